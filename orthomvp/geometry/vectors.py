"""Row-wise operations on arrays of points and pixel positions, (..., k) with a short last
axis (k = 2 or 3): numpy's reductions and ``linalg.norm`` over such an axis are several times
slower than the same arithmetic column by column, and these run once per post and view."""

from __future__ import annotations

import numpy as np


def finite_rows(a: np.ndarray) -> np.ndarray:
    """True where every value along the last axis of ``a`` is finite: ``np.isfinite(a).all(
    axis=-1)`` without numpy's reduction over a short last axis, which is 2-3x slower for the
    (..., 2) and (..., 3) arrays of pixel positions and points."""
    a = np.asarray(a)
    ok = np.isfinite(a[..., 0])
    for k in range(1, a.shape[-1]):
        ok &= np.isfinite(a[..., k])
    return ok


def column_range(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest value of each column of ``a`` (n, k), (k,) each: ``a.min(axis=0)``
    and ``a.max(axis=0)`` (NaN propagates) column by column, which is several times faster
    for a few columns."""
    return (
        np.array([a[:, k].min() for k in range(a.shape[1])]),
        np.array([a[:, k].max() for k in range(a.shape[1])]),
    )


def row_norms(a: np.ndarray) -> np.ndarray:
    """Euclidean length of each row (last axis) of ``a``: ``np.linalg.norm(a, axis=-1)``,
    about 4x faster for rows of 3."""
    a = np.asarray(a)
    total = a[..., 0] * a[..., 0]
    for k in range(1, a.shape[-1]):
        total = total + a[..., k] * a[..., k]
    return np.sqrt(total)


def nan_median(a: np.ndarray) -> float:
    """The median of the values of ``a`` that are not NaN (NaN when there is none): the value
    of ``np.nanmedian(a)``, without numpy's median, whose first call imports ``numpy.ma``
    (10 ms of a command)."""
    v = np.asarray(a, dtype=np.float64).ravel()
    v = v[~np.isnan(v)]
    n = v.size
    if n == 0:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(v, k)[k])
    part = np.partition(v, [k - 1, k])
    return float((part[k - 1] + part[k]) / 2)


def perimeter(window: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions ``(c, r)`` of every post on the border of a window (row0, row1, col0,
    col1), half-open, in posts."""
    r0, r1, c0, c1 = window
    cols, rows = np.arange(c0, c1, dtype=np.float64), np.arange(r0, r1, dtype=np.float64)
    c = np.concatenate([cols, cols, np.full(len(rows), c0), np.full(len(rows), c1 - 1)])
    r = np.concatenate([np.full(len(cols), r0), np.full(len(cols), r1 - 1), rows, rows])
    return c, r


def unit_vector(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Eq. (3): body-fixed unit vector (..., 3) of planetocentric ``lon``, ``lat`` (radians)."""
    cl = np.cos(lat)
    return np.stack([np.cos(lon) * cl, np.sin(lon) * cl, np.sin(lat)], axis=-1)
