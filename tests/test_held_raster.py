"""Datasets kept open between reads (orthomvp.io.raster.held_raster) inside held_rasters blocks
(a run's tiles): the values of a fresh open, one reader at a time per dataset, a changed file
opened afresh, at most HELD_OPEN kept, all closed when the last block ends, nothing held
outside one, and a forked child that does not use its parent's datasets."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.windows import Window

from orthomvp.engine.images import ImageSource
from orthomvp.errors import InputError
from orthomvp.io import raster
from orthomvp.io.raster import HELD_OPEN, held_raster, held_rasters


def write(path: Path, data: np.ndarray, **options: object) -> None:
    bands, rows, cols = data.shape
    profile = dict(driver="GTiff", height=rows, width=cols, count=bands, dtype=data.dtype.name)
    transform = Affine(1, 0, 0, 0, -1, rows)
    with rasterio.open(path, "w", transform=transform, **profile, **options) as dst:
        dst.write(data)


def held_count() -> int:
    return sum(map(len, raster._held.values()))


@pytest.fixture(autouse=True)
def _none_left() -> Iterator[None]:
    """No test leaves a block open or a dataset held."""
    assert raster._scopes == 0 and held_count() == 0
    yield
    assert raster._scopes == 0 and held_count() == 0


def test_a_held_dataset_is_reused_and_reads_what_a_fresh_open_reads(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    data = np.random.default_rng(1).integers(0, 255, (3, 300, 200), dtype=np.uint8)
    write(path, data, tiled=True, blockxsize=64, blockysize=64, compress="jpeg")
    with rasterio.open(path) as src:
        want = src.read(window=Window(10, 20, 150, 250))
    with held_rasters():
        with held_raster(path) as first:
            np.testing.assert_array_equal(first.read(window=Window(10, 20, 150, 250)), want)
        with held_raster(path) as second:
            assert second is first and not second.closed
            np.testing.assert_array_equal(second.read(window=Window(10, 20, 150, 250)), want)
        assert held_count() == 1
    assert first.closed  # the block's end closes it


def test_outside_a_block_nothing_is_held(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.ones((1, 10, 10), np.float32))
    with held_raster(path) as src:
        assert src.read(1)[0, 0] == 1
    assert src.closed and held_count() == 0


def test_blocks_nest_and_the_last_one_closes(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.ones((1, 10, 10), np.float32))
    with held_rasters():
        with held_rasters():
            with held_raster(path) as src:
                pass
        assert not src.closed and held_count() == 1  # the outer block still holds it
    assert src.closed


def test_a_dataset_in_use_when_the_block_ends_is_closed_when_returned(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.ones((1, 10, 10), np.float32))
    scope = held_rasters()
    scope.__enter__()
    with held_raster(path) as src:
        scope.__exit__(None, None, None)  # (another thread's run ends meanwhile)
        assert not src.closed and src.read(1)[0, 0] == 1
    assert src.closed and held_count() == 0


def test_a_dataset_in_use_is_not_handed_to_a_second_reader(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.zeros((1, 10, 10), np.float32))
    with held_rasters():
        with held_raster(path) as a, held_raster(path) as b:
            assert a is not b
        assert held_count() == 2
        with held_raster(path) as c:
            assert c is a  # the most recently returned (b was returned first)


def test_an_error_in_the_block_returns_the_dataset(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.full((1, 10, 10), 7, np.float32))
    with held_rasters():
        with pytest.raises(ZeroDivisionError), held_raster(path) as src:
            1 / 0  # noqa: B018
        assert held_count() == 1 and not src.closed
        with held_raster(path) as again:
            assert again is src and again.read(1)[0, 0] == 7


def test_a_changed_file_is_opened_afresh(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.full((1, 10, 10), 1, np.float32))
    with held_rasters():
        with held_raster(path) as src:
            assert src.read(1)[0, 0] == 1
        # replaced (another inode), as an atomic writer replaces it
        write(tmp_path / "b.tif", np.full((1, 10, 10), 2, np.float32))
        os.replace(tmp_path / "b.tif", path)
        with held_raster(path) as src:
            assert src.read(1)[0, 0] == 2
        # rewritten in place, same size: only its modification time tells
        with rasterio.open(path, "r+") as dst:
            dst.write(np.full((1, 10, 10), 3, np.float32))
        stat = path.stat()
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
        with held_raster(path) as src:
            assert src.read(1)[0, 0] == 3


def test_a_vrt_whose_source_changed_is_read_afresh_by_the_next_block(tmp_path: Path) -> None:
    """The key covers the VRT, not its sources: a run reads them as they were when it opened
    them, and the next run as they are."""
    source = tmp_path / "src.tif"
    write(source, np.full((1, 10, 10), 1, np.float32))
    vrt = tmp_path / "dem.vrt"
    with rasterio.open(source) as src:
        rasterio.shutil.copy(src, vrt, driver="VRT")
    with held_rasters(), held_raster(vrt) as src:
        assert src.read(1)[0, 0] == 1
    write(tmp_path / "new.tif", np.full((1, 10, 10), 2, np.float32))
    os.replace(tmp_path / "new.tif", source)
    with held_rasters(), held_raster(vrt) as src:
        assert src.read(1)[0, 0] == 2


def test_at_most_held_open_datasets_are_kept_and_the_oldest_are_closed(tmp_path: Path) -> None:
    datasets = []
    with held_rasters():
        for k in range(HELD_OPEN + 3):
            path = tmp_path / f"{k}.tif"
            write(path, np.full((1, 4, 4), k, np.float32))
            with held_raster(path) as src:
                datasets.append(src)
        assert held_count() == HELD_OPEN
        assert [d.closed for d in datasets] == [True] * 3 + [False] * HELD_OPEN
        with held_raster(tmp_path / "3.tif") as src:  # still held: the same dataset
            assert src is datasets[3]


def test_a_missing_file_or_a_directory_is_an_input_error(tmp_path: Path) -> None:
    with held_rasters():
        with pytest.raises(InputError, match="no such file"), held_raster(tmp_path / "none.tif"):
            pass
        with pytest.raises(InputError, match="a directory"), held_raster(tmp_path):
            pass
        assert held_count() == 0


def test_threads_reading_one_image_read_its_pixels(tmp_path: Path) -> None:
    """Windows of a JPEG-compressed image read by 4 threads at once through the held datasets
    (an image source's reads) are the windows of a fresh read of the whole image."""
    path = tmp_path / "image.tif"
    data = np.random.default_rng(2).integers(0, 255, (3, 400, 300), dtype=np.uint8)
    write(path, data, tiled=True, blockxsize=64, blockysize=64, compress="jpeg")
    with rasterio.open(path) as src:
        whole = src.read().astype(np.float32)
    view = ImageSource(path, 300, 400, 3, None)  # type: ignore[arg-type]  # (no camera needed)
    rng = np.random.default_rng(3)
    windows = []
    for _ in range(80):
        r0, c0 = rng.integers(0, 400 - 100), rng.integers(0, 300 - 100)
        windows.append((r0, r0 + rng.integers(1, 100), c0, c0 + rng.integers(1, 100)))
    with held_rasters(), ThreadPoolExecutor(4) as pool:
        got = list(pool.map(view.read, windows))
        assert 1 <= held_count() <= 4
    for (r0, r1, c0, c1), values in zip(windows, got, strict=True):
        np.testing.assert_array_equal(values, whole[:, r0:r1, c0:c1])


IMAGE = None  # (set in the forked children's parent)


def _read_windows(seed: int) -> int:
    """In a forked child: windows of IMAGE read as ImageSource reads them that differ from a
    fresh read (and anything held: the parent's datasets must not be)."""
    assert raster._scopes == 0 and held_count() == 0
    path, whole = IMAGE
    view = ImageSource(path, whole.shape[2], whole.shape[1], whole.shape[0], None)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    wrong = 0
    with held_rasters():
        for _ in range(60):
            r0, c0 = rng.integers(0, 400), rng.integers(0, 400)
            values = view.read((r0, r0 + 100, c0, c0 + 100))
            wrong += not np.array_equal(values, whole[:, r0 : r0 + 100, c0 : c0 + 100])
    return wrong


def test_a_forked_child_does_not_use_its_parents_datasets(tmp_path: Path) -> None:
    """Children forked while the parent holds a dataset of an uncompressed tiled image read
    its windows right (sharing the parent's file offsets, 30% of them came back wrong)."""
    global IMAGE
    path = tmp_path / "image.tif"
    data = np.random.default_rng(4).integers(0, 255, (3, 500, 500), dtype=np.uint8)
    write(path, data, tiled=True, blockxsize=64, blockysize=64)
    IMAGE = (path, data.astype(np.float32))
    view = ImageSource(path, 500, 500, 3, None)  # type: ignore[arg-type]
    with held_rasters(), rasterio.Env(GDAL_CACHEMAX=1):
        view.read((0, 10, 0, 10))
        assert held_count() == 1
        with multiprocessing.get_context("fork").Pool(2) as pool:
            assert pool.map(_read_windows, range(4)) == [0, 0, 0, 0]
