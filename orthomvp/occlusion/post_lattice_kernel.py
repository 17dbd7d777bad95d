"""The interpolation of :mod:`orthomvp.occlusion.post_lattice` as a numba kernel: each point's
values from the eight nodes of its unit, without numpy's (points, channels) temporaries.

This module imports numba (through :mod:`orthomvp.jit`): it is imported where a lattice is
first used."""

from __future__ import annotations

import numpy as np

from orthomvp.jit import cached_jit


def _interpolate(nodes: np.ndarray, first: np.ndarray, frac: np.ndarray, out: np.ndarray) -> None:
    """Into ``out`` (points, channels): the values of ``nodes`` (node rows, node columns,
    levels, channels) interpolated (bilinear across rows and columns, linear between levels)
    at each point's fractions ``frac`` (points, 3) of its unit, whose first node is ``first``
    (points, 3: node row, column, level)."""
    for p in range(first.shape[0]):
        i, j, k = first[p, 0], first[p, 1], first[p, 2]
        a, b, t = frac[p, 0], frac[p, 1], frac[p, 2]
        for q in range(nodes.shape[3]):
            low = (1.0 - a) * ((1.0 - b) * nodes[i, j, k, q] + b * nodes[i, j + 1, k, q]) + a * (
                (1.0 - b) * nodes[i + 1, j, k, q] + b * nodes[i + 1, j + 1, k, q]
            )
            k1 = k + 1
            high = (1.0 - a) * ((1.0 - b) * nodes[i, j, k1, q] + b * nodes[i, j + 1, k1, q]) + a * (
                (1.0 - b) * nodes[i + 1, j, k1, q] + b * nodes[i + 1, j + 1, k1, q]
            )
            out[p, q] = low + t * (high - low)


interpolate = cached_jit(_interpolate, fastmath=False, error_model="numpy")


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
    its values interpolated in the unit that serves it. ``where`` (posts, 3): the post's
    global row and column (in posts) and height (in levels); ``which`` (posts,): its finest
    unit; ``unit`` (units, 8): per finest unit the lattice serving it (-1: none, the post is
    left alone), that lattice's unit (global row, column, level), the unit's first node in
    that lattice's nodes (row, column, level) and whether it is dead (its values NaN). The
    lattices' nodes lie one after another in ``buffer``; ``meta`` (lattices, 3): where each
    begins and its numbers of node columns and levels; ``steps`` their steps in posts. The
    direction (channels 6..8) is normalised."""
    n_ch = out.shape[2]
    for p in range(which.shape[0]):
        u = which[p]
        k = unit[u, 0]
        if k < 0:
            continue
        step = steps[k]
        a = where[p, 0] / step - unit[u, 1]
        b = where[p, 1] / step - unit[u, 2]
        t = where[p, 2] - unit[u, 3]
        row, col = rc[p, 0], rc[p, 1]
        if unit[u, 7]:
            for q in range(n_ch):
                out[row, col, q] = np.nan
            continue
        cols, levels = meta[k, 1], meta[k, 2]
        dl = n_ch
        dj = levels * n_ch
        di = cols * dj
        base = meta[k, 0] + unit[u, 4] * di + unit[u, 5] * dj + unit[u, 6] * dl
        for q in range(n_ch):
            s = base + q
            low = (1.0 - a) * ((1.0 - b) * buffer[s] + b * buffer[s + dj]) + a * (
                (1.0 - b) * buffer[s + di] + b * buffer[s + di + dj]
            )
            s += dl
            high = (1.0 - a) * ((1.0 - b) * buffer[s] + b * buffer[s + dj]) + a * (
                (1.0 - b) * buffer[s + di] + b * buffer[s + di + dj]
            )
            out[row, col, q] = low + t * (high - low)
        norm = np.sqrt(out[row, col, 6] ** 2 + out[row, col, 7] ** 2 + out[row, col, 8] ** 2)
        for q in range(6, 9):
            out[row, col, q] /= norm


fill = cached_jit(_fill, fastmath=False, error_model="numpy")
