"""Radiometric balance of a mosaic's views. This module owns the balance: the overlap statistics
of each pair of views (:func:`pair_stats`, summed over the windows of a survey), the per view
and band gains, and offsets, solved from them by constrained least squares with one view held
fixed or the mean held at identity (:func:`solve_balance`, :data:`BALANCES`), and the
:class:`Correction` that :func:`orthomvp.ortho.composite.compose` applies before it composes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from orthomvp.codes import Code
from orthomvp.errors import InputError

BALANCES = ("gain", "gain-offset")
"""Radiometric balancing: one gain per image and band (means matched on overlaps), or a gain
(standard deviations matched) and an offset (means matched)."""


@dataclass(frozen=True)
class Correction:
    """Per view and band: corrected = ``gains`` * value + ``offsets`` ((views, bands))."""

    gains: np.ndarray
    offsets: np.ndarray

    def apply(self, values: np.ndarray) -> np.ndarray:
        """``values`` (views, bands, ...) corrected, float32 (computed in float64 and rounded,
        one view at a time: the float64 products of a view, not of all, are held at once)."""
        shape = self.gains.shape[1:] + (1,) * (values.ndim - 2)
        out = np.empty(values.shape, np.float32)
        for k, (gain, offset) in enumerate(zip(self.gains, self.offsets, strict=True)):
            out[k] = values[k] * gain.reshape(shape) + offset.reshape(shape)
        return out


def pair_stats(values: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Overlap statistics (views, views, bands, 5) float64: for each ordered pair (i, j) and
    band, the posts both see, the sums of i's and of j's values, and of their squares (over
    the posts of that pair), from ``values`` (views, bands, rows, cols) and ``codes``."""
    n, bands = values.shape[:2]
    visible = (codes == Code.VISIBLE) & np.isfinite(values).all(axis=1)
    out = np.zeros((n, n, bands, 5))
    for i in range(n):
        for j in range(n):
            both = visible[i] & visible[j]
            if i == j or not both.any():
                continue
            a = values[i][:, both].astype(np.float64)
            b = values[j][:, both].astype(np.float64)
            out[i, j] = np.stack(
                [np.full(bands, both.sum()), a.sum(1), b.sum(1), (a * a).sum(1), (b * b).sum(1)],
                axis=1,
            )
    return out


def _constrained(
    rows: list[tuple[float, dict[int, float]]], n: int, reference: int | None
) -> np.ndarray:
    """Least squares of ``rows`` ((right-hand side, {unknown: coefficient})) over ``n``
    unknowns x, with x[reference] = its target or (None) the unknowns' mean at the target;
    targets are the rows' natural values: 1 for gains, 0 for offsets, given by the caller as
    the last row (coefficient 1 of every unknown, or of the reference)."""
    *eqs, (target, _) = rows
    a = np.zeros((len(eqs) + n, n))
    y = np.zeros(len(eqs) + n)
    for m, (rhs, coef) in enumerate(eqs):
        y[m] = rhs
        for k, v in coef.items():
            a[m, k] = v
    # a faint pull of every unknown towards the target keeps views without overlaps defined
    scale = 1e-6 * max(float(np.abs(a).max()), 1.0)
    a[len(eqs) :] = scale * np.eye(n)
    y[len(eqs) :] = scale * target
    c = np.zeros((1, n))
    if reference is None:
        c[0] = 1.0 / n
    else:
        c[0, reference] = 1.0
    kkt = np.block([[2 * a.T @ a, c.T], [c, np.zeros((1, 1))]])
    rhs = np.concatenate([2 * a.T @ y, [target]])
    return np.linalg.solve(kkt, rhs)[:n]


def solve_balance(
    stats: np.ndarray, mode: str, reference: int | None, *, left_out: Sequence[int] = ()
) -> Correction:
    """Per-view gains and offsets from :func:`pair_stats` (summed over windows): for every
    overlapping pair, weighted by the root of its posts, gains match the means (``mode``
    "gain") or the standard deviations ("gain-offset", whose offsets then match the means),
    with view ``reference`` held fixed (gain 1, offset 0) or the mean gain 1 and offset 0.
    Views ``left_out`` (that see no post) take no part: gain 1, offset 0, the others' as
    without them."""
    n, bands = stats.shape[0], stats.shape[2]
    if reference is not None and not 0 <= reference < n:
        raise InputError(f"balance reference {reference + 1} is not one of the {n} views")
    if left_out:
        if reference in left_out:
            raise InputError(f"balance reference {reference + 1} sees no post of the grid")
        kept = [k for k in range(n) if k not in left_out]
        ref = None if reference is None else kept.index(reference)
        solved = solve_balance(stats[np.ix_(kept, kept)], mode, ref)
        gains, offsets = np.ones((n, bands)), np.zeros((n, bands))
        gains[kept], offsets[kept] = solved.gains, solved.offsets
        return Correction(gains, offsets)
    gains, offsets = np.ones((n, bands)), np.zeros((n, bands))
    for b in range(bands):
        mean, std, weight = {}, {}, {}
        for i in range(n):
            for j in range(i + 1, n):
                cnt, si, sj, qi, qj = stats[i, j, b]
                if cnt < 2:
                    continue
                mean[i, j] = (si / cnt, sj / cnt)
                std[i, j] = (
                    np.sqrt(max(qi / cnt - (si / cnt) ** 2, 0.0)),
                    np.sqrt(max(qj / cnt - (sj / cnt) ** 2, 0.0)),
                )
                weight[i, j] = np.sqrt(cnt)
        match = std if mode == "gain-offset" else mean
        rows = [
            (0.0, {i: w * match[i, j][0], j: -w * match[i, j][1]}) for (i, j), w in weight.items()
        ]
        gains[:, b] = _constrained([*rows, (1.0, {})], n, reference)
        if mode == "gain-offset":
            g = gains[:, b]
            rows = [
                (-w * (g[i] * mean[i, j][0] - g[j] * mean[i, j][1]), {i: w, j: -w})
                for (i, j), w in weight.items()
            ]
            offsets[:, b] = _constrained([*rows, (0.0, {})], n, reference)
    return Correction(gains, offsets)
