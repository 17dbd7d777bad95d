"""The orthomvp exception family.

Every error that a user can cause (bad files, bad arguments, impossible geometry) raises a
subclass of :class:`OrthoMVPError`; the CLI prints its message as one line and exits with 2.
"""

from __future__ import annotations

from pathlib import Path


class OrthoMVPError(Exception):
    """Base class of all errors orthomvp reports to users."""


class InputError(OrthoMVPError):
    """A file or argument that cannot be used (missing, corrupt, inconsistent)."""


class FormatError(InputError):
    """A file whose contents do not follow its format; names the file and, when known, the line."""

    def __init__(self, path: str | Path, message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class GeometryError(OrthoMVPError):
    """Geometry that cannot work: a camera behind the surface, no overlap between DEM and image."""
