"""The visibility rule (occluder surface + default epsilon) against independent truth: the city's
exact clipping truth (walls between posts), the crater's marched truth with DEM noise, and
hand geometry for roof edges, isolated peaks, holes and DEM borders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS
from scipy.ndimage import binary_dilation

from orthomvp.camera import PinholeCamera
from orthomvp.codes import Code, WorldFrame
from orthomvp.engine import plan_ortho
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import STEP_SLOPE, occluder_mesh, terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import EPS_FLOOR, compute_visibility
from orthomvp.synthetic import (
    away_from_boundaries,
    classification_scores,
    load_scene,
    look_at,
    make_scene,
)

HIDDEN = (Code.OCCLUDED, Code.FACING_AWAY)


def wall_foot_leak(codes: np.ndarray, truth: np.ndarray, ground: np.ndarray, roofs: np.ndarray):
    """(posts given a value, posts) among the occluded ground posts within 3 posts of a
    building (every one of them: none excused)."""
    near = binary_dilation(roofs, np.ones((7, 7), bool)) & ~roofs
    foot = (truth == Code.OCCLUDED) & ground & near
    return int((foot & (codes == Code.VISIBLE)).sum()), int(foot.sum())


@pytest.mark.parametrize("seed", [0, 1])
def test_city_goals_hold(seed: int) -> None:
    """Issue 15: F1 >= 0.99 away from class boundaries, 0 ghosts there, at most 1% of the hidden
    ground posts at wall feet get a value. Measured (seeds 0 and 1, 4 views each): F1 1.0000 /
    1.0000, 0 ghosts away from boundaries, 0.20% at wall feet; the plain mesh with the same
    epsilon leaks 1.43% there (its walls slope across a cell: their shadows fall short)."""
    city = make_scene("city", size=160, seed=seed)
    x, y = city.post_local()
    piece = city.surface.pieces(x, y)[3]
    roofs = (piece >= 1) & (piece <= len(city.surface.buildings))
    plain = RayCaster(terrain_mesh(city.terrain))
    leak, leak_plain, feet = 0, 0, 0
    for name, cam in city.cameras.items():
        truth = city.visibility_truth(cam)
        vis = compute_visibility(city.terrain, cam)
        keep = away_from_boundaries(truth)
        scores = classification_scores(vis.codes, truth, keep)
        assert scores["scored"] > 15_000
        assert scores["f1_visible"] >= 0.99 and scores["f1_hidden"] >= 0.99, (name, scores)
        assert not (np.isin(truth, HIDDEN) & keep & (vis.codes == Code.VISIBLE)).any(), name
        got, n = wall_foot_leak(vis.codes, truth, piece == 0, roofs)
        mesh_codes = compute_visibility(city.terrain, cam, caster=plain).codes
        leak, leak_plain, feet = (
            leak + got,
            leak_plain + wall_foot_leak(mesh_codes, truth, piece == 0, roofs)[0],
            feet + n,
        )
    assert feet > 5000
    assert leak <= 0.01 * feet, f"{leak} of {feet} hidden wall-foot posts get a value"
    assert leak_plain > 0.01 * feet  # what the occluder surface fixes


def test_crater_with_dem_noise_stays_within_the_former_rule() -> None:
    """The crater (160 x 40 m posts, 55 degree oblique view) with 10 m of DEM noise: F1 of
    'hidden' 0.9819 (the former rule, plain mesh and max(4, GSD / cos e): 0.9796)."""
    scene = make_scene("crater")
    cam = scene.cameras["oblique"]
    truth = scene.visibility_truth(cam)
    rng = np.random.default_rng(0)
    noisy = scene.terrain.with_values(
        scene.terrain.values + rng.normal(0, 10.0, scene.terrain.shape)
    )
    scores = classification_scores(
        compute_visibility(noisy, cam).codes, truth, away_from_boundaries(truth)
    )
    assert scores["f1_hidden"] >= 0.98 and scores["f1_visible"] >= 0.997, scores


def test_without_steps_the_occluder_is_the_plain_mesh() -> None:
    """No edge of the crater is steeper than the step slope: every ray's first hit is the
    plain mesh's, and the surface has no more triangles."""
    scene = make_scene("crater", size=48, spacing=80.0)
    t, cam = scene.terrain, scene.cameras["oblique"]
    occ, plain = occluder_mesh(t), terrain_mesh(t)
    assert len(occ.faces) == len(plain.faces)
    posts = t.world_points().reshape(-1, 3)
    a = RayCaster(occ).first_hit(np.broadcast_to(cam.center, posts.shape), posts - cam.center)
    b = RayCaster(plain).first_hit(np.broadcast_to(cam.center, posts.shape), posts - cam.center)
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_allclose(a.distance[a.mask], b.distance[b.mask], atol=1e-3)


SPACING = 0.5


def map_terrain(values: np.ndarray) -> Terrain:
    """``values`` on 0.5 m posts in UTM 33N (map frame), post (0, 0) at the north-west."""
    return Terrain(
        np.asarray(values, np.float64),
        Affine(SPACING, 0, 500_000.0, 0, -SPACING, 5_000_000.0),
        CRS.from_epsg(32633),
        world=WorldFrame.MAP,
    )


def east_camera(terrain: Terrain, elevation: float, target: tuple[float, float]) -> PinholeCamera:
    """A camera 3 km away due east of the post (c, r) = ``target``, looking down at it at
    ``elevation`` degrees above the horizon (rays within 0.1 degrees of that elevation
    over the grids here)."""
    c, r = target
    p = terrain.to_world(np.array(c), np.array(r), np.array(0.0))
    e = np.radians(elevation)
    centre = p + 3000.0 * np.array([np.cos(e), 0.0, np.sin(e)])
    return PinholeCamera(
        4e4,
        4e4,
        500.0,
        500.0,
        centre,
        look_at(centre, p, np.array([0.0, 1.0, 0.0])),
        width=1000,
        height=1000,
    )


def test_roof_edges_and_wall_feet_of_a_flat_box() -> None:
    """A 5.9 m box, walls halfway between posts, seen from the east at 45 degrees: the post k
    posts west of the box is hidden iff its line of sight, rising 0.5 m per post, passes under
    the eave: (k - 0.5) 0.5 m < 5.9 m, k = 1..12 (k = 1 faces away on the DEM's normals).
    Every roof post is visible but the west edge's, whose DEM normal (central differences
    across the wall) faces away; no roof post is hidden. Every ground post east of the box is
    visible. The plain mesh drops the last shadow post: its roof edge lies half a post inside
    the wall."""
    values = np.zeros((40, 60))
    values[10:30, 20:40] = 5.9  # columns 20..39: walls at c = 19.5 and 39.5
    t = map_terrain(values)
    cam = east_camera(t, 45.0, (30.0, 20.0))
    for caster, shadow in ((None, 12), (RayCaster(terrain_mesh(t)), 11)):
        codes = compute_visibility(t, cam, caster=caster).codes
        assert (codes[10:30, 21:40] == Code.VISIBLE).all()  # the roof, its east edge included
        assert (codes[10:30, 20] == Code.FACING_AWAY).all()  # normals across the wall, not hits
        assert (codes[:, 40:] == Code.VISIBLE).all()  # facing the camera, wall feet included
        row = codes[12:28, :20]  # behind the box, rows clear of its corners
        assert np.isin(row[:, 20 - shadow : 20], HIDDEN).all()
        assert (row[:, : 20 - shadow] == Code.VISIBLE).all()


def test_an_isolated_peak_hides_past_epsilon_and_not_itself() -> None:
    """One post 3.2 m above flat ground, seen from the east at 45 degrees: the peak and its
    faces are visible; ground posts k posts west of it are hidden in the truth of a 1-post
    pillar (pixel-is-area) for (k - 0.5) 0.5 m < 3.2 m, k <= 6; those past epsilon (3 posts)
    are called hidden, the rest of the row visible. (k = 1, 2 see their occluder within
    epsilon: no distance rule tells them from a visible post's own bumps; the README says so.)"""
    values = np.zeros((21, 31))
    values[10, 20] = 3.2
    t = map_terrain(values)
    codes = compute_visibility(t, east_camera(t, 45.0, (20.0, 10.0))).codes
    assert EPS_FLOOR == 3.0
    assert codes[10, 20] == Code.VISIBLE and (codes[9:12, 21:] == Code.VISIBLE).all()
    assert (codes[10, 14:18] == Code.OCCLUDED).all()  # k = 3..6: first hits 3.7..6 posts away
    assert (codes[10, :14] == Code.VISIBLE).all()
    assert (codes[[8, 12]] == Code.VISIBLE).all()  # rows beside the pillar


def test_occluder_is_closed_conservative_and_bounded_at_holes_and_borders() -> None:
    """A wall along the DEM's border, steps next to holes: vertical rays over every cell with
    four posts hit the occluder (no cracks), never below the plain mesh, never above the
    highest post; across a step the occluder stands at the higher post's height from the line
    halfway between the posts."""
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 0.5, (24, 24))
    values[:, -3:] = 8.0  # a wall along the east border
    values[8:14, 6:12] = 5.0  # a box...
    values[10, 7] = values[3, 15] = values[16, 4] = np.nan  # ...with a hole in it, and others
    values[3, 16] = 7.0  # a step next to a hole
    t = map_terrain(values)
    assert len(occluder_mesh(t).faces) > len(terrain_mesh(t).faces)
    cells = np.isfinite(values[:-1, :-1] + values[1:, :-1] + values[:-1, 1:] + values[1:, 1:])
    fc, fr = np.meshgrid(np.arange(0, 23, 0.125) + 1e-3, np.arange(0, 23, 0.125) + 1e-3)
    inside = cells[fr.astype(int), fc.astype(int)].ravel()
    top = t.to_world(fc, fr, np.full(fc.shape, 100.0)).reshape(-1, 3)
    down = np.broadcast_to([0.0, 0.0, -1.0], top.shape)
    occ = RayCaster(occluder_mesh(t)).first_hit(top, down)
    plain = RayCaster(terrain_mesh(t)).first_hit(top, down)
    assert occ.mask[inside].all()
    z_occ, z_plain = occ.points[inside, 2], plain.points[inside, 2]
    assert (z_occ >= z_plain - 1e-4).all() and (z_occ <= np.nanmax(values) + 1e-4).all()
    # the border wall: full height from halfway between columns 20 and 21 (c = 20.5)
    wall = inside & (fr.ravel() < 20) & (fr.ravel() > 18)
    c = fc.ravel()
    np.testing.assert_allclose(occ.points[wall & (c > 20.51), 2], 8.0, atol=1e-4)
    assert (occ.points[wall & (c < 20.49) & (c > 20.01), 2] < 8.0).all()
    assert STEP_SLOPE == 3.0  # the walls above are 10:1 and steeper, the noise 1:1


def test_tiled_equals_untiled_on_the_city(city_dir: Path, tmp_path: Path) -> None:
    """Tiles cut through stepped cells: the engine's codes equal the whole DEM's."""
    from orthomvp.engine import Outputs, run_plan
    from orthomvp.io.raster import read_image

    view = (city_dir / "sw.tif", city_dir / "sw.tsai")
    codes = []
    for tile in (16, 64):
        plan = plan_ortho(city_dir / "dem.tif", [view], tile=tile, progress=False, grid="dem")
        out = tmp_path / f"vis{tile}.tif"
        run_plan(plan, Outputs(visibility=out), progress=False)
        codes.append(read_image(out)[0])
    np.testing.assert_array_equal(codes[0], codes[1])
    scene = load_scene(city_dir)
    camera = scene.views["sw"].camera
    np.testing.assert_array_equal(codes[0], compute_visibility(scene.terrain, camera).codes)
    assert (codes[0] == Code.OCCLUDED).sum() > 100
