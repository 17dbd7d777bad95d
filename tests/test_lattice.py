"""The lattice geometry of costly cameras (orthomvp.occlusion.post_lattice) against the exact
path it stands for: every post's pixel, ray and GSD within the stated bound of the camera's
own values, the same codes away from class boundaries, the same values whatever the tiling."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS

from orthomvp.bench.peer import SYNTHETIC_PEER_CRS
from orthomvp.bench.workload import bench_line_scanner, bench_terrain
from orthomvp.camera import Camera, read_camera
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import finite_rows
from orthomvp.occlusion.paths import Geometry, VisibilityPath
from orthomvp.occlusion.post_lattice import (
    GSD_RELATIVE,
    LATTICE_ERROR,
    WORLD_TOLERANCE,
    exact_values,
    tile_values,
    world_block,
)
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.synthetic import MOON_CRS
from orthomvp.synthetic.scoring import away_from_boundaries
from tests.conftest import shared

UNDULATION = 28.0  # m, the geoid under the QuickBird scene (as tests/test_rpc.py)


def quickbird_case(world: str = "map") -> tuple[Terrain, Camera]:
    """The QuickBird RPC camera over the ngi-aerial DEM, in the map frame (the camera's own
    values through numpy and PROJ) or the body frame (through the RPC's numba kernels)."""
    terrain = Terrain.read(shared("ngi-aerial", "dem.tif"), world=world, vertical_datum="ignore")
    camera = read_camera(shared("rpc-quickbird", "qb2_basic1b.tif"))
    return terrain, replace(camera.bind(terrain), height_offset=UNDULATION)


def nac_case() -> tuple[Terrain, Camera]:
    """The LRO NAC line scanner of a real ISD (ALE's, from the cube in isis/) over 240 x 240
    posts of rolling lunar relief (+-25 m, 1 m posts) around its 220 m footprint."""
    camera = read_camera(shared("isis", "M143947267L.cal.echo.crop.isd.json"))
    centre = camera.image_to_ground(np.array([[199.5, 199.5]]))[0]
    lon, lat = (
        np.degrees(np.arctan2(centre[1], centre[0])),
        np.degrees(np.arcsin(centre[2] / np.linalg.norm(centre))),
    )
    n, step = 240, np.degrees(1.0 / 1737400.0)
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    z = 25 * np.sin(c / 17.0) * np.cos(r / 23.0) + 8 * np.sin((c + r) / 5.0)
    transform = Affine(step, 0, lon - n / 2 * step, 0, -step, lat + n / 2 * step)
    return Terrain(z, transform, CRS.from_proj4(MOON_CRS), name="nac"), camera


def _posts(terrain: Terrain) -> tuple[np.ndarray, np.ndarray]:
    r, c = np.mgrid[0 : terrain.shape[0], 0 : terrain.shape[1]].astype(np.float64)
    p = terrain.to_world(c, r, terrain.values)
    return p, finite_rows(p)


def check_bound(
    terrain: Terrain, camera: Camera, error: float = LATTICE_ERROR, exact_within: float = 0.0
) -> np.ndarray:
    """Every post's interpolated pixel, ray and GSD against the camera's own: within
    ``error`` pixels (the ray's offset at the post in pixels of its GSD) and GSD_RELATIVE; the
    posts left exact within ``exact_within`` (pixels, metres) of them (0: the same values)."""
    p, ok = _posts(terrain)
    whole = (slice(0, terrain.shape[0]), slice(0, terrain.shape[1]))
    values, exact = tile_values(terrain, camera, *whole, p, ok, error=error)
    truth = exact_values(camera, p)
    imaged = finite_rows(truth[..., :2]) & camera.in_image(truth[..., :2])
    assert imaged.sum() > 1000
    v, t = values[imaged], truth[imaged]
    assert np.isfinite(v).all()
    assert np.abs(v[:, :2] - t[:, :2]).max() <= error
    gsd = t[:, 9]
    d = v[:, 6:9] / np.linalg.norm(v[:, 6:9], axis=-1, keepdims=True)
    rng = np.linalg.norm(p[imaged] - t[:, 3:6], axis=-1)
    ray = np.linalg.norm(v[:, 3:6] - t[:, 3:6], axis=-1) + rng * np.linalg.norm(
        d - t[:, 6:9], axis=-1
    )
    assert (ray / gsd).max() <= error
    assert (np.abs(v[:, 9] - gsd) / gsd).max() <= GSD_RELATIVE
    assert (np.sign(v[:, 2]) == np.sign(t[:, 2])).all()
    np.testing.assert_allclose(values[exact], truth[exact], rtol=0, atol=exact_within)
    return exact


def check_codes(terrain: Terrain, camera: Camera) -> None:
    """compute_visibility takes the lattice by default; its codes are the exact path's away
    from class boundaries, and its pixels within the bound."""
    path = VisibilityPath()
    step = float(np.mean(terrain.post_spacing()))
    resolver = path.resolve(
        terrain, camera, None, fields=frozenset(), carry_from=None, spacing=step, step=1.0
    )
    assert resolver.geometry is Geometry.LATTICE
    exact = compute_visibility(terrain, camera, path=VisibilityPath(geometry="general"))
    fast = compute_visibility(terrain, camera)
    keep = away_from_boundaries(exact.codes)
    assert keep.mean() > 0.5
    np.testing.assert_array_equal(fast.codes[keep], exact.codes[keep])
    both = finite_rows(exact.uv)
    np.testing.assert_array_equal(finite_rows(fast.uv)[keep], both[keep])
    assert np.abs(fast.uv[both & keep] - exact.uv[both & keep]).max() <= LATTICE_ERROR


@pytest.mark.realdata
@pytest.mark.slow
def test_rpc_within_the_bound() -> None:
    terrain, camera = quickbird_case()
    part = terrain.crop(100, 300, 60, 260)
    check_bound(part, camera)
    assert check_bound(part, camera, error=1e-6).any()  # a tighter bound: some posts exact


@pytest.mark.realdata
@pytest.mark.slow
def test_rpc_codes_as_exact() -> None:
    terrain, camera = quickbird_case()
    check_codes(terrain.crop(0, 300, 0, 327), camera)


@pytest.mark.realdata
@pytest.mark.slow
def test_rpc_body_frame_within_the_bound_and_codes_as_exact() -> None:
    """The body frame, as the command line binds an RPC camera: the lattice's exact values
    from the RPC's numba kernels (tests/test_rpc_kernel.py), and at 24 m posts its cubics
    (bilinear misses by far more than the bound over a cell of 64 posts)."""
    terrain, camera = quickbird_case("body")
    part = terrain.crop(100, 300, 60, 260)
    check_bound(part, camera)
    assert check_bound(part, camera, error=1e-6, exact_within=1e-5).any()
    check_codes(terrain.crop(0, 300, 0, 327), camera)


@pytest.mark.realdata
@pytest.mark.slow
def test_csm_line_scanner_within_the_bound() -> None:
    terrain, camera = nac_case()
    check_bound(terrain, camera)


def test_synthetic_line_scanner_with_occlusion() -> None:
    """The bench's orbital line scanner 30 degrees off nadir over its relief made five times
    as steep: every post within the bound (line scanners keep the exact path by default)."""
    terrain = bench_terrain(160)
    terrain = terrain.with_values(terrain.values * 5)
    camera = bench_line_scanner(terrain)
    check_bound(terrain, camera)


def test_every_tiling_gives_the_same_values() -> None:
    """The lattice is the grid's: a tile's posts get the values the whole grid gives them."""
    terrain = bench_terrain(120)
    camera = bench_line_scanner(terrain)
    p, ok = _posts(terrain)
    whole, _ = tile_values(terrain, camera, slice(0, 120), slice(0, 120), p, ok)
    rs, cs = slice(37, 101), slice(13, 58)
    part, _ = tile_values(terrain, camera, rs, cs, p[rs, cs], ok[rs, cs])
    np.testing.assert_allclose(part, whole[rs, cs], rtol=1e-12, atol=1e-9, equal_nan=True)
    window = terrain.crop(37, 101, 13, 58)  # a Terrain of its own, as the engine's tiles are
    alone, _ = tile_values(window, camera, slice(0, 64), slice(0, 45), p[rs, cs], ok[rs, cs])
    np.testing.assert_allclose(alone, whole[rs, cs], rtol=1e-12, atol=1e-9, equal_nan=True)


@pytest.mark.parametrize("res", [2.0, 6.0, 24.0])
def test_world_points_within_their_tolerance_whatever_the_tiling(res: float) -> None:
    """Body-fixed points of a transverse Mercator grid on the WGS84 ellipsoid: the lattice's
    within WORLD_TOLERANCE of Terrain.to_world (PROJ) at every post, NaN heights NaN, and a
    window's points those of the whole grid."""
    z = np.random.default_rng(0).uniform(150, 780, (300, 260))
    z[5, 7] = np.nan
    transform = Affine(res, 0, -59326.0, 0, -res, -3724892.0)
    terrain = Terrain(z, transform, CRS.from_proj4(SYNTHETIC_PEER_CRS), world="body")
    r, c = np.mgrid[0:300, 0:260].astype(np.float64)
    truth = terrain.to_world(c, r, z)
    whole = world_block(terrain, 0, 300, 0, 260)
    np.testing.assert_array_equal(np.isnan(whole), np.isnan(truth))
    assert np.nanmax(np.abs(whole - truth)) <= WORLD_TOLERANCE
    np.testing.assert_array_equal(world_block(terrain, 37, 211, 13, 158), whole[37:211, 13:158])


@pytest.mark.slow
def test_synthetic_rpc_cubics_within_the_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """A made-up RPC camera (tests/test_rpc.py's) with a strong quadratic term, over rolling
    relief in the body frame: bilinear cells of 64 posts miss by far more than the bound, so the
    lattice takes cubics there (and the kernels' values); every post within the bound of the
    camera's own numpy values, and the codes as the exact path's away from class boundaries."""
    from orthomvp.camera import Rpc, RpcCamera
    from orthomvp.occlusion import post_lattice
    from tests.test_rpc import synthetic_rpc

    values = synthetic_rpc()
    values["samp_num_coeff"][7] = values["line_num_coeff"][8] = 2e-3  # L^2, P^2
    camera = RpcCamera(Rpc.from_mapping(values), width=800, height=1000)
    n, step = 120, 0.0005  # degrees, about 55 m
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    z = 300 + 60 * np.sin(c / 9.0) * np.cos(r / 13.0) + 20 * np.sin((c + r) / 4.0)
    transform = Affine(step, 0, 20.0 - n / 2 * step, 0, -step, 10.0 + n / 2 * step)
    terrain = Terrain(z, transform, CRS.from_epsg(4326), world="body")
    camera = camera.bind(terrain)
    cubic = []
    check = post_lattice._check

    def counted(*args: object) -> tuple:
        out = check(*args)
        cubic.append((len(args[2]), int(out[4].sum())))  # (units checked, units gone cubic)
        return out

    monkeypatch.setattr(post_lattice, "_check", counted)
    check_bound(terrain, camera, exact_within=1e-5)
    # the first lattice of the grid's units (after _first_lattice's probe of one unit)
    assert next(n for units, n in cubic if units > 1) > 0
    monkeypatch.undo()
    check_codes(terrain, camera)


@pytest.mark.realdata
@pytest.mark.parametrize(("res", "first"), [(6.0, 1), (2.0, 0)])
def test_first_lattice_from_the_probe(res: float, first: int) -> None:
    """QuickBird in the body frame over rolling relief on the bench's transverse Mercator grid:
    at 6 m posts every unit of 64 posts misses by less than four times the bound and halves,
    so the probe starts the lattice at 32 posts; at 2 m at 64. Either way every post within the
    bound of the camera's own values, and a tile's values those of the whole grid."""
    from orthomvp.occlusion.post_lattice import LATTICE_STEPS, _first_lattice

    n = 240
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    z = 450 + 150 * np.sin(c / 37.0) * np.cos(r / 29.0)
    transform = Affine(res, 0, -57000.0, 0, -res, -3728900.0)
    terrain = Terrain(z, transform, CRS.from_proj4(SYNTHETIC_PEER_CRS), world="body")
    camera = read_camera(shared("rpc-quickbird", "qb2_basic1b.tif"))
    camera = replace(camera.bind(terrain), height_offset=UNDULATION)
    assert _first_lattice(terrain, camera, LATTICE_STEPS, LATTICE_ERROR) == first
    check_bound(terrain, camera)
    p, ok = _posts(terrain)
    whole, _ = tile_values(terrain, camera, slice(0, n), slice(0, n), p, ok)
    window = terrain.crop(37, 201, 13, 158)
    rs, cs = slice(37, 201), slice(13, 158)
    alone, _ = tile_values(window, camera, slice(0, 164), slice(0, 145), p[rs, cs], ok[rs, cs])
    np.testing.assert_allclose(alone, whole[rs, cs], rtol=1e-12, atol=1e-9, equal_nan=True)
