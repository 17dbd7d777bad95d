"""The per-post geometry of the visibility test fused into one numba kernel, for the common
aerial case: a frame camera without lens distortion over a grid in the map world frame.

:func:`orthomvp.visibility.compute_visibility` computes, for every post of a tile, its world
point, its normal (central differences, one-sided at the block's edges), the pixel it projects
to, whether it lies in the image and faces the camera, its emission angle and GSD, and (on a
grid finer than the DEM) the code carried from the four DEM posts around it. In numpy that is
some forty passes over (rows, cols, 3) float64 arrays; here it is one pass, with the same
formulas in the same order (no fast-math), so that the codes are the numpy path's and the
positions agree to the last bits of float64 (numpy's matrix product may fuse multiply-adds).
The rays of the posts it leaves to cast stay in numpy.

This module (and numba with it) is imported only when a grid is large enough for the kernel
to pay for the import (:data:`orthomvp.visibility.FUSED_POSTS`); the first call compiles into
numba's cache.
"""

from __future__ import annotations

import math

import numpy as np

from orthomvp.codes import Code
from orthomvp.jit import cached_jit

_NODATA, _VISIBLE = np.uint8(Code.NODATA), np.uint8(Code.VISIBLE)
_OCCLUDED, _AWAY = np.uint8(Code.OCCLUDED), np.uint8(Code.FACING_AWAY)


def _point(S: np.ndarray, z: np.ndarray, r: int, c: int) -> tuple[float, float, float]:
    """World point of block post (r, c) whose grid pixel is given by ``S`` rows 2-3."""
    gc, gr = S[2, 0] + c, S[2, 1] + r
    return S[0, 0] * gc + S[0, 1] * gr + S[0, 2], S[1, 0] * gc + S[1, 1] * gr + S[1, 2], z[r, c]


def _diff(
    S: np.ndarray, z: np.ndarray, r: int, c: int, dr: int, dc: int, n: int, k: int
) -> tuple[float, float, float]:
    """The difference of the block's points along one axis at (r, c) (``k`` the post's index
    along it, ``n`` the block's length, (``dr``, ``dc``) the unit step), as
    :func:`orthomvp.terrain._difference`: central, one-sided at the ends; where its first
    component is NaN, forward, else backward."""
    if 0 < k < n - 1:
        a = _point(S, z, r + dr, c + dc)
        b = _point(S, z, r - dr, c - dc)
        d = ((a[0] - b[0]) * 0.5, (a[1] - b[1]) * 0.5, (a[2] - b[2]) * 0.5)
    elif k == 0:
        a = _point(S, z, r + dr, c + dc)
        b = _point(S, z, r, c)
        d = (a[0] - b[0], a[1] - b[1], a[2] - b[2])
    else:
        a = _point(S, z, r, c)
        b = _point(S, z, r - dr, c - dc)
        d = (a[0] - b[0], a[1] - b[1], a[2] - b[2])
    if not math.isnan(d[0]):
        return d
    nan = math.nan
    if k + 1 < n:
        a = _point(S, z, r + dr, c + dc)
        b = _point(S, z, r, c)
        f = (a[0] - b[0], a[1] - b[1], a[2] - b[2])
        if not math.isnan(f[0]):
            return f
    if k >= 1:
        a = _point(S, z, r, c)
        b = _point(S, z, r - dr, c - dc)
        return (a[0] - b[0], a[1] - b[1], a[2] - b[2])
    return (nan, nan, nan)


def frame_posts(
    z: np.ndarray,
    S: np.ndarray,
    inner: np.ndarray,
    cam: np.ndarray,
    M: np.ndarray,
    carry: np.ndarray,
    Si: np.ndarray,
    occlusion: bool,
    codes: np.ndarray,
    uv: np.ndarray,
    emission: np.ndarray,
    gsd: np.ndarray,
    facing_gsd: np.ndarray,
    cast: np.ndarray,
) -> None:
    """Fill the per-post outputs of one tile (see :func:`orthomvp.visibility.compute_visibility`).

    ``z`` (R, C) the heights of the tile's block (the tile and one post around it within the
    grid); ``S`` (3, 3): rows 0-1 the grid's pixel-to-map affine, row 2 the block's first grid
    pixel (c, r); ``inner`` (4,) the tile's first row and column in the block and its rows and
    columns. ``cam`` (12,): centre (3), focal (2) and offset (2) in pitch units, pitch, width,
    height, the GSD's focal length in pixels, unused; ``M`` (3, 3) world to image axes.
    ``carry`` (rows, cols) uint8 codes of the DEM posts from DEM pixel (``Si`` row 2) on, with
    ``Si`` rows 0-1 the DEM's map-to-pixel affine (an empty ``carry``: none). Outputs, tile
    shaped: codes, uv (…, 2), emission (degrees), GSD (metres, NaN unless in the image and
    facing), the facing GSD (metres) and the posts left to ``cast``."""
    r0, c0, rows, cols = inner[0], inner[1], inner[2], inner[3]
    R, C = z.shape
    cx, cy, cz = cam[0], cam[1], cam[2]
    fu, fv, ou, ov, pitch = cam[3], cam[4], cam[5], cam[6], cam[7]
    width, height, gfocal = cam[8], cam[9], cam[10]
    has_carry = carry.shape[0] > 1 and carry.shape[1] > 1
    crow, ccol = carry.shape[0], carry.shape[1]
    nan = math.nan
    for i in range(rows):
        for j in range(cols):
            r, c = r0 + i, c0 + j
            px, py, pz = _point(S, z, r, c)
            a = _diff(S, z, r, c, 0, 1, C, c)
            b = _diff(S, z, r, c, 1, 0, R, r)
            n0 = a[1] * b[2] - a[2] * b[1]
            n1 = a[2] * b[0] - a[0] * b[2]
            n2 = a[0] * b[1] - a[1] * b[0]
            scale = (1.0 if n2 >= 0 else -1.0) / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            n0, n1, n2 = n0 * scale, n1 * scale, n2 * scale
            ok = math.isfinite(pz) and math.isfinite(n0) and math.isfinite(n1) and math.isfinite(n2)
            dx, dy, dz = px - cx, py - cy, pz - cz
            s0 = dx * M[0, 0] + dy * M[0, 1] + dz * M[0, 2]
            s1 = dx * M[1, 0] + dy * M[1, 1] + dz * M[1, 2]
            depth = dx * M[2, 0] + dy * M[2, 1] + dz * M[2, 2]
            u = v = nan
            if depth > 0:
                u = (s0 / depth * fu + ou) / pitch
                v = (s1 / depth * fv + ov) / pitch
            inside = ok and depth > 0 and -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5
            tx, ty, tz = cx - px, cy - py, cz - pz
            cos_e = (n0 * tx + n1 * ty + n2 * tz) / math.sqrt(tx * tx + ty * ty + tz * tz)
            fg = math.sqrt(dx * dx + dy * dy + dz * dz) / gfocal
            facing = cos_e > 0
            code = (_VISIBLE if facing else _AWAY) if inside else _NODATA
            todo = inside and facing and occlusion
            if todo and has_carry:
                dcol = Si[0, 0] * px + Si[0, 1] * py + Si[0, 2]
                drow = Si[1, 0] * px + Si[1, 1] * py + Si[1, 2]
                fi, fj = math.floor(drow) - Si[2, 1], math.floor(dcol) - Si[2, 0]
                if 0 <= fi < crow - 1 and 0 <= fj < ccol - 1:
                    ki, kj = int(fi), int(fj)
                    first = carry[ki, kj]
                    if (
                        (first == _VISIBLE or first == _OCCLUDED)
                        and carry[ki + 1, kj] == first
                        and carry[ki, kj + 1] == first
                        and carry[ki + 1, kj + 1] == first
                    ):
                        code = first
                        todo = False
            codes[i, j] = code
            uv[i, j, 0] = u if inside else nan
            uv[i, j, 1] = v if inside else nan
            emission[i, j] = math.degrees(math.acos(min(max(cos_e, -1.0), 1.0))) if ok else nan
            gsd[i, j] = fg / max(cos_e, 0.1) if inside and facing else nan
            facing_gsd[i, j] = fg
            cast[i, j] = todo


_point = cached_jit(_point)
_diff = cached_jit(_diff)
frame_posts = cached_jit(frame_posts)
