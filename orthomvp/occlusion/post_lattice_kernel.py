"""The kernels of :mod:`orthomvp.occlusion.post_lattice` in numba: the units' checks and the
posts' interpolation (from the 2 x 2 or, cubic, the 4 x 4 nodes around a unit across rows and
columns, linear between levels), the world points, normals and post geometry, without numpy's
(points, channels) temporaries.

This module imports numba (through :mod:`orthomvp.jit`): it is imported where a lattice is
first used."""

from __future__ import annotations

import numpy as np

from orthomvp.jit import cached_jit


def _weights(t: float, cubic: bool, w: np.ndarray) -> None:
    """Into ``w`` (4,): the weights of the nodes at -1, 0, 1, 2 for a point at fraction ``t``
    between nodes 0 and 1: linear, or with ``cubic`` Catmull-Rom's (the cubic through the
    four, which passes through the nodes and is exact for quadratics)."""
    if not cubic:
        w[0], w[1], w[2], w[3] = 0.0, 1.0 - t, t, 0.0
        return
    t2 = t * t
    t3 = t2 * t
    w[0] = 0.5 * (-t3 + 2.0 * t2 - t)
    w[1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0)
    w[2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t)
    w[3] = 0.5 * (t3 - t2)


_weights = cached_jit(_weights, fastmath=False, error_model="numpy")


def _fill(
    buffer: np.ndarray,
    meta: np.ndarray,
    steps: np.ndarray,
    unit: np.ndarray,
    which: np.ndarray,
    rc: np.ndarray,
    where: np.ndarray,
    out: np.ndarray,
) -> None:
    """Into ``out`` (rows, cols, channels) at each post's tile row and column ``rc`` (posts, 2):
    its values interpolated in the unit that serves it (bilinear or cubic, as in
    :func:`verdicts`). ``where`` (posts, 3): the post's global row and column (in posts) and
    height (in levels); ``which`` (posts,): its finest unit; ``unit`` (units, 9): per finest
    unit the lattice serving it (-1: none, the post is left alone), that lattice's unit
    (global row, column, level), the unit's first node in that lattice's nodes (row, column,
    level), whether it is dead (its values NaN) and whether it is cubic. The lattices' nodes
    lie one after another in ``buffer``; ``meta`` (lattices, 3): where each begins and its
    numbers of node columns and levels; ``steps`` their steps in posts. The direction
    (channels 6..8) is normalised."""
    n_ch = out.shape[2]
    wa, wb = np.empty(4), np.empty(4)
    for p in range(which.shape[0]):
        u = which[p]
        k = unit[u, 0]
        if k < 0:
            continue
        step = steps[k]
        row, col = rc[p, 0], rc[p, 1]
        if unit[u, 7]:
            for q in range(n_ch):
                out[row, col, q] = np.nan
            continue
        a = where[p, 0] / step - unit[u, 1]
        b = where[p, 1] / step - unit[u, 2]
        t = where[p, 2] - unit[u, 3]
        cols, levels = meta[k, 1], meta[k, 2]
        dj = levels * n_ch
        di = cols * dj
        base = meta[k, 0] + unit[u, 4] * di + unit[u, 5] * dj + unit[u, 6] * n_ch
        if not unit[u, 8]:  # bilinear: the unit's corners alone
            w00, w01, w10, w11 = (1.0 - a) * (1.0 - b), (1.0 - a) * b, a * (1.0 - b), a * b
            for q in range(n_ch):
                s = base + q
                low = w00 * buffer[s] + w01 * buffer[s + dj]
                low += w10 * buffer[s + di] + w11 * buffer[s + di + dj]
                s += n_ch
                high = w00 * buffer[s] + w01 * buffer[s + dj]
                high += w10 * buffer[s + di] + w11 * buffer[s + di + dj]
                out[row, col, q] = low + t * (high - low)
        else:
            _weights(a, True, wa)
            _weights(b, True, wb)
            base -= di + dj
            for q in range(n_ch):
                low, high = 0.0, 0.0
                for x in range(4):
                    for y in range(4):
                        w = wa[x] * wb[y]
                        s = base + x * di + y * dj + q
                        low += w * buffer[s]
                        high += w * buffer[s + n_ch]
                out[row, col, q] = low + t * (high - low)
        norm = np.sqrt(out[row, col, 6] ** 2 + out[row, col, 7] ** 2 + out[row, col, 8] ** 2)
        for q in range(6, 9):
            out[row, col, q] /= norm


fill = cached_jit(_fill, fastmath=False, error_model="numpy")


def _affine_block(
    base: np.ndarray,
    up: np.ndarray,
    i: np.ndarray,
    ti: np.ndarray,
    j: np.ndarray,
    tj: np.ndarray,
    height: np.ndarray,
    out: np.ndarray,
) -> None:
    """Into ``out`` (rows, cols, 3): ``base`` + ``height`` * ``up`` at each post, ``base`` and
    ``up`` (node rows, node columns, 3) bilinear between nodes (rows first, then columns): a
    post of row r lies ``ti[r]`` of the way from node row ``i[r]`` to the next, of column c
    ``tj[c]`` from node column ``j[c]``; ``height`` (rows, cols)."""
    for r in range(out.shape[0]):
        a, t = i[r], ti[r]
        for c in range(out.shape[1]):
            b, u = j[c], tj[c]
            h = height[r, c]
            for q in range(3):
                v0 = base[a, b, q] + t * (base[a + 1, b, q] - base[a, b, q])
                v1 = base[a, b + 1, q] + t * (base[a + 1, b + 1, q] - base[a, b + 1, q])
                w0 = up[a, b, q] + t * (up[a + 1, b, q] - up[a, b, q])
                w1 = up[a, b + 1, q] + t * (up[a + 1, b + 1, q] - up[a, b + 1, q])
                out[r, c, q] = (v0 + u * (v1 - v0)) + h * (w0 + u * (w1 - w0))


affine_block = cached_jit(_affine_block, fastmath=False, error_model="numpy")


def _difference(p: np.ndarray, i: int, j: int, axis: int, out: np.ndarray) -> None:
    """Into ``out`` (3,): :func:`orthomvp.geometry.normals._difference` of the grid of points
    ``p`` (rows, cols, 3) at post (``i``, ``j``) along ``axis`` (0 rows, 1 columns): central,
    one-sided at the ends and, component by component, next to holes; the same operations in
    the same order, so the same values to the bit."""
    n = p.shape[axis]
    if n == 1:
        out[:] = 0.0
        return
    k = i if axis == 0 else j
    di, dj = (1, 0) if axis == 0 else (0, 1)
    if k == 0:
        for q in range(3):
            out[q] = p[i + di, j + dj, q] - p[i, j, q]
    elif k == n - 1:
        for q in range(3):
            out[q] = p[i, j, q] - p[i - di, j - dj, q]
    else:
        for q in range(3):
            out[q] = (p[i + di, j + dj, q] - p[i - di, j - dj, q]) * 0.5
    if not np.isnan(out[0]):
        return
    for q in range(3):
        fwd = p[i + di, j + dj, q] - p[i, j, q] if k < n - 1 else np.nan
        bwd = p[i, j, q] - p[i - di, j - dj, q] if k > 0 else np.nan
        out[q] = bwd if np.isnan(fwd) else fwd


_difference = cached_jit(_difference, fastmath=False, error_model="numpy")


def _normals(p: np.ndarray, radial: bool, out: np.ndarray) -> None:
    """Into ``out`` (rows, cols, 3): :func:`orthomvp.geometry.normals.grid_normals` of ``p``
    (rows, cols, 3) with ``up`` the points' own directions (``radial``, the body frame's
    :meth:`~orthomvp.geometry.terrain.Terrain.up_vectors`) or +z (the map frame's), to the
    bit."""
    a, b = np.empty(3), np.empty(3)
    for i in range(p.shape[0]):
        for j in range(p.shape[1]):
            _difference(p, i, j, 1, a)
            _difference(p, i, j, 0, b)
            n0 = a[1] * b[2] - a[2] * b[1]
            n1 = a[2] * b[0] - a[0] * b[2]
            n2 = a[0] * b[1] - a[1] * b[0]
            if radial:
                x, y, z = p[i, j, 0], p[i, j, 1], p[i, j, 2]
                norm = np.sqrt(x * x + y * y + z * z)
                up = n0 * (x / norm) + n1 * (y / norm) + n2 * (z / norm)
            else:
                up = n0 * 0.0 + n1 * 0.0 + n2 * 1.0
            scale = (1.0 if up >= 0 else -1.0) / np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            out[i, j, 0], out[i, j, 1], out[i, j, 2] = n0 * scale, n1 * scale, n2 * scale


normals = cached_jit(_normals, fastmath=False, error_model="numpy")


def _finish(
    values: np.ndarray,
    p: np.ndarray,
    n: np.ndarray,
    ok: np.ndarray,
    width: float,
    height: float,
    inside: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    cos_e: np.ndarray,
) -> None:
    """The posts' geometry from their ``values`` (rows, cols, 10), world points ``p`` and
    normals ``n`` (rows, cols, 3) where ``ok``: whether each is ``inside`` the image of
    ``width`` x ``height`` pixels (within half a pixel of its outermost centres) with a positive
    depth, the ray's ``origins`` and ``directions`` there (NaN elsewhere) and the emission
    cosine ``cos_e`` (NaN outside)."""
    for i in range(p.shape[0]):
        for j in range(p.shape[1]):
            u, v, depth = values[i, j, 0], values[i, j, 1], values[i, j, 2]
            seen = (
                ok[i, j] and depth > 0 and u >= -0.5 and u <= width - 0.5 and v >= -0.5
                and v <= height - 0.5
            )  # fmt: skip
            inside[i, j] = seen
            if not seen:
                for q in range(3):
                    origins[i, j, q] = directions[i, j, q] = np.nan
                cos_e[i, j] = np.nan
                continue
            for q in range(3):
                origins[i, j, q] = values[i, j, 3 + q]
                directions[i, j, q] = values[i, j, 6 + q]
            x = origins[i, j, 0] - p[i, j, 0]
            y = origins[i, j, 1] - p[i, j, 1]
            z = origins[i, j, 2] - p[i, j, 2]
            cos_e[i, j] = (n[i, j, 0] * x + n[i, j, 1] * y + n[i, j, 2] * z) / np.sqrt(
                x * x + y * y + z * z
            )


finish = cached_jit(_finish, fastmath=False, error_model="numpy")


def _verdicts(
    nodes: np.ndarray,
    first: np.ndarray,
    frac: np.ndarray,
    cubic: bool,
    exact: np.ndarray,
    xyz: np.ndarray,
    at: np.ndarray,
    error: float,
    far: float,
    gsd_relative: float,
    miss: np.ndarray,
    far_miss: np.ndarray,
) -> None:
    """Per unit whose first node is ``first`` (units, 3): whether its interpolation from
    ``nodes`` (node rows, node columns, levels, channels; bilinear across rows and columns from
    the unit's corners or, with ``cubic``, Catmull-Rom from the 4 x 4 nodes around it; linear
    between levels) at its checks' fractions ``frac`` (checks, 3) ``miss``-es
    the ``exact`` values (points, 10) at world points ``xyz`` (points, 3), ``at`` (units,
    checks) giving each check's point, by more than ``error`` pixels (the pixel's offset, or the
    ray's offset at the point in pixels of its GSD), by more than ``gsd_relative`` of the GSD,
    in the sign of the depth, or by not being finite; and whether it misses by more than
    ``far`` pixels (``far_miss``)."""
    n_ch = nodes.shape[3]
    wa, wb, est = np.empty(4), np.empty(4), np.empty(n_ch)
    for p in range(first.shape[0]):
        i, j, k = first[p, 0], first[p, 1], first[p, 2]
        worst = 0.0
        for m in range(frac.shape[0]):
            _weights(frac[m, 0], cubic, wa)
            _weights(frac[m, 1], cubic, wb)
            t = frac[m, 2]
            finite = True
            for q in range(n_ch):
                low, high = 0.0, 0.0
                for x in range(4):
                    if wa[x] == 0.0 and not cubic:
                        continue
                    for y in range(4):
                        if wb[y] == 0.0 and not cubic:
                            continue
                        w = wa[x] * wb[y]
                        low += w * nodes[i - 1 + x, j - 1 + y, k, q]
                        high += w * nodes[i - 1 + x, j - 1 + y, k + 1, q]
                est[q] = low + t * (high - low)
                finite = finite and np.isfinite(est[q]) and np.isfinite(exact[at[p, m], q])
            if not finite:
                worst = np.inf
                break
            e = exact[at[p, m]]
            gsd = e[9]
            uv = np.hypot(est[0] - e[0], est[1] - e[1])
            rng = np.sqrt(
                (xyz[at[p, m], 0] - e[3]) ** 2 + (xyz[at[p, m], 1] - e[4]) ** 2
                + (xyz[at[p, m], 2] - e[5]) ** 2
            )  # fmt: skip
            norm = np.sqrt(est[6] ** 2 + est[7] ** 2 + est[8] ** 2)
            turn = np.sqrt(
                (est[6] / norm - e[6]) ** 2 + (est[7] / norm - e[7]) ** 2
                + (est[8] / norm - e[8]) ** 2
            )  # fmt: skip
            shift = np.sqrt((est[3] - e[3]) ** 2 + (est[4] - e[4]) ** 2 + (est[5] - e[5]) ** 2)
            ray = (shift + rng * turn) / gsd
            if not (abs(est[9] - gsd) <= gsd_relative * gsd and np.sign(est[2]) == np.sign(e[2])):
                worst = np.inf
                break
            worst = max(worst, uv, ray)
            if not worst <= far:
                break
        miss[p] = not worst <= error
        far_miss[p] = not worst <= far


verdicts = cached_jit(_verdicts, fastmath=False, error_model="numpy")


def _posts(
    ok: np.ndarray,
    heights: np.ndarray,
    row0: float,
    col0: float,
    fine: int,
    level: float,
    rc: np.ndarray,
    where: np.ndarray,
    cell: np.ndarray,
) -> None:
    """The posts where ``ok`` (rows, cols), in row-major order: their tile row and column
    ``rc`` (posts, 2); ``where`` (posts, 3), their global row and column (``row0``, ``col0``:
    those of the tile's post (0, 0)) and their height in ``level`` units (``heights`` (rows,
    cols)); and ``cell`` (posts, 3), the unit of the lattice of ``fine`` posts holding each
    (global cell row, column, level)."""
    p = 0
    for i in range(ok.shape[0]):
        for j in range(ok.shape[1]):
            if not ok[i, j]:
                continue
            gr, gc = i + row0, j + col0
            fl = np.float64(heights[i, j]) / level
            rc[p, 0], rc[p, 1] = i, j
            where[p, 0], where[p, 1], where[p, 2] = gr, gc, fl
            cell[p, 0] = np.int64(np.floor(gr / fine))
            cell[p, 1] = np.int64(np.floor(gc / fine))
            cell[p, 2] = np.int64(np.floor(fl))
            p += 1


posts = cached_jit(_posts, fastmath=False, error_model="numpy")


def _unique_table(a: np.ndarray, most: int, rows: np.ndarray, inverse: np.ndarray) -> int:
    """The distinct rows of ``a`` (n, 3) of integers in order into ``rows`` (n, 3), and where
    each row of ``a`` is among them into ``inverse`` (n,), through a table over their span
    (as :func:`orthomvp.occlusion.post_lattice._unique_rows`); returns their number, or -1
    (nothing written) when the span holds more than ``most`` entries."""
    n = a.shape[0]
    low0, low1, low2 = a[0, 0], a[0, 1], a[0, 2]
    high0, high1, high2 = low0, low1, low2
    for i in range(1, n):
        low0, high0 = min(low0, a[i, 0]), max(high0, a[i, 0])
        low1, high1 = min(low1, a[i, 1]), max(high1, a[i, 1])
        low2, high2 = min(low2, a[i, 2]), max(high2, a[i, 2])
    span1, span2 = high1 - low1 + 1, high2 - low2 + 1
    if np.float64(high0 - low0 + 1) * np.float64(span1) * np.float64(span2) > most:
        return -1
    table = np.zeros((high0 - low0 + 1) * span1 * span2, np.int64)
    for i in range(n):
        inverse[i] = ((a[i, 0] - low0) * span1 + (a[i, 1] - low1)) * span2 + (a[i, 2] - low2)
        table[inverse[i]] = 1
    m = 0
    for key in range(table.shape[0]):
        if table[key]:
            rows[m, 0] = key // (span1 * span2) + low0
            rows[m, 1] = key // span2 % span1 + low1
            rows[m, 2] = key % span2 + low2
            table[key] = m
            m += 1
    for i in range(n):
        inverse[i] = table[inverse[i]]
    return m


unique_table = cached_jit(_unique_table, fastmath=False, error_model="numpy")
