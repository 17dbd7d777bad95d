"""The MVP fit through the engine: a plan of tiles on the DEM's own grid, each fitted from
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

import gc
import math
import tempfile
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from rasterio.enums import Resampling

from orthomvp.camera import NullDistortion, PinholeCamera
from orthomvp.codes import Code, WorldFrame
from orthomvp.engine.grid import DemSource, OutputGrid, WindowT, output_grid, scan_dem
from orthomvp.engine.grid import with_world as dem_with_world
from orthomvp.engine.halo import footprint, image_box, perimeter, tile_halo
from orthomvp.engine.images import ImageSource, image_source
from orthomvp.engine.plan import (
    BASE_BYTES,
    MESH_BYTES,
    WINDOW_BYTES,
    HaloWarning,
    _no_overlap,
    _sees,
    _union,
)
from orthomvp.engine.plan import _frame as world_frame
from orthomvp.engine.progress import Progress
from orthomvp.engine.run import (
    GDAL_CACHE,
    check_memory,
    check_views,
    executor,
    results,
    workers_of,
)
from orthomvp.engine.tile import GC_POSTS, _has_cell, _release, _timed
from orthomvp.engine.writer import COMPRESSIONS, FORMATS, Layer, output_files
from orthomvp.errors import GeometryError, InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.mvp.fit import TILE as BATCH
from orthomvp.mvp.problem import levels_for
from orthomvp.mvp.views import ViewWindow, covers, exact_masks, union, view_statistics, window_for
from orthomvp.raycast import RayCaster
from orthomvp.visibility import compute_visibility
from orthomvp.world import check_cameras_above, detect_world

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
    ``reach`` and ``elevation`` of the occluder halos (as :class:`~orthomvp.engine.Plan`)."""

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

    @property
    def levels(self) -> int:
        return self.options.levels

    def tile_bytes(self, job: FitJob, threads: int = 1) -> int:
        """Expected peak memory of one tile in a worker with ``threads`` threads, bytes."""
        if job.dem is None:
            return 0
        k = len(job.views)
        posts = _posts(_grow(job.fit, 1, self.grid.shape))
        pixels = sum(_posts(w) for w in job.images)
        side = 2 * self.options.hwin + 1
        batch = BATCH_SAMPLE_BYTES * BATCH * BATCH * k * side * side * max(threads, 1)
        return (
            (WINDOW_BYTES + MESH_BYTES) * job.dem_posts
            + (FIT_POST_BYTES + FIT_VIEW_BYTES * k) * posts
            + PIXEL_BYTES * pixels
            + batch
        )

    def peak_memory(self, workers: int, processes: int = 0, threads: int = 1) -> int:
        """Expected peak memory of a run with ``workers`` tiles at a time (each with
        ``threads`` threads) and ``processes`` worker processes besides this one, bytes."""
        sizes = sorted((self.tile_bytes(job, threads) for job in self.tiles), reverse=True)
        return (1 + processes) * BASE_BYTES + sum(sizes[:workers])

    def summary(self, peak: int, workers: int) -> str:
        """One line: grid size, tiles, images, the largest windows and the expected ``peak``
        memory (bytes) with ``workers`` tiles at a time."""
        rows, cols = self.grid.shape
        run = [job for job in self.tiles if job.views]
        biggest = max(run, key=lambda job: job.dem_posts, default=None)
        windows = ""
        if biggest is not None and biggest.dem is not None:
            r0, r1, c0, c1 = biggest.dem
            r0_, r1_, c0_, c1_ = max((w for job in run for w in job.images), key=_posts)
            windows = (
                f", DEM windows up to {c1 - c0:,} x {r1 - r0:,} posts, image windows up to "
                f"{c1_ - c0_:,} x {r1_ - r0_:,} px"
            )
        return (
            f"plan: fit {cols:,} x {rows:,} posts, {len(run)} of {len(self.tiles)} tiles of "
            f"{self.tile} x {self.tile} to run, {len(self.views)} images, {self.levels} "
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


def _undistorted(camera: PinholeCamera) -> PinholeCamera:
    return replace(camera, distortion=NullDistortion())


def patch_box(
    dem: DemSource, window: WindowT, camera: PinholeCamera, reach: int, slack: float
) -> tuple[float, float, float, float]:
    """Where the patches of the posts of ``window`` may fall in the image without lens
    distortion: the bounding box (c0, c1, r0, r1) of the projections of the window grown by
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
    views: Sequence[tuple[str | Path, str | Path | PinholeCamera]],
    options: FitOptions | None = None,
    *,
    tile: int = 1024,
    eps: float | None = None,
    dem_crs: object | None = None,
    radius_values: bool = False,
    world: WorldFrame | str = "auto",
    progress: bool = True,
) -> FitPlan:
    """Plan the MVP fit (:func:`orthomvp.mvp.fit_dem` with ``options``) of the DEM at path
    ``dem`` from ``views`` ((image path, camera or camera path) pairs, at least 2), in tiles
    of ``tile`` x ``tile`` posts of the DEM's grid; ``eps`` (DEM posts), ``dem_crs``,
    ``radius_values`` and ``world`` as for :func:`~orthomvp.engine.plan_ortho`.

    Reads the DEM once in blocks, each image twice in blocks (its statistics), and the
    cameras. Raises InputError for bad options and GeometryError when an image sees none of
    the DEM; warns (:class:`~orthomvp.engine.HaloWarning`) when a camera's occluder halo is
    larger than the DEM.
    """
    opts = options or FitOptions()
    if isinstance(tile, bool) or not isinstance(tile, int | np.integer) or tile < 2:
        raise InputError(f"tile must be an integer of at least 2 posts, got {tile!r}")
    if eps is not None and not eps > 0:
        raise InputError(f"eps must be a positive number of DEM posts, got {eps}")
    opts.window  # noqa: B018 - validates hwin and sigma
    if opts.levels < 1 or opts.deconvolve < 0 or opts.max_iter < 1:
        raise InputError("levels and max_iter must be at least 1, deconvolve at least 0")
    if len(views) < 2:
        raise InputError(
            f"got {len(views)} images and {len(views)} cameras: this needs at least 2 images, "
            "each with its camera"
        )
    frame = world_frame(world)
    sources = tuple(image_source(image, camera) for image, camera in views)
    with Progress("reading the DEM's heights", progress, unit="row") as bar:
        source = scan_dem(dem, dem_crs, radius_values, progress=bar)
    if frame is None:
        frame = detect_world(source.preview, np.array([v.camera.center for v in sources]))
    source = dem_with_world(source, frame)
    check_cameras_above(source.preview, np.array([v.camera.center for v in sources]))
    grid = output_grid(source)
    levels = levels_for(min(min(v.width, v.height) for v in sources), opts.levels)
    opts = replace(opts, levels=levels)
    spacing = source.post_spacing()
    margin = opts.deconvolve * opts.hwin
    windows = grid.tiles(int(tile))
    jobs, boxes = [], [[] for _ in sources]
    reach, elevation = [0.0] * len(sources), [90.0] * len(sources)
    with Progress("planning tiles", progress, len(windows)) as bar:
        for index, window in enumerate(windows):
            job, tile_boxes, halos = _job(source, sources, index, window, margin, opts, spacing)
            jobs.append(job)
            for k, (box, halo) in enumerate(zip(tile_boxes, halos, strict=True)):
                boxes[k].append(box)
                if halo is not None:
                    reach[k] = max(reach[k], halo.reach)
                    elevation[k] = min(elevation[k], halo.elevation)
            bar.update()
    for k, view in enumerate(sources):
        if not any(_sees(box, view) for box in boxes[k]):
            raise GeometryError(_no_overlap(view, boxes[k], source))
        if reach[k] > max(source.shape):
            warnings.warn(
                f"{view.path}: lines of sight as low as {elevation[k]:.1f} degrees above the "
                f"horizon can be blocked by terrain up to {reach[k]:,.0f} DEM posts away, more "
                f"than the DEM's {max(source.shape):,} posts: every tile reads and meshes most "
                "of the DEM, so memory grows with it (results stay correct)",
                HaloWarning,
                stacklevel=2,
            )
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
        int(tile),
        opts,
        eps,
        spacing,
        margin,
        tuple(reach),
        tuple(elevation),
    )


# ------------------------------------------------------------------------------ per tile
@dataclass
class FitTile:
    """A finished tile of the fit, on its ``window`` of the DEM grid: ``heights`` float32
    (NaN where unresolved), ``normals`` (3, rows, cols) float32 n_theta, n_phi and the tilt
    from the local vertical (degrees), ``cost`` float32, ``views`` uint8, ``uncertainty``
    (2, rows, cols) float32 sigma_h and the converged flag (NaN where unresolved); for the
    summary, ``fitted`` and ``converged`` counts, ``shift`` (heights minus the input) and
    ``sigma`` (the finite sigma_h) of the fitted posts as float64; per view the posts
    ``inside`` the image and those ``seen`` (visible or occluded); ``refits``: times the
    tile was fitted again with grown image windows; ``seconds`` per phase."""

    index: int
    window: WindowT
    heights: np.ndarray
    normals: np.ndarray
    cost: np.ndarray
    views: np.ndarray
    uncertainty: np.ndarray
    fitted: int = 0
    converged: int = 0
    shift: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inside: list[int] = field(default_factory=list)
    seen: list[int] = field(default_factory=list)
    refits: int = 0
    seconds: dict[str, float] = field(default_factory=dict)


def empty_tile(plan: FitPlan, job: FitJob) -> FitTile:
    """The result of a tile with nothing fitted."""
    r0, r1, c0, c1 = job.window
    shape = (r1 - r0, c1 - c0)
    n = len(plan.views)
    return FitTile(
        job.index,
        job.window,
        np.full(shape, np.nan, np.float32),
        np.full((3, *shape), np.nan, np.float32),
        np.full(shape, np.nan, np.float32),
        np.zeros(shape, np.uint8),
        np.full((2, *shape), np.nan, np.float32),
        inside=[0] * n,
        seen=[0] * n,
    )


def run_fit_tile(plan: FitPlan, index: int, threads: int = 1, progress: bool = False) -> FitTile:
    """Fit tile ``index`` of ``plan`` with ``threads`` threads (``progress``: the fitter's
    own bar over its batches). Frees its memory as :func:`~orthomvp.engine.tile.run_tile`."""
    try:
        return _run_fit_tile(plan, index, threads, progress)
    finally:
        if plan.tiles[index].dem_posts >= GC_POSTS:
            gc.collect()
            _release()


def _sub(window: WindowT, within: WindowT) -> tuple[slice, slice]:
    """Slices of ``window`` in an array of ``within``."""
    r0, r1, c0, c1 = window
    return slice(r0 - within[0], r1 - within[0]), slice(c0 - within[2], c1 - within[2])


def _run_fit_tile(plan: FitPlan, index: int, threads: int, progress: bool) -> FitTile:
    job = plan.tiles[index]
    result = empty_tile(plan, job)
    if job.dem is None or job.fit is None:
        return result
    seconds = result.seconds
    with _timed(seconds, "read"):
        values = plan.dem.read(job.dem)
    ext = _grow(job.fit, 1, plan.grid.shape)
    assert ext is not None
    if not _has_cell(np.isfinite(values)) or not np.isfinite(values[_sub(ext, job.dem)]).any():
        return result
    window = plan.dem.window_terrain(job.dem, values)
    terrain = plan.dem.window_terrain(ext, values[_sub(ext, job.dem)])
    inner, fit = _sub(job.window, ext), _sub(job.fit, ext)
    with _timed(seconds, "mesh"):
        caster = RayCaster(terrain_mesh(window), threads=threads)
    visible = np.zeros((len(job.views), *terrain.shape), bool)
    for i, k in enumerate(job.views):
        with _timed(seconds, "visibility"):
            vis = compute_visibility(
                terrain,
                plan.views[k].camera,
                eps=plan.eps,
                caster=caster,
                threads=threads,
                spacing=plan.spacing,
                strict=False,
            )
        codes = vis.codes[inner]
        result.inside[k] = int((codes != Code.NODATA).sum())
        result.seen[k] = int(np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).sum())
        visible[i][fit] = vis.codes[fit] == Code.VISIBLE
        del vis
    del caster, window, values
    if not (visible.sum(axis=0) >= 2).any():
        return result
    images = list(job.images)
    geometry = plan.dem.geometry()
    while True:
        windows = [
            ViewWindow(w, (plan.views[k].width, plan.views[k].height), *plan.stats[k])
            for k, w in zip(job.views, images, strict=True)
        ]
        with _timed(seconds, "read"):
            crops = [
                plan.views[k].read(w, band=1)[0] for k, w in zip(job.views, images, strict=True)
            ]
        with _timed(seconds, "fit"):
            res = fit_dem(
                terrain,
                crops,
                [plan.views[k].camera for k in job.views],
                plan.options,
                visible=visible,
                eps=plan.eps,
                progress=progress,
                threads=threads,
                windows=windows,
                spacing=plan.spacing,
                origin=(ext[2], ext[0]),
                geometry=geometry,
                strict=False,
            )
        del crops
        grown = _regrow(plan, job, windows, res.extents, result.refits)
        if grown is None:
            break
        images = grown
        result.refits += 1
    _fill(plan, result, res, terrain, geometry, ext, inner)
    return result


def _regrow(
    plan: FitPlan,
    job: FitJob,
    windows: list[ViewWindow],
    extents: list[np.ndarray] | None,
    refits: int,
) -> list[WindowT] | None:
    """None when every sampled position lay where the windows are exact, else the image
    windows grown to hold them (whole images after :data:`RETRIES` refits)."""
    assert extents is not None
    out, grown = [], False
    for i, (k, view) in enumerate(zip(job.views, windows, strict=True)):
        camera, size = plan.views[k].camera, view.size
        masks = exact_masks(view, camera, plan.levels)
        window = view.window
        for level in range(plan.levels):
            box = extents[level][i]
            finite = not np.isnan(box).any()
            if covers(view, masks, level, tuple(box), finite):
                continue
            grown = True
            if not finite or refits >= RETRIES:
                window = (0, size[1], 0, size[0])
                break
            s = 1 << level
            zero = (box[0] * s, (box[1] + 1) * s, box[2] * s, (box[3] + 1) * s)
            window = union(window, window_for(zero, camera, size, plan.levels))
        out.append(window)
    return out if grown else None


def _fill(
    plan: FitPlan,
    result: FitTile,
    res: Any,
    terrain: Any,
    geometry: Any,
    ext: WindowT,
    inner: tuple[slice, slice],
) -> None:
    """The tile's arrays and counts from the fit ``res`` of the fit grid ``ext``."""
    heights = res.heights[inner]
    ok = np.isfinite(heights)
    c, r = terrain.grid()
    c, r = c[inner] + ext[2], r[inner] + ext[0]
    p = geometry.to_world(c, r, terrain.values[inner])
    up = geometry.up_vectors(p)
    normals = res.normals[inner]
    tilt = np.degrees(np.arccos(np.clip(np.sum(normals * up, axis=-1), -1, 1)))
    result.heights = heights.astype(np.float32)
    result.normals = np.stack([res.n_theta[inner], res.n_phi[inner], tilt]).astype(np.float32)
    result.cost = res.cost[inner].astype(np.float32)
    result.views = res.views[inner].astype(np.uint8)
    converged = res.converged[inner]
    result.uncertainty = np.stack([res.sigma_h[inner], np.where(ok, converged, np.nan)]).astype(
        np.float32
    )
    result.fitted = int(ok.sum())
    result.converged = int(converged.sum())
    result.shift = heights[ok] - res.initial[inner][ok]
    sigma = res.sigma_h[inner][ok]
    result.sigma = sigma[np.isfinite(sigma)]


# ------------------------------------------------------------------------------ outputs
@dataclass(frozen=True)
class FitOutputs:
    """What a fit writes, on the DEM's grid: ``heights`` (float32, NaN where fewer than 2
    views see a post) and, when given, ``normals`` (3 bands float32: n_theta_deg, n_phi_deg,
    tilt_deg), ``cost`` (float32, eq. 20), ``views`` (uint8, views used) and ``uncertainty``
    (2 bands float32: sigma_h_m, converged 0/1), NaN where unresolved; ``format``,
    ``compress`` and ``blocksize`` as for :class:`~orthomvp.engine.Outputs`."""

    heights: str | Path
    normals: str | Path | None = None
    cost: str | Path | None = None
    views: str | Path | None = None
    uncertainty: str | Path | None = None
    format: str = "cog"
    compress: str = "deflate"
    blocksize: int = 512

    def __post_init__(self) -> None:
        for name, value, allowed in (
            ("format", self.format, FORMATS),
            ("compression", self.compress, COMPRESSIONS),
        ):
            if value not in allowed:
                raise InputError(
                    f"output {name} must be one of {', '.join(allowed)}, not {value!r}"
                )
        if self.blocksize < 16 or self.blocksize % 16:
            raise InputError(f"block size must be a multiple of 16 pixels, got {self.blocksize}")

    def layers(self) -> list[Layer]:
        """The files to write."""
        f32, avg, near = "float32", Resampling.average, Resampling.nearest
        specs = [
            ("heights", 1, f32, np.nan, avg, ()),
            ("normals", 3, f32, np.nan, near, ("n_theta_deg", "n_phi_deg", "tilt_deg")),
            ("cost", 1, f32, np.nan, avg, ()),
            ("views", 1, "uint8", None, near, ()),
            ("uncertainty", 2, f32, np.nan, near, ("sigma_h_m", "converged")),
        ]
        return [
            Layer(Path(path), n, dtype, nodata, resampling, _getter(name), names)
            for name, n, dtype, nodata, resampling, names in specs
            if (path := getattr(self, name)) is not None
        ]


def _getter(name: str) -> Any:
    return lambda result: getattr(result, name)


class Median:
    """The median of a stream of float64 values, as :func:`numpy.median` gives it, in bounded
    memory: up to ``budget`` values are kept in memory; beyond, all go to a temporary file
    (in ``folder``) and the middle ones are selected in passes over it, 16 bits of their
    sort keys at a time. Use as a context manager (the file is removed on exit)."""

    def __init__(self, budget: int = 1 << 23, folder: str | Path | None = None):
        self.budget, self.folder = budget, folder
        self.parts: list[np.ndarray] = []
        self.count = 0
        self.file: Any = None

    def __enter__(self) -> Median:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None

    def add(self, values: np.ndarray) -> None:
        values = np.asarray(values, np.float64).ravel()
        if not len(values):
            return
        self.count += len(values)
        if self.file is None and self.count <= self.budget:
            self.parts.append(values)
            return
        if self.file is None:
            self.file = tempfile.TemporaryFile(dir=self.folder)
            for part in self.parts:
                part.tofile(self.file)
            self.parts = []
        values.tofile(self.file)

    def value(self) -> float:
        """The median (NaN without values)."""
        if not self.count:
            return math.nan
        n = self.count
        ranks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        if self.file is None:
            return float(np.median(np.concatenate(self.parts)))
        picked = [self._select(rank) for rank in ranks]
        return picked[0] if len(picked) == 1 else float(np.mean(picked))

    def _chunks(self) -> Any:
        self.file.flush()
        self.file.seek(0)
        step = max(self.budget // 4, 1 << 16)
        while True:
            chunk = np.fromfile(self.file, np.float64, step)
            if not len(chunk):
                return
            yield chunk

    @staticmethod
    def _keys(values: np.ndarray) -> np.ndarray:
        """Unsigned keys in the order of the values (negative values' bits flipped)."""
        bits = values.view(np.uint64)
        sign = bits >> np.uint64(63)
        return np.where(sign == 1, ~bits, bits | np.uint64(1 << 63))

    def _select(self, rank: int) -> float:
        """The value of 0-based ``rank`` in sorted order, in passes over the file: each pass
        narrows the candidates to those whose keys share 16 more leading bits, until they
        fit in the budget (or are all equal)."""
        prefix, shift = 0, 64  # candidates: keys whose leading 64 - shift bits are prefix
        while True:
            counts = np.zeros(1 << 16, np.int64)
            inside = 0
            for keys in self._candidates(prefix, shift):
                inside += len(keys)
                if shift:
                    counts += np.bincount(
                        ((keys >> np.uint64(shift - 16)) & np.uint64(0xFFFF)).astype(np.int64),
                        minlength=1 << 16,
                    )
            if inside <= self.budget or not shift:
                break
            cumulative = np.cumsum(counts)
            b = int(np.searchsorted(cumulative, rank, side="right"))
            rank -= int(cumulative[b - 1]) if b else 0
            prefix, shift = (prefix << 16) | b, shift - 16
        if not shift:  # every candidate has the same key: the same value
            return self._value(prefix)
        values = np.concatenate(
            [chunk[self._match(self._keys(chunk), prefix, shift)] for chunk in self._chunks()]
        )
        return float(np.partition(values, rank)[rank])

    @staticmethod
    def _value(key: int) -> float:
        """The value of a key (inverse of :meth:`_keys`)."""
        k = np.array([key], np.uint64)
        bits = k ^ np.uint64(1 << 63) if key >> 63 else ~k
        return float(bits.view(np.float64)[0])

    @staticmethod
    def _match(keys: np.ndarray, prefix: int, shift: int) -> np.ndarray:
        """Which ``keys`` have the leading bits ``prefix`` (all of them when ``shift`` is 64)."""
        if shift >= 64:
            return np.ones(len(keys), bool)
        return (keys >> np.uint64(shift)) == np.uint64(prefix)

    def _candidates(self, prefix: int, shift: int) -> Any:
        for chunk in self._chunks():
            keys = self._keys(chunk)
            yield keys[self._match(keys, prefix, shift)]


@dataclass
class FitReport:
    """What a fit did: tiles run and skipped, wall-clock seconds, the workers' seconds per
    phase (read, mesh, visibility, fit) and the writer's (write); the DEM's ``posts``, those
    ``fitted`` and ``converged``; the change of the fitted heights from the input (median
    and RMS) and the median 1-sigma uncertainty; ``refits``: tiles fitted again with grown
    image windows."""

    tiles_run: int = 0
    tiles_skipped: int = 0
    seconds: float = 0.0
    phases: dict[str, float] = field(default_factory=dict)
    posts: int = 0
    fitted: int = 0
    converged: int = 0
    median_shift: float = math.nan
    rms_shift: float = math.nan
    median_sigma: float = math.nan
    refits: int = 0

    def line(self, output: str | Path) -> str:
        """The one-line summary that ``orthomvp fit`` prints."""
        return (
            f"wrote {output}: {self.fitted:,} of {self.posts:,} posts fitted "
            f"({self.converged:,} converged); change from the input: median "
            f"{self.median_shift:+.2f}, RMS {self.rms_shift:.2f}; median uncertainty "
            f"{self.median_sigma:.2f}"
        )


def run_fit(
    plan: FitPlan,
    outputs: FitOutputs,
    *,
    threads: int | None = None,
    processes: int | None = None,
    client: Any = None,
    progress: bool = True,
    inflight: int | None = None,
) -> FitReport:
    """Fit every tile of ``plan`` and write ``outputs`` (all of them, or none).

    Tiles run in ``threads`` threads (default one per core), or ``processes`` worker
    processes, or on the Dask ``client``, at most ``inflight`` (default twice the workers)
    at a time; with fewer tiles than threads each tile fits with several threads (and, alone,
    shows the fitter's own progress). Raises InputError before any work when the expected
    peak memory exceeds what is available, GeometryError (writing nothing) when no post is
    visible in 2 or more images or an image sees only posts facing away, WorkerError
    (writing nothing) when a worker dies.
    """
    workers = workers_of(threads, processes, client)
    if inflight is not None and inflight < 1:
        raise InputError(f"inflight must be at least 1, got {inflight}")
    jobs = [job.index for job in plan.tiles if job.views]
    at_once = min(workers, max(len(jobs), 1))
    local = client is None and not processes
    inner = max(1, workers // max(len(jobs), 1)) if local else 1
    peak = check_memory(plan, plan.peak_memory(at_once, processes or 0, inner), at_once)
    start = time.perf_counter()
    rows, cols = plan.grid.shape
    report = FitReport(posts=rows * cols)
    inside, seen = [0] * len(plan.views), [0] * len(plan.views)
    squares = 0.0
    pool = executor(plan, run_fit_tile, workers, processes, client)
    folder = Path(outputs.heights).parent
    with (
        Progress("fitting tiles", progress, len(plan.tiles)) as bar,
        pool as (submit, wait),
        Median(folder=folder) as shifts,
        Median(folder=folder) as sigmas,
    ):
        bar.note(plan.summary(peak, at_once))
        args = (inner, bool(progress and local and at_once == 1))
        with (
            rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE),
            output_files(plan.grid, outputs.layers(), outputs) as writer,
        ):
            for job in plan.tiles:
                if not job.views:
                    writer.write(empty_tile(plan, job))
                    report.tiles_skipped += 1
                    bar.update()
            for result in results(submit, wait, jobs, args, inflight or 2 * workers):
                t0 = time.perf_counter()
                writer.write(result)
                report.phases["write"] = report.phases.get("write", 0.0) + (
                    time.perf_counter() - t0
                )
                report.tiles_run += 1
                for phase, seconds in result.seconds.items():
                    report.phases[phase] = report.phases.get(phase, 0.0) + seconds
                report.fitted += result.fitted
                report.converged += result.converged
                report.refits += result.refits
                squares += float(np.sum(result.shift**2))
                shifts.add(result.shift)
                sigmas.add(result.sigma)
                inside = [a + b for a, b in zip(inside, result.inside, strict=True)]
                seen = [a + b for a, b in zip(seen, result.seen, strict=True)]
                bar.update()
            # views seen in some tile, only facing away (views that no tile fits are not
            # known to be inside: the plan checked that each one sees the DEM)
            tried = [k for k, n in enumerate(inside) if n]
            check_views([plan.views[k] for k in tried], [1] * len(tried), [seen[k] for k in tried])
            if not report.fitted:
                raise GeometryError("no post is visible in 2 or more images: nothing to fit")
        report.median_shift = shifts.value()
        report.median_sigma = sigmas.value()
    report.rms_shift = math.sqrt(squares / report.fitted)
    report.seconds = time.perf_counter() - start
    return report
