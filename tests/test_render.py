"""Offscreen snapshots (orthomvp.present.snapshot) and the ``orthomvp render`` command, without a
display."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from PIL import Image

from orthomvp.cli import main
from orthomvp.codes import Code, View
from orthomvp.errors import InputError
from orthomvp.present.snapshot import (
    CROP_MARGIN,
    SnapshotOptions,
    background_image,
    snapshot,
)
from orthomvp.synthetic import Scene, make_scene
from tests.conftest import shared

SIZE = (320, 240)


@pytest.fixture(autouse=True)
def no_display(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test renders with no display at all."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


@pytest.fixture(scope="module")
def crater() -> Scene:
    return make_scene("crater", size=64, spacing=80.0)


def render(terrain, options: dict | None = None, **rasters) -> np.ndarray:  # noqa: ANN001
    """The image of a snapshot of ``SIZE`` (unless ``options`` say otherwise), plotter closed."""
    snap = snapshot(
        terrain, **rasters, options=SnapshotOptions(**{"size": SIZE, **(options or {})})
    )
    snap.close()
    return snap.image


def green(image: np.ndarray) -> np.ndarray:
    """Pixels of the occlusion green (shaded), a mask."""
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (g >= 60) & (g > 2 * r + 20) & (g > 2 * b + 20)


def red(image: np.ndarray) -> np.ndarray:
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (r > b + 60) & (r > g + 40)


def blue(image: np.ndarray) -> np.ndarray:
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (b > r + 60) & (b > g + 20)


def test_relief_snapshot_is_not_blank(crater: Scene, tmp_path: Path) -> None:
    snap = snapshot(crater.terrain, options=SnapshotOptions(size=SIZE))
    try:
        image = snap.image
        assert image.shape == (240, 320, 3) and image.dtype == np.uint8
        assert image.std() > 20
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 500
        snap.save(tmp_path / "relief.png")
        assert np.array_equal(np.asarray(Image.open(tmp_path / "relief.png")), image)
        # the plotter stays usable: add to the scene (local frame) and render again
        snap.plotter.add_points(np.zeros((1, 3)), color="red", point_size=30)
        again = snap.plotter.screenshot(return_img=True)
        assert red(again).sum() > red(image).sum()
    finally:
        snap.close()


@pytest.mark.parametrize("view", ["oblique", "top"])
def test_visibility_snapshot_shows_occluded_posts_green(crater: Scene, view: str) -> None:
    camera = crater.cameras["oblique"]
    vis = crater.visibility_truth(camera)
    assert (vis == Code.OCCLUDED).mean() > 0.03
    options = {"view": view, "legend": False}
    image = render(crater.terrain, options, visibility=vis, cameras=[camera])
    assert green(image).mean() > 0.005
    # the same scene with every post visible has no green at all
    everywhere = np.ones_like(vis)
    image = render(crater.terrain, options, visibility=everywhere, cameras=[camera])
    assert not green(image).any()


def test_no_green_where_the_scene_has_no_occlusion(crater: Scene) -> None:
    camera = crater.cameras["nadir"]
    vis = crater.visibility_truth(camera)
    assert not (vis == Code.OCCLUDED).any()
    options = SnapshotOptions(rays=8, size=SIZE)
    snap = snapshot(crater.terrain, visibility=vis, cameras=[camera], options=options)
    try:
        assert snap.plotter.legend is not None
        snap.plotter.remove_legend()  # the legend has a green swatch
        image = snap.plotter.screenshot(return_img=True)
        assert not green(image).any()
        assert image.std() > 20
    finally:
        snap.close()


def test_height_error_uses_both_ends_of_a_symmetric_colour_map(crater: Scene) -> None:
    x, y = crater.post_local()
    truth = crater.terrain.values
    wave = 20 * np.sin(x / 600) * np.cos(y / 500)
    quiet = {"legend": False}
    image = render(crater.terrain, quiet, heights=truth + wave, truth=truth)
    assert red(image).mean() > 0.02 and blue(image).mean() > 0.02
    # positive errors only: red, and no blue, since the limits stay symmetric about 0
    image = render(crater.terrain, quiet, heights=truth + np.abs(wave), truth=truth)
    assert red(image).mean() > 0.02 and not blue(image).any()
    options = SnapshotOptions(size=SIZE)
    snap = snapshot(crater.terrain, heights=truth + wave, truth=truth, options=options)
    try:
        assert list(snap.plotter.scalar_bars.keys()) == ["height error (m)"]
    finally:
        snap.close()


def test_draped_orthophoto(crater: Scene) -> None:
    x, y = crater.post_local()
    ortho = crater.surface.radiance(x, y).astype(np.float32)
    ortho[:, :20] = np.nan
    image = render(crater.terrain, ortho=np.stack([ortho, ortho * 0.5, ortho * 0.8]))
    assert image.std() > 20 and len(np.unique(image.reshape(-1, 3), axis=0)) > 1000


def test_from_camera_view_matches_the_camera(crater: Scene) -> None:
    camera = crater.cameras["oblique"]
    width, height = 3 * camera.width, 3 * camera.height
    options = SnapshotOptions(view="from-camera", size=(width, height), rays=4)
    snap = snapshot(crater.terrain, cameras=[camera], options=options)
    try:
        assert snap.image.shape == (height, width, 3) and snap.image.std() > 20
        pts = crater.terrain.world_points().reshape(-1, 3)[::37]
        uv, _ = camera.project(pts)
        renderer = snap.plotter.renderer
        display = []
        for p in pts - snap.origin:
            renderer.SetWorldPoint(*p, 1.0)
            renderer.WorldToDisplay()
            display.append(renderer.GetDisplayPoint()[:2])
        # display x from the left, y from the bottom; pixel edges at -0.5
        expected = np.column_stack([3 * (uv[:, 0] + 0.5), height - 3 * (uv[:, 1] + 0.5)])
        np.testing.assert_allclose(display, expected, atol=0.01)
    finally:
        snap.close()


@pytest.mark.realdata
def test_from_camera_view_through_an_isis_frame_cube(tmp_path: Path) -> None:
    """The audit's case: an ISIS frame cube (a CSM frame camera: Apollo 15 Metric over Hadley)
    is a frame camera, and the from-camera view looks through it: every post it sees lands
    where the camera's own projection puts it (lens model included) within 0.5 px; the
    command line renders it too."""
    from orthomvp.camera import read_camera
    from orthomvp.camera.csm import CsmFrameCamera
    from orthomvp.geometry.terrain import Terrain

    dem = shared("as15-hadley", "LOLA_hadley_dem.tif")
    cube = shared("as15-hadley", "AS15-M-1134-hadley.cub")
    camera, terrain = read_camera(cube), Terrain.read(dem)
    assert isinstance(camera, CsmFrameCamera)
    width, height = camera.width, camera.height
    options = SnapshotOptions(view="from-camera", size=(width, height))
    snap = snapshot(terrain, cameras=[camera], options=options)
    try:
        assert snap.image.std() > 20
        pts = terrain.world_points().reshape(-1, 3)[::37]
        uv, _ = camera.project(pts)
        inside = np.isfinite(uv).all(axis=1) & (uv >= 0).all(axis=1)
        inside &= (uv[:, 0] < width) & (uv[:, 1] < height)
        assert inside.sum() > 500
        renderer = snap.plotter.renderer
        display = []
        for p in pts[inside] - snap.origin:
            renderer.SetWorldPoint(*p, 1.0)
            renderer.WorldToDisplay()
            display.append(renderer.GetDisplayPoint()[:2])
        expected = np.column_stack([uv[inside, 0] + 0.5, height - (uv[inside, 1] + 0.5)])
        np.testing.assert_allclose(display, expected, atol=0.5)
    finally:
        snap.close()
    out = tmp_path / "through.png"
    argv = ["-q", "render", str(dem), "--camera", str(cube), "--view", "from-camera"]
    assert main([*argv, "--size", "200", "200", "-o", str(out)]) == 0
    assert out.stat().st_size > 1000
    # without --size: the image's own aspect, 1024 px on the long side (it was an internal
    # error, found in review: the size came from a pinhole camera's focal lengths)
    assert main([*argv, "-o", str(tmp_path / "sized.png")]) == 0
    rows, cols = plt_image(tmp_path / "sized.png").shape[:2]
    assert max(rows, cols) == 1024 and abs(cols / rows - width / height) < 2e-3


def plt_image(path: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(path)


@pytest.mark.realdata
def test_from_camera_view_refuses_a_mirrored_csm_frame(tmp_path: Path) -> None:
    """usgscsm's orbital framer images the ground mirrored against its boresight (lines run
    against boresight x samples): no view through a lens shows that, and the view is refused
    in one InputError (it was an image 1.5e10 px off, VTK's field of view clamped)."""
    import rasterio
    from affine import Affine

    from orthomvp.camera import read_camera
    from orthomvp.geometry.terrain import Terrain

    n, step = 64, 0.12 / 64
    y, x = np.mgrid[0:n, 0:n]
    heights = (200 * np.exp(-((x - 40) ** 2 + (y - 20) ** 2) / 60.0)).astype("float32")
    profile = dict(driver="GTiff", width=n, height=n, count=1, dtype="float32")
    profile |= {"crs": "+proj=longlat +R=1000000 +no_defs"}
    profile["transform"] = Affine(step, 0, -0.06, 0, -step, 0.06)
    with rasterio.open(tmp_path / "dem.tif", "w", **profile) as ds:
        ds.write(heights, 1)
    camera = read_camera(shared("csm", "orbitalFramer.json"))
    terrain = Terrain.read(tmp_path / "dem.tif")
    with pytest.raises(InputError, match="its image is mirrored"):
        snapshot(terrain, cameras=[camera], options=SnapshotOptions(view="from-camera"))


def test_vertical_exaggeration_scales_relief(crater: Scene) -> None:
    up = crater.terrain.up_vectors(crater.terrain.world_points()[32, 32])
    ranges = []
    for k in (1.0, 3.0):
        snap = snapshot(crater.terrain, options=SnapshotOptions(exaggerate=k, size=SIZE))
        heights = np.asarray(snap.plotter.meshes[0].points) @ up
        ranges.append(np.ptp(heights))
        snap.close()
    assert ranges[1] / ranges[0] == pytest.approx(3.0, rel=0.01)


def test_bad_inputs_raise_input_errors(crater: Scene) -> None:
    t = crater.terrain
    vis = np.ones(t.shape, np.uint8)
    nadir = [crater.cameras["nadir"]]
    cases = [  # (rasters and cameras, options, words in the message)
        ({"visibility": vis[:-1]}, {}, "DEM grid"),
        ({"ortho": np.ones((2, *t.shape))}, {}, "2"),
        ({"visibility": vis * 7}, {}, "codes"),
        ({"visibility": np.stack([vis, vis])}, {}, "one band"),
        ({"visibility": vis, "ortho": vis}, {}, "not several"),
        ({"heights": t.values}, {}, "truth"),
        ({}, {"view": "sideways"}, "unknown view"),
        ({}, {"view": "from-camera"}, "camera"),
        ({"cameras": nadir}, {"view": "from-camera", "view_camera": 1}, "camera 2 .counted from 1"),
        ({}, {"exaggerate": 0.0}, "exaggeration"),
        ({}, {"size": (4, 4)}, "size"),
        ({}, {"rays": -1}, "rays"),
        ({}, {"elevation": 0.0}, "elevation"),
        ({}, {"error_limit": 0.0}, "limit"),
    ]
    for rasters, options, words in cases:
        with pytest.raises(InputError, match=words):
            snapshot(t, **rasters, options=SnapshotOptions(**options))


def test_crop_cuts_only_empty_background(crater: Scene) -> None:
    """A cropped snapshot is the uncropped one inside its box, and outside the box the
    uncropped one shows nothing but the background."""
    full = snapshot(crater.terrain, options=SnapshotOptions(size=SIZE))
    cut = snapshot(crater.terrain, options=SnapshotOptions(size=SIZE, crop=True))
    full.close()
    cut.close()
    left, top, right, bottom = cut.box
    assert full.box == (0, 0, *SIZE) and cut.image.shape == (bottom - top, right - left, 3)
    assert cut.image.size < 0.8 * full.image.size  # the empty margins are gone
    np.testing.assert_array_equal(cut.image, full.image[top:bottom, left:right])
    background = background_image(*SIZE)
    outside = np.ones(SIZE[::-1], bool)
    outside[top:bottom, left:right] = False
    drawn = np.abs(full.image.astype(int) - background.astype(int)).max(axis=-1) > 2
    assert not drawn[outside].any()
    # the box is tight: the scene comes to within the margin of each side (or to the edge)
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    assert (top, left) == (max(rows[0] - CROP_MARGIN, 0), max(cols[0] - CROP_MARGIN, 0))
    assert (bottom, right) == (
        min(rows[-1] + 1 + CROP_MARGIN, SIZE[1]),
        min(cols[-1] + 1 + CROP_MARGIN, SIZE[0]),
    )


def test_options_take_view_names_and_check_themselves() -> None:
    options = SnapshotOptions(view="top", size=[640.0, 480.0])
    assert options.view is View.TOP and options.size == (640, 480)
    assert SnapshotOptions(view=View.FROM_CAMERA).view == "from-camera"
    with pytest.raises(InputError, match="oblique, top, from-camera"):
        SnapshotOptions(view="side")


def test_cli_renders_end_to_end(crater_dir: Path, tmp_path: Path, capsys) -> None:  # noqa: ANN001
    d = crater_dir
    out = tmp_path / "vis.png"
    argv = ["render", str(d / "dem.tif"), "--visibility", str(d / "oblique.visibility.tif")]
    argv += ["--camera", str(d / "oblique.tsai"), str(d / "nadir.tsai"), "--rays", "5"]
    argv += ["-o", str(out), "--size", "320", "240", "--exaggerate", "2"]
    assert main(argv) == 0
    image = np.asarray(Image.open(out))
    assert image.shape == (240, 320, 3) and green(image).any()
    assert "wrote" in capsys.readouterr().out
    out = tmp_path / "cam.png"
    argv = ["render", str(d / "dem.tif"), "--ortho", str(d / "truth_radiance.tif")]
    argv += ["--camera", str(d / "oblique.tsai"), "--camera", str(d / "nadir.tsai")]
    argv += ["--view", "from-camera", "--camera-index", "2", "-o", str(out)]
    assert main([*argv, "--size", "200", "200"]) == 0
    assert np.asarray(Image.open(out)).shape == (200, 200, 3)


def test_cli_bad_inputs_exit_2_without_output(
    crater_dir: Path,
    tmp_path: Path,
    capsys,  # noqa: ANN001
) -> None:
    d = crater_dir
    dem, out = str(d / "dem.tif"), tmp_path / "snap.png"
    small = tmp_path / "small.tif"  # no georeference, not the DEM's size: cannot be placed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(
            small, "w", driver="GTiff", width=12, height=10, count=1, dtype="float32"
        ) as dst:
            dst.write(np.ones((1, 10, 12), np.float32))
    cases = [
        ["--visibility", str(small)],  # a raster off the DEM grid, without a georeference
        ["--ortho", str(tmp_path / "missing.tif")],
        ["--heights", dem],  # no --truth
        ["--camera", str(d / "nadir.tsai"), "--view", "from-camera", "--camera-index", "2"],
        ["--exaggerate", "-1"],
        ["--error-limit", "5"],  # no height error to colour (found by an audit: ignored)
        ["--rays", "4"],  # no camera to draw rays from
    ]
    for extra in cases:
        assert main(["render", dem, "-o", str(out), "--size", "64", "48", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith("orthomvp: error:") and err.count("\n") == 1, err
        assert not out.exists()
    assert not list(tmp_path.glob(".snap.png*"))  # no temporary file left behind


def _grid(d: Path) -> tuple:
    """Transform and CRS of the scene's DEM."""
    from orthomvp.geometry.terrain import Terrain

    t = Terrain.read(d / "dem.tif")
    return t.transform, t.crs


def test_scale_bar_exaggeration_and_camera_labels(crater: Scene) -> None:
    """The scale bar is as long as its label says (exact float64), the vertical exaggeration is
    written under it, and the camera labels (two cameras whose glyphs stand close together)
    lie inside the window without overlapping each other or the scale bar's labels, as VTK
    itself measures the rendered texts."""
    import pyvista as pv

    cams = [crater.cameras["oblique"], crater.cameras["nadir"]]
    width, height = 480, 360
    options = SnapshotOptions(size=(width, height), exaggerate=1.5, legend=True)
    snap = snapshot(crater.terrain, cameras=cams, options=options)
    try:
        actors = snap.plotter.actors
        texts = {name: a for name, a in actors.items() if isinstance(a, pv.Text)}
        assert {"camera label 1", "camera label 2", "scale bar label 0", "scale bar label 1"} <= (
            texts.keys()
        )
        length_text = texts["scale bar label 0"].input
        value, unit = re.fullmatch(r"(\d+) (m|km)", length_text).groups()
        length = float(value) * (1000 if unit == "km" else 1)
        assert texts["scale bar label 1"].input == "vertical exaggeration 1.5x"
        points = np.asarray(actors["scale bar"].mapper.dataset.points, np.float64)
        # float32 points in the local frame: metres to within their resolution
        assert np.linalg.norm(points[1] - points[0]) == pytest.approx(length, rel=1e-6)
        assert length <= 0.25 * crater.terrain.post_spacing()[0] * 63 * 1.0001
        boxes = {}
        for name, actor in texts.items():
            bbox = [0.0] * 4
            actor.GetBoundingBox(snap.plotter.renderer, bbox)  # about the text's position
            px, py = actor.GetPosition()
            x0, x1, y0, y1 = bbox[0] + px, bbox[1] + px, bbox[2] + py, bbox[3] + py
            boxes[name] = x0, x1, y0, y1  # display pixels
            assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height, (name, bbox)
        names = sorted(boxes)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                p, q = boxes[a], boxes[b]
                apart = p[1] <= q[0] or q[1] <= p[0] or p[3] <= q[2] or q[3] <= p[2]
                assert apart, (a, p, b, q)
    finally:
        snap.close()
    flat = SnapshotOptions(size=(width, height), legend=True)
    snap = snapshot(crater.terrain, options=flat)
    try:
        assert snap.plotter.actors["scale bar label 1"].input == "no vertical exaggeration"
    finally:
        snap.close()
    snap = snapshot(crater.terrain, options=SnapshotOptions(size=(width, height), legend=False))
    try:
        assert "scale bar" not in snap.plotter.actors
    finally:
        snap.close()
