"""OpenSfM and OpenDroneMap cameras: ``opensfm/reconstruction.json``, ODM's ``cameras.json``
and ``odm_report/shots.geojson``.

Interior (a ``cameras`` entry): ``projection_type``, ``width``, ``height`` (pixels), ``focal``
or ``focal_x``/``focal_y`` and the principal point offsets ``c_x``, ``c_y`` in OpenSfM's
normalised image coordinates (units of max(width, height) pixels, offsets from the image
centre), and the model's coefficients (default 0). The pixel (column, row) of the normalised
distorted position (x, y) is (fx x + cx, fy y + cy) max(w, h) + ((w - 1) / 2, (h - 1) / 2), so
fu = focal_x max(w, h) and cu = (w - 1) / 2 + c_x max(w, h) pixels (likewise v). Projection
types and the lens models here that compute them exactly:

- ``perspective`` (k1, k2), ``simple_radial`` (k1), ``radial`` (k1, k2) and ``brown``
  (k1, k2, k3, p1, p2): OpenSfM's Brown model, x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y +
  p2 (r2 + 2 x^2) (y alike), which is :class:`TsaiDistortion`;
- ``fisheye`` (k1, k2): theta_d = theta (1 + k1 theta^2 + k2 theta^4), and ``fisheye_opencv``
  (k1..k4): :class:`FisheyeDistortion`.

All coefficients 0 give no distortion. Other types (``spherical``, ``equirectangular``,
``dual``, ``fisheye62``, ``fisheye624``) are refused by name.

Exterior (a shot): ``rotation``, an angle-axis vector r (radians), and ``translation`` t,
world-to-camera: X_cam = Rod(r) X + t in OpenCV camera axes (x right, y down, z forward: VW's
u, v, w), so the centre is C = -Rod(r)^T t and R (camera-to-world) = Rod(r)^T.

World frame (the map frame of :mod:`orthomvp.geometry.world`): C + (E, N, h) of the reconstruction's
``reference_lla`` in a projected CRS, default the WGS 84 UTM zone of the reference (zone from
the longitude alone, north or south from the latitude), R unchanged: Orthority's convention.
For ODM it is exact: ODM rewrites ``reconstruction.json`` in its DSM's projected CRS minus an
offset, with the same transform as its point cloud and DSM, and sets the reference at that
offset (the topocentric original is kept as ``reconstruction.topocentric.json``). A plain
OpenSfM reconstruction is topocentric (east, north, up at the reference); taking it as the map
frame leaves out the grid convergence (a turn about the vertical of gamma = dlon sin(lat), up
to 3 degrees at a UTM zone's edge: that pointing error, and horizontal errors of gamma times
the distance d from the reference, 37 m at 1 km at 45 N, 3 degrees from the central
meridian), the scale factor (0.9996 to 1.0010 of the distances) and the Earth's curvature
(heights low by d^2 / 12,740 km: 8 cm at 1 km).

``shots.geojson`` (ODM's report) holds, per image, ``filename``, ``translation`` (the camera
centre in the DSM's CRS, offset added back), ``rotation`` (as in the reconstruction),
``width``, ``height`` and ``focal``, and no interior: that comes from ``cameras.json`` (given,
or found beside the file or one directory up, as ODM lays them out), the entry with the same
size and focal length.
"""

from __future__ import annotations

import functools
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera.distortion import (
    Distortion,
    FisheyeDistortion,
    NullDistortion,
    TsaiDistortion,
)
from orthomvp.camera.formats._common import (
    CameraFile,
    CameraFormat,
    Interior,
    decode_text,
    read_bytes,
)
from orthomvp.camera.model import FieldError, PinholeCamera
from orthomvp.errors import FormatError, InputError

if TYPE_CHECKING:
    from pyproj import CRS, Transformer

_BROWN = ("k1", "k2", "k3", "p1", "p2")
PROJECTIONS: dict[str, tuple[str, ...]] = {
    "perspective": ("k1", "k2"),
    "simple_radial": ("k1",),
    "radial": ("k1", "k2"),
    "brown": _BROWN,
    "fisheye": ("k1", "k2"),
    "fisheye_opencv": ("k1", "k2", "k3", "k4"),
}
"""The projection types read, and their distortion coefficients."""
_FISHEYES = ("fisheye", "fisheye_opencv")
_INTERIOR_KEYS = ("projection_type", "width", "height", "focal", "focal_x", "focal_y")
_CENTRE_KEYS = ("c_x", "c_y")
CAMERAS_JSON = "cameras.json"
"""The name of ODM's interior parameter file."""
WGS84 = 4979
"""The CRS of ``reference_lla``, an EPSG code: WGS 84 latitude, longitude (degrees),
ellipsoidal height."""
_SHOTS_KEY = re.compile(r'"shots"\s*:')
_PROJECTION_KEY = re.compile(r'"projection_type"\s*:')
_FEATURE_COLLECTION = re.compile(r'"type"\s*:\s*"FeatureCollection"')
_TRANSLATION_KEY = re.compile(r'"translation"\s*:')


@dataclass(frozen=True)
class _Interior(Interior):
    """One camera of a ``cameras`` section: pixels, and the normalised focal length (to match
    ODM's shots)."""

    focal: float


def utm_crs(lat: float, lon: float) -> CRS:
    """The WGS 84 UTM CRS of latitude ``lat``, longitude ``lon`` (degrees): zone
    floor((lon + 180) / 6) mod 60 + 1, north for lat >= 0 (no Norway or Svalbard exceptions,
    as Orthority and ODM)."""
    from pyproj import CRS

    zone = int(math.floor((lon + 180.0) / 6.0)) % 60 + 1
    return CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)


def rodrigues(vector: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of an angle-axis ``vector`` (3,): angle |vector| radians about
    its direction, right-handed (OpenCV's Rodrigues)."""
    angle = float(np.linalg.norm(vector))
    if angle == 0.0:
        return np.eye(3)
    k = np.asarray(vector, float) / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.cos(angle) * np.eye(3) + (1 - np.cos(angle)) * np.outer(k, k) + np.sin(angle) * cross


def read_opensfm_cameras(path: str | Path, *, crs: object = None) -> dict[str, PinholeCamera]:
    """The cameras of an OpenSfM ``reconstruction.json``, keyed by the stem of each shot's
    image name, in the map frame of the projected ``crs`` (anything pyproj takes; default the
    UTM zone of the reference, :func:`utm_crs`); see the module docstring for the conventions.
    FormatError naming the file and key for a file that breaks the format."""
    path = Path(path)
    return _reconstruction(path, decode_text(path, read_bytes(path, "reconstruction")), crs)


def read_odm_shots(
    path: str | Path, *, interior: str | Path | None = None
) -> dict[str, PinholeCamera]:
    """The cameras of ODM's ``shots.geojson``, keyed by image stem, with the interior of
    ``interior`` (ODM's ``cameras.json``; default: the one beside ``path`` or a directory up).
    Positions are the file's ``translation``, in the projected CRS of ODM's outputs."""
    path = Path(path)
    return _shots(path, decode_text(path, read_bytes(path, "ODM shots file")), interior)


def _load(path: Path, text: str) -> object:
    """The JSON document ``text`` of ``path``; FormatError when it is not JSON."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}", exc.lineno) from None


def _number(path: Path, key: str, value: object) -> float:
    """``value`` of ``key`` as a finite float; FormatError otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FormatError(path, f"{key}: {value!r} is not a finite number")
    return float(value)


def _vector(path: Path, key: str, value: object) -> np.ndarray:
    """``value`` of ``key`` as 3 finite numbers; FormatError otherwise."""
    if not isinstance(value, list) or len(value) != 3:
        raise FormatError(path, f"{key}: expected a list of 3 numbers, got {value!r}")
    return np.array([_number(path, f"{key}[{i}]", v) for i, v in enumerate(value)])


def _object(path: Path, key: str, value: object) -> dict:
    """``value`` of ``key`` when it is a JSON object; FormatError otherwise."""
    if not isinstance(value, dict):
        raise FormatError(path, f"{key}: expected an object, got {type(value).__name__}")
    return value


def _get(path: Path, obj: Mapping, where: str, key: str) -> object:
    """``obj[key]``; FormatError naming ``where.key`` when it is missing."""
    if key not in obj:
        raise FormatError(path, f"{where}: missing key {key!r}")
    return obj[key]


def _interiors(path: Path, cameras: object, where: str) -> dict[str, _Interior]:
    """The cameras of a ``cameras`` section (``where`` names it in messages), by id."""
    out: dict[str, _Interior] = {}
    for cam_id, spec in _object(path, where, cameras).items():
        out[cam_id] = _interior(
            path, _object(path, f"{where}[{cam_id!r}]", spec), f"{where}[{cam_id!r}]"
        )
    return out


def _interior(path: Path, spec: dict, where: str) -> _Interior:
    """One camera of a ``cameras`` section (see the module docstring)."""
    kind = _get(path, spec, where, "projection_type")
    if kind not in PROJECTIONS:
        raise FormatError(
            path,
            f"{where}.projection_type: {kind!r} is not supported "
            f"(supported: {', '.join(PROJECTIONS)})",
        )
    coefficients = PROJECTIONS[str(kind)]
    for key in spec:
        if key not in _INTERIOR_KEYS + _CENTRE_KEYS + coefficients:
            raise FormatError(path, f"{where}.{key}: {kind} cameras have no parameter {key!r}")
    size = []
    for key in ("width", "height"):
        value = _get(path, spec, where, key)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise FormatError(path, f"{where}.{key}: {value!r} is not a positive integer")
        size.append(value)
    width, height = size
    if "focal" in spec:
        fx = fy = _number(path, f"{where}.focal", spec["focal"])
    elif "focal_x" in spec:
        fx = _number(path, f"{where}.focal_x", spec["focal_x"])
        fy = _number(path, f"{where}.focal_y", _get(path, spec, where, "focal_y"))
    else:
        raise FormatError(path, f"{where}: missing key 'focal' (or 'focal_x' and 'focal_y')")
    cx, cy = (_number(path, f"{where}.{k}", spec.get(k, 0.0)) for k in _CENTRE_KEYS)
    k = {key: _number(path, f"{where}.{key}", spec.get(key, 0.0)) for key in coefficients}
    distortion: Distortion
    if not any(k.values()):
        distortion = NullDistortion()
    elif kind in _FISHEYES:
        distortion = FisheyeDistortion(**{f"k{i}": k.get(f"k{i}", 0.0) for i in range(1, 5)})
    else:
        distortion = TsaiDistortion(**{key: k.get(key, 0.0) for key in _BROWN})
    big = max(width, height)
    return _Interior(
        fu=fx * big,
        fv=fy * big,
        cu=(width - 1) / 2 + cx * big,
        cv=(height - 1) / 2 + cy * big,
        width=width,
        height=height,
        distortion=distortion,
        focal=fx,
    )


def _camera(
    path: Path, where: str, intr: _Interior, centre: np.ndarray, rotation: np.ndarray
) -> PinholeCamera:
    """The camera of interior ``intr`` at world ``centre`` with world-to-camera angle-axis
    ``rotation``."""
    try:
        return PinholeCamera(center=centre, rotation=rodrigues(rotation).T, **intr.fields())
    except FieldError as exc:
        raise FormatError(path, f"{where}: {exc}") from None


def _map_crs(crs: object, lat: float, lon: float) -> CRS:
    """The projected CRS ``crs`` (default :func:`utm_crs` of the reference); InputError when it
    is not one."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    if crs is None:
        return utm_crs(lat, lon)
    try:
        out = CRS.from_user_input(crs)
    except CRSError as exc:
        raise InputError(f"not a CRS: {crs!r} ({exc})") from None
    if not out.is_projected:
        raise InputError(
            f"OpenSfM cameras are placed in a projected CRS (a map frame); {out.name} is not one"
        )
    return out


def _to_map(crs: CRS) -> Transformer:
    """The transformer from :data:`WGS84` (lon, lat) to the map ``crs``."""
    from pyproj import CRS, Transformer

    return Transformer.from_crs(CRS.from_epsg(WGS84), crs, always_xy=True)


def _reconstruction(path: Path, text: str, crs: object) -> dict[str, PinholeCamera]:
    """The cameras of the reconstruction file ``path`` holding ``text`` (see
    :func:`read_opensfm_cameras`)."""
    doc = _load(path, text)
    if not isinstance(doc, list) or not doc:
        raise FormatError(path, "expected a JSON list of reconstructions", 1)
    out: dict[str, PinholeCamera] = {}
    for n, rec in enumerate(doc):
        where = f"[{n}]"
        rec = _object(path, where, rec)
        cameras = _interiors(path, _get(path, rec, where, "cameras"), f"{where}.cameras")
        ref = _object(path, f"{where}.reference_lla", _get(path, rec, where, "reference_lla"))
        lat, lon, alt = (
            _number(
                path, f"{where}.reference_lla.{k}", _get(path, ref, f"{where}.reference_lla", k)
            )
            for k in ("latitude", "longitude", "altitude")
        )
        to_map = _to_map(_map_crs(crs, lat, lon))
        easting, northing = to_map.transform(lon, lat)
        origin = np.array([easting, northing, alt])
        shots = _object(path, f"{where}.shots", _get(path, rec, where, "shots"))
        for name, shot in shots.items():
            at = f"{where}.shots[{name!r}]"
            shot = _object(path, at, shot)
            cam_id = _get(path, shot, at, "camera")
            if cam_id not in cameras:
                raise FormatError(path, f"{at}.camera: {cam_id!r} is not in {where}.cameras")
            rotation = _vector(path, f"{at}.rotation", _get(path, shot, at, "rotation"))
            translation = _vector(path, f"{at}.translation", _get(path, shot, at, "translation"))
            centre = origin - rodrigues(rotation).T @ translation
            key = Path(name).stem
            if key in out:
                raise FormatError(path, f"{at}: image {key!r} appears twice")
            out[key] = _camera(path, at, cameras[cam_id], centre, rotation)
    return out


def _shots(
    path: Path, text: str, interior: str | Path | None, interior_data: bytes | None = None
) -> dict[str, PinholeCamera]:
    """The cameras of the ODM shots file ``path`` holding ``text`` (see
    :func:`read_odm_shots`); ``interior_data``: the bytes of its ``cameras.json`` if read
    already."""
    doc = _object(path, "the file", _load(path, text))
    if doc.get("type") != "FeatureCollection":
        raise FormatError(path, "expected a GeoJSON FeatureCollection", 1)
    features = _get(path, doc, "the FeatureCollection", "features")
    if not isinstance(features, list):
        raise FormatError(path, "features: expected a list")
    found = _find_cameras_json(path) if interior is None else Path(interior)
    if interior_data is None:
        interior_data = read_bytes(found, "ODM cameras.json")
    interior_text = decode_text(found, interior_data)
    cameras = _interiors(found, _load(found, interior_text), "cameras")
    out: dict[str, PinholeCamera] = {}
    for n, feature in enumerate(features):
        at = f"features[{n}].properties"
        props = _object(
            path,
            at,
            _get(path, _object(path, f"features[{n}]", feature), f"features[{n}]", "properties"),
        )
        name = _get(path, props, at, "filename")
        if not isinstance(name, str):
            raise FormatError(path, f"{at}.filename: {name!r} is not a file name")
        intr = _match(path, at, props, cameras, found)
        rotation = _vector(path, f"{at}.rotation", _get(path, props, at, "rotation"))
        centre = _vector(path, f"{at}.translation", _get(path, props, at, "translation"))
        key = Path(name).stem
        if key in out:
            raise FormatError(path, f"{at}: image {key!r} appears twice")
        out[key] = _camera(path, at, intr, centre, rotation)
    return out


def _find_cameras_json(path: Path) -> Path:
    """ODM's ``cameras.json`` beside the shots file ``path`` or one directory up."""
    for directory in (path.parent, path.parent.parent):
        if (directory / CAMERAS_JSON).is_file():
            return directory / CAMERAS_JSON
    raise InputError(
        f"{path}: ODM shots need the interior parameters of {CAMERAS_JSON}: none beside them or "
        f"one directory up: put ODM's {CAMERAS_JSON} there (or in Python, name it: "
        "read_camera(..., interior=FILE))"
    )


def _match(
    path: Path, at: str, props: dict, cameras: dict[str, _Interior], found: Path
) -> _Interior:
    """The camera of ``cameras`` (read from ``found``) that took the shot with properties
    ``props``: the one camera, or the one of the shot's width, height and focal length."""
    size = tuple(_get(path, props, at, key) for key in ("width", "height"))
    focal = _number(path, f"{at}.focal", _get(path, props, at, "focal"))
    same = [
        c
        for c in cameras.values()
        if (c.width, c.height) == size and math.isclose(c.focal, focal, rel_tol=1e-9)
    ]
    if len(same) != 1:
        what = "no camera" if not same else f"{len(same)} cameras"
        raise FormatError(
            path,
            f"{at}: {what} of {found} with width x height {size[0]} x {size[1]} and focal "
            f"{focal!r}",
        )
    return same[0]


def _pick(path: Path, cameras: dict[str, PinholeCamera], image: str | Path | None) -> PinholeCamera:
    """The camera of ``image`` (by stem) in ``cameras``, read from ``path``; InputError when it
    is not there, or when no image is named and there is more than one camera."""
    if image is None:
        if len(cameras) != 1:
            raise InputError(
                f"{path}: holds {len(cameras)} cameras; name the image to pick one by its stem"
            )
        return next(iter(cameras.values()))
    stem = Path(image).stem
    if stem not in cameras:
        shown = ", ".join(map(repr, list(cameras)[:5])) + (", ..." if len(cameras) > 5 else "")
        raise InputError(f"{path}: no camera for image {stem!r} (it has {shown})")
    return cameras[stem]


def read_reconstruction(file: CameraFile) -> PinholeCamera:
    """The camera of ``file.image`` in a ``reconstruction.json`` (see
    :func:`orthomvp.camera.read_camera`), in the default map frame."""
    return _pick(file.path, _file_reconstruction(file.path, file.text), file.image)


def read_shots(file: CameraFile) -> PinholeCamera:
    """The camera of ``file.image`` in ODM's ``shots.geojson``, with ``file.interior`` or the
    ``cameras.json`` found by :func:`read_odm_shots`."""
    interior = file.interior
    try:
        found = _find_cameras_json(file.path) if interior is None else Path(interior)
        interior_data = read_bytes(found, "ODM cameras.json")
    except InputError:  # no cameras.json to read: _shots says so, after the shots' own errors
        return _pick(file.path, _shots(file.path, file.text, interior), file.image)
    return _pick(file.path, _file_shots(file.path, file.text, interior, interior_data), file.image)


@functools.lru_cache(maxsize=4)
def _file_reconstruction(path: Path, text: str) -> dict[str, PinholeCamera]:
    """:func:`_reconstruction` of ``text`` in the default map frame, built once per process for
    the same file and contents: a mosaic's images pick their cameras from one file, and
    building them all for each image made its planning grow as the square of their number.
    Cameras are immutable; the dict is shared: read it, never change it."""
    return _reconstruction(path, text, None)


@functools.lru_cache(maxsize=4)
def _file_shots(
    path: Path, text: str, interior: str | Path | None, interior_data: bytes
) -> dict[str, PinholeCamera]:
    """:func:`_shots` of ``text`` with ``interior`` and the bytes of its ``cameras.json``, built
    once per process for the same files and contents, as :func:`_file_reconstruction`."""
    return _shots(path, text, interior, interior_data)


def refuse_cameras_json(file: CameraFile) -> PinholeCamera:
    """Raise InputError: ODM's ``cameras.json`` holds no camera pose."""
    raise InputError(
        f"{file.path}: OpenSfM/ODM interior parameters hold no camera position; give "
        "opensfm/reconstruction.json or odm_report/shots.geojson as the camera"
    )


def is_reconstruction(file: CameraFile) -> bool:
    """Whether the file looks like a reconstruction: a JSON list with a ``"shots"`` key."""
    return file.head.startswith("[") and _SHOTS_KEY.search(file.head) is not None


def is_shots(file: CameraFile) -> bool:
    """Whether the file looks like ODM's shots: a FeatureCollection with ``"translation"``."""
    head = file.head
    return (
        _FEATURE_COLLECTION.search(head) is not None and _TRANSLATION_KEY.search(head) is not None
    )


def is_cameras_json(file: CameraFile) -> bool:
    """Whether the file looks like a ``cameras`` section: an object with ``projection_type``."""
    return file.head.startswith("{") and _PROJECTION_KEY.search(file.head) is not None


FORMATS = (
    CameraFormat("OpenSfM reconstruction", (".json",), read_reconstruction, is_reconstruction),
    CameraFormat("ODM shots", (".geojson", ".json"), read_shots, is_shots),
    CameraFormat("OpenSfM/ODM cameras.json", (".json",), refuse_cameras_json, is_cameras_json),
)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry: a reconstruction,
ODM's shots with their ``cameras.json``, and a ``cameras.json`` alone, refused."""
