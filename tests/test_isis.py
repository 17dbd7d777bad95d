"""Tests of orthomvp.io.isis: ISIS3 cube labels and raw pixels, and read_image's dispatch to them.

Synthetic cubes are written here with hand-made labels in both storage formats and byte orders;
the real Apollo 15 cube in ../shared/data is compared with its float32 GeoTIFF conversion.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pvl
import pytest
import rasterio
from conftest import shared

from orthomvp.errors import FormatError, InputError
from orthomvp.io.isis import label_text, parse_label, read_cube, read_label
from orthomvp.io.raster import read_image

# ISIS special pixels (SpecialPixel.h): each type's NULL, LRS, LIS, HIS, HRS raw values, and the
# edges of its valid range (VALID_MIN, VALID_MAX), which must stay valid
SPECIAL = {
    "UnsignedByte": ("u1", [0, 255], [1, 254]),
    "SignedWord": ("i2", [-32768, -32767, -32766, -32765, -32764, -32753], [-32752, 32767]),
    "UnsignedWord": ("u2", [0, 1, 2, 65534, 65535], [3, 65522]),
}
REAL_SPECIAL = ["ff7ffffb", "ff7ffffc", "ff7ffffd", "ff7ffffe", "ff7fffff", "7fc00000"]
REAL_VALID = ["ff7ffffa", "7f7fffff"]  # VALID_MIN4 and the largest float32


def label(
    samples: int,
    lines: int,
    bands: int,
    kind: str,
    order: str,
    tile: tuple[int, int] | None,
    base: float = 0.0,
    multiplier: float = 1.0,
    start: int = 1025,
) -> str:
    """A minimal ISIS3 label in the layout ISIS writes, with a few other groups and comments."""
    fmt = (
        f"    Format      = Tile\n    TileSamples = {tile[0]}\n    TileLines   = {tile[1]}\n"
        if tile
        else "    Format      = BandSequential\n"
    )
    return (
        "Object = IsisCube\n  Object = Core\n"
        f"    StartByte   = {start}\n{fmt}"
        "    /* dimensions */\n"
        f"    Group = Dimensions\n      Samples = {samples}\n      Lines   = {lines}\n"
        f"      Bands   = {bands}\n    End_Group\n\n"
        f"    Group = Pixels\n      Type       = {kind}\n      ByteOrder  = {order}\n"
        f"      Base       = {base!r}\n      Multiplier = {multiplier!r}\n    End_Group\n"
        "  End_Object\n\n"
        '  Group = Instrument\n    SpacecraftName = "APOLLO 15"\n'
        "    StartTime      = 1971-08-01T11:41:16.865\n"
        "    Kernel         = $apollo15/kernels/ik/apollo15_metric_v2.0001.-\n"
        "                     ti\n"
        "    Focal          = 76.054 <millimeters>\n"
        "    List           = (1.0, 2.0,\n                      3.0)\n"
        "  End_Group\nEnd_Object\n\n"
        "Object = Label\n  Bytes = 1024\nEnd_Object\nEnd\n"
    )


def write_cube(
    path: Path,
    raw: np.ndarray,
    kind: str,
    order: str,
    tile: tuple[int, int] | None,
    base: float = 0.0,
    multiplier: float = 1.0,
) -> None:
    """Write ``raw`` (bands, lines, samples) as a cube, tiles padded with junk at the edges."""
    bands, lines, samples = raw.shape
    dtype = raw.dtype.newbyteorder("<" if order == "Lsb" else ">")
    if tile:
        ts, tl = tile
        across, down = -(-samples // ts), -(-lines // tl)
        padded = np.full((bands, down * tl, across * ts), raw.flat[0], dtype)
        padded[:, :lines, :samples] = raw
        data = padded.reshape(bands, down, tl, across, ts).transpose(0, 1, 3, 2, 4).tobytes()
    else:
        data = raw.astype(dtype).tobytes()
    text = label(samples, lines, bands, kind, order, tile, base, multiplier).encode()
    assert len(text) < 1024
    path.write_bytes(text + b"\0" * (1024 - len(text)) + data)


def synthetic_raw(kind: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(2, 7, 9) raw pixels of ``kind`` with special and edge values, and the special mask."""
    shape = (2, 7, 9)
    if kind == "Real":
        raw = rng.normal(0, 1000, shape).astype(np.float32)
        specials = [np.frombuffer(bytes.fromhex(h), ">f4")[0] for h in REAL_SPECIAL]
        edges = [np.frombuffer(bytes.fromhex(h), ">f4")[0] for h in REAL_VALID]
    else:
        code, specials, edges = SPECIAL[kind]
        info = np.iinfo(code)
        raw = rng.integers(max(info.min, -1000) + 10, min(info.max, 1000) - 10, shape).astype(code)
    mask = np.zeros(shape, bool)
    flat = rng.choice(raw.size, len(specials) + len(edges), replace=False)
    for index, value in zip(flat, [*specials, *edges], strict=True):
        raw.flat[index] = value
    mask.flat[flat[: len(specials)]] = True
    return raw, mask


@pytest.mark.parametrize("kind", ["UnsignedByte", "SignedWord", "UnsignedWord", "Real"])
@pytest.mark.parametrize("order", ["Lsb", "Msb"])
@pytest.mark.parametrize("tile", [None, (4, 3), (9, 7)], ids=["bsq", "tile4x3", "tile9x7"])
def test_synthetic_cubes(tmp_path: Path, kind: str, order: str, tile: tuple[int, int]) -> None:
    rng = np.random.default_rng(sum(map(ord, f"{kind}{order}{tile}")))
    raw, special = synthetic_raw(kind, rng)
    base, multiplier = (0.0, 1.0) if kind == "Real" else (-12.5, 0.25)
    path = tmp_path / "cube.cub"
    write_cube(path, raw, kind, order, tile, base, multiplier)
    got = read_image(path)
    assert got.dtype == np.float32 and got.shape == (2, 7, 9)
    np.testing.assert_array_equal(np.isnan(got), special)
    expected = np.float32(base) + np.float32(multiplier) * raw.astype(np.float32)
    np.testing.assert_array_equal(got[~special], expected[~special])


def test_upper_case_suffix_and_label_tree(tmp_path: Path) -> None:
    raw = np.arange(12, dtype=np.int16).reshape(1, 3, 4)
    path = tmp_path / "IMAGE.CUB"
    write_cube(path, raw, "SignedWord", "Lsb", (2, 2), base=1.0, multiplier=2.0)
    np.testing.assert_array_equal(read_image(path)[0], 1.0 + 2.0 * raw[0])
    tree = read_label(path)
    instrument = tree["IsisCube"]["Instrument"]
    assert instrument["SpacecraftName"] == "APOLLO 15"
    assert instrument["Kernel"] == "$apollo15/kernels/ik/apollo15_metric_v2.0001.ti"
    assert instrument["Focal"] == pvl.Quantity(76.054, "millimeters")
    assert instrument["List"] == [1.0, 2.0, 3.0]
    assert tree["Label"]["Bytes"] == 1024
    np.testing.assert_array_equal(read_cube(path), read_image(path))


@pytest.mark.realdata
def test_real_hadley_cube_matches_its_geotiff() -> None:
    cube = read_image(shared("as15-hadley", "AS15-M-1134-hadley.cub"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(shared("as15-hadley", "AS15-M-1134-hadley.tif")) as src:
            reference = src.read()
    assert cube.shape == reference.shape == (1, 750, 750)
    assert np.array_equal(cube, reference, equal_nan=True)


def test_images_of_other_formats_read_quietly(tmp_path: Path) -> None:
    data = (np.arange(3 * 20 * 30) % 251).astype(np.uint8).reshape(3, 20, 30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        for driver, name in (("PNG", "a.png"), ("JPEG", "a.jpg"), ("GTiff", "a.tif")):
            with rasterio.open(
                tmp_path / name, "w", driver=driver, width=30, height=20, count=3, dtype="uint8"
            ) as dst:
                dst.write(data)
        with rasterio.open(
            tmp_path / "b.tif", "w", driver="GTiff", width=30, height=20, count=2,
            dtype="int16", nodata=-9999,
        ) as dst:  # fmt: skip
            dst.write(np.stack([data[0].astype(np.int16) - 100, np.full((20, 30), -9999)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no NotGeoreferencedWarning escapes
        for name in ("a.png", "a.jpg", "a.tif"):
            image = read_image(tmp_path / name)
            assert image.shape == (3, 20, 30) and image.dtype == np.float32
        np.testing.assert_array_equal(read_image(tmp_path / "a.png"), data)
        both = read_image(tmp_path / "b.tif")
    np.testing.assert_array_equal(both[0], data[0] - 100.0)
    assert np.isnan(both[1]).all()


def corrupt(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


GOOD = label(4, 3, 1, "SignedWord", "Lsb", None)
BAD_LABELS = {
    "not a cube": ("PDS_VERSION_ID = PDS3\nEnd\n", "not an ISIS3 cube"),
    "no End": (GOOD.replace("\nEnd\n", "\n"), "no End line"),
    "no Core": (corrupt(GOOD, "Object = Core", "Object = Kore"), "no Object = IsisCube > Object"),
    "no Samples": (corrupt(GOOD, "Samples = 4", "Sample = 4"), "lacks Dimensions Samples"),
    "bad Lines": (corrupt(GOOD, "Lines   = 3", "Lines   = three"), "Lines = 'three' is not"),
    "zero Bands": (corrupt(GOOD, "Bands   = 1", "Bands   = 0"), "Bands = '0' is not an integer"),
    "Double": (corrupt(GOOD, "SignedWord", "Double"), "pixel type 'Double' is not supported"),
    "byte order": (corrupt(GOOD, "= Lsb", "= Middle"), "ByteOrder = 'Middle' is neither"),
    "format": (corrupt(GOOD, "= BandSequential", "= Bil"), "Format = 'Bil' is neither"),
    "no tile size": (corrupt(GOOD, "= BandSequential", "= Tile"), "lacks Core TileSamples"),
    "bad base": (corrupt(GOOD, "Base       = 0.0", "Base       = nan"), "Base = 'nan'"),
    "unbalanced": (corrupt(GOOD, "    End_Group\n\n", "    End_Object\n\n"), "does not close"),
    "junk line": (corrupt(GOOD, "/* dimensions */", "dimensions here"), "not a PVL statement"),
    "open object": (corrupt(GOOD, "End_Object\nEnd\n", "End\n"), "label ends inside object"),
    "open quote": (corrupt(GOOD, '"APOLLO 15"', '"APOLLO 15'), "not a PVL statement"),
    "open unit": (
        corrupt(GOOD, "    End_Group\n  End_Object\n\n  Group = Instrument", " <  End_Group"),
        "not a PVL statement: the label ends inside one",
    ),
    "detached": (corrupt(GOOD, "StartByte   = 1025", "^Core = data.cub"), "detached cube data"),
    "empty Lines": (corrupt(GOOD, "Lines   = 3", "Lines   ="), "Lines = '' is not an integer"),
    "stray =": (corrupt(GOOD, "      Multiplier", "  =    Multiplier"), "not a PVL statement"),
    "bad date": (corrupt(GOOD, "1971-08-01T", "1971-08-0 T"), "a value pvl cannot decode"),
}


@pytest.mark.parametrize("case", list(BAD_LABELS))
def test_corrupt_labels(tmp_path: Path, case: str) -> None:
    text, message = BAD_LABELS[case]
    path = tmp_path / "bad.cub"
    path.write_bytes(text.encode().ljust(1024, b"\0") + bytes(24))
    with pytest.raises(FormatError, match=message.replace("(", r"\(")) as info:
        read_image(path)
    assert str(info.value).startswith(str(path))


def test_truncated_and_missing_cubes(tmp_path: Path) -> None:
    path = tmp_path / "cube.cub"
    write_cube(path, np.zeros((2, 5, 6), np.uint16), "UnsignedWord", "Msb", (4, 4))
    data = path.read_bytes()
    assert len(data) == 1024 + 2 * 2 * 2 * 16 * 2  # two bands of 2 x 2 padded 4 x 4 tiles
    path.write_bytes(data[:-1])
    with pytest.raises(FormatError, match="truncated cube: 256 bytes of pixels expected from byte "
                       "1025, the file has 255"):  # fmt: skip
        read_image(path)
    path.write_bytes(b"Object = IsisCube\n\0\0garbage End\n")
    with pytest.raises(FormatError, match="no End line|NUL"):
        read_image(path)
    with pytest.raises(InputError, match="not found"):
        read_image(tmp_path / "missing.cub")


def test_parse_label_errors_name_the_line(tmp_path: Path) -> None:
    with pytest.raises(FormatError) as info:
        parse_label(tmp_path / "x.cub", "Object = IsisCube\n  Group = A\n  End_Object\nEnd\n")
    assert info.value.line == 3
    # lines of the file as written, although pvl joins the Kernel value's two lines first
    for case, line in (("unbalanced", 10), ("open object", 33)):
        text = BAD_LABELS[case][0]
        assert text.splitlines()[line - 1].strip() in ("End_Object", "End")
        with pytest.raises(FormatError) as info:
            parse_label(tmp_path / "x.cub", text)
        assert info.value.line == line


DATES = """Object = IsisCube
  Group = Instrument
    StartTime = 1971-08-01T11:41:16.865Z
    StopTime = 1971-213T11:41:17
    Day = 1971-08-01
    Clock = 12:00:01.5
    Compact = 19710801T114116
    Offset = 1971-08-01T11:41:16+07:00
    Word = Tile
    Number = 2024
    Signed = -12:00
    Odd = --5
    Mixed = (1971-08-01, Lsb, 3.5, 12:00)
  End_Group
End_Object
End
"""


def _flat(node: object, prefix: str = "") -> list[tuple]:
    """Every keyword of a parsed label with the type and value it decoded to."""
    out = []
    for key, value in node.items():
        if isinstance(value, (pvl.PVLModule, pvl.PVLGroup, pvl.PVLObject)):
            out += [(prefix + key, type(value).__name__), *_flat(value, prefix + key + "/")]
        else:
            out.append((prefix + key, type(value).__name__, repr(value)))
    return out


def test_labels_decode_as_pvls_own_parser_does() -> None:
    """The label parser refuses a value as a date at once unless it starts with a digit after
    any signs; every value still decodes as pvl's OmniParser decodes it (dates, times, zone
    offsets, words, numbers)."""
    from pvl.parser import OmniParser

    assert _flat(parse_label("x.cub", DATES)) == _flat(pvl.loads(DATES, parser=OmniParser()))
    decoded = dict((k, v) for k, *v in _flat(parse_label("x.cub", DATES)))
    assert decoded["IsisCube/Instrument/StartTime"][0] == "datetime"
    assert decoded["IsisCube/Instrument/Day"][0] == "date"
    assert decoded["IsisCube/Instrument/Clock"][0] == "time"
    assert decoded["IsisCube/Instrument/Signed"][0] == "time"
    assert decoded["IsisCube/Instrument/Word"] == ["str", "'Tile'"]


@pytest.mark.realdata
@pytest.mark.parametrize(
    "parts",
    [("as15-hadley", "AS15-M-1134-hadley.cub"), ("isis", "M143947267L.cal.echo.crop.cub")],
)
def test_real_labels_decode_as_pvls_own_parser_does(parts: tuple[str, str]) -> None:
    from pvl.parser import OmniParser

    text = label_text(shared(*parts))
    assert _flat(parse_label("x.cub", text)) == _flat(pvl.loads(text, parser=OmniParser()))


def test_a_cubes_layout_is_parsed_once_per_label(tmp_path: Path, monkeypatch) -> None:
    """Tiles read a cube's pixels window by window; its label is parsed once, and again only
    when the file's label changes."""
    from orthomvp.io import isis

    raw = (np.arange(20 * 30) % 200 + 1).astype(np.uint8).reshape(1, 20, 30)
    path = tmp_path / "a.cub"
    write_cube(path, raw, "UnsignedByte", "Lsb", None)
    truth = isis.cube_layout(path, read_label(path))
    parsed = []
    monkeypatch.setattr(isis, "parse_label", lambda p, t: parsed.append(p) or parse_label(p, t))
    first = isis.read_layout(path)
    assert isis.read_layout(path) is first and len(parsed) == 1
    assert first == truth
    write_cube(path, np.concatenate([raw, raw]), "UnsignedByte", "Lsb", None)
    assert isis.read_layout(path).bands == 2 and len(parsed) == 2


@pytest.mark.realdata
def test_a_cube_that_is_its_own_camera_is_parsed_once(tmp_path: Path, monkeypatch) -> None:
    """The README's cube ortho reads the cube as its camera and as its image: one label parse,
    and the same layout as from a fresh parse of the file."""
    from orthomvp.camera import read_camera
    from orthomvp.engine.images import image_source
    from orthomvp.io import isis

    cube = tmp_path / "hadley.cub"  # a path no earlier test has read
    cube.write_bytes(shared("as15-hadley", "AS15-M-1134-hadley.cub").read_bytes())
    truth = isis.cube_layout(cube, read_label(cube))
    parsed = []
    monkeypatch.setattr(isis, "parse_label", lambda p, t: parsed.append(p) or parse_label(p, t))
    camera = read_camera(cube)
    source = image_source(cube, camera)
    assert len(parsed) == 1
    assert isis.read_layout(cube) == truth and (source.width, source.height) == (750, 750)


@pytest.mark.realdata
def test_a_worker_reads_a_cube_with_the_layout_of_the_plan(tmp_path: Path, monkeypatch) -> None:
    """A worker process gets the image with its layout (pickled with the plan) and parses no
    label of its own while the file's label is unchanged; its pixels are the cube's own (its
    float32 GeoTIFF conversion)."""
    import functools
    import pickle

    from orthomvp.camera import read_camera
    from orthomvp.engine.images import image_source
    from orthomvp.io import isis

    cube = tmp_path / "hadley.cub"
    cube.write_bytes(shared("as15-hadley", "AS15-M-1134-hadley.cub").read_bytes())
    source = pickle.loads(pickle.dumps(image_source(cube, read_camera(cube))))
    for name in ("_parsed", "_layout"):  # a new process: nothing parsed yet
        monkeypatch.setattr(isis, name, functools.lru_cache(16)(getattr(isis, name).__wrapped__))
    parsed = []
    monkeypatch.setattr(isis, "parse_label", lambda p, t: parsed.append(p) or parse_label(p, t))
    pixels = source.read((100, 164, 200, 300))
    assert parsed == []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(shared("as15-hadley", "AS15-M-1134-hadley.tif")) as src:
            truth = src.read(window=((100, 164), (200, 300)))
    np.testing.assert_array_equal(pixels, truth)


def test_a_cube_whose_label_changed_is_read_with_its_new_layout(tmp_path: Path) -> None:
    """A layout read before is used only while the label is the text it was read from."""
    from orthomvp.io import isis

    raw = (np.arange(20 * 30) % 200 + 1).astype(np.uint8).reshape(1, 20, 30)
    path = tmp_path / "a.cub"
    write_cube(path, raw, "UnsignedByte", "Lsb", None)
    known = isis.read_layout(path)
    assert isis.read_layout(path, known=known) is known and known.bands == 1
    write_cube(path, np.concatenate([raw, raw]), "UnsignedByte", "Lsb", None)
    assert isis.read_layout(path, known=known).bands == 2
