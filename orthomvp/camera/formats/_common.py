"""What the camera format modules share: the file being read, the registry entry of a format,
clear errors, building cameras, and the atomic writer.

Readers raise InputError for a file that cannot be read and FormatError, naming the file and
(for text formats) the line, for a file that breaks its format.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from orthomvp.camera.distortion import Distortion, distortion_class
from orthomvp.camera.model import Camera, FieldError, PinholeCamera
from orthomvp.errors import FormatError, InputError
from orthomvp.io.files import read_bounded
from orthomvp.io.outputs import atomic_path


@dataclass(frozen=True)
class CameraFile:
    """A camera file to read, and what multi-camera formats need to pick one camera.

    ``image``: the image (a path or a name) whose camera is wanted; ``interior``: Orthority's
    interior parameter file. Single-camera formats ignore both. The content is read on first use.
    """

    path: Path
    image: str | Path | None = None
    interior: str | Path | None = None

    @cached_property
    def data(self) -> bytes:
        """The file's bytes; InputError if it cannot be read."""
        return read_bytes(self.path, "camera file")

    @cached_property
    def text(self) -> str:
        """The file as text; FormatError if it is not UTF-8."""
        return decode_text(self.path, self.data)

    @cached_property
    def head(self) -> str:
        """The text without leading white space, for recognising the format; "" if not UTF-8."""
        try:
            return self.data.decode("utf-8-sig").lstrip()
        except UnicodeDecodeError:
            return ""


Reader = Callable[[CameraFile], Camera]
"""Reads the camera of a file."""
Sniff = Callable[[CameraFile], bool]
"""Whether a file's content is of a format."""


@dataclass(frozen=True)
class CameraFormat:
    """A camera file format in :mod:`orthomvp.camera`'s registry.

    ``name``: what the format is called in messages; ``suffixes``: the lower-case file name
    extensions that name it; ``read``: its reader; ``sniff``: recognises its content, to choose
    among formats sharing an extension and for files whose extension no format names (None: the
    extension alone tells).
    """

    name: str
    suffixes: tuple[str, ...]
    read: Reader
    sniff: Sniff | None = None


def read_bytes(path: Path, what: str) -> bytes:
    """The contents of ``path``, every camera format's read; InputError naming ``what`` if it
    cannot be read, is not a regular file or is larger than
    :data:`~orthomvp.io.files.MAX_SMALL_FILE` (see :func:`~orthomvp.io.files.read_bounded`)."""
    return read_bounded(path, what)


def decode_text(path: Path, data: bytes) -> str:
    """``data`` decoded as UTF-8 (a byte-order mark dropped); FormatError if it is not text."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not a text file (invalid UTF-8 at byte {exc.start})") from None


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def number(path: Path, token: str, key: str, line: int) -> float:
    """The number ``token`` given for ``key`` at ``line``; FormatError if it is not one."""
    if not _NUMBER.fullmatch(token):
        raise FormatError(path, f"{token!r} after '{key} =' is not a number", line)
    return float(token)


@dataclass(frozen=True)
class Interior:
    """A frame camera's interior parameters, in pixels: focal lengths, principal point, image
    size and lens distortion, as :class:`~orthomvp.camera.model.PinholeCamera` takes them."""

    fu: float
    fv: float
    cu: float
    cv: float
    width: int
    height: int
    distortion: Distortion

    def fields(self) -> dict[str, object]:
        """The PinholeCamera keyword arguments of these parameters."""
        return {name: getattr(self, name) for name in Interior.__dataclass_fields__}


def build_camera(path: Path, where: Callable[[str], int | None], **kwargs: object) -> PinholeCamera:
    """PinholeCamera(**kwargs), its validation errors as FormatError at the line ``where`` gives
    for the offending field's name."""
    try:
        return PinholeCamera(**kwargs)
    except FieldError as exc:
        raise FormatError(path, str(exc), where(exc.field)) from exc


def build_distortion(
    path: Path, name: str, values: Mapping[str, float], line: int | None
) -> Distortion:
    """The distortion model ``name`` with parameters ``values``; FormatError at ``line``."""
    try:
        cls = distortion_class(name)
    except InputError as exc:
        raise FormatError(path, str(exc), line) from None
    missing = [p for p in cls.required_params() if p not in values]
    if missing:
        raise FormatError(path, f"{cls.name} distortion is missing {', '.join(missing)}", line)
    unknown = [p for p in values if p not in cls.param_names()]
    if unknown:
        raise FormatError(path, f"{cls.name} distortion has no parameter {unknown[0]!r}", line)
    try:
        return cls(**values)
    except InputError as exc:
        raise FormatError(path, str(exc), line) from None


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``path`` through
    :func:`orthomvp.io.outputs.atomic_path`; OutputError (naming the path and the cause) if it
    cannot be written."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
