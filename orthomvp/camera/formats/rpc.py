"""RPC camera files: GeoTIFF RPC metadata, DigitalGlobe ``_RPC.TXT`` and ``.RPB``, and
Orthority's ``rpc_param.yaml``.

- GeoTIFF (or any raster GDAL reads with RPCs): GDAL's ``RPC`` metadata domain (the
  RPCCoefficient TIFF tag, or an ``.RPB``/``_RPC.TXT`` file beside the image), keys such as
  ``LINE_OFF`` and ``LINE_NUM_COEFF`` (20 numbers separated by spaces); the image size is the
  raster's. The camera file can be the image itself.
- ``_RPC.TXT``, as GDAL reads and writes it: ``KEY: value [unit]`` lines, the coefficients one
  a line as ``LINE_NUM_COEFF_1`` ... ``LINE_NUM_COEFF_20``.
- ``.RPB``: ``name = value;`` statements, the coefficients as ``lineNumCoef = (c1, ..., c20);``
  (``lineOffset``, ``sampScale``, ``heightOffset``, ...).
- Orthority's YAML: a mapping of image file names to ``im_size`` [width, height] and ``rpc``
  (the keys of :data:`orthomvp.camera.rpc.RPC_KEYS`); the image's stem picks the entry.

Every reader returns an :class:`~orthomvp.camera.rpc.RpcCamera` in the default world frame
(WGS84 geocentric; :meth:`~orthomvp.camera.rpc.RpcCamera.bind` moves it to a terrain's), and
raises FormatError naming the file and the key (and the line, for the text formats) for a
missing key, a wrong number of coefficients or a value that is not a number.
"""

from __future__ import annotations

import functools
import math
import re
import warnings
from pathlib import Path

import rasterio
from rasterio.errors import NotGeoreferencedWarning, RasterioError

from orthomvp.camera.formats._common import CameraFile, CameraFormat, number
from orthomvp.camera.model import FieldError
from orthomvp.camera.rpc import RpcCamera
from orthomvp.camera.rpc_model import COEFFICIENTS, RPC_KEYS, Rpc
from orthomvp.errors import FormatError, InputError
from orthomvp.io.files import check_regular, open_regular

_RPB_NAMES = dict(
    zip(
        RPC_KEYS,
        (
            "lineOffset",
            "sampOffset",
            "latOffset",
            "longOffset",
            "heightOffset",
            "lineScale",
            "sampScale",
            "latScale",
            "longScale",
            "heightScale",
            "lineNumCoef",
            "lineDenCoef",
            "sampNumCoef",
            "sampDenCoef",
        ),
        strict=True,
    )
)
_TXT_LINE = re.compile(r"^[ \t]*([A-Za-z_][A-Za-z0-9_]*)[ \t]*:[ \t]*(.*?)[ \t]*$", re.MULTILINE)
_RPB_STATEMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(\([^)]*\)|[^;]*?)\s*;")
_TIFF_MAGIC = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")


def _build(
    path: Path,
    values: dict[str, object],
    names: dict[str, str],
    lines: dict[str, int],
    where: str = "",
) -> Rpc:
    """The RPC of parsed ``values`` (by RPC key); ``names`` and ``lines`` give each key's name
    and line in the file, ``where`` a prefix for messages, for FormatError."""
    missing = [names[key] for key in RPC_KEYS if key not in values]
    if missing:
        raise FormatError(path, f"{where}no RPC coefficients: missing {', '.join(missing)}")
    try:
        return Rpc(**values)
    except FieldError as exc:
        key = exc.field.split("[")[0]
        label = "" if names[key] == key else f"{names[key]}: "  # the message names the key
        raise FormatError(path, f"{where}{label}{exc}", lines.get(key)) from None


def _coefficients(path: Path, name: str, tokens: list[str], line: int | None) -> list[float]:
    """20 numbers of the key ``name``; FormatError otherwise."""
    if len(tokens) != 20:
        raise FormatError(path, f"{name} must be 20 coefficients, got {len(tokens)}", line)
    return [number(path, token, name, line) for token in tokens]


def read_geotiff(file: CameraFile) -> RpcCamera:
    """The RPC camera of a raster's RPC metadata; its image size is the raster's."""
    path = file.path
    check_regular(path, "camera file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                tags, width, height = ds.tags(ns="RPC"), ds.width, ds.height
    except RasterioError as exc:
        raise FormatError(path, f"not a readable raster ({exc})") from None
    if not tags:
        raise FormatError(path, "no RPC coefficients: the raster has no RPC metadata")
    upper = {key.upper(): value for key, value in tags.items()}
    names = {key: key.upper() for key in RPC_KEYS}
    values: dict[str, object] = {}
    for key in RPC_KEYS:
        if names[key] in upper:
            tokens = upper[names[key]].split()
            if key in COEFFICIENTS:
                values[key] = _coefficients(path, names[key], tokens, None)
            else:  # the first word, as GDAL reads it (an _RPC.TXT beside it keeps its units)
                values[key] = number(path, tokens[0] if tokens else "", names[key], None)
    return RpcCamera(_build(path, values, names, {}), width=width, height=height)


def read_txt(file: CameraFile) -> RpcCamera:
    """The RPC camera of a DigitalGlobe/GDAL ``_RPC.TXT`` file (no image size)."""
    path = file.path
    found: dict[str, tuple[str, int]] = {}
    for match in _TXT_LINE.finditer(file.text):
        line = file.text.count("\n", 0, match.start()) + 1
        key = match.group(1).upper()
        if key in found:
            raise FormatError(path, f"{key} given twice", line)
        found[key] = (match.group(2), line)
    names = {key: key.upper() for key in RPC_KEYS}
    values: dict[str, object] = {}
    lines: dict[str, int] = {}
    for key in RPC_KEYS:
        name = names[key]
        if key in COEFFICIENTS:
            items = [found.get(f"{name}_{i}") for i in range(1, 21)]
            if not any(items):
                continue
            absent = [f"{name}_{i}" for i, item in enumerate(items, 1) if item is None]
            if absent:
                raise FormatError(path, f"{name} must be 20 coefficients: missing {absent[0]}")
            values[key] = [
                number(path, text.split()[0] if text else text, f"{name}_{i}", line)
                for i, (text, line) in enumerate(items, 1)
            ]
            lines[key] = items[0][1]
        elif name in found:
            text, line = found[name]
            values[key] = number(path, text.split()[0] if text else text, name, line)
            lines[key] = line
    return RpcCamera(_build(path, values, names, lines))


def read_rpb(file: CameraFile) -> RpcCamera:
    """The RPC camera of a DigitalGlobe ``.RPB`` file (no image size)."""
    path, text = file.path, file.text
    by_name = {name: key for key, name in _RPB_NAMES.items()}
    values: dict[str, object] = {}
    lines: dict[str, int] = {}
    for match in _RPB_STATEMENT.finditer(text):
        key = by_name.get(match.group(1))
        if key is None:
            continue
        line = text.count("\n", 0, match.start()) + 1
        if key in values:
            raise FormatError(path, f"{match.group(1)} given twice", line)
        value = match.group(2)
        if key in COEFFICIENTS:
            if not value.startswith("("):
                raise FormatError(
                    path, f"{match.group(1)} must be a list ( ... ) of 20 numbers", line
                )
            tokens = [t.strip() for t in value[1:-1].split(",") if t.strip()]
            values[key] = _coefficients(path, match.group(1), tokens, line)
        else:
            values[key] = number(path, value, match.group(1), line)
        lines[key] = line
    return RpcCamera(_build(path, values, _RPB_NAMES, lines))


@functools.lru_cache(maxsize=4)
def _yaml_document(text: str) -> object:
    """``yaml.safe_load(text)``, loaded once per process for the same text: a mosaic's images
    pick their RPCs from one file, and loading it for each image made its planning grow as the
    square of their number. The document is shared: read it, never change it."""
    import yaml

    return yaml.safe_load(text)


def read_orthority_rpc(file: CameraFile) -> RpcCamera:
    """The RPC camera of ``file.image`` (by stem) in Orthority's RPC parameter YAML file;
    without an image, the file must hold one camera."""
    import yaml

    path = file.path
    try:
        root = _yaml_document(file.text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise FormatError(
            path, f"invalid YAML: {exc}", None if mark is None else mark.line + 1
        ) from None
    if not isinstance(root, dict) or not root:
        raise FormatError(path, "expected a mapping of image file names to RPC parameters")
    cameras = {Path(str(name)).stem: (str(name), entry) for name, entry in root.items()}
    if file.image is None:
        if len(cameras) != 1:
            raise InputError(
                f"{path}: holds {len(cameras)} cameras; name the image to pick one by its stem"
            )
        name, entry = next(iter(cameras.values()))
    else:
        stem = Path(file.image).stem
        if stem not in cameras:
            raise InputError(
                f"{path}: no camera for image {stem!r} (it has {', '.join(map(repr, cameras))})"
            )
        name, entry = cameras[stem]
    where = f"image {name!r}: "
    if not isinstance(entry, dict) or not isinstance(entry.get("rpc"), dict):
        raise FormatError(path, f"{where}no RPC coefficients (missing rpc)")
    size = entry.get("im_size")
    if not (
        isinstance(size, list)
        and len(size) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)
    ):
        raise FormatError(
            path, f"{where}: im_size must be [width, height] in whole pixels, got {size!r}"
        )
    rpc = {str(key): value for key, value in entry["rpc"].items()}
    names = {key: key for key in RPC_KEYS}
    values: dict[str, object] = {}
    for key in RPC_KEYS:
        if key not in rpc:
            continue
        value = rpc[key]
        if key in COEFFICIENTS:
            if not isinstance(value, list) or len(value) != 20:
                got = len(value) if isinstance(value, list) else repr(value)
                raise FormatError(path, f"{where}{key} must be 20 coefficients, got {got}")
            items = value
        else:
            items = [value]
        for item in items:
            if not (
                isinstance(item, int | float) and not isinstance(item, bool) and math.isfinite(item)
            ):
                raise FormatError(path, f"{where}{key}: {item!r} is not a number")
        values[key] = items if key in COEFFICIENTS else items[0]
    return RpcCamera(_build(path, values, names, {}, where), width=size[0], height=size[1])


def is_tiff(file: CameraFile) -> bool:
    """Whether the file starts as a TIFF or BigTIFF does (reads only those bytes)."""
    try:
        with open_regular(file.path, "camera file") as f:
            return f.read(4) in _TIFF_MAGIC
    except OSError:
        return False


def is_rpc_txt(file: CameraFile) -> bool:
    """Whether the file has an ``_RPC.TXT`` ``LINE_OFF:`` line."""
    return re.search(r"^[ \t]*LINE_OFF[ \t]*:", file.head, re.MULTILINE | re.IGNORECASE) is not None


def is_rpb(file: CameraFile) -> bool:
    """Whether the file has an ``.RPB`` ``lineOffset =`` statement."""
    return re.search(r"\blineOffset\s*=", file.head) is not None


def is_orthority_rpc(file: CameraFile) -> bool:
    """Whether the YAML file has an ``rpc:`` key (Orthority's RPC parameters)."""
    return re.search(r"(?:^|[\s{,])[\"']?rpc[\"']?[ \t]*:", file.head) is not None


FORMATS = (
    CameraFormat("GeoTIFF RPC metadata", (".tif", ".tiff"), read_geotiff, is_tiff),
    CameraFormat("RPC text (_RPC.TXT)", (), read_txt, is_rpc_txt),
    CameraFormat("RPB", (".rpb",), read_rpb, is_rpb),
    CameraFormat(
        "Orthority RPC parameters", (".yaml", ".yml"), read_orthority_rpc, is_orthority_rpc
    ),
)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry (ahead of Orthority's
interior parameter files, which share ``.yaml``). ``_RPC.TXT`` files are recognised by their
content alone: ``.txt`` names no format."""
