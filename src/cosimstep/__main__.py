"""``python -m cosimstep`` runs the command line."""

from cosimstep.cli import main

main()
