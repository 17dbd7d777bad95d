"""The fused per-post geometry (:mod:`orthomvp.frame_kernel`) against the numpy path it
replaces: the same codes, misses and epsilons, positions to the last bits of float64."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from orthomvp.camera import BrownConradyDistortion
from orthomvp.synthetic.loader import load_scene
from orthomvp.visibility import compute_visibility, occluder_caster


def assert_same(a, b) -> None:  # noqa: ANN001 - two Visibility results
    np.testing.assert_array_equal(a.codes, b.codes)
    np.testing.assert_array_equal(a.miss, b.miss)
    np.testing.assert_array_equal(a.eps, b.eps)
    np.testing.assert_allclose(a.uv, b.uv, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.emission, b.emission, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.gsd, b.gsd, rtol=1e-12, atol=0)


def test_fused_equals_numpy_on_the_city(city_dir: Path) -> None:
    """Every view of the city (map frame, walls, holes-free), on its own grid and, with the
    codes carried from the DEM, on a grid three times finer."""
    scene = load_scene(city_dir)
    dem = scene.terrain
    caster = occluder_caster(dem)
    spacing = abs(dem.transform.a)
    fine = dem.regrid(res=(spacing / 3, spacing / 3))
    for view in scene.views.values():
        cam = view.camera
        a = compute_visibility(dem, cam, caster=caster, fused=False)
        b = compute_visibility(dem, cam, caster=caster, fused=True)
        assert_same(a, b)
        assert (a.codes == 2).sum() > 100 and (a.codes == 1).sum() > 1000
        kw = dict(caster=caster, post_scale=1 / 3, dem=dem)
        a = compute_visibility(fine, cam, fused=False, **kw)
        b = compute_visibility(fine, cam, fused=True, **kw)
        assert_same(a, b)
        # most posts take their code from the DEM posts around them, without a ray
        assert np.isnan(b.miss[b.codes == 1]).mean() > 0.5


def test_fused_falls_back_where_it_does_not_apply(city_dir: Path, crater_dir: Path) -> None:
    """A lens with distortion, or a body-fixed grid, takes the numpy path even when asked."""
    scene = load_scene(city_dir)
    cam = next(iter(scene.views.values())).camera
    lens = replace(cam, distortion=BrownConradyDistortion(0.0, 0.0, 1e-9, 0.0, 0.0, 0.0, 0.0, 0.0))
    caster = occluder_caster(scene.terrain)
    a = compute_visibility(scene.terrain, lens, caster=caster, fused=False)
    b = compute_visibility(scene.terrain, lens, caster=caster, fused=True)
    np.testing.assert_array_equal(a.uv, b.uv)
    crater = load_scene(crater_dir)
    cam = next(iter(crater.views.values())).camera
    a = compute_visibility(crater.terrain, cam, fused=False)
    b = compute_visibility(crater.terrain, cam, fused=True)
    np.testing.assert_array_equal(a.uv, b.uv)
