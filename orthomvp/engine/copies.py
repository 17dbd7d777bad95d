"""Images in formats that decode only from the top (JPEG, PNG, GeoTIFFs of one compressed
strip), copied once per run into uncompressed tiled GeoTIFFs that the tiles read window by
window.

GDAL's JPEG and PNG drivers read an image a line at a time and keep no line they passed, and
so does its GeoTIFF driver for a compressed strip that holds the whole image: a window above
the last one read decodes the file again from its first line. A run reads each image in
windows, tile after tile and from several threads, so a large JPEG was decoded from the top
many times over (a 2,560 x 4,608 px JPEG under 128-post tiles: 10.4 s against 4.2 s for the
same pixels as a tiled GeoTIFF, ``orthomvp bench --formats``). A run therefore copies each
such image once, with GDAL's own ``CreateCopy`` (the values, masks, nodata, scale and offset as
GDAL reads them), in a background thread as soon as the first tile that reads it is
submitted (a worker that needs it sooner waits for it), and removes the copy as soon as no
tile still to run reads it: the disk holds the copies that the tiles in flight need, not one
of every image.

Only an image that two tiles or more of the run read is copied (one tile reads its window
once, as cheaply as the copy would). Copies go into a hidden folder beside the run's first
output (the disk the user chose for large files), else (and for ``check``, which writes no
raster) the temporary folder, never a folder in memory (a RAM-backed ``/tmp`` would take the
copies from memory). The run holds a lock in its folder while it lasts and removes the folder
at its end; it also removes the folders there that runs of this machine killed outright left
(the folder's name holds the host and the process id; its lock is free). An image is read
directly, as it would be without copies, when its disk would be left with less than the
reserve free (with a warning), when the copy fails or would not read as the image does, and on
a Dask cluster with workers on other machines (they cannot see this machine's folder)."""

from __future__ import annotations

import contextlib
import glob
import os
import re
import shutil
import socket
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from rasterio.enums import Interleaving

from orthomvp.errors import OrthoMVPWarning
from orthomvp.io.preflight import size_text
from orthomvp.io.raster import open_raster

SEQUENTIAL = frozenset({"JPEG", "PNG"})
"""GDAL drivers that decode from the top of the file for a window above the last one read."""

COPY_PIXELS = 1 << 22
"""Pixels (per band) from which such an image is copied; a smaller one decodes in a few tens of
milliseconds and is read directly."""

BLOCK_BYTES = 16 << 20
"""Bytes of a compressed GeoTIFF block (decoded) from which its image is copied."""

RESERVE = 1 << 30
"""Bytes that a copy must leave free on its disk, besides the outputs' own size."""


@dataclass(frozen=True)
class Copy:
    """Where a run puts an image's copy, its size (bytes, uncompressed) and the bytes that must
    stay free on that disk after it."""

    path: Path
    nbytes: int
    reserve: int


def copied(image: Path, copy: Copy, *, full: Callable[[int], None] | None = None) -> Path:
    """The file to read ``image`` from: its copy, made now unless another thread or process of
    the run made it (a lock file beside it lets one copy at a time); ``image`` itself when the
    disk lacks the room (then ``full(free bytes)`` is called), the copies' folder is gone, or
    the copy failed (a corrupt image then fails as the direct read reports it; a file beside
    the copy says so to the next readers)."""
    target, failed = copy.path, copy.path.with_name(copy.path.name + ".failed")
    if target.exists():
        return target
    if failed.exists():
        return image
    try:
        with _locked(target.with_name(target.name + ".lock")):
            if not target.exists() and not failed.exists():
                _make(image, copy, failed, full)
    except OSError:  # (the lock file cannot be made)
        return image
    return target if target.exists() else image


def _make(image: Path, copy: Copy, failed: Path, full: Callable[[int], None] | None) -> None:
    """Copy ``image`` to ``copy.path`` (through a partial file, renamed when complete) when its
    disk keeps ``copy.reserve`` bytes free after it (else ``full(free bytes)``, if given); on
    any failure, create ``failed``."""
    target = copy.path
    room, free = _room(copy)
    if not room:
        if full is not None:
            full(free)
        return
    part = target.with_name(f"{target.name}.{os.getpid()}.{threading.get_ident()}.part")
    try:
        _copy(image, part)
        os.replace(part, target)
    except Exception:  # (any failure: the direct read is the answer)
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)  # (first: room for the mark on a full disk)
        with contextlib.suppress(OSError):
            failed.touch()
    finally:
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)


def _room(copy: Copy) -> tuple[bool, int]:
    """Whether the disk of ``copy``'s folder keeps ``copy.reserve`` bytes free after it, and
    its free bytes (OSError where the folder is gone)."""
    free = shutil.disk_usage(copy.path.parent).free
    return free - copy.nbytes >= copy.reserve, free


def _copy(image: Path, part: Path) -> None:
    """``image`` as an uncompressed GeoTIFF of 256-pixel tiles at ``part`` (GDAL's CreateCopy:
    one pass down the image; its masks, nodata, scale and offset kept, the mask inside the
    file whatever ``GDAL_TIFF_INTERNAL_MASK`` says); ValueError when ``part`` would not read
    as ``image`` does: a sidecar file beside it (which renaming ``part`` would leave behind),
    or another nodata, mask, scale or offset of a band (a GeoTIFF has one nodata value for
    all its bands)."""
    import rasterio
    import rasterio.shutil

    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        rasterio.shutil.copy(
            os.fspath(image),
            os.fspath(part),
            driver="GTiff",
            tiled=True,
            blockxsize=256,
            blockysize=256,
            bigtiff="IF_SAFER",
        )
    if any(part.parent.glob(f"{glob.escape(part.name)}.*")):
        raise ValueError(f"{part}: GDAL wrote a sidecar file")
    with open_raster(image) as src, open_raster(part) as dst:
        if _reading(src) != _reading(dst):
            raise ValueError(f"{part}: the copy does not read as {image} does")


def _reading(src: Any) -> tuple:
    """What GDAL's reading of the open dataset ``src`` depends on besides its pixels: its
    bands' data types, nodata values, mask flags, scales and offsets."""
    nodata = tuple(repr(value) for value in src.nodatavals)  # (NaN equals NaN)
    flags = tuple(tuple(band) for band in src.mask_flag_enums)
    return src.count, src.dtypes, nodata, flags, src.scales, src.offsets


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


def decodes_from_top(src: Any) -> bool:
    """Whether GDAL decodes the open dataset ``src`` from its top, or decodes far more than a
    window, for a window above the last one read: a JPEG or PNG file, or a compressed GeoTIFF
    whose strip GDAL reads a line at a time (one 8-bit strip of over 2,000 lines for the whole
    image: GDAL's blocks are then one line high) or whose blocks hold :data:`BLOCK_BYTES` or
    more (each thread's dataset would keep its own in GDAL's cache)."""
    if src.driver in SEQUENTIAL:
        return True
    if src.driver != "GTiff" or src.compression is None or not src.block_shapes:
        return False
    lines, width = src.block_shapes[0]
    size = lines * width * np.dtype(src.dtypes[0]).itemsize
    size *= src.count if src.interleaving == Interleaving.pixel else 1
    # (a strip GDAL splits into lines has no offset of its own: strips of one line do)
    split = lines == 1 < src.height and not src.get_tag_item("BLOCK_OFFSET_0_1", "TIFF", bidx=1)
    return split or size >= BLOCK_BYTES


def wanted(view: Any) -> bool:
    """Whether ``view`` (an :class:`~orthomvp.engine.images.ImageSource`) is copied: it
    :func:`decodes_from_top` and has :data:`COPY_PIXELS` or more."""
    return view.from_top and view.width * view.height >= COPY_PIXELS


IN_USE = "in-use.lock"
"""The file in a folder of copies that its run holds locked (``flock``) while it lasts."""

STALE_SECONDS = 60.0
"""Seconds since a folder of copies last changed before another run may remove it."""

REREADS = 2
"""Tiles of a run (or of a survey) that must read an image for it to be copied: one tile
reads its window once, as cheaply as the copy would."""


@contextlib.contextmanager
def image_copies(
    plan: Any, near: Path | None, *, local: bool, jobs: Sequence[int], reserve: int = 0
) -> Iterator[Any]:
    """``plan`` (any plan whose ``views`` are :class:`~orthomvp.engine.images.ImageSource`) with
    a :class:`Copy` for each view :func:`wanted` that :data:`REREADS` or more of the tiles
    ``jobs`` read (none unless every worker is ``local``), in a hidden folder beside ``near``
    (a file; the temporary folder when None or that folder cannot be made; never a folder in
    memory, such as a ``tmpfs``), removed with every copy at the end of the block; the same
    plan when no view is copied. ``reserve``: bytes the outputs still need on that disk."""
    reads = _reads(plan, jobs)
    chosen = [wanted(v) and n >= REREADS for v, n in zip(plan.views, reads, strict=True)]
    if not local or not any(chosen):
        yield plan
        return
    folder = None
    parents = [near.parent] if near is not None else []
    for parent in [Path(p).resolve() for p in [*parents, tempfile.gettempdir()]]:
        if _in_memory(parent):
            continue
        with contextlib.suppress(OSError):
            folder = Path(tempfile.mkdtemp(prefix=_prefix(os.getpid()), dir=parent))
        if folder is not None:
            with contextlib.suppress(OSError):  # (its own folder is made: it stays the one)
                _remove_stale(parent)
            break
    if folder is None:
        yield plan
        return
    views = tuple(
        replace(view, copy=Copy(folder / f"{k}.tif", _nbytes(view), RESERVE + reserve))
        if chosen[k]
        else view
        for k, view in enumerate(plan.views)
    )
    with contextlib.ExitStack() as stack:
        stack.callback(shutil.rmtree, folder, ignore_errors=True)
        with contextlib.suppress(OSError):  # (held while the run lasts: the folder is in use)
            stack.enter_context(_locked(folder / IN_USE))
        yield replace(plan, views=views)


def reread(plan: Any, jobs: Sequence[int]) -> Any:
    """``plan`` without the copies of the views that fewer than :data:`REREADS` of its tiles
    ``jobs`` read (a survey's plan: the same plan when none is dropped)."""
    reads = _reads(plan, jobs)
    if all(v.copy is None or n >= REREADS for v, n in zip(plan.views, reads, strict=True)):
        return plan
    views = tuple(
        v if n >= REREADS else replace(v, copy=None) for v, n in zip(plan.views, reads, strict=True)
    )
    return replace(plan, views=views)


def _reads(plan: Any, jobs: Sequence[int]) -> list[int]:
    """Per view of ``plan``, how many of its tiles ``jobs`` read it."""
    views = {job.index: job.views for job in plan.tiles}
    reads = [0] * len(plan.views)
    for index in jobs:
        for k in views[index]:
            reads[k] += 1
    return reads


def _in_memory(folder: Path) -> bool:
    """Whether ``folder`` lies on a file system held in memory (``tmpfs``, ``ramfs``: Linux's
    ``/proc/mounts``; False where it cannot be told)."""
    try:
        with open("/proc/mounts", encoding="utf-8", errors="replace") as handle:
            mounts = [line.split()[1:3] for line in handle if len(line.split()) > 2]
    except OSError:
        return False
    path = os.fspath(folder)
    best, kind = "", ""
    for point, fstype in mounts:  # (in mounting order: of two on one point, the later is seen)
        point = re.sub(r"\\([0-7]{3})", lambda m: chr(int(m[1], 8)), point)  # (\040: " ")
        inside = path == point or path.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= len(best):
            best, kind = point, fstype
    return kind in ("tmpfs", "ramfs")


def _prefix(pid: int) -> str:
    """The start of the name of a folder of copies made by process ``pid`` of this machine."""
    return f".orthomvp-copies-{socket.gethostname()}-{pid}-"


def _remove_stale(parent: Path) -> None:
    """Remove the folders of copies in ``parent`` that a process of this machine that no longer
    runs left behind (killed outright, it could not remove them); those of other machines, of
    running processes and anything else stay."""
    if os.name != "posix":  # (os.kill(pid, 0) ends the process on Windows)
        return
    start = _prefix(0)[:-2]  # (".orthomvp-copies-HOST-")
    for folder in parent.glob(f"{glob.escape(start)}*"):
        pid, _, rest = folder.name[len(start) :].partition("-")  # (rest: mkdtemp's, no "-")
        if not re.fullmatch("[0-9]+", pid) or not rest or "-" in rest:
            continue
        if not folder.is_dir() or folder.is_symlink():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            _remove_unused(folder)
        except (PermissionError, OverflowError):  # (another user's live process; no such pid)
            continue


def _remove_unused(folder: Path) -> None:
    """Remove ``folder`` (of copies, whose process id runs no process here) unless a run holds
    its lock (a run in another process-id namespace of the same host, such as a container) or
    it changed in the last :data:`STALE_SECONDS` (a run making it now)."""
    import fcntl

    if time.time() - folder.stat().st_mtime < STALE_SECONDS:
        return
    with open(folder / IN_USE, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return
        shutil.rmtree(folder, ignore_errors=True)


def _nbytes(view: Any) -> int:
    """Bytes of ``view``'s uncompressed copy (its pixels, 8 bytes a sample at most)."""
    return view.width * view.height * view.bands * np.dtype(view.dtype or "float64").itemsize


class Copies:
    """The copies that the tiles ``jobs`` of ``plan`` read: each made ahead, in one background
    thread of this process, as the first tile reading it is submitted (:meth:`started`; a
    worker that needs it sooner waits for it on its lock), and removed when the last tile
    reading it finishes (:meth:`finished`). :meth:`close` waits for the thread (a run uses
    it within ``contextlib.closing``). ``warned``: the images already said to have no room for
    their copy (in a survey before; each is said once)."""

    def __init__(self, plan: Any, jobs: Sequence[int], warned: set[Path] | None = None) -> None:
        self.plan = plan
        self.warned = set() if warned is None else warned  # (images said to have no room)
        self.views = {job.index: job.views for job in plan.tiles}
        reads = enumerate(zip(plan.views, _reads(plan, jobs), strict=True))
        self.left = {k: n for k, (view, n) in reads if view.copy is not None and n}
        self.lock = threading.Lock()
        self.queued: set[int] = set()
        self.pool: ThreadPoolExecutor | None = None

    def started(self, index: int) -> None:
        """Tile ``index`` is submitted: start the copies of its views not started yet."""
        for k in self.views[index]:
            if k in self.left and k not in self.queued:
                self.queued.add(k)
                if self.pool is None:
                    self.pool = ThreadPoolExecutor(1, thread_name_prefix="orthomvp-copy")
                self.pool.submit(self._ahead, k)

    def _ahead(self, k: int) -> None:
        """Make view ``k``'s copy unless no tile needs it any more (and remove it when the last
        tile finished meanwhile); an :class:`~orthomvp.errors.OrthoMVPWarning` when its disk
        has no room for it (the image is then read directly)."""
        view = self.plan.views[k]
        with self.lock:
            if not self.left[k]:
                return

        def full(free: int) -> None:  # (when this thread found no room, not another's copy)
            if view.path in self.warned:
                return
            self.warned.add(view.path)
            warnings.warn(
                f"{view.path}: read directly, decoded again for every tile that reads it: "
                f"no room for its copy ({size_text(view.copy.nbytes)}, with "
                f"{size_text(view.copy.reserve)} kept free; {size_text(free)} "
                f"free in {view.copy.path.parent.parent})",
                OrthoMVPWarning,
                stacklevel=1,
            )

        copied(view.path, view.copy, full=full)
        with self.lock:
            if not self.left[k]:
                view.copy.path.unlink(missing_ok=True)

    def finished(self, index: int) -> None:
        """Tile ``index`` is done: remove the copy of each view that no tile still reads."""
        for k in self.views[index]:
            with self.lock:
                if k not in self.left:
                    continue
                self.left[k] -= 1
                if not self.left[k]:
                    self.plan.views[k].copy.path.unlink(missing_ok=True)

    def close(self) -> None:
        """Wait for the copy under way, start no other."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
