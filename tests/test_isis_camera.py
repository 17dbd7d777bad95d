"""The camera of a spiceinit'd ISIS3 cube read from the cube itself (orthomvp.camera.isis),
against usgscsm on ALE's ISD of the same cube (../shared/data/isis, see its README), against
ALE's ISD itself, against ISIS's Apollo Metric lens formulas worked here by hand, against
SPICE's time conversion; the polynomial table cache; bad cubes made by editing copies."""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from orthomvp.camera import read_camera
from orthomvp.camera.csm import CsmFrameCamera, LineScanCamera, read_isd
from orthomvp.camera.isis import cube_isd, read_cube_camera, utc_to_et
from orthomvp.camera.isis.core import SpiceCube
from orthomvp.errors import FormatError, InputError
from tests.conftest import shared
from tests.ramp_ortho import ramp_ortho_checks

LRO = "M143947267L.cal.echo.crop"
APOLLO = "AS15-M-1134-hadley"
LABEL_BYTES = 65536  # both cubes reserve this much for the label (Object = Label)


def _cube(name: str) -> Path:
    return shared("isis", f"{name}.cub") if name == LRO else shared("as15-hadley", f"{name}.cub")


def _truth(name: str) -> dict:
    return json.loads(shared("isis", f"{name}.truth.json").read_text())


def _grid(truth: dict) -> tuple[np.ndarray, np.ndarray]:
    pts = truth["points"]
    return np.array([p["line"] for p in pts]), np.array([p["sample"] for p in pts])


def _edited(tmp_path: Path, name: str, edit, *, size: int | None = None) -> Path:
    """A copy of cube ``name`` whose label text is ``edit(text)`` (padded back to its reserved
    bytes, so that every offset holds), cut to ``size`` bytes if given."""
    data = bytearray(_cube(name).read_bytes())
    end = data.index(b"\nEnd\n") + 5
    text = edit(data[:end].decode("latin-1")).encode("latin-1")
    assert len(text) <= LABEL_BYTES
    data[:LABEL_BYTES] = text + bytes(LABEL_BYTES - len(text))
    out = tmp_path / f"{name}.cub"
    out.write_bytes(bytes(data[:size]))
    return out


def _drop_object(text: str, kind: str, name: str | None = None) -> str:
    """``text`` without the top-level ``Object = kind`` (named ``name``) blocks."""
    pattern = rf"^Object = {kind}\n(?:(?!^End_Object$).*\n)*?^End_Object\n"
    return re.sub(
        pattern,
        lambda m: "" if name is None or re.search(rf"Name\s+= {name}\n", m.group(0)) else m[0],
        text,
        flags=re.MULTILINE,
    )


# --- accuracy ----------------------------------------------------------------------------


@pytest.mark.realdata
def test_lro_nac_against_usgscsm_truth() -> None:
    """The LRO NAC crop from its cube: image to ground within 1 cm at h = 0 and 2000 m, ground
    to image within 0.01 px, loci, against usgscsm on ALE's ISD (AlphaCube folded in)."""
    cam = read_camera(_cube(LRO))
    assert isinstance(cam, LineScanCamera)
    truth = _truth(LRO)
    line, sample = _grid(truth)
    origin, direction = cam.csm_locus(line, sample)
    pts = truth["points"]
    np.testing.assert_allclose(origin, [p["remote_locus"]["point"] for p in pts], atol=1e-3)
    np.testing.assert_allclose(direction, [p["remote_locus"]["direction"] for p in pts], atol=1e-9)
    for k, height in enumerate(truth["settings"]["heights_m"]):
        want = np.array([p["heights"][k]["ground"] for p in pts])
        ground = cam.csm_image_to_ground(line, sample, height)
        assert np.linalg.norm(ground - want, axis=1).max() < 0.01
        g_line, g_sample, _ = cam.csm_ground_to_image(want)
        g2i = np.array(
            [[p["heights"][k]["g2i"]["line"], p["heights"][k]["g2i"]["sample"]] for p in pts]
        )
        assert np.abs(np.stack([g_line, g_sample], -1) - g2i).max() < 0.01


@pytest.mark.realdata
@pytest.mark.parametrize("name", [LRO, APOLLO])
def test_cube_isd_equals_ales(name: str) -> None:
    """Every number that ALE's driver puts in its ISD of the cube (times, line rate, detector,
    focal plane, tables, radii) comes out of the cube alone, to rounding."""
    ale = json.loads(shared("isis", f"{name}.isd.json").read_text())
    ours = json.loads(json.dumps(cube_isd(_cube(name))))  # JSON as it is, for usgscsm and ASP
    for key in (
        "image_lines",
        "image_samples",
        "name_model",
        "focal_length_model",
        "detector_center",
        "focal2pixel_lines",
        "focal2pixel_samples",
        "detector_sample_summing",
        "detector_line_summing",
        "starting_detector_line",
        "starting_detector_sample",
        "optical_distortion",
        "radii",
        "center_ephemeris_time",
        "starting_ephemeris_time",
        "line_scan_rate",
    ):
        if key in ale:
            assert json.dumps(ours[key]) == json.dumps(ale[key]) or np.allclose(
                np.array(list(_numbers(ours[key]))), np.array(list(_numbers(ale[key]))), rtol=1e-13
            ), key
    for table, fields in (
        ("instrument_pointing", ("ephemeris_times", "quaternions", "angular_velocities")),
        ("body_rotation", ("ephemeris_times", "quaternions", "constant_rotation")),
        ("instrument_position", ("ephemeris_times", "positions", "velocities")),
        ("sun_position", ("ephemeris_times", "positions", "velocities")),
    ):
        for field in fields:
            np.testing.assert_allclose(
                ours[table][field], ale[table][field], rtol=1e-13, atol=1e-12, err_msg=table
            )


def _numbers(value: object):
    if isinstance(value, dict):
        for v in value.values():
            yield from _numbers(v)
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v)
    elif isinstance(value, int | float):
        yield float(value)


# ISIS's Apollo 15 Metric lens, as published in its instrument addendum (apollo15MetricAddendum):
# principal point (mm), radial k1..k3 and decentering j1, j2, t0
XP, YP = -0.006, -0.002
K1, K2, K3 = -1.3361854e-06, 5.2261757e-10, -5.0728336e-14
J1, J2, T0 = -5.4958195e-07, -4.608942e-11, 2.965907


def _focal_mm(line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Focal-plane mm of the Hadley cube's CSM (line, sample): 4x reduction from sample 4396.5 and
    line 7996.5 (AlphaCube), detector centre 11449.5, ITRANSS = (0, -200, 0), ITRANSL = (0, 0,
    200)."""
    det_sample, det_line = 4 * sample + 4396.0, 4 * line + 7996.0
    return -(det_sample - 11449.5) / 200.0, (det_line - 11449.5) / 200.0


@pytest.mark.realdata
def test_apollo_differs_from_the_lensless_truth_by_isis_lens() -> None:
    """The Hadley frame from its cube sees usgscsm's ground points (ALE's ISD has no lens model)
    at the pixels that ISIS's ApolloMetricDistortionMap predicts: worked here from the
    published coefficients, the undistorted focal-plane point of our pixel (x_u = dr x - dt
    sin t0, y_u = dr y + dt cos t0 about the principal point) is the truth's pixel's."""
    cam = read_camera(_cube(APOLLO))
    assert isinstance(cam, CsmFrameCamera)
    truth = _truth(APOLLO)
    pts = truth["points"]
    line, sample = _grid(truth)
    for k in range(len(truth["settings"]["heights_m"])):
        want = np.array([p["heights"][k]["ground"] for p in pts])
        t_line = np.array([p["heights"][k]["g2i"]["line"] for p in pts])
        t_sample = np.array([p["heights"][k]["g2i"]["sample"] for p in pts])
        o_line, o_sample, _ = cam.csm_ground_to_image(want)
        x, y = _focal_mm(o_line, o_sample)
        x, y = x - XP, y - YP
        rr = x * x + y * y
        dr = 1 + K1 * rr + K2 * rr**2 + K3 * rr**3
        dt = J1 * rr + J2 * rr**2
        ux, uy = dr * x - dt * np.sin(T0), dr * y + dt * np.cos(T0)
        tx, ty = _focal_mm(t_line, t_sample)
        assert np.abs(ux - tx).max() * 50 < 1e-6  # mm to cube pixels (0.02 mm each)
        assert np.abs(uy - ty).max() * 50 < 1e-6
        shift = np.hypot(o_line - t_line, o_sample - t_sample)
        assert 0.2 < shift.min() and 1.5 < shift.max() < 1.8  # the lens moves every point
    # image to ground: our ray through a pixel is the lens-free ray through the pixel whose
    # focal-plane point is the undistorted one
    plain = read_isd(shared("isis", f"{APOLLO}.isd.json"))
    x, y = _focal_mm(line, sample)
    x, y = x - XP, y - YP
    rr = x * x + y * y
    dr = 1 + K1 * rr + K2 * rr**2 + K3 * rr**3
    dt = J1 * rr + J2 * rr**2
    ux, uy = dr * x - dt * np.sin(T0), dr * y + dt * np.cos(T0)
    p_sample = (-200.0 * ux + 11449.5 - 4396.0) / 4
    p_line = (200.0 * uy + 11449.5 - 7996.0) / 4
    ours = cam.csm_image_to_ground(line, sample, 0.0)
    lensless = plain.csm_image_to_ground(p_line, p_sample, 0.0)
    assert np.linalg.norm(ours - lensless, axis=1).max() < 0.01


@pytest.mark.realdata
def test_apollo_against_the_converted_tsai() -> None:
    """The pinhole model converted from the same cube's tables (no lens) sees the cube
    reader's lens-free geometry within 0.2 px everywhere (a constant eighth of a pixel: the
    4x reduction of a half-pixel convention); with ISIS's lens the two differ by 0.4 px (the
    corner nearest the principal point) to 1.95 px (the far corner) over the crop."""
    cam = read_cube_camera(_cube(APOLLO))
    plain = read_isd(shared("isis", f"{APOLLO}.isd.json"))
    tsai = read_camera(shared("as15-hadley", f"{APOLLO}.converted.tsai"))
    g = np.linspace(0.0, 749.0, 7)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    lensless = np.linalg.norm(tsai.project(plain.image_to_ground(uv, 0.0))[0] - uv, axis=1)
    assert lensless.max() < 0.2
    with_lens = np.linalg.norm(tsai.project(cam.image_to_ground(uv, 0.0))[0] - uv, axis=1)
    assert 0.3 < with_lens.min() and 1.8 < with_lens.max() < 2.0


# --- times and tables ---------------------------------------------------------------------


def test_utc_to_et_matches_spice() -> None:
    """SPICE's str2et values: J2000 noon UTC is 64.183927 s TDB (32 leap seconds + 32.184 s +
    the periodic term); 1971 takes TAI - UTC = 9 s (one less than the table's first entry)."""
    assert utc_to_et("2000-01-01T12:00:00") == pytest.approx(64.183927284, abs=1e-6)
    assert utc_to_et("2017-01-01T00:00:00Z") - utc_to_et("2016-12-31T23:59:59") == pytest.approx(
        2.0, abs=1e-6
    )  # the leap second
    assert utc_to_et("1971-08-01T11:41:16.865") == pytest.approx(-896833081.95174, abs=1e-5)


@pytest.mark.realdata
def test_clock_time_hex_with_leading_zeros(tmp_path: Path) -> None:
    """A CLOCK_ET value whose leading zeros a PVL reader would strip is padded back to 16 hex
    digits: 0000000000002040 is the little-endian double 8.0."""
    path = _edited(tmp_path, LRO, lambda t: t.replace("= 83402a625b6bb441", "= 0000000000002040"))
    assert SpiceCube(path).clock_et("1/311000799:63569") == 8.0
    assert (
        SpiceCube(_cube(LRO)).clock_et("1/311000799:63569")
        == struct.unpack("<d", bytes.fromhex("83402a625b6bb441"))[0]
    )


def _append_table(data: bytearray, rows: np.ndarray) -> tuple[int, int]:
    start = len(data) + 1
    data += rows.astype("<f8").tobytes()
    return start, rows.size * 8


@pytest.mark.realdata
def test_polynomial_table_cache(tmp_path: Path) -> None:
    """spiceinit's polynomial form (ZXZ Euler angle and position coefficients, the last record
    holding base time, time scale and degree) gives the camera of the record form: the LRO
    tables rewritten as the polynomials through their records (angles from scipy's Euler
    decomposition, ISIS's convention eul2m(a3, a2, a1, 3, 1, 3))."""
    from scipy.spatial.transform import Rotation

    cube = SpiceCube(_cube(LRO))
    point, pos = cube.table("InstrumentPointing"), cube.table("InstrumentPosition")
    q = np.stack([point.columns[f"J2000Q{i}"] for i in range(4)], -1)
    t_q = point.columns["ET"]
    angles = -Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("zxz")  # (a1, a2, a3) per row
    base, scale = t_q.mean(), (t_q[-1] - t_q[0]) / 2
    deg = len(t_q) - 1
    vander = np.vander((t_q - base) / scale, deg + 1, increasing=True)
    ang_coef = np.linalg.solve(vander, np.unwrap(angles, axis=0))
    t_p = pos.columns["ET"]
    xyz = np.stack([pos.columns[f"J2000{a}"] for a in "XYZ"], -1)
    p_base, p_scale = t_p.mean(), (t_p[-1] - t_p[0]) / 2
    pos_coef = np.linalg.solve(np.vander((t_p - p_base) / p_scale, len(t_p), increasing=True), xyz)
    data = bytearray(_cube(LRO).read_bytes())
    q_start, q_bytes = _append_table(data, np.vstack([ang_coef, [base, scale, deg]]))
    p_start, p_bytes = _append_table(data, np.vstack([pos_coef, [p_base, p_scale, len(t_p) - 1]]))
    fields = "".join(
        f"\n  Group = Field\n    Name = {n}\n    Type = Double\n    Size = 1\n  End_Group\n"
        for n in ("{0}1", "{0}2", "{0}3")
    )
    text = data[: data.index(b"\nEnd\n") + 5].decode("latin-1")

    def table(name: str, start: int, nbytes: int, records: int, extra: str, prefix: str) -> str:
        return (
            f"Object = Table\n  Name = {name}\n  StartByte = {start}\n  Bytes = {nbytes}\n"
            f"  Records = {records}\n  ByteOrder = Lsb\n{extra}"
            + fields.format(prefix)
            + "End_Object\n"
        )

    text = _drop_object(
        _drop_object(text, "Table", "InstrumentPointing"), "Table", "InstrumentPosition"
    )
    t0, t1 = t_q[0], t_q[-1]
    text = text.replace(
        "Object = History",
        table(
            "InstrumentPointing",
            q_start,
            q_bytes,
            len(ang_coef) + 1,
            f"  TimeDependentFrames = (-85600, 1)\n  CkTableStartTime = {float(t0)!r}\n"
            f"  CkTableEndTime = {float(t1)!r}\n  CkTableOriginalSize = 101\n",
            "J2000Ang",
        )
        + table(
            "InstrumentPosition",
            p_start,
            p_bytes,
            len(pos_coef) + 1,
            f"  SpkTableStartTime = {float(t_p[0])!r}\n  SpkTableEndTime = {float(t_p[-1])!r}\n"
            "  SpkTableOriginalSize = 101\n",
            "J2000SV",
        )
        .replace("Name = J2000SV1", "Name = J2000SVX")
        .replace("Name = J2000SV2", "Name = J2000SVY")
        .replace("Name = J2000SV3", "Name = J2000SVZ")
        + "Object = History",
        1,
    )
    encoded = text.encode("latin-1")
    data[:LABEL_BYTES] = encoded + bytes(LABEL_BYTES - len(encoded))
    path = tmp_path / "poly.cub"
    path.write_bytes(bytes(data))
    isd = cube_isd(path)
    times = np.linspace(t0, t1, 101)
    np.testing.assert_allclose(isd["instrument_pointing"]["ephemeris_times"], times)
    tt = (times - base) / scale
    euler = np.stack([np.polynomial.polynomial.polyval(tt, ang_coef[:, i]) for i in range(3)], -1)
    want = Rotation.from_euler("zxz", -euler).as_quat()[:, [3, 0, 1, 2]]  # (w, x, y, z)
    got = np.array(isd["instrument_pointing"]["quaternions"])
    want *= np.sign(np.sum(want * got, axis=1))[:, None]
    np.testing.assert_allclose(got, want, atol=1e-12)
    np.testing.assert_allclose(got[[0, -1]], q[[0, -1]] * np.sign(q[0, 0] * got[0, 0]), atol=1e-12)
    positions = np.array(isd["instrument_position"]["positions"])
    np.testing.assert_allclose(positions[[0, -1]], xyz[[0, -1]], atol=1e-9)
    # the camera: within what a cubic in Euler angles and SLERP between records differ by
    poly, records = read_cube_camera(path), read_cube_camera(_cube(LRO))
    g = np.linspace(0.0, 399.0, 9)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    assert np.abs(poly.project(records.image_to_ground(uv, 0.0))[0] - uv).max() < 0.1


# --- bad input ----------------------------------------------------------------------------


def _no_spice(text: str) -> str:
    text = re.sub(r"  Group = Kernels\n(?:.*\n)*?  End_Group\n", "", text)
    return _drop_object(_drop_object(text, "Table"), "NaifKeywords")


@pytest.mark.realdata
@pytest.mark.parametrize(
    ("name", "edit", "size", "expect"),
    [
        (LRO, _no_spice, None, r"no SPICE attached: run spiceinit \(attach=yes\), or give an ISD"),
        (
            LRO,
            lambda t: _drop_object(t, "Table", "InstrumentPointing").replace(
                "InstrumentPointing        = (Table,\n                                 $lro",
                "InstrumentPointing        = ($lro",
            ),
            None,
            r"Table InstrumentPointing is not attached: Kernels InstrumentPointing points to "
            r"kernels \(\$lro/kernels/ck/lrolc",
        ),
        (
            LRO,
            lambda t: t.replace("InstrumentId                = NACL", "InstrumentId = HIRISE"),
            None,
            r"instrument 'HIRISE' of 'LUNAR RECONNAISSANCE ORBITER' is not supported .*"
            r"give an ISD from ALE's isd_generate instead",
        ),
        (
            APOLLO,
            lambda t: t.replace(
                "  Group = AlphaCube",
                "  Group = Mapping\n    ProjectionName = Equirectangular\n  End_Group\n\n"
                "  Group = AlphaCube",
            ),
            None,
            r"map-projected \(level 2\) cube \(IsisCube > Group = Mapping\) has no camera",
        ),
        (LRO, lambda t: t, 706000, r"truncated Table BodyRotation"),
        (
            LRO,
            lambda t: re.sub(r"  INS-85600_OD_K +=.*\n", "", t),
            None,
            r"NaifKeywords lacks INS-85600_OD_K",
        ),
        (
            APOLLO,
            lambda t: t.replace("= 1971-08-01T11:41:16.865", "= 1971-08-01T11:41:18.865"),
            None,
            r"the image time .* is \+2\.0+ s from the one record of its",
        ),
        (
            LRO,
            lambda t: _alpha(t, (2999.5, 16800.5), (1.0, 1.0), 400),
            None,
            r"the cube's lines are exposed over ET \[.*\], beyond its instrument_pointing table",
        ),
    ],
    ids=[
        "no-spice",
        "kernels-not-attached",
        "unsupported",
        "map-projected",
        "truncated",
        "missing-key",
        "time-outside",
        "lines-outside",
    ],
)
def test_bad_cubes(
    tmp_path: Path, capsys: pytest.CaptureFixture, name: str, edit, size: int | None, expect: str
) -> None:
    """Each bad cube: one line naming the file and what is missing, from the API
    (InputError/FormatError) and on the command line (exit status 2)."""
    from orthomvp.cli import main

    path = _edited(tmp_path, name, edit, size=size)
    with pytest.raises(InputError, match=expect) as info:
        read_camera(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    dem = shared("as15-hadley", "LOLA_hadley_dem.tif")
    out = tmp_path / "o.tif"
    capsys.readouterr()
    assert main(["-q", "ortho", str(dem), str(path), str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: error: ") and str(path) in err[0]
    assert not out.exists()


@pytest.mark.realdata
def test_points_outside_the_tables_are_nan() -> None:
    """Ground points seen before the first or after the last line (outside the tables'
    times) project to NaN, not to extrapolated pixels; rays beyond the lines are NaN."""
    cam = read_cube_camera(_cube(LRO))
    uv = np.array([[200.0, 0.0], [200.0, 399.0]])
    first, last = cam.image_to_ground(uv, 0.0)
    beyond = np.array([first - (last - first) * 0.5, last + (last - first) * 0.5])
    assert np.isnan(cam.project(beyond)[0]).all()
    assert np.isnan(cam.ray(np.array([[200.0, -50.0], [200.0, 460.0]]))[1]).all()


@pytest.mark.realdata
def test_format_errors_name_the_file_for_a_cube_that_is_not_one(tmp_path: Path) -> None:
    """A .cub that is not a cube is not taken for one."""
    path = tmp_path / "x.cub"
    path.write_text("hello\n")
    with pytest.raises(FormatError, match=re.escape(str(path))):
        read_camera(path)


def _alpha(text: str, start: tuple[float, float], slope: tuple[float, float], beta: int) -> str:
    """``text`` with its AlphaCube group's start (sample, line) and reduction (slopes) set."""
    values = {
        "AlphaStartingSample": start[0],
        "AlphaStartingLine": start[1],
        "AlphaEndingSample": start[0] + slope[0] * beta,
        "AlphaEndingLine": start[1] + slope[1] * beta,
    }
    for key, value in values.items():
        text = re.sub(rf"({key} +=) \S+", rf"\g<1> {value!r}", text)
    return text


@pytest.mark.realdata
@pytest.mark.parametrize(
    ("name", "start", "slope"),
    [
        (APOLLO, (4000.25, 7000.5), (15.976, 15.976)),  # a reduced cube of 15.976x
        (APOLLO, (4396.5, 7996.5), (3.7, 4.3)),
        (LRO, (2999.5, 15999.5), (1.5, 1.25)),  # line scanner: longer lines, wider samples
        (LRO, (2000.5, 16099.5), (2.5, 0.75)),
    ],
)
def test_alpha_cube_reductions(tmp_path: Path, name: str, start: tuple, slope: tuple) -> None:
    """A cropped and reduced cube (any real factor) sees a ground point at the pixel that the
    AlphaCube formula alpha = slope (beta - 0.5) + start carries the shared cube's pixel to."""
    samples, lines = SpiceCube(_cube(name)).size
    ref = read_cube_camera(_cube(name))
    alpha_ref = SpiceCube(_cube(name)).alpha
    path = _edited(tmp_path, name, lambda t: _alpha(t, start, slope, samples))
    cam = read_cube_camera(path)
    g = np.linspace(0.0, samples - 1.0, 5)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    ground = ref.image_to_ground(uv, 0.0)
    # the shared cube's pixel -> 1-based alpha -> the edited cube's pixel (beta - 1)
    a_s = alpha_ref.sample_slope * (uv[:, 0] + 0.5) + alpha_ref.start_sample
    a_l = alpha_ref.line_slope * (uv[:, 1] + 0.5) + alpha_ref.start_line
    want = np.stack([(a_s - start[0]) / slope[0] - 0.5, (a_l - start[1]) / slope[1] - 0.5], -1)
    got = cam.project(ground)[0]
    inside = (want[:, 1] > -0.4) & (want[:, 1] < lines - 0.6)
    np.testing.assert_allclose(got[inside], want[inside], atol=1e-3)
    if name == LRO:  # a line scanner sees nothing before its first or after its last line
        outside = (want[:, 1] < -0.6) | (want[:, 1] > lines - 0.4)
        assert np.isnan(got[outside]).all()


def _hex_et(et: float) -> str:
    """A CLOCK_ET value: the little-endian double's 16 hex digits."""
    return struct.pack("<d", et).hex()


LRO_RATE = 0.3632e-3 * 1.0045  # the LRO crop's line time, s (LineExposureDuration, MULTIPLI)


@pytest.mark.realdata
@pytest.mark.parametrize(("summing", "first"), [(1, 100), (2, 0)])
def test_ctx_rules(tmp_path: Path, summing: int, first: int) -> None:
    """CTX's rules on the LRO crop relabelled as CTX (no lens): lines start at the clock time
    (no preroll) and last LineExposureDuration x SpatialSumming, samples are summed and start
    at SampleFirstPixel: it sees what the lens-free LRO camera sees, at the sample that the
    detector mapping carries it to (detector = summing x sample + first, in CSM samples)."""
    clock = "0911857281:050"
    lro = json.loads(shared("isis", f"{LRO}.isd.json").read_text())
    start = struct.unpack("<d", bytes.fromhex("83402a625b6bb441"))[0] + 1024 * LRO_RATE

    def edit(text: str) -> str:
        text = re.sub(
            r'SpacecraftName += "LUNAR RECONNAISSANCE ORBITER"',
            "SpacecraftName = Mars_Reconnaissance_Orbiter",
            text,
            count=1,
        )
        text = text.replace(
            "InstrumentId                = NACL",
            f'InstrumentId = CTX\n    SpacecraftClockCount = "{clock}"',
        )
        text = text.replace("= 0.363200 <ms>", f"= {LRO_RATE * 1000 / summing!r} <ms>")
        text = re.sub(r"SpatialSumming +\= 1", f"SpatialSumming = {summing}", text)
        text = re.sub(r"SampleFirstPixel +\= 0", f"SampleFirstPixel = {first}", text)
        text = re.sub(r"INS-85600_OD_K +=.*", "INS-85600_OD_K = (0.0, 0.0, 0.0)", text)
        return text.replace(
            "End_Object\n\nObject = OriginalLabel",
            f"  CLOCK_ET_-74_{clock}_COMPUTED = {_hex_et(start)}\nEnd_Object\n\n"
            "Object = OriginalLabel",
        )

    path = _edited(tmp_path, LRO, edit)
    isd = cube_isd(path)
    assert isd["line_scan_rate"][0][2] == pytest.approx(LRO_RATE, rel=1e-12)
    assert isd["starting_ephemeris_time"] == pytest.approx(lro["starting_ephemeris_time"], abs=1e-7)
    assert isd["detector_sample_summing"] == summing
    ctx = read_cube_camera(path)
    plain = camera_from_isd_without_lens(lro)
    g = np.linspace(0.0, 399.0, 5)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    ground = plain.image_to_ground(uv, 0.0)
    got = ctx.project(ground)[0]
    # LRO detector sample (u + 0.5) + 2999 = CTX's summing (u' + 0.5) + summing 2999 + first
    want_u = ((uv[:, 0] + 0.5 + 2999) - summing * 2999 - first) / summing - 0.5
    np.testing.assert_allclose(got[:, 0], want_u, atol=1e-6)
    np.testing.assert_allclose(got[:, 1], uv[:, 1], atol=1e-6)


def camera_from_isd_without_lens(isd: dict) -> LineScanCamera:
    """The camera of ALE's LRO ISD with its lens coefficient set to 0."""
    from orthomvp.camera.csm import camera_from_isd

    return camera_from_isd({**isd, "optical_distortion": {"lrolrocnac": {"coefficients": [0.0]}}})


@pytest.mark.realdata
@pytest.mark.parametrize(("pixel_binning", "fpu_binning", "summing"), [(0, 0, 1), (2, 1, 4)])
def test_mdis_rules(tmp_path: Path, pixel_binning: int, fpu_binning: int, summing: int) -> None:
    """MDIS's rules on the Hadley frame relabelled as MDIS-NAC (identity Taylor lens): the
    time is mid-exposure after the clock time, the focal length is the FL_TEMP_COEFFS
    polynomial at FocalPlaneTemperature, binning sums pixels (doubled by FPU binning); and a
    camera looking along +z with the Apollo frame's pose sees, without summing, each ground
    point at the pixel point-reflected about the detector centre from the lens-free Apollo
    camera's."""
    clock = "1/0012345678:000"
    table_et = -896833081.9517406
    coeffs = "(75.954, -0.005, 0.0, 0.0, 0.0, 0.0)"  # 76.054 mm at -20 C

    def edit(text: str) -> str:
        text = text.replace('SpacecraftName = "APOLLO 15"', "SpacecraftName = MESSENGER")
        text = text.replace(
            "InstrumentId   = METRIC",
            f'InstrumentId = MDIS-NAC\n    SpacecraftClockCount = "{clock}"\n'
            f"    ExposureDuration = 10 <ms>\n    FpuBinningMode = {fpu_binning}\n"
            f"    PixelBinningMode = {pixel_binning}\n    FocalPlaneTemperature = -20.0",
        )
        text = text.replace("NaifFrameCode             = -915240", "NaifFrameCode = -236820")
        text = text.replace("INS-915240_", "INS-236820_")
        extra = (
            f"  CLOCK_ET_-236_{clock}_COMPUTED = {_hex_et(table_et - 0.005)}\n"
            "  INS-236820_BORESIGHT_SAMPLE = 11450.0\n  INS-236820_BORESIGHT_LINE = 11450.0\n"
            f"  INS-236820_FL_TEMP_COEFFS = {coeffs}\n"
            "  INS-236820_OD_T_X = (0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)\n"
            "  INS-236820_OD_T_Y = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)\n"
        )
        return text.replace("End_Object\nEnd\n", extra + "End_Object\nEnd\n")

    path = _edited(tmp_path, APOLLO, edit)
    isd = cube_isd(path)
    assert isd["center_ephemeris_time"] == pytest.approx(table_et, abs=1e-6)
    assert isd["focal_length_model"]["focal_length"] == pytest.approx(76.054, abs=1e-12)
    assert isd["detector_sample_summing"] == isd["detector_line_summing"] == 4 * summing
    assert isd["detector_center"] == {"line": 11449.5, "sample": 11449.5}
    if summing > 1:
        return
    mdis = read_cube_camera(path)
    plain = read_isd(shared("isis", f"{APOLLO}.isd.json"))
    g = np.linspace(0.0, 749.0, 5)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    got = mdis.project(plain.image_to_ground(uv, 0.0))[0]
    # detector 4 (u + 0.5) + start - 11449.5 negated: u' = (2 (11449.5 - start)) / 4 - 1 - u
    want = np.stack([3525.75 - uv[:, 0], 1725.75 - uv[:, 1]], -1)
    np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.realdata
def test_lro_cube_as_camera_through_the_command_line(tmp_path: Path) -> None:
    """`orthomvp ortho DEM IMAGE CUBE`: an image whose bands hold each pixel's own column and
    row, orthorectified through the LRO cube's camera onto a flat DEM of the Moon's sphere,
    gives at usgscsm's ground points (h = 0) usgscsm's own ground-to-image pixel."""
    cube = _cube(LRO)
    checked = ramp_ortho_checks(
        tmp_path, read_camera(cube), cube, _truth(LRO), rows=400, cols=400, radius=1737400.0
    )
    assert checked >= 25


@pytest.mark.realdata
@pytest.mark.slow
def test_hadley_cube_as_its_own_camera(tmp_path: Path) -> None:
    """`orthomvp ortho LOLA_DEM CUBE CUBE` (the cube as its own camera) gives the orthophoto
    of the pixels and lens-free pinhole (.tif + .converted.tsai) to within the lens model's
    1-2 pixels: the two correlate above 0.95 over 80 % of the DEM."""
    import rasterio

    from orthomvp.cli import main

    dem = shared("as15-hadley", "LOLA_hadley_dem.tif")
    cube = _cube(APOLLO)
    tsai = shared("as15-hadley", f"{APOLLO}.converted.tsai")
    a, b = tmp_path / "cube.tif", tmp_path / "tsai.tif"
    grid = ["--grid", "dem"]  # both on one grid
    assert main(["-q", "ortho", str(dem), str(cube), str(cube), "-o", str(a), *grid]) == 0
    tif = shared("as15-hadley", f"{APOLLO}.tif")
    assert main(["-q", "ortho", str(dem), str(tif), str(tsai), "-o", str(b), *grid]) == 0
    with rasterio.open(a) as src_a, rasterio.open(b) as src_b:
        one, two = src_a.read(1).astype(float), src_b.read(1).astype(float)
        nodata = src_a.nodata
    ok = np.isfinite(one) & np.isfinite(two)
    if nodata is not None:
        ok &= (one != nodata) & (two != nodata)
    assert ok.mean() > 0.8
    assert np.corrcoef(one[ok], two[ok])[0, 1] > 0.95


@pytest.mark.realdata
def test_lro_nac_right_flips_the_line_axis(tmp_path: Path) -> None:
    """The right NAC's frame is turned by 180 degrees: flying the same way as the left one
    (whose ISD keeps ITRANSL), its line axis is negated, as ALE does."""
    path = _edited(
        tmp_path,
        LRO,
        lambda t: (
            t.replace("INS-85600_", "INS-85610_")
            .replace("NaifFrameCode             = -85600", "NaifFrameCode = -85610")
            .replace("InstrumentId                = NACL", "InstrumentId = NACR")
        ),
    )
    left, right = cube_isd(_cube(LRO)), cube_isd(path)
    assert left["focal2pixel_lines"] == [0.0, 142.857, 0.0]
    assert right["focal2pixel_lines"] == [-0.0, -142.857, -0.0]
    assert isinstance(read_cube_camera(path), LineScanCamera)


@pytest.mark.realdata
def test_dawn_fc_rules(tmp_path: Path) -> None:
    """Dawn FC's rules on the Hadley frame relabelled as FC2 (a 1024 x 1024 original image,
    crop from pixel 100, no lens): mid-exposure time 193 ms after the clock start, detector
    centre CCD_CENTER + 0.5; looking along +z with the Apollo frame's pose, it sees each ground
    point at the detector position point-reflected about the centre from the lens-free Apollo
    camera's."""
    clock = "488933127:000"
    table_et = -896833081.9517406

    def edit(text: str) -> str:
        text = text.replace('SpacecraftName = "APOLLO 15"', "SpacecraftName = DAWN")
        text = text.replace(
            "InstrumentId   = METRIC",
            f'InstrumentId = FC2\n    SpacecraftClockStartCount = "{clock}"\n'
            "    ExposureDuration = 20 <ms>",
        )
        text = text.replace("NaifFrameCode             = -915240", "NaifFrameCode = -203121")
        text = text.replace("INS-915240_", "INS-203121_")
        text = _alpha(text, (100.5, 200.5), (1.0, 1.0), 750)
        text = re.sub(r"Alpha(Samples|Lines) += 22900", r"Alpha\1 = 1024", text)
        extra = (
            f"  CLOCK_ET_-203_{clock}_COMPUTED = {_hex_et(table_et - 0.193 - 0.010)}\n"
            "  INS-203121_CCD_CENTER = (511.5, 511.5)\n  INS-203121_RAD_DIST_COEFF = 0.0\n"
        )
        return text.replace("End_Object\nEnd\n", extra + "End_Object\nEnd\n")

    path = _edited(tmp_path, APOLLO, edit)
    isd = cube_isd(path)
    assert isd["center_ephemeris_time"] == pytest.approx(table_et, abs=1e-6)
    assert isd["detector_center"] == {"line": 512.0, "sample": 512.0}
    assert isd["optical_distortion"] == {"dawnfc": {"coefficients": [0.0]}}
    assert (isd["starting_detector_sample"], isd["starting_detector_line"]) == (100.0, 200.0)
    fc = read_cube_camera(path)
    plain = read_isd(shared("isis", f"{APOLLO}.isd.json"))
    g = np.linspace(0.0, 749.0, 5)
    uv = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    got = fc.project(plain.image_to_ground(uv, 0.0))[0]
    # Apollo: detector 4 (u + 0.5) + start about 11449.5; FC2: (u' + 0.5) + first about 512
    off_s = 4 * (uv[:, 0] + 0.5) + 4396.0 - 11449.5
    off_l = 4 * (uv[:, 1] + 0.5) + 7996.0 - 11449.5
    want = np.stack([512.0 - off_s - 100.0 - 0.5, 512.0 - off_l - 200.0 - 0.5], -1)
    np.testing.assert_allclose(got, want, atol=1e-6)


@pytest.mark.realdata
def test_ales_apollo_isd_with_its_negative_focal_length() -> None:
    """ALE's ISD of the Hadley frame (focal length -76.054 mm: the camera looks along -z) read
    as an ISD gives usgscsm's own numbers: image to ground within 1 cm, ground to image within
    0.01 px, points in front of the camera at positive depth."""
    cam = read_isd(shared("isis", f"{APOLLO}.isd.json"))
    truth = _truth(APOLLO)
    line, sample = _grid(truth)
    pts = truth["points"]
    for k, height in enumerate(truth["settings"]["heights_m"]):
        want = np.array([p["heights"][k]["ground"] for p in pts])
        ground = cam.csm_image_to_ground(line, sample, height)
        assert np.linalg.norm(ground - want, axis=1).max() < 0.01
        g_line, g_sample, depth = cam.csm_ground_to_image(want)
        g2i = np.array(
            [[r["g2i"]["line"], r["g2i"]["sample"]] for r in (p["heights"][k] for p in pts)]
        )
        assert np.abs(np.stack([g_line, g_sample], -1) - g2i).max() < 0.01
        assert (depth > 1e5).all()  # about 106 km below the spacecraft


@pytest.mark.realdata
def test_frame_states_between_records() -> None:
    """A frame camera's state from multi-record tables (here the LRO crop's) at a time between
    records: positions by cubic Hermite on positions and velocities, rotations by SLERP
    (checked with scipy's), and InputError outside the tables (never extrapolated)."""
    from scipy.interpolate import CubicHermiteSpline
    from scipy.spatial.transform import Rotation, Slerp

    from orthomvp.camera.isis.isd import states_at

    cube = SpiceCube(_cube(LRO))
    spice = cube.spice
    pos = spice["instrument_position"]
    t = np.asarray(pos["ephemeris_times"])
    time = 0.3 * t[0] + 0.7 * t[1]
    state = states_at(cube, spice, time)
    spline = CubicHermiteSpline(t, np.asarray(pos["positions"]), np.asarray(pos["velocities"]))
    np.testing.assert_allclose(
        state["instrument_position"]["positions"][0], spline(time), atol=1e-9
    )
    point = spice["instrument_pointing"]
    q = np.asarray(point["quaternions"])
    slerp = Slerp(np.asarray(point["ephemeris_times"]), Rotation.from_quat(q[:, [1, 2, 3, 0]]))
    want = slerp([time]).as_quat()[0][[3, 0, 1, 2]]
    got = np.asarray(state["instrument_pointing"]["quaternions"][0])
    np.testing.assert_allclose(got * np.sign(got @ want), want, atol=1e-12)
    with pytest.raises(InputError, match="outside its instrument_pointing table"):
        states_at(cube, spice, t[0] - 0.01)
