"""Reading raster values with NaN where GDAL's mask says there is none: the same values as
rasterio's masked read, for every kind of mask."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.windows import Window

from orthomvp.io.raster import read_values

CASES = [
    ("float32", np.nan),
    ("float32", -9999.0),
    ("float64", -3.4028234663852886e38),
    ("uint8", 0),
    ("uint16", None),
    ("int16", -32768),
]


def masked_read(src, indexes, window, dtype) -> np.ndarray:  # noqa: ANN001
    data = src.read(indexes, window=window, masked=True)
    return np.ma.filled(data.astype(dtype), np.nan)


@pytest.mark.parametrize(("kind", "nodata"), CASES)
def test_read_values_equals_a_masked_read(tmp_path: Path, kind: str, nodata: float | None) -> None:
    rng = np.random.default_rng(7)
    data = (rng.random((3, 40, 50)) * 200).astype(kind)
    if nodata is not None:
        data[rng.random(data.shape) < 0.2] = np.array(nodata).astype(kind)
    path = tmp_path / f"{kind}.tif"
    profile = dict(driver="GTiff", height=40, width=50, count=3, dtype=kind, nodata=nodata)
    with rasterio.open(path, "w", transform=Affine(1, 0, 0, 0, -1, 40), **profile) as dst:
        dst.write(data)
    window = Window(5, 3, 30, 20)
    with rasterio.open(path) as src:
        for indexes, win in ((None, None), (1, window), ([2, 3], window)):
            for dtype in (np.float32, np.float64):
                got = read_values(src, indexes, win, dtype)
                want = masked_read(src, indexes, win, dtype)
                assert got.dtype == dtype
                np.testing.assert_array_equal(got, want)
        if nodata is not None:
            assert np.isnan(read_values(src, None, None, np.float32)).mean() > 0.1


def test_read_values_honours_an_internal_mask(tmp_path: Path) -> None:
    """A dataset mask (not a nodata value) goes through rasterio's masked read."""
    path = tmp_path / "mask.tif"
    data = np.arange(2 * 20 * 30, dtype=np.uint8).reshape(2, 20, 30)
    profile = dict(driver="GTiff", height=20, width=30, count=2, dtype="uint8")
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(path, "w", transform=Affine(1, 0, 0, 0, -1, 20), **profile) as dst:
            dst.write(data)
            mask = np.full((20, 30), 255, np.uint8)
            mask[5:10, 5:15] = 0
            dst.write_mask(mask)
    with rasterio.open(path) as src:
        got = read_values(src, None, None, np.float32)
        np.testing.assert_array_equal(got, masked_read(src, None, None, np.float32))
    assert np.isnan(got[:, 5:10, 5:15]).all() and np.isfinite(got[:, :5]).all()


def test_read_values_with_a_nodata_value_per_band(tmp_path: Path) -> None:
    """Bands with different nodata values, or only some with one (a VRT can say so), and a
    float band whose nodata GDAL matches within ulps: the masked read's values."""
    src_path = tmp_path / "bands.tif"
    data = np.array([[[0, 1, 255], [7, 0, 9]], [[255, 0, 3], [0, 255, 5]]], np.uint8)
    profile = dict(driver="GTiff", height=2, width=3, count=2, dtype="uint8")
    with rasterio.open(src_path, "w", transform=Affine(1, 0, 0, 0, -1, 2), **profile) as dst:
        dst.write(data)
    for nodatas in ((0, 255), (None, 255), (255, None)):
        vrt = tmp_path / f"bands-{nodatas[0]}-{nodatas[1]}.vrt"
        bands = "".join(
            f'<VRTRasterBand dataType="Byte" band="{b}">'
            + (f"<NoDataValue>{nd}</NoDataValue>" if nd is not None else "")
            + f"<SimpleSource><SourceFilename>{src_path}</SourceFilename>"
            f"<SourceBand>{b}</SourceBand></SimpleSource></VRTRasterBand>"
            for b, nd in enumerate(nodatas, start=1)
        )
        vrt.write_text(f'<VRTDataset rasterXSize="3" rasterYSize="2">{bands}</VRTDataset>')
        with rasterio.open(vrt) as src:
            for indexes in (None, 1, 2, [2, 1]):
                got = read_values(src, indexes, None, np.float32)
                np.testing.assert_array_equal(got, masked_read(src, indexes, None, np.float32))
    near = tmp_path / "near.tif"
    values = np.array([[[-9999.0, np.nextafter(np.float32(-9999), np.float32(0)), 5.0]]], "f4")
    profile = dict(driver="GTiff", height=1, width=3, count=1, dtype="float32", nodata=-9999.0)
    with rasterio.open(near, "w", transform=Affine(1, 0, 0, 0, -1, 1), **profile) as dst:
        dst.write(values)
    with rasterio.open(near) as src:
        got = read_values(src, None, None, np.float32)
        np.testing.assert_array_equal(got, masked_read(src, None, None, np.float32))
