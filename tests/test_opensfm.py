"""OpenSfM's reconstruction.json, ODM's shots.geojson and cameras.json, ``mosaic --odm`` and
``check --odm``.

Expected pixels come from OpenSfM's documented model computed by hand here (normalised image
coordinates in units of max(width, height), the Brown and fisheye formulas), from Orthority's
own OpenSfM reader and cameras (when it is installed), from OpenCV's Rodrigues, and, for the
ODM dataset, from the same mosaic (and check) with the cameras given directly.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from orthomvp.camera import (
    FisheyeDistortion,
    NullDistortion,
    PinholeCamera,
    TsaiDistortion,
    read_camera,
    read_odm_shots,
    read_opensfm_cameras,
    write_json,
)
from orthomvp.camera.formats.opensfm import rodrigues, utm_crs
from orthomvp.errors import FormatError, InputError
from orthomvp.io.raster import read_image
from tests.test_cli import assert_one_line_error, run

# reference at 3 E, 0 N: UTM zone 31N's central meridian on the equator, easting 500,000 m,
# northing 0; altitude 10 m
REFERENCE = {"latitude": 0.0, "longitude": 3.0, "altitude": 10.0}
LOOK_DOWN = [math.pi, 0.0, 0.0]  # world-to-camera: camera x = east, y = south, z = down
# the camera centre at topocentric (10, 20, 100): t = -Rod(r) C = -(10, -20, -100)
TRANSLATION = [-10.0, 20.0, 100.0]
POINT = np.array([500_015.0, 30.0, 10.0])  # (5, 10, -100) from the centre (500010, 20, 110)
# its camera coordinates (5, -10, 100): normalised (x, y) = (0.05, -0.1)
X, Y = 0.05, -0.1


def reconstruction(camera: dict, shots: dict | None = None, **extra: object) -> list[dict]:
    """A reconstruction.json document with ``camera`` as "cam" and one shot "IMG_1.JPG"."""
    shot = {"rotation": LOOK_DOWN, "translation": TRANSLATION, "camera": "cam"}
    rec = {"cameras": {"cam": camera}, "shots": shots or {"IMG_1.JPG": shot}}
    return [rec | {"reference_lla": REFERENCE} | extra]


def write(path: Path, doc: object) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    return path


def one_camera(tmp_path: Path, camera: dict) -> PinholeCamera:
    path = write(tmp_path / "opensfm" / "reconstruction.json", reconstruction(camera))
    return read_camera(path, "images/IMG_1.JPG")


def test_perspective_by_hand(tmp_path: Path) -> None:
    spec = {"projection_type": "perspective", "width": 200, "height": 100, "focal": 0.5}
    cam = one_camera(tmp_path, spec | {"k1": 0.1, "k2": -0.02})
    np.testing.assert_allclose(cam.center, [500_010.0, 20.0, 110.0], atol=1e-6)
    r2 = X * X + Y * Y
    radial = 1 + 0.1 * r2 - 0.02 * r2 * r2
    # fu = 0.5 max(200, 100) = 100 px; principal point ((200 - 1) / 2, (100 - 1) / 2)
    expected = [100 * X * radial + 99.5, 100 * Y * radial + 49.5]
    np.testing.assert_allclose(cam.project(POINT)[0], expected, atol=1e-6)
    assert cam.project(POINT)[1] == pytest.approx(100.0)
    # no coefficients: no distortion model at all
    plain = one_camera(tmp_path / "plain", spec)
    assert isinstance(plain.distortion, NullDistortion)
    np.testing.assert_allclose(plain.project(POINT)[0], [104.5, 39.5], atol=1e-6)


def test_brown_by_hand_and_the_portrait_normalisation(tmp_path: Path) -> None:
    k1, k2, k3, p1, p2 = 0.1, -0.02, 0.003, 0.01, -0.005
    spec = {
        "projection_type": "brown",
        "width": 100,
        "height": 200,  # portrait: normalised by the height
        "focal_x": 0.5,
        "focal_y": 0.52,
        "c_x": 0.01,
        "c_y": -0.02,
        "k1": k1,
        "k2": k2,
        "k3": k3,
        "p1": p1,
        "p2": p2,
    }
    cam = one_camera(tmp_path, spec)
    assert isinstance(cam.distortion, TsaiDistortion)
    r2 = X * X + Y * Y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = X * radial + 2 * p1 * X * Y + p2 * (r2 + 2 * X * X)
    yd = Y * radial + p1 * (r2 + 2 * Y * Y) + 2 * p2 * X * Y
    expected = [200 * (0.5 * xd + 0.01) + 49.5, 200 * (0.52 * yd - 0.02) + 99.5]
    np.testing.assert_allclose(cam.project(POINT)[0], expected, atol=1e-6)


@pytest.mark.parametrize("kind", ["fisheye", "fisheye_opencv"])
def test_fisheye_by_hand(tmp_path: Path, kind: str) -> None:
    spec = {"projection_type": kind, "width": 200, "height": 100, "k1": 0.1, "k2": -0.05}
    spec |= {"focal": 0.5} if kind == "fisheye" else {"focal_x": 0.5, "focal_y": 0.5, "k4": 0.01}
    cam = one_camera(tmp_path, spec)
    assert isinstance(cam.distortion, FisheyeDistortion)
    r = math.hypot(X, Y)
    t = math.atan(r)
    k4 = 0.01 if kind == "fisheye_opencv" else 0.0
    td = t * (1 + 0.1 * t**2 - 0.05 * t**4 + k4 * t**8)
    expected = [100 * X * td / r + 99.5, 100 * Y * td / r + 49.5]
    np.testing.assert_allclose(cam.project(POINT)[0], expected, atol=1e-6)


def test_rodrigues_is_opencvs() -> None:
    rng = np.random.default_rng(3)
    for vector in [*rng.normal(size=(20, 3)), np.zeros(3), np.array([0.0, 0.0, 1e-9])]:
        np.testing.assert_allclose(rodrigues(vector), cv2.Rodrigues(vector)[0], atol=1e-14)


def test_utm_zone_rule() -> None:
    assert utm_crs(0.0, 3.0).to_epsg() == 32631
    assert utm_crs(-33.9, 18.4).to_epsg() == 32734
    assert utm_crs(24.68, 120.95).to_epsg() == 32651
    assert utm_crs(10.0, 180.0).to_epsg() == 32601  # wraps to zone 1


def test_picks_the_shot_by_stem_and_other_crs(tmp_path: Path) -> None:
    shot = {"rotation": LOOK_DOWN, "camera": "cam"}
    shots = {
        "a.JPG": shot | {"translation": TRANSLATION},
        "b.tif": shot | {"translation": [0.0, 0.0, 50.0]},
    }
    spec = {"projection_type": "perspective", "width": 200, "height": 100, "focal": 0.5}
    path = write(tmp_path / "rec.json", reconstruction(spec, shots))
    np.testing.assert_allclose(read_camera(path, "x/b.png").center, [500_000, 0, 60], atol=1e-6)
    np.testing.assert_allclose(read_camera(path, "a").center, [500_010, 20, 110], atol=1e-6)
    with pytest.raises(InputError, match="no camera for image 'c'"):
        read_camera(path, "c.jpg")
    with pytest.raises(InputError, match="holds 2 cameras"):
        read_camera(path)
    # the reference in another projected CRS: its coordinates there, plus the shot's offset
    cams = read_opensfm_cameras(path, crs="EPSG:32632")
    east, north = Transformer.from_crs(4979, 32632, always_xy=True).transform(3.0, 0.0)
    np.testing.assert_allclose(cams["a"].center, [east + 10, north + 20, 110], atol=1e-6)
    with pytest.raises(InputError, match="projected CRS"):
        read_opensfm_cameras(path, crs="EPSG:4326")


def shots_geojson(cameras: dict[str, PinholeCamera], focal: float) -> dict:
    """ODM's shots.geojson of ``cameras``: centre and world-to-camera angle-axis."""
    features = []
    for name, cam in cameras.items():
        props = {
            "filename": f"{name}.JPG",
            "focal": focal,
            "width": cam.width,
            "height": cam.height,
            "translation": cam.center.tolist(),
            "rotation": cv2.Rodrigues(cam.rotation.T)[0].ravel().tolist(),
        }
        geometry = {"type": "Point", "coordinates": [3.0, 0.0, 110.0]}
        features.append({"type": "Feature", "properties": props, "geometry": geometry})
    return {"type": "FeatureCollection", "features": features}


def test_odm_shots_and_cameras_json(tmp_path: Path) -> None:
    spec = {
        "projection_type": "brown",
        "width": 200,
        "height": 100,
        "focal_x": 0.5,
        "focal_y": 0.5,
        "k1": 0.1,
    }
    other = spec | {"width": 300, "height": 200}
    rec = write(tmp_path / "opensfm" / "reconstruction.json", reconstruction(spec))
    expected = read_opensfm_cameras(rec)
    write(tmp_path / "cameras.json", {"v2 a": spec, "v2 b": other})
    shots = write(tmp_path / "odm_report" / "shots.geojson", shots_geojson(expected, 0.5))
    got = read_camera(shots, "IMG_1.tif")  # cameras.json one directory up
    np.testing.assert_allclose(got.project(POINT)[0], expected["IMG_1"].project(POINT)[0])
    np.testing.assert_allclose(got.center, expected["IMG_1"].center)
    assert got.distortion == expected["IMG_1"].distortion
    # the interior given explicitly; a shot whose size matches no camera is refused
    write(tmp_path / "elsewhere" / "cams.json", {"v2 b": other})
    with pytest.raises(FormatError, match=r"features\[0\].properties: no camera of .*cams.json"):
        read_odm_shots(shots, interior=tmp_path / "elsewhere" / "cams.json")
    (tmp_path / "cameras.json").unlink()
    with pytest.raises(InputError, match=r"put ODM's cameras.json there \(or in Python, name"):
        read_camera(shots, "IMG_1")
    # cameras.json alone holds no pose
    lone = write(tmp_path / "lone" / "cameras.json", {"cam": spec})
    with pytest.raises(InputError, match="hold no camera position"):
        read_camera(lone)


def orthority_pixels(rec: Path, shot: str, points: np.ndarray) -> np.ndarray:
    """Orthority's pixels of world ``points`` (n, 3) for ``shot`` of ``rec``."""
    factory = pytest.importorskip("orthority.factory", reason="Orthority is not installed")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its "sensor_size not specified" warning
        camera = factory.FrameCameras(rec, rec).get(shot)
        return camera.world_to_pixel(points.T).T


@pytest.mark.parametrize(
    "spec",
    [
        {"projection_type": "perspective", "focal": 0.85, "k1": -0.1, "k2": 0.02},
        {
            "projection_type": "brown",
            "focal_x": 0.6665,
            "focal_y": 0.6671,
            "c_x": -0.0015,
            "c_y": 0.0047,
            "k1": -0.264,
            "k2": 0.1019,
            "k3": -0.0258,
            "p1": 0.00073,
            "p2": 0.00026,
        },
        {"projection_type": "fisheye", "focal": 0.4, "k1": -0.03, "k2": 0.004},
    ],
    ids=lambda spec: spec["projection_type"],
)
def test_agrees_with_orthority(tmp_path: Path, spec: dict) -> None:
    spec = spec | {"width": 1368, "height": 912}
    # a drone block near Hsinchu (UTM 51N), reference as ODM sets it
    shots = {
        "IMG_0142.JPG": {
            "rotation": [2.6378, 0.0466, -0.0111],
            "translation": [-74.06, -17.73, 222.57],
            "camera": "cam",
        },
        "IMG_0018.JPG": {
            "rotation": [1.8846, -1.9859, 0.5506],
            "translation": [-71.76, 195.50, 100.90],
            "camera": "cam",
        },
    }
    rec = reconstruction(spec, shots)
    rec[0]["reference_lla"] = {"latitude": 24.6809, "longitude": 120.9506, "altitude": 0.0}
    path = write(tmp_path / "reconstruction.json", rec)
    rng = np.random.default_rng(1)
    for shot in shots:
        cam = read_camera(path, shot)
        uv = rng.uniform([0, 0], [1367, 911], (400, 2))
        origins, directions = cam.ray(uv)
        points = origins + directions * rng.uniform(50, 300, (400, 1))
        theirs = orthority_pixels(path, shot, points)
        ours = cam.project(points)[0]
        assert np.abs(ours - theirs).max() < 1e-6
        np.testing.assert_allclose(ours, uv, atol=1e-6)


@pytest.mark.parametrize(
    ("doc", "words"),
    [
        ('[{\n  "cameras": {,}', ["invalid JSON", "line 2"]),
        ({"cameras": {}}, ["expected a JSON list"]),
        ([{"cameras": {}, "shots": {}}], ["[0]: missing key 'reference_lla'"]),
        (
            reconstruction({"projection_type": "spherical", "width": 2, "height": 1}),
            ["[0].cameras['cam'].projection_type: 'spherical' is not supported"],
        ),
        (
            reconstruction({"projection_type": "perspective", "width": 2, "height": 1}),
            ["[0].cameras['cam']: missing key 'focal'"],
        ),
        (
            reconstruction(
                {"projection_type": "perspective", "width": 2, "height": 1, "focal": 1, "p1": 0}
            ),
            ["[0].cameras['cam'].p1: perspective cameras have no parameter 'p1'"],
        ),
        (
            reconstruction({"projection_type": "brown", "width": 2.5, "height": 1, "focal": 1}),
            ["[0].cameras['cam'].width: 2.5 is not a positive integer"],
        ),
        (
            reconstruction(
                {"projection_type": "perspective", "width": 2, "height": 1, "focal": 1},
                {"a": {"rotation": [0, 0, 0], "camera": "cam"}},
            ),
            ["[0].shots['a']: missing key 'translation'"],
        ),
        (
            reconstruction(
                {"projection_type": "perspective", "width": 2, "height": 1, "focal": 1},
                {"a": {"rotation": [0, "x", 0], "translation": [0, 0, 0], "camera": "cam"}},
            ),
            ["[0].shots['a'].rotation[1]: 'x' is not a finite number"],
        ),
        (
            reconstruction(
                {"projection_type": "perspective", "width": 2, "height": 1, "focal": 1},
                {"a": {"rotation": [0, 0, 0], "translation": [0, 0, 0], "camera": "other"}},
            ),
            ["[0].shots['a'].camera: 'other' is not in [0].cameras"],
        ),
        (
            reconstruction(
                {"projection_type": "perspective", "width": 2, "height": 1, "focal": -1}
            ),
            ["[0].shots['IMG_1.JPG']: fu must be positive"],
        ),
    ],
)
def test_bad_reconstructions(tmp_path: Path, doc: object, words: list[str]) -> None:
    path = tmp_path / "reconstruction.json"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    with pytest.raises(FormatError) as info:
        read_opensfm_cameras(path)
    for word in [str(path), *words]:
        assert word in str(info.value)


def test_bad_reconstruction_through_read_camera(tmp_path: Path) -> None:
    # recognised by its content, so the reconstruction reader reports the broken key
    doc = reconstruction({"projection_type": "dual", "width": 2, "height": 1, "focal": 1})
    path = write(tmp_path / "reconstruction.json", doc)
    with pytest.raises(FormatError, match="'dual' is not supported"):
        read_camera(path, "IMG_1")


# ------------------------------------------------------------------- an ODM dataset
UTM = "EPSG:32631"
E0, N0 = 500_000.0, 4_000_000.0  # the map position of the scene's centre
RECONSTRUCTION = "opensfm/reconstruction.json"


def map_cameras(scene: object, names: tuple[str, ...]) -> dict[str, PinholeCamera]:
    """The ``scene``'s cameras ``names`` moved into the map frame of :data:`UTM` (east, north,
    up at the tile centre -> E0 + x, N0 + y, z), brought 100 times closer along the optical
    axis with a focal length 100 times shorter (about the same view of the ground near the
    axis; the map frame wants cameras within a few DEM extents), with a little radial distortion."""
    from orthomvp.synthetic.surface import MOON_RADIUS, local_frame

    up, east, north = local_frame(scene.surface.lon0, scene.surface.lat0)
    to_map = np.stack([east, north, up])
    out = {}
    for name in names:
        cam = scene.cameras[name]
        centre = to_map @ (cam.center - MOON_RADIUS * up)
        rotation = to_map @ cam.rotation
        axis = rotation[:, 2]
        ground = centre + axis * (-centre[2] / axis[2])
        out[name] = PinholeCamera(
            fu=cam.fu / cam.pitch / 100,
            fv=cam.fv / cam.pitch / 100,
            cu=cam.cu / cam.pitch,
            cv=cam.cv / cam.pitch,
            center=np.array([E0, N0, 0.0]) + ground + (centre - ground) / 100,
            rotation=rotation,
            distortion=TsaiDistortion(k1=-0.01, k2=0.0, p1=0.0, p2=0.0),
            width=cam.width,
            height=cam.height,
        )
    return out


def to_opensfm(cameras: dict[str, PinholeCamera]) -> list[dict]:
    """A reconstruction.json of map-frame ``cameras`` (one OpenSfM camera each), reference
    at (E0, N0, 0) in :data:`UTM`."""
    lon, lat = Transformer.from_crs(UTM, 4979, always_xy=True).transform(E0, N0)
    ref = np.array([E0, N0, 0.0])
    rec: dict = {"cameras": {}, "shots": {}}
    for name, cam in cameras.items():
        big = max(cam.width, cam.height)
        rec["cameras"][f"v2 {name}"] = {
            "projection_type": "brown",
            "width": cam.width,
            "height": cam.height,
            "focal_x": cam.fu / big,
            "focal_y": cam.fv / big,
            "c_x": (cam.cu - (cam.width - 1) / 2) / big,
            "c_y": (cam.cv - (cam.height - 1) / 2) / big,
            "k1": cam.distortion.k1,
        }
        world_to_camera = cam.rotation.T
        rec["shots"][f"{name}.tif"] = {
            "rotation": Rotation.from_matrix(world_to_camera).as_rotvec().tolist(),
            "translation": (-world_to_camera @ (cam.center - ref)).tolist(),
            "camera": f"v2 {name}",
        }
    rec["reference_lla"] = {"latitude": lat, "longitude": lon, "altitude": 0.0}
    return [rec]


@pytest.fixture(scope="module")
def odm_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, PinholeCamera]]:
    """A tiny ODM dataset made from the crater scene: odm_dem/dsm.tif (the scene's heights on
    a 40 m UTM grid), images/*.tif (rendered), opensfm/reconstruction.json, and one image that
    was not reconstructed; returns it and the map-frame cameras."""
    from orthomvp.synthetic import make_scene

    scene = make_scene("crater", size=32, spacing=40.0)
    root = tmp_path_factory.mktemp("odm")
    cameras = map_cameras(scene, ("nadir", "oblique"))
    (root / "odm_dem").mkdir()
    size = scene.terrain.shape[0]
    transform = Affine(40.0, 0, E0 - 20.0 * size, 0, -40.0, N0 + 20.0 * size)
    profile = {"driver": "GTiff", "height": size, "width": size, "count": 1, "dtype": "float32"}
    with rasterio.open(
        root / "odm_dem" / "dsm.tif", "w", **profile, crs=UTM, transform=transform
    ) as dst:
        dst.write(scene.terrain.values.astype(np.float32), 1)
    (root / "images").mkdir()
    for name in (*cameras, "stray"):
        image = scene.render(scene.cameras["nadir" if name == "stray" else name], supersample=1)
        rows, cols = image.shape
        profile = {"driver": "GTiff", "height": rows, "width": cols, "count": 1, "dtype": "float32"}
        with warnings.catch_warnings():  # the images have no georeferencing
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(root / "images" / f"{name}.tif", "w", **profile) as dst:
                dst.write(image.astype(np.float32), 1)
    write(root / "opensfm" / "reconstruction.json", to_opensfm(cameras))
    return root, cameras


@pytest.mark.slow
def test_mosaic_odm_equals_the_cameras_given_directly(
    odm_dir: tuple[Path, dict[str, PinholeCamera]], tmp_path: Path
) -> None:
    root, cameras = odm_dir
    odm, direct, through = (tmp_path / f"{n}.tif" for n in ("odm", "direct", "through"))
    proc = run("mosaic", "--odm", str(root), "-o", str(odm), "--source", str(tmp_path / "s.tif"))
    assert proc.returncode == 0, proc.stderr
    assert "1 images in" in proc.stderr and "stray.tif" in proc.stderr  # not reconstructed
    pairs, recs = [], []
    for name, cam in cameras.items():
        write_json(cam, tmp_path / f"{name}.json")
        pairs += [str(root / "images" / f"{name}.tif"), str(tmp_path / f"{name}.json")]
        recs += [str(root / "images" / f"{name}.tif"), str(root / RECONSTRUCTION)]
    dsm = str(root / "odm_dem" / "dsm.tif")
    assert run("mosaic", dsm, *pairs, "-o", str(direct)).returncode == 0
    assert run("mosaic", dsm, *recs, "-o", str(through)).returncode == 0
    a, b, c = (read_image(p)[0] for p in (odm, direct, through))
    filled = np.isfinite(b)
    assert filled.mean() > 0.5  # the views see most of the DEM
    for other in (a, c):
        assert np.array_equal(np.isfinite(other), filled)
        np.testing.assert_allclose(other[filled], b[filled], atol=1e-4)
    with rasterio.open(odm) as src:
        assert src.crs.to_epsg() == 32631


def test_mosaic_odm_bad_datasets(
    odm_dir: tuple[Path, dict[str, PinholeCamera]], tmp_path: Path
) -> None:
    root, _ = odm_dir
    out = tmp_path / "m.tif"
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    write(empty / RECONSTRUCTION, to_opensfm({}))
    proc = run("mosaic", "--odm", str(empty), "-o", str(out))
    assert_one_line_error(proc, str(empty), "no DEM", "odm_dem/dsm.tif", "--dsm")
    proc = run("mosaic", "--odm", str(tmp_path / "nowhere"), "-o", str(out))
    assert_one_line_error(proc, "nowhere", "needs an ODM dataset directory")
    dsm = str(root / "odm_dem" / "dsm.tif")
    assert_one_line_error(run("mosaic", dsm, "--odm", str(root), "-o", str(out)), "give no DEM")
    assert_one_line_error(run("mosaic", "-o", str(out)), "or --odm DIR")
    assert not out.exists()


def test_check_odm_equals_the_views_given_directly(
    odm_dir: tuple[Path, dict[str, PinholeCamera]], tmp_path: Path
) -> None:
    root, cameras = odm_dir
    odm, direct = tmp_path / "odm", tmp_path / "direct"
    proc = run("check", "--odm", str(root), "-o", str(odm), "--eps", "2", "4")
    assert proc.returncode == 0, proc.stderr
    assert "1 images in" in proc.stderr and "stray.tif" in proc.stderr  # not reconstructed
    assert "orthomvp: eps 2 posts: median NCC" in proc.stdout
    pairs = []
    for name in sorted(cameras):  # ODM's order: the images sorted by name
        pairs += [str(root / "images" / f"{name}.tif"), str(root / RECONSTRUCTION)]
    dsm = str(root / "odm_dem" / "dsm.tif")
    proc = run("-q", "check", dsm, *pairs, "-o", str(direct), "--eps", "2", "4")
    assert proc.returncode == 0, proc.stderr
    table = (odm.with_suffix(".csv")).read_text()
    assert table == direct.with_suffix(".csv").read_text()
    visible = [line for line in table.splitlines() if line.startswith("2,all,all,visible,0,inf")]
    assert len(visible) == 1 and int(visible[0].split(",")[7]) > 200  # posts scored


def test_check_odm_bad_datasets(
    odm_dir: tuple[Path, dict[str, PinholeCamera]], tmp_path: Path
) -> None:
    root, _ = odm_dir
    out = tmp_path / "out"
    out.mkdir()
    chk = str(out / "chk")
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    write(empty / RECONSTRUCTION, to_opensfm({}))
    proc = run("check", "--odm", str(empty), "-o", chk)
    assert_one_line_error(proc, str(empty), "no DEM", "odm_dem/dsm.tif", "--dsm")
    blind = tmp_path / "blind"  # a DEM, no cameras
    (blind / "odm_dem").mkdir(parents=True)
    dsm = root / "odm_dem" / "dsm.tif"
    (blind / "odm_dem" / "dsm.tif").write_bytes(dsm.read_bytes())
    proc = run("check", "--odm", str(blind), "-o", chk)
    assert_one_line_error(proc, str(blind), "no cameras", RECONSTRUCTION)
    lost = tmp_path / "lost"  # a DEM without a CRS
    (lost / "odm_dem").mkdir(parents=True)
    with rasterio.open(dsm) as src:
        profile, values = src.profile, src.read()
    profile.pop("crs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(lost / "odm_dem" / "dsm.tif", "w", **profile) as dst:
            dst.write(values)
    write(lost / RECONSTRUCTION, [])
    proc = run("check", "--odm", str(lost), "-o", chk)
    assert_one_line_error(proc, "dsm.tif", "the DEM has no CRS", "--dem-crs")
    proc = run("check", "--odm", str(tmp_path / "nowhere"), "-o", chk)
    assert_one_line_error(proc, "nowhere", "needs an ODM dataset directory")
    assert_one_line_error(run("check", str(dsm), "--odm", str(root), "-o", chk), "give no DEM")
    assert_one_line_error(run("check", "-o", chk), "or --odm DIR")
    assert not list(out.iterdir())
