"""Visibility, orthophotos and mosaics on the crater scene, scored against marched truth."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS

from orthomvp.camera import PinholeCamera
from orthomvp.errors import GeometryError, InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector
from orthomvp.occlusion.visibility import compute_visibility, default_eps, occluder_caster
from orthomvp.ortho.composite import MosaicOptions, doubtful, trusted
from orthomvp.ortho.orthophoto import mosaic, orthorectify, sample_image
from orthomvp.ortho.support import blocked as support_blocked
from orthomvp.ortho.support import candidates, window_samples
from orthomvp.quality.eps_study import eps_study, reclassify
from orthomvp.synthetic import away_from_boundaries, classification_scores, load_scene, look_at


@pytest.fixture(scope="module")
def scene(crater_dir):
    return load_scene(crater_dir)


def test_visibility_f1_against_marched_truth(scene) -> None:
    view = scene.views["oblique"]
    vis = compute_visibility(scene.terrain, view.camera)
    keep = away_from_boundaries(view.truth)
    scores = classification_scores(vis.codes, view.truth, keep)
    assert scores["f1_visible"] >= 0.99, scores
    assert scores["f1_hidden"] >= 0.95, scores
    # the facing-away class on its own, and occlusion on its own
    for code in (2, 3):
        t, p = (view.truth == code) & keep, (vis.codes == code) & keep
        assert (t & p).sum() / max(t.sum(), 1) > 0.95
    nadir = compute_visibility(scene.terrain, scene.views["nadir"].camera)
    assert (nadir.codes == 1).all()


def test_orthophoto_has_no_ghosts_and_matches_radiance(scene) -> None:
    view = scene.views["oblique"]
    keep = away_from_boundaries(view.truth)
    hidden = np.isin(view.truth, (2, 3)) & keep
    ortho = orthorectify(scene.terrain, view.image, view.camera)
    naive = orthorectify(scene.terrain, view.image, view.camera, occlusion=False)
    ghosts = (np.isfinite(ortho.data[0]) & hidden).sum()
    assert hidden.sum() > 100
    assert ghosts <= 0.005 * hidden.sum(), f"{ghosts} ghosts among {hidden.sum()} hidden posts"
    assert np.isfinite(naive.data[0])[hidden].all()  # the naive orthophoto fills them all
    visible = (view.truth == 1) & keep & np.isfinite(ortho.data[0])
    corr = np.corrcoef(ortho.data[0][visible], scene.radiance[visible])[0, 1]
    assert corr >= 0.98, f"orthophoto vs true radiance: r = {corr:.4f}"
    assert ortho.transform == scene.terrain.transform and ortho.data.dtype == np.float32


def test_mosaic_fills_hidden_posts(scene) -> None:
    oblique, nadir = scene.views["oblique"], scene.views["nadir"]
    views = [(oblique.image, oblique.camera), (nadir.image, nadir.camera)]
    plain = MosaicOptions(seamlines=False, blend=0)
    result = mosaic(scene.terrain, views, options=plain)
    hidden = np.isin(oblique.truth, (2, 3)) & away_from_boundaries(oblique.truth)
    filled = np.isfinite(result.data[0])[hidden].mean()
    assert filled >= 0.99
    assert (result.source[hidden] == 2).all()
    # where both see a post and trust it alike (samples clear of occluders in the image near
    # occlusion boundaries included), the smaller emission angle wins
    vis = result.visibilities
    seen = np.array([v.codes == 1 for v in vis])
    doubt = np.array([doubtful(v.miss, v.eps) for v in vis])
    tests = candidates(seen & ~doubt)
    caster, whole = occluder_caster(scene.terrain), (slice(None), slice(None))
    blocked = np.zeros(seen.shape, bool)
    for k, (v, (_, cam)) in enumerate(zip(vis, views, strict=True)):
        test = tests[k]
        blocked[k] = support_blocked(
            scene.terrain, whole, cam, window_samples(v.uv, v.gsd), v.emission, test, caster
        )
    assert blocked.any()
    trust = trusted(seen, doubt, blocked)
    both = trust[0] & trust[1]
    assert both.sum() > 0.5 * (seen[0] & seen[1]).sum()
    e0, e1 = result.visibilities[0].emission, result.visibilities[1].emission
    np.testing.assert_array_equal(result.source[both], np.where(e0 < e1, 1, 2)[both])
    visible = np.isfinite(result.data[0]) & away_from_boundaries(oblique.truth)
    assert np.corrcoef(result.data[0][visible], scene.radiance[visible])[0, 1] > 0.98
    # the default (seamlines, 8-post feather) fills the same posts, as faithfully
    seamless = mosaic(scene.terrain, views)
    np.testing.assert_array_equal(np.isfinite(seamless.data), np.isfinite(result.data))
    assert np.corrcoef(seamless.data[0][visible], scene.radiance[visible])[0, 1] > 0.98


def test_eps_rule_and_study(crater_dir) -> None:
    np.testing.assert_array_equal(default_eps(np.array([0.5, 4.0, 7.5])), [3.0, 4.0, 7.5])
    rows = eps_study(crater_dir, eps_values=(0.05, 4.0, 500.0))
    oblique = {r["eps"]: r for r in rows if r["view"] == "oblique"}
    assert oblique["default"]["f1_visible"] >= 0.99
    # an epsilon larger than the tile lets every occluded post through: recall of hidden drops
    assert oblique[500.0]["recall_hidden"] < oblique[4.0]["recall_hidden"]


def test_reclassify_matches_a_fresh_run(scene) -> None:
    view = scene.views["oblique"]
    vis = compute_visibility(scene.terrain, view.camera)
    again = compute_visibility(scene.terrain, view.camera, eps=1.5)
    np.testing.assert_array_equal(reclassify(vis, 1.5), again.codes)


def test_sample_image_against_exact_bilinear() -> None:
    rng = np.random.default_rng(0)
    img = rng.random((2, 30, 40)).astype(np.float32)
    uv = np.column_stack([rng.uniform(0, 39, 500), rng.uniform(0, 29, 500)])
    out = sample_image(img, uv, "bilinear")
    c0, r0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    fx, fy = uv[:, 0] - c0, uv[:, 1] - r0
    c1, r1 = np.minimum(c0 + 1, 39), np.minimum(r0 + 1, 29)
    for b in range(2):
        i = img[b]
        expected = (
            i[r0, c0] * (1 - fx) * (1 - fy)
            + i[r0, c1] * fx * (1 - fy)
            + i[r1, c0] * (1 - fx) * fy
            + i[r1, c1] * fx * fy
        )
        np.testing.assert_allclose(out[b], expected, atol=2e-3)  # cv2 uses 5-bit weights
    nearest = sample_image(img, np.array([[3.2, 4.7], [np.nan, 1.0], [-5.0, 2.0]]), "nearest")
    assert nearest[0, 0] == img[0, 5, 3] and np.isnan(nearest[:, 1:]).all()


def test_sample_image_on_a_grid_longer_than_a_remap_map() -> None:
    """A grid of positions with a side beyond what cv2.remap's map takes is laid out in rows
    instead, with the same values."""
    rng = np.random.default_rng(3)
    img = rng.random((1, 20, 30)).astype(np.float32)
    uv = np.stack([rng.uniform(0, 29, (40000, 1)), rng.uniform(0, 19, (40000, 1))], -1)
    uv = uv.astype(np.float32)
    got = sample_image(img, uv, "bilinear")
    assert got.shape == (1, 40000, 1)
    np.testing.assert_array_equal(got[:, :, 0], sample_image(img, uv[:, 0], "bilinear"))


def test_sample_image_cubic_against_keys_kernel() -> None:
    """Cubic samples against OpenCV's cubic convolution (Keys, a = -0.75) evaluated here:
    finite wherever the 4 x 4 taps lie in the image (OpenCV 5.0's own NaN border gave NaN far
    inside the image), NaN where a tap lies outside."""
    rng = np.random.default_rng(1)
    img = rng.random((2, 30, 40)).astype(np.float32)
    uv = np.column_stack([rng.uniform(-4, 43, 3000), rng.uniform(-4, 33, 3000)])
    out = sample_image(img, uv, "cubic")

    def keys(t: np.ndarray) -> np.ndarray:
        t, a = np.abs(t), -0.75
        near = ((a + 2) * t - (a + 3)) * t * t + 1
        far = ((a * t - 5 * a) * t + 8 * a) * t - 4 * a
        return np.where(t <= 1, near, np.where(t < 2, far, 0.0))

    c0, r0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (c0 >= 1) & (c0 + 2 <= 39) & (r0 >= 1) & (r0 + 2 <= 29)
    assert inside.sum() > 1500 and (~inside).sum() > 500
    assert np.isfinite(out[:, inside]).all() and np.isnan(out[:, ~inside]).all()
    for b in range(2):
        expected = np.zeros(inside.sum())
        for i in range(-1, 3):
            for j in range(-1, 3):
                w = keys(uv[inside, 0] - (c0[inside] + j)) * keys(uv[inside, 1] - (r0[inside] + i))
                expected += w * img[b, r0[inside] + i, c0[inside] + j]
        np.testing.assert_allclose(out[b, inside], expected, atol=3e-3)  # 5-bit positions


@pytest.mark.parametrize("interp", ["nearest", "bilinear", "cubic"])
def test_sample_image_on_a_grid_of_positions_samples_as_a_list_of_them(interp: str) -> None:
    """A (rows, cols, 2) float32 grid of positions is cv2.remap's map as it is; the values are
    those of the same positions as a list (laid out in rows of 4096), NaN positions and
    positions outside the image giving NaN."""
    rng = np.random.default_rng(5)
    img = rng.random((3, 60, 80)).astype(np.float32)
    uv = np.stack([rng.uniform(-3, 82, (37, 53)), rng.uniform(-3, 62, (37, 53))], -1)
    uv = uv.astype(np.float32)
    uv[5, 7] = np.nan
    uv[6, 8, 1] = np.nan
    grid = sample_image(img, uv, interp)
    listed = sample_image(img, uv.reshape(-1, 2), interp).reshape(3, 37, 53)
    assert grid.shape == (3, 37, 53)
    np.testing.assert_array_equal(grid, listed)
    assert np.isnan(grid[:, 5, 7]).all() and np.isnan(grid[:, 6, 8]).all()
    outside = (uv[..., 0] < -1) | (uv[..., 0] > 81) | (uv[..., 1] < -1) | (uv[..., 1] > 61)
    assert outside.any() and np.isnan(grid[:, outside]).all()
    assert np.isfinite(grid[:, ~outside & np.isfinite(uv).all(-1)]).mean() > 0.8
    # into a given array: the grid's (its map's own) and the list's (laid out in rows)
    for positions, want in ((uv, grid), (uv.reshape(-1, 2), listed.reshape(3, -1))):
        out = np.zeros(want.shape, np.float32)
        assert sample_image(img, positions, interp, out=out) is out
        np.testing.assert_array_equal(out, want)
    with pytest.raises(InputError, match="samples go into a C-contiguous float32"):
        sample_image(img, uv, interp, out=np.zeros((3, 37, 52), np.float32))
    with pytest.raises(InputError, match="not contiguous"):
        sample_image(img, uv, interp, out=np.zeros((3, 53, 37), np.float32).transpose(0, 2, 1))


def _flat_terrain() -> Terrain:
    step = np.degrees(50.0 / 1737400.0)
    return Terrain(
        np.zeros((40, 40)),
        Affine(step, 0, 10.0, 0, -step, 0.5),
        CRS.from_proj4("+proj=longlat +R=1737400"),
    )


def _camera_at(terrain: Terrain, height: float, offset_m: float = 0.0) -> PinholeCamera:
    lon, lat = terrain.pixel_to_lonlat(np.array(19.5), np.array(19.5))
    up = unit_vector(lon, lat)
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.cross(up, east)
    target = 1737400.0 * up + offset_m * east
    centre = (1737400.0 + height) * up + offset_m * east
    return PinholeCamera(
        2000.0, 2000.0, 100.0, 100.0, centre, look_at(centre, target, north), width=200, height=200
    )


def test_bad_geometry_is_reported() -> None:
    terrain = _flat_terrain()
    good = _camera_at(terrain, 100_000.0)
    assert (compute_visibility(terrain, good).codes == 1).all()
    below = _camera_at(terrain, -5_000.0)
    with pytest.raises(GeometryError, match="behind|below|faces away"):
        compute_visibility(terrain, below)
    aside = _camera_at(terrain, 100_000.0, offset_m=60_000.0)
    with pytest.raises(GeometryError, match="does not cover"):
        compute_visibility(terrain, aside)
    with pytest.raises(InputError, match="image size"):
        compute_visibility(terrain, good.with_image_size(None, None))
    with pytest.raises(InputError, match="eps"):
        compute_visibility(terrain, good, eps=-1.0)
    image = np.ones((1, 100, 100), np.float32)
    with pytest.raises(InputError, match="camera says"):
        orthorectify(terrain, image, good)


def test_partial_coverage_and_holes() -> None:
    terrain = _flat_terrain()
    values = terrain.values.copy()
    values[5:9, 5:9] = np.nan
    terrain = terrain.with_values(values)
    cam = _camera_at(terrain, 100_000.0).with_image_size(110, 200)  # cuts off the east side
    image = np.ones((3, 200, 110), np.float32)
    ortho = orthorectify(terrain, image, cam)
    codes = ortho.visibility.codes
    assert np.isnan(ortho.data[:, 5:9, 5:9]).all() and (codes[5:9, 5:9] == 0).all()
    # posts next to the hole keep a normal (one-sided differences) and stay visible
    assert (codes[4, 4:10] == 1).all() and (codes[9, 4:10] == 1).all()
    assert (codes[:, :25] != 0).sum() == 25 * 40 - 16 and (codes[:, -5:] == 0).all()
    assert ortho.data.shape == (3, 40, 40)


def test_lens_distortion_is_followed(scene) -> None:
    """A distorted camera with the same pose sees the same posts: the test back-projects the
    distorted pixel with the camera's own (distortion-aware) ray, so the round trip holds."""
    from dataclasses import replace

    from orthomvp.camera import TsaiDistortion

    view = scene.views["oblique"]
    cam = view.camera
    lens = replace(cam, distortion=TsaiDistortion(k1=300.0, k2=0.0, p1=0.05, p2=-0.03))
    plain = compute_visibility(scene.terrain, cam)
    bent = compute_visibility(scene.terrain, lens)
    both = (plain.codes != 0) & (bent.codes != 0)
    assert both.mean() > 0.9
    np.testing.assert_array_equal(plain.codes[both], bent.codes[both])
    # uv moved by the distortion, by up to several pixels, consistently with project()
    shift = np.linalg.norm(bent.uv - plain.uv, axis=-1)
    assert np.nanmax(shift) > 1.0
    uv, _ = lens.project(scene.terrain.world_points())
    np.testing.assert_allclose(bent.uv[both], uv[both], atol=1e-9)


def test_a_visibility_of_another_camera_or_grid_is_refused(scene) -> None:
    """orthorectify(visibility=...) takes only the visibility of its own camera and terrain:
    another camera's paints its codes (ghosts) on this image, another grid's has another
    shape; both are InputErrors, and the visibility's own is accepted and used as is."""
    oblique, nadir = scene.views["oblique"], scene.views["nadir"]
    own = compute_visibility(scene.terrain, oblique.camera)
    reused = orthorectify(scene.terrain, oblique.image, oblique.camera, visibility=own)
    np.testing.assert_array_equal(
        reused.data, orthorectify(scene.terrain, oblique.image, oblique.camera).data
    )
    other = compute_visibility(scene.terrain, nadir.camera)
    with pytest.raises(InputError, match="visibility is not of this camera and terrain: at post"):
        orthorectify(scene.terrain, oblique.image, oblique.camera, visibility=other)
    smaller = scene.terrain.crop(0, 48, 0, 48)
    with pytest.raises(InputError, match=r"visibility is of a 48 x 48 grid, the terrain is 64 x"):
        orthorectify(
            scene.terrain,
            oblique.image,
            oblique.camera,
            visibility=compute_visibility(smaller, oblique.camera),
        )
    # the same grid with other heights: the positions move
    raised = scene.terrain.with_values(scene.terrain.values + 500.0)
    with pytest.raises(InputError, match="not of this camera and terrain"):
        orthorectify(raised, oblique.image, oblique.camera, visibility=own)
