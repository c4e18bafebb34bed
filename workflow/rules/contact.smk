# Rules of the contact stage (wiring only: every rule calls capsule-cli).
# Appends its final outputs to CONTACT_TARGETS when config["contact"]["enabled"].
