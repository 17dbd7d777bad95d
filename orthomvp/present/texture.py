"""A texture raster read at the posts of a DEM grid, whatever its own grid.

A raster on the DEM grid (the same shape, and the same georeference or none) is read as it is.
Any other georeferenced raster (finer, coarser, another extent or another CRS) is sampled at
the posts' map coordinates: the texel that holds the post's centre (nearest neighbour, as
rasterio's ``index`` and ``sample`` pick it), NaN where the post falls outside the raster or
on its no data. A raster without a georeference (an identity transform and no CRS) whose shape
differs from the DEM's cannot be placed: InputError naming both shapes.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning
from rasterio.windows import Window

from orthomvp.errors import InputError
from orthomvp.io.raster import open_raster, read_image, read_values

WINDOW_TEXELS = 1 << 24
"""Texels (at most, unless one post needs more) of one read of a sampled raster."""
IMAGE_SIDE = 4096
"""Texels a side (at most) of a mesh's image texture at a texture raster's own resolution."""


class TextureSampler:
    """The raster at ``path`` read at the posts of the DEM grid of ``shape`` (rows, cols),
    ``transform`` (its pixel corners; posts are pixel centres) and ``crs`` (a rasterio or
    pyproj CRS; the raster's own CRS, when it has one, may differ). ``what`` names the raster
    in messages. ``on_grid``: whether the raster is on the DEM grid (read as it is);
    ``count``: its bands."""

    def __init__(
        self,
        path: str | Path,
        shape: tuple[int, int],
        transform: Affine,
        crs: Any,
        what: str = "texture raster",
    ) -> None:
        self.path, self.shape, self.transform, self.what = Path(path), shape, transform, what
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with open_raster(self.path) as src:
                own_shape, own_transform, own_crs = (src.height, src.width), src.transform, src.crs
                self.count = src.count
        georeferenced = own_crs is not None or not own_transform.is_identity
        same = own_transform.almost_equals(transform) and (own_crs is None or own_crs == crs)
        self.on_grid = own_shape == tuple(shape) and (not georeferenced or same)
        if not self.on_grid and not georeferenced:
            raise InputError(
                f"{self.path}: the {what} ({own_shape[1]} x {own_shape[0]} px) has no "
                f"georeference and is not the DEM's size ({shape[1]} x {shape[0]} posts): give "
                "it a georeference, or resample it onto the DEM grid"
            )
        self._inverse = ~own_transform
        self._own_shape = own_shape
        self._to_own = None if own_crs is None else self._transformer(crs, own_crs)

    def _transformer(self, dem_crs: Any, own_crs: Any) -> Any:
        """A pyproj transformer from the DEM's CRS to the raster's (x, y order), or None when
        they are the same (horizontally); InputError when pyproj has none (another body)."""
        if dem_crs is None or own_crs == dem_crs:
            return None
        from pyproj import CRS, Transformer
        from pyproj.exceptions import ProjError

        source = CRS.from_user_input(dem_crs.to_wkt())
        target = CRS.from_user_input(own_crs.to_wkt())
        source, target = (c.sub_crs_list[0] if c.is_compound else c for c in (source, target))
        if source.equals(target, ignore_axis_order=True):
            return None
        try:
            return Transformer.from_crs(source, target, always_xy=True)
        except ProjError as exc:
            raise InputError(
                f"{self.path}: the {self.what}'s CRS ({target.name}) cannot be reached from "
                f"the DEM's ({source.name}): {' '.join(str(exc).split())}"
            ) from exc

    def read(self, r0: int, r1: int, bands: list[int]) -> np.ndarray:
        """``bands`` (1-based) at the posts of DEM rows ``r0`` to ``r1`` (all columns):
        float32 (len(bands), r1 - r0, cols), NaN outside the raster and on its no data."""
        cols = self.shape[1]
        if self.on_grid:
            with open_raster(self.path) as src:
                return read_values(src, bands, Window(0, r0, cols, r1 - r0), np.float32)
        r, c = np.mgrid[r0:r1, 0:cols]
        return self.at(c.ravel(), r.ravel(), bands).reshape(len(bands), r1 - r0, cols)

    def at(self, c: np.ndarray, r: np.ndarray, bands: list[int]) -> np.ndarray:
        """``bands`` at the DEM posts of columns ``c`` and rows ``r`` (integer arrays of one
        length n): float32 (len(bands), n), NaN outside the raster and on its no data."""
        x, y = (self.transform @ Affine.translation(0.5, 0.5)) @ (
            np.asarray(c, np.float64),
            np.asarray(r, np.float64),
        )
        if self._to_own is not None:
            x, y = self._to_own.transform(x, y)
        tc, tr = self._inverse @ (np.asarray(x), np.asarray(y))
        out = np.full((len(bands), len(tc)), np.nan, np.float32)
        rows, cols = self._own_shape
        with np.errstate(invalid="ignore"):
            inside = (tc >= 0) & (tc < cols) & (tr >= 0) & (tr < rows)
        where = np.flatnonzero(inside)
        if len(where):
            ci = np.floor(tc[where]).astype(np.int64)
            ri = np.floor(tr[where]).astype(np.int64)
            with open_raster(self.path) as src:
                _gather(src, bands, ri, ci, out, where)
        return out

    def grid(self) -> np.ndarray:
        """Every band at every post: float32 (count, rows, cols)."""
        return self.read(0, self.shape[0], list(range(1, self.count + 1)))

    def texels_per_post(self) -> float:
        """The raster's texels along one post spacing of the DEM grid, at the grid's centre
        (the mean of both directions): 1 on the DEM grid, 2 for a raster twice as fine."""
        if self.on_grid:
            return 1.0
        r, c = self.shape[0] // 2, self.shape[1] // 2
        x, y = (self.transform @ Affine.translation(0.5, 0.5)) @ (
            np.array([c, c + 1, c], np.float64),
            np.array([r, r, r + 1], np.float64),
        )
        if self._to_own is not None:
            x, y = self._to_own.transform(x, y)
        tc, tr = self._inverse @ (np.asarray(x), np.asarray(y))
        return float(np.mean(np.hypot(tc[1:] - tc[0], tr[1:] - tr[0])))


def on_dem_grid(path: str | Path, terrain: Any, what: str = "texture raster") -> np.ndarray:
    """The raster at ``path`` on the grid of ``terrain`` (a
    :class:`~orthomvp.geometry.terrain.Terrain`): read as it is when it is on it
    (:func:`~orthomvp.io.raster.read_image`), else sampled at the posts
    (:class:`TextureSampler`); float32 (bands, rows, cols), NaN where it has no value."""
    sampler = TextureSampler(path, terrain.shape, terrain.transform, terrain.crs, what)
    return read_image(path) if sampler.on_grid else sampler.grid()


def finer_grid(path: str | Path, terrain: Any) -> np.ndarray | None:
    """The raster at ``path`` sampled on the grid of ``terrain`` refined ``k`` times (each
    post's cell cut into k x k texels, over the DEM grid's extent), ``k`` its texels per post
    rounded and at most :data:`IMAGE_SIDE` texels a side: float32 (bands, k * rows, k * cols)
    of its first 3 bands,
    NaN where it has no value; None when ``k`` < 2 (a raster no finer than the DEM)."""
    rows, cols = terrain.shape
    sampler = TextureSampler(path, terrain.shape, terrain.transform, terrain.crs)
    k = min(round(sampler.texels_per_post()), IMAGE_SIDE // max(rows, cols))
    if k < 2:
        return None
    fine = terrain.transform @ Affine.scale(1 / k)
    bands = list(range(1, min(sampler.count, 3) + 1))  # what the colours take
    return TextureSampler(path, (k * rows, k * cols), fine, terrain.crs).read(0, k * rows, bands)


def _gather(
    src: Any, bands: list[int], ri: np.ndarray, ci: np.ndarray, out: np.ndarray, where: np.ndarray
) -> None:
    """``out[:, where]`` = ``bands`` of the open raster ``src`` at its pixels (``ri``, ``ci``),
    read in windows of at most :data:`WINDOW_TEXELS` texels (the points halved, in their order,
    until each half's bounding window fits)."""
    r0, r1, c0, c1 = ri.min(), ri.max() + 1, ci.min(), ci.max() + 1
    if (r1 - r0) * (c1 - c0) > WINDOW_TEXELS and len(ri) > 1:
        half = len(ri) // 2
        _gather(src, bands, ri[:half], ci[:half], out, where[:half])
        _gather(src, bands, ri[half:], ci[half:], out, where[half:])
        return
    data = read_values(src, bands, Window(c0, r0, c1 - c0, r1 - r0), np.float32)
    out[:, where] = data[:, ri - r0, ci - c0]
