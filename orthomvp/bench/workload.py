"""The synthetic lunar workload of the ray-casting and orthophoto benchmarks: a DEM with
rolling relief, rays onto it, and a camera over it."""

from __future__ import annotations

import numpy as np
from affine import Affine
from pyproj import CRS

from orthomvp.camera import PinholeCamera
from orthomvp.camera.csm import LineScanCamera
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector
from orthomvp.io.preflight import check_memory, count_text
from orthomvp.synthetic import MOON_CRS, MOON_RADIUS, ViewSpec, orbital_camera
from orthomvp.synthetic.linescan import orbital_line_scanner
from orthomvp.validate import number

RAYCAST_BYTES_PER_POST = 600
"""Peak memory of the ray-casting benchmark per DEM post (DEM, mesh, Embree and Open3D
scenes), bytes."""
BYTES_PER_RAY = 300
"""Peak memory of the ray-casting benchmark per ray (float64 and float32 rays, hits), bytes."""
ORTHO_BYTES_PER_POST = 1000
"""Peak memory of the orthophoto benchmark per DEM post (DEM, mesh, Embree scene, the image,
the orthophoto and the bare cast's rays), bytes."""


def check_raycast_memory(
    size: int, rays: int, advice: str = "choose a smaller size or fewer rays"
) -> None:
    """InputError, before any work, for a ray-casting benchmark that cannot fit in memory."""
    size = number(size, "size (posts)", minimum=2, integer=True)
    rays = number(rays, "rays", minimum=1, integer=True)
    posts = float(size) * size
    check_memory(
        f"the ray-casting benchmark is {count_text(posts)} posts and {count_text(rays)} rays",
        posts * RAYCAST_BYTES_PER_POST + rays * BYTES_PER_RAY,
        advice,
    )


def check_ortho_memory(size: int, advice: str = "choose a smaller size") -> None:
    """InputError, before any work, for an orthophoto benchmark that cannot fit in memory."""
    size = number(size, "size (posts)", minimum=2, integer=True)
    posts = float(size) * size
    check_memory(
        f"the orthophoto benchmark is {count_text(posts)} posts ({size:,} x {size:,})",
        posts * ORTHO_BYTES_PER_POST,
        advice,
    )


def bench_terrain(size: int) -> Terrain:
    """A lunar DEM of ``size`` x ``size`` posts 20 m apart with 300 m rolling relief."""
    step = np.degrees(20.0 / MOON_RADIUS)
    r, c = np.mgrid[0:size, 0:size].astype(np.float64)
    z = 300 * np.sin(c / 37.0) * np.cos(r / 53.0) + 80 * np.sin((c + r) / 11.0)
    transform = Affine(step, 0, 30.0, 0, -step, 10.0 + size * step)
    return Terrain(z, transform, CRS.from_proj4(MOON_CRS), name="bench")


def camera_rays(terrain: Terrain, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays from a point 110 km up and 40 km aside, towards random posts of ``terrain``:
    the origin (3,) and unnormalised directions (n, 3), body-fixed metres."""
    rows, cols = terrain.shape
    rng = np.random.default_rng(seed)
    c, r = rng.uniform(0, cols - 1, n), rng.uniform(0, rows - 1, n)
    targets = terrain.to_world(c, r, np.zeros(n))
    lon, lat = terrain.pixel_to_lonlat(np.array((cols - 1) / 2), np.array((rows - 1) / 2))
    up = unit_vector(lon, lat)
    side = np.cross(up, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    origin = (MOON_RADIUS + 110_000.0) * up + 40_000.0 * side
    return origin, targets - origin


def bench_camera(terrain: Terrain, emission_deg: float = 30.0) -> PinholeCamera:
    """A camera 110 km up, ``emission_deg`` off the vertical towards the east, whose image
    (about one pixel per post) covers the whole DEM."""
    view = ViewSpec("bench", emission_deg, 90.0)
    return orbital_camera(terrain, view, float(np.mean(terrain.post_spacing())))


def bench_line_scanner(terrain: Terrain, emission_deg: float = 30.0) -> LineScanCamera:
    """A line scanner 110 km up on a north-south orbit, looking ``emission_deg`` off the
    vertical towards the east as :func:`bench_camera` does, about one pixel per post."""
    view = ViewSpec("bench", emission_deg, 90.0)
    return orbital_line_scanner(terrain, view, float(np.mean(terrain.post_spacing())))
