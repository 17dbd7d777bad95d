"""Raster file input and output: images of any common format, GeoTIFFs written atomically.

Arrays are band-first, ``(bands, rows, cols)``. Every writer goes through :func:`atomic_path`
(or :func:`atomic_paths` for a set of outputs, :func:`atomic_dir` for a directory), so a
failure never leaves a half-written file at the destination:

- outputs are written to hidden temporary files beside their targets, named with the process
  id (:func:`temp_name`), and renamed onto the targets only when all of them were written;
- a failure, SIGINT or SIGTERM removes them, and creating or removing one is never cut in
  half by a signal (:class:`HeldSignals`); what a killed run (SIGKILL) left is removed by the
  next run writing the same output (:func:`remove_stale`);
- a failed write is one OutputError naming the output and the cause ("cannot write out.tif:
  no space left on device (needs up to 145 MB)"), and what GDAL and libtiff print about it
  is held back (:func:`writing`); a disk with no space left is refused before writing.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import itertools
import os
import shutil
import signal
import sys
import threading
import warnings
import zlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import rasterio
from affine import Affine
from rasterio._err import CPLE_BaseError
from rasterio.enums import MaskFlags
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError

from orthomvp.errors import InputError, OrthoMVPError, OutputError

SIGNALS_HELD = (signal.SIGINT, signal.SIGTERM)
"""The signals that :class:`HeldSignals` holds (Ctrl-C, and ``timeout``'s or a scheduler's)."""
TEMP_TAG = "orthomvp"
"""Temporary outputs are named ``.NAME.orthomvp-PID-HOST-TOKEN[TAG]SUFFIX`` beside NAME."""
_HOST = f"{zlib.crc32(os.uname().nodename.encode()):08x}"
_CAUSES = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EFBIG: "file too large",
    errno.EIO: "input/output error",
}
"""Causes of failed writes, as they are named in error messages."""
_SPACE = (errno.ENOSPC, errno.EDQUOT)


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _deliver(signum: int, handler: Any, frame: FrameType | None) -> None:
    """Hand signal ``signum`` to ``handler`` as returned by :func:`signal.getsignal`."""
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL:
        signal.signal(signum, signal.SIG_DFL)
        signal.raise_signal(signum)


class HeldSignals:
    """Within the block, SIGINT and SIGTERM are held, and delivered at its end to the handlers
    of before; within :meth:`released` (the long work, such as writing the file) they are
    not. So everything around that work (creating a temporary file and noting its name,
    renaming it, removing it) is never cut in half by a signal: one arriving there waits,
    and one arriving during the work raises where the clean-up that follows is held again.
    Only the main thread runs Python's signal handlers: elsewhere nothing is held."""

    def __init__(self) -> None:
        self.previous: dict[int, Any] = {}
        self.held: list[int] = []
        self.holding = False

    def _hold(self, signum: int, frame: FrameType | None) -> None:
        if self.holding:
            self.held.append(signum)
        else:  # left installed: a signal cut short putting the handlers back
            _deliver(signum, self.previous[signum], frame)

    def __enter__(self) -> HeldSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS_HELD:
                handler = signal.getsignal(sig)
                if handler is None:  # not installed from Python: cannot be put back
                    continue
                if handler != self._hold:  # (still installed if putting it back was cut)
                    self.previous[sig] = handler
                signal.signal(sig, self._hold)
            self.holding = True
        return self

    def __exit__(self, *exc: object) -> None:
        if not self.holding:  # released, and never taken back (see released)
            return
        self.holding = False
        try:
            for sig, handler in self.previous.items():
                signal.signal(sig, handler)
        finally:
            held, self.held = self.held, []
            for sig in dict.fromkeys(held):
                signal.raise_signal(sig)

    @contextlib.contextmanager
    def released(self) -> Iterator[None]:
        """Within this block the signals are not held (those held so far are delivered)."""
        self.__exit__()
        try:
            yield
        except GeneratorExit:  # closed by the garbage collector, long after: leave them alone
            raise
        except BaseException:
            self.__enter__()
            raise
        self.__enter__()


_pending: dict[Path, None] = {}
"""This process's temporary outputs (files and directories) not yet renamed or removed."""


def _new_temp(path: Path, tag: str = "") -> Path:
    """A new :func:`temp_name`, noted in :data:`_pending` (call with signals held)."""
    tmp = temp_name(path, tag)
    _pending[tmp] = None
    return tmp


def _drop(tmp: Path) -> None:
    """Remove a temporary output (call with signals held)."""
    _remove(tmp)
    _pending.pop(tmp, None)


def remove_temporaries() -> None:
    """The last resort after an interrupt: remove every temporary output of this process that
    is still there, and give file descriptor 2 back if it is captured (see :func:`writing`).

    A signal that arrives just as a ``with`` block ends (in contextlib, before it resumes the
    generator that would clean up) leaves that clean-up to the garbage collector, which may
    run late or not at all; the command line calls this before it reports the interrupt, and
    it runs at exit."""
    for tmp in list(_pending):
        _drop(tmp)
    _end_capture()


def temp_name(path: Path, tag: str = "") -> Path:
    """A new temporary name beside ``path`` that :func:`remove_stale` recognises: hidden, with
    this process's id and machine, ending as ``path`` does (``tag`` before the suffix)."""
    token = os.urandom(4).hex()
    name = f".{path.name}.{TEMP_TAG}-{os.getpid()}-{_HOST}-{token}{tag}{path.suffix}"
    return path.with_name(name)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` (of this machine) exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True


def remove_stale(path: Path) -> list[Path]:
    """Remove the temporary files and directories of ``path`` (see :func:`temp_name`) that
    runs on this machine left when they were killed (SIGKILL, a power cut): those whose
    process is gone. Returns what was removed."""
    prefix = f".{path.name}.{TEMP_TAG}-"
    try:
        entries = [e for e in os.scandir(path.parent) if e.name.startswith(prefix)]
    except OSError:
        return []
    removed = []
    for entry in entries:
        pid, _, rest = entry.name[len(prefix) :].partition("-")
        if not pid.isdigit() or not rest.startswith(f"{_HOST}-") or _alive(int(pid)):
            continue
        with contextlib.suppress(OSError):  # another run may have removed it first
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def _remove(tmp: Path) -> None:
    """Remove a temporary file (with the .aux.xml sidecar GDAL may leave) or directory, if
    there. A failure is not reported: the error that led here is the one to report (and on
    a read-only file system even removing what is not there fails)."""
    if tmp.is_dir() and not tmp.is_symlink():
        shutil.rmtree(tmp, ignore_errors=True)
    for name in (tmp, Path(f"{tmp}.aux.xml")):
        with contextlib.suppress(OSError):
            name.unlink()


def _size_text(size: int) -> str:
    """``size`` bytes in kB, MB or GB (powers of 1000)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{max(size, 1) / 1e3:.3g} kB"


def check_space(path: str | Path, need: int = 0) -> None:
    """OutputError unless the file system of ``path``'s directory has ``need`` bytes (and at
    least one) free."""
    path = Path(path)
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return  # the directory is checked elsewhere
    if free < max(need, 1):
        note = f" (needs about {_size_text(need)}, {_size_text(free)} free)" if need else ""
        raise OutputError(f"cannot write {path}: no space left on device{note}")


def write_error(
    path: Path, exc: BaseException | None, chatter: str = "", size: int | None = None
) -> OutputError:
    """The one-line OutputError of a failed write of ``path``: the cause from ``exc``'s errno,
    from what GDAL or libtiff printed (``chatter``), or from a full disk, with how much
    space the output needs (``size``, at most) when the cause is space."""
    # GDAL's exceptions have an errno of their own (CPLE numbers): only an OSError's counts
    code = exc.errno if isinstance(exc, OSError) and not isinstance(exc, CPLE_BaseError) else None
    if code is None:
        code = next((c for c in _CAUSES if os.strerror(c) in chatter), None)
    if code is None:
        with contextlib.suppress(OSError):
            code = errno.ENOSPC if shutil.disk_usage(path.parent).free == 0 else None
    if code is not None:
        cause = _CAUSES.get(code) or os.strerror(code).lower()
    else:  # a GDAL error without an errno: its own words, without pointers to other lines
        text = " ".join(str(exc).replace("See previous exception for details.", "").split())
        cause = text or "the GeoTIFF writer failed"
    note = f" (needs up to {_size_text(size)})" if code in _SPACE and size else ""
    return OutputError(f"cannot write {path}: {cause}{note}")


def _failed(chatter: str) -> bool:
    """Whether what GDAL and libtiff printed tells of a failed write: libtiff's I/O procedures
    (``_tiffWriteProc``, ``_tiffSeekProc``) complain only then, and so does a cause of
    :data:`_CAUSES`. (Other messages, which GDAL recovers from, are let through.)"""
    return any(
        line.startswith("_tiff") or any(os.strerror(c) in line for c in _CAUSES)
        for line in chatter.splitlines()
    )


_capture: dict[str, int | None] = {"fd": None, "saved": None}
"""The capture of file descriptor 2: its file in memory, and the real stderr."""
_capture_lock = threading.RLock()


@contextlib.contextmanager
def _stderr_captured() -> Iterator[Callable[[], str]]:
    """Within the block, file descriptor 2 (where GDAL and libtiff print their errors) goes into
    memory; yields a function returning what was printed so far. Blocks of other threads wait;
    nested blocks share the outer one's capture."""
    with _capture_lock:
        if (fd := _capture["fd"]) is not None:
            start = os.lseek(fd, 0, os.SEEK_CUR)
            yield lambda: os.pread(fd, 1 << 16, start).decode(errors="replace")
            return
        with HeldSignals() as held:
            try:
                sys.stderr.flush()
                fd = _capture["fd"] = _memory_file()
                _capture["saved"] = os.dup(2)
                os.dup2(fd, 2)
                with held.released():
                    yield lambda: os.pread(fd, 1 << 16, 0).decode(errors="replace")
            finally:
                _end_capture()


def _end_capture() -> None:
    """Give file descriptor 2 back, if it is captured (call with signals held)."""
    fd, saved = _capture["fd"], _capture["saved"]
    _capture.update(fd=None, saved=None)
    if saved is not None:
        os.dup2(saved, 2)
        os.close(saved)
    if fd is not None:
        os.close(fd)


def _memory_file() -> int:
    """A file descriptor of a file in memory (where possible, else of the null device)."""
    if hasattr(os, "memfd_create"):
        return os.memfd_create("orthomvp-stderr")
    return os.open(os.devnull, os.O_WRONLY)


@contextlib.contextmanager
def writing(path: str | Path, size: int | None = None) -> Iterator[None]:
    """Report a failure of the block, which writes ``path``, as one OutputError naming ``path``
    and the cause (see :func:`write_error`). What GDAL and libtiff print meanwhile is held
    back: it becomes that error when it tells of a failure (also of one they did not raise,
    such as a full disk when a dataset is closed), and is let through otherwise."""
    path = Path(path)
    with _stderr_captured() as printed:
        try:
            yield
        except OrthoMVPError:
            raise
        except (OSError, RasterioError, CPLE_BaseError) as exc:
            raise write_error(path, exc, printed(), size) from exc
        chatter = printed()
    if _failed(chatter):
        raise write_error(path, None, chatter, size)
    sys.stderr.write(chatter)


@contextlib.contextmanager
def atomic_paths(paths: Sequence[str | Path], need: Sequence[int] = ()) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``paths``; rename them onto ``paths``, one after another,
    when the block succeeds; on any failure (SIGINT and SIGTERM too) remove them all and
    touch no target.

    First the temporary files that killed runs left beside the targets are removed (see
    :func:`remove_stale`), and the free space is checked: at least one byte, and ``need``
    (bytes each output surely takes) in total per directory. A failure to create or rename
    raises an OutputError naming the target; the writes themselves are the block's (see
    :func:`writing`)."""
    targets = [Path(p) for p in paths]
    for target in targets:
        if not target.parent.is_dir():
            raise InputError(f"{target}: output directory {target.parent} does not exist")
    temps: list[Path] = []
    target = targets[0]
    own = True  # whether an OSError is of creating or renaming (the block's pass through)
    with HeldSignals() as held:
        try:
            per_dir: dict[Path, list] = {}  # the first target of each directory, and the total
            for target, size in itertools.zip_longest(targets, need[: len(targets)], fillvalue=0):
                per_dir.setdefault(target.parent, [target, 0])[1] += size
            for target, total in per_dir.values():
                check_space(target, total)
            for target in targets:
                remove_stale(target)
                temps.append(_new_temp(target))  # noted before it exists: removed in any case
                os.close(os.open(temps[-1], os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            own = False
            with held.released():
                yield temps
            own = True
            mode = 0o666 & ~_umask()
            for target, tmp in zip(targets, temps, strict=True):  # noqa: B007 (named on failure)
                os.chmod(tmp, mode)
                os.replace(tmp, target)
        except OrthoMVPError:
            raise
        except OSError as exc:
            if not own:
                raise
            raise write_error(target, exc) from exc
        finally:
            for tmp in temps:
                _drop(tmp)


@contextlib.contextmanager
def atomic_path(path: str | Path, size: int | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds
    (see :func:`atomic_paths`). A failed write in the block is reported as one OutputError
    naming ``path`` (see :func:`writing`; ``size``: bytes the output takes at most)."""
    with atomic_paths([path]) as (tmp,), writing(path, size):
        yield tmp


def write_set(writers: dict[Path, Callable[[Path], object]]) -> None:
    """Write several files as one atomic set: each ``writers[path](tmp)`` writes its
    temporary file; all are renamed onto their paths only when all were written (see
    :func:`atomic_paths`); a failure is one OutputError naming the file."""
    with atomic_paths(list(writers)) as temps:
        for (path, write), tmp in zip(writers.items(), temps, strict=True):
            with writing(path):
                write(tmp)


@contextlib.contextmanager
def scratch_path(path: str | Path, tag: str) -> Iterator[Path]:
    """Yield a temporary name beside ``path`` (see :func:`temp_name`) for work files that
    make ``path``; whatever was written there is removed after the block."""
    with HeldSignals() as held:
        tmp = _new_temp(Path(path), tag)
        try:
            with held.released():
                yield tmp
        finally:
            _drop(tmp)


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; on success move its files into ``path``.

    On failure (SIGINT and SIGTERM too) the temporary directory is removed and ``path`` is
    left as it was; errors name the files under ``path``, not under the temporary directory.
    Temporary directories of killed runs are removed first (see :func:`remove_stale`).
    """
    path = Path(path)
    if not path.parent.exists():
        raise InputError(f"{path}: parent directory {path.parent} does not exist")
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a directory")
    check_space(path)
    tmp: Path | None = None
    with HeldSignals() as held:
        try:
            remove_stale(path)
            tmp = _new_temp(path)
            tmp.mkdir()
            with held.released():
                yield tmp
            os.chmod(tmp, 0o777 & ~_umask())
            if path.exists():
                for item in tmp.iterdir():
                    os.replace(item, path / item.name)
            else:
                os.replace(tmp, path)
        except OutputError as exc:
            raise OutputError(str(exc).replace(str(tmp), str(path))) from exc.__cause__
        except OSError as exc:
            if tmp is None or not str(exc.filename or "").startswith(str(tmp)):
                raise
            raise write_error(path / Path(exc.filename).relative_to(tmp), exc) from exc
        finally:
            if tmp is not None:
                _drop(tmp)


atexit.register(remove_temporaries)


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


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 ``(bands, rows, cols)``; nodata -> NaN.

    ISIS3 cubes (``.cub``) are read by :func:`orthomvp.io.isis.read_cube` (special pixels -> NaN);
    everything else (GeoTIFF/TIFF of any dtype and band count, PNG, JPEG, ...) by rasterio.
    """
    if isinstance(path, (str, os.PathLike)) and Path(path).suffix.lower() == ".cub":
        from orthomvp.io.isis import read_cube  # pvl, only for cubes

        return read_cube(path)
    with open_raster(path) as src:
        try:
            return read_values(src, None, None, np.float32)
        except RasterioError as exc:
            raise InputError(f"{path}: corrupt raster data ({exc})") from exc


def read_values(src: Any, indexes: int | list[int] | None, window: Any, dtype: type) -> np.ndarray:
    """Bands ``indexes`` (as rasterio's ``read`` takes them) of the open dataset ``src`` in
    ``window`` as ``dtype`` floats, NaN where GDAL's mask says there is no value: the values
    of ``np.ma.filled(src.read(indexes, window=window, masked=True).astype(dtype), nan)``.

    Where that mask is plain, the data are read once and compared with the nodata value (a
    masked read reads them twice and imports ``numpy.ma``): every band read is all valid, or
    every band read is masked by its nodata value alone, the same value for all of them and
    one GDAL compares exactly (any value of an integer band, NaN of a float band; GDAL matches
    other float nodata values within a few ulps, which goes through the masked read). The
    masked read otherwise. RasterioError as rasterio raises it."""
    bands = [indexes] if isinstance(indexes, int) else indexes or list(src.indexes)
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
