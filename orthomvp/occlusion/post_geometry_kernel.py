""":func:`orthomvp.occlusion.post_geometry.separable` and the first classification of the visibility
test (inside the image, facing the camera, the codes carried from the DEM's posts) as one numba
kernel over a tile's posts, without the numpy path's (rows, cols) float64 temporaries.

The kernel gives the numpy path's values bit for bit, which stays as its reference: the same
float64 operations in the same order (central differences, the cross product with its zero
terms, the projection's three terms summed in order), no fused multiply-add. It runs on one
thread without the GIL (the engine's tiles run in parallel).

This module imports numba (through :mod:`orthomvp.jit`): it is imported only when a plan large
enough to pay for it runs (:attr:`orthomvp.engine.plan.Plan.fused`)."""

from __future__ import annotations

import numpy as np

from orthomvp.camera import PinholeCamera
from orthomvp.codes import Code
from orthomvp.geometry.terrain import Terrain
from orthomvp.jit import cached_jit
from orthomvp.occlusion.post_geometry import PostGeometry, block_axes, tile_block

_VISIBLE, _OCCLUDED = np.uint8(Code.VISIBLE), np.uint8(Code.OCCLUDED)
_FACING_AWAY, _NODATA = np.uint8(Code.FACING_AWAY), np.uint8(Code.NODATA)


def _difference(v: np.ndarray, i: int) -> float:
    """The central difference of ``v`` (1-D) at ``i``, one-sided at the two ends (as
    :func:`orthomvp.geometry.terrain.central_difference`), in float64."""
    n = len(v)
    if i == 0:
        return np.float64(v[1]) - np.float64(v[0])
    if i == n - 1:
        return np.float64(v[n - 1]) - np.float64(v[n - 2])
    return (np.float64(v[i + 1]) - np.float64(v[i - 1])) * 0.5


_difference = cached_jit(_difference, fastmath=False, error_model="numpy")


def _height_difference(z: np.ndarray, r: int, c: int, dr: int, dc: int) -> float:
    """:func:`_difference` of the heights ``z`` (2-D) at post (``r``, ``c``) along the rows
    (``dr`` = 1) or the columns (``dc`` = 1), without a view of the row or column."""
    n = z.shape[0] if dr else z.shape[1]
    i = r if dr else c
    if i == 0:
        return np.float64(z[r + dr, c + dc]) - np.float64(z[r, c])
    if i == n - 1:
        return np.float64(z[r, c]) - np.float64(z[r - dr, c - dc])
    return (np.float64(z[r + dr, c + dc]) - np.float64(z[r - dr, c - dc])) * 0.5


_height_difference = cached_jit(
    _height_difference, fastmath=False, error_model="numpy", inline="always"
)


def _classify(
    z: np.ndarray,
    bx: np.ndarray,
    by: np.ndarray,
    inner: np.ndarray,
    cam: np.ndarray,
    occlusion: bool,
    dem_codes: np.ndarray,
    to_dem: np.ndarray,
    ok: np.ndarray,
    inside: np.ndarray,
    uv: np.ndarray,
    cos_e: np.ndarray,
    facing_gsd: np.ndarray,
    codes: np.ndarray,
    cast: np.ndarray,
) -> None:
    """The posts ``inner`` (row and column of the first, rows, cols) of the block of heights
    ``z`` (the tile with one post around, within the grid) whose eastings are ``bx`` and
    northings ``by``, seen by the pinhole ``cam`` (centre, the 3 x 3 world-to-image axes, fu,
    fv, cu, cv, pitch, width, height): into ``ok``, ``inside``, ``uv`` (NaN outside the
    image), ``cos_e`` and ``facing_gsd`` as :class:`~orthomvp.occlusion.post_geometry.PostGeometry`;
    into ``codes`` NODATA
    outside the image, FACING_AWAY, or VISIBLE, or the code that the four DEM posts around
    agree on (``dem_codes``, VISIBLE or OCCLUDED; ``to_dem``: the DEM column's scale and offset
    from an easting, the row's from a northing, the first DEM post's row and column); ``cast``
    where a ray is still needed (``occlusion``)."""
    i0, j0, rows, cols = inner[0], inner[1], inner[2], inner[3]
    cx, cy, cz = cam[0], cam[1], cam[2]
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = cam[3:12]
    fu, fv, cu, cv, pitch, width, height = cam[12:19]
    focal_px = 0.5 * (fu + fv) / pitch
    drows, dcols = dem_codes.shape
    carry = drows >= 2 and dcols >= 2
    for r in range(rows):
        br = i0 + r
        y = by[br]
        dby = _difference(by, br)
        for c in range(cols):
            bc = j0 + c
            x = bx[bc]
            zz = np.float64(z[br, bc])
            dbx = _difference(bx, bc)
            dzc = _height_difference(z, br, bc, 0, 1)  # along the columns
            dzr = _height_difference(z, br, bc, 1, 0)  # along the rows
            # a = (dbx, 0, dzc), b = (0, dby, dzr): a x b with its zero terms, as unit_normals
            n0 = 0.0 * dzr - dzc * dby
            n1 = dzc * 0.0 - dbx * dzr
            n2 = dbx * dby - 0.0 * 0.0
            sign = 1.0 if n0 * 0.0 + n1 * 0.0 + n2 * 1.0 >= 0 else -1.0
            scale = sign / np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            n0, n1, n2 = n0 * scale, n1 * scale, n2 * scale
            good = (
                np.isfinite(zz)
                and np.isfinite(n0)
                and np.isfinite(n1)
                and np.isfinite(n2)
                and np.isfinite(x)
                and np.isfinite(y)
            )
            ok[r, c] = good
            dx, dy, dz = x - cx, y - cy, zz - cz
            depth = dx * m20 + dy * m21 + dz * m22
            u = v = np.nan
            if depth > 0:
                s0 = dx * m00 + dy * m01 + dz * m02
                s1 = dx * m10 + dy * m11 + dz * m12
                u = (s0 / depth * fu + cu) / pitch
                v = (s1 / depth * fv + cv) / pitch
            seen = good and u >= -0.5 and u <= width - 0.5 and v >= -0.5 and v <= height - 0.5
            inside[r, c] = seen
            uv[r, c, 0] = u if seen else np.nan
            uv[r, c, 1] = v if seen else np.nan
            tx, ty, tz = cx - x, cy - y, cz - zz
            ce = (n0 * tx + n1 * ty + n2 * tz) / np.sqrt(tx * tx + ty * ty + tz * tz)
            cos_e[r, c] = ce
            facing_gsd[r, c] = np.sqrt(dx * dx + dy * dy + dz * dz) / focal_px
            code, ray = _NODATA, False
            if seen:
                code = _VISIBLE if ce > 0 else _FACING_AWAY
                ray = ce > 0 and occlusion
            if ray and carry:
                i = np.floor(to_dem[2] * y + to_dem[3]) - to_dem[4]
                j = np.floor(to_dem[0] * x + to_dem[1]) - to_dem[5]
                if i >= 0 and i < drows - 1 and j >= 0 and j < dcols - 1:
                    a, b = int(i), int(j)
                    first = dem_codes[a, b]
                    if (
                        (first == _VISIBLE or first == _OCCLUDED)
                        and dem_codes[a + 1, b] == first
                        and dem_codes[a, b + 1] == first
                        and dem_codes[a + 1, b + 1] == first
                    ):
                        code, ray = first, False
            codes[r, c] = code
            cast[r, c] = ray


_classify = cached_jit(_classify, fastmath=False, error_model="numpy")


def _interpolate_grid(
    v: np.ndarray,
    c0: np.ndarray,
    fx: np.ndarray,
    c_in: np.ndarray,
    r0: np.ndarray,
    fy: np.ndarray,
    r_in: np.ndarray,
    out: np.ndarray,
) -> None:
    """Into ``out`` (rows, cols) float64:
    :meth:`orthomvp.geometry.terrain.Terrain.interpolate_grid` of the heights ``v`` from each
    column's cell ``c0``, fraction ``fx`` and whether it is inside, and each row's (``r0``, ``fy``,
    ``r_in``), with the same operations in the same order."""
    for i in range(len(r0)):
        a_row, b_row, y = r0[i], r0[i] + 1, fy[i]
        for j in range(len(c0)):
            if not (r_in[i] and c_in[j]):
                out[i, j] = np.nan
                continue
            k, x = c0[j], fx[j]
            a, b = v[a_row, k], v[a_row, k + 1]
            d, e = v[b_row, k], v[b_row, k + 1]
            if x + y <= 1:
                out[i, j] = a + x * (b - a) + y * (d - a)
            else:
                out[i, j] = e + (1 - x) * (d - e) + (1 - y) * (b - e)


_interpolate_grid = cached_jit(_interpolate_grid, fastmath=False, error_model="numpy")


def interpolate_grid(terrain: Terrain, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """:meth:`orthomvp.geometry.terrain.Terrain.interpolate_grid` (the same values, bit for bit) as
    a kernel: the heights of ``terrain`` at every pair of fractional columns ``c`` (n,) and rows
    ``r`` (m,), (m, n) float64."""
    cells = terrain.grid_cells(c, r)
    out = np.empty((len(cells[3]), len(cells[0])))
    _interpolate_grid(terrain.values, *cells, out)
    return out


def classify_tile(
    terrain: Terrain,
    camera: PinholeCamera,
    rs: slice,
    cs: slice,
    *,
    occlusion: bool,
    dem_codes: np.ndarray | None = None,
    dem: Terrain | None = None,
    dem_first: tuple[int, int] = (0, 0),
    uv: np.ndarray | None = None,
    codes: np.ndarray | None = None,
) -> tuple[PostGeometry, np.ndarray, np.ndarray]:
    """The geometry of the posts of tile (``rs``, ``cs``) of ``terrain`` (a case
    :func:`~orthomvp.occlusion.post_geometry.separable_applies` to; pixels NaN outside the image),
    their first codes (uint8) and where rays are still needed (bool), as the visibility test makes
    them: the codes of the DEM's posts ``dem_codes`` (of ``dem``, in the grid's CRS, its first
    post ``dem_first`` (row, col) of the DEM) carried where the four around a post agree.
    Pixels and codes go into ``uv`` (rows, cols, 2) and ``codes`` (rows, cols) when given."""
    r0, r1, c0, c1 = block = tile_block(terrain, rs, cs)
    bx, by = block_axes(terrain, block)
    inner = np.array([rs.start - r0, cs.start - c0, rs.stop - rs.start, cs.stop - cs.start])
    m = camera.world_to_image_axes
    cam = np.array(
        [*camera.center, *m.ravel(), camera.fu, camera.fv, camera.cu, camera.cv, camera.pitch,
         camera.width, camera.height],
        dtype=np.float64,
    )  # fmt: skip
    if dem_codes is None or dem is None:
        dem_codes, to_dem = np.zeros((0, 0), np.uint8), np.zeros(6)
    else:
        Si = np.linalg.inv(dem.S)
        to_dem = np.array([Si[0, 0], Si[0, 2], Si[1, 1], Si[1, 2], *dem_first], np.float64)
    shape = (int(inner[2]), int(inner[3]))
    ok, inside, cast = (np.empty(shape, bool) for _ in range(3))
    cos_e, facing_gsd = np.empty(shape), np.empty(shape)
    uv = np.empty((*shape, 2)) if uv is None else uv
    codes = np.empty(shape, np.uint8) if codes is None else codes
    _classify(
        terrain.values[r0:r1, c0:c1], bx, by, inner, cam, occlusion, dem_codes, to_dem,
        ok, inside, uv, cos_e, facing_gsd, codes, cast,
    )  # fmt: skip
    x = bx[None, inner[1] : inner[1] + shape[1]]
    y = by[inner[0] : inner[0] + shape[0], None]
    z = terrain.values[rs, cs].astype(np.float64, copy=False)
    return PostGeometry(x, y, z, ok, uv, inside, cos_e, facing_gsd, None), codes, cast
