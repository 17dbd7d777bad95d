"""Cameras other than the pinhole go through the generic Camera path of visibility, the
engine's halo and image boxes, and truth marching: per-post ray origins, the model's own
rays, NaN for what a camera does not image.

The oracle is the pinhole's own fast path. A :class:`Generic` camera is a pinhole seen only
through the Camera protocol (its origins NaN where a pixel is NaN, as a line scanner's are);
a :class:`Strip` camera images only the posts whose rows fall within a band of the image (a
line scanner's time range) and gives NaN, not an extrapolated pixel, for the others.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.camera import Camera, PinholeCamera, load_view, sensor_positions
from orthomvp.codes import Code
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.orthophoto import orthorectify
from orthomvp.synthetic.truth import visibility_truth


@dataclass(frozen=True)
class Generic:
    """A pinhole behind the Camera protocol; rows outside ``rows`` (first, last) are not
    imaged: NaN pixels and depths, as a line scanner beyond its time range."""

    pinhole: PinholeCamera
    rows: tuple[float, float] = (-np.inf, np.inf)

    @property
    def width(self) -> int | None:
        return self.pinhole.width

    @property
    def height(self) -> int | None:
        return self.pinhole.height

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, depth = self.pinhole.project(xyz)
        off = ~((uv[..., 1] >= self.rows[0]) & (uv[..., 1] <= self.rows[1]))
        return np.where(off[..., None], np.nan, uv), np.where(off, np.nan, depth)

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.pinhole.ray(uv)

    def origins(self, uv: np.ndarray) -> np.ndarray:
        o = self.pinhole.origins(uv)
        return np.where(np.isfinite(uv).all(axis=-1)[..., None], o, np.nan)

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        return self.pinhole.gsd(xyz)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        return self.pinhole.in_image(uv)

    def with_image_size(self, width: int | None, height: int | None) -> Generic:
        return replace(self, pinhole=self.pinhole.with_image_size(width, height))

    def crop(self, c0: int, r0: int, width: int, height: int) -> Generic:
        rows = (self.rows[0] - r0, self.rows[1] - r0)
        return Generic(self.pinhole.crop(c0, r0, width, height), rows)


@pytest.fixture(scope="module")
def oblique(crater_dir: Path) -> tuple[Terrain, np.ndarray, PinholeCamera]:
    image, camera = load_view(crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    return Terrain.read(crater_dir / "dem.tif"), image, camera


def test_generic_cameras_follow_the_protocol(oblique: tuple) -> None:
    _, _, camera = oblique
    generic = Generic(camera)
    assert isinstance(generic, Camera) and not isinstance(generic, PinholeCamera)
    np.testing.assert_array_equal(sensor_positions(generic), camera.center[None])


def test_visibility_through_the_protocol_equals_the_pinhole_path(oblique: tuple) -> None:
    terrain, image, camera = oblique
    a = compute_visibility(terrain, camera)
    b = compute_visibility(terrain, Generic(camera))
    assert np.isin(a.codes, (Code.OCCLUDED,)).sum() > 50  # the rim hides terrain
    np.testing.assert_array_equal(a.codes, b.codes)
    np.testing.assert_allclose(b.uv, a.uv, equal_nan=True)
    np.testing.assert_allclose(b.gsd, a.gsd, equal_nan=True)
    np.testing.assert_allclose(b.miss, a.miss, rtol=1e-9, atol=1e-9, equal_nan=True)
    ortho_a = orthorectify(terrain, image, camera)
    ortho_b = orthorectify(terrain, image, Generic(camera))
    np.testing.assert_array_equal(ortho_a.data, ortho_b.data)


def test_posts_a_camera_does_not_image_are_nodata(oblique: tuple) -> None:
    """Rows of the image beyond a strip camera's range: the posts there are NODATA (never an
    extrapolated pixel); elsewhere the codes are the pinhole's, and truth marching through
    the protocol gives the pinhole's truth on the imaged posts."""
    terrain, _, camera = oblique
    strip = Generic(camera, rows=(40.0, 80.0))
    a = compute_visibility(terrain, camera)
    b = compute_visibility(terrain, strip)
    on = (a.uv[..., 1] >= 40.0) & (a.uv[..., 1] <= 80.0)
    assert on.sum() > 500 and (~on & (a.codes != Code.NODATA)).sum() > 500
    np.testing.assert_array_equal(b.codes[on], a.codes[on])
    assert (b.codes[~on] == Code.NODATA).all() and np.isnan(b.uv[~on]).all()
    c, r = terrain.grid()
    points = terrain.to_world(c, r, terrain.values)
    normals = terrain.normals()
    below = _below(terrain)
    spacing = float(np.mean(terrain.post_spacing()))
    radius = float(np.linalg.norm(points, axis=-1).max()) + 1.0
    t_pin = visibility_truth(camera, points, normals, below, radius, spacing / 4)
    t_strip = visibility_truth(strip, points, normals, below, radius, spacing / 4)
    np.testing.assert_array_equal(t_strip[on], t_pin[on])
    assert (t_strip[~on] == Code.NODATA).all()


def _below(terrain: Terrain):  # noqa: ANN202
    """Whether world points lie below the DEM's bilinear surface (the scene's own DEM stands
    in for its analytic surface: both cameras are marched against the same one)."""

    def below(xyz: np.ndarray) -> np.ndarray:
        c, r, h = terrain.from_world(xyz)
        under = terrain.interpolate(c, r)
        return np.isfinite(under) & (h < under)

    return below


def test_engine_plans_and_runs_generic_cameras(
    crater_dir: Path, oblique: tuple, tmp_path: Path
) -> None:
    """Tiled through the engine (tiles small enough that the halo matters), a generic strip
    camera gives the in-memory codes and orthophoto; tiles beyond the strip read no image."""
    terrain, image, camera = oblique
    strip = Generic(camera, rows=(40.0, 80.0))
    plan = plan_ortho(
        crater_dir / "dem.tif", [(crater_dir / "oblique.tif", strip)], tile=16, grid="dem"
    )
    outputs = Outputs(ortho=tmp_path / "o.tif", visibility=tmp_path / "v.tif")
    run_plan(plan, outputs, progress=False)
    with rasterio.open(tmp_path / "v.tif") as src:
        codes = src.read(1)
    with rasterio.open(tmp_path / "o.tif") as src:
        ortho = src.read()
    vis = compute_visibility(terrain, strip)
    np.testing.assert_array_equal(codes, vis.codes)
    expected = orthorectify(terrain, read_image(crater_dir / "oblique.tif"), strip).data
    np.testing.assert_allclose(ortho, expected, rtol=1e-6, equal_nan=True)
    unseen = [job for job in plan.tiles if not job.views]
    assert unseen, "some tiles lie beyond the strip"


def test_snapshots_draw_any_camera_and_look_through_frame_cameras_only(
    oblique: tuple, tmp_path: Path
) -> None:
    """A camera without one centre is drawn from its own rays: the glyph's corners lie on its
    corner rays and the snapshot shows it (its pixels differ from the bare DEM's); the
    from-camera view needs one centre: one clear error."""
    from orthomvp.codes import View
    from orthomvp.errors import InputError
    from orthomvp.present.snapshot import SnapshotOptions, snapshot
    from orthomvp.present.viewpoint import camera_glyph

    terrain, _, camera = oblique
    generic = Generic(camera)
    rect = (-0.5, -0.5, camera.width - 0.5, camera.height - 0.5)
    origin = np.zeros(3)
    far = 1e9  # a radius that keeps the glyph at the camera, unwidened
    glyph = camera_glyph(generic, rect, origin, camera.center + 1.0, far)
    apex = glyph.points[0]
    np.testing.assert_allclose(apex, camera.center, atol=1e-6)
    centre_uv = np.array([(camera.width - 1) / 2, (camera.height - 1) / 2])
    axis = camera.ray(centre_uv)[1]
    np.testing.assert_allclose(np.cross(glyph.points[5] - apex, axis), 0, atol=1e-6)
    for k, (u, v) in enumerate([(0, 0), (camera.width - 1, 0)], start=1):
        _, d = camera.ray(np.array([u, v], float))
        along = glyph.points[k] - apex
        # widened about the axis: the corner's offset from the axis keeps the ray's direction
        t_glyph = along / (along @ axis) - axis
        t_ray = d / (d @ axis) - axis
        np.testing.assert_allclose(np.cross(t_glyph, t_ray), 0, atol=1e-9)
        assert t_glyph @ t_ray > 0
    opts = SnapshotOptions(size=(320, 240), rays=20)
    bare = snapshot(terrain, options=opts)
    drawn = snapshot(terrain, cameras=[generic], options=opts)
    try:
        assert (bare.image != drawn.image).any(axis=-1).mean() > 0.01
    finally:
        bare.close()
        drawn.close()
    with pytest.raises(InputError, match="camera 1: the from-camera view needs a frame camera"):
        snapshot(terrain, cameras=[generic], options=SnapshotOptions(view=View.FROM_CAMERA))
