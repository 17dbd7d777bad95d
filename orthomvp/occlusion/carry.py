"""Codes carried from a DEM's posts to a finer grid resampled from it (see
:func:`orthomvp.occlusion.visibility.compute_visibility`'s ``dem``): a grid post inside the
image and facing the camera whose four surrounding DEM posts are all visible, or all occluded,
takes that code without a ray of its own. :func:`dem_window` says which DEM posts to classify,
:class:`DemCodes` holds their codes and carries them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.codes import Code
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import perimeter
from orthomvp.occlusion.post_geometry import PostGeometry


def dem_window(grid: Terrain, dem: Terrain) -> tuple[int, int, int, int]:
    """The DEM posts (r0, r1, c0, c1) under ``grid``, with two posts around them, within the
    DEM: the posts next to a grid post then have the central-difference normals of the whole
    DEM, so their codes do not depend on the window (or on how a larger grid was tiled)."""
    c, r = perimeter((0, grid.shape[0], 0, grid.shape[1]))
    # a post off the DEM has no height; its position on the DEM does not need one (both CRSs
    # are of one body, and a height moves a point along its vertical only)
    values = grid.values[r.astype(int), c.astype(int)]
    values = np.where(np.isfinite(values), values, 0.0)
    dc, dr = dem_pixels(grid, dem, c, r, values)
    rows, cols = dem.shape
    r0 = int(np.clip(np.floor(np.nanmin(dr, initial=np.inf)) - 2, 0, rows))
    r1 = int(np.clip(np.floor(np.nanmax(dr, initial=-np.inf)) + 4, 0, rows))
    c0 = int(np.clip(np.floor(np.nanmin(dc, initial=np.inf)) - 2, 0, cols))
    c1 = int(np.clip(np.floor(np.nanmax(dc, initial=-np.inf)) + 4, 0, cols))
    return r0, r1, c0, c1


@dataclass(frozen=True)
class DemCodes:
    """Visibility codes of the DEM posts under a finer grid: ``codes`` of the window of
    ``dem`` (:func:`dem_window`) whose first post is DEM post (``r0``, ``c0``)."""

    dem: Terrain
    codes: np.ndarray
    r0: int
    c0: int

    def kernel_args(self) -> dict[str, object]:
        """The codes as :func:`orthomvp.occlusion.post_geometry_kernel.classify_tile` takes them."""
        return {"dem_codes": self.codes, "dem": self.dem, "dem_first": (self.r0, self.c0)}

    def at(self, grid: Terrain, rs: slice, cs: slice, g: PostGeometry) -> np.ndarray:
        """Codes carried to the grid posts of tile (``rs``, ``cs``) whose geometry is ``g``:
        VISIBLE or OCCLUDED where all four surrounding DEM posts agree on it, else 0."""
        if grid.crs == self.dem.crs:
            # neither grid is rotated (Terrain refuses it), so DEM columns follow from grid
            # columns alone and rows from rows: Terrain.pixel_to_crs and crs_to_pixel without
            # their zero terms (adding zero is exact: the same values)
            S, Si = grid.S, np.linalg.inv(self.dem.S)
            c = np.arange(cs.start, cs.stop, dtype=np.float64)[None, :]
            r = np.arange(rs.start, rs.stop, dtype=np.float64)[:, None]
            dc = Si[0, 0] * (S[0, 0] * c + S[0, 2]) + Si[0, 2]
            dr = Si[1, 1] * (S[1, 1] * r + S[1, 2]) + Si[1, 2]
        else:
            r, c = np.mgrid[rs, cs].astype(np.float64)
            dc, dr = dem_pixels(grid, self.dem, c, r, p=g.points(np.ones(c.shape, bool)))
            dc, dr = dc.reshape(c.shape), dr.reshape(c.shape)  # (the points come flat)
        rows, cols = self.codes.shape
        if rows < 2 or cols < 2:  # no DEM cell under the grid: nothing to carry
            return np.zeros(np.broadcast_shapes(dc.shape, dr.shape), np.uint8)
        with np.errstate(invalid="ignore"):
            i, j = np.floor(dr) - self.r0, np.floor(dc) - self.c0
            ok = (i >= 0) & (i < rows - 1) & (j >= 0) & (j < cols - 1)
        # the four DEM posts around each grid post, gathered from the flat codes
        at = np.where(ok, i * cols + j, 0).astype(np.intp)
        flat = self.codes.ravel()
        first = flat[at]
        agree = ok & ((first == Code.VISIBLE) | (first == Code.OCCLUDED))
        for step in (1, cols, cols + 1):
            agree &= flat[at + step] == first
        return np.where(agree, first, 0).astype(np.uint8)


def dem_pixels(
    grid: Terrain,
    dem: Terrain,
    c: np.ndarray,
    r: np.ndarray,
    values: np.ndarray | None = None,
    p: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """DEM pixel positions (c, r) of grid posts (``c``, ``r``): through the CRS when both
    grids share it, else through their world points ``p`` (or those of ``values``)."""
    if grid.crs == dem.crs:
        return dem.crs_to_pixel(*grid.pixel_to_crs(c, r))
    if p is None:
        p = grid.to_world(c, r, values)
    dc, dr, _ = dem.from_world(p)
    return dc, dr
