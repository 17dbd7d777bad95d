"""Vision Workbench's pinhole camera files (VW's ``TsaiFile``): ``.tsai`` text and ``.pinhole``.

``.tsai`` text: ASP/VW VERSION_1 to VERSION_4 and the unversioned form, read as VW's
``PinholeModel::read`` does and written as VERSION_4 with every number exact. ``.pinhole``:
VW's binary protobuf of the same fields (``TsaiFile.proto``), decoded here without a protobuf
library. Units and conventions are those of :class:`orthomvp.camera.model.PinholeCamera`.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from orthomvp.camera.distortion import distortion_class
from orthomvp.camera.formats._common import (
    CameraFile,
    CameraFormat,
    build_camera,
    build_distortion,
    number,
    write_text,
)
from orthomvp.camera.model import PinholeCamera
from orthomvp.errors import FormatError, InputError

# .tsai text

_KEY_VALUES = re.compile(r"(\w+)\s*=\s*(.*)")
_TSAI_KEYS = (
    ("fu", "fu", 1),
    ("fv", "fv", 1),
    ("cu", "cu", 1),
    ("cv", "cv", 1),
    ("u_direction", "u_direction", 3),
    ("v_direction", "v_direction", 3),
    ("w_direction", "w_direction", 3),
    ("C", "center", 3),
    ("R", "rotation", 9),
)


class _Lines:
    """The non-blank lines of a text file, read one by one with their 1-based numbers."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        lines = text.splitlines()
        self.items = [(i + 1, s.strip()) for i, s in enumerate(lines) if s.strip()]
        self.end = len(lines) + 1
        self.pos = 0

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def take(self, expected: str) -> tuple[int, str]:
        """The next line; FormatError saying ``expected`` at the end of the file."""
        item = self.peek()
        if item is None:
            raise FormatError(self.path, f"file ends where {expected} was expected", self.end)
        self.pos += 1
        return item

    def numbers(self, key: str, count: int) -> tuple[list[float], int]:
        """Parse the next line as ``key = n1 ... n<count>``; returns the numbers and line."""
        line, text = self.take(f"'{key} = ...'")
        match = _KEY_VALUES.fullmatch(text)
        if match is None or match[1] != key:
            raise FormatError(self.path, f"expected '{key} = ...', found {text!r}", line)
        tokens = match[2].split()
        if len(tokens) != count:
            plural = "number" if count == 1 else "numbers"
            raise FormatError(
                self.path, f"expected {count} {plural} after '{key} =', found {len(tokens)}", line
            )
        return [number(self.path, t, key, line) for t in tokens], line


def is_tsai(file: CameraFile) -> bool:
    """Whether the file looks like ``.tsai`` text: it starts with ``VERSION_`` or ``fu =``."""
    return re.match(r"VERSION_|fu\s*=", file.head) is not None


def read_tsai(file: CameraFile) -> PinholeCamera:
    """The camera of a ``.tsai`` text file (see :func:`parse_tsai`)."""
    return parse_tsai(file.path, file.text)


def parse_tsai(path: Path, text: str) -> PinholeCamera:
    """Parse ASP/VW ``.tsai`` text, following VW's ``PinholeModel::read``.

    VERSION_4 has a ``PINHOLE`` line after the version; VERSION_3 and 4 need ``pitch`` and the
    distortion name. The unversioned (and VERSION_1/2) form may omit ``pitch`` (1) and the name,
    in which case TSAI parameters follow directly.
    """
    lines = _Lines(path, text)
    version = 1
    first = lines.peek()
    if first is None:
        raise FormatError(path, "empty camera file", 1)
    if first[1].startswith("VERSION"):
        line, header = lines.take("VERSION_4")
        match = re.fullmatch(r"VERSION_(\d+)", header)
        if match is None or not 1 <= int(match[1]) <= 4:
            raise FormatError(path, f"unsupported version {header!r} (expected VERSION_1..4)", line)
        version = int(match[1])
        if version == 4:
            line, kind = lines.take("'PINHOLE'")
            if kind != "PINHOLE":
                raise FormatError(
                    path, f"camera type {kind!r} is not supported, only PINHOLE", line
                )
    values: dict[str, object] = {}
    where: dict[str, int] = {}
    for key, name, count in _TSAI_KEYS:
        numbers, where[name] = lines.numbers(key, count)
        values[name] = (
            numbers[0] if count == 1 else np.reshape(numbers, (3, 3) if count == 9 else 3)
        )
    nxt = lines.peek()
    if version >= 3 or (nxt is not None and nxt[1].startswith("pitch")):
        (values["pitch"],), where["pitch"] = lines.numbers("pitch", 1)
    nxt = lines.peek()
    if version <= 2 and nxt is not None and _KEY_VALUES.fullmatch(nxt[1]):
        model, name_line = "TSAI", nxt[0]  # old files: TSAI parameters without a name line
    else:
        name_line, model = lines.take("the lens distortion name (NULL, TSAI, ...)")
    try:
        names = distortion_class(model).param_names()
    except InputError as exc:
        raise FormatError(path, str(exc), name_line) from None
    params: dict[str, float] = {}
    while lines.peek() is not None:
        line, text_ = lines.take("")
        match = _KEY_VALUES.fullmatch(text_)
        if match is None or len(match[2].split()) != 1:
            raise FormatError(path, f"expected '<parameter> = <number>', found {text_!r}", line)
        if match[1] not in names:
            raise FormatError(path, f"{model} distortion has no parameter {match[1]!r}", line)
        if match[1] in params:
            raise FormatError(path, f"distortion parameter {match[1]!r} given twice", line)
        params[match[1]] = number(path, match[2].strip(), match[1], line)
    values["distortion"] = build_distortion(path, model, params, name_line)
    return build_camera(path, where.get, **values)


# .pinhole protobuf

_PB_DOUBLES = {
    2: ("focal_length", 2),
    3: ("center_point", 2),
    4: ("u_direction", 3),
    5: ("v_direction", 3),
    6: ("w_direction", 3),
    7: ("camera_center", 3),
    8: ("camera_rotation", 9),
    10: ("distortion_vector", None),
    11: ("pixel_pitch", 1),
}


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    """Decode a base-128 varint at ``pos``; returns the value and the position after it."""
    start, value, shift = pos, 0, 0
    while True:
        if pos >= len(data):
            raise ValueError(f"truncated varint at byte {start}")
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7
        if shift >= 70:
            raise ValueError(f"varint longer than 10 bytes at byte {start}")


def decode_protobuf(data: bytes) -> dict[int, list[tuple[int, bytes]]]:
    """Split a protobuf message into its fields: number -> [(wire type, raw bytes), ...].

    Handles wire types 0 (varint; the value is dropped, TsaiFile has no varint field),
    1 (64-bit), 2 (length-delimited) and 5 (32-bit); raises ValueError, naming the byte offset,
    on anything malformed.
    """
    if not data:
        raise ValueError("empty file")
    out: dict[int, list[tuple[int, bytes]]] = {}
    pos = 0
    while pos < len(data):
        start = pos
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise ValueError(f"invalid field number 0 at byte {start}")
        if wire == 0:
            pos = _varint(data, pos)[1]
            size = 0
        elif wire == 2:
            size, pos = _varint(data, pos)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
        else:
            raise ValueError(f"unsupported wire type {wire} (field {number}) at byte {start}")
        if pos + size > len(data):
            raise ValueError(f"field {number} at byte {start} runs past the end of the file")
        out.setdefault(number, []).append((wire, data[pos : pos + size]))
        pos += size
    return out


def _pb_doubles(number: int, entries: list[tuple[int, bytes]]) -> list[float]:
    """The doubles of a repeated double field, packed (wire type 2) or not (wire type 1)."""
    values: list[float] = []
    for wire, raw in entries:
        if wire not in (1, 2):
            raise ValueError(f"field {number} has wire type {wire}, expected doubles")
        if len(raw) % 8:
            raise ValueError(f"field {number}: {len(raw)} bytes of packed doubles")
        values.extend(struct.unpack(f"<{len(raw) // 8}d", raw))
    return values


def is_pinhole(file: CameraFile) -> bool:
    """Whether the file decodes as a protobuf message (the ``.pinhole`` form)."""
    data = file.data  # (a file that cannot be read: its InputError, not a ValueError here)
    try:
        decode_protobuf(data)
    except ValueError:
        return False
    return True


def read_pinhole(file: CameraFile) -> PinholeCamera:
    """The camera of a binary ``.pinhole`` file."""
    data = file.data
    try:
        decoded = decode_protobuf(data)
    except ValueError as exc:
        raise FormatError(file.path, f"corrupt .pinhole protobuf: {exc}") from exc
    return camera_from_protobuf(file.path, decoded)


def camera_from_protobuf(path: Path, decoded: dict[int, list[tuple[int, bytes]]]) -> PinholeCamera:
    """A camera from the fields of a VW ``TsaiFile`` message (see TsaiFile.proto)."""
    try:
        entries = decoded.get(9, [])
        if not entries or entries[-1][0] != 2:
            raise ValueError("the required distortion_name (field 9) is missing")
        distortion_name = entries[-1][1].decode("utf-8")
        got: dict[str, list[float]] = {}
        for number, (name, count) in _PB_DOUBLES.items():
            values = _pb_doubles(number, decoded.get(number, []))
            if number == 11 and values:
                values = values[-1:]  # a non-repeated field: the last value wins
            if count is not None and len(values) != count:
                raise ValueError(
                    f"{name} (field {number}) has {len(values)} values, expected {count}"
                )
            got[name] = values
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"bad .pinhole camera: {exc}") from exc
    dist_values = got["distortion_vector"]
    try:
        cls = distortion_class(distortion_name)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None
    counts = range(len(cls.required_params()), len(cls.param_names()) + 1)
    if len(dist_values) not in counts:
        raise FormatError(
            path,
            f"{distortion_name} distortion needs {' or '.join(map(str, counts))} values, "
            f"got {len(dist_values)}",
        )
    distortion = build_distortion(
        path, cls.name, dict(zip(cls.param_names(), dist_values, strict=False)), None
    )
    return build_camera(
        path,
        lambda _: None,
        fu=got["focal_length"][0],
        fv=got["focal_length"][1],
        cu=got["center_point"][0],
        cv=got["center_point"][1],
        u_direction=got["u_direction"],
        v_direction=got["v_direction"],
        w_direction=got["w_direction"],
        center=got["camera_center"],
        rotation=np.reshape(got["camera_rotation"], (3, 3)),  # row-major, as VW's MatrixProxy
        pitch=got["pixel_pitch"][0],
        distortion=distortion,
    )


FORMATS = (
    CameraFormat(".tsai text", (".tsai",), read_tsai, is_tsai),
    CameraFormat("a .pinhole protobuf", (".pinhole",), read_pinhole, is_pinhole),
)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry."""


# Writing


def _fmt(*values: float) -> str:
    """Shortest round-trip text of each value (Python repr), space-separated."""
    return " ".join(repr(float(v)) for v in values)


def tsai_text(camera: PinholeCamera) -> str:
    """The camera as ASP/VW VERSION_4 ``.tsai`` text, every number exact."""
    lines = [
        "VERSION_4",
        "PINHOLE",
        f"fu = {_fmt(camera.fu)}",
        f"fv = {_fmt(camera.fv)}",
        f"cu = {_fmt(camera.cu)}",
        f"cv = {_fmt(camera.cv)}",
        f"u_direction = {_fmt(*camera.u_direction)}",
        f"v_direction = {_fmt(*camera.v_direction)}",
        f"w_direction = {_fmt(*camera.w_direction)}",
        f"C = {_fmt(*camera.center)}",
        f"R = {_fmt(*camera.rotation.ravel())}",
        f"pitch = {_fmt(camera.pitch)}",
        camera.distortion.name,
    ]
    lines += [f"{name} = {_fmt(value)}" for name, value in camera.distortion.params().items()]
    return "\n".join(lines) + "\n"


def write_tsai(camera: PinholeCamera, path: str | Path) -> None:
    """Write ``camera`` as VERSION_4 ``.tsai`` text (the image size is not stored)."""
    write_text(path, tsai_text(camera))
