"""The reference shape models in meshes/ still match the scenes they were made from, and the
small body works as a DEM: ray hits and occlusions against its analytic shape."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.ndimage import maximum_filter, minimum_filter

from orthomvp.camera import PinholeCamera
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import SmallBody, look_at, make_scene

MESHES = Path(__file__).resolve().parents[1] / "meshes"
STEP = 1.0  # degrees between posts of the small body's DEM


def test_crater_truth_matches_the_analytic_scene() -> None:
    mesh = trimesh.load(MESHES / "crater-truth.ply", process=False)
    assert len(mesh.vertices) == 96 * 96 and len(mesh.faces) == 2 * 95 * 95
    scene = make_scene("crater", size=96, spacing=50.0)
    world = scene.terrain.world_points().reshape(-1, 3)
    origin = np.array([1557054.143, 97936.496, 764328.194])
    # float64 local coordinates; the origin above is rounded to the millimetre
    np.testing.assert_allclose(mesh.vertices + origin, world, rtol=0, atol=1e-3)
    colours = mesh.visual.vertex_colors[:, :3].astype(float)
    assert colours.std() > 20  # the radiance texture is there


# ------------------------------------------------------------------------------ small body
@pytest.fixture(scope="module")
def body() -> SmallBody:
    return SmallBody.from_seed(0)


@pytest.fixture(scope="module")
def body_dem(body: SmallBody) -> tuple[Terrain, RayCaster]:
    """The small body as a global DEM of radii, 1 degree posts, and a ray caster on it."""
    t = body.terrain(STEP)
    return t, RayCaster(terrain_mesh(t))


def test_small_body_ply_matches_the_generator(body: SmallBody) -> None:
    path = MESHES / "small-body.ply"
    assert path.stat().st_size < 1_000_000
    mesh = trimesh.load(path, process=False)
    fresh = body.mesh(subdivisions=5)
    assert len(mesh.vertices) == len(fresh.vertices) == 10242
    assert len(mesh.faces) == len(fresh.faces) == 20480
    np.testing.assert_allclose(mesh.vertices, fresh.vertices, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(mesh.faces, fresh.faces)
    # every vertex lies on the analytic surface, along its own direction
    rho = np.linalg.norm(mesh.vertices, axis=1)
    np.testing.assert_allclose(rho, body.radius_along(mesh.vertices / rho[:, None]), atol=1e-6)
    # a closed surface wound outward; asteroid-like size and elongation
    assert mesh.is_watertight and mesh.volume > 0
    eq_radius = (3 * mesh.volume / (4 * np.pi)) ** (1 / 3)  # measured 2401 m
    a, b, c = mesh.extents  # measured 7221 x 4200 x 3738 m
    assert 2000 < eq_radius < 3000 and 1.4 < a / b < 2.0 and b >= c
    assert rho.max() <= body.max_radius


def test_small_body_radius_grid(body: SmallBody, body_dem: tuple) -> None:
    t, _ = body_dem
    assert t.shape == (180, 360) and t.radius_values
    assert t.crs.ellipsoid.semi_major_metre == body.mean_radius == 2500.0
    # post (c, r) at the pixel centre: lon -180 + (c + 0.5), lat 90 - (r + 0.5) degrees
    r, c = np.mgrid[0:180, 0:360]
    lon, lat = np.radians(-180 + (c + 0.5) * STEP), np.radians(90 - (r + 0.5) * STEP)
    np.testing.assert_allclose(t.values, body.radius(lon, lat), rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        t.world_points(), body.radius(lon, lat)[..., None] * unit_vector(lon, lat), atol=1e-9
    )


def test_rays_hit_the_analytic_surface(body: SmallBody, body_dem: tuple) -> None:
    """Rays from a camera 10 km from the body centre, aimed at random surface points up to
    50 degrees from the sub-camera point (far from the poles and the 180-degree seam, where the
    DEM mesh has holes), first hit the DEM mesh on the analytic surface."""
    t, caster = body_dem
    rng = np.random.default_rng(1)
    lon0, lat0 = np.radians(20.0), np.radians(10.0)
    centre = 10_000.0 * unit_vector(lon0, lat0)
    lon = lon0 + np.radians(rng.uniform(-50, 50, 20_000))
    lat = lat0 + np.radians(rng.uniform(-50, 50, 20_000))
    target = body.surface_point(lon, lat)
    hits = caster.first_hit(centre, target - centre)
    d = target - centre
    aimed = np.linalg.norm(d, axis=1)
    slant = np.abs(np.einsum("ij,ij->i", body.surface_normal(lon, lat), d)) / aimed
    # measured 98.7% hit; the rest graze the limb (within 1.7 degrees of the tangent plane)
    # and pass above the facets, which are chords of the convex limb
    assert hits.mask.mean() > 0.95 and slant[~hits.mask].max() < 0.05
    p = hits.points[hits.mask]
    rho = np.linalg.norm(p, axis=1)
    err = np.abs(rho - body.radius_along(p / rho[:, None]))
    spacing = rho * np.radians(STEP)  # post spacing along the meridians, 30-68 m
    # facets are chords of the surface: measured median 0.004, 99% 0.033 and max 0.23 post
    # spacings, the largest where the facets cut across a crater rim, whose slope jumps by
    # 0.8 (chord error up to about spacing x 0.8 / 4)
    rel = err / spacing
    assert np.median(rel) < 0.01 and np.percentile(rel, 99) < 0.05 and rel.max() < 0.3
    # a first hit: never behind the surface point the ray was aimed at, beyond what the
    # chord error allows along a ray that meets the surface at a slant (measured 0.22 spacings)
    beyond = (hits.distance - aimed)[hits.mask] * slant[hits.mask] / spacing
    assert beyond.max() < 0.3, beyond.max()


def grazing_camera(body: SmallBody, t: Terrain, k: int, emission: float) -> PinholeCamera:
    """A camera about 10 km from the body centre looking at crater ``k`` from ``emission``
    degrees off its local vertical (from the east), ground sample distance 0.8 posts, its
    image just covering the posts within two crater radii."""
    centre_dir = body.crater_centres[k]
    target = body.radius_along(centre_dir) * centre_dir
    up = centre_dir
    north = np.array([0.0, 0.0, 1.0]) - up * up[2]
    north /= np.linalg.norm(north)
    east = np.cross(north, up)
    em = np.radians(emission)
    dist = 9000.0
    position = target + dist * (np.cos(em) * up + np.sin(em) * east)
    rot = look_at(position, target, north)
    f = dist / (0.8 * np.mean(t.post_spacing()))
    dirs = unit_vector(*t.pixel_to_lonlat(*t.grid()))
    near = np.arccos(np.clip(dirs @ centre_dir, -1, 1)) < 2 * body.crater_radii[k]
    uv, _ = PinholeCamera(f, f, 0.0, 0.0, position, rot).project(t.world_points()[near])
    lo, hi = uv.min(axis=0) - 6, uv.max(axis=0) + 6
    width, height = (int(np.ceil(v)) for v in hi - lo)
    return PinholeCamera(f, f, -lo[0], -lo[1], position, rot, width=width, height=height)


def test_crater_occlusion_matches_marched_truth(body: SmallBody, body_dem: tuple) -> None:
    """A grazing camera over the largest crater away from the poles and the seam: the crater
    hides part of its floor; orthomvp's visibility on the DEM agrees with visibility marched
    against the analytic radius."""
    t, caster = body_dem
    lon = np.degrees(np.arctan2(body.crater_centres[:, 1], body.crater_centres[:, 0]))
    lat = np.degrees(np.arcsin(body.crater_centres[:, 2]))
    away = (np.abs(lat) < 45) & (np.abs(lon) < 120)
    k = np.flatnonzero(away)[np.argmax(body.crater_radii[away])]
    cam = grazing_camera(body, t, k, emission=70.0)
    assert 9000 < np.linalg.norm(cam.center) < 11000
    truth = body.visibility_truth(t, cam)
    codes = compute_visibility(t, cam, caster=caster).codes
    # the crater hides posts (measured 346, 98% of them inside the rim)
    dirs = unit_vector(*t.pixel_to_lonlat(*t.grid()))
    in_crater = np.arccos(np.clip(dirs @ body.crater_centres[k], -1, 1)) < body.crater_radii[k]
    hidden = truth == 2
    assert hidden.sum() > 200 and in_crater[hidden].mean() > 0.9
    # away from class boundaries (5 x 5 posts of one truth code): F1 of "visible" measured
    # 0.998, occluded posts all found
    same = maximum_filter(truth, 5, mode="nearest") == minimum_filter(truth, 5, mode="nearest")
    sel = same & (truth > 0)
    tp = np.sum((codes == 1) & (truth == 1) & sel)
    fp = np.sum((codes == 1) & (truth != 1) & sel)
    fn = np.sum((codes != 1) & (truth == 1) & sel)
    f1 = 2 * tp / (2 * tp + fp + fn)
    assert f1 > 0.98, f1
    deep = hidden & same
    assert deep.sum() > 100 and np.mean(codes[deep] == 2) > 0.95
