"""``python -m orthomvp``: the command line."""

from orthomvp.cli import main_entry

main_entry()
