"""Cameras whose file states their world CRS (orthomvp.engine.stated_crs): an Orthority
exterior file's ``.prj`` or ``world_crs`` against the DEM's CRS. A DEM in another CRS is
refused in one line naming both and how to reproject the DEM; that remedy works; a DEM in
the cameras' CRS runs as before."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.warp import Resampling, reproject, transform_bounds

from orthomvp.camera.formats.orthority import stated_crs
from orthomvp.cli import main
from tests.conftest import shared

FRAME = "3324c_2015_1004_05_0182_RGB.tif"


def test_what_a_camera_file_states(tmp_path: Path) -> None:
    """A CSV file's ``.prj`` (same stem), a GeoJSON FeatureCollection's ``world_crs``; nothing
    for a CSV without ``.prj``, a GeoJSON without ``world_crs``, other JSON, other files."""
    csv = tmp_path / "cams.csv"
    csv.write_text("filename,x,y,z,omega,phi,kappa\n")
    assert stated_crs(csv) is None
    csv.with_suffix(".prj").write_text("EPSG:32735\n")
    assert stated_crs(csv) == "EPSG:32735"
    collection = {"type": "FeatureCollection", "features": []}
    geojson = tmp_path / "cams.geojson"
    geojson.write_text(json.dumps(collection))
    assert stated_crs(geojson) is None
    geojson.write_text(json.dumps(collection | {"world_crs": "EPSG:2154"}))
    assert stated_crs(geojson) == "EPSG:2154"
    other = tmp_path / "camera.json"
    other.write_text(json.dumps({"world_crs": "EPSG:2154"}))  # not a FeatureCollection
    assert stated_crs(other) is None
    tsai = tmp_path / "cam.tsai"
    tsai.write_text("VERSION_4\n")
    tsai.with_suffix(".prj").write_text("EPSG:32735\n")
    assert stated_crs(tsai) is None


def warped(src: Path, dst: Path, crs: object) -> Path:
    """``src`` reprojected into ``crs`` (bilinear; its nodata kept), written to ``dst``."""
    with rasterio.open(src) as ds:
        left, bottom, right, top = transform_bounds(ds.crs, crs, *ds.bounds)
        step = abs(ds.transform.a)  # (metres on both sides)
        width, height = math.ceil((right - left) / step), math.ceil((top - bottom) / step)
        transform = Affine(step, 0.0, left, 0.0, -step, top)
        profile = ds.profile | {"crs": crs, "transform": transform}
        profile |= {"width": width, "height": height, "driver": "GTiff"}
        out = np.full((height, width), np.nan, np.float32)
        reproject(
            ds.read(1).astype(np.float32), out, src_transform=ds.transform, src_crs=ds.crs,
            src_nodata=ds.nodata, dst_transform=transform, dst_crs=crs, dst_nodata=np.nan,
            resampling=Resampling.bilinear,
        )  # fmt: skip
    profile |= {"dtype": "float32", "nodata": np.nan, "count": 1}
    with rasterio.open(dst, "w", **profile) as ds:
        ds.write(out, 1)
    return dst


@pytest.mark.realdata
@pytest.mark.parametrize("exterior", ["ngi_xyz_opk.csv", "ngi_ext_param.geojson"])
def test_a_dem_in_another_crs_is_refused_naming_both(
    exterior: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The ngi-aerial DEM in UTM 35S under cameras in the South African Lo25 (a transverse
    Mercator about 25 E): exit 2, one line naming both CRSs and gdalwarp; the same DEM
    reprojected into the cameras' CRS (what the line says to do) runs."""
    ngi = shared("ngi-aerial")
    cameras = ngi / "orthority-format" / exterior
    utm = warped(ngi / "dem.tif", tmp_path / "dem-utm.tif", "EPSG:32735")
    out = tmp_path / "o.tif"
    args = ["ortho", str(utm), str(ngi / FRAME), str(cameras), "-o", str(out), "--res", "48m"]
    assert main(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"orthomvp: error: {cameras}: its cameras are in ")
    assert "'WGS 84 / UTM zone 35S'" in err[0] and "gdalwarp -t_srs " in err[0]
    assert "lon_0=25" in err[0] or "ngi_xyz_opk.prj" in err[0]
    assert not out.exists()
    theirs = stated_crs(cameras)
    back = warped(utm, tmp_path / "dem-back.tif", rasterio.crs.CRS.from_user_input(theirs))
    args[1] = str(back)
    assert main(args) == 0, capsys.readouterr().err
    with rasterio.open(out) as o:
        assert o.crs == rasterio.crs.CRS.from_user_input(theirs)
        assert o.read(1, masked=True).count() > 0.9 * o.width * o.height


@pytest.mark.realdata
def test_a_prj_that_agrees_with_the_dem_changes_nothing(tmp_path: Path) -> None:
    """The shipped DEM (Lo25 with EGM2008 heights) and the cameras' ``.prj`` (the same
    projection as a PROJ string) agree: the orthophoto is the one without the ``.prj``."""
    ngi = shared("ngi-aerial")
    folder = tmp_path / "cams"
    folder.mkdir()
    for name in ("ngi_xyz_opk.csv", "ngi_int_param.yaml"):
        shutil.copy(ngi / "orthority-format" / name, folder)
    common = ["--res", "48m", "--height-offset", "28"]
    without = [str(ngi / "dem.tif"), str(ngi / FRAME), str(folder / "ngi_xyz_opk.csv")]
    assert main(["ortho", *without, "-o", str(tmp_path / "a.tif"), *common]) == 0
    shutil.copy(ngi / "orthority-format" / "ngi_xyz_opk.prj", folder)
    assert main(["ortho", *without, "-o", str(tmp_path / "b.tif"), *common]) == 0
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        np.testing.assert_array_equal(a.read(), b.read())


@pytest.mark.realdata
def test_a_stated_crs_that_is_the_dems_needs_no_pyproj(tmp_path: Path) -> None:
    """GDAL tells that the .prj beside the cameras is the DEM's CRS: the check imports no
    pyproj (80 ms with its imports, a fifth of a small orthophoto's whole run)."""
    import subprocess
    import sys

    from orthomvp.bench.peer import horizontal_dem

    data = shared("ngi-aerial")
    dem = horizontal_dem(data / "dem.tif", tmp_path / "dem.tif")
    args = [
        sys.executable, "-X", "importtime", "-m", "orthomvp", "-q", "ortho", str(dem),
        str(data / "3324c_2015_1004_05_0182_RGB.tif"),
        str(data / "orthority-format" / "ngi_xyz_opk.csv"), "--res", "24", "24",
        "-o", str(tmp_path / "o.tif"),
    ]  # fmt: skip
    proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines()}
    assert "orthomvp.engine.stated_crs" in imported and "pyproj" not in imported
