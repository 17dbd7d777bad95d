"""Units of a CRS as the user reads them: ``--bounds`` (the API's ``bounds``) in the wrong units
on a geographic output CRS (a latitude beyond a pole is refused in one line that says bounds
are in the CRS's units, before planning), and the names of units in ``orthomvp info``."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS
from rasterio.errors import NotGeoreferencedWarning

from orthomvp.engine.units import check_latitudes, unit_scale
from orthomvp.errors import InputError
from tests.conftest import shared
from tests.test_cli import run as cli_run


def test_latitudes_beyond_a_pole_are_refused_on_a_geographic_crs_only() -> None:
    wgs84 = CRS.from_epsg(4326)
    check_latitudes((2.9, -90.0, 3.1, 90.0), wgs84)  # the poles themselves are on the globe
    for bounds, latitude in (((2.9, 89.5, 3.1, 95.0), "95"), ((0, -90.5, 1, 0), "-90.5")):
        with pytest.raises(InputError, match=rf"latitude {latitude} lies outside \+-90 degrees"):
            check_latitudes(bounds, wgs84)
    # metres on a projected CRS are not latitudes, however large
    check_latitudes((79598.0, 782996.0, 80598.0, 783996.0), CRS.from_epsg(32633))
    # a CRS counting grads (NTF Paris): its pole is at 100 of them
    grads = CRS.from_epsg(4807)
    check_latitudes((0, 99.0, 1, 100.0), grads)
    with pytest.raises(InputError, match=r"latitude 101 lies outside \+-100 grads"):
        check_latitudes((0, 99.0, 1, 101.0), grads)


@pytest.mark.realdata
def test_metres_as_bounds_on_a_lunar_degree_crs(tmp_path: Path) -> None:
    import orthomvp as om

    dem = shared("as15-hadley", "LOLA_hadley_dem.tif")
    cube = shared("as15-hadley", "AS15-M-1134-hadley.cub")
    out = tmp_path / "b.tif"
    for bounds, latitude in ((["79598", "782996", "80598", "783996"], "782996"),
                             (["2.9", "89.5", "3.1", "95"], "95")):  # fmt: skip
        proc = subprocess.run(
            [sys.executable, "-m", "orthomvp", "ortho", dem, cube, "-o", out, "--bounds", *bounds],
            capture_output=True,
            text=True,
        )
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("orthomvp: error: "), proc.stderr
        assert f"latitude {latitude} lies outside +-90 degrees" in lines[0], lines[0]
        assert "in the output CRS's units, degrees here" in lines[0], lines[0]
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match=r"latitude 95 lies outside \+-90 degrees"):
        om.plan_ortho(dem, [(cube, cube)], bounds=(2.9, 89.5, 3.1, 95.0), progress=False)


@pytest.mark.parametrize(
    ("epsg", "name"),
    [
        (2277, "US survey feet"),
        (2222, "feet"),
        (2314, "Clarke's feet"),
        (3167, "British chains (Sears 1922 truncated)"),
        (2066, "Clarke's links"),
        (4807, "grads"),
        (4326, "degrees"),
        (32633, "m"),
    ],
)
def test_unit_names_are_plural_english(epsg: int, name: str) -> None:
    """pyproj's unit names made plural ("US survey foot" was "US survey foots"), with the
    metres per unit pyproj gives."""
    crs = CRS.from_epsg(epsg)
    per_unit, unit = unit_scale(crs, 6378137.0)
    assert unit == name
    factor = crs.axis_info[0].unit_conversion_factor
    assert per_unit == (6378137.0 * factor if crs.is_geographic else factor)


def test_info_names_feet(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import numpy as np
    from affine import Affine

    from orthomvp.cli import main
    from orthomvp.geometry.terrain import Terrain

    dem = tmp_path / "ftus.tif"
    spacing = 24 / 0.3048006096012192  # 24 m in US survey feet (EPSG:9003: 1200/3937 m)
    Terrain(np.zeros((8, 8)), Affine(spacing, 0, 2e6, 0, -spacing, 1e7), "EPSG:2277").write(dem)
    assert main(["info", str(dem)]) == 0
    out = capsys.readouterr().out
    assert "(projected, US survey feet)" in out, out
    assert "78.74 x 78.74 US survey feet (24 x 24 m)" in out, out
    assert "foots" not in out


@pytest.mark.realdata
def test_info_names_the_vertical_datum_once(capsys: pytest.CaptureFixture) -> None:
    from orthomvp.cli import main

    dem = str(shared("ngi-aerial", "dem.tif"))
    rpc = str(shared("rpc-quickbird", "qb2_basic1b.tif"))
    assert main(["info", dem]) == 0
    assert "height above EGM2008 (the vertical datum)" in capsys.readouterr().out
    assert main(["info", dem, rpc, "--height-offset", "28"]) == 0
    out = capsys.readouterr().out
    assert "(from EGM2008 heights, shifted for the cameras)" in out, out


def test_a_camera_grid_grown_past_the_pole_is_not_refused(tmp_path: Path) -> None:
    """A geographic DEM reaching the south pole and a nadir camera near it: the default camera
    grid, grown outward to its lattice, may pass -90 degrees; only bounds the user gives are
    checked against the poles, so the run writes its orthophoto (as it did before the check)."""
    dem, image, camera = tmp_path / "dem.tif", tmp_path / "img.tif", tmp_path / "cam.tsai"
    profile = dict(driver="GTiff", width=500, height=250, count=1, dtype="float32")
    moon = "+proj=longlat +R=1737400 +no_defs"
    transform = Affine(0.02, 0.0, 0.0, 0.0, -0.02, -85.0)
    with rasterio.open(dem, "w", **profile, crs=moon, transform=transform) as ds:
        ds.write(np.zeros((1, 250, 500), np.float32))
    ramp = (np.add.outer(np.arange(200), np.arange(200)) % 250).astype(np.uint8)[None]
    with warnings.catch_warnings():  # (an image has no georeference)
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(image, "w", driver="GTiff", width=200, height=200, count=1,
                           dtype="uint8") as ds:  # fmt: skip
            ds.write(ramp)
    camera.write_text(
        "VERSION_4\nPINHOLE\nfu = 250.0\nfv = 250.0\ncu = 100\ncv = 100\n"
        "u_direction = 1.0 0.0 0.0\nv_direction = 0.0 1.0 0.0\nw_direction = 0.0 0.0 1.0\n"
        "C = 15538.455175349083 1359.4386765487684 -1787331.9412848998\n"
        "R = -0.08715574274765817 -0.9961567660501535 -0.008693328396189484 "
        "0.9961946980917455 -0.08715242412403446 -0.0007605676829745822 "
        "0.0 -0.008726535498373898 0.9999619230641713\npitch = 1.0\nNULL\n"
    )
    out = tmp_path / "o.tif"
    result = cli_run("ortho", str(dem), str(image), str(camera), "-o", str(out))
    assert result.returncode == 0, result.stderr
    with rasterio.open(out) as o:
        assert o.bounds.bottom < -90.0 and np.isfinite(o.read(1)).sum() > 100_000
