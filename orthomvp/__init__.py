"""orthomvp: occlusion-aware orthorectification and multi-view DEM refinement.

The front of the Python API, each name imported on first use so that ``import orthomvp`` stays
light (it imports no numpy)::

    import orthomvp as om

    terrain = om.Terrain.read("dem.tif")
    image = read_image("image.tif")                         # orthomvp.io.raster
    camera = om.read_camera("image.tsai").with_image_size(image.shape[2], image.shape[1])
    vis = om.compute_visibility(terrain, camera)           # codes: 1 visible, 2 occluded, ...
    ortho = om.orthorectify(terrain, image, camera)         # occluded posts NaN
    report = om.run_plan(om.plan_ortho("dem.tif", [("image.tif", "image.tsai")]),
                         om.Outputs(ortho="ortho.tif"))     # any size, tile by tile

The rooms behind it: :mod:`orthomvp.geometry` (DEMs, frames), :mod:`orthomvp.camera` (every
sensor), :mod:`orthomvp.occlusion` (who sees what), :mod:`orthomvp.ortho` (orthophotos and
mosaics), :mod:`orthomvp.mvp` (the plane fitter), :mod:`orthomvp.engine` (tiles in bounded
memory), :mod:`orthomvp.io` (rasters, cubes, atomic outputs), :mod:`orthomvp.present`,
:mod:`orthomvp.explore`, :mod:`orthomvp.quality`, :mod:`orthomvp.synthetic` and
:mod:`orthomvp.cli`. Errors are the :mod:`orthomvp.errors` family.
"""

import sys
from types import ModuleType
from typing import TYPE_CHECKING

from orthomvp._lazy import lazy_exports
from orthomvp._moved import install_aliases

__version__ = "0.1.0"

_HOMES = {
    "Terrain": "orthomvp.geometry.terrain",
    "read_camera": "orthomvp.camera",
    "Visibility": "orthomvp.occlusion.visibility",
    "compute_visibility": "orthomvp.occlusion.visibility",
    "Ortho": "orthomvp.ortho.orthophoto",
    "Mosaic": "orthomvp.ortho.orthophoto",
    "orthorectify": "orthomvp.ortho.orthophoto",
    "mosaic": "orthomvp.ortho.orthophoto",
    "MosaicOptions": "orthomvp.ortho.composite",
    "FitOptions": "orthomvp.mvp.fit",
    "FitResult": "orthomvp.mvp.fit",
    "fit_dem": "orthomvp.mvp.fit",
    "Plan": "orthomvp.engine.plan",
    "plan_ortho": "orthomvp.engine.plan",
    "Outputs": "orthomvp.engine.writer",
    "RunReport": "orthomvp.engine.run",
    "run_plan": "orthomvp.engine.run",
    "FitPlan": "orthomvp.engine.fit_plan",
    "plan_fit": "orthomvp.engine.fit_plan",
    "FitOutputs": "orthomvp.engine.fit",
    "FitReport": "orthomvp.engine.fit",
    "run_fit": "orthomvp.engine.fit",
    "CheckPlan": "orthomvp.engine.check_plan",
    "plan_check": "orthomvp.engine.check_plan",
    "CheckResult": "orthomvp.engine.check",
    "run_check": "orthomvp.engine.check",
    "dask_client": "orthomvp.engine.cluster",
}
"""Where each name of the front lives."""

__all__ = [
    "__version__",
    "CheckPlan",
    "CheckResult",
    "FitOptions",
    "FitOutputs",
    "FitPlan",
    "FitReport",
    "FitResult",
    "Mosaic",
    "MosaicOptions",
    "Ortho",
    "Outputs",
    "Plan",
    "RunReport",
    "Terrain",
    "Visibility",
    "compute_visibility",
    "dask_client",
    "fit_dem",
    "mosaic",
    "orthorectify",
    "plan_check",
    "plan_fit",
    "plan_ortho",
    "read_camera",
    "run_check",
    "run_fit",
    "run_plan",
]

if TYPE_CHECKING:
    from orthomvp.camera import read_camera
    from orthomvp.engine.check import CheckResult, run_check
    from orthomvp.engine.check_plan import CheckPlan, plan_check
    from orthomvp.engine.cluster import dask_client
    from orthomvp.engine.fit import FitOutputs, FitReport, run_fit
    from orthomvp.engine.fit_plan import FitPlan, plan_fit
    from orthomvp.engine.plan import Plan, plan_ortho
    from orthomvp.engine.run import RunReport, run_plan
    from orthomvp.engine.writer import Outputs
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.mvp.fit import FitOptions, FitResult, fit_dem
    from orthomvp.occlusion.visibility import Visibility, compute_visibility
    from orthomvp.ortho.composite import MosaicOptions
    from orthomvp.ortho.orthophoto import Mosaic, Ortho, mosaic, orthorectify


class _Front(ModuleType):
    """The package, whose front names are not rebound by the import of an old module path of the
    same name (``import orthomvp.mosaic``, now :mod:`orthomvp.ortho.composite`, would otherwise
    make ``orthomvp.mosaic`` that module instead of the function)."""

    def __setattr__(self, name: str, value: object) -> None:
        if name in _HOMES and isinstance(value, ModuleType):
            return
        super().__setattr__(name, value)


__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
sys.modules[__name__].__class__ = _Front
install_aliases()
