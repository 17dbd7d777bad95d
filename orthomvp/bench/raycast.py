"""Ray-casting benchmark: :meth:`~orthomvp.occlusion.raycast.RayCaster.first_hit` against the bare
backend call on the same rays, per backend."""

from __future__ import annotations

import time

import numpy as np

from orthomvp.bench.timing import best_time
from orthomvp.bench.workload import bench_terrain, camera_rays, check_raycast_memory
from orthomvp.errors import InputError
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import BACKENDS, RayCaster


def bench_raycast(size: int = 1000, rays: int = 1_000_000) -> list[dict]:
    """Rays per second of :meth:`RayCaster.first_hit` and of the bare backend call per backend,
    ``rays`` rays onto a ``size`` x ``size`` DEM; one row per backend (a backend that cannot
    be loaded gets a row with its reason as ``unavailable``)."""
    check_raycast_memory(size, rays)
    terrain = bench_terrain(size)
    tmesh = terrain_mesh(terrain)
    origin, dirs = camera_rays(terrain, rays)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    o32 = np.tile((origin - tmesh.origin).astype(np.float32), (rays, 1))
    d32 = unit.astype(np.float32)
    rows = []
    for backend in BACKENDS:
        t0 = time.perf_counter()
        try:
            caster = RayCaster(tmesh, backend)
        except InputError as exc:  # an optional backend that cannot load
            rows.append({"backend": backend, "unavailable": str(exc), "rays": rays})
            continue
        build = time.perf_counter() - t0
        raw = best_time(lambda c=caster: c.raw_cast(o32, d32))
        wrapped = best_time(lambda c=caster: c.first_hit(origin, dirs))
        hits = caster.first_hit(origin, dirs)
        rows.append(
            {
                "backend": backend,
                "triangles": len(tmesh.faces),
                "rays": rays,
                "build_s": build,
                "raw_rays_per_s": rays / raw,
                "wrapper_rays_per_s": rays / wrapped,
                "ratio": raw / wrapped,
                "hit_fraction": float(hits.mask.mean()),
            }
        )
    return rows
