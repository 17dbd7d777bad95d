"""numba compilation of the fused kernels (:mod:`orthomvp.mvp.kernel`,
:mod:`orthomvp.post_geometry_kernel`, :mod:`orthomvp.mosaic_kernel`): lazily on first call,
releasing the GIL, cached on disk where numba can write (beside the package, else
``~/.cache/numba`` or ``NUMBA_CACHE_DIR``). Import this module only where a kernel runs: it
imports numba (about 0.15 s; the first kernel then loads in about 0.3 s)."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numba

# OpenMP first: the layer numba takes here anyway, and the older TBB that Open3D loads (when
# its ray caster or the bench ran first) would otherwise print a warning at the first
# parallel call
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


def cached_jit(fn: Callable, **options: object) -> Callable:
    """``fn`` compiled with ``options`` on its first call, without the GIL, cached on disk; where
    no directory is writable, compiled in every process (with a warning)."""
    try:
        return numba.njit(cache=True, nogil=True, **options)(fn)
    except RuntimeError as err:  # no writable cache directory anywhere
        warnings.warn(f"numba cannot cache {fn.__name__} ({err})", stacklevel=2)
        return numba.njit(nogil=True, **options)(fn)
