"""Multi-view photogrammetry (MVP): refine a DEM by fitting a plane per post to every view in
which the post is visible. ``plane``: geometry and homographies (eqs. 5-18); ``patches``:
sampling, normalisation and the objective (eqs. 19-21); ``fit``: the batched optimiser."""

from orthomvp.mvp.fit import FitOptions, FitResult, fit_dem

__all__ = ["FitOptions", "FitResult", "fit_dem"]
