"""Multi-view photogrammetry (MVP): refine a DEM by fitting a plane per post to every view in
which the post is visible. ``plane``: geometry of height lines and planes (eqs. 5-18);
``model``: a batch of posts' homographies and their derivatives; ``window``: the Gaussian patch
window; ``patches``: sampling, normalisation and the objective (eqs. 19-21), in numpy; ``kernel``:
the same objective as one fused numba kernel, which the fitter runs; ``lm``: the batched
Levenberg-Marquardt and its coarse-to-fine driver; ``problem``: a DEM and its views prepared for
the objective (shared with the explorer); ``fit``: the fitter over a whole DEM; ``deconvolve``:
from plane heights back to surface heights."""

from orthomvp.mvp.fit import FitOptions, FitResult, fit_dem

__all__ = ["FitOptions", "FitResult", "fit_dem"]
