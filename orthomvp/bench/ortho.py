"""Orthophoto benchmark: the occlusion-aware orthophoto against the bare Embree cast of one ray
per post."""

from __future__ import annotations

import time

import numpy as np

from orthomvp.bench.timing import best_time
from orthomvp.bench.workload import bench_camera, bench_terrain, check_ortho_memory
from orthomvp.occlusion.visibility import occluder_caster
from orthomvp.ortho.orthophoto import orthorectify


def bench_ortho(size: int = 2000) -> dict:
    """Occlusion-aware orthophoto of one image onto a ``size`` x ``size`` DEM, against the bare
    Embree cast of one ray per post (the same rays) in the same run. Mesh and BVH building
    are timed separately and excluded from both."""
    check_ortho_memory(size)
    terrain = bench_terrain(size)
    t0 = time.perf_counter()
    caster = occluder_caster(terrain)
    build = time.perf_counter() - t0
    cam = bench_camera(terrain)
    rng = np.random.default_rng(0)
    image = rng.random((1, cam.height, cam.width), dtype=np.float32)
    posts = terrain.world_points().reshape(-1, 3)
    d = posts - cam.center
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o32 = np.tile((cam.center - caster.tmesh.origin).astype(np.float32), (len(d), 1))
    d32 = d.astype(np.float32)
    raw = best_time(lambda: caster.raw_cast(o32, d32), repeat=2)
    full = best_time(lambda: orthorectify(terrain, image, cam, caster=caster), repeat=2)
    naive = best_time(
        lambda: orthorectify(terrain, image, cam, occlusion=False, caster=caster), repeat=2
    )
    ortho = orthorectify(terrain, image, cam, caster=caster)
    n = terrain.values.size
    return {
        "posts": n,
        "build_s": build,
        "raw_cast_s": raw,
        "ortho_s": full,
        "naive_ortho_s": naive,
        "posts_per_s": n / full,
        "ratio": full / raw,
        "visible_fraction": float(np.isfinite(ortho.data[0]).mean()),
    }
