"""The row-wise helpers give numpy's own results (NaN and inf included)."""

from __future__ import annotations

import numpy as np

from orthomvp.geometry.vectors import column_range, finite_rows, row_norms


def test_rows_as_numpy() -> None:
    rng = np.random.default_rng(3)
    for k in (2, 3):
        a = rng.normal(0, 1e3, (40, 30, k))
        a[1, 2, 0], a[3, 4, k - 1], a[5, 6] = np.nan, np.inf, -np.inf
        np.testing.assert_array_equal(finite_rows(a), np.isfinite(a).all(axis=-1))
        np.testing.assert_allclose(row_norms(a), np.linalg.norm(a, axis=-1), rtol=1e-15)
        flat = a.reshape(-1, k)[np.isfinite(a).all(axis=-1).ravel()]
        lo, hi = column_range(flat)
        np.testing.assert_array_equal(lo, flat.min(axis=0))
        np.testing.assert_array_equal(hi, flat.max(axis=0))
    lo, hi = column_range(np.array([[1.0, np.nan], [0.0, 2.0]]))
    assert lo[0] == 0.0 and np.isnan(lo[1]) and np.isnan(hi[1])


def test_nan_median_is_numpys_nanmedian() -> None:
    from orthomvp.geometry.vectors import nan_median

    rng = np.random.default_rng(11)
    for n in (1, 2, 3, 10, 11, 1000, 1001):
        a = rng.normal(size=n) * 1e3
        a[rng.random(n) < 0.3] = np.nan
        a[0] = np.inf if n > 5 else a[0]
        expected = np.nanmedian(a) if np.isfinite(a).any() or np.isinf(a).any() else np.nan
        got = nan_median(a.reshape(-1, 1) if n % 2 else a)
        assert (np.isnan(got) and np.isnan(expected)) or got == expected
    assert np.isnan(nan_median(np.full((3, 4), np.nan)))
