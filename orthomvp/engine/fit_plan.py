"""Planning the MVP fit through the engine: a plan of tiles on the DEM's own grid, each fitted from
windows of the DEM and of the images, with the results of the in-memory fit
(:func:`orthomvp.mvp.fit_dem`) bit for bit.

What a tile of posts T needs (the bound, derived from the code of :mod:`orthomvp.mvp`):

- Heights at T are the fitted plane heights after ``options.deconvolve`` Van Cittert steps
  (:func:`orthomvp.mvp.deconvolve.deconvolve`), each of which reads the plane heights within
  ``hwin`` posts of a post: so the planes of every post within ``deconvolve * hwin`` posts of T
  are fitted (the *fit window* F; normals, cost, views and uncertainty at T need only T).
- Fitting a post reads, from the DEM, its own value and its normal, central differences of its
  neighbours: the *fit grid* is F and one post around. Its patch (``hwin`` posts at the finest
  level, ``hwin * 2**(levels - 1)`` at the coarsest) lies on the fitted plane and reads image
  pixels only, no DEM post.
- The views that see a post come from the visibility test of F's posts, which needs the
  occluder halo of F for each view (:mod:`orthomvp.engine.halo`).

So the DEM window of a tile is T grown by ``deconvolve * hwin + 1`` posts, united with the
occluder halos of F (clipped to the DEM). The image window of a view is where the patches of
F's posts can fall: F grown by ``hwin * 2**(levels - 1)`` posts, at heights from the DEM's
lowest minus to its highest plus that many post spacings (planes tilted up to 45 degrees),
projected, grown by the pyramid's margin and aligned (:func:`orthomvp.mvp.views.window_for`).
That is an estimate: planes move while they are fitted. After the fit, the positions actually
sampled are checked against the pixels the windows compute exactly
(:func:`orthomvp.mvp.views.exact_masks`), and a tile whose samples strayed is fitted again with
its windows grown to hold them (at most :data:`RETRIES` times, then the whole image of the view
in question), so the results never depend on the estimate.

The image statistics that the fit takes from whole images (the fill value of nodata pixels and
the flatness thresholds) come from one pass over each image in blocks when planning.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera import Camera, NullDistortion, PinholeCamera
from orthomvp.codes import WorldFrame
from orthomvp.engine.arguments import dem_path, dem_reading, eps_posts, view_pairs
from orthomvp.engine.grid import DemSource, OutputGrid, WindowT, output_grid
from orthomvp.engine.grid_choice import check_plan, read_source
from orthomvp.engine.halo import Box, Halo, footprint, image_box, tile_halo
from orthomvp.engine.images import ImageSource, image_source
from orthomvp.engine.plan import _sees, _union
from orthomvp.engine.progress import Progress
from orthomvp.engine.tiling import (
    MESH_BYTES,
    TILE,
    WINDOW_BYTES,
    check_tile,
    largest_dem_window,
    peak_bytes,
)
from orthomvp.errors import GeometryError, InputError, OrthoMVPWarning
from orthomvp.geometry.datum import HeightOptions
from orthomvp.geometry.vectors import perimeter
from orthomvp.mvp import FitOptions
from orthomvp.mvp.fit import TILE as BATCH
from orthomvp.mvp.problem import MIN_LEVEL_SIZE, levels_for
from orthomvp.mvp.views import view_statistics, window_for
from orthomvp.occlusion.paths import Rays, VisibilityPath
from orthomvp.validate import of_type

RETRIES = 3
"""Times a tile is fitted again with grown image windows before it takes whole images."""

# Bytes of memory, from the growth of the peak resident set size over single tiles of the
# hills scene (200 x 200 posts, 4 views, tiles of 32 to 200 posts, hwin 3 and 10, 1 and 2
# threads), rounded up: per post of the fit grid (the problem's and the result's arrays, the
# deconvolution's moments: about 750 measured with the views' share and the DEM window's),
# per post and view (the visibility test's arrays, the masks), per pixel of an image window
# (the window, its fill and undistortion, the pyramid of values and gradients, the
# exactness masks), and per thread for a batch of BATCH x BATCH posts per sample of the
# patch and view (samples, their derivatives and the normal equations' products, float32,
# with the heap they leave behind: about 170 MB a thread at hwin 10 with 4 views).
FIT_POST_BYTES = 500
FIT_VIEW_BYTES = 80
PIXEL_BYTES = 48
BATCH_SAMPLE_BYTES = 170


@dataclass(frozen=True)
class FitJob:
    """One tile of the fit: ``window`` the posts it writes (T); ``fit`` the posts whose planes
    it fits (F, see the module docstring), ``dem`` the DEM window it reads, ``views`` the
    images that see F, and ``images`` per view in ``views`` the image window it reads
    (row0, row1, col0, col1); ``fit``, ``dem`` None (and no views) when fewer than two
    images see F: nothing there can be fitted."""

    index: int
    window: WindowT
    fit: WindowT | None
    dem: WindowT | None
    views: tuple[int, ...]
    images: tuple[WindowT, ...]

    @property
    def dem_posts(self) -> int:
        """Posts of the DEM window (0 without one)."""
        return _posts(self.dem)

    @property
    def fit_posts(self) -> int:
        """Posts whose planes the tile fits (0 without any)."""
        return _posts(self.fit)


def _posts(window: WindowT | None) -> int:
    if window is None:
        return 0
    r0, r1, c0, c1 = window
    return (r1 - r0) * (c1 - c0)


@dataclass(frozen=True)
class FitPlan:
    """Everything a worker needs to fit tiles, by value or by path: the DEM, its grid (the
    output grid), the views with per view the ``stats`` (fill value, standard deviation per
    pyramid level) of the whole image, the tiles, the ``options`` (``levels`` the pyramid
    levels of the whole images), ``eps`` of the visibility test, ``spacing`` the DEM's mean
    post spacing in metres, ``margin`` the deconvolution's reach in posts, and per view
    ``reach`` and ``elevation`` of the occluder halos (as :class:`~orthomvp.engine.Plan`);
    ``progress`` whether a run reports progress unless told otherwise (the planner's)."""

    dem: DemSource
    grid: OutputGrid
    views: tuple[ImageSource, ...]
    stats: tuple[tuple[float, tuple[float, ...]], ...]
    tiles: tuple[FitJob, ...]
    tile: int
    options: FitOptions
    eps: float | None
    spacing: float
    margin: int
    reach: tuple[float, ...]
    elevation: tuple[float, ...]
    progress: bool = True

    @property
    def levels(self) -> int:
        return self.options.levels

    @cached_property
    def visibility_path(self) -> VisibilityPath:
        """The way of every tile's visibility test (:mod:`orthomvp.occlusion.paths`): the numpy
        separable geometry, every ray cast on the whole occluder mesh of the tile's window, the
        DEM's :attr:`spacing`, and tiles that may see no post."""
        return VisibilityPath(rays=Rays.WHOLE_MESH, spacing=self.spacing, strict=False)

    def tile_bytes(self, job: FitJob, threads: int = 1) -> int:
        """Expected peak memory of one tile in a worker with ``threads`` threads, bytes."""
        if job.dem is None:
            return 0
        k = len(job.views)
        posts = _posts(_grow(job.fit, 1, self.grid.shape))
        pixels = sum(_posts(w) for w in job.images)
        batch = self.patch_bytes(threads, k, posts)
        return (
            (WINDOW_BYTES + MESH_BYTES) * job.dem_posts
            + (FIT_POST_BYTES + FIT_VIEW_BYTES * k) * posts
            + PIXEL_BYTES * pixels
            + batch
        )

    def patch_bytes(self, threads: int = 1, views: int = 0, posts: int = 0) -> int:
        """The patches' share of :meth:`tile_bytes`, bytes: a batch of BATCH x BATCH posts
        (at most the tile's ``posts``) per thread, each post's (2 hwin + 1)^2 samples of each
        of ``views`` images; by default for the tile of most views and posts."""
        if not views:
            fitted = [job for job in self.tiles if job.dem is not None]
            if not fitted:
                return 0
            views = max(len(job.views) for job in fitted)
            posts = max(_posts(_grow(job.fit, 1, self.grid.shape)) for job in fitted)
        side = 2 * self.options.hwin + 1
        batch = min(BATCH * BATCH, posts)
        return BATCH_SAMPLE_BYTES * batch * views * side * side * max(threads, 1)

    def peak_memory(self, workers: int, processes: int = 0, threads: int = 1) -> int:
        """Expected peak memory of a run with ``workers`` tiles at a time (each with
        ``threads`` threads) and ``processes`` worker processes besides this one, bytes."""
        sizes = (self.tile_bytes(job, threads) for job in self.tiles)
        return peak_bytes(sizes, workers, processes)

    def summary(self, peak: int, workers: int) -> str:
        """One line: grid size, tiles, images, the largest windows and the expected ``peak``
        memory (bytes) with ``workers`` tiles at a time."""
        rows, cols = self.grid.shape
        run = [job for job in self.tiles if job.views]
        windows = largest_dem_window(run)
        if windows:
            r0, r1, c0, c1 = max((w for job in run for w in job.images), key=_posts)
            windows += f", image windows up to {c1 - c0:,} x {r1 - r0:,} px"
        return (
            f"orthomvp: plan: fit {cols:,} x {rows:,} posts, {len(run)} of {len(self.tiles)} "
            f"tiles of {self.tile} x {self.tile} to run, {len(self.views)} images, {self.levels} "
            f"pyramid level(s); tiles read {self.margin + 1} posts around them and an occluder "
            f"halo up to {max(self.reach, default=0.0):.0f} posts{windows}; expected peak "
            f"memory {peak / 2**30:.2f} GiB with {workers} tile(s) at a time"
        )


def _grow(window: WindowT | None, n: int, shape: tuple[int, int]) -> WindowT | None:
    """``window`` grown by ``n`` posts on every side, clipped to ``shape``."""
    if window is None:
        return None
    r0, r1, c0, c1 = window
    rows, cols = shape
    return max(r0 - n, 0), min(r1 + n, rows), max(c0 - n, 0), min(c1 + n, cols)


def _undistorted(camera: Camera) -> Camera:
    """A pinhole without its lens distortion (the fit samples such images); other cameras as
    they are."""
    if isinstance(camera, PinholeCamera):
        return replace(camera, distortion=NullDistortion())
    return camera


def patch_box(
    dem: DemSource, window: WindowT, camera: Camera, reach: int, slack: float
) -> tuple[float, float, float, float]:
    """Where the patches of the posts of ``window`` may fall in the image (a pinhole's without
    lens distortion): the bounding box (c0, c1, r0, r1) of the projections of the window grown by
    ``reach`` posts (not clipped to the DEM), at the DEM's lowest value minus ``slack`` and
    its highest plus ``slack`` (metres); the whole plane when some point lies behind the
    camera."""
    r0, r1, c0, c1 = window
    grown = (r0 - reach, r1 + reach, c0 - reach, c1 + reach)
    pc, pr = perimeter(grown)
    lc, lr = np.meshgrid(
        np.linspace(grown[2], grown[3] - 1, 9), np.linspace(grown[0], grown[1] - 1, 9)
    )
    c = np.concatenate([pc, lc.ravel()] * 2)
    r = np.concatenate([pr, lr.ravel()] * 2)
    n = len(c) // 2
    h = np.concatenate([np.full(n, dem.h_min - slack), np.full(n, dem.h_max + slack)])
    uv, depth = _undistorted(camera).project(dem.to_world(c, r, h))
    if not ((depth > 0) & np.isfinite(uv).all(axis=-1)).all():
        return (-np.inf, np.inf, -np.inf, np.inf)
    return (uv[:, 0].min(), uv[:, 0].max(), uv[:, 1].min(), uv[:, 1].max())


def _job(
    dem: DemSource,
    views: tuple[ImageSource, ...],
    index: int,
    window: WindowT,
    margin: int,
    options: FitOptions,
    spacing: float,
) -> tuple[FitJob, list, list]:
    """Plan one tile: the job, and per view the fit window's image box (where its posts
    appear, for the error when a view sees nothing) and occluder halo (None where not
    computed)."""
    to_dem = _identity
    fit = _grow(window, margin, dem.shape)
    boxes: list = [None] * len(views)
    halos: list = [None] * len(views)
    need = footprint(dem, to_dem, fit, True)
    seen = []
    for k, view in enumerate(views):
        boxes[k] = image_box(dem, to_dem, fit, view.camera)
        if _sees(boxes[k], view):
            seen.append(k)
    if len(seen) < 2:
        return FitJob(index, window, None, None, (), ()), boxes, halos
    reach = options.hwin << (options.levels - 1)
    images = []
    for k in seen:
        view = views[k]
        halos[k] = tile_halo(dem, to_dem, fit, view.camera)
        need = _union(need, halos[k].window)
        box = patch_box(dem, fit, view.camera, reach, reach * spacing)
        images.append(window_for(box, view.camera, (view.width, view.height), options.levels))
    return FitJob(index, window, fit, need, tuple(seen), tuple(images)), boxes, halos


def _identity(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The DEM's grid is the output grid."""
    return np.asarray(c, dtype=np.float64), np.asarray(r, dtype=np.float64)


def plan_fit(
    dem: str | Path,
    views: Sequence[tuple[str | Path, str | Path | Camera]],
    options: FitOptions | None = None,
    *,
    tile: int | None = None,
    eps: float | None = None,
    dem_crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = "auto",
    progress: bool = True,
    vertical_datum: str = "auto",
    height_offset: float | None = None,
) -> FitPlan:
    """Plan the MVP fit (:func:`orthomvp.mvp.fit_dem` with ``options``) of the DEM at path
    ``dem`` from ``views`` ((image path, camera or camera path) pairs, at least 2), in tiles
    of ``tile`` x ``tile`` posts of the DEM's grid (default :data:`~orthomvp.engine.tiling.TILE`:
    a fit tile's margin is too wide for smaller ones); ``eps`` (DEM posts), ``dem_crs``,
    ``radius_values``, ``world``, ``vertical_datum`` and ``height_offset`` as for
    :func:`~orthomvp.engine.plan_ortho`. The fitted heights are those the cameras need: in
    the DEM's vertical datum, written under its whole CRS, when they are the file's (the map
    frame), else under its horizontal CRS (:meth:`~orthomvp.engine.grid.DemSource.heights_crs`).

    ``progress``: progress bars (or log lines) and notes on stderr, here and, by default, in
    :func:`~orthomvp.engine.run_fit`; False prints nothing.

    Reads the DEM once in blocks, each image twice in blocks (its statistics), and the
    cameras. Raises InputError for bad options and GeometryError when fewer than 2 images see
    the DEM (those that see none are left out, with a
    :class:`~orthomvp.errors.LeftOutWarning`); warns (:class:`~orthomvp.engine.HaloWarning`)
    when a camera's occluder halo is larger than the DEM.
    """
    dem = dem_path(dem)
    of_type(options, (FitOptions, type(None)), "options", " (FitOptions)")
    opts = options or FitOptions()
    tile = check_tile(tile) or TILE
    eps = eps_posts(eps)
    dem_reading(
        radius_values=radius_values,
        world=world,
        progress=progress,
        vertical_datum=vertical_datum,
        height_offset=height_offset,
        dem_crs=dem_crs,
    )
    opts.window  # noqa: B018 - validates hwin and sigma
    if opts.levels < 1 or opts.deconvolve < 0 or opts.max_iter < 1:
        raise InputError("levels and max_iter must be at least 1, deconvolve at least 0")
    sources = tuple(image_source(image, camera) for image, camera in view_pairs(views, 2))
    heights = HeightOptions(vertical_datum, height_offset)
    source, sources = read_source(dem, sources, dem_crs, radius_values, world, progress, heights)
    grid = output_grid(source)
    asked = opts.levels
    spacing = source.post_spacing()
    margin = opts.deconvolve * opts.hwin

    def planned(levels: int) -> tuple[FitOptions, list, list, list, list, list[bool]]:
        """The tiles with a pyramid of ``levels``, and which images see the DEM."""
        o = replace(opts, levels=levels)
        jobs, boxes, reach, elevation = plan_tiles(
            grid.tiles(tile),
            lambda index, window: _job(source, sources, index, window, margin, o, spacing),
            len(sources),
            progress,
        )
        seen = [any(_sees(box, view) for box in boxes[k]) for k, view in enumerate(sources)]
        return o, jobs, boxes, reach, elevation, seen

    opts, jobs, boxes, reach, elevation, seen = planned(
        levels_for(min(min(v.width, v.height) for v in sources), asked)
    )
    kept = [view for view, s in zip(sources, seen, strict=True) if s]
    if kept and len(kept) < len(sources):  # the images left out do not limit the pyramid
        levels = levels_for(min(min(v.width, v.height) for v in kept), asked)
        again = planned(levels) if levels != opts.levels else None
        if again is not None and again[-1] == seen:  # (else one more sees it: the first plan)
            opts, jobs, boxes, reach, elevation, seen = again
    levels = opts.levels
    if asked > max(levels, FitOptions().levels):  # (the default adapts in silence)
        side = min(min(sources[k].width, sources[k].height) for k, s in enumerate(seen) if s)
        warnings.warn(
            f"--levels {asked}: the smallest image that sees the DEM ({side} px a side) holds "
            f"{levels} pyramid level(s) of at least {MIN_LEVEL_SIZE} px; fitting with {levels}",
            OrthoMVPWarning,
            stacklevel=3,
        )
    if sum(seen) == 1:  # (none: check_plan says why)
        raise GeometryError(
            f"only 1 of the {len(sources)} images sees the DEM ({sources[seen.index(True)].path}): "
            "a fit needs 2"
        )
    check_plan(source, sources, boxes, seen, reach, elevation)
    used = sorted({k for job in jobs for k in job.views})
    stats: list[tuple[float, tuple[float, ...]]] = [(0.0, (1.0,) * levels)] * len(sources)
    rows = 2 * sum(sources[k].height for k in used)
    with Progress("reading the images' statistics", progress, rows, unit="row") as bar:
        for k in used:
            view = sources[k]
            stats[k] = view_statistics(
                lambda w, v=view: v.read(w, band=1)[0],
                view.camera,
                (view.width, view.height),
                levels,
                progress=bar.update,
            )
    return FitPlan(
        source,
        grid,
        sources,
        tuple(stats),
        tuple(jobs),
        tile,
        opts,
        eps,
        spacing,
        margin,
        tuple(reach),
        tuple(elevation),
        progress,
    )


def plan_tiles(
    windows: list[WindowT],
    job: Callable[[int, WindowT], tuple[Any, list[Box | None], list[Halo | None]]],
    views: int,
    progress: bool,
) -> tuple[list[Any], list[list[Box | None]], list[float], list[float]]:
    """Run ``job(index, window)`` for every tile window: the jobs, per view the image box of
    every tile, and per view the farthest occluder track (DEM posts) and the lowest line of
    sight (degrees) over all tiles."""
    jobs: list[Any] = []
    boxes: list[list[Box | None]] = [[] for _ in range(views)]
    reach, elevation = [0.0] * views, [90.0] * views
    with Progress("planning tiles", progress, len(windows)) as bar:
        for index, window in enumerate(windows):
            tile_job, tile_boxes, halos = job(index, window)
            jobs.append(tile_job)
            for k, (box, halo) in enumerate(zip(tile_boxes, halos, strict=True)):
                boxes[k].append(box)
                if halo is not None:
                    reach[k] = max(reach[k], halo.reach)
                    elevation[k] = min(elevation[k], halo.elevation)
            bar.update()
    return jobs, boxes, reach, elevation
