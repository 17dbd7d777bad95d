"""Which views can see a tile, before any tile is planned: a conservative index of the output
grid, so that planning a tile costs the views that can see it, not all of them.

The grid is cut into cells on a lattice of at most :data:`LATTICE` posts a side (a step of
``ceil(side / LATTICE)`` posts). Each view projects the lattice once, at the DEM's lowest and
highest values (the heights :func:`~orthomvp.engine.halo.image_box` samples a tile at); a
cell's box is the bounding box in pixels of its four corners at both heights, grown by
:data:`SLACK` of its size and one pixel for the bend of the projection within a cell (a frame
camera in the map frame maps a cell at one height to the quadrilateral of its corners: no bend
at all). A cell with a corner that the camera does not image in front of it (behind it, or no
pixel: a line scanner's ground beyond its lines), or next to one, has the whole image plane as
its box. A tile's box is then the bounding box of its cells' boxes: it holds every point that
``image_box`` samples in the tile, so a view whose tile box misses the image (as
:func:`orthomvp.engine.plan._sees` tests it) cannot be one that ``image_box`` finds seeing the
tile. Building the index costs ``(LATTICE + 1)^2`` projections a view at two heights, whatever
the grid; a tile's query, a few numpy reductions over its cells for all views at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from orthomvp.engine.grid import DemSource, WindowT
from orthomvp.engine.images import ImageSource

LATTICE = 128
"""Cells along the longer side of the grid (at most)."""

SLACK = 0.25
"""A cell's box grows by this share of its larger side (pixels), and by one pixel."""

ToDem = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _axis(n: int, step: int) -> np.ndarray:
    """Lattice positions 0, step, ... and the last post ``n - 1`` (two when n is 1)."""
    positions = np.unique(np.append(np.arange(0, n, step), n - 1))
    return positions if len(positions) > 1 else np.zeros(2, np.int64)


class ViewIndex:
    """Per view, the pixel box of every cell of the output grid (module docstring);
    :meth:`views` gives the views whose box of a window meets their image."""

    def __init__(
        self,
        dem: DemSource,
        to_dem: ToDem,
        shape: tuple[int, int],
        views: Sequence[ImageSource],
        margin: float,
    ) -> None:
        """Index the grid of ``shape`` (rows, cols; positions through ``to_dem`` to the DEM)
        for ``views``; a view meets a window when its box reaches within ``margin`` pixels
        of the image's outer pixel centres."""
        rows, cols = shape
        self.step = max(1, math.ceil(max(rows, cols) / LATTICE))
        self.shape = shape
        rr, cc = _axis(rows, self.step), _axis(cols, self.step)
        c, r = np.meshgrid(cc.astype(np.float64), rr.astype(np.float64))
        dc, dr = to_dem(c.ravel(), r.ravel())
        points = [dem.to_world(dc, dr, np.full(dc.shape, h)) for h in (dem.h_min, dem.h_max)]
        shape_cells = (len(rr) - 1, len(cc) - 1)
        n = len(views)
        self.low = np.empty((2, n, *shape_cells))  # (u, v) lowest per view and cell
        self.high = np.empty((2, n, *shape_cells))
        self.size = np.array([[view.width, view.height] for view in views], np.float64)
        self.margin = margin
        for k, view in enumerate(views):
            uv, depth = zip(*(view.camera.project(p) for p in points), strict=True)
            uv = np.stack(uv).reshape(2, len(rr), len(cc), 2)
            depth = np.stack(depth).reshape(2, len(rr), len(cc))
            good = (depth > 0) & np.isfinite(uv).all(axis=-1)  # (heights, rows, cols)
            corners = [uv[:, :-1, :-1], uv[:, 1:, :-1], uv[:, :-1, 1:], uv[:, 1:, 1:]]
            stack = np.concatenate(corners, axis=0)  # (8, cells r, cells c, 2)
            ok = np.concatenate(
                [good[:, :-1, :-1], good[:, 1:, :-1], good[:, :-1, 1:], good[:, 1:, 1:]]
            ).all(axis=0)
            ok = _erode(ok)
            with np.errstate(invalid="ignore"):
                lo, hi = stack.min(axis=0), stack.max(axis=0)  # (cells r, cells c, 2)
            grow = SLACK * (hi - lo).max(axis=-1, keepdims=True) + 1.0
            lo = np.where(ok[..., None], lo - grow, -np.inf)
            hi = np.where(ok[..., None], hi + grow, np.inf)
            self.low[:, k] = np.moveaxis(lo, -1, 0)
            self.high[:, k] = np.moveaxis(hi, -1, 0)

    def views(self, window: WindowT) -> np.ndarray:
        """Indices (ascending) of the views whose box of the posts of ``window`` (r0, r1, c0,
        c1) meets their image, ``margin`` pixels around."""
        r0, r1, c0, c1 = window
        last_r, last_c = self.low.shape[2] - 1, self.low.shape[3] - 1
        a, b = min(r0 // self.step, last_r), min((r1 - 1) // self.step, last_r) + 1
        c, d = min(c0 // self.step, last_c), min((c1 - 1) // self.step, last_c) + 1
        lo = self.low[:, :, a:b, c:d].min(axis=(2, 3)).T  # (views, 2)
        hi = self.high[:, :, a:b, c:d].max(axis=(2, 3)).T
        meets = (hi >= -self.margin) & (lo <= self.size - 1 + self.margin)
        return np.flatnonzero(meets.all(axis=1))

    def most(self, margin: int) -> Callable[[int], int]:
        """For a tile side (posts), the most views that can see one of the grid's tiles of
        that side grown by ``margin`` posts (as :meth:`views` finds them)."""

        def most(side: int) -> int:
            rows, cols = self.shape
            counts = [
                len(
                    self.views(
                        (
                            max(r - margin, 0),
                            min(r + side + margin, rows),
                            max(c - margin, 0),
                            min(c + side + margin, cols),
                        )
                    )
                )
                for r in range(0, rows, side)
                for c in range(0, cols, side)
            ]
            return max(counts, default=0)

        return most


def _erode(ok: np.ndarray) -> np.ndarray:
    """``ok`` (rows, cols) bool, False also next to (eight neighbours) a False cell."""
    out = ok.copy()
    pad = np.pad(ok, 1, constant_values=True)
    rows, cols = ok.shape
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            out &= pad[dr : dr + rows, dc : dc + cols]
    return out
