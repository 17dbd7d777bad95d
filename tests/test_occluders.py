"""Rays proved clear from the DEM's heights (orthomvp.occlusion.occluders): the oracle is the first
hit cast on the whole occluder mesh, for every post, on rough, stepped and city terrain seen from
low to high elevations; visibility with the proof gives the codes of casting every ray."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS

from orthomvp.camera import PinholeCamera
from orthomvp.camera.distortion import TsaiDistortion
from orthomvp.codes import DOUBT, Code, WorldFrame
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import TerrainMesh, occluder_mesh
from orthomvp.occlusion.occluders import RADII, Occluders, _box
from orthomvp.occlusion.paths import Geometry, Rays, VisibilityPath
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.composite import MosaicOptions, doubtful
from orthomvp.ortho.orthophoto import mosaic
from orthomvp.synthetic import make_scene
from orthomvp.synthetic.cameras import look_at

SPACING = 2.0
PROVED = VisibilityPath(rays=Rays.PROVED)
PART_MESHES = VisibilityPath(rays=Rays.PART_MESHES)  # every ray cast, on meshes of parts
WHOLE_MESH = VisibilityPath(rays=Rays.WHOLE_MESH)  # every ray cast, on the whole mesh


def map_terrain(values: np.ndarray, posts: tuple[float, float] = (SPACING, SPACING)) -> Terrain:
    """``values`` on posts of ``posts`` (east, north) metres, 2 m square by default, in UTM
    33N (map frame)."""
    return Terrain(
        np.asarray(values, np.float64),
        Affine(posts[0], 0, 500_000.0, 0, -posts[1], 5_000_000.0),
        CRS.from_epsg(32633),
        world=WorldFrame.MAP,
    )


def rough(seed: int, shape: tuple[int, int] = (90, 110)) -> np.ndarray:
    """Hills, one-post spikes, walls of a few posts and holes: every kind of height a proof
    must bound."""
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    z = 20 * np.sin(r / 9) * np.cos(c / 13) + rng.normal(0, 0.7, shape)
    spikes = rng.random(shape) < 0.002
    z[spikes] += rng.uniform(5, 30, spikes.sum())
    z[20:24, 30:70] += 25  # a wall
    z[50:80, 80:84] += 12
    z[rng.random(shape) < 0.003] = np.nan
    return z


def camera_at(terrain: Terrain, elevation: float, azimuth: float) -> PinholeCamera:
    """A camera 1.5 km from the grid centre at ``elevation`` degrees above its horizon, from
    ``azimuth`` degrees east of north, with an image holding the whole grid."""
    rows, cols = terrain.shape
    target = terrain.to_world(np.array((cols - 1) / 2), np.array((rows - 1) / 2), np.array(0.0))
    e, a = np.radians(elevation), np.radians(azimuth)
    centre = target + 1500.0 * np.array([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)])
    return PinholeCamera(
        1500.0, 1500.0, 1000.0, 1000.0, centre,
        look_at(centre, target, np.array([0.0, 1.0, 0.0])), width=2000, height=2000,
    )  # fmt: skip


VIEWS = [(89.9, 0.0), (70.0, 30.0), (45.0, 200.0), (20.0, 290.0)]


def scene_views(kind: str, seed: int) -> tuple[Terrain, list[PinholeCamera]]:
    """The small city and its four views, or a rough map (``seed``) seen from :data:`VIEWS`."""
    if kind == "city":
        scene = make_scene("city", size=64)
        return scene.terrain, list(scene.cameras.values())
    t = map_terrain(rough(seed))
    return t, [camera_at(t, e, a) for e, a in VIEWS]


@pytest.mark.parametrize(("seed", "size"), [(0, (2.0, 2.0)), (1, (1.0, 4.0)), (2, (3.0, 1.5))])
@pytest.mark.parametrize(("elevation", "azimuth"), VIEWS)
def test_a_ray_proved_clear_meets_nothing_beyond_its_reach(
    seed: int, size: tuple[float, float], elevation: float, azimuth: float
) -> None:
    """Every post of a rough map (spikes, walls, holes; square and oblong posts), and as many
    points on the surface between posts and up to 0.49 post beyond its edges, with a random
    reach of 0.5 to 6 posts: a ray proved clear has its first cast hit (on the whole occluder
    mesh) within its reach of the point, horizontally, or past the point. The proof is not
    vacuous: it proves some rays, not all, and on square posts leaves those that meet the
    surface farther away, and from high above proves nearly half."""
    t = map_terrain(rough(seed), size)
    cam = camera_at(t, elevation, azimuth)
    rng = np.random.default_rng(seed)
    rows, cols = t.shape
    n = rows * cols
    c, r = rng.uniform(-0.49, cols - 0.51, n), rng.uniform(-0.49, rows - 0.51, n)
    z = t.interpolate(np.clip(c, 0, cols - 1), np.clip(r, 0, rows - 1))
    posts = np.concatenate([t.world_points().reshape(-1, 3), t.to_world(c, r, z)])
    posts = posts[np.isfinite(posts[:, 2])]
    reach = rng.uniform(0.5, 6, len(posts)) * min(size)
    proved = Occluders(t).clear(posts, cam.center, reach)
    hits = RayCaster(occluder_mesh(t)).first_hit(cam.center, posts - cam.center)
    along = np.linalg.norm(posts - cam.center, axis=1)
    before = hits.mask & (hits.distance < along - 1e-6)  # hits in front of the post
    away = np.hypot(*(hits.points[:, :2] - posts[:, :2]).T)
    assert not (proved & before & (away > reach + 1e-6)).any()
    far = before & (away > reach)
    assert not proved.all() and (proved.any() or elevation < 60)
    if size == (2.0, 2.0):
        assert proved.sum() > 20
        if elevation > 60:
            assert proved.mean() > 0.4
        else:
            assert far.sum() > 100  # posts that the proof must not take


def test_a_ray_proved_clear_on_the_city_meets_nothing_beyond_its_reach() -> None:
    """The city's walls (steps of many metres between 1 m posts), seen by its four views:
    the same guarantee, with reaches of 2.5 posts (the default epsilon's)."""
    scene = make_scene("city", size=64)
    t = scene.terrain
    posts = t.world_points().reshape(-1, 3)
    reach = 2.5 * min(abs(t.transform.a), abs(t.transform.e))
    caster = RayCaster(occluder_mesh(t))
    occluders = Occluders(t)
    proved_any = 0
    for cam in scene.cameras.values():
        proved = occluders.clear(posts, cam.center, reach)
        hits = caster.first_hit(cam.center, posts - cam.center)
        along = np.linalg.norm(posts - cam.center, axis=1)
        before = hits.mask & (hits.distance < along - 1e-6)
        away = np.hypot(*(hits.points[:, :2] - posts[:, :2]).T)
        assert not (proved & before & (away > reach + 1e-6)).any()
        proved_any += proved.sum()
    assert proved_any > 0.2 * 4 * len(posts)


def test_the_bounds_are_the_highest_posts_of_their_boxes() -> None:
    """The height bounds against a direct maximum over each box, rounded up to float32."""
    values = rough(3, (40, 50))
    occluders = Occluders(map_terrain(values))
    top, boxes, _ = occluders._bounds
    assert top >= np.nanmax(values) and np.float32(top) == top
    low = np.where(np.isnan(values), -np.inf, values)
    for radius, box in zip(RADII, boxes, strict=True):
        for r, c in [(0, 0), (17, 23), (39, 49), (5, 44)]:
            want = low[max(r - radius, 0) : r + radius + 1, max(c - radius, 0) : c + radius + 1]
            assert (
                box[r, c] >= want.max()
                and box[r, c] == np.float32(want.max())
                or (np.float32(want.max()) < want.max() <= box[r, c])
            )


def test_nothing_is_proved_off_the_map_frame() -> None:
    """On a body-fixed frame (the crater on the Moon) the heights are not along z: no proof."""
    scene = make_scene("crater", size=32, spacing=80.0)
    posts = scene.terrain.world_points().reshape(-1, 3)
    occluders = Occluders(scene.terrain)
    assert not occluders.provable
    assert not occluders.clear(posts, scene.cameras["nadir"].center, 1e6).any()


@pytest.fixture
def rays(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of rays cast by every RayCaster.first_hit call from now on."""
    calls: list[int] = []
    first_hit = RayCaster.first_hit

    def counted(self: RayCaster, origins: np.ndarray, directions: np.ndarray, **options):  # noqa: ANN202
        calls.append(len(np.atleast_2d(directions)))
        return first_hit(self, origins, directions, **options)

    monkeypatch.setattr(RayCaster, "first_hit", counted)
    return calls


@pytest.mark.parametrize("scene_kind", ["rough", "city"])
def test_visibility_with_the_proof_has_the_codes_of_casting_every_ray(
    scene_kind: str, rays: list[int]
) -> None:
    """The codes, pixels and cast misses with the proof are those of casting every ray on the
    whole occluder mesh (a plain RayCaster, in its own frame: the misses within 1% of a post
    but at crests); a proved post has no miss or eps (NaN), and cast it would not have been
    doubtful; fewer rays are cast."""
    t, cameras = scene_views(scene_kind, 5)
    occluded = 0
    whole = RayCaster(occluder_mesh(t))
    for cam in cameras:
        rays.clear()
        proved = compute_visibility(t, cam, caster=Occluders(t), path=PROVED)
        cast_proved = sum(rays)
        every = compute_visibility(t, cam, caster=whole)
        np.testing.assert_array_equal(proved.codes, every.codes)
        np.testing.assert_array_equal(proved.uv, every.uv)
        cast = np.isin(every.codes, (Code.VISIBLE, Code.OCCLUDED))
        assert np.isfinite(every.eps[cast]).all()
        skipped = cast & np.isnan(proved.miss)
        assert skipped.any() and np.isnan(proved.eps[skipped]).all()
        assert (every.codes[skipped] == Code.VISIBLE).all()
        assert not doubtful(every.miss, every.eps)[skipped].any()
        miss = every.miss[skipped]
        assert ((miss <= every.eps[skipped] - DOUBT) | (miss == np.inf)).all()
        kept = cast & ~skipped
        a, b = proved.miss[kept], every.miss[kept]
        # a ray through a crest's vertex meets it, or slips past to meet the surface within a
        # post beyond it or not at all, as float32 rounds the vertices in each frame
        apart = ~np.isclose(a, b, atol=1e-2)
        assert apart.sum() <= 0.05 * apart.size and (np.fmin(a, b)[apart] < 1e-3).all()
        assert (np.fmax(a, b)[apart] < 1.5).sum() + np.isinf(np.fmax(a, b)[apart]).sum() == (
            apart.sum()
        )
        assert cast_proved == kept.sum() < cast.sum()
        occluded += (every.codes == Code.OCCLUDED).sum()
    assert occluded > 500


def test_misses_asked_for_are_measured_for_every_post(rays: list[int]) -> None:
    """By default the proof runs unless the misses are asked for: with them every post in the
    image and facing the camera is cast (finite eps); without them the proof skips posts."""
    t = map_terrain(rough(6))
    cam = camera_at(t, 70.0, 30.0)
    full = compute_visibility(t, cam)
    cast = np.isin(full.codes, (Code.VISIBLE, Code.OCCLUDED))
    assert np.isfinite(full.eps[cast]).all()
    assert sum(rays) == cast.sum()
    rays.clear()
    codes = compute_visibility(t, cam, fields=frozenset()).codes
    np.testing.assert_array_equal(codes, full.codes)
    assert sum(rays) < 0.8 * cast.sum()


def test_a_distorted_camera_casts_every_ray() -> None:
    """A lens with distortion bends the ray through a post's pixel off the straight line that
    the proof bounds: every ray is cast."""
    t = map_terrain(rough(7))
    cam = camera_at(t, 70.0, 30.0)
    bent = replace(cam, distortion=TsaiDistortion(k1=1e-3, k2=0.0, p1=0.0, p2=0.0))
    vis = compute_visibility(t, bent, path=PROVED)
    cast = np.isin(vis.codes, (Code.VISIBLE, Code.OCCLUDED))
    assert cast.sum() > 1000 and not np.isnan(vis.miss[cast]).any()


def test_posts_all_proved_build_no_mesh(monkeypatch: pytest.MonkeyPatch) -> None:
    """Gentle ground seen from straight above: every ray is proved clear and no mesh is
    built; the codes are those of casting."""
    r, c = np.mgrid[0:60, 0:70].astype(float)
    t = map_terrain(3 * np.sin(r / 15) + 2 * np.cos(c / 11))
    cam = camera_at(t, 89.9, 0.0)
    every = compute_visibility(t, cam, caster=Occluders(t), path=PART_MESHES)

    def refuse(*args: object, **kw: object) -> None:
        raise AssertionError("a mesh was built")

    monkeypatch.setattr("orthomvp.occlusion.occluders.occluder_mesh", refuse)
    occluders = Occluders(t)
    proved = compute_visibility(t, cam, caster=occluders, path=PROVED)
    np.testing.assert_array_equal(proved.codes, every.codes)
    assert (proved.codes == Code.VISIBLE).mean() > 0.9 and occluders.mesh_seconds == 0


def test_engine_mosaic_of_the_city_with_the_proof_is_the_in_memory_one(
    city_dir: Path, tmp_path: Path
) -> None:
    """The engine proves rays in the map frame; the in-memory mosaic casts every ray: the
    same views, flags and values, in tiles."""
    import json

    from orthomvp.synthetic.loader import load_scene

    summary = json.loads((city_dir / "scene.json").read_text())
    names = list(summary["views"])
    views = [(city_dir / v["image"], city_dir / v["camera"]) for v in summary["views"].values()]
    plan = plan_ortho(city_dir / summary["dem"], views, tile=24, progress=False,
                      mosaic=MosaicOptions(), grid="dem")  # fmt: skip
    out = Outputs(ortho=tmp_path / "m.tif", source=tmp_path / "s.tif")
    run_plan(plan, out, threads=2, progress=False)
    with rasterio.open(out.ortho) as a, rasterio.open(out.source) as b:
        data, source = a.read(), b.read()
    scene = load_scene(city_dir)
    memory = mosaic(scene.terrain, [(scene.views[n].image, scene.views[n].camera) for n in names])
    np.testing.assert_array_equal(source[0], memory.source)
    np.testing.assert_array_equal(source[1], memory.flags)
    np.testing.assert_allclose(data, memory.data, rtol=1e-6, equal_nan=True)
    assert (memory.flags != 0).any() and np.isfinite(data).mean() > 0.9


@pytest.mark.parametrize("radius", RADII)
@pytest.mark.parametrize("offset", [0.0, 0.45])
def test_a_spike_just_outside_a_box_is_not_missed(radius: int, offset: float) -> None:
    """Flat ground and one spike, a wall on every side, one post beyond a box's radius east of
    a point ``offset`` posts east of a post, under a camera far due east at 60 degrees. The
    spike's cell centres stand at its height half a post nearer: the ray meets them when the
    spike stands higher than the ray there, here 0.25 post's rise higher; such a ray is never
    proved clear (a box stretched half a post farther would prove it). A spike lower than the
    ray where the box's stretch ends is proved clear."""
    cols = 2 * radius + 12
    values = np.zeros((9, cols))
    c0 = 4
    spike = c0 + radius + 1
    t = np.tan(np.radians(60.0))
    rise = SPACING * t  # the ray's rise per post
    values[4, spike] = (spike - 0.5 - c0 - offset + 0.25) * rise
    terrain = map_terrain(values)
    point = terrain.to_world(np.array(c0 + offset), np.array(4.0), np.array(0.0))
    centre = point + 1e5 * np.array([0.5, 0.0, np.sqrt(3) / 2])
    reach = 2.5 * SPACING
    hit = RayCaster(occluder_mesh(terrain)).first_hit(centre, point - centre)
    assert hit.mask[0] and hit.points[0, 0] - point[0] > reach  # the ray meets the spike
    assert not Occluders(terrain).clear(point[None], centre, reach)[0]
    values[4, spike] = (radius - 1.25) * rise  # below the ray where the box ends: proved
    assert Occluders(map_terrain(values)).clear(point[None], centre, reach)[0]


@pytest.mark.parametrize("scene_kind", ["rough", "city"])
def test_meshes_of_the_cells_rays_pass_over_cast_as_the_whole(
    scene_kind: str, rays: list[int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Casting the rays not proved clear on meshes of only the cells they pass over
    (Occluders.cast_from) gives the misses of casting them on the whole mesh, bit for bit."""
    t, cameras = scene_views(scene_kind, 8)
    monkeypatch.setattr(
        "orthomvp.occlusion.occluders.PART_BUDGET", 100.0
    )  # parts, whatever they cost
    monkeypatch.setattr("orthomvp.occlusion.occluders.TRACK_SAMPLES", 1000)
    whole = Occluders(t)
    assert whole.caster is not None  # built: every cast on the whole mesh
    parts = 0
    for cam in cameras:
        occluders = Occluders(t)
        part = compute_visibility(t, cam, caster=occluders, path=PROVED)
        every = compute_visibility(t, cam, caster=whole, path=PROVED)
        np.testing.assert_array_equal(part.codes, every.codes)
        np.testing.assert_array_equal(part.miss, every.miss)
        parts += occluders._caster is None  # cast on parts only
        # every ray, none proved, cast on parts and on the whole mesh that the path asks for
        on_parts, on_whole = Occluders(t), Occluders(t)
        a = compute_visibility(t, cam, caster=on_parts, path=PART_MESHES)
        b = compute_visibility(t, cam, caster=on_whole, path=WHOLE_MESH)
        for name in ("codes", "uv", "miss", "eps"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert (
            on_whole._caster is not None
            and np.isfinite(b.miss).sum() > np.isfinite(part.miss).sum()
        )
    assert parts >= 2


def test_a_mesh_of_some_cells_has_the_whole_mesh_triangles_there() -> None:
    """Meshes of blocks of the city's cells (its walls split cells into fans that depend on
    their neighbours, across the blocks' edges too) hold exactly the whole mesh's triangles
    over those cells, vertex for vertex."""
    t = make_scene("city", size=48).terrain
    occluders = Occluders(t)
    cells = (t.shape[0] - 1, t.shape[1] - 1)

    def triangles(mesh: TerrainMesh, keep: np.ndarray | None = None) -> set:
        tri = mesh.world_vertices[mesh.faces]  # (n, 3, 3)
        if keep is not None:  # those over a kept cell: their centroid's cell
            c, r = t.crs_to_pixel(*tri.mean(axis=1)[:, :2].T)
            tri = tri[keep[np.floor(r).astype(int), np.floor(c).astype(int)]]
        return {tuple(np.round(v, 6).ravel()) for v in tri}

    blocks = [np.s_[r : r + 6, 5:40] for r in range(1, cells[0] - 6, 3)]
    blocks += [np.s_[5:40, c : c + 6] for c in range(1, cells[1] - 6, 3)]
    for block in blocks:  # strips across the walls, each way
        where = np.zeros(cells, bool)
        where[block] = True
        part = occluders._part(where, _box(where)).tmesh
        mine = triangles(part)
        assert mine == triangles(occluder_mesh(t, part.origin), where) and len(mine) > 200


@pytest.mark.parametrize(
    ("size", "factor"), [((2.0, 2.0), 0.4), ((2.0, 2.0), 2.5), ((1.0, 3.0), 1.0), ((3.0, 1.5), 0.5)]
)
@pytest.mark.parametrize("geometry", [Geometry.SEPARABLE, Geometry.SEPARABLE_KERNEL])
@pytest.mark.parametrize("eps", [None, 1.2])
def test_the_proof_keeps_codes_and_doubt_on_other_grids(
    size: tuple[float, float], factor: float, geometry: Geometry, eps: float | None
) -> None:
    """Grids finer than the DEM (codes carried from its posts), coarser, and on oblong posts,
    through the numpy and the numba geometry, with the default epsilon and a small one: the
    proof changes no code and no doubt, and proves posts where the epsilon allows it."""
    dem = map_terrain(rough(9, (60, 70)), size)
    grid = dem if factor == 1 else dem.regrid((size[0] * factor, size[1] * factor))
    scale = float(np.mean(grid.post_spacing()) / np.mean(dem.post_spacing()))
    proved = 0
    for elevation, azimuth in VIEWS[:3]:
        cam = camera_at(dem, elevation, azimuth)
        runs = [
            compute_visibility(
                grid, cam, caster=Occluders(dem), eps=eps, post_scale=scale,
                dem=None if factor == 1 else dem, fields=frozenset({"miss"}),
                path=VisibilityPath(geometry=geometry, rays=rays),
            )
            for rays in (Rays.PROVED, Rays.PART_MESHES)
        ]  # fmt: skip
        np.testing.assert_array_equal(runs[0].codes, runs[1].codes)
        doubt = [doubtful(v.miss, v.eps) for v in runs]
        np.testing.assert_array_equal(doubt[0], doubt[1])
        proved += (np.isnan(runs[0].miss) & ~np.isnan(runs[1].miss)).sum()
    # eps 1.2 leaves a reach of 0.7 post, short of a hit just past the post: nothing proved
    assert proved > 100 if eps is None else proved == 0


def test_points_off_the_dem_or_above_the_camera_are_not_proved() -> None:
    """The proof speaks of the DEM's posts: a point more than half a post off the grid, or
    at or above the camera, is never proved, while the same point on the grid is."""
    t = map_terrain(np.zeros((20, 30)))
    occluders = Occluders(t)
    c = np.array([-3.0, -0.51, 10.0, 29.51, 33.0, 10.0, 10.0])
    r = np.array([10.0, 10.0, -0.6, 10.0, 10.0, 19.6, 10.0])
    points = t.to_world(c, r, np.zeros(len(c)))
    centre = t.to_world(np.array(10.0), np.array(10.0), np.array(500.0))
    np.testing.assert_array_equal(occluders.clear(points, centre, 5.0), [0, 0, 0, 0, 0, 0, 1])
    low = centre - np.array([0.0, 0.0, 500.0])  # level with the ground
    assert not occluders.clear(points, low, 5.0).any()


def test_parts_keep_the_walls_that_close_holes(monkeypatch: pytest.MonkeyPatch) -> None:
    """A wall one post thick with a hole in it: the cells around the hole have no triangle of
    their own but the triangles that close the wall's side; meshes of parts keep them, and
    block the same rays as the whole mesh, from every side."""
    monkeypatch.setattr("orthomvp.occlusion.occluders.PART_BUDGET", 100.0)
    values = np.zeros((80, 80))
    values[20:60, 40] = 15.0
    values[40, 40] = np.nan
    t = map_terrain(values, (1.0, 1.0))
    whole = Occluders(t)
    assert whole.caster is not None
    posts = t.world_points()[25:55, 25:55].reshape(-1, 3)
    posts = posts[np.isfinite(posts[:, 2])]
    middle = t.to_world(np.array(40.5), np.array(40.5), np.array(0.0))
    blocked = 0
    for elevation in (20, 30, 45):
        for azimuth in range(0, 360, 15):
            e, a = np.radians(elevation), np.radians(azimuth)
            direction = np.array([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)])
            centre = middle + 500.0 * direction
            part, every = (
                Occluders(t).cast_from(centre, posts, 1.0),
                whole.cast_from(centre, posts, 1.0),
            )
            along = np.linalg.norm(posts - centre, axis=1) - 0.5  # (the post's own vertex
            # is met or slipped past as float32 rounds each mesh's BVH: not compared)
            hit = [h.mask & (h.distance < along) for h in (part, every)]
            np.testing.assert_array_equal(hit[0], hit[1])
            np.testing.assert_array_equal(part.distance[hit[0]], every.distance[hit[1]])
            blocked += hit[1].sum()
    assert blocked > 1000


def test_long_tracks_mesh_the_whole_surface() -> None:
    """Tracks that would take more samples than the budget (a camera below a spike: every ray
    runs on to the grid's edge), or a ray from below its point, mesh the whole surface."""
    values = np.zeros((60, 60))
    values[5, 5] = 500.0  # far above the camera
    t = map_terrain(values)
    posts = t.world_points().reshape(-1, 3)
    centre = t.to_world(np.array(30.0), np.array(-200.0), np.array(100.0))  # far north
    occluders = Occluders(t)
    assert occluders.track_cells(centre, posts, 2.0) is None
    occluders.cast_from(centre, posts, 2.0)
    assert occluders._caster is not None  # the whole mesh
    below = Occluders(t)
    assert below.track_cells(centre - [0.0, 0.0, 200.0], posts, 2.0) is None
    few = Occluders(t)
    assert few.track_cells(centre, posts[:5], 2.0).sum() > 0  # a few tracks: their cells


def test_an_output_crs_as_rasterio_reads_it(tmp_path: Path) -> None:
    """A CRS object of rasterio's as the output CRS of a body-frame DEM (another raster's, say)
    plans as its pyproj twin does."""
    from rasterio.crs import CRS as FileCRS

    from orthomvp.engine.grid import output_grid, scan_dem

    scene = make_scene("crater", size=32, spacing=80.0)
    scene.terrain.write(tmp_path / "dem.tif")
    dem = scan_dem(tmp_path / "dem.tif")
    text = "+proj=eqc +lon_0=3.6 +R=1737400 +units=m +no_defs"
    mine = output_grid(dem, (100.0, 100.0), None, FileCRS.from_user_input(text))
    theirs = output_grid(dem, (100.0, 100.0), None, text)
    assert mine.shape == theirs.shape and mine.transform == theirs.transform
