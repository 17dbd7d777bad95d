"""``python -m orthomvp``: the command line."""

from orthomvp._entry import main

if __name__ == "__main__":  # worker processes spawned by --processes import this module too
    main()
