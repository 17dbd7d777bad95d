"""Datasets kept open between reads (orthomvp.raster.held_raster): the values of a fresh open,
one reader at a time per dataset, a changed file opened afresh, and at most HELD_OPEN kept."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.windows import Window

from orthomvp import raster
from orthomvp.engine.images import ImageSource
from orthomvp.errors import InputError
from orthomvp.raster import HELD_OPEN, held_raster


def write(path: Path, data: np.ndarray, **options: object) -> None:
    bands, rows, cols = data.shape
    profile = dict(driver="GTiff", height=rows, width=cols, count=bands, dtype=data.dtype.name)
    transform = Affine(1, 0, 0, 0, -1, rows)
    with rasterio.open(path, "w", transform=transform, **profile, **options) as dst:
        dst.write(data)


def held_count() -> int:
    return sum(map(len, raster._held.values()))


@pytest.fixture(autouse=True)
def _none_held() -> None:
    """Each test starts with no dataset held (those of other tests closed)."""
    with raster._held_lock:
        for datasets in raster._held.values():
            for dataset in datasets:
                dataset.close()
        raster._held.clear()


def test_a_held_dataset_is_reused_and_reads_what_a_fresh_open_reads(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    data = np.random.default_rng(1).integers(0, 255, (3, 300, 200), dtype=np.uint8)
    write(path, data, tiled=True, blockxsize=64, blockysize=64, compress="jpeg")
    with rasterio.open(path) as src:
        want = src.read(window=Window(10, 20, 150, 250))
    with held_raster(path) as first:
        np.testing.assert_array_equal(first.read(window=Window(10, 20, 150, 250)), want)
    with held_raster(path) as second:
        assert second is first and not second.closed
        np.testing.assert_array_equal(second.read(window=Window(10, 20, 150, 250)), want)
    assert held_count() == 1


def test_a_dataset_in_use_is_not_handed_to_a_second_reader(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.zeros((1, 10, 10), np.float32))
    with held_raster(path) as a, held_raster(path) as b:
        assert a is not b
    assert held_count() == 2
    with held_raster(path) as c:
        assert c is a  # the most recently returned (b was returned first)


def test_a_changed_file_is_opened_afresh(tmp_path: Path) -> None:
    path = tmp_path / "a.tif"
    write(path, np.full((1, 10, 10), 1, np.float32))
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


def test_at_most_held_open_datasets_are_kept_and_the_oldest_are_closed(tmp_path: Path) -> None:
    datasets = []
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
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(view.read, windows))
    for (r0, r1, c0, c1), values in zip(windows, got, strict=True):
        np.testing.assert_array_equal(values, whole[:, r0:r1, c0:c1])
    assert 1 <= held_count() <= 4
