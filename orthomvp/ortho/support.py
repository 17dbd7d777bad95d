"""Whether a view's sample at a post reaches an occluder in the image: the mosaic's margin in
image space from the occlusion boundary.

A post's value from a view is a bilinear sample of the four pixels around its image position,
and each pixel integrates its own footprint: the sample reaches about 1.5 pixels around the
position. A post whose own ray is clear can still have an occluder (a roof edge, a wall top,
a crown) within that reach in the image, just beside its line of sight: part of its value is
then the occluder's (a partial ghost), most often at wall feet, where the visible ground
starts just past a roof edge's shadow. The test casts the rays through the four points
:data:`OFFSET` pixels diagonally from the post's position on the occluder surface the
visibility test casts on, and calls the sample blocked where one of them first hits the surface
nearer the camera than the post and more than :data:`REACH` DEM posts from it (horizontally,
as the visibility test's misses): a wall rising at the post's own foot is not an occluder.

The mosaic (:func:`orthomvp.ortho.composite.trusted`) then prefers, among the views it trusts
at a post, those whose sample is not blocked; where every view's is, it takes them as before,
so no post is lost. On the city with exact truth this halves the share of the posts taken from
each view whose sample has any occluder in it (docs/mosaics.md).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from orthomvp.camera import Camera
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.occlusion.occluders import Occluders
    from orthomvp.occlusion.raycast import RayCaster

OFFSET = 1.5
"""Pixels from a post's image position, along each image axis, of the four support rays (the
bilinear taps' pixels reach 1.5 pixels; on the city 1.5 leaves fewer partial ghosts than 1 or
2)."""

DIRECTIONS = ((-1, -1), (1, -1), (-1, 1), (1, 1))
"""Directions of the support rays in the image (u, v), :data:`OFFSET` pixels along each axis
(the four axis directions as well change nothing on the city)."""

REACH = 2.0
"""DEM posts (horizontal) beyond which a support ray's first hit nearer the camera than the
post is an occluder."""


def blocked(
    grid: Terrain,
    inner: tuple[slice, slice],
    camera: Camera,
    uv: np.ndarray,
    test: np.ndarray,
    caster: RayCaster | Occluders,
    *,
    post_scale: float = 1.0,
) -> np.ndarray:
    """Where (rows, cols) the sample of ``camera`` at the posts ``inner`` of ``grid`` (image
    positions ``uv`` (rows, cols, 2)) reaches an occluder (module docstring), tested at the
    posts ``test`` (rows, cols) only (False elsewhere); ``caster`` casts on the occluder
    surface; ``post_scale`` the size of a grid post in DEM posts."""
    out = np.zeros(test.shape, bool)
    if not test.any():
        return out
    rows, cols = np.nonzero(test)
    points = grid.world_points()[inner][rows, cols]
    at = uv[rows, cols]
    for du, dv in DIRECTIONS:
        o, d = camera.ray(at + OFFSET * np.array([du, dv]))
        unit = d / np.linalg.norm(d, axis=1, keepdims=True)
        along = np.einsum("ij,ij->i", points - o, unit)
        hits = caster.first_hit(o, unit, invalid="miss")
        front = hits.mask & (hits.distance < along)
        if not front.any():
            continue
        hc, hr, _ = grid.from_world(hits.points[front])
        post_r = rows[front] + (inner[0].start or 0)
        post_c = cols[front] + (inner[1].start or 0)
        far = np.hypot(hc - post_c, hr - post_r) * post_scale > REACH
        out[rows[front][far], cols[front][far]] = True
    return out
