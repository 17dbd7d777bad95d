"""The module paths of release 0.1 that moved into the domain packages: importing one still
works for one more release, warns (:class:`DeprecationWarning`) and gives the module at its new
path (the same object, so monkeypatching either patches both). One name is taken by the
package's front: ``orthomvp.mosaic`` is the function, so ``from orthomvp.mosaic import NAME``
still gives the 0.1 module's names (from :mod:`orthomvp.ortho.composite`), while ``import
orthomvp.mosaic as m`` gives the function."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

MOVED = {
    "orthomvp.check": "orthomvp.quality.check",
    "orthomvp.embree": "orthomvp.occlusion.embree",
    "orthomvp.epsstudy": "orthomvp.quality.eps_study",
    "orthomvp.isis": "orthomvp.io.isis",
    "orthomvp.memory": "orthomvp.io.preflight",
    "orthomvp.mesh": "orthomvp.occlusion.mesh",
    "orthomvp.mesh_stream": "orthomvp.present.mesh_stream",
    "orthomvp.mosaic": "orthomvp.ortho.composite",
    "orthomvp.mosaic_kernel": "orthomvp.ortho.composite_kernel",
    "orthomvp.occluders": "orthomvp.occlusion.occluders",
    "orthomvp.post_geometry": "orthomvp.occlusion.post_geometry",
    "orthomvp.post_geometry_kernel": "orthomvp.occlusion.post_geometry_kernel",
    "orthomvp.raycast": "orthomvp.occlusion.raycast",
    "orthomvp.terrain": "orthomvp.geometry.terrain",
    "orthomvp.vectors": "orthomvp.geometry.vectors",
    "orthomvp.visibility": "orthomvp.occlusion.visibility",
    "orthomvp.world": "orthomvp.geometry.world",
}
"""Old module path -> new module path."""

SPLIT = {
    "orthomvp.raster": (
        "orthomvp.io.raster",
        "orthomvp.io.outputs",
        "orthomvp.io.signals",
        "orthomvp.io.write_errors",
        "orthomvp.io.preflight",
    ),
}
"""Old module path -> the modules its names went to, looked up in this order."""


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old paths of :data:`MOVED` and loads each as its new module."""

    def __init__(self) -> None:
        self.specs: dict[str, importlib.machinery.ModuleSpec] = {}

    def find_spec(self, fullname: str, path: object = None, target: object = None):  # noqa: ANN201
        if fullname not in MOVED and fullname not in SPLIT:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        if spec.name in SPLIT:
            return _merged(spec.name, SPLIT[spec.name])
        new = MOVED[spec.name]
        warnings.warn(
            f"{spec.name} moved to {new}; the old path goes in orthomvp 0.3",
            DeprecationWarning,
            stacklevel=2,
        )
        module = importlib.import_module(new)
        self.specs[new] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module is the new one, already imported. Its own spec and loader,
        which the import system replaced with the old path's, are put back."""
        if module.__name__ in SPLIT:
            return
        module.__spec__ = spec = self.specs[module.__name__]
        module.__loader__ = spec.loader


def _merged(name: str, homes: tuple[str, ...]) -> ModuleType:
    """A module ``name`` whose attributes are those of the modules ``homes``, first found first."""
    warnings.warn(
        f"{name} was split into {', '.join(homes)}; the old path goes in orthomvp 0.3",
        DeprecationWarning,
        stacklevel=3,
    )
    modules = [importlib.import_module(home) for home in homes]
    merged = ModuleType(name, f"The names of {name} of release 0.1, now in {', '.join(homes)}.")

    def __getattr__(attr: str) -> object:
        for module in modules:
            if hasattr(module, attr):
                return getattr(module, attr)
        raise AttributeError(f"module {name!r} has no attribute {attr!r}")

    merged.__getattr__ = __getattr__
    return merged


def install_aliases() -> None:
    """Put the finder first on :data:`sys.meta_path` (once)."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.insert(0, _Alias())
