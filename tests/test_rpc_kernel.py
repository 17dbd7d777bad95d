"""The RPC's numba kernels (orthomvp.camera.rpc_kernel) against the numpy model they stand for
(orthomvp.camera.rpc_model.Rpc, itself checked against GDAL in tests/test_rpc.py), their
analytic derivatives against finite differences, their geocentric conversions against PROJ, and
the values the lattice takes from them against the camera's own project, ray and gsd."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS, Transformer

from orthomvp.camera import Rpc, RpcCamera, read_camera
from orthomvp.camera import rpc_kernel as kernel
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.post_lattice import exact_values
from tests.conftest import shared
from tests.test_rpc import synthetic_rpc

WGS84_A, WGS84_B = 6378137.0, 6356752.314245179


def _domain_points(rpc: Rpc, n: int, reach: float = 1.2) -> tuple[np.ndarray, ...]:
    """``n`` random (lon, lat, height) within ``reach`` of the RPC's normalised domain."""
    rng = np.random.default_rng(7)
    x, y, z = rng.uniform(-reach, reach, (3, n))
    return (
        rpc.long_off + x * rpc.long_scale,
        rpc.lat_off + y * rpc.lat_scale,
        rpc.height_off + z * rpc.height_scale,
    )


def test_projection_and_inversion_as_the_numpy_model() -> None:
    rpc = Rpc.from_mapping(synthetic_rpc())
    coef, scales = kernel.pack(rpc)
    lon, lat, h = _domain_points(rpc, 5000)
    truth = rpc.project(lon, lat, h)
    uv = np.empty((lon.size, 2))
    kernel.project(lon, lat, h, coef, scales, uv)
    assert np.abs(uv - truth).max() < 1e-9  # pixels
    start = np.stack([lon, lat], -1) + 0.3 * rpc.long_scale
    ground = np.empty_like(start)
    kernel.ground(truth, h, start, coef, scales, ground)
    t_lon, t_lat = rpc.ground(truth, h, start=(start[:, 0], start[:, 1]))
    metres = 111_000.0  # per degree, about
    assert np.abs(ground[:, 0] - t_lon).max() * metres < 1e-6
    assert np.abs(ground[:, 1] - t_lat).max() * metres < 1e-6
    assert np.abs(ground[:, 0] - lon).max() * metres < 1e-6  # and the points themselves
    assert np.abs(ground[:, 1] - lat).max() * metres < 1e-6
    bad = np.array([[np.nan, 10.0], [5.0, 5.0]])  # not finite: NaN, as the numpy model
    out = np.empty((2, 2))
    kernel.ground(bad, np.array([300.0, np.inf]), np.zeros((2, 2)) + 20, coef, scales, out)
    assert np.isnan(out).all()


def test_analytic_derivatives_against_finite_differences() -> None:
    """The derivatives of the normalised sample and line by L, P and H, against central
    differences of the kernel's own ratios (step 1e-6: truncation ~1e-12, rounding ~1e-10)."""
    coef, _ = kernel.pack(Rpc.from_mapping(synthetic_rpc()))
    coef = coef + np.random.default_rng(3).normal(scale=0.02, size=coef.shape)  # curved
    coef[[1, 3], 0] = 1.0
    out, work, ahead, behind = (np.empty((2, 4)) for _ in range(4))
    step = 1e-6
    for x, y, z in np.random.default_rng(4).uniform(-1.3, 1.3, (50, 3)):
        kernel._ratios(coef, x, y, z, out, work)
        for k, dx in enumerate(np.eye(3) * step):
            kernel._ratios(coef, x + dx[0], y + dx[1], z + dx[2], ahead, work)
            kernel._ratios(coef, x - dx[0], y - dx[1], z - dx[2], behind, work)
            numeric = (ahead[:, 0] - behind[:, 0]) / (2 * step)
            np.testing.assert_allclose(out[:, 1 + k], numeric, rtol=1e-7, atol=1e-8)


def test_geocentric_conversions_against_proj() -> None:
    rng = np.random.default_rng(5)
    n = 4000
    lon, lat = rng.uniform(-180, 180, n), rng.uniform(-89.9, 89.9, n)
    h = rng.uniform(-500, 9000, n)
    xyz = np.stack(Transformer.from_crs(4979, 4978, always_xy=True).transform(lon, lat, h), -1)
    e2 = 1 - (WGS84_B / WGS84_A) ** 2
    mine = np.empty_like(xyz)
    kernel.to_geocentric(np.stack([lon, lat, h + 28.0], -1), WGS84_A, e2, 28.0, mine)
    assert np.abs(mine - xyz).max() < 1e-6  # metres (28 m: a height offset, taken off)
    back = np.empty_like(xyz)
    kernel.to_geodetic(xyz, WGS84_A, e2, 0.0, back)
    assert np.abs(back[:, 0] - lon).max() < 1e-11 and np.abs(back[:, 1] - lat).max() < 1e-11
    assert np.abs(back[:, 2] - h).max() < 1e-6
    nan = np.full((1, 3), np.nan)
    kernel.to_geodetic(nan, WGS84_A, e2, 0.0, back[:1])
    assert np.isnan(back[0]).all()


def check_values(camera: RpcCamera, xyz: np.ndarray) -> None:
    """The kernels' values against exact_values (the camera's own project, ray and gsd, numpy
    and PROJ): the same points imaged, pixels within 1e-8 px, depths and origins within 1e-5 m,
    directions within 1e-9, GSDs within 1e-6 of themselves (central differences of 1 m)."""
    fast = kernel.camera_values(camera, xyz)
    assert fast is not None
    truth = exact_values(camera, xyz)
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(truth))
    ok = np.isfinite(truth).all(axis=-1)
    assert ok.sum() > 0.5 * ok.size
    f, t = fast[ok], truth[ok]
    assert np.abs(f[:, :2] - t[:, :2]).max() < 1e-8
    assert np.abs(f[:, 2:6] - t[:, 2:6]).max() < 1e-5
    assert np.abs(f[:, 6:9] - t[:, 6:9]).max() < 1e-9
    assert (np.abs(f[:, 9] - t[:, 9]) / t[:, 9]).max() < 1e-6


def test_values_as_the_camera_gives_them() -> None:
    """A synthetic RPC camera in the geocentric frame (its default), at points inside its
    domain, beyond it (NaN), above its top (negative depths) and not finite."""
    rpc = Rpc.from_mapping(synthetic_rpc())
    camera = RpcCamera(rpc, width=800, height=1000)
    lon, lat, h = _domain_points(rpc, 3000, reach=1.7)
    xyz = camera.to_world(lon, lat, h)
    xyz[:5] = np.nan
    check_values(camera, xyz.reshape(50, 60, 3))
    above = camera.to_world(rpc.long_off, rpc.lat_off, camera.top + 50.0)
    assert kernel.camera_values(camera, above[None])[0, 2] < 0


def test_frames_the_kernels_do_not_serve() -> None:
    """A projected (map-frame) world CRS is not served: the lattice keeps the camera's own."""
    rpc = Rpc.from_mapping(synthetic_rpc())
    utm = CRS.from_epsg(32634)
    assert kernel.frame(RpcCamera(rpc, crs=utm)) is None
    assert kernel.camera_values(RpcCamera(rpc, crs=utm), np.zeros((1, 3))) is None
    assert kernel.frame(RpcCamera(rpc)) is not None


@pytest.mark.realdata
def test_quickbird_values_over_the_dem() -> None:
    """The QuickBird camera over the ngi-aerial DEM in the body frame, as the CLI binds it."""
    terrain = Terrain.read(shared("ngi-aerial", "dem.tif"), world="body", vertical_datum="ignore")
    camera = read_camera(shared("rpc-quickbird", "qb2_basic1b.tif")).bind(terrain)
    r, c = np.mgrid[0 : terrain.shape[0] : 4, 0 : terrain.shape[1] : 4].astype(np.float64)
    check_values(camera, terrain.to_world(c, r, terrain.values[::4, ::4]))
