"""One tile of a plan, start to finish, in whatever worker runs it: read the DEM window, mesh
it, classify the tile's posts for each view, sample only the image windows they fall in, and
return the tile's arrays. Nothing outlives the call but the result.

The tile's posts are classified with one post around them (the border), so that surface
normals are the same central differences as on the whole grid; the border is cut off again.
"""

from __future__ import annotations

import ctypes
import gc
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from orthomvp.codes import Code
from orthomvp.engine.grid import WindowT, grid_to_dem
from orthomvp.engine.images import ImageSource
from orthomvp.engine.plan import IMAGE_MARGIN, SAMPLE_BUDGET_PIXELS, Plan, TileJob
from orthomvp.ortho import sample_image
from orthomvp.terrain import Terrain
from orthomvp.visibility import compute_visibility, occluder_caster

GC_POSTS = 1 << 15
"""DEM window posts from which a tile ends with a full garbage collection (see run_tile)."""


@dataclass
class TileResult:
    """A finished tile: ``window`` on the output grid; ``data`` (bands, rows, cols) float32
    (NaN where empty), ``codes`` (views, rows, cols) uint8, ``source`` (rows, cols) 1-based
    view index (0 = none), each None unless asked for. ``inside`` and ``seen`` count, per view,
    the posts inside the image and those visible or occluded; ``counts`` per view the posts of
    each :class:`~orthomvp.codes.Code`; ``valid`` the tile's posts with a height (for a tile
    that no image sees: all of them, unread); ``seconds`` per phase (read, mesh, visibility,
    sample)."""

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
        np.zeros(shape, np.uint8 if n < 256 else np.uint16) if "source" in kinds else None,
        [0] * n,
        [0] * n,
        [[shape[0] * shape[1], 0, 0, 0] for _ in range(n)],
        shape[0] * shape[1],
    )


def _has_cell(valid: np.ndarray) -> bool:
    """Whether any grid cell has four valid corners (something to mesh)."""
    return bool((valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]).any())


def _grid_tile(plan: Plan, job: TileJob, window: Terrain) -> tuple[Terrain, tuple[slice, slice]]:
    """The tile's posts with one around (within the grid) as a Terrain with heights taken from
    the DEM ``window``, and the slices of the tile itself in it."""
    r0, r1, c0, c1 = job.window
    rows, cols = plan.grid.shape
    ext = (max(r0 - 1, 0), min(r1 + 1, rows), max(c0 - 1, 0), min(c1 + 1, cols))
    inner = (slice(r0 - ext[0], r1 - ext[0]), slice(c0 - ext[2], c1 - ext[2]))
    w0, _, w2, _ = job.dem
    if plan.grid.on_dem:
        values = window.values[ext[0] - w0 : ext[1] - w0, ext[2] - w2 : ext[3] - w2]
    else:
        r, c = np.mgrid[ext[0] : ext[1], ext[2] : ext[3]].astype(np.float64)
        dc, dr = grid_to_dem(plan.grid, plan.dem)(c, r)
        values = window.interpolate(dc - w2, dr - w0)
    grid = plan.grid.georef(ext, window)
    return (grid.with_values(values) if np.isfinite(values).any() else None), inner


def _read_window(view: ImageSource, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image pixels around positions ``uv`` (n, 2) and the positions relative to them,
    shifted in float32 as :func:`~orthomvp.ortho.sample_image` uses them (exact, so every
    window samples exactly as the whole image would)."""
    lo, hi = np.floor(uv.min(axis=0)).astype(int), np.floor(uv.max(axis=0)).astype(int)
    c0, r0 = max(lo[0] - IMAGE_MARGIN, 0), max(lo[1] - IMAGE_MARGIN, 0)
    c1 = min(max(hi[0] + IMAGE_MARGIN + 2, c0 + 1), view.width)
    r1 = min(max(hi[1] + IMAGE_MARGIN + 2, r0 + 1), view.height)
    shifted = uv.astype(np.float32) - np.array([c0, r0], np.float32)
    return view.read((r0, r1, c0, c1)), shifted.astype(np.float64)


def sample_view(view: ImageSource, uv: np.ndarray, interp: str) -> np.ndarray:
    """Values (bands, n) float32 of the image at positions ``uv`` (n, 2), reading only the
    window they fall in; in pieces (split along the longer side) while a window would exceed
    :data:`~orthomvp.engine.plan.SAMPLE_BUDGET_PIXELS`."""
    span = np.floor(uv.max(axis=0)) - np.floor(uv.min(axis=0)) + 2 * IMAGE_MARGIN + 2
    if len(uv) > 1 and span[0] * span[1] > SAMPLE_BUDGET_PIXELS:
        order = np.argsort(uv[:, int(np.argmax(span))], kind="stable")
        half = len(uv) // 2
        out = np.empty((view.bands, len(uv)), np.float32)
        out[:, order[:half]] = sample_view(view, uv[order[:half]], interp)
        out[:, order[half:]] = sample_view(view, uv[order[half:]], interp)
        return out
    pixels, shifted = _read_window(view, uv)
    return sample_image(pixels, shifted, interp)


def run_tile(plan: Plan, index: int, kinds: frozenset[str], threads: int = 1) -> TileResult:
    """Run tile ``index`` of ``plan`` for the outputs ``kinds`` ("ortho": image values,
    "visibility": codes per view, "source": the mosaic's view per post), with
    ``threads`` threads for ray casting and visibility.

    The garbage collector runs after every tile whose DEM window has at least
    :data:`GC_POSTS` posts, and freed memory goes back to the system: the mesh library's
    objects hold reference cycles, and without it the meshes of many tiles pile up before
    Python collects them. (A full collection takes milliseconds to tens of milliseconds;
    smaller tiles leave their few megabytes to Python's own schedule.)"""
    try:
        return _run_tile(plan, index, kinds, threads)
    finally:
        if plan.tiles[index].dem_posts >= GC_POSTS:
            gc.collect()
            _release()


def _release() -> None:
    """Hand freed memory back to the system (glibc's malloc_trim; nothing elsewhere). Without
    it, the heap keeps the high-water mark of every thread's arena, and tiles that free and
    reallocate the same large arrays let the resident set creep up over a long run."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _libc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL("libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


_LIBC = _libc()


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
    grid, inner = _grid_tile(plan, job, window)
    if grid is None:
        return result
    caster = None
    if plan.occlusion:
        with _timed(seconds, "mesh"):
            caster = occluder_caster(window, threads=threads)
    result.valid = int(np.isfinite(grid.values[inner]).sum())
    best = np.full(grid.values[inner].shape, np.inf)
    for k in job.views:
        view = plan.views[k]
        with _timed(seconds, "visibility"):
            vis = compute_visibility(
                grid,
                view.camera,
                eps=plan.eps,
                caster=caster,
                threads=threads,
                post_scale=plan.post_scale,
                occlusion=plan.occlusion,
                spacing=plan.spacing,
                strict=False,
                dem=window,
            )
        codes, uv, emission = vis.codes[inner], vis.uv[inner], vis.emission[inner]
        result.inside[k] = int((codes != Code.NODATA).sum())
        result.seen[k] = int(np.isin(codes, (Code.VISIBLE, Code.OCCLUDED)).sum())
        result.counts[k] = np.bincount(codes.ravel(), minlength=len(Code)).tolist()
        if result.codes is not None:
            result.codes[k] = codes
        keep = codes == Code.VISIBLE if plan.occlusion else np.isfinite(uv).all(axis=-1)
        keep &= emission < best
        if (result.data is not None or result.source is not None) and keep.any():
            with _timed(seconds, "sample"):
                values = sample_view(view, uv[keep], plan.interp)
            ok = np.isfinite(values).all(axis=0)
            rows, cols = np.nonzero(keep)
            if result.data is not None:
                result.data[:, rows[ok], cols[ok]] = values[:, ok]
            keep[rows[~ok], cols[~ok]] = False
        if result.source is not None:
            result.source[keep] = k + 1
        best[keep] = emission[keep]
    return result
