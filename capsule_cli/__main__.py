"""``python -m capsule_cli`` runs the CLI."""
from .cli import main

main()
