"""Grids of a geographic CRS far from the equator: a spacing in metres converts to square
degrees (as gdalwarp and ASP's mapproject take it), so that its posts crowd east-west by the
cosine of the latitude; the grid choice warns, and gives the spacing in degrees that makes
them square, checked against great-circle distances on the sphere."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from orthomvp.engine.grid import scan_dem
from orthomvp.engine.grid_choice import choose_grid
from orthomvp.engine.units import east_west_text
from orthomvp.errors import OrthoMVPWarning

MOON = "+proj=longlat +R=1737400 +no_defs"
R = 1737400.0


def _dem(folder: Path, latitude: float) -> Path:
    """A 64 x 64-post lunar DEM in degrees (0.01 degree posts) whose top edge is at
    ``latitude``, gentle heights."""
    path = folder / f"dem{latitude:g}.tif"
    rows = cols = 64
    r, c = np.mgrid[0:rows, 0:cols]
    values = (100 * np.sin(r / 9.0) * np.cos(c / 7.0)).astype(np.float32)
    profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype="float32", crs=MOON)
    profile["transform"] = Affine(0.01, 0, 10.0, 0, -0.01, latitude)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(values, 1)
    return path


def _grid(dem: Path, res: object):
    source = scan_dem(dem)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        grid = choose_grid(source, [], grid="dem", res=res)
    return grid, [w for w in caught if issubclass(w.category, OrthoMVPWarning)]


def _spacing(grid) -> tuple[float, float]:
    """Great-circle metres between neighbouring posts at the grid's centre, east-west and
    north-south (haversine on the sphere)."""
    T = grid.transform
    lat = math.radians(T.f + T.e * grid.shape[0] / 2)
    dlon, dlat = math.radians(abs(T.a)), math.radians(abs(T.e))
    east = 2 * R * math.asin(abs(math.cos(lat) * math.sin(dlon / 2)))
    return east, R * dlat


def test_metres_far_from_the_equator_warn_and_the_suggested_degrees_are_square(
    tmp_path: Path,
) -> None:
    dem = _dem(tmp_path, 80.64)  # centred at 80.32 N
    grid, caught = _grid(dem, "200m")
    east, north = _spacing(grid)
    assert north == pytest.approx(200.0, rel=1e-9)
    centre = grid.transform.f + grid.transform.e * grid.shape[0] / 2
    assert 80.3 < centre < 80.34
    assert east == pytest.approx(200.0 * math.cos(math.radians(centre)), rel=1e-6)
    (warning,) = caught
    text = str(warning.message)
    assert f"{east:.3g} m apart east-west" in text and "200 m north-south" in text
    assert "--crs with a polar stereographic CRS of the body (+proj=stere +lat_0=90)" in text
    x, y = (float(v) for v in re.search(r"--res (\S+)deg (\S+)deg", text).groups())
    square, quiet = _grid(dem, (f"{x}deg", f"{y}deg"))
    east, north = _spacing(square)
    assert east == pytest.approx(north, rel=2e-3) and north == pytest.approx(200.0, rel=2e-3)
    assert quiet == []  # (degrees given: square on the ground, no warning)


@pytest.mark.parametrize(("latitude", "res"), [(20.64, "200m"), (80.64, "0.002")])
def test_no_warning_near_the_equator_or_for_degrees_given(
    tmp_path: Path, latitude: float, res: str
) -> None:
    """At 20 N the posts lie 0.94 of their spacing apart east-west; a bare number on a degree
    CRS is the user's own choice of degrees."""
    _, caught = _grid(_dem(tmp_path, latitude), res)
    assert caught == []


def test_the_warning_holds_exactly_at_its_share() -> None:
    """Half the north-south spacing east-west, or less, warns: latitude 60 is the edge."""
    from pyproj import CRS

    crs = CRS.from_user_input(MOON)
    assert east_west_text((0.01, 0.01), 59.9, crs, R) is None
    assert east_west_text((0.01, 0.01), -60.1, crs, R) is not None
    assert east_west_text((0.02, 0.01), 70.0, crs, R) is None  # (already wider in longitude)
    assert east_west_text((0.01, 0.01), 80.0, CRS.from_epsg(32633), R) is None  # (projected)


def test_info_gives_the_ground_spacing_of_degrees_at_the_dem_centre(tmp_path: Path) -> None:
    """Found by a new user's audit: `info` gave a degree of longitude the metres of one of
    latitude (Hadley, 25.5 N: "118 x 118 m" where posts lie 107 m apart east-west). Against
    pyproj's geodesic on the sphere, at the DEM's centre and median height."""
    from pyproj import Geod

    from orthomvp.engine.info import describe

    dem = _dem(tmp_path, 80.64)
    d = describe(dem)["properties"]["dem"]
    east, north = d["post_spacing_m"]
    with rasterio.open(dem) as ds:
        heights = ds.read(1)
    radius = R + float(np.median(heights))
    geod = Geod(a=radius, b=radius)
    lat = 80.64 - 0.01 * (31.5 + 0.5)  # the grid centre: row 31.5, pixel centres
    _, _, along = geod.inv(10.0, lat, 10.01, lat)
    _, _, down = geod.inv(10.0, lat, 10.0, lat - 0.01)
    assert east == pytest.approx(along, rel=1e-4) and north == pytest.approx(down, rel=1e-6)
    assert east < 0.17 * north
