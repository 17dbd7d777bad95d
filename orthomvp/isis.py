"""ISIS3 cubes (``.cub``): the PVL label and the raw pixels, read with numpy, without ISIS.

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

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from orthomvp.errors import FormatError, InputError

_LABEL_CHUNK = 1 << 16  # bytes read at a time while looking for the label's End line
_LABEL_LIMIT = 1 << 26  # give up looking for the End line after this many bytes
_END = re.compile(rb"^[ \t]*End[ \t]*\r?$", re.MULTILINE)
_STATEMENT = re.compile(r"\^?([^\s=]+)\s*=\s*(.*)")
_COMMENT = re.compile(r"/\*.*?\*/", re.DOTALL)

_VALID_MIN4 = float(np.frombuffer(bytes.fromhex("ff7ffffa"), ">f4")[0])
_TYPES: dict[str, tuple[str, float, float]] = {  # ISIS type -> numpy dtype, valid min, valid max
    "unsignedbyte": ("u1", 1, 254),
    "signedword": ("i2", -32752, 32767),
    "unsignedword": ("u2", 3, 65522),
    "real": ("f4", _VALID_MIN4, float(np.finfo(np.float32).max)),
}


@dataclass
class PvlNode:
    """A PVL object or group: its keywords (name -> (text value, line)) and child nodes."""

    kind: str
    name: str
    keywords: dict[str, tuple[str, int]] = field(default_factory=dict)
    children: list[PvlNode] = field(default_factory=list)

    def child(self, kind: str, name: str) -> PvlNode | None:
        """The first child ``kind`` (object or group) called ``name`` (case-insensitive)."""
        for node in self.children:
            if node.kind == kind and node.name.lower() == name.lower():
                return node
        return None


def parse_label(path: str | Path, text: str) -> PvlNode:
    """Parse PVL label ``text`` (up to its ``End`` line) into a tree of objects and groups.

    Keyword values are kept as text (units in ``<...>`` and enclosing quotes removed); a value
    continues on the next lines while its quotes or brackets are open or it ends with ``-``
    (PVL's word continuation). Comments ``/* ... */`` are ignored. FormatError on unbalanced
    objects or groups and on lines that are not statements.
    """
    root = PvlNode("root", "")
    stack = [root]
    lines = _COMMENT.sub(lambda m: "\n" * m.group().count("\n"), text).splitlines()
    number = 0
    while number < len(lines):
        line = lines[number].strip()
        number += 1
        if not line:
            continue
        lowered = line.lower()
        if lowered == "end":
            if len(stack) > 1:
                raise FormatError(path, f"label ends inside {stack[-1].kind} {stack[-1].name}")
            return root
        if lowered in ("end_object", "end_group", "endobject", "endgroup"):
            kind = "object" if "object" in lowered else "group"
            if stack[-1].kind != kind:
                raise FormatError(path, f"{line} does not close a {kind}", number)
            stack.pop()
            continue
        match = _STATEMENT.fullmatch(line)
        if match is None:
            raise FormatError(path, f"not a PVL statement: {line[:60]!r}", number)
        key, value, start = match[1], match[2], number
        while number < len(lines) and _continues(value):
            value = (value[:-1] if value.endswith("-") else value + " ") + lines[number].strip()
            number += 1
        if key.lower() in ("object", "group"):
            node = PvlNode(key.lower(), _plain(value))
            stack[-1].children.append(node)
            stack.append(node)
        else:
            stack[-1].keywords.setdefault(key, (_plain(value), start))
    raise FormatError(path, "the label has no End line")


def _continues(value: str) -> bool:
    """Whether a PVL value goes on to the next line."""
    unquoted = re.sub(r'"[^"]*"', "", value)
    if unquoted.count('"') % 2:
        return True
    return unquoted.count("(") > unquoted.count(")") or unquoted.count("{") > unquoted.count(
        "}"
    ) or value.endswith("-")  # fmt: skip


def _plain(value: str) -> str:
    """A value without its units and enclosing quotes."""
    value = re.sub(r"\s*<[^<>]*>\s*$", "", value.strip())
    if len(value) >= 2 and value[0] == value[-1] and value[0] in "\"'":
        return value[1:-1]
    return value


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

    @property
    def nbytes(self) -> int:
        """The size of the pixel data in the file, bytes."""
        across = -(-self.samples // self.tile_samples)
        down = -(-self.lines // self.tile_lines)
        count = across * down * self.tile_samples * self.tile_lines
        return self.bands * count * self.dtype.itemsize


def read_label(path: str | Path) -> PvlNode:
    """The parsed label of the ISIS3 cube at ``path``."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            head = b""
            while True:
                chunk = handle.read(_LABEL_CHUNK)
                head += chunk
                match = _END.search(head)
                if match or not chunk or len(head) > _LABEL_LIMIT:
                    break
    except FileNotFoundError:
        raise InputError(f"{path}: image not found") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read image ({exc.strerror})") from exc
    if not re.match(rb"\s*Object\s*=\s*IsisCube\b", head, re.IGNORECASE):
        raise FormatError(path, "not an ISIS3 cube: the file does not start 'Object = IsisCube'")
    if match is None:
        raise FormatError(path, "the cube label has no End line", 1)
    label = head[: match.end()]
    if b"\0" in label:
        raise FormatError(path, "corrupt cube label (NUL bytes before its End line)")
    return parse_label(path, label.decode("latin-1"))


def cube_layout(path: str | Path, label: PvlNode) -> CubeLayout:
    """The pixel layout that ``label`` describes; FormatError for anything missing or bad."""
    cube = label.child("object", "IsisCube")
    core = cube.child("object", "Core") if cube else None
    if core is None:
        raise FormatError(path, "the label has no Object = IsisCube > Object = Core")
    if "^Core" in core.keywords or "^core" in core.keywords:
        raise FormatError(path, "detached cube data (^Core) is not supported")
    dims = core.child("group", "Dimensions")
    pixels = core.child("group", "Pixels")
    if dims is None or pixels is None:
        raise FormatError(path, "the Core object lacks its Dimensions or Pixels group")

    def get(node: PvlNode, key: str) -> tuple[str, int]:
        for name, value in node.keywords.items():
            if name.lower() == key.lower():
                return value
        raise FormatError(path, f"the cube label lacks {node.name} {key}")

    def integer(node: PvlNode, key: str, minimum: int = 1) -> int:
        text, line = get(node, key)
        if not re.fullmatch(r"[+-]?\d+", text) or int(text) < minimum:
            raise FormatError(path, f"{key} = {text!r} is not an integer >= {minimum}", line)
        return int(text)

    def number(node: PvlNode, key: str) -> float:
        text, line = get(node, key)
        try:
            value = float(text)
        except ValueError:
            value = np.nan
        if not np.isfinite(value):
            raise FormatError(path, f"{key} = {text!r} is not a finite number", line)
        return value

    kind, line = get(pixels, "Type")
    if kind.lower() not in _TYPES:
        known = ", ".join(("UnsignedByte", "SignedWord", "UnsignedWord", "Real"))
        raise FormatError(path, f"pixel type {kind!r} is not supported (supported: {known})", line)
    code, low, high = _TYPES[kind.lower()]
    order, line = get(pixels, "ByteOrder")
    if order.lower() not in ("lsb", "msb"):
        raise FormatError(path, f"ByteOrder = {order!r} is neither Lsb nor Msb", line)
    fmt, line = get(core, "Format")
    if fmt.lower() not in ("tile", "bandsequential"):
        raise FormatError(path, f"Format = {fmt!r} is neither Tile nor BandSequential", line)
    tiled = fmt.lower() == "tile"
    samples, lines = integer(dims, "Samples"), integer(dims, "Lines")
    return CubeLayout(
        start=integer(core, "StartByte") - 1,
        tiled=tiled,
        tile_samples=integer(core, "TileSamples") if tiled else samples,
        tile_lines=integer(core, "TileLines") if tiled else lines,
        samples=samples,
        lines=lines,
        bands=integer(dims, "Bands"),
        dtype=np.dtype(("<" if order.lower() == "lsb" else ">") + code),
        valid=(low, high),
        base=number(pixels, "Base"),
        multiplier=number(pixels, "Multiplier"),
    )


def read_cube(path: str | Path) -> np.ndarray:
    """Read an ISIS3 cube's pixels as float32 ``(bands, lines, samples)``; special pixels NaN.

    Values are Base + Multiplier * raw in float32 arithmetic (Base and Multiplier rounded to
    float32 first; within a float32 ulp or two of the exact value).
    FormatError for a label that is not a cube's, an unsupported layout or a truncated file.
    """
    path = Path(path)
    layout = cube_layout(path, read_label(path))
    with path.open("rb") as handle:
        handle.seek(layout.start)
        data = handle.read(layout.nbytes)
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
    values = raw.astype(np.float32)
    low, high = layout.valid
    with np.errstate(invalid="ignore"):
        special = ~((values >= low) & (values <= high))
    out = np.float32(layout.base) + np.float32(layout.multiplier) * values
    out[special] = np.nan
    return out
