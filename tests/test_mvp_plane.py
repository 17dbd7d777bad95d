"""MVP geometry and objective: every formula against finite differences or exact geometry."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS
from scipy.ndimage import gaussian_filter

from orthomvp.camera import PinholeCamera
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector
from orthomvp.mvp.deconvolve import deconvolve, window_plane
from orthomvp.mvp.model import PlaneModel
from orthomvp.mvp.patches import ViewStack
from orthomvp.mvp.plane import (
    L_matrix,
    angles_from_normal,
    lonlat_jacobian,
    normal_from_angles,
    post_lines,
    tangent_basis,
    uses_central_model,
)
from orthomvp.mvp.window import Window
from orthomvp.synthetic import look_at, make_scene

RNG = np.random.default_rng(7)


def test_eq5_jacobian_matches_finite_differences() -> None:
    lon = RNG.uniform(-np.pi, np.pi, 50)
    lat = RNG.uniform(-1.5, 1.5, 50)
    J = lonlat_jacobian(lon, lat)
    d = 1e-6
    fd_lon = (unit_vector(lon + d, lat) - unit_vector(lon - d, lat)) / (2 * d)
    fd_lat = (unit_vector(lon, lat + d) - unit_vector(lon, lat - d)) / (2 * d)
    np.testing.assert_allclose(J[..., 0], fd_lon, atol=1e-9)
    np.testing.assert_allclose(J[..., 1], fd_lat, atol=1e-9)
    # the paper's printed sign (+cos lon sin lat) would fail here
    assert np.allclose(J[..., 0, 1], -np.cos(lon) * np.sin(lat))


def test_eq7_L_is_the_first_order_taylor_expansion() -> None:
    lon0, lat0 = 0.4, -0.7
    L = L_matrix(lon0, lat0)
    for dl in (1e-3, 1e-4):
        theta = np.array([lon0 + dl, lat0 - 0.5 * dl, 1.0])
        e_lin = L @ theta
        assert e_lin[3] == 1.0
        err = np.linalg.norm(e_lin[:3] - unit_vector(theta[0], theta[1]))
        assert err < dl**2  # second-order remainder only


def test_eq11_normal_angles_round_trip() -> None:
    t = RNG.uniform(-np.pi, np.pi, 100)
    p = RNG.uniform(-1.5, 1.5, 100)
    n = normal_from_angles(t, p)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0)
    t2, p2 = angles_from_normal(3.0 * n)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    np.testing.assert_allclose(p2, p, atol=1e-12)


def _camera_over(terrain: Terrain, emission_deg: float, azimuth_deg: float) -> PinholeCamera:
    """A camera 100 km (map frame: 3 km) from the grid centre, looking at it."""
    rows, cols = terrain.shape
    c0, r0 = np.array((cols - 1) / 2), np.array((rows - 1) / 2)
    v = np.array(float(np.median(terrain.values)))
    target = terrain.to_world(c0, r0, v)
    up = terrain.to_world(c0, r0, v + 1.0) - target
    up /= np.linalg.norm(up)
    north = terrain.to_world(c0, r0 - 1, v) - target
    north -= up * (north @ up)
    north /= np.linalg.norm(north)
    east = np.cross(north, up)
    em, az = np.radians(emission_deg), np.radians(azimuth_deg)
    dist = 3000.0 if terrain.world == "map" else 100_000.0
    centre = target + dist * (
        np.cos(em) * up + np.sin(em) * (np.sin(az) * east + np.cos(az) * north)
    )
    f = dist / 30.0  # 30 m pixels at the target, as the Apollo metric frames
    return PinholeCamera(f, f, 500.0, 500.0, centre, look_at(centre, target, north))


def _terrains() -> dict[str, Terrain]:
    moon = "+proj=longlat +R=1737400 +no_defs"
    d = 40 / 1737400 * 180 / np.pi
    return {
        "moon geographic (central)": Terrain(
            np.full((80, 80), -1500.0), Affine(d, 0, 10.0, 0, -d, 30.0), CRS.from_proj4(moon)
        ),
        "moon radii (central)": Terrain(
            np.full((80, 80), 1735900.0),
            Affine(d, 0, 170.0, 0, -d, -60.0),
            CRS.from_proj4(moon),
            radius_values=True,
        ),
        "moon polar stereographic (central)": Terrain(
            np.full((80, 80), 200.0),
            Affine(40, 0, 100000.0, 0, -40, 50000.0),
            CRS.from_proj4("+proj=stere +lat_0=90 +lon_0=0 +R=1737400 +units=m +no_defs"),
        ),
        "mars ellipsoid (central)": Terrain(
            np.full((80, 80), 3000.0),
            Affine(0.0007, 0, 77.0, 0, -0.0007, 48.0),
            CRS.from_proj4("+proj=longlat +a=3396190 +b=3376200 +no_defs"),
        ),
        "utm map frame (parallel)": Terrain(
            np.full((80, 80), 400.0),
            Affine(5, 0, 500000.0, 0, -5, 6200000.0),
            CRS.from_epsg(32735),
            world="map",
        ),
    }


def _exact_image_points(terrain, camera, c0, r0, h, n, c, r) -> np.ndarray:  # noqa: ANN001
    """Independent reference: for each grid pixel, the DEM's own height line (all values at
    that pixel, through Terrain.to_world) meets the plane through the post's point at height
    h with normal n; project that point."""
    x0 = terrain.to_world(np.array(c0), np.array(r0), np.array(h))
    p0 = terrain.to_world(c, r, np.full(c.shape, h - 50.0))
    p1 = terrain.to_world(c, r, np.full(c.shape, h + 50.0))
    d = p1 - p0
    t = ((x0 - p0) @ n) / (d @ n)
    uv, _ = camera.project(p0 + t[:, None] * d)
    return uv


@pytest.mark.parametrize("name", list(_terrains()))
def test_homography_matches_exact_plane_projection(name: str) -> None:
    """H = F G maps patch offsets to the exact image position of the plane point: within
    0.01 px for the paper's patches (hwin 10, pyramid level 0), and within 0.02 px of the
    image it samples at the coarse levels (patch steps of 2 and 4 posts on images reduced 2
    and 4 times, 80 to 160 posts wide), which only steer the start of the fit."""
    terrain = _terrains()[name]
    assert uses_central_model(terrain) == ("central" in name)
    camera = _camera_over(terrain, 25.0, 60.0)
    c0, r0, h = 41.0, 37.0, float(terrain.values[37, 41]) + 120.0
    lines = post_lines(terrain, np.array([c0]), np.array([r0]), np.array([h - 120.0]))
    up = lines.up[0]
    t1, t2 = tangent_basis(up[None])
    n = up + 0.35 * t1[0] - 0.2 * t2[0]  # about 22 degrees of tilt
    n /= np.linalg.norm(n)
    model = PlaneModel(lines, n[None], camera.F[None], 40.0)
    theta = np.array([[h, 0.0, 0.0]])
    offsets = Window(10, 5.0).offsets
    worst = []
    for level in (0, 1, 2):
        step = 2.0**level
        H, _ = model.homographies(theta, level, derivatives=False)
        xyw = H[0, 0] @ np.vstack([offsets.T, np.ones(len(offsets))])
        uv_h = (xyw[:2] / xyw[2]).T
        c = c0 + step * offsets[:, 0].astype(float)
        r = r0 + step * offsets[:, 1].astype(float)
        uv_exact = _exact_image_points(terrain, camera, c0, r0, h, n, c, r) / step
        worst.append(float(np.abs(uv_h - uv_exact).max()))
    assert worst[0] < 0.01, f"{name}: homography off by {worst[0]:.4f} px"
    assert max(worst) < 0.02, f"{name}: coarse homographies off by {worst} px"


def test_homography_derivatives_match_finite_differences() -> None:
    terrain = _terrains()["moon geographic (central)"]
    cams = [_camera_over(terrain, 20.0, 0.0), _camera_over(terrain, 10.0, 200.0)]
    F = np.stack([c.F for c in cams])
    c, r = np.array([30.0, 50.0]), np.array([40.0, 20.0])
    lines = post_lines(terrain, c, r, np.array([-1500.0, -1500.0]))
    model = PlaneModel(lines, lines.up, F, 40.0)
    theta = np.array([[-1480.0, 0.05, -0.1], [-1510.0, -0.02, 0.2]])
    H, dH = model.homographies(theta, 1)
    steps = (10.0, 1e-3, 1e-3)  # H is affine in each parameter: any step is exact
    for p, d in enumerate(steps):
        tp, tm = theta.copy(), theta.copy()
        tp[:, p] += d
        tm[:, p] -= d
        fd = (model.homographies(tp, 1, False)[0] - model.homographies(tm, 1, False)[0]) / (2 * d)
        scale = np.abs(dH[:, :, p]).max()
        np.testing.assert_allclose(dH[:, :, p], fd, atol=1e-6 * scale)


def _planar_setup(hwin: int = 10, blur: float = 0.0):  # noqa: ANN202
    scene = make_scene("planar", size=48)
    cams = list(scene.cameras.values())
    images = [scene.render(cam, 2) for cam in cams]
    if blur:
        images = [gaussian_filter(img, blur) for img in images]
    stack = ViewStack.build(images, cams, 1)
    terrain = scene.terrain
    c, r = np.array([20.0, 26.0, 24.0]), np.array([22.0, 25.0, 18.0])
    ri, ci = r.astype(int), c.astype(int)
    lines = post_lines(terrain, c, r, terrain.values[ri, ci])
    model = PlaneModel(lines, terrain.normals()[ri, ci], stack.F, 40.0)
    return scene, stack, model, Window(hwin, hwin / 2), terrain.values[ri, ci]


def test_normalised_patches_and_eq20_identity() -> None:
    """Eq. 19 patches have zero weighted mean and unit weighted std; eq. 20 equals
    (n - 1) (1 - mean pairwise weighted correlation), computed independently in float64."""
    _, stack, model, window, h = _planar_setup()
    theta = np.column_stack([h + 10.0, np.zeros(3), np.zeros(3)])
    H, _ = model.homographies(theta, 0, False)
    W = np.ones((3, 4), bool)
    ev = stack.evaluate(0, H, W, window, keep_patches=True)
    I = ev.patches.astype(np.float64)  # noqa: E741
    gg = window.weights.astype(np.float64)
    np.testing.assert_allclose(I @ gg, 0.0, atol=1e-5)
    np.testing.assert_allclose((I * I) @ gg, 1.0, atol=1e-4)
    for b in range(3):
        rho = [(I[b, k] * I[b, m]) @ gg for k in range(4) for m in range(k + 1, 4)]
        assert ev.cost[b] == pytest.approx(3 * (1 - np.mean(rho)), rel=1e-4)
        A = I[b].mean(axis=0)
        direct = sum(((A - I[b, k]) ** 2) @ gg for k in range(4))
        assert ev.cost[b] == pytest.approx(direct, rel=1e-4)


def test_objective_gradient_matches_finite_differences() -> None:
    """2 J^T r (analytic, through image gradients and the normalisation) against central
    differences of f, away from the minimum. The images are smoothed (sigma 1.5 px) so that
    the per-pixel image gradient is accurate and the test checks the algebra."""
    _, stack, model, window, h = _planar_setup(blur=1.5)
    theta = np.column_stack([h + 12.0, np.full(3, 0.03), np.full(3, -0.02)])
    W = np.ones((3, 4), bool)
    H, dH = model.homographies(theta, 0)
    ev = stack.evaluate(0, H, W, window, dH)
    grad = 2 * ev.JTr
    for p, d in enumerate((1.0, 0.003, 0.003)):
        tp, tm = theta.copy(), theta.copy()
        tp[:, p] += d
        tm[:, p] -= d
        fp = stack.evaluate(0, model.homographies(tp, 0, False)[0], W, window).cost
        fm = stack.evaluate(0, model.homographies(tm, 0, False)[0], W, window).cost
        fd = (fp - fm) / (2 * d)
        np.testing.assert_allclose(
            grad[:, p], fd, err_msg=f"parameter {p}", rtol=0.1, atol=0.01 * np.abs(fd).max()
        )
    # J^T J is positive definite and matches the curvature of f along h
    assert np.all(np.linalg.eigvalsh(ev.JTJ) > 0)


def test_window_plane_is_exact_on_planes_and_deconvolution_undoes_the_window() -> None:
    r, c = np.mgrid[0:60, 0:70].astype(float)
    plane = 3.0 + 0.5 * c - 0.25 * r
    holes = plane.copy()
    holes[20:25, 30:33] = np.nan
    fitted = window_plane(holes, 10, 5.0)
    ok = np.isfinite(fitted)
    assert ok.sum() > 0.95 * np.isfinite(holes).sum()
    np.testing.assert_allclose(fitted[ok], plane[ok], atol=1e-8)  # borders and holes too
    # a curved surface: plane heights are biased by k sigma^2 / 2; deconvolution removes it
    x, y = (c - 35) * 30.0, (r - 30) * 30.0
    surface = 200 * np.exp(-(x**2 + y**2) / (2 * 400.0**2))
    smoothed = window_plane(surface, 10, 5.0)
    inner = (slice(12, -12), slice(12, -12))
    before = np.sqrt(np.mean((smoothed - surface)[inner] ** 2))
    after = np.sqrt(np.mean((deconvolve(smoothed, 10, 5.0, 2) - surface)[inner] ** 2))
    assert before > 5.0 and after < 0.1 * before


def test_window_grid_and_weights() -> None:
    """The patch grid runs c fastest over -hwin..hwin, the weights are the normalised Gaussian
    of the offsets, and bad sizes are refused."""
    w = Window(2, 1.5)
    assert w.side == 5 and w.offsets.shape == (25, 2) and w.weights.dtype == np.float32
    first = [[-2, -2], [-1, -2], [0, -2], [1, -2], [2, -2], [-2, -1]]
    np.testing.assert_array_equal(w.offsets[:6], first)
    d2 = (w.offsets.astype(np.float64) ** 2).sum(axis=1)
    expected = np.exp(-d2 / (2 * 1.5**2))
    np.testing.assert_allclose(w.weights, expected / expected.sum(), rtol=1e-6)
    for hwin, sigma in ((0, 1.0), (3, 0.0), (3, float("nan"))):
        with pytest.raises(InputError, match="hwin must be >= 1 and sigma > 0"):
            Window(hwin, sigma)
