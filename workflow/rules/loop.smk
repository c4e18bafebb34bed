# Rules of the loop stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to LOOP_TARGETS when config["loop"]["enabled"].
