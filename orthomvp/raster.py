"""Raster file input and output: images of any common format, GeoTIFFs written atomically.

Arrays are band-first, ``(bands, rows, cols)``. Every writer goes through :func:`atomic_path`,
so a failure never leaves a half-written file at the destination.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError

from orthomvp.errors import InputError
from orthomvp.isis import read_cube


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds."""
    path = Path(path)
    if path.parent and not path.parent.exists():
        raise InputError(f"{path}: output directory {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent or ".")
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    finally:
        tmp_path.unlink(missing_ok=True)
        # rasterio may leave an .aux.xml sidecar beside the temporary file
        Path(str(tmp_path) + ".aux.xml").unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; on success move its files into ``path``.

    On failure the temporary directory is removed and ``path`` is left as it was.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise InputError(f"{path}: parent directory {parent} does not exist")
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a directory")
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        if path.exists():
            for item in tmp.iterdir():
                os.replace(item, path / item.name)
        else:
            os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def open_raster(path: str | Path) -> rasterio.DatasetReader:
    """Open a raster with rasterio, turning every failure into an :class:`InputError`."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"a raster file name is a str or a Path, got {type(path).__name__}")
    path = Path(path)
    if not path.is_file():
        raise InputError(
            f"{path}: {'a directory, not a file' if path.is_dir() else 'no such file'}"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            return rasterio.open(path)
    except (RasterioIOError, RasterioError) as exc:
        raise InputError(f"{path}: not a readable raster ({exc})") from exc


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 ``(bands, rows, cols)``; nodata -> NaN.

    ISIS3 cubes (``.cub``) are read by :func:`orthomvp.isis.read_cube` (special pixels -> NaN);
    everything else (GeoTIFF/TIFF of any dtype and band count, PNG, JPEG, ...) by rasterio.
    """
    if isinstance(path, (str, os.PathLike)) and Path(path).suffix.lower() == ".cub":
        return read_cube(path)
    with open_raster(path) as src:
        try:
            data = src.read(masked=True)
        except RasterioError as exc:
            raise InputError(f"{path}: corrupt raster data ({exc})") from exc
    return np.ma.filled(data.astype(np.float32), np.nan)


def write_geotiff(
    path: str | Path,
    data: np.ndarray,
    transform: Affine,
    crs: object,
    nodata: float | None = None,
    band_names: list[str] | None = None,
) -> None:
    """Write ``data`` ((rows, cols) or (bands, rows, cols)) as a tiled, compressed GeoTIFF.

    ``transform`` refers to pixel corners (GDAL convention); ``crs`` is anything rasterio accepts.
    Floating-point NaNs are written as they are and declared as nodata when ``nodata`` is NaN.
    """
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[None]
    profile = {
        "driver": "GTiff",
        "height": arr.shape[1],
        "width": arr.shape[2],
        "count": arr.shape[0],
        "dtype": arr.dtype.name,
        "transform": transform,
        "crs": crs,
        "compress": "deflate",
        "nodata": nodata,
    }
    if arr.shape[1] >= 256 and arr.shape[2] >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    with warnings.catch_warnings(), atomic_path(path) as tmp:
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(arr)
            for i, name in enumerate(band_names or [], start=1):
                dst.set_band_description(i, name)
