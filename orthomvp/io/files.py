"""Reading input files safely. This module owns :func:`read_bounded` (the whole of a small
file: camera files and other parameter files, at most :data:`MAX_SMALL_FILE` bytes),
:func:`open_regular` (a file opened for reading, refused at once unless it is a regular file)
and :func:`check_regular` (the same check, for files that a library opens itself).

A FIFO, a device (``/dev/zero``, ``/dev/null``), a socket or a directory is refused by what it
is, without waiting for a writer or reading endlessly; a symbolic link is followed, and the
message names where it leads. A file larger than the limit is refused before it is read.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from orthomvp.errors import InputError
from orthomvp.io.preflight import disk_size_text

MAX_SMALL_FILE = 64 * 2**20
"""The most bytes :func:`read_bounded` reads: 64 MiB. Camera files are kilobytes to a few
megabytes (the largest of the test data, a CSM line-scan ISD: 178 kB); parsing text takes
several times its size in memory (a 2 GB ``.tsai`` of zeros peaked at 14.7 GB)."""

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _not_regular(path: Path, mode: int, what: str) -> InputError:
    """The InputError of ``path``, which is not a regular file (``mode``: its st_mode)."""
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    real = os.path.realpath(path)
    where = f" ({real})" if real != os.path.abspath(path) else ""
    return InputError(f"{path}: the {what} is {kind}{where}, not a regular file")


def check_regular(path: str | Path, what: str) -> None:
    """InputError unless ``path`` (a symbolic link followed) is a regular file: "not found",
    or what it is instead (a directory, a FIFO, a device, ...)."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found (no such file)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what} ({exc.strerror})") from exc
    if not stat.S_ISREG(mode):
        raise _not_regular(path, mode, what)


@contextlib.contextmanager
def open_regular(path: str | Path, what: str) -> Iterator[BinaryIO]:
    """``path`` opened for reading in binary; InputError naming ``what`` if it is missing,
    cannot be read, or is not a regular file (checked on the open file: a FIFO is opened
    without waiting for a writer, and refused)."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found (no such file)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what} ({exc.strerror})") from exc
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise _not_regular(path, mode, what)
        os.set_blocking(fd, True)
        handle = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with handle:
        yield handle


def read_bounded(path: str | Path, what: str, limit: int = MAX_SMALL_FILE) -> bytes:
    """The contents of the regular file ``path``, at most ``limit`` bytes (see
    :data:`MAX_SMALL_FILE`); InputError naming ``what`` if it is larger (refused before it
    is read, or once the limit is passed if it grows meanwhile), or cannot be read (see
    :func:`open_regular`)."""
    with open_regular(path, what) as handle:
        size = os.fstat(handle.fileno()).st_size
        data = handle.read(limit + 1) if size <= limit else b""
    if size > limit or len(data) > limit:
        raise InputError(
            f"{path}: {disk_size_text(max(size, len(data)))} is more than a {what} may be "
            f"({limit / 2**20:g} MiB at most)"
        )
    return data


def read_range(handle: BinaryIO, start: int, size: int) -> bytes:
    """Up to ``size`` bytes of the open regular file ``handle`` from byte ``start`` (0-based),
    never more than the file holds: a size taken from a file's own header or label (an ISIS3
    cube's pixels or tables) that is wrong must not be allocated (``read(10**11)`` allocates it
    first). Fewer bytes than ``size``: the file is truncated (the caller says so)."""
    end = os.fstat(handle.fileno()).st_size
    handle.seek(start)
    return handle.read(max(0, min(size, end - start)))
