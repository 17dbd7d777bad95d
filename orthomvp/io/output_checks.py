"""The rules every output of a command or an engine run follows, checked before any work, one
implementation for the command line (:func:`orthomvp.cli.options.check_outputs`, which names the
options ``-o``, ``--overwrite``) and the Python API (:class:`orthomvp.engine.Outputs`, which
names the arguments ``ortho``, ``overwrite=True``): two outputs never share a file, an output
never replaces an input unless told twice, an existing file is replaced only when told, and the
file name's extension matches the format written."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from orthomvp.errors import InputError

GEOTIFF = (".tif", ".tiff")
"""File name extensions of the GeoTIFF outputs."""


@dataclass(frozen=True)
class Output:
    """An output file, for :func:`check_outputs`: the ``option`` that names it (``-o``,
    ``--visibility``; ``ortho`` in the API), its ``path`` (None when not asked for), the
    ``suffixes`` its format allows (lower case; empty: any) and the format's ``name`` for
    messages."""

    option: str
    path: Path | None
    suffixes: tuple[str, ...] = GEOTIFF
    name: str = "a GeoTIFF"


@dataclass(frozen=True)
class Flags:
    """How messages name the two permissions: the command line's options, or the API's
    arguments (:data:`API_FLAGS`)."""

    overwrite: str = "--overwrite"
    replace_input: str = "--overwrite --replace-input"


API_FLAGS = Flags("overwrite=True", "overwrite=True and replace_input=True")
"""The permissions as the engine's output classes name them."""


def check_names(outputs: Sequence[Output]) -> None:
    """InputError naming the path for two outputs with the same path (also through links or
    ``..``), an output that is a directory, or one whose extension does not match its
    format."""
    given = [out for out in outputs if out.path is not None]
    for i, out in enumerate(given):
        for other in given[:i]:
            if same_file(out.path, other.path):  # type: ignore[arg-type]
                alias = f" (as {out.path})" if str(out.path) != str(other.path) else ""
                raise InputError(
                    f"{other.path}: given to both {other.option} and {out.option}{alias}; one "
                    "would overwrite the other: give each output its own file"
                )
    for out in given:
        path = Path(out.path)  # type: ignore[arg-type]
        if path.is_dir():
            raise InputError(f"{path}: {out.option} names a directory; give a file name")
        if out.suffixes and path.suffix.lower() not in out.suffixes:
            raise InputError(
                f"{path}: {out.option} writes {out.name}; name it "
                f"{' or '.join(out.suffixes)}" + (f", not {path.suffix}" if path.suffix else "")
            )


def check_outputs(
    outputs: Sequence[Output],
    inputs: Sequence[tuple[str, Path | str | None]] = (),
    overwrite: bool = False,
    replace_input: bool = False,
    flags: Flags = Flags(),
) -> None:
    """Refuse, before any work, outputs that cannot end well, with an InputError naming the
    path (:func:`check_names`, then): an output that is one of the ``inputs`` ((label, path)
    pairs, e.g. ("DEM", dem.path)) unless both ``overwrite`` and ``replace_input``; an output
    file that exists, unless ``overwrite`` (as rio and gdalwarp); an output whose directory
    is missing, not a directory or not writable (OutputError
    when its disk is full). ``flags`` names the permissions in the messages."""
    check_names(outputs)
    given = [out for out in outputs if out.path is not None]
    for out in given:
        for label, path in inputs:
            if path is not None and same_file(out.path, path) and not (overwrite and replace_input):  # type: ignore[arg-type]
                alias = f" ({path})" if str(out.path) != str(path) else ""
                raise InputError(
                    f"{out.path}: {out.option} would replace the input {label}{alias}; give "
                    f"another file name, or {flags.replace_input} to replace it"
                )
    for out in given:
        path = Path(out.path)  # type: ignore[arg-type]
        if not overwrite and os.path.lexists(path):
            raise InputError(
                f"{path}: the output file of {out.option} exists; give {flags.overwrite} to "
                "replace it"
            )
        check_directory(path, f"{path}: {out.option}")


def holds(folder: Path, names: Sequence[str]) -> bool:
    """Whether ``folder`` holds every file of ``names`` (paths relative to it): the marks by
    which a command knows its own earlier output."""
    return all((folder / name).is_file() for name in names)


def check_folder(
    path: Path,
    what: str,
    *,
    overwrite: bool = False,
    refresh: Sequence[str] = (),
    flags: Flags = API_FLAGS,
) -> None:
    """InputError for an output folder ``path`` that is a file, whose directory is missing or
    not writable, or that holds files, unless ``overwrite`` or unless it holds every file named
    in ``refresh`` (paths relative to it: the marks of the command's own earlier output, which
    it may refresh); ``what`` names the folder in the message (``"--export"``)."""
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: {what} is a file, not a directory")
    if path.is_dir() and not overwrite and any(path.iterdir()):
        if not (refresh and holds(path, refresh)):
            raise InputError(
                f"{path}: {what} exists and is not empty; give {flags.overwrite} to write "
                "into it (files of the same name are replaced)"
            )
    check_directory(path, f"{path}: {what}")


def check_parent(path: Path, what: str) -> None:
    """InputError ``"{what}: the directory ... does not exist"`` (or is not a directory) for
    the directory of the output ``path``."""
    directory = path.parent
    if not directory.is_dir():
        problem = "is not a directory" if directory.exists() else "does not exist"
        raise InputError(f"{what}: the directory {directory} {problem}")


def check_directory(path: Path, what: str) -> None:
    """InputError ``"{what} ..."`` unless the directory of the output ``path`` exists and is
    writable; an OutputError naming ``path`` when its disk has no space left."""
    check_parent(path, what)
    directory = path.parent
    if not os.access(directory, os.W_OK | os.X_OK):
        read_only = os.statvfs(directory).f_flag & os.ST_RDONLY
        cause = "a read-only file system" if read_only else "permission denied"
        raise InputError(f"{what}: cannot write in the directory {directory} ({cause})")
    from orthomvp.io.preflight import check_space

    check_space(path)


def same_file(a: Path | str, b: Path | str) -> bool:
    """Whether paths ``a`` and ``b`` name the same file: the same path once resolved
    (symbolic links, ``..``), or, when both exist, the same inode (hard links)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False
