"""The engine: tiled runs agree with untiled and in-memory ones, on every executor; outputs are
COGs or tiled GeoTIFFs written atomically; memory is bounded by the tile."""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import tracemalloc
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

import orthomvp.engine.grid as engine_grid
import orthomvp.engine.run as engine_run
from orthomvp.camera import PinholeCamera, load_view
from orthomvp.engine import (
    HaloWarning,
    Outputs,
    WorkerError,
    dask_client,
    plan_ortho,
    run_plan,
)
from orthomvp.engine.images import ImageSource, image_source
from orthomvp.engine.scale import write_scale_scene
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import write_geotiff
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.orthophoto import mosaic, orthorectify
from orthomvp.synthetic import look_at
from tests.test_cli import assert_one_line_error
from tests.test_cli import run as cli_run


def read(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read()


def same(a: np.ndarray, b: np.ndarray) -> None:
    """Equal to float32 rounding, with NaN in the same places."""
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a, b, rtol=1e-6, equal_nan=True)


@pytest.fixture(scope="module")
def crater(crater_dir: Path) -> dict:
    d = crater_dir
    views = {name: (d / f"{name}.tif", d / f"{name}.tsai") for name in ("oblique", "nadir")}
    return {"dem": d / "dem.tif", "terrain": Terrain.read(d / "dem.tif"), "views": views}


def run(plan, tmp_path: Path, name: str, **kw) -> dict[str, np.ndarray]:  # noqa: ANN001
    kinds = kw.pop("kinds", ("ortho", "visibility"))
    outputs = Outputs(**{k: tmp_path / f"{name}-{k}.tif" for k in kinds}, **kw.pop("out", {}))
    report = run_plan(plan, outputs, progress=False, **kw)
    result = {k: read(tmp_path / f"{name}-{k}.tif") for k in kinds}
    result["report"] = report
    return result


def test_tiled_equals_untiled_and_in_memory(crater: dict, tmp_path: Path) -> None:
    view = crater["views"]["oblique"]
    tiled = plan_ortho(crater["dem"], [view], tile=16, progress=False, grid="dem")
    whole = plan_ortho(crater["dem"], [view], tile=64, progress=False, grid="dem")
    # the halo matters: occluders lie farther from a tile than the tile is wide
    assert tiled.reach[0] > 16 and len(tiled.tiles) == 16 and len(whole.tiles) == 1
    assert any(job.dem_posts > 2 * (16 + 2) ** 2 for job in tiled.tiles)
    a, b = run(tiled, tmp_path, "tiled"), run(whole, tmp_path, "whole")
    np.testing.assert_array_equal(a["visibility"], b["visibility"])
    same(a["ortho"], b["ortho"])
    image, camera = load_view(*view)
    ortho = orthorectify(crater["terrain"], image, camera)
    np.testing.assert_array_equal(a["visibility"][0], ortho.visibility.codes)
    same(a["ortho"], ortho.data)
    assert {1, 2, 3} <= set(np.unique(a["visibility"]))  # visible, occluded and facing away
    assert a["report"].filled == int(np.isfinite(ortho.data).all(axis=0).sum())


def test_mosaic_tiled_equals_in_memory(crater: dict, tmp_path: Path) -> None:
    views = [crater["views"]["oblique"], crater["views"]["nadir"]]
    plan = plan_ortho(crater["dem"], views, tile=16, progress=False, grid="dem")
    got = run(plan, tmp_path, "mos", kinds=("ortho", "source", "visibility"), threads=2)
    expected = mosaic(crater["terrain"], [load_view(*v) for v in views])
    np.testing.assert_array_equal(got["source"][0], expected.source)
    same(got["ortho"], expected.data)
    for k, vis in enumerate(expected.visibilities):
        np.testing.assert_array_equal(got["visibility"][k], vis.codes)
    assert got["report"].taken == [int((expected.source == k).sum()) for k in (1, 2)]


def test_other_grid_and_crs(crater: dict, tmp_path: Path) -> None:
    view = crater["views"]["oblique"]
    res = (0.0009, 0.0007)
    tiled = plan_ortho(crater["dem"], [view], tile=16, res=res, progress=False, grid="dem")
    whole = plan_ortho(crater["dem"], [view], tile=1024, res=res, progress=False, grid="dem")
    a, b = run(tiled, tmp_path, "a"), run(whole, tmp_path, "b")
    np.testing.assert_array_equal(a["visibility"], b["visibility"])
    same(a["ortho"], b["ortho"])
    # the in-memory way: the DEM regridded, rays against the original DEM's mesh
    terrain = crater["terrain"]
    grid = terrain.regrid(res)
    scale = float(np.mean(grid.post_spacing()) / np.mean(terrain.post_spacing()))
    image, camera = load_view(*view)
    caster = RayCaster(terrain_mesh(terrain))
    ortho = orthorectify(grid, image, camera, caster=caster, post_scale=scale, dem=terrain)
    assert tiled.grid.shape == grid.shape and tiled.grid.transform == grid.transform
    np.testing.assert_array_equal(a["visibility"][0], ortho.visibility.codes)
    np.testing.assert_allclose(a["ortho"], ortho.data, rtol=1e-5, equal_nan=True)
    # a projected CRS on the same body
    eqc = "+proj=eqc +lat_ts=26 +lon_0=3.6 +R=1737400 +units=m +no_defs"
    c1 = run(
        plan_ortho(crater["dem"], [view], tile=16, crs=eqc, progress=False, grid="dem"),
        tmp_path,
        "c",
    )
    c2 = run(
        plan_ortho(crater["dem"], [view], tile=64, crs=eqc, progress=False, grid="dem"),
        tmp_path,
        "d",
    )
    np.testing.assert_array_equal(c1["visibility"], c2["visibility"])
    same(c1["ortho"], c2["ortho"])
    with rasterio.open(tmp_path / "c-ortho.tif") as src:
        assert src.crs.to_dict().get("proj") == "eqc"
        assert abs(src.transform.a - 80.0) < 1.0  # the DEM's 80 m posts
    with pytest.raises(InputError, match="another body"):
        plan_ortho(crater["dem"], [view], crs="EPSG:4326", progress=False, grid="dem")


def test_naive_builds_no_mesh(crater: dict, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    view = crater["views"]["oblique"]

    def refuse(*args: object, **kw: object) -> None:
        raise AssertionError("a mesh was built")

    monkeypatch.setattr("orthomvp.occlusion.occluders.occluder_mesh", refuse)
    monkeypatch.setattr("orthomvp.occlusion.visibility.occluder_mesh", refuse)
    plan = plan_ortho(crater["dem"], [view], tile=16, occlusion=False, progress=False, grid="dem")
    got = run(plan, tmp_path, "naive", kinds=("ortho",))
    image, camera = load_view(*view)
    same(got["ortho"], orthorectify(crater["terrain"], image, camera, occlusion=False).data)


@pytest.mark.parametrize("threads", [None, 16])
def test_visibility_alone_reads_no_image(
    crater: dict,
    tmp_path: Path,
    monkeypatch,
    threads: int | None,  # noqa: ANN001
) -> None:
    """Not even ahead, in a tile's spare thread (16 threads for a few tiles: they would)."""
    reads = []
    monkeypatch.setattr(ImageSource, "read", lambda *args, **kw: reads.append(args))
    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=32, progress=False, grid="dem")
    assert len(plan.tiles) < 16
    got = run(plan, tmp_path, "vis", kinds=("visibility",), threads=threads)
    expected = compute_visibility(crater["terrain"], load_view(*view)[1])
    np.testing.assert_array_equal(got["visibility"][0], expected.codes)
    assert reads == []


def test_uncovered_tiles_are_skipped(crater: dict, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """An image that covers part of the DEM: tiles it cannot see are not read at all."""
    image, camera = load_view(*crater["views"]["nadir"])
    part = image[:, :50, :45]
    write_geotiff(tmp_path / "part.tif", part, Affine.identity(), None)
    camera = camera.with_image_size(None, None)
    reads = []
    original = engine_grid.DemSource.read
    monkeypatch.setattr(
        engine_grid.DemSource, "read", lambda self, w: reads.append(w) or original(self, w)
    )
    plan = plan_ortho(
        crater["dem"], [(tmp_path / "part.tif", camera)], tile=16, progress=False, grid="dem"
    )
    got = run(plan, tmp_path, "part", threads=1)
    assert got["report"].tiles_skipped > 0
    assert len(reads) == got["report"].tiles_run < len(plan.tiles)
    expected = orthorectify(crater["terrain"], part, camera)
    np.testing.assert_array_equal(got["visibility"][0], expected.visibility.codes)
    same(got["ortho"], expected.data)


def test_huge_image_windows_are_sampled_in_pieces(
    crater: dict,
    tmp_path: Path,
    monkeypatch,  # noqa: ANN001
) -> None:
    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=32, progress=False, grid="dem")
    whole = run(plan, tmp_path, "whole", kinds=("ortho",))
    reads = []
    original = ImageSource.read
    monkeypatch.setattr(ImageSource, "read", lambda self, w: reads.append(w) or original(self, w))
    monkeypatch.setattr("orthomvp.engine.tile.SAMPLE_BUDGET_PIXELS", 200)
    pieces = run(plan, tmp_path, "pieces", kinds=("ortho",))
    np.testing.assert_array_equal(whole["ortho"], pieces["ortho"])
    assert len(reads) > 4 * len(plan.tiles)
    assert max((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in reads) <= 200


def grazing_view(terrain: Terrain, tmp_path: Path) -> tuple[Path, PinholeCamera]:
    """A camera 25 km from the crater's centre, 1.5 km up: lines of sight 2 to 4 degrees above
    the horizon; its image is noise."""
    rows, cols = terrain.shape
    mid = np.array((cols - 1) / 2), np.array((rows - 1) / 2)
    target = terrain.to_world(*mid, np.array(0.0))
    up = target / np.linalg.norm(target)
    north = np.array([0.0, 0.0, 1.0]) - up * up[2]
    north /= np.linalg.norm(north)
    centre = target + 1500.0 * up - 25_000.0 * north
    rotation = look_at(centre, target, north)
    camera = PinholeCamera(700.0, 700.0, 100.0, 60.0, centre, rotation, width=200, height=120)
    rng = np.random.default_rng(1)
    write_geotiff(
        tmp_path / "grazing.tif", rng.random((1, 120, 200), np.float32), Affine.identity(), None
    )
    return tmp_path / "grazing.tif", camera


def test_grazing_view_warns_and_stays_correct(crater: dict, tmp_path: Path) -> None:
    path, camera = grazing_view(crater["terrain"], tmp_path)
    with pytest.warns(HaloWarning, match="degrees above the horizon"):
        plan = plan_ortho(crater["dem"], [(path, camera)], tile=16, progress=False, grid="dem")
    assert plan.elevation[0] < 5.0
    got = run(plan, tmp_path, "grazing")
    expected = compute_visibility(crater["terrain"], camera)
    np.testing.assert_array_equal(got["visibility"][0], expected.codes)
    assert (expected.codes == 2).sum() > 100  # much of the crater is hidden


def test_outputs_cog_gtiff_dtypes(crater: dict, tmp_path: Path) -> None:
    view = crater["views"]["oblique"]
    plan = plan_ortho(
        crater["dem"], [view], tile=64, res=(0.0009, 0.0007), progress=False, grid="dem"
    )
    cog = tmp_path / "cog.tif"
    run_plan(plan, Outputs(ortho=cog, blocksize=64), progress=False)  # zstd, level 1: the default
    with rasterio.open(cog) as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert src.compression.name == "zstd" and src.block_shapes[0] == (64, 64)
        assert src.overviews(1) and src.dtypes[0] == "float32" and np.isnan(src.nodata)
        reference = src.read(1)
    tif = tmp_path / "plain.tif"
    out = Outputs(ortho=tif, format="gtiff", compress="lzw", dtype="uint8", nodata=0, blocksize=64)
    run_plan(plan, out, progress=False)
    with rasterio.open(tif) as src:
        assert src.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") != "COG"
        assert src.block_shapes[0] == (64, 64)
        assert src.overviews(1) and src.compression.name == "lzw" and src.nodata == 0
        codes = src.read(1)
    empty = np.isnan(reference)
    assert (codes[empty] == 0).all() and (codes[~empty] >= 1).all()
    expected = np.clip(np.rint(reference[~empty]), 1, 255)
    np.testing.assert_array_equal(codes[~empty], expected)
    slow = tmp_path / "slow.tif"  # deflate, GDAL's default level, when asked for
    run_plan(plan, Outputs(ortho=slow, blocksize=64, compress="deflate"), progress=False)
    with rasterio.open(slow) as src:
        assert src.compression.name == "deflate"
        np.testing.assert_array_equal(src.read(1), reference)
    plan16 = plan_ortho(crater["dem"], [view], tile=16, progress=False, grid="dem")
    out = Outputs(ortho=tmp_path / "i16.tif", compress="none", dtype="int16")
    run_plan(plan16, out, progress=False)
    with rasterio.open(tmp_path / "i16.tif") as src:
        assert src.dtypes[0] == "int16" and src.nodata == -32768 and src.compression is None
    for bad in ({"format": "png"}, {"compress": "jpeg"}, {"dtype": "float64"}, {"blocksize": 100}):
        with pytest.raises(InputError):
            Outputs(ortho=tmp_path / "x.tif", **bad)
    with pytest.raises(InputError, match="not a uint8 value"):
        Outputs(ortho=tmp_path / "x.tif", dtype="uint8", nodata=-1)


def test_failures_leave_no_output(crater: dict, tmp_path: Path) -> None:
    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=32, progress=False, grid="dem")
    with pytest.raises(InputError, match="does not exist"):
        run_plan(plan, Outputs(ortho=tmp_path / "a.tif", visibility=tmp_path / "no/v.tif"))
    assert list(tmp_path.iterdir()) == []
    camera = load_view(*view)[1]
    away = replace(camera, rotation=camera.rotation @ np.diag([1.0, -1.0, -1.0]))
    with pytest.raises(GeometryError, match="look away"):
        plan_ortho(crater["dem"], [(view[0], away)], progress=False, grid="dem")


class DyingCamera(PinholeCamera):
    """A camera whose projection kills the worker process it runs in."""

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if multiprocessing.parent_process() is not None:
            os._exit(3)
        return super().project(xyz)


def test_processes_equal_threads_and_dead_worker(crater: dict, tmp_path: Path) -> None:
    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=16, progress=False, grid="dem")
    a, b = run(plan, tmp_path, "thr", threads=2), run(plan, tmp_path, "proc", processes=2)
    np.testing.assert_array_equal(a["visibility"], b["visibility"])
    np.testing.assert_array_equal(a["ortho"], b["ortho"])
    camera = load_view(*view)[1]
    dying = DyingCamera(**{k: getattr(camera, k) for k in camera.__dataclass_fields__})
    plan = plan_ortho(crater["dem"], [(view[0], dying)], tile=16, progress=False, grid="dem")
    before = set(tmp_path.iterdir())
    with pytest.raises(WorkerError, match="worker died"):
        run_plan(plan, Outputs(ortho=tmp_path / "dead.tif"), processes=2, progress=False)
    assert set(tmp_path.iterdir()) == before


def test_dask_local_cluster_equals_threads(crater: dict, tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=16, progress=False, grid="dem")
    a = run(plan, tmp_path, "thr", threads=2)
    with dask_client(workers=2) as client:
        b = run(plan, tmp_path, "dask", client=client)
    np.testing.assert_array_equal(a["visibility"], b["visibility"])
    np.testing.assert_array_equal(a["ortho"], b["ortho"])
    with pytest.raises(InputError, match="no Dask scheduler answers at tcp://127.0.0.1:9") as err:
        with dask_client(address="tcp://127.0.0.1:9", timeout=1):
            pass
    assert "\n" not in str(err.value)


def test_dask_without_distributed_says_what_to_install(
    crater: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without Dask's distributed (the dask extra), dask_client and --dask give one line that
    names the package to install (it was an internal error), and write nothing."""
    monkeypatch.setitem(sys.modules, "distributed", None)  # (an import of it fails)
    with pytest.raises(InputError, match=r"pip install dask\[distributed\]") as err:
        with dask_client(workers=1):
            pass
    assert "\n" not in str(err.value)
    image, camera = crater["views"]["oblique"]
    out = tmp_path / "ortho.tif"
    args = ("ortho", str(crater["dem"]), str(image), str(camera), "-o", str(out))
    assert_one_line_error(cli_run(*args, "--dask", "local:1"), "pip install dask[distributed]")
    assert list(tmp_path.iterdir()) == []


class DyingOnceCamera(PinholeCamera):
    """A camera whose first projection in a worker process kills that process; the marker
    file named by $ORTHOMVP_TEST_DIED (inherited by the workers) records the death."""

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        marker = Path(os.environ["ORTHOMVP_TEST_DIED"])
        if multiprocessing.parent_process() is not None and not marker.exists():
            marker.touch()
            os._exit(3)
        return super().project(xyz)


@pytest.mark.slow
def test_dask_retries_a_dead_workers_tile_or_fails_cleanly(
    crater: dict, tmp_path: Path, monkeypatch
) -> None:  # noqa: ANN001
    """A Dask worker that dies under a tile: its tile is retried on a restarted worker and
    the output equals the threaded one; a tile that kills every worker it runs on ends the
    run with one WorkerError line and no output."""
    pytest.importorskip("distributed")
    import dask

    view = crater["views"]["oblique"]
    camera = load_view(*view)[1]
    fields = {k: getattr(camera, k) for k in camera.__dataclass_fields__}
    a = run(
        plan_ortho(crater["dem"], [view], tile=16, progress=False, grid="dem"),
        tmp_path,
        "thr",
        threads=2,
    )
    marker = tmp_path / "died"
    monkeypatch.setenv("ORTHOMVP_TEST_DIED", str(marker))
    once = plan_ortho(
        crater["dem"], [(view[0], DyingOnceCamera(**fields))], tile=16, progress=False, grid="dem"
    )
    always = plan_ortho(
        crater["dem"], [(view[0], DyingCamera(**fields))], tile=16, progress=False, grid="dem"
    )
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        with dask_client(workers=2) as client:
            b = run(once, tmp_path, "retried", client=client)
            assert marker.exists()  # a worker did die
            before = set(tmp_path.iterdir())
            with pytest.raises(WorkerError, match="worker died") as err:
                run_plan(
                    always, Outputs(ortho=tmp_path / "dead.tif"), client=client, progress=False
                )
    assert "\n" not in str(err.value)
    assert set(tmp_path.iterdir()) == before
    np.testing.assert_array_equal(a["visibility"], b["visibility"])
    np.testing.assert_array_equal(a["ortho"], b["ortho"])


def test_preflight_and_progress(crater: dict, tmp_path: Path, monkeypatch, capfd) -> None:  # noqa: ANN001
    view = crater["views"]["oblique"]
    monkeypatch.setattr("orthomvp.engine.progress.LOG_AFTER", 0.0)  # log even short phases
    plan = plan_ortho(crater["dem"], [view], tile=16, progress=True, grid="dem")
    err = capfd.readouterr().err
    assert "reading the DEM's heights" in err and "planning tiles: 16/16" in err
    run_plan(plan, Outputs(ortho=tmp_path / "o.tif"), threads=1, progress=True)
    err = capfd.readouterr().err
    assert "plan: 64 x 64 posts, 16 of 16 tiles of 16 x 16" in err and "GiB" in err
    assert "orthomvp: tiles: 16/16 tiles (100%)" in err
    run_plan(plan, Outputs(ortho=tmp_path / "q.tif"), threads=1, progress=False)
    assert capfd.readouterr().err == ""
    monkeypatch.setattr(engine_run, "available_memory", lambda: 100 << 20)
    with pytest.raises(InputError, match="use smaller tiles or fewer threads/processes"):
        run_plan(plan, Outputs(ortho=tmp_path / "m.tif"), progress=False)
    assert not (tmp_path / "m.tif").exists()


def test_bad_options(crater: dict) -> None:
    view = crater["views"]["oblique"]
    for kw, match in (
        ({"tile": 1}, "tile must be"),
        ({"eps": -1.0}, r"eps \(DEM posts\) must be > 0"),
        ({"interp": "lanczos"}, "interpolation"),
        ({"world": "moon"}, "world frame"),
    ):
        with pytest.raises(InputError, match=match):
            plan_ortho(crater["dem"], [view], progress=False, **kw, grid="dem")
    with pytest.raises(InputError, match="at least one image"):
        plan_ortho(crater["dem"], [], progress=False, grid="dem")


def test_cube_windows_match_the_whole_cube(tmp_path: Path) -> None:
    from test_isis import synthetic_raw, write_cube

    from orthomvp.io.isis import read_cube

    raw, _ = synthetic_raw("SignedWord", np.random.default_rng(0))
    for tile in (None, (4, 3)):
        path = tmp_path / f"c{tile is None}.cub"
        write_cube(path, raw, "SignedWord", "Msb", tile, -12.5, 0.25)
        whole = read_cube(path)
        source = ImageSource(path, 9, 7, 2, None)  # type: ignore[arg-type]
        for window in ((0, 7, 0, 9), (2, 5, 3, 8), (6, 7, 8, 9)):
            r0, r1, c0, c1 = window
            np.testing.assert_array_equal(source.read(window), whole[:, r0:r1, c0:c1])


def vm(field: str) -> int:
    """A memory figure of this process from /proc/self/status, bytes."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {field} in /proc/self/status")


def rss_of_run(dem: Path, image: Path, camera: PinholeCamera, tile: int) -> tuple[int, int]:
    """In a fresh process: the resident set size once everything is imported, and its peak
    while planning and running the orthophoto (DEM scanned in blocks of 64 Ki posts), bytes.
    The peak is reset first (Linux: writing 5 to /proc/self/clear_refs resets VmHWM)."""
    engine_grid.SCAN_POSTS = 1 << 16
    Path("/proc/self/clear_refs").write_text("5")
    base = vm("VmRSS")
    plan = plan_ortho(dem, [(image, camera)], tile=tile, progress=False, grid="dem")
    run_plan(plan, Outputs(ortho=dem.parent / "o.tif"), threads=1, progress=False)
    return base, vm("VmHWM")


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc")
def test_memory_is_bounded_by_the_tile(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """Peak memory (RSS above the loaded interpreter) of planning and running an orthophoto in
    tiles of 256 posts: a DEM of 1024 x 1024 posts needs no more than 1.5 times what one of a
    quarter the posts does, and far less than the ~390 B/post of an untiled run. Planning
    alone (traced allocations, DEM scanned in blocks of 64 Ki posts) is as flat."""
    monkeypatch.setattr(engine_grid, "SCAN_POSTS", 1 << 16)
    monkeypatch.setattr(engine_grid, "HELD_POSTS", 0)  # (a bounded 2 MiB otherwise)
    grown, planning = [], []
    for n in (512, 1024):
        folder = tmp_path / str(n)
        folder.mkdir()
        scene = write_scale_scene(folder, n)
        tracemalloc.start()
        plan_ortho(scene[0], [scene[1:]], tile=256, progress=False, grid="dem")
        planning.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(1, mp_context=ctx) as pool:
            base, peak = pool.submit(rss_of_run, *scene, 256).result()
        grown.append(peak - base)
    assert planning[1] < 1.5 * planning[0], [p / 2**20 for p in planning]
    assert grown[1] < 1.5 * grown[0], [g / 2**20 for g in grown]
    assert grown[1] < 0.5 * 1024 * 1024 * 390, [g / 2**20 for g in grown]


def test_image_source_checks_the_camera(crater: dict) -> None:
    image, camera = crater["views"]["oblique"]
    wrong = load_view(image, camera)[1].with_image_size(10, 10)
    with pytest.raises(InputError, match="but its camera says 10 x 10"):
        image_source(image, wrong)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        src = image_source(image, camera)
    assert (src.width, src.height, src.bands) == (src.camera.width, src.camera.height, 1)


def test_cli_engine_choices_match_the_engine() -> None:
    from orthomvp.cli import engine_options
    from orthomvp.engine import writer

    assert engine_options.FORMATS == writer.FORMATS
    assert engine_options.COMPRESSIONS == writer.COMPRESSIONS
    assert engine_options.DTYPES == tuple(writer.NODATA)


def test_bench_scale_command(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    from orthomvp.cli import main

    assert main(["bench", "--scale", "128", "--json", str(tmp_path / "scale.json")]) == 0
    (row,) = json.loads((tmp_path / "scale.json").read_text())["scale"]
    assert row["posts"] == 128 * 128 and row["filled"] > 0.9 * row["posts"]
    assert row["us_per_post"] > 0 and row["peak_rss_mb"] > 0
    assert abs(sum(row["shares"].values()) - 1) < 1e-9
    assert "us/post" in capsys.readouterr().out


@pytest.mark.parametrize("compress", ["deflate", "none"])
def test_outputs_switch_to_bigtiff_when_they_may_pass_4_gib(tmp_path: Path, compress: str) -> None:
    """The engine's creation options give a classic TIFF (version 42) for a small output and
    a BigTIFF (version 43) for one that may pass 4 GiB (here 6.4 GB of float32 before
    compression); GDAL writes the header at creation, so no data needs writing."""
    from orthomvp.engine.writer import _creation

    opts = _creation(Outputs(ortho=tmp_path / "o.tif", compress=compress), "float32")
    versions = {}
    for side in (1000, 40000):
        path = tmp_path / f"{side}.tif"
        profile = dict(driver="GTiff", width=side, height=side, count=1, dtype="float32")
        with rasterio.open(path, "w", tiled=True, sparse_ok=True, **profile, **opts):
            pass
        versions[side] = int.from_bytes(path.read_bytes()[2:4], "little")
    assert versions == {1000: 42, 40000: 43}


def test_auto_tile_gives_every_core_a_tile_on_small_grids(crater_dir: Path) -> None:
    """The default tile: 1024 posts, or the longer side split among the cores (rounded up to
    a multiple of 64, at least 256 posts); a plan without ``tile`` uses it."""
    from orthomvp.engine.tiling import SINGLE_VIEW_TILE, auto_tile, check_tile

    assert auto_tile((5000, 3000), 2) == 1024
    assert auto_tile((508, 327), 2) == 256  # 2 x 2 tiles
    assert auto_tile((1400, 600), 2) == 704  # a multiple of 64: overviews from the tiles
    assert auto_tile((3000, 600), 4) == 768
    assert auto_tile((100, 50), 2) == 256
    # a single view's orthophoto: one tile below two of SINGLE_VIEW_TILE
    assert auto_tile((291, 163), 2, smallest=SINGLE_VIEW_TILE) == 512
    assert auto_tile((1164, 651), 2, smallest=SINGLE_VIEW_TILE) == 640
    assert check_tile(None) is None
    # a mosaic's tiles keep every view's samples under the heap's mmap threshold
    from orthomvp.engine.heap import MMAP_THRESHOLD
    from orthomvp.engine.tiling import MOSAIC_SMALL_TILE, mosaic_tile

    assert mosaic_tile(2, 3, 13) == 1024 and mosaic_tile(30, 3, 13) == 256
    # where many views overlap, below 256 posts (MOSAIC_SMALL_TILE), however many views
    assert mosaic_tile(50, 3, 13) == mosaic_tile(500, 3, 13) == MOSAIC_SMALL_TILE < 256
    for views, bands in ((3, 1), (4, 3), (6, 3), (8, 4)):
        tile = mosaic_tile(views, bands, 13)
        stack = (tile + 26) ** 2 * views * bands * 4  # bytes, the tile with its margin
        bigger = (tile + 128 + 26) ** 2 * views * bands * 4
        assert stack <= MMAP_THRESHOLD and (tile == 1024 or bigger > MMAP_THRESHOLD)
    assert auto_tile((5000, 3000), 2, largest=768) == 768
    view = [(crater_dir / "nadir.tif", crater_dir / "nadir.tsai")]
    plan = plan_ortho(crater_dir / "dem.tif", view, progress=False, grid="dem")
    assert (
        plan.tile == auto_tile(plan.grid.shape, smallest=SINGLE_VIEW_TILE) and len(plan.tiles) == 1
    )


@pytest.mark.parametrize("views", [("oblique",), ("oblique", "nadir")])
def test_a_tile_leaves_no_reference_cycles(crater_dir: Path, views: tuple[str, ...]) -> None:
    """An ortho or mosaic tile's arrays go back when its result is dropped, without a garbage
    collection (the engine runs none after a tile): no array is left in a reference cycle."""
    import gc

    from orthomvp.engine.tile import run_tile

    pairs = [(crater_dir / f"{v}.tif", crater_dir / f"{v}.tsai") for v in views]
    plan = plan_ortho(crater_dir / "dem.tif", pairs, tile=32, progress=False, grid="dem")
    run_tile(plan, 0, frozenset({"ortho", "source"}))  # first calls: caches, lazy imports
    gc.collect()
    gc.disable()
    try:
        gc.set_debug(gc.DEBUG_SAVEALL)  # keep what a collection finds, to look at
        for job in plan.tiles:
            result = run_tile(plan, job.index, frozenset({"ortho", "source", "visibility"}))
            del result
            gc.collect()
            assert not [o for o in gc.garbage if isinstance(o, np.ndarray)], job.index
            gc.garbage.clear()
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()


def test_sample_grid_gives_sample_views_values_in_place(
    crater: dict, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The tile's sampling on its grid of positions equals sampling the kept positions as a
    list (bit for bit), NaN where not kept; also when the image window is over the budget
    and the list is sampled in pieces."""
    from orthomvp.engine import tile as tile_module
    from orthomvp.engine.images import image_source

    image, camera_path = crater["views"]["oblique"]
    view = image_source(image, camera_path)
    vis = compute_visibility(crater["terrain"], view.camera)
    uv, keep = vis.uv, vis.codes == 1
    assert keep.any() and not keep.all()
    expected = np.full((view.bands, *keep.shape), np.nan, np.float32)
    expected[:, keep] = tile_module.sample_view(view, uv[keep], "bilinear")
    np.testing.assert_array_equal(tile_module.sample_grid(view, uv, keep, "bilinear"), expected)
    out = np.zeros(expected.shape, np.float32)  # into a given array, NaN where not kept
    assert tile_module.sample_grid(view, uv, keep, "bilinear", out=out) is out
    np.testing.assert_array_equal(out, expected)
    none = tile_module.sample_grid(view, uv, np.zeros_like(keep), "bilinear", out=out)
    assert none is out and np.isnan(out).all()
    fortran = np.asfortranarray(uv)  # any memory layout of the positions
    got = tile_module.sample_grid(view, fortran, keep, "bilinear")
    np.testing.assert_array_equal(got, expected)
    monkeypatch.setattr(tile_module, "SAMPLE_BUDGET_PIXELS", 64)
    pieces = tile_module.sample_grid(view, uv, keep, "bilinear")
    np.testing.assert_array_equal(pieces, expected)
    out[...] = 0
    tile_module.sample_grid(view, uv, keep, "bilinear", out=out)
    np.testing.assert_array_equal(out, expected)


def test_a_small_dem_is_held_and_read_from_memory(
    crater: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A DEM of at most HELD_POSTS posts is kept by the scan, and its windows equal the
    file's; a larger one is read from the file; the outputs are the same either way."""
    from orthomvp.engine import grid as grid_module

    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], tile=24, progress=False, grid="dem")
    assert plan.dem.held is not None
    monkeypatch.setattr(grid_module, "HELD_POSTS", 100)
    unheld = plan_ortho(crater["dem"], [view], tile=24, progress=False, grid="dem")
    assert unheld.dem.held is None
    for window in ((0, 64, 0, 64), (3, 40, 10, 33), (60, 64, 0, 5)):
        np.testing.assert_array_equal(plan.dem.read(window), unheld.dem.read(window))
    a, b = run(plan, tmp_path, "held"), run(unheld, tmp_path, "file")
    np.testing.assert_array_equal(a["ortho"], b["ortho"])
    np.testing.assert_array_equal(a["visibility"], b["visibility"])


def test_prefetched_image_windows_sample_as_reads(
    crater: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tile with a spare thread reads each view's image window (from the plan) in the
    background; it holds the window that sampling needs (no other read), and the outputs
    are the same as with one thread, which reads the windows as it samples them."""
    from concurrent.futures import Future

    from orthomvp.engine import tile as tile_module
    from orthomvp.engine.images import ImageSource

    view = crater["views"]["oblique"]
    plan = plan_ortho(crater["dem"], [view], progress=False, grid="dem")
    assert len(plan.tiles) == 1 and plan.tiles[0].image_windows
    job = plan.tiles[0]
    with tile_module._prefetch(plan, job, 1) as none:
        assert none == {}
    with tile_module._prefetch(plan, job, 2) as reads:
        ((window, future),) = reads.values()
        assert isinstance(future, Future) and window == job.image_windows[0]
        pixels = future.result()
        r0, r1, c0, c1 = window
        np.testing.assert_array_equal(pixels, plan.views[0].read(window))
    readers, reading = [], ImageSource.read

    def counted(self: ImageSource, window: tuple, *args: object) -> np.ndarray:
        readers.append(window)
        return reading(self, window, *args)

    monkeypatch.setattr(ImageSource, "read", counted)
    one = run_plan(plan, Outputs(ortho=tmp_path / "one.tif"), threads=1, progress=False)
    alone, readers[:] = list(readers), []
    two = run_plan(plan, Outputs(ortho=tmp_path / "two.tif"), threads=2, progress=False)
    # the plan's window, read once, against the window that sampling needs
    assert readers == [job.image_windows[0]] and len(alone) == 1 and alone != readers
    assert one.filled == two.filled > 0
    np.testing.assert_array_equal(read(tmp_path / "one.tif"), read(tmp_path / "two.tif"))


def test_a_mosaics_small_tiles_grow_where_the_grid_would_need_too_many(
    crater_dir: Path, monkeypatch
) -> None:  # noqa: ANN001
    """Where many views overlap, a mosaic's default tile may go below 256 posts
    (MOSAIC_SMALL_TILE); where that would cut the grid into more than MAX_TILES tiles, the
    default grows (by TILE_STEP) until it does not, instead of refusing a plan whose tile the
    user did not choose. A tile the user chose is still refused."""
    import orthomvp.engine.grid_choice as grid_choice
    import orthomvp.engine.plan as plan_module
    from orthomvp.errors import InputError

    views = [(crater_dir / f"{v}.tif", crater_dir / f"{v}.tsai") for v in ("nadir", "oblique")]
    monkeypatch.setattr(plan_module, "mosaic_tile", lambda *args: 192)
    plan = plan_ortho(crater_dir / "dem.tif", views, progress=False, grid="dem", res="5m")
    rows, cols = plan.grid.shape
    assert plan.tile == 192 and rows > 2 * 192
    at = {side: -(-rows // side) * -(-cols // side) for side in (192, 256)}
    assert at[192] > at[256]
    for module in (grid_choice, plan_module):
        monkeypatch.setattr(module, "MAX_TILES", at[256])
    plan = plan_ortho(crater_dir / "dem.tif", views, progress=False, grid="dem", res="5m")
    assert plan.tile == 256 and len(plan.tiles) == at[256]
    with pytest.raises(InputError, match="choose larger tiles"):
        plan_ortho(crater_dir / "dem.tif", views, progress=False, grid="dem", res="5m", tile=192)
