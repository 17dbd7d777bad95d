"""Synthetic scenes: the truth they carry is checked by independent means."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from affine import Affine
from scipy.ndimage import binary_erosion, map_coordinates

from orthomvp.camera import read_camera
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.synthetic import make_scene


def interior(mask: np.ndarray, width: int = 2) -> np.ndarray:
    """Posts farther than ``width`` posts from the boundary of ``mask`` (both sides)."""
    s = np.ones((2 * width + 1, 2 * width + 1), bool)
    return binary_erosion(mask, s, border_value=1) | binary_erosion(~mask, s, border_value=1)


def test_scene_directory(crater_dir) -> None:
    summary = json.loads((crater_dir / "scene.json").read_text())
    assert summary["kind"] == "crater" and set(summary["views"]) == {
        "oblique",
        "nadir",
        "fore",
        "aft",
    }
    dem = Terrain.read(crater_dir / summary["dem"])
    assert dem.shape == (64, 64) and dem.radii[0] == 1737400.0
    assert np.mean(dem.post_spacing()) == pytest.approx(80.0, rel=1e-3)
    for view in summary["views"].values():
        cam = read_camera(crater_dir / view["camera"])
        image = read_image(crater_dir / view["image"])
        vis = read_image(crater_dir / view["visibility"])[0]
        assert image.shape[0] == 1 and np.isfinite(image).all() and image.std() > 0.05
        assert vis.shape == dem.shape
        counts = view["visibility_counts"]
        assert counts == {code.label: int((vis == code).sum()) for code in Code}
        assert sum(counts.values()) == vis.size
        # every post is inside each image, and all project inside the image bounds
        uv, depth = cam.project(dem.world_points())
        assert (depth > 0).all()
        assert uv[..., 0].min() > 0 and uv[..., 0].max() < image.shape[2] - 1
        assert uv[..., 1].min() > 0 and uv[..., 1].max() < image.shape[1] - 1
    oblique = read_image(crater_dir / "oblique.visibility.tif")[0]
    nadir = read_image(crater_dir / "nadir.visibility.tif")[0]
    assert (oblique == Code.OCCLUDED).sum() > 50 and (oblique == Code.FACING_AWAY).sum() > 50
    assert (nadir == Code.VISIBLE).all()


def test_visibility_truth_matches_an_independent_ray_cast() -> None:
    """Marched truth vs the first hit of each post's ray on a mesh 4x finer than the DEM."""
    scene = make_scene("crater", size=64, spacing=80.0)
    cam = scene.cameras["oblique"]
    truth = scene.visibility_truth(cam)
    # a 4x finer mesh of the analytic surface, cast from the camera towards each post
    t = scene.terrain
    fine_t = Terrain(
        np.zeros((253, 253)),
        t.transform @ Affine.scale(0.25),
        t.crs,
    )
    x, y = scene.surface.lonlat_to_local(*fine_t.pixel_to_lonlat(*fine_t.grid()))
    fine = fine_t.with_values(scene.surface.height(x, y))
    post = scene.surface.surface_point(*scene.post_local()).reshape(-1, 3)
    hits = RayCaster(terrain_mesh(fine)).first_hit(cam.center, post - cam.center)
    gap = np.linalg.norm(hits.points - post, axis=1).reshape(t.shape)
    hidden_cast = gap > 20.0  # a quarter post: the first hit is elsewhere
    hidden_truth = np.isin(truth, (Code.OCCLUDED, Code.FACING_AWAY))
    keep = interior(hidden_truth)
    agree = np.mean(hidden_cast[keep] == hidden_truth[keep])
    assert keep.sum() > 0.7 * truth.size
    assert agree > 0.995, f"marched and cast visibility agree on {agree:.4f} of posts"


def test_facing_away_matches_dem_normals() -> None:
    scene = make_scene("crater", size=64, spacing=80.0)
    cam = scene.cameras["oblique"]
    truth = scene.visibility_truth(cam)
    p = scene.terrain.world_points()
    away = np.einsum("...i,...i->...", scene.terrain.normals(), cam.center - p) < 0
    keep = interior(away)
    assert np.mean((truth == Code.FACING_AWAY)[keep] == away[keep]) > 0.99


def test_rendered_image_matches_truth_radiance(crater_dir) -> None:
    """Sampling each image at the projection of visible posts gives back the true radiance."""
    dem = Terrain.read(crater_dir / "dem.tif")
    radiance = read_image(crater_dir / "truth_radiance.tif")[0]
    for name in ("nadir", "oblique"):
        cam = read_camera(crater_dir / f"{name}.tsai")
        image = read_image(crater_dir / f"{name}.tif")[0]
        vis = read_image(crater_dir / f"{name}.visibility.tif")[0]
        uv, _ = cam.project(dem.world_points())
        sampled = map_coordinates(image, [uv[..., 1], uv[..., 0]], order=1)
        keep = interior(vis == Code.VISIBLE) & (vis == Code.VISIBLE)
        corr = np.corrcoef(sampled[keep], radiance[keep])[0, 1]
        assert corr > 0.9, f"{name}: correlation {corr:.3f}"


def test_planar_scene_is_a_plane() -> None:
    scene = make_scene("planar", size=32)
    n = np.array(scene.facts["plane_normal"])
    x0 = np.array(scene.facts["plane_point"])
    pts = scene.terrain.world_points()
    assert np.abs((pts - x0) @ n).max() < 1e-6
    theta, phi = scene.facts["plane_normal_angles_deg"]
    t, p = np.radians(theta), np.radians(phi)
    np.testing.assert_allclose([np.cos(t) * np.cos(p), np.sin(t) * np.cos(p), np.sin(p)], n)
    # the normal is tilted a few degrees from the vertical at the tile centre
    up = pts[16, 16] / np.linalg.norm(pts[16, 16])
    assert 3.5 < np.degrees(np.arccos(up @ n)) < 8.5
    assert all(
        v == Code.VISIBLE
        for cam in scene.cameras.values()
        for v in np.unique(scene.visibility_truth(cam))
    )


def test_hills_and_seeds() -> None:
    a = make_scene("hills", size=32, seed=1)
    b = make_scene("hills", size=32, seed=1)
    c = make_scene("hills", size=32, seed=2)
    np.testing.assert_array_equal(a.terrain.values, b.terrain.values)
    assert np.abs(a.terrain.values - c.terrain.values).max() > 1.0
    assert len(a.cameras) == 4
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.terrain = c.terrain  # a scene is made complete and stays as made
    with pytest.raises(InputError, match="kind"):
        make_scene("volcano")
    with pytest.raises(InputError):
        make_scene("hills", size=4)


@pytest.mark.parametrize("kind", ["hills", "city"])
def test_image_margin_frames_the_dem_that_many_pixels_wider(kind: str) -> None:
    """``image_margin`` pixels lie between the DEM's projection (its corners at the lowest and
    highest heights, through the camera's own projection) and each image edge."""
    for margin in (6.0, 14.0):
        scene = make_scene(kind, size=16, image_margin=margin)
        t = scene.terrain
        rows, cols = t.shape
        h = t.values[t.valid]
        corners = t.to_world(
            np.array([0, cols - 1] * 4, float),
            np.array([0, 0, rows - 1, rows - 1] * 2, float),
            np.repeat([h.min(), h.max()], 4),
        )
        for cam in scene.cameras.values():
            uv, _ = cam.project(corners)
            lo, hi = uv.min(axis=0), uv.max(axis=0)
            np.testing.assert_allclose(lo, margin, atol=1e-6)
            assert np.all(np.array([cam.width, cam.height]) - hi >= margin - 1e-6)
            assert np.all(np.array([cam.width, cam.height]) - hi < margin + 1)
    with pytest.raises(InputError, match="margin"):
        make_scene("hills", size=16, image_margin=-1)
