"""Tests of orthomvp.camera: the VW pinhole model, its lens distortions and its camera files.

Expected values come from hand calculation with the formulas of the ASP documentation
("Pinhole models") and VW's PinholeModel/LensDistortion, from numbers in VW's own unit tests
(TestPinholeModel.cxx), and from the real Apollo 15 cameras in ../shared/data.
"""

from __future__ import annotations

import ast
import json
import math
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA as DATA
from scipy.spatial.transform import Rotation

import orthomvp.camera
from orthomvp.camera import (
    BrownConradyDistortion,
    NullDistortion,
    PinholeCamera,
    TsaiDistortion,
    read_camera,
    tsai_text,
    write_json,
    write_tsai,
)
from orthomvp.errors import FormatError, InputError

APOLLO = DATA / "apollo15-mvp"
APOLLO_SIZES = [(281, 118), (202, 120), (116, 121), (196, 121)]  # width x height, data README
MOON_RADIUS = 1737400.0
needs_data = pytest.mark.skipif(
    not APOLLO.is_dir(), reason=f"real data directory {APOLLO} is absent"
)

IDENTITY = np.eye(3)
SWAPPED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # u=+y, v=+x, w=-z
FLIPPED_V = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])


def tsai_lens() -> TsaiDistortion:
    """The TSAI coefficients of VW's PinholeTest, plus a k3."""
    return TsaiDistortion(
        k1=-0.2796604335308075,
        k2=0.1031486615538597,
        p1=-0.0007824968779459596,
        p2=0.0009675505571067333,
        k3=0.01,
    )


def brown_lens(pitch: float) -> BrownConradyDistortion:
    """A moderate Brown-Conrady lens (a few pixels at the corners), in units of ``pitch``."""
    return BrownConradyDistortion(
        xp=-0.6 * pitch,
        yp=-0.2 * pitch,
        k1=1e-7 / pitch**2,
        k2=-5e-14 / pitch**4,
        k3=1e-20 / pitch**6,
        p1=5e-7 / pitch,
        p2=1e-12 / pitch**3,
        phi=0.201,
    )


def make_camera(lens: str, pitch: float = 1.0, frame: np.ndarray = IDENTITY) -> PinholeCamera:
    """A 1000 x 800 pixel camera 5 km above the origin, intrinsics in units of ``pitch``."""
    distortion = {"null": NullDistortion(), "tsai": tsai_lens(), "brown": brown_lens(pitch)}[lens]
    return PinholeCamera(
        fu=1200.0 * pitch,
        fv=1150.0 * pitch,
        cu=510.0 * pitch,
        cv=390.0 * pitch,
        center=np.array([100.0, -200.0, 5000.0]),
        rotation=Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix(),
        u_direction=frame[0],
        v_direction=frame[1],
        w_direction=frame[2],
        pitch=pitch,
        distortion=distortion,
        width=1000,
        height=800,
    )


CASES = {
    "null": ("null", 1.0, IDENTITY),
    "null-pitch-swapped": ("null", 0.0074, SWAPPED),
    "tsai": ("tsai", 1.0, IDENTITY),
    "tsai-pitch": ("tsai", 0.0074, IDENTITY),
    "tsai-swapped": ("tsai", 1.0, SWAPPED),
    "brown": ("brown", 1.0, IDENTITY),
    "brown-pitch-flipped": ("brown", 0.0074, FLIPPED_V),
}


@pytest.fixture(params=list(CASES))
def camera(request: pytest.FixtureRequest) -> PinholeCamera:
    return make_camera(*CASES[request.param])


def assert_same_camera(a: PinholeCamera, b: PinholeCamera, with_size: bool = True) -> None:
    """Every field bit-for-bit equal."""
    for name in ("fu", "fv", "cu", "cv", "pitch"):
        assert getattr(a, name) == getattr(b, name), name
    for name in ("center", "rotation", "u_direction", "v_direction", "w_direction"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.distortion == b.distortion
    if with_size:
        assert (a.width, a.height) == (b.width, b.height)


# ---------------------------------------------------------------------------------------------
# The model


def test_hand_computed_projection() -> None:
    # C = (0, 0, 10), R = I: the camera looks along +z; pixel = 100 * (x/z, y/z) + 50
    cam = PinholeCamera(fu=100, fv=100, cu=50, cv=50, center=[0, 0, 10], rotation=np.eye(3))
    pts = np.array([[0, 0, 20], [1, 2, 20], [-5, 5, 30], [2, -1, 15]], dtype=float)
    uv, depth = cam.project(pts)
    np.testing.assert_allclose(uv, [[50, 50], [60, 70], [25, 75], [90, 30]], atol=1e-12)
    np.testing.assert_allclose(depth, [10, 10, 20, 5], atol=1e-12)
    # behind the camera and in its focal plane: no pixel
    uv, depth = cam.project(np.array([[0, 0, 0], [3, 3, 10]], dtype=float))
    assert np.isnan(uv).all()
    np.testing.assert_allclose(depth, [-10, 0])
    np.testing.assert_allclose(cam.K, [[100, 0, 50], [0, 100, 50], [0, 0, 1]])
    np.testing.assert_allclose(cam.look_direction, [0, 0, 1])


def test_hand_computed_nadir_camera() -> None:
    # R = diag(1, -1, -1): camera y and z point to world -y and -z; it looks straight down
    cam = PinholeCamera(
        fu=100, fv=100, cu=50, cv=50, center=[0, 0, 10], rotation=np.diag([1.0, -1.0, -1.0])
    )
    uv, depth = cam.project(np.array([[0, 0, 0], [1, 2, 0], [-3, -4, 5]], dtype=float))
    np.testing.assert_allclose(uv, [[50, 50], [60, 30], [-10, 130]], atol=1e-12)
    np.testing.assert_allclose(depth, [10, 10, 5])
    np.testing.assert_allclose(cam.look_direction, [0, 0, -1])
    origin, direction = cam.ray(np.array([60.0, 30.0]))
    ground = origin + direction * (-origin[2] / direction[2])
    np.testing.assert_allclose(ground, [1, 2, 0], atol=1e-12)


def test_hand_computed_rotated_camera() -> None:
    # R = 90 degrees about z, camera-to-world: camera x is world +y, camera y is world -x
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cam = PinholeCamera(fu=100, fv=100, cu=50, cv=50, center=[0, 0, 0], rotation=rot)
    # world (0, 1, 10) is camera (1, 0, 10); world (-2, 0, 10) is camera (0, 2, 10)
    uv, depth = cam.project(np.array([[0, 1, 10], [-2, 0, 10]], dtype=float))
    np.testing.assert_allclose(uv, [[60, 50], [50, 70]], atol=1e-12)
    np.testing.assert_allclose(depth, 10)


def test_vw_coordinate_frame_example() -> None:
    # VW TestPinholeModel CoordinateFrame: +u along camera +y, +v along +x, +w along -z
    cam = PinholeCamera(
        fu=500, fv=500, cu=500, cv=500, center=np.zeros(3), rotation=np.eye(3),
        u_direction=SWAPPED[0], v_direction=SWAPPED[1], w_direction=SWAPPED[2],
    )  # fmt: skip
    pts = np.array([[0, 0, -10], [-10, 0, -10], [10, 0, -10], [0, -10, -10], [0, 10, -10]], float)
    uv, depth = cam.project(pts)
    np.testing.assert_allclose(uv, [[500, 500], [500, 0], [500, 1000], [0, 500], [1000, 500]])
    np.testing.assert_allclose(depth, 10)
    np.testing.assert_allclose(cam.look_direction, [0, 0, -1])
    _, directions = cam.ray(uv)
    np.testing.assert_allclose(directions, pts / np.linalg.norm(pts, axis=1)[:, None], atol=1e-15)


def test_tsai_distortion_hand_and_vw_values() -> None:
    # VW TestPinholeModel TsaiDistortion: f = c = 500, undistorted (200, 200) -> (244.865, 244.395)
    k1, k2 = -0.2805362343788147, 0.1062035113573074
    p1, p2 = -0.0001422458299202845, 0.00116333004552871
    lens = TsaiDistortion(k1, k2, p1, p2)
    cam = PinholeCamera(500, 500, 500, 500, np.zeros(3), np.eye(3), distortion=lens)
    x = y = (200 - 500) / 500
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    uv, _ = cam.project(np.array([x, y, 1.0]))
    np.testing.assert_allclose(uv, [500 * xd + 500, 500 * yd + 500], rtol=0, atol=1e-9)
    np.testing.assert_allclose(uv, [244.865, 244.395], atol=1e-3)
    _, direction = cam.ray(uv)
    np.testing.assert_allclose(direction, np.array([x, y, 1]) / math.sqrt(r2 + 1), atol=1e-13)


@pytest.mark.parametrize("pitch", [1.0, 0.01])
def test_brown_conrady_hand_values(pitch: float) -> None:
    # ASP docs / VW: from the distorted position p (pitch units), x = p - c - (xp, yp),
    # undistorted = x radial - t sin(phi) (+ t cos(phi) for y) + c, not normalised by f
    lens = brown_lens(pitch)
    cam = PinholeCamera(
        1000 * pitch, 1000 * pitch, 500 * pitch, 400 * pitch, np.zeros(3), np.eye(3),
        pitch=pitch, distortion=lens,
    )  # fmt: skip
    u, v = 800.0, 100.0
    x = u * pitch - 500 * pitch - lens.xp
    y = v * pitch - 400 * pitch - lens.yp
    r2 = x * x + y * y
    radial = 1 + lens.k1 * r2 + lens.k2 * r2**2 + lens.k3 * r2**3
    t = lens.p1 * r2 + lens.p2 * r2**2
    ux = x * radial - t * math.sin(lens.phi)
    uy = y * radial + t * math.cos(lens.phi)
    expected = np.array([ux / (1000 * pitch), uy / (1000 * pitch), 1.0])
    _, direction = cam.ray(np.array([u, v]))
    np.testing.assert_allclose(direction, expected / np.linalg.norm(expected), atol=1e-14)
    assert abs(ux - (u - 500) * pitch) > 0.5 * pitch  # the lens moves this pixel visibly
    uv, _ = cam.project(direction * 7.0)
    np.testing.assert_allclose(uv, [u, v], atol=1e-9)


def test_point_on_pixel_ray_projects_back(camera: PinholeCamera) -> None:
    rng = np.random.default_rng(1)
    uv = rng.uniform([-0.5, -0.5], [999.5, 799.5], size=(2000, 2))
    origins, directions = camera.ray(uv)
    np.testing.assert_array_equal(origins, np.broadcast_to(camera.center, origins.shape))
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-15)
    distance = rng.uniform(10.0, 2e4, size=len(uv))
    back, depth = camera.project(origins + directions * distance[:, None])
    assert np.abs(back - uv).max() < 1e-6
    np.testing.assert_allclose(depth, distance * (directions @ camera.look_direction))
    assert (depth > 0).all()


def test_projected_pixel_ray_passes_through_point(camera: PinholeCamera) -> None:
    rng = np.random.default_rng(2)
    # points within about +-20 degrees of the optical axis, 100 m to 10 km away
    offsets = rng.normal(size=(2000, 3))
    offsets /= np.linalg.norm(offsets, axis=1)[:, None]
    direction = camera.look_direction + 0.35 * offsets
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    pts = camera.center + direction * rng.uniform(100, 1e4, size=(2000, 1))
    uv, _ = camera.project(pts)
    assert np.isfinite(uv).all()
    _, back = camera.ray(uv)
    np.testing.assert_allclose(back, direction, atol=1e-11)


@pytest.mark.parametrize("offset", [(120, 45), (-30, 700)])
def test_crop_is_the_camera_shifted_by_the_window(camera: PinholeCamera, offset) -> None:  # noqa: ANN001
    """A window's camera projects every point to the full image's pixel minus the window
    offset, and casts the same rays through the shifted pixels, lens distortion included."""
    c0, r0 = offset
    crop = camera.crop(c0, r0, 300, 200)
    assert (crop.width, crop.height) == (300, 200)
    rng = np.random.default_rng(7)
    uv = rng.uniform([-0.5, -0.5], [999.5, 799.5], size=(2000, 2))
    _, directions = camera.ray(uv)
    pts = camera.center + directions * rng.uniform(100, 1e4, size=(len(uv), 1))
    full, depth = camera.project(pts)
    shifted, depth_crop = crop.project(pts)
    np.testing.assert_allclose(shifted, full - [c0, r0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(depth_crop, depth)
    np.testing.assert_allclose(crop.ray(uv - [c0, r0])[1], directions, rtol=0, atol=1e-12)
    back = crop.crop(-c0, -r0, 1000, 800)
    assert_same_camera(replace(back, cu=camera.cu, cv=camera.cv), camera)
    np.testing.assert_allclose([back.cu, back.cv], [camera.cu, camera.cv], rtol=1e-15)
    with pytest.raises(InputError, match="integer"):
        camera.crop(1.5, 0, 10, 10)
    with pytest.raises(InputError, match="width"):
        camera.crop(0, 0, 0, 10)


def test_distortion_actually_moves_pixels() -> None:
    for lens in ("tsai", "brown"):
        plain, distorted = make_camera("null"), make_camera(lens)
        pts = plain.ray(np.array([[20.0, 30.0], [980.0, 770.0]]))[1] * 100 + plain.center
        shift = np.abs(distorted.project(pts)[0] - plain.project(pts)[0]).max()
        assert shift > 2.0, lens


def test_projection_matrix_agrees_with_project() -> None:
    rng = np.random.default_rng(3)
    for lens, pitch, frame in CASES.values():
        if lens != "null":
            continue
        cam = make_camera(lens, pitch, frame)
        pts = cam.ray(rng.uniform(0, 800, (100, 2)))[1] * rng.uniform(10, 1e4, (100, 1))
        pts += cam.center
        h = np.hstack([pts, np.ones((100, 1))]) @ cam.F.T
        np.testing.assert_allclose(h[:, :2] / h[:, 2:], cam.project(pts)[0], rtol=1e-12)
        assert cam.F.shape == (3, 4)
    with pytest.raises(InputError, match="TSAI"):
        _ = make_camera("tsai").F


def test_intrinsic_matrix_in_pixels() -> None:
    cam = make_camera("null", pitch=0.0074)
    np.testing.assert_allclose(cam.K, [[1200, 0, 510], [0, 1150, 390], [0, 0, 1]], rtol=1e-15)


def test_fold_of_the_distortion_gives_no_pixel() -> None:
    # k1 = -0.5: x (1 - 0.5 x^2) peaks at x = 0.816 and folds back; x = 1.5 would land at -0.19
    cam = PinholeCamera(
        1000, 1000, 500, 500, np.zeros(3), np.eye(3), distortion=TsaiDistortion(-0.5, 0, 0, 0)
    )
    uv, depth = cam.project(np.array([[0.5, 0.0, 1.0], [1.5, 0.0, 1.0]]))
    np.testing.assert_allclose(uv[0], [500 + 1000 * (0.5 - 0.5 * 0.125), 500])
    assert np.isnan(uv[1]).all()
    np.testing.assert_allclose(depth, 1.0)


def test_shapes_and_nan() -> None:
    cam = make_camera("tsai")
    uv, depth = cam.project(np.full((4, 5, 3), 1.0) + [0, 0, -1000])
    assert uv.shape == (4, 5, 2) and depth.shape == (4, 5)
    origin, direction = cam.ray(np.array([np.nan, 3.0]))
    assert origin.shape == direction.shape == (3,)
    assert np.isnan(direction).all()
    with pytest.raises(InputError):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(InputError):
        cam.ray(np.zeros(3))


def test_construction_is_validated() -> None:
    good = {"fu": 100, "fv": 100, "cu": 50, "cv": 50, "center": np.zeros(3), "rotation": np.eye(3)}
    for change in (
        {"rotation": np.eye(3) * 1.001},
        {"rotation": np.diag([1.0, 1.0, -1.0])},
        {"u_direction": np.array([1.0, 1.0, 0.0])},
        {"fu": 0.0},
        {"pitch": -1.0},
        {"center": [0.0, np.nan, 0.0]},
        {"center": [0.0, 0.0]},
        {"width": 0},
    ):
        with pytest.raises(InputError):
            PinholeCamera(**{**good, **change})
    cam = PinholeCamera(**good).with_image_size(640, 480)
    assert (cam.width, cam.height) == (640, 480)
    with pytest.raises(InputError):
        cam.with_image_size(640, -1)
    with pytest.raises(InputError):
        TsaiDistortion(0.1, float("inf"), 0, 0)


# ---------------------------------------------------------------------------------------------
# .tsai files

ASP_DOC_EXAMPLE = """\
VERSION_4
PINHOLE
fu = 28.429
fv = 28.429
cu = 17.9712
cv = 11.9808
u_direction = 1  0  0
v_direction = 0  1  0
w_direction = 0  0  1
C = 266.943 -105.583 -2.14189
R = 0.0825447 0.996303 -0.0238243 -0.996008 0.0832884 0.0321213 0.0339869 0.0210777 0.9992
pitch = 0.0064
TSAI
k1 = -0.094196634563
k2 = 0.115036424262
k3 = -0.032238313341
p1 = -0.000256622541
p2 = -0.000353613460
"""


def test_asp_documentation_example(tmp_path: Path) -> None:
    path = tmp_path / "doc.tsai"
    path.write_text(ASP_DOC_EXAMPLE)
    cam = read_camera(path)
    assert (cam.fu, cam.fv, cam.cu, cam.cv, cam.pitch) == (28.429, 28.429, 17.9712, 11.9808, 0.0064)
    assert cam.distortion == TsaiDistortion(
        k1=-0.094196634563, k2=0.115036424262, p1=-0.000256622541, p2=-0.000353613460,
        k3=-0.032238313341,
    )  # fmt: skip
    np.testing.assert_array_equal(cam.center, [266.943, -105.583, -2.14189])
    # by hand: q = R^T (X - C); (x, y) = q_xy / q_z; TSAI on (x, y); pixel = (f xd + c) / pitch
    X = cam.center + cam.rotation @ np.array([3.0, -2.0, 10.0])
    q = cam.rotation.T @ (X - cam.center)
    x, y = q[0] / q[2], q[1] / q[2]
    d = cam.distortion
    r2 = x * x + y * y
    radial = 1 + d.k1 * r2 + d.k2 * r2**2 + d.k3 * r2**3
    xd = x * radial + 2 * d.p1 * x * y + d.p2 * (r2 + 2 * x * x)
    yd = y * radial + d.p1 * (r2 + 2 * y * y) + 2 * d.p2 * x * y
    expected = [(28.429 * xd + 17.9712) / 0.0064, (28.429 * yd + 11.9808) / 0.0064]
    uv, depth = cam.project(X)
    np.testing.assert_allclose(uv, expected, rtol=0, atol=1e-9)
    assert abs(uv[0] - (28.429 * x + 17.9712) / 0.0064) > 5  # the lens moves it > 5 pixels
    np.testing.assert_allclose(depth, q[2])
    assert abs(cam.ray(uv)[1] @ (X - cam.center) / np.linalg.norm(X - cam.center) - 1) < 1e-14


def test_old_unversioned_tsai(tmp_path: Path) -> None:
    # VW TestPinholeModel OldFormatReadTest: no version, no pitch, TSAI parameters without a name
    path = tmp_path / "monkey.tsai"
    path.write_text(
        "fu = 54.6\nfv = 45.3\ncu = 3\ncv = 5\nu_direction = 1 0 0\nv_direction = 0 1 0\n"
        "w_direction = 0 0 1\nC = 18.6 14.4 13.3\nR = 1 0 0 0 1 0 0 0 1\n"
        "k1 = 0.001\nk2 = 0.001\np1 = 0.010\np2 = 1\n"
    )
    cam = read_camera(path)
    assert (cam.fu, cam.fv, cam.cu, cam.cv, cam.pitch) == (54.6, 45.3, 3.0, 5.0, 1.0)
    np.testing.assert_array_equal(cam.center, [18.6, 14.4, 13.3])
    assert cam.distortion == TsaiDistortion(0.001, 0.001, 0.010, 1.0)


def test_version3_tsai_with_vw_brown_conrady_layout(tmp_path: Path) -> None:
    # VERSION_3 has no PINHOLE line; VW writes BrownConrady parameters as "xp  = ..."
    path = tmp_path / "v3.tsai"
    path.write_text(
        "VERSION_3\nfu = 10\nfv = 11\ncu = 5\ncv = 4\nu_direction = 1 0 0\nv_direction = 0 1 0\n"
        "w_direction = 0 0 1\nC = 1 2 3\nR = 0 -1 0 1 0 0 0 0 1\npitch = 0.01\nBrownConrady\n"
        "xp  = 0.5\nyp  = 0.4\nk1  = 1.31024e-04\nk2  = -2.05354e-07\nk3  = 1.31024e-08\n"
        "p1  = 0.5\np2  = 0.4\nphi = 0.001\n"
    )
    cam = read_camera(path)
    assert cam.distortion == BrownConradyDistortion(
        0.5, 0.4, 1.31024e-04, -2.05354e-07, 1.31024e-08, 0.5, 0.4, 0.001
    )
    np.testing.assert_array_equal(cam.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert cam.pitch == 0.01


@pytest.mark.parametrize("lens", ["null", "tsai", "brown"])
def test_write_tsai_round_trip_is_exact(tmp_path: Path, lens: str) -> None:
    rng = np.random.default_rng(4)
    cam = make_camera(lens, pitch=float(rng.uniform(0.001, 0.01)), frame=SWAPPED)
    cam = PinholeCamera(
        fu=float(rng.uniform(1, 100)), fv=float(rng.uniform(1, 100)),
        cu=float(rng.normal()), cv=float(rng.normal()),
        center=rng.normal(size=3) * 1e6, rotation=Rotation.random(random_state=5).as_matrix(),
        u_direction=cam.u_direction, v_direction=cam.v_direction, w_direction=cam.w_direction,
        pitch=cam.pitch, distortion=cam.distortion,
    )  # fmt: skip
    path = tmp_path / "cam.tsai"
    path.write_text("old content")
    write_tsai(cam, path)
    assert [p.name for p in tmp_path.iterdir()] == ["cam.tsai"]  # no temporary file left
    text = path.read_text()
    assert text.startswith("VERSION_4\nPINHOLE\nfu = ")
    assert f"\n{cam.distortion.name}\n" in text
    assert_same_camera(read_camera(path), cam, with_size=False)
    assert tsai_text(read_camera(path)) == text


@pytest.mark.parametrize("lens", ["null", "tsai", "brown"])
def test_json_round_trip_is_exact(tmp_path: Path, lens: str) -> None:
    cam = make_camera(lens, pitch=0.0074, frame=FLIPPED_V)
    path = tmp_path / "cam.json"
    write_json(cam, path)
    assert [p.name for p in tmp_path.iterdir()] == ["cam.json"]
    obj = json.loads(path.read_text())
    assert obj["distortion"]["model"] == cam.distortion.name
    assert obj["fu"] == cam.fu and obj["width"] == 1000
    assert_same_camera(read_camera(path), cam)


def test_json_defaults(tmp_path: Path) -> None:
    path = tmp_path / "min.json"
    path.write_text('{"fu": 10, "fv": 10, "cu": 1, "cv": 2, "center": [0, 0, 0],\n'
                    ' "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}')  # fmt: skip
    cam = read_camera(path)
    assert cam.pitch == 1.0 and cam.distortion == NullDistortion() and cam.width is None
    np.testing.assert_array_equal(cam.w_direction, [0, 0, 1])


# ---------------------------------------------------------------------------------------------
# .pinhole protobuf files


def pb_key(number: int, wire: int) -> bytes:
    return bytes([number << 3 | wire])


def pb_doubles(number: int, values: list[float], packed: bool) -> bytes:
    if packed:
        payload = struct.pack(f"<{len(values)}d", *values)
        return pb_key(number, 2) + bytes([len(payload)]) + payload
    return b"".join(pb_key(number, 1) + struct.pack("<d", v) for v in values)


def pb_string(number: int, text: str) -> bytes:
    return pb_key(number, 2) + bytes([len(text)]) + text.encode()


def tsaifile(
    cam: PinholeCamera,
    packed: bool = True,
    name: str | None = None,
    rotation: np.ndarray | None = None,
) -> bytes:
    """A VW TsaiFile message for ``cam`` (or its fields overridden), encoded by hand."""
    rotation = cam.rotation if rotation is None else rotation
    dist = list(cam.distortion.params().values())
    if isinstance(cam.distortion, TsaiDistortion):
        dist = dist[:4]  # VW's protobuf TSAI has k1, k2, p1, p2
    return b"".join(
        [
            pb_string(1, "test camera"),
            pb_doubles(2, [cam.fu, cam.fv], packed),
            pb_doubles(3, [cam.cu, cam.cv], packed),
            pb_doubles(4, list(cam.u_direction), packed),
            pb_doubles(5, list(cam.v_direction), packed),
            pb_doubles(6, list(cam.w_direction), packed),
            pb_doubles(7, list(cam.center), packed),
            pb_doubles(8, list(rotation.ravel()), packed),
            pb_key(15, 0) + b"\x96\x01",  # an unknown varint field, to be skipped
            pb_string(9, name or cam.distortion.name.upper()),
            pb_doubles(10, dist, packed) if dist else b"",
            pb_doubles(11, [cam.pitch], packed=False),
        ]
    )


@pytest.mark.parametrize("packed", [True, False])
@pytest.mark.parametrize("lens", ["null", "tsai", "brown"])
def test_pinhole_protobuf_packed_and_unpacked(tmp_path: Path, lens: str, packed: bool) -> None:
    cam = make_camera(lens, pitch=0.0074, frame=SWAPPED)
    if lens == "tsai":
        cam = replace(cam, distortion=TsaiDistortion(0.1, -0.02, 1e-3, 2e-4))
    path = tmp_path / "cam.pinhole"
    path.write_bytes(tsaifile(cam, packed))
    assert_same_camera(read_camera(path), cam, with_size=False)


@pytest.mark.realdata
@needs_data
@pytest.mark.parametrize("index", range(4))
def test_apollo_pinhole_matches_converted_tsai(index: int) -> None:
    binary = read_camera(APOLLO / f"camera{index}.pinhole")
    text = read_camera(APOLLO / f"camera{index}.converted.tsai")
    for name in ("fu", "fv", "cu", "cv", "pitch"):
        assert getattr(binary, name) == getattr(text, name)
    assert binary.fu == 3802.7 and binary.distortion == NullDistortion()
    # R is camera-to-world: the optical axis of these mapping frames points near the Moon's centre
    assert binary.look_direction @ (-binary.center / np.linalg.norm(binary.center)) > 0.99
    np.testing.assert_allclose(binary.center, text.center, rtol=1e-15, atol=1e-6)
    np.testing.assert_allclose(binary.rotation, text.rotation, rtol=0, atol=1e-15)
    # points on the lunar sphere seen by every pixel of a grid over the image
    width, height = APOLLO_SIZES[index]
    u, v = np.meshgrid(np.linspace(-0.5, width - 0.5, 15), np.linspace(-0.5, height - 0.5, 9))
    uv = np.stack([u, v], axis=-1)
    o, d = binary.ray(uv)
    od = (o * d).sum(-1)
    t = -od - np.sqrt(od**2 - (o * o).sum(-1) + MOON_RADIUS**2)
    ground = o + d * t[..., None]
    uv_binary, depth = binary.project(ground)
    uv_text, _ = text.project(ground)
    assert np.abs(uv_binary - uv_text).max() < 1e-6
    assert np.abs(uv_binary - uv).max() < 1e-6
    assert ((depth > 110e3) & (depth < 125e3)).all()  # about 117 km above the surface


@pytest.mark.realdata
@needs_data
def test_every_shared_tsai_file_reads_and_round_trips(tmp_path: Path) -> None:
    paths = sorted(DATA.glob("*/*.tsai"))
    assert len(paths) >= 9
    for path in paths:
        cam = read_camera(path)
        write_tsai(cam, tmp_path / path.name)
        assert_same_camera(read_camera(tmp_path / path.name), cam)
        centre = np.array([cam.cu, cam.cv]) / cam.pitch
        np.testing.assert_allclose(cam.ray(centre)[1], cam.look_direction, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Recognising files, and bad files


def test_unknown_extensions_are_sniffed(tmp_path: Path) -> None:
    cam = make_camera("brown")
    (tmp_path / "a.txt").write_text(tsai_text(cam))
    write_json(cam, tmp_path / "b.cam")
    (tmp_path / "c.bin").write_bytes(tsaifile(cam))
    for name in ("a.txt", "b.cam", "c.bin"):
        assert_same_camera(read_camera(tmp_path / name), cam, with_size=name == "b.cam")
    (tmp_path / "d.xyz").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(FormatError, match=r"d\.xyz: not a camera file"):
        read_camera(tmp_path / "d.xyz")


def test_formats_never_import_the_registry() -> None:
    """orthomvp.camera imports its model, distortion and format modules, never the reverse."""
    package = Path(orthomvp.camera.__file__).parent
    for path in [package / "model.py", package / "distortion.py", *package.glob("formats/*.py")]:
        nodes = list(ast.walk(ast.parse(path.read_text())))
        imported = {node.module for node in nodes if isinstance(node, ast.ImportFrom)}
        imported |= {a.name for node in nodes if isinstance(node, ast.Import) for a in node.names}
        assert "orthomvp.camera" not in imported, path
        assert "orthomvp.camera.formats" not in imported, path


def test_missing_file_is_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="nope.tsai") as info:
        read_camera(tmp_path / "nope.tsai")
    assert not isinstance(info.value, FormatError)
    with pytest.raises(InputError, match="nodir"):
        write_tsai(make_camera("null"), tmp_path / "nodir" / "cam.tsai")


GOOD_TSAI = [
    "VERSION_4",
    "PINHOLE",
    "fu = 1000",
    "fv = 1000",
    "cu = 500",
    "cv = 400",
    "u_direction = 1 0 0",
    "v_direction = 0 1 0",
    "w_direction = 0 0 1",
    "C = 1 2 3",
    "R = 1 0 0 0 1 0 0 0 1",
    "pitch = 1",
    "TSAI",
    "k1 = 0.1",
    "k2 = 0.01",
    "p1 = 0.001",
    "p2 = 0.002",
]


def edit(line: int, text: str | None) -> list[str]:
    """GOOD_TSAI with 1-based ``line`` replaced by ``text`` (None: deleted)."""
    lines = list(GOOD_TSAI)
    if text is None:
        del lines[line - 1]
    else:
        lines[line - 1] = text
    return lines


BAD_TSAI = {
    "truncated": (GOOD_TSAI[:9], 10, "file ends where 'C = ...' was expected"),
    "truncated before distortion": (GOOD_TSAI[:12], 13, "lens distortion name"),
    "non-numeric": (edit(3, "fu = abc"), 3, "'abc' after 'fu =' is not a number"),
    "too few numbers": (edit(10, "C = 1 2"), 10, "expected 3 numbers after 'C =', found 2"),
    "missing key": (edit(6, None), 6, "expected 'cv = ...', found 'u_direction = 1 0 0'"),
    "missing pitch": (edit(12, None), 12, "expected 'pitch = ...', found 'TSAI'"),
    "bad rotation": (edit(11, "R = 1 0 0 0 1 0 0 0 2"), 11, "R is not a rotation"),
    "reflection": (edit(11, "R = 1 0 0 0 1 0 0 0 -1"), 11, "reflection"),
    "skew frame": (edit(7, "u_direction = 1 0.1 0"), 7, "not orthonormal"),
    "negative focal": (edit(4, "fv = -1000"), 4, "fv must be positive"),
    "overflow": (edit(5, "cu = 1e999"), 5, "finite"),
    "not pinhole": (edit(2, "OPTICAL_BAR"), 2, "'OPTICAL_BAR' is not supported"),
    "bad version": (edit(1, "VERSION_9"), 1, "unsupported version"),
    "unknown distortion": (edit(13, "WOBBLY"), 13, "unsupported lens distortion model"),
    "rpc distortion": (edit(13, "RPC"), 13, "ASP's RPC lens distortion is not supported"),
    "missing parameter": (edit(17, None), 13, "TSAI distortion is missing p2"),
    "bad parameter": (edit(15, "k2 = 1,5"), 15, "'1,5' after 'k2 =' is not a number"),
    "unknown parameter": ([*GOOD_TSAI, "k9 = 1"], 18, "no parameter 'k9'"),
    "repeated parameter": ([*GOOD_TSAI, "k1 = 1"], 18, "'k1' given twice"),
    "junk line": ([*GOOD_TSAI, "hello"], 18, "expected '<parameter> = <number>'"),
    "empty": ([], 1, "empty camera file"),
}


@pytest.mark.parametrize("case", list(BAD_TSAI))
def test_bad_tsai_files(tmp_path: Path, case: str) -> None:
    lines, line, message = BAD_TSAI[case]
    path = tmp_path / "cam.tsai"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError) as info:
        read_camera(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}, line {line}: ")
    assert message in str(info.value)


def test_good_tsai_template_reads(tmp_path: Path) -> None:
    path = tmp_path / "cam.tsai"
    path.write_text("\n".join(GOOD_TSAI) + "\n")
    assert read_camera(path).distortion == TsaiDistortion(0.1, 0.01, 0.001, 0.002)


def test_binary_garbage_tsai(tmp_path: Path) -> None:
    path = tmp_path / "cam.tsai"
    path.write_bytes(b"VERSION_4\n\xff\xfe")
    with pytest.raises(FormatError, match="cam.tsai: not a text file"):
        read_camera(path)


BAD_JSON = {
    "syntax": ('{"fu": 10,\n "fv": }', 2, "invalid JSON"),
    "bad rotation": (
        (
            '{"fu": 1, "fv": 1, "cu": 0, "cv": 0, "center": [0, 0, 0],\n'
            ' "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 3]]}'
        ),
        2,
        "R is not a rotation",
    ),
    "not a number": (
        (
            '{"fu": "ten", "fv": 1, "cu": 0, "cv": 0, "center": [0, 0, 0],\n'
            ' "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}'
        ),
        1,
        "fu: 'ten' is not a number",
    ),
    "unknown key": ('{\n"fu": 1,\n"focal": 3}', 3, "unknown key 'focal'"),
    "bad model": (
        (
            '{"fu": 1, "fv": 1, "cu": 0, "cv": 0, "center": [0, 0, 0],\n'
            ' "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],\n "distortion": {"model": "RPC"}}'
        ),
        3,
        "ASP's RPC lens distortion is not supported",
    ),
}


@pytest.mark.parametrize("case", list(BAD_JSON))
def test_bad_json_files(tmp_path: Path, case: str) -> None:
    text, line, message = BAD_JSON[case]
    path = tmp_path / "cam.json"
    path.write_text(text)
    with pytest.raises(FormatError) as info:
        read_camera(path)
    assert str(info.value).startswith(f"{path}, line {line}: ")
    assert message in str(info.value)


def test_json_missing_key(tmp_path: Path) -> None:
    path = tmp_path / "cam.json"
    path.write_text('{"fu": 1, "fv": 1, "cu": 0, "cv": 0, "center": [0, 0, 0]}')
    with pytest.raises(FormatError, match=r"cam\.json: missing key 'rotation'"):
        read_camera(path)


def corrupt_pinholes() -> dict[str, tuple[bytes, str]]:
    good = tsaifile(make_camera("null"))
    return {
        "truncated": (good[:100], "runs past the end"),
        "truncated varint": (good + b"\x82", "truncated varint"),
        "wire type 7": (good[:13] + b"\x17" + good[13:], "unsupported wire type 7 (field 2)"),
        "empty": (b"", "empty file"),
        "no distortion name": (good.replace(pb_string(9, "NULL"), b""), "distortion_name"),
        "no focal length": (
            good.replace(pb_doubles(2, [1200.0, 1150.0], True), b""),
            "focal_length (field 2) has 0 values, expected 2",
        ),
        "doubles as string": (good + pb_string(7, "abc"), "3 bytes of packed doubles"),
        "float for double": (good + pb_key(11, 5) + b"\0\0\x80\x3f", "wire type 5"),
        "bad rotation": (tsaifile(make_camera("null"), rotation=2 * np.eye(3)), "not a rotation"),
        "unknown distortion": (tsaifile(make_camera("null"), name="WOBBLY"), "'WOBBLY'"),
        "fov needs 1": (tsaifile(make_camera("null"), name="FOV"), "FOV distortion needs 1"),
        "tsai needs 4": (good.replace(b"NULL", b"TSAI"), "TSAI distortion needs 4 or 5 values"),
    }


@pytest.mark.parametrize("case", list(corrupt_pinholes()))
def test_corrupt_pinhole_files(tmp_path: Path, case: str) -> None:
    data, message = corrupt_pinholes()[case]
    path = tmp_path / "cam.pinhole"
    path.write_bytes(data)
    with pytest.raises(FormatError) as info:
        read_camera(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


def test_camera_protocol_origins_and_gsd() -> None:
    """A pinhole is a Camera; its ray origins are its centre and its GSD matches the pixel
    footprint found by finite differences of project() at a point on the optical axis."""
    from orthomvp.camera import Camera

    rot = np.diag([1.0, -1.0, -1.0])  # looking straight down
    cam = PinholeCamera(
        800.0, 800.0, 400.0, 300.0, [10.0, 20.0, 1000.0], rot, width=800, height=600
    )
    assert isinstance(cam, Camera)
    uv = np.array([[0.0, 0.0], [799.0, 599.0]])
    np.testing.assert_array_equal(cam.origins(uv), np.broadcast_to(cam.center, (2, 3)))
    np.testing.assert_allclose(cam.origins(uv), cam.ray(uv)[0])
    x = np.array([10.0, 20.0, 0.0])  # 1000 m below the camera
    step = 0.01
    du = cam.project(x + [step, 0.0, 0.0])[0] - cam.project(x)[0]
    np.testing.assert_allclose(cam.gsd(x), step / np.linalg.norm(du), rtol=1e-9)
    assert cam.gsd(x) == pytest.approx(1000.0 / 800.0)
