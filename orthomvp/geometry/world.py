"""Which world frame the cameras live in, judged from their centres and the DEM.

Two frames are possible (see :mod:`orthomvp.geometry.terrain`): body-fixed Cartesian metres
(``"body"``, planetary data, ASP's convention) and the DEM's projected CRS taken as Cartesian
(easting, northing, height; ``"map"``, aerial data, Orthority's convention). A camera centre is

- *body-plausible* when it lies above the tangent plane of at least one DEM post in body-fixed
  coordinates (an orbiter, or an aircraft given in Earth-centred coordinates, is; map
  coordinates, whose norm is far below the body radius, or that lie on the far side, are not);
- *map-plausible* (projected CRSs only) when its (x, y) lie within :data:`MAP_EXTENTS` DEM
  extents of the DEM's map extent and its z lies above the DEM height under it (the lowest DEM
  height when outside) and at most :data:`MAP_ALTITUDE` metres above the highest.

The frame is picked when every camera is plausible in exactly the same one frame; otherwise
the choice is left to the user (``--world body|map``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from orthomvp.codes import WorldFrame
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain

MAP_EXTENTS = 3.0
"""How far beyond the DEM's map extent a map-frame camera may lie, in DEM extents (per axis)."""

MAP_ALTITUDE = 100_000.0
"""Highest plausible map-frame camera above the DEM's highest post, in DEM height units (m)."""

_SAMPLES = 64  # posts per side sampled for the body-frame test


def body_plausible(terrain: Terrain, centres: np.ndarray) -> np.ndarray:
    """Boolean (n,): camera centres (n, 3) that lie above the tangent plane (outward normal =
    local vertical) of at least one of up to 64 x 64 DEM posts with heights, taken evenly among
    them, in body-fixed metres.

    A post p's plane (radial normal) has c above it when c . p / |p| > |p|, never when |c| is
    at most |p|: centres no farther from the body's centre than the nearest post can be
    ruled out before any post is transformed (map coordinates are: 3.7e6 m against the
    Earth's 6.36e6). A post at height h over the ellipsoid lies at least b + min(h, 0) from
    the centre (b the semi-minor axis); with radius values, at its value."""
    centres = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    lowest = float(np.nanmin(terrain.values))
    nearest = lowest if terrain.radius_values else terrain.radii[1] + min(lowest, 0.0)
    if (np.linalg.norm(centres, axis=1) <= nearest).all():
        return np.zeros(len(centres), bool)
    body = terrain if terrain.world == WorldFrame.BODY else replace(terrain, world=WorldFrame.BODY)
    # evenly among the valid posts (a grid of samples could meet only nodata: every other post)
    valid = np.flatnonzero(np.isfinite(body.values))
    pick = valid[np.linspace(0, len(valid) - 1, min(len(valid), _SAMPLES**2)).astype(np.intp)]
    rows, cols = np.unravel_index(pick, body.shape)
    c, r = body.grid()
    p = body.to_world(c[rows, cols], r[rows, cols], body.values[rows, cols])
    up = body.up_vectors(p)
    above = np.einsum("ci,pi->cp", centres, up) - np.einsum("pi,pi->p", p, up) > 0
    return above.any(axis=1)


def map_plausible(terrain: Terrain, centres: np.ndarray) -> np.ndarray:
    """Boolean (n,): camera centres (n, 3) that fit the DEM's map frame (see the module
    docstring); all False for geographic CRSs."""
    if not terrain.crs.is_projected:
        return np.zeros(len(centres), bool)
    t = terrain.transform
    rows, cols = terrain.shape
    xs = sorted((t.c, t.c + cols * t.a))
    ys = sorted((t.f, t.f + rows * t.e))
    width, height = xs[1] - xs[0], ys[1] - ys[0]
    x, y, z = centres.T
    near = (
        (x >= xs[0] - MAP_EXTENTS * width)
        & (x <= xs[1] + MAP_EXTENTS * width)
        & (y >= ys[0] - MAP_EXTENTS * height)
        & (y <= ys[1] + MAP_EXTENTS * height)
    )
    under = terrain.interpolate(*terrain.crs_to_pixel(x, y))
    under = np.where(np.isfinite(under), under, np.nanmin(terrain.values))
    return near & (z > under) & (z <= np.nanmax(terrain.values) + MAP_ALTITUDE)


def _camera(views: np.ndarray | None, k: int) -> int:
    """The 1-based camera that centre ``k`` belongs to (``views``: each centre's camera index,
    as :func:`~orthomvp.camera.camera_centres` gives; None: one centre a camera)."""
    return (k if views is None else int(views[k])) + 1


def detect_world(
    terrain: Terrain, centres: np.ndarray, views: np.ndarray | None = None
) -> WorldFrame:
    """The world frame (``"body"`` or ``"map"``) of cameras with ``centres`` (n, 3) over
    ``terrain`` (its own ``world`` is ignored); ``views``: the camera of each centre, which
    messages name (default: one centre a camera). Geographic CRSs are always ``"body"``.

    Raises InputError, asking for ``--world body|map``, when there are no cameras, when a
    camera fits both frames or neither, or when the cameras disagree.
    """
    if not terrain.crs.is_projected:
        return WorldFrame.BODY
    centres = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    if centres.size == 0:
        raise InputError(
            f"{terrain.name}: no cameras to tell the world frame of a projected DEM from; "
            "give --world body or --world map"
        )
    body, map_ = body_plausible(terrain, centres), map_plausible(terrain, centres)
    if (body & ~map_).all():
        return WorldFrame.BODY
    if (map_ & ~body).all():
        return WorldFrame.MAP
    both, neither = np.flatnonzero(body & map_), np.flatnonzero(~body & ~map_)
    if both.size:
        why = (
            f"camera {_camera(views, both[0])} fits both body-fixed metres and the DEM's map frame"
        )
    elif neither.size:
        why = (
            f"camera {_camera(views, neither[0])} fits neither body-fixed metres nor the DEM's "
            "map frame "
            f"(within {MAP_EXTENTS:g} DEM extents of its map extent, above its heights)"
        )
    else:
        why = (
            f"camera {_camera(views, np.flatnonzero(body)[0])} fits body-fixed metres, camera "
            f"{_camera(views, np.flatnonzero(map_)[0])} the DEM's map frame"
        )
    raise InputError(
        f"{terrain.name}: cannot tell the cameras' world frame: {why}; "
        "give --world body or --world map"
    )


def check_cameras_above(
    terrain: Terrain,
    centres: np.ndarray,
    views: np.ndarray | None = None,
    *,
    spare: bool = False,
) -> None:
    """GeometryError when a camera centre of ``centres`` (n, 3; ``views``: the camera of each,
    as :func:`detect_world`) does not sit above the DEM in the body-fixed frame of its CRS (see
    :func:`body_plausible`): the DEM's CRS names another body (an Earth CRS for lunar cameras),
    the cameras belong to the map frame, or a camera looks at another part of the body. Says
    how far from the body's centre the camera is, against the body's radius, or where on the
    body it looks, against the DEM's extent. With ``spare`` (commands of several images, which
    leave out the images that see no post), cameras that merely look at another part of the
    body pass while one camera sits above the DEM. Map-frame terrains are not checked."""
    if terrain.world != WorldFrame.BODY:
        return
    centres = np.atleast_2d(np.asarray(centres, dtype=np.float64))
    if not len(centres):
        return
    ok = body_plausible(terrain, centres)
    if ok.all():
        return
    radius = terrain.radii[1]
    distance = np.linalg.norm(centres, axis=1)
    if spare and ok.any() and (distance[~ok] >= radius).all():
        return
    k = int(np.flatnonzero(~ok)[0])
    if distance[k] < radius:
        where = (
            f"{distance[k] / 1000:,.0f} km from the centre of the DEM's body, below its surface "
            f"({radius / 1000:,.0f} km radius)"
        )
    else:
        where = f"beyond the DEM's horizon ({_looks_at(terrain, centres[k])})"
    raise GeometryError(
        f"{terrain.name}: camera {_camera(views, k)} is {where} in the DEM's CRS "
        f"({terrain.geodetic_crs.name}): the cameras do not sit above the DEM in this "
        "CRS and body; is it the DEM of these images, the right CRS for these cameras "
        "(--dem-crs), or do they live in the DEM's map frame (--world map)?"
    )


def _looks_at(terrain: Terrain, centre: np.ndarray) -> str:
    """Where on the body a camera at body-fixed ``centre`` lies over (planetocentric, degrees),
    against the DEM's extent in longitude and latitude."""
    x, y, z = (float(v) for v in centre)
    lon, lat = math.degrees(math.atan2(y, x)), math.degrees(math.atan2(z, math.hypot(x, y)))
    rows, cols = terrain.shape
    c = np.array([0.0, cols - 1, 0.0, cols - 1, (cols - 1) / 2])
    r = np.array([0.0, 0.0, rows - 1, rows - 1, (rows - 1) / 2])
    dem_lon, dem_lat = (np.degrees(v) for v in terrain.pixel_to_lonlat(c, r))
    return (
        f"over longitude {lon:.2f}, latitude {lat:.2f}; the DEM covers longitude "
        f"{dem_lon.min():.2f} to {dem_lon.max():.2f}, latitude {dem_lat.min():.2f} to "
        f"{dem_lat.max():.2f}"
    )


BODY_TOLERANCE = 0.1
"""How far (relative) a radius may lie outside another ellipsoid's span of radii for both to
be of one body: datasets give a small body's shape differently (Vesta's 289 x 229 km ellipsoid,
or a sphere of its mean radius)."""


def check_camera_bodies(terrain: Terrain, cameras: Sequence[object]) -> None:
    """GeometryError when a camera of ``cameras`` that knows its body's ellipsoid (a CSM
    camera: an ISD's or a cube's radii) is of another body than the DEM's CRS: their spans of
    radii, each widened by :data:`BODY_TOLERANCE`, do not meet (a lunar cube on a DEM whose CRS
    lost its body and says WGS 84). Cameras that know no body are not checked."""
    a = terrain.radii[0]
    ours = (min(terrain.radii) * (1 - BODY_TOLERANCE), max(terrain.radii) * (1 + BODY_TOLERANCE))
    for k, camera in enumerate(cameras, start=1):
        ellipsoid = getattr(camera, "ellipsoid", None)
        if ellipsoid is None:
            continue
        theirs = ellipsoid.semi_major
        low = min(theirs, ellipsoid.semi_minor) * (1 - BODY_TOLERANCE)
        if low <= ours[1] and ours[0] <= max(theirs, ellipsoid.semi_minor) * (1 + BODY_TOLERANCE):
            continue
        raise GeometryError(
            f"{terrain.name}: camera {k} is of a body of equatorial radius {theirs / 1000:,.1f} "
            f"km, the DEM's CRS ({terrain.geodetic_crs.name}) of one of {a / 1000:,.1f} km: "
            "give the DEM's CRS for the cameras' body with --dem-crs (e.g. IAU_2015:30100 for "
            "the Moon, IAU_2015:49900 for Mars)"
        )
