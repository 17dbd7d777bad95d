"""The MVP benchmark's figures agree with the fit they time and with each other."""

from __future__ import annotations

import math

import pytest

from orthomvp.bench import format_mvp
from orthomvp.bench import mvp as mvp_bench
from orthomvp.mvp.fit import FitResult


@pytest.mark.slow
def test_bench_mvp_is_consistent(monkeypatch: pytest.MonkeyPatch) -> None:
    fits: list[FitResult] = []
    fit_dem = mvp_bench.fit_dem

    def recording(*args: object, **kwargs: object) -> FitResult:
        fits.append(fit_dem(*args, **kwargs))
        return fits[-1]

    monkeypatch.setattr(mvp_bench, "fit_dem", recording)
    row = mvp_bench.bench_mvp(40)
    (fit,) = fits
    assert row["samples"] > 0 and row["samples"] == fit.samples
    # the baseline takes as many samples, short of less than one map row (3 x 21 x 21)
    assert row["samples"] - 3 * 21 * 21 < row["remap_samples"] <= row["samples"]
    assert row["fitted"] == int(fit.resolved.sum()) > 0
    assert row["fit_s"] > 0 and row["remap_s"] > 0
    assert row["posts_per_s"] == pytest.approx(row["fitted"] / row["fit_s"])
    assert row["ratio"] == pytest.approx(row["fit_s"] / row["remap_s"])
    assert math.isfinite(row["rmse_m"]) and row["rmse_m"] < 10.0
    text = format_mvp(row)
    assert f"ratio {row['ratio']:.1f}x" in text and "40 x 40 posts" in text
    assert row["kernel_compile_s"] > 0 and row["kernel_first_call_s"] > 0
    assert f"{row['kernel_compile_s']:.1f} s" in text
