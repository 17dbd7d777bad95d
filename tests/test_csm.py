"""USGS CSM cameras (orthomvp.camera.csm) against usgscsm's own numbers: the truth tables that
usgscsm 2.1.0 computed for its 7 test ISDs (../shared/data/csm, see its README) and expected
values from usgscsm's gtests; pixel conventions, the ISD writer, bad ISDs, vectorisation."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from orthomvp.camera import Camera, read_camera
from orthomvp.camera.csm import (
    CsmFrameCamera,
    LineScanCamera,
    PushFrameCamera,
    camera_from_isd,
    camera_from_state,
    csm_to_uv,
    line_scan_isd,
    read_isd,
    uv_to_csm,
    write_isd,
)
from orthomvp.errors import FormatError
from tests.conftest import shared
from tests.ramp_ortho import ramp_ortho_checks

ISDS = [
    "constVelocityLineScan",
    "orbitalLineScan",
    "flippedOrbitalLineScan",
    "orbitalPushFrame",
    "orbitalFramer",
    "simpleFramerISD",
    "dawnfc_radtan",
]


def _case(name: str) -> tuple[Path, dict]:
    path = shared("csm", f"{name}.json")
    return path, json.loads(path.with_name(f"{name}.truth.json").read_text())


@pytest.mark.realdata
@pytest.mark.parametrize("name", ISDS)
def test_against_usgscsm_truth(name: str) -> None:
    """Image to ground within 1 cm, ground to image within 0.01 px, loci, sensor state."""
    path, truth = _case(name)
    cam = read_camera(path)
    assert isinstance(cam, Camera)
    pts = truth["points"]
    line = np.array([p["line"] for p in pts])
    sample = np.array([p["sample"] for p in pts])
    origin, direction = cam.csm_locus(line, sample)
    np.testing.assert_allclose(origin, [p["remote_locus"]["point"] for p in pts], atol=1e-6)
    np.testing.assert_allclose(direction, [p["remote_locus"]["direction"] for p in pts], atol=1e-12)
    checked = 0
    for k, height in enumerate(truth["settings"]["heights_m"]):
        rows = [p["heights"][k] for p in pts]
        usable = np.array(
            [not (r["ray_misses_ellipsoid"] or r["sensor_inside_inflated_ellipsoid"]) for r in rows]
        )
        ground = cam.csm_image_to_ground(line, sample, height)
        want = np.array([r["ground"] for r in rows])
        np.testing.assert_allclose(ground[usable], want[usable], rtol=0, atol=0.01)
        assert np.isnan(ground[~usable]).all()  # misses are NaN, not usgscsm's nearest point
        # ground to image of usgscsm's ground points, against usgscsm's groundToImage
        g_line, g_sample, _ = cam.csm_ground_to_image(want)
        finite = np.isfinite(want).all(axis=1) & usable
        g2i = np.array([[r["g2i"]["line"], r["g2i"]["sample"]] for r in rows])
        np.testing.assert_allclose(
            np.stack([g_line, g_sample], -1)[finite], g2i[finite], rtol=0, atol=0.01
        )
        checked += int(finite.sum())
    assert checked >= 20  # the 10 m bodies leave few rays hitting (data README)
    for s in truth["sensor_state"]:
        if isinstance(cam, CsmFrameCamera):
            np.testing.assert_allclose(cam.position, s["position"], atol=1e-6)
            np.testing.assert_allclose(cam.velocity, s["velocity"], atol=1e-6)
            continue
        assert cam.image_time(np.array(s["line"])) == pytest.approx(s["image_time"], abs=1e-12)
        if isinstance(cam, LineScanCamera):
            np.testing.assert_allclose(
                cam.sensor_position(np.array([s["line"]]))[0], s["position"], atol=1e-6
            )
            np.testing.assert_allclose(
                cam.sensor_velocity(np.array([s["line"]]))[0], s["velocity"], atol=1e-6
            )


@pytest.mark.realdata
def test_usgscsm_gtest_values() -> None:
    """Expected values from usgscsm's tests/*.cpp."""
    # LineScanCameraTests.cpp, TEST_F(OrbitalLineScanSensorModel, Center)
    ls = read_isd(shared("csm", "orbitalLineScan.json"))
    np.testing.assert_allclose(
        ls.csm_image_to_ground(np.array(8.5), np.array(8.0)),
        [999999.67004351015, 0.0, -812.35021438796923],
        atol=1e-6,
    )
    # TEST_F(OrbitalLineScanSensorModel, ImageToGroundHeight)
    g = ls.csm_image_to_ground(np.array(8.5), np.array(8.0), 100.0)
    assert np.linalg.norm(g) == pytest.approx(1000100, abs=1e-6)
    # TEST_F(OrbitalLineScanSensorModel, InversionHeight): within 0.1 px (we reach 1e-6)
    lines = np.arange(0.5, 16, 1.0)
    ground = ls.csm_image_to_ground(lines, np.full_like(lines, 8.0), 100.0)
    back_line, back_sample, _ = ls.csm_ground_to_image(ground)
    np.testing.assert_allclose(back_line, lines, atol=1e-6)
    np.testing.assert_allclose(back_sample, 8.0, atol=1e-6)
    # TEST_F(FlippedOrbitalLineScanSensorModel, OppositeFlightDetector)
    flipped = read_isd(shared("csm", "flippedOrbitalLineScan.json"))
    g = flipped.csm_image_to_ground(np.array([8.7]), np.array([8.0]))
    back_line, back_sample, _ = flipped.csm_ground_to_image(g)
    assert (back_line[0], back_sample[0]) == pytest.approx((8.7, 8.0), abs=1e-3)
    # FrameCameraTests.cpp, TEST_F(FrameSensorModel, Center) and SlightlyOffCenter
    frame = read_isd(shared("csm", "simpleFramerISD.json"))
    np.testing.assert_allclose(
        frame.csm_image_to_ground(np.array(7.5), np.array(7.5)), [10.0, 0, 0], atol=1e-8
    )
    np.testing.assert_allclose(
        frame.csm_image_to_ground(np.array(7.5), np.array(6.5)),
        [9.80194018, 0, 1.98039612],
        atol=1e-8,
    )
    # TEST_F(OrbitalFrameSensorModel, Center)
    orbital = read_isd(shared("csm", "orbitalFramer.json"))
    np.testing.assert_allclose(
        orbital.csm_image_to_ground(np.array(8.0), np.array(8.0)), [1e6, 0, 0], atol=1e-8
    )
    # PushFrameCameraTests.cpp, TEST_F(OrbitalPushFrameSensorModel, Center)
    push = read_isd(shared("csm", "orbitalPushFrame.json"))
    assert isinstance(push, PushFrameCamera)
    np.testing.assert_allclose(
        push.csm_image_to_ground(np.array(6.0), np.array(8.0)), [1e6, 0, 0], atol=1e-9
    )


def test_pixel_convention() -> None:
    """CSM (line, sample) = (row + 0.5, column + 0.5): the first pixel centre is (0.5, 0.5)."""
    np.testing.assert_array_equal(
        csm_to_uv(np.array([0.5, 10.0]), np.array([0.5, 3.0])), [[0, 0], [2.5, 9.5]]
    )
    line, sample = uv_to_csm(np.array([[0.0, 0.0], [2.5, 9.5]]))
    np.testing.assert_array_equal(line, [0.5, 10.0])
    np.testing.assert_array_equal(sample, [0.5, 3.0])


@pytest.mark.realdata
def test_project_uses_orthomvp_pixels_and_crop() -> None:
    cam = read_camera(shared("csm", "orbitalLineScan.json"))
    ground = cam.csm_image_to_ground(np.array([4.5]), np.array([10.5]))  # centre of pixel (10, 4)
    uv, depth = cam.project(ground)
    np.testing.assert_allclose(uv, [[10.0, 4.0]], atol=1e-6)
    assert depth[0] > 0 and cam.in_image(uv).all()
    crop = cam.crop(3, 2, 8, 8)
    np.testing.assert_allclose(crop.project(ground)[0], uv - [3, 2], atol=1e-9)
    origins, directions = cam.ray(uv)
    t = np.sum((ground - origins) * directions, axis=-1)
    assert t[0] > 0  # the ray points into the scene
    np.testing.assert_allclose(origins + t[:, None] * directions, ground, atol=1e-6)
    np.testing.assert_allclose(cam.origins(uv), origins)
    np.testing.assert_allclose(cam.image_to_ground(uv), ground, atol=1e-6)
    gsd = cam.gsd(ground)[0]
    # 50 mm x 10 px/mm; the range is taken at the line found to 1e-3 lines (LineScanCamera.gsd)
    assert gsd == pytest.approx(np.linalg.norm(ground[0] - origins[0]) / 500.0, rel=1e-6)


@pytest.mark.realdata
def test_outside_time_range_is_nan() -> None:
    """A point imaged before the first line or after the last: NaN, not an extrapolated pixel."""
    cam = read_isd(shared("csm", "orbitalLineScan.json"))
    ground = cam.csm_image_to_ground(np.array([8.0]), np.array([8.0]))[0]
    along = cam.csm_image_to_ground(np.array([16.0]), np.array([8.0]))[0] - ground
    outside = np.array([ground + 2.0 * along, ground - 2.0 * along])  # lines ~24 and ~-8
    uv, depth = cam.project(outside)
    assert np.isnan(uv).all() and np.isnan(depth).all()
    assert np.isnan(cam.ray(np.array([[8.0, -3.0], [8.0, 20.0]]))[0]).all()


@pytest.mark.realdata
def test_vectorised_equals_pointwise() -> None:
    cam = read_isd(shared("csm", "orbitalLineScan.json"))
    rng = np.random.default_rng(1)
    uv = rng.uniform(-0.5, 15.5, size=(2000, 2))
    ground = cam.image_to_ground(uv, rng.uniform(-500, 500, size=2000))
    many, _ = cam.project(ground)
    one = np.array([cam.project(g[None])[0][0] for g in ground[:50]])
    np.testing.assert_array_equal(many[:50], one)
    np.testing.assert_allclose(many, uv, atol=1e-6)


@pytest.mark.realdata
def test_line_scan_isd_writer_round_trip(tmp_path: Path) -> None:
    cam = read_isd(shared("csm", "orbitalLineScan.json"))
    path = tmp_path / "written.json"
    write_isd(cam, path)
    back = read_camera(path)
    assert isinstance(back, LineScanCamera)
    np.testing.assert_allclose(
        back.trajectory.positions, cam.trajectory.positions, rtol=0, atol=1e-6
    )
    rng = np.random.default_rng(2)
    uv = rng.uniform(-0.5, 15.5, size=(200, 2))
    ground = cam.image_to_ground(uv)
    np.testing.assert_allclose(back.project(ground)[0], cam.project(ground)[0], atol=1e-8)
    np.testing.assert_allclose(back.image_to_ground(uv), ground, atol=1e-6)


@pytest.mark.realdata
def test_model_state_round_trip(tmp_path: Path) -> None:
    """A usgscsm/ASP model state (name line, then m_* JSON) of the same line scanner."""
    cam = read_isd(shared("csm", "orbitalLineScan.json"))
    t, fp = cam.trajectory, cam.focal_plane
    state = {
        "m_nLines": cam.lines,
        "m_nSamples": cam.samples,
        "m_majorAxis": cam.ellipsoid.semi_major,
        "m_minorAxis": cam.ellipsoid.semi_minor,
        "m_distortionType": 0,
        "m_opticalDistCoeffs": fp.distortion.coefficients.tolist(),
        "m_focalLength": fp.focal_length,
        "m_iTransS": fp.i_trans_s.tolist(),
        "m_iTransL": fp.i_trans_l.tolist(),
        "m_detectorSampleOrigin": fp.sample_origin,
        "m_detectorLineOrigin": fp.line_origin,
        "m_detectorSampleSumming": 1,
        "m_detectorLineSumming": 1,
        "m_startingDetectorSample": 0,
        "m_startingDetectorLine": 1,
        "m_positions": t.positions.ravel().tolist(),
        "m_velocities": t.velocities.ravel().tolist(),
        "m_t0Ephem": t.t0_ephem,
        "m_dtEphem": t.dt_ephem,
        "m_quaternions": t.quaternions.ravel().tolist(),
        "m_t0Quat": t.t0_quat,
        "m_dtQuat": t.dt_quat,
        "m_platformFlag": 1,
        "m_intTimeLines": [0.5],
        "m_intTimeStartTimes": [-0.85],
        "m_intTimes": [0.1],
        "m_centerEphemerisTime": 1000.0,
        "m_currentParameterValue": [0.0] * 16,
    }
    path = tmp_path / "state.json"
    path.write_text("USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL\n" + json.dumps(state))
    back = read_camera(path)
    _, truth = _case("orbitalLineScan")
    p = truth["points"][40]
    np.testing.assert_allclose(
        back.csm_image_to_ground(np.array(p["line"]), np.array(p["sample"])),
        p["heights"][0]["ground"],
        atol=0.01,
    )
    state["m_currentParameterValue"][0] = 1.0
    path.write_text("USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL\n" + json.dumps(state))
    with pytest.raises(FormatError, match="m_currentParameterValue"):
        camera_from_state(path.read_text(), path)


def _isd() -> dict:
    return json.loads(shared("csm", "orbitalLineScan.json").read_text())


@pytest.mark.realdata
def test_bad_isd_missing_key(tmp_path: Path) -> None:
    isd = _isd()
    del isd["focal2pixel_lines"]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(isd))
    with pytest.raises(FormatError, match=r"bad\.json.*focal2pixel_lines"):
        read_camera(path)


@pytest.mark.realdata
def test_bad_isd_unknown_model() -> None:
    isd = _isd()
    isd["name_model"] = "USGS_ASTRO_SAR_SENSOR_MODEL"
    with pytest.raises(FormatError, match="name_model.*unknown sensor model"):
        camera_from_isd(isd, "x.json")


@pytest.mark.realdata
def test_bad_isd_inconsistent_lengths() -> None:
    isd = _isd()
    isd["instrument_position"]["velocities"].pop()
    with pytest.raises(FormatError, match="instrument_position.velocities"):
        camera_from_isd(isd, "x.json")
    isd = _isd()
    isd["instrument_pointing"]["ephemeris_times"].pop()
    with pytest.raises(FormatError, match="instrument_pointing.quaternions"):
        camera_from_isd(isd, "x.json")


@pytest.mark.realdata
def test_bad_isd_times_outside_ephemeris() -> None:
    isd = _isd()
    isd["line_scan_rate"] = [[0.5, -0.85, 1.0]]  # 16 s of lines, 1.5 s of ephemeris
    with pytest.raises(FormatError, match="line_scan_rate.*outside the ephemeris"):
        camera_from_isd(isd, "x.json")


@pytest.mark.realdata
def test_bad_isd_unknown_distortion() -> None:
    isd = _isd()
    isd["optical_distortion"] = {"cahvor": {"coefficients": [0, 0, 0, 0, 0]}}
    with pytest.raises(FormatError, match="optical_distortion.cahvor"):
        camera_from_isd(isd, "x.json")


@pytest.mark.realdata
def test_line_scan_isd_dict_is_json() -> None:
    cam = read_isd(shared("csm", "orbitalLineScan.json"))
    assert (
        json.loads(json.dumps(line_scan_isd(cam)))["name_model"]
        == "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
    )


@pytest.mark.parametrize("name", ["orbitalFramer", "orbitalPushFrame", "orbitalLineScan"])
def test_csm_cameras_through_the_command_line(name: str, tmp_path: Path) -> None:
    """`orthomvp ortho` with an ISD camera: an image whose bands hold each pixel's own column
    and row, orthorectified onto a flat DEM of the ISD's 1000 km sphere, gives at usgscsm's
    ground points (its truth table, height 0) usgscsm's own ground-to-image pixel."""
    isd, truth = _case(name)
    rows, cols = int(truth["image_size"]["lines"]), int(truth["image_size"]["samples"])
    camera = read_camera(isd).with_image_size(cols, rows)
    checked = ramp_ortho_checks(tmp_path, camera, isd, truth, rows=rows, cols=cols, radius=1e6)
    assert checked >= 25


@pytest.mark.parametrize(
    ("model", "coefficients", "way"),
    [
        ("kaguyalism", [0.01, 1e-4, -2e-5, 3e-6, 0, -0.02, 2e-4, 1e-5, -4e-6, 0], "distort"),
        ("dawnfc", [9.2e-6], "undistort"),
        ("lrolrocnac", [1.8e-5], "distort"),
        ("apollometric", None, "distort"),
    ],
)
def test_iterated_lenses_leave_nan_points_out_of_their_steps(
    model: str, coefficients: list | None, way: str, monkeypatch
) -> None:
    """A lens inverted by iteration gives every finite point the value it has without NaN
    points beside it, a NaN coordinate comes back NaN, and the NaN points do not keep the
    others iterating to the step limit (counted where the model's terms are a function)."""
    from orthomvp.camera.csm import distortion as csm_distortion
    from orthomvp.camera.isis.apollo_metric import ApolloMetricDistortion

    calls: list = []
    if model == "apollometric":  # Apollo 15's published coefficients (ISIS's kernel)
        k = (-1.3361854e-06, 5.2261757e-10, -5.0728336e-14)
        lens = ApolloMetricDistortion(-0.006, -0.002, *k, -5.4958195e-07, -4.608942e-11, 2.965907)
        real = ApolloMetricDistortion._shift
        monkeypatch.setattr(
            ApolloMetricDistortion, "_shift", lambda *a: calls.append(1) or real(*a)
        )
    else:
        lens = csm_distortion.CsmDistortion(model, np.array(coefficients))
        real = csm_distortion._kaguya_terms
        monkeypatch.setattr(csm_distortion, "_kaguya_terms", lambda *a: calls.append(1) or real(*a))
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-30, 30, 400), rng.uniform(-30, 30, 400)
    clean = getattr(lens, way)(x, y, 100.0)
    steps = len(calls)
    x[::7], y[3::11] = np.nan, np.nan
    out = getattr(lens, way)(x, y, 100.0)
    bad = np.isnan(x) | np.isnan(y)
    for a, b in zip(out, clean, strict=True):
        np.testing.assert_array_equal(a[~bad], b[~bad])
    iterated = out[1:] if model == "lrolrocnac" else out  # (its x passes through)
    for a, b in zip(iterated, (x, y)[-len(iterated) :], strict=True):
        assert np.isnan(a[np.isnan(b)]).all()
    if model in ("apollometric", "kaguyalism"):
        assert 0 < steps < 10 and len(calls) - steps == steps  # not the limit's 50


def test_apollo_metric_far_off_the_lens_is_nan_without_a_warning() -> None:
    """Points far outside the Apollo Metric focal plane (where the fixed-point inversion
    diverges, as a grid far off the image asks for) come back NaN, silently; points on it as
    before."""
    from orthomvp.camera.isis.apollo_metric import ApolloMetricDistortion

    k = (-1.3361854e-06, 5.2261757e-10, -5.0728336e-14)
    lens = ApolloMetricDistortion(-0.006, -0.002, *k, -5.4958195e-07, -4.608942e-11, 2.965907)
    x, y = np.array([1e5, -3e6, 10.0]), np.array([2e5, 1e4, -20.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = lens.distort(x, y)
    assert np.isnan(out[0][:2]).all() and np.isnan(out[1][:2]).all()
    back = lens.undistort(out[0][2:], out[1][2:])
    np.testing.assert_allclose([back[0][0], back[1][0]], [10.0, -20.0], atol=1e-5)
