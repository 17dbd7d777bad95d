"""Terrain: georeference conventions and exact to_world/from_world inverses."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS

from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from tests.conftest import shared

MOON = "+proj=longlat +R=1737400 +no_defs"
MARS_ELLIPSOID = "+proj=longlat +a=3396190 +b=3376200 +no_defs"


def geographic(lon0: float, lat0: float, step: float, n: int, crs: str = MOON) -> Terrain:
    """An n x n geographic grid whose upper-left corner is at (lon0, lat0) degrees."""
    rng = np.random.default_rng(1)
    values = rng.uniform(-3000, 3000, (n, n))
    return Terrain(values, Affine(step, 0, lon0, 0, -step, lat0), CRS.from_proj4(crs))


def random_round_trip(t: Terrain, seed: int = 0) -> None:
    rows, cols = t.shape
    rng = np.random.default_rng(seed)
    c = rng.uniform(-0.5, cols - 0.5, 2000)
    r = rng.uniform(-0.5, rows - 0.5, 2000)
    v = rng.uniform(-5000, 5000, 2000)
    if t.radius_values:
        v += 1737400
    xyz = t.to_world(c, r, v)
    c2, r2, v2 = t.from_world(xyz)
    np.testing.assert_allclose(c2, c, atol=1e-7)
    np.testing.assert_allclose(r2, r, atol=1e-7)
    np.testing.assert_allclose(v2, v, atol=1e-6)


@pytest.mark.parametrize(
    "lon0, lat0",
    [(10, 20), (-120, -30), (179.0, 5), (-180.5, -40), (350, 60), (0, 89.9), (20, -88.5)],
    ids=["north", "south", "across-180", "west-of-180", "lon-350", "north-pole", "south-pole"],
)
def test_sphere_round_trip(lon0: float, lat0: float) -> None:
    random_round_trip(geographic(lon0, lat0, 0.01, 150))


def test_ellipsoid_round_trip_and_closed_form() -> None:
    t = geographic(40, 50, 0.05, 40, MARS_ELLIPSOID)
    assert not t.is_sphere
    random_round_trip(t)
    # independent geodetic -> body-fixed closed form
    a, b = 3396190.0, 3376200.0
    c, r = np.array([3.0, 17.5]), np.array([9.0, 30.25])
    h = np.array([1200.0, -4000.0])
    lon = np.radians(40 + 0.05 * (c + 0.5))
    lat = np.radians(50 - 0.05 * (r + 0.5))
    e2 = 1 - b**2 / a**2
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    expected = np.stack(
        [
            (n + h) * np.cos(lat) * np.cos(lon),
            (n + h) * np.cos(lat) * np.sin(lon),
            (n * (1 - e2) + h) * np.sin(lat),
        ],
        axis=-1,
    )
    np.testing.assert_allclose(t.to_world(c, r, h), expected, atol=1e-6)


def test_pixel_centres_and_eq_1_to_4() -> None:
    """Integer pixels are centres: pixel (0, 0) lies half a post inside the GeoTIFF corner."""
    t = geographic(55.0, 10.0, 0.002, 20)
    xyz = t.to_world(np.array(0.0), np.array(0.0), np.array(100.0))
    lon, lat = np.radians(55.001), np.radians(9.999)
    expected = 1737500.0 * np.array(
        [np.cos(lon) * np.cos(lat), np.sin(lon) * np.cos(lat), np.sin(lat)]
    )
    np.testing.assert_allclose(xyz, expected, atol=1e-6)
    # eq. (2): S maps pixel centres to (lon, lat) in degrees
    np.testing.assert_allclose(
        t.S, [[0.002, 0, 55.001], [0, -0.002, 9.999], [0, 0, 1]], rtol=0, atol=1e-12
    )


def test_radius_values() -> None:
    t = geographic(10, 20, 0.01, 30)
    t = t.with_values(t.values + 1737400)
    t = Terrain(t.values, t.transform, t.crs, radius_values=True)
    random_round_trip(t)
    xyz = t.to_world(np.array(3.0), np.array(4.0), np.array(1737900.0))
    assert np.linalg.norm(xyz) == pytest.approx(1737900.0, abs=1e-6)


@pytest.mark.parametrize(
    "proj",
    [
        "+proj=eqc +lat_ts=0 +lon_0=0 +R=1737400 +units=m +no_defs",
        "+proj=stere +lat_0=-90 +lon_0=0 +k=1 +R=1737400 +units=m +no_defs",
        "+proj=stere +lat_0=90 +lon_0=0 +k=1 +R=3396190 +units=m +no_defs",
    ],
    ids=["eqc", "south-polar-stereographic", "mars-north-polar-stereographic"],
)
def test_projected_round_trip(proj: str) -> None:
    values = np.zeros((100, 100))
    t = Terrain(values, Affine(100.0, 0, -5000, 0, -100.0, 5000), CRS.from_proj4(proj))
    random_round_trip(t)
    if "stere" in proj:
        # the projection origin (x = y = 0, the corner between the four central posts) is the pole
        xyz = t.to_world(np.array(49.5), np.array(49.5), np.array(250.0))
        radius = t.radii[0] + 250.0
        sign = -1 if "lat_0=-90" in proj else 1
        np.testing.assert_allclose(xyz, [0, 0, sign * radius], atol=1e-6)


def test_map_world_frame() -> None:
    crs = CRS.from_epsg(32633)
    t = Terrain(np.ones((10, 10)), Affine(24, 0, 500000, 0, -24, 4000000), crs, world="map")
    xyz = t.to_world(np.array(0.0), np.array(0.0), np.array(150.0))
    np.testing.assert_allclose(xyz, [500012, 3999988, 150])
    random_round_trip(t)
    with pytest.raises(InputError, match="projected"):
        Terrain(np.ones((5, 5)), Affine(1, 0, 0, 0, -1, 0), CRS.from_proj4(MOON), world="map")


def test_normals_of_a_sphere_are_radial() -> None:
    t = geographic(30, 40, 0.01, 20).with_values(np.full((20, 20), 500.0))
    n = t.normals()
    up = t.world_points()
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    np.testing.assert_allclose(n[1:-1, 1:-1], up[1:-1, 1:-1], atol=1e-9)
    # one-sided differences at the border see the curvature of one post step (0.01 deg)
    np.testing.assert_allclose(n, up, atol=2e-4)


def test_interpolate_and_regrid() -> None:
    t = geographic(10.0, 0.5, np.degrees(50.0 / 1737400.0), 40)  # 50 m posts
    c, r = t.grid()
    linear = t.with_values(3.0 * c - 2.0 * r + 7.0)
    rng = np.random.default_rng(2)
    cc, rr = rng.uniform(0, 39, 300), rng.uniform(0, 39, 300)
    np.testing.assert_allclose(linear.interpolate(cc, rr), 3.0 * cc - 2.0 * rr + 7.0)
    assert np.isnan(linear.interpolate(np.array([-0.1, 39.2]), np.array([3.0, 3.0]))).all()
    # on a curved surface, integer positions give the posts back
    curved = t.with_values(np.sin(c / 3.0) * np.cos(r / 5.0) * 100)
    np.testing.assert_allclose(curved.interpolate(c, r), curved.values)
    # regridding at half the pixel size: new posts sit between the old ones
    half = linear.regrid(res=(abs(t.transform.a) / 2, abs(t.transform.e) / 2))
    assert half.shape == (80, 80)
    oc, orow = t.crs_to_pixel(*half.pixel_to_crs(*half.grid()))
    np.testing.assert_allclose(oc[0, :3], [-0.25, 0.25, 0.75])
    inside = np.isfinite(half.values)
    np.testing.assert_allclose(half.values[inside], (3.0 * oc - 2.0 * orow + 7.0)[inside])
    assert inside.sum() == 78 * 78
    with pytest.raises(InputError, match="overlap"):
        t.regrid(bounds=(50.0, 10.0, 51.0, 11.0))


def test_interpolate_grid_is_interpolate_bit_for_bit() -> None:
    """On every pair of column and row positions (inside, on the last post, beyond the grid,
    next to a hole), as :meth:`interpolate` on the full meshgrid; and regridding, which now
    uses it, equals interpolating at every new post's own position."""
    t = geographic(10.0, 0.5, np.degrees(50.0 / 1737400.0), 40)
    rng = np.random.default_rng(4)
    values = rng.normal(0, 100, t.shape)
    values[7, 11] = np.nan
    dem = t.with_values(values)
    cc = np.concatenate([rng.uniform(-1, 40, 57), [0.0, 39.0, 10.5, 11.0, -1e-9]])
    rr = np.concatenate([rng.uniform(-1, 40, 43), [0.0, 39.0, 6.5, 7.0]])
    got = dem.interpolate_grid(cc, rr)
    want = dem.interpolate(*np.meshgrid(cc, rr))
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got).any() and np.isfinite(got).any()
    fine = dem.regrid(res=(abs(t.transform.a) / 3, abs(t.transform.e) / 3))
    at = dem.interpolate(*dem.crs_to_pixel(*fine.pixel_to_crs(*fine.grid())))
    np.testing.assert_array_equal(fine.values, at)


def test_geotiff_round_trip_with_nodata(tmp_path) -> None:
    t = geographic(10, 20, 0.01, 16)
    values = t.values.copy()
    values[3, 4] = np.nan
    t.with_values(values).write(tmp_path / "dem.tif")
    back = Terrain.read(tmp_path / "dem.tif")
    assert np.isnan(back.values[3, 4]) and back.valid.sum() == 16 * 16 - 1
    np.testing.assert_allclose(back.values[back.valid], values[back.valid].astype(np.float32))
    assert back.transform == t.transform
    np.testing.assert_allclose(back.to_world(1.0, 2.0, 0.0), t.to_world(1.0, 2.0, 0.0))
    # a file with an explicit nodata value
    profile = dict(driver="GTiff", width=4, height=4, count=1, dtype="int16", nodata=-32768)
    profile.update(crs=MOON, transform=Affine(0.1, 0, 0, 0, -0.1, 0))
    with rasterio.open(tmp_path / "nd.tif", "w", **profile) as dst:
        data = np.arange(16, dtype=np.int16).reshape(4, 4)
        data[0, 0] = -32768
        dst.write(data, 1)
    nd = Terrain.read(tmp_path / "nd.tif")
    assert np.isnan(nd.values[0, 0]) and nd.values[3, 3] == 15


def test_bad_dems(tmp_path) -> None:
    with pytest.raises(InputError, match="no such file"):
        Terrain.read(tmp_path / "missing.tif")
    (tmp_path / "corrupt.tif").write_bytes(b"II*\x00garbage" * 10)
    with pytest.raises(InputError, match="corrupt.tif"):
        Terrain.read(tmp_path / "corrupt.tif")
    profile = dict(driver="GTiff", width=4, height=4, count=1, dtype="float32")
    with rasterio.open(tmp_path / "nocrs.tif", "w", **profile) as dst:
        dst.write(np.zeros((4, 4), np.float32), 1)
    with pytest.raises(InputError, match="no CRS"):
        Terrain.read(tmp_path / "nocrs.tif")
    profile.update(transform=Affine(0.1, 0, 0, 0, -0.1, 0))
    with rasterio.open(tmp_path / "nocrs2.tif", "w", **profile) as dst:
        dst.write(np.zeros((4, 4), np.float32), 1)
    t = Terrain.read(tmp_path / "nocrs2.tif", crs=MOON)
    assert t.radii == (1737400.0, 1737400.0)
    with pytest.raises(InputError, match="CRS"):
        Terrain.read(tmp_path / "nocrs2.tif", crs="not a crs")
    profile.update(crs=MOON)
    with rasterio.open(tmp_path / "allnan.tif", "w", **profile) as dst:
        dst.write(np.full((4, 4), np.nan, np.float32), 1)
    with pytest.raises(InputError, match="no valid heights"):
        Terrain.read(tmp_path / "allnan.tif")


@pytest.mark.realdata
def test_apollo15_dem() -> None:
    t = Terrain.read(shared("apollo15-mvp", "ground-dem.tif"))
    assert t.shape == (64, 64) and t.is_sphere and t.radii[0] == 1737400.0
    lon, lat = t.pixel_to_lonlat(np.array([-0.5, 63.5]), np.array([63.5, -0.5]))
    np.testing.assert_allclose(np.degrees(lon), [55.723, 55.810], atol=2e-3)
    np.testing.assert_allclose(np.degrees(lat), [9.668, 9.756], atol=2e-3)
    assert np.mean(t.post_spacing()) == pytest.approx(41.6, abs=0.5)
    random_round_trip(t)


NGI_WKT = (
    'PROJCS["Lo25 WGS84 + EGM2008 height",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",'
    '6378137,298.257223563]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
    'PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],'
    'PARAMETER["central_meridian",25],PARAMETER["scale_factor",1],PARAMETER["false_easting",0],'
    'PARAMETER["false_northing",0],UNIT["metre",1]]'
)
FILE_CRSS = [
    "EPSG:32633",
    "EPSG:4326",
    NGI_WKT,
    "+proj=eqc +R=1737400 +units=m +no_defs",
    "+proj=longlat +a=3396190 +b=3376200 +no_defs",
    "+proj=stere +lat_0=-90 +a=3396190 +rf=169.8944472236118 +units=m +no_defs",
]


@pytest.mark.parametrize("text", FILE_CRSS)
def test_a_file_crs_is_what_pyproj_reads_of_it(text: str) -> None:
    """A DEM's CRS as rasterio reads it from the file is kept (no pyproj), and behaves as the
    pyproj CRS read from its WKT did: the same radii bit for bit (from the WKT's spheroid), the
    same world points in the body frame, equal CRSs."""
    from rasterio.crs import CRS as FileCRS

    file_crs = FileCRS.from_user_input(text)
    mine = Terrain(np.full((6, 7), 120.0), Affine(0.01, 0, 3, 0, -0.01, 40), file_crs)
    if file_crs.is_projected:
        mine = Terrain(mine.values, Affine(500.0, 0, 1e5, 0, -500.0, -2e5), file_crs)
    assert mine.crs is file_crs
    theirs = Terrain(mine.values, mine.transform, CRS.from_user_input(file_crs.to_wkt()))
    assert mine.radii == theirs.radii and theirs.crs == mine.crs  # (pyproj's equality)
    c, r = mine.grid()
    np.testing.assert_array_equal(
        mine.to_world(c, r, mine.values), theirs.to_world(c, r, theirs.values)
    )


def test_a_compound_file_crs_keeps_its_horizontal_part() -> None:
    """A file's compound CRS (projected + vertical) becomes its horizontal part, as before."""
    from rasterio.crs import CRS as FileCRS

    compound = FileCRS.from_user_input("EPSG:5972")  # ETRS89 / UTM 32N + NN2000 height
    t = Terrain(np.zeros((3, 3)), Affine(10.0, 0, 5e5, 0, -10.0, 6e6), compound)
    horizontal = CRS.from_user_input(compound.to_wkt()).sub_crs_list[0]
    assert t.crs.is_projected and not t.crs.is_compound and t.crs == horizontal


def test_a_map_frame_run_never_imports_pyproj(city_dir) -> None:  # noqa: ANN001
    """pyproj's import takes about 45 ms; a map-frame orthophoto of files needs none of it
    (GDAL reads the CRSs), while a body-frame terrain imports it where it transforms."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from orthomvp.cli import main\n"
        f"code = main(['-q', 'mosaic', {str(city_dir / 'dem.tif')!r}, "
        f"{str(city_dir / 'ne.tif')!r}, {str(city_dir / 'ne.tsai')!r}, "
        f"{str(city_dir / 'sw.tif')!r}, {str(city_dir / 'sw.tsai')!r}, "
        f"'-o', sys.argv[1]])\n"
        "print(code, 'pyproj' in sys.modules)\n"
    )
    out = city_dir.parent / "no-pyproj.tif"
    proc = subprocess.run(
        [sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1].split() == ["0", "False"] and out.exists()
