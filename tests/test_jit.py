"""orthomvp.jit's start: numba's BLAS check runs on scipy's cython_blas alone, and leaves numba,
scipy.linalg and the kernels as they would be after the usual check (in a fresh interpreter,
since this one may hold scipy.linalg already)."""

from __future__ import annotations

import subprocess
import sys

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

from orthomvp.mosaic_kernel import _box
values = np.arange(20, dtype=np.int64).reshape(4, 5)
out, tmp = np.empty_like(values), np.empty_like(values)
_box(values, 1, out, tmp)
from orthomvp.mosaic import box_sum
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
