"""Raster file input and output: images of any common format read whole or by windows, through
datasets held open between reads (:func:`held_raster`), and GeoTIFFs written.

Arrays are band-first, ``(bands, rows, cols)``. GeoTIFFs are written through
:func:`orthomvp.io.outputs.atomic_path`, so a failure never leaves a half-written file at the
destination (see :mod:`orthomvp.io.outputs`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from affine import Affine
from rasterio.enums import ColorInterp, MaskFlags
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError

from orthomvp.errors import InputError
from orthomvp.io.files import check_regular
from orthomvp.io.outputs import atomic_path

_BROKEN = ("IO error", "Read error", "truncated", "Cannot read")
"""Words of GDAL's and libtiff's complaints that tell of a file that is corrupt or cut short."""


class _Complaints(logging.Handler):
    """The warnings rasterio logs for GDAL (``rasterio._env``) in this thread, while added."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.messages.append(record.getMessage())


def _gdal_text(message: str) -> str:
    """GDAL's message without rasterio's ``CPLE_... in FILE:`` prefix and pointers to other
    messages."""
    text = re.sub(r"^CPLE_\w+ in [^:]*: ", "", message)
    return " ".join(text.replace("See previous exception for details.", "").split())


def _file_size(path: str | Path) -> str:
    """``; the file has N bytes`` (nothing when it cannot be told)."""
    try:
        return f"; the file has {os.path.getsize(path):,} bytes"
    except OSError:
        return ""


def corrupt_data(path: str | Path, exc: BaseException) -> InputError:
    """The InputError of a failed read of ``path``: GDAL's first cause (the deepest of the
    chain of exceptions rasterio raises: "TIFFFillStrip:Read error at scanline 0; got 1231
    bytes, expected 6795", where rasterio says "Read failed. See previous exception for
    details.") and the file's size."""
    causes = []
    while exc is not None and len(causes) < 20:
        causes.append(_gdal_text(str(exc)))
        exc = exc.__cause__ or exc.__context__
    cause = next((c for c in reversed(causes) if c), "") or "GDAL gave no reason"
    return InputError(f"{path}: corrupt or truncated raster data ({cause}{_file_size(path)})")


def open_raster(path: str | Path) -> rasterio.DatasetReader:
    """Open a raster with rasterio, turning every failure into an :class:`InputError`: also
    a file that GDAL opens while complaining that parts of it cannot be read (a GeoTIFF cut
    short opens without its georeferencing tags)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"a raster file name is a str or a Path, got {type(path).__name__}")
    path = Path(path)
    check_regular(path, "raster")
    complaints = _Complaints()
    logger = logging.getLogger("rasterio._env")
    logger.addHandler(complaints)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            src = rasterio.open(path)
    except (RasterioIOError, RasterioError) as exc:
        text = _gdal_text(str(exc)).removeprefix(f"{path}: ").removeprefix(f"{path.name}: ")
        raise InputError(f"{path}: not a readable raster ({text})") from exc
    except UnicodeEncodeError:  # (rasterio passes GDAL UTF-8 names)
        raise InputError(f"{path}: GDAL cannot open a file whose name is not UTF-8") from None
    finally:
        logger.removeHandler(complaints)
    broken = [m for m in complaints.messages if any(word in m for word in _BROKEN)]
    if broken:
        src.close()
        raise InputError(
            f"{path}: corrupt or truncated raster ({_gdal_text(broken[0])}{_file_size(path)})"
        )
    return src


HELD_OPEN = 16
"""Datasets that :func:`held_raster` keeps open while no thread reads them (the most recently
used)."""

_held_lock = threading.Lock()
_held: dict[tuple, list[rasterio.DatasetReader]] = {}  # free datasets by file, oldest first
_scopes = 0  # how many held_rasters() blocks are open
_forked_off: list[dict] = []  # a forked child's copies of its parent's datasets, never used


def _forget_held() -> None:
    """In a forked child: nothing held, a fresh lock (the parent's datasets share their files'
    offsets with it, and another thread may have held the lock). The copies are kept, unused
    and unclosed: closing them would call GDAL, whose locks the fork may have copied held."""
    global _held_lock, _held, _scopes
    _forked_off.append(_held)
    _held_lock, _held, _scopes = threading.Lock(), {}, 0


os.register_at_fork(after_in_child=_forget_held)


@contextlib.contextmanager
def held_rasters() -> Iterator[None]:
    """A block in which :func:`held_raster` keeps the datasets it opens for the next reader
    (a run's tiles: :func:`orthomvp.engine.run.executor`'s threads); leaving the last such
    block closes them, so that no file stays open after a run (a file deleted or changed
    since, a VRT's sources or a sidecar file changed since, are read afresh by the next)."""
    global _scopes
    with _held_lock:
        _scopes += 1
    try:
        yield
    finally:
        with _held_lock:
            _scopes -= 1
            old = [] if _scopes else [src for free in _held.values() for src in free]
            if not _scopes:
                _held.clear()
        for dataset in old:
            dataset.close()


@contextlib.contextmanager
def held_raster(path: Path) -> Iterator[rasterio.DatasetReader]:
    """``path`` opened as :func:`open_raster` opens it, for this thread alone while in the
    ``with`` block; inside :func:`held_rasters`, kept open afterwards for the next reader (the
    :data:`HELD_OPEN` most recently used), else closed. GDAL keeps a dataset's decoded blocks in
    its block cache only while the dataset is open, so tiles that read overlapping windows of
    a compressed image decode its blocks once (a JPEG-compressed 1152 x 640 image: 10 ms a read
    opened afresh, 2 ms held). A thread that finds the file's dataset in use opens another; a
    file that changed since (another inode, size or modification time) is opened afresh."""
    try:
        st = os.stat(path)
    except OSError:
        st = None
    if st is None or not _scopes:
        with open_raster(path) as src:  # (a missing file: its InputError)
            yield src
        return
    key = (os.fspath(path), st.st_ino, st.st_size, st.st_mtime_ns)
    with _held_lock:
        free = _held.pop(key, [])
        src = free.pop() if free else None
        if free:
            _held[key] = free
    if src is None:
        src = open_raster(path)
    try:
        yield src
    finally:
        with _held_lock:
            old = [] if _scopes else [src]  # (the last block closed meanwhile)
            if _scopes:
                _held[key] = [*_held.pop(key, []), src]  # (last: the most recently used)
            while sum(map(len, _held.values())) > HELD_OPEN:
                oldest = next(iter(_held))
                old.append(_held[oldest].pop(0))
                if not _held[oldest]:
                    del _held[oldest]
        for dataset in old:
            dataset.close()


def image_bands(src: Any) -> list[int]:
    """The bands (1-based) of the open dataset ``src`` that hold image values: all but a last
    band GDAL reads as alpha (an RGBA PNG's, a TIFF's extra sample), which GDAL already applies
    to the others as their mask."""
    count = src.count
    if count > 1 and src.colorinterp[-1] == ColorInterp.alpha:
        return list(range(1, count))
    return list(range(1, count + 1))


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 ``(bands, rows, cols)``; nodata -> NaN; an alpha band is the
    mask of the others, not a band of values (:func:`image_bands`).

    ISIS3 cubes (``.cub``) are read by :func:`orthomvp.io.isis.read_cube` (special pixels -> NaN);
    everything else (GeoTIFF/TIFF of any dtype and band count, PNG, JPEG, ...) by rasterio.
    """
    if isinstance(path, (str, os.PathLike)) and Path(path).suffix.lower() == ".cub":
        from orthomvp.io.isis import read_cube  # pvl, only for cubes

        return read_cube(path)
    with open_raster(path) as src:
        try:
            return read_values(src, image_bands(src), None, np.float32)
        except RasterioError as exc:
            raise corrupt_data(path, exc) from exc


def read_values(src: Any, indexes: int | list[int] | None, window: Any, dtype: type) -> np.ndarray:
    """Bands ``indexes`` (as rasterio's ``read`` takes them) of the open dataset ``src`` in
    ``window`` as ``dtype`` floats, NaN where GDAL's mask says there is no value: the values
    of ``np.ma.filled(src.read(indexes, window=window, masked=True).astype(dtype), nan)``.

    Where that mask is plain, the data are read once and compared with the nodata value (a
    masked read reads them twice and imports ``numpy.ma``): every band read is all valid, or
    every band read is masked by its nodata value alone, the same value for all of them and
    one GDAL compares exactly (any value of an integer band, NaN of a float band; GDAL matches
    other float nodata values within a few ulps, which goes through the masked read). The
    masked read otherwise. RasterioError as rasterio raises it; InputError for complex values
    (never taken as their real part).

    The values are those the stored numbers stand for: each band's GDAL scale and offset
    (``value = stored * scale + offset``, as ``gdal_translate -unscale`` gives them) applied
    after the nodata test, which compares the stored numbers."""
    bands = [indexes] if isinstance(indexes, int) else indexes or list(src.indexes)
    for band in bands:
        if np.dtype(src.dtypes[band - 1]).kind == "c":
            raise InputError(
                f"{src.name}: band {band} holds complex numbers ({src.dtypes[band - 1]}), not "
                "real values; convert it first (its real part or its amplitude)"
            )
    values = _stored_values(src, indexes, bands, window, dtype)
    scales = [src.scales[b - 1] for b in bands]
    offsets = [src.offsets[b - 1] for b in bands]
    if all(scale == 1 for scale in scales) and not any(offsets):
        return values
    shape = () if isinstance(indexes, int) else (len(bands), 1, 1)
    values *= np.asarray(scales, dtype).reshape(shape)
    values += np.asarray(offsets, dtype).reshape(shape)
    return values


def _stored_values(
    src: Any, indexes: int | list[int] | None, bands: list[int], window: Any, dtype: type
) -> np.ndarray:
    """:func:`read_values` before the scale and offset: the stored numbers as ``dtype``, NaN
    where there is no value."""
    flags = {tuple(src.mask_flag_enums[b - 1]) for b in bands}
    nodatas = {src.nodatavals[b - 1] for b in bands}
    kinds = {np.dtype(src.dtypes[b - 1]) for b in bands}
    nodata = next(iter(nodatas)) if len(nodatas) == 1 else None
    if flags == {(MaskFlags.all_valid,)}:
        return src.read(indexes, window=window).astype(dtype)
    if flags == {(MaskFlags.nodata,)} and nodata is not None and len(kinds) == 1:
        (kind,) = kinds
        exact = np.isnan(nodata) if kind.kind == "f" else float(nodata).is_integer()
        if exact:
            data = src.read(indexes, window=window)
            values = data.astype(dtype)
            values[np.isnan(data) if np.isnan(nodata) else data == nodata] = np.nan
            return values
    data = src.read(indexes, window=window, masked=True)
    return np.ma.filled(data.astype(dtype), np.nan)


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
    with warnings.catch_warnings(), atomic_path(path, size=arr.nbytes) as tmp:
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(arr)
            for i, name in enumerate(band_names or [], start=1):
                dst.set_band_description(i, name)
        check_written(tmp)


def check_written(path: Path) -> None:
    """Open a GeoTIFF just written: GDAL does not always raise when closing a dataset fails
    (a full disk can leave an empty file), but then the file does not open."""
    with rasterio.open(path):
        pass
