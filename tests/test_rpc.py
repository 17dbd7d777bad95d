"""Tests of RPC cameras (issue 14): the RPC00B model against GDAL's own RPC transformer
(rasterio.transform.RPCTransformer, an independent implementation), the four RPC file formats
against each other and against GDAL's readers, the world-frame bindings against pyproj, rays,
crop, GSD, the ground control points of ../shared/data/rpc-quickbird, and bad input.

GDAL's RPC transformer reports pixel corners: its (col, row) are RPC's (sample, line) + 0.5,
orthomvp's (u, v) + 0.5.
"""

from __future__ import annotations

import json
import pickle
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
import yaml
from conftest import shared
from pyproj import CRS, Transformer
from rasterio.errors import NotGeoreferencedWarning
from rasterio.rpc import RPC
from rasterio.transform import RPCTransformer

from orthomvp.camera import (
    Camera,
    Rpc,
    RpcCamera,
    check_image,
    load_view,
    read_camera,
    world_crs,
)
from orthomvp.camera.rpc_model import COEFFICIENTS, OFFSETS_SCALES, RPC_KEYS
from orthomvp.errors import FormatError, InputError
from orthomvp.geometry.terrain import Terrain

QB = "rpc-quickbird"
IMAGE = "qb2_basic1b.tif"
UNDULATION = 28.0  # m, EGM2008 geoid height near the GCPs (GCP minus DEM heights: 27..29 m)

_RPB_NAMES = (
    "lineOffset sampOffset latOffset longOffset heightOffset lineScale sampScale latScale "
    "longScale heightScale lineNumCoef lineDenCoef sampNumCoef sampDenCoef"
).split()
_UNITS = {"line": "pixels", "samp": "pixels", "lat": "degrees", "long": "degrees"}


def synthetic_rpc() -> dict[str, object]:
    """A made-up RPC (no data needed): nearly affine, with small terms of every degree."""
    rng = np.random.default_rng(1)
    small = rng.normal(scale=1e-5, size=(4, 20))
    num_l, den_l, num_s, den_s = small
    num_l[[0, 1, 2, 3]] = [0.01, -0.05, -1.02, 0.03]
    num_s[[0, 1, 2, 3]] = [-0.02, 1.01, 0.04, -0.02]
    den_l[0] = den_s[0] = 1.0
    return dict(
        line_off=500.0, samp_off=400.0, lat_off=10.0, long_off=20.0, height_off=300.0,
        line_scale=520.0, samp_scale=420.0, lat_scale=0.05, long_scale=0.05, height_scale=400.0,
        line_num_coeff=num_l.tolist(), line_den_coeff=den_l.tolist(),
        samp_num_coeff=num_s.tolist(), samp_den_coeff=den_s.tolist(),
    )  # fmt: skip


def flat(values: dict[str, object]) -> np.ndarray:
    """The RPC parameters of a mapping as one array (:data:`RPC_KEYS` order)."""
    return np.hstack([values[key] for key in RPC_KEYS])


def quickbird() -> tuple[RPC, RpcCamera]:
    """rasterio's RPC of the QuickBird image, and ours read from the same file."""
    path = shared(QB, IMAGE)
    with rasterio.open(path) as ds:
        rpc = ds.rpcs
    return rpc, read_camera(path)


def rpc_txt(values: dict[str, object]) -> str:
    """``values`` as a DigitalGlobe/GDAL _RPC.TXT file."""
    out = []
    for key in OFFSETS_SCALES:
        unit = _UNITS.get(key.split("_")[0], "meters")
        out.append(f"{key.upper()}: {values[key]!r} {unit}")
    for key in COEFFICIENTS:
        out += [f"{key.upper()}_{i}: {c!r}" for i, c in enumerate(values[key], 1)]
    return "\n".join(out) + "\n"


def rpc_rpb(values: dict[str, object]) -> str:
    """``values`` as a DigitalGlobe .RPB file."""
    out = ['satId = "QB02";', 'bandId = "P";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE"]
    out += ["\terrBias = 12.15;", "\terrRand = 0.3;"]
    for key, name in zip(OFFSETS_SCALES + COEFFICIENTS, _RPB_NAMES, strict=True):
        if key in COEFFICIENTS:
            body = ",\n\t\t\t".join(f"{c!r}" for c in values[key])
            out.append(f"\t{name} = (\n\t\t\t{body});")
        else:
            out.append(f"\t{name} = {values[key]!r};")
    return "\n".join(out + ["END_GROUP = IMAGE", "END;"]) + "\n"


def rpc_yaml(values: dict[str, object], name: str = IMAGE, size: object = (850, 1450)) -> str:
    """``values`` as Orthority's rpc_param.yaml for the image ``name``."""
    return yaml.safe_dump({name: {"im_size": list(size), "rpc": values}})


def write_tiff(path: Path, rpc: dict[str, object] | None, size: tuple[int, int] = (40, 30)) -> Path:
    """A small uint8 GeoTIFF with ``rpc`` in its metadata (none when None)."""
    width, height = size
    profile = dict(driver="GTiff", width=width, height=height, count=1, dtype="uint8")
    if rpc is not None:
        profile["rpcs"] = RPC(**rpc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as ds:
            ds.write(np.arange(width * height, dtype=np.uint8).reshape(1, height, width))
    return path


# ------------------------------------------------------------------ against GDAL's transformer
@pytest.mark.realdata
def test_project_matches_gdal() -> None:
    gdal_rpc, camera = quickbird()
    r = gdal_rpc
    lon, lat, h = np.meshgrid(
        np.linspace(r.long_off - r.long_scale, r.long_off + r.long_scale, 21),
        np.linspace(r.lat_off - r.lat_scale, r.lat_off + r.lat_scale, 21),
        np.linspace(r.height_off - r.height_scale, r.height_off + r.height_scale, 5),
        indexing="ij",
    )
    with RPCTransformer(gdal_rpc) as t:
        rows, cols = t.rowcol(lon.ravel(), lat.ravel(), zs=h.ravel(), op=lambda x: x)
    truth = np.stack([cols, rows], axis=-1).reshape(lon.shape + (2,)) - 0.5
    direct = camera.rpc.project(lon, lat, h)
    uv, depth = camera.project(camera.to_world(lon, lat, h))  # through WGS84 geocentric metres
    err_direct, err_world = np.abs(direct - truth).max(), np.abs(uv - truth).max()
    print(f"project vs GDAL: max {err_direct:.2g} px (geodetic), {err_world:.2g} px (ECEF)")
    assert err_direct < 0.01 and err_world < 0.01
    assert (depth[..., :-1] > 0).all()  # below the top height (the last level is the top)


@pytest.mark.realdata
def test_image_to_ground_matches_gdal() -> None:
    gdal_rpc, camera = quickbird()
    r = gdal_rpc
    u, v, h = np.meshgrid(
        np.linspace(-0.5, camera.width - 0.5, 17),
        np.linspace(-0.5, camera.height - 0.5, 23),
        np.linspace(r.height_off - r.height_scale, r.height_off + r.height_scale, 5),
        indexing="ij",
    )
    lon, lat = camera.rpc.ground(np.stack([u, v], axis=-1), h)
    # GDAL stops iterating at 0.1 px by default (5e-8 degrees off here): ask it for 1e-10 px
    with RPCTransformer(gdal_rpc, RPC_PIXEL_ERROR_THRESHOLD=1e-10, RPC_MAX_ITERATIONS=100) as t:
        xs, ys = t.xy(v.ravel(), u.ravel(), zs=h.ravel(), offset="center")
    err = max(
        np.abs(np.reshape(xs, lon.shape) - lon).max(),
        np.abs(np.reshape(ys, lat.shape) - lat).max(),
    )
    print(f"image to ground vs GDAL: max {err:.2g} degrees")
    assert err < 1e-8
    back = camera.rpc.project(lon, lat, h)  # and it is the RPC's own inverse
    assert np.abs(back - np.stack([u, v], axis=-1)).max() < 1e-6


# ------------------------------------------------------------------ the file formats
def test_every_format_gives_the_same_rpc(tmp_path: Path) -> None:
    values = synthetic_rpc()
    tif = write_tiff(tmp_path / "scene.tif", values)
    (tmp_path / "scene_RPC.TXT").write_text(rpc_txt(values))
    (tmp_path / "scene.RPB").write_text(rpc_rpb(values))
    (tmp_path / "rpc_param.yaml").write_text(rpc_yaml(values, "scene.tif", (40, 30)))
    cameras = [
        read_camera(tif),
        read_camera(tmp_path / "scene_RPC.TXT"),
        read_camera(tmp_path / "scene.RPB"),
        read_camera(tmp_path / "rpc_param.yaml", tif),
        read_camera(tmp_path / "rpc_param.yaml"),  # one image: no name needed
    ]
    assert all(isinstance(c, RpcCamera) and isinstance(c, Camera) for c in cameras)
    for camera in cameras:
        assert camera.rpc.to_dict() == Rpc.from_mapping(values).to_dict()
    assert [(c.width, c.height) for c in cameras] == [(40, 30), (None, None), (None, None)] + [
        (40, 30)
    ] * 2
    # the image's camera is the image, and the text files take its size through load_view
    for camera_file in (tif, tmp_path / "scene.RPB", tmp_path / "rpc_param.yaml"):
        image, camera = load_view(tif, camera_file)
        assert image.shape == (1, 30, 40) and (camera.width, camera.height) == (40, 30)


@pytest.mark.realdata
def test_quickbird_formats_agree(tmp_path: Path) -> None:
    gdal_rpc, camera = quickbird()
    yaml_camera = read_camera(shared(QB, "rpc_param.yaml"), IMAGE)
    assert yaml_camera.rpc.to_dict() == camera.rpc.to_dict()
    np.testing.assert_array_equal(flat(camera.rpc.to_dict()), flat(gdal_rpc.to_dict()))
    assert (yaml_camera.width, yaml_camera.height) == (camera.width, camera.height) == (850, 1450)
    values = camera.rpc.to_dict()
    (tmp_path / "a_RPC.TXT").write_text(rpc_txt(values))
    (tmp_path / "a.RPB").write_text(rpc_rpb(values))
    for name in ("a_RPC.TXT", "a.RPB"):
        assert read_camera(tmp_path / name).rpc.to_dict() == values


@pytest.mark.parametrize("sidecar", ["scene_RPC.TXT", "scene.RPB"])
def test_gdal_reads_the_text_files_alike(tmp_path: Path, sidecar: str) -> None:
    """The files these tests write are what GDAL itself reads: beside an image without RPC
    metadata, GDAL takes its RPCs from them, and so does our GeoTIFF reader."""
    values = synthetic_rpc()
    tif = write_tiff(tmp_path / "scene.tif", None)
    text = rpc_txt(values) if sidecar.endswith("TXT") else rpc_rpb(values)
    (tmp_path / sidecar).write_text(text)
    with rasterio.open(tif) as ds:
        gdal = ds.rpcs.to_dict()
    ours = read_camera(tmp_path / sidecar).rpc.to_dict()
    np.testing.assert_allclose(flat(gdal), flat(ours), rtol=1e-14)
    np.testing.assert_allclose(flat(read_camera(tif).rpc.to_dict()), flat(ours), rtol=1e-14)


# ------------------------------------------------------------------ geometry
def rays_project_back(camera: RpcCamera) -> float:
    """Check the rays of a grid of pixels of ``camera``: unit directions, origins at ``top``,
    both ends (``top``, ``bottom``) projecting back to the pixel exactly and with depth = the
    distance along the ray, inner points to within the RPC's own line-of-sight curvature (the
    returned worst pixel error), their depth to within that error times the GSD."""
    uv = np.stack(
        np.meshgrid(np.linspace(0, camera.width - 1, 9), np.linspace(0, camera.height - 1, 11)),
        axis=-1,
    )
    origins, directions = camera.ray(uv)
    assert np.allclose(np.linalg.norm(directions, axis=-1), 1.0)
    np.testing.assert_array_equal(camera.origins(uv), origins)
    _, _, top = camera.to_geodetic(origins)
    np.testing.assert_allclose(top, camera.top, atol=1e-6)
    length = np.linalg.norm(origins - _low(camera, uv), axis=-1)
    worst = 0.0
    for fraction in (0.0, 0.25, 0.5, 0.75, 1.0):
        t = fraction * length
        xyz = origins + t[..., None] * directions
        back, depth = camera.project(xyz)
        error = np.abs(back - uv).max(axis=-1)
        if fraction in (0.0, 1.0):
            assert error.max() < 1e-6
            np.testing.assert_allclose(depth, t, atol=1e-5)
        else:
            assert (np.abs(depth - t) <= 2 * error * camera.gsd(xyz) + 1e-5).all()
        worst = max(worst, float(error.max()))
    return worst


def test_rays_project_back_to_their_pixels() -> None:
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()), width=800, height=1000)
    assert camera.top == 300.0 + 400.0 and camera.bottom == 300.0 - 400.0
    worst = rays_project_back(camera)
    print(f"synthetic RPC: points on rays project back within {worst:.2g} px")
    assert worst < 0.02  # its made-up height terms bend the line of sight this much


@pytest.mark.realdata
def test_quickbird_rays_are_straight() -> None:
    _, camera = quickbird()
    worst = rays_project_back(camera)
    print(f"QuickBird RPC: points on rays project back within {worst:.2g} px")
    assert worst < 1e-3


def _low(camera: RpcCamera, uv: np.ndarray) -> np.ndarray:
    """The world points imaged at ``uv`` at height ``bottom``, independently of ray()."""
    lon, lat = camera.rpc.ground(uv, camera.bottom)
    return camera.to_world(lon, lat, camera.bottom)


def test_ray_heights_are_settable_and_checked() -> None:
    rpc = Rpc.from_mapping(synthetic_rpc())
    camera = RpcCamera(rpc, top=850.0, bottom=-200.0)
    _, _, h = camera.to_geodetic(camera.origins(np.array([[10.0, 20.0]])))
    assert h == pytest.approx([850.0], abs=1e-6)
    with pytest.raises(InputError, match="top"):
        RpcCamera(rpc, top=0.0, bottom=10.0)
    with pytest.raises(InputError, match=r"top \(5000.0 m\) lies beyond the RPC's heights "):
        RpcCamera(rpc, top=5000.0)
    assert RpcCamera(rpc, top=5000.0, margin=12).top == 5000.0


def test_outside_the_domain_is_nan() -> None:
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()), margin=0.5)
    lon = np.array([20.0, 20.0 + 0.05 * 1.4, 20.0 + 0.05 * 1.6, 20.0, np.nan])
    height = np.array([300.0, 300.0, 300.0, 300.0 + 400 * 1.6, 300.0])
    uv, depth = camera.project(camera.to_world(lon, np.full(5, 10.0), height))
    assert np.isfinite(uv[:2]).all() and np.isnan(uv[2:]).all()
    assert (depth[:2] > 0).all() and np.isnan(depth[2:]).all()
    far = camera.rpc.project(20.0 + 0.05 * 1.6, 10.0, 300.0)  # a pixel whose ground is outside
    assert np.isnan(camera.ray(far[None])[0]).all()


def test_crop_shifts_pixels() -> None:
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()), width=800, height=1000)
    crop = camera.crop(100, -30, 50, 60)
    assert (crop.width, crop.height) == (50, 60)
    lon, lat = np.meshgrid(np.linspace(19.97, 20.03, 5), np.linspace(9.97, 10.03, 5))
    xyz = camera.to_world(lon, lat, np.full(lon.shape, 250.0))
    np.testing.assert_allclose(crop.project(xyz)[0], camera.project(xyz)[0] - (100, -30))
    uv = camera.project(xyz)[0]
    for a, b in zip(crop.ray(uv - (100, -30)), camera.ray(uv), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    assert camera.with_image_size(3, 4).in_image(np.array([[2.5, 3.5], [2.6, 0.0]])).tolist() == [
        True,
        False,
    ]


def test_gsd_against_ground_pixel_footprint() -> None:
    """GSD against the footprint of one pixel on the ground: the ground points of a pixel's
    neighbours at one height span a parallelogram whose area, times the cosine of the angle
    between the ray and the vertical, is the area perpendicular to the ray."""
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()))
    uv = np.array([[400.0, 500.0], [10.0, 20.0], [700.0, 900.0]])
    lon, lat = camera.rpc.ground(uv, 250.0)
    xyz = camera.to_world(lon, lat, 250.0)
    steps = [camera.to_world(*camera.rpc.ground(uv + d, 250.0), 250.0) for d in ((1, 0), (0, 1))]
    up = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)  # near enough for the cosine
    _, d = camera.ray(uv)
    area = np.linalg.norm(np.cross(steps[0] - xyz, steps[1] - xyz), axis=-1)
    expected = np.sqrt(area * np.abs(np.einsum("ij,ij->i", d, up)))
    np.testing.assert_allclose(camera.gsd(xyz), expected, rtol=0.01)


@pytest.mark.realdata
def test_map_and_body_frames() -> None:
    """The DEM's posts, through Terrain.to_world in either world frame and the camera bound to
    it, land on the pixels that pyproj's geodetic coordinates of the same posts give."""
    _, camera = quickbird()
    posts = {}
    for frame in ("map", "body"):
        terrain = Terrain.read(
            shared("ngi-aerial", "dem.tif"), world=frame, vertical_datum="ignore"
        )
        bound = replace_offset(camera.bind(terrain), UNDULATION)  # the camera takes the geoid
        assert bound.crs == world_crs(terrain)
        r, c = np.mgrid[0 : terrain.shape[0] : 25, 0 : terrain.shape[1] : 25]
        h = terrain.values[r, c]
        posts[frame] = bound.project(terrain.to_world(c, r, h))
    x, y = terrain.pixel_to_crs(c, r)
    lon, lat = Transformer.from_crs(terrain.crs, "EPSG:4326", always_xy=True).transform(x, y)
    truth = camera.rpc.project(lon, lat, h + UNDULATION)
    for frame, (uv, depth) in posts.items():
        ok = np.isfinite(h)
        assert np.abs(uv[ok] - truth[ok]).max() < 1e-6, frame
        assert (depth[ok] > 0).all()
    np.testing.assert_allclose(posts["map"][1], posts["body"][1], rtol=2e-3)  # map scale 1.0..1.001
    # map frame: world z is the DEM's (orthometric) height, the top minus the undulation
    map_camera = replace_offset(
        camera.bind(Terrain.read(shared("ngi-aerial", "dem.tif"), world="map")), UNDULATION
    )
    assert map_camera.origins(np.array([[400.0, 700.0]]))[0, 2] == pytest.approx(
        camera.top - UNDULATION
    )


def replace_offset(camera: RpcCamera, offset: float) -> RpcCamera:
    """``camera`` with world heights ``offset`` metres below ellipsoidal ones."""
    from dataclasses import replace

    return replace(camera, height_offset=offset)


def test_world_crs_must_be_cartesian() -> None:
    rpc = Rpc.from_mapping(synthetic_rpc())
    with pytest.raises(InputError, match="geocentric or projected"):
        RpcCamera(rpc, crs="EPSG:4326")
    with pytest.raises(InputError, match="cannot understand"):
        RpcCamera(rpc, crs="no such CRS")
    utm = RpcCamera(rpc, crs=CRS.from_epsg(32634))  # UTM 34N: lon 21 is its central meridian
    xyz = utm.to_world(21.0, 10.0, 100.0)
    assert xyz[0] == pytest.approx(500_000.0) and xyz[2] == pytest.approx(100.0)


def test_pickles_for_worker_processes() -> None:
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()), crs="EPSG:32634", height_offset=5.0)
    xyz = camera.to_world(20.01, 10.01, 200.0)
    camera.project(xyz)  # builds the cached transformer
    again = pickle.loads(pickle.dumps(camera))
    np.testing.assert_array_equal(again.project(xyz)[0], camera.project(xyz)[0])


# ------------------------------------------------------------------ ground control points
@pytest.mark.realdata
def test_gcp_residuals() -> None:
    """Orthority's GCPs (geometry: WGS84 lon, lat, ellipsoidal height; ``ji``: pixel with
    integer values at pixel centres, as ours). The RPC is the raw one of a basic 1B product
    (err_bias 12.15 m): residuals of a few pixels, nearly one common shift, are expected."""
    _, camera = quickbird()
    features = json.loads(shared(QB, "gcps.geojson").read_text())["features"]
    lon, lat, h = np.array([f["geometry"]["coordinates"] for f in features]).T
    measured = np.array([f["properties"]["ji"] for f in features])
    residual = camera.project(camera.to_world(lon, lat, h))[0] - measured
    norm = np.linalg.norm(residual, axis=-1)
    mean = residual.mean(axis=0)
    print(
        f"GCP residuals (px): {np.round(norm, 2).tolist()}; mean shift ({mean[0]:.2f}, "
        f"{mean[1]:.2f}), spread about it {np.linalg.norm(residual - mean, axis=-1).max():.2f}"
    )
    assert len(features) == 5 and norm.max() < 5.0
    assert np.linalg.norm(residual - mean, axis=-1).max() < 0.5  # a bias, not a bad model


# ------------------------------------------------------------------ bad input
def _bad_yaml(values: dict[str, object]) -> str:
    return rpc_yaml(values, "scene.tif")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda v: v.pop("line_num_coeff"), "missing line_num_coeff"),
        (lambda v: v.update(samp_den_coeff=v["samp_den_coeff"][:19]), "samp_den_coeff must be 20"),
        (lambda v: v.update(lat_off="north"), "'scene.tif': lat_off: 'north' is not a number"),
        (lambda v: v["line_den_coeff"].__setitem__(3, "x"), "line_den_coeff: 'x' is not a number"),
        (lambda v: v.update(long_scale=0), "long_scale must not be 0"),
    ],
)
def test_bad_orthority_rpc(tmp_path: Path, change: object, message: str) -> None:
    values = synthetic_rpc()
    change(values)  # type: ignore[operator]
    path = tmp_path / "rpc_param.yaml"
    path.write_text(_bad_yaml(values))
    with pytest.raises(FormatError, match=message) as err:
        read_camera(path, "scene.tif")
    assert str(path) in str(err.value)


def test_bad_text_files(tmp_path: Path) -> None:
    values = synthetic_rpc()
    txt = tmp_path / "a_RPC.TXT"
    txt.write_text(rpc_txt(values).replace("LINE_DEN_COEFF_7:", "LINE_DEN_COEF_7:"))
    with pytest.raises(FormatError, match=f"{txt}: LINE_DEN_COEFF must be 20 .* LINE_DEN_COEFF_7"):
        read_camera(txt)
    txt.write_text(rpc_txt(values).replace("HEIGHT_SCALE: 400.0", "HEIGHT_SCALE: lots"))
    with pytest.raises(FormatError, match=r"line 10: 'lots' after 'HEIGHT_SCALE"):
        read_camera(txt)
    txt.write_text("\n".join(rpc_txt(values).splitlines()[:10]))
    with pytest.raises(FormatError, match="no RPC coefficients: missing LINE_NUM_COEFF"):
        read_camera(txt)
    rpb = tmp_path / "a.RPB"
    rpb.write_text(rpc_rpb(values).replace(f"{values['samp_num_coeff'][-1]!r});", ");", 1))
    with pytest.raises(
        FormatError, match=f"{rpb}, line .*: sampNumCoef must be 20 coefficients, got 19"
    ):
        read_camera(rpb)
    rpb.write_text(rpc_rpb(values).replace("latScale = 0.05;", "latScale = ;"))
    with pytest.raises(FormatError, match="'' after 'latScale"):
        read_camera(rpb)


def test_raster_without_rpcs(tmp_path: Path) -> None:
    tif = write_tiff(tmp_path / "plain.tif", None)
    with pytest.raises(FormatError, match=f"{tif}: no RPC coefficients"):
        read_camera(tif)
    with pytest.raises(InputError, match="not found"):
        read_camera(tmp_path / "missing.tif")
    (tmp_path / "fake.tif").write_text("II*\0 not really")
    with pytest.raises(FormatError, match="not a readable raster"):
        read_camera(tmp_path / "fake.tif")


def test_orthority_rpc_picks_by_stem(tmp_path: Path) -> None:
    a, b = synthetic_rpc(), synthetic_rpc() | {"line_off": 7.0}
    path = tmp_path / "rpc_param.yaml"
    path.write_text(
        json.dumps({"a.tif": {"im_size": [4, 5], "rpc": a}, "b.jpg": {"im_size": [6, 7], "rpc": b}})
    )
    assert read_camera(path, "/x/b.tif").rpc.line_off == 7.0
    assert read_camera(path, "a").width == 4
    with pytest.raises(InputError, match="holds 2 cameras"):
        read_camera(path)
    with pytest.raises(InputError, match="no camera for image 'c'"):
        read_camera(path, "c.tif")
    # an Orthority interior file beside it is still refused as before
    shutil.copy(path, tmp_path / "int.yaml")
    (tmp_path / "int.yaml").write_text("cam:\n  type: pinhole\n  im_size: [4, 5]\n  focal_len: 1\n")
    with pytest.raises(InputError, match="interior parameters hold no camera position"):
        read_camera(tmp_path / "int.yaml")


def test_check_image_takes_any_camera() -> None:
    camera = RpcCamera(Rpc.from_mapping(synthetic_rpc()))
    assert check_image(np.zeros((30, 40)), camera).width == 40
    with pytest.raises(InputError, match="is 40 x 30 px but its camera says 4 x 5"):
        check_image(np.zeros((30, 40)), camera.with_image_size(4, 5))
    with pytest.raises(InputError, match="its camera must be a camera model"):
        check_image(np.zeros((30, 40)), "camera")  # type: ignore[arg-type]


def _grey(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read().astype(np.float64).mean(axis=0)


@pytest.mark.slow
def test_rpc_orthophoto_onto_the_ngi_dem(tmp_path: Path) -> None:
    """The QuickBird image through its RPCs onto the NGI DEM, tiled by the engine: the codes
    equal the in-memory visibility of the bound camera, and the orthophoto lines up with the
    NGI aerial frame's orthophoto of the same grid (a 2015 aerial frame against a 2003
    satellite image: phase correlation within 0.6 of a 24 m post, positive correlation).
    The DEM's EGM2008 heights take the undulation (--height-offset), and the raw RPC its bias
    measured on the GCPs (an image offset, as RPC refinement does): without either the two
    errors, about 8 m and 12 m on the ground, cancelled in part (0.24 posts, r 0.47); with the
    bias alone 0.86 posts, r 0.48."""
    import cv2

    from orthomvp.codes import WorldFrame
    from orthomvp.engine import Outputs, plan_ortho, run_plan
    from orthomvp.occlusion.visibility import compute_visibility

    dem, image = shared("ngi-aerial", "dem.tif"), shared(QB, IMAGE)
    frame = "3324c_2015_1004_05_0182_RGB"
    aerial = (shared("ngi-aerial", f"{frame}.tif"), shared("ngi-aerial", f"{frame}.converted.tsai"))
    from dataclasses import replace

    _, raw = quickbird()
    features = json.loads(shared(QB, "gcps.geojson").read_text())["features"]
    lon, lat, h = np.array([f["geometry"]["coordinates"] for f in features]).T
    measured = np.array([f["properties"]["ji"] for f in features])
    bias = (raw.project(raw.to_world(lon, lat, h))[0] - measured).mean(axis=0)
    rpc = replace(raw.rpc, samp_off=raw.rpc.samp_off - bias[0], line_off=raw.rpc.line_off - bias[1])
    refined = replace(raw, rpc=rpc)
    heights = {"height_offset": UNDULATION}
    plan = plan_ortho(dem, [(image, refined)], tile=128, progress=False, grid="dem", **heights)
    assert plan.dem.world == WorldFrame.BODY
    run_plan(
        plan, Outputs(ortho=tmp_path / "qb.tif", visibility=tmp_path / "v.tif"), progress=False
    )
    run_plan(
        plan_ortho(dem, [aerial], progress=False, grid="dem"),
        Outputs(ortho=tmp_path / "ngi.tif"),
        progress=False,
    )
    terrain = Terrain.read(dem, world=WorldFrame.BODY, height_offset=UNDULATION)
    camera = refined.bind(terrain).with_image_size(850, 1450)
    with rasterio.open(tmp_path / "v.tif") as src:
        np.testing.assert_array_equal(src.read(1), compute_visibility(terrain, camera).codes)
    q, a = _grey(tmp_path / "qb.tif"), _grey(tmp_path / "ngi.tif")
    ok = np.isfinite(q) & np.isfinite(a)
    assert ok.sum() > 20_000
    rows, cols = np.flatnonzero(ok.any(axis=1)), np.flatnonzero(ok.any(axis=0))
    box = np.s_[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    m = ok[box]

    def norm(x: np.ndarray) -> np.ndarray:
        return np.where(m, (x - x[m].mean()) / x[m].std(), 0).astype(np.float32)

    window = cv2.createHanningWindow(m.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(norm(a[box]), norm(q[box]), window=window)
    assert np.hypot(dx, dy) < 0.6  # posts (measured: 0.47)
    assert np.corrcoef(q[ok], a[ok])[0, 1] > 0.3  # measured: 0.515
