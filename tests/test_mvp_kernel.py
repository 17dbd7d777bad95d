"""The fused MVP kernel against the numpy objective (its reference): cost, views used, normal
equations, leave-one-out correlations and sampled extents, on random problems and on every
pyramid level of a synthetic scene."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from orthomvp.mvp.kernel import fused_evaluate
from orthomvp.mvp.patches import (
    Evaluation,
    boxes,
    evaluate,
    image_gradients,
    sample_patches,
)
from orthomvp.mvp.window import Window
from orthomvp.synthetic import make_scene

RTOL = 1e-6


def assert_matches(got: Evaluation, ref: Evaluation, jac: bool) -> None:
    """Views used equal; per post with 2 or more views: cost to RTOL of its range n - 1 (f =
    (n - 1) (1 - mean correlation); near 0 the two bilinear samplers' float32 roundings
    show); JTJ to RTOL of its norm and JTr of its Cauchy-Schwarz bound sqrt(f JTJ_ii);
    JgJ (for the uncertainty only, with the squared weights that leave fewer samples
    to average the roundings) to 10 RTOL of its norm; leave-one-out correlations to
    RTOL."""
    np.testing.assert_array_equal(got.used, ref.used)
    ok = np.isfinite(ref.cost)
    np.testing.assert_array_equal(np.isfinite(got.cost), ok)
    assert ok.sum() > 10
    n = ref.used.sum(axis=1)[ok]
    assert (np.abs(got.cost[ok] - ref.cost[ok]) <= RTOL * (n - 1)).all()
    np.testing.assert_allclose(got.loo, ref.loo, rtol=0, atol=RTOL)  # NaN where ref is NaN
    if not jac:
        return
    for name, tol in (("JTJ", RTOL), ("JgJ", 10 * RTOL)):
        a, b = getattr(got, name)[ok], getattr(ref, name)[ok]
        err = np.abs(a - b).max(axis=(1, 2)) / np.linalg.norm(b, axis=(1, 2))
        assert err.max() < tol, (name, err.max())
    diag = np.einsum("bii->bi", ref.JTJ[ok])
    bound = np.sqrt(ref.cost[ok, None] * diag)
    assert (np.abs(got.JTr[ok] - ref.JTr[ok]) <= RTOL * bound).all()


def random_problem(seed: int, B: int = 200, K: int = 5):  # noqa: ANN201
    """K textured views (of different sizes, as windows of larger images at ``origins``, one
    with a flat region), B random projective patches per view (some partly or wholly outside
    the windows' borders), a random view mask and random homography derivatives."""
    rng = np.random.default_rng(seed)
    images, origins = [], rng.integers(0, 50, (K, 2)).astype(np.float32)
    for k in range(K):
        img = ndimage.gaussian_filter(rng.normal(size=(90 + 7 * k, 110 - 5 * k)), 1.5)
        img = img.astype(np.float32)
        if k == 1:
            img[:40, :40] = 0.3  # flat: patches there carry nothing
        gc, gr = image_gradients(img)
        images.append(np.ascontiguousarray(np.stack([img, gc, gr], -1)))
    H = np.zeros((B, K, 3, 3))
    for i, j, lo, hi in ((0, 0, 0.7, 1.4), (1, 1, 0.7, 1.4), (0, 1, -0.3, 0.3), (1, 0, -0.3, 0.3)):
        H[..., i, j] = rng.uniform(lo, hi, (B, K))
    H[..., 2, :2] = rng.uniform(-2e-3, 2e-3, (B, K, 2))
    H[..., 2, 2] = 1.0
    for k, img in enumerate(images):  # centres anywhere in the windows: some patches cross
        H[:, k, 0, 2] = origins[k, 0] + rng.uniform(0, img.shape[1] - 1, B)
        H[:, k, 1, 2] = origins[k, 1] + rng.uniform(0, img.shape[0] - 1, B)
    H *= rng.uniform(0.5, 3.0, (B, K, 1, 1))  # any scale
    dH = rng.normal(size=(B, K, 3, 3, 3)) * np.array([0.05, 0.05, 2.0])[:, None] * 0.1
    W = rng.random((B, K)) < 0.75
    W[:5] = False  # no views at all
    W[5:10, 1:] = False  # one view
    flat = np.full(K, 2e-3, np.float32)  # 1% of the images' standard deviation
    return images, origins, flat, H, dH, W


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("jac", [False, True])
def test_kernel_matches_numpy_on_random_problems(seed: int, jac: bool) -> None:
    images, origins, flat, H, dH, W = random_problem(seed)
    window = Window(4 + seed, 1.0 + seed)
    dH = dH if jac else None
    ref = evaluate(images, flat, H, W, window, dH, extras=True, origins=origins)
    got = fused_evaluate(images, origins, flat, H, dH, W, window, extras=True)
    assert (~got.used[W]).any() and got.used.any()  # flat patches were left out
    assert_matches(got, ref, jac)
    # the bounding boxes of the sampled positions, in whole-image pixels
    _, u, v, _ = sample_patches(images, H, window.offsets, 1, origins)
    np.testing.assert_allclose(got.box, boxes(u, v, W), rtol=RTOL)  # float32 rounding
    if jac:  # without extras, the same normal equations
        lean = fused_evaluate(images, origins, flat, H, dH, W, window, extras=False)
        np.testing.assert_array_equal(lean.JTJ, got.JTJ)
        np.testing.assert_array_equal(lean.JTr, got.JTr)
        assert np.isnan(lean.loo).all()


def test_positions_that_are_not_finite_mark_the_box() -> None:
    images, origins, flat, H, dH, W = random_problem(3, B=40)
    H[:10, :, 2, :2] = 0.0
    H[:10, :, 2, 2] = 0.0  # w = 0: every position infinite
    W[:10] = True
    window = Window(3, 1.5)
    got = fused_evaluate(images, origins, flat, H, dH, W, window, extras=True)
    assert np.isnan(got.box[:10]).all() and np.isfinite(got.box[10:][W[10:]]).all()
    assert not got.used[:10].any()


@pytest.fixture(scope="module")
def hills_stack():  # noqa: ANN201
    from orthomvp.mvp.problem import FitProblem

    scene = make_scene("hills", size=48)
    cams = list(scene.cameras.values())
    images = [scene.render(cam, 2) for cam in cams]
    visible = np.ones((len(cams), *scene.terrain.shape), bool)
    problem = FitProblem.build(scene.terrain, images, cams, levels=3, visible=visible)
    return scene, problem


@pytest.mark.parametrize("level", [0, 1, 2])
def test_kernel_matches_numpy_at_every_pyramid_level(hills_stack, level: int) -> None:  # noqa: ANN001
    """The fitter's homographies and derivatives on the hills scene's pyramid, planes off
    the truth by up to 20 m and 0.2 in tilt, a third of the views occluded at random."""
    scene, problem = hills_stack
    assert problem.levels == 3
    rng = np.random.default_rng(level)
    r, c = np.mgrid[6:42:2, 6:42:2]
    c, r = c.ravel(), r.ravel()
    model = problem.model(problem.lines(c, r), problem.normals[r, c])
    theta = np.zeros((len(c), 3))
    theta[:, 0] = problem.terrain.values[r, c] + rng.uniform(-20, 20, len(c))
    theta[:, 1:] = rng.uniform(-0.2, 0.2, (len(c), 2))
    H, dH = model.homographies(theta, level)
    W = rng.random(H.shape[:2]) < 0.67
    stack = problem.stack
    window = Window(5, 2.5)
    ref = evaluate(stack.levels[level], stack.flat[level], H, W, window, dH, extras=True)
    got = stack.evaluate(level, H, W, window, dH, extras=True)
    assert_matches(got, ref, True)
    assert stack.samples == int(W.sum()) * len(window.offsets) * 3
    stack.samples = 0


def test_kept_patches_come_from_the_numpy_objective(hills_stack) -> None:  # noqa: ANN001
    scene, problem = hills_stack
    c, r = np.array([20, 24]), np.array([22, 30])
    model = problem.model(problem.lines(c, r), problem.normals[r, c])
    theta = np.c_[problem.terrain.values[r, c], np.zeros((2, 2))]
    H, _ = model.homographies(theta, 0, derivatives=False)
    W = np.ones(H.shape[:2], bool)
    window = Window(5, 2.5)
    kept = problem.stack.evaluate(0, H, W, window, keep_patches=True)
    fused = problem.stack.evaluate(0, H, W, window)
    assert kept.patches.shape == (2, H.shape[1], len(window.offsets))
    np.testing.assert_allclose(fused.cost, kept.cost, rtol=RTOL)
    problem.stack.samples = 0


def test_no_threading_warning_after_open3d() -> None:
    """Open3D loads an older TBB; the kernel's first parallel call then still prints nothing
    (numba takes OpenMP first) and runs, in a fresh process with warnings as errors."""
    import subprocess
    import sys

    code = (
        "import warnings; warnings.simplefilter('error'); import open3d; "
        "from orthomvp.mvp.kernel import compile_seconds; compile_seconds(); "
        "import numba; print(numba.threading_layer())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stderr == "", out.stderr[-500:]
    assert out.stdout.split()[-1] in ("omp", "tbb", "workqueue")


def test_typed_images_compile_nothing_in_a_new_process() -> None:
    """The kernel's typed List of a stack's images comes from a function compiled once and
    cached on disk: a fresh process compiles none of numba's list methods (``List(images)``
    compiles them in every process, 0.25-0.55 s), and the list holds the images as they are."""
    import json
    import subprocess
    import sys

    from orthomvp.mvp.patches import ViewStack

    images = [np.arange(60.0, dtype=np.float32).reshape(4, 5, 3), np.ones((2, 3, 3), np.float32)]
    stack = ViewStack([images], np.zeros((2, 3, 4)), [[(5, 4), (3, 2)]], [np.zeros(2)])
    typed = stack.typed_levels(0)
    assert len(typed) == 2 and stack.typed_levels(0) is typed
    for got, image in zip(typed, images, strict=True):
        assert got.dtype == np.float32 and got.flags.c_contiguous
        np.testing.assert_array_equal(got, image)
    code = (
        "import json, numpy as np; import numba.typed.typedlist as t; "
        "from orthomvp.mvp.patches import ViewStack; "
        "ViewStack([[np.ones((4, 5, 3), np.float32)] * 3], None, None, None).typed_levels(0); "
        "print(json.dumps({n: len(getattr(t, n).overloads) for n in dir(t) "
        "if hasattr(getattr(t, n), 'overloads')}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-500:]
    compiled = {name: n for name, n in json.loads(out.stdout.split("\n")[-2]).items() if n}
    assert compiled == {}
