"""Tests of the camera formats of issue 7: every ASP ``.tsai`` version and distortion model, and
Orthority's interior (YAML) and exterior (CSV, GeoJSON) parameter files.

Expected values come from the formulas in the ASP documentation ("Pinhole models") and VW's
LensDistortion.cc, from OpenCV's own implementation (cv2.projectPoints, an independent code
base), from Orthority's documented conventions, and from the ``*.converted.tsai`` files in
../shared/data, which were converted from the originals independently of this code.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared
from scipy.spatial.transform import Rotation

from orthomvp.camera import (
    BrownConradyDistortion,
    Distortion,
    FisheyeDistortion,
    FovDistortion,
    NullDistortion,
    OpenCVDistortion,
    PhotometrixDistortion,
    PinholeCamera,
    TsaiDistortion,
    orthority_rotation,
    read_camera,
    read_orthority_cameras,
    tsai_text,
    write_json,
    write_tsai,
)
from orthomvp.errors import FormatError, InputError

WIDTH, HEIGHT = 1000, 800
FOCAL = np.array([1200.0, 1150.0])
OFFSET = np.array([510.0, 390.0])

LENSES: dict[str, Distortion] = {
    "null": NullDistortion(),
    "tsai": TsaiDistortion(k1=-0.28, k2=0.1, p1=-8e-4, p2=9e-4, k3=0.01),
    "brown": BrownConradyDistortion(
        xp=-0.6, yp=-0.2, k1=1e-7, k2=-5e-14, k3=1e-20, p1=5e-7, p2=1e-12, phi=0.201
    ),
    "photometrix": PhotometrixDistortion(
        xp=0.4, yp=-0.3, k1=1e-7, k2=-5e-14, k3=1e-20, p1=3e-7, p2=-2e-7, b1=0.0, b2=0.0
    ),
    "fisheye": FisheyeDistortion(k1=-0.03, k2=0.04, k3=-0.06, k4=0.03),
    "fov": FovDistortion(k1=0.9),
    "opencv": OpenCVDistortion(
        k1=-0.2,
        k2=0.05,
        p1=1e-3,
        p2=-2e-3,
        k3=0.01,
        k4=0.1,
        k5=-0.02,
        k6=0.003,
        s1=1e-3,
        s2=-2e-4,
        s3=5e-4,
        s4=1e-4,
        tx=0.02,
        ty=-0.03,
    ),  # fmt: skip
}


def image_grid(n: int = 21) -> np.ndarray:
    """(n * n, 2) pixels spanning a WIDTH x HEIGHT image, edges included."""
    u, v = np.meshgrid(np.linspace(-0.5, WIDTH - 0.5, n), np.linspace(-0.5, HEIGHT - 0.5, n))
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def grid_points(camera: PinholeCamera, distance: float, n: int = 15) -> np.ndarray:
    """World points at ``distance`` along the rays through an n x n grid over the image."""
    width, height = camera.width or WIDTH, camera.height or HEIGHT
    u, v = np.meshgrid(np.linspace(-0.5, width - 0.5, n), np.linspace(-0.5, height - 0.5, n))
    origins, directions = camera.ray(np.stack([u, v], axis=-1))
    return origins + directions * distance


# ---------------------------------------------------------------------------------------------
# Lens distortion: round trips, hand values, OpenCV as the reference


@pytest.mark.parametrize("lens", [k for k in LENSES if k != "null"])
def test_distort_undistort_round_trip(lens: str) -> None:
    model = LENSES[lens]
    pixels = image_grid()
    moved = model.distort(pixels, FOCAL, OFFSET)
    assert np.abs(moved - pixels).max() > 0.5  # the lens moves pixels visibly
    np.testing.assert_allclose(model.undistort(moved, FOCAL, OFFSET), pixels, rtol=0, atol=1e-9)
    back = model.distort(model.undistort(pixels, FOCAL, OFFSET), FOCAL, OFFSET)
    np.testing.assert_allclose(back, pixels, rtol=0, atol=1e-9)


def test_opencv_distortion_agrees_with_cv2() -> None:
    lens = LENSES["opencv"]
    rng = np.random.default_rng(5)
    normalised = rng.uniform(-0.45, 0.45, (500, 2))
    k = np.array([[FOCAL[0], 0, OFFSET[0]], [0, FOCAL[1], OFFSET[1]], [0, 0, 1]])
    coefficients = np.array(list(lens.params().values()))  # k1 k2 p1 p2 k3 k4..k6 s1..s4 tx ty
    rays = np.hstack([normalised, np.ones((500, 1))])
    expected = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, coefficients)[0][:, 0]
    got = lens.distort(normalised * FOCAL + OFFSET, FOCAL, OFFSET)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def test_opencv_hand_value() -> None:
    # one point through OpenCV's documented formulas, step by step
    d = LENSES["opencv"]
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    g = (1 + d.k1 * r2 + d.k2 * r2**2 + d.k3 * r2**3) / (
        1 + d.k4 * r2 + d.k5 * r2**2 + d.k6 * r2**3
    )
    xd = x * g + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x) + d.s1 * r2 + d.s2 * r2**2
    yd = y * g + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y + d.s3 * r2 + d.s4 * r2**2
    ctx, stx, cty, sty = math.cos(d.tx), math.sin(d.tx), math.cos(d.ty), math.sin(d.ty)
    rot = np.array([[cty, 0, -sty], [0, 1, 0], [sty, 0, cty]]) @ np.array(
        [[1, 0, 0], [0, ctx, stx], [0, -stx, ctx]]
    )
    tilt = np.array([[rot[2, 2], 0, -rot[0, 2]], [0, rot[2, 2], -rot[1, 2]], [0, 0, 1]]) @ rot
    h = tilt @ [xd, yd, 1.0]
    expected = FOCAL * h[:2] / h[2] + OFFSET
    got = d.distort(np.array([x, y]) * FOCAL + OFFSET, FOCAL, OFFSET)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


def test_fisheye_agrees_with_cv2_and_hand_value() -> None:
    lens = LENSES["fisheye"]
    x, y = 0.5, -0.4
    r = math.hypot(x, y)
    t = math.atan(r)
    td = t * (1 + lens.k1 * t**2 + lens.k2 * t**4 + lens.k3 * t**6 + lens.k4 * t**8)
    got = lens.distort(np.array([x, y]) * FOCAL + OFFSET, FOCAL, OFFSET)
    np.testing.assert_allclose(got, np.array([x, y]) * td / r * FOCAL + OFFSET, atol=1e-9)
    rng = np.random.default_rng(6)
    rays = np.hstack([rng.uniform(-1.5, 1.5, (300, 2)), np.ones((300, 1))])
    k = np.array([[FOCAL[0], 0, OFFSET[0]], [0, FOCAL[1], OFFSET[1]], [0, 0, 1]])
    coefficients = np.array(list(lens.params().values()))
    expected = cv2.fisheye.projectPoints(rays[None], np.zeros(3), np.zeros(3), k, coefficients)
    got = lens.distort(rays[:, :2] * FOCAL + OFFSET, FOCAL, OFFSET)
    np.testing.assert_allclose(got, expected[0][0], rtol=0, atol=1e-9)
    centre = lens.distort(OFFSET + 1e-10, FOCAL, OFFSET)  # r below 1e-8: the identity, as VW
    np.testing.assert_array_equal(centre, OFFSET + 1e-10)


def test_fov_hand_value() -> None:
    lens = LENSES["fov"]
    x, y = 0.3, 0.4  # r = 0.5
    rd = math.atan(0.5 * 2 * math.tan(0.45)) / 0.9
    got = lens.distort(np.array([x, y]) * FOCAL + OFFSET, FOCAL, OFFSET)
    np.testing.assert_allclose(got, np.array([x, y]) * rd / 0.5 * FOCAL + OFFSET, atol=1e-9)
    with pytest.raises(InputError, match="k1 = -1.0 must be positive"):
        FovDistortion(k1=-1.0)
    far = np.array([[10.0, 0.0]]) * FOCAL + OFFSET  # r_d k1 = 9 > pi / 2: no undistorted pixel
    assert np.isnan(lens.undistort(far, FOCAL, OFFSET)).all()


def test_photometrix_hand_value() -> None:
    # VW: x = X - cu - xp; X_undist = X + x dr/r + P1 (r2 + 2 x^2) + 2 P2 x y (and y alike)
    d = LENSES["photometrix"]
    point = np.array([900.0, 100.0])
    x, y = point - OFFSET - [d.xp, d.yp]
    r2 = x * x + y * y
    drr = d.k1 * r2 + d.k2 * r2**2 + d.k3 * r2**3
    expected = [
        point[0] + x * drr + d.p1 * (r2 + 2 * x * x) + 2 * d.p2 * x * y,
        point[1] + y * drr + d.p2 * (r2 + 2 * y * y) + 2 * d.p1 * x * y,
    ]
    np.testing.assert_allclose(d.undistort(point, FOCAL, OFFSET), expected, rtol=0, atol=1e-9)
    assert abs(expected[0] - point[0]) > 1  # a visible correction


# ---------------------------------------------------------------------------------------------
# .tsai: every version and distortion model ASP documents

BODY = """\
fu = 1200
fv = 1150
cu = 510
cv = 390
u_direction = 1 0 0
v_direction = 0 1 0
w_direction = 0 0 1
C = 100 -200 5000
R = 1 0 0 0 -1 0 0 0 -1
"""
TSAI_PARAMS = "k1 = -0.28\nk2 = 0.1\np1 = -0.0008\np2 = 0.0009\n"
EXPECTED_TSAI = TsaiDistortion(-0.28, 0.1, -0.0008, 0.0009)

VERSIONS = {
    "unversioned": (BODY + TSAI_PARAMS, 1.0, EXPECTED_TSAI),
    "unversioned-pitch-name": (BODY + "pitch = 0.5\nNULL\n", 0.5, NullDistortion()),
    "VERSION_1": ("VERSION_1\n" + BODY + TSAI_PARAMS, 1.0, EXPECTED_TSAI),
    "VERSION_2": ("VERSION_2\n" + BODY + "TSAI\n" + TSAI_PARAMS, 1.0, EXPECTED_TSAI),
    "VERSION_2-pitch": ("VERSION_2\n" + BODY + "pitch = 2\n" + TSAI_PARAMS, 2.0, EXPECTED_TSAI),
    "VERSION_3": ("VERSION_3\n" + BODY + "pitch = 0.01\nNULL\n", 0.01, NullDistortion()),
    "VERSION_4": ("VERSION_4\nPINHOLE\n" + BODY + "pitch = 1\nTSAI\n" + TSAI_PARAMS, 1.0,
                  EXPECTED_TSAI),
    "VERSION_4-k3-any-order": (
        "VERSION_4\nPINHOLE\n" + BODY + "pitch = 1\nTSAI\nk3 = 0.5\np2 = 4\np1 = 3\nk2 = 2\n"
        "k1 = 1\n", 1.0, TsaiDistortion(1, 2, 3, 4, 0.5),
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(VERSIONS))
def test_every_tsai_version(tmp_path: Path, case: str) -> None:
    text, pitch, lens = VERSIONS[case]
    path = tmp_path / "cam.tsai"
    path.write_text(text)
    cam = read_camera(path)
    assert (cam.fu, cam.fv, cam.cu, cam.cv, cam.pitch) == (1200, 1150, 510, 390, pitch)
    assert cam.distortion == lens
    np.testing.assert_array_equal(cam.rotation, np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(cam.center, [100, -200, 5000])


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ("VERSION_3\n" + BODY + "NULL\n", 11, "expected 'pitch = ...', found 'NULL'"),
        ("VERSION_3\n" + BODY + "pitch = 1\n" + TSAI_PARAMS, 12, "unsupported lens distortion"),
        ("VERSION_4\n" + BODY, 2, "camera type 'fu = 1200' is not supported"),
        ("VERSION_5\n" + BODY, 1, "unsupported version 'VERSION_5'"),
    ],
)
def test_tsai_version_rules(tmp_path: Path, text: str, line: int, message: str) -> None:
    path = tmp_path / "cam.tsai"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        read_camera(path)
    assert info.value.line == line


# The distortion sections of the ASP documentation's samples ("File formats")
ASP_SAMPLES = {
    "TSAI": ("TSAI\nk1 = 1.31024e-04\nk2 = -2.05354e-07\np1 = 0.5\np2 = 0.4\nk3 = 1e-3\n",
             TsaiDistortion(1.31024e-04, -2.05354e-07, 0.5, 0.4, 1e-3)),
    "BrownConrady": (
        "BrownConrady\nxp = 0.5\nyp = 0.4\nk1 = 1.31024e-04\nk2 = -2.05354e-07\n"
        "k3 = 1.31024e-08\np1 = 0.5\np2 = 0.4\nphi = 0.001\n",
        BrownConradyDistortion(0.5, 0.4, 1.31024e-04, -2.05354e-07, 1.31024e-08, 0.5, 0.4, 0.001),
    ),
    "Photometrix": (
        "Photometrix\nxp = 0.004\nyp = -0.191\nk1 = 1.31024e-04\nk2 = -2.05354e-07\n"
        "k3 = -5.28558e-011\np1 = 7.2359e-006\np2 = 2.2656e-006\nb1 = 0.0\nb2 = 0.0\n",
        PhotometrixDistortion(0.004, -0.191, 1.31024e-04, -2.05354e-07, -5.28558e-11,
                              7.2359e-06, 2.2656e-06, 0.0, 0.0),
    ),
    "FISHEYE": (
        "FISHEYE\nk1 = -0.036031089735101024\nk2 = 0.038013929764216248\n"
        "k3 = -0.058893197165394658\nk4 = 0.02915171342570104\n",
        FisheyeDistortion(-0.036031089735101024, 0.038013929764216248, -0.058893197165394658,
                          0.02915171342570104),
    ),
    "FOV": ("FOV\nk1 = 1.0001\n", FovDistortion(1.0001)),
}  # fmt: skip


@pytest.mark.parametrize("model", list(ASP_SAMPLES))
def test_asp_documentation_distortion_samples(tmp_path: Path, model: str) -> None:
    text, lens = ASP_SAMPLES[model]
    path = tmp_path / "cam.tsai"
    path.write_text("VERSION_4\nPINHOLE\n" + BODY + "pitch = 1\n" + text)
    cam = read_camera(path)
    assert cam.distortion == lens
    write_tsai(cam, tmp_path / "again.tsai")
    assert read_camera(tmp_path / "again.tsai").distortion == lens


@pytest.mark.parametrize(
    ("text", "name"),
    [
        (
            "AdjustableTSAI\nRadial Coeff: Vector3(1.31024e-04, 1.31024e-07, 1.31024e-08)\n"
            "Tangential Coeff: Vector2(-2.05354e-07, 1.05354e-07)\nAlpha: 0.4\n",
            "AdjustableTSAI",
        ),
        (
            "RPC\nrpc_degree = 1\ndistortion_num_x = 0 1 0\ndistortion_den_x = 1 0 0\n"
            "distortion_num_y = 0 0 1\ndistortion_den_y = 1 0 0\n",
            "RPC",
        ),
    ],
)
def test_unsupported_asp_distortions_are_named(tmp_path: Path, text: str, name: str) -> None:
    path = tmp_path / "cam.tsai"
    path.write_text("VERSION_4\nPINHOLE\n" + BODY + "pitch = 1\n" + text)
    with pytest.raises(FormatError, match=f"ASP's {name} lens distortion is not supported") as e:
        read_camera(path)
    assert e.value.line == 13
    assert "convert_pinhole_model" in str(e.value)


@pytest.mark.parametrize("lens", list(LENSES))
def test_every_model_through_the_camera(tmp_path: Path, lens: str) -> None:
    cam = PinholeCamera(
        fu=FOCAL[0], fv=FOCAL[1], cu=OFFSET[0], cv=OFFSET[1], center=[100.0, -200.0, 5000.0],
        rotation=Rotation.from_euler("xyz", [3.0, -0.2, 1.1]).as_matrix(),
        distortion=LENSES[lens], width=WIDTH, height=HEIGHT,
    )  # fmt: skip
    for writer, name in ((write_tsai, "cam.tsai"), (write_json, "cam.json")):
        writer(cam, tmp_path / name)
        again = read_camera(tmp_path / name)
        assert again.distortion == cam.distortion
        assert tsai_text(again) == tsai_text(cam)
    pixels = image_grid(15)
    points = grid_points(cam, 4000.0)
    uv, depth = cam.project(points)
    np.testing.assert_allclose(uv, pixels.reshape(15, 15, 2), rtol=0, atol=1e-6)
    assert (depth > 0).all()


# ---------------------------------------------------------------------------------------------
# Orthority interior and exterior parameters

INTERIOR_HEAD = """\
# cameras in several styles: flow and block lists, quoted keys, comments
Integraph DMC:
    type: pinhole
    im_size: [640, 1152]
    focal_len: 120.0   # mm
    sensor_size: [92.16, 165.888]
'brown cam':
  type: brown
  im_size:
  - 400
  - 300
  focal_len: 0.8333
  cx: -0.01
  cy: 0.02
  k1: -0.25
  k2: 0.2
  p1: 0.01
  p2: 0.01
  k3: -0.1
"""
INTERIOR_FLOW = (
    '"opencv cam": {type: opencv, im_size: [600, 400], focal_len: [8.1, 7.9], '
    "sensor_size: [6, 4], k1: -0.2, k4: 0.05, s1: 0.001, tx: 0.01}\n"
)
INTERIOR_BLOCK = """\
"opencv cam":
  type: opencv
  im_size: [600, 400]
  focal_len: [8.1, 7.9]
  sensor_size: [6, 4]
  k1: -0.2
  k4: 0.05
  s1: 0.001
  tx: 0.01
"""

EXTERIOR_CSV = """\
filename,x,y,z,omega,phi,kappa,camera
img_a.tif,1000.0,2000.0,1500.0,1.5,-2.0,30.0,Integraph DMC
img_b,1100.0,2050.0,1400.0,-0.5,0.7,-170.0,brown cam
img_c.jpg,900.0,1950.0,1600.0,3.0,1.0,95.0,opencv cam
"""


def write_orthority(tmp_path: Path, opencv: str = INTERIOR_FLOW) -> tuple[Path, Path]:
    """Interior and CSV exterior files of three cameras; returns their paths."""
    (tmp_path / "int_param.yaml").write_text(INTERIOR_HEAD + opencv)
    (tmp_path / "xyz_opk.csv").write_text(EXTERIOR_CSV)
    return tmp_path / "int_param.yaml", tmp_path / "xyz_opk.csv"


def orthority_reference(
    xyz_world: np.ndarray, params: dict[str, object], position: list[float], opk_deg: list[float]
) -> np.ndarray:
    """Pixels of world points through Orthority's documented model, with OpenCV's projector.

    K from im_size, focal_len, sensor_size (absent: focal_len times the image width), cx, cy
    (offsets from the image centre (w - 1) / 2, (h - 1) / 2 in units of max(w, h)); pose from
    R = Rx(omega) Ry(phi) Rz(kappa) diag(1, -1, -1), camera-to-world; distortion by OpenCV.
    """
    w, h = params["im_size"]
    focal = np.broadcast_to(np.asarray(params["focal_len"], float), (2,))
    sensor = params.get("sensor_size")
    f = focal * (np.array([w, h]) / sensor if sensor else w)
    c = (np.array([w, h]) - 1) / 2 + max(w, h) * np.array(
        [params.get("cx", 0), params.get("cy", 0)]
    )
    k = np.array([[f[0], 0, c[0]], [0, f[1], c[1]], [0, 0, 1]])
    o, p, q = np.radians(opk_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(o), -np.sin(o)], [0, np.sin(o), np.cos(o)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(q), -np.sin(q), 0], [np.sin(q), np.cos(q), 0], [0, 0, 1]])
    r = rx @ ry @ rz @ np.diag([1, -1, -1])
    names = ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty"]
    coefficients = np.array([float(params.get(n, 0.0)) for n in names])
    rvec = cv2.Rodrigues(r.T)[0]
    tvec = -r.T @ np.asarray(position, float)
    return cv2.projectPoints(xyz_world.reshape(-1, 3), rvec, tvec, k, coefficients)[0][:, 0]


REFERENCE_PARAMS = {
    "img_a": ({"im_size": [640, 1152], "focal_len": 120.0, "sensor_size": [92.16, 165.888]},
              [1000.0, 2000.0, 1500.0], [1.5, -2.0, 30.0]),
    "img_b": ({"im_size": [400, 300], "focal_len": 0.8333, "cx": -0.01, "cy": 0.02, "k1": -0.25,
               "k2": 0.2, "p1": 0.01, "p2": 0.01, "k3": -0.1},
              [1100.0, 2050.0, 1400.0], [-0.5, 0.7, -170.0]),
    "img_c": ({"im_size": [600, 400], "focal_len": [8.1, 7.9], "sensor_size": [6, 4], "k1": -0.2,
               "k4": 0.05, "s1": 0.001, "tx": 0.01},
              [900.0, 1950.0, 1600.0], [3.0, 1.0, 95.0]),
}  # fmt: skip


@pytest.mark.parametrize("style", ["flow", "block"])
def test_orthority_cameras_match_the_documented_model(tmp_path: Path, style: str) -> None:
    interior, exterior = write_orthority(
        tmp_path, INTERIOR_FLOW if style == "flow" else INTERIOR_BLOCK
    )
    cams = read_orthority_cameras(interior, exterior)
    assert sorted(cams) == ["img_a", "img_b", "img_c"]
    assert isinstance(cams["img_a"].distortion, NullDistortion)
    assert isinstance(cams["img_b"].distortion, TsaiDistortion)  # brown is OpenCV's 5-term model
    assert isinstance(cams["img_c"].distortion, OpenCVDistortion)
    assert (cams["img_b"].width, cams["img_b"].height) == (400, 300)
    for stem, (params, position, opk) in REFERENCE_PARAMS.items():
        cam = cams[stem]
        points = grid_points(cam, 1000.0, n=11)
        expected = orthority_reference(points, params, position, opk)
        got = cam.project(points)[0].reshape(-1, 2)
        assert np.abs(got - expected).max() < 1e-6, stem


def test_orthority_focal_length_conventions(tmp_path: Path) -> None:
    (tmp_path / "int.yaml").write_text(
        "a:\n  type: pinhole\n  im_size: [300, 400]\n  focal_len: 0.5\n  cx: 0.1\n  cy: -0.05\n"
    )
    (tmp_path / "ext.csv").write_text("photo.tif 1 2 3 0 0 0\n")  # legacy: no header, spaces
    cam = read_orthority_cameras(tmp_path / "int.yaml", tmp_path / "ext.csv")["photo"]
    # no sensor size: focal_len normalised by the image width; c = (w - 1) / 2 + cx max(w, h)
    assert (cam.fu, cam.fv) == (150.0, 150.0)
    assert (cam.cu, cam.cv) == pytest.approx((149.5 + 40.0, 199.5 - 20.0), abs=1e-12)
    np.testing.assert_array_equal(cam.rotation, np.diag([1.0, -1.0, -1.0]))  # nadir: looks down
    np.testing.assert_allclose(cam.look_direction, [0, 0, -1])


def test_orthority_rotation_is_patb() -> None:
    # kappa = 90 degrees: the camera's x (image right) points to world +y (north)
    r = orthority_rotation(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 0, -1], atol=1e-15)  # looks down
    # omega tilts about world x, phi about y: R = Rx Ry Rz diag(1, -1, -1)
    o, p, k = 0.1, -0.2, 0.3
    expected = Rotation.from_euler("XYZ", [o, p, k]).as_matrix() @ np.diag([1, -1, -1])
    np.testing.assert_allclose(orthority_rotation(o, p, k), expected, atol=1e-15)


def test_read_camera_picks_the_row_by_image_stem(tmp_path: Path) -> None:
    interior, exterior = write_orthority(tmp_path)
    cams = read_orthority_cameras(interior, exterior)
    for image in ("img_a.tif", tmp_path / "sub" / "img_b.png", "img_c"):
        cam = read_camera(exterior, image)  # the interior file is found beside the exterior
        assert tsai_text(cam) == tsai_text(cams[Path(image).stem])
    with pytest.raises(InputError, match="no camera for image 'nope'"):
        read_camera(exterior, "nope.tif")
    with pytest.raises(InputError, match="holds 3 cameras; name the image"):
        read_camera(exterior)
    with pytest.raises(InputError, match="hold no camera position"):
        read_camera(interior, "img_a.tif")
    (tmp_path / "other.yml").write_text("x:\n  type: pinhole\n")
    with pytest.raises(InputError, match=r"there are 2 \(int_param.yaml, other.yml\): keep"):
        read_camera(exterior, "img_a.tif")
    cam = read_camera(exterior, "img_a.tif", interior=interior)  # explicit: no search
    assert tsai_text(cam) == tsai_text(cams["img_a"])


def test_geojson_exterior_and_radians(tmp_path: Path) -> None:
    interior, _ = write_orthority(tmp_path)
    features = [
        {"type": "Feature", "properties": {"filename": "img_b.jpg", "camera": "brown cam",
         "xyz": [1100.0, 2050.0, 1400.0], "opk": [math.radians(-0.5), math.radians(0.7),
         math.radians(-170.0)]}, "geometry": {"type": "Point", "coordinates": [0, 0, 0]}},
    ]  # fmt: skip
    (tmp_path / "ext.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "world_crs": "EPSG:32634", "features": features})
    )
    (tmp_path / "ext.json").write_text((tmp_path / "ext.geojson").read_text())
    (tmp_path / "rad.csv").write_text(
        "filename;x;y;z;omega;phi;kappa;camera\n"
        f"img_b;1100;2050;1400;{math.radians(-0.5)!r};{math.radians(0.7)!r};"
        f"{math.radians(-170.0)!r};brown cam\n"
    )
    expected = tsai_text(read_orthority_cameras(interior, tmp_path / "xyz_opk.csv")["img_b"])
    geo = read_orthority_cameras(interior, tmp_path / "ext.geojson")["img_b"]
    rad = read_orthority_cameras(interior, tmp_path / "rad.csv", radians=True)["img_b"]
    assert tsai_text(geo) == tsai_text(rad) == expected
    assert tsai_text(read_camera(tmp_path / "ext.json", "img_b.jpg")) == expected
    (tmp_path / "ext.txt").write_text((tmp_path / "ext.geojson").read_text())
    assert tsai_text(read_camera(tmp_path / "ext.txt", "img_b.jpg")) == expected  # by content


BAD_INTERIOR = {
    "unknown type": ("c:\n  type: spherical\n  im_size: [4, 3]\n  focal_len: 1\n", 2,
                     "camera type 'spherical' is not supported"),
    "no type": ("c:\n  im_size: [4, 3]\n  focal_len: 1\n", 1, "camera type None"),
    "unknown parameter": ("c:\n  type: brown\n  im_size: [4, 3]\n  focal_len: 1\n  k4: 0.1\n", 5,
                          "brown cameras have no parameter 'k4'"),
    "missing focal": ("c:\n  type: pinhole\n  im_size: [4, 3]\n", 1, "missing focal_len"),
    "bad size": ("c:\n  type: pinhole\n  im_size: [4.5, 3]\n  focal_len: 1\n", 3,
                 "im_size must be whole pixels"),
    "negative focal": ("c:\n  type: pinhole\n  im_size: [4, 3]\n  focal_len: -1\n", 4,
                       "focal_len must be positive"),
    "text focal": ("c:\n  type: pinhole\n  im_size: [4, 3]\n  focal_len: long\n", 4,
                   "focal_len must be 1 or 2 finite number(s)"),
    "not a mapping": ("- a\n- b\n", 1, "expected a mapping of camera ids"),
    "tab": ("c:\n\ttype: pinhole\n", 2, "found character '\\t' that cannot start any token"),
    "unterminated": ("c:\n  type: 'pinhole\n", 3,
                     "invalid YAML: while scanning a quoted scalar, found unexpected end"),
    "duplicate": ("c:\n  type: pinhole\n  type: brown\n", 3, "key 'type' given twice"),
    "indentation": ("c:\n  type: pinhole\n      focal_len: 1\n", 3,
                    "mapping values are not allowed here"),
    "no colon": ("c:\n  type pinhole\n", 1, "camera 'c': expected a mapping of parameters"),
    "two documents": ("a:\n  type: pinhole\n---\nb:\n  type: pinhole\n", 3,
                      "expected a single document in the stream, but found another document"),
    "python tag": ("c:\n  type: !!python/object/apply:os.getcwd []\n", 2,
                   "could not determine a constructor"),  # the safe loader runs no code
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_INTERIOR))
def test_bad_interior_files(tmp_path: Path, case: str) -> None:
    text, line, message = BAD_INTERIOR[case]
    (tmp_path / "int.yaml").write_text(text)
    (tmp_path / "ext.csv").write_text("filename,x,y,z,omega,phi,kappa\na,0,0,1,0,0,0\n")
    with pytest.raises(FormatError) as info:
        read_orthority_cameras(tmp_path / "int.yaml", tmp_path / "ext.csv")
    assert str(info.value).startswith(f"{tmp_path / 'int.yaml'}, line {line}: "), str(info.value)
    assert message in str(info.value)


BAD_EXTERIOR = {
    "non-numeric": ("filename,x,y,z,omega,phi,kappa\na,0,0,x1,0,0,0\n", 2, "'x1' after 'z ='"),
    "short row": ("filename,x,y,z,omega,phi,kappa\na,0,0,1,0,0\n", 2, "expected 7 fields"),
    "lat lon": ("filename,latitude,longitude,altitude,omega,phi,kappa\na,0,0,1,0,0,0\n", 1,
                "latitude, longitude, altitude would need Orthority's CRS conversions"),
    "unknown camera": ("filename,x,y,z,omega,phi,kappa,camera\na,0,0,1,0,0,0,zz\n", 2,
                       "camera 'zz' of image 'a' is not in"),
    "duplicate": (
        "filename,x,y,z,omega,phi,kappa,camera\na.tif,0,0,1,0,0,0,brown cam\n"
        "a.jpg,0,0,1,0,0,0,brown cam\n",
        3,
        "image 'a' appears twice",
    ),
    "no camera id": ("filename,x,y,z,omega,phi,kappa\na,0,0,1,0,0,0\n", 2,
                     "image 'a' names no camera, and"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_EXTERIOR))
def test_bad_exterior_files(tmp_path: Path, case: str) -> None:
    text, line, message = BAD_EXTERIOR[case]
    interior, _ = write_orthority(tmp_path)
    (tmp_path / "bad.csv").write_text(text)
    with pytest.raises(FormatError) as info:
        read_orthority_cameras(interior, tmp_path / "bad.csv")
    assert str(info.value).startswith(f"{tmp_path / 'bad.csv'}, line {line}: "), str(info.value)
    assert message in str(info.value)


def test_bad_geojson(tmp_path: Path) -> None:
    interior, _ = write_orthority(tmp_path)
    path = tmp_path / "ext.geojson"
    for obj, message in (
        ({"type": "Feature"}, "expected a GeoJSON FeatureCollection"),
        ({"type": "FeatureCollection", "features": []}, "has no features"),
        ({"type": "FeatureCollection", "features": [{"properties": {"filename": "a",
          "xyz": [1, 2], "opk": [0, 0, 0]}}]}, "feature 0 (a): xyz must be 3 numbers"),
    ):  # fmt: skip
        path.write_text(json.dumps(obj))
        with pytest.raises(FormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
            read_orthority_cameras(interior, path)


# ---------------------------------------------------------------------------------------------
# The shared real data: readers reproduce the *.converted.tsai files

NGI_STEMS = [
    "3324c_2015_1004_05_0182_RGB",
    "3324c_2015_1004_05_0184_RGB",
    "3324c_2015_1004_06_0251_RGB",
    "3324c_2015_1004_06_0253_RGB",
]


@pytest.mark.realdata
@pytest.mark.parametrize("stem", NGI_STEMS)
def test_ngi_orthority_cameras_match_converted_tsai(stem: str) -> None:
    formats = shared("ngi-aerial", "orthority-format")
    converted = read_camera(shared("ngi-aerial", f"{stem}.converted.tsai"))
    cam = read_camera(formats / "ngi_xyz_opk.csv", shared("ngi-aerial", f"{stem}.tif"))
    assert (cam.width, cam.height) == (640, 1152)
    assert cam.fu == pytest.approx(120 * 640 / 92.16, rel=1e-15)  # 833.33 px: 0.144 mm pixels
    # points on the rays through a 15 x 15 pixel grid, 4.5 to 5.5 km away (the camera is about
    # 5 km above terrain at 150..780 m)
    points = np.concatenate([grid_points(converted, d) for d in (4500.0, 5500.0)])
    expected, depth = converted.project(points)
    got = cam.project(points)[0]
    assert np.abs(got - expected).max() < 1e-6  # measured: 2.3e-10 px
    assert (depth > 3000).all()  # along the optical axis: the view is 70 degrees wide
    geo = read_camera(formats / "ngi_ext_param.geojson", f"{stem}.tif")
    # the GeoJSON keeps more digits than the CSV (3 decimals of a degree, of a metre)
    assert np.abs(geo.project(points)[0] - expected).max() < 0.05
    np.testing.assert_allclose(geo.center, cam.center, atol=0.005)


@pytest.mark.realdata
def test_hadley_converted_tsai_reads() -> None:
    cam = read_camera(shared("as15-hadley", "AS15-M-1134-hadley.converted.tsai"))
    assert (cam.fu, cam.fv, cam.cu, cam.cv, cam.pitch) == (3802.7, 3802.7, 1763.0, 863.0, 1.0)
    assert cam.distortion == NullDistortion()
    # looks at the Moon: the ray through the principal point meets the 1737.4 km sphere
    o, d = cam.ray(np.array([1763.0, 863.0]))
    od = o @ d
    hit = -od - math.sqrt(od**2 - o @ o + 1737400.0**2)
    assert 50e3 < hit < 200e3
    uv, _ = cam.project(o + d * hit)
    np.testing.assert_allclose(uv, [1763.0, 863.0], atol=1e-6)


def test_interior_yaml_features(tmp_path: Path) -> None:
    """Interior files are YAML as PyYAML reads it: directives, document markers, comments,
    quoting, block sequences, anchors and aliases; camera ids are the keys as written."""
    (tmp_path / "int.yaml").write_text(
        """\
%YAML 1.1
---
# the opencv camera of INTERIOR_BLOCK, written differently
'opencv cam':  # a quoted id
  type: "opencv"
  im_size:
  - 600
  - 400
  focal_len: &focal [8.1, 7.9]
  sensor_size: [6, 4]
  k1: -0.2
  k4: 5.0e-2
  s1: 1.0e-3
  tx: 0.01
1:
  type: pinhole
  im_size: [600, 400]
  focal_len: *focal
  sensor_size: [6, 4]
...
"""
    )
    (tmp_path / "ext.csv").write_text(
        "filename,x,y,z,omega,phi,kappa,camera\n"
        "img_c.jpg,900.0,1950.0,1600.0,3.0,1.0,95.0,opencv cam\n"
        "img_d,900.0,1950.0,1600.0,3.0,1.0,95.0,1\n"
    )
    cams = read_orthority_cameras(tmp_path / "int.yaml", tmp_path / "ext.csv")
    (tmp_path / "plain").mkdir()
    plain = read_orthority_cameras(*write_orthority(tmp_path / "plain", INTERIOR_BLOCK))
    assert tsai_text(cams["img_c"]) == tsai_text(plain["img_c"])
    assert (cams["img_d"].fu, cams["img_d"].fv) == (8.1 * 600 / 6, 7.9 * 400 / 4)
    assert isinstance(cams["img_d"].distortion, NullDistortion)
