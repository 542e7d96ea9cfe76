"""``python -m planner.cli``: the ``cabinplan`` command."""

from planner.cli import main

main()
