"""numba compilation of the fused kernels (:mod:`orthomvp.mvp.kernel`,
:mod:`orthomvp.occlusion.post_geometry_kernel`, :mod:`orthomvp.occlusion.post_lattice_kernel`,
:mod:`orthomvp.ortho.composite_kernel`, :mod:`orthomvp.camera.rpc_kernel`,
:mod:`orthomvp.camera.csm.table_kernel`): lazily on
first call, releasing the GIL, cached on disk in the user's cache folder (:func:`cache_dir`:
``NUMBA_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/orthomvp/numba`` or
``~/.cache/orthomvp/numba``), never in the package's own folder. Import this module only where a
kernel runs: it imports numba (about 0.15 s; the first kernel then loads in about 0.15 s)."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
import warnings
from collections.abc import Callable


def cache_dir() -> str:
    """The folder of numba's cache: ``NUMBA_CACHE_DIR`` when set, else ``orthomvp/numba`` in the
    user's cache folder (``XDG_CACHE_HOME``, by default ``~/.cache``)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "orthomvp", "numba")


# numba's configuration through the environment, which it reads at its import and reads again
# whenever the NUMBA_ variables change (a value set on numba.config alone would be reset then);
# child processes inherit it. The cache in the user's cache folder. OpenMP before TBB: the
# layer numba takes here anyway, and the older TBB that Open3D loads (when its ray caster or the
# bench ran first) would otherwise print a warning at the first parallel call.
os.environ["NUMBA_CACHE_DIR"] = cache_dir()
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp tbb workqueue")

import numba  # noqa: E402

numba.config.reload_config()  # (where numba was imported before this module)

BLAS = "scipy.linalg.cython_blas"


def _check_blas_alone() -> None:
    """Run numba's check for a BLAS (at the import of ``numba.np.arraymath``, which the first
    kernel's load does) on scipy's ``cython_blas`` alone, without the package around it: the
    check imports ``scipy.linalg.cython_blas``, and ``scipy.linalg``'s own imports took 0.2 s of
    a 0.45 s kernel load (0.44 -> 0.31 s with numpy and numba's import). The module goes into
    ``sys.modules`` for the check only and is taken out after it, so that a later import of
    ``scipy.linalg`` is the usual one (and gets the same module: Python keeps an extension
    once loaded). Nothing is done where ``scipy.linalg`` or the check already ran, and on any
    failure numba's check imports the package as usual."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    try:
        import scipy  # (numba's import took it already)

        stem = os.path.join(os.path.dirname(scipy.__file__), "linalg", "cython_blas")
        paths = [stem + suffix for suffix in importlib.machinery.EXTENSION_SUFFIXES]
        spec = importlib.util.spec_from_file_location(BLAS, next(filter(os.path.isfile, paths)))
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 (any failure: numba's check as usual)
        return
    sys.modules[BLAS] = module
    try:
        import numba.np.arraymath  # noqa: F401 (the check)
    finally:
        if sys.modules.get(BLAS) is module:
            del sys.modules[BLAS]


_check_blas_alone()


def cached_jit(fn: Callable, **options: object) -> Callable:
    """``fn`` compiled with ``options`` on its first call, without the GIL, cached on disk; where
    no directory is writable, compiled in every process (with a warning)."""
    try:
        return numba.njit(cache=True, nogil=True, **options)(fn)
    except RuntimeError as err:  # no writable cache directory anywhere
        warnings.warn(f"numba cannot cache {fn.__name__} ({err})", stacklevel=2)
        return numba.njit(nogil=True, **options)(fn)
