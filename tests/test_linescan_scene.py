"""The line-scan crater (``orthomvp synth crater --sensor linescan``): an oblique USGS CSM line
scanner whose lines are each rendered from their own sensor position, scored against
visibility truth marched towards the sensor position at the time each post is imaged, and
against the analytic radiance; the tiled engine against the in-memory result."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.camera import read_camera
from orthomvp.camera.csm import LineScanCamera
from orthomvp.cli import main
from orthomvp.codes import Code
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.orthophoto import orthorectify
from orthomvp.synthetic import (
    Scene,
    away_from_boundaries,
    classification_scores,
    load_scene,
    make_scene,
)


@pytest.fixture(scope="module")
def made() -> Scene:
    return make_scene("crater", size=64, spacing=80.0, sensor="linescan")


@pytest.fixture(scope="module")
def scene_dir(made: Scene, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("linescan-crater")
    made.write(out, supersample=2)
    return out


@pytest.fixture(scope="module")
def scene(scene_dir: Path):
    return load_scene(scene_dir)


def test_scene_is_a_line_scanner_that_hides_terrain(scene_dir: Path, scene) -> None:
    """The camera file is an ISD read back as a line scanner whose sensor moves between the
    first and last lines; its truth has occluded posts behind the rim and the peak."""
    camera = read_camera(scene_dir / "linescan.json")
    assert isinstance(camera, LineScanCamera)
    view = scene.views["linescan"]
    assert scene.summary["sensor"] == "linescan"
    assert (view.camera.width, view.camera.height) == (camera.samples, camera.lines)
    first, last = camera.origins(np.array([[0.0, 0.0], [0.0, camera.lines - 1.0]]))
    assert np.linalg.norm(last - first) > 1000.0  # metres flown during the image
    counts = np.bincount(view.truth.ravel(), minlength=4)
    assert counts[Code.NODATA] == 0  # the image holds the whole DEM
    assert counts[Code.OCCLUDED] > 0.03 * view.truth.size


def test_truth_is_marched_towards_each_posts_line(made, scene) -> None:
    """The written truth marches each post towards the sensor position at the time of its
    line: marching towards the position at the image centre's line instead changes codes."""
    view = scene.views["linescan"]
    written = made.visibility_truth(made.cameras["linescan"])
    np.testing.assert_array_equal(written, view.truth)
    centre = view.camera.origins(np.array([view.camera.width / 2, view.camera.height / 2]))
    one_centre = made.visibility_truth(_FixedOrigin(view.camera, centre))
    # the sensor flies about 5 km during the image, 190 km from the tile: 5 posts change here
    assert (one_centre != view.truth).sum() >= 3


@dataclass(frozen=True)
class _FixedOrigin:
    """A line scanner whose every pixel is taken as seen from one ``origin`` (a pinhole's
    assumption), through the Camera protocol."""

    camera: LineScanCamera
    origin: np.ndarray

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.camera.project(xyz)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        return self.camera.in_image(uv)

    def origins(self, uv: np.ndarray) -> np.ndarray:
        finite = np.isfinite(uv).all(axis=-1)[..., None]
        return np.where(finite, np.broadcast_to(self.origin, uv.shape[:-1] + (3,)), np.nan)


def test_visibility_f1_against_marched_truth(scene) -> None:
    view = scene.views["linescan"]
    vis = compute_visibility(scene.terrain, view.camera)
    keep = away_from_boundaries(view.truth)
    scores = classification_scores(vis.codes, view.truth, keep)
    assert scores["f1_visible"] >= 0.99, scores
    assert scores["f1_hidden"] >= 0.95, scores


def test_orthophoto_has_no_ghosts_and_matches_radiance(scene) -> None:
    view = scene.views["linescan"]
    ortho = orthorectify(scene.terrain, view.image, view.camera)
    keep = away_from_boundaries(view.truth)
    hidden = (view.truth == Code.OCCLUDED) & keep
    ghosts = int((np.isfinite(ortho.data[0]) & hidden).sum())
    assert hidden.sum() > 50
    assert ghosts == 0, f"{ghosts} ghosts among {hidden.sum()} hidden posts"
    naive = orthorectify(scene.terrain, view.image, view.camera, occlusion=False)
    assert np.isfinite(naive.data[0][hidden]).all()  # what a naive orthophoto paints there
    visible = np.isfinite(ortho.data[0]) & keep
    corr = np.corrcoef(ortho.data[0][visible], scene.radiance[visible])[0, 1]
    assert corr >= 0.98, f"orthophoto vs true radiance: r = {corr:.4f}"


def test_tiled_engine_equals_in_memory(scene_dir: Path, scene, tmp_path: Path) -> None:
    """Tiles of 12 posts, whose DEM windows reach beyond them by the occluder halo, give the
    in-memory codes and orthophoto, with the camera read from the ISD by path."""
    dem, image, isd = scene_dir / "dem.tif", scene_dir / "linescan.tif", scene_dir / "linescan.json"
    plan = plan_ortho(dem, [(image, isd)], tile=12, grid="dem")
    grown = [
        job for job in plan.tiles if job.dem is not None and _size(job.dem) > _size(job.window)
    ]
    assert grown, "the halo reaches beyond the tiles"
    outputs = Outputs(ortho=tmp_path / "o.tif", visibility=tmp_path / "v.tif")
    run_plan(plan, outputs, progress=False)
    view = scene.views["linescan"]
    with rasterio.open(tmp_path / "v.tif") as src:
        codes = src.read(1)
    with rasterio.open(tmp_path / "o.tif") as src:
        ortho = src.read()
    np.testing.assert_array_equal(codes, compute_visibility(scene.terrain, view.camera).codes)
    expected = orthorectify(scene.terrain, view.image, view.camera).data
    np.testing.assert_allclose(ortho, expected, rtol=1e-6, equal_nan=True)


def _size(window: tuple[int, int, int, int]) -> int:
    r0, r1, c0, c1 = window
    return (r1 - r0) * (c1 - c0)


def test_command_line_on_the_scene(scene_dir: Path, scene, tmp_path: Path) -> None:
    """``orthomvp visibility`` and ``ortho`` take the scene's ISD as the frame scenes' .tsai."""
    files = [str(scene_dir / n) for n in ("dem.tif", "linescan.tif", "linescan.json")]
    dem_grid = ["--grid", "dem"]
    assert main(["visibility", *files, "-o", tmp_path / "v.tif", *dem_grid]) == 0
    assert main(["ortho", *files, "-o", tmp_path / "o.tif", *dem_grid]) == 0
    assert np.isfinite(rasterio.open(tmp_path / "o.tif").read(1)).mean() > 0.8
    truth = scene.views["linescan"].truth
    with rasterio.open(tmp_path / "v.tif") as src:
        codes = src.read(1)
    keep = away_from_boundaries(truth)
    assert classification_scores(codes, truth, keep)["f1_visible"] >= 0.99


def test_info_gives_the_time_range_of_the_lines_that_see_the_dem(scene_dir: Path) -> None:
    """``describe``'s time range is that of the first and last lines into which the camera
    projects a DEM post (usgscsm's getImageTime of those lines), its GSD the camera's own."""
    from orthomvp.engine.grid_choice import read_source
    from orthomvp.engine.images import image_source
    from orthomvp.engine.info import describe
    from orthomvp.geometry.terrain import Terrain

    dem, image, isd = (scene_dir / n for n in ("dem.tif", "linescan.tif", "linescan.json"))
    feature = describe(dem, image, isd)
    props = feature["properties"]["image"]
    assert props["camera"] == "LineScanCamera"
    source, views = read_source(dem, [image_source(image, isd)], None, False, "auto", False)
    camera = views[0].camera
    uv, _ = camera.project(Terrain.read(dem, world=source.world).world_points())
    rows = uv[..., 1][np.isfinite(uv).all(axis=-1) & camera.in_image(uv)]
    t = camera.image_time(np.array([rows.min(), rows.max()]) + 0.5)
    assert props["time_s"] == pytest.approx(list(t), abs=1e-9)
    assert t[1] - t[0] > 0.5 * (camera.image_time(camera.lines) - camera.image_time(0.0))


def test_messages_count_cameras_not_a_line_scanners_positions(scene_dir: Path) -> None:
    """Found by a new user's audit: a line scanner gives several sensor positions, and the
    camera after it was named by its position's number ("camera 4" of two)."""
    from dataclasses import replace

    from orthomvp.camera import PinholeCamera, camera_centres
    from orthomvp.errors import GeometryError
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.geometry.world import check_cameras_above

    line = read_camera(scene_dir / "linescan.json")  # (an ISD: the image's size with it)
    assert line.width is not None and line.height is not None
    centres, views = camera_centres([line, line])
    assert len(centres) > 2 and views.tolist() == sorted(views.tolist())
    assert set(views.tolist()) == {0, 1}
    terrain = Terrain.read(scene_dir / "dem.tif")
    far = PinholeCamera(1000.0, 1000.0, 500.0, 500.0, -centres[0], np.eye(3))  # (the far side)
    with pytest.raises(GeometryError, match=r"camera 2 is beyond the DEM's horizon"):
        check_cameras_above(terrain, *camera_centres([line, far]))
    with pytest.raises(GeometryError, match=r"camera 3 is beyond"):
        check_cameras_above(terrain, *camera_centres([line, replace(line), far]))
