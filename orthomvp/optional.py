"""Soft imports of the heavy dependencies that only some features need (trimesh, Open3D,
pyvista, embreex): each is imported where its feature runs, so that importing the core
(visibility, orthophotos) stays light, and a missing one fails only when its feature is used,
with a message that says what to install."""

from __future__ import annotations

import importlib
from types import ModuleType

from orthomvp.errors import InputError

SYSTEM_LIBRARIES = {"open3d": "libusb-1.0-0"}
"""The Debian/Ubuntu package of the system library that a pip package loads, where one is
commonly missing (Open3D's libusb-1.0.so.0)."""


def require(module: str, feature: str, package: str | None = None) -> ModuleType:
    """Import ``module`` (e.g. ``"scipy.spatial"``) for ``feature`` (a phrase: "mesh export").

    Raises InputError naming the pip package (``package``, default the module's top-level name)
    when the import fails, or, when a shared library it loads is missing (OSError), that
    library (and its Debian package, when known).
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        name = package or module.partition(".")[0]
        raise InputError(
            f"{feature} needs the package {name}, which cannot be imported ({exc}): "
            f"install it with 'pip install {name}'"
        ) from exc
    except OSError as exc:
        name = package or module.partition(".")[0]
        system = SYSTEM_LIBRARIES.get(name)
        hint = f" (on Debian or Ubuntu: apt-get install {system})" if system else ""
        raise InputError(
            f"{feature} needs the package {name}, which cannot load a system library "
            f"({exc}): install that library{hint}"
        ) from exc
