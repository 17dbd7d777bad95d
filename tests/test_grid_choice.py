"""The output grid chosen from the cameras, resolutions with units, the size preflight and
``orthomvp info``: footprints against the camera's own projection of every DEM post, GSDs
against finite differences of the camera's projection along the ground."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from matplotlib.path import Path as Polygon

from orthomvp.engine.footprint import image_footprint
from orthomvp.engine.grid_choice import choose_grid, read_source
from orthomvp.engine.images import image_source
from orthomvp.engine.units import CLEAN, clean_metres, parse_length, parse_res
from orthomvp.errors import InputError
from orthomvp.geometry.datum import HeightOptions
from orthomvp.geometry.terrain import Terrain
from tests.conftest import shared

REAL = {
    "apollo15": (
        "apollo15-mvp/ground-dem.tif",
        "apollo15-mvp/image0.tif",
        "apollo15-mvp/camera0.pinhole",
    ),
    "ngi-orthority": (
        "ngi-aerial/dem.tif",
        "ngi-aerial/3324c_2015_1004_05_0182_RGB.tif",
        "ngi-aerial/orthority-format/ngi_xyz_opk.csv",
    ),
    "quickbird-rpc": ("ngi-aerial/dem.tif", "rpc-quickbird/qb2_basic1b.tif", None),
    "as15-hadley": (
        "as15-hadley/LOLA_hadley_dem.tif",
        "as15-hadley/AS15-M-1134-hadley.tif",
        "as15-hadley/AS15-M-1134-hadley.converted.tsai",
    ),
}


def cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "orthomvp", *map(str, args)], capture_output=True, text=True
    )


def one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("orthomvp: error: "), proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


# ----------------------------------------------------------------------------- units
def test_lengths_parse_with_and_without_units() -> None:
    assert parse_length("5m") == parse_length(" 5 m ").__class__(5.0, "m", "5m")
    assert parse_length("2.5km").value == 2500.0 and parse_length("2.5km").unit == "m"
    assert parse_length("30cm").value == pytest.approx(0.3)
    assert parse_length("0.0003deg").value == 0.0003 and parse_length("0.0003deg").unit == "deg"
    assert parse_length("36arcsec").value == pytest.approx(0.01)
    assert parse_length("1.5arcmin").value == pytest.approx(0.025)
    assert parse_length("30").unit is None and parse_length(30).value == 30.0
    assert parse_length("1e-6").value == 1e-6
    assert parse_res("5m") == (parse_length("5m"),) * 2
    assert parse_res(("4", "3m"))[1].unit == "m"
    for bad in ("5 furlong", "-5m", "0", "nan", "m", "", "5m5", True, (1, 2, 3), object()):
        with pytest.raises(InputError):
            parse_res(bad)


def test_clean_resolutions_are_the_nearest_on_a_log_scale() -> None:
    rng = np.random.default_rng(1)
    candidates = np.array([m * 10.0**k for k in range(-8, 9) for m in CLEAN])
    for x in 10 ** rng.uniform(-6, 6, 500):
        best = candidates[np.argmin(np.abs(np.log(candidates / x)))]
        assert clean_metres(x) == pytest.approx(best, rel=1e-12)
    assert [clean_metres(x) for x in (5.94, 31.9, 0.37, 1.0, 2.3)] == [5, 25, 0.5, 1, 2.5]


# -------------------------------------------------------------------- footprint truth
def _real(name: str) -> tuple[Path, Path, Path]:
    dem, image, camera = REAL[name]
    return shared(dem), shared(image), shared(camera) if camera else shared(image)


def _truth(dem_path: Path, image: Path, camera: Path):  # noqa: ANN202
    """The engine's reading of the scene, and every DEM post's projection by the camera."""
    as_read = HeightOptions("ignore")  # the ngi-aerial DEM's EGM2008 heights: no grid here
    views = [image_source(image, camera)]
    source, views = read_source(dem_path, views, None, False, "auto", False, as_read)
    view = views[0]
    terrain = Terrain.read(dem_path, world=source.world, vertical_datum="ignore")
    points = terrain.world_points()
    uv, _ = view.camera.project(points)
    seen = np.isfinite(terrain.values) & np.isfinite(uv).all(axis=-1)
    seen[seen] = view.camera.in_image(uv[seen])
    return source, view, terrain, points, uv, seen


def _lonlat(terrain: Terrain, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    lon, lat = terrain.pixel_to_lonlat(c, r, wrap=False)
    return np.degrees(np.stack([lon, lat], axis=-1))


def _ground_gsd(terrain: Terrain, camera, points: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """Metres per pixel on the horizontal plane by central differences of 5 cm of the
    camera's projection along east and north (from lon/lat, or the map axes)."""
    if terrain.world.value == "map":
        east, north = np.eye(3)[0], np.eye(3)[1]
        east, north = np.broadcast_to(east, points.shape), np.broadcast_to(north, points.shape)
    else:
        lon = np.arctan2(points[:, 1], points[:, 0])
        lat = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
        east = np.stack([-np.sin(lon), np.cos(lon), 0 * lon], axis=-1)
        north = np.stack(
            [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], axis=-1
        )
    h = 0.05
    du = (camera.project(points + h * east)[0] - camera.project(points - h * east)[0]) / (2 * h)
    dv = (camera.project(points + h * north)[0] - camera.project(points - h * north)[0]) / (2 * h)
    return 1 / np.sqrt(np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]))


@pytest.mark.realdata
@pytest.mark.parametrize("name", list(REAL))
def test_footprint_is_what_the_camera_projects_into_the_image(name: str) -> None:
    source, view, terrain, points, uv, seen = _truth(*_real(name))
    fp = image_footprint(source, view)
    rows, cols = np.nonzero(seen)
    assert fp.step == 1  # these DEMs fit the lattice: the window is exact
    assert fp.window == (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)
    assert fp.seen == seen.sum()
    # the outline (lon/lat) holds every seen post and little else
    ring = _lonlat(terrain, fp.outline[:, 0], fp.outline[:, 1])
    polygon = Polygon(ring)
    c, r = np.meshgrid(np.arange(terrain.shape[1]), np.arange(terrain.shape[0]))
    inside = polygon.contains_points(_lonlat(terrain, c.ravel(), r.ravel()), radius=-1e-9)
    inside = inside.reshape(seen.shape)
    assert inside[seen].all()
    hull_only = inside & ~seen & np.isfinite(terrain.values)
    assert hull_only.sum() <= 0.03 * seen.sum() + 2 * (seen.shape[0] + seen.shape[1])
    # GSD against finite differences of the camera's own projection at every seen post
    truth = _ground_gsd(terrain, view.camera, points[seen])
    assert np.median(fp.gsd) == pytest.approx(np.median(truth), rel=0.01)
    assert fp.gsd.min() >= truth.min() * 0.99 and fp.gsd.max() <= truth.max() * 1.01
    # emission: the angle between the radial/vertical up and the line to the sensor
    assert 0 <= fp.emission.min() <= fp.emission.max() < 90


@pytest.mark.slow
def test_footprint_of_a_large_dem_is_found_on_a_bounded_lattice(
    crater_dir: Path, tmp_path: Path
) -> None:
    """A DEM of 1,500 x 1,300 posts (beyond the 512-post lattice): the coarse search and a
    decimated window still bound every post that the camera projects into the image."""
    with rasterio.open(crater_dir / "dem.tif") as src:
        profile, t = src.profile, src.transform
    big = 1500, 1300
    step = Affine.scale(0.2)
    transform = t @ Affine.translation(-200, -150) @ step
    y, x = np.mgrid[0 : big[0], 0 : big[1]]
    values = (60 * np.sin(x / 37.0) * np.cos(y / 53.0)).astype("float32")
    profile.update(height=big[0], width=big[1], transform=transform, tiled=True)
    profile.update(blockxsize=256, blockysize=256, dtype="float32", nodata=None)
    path = tmp_path / "big.tif"
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(values, 1)
    source, view, terrain, points, uv, seen = _truth(
        path, crater_dir / "oblique.tif", crater_dir / "oblique.tsai"
    )
    assert source.held is None  # read in windows, never whole
    fp = image_footprint(source, view)
    rows, cols = np.nonzero(seen)
    truth = (rows.min(), rows.max() + 1, cols.min(), cols.max() + 1)
    r0, r1, c0, c1 = fp.window
    assert fp.step > 1
    assert r0 <= truth[0] and r1 >= truth[1] and c0 <= truth[2] and c1 >= truth[3]
    slack = fp.step - 1
    assert truth[0] - r0 <= slack and r1 - truth[1] <= slack
    assert truth[2] - c0 <= slack and c1 - truth[3] <= slack
    assert seen.sum() < 0.5 * seen.size  # the image sees a part of the DEM only


# -------------------------------------------------------------------------- the grid
@pytest.mark.realdata
def test_camera_grid_on_ngi_is_the_footprint_at_the_images_gsd() -> None:
    dem, image, camera = _real("ngi-orthority")
    source, views = read_source(dem, [image_source(image, camera)], None, False, "auto", False)
    fp = image_footprint(source, views[0])
    grid = choose_grid(source, views, footprints=[fp])
    t, d = grid.transform, source.transform
    assert t.a == -t.e == clean_metres(float(np.median(fp.gsd))) == 5.0
    # edges on the DEM's lattice of 5 m, outside the footprint's posts by less than a post
    for edge, origin in ((t.c, d.c), (t.f, d.f)):
        assert (edge - origin) / 5.0 == pytest.approx(round((edge - origin) / 5.0), abs=1e-6)
    r0, r1, c0, c1 = fp.window
    left, top = d @ (c0, r0)
    right, bottom = d @ (c1, r1)
    rows, cols = grid.shape
    assert 0 <= left - t.c < 5 and 0 <= t.f - top < 5
    assert 0 <= t.c + cols * t.a - right < 5 and 0 <= bottom - (t.f + rows * t.e) < 5
    # --res alone keeps the extent, --bounds alone keeps the resolution; "dem" is the DEM's
    coarse = choose_grid(source, views, res="24m", footprints=[fp])
    assert coarse.transform.a == 24 and coarse.shape[1] == pytest.approx(cols * 5 / 24, abs=2)
    box = choose_grid(source, views, bounds=(-56000, -3728000, -55000, -3727000))
    assert box.transform.a == 5 and box.shape == (200, 200)
    own = choose_grid(source, views, grid="dem")
    assert own.on_dem and own.transform == d


@pytest.mark.realdata
@pytest.mark.slow
def test_ortho_on_the_camera_grid_is_mostly_filled(tmp_path: Path) -> None:
    dem, image, camera = _real("apollo15")
    out, old = tmp_path / "o.tif", tmp_path / "dem.tif"
    for args, path in (((), out), (("--grid", "dem"), old)):
        proc = cli("ortho", dem, image, camera, "-o", path, *args)
        assert proc.returncode == 0, proc.stderr
        assert "warning" not in proc.stderr  # a footprint's grid is not a partial cover
    with rasterio.open(out) as a, rasterio.open(old) as b, rasterio.open(dem) as d:
        assert b.transform == d.transform
        assert a.crs == d.crs and a.res[0] == pytest.approx(25 / (1737400 * math.pi / 180))
        filled = np.isfinite(a.read(1)).mean()
    assert filled > 0.9


# ------------------------------------------------------------------------- refusals
@pytest.mark.realdata
@pytest.mark.slow
def test_absurd_resolutions_are_refused_in_one_line_before_planning(tmp_path: Path) -> None:
    dem, image, camera = _real("apollo15")
    out = tmp_path / "o.tif"
    one_line_error(
        cli("ortho", dem, image, camera, "-o", out, "--res", "30"),
        "30 (degrees",
        "910 km",
        "probably meant metres: 30m",
    )
    start = time.perf_counter()
    one_line_error(cli("ortho", dem, image, camera, "-o", out, "--res", "1e-6"), "posts per pixel")
    assert time.perf_counter() - start < 30  # planning its 47,610 tiles took > 300 s
    ngi, frame, cam = _real("ngi-orthority")
    one_line_error(
        cli("ortho", ngi, frame, cam, "-o", out, "--res", "1e-6"), "finer than a millimetre"
    )
    one_line_error(cli("ortho", ngi, frame, cam, "-o", out, "--res", "5parsec"), "unknown unit")
    one_line_error(cli("ortho", ngi, frame, cam, "-o", out, "--res", "1", "2", "3"), "--res")
    one_line_error(cli("ortho", ngi, frame, cam, "-o", out, "--grid", "image"), "--grid")
    assert not out.exists()


# ------------------------------------------------------------------------------ info
@pytest.mark.realdata
@pytest.mark.slow
def test_info_json_is_geojson_with_the_footprint() -> None:
    dem, image, _ = _real("quickbird-rpc")
    proc = cli("info", dem, image, "--json", "--height-offset", 28)  # the image's own RPCs
    assert proc.returncode == 0, proc.stderr
    feature = json.loads(proc.stdout)
    assert feature["type"] == "Feature" and feature["geometry"]["type"] == "Polygon"
    ring = np.array(feature["geometry"]["coordinates"][0])
    assert (ring[0] == ring[-1]).all() and len(ring) >= 4
    x, y = ring[:, 0], ring[:, 1]
    assert np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) > 0  # counter-clockwise
    props = feature["properties"]
    assert props["dem"]["vertical_datum"] == "EGM2008 height"
    assert props["image"]["camera"] == "RpcCamera"
    lon0, lat0, lon1, lat1 = props["dem"]["extent_lonlat"]
    assert lon0 <= x.min() and x.max() <= lon1 and lat0 <= y.min() and y.max() <= lat1
    grid = props["image"]["grid"]
    assert grid["res"] == [5.0, 5.0] and 0 < grid["dem_share"] < 1
    proc = cli("info", dem)
    assert proc.returncode == 0 and "vertical datum: EGM2008 height" in proc.stdout
    assert "24 x 24 m" in proc.stdout


@pytest.mark.realdata
def test_info_text_for_a_lunar_frame() -> None:
    dem, image, camera = _real("as15-hadley")
    proc = cli("info", dem, image, camera)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "geographic, degrees" in text and "1,737,400.0" in text
    assert "GSD:           median 28.6 m" in text and "default grid:" in text
    one_line_error(cli("info", dem, image, dem.parent / "nope.tsai"), "nope.tsai")


def test_plan_ortho_defaults_to_the_camera_grid(crater_dir: Path) -> None:
    """The API's default is the command line's: the footprint at the image's clean GSD; "dem"
    is the DEM's own grid; a resolution with a unit is converted on the DEM's body."""
    from orthomvp.engine import plan_ortho

    dem, view = crater_dir / "dem.tif", (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    plan = plan_ortho(dem, [view], progress=False)
    source, views = read_source(dem, [image_source(*view)], None, False, "auto", False)
    fp = image_footprint(source, views[0])
    radius = source.preview.radii[0]
    degree = radius * math.pi / 180  # metres per degree on the body
    assert source.crs.is_geographic
    assert plan.grid.transform.a == pytest.approx(clean_metres(np.median(fp.gsd)) / degree)
    assert plan.grid == choose_grid(source, views)
    assert not plan.grid.on_dem and plan.grid.shape != source.shape
    assert plan_ortho(dem, [view], grid="dem", progress=False).grid.on_dem
    fine = plan_ortho(dem, [view], res="100m", progress=False).grid
    assert fine.transform.a == pytest.approx(100 / degree) == -fine.transform.e
    with pytest.raises(InputError, match="grid must be one of camera, dem"):
        plan_ortho(dem, [view], grid="image", progress=False)
    with pytest.raises(InputError, match="probably meant metres: 30m"):
        plan_ortho(dem, [view], res=30, progress=False)


def test_a_grid_beyond_the_free_space_is_refused_before_planning(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Free space: refused when even 10:1 compression would not fit; the DEM's own grid is
    never refused for its posts per pixel, a finer grid is."""
    import shutil

    from orthomvp.engine import grid_choice

    dem, view = crater_dir / "dem.tif", (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    source, views = read_source(dem, [image_source(*view)], None, False, "auto", False)
    grid = choose_grid(source, views)
    rows, cols = grid.shape
    need = rows * cols * 4 * views[0].bands * 4 / 3 / grid_choice.COMPRESSION
    usage = shutil.disk_usage(tmp_path)
    for free, refused in ((int(need) - 1, True), (int(need) + 1, False)):
        monkeypatch.setattr(
            grid_choice.shutil, "disk_usage", lambda _, f=free: usage._replace(free=f)
        )
        if refused:
            with pytest.raises(InputError, match=f"free in {tmp_path}"):
                grid_choice.check_grid_size(grid, source, views, tmp_path)
        else:
            grid_choice.check_grid_size(grid, source, views, tmp_path)
    monkeypatch.undo()
    pixels = views[0].width * views[0].height
    own = choose_grid(source, views, grid="dem")
    monkeypatch.setattr(grid_choice, "POSTS_PER_PIXEL", own.shape[0] * own.shape[1] / pixels / 2)
    grid_choice.check_grid_size(own, source, views)  # the DEM's own grid: always written
    with pytest.raises(InputError, match="posts per pixel"):
        grid_choice.check_grid_size(choose_grid(source, views, res="1m"), source, views)


@pytest.mark.parametrize(
    "crs", ["EPSG:4326", "EPSG:32633", "+proj=longlat +R=1737400 +no_defs", "EPSG:2236"]
)
def test_unit_scale_is_the_same_from_rasterio_and_pyproj(crs: str) -> None:
    """A file's CRS as rasterio reads it gives the units pyproj gives (without pyproj)."""
    from pyproj import CRS as ProjCRS
    from rasterio.crs import CRS as FileCRS

    from orthomvp.engine.units import unit_scale

    file_scale = unit_scale(FileCRS.from_user_input(crs), 1737400.0)
    proj_scale = unit_scale(ProjCRS.from_user_input(crs), 1737400.0)
    assert file_scale[1] == proj_scale[1]
    assert file_scale[0] == pytest.approx(proj_scale[0], rel=1e-12)


def _cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "orthomvp", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--crs", "EPSG:4326"], "another body"),  # the Moon's DEM, the Earth's CRS
        (["--bounds", "-1e200", "-90", "1e200", "90"], "the output grid would be"),
        (["--bounds", "-1e200", "-1e200", "1e200", "1e200"], "lies outside +-90 degrees"),
        (["--bounds", "100", "50", "100.01", "50.01"], "miss the DEM"),
    ],
)
def test_grids_that_cannot_be_are_one_line_with_exit_2(
    crater_dir: Path, tmp_path: Path, options: list, words: str
) -> None:
    """Found in review: the camera grid in another body's CRS and an enormous grid were
    internal errors, and bounds off the DEM blamed the camera."""
    out = tmp_path / "o.tif"
    d = crater_dir
    proc = _cli("ortho", d / "dem.tif", d / "oblique.tif", d / "oblique.tsai", "-o", out, *options)
    assert proc.returncode == 2, proc.stderr
    (line,) = proc.stderr.splitlines()
    assert line.startswith("orthomvp: error:") and words in line, line
    assert not out.exists()


def test_info_names_heights_shifted_for_the_cameras(crater_dir: Path) -> None:
    d = crater_dir
    plain = _cli("info", d / "dem.tif", d / "oblique.tif", d / "oblique.tsai")
    shifted = _cli(
        "info", d / "dem.tif", d / "oblique.tif", d / "oblique.tsai", "--height-offset", "5"
    )
    assert plain.returncode == shifted.returncode == 0, shifted.stderr
    assert "shifted for the cameras" in shifted.stdout
    assert "shifted for the cameras" not in plain.stdout


def test_info_of_radii_and_a_map_frame_on_degrees_say_so(tmp_path: Path) -> None:
    """Found by a new user's audit: `info --radius-values` said "vertical datum: none (heights
    above the ellipsoid)", and the map frame on a degree CRS was refused in Python's words."""
    from orthomvp.cli.info import text_lines
    from orthomvp.engine.info import describe

    path = tmp_path / "radii.tif"
    values = 1737400.0 + np.arange(64, dtype=np.float32).reshape(8, 8)
    profile = dict(driver="GTiff", width=8, height=8, count=1, dtype="float32")
    profile |= {"crs": "+proj=longlat +R=1737400 +no_defs"}
    profile["transform"] = Affine(0.01, 0, 10.0, 0, -0.01, 20.0)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(values, 1)
    lines = text_lines(describe(path, radius_values=True))
    assert "  vertical datum: none (radii)" in lines
    with pytest.raises(InputError, match=r"the map frame \(--world map\) needs a projected CRS"):
        Terrain.read(path, world="map")
