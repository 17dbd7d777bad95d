"""The MVP plane fitter against analytic synthetic truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from orthomvp.errors import GeometryError, InputError
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import ViewStack
from orthomvp.mvp.plane import post_lines
from orthomvp.mvp.window import Window
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import make_scene


@pytest.fixture(scope="module")
def planar():  # noqa: ANN201
    scene = make_scene("planar", size=48)
    cams = list(scene.cameras.values())
    return scene, cams, [scene.render(cam, 2) for cam in cams]


@pytest.fixture(scope="module")
def hills():  # noqa: ANN201
    scene = make_scene("hills", size=72)
    cams = list(scene.cameras.values())
    truth = scene.terrain.values
    start = scene.terrain.with_values(ndimage.gaussian_filter(truth, 3) + 15.0)
    return scene, cams, [scene.render(cam, 2) for cam in cams], start


def _objective_along(model, stack, theta, window, axis, values):  # noqa: ANN001, ANN202
    """f at copies of ``theta`` (1, 3) with parameter ``axis`` set to each of ``values``."""
    th = np.repeat(theta, len(values), axis=0)
    th[:, axis] = values
    sub = model.take(np.zeros(len(values), int))
    H, _ = sub.homographies(th, 0, derivatives=False)
    return stack.evaluate(0, H, np.ones((len(values), H.shape[1]), bool), window).cost


def test_planar_objective_minima_at_the_true_plane(planar) -> None:  # noqa: ANN001
    """Paper section 4.3: along h the minimum of f lies at the true height within 0.05 ground
    pixels; over orientations at the true normal within 0.5 degrees."""
    scene, cams, images = planar
    gsd = scene.gsd
    n_true = np.array(scene.facts["plane_normal"])
    stack = ViewStack.build(images, cams, 1)
    window = Window(10, 5.0)
    for c, r in ((20, 22), (27, 25), (24, 30)):
        h_true = scene.terrain.values[r, c]
        lines = post_lines(scene.terrain, np.array([c], float), np.array([r], float), [h_true])
        model = PlaneModel(lines, n_true[None], stack.F, scene.spacing)
        theta = np.array([[h_true, 0.0, 0.0]])
        hs = h_true + np.linspace(-2, 2, 81) * gsd
        f = _objective_along(model, stack, theta, window, 0, hs)
        i = int(np.argmin(f))
        a, b, _ = np.polyfit(hs[i - 3 : i + 4] - h_true, f[i - 3 : i + 4], 2)
        assert abs(-b / (2 * a)) < 0.05 * gsd
        assert f[0] > 10 * f[i] and f[-1] > 10 * f[i]  # a well-defined minimum
        # orientation: a grid of tilts of +-3 degrees around the true normal
        t = np.tan(np.radians(np.linspace(-3, 3, 25)))
        aa, bb = np.meshgrid(t, t)
        th = np.repeat(theta, aa.size, axis=0)
        th[:, 1], th[:, 2] = aa.ravel(), bb.ravel()
        H, _ = model.take(np.zeros(aa.size, int)).homographies(th, 0, derivatives=False)
        cost = stack.evaluate(0, H, np.ones((aa.size, 4), bool), window).cost
        j = int(np.argmin(cost))
        n_min = model.take([0]).normal(th[j : j + 1])[0]
        assert np.degrees(np.arccos(min(1.0, n_min @ n_true))) < 0.5


def test_planar_fit_converges_to_the_true_plane(planar) -> None:  # noqa: ANN001
    scene, cams, images = planar
    gsd = scene.gsd
    truth = scene.terrain.values
    n_true = np.array(scene.facts["plane_normal"])
    res = fit_dem(scene.terrain.with_values(truth + 20.0), images, cams, FitOptions(deconvolve=0))
    ok = res.resolved
    assert ok.sum() > 1000 and res.converged[ok].all()
    err = np.abs(res.heights - truth)[ok]
    assert np.median(err) < 0.05 * gsd and np.percentile(err, 95) < 0.1 * gsd
    angle = np.degrees(np.arccos(np.clip(res.normals[ok] @ n_true, -1, 1)))
    assert np.median(angle) < 0.5
    np.testing.assert_allclose(
        res.n_theta[ok], np.degrees(np.arctan2(*res.normals[ok][:, 1::-1].T))
    )
    # posts without a full window inside two images are left unresolved, not guessed
    assert np.isnan(res.heights[0, 0]) and res.views[0, 0] == 0


@pytest.mark.slow
def test_uncertainty_follows_image_noise(planar) -> None:  # noqa: ANN001
    """On the exact plane model, sigma_h grows with image noise and is within a factor of 3 of
    the actual height error (it assumes independent samples; bilinear samples at one post
    spacing are correlated, so it runs about 2x optimistic here)."""
    scene, cams, images = planar
    truth = scene.terrain.values
    rng = np.random.default_rng(1)
    rows = []
    for noise in (0.01, 0.03):
        noisy = [im + rng.normal(0, noise, im.shape).astype(np.float32) for im in images]
        res = fit_dem(
            scene.terrain.with_values(truth + 20.0), noisy, cams, FitOptions(deconvolve=0)
        )
        ok = res.resolved
        actual = np.sqrt(np.mean((res.heights - truth)[ok] ** 2))
        predicted = np.sqrt(np.mean(res.sigma_h[ok] ** 2))
        assert predicted / 3 < actual < 3 * predicted
        rows.append(predicted)
    assert 2.0 < rows[1] / rows[0] < 4.0  # about linear in the noise


@pytest.mark.slow
def test_hills_from_a_smoothed_offset_dem(hills) -> None:  # noqa: ANN001
    """RMSE against the analytic truth, posts with >= 2 views, 12 posts from the border:
    at most 0.3 of the initial RMSE and at most 0.5 ground pixels."""
    scene, cams, images, start = hills
    truth = scene.terrain.values
    gsd = scene.gsd
    res = fit_dem(start, images, cams)
    keep = np.zeros(truth.shape, bool)
    keep[12:-12, 12:-12] = True
    keep &= res.views >= 2
    assert keep.sum() > 0.9 * 48 * 48
    rmse0 = np.sqrt(np.mean((start.values - truth)[keep] ** 2))
    rmse = np.sqrt(np.mean((res.heights - truth)[keep] ** 2))
    plane = np.sqrt(np.mean((res.plane_heights - truth)[keep] ** 2))
    assert 10 < rmse0 < 25
    assert rmse <= 0.3 * rmse0 and rmse <= 0.5 * gsd, (rmse0, rmse, plane)
    assert rmse < plane  # the window deconvolution helps on curved terrain


@pytest.mark.slow
def test_outlier_view_is_dropped(hills) -> None:  # noqa: ANN001
    """A bright blob with its own texture in one of four images: with rejection the heights
    under it are as good as around it; without, measurably worse."""
    scene, cams, images, start = hills
    truth = scene.terrain.values
    k = 1  # fore1
    r, c = np.mgrid[0:72, 0:72]
    dist = np.hypot(r - 36, c - 36)
    disk = dist <= 9
    xyz = scene.terrain.to_world(c[disk].astype(float), r[disk].astype(float), truth[disk])
    uv, _ = cams[k].project(xyz)
    img = images[k].copy()
    vv, uu = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    centre = uv.mean(axis=0)
    blob = np.hypot(uu - centre[0], vv - centre[1]) <= np.hypot(*(uv - centre).T).max() + 3
    noise = ndimage.gaussian_filter(np.random.default_rng(5).normal(size=img.shape), 1.5)
    img[blob] = (0.9 + 0.3 * noise)[blob]
    corrupted = [*images[:k], img.astype(np.float32), *images[k + 1 :]]
    inner, ring = dist <= 6, (dist > 14) & (dist < 24)
    out = {}
    for reject in (0.5, None):
        res = fit_dem(start, corrupted, cams, FitOptions(reject_below=reject))
        e = res.heights - truth
        out[reject] = [np.sqrt(np.nanmean(e[m & res.resolved] ** 2)) for m in (inner, ring)]
        if reject:
            assert not res.view_mask[k][inner].any()  # dropped under the blob
            assert res.view_mask[k][ring].mean() > 0.8  # kept elsewhere (windows reach the blob)
    assert out[0.5][0] < 1.2 * out[0.5][1]
    assert out[None][0] > 1.3 * out[0.5][0]


@pytest.mark.slow
def test_crater_hidden_views_stay_out(crater_dir) -> None:  # noqa: ANN001
    """Posts hidden in one view and visible in >= 2 others are fitted without the hidden
    view; feeding the hidden views in as well biases them badly."""
    from orthomvp.synthetic import load_scene

    data = load_scene(crater_dir)
    views = list(data.views.values())
    truth = data.terrain.values
    start = data.terrain.with_values(truth + 10.0)
    images = [v.image for v in views]
    cams = [v.camera for v in views]
    codes = np.stack([compute_visibility(start, cam).codes for cam in cams])
    true_codes = np.stack([v.truth for v in views])
    posts = ((true_codes == 2).sum(0) >= 1) & ((true_codes == 1).sum(0) >= 2)
    opts = FitOptions(hwin=6, sigma=3.0, reject_below=None)
    rmse = {}
    for name, visible in (("visible", codes == 1), ("hidden too", np.isin(codes, (1, 2)))):
        res = fit_dem(start, images, cams, opts, visible=visible)
        ok = posts & res.resolved
        assert ok.sum() > 100
        rmse[name] = np.sqrt(np.mean((res.heights - truth)[ok] ** 2))
        if name == "visible":
            used_hidden = res.view_mask & (codes == 2)
            assert not used_hidden.any()
    assert rmse["hidden too"] > 2.5 * rmse["visible"], rmse


def test_bad_input(planar) -> None:  # noqa: ANN001
    scene, cams, images = planar
    with pytest.raises(InputError, match="at least 2"):
        fit_dem(scene.terrain, images[:1], cams[:1])
    with pytest.raises(InputError, match="hwin"):
        fit_dem(scene.terrain, images, cams, FitOptions(hwin=0))
    nobody = np.zeros((4, *scene.terrain.shape), bool)
    with pytest.raises(GeometryError, match="2 or more"):
        fit_dem(scene.terrain, images, cams, visible=nobody)
