"""The C heap (glibc malloc) of whatever runs tiles: a thread pool, worker processes or Dask
workers, so that all three run a tile at the same speed and give its memory back.

Each tile allocates and frees numpy temporaries of one to tens of megabytes. glibc serves
blocks above its mmap threshold (128 kB at start) with fresh pages from the kernel, and raises
that threshold, up to 32 MB, each time such a block is freed; a long-lived process thus soon
takes its temporaries from memory it already holds. Setting a trim or mmap threshold turns
that adjustment off, and Dask's nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``
(``distributed.nanny.pre-spawn-environ``): every temporary then costs page faults and
zeroing. Measured on a 2,048-post orthophoto: 1.65 million minor faults in the two Dask
workers against 0.28 million with threads, and the visibility phase half again as slow.
:func:`settle` fixes the thresholds at the values the adjustment reaches (mmap 32 MB, trim
64 MB) in every process that runs a tile, whatever its environment; :func:`release` hands
freed memory back after a large tile; :func:`tile_heap` does both around one tile.
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager

RELEASE_POSTS = 1 << 15
"""Tiles whose DEM window has at least this many posts are followed by :func:`release`
(:func:`tile_heap`)."""
MMAP_THRESHOLD = 32 << 20
"""Blocks at least this large (bytes) are mapped afresh and unmapped when freed (glibc's
largest dynamic mmap threshold on 64-bit systems)."""
TRIM_THRESHOLD = 64 << 20
"""Free memory at the top of the heap beyond this (bytes) goes back to the kernel at once
(twice the mmap threshold, as glibc's adjustment sets it)."""
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
"""mallopt parameters (malloc.h)."""


def _libc() -> ctypes.CDLL | None:
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    return libc if hasattr(libc, "malloc_trim") and hasattr(libc, "mallopt") else None


_LIBC = _libc()
_settled = False


def settle() -> None:
    """Fix this process's heap thresholds (module docstring), once; nothing without glibc."""
    global _settled
    if _LIBC is not None and not _settled:
        _LIBC.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        _LIBC.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
        _settled = True


def release() -> None:
    """Hand freed memory back to the system (glibc's malloc_trim; nothing elsewhere). Without
    it, the heap keeps the high-water mark of every thread's arena, and tiles that free and
    reallocate the same large arrays let the resident set creep up over a long run."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


@contextmanager
def tile_heap(posts: int) -> Iterator[None]:
    """Around one tile whose DEM window has ``posts`` posts: the heap settled before it; after
    it, when the window has at least :data:`RELEASE_POSTS` posts, freed memory handed back. A
    tile leaves no reference cycles (a garbage collection after one finds nothing, and would
    cost 12-14 ms), so its arrays are freed as soon as its result is taken."""
    settle()
    try:
        yield
    finally:
        if posts >= RELEASE_POSTS:
            release()
