"""The orthomvp exception family.

Every error that a user can cause (bad files, bad arguments, impossible geometry, outputs that
cannot be written) raises a subclass of :class:`OrthoMVPError`; the CLI prints its message as
one line and exits with 2. Each class is also a subclass of the matching built-in, as
rasterio's are, so that code catching ``ValueError`` or ``OSError`` keeps working:

- :class:`InputError` (``ValueError``): a file or argument that cannot be used: missing,
  corrupt, of the wrong type or shape, out of range;
- :class:`FormatError` (an ``InputError``): a file that breaks its format;
- :class:`GeometryError` (``ValueError``): geometry that cannot work;
- :class:`OutputError` (``OSError``): an output that cannot be written.
"""

from __future__ import annotations

from pathlib import Path


class OrthoMVPError(Exception):
    """Base class of all errors orthomvp reports to users."""


class InputError(OrthoMVPError, ValueError):
    """A file or argument that cannot be used (missing, corrupt, inconsistent, of the wrong
    type, shape or range)."""


class FormatError(InputError):
    """A file whose contents do not follow its format; names the file and, when known, the line."""

    def __init__(self, path: str | Path, message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        self.reason = message
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")

    def __reduce__(self) -> tuple[type, tuple[str, str, int | None]]:
        """Pickle by the constructor's arguments (errors cross process boundaries in the
        engine's worker pools)."""
        return type(self), (self.path, self.reason, self.line)


class GeometryError(OrthoMVPError, ValueError):
    """Geometry that cannot work: a camera behind the surface, no overlap between DEM and image."""


class OutputError(OrthoMVPError, OSError):
    """An output whose writing fails (no space, no permission, a folder gone while writing);
    the message names the path and the cause. An output refused before anything is written
    (it exists, its folder does not) is an :class:`InputError`."""


class OrthoMVPWarning(UserWarning):
    """Something a user should know that does not stop the work (infinite DEM heights taken
    as nodata, an image that covers only part of the DEM); the CLI prints it as one line."""


class LeftOutWarning(OrthoMVPWarning):
    """Some of a mosaic's or a fit's images see no post of the grid: they are left out, named
    in one warning (they keep their numbers: a left-out image's never appears in the source
    raster)."""
