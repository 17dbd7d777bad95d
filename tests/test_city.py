"""The city scene: its truth checked by hand geometry and by independent marching, and
orthomvp's visibility scored against it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from orthomvp.codes import Code, WorldFrame
from orthomvp.geometry.world import detect_world
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import away_from_boundaries, classification_scores, load_scene, make_scene
from orthomvp.synthetic.city import BASE_HEIGHT, ORIGIN, Building, CitySurface, Ground


@pytest.fixture(scope="module")
def city():
    return make_scene("city", size=96)


def flat_box(pitch: float) -> CitySurface:
    """Flat ground at BASE_HEIGHT and one building 10 m x 8 m, eaves 6 m high, ridge along x."""
    ground = Ground(0.0, 0.0, 0.0, 0.1, 0.1, 0.0, 0.0)
    b = Building(-5.0, 5.0, -4.0, 4.0, BASE_HEIGHT + 6, pitch, "x", BASE_HEIGHT - 1, 0.5, 0.5)
    return CitySurface(ground, (b,), (), lambda x, y: np.full(np.shape(x), 0.5), np.eye(3)[2])


@pytest.mark.parametrize("camera_yz", [(-200.0, 200.0), (-400.0, 150.0)])
def test_one_gabled_box_hides_what_hand_geometry_says(camera_yz: tuple[float, float]) -> None:
    """Ground posts north of the box, camera due south: the segment in the plane x = 0 rises
    with slope s; hidden iff it passes under the north eave, the ridge or the south eave
    (the roof profile and the segment are linear in between)."""
    surface = flat_box(0.5)
    cy, cz = camera_yz
    y_p = np.linspace(4.05, 30, 600)
    posts = np.stack([np.zeros_like(y_p), y_p, np.full_like(y_p, BASE_HEIGHT)], axis=-1)
    hidden = surface.hidden(posts, np.array([0.0, cy, BASE_HEIGHT + cz]), step=0.1)
    s = cz / (y_p - cy)
    depth = np.max([6 - (y_p - 4) * s, 8 - y_p * s, 6 - (y_p + 4) * s], axis=0)
    clear = np.abs(depth) > 1e-3
    assert hidden.any() and not hidden.all()
    np.testing.assert_array_equal(hidden[clear], depth[clear] > 0)
    if cz / (30 - cy) < 0.5:  # a flat camera: some segments clear the eave but hit the gable
        assert (hidden & (6 - (y_p - 4) * s < 0)).any()


def test_dem_heights_are_roofs_trees_and_ground_by_hand(city) -> None:
    t, surface = city.terrain, city.surface
    x, y = city.post_local()
    g = surface.ground
    ground = (
        BASE_HEIGHT
        + g.sx * x
        + g.sy * y
        + g.amp * np.sin(g.kx * x + g.px) * np.cos(g.ky * y + g.py)
    )
    expect = ground.copy()
    corners = t.transform.c - ORIGIN[0], t.transform.f - ORIGIN[1]
    assert len(surface.buildings) >= 3 and len(surface.trees) >= 3
    for b in surface.buildings:
        # walls on cell corners: a whole number of posts from the DEM's corner
        for edge in ((b.x0 - corners[0]) / city.spacing, (b.y0 - corners[1]) / city.spacing):
            assert edge == pytest.approx(round(edge), abs=1e-9)
        inside = (x > b.x0) & (x < b.x1) & (y > b.y0) & (y < b.y1)
        along = y - (b.y0 + b.y1) / 2 if b.ridge == "x" else x - (b.x0 + b.x1) / 2
        half = (b.y1 - b.y0) / 2 if b.ridge == "x" else (b.x1 - b.x0) / 2
        expect[inside] = b.eave + b.pitch * (half - np.abs(along[inside]))
        assert inside.sum() >= 16 and (expect[inside] > ground[inside] + 3).all()
    for tree in surface.trees:
        q = ((x - tree.x) ** 2 + (y - tree.y) ** 2) / tree.radius**2
        crown = tree.z + tree.height * np.sqrt(np.clip(1 - q, 0, None))
        expect = np.where((q < 1) & (crown > expect), crown, expect)
    np.testing.assert_allclose(t.values, expect, atol=1e-9)
    assert np.ptp(t.values) > 8  # roofs and crowns stand metres above the ground


@pytest.mark.slow
def test_truth_agrees_with_a_fine_march_against_the_height_field(city) -> None:
    """The exact truth against sampling each segment every 2 cm with the point test
    'below' (z < H(x, y)), which can only miss the corner of a piece, never invent one."""
    cam = city.cameras["sw"]
    truth = city.visibility_truth(cam)
    x, y = city.post_local()
    p = np.stack([x, y, city.surface.height(x, y)], axis=-1)[truth == Code.VISIBLE]
    q = np.stack([x, y, city.surface.height(x, y)], axis=-1)[truth == Code.OCCLUDED]
    centre = cam.center - ORIGIN
    top = city.terrain.values.max()

    def marched(points: np.ndarray) -> np.ndarray:
        u = centre - points
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        hit = np.zeros(len(points), bool)
        for s in np.arange(0.01, np.max((top - points[:, 2]) / u[:, 2]), 0.02):
            hit |= city.surface.below(points + s * u)  # up to above the highest roof
        return hit

    assert len(q) > 500
    assert not marched(p).any()
    assert marched(q).mean() > 0.999


@pytest.mark.slow
def test_images_show_the_true_radiance(city) -> None:
    """Two views' images sampled at its truth-visible posts is the truth radiance there."""
    from orthomvp.ortho.orthophoto import sample_image

    radiance = city.surface.radiance(*city.post_local())
    for name in ("ne", "sw"):
        cam = city.cameras[name]
        image = city.render(cam, supersample=2)
        truth = city.visibility_truth(cam)
        keep = away_from_boundaries(truth, 2) & (truth == Code.VISIBLE)
        uv, _ = cam.project(city.terrain.world_points())
        sampled = sample_image(image[None], uv)[0]
        assert keep.sum() > 4000
        assert np.corrcoef(sampled[keep], radiance[keep])[0, 1] > 0.98  # pixels blur
        assert np.median(np.abs(sampled[keep] - radiance[keep])) < 0.01


def test_city_directory_is_a_map_frame_scene(tmp_path) -> None:
    scene = make_scene("city", size=32, seed=3)
    scene.write(tmp_path, supersample=1)
    summary = json.loads((tmp_path / "scene.json").read_text())
    assert summary["kind"] == "city" and summary["crs"] == "EPSG:32633"
    data = load_scene(tmp_path)
    assert data.terrain.world == WorldFrame.MAP and data.terrain.crs.to_epsg() == 32633
    assert np.mean(data.terrain.post_spacing()) == pytest.approx(0.5)
    centres = np.array([v.camera.center for v in data.views.values()])
    assert detect_world(data.terrain, centres) == WorldFrame.MAP
    assert set(data.views) == {"ne", "se", "sw", "nw"}
    for name, view in data.views.items():
        np.testing.assert_array_equal(view.truth, scene.visibility_truth(scene.cameras[name]))
        # the camera looks down at its emission angle
        down = ORIGIN + [0, 0, np.median(scene.terrain.values)] - view.camera.center
        emission = np.degrees(np.arccos(-down[2] / np.linalg.norm(down)))
        assert emission == pytest.approx(summary["views"][name]["emission_deg"], abs=0.5)


def test_orthomvp_visibility_on_the_city(city) -> None:
    """F1 away from truth class boundaries, per view, against the exact truth."""
    for name, cam in city.cameras.items():
        truth = city.visibility_truth(cam)
        vis = compute_visibility(city.terrain, cam)
        scores = classification_scores(vis.codes, truth, away_from_boundaries(truth))
        assert scores["scored"] > 6000
        assert scores["f1_visible"] >= 0.99 and scores["f1_hidden"] >= 0.99, (name, scores)
