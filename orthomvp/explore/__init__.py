"""The objective explorer (``orthomvp explore``), successor of mvpgui: the MVP objective at one
DEM post against height and orientation, the views and patches there, the optimiser's path, and
the effect of the window size. ``session``: state and computations; ``plots``: figures and their
data; ``shell``: the ``mvp>`` command interpreter."""

from orthomvp.explore.session import ExploreError, Explorer
from orthomvp.explore.shell import ExplorerShell, run_commands, split_commands

__all__ = ["Explorer", "ExploreError", "ExplorerShell", "run_commands", "split_commands"]
