"""Ray casting: millimetre hits at lunar radius against an exact float64 reference."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from conftest import open3d_missing, require_open3d
from pyproj import CRS

from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion import raycast
from orthomvp.occlusion.embree import Scene, _padded, vertex_buffer
from orthomvp.occlusion.mesh import TerrainMesh, terrain_mesh
from orthomvp.occlusion.raycast import BACKENDS, RayCaster

R = 1737400.0
MOON = CRS.from_proj4(f"+proj=longlat +R={R:.0f} +no_defs")
ALTITUDE = 117e3
CM = 0.01

pytestmark = pytest.mark.filterwarnings("error")  # misses and NaN rays must not warn


def sphere_terrain(n: int, spacing: float, relief: float, seed: int = 0) -> Terrain:
    """n x n posts on the lunar sphere near (25 E, 12 N), ``relief`` metres of smooth hills."""
    step = np.degrees(spacing / R)
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0:n, 0:n] / n
    h = relief * (0.5 * np.sin(5 * c + 1) * np.cos(4 * r) + 0.3 * c - 0.2 * r)
    h += rng.normal(0, relief * 0.01, (n, n))
    return Terrain(h, Affine(step, 0, 25.0, 0, -step, 12.0), MOON)


def camera_above(tm: TerrainMesh, east: float) -> np.ndarray:
    """A camera ALTITUDE above the tile centre, moved ``east`` metres (oblique view)."""
    up = tm.origin / np.linalg.norm(tm.origin)
    e = np.cross([0.0, 0.0, 1.0], up)
    return tm.origin + ALTITUDE * up + east * e / np.linalg.norm(e)


def reference_hits(
    tm: TerrainMesh, o: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact float64 Moller-Trumbore over every triangle, nearest positive t, world frame.

    Returns (t along unit d, triangle or -1, hit points, edge margin = min barycentric).
    """
    o = np.broadcast_to(o, d.shape)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    v = tm.world_vertices[tm.faces]
    v0, e1, e2 = v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    n = len(d)
    t_best, tri, margin = np.full(n, np.inf), np.full(n, -1), np.full(n, np.inf)
    for s in range(0, n, 64):
        oo, dd = o[s : s + 64, None, :], d[s : s + 64, None, :]
        p = np.cross(dd, e2)
        det = np.sum(e1 * p, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            sv = oo - v0
            u = np.sum(sv * p, axis=-1) * inv
            q = np.cross(sv, e1)
            w = np.sum(dd * q, axis=-1) * inv
            t = np.sum(e2 * q, axis=-1) * inv
        ok = (det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
        t = np.where(ok, t, np.inf)
        k = np.argmin(t, axis=1)
        rows = np.arange(len(k))
        hit = np.isfinite(t[rows, k])
        t_best[s : s + 64] = t[rows, k]
        tri[s : s + 64] = np.where(hit, k, -1)
        m = np.minimum(np.minimum(u[rows, k], w[rows, k]), 1 - u[rows, k] - w[rows, k])
        margin[s : s + 64] = np.where(hit, m, np.inf)
    with np.errstate(invalid="ignore"):
        points = o + t_best[:, None] * d
    points[tri < 0] = np.nan
    return t_best, tri, points, margin


def interior_points(tm: TerrainMesh, k: int, rng: np.random.Generator) -> np.ndarray:
    """World points well inside random triangles (barycentrics >= 0.05)."""
    f = rng.integers(0, len(tm.faces), k)
    b = rng.dirichlet([1, 1, 1], k) * 0.85 + 0.05
    return np.einsum("ij,ijk->ik", b, tm.world_vertices[tm.faces[f]])


@pytest.fixture(scope="module")
def small() -> TerrainMesh:
    """40 x 40 posts, 20 m apart, about 300 m of relief (slopes up to ~50 degrees)."""
    return terrain_mesh(sphere_terrain(40, 20.0, 300.0))


@pytest.fixture(scope="module")
def casters(small: TerrainMesh) -> dict[str, RayCaster]:
    """A caster per backend that loads (tests on Open3D skip without it: see conftest)."""
    return {b: RayCaster(small, b) for b in BACKENDS if b != "open3d" or not open3d_missing()}


@pytest.fixture(scope="module")
def precision_rays(small: TerrainMesh):
    """500 rays from 117 km: 440 aimed inside triangles, 60 beside the tile; the reference."""
    rng = np.random.default_rng(10)
    cam = camera_above(small, east=25e3)
    targets = interior_points(small, 440, rng)
    up = small.origin / np.linalg.norm(small.origin)
    side = np.cross(up, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    offset = rng.choice([-1, 1], 60) * rng.uniform(600, 2000, 60)
    beside = small.origin + offset[:, None] * side
    d = np.vstack([targets, beside]) - cam
    return cam, d, reference_hits(small, cam, d)


@pytest.mark.parametrize("backend", BACKENDS)
def test_precision_at_lunar_radius(backend, small, casters, precision_rays) -> None:
    cam, d, (t_ref, tri_ref, p_ref, margin) = precision_rays
    clear = margin > 1e-6  # rays not within 1e-6 (barycentric) of a triangle edge
    assert (~clear).sum() <= 2
    assert tri_ref[:440].min() >= 0 and np.all(tri_ref[440:] == -1)
    h = casters[backend].first_hit(cam, d)
    np.testing.assert_array_equal(h.mask[clear], tri_ref[clear] >= 0)
    np.testing.assert_array_equal(h.triangle[clear], tri_ref[clear])
    hit = h.mask & clear
    err = np.linalg.norm(h.points[hit] - p_ref[hit], axis=1).max()
    # measured: 0.13 mm (embree), 0.14 mm (open3d) at 119-120 km range
    assert err < CM, f"{backend}: max hit point error {err * 1e3:.3f} mm"
    derr = np.abs(h.distance[hit] - t_ref[hit]).max()
    assert derr < CM, f"{backend}: max distance error {derr * 1e3:.3f} mm"
    # barycentrics reproduce the points: p = (1-u-v) v0 + u v1 + v v2 (measured 0.14 mm)
    v = small.world_vertices[small.faces[h.triangle[hit]]]
    u, w = h.barycentric[hit, 0:1], h.barycentric[hit, 1:2]
    p_bary = (1 - u - w) * v[:, 0] + u * v[:, 1] + w * v[:, 2]
    berr = np.linalg.norm(p_bary - h.points[hit], axis=1).max()
    assert berr < CM, f"{backend}: barycentric point error {berr * 1e3:.3f} mm"
    assert np.all(h.distance[~h.mask] == np.inf)


def test_naive_float32_body_fixed_is_not_enough(small, casters, precision_rays) -> None:
    """The same cast in float32 absolute coordinates misses the reference by decimetres."""
    from embreex import mesh_construction, rtcore_scene

    cam, d, (_, tri_ref, p_ref, margin) = precision_rays
    scene = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(
        scene, small.world_vertices.astype(np.float32), small.faces.astype(np.int32)
    )
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    o32 = np.broadcast_to(cam, d.shape).astype(np.float32)
    out = scene.run(o32, unit.astype(np.float32), output=1)
    ok = (out["primID"] >= 0) & (tri_ref >= 0)
    naive = o32[ok].astype(np.float64) + out["tfar"][ok, None] * unit[ok].astype(np.float32)
    naive_err = np.linalg.norm(naive - p_ref[ok], axis=1)
    h = casters["embree"].first_hit(cam, d)
    good = h.mask & (tri_ref >= 0) & (margin > 1e-6)
    ours = np.linalg.norm(h.points[good] - p_ref[good], axis=1).max()
    # measured: naive float32 max error 0.11 m, median 2.4 cm; local frame 0.13 mm
    assert naive_err.max() > 0.08, f"naive float32 max error {naive_err.max():.3f} m"
    assert np.median(naive_err) > 0.01, f"naive float32 median {np.median(naive_err):.3f} m"
    assert ours < 1e-3, f"local frame max error {ours * 1e3:.3f} mm"


def test_backends_agree_on_a_large_oblique_scene() -> None:
    require_open3d()
    tm = terrain_mesh(sphere_terrain(300, 20.0, 600.0, seed=2))
    rng = np.random.default_rng(11)
    cam = camera_above(tm, east=80e3)  # about 34 degrees off nadir
    targets = tm.world_vertices[rng.integers(0, len(tm.world_vertices), 200_000)]
    d = targets + rng.normal(0, 30, targets.shape) - cam
    a, b = (RayCaster(tm, backend).first_hit(cam, d) for backend in BACKENDS)
    same_mask = np.mean(a.mask == b.mask)
    assert same_mask > 0.9999, f"hit masks agree on {same_mask:.6f} of the rays"
    both = a.mask & b.mask
    assert both.sum() > 150_000
    err = np.linalg.norm(a.points[both] - b.points[both], axis=1)
    # measured: identical masks and triangles on all 200k rays, points within 0.98 mm
    assert np.mean(err < CM) > 0.9999, f"{np.mean(err >= CM):.2e} of points differ by > 1 cm"
    assert np.mean(a.triangle[both] == b.triangle[both]) > 0.9999


@pytest.mark.parametrize("backend", BACKENDS)
def test_misses_and_argument_forms(backend, small, casters) -> None:
    rc = casters[backend]
    rng = np.random.default_rng(12)
    up = small.origin / np.linalg.norm(small.origin)
    cam = camera_above(small, east=0.0)
    targets = interior_points(small, 50, rng)
    d = targets - cam

    def assert_miss(h: raycast.Hits) -> None:
        assert not h.mask.any()
        assert np.all(h.distance == np.inf) and np.all(h.triangle == -1)
        assert np.isnan(h.points).all() and np.isnan(h.barycentric).all()

    # pointing away from the surface, from above it and from 117 km
    assert_miss(rc.first_hit(targets + 50 * up, np.broadcast_to(up, d.shape)))
    assert_miss(rc.first_hit(cam, -d))
    assert_miss(rc.first_hit(cam, [0.0, 0.0, 1.0]))  # axis-aligned: inf * 0 must not warn
    # passing beside the tile: horizontal rays 2 km above the origin, and vertical ones 3 km off
    side = np.cross(up, [0.0, 0.0, 1.0])
    assert_miss(rc.first_hit(small.origin + 2000 * up + np.outer(rng.normal(0, 500, 20), up), side))
    assert_miss(rc.first_hit(small.origin + 3000 * side + 1e4 * up, -up))

    ref = rc.first_hit(np.broadcast_to(cam, d.shape).copy(), d)
    t_ref, tri_ref, p_ref, _ = reference_hits(small, cam, d)
    np.testing.assert_array_equal(ref.triangle, tri_ref)
    # one origin broadcast to many directions; non-unit directions: distances still metres
    scale = rng.uniform(1e-3, 1e3, (len(d), 1))
    h = rc.first_hit(cam, d * scale)
    np.testing.assert_array_equal(h.triangle, ref.triangle)
    np.testing.assert_allclose(h.distance, t_ref, rtol=0, atol=CM)
    np.testing.assert_allclose(h.distance, np.linalg.norm(p_ref - cam, axis=1), rtol=0, atol=CM)
    np.testing.assert_allclose(h.points, p_ref, rtol=0, atol=CM)
    # one direction broadcast to many origins, and a single ray as (3,) arrays
    origins = targets + 1000 * up
    many = rc.first_hit(origins, -up)
    np.testing.assert_allclose(many.points, rc.first_hit(origins, np.tile(-up, (50, 1))).points)
    one = rc.first_hit(cam, d[0])
    assert one.mask.shape == (1,) and one.triangle[0] == tri_ref[0]
    np.testing.assert_allclose(one.points[0], p_ref[0], rtol=0, atol=CM)
    # empty input
    e = rc.first_hit(cam, np.empty((0, 3)))
    assert e.mask.shape == e.distance.shape == e.triangle.shape == (0,)
    assert e.points.shape == (0, 3) and e.barycentric.shape == (0, 2)
    # NaN or zero directions are misses with invalid="miss", the others unaffected
    bad = d.copy()
    bad[::3] = np.nan
    bad[1::7] = 0.0
    h = rc.first_hit(cam, bad, invalid="miss")
    broken = ~np.isfinite(bad).all(axis=1) | ~bad.any(axis=1)
    assert not h.mask[broken].any() and np.all(h.triangle[broken] == -1)
    np.testing.assert_array_equal(h.triangle[~broken], ref.triangle[~broken])


@pytest.mark.parametrize(
    ("origins", "directions", "match"),
    [
        ([[np.nan, 0.0, 0.0]], [[0.0, 0.0, -1.0]], "origins 0 is not finite"),
        ([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], "direction 0 is zero"),
        ([[0.0, 0.0, 0.0]], [[np.inf, 0.0, 0.0]], "directions 0 is not finite"),
        (np.zeros((2, 2)), np.zeros((2, 2)), r"origins must be \(n, 3\) or \(3,\)"),
        (np.zeros((2, 3, 3)), np.ones((2, 3, 3)), r"must be \(n, 3\)"),
        (np.zeros((2, 3)), np.ones((3, 3)), r"origins \(2, 3\) and directions \(3, 3\)"),
        ("abc", "def", "origins must be numbers"),
    ],
)
def test_bad_rays_are_refused(small, casters, origins, directions, match) -> None:
    """Rays that cannot be cast are an InputError naming the first bad one, not misses."""
    rc = casters[BACKENDS[0]]
    with pytest.raises(InputError, match=match):
        rc.first_hit(origins, directions)
    with pytest.raises(InputError, match="invalid must be raise or miss"):
        rc.first_hit([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], invalid="skip")


@pytest.mark.parametrize("backend", BACKENDS)
def test_origin_just_above_the_surface(backend, small, casters) -> None:
    """Origins inside the bounding sphere, 0.5-3 m above the surface: the hit below is found."""
    rng = np.random.default_rng(13)
    targets = interior_points(small, 200, rng)
    up = targets / np.linalg.norm(targets, axis=1, keepdims=True)
    tilt = rng.normal(0, 0.2, targets.shape)
    d = -(up + tilt - np.sum(tilt * up, axis=1, keepdims=True) * up)  # downward, up to ~30 deg
    o = targets - d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.5, 3, (200, 1))
    t_ref, tri_ref, p_ref, margin = reference_hits(small, o, d)
    h = casters[backend].first_hit(o, d)
    clear = margin > 1e-6
    np.testing.assert_array_equal(h.triangle[clear], tri_ref[clear])
    assert h.mask.all()
    err = np.linalg.norm(h.points - p_ref, axis=1).max()
    assert err < 1e-3, f"max error {err * 1e3:.3f} mm"
    np.testing.assert_allclose(h.distance, t_ref, rtol=0, atol=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_threaded_chunks_equal_small_batches(backend, small) -> None:
    rng = np.random.default_rng(14)
    n = raycast.CHUNK + 20_000
    cam = camera_above(small, east=10e3)
    d = interior_points(small, n, rng) + rng.normal(0, 5, (n, 3)) - cam
    whole = RayCaster(small, backend, threads=4).first_hit(cam, d)
    single = RayCaster(small, backend, threads=1)
    parts = [single.first_hit(cam, d[s : s + 25_000]) for s in range(0, n, 25_000)]
    for name in ("distance", "triangle", "barycentric", "points", "mask"):
        np.testing.assert_array_equal(
            getattr(whole, name), np.concatenate([getattr(p, name) for p in parts]), err_msg=name
        )
    assert 0.9 < whole.mask.mean() < 1


def test_bad_backend() -> None:
    with pytest.raises(InputError):
        RayCaster(terrain_mesh(sphere_terrain(4, 20.0, 10.0)), "optix")


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 5000])
def test_embree_scene_matches_embreex(small, n) -> None:
    """The zero-copy scene and its 8-ray packets give embreex's own answers bit for bit:
    the same triangles, distances and barycentrics, for any number of rays (partial packets),
    hits and misses alike."""
    from embreex import mesh_construction, rtcore_scene

    v32 = vertex_buffer(len(small.vertices))
    v32[:] = small.vertices
    faces = small.faces.astype(np.int32)
    scene = Scene(v32, faces)
    assert np.shares_memory(scene._vertices, v32) and np.shares_memory(scene._faces, faces)
    reference = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(reference, v32, faces)
    rng = np.random.default_rng(15)
    up = small.origin / np.linalg.norm(small.origin)  # local frame: up is not +z
    size = np.ptp(small.vertices, axis=0).max()
    o = rng.normal(0, size / 4, (n, 3)) + 3 * size * up
    targets = small.vertices[rng.integers(0, len(small.vertices), n)]
    d = targets + rng.normal(0, size / 3, (n, 3)) - o  # some pass beside the tile
    o, d = o.astype(np.float32), (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    t, tri, u, v = scene.intersect(o, d)
    ref = reference.run(o, d, output=1)
    np.testing.assert_array_equal(tri, ref["primID"])
    hit = tri >= 0
    np.testing.assert_array_equal(t[hit], ref["tfar"][hit])
    np.testing.assert_array_equal(u[hit], ref["u"][hit])
    np.testing.assert_array_equal(v[hit], ref["v"][hit])
    assert np.all(t[~hit] == np.inf)
    if n == 5000:
        assert 0.2 < hit.mean() < 0.95


def test_embree_vertex_buffer_is_padded() -> None:
    """Embree reads 16 bytes at the last float32 vertex: arrays without 4 spare bytes after
    them are copied once into a padded buffer, padded ones are shared."""
    v = vertex_buffer(10)
    assert v.base.nbytes >= v.nbytes + 4 and _padded(v) is v
    plain = np.zeros((10, 3), np.float32)
    padded = _padded(plain)
    assert padded is not plain and padded.base.nbytes >= plain.nbytes + 4
    assert _padded(plain[:5]).base is plain  # a view with spare bytes after it is shared
