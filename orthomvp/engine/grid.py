"""The engine's two grids: the DEM on disk (read window by window) and the output grid.

Pixel coordinates are ``(c, r)`` with integer values at post centres, as everywhere in
orthomvp; windows are ``(row0, row1, col0, col1)``, half-open, in posts. Nothing here holds a
whole DEM in memory: :func:`scan_dem` reads it once in blocks of bounded size for its height
range and a decimated preview (at most :data:`PREVIEW` posts a side), and the preview stands in
for the DEM wherever a whole-grid view is needed (frame detection, longitude wrapping).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rasterio
from affine import Affine
from rasterio.crs import CRS as FileCRS
from rasterio.errors import RasterioError
from rasterio.windows import Window

from orthomvp.codes import WorldFrame
from orthomvp.engine.progress import Progress
from orthomvp.errors import InputError
from orthomvp.geometry.crs import as_crs, as_pyproj, dem_georeference
from orthomvp.geometry.datum import (
    TOLERANCE,
    HeightOptions,
    HeightShift,
    height_shift,
    vertical_part,
    whole_crs,
)
from orthomvp.geometry.heights import check_relief, count_unusable, unusable, warn_infinite
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import nan_median
from orthomvp.io.raster import corrupt_data, held_raster, open_raster, read_values

if TYPE_CHECKING:
    from pyproj import CRS

PREVIEW = 256
"""Posts a side (at most) of the decimated DEM that :func:`scan_dem` keeps."""

SCAN_POSTS = 1 << 22
"""Posts (at most) read at a time by :func:`scan_dem`: 32 MiB of float64 (about 100 MiB with
the masked read's copies)."""

GDAL_CACHE = 64 << 20
"""Bytes of GDAL's block cache while the engine scans the DEM and writes its outputs. GDAL's
default, 5% of the machine's memory, would keep every block of a DEM read in one long pass
(or of an output written in windows that do not align with its blocks) for the whole pass.
GDAL compresses an output's blocks when they leave the cache, so a cache that holds a whole
output (256 MB did: 170 MB for a 3 m mosaic of four ngi-aerial frames with its overviews)
leaves all of its compression for the end, after the last tile: 0.35 s against 0.15 s
there with 64 MB, where it overlaps the tiles."""

WindowT = tuple[int, int, int, int]
"""(row0, row1, col0, col1), half-open, in posts."""


HELD_POSTS = 1 << 18
"""A DEM of at most this many posts (2 MiB of float64) is kept whole by :func:`scan_dem`, which
reads it anyway, and tiles take their windows from it instead of reading the file again (the
24 m orthophoto of ngi-aerial reads its 508 x 327 DEM once); a bounded cost, beyond which DEMs
are read in windows."""


@dataclass(frozen=True)
class DemSource:
    """A DEM file and its conventions, and for a small DEM its values.

    ``preview`` is the DEM decimated by ``stride`` (post ``(i, j)`` of the preview is post
    ``(i * stride, j * stride)`` of the DEM); ``h_min``, ``h_max`` are its lowest and highest
    values over every post (metres of height, or of radius with ``radius_values``); ``held``
    every value (as :meth:`read` gives them) of a DEM of at most :data:`HELD_POSTS` posts,
    else None.
    """

    path: Path
    shape: tuple[int, int]
    transform: Affine
    crs: CRS | FileCRS
    radius_values: bool
    world: WorldFrame
    h_min: float
    h_max: float
    preview: Terrain
    stride: int
    held: np.ndarray | None = field(default=None, compare=False, repr=False)
    file_crs: object | None = field(default=None, compare=False, repr=False)
    heights: HeightOptions = field(default=HeightOptions(), compare=False, repr=False)
    shift: HeightShift | None = field(default=None, compare=False, repr=False)
    raw: tuple[np.ndarray, float, float] | None = field(default=None, compare=False, repr=False)

    def read(self, window: WindowT) -> np.ndarray:
        """The DEM values in ``window`` as float64 (rows, cols), NaN at nodata, shifted to the
        heights the cameras need (``shift``, :mod:`orthomvp.geometry.datum`)."""
        values = self._read(window)
        return values if self.shift is None else values + self.shift.window(window)

    def heights_crs(self) -> CRS | FileCRS:
        """The CRS that says what :meth:`read`'s values are, for a DEM written from them: the
        DEM's whole CRS, its vertical part included, when they are the file's heights (no
        ``shift``), else its horizontal CRS (heights above its ellipsoid, or moved by an
        offset the user gave for that)."""
        if self.shift is None and vertical_part(self.file_crs) is not None:
            return whole_crs(self.file_crs, str(self.path))
        return self.crs

    def _read(self, window: WindowT) -> np.ndarray:
        """The DEM values in ``window`` as the file holds them."""
        r0, r1, c0, c1 = window
        if self.held is not None:
            return self.held[r0:r1, c0:c1].copy()
        with held_raster(self.path) as src:
            try:
                values = read_values(src, 1, Window(c0, r0, c1 - c0, r1 - r0), np.float64)
            except RasterioError as exc:
                raise corrupt_data(self.path, exc) from exc
        values[unusable(values)] = np.nan  # as Terrain.read: infinite or fill values are nodata
        return values

    def window_terrain(self, window: WindowT, values: np.ndarray) -> Terrain:
        """A :class:`Terrain` of ``values`` read from ``window`` (its own pixel (0, 0) is the
        window's first post)."""
        r0, _, c0, _ = window
        return Terrain(
            values,
            self.transform @ Affine.translation(c0, r0),
            self.crs,
            self.radius_values,
            self.world,
            name=str(self.path),
        )

    def geometry(self) -> Terrain:
        """The DEM's grid as a :class:`Terrain` without its values (a 2 x 2 stand-in): its
        georeference, conventions and the longitude it wraps around (the whole grid's
        centre), so that geometry at DEM pixel positions comes out exactly as on the whole
        DEM read into memory."""
        rows, cols = self.shape
        grid = Terrain(
            np.zeros((2, 2)),
            self.transform,
            self.crs,
            self.radius_values,
            self.world,
            name=str(self.path),
        )
        mid = np.array([(cols - 1) / 2, (rows - 1) / 2])
        lon, _ = grid.pixel_to_lonlat(mid[0], mid[1], wrap=False)
        return replace(grid, wrap_lon=float(lon))

    def to_world(self, c: np.ndarray, r: np.ndarray, value: np.ndarray) -> np.ndarray:
        """World xyz (..., 3) of DEM pixel positions ``(c, r)`` with DEM ``value``."""
        s = self.stride
        return self.preview.to_world(np.asarray(c) / s, np.asarray(r) / s, value)

    def from_world(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """DEM pixel position ``(c, r)`` and value of world points (..., 3)."""
        c, r, v = self.preview.from_world(xyz)
        return c * self.stride, r * self.stride, v

    def post_spacing(self) -> float:
        """Metres between neighbouring posts at the DEM centre (mean of both directions),
        at the median height: what :meth:`Terrain.post_spacing` gives for the whole DEM."""
        return float(np.mean(self.ground_spacing()))

    def ground_spacing(
        self,
        to_dem: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
        shape: tuple[int, int] | None = None,
    ) -> tuple[float, float]:
        """World distances (along columns, along rows) between neighbouring posts at the
        centre of a grid of ``shape`` whose positions ``to_dem`` maps into this DEM (default:
        the DEM's own grid), at the DEM's median height."""
        rows, cols = self.shape if shape is None else shape
        c0, r0 = (cols - 1) / 2, (rows - 1) / 2
        c, r = np.array([c0, c0 + 1, c0]), np.array([r0, r0, r0 + 1])
        if to_dem is not None:
            c, r = to_dem(c, r)
        p = self.to_world(c, r, np.full(3, nan_median(self.preview.values)))
        return float(np.linalg.norm(p[1] - p[0])), float(np.linalg.norm(p[2] - p[0]))


def _blocks(rows: int, cols: int) -> Iterator[tuple[int, int]]:
    """Row ranges of full-width blocks of at most :data:`SCAN_POSTS` posts."""
    step = max(1, SCAN_POSTS // max(cols, 1))
    for r0 in range(0, rows, step):
        yield r0, min(r0 + step, rows)


def scan_dem(
    path: str | Path,
    crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = WorldFrame.BODY,
    progress: Progress | None = None,
    *,
    heights: HeightOptions | None = None,
) -> DemSource:
    """Read a DEM once, block by block (peak memory :data:`SCAN_POSTS` float64 posts), for its
    height range and a preview; ``crs`` overrides the file's CRS. ``progress`` counts rows.
    Heights stay as the file holds them until :func:`with_world` shifts them for the cameras'
    frame as ``heights`` says.
    InputError for a DEM without CRS, georeference, valid heights or a cell of four, or whose
    vertical datum cannot be converted."""
    path = Path(path)
    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE), open_raster(path) as src:
        rows, cols = src.height, src.width
        transform, file_crs = src.transform, src.crs
        the_crs = dem_georeference(path, file_crs, transform, crs, shape=(rows, cols))
        if min(rows, cols) < 2:
            raise InputError(f"{path}: a DEM needs at least 2 x 2 posts, got {(rows, cols)}")
        stride = max(1, -(-max(rows, cols) // PREVIEW))
        if progress:
            progress.set_total(rows)
        lo, hi, parts, infinite, extreme = np.inf, -np.inf, [], 0, 0
        cell, last = False, np.zeros((0, cols), bool)  # a cell of 4 valid posts; the last row
        held = np.empty((rows, cols)) if rows * cols <= HELD_POSTS else None
        for r0, r1 in _blocks(rows, cols):
            try:
                block = read_values(src, 1, Window(0, r0, cols, r1 - r0), np.float64)
            except RasterioError as exc:
                raise corrupt_data(path, exc) from exc
            bad = unusable(block)
            if bad.any():
                counts = count_unusable(block)
                infinite, extreme = infinite + counts[0], extreme + counts[1]
                block[bad] = np.nan
            if np.isfinite(block).any():
                lo, hi = min(lo, np.nanmin(block)), max(hi, np.nanmax(block))
                ok = np.vstack([last, np.isfinite(block)])
                cell = cell or bool((ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]).any())
            last = np.isfinite(block[-1:])
            parts.append(block[(-r0) % stride :: stride, ::stride].copy())  # not a view
            if held is not None:
                held[r0:r1] = block
            if progress:
                progress.update(r1 - r0)
    if not np.isfinite(lo):
        raise InputError(f"{path}: the DEM holds no valid heights")
    if not cell:
        raise InputError(
            f"{path}: no 2 x 2 posts of the DEM all have heights (nodata beside every valid "
            "post): it has no surface to project onto"
        )
    warn_infinite(path, infinite, extreme)
    shift = 0.5 - 0.5 * stride  # preview pixel i's centre is DEM pixel (i * stride)'s centre
    preview_transform = transform @ Affine.translation(shift, shift) @ Affine.scale(stride)
    values = np.concatenate(parts)
    if values.shape[0] < 2 or values.shape[1] < 2:  # a long thin DEM: keep two posts a side
        pad = ((0, max(0, 2 - values.shape[0])), (0, max(0, 2 - values.shape[1])))
        values = np.pad(values, pad, constant_values=np.nan)
    if not np.isfinite(values).any():  # valid posts exist, but none on the preview lattice
        values = np.full_like(values, (lo + hi) / 2)
    preview = Terrain(values, preview_transform, the_crs, radius_values, world, name=str(path))
    check_relief(str(path), lo, hi, nan_median(preview.values), preview.radii[0])
    source = DemSource(
        path,
        (rows, cols),
        transform,
        the_crs,
        radius_values,
        preview.world,
        float(lo),
        float(hi),
        preview,
        stride,
        held,
        file_crs if crs is None else crs,
        heights or HeightOptions(),
    )
    return source


def with_world(dem: DemSource, world: WorldFrame) -> DemSource:
    """The same DEM with cameras in another world frame, its heights shifted to what they need
    (:func:`~orthomvp.geometry.datum.height_shift`): the preview and the height range at once
    (the range widened by the largest shift between neighbouring preview posts, a bound for the
    shift between them), each window as :meth:`DemSource.read` reads it."""
    values, lo, hi = dem.raw or (dem.preview.values, dem.h_min, dem.h_max)
    shift = height_shift(
        dem.file_crs,
        dem.transform,
        dem.shape,
        world=world,
        heights=dem.heights,
        radius_values=dem.radius_values,
        name=str(dem.path),
    )
    if shift is not None:
        r, c = np.mgrid[0 : values.shape[0], 0 : values.shape[1]] * dem.stride
        n = shift.at(c, r)
        steps = [np.abs(np.diff(n, axis=k)).max(initial=0.0) for k in (0, 1)]
        margin = max(steps) + TOLERANCE
        lo, hi = lo + n.min() - margin, hi + n.max() + margin
        values = values + n
    preview = replace(dem.preview, world=world, values=values)
    return replace(
        dem,
        world=world,
        preview=preview,
        h_min=lo,
        h_max=hi,
        shift=shift,
        raw=dem.raw or (dem.preview.values, dem.h_min, dem.h_max),
    )


@dataclass(frozen=True)
class OutputGrid:
    """The output grid: ``transform`` (pixel corners, as GDAL), ``shape`` (rows, cols) and
    ``crs``. ``on_dem`` when its posts are the DEM's posts (no interpolation needed)."""

    transform: Affine
    shape: tuple[int, int]
    crs: CRS | FileCRS
    on_dem: bool

    def georef(self, window: WindowT, like: Terrain) -> Terrain:
        """A :class:`Terrain` of the grid posts in ``window`` (values zero, to be filled), with
        the conventions of ``like``."""
        r0, r1, c0, c1 = window
        return replace(
            like,
            values=np.zeros((r1 - r0, c1 - c0)),
            transform=self.transform @ Affine.translation(c0, r0),
            crs=self.crs,
        )

    def tiles(self, size: int) -> list[WindowT]:
        """Windows of ``size`` x ``size`` posts covering the grid, row by row."""
        rows, cols = self.shape
        return [
            (r, min(r + size, rows), c, min(c + size, cols))
            for r in range(0, rows, size)
            for c in range(0, cols, size)
        ]


def same_body(dem: DemSource, crs: CRS | FileCRS) -> None:
    """InputError unless ``crs`` lies on the DEM's body (same ellipsoid): heights carry over."""
    crs = as_pyproj(crs)
    ours, theirs = dem.preview.geodetic_crs, crs if crs.is_geographic else crs.geodetic_crs
    a = (ours.ellipsoid.semi_major_metre, ours.ellipsoid.semi_minor_metre)
    b = (theirs.ellipsoid.semi_major_metre, theirs.ellipsoid.semi_minor_metre)
    pm = (ours.prime_meridian.longitude, theirs.prime_meridian.longitude)
    if not np.allclose(a, b, rtol=1e-12, atol=1e-6) or pm[0] != pm[1]:
        raise InputError(
            f"the output CRS lies on another body than the DEM's (semi-axes {b[0]:.0f} / "
            f"{b[1]:.0f} m against {a[0]:.0f} / {a[1]:.0f} m): give a CRS on the DEM's body"
        )


def output_grid(
    dem: DemSource,
    res: tuple[float, float] | None = None,
    bounds: tuple[float, float, float, float] | None = None,
    crs: object | None = None,
) -> OutputGrid:
    """The output grid: the DEM's own, or pixel size ``res`` (x, y) and ``bounds`` (left,
    bottom, right, top) in the units of ``crs`` (default: the DEM's CRS; degrees or metres).

    Defaults in another CRS: the DEM's extent transformed into it (21 points a side), and the
    DEM's post spacing at its centre measured in it. Posts are placed as by
    :meth:`Terrain.regrid`: ``round(extent / res)`` (at least 2) from the top-left corner.
    """
    out_crs = dem.crs if crs is None else as_crs(crs, "output CRS")  # (the survey's: a grid's)
    same_crs = out_crs == dem.crs
    if not same_crs:
        if dem.world == WorldFrame.MAP:
            raise InputError(
                "the cameras live in the DEM's projected CRS (world frame 'map'): the output "
                "must stay in that CRS"
            )
        same_body(dem, out_crs)
    if same_crs and res is None and bounds is None:
        return OutputGrid(dem.transform, dem.shape, dem.crs, True)
    t, (rows, cols) = dem.transform, dem.shape
    if same_crs:
        left, top = t.c, t.f
        right, bottom = left + cols * t.a, top + rows * t.e
        dx, dy = abs(t.a), abs(t.e)
    else:
        from pyproj import Transformer

        to_out = Transformer.from_crs(as_pyproj(dem.crs), as_pyproj(out_crs), always_xy=True)
        x0, y0, x1, y1 = (t.c, t.f + rows * t.e, t.c + cols * t.a, t.f)
        left, bottom, right, top = to_out.transform_bounds(x0, y0, x1, y1, densify_pts=21)
        c, r = (cols - 1) / 2, (rows - 1) / 2
        x, y = (t @ Affine.translation(0.5, 0.5)) @ (
            np.array([c, c + 1, c]),
            np.array([r, r, r + 1]),
        )
        ox, oy = to_out.transform(x, y)
        dx = float(np.hypot(ox[1] - ox[0], oy[1] - oy[0]))
        dy = float(np.hypot(ox[2] - ox[0], oy[2] - oy[0]))
    if bounds is not None:
        left, bottom, right, top = (float(v) for v in bounds)
        if not (right > left and top > bottom):
            raise InputError(f"bounds must be left bottom right top, got {bounds}")
    if res is not None:
        dx, dy = float(res[0]), float(res[1])
    if not (dx > 0 and dy > 0):
        raise InputError(f"resolution must be positive, got {res}")
    n_c = max(int(round((right - left) / dx)), 2)
    n_r = max(int(round((top - bottom) / dy)), 2)
    grid = Affine(dx, 0, left, 0, -dy, top)
    return OutputGrid(grid, (n_r, n_c), out_crs, same_crs and grid == t and (n_r, n_c) == dem.shape)


def grid_to_dem(
    grid: OutputGrid, dem: DemSource
) -> Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """A function from output-grid pixel positions ``(c, r)`` to DEM pixel positions."""
    to_dem = None
    if grid.crs != dem.crs:
        from pyproj import Transformer

        to_dem = Transformer.from_crs(as_pyproj(grid.crs), as_pyproj(dem.crs), always_xy=True)
    g = grid.transform @ Affine.translation(0.5, 0.5)
    d = ~(dem.transform @ Affine.translation(0.5, 0.5))

    def convert(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, y = g @ (np.asarray(c, dtype=np.float64), np.asarray(r, dtype=np.float64))
        if to_dem is not None:
            x, y = to_dem.transform(x, y)
        return d @ (np.asarray(x), np.asarray(y))

    return convert
