# Rules of the friction stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to FRICTION_TARGETS when config["friction"]["enabled"].
