"""Atomic output sets, the writer every command relies on. This module owns
:func:`atomic_path`, :func:`atomic_paths`, :func:`write_set`, :func:`atomic_dir` and
:func:`scratch_path`: outputs are written to hidden temporary files beside their targets, named
with the process id and machine (:func:`temp_name`), and renamed onto the targets only when all
of them were written; a failure, SIGINT or SIGTERM removes them (creating, renaming or removing
one is never cut in half by a signal: :class:`~orthomvp.io.signals.HeldSignals`), what a killed
run (SIGKILL) left is removed by the next run writing the same output (:func:`remove_stale`),
and :func:`remove_temporaries` is the last resort after an interrupt and at exit. A disk with
no space left is refused before writing (:func:`~orthomvp.io.preflight.check_space`); a failed
write is one OutputError naming the output (:func:`~orthomvp.io.write_errors.writing`).
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import os
import shutil
import stat
import tempfile
import zlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from orthomvp.errors import InputError, OrthoMVPError, OutputError
from orthomvp.io.preflight import check_space
from orthomvp.io.signals import HeldSignals
from orthomvp.io.write_errors import release_stderr, write_error, writing

TEMP_TAG = "orthomvp"
"""Temporary outputs are named ``.NAME.orthomvp-PID-HOST-TOKEN[TAG]SUFFIX`` beside NAME (a long
NAME shortened: :func:`_name_part`)."""
_HOST = f"{zlib.crc32(os.uname().nodename.encode()):08x}"


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_pending: dict[Path, int | None] = {}
"""This process's temporary outputs (files and directories) not yet renamed or removed, with
a file descriptor of the directory they are in (None where it cannot be opened): they are
removed through it, so that those of a directory renamed or moved during the run are removed
too."""


written: list[Path] = []
"""The outputs this process renamed onto their targets (complete, each set of them whole; not
those renamed inside a temporary directory, which counts once moved in place)."""


def _new_temp(path: Path, tag: str = "") -> Path:
    """A new :func:`temp_name`, noted in :data:`_pending` (call with signals held)."""
    tmp = temp_name(path, tag)
    try:
        fd: int | None = os.open(tmp.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        fd = None
    _pending[tmp] = fd
    return tmp


def _drop(tmp: Path) -> None:
    """Remove a temporary output (call with signals held): where its directory is now, if it
    was renamed or moved meanwhile."""
    fd = _pending.pop(tmp, None)
    try:
        _remove(tmp, fd)
    finally:
        if fd is not None:
            os.close(fd)


def remove_temporaries() -> None:
    """The last resort after an interrupt: remove every temporary output of this process that
    is still there, and give file descriptor 2 back if it is captured (see
    :func:`~orthomvp.io.write_errors.writing`).

    A signal that arrives just as a ``with`` block ends (in contextlib, before it resumes the
    generator that would clean up) leaves that clean-up to the garbage collector, which may
    run late or not at all; the command line calls this before it reports the interrupt, and
    it runs at exit."""
    for tmp in list(_pending):
        _drop(tmp)
    release_stderr()


NAME_PART = 100
"""Bytes of the output's name that its temporaries' names keep (see :func:`_name_part`)."""


def _name_part(path: Path) -> str:
    """The output's name as its temporaries' names begin with it: whole when it is at most
    :data:`NAME_PART` bytes of UTF-8, else its first bytes and a checksum of the whole name,
    so that a temporary's name stays well within the 255 bytes a file name may have however
    long the output's name is; bytes that are not UTF-8 are replaced (GDAL takes UTF-8 file
    names only; the temporary is renamed onto the output's own name)."""
    raw = os.fsencode(path.name)
    text = raw.decode("utf-8", "replace")
    if len(raw) <= NAME_PART and text == path.name:
        return text
    short = raw[: NAME_PART - 9].decode("utf-8", "replace").rstrip("\ufffd") or "_"
    return f"{short}~{zlib.crc32(raw):08x}"


def temp_name(path: Path, tag: str = "") -> Path:
    """A new temporary name beside ``path`` that :func:`remove_stale` recognises: hidden, with
    this process's id and machine, ending as ``path`` does (``tag`` before the suffix; a suffix
    of more than 16 bytes is left out)."""
    token = os.urandom(4).hex()
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= 16 else ""
    name = f".{_name_part(path)}.{TEMP_TAG}-{os.getpid()}-{_HOST}-{token}{tag}{suffix}"
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


def process_scratch(tag: str) -> tempfile.TemporaryDirectory:
    """A temporary directory of this process in the system's temporary folder (removed when
    the returned object is cleaned up), named ``orthomvp-TAG-PID-HOST-...``; those of ``tag``
    that runs on this machine left when they were killed (SIGKILL: no cleanup ran) are
    removed first (:func:`_remove_dead`)."""
    prefix = f"orthomvp-{tag}-"
    _remove_dead(Path(tempfile.gettempdir()), prefix)
    return tempfile.TemporaryDirectory(
        prefix=f"{prefix}{os.getpid()}-{_HOST}-", ignore_cleanup_errors=True
    )


def remove_stale(path: Path) -> list[Path]:
    """Remove the temporary files and directories of ``path`` (see :func:`temp_name`) that
    runs on this machine left when they were killed (SIGKILL, a power cut): those whose
    process is gone. Returns what was removed."""
    return _remove_dead(path.parent, f".{_name_part(path)}.{TEMP_TAG}-")


def _remove_dead(folder: Path, prefix: str) -> list[Path]:
    """Remove the files and directories in ``folder`` named ``PREFIX + PID-HOST-...`` of
    this machine whose process is gone; returns what was removed."""
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(prefix)]
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


def _remove(tmp: Path, dir_fd: int | None = None) -> None:
    """Remove a temporary file (with the .aux.xml sidecar GDAL may leave) or directory, if
    there: ``tmp``, or its name in the directory of file descriptor ``dir_fd``. A failure is
    not reported: the error that led here is the one to report (and on a read-only file system
    even removing what is not there fails)."""
    name = tmp.name if dir_fd is not None else os.fspath(tmp)
    with contextlib.suppress(OSError):
        if stat.S_ISDIR(os.stat(name, dir_fd=dir_fd, follow_symlinks=False).st_mode):
            _remove_tree(name, dir_fd)
    for each in (name, f"{name}.aux.xml"):
        with contextlib.suppress(OSError):
            os.unlink(each, dir_fd=dir_fd)


def _remove_tree(name: str, dir_fd: int | None) -> None:
    """Remove directory ``name`` (in the directory of ``dir_fd``) and everything in it, not
    following symbolic links (``shutil.rmtree`` takes ``dir_fd`` from Python 3.11 only)."""
    for _, dirs, files, fd in os.fwalk(name, topdown=False, dir_fd=dir_fd):
        for file in files:
            with contextlib.suppress(OSError):
                os.unlink(file, dir_fd=fd)
        for sub in dirs:  # (a symbolic link to a directory is listed here too)
            with contextlib.suppress(OSError):
                try:
                    os.rmdir(sub, dir_fd=fd)
                except NotADirectoryError:
                    os.unlink(sub, dir_fd=fd)
    os.rmdir(name, dir_fd=dir_fd)


@contextlib.contextmanager
def atomic_paths(paths: Sequence[str | Path], need: Sequence[int] = ()) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``paths``; rename them onto ``paths``, one after another,
    when the block succeeds; on any failure (SIGINT, SIGTERM and SIGHUP too) remove them all and
    touch no target.

    First the temporary files that killed runs left beside the targets are removed (see
    :func:`remove_stale`), and the free space is checked: at least one byte, and ``need``
    (bytes each output surely takes) in total per directory. A failure to create or rename
    raises an OutputError naming the target; the writes themselves are the block's (see
    :func:`~orthomvp.io.write_errors.writing`)."""
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
            written.extend(t for t in targets if not any(d in _pending for d in t.parents))
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
    naming ``path`` (see :func:`~orthomvp.io.write_errors.writing`; ``size``: bytes the output
    takes at most)."""
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


def _folder(path: Path) -> bool:
    """Whether ``path`` is a folder itself (not a link to one)."""
    return path.is_dir() and not path.is_symlink()


def _clashes(source: Path, target: Path) -> None:
    """OutputError naming the first item of ``source`` whose place in ``target`` holds a
    folder where the item is none, or the reverse (links count as files): found before
    anything moves, so that such a clash leaves ``target`` as it was."""
    for item in source.iterdir():
        there = target / item.name
        if not there.exists() and not there.is_symlink():
            continue
        if _folder(item) != _folder(there):
            what = "a folder" if _folder(there) else "not a folder"
            raise OutputError(f"{there}: cannot write it: it is {what} already; move it away")
        if _folder(item):
            _clashes(item, there)


def _move_into(
    source: Path, target: Path, replace: Sequence[str] = (), trash: Path | None = None
) -> None:
    """Move the items of directory ``source`` into directory ``target``: a file replaces the
    file of its name, a folder merges into the folder of its name (a rename cannot replace a
    folder that holds files) unless its name is in ``replace``, when the folder of ``target``
    is first moved into the new directory ``trash`` whole; what else ``target`` holds stays. A
    folder meeting a file, or the reverse, is refused before anything moves
    (:func:`_clashes`); only a failing rename (a full disk, no permission) can leave part of
    ``source`` moved (the folders moved to ``trash`` then go back)."""
    _clashes(source, target)
    for name in replace:
        if _folder(source / name) and _folder(target / name) and trash is not None:
            trash.mkdir(exist_ok=True)
            os.replace(target / name, trash / name)
    try:
        _merge(source, target)
    except BaseException:
        if trash is not None and trash.is_dir():  # the replaced folders go back as they were
            for old in trash.iterdir():
                if (target / old.name).exists():
                    shutil.rmtree(target / old.name, ignore_errors=True)
                os.replace(old, target / old.name)
        raise


def _merge(source: Path, target: Path) -> None:
    """:func:`_move_into` once its clashes are ruled out."""
    for item in source.iterdir():
        there = target / item.name
        if _folder(item) and _folder(there):
            _merge(item, there)
            item.rmdir()
        else:
            os.replace(item, there)


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, replace: Sequence[str] = ()) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; on success move its files into ``path``
    (its folders merge into those of their names there, but those named in ``replace``
    replace theirs whole: nothing of the old ones stays).

    On failure (SIGINT, SIGTERM and SIGHUP too) the temporary directory is removed and ``path`` is
    left as it was; errors name the files under ``path``, not under the temporary directory.
    Temporary directories of killed runs are removed first (see :func:`remove_stale`).
    """
    path = Path(os.path.abspath(path))  # ("." has no name to put a temporary beside)
    if not path.parent.exists():
        raise InputError(f"{path}: parent directory {path.parent} does not exist")
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a directory")
    check_space(path)
    tmp: Path | None = None
    trash: Path | None = None
    with HeldSignals() as held:
        try:
            remove_stale(path)
            tmp = _new_temp(path)
            tmp.mkdir()
            with held.released():
                yield tmp
            os.chmod(tmp, 0o777 & ~_umask())
            if path.exists():
                trash = _new_temp(path, "old") if replace else None
                _move_into(tmp, path, replace, trash)
            else:
                os.replace(tmp, path)
            written.append(path)
        except OutputError as exc:
            raise OutputError(str(exc).replace(str(tmp), str(path))) from exc.__cause__
        except OSError as exc:
            if tmp is None or not str(exc.filename or "").startswith(str(tmp)):
                raise
            raise write_error(path / Path(exc.filename).relative_to(tmp), exc) from exc
        finally:
            for temporary in (tmp, trash):
                if temporary is not None:
                    _drop(temporary)


atexit.register(remove_temporaries)
