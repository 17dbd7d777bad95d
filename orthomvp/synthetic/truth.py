"""Visibility truth by marching: each surface point's segment to the camera is sampled against
an analytic surface, never against the mesh that the code under test casts rays on."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from orthomvp.camera import Camera
from orthomvp.codes import Code

Below = Callable[[np.ndarray], np.ndarray]
"""Whether body-fixed points (n, 3), metres, lie under the analytic surface: (n,) bool."""


def march(
    points: np.ndarray, centre: np.ndarray, step: float, max_radius: float, below: Below
) -> np.ndarray:
    """Whether the segment from each surface point (n, 3) to ``centre`` ((3,), or (n, 3): one
    sensor position per point, as for a line scanner) dips below the
    surface: (n,) bool. Samples lie ``step`` metres apart from ``step / 2`` on, up to where the
    segment leaves the sphere of ``max_radius`` (metres from the body centre; no surface point
    lies beyond it) for good, or reaches ``centre``."""
    seg = centre - points
    length = np.linalg.norm(seg, axis=1)
    unit = seg / length[:, None]
    b = np.einsum("ij,ij->i", points, unit)
    pp = np.einsum("ij,ij->i", points, points)
    leave = -b + np.sqrt(np.maximum(b * b - pp + max_radius**2, 0))
    reach = np.minimum(leave, length)
    hidden = np.zeros(len(points), bool)
    s = step / 2
    active = np.flatnonzero(reach > s)
    while active.size:
        under = below(points[active] + s * unit[active])
        hidden[active[under]] = True
        active = active[~under & (reach[active] > s + step)]
        s += step
    return hidden


def visibility_truth(
    camera: Camera,
    points: np.ndarray,
    normals: np.ndarray,
    below: Below,
    max_radius: float,
    step: float,
) -> np.ndarray:
    """Truth :class:`~orthomvp.codes.Code` of surface ``points`` for ``camera`` by
    :func:`truth_codes`, with :func:`march` (``step`` metres, up to ``max_radius``) against
    ``below`` as the occlusion test."""
    return truth_codes(camera, points, normals, lambda p, s: march(p, s, step, max_radius, below))


def truth_codes(
    camera: Camera,
    points: np.ndarray,
    normals: np.ndarray,
    hidden: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> np.ndarray:
    """Truth :class:`~orthomvp.codes.Code` (uint8, the shape of ``points`` without its last
    axis) of surface ``points`` (..., 3) with outward unit ``normals`` (..., 3) for ``camera``
    (with its image size): NODATA outside the image or behind the camera, FACING_AWAY where
    the normal points away from the camera, else OCCLUDED or VISIBLE by ``hidden(points (n, 3),
    sensors (n, 3))``, whether the segment from each point towards where the camera images it
    from (a line scanner: its position at the point's line time) dips under the surface."""
    uv, depth = camera.project(points)
    inside = (depth > 0) & camera.in_image(uv)
    sensor = camera.origins(np.where(inside[..., None], uv, np.nan))
    with np.errstate(invalid="ignore"):
        facing = np.einsum("...i,...i->...", normals, sensor - points) > 0
    codes = np.full(inside.shape, Code.NODATA, np.uint8)
    codes[inside & ~facing] = Code.FACING_AWAY
    cast = inside & facing
    codes[cast] = np.where(hidden(points[cast], sensor[cast]), Code.OCCLUDED, Code.VISIBLE)
    return codes
