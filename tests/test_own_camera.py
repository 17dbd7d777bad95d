"""``ortho`` and ``visibility`` without CAMERA: an image that is its own camera (a spiceinit'd
cube, a GeoTIFF with RPCs) gives the same output as with the image named as its camera; an
image that is not says so in one line with exit status 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio

from tests.conftest import shared


def run(*args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "orthomvp", "-q", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


def _same(a: Path, b: Path) -> None:
    with rasterio.open(a) as x, rasterio.open(b) as y:
        assert x.transform == y.transform and x.shape == y.shape
        np.testing.assert_array_equal(x.read(), y.read())


HADLEY = (("as15-hadley", "LOLA_hadley_dem.tif"), ("as15-hadley", "AS15-M-1134-hadley.cub"))
QUICKBIRD = (("ngi-aerial", "dem.tif"), ("rpc-quickbird", "qb2_basic1b.tif"))


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "data", "options"),
    [
        ("ortho", HADLEY, ["--res", "100m"]),
        ("visibility", HADLEY, ["--res", "100m"]),
        ("ortho", QUICKBIRD, ["--res", "48m", "--height-offset", "28"]),
    ],
)
def test_an_image_that_is_its_own_camera(
    command: str, data: tuple, options: list, tmp_path: Path
) -> None:
    dem_path, image_path = shared(*data[0]), shared(*data[1])
    alone, named = tmp_path / "alone.tif", tmp_path / "named.tif"
    proc = run(command, dem_path, image_path, "-o", alone, *options)
    assert proc.returncode == 0 and proc.stdout == proc.stderr == "", proc.stderr
    proc = run(command, dem_path, image_path, image_path, "-o", named, *options)
    assert proc.returncode == 0, proc.stderr
    _same(alone, named)


@pytest.mark.realdata
def test_an_image_without_a_camera_of_its_own(tmp_path: Path) -> None:
    out = tmp_path / "o.tif"
    proc = run(
        "ortho",
        shared("as15-hadley", "LOLA_hadley_dem.tif"),
        shared("as15-hadley", "AS15-M-1134-hadley.tif"),
        "-o",
        out,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "no CAMERA given" in proc.stderr
    assert not out.exists() and not list(tmp_path.iterdir())


def test_a_missing_image_without_a_camera_is_named_as_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A mistyped IMAGE with CAMERA left out is reported as the missing raster it is (as a
    missing IMAGE with its CAMERA is), not as an image without a camera of its own."""
    from affine import Affine

    from orthomvp.cli import main
    from orthomvp.geometry.terrain import Terrain

    dem, out = tmp_path / "dem.tif", tmp_path / "o.tif"
    Terrain(np.zeros((4, 4)), Affine(10, 0, 5e5, 0, -10, 0), "EPSG:32633").write(dem)
    for command in ("ortho", "visibility"):
        assert main([command, str(dem), str(tmp_path / "typo.tif"), "-o", str(out)]) == 2
        err = capsys.readouterr().err.splitlines()
        assert err == [f"orthomvp: error: {tmp_path / 'typo.tif'}: raster not found (no such file)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.tif"]
