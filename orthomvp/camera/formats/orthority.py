"""Orthority's camera parameter files: interior (YAML) and exterior (CSV, GeoJSON).

Interior parameters (``int_param.yaml``) give each camera's model, image size, focal length,
principal point and distortion; exterior parameters (``xyz_opk.csv``, GeoJSON) give each image's
position, its omega, phi, kappa angles and the camera that took it.
:func:`read_orthority_cameras` combines the two into pinhole cameras by image stem, and
:func:`read_exterior` picks one image's camera for :func:`orthomvp.camera.read_camera`.
YAML is read with PyYAML's safe loader, as Orthority itself reads it.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera.distortion import (
    Distortion,
    FisheyeDistortion,
    NullDistortion,
    OpenCVDistortion,
    TsaiDistortion,
)
from orthomvp.camera.formats._common import (
    CameraFile,
    CameraFormat,
    Interior,
    build_camera,
    decode_text,
    number,
    read_bytes,
)
from orthomvp.camera.model import PinholeCamera
from orthomvp.errors import FormatError, InputError

if TYPE_CHECKING:
    import yaml

_ORTHORITY_MODELS: dict[str, tuple[str, ...]] = {
    "pinhole": (),
    "brown": ("k1", "k2", "p1", "p2", "k3"),
    "fisheye": FisheyeDistortion.param_names(),
    "opencv": OpenCVDistortion.param_names(),
}
_ORTHORITY_COMMON = ("type", "im_size", "focal_len", "sensor_size", "cx", "cy")
_CSV_LEGACY_FIELDS = ("filename", "x", "y", "z", "omega", "phi", "kappa")
INTERIOR_SUFFIXES = (".yaml", ".yml")
"""File name extensions (lower case) of interior parameter files."""
_FEATURE_COLLECTION = re.compile(r'"type"\s*:\s*"FeatureCollection"')


def orthority_rotation(omega: float, phi: float, kappa: float) -> np.ndarray:
    """Camera-to-world R (3, 3) of Orthority/PATB angles (radians), for VW's camera axes.

    R = Rx(omega) Ry(phi) Rz(kappa) diag(1, -1, -1), with the right-handed rotations
    Rx(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]] (Ry, Rz alike): the angles rotate
    PATB camera axes (x right, y up, z backward) to the world; diag(1, -1, -1) turns them into
    the OpenCV/VW axes used here (x right, y down, z forward, u = x, v = y, w = z).
    """
    co, so, cp, sp, ck, sk = (f(a) for a in (omega, phi, kappa) for f in (np.cos, np.sin))
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, co, -so], [0.0, so, co]])
    rot_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rot_z = np.array([[ck, -sk, 0.0], [sk, ck, 0.0], [0.0, 0.0, 1.0]])
    return rot_x @ rot_y @ rot_z @ np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class _Exterior:
    """One image of an exterior parameter file: position (world units), angles in radians."""

    filename: str
    camera: str | None
    xyz: tuple[float, float, float]
    opk: tuple[float, float, float]
    line: int | None


def read_orthority_cameras(
    interior: str | Path, exterior: str | Path, *, radians: bool = False
) -> dict[str, PinholeCamera]:
    """The cameras of Orthority interior and exterior parameter files, by image file stem.

    ``interior``: Orthority's YAML interior parameters, a mapping of camera id to ``type``
    (``pinhole``, ``brown``, ``opencv`` or ``fisheye``), ``im_size`` [width, height] pixels,
    ``focal_len`` (a number or [fx, fy]) in the units of the optional ``sensor_size``
    [width, height] (absent: ``focal_len`` is normalised by the image width, as Orthority does),
    ``cx``, ``cy`` (principal point offsets in OpenSfM normalised image coordinates: the
    principal point is ((w - 1) / 2 + cx max(w, h), (h - 1) / 2 + cy max(w, h)) pixels) and the
    model's distortion coefficients (default 0): ``brown`` k1 k2 p1 p2 k3 and ``opencv`` k1..k6
    p1 p2 s1..s4 tx ty, both OpenCV's model (TSAI here, or :class:`OpenCVDistortion` when a
    coefficient beyond TSAI's is set); ``fisheye`` k1..k4 (FISHEYE). Without any coefficient the
    camera has no distortion.

    ``exterior``: Orthority's CSV (header naming ``filename``, ``x``, ``y``, ``z``, ``omega``,
    ``phi``, ``kappa`` and optionally ``camera``, or no header and those seven in that order;
    angles in degrees unless ``radians``) or GeoJSON (a FeatureCollection whose features have
    ``filename``, ``camera``, ``xyz`` and ``opk`` in radians). Positions are world coordinates
    as given (a projected CRS taken as Cartesian); the angles give R by
    :func:`orthority_rotation`. A row's ``camera`` names its interior camera; without it, the
    interior file must hold one camera.

    Returns the cameras (pitch 1, intrinsics in pixels, image size set), keyed by the stem of
    each ``filename`` (the name without directory and extension). FormatError for bad files.
    """
    interior, exterior = Path(interior), Path(exterior)
    text = decode_text(exterior, read_bytes(exterior, "exterior parameter file"))
    images = _read_exterior(exterior, text, radians)  # first: is it exterior parameters at all?
    return _combine(_read_interior(interior, _interior_text(interior)), interior, exterior, images)


def _combine(
    cameras: dict[str, Interior], interior: Path, exterior: Path, images: list[_Exterior]
) -> dict[str, PinholeCamera]:
    """The cameras of the ``images`` of the exterior file ``exterior``, by image file stem,
    with the interior ``cameras`` of the file ``interior`` (see
    :func:`read_orthority_cameras`)."""
    out: dict[str, PinholeCamera] = {}
    for ext in images:
        key = Path(ext.filename).stem
        if key in out:
            raise FormatError(exterior, f"image {key!r} appears twice", ext.line)
        if ext.camera is not None:
            if ext.camera not in cameras:
                raise FormatError(
                    exterior,
                    f"camera {ext.camera!r} of image {key!r} is not in {interior} "
                    f"(it has {', '.join(map(repr, cameras))})",
                    ext.line,
                )
            intr = cameras[ext.camera]
        elif len(cameras) == 1:
            intr = next(iter(cameras.values()))
        else:
            raise FormatError(
                exterior,
                f"image {key!r} names no camera, and {interior} holds {len(cameras)}",
                ext.line,
            )
        out[key] = build_camera(
            exterior,
            lambda _, line=ext.line: line,
            center=ext.xyz,
            rotation=orthority_rotation(*ext.opk),
            **intr.fields(),
        )
    return out


def read_exterior(file: CameraFile) -> PinholeCamera:
    """The camera of ``file.image`` in an exterior parameter file, with the interior parameters
    of ``file.interior`` or of the one ``.yaml`` file beside it (see
    :func:`orthomvp.camera.read_camera`); CSV angles in degrees."""
    path, interior = file.path, file.interior
    text = file.text  # read first: a missing or unreadable camera file is reported as such
    _images(path, text)  # then what it holds: not exterior parameters is said as such
    if interior is None:
        found = sorted(p for p in path.parent.iterdir() if p.suffix.lower() in INTERIOR_SUFFIXES)
        if len(found) != 1:
            what, remedy = "is none", "put it there"
            if found:
                names = ", ".join(p.name for p in found)
                what, remedy = f"are {len(found)} ({names})", "keep only theirs there"
            raise InputError(
                f"{path}: Orthority exterior parameters need their interior parameter file "
                f"(.yaml) beside them, and there {what}: {remedy} (or in Python, name it: "
                "read_camera(..., interior=FILE))"
            )
        interior = found[0]
    interior = Path(interior)
    cameras = _file_cameras(path, text, interior, _interior_text(interior))
    if file.image is None:
        if len(cameras) != 1:
            raise InputError(
                f"{path}: holds {len(cameras)} cameras; name the image to pick one by its stem"
            )
        return next(iter(cameras.values()))
    stem = Path(file.image).stem
    if stem not in cameras:
        raise InputError(
            f"{path}: no camera for image {stem!r} (it has {', '.join(map(repr, cameras))})"
        )
    return cameras[stem]


@functools.lru_cache(maxsize=4)
def _file_cameras(
    path: Path, text: str, interior: Path, interior_text: str
) -> dict[str, PinholeCamera]:
    """Every camera of the exterior file ``path`` holding ``text`` with the interior file
    ``interior`` holding ``interior_text`` (CSV angles in degrees), built once per process for
    the same contents: a mosaic's images pick their cameras from one file, and building them
    all for each image made its planning grow as the square of their number (1,000 rows: 0.08 s
    an image). Cameras are immutable; the dict is shared: read it, never change it."""
    images = list(_images(path, text))
    return _combine(_read_interior(interior, interior_text), interior, path, images)


@functools.lru_cache(maxsize=4)
def _images(path: Path, text: str) -> tuple[_Exterior, ...]:
    """The images of the exterior file ``path`` holding ``text`` (CSV angles in degrees),
    parsed once per process for the same contents (see :func:`_file_cameras`)."""
    return tuple(_read_exterior(path, text, radians=False))


def refuse_interior(file: CameraFile) -> PinholeCamera:
    """Raise InputError: an interior parameter file alone holds no camera pose."""
    raise InputError(
        f"{file.path}: Orthority interior parameters hold no camera position; give the exterior "
        "parameter file (.csv or .geojson) as the camera, with this file beside it"
    )


def stated_crs(path: Path) -> str | None:
    """The world CRS an Orthority exterior file states for its cameras, as it gives it (WKT,
    PROJ string or authority code): the ``.prj`` beside a CSV file (of the same stem) or a
    GeoJSON file's ``world_crs``; None where it states none, or for another kind of file."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        prj = path.with_suffix(".prj")
        if not prj.is_file():
            return None
        return prj.read_text(errors="replace").strip() or None
    if suffix not in (".geojson", ".json"):
        return None
    try:
        obj = json.loads(path.read_text(errors="replace"))
    except (OSError, json.JSONDecodeError):
        return None  # (reading the camera says what is wrong with the file)
    if not isinstance(obj, dict) or obj.get("type") != "FeatureCollection":
        return None
    crs = obj.get("world_crs")
    return crs if isinstance(crs, str) and crs.strip() else None


def is_geojson(file: CameraFile) -> bool:
    """Whether the file looks like a GeoJSON FeatureCollection (an exterior file)."""
    return _FEATURE_COLLECTION.search(file.head) is not None


FORMATS = (
    CameraFormat("Orthority interior parameters", INTERIOR_SUFFIXES, refuse_interior),
    CameraFormat("Orthority CSV", (".csv",), read_exterior),
    CameraFormat("Orthority GeoJSON", (".geojson", ".json"), read_exterior, is_geojson),
)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry: an exterior parameter
file, whose interior file lies beside it or is given, and an interior file alone, refused."""


def _interior_text(path: Path) -> str:
    """The Orthority interior parameter file ``path`` as text."""
    return decode_text(path, read_bytes(path, "interior parameter file"))


def _read_interior(path: Path, text: str) -> dict[str, Interior]:
    """The cameras of the Orthority interior parameter (YAML) file ``path`` holding ``text``, by
    camera id."""
    import yaml

    loader = yaml.SafeLoader(text)
    try:
        root = loader.get_single_node()
        if not isinstance(root, yaml.MappingNode) or not root.value:
            line = 1 if root is None else root.start_mark.line + 1
            raise FormatError(path, "expected a mapping of camera ids to their parameters", line)
        out: dict[str, Interior] = {}
        for cam_id, line, node in _yaml_items(path, root):
            if not isinstance(node, yaml.MappingNode):
                raise FormatError(
                    path, f"camera {cam_id!r}: expected a mapping of parameters", line
                )
            items = _yaml_items(path, node)
            params = {key: loader.construct_object(value, deep=True) for key, _, value in items}
            lines = {key: key_line for key, key_line, _ in items}
            out[cam_id] = _interior(path, cam_id, params, line, lines)
        return out
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        context, problem = getattr(exc, "context", None), getattr(exc, "problem", None)
        message = ", ".join(filter(None, (context, problem))) or str(exc)
        line = None if mark is None else mark.line + 1
        raise FormatError(path, f"invalid YAML: {message}", line) from None
    finally:
        loader.dispose()


def _yaml_items(path: Path, node: yaml.MappingNode) -> list[tuple[str, int, yaml.Node]]:
    """(key, 1-based line of the key, value node) of a YAML mapping; keys as written in the
    file (``1`` is the id "1"). FormatError on a key that is not a scalar or is given twice."""
    import yaml

    items: list[tuple[str, int, yaml.Node]] = []
    for key, value in node.value:
        line = key.start_mark.line + 1
        if not isinstance(key, yaml.ScalarNode):
            raise FormatError(path, "keys must be plain names", line)
        if any(key.value == seen for seen, _, _ in items):
            raise FormatError(path, f"key {key.value!r} given twice", line)
        items.append((key.value, line, value))
    return items


def _interior(
    path: Path, cam_id: str, params: dict[str, object], line: int, lines: dict[str, int]
) -> Interior:
    """One camera of an interior parameter file (see :func:`read_orthority_cameras`);
    ``line`` is the camera id's line, ``lines`` each parameter's."""

    def fail(key: str, message: str) -> FormatError:
        return FormatError(path, f"camera {cam_id!r}: {message}", lines.get(key, line))

    def numbers(key: str, sizes: tuple[int, ...], positive: bool = False) -> list[float]:
        value = params[key]
        items = value if isinstance(value, list) else [value]
        if len(items) not in sizes or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in items
        ):
            count = " or ".join(map(str, sizes))
            raise fail(key, f"{key} must be {count} finite number(s), got {value!r}")
        if positive and min(items) <= 0:
            raise fail(key, f"{key} must be positive, got {value!r}")
        return [float(v) for v in items]

    kind = params.get("type")
    if kind is None and "rpc" in params:
        raise fail(
            "rpc",
            "holds RPC parameters (an Orthority RPC file), not the interior parameters of a "
            "frame camera",
        )
    if kind not in _ORTHORITY_MODELS:
        known = ", ".join(_ORTHORITY_MODELS)
        raise fail("type", f"camera type {kind!r} is not supported (supported: {known})")
    coefficients = _ORTHORITY_MODELS[str(kind)]
    for key in params:
        if key not in _ORTHORITY_COMMON + coefficients:
            raise fail(key, f"{kind} cameras have no parameter {key!r}")
    for key in ("im_size", "focal_len"):
        if key not in params:
            raise fail(key, f"missing {key}")
    size = numbers("im_size", (2,), positive=True)
    if not all(v == int(v) for v in size):
        raise fail("im_size", f"im_size must be whole pixels, got {params['im_size']!r}")
    width, height = int(size[0]), int(size[1])
    focal = numbers("focal_len", (1, 2), positive=True)  # [f] or [fx, fy]
    if "sensor_size" in params:
        sensor = numbers("sensor_size", (2,), positive=True)
        fu, fv = focal[0] * width / sensor[0], focal[-1] * height / sensor[1]
    else:
        fu, fv = focal[0] * width, focal[-1] * width
    cx, cy = (numbers(key, (1,))[0] if key in params else 0.0 for key in ("cx", "cy"))
    coeffs = {key: numbers(key, (1,))[0] for key in coefficients if key in params}
    tsai = TsaiDistortion.param_names()
    distortion: Distortion
    if kind == "fisheye":
        distortion = FisheyeDistortion(**{key: coeffs.get(key, 0.0) for key in coefficients})
    elif not any(coeffs.values()):
        distortion = NullDistortion()
    elif not any(value for key, value in coeffs.items() if key not in tsai):
        distortion = TsaiDistortion(**{key: coeffs.get(key, 0.0) for key in tsai})
    else:
        distortion = OpenCVDistortion(**coeffs)
    big = max(width, height)
    return Interior(
        fu=fu,
        fv=fv,
        cu=(width - 1) / 2 + big * cx,
        cv=(height - 1) / 2 + big * cy,
        width=width,
        height=height,
        distortion=distortion,
    )


def _read_exterior(path: Path, text: str, radians: bool) -> list[_Exterior]:
    """The images of the Orthority exterior parameter file ``path`` (CSV, or GeoJSON) holding
    ``text``."""
    if path.suffix.lower() == ".csv":
        return _csv_exterior(path, text, radians)
    return _geojson_exterior(path, text)


def _csv_exterior(path: Path, text: str, radians: bool) -> list[_Exterior]:
    """Orthority CSV exterior parameters (see :func:`read_orthority_cameras`)."""
    try:
        dialect: type[csv.Dialect] | csv.Dialect = csv.Sniffer().sniff(
            text[:4096], delimiters=",;: \t"
        )
    except csv.Error:
        dialect = csv.excel
    reader = csv.reader(io.StringIO(text), dialect)
    rows: list[tuple[int, list[str]]] = []
    try:
        for row in reader:
            if any(cell.strip() for cell in row):
                rows.append((reader.line_num, [cell.strip() for cell in row]))
    except csv.Error as exc:
        raise FormatError(path, f"bad CSV: {exc}", reader.line_num) from None
    if not rows:
        raise FormatError(path, "no images in the file", 1)
    if "filename" in rows[0][1]:
        fields, rows = rows[0][1], rows[1:]
    else:
        fields = list(_CSV_LEGACY_FIELDS)
    missing = [f for f in _CSV_LEGACY_FIELDS if f not in fields]
    if missing:
        other = [
            f for f in ("latitude", "longitude", "altitude", "roll", "pitch", "yaw") if f in fields
        ]
        hint = (
            f"; {', '.join(other)} would need Orthority's CRS conversions, not supported"
            if other
            else ""
        )
        raise FormatError(path, f"missing field(s) {', '.join(missing)}{hint}", 1)
    out = []
    for line, row in rows:
        if len(row) != len(fields):
            raise FormatError(path, f"expected {len(fields)} fields, found {len(row)}", line)
        values = dict(zip(fields, row, strict=True))
        numbers = [number(path, values[key], key, line) for key in _CSV_LEGACY_FIELDS[1:]]
        angles = numbers[3:] if radians else [math.radians(a) for a in numbers[3:]]
        out.append(
            _Exterior(
                filename=values["filename"],
                camera=values.get("camera") or None,
                xyz=(numbers[0], numbers[1], numbers[2]),
                opk=(angles[0], angles[1], angles[2]),
                line=line,
            )
        )
    return out


def _geojson_exterior(path: Path, text: str) -> list[_Exterior]:
    """Orthority GeoJSON exterior parameters (see :func:`read_orthority_cameras`)."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}", exc.lineno) from None
    if not isinstance(obj, dict) or obj.get("type") != "FeatureCollection":
        raise FormatError(path, "expected a GeoJSON FeatureCollection", 1)
    features = obj.get("features")
    if not isinstance(features, list) or not features:
        raise FormatError(path, "the FeatureCollection has no features")
    out = []
    for i, feature in enumerate(features):
        props = feature.get("properties") if isinstance(feature, dict) else None
        if not isinstance(props, dict):
            raise FormatError(path, f"feature {i} has no properties")
        name = props.get("filename")
        camera = props.get("camera")
        if "ji" in props and "xyz" not in props and "opk" not in props:
            raise FormatError(
                path,
                f"an Orthority GCP file (ground control points: feature {i} has pixel "
                "coordinates 'ji' and a ground point), not camera exterior parameters ('xyz' "
                "and 'opk'): give the image's camera instead (none for an image that carries "
                "its own RPCs)",
            )
        if not isinstance(name, str) or not (camera is None or isinstance(camera, str)):
            raise FormatError(path, f"feature {i}: filename (and camera) must be strings")
        vectors = []
        for key in ("xyz", "opk"):
            value = props.get(key)
            if not (
                isinstance(value, list)
                and len(value) == 3
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            ):
                raise FormatError(path, f"feature {i} ({name}): {key} must be 3 numbers")
            vectors.append((float(value[0]), float(value[1]), float(value[2])))
        out.append(_Exterior(name, camera, vectors[0], vectors[1], None))
    return out
