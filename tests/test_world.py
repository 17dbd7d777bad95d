"""World-frame auto-detection: body-fixed metres or the DEM's map frame, from camera centres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS, Transformer

from orthomvp.camera import read_camera
from orthomvp.cli import main
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.world import body_plausible, detect_world, map_plausible
from orthomvp.io.raster import write_geotiff
from orthomvp.synthetic import make_scene
from tests.conftest import shared

MOON_EQC = "+proj=eqc +R=1737400 +units=m +no_defs"


def eqc(terrain: Terrain) -> Terrain:
    """The same posts in the Moon's equirectangular projection (metres), heights unchanged."""
    t, k = terrain.transform, np.radians(1737400.0)
    grid = Affine(t.a * k, 0, t.c * k, 0, t.e * k, t.f * k)
    return Terrain(terrain.values, grid, CRS.from_proj4(MOON_EQC))


def ngi() -> tuple[Terrain, np.ndarray]:
    d = shared("ngi-aerial")
    exterior = d / "orthority-format" / "ngi_xyz_opk.csv"
    images = sorted(d.glob("*_RGB.tif"))
    dem = Terrain.read(d / "dem.tif", vertical_datum="ignore")  # EGM2008 heights, no grid here
    return dem, np.array([read_camera(exterior, f).center for f in images])


def ambiguous() -> tuple[Terrain, np.ndarray]:
    """Made up: a near-global lunar DEM in eqc metres, 50 km below the reference sphere, and a
    camera at (R + 100 km, 0, 0), which is 100 km above lon 0, lat 0 in body-fixed metres and,
    read as map coordinates, 50 km above the DEM inside its map extent."""
    values = np.full((64, 64), -50_000.0)
    grid = Affine(60_000.0, 0, -1_920_000.0, 0, -60_000.0, 1_920_000.0)
    return Terrain(values, grid, CRS.from_proj4(MOON_EQC)), np.array([[1_837_400.0, 0.0, 0.0]])


@pytest.mark.realdata
def test_ngi_aerial_cameras_are_in_the_map_frame() -> None:
    terrain, centres = ngi()
    assert not body_plausible(terrain, centres).any()
    assert map_plausible(terrain, centres).all()
    assert detect_world(terrain, centres) == "map"


@pytest.mark.realdata
def test_ngi_aerial_cameras_in_earth_centred_metres_are_body() -> None:
    terrain, centres = ngi()
    to_ecef = Transformer.from_crs(terrain.crs.to_3d(), "EPSG:4978", always_xy=True)
    ecef = np.stack(to_ecef.transform(*centres.T), axis=-1)
    assert detect_world(terrain, ecef) == "body"
    with pytest.raises(InputError, match="--world body or --world map"):
        detect_world(terrain, np.vstack([centres[:1], ecef[1:]]))  # the cameras disagree


@pytest.mark.realdata
def test_apollo15_cameras_are_body_fixed() -> None:
    d = shared("apollo15-mvp")
    terrain = Terrain.read(d / "ground-dem.tif")
    centres = np.array([read_camera(d / f"camera{k}.pinhole").center for k in range(4)])
    assert detect_world(terrain, centres) == "body"  # geographic CRS
    projected = eqc(terrain)
    assert body_plausible(projected, centres).all() and not map_plausible(projected, centres).any()
    assert detect_world(projected, centres) == "body"


def test_synthetic_lunar_scenes_are_body_fixed() -> None:
    scene = make_scene("crater", size=32, spacing=80.0)
    centres = np.array([c.center for c in scene.cameras.values()])
    assert detect_world(scene.terrain, centres) == "body"
    assert detect_world(eqc(scene.terrain), centres) == "body"


def test_ambiguous_and_implausible_cameras_raise() -> None:
    terrain, centres = ambiguous()
    assert body_plausible(terrain, centres).all() and map_plausible(terrain, centres).all()
    with pytest.raises(InputError, match="fits both"):
        detect_world(terrain, centres)
    with pytest.raises(InputError, match="no cameras"):
        detect_world(terrain, np.empty((0, 3)))
    # below the surface in both frames
    below = np.array([[0.0, 0.0, -60_000.0]])
    with pytest.raises(InputError, match="fits neither"):
        detect_world(terrain, below)


def write_scene(tmp_path: Path) -> tuple[Path, Path, Path]:
    """The ambiguous scene as files: DEM, a 64 x 64 image and a camera looking straight down
    the map frame's -z (rows along -y), focal length 16 px."""
    terrain, (centre,) = ambiguous()
    dem, image, camera = tmp_path / "dem.tif", tmp_path / "image.tif", tmp_path / "cam.tsai"
    terrain.write(dem)
    pixels = np.random.default_rng(0).random((64, 64), np.float32)
    write_geotiff(image, pixels, Affine.identity(), None)
    camera.write_text(
        "VERSION_4\nPINHOLE\nfu = 16\nfv = 16\ncu = 31.5\ncv = 31.5\n"
        "u_direction = 1 0 0\nv_direction = 0 1 0\nw_direction = 0 0 1\n"
        f"C = {centre[0]} {centre[1]} {centre[2]}\nR = 1 0 0 0 -1 0 0 0 -1\npitch = 1\nNULL\n"
    )
    return dem, image, camera


def test_cli_asks_for_world_when_ambiguous_and_obeys_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dem, image, camera = write_scene(tmp_path)
    common = ["visibility", str(dem), str(image), str(camera)]
    assert main([*common, "-o", str(tmp_path / "auto.tif")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("orthomvp: error:") and "--world body or --world map" in err
    assert "\n" not in err and not (tmp_path / "auto.tif").exists()
    assert main([*common, "-o", str(tmp_path / "map.tif"), "--world", "map"]) == 0
    out = capsys.readouterr().out
    assert "wrote" in out and " 0 visible" not in out


@pytest.mark.realdata
def test_cli_world_auto_on_ngi_aerial(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = shared("ngi-aerial")
    image = d / "3324c_2015_1004_05_0182_RGB.tif"
    exterior = d / "orthority-format" / "ngi_xyz_opk.csv"
    args = ["visibility", str(d / "dem.tif"), str(image), str(exterior)]
    assert main([*args, "-o", str(tmp_path / "auto.tif")]) == 0
    auto = capsys.readouterr().out.split(":", 2)[2]
    assert main([*args, "-o", str(tmp_path / "map.tif"), "--world", "map"]) == 0
    assert capsys.readouterr().out.split(":", 2)[2] == auto
    assert main([*args, "-o", str(tmp_path / "body.tif"), "--world", "body"]) == 2  # overridden
    err = capsys.readouterr().err  # the cameras are not above the DEM in body-fixed metres
    assert "below its surface" in err and "do not sit above the DEM" in err


def test_centres_nearer_the_body_centre_than_every_post_are_ruled_out_untransformed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The shortcut gives what transforming the posts gives: on a lunar DEM 50 km below the
    sphere, centres at the posts' distance or nearer are not body-plausible (found without
    transforming a post), and centres just above a post still are (found by transforming)."""
    terrain, _ = ambiguous()
    nearest = 1737400.0 - 50_000.0  # every post lies at this distance from the centre
    lon, lat = terrain.pixel_to_lonlat(np.array(31.0), np.array(31.0))  # a post
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    below = np.array([0.999 * nearest * up, 0.5 * nearest * up[::-1], [0.0, 0.0, 0.0]])
    above = np.array([(nearest + 10.0) * up])
    full = body_plausible(terrain, np.concatenate([below, above]))
    assert full.tolist() == [False, False, False, True]

    def no_transform(*args: object, **kwargs: object) -> None:
        raise AssertionError("posts were transformed")

    monkeypatch.setattr(Terrain, "to_world", no_transform)
    assert not body_plausible(terrain, below).any()
    with pytest.raises(AssertionError, match="transformed"):
        body_plausible(terrain, above)
