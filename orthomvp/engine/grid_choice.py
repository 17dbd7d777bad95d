"""What a plan runs on: the DEM and views read for the engine (:func:`read_source`), and the
output grid (:func:`choose_grid`): by default from the cameras (the part of the DEM the images
see, at the images' own ground sample distance), or the DEM's own; checked for size before
any tile is planned (:func:`check_grid_size`).

The camera grid (``grid="camera"``):

- extent: the union of the images' footprints (:func:`orthomvp.engine.footprint.image_footprint`:
  every DEM post whose projection falls on an image, hidden or not), as the outer edges of
  those posts, snapped outward to the lattice of ``res`` from the DEM's top-left corner, so
  that grids at one resolution line up with each other and, at the DEM's post spacing, with the
  DEM's posts (in another output CRS the extent is transformed, not snapped);
- resolution: the median ground sample distance over the footprints (metres per pixel on the
  horizontal plane, every view's samples pooled), rounded to the nearest clean value, 1, 2,
  2.5 or 5 times a power of ten metres (:func:`orthomvp.engine.units.clean_metres`), then
  converted to the CRS's units (:mod:`orthomvp.engine.units`: on a geographic CRS, degrees
  by the body's equatorial radius), square: a warning where its posts crowd east-west).

``res`` and ``bounds`` given replace the camera's choice of each: ``res`` alone keeps the
footprint's extent (snapped to the lattice of that ``res``), ``bounds`` alone keeps the
images' resolution. When no image sees the DEM, the DEM's grid is used (and the plan then
says why nothing is seen).
"""

from __future__ import annotations

import math
import shutil
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from orthomvp.camera import camera_centres, in_world, sensor_positions
from orthomvp.camera.rpc import in_vertical_datum
from orthomvp.codes import WorldFrame
from orthomvp.engine.footprint import Footprint, image_footprints, union_window, window_bounds
from orthomvp.engine.grid import (
    DemSource,
    OutputGrid,
    grid_to_dem,
    output_grid,
    same_body,
    scan_dem,
)
from orthomvp.engine.grid import with_world as dem_with_world
from orthomvp.engine.halo import Box
from orthomvp.engine.images import ImageSource
from orthomvp.engine.progress import Progress
from orthomvp.engine.stated_crs import check_stated_crs
from orthomvp.engine.units import (
    check_latitudes,
    check_res,
    clean_metres,
    east_west_text,
    parse_res,
    to_units,
    unit_scale,
)
from orthomvp.errors import GeometryError, InputError, LeftOutWarning, OrthoMVPWarning
from orthomvp.geometry.crs import as_crs, as_pyproj
from orthomvp.geometry.datum import HeightOptions
from orthomvp.geometry.vectors import nan_median
from orthomvp.geometry.world import check_camera_bodies, check_cameras_above, detect_world
from orthomvp.io.preflight import count_text, size_text

GRIDS = ("camera", "dem")
"""The output grids a plan can choose by default: the cameras' footprint, or the DEM's own."""

GDAL_MAX_SIDE = 2**31 - 1
"""Posts a side of the largest raster GDAL can create."""

POSTS_PER_PIXEL = 10_000
"""Posts of output grid per pixel of the images (all together) above which a grid other than
the DEM's own is refused before planning: 100 times finer than the images in each direction,
a resolution in the wrong units rather than a wish."""

COMPRESSION = 10
"""The compression ratio granted to a compressed output when checking free space before
planning: a grid whose outputs would not fit even at this ratio is refused."""


MAX_TILES = 250_000
"""Tiles of a plan above which its grid is refused before planning (a grid of 16 x 16 thousand
tiles of 1,024 posts, 2.7e11 posts: a terabyte a band as float32)."""


class HaloWarning(UserWarning):
    """A camera whose lines of sight are so low that each tile needs most of the DEM."""


def world_frame(world: WorldFrame | str) -> WorldFrame | None:
    """The world frame asked for, None for "auto"."""
    if world == "auto":
        return None
    try:
        return WorldFrame(world)
    except ValueError:
        names = ", ".join(["auto", *(w.value for w in WorldFrame)])
        raise InputError(f"world frame must be one of {names}, not {world!r}") from None


def read_source(
    dem: str | Path,
    sources: Sequence[ImageSource],
    dem_crs: object | None,
    radius_values: bool,
    world: WorldFrame | str,
    progress: bool,
    heights: HeightOptions | None = None,
) -> tuple[DemSource, tuple[ImageSource, ...]]:
    """The DEM scanned once in blocks, in the world frame ``world`` asks for ("auto": the one
    its cameras fit, :func:`~orthomvp.geometry.world.detect_world`), its heights shifted to what
    that frame's cameras need as ``heights`` says (:mod:`orthomvp.geometry.datum`), with every
    camera above it; and the views with their cameras in that frame
    (:func:`~orthomvp.camera.in_world`); an RPC camera among map-frame cameras on a DEM with a
    vertical datum takes the DEM's compound CRS (:func:`~orthomvp.camera.rpc.in_vertical_datum`:
    PROJ converts its heights with the geoid's grid, or it is refused naming the grid)."""
    frame = world_frame(world)
    centres, views = camera_centres([v.camera for v in sources])
    with Progress("reading the DEM's heights", progress, unit="row") as bar:
        source = scan_dem(dem, dem_crs, radius_values, progress=bar, heights=heights)
    check_camera_bodies(source.preview, [v.camera for v in sources])
    if frame != WorldFrame.BODY:  # cameras in a map frame: their file's CRS, if it names one
        check_stated_crs(sources, source.crs, source.preview.name)
    if frame is None:
        frame = detect_world(source.preview, centres, views)
    preview = replace(source.preview, world=frame)  # the heights as read tell "above" enough
    preview.check_convention()  # heights against radii, before the cameras are judged by them
    sources = tuple(replace(v, camera=in_world(v.camera, preview)) for v in sources)
    # (of several images, those that look at another part of the body are left out below)
    centres, views = camera_centres([v.camera for v in sources])
    check_cameras_above(preview, centres, views, spare=len(sources) > 1)
    source = dem_with_world(source, frame)
    as_read = source.heights == HeightOptions()  # auto, no offset: the map frame's rule
    named = [(str(v.path), v.camera) for v in sources]
    cameras = in_vertical_datum(named, frame, source.file_crs, as_read)
    sources = tuple(replace(v, camera=c) for v, c in zip(sources, cameras, strict=True))
    return source, sources


def grid_spacing(grid: OutputGrid, dem: DemSource) -> float:
    """Metres between neighbouring output posts at the grid centre (mean of both directions)
    at the DEM's median height, as :meth:`Terrain.post_spacing` gives for a regridded DEM."""
    return float(np.mean(dem.ground_spacing(grid_to_dem(grid, dem), grid.shape)))


def dem_extent_metres(dem: DemSource, radius: float) -> float:
    """The DEM's longer side on the ground, metres (nominal, see :mod:`orthomvp.engine.units`)."""
    per_unit, _ = unit_scale(dem.crs, radius)
    rows, cols = dem.shape
    return max(cols * abs(dem.transform.a), rows * abs(dem.transform.e)) * per_unit


def choose_grid(
    dem: DemSource,
    sources: Sequence[ImageSource],
    *,
    grid: str = "camera",
    res: object = None,
    bounds: tuple[float, float, float, float] | None = None,
    crs: object | None = None,
    footprints: Sequence[Footprint] | None = None,
) -> OutputGrid:
    """The output grid (see the module docstring): ``grid`` "camera" or "dem" chooses what
    ``res`` (one value or (x, y), each a number in the output CRS's units or a length with
    its unit, :func:`orthomvp.engine.units.parse_length`) and ``bounds`` (left, bottom,
    right, top in the output CRS's units) leave open; ``crs`` the output CRS (default the
    DEM's). ``footprints`` of the ``sources``, when already computed. InputError for a
    resolution absurd for the CRS (:func:`orthomvp.engine.units.check_res`)."""
    if grid not in GRIDS:
        raise InputError(f"grid must be one of {', '.join(GRIDS)}, not {grid!r}")
    lengths = parse_res(res)
    radius = dem.preview.radii[0]
    out_crs = dem.crs if crs is None else as_crs(crs, "output CRS")
    if bounds is not None:  # (the user's: a grid grown to its lattice may pass a pole)
        check_latitudes(tuple(float(v) for v in bounds), out_crs)
    units = None
    if lengths is not None:
        units, metres = to_units(lengths, out_crs, radius)
        check_res(lengths, metres, out_crs, radius, dem_extent_metres(dem, radius))
    # a spacing given in metres, whose posts may crowd east-west on a geographic CRS
    in_metres = lengths is not None and any(length.unit == "m" for length in lengths)
    if grid == "dem" or (units is not None and bounds is not None):
        return _checked(output_grid(dem, units, bounds, crs), radius, in_metres)
    if footprints is None:
        footprints = image_footprints(dem, sources)
    windows = [f.window for f in footprints if f.window is not None]
    if not windows:
        return _checked(output_grid(dem, units, bounds, crs), radius, in_metres)
    if units is None:
        gsd = np.concatenate([f.gsd for f in footprints])
        per_unit, _ = unit_scale(out_crs, radius)
        side = clean_metres(float(nan_median(gsd))) / per_unit
        units = (side, side)
    if bounds is None:
        bounds = window_bounds(dem, union_window(windows))
        if out_crs == dem.crs:
            bounds = _snap(bounds, dem, units)
        else:
            from pyproj import Transformer

            same_body(dem, out_crs)  # (else PROJ's own error, as an internal one)
            to_out = Transformer.from_crs(as_pyproj(dem.crs), as_pyproj(out_crs), always_xy=True)
            bounds = to_out.transform_bounds(*bounds, densify_pts=21)
    # (the images' spacing is in metres too)
    return _checked(output_grid(dem, units, bounds, crs), radius, in_metres or lengths is None)


def _checked(out: OutputGrid, radius: float, from_metres: bool) -> OutputGrid:
    """``out``, with a warning (:func:`~orthomvp.engine.units.east_west_text`) where its
    spacing came ``from_metres`` on a geographic CRS and its posts crowd east-west."""
    if from_metres and out.crs.is_geographic:
        T = out.transform
        text = east_west_text((abs(T.a), abs(T.e)), T.f + T.e * out.shape[0] / 2, out.crs, radius)
        if text:
            warnings.warn(text, OrthoMVPWarning, stacklevel=4)
    return out


def _snap(
    bounds: tuple[float, float, float, float], dem: DemSource, res: tuple[float, float]
) -> tuple[float, float, float, float]:
    """``bounds`` grown outward to the lattice of ``res`` from the DEM's top-left corner."""
    left, bottom, right, top = bounds
    x0, y0 = dem.transform.c, dem.transform.f
    dx, dy = res
    tiny = 1e-9
    k = (math.floor((left - x0) / dx + tiny), math.ceil((right - x0) / dx - tiny))
    m = (math.floor((y0 - top) / dy + tiny), math.ceil((y0 - bottom) / dy - tiny))
    return x0 + k[0] * dx, y0 - m[1] * dy, x0 + k[1] * dx, y0 - m[0] * dy


def check_grid_size(
    grid: OutputGrid,
    dem: DemSource,
    sources: Sequence[ImageSource],
    output_dir: str | Path | None = None,
) -> None:
    """Refuse, before any planning, a grid that cannot be written: InputError (one line with
    its posts and bytes) when a side exceeds GDAL's limit (:data:`GDAL_MAX_SIDE`), when a
    grid other than the DEM's own has more than :data:`POSTS_PER_PIXEL` posts per pixel of
    the images, or when its outputs (float32 of every band, with overviews) would not fit in
    the free space of ``output_dir`` even compressed :data:`COMPRESSION` times."""
    rows, cols = grid.shape
    per_unit, unit = unit_scale(grid.crs, dem.preview.radii[0])
    res = abs(grid.transform.a)
    advice = "choose a coarser res or smaller bounds"
    if max(rows, cols) > GDAL_MAX_SIDE:  # (before the sizes: their product may pass float's)
        raise InputError(
            f"the output grid would be {float(cols):.3g} x {float(rows):.3g} posts of {res:.3g} "
            f"{unit}, beyond GDAL's rasters ({GDAL_MAX_SIDE:,} a side): {advice}"
        )
    posts = rows * cols
    bands = max(v.bands for v in sources) if sources else 1
    nbytes = posts * 4 * bands * 4 / 3
    size = (
        f"{cols:,} x {rows:,} posts of {res:.3g} {unit} ({res * per_unit:.3g} m on the ground; "
        f"{count_text(posts)} posts, {size_text(nbytes)} as float32)"
    )
    pixels = sum(v.width * v.height for v in sources)
    own = grid.on_dem or (grid.shape == dem.shape and grid.crs == dem.crs)
    if not own and pixels and posts > POSTS_PER_PIXEL * pixels:
        raise InputError(
            f"the output grid would be {size}, {count_text(posts / pixels)} posts per pixel of "
            f"the images' {count_text(pixels)}: {advice} (the camera grid's default is the "
            "images' own ground sample distance)"
        )
    if output_dir is not None:
        try:
            free = shutil.disk_usage(output_dir).free
        except OSError:
            return  # the directory is checked where it is written
        if nbytes / COMPRESSION > free:
            raise InputError(
                f"the output grid would be {size}, more than the {size_text(free)} free in "
                f"{output_dir} even compressed {COMPRESSION} times: {advice}"
            )


def tile_count(grid: OutputGrid, tile: int) -> int:
    """Tiles of ``tile`` posts a side that cover ``grid``."""
    rows, cols = grid.shape
    return -(-rows // tile) * -(-cols // tile)


def check_tile_count(grid: OutputGrid, tile: int) -> None:
    """Refuse, before any tile is planned, a grid cut into more than :data:`MAX_TILES` tiles
    of ``tile`` posts a side: InputError, one line with the grid and the count."""
    rows, cols = grid.shape
    tiles = tile_count(grid, tile)
    if tiles > MAX_TILES:
        raise InputError(
            f"the output grid of {cols:,} x {rows:,} posts would be {count_text(tiles)} tiles of "
            f"{tile} posts, more than the {MAX_TILES:,} a plan holds: choose larger tiles, a "
            "coarser res or smaller bounds"
        )


def _no_overlap(view: ImageSource, boxes: list[Box | None], dem: DemSource) -> str:
    """Why no tile of the grid can be seen in ``view``, in one line."""
    preview = dem.preview
    points = preview.world_points()[preview.valid]
    centre = points.mean(axis=0)
    if (np.dot(sensor_positions(view.camera) - centre, preview.up_vectors(centre)) < 0).all():
        return f"{view.path}: the camera is below the surface of the DEM"
    seen = [b for b in boxes if b is not None]
    if not seen:
        return (
            f"{view.path}: no post of the output grid that the DEM covers lies in front of the "
            "camera (do --bounds, or --crs, miss the DEM, or does the camera look away from it?)"
        )
    c0, c1 = min(b[0] for b in seen), max(b[1] for b in seen)
    r0, r1 = min(b[2] for b in seen), max(b[3] for b in seen)
    return (
        f"{view.path}: the image ({view.width} x {view.height} px) does not cover the output "
        f"grid: its posts project to columns {c0:.0f}..{c1:.0f}, rows {r0:.0f}..{r1:.0f}"
    )


def left_out_text(sources: Sequence[ImageSource], left_out: Sequence[int]) -> str:
    """The :class:`LeftOutWarning` of the views ``left_out`` (0-based) of ``sources``."""
    names = ", ".join(str(sources[k].path) for k in left_out)
    see, are = ("sees", "is") if len(left_out) == 1 else ("see", "are")
    return (
        f"{len(left_out)} of {len(sources)} images {see} no post of the output grid and {are} "
        f"left out: {names}"
    )


def check_plan(
    source: DemSource,
    sources: Sequence[ImageSource],
    boxes: list[list[Box | None]],
    seen: list[bool],
    reach: list[float],
    elevation: list[float],
) -> tuple[int, ...]:
    """The views that no tile sees (``seen``), left out: their indices (0-based), named in one
    :class:`LeftOutWarning`; GeometryError, saying why, when no view sees a tile (``boxes``:
    the first view's, for the reason). A :class:`HaloWarning` for a view whose occluder halo
    is larger than the DEM."""
    if not any(seen):
        why = _no_overlap(sources[0], boxes[0], source)
        if len(sources) > 1:
            why = f"none of the {len(sources)} images sees a post of the output grid; {why}"
        raise GeometryError(why)
    left_out = tuple(k for k, s in enumerate(seen) if not s)
    if left_out:
        warnings.warn(left_out_text(sources, left_out), LeftOutWarning, stacklevel=3)
    for k, view in enumerate(sources):
        if seen[k] and reach[k] > max(source.shape):
            warnings.warn(
                f"{view.path}: lines of sight as low as {elevation[k]:.1f} degrees above the "
                f"horizon can be blocked by terrain up to {reach[k]:,.0f} DEM posts away, more "
                f"than the DEM's {max(source.shape):,} posts: every tile reads and meshes most "
                "of the DEM, so memory grows with it (results stay correct)",
                HaloWarning,
                stacklevel=3,
            )
    return left_out
