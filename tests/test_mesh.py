"""Terrain meshes: triangulation, holes, winding, world positions, export and decimation."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
import trimesh
from affine import Affine
from conftest import require_open3d
from matplotlib import colormaps
from pyproj import CRS
from scipy.ndimage import maximum_filter, minimum_filter
from scipy.spatial import cKDTree

from orthomvp.cli import main
from orthomvp.codes import CODE_RGB
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import write_geotiff
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.present.colours import NAN_RGB, error_colour_limit
from orthomvp.present.export import export_mesh
from orthomvp.synthetic import make_scene

if TYPE_CHECKING:
    import open3d

R = 1737400.0
MOON = CRS.from_proj4(f"+proj=longlat +R={R:.0f} +no_defs")
MOON_EQC = CRS.from_proj4(f"+proj=eqc +R={R:.0f} +units=m +no_defs")
ROWS, COLS = 5, 6
HOLES = [(1, 2), (3, 4)]  # (r, c)
LON0, LAT0 = 30.0, 10.0  # upper-left corner, degrees
STEP = np.degrees(20.0 / R)  # 20 m posts


def small_terrain(north_up: bool = True, holes: bool = True) -> Terrain:
    """5 x 6 posts, 20 m apart, on the lunar sphere with two holes (or none)."""
    rng = np.random.default_rng(3)
    values = rng.uniform(-40, 40, (ROWS, COLS))
    for r, c in HOLES if holes else ():
        values[r, c] = np.nan
    e = -STEP if north_up else STEP
    return Terrain(values, Affine(STEP, 0, LON0, 0, e, LAT0), MOON)


def hand_world(t: Terrain, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Body-fixed xyz of posts from first principles: pixel centres, (R + h) e(lon, lat)."""
    lon = np.radians(t.transform.c + (c + 0.5) * t.transform.a)
    lat = np.radians(t.transform.f + (r + 0.5) * t.transform.e)
    rad = R + t.values[r, c]
    return np.stack(
        [rad * np.cos(lat) * np.cos(lon), rad * np.cos(lat) * np.sin(lon), rad * np.sin(lat)], -1
    )


def brute_triangles(valid: np.ndarray) -> set[tuple[int, ...]]:
    """The documented triangulation by a plain loop: two per cell, cut (c+1, r)-(c, r+1)."""
    rows, cols = valid.shape
    out = set()
    for r in range(rows - 1):
        for c in range(cols - 1):
            for tri in (
                [(r, c), (r + 1, c), (r, c + 1)],
                [(r, c + 1), (r + 1, c), (r + 1, c + 1)],
            ):
                if all(valid[p] for p in tri):
                    out.add(tuple(sorted(p[0] * cols + p[1] for p in tri)))
    return out


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices[faces]
    return np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])


@pytest.mark.parametrize("holes", [True, False], ids=["holes", "no-holes"])
@pytest.mark.parametrize("north_up", [True, False], ids=["north-up", "south-up"])
def test_triangulation_holes_positions_winding(north_up: bool, holes: bool) -> None:
    t = small_terrain(north_up, holes)
    tm = terrain_mesh(t)
    faces_posts = tm.vertex_post[tm.faces]
    expected = brute_triangles(np.isfinite(t.values))
    # 20 cells x 2 = 40; each hole removes the 6 triangles that use it (counted by hand)
    assert len(tm.faces) == len(expected) == (28 if holes else 40)
    assert {tuple(sorted(f)) for f in faces_posts} == expected
    hole_posts = {r * COLS + c for r, c in HOLES} if holes else set()
    assert not hole_posts & set(faces_posts.ravel())
    assert tm.faces.dtype == np.int32 and tm.faces.flags.c_contiguous  # as Embree shares it
    # every vertex is a distinct used post
    assert len(np.unique(tm.vertex_post)) == len(tm.vertex_post) == len(np.unique(faces_posts))
    r, c = np.divmod(tm.vertex_post, COLS)
    world = tm.vertices + tm.origin
    np.testing.assert_allclose(world, t.to_world(c, r, t.values[r, c]), rtol=0, atol=1e-6)
    np.testing.assert_allclose(world, hand_world(t, r, c), rtol=0, atol=1e-6)
    np.testing.assert_allclose(tm.world_vertices, world, rtol=0, atol=0)
    # the local frame is small: vertices within a few hundred metres of the origin
    assert np.abs(tm.vertices).max() < 200
    # outward normals: away from the body centre
    n = face_normals(world, tm.faces)
    centroids = world[tm.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", n, centroids) > 0)
    # uv: u along columns, v up the rows, at pixel centres
    np.testing.assert_allclose(tm.uv[:, 0] * COLS - 0.5, c, atol=1e-12)
    np.testing.assert_allclose((1 - tm.uv[:, 1]) * ROWS - 0.5, r, atol=1e-12)


def test_default_and_given_origin() -> None:
    t = small_terrain()
    tm = terrain_mesh(t)
    # valid post nearest the centre (2, 2.5): (2, 2) and (2, 3) tie; either is acceptable
    candidates = hand_world(t, np.array([2, 2]), np.array([2, 3]))
    assert np.min(np.linalg.norm(candidates - tm.origin, axis=1)) < 1e-6
    origin = np.array([1.4e6, 8.6e5, 3.0e5])
    tm2 = terrain_mesh(t, origin=origin)
    np.testing.assert_array_equal(tm2.origin, origin)
    np.testing.assert_allclose(tm2.world_vertices, tm.world_vertices, rtol=0, atol=1e-6)


@pytest.mark.parametrize("e", [-1.0, 1.0], ids=["north-up", "south-up"])
def test_map_frame_normals_point_up(e: float) -> None:
    rng = np.random.default_rng(4)
    values = rng.uniform(-30, 30, (7, 9))
    values[3, 3] = np.nan
    t = Terrain(values, Affine(20.0, 0, 1e5, 0, 20.0 * e, -2e5), MOON_EQC, world="map")
    tm = terrain_mesh(t)
    assert len(tm.faces) == len(brute_triangles(np.isfinite(values)))
    assert np.all(face_normals(tm.vertices, tm.faces)[:, 2] > 0)
    r, c = np.divmod(tm.vertex_post, 9)
    expected = np.column_stack([1e5 + 20 * (c + 0.5), -2e5 + 20 * e * (r + 0.5), values[r, c]])
    np.testing.assert_allclose(tm.world_vertices, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_winding_with_a_pole_row(seed: int) -> None:
    """A grid whose first row of posts sits on a pole: those faces are degenerate."""
    rng = np.random.default_rng(seed)
    e = 1.0 if seed % 2 else -1.0
    values = rng.normal(0, 100, (6, 8))
    t = Terrain(values, Affine(1.0, 0, rng.uniform(-180, 180), 0, e, -90.5 * e), MOON)
    tm = terrain_mesh(t)
    world = tm.world_vertices
    faces = tm.faces
    r = tm.vertex_post[faces] // 8
    off_pole = ~(r == 0).any(axis=1)
    n = face_normals(world, faces[off_pole])
    assert np.all(np.einsum("ij,ij->i", n, world[faces[off_pole]].mean(axis=1)) > 0)


def test_no_valid_cell_raises() -> None:
    values = np.full((4, 4), np.nan)
    values[::2, ::2] = 1.0  # valid posts, but no cell with four
    with pytest.raises(InputError):
        terrain_mesh(Terrain(values, Affine(STEP, 0, 0, 0, -STEP, 0), MOON))


# ------------------------------------------------------------------------------------ export
def rgb_texture() -> np.ndarray:
    return np.random.default_rng(5).integers(0, 256, (ROWS, COLS, 3), dtype=np.uint8)


def match_vertices(loaded: np.ndarray, expected: np.ndarray, tol: float) -> np.ndarray:
    """Index into ``expected`` of each loaded vertex; asserts each is within ``tol``."""
    dist, idx = cKDTree(expected).query(loaded)
    assert dist.max() < tol, f"max vertex position error {dist.max():.3g} m"
    return idx


def check_shape(loaded_v: np.ndarray, loaded_f: np.ndarray, tm, offset, tol: float) -> None:
    """Same faces (as position triples) and the same set of positions, loaders may split."""
    expected = tm.vertices + offset
    idx = match_vertices(loaded_v, expected, tol)
    assert set(idx) == set(range(len(expected)))
    assert len(loaded_f) == len(tm.faces)
    got = {tuple(sorted(f)) for f in idx[loaded_f]}
    assert got == {tuple(sorted(f)) for f in tm.faces}
    # winding survives: normals still up (the tile is small: one up direction)
    up = tm.origin / np.linalg.norm(tm.origin)
    assert np.all(face_normals(loaded_v, loaded_f) @ up > 0)


def sample_texture(mesh: trimesh.Trimesh) -> np.ndarray:
    """RGB of the loaded texture image at each vertex's UV (nearest pixel)."""
    mat = mesh.visual.material
    image = mat.image if hasattr(mat, "image") else mat.baseColorTexture
    img = np.asarray(image.convert("RGB"))
    h, w = img.shape[:2]
    uv = mesh.visual.uv
    col = np.rint(uv[:, 0] * w - 0.5).astype(int)
    row = np.rint((1 - uv[:, 1]) * h - 0.5).astype(int)
    return img[row, col]


@pytest.mark.parametrize("local", [False, True], ids=["world", "local"])
def test_export_ply(tmp_path: Path, local: bool) -> None:
    o3d = require_open3d()
    t, tex = small_terrain(), rgb_texture()
    tm = terrain_mesh(t)
    offset = np.zeros(3) if local else tm.origin
    path = tmp_path / "m.ply"
    export_mesh(tm, path, texture=tex, local=local)
    r, c = np.divmod(tm.vertex_post, COLS)
    m = trimesh.load(path, process=False)
    assert len(m.vertices) == len(tm.vertices) and len(m.faces) == len(tm.faces)
    # PLY keeps the vertex order: exact correspondence; body-fixed coordinates in float64
    err = np.abs(m.vertices - (tm.vertices + offset)).max()
    assert err < 1e-6, f"PLY vertex error {err:.3g} m"
    np.testing.assert_array_equal(m.faces, tm.faces)
    np.testing.assert_array_equal(m.visual.vertex_colors[:, :3], tex[r, c])
    o3 = o3d.io.read_triangle_mesh(str(path))
    np.testing.assert_allclose(np.asarray(o3.vertices), tm.vertices + offset, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(o3.triangles), tm.faces)
    o3_rgb = np.rint(np.asarray(o3.vertex_colors) * 255).astype(np.uint8)
    np.testing.assert_array_equal(o3_rgb, tex[r, c])


@pytest.mark.parametrize("local", [False, True], ids=["world", "local"])
def test_export_obj(tmp_path: Path, local: bool) -> None:
    o3d = require_open3d()
    t, tex = small_terrain(), rgb_texture()
    tm = terrain_mesh(t)
    offset = np.zeros(3) if local else tm.origin
    path = tmp_path / "m.obj"
    export_mesh(tm, path, texture=tex, local=local)
    assert (tmp_path / "m.mtl").exists()
    m = trimesh.load(path, process=False)
    check_shape(m.vertices, m.faces, tm, offset, tol=1e-6)
    idx = match_vertices(m.vertices, tm.vertices + offset, 1e-6)
    r, c = np.divmod(tm.vertex_post[idx], COLS)
    np.testing.assert_array_equal(sample_texture(m), tex[r, c])
    # Open3D's OBJ reader (tinyobjloader) parses float32: 0.11 m at lunar radius, the file's 1e-8
    o3 = o3d.io.read_triangle_mesh(str(path))
    tol = 1e-4 if local else 0.12
    check_shape(np.asarray(o3.vertices), np.asarray(o3.triangles), tm, offset, tol=tol)


def test_obj_textures_do_not_collide(tmp_path: Path) -> None:
    """Two textured OBJs in one directory keep their own texture images."""
    t = small_terrain()
    tm = terrain_mesh(t)
    tex_a, tex_b = rgb_texture(), 255 - rgb_texture()
    export_mesh(tm, tmp_path / "a.obj", texture=tex_a)
    export_mesh(tm, tmp_path / "b.obj", texture=tex_b)
    for name, tex in (("a", tex_a), ("b", tex_b)):
        m = trimesh.load(tmp_path / f"{name}.obj", process=False)
        idx = match_vertices(m.vertices, tm.world_vertices, 1e-6)
        r, c = np.divmod(tm.vertex_post[idx], COLS)
        np.testing.assert_array_equal(sample_texture(m), tex[r, c])


@pytest.mark.parametrize("local", [False, True], ids=["world", "local"])
def test_export_glb(tmp_path: Path, local: bool) -> None:
    t, tex = small_terrain(), rgb_texture()
    tm = terrain_mesh(t)
    offset = np.zeros(3) if local else tm.origin
    path = tmp_path / "m.glb"
    export_mesh(tm, path, texture=tex, local=local)
    m = trimesh.load(path, force="mesh", process=False)
    # glTF vertices are float32; body-fixed positions must not lose the 0.12 m of float32 at
    # lunar radius (the offset travels in the node transform)
    check_shape(m.vertices, m.faces, tm, offset, tol=1e-4)
    idx = match_vertices(m.vertices, tm.vertices + offset, 1e-4)
    r, c = np.divmod(tm.vertex_post[idx], COLS)
    np.testing.assert_array_equal(sample_texture(m), tex[r, c])


def test_ply_colours_float_raster_and_layouts(tmp_path: Path) -> None:
    # float grey on 20 x 20 posts: stretched between the 1st and 99th percentiles, which are
    # -50 and 150 by construction (3 outliers and 3 plateau values at each end; robust to any
    # percentile interpolation), clipped outside; NaN becomes the shared NaN colour
    flat = Terrain(np.zeros((20, 20)), Affine(STEP, 0, LON0, 0, -STEP, LAT0), MOON)
    ftm = terrain_mesh(flat)
    ramp = np.linspace(0, 100, 387)
    grey = np.concatenate([[-1000] * 3, [-50] * 3, ramp, [150] * 3, [1000] * 3, [np.nan]])
    grey = np.random.default_rng(6).permutation(grey).reshape(20, 20)
    expect = np.repeat(np.clip((grey + 50) / 200, 0, 1)[..., None] * 255, 3, axis=-1)
    expect[np.isnan(grey)] = NAN_RGB
    export_mesh(ftm, tmp_path / "g.ply", texture=grey.astype(np.float32))
    got = trimesh.load(tmp_path / "g.ply", process=False).visual.vertex_colors
    want = expect.reshape(-1, 3)[ftm.vertex_post]
    assert np.abs(got[:, :3].astype(float) - want).max() < 1.0 + 1e-9  # uint8 truncation
    filled = np.isfinite(grey).ravel()[ftm.vertex_post]
    assert np.all(got[filled, 0] == got[filled, 1]) and np.all(got[filled, 1] == got[filled, 2])
    np.testing.assert_array_equal(got[~filled, :3], [NAN_RGB])
    assert got[:, 3].min() == 255
    assert {0, 255} <= set(got[filled, 0].tolist())
    t = small_terrain()
    tm = terrain_mesh(t)
    r, c = np.divmod(tm.vertex_post, COLS)
    # band-first (3, rows, cols), as read_image gives, equals (rows, cols, 3)
    tex = rgb_texture()
    export_mesh(tm, tmp_path / "b.ply", texture=np.moveaxis(tex, -1, 0))
    got = trimesh.load(tmp_path / "b.ply", process=False).visual.vertex_colors
    np.testing.assert_array_equal(got[:, :3], tex[r, c])
    # uint8 grey, 2-D
    export_mesh(tm, tmp_path / "u.ply", texture=tex[..., 1])
    got = trimesh.load(tmp_path / "u.ply", process=False).visual.vertex_colors
    np.testing.assert_array_equal(got[:, :3], np.repeat(tex[r, c, 1:2], 3, axis=1))


def test_export_errors_leave_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tm = terrain_mesh(small_terrain())
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "m.stl")
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "m.ply", texture=np.zeros((ROWS + 1, COLS, 3), np.uint8))
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "m.glb", texture=np.zeros((ROWS, COLS - 1), np.float32))
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "missing" / "m.ply")
    assert list(tmp_path.iterdir()) == []
    # a write that fails half-way: no partial file, and an existing file is left as it was
    real = Path.write_bytes

    def broken(self: Path, data: bytes) -> int:
        real(self, data[: len(data) // 2])
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_bytes", broken)
    (tmp_path / "old.glb").write_text("old")
    for name in ("m.ply", "m.obj", "old.glb"):
        with pytest.raises(OSError):
            export_mesh(tm, tmp_path / name, texture=rgb_texture(), overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.glb"]
    assert (tmp_path / "old.glb").read_text() == "old"


# -------------------------------------------------------------------------------- decimation
def bump(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """A smooth 200 m hill, sigma 300 m, at (20.0, 5.0) degrees."""
    x = (lon - np.radians(20.0)) * np.cos(lat) * R
    y = (lat - np.radians(5.0)) * R
    return 200.0 * np.exp(-(x * x + y * y) / (2 * 300.0**2))


def test_decimation_stays_on_the_surface(tmp_path: Path) -> None:
    o3d = require_open3d()
    n = 60
    corner = 20.0 - n / 2 * STEP, 5.0 + n / 2 * STEP
    t0 = Terrain(np.zeros((n, n)), Affine(STEP, 0, corner[0], 0, -STEP, corner[1]), MOON)
    lon, lat = t0.pixel_to_lonlat(*t0.grid())
    t = t0.with_values(bump(lon, lat))
    tm = terrain_mesh(t)
    assert len(tm.faces) == 2 * (n - 1) ** 2
    ramp = np.broadcast_to(np.linspace(0, 250, n).astype(np.uint8), (n, n))
    target = 800
    for local, ext in ((False, "ply"), (True, "ply"), (False, "obj"), (False, "glb")):
        path = tmp_path / f"d{int(local)}.{ext}"
        export_mesh(tm, path, texture=ramp, local=local, target_triangles=target)
        m = trimesh.load(path, force="mesh", process=False)
        assert 0.8 * target <= len(m.faces) <= 1.02 * target
        world = m.vertices + (tm.origin if local else 0)
        # height error against the true surface (the full mesh's own facets are off by up to
        # 0.2 m at their centroids); measured 0.50 m for 800 of 6962 triangles
        rad = np.linalg.norm(world, axis=1)
        vlon, vlat = np.arctan2(world[:, 1], world[:, 0]), np.arcsin(world[:, 2] / rad)
        err = np.abs(rad - R - bump(vlon, vlat))
        assert err.max() < 1.0, f"decimated surface {err.max():.2f} m from the true one"
        # the footprint is kept: a vertex near each corner post of the grid (measured 0.33 m)
        corners = tm.world_vertices[np.isin(tm.vertex_post, [0, n - 1, n * n - n, n * n - 1])]
        assert cKDTree(world).query(corners)[0].max() < 1.0
        if ext == "ply":
            assert len(o3d.io.read_triangle_mesh(str(path)).triangles) == len(m.faces)
            # colours carried over: the ramp (grey, along columns) at the nearest post
            _, near = cKDTree(tm.world_vertices).query(world)
            expected = ramp.ravel()[tm.vertex_post[near]]
            np.testing.assert_array_equal(m.visual.vertex_colors[:, 0], expected)
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", target_triangles=3)


# ------------------------------------------------------------------------------ colour kinds
TABLE = CODE_RGB
"""The shared visibility colours (codes 0-3)."""
HOLES_48 = (slice(20, 23), slice(30, 32))


@pytest.fixture(scope="module")
def crater48() -> tuple[Terrain, np.ndarray, np.ndarray]:
    """The crater scene on 48 x 48 posts as a fitted DEM would be: the truth with a block of
    unresolved posts (NaN); its truth heights; and visibility codes of the oblique view with
    every code present (four columns set to 0, as if outside the image)."""
    scene = make_scene("crater", size=48)
    truth = scene.terrain.values
    fitted = truth.copy()
    fitted[HOLES_48] = np.nan
    codes = scene.visibility_truth(scene.cameras["oblique"])
    codes[:, :4] = 0
    return scene.terrain.with_values(fitted), truth, codes


def expected_counts(valid: np.ndarray) -> tuple[int, int]:
    """(vertices, triangles) of a grid mesh: each cell's two triangles whose corners are valid;
    every valid post here lies in some triangle."""
    a, b, d, e = valid[:-1, :-1], valid[:-1, 1:], valid[1:, :-1], valid[1:, 1:]
    return int(valid.sum()), int((a & d & b).sum() + (b & d & e).sum())


def o3d_texture_colours(o3: open3d.geometry.TriangleMesh) -> np.ndarray:
    """RGB of an Open3D mesh's texture at each triangle corner's UV (nearest texel); Open3D
    keeps v pointing down the image rows."""
    ids = np.asarray(o3.triangle_material_ids)
    assert len(set(ids.tolist())) == 1
    img = np.asarray(o3.textures[ids[0]])
    h, w = img.shape[:2]
    uv = np.asarray(o3.triangle_uvs)
    return img[np.rint(uv[:, 1] * h - 0.5).astype(int), np.rint(uv[:, 0] * w - 0.5).astype(int)]


@pytest.mark.parametrize("local", [False, True], ids=["body", "local"])
@pytest.mark.parametrize("fmt", ["ply", "obj", "glb"])
def test_visibility_colours_in_every_format(
    tmp_path: Path, crater48: tuple, fmt: str, local: bool
) -> None:
    o3d = require_open3d()
    t, _, codes = crater48
    tm = terrain_mesh(t)
    n_vert, n_tri = expected_counts(t.valid)
    # 48 x 48 posts less the 3 x 2 hole; 2 x 47 x 47 triangles less the 22 that touch the hole
    # (the 12 cells around it, but one triangle of the two cells on the cut's corners)
    assert (len(tm.vertices), len(tm.faces)) == (n_vert, n_tri) == (2298, 4396)
    assert set(codes[t.valid].tolist()) == {0, 1, 2, 3}
    offset = np.zeros(3) if local else tm.origin
    # expected positions from the DEM itself, in the frame written
    r, c = np.divmod(tm.vertex_post, 48)
    expected = t.to_world(c, r, t.values[r, c]) - tm.origin + offset
    want = TABLE[codes[r, c]]
    path = tmp_path / f"m.{fmt}"
    export_mesh(tm, path, codes, local=local, colour_kind="visibility")
    m = trimesh.load(path, force="mesh", process=False)
    o3 = o3d.io.read_triangle_mesh(str(path))
    assert len(m.faces) == len(np.asarray(o3.triangles)) == n_tri
    if fmt == "ply":
        # vertex order kept; float64 body-fixed coordinates
        assert len(m.vertices) == len(np.asarray(o3.vertices)) == n_vert
        np.testing.assert_allclose(m.vertices, expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(o3.vertices), expected, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(m.faces, tm.faces)
        np.testing.assert_array_equal(np.asarray(o3.triangles), tm.faces)
        np.testing.assert_array_equal(m.visual.vertex_colors[:, :3], want)
        o3_rgb = np.rint(np.asarray(o3.vertex_colors) * 255).astype(np.uint8)
        np.testing.assert_array_equal(o3_rgb, want)
        return
    # OBJ and GLB: an image texture. trimesh reads OBJ in float64 and applies the GLB node
    # transform in float64 to float32 local vertices; Open3D reads both in float32 (spacing
    # 0.125 m at 1.6e6 m; GLB rounds twice, local then world: measured 0.126 m off in 3-D).
    if fmt == "obj":
        mtl = (tmp_path / "m.mtl").read_text()
        assert "map_Kd m.png" in mtl and "Kd 1.0" in mtl
        assert (tmp_path / "m.png").is_file()
    check_shape(m.vertices, m.faces, tm, offset, tol=1e-6 if fmt == "obj" else 1e-4)
    idx = match_vertices(m.vertices, expected, 1e-6 if fmt == "obj" else 1e-4)
    np.testing.assert_array_equal(sample_texture(m), want[idx])
    o3_v = np.asarray(o3.vertices)
    tol = 1e-4 if local else 0.25
    check_shape(o3_v, np.asarray(o3.triangles), tm, offset, tol=tol)
    corners = match_vertices(o3_v[np.asarray(o3.triangles).ravel()], expected, tol)
    np.testing.assert_array_equal(o3d_texture_colours(o3), want[corners])


def test_error_colours(tmp_path: Path, crater48: tuple) -> None:
    o3d = require_open3d()
    t, truth, _ = crater48
    tm = terrain_mesh(t)
    c, _ = t.grid()
    error = (c - 23.0) * 0.5  # metres: -11.5 (west, blue) .. +12 (east, red), 0 at column 23
    error[0, 40:], error[1, 40:] = 100.0, -100.0  # 16 outliers (0.7%), clipped
    error[10, 10] = np.nan  # a valid post without an error: grey
    lim = error_colour_limit(error)
    assert lim == np.percentile(np.abs(error[np.isfinite(error)]), 99) == 12.0
    cmap = colormaps["RdBu_r"]
    e = error.ravel()[tm.vertex_post]
    for limit, path in ((None, tmp_path / "e.ply"), (4.0, tmp_path / "e4.ply")):
        export_mesh(tm, path, error, colour_kind="error", error_limit=limit)
        rgb = trimesh.load(path, process=False).visual.vertex_colors[:, :3].astype(int)
        o3_rgb = np.rint(np.asarray(o3d.io.read_triangle_mesh(str(path)).vertex_colors) * 255)
        np.testing.assert_array_equal(o3_rgb, rgb)
        a = limit or lim
        pos, neg, nan = e > 0, e < 0, np.isnan(e)
        assert np.all(rgb[pos, 0] > rgb[pos, 2]) and np.all(rgb[neg, 2] > rgb[neg, 0])
        assert np.all(rgb[e == 0] > 240)  # white at zero
        np.testing.assert_array_equal(rgb[nan], [NAN_RGB])
        # saturated at +-limit, and the colour map in between (uint8 rounding aside)
        red, blue = cmap(1.0, bytes=True)[:3], cmap(0.0, bytes=True)[:3]
        assert np.all(rgb[e >= a] == red) and np.all(rgb[e <= -a] == blue)
        assert (e >= a).sum() >= 8 and (e <= -a).sum() >= 8
        ok = ~nan
        mapped = cmap(np.clip((e[ok] / a + 1) / 2, 0, 1), bytes=True)[:, :3].astype(int)
        assert np.abs(rgb[ok] - mapped).max() <= 1
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", error, colour_kind="error", error_limit=0.0)
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", np.full(t.shape, np.nan), colour_kind="error")
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", np.stack([error] * 3), colour_kind="error")
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", truth, colour_kind="visibility")  # not codes
    with pytest.raises(InputError):
        export_mesh(tm, tmp_path / "x.ply", error, colour_kind="slope")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.ply", "e4.ply"]


def test_decimation_keeps_visibility_colours(tmp_path: Path, crater48: tuple) -> None:
    o3d = require_open3d()
    t, _, codes = crater48
    tm = terrain_mesh(t)
    target = 1000
    # posts whose 5 x 5 neighbourhood holds one code: a vertex moved by the decimation (or by
    # Open3D's float32) stays among posts of that code
    same = maximum_filter(codes, 5, mode="nearest") == minimum_filter(codes, 5, mode="nearest")
    for fmt in ("ply", "obj", "glb"):
        path = tmp_path / f"d.{fmt}"
        export_mesh(tm, path, codes, target_triangles=target, colour_kind="visibility")
        m = trimesh.load(path, force="mesh", process=False)
        assert 0.8 * target <= len(m.faces) <= 1.02 * target
        _, near = cKDTree(tm.world_vertices).query(m.vertices)
        post = tm.vertex_post[near]
        want = TABLE[codes.ravel()[post]]
        rgb = m.visual.vertex_colors[:, :3]
        # every colour is the table colour of its nearest post: no blends of two codes
        exact = (rgb == want).all(axis=1)
        assert exact[same.ravel()[post]].all() and exact.mean() > 0.99, exact.mean()
        if fmt == "ply":
            o3 = o3d.io.read_triangle_mesh(str(path))
            assert len(o3.triangles) == len(m.faces)
            np.testing.assert_array_equal(np.rint(np.asarray(o3.vertex_colors) * 255), rgb)


# ------------------------------------------------------------------------------ the command
def test_cli_mesh_colour_options(
    tmp_path: Path, crater48: tuple, capsys: pytest.CaptureFixture
) -> None:
    t, truth, codes = crater48
    # a fitted DEM: 3 m high in the east half, 3 m low in the west, NaN where unresolved
    c, _ = t.grid()
    fitted = t.values + np.where(c >= 24, 3.0, -3.0)
    t.write(tmp_path / "fitted.tif", fitted)
    t.write(tmp_path / "truth.tif", truth)
    # as `orthomvp visibility` writes it: uint8, nodata 0 (read back as NaN)
    write_geotiff(tmp_path / "vis.tif", codes, t.transform, t.crs, nodata=0)
    inputs = ["fitted.tif", "truth.tif", "vis.tif"]
    fit, tru, vis = (str(tmp_path / n) for n in inputs)
    n_vert, n_tri = expected_counts(np.isfinite(fitted))

    out = str(tmp_path / "err.ply")
    assert main(["mesh", fit, "-o", out, "--error-against", tru]) == 0
    assert "error colours: blue -3 m, white 0, red +3 m" in capsys.readouterr().out
    m = trimesh.load(out, process=False)
    assert (len(m.vertices), len(m.faces)) == (n_vert, n_tri)
    # the posts in row-major order, with the heights as written (float32)
    world = Terrain.read(fit).world_points()[np.isfinite(fitted)]
    np.testing.assert_allclose(m.vertices, world, rtol=0, atol=1e-6)
    east = (c >= 24)[np.isfinite(fitted)]
    rgb = m.visual.vertex_colors[:, :3]
    # every error is +-3 m, the limit: saturated red (DEM above the truth) and blue (below)
    red, blue = (colormaps["RdBu_r"](x, bytes=True)[:3] for x in (1.0, 0.0))
    assert np.all(rgb[east] == red) and np.all(rgb[~east] == blue)

    out = str(tmp_path / "vis.glb")
    assert main(["mesh", fit, "-o", out, "--texture", vis, "--colour-by", "visibility"]) == 0
    m = trimesh.load(out, force="mesh", process=False)
    tm = terrain_mesh(t.with_values(fitted))
    idx = match_vertices(m.vertices, tm.world_vertices, 1e-4)
    np.testing.assert_array_equal(sample_texture(m), TABLE[codes.ravel()[tm.vertex_post[idx]]])

    out = str(tmp_path / "lim.obj")
    args = ["mesh", fit, "-o", out, "--error-against", tru, "--error-limit", "6", "--local-origin"]
    assert main(args) == 0
    assert "blue -6 m" in capsys.readouterr().out
    assert {"lim.obj", "lim.mtl", "lim.png"} <= {p.name for p in tmp_path.iterdir()}

    capsys.readouterr()
    bad = str(tmp_path / "bad.ply")
    other = tmp_path / "other.tif"
    replace(t, values=truth[:-1]).write(other)  # one row short: another grid
    for args, words in (
        (["--error-against", str(other)], "not on the grid"),
        (["--texture", vis, "--colour-by", "error", "--error-limit", "-1"], "range x>0"),
        (["--texture", fit, "--colour-by", "visibility"], "codes"),
        (["--colour-by", "error"], "needs a raster"),
        (["--texture", vis, "--colour-by", "visibility", "--error-limit", "2"], "error colours"),
        (["--error-against", tru, "--colour-by", "image"], "height error"),
    ):
        assert main(["mesh", fit, "-o", bad, *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("orthomvp: error:") and words in err[0], err
    assert main(["mesh", fit, "-o", bad, "--texture", vis, "--error-against", tru]) == 2
    assert "not allowed with" in capsys.readouterr().err
    made = {"err.ply", "vis.glb", "lim.obj", "lim.mtl", "lim.png", "other.tif", *inputs}
    assert {p.name for p in tmp_path.iterdir()} == made
