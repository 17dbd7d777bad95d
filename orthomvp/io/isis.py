"""ISIS3 cubes (``.cub``): the PVL label, parsed with pvl, and the raw pixels, read with numpy.

A cube starts with its label, PVL text that ends with a line ``End``. Its
``Object = IsisCube > Object = Core`` says where and how the pixels are stored:

- ``StartByte``: 1-based byte offset of the pixels in the file;
- ``Format``: ``BandSequential`` (band by band, each band line by line) or ``Tile`` (tiles of
  ``TileSamples`` x ``TileLines`` pixels, each band's tiles row by row, the tiles at the right
  and bottom edges padded to full size);
- ``Group = Dimensions``: ``Samples`` (columns), ``Lines`` (rows), ``Bands``;
- ``Group = Pixels``: ``Type`` (``UnsignedByte``, ``SignedWord``, ``UnsignedWord``, ``Real``),
  ``ByteOrder`` (``Lsb``, ``Msb``), ``Base`` and ``Multiplier``: value = Base + Multiplier * raw.

Raw values outside the type's valid range are ISIS special pixels (NULL, LRS, LIS, HIS, HRS) and
become NaN: valid are 1..254 (UnsignedByte), -32752..32767 (SignedWord), 3..65522
(UnsignedWord), and finite Real values >= -3.4028226e38 (VALID_MIN4, bits 0xFF7FFFFA; the five
special floats lie just below it).
"""

from __future__ import annotations

import functools
import re
import string
import sys
import warnings
from collections.abc import Generator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

with warnings.catch_warnings():  # pvl warns on import about an optional library and a rename
    warnings.simplefilter("ignore")
    import pvl
    from pvl.collections import PVLAggregation, PVLGroup, PVLModule, PVLObject
from pvl.decoder import OmniDecoder
from pvl.exceptions import LexerError, ParseError
from pvl.grammar import OmniGrammar
from pvl.parser import OmniParser

from orthomvp.errors import FormatError, InputError
from orthomvp.io.files import MAX_SMALL_FILE, open_regular, read_range

_LABEL_CHUNK = 1 << 16  # bytes read at a time while looking for the label's End line
_START = re.compile(rb"\s*Object\s*=\s*IsisCube\b", re.IGNORECASE)
_END = re.compile(rb"^[ \t]*End[ \t]*\r?$", re.MULTILINE)
_CONTINUATION = re.compile(r"-[\n\r\f]\s*")  # what OmniParser joins before it parses

_VALID_MIN4 = float(np.frombuffer(bytes.fromhex("ff7ffffa"), ">f4")[0])
_TYPES: dict[str, tuple[str, float, float]] = {  # ISIS type -> numpy dtype, valid min, valid max
    "unsignedbyte": ("u1", 1, 254),
    "signedword": ("i2", -32752, 32767),
    "unsignedword": ("u2", 3, 65522),
    "real": ("f4", _VALID_MIN4, float(np.finfo(np.float32).max)),
}
_MISSING = object()


class _BlockError(LexerError):
    """A group or object that does not close with its own end statement."""


_SIGNS = "+-" + string.whitespace  # (dateutil 2.7-2.9 read "--5" and " 1:00" as times)


class _LabelDecoder(OmniDecoder):
    """pvl's permissive decoder, except that a value that does not start with a digit (after
    any signs and spaces) is refused as a date or time at once: every form pvl tries (its
    grammar's strptime formats, dateutil's ISO 8601 and a bare time-zone offset) starts so,
    and trying them on every word of a label took three quarters of a cube label's parse
    (0.2 s)."""

    def decode_datetime(self, value: str) -> Any:
        """A date, time or datetime, as OmniDecoder decodes ``value``; ValueError otherwise."""
        if not value.lstrip(_SIGNS)[:1].isdigit():
            raise ValueError(f"not a date or time: {value}")
        return super().decode_datetime(value)


class _LabelParser(OmniParser):
    """pvl's permissive parser, except that a group or object must close with its own end
    statement (OmniParser drops such a block, and what follows it up to that end, silently),
    and that a stray ``=`` is an error (OmniParser 1.3 loops forever on ``a = 1 = b = 2``)."""

    _repair_at: int | None = None  # where the last repair of an empty value started

    def parse_module_post_hook(self, module: PVLModule, tokens: Generator) -> tuple:
        """OmniParser's repair of empty values, unless it is stuck at the same token."""
        token = next(tokens, None)
        if token is not None:
            tokens.send(token)
            if token.pos == self._repair_at:
                raise ValueError("no progress")  # pvl's callers report the token they stop at
            self._repair_at = token.pos
        return super().parse_module_post_hook(module, tokens)

    def parse_end_aggregation(self, begin_agg: str, block_name: str, tokens: Generator) -> None:
        """Parse a block's end statement; _BlockError for an End or another block's end."""
        try:
            return super().parse_end_aggregation(begin_agg, block_name, tokens)
        except LexerError:
            raise
        except ValueError:
            token = next(tokens)  # the token that did not close the block, put back by pvl
            tokens.send(token)
            kind = "object" if "object" in begin_agg.casefold() else "group"
            ends = {end.casefold() for end in self.grammar.aggregation_keywords.values()}
            if token.is_end_statement():
                message = f"label ends inside {kind} {block_name}"
            elif token.casefold() in ends:
                message = f"{token} does not close {kind} {block_name}"
            else:
                raise
            raise _BlockError(message, self.doc, token.pos + len(token) - 1, token) from None


def parse_label(path: str | Path, text: str) -> PVLModule:
    """Parse PVL label ``text`` (ISIS3, PDS3 and the other PVL dialects) with pvl.

    FormatError naming the line for text that is not PVL and for groups or objects that do not
    close with their own End_Group or End_Object.
    """
    try:
        parser = _LabelParser(decoder=_LabelDecoder(grammar=OmniGrammar()))
        return pvl.loads(text, parser=parser)
    except _BlockError as exc:
        raise FormatError(path, str(exc.msg), _line(text, exc.pos)) from exc
    except LexerError as exc:
        message = f"not a PVL statement: {_one_line(exc.msg)}"
        raise FormatError(path, message, _line(text, exc.pos)) from exc
    except ParseError as exc:
        raise FormatError(path, f"not a PVL statement: {_one_line(exc.args[-1])}") from exc
    except StopIteration:  # pvl ran out of text inside a statement
        raise FormatError(path, "not a PVL statement: the label ends inside one") from None
    except (TypeError, ValueError, ArithmeticError) as exc:  # pvl's decoder, e.g. on 1971-08-0
        raise FormatError(path, f"a value pvl cannot decode ({_one_line(exc)})") from exc


def _one_line(message: object, limit: int = 100) -> str:
    """pvl's error ``message`` on one line, cut to ``limit`` characters."""
    text = " ".join(str(message).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _line(text: str, pos: int) -> int:
    """The line of ``text`` that holds position ``pos`` of what OmniParser parses: ``text`` with
    its continuations (``-`` at the end of a line) joined."""
    for match in _CONTINUATION.finditer(text):
        if match.start() > pos:
            break
        pos += match.end() - match.start()
    return text.count("\n", 0, pos) + 1


def _block(
    node: PVLModule | PVLAggregation, kind: type[PVLAggregation], name: str
) -> PVLAggregation | None:
    """The first group or object (``kind``) called ``name`` in ``node`` (case-insensitive)."""
    for key, value in node.items():
        if isinstance(value, kind) and key.casefold() == name.casefold():
            return value
    return None


def _keyword(node: PVLAggregation, key: str) -> Any:
    """The value of ``node``'s first keyword ``key`` (case-insensitive, units dropped)."""
    for name, value in node.items():
        if not isinstance(value, PVLAggregation) and name.casefold() == key.casefold():
            return value.value if isinstance(value, pvl.Quantity) else value
    return _MISSING


@dataclass(frozen=True)
class CubeLayout:
    """Where and how a cube stores its pixels (see the module docstring)."""

    start: int  # 0-based byte offset
    tiled: bool
    tile_samples: int
    tile_lines: int
    samples: int
    lines: int
    bands: int
    dtype: np.dtype
    valid: tuple[float, float]
    base: float
    multiplier: float
    text: str = field(default="", compare=False, repr=False)  # the label it was read from

    @property
    def nbytes(self) -> int:
        """The size of the pixel data in the file, bytes."""
        across = -(-self.samples // self.tile_samples)
        down = -(-self.lines // self.tile_lines)
        count = across * down * self.tile_samples * self.tile_lines
        return self.bands * count * self.dtype.itemsize


def read_label(path: str | Path) -> PVLModule:
    """The parsed label of the ISIS3 cube at ``path``."""
    return parse_label(path, label_text(path))


def read_layout(path: str | Path, *, known: CubeLayout | None = None) -> CubeLayout:
    """The pixel layout of the ISIS3 cube at ``path`` (:func:`cube_layout`), its label parsed
    once per process for the same path and text: a run reads a cube's pixels tile by tile.
    ``known``: a layout read before (in the planning process, say), taken as it is while the
    file's label is still the text it was read from (a worker process parses no label)."""
    text = label_text(path)
    if known is not None and known.text == text:
        return known
    return _layout(str(path), text)


@functools.lru_cache(maxsize=16)
def _layout(path: str, text: str) -> CubeLayout:
    """:func:`cube_layout` of the label ``text`` of the cube at ``path``."""
    return replace(cube_layout(path, cached_label(path, text)), text=text)


def cached_label(path: str | Path, text: str) -> PVLModule:
    """:func:`parse_label` of ``text``, the label of the cube at ``path``, parsed once per
    process for the same path and text: a cube that is its own camera is read as a camera and
    as an image (about 0.2 s a parse). The module is shared: read it, never change it."""
    return _parsed(str(path), text)


@functools.lru_cache(maxsize=16)
def _parsed(path: str, text: str) -> PVLModule:
    """:func:`parse_label` of ``text`` for :func:`cached_label`."""
    return parse_label(path, text)


def label_text(path: str | Path) -> str:
    """The label of the ISIS3 cube at ``path`` as text, up to and including its End line."""
    path = Path(path)
    try:
        with open_regular(path, "image") as handle:
            head = bytearray()
            while True:
                chunk = handle.read(_LABEL_CHUNK)
                head += chunk
                if not _START.match(head[:_LABEL_CHUNK]):
                    raise FormatError(
                        path, "not an ISIS3 cube: the file does not start 'Object = IsisCube'"
                    )
                # (only the new bytes, and an End line's length before them)
                match = _END.search(head, max(0, len(head) - len(chunk) - 64))
                if match or not chunk or len(head) > MAX_SMALL_FILE:
                    break
    except OSError as exc:
        raise InputError(f"{path}: cannot read image ({exc.strerror})") from exc
    if match is None and len(head) > MAX_SMALL_FILE:
        raise FormatError(path, f"no End line in the label's first {MAX_SMALL_FILE >> 20} MiB", 1)
    if match is None:
        raise FormatError(path, "the cube label has no End line", 1)
    label = head[: match.end()]
    if b"\0" in label:
        raise FormatError(path, "corrupt cube label (NUL bytes before its End line)")
    return label.decode("latin-1")


def read_section(path: str | Path, start: int, size: int) -> bytes:
    """Up to ``size`` bytes of the cube at ``path`` from byte ``start`` (0-based): its pixels or
    a table, as its label places them; never more than the file holds, however large the
    label's count (see :func:`~orthomvp.io.files.read_range`). Fewer: the file is truncated."""
    with open_regular(path, "image") as handle:
        return read_range(handle, start, size)


def cube_layout(path: str | Path, label: PVLModule) -> CubeLayout:
    """The pixel layout that ``label`` describes; FormatError for anything missing or bad."""
    cube = _block(label, PVLObject, "IsisCube")
    core = _block(cube, PVLObject, "Core") if cube is not None else None
    if core is None:
        raise FormatError(path, "the label has no Object = IsisCube > Object = Core")
    if _keyword(core, "^Core") is not _MISSING:
        raise FormatError(path, "detached cube data (^Core) is not supported")
    nodes = {
        "Core": core,
        "Dimensions": _block(core, PVLGroup, "Dimensions"),
        "Pixels": _block(core, PVLGroup, "Pixels"),
    }
    if nodes["Dimensions"] is None or nodes["Pixels"] is None:
        raise FormatError(path, "the Core object lacks its Dimensions or Pixels group")

    def get(node: str, key: str) -> Any:
        value = _keyword(nodes[node], key)
        if value is _MISSING:
            raise FormatError(path, f"the cube label lacks {node} {key}")
        return value

    def integer(node: str, key: str) -> int:
        value = get(node, key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise FormatError(path, f"{key} = {str(value)!r} is not an integer >= 1")
        return value

    def number(node: str, key: str) -> float:
        value = get(node, key)
        real = isinstance(value, int | float) and not isinstance(value, bool)
        if not (real and abs(value) <= sys.float_info.max):  # not NaN, infinite or huge
            raise FormatError(path, f"{key} = {str(value)!r} is not a finite number")
        return float(value)

    kind = str(get("Pixels", "Type"))
    if kind.lower() not in _TYPES:
        known = ", ".join(("UnsignedByte", "SignedWord", "UnsignedWord", "Real"))
        raise FormatError(path, f"pixel type {kind!r} is not supported (supported: {known})")
    code, low, high = _TYPES[kind.lower()]
    order = str(get("Pixels", "ByteOrder"))
    if order.lower() not in ("lsb", "msb"):
        raise FormatError(path, f"ByteOrder = {order!r} is neither Lsb nor Msb")
    fmt = str(get("Core", "Format"))
    if fmt.lower() not in ("tile", "bandsequential"):
        raise FormatError(path, f"Format = {fmt!r} is neither Tile nor BandSequential")
    tiled = fmt.lower() == "tile"
    samples, lines = integer("Dimensions", "Samples"), integer("Dimensions", "Lines")
    return CubeLayout(
        start=integer("Core", "StartByte") - 1,
        tiled=tiled,
        tile_samples=integer("Core", "TileSamples") if tiled else samples,
        tile_lines=integer("Core", "TileLines") if tiled else lines,
        samples=samples,
        lines=lines,
        bands=integer("Dimensions", "Bands"),
        dtype=np.dtype(("<" if order.lower() == "lsb" else ">") + code),
        valid=(low, high),
        base=number("Pixels", "Base"),
        multiplier=number("Pixels", "Multiplier"),
    )


def read_cube(path: str | Path) -> np.ndarray:
    """Read an ISIS3 cube's pixels as float32 ``(bands, lines, samples)``; special pixels NaN.

    Values are Base + Multiplier * raw in float32 arithmetic (Base and Multiplier rounded to
    float32 first; within a float32 ulp or two of the exact value).
    FormatError for a label that is not a cube's, an unsupported layout or a truncated file.
    """
    path = Path(path)
    layout = read_layout(path)
    data = read_section(path, layout.start, layout.nbytes)
    if len(data) < layout.nbytes:
        raise FormatError(
            path,
            f"truncated cube: {layout.nbytes} bytes of pixels expected from byte "
            f"{layout.start + 1}, the file has {len(data)}",
        )
    raw = np.frombuffer(data, layout.dtype)
    ts, tl = layout.tile_samples, layout.tile_lines
    across, down = -(-layout.samples // ts), -(-layout.lines // tl)
    raw = raw.reshape(layout.bands, down, across, tl, ts).transpose(0, 1, 3, 2, 4)
    raw = raw.reshape(layout.bands, down * tl, across * ts)[:, : layout.lines, : layout.samples]
    return cube_values(layout, raw)


def cube_values(layout: CubeLayout, stored: np.ndarray) -> np.ndarray:
    """The float32 values of a cube's ``stored`` numbers (any part of its pixels, as the file
    holds them): Base + Multiplier * stored in float32 arithmetic, NaN at special pixels
    (stored numbers outside the type's valid range)."""
    values = stored.astype(np.float32)
    low, high = layout.valid
    with np.errstate(invalid="ignore"):
        special = ~((values >= low) & (values <= high))
    out = np.float32(layout.base) + np.float32(layout.multiplier) * values
    out[special] = np.nan
    return out
