# Rules of the dynamics stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to DYNAMICS_TARGETS when config["dynamics"]["enabled"].
