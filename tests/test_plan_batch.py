"""Batched planning (orthomvp.engine.halo.TileSamples): the image boxes and occluder halos of
many tiles for one camera at once are those of image_box and tile_halo tile by tile, to the
bit, for a frame camera (map and body frame), a camera that sees tiles partly behind it, an
RPC camera, a line scanner, and a camera that does not image part of the ground; and a plan
is the one the per-tile planner makes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from orthomvp.bench.mosaic import growing_scene
from orthomvp.camera import PinholeCamera
from orthomvp.engine import halo, plan_ortho
from orthomvp.engine.grid import grid_to_dem
from orthomvp.engine.halo import (
    BATCH_POSTS,
    TileSamples,
    footprint,
    image_box,
    tile_halo,
    tile_runs,
)
from orthomvp.engine.plan import TileJob, _sees, _union, grow, pixel_window
from orthomvp.synthetic import make_scene
from orthomvp.synthetic.cameras import look_at
from tests.conftest import SHARED_DATA
from tests.test_generic_camera import Generic

QUICKBIRD = SHARED_DATA / "rpc-quickbird" / "qb2_basic1b.tif"
NGI = SHARED_DATA / "ngi-aerial"


def windows(shape: tuple[int, int], seed: int) -> list[tuple[int, int, int, int]]:
    """Tiles of 16 and 40 posts over a grid of ``shape`` and 60 random windows of 1 to 90
    posts a side (some of one row or column)."""
    rows, cols = shape
    out = [
        (r, min(r + side, rows), c, min(c + side, cols))
        for side in (16, 40)
        for r in range(0, rows, side)
        for c in range(0, cols, side)
    ]
    rng = np.random.default_rng(seed)
    for _ in range(60):
        h, w = (int(x) for x in rng.integers(1, 90, 2))
        r0, c0 = int(rng.integers(0, rows)), int(rng.integers(0, cols))
        out.append((r0, min(r0 + h, rows), c0, min(c0 + w, cols)))
    return out


def behind(plan: object) -> PinholeCamera:
    """A frame camera just above the grid's middle, looking level to the east: the western
    tiles lie behind it, those across its meridian partly."""
    rows, cols = plan.grid.shape
    to_dem = grid_to_dem(plan.grid, plan.dem)
    c, r = to_dem(np.array([cols / 2]), np.array([rows / 2]))
    centre = plan.dem.to_world(c, r, np.array([plan.dem.h_max + 5.0]))[0]
    east = plan.dem.to_world(c + 1, r, np.array([plan.dem.h_max + 5.0]))[0] - centre
    up = plan.dem.preview.up_vectors(centre[None])[0]
    north = np.cross(up, east)
    rotation = look_at(centre, centre + east / np.linalg.norm(east), north / np.linalg.norm(north))
    return PinholeCamera(400.0, 400.0, 500.0, 500.0, centre, rotation, width=1000, height=1000)


def cases(crater_dir: Path, city_dir: Path, tmp: Path) -> dict[str, tuple]:
    """Per case: a plan (for its DEM and grid) and the camera to test on it."""
    out: dict[str, tuple] = {}
    city = [(city_dir / "nw.tif", city_dir / "nw.tsai")]
    plan = plan_ortho(city_dir / "dem.tif", city, progress=False, occlusion=False)
    out["frame, map frame"] = (plan, plan.views[0].camera)
    out["frame, partly behind"] = (plan, behind(plan))
    crater = [(crater_dir / "oblique.tif", crater_dir / "oblique.tsai")]
    plan = plan_ortho(crater_dir / "dem.tif", crater, progress=False, occlusion=False)
    out["frame, body frame"] = (plan, plan.views[0].camera)
    out["partly imaged (a strip)"] = (plan, Generic(plan.views[0].camera, rows=(40.0, 80.0)))
    linescan = tmp / "linescan"
    make_scene("crater", size=64, spacing=80.0, sensor="linescan").write(linescan, supersample=1)
    view = [(linescan / "linescan.tif", linescan / "linescan.json")]
    plan = plan_ortho(linescan / "dem.tif", view, progress=False, occlusion=False)
    out["line scanner"] = (plan, plan.views[0].camera)
    if QUICKBIRD.is_file():
        plan = plan_ortho(
            NGI / "dem.tif",
            [(QUICKBIRD, QUICKBIRD)],
            res="24m",
            progress=False,
            occlusion=False,
            height_offset=28.0,  # EGM2008's undulation there (as orthomvp.bench.gdal has it)
        )
        out["RPC"] = (plan, plan.views[0].camera)
    return out


@pytest.fixture(scope="module")
def scenes(crater_dir: Path, city_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    return cases(crater_dir, city_dir, tmp_path_factory.mktemp("batch"))


NAMES = [
    "frame, map frame",
    "frame, partly behind",
    "frame, body frame",
    "partly imaged (a strip)",
    "line scanner",
    "RPC",
]


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_batched_boxes_and_halos_are_the_per_tile_ones(scenes: dict, name: str) -> None:
    """Over about 80 windows (500 on the RPC's grid), and over every other one (a batch of a
    subset), the boxes and halos equal image_box's and tile_halo's exactly (floats compared
    with ==); each case takes the branches it is there for."""
    if name not in scenes:
        pytest.skip(f"real data not available: {QUICKBIRD} is absent")
    plan, camera = scenes[name]
    dem, to_dem = plan.dem, grid_to_dem(plan.grid, plan.dem)
    tiles = windows(plan.grid.shape, len(name))
    samples = TileSamples(dem, to_dem, tiles)
    truth = [image_box(dem, to_dem, tile, camera) for tile in tiles]
    for which in (list(range(len(tiles))), list(range(1, len(tiles), 2))):
        assert samples.image_boxes(which, camera) == [truth[i] for i in which]
        halos = [tile_halo(dem, to_dem, tiles[i], camera) for i in which]
        assert samples.halos(which, camera) == halos
    assert samples.image_boxes([], camera) == [] and samples.halos([], camera) == []
    plane = [box == (-np.inf, np.inf, -np.inf, np.inf) for box in truth]
    finite = [box is not None and np.isfinite(box).all() for box in truth]
    if name == "frame, partly behind":
        assert any(plane) and None in truth and any(finite)
    elif name == "partly imaged (a strip)":  # the dense lattice, and tiles it misses
        assert None in truth and any(finite) and not any(plane)
    else:
        assert all(finite)


def per_tile(plan: object, margin: int) -> tuple[list[TileJob], list[float], list[float]]:
    """The planner as it was before batching: image_box then tile_halo, view by view, tile by
    tile (every view tried in every tile)."""
    dem, grid, views = plan.dem, plan.grid, plan.views
    to_dem = grid_to_dem(grid, dem)
    jobs, reach, elevation = [], [0.0] * len(views), [90.0] * len(views)
    for index, tile in enumerate(grid.tiles(plan.tile)):
        window = grow(tile, margin, grid.shape)
        need = footprint(dem, to_dem, window, grid.on_dem)
        seen, images = [], []
        for k, view in enumerate(views if need[0] < need[1] and need[2] < need[3] else ()):
            box = image_box(dem, to_dem, window, view.camera)
            if not _sees(box, view):
                continue
            seen.append(k)
            images.append(pixel_window(view, (box[0], box[2]), (box[1], box[3])))
            halo = tile_halo(dem, to_dem, window, view.camera)
            need = _union(need, halo.window)
            reach[k] = max(reach[k], halo.reach)
            elevation[k] = min(elevation[k], halo.elevation)
        job = TileJob(index, tile, tuple(seen), need, tuple(images))
        jobs.append(job if seen else TileJob(index, tile, (), None, ()))
    return jobs, reach, elevation


@pytest.mark.slow
@pytest.mark.parametrize("where", ["synthetic", "ngi-aerial"])
def test_plans_are_those_of_the_per_tile_planner(
    where: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 16-image mosaic plan (tiles of 64 posts, in runs of the default size and of one tile
    each, and of the default side): every tile's views, DEM window and image windows, and
    every view's reach and elevation, are the per-tile planner's."""
    if where == "ngi-aerial" and not (NGI / "dem.tif").is_file():
        pytest.skip(f"real data not available: {NGI} is absent")
    dem, views, _ = growing_scene(NGI if where == "ngi-aerial" else None, 16, tmp_path)
    for tile, batch in ((64, BATCH_POSTS), (64, 1), (None, BATCH_POSTS)):
        monkeypatch.setattr(halo, "BATCH_POSTS", batch)
        plan = plan_ortho(dem, views, res="30m", progress=False, tile=tile)
        if batch == BATCH_POSTS:
            assert len(tile_runs(list(plan.grid.tiles(plan.tile)))) > 1 or tile is None
        jobs, reach, elevation = per_tile(plan, plan.margin)
        assert list(plan.tiles) == jobs
        assert plan.reach == tuple(reach) and plan.elevation == tuple(elevation)
        assert sum(len(job.views) for job in jobs) > len(jobs)
