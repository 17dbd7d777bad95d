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
