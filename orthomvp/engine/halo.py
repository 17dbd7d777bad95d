"""The occluder halo: the DEM posts that can hide a tile's posts from a camera.

The bound. An occluder is a point of the surface that visibility casts on (the DEM mesh with
its steps made walls, :func:`orthomvp.occlusion.mesh.occluder_mesh`, whose vertices are posts or
lie on their cells at a post's height or the mean of two), so its height is at most ``h_max``, the
DEM's highest value. The set O of points no higher than ``h_max`` is convex: the half-space
``z <= h_max`` in the map frame, the ball of radius ``R + h_max`` on a sphere (``h_max`` itself
with radius values), and the ellipsoid grown by ``h_max`` (a parallel body of a convex body) on
an ellipsoid. A post p can only be hidden by surface on its line of sight towards the camera C
while that line is inside O: the segment from p to where the line leaves O (or to C, when C is
inside O). Posts are taken at the DEM's lowest value ``h_min``: a lower start at the same map
position has a line of sight below the true one in the same vertical plane (both end at C), so
it leaves O later along the same ground track, and its track contains the true one.

On a sphere of radius R the exit is exact; as a distance: a line of sight at elevation e above
the local horizontal rises above the surface by about ``s tan(e) + s^2 / (2R)`` over the arc
distance s, so occluders lie within ``s* = R (sqrt(tan(e)^2 + 2 (h_max - h_post) / R) - tan(e))``,
finite even for grazing lines (e <= 0). In the map frame ``s* = (h_max - h_post) / tan(e)``,
bounded only by the camera itself as e goes to 0.

A tile's window is the bounding box, in DEM posts, of the ground tracks of its perimeter posts
(each sampled at :data:`TRACK_SAMPLES` points from the post to its exit and mapped back to the
grid), widened by :data:`HALO_MARGIN` posts for the triangles around a hit and the slight bend
of a track between samples. The tracks of the tile's interior posts lie between those of its
perimeter (the exit moves smoothly with the post).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from orthomvp.camera import Camera, PinholeCamera, sensor_positions
from orthomvp.codes import WorldFrame
from orthomvp.engine.grid import DemSource, WindowT
from orthomvp.geometry.crs import geocentric_transformer
from orthomvp.geometry.vectors import perimeter

TRACK_SAMPLES = 9
"""Points per ground track (from the post to where its line of sight leaves O)."""

HALO_MARGIN = 2
"""Posts added around every window."""

DENSE = 33
"""Lattice points a side where a camera does not image part of a tile (:func:`image_box`)."""

BISECTIONS = 40
"""Bisection steps for the exit from O on an ellipsoid (the exit to 2^-40 of its bracket)."""

BATCH_POSTS = 1 << 13
"""Posts sampled (perimeters and lattices) in one run of tiles that planning projects at once
for every view: small enough that a run's arrays stay in cache (60 tiles of 256 posts x 64
views, boxes and halos: 1.7-2.1 s of CPU in runs of 2^12 to 2^14 posts, 7-9 s in 2^15,
3.2-3.6 s tile by tile)."""

ToDem = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
Box = tuple[float, float, float, float]
"""Where a tile can appear in an image: (c0, c1, r0, r1) in pixels (:func:`image_box`)."""


@dataclass(frozen=True)
class Halo:
    """The occluder window of one tile for one camera: ``window`` in DEM posts (clipped to the
    DEM), ``reach`` the farthest ground track in posts (unclipped), ``elevation`` the lowest
    line of sight over the tile's perimeter in degrees above the local horizontal."""

    window: WindowT
    reach: float
    elevation: float


def _ball_exit(p: np.ndarray, d: np.ndarray, radius: float) -> np.ndarray:
    """Distance along unit directions ``d`` from points ``p`` inside a ball about the origin
    to its surface."""
    b = np.einsum("ij,ij->i", p, d)
    c = np.einsum("ij,ij->i", p, p) - radius * radius
    return -b + np.sqrt(np.maximum(b * b - c, 0.0))


def exit_distance(dem: DemSource, p: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Metres along unit directions ``d`` (n, 3) from world points ``p`` (n, 3), at most
    ``h_max`` high, to where the line leaves O (see the module docstring)."""
    if dem.world == WorldFrame.MAP:
        with np.errstate(divide="ignore"):
            return np.where(d[:, 2] > 0, (dem.h_max - p[:, 2]) / d[:, 2], np.inf)
    a, _ = dem.preview.radii
    if dem.radius_values:
        return _ball_exit(p, d, dem.h_max)
    if dem.preview.is_sphere:
        return _ball_exit(p, d, a + dem.h_max)
    # ellipsoid: O lies inside the ball of radius a + max(h_max, 0); bisect its convex extent
    # on the points' geodetic heights alone (the values of from_world, through the same
    # transformation, without mapping the points onto the grid)
    to_geodetic = geocentric_transformer(dem.preview.crs, dem.preview.radii)
    lo = np.zeros(len(p))
    hi = _ball_exit(p, d, a + max(dem.h_max, 0.0))
    for _ in range(BISECTIONS):
        mid = (lo + hi) / 2
        q = p + mid[:, None] * d
        _, _, h = to_geodetic.transform(q[:, 0], q[:, 1], q[:, 2], direction="INVERSE")
        inside = np.asarray(h) <= dem.h_max
        lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
    return hi


def tile_halo(dem: DemSource, to_dem: ToDem, tile: WindowT, camera: Camera) -> Halo:
    """The occluder window of the output-grid ``tile`` for ``camera`` (module docstring)."""
    c, r = to_dem(*perimeter(tile))
    p = dem.to_world(c, r, np.full(c.shape, dem.h_min))
    c, r, p, sensor = _lines_of_sight(camera, c, r, p)
    to_cam = sensor - p
    dist = np.linalg.norm(to_cam, axis=-1)
    d = to_cam / dist[:, None]
    t_end = np.minimum(exit_distance(dem, p, d), dist)
    k = np.linspace(0.0, 1.0, TRACK_SAMPLES)
    track = p[:, None, :] + (t_end[:, None] * k)[..., None] * d[:, None, :]
    tc, tr, _ = dem.from_world(track)
    reach = float(np.nanmax(np.hypot(tc - c[:, None], tr - r[:, None])))
    sin_e = np.einsum("ij,ij->i", d, dem.preview.up_vectors(p))
    rows, cols = dem.shape
    box = (
        max(int(np.floor(np.nanmin(tr))) - HALO_MARGIN, 0),
        min(int(np.ceil(np.nanmax(tr))) + HALO_MARGIN + 1, rows),
        max(int(np.floor(np.nanmin(tc))) - HALO_MARGIN, 0),
        min(int(np.ceil(np.nanmax(tc))) + HALO_MARGIN + 1, cols),
    )
    return Halo(box, reach, float(np.degrees(np.arcsin(np.clip(sin_e.min(), -1, 1)))))


def _lines_of_sight(
    camera: Camera, c: np.ndarray, r: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Posts ``(c, r)`` at world points ``p`` (n, 3) paired with where the camera sees them
    from: its centre for a frame camera; else the origin of the ray through each post's pixel
    (a line scanner's position when it images the post), and for posts it does not image
    every one of :func:`~orthomvp.camera.sensor_positions` (any could matter)."""
    return _lines_of_sight_batch(camera, c, r, p, np.zeros(len(c), np.intp))[:4]


def footprint(dem: DemSource, to_dem: ToDem, tile: WindowT, on_dem: bool) -> WindowT:
    """The DEM window that holds an output-grid window's posts and what they are computed
    from: on the DEM's own grid the posts plus one around (normals are central differences),
    else every DEM post that the interpolation of the posts, one around, touches."""
    r0, r1, c0, c1 = tile
    rows, cols = dem.shape
    if on_dem:
        return max(r0 - 1, 0), min(r1 + 1, rows), max(c0 - 1, 0), min(c1 + 1, cols)
    c, r = to_dem(*perimeter((r0 - 1, r1 + 1, c0 - 1, c1 + 1)))
    return (
        max(int(np.floor(np.nanmin(r))) - 1, 0),
        min(int(np.floor(np.nanmax(r))) + 3, rows),
        max(int(np.floor(np.nanmin(c))) - 1, 0),
        min(int(np.floor(np.nanmax(c))) + 3, cols),
    )


def image_box(dem: DemSource, to_dem: ToDem, tile: WindowT, camera: Camera) -> Box | None:
    """Where the tile can appear in the image: the bounding box (c0, c1, r0, r1) in pixels of
    the projections of its perimeter and a 9 x 9 lattice of its posts at the DEM's lowest and
    highest values, or None when the camera sees none of them in front of it.

    Points behind the camera make the box the whole image plane (conservative). Points that a
    camera does not image (NaN depth: a line scanner's ground beyond its first or last line)
    are left out after sampling the tile on a :data:`DENSE` x :data:`DENSE` lattice, the box
    growing by the largest pixel step between neighbouring samples: the imaged part of the
    tile ends within one step of the last imaged sample."""
    uv, depth = _box_samples(dem, to_dem, tile, camera, 9)
    if not (depth > 0).any():
        return None
    if (depth <= 0).any() or (np.isfinite(depth) & ~np.isfinite(uv).all(axis=-1)).any():
        return (-np.inf, np.inf, -np.inf, np.inf)
    if not np.isfinite(depth).all():
        uv, depth = _box_samples(dem, to_dem, tile, camera, DENSE)
        grid = uv.reshape(2, DENSE, DENSE, 2)
        with np.errstate(invalid="ignore"):
            steps = [np.abs(np.diff(grid, axis=a)) for a in (1, 2)]
        step = max(float(np.nanmax(s)) if np.isfinite(s).any() else 0.0 for s in steps)
        uv = uv[np.isfinite(uv).all(axis=-1)]
        if not len(uv):
            return None
        lo, hi = uv.min(axis=0) - step, uv.max(axis=0) + step
        return (lo[0], hi[0], lo[1], hi[1])
    return (uv[:, 0].min(), uv[:, 0].max(), uv[:, 1].min(), uv[:, 1].max())


def _box_samples(
    dem: DemSource, to_dem: ToDem, tile: WindowT, camera: Camera, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and depths of the tile's perimeter (only for ``n`` = 9) and an ``n`` x ``n``
    lattice of its posts, at the DEM's lowest then highest values."""
    r0, r1, c0, c1 = tile
    lc, lr = np.meshgrid(np.linspace(c0, c1 - 1, n), np.linspace(r0, r1 - 1, n))
    c, r = lc.ravel(), lr.ravel()
    if n == 9:
        pc, pr = perimeter(tile)
        c, r = np.concatenate([pc, c]), np.concatenate([pr, r])
    c, r = to_dem(c, r)
    c, r = np.concatenate([c, c]), np.concatenate([r, r])
    h = np.concatenate([np.full(len(c) // 2, dem.h_min), np.full(len(c) // 2, dem.h_max)])
    return camera.project(dem.to_world(c, r, h))


def tile_runs(windows: list[WindowT]) -> list[tuple[int, int]]:
    """``windows`` cut into consecutive runs (first, last) of at most :data:`BATCH_POSTS`
    posts sampled (their perimeters and 9 x 9 lattices; one window a run at least), for
    :class:`TileSamples`."""
    runs, first, posts = [], 0, 0
    for i, (r0, r1, c0, c1) in enumerate(windows):
        size = 2 * (r1 - r0 + c1 - c0) + 81
        if posts and posts + size > BATCH_POSTS:
            runs.append((first, i))
            first, posts = i, 0
        posts += size
    return runs + [(first, len(windows))] if windows else runs


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The indices ``start, ..., start + count - 1`` of every (start, count) pair, in order."""
    total = int(counts.sum())
    ends = np.cumsum(counts)
    return np.repeat(starts - (ends - counts), counts) + np.arange(total)


def _offsets(counts: np.ndarray) -> np.ndarray:
    """Where each of consecutive segments of ``counts`` (all > 0) starts."""
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)


class TileSamples:
    """The points :func:`image_box` and :func:`tile_halo` sample in output-grid ``tiles``,
    computed once for every camera: per tile its perimeter posts then a 9 x 9 lattice of its
    posts (DEM positions), and their world points at the DEM's lowest and highest values.

    :meth:`image_boxes` and :meth:`halos` give, for any of the tiles and one camera, what
    those functions give tile by tile (the same values: one projection of all the tiles'
    points and per-tile reductions of it, instead of small numpy operations per tile)."""

    def __init__(self, dem: DemSource, to_dem: ToDem, tiles: list[WindowT]) -> None:
        self.dem, self.to_dem, self.tiles = dem, to_dem, tiles
        parts = []
        for tile in tiles:
            r0, r1, c0, c1 = tile
            lc, lr = np.meshgrid(np.linspace(c0, c1 - 1, 9), np.linspace(r0, r1 - 1, 9))
            pc, pr = perimeter(tile)
            parts.append((np.concatenate([pc, lc.ravel()]), np.concatenate([pr, lr.ravel()])))
        self.edge = np.array([2 * (t[1] - t[0] + t[3] - t[2]) for t in tiles], np.intp)
        self.count = np.array([len(c) for c, _ in parts], np.intp)
        self.start = _offsets(self.count)
        if not tiles:
            return
        c, r = (np.concatenate([part[i] for part in parts]) for i in (0, 1))
        self.c, self.r = to_dem(c, r)
        n = len(self.c)
        self.world = dem.to_world(
            np.concatenate([self.c, self.c]),
            np.concatenate([self.r, self.r]),
            np.concatenate([np.full(n, dem.h_min), np.full(n, dem.h_max)]),
        )

    def image_boxes(self, which: list[int], camera: Camera) -> list[Box | None]:
        """:func:`image_box` of the tiles at indices ``which``, for ``camera``."""
        if not which:
            return []
        k = np.asarray(which, np.intp)
        count, low = self.count[k], self.start[k]
        n = len(self.c)
        # per tile its points at the lowest then at the highest value, as image_box has them
        starts = np.stack([low, low + n], axis=1).ravel()
        uv, depth = camera.project(self.world[_ranges(starts, np.repeat(count, 2))])
        at = _offsets(2 * count)
        imaged = np.isfinite(uv).all(axis=-1)
        front = np.logical_or.reduceat(depth > 0, at)
        plane = np.logical_or.reduceat((depth <= 0) | (np.isfinite(depth) & ~imaged), at)
        beyond = ~np.logical_and.reduceat(np.isfinite(depth), at)
        with np.errstate(invalid="ignore"):
            lo, hi = np.minimum.reduceat(uv, at, axis=0), np.maximum.reduceat(uv, at, axis=0)
        boxes: list[Box | None] = []
        for j, i in enumerate(which):
            if not front[j]:
                boxes.append(None)
            elif plane[j]:
                boxes.append((-np.inf, np.inf, -np.inf, np.inf))
            elif beyond[j]:  # ground the camera does not image: the dense lattice, per tile
                boxes.append(image_box(self.dem, self.to_dem, self.tiles[i], camera))
            else:
                boxes.append((lo[j, 0], hi[j, 0], lo[j, 1], hi[j, 1]))
        return boxes

    def halos(self, which: list[int], camera: Camera) -> list[Halo]:
        """:func:`tile_halo` of the tiles at indices ``which``, for ``camera``."""
        if not which:
            return []
        dem = self.dem
        k = np.asarray(which, np.intp)
        at = _ranges(self.start[k], self.edge[k])
        segment = np.repeat(np.arange(len(k)), self.edge[k])
        c, r, p, sensor, segment = _lines_of_sight_batch(
            camera, self.c[at], self.r[at], self.world[at], segment
        )
        to_cam = sensor - p
        dist = np.linalg.norm(to_cam, axis=-1)
        d = to_cam / dist[:, None]
        t_end = np.minimum(exit_distance(dem, p, d), dist)
        # the ground tracks as tile_halo has them, laid out (sample, line) so that every
        # operation runs over long rows and every reduction over a line's samples goes across
        # them: the same operations on the same values
        along = np.linspace(0.0, 1.0, TRACK_SAMPLES)[:, None] * t_end
        track = np.stack([p[:, i] + along * d[:, i] for i in range(3)], axis=-1)
        tc, tr, _ = dem.from_world(track)
        at = _offsets(np.bincount(segment, minlength=len(k)))
        reach = np.fmax.reduceat(np.fmax.reduce(np.hypot(tc - c, tr - r), axis=0), at)
        bounds = [
            u.reduceat(u.reduce(x, axis=0), at)
            for u, x in ((np.fmin, tr), (np.fmax, tr), (np.fmin, tc), (np.fmax, tc))
        ]
        sin_e = np.minimum.reduceat(np.einsum("ij,ij->i", d, dem.preview.up_vectors(p)), at)
        elevation = np.degrees(np.arcsin(np.clip(sin_e, -1, 1)))
        rows, cols = dem.shape
        return [
            Halo(
                (
                    max(int(np.floor(bounds[0][j])) - HALO_MARGIN, 0),
                    min(int(np.ceil(bounds[1][j])) + HALO_MARGIN + 1, rows),
                    max(int(np.floor(bounds[2][j])) - HALO_MARGIN, 0),
                    min(int(np.ceil(bounds[3][j])) + HALO_MARGIN + 1, cols),
                ),
                float(reach[j]),
                float(elevation[j]),
            )
            for j in range(len(k))
        ]


def _lines_of_sight_batch(
    camera: Camera, c: np.ndarray, r: np.ndarray, p: np.ndarray, segment: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_lines_of_sight` of posts from several tiles (``segment``: each post's tile,
    ascending), with each line's tile, the lines grouped by tile (ascending)."""
    if isinstance(camera, PinholeCamera):
        return c, r, p, np.broadcast_to(camera.center, p.shape), segment
    uv, _ = camera.project(p)
    origin = camera.origins(uv)
    known = np.isfinite(origin).all(axis=1)
    if known.all():  # (the sensor's positions, from the model's rays, only for the others)
        return c, r, p, origin, segment
    others = sensor_positions(camera)
    k = len(others)
    order = np.argsort(
        np.concatenate([segment[known], np.repeat(segment[~known], k)]), kind="stable"
    )
    return (
        np.concatenate([c[known], np.repeat(c[~known], k)])[order],
        np.concatenate([r[known], np.repeat(r[~known], k)])[order],
        np.concatenate([p[known], np.repeat(p[~known], k, axis=0)])[order],
        np.concatenate([origin[known], np.tile(others, ((~known).sum(), 1))])[order],
        np.concatenate([segment[known], np.repeat(segment[~known], k)])[order],
    )
