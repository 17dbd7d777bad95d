"""Planning from the views' index (orthomvp.engine.view_index): a tile meets only the views
that can see it, and never misses one that the brute-force test (image_box on every view)
finds; plans are the same with and without the index."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import orthomvp.engine.plan as plan_module
from orthomvp.bench.mosaic import growing_scene
from orthomvp.engine import plan_ortho
from orthomvp.engine.grid import grid_to_dem
from orthomvp.engine.halo import image_box
from orthomvp.engine.plan import IMAGE_MARGIN, _sees, grow
from orthomvp.engine.tiling import SMALL_TILE, auto_tile, mosaic_tile
from orthomvp.engine.view_index import ViewIndex
from orthomvp.io.preflight import count_text
from tests.conftest import SHARED_DATA

NGI = SHARED_DATA / "ngi-aerial"


class AllViews:
    """A stand-in for ViewIndex that offers every view to every tile (the brute force)."""

    def __init__(self, dem: object, to_dem: object, shape: object, views: list, margin: float):
        self.n = len(views)

    def views(self, window: tuple[int, int, int, int]) -> np.ndarray:
        return np.arange(self.n)


def scenes(tmp: Path, crater_dir: Path, city_dir: Path) -> dict[str, tuple]:
    """Scenes and the resolution of their grids: 16 ngi-aerial frames tiled 2 x 2 over their
    DEM (when the data is here), 16 synthetic aerial frames the same way, the crater (body
    frame, three views), the city (map frame)."""
    out = {}
    if (NGI / "dem.tif").is_file():
        (tmp / "ngi").mkdir()
        dem, views, _ = growing_scene(NGI, 16, tmp / "ngi")
        out["ngi-16"] = (dem, views, "30m")
    (tmp / "syn").mkdir()
    dem, views, _ = growing_scene(None, 16, tmp / "syn")
    out["synthetic-16"] = (dem, views, "30m")
    crater = [(crater_dir / f"{v}.tif", crater_dir / f"{v}.tsai") for v in ("oblique", "nadir")]
    out["crater"] = (crater_dir / "dem.tif", crater, None)
    city = [(city_dir / f"{v}.tif", city_dir / f"{v}.tsai") for v in ("ne", "se", "sw", "nw")]
    out["city"] = (city_dir / "dem.tif", city, None)
    return out


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory, crater_dir: Path, city_dir: Path) -> dict:
    tmp = tmp_path_factory.mktemp("index")
    return {
        name: (dem, views, plan_ortho(dem, views, res=res, progress=False, tile=64))
        for name, (dem, views, res) in scenes(tmp, crater_dir, city_dir).items()
    }


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ngi-16", "synthetic-16", "crater", "city"])
def test_index_never_misses_a_view_that_sees_a_window(planned: dict, name: str) -> None:
    """For random windows of 1 to 400 posts a side (and the whole grid): every view whose
    image_box meets its image (the brute-force planner's test) is among the index's views;
    on the growing sets the index leaves most views out."""
    if name not in planned:
        pytest.skip(f"real data not available: {NGI} is absent")
    _, _, plan = planned[name]
    to_dem = grid_to_dem(plan.grid, plan.dem)
    index = ViewIndex(plan.dem, to_dem, plan.grid.shape, plan.views, 0.5 + IMAGE_MARGIN)
    rows, cols = plan.grid.shape
    rng = np.random.default_rng(7)
    windows = [(0, rows, 0, cols)]
    for _ in range(150):
        h, w = (int(x) for x in rng.integers(1, 400, 2))
        r0, c0 = int(rng.integers(0, rows)), int(rng.integers(0, cols))
        windows.append((r0, min(r0 + h, rows), c0, min(c0 + w, cols)))
    offered, seeing = 0, 0
    for window in windows:
        got = set(index.views(window).tolist())
        for k, view in enumerate(plan.views):
            if _sees(image_box(plan.dem, to_dem, window, view.camera), view):
                assert k in got, (window, k)
                seeing += 1
        offered += len(got)
    assert seeing > 0
    if name.endswith("-16"):
        assert offered < 0.4 * len(windows) * len(plan.views)
        assert offered < 2 * seeing


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ngi-16", "synthetic-16", "crater", "city"])
def test_plans_with_the_index_are_the_brute_forces(
    planned: dict, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every tile's views, DEM window and image windows, and every view's reach and elevation,
    are those of the planner that tries every view in every tile (tiles of 64 posts, and of
    the default side)."""
    if name not in planned:
        pytest.skip(f"real data not available: {NGI} is absent")
    dem, views, indexed = planned[name]
    res = "30m" if name.endswith("-16") else None
    default = plan_ortho(dem, views, res=res, progress=False)
    monkeypatch.setattr(plan_module, "ViewIndex", AllViews)
    for plan, tile in ((indexed, 64), (default, default.tile)):
        brute = plan_ortho(dem, views, res=res, progress=False, tile=tile)
        assert plan.tiles == brute.tiles
        assert plan.reach == brute.reach and plan.elevation == brute.elevation


@pytest.mark.slow
def test_mosaic_tiles_shrink_with_the_views_of_a_tile_not_the_images(planned: dict) -> None:
    """The default side of a mosaic's tiles: mosaic_tile of the most views that the index
    finds in one tile, which on the growing set at 12 m is fewer than all 16 (so the tiles are
    larger than mosaic_tile(16) gives); a count is every view at every side, as before."""
    dem, views, _ = planned["synthetic-16"]
    plan = plan_ortho(dem, views, res="12m", progress=False)
    assert plan.tile > mosaic_tile(16, 3, plan.margin)
    to_dem = grid_to_dem(plan.grid, plan.dem)
    index = ViewIndex(plan.dem, to_dem, plan.grid.shape, plan.views, 0.5 + IMAGE_MARGIN)

    def most(side: int) -> int:
        grid = plan.grid
        return max(len(index.views(grow(w, plan.margin, grid.shape))) for w in grid.tiles(side))

    largest = mosaic_tile(most, 3, plan.margin)
    assert plan.tile == auto_tile(plan.grid.shape, largest=largest, smallest=SMALL_TILE)
    assert mosaic_tile(lambda side: 16, 3, 13) == mosaic_tile(16, 3, 13)


def test_huge_grids_are_refused_before_any_tile_is_planned(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A grid cut into more tiles than a plan holds (1 m posts on the 5 km crater in tiles of
    2 posts: millions), one beyond the free space of the output folder, and one finer than
    the images are refused (InputError, one line) before the views are indexed or any tile
    planned; a 20 m grid in one tile of 512 posts is planned."""
    import shutil

    from orthomvp.engine import grid_choice
    from orthomvp.errors import InputError

    dem = crater_dir / "dem.tif"
    views = [(crater_dir / f"{v}.tif", crater_dir / f"{v}.tsai") for v in ("oblique", "nadir")]

    def never(*args: object, **kwargs: object) -> None:
        raise AssertionError("planning started")

    with monkeypatch.context() as patch:
        patch.setattr(plan_module, "ViewIndex", never)
        patch.setattr(plan_module, "_jobs", never)
        with pytest.raises(InputError, match="tiles of 2 posts, more than the 250,000") as info:
            plan_ortho(dem, views, res="1m", tile=2, progress=False)
        cols, rows, count = re.search(
            r"of ([\d,]+) x ([\d,]+) posts would be (\S+) tiles", str(info.value)
        ).groups()
        cols, rows = int(cols.replace(",", "")), int(rows.replace(",", ""))
        assert rows > 4000 and count == count_text(math.ceil(rows / 2) * math.ceil(cols / 2))
        usage = shutil.disk_usage(tmp_path)
        patch.setattr(grid_choice.shutil, "disk_usage", lambda _: usage._replace(free=1000))
        with pytest.raises(InputError, match=f"free in {tmp_path}"):
            plan_ortho(dem, views, res="1m", output_dir=tmp_path, progress=False)
        with pytest.raises(InputError, match="posts per pixel"):
            plan_ortho(dem, views, res="1cm", progress=False)
    plan = plan_ortho(dem, views, res="20m", tile=512, progress=False)
    assert len(plan.tiles) == 1 and plan.tiles[0].views == (0, 1)
