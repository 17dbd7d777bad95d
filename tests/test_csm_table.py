"""The line scanner's fast paths against its exact ones: usgscsm's Lagrange interpolation as
per-interval polynomials against the weights form, and the per-line sensor-state table
(ground to image, rays, origins) against the exact ephemeris, within the error it claims."""

from __future__ import annotations

import numpy as np
import pytest

from orthomvp.camera.csm import LineScanCamera
from orthomvp.camera.csm.ephemeris import (
    lagrange,
    lagrange_polynomials,
    lagrange_weights,
    polynomial_values,
)
from orthomvp.camera.csm.linescan import TABLE_PIXELS
from orthomvp.synthetic import ViewSpec, make_scene
from orthomvp.synthetic.linescan import orbital_line_scanner


@pytest.mark.parametrize(("count", "order"), [(41, 8), (12, 8), (9, 4), (3, 8), (2, 8)])
def test_polynomials_equal_lagrange_weights(count: int, order: int) -> None:
    """Inside the nodes, before the first and after the last (extrapolation), to rounding."""
    rng = np.random.default_rng(count)
    values = 1.7e6 + 1e4 * np.cumsum(rng.normal(size=(count, 3)), axis=0)
    t0, dt = -3.2, 0.25
    times = rng.uniform(t0 - 2 * dt, t0 + (count + 1) * dt, 500)
    want = lagrange(values, *lagrange_weights(times, t0, dt, count, order))
    got = polynomial_values(lagrange_polynomials(values, order), times, t0, dt)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8)  # metres at 1.7e6 m
    assert np.isnan(polynomial_values(lagrange_polynomials(values, order), [np.nan], t0, dt)).all()


@pytest.fixture(scope="module")
def scanner() -> LineScanCamera:
    scene = make_scene("crater", size=48, spacing=80.0)
    return orbital_line_scanner(scene.terrain, ViewSpec("t", 40.0, 120.0), scene.gsd)


def _exact(camera: LineScanCamera) -> LineScanCamera:
    """A copy of ``camera`` that never uses its table (exact ephemeris, exact polish)."""
    copy = camera.crop(0, 0, camera.samples, camera.lines)
    copy.__dict__["_use_table"] = False
    return copy


def test_table_stands_in_within_its_claimed_error(scanner: LineScanCamera) -> None:
    """An orbital scanner's table error is far below the threshold; its ground to image,
    rays and origins agree with the exact model's within that error (pixels) and within
    micrometres (positions)."""
    assert scanner._use_table and scanner.table_error < TABLE_PIXELS
    exact = _exact(scanner)
    rng = np.random.default_rng(0)
    uv = rng.uniform([-0.5, -0.5], [scanner.samples - 0.5, scanner.lines - 0.5], (4000, 2))
    ground = exact.image_to_ground(uv, rng.uniform(-2000, 2000, len(uv)))
    fast, depth = scanner.project(ground)
    slow, depth_slow = exact.project(ground)
    assert np.isfinite(slow).all()
    np.testing.assert_allclose(fast, slow, rtol=0, atol=max(scanner.table_error, 1e-6))
    np.testing.assert_allclose(slow, uv, rtol=0, atol=1e-6)
    np.testing.assert_allclose(depth, depth_slow, rtol=1e-9)
    o_fast, d_fast = scanner.ray(uv)
    o_slow, d_slow = exact.ray(uv)
    np.testing.assert_allclose(o_fast, o_slow, rtol=0, atol=1e-3)
    np.testing.assert_allclose(d_fast, d_slow, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(d_fast, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(scanner.origins(uv), o_slow, rtol=0, atol=1e-3)
    np.testing.assert_allclose(scanner.gsd(ground), exact.gsd(ground), rtol=1e-6)


def test_first_lines_without_the_affine_guess(scanner: LineScanCamera) -> None:
    """Started from the first and last lines (a lattice that misses the body), ground to
    image finds the same pixels; points beyond the image's lines get NaN."""
    plain = scanner.crop(0, 0, scanner.samples, scanner.lines)
    plain.__dict__["_first_guess"] = None
    rng = np.random.default_rng(1)
    uv = rng.uniform([-0.5, -0.5], [scanner.samples - 0.5, scanner.lines - 0.5], (1000, 2))
    ground = scanner.image_to_ground(uv)
    np.testing.assert_allclose(plain.project(ground)[0], uv, rtol=0, atol=1e-6)
    beyond = scanner.image_to_ground(np.array([[10.0, -3.0], [10.0, scanner.lines + 2.0]]))
    assert np.isnan(beyond).all()  # no ray exists beyond the time range
    off = _beyond_last_line(scanner)
    for camera in (scanner, plain):
        uv_off, depth = camera.project(off)
        assert np.isnan(uv_off).all() and np.isnan(depth).all()
        assert np.isnan(camera.gsd(off)).all()


def _beyond_last_line(camera: LineScanCamera) -> np.ndarray:
    """Ground points that the scanner would see 5 and 20 lines after its last line: the exact
    model extrapolated along its orbit (usgscsm extrapolates the ephemeris too)."""
    line = np.array([camera.lines + 5.0, camera.lines + 20.0])
    origin, direction = camera.csm_locus(np.full(2, camera.lines - 0.5), np.full(2, 50.0))
    shift = camera.sensor_position(line) - camera.sensor_position(np.full(2, camera.lines - 0.5))
    ground = camera.ellipsoid.intersect(origin, camera.look_sign * direction, np.zeros(2))
    return ground + shift


def test_window_copies_share_the_model_tables(scanner: LineScanCamera) -> None:
    """Cropped and resized copies (one per engine tile) reuse the model's table and first
    guess, and project as the whole image does, shifted by the window."""
    rng = np.random.default_rng(2)
    uv = rng.uniform([-0.5, -0.5], [scanner.samples - 0.5, scanner.lines - 0.5], (200, 2))
    ground = scanner.image_to_ground(uv)
    whole = scanner.project(ground)[0]
    crop = scanner.crop(3, 5, 20, 30)
    assert crop._table is scanner._table and crop._first_guess is scanner._first_guess
    np.testing.assert_array_equal(crop.project(ground)[0], whole - [3, 5])
    assert scanner.with_image_size(10, 10)._table is scanner._table
