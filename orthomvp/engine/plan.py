"""Plans: the output grid cut into tiles, and per tile the images that see it and the DEM
window it needs (its posts plus the occluder halo of :mod:`orthomvp.engine.halo`).

Planning reads the DEM once in bounded blocks (:func:`orthomvp.engine.grid.scan_dem`) and
only the headers of the images; everything else is geometry on the tiles' perimeters.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np

from orthomvp.camera import Camera
from orthomvp.codes import WorldFrame
from orthomvp.engine.arguments import (
    PATHLIKE,
    check_bounds,
    dem_path,
    dem_reading,
    eps_posts,
    view_pairs,
)
from orthomvp.engine.grid import DemSource, OutputGrid, WindowT, grid_to_dem
from orthomvp.engine.grid_choice import (
    MAX_TILES,
    check_grid_size,
    check_plan,
    check_tile_count,
    choose_grid,
    grid_spacing,
    read_source,
    tile_count,
)
from orthomvp.engine.halo import Box, TileSamples, ToDem, footprint, tile_runs
from orthomvp.engine.images import ImageSource, image_source
from orthomvp.engine.progress import Progress
from orthomvp.engine.tiling import (
    MESH_BYTES,
    MOSAIC_BYTES,
    SINGLE_VIEW_TILE,
    SMALL_TILE,
    TILE,
    TILE_BYTES,
    TILE_STEP,
    VIEW_BYTES,
    WINDOW_BYTES,
    auto_tile,
    check_tile,
    largest_dem_window,
    mosaic_tile,
    peak_bytes,
)
from orthomvp.engine.view_index import ViewIndex
from orthomvp.errors import InputError
from orthomvp.geometry.datum import HeightOptions
from orthomvp.occlusion.occluders import BOUND_BYTES
from orthomvp.occlusion.paths import Geometry, Rays, VisibilityPath
from orthomvp.ortho.balance import Correction
from orthomvp.ortho.composite import FUSED_POSTS, MosaicOptions
from orthomvp.ortho.orthophoto import INTERPOLATION
from orthomvp.validate import of_type

IMAGE_MARGIN = 2
"""Image pixels read beyond the outermost sampled positions (cubic interpolation needs 2)."""

SAMPLE_BUDGET_PIXELS = 1 << 24
"""Pixels of an image window (per band) above which a tile samples its image in pieces."""


@dataclass(frozen=True)
class TileJob:
    """One output tile: ``window`` on the output grid; ``views``, the indices of the images
    that may see it; ``dem``, the DEM window it reads (None when no image sees it);
    ``image_windows``, per view, the image window (r0, r1, c0, c1) expected to be read (the
    bounds of where the tile can appear, see :func:`pixel_window`)."""

    index: int
    window: WindowT
    views: tuple[int, ...]
    dem: WindowT | None
    image_windows: tuple[WindowT, ...]

    @property
    def image_pixels(self) -> tuple[int, ...]:
        """Per view, the pixels of :attr:`image_windows`."""
        return tuple((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in self.image_windows)

    @property
    def dem_posts(self) -> int:
        """Posts of the DEM window (0 without one)."""
        if self.dem is None:
            return 0
        r0, r1, c0, c1 = self.dem
        return (r1 - r0) * (c1 - c0)


@dataclass(frozen=True)
class Plan:
    """Everything a worker needs, by value or by path: the DEM, the output grid, the views,
    the tiles, and the options (``eps`` in DEM posts or None for the default rule,
    ``interp``). ``spacing`` is one DEM post in metres at the DEM centre, ``post_scale`` one
    output post in DEM posts (both for the epsilon test, the same in every tile);
    ``reach`` and ``elevation`` per view: the farthest occluder track in DEM posts and the
    lowest line of sight in degrees over all tiles. ``mosaic`` (always with two views or
    more) says how views combine, ``correction`` the balance found by
    :func:`orthomvp.engine.survey.survey`; ``progress`` whether a run reports progress unless
    told otherwise; ``left_out`` the views (0-based) that see no post of the grid: in
    ``views`` (indices keep the caller's numbering), in no tile."""

    dem: DemSource
    grid: OutputGrid
    views: tuple[ImageSource, ...]
    tiles: tuple[TileJob, ...]
    tile: int
    occlusion: bool
    eps: float | None
    interp: str
    spacing: float
    post_scale: float
    reach: tuple[float, ...]
    elevation: tuple[float, ...]
    mosaic: MosaicOptions | None = None
    correction: Correction | None = None
    progress: bool = True
    left_out: tuple[int, ...] = ()

    @property
    def bands(self) -> int:
        return self.views[0].bands

    @property
    def margin(self) -> int:
        """Posts computed around every tile for the mosaic's seams and blending
        (:attr:`orthomvp.ortho.composite.MosaicOptions.margin`; 0 without a mosaic)."""
        return self.mosaic.margin if self.mosaic is not None else 0

    @cached_property
    def fused(self) -> bool:
        """Whether tiles run the numba kernels (their grid heights, the visibility test's
        geometry and the composition): a mosaic whose tiles with views hold
        :data:`orthomvp.ortho.composite.FUSED_POSTS` posts or more."""
        if self.mosaic is None:
            return False
        windows = (job.window for job in self.tiles if job.views)
        return sum((r1 - r0) * (c1 - c0) for r0, r1, c0, c1 in windows) >= FUSED_POSTS

    @cached_property
    def visibility_path(self) -> VisibilityPath:
        """The way of every tile's visibility test (:mod:`orthomvp.occlusion.paths`): the numba
        kernel's geometry where the plan runs the kernels (:attr:`fused`), else the numpy
        separable one; rays proved clear where they can be (a mosaic's misses matter only to
        its doubt, which a proved post cannot have); the DEM's :attr:`spacing`, and tiles that
        may see no post."""
        geometry = Geometry.SEPARABLE_KERNEL if self.fused else Geometry.SEPARABLE
        return VisibilityPath(
            geometry=geometry, rays=Rays.PROVED, spacing=self.spacing, strict=False
        )

    def extent(self, job: TileJob) -> WindowT:
        """The posts a tile computes: its window grown by :attr:`margin`, within the grid."""
        return grow(job.window, self.margin, self.grid.shape)

    def tile_bytes(self, job: TileJob, images: bool = True) -> int:
        """Expected peak memory of one tile in a worker, bytes (the constants above)."""
        r0, r1, c0, c1 = job.window
        ext = (r1 - r0 + 2) * (c1 - c0 + 2)
        mesh = (MESH_BYTES + BOUND_BYTES) * job.dem_posts if self.occlusion else 0
        pixels = max((min(p, SAMPLE_BUDGET_PIXELS) for p in job.image_pixels), default=0)
        image = 8 * self.bands * pixels if images else 0
        if self.mosaic is not None:
            m = 2 * self.margin
            ext = (r1 - r0 + 2 + m) * (c1 - c0 + 2 + m)
            # per view: samples of every band, codes, angles, GSD, costs and weights
            views = (VIEW_BYTES + 4 * self.bands + MOSAIC_BYTES) * ext * len(job.views)
        else:
            views = VIEW_BYTES * ext * len(job.views)
        return WINDOW_BYTES * job.dem_posts + mesh + TILE_BYTES * ext + views + image

    def peak_memory(self, workers: int, processes: int = 0, images: bool = True) -> int:
        """Expected peak memory of a run with ``workers`` tiles in flight at once and
        ``processes`` worker processes besides this one (:func:`peak_bytes`), reading images
        or not, bytes."""
        return peak_bytes((self.tile_bytes(job, images) for job in self.tiles), workers, processes)

    def summary(self, peak: int, workers: int) -> str:
        """One line: grid size, tiles, images, the largest DEM window, and the expected
        ``peak`` memory (bytes) with ``workers`` tiles at a time."""
        rows, cols = self.grid.shape
        run = [job for job in self.tiles if job.views]
        window = largest_dem_window(run)
        reach = max(self.reach, default=0.0)
        return (
            f"orthomvp: plan: {cols:,} x {rows:,} posts, {len(run)} of {len(self.tiles)} tiles of "
            f"{self.tile} x {self.tile} to run, {len(self.views)} image(s), occluder halo up to "
            f"{reach:.0f} DEM posts{window}; expected peak memory {peak / 2**30:.2f} GiB with "
            f"{workers} tile(s) at a time"
        )


def _views(
    views: Sequence[tuple[str | Path, str | Path | Camera]],
) -> tuple[ImageSource, ...]:
    sources = tuple(image_source(image, camera) for image, camera in view_pairs(views))
    bands = {v.bands for v in sources}
    if len(bands) != 1:
        raise InputError(f"the images have different numbers of bands: {sorted(bands)}")
    return sources


def pixel_window(view: ImageSource, low: Sequence[float], high: Sequence[float]) -> WindowT:
    """The window (r0, r1, c0, c1) of the image pixels that positions from ``low`` to ``high``
    (u, v) sample, with :data:`IMAGE_MARGIN` pixels around, clipped to the image (infinite
    bounds at its edges)."""
    (u0, v0), (u1, v1) = ([int(np.floor(np.clip(x, -1, 1 << 31))) for x in b] for b in (low, high))
    c0 = min(max(u0 - IMAGE_MARGIN, 0), view.width)
    r0 = min(max(v0 - IMAGE_MARGIN, 0), view.height)
    c1 = min(max(u1 + IMAGE_MARGIN + 2, c0 + 1), view.width)
    r1 = min(max(v1 + IMAGE_MARGIN + 2, r0 + 1), view.height)
    return (r0, r1, c0, c1)


def grow(window: WindowT, margin: int, shape: tuple[int, int]) -> WindowT:
    """``window`` grown by ``margin`` posts on every side, within a grid of ``shape``."""
    r0, r1, c0, c1 = window
    rows, cols = shape
    return max(r0 - margin, 0), min(r1 + margin, rows), max(c0 - margin, 0), min(c1 + margin, cols)


def _union(a: WindowT, b: WindowT) -> WindowT:
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


def _sees(box: Box | None, view: ImageSource) -> bool:
    """Whether a tile's image box (see :func:`~orthomvp.engine.halo.image_box`) meets the
    image (half a pixel beyond its outer pixel centres, plus the interpolation margin)."""
    m = 0.5 + IMAGE_MARGIN
    return box is not None and (
        box[1] >= -m
        and box[0] <= view.width - 1 + m
        and box[3] >= -m
        and box[2] <= view.height - 1 + m
    )


def _jobs(
    dem: DemSource,
    to_dem: ToDem,
    grid: OutputGrid,
    views: tuple[ImageSource, ...],
    windows: list[WindowT],
    occlusion: bool,
    margin: int = 0,
    candidates: ViewIndex | None = None,
    progress: bool = False,
) -> tuple[list[TileJob], list[list[Box | None]], list[float], list[float]]:
    """Plan the tiles ``windows``: their jobs (the views that see a tile, its DEM window), per
    view the image box of every tile (None where not computed), and per view the farthest
    occluder track (DEM posts) and the lowest line of sight (degrees) over all tiles, all for
    the tiles grown by ``margin`` posts (the posts they compute). With ``candidates``, an index
    of the grid, only the views it finds can see a tile are tried. Tiles go in runs
    (:func:`~orthomvp.engine.halo.tile_runs`), and in each run every view's image boxes, then
    its halos where it sees a tile, are found at once
    (:class:`~orthomvp.engine.halo.TileSamples`)."""
    n = len(views)
    grown = [grow(window, margin, grid.shape) for window in windows]
    need = [footprint(dem, to_dem, window, grid.on_dem) for window in grown]
    on = [r0 < r1 and c0 < c1 for r0, r1, c0, c1 in need]  # else the tile lies off the DEM
    boxes: list[list[Box | None]] = [[None] * len(windows) for _ in range(n)]
    reach, elevation = [0.0] * n, [90.0] * n
    tiles: list[list[int]] = [[] for _ in range(n)]  # per view, the tiles it may see
    for i, window in enumerate(grown):
        for k in (range(n) if candidates is None else candidates.views(window)) if on[i] else ():
            tiles[k].append(i)
    seen: list[list[int]] = [[] for _ in windows]
    image: list[list[WindowT]] = [[] for _ in windows]
    at = [0] * n  # per view, its first tile not yet planned (tiles[k] ascends)
    with Progress("planning tiles", progress, len(windows)) as bar:
        for first, last in tile_runs(grown):
            samples = TileSamples(dem, to_dem, grown[first:last])
            for k, view in enumerate(views):
                end = bisect.bisect_left(tiles[k], last, at[k])
                mine = [i - first for i in tiles[k][at[k] : end]]
                at[k] = end
                sees = []
                for j, box in zip(mine, samples.image_boxes(mine, view.camera), strict=True):
                    boxes[k][first + j] = box
                    if _sees(box, view):
                        sees.append(j)
                        seen[first + j].append(k)
                        image[first + j].append(pixel_window(view, box[::2], box[1::2]))
                halos = samples.halos(sees, view.camera) if occlusion else []
                for j, halo in zip(sees if occlusion else [], halos, strict=True):
                    need[first + j] = _union(need[first + j], halo.window)
                    reach[k] = max(reach[k], halo.reach)
                    elevation[k] = min(elevation[k], halo.elevation)
            bar.update(last - first)
    jobs = [
        TileJob(i, window, tuple(seen[i]), need[i], tuple(image[i]))
        if seen[i]
        else TileJob(i, window, (), None, ())
        for i, window in enumerate(windows)
    ]
    return jobs, boxes, reach, elevation


def plan_ortho(
    dem: str | Path,
    views: Sequence[tuple[str | Path, str | Path | Camera]],
    *,
    tile: int | None = None,
    grid: str = "camera",
    res: object = None,
    bounds: tuple[float, float, float, float] | None = None,
    crs: object | None = None,
    output_dir: str | Path | None = None,
    occlusion: bool = True,
    eps: float | None = None,
    interp: str = "bilinear",
    dem_crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = "auto",
    progress: bool = True,
    mosaic: MosaicOptions | None = None,
    vertical_datum: str = "auto",
    height_offset: float | None = None,
) -> Plan:
    """Plan orthophotos, visibility codes or a mosaic of ``views`` ((image path, camera or
    camera path) pairs) on the DEM at path ``dem``.

    The output grid (:func:`orthomvp.engine.grid_choice.choose_grid`) is by default
    (``grid="camera"``) the part of the DEM the images see at their own ground sample distance
    (rounded to 1, 2, 2.5 or 5 x 10^k m), or with ``grid="dem"`` the DEM's own; ``res`` (one
    value or (x, y): numbers in the units of ``crs``, or lengths with a unit such as "5m" or
    "0.0003deg") and ``bounds`` (left, bottom, right, top in the units of ``crs``; default
    the DEM's CRS, or any CRS pyproj knows on the same body) replace either choice. A grid
    that cannot be written (:func:`~orthomvp.engine.grid_choice.check_grid_size`, with the
    free space of ``output_dir`` when given) is refused before any tile is planned. It is cut
    into tiles of ``tile`` x ``tile`` posts (default :func:`auto_tile`: 1024, smaller on a grid
    too small to give every core a tile; for a mosaic at most :func:`mosaic_tile` of the views
    that see one tile).
    ``occlusion``, ``eps`` (DEM posts) and ``interp`` are those of
    :func:`orthomvp.ortho.orthophoto.orthorectify`; ``dem_crs`` overrides the DEM file's
    CRS, ``radius_values`` and ``world`` ("auto", "body", "map") as for
    :meth:`orthomvp.geometry.terrain.Terrain.read` and :func:`orthomvp.geometry.world.detect_world`;
    ``vertical_datum`` ("auto", "ignore") and ``height_offset`` (metres added to the DEM's
    heights) say how its heights become the cameras' (:mod:`orthomvp.geometry.datum`).

    With two views or more the plan is a mosaic, combined as ``mosaic`` says (default
    :class:`~orthomvp.ortho.composite.MosaicOptions`: seamlines and blending on); with one view
    a mosaic when ``mosaic`` is given (source raster, flags, hole policy as with more), else
    an orthophoto. A mosaic's tiles compute their posts plus the options' margin, so tiles join
    as one untiled run would. Views that see no post of the grid are left out
    (:attr:`Plan.left_out`, one :class:`~orthomvp.errors.LeftOutWarning`).

    ``progress``: progress bars (or log lines) and notes on stderr, here and, by default, in
    :func:`~orthomvp.engine.run_plan`; False prints nothing.

    Reads the DEM once in blocks and the images' headers. Raises GeometryError when no image
    sees the grid (InputError when the balance's reference is left out); warns (HaloWarning)
    when a camera's occluder halo is larger than the DEM."""
    dem = dem_path(dem)
    tile = check_tile(tile)
    eps = eps_posts(eps)
    of_type(occlusion, bool, "occlusion")
    bounds = check_bounds(bounds)
    if output_dir is not None and not Path(of_type(output_dir, PATHLIKE, "output_dir")).is_dir():
        raise InputError(f"output_dir {output_dir} is not a directory")
    dem_reading(
        radius_values=radius_values,
        world=world,
        progress=progress,
        vertical_datum=vertical_datum,
        height_offset=height_offset,
        dem_crs=dem_crs,
    )
    if interp not in INTERPOLATION:
        raise InputError(f"interpolation must be one of {', '.join(INTERPOLATION)}")
    sources = _views(views)
    if mosaic is not None and not isinstance(mosaic, MosaicOptions):
        raise InputError(f"mosaic must be MosaicOptions or None, got {type(mosaic).__name__}")
    mosaic = (mosaic or MosaicOptions()) if len(sources) > 1 else mosaic
    margin = mosaic.margin if mosaic is not None else 0
    smallest = SINGLE_VIEW_TILE if mosaic is None else SMALL_TILE
    stack = max(v.bands for v in sources) if mosaic is not None else 0
    source, sources, out, jobs, reach, elevation, tile, left_out = tile_grid(
        dem,
        sources,
        grid=grid,
        output_dir=output_dir,
        tile=tile,
        occlusion=occlusion,
        margin=margin,
        dem_crs=dem_crs,
        radius_values=radius_values,
        world=world,
        progress=progress,
        res=res,
        bounds=bounds,
        crs=crs,
        smallest=smallest,
        heights=HeightOptions(vertical_datum, height_offset),
        stack=stack,
    )
    if mosaic and mosaic.balance and mosaic.reference in left_out:
        raise InputError(f"balance reference {mosaic.reference + 1} sees no post of the grid")
    spacing = source.post_spacing()
    post_scale = 1.0 if out.on_dem else grid_spacing(out, source) / spacing
    return Plan(
        source,
        out,
        sources,
        tuple(jobs),
        tile,
        occlusion,
        eps,
        interp,
        spacing,
        post_scale,
        tuple(reach),
        tuple(elevation),
        mosaic,
        progress=progress,
        left_out=left_out,
    )


class TiledGrid(NamedTuple):
    """What :func:`tile_grid` gives: the DEM source, the views, the output grid, the tiles'
    jobs, per view the farthest occluder track (DEM posts) and the lowest line of sight
    (degrees), the tile side (posts), and the views left out (:func:`check_plan`)."""

    source: DemSource
    sources: tuple[ImageSource, ...]
    grid: OutputGrid
    jobs: list[TileJob]
    reach: list[float]
    elevation: list[float]
    tile: int
    left_out: tuple[int, ...]


def tile_grid(
    dem: str | Path,
    sources: Sequence[ImageSource],
    *,
    tile: int | None,
    occlusion: bool,
    margin: int,
    dem_crs: object | None,
    radius_values: bool,
    world: WorldFrame | str,
    progress: bool,
    res: object = None,
    bounds: tuple[float, float, float, float] | None = None,
    crs: object | None = None,
    grid: str = "dem",
    output_dir: str | Path | None = None,
    largest: int = TILE,
    smallest: int = SMALL_TILE,
    heights: HeightOptions | None = None,
    stack: int = 0,
) -> TiledGrid:
    """What every engine plan starts with: the DEM and views
    (:func:`~orthomvp.engine.grid_choice.read_source`), the output grid (``grid``, ``res``,
    ``bounds``, ``crs``: :func:`~orthomvp.engine.grid_choice.choose_grid`), checked for size
    (with the free space of ``output_dir``), and its tiles of ``tile`` posts (None:
    :func:`auto_tile`, from ``smallest`` to ``largest``, for a mosaic of ``stack`` bands at most
    :func:`mosaic_tile` of the views that see a tile, which may be smaller, grown again where
    the grid would need more than :data:`~orthomvp.engine.grid_choice.MAX_TILES` of them), each
    with ``margin`` posts around it, its DEM window (with the occluder halo when
    ``occlusion``) and its image boxes (:func:`_jobs`), checked (:func:`check_plan`)."""
    source, sources = read_source(dem, sources, dem_crs, radius_values, world, progress, heights)
    out = choose_grid(source, sources, grid=grid, res=res, bounds=bounds, crs=crs)
    check_grid_size(out, source, sources, output_dir)
    check_tile_count(out, largest if tile is None else tile)
    to_dem = grid_to_dem(out, source)
    found = ViewIndex(source, to_dem, out.shape, sources, 0.5 + IMAGE_MARGIN)
    if tile is None:
        widest = largest
        if stack:
            largest = min(largest, mosaic_tile(found.most(margin), stack, margin))
        tile = auto_tile(out.shape, largest=largest, smallest=smallest)
        while tile < widest and tile_count(out, tile) > MAX_TILES:  # (many views, a huge grid)
            tile = min(tile + TILE_STEP, widest)
    check_tile_count(out, tile)
    windows = out.tiles(tile)
    jobs, boxes, reach, elevation = _jobs(
        source, to_dem, out, sources, windows, occlusion, margin, found, progress
    )
    seen = [any(k in job.views for job in jobs) for k in range(len(sources))]
    if not any(seen):  # the first view's box in every tile, for the message saying why
        boxes[0] = _jobs(source, to_dem, out, sources[:1], windows, False, margin)[1][0]
    left_out = check_plan(source, sources, boxes, seen, reach, elevation)
    return TiledGrid(source, sources, out, jobs, reach, elevation, tile, left_out)
