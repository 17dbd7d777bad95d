"""A camera that knows its body (a cube's or an ISD's ellipsoid) on a DEM whose CRS is of
another body (orthomvp.geometry.world.check_camera_bodies): one line naming both radii and
--dem-crs; with the right --dem-crs the run is the one on the DEM with its own CRS."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.engine import plan_ortho
from orthomvp.errors import GeometryError
from tests.conftest import shared
from tests.test_cli import run as cli_run


def earth_copy(src: Path, dst: Path) -> Path:
    """``src`` with its CRS replaced by WGS 84 (as a tool that lost the body would write it)."""
    with rasterio.open(src) as ds:
        profile, values = ds.profile, ds.read()
    with rasterio.open(dst, "w", **(profile | {"crs": "EPSG:4326"})) as ds:
        ds.write(values)
    return dst


@pytest.mark.realdata
def test_a_lunar_cube_on_a_dem_that_says_earth(tmp_path: Path) -> None:
    hadley = shared("as15-hadley")
    cube = hadley / "AS15-M-1134-hadley.cub"
    lola = hadley / "LOLA_hadley_dem.tif"
    earth = earth_copy(lola, tmp_path / "lola-earth.tif")
    out = tmp_path / "o.tif"
    result = cli_run("ortho", str(earth), str(cube), "-o", str(out), "--res", "200m")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"orthomvp: error: {earth}: camera 1 is of")
    assert "1,737.4 km" in lines[0] and "6,378.1 km" in lines[0] and "--dem-crs" in lines[0]
    assert not out.exists()
    with pytest.raises(GeometryError, match="of a body of equatorial radius 1,737.4 km"):
        plan_ortho(earth, [(cube, cube)], progress=False)
    # the remedy: the Moon's CRS given; the same orthophoto as on the DEM with its own CRS
    moon = "IAU_2015:30100"
    args = ("--res", "200m", "--dem-crs", moon)
    assert cli_run("ortho", str(earth), str(cube), "-o", str(out), *args).returncode == 0
    own = tmp_path / "own.tif"
    assert cli_run("ortho", str(lola), str(cube), "-o", str(own), *args).returncode == 0
    with rasterio.open(out) as a, rasterio.open(own) as b:
        np.testing.assert_array_equal(a.read(), b.read())
        assert np.isfinite(a.read(1)).sum() > 1000


@pytest.mark.parametrize(
    ("dem_radii", "camera_radii", "same"),
    [
        ((262_000.0, 262_000.0), (289_000.0, 229_000.0), True),  # Vesta: a sphere, an ellipsoid
        ((1_737_400.0, 1_737_400.0), (1_737_400.0, 1_737_400.0), True),
        ((3_396_190.0, 3_376_200.0), (3_396_190.0, 3_396_190.0), True),
        ((6_378_137.0, 6_356_752.3), (1_737_400.0, 1_737_400.0), False),  # the Moon on WGS 84
        ((6_378_137.0, 6_356_752.3), (3_396_190.0, 3_376_200.0), False),  # Mars on WGS 84
        ((1_737_400.0, 1_737_400.0), (3_396_190.0, 3_376_200.0), False),  # Mars on the Moon
    ],
)
def test_one_body_or_two(
    dem_radii: tuple[float, float], camera_radii: tuple[float, float], same: bool
) -> None:
    """Bodies are told apart by their spans of radii (each widened by a tenth), so that a
    small body given as a sphere and as an ellipsoid is one body."""
    from types import SimpleNamespace

    from orthomvp.camera.csm.geometry import Ellipsoid
    from orthomvp.geometry.world import check_camera_bodies

    dem = SimpleNamespace(radii=dem_radii, name="dem.tif", geodetic_crs=SimpleNamespace(name="X"))
    camera = SimpleNamespace(ellipsoid=Ellipsoid(*camera_radii))
    if same:
        check_camera_bodies(dem, [object(), camera])
    else:
        with pytest.raises(GeometryError, match="dem.tif: camera 2 is of a body"):
            check_camera_bodies(dem, [object(), camera])
