"""The ``orthomvp`` console script: a Ctrl-C while the command line's modules are still being
imported ends as one line with exit status 130, like one later (:func:`orthomvp.cli.main`),
instead of Python's traceback."""

from __future__ import annotations

import sys


def main() -> None:
    """Import the command line and run it (:func:`orthomvp.cli.main_entry`)."""
    try:
        from orthomvp.cli import main_entry
    except KeyboardInterrupt:
        print("orthomvp: interrupted; no partial output was kept", file=sys.stderr)
        raise SystemExit(130) from None
    main_entry()
