"""Failed writes as one error line. This module owns :func:`writing`, the block around every
write of an output: a failure in it (an OSError, a rasterio or GDAL error) becomes one
OutputError naming the output and the cause ("cannot write out.tif: no space left on device
(needs up to 145 MB)", :func:`write_error`), and what GDAL and libtiff print on file descriptor
2 meanwhile is captured in memory and held back: it becomes that error when it tells of a
failure GDAL did not raise (a full disk when a dataset is closed), and is let through
otherwise. :func:`release_stderr` gives file descriptor 2 back after an interrupt.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from rasterio._err import CPLE_BaseError
from rasterio.errors import RasterioError

from orthomvp.errors import OrthoMVPError, OutputError
from orthomvp.io.preflight import disk_size_text
from orthomvp.io.signals import HeldSignals

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
    if code == errno.ENOENT and not path.parent.is_dir():
        cause = f"its directory {path.parent} was moved or removed during the run"
    elif code is not None:
        cause = _CAUSES.get(code) or os.strerror(code).lower()
    else:  # a GDAL error without an errno: its own words, without pointers to other lines
        text = " ".join(str(exc).replace("See previous exception for details.", "").split())
        cause = text or "the GeoTIFF writer failed"
    note = f" (needs up to {disk_size_text(size)})" if code in _SPACE and size else ""
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
                release_stderr()


def release_stderr() -> None:
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
