"""Local normalised cross-correlation (NCC) of two rasters, and statistics of NCC values by
first-hit miss distance that merge exactly, whatever tiles they were gathered in.

Box sums run in a fixed order over each post's own neighbours (no running sums along rows),
so an NCC value depends only on the posts of its window: a tile computed with
``window // 2`` posts around it gives the whole grid's values bit for bit.

:class:`NccTally` keeps, per miss bin, counts, the exact sum of the NCC values (fixed point,
units of 2**-52) and a histogram of :data:`NCC_BINS` bins over [-1, 1]. Merging two tallies
adds integers, so the merged counts, means and histograms do not depend on how the values
were split or in what order they arrived; medians come from the histogram, within
:data:`MEDIAN_BOUND` of the exact median.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MISS_BINS = (0.0, 0.25, 1.0, 2.0, 4.0, 8.0, 16.0, np.inf)
"""Edges of the miss-distance bins, DEM posts (each bin includes its lower edge)."""
ROW_EDGES = list(zip(MISS_BINS[:-1], MISS_BINS[1:], strict=True)) + [(0.0, np.inf)]
"""The (from, to) miss distances of a check's rows: each bin, then all of them."""


def check_row(
    eps: float, pair: tuple[str, str], cls: str, edges: tuple[float, float], figures: tuple
) -> dict:
    """One row of the check's CSV (:data:`orthomvp.quality.check.CSV_FIELDS`): ``eps``, the views
    ``pair`` (view, other), the class, the miss ``edges`` and ``figures`` (posts, scored,
    NCC mean, NCC median)."""
    posts, scored, mean, median = figures
    return {
        "eps": eps,
        "view": pair[0],
        "other": pair[1],
        "class": cls,
        "miss_from": edges[0],
        "miss_to": edges[1],
        "posts": posts,
        "scored": scored,
        "ncc_mean": mean,
        "ncc_median": median,
    }


NCC_BINS = 4000
"""Bins of the NCC histogram over [-1, 1] (width 0.0005)."""
MEDIAN_BOUND = 1.0 / NCC_BINS
"""Largest difference between a tally's median and the exact median: half a bin (0.00025).
Each middle value is taken as the centre of its bin."""
FIXED = 52
"""Sums are kept as integers in units of 2**-FIXED (NCC values rounded by at most 2**-53)."""
_HALF = 26
"""Fixed-point values are summed as high and low halves of this many bits (exact in int64)."""


def box_sum(x: np.ndarray, window: int) -> np.ndarray:
    """Sums of ``x`` (rows, cols) over the ``window`` x ``window`` box (odd) around each
    post, zeros beyond the array; each sum adds the post's own neighbours in a fixed order."""
    h = window // 2
    rows, cols = x.shape
    padded = np.pad(np.asarray(x, np.float64), h)
    across = padded[:, :cols].copy()
    for j in range(1, window):
        across += padded[:, j : j + cols]
    out = across[:rows].copy()
    for i in range(1, window):
        out += across[i : i + rows]
    return out


def local_ncc(a: np.ndarray, b: np.ndarray, window: int) -> np.ndarray:
    """NCC (rows, cols) of ``a`` and ``b`` (rows, cols; NaN = no value) in a ``window`` x
    ``window`` box (odd) around each post, over the posts where both have values; NaN where
    fewer than half the box has both, or where either is flat (variance <= 1e-10)."""
    ok = np.isfinite(a) & np.isfinite(b)
    a0, b0 = np.where(ok, a, 0.0).astype(np.float64), np.where(ok, b, 0.0).astype(np.float64)
    n = box_sum(ok.astype(np.float64), window)
    with np.errstate(invalid="ignore", divide="ignore"):
        ma, mb = box_sum(a0, window) / n, box_sum(b0, window) / n
        va = box_sum(a0 * a0, window) / n - ma * ma
        vb = box_sum(b0 * b0, window) / n - mb * mb
        cov = box_sum(a0 * b0, window) / n - ma * mb
        ncc = cov / np.sqrt(va * vb)
    good = (n >= window * window / 2) & (va > 1e-10) & (vb > 1e-10)
    return np.where(good, np.clip(ncc, -1, 1), np.nan)


def miss_bin(miss: np.ndarray) -> np.ndarray:
    """The index of each miss distance's bin in :data:`MISS_BINS` (miss >= 0, finite)."""
    return np.searchsorted(MISS_BINS, miss, side="right") - 1


@dataclass
class NccTally:
    """NCC values of posts by miss bin (:data:`MISS_BINS`): per bin the ``posts``, those
    ``scored`` (a finite NCC), the exact ``sums`` of their NCC values in units of 2**-52
    (Python integers), and their histogram, sparse: the occupied ``cells`` (miss bin times
    :data:`NCC_BINS` plus NCC bin, sorted) and their ``counts``."""

    posts: np.ndarray
    scored: np.ndarray
    sums: list[int]
    cells: np.ndarray
    counts: np.ndarray

    @classmethod
    def empty(cls) -> NccTally:
        bins = len(MISS_BINS) - 1
        zero = np.zeros(bins, np.int64)
        return cls(zero, zero.copy(), [0] * bins, np.zeros(0, np.int64), np.zeros(0, np.int64))

    @classmethod
    def of(cls, miss: np.ndarray, ncc: np.ndarray) -> NccTally:
        """The tally of posts with first-hit ``miss`` distances (DEM posts, >= 0) and
        ``ncc`` values (NaN: not scored), 1-D arrays of the same length."""
        bins = len(MISS_BINS) - 1
        m = miss_bin(miss)
        ok = np.isfinite(ncc)
        m_ok, v = m[ok], ncc[ok]
        fixed = np.rint(v * 2.0**FIXED).astype(np.int64)
        hi, lo = np.zeros(bins, np.int64), np.zeros(bins, np.int64)
        np.add.at(hi, m_ok, fixed >> _HALF)
        np.add.at(lo, m_ok, fixed & ((1 << _HALF) - 1))
        sums = [(int(h) << _HALF) + int(low) for h, low in zip(hi, lo, strict=True)]
        k = np.clip(np.floor((v + 1.0) * (NCC_BINS / 2)), 0, NCC_BINS - 1).astype(np.int64)
        cells, counts = np.unique(m_ok * NCC_BINS + k, return_counts=True)
        return cls(
            np.bincount(m, minlength=bins).astype(np.int64),
            np.bincount(m_ok, minlength=bins).astype(np.int64),
            sums,
            cells.astype(np.int64),
            counts.astype(np.int64),
        )

    def merge(self, other: NccTally) -> NccTally:
        """Both tallies' values together (exact: integers only)."""
        cells = np.concatenate([self.cells, other.cells])
        counts = np.concatenate([self.counts, other.counts])
        unique, where = np.unique(cells, return_inverse=True)
        merged = np.zeros(len(unique), np.int64)
        np.add.at(merged, where, counts)
        return NccTally(
            self.posts + other.posts,
            self.scored + other.scored,
            [a + b for a, b in zip(self.sums, other.sums, strict=True)],
            unique,
            merged,
        )

    def summary(self, k: int | None = None) -> tuple[int, int, float, float]:
        """(posts, scored, mean NCC, median NCC) of miss bin ``k``, or of all bins (None);
        NaN mean and median without scored posts. The mean is the exact mean of the values
        rounded to 2**-52, correctly rounded; the median within :data:`MEDIAN_BOUND`."""
        bins = slice(None) if k is None else slice(k, k + 1)
        posts, scored = int(self.posts[bins].sum()), int(self.scored[bins].sum())
        if not scored:
            return posts, 0, float("nan"), float("nan")
        total = sum(self.sums[bins])
        mean = total / (scored << FIXED)  # int / int: correctly rounded
        sel = slice(None) if k is None else self.cells // NCC_BINS == k
        hist = np.zeros(NCC_BINS, np.int64)
        np.add.at(hist, self.cells[sel] % NCC_BINS, self.counts[sel])
        cumulative = np.cumsum(hist)
        ranks = [scored // 2] if scored % 2 else [scored // 2 - 1, scored // 2]
        at = np.searchsorted(cumulative, ranks, side="right")
        median = float(np.mean(-1.0 + (at + 0.5) * (2.0 / NCC_BINS)))
        return posts, scored, float(mean), median
