"""Vertical datums (orthomvp.geometry.datum): a DEM's heights converted to what its cameras need,
checked against pyproj's own transformation; refusals when PROJ lacks the geoid's grid."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS, Transformer
from pyproj.crs import CompoundCRS

from orthomvp.engine.grid import scan_dem, with_world
from orthomvp.errors import InputError
from orthomvp.geometry import datum
from orthomvp.geometry.datum import TOLERANCE, HeightOptions, height_shift, vertical_part
from orthomvp.geometry.terrain import Terrain
from tests.conftest import shared

NGI = ("ngi-aerial", "dem.tif")
EGM96 = 5773  # EPSG: EGM96 height; its grid (egm96_15.gtx) comes with Debian's proj-data
EGM2008_GRID = "us_nga_egm08_25.tif"


@functools.cache
def grid_missing(vertical: int) -> str | None:
    """Why PROJ cannot convert heights of EPSG ``vertical`` to WGS84 ellipsoidal ones here
    (None when it can)."""
    crs = CompoundCRS("test", [CRS.from_epsg(4326), CRS.from_epsg(vertical)])
    try:
        datum._transformer(crs.to_wkt(), "test")
    except InputError as exc:
        return str(exc)
    return None


def needs_egm96() -> None:
    reason = grid_missing(EGM96)
    if reason is not None:
        pytest.skip(f"PROJ has no EGM96 grid (apt-get install proj-data): {reason}")


def retagged(tmp_path: Path, vertical: int) -> Path:
    """The NGI DEM with its heights said to be of EPSG ``vertical`` (its own horizontal CRS)."""
    with rasterio.open(shared(*NGI)) as src:
        profile, values = src.profile, src.read(1)
        horizontal = CRS.from_wkt(src.crs.to_wkt()).sub_crs_list[0]
    compound = CompoundCRS(f"{horizontal.name} + {vertical}", [horizontal, CRS.from_epsg(vertical)])
    profile.update(crs=rasterio.crs.CRS.from_wkt(compound.to_wkt()))
    path = tmp_path / f"dem-{vertical}.tif"
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(values, 1)
    return path


def pyproj_heights(path: Path, terrain: Terrain) -> np.ndarray:
    """The ellipsoidal heights of the DEM's posts by pyproj's own transformation from the file's
    compound CRS to WGS84 3D (with the grid PROJ has)."""
    with rasterio.open(path) as src:
        compound, raw = CRS.from_wkt(src.crs.to_wkt()), src.read(1).astype(np.float64)
    to_3d = Transformer.from_crs(compound, "EPSG:4979", always_xy=True, only_best=True)
    x, y = terrain.pixel_to_crs(*terrain.grid())
    return np.asarray(to_3d.transform(x, y, raw)[2])


@pytest.mark.realdata
def test_geoid_heights_against_pyproj(tmp_path: Path) -> None:
    """EGM96 heights (grid present) become WGS84 ellipsoidal heights at every post within
    TOLERANCE of pyproj's own transformation, from a lattice far coarser than the posts."""
    needs_egm96()
    path = retagged(tmp_path, EGM96)
    terrain = Terrain.read(path)
    truth = pyproj_heights(path, terrain)
    ok = np.isfinite(truth)
    error = np.abs(terrain.values[ok] - truth[ok]).max()
    raw = Terrain.read(path, vertical_datum="ignore").values
    n = terrain.values - raw
    print(f"EGM96 undulation {np.nanmin(n):.2f}..{np.nanmax(n):.2f} m, error {error:.1e} m")
    assert error < TOLERANCE
    assert 27.5 < np.nanmin(n) and np.nanmax(n) < 29.0  # EGM96 there: 28.1..28.6 m
    with rasterio.open(path) as src:
        shift = height_shift(src.crs, src.transform, terrain.shape, world="body")
    assert shift is not None and shift.step >= 16  # posts between PROJ's evaluations


@pytest.mark.realdata
def test_windows_preview_and_range_agree_with_the_whole_dem(tmp_path: Path) -> None:
    """The engine's per-window reads give the whole DEM's converted values (one lattice for
    every window), its preview the same at its posts, and its height range bounds them."""
    needs_egm96()
    path = retagged(tmp_path, EGM96)
    whole = Terrain.read(path).values
    source = with_world(scan_dem(path, heights=HeightOptions()), "body")
    for window in [(0, 50, 0, 40), (37, 203, 101, 327), (300, 508, 250, 327)]:
        r0, r1, c0, c1 = window
        np.testing.assert_allclose(source.read(window), whole[r0:r1, c0:c1], atol=1e-9)
    s = source.stride
    np.testing.assert_allclose(source.preview.values, whole[::s, ::s], atol=1e-9)
    assert source.h_min <= np.nanmin(whole) and source.h_max >= np.nanmax(whole)
    assert source.h_max - np.nanmax(whole) < 0.5  # a bound, not a loose one
    back = with_world(source, "map")  # the map frame: the file's heights again
    raw = Terrain.read(path, vertical_datum="ignore").values
    np.testing.assert_array_equal(back.read((0, 50, 0, 40)), raw[:50, :40])
    np.testing.assert_array_equal(back.preview.values, raw[::s, ::s])


@pytest.mark.realdata
def test_missing_grid_is_refused_in_one_line_and_offsets_stand_in() -> None:
    """EGM2008's grid is not in PROJ's data here: the body frame refuses, naming the grid and
    how to get it; the map frame (Orthority's convention), --height-offset and ignore read."""
    if grid_missing(3855) is None:
        pytest.skip(f"PROJ has {EGM2008_GRID} here: nothing is missing")
    path = shared(*NGI)
    with pytest.raises(InputError) as info:
        Terrain.read(path)
    message = str(info.value)
    assert "\n" not in message and "'EGM2008 height'" in message
    assert f"projsync --file {EGM2008_GRID}" in message and "--height-offset" in message
    raw = Terrain.read(path, vertical_datum="ignore").values
    np.testing.assert_array_equal(Terrain.read(path, world="map").values, raw)
    np.testing.assert_array_equal(Terrain.read(path, height_offset=28.25).values, raw + 28.25)
    np.testing.assert_array_equal(
        Terrain.read(path, world="map", height_offset=-3.0).values, raw - 3.0
    )
    with pytest.raises(InputError, match=EGM2008_GRID):
        with_world(scan_dem(path), "body")


def test_a_vertical_datum_proj_cannot_convert_is_refused() -> None:
    """A lunar geoid PROJ knows nothing of: refused, not taken as heights above the sphere."""
    moon = CRS.from_user_input("IAU_2015:30100")
    geoid = CRS.from_wkt(
        'VERTCRS["Lunar geoid height",VDATUM["Lunar geoid"],CS[vertical,1],'
        'AXIS["gravity-related height (H)",up,LENGTHUNIT["metre",1]]]'
    )
    compound = CompoundCRS("Moon + lunar geoid", [moon, geoid])
    assert vertical_part(compound).name == "Lunar geoid height"
    grid = Affine(0.01, 0, 55.0, 0, -0.01, 10.0)
    with pytest.raises(InputError, match="PROJ knows no transformation") as info:
        height_shift(compound, grid, (10, 10), world="body", name="moon.tif")
    assert str(info.value).startswith("moon.tif: its heights are 'Lunar geoid height'")
    assert (
        height_shift(
            compound, grid, (10, 10), world="body", heights=HeightOptions(height_offset=12.5)
        ).offset
        == 12.5
    )
    assert (
        height_shift(compound, grid, (10, 10), world="body", heights=HeightOptions("ignore"))
        is None
    )
    assert height_shift(moon, grid, (10, 10), world="body") is None  # no vertical part
    assert height_shift(compound, grid, (10, 10), world="body", radius_values=True) is None


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"vertical_datum": "geoid"}, "must be one of auto, ignore"),
        ({"height_offset": float("nan")}, "must be finite"),
        ({"height_offset": "28"}, "must be a number of metres"),
        ({"vertical_datum": "ignore", "height_offset": 1.0}, "not both"),
    ],
)
def test_bad_options(options: dict[str, object], message: str) -> None:
    with pytest.raises(InputError, match=message):
        HeightOptions(**options)  # type: ignore[arg-type]


def test_lattice_interpolation_is_exact_for_a_plane() -> None:
    """Bilinear interpolation between lattice nodes reproduces a shift linear in the posts,
    whatever the window, so windows agree with each other."""

    class Plane(datum.HeightShift):
        def exact(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
            return 0.25 * np.asarray(c) - 0.5 * np.asarray(r) + 3.0

    shift = Plane(wkt="a plane", step=8)
    r, c = np.mgrid[3:41, 5:30].astype(np.float64)
    np.testing.assert_allclose(shift.window((3, 41, 5, 30)), shift.exact(c, r), atol=1e-12)
    np.testing.assert_allclose(shift.window((0, 9, 0, 9)), shift.exact(*np.mgrid[0:9, 0:9][::-1]))


@pytest.mark.parametrize(
    ("place", "origin", "post"),
    [
        ("Himalaya", (85.0, 30.0), 3.0),
        ("Andes", (-72.0, -30.0), 1.0),
        ("Indonesia", (120.0, 0.0), 3.0),
    ],
)
def test_chosen_lattice_within_tolerance_where_the_geoid_is_rough(
    place: str, origin: tuple[float, float], post: float
) -> None:
    """Where EGM96 is steepest, the chosen lattice keeps the interpolated undulation within
    TOLERANCE of PROJ's at every post of windows across the DEM (arc-second posts)."""
    needs_egm96()
    crs = CompoundCRS("WGS84 + EGM96 height", [CRS.from_epsg(4326), CRS.from_epsg(EGM96)])
    deg = post / 3600
    grid = Affine(deg, 0, origin[0], 0, -deg, origin[1])
    shift = height_shift(crs, grid, (8000, 8000), world="body", name=place)
    assert shift is not None and shift.step > 1
    for r0, c0 in [(0, 0), (2711, 5123), (7600, 400)]:
        window = (r0, r0 + 300, c0, c0 + 300)
        r, c = np.mgrid[r0 : r0 + 300, c0 : c0 + 300].astype(np.float64)
        assert np.abs(shift.window(window) - shift.exact(c, r)).max() < TOLERANCE, window


@pytest.mark.realdata
def test_the_crs_a_dem_written_from_the_values_carries(tmp_path: Path) -> None:
    """The file's heights keep the DEM's whole CRS (vertical part included); converted or
    offset heights its horizontal CRS (heights above its ellipsoid)."""
    source = scan_dem(shared(*NGI), heights=HeightOptions())
    assert vertical_part(with_world(source, "map").heights_crs()).name == "EGM2008 height"
    offset = scan_dem(shared(*NGI), heights=HeightOptions(height_offset=28.0))
    assert vertical_part(with_world(offset, "map").heights_crs()) is None
    if grid_missing(EGM96) is None:
        egm96 = with_world(scan_dem(retagged(tmp_path, EGM96)), "body")
        assert egm96.shift is not None and vertical_part(egm96.heights_crs()) is None
        assert egm96.heights_crs() == egm96.crs


def test_an_rpc_camera_in_a_compound_crs_converts_its_heights() -> None:
    """An RPC camera whose world CRS is projected + EGM96 height projects points of EGM96
    heights where its RPC puts their ellipsoidal heights (pyproj's own transformation); with
    EGM2008, whose grid PROJ lacks here, it is refused naming the grid."""
    from orthomvp.camera.rpc import RpcCamera
    from orthomvp.camera.rpc_model import Rpc
    from tests.test_rpc import synthetic_rpc

    needs_egm96()
    utm = CRS.from_epsg(32634)
    crs = CompoundCRS("UTM 34N + EGM96 height", [utm, CRS.from_epsg(EGM96)])
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()), crs=crs)
    lon, lat = np.meshgrid(np.linspace(19.98, 20.02, 4), np.linspace(9.98, 10.02, 4))
    x, y = Transformer.from_crs(4326, utm, always_xy=True).transform(lon, lat)
    xyz = np.stack([x, y, np.full(x.shape, 250.0)], axis=-1)
    to_3d = Transformer.from_crs(crs, "EPSG:4979", always_xy=True, only_best=True)
    truth = camera.rpc.project(*to_3d.transform(x, y, xyz[..., 2]))
    np.testing.assert_allclose(camera.project(xyz)[0], truth, atol=1e-6)
    np.testing.assert_allclose(camera.to_world(*to_3d.transform(x, y, xyz[..., 2])), xyz, atol=1e-6)
    if grid_missing(3855) is not None:
        egm2008 = CompoundCRS("UTM 34N + EGM2008 height", [utm, CRS.from_epsg(3855)])
        with pytest.raises(InputError, match=EGM2008_GRID):
            RpcCamera(Rpc.from_mapping(synthetic_rpc()), crs=egm2008)
