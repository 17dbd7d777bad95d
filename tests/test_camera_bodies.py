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
