"""``python -m orthomvp``: the command line."""

from orthomvp.cli import main_entry

if __name__ == "__main__":  # worker processes spawned by --processes import this module too
    main_entry()
