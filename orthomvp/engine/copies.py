"""Images in formats that decode only from the top (JPEG, PNG), copied once per run into
uncompressed tiled GeoTIFFs that the tiles read window by window.

GDAL's JPEG and PNG drivers read an image a line at a time and keep no line they passed: a
window above the last one read decodes the file again from its first line. A run reads each
image in windows, tile after tile and from several threads, so a large JPEG would be decoded
from the top many times over (a 2,560 x 4,608 JPEG under 128-post tiles: 19.8 s against 4.0 s
for the same pixels as a tiled GeoTIFF). A run therefore copies each such image once, with
GDAL's own ``CreateCopy`` (the values, masks, nodata, scale and offset as GDAL reads them),
when a tile first needs it, and removes the copy as soon as no tile still to run needs it: the
disk holds the copies of the images that the tiles in flight and those between them need, not
of every image.

Copies go into a hidden folder beside the run's first output (the disk the user chose for
large files; a RAM-backed ``/tmp`` would take the copies from memory), or the temporary folder
when there is no output, which the run removes at its end. An image is read directly, as it
would be without copies, when its disk would be left with less than the reserve free, when the
copy fails for any reason, and on a Dask cluster with workers on other machines (they cannot
see this machine's folder)."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

SEQUENTIAL = frozenset({"JPEG", "PNG"})
"""GDAL drivers that decode from the top of the file for a window above the last one read."""

COPY_PIXELS = 1 << 22
"""Pixels (per band) from which such an image is copied; a smaller one decodes in a few tens of
milliseconds and is read directly."""

RESERVE = 1 << 30
"""Bytes that a copy must leave free on its disk, besides the outputs' own size."""


@dataclass(frozen=True)
class Copy:
    """Where a run puts an image's copy, its size (bytes, uncompressed) and the bytes that must
    stay free on that disk after it."""

    path: Path
    nbytes: int
    reserve: int


def copied(image: Path, copy: Copy) -> Path:
    """The file to read ``image`` from: its copy, made now unless another thread or process of
    the run made it (a lock file beside it lets one copy at a time); ``image`` itself when the
    disk lacks the room, the copies' folder is gone, or the copy failed (a corrupt image then
    fails as the direct read reports it; a file beside the copy says so to the next readers)."""
    target, failed = copy.path, copy.path.with_name(copy.path.name + ".failed")
    if target.exists():
        return target
    if failed.exists():
        return image
    try:
        with _locked(target.with_name(target.name + ".lock")):
            if not target.exists() and not failed.exists():
                _make(image, copy, failed)
    except OSError:  # (the lock file cannot be made)
        return image
    return target if target.exists() else image


def _make(image: Path, copy: Copy, failed: Path) -> None:
    """Copy ``image`` to ``copy.path`` (through a partial file, renamed when complete) when its
    disk keeps ``copy.reserve`` bytes free after it; on any failure, create ``failed``."""
    target = copy.path
    if shutil.disk_usage(target.parent).free - copy.nbytes < copy.reserve:
        return
    part = target.with_name(f"{target.name}.{os.getpid()}.{threading.get_ident()}.part")
    try:
        _copy(image, part)
        os.replace(part, target)
    except Exception:  # (any failure: the direct read is the answer)
        with contextlib.suppress(OSError):
            failed.touch()
    finally:
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)


def _copy(image: Path, part: Path) -> None:
    """``image`` as an uncompressed GeoTIFF of 256-pixel tiles at ``part`` (GDAL's CreateCopy:
    one pass down the image; its masks, nodata, scale and offset kept)."""
    import rasterio.shutil

    rasterio.shutil.copy(
        os.fspath(image),
        os.fspath(part),
        driver="GTiff",
        tiled=True,
        blockxsize=256,
        blockysize=256,
        bigtiff="IF_SAFER",
    )


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on the file ``path`` (created) within the block: between threads and
    processes alike (``flock`` locks an open file description); no lock where there is no
    ``fcntl``."""
    try:
        import fcntl
    except ImportError:  # (not on Linux or macOS: two readers may both copy; both are right)
        yield
        return
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def wanted(driver: str | None, width: int, height: int) -> bool:
    """Whether an image read by GDAL's ``driver`` with ``width`` x ``height`` pixels is copied."""
    return driver in SEQUENTIAL and width * height >= COPY_PIXELS


@contextlib.contextmanager
def image_copies(plan: Any, near: Path | None, *, local: bool, reserve: int = 0) -> Iterator[Any]:
    """``plan`` (any plan whose ``views`` are :class:`~orthomvp.engine.images.ImageSource`) with
    a :class:`Copy` for each view :func:`wanted` (none unless every worker is ``local``), in a
    hidden folder beside ``near`` (a file; the temporary folder when None or that folder cannot
    be made), removed with every copy at the end of the block. ``reserve``: bytes the outputs
    still need on that disk."""
    if not local or not any(wanted(v.driver, v.width, v.height) for v in plan.views):
        yield plan
        return
    folder = None
    for parent in ([near.parent] if near is not None else []) + [Path(tempfile.gettempdir())]:
        with contextlib.suppress(OSError):
            folder = Path(tempfile.mkdtemp(prefix=".orthomvp-copies-", dir=parent))
            break
    if folder is None:
        yield plan
        return
    views = tuple(
        replace(view, copy=Copy(folder / f"{k}.tif", _nbytes(view), RESERVE + reserve))
        if wanted(view.driver, view.width, view.height)
        else view
        for k, view in enumerate(plan.views)
    )
    try:
        yield replace(plan, views=views)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _nbytes(view: Any) -> int:
    """Bytes of ``view``'s uncompressed copy (its pixels, 8 bytes a sample at most)."""
    return view.width * view.height * view.bands * np.dtype(view.dtype or "float64").itemsize


def release_after(plan: Any, jobs: Sequence[int]) -> Callable[[int], None]:
    """``finished(index)``, to be called as each of the tiles ``jobs`` of ``plan`` is done: it
    removes the copy of each view that no tile of ``jobs`` still to finish reads."""
    views = {job.index: job.views for job in plan.tiles}
    left: dict[int, int] = {}
    for index in jobs:
        for k in views[index]:
            if plan.views[k].copy is not None:
                left[k] = left.get(k, 0) + 1
    lock = threading.Lock()

    def finished(index: int) -> None:
        for k in views[index]:
            with lock:
                if k not in left:
                    continue
                left[k] -= 1
                done = not left[k]
            if done:
                plan.views[k].copy.path.unlink(missing_ok=True)

    return finished
