"""Visibility on a grid finer than the DEM: the DEM's posts are classified, their codes are
carried to grid posts between four agreeing DEM posts, and only posts near class boundaries
are cast. The oracle is casting every grid post; the truth is marched on the analytic crater."""

from __future__ import annotations

import numpy as np
import pytest

from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.occlusion.mesh import occluder_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import make_scene
from orthomvp.synthetic.truth import visibility_truth


class CountingCaster(RayCaster):
    """A ray caster that counts the rays it casts."""

    rays = 0

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, **options):  # noqa: ANN201
        self.rays += len(np.atleast_2d(directions))
        return super().first_hit(origins, directions, **options)


@pytest.fixture(scope="module")
def scene():  # noqa: ANN201
    return make_scene("crater", size=64, spacing=80.0)


@pytest.mark.parametrize("factor", [3, 5])
def test_carried_codes_equal_casting_every_post_with_fewer_rays(scene, factor: int) -> None:  # noqa: ANN001
    dem, camera = scene.terrain, scene.cameras["oblique"]
    grid = dem.regrid((abs(dem.transform.a) / factor, abs(dem.transform.e) / factor))
    scale = float(np.mean(grid.post_spacing()) / np.mean(dem.post_spacing()))
    caster = CountingCaster(occluder_mesh(dem))
    every = compute_visibility(grid, camera, caster=caster, post_scale=scale)
    rays_every, caster.rays = caster.rays, 0
    carried = compute_visibility(grid, camera, caster=caster, post_scale=scale, dem=dem)
    assert (every.codes == Code.OCCLUDED).sum() > 1000  # the rim hides terrain
    np.testing.assert_array_equal(carried.codes, every.codes)
    np.testing.assert_array_equal(carried.uv, every.uv)
    assert caster.rays * 4 < rays_every  # DEM posts plus boundary posts only
    cast = np.isfinite(carried.miss)
    assert cast.sum() < 0.5 * np.isfinite(every.miss).sum()
    np.testing.assert_array_equal(carried.miss[cast], every.miss[cast])
    # against marched truth on the analytic surface: no ghost that casting avoids
    x, y = scene.surface.lonlat_to_local(*grid.pixel_to_lonlat(*grid.grid()))
    spacing = float(np.mean(dem.post_spacing()))
    truth = visibility_truth(
        camera,
        scene.surface.surface_point(x, y),
        scene.surface.surface_normal(x, y),
        scene.surface.below,
        scene.max_radius,
        spacing / 4,
    )
    ghosts = (carried.codes == Code.VISIBLE) & (truth == Code.OCCLUDED)
    assert ghosts.sum() <= ((every.codes == Code.VISIBLE) & (truth == Code.OCCLUDED)).sum()
    assert ghosts.sum() < 0.05 * (truth == Code.OCCLUDED).sum()


def test_the_dem_grid_itself_is_cast_as_before(scene) -> None:  # noqa: ANN001
    """On the DEM's own grid (post_scale 1) ``dem`` changes nothing."""
    dem, camera = scene.terrain, scene.cameras["oblique"]
    a = compute_visibility(dem, camera)
    b = compute_visibility(dem, camera, dem=dem)
    np.testing.assert_array_equal(a.codes, b.codes)
    np.testing.assert_array_equal(a.miss, b.miss)


@pytest.mark.parametrize("fields", [(), ("emission",), ("gsd", "miss")])
def test_visibility_computes_only_the_fields_asked_for(scene, fields: tuple) -> None:  # noqa: ANN001
    """Codes and positions are the same whatever is asked for; the fields asked for equal a
    full run's, bit for bit, and the others are read-only NaN."""
    dem, camera = scene.terrain, scene.cameras["oblique"]
    grid = dem.regrid((abs(dem.transform.a) / 3, abs(dem.transform.e) / 3))
    scale = float(np.mean(grid.post_spacing()) / np.mean(dem.post_spacing()))
    caster = RayCaster(occluder_mesh(dem))
    full = compute_visibility(grid, camera, caster=caster, post_scale=scale, dem=dem)
    some = compute_visibility(
        grid, camera, caster=caster, post_scale=scale, dem=dem, fields=frozenset(fields)
    )
    np.testing.assert_array_equal(some.codes, full.codes)
    np.testing.assert_array_equal(some.uv, full.uv)
    names = {"emission": ["emission"], "gsd": ["gsd"], "miss": ["miss", "eps"]}
    for field, attrs in names.items():
        for attr in attrs:
            got = getattr(some, attr)
            assert got.shape == full.codes.shape
            if field in fields:
                np.testing.assert_array_equal(got, getattr(full, attr))
                assert np.isfinite(got).any()
            else:
                assert np.isnan(got).all() and not got.flags.writeable
    with pytest.raises(InputError, match="fields"):
        compute_visibility(grid, camera, caster=caster, fields=frozenset({"normals"}))


def test_carried_codes_through_another_crs_equal_casting_every_post(scene) -> None:  # noqa: ANN001
    """A finer grid in another CRS of the body (equidistant cylindrical), wider than the DEM on
    every side (its edge posts have no height): the codes carried from the DEM's posts through
    the two CRSs are those of casting every grid post."""
    from affine import Affine
    from pyproj import CRS, Transformer

    from orthomvp.geometry.terrain import Terrain

    dem, camera = scene.terrain, scene.cameras["oblique"]
    eqc = CRS.from_proj4("+proj=eqc +R=1737400 +no_defs")
    to_eqc = Transformer.from_crs(dem.crs, eqc, always_xy=True)
    rows_dem, cols_dem = dem.shape
    corners = dem.transform @ (
        np.array([0, cols_dem, 0, cols_dem]),
        np.array([0, 0, rows_dem, rows_dem]),
    )
    left, bottom, right, top = to_eqc.transform_bounds(
        min(corners[0]), min(corners[1]), max(corners[0]), max(corners[1])
    )
    step = float(np.mean(dem.post_spacing())) / 3
    pad = 3 * step
    cols, rows = int((right - left + 2 * pad) / step), int((top - bottom + 2 * pad) / step)
    transform = Affine(step, 0, left - pad, 0, -step, top + pad)
    c, r = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    x, y = transform @ (c, r)
    lon, lat = Transformer.from_crs(eqc, dem.crs, always_xy=True).transform(x, y)
    values = dem.interpolate(*dem.crs_to_pixel(lon, lat))
    assert np.isnan(values[0]).all() and np.isfinite(values).mean() > 0.8
    grid = Terrain(values, transform, eqc)
    scale = step / float(np.mean(dem.post_spacing()))
    caster = CountingCaster(occluder_mesh(dem))
    every = compute_visibility(grid, camera, caster=caster, post_scale=scale)
    rays_every, caster.rays = caster.rays, 0
    carried = compute_visibility(grid, camera, caster=caster, post_scale=scale, dem=dem)
    assert (every.codes == Code.OCCLUDED).sum() > 1000
    np.testing.assert_array_equal(carried.codes, every.codes)
    assert caster.rays * 2 < rays_every
