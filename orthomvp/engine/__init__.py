"""The engine: every DEM command as a plan of output tiles run in bounded memory.

:func:`plan_ortho` cuts the output grid into tiles and finds, for each tile and image, the DEM
window it needs (its posts plus the occluder halo, see :mod:`orthomvp.engine.halo`);
:func:`run_plan` runs the tiles in threads, processes or on a Dask cluster
(:func:`dask_client`) and writes Cloud-Optimized or tiled GeoTIFFs (:class:`Outputs`).

    plan = plan_ortho("dem.tif", [("image.tif", "image.tsai")], tile=1024)
    report = run_plan(plan, Outputs(ortho="ortho.tif", visibility="vis.tif"), threads=2)

The MVP fit runs the same way (:mod:`orthomvp.engine.fit_plan`, :mod:`orthomvp.engine.fit`):

    plan = plan_fit("dem.tif", [("a.tif", "a.tsai"), ("b.tif", "b.tsai")], FitOptions())
    report = run_fit(plan, FitOutputs(heights="fitted.tif", uncertainty="sigma.tif"))

By default the output grid is the part of the DEM the images see, at their own ground sample
distance (:func:`choose_grid`; ``plan_ortho(..., grid="dem")`` for the DEM's own grid), and
:func:`describe` says what an image sees of a DEM (``orthomvp info``):

    feature = describe("dem.tif", "image.tif", "image.tsai")  # a GeoJSON Feature

And the truth-free check (:mod:`orthomvp.engine.check_plan`, :mod:`orthomvp.engine.check`):

    result = run_check(plan_check("dem.tif", [("a.tif", "a.tsai"), ("b.tif", "b.tsai")]))
"""

import importlib
from typing import TYPE_CHECKING, Any

_HOMES = {
    "CheckResult": "check",
    "run_check": "check",
    "CheckPlan": "check_plan",
    "plan_check": "check_plan",
    "FitOutputs": "fit",
    "FitReport": "fit",
    "run_fit": "fit",
    "FitPlan": "fit_plan",
    "plan_fit": "fit_plan",
    "HaloWarning": "grid_choice",
    "choose_grid": "grid_choice",
    "describe": "info",
    "image_footprint": "footprint",
    "Plan": "plan",
    "TileJob": "plan",
    "plan_ortho": "plan",
    "RunReport": "run",
    "WorkerError": "cluster",
    "dask_client": "cluster",
    "run_plan": "run",
    "Outputs": "writer",
}
"""The module of each name below: imported on first use, so that the orthophoto path does not
load the MVP fit (and scipy.ndimage with it)."""

__all__ = [
    "CheckPlan",
    "CheckResult",
    "FitOutputs",
    "FitPlan",
    "FitReport",
    "HaloWarning",
    "Outputs",
    "Plan",
    "RunReport",
    "TileJob",
    "WorkerError",
    "choose_grid",
    "dask_client",
    "describe",
    "image_footprint",
    "plan_check",
    "plan_fit",
    "plan_ortho",
    "run_check",
    "run_fit",
    "run_plan",
]

if TYPE_CHECKING:
    from orthomvp.engine.check import CheckResult, run_check
    from orthomvp.engine.check_plan import CheckPlan, plan_check
    from orthomvp.engine.cluster import WorkerError, dask_client
    from orthomvp.engine.fit import FitOutputs, FitReport, run_fit
    from orthomvp.engine.fit_plan import FitPlan, plan_fit
    from orthomvp.engine.footprint import image_footprint
    from orthomvp.engine.grid_choice import HaloWarning, choose_grid
    from orthomvp.engine.info import describe
    from orthomvp.engine.plan import Plan, TileJob, plan_ortho
    from orthomvp.engine.run import RunReport, run_plan
    from orthomvp.engine.writer import Outputs


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
