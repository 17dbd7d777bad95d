"""Cameras whose file states their world CRS (an Orthority exterior file: the ``.prj`` beside
a CSV file, a GeoJSON file's ``world_crs``) against the DEM's CRS. orthomvp takes cameras in
the DEM's frame; a camera file in another CRS is refused in one line that names both CRSs and
how to reproject the DEM, before the world-frame test would only say that the cameras fit
neither frame."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from orthomvp.camera import sensor_positions
from orthomvp.camera.formats.orthority import stated_crs
from orthomvp.errors import InputError
from orthomvp.geometry.crs import as_pyproj, horizontal_crs, parse_crs

if TYPE_CHECKING:
    from rasterio.crs import CRS as FileCRS

    from orthomvp.engine.images import ImageSource

AGREE = 1.0
"""Metres within which a camera's position must be the same in its file's CRS and in the
DEM's horizontal CRS."""


def check_stated_crs(sources: Sequence[ImageSource], dem_crs: FileCRS, dem: str) -> None:
    """InputError when a camera file of ``sources`` states a world CRS in which its first
    camera's horizontal position lies more than :data:`AGREE` metres from where the same
    numbers lie in the CRS ``dem_crs`` of the DEM ``dem`` (its horizontal part); files that
    state none, and cameras given as objects, are not checked."""
    stated, seen = [], set()
    for view in sources:
        file = view.camera_file
        if file is not None and file not in seen:
            seen.add(file)
            if (text := stated_crs(file)) is not None:
                stated.append((view, file, text))
    stated = [item for item in stated if not _same(item[2], dem_crs)]
    if not stated:
        return  # (pyproj not imported, 80 ms with its imports: a map-frame run needs it not)
    from pyproj import Transformer
    from pyproj.exceptions import ProjError

    dem_horizontal = horizontal_crs(as_pyproj(dem_crs))
    for view, file, text in stated:
        where = file.with_suffix(".prj").name if file.suffix.lower() == ".csv" else "world_crs"
        theirs = parse_crs(text, f"{file} ({where})")
        x, y, _ = sensor_positions(view.camera)[0]
        try:
            to_dem = Transformer.from_crs(theirs, dem_horizontal, always_xy=True)
            dx, dy = to_dem.transform(x, y, errcheck=True)
        except ProjError:
            dx = dy = np.nan
        apart = float(np.hypot(dx - x, dy - y))
        if apart <= AGREE:
            continue
        how = f"{apart:,.0f} m apart" if np.isfinite(apart) else "beyond the DEM's CRS"
        target = file.with_suffix(".prj") if where != "world_crs" else _short(theirs)
        raise InputError(
            f"{file}: its cameras are in {_name(theirs)} (its {where}), the DEM {dem} is in "
            f"{_name(dem_horizontal)}, and the position of {view.path.name}'s camera lies "
            f"{how} in the two: cameras are taken in the DEM's CRS; reproject the DEM into "
            f"theirs (gdalwarp -t_srs {target} DEM NEW_DEM.tif) and give that one"
        )


def _same(text: str, dem_crs: FileCRS) -> bool:
    """Whether GDAL takes the CRS ``text`` for ``dem_crs`` itself (names aside), so that no
    position need be compared; False where it cannot tell (then pyproj decides)."""
    from rasterio.crs import CRS as FileCRS
    from rasterio.errors import CRSError

    try:
        return bool(FileCRS.from_user_input(text) == dem_crs)
    except (CRSError, TypeError, ValueError):
        return False


def _name(crs: object) -> str:
    """A CRS's name, quoted, or where it has none its :func:`_short` form."""
    return _short(crs) if crs.name in ("", "unknown", "unnamed") else repr(crs.name)


def _short(crs: object) -> str:
    """A CRS as a ``-t_srs`` argument: its authority code, else its PROJ string, quoted."""
    code = crs.to_authority()
    if code:
        return ":".join(code)
    return f'"{crs.to_proj4()}"'
