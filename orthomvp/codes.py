"""The shared vocabulary: visibility codes with their names and colours, and the string enums
used as options (and as CLI choices).

This module is the bottom layer: it imports nothing from orthomvp but the exception family.
"""

from __future__ import annotations

from enum import Enum, IntEnum

import numpy as np

from orthomvp.errors import InputError


class Code(IntEnum):
    """Per-post visibility of one image, as stored in uint8 rasters on the DEM grid."""

    NODATA = 0
    """no data, or the post projects outside the image (or behind the camera)"""
    VISIBLE = 1
    OCCLUDED = 2
    """the ray from the camera hits the surface elsewhere first"""
    FACING_AWAY = 3
    """the surface normal points away from the camera"""

    @property
    def label(self) -> str:
        """Human-readable name (legends, counts)."""
        return _LABELS[self]

    @property
    def rgb(self) -> tuple[int, int, int]:
        """RGB uint8 colour of the code in figures, meshes and snapshots (occluded is green,
        as in the occlusion poster's figure 4). The palette has one colour per meaning: no
        data is the colour of every post without a value (an empty orthophoto post, an
        unresolved height), and none of these is red or blue, which mean too high and too low
        on height-error maps."""
        return _RGB[self]


_LABELS = {
    Code.NODATA: "no data / outside",
    Code.VISIBLE: "visible",
    Code.OCCLUDED: "occluded",
    Code.FACING_AWAY: "facing away",
}
_RGB = {
    Code.NODATA: (150, 110, 200),  # violet: no value
    Code.VISIBLE: (215, 215, 210),  # light grey
    Code.OCCLUDED: (20, 200, 40),  # green
    Code.FACING_AWAY: (235, 115, 30),  # orange
}

CODE_RGB = np.array([c.rgb for c in Code], np.uint8)
"""RGB uint8 (4, 3) look-up table indexed by code."""


DOUBT = 0.5
"""A first hit farther than epsilon minus this many DEM posts from its post makes the post
doubtful for a mosaic (:func:`orthomvp.ortho.composite.doubtful`), though visible; the visibility
test calls a post visible without a cast only where its first hit cannot lie that far
(:mod:`orthomvp.occlusion.occluders`)."""


def classify(miss: np.ndarray, eps: np.ndarray | float) -> np.ndarray:
    """The epsilon rule on the posts whose ray was cast: OCCLUDED where the first hit lies more
    than ``eps`` DEM posts from the post (``miss``, finite), VISIBLE otherwise, including rays
    that hit nothing (``miss`` inf: nothing is in their way). uint8 codes, shape of ``miss``."""
    miss = np.asarray(miss)
    hidden = np.isfinite(miss) & (miss > eps)
    return np.where(hidden, Code.OCCLUDED, Code.VISIBLE).astype(np.uint8)


class Choice(str, Enum):
    """Base of the option enums: members compare equal to their string values, print as them,
    and converting a bad string (``Interp("linear")``) raises an InputError that lists the
    choices, so that functions accept plain strings by converting them with the enum."""

    def __str__(self) -> str:
        return self.value

    @classmethod
    def _missing_(cls, value: object) -> None:
        choices = ", ".join(member.value for member in cls)
        raise InputError(f"unknown {_NOUNS[cls]} {value!r}; choose one of {choices}")


class WorldFrame(Choice):
    """The frame in which cameras live: body-fixed Cartesian metres, or the DEM's projected CRS
    taken as Cartesian (easting, northing, height; aerial data, Orthority's convention)."""

    BODY = "body"
    MAP = "map"


class Interp(Choice):
    """Image interpolation when sampling orthophotos."""

    NEAREST = "nearest"
    BILINEAR = "bilinear"
    CUBIC = "cubic"


class View(Choice):
    """Viewpoints of 3D snapshots: oblique from an azimuth, straight down, or through a camera."""

    OBLIQUE = "oblique"
    TOP = "top"
    FROM_CAMERA = "from-camera"


_NOUNS = {WorldFrame: "world frame", Interp: "interpolation", View: "view"}
"""What each option enum chooses, for error messages."""
