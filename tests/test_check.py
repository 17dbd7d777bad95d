"""The truth-free check: its NCC, its separation of visible from occluded posts on the city,
views that do not overlap, the tiled check against the in-memory one, and its command line."""

from __future__ import annotations

import functools
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from affine import Affine

import orthomvp.engine.grid as engine_grid
import orthomvp.engine.run as engine_run
from orthomvp.camera import load_view, sensor_positions, write_tsai
from orthomvp.engine import CheckPlan, dask_client, plan_check, run_check
from orthomvp.engine.ncc import MEDIAN_BOUND, MISS_BINS, NccTally
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.world import detect_world
from orthomvp.io.raster import write_geotiff
from orthomvp.quality.check import CheckResult, check_views, local_ncc
from orthomvp.synthetic import load_scene
from tests.conftest import shared
from tests.test_cli import assert_one_line_error, run

NAMES = ("ne", "se", "sw", "nw")
CRATER = ("oblique", "nadir", "fore", "aft")
LABELS = ("eps", "view", "other", "class", "miss_from", "miss_to")


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
    out = tmp_path / "chk_eps2.4"  # the suffixes go after the whole prefix
    proc = run("check", str(city_dir / "dem.tif"), *files, "-o", str(out), "--eps", "2", "4")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith("orthomvp: plan: check ")
    medians = re.findall(r"orthomvp: eps (\d) posts: median NCC (\d\.\d+) \(", proc.stdout)
    assert [e for e, _ in medians] == ["2", "4"] and all(float(m) > 0.9 for _, m in medians)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chk_eps2.4.csv", "chk_eps2.4.png"]
    lines = (tmp_path / "chk_eps2.4.csv").read_text().splitlines()
    assert lines[0] == "eps,view,other,class,miss_from,miss_to,posts,scored,ncc_mean,ncc_median"
    assert len(lines) == 1 + 2 * 12 * 2 * 8 + 2 * 2 * 8  # eps x ordered pairs x classes x bins
    assert (tmp_path / "chk_eps2.4.png").read_bytes()[:4] == b"\x89PNG"


def test_prefix_naming_a_directory_is_refused(
    city_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """check and eps-study -o PREFIX: a prefix that names a directory (., an existing one, one
    ending in /) is one line saying what -o means, and nothing is written."""
    files = [str(city_dir / f"{n}.{ext}") for n in NAMES[:2] for ext in ("tif", "tsai")]
    (tmp_path / "existdir").mkdir()
    monkeypatch.chdir(tmp_path)
    for prefix in (".", "..", "existdir", "existdir/", str(tmp_path), "new/"):
        for command in (["check", str(city_dir / "dem.tif"), *files], ["eps-study", "scene"]):
            proc = run(*command, "-o", prefix)
            assert_one_line_error(
                proc, f"{prefix} names a directory; -o is the PREFIX", "PREFIX.csv and PREFIX.png"
            )
    assert [p.name for p in tmp_path.iterdir()] == ["existdir"]
    assert not list((tmp_path / "existdir").iterdir())


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


def compare(got: CheckResult, expected: CheckResult) -> None:
    """The tiled check against the in-memory one: the same rows, posts and scored posts,
    means to rounding, medians within the histogram's bound."""
    assert (got.pairs, got.apart, got.names) == (expected.pairs, expected.apart, expected.names)
    assert len(got.rows) == len(expected.rows)
    for g, e in zip(got.rows, expected.rows, strict=True):
        assert [g[k] for k in LABELS] == [e[k] for k in LABELS]
        assert (g["posts"], g["scored"]) == (e["posts"], e["scored"]), (g, e)
        if e["scored"]:
            assert g["ncc_mean"] == pytest.approx(e["ncc_mean"], rel=1e-9, abs=1e-12)
            assert abs(g["ncc_median"] - e["ncc_median"]) <= MEDIAN_BOUND + 1e-12, (g, e)
        else:
            assert np.isnan(g["ncc_mean"]) and np.isnan(g["ncc_median"])


def same_rows(a: CheckResult, b: CheckResult) -> bool:
    """Whether two checks have the same rows, value for value."""
    return [str(r) for r in a.rows] == [str(r) for r in b.rows]


def test_tallies_merge_exactly_and_bound_the_median() -> None:
    rng = np.random.default_rng(3)
    n = 5000
    miss = rng.exponential(3.0, n)
    miss[:40] = np.array(MISS_BINS[:-1]).repeat(40 // 7 + 1)[:40]  # on the bin edges
    ncc = np.clip(rng.normal(0.6, 0.3, n), -1, 1)
    ncc[rng.random(n) < 0.1] = np.nan
    ncc[40:45], ncc[45:48] = 1.0, -1.0
    whole = NccTally.of(miss, ncc)
    cuts = np.sort(rng.choice(n, 20, replace=False))
    parts = [
        NccTally.of(m, v) for m, v in zip(np.split(miss, cuts), np.split(ncc, cuts), strict=True)
    ]
    merged = functools.reduce(NccTally.merge, reversed(parts), NccTally.empty())
    bins = list(zip(MISS_BINS[:-1], MISS_BINS[1:], strict=True))
    for k in [None, *range(len(bins))]:
        np.testing.assert_equal(merged.summary(k), whole.summary(k))  # split or not, the same
        lo, hi = (0.0, np.inf) if k is None else bins[k]
        sel = (miss >= lo) & (miss < hi)
        values = ncc[sel][np.isfinite(ncc[sel])]
        posts, scored, mean, median = whole.summary(k)
        assert (posts, scored) == (sel.sum(), values.size) and scored > 0
        assert mean == pytest.approx(values.mean(), rel=1e-12)
        assert abs(median - np.median(values)) <= MEDIAN_BOUND + 1e-12
    assert np.isnan(NccTally.empty().summary()[2:]).all()


def test_tiled_check_equals_in_memory_and_itself(
    crater_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dem = crater_dir / "dem.tif"
    views = [(crater_dir / f"{n}.tif", crater_dir / f"{n}.tsai") for n in CRATER]
    terrain = Terrain.read(dem)
    expected = check_views(terrain, [load_view(*v) for v in views], names=list(CRATER))
    assert expected.pooled(1.0, "occluded")["scored"] > 100  # occlusion to check
    plan = plan_check(dem, views, names=CRATER, tile=12, progress=False)
    # small tiles: occluders lie beyond them, and NCC boxes reach 3 posts past their edges
    assert plan.margin == 3 and max(plan.base.reach) > 12 and len(plan.tiles) == 36
    assert any(job.dem_posts > (12 + 2 * 3 + 2) ** 2 for job in plan.tiles)
    got = run_check(plan, threads=2, progress=False)
    compare(got, expected)
    # another tiling, and worker processes: the same rows, value for value
    other = plan_check(dem, views, names=CRATER, tile=20, progress=False)
    assert same_rows(run_check(other, threads=1, progress=False), got)
    assert same_rows(run_check(plan, processes=2, progress=False), got)
    # without the margin the tiles' NCC boxes are cut at their edges: the test sees it
    monkeypatch.setattr(CheckPlan, "margin", property(lambda self: 0))
    assert not same_rows(run_check(plan, threads=2, progress=False), got)


def test_check_on_dask_equals_threads(crater_dir: Path) -> None:
    pytest.importorskip("distributed")
    views = [(crater_dir / f"{n}.tif", crater_dir / f"{n}.tsai") for n in CRATER]
    plan = plan_check(crater_dir / "dem.tif", views, tile=16, progress=False)
    threaded = run_check(plan, threads=2, progress=False)
    with dask_client(workers=2) as client:
        assert same_rows(run_check(plan, client=client, progress=False), threaded)


def test_tiles_only_one_view_sees_are_not_read(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A view that covers part of the DEM: tiles where it cannot pair with another view are
    not read at all, and the result is the in-memory one."""
    image, camera = load_view(crater_dir / "nadir.tif", crater_dir / "nadir.tsai")
    part = image[:, :50, :45]
    write_geotiff(tmp_path / "part.tif", part, Affine.identity(), None)
    camera = camera.with_image_size(None, None)
    oblique = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    reads = []
    original = engine_grid.DemSource.read
    monkeypatch.setattr(
        engine_grid.DemSource, "read", lambda self, w: reads.append(w) or original(self, w)
    )
    views = [oblique, (tmp_path / "part.tif", camera)]
    plan = plan_check(crater_dir / "dem.tif", views, tile=16, progress=False)
    reads.clear()
    got = run_check(plan, threads=1, progress=False)
    paired = [job for job in plan.tiles if job.views]
    assert len(reads) == len(paired) < len(plan.tiles)
    terrain = Terrain.read(crater_dir / "dem.tif")
    compare(got, check_views(terrain, [load_view(*oblique), (part, camera)]))


def test_check_feedback_and_memory_preflight(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture
) -> None:
    dem = crater_dir / "dem.tif"
    views = [(crater_dir / f"{n}.tif", crater_dir / f"{n}.tsai") for n in CRATER[:2]]
    monkeypatch.setattr("orthomvp.engine.progress.LOG_AFTER", 0.0)  # log even short phases
    plan = plan_check(dem, views, tile=16, progress=True)
    err = capfd.readouterr().err
    assert "reading the DEM's heights" in err and "planning tiles: 16/16" in err
    run_check(plan, threads=1, progress=True)
    err = capfd.readouterr().err
    assert "orthomvp: plan: check 64 x 64 posts" in err and "7 x 7 NCC windows" in err
    assert "GiB" in err and "orthomvp: checking tiles: 16/16 tiles (100%)" in err
    run_check(plan, threads=1, progress=False)
    assert capfd.readouterr().err == ""
    # a peak that does not fit: refused before any work, in one line, with nothing written
    one = plan.peak_memory(1)
    assert plan.peak_memory(2) > one > 300 << 20  # grows with the tiles at a time
    monkeypatch.setattr(engine_run, "available_memory", lambda: 100 << 20)
    with pytest.raises(InputError, match="use smaller tiles or fewer threads/processes"):
        run_check(plan, threads=1, progress=False)
    files = [str(p) for v in views for p in v]
    out = tmp_path / "chk"
    proc = run("-q", "check", str(dem), *files, "-o", str(out), "--tile", "16")
    assert_one_line_error(proc, "GiB of memory", "use smaller tiles")
    assert not list(tmp_path.iterdir())


def test_check_engine_bad_input(crater_dir: Path, tmp_path: Path) -> None:
    dem = crater_dir / "dem.tif"
    views = [(crater_dir / f"{n}.tif", crater_dir / f"{n}.tsai") for n in CRATER[:2]]
    for kw, match in (
        ({"tile": 1}, "tile must be"),
        ({"window": 4}, "odd"),
        ({"eps_values": ()}, "at least one epsilon"),
        ({"eps_values": (-1.0,)}, "epsilon"),
        ({"names": ["a"]}, "1 names for 2 views"),
        ({"world": "moon"}, "world frame"),
    ):
        with pytest.raises(InputError, match=match):
            plan_check(dem, views, progress=False, **kw)
    with pytest.raises(InputError, match="at least two"):
        plan_check(dem, views[:1], progress=False)
    files = [str(p) for v in views for p in v]
    out = str(tmp_path / "chk")
    for args, words in (
        (["--tile", "1"], ("--tile",)),
        (["--threads", "1", "--processes", "1"], ("exclude each other",)),
        (["--format", "cog"], ("No such option",)),  # a table and a plot: no raster options
        (["--res", "1", "1"], ("No such option",)),  # on the DEM's grid
        (["--dem-crs", "nonsense"], ("nonsense",)),
    ):
        assert_one_line_error(run("check", str(dem), *files, "-o", out, *args), *words)
    assert_one_line_error(run("check", "-o", out), "or --odm DIR")
    assert_one_line_error(run("check", str(dem), "-o", out), "or --odm DIR")
    assert not list(tmp_path.iterdir())


@pytest.mark.realdata
def test_ngi_aerial_tiled_check_equals_in_memory() -> None:
    """Four aerial frames (map frame) in tiles of 128 posts: the in-memory check's counts,
    means and medians (within the bound); visible posts correlate (median 0.90)."""
    d = shared("ngi-aerial")
    names = [str(p) for p in sorted(d.glob("*_RGB.tif"))]
    views = [(name, name.removesuffix(".tif") + ".converted.tsai") for name in names]
    got = run_check(plan_check(d / "dem.tif", views, names=names, tile=128, progress=False))
    loaded = [load_view(*v) for v in views]
    terrain = Terrain.read(d / "dem.tif", world="map")  # EGM2008 heights: the map frame's own
    centres = np.concatenate([sensor_positions(camera) for _, camera in loaded])
    terrain = replace(terrain, world=detect_world(terrain, centres))
    compare(got, check_views(terrain, loaded, names=names))
    assert len(got.pairs) == 6 and got.pooled(4.0, "visible")["ncc_median"] > 0.85


def test_an_image_left_out_of_the_check_is_said_once(crater_dir: Path, tmp_path: Path) -> None:
    """Of three views of the crater one moved off it (its camera 60 km east) is left out with
    one warning line; no line names it in a pair that does not overlap, and the other two are
    checked as they are alone."""
    from orthomvp.camera import read_camera

    camera = read_camera(crater_dir / "nadir.tsai")
    x, y, _ = camera.center
    east = np.array([-y, x, 0.0]) / np.hypot(x, y)
    away = tmp_path / "away.tsai"
    write_tsai(replace(camera, center=camera.center + 60_000.0 * east), away)
    files = [
        str(crater_dir / f"{n}.{ext}") for n in ("nadir", "oblique") for ext in ("tif", "tsai")
    ]
    dem = str(crater_dir / "dem.tif")
    args = ["--eps", "2"]
    proc = run("check", dem, *files, str(crater_dir / "nadir.tif"), str(away), "-o",
               str(tmp_path / "c"), *args)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    warned = [x for x in proc.stderr.splitlines() if x.startswith("orthomvp: warning:")]
    assert len(warned) == 1 and "is left out" in warned[0], proc.stderr
    assert "do not overlap" not in proc.stdout and "do not overlap" not in proc.stderr
    alone = run("check", dem, *files, "-o", str(tmp_path / "a"), *args)
    assert alone.returncode == 0, alone.stderr
    median = re.compile(r"median NCC .*")
    assert median.findall(proc.stdout) == median.findall(alone.stdout) != []


def test_prefix_files_take_a_suffix_given_for_one_of_the_pair() -> None:
    """`-o check.csv` wrote check.csv.csv: a .csv or .png given names the pair's stem; other
    dots stay in the name (`-o results_eps0.5`)."""
    from orthomvp.cli.options import prefix_files

    cases = [
        ("out/check.csv", "out/check"), ("check.PNG", "check"),
        ("results_eps0.5", "results_eps0.5"), ("a.b", "a.b"), (".csv", ".csv"),
    ]  # fmt: skip
    for given, stem in cases:
        table, figure = prefix_files(Path(given))
        assert (table, figure) == (Path(stem + ".csv"), Path(stem + ".png")), given


def test_the_default_prefix_beside_a_folder_of_its_name(
    city_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Found in review: in a folder holding a check/ folder, check without -o was refused as
    "-o names a directory", an option the user never gave; it writes check.csv and check.png
    beside that folder."""
    files = [str(city_dir / f"{n}.{ext}") for n in NAMES[:2] for ext in ("tif", "tsai")]
    (tmp_path / "check").mkdir()
    monkeypatch.chdir(tmp_path)
    proc = run("-q", "check", str(city_dir / "dem.tif"), *files, "--eps", "2")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["check", "check.csv", "check.png"]
