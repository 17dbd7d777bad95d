"""orthomvp.jit's start: numba's BLAS check runs on scipy's cython_blas alone, and leaves numba,
scipy.linalg and the kernels as they would be after the usual check (in a fresh interpreter,
since this one may hold scipy.linalg already)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import orthomvp

CHECK = """
import sys
import numpy as np
import orthomvp.jit
import numba
import numba.np.arraymath
assert "scipy.linalg" not in sys.modules, "the check imported scipy.linalg"
assert "scipy.linalg.cython_blas" not in sys.modules, "the module was left in sys.modules"
assert numba.np.arraymath._HAVE_BLAS, "numba found no BLAS"

@numba.njit
def dot(a, b):
    return np.dot(a, b), np.correlate(a[0], b)

a = np.arange(6.0).reshape(2, 3)
b = np.array([1.0, 2.0, 3.0])
got, corr = dot(a, b)
np.testing.assert_array_equal(got, a @ b)
np.testing.assert_array_equal(corr, np.correlate(a[0], b))

import scipy.linalg
import scipy.linalg.cython_blas as blas
assert scipy.linalg.cython_blas is blas and "dgemm" in blas.__pyx_capi__
np.testing.assert_allclose(scipy.linalg.solve(np.diag([2.0, 4.0]), np.ones(2)), [0.5, 0.25])

from orthomvp.ortho.composite_kernel import _box
values = np.arange(20, dtype=np.int64).reshape(4, 5)
out, tmp = np.empty_like(values), np.empty_like(values)
_box(values, 1, out, tmp)
from orthomvp.ortho.composite import box_sum
np.testing.assert_array_equal(out, box_sum(values, 1))
print("ok")
"""


def test_numba_blas_check_without_scipy_linalg() -> None:
    done = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"


def test_a_process_that_imported_scipy_linalg_first_is_left_alone() -> None:
    code = (
        "import sys, scipy.linalg, scipy.linalg.cython_blas as b\n"
        "import orthomvp.jit, numba.np.arraymath\n"
        "assert sys.modules['scipy.linalg.cython_blas'] is b and numba.np.arraymath._HAVE_BLAS\n"
        "print('ok')"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"


KERNEL = """
import numpy as np
from orthomvp.ortho.composite_kernel import _box
values = np.arange(20, dtype=np.int64).reshape(4, 5)
_box(values, 1, np.empty_like(values), np.empty_like(values))
"""


def _cache_files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.suffix in (".nbi", ".nbc")]


def _run_kernel(env: dict[str, str]) -> None:
    subprocess.run([sys.executable, "-c", KERNEL], env=env, check=True, timeout=300)


def test_kernels_cache_in_the_users_cache_folder_never_in_the_package(tmp_path: Path) -> None:
    """The README's order (a regular install runs the demo, then ``pip install -e``) broke when
    numba cached beside the package: the left folder hid the editable install."""
    package = Path(orthomvp.__file__).parent
    before = {p: p.stat().st_mtime_ns for p in _cache_files(package)}
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    _run_kernel({**env, "HOME": str(tmp_path)})
    cached = _cache_files(tmp_path / ".cache" / "orthomvp" / "numba")
    assert any(p.name.startswith("composite_kernel._box") for p in cached), cached
    after = {p: p.stat().st_mtime_ns for p in _cache_files(package)}
    assert after == before, "numba wrote into the package's folder"

    _run_kernel({**env, "HOME": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert _cache_files(tmp_path / "xdg" / "orthomvp" / "numba")
    _run_kernel({**env, "HOME": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "own")})
    assert _cache_files(tmp_path / "own")


def test_the_configuration_survives_numba_reading_its_environment_again(tmp_path: Path) -> None:
    """numba re-reads its NUMBA_ variables whenever they change; the cache folder and OpenMP
    before TBB (else the older TBB of Open3D prints a warning) hold after such a reload, also
    when numba was imported before orthomvp.jit."""
    code = (
        "import os, numba\n"
        "import orthomvp.jit\n"
        "os.environ['NUMBA_SOMETHING_ELSE'] = '1'\n"
        "numba.config.reload_config()\n"
        "print(numba.config.THREADING_LAYER_PRIORITY[0], numba.config.CACHE_DIR)\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["HOME"] = str(tmp_path)
    env.pop("XDG_CACHE_HOME", None)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    layer, folder = out.stdout.split()
    assert layer == "omp" and folder == str(tmp_path / ".cache" / "orthomvp" / "numba")
