"""ISIS3 cubes as cameras: a spiceinit'd level-1 cube carries its camera (SPICE tables and
``NaifKeywords``), read by :mod:`orthomvp.camera.isis` (imported when a cube is read, so that
reading a camera of another format does not load it). The image can be its own camera:
``orthomvp ortho DEM IMAGE.cub IMAGE.cub``."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from orthomvp.camera.formats._common import CameraFile, CameraFormat
from orthomvp.io.files import open_regular

if TYPE_CHECKING:
    from orthomvp.camera.csm.isd import CsmCamera

_CUBE = re.compile(rb"\s*Object\s*=\s*IsisCube\b", re.IGNORECASE)


def read_cube_file(file: CameraFile) -> CsmCamera:
    """The camera of a spiceinit'd cube."""
    from orthomvp.camera.isis import read_cube_camera

    return read_cube_camera(file.path)


def is_cube(file: CameraFile) -> bool:
    """Whether the file starts as an ISIS3 cube's label (only its first bytes are read)."""
    try:
        with open_regular(file.path, "camera file") as handle:
            return _CUBE.match(handle.read(256)) is not None
    except OSError:
        return False


FORMATS = (CameraFormat("an ISIS3 cube", (".cub",), read_cube_file, is_cube),)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry."""
