"""Rendering the images of a synthetic scene: rays cast on a mesh finer than the DEM, each hit
shaded with the analytic Lambertian radiance, supersampled."""

from __future__ import annotations

import numpy as np
from affine import Affine

from orthomvp.camera import Camera
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.synthetic.surface import LocalSurface
from orthomvp.validate import number

FINE_FACTOR = 3
"""Posts of the rendering surface per DEM post, along each axis."""
MAX_SUPERSAMPLE = 16
"""Most rays per pixel side (256 per pixel)."""
FINE_MARGIN = 0.6
"""Extra width of the rendering surface on each side, as a fraction of the DEM's size."""


def fine_terrain(surface: LocalSurface, terrain: Terrain) -> Terrain:
    """``surface`` sampled :data:`FINE_FACTOR` times finer than the DEM ``terrain`` (whose grid
    and CRS it keeps), :data:`FINE_MARGIN` of its size wider on each side."""
    factor, margin = FINE_FACTOR, FINE_MARGIN
    rows, cols = terrain.shape
    n_r, n_c = int(rows * (1 + 2 * margin) * factor), int(cols * (1 + 2 * margin) * factor)
    tr = terrain.transform
    corner_x, corner_y = tr.c - margin * cols * tr.a, tr.f - margin * rows * tr.e
    fine = Affine(tr.a / factor, 0, corner_x, 0, tr.e / factor, corner_y)
    ft = Terrain(np.zeros((n_r, n_c)), fine, terrain.crs)
    x, y = surface.lonlat_to_local(*ft.pixel_to_lonlat(*ft.grid()))
    return ft.with_values(surface.height(x, y))


def render_image(
    surface: LocalSurface, caster: RayCaster, camera: Camera, supersample: int = 3
) -> np.ndarray:
    """The image (rows, cols) float32 that ``camera`` (with its image size) takes of
    ``surface``: per pixel the mean radiance of ``supersample`` x ``supersample`` rays cast on
    ``caster``'s mesh of the surface (0 where a ray hits nothing), each from its own origin
    (a line scanner's sub-pixel rows from the sensor positions of their times)."""
    w, h = camera.width, camera.height
    k = number(
        supersample,
        "supersample (rays per pixel side)",
        minimum=1,
        maximum=MAX_SUPERSAMPLE,
        integer=True,
    )
    offs = (np.arange(k) + 0.5) / k - 0.5
    out = np.zeros(h * w, np.float64)
    rows_per = max(1, 200_000 // (w * k * k))
    for r0 in range(0, h, rows_per):
        rr, cc = np.mgrid[r0 : min(r0 + rows_per, h), 0:w].astype(np.float64)
        uv = np.stack([cc.ravel(), rr.ravel()], axis=-1)
        sub = uv[:, None, None, :] + np.stack(np.meshgrid(offs, offs, indexing="xy"), -1)
        o, d = camera.ray(sub.reshape(-1, 2))
        hits = caster.first_hit(o, d, invalid="miss")
        val = np.zeros(len(d))
        if hits.mask.any():
            hx, hy, _ = surface.world_to_local(hits.points[hits.mask])
            val[hits.mask] = surface.radiance(hx, hy)
        out[r0 * w : r0 * w + uv.shape[0]] = val.reshape(-1, k * k).mean(axis=1)
    return out.reshape(h, w).astype(np.float32)
