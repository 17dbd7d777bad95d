"""The occluder surface of a DEM as the visibility test meets it: a ray caster on
:func:`~orthomvp.mesh.occluder_mesh`, built on first need, and a proof from the DEM's heights
alone that a ray meets the surface nowhere far from its post, so that most posts need no ray.

The proof (map world frame, a ray straight from a camera centre C to a post P; heights along
z). Along the ground track from P towards C, at horizontal distance s, the ray stands at
``z_P + s t`` with ``t = (z_C - z_P) / |C - P|`` (horizontal distance). The occluder surface
over a ground point is no higher than the highest post of its cell (its heights are post
heights, means of two or maxima). Within ``s <= (k - 1) p`` of P (``p`` the smaller post
spacing) the track stays within ``k - 1/2`` posts, along rows and columns, of the post nearest
P, over cells whose corners lie within ``k`` posts of it: there the surface is no higher than
the highest post of that box. Where the ray at ``s_a`` stands above that height, it meets
nothing from ``s_a`` to ``s_b = (k - 1) p``. Stretches bounded by the
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
from orthomvp.mesh import occluder_mesh
from orthomvp.raycast import Hits, RayCaster
from orthomvp.terrain import Terrain

RADII = (4, 8, 16, 32, 64)
"""Half-widths, in posts, of the boxes whose highest posts bound the track's stretches."""
BOUND_BYTES = 4 * len(RADII)
"""Memory of the proof's height bounds per DEM post, bytes (float32 per radius)."""
CLEARANCE = 1e-5
"""Height by which a ray must clear a bound, as a fraction of the DEM's extent (1 cm a km;
float32 casting errs by about 1e-7 of it)."""


class Occluders:
    """The occluder surface of ``terrain`` (a DEM or a window of one): :meth:`first_hit` casts
    on its :func:`~orthomvp.mesh.occluder_mesh` (built, with its ray caster on ``threads``, at
    the first cast), :meth:`clear` proves rays clear without one. ``mesh_seconds`` is the time
    spent meshing."""

    def __init__(self, terrain: Terrain, *, threads: int | None = None) -> None:
        self.terrain = terrain
        self.threads = threads
        self.mesh_seconds = 0.0
        self._caster: RayCaster | None = None
        self._lock = threading.Lock()

    @property
    def caster(self) -> RayCaster:
        """The ray caster on the occluder mesh, built on first use."""
        with self._lock:
            if self._caster is None:
                start = time.perf_counter()
                self._caster = RayCaster(occluder_mesh(self.terrain), threads=self.threads)
                self.mesh_seconds += time.perf_counter() - start
            return self._caster

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """:meth:`orthomvp.raycast.RayCaster.first_hit` on the occluder mesh."""
        return self.caster.first_hit(origins, directions)

    @property
    def provable(self) -> bool:
        """Whether :meth:`clear` can prove anything: the map world frame, heights along z."""
        return self.terrain.world == WorldFrame.MAP

    @cached_property
    def _bounds(self) -> tuple[float, list[np.ndarray], float]:
        """The highest post, the highest post within each of :data:`RADII` posts (rows and
        columns) of every post (float32, rounded up; holes lowest), and the clearance."""
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
        rows, cols = v.shape
        x, y = self.terrain.pixel_to_crs(np.array([0.0, cols - 1.0]), np.array([0.0, rows - 1.0]))
        extent = float(np.hypot(np.ptp(x), np.ptp(y))) + float(np.nanmax(np.abs(v), initial=0))
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
        proven = np.zeros(n, bool)
        if not self.provable or n == 0:
            return proven
        top, boxes, clearance = self._bounds
        rows, cols = self.terrain.shape
        c, r = self.terrain.crs_to_pixel(points[:, 0], points[:, 1])
        ground = np.hypot(centre[0] - points[:, 0], centre[1] - points[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = (centre[2] - points[:, 2]) / ground
            slope[(ground == 0) & (centre[2] > points[:, 2])] = np.inf
            ok = (slope > 0) & (c > -0.5) & (c < cols - 0.5) & (r > -0.5) & (r < rows - 0.5)
        todo = np.flatnonzero(ok)
        ri = np.rint(r[todo]).astype(np.intp)
        ci = np.rint(c[todo]).astype(np.intp)
        start = np.broadcast_to(np.asarray(reach, dtype=np.float64), (n,))[todo]
        z, slope = points[todo, 2], slope[todo]
        S = self.terrain.S  # (a grid is never rotated: Terrain refuses it)
        post = min(abs(S[0, 0]), abs(S[1, 1]))  # world units: the map frame's
        for radius, box in zip(RADII, boxes, strict=True):
            height = z + start * slope  # the ray where the stretch begins
            above = height > top + clearance
            proven[todo[above]] = True
            end = (radius - 1) * post  # the stretch up to here lies over the box
            within = start < end
            keep = ~above & (~within | (height > box[ri, ci] + clearance))
            todo, ri, ci, z, slope = todo[keep], ri[keep], ci[keep], z[keep], slope[keep]
            start = np.maximum(start[keep], end)
            if not todo.size:
                return proven
        proven[todo[z + start * slope > top + clearance]] = True
        return proven
