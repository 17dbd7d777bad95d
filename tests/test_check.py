"""The truth-free check: its NCC, its separation of visible from occluded posts on the city,
views that do not overlap, and its command line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from orthomvp.camera import load_view, write_tsai
from orthomvp.check import check_views, local_ncc
from orthomvp.errors import GeometryError, InputError
from orthomvp.raster import write_geotiff
from orthomvp.synthetic import load_scene
from tests.test_cli import assert_one_line_error, run

NAMES = ("ne", "se", "sw", "nw")


def test_local_ncc_is_the_correlation_of_each_window() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 30, 30))
    b = 0.6 * a + 0.4 * b
    a[rng.random(a.shape) < 0.2] = np.nan
    b[5:12, 5:12] = np.nan  # a hole: windows inside it have too few pairs
    ncc = local_ncc(a, b, 5)
    for r, c in [(15, 15), (3, 20), (25, 4), (12, 12)]:
        wa, wb = a[r - 2 : r + 3, c - 2 : c + 3], b[r - 2 : r + 3, c - 2 : c + 3]
        ok = np.isfinite(wa) & np.isfinite(wb)
        assert ok.sum() >= 13
        assert ncc[r, c] == pytest.approx(np.corrcoef(wa[ok], wb[ok])[0, 1], abs=1e-9)
    assert np.isnan(ncc[8, 8])
    assert np.isnan(local_ncc(np.ones((9, 9)), rng.normal(size=(9, 9)), 3)).all()  # flat


@pytest.fixture(scope="module")
def city(city_dir: Path):
    return load_scene(city_dir)


def test_check_separates_visible_from_occluded_on_the_city(city) -> None:
    views = [(city.views[n].image, city.views[n].camera) for n in NAMES]
    result = check_views(city.terrain, views, eps_values=(1.0, 4.0), names=list(NAMES))
    assert result.pairs == [(1, 2), (1, 3), (1, 4), (2, 3), (2, 4), (3, 4)] and not result.apart
    for eps in (1.0, 4.0):
        visible, occluded = result.pooled(eps, "visible"), result.pooled(eps, "occluded")
        assert visible["scored"] > 20_000 and occluded["scored"] > 2_000
        assert visible["ncc_median"] > 0.95 and occluded["ncc_median"] < 0.3
    # at eps 1 the posts hit 4-16 posts away are occluded and disagree; at eps 8 they are
    # called visible and the visible NCC falls with the miss distance (partial ghosts)
    far = [
        r
        for r in check_views(city.terrain, views, eps_values=(8.0,)).rows
        if r["view"] == "all"
        and r["class"] == "visible"
        and r["miss_from"] in (0.0, 4.0)
        and r["miss_to"] != np.inf
    ]
    near, ghosts = far
    assert ghosts["scored"] > 50 and ghosts["ncc_median"] < near["ncc_median"] - 0.3


def test_views_that_do_not_overlap(city) -> None:
    image, cam = city.views["ne"].image, city.views["ne"].camera
    third = cam.width // 3
    left = (image[:, :, :third], cam.crop(0, 0, third, cam.height))
    right = (image[:, :, -third:], cam.crop(cam.width - third, 0, third, cam.height))
    other = (city.views["sw"].image, city.views["sw"].camera)
    result = check_views(city.terrain, [left, right, other], eps_values=(4.0,))
    assert result.apart == [(1, 2)] and result.pairs == [(1, 3), (2, 3)]
    with pytest.raises(GeometryError, match="no two of the 2 views overlap"):
        check_views(city.terrain, [left, right])
    with pytest.raises(InputError, match="odd"):
        check_views(city.terrain, [left, other], window=6)


def test_check_command(city_dir: Path, tmp_path: Path) -> None:
    files = [str(city_dir / f"{n}.{ext}") for n in NAMES for ext in ("tif", "tsai")]
    out = tmp_path / "chk"
    proc = run("-q", "check", str(city_dir / "dem.tif"), *files, "-o", str(out), "--eps", "2", "4")
    assert proc.returncode == 0, proc.stderr
    assert "eps 2: median NCC 0.9" in proc.stdout and "eps 4: median NCC 0.9" in proc.stdout
    lines = (tmp_path / "chk.csv").read_text().splitlines()
    assert lines[0] == "eps,view,other,class,miss_from,miss_to,posts,scored,ncc_mean,ncc_median"
    assert len(lines) == 1 + 2 * 12 * 2 * 8 + 2 * 2 * 8  # eps x ordered pairs x classes x bins
    assert (tmp_path / "chk.png").read_bytes()[:4] == b"\x89PNG"


def test_check_command_bad_input(city_dir: Path, tmp_path: Path) -> None:
    dem = str(city_dir / "dem.tif")
    ne = [str(city_dir / "ne.tif"), str(city_dir / "ne.tsai")]
    sw = [str(city_dir / "sw.tif"), str(city_dir / "sw.tsai")]
    out = tmp_path / "chk"
    assert_one_line_error(run("check", dem, *ne, "-o", str(out)), "at least 2 IMAGE CAMERA")
    assert_one_line_error(run("check", dem, *ne, sw[0], "-o", str(out)), "odd number")
    assert_one_line_error(run("check", dem, *ne, *sw, "-o", str(out), "--window", "4"), "odd")
    assert_one_line_error(
        run("check", dem, *ne, *sw, "-o", str(tmp_path / "no" / "chk")), "does not exist"
    )
    # two halves of one image see different posts: no pair to check
    image, cam = load_view(*ne)
    half = cam.width // 2
    write_geotiff(tmp_path / "l.tif", image[0, :, :half], None, None)
    write_geotiff(tmp_path / "r.tif", image[0, :, -half:], None, None)
    write_tsai(cam.crop(0, 0, half, cam.height), tmp_path / "l.tsai")
    write_tsai(cam.crop(cam.width - half, 0, half, cam.height), tmp_path / "r.tsai")
    halves = [str(tmp_path / f) for f in ("l.tif", "l.tsai", "r.tif", "r.tsai")]
    assert_one_line_error(run("check", dem, *halves, "-o", str(out)), "no two of the 2 views")
    assert not list(tmp_path.glob("chk*"))
