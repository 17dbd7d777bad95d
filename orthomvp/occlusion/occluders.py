"""The occluder surface of a DEM as the visibility test meets it: a ray caster on
:func:`~orthomvp.occlusion.mesh.occluder_mesh`, built on first need, and a proof from the DEM's
heights alone that a ray meets the surface nowhere far from its post, so that most posts need no
ray.

The proof (map world frame, a ray straight from a camera centre C to a post P; heights along
z). Along the ground track from P towards C, at horizontal distance s, the ray stands at
``z_P + s t`` with ``t = (z_C - z_P) / |C - P|`` (horizontal distance). The occluder surface
over a ground point is no higher than the highest post of its cell (its heights are post
heights, means of two or maxima). Within ``s <= (k - 1/2) p`` of P (``p`` the smaller post
spacing) the track stays within ``k`` posts, along rows and columns, of the post nearest P
(half a post away at most), over cells whose corners lie within ``k`` posts of it (or on the
edge of such a cell, whose heights are those of its own two posts): there the surface is no
higher than the highest post of that box. Where the ray at ``s_a`` stands above that height,
it meets nothing from ``s_a`` to ``s_b = (k - 1/2) p``. Stretches bounded by the
boxes of :data:`RADII` posts, then the DEM's highest post, cover the track from a ``reach``
``s_0`` on: a ray proved clear can meet the surface only within ``s_0`` of P, horizontally, or
beyond P. The heights are rounded up to float32 and the ray must clear them by
:data:`CLEARANCE` of the DEM's size, far above the float32 casting's error.
"""

from __future__ import annotations

import threading
import time
from functools import cached_property

import cv2
import numpy as np

from orthomvp.codes import WorldFrame
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import occluder_mesh
from orthomvp.occlusion.raycast import Hits, RayCaster

RADII = (4, 8, 16, 32, 64)
"""Half-widths, in posts, of the boxes whose highest posts bound the track's stretches."""
BOUND_BYTES = 4 * len(RADII)
"""Memory of the proof's height bounds per DEM post, bytes (float32 per radius)."""
CLEARANCE = 1e-5
"""Height by which a ray must clear a bound, as a fraction of the DEM's extent (1 cm a km;
float32 casting errs by about 1e-7 of it)."""


PART_BUDGET = 0.75
"""What the meshes of parts of a surface may cost in all, as a share of its whole mesh's,
before the whole is meshed instead (:meth:`Occluders.cast_from`)."""
PART_PREP = 0.2
"""The share of a mesh's cost that goes with its window's posts (the steps and the fine
grid); the rest goes with the cells it triangulates (triangles and the BVH)."""
TRACK_SAMPLES = 4
"""Samples of the rays' tracks, per cell of the surface, beyond which the whole surface is
meshed instead of the cells the tracks pass over (their arrays take about 40 bytes a sample;
sampling costs less than meshing below about 15 a cell)."""


def _box(where: np.ndarray) -> tuple[int, int, int, int] | None:
    """The cells (r0, r1, c0, c1) around the True cells of ``where``, grown by one (a cell's
    split depends on its neighbours': :func:`~orthomvp.occlusion.mesh.occluder_mesh`); None without
    one."""
    rows = np.flatnonzero(where.any(axis=1))
    if not rows.size:
        return None
    cols = np.flatnonzero(where.any(axis=0))
    height, width = where.shape
    return (
        max(int(rows[0]) - 1, 0),
        min(int(rows[-1]) + 2, height),
        max(int(cols[0]) - 1, 0),
        min(int(cols[-1]) + 2, width),
    )


def _area(box: tuple[int, int, int, int]) -> int:
    """Cells in ``box`` (r0, r1, c0, c1)."""
    return (box[1] - box[0]) * (box[3] - box[2])


class Occluders:
    """The occluder surface of ``terrain`` (a DEM or a window of one): :meth:`first_hit` casts
    on its :func:`~orthomvp.occlusion.mesh.occluder_mesh` (built, with its ray caster on
    ``threads``, at the first cast), :meth:`cast_from` on the cells that rays from a camera centre
    can meet,
    :meth:`clear` proves rays clear without a mesh. ``mesh_seconds`` is the time spent
    meshing."""

    def __init__(self, terrain: Terrain, *, threads: int | None = None) -> None:
        self.terrain = terrain
        self.threads = threads
        self.mesh_seconds = 0.0
        self._caster: RayCaster | None = None
        self._meshed = 0.0  # the cost of the parts meshed so far, in cells
        self._lock = threading.Lock()
        self._count = threading.Lock()
        self._bounding = threading.Lock()
        self._bounded: tuple[float, list[np.ndarray], float] | None = None

    @property
    def caster(self) -> RayCaster:
        """The ray caster on the whole occluder mesh, built on first use."""
        with self._lock:
            if self._caster is None:
                self._caster = self._mesh()
            return self._caster

    def first_hit(
        self, origins: np.ndarray, directions: np.ndarray, *, invalid: str = "miss"
    ) -> Hits:
        """:meth:`orthomvp.occlusion.raycast.RayCaster.first_hit` on the occluder mesh (rays
        a camera cannot map are misses by default)."""
        return self.caster.first_hit(origins, directions, invalid=invalid)

    def cast_from(self, centre: np.ndarray, points: np.ndarray, beyond: float) -> Hits:
        """:meth:`first_hit` of the rays from ``centre`` (3,) through ``points`` (n, 3), map
        world frame, up to ``beyond`` (world units) past them: the same hits, cast on a mesh
        of only the cells they pass over, from ``beyond`` past their point (horizontally) to
        where they rise above the highest post (:meth:`track_cells`), while such meshes cost
        less than the whole one (:data:`PART_BUDGET`; then on the whole, built once)."""
        centre = np.asarray(centre, dtype=np.float64)
        points = np.asarray(points, dtype=np.float64)
        if self._caster is None and self.provable:
            where = self.track_cells(centre, points, beyond)
            box = None if where is None else _box(where)
            with self._lock:
                part = box is not None and self._caster is None
                if part:
                    cost = PART_PREP * _area(box) + (1 - PART_PREP) * int(where.sum())
                    part = self._meshed + cost <= PART_BUDGET * where.size
                    self._meshed += cost if part else 0
            if part:
                caster = self._part(where, box)
                if caster is None:  # no triangle there: nothing to meet
                    return Hits.none(len(points))
                return caster.first_hit(centre, points - centre, invalid="miss")
        return self.first_hit(centre, points - centre)

    def track_cells(
        self, centre: np.ndarray, points: np.ndarray, beyond: float
    ) -> np.ndarray | None:
        """The cells (rows - 1, cols - 1) bool that the rays from ``centre`` to ``points``
        (map world frame) pass over from ``beyond`` past their point to where they stand above
        the highest post, within the grid; None (every cell) for a ray from below its point,
        or tracks longer in all than :data:`TRACK_SAMPLES` times the cells. The tracks are
        sampled at most a post apart, so the cells between samples are next to theirs."""
        top, _, clearance = self._bounds
        rows, cols = self.terrain.shape
        c, r = self.terrain.crs_to_pixel(points[:, 0], points[:, 1])
        cc, cr = self.terrain.crs_to_pixel(centre[0], centre[1])
        dc, dr = cc - c, cr - r  # to the centre's ground point, in posts
        rise = centre[2] - points[:, 2]
        if not (rise > 0).all():
            return None
        back = beyond / self._post + 1  # posts past the point
        steps = np.maximum(np.abs(dc), np.abs(dr))  # posts to the centre's ground point
        with np.errstate(divide="ignore", invalid="ignore"):
            end = np.clip((top + clearance - points[:, 2]) / rise, 0, 1)  # of the way there
            start = np.where(steps > 0, -back / steps, 0.0)
            for p, d, size in ((c, dc, cols), (r, dr, rows)):  # cut to the grid (and a post)
                low, high = (-1 - p) / d, (size - p) / d
                start = np.where(d == 0, start, np.maximum(start, np.fmin(low, high)))
                end = np.where(d == 0, end, np.minimum(end, np.fmax(low, high)))
        n = np.where(end >= start, np.ceil((end - start) * steps) + 2, 0).astype(np.intp)
        if n.sum() > TRACK_SAMPLES * (rows - 1) * (cols - 1):
            return None
        first = np.cumsum(n) - n
        ray = np.repeat(np.arange(len(n)), n)
        k = np.arange(n.sum()) - first[ray]
        f = start[ray] + k * ((end - start) / np.maximum(n - 1, 1))[ray]
        where = np.zeros((rows - 1, cols - 1), np.uint8)
        sc = np.clip(np.floor(c[ray] + f * dc[ray]), 0, cols - 2).astype(np.intp)
        sr = np.clip(np.floor(r[ray] + f * dr[ray]), 0, rows - 2).astype(np.intp)
        where[sr, sc] = 1
        return cv2.dilate(where, np.ones((3, 3), np.uint8)).view(bool)

    @cached_property
    def _extent(self) -> tuple[np.ndarray, np.ndarray]:
        """The lowest and highest (x, y, height) of the surface's posts, map frame."""
        v = self.terrain.values
        rows, cols = v.shape
        x, y = self.terrain.pixel_to_crs(np.array([0.0, cols - 1.0]), np.array([0.0, rows - 1.0]))
        return (
            np.array([x.min(), y.min(), np.nanmin(v)]),
            np.array([x.max(), y.max(), np.nanmax(v)]),
        )

    @cached_property
    def _post(self) -> float:
        """The smaller post spacing, world units (the map frame's; a grid is never rotated:
        Terrain refuses it)."""
        S = self.terrain.S
        return min(abs(S[0, 0]), abs(S[1, 1]))

    @cached_property
    def _frame(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None:
        """The origin and local box of every mesh of this surface in the map world frame, so
        that a mesh of part of it casts as the whole does (None elsewhere: each mesh its
        own): the middle and the extent of the grid and its heights."""
        if not self.provable:
            return None
        low, high = self._extent
        origin = (low + high) / 2
        return origin, (low - origin, high - origin)

    def _part(self, where: np.ndarray, box: tuple[int, int, int, int]) -> RayCaster | None:
        """A ray caster on the cells ``where`` of the occluder mesh (None when they hold no
        triangle): the mesh of the posts around them (``box``, :func:`_box`), cut to them."""
        r0, r1, c0, c1 = box
        try:  # (a box of holes: no heights, or no triangle, to mesh)
            return self._mesh(self.terrain.crop(r0, r1 + 1, c0, c1 + 1), where[r0:r1, c0:c1])
        except InputError:
            return None

    def _mesh(self, terrain: Terrain | None = None, where: np.ndarray | None = None) -> RayCaster:
        """A ray caster on the occluder mesh of ``terrain`` (default the whole surface), of
        the cells ``where`` only when given."""
        start = time.perf_counter()
        terrain, frame = terrain or self.terrain, self._frame
        if frame is None:
            caster = RayCaster(occluder_mesh(terrain), threads=self.threads)
        else:
            origin, bounds = frame
            mesh = occluder_mesh(terrain, origin, where=where)
            caster = RayCaster(mesh, threads=self.threads, bounds=bounds)
        seconds = time.perf_counter() - start
        with self._count:
            self.mesh_seconds += seconds
        return caster

    @property
    def provable(self) -> bool:
        """Whether :meth:`clear` can prove anything: the map world frame, heights along z."""
        return self.terrain.world == WorldFrame.MAP

    @property
    def _bounds(self) -> tuple[float, list[np.ndarray], float]:
        """The highest post, the highest post within each of :data:`RADII` posts (rows and
        columns) of every post (float32, rounded up; holes lowest), and the clearance;
        computed once, whatever the threads asking."""
        with self._bounding:
            if self._bounded is None:
                self._bounded = self._height_bounds()
            return self._bounded

    def _height_bounds(self) -> tuple[float, list[np.ndarray], float]:
        """:attr:`_bounds`, computed."""
        v = self.terrain.values
        up = v.astype(np.float32)
        up = np.where(up < v, np.nextafter(up, np.float32(np.inf)), up)
        up[np.isnan(v)] = -np.inf
        top = float(np.max(up))
        boxes, done = [], 0
        for radius in RADII:  # each box the last one's grown by the difference
            grow = 2 * (radius - done) + 1
            boxes.append(cv2.dilate(boxes[-1] if boxes else up, np.ones((grow, grow), np.uint8)))
            done = radius
        low, high = self._extent
        extent = float(np.hypot(*(high - low)[:2])) + float(np.nanmax(np.abs(v), initial=0))
        return top, boxes, CLEARANCE * extent

    def clear(
        self, points: np.ndarray, centre: np.ndarray, reach: np.ndarray | float
    ) -> np.ndarray:
        """Which rays from the camera centre ``centre`` (3,) to ``points`` (n, 3), world
        frame, provably meet the surface nowhere more than ``reach`` (metres, horizontally;
        scalar or (n,)) before their point, bool (n,). See the module docstring; False for
        points off the DEM or not below the centre, and everywhere off the map world frame."""
        points = np.asarray(points, dtype=np.float64)
        n = len(points)
        if not self.provable or n == 0:
            return np.zeros(n, bool)
        top, boxes, clearance = self._bounds
        rows, cols = self.terrain.shape
        c, r = self.terrain.crs_to_pixel(points[:, 0], points[:, 1])
        z = points[:, 2]
        ground = np.hypot(centre[0] - points[:, 0], centre[1] - points[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = (centre[2] - z) / ground  # inf straight below the centre
            proven = (slope > 0) & (c > -0.5) & (c < cols - 0.5) & (r > -0.5) & (r < rows - 0.5)
        post = np.where(proven, np.rint(r) * cols + np.rint(c), 0).astype(np.intp)
        start = np.asarray(reach, dtype=np.float64)
        with np.errstate(invalid="ignore"):  # (0 * inf: not proved)
            for radius, box in zip(RADII, boxes, strict=True):
                end = (radius - 0.5) * self._post  # the stretch up to here lies over the box
                bound = np.take(box.ravel(), post) + clearance  # (no higher than the top)
                proven &= (start >= end) | (z + start * slope > bound)
                start = np.maximum(start, end)
            proven &= z + start * slope > top + clearance
        return proven
