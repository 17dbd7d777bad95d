"""Colours of rasters on a DEM grid, shared by mesh export and 3D snapshots.

Three kinds of raster are coloured (:data:`COLOUR_KINDS`):

- ``"image"``: grey (1 band) or RGB (the first 3 of 3 or more bands). uint8 is taken as it is;
  other data is stretched between its 1st and 99th percentiles.
- ``"visibility"``: one band of :class:`orthomvp.codes.Code` values (NaN counts as no data), in
  the fixed colours :data:`orthomvp.codes.CODE_RGB` (occluded green, facing away orange).
- ``"error"``: one band of height errors in metres, on the diverging colour map
  :data:`ERROR_CMAP` from ``-limit`` (blue) through 0 (white) to ``+limit`` (red), clipped.

Posts without a value (NaN) are :data:`NAN_RGB` in every kind. Rasters are (rows, cols),
(rows, cols, bands) or band-first (bands, rows, cols), as :func:`orthomvp.io.raster.read_image`
reads them; colours are RGB uint8.

This module and :mod:`orthomvp.codes` are the one palette of the maps, snapshots, meshes and
pages: one colour per meaning (light grey visible, green occluded, orange facing away, violet no
data or no value, red too high and blue too low), cameras in colours apart from those, and
heights on their own sequential scale (:data:`HEIGHT_CMAP`) with a colour bar in metres.
"""

from __future__ import annotations

import numpy as np

from orthomvp.codes import CODE_RGB, Code
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.validate import number

COLOUR_KINDS = ("image", "visibility", "error")
ERROR_CMAP = "RdBu_r"
"""Matplotlib colour map of height errors: negative (too low) blue, zero white, positive (too
high) red."""
HEIGHT_CMAP = "cividis"
"""Matplotlib colour map of heights (elevation) in maps: low dark blue-grey to high yellow."""
NAN_RGB = Code.NODATA.rgb
"""RGB uint8 of posts without a value (an empty orthophoto post, an unknown height error),
violet: the colour of the no-data code (no grey, which images and relief use)."""
CAMERA_COLOURS = ("#ffd21f", "#ff4fd8", "#4fc3ff", "#ffffff")
"""Colours of cameras in 3D snapshots (frusta, labels, rays and their hits), in turn: none of
them green (occluded), orange (facing away), violet (no data) or red (too high)."""


def raster_bands(data: np.ndarray, shape: tuple[int, int], name: str = "raster") -> np.ndarray:
    """``data`` as band-first (bands, rows, cols), its dtype kept, from (rows, cols),
    (rows, cols, bands) or (bands, rows, cols); InputError (naming the ``name`` raster) unless it
    is on the DEM grid of ``shape`` (rows, cols)."""
    arr = np.asarray(data)
    if arr.ndim == 2:
        arr = arr[None]
    elif arr.ndim == 3 and arr.shape[:2] == shape and arr.shape[1:] != shape:
        arr = np.moveaxis(arr, -1, 0)
    if arr.ndim != 3 or arr.shape[1:] != shape:
        if arr.ndim < 2:
            got = f"of shape {arr.shape}"
        else:
            size = arr.shape[1:] if arr.ndim == 3 and arr.shape[0] < 5 else arr.shape[:2]
            got = f"{size[1]} x {size[0]}"
        raise InputError(
            f"the {name} is {got} but the DEM grid is {shape[1]} x {shape[0]} "
            "(columns x rows): give a raster on the DEM grid"
        )
    return arr


def one_band(data: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    """The single band (rows, cols) of a raster on the DEM grid (see :func:`raster_bands`)."""
    bands = raster_bands(data, shape, name)
    if len(bands) != 1:
        raise InputError(f"the {name} must have one band, this one has {len(bands)}")
    return bands[0]


def visibility_codes(data: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Visibility codes (rows, cols) uint8 from a one-band raster on the DEM grid (NaN -> 0);
    InputError for any value that is not a code."""
    band = one_band(data, shape, "visibility raster")
    band = np.where(np.isfinite(band), band, Code.NODATA)
    if not np.isin(band, list(Code)).all():
        raise InputError(
            "the visibility raster holds values other than the codes 0 (outside), 1 (visible), "
            "2 (occluded) and 3 (facing away)"
        )
    return band.astype(np.uint8)


def image_colours(
    bands: np.ndarray, name: str = "image", *, stretch: tuple[float, float] | None = None
) -> np.ndarray:
    """Per-post RGB (rows * cols, 3) uint8 of a band-first image (bands, rows, cols): grey from
    1 band, RGB from the first 3 of 3 or more. uint8 is taken as it is; other data is stretched
    linearly from ``stretch`` (low, high; default its 1st and 99th percentile over the posts
    where every used band is finite) to 0 and 255, clipped; the other posts are
    :data:`NAN_RGB`."""
    if len(bands) == 2:
        raise InputError(f"the {name} must have 1 band (grey) or 3 or more (RGB), not 2")
    rgb = np.moveaxis(bands[:3], 0, -1).reshape(-1, min(len(bands), 3))
    if rgb.dtype == np.uint8:
        return np.broadcast_to(rgb, (len(rgb), 3)).copy()
    rgb = rgb.astype(np.float64)
    filled = np.isfinite(rgb).all(axis=1)
    if stretch is None:
        if not filled.any():
            raise InputError(f"the {name} holds no valid values")
        stretch = np.percentile(rgb[filled], [1, 99])
    lo, hi = stretch
    scaled = np.clip((rgb - lo) / max(hi - lo, 1e-12), 0, 1) * 255
    out = np.broadcast_to(np.where(filled[:, None], scaled, 0), (len(rgb), 3)).astype(np.uint8)
    out[~filled] = NAN_RGB
    return out


def check_error_limit(limit: float | None) -> float | None:
    """``limit`` (metres, or None for automatic), InputError unless a finite number > 0."""
    if limit is None:
        return None
    return number(limit, "the error colour limit (metres)", minimum=0, min_open=True)


def error_colour_limit(error: np.ndarray, limit: float | None = None) -> float:
    """The half-range in metres of the error colour scale: ``limit`` when given (it must be
    positive), else the 99th percentile of ``|error|`` over its finite values (at least 1 mm)."""
    if check_error_limit(limit) is not None:
        return float(limit)
    err = np.abs(np.asarray(error, dtype=np.float64))
    finite = np.isfinite(err)
    if not finite.any():
        raise InputError("the error raster holds no valid values")
    return max(float(np.percentile(err[finite], 99)), 1e-3)


def error_colours(error: np.ndarray, limit: float | None = None) -> np.ndarray:
    """RGB (n, 3) uint8 of the height errors ``error`` (metres, any shape, flattened) on
    :data:`ERROR_CMAP` between -+ :func:`error_colour_limit`, clipped; NaN is :data:`NAN_RGB`."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    err = np.asarray(error, dtype=np.float64).ravel()
    lim = error_colour_limit(err, limit)
    rgb = colormaps[ERROR_CMAP](Normalize(-lim, lim, clip=True)(err), bytes=True)[:, :3]
    rgb[~np.isfinite(err)] = NAN_RGB
    return rgb


def post_colours(
    data: np.ndarray, shape: tuple[int, int], kind: str = "image", limit: float | None = None
) -> np.ndarray:
    """Per-post RGB (rows * cols, 3) uint8 of a raster on the DEM grid of ``shape``, coloured as
    ``kind`` (one of :data:`COLOUR_KINDS`) says; ``limit`` is the error colour limit."""
    if kind not in COLOUR_KINDS:
        raise InputError(f"colour kind must be one of {', '.join(COLOUR_KINDS)}, not {kind!r}")
    if kind == "visibility":
        return CODE_RGB[visibility_codes(data, shape).ravel()]
    if kind == "error":
        return error_colours(one_band(data, shape, "error raster"), limit)
    return image_colours(raster_bands(data, shape, "texture raster"), "texture raster")


def height_error(terrain: Terrain, truth: Terrain) -> np.ndarray:
    """``terrain - truth`` (rows, cols) in the DEMs' value units (metres), NaN where either has
    a hole; the two must share one grid (shape, georeference and CRS)."""
    same = (
        terrain.shape == truth.shape
        and terrain.transform.almost_equals(truth.transform)
        and terrain.crs == truth.crs
    )
    if not same:
        rows, cols = truth.shape
        raise InputError(
            f"{truth.name}: the truth DEM ({cols} x {rows} posts) is not on the grid of "
            f"{terrain.name} ({terrain.shape[1]} x {terrain.shape[0]} posts, same georeference "
            "and CRS needed): resample it onto the DEM grid first"
        )
    return terrain.values - truth.values
