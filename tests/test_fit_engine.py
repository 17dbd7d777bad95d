"""The MVP fit through the engine: windows of images give the whole images' pyramids where
the fit samples them, and a tiled fit equals the in-memory fit bit for bit, on threads,
processes and Dask, with every output written as ``orthomvp fit`` writes it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from scipy import ndimage

import orthomvp.engine.fit_plan as engine_fit_plan
from orthomvp.camera import load_view
from orthomvp.engine import FitOutputs, dask_client, plan_fit, run_fit
from orthomvp.engine.median import Median
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.mvp.patches import ViewStack
from orthomvp.mvp.views import (
    ViewWindow,
    alignment,
    covers,
    exact_masks,
    view_statistics,
    window_for,
)
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import make_scene
from tests.test_camera import make_camera
from tests.test_cli import assert_one_line_error, run

OPTIONS = FitOptions(hwin=5, levels=2)
"""Small patches (the test's time), two levels (the pyramid's windows matter)."""

KINDS = ("heights", "normals", "cost", "views", "uncertainty")


def read(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read()


# ------------------------------------------------------------------------- image windows
@pytest.mark.parametrize("lens", ["null", "tsai", "brown"])
def test_window_pyramids_are_the_whole_image_where_exact(lens: str) -> None:
    """Aligned windows of an image (with nodata pixels, through lens distortion) give the
    whole image's pyramid of values and gradients, bit for bit, wherever the exact masks
    say so; the masks cover most of each window; statistics from windows are the whole
    image's."""
    rng = np.random.default_rng(3)
    camera = make_camera(lens)
    size = (camera.width, camera.height)
    image = cv2.GaussianBlur(rng.normal(size=size[::-1]).astype(np.float32), (0, 0), 1.5) + 5
    image[rng.random(image.shape) < 1e-3] = np.nan
    read = lambda w: image[w[0] : w[1], w[2] : w[3]]  # noqa: E731
    partial = 0
    for levels in (1, 3):
        whole = ViewStack.build([image], [camera], levels)
        fill, std = view_statistics(read, camera, size, levels, block=512)
        np.testing.assert_allclose(
            [f[0] for f in whole.flat], [1e-6 * s for s in std], rtol=1e-6, atol=0
        )
        for _ in range(4):
            c0, r0 = rng.uniform(-40, 900), rng.uniform(-40, 700)
            box = (c0, c0 + rng.uniform(0, 300), r0, r0 + rng.uniform(0, 200))
            window = window_for(box, camera, size, levels)
            r0_, r1_, c0_, c1_ = window
            assert r0_ % alignment(levels) == 0 and c0_ % alignment(levels) == 0
            view = ViewWindow(window, size, fill, std)
            partial += not view.whole
            stack = ViewStack.build([read(window)], [camera], levels, [view])
            masks = exact_masks(view, camera, levels)
            for level in range(levels):
                got = stack.levels[level][0]
                rows, cols = got.shape[:2]
                r, c = r0_ >> level, c0_ >> level
                expected = whole.levels[level][0][r : r + rows, c : c + cols]
                exact = masks[level]
                np.testing.assert_array_equal(got[exact], expected[exact])
                assert exact.mean() > 0.5
                assert stack.flat[level][0] == whole.flat[level][0]
                assert stack.sizes[level] == whole.sizes[level]
                # the box asked for is covered, at every level
                s = 1 << level
                inside = (box[0] / s, box[1] / s, box[2] / s, box[3] / s)
                assert covers(view, masks, level, inside)
            assert not covers(view, masks, 0, (0.0, 1e6, 0.0, 1.0)) or view.whole
    assert partial >= 4


def test_median_in_bounded_memory(tmp_path: Path) -> None:
    """Medians of streams beyond the memory budget, selected in passes over a file, are
    numpy's: odd and even counts, negative values, ties."""
    rng = np.random.default_rng(0)
    for n in (9_999, 10_000):
        values = np.concatenate([rng.normal(-3, 10, n - 2000), np.full(2000, 1.25)])
        rng.shuffle(values)
        with Median(budget=700, folder=tmp_path) as median:
            for part in np.array_split(values, 37):
                median.add(part)
            assert median.file is not None
            assert median.value() == np.median(values)
    with Median(budget=10) as median:
        median.add(np.full(100, -2.5))
        assert median.value() == -2.5
    assert np.isnan(Median().value())
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------- the tiled fit
@pytest.fixture(scope="module")
def hills(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The hills scene (48 x 48 posts, images of about 150 pixels a side: windows are parts
    of them), a smoothed DEM 15 m high as the start, and the in-memory fit."""
    folder = tmp_path_factory.mktemp("hills")
    make_scene("hills", size=48, gsd_ratio=0.3).write(folder, supersample=2)
    truth = Terrain.read(folder / "dem.tif")
    start = truth.with_values(ndimage.gaussian_filter(truth.values, 3) + 15.0)
    start.write(folder / "start.tif")
    views = [
        (folder / f"{n}.tif", folder / f"{n}.tsai") for n in ("fore2", "fore1", "aft1", "aft2")
    ]
    loaded = [load_view(*v) for v in views]
    terrain = Terrain.read(folder / "start.tif")
    res = fit_dem(terrain, [v[0] for v in loaded], [v[1] for v in loaded], OPTIONS, threads=2)
    up = terrain.up_vectors(terrain.world_points())
    tilt = np.degrees(np.arccos(np.clip(np.sum(res.normals * up, axis=-1), -1, 1)))
    ok = res.resolved
    shift = res.heights[ok] - res.initial[ok]
    expected = {
        "heights": res.heights.astype(np.float32)[None],
        "normals": np.stack([res.n_theta, res.n_phi, tilt]).astype(np.float32),
        "cost": res.cost.astype(np.float32)[None],
        "views": res.views.astype(np.uint8)[None],
        "uncertainty": np.stack([res.sigma_h, np.where(ok, res.converged, np.nan)]).astype(
            np.float32
        ),
        "summary": (
            int(ok.sum()),
            int(res.converged.sum()),
            float(np.median(shift)),
            float(np.sqrt(np.mean(shift**2))),
            float(np.nanmedian(res.sigma_h[ok])),
        ),
    }
    # the in-memory fit of one tile's posts and one around only (no deconvolution margin)
    codes = [compute_visibility(terrain, camera).codes for _, camera in loaded]
    visible = np.stack(codes)[:, 11:25, 11:25] == 1
    bare = fit_dem(
        replace(terrain, values=terrain.values[11:25, 11:25]),
        [v[0] for v in loaded],
        [v[1] for v in loaded],
        OPTIONS,
        visible=visible,
        origin=(11, 11),
        geometry=terrain,
        spacing=float(np.mean(terrain.post_spacing())),
    )
    expected["bare"] = bare.heights[1:-1, 1:-1]
    return {"dem": folder / "start.tif", "views": views, "expected": expected}


def fit(hills: dict, tmp_path: Path, name: str, tile: int, **kw) -> dict:  # noqa: ANN003
    plan = plan_fit(hills["dem"], hills["views"], OPTIONS, tile=tile, progress=False)
    outputs = FitOutputs(**{k: tmp_path / f"{name}-{k}.tif" for k in KINDS})
    report = run_fit(plan, outputs, progress=False, **kw)
    got = {k: read(tmp_path / f"{name}-{k}.tif") for k in KINDS}
    return {"plan": plan, "report": report, **got}


def assert_same(got: dict, expected: dict) -> None:
    for kind in KINDS:
        np.testing.assert_array_equal(got[kind], expected[kind], err_msg=kind)
    report = got["report"]
    fitted, converged, median, rms, sigma = expected["summary"]
    assert (report.fitted, report.converged, report.median_shift) == (fitted, converged, median)
    assert report.rms_shift == pytest.approx(rms, rel=1e-12)
    assert report.median_sigma == sigma


def test_tiled_fit_equals_the_in_memory_fit(hills: dict, tmp_path: Path) -> None:
    """Tiles of 12 posts, narrower than what a tile reads around it (6 posts of fit margin
    and the occluder halos), from parts of the images: every output equal to the in-memory
    fit's, bit for bit."""
    got = fit(hills, tmp_path, "tiled", tile=12, threads=2)
    plan, report = got["plan"], got["report"]
    assert len(plan.tiles) == 16 and report.tiles_run == 16 and report.refits == 0
    assert all(job.dem_posts > (12 + 2 * 6) ** 2 // 2 for job in plan.tiles)
    assert any(job.dem[1] - job.dem[0] > 12 + 2 * 6 for job in plan.tiles)  # halos reach out
    sizes = [(v.height, v.width) for v in plan.views]
    partial = [
        (r1 - r0, c1 - c0) != sizes[k]
        for job in plan.tiles
        for k, (r0, r1, c0, c1) in zip(job.views, job.images, strict=True)
    ]
    assert np.mean(partial) > 0.25
    assert_same(got, hills["expected"])
    # without the margins, the tile in the middle would come out otherwise
    bare = hills["expected"]["bare"]
    assert np.nanmax(np.abs(bare - got["heights"][0, 12:24, 12:24])) > 0.01
    assert got["heights"].dtype == np.float32 and got["views"].dtype == np.uint8
    assert 0.5 < np.isfinite(got["heights"]).mean() < 1
    with rasterio.open(tmp_path / "tiled-normals.tif") as src:
        assert src.descriptions == ("n_theta_deg", "n_phi_deg", "tilt_deg")
    assert report.line("x.tif").startswith(f"wrote x.tif: {report.fitted:,} of 2,304 posts")


@pytest.mark.slow
def test_crater_tiled_fit_equals_the_in_memory_fit(crater_dir: Path, tmp_path: Path) -> None:
    """The crater: posts hidden behind its rim (occluder halos wider than the tiles), three
    pyramid levels; tiles of 16 posts give the in-memory fit's heights, views and converged
    flags bit for bit."""
    d = crater_dir
    views = [(d / f"{n}.tif", d / f"{n}.tsai") for n in ("oblique", "nadir", "fore")]
    options = FitOptions(hwin=4, reject_below=None)
    terrain = Terrain.read(d / "dem.tif")
    terrain.write(tmp_path / "start.tif", terrain.values + 10.0)
    start = Terrain.read(tmp_path / "start.tif")
    loaded = [load_view(*v) for v in views]
    res = fit_dem(start, [v[0] for v in loaded], [v[1] for v in loaded], options, threads=2)
    plan = plan_fit(tmp_path / "start.tif", views, options, tile=16, progress=False)
    assert plan.levels == 3 and max(plan.reach) > 16
    outputs = FitOutputs(
        tmp_path / "h.tif", views=tmp_path / "v.tif", uncertainty=tmp_path / "u.tif"
    )
    report = run_fit(plan, outputs, threads=2, progress=False)
    np.testing.assert_array_equal(read(tmp_path / "h.tif")[0], res.heights.astype(np.float32))
    np.testing.assert_array_equal(read(tmp_path / "v.tif")[0], res.views)
    converged = np.where(res.resolved, res.converged, np.nan).astype(np.float32)
    np.testing.assert_array_equal(read(tmp_path / "u.tif")[1], converged)
    assert report.fitted == res.resolved.sum() > 1000


def test_windows_that_miss_samples_are_grown(hills: dict, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """When the planned image windows are too small for where the planes move, the tile is
    fitted again with windows that hold every sample: the results do not change."""
    real = engine_fit_plan.patch_box

    def shrunk(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        c0, c1, r0, r1 = real(*args, **kwargs)
        cm, rm = (c0 + c1) / 2, (r0 + r1) / 2
        return cm - 4, cm + 4, rm - 4, rm + 4

    monkeypatch.setattr(engine_fit_plan, "patch_box", shrunk)
    got = fit(hills, tmp_path, "grown", tile=24, threads=2)
    assert got["report"].refits > 0
    assert_same(got, hills["expected"])


@pytest.mark.slow
def test_processes_and_dask_equal_threads(hills: dict, tmp_path: Path) -> None:
    assert_same(fit(hills, tmp_path, "proc", tile=24, processes=2), hills["expected"])
    pytest.importorskip("distributed")
    with dask_client(workers=2) as client:
        assert_same(fit(hills, tmp_path, "dask", tile=24, client=client), hills["expected"])


def test_bad_input(hills: dict, tmp_path: Path) -> None:
    views = hills["views"]
    with pytest.raises(InputError, match="at least 2 images"):
        plan_fit(hills["dem"], views[:1], progress=False)
    with pytest.raises(InputError, match="hwin"):
        plan_fit(hills["dem"], views, FitOptions(hwin=0), progress=False)
    with pytest.raises(InputError, match="tile"):
        plan_fit(hills["dem"], views, tile=1, progress=False)
    plan = plan_fit(hills["dem"], views, OPTIONS, tile=24, progress=False)
    with pytest.raises(InputError, match="not several"):
        run_fit(plan, FitOutputs(tmp_path / "x.tif"), threads=1, processes=1)
    with pytest.raises(InputError, match="format"):
        FitOutputs(tmp_path / "x.tif", format="png")
    # a DEM far from every image: nothing to fit, nothing written
    terrain = Terrain.read(hills["dem"])
    away = terrain.transform @ terrain.transform.translation(500, 0)
    Terrain(terrain.values, away, terrain.crs).write(tmp_path / "away.tif")
    with pytest.raises(GeometryError, match="does not cover"):
        plan_fit(tmp_path / "away.tif", views, OPTIONS, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["away.tif"]


def test_cli_engine_options(hills: dict, tmp_path: Path) -> None:
    pairs = [str(p) for view in hills["views"] for p in view]
    out = str(tmp_path / "fit.tif")
    dem = str(hills["dem"])
    assert_one_line_error(
        run("fit", dem, *pairs, "-o", out, "--threads", "1", "--processes", "2"), "one of"
    )
    assert_one_line_error(run("fit", dem, *pairs, "-o", out, "--dask", "local:x"), "local:N")
    assert_one_line_error(run("fit", dem, *pairs, "-o", out, "--tile", "1"), "tile")
    assert list(tmp_path.iterdir()) == []
