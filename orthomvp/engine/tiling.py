"""How big a plan's tiles are and what they cost: the default tile side (:func:`auto_tile`,
:func:`mosaic_tile`), the bytes of memory per post of each part of a tile, and a run's
expected peak memory (:func:`peak_bytes`), which the engine checks before any work."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from orthomvp.engine.heap import MMAP_THRESHOLD
from orthomvp.errors import InputError

TILE = 1024
"""Default tile side, posts."""

SMALL_TILE = 256
"""Smallest tile side :func:`auto_tile` chooses, posts, unless its ``largest`` is smaller (a
mosaic whose tiles many views see: :data:`MOSAIC_SMALL_TILE`): below it a tile's fixed costs
(its mesh over the occluder halo, the mosaic's margin) outweigh the cores it keeps busy."""

SINGLE_VIEW_TILE = 512
"""Smallest tile side :func:`auto_tile` chooses for an orthophoto of one view, posts: a grid
whose longer side is shorter than two of them is one tile (at 24 m on ngi-aerial, 291 x 163
posts: 0.40 s for the whole command against 0.42 s in tiles of 256, one of them 35 posts
high); a mosaic's compose still gains from tiles of :data:`SMALL_TILE`."""

MOSAIC_SMALL_TILE = 192
"""Smallest tile side :func:`mosaic_tile` chooses, posts, where many views overlap one place:
64 views over a tile of 192 posts with the margin hold 3.2 million view posts (4 views over
768 posts: 2.5 million; over 256: 5.2 million). The fixed set of ``orthomvp bench`` at 64
views peaked at 805 MB in tiles of 192 (787-841 at 4 views; 991 in 256), 5% more CPU; tiles of
128 peaked at 620 MB but took 56% more CPU (the visibility phase 1.7x for 1.2x the posts:
it has fixed costs per view and tile)."""

TILE_STEP = 64
""":func:`auto_tile` gives multiples of it, so that each tile makes the output's first six
overview levels from its own posts (:mod:`orthomvp.engine.overviews`)."""

# Bytes of memory per post, from the peak resident set size of runs of the scale benchmark's
# scene (orthomvp.engine.scale, 2048 x 2048 posts, tiles of 128 to 1024 posts, one thread),
# rounded up: the DEM window meshed for Embree (world points, triangles, the trimesh, the
# caster's float32 copies and BVH: about 290 measured; the occluder surface of a city whose
# walls step a third of the cells 1.6 times that), the window's values, and the posts of
# a tile (with one around) through visibility and sampling (float64 geometry in
# compute_visibility's sub-tiles, codes, uv, emission: about 150 measured for one view).
MESH_BYTES = 480
WINDOW_BYTES = 16
TILE_BYTES = 100
VIEW_BYTES = 50
MOSAIC_BYTES = 80
BASE_BYTES = 300 << 20
"""An interpreter with numpy, rasterio, pyproj, trimesh and Embree loaded, and GDAL's block
cache (bounded by :data:`orthomvp.engine.grid.GDAL_CACHE`)."""
WORKER_BYTES = 140 << 20
"""A worker process besides this one (of a process pool or a Dask cluster), tiles apart: the
engine imported and a tile run. Measured (resident set, after the tiles of a 160 x 160
orthophoto, Python 3.11, distributed 2026.8): 136-138 MiB a Dask worker, 111 MiB a
process-pool worker (61-83 MiB of it not shared with others)."""


def peak_bytes(sizes: Iterable[int], workers: int, processes: int) -> int:
    """Expected peak memory of a run whose tiles take ``sizes`` bytes each, with ``workers``
    tiles in flight at once (the largest) and ``processes`` worker processes besides this one
    (:data:`BASE_BYTES` this one, :data:`WORKER_BYTES` each worker), bytes."""
    return BASE_BYTES + processes * WORKER_BYTES + sum(sorted(sizes, reverse=True)[:workers])


def largest_dem_window(run: Sequence[Any]) -> str:
    """``", DEM windows up to C x R posts"`` for the largest DEM window (``dem``, with
    ``dem_posts``) of the tiles ``run``, for a plan's summary; empty without one."""
    biggest = max(run, key=lambda job: job.dem_posts, default=None)
    if biggest is None or biggest.dem is None:
        return ""
    r0, r1, c0, c1 = biggest.dem
    return f", DEM windows up to {c1 - c0:,} x {r1 - r0:,} posts"


def auto_tile(
    shape: tuple[int, int],
    cores: int | None = None,
    largest: int = TILE,
    smallest: int = SMALL_TILE,
) -> int:
    """The default tile side for a grid of ``shape`` (rows, cols): ``largest`` (default
    :data:`TILE`), or on a grid too small to give each of the ``cores`` (default: this
    machine's) a tile, its longer side split among them, rounded up to a multiple of
    :data:`TILE_STEP` and at least ``smallest`` posts (at most ``largest`` even so)."""
    cores = cores or os.cpu_count() or 1
    split = math.ceil(max(shape) / cores / TILE_STEP) * TILE_STEP
    return min(largest, max(smallest, split))


def mosaic_tile(views: int | Callable[[int], int], bands: int, margin: int) -> int:
    """The largest default tile side of a mosaic (a multiple of 128 from :data:`SMALL_TILE` to
    :data:`TILE`, else :data:`MOSAIC_SMALL_TILE`) whose stack of the samples of the views that see
    one tile (float32, with the ``margin`` around the tile) stays below the heap's mmap
    threshold (:data:`orthomvp.engine.heap.MMAP_THRESHOLD`): larger blocks come afresh from the
    kernel at every allocation, and compose's temporaries of that size then cost page faults (a
    4-view RGB mosaic at 3 m on ngi-aerial: compose 8.0 s in 1,024-post tiles, 4.6 s in 768).
    ``views``: the most views that see one tile, for a side of posts (a function of the side),
    or every view (a count). The memory rule: a tile's stack holds only its own views, so
    tiles shrink as more views overlap one place, not as more images join the mosaic."""
    per_post = max(4 * bands, 8)
    for side in (*range(TILE, SMALL_TILE - 1, -128), MOSAIC_SMALL_TILE):
        count = views if isinstance(views, int) else views(side)
        if (side + 2 * margin) ** 2 * max(count, 1) * per_post <= MMAP_THRESHOLD:
            return side
    return MOSAIC_SMALL_TILE


def check_tile(tile: object) -> int | None:
    """``tile`` (posts a side) as an int, or None (:func:`auto_tile`); InputError unless an
    integer of at least 2 or None."""
    if tile is None:
        return None
    if isinstance(tile, bool) or not isinstance(tile, int | np.integer) or tile < 2:
        raise InputError(f"tile must be an integer of at least 2 posts or None, got {tile!r}")
    return int(tile)
