"""Line-scan benchmark: ground to image throughput of a USGS CSM line scanner, and its
occlusion-aware orthophoto against a frame camera's on the same grid, in the same run."""

from __future__ import annotations

import time

import numpy as np

from orthomvp.bench.workload import (
    bench_camera,
    bench_line_scanner,
    bench_terrain,
    check_ortho_memory,
)
from orthomvp.camera.csm import posts_per_second
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.ortho.orthophoto import orthorectify


def bench_linescan(size: int = 1000, posts: int = 1_000_000, repeat: int = 3) -> dict:
    """Ground to image of ``posts`` random ground points through the line scanner of
    :func:`~orthomvp.bench.workload.bench_line_scanner` (points per second), and the
    occlusion-aware orthophotos of that scanner and of the frame camera of
    :func:`~orthomvp.bench.workload.bench_camera` (both 30 degrees off nadir, one pixel per
    post) onto one ``size`` x ``size`` DEM: best wall-clock time of ``repeat`` alternating
    runs each, mesh and BVH built once, not counted; ratio = line scan / frame."""
    check_ortho_memory(size)
    terrain = bench_terrain(size)
    caster = RayCaster(terrain_mesh(terrain))
    frame, scanner = bench_camera(terrain), bench_line_scanner(terrain)
    rng = np.random.default_rng(0)
    images = {
        "frame": (rng.random((1, frame.height, frame.width), dtype=np.float32), frame),
        "linescan": (rng.random((1, scanner.lines, scanner.samples), dtype=np.float32), scanner),
    }
    pps = posts_per_second(scanner, posts=posts)
    best = {name: np.inf for name in images}
    for _ in range(repeat):
        for name, (image, camera) in images.items():
            t0 = time.perf_counter()
            orthorectify(terrain, image, camera, caster=caster)
            best[name] = min(best[name], time.perf_counter() - t0)
    return {
        "posts": terrain.values.size,
        "project_points": posts,
        "project_points_per_s": pps,
        "lines": scanner.lines,
        "table_error_px": scanner.table_error,
        "frame_ortho_s": best["frame"],
        "linescan_ortho_s": best["linescan"],
        "ratio": best["linescan"] / best["frame"],
    }
