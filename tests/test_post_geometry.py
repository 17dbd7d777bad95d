"""The separable per-post geometry (:func:`orthomvp.occlusion.post_geometry.separable`) against the
general path: the same codes, misses and epsilons, emission angles and GSDs to the bit,
positions to the last bits of float64."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from affine import Affine

from orthomvp.camera import BrownConradyDistortion
from orthomvp.occlusion.paths import Geometry, VisibilityPath
from orthomvp.occlusion.post_geometry import general, image_window, separable, separable_applies
from orthomvp.occlusion.visibility import compute_visibility, occluder_caster
from orthomvp.synthetic.loader import load_scene

GENERAL = VisibilityPath(geometry=Geometry.GENERAL)  # the oracle of the separable geometry
KERNEL = VisibilityPath(geometry=Geometry.SEPARABLE_KERNEL)  # that the numpy one tests


def assert_same(a, b) -> None:  # noqa: ANN001 - two Visibility results
    np.testing.assert_array_equal(a.codes, b.codes)
    np.testing.assert_array_equal(a.miss, b.miss)
    np.testing.assert_array_equal(a.eps, b.eps)
    np.testing.assert_allclose(a.uv, b.uv, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.emission, b.emission)
    np.testing.assert_array_equal(a.gsd, b.gsd)


@pytest.fixture(scope="module")
def city_grids(city_dir: Path) -> tuple:
    """The city's DEM, a ray caster on it, the DEM with holes, a grid three times finer, and
    the scene's cameras."""
    scene = load_scene(city_dir)
    dem = scene.terrain
    spacing = abs(dem.transform.a)
    values = dem.values.copy()
    values[20:23, 30:41] = np.nan
    values[5, 5] = np.nan
    fine = dem.regrid(res=(spacing / 3, spacing / 3))
    cameras = [view.camera for view in scene.views.values()]
    return dem, occluder_caster(dem), dem.with_values(values), fine, cameras


def test_separable_equals_general_on_the_city(city_grids: tuple) -> None:
    """Every view of the city (map frame, walls), on its own grid, with holes, and, with the
    codes carried from the DEM, on a grid three times finer."""
    dem, caster, holes, fine, cameras = city_grids
    for cam in cameras:
        a = compute_visibility(dem, cam, caster=caster, path=GENERAL)
        b = compute_visibility(dem, cam, caster=caster)
        assert_same(a, b)
        assert (a.codes == 2).sum() > 100 and (a.codes == 1).sum() > 1000
        a = compute_visibility(holes, cam, caster=caster, path=GENERAL)
        b = compute_visibility(holes, cam, caster=caster)
        assert_same(a, b)
        assert (a.codes[19:24, 29:42] == 0).sum() > 33  # the hole and the posts beside it
        kw = dict(caster=caster, post_scale=1 / 3, dem=dem)
        a = compute_visibility(fine, cam, path=GENERAL, **kw)
        b = compute_visibility(fine, cam, **kw)
        assert_same(a, b)
        # most posts take their code from the DEM posts around them, without a ray
        assert np.isnan(b.miss[b.codes == 1]).mean() > 0.5


@pytest.mark.parametrize("flip", [False, True])
def test_separable_tile_field_by_field(city_dir: Path, flip: bool) -> None:
    """One tile's geometry, field by field, on the city's north-up grid and on the same grid
    stored south-up (rows running north): eastings are one row, northings one column."""
    scene = load_scene(city_dir)
    dem = scene.terrain
    rows, cols = dem.shape
    if flip:
        t = dem.transform
        dem = replace(
            dem, values=dem.values[::-1].copy(), transform=t @ Affine(1, 0, 0, 0, -1, rows)
        )
    cam = next(iter(scene.views.values())).camera
    tile = (slice(3, rows - 2), slice(0, cols))
    a, b = general(dem, cam, *tile), separable(dem, cam, *tile)
    assert b.x.shape == (1, cols) and b.y.shape == (rows - 5, 1)
    for name in ("x", "y", "z", "ok", "inside", "cos_e", "facing_gsd"):
        got = np.broadcast_to(getattr(b, name), a.z.shape)
        np.testing.assert_array_equal(getattr(a, name), got, err_msg=name)
    np.testing.assert_allclose(a.uv, b.uv, rtol=0, atol=1e-9)
    assert a.inside.sum() > 1000


def test_general_path_where_separable_does_not_apply(city_dir: Path, crater_dir: Path) -> None:
    """A lens with distortion, or a body-fixed grid, takes the general path whatever the
    :class:`VisibilityPath` allows (the numba kernel too)."""
    scene = load_scene(city_dir)
    cam = next(iter(scene.views.values())).camera
    lens = replace(cam, distortion=BrownConradyDistortion(0.0, 0.0, 1e-9, 0.0, 0.0, 0.0, 0.0, 0.0))
    caster = occluder_caster(scene.terrain)
    a = compute_visibility(scene.terrain, lens, caster=caster, path=GENERAL)
    b = compute_visibility(scene.terrain, lens, caster=caster, path=KERNEL)
    np.testing.assert_array_equal(a.uv, b.uv)
    crater = load_scene(crater_dir)
    cam = next(iter(crater.views.values())).camera
    a = compute_visibility(crater.terrain, cam, path=GENERAL)
    b = compute_visibility(crater.terrain, cam, path=KERNEL)
    np.testing.assert_array_equal(a.uv, b.uv)


def test_image_window_bounds_the_posts_in_the_image(city_dir: Path) -> None:
    """A camera cropped to a corner of its image sees part of the city: the window holds
    every post the general path finds in the image, is smaller than the grid, and the fast
    path (which works only inside it) gives the general path's result everywhere."""
    scene = load_scene(city_dir)
    dem = scene.terrain
    caster = occluder_caster(dem)
    for view in scene.views.values():
        cam = view.camera
        corner = cam.crop(0, 0, cam.width // 2, cam.height // 3)
        a = compute_visibility(dem, corner, caster=caster, path=GENERAL)
        b = compute_visibility(dem, corner, caster=caster)
        assert_same(a, b)
        r0, r1, c0, c1 = image_window(dem, corner)
        rows, cols = np.nonzero(a.codes)
        assert len(rows) > 100
        assert r0 <= rows.min() and rows.max() < r1 and c0 <= cols.min() and cols.max() < c1
        assert (r1 - r0) * (c1 - c0) < 0.7 * dem.values.size


def assert_identical(a, b) -> None:  # noqa: ANN001 - two Visibility results
    for name in ("codes", "uv", "miss", "eps", "emission", "gsd"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_fused_kernel_equals_numpy_on_the_city(city_grids: tuple) -> None:
    """The numba kernel (``Geometry.SEPARABLE_KERNEL``) gives the numpy path's codes, misses,
    epsilons, positions, emission angles and GSDs bit for bit: every view of the city on its
    grid, with holes, without occlusion, and on a grid three times finer with the codes carried
    from the DEM (most posts without a ray), split in tiles of 7 posts (every tile's border)."""
    import orthomvp.occlusion.visibility as visibility

    dem, caster, holes, fine, cameras = city_grids
    for cam in cameras:
        for terrain, kw in (
            (dem, {}),
            (holes, {}),
            (dem, {"occlusion": False}),
            (fine, {"post_scale": 1 / 3, "dem": dem}),
        ):
            a = compute_visibility(terrain, cam, caster=caster, **kw)
            b = compute_visibility(terrain, cam, caster=caster, path=KERNEL, **kw)
            assert_identical(a, b)
        assert separable_applies(terrain, cam) and (a.codes == 2).sum() > 1000
        assert np.isnan(b.miss[b.codes == 1]).mean() > 0.5
    # a crop of the image: its window is a part of the grid, NaN and NODATA around it
    w, h = cam.width, cam.height
    part = cam.crop(2 * w // 5, 2 * h // 5, w // 5, h // 5)
    r0, r1, c0, c1 = image_window(dem, part)
    outside = np.ones(dem.shape, bool)
    outside[r0:r1, c0:c1] = False
    assert 0 < (r1 - r0) * (c1 - c0) < dem.shape[0] * dem.shape[1] / 2
    a = compute_visibility(dem, part, caster=caster, path=VisibilityPath(strict=False))
    b = compute_visibility(dem, part, caster=caster, path=replace(KERNEL, strict=False))
    assert_identical(a, b)
    assert np.isnan(b.uv[outside]).all() and (b.codes[outside] == 0).all()
    tile, visibility.TILE = visibility.TILE, 7
    try:
        a = compute_visibility(holes, cam, caster=caster)
        b = compute_visibility(holes, cam, caster=caster, path=KERNEL)
    finally:
        visibility.TILE = tile
    assert_identical(a, b)


@pytest.mark.parametrize("flip", [False, True])
def test_fused_kernel_tile_field_by_field(city_dir: Path, flip: bool) -> None:
    """The kernel's geometry of one tile, field by field, equals :func:`separable`'s (pixels
    where inside the image, NaN elsewhere), on the city's grid north-up and south-up, with a
    hole; its first codes are NODATA outside, FACING_AWAY or VISIBLE, rays where visible."""
    from orthomvp.occlusion.post_geometry_kernel import classify_tile

    scene = load_scene(city_dir)
    dem = scene.terrain
    rows, cols = dem.shape
    values = dem.values.copy()
    values[10:12, 4:9] = np.nan
    dem = dem.with_values(values)
    if flip:
        t = dem.transform
        dem = replace(
            dem, values=dem.values[::-1].copy(), transform=t @ Affine(1, 0, 0, 0, -1, rows)
        )
    for cam in (v.camera for v in scene.views.values()):
        tile = (slice(3, rows - 2), slice(0, cols))
        a = separable(dem, cam, *tile)
        b, codes, cast = classify_tile(dem, cam, *tile, occlusion=True)
        for name in ("x", "y", "z", "ok", "inside", "cos_e", "facing_gsd"):
            got, want = np.broadcast_arrays(getattr(b, name), getattr(a, name))
            np.testing.assert_array_equal(got, want, err_msg=name)
        want_uv = np.where(a.inside[..., None], a.uv, np.nan)
        np.testing.assert_array_equal(b.uv, want_uv)
        facing = a.cos_e > 0
        np.testing.assert_array_equal(codes, np.where(a.inside, np.where(facing, 1, 3), 0))
        np.testing.assert_array_equal(cast, a.inside & facing)
        assert a.inside.sum() > 1000 and (~a.ok).sum() >= 10


def test_fused_grid_heights_equal_interpolate_grid() -> None:
    """The kernel's grid heights equal :meth:`Terrain.interpolate_grid` bit for bit: a hole,
    positions beyond every edge and on the last post (a Terrain holds float64 heights)."""
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.occlusion.post_geometry_kernel import interpolate_grid

    rng = np.random.default_rng(3)
    values = rng.random((60, 70)) * 1000
    values[30:32, 40:43] = np.nan
    dem = Terrain(values=values, transform=Affine(24, 0, 0, 0, -24, 0), crs="EPSG:32735")
    c = np.concatenate([np.linspace(-3, 72, 301), [69.0]])
    r = np.concatenate([np.linspace(-2, 61, 257), [59.0]])
    want = dem.interpolate_grid(c, r)
    got = interpolate_grid(dem, c, r)
    np.testing.assert_array_equal(got, want, strict=True)
    assert np.isnan(want).any() and np.isfinite(want).mean() > 0.8
