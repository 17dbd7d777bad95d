"""``orthomvp fit`` end to end (in this process, see tests/test_cli.py): outputs on the DEM grid,
one-line errors, nothing half-written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.geometry.terrain import Terrain
from tests.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "hills"
    proc = run("-q", "synth", "hills", str(out), "--size", "48", "--supersample", "2")
    assert proc.returncode == 0, proc.stderr
    dem = Terrain.read(out / "dem.tif")
    dem.write(out / "start.tif", dem.values + 15.0)
    return out


def pairs(scene: Path) -> list[str]:
    return [
        str(scene / f"{v}.{ext}")
        for v in ("fore2", "fore1", "aft1", "aft2")
        for ext in ("tif", "tsai")
    ]


@pytest.mark.slow
def test_fit_writes_every_output(scene: Path, tmp_path: Path) -> None:
    outs = {k: tmp_path / f"{k}.tif" for k in ("fit", "n", "c", "v", "u")}
    proc = run(
        "-q", "fit", str(scene / "start.tif"), *pairs(scene), "-o", str(outs["fit"]),
        "--normals", str(outs["n"]), "--cost", str(outs["c"]), "--views", str(outs["v"]),
        "--uncertainty", str(outs["u"]),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == proc.stderr == ""  # -q: warnings and errors only
    truth = Terrain.read(scene / "dem.tif").values
    with rasterio.open(outs["fit"]) as src:
        fitted = src.read(1)
        assert src.transform == rasterio.open(scene / "dem.tif").transform
    ok = np.isfinite(fitted)
    assert ok.mean() > 0.4
    err = (fitted - truth)[ok]  # the start was 15 m high everywhere
    assert np.median(np.abs(err)) < 5.0 and np.sqrt(np.mean(err**2)) < 10.0
    with rasterio.open(outs["n"]) as src:
        assert src.count == 3 and src.descriptions[2] == "tilt_deg"
        assert np.nanmax(src.read(3)) < 45
    with rasterio.open(outs["v"]) as src:
        views = src.read(1)
        assert set(np.unique(views[ok])) <= {2, 3, 4} and (views[~ok] == 0).all()
    with rasterio.open(outs["u"]) as src:
        assert src.count == 2 and np.nanmedian(src.read(1)) > 0
    with rasterio.open(outs["c"]) as src:
        assert np.nanmax(src.read(1)) < 3.0  # eq. 20 with 4 views lies in [0, 6]


@pytest.mark.slow
def test_fit_errors_are_one_line_and_leave_nothing(scene: Path, tmp_path: Path) -> None:
    out = tmp_path / "fit.tif"
    p = pairs(scene)
    assert_one_line_error(run("fit", str(scene / "start.tif"), *p[:3], "-o", str(out)), "pairs")
    assert_one_line_error(run("fit", str(scene / "start.tif"), *p[:2], "-o", str(out)), "2")
    missing = [*p[:-1], str(tmp_path / "nope.tsai")]
    assert_one_line_error(run("fit", str(scene / "start.tif"), *missing, "-o", str(out)), "nope")
    assert_one_line_error(
        run("fit", str(scene / "start.tif"), *p, "-o", str(out), "--hwin", "0"), "hwin"
    )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_window_too_large_is_named_as_such(scene: Path, tmp_path: Path) -> None:
    """Found by a new user's audit: a window larger than the images' overlap said "no post is
    visible in 2 or more images" (fit_dem itself says why), and one needing more memory than
    the machine has said "use smaller tiles", which changes nothing."""
    out = tmp_path / "fit.tif"
    args = ["fit", str(scene / "start.tif"), *pairs(scene), "-o", str(out), "--levels", "1"]
    proc = run(*args, "--hwin", "40")
    assert_one_line_error(proc, "posts are visible in 2 or more images, but at none of them")
    assert "81 x 81 samples (hwin 40): choose a smaller hwin" in proc.stderr
    proc = run(*args, "--hwin", "400", "--tile", "16")
    assert_one_line_error(proc, "choose a smaller --hwin (every post's patch holds 801 squared")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_levels_beyond_the_images_warn(scene: Path, tmp_path: Path) -> None:
    """Found by a new user's audit: --levels beyond what the images hold was capped in
    silence. One warning line says how many the smallest image holds; the fit then equals the
    one asked for with that many."""
    from orthomvp.mvp.problem import MIN_LEVEL_SIZE, levels_for

    with rasterio.open(scene / "fore2.tif") as src:
        side = min(src.width, src.height)
    levels = levels_for(side, 10)
    assert levels < 10
    out, same = tmp_path / "ten.tif", tmp_path / "same.tif"
    args = ["fit", str(scene / "start.tif"), *pairs(scene), "--hwin", "4"]
    proc = run(*args, "-o", str(out), "--levels", "10")
    assert proc.returncode == 0, proc.stderr
    warned = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert warned == [
        f"orthomvp: warning: --levels 10: the smallest image that sees the DEM ({side} px a "
        f"side) holds {levels} pyramid level(s) of at least {MIN_LEVEL_SIZE} px; fitting with "
        f"{levels}"
    ]
    proc = run("-q", *args, "-o", str(same), "--levels", str(levels))
    assert proc.returncode == 0 and proc.stderr == ""
    with rasterio.open(out) as a, rasterio.open(same) as b:
        assert np.array_equal(a.read(), b.read(), equal_nan=True)


def test_the_summary_says_when_the_input_heights_were_moved() -> None:
    """Found by a new user's audit: with --height-offset the change was measured from the
    moved heights, which the output holds too, and the line did not say so."""
    from orthomvp.engine.fit import FitReport, _input_heights
    from orthomvp.geometry.datum import HeightShift

    assert _input_heights(None) == ""
    moved = _input_heights(HeightShift(offset=28.0))
    assert moved == "the DEM's heights moved by +28 m for the cameras, as the output holds them"
    assert "the geoid undulation and -1.5 m" in _input_heights(HeightShift(-1.5, "WKT"))
    line = FitReport(posts=4, fitted=2, input_heights=moved).line("x.tif")
    assert f"fitted - input ({moved}): median" in line
    assert "fitted - input: median" in FitReport(posts=4, fitted=2).line("x.tif")
