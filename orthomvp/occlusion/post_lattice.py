"""Per-post geometry of a tile for cameras whose ground-to-image is costly (RPC cameras: each
post needs iterations through the model; :func:`lattice_applies`), from an error-bounded lattice:
:func:`lattice` gives :func:`~orthomvp.occlusion.post_geometry.general`'s
:class:`~orthomvp.occlusion.post_geometry.PostGeometry` within :data:`LATTICE_ERROR` pixels.

A post's pixel, depth, ray (origin and direction) and GSD are smooth functions of its grid
column, row and height. They are evaluated exactly (the camera's own ``project``, ``ray`` and
``gsd``, as :func:`~orthomvp.occlusion.post_geometry.general` calls them, or for an RPC camera in
a geocentric world frame the same values from the RPC's numba kernels,
:func:`orthomvp.camera.rpc_kernel.camera_values`, within about 1e-9 pixels) at the nodes of a
lattice and interpolated in between (linear in height; across the grid bilinear, or cubic where
bilinear would need far finer cells, see below). The lattice belongs to the grid, not to the
tile, so that every tiling gives the same values: nodes at the grid's columns and rows that are
multiples of ``step`` (counted from the CRS's origin in posts) and at heights that are multiples
of :data:`LEVEL_SPACING`. Each post lies in a unit: a cell of the lattice between two levels of
height. A unit's bilinear interpolation is checked against the exact values at its 27 midpoints
and corners (the cell's centre, edge midpoints and corners, at its two levels and halfway between
them: where a quadratic's error peaks); it fails where any check misses by more than half of
``error`` pixels (:data:`CHECK_SHARE`; the pixel's offset, or the ray's offset at the point in
pixels of the point's GSD), by more than :data:`GSD_RELATIVE` of the GSD, changes the sign of
the depth, or is not imaged (NaN). Where bilinear misses by more than four times that (so that
one halving of the cell, which quarters a quadratic's error, would not do), or in the finest
lattice, the unit is tried with Catmull-Rom cubics across rows and columns instead (from the
4 x 4 nodes around the cell; exact for quadratics, such as the RPC's curvature that held units
to cells of 8 posts at 24 m), checked the same way at a quarter, half and three quarters of the
cell (a cubic's error vanishes at the midpoint). The posts of units that fail both go to the
lattice of half the step (:data:`LATTICE_STEPS`), and past the finest to the exact values. A
grid's units are first tried on the coarsest lattice whose unit around a probe (the centre of
the RPC's domain) passes, the same for all its tiles (:func:`_first_lattice`): where every unit
of a lattice would halve, none is checked on it (the same values as checking them all); where
some would pass it but the probe's fails, they are served by the finer lattice, within the same
bound. A
unit none of whose checks is imaged (beyond an RPC's domain, a line scanner's lines), or all of
whose checks' pixels have a bounding box more than a pixel off the image, is taken as not
imaged, its values NaN: an image would have to fit between checks half a cell apart to be
missed. The exact path (``Geometry.GENERAL``) stays the test oracle. Normals and everything
else built from the DEM alone are computed as in
:func:`~orthomvp.occlusion.post_geometry.general` (the same operations in numba kernels, the same
values to the bit), from world points that on an ellipsoid come from a lattice too
(:func:`world_block`).

The interpolation, the normals and the world points run in numba kernels
(:mod:`orthomvp.occlusion.post_lattice_kernel`).
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from orthomvp.camera import Camera, RpcCamera
from orthomvp.codes import WorldFrame
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import finite_rows
from orthomvp.occlusion.post_geometry import PostGeometry, tile_block

LATTICE_STEPS = (64, 32, 16, 8, 4)
"""Posts between lattice nodes along rows and columns: the first lattice, and the finer ones
that the posts of failed units go to in turn."""
LEVEL_SPACING = 16.0
"""Height between the lattice's levels, in the grid's height units (metres)."""
LATTICE_ERROR = 0.004
"""The interpolation error allowed, pixels: a unit's checks must be within half of it
(:data:`CHECK_SHARE`), a margin for the posts between the checks."""
CHECK_SHARE = 0.5
"""The share of the allowed error that a unit's checks may miss by."""
_FAR = 4.0  # bilinear's error beyond the bound this many times: cubics, not a finer lattice
WORLD_TOLERANCE = 1e-4
"""The largest offset (metres) of a world point from the lattice of :func:`world_block`."""
GSD_RELATIVE = 1e-3
"""The largest relative error of an interpolated GSD allowed at a check."""
_U, _V, _DEPTH, _O, _D, _GSD = 0, 1, 2, slice(3, 6), slice(6, 9), 9  # channels of the values
_CHANNELS = 10
_TABLE_MOST = 1 << 24  # entries of _unique_rows's table at most (128 MiB)
# a unit's points, in quarter steps across rows and columns and half steps between levels
# from its first node: the checks of bilinear interpolation (its corners, edge midpoints and
# centre, at its two levels and halfway between them), those of cubic interpolation (inside it,
# at a quarter, half and three quarters of the cell, at the same heights), and the other nodes
# around it that cubic interpolation reads
_SCALE = np.array([4, 4, 2])
_HALVES = np.array([(2 * a, 2 * b, t) for a in range(3) for b in range(3) for t in range(3)])
_QUARTERS = np.array([(a, b, t) for a in (1, 2, 3) for b in (1, 2, 3) for t in range(3)])
_RING = np.array(
    [(4 * a, 4 * b, 2 * t) for a in range(-1, 3) for b in range(-1, 3) for t in (0, 1)
     if not (0 <= a <= 1 and 0 <= b <= 1)]
)  # fmt: skip


def lattice_applies(terrain: Terrain, camera: Camera) -> bool:
    """Whether :func:`lattice` serves ``camera``: an :class:`~orthomvp.camera.RpcCamera`
    (whose ground to image iterates), on a grid of 2 x 2 posts or more. CSM line scanners keep
    the exact path: at the bound that keeps the RPC's two world frames together, their checks
    cost more than their own one-search geometry
    (:meth:`~orthomvp.camera.csm.linescan.LineScanCamera.imaging`)."""
    return isinstance(camera, RpcCamera) and min(terrain.shape) >= 2


def exact_values(camera: Camera, xyz: np.ndarray) -> np.ndarray:
    """The camera's values (..., 10) at world points ``xyz`` (..., 3): pixel (u, v), depth,
    the ray's origin and unit direction through that pixel, GSD (metres); NaN where not
    imaged."""
    out = np.full((*xyz.shape[:-1], _CHANNELS), np.nan)
    if not xyz.size:
        return out
    uv, depth = camera.project(xyz)
    out[..., :2], out[..., _DEPTH] = uv, depth
    good = finite_rows(uv)
    if good.any():
        origin, direction = camera.ray(uv[good])
        out[good, _O], out[good, _D] = origin, direction
    out[..., _GSD] = camera.gsd(xyz)
    return out


def fast_values(camera: Camera, xyz: np.ndarray) -> np.ndarray:
    """:func:`exact_values` through the RPC kernels where they serve the camera (an RPC camera
    in a geocentric world frame, :func:`orthomvp.camera.rpc_kernel.camera_values`: the same
    values within about 1e-9 pixels and 1e-8 metres, in one evaluation a point), else
    :func:`exact_values` itself."""
    if isinstance(camera, RpcCamera) and xyz.size:
        from orthomvp.camera.rpc_kernel import camera_values

        out = camera_values(camera, xyz)
        if out is not None:
            return out
    return exact_values(camera, xyz)


def _outside(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Per unit, whether its checks' pixels ``uv`` (units, checks, 2) show that none of its
    posts is imaged: none is imaged, or all are and their bounding box lies more than a pixel
    off the image."""
    finite = np.isfinite(uv).all(axis=-1)
    low = np.where(finite[..., None], uv, np.inf).min(axis=1)
    high = np.where(finite[..., None], uv, -np.inf).max(axis=1)
    w, h = camera.width, camera.height
    off = (high[:, 0] < -1.5) | (high[:, 1] < -1.5) | (low[:, 0] > w + 0.5) | (low[:, 1] > h + 0.5)
    return ~finite.any(axis=1) | (finite.all(axis=1) & off)


def tile_values(
    terrain: Terrain,
    camera: Camera,
    rs: slice,
    cs: slice,
    p: np.ndarray,
    ok: np.ndarray,
    *,
    steps: tuple[int, ...] = LATTICE_STEPS,
    error: float = LATTICE_ERROR,
) -> tuple[np.ndarray, np.ndarray]:
    """The values (rows, cols, 10) of :func:`exact_values` at the posts ``p`` (rows, cols, 3)
    of tile (``rs``, ``cs``) of ``terrain`` where ``ok``, interpolated within ``error`` pixels
    from the grid's lattices of ``steps`` posts in turn (each a multiple of the last), or else
    exact (module docstring); and where they are exact (bool (rows, cols)). The posts are
    sorted once into the finest lattice's units; a coarser unit serves all of its own."""
    from orthomvp.occlusion.post_lattice_kernel import fill, posts

    rows, cols = ok.shape
    out = np.full((rows, cols, _CHANNELS), np.nan)
    exact = np.zeros((rows, cols), bool)
    count = int(np.count_nonzero(ok))
    if not count:
        return out, exact
    T = terrain.transform  # a post's index counted from the CRS's origin: tile index + offset
    origin = (T.f / T.e + 0.5 + rs.start, T.c / T.a + 0.5 + cs.start)
    steps = steps[_first_lattice(terrain, camera, steps, error) :]
    fine = steps[-1]
    rc, place = np.empty((count, 2), np.int64), np.empty((count, 3))
    cell = np.empty((count, 3), np.int64)
    posts(ok, terrain.values[rs, cs], *origin, fine, LEVEL_SPACING, rc, place, cell)
    units, which = _unique_rows(cell)  # the finest units holding posts
    served = np.full(len(units), -1)  # which lattice serves each
    parent = np.zeros_like(units)  # its unit in that lattice
    dead = np.zeros(len(units), bool)
    cubic = np.zeros(len(units), bool)
    lattices = []
    todo = np.arange(len(units))
    for k, step in enumerate(steps):
        if not todo.size:
            break
        up = units[todo].copy()
        up[:, :2] //= step // fine
        coarse, where = _unique_rows(up)
        last = k == len(steps) - 1
        nodes, first, passed, gone, bicubic = _check(
            terrain, camera, coarse, step, origin, rs, cs, error, last
        )
        lattices.append((step, nodes, first))
        good = passed[where]
        served[todo[good]], parent[todo[good]] = k, coarse[where[good]]
        dead[todo[good]], cubic[todo[good]] = gone[where[good]], bicubic[where[good]]
        todo = todo[~good]
    unit_table = np.full((len(units), 9), -1, np.int64)
    buffers, meta = [], []
    offset = 0
    for k, (_, nodes, first) in enumerate(lattices):
        mine = served == k
        unit_table[mine, 0] = k
        unit_table[mine, 1:4] = parent[mine]
        unit_table[mine, 4:7] = parent[mine] - first
        buffers.append(nodes.ravel())
        meta.append((offset, nodes.shape[1], nodes.shape[2]))
        offset += nodes.size
    unit_table[:, 7], unit_table[:, 8] = dead, cubic
    if lattices:
        fill(
            np.concatenate(buffers), np.array(meta, np.int64),
            np.array([step for step, _, _ in lattices], np.float64), unit_table, which,
            rc, place, out,
        )  # fmt: skip
    rest = served[which] < 0
    exact[rc[rest, 0], rc[rest, 1]] = True
    if rest.any():
        out[exact] = fast_values(camera, p[exact])
    return out, exact


_FIRST: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _first_lattice(terrain: Terrain, camera: Camera, steps: tuple[int, ...], error: float) -> int:
    """The index in ``steps`` of the lattice that the units of ``terrain``'s grid are tried on
    first: the first whose unit around a probe passes its checks (bilinear, or cubic where
    bilinear misses far), the probe being the centre of an RPC camera's domain (its longitude
    and latitude offsets, at its height offset); 0 for other cameras, or where the probe's unit
    is not imaged. A unit that a coarser lattice would have served is then served by a finer
    one, checked the same way; a grid whose units all fail the coarser lattice (the QuickBird
    image at 6 m: every unit of 64 posts misses by less than four times the bound and halves)
    is spared checking them. The same for every tile of a grid (kept per camera and grid)."""
    if not isinstance(camera, RpcCamera) or len(steps) < 2:
        return 0
    T = terrain.transform
    origin = (T.f / T.e + 0.5, T.c / T.a + 0.5)  # the global index of post (0, 0)
    key = (
        terrain.crs, terrain.world, terrain.radius_values, T.a, T.b, T.d, T.e,
        origin[0] % 1.0, origin[1] % 1.0, steps, error,
    )  # fmt: skip
    known = _FIRST.setdefault(camera, {})
    if key not in known:
        rpc = camera.rpc
        c, r = map(
            float, terrain.lonlat_to_pixel(np.radians(rpc.long_off), np.radians(rpc.lat_off))
        )
        level = math.floor((rpc.height_off - camera.height_offset) / LEVEL_SPACING)
        first = 0
        while first < len(steps) - 1 and math.isfinite(r) and math.isfinite(c):
            step = steps[first]
            unit = np.array([[math.floor((r + origin[0]) / step),
                              math.floor((c + origin[1]) / step), level]])  # fmt: skip
            _, _, passed, dead, _ = _check(
                terrain, camera, unit, step, origin, slice(0, 0), slice(0, 0), error, False
            )
            if dead[0] or passed[0]:
                first = 0 if dead[0] else first
                break
            first += 1
        known[key] = first
    return known[key]


def _check(
    terrain: Terrain,
    camera: Camera,
    units: np.ndarray,
    step: int,
    origin: tuple[float, float],
    rs: slice,
    cs: slice,
    error: float,
    last: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The units ``units`` (n, 3: global cell row, column, level) of the lattice of ``step``
    posts, checked: the nodes (node rows, node columns, levels, 10) around them and the
    global index of the first, whether each unit passes its checks, whether it is dead, and
    whether it is interpolated by cubics (module docstring; always where bilinear fails in the
    ``last`` lattice). ``origin``: the global (row, column) index of post (0, 0) of tile
    (``rs``, ``cs``)."""
    points, at = _unique_rows((_SCALE * units[:, None, :] + _HALVES[None]).reshape(-1, 3))
    at = at.reshape(len(units), len(_HALVES))  # (each evaluated once)
    xyz, exact = _exact_at(terrain, camera, points, step, origin, rs, cs)
    first = points.min(axis=0) // _SCALE - (1, 1, 0)  # (units start at a node; and the ring)
    nodes = np.full((*(points.max(axis=0) // _SCALE - first + (2, 2, 1)), _CHANNELS), np.nan)
    node = ~(points % _SCALE).any(axis=1)
    nodes[tuple((points[node] // _SCALE - first).T)] = exact[node]
    miss, far = _verdicts(nodes, units - first, _HALVES, False, exact, xyz, at, error)
    dead = _outside(camera, exact[:, :2][at])
    cubic = miss & (far | last) & ~dead
    if cubic.any():  # the ring's nodes and the checks inside the cell
        mine = units[cubic]
        extra = _SCALE * mine[:, None, :] + np.concatenate([_QUARTERS, _RING])[None]
        points, at = _unique_rows(extra.reshape(-1, 3))
        at = at.reshape(len(mine), -1)[:, : len(_QUARTERS)]
        xyz, exact = _exact_at(terrain, camera, points, step, origin, rs, cs)
        node = ~(points % _SCALE).any(axis=1)
        nodes[tuple((points[node] // _SCALE - first).T)] = exact[node]
        cubic[cubic] = ~_verdicts(nodes, mine - first, _QUARTERS, True, exact, xyz, at, error)[0]
    return nodes, first, ~miss | cubic | dead, dead, cubic & ~dead


def _exact_at(
    terrain: Terrain,
    camera: Camera,
    points: np.ndarray,
    step: int,
    origin: tuple[float, float],
    rs: slice,
    cs: slice,
) -> tuple[np.ndarray, np.ndarray]:
    """The world points (n, 3) of lattice ``points`` (n, 3: global row and column in quarter
    steps of ``step`` posts, height in half levels) and the camera's exact values there. In a
    body frame each of their distinct places (a point's row and column; most are taken at three
    heights or more) is mapped to longitude and latitude once, then every point to the world
    (:meth:`Terrain.lonlat_to_world`): :meth:`Terrain.to_world`'s values."""
    places, at = _unique_rows(np.column_stack([points[:, :2], np.zeros(len(points), np.int64)]))
    rows = places[:, 0] / 4.0 * step - origin[0] + rs.start  # the terrain's rows and columns
    cols = places[:, 1] / 4.0 * step - origin[1] + cs.start
    height = points[:, 2] / 2.0 * LEVEL_SPACING
    if terrain.world == WorldFrame.MAP:
        xyz = terrain.to_world(cols[at], rows[at], height)
    else:
        lon, lat = terrain.pixel_to_lonlat(cols, rows, wrap=False)
        xyz = terrain.lonlat_to_world(lon[at], lat[at], height)
    return xyz, fast_values(camera, xyz)


def _verdicts(
    nodes: np.ndarray,
    first: np.ndarray,
    checks: np.ndarray,
    cubic: bool,
    exact: np.ndarray,
    xyz: np.ndarray,
    at: np.ndarray,
    error: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per unit whose first node is ``first`` (units, 3): whether its interpolation from
    ``nodes`` (bilinear, or ``cubic``) misses the ``exact`` values at the world points ``xyz``
    of its ``checks`` (in :data:`_SCALE` units; ``at`` (units, checks): their points) by more
    than its share of ``error`` (:data:`CHECK_SHARE`; the criteria of the module docstring), and
    whether it misses by more than :data:`_FAR` times that."""
    from orthomvp.occlusion.post_lattice_kernel import verdicts

    miss, far = np.empty(len(first), bool), np.empty(len(first), bool)
    share = error * CHECK_SHARE
    verdicts(
        nodes, first, checks / _SCALE, cubic, exact, xyz, at, share, share * _FAR,
        GSD_RELATIVE, miss, far,
    )  # fmt: skip
    return miss, far


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``a`` (n, 3) of integers, in order, and where each row of ``a``
    is among them (as ``np.unique(axis=0, return_inverse=True)``), through a table over their
    span (small: cells and levels of a tile; a kernel, :func:`unique_table`) or, where it is
    not, a sort."""
    from orthomvp.occlusion.post_lattice_kernel import unique_table

    a = np.ascontiguousarray(a, np.int64)
    if not len(a):
        return np.empty((0, 3), np.int64), np.empty(0, np.int64)
    rows, inverse = np.empty_like(a), np.empty(len(a), np.int64)
    m = unique_table(a, _TABLE_MOST, rows, inverse)
    if m >= 0:
        return rows[:m].copy(), inverse  # (not a view holding every row's slot)
    rows, inverse = np.unique(a, axis=0, return_inverse=True)  # (a tile of extreme relief)
    return rows, inverse.ravel()


def world_block(terrain: Terrain, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """World points (rows, cols, 3) of the posts [r0:r1, c0:c1] of ``terrain``: in the body
    frame on an ellipsoid, where every post would go through PROJ twice (map to geodetic, and
    geodetic to body-fixed), from the grid's own lattice of every k-th post (counted from the
    CRS's origin): a point is P + h U, affine in its height h along the geodetic normal, and P
    and U are bilinear between the nodes within :data:`WORLD_TOLERANCE` (the ellipsoid's
    curvature over k posts: (k d)^2 / 8a, k at most 16); elsewhere
    :meth:`~orthomvp.geometry.terrain.Terrain.to_world` itself."""
    values = terrain.values[r0:r1, c0:c1]
    r, c = np.arange(r0, r1, dtype=np.float64), np.arange(c0, c1, dtype=np.float64)
    T = terrain.transform
    a = terrain.radii[0]
    d = max(abs(T.a), abs(T.e))
    d = np.radians(d) * a if terrain.crs.is_geographic else d
    k = 1
    while k < 16 and (2 * k * d) ** 2 / (8 * a) <= WORLD_TOLERANCE:
        k *= 2
    body = terrain.world != WorldFrame.MAP and not (terrain.radius_values or terrain.is_sphere)
    if not body or k == 1:
        return terrain.to_world(c[None, :], r[:, None], values)
    gr, gc = T.f / T.e + 0.5, T.c / T.a + 0.5  # the global index of post (0, 0)
    nr = np.arange(np.floor((gr + r0) / k), np.ceil((gr + r1 - 1) / k) + 1) * k - gr
    nc = np.arange(np.floor((gc + c0) / k), np.ceil((gc + c1 - 1) / k) + 1) * k - gc
    nr = nr if len(nr) > 1 else np.append(nr, nr[0] + k)
    nc = nc if len(nc) > 1 else np.append(nc, nc[0] + k)
    base = terrain.to_world(nc[None, :], nr[:, None], np.zeros((len(nr), len(nc))))
    up = terrain.to_world(nc[None, :], nr[:, None], np.ones((len(nr), len(nc)))) - base

    from orthomvp.occlusion.post_lattice_kernel import affine_block

    i = np.clip(np.searchsorted(nr, r, side="right") - 1, 0, len(nr) - 2)
    j = np.clip(np.searchsorted(nc, c, side="right") - 1, 0, len(nc) - 2)
    out = np.empty((len(r), len(c), 3))
    affine_block(
        base, up, i, (r - nr[i]) / (nr[i + 1] - nr[i]), j, (c - nc[j]) / (nc[j + 1] - nc[j]),
        np.ascontiguousarray(values, np.float64), out,
    )  # fmt: skip
    return out


def lattice(
    terrain: Terrain,
    camera: Camera,
    rs: slice,
    cs: slice,
    *,
    steps: tuple[int, ...] = LATTICE_STEPS,
    error: float = LATTICE_ERROR,
) -> PostGeometry:
    """:func:`~orthomvp.occlusion.post_geometry.general` for a case :func:`lattice_applies`
    to, the camera's values interpolated on the grid's lattices of ``steps`` posts within
    ``error`` pixels (module docstring); the rays' unit directions come with it
    (:attr:`PostGeometry.directions`)."""
    from orthomvp.occlusion.post_lattice_kernel import finish, normals

    r0, r1, c0, c1 = tile_block(terrain, rs, cs)
    block = world_block(terrain, r0, r1, c0, c1)
    n = np.empty_like(block)
    normals(block, terrain.world != WorldFrame.MAP, n)  # (grid_normals, to the bit)
    inner = (slice(rs.start - r0, rs.stop - r0), slice(cs.start - c0, cs.stop - c0))
    p, n = block[inner], n[inner]
    ok = finite_rows(p) & finite_rows(n)
    values, _ = tile_values(terrain, camera, rs, cs, p, ok, steps=steps, error=error)
    if camera.width is None or camera.height is None:
        camera.in_image(values[..., :2])  # (the error it raises)
    inside = np.empty(ok.shape, bool)
    origins, directions = np.empty_like(p), np.empty_like(p)
    cos_e = np.empty(ok.shape)
    finish(values, p, n, ok, camera.width, camera.height, inside, origins, directions, cos_e)
    uv = values[..., :2]
    return PostGeometry(
        p[..., 0], p[..., 1], p[..., 2], ok, uv, inside, cos_e, values[..., _GSD], origins,
        directions,
    )  # fmt: skip
