"""MVP benchmark: the plane fit against bare ``cv2.remap`` of as many bilinear samples as the
fit reports taking (:attr:`orthomvp.mvp.FitResult.samples`)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

from orthomvp.bench.timing import best_time
from orthomvp.codes import Code
from orthomvp.mvp.fit import TILE, FitOptions, fit_dem
from orthomvp.occlusion.visibility import compute_visibility, occluder_caster
from orthomvp.synthetic import make_scene

CHANNELS = 3
"""Samples per position in the baseline: the fitter's images are stacks of value and c, r
gradients, and it samples all three wherever it needs derivatives (most of its samples)."""


def remap_baseline(
    images: list[np.ndarray], samples: int, window: int, repeat: int = 3, seed: int = 0
) -> tuple[float, int]:
    """Seconds to take ``samples`` bilinear samples with bare ``cv2.remap`` (as in the fitter:
    INTER_LINEAR, BORDER_REPLICATE) from the (rows, cols, 3) stacks of value and gradients of
    the (rows, cols) float32 ``images``, :data:`CHANNELS` per position, at random positions
    inside them, in maps of TILE**2 rows x ``window`` positions (the fitter's full batch),
    spread evenly over the images; best of ``repeat``. cv2 parallelises each call with its own
    threads. Returns the seconds and the samples taken (``samples`` rounded down to whole map
    rows)."""
    rng = np.random.default_rng(seed)
    rows_per_call = TILE * TILE
    per_view, extra = divmod(samples // CHANNELS // window, len(images))  # map rows
    calls = []
    for k, img in enumerate(images):
        gr, gc = np.gradient(img)
        src = np.stack([img, gc, gr], axis=-1)
        u = rng.uniform(0, img.shape[1] - 1, (rows_per_call, window)).astype(np.float32)
        v = rng.uniform(0, img.shape[0] - 1, (rows_per_call, window)).astype(np.float32)
        share = per_view + (k < extra)
        for r0 in range(0, share, rows_per_call):
            n = min(rows_per_call, share - r0)
            calls.append((src, u[:n], v[:n]))

    def run() -> None:
        for src, u, v in calls:
            cv2.remap(src, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    return best_time(run, repeat), sum(u.size for _, u, _ in calls) * CHANNELS


def cold_compile_seconds() -> float:
    """Seconds the MVP kernel takes to compile in a fresh process with an empty numba cache
    (``NUMBA_CACHE_DIR`` a new temporary directory; imports not counted)."""
    code = "from orthomvp.mvp.kernel import compile_seconds; print(compile_seconds())"
    with tempfile.TemporaryDirectory(prefix="orthomvp-numba-") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": tmp}
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
    return float(out.stdout.split()[-1])


def bench_mvp(size: int = 96) -> dict:
    """The MVP fit (hwin 10) of a ``size`` x ``size`` hills scene seen in its 4 views, from the
    truth smoothed (Gaussian, 3 posts) and raised 15 m, against bare ``cv2.remap`` of as many
    bilinear samples from the same images in the same run. Rendering and the visibility masks
    (computed once beforehand) are not timed; the fit runs once, after the kernel's first
    call (compiled or loaded from numba's cache, timed apart, as is its compilation in a
    fresh process with an empty cache)."""
    from orthomvp.mvp.kernel import compile_seconds

    first_s = compile_seconds()
    cold_s = cold_compile_seconds()
    scene = make_scene("hills", size=size)
    truth = scene.terrain.values
    initial = scene.terrain.with_values(gaussian_filter(truth, 3) + 15.0)
    cameras = list(scene.cameras.values())
    images = [scene.render(camera) for camera in cameras]
    caster = occluder_caster(initial)
    visible = np.stack(
        [compute_visibility(initial, c, caster=caster).codes == Code.VISIBLE for c in cameras]
    )
    options = FitOptions(hwin=10)
    t0 = time.perf_counter()
    result = fit_dem(initial, images, cameras, options, visible=visible)
    fit_s = time.perf_counter() - t0
    remap_s, remap_samples = remap_baseline(images, result.samples, (2 * options.hwin + 1) ** 2)
    ok = result.resolved
    fitted = int(ok.sum())
    return {
        "posts": truth.size,
        "size": size,
        "views": len(cameras),
        "hwin": options.hwin,
        "fit_threads": os.cpu_count() or 1,
        "cv2_threads": cv2.getNumThreads(),
        "fitted": fitted,
        "fit_s": fit_s,
        "posts_per_s": fitted / fit_s,
        "samples": result.samples,
        "remap_samples": remap_samples,
        "remap_s": remap_s,
        "ratio": fit_s / remap_s,
        "kernel_first_call_s": first_s,
        "kernel_compile_s": cold_s,
        "rmse_m": float(np.sqrt(np.mean((result.heights[ok] - truth[ok]) ** 2))),
        "initial_rmse_m": float(np.sqrt(np.mean((initial.values[ok] - truth[ok]) ** 2))),
    }
