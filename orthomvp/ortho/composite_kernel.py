"""The labels and the blend of :func:`orthomvp.ortho.composite.compose` as numba kernels: the seam
cost of every view at a post (median of the visible views, disagreement, quantised total), its box
sums, the label (least averaged cost), the blend votes (box sums of the labels) and the
weighted values, without the numpy path's temporaries.

The kernels give the numpy path's values bit for bit, which stays as their reference: the
same float32 and float64 operations in the same order (median and disagreement in float32,
costs in float64, no fused multiply-add), and box sums of integers, exact in any order. Each
runs on one thread without the GIL (the engine's tiles run in parallel).

This module imports numba (through :mod:`orthomvp.jit`): it is imported only when a mosaic
large enough to pay for it composes (:data:`orthomvp.ortho.composite.FUSED_POSTS`); loading the
compiled kernels from numba's cache takes about 0.3 s a process with numba's import,
compiling them the first time a few seconds."""

from __future__ import annotations

import numpy as np

from orthomvp.jit import cached_jit

_TINY = np.float32(1e-12)
_ONE = np.float32(1.0)
_TWO = np.float32(2.0)
_FEW = 8
"""Values a seam median sorts outright (:func:`_middle`); more are selected."""


def _box(a: np.ndarray, radius: int, out: np.ndarray, tmp: np.ndarray) -> None:
    """Into ``out`` (rows, cols; integers): the sums of ``a`` (rows, cols; integers or
    booleans) over the (2 ``radius`` + 1)^2 box around each post, zero beyond the array (as
    :func:`orthomvp.ortho.composite.box_sum`); ``tmp`` (rows, cols; integers) is scratch. ``out``
    may be ``a`` itself."""
    rows, cols = a.shape
    if rows == 0 or cols == 0:  # nothing to sum (and no first row to start from)
        return
    for c in range(cols):  # the column sums of the first row's box
        tmp[0, c] = 0
    for i in range(min(radius + 1, rows)):
        for c in range(cols):
            tmp[0, c] += a[i, c]
    for r in range(1, rows):  # then slide down, a row in and a row out
        enter, leave = r + radius, r - radius - 1
        for c in range(cols):
            s = tmp[r - 1, c]
            if enter < rows:
                s += a[enter, c]
            if leave >= 0:
                s -= a[leave, c]
            tmp[r, c] = s
    for r in range(rows):  # and along each row
        s = 0
        for c in range(min(radius + 1, cols)):
            s += tmp[r, c]
        out[r, 0] = s
        for c in range(1, cols):
            enter, leave = c + radius, c - radius - 1
            if enter < cols:
                s += tmp[r, enter]
            if leave >= 0:
                s -= tmp[r, leave]
            out[r, c] = s


def _count(n: int, i: int, radius: int) -> int:
    """Posts of an axis of ``n`` posts within ``radius`` of post ``i``."""
    return min(i + radius, n - 1) - max(i - radius, 0) + 1


def _seam_labels(
    values: np.ndarray,
    visible: np.ndarray,
    cost: np.ndarray,
    radius: int,
    quant: float,
    disagree: np.float32,
    label: np.ndarray,
    seen: np.ndarray,
    quanta: np.ndarray,
    tmp: np.ndarray,
) -> None:
    """Into ``label`` (rows, cols) int64: the visible view of least seam cost at each post (the
    first on ties, -1 where none is visible), as :func:`orthomvp.ortho.composite.labels` with
    seamlines: each view's priority ``cost`` (NaN as 0), plus the share of the posts within
    ``radius`` that it does not see, plus its disagreement with the median of the visible views'
    ``values`` (times ``disagree``, at most 1), in steps of 1 / ``quant``, summed over the
    visible posts within ``radius`` and divided by their number. ``seen`` and ``quanta``
    (views, rows, cols) and ``tmp`` (rows, cols), integers, are scratch."""
    n, bands, rows, cols = values.shape
    for k in range(n):
        _box(visible[k], radius, seen[k], tmp)
    ordered = np.empty(n, np.float32)
    median = np.empty(bands, np.float32)
    for r in range(rows):
        across = _count(rows, r, radius)
        for c in range(cols):
            inside = across * _count(cols, c, radius)
            m = 0
            for k in range(n):
                if visible[k, r, c]:
                    m += 1
            for b in range(bands):
                j = 0
                for k in range(n):  # the visible views' values
                    if visible[k, r, c]:
                        ordered[j] = values[k, b, r, c]
                        j += 1
                if m > 0:
                    median[b] = _middle(ordered, m)
            for k in range(n):
                if not visible[k, r, c]:
                    quanta[k, r, c] = 0
                    continue
                d = np.float32(0.0)
                for b in range(bands):
                    x, mid = values[k, b, r, c], median[b]
                    rel = abs(x - mid) / (abs(x) + abs(mid) + _TINY) * disagree
                    d += rel if rel < _ONE else _ONE  # (NaN as 1, as numpy's fmin)
                d = d / np.float32(bands)
                t = cost[k, r, c]
                if np.isnan(t):
                    t = 0.0
                t = t + (1.0 - seen[k, r, c] / inside)
                t = t + np.float64(d)
                quanta[k, r, c] = np.int64(np.rint(t * quant))
    for k in range(n):
        _box(quanta[k], radius, quanta[k], tmp)
    _least(quanta, seen, visible, label)


def _middle(a: np.ndarray, m: int) -> np.float32:
    """The median of ``a[:m]`` (finite; m >= 1) in float32, the mean of its two middle values
    when m is even (as numpy's sorted median), found by selection: an insertion sort up to
    :data:`_FEW` values, else a quickselect (three-way partitions about a median of three,
    linear in m on average). ``a[:m]`` is reordered."""
    hi = m // 2
    if m <= _FEW:
        for j in range(1, m):
            x, i = a[j], j
            while i > 0 and a[i - 1] > x:
                a[i] = a[i - 1]
                i -= 1
            a[i] = x
        return (a[(m - 1) // 2] + a[hi]) / _TWO
    upper = _select(a, m, hi)
    if m % 2:
        return (upper + upper) / _TWO
    lower = a[0]  # a[:hi] holds the hi smallest values: the lower middle is their largest
    for i in range(1, hi):
        if a[i] > lower:
            lower = a[i]
    return (lower + upper) / _TWO


def _select(a: np.ndarray, m: int, k: int) -> np.float32:
    """The ``k``-th smallest (0-based) of ``a[:m]``, with ``a[:m]`` reordered so that the values
    before position ``k`` are no larger (quickselect)."""
    lo, hi = 0, m - 1
    while lo < hi:
        x, y, z = a[lo], a[(lo + hi) // 2], a[hi]
        pivot = max(min(x, y), min(max(x, y), z))  # the median of the three
        lt, i, gt = lo, lo, hi
        while i <= gt:  # a[lo:lt] < pivot, a[lt:i] == pivot, a[gt + 1 : hi + 1] > pivot
            v = a[i]
            if v < pivot:
                a[i], a[lt] = a[lt], v
                lt += 1
                i += 1
            elif v > pivot:
                a[i], a[gt] = a[gt], v
                gt -= 1
            else:
                i += 1
        if k < lt:
            hi = lt - 1
        elif k > gt:
            lo = gt + 1
        else:
            return pivot
    return a[k]


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
    label: np.ndarray,
    visible: np.ndarray,
    values: np.ndarray,
    radius: int,
    weights: np.ndarray,
    data: np.ndarray,
    votes: np.ndarray,
    tmp: np.ndarray,
) -> None:
    """Into ``weights`` (views, rows, cols) float32: each visible view's posts labelled with it
    within ``radius`` (a box; 0: the post alone) over their sum at the post (the label's
    one-hot where that sum is 0); into ``data`` (bands, rows, cols) float32: the weighted sum
    of the visible views' ``values``, NaN where ``label`` is -1. ``votes`` (views, rows,
    cols) and ``tmp`` (rows, cols), integers, are scratch."""
    n, bands, rows, cols = values.shape
    for k in range(n):
        for r in range(rows):
            for c in range(cols):
                votes[k, r, c] = 1 if label[r, c] == k else 0
        if radius > 0:
            _box(votes[k], radius, votes[k], tmp)
    for r in range(rows):
        for c in range(cols):
            total, voter = 0, -1
            for k in range(n):
                if visible[k, r, c] and votes[k, r, c] > 0:
                    voter = k if total == 0 else -2  # the one view with votes, or -2
                    total += votes[k, r, c]
            if voter >= 0:  # one view's votes: its weight v / v = 1, the others' 0
                for k in range(n):
                    weights[k, r, c] = _ONE if k == voter else np.float32(0.0)
                for b in range(bands):  # (0 + value, as the weighted sum: -0 becomes +0)
                    data[b, r, c] = np.float32(0.0) + values[voter, b, r, c]
                continue
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
                    if weights[k, r, c] == 0:
                        continue  # (+-0 added to the sum, never -0, changes nothing)
                    x = values[k, b, r, c] if visible[k, r, c] else np.float32(0.0)
                    acc += weights[k, r, c] * x
                data[b, r, c] = acc


_box = cached_jit(_box, fastmath=False, error_model="numpy")
_count = cached_jit(_count, fastmath=False, error_model="numpy", inline="always")
_select = cached_jit(_select, fastmath=False, error_model="numpy")
_middle = cached_jit(_middle, fastmath=False, error_model="numpy")
_least = cached_jit(_least, fastmath=False, error_model="numpy")
_seam_labels = cached_jit(_seam_labels, fastmath=False, error_model="numpy")
_blend = cached_jit(_blend, fastmath=False, error_model="numpy")


def labels(
    cost: np.ndarray,
    visible: np.ndarray,
    values: np.ndarray,
    radius: int | None,
    quant: int = 0,
    disagree: float = 0.0,
) -> np.ndarray:
    """The 0-based view of each post (rows, cols) int64, -1 where none is ``visible``: least
    priority ``cost``, or least seam cost over ``radius`` (None: no seamlines) with the
    disagreement's scale ``disagree`` and ``quant`` steps per unit of cost
    (:data:`orthomvp.ortho.composite.DISAGREE`, :data:`orthomvp.ortho.composite.QUANT`). The labels
    of
    :func:`orthomvp.ortho.composite.labels` for what :func:`~orthomvp.ortho.composite.compose`
    gives it: finite costs and values where visible."""
    out = np.empty(visible.shape[1:], np.int64)
    if radius is None:
        _least(cost, np.empty((0, 0, 0), np.int64), visible, out)
    else:  # int32 scratch (half the memory traffic of int64) where the box sums of the
        # quanta surely fit: a post's are at most (its cost + 2) quant
        top = np.fmax.reduce(np.abs(cost), axis=None, initial=0.0)
        small = np.isfinite(top) and (2 * radius + 1) ** 2 * quant * (top + 3) < 2**31
        dtype = np.int32 if small else np.int64
        seen, quanta = np.empty(visible.shape, dtype), np.empty(visible.shape, dtype)
        tmp = np.empty(out.shape, dtype)
        scale, step = np.float32(disagree), float(quant)
        _seam_labels(values, visible, cost, radius, step, scale, out, seen, quanta, tmp)
    return out


def blend(
    label: np.ndarray, visible: np.ndarray, values: np.ndarray, radius: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_blend`'s weights (views, rows, cols) and data (bands, rows, cols), float32."""
    weights = np.empty(visible.shape, np.float32)
    data = np.empty((values.shape[1], *visible.shape[1:]), np.float32)
    votes = np.empty(visible.shape, np.int32)  # at most (2 radius + 1)^2
    _blend(label, visible, values, radius, weights, data, votes, np.empty(label.shape, np.int32))
    return weights, data
