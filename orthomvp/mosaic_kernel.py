"""The per-post steps of :func:`orthomvp.mosaic.compose` as numba kernels: the seam cost of
every view at a post (median of the visible views, disagreement, quantised total), the label
(least averaged cost) and the blend (weights and weighted values). The box sums between them
stay OpenCV's (:func:`orthomvp.mosaic.box_sum`).

The kernels give the numpy path's values bit for bit, which stays as their reference: the
same float32 and float64 operations in the same order (median and disagreement in float32,
costs in float64, no fused multiply-add). Each runs on one thread without the GIL (the engine's
tiles run in parallel).

numba is imported here (and in :mod:`orthomvp.jit`) only, and this module only when a mosaic
large enough to pay for it composes (:data:`orthomvp.mosaic.FUSED_POSTS`); loading the
compiled kernels from numba's cache takes about 0.3 s a process, compiling them the first time
a few seconds."""

from __future__ import annotations

import numpy as np

from orthomvp.jit import cached_jit

_QUANT = 1024.0
_DISAGREE = np.float32(4.0)
_TINY = np.float32(1e-12)
_ONE = np.float32(1.0)
_TWO = np.float32(2.0)


def _seam_quanta(
    values: np.ndarray,
    visible: np.ndarray,
    cost: np.ndarray,
    seen: np.ndarray,
    inside: np.ndarray,
    quanta: np.ndarray,
) -> None:
    """Into ``quanta`` (views, rows, cols) int64: the quantised seam cost of each view at each
    post where it is ``visible`` (0 elsewhere): its priority ``cost`` (NaN as 0), plus the
    share of the ``inside`` posts around that it does not see (``seen``), plus its
    disagreement with the median of the visible views' ``values``."""
    n, bands, rows, cols = values.shape
    sorted_ = np.empty(n, np.float32)
    median = np.empty(bands, np.float32)
    for r in range(rows):
        for c in range(cols):
            m = 0
            for k in range(n):
                if visible[k, r, c]:
                    m += 1
            if m == 0:
                for k in range(n):
                    quanta[k, r, c] = 0
                continue
            for b in range(bands):
                j = 0
                for k in range(n):  # insertion sort of the visible views' values
                    if visible[k, r, c]:
                        x = values[k, b, r, c]
                        i = j
                        while i > 0 and sorted_[i - 1] > x:
                            sorted_[i] = sorted_[i - 1]
                            i -= 1
                        sorted_[i] = x
                        j += 1
                median[b] = (sorted_[(m - 1) // 2] + sorted_[m // 2]) / _TWO
            for k in range(n):
                if not visible[k, r, c]:
                    quanta[k, r, c] = 0
                    continue
                d = np.float32(0.0)
                for b in range(bands):
                    x, mid = values[k, b, r, c], median[b]
                    rel = abs(x - mid) / (abs(x) + abs(mid) + _TINY) * _DISAGREE
                    d += rel if rel < _ONE else _ONE
                d = d / np.float32(bands)
                t = cost[k, r, c]
                if np.isnan(t):
                    t = 0.0
                t = t + (1.0 - seen[k, r, c] / inside[r, c])
                t = t + np.float64(d)
                quanta[k, r, c] = np.int64(np.rint(t * _QUANT))


def _least(cost: np.ndarray, seen: np.ndarray, visible: np.ndarray, label: np.ndarray) -> None:
    """Into ``label`` (rows, cols): the 0-based visible view of least ``cost`` (views, rows,
    cols; divided by ``seen`` unless it is empty), the first on ties or NaN, -1 where none is
    visible."""
    n, rows, cols = visible.shape
    divide = seen.shape[0] > 0
    for r in range(rows):
        for c in range(cols):
            best, low = -1, np.inf
            for k in range(n):
                if not visible[k, r, c]:
                    continue
                x = cost[k, r, c] / seen[k, r, c] if divide else cost[k, r, c]
                if np.isnan(x):
                    best = k
                    break
                if best < 0 or x < low:
                    best, low = k, x
            label[r, c] = best


def _blend(
    votes: np.ndarray,
    visible: np.ndarray,
    values: np.ndarray,
    label: np.ndarray,
    weights: np.ndarray,
    data: np.ndarray,
) -> None:
    """Into ``weights`` (views, rows, cols) float32: each visible view's ``votes`` over their
    sum at the post (the label's one-hot where that sum is 0); into ``data`` (bands, rows,
    cols) float32: the weighted sum of the visible views' ``values``, NaN where ``label`` is
    -1."""
    n, bands, rows, cols = values.shape
    for r in range(rows):
        for c in range(cols):
            total = 0
            for k in range(n):
                if visible[k, r, c]:
                    total += votes[k, r, c]
            for k in range(n):
                if total > 0:
                    v = votes[k, r, c] if visible[k, r, c] else 0
                    weights[k, r, c] = np.float32(v / total)
                else:
                    weights[k, r, c] = _ONE if label[r, c] == k else np.float32(0.0)
            if label[r, c] < 0:
                for b in range(bands):
                    data[b, r, c] = np.nan
                continue
            for b in range(bands):
                acc = np.float32(0.0)
                for k in range(n):
                    x = values[k, b, r, c] if visible[k, r, c] else np.float32(0.0)
                    acc += weights[k, r, c] * x
                data[b, r, c] = acc


_seam_quanta = cached_jit(_seam_quanta, fastmath=False, error_model="numpy")
_least = cached_jit(_least, fastmath=False, error_model="numpy")
_blend = cached_jit(_blend, fastmath=False, error_model="numpy")


def seam_quanta(
    values: np.ndarray, visible: np.ndarray, cost: np.ndarray, seen: np.ndarray, inside: np.ndarray
) -> np.ndarray:
    """:func:`_seam_quanta`'s result (views, rows, cols) int64."""
    out = np.empty(visible.shape, np.int64)
    _seam_quanta(values, visible, cost, seen, inside, out)
    return out


def least(cost: np.ndarray, visible: np.ndarray, seen: np.ndarray | None = None) -> np.ndarray:
    """:func:`_least`'s labels (rows, cols) int64."""
    out = np.empty(visible.shape[1:], np.int64)
    _least(cost, np.empty((0, 0, 0), np.int64) if seen is None else seen, visible, out)
    return out


def blend(
    votes: np.ndarray, visible: np.ndarray, values: np.ndarray, label: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_blend`'s weights (views, rows, cols) and data (bands, rows, cols), float32."""
    weights = np.empty(visible.shape, np.float32)
    data = np.empty((values.shape[1], *visible.shape[1:]), np.float32)
    _blend(votes, visible, values, label, weights, data)
    return weights, data
