"""Undo the smoothing of the window: from fitted plane heights back to surface heights.

A plane fitted under a Gaussian window to a curved surface passes, at its post, through the
window's weighted least-squares plane of the true heights, P(h) (to first order in the
misregistration): on a surface of curvature k that is h + k sigma^2 / 2 too high or low, which
is the largest error of the plane fitter on rolling terrain. Given fitted heights f = P(h), a
few Van Cittert steps ``d <- d + (f - P(d))``, from d = f, recover h: each step removes the
smoothing to the next order, and since P's Gaussian transfer function lies in [0, 1] no
frequency is amplified more than (steps + 1) times. P is the windowed plane fit itself (not a
plain Gaussian blur), so posts near holes and borders are corrected without bias from slopes.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d


def window_plane(values: np.ndarray, hwin: int, sigma: float) -> np.ndarray:
    """At every post, the value at the post of the plane fitted by Gaussian-weighted least
    squares (sigma in posts, |offsets| <= hwin) to the finite ``values`` around it; NaN where
    the fit is singular (too few neighbours) or the post itself is NaN."""
    ok = np.isfinite(values)
    w = ok.astype(np.float64)
    v = np.where(ok, values, 0.0)
    i = np.arange(-hwin, hwin + 1, dtype=np.float64)
    g = np.exp(-(i**2) / (2 * sigma**2))
    k = {0: g, 1: g * i, 2: g * i * i}

    def moment(f: np.ndarray, pc: int, pr: int) -> np.ndarray:
        out = correlate1d(f, k[pc], axis=1, mode="constant")
        return correlate1d(out, k[pr], axis=0, mode="constant")

    m = {(a, b): moment(w, a, b) for a, b in ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))}
    A = np.stack(
        [
            np.stack([m[0, 0], m[1, 0], m[0, 1]], -1),
            np.stack([m[1, 0], m[2, 0], m[1, 1]], -1),
            np.stack([m[0, 1], m[1, 1], m[0, 2]], -1),
        ],
        -2,
    )
    rhs = np.stack([moment(v, 0, 0), moment(v, 1, 0), moment(v, 0, 1)], -1)
    out = np.full(values.shape, np.nan)
    good = ok & (np.abs(np.linalg.det(A)) > 1e-9 * np.maximum(m[0, 0], 1e-300) ** 3)
    out[good] = np.linalg.solve(A[good], rhs[good][..., None])[:, 0, 0]
    return out


def deconvolve(fitted: np.ndarray, hwin: int, sigma: float, steps: int = 1) -> np.ndarray:
    """Surface heights from plane heights ``fitted`` (NaN where unresolved) by ``steps``
    Van Cittert steps against :func:`window_plane`; posts where the plane fit is singular keep
    their fitted value."""
    d = fitted.copy()
    for _ in range(steps):
        p = window_plane(d, hwin, sigma)
        d = np.where(np.isfinite(p), d + (fitted - p), d)
    return d
