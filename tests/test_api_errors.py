"""The Python API's errors: one family (``orthomvp.errors``), whose classes are also the
matching built-ins; wrong types, shapes and ranges raise it where they enter the library, so the
API refuses what the command line refuses; sizes that cannot fit in memory are refused before
any work; and errors name their real cause."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import CRS

from orthomvp.camera import as_image, read_camera
from orthomvp.errors import (
    FormatError,
    GeometryError,
    InputError,
    OrthoMVPError,
    OrthoMVPWarning,
    OutputError,
)
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.io.raster import read_image
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import compute_visibility
from orthomvp.ortho.orthophoto import mosaic, orthorectify, sample_image
from orthomvp.present.export import export_mesh
from orthomvp.present.snapshot import SnapshotOptions, snapshot
from orthomvp.synthetic import make_scene


def test_the_family_is_also_the_builtins() -> None:
    assert issubclass(InputError, ValueError) and issubclass(FormatError, ValueError)
    assert issubclass(GeometryError, ValueError)
    assert issubclass(OutputError, OSError) and issubclass(OutputError, OrthoMVPError)
    for cls in (InputError, FormatError, GeometryError, OutputError):
        assert issubclass(cls, OrthoMVPError)
    assert str(OutputError("cannot write out/v.tif: no space left on device")).startswith("cannot")
    with pytest.raises(ValueError, match="hwin"):  # code that catches ValueError keeps working
        FitOptions(hwin=0)


def test_the_family_crosses_process_boundaries(tmp_path: Path) -> None:
    """Errors raised in the engine's worker processes reach the parent as themselves (a
    FormatError once failed to unpickle there and surfaced as a dead worker)."""
    import pickle
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from orthomvp.camera.model import FieldError

    cases = [
        FormatError("a/b.tsai", "bad focal length", line=3),
        FormatError("a/b.cub", "truncated"),
        FieldError("fu", "fu must be positive"),
        InputError("x"),
        GeometryError("y"),
        OutputError("cannot write o.tif: no space left on device"),
    ]
    for exc in cases:
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and str(back) == str(exc)
        assert getattr(back, "line", None) == getattr(exc, "line", None)
        assert getattr(back, "field", None) == getattr(exc, "field", None)
    bad = tmp_path / "bad.tsai"
    bad.write_text("VERSION_4\nPINHOLE\nfu = nonsense\n")
    with pytest.raises(FormatError) as local:
        read_camera(bad)
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        with pytest.raises(FormatError) as remote:
            pool.submit(read_camera, bad).result()
    assert str(remote.value) == str(local.value) and remote.value.line == local.value.line


@pytest.fixture(scope="module")
def view(crater_dir: Path) -> tuple[Terrain, np.ndarray, object]:
    dem = Terrain.read(crater_dir / "dem.tif")
    image = read_image(crater_dir / "oblique.tif")
    camera = read_camera(crater_dir / "oblique.tsai").with_image_size(*image.shape[:0:-1])
    return dem, image, camera


def test_wrong_types_and_shapes_raise_the_family(view: tuple, crater_dir: Path) -> None:
    dem, image, camera = view
    tm = terrain_mesh(dem)
    calls = {
        "a DEM file name": lambda: Terrain.read(None),
        "a DEM file name ": lambda: Terrain.read(123),
        "a directory": lambda: Terrain.read(crater_dir),
        "transform must be an affine": lambda: Terrain(dem.values, None, dem.crs),
        "cannot understand CRS": lambda: Terrain(dem.values, dem.transform, None),
        "real numbers": lambda: Terrain(np.full((4, 4), "a"), dem.transform, dem.crs),
        "resolution must be two numbers": lambda: dem.regrid(res="x"),
        "bounds must be four numbers": lambda: dem.regrid(bounds=(1, 2)),
        "camera file name": lambda: read_camera(None),
        "raster file name": lambda: read_image(None),
        "its camera must be a camera model": lambda: orthorectify(dem, image, None),
        "expected an image array": lambda: orthorectify(dem, None, camera),
        "terrain must be a Terrain": lambda: orthorectify(None, image, camera),
        "expected an image array ": lambda: orthorectify(dem, "oblique.tif", camera),
        "eps (DEM posts) must be a number": lambda: orthorectify(dem, image, camera, eps="x"),
        "visibility must be a Visibility": lambda: orthorectify(dem, image, camera, visibility=1),
        "caster must be an Occluders": lambda: compute_visibility(dem, camera, caster="x"),
        "camera must be a Camera": lambda: compute_visibility(dem, "camera"),
        "(image, camera) pair": lambda: mosaic(dem, [image]),
        "a list of (image, camera) views": lambda: mosaic(dem, None),
        "pixel positions": lambda: sample_image(image, None),
        "hwin must be an integer, got str": lambda: FitOptions(hwin="5"),
        "hwin must be an integer, got float": lambda: FitOptions(hwin=2.5),
        "options must be a FitOptions": lambda: fit_dem(dem, [image, image], [camera] * 2, "x"),
        "images and cameras must be lists": lambda: fit_dem(dem, None, [camera]),
        "rays must be an integer": lambda: SnapshotOptions(rays="3"),
        "snapshot size must be (width, height)": lambda: SnapshotOptions(size=5),
        "scene size (posts) must be an integer": lambda: make_scene("crater", size="x"),
        "the mesh must be a TerrainMesh": lambda: export_mesh(None, "x.ply"),
        "a ray caster needs a TerrainMesh": lambda: RayCaster(None),
        "terrain must be a Terrain ": lambda: terrain_mesh(None),
    }
    for words, call in calls.items():
        with pytest.raises(InputError) as info:
            call()
        assert words.strip() in str(info.value), (words, str(info.value))
    assert tm is not None


def test_what_passed_silently_is_refused_or_documented(view: tuple) -> None:
    dem, image, camera = view
    # options check themselves, as the command line does
    for kwargs, words in (
        ({"levels": 0}, "levels must be >= 1"),
        ({"sigma": float("nan")}, "sigma must be > 0"),
        ({"reject_below": 5}, "reject_below must be in [-1, 1]"),
        ({"deconvolve": -3}, "deconvolve must be in [0, 10]"),
        ({"max_iter": -1}, "max_iter must be >= 0"),
        ({"htol": -1}, "htol"),
    ):
        with pytest.raises(InputError, match=words.replace("[", r"\[").replace("]", r"\]")):
            FitOptions(**kwargs)
    assert FitOptions(hwin=5.0).hwin == 5  # a float with an integer value is fine
    with pytest.raises(InputError, match=r"the DEM's shape \(64, 64\), got \(10, 10\)"):
        dem.with_values(np.zeros((10, 10)))
    with pytest.raises(InputError, match=r"\(bands, rows, cols\) or \(rows, cols\)"):
        orthorectify(dem, image[None], camera)  # 4-D
    for bad in (image.astype(np.complex64), image > 0.5):
        with pytest.raises(InputError, match="real numbers"):
            orthorectify(dem, bad, camera)
    # integer images are taken as float32 with their values (documented in as_image)
    scaled = np.nan_to_num(image / np.nanmax(image) * 255)
    as_uint8 = scaled.astype(np.uint8)
    assert as_image(as_uint8).dtype == np.float32
    a = orthorectify(dem, as_uint8, camera).data
    b = orthorectify(dem, as_uint8.astype(np.float32), camera).data
    np.testing.assert_array_equal(a, b)
    # a (rows, cols) image is one band
    np.testing.assert_array_equal(
        orthorectify(dem, image[0], camera).data, orthorectify(dem, image, camera).data
    )


def test_images_as_rows_cols_bands_are_named_as_such(view: tuple, crater_dir: Path) -> None:
    dem, image, _ = view
    rgb = np.repeat(np.moveaxis(image, 0, -1), 3, axis=-1)  # (rows, cols, 3), as PIL gives
    camera = read_camera(crater_dir / "oblique.tsai")
    with pytest.raises(InputError, match=r"looks like \(rows, cols, bands\).*np.moveaxis"):
        orthorectify(dem, rgb, camera)


def test_infinite_heights_are_nodata(crater_dir: Path, tmp_path: Path) -> None:
    with rasterio.open(crater_dir / "dem.tif") as src:
        profile, values = src.profile, src.read(1)
    values[3, 4:7] = np.inf
    values[5, 5] = -np.inf
    with rasterio.open(tmp_path / "inf.tif", "w", **profile) as dst:
        dst.write(values, 1)
    with pytest.warns(OrthoMVPWarning, match="4 infinite heights taken as nodata"):
        dem = Terrain.read(tmp_path / "inf.tif")
    assert np.isnan(dem.values[3, 4:7]).all() and np.isnan(dem.values[5, 5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning on the way
        terrain_mesh(dem)
        dem.normals()
    direct = Terrain(values, dem.transform, dem.crs)
    assert np.isnan(direct.values[5, 5])


def test_sizes_that_cannot_fit_are_refused_before_any_work(view: tuple) -> None:
    dem, image, camera = view
    with pytest.raises(InputError, match=r"this grid is 3\.2e12 posts .* about \d+ TiB"):
        dem.regrid(res=(1e-7, 1e-7))
    with pytest.raises(InputError, match=r"this scene is 1e12 posts .*choose a smaller size"):
        make_scene("crater", size=10**6)
    with pytest.raises(InputError, match=r"hwin 2000 makes patches of 4,001 x 4,001 samples"):
        fit_dem(dem, [image, image], [camera, camera], FitOptions(hwin=2000))
    check_memory("a job", 1e6, "never refused")
    with pytest.raises(InputError, match="a job, about 888178419700125 PiB; this machine has"):
        check_memory("a job", 1e30, "")
    with pytest.raises(InputError):
        check_memory("a job", float("nan"), "")
    assert count_text(1.6e11) == "1.6e11" and count_text(12345) == "12,345"


def test_ranges_of_scenes_snapshots_and_studies(crater_dir: Path) -> None:
    from orthomvp.quality.eps_study import eps_study

    for kwargs, words in (
        ({"size": 0}, "scene size"),  # 0 no longer means the default
        ({"spacing": 0}, "post spacing"),
        ({"spacing": 1e-9}, "post spacing"),
        ({"gsd_ratio": float("nan")}, "GSD ratio"),
        ({"seed": -1}, "seed"),
    ):
        with pytest.raises(InputError, match=words):
            make_scene("crater", **kwargs)
    for kwargs in ({"rays": -1}, {"rays": 10**9}, {"azimuth": float("nan")}, {"view_camera": -1}):
        with pytest.raises(InputError):
            SnapshotOptions(**kwargs)
    for kwargs in ({"eps_values": (-1.0,)}, {"eps_values": (0.0,)}, {"noise": (float("nan"),)},
                   {"noise": (-5.0,)}, {"eps_values": ()}):  # fmt: skip
        with pytest.raises(InputError):
            eps_study(crater_dir, **kwargs)


def test_the_real_cause_is_named(view: tuple, crater_dir: Path) -> None:
    dem, image, camera = view
    # an Earth CRS on a lunar DEM: the cameras are inside the Earth, not "looking away"
    earth = replace(dem, crs=CRS.from_epsg(4326))
    with pytest.raises(GeometryError, match="do not sit above the DEM") as info:
        compute_visibility(earth, camera)
    assert "below its surface" in str(info.value) and "WGS 84" in str(info.value)
    # a camera looking away, seen through in a snapshot: not "without an image size"
    away = replace(camera, rotation=camera.rotation @ np.diag([1.0, -1.0, -1.0]))
    away = away.with_image_size(None, None)
    with pytest.raises(InputError, match="camera 1 looks away from the DEM"):
        snapshot(dem, cameras=[away], options=SnapshotOptions(view="from-camera"))


def test_a_window_too_large_for_the_images_is_named() -> None:
    """Posts seen by two images, but patches that leave the images: the window is the cause,
    not the visibility."""
    scene = make_scene("crater", size=16, spacing=80.0)
    cameras = list(scene.cameras.values())[:2]
    images = [scene.render(camera, 1) for camera in cameras]
    with pytest.raises(GeometryError, match=r"25 x 25 samples \(hwin 12\): choose a smaller hwin"):
        fit_dem(scene.terrain, images, cameras, FitOptions(hwin=12, levels=1))
