"""The line scanner's fast ground to image (the numba kernels of
orthomvp.camera.csm.table_kernel) against the numpy iteration it replaces, which stays the
oracle: the same values bit for bit, on the image and off it, started from the affine guess
or from the first and last lines, with one line rate or several; usgscsm's truth through the
kernel; and the one-evaluation post geometry (LineScanCamera.imaging) against the model's own
pixels, origins, rays and GSDs."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import orthomvp.camera.csm.linescan as linescan
from orthomvp.camera import read_camera
from orthomvp.camera.csm import CsmDistortion, LineScanCamera
from orthomvp.camera.csm.linescan import PRECISION
from orthomvp.occlusion.post_geometry import general
from orthomvp.synthetic import ViewSpec, make_scene
from orthomvp.synthetic.linescan import orbital_line_scanner
from tests.conftest import shared

NUMPY = 1 << 62  # KERNEL_POINTS that no block reaches: the numpy iteration


@pytest.fixture(scope="module")
def scene_and_scanner() -> tuple:
    scene = make_scene("crater", size=48, spacing=80.0)
    return scene, orbital_line_scanner(scene.terrain, ViewSpec("t", 40.0, 120.0), scene.gsd)


@pytest.fixture(scope="module")
def scanner(scene_and_scanner: tuple) -> LineScanCamera:
    return scene_and_scanner[1]


def _fresh(camera: LineScanCamera, **changes: object) -> LineScanCamera:
    """A copy of ``camera`` (with ``changes``) that shares none of its cached tables."""
    return dataclasses.replace(camera, **changes)


def _ground(camera: LineScanCamera, n: int, seed: int) -> np.ndarray:
    """``n`` ground points seen at random pixels and heights, then points off the image: four
    past the first and last lines (two beyond the ephemeris span), NaN, and one past the
    last sample (last)."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform([-0.5, -0.5], [camera.samples - 0.5, camera.lines - 0.5], (n, 2))
    ground = camera.image_to_ground(uv, rng.uniform(-2000, 2000, n))
    origin, direction = camera.csm_locus(np.full(4, camera.lines / 2), np.full(4, 5.0))
    mid = camera.ellipsoid.intersect(origin, camera.look_sign * direction, np.zeros(4))
    along = camera.sensor_position(np.array([camera.lines + 40.0])) - camera.sensor_position(
        np.array([camera.lines / 2])
    )
    across = camera.image_to_ground(np.array([[camera.samples + 30.0, camera.lines / 2]]))
    off = np.vstack([mid + along * [[4], [-4], [1.5], [-1.6]], [[np.nan] * 3], across])
    return np.vstack([ground, off])


def _both(camera: LineScanCamera, monkeypatch: pytest.MonkeyPatch, fn) -> tuple:
    """``fn(camera)`` through the kernel (every block) and through the numpy iteration."""
    with monkeypatch.context() as m:
        m.setattr(linescan, "KERNEL_POINTS", 1)
        fast = fn(camera)
        m.setattr(linescan, "KERNEL_POINTS", NUMPY)
        slow = fn(camera)
    return fast, slow


def _assert_same(fast: tuple, slow: tuple) -> None:
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)  # NaN where NaN, bit for bit elsewhere


@pytest.mark.parametrize("guess", [True, False])
def test_kernel_equals_numpy_iteration(
    scanner: LineScanCamera, guess: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ground to image and imaging, from the affine guess or the first and last lines: the
    numpy iteration's values to the bit, NaN for every point off the image."""
    camera = _fresh(scanner)
    if not guess:
        camera.__dict__["_first_guess"] = None
    assert camera._use_table and camera.focal_plane.distortion.is_identity
    ground = _ground(camera, 5000, 0)
    fast, slow = _both(camera, monkeypatch, lambda c: c.csm_ground_to_image(ground))
    _assert_same(fast, slow)
    assert np.isfinite(fast[0][:5000]).all() and np.isnan(fast[0][5000:-1]).all()
    assert fast[1][-1] > camera.samples  # imaged, off the image's samples
    _assert_same(*_both(camera, monkeypatch, lambda c: c.imaging(ground)))


def test_kernel_equals_numpy_with_several_line_rates(
    scanner: LineScanCamera, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Three line rates (as HRSC's), the rate changing mid-image: the table still stands in
    for the ephemeris here, the kernel gives the numpy iteration's values, and both find
    the exact model's pixels within the table's error; the exact model's own search (the
    table's camera-frame coordinates from the kernel) gives numpy's values too."""
    dt = float(scanner.int_times[0])
    lines = np.array([0.5, 300.5, 320.5])
    rates = dt * np.array([1.0, 0.97, 0.94])
    starts = scanner.int_time_start_times[0] + np.concatenate(
        [[0.0], np.cumsum(rates[:-1] * np.diff(lines))]
    )
    camera = _fresh(scanner, int_time_lines=lines, int_time_start_times=starts, int_times=rates)
    assert camera._use_table
    ground = _ground(camera, 5000, 1)
    fast, slow = _both(camera, monkeypatch, lambda c: c.csm_ground_to_image(ground))
    _assert_same(fast, slow)
    exact = _fresh(camera)
    exact.__dict__["_use_table"] = False  # as where the table does not serve: the table's
    # search (its camera-frame coordinates from the kernel), then exact Newton steps
    want, want_numpy = _both(exact, monkeypatch, lambda c: c.csm_ground_to_image(ground))
    _assert_same(want, want_numpy)
    for a, b in zip(fast[:2], want[:2], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=max(camera.table_error, PRECISION))


def test_kernel_knows_every_lens() -> None:
    """The line scanner's lens codes are the kernel's, one for each of usgscsm's distortion
    models."""
    from orthomvp.camera.csm import table_kernel as k
    from orthomvp.camera.csm.distortion import MODELS

    names = ("radial", "lrolrocnac", "transverse", "kaguyalism", "dawnfc", "radtan")
    codes = (k.RADIAL, k.LRONAC, k.TRANSVERSE, k.KAGUYA, k.DAWN, k.RADTAN)
    assert linescan.KERNEL_DISTORTIONS == dict(zip(names, codes, strict=True))
    assert set(names) == set(MODELS) and k.IDENTITY not in codes


def _transverse() -> np.ndarray:
    c = np.zeros(20)
    c[1], c[12], c[3], c[15] = 1.0, 1.0, 1e-5, -2e-5  # x' = x + 1e-5 x^2, y' = y - 2e-5 x^2
    return c


@pytest.mark.parametrize(
    ("model", "coefficients", "found"),
    [
        ("radial", np.array([0.0, 1e-5, 0.0]), PRECISION),
        ("lrolrocnac", np.array([1.8e-5]), PRECISION),
        ("transverse", _transverse(), PRECISION),
        # usgscsm's Kaguya iteration stops at 1e-6 mm: 1e-5 px on this detector
        ("kaguyalism", np.array([1e-3, 1e-3, 5e-2, 1e-2, 0, -2e-3, 2e-4, 5e-2, 1e-2, 0]), 1e-5),
        ("dawnfc", np.array([1e-5]), PRECISION),
        ("radtan", np.array([1e-2, 1e-3, 1e-4, -1e-4, 0.0]), PRECISION),
    ],
)
def test_distorted_lenses(
    scanner: LineScanCamera,
    model: str,
    coefficients: np.ndarray,
    found: float,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A distorted lens: the kernel applies each of usgscsm's models point by point, with the
    numpy iteration's values to the bit; the pixels of image to ground found again within
    usgscsm's precision (``found`` pixels)."""
    plane = dataclasses.replace(  # the detector line off the focal plane's x axis
        scanner.focal_plane, distortion=CsmDistortion(model, coefficients), line_origin=40.0
    )
    camera = _fresh(scanner, focal_plane=plane)
    assert camera._kernel_applies(1 << 20)
    ground = _ground(camera, 5000, 2)
    fast, slow = _both(camera, monkeypatch, lambda c: c.csm_ground_to_image(ground))
    _assert_same(fast, slow)
    _assert_same(*_both(camera, monkeypatch, lambda c: c.imaging(ground)))
    rng = np.random.default_rng(3)
    uv = rng.uniform([-0.5, -0.5], [camera.samples - 0.5, camera.lines - 0.5], (5000, 2))
    with monkeypatch.context() as m:
        m.setattr(linescan, "KERNEL_POINTS", 1)
        again = camera.project(camera.image_to_ground(uv))[0]
    np.testing.assert_allclose(again, uv, rtol=0, atol=found)


@pytest.mark.realdata
@pytest.mark.parametrize(
    "name", ["constVelocityLineScan", "orbitalLineScan", "flippedOrbitalLineScan"]
)
def test_kernel_against_usgscsm_truth(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """usgscsm's groundToImage of its truth tables' ground points, within 0.01 px (the truth
    test's threshold), through the kernel; and the numpy iteration's values to the bit."""
    path = shared("csm", f"{name}.json")
    truth = json.loads(path.with_name(f"{name}.truth.json").read_text())
    camera = read_camera(path)
    assert camera._kernel_applies(1 << 20)
    checked = 0
    for k in range(len(truth["settings"]["heights_m"])):
        rows = [p["heights"][k] for p in truth["points"]]
        want = np.array([r["ground"] for r in rows], dtype=np.float64)
        usable = np.array(
            [not (r["ray_misses_ellipsoid"] or r["sensor_inside_inflated_ellipsoid"]) for r in rows]
        ) & np.isfinite(want).all(axis=1)
        fast, slow = _both(camera, monkeypatch, lambda c, w=want: c.csm_ground_to_image(w))
        _assert_same(fast, slow)
        g2i = np.array([[r["g2i"]["line"], r["g2i"]["sample"]] for r in rows])
        got = np.stack(fast[:2], -1)
        np.testing.assert_allclose(got[usable], g2i[usable], rtol=0, atol=0.01)
        checked += int(usable.sum())
    assert checked >= 20


def test_imaging_is_the_models_own_geometry(scanner: LineScanCamera) -> None:
    """One evaluation gives project's pixels and depths to the bit, the sensor positions of
    origins() within a micrometre, the model's ray directions (ray()) within 1e-9, the GSD of
    gsd() within 1e-7 of itself, and the pixels round-trip within usgscsm's precision."""
    rng = np.random.default_rng(4)
    uv0 = rng.uniform([-0.5, -0.5], [scanner.samples - 0.5, scanner.lines - 0.5], (6000, 2))
    ground = scanner.image_to_ground(uv0, rng.uniform(-2000, 2000, len(uv0))).reshape(60, 100, 3)
    uv, depth, origin, direction, gsd = scanner.imaging(ground)
    want_uv, want_depth = scanner.project(ground)
    np.testing.assert_array_equal(uv, want_uv)
    np.testing.assert_array_equal(depth, want_depth)
    np.testing.assert_allclose(uv.reshape(-1, 2), uv0, rtol=0, atol=PRECISION)
    np.testing.assert_allclose(origin, scanner.origins(uv), rtol=0, atol=1e-6)
    np.testing.assert_allclose(direction, scanner.ray(uv)[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(gsd, scanner.gsd(ground), rtol=1e-7)


def test_general_geometry_of_a_line_scanner(scene_and_scanner: tuple) -> None:
    """post_geometry.general for a line scanner: the pixels of project, and the origins,
    emission cosines and GSDs that the model's separate calls give, within rounding of the
    line search; NaN origins and rays outside the image."""
    scene, scanner = scene_and_scanner
    terrain = scene.terrain
    rows, cols = terrain.shape
    g = general(terrain, scanner, slice(0, rows), slice(0, cols))
    p = np.stack(np.broadcast_arrays(g.x, g.y, g.z), -1)
    uv, depth = scanner.project(p)
    inside = g.ok & (depth > 0) & scanner.in_image(uv)
    assert inside.sum() > 0.9 * inside.size
    np.testing.assert_array_equal(g.inside, inside)
    np.testing.assert_array_equal(g.uv, uv)
    origins = scanner.origins(np.where(inside[..., None], uv, np.nan))
    np.testing.assert_allclose(g.origins, origins, rtol=0, atol=1e-6)
    np.testing.assert_allclose(g.directions[inside], scanner.ray(uv[inside])[1], atol=1e-9)
    assert np.isnan(g.directions[~inside]).all() and np.isnan(g.origins[~inside]).all()
    np.testing.assert_allclose(g.facing_gsd[inside], scanner.gsd(p)[inside], rtol=1e-7)
    reference = general(terrain, _PlainScanner(scanner), slice(0, rows), slice(0, cols))
    np.testing.assert_allclose(g.cos_e[inside], reference.cos_e[inside], rtol=0, atol=1e-12)


class _PlainScanner:
    """A camera that is the line scanner but not a LineScanCamera: general's path through the
    model's separate calls (project, origins, gsd)."""

    def __init__(self, camera: LineScanCamera) -> None:
        self._camera = camera

    def __getattr__(self, name: str) -> object:
        return getattr(self._camera, name)


@pytest.mark.realdata
def test_real_lro_nac_through_the_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    """ALE's ISD of a real LRO NAC image (its lens, LRO NAC distortion): the kernel serves
    it and gives the numpy iteration's values to the bit, on the image and off it, and the
    pixels of image to ground are found again within usgscsm's precision."""
    camera = read_camera(shared("isis", "M143947267L.cal.echo.crop.isd.json"))
    assert camera.focal_plane.distortion.model == "lrolrocnac"
    assert camera._kernel_applies(1 << 20)
    ground = _ground(camera, 5000, 5)
    fast, slow = _both(camera, monkeypatch, lambda c: c.csm_ground_to_image(ground))
    _assert_same(fast, slow)
    _assert_same(*_both(camera, monkeypatch, lambda c: c.imaging(ground)))
    assert np.isfinite(fast[0][:5000]).all() and np.isnan(fast[0][5000:-1]).all()
    rng = np.random.default_rng(6)
    uv = rng.uniform([-0.5, -0.5], [camera.samples - 0.5, camera.lines - 0.5], (5000, 2))
    with monkeypatch.context() as m:
        m.setattr(linescan, "KERNEL_POINTS", 1)
        found = camera.project(camera.image_to_ground(uv, rng.uniform(-50, 50, len(uv))))[0]
    np.testing.assert_allclose(found, uv, rtol=0, atol=PRECISION)


def test_visibility_codes_unchanged() -> None:
    """The visibility test of a line scanner over a crater through the one-evaluation geometry
    and through the model's separate calls (its own ray through each post's pixel): the same
    codes, the distances to occluders within 1e-6 posts, GSDs within 1e-12 of themselves."""
    from orthomvp.occlusion.visibility import compute_visibility

    scene = make_scene("crater", size=96, spacing=40.0)
    camera = orbital_line_scanner(scene.terrain, ViewSpec("t", 40.0, 120.0), scene.gsd)
    fast = compute_visibility(scene.terrain, camera)
    slow = compute_visibility(scene.terrain, _PlainScanner(camera))
    codes, counts = np.unique(fast.codes, return_counts=True)
    assert len(codes) == 3 and counts.min() > 100  # visible, occluded, facing away
    np.testing.assert_array_equal(fast.codes, slow.codes)
    # a ray that grazes its own post's surface meets it within float32's rounding (1e-4
    # posts or less) or not at all, as either rounds: no occluder, either way
    clear_fast, clear_slow = ((m < 0.01) | np.isinf(m) for m in (fast.miss, slow.miss))
    np.testing.assert_array_equal(clear_fast, clear_slow)
    np.testing.assert_array_equal(np.isnan(fast.miss), np.isnan(slow.miss))
    hit = np.isfinite(slow.miss) & ~clear_slow
    assert hit.sum() > 100
    np.testing.assert_allclose(fast.miss[hit], slow.miss[hit], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast.gsd, slow.gsd, rtol=1e-12)
