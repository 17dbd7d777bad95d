"""Vertical datums on the command line: the QuickBird RPCs and the NGI frames (Orthority's
format) on the NGI DEM, whose heights are EGM2008 (no grid here) or, retagged, EGM96 (grid
from Debian's proj-data); refusals in one line with exit status 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import CRS, Transformer

from orthomvp.camera import read_camera
from orthomvp.cli import main
from tests.conftest import shared
from tests.test_datum import EGM96, EGM2008_GRID, grid_missing, needs_egm96, retagged

QB = shared("rpc-quickbird", "qb2_basic1b.tif")
NGI_DEM = shared("ngi-aerial", "dem.tif")
FRAME = "3324c_2015_1004_05_0182_RGB"
BOUNDS = (-57500.0, -3731000.0, -54500.0, -3727000.0)  # Lo25 metres, inside the QuickBird image
RES = 6.0  # metres, about the QuickBird image's ground pixel here


def one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("orthomvp: error: "), err
    return err


def grey(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read().astype(np.float64).mean(axis=0)


def registration(a: np.ndarray, b: np.ndarray, margin: int = 20) -> tuple[float, float]:
    """The shift (dx, dy), posts, that moves ``b`` onto ``a`` (cubic interpolation, least
    squares over both but ``margin`` posts at the borders; both filled there)."""
    from scipy.ndimage import shift
    from scipy.optimize import minimize

    inner = np.s_[margin:-margin, margin:-margin]
    assert np.isfinite(a[inner]).all() and np.isfinite(b[inner]).all()

    def cost(p: np.ndarray) -> float:
        return float(np.mean((shift(b, (p[1], p[0]), order=3)[inner] - a[inner]) ** 2))

    found = minimize(cost, np.zeros(2), method="Nelder-Mead", options={"xatol": 1e-3})
    return float(found.x[0]), float(found.x[1])


def rpc_ortho(dem: Path, out: Path, *options: str) -> np.ndarray:
    grid = ["--res", str(RES), str(RES), "--bounds", *map(str, BOUNDS)]
    assert main(["-q", "ortho", str(dem), str(QB), str(QB), "-o", str(out), *grid, *options]) == 0
    return grey(out)


def predicted_shift(dem: Path, undulation: float) -> np.ndarray:
    """Posts (dx, dy) that an orthophoto whose heights are ``undulation`` metres too low must
    move to land on the right one, from the RPC alone: the ground point seen at the grid
    centre's pixel at the right height, against the grid centre (rows grow southward)."""
    camera = read_camera(QB)
    x, y = (BOUNDS[0] + BOUNDS[2]) / 2, (BOUNDS[1] + BOUNDS[3]) / 2
    with rasterio.open(dem) as src:
        h = float(next(src.sample([(x, y)]))[0])
        horizontal = CRS.from_wkt(src.crs.to_wkt()).sub_crs_list[0]
    to_lonlat = Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform(x, y)
    uv = camera.rpc.project(lon, lat, h)  # where the uncorrected orthophoto samples
    seen = camera.rpc.ground(uv, h + undulation)  # the ground point really there
    gx, gy = to_lonlat.transform(*seen, direction="INVERSE")
    return np.array([gx - x, y - gy]) / RES


@pytest.mark.realdata
def test_missing_grid_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    if grid_missing(3855) is None:
        pytest.skip(f"PROJ has {EGM2008_GRID} here: nothing is missing")
    out = tmp_path / "qb.tif"
    assert main(["-q", "ortho", str(NGI_DEM), str(QB), str(QB), "-o", str(out)]) == 2
    err = one_line_error(capsys)
    assert f"projsync --file {EGM2008_GRID}" in err and "--height-offset METRES" in err
    assert not out.exists()
    # an RPC in the DEM's map frame takes the DEM's compound CRS, which needs the grid too
    map_frame = ["-o", str(out), "--world", "map"]
    assert main(["-q", "ortho", str(NGI_DEM), str(QB), str(QB), *map_frame]) == 2
    assert "the world CRS 'Lo25 WGS84 + EGM2008 height'" in (err := one_line_error(capsys))
    assert f"projsync --file {EGM2008_GRID}" in err and not out.exists()
    render = ["-q", "render", str(NGI_DEM), "--camera", str(QB), "--world", "map", "-o"]
    assert main([*render, str(tmp_path / "r.png")]) == 2  # the in-memory commands refuse
    assert "an RPC camera wants heights above" in one_line_error(capsys)
    both = ["--height-offset", "28", "--vertical-datum", "ignore"]
    assert main(["-q", "ortho", str(NGI_DEM), str(QB), str(QB), "-o", str(out), *both]) == 2
    assert "not both" in one_line_error(capsys) and not out.exists()


@pytest.mark.realdata
@pytest.mark.slow
def test_rpc_orthophoto_with_the_geoid_equals_the_undulation_offset(tmp_path: Path) -> None:
    """The QuickBird orthophoto on EGM96 heights converted with the geoid grid equals the one
    made with --height-offset = the undulation at the grid's centre (which varies by centimetres
    over it) and the one in the DEM's map frame (the RPC camera converting its heights itself),
    and differs from the uncorrected one by the shift the RPC predicts for the undulation (about
    1.3 px at 6 m)."""
    needs_egm96()
    dem = retagged(tmp_path, EGM96)
    x, y = (BOUNDS[0] + BOUNDS[2]) / 2, (BOUNDS[1] + BOUNDS[3]) / 2
    with rasterio.open(dem) as src:
        compound = CRS.from_wkt(src.crs.to_wkt())
    to_3d = Transformer.from_crs(compound, "EPSG:4979", always_xy=True, only_best=True)
    undulation = float(to_3d.transform(x, y, 0.0)[2])
    datum = rpc_ortho(dem, tmp_path / "datum.tif", "--processes", "2")  # the grid in workers too
    offset = rpc_ortho(dem, tmp_path / "offset.tif", "--height-offset", f"{undulation!r}")
    ignored = rpc_ortho(dem, tmp_path / "ignored.tif", "--vertical-datum", "ignore")
    mapped = rpc_ortho(dem, tmp_path / "mapped.tif", "--world", "map")  # PROJ's geoid per point
    assert np.nanmax(np.abs(mapped - datum)) < 0.01  # grey levels
    ok = np.isfinite(datum) & np.isfinite(offset)
    assert ok.sum() > 0.9 * datum.size
    assert np.corrcoef(datum[ok], offset[ok])[0, 1] > 0.99999
    assert np.abs(datum[ok] - offset[ok]).mean() < 0.1  # grey levels, of 0..255
    moved = np.array(registration(datum, ignored))
    expected = predicted_shift(dem, undulation)
    ok = np.isfinite(datum) & np.isfinite(ignored)
    r = np.corrcoef(datum[ok], ignored[ok])[0, 1]
    print(
        f"undulation {undulation:.2f} m; the uncorrected orthophoto moves by "
        f"({moved[0]:.2f}, {moved[1]:.2f}) px onto the corrected one (the RPC predicts "
        f"({expected[0]:.2f}, {expected[1]:.2f})); correlation {r:.4f}"
    )
    assert np.abs(moved - expected).max() < 0.1 and np.hypot(*expected) > 1.0
    assert r < 0.97


@pytest.mark.realdata
def test_geoid_conversion_against_the_gcps(tmp_path: Path) -> None:
    """Orthority's GCPs carry WGS84 ellipsoidal heights: the DEM's heights at them are about
    28 m lower as read, and within the DEM's own error (and EGM96's difference from EGM2008)
    once converted."""
    from orthomvp.geometry.terrain import Terrain

    needs_egm96()
    dem = retagged(tmp_path, EGM96)
    features = json.loads(shared("rpc-quickbird", "gcps.geojson").read_text())["features"]
    lon, lat, h = np.array([f["geometry"]["coordinates"] for f in features]).T
    raw, converted = Terrain.read(dem, vertical_datum="ignore"), Terrain.read(dem)
    c, r = raw.crs_to_pixel(
        *Transformer.from_crs(4326, raw.crs, always_xy=True).transform(lon, lat)
    )
    before, after = h - raw.interpolate(c, r), h - converted.interpolate(c, r)
    ok = np.isfinite(before)
    assert ok.sum() >= 3 and (before[ok] > 27).all() and (np.abs(after[ok]) < 1.5).all()


@pytest.mark.realdata
def test_map_frame_cameras_keep_the_dem_heights(tmp_path: Path) -> None:
    """The rule for cameras in the DEM's map frame (Orthority's format): their z is in the
    DEM's vertical datum, so EGM2008 heights need no grid and are used as they are, as are
    EGM96 heights whose grid PROJ has; --height-offset still moves them."""
    image = shared("ngi-aerial", f"{FRAME}.tif")
    exterior = shared("ngi-aerial", "orthority-format", "ngi_xyz_opk.csv")

    def ortho(dem: Path, name: str, *options: str) -> np.ndarray:
        out = tmp_path / name
        args = ["-q", "ortho", str(dem), str(image), str(exterior), "-o", str(out), *options]
        assert main(args) == 0
        return grey(out)

    auto = ortho(NGI_DEM, "auto.tif")
    np.testing.assert_array_equal(auto, ortho(NGI_DEM, "ignore.tif", "--vertical-datum", "ignore"))
    if grid_missing(EGM96) is None:
        np.testing.assert_array_equal(auto, ortho(retagged(tmp_path, EGM96), "egm96.tif"))
    moved = ortho(NGI_DEM, "moved.tif", "--height-offset", "30")
    ok = np.isfinite(auto) & np.isfinite(moved)
    assert np.abs(auto[ok] - moved[ok]).max() > 10


def test_every_dem_command_takes_the_options(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("ortho", "visibility", "mosaic", "fit", "check", "render", "explore", "mesh"):
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert "--height-offset METRES" in text and "metres added to every DEM height" in text
        assert "--vertical-datum [auto|ignore]" in text, command


@pytest.mark.realdata
@pytest.mark.slow
def test_fit_in_the_map_frame_keeps_the_vertical_datum(tmp_path: Path) -> None:
    """A fit with Orthority-format cameras writes the DEM's own (EGM2008) heights, and says so
    in its CRS, so that reading it back converts it as the input would be."""
    d, exterior = shared("ngi-aerial"), shared("ngi-aerial", "orthority-format", "ngi_xyz_opk.csv")
    views = [
        str(v)
        for f in ("05_0182", "05_0184")
        for v in (d / f"3324c_2015_1004_{f}_RGB.tif", exterior)
    ]
    out = tmp_path / "fit.tif"
    assert main(["-q", "fit", str(NGI_DEM), *views, "-o", str(out), "--levels", "1"]) == 0
    with rasterio.open(out) as fitted, rasterio.open(NGI_DEM) as dem:
        assert CRS.from_wkt(fitted.crs.to_wkt()) == CRS.from_wkt(dem.crs.to_wkt())
        change = fitted.read(1) - dem.read(1)
    assert abs(np.nanmedian(change)) < 3.0  # metres: the same datum, not 28 m apart
