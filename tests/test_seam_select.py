"""The seam kernel's median by selection (orthomvp.ortho.composite_kernel._middle) against the
sorted median it replaced, and the fused composition of many views against numpy's."""

from __future__ import annotations

import numpy as np
import pytest

from orthomvp.ortho.composite import MosaicOptions
from tests.test_mosaic import random_stack


def sorted_median(values: np.ndarray) -> np.float32:
    """The old kernel's median: the mean in float32 of the two middle values once sorted."""
    s = np.sort(values)
    m = len(s)
    return (s[(m - 1) // 2] + s[m // 2]) / np.float32(2)


def test_selected_median_is_the_sorted_one() -> None:
    """For 1 to 100 values (ties, signed zeros, repeated and spread values, sorted and reversed
    runs, extremes): the same float32 median as sorting gives, and ``a[:m]`` still holds the
    same values."""
    from orthomvp.ortho.composite_kernel import _middle

    rng = np.random.default_rng(11)
    cases = 0
    for m in range(1, 101):
        for kind in range(6):
            if kind == 0:
                a = rng.standard_normal(m)
            elif kind == 1:
                a = np.round(rng.random(m) * 3) / 2  # many ties
            elif kind == 2:
                a = rng.choice([-0.0, 0.0, 1.0, -1.0], m)
            elif kind == 3:
                a = np.arange(m, dtype=np.float64)
            elif kind == 4:
                a = np.arange(m, dtype=np.float64)[::-1].copy()
            else:
                a = rng.choice([3.4e38, -3.4e38, 1e-45, 7.0], m)
            a = a.astype(np.float32)
            buf = np.concatenate([a, rng.random(5).astype(np.float32)])  # beyond m: unused
            got = _middle(buf, m)
            want = sorted_median(a)
            assert got == want or (np.isnan(want) and np.isnan(got)), (m, kind, a)
            np.testing.assert_array_equal(np.sort(buf[:m]), np.sort(a))
            cases += 1
    assert cases == 600


@pytest.mark.parametrize("views", [17, 40])
def test_fused_compose_of_many_views_is_numpys(views: int) -> None:
    """With more views at a post than are sorted outright: the kernels' composition (data,
    labels, flags, weights) is numpy's bit for bit."""
    from orthomvp.ortho.composite import compose

    args = random_stack(views, seed=views, shape=(24, 30))
    options = MosaicOptions()
    ref = compose(*args[:5], options, None, args[5])
    got = compose(*args[:5], options, None, args[5], fused=True)
    for name in ("data", "source", "flags", "weights"):
        np.testing.assert_array_equal(getattr(ref, name), getattr(got, name), err_msg=name)
    assert (ref.source > 0).any()


def test_box_sums_of_an_empty_window_write_nothing(tmp_path) -> None:
    """The box-sum kernel on a window of no rows or no columns returns without writing (it
    wrote a first row of column sums past an empty buffer): run with numba's bounds checking
    on, in a fresh cache, where such a write raises IndexError."""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from orthomvp.ortho.composite_kernel import _box\n"
        "for shape in ((0, 5), (5, 0), (0, 0)):\n"
        "    a = np.zeros(shape, np.int32)\n"
        "    _box(a, 2, np.zeros(shape, np.int32), np.zeros(shape, np.int32))\n"
        "a = np.arange(12, dtype=np.int32).reshape(3, 4)\n"
        "out = np.zeros_like(a)\n"
        "_box(a, 1, out, np.zeros_like(a))\n"
        "print(out[1, 1], out[0, 0])\n"
    )
    env = {**os.environ, "NUMBA_BOUNDSCHECK": "1", "NUMBA_CACHE_DIR": str(tmp_path)}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    # the 3 x 3 box around (1, 1) holds 0..2, 4..6, 8..10; around (0, 0): 0, 1, 4, 5
    assert run.stdout.split() == ["45", "10"]
