"""Orbital pinhole cameras over a DEM: placements by emission angle and azimuth, and the
placements of each scene kind."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.camera import PinholeCamera
from orthomvp.codes import WorldFrame
from orthomvp.geometry.terrain import Terrain
from orthomvp.synthetic.surface import local_frame

ALTITUDE = 110_000.0
"""Default camera altitude above the tile centre, metres (Apollo 15 Metric Camera-like)."""


@dataclass(frozen=True)
class ViewSpec:
    """A camera placement: emission angle from the vertical at the tile centre, azimuth of the
    camera as seen from the ground (degrees clockwise from north), and altitude in metres."""

    name: str
    emission: float
    azimuth: float
    altitude: float = ALTITUDE


VIEWS = {
    "planar": (
        ViewSpec("orbit1", 14.0, 180.0),
        ViewSpec("orbit2", 5.0, 180.0),
        ViewSpec("orbit3", 5.0, 0.0),
        ViewSpec("orbit4", 14.0, 0.0),
    ),
    "crater": (
        ViewSpec("oblique", 55.0, 200.0),
        ViewSpec("nadir", 3.0, 90.0),
        ViewSpec("fore", 18.0, 0.0),
        ViewSpec("aft", 18.0, 180.0),
    ),
    "hills": (
        ViewSpec("fore2", 22.0, 0.0),
        ViewSpec("fore1", 8.0, 0.0),
        ViewSpec("aft1", 8.0, 180.0),
        ViewSpec("aft2", 22.0, 180.0),
    ),
}
"""The views of each scene kind, in order."""


def look_at(centre: np.ndarray, target: np.ndarray, north: np.ndarray) -> np.ndarray:
    """Camera-to-world rotation looking from ``centre`` at ``target`` with image rows running
    roughly southward (columns eastward for a nadir view): columns of R are the camera x (right),
    y (down) and z (forward) axes."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(-north, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def orbital_camera(
    terrain: Terrain, view: ViewSpec, gsd: float, margin: float = 6.0
) -> PinholeCamera:
    """A pinhole camera placed as ``view`` says over the centre of ``terrain`` (body or map
    frame), looking at that centre (at the median height), with ground sample distance
    ``gsd`` metres there and an image just large enough (plus ``margin`` pixels) to hold the
    whole DEM."""
    rows, cols = terrain.shape
    mid = np.array((cols - 1) / 2), np.array((rows - 1) / 2)
    heights = terrain.values[terrain.valid]
    if terrain.world == WorldFrame.MAP:  # easting, northing, height
        east, north, up = np.eye(3)
        target = terrain.to_world(*mid, np.median(heights))
    else:
        up, east, north = local_frame(*terrain.pixel_to_lonlat(*mid))
        target = (terrain.radii[0] + float(np.median(heights))) * up
    corners = terrain.to_world(
        np.array([0, cols - 1, 0, cols - 1] * 2, float),
        np.array([0, 0, rows - 1, rows - 1] * 2, float),
        np.repeat([heights.min(), heights.max()], 4),
    )
    em, az = np.radians(view.emission), np.radians(view.azimuth)
    horiz = np.sin(az) * east + np.cos(az) * north
    # `altitude` above the target, seen from the target at emission angle `em`
    dist = view.altitude / np.cos(em)
    centre = target + dist * (np.sin(em) * horiz + np.cos(em) * up)
    rot = look_at(centre, target, north)
    f = dist / gsd
    uv, _ = PinholeCamera(f, f, 0.0, 0.0, centre, rot).project(corners)
    lo, hi = uv.min(axis=0) - margin, uv.max(axis=0) + margin
    width, height = (int(np.ceil(v)) for v in hi - lo)
    return PinholeCamera(f, f, -lo[0], -lo[1], centre, rot, width=width, height=height)
