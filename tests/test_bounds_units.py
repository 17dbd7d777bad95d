"""Units of a CRS as the user reads them: ``--bounds`` (the API's ``bounds``) in the wrong units
on a geographic output CRS (a latitude beyond a pole is refused in one line that says bounds
are in the CRS's units, before planning), and the names of units in ``orthomvp info``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from pyproj import CRS

from orthomvp.engine.units import check_latitudes, unit_scale
from orthomvp.errors import InputError
from tests.conftest import shared


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
