"""``python -m dfc`` runs the command line."""

from .cli import main

main()
