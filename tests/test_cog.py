"""Overview levels made from tiles, and COGs laid out from tiled GeoTIFFs by copying their
compressed tiles: against GDAL's own COG driver and overviews, and block means computed here."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.enums import Resampling

from orthomvp.engine import Outputs, cog, overviews, plan_ortho, run_plan
from orthomvp.engine.cog import TiffLayoutError, assemble
from orthomvp.engine.overviews import halve, window_level


def block_means(data: np.ndarray) -> np.ndarray:
    """NaN-aware means of 2 x 2 blocks, the array padded with NaN to even sides."""
    bands, rows, cols = data.shape
    r, c = -(-rows // 2), -(-cols // 2)
    padded = np.full((bands, 2 * r, 2 * c), np.nan)
    padded[:, :rows, :cols] = data
    blocks = padded.reshape(bands, r, 2, c, 2)
    counts = np.isfinite(blocks).sum(axis=(2, 4))
    sums = np.nansum(blocks, axis=(2, 4))
    with np.errstate(invalid="ignore"):
        return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


@pytest.mark.parametrize("shape", [(3, 6, 8), (1, 5, 7), (2, 1, 1), (1, 2, 3), (2, 9, 4)])
def test_halve_gives_block_means_and_lower_right_posts(shape: tuple[int, int, int]) -> None:
    rng = np.random.default_rng(sum(shape))
    data = rng.random(shape).astype(np.float32) * 100
    data[rng.random(shape) < 0.3] = np.nan
    np.testing.assert_allclose(halve(data, "average", np.nan), block_means(data), rtol=1e-6)
    assert halve(data, "average", np.nan).dtype == np.float32
    codes = rng.integers(0, 4, shape).astype(np.uint8)
    rows, cols = shape[1:]
    expected = np.array(
        [
            [
                [
                    codes[b, min(2 * i + 1, rows - 1), min(2 * j + 1, cols - 1)]
                    for j in range(-(-cols // 2))
                ]
                for i in range(-(-rows // 2))
            ]
            for b in range(shape[0])
        ],
        np.uint8,
    ).reshape(shape[0], -(-rows // 2), -(-cols // 2))
    np.testing.assert_array_equal(halve(codes, "nearest", 0), expected)
    # integer data with a nodata value: those posts do not count
    ints = np.where(np.isnan(data), 0, np.rint(data) + 1).astype(np.uint16)
    got = halve(ints, "average", 0)
    np.testing.assert_allclose(got, block_means(np.where(ints == 0, np.nan, ints)), rtol=1e-6)
    with pytest.raises(ValueError, match="resampling"):
        halve(data, "cubic", np.nan)


@pytest.mark.parametrize("shape", [(3, 6, 8), (1, 5, 7), (2, 1, 1), (1, 2, 3), (2, 9, 4)])
@pytest.mark.parametrize("kind", ["float32", "uint16"])
def test_halve_of_full_data_equals_the_masked_path(
    shape: tuple[int, int, int], kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without an empty post, block means bit for bit as the path for data with empty posts
    gives them (one empty post, in block (0, 0) of band 0, sends it there), and without the
    masked path's count sums (of uint8); also for an empty array."""
    rng = np.random.default_rng(sum(shape))
    data = (rng.random(shape) * 1000 + 1).astype(kind)
    nodata = np.nan if kind == "float32" else 0
    summed = []
    pairs = overviews._pairs
    monkeypatch.setattr(
        overviews, "_pairs", lambda a, axis: summed.append(a.dtype) or pairs(a, axis)
    )
    full = halve(data, "average", nodata)
    assert np.dtype(np.uint8) not in summed
    assert halve(data[:, :0], "average", nodata).shape == (shape[0], 0, -(-shape[2] // 2))
    holed = data.copy()
    holed[0, 0, 0] = nodata
    masked = halve(holed, "average", nodata)
    np.testing.assert_allclose(full, block_means(data.astype(np.float64)), rtol=1e-6)
    full[0, 0, 0] = masked[0, 0, 0]  # the one block that differs
    assert full.dtype == np.float32
    np.testing.assert_array_equal(full.view(np.uint32), masked.view(np.uint32))


def test_window_level_takes_whole_blocks_only() -> None:
    shape = (1000, 700)
    assert window_level((0, 512, 0, 512), shape, 4) == (0, 128, 0, 128)
    assert window_level((512, 1000, 512, 700), shape, 8) == (64, 125, 64, 88)  # edges: ceil
    assert window_level((512, 1000, 512, 700), shape, 1024) is None  # not on a block's start
    assert window_level((0, 300, 0, 256), shape, 8) is None  # ends inside a block
    assert window_level((0, 1000, 0, 700), shape, 4096) == (0, 1, 0, 1)


def ifd_chain(path: Path) -> list[dict]:
    """Every IFD of a little-endian TIFF: its offset, end, tile offsets and byte counts."""
    raw = path.read_bytes()
    big = struct.unpack_from("<H", raw, 2)[0] == 43
    at = struct.unpack_from("<Q" if big else "<I", raw, 8 if big else 4)[0]
    ifds = []
    while at:
        n = struct.unpack_from("<Q" if big else "<H", raw, at)[0]
        entry, head = (20, 8) if big else (12, 2)
        fields = {}
        for i in range(n):
            fmt = "<HHQQ" if big else "<HHII"
            tag, kind, count, value = struct.unpack_from(fmt, raw, at + head + i * entry)
            fields[tag] = (kind, count, value)
        arrays = {}
        for tag in (324, 325):
            kind, count, value = fields[tag]
            dtype = {3: "<u2", 4: "<u4", 16: "<u8"}[kind]
            size = np.dtype(dtype).itemsize * count
            where = at + head + list(fields).index(tag) * entry + 4 + (8 if big else 4)
            start = where if size <= (8 if big else 4) else value
            arrays[tag] = np.frombuffer(raw, dtype, count, start).astype(np.int64)
        end = at + head + n * entry + (8 if big else 4)
        ifds.append({"at": at, "end": end, "offsets": arrays[324], "counts": arrays[325]})
        at = struct.unpack_from("<Q" if big else "<I", raw, end - (8 if big else 4))[0]
    return ifds


def check_cog_layout(path: Path) -> None:
    """What makes a COG, as GDAL's COG driver lays it out: IFDs (and their values) before any
    tile, the smallest overview's tiles first and the full resolution's last, each level's
    tiles row by row, each with its size before it and its last 4 bytes after it."""
    raw = path.read_bytes()
    ifds = ifd_chain(path)
    first_tile = min(int(i["offsets"][i["counts"] > 0].min()) for i in ifds)
    assert all(i["end"] <= first_tile for i in ifds)
    assert [i["at"] for i in ifds] == sorted(i["at"] for i in ifds)
    previous_end = 0
    for ifd in reversed(ifds):
        offsets, counts = ifd["offsets"], ifd["counts"]
        assert (np.diff(offsets) > 0).all() and offsets[0] > previous_end
        for offset, count in zip(offsets, counts, strict=True):
            assert struct.unpack_from("<I", raw, offset - 4)[0] == count
            assert (
                raw[offset + count - 4 : offset + count] == raw[offset + count : offset + count + 4]
            )
        previous_end = int(offsets[-1] + counts[-1])
    with rasterio.open(path) as src:
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"


def gdal_cog_and_levels(tmp_path: Path, data: np.ndarray, bigtiff: str = "NO") -> tuple:
    """A tiled GeoTIFF of ``data``, GDAL's COG of it, and that COG's overviews each as a tiled
    GeoTIFF of the same creation options."""
    bands, rows, cols = data.shape
    profile = dict(
        driver="GTiff",
        count=bands,
        dtype=data.dtype.name,
        crs="EPSG:32633",
        nodata=np.nan,
        tiled=True,
        blockxsize=64,
        blockysize=64,
        compress="zstd",
        predictor=3,
        bigtiff=bigtiff,
    )
    transform = Affine(2.0, 0, 500000, 0, -2.0, 4000000)
    base = tmp_path / "base.tif"
    with rasterio.open(base, "w", height=rows, width=cols, transform=transform, **profile) as dst:
        dst.write(data)
    gdal = tmp_path / "gdal-cog.tif"
    rasterio.shutil.copy(
        base,
        gdal,
        driver="COG",
        BLOCKSIZE=64,
        COMPRESS="ZSTD",
        PREDICTOR="YES",
        RESAMPLING="AVERAGE",
    )
    levels = []
    with rasterio.open(gdal) as src:
        count = len(src.overviews(1))
    for k in range(count):
        with rasterio.open(gdal, overview_level=k) as src:
            path = tmp_path / f"level{k}.tif"
            shape = dict(height=src.height, width=src.width, transform=src.transform)
            with rasterio.open(path, "w", **shape, **profile) as dst:
                dst.write(src.read())
            levels.append(path)
    return base, gdal, levels


def read_levels(path: Path) -> list[np.ndarray]:
    with rasterio.open(path) as src:
        count = len(src.overviews(1))
        out = [src.read()]
    for k in range(count):
        with rasterio.open(path, overview_level=k) as src:
            out.append(src.read())
    return out


@pytest.mark.parametrize("bigtiff", ["NO", "YES"])
def test_assemble_lays_out_gdal_tiles_as_gdals_cog(tmp_path: Path, bigtiff: str) -> None:
    rng = np.random.default_rng(3)
    data = rng.normal(100, 20, (3, 300, 217)).astype(np.float32)
    data[:, 40:90, 100:180] = np.nan
    base, gdal, levels = gdal_cog_and_levels(tmp_path, data, bigtiff)
    assert len(levels) == 3
    out = tmp_path / "ours.tif"
    assemble(base, levels, out)
    check_cog_layout(out)
    assert out.read_bytes()[2] == 42  # a classic TIFF: it fits, whatever the base was
    assert out.stat().st_size == gdal.stat().st_size  # the same tiles, leaders and trailers
    for ours, theirs in zip(read_levels(out), read_levels(gdal), strict=True):
        np.testing.assert_array_equal(ours, theirs)
    with rasterio.open(out) as a, rasterio.open(gdal) as b:
        assert a.profile == b.profile or {
            k: (a.profile[k], b.profile[k]) for k in a.profile if a.profile[k] != b.profile[k]
        } == {"nodata": (a.nodata, b.nodata)}
        assert a.crs == b.crs and a.transform == b.transform and np.isnan(a.nodata)


def test_assemble_writes_a_bigtiff_when_a_classic_one_cannot_hold_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(4)
    data = rng.normal(0, 1, (1, 200, 150)).astype(np.float32)
    base, gdal, levels = gdal_cog_and_levels(tmp_path, data)
    monkeypatch.setattr(cog, "CLASSIC_LIMIT", 10_000)
    out = tmp_path / "big.tif"
    assemble(base, levels, out)
    assert out.read_bytes()[2] == 43
    check_cog_layout(out)
    for ours, theirs in zip(read_levels(out), read_levels(gdal), strict=True):
        np.testing.assert_array_equal(ours, theirs)


def test_assemble_refuses_a_damaged_file_with_one_error(tmp_path: Path) -> None:
    """A work file cut short anywhere (a full disk) is a TiffLayoutError, an OSError, which
    the writer reports as a failed write of the output: never another exception."""
    rng = np.random.default_rng(9)
    base, _, levels = gdal_cog_and_levels(tmp_path, rng.normal(size=(1, 90, 70)).astype("f4"))
    raw = base.read_bytes()
    cut = tmp_path / "cut.tif"
    for end in sorted({*range(0, 64), *range(0, len(raw), max(len(raw) // 97, 1))}):
        cut.write_bytes(raw[:end])
        try:
            assemble(cut, levels, tmp_path / "out.tif")
        except TiffLayoutError:
            pass
    assert issubclass(TiffLayoutError, OSError)


def test_assemble_refuses_what_is_not_a_tiled_little_endian_tiff(tmp_path: Path) -> None:
    text = tmp_path / "a.tif"
    text.write_bytes(b"not a tiff at all")
    with pytest.raises(TiffLayoutError, match="little-endian"):
        assemble(text, [], tmp_path / "out.tif")
    striped = tmp_path / "striped.tif"
    with rasterio.open(
        striped, "w", driver="GTiff", height=10, width=10, count=1, dtype="uint8"
    ) as dst:
        dst.write(np.ones((1, 10, 10), np.uint8))
    with pytest.raises(TiffLayoutError, match="not a tiled TIFF"):
        assemble(striped, [], tmp_path / "out.tif")


def cascade(data: np.ndarray, levels: int) -> list[np.ndarray]:
    """The overview levels of ``data`` as block means of the level before."""
    out = [data.astype(np.float64)]
    for _ in range(levels):
        out.append(block_means(out[-1]))
    return out


def crater_plan(crater_dir: Path, tile: int):  # noqa: ANN201
    view = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    res = (0.0003, 0.0003)
    return plan_ortho(
        crater_dir / "dem.tif", [view], tile=tile, res=res, progress=False, grid="dem"
    )


def test_engine_cog_overviews_are_block_means_of_the_level_before(
    crater_dir: Path, tmp_path: Path
) -> None:
    """Tiles of 64 posts make the levels as they are written; tiles of 50 make none (no
    window starts on a block of 4), so all are made at the end from the level before. Both give
    the cascade of block means (GDAL's own average, where its blocks are ours), and the
    visibility codes' levels are the lower-right post of each block."""
    files = {}
    for tile in (64, 50):
        ortho, vis = tmp_path / f"o{tile}.tif", tmp_path / f"v{tile}.tif"
        outputs = Outputs(ortho=ortho, visibility=vis, blocksize=32)
        run_plan(crater_plan(crater_dir, tile), outputs, progress=False)
        check_cog_layout(ortho)
        check_cog_layout(vis)
        files[tile] = (read_levels(ortho), read_levels(vis))
    levels, codes = files[64]
    assert len(levels) >= 3 and np.isnan(levels[0]).any() and np.isfinite(levels[0]).any()
    expected = cascade(levels[0], len(levels) - 1)
    for got, want in zip(levels[1:], expected[1:], strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    # GDAL's own average on the even part of the grid (where its blocks are ours), to float32's
    # last bit (GDAL sums in another order)
    rows, cols = (n - n % 2 for n in levels[0].shape[1:])
    even = levels[0][:, :rows, :cols]
    copy = tmp_path / "gdal.tif"
    with rasterio.open(tmp_path / "o64.tif") as src:
        profile = src.profile | {"driver": "GTiff", "compress": "none"}
    with rasterio.open(copy, "w", **profile | {"height": rows, "width": cols}) as dst:
        dst.write(even)
        dst.build_overviews([2], Resampling.average)
    with rasterio.open(copy, overview_level=0) as src:
        gdal = src.read()
    np.testing.assert_allclose(halve(even, "average", np.nan), gdal, rtol=2.4e-7, atol=0)
    np.testing.assert_array_equal(np.isnan(halve(even, "average", np.nan)), np.isnan(gdal))
    for before, after in zip(codes, codes[1:], strict=False):
        np.testing.assert_array_equal(after, halve(before, "nearest", 0))
    assert (codes[0] == 2).any() and (codes[0] == 1).any()  # occluded and visible posts
    for a, b in zip(files[50][0] + files[50][1], levels + codes, strict=True):
        np.testing.assert_array_equal(a, b)


def test_engine_cog_overviews_of_integer_orthophotos(crater_dir: Path, tmp_path: Path) -> None:
    """uint8 orthophotos: the levels are the rounded block means of the level before (as
    written, rounded), nodata (0) left out, whatever the tiles (64 posts: levels from the
    tiles; 50: from the files)."""
    files = []
    for tile in (64, 50):
        path = tmp_path / f"u8-{tile}.tif"
        outputs = Outputs(ortho=path, dtype="uint8", blocksize=32)
        run_plan(crater_plan(crater_dir, tile), outputs, progress=False)
        files.append(read_levels(path))
    for a, b in zip(*files, strict=True):
        np.testing.assert_array_equal(a, b)
    levels = files[0]
    assert levels[0].dtype == np.uint8 and (levels[0] == 0).any()
    for before, after in zip(levels, levels[1:], strict=False):
        means = block_means(np.where(before == 0, np.nan, before.astype(np.float64)))
        expected = np.where(np.isnan(means), 0, np.clip(np.rint(means), 1, 255))
        np.testing.assert_array_equal(after, expected)


def test_integer_levels_are_made_from_the_rounded_level_before(tmp_path: Path) -> None:
    """A uint8 output whose level-1 means tie at .5: level 2 comes from level 1 as written
    (rounded), whether the tiles make it (tiles of 4) or the file does (tiles of 2)."""
    from types import SimpleNamespace

    from pyproj import CRS

    from orthomvp.engine.grid import OutputGrid
    from orthomvp.engine.writer import Layer, output_files

    # level 1 of the 4 x 4 posts: [[2.5, 2.5], [2.5, 3.5]] -> rounded [[2, 2], [2, 4]] -> 2.5 -> 2
    data = np.array([[2, 3, 2, 3], [2, 3, 2, 3], [2, 3, 3, 4], [2, 3, 3, 4]], np.uint8)
    big = np.tile(data, (16, 16))  # 64 x 64 posts, blocks of 16: levels of factors 2 and 4
    grid = OutputGrid(Affine(1, 0, 0, 0, -1, 32), big.shape, CRS.from_epsg(32633), True)
    written = []
    for tile in (4, 2):
        path = tmp_path / f"u8-{tile}.tif"
        layer = Layer(path, 1, "uint8", 0, Resampling.average, lambda r: r.data)
        outputs = Outputs(ortho=path, dtype="uint8", blocksize=16)
        with output_files(grid, [layer], outputs) as writer:
            for r in range(0, 64, tile):
                for c in range(0, 64, tile):
                    part = big[r : r + tile, c : c + tile][None]
                    writer.write(SimpleNamespace(window=(r, r + tile, c, c + tile), data=part))
        written.append(read_levels(path))
    for a, b in zip(*written, strict=True):
        np.testing.assert_array_equal(a, b)
    level1, level2 = written[0][1][0], written[0][2][0]
    assert level1[:2, :2].tolist() == [[2, 2], [2, 4]]  # 2.5 rounds to even, 3.5 to 4
    assert level2[0, 0] == 2  # the mean of the rounded level 1 (2.5), not of its means (2.75)
