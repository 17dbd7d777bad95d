"""CRS helpers: a DEM's CRS as pyproj or rasterio gives it, its horizontal part, its radii.

A file's CRS is kept as rasterio reads it (GDAL) where that is enough, because pyproj's import
takes about 45 ms; pyproj is imported only where a transformation, a compound CRS or a CRS the
user gives needs it.
"""

from __future__ import annotations

import functools
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from affine import Affine
from rasterio.crs import CRS as FileCRS

from orthomvp.errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS, Transformer


def horizontal_crs(crs: CRS | FileCRS, source: str = "CRS") -> CRS | FileCRS:
    """The horizontal part of a (possibly compound) CRS: a pyproj CRS's own, a file's (not
    compound: itself) through pyproj."""
    if is_pyproj(crs):
        return crs.sub_crs_list[0] if crs.is_compound else crs
    if crs.to_wkt().startswith(("COMPD_CS", "COMPOUNDCRS")):
        return parse_crs(crs.to_wkt(), source)
    return crs


def parse_crs(value: object, source: str) -> CRS:
    """A pyproj CRS from anything pyproj accepts (WKT, PROJ string, 'IAU_2015:30100', ...)."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return horizontal_crs(CRS.from_user_input(value))
    except CRSError as exc:
        raise InputError(f"{source}: cannot understand CRS {value!r} ({exc})") from exc


def as_crs(value: object, source: str) -> CRS | FileCRS:
    """The horizontal part of a CRS object (pyproj's, or a file's as rasterio reads it, kept
    so), or the pyproj CRS of anything else pyproj reads (:func:`parse_crs`)."""
    if isinstance(value, FileCRS) or is_pyproj(value):
        return horizontal_crs(value, source)
    return parse_crs(value, source)


def is_pyproj(crs: object) -> bool:
    """Whether ``crs`` is a pyproj CRS (never, while pyproj is not imported)."""
    pyproj = sys.modules.get("pyproj")
    return pyproj is not None and isinstance(crs, pyproj.CRS)


def as_pyproj(crs: CRS | FileCRS) -> CRS:
    """``crs`` as a pyproj CRS: itself, or a file's read from its WKT (as :func:`parse_crs`
    reads it)."""
    return crs if is_pyproj(crs) else parse_crs(crs.to_wkt(), "CRS")


_SPHEROID = re.compile(r'SPHEROID\["[^"]*",\s*([^,\]]+),\s*([^,\]]+)')


def file_radii(crs: FileCRS) -> tuple[float, float] | None:
    """(semi-major, semi-minor) axes of a file CRS's ellipsoid from its WKT 1 (metres; the
    semi-minor as PROJ computes it from the inverse flattening, 0 for a sphere); None when the
    WKT does not say them plainly."""
    found = _SPHEROID.search(crs.to_wkt())
    if found is None:
        return None
    try:
        a, rf = float(found[1]), float(found[2])
    except ValueError:
        return None
    return a, (a if rf == 0 else (1.0 - 1.0 / rf) * a)


def dem_georeference(
    path: str | Path,
    file_crs: FileCRS | None,
    transform: Affine,
    crs: object | None,
    *,
    shape: tuple[int, int] | None = None,
) -> CRS | FileCRS:
    """The CRS of the DEM at ``path``: ``crs`` when given (a pyproj CRS, :func:`parse_crs`),
    else the file's (rasterio's, read by GDAL: see :class:`Terrain`); InputError for a DEM
    without CRS or without georeference (identity ``transform``), or (given its ``shape``,
    rows and columns) a geographic DEM whose posts lie past latitude 90 degrees."""
    if crs is not None:
        the_crs = parse_crs(crs, str(path))
    elif file_crs is None:
        raise InputError(f"{path}: the DEM has no CRS; give one with --dem-crs")
    else:
        the_crs = horizontal_crs(file_crs, str(path))
    if transform == Affine.identity():
        raise InputError(f"{path}: the DEM has no georeference (identity transform)")
    if shape is not None and the_crs.is_geographic:
        rows, cols = shape
        corners = [transform @ (c + 0.5, r + 0.5) for r in (0, rows - 1) for c in (0, cols - 1)]
        lat = max((y for _, y in corners), key=abs)
        if not abs(lat) <= 90:
            raise InputError(
                f"{path}: the DEM's posts reach latitude {lat:.6g} degrees, past the pole: "
                "is its georeferencing (or its CRS's axis order) right?"
            )
    return the_crs


@functools.lru_cache(maxsize=32)
def lonlat_transformer(crs: CRS | FileCRS) -> Transformer:
    """Map coordinates of ``crs`` to (lon, lat) degrees on its body: made once a process
    for every Terrain on it (the engine makes several a tile; pyproj's transformers are
    thread-safe)."""
    from pyproj import Transformer

    pyproj_crs = as_pyproj(crs)
    return cheap_per_thread(
        Transformer.from_crs(pyproj_crs, pyproj_crs.geodetic_crs, always_xy=True)
    )


@functools.lru_cache(maxsize=32)
def geocentric_transformer(crs: CRS | FileCRS, radii: tuple[float, float]) -> Transformer:
    """(lon, lat) degrees and height on the body of ``crs`` (whose ellipsoid has ``radii``,
    metres) to body-fixed metres, made once a process (as :func:`lonlat_transformer`)."""
    from pyproj import CRS, Transformer

    a, b = radii
    geocent = CRS.from_proj4(f"+proj=geocent +a={a!r} +b={b!r} +units=m +no_defs")
    pyproj_crs = as_pyproj(crs)
    geodetic = pyproj_crs if pyproj_crs.is_geographic else pyproj_crs.geodetic_crs
    return cheap_per_thread(Transformer.from_crs(geodetic.to_3d(), geocent, always_xy=True))


def cheap_per_thread(transformer: Transformer) -> Transformer:
    """``transformer`` made again from its operation's PROJ string, when it has one operation
    that a PROJ string gives (else ``transformer`` itself): the same operation and numbers.

    pyproj keeps one PROJ object per thread and makes it again in every new thread, and after
    unpickling, from what the transformer was made of. From two CRSs that searches PROJ's
    database: 30-70 ms for a geocentric transformer, in every worker thread of every run. From
    a PROJ string it takes 0.2 ms."""
    from pyproj import Transformer
    from pyproj.exceptions import ProjError

    try:
        return Transformer.from_pipeline(transformer.definition)
    except ProjError:  # several candidates chosen point by point, or no PROJ string
        return transformer
