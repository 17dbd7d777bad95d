"""One tile of a plan, start to finish, in whatever worker runs it: read the DEM window, mesh
it, classify the tile's posts for each view, sample only the image windows they fall in, and
return the tile's arrays. Nothing outlives the call but the result.

The tile's posts are classified with one post around them (the border), so that surface
normals are the same central differences as on the whole grid; the border is cut off again.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np

from orthomvp.codes import Code, Interp
from orthomvp.engine import heap
from orthomvp.engine.grid import WindowT, grid_to_dem
from orthomvp.engine.images import ImageSource
from orthomvp.engine.plan import IMAGE_MARGIN, SAMPLE_BUDGET_PIXELS, Plan, TileJob, pixel_window
from orthomvp.engine.support_samples import SupportSamples
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import column_range, finite_rows
from orthomvp.occlusion.occluders import Occluders
from orthomvp.occlusion.paths import VisibilityPath
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.occlusion.visibility import Visibility, compute_visibility
from orthomvp.ortho.balance import Correction
from orthomvp.ortho.composite import compose, doubtful, nadir_angle
from orthomvp.ortho.holes import FLAGS
from orthomvp.ortho.orthophoto import OUTSIDE, sample_image
from orthomvp.ortho.support import Support, candidates, clear_blend, clear_taps
from orthomvp.ortho.support import blocked as support_blocked


@dataclass
class TileResult:
    """A finished tile: ``window`` on the output grid; ``data`` (bands, rows, cols) float32
    (NaN where empty), ``codes`` (views, rows, cols) uint8, ``source`` (layers, rows, cols):
    the 1-based view of each post (0 = none), and for a mosaic its
    :class:`~orthomvp.ortho.composite.Flag` and every view's blend weight in 1/255 (see
    :func:`source_layers`), each None unless asked for. ``inside`` and ``seen`` count, per view,
    the posts inside the image and those visible or occluded; ``counts`` per view the posts of
    each :class:`~orthomvp.codes.Code`; ``valid`` the tile's posts with a height (for a tile
    that no image sees: all of them, unread); ``seconds`` per phase (read, mesh, visibility,
    sample, compose); ``stack`` (kind "stack" of a mosaic plan) every view's samples (views,
    bands, rows, cols) and codes (views, rows, cols), uncomposed; ``taken`` per view the posts
    whose value it gave (zeros unless values or sources were made); ``flags`` for a mosaic the
    posts of each :class:`~orthomvp.ortho.holes.Flag` value (0 ..
    :data:`~orthomvp.ortho.holes.FLAGS` - 1; all empty outside unless values or sources were
    made)."""

    index: int
    window: WindowT
    data: np.ndarray | None
    codes: np.ndarray | None
    source: np.ndarray | None
    inside: list[int]
    seen: list[int]
    counts: list[list[int]]
    valid: int
    seconds: dict[str, float] = field(default_factory=dict)
    stack: tuple[np.ndarray, np.ndarray] | None = None
    taken: list[int] = field(default_factory=list)
    flags: list[int] = field(default_factory=list)


@contextmanager
def _timed(seconds: dict[str, float], phase: str) -> Iterator[None]:
    start = time.perf_counter()
    yield
    seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - start


def empty_result(plan: Plan, job: TileJob, kinds: frozenset[str]) -> TileResult:
    """The result of a tile that no image sees: all nodata."""
    r0, r1, c0, c1 = job.window
    shape = (r1 - r0, c1 - c0)
    n = len(plan.views)
    return TileResult(
        job.index,
        job.window,
        np.full((plan.bands, *shape), np.nan, np.float32) if "ortho" in kinds else None,
        np.zeros((n, *shape), np.uint8) if "visibility" in kinds else None,
        np.zeros((source_layers(plan), *shape), source_dtype(plan)) if "source" in kinds else None,
        [0] * n,
        [0] * n,
        [[shape[0] * shape[1], 0, 0, 0] for _ in range(n)],
        shape[0] * shape[1],
        taken=[0] * n,
        flags=[shape[0] * shape[1]] + [0] * (FLAGS - 1) if plan.mosaic is not None else [],
    )


def source_layers(plan: Plan) -> int:
    """Bands of the source raster: the view; for a mosaic also the flag and one weight per
    view."""
    return 2 + len(plan.views) if plan.mosaic is not None else 1


def source_dtype(plan: Plan) -> type:
    """The source raster's data type (uint8 up to 254 views)."""
    return np.uint8 if len(plan.views) < 255 else np.uint16


def _has_cell(valid: np.ndarray) -> bool:
    """Whether any grid cell has four valid corners (something to mesh)."""
    return bool((valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]).any())


def _grid_tile(
    plan: Plan, job: TileJob, window: Terrain, posts: WindowT, fused: bool = False
) -> tuple[Terrain, tuple[slice, slice]]:
    """The grid window ``posts`` with one post around (within the grid) as a Terrain with
    heights taken from the DEM ``window`` (``fused``: by the numba kernel), and the slices of
    ``posts`` in it."""
    r0, r1, c0, c1 = posts
    rows, cols = plan.grid.shape
    ext = (max(r0 - 1, 0), min(r1 + 1, rows), max(c0 - 1, 0), min(c1 + 1, cols))
    inner = (slice(r0 - ext[0], r1 - ext[0]), slice(c0 - ext[2], c1 - ext[2]))
    w0, _, w2, _ = job.dem
    if plan.grid.on_dem:
        values = window.values[ext[0] - w0 : ext[1] - w0, ext[2] - w2 : ext[3] - w2]
    elif plan.grid.crs == plan.dem.crs:  # neither is rotated (both make Terrains, which
        # refuse it), so columns and rows map apart
        to_dem = grid_to_dem(plan.grid, plan.dem)
        dc, _ = to_dem(np.arange(ext[2], ext[3], dtype=np.float64), 0.0)
        _, dr = to_dem(0.0, np.arange(ext[0], ext[1], dtype=np.float64))
        if fused:
            from orthomvp.occlusion.post_geometry_kernel import interpolate_grid

            values = interpolate_grid(window, dc - w2, dr - w0)
        else:
            values = window.interpolate_grid(dc - w2, dr - w0)
    else:
        r, c = np.mgrid[ext[0] : ext[1], ext[2] : ext[3]].astype(np.float64)
        dc, dr = grid_to_dem(plan.grid, plan.dem)(c, r)
        values = window.interpolate(dc - w2, dr - w0)
    grid = plan.grid.georef(ext, window)
    return (grid.with_values(values) if np.isfinite(values).any() else None), inner


def _read_window(view: ImageSource, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image pixels around positions ``uv`` (n, 2) and the positions relative to them,
    shifted in float32 as :func:`~orthomvp.ortho.orthophoto.sample_image` uses them (exact, so every
    window samples exactly as the whole image would)."""
    window = pixel_window(view, *column_range(uv))
    shifted = uv.astype(np.float32) - np.array([window[2], window[0]], np.float32)
    return view.read(window), shifted


def _span(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Columns and rows of the image window that positions from ``low`` to ``high`` (u, v)
    sample, before clipping to the image (:func:`~orthomvp.engine.plan.pixel_window`)."""
    return np.floor(high) - np.floor(low) + 2 * IMAGE_MARGIN + 2


def sample_view(view: ImageSource, uv: np.ndarray, interp: str) -> np.ndarray:
    """Values (bands, n) float32 of the image at positions ``uv`` (n, 2), reading only the
    window they fall in; in pieces (split along the longer side) while a window would exceed
    :data:`~orthomvp.engine.plan.SAMPLE_BUDGET_PIXELS`."""
    low, high = column_range(uv)
    span = _span(low, high)
    if len(uv) > 1 and span[0] * span[1] > SAMPLE_BUDGET_PIXELS:
        order = np.argsort(uv[:, int(np.argmax(span))], kind="stable")
        half = len(uv) // 2
        out = np.empty((view.bands, len(uv)), np.float32)
        out[:, order[:half]] = sample_view(view, uv[order[:half]], interp)
        out[:, order[half:]] = sample_view(view, uv[order[half:]], interp)
        return out
    pixels, shifted = _read_window(view, uv)
    return sample_image(pixels, shifted, interp)


Prefetched = tuple[WindowT, "Future[np.ndarray]"]
"""An image window (r0, r1, c0, c1) being read in the background, and its pixels to come."""


@contextmanager
def _prefetch(plan: Plan, job: TileJob, threads: int) -> Iterator[dict[int, Prefetched]]:
    """With a spare thread (``threads`` > 1: fewer tiles than workers), each view's image
    window of the tile (:attr:`TileJob.image_windows`, within the sampling budget) read in
    the background while the tile meshes and classifies its posts; none otherwise."""
    if threads < 2 or not job.image_windows:
        yield {}
        return
    with ThreadPoolExecutor(1) as pool:
        reads = {}
        for k, window in zip(job.views, job.image_windows, strict=True):
            r0, r1, c0, c1 = window
            if 0 < (r1 - r0) * (c1 - c0) <= SAMPLE_BUDGET_PIXELS:
                reads[k] = (window, pool.submit(plan.views[k].read, window))
        try:
            yield reads
        finally:
            for _, future in reads.values():
                future.cancel()


def sample_grid(
    view: ImageSource,
    uv: np.ndarray,
    keep: np.ndarray,
    interp: str,
    prefetched: Prefetched | None = None,
    *,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Values (bands, rows, cols) float32 of the image at the positions ``uv`` (rows, cols, 2)
    where ``keep`` (rows, cols), NaN elsewhere: the same values as :func:`sample_view` of
    ``uv[keep]``, with the grid itself as the map of ``cv2.remap`` (no gathering of the kept
    positions, no scattering of their values). The pixels come from the ``prefetched`` window
    when it holds the window needed. ``out``: a C-contiguous float32 array (bands, rows, cols)
    to write the values into (and return)."""
    if out is None:
        out = np.empty((view.bands, *keep.shape), np.float32)
    if not keep.any():
        out.fill(np.nan)
        return out
    shifted = uv.astype(np.float32, order="C")  # the positions as sampled (float32; exact)
    mask = np.ascontiguousarray(keep).view(np.uint8)
    (u0, u1, _, _), (v0, v1, _, _) = (cv2.minMaxLoc(a, mask) for a in cv2.split(shifted))
    low, high = np.array([u0, v0]), np.array([u1, v1])
    span = _span(low, high)
    if span[0] * span[1] > SAMPLE_BUDGET_PIXELS:  # in pieces
        out.fill(np.nan)
        out[:, keep] = sample_view(view, uv[keep], interp)
        return out
    window = pixel_window(view, low, high)
    r0, r1, c0, c1 = window
    pixels = None
    if prefetched is not None:
        (p0, p1, q0, q1), future = prefetched
        if p0 <= r0 and r1 <= p1 and q0 <= c0 and c1 <= q1:
            pixels = future.result()[:, r0 - p0 : r1 - p0, c0 - q0 : c1 - q0]
    if pixels is None:
        pixels = view.read(window)
    # (u, v) as one complex64 a post: numpy's arithmetic over a last axis of 2 is slow
    maps = shifted.view(np.complex64)[..., 0]
    maps -= np.complex64(complex(c0, r0))  # each part in float32, as _read_window does
    np.copyto(maps, np.complex64(complex(OUTSIDE, OUTSIDE)), where=~keep)
    return sample_image(pixels, shifted, interp, out=out)


def run_tile(plan: Plan, index: int, kinds: frozenset[str], threads: int = 1) -> TileResult:
    """Run tile ``index`` of ``plan`` for the outputs ``kinds`` ("ortho": image values,
    "visibility": codes per view, "source": the mosaic's view per post, "stack": a mosaic's
    uncomposed samples), with ``threads`` threads for ray casting and visibility, inside
    :func:`orthomvp.engine.heap.tile_heap` (so that threads, processes and Dask workers run it
    at the same speed, and its memory goes back to the system)."""
    with heap.tile_heap(plan.tiles[index].dem_posts):
        return _run_tile(plan, index, kinds, threads)


def _run_tile(plan: Plan, index: int, kinds: frozenset[str], threads: int) -> TileResult:
    job = plan.tiles[index]
    result = empty_result(plan, job, kinds)
    if not job.views:
        return result
    seconds = result.seconds
    with _timed(seconds, "read"):
        values = plan.dem.read(job.dem)
    if not _has_cell(np.isfinite(values)):
        return result
    window = plan.dem.window_terrain(job.dem, values)
    if plan.mosaic is not None:
        return _mosaic_tile(plan, job, result, window, kinds, threads)
    grid, inner = _grid_tile(plan, job, window, job.window)
    if grid is None:
        return result
    caster = Occluders(window, threads=threads) if plan.occlusion else None
    result.valid = int(np.isfinite(grid.values[inner]).sum())
    best = np.full(grid.values[inner].shape, np.inf)
    label = np.zeros(best.shape, np.int64)  # the 1-based view each post came from, 0 none
    many = len(job.views) > 1  # then each post takes the view of least emission angle
    fields = frozenset({"emission"} if many else ())
    pixels = result.data is not None or result.source is not None  # (else none is read)
    with _prefetch(plan, job, threads if pixels else 1) as prefetched:
        for k in job.views:
            view = plan.views[k]
            with _timed(seconds, "visibility"):
                vis = _visibility(
                    plan, grid, k, caster, window, threads, fields, plan.visibility_path
                )
            codes, uv, emission = vis.codes[inner], vis.uv[inner], vis.emission[inner]
            _record_codes(result, k, codes)
            keep = codes == Code.VISIBLE if plan.occlusion else finite_rows(uv)
            if many:
                keep &= emission < best
            if pixels and keep.any():
                with _timed(seconds, "sample"):
                    values = sample_grid(view, uv, keep, plan.interp, prefetched.get(k))
                keep &= np.isfinite(values).all(axis=0)
                if result.data is not None:
                    np.copyto(result.data, values, where=keep)
            label[keep] = k + 1
            if many:
                best[keep] = emission[keep]
    _mesh_phase(seconds, caster)
    if result.source is not None:
        result.source[0] = label
    if result.data is not None or result.source is not None:
        result.taken = _taken(label, len(plan.views))
    return result


def _record_codes(result: TileResult, k: int, codes: np.ndarray) -> None:
    """View ``k``'s ``codes`` of the tile's posts into ``result``: its posts of each code,
    those inside the image and those seen (visible or occluded), and the codes themselves
    when they are an output."""
    counts = [int(np.count_nonzero(codes == code)) for code in Code]  # (5x bincount's speed)
    result.counts[k] = counts
    result.inside[k] = int(codes.size - counts[Code.NODATA])
    result.seen[k] = int(counts[Code.VISIBLE] + counts[Code.OCCLUDED])
    if result.codes is not None:
        result.codes[k] = codes


def _taken(label: np.ndarray, views: int) -> list[int]:
    """Posts per view in ``label`` (the 1-based view of each post, 0 none)."""
    return np.bincount(label.ravel(), minlength=views + 1)[1:].tolist()


def _visibility(
    plan: Plan,
    grid: Terrain,
    k: int,
    caster: Occluders | RayCaster | None,
    window: Terrain,
    threads: int,
    fields: frozenset[str],
    path: VisibilityPath,
) -> Visibility:
    """View ``k``'s visibility on ``grid`` (occluders from the DEM ``window``), with the
    optional ``fields`` of :func:`~orthomvp.occlusion.visibility.compute_visibility`, on the
    plan's ``path``."""
    return compute_visibility(
        grid,
        plan.views[k].camera,
        eps=plan.eps,
        caster=caster,
        occlusion=plan.occlusion,
        fields=fields,
        dem=window,
        post_scale=plan.post_scale,
        threads=threads,
        path=path,
    )


def _mesh_phase(seconds: dict[str, float], caster: Occluders | None) -> None:
    """Move the time spent meshing the occluders, at the first cast within a view's
    visibility, from the visibility phase to the mesh phase."""
    if caster is not None and caster.mesh_seconds:
        seconds["mesh"] = caster.mesh_seconds
        seconds["visibility"] -= caster.mesh_seconds


def _mosaic_tile(
    plan: Plan,
    job: TileJob,
    result: TileResult,
    window: Terrain,
    kinds: frozenset[str],
    threads: int,
) -> TileResult:
    """A mosaic tile: every view's samples, codes and angles on the tile grown by the plan's
    margin (:meth:`Plan.extent`), composed (:func:`orthomvp.ortho.composite.compose`), cut to the
    tile."""
    assert plan.mosaic is not None
    ext = plan.extent(job)
    grid, inner = _grid_tile(plan, job, window, ext, plan.fused)
    if grid is None:
        return result
    seconds, n = result.seconds, len(plan.views)
    r0, r1, c0, c1 = job.window
    core = (slice(r0 - ext[0], r1 - ext[0]), slice(c0 - ext[2], c1 - ext[2]))
    shape = (ext[1] - ext[0], ext[3] - ext[2])
    caster = Occluders(window, threads=threads) if plan.occlusion else None
    result.valid = int(np.isfinite(grid.values[inner][core]).sum())
    # the stacks hold the tile's views only, in the plan's order: the others see none of the
    # window, and compose gives what it gives with them (priority "order" depends only on the
    # views' order: ORDER_STEP outweighs every other cost)
    views = sorted(job.views)
    m = len(views)
    values = np.empty((m, plan.bands, *shape), np.float32)  # samples, NaN where none
    codes = np.zeros((m, *shape), np.uint8)
    holes, priority = plan.mosaic.holes, plan.mosaic.priority
    emission = np.full((m, *shape), np.inf)
    # GSD and nadir angles only where the options use them (else read-only infinities)
    use_gsd, use_nadir = priority == "gsd", priority == "nadir" or holes == "naive"
    none = np.broadcast_to(np.inf, (m, *shape))
    gsd = np.full((m, *shape), np.inf) if use_gsd else none
    nadir = np.full((m, *shape), np.inf) if use_nadir else none
    doubt = np.zeros((m, *shape), bool)
    # the doubtful posts' slack only for a hole policy that uses it (fill_holes)
    slack = np.zeros((m, *shape)) if holes != "empty" else None
    testing = caster is not None  # the support test (its samples: SupportSamples)
    kept: list[SupportSamples] = []
    fields = frozenset({"emission", "miss", "gsd"})
    for i, k in enumerate(views):
        with _timed(seconds, "visibility"):
            vis = _visibility(plan, grid, k, caster, window, threads, fields, plan.visibility_path)
        code, uv = vis.codes[inner], vis.uv[inner]
        inside = code != Code.NODATA  # (the posts with a pixel)
        if not plan.occlusion:
            code = np.where(inside, Code.VISIBLE, Code.NODATA).astype(np.uint8)
        _record_codes(result, k, code[core])
        codes[i], emission[i] = code, vis.emission[inner]
        if use_gsd:
            gsd[i] = vis.gsd[inner]
        doubt[i] = doubtful(vis.miss[inner], vis.eps[inner])
        if slack is not None:
            slack[i] = np.where(doubt[i], vis.eps[inner] - vis.miss[inner], 0.0)
        if testing:
            seen_i = code == Code.VISIBLE
            kept.append(
                SupportSamples.keep(seen_i & ~doubt[i], uv, vis.gsd[inner], seen_i & doubt[i])
            )
        if use_nadir:
            nadir[i] = np.where(inside, nadir_angle(grid, inner, plan.views[k].camera, uv), np.inf)
        need = code == Code.VISIBLE
        if holes == "behind":
            need |= code == Code.FACING_AWAY
        elif holes == "naive":
            need |= code != Code.NODATA
        wanted = result.data is not None or result.source is not None or "stack" in kinds
        if wanted and need.any():
            with _timed(seconds, "sample"):
                sample_grid(plan.views[k], uv, need, plan.interp, out=values[i])
        else:
            values[i].fill(np.nan)
    _mesh_phase(seconds, caster)
    if "stack" in kinds:  # every view's, as the survey takes them
        rows, cols = r1 - r0, c1 - c0
        every = np.full((n, plan.bands, rows, cols), np.nan, np.float32)
        every_codes = np.zeros((n, rows, cols), np.uint8)
        every[views] = values[:, :, core[0], core[1]]
        every_codes[views] = codes[:, core[0], core[1]]
        result.stack = (every, every_codes)
    if result.data is None and result.source is None:
        return result
    correction = plan.correction
    if correction is not None:
        correction = Correction(correction.gains[views], correction.offsets[views])
    blocked = np.zeros((m, *shape), bool)

    def test(posts: np.ndarray) -> np.ndarray:
        """Where the views' samples at ``posts`` (views, rows, cols) reach an occluder."""
        out = np.zeros(posts.shape, bool)
        for i, k in enumerate(views):
            if posts[i].any():
                camera = plan.views[k].camera
                ask = posts[i]
                out[i] = support_blocked(grid, inner, camera, kept[i].at, emission[i], ask, caster)
        return out

    def resample(posts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The samples (bands, posts) at ``posts`` (views, rows, cols) of their clear pixels,
        and those pixels' weights (posts,)."""
        taken, clear = [], []
        for i, k in enumerate(views):
            if posts[i].any():
                camera = plan.views[k].camera
                taps, w = clear_taps(grid, inner, camera, kept[i].at, emission[i], posts[i], caster)
                pixels = sample_view(plan.views[k], taps.reshape(-1, 2), Interp.NEAREST)
                value, weight = clear_blend(pixels.reshape(-1, *w.shape).swapaxes(0, 1), w)
                taken.append(value)
                clear.append(weight)
        return np.concatenate(taken, axis=1), np.concatenate(clear)

    support = None
    if testing:
        sure = (codes == Code.VISIBLE) & ~doubt
        support = Support(test, sure)
        with _timed(seconds, "visibility"):
            blocked = support(candidates(sure))
    with _timed(seconds, "compose"):
        comp = compose(
            values, codes, emission, gsd, nadir, plan.mosaic, correction, doubt,
            slack=slack, blocked=blocked, fused=plan.fused, support=support,
            resample=resample if support else None,
        )  # fmt: skip
    source = np.array([0, *(k + 1 for k in views)])[comp.source[core]]  # 1-based of all views
    result.taken = _taken(source, n)
    result.flags = np.bincount(comp.flags[core].ravel(), minlength=FLAGS).tolist()
    if result.data is not None:
        result.data = comp.data[:, core[0], core[1]]
    if result.source is not None:
        weights = np.zeros((n, *source.shape))
        weights[views] = np.rint(comp.weights[:, core[0], core[1]] * 255)
        layers = [source[None], comp.flags[core][None], weights]
        result.source = np.concatenate(layers).astype(source_dtype(plan))
    return result
