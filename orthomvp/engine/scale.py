"""The scale benchmark: a synthetic DEM and image of any size, written tile by tile, and the
engine's orthophoto of them, measured for time per post, peak memory and where the time goes.

The scene is self-similar across sizes: a lunar DEM of ``posts`` x ``posts`` posts
:data:`SPACING` metres apart at the equator with 300 m rolling relief (the hills of
``orthomvp bench``), and one frame camera at 1.2 DEM extents altitude, 20 degrees off
nadir towards the east, whose ``posts`` x ``posts`` pixel image just covers the DEM (about one
pixel per post). Image pixels are a procedural uint8 texture, not a rendering.

Each size runs in a fresh process, so that its peak resident set size (``ru_maxrss``) is its
own; worker processes (``processes`` or a Dask LocalCluster) are reported separately.
"""

from __future__ import annotations

import multiprocessing
import resource
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine
from pyproj import CRS
from rasterio.errors import NotGeoreferencedWarning
from rasterio.windows import Window

from orthomvp.camera import PinholeCamera
from orthomvp.errors import OrthoMVPError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.vectors import unit_vector

SPACING = 20.0
"""Metres between posts of the synthetic DEM."""
LUNAR = "+proj=longlat +R=1737400 +no_defs"
BLOCK = 1024
"""Posts (pixels) a side of the blocks the synthetic files are written in."""


def _blocks(n: int) -> list[tuple[int, int, int, int]]:
    return [
        (r, min(r + BLOCK, n), c, min(c + BLOCK, n))
        for r in range(0, n, BLOCK)
        for c in range(0, n, BLOCK)
    ]


def hills(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Heights in metres at DEM pixel positions: 300 m hills 37 x 53 posts across with 80 m
    ridges (slopes up to about 45 degrees at 20 m posts)."""
    return 300 * np.sin(c / 37.0) * np.cos(r / 53.0) + 80 * np.sin((c + r) / 11.0)


def texture(c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """A procedural uint8 texture at pixel positions: crossed waves of several periods."""
    v = 128 + 50 * np.sin(c / 5.3) * np.sin(r / 7.1) + 40 * np.sin((c * 0.37 + r * 0.91) / 2.3)
    return np.clip(v, 0, 255).astype(np.uint8)


def _profile(n: int, dtype: str) -> dict:
    return {
        "driver": "GTiff",
        "height": n,
        "width": n,
        "count": 1,
        "dtype": dtype,
        "tiled": True,
        "blockxsize": 512,
        "blockysize": 512,
        "compress": "deflate",
        "bigtiff": "IF_SAFER",
    }


def scale_camera(terrain: Terrain, n: int, pixels: int | None = None) -> PinholeCamera:
    """The scene's camera (module docstring) over the DEM grid ``terrain`` of ``n`` x ``n``
    posts (its values are not used beyond its georeference), with an image of ``pixels`` x
    ``pixels`` (default ``n``) that just covers the grid."""
    pixels = pixels or n
    mid = (n - 1) / 2
    lon, lat = terrain.pixel_to_lonlat(np.array(mid), np.array(mid))
    up = unit_vector(lon, lat)
    north = np.array([0.0, 0.0, 1.0]) - up * up[2]
    north /= np.linalg.norm(north)
    east = np.cross(north, up)
    altitude = 1.2 * n * SPACING
    target = terrain.to_world(np.array(mid), np.array(mid), np.array(0.0))
    centre = target + altitude * up + altitude * np.tan(np.radians(20.0)) * east
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(-north, z)
    x /= np.linalg.norm(x)
    rotation = np.column_stack([x, np.cross(z, x), z])
    edge = np.linspace(0, n - 1, 33)
    c = np.concatenate([edge, edge, np.zeros(33), np.full(33, n - 1.0)])
    r = np.concatenate([np.zeros(33), np.full(33, n - 1.0), edge, edge])
    local = (terrain.to_world(c, r, np.zeros(len(c))) - centre) @ rotation
    half = np.abs(local[:, :2] / local[:, 2:]).max()
    f = (pixels / 2 - 1) / half
    mid_px = pixels / 2 - 0.5
    return PinholeCamera(f, f, mid_px, mid_px, centre, rotation, width=pixels, height=pixels)


def write_scale_scene(
    folder: str | Path, posts: int, pixels: int | None = None
) -> tuple[Path, Path, PinholeCamera]:
    """Write the scene of ``posts`` x ``posts`` (module docstring) into ``folder`` block by
    block (memory: one block): ``dem.tif`` (float32 heights) and ``image.tif`` (uint8,
    ``pixels`` x ``pixels``, default ``posts``); returns their paths and the camera."""
    pixels = pixels or posts
    folder = Path(folder)
    step = np.degrees(SPACING / 1737400.0)
    transform = Affine(step, 0, 30.0 - posts * step / 2, 0, -step, posts * step / 2)
    dem, image = folder / "dem.tif", folder / "image.tif"
    with rasterio.open(
        dem, "w", **_profile(posts, "float32"), crs=LUNAR, transform=transform
    ) as dst:
        for r0, r1, c0, c1 in _blocks(posts):
            r, c = np.mgrid[r0:r1, c0:c1].astype(np.float64)
            dst.write(hills(c, r).astype(np.float32)[None], window=Window(c0, r0, c1 - c0, r1 - r0))
    grid = Terrain(np.zeros((2, 2)), transform, CRS.from_user_input(LUNAR), name="scale")
    camera = scale_camera(grid, posts, pixels)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        dst = rasterio.open(image, "w", **_profile(pixels, "uint8"))
    with dst:
        for r0, r1, c0, c1 in _blocks(pixels):
            r, c = np.mgrid[r0:r1, c0:c1]
            dst.write(texture(c, r)[None], window=Window(c0, r0, c1 - c0, r1 - r0))
    return dem, image, camera


def _measure(conn: object, dem: Path, image: Path, camera: PinholeCamera, options: dict) -> None:
    """Child process: plan and run the orthophoto, send back the figures."""
    from orthomvp.engine import Outputs, dask_client, plan_ortho, run_plan

    t0 = time.perf_counter()
    plan = plan_ortho(dem, [(image, camera)], grid="dem", tile=options["tile"], progress=False)
    planning = time.perf_counter() - t0
    out = Outputs(ortho=Path(options["folder"]) / "ortho.tif")
    if options.get("dask"):
        with dask_client(workers=options["dask"]) as client:
            report = run_plan(plan, out, client=client, progress=False)
    else:
        kind = "processes" if options.get("processes") else "threads"
        report = run_plan(plan, out, progress=False, **{kind: options[kind]})
    conn.send(  # type: ignore[attr-defined]
        {
            "planning_s": planning,
            "run_s": report.seconds,
            "phases_s": report.phases,
            "tiles": report.tiles_run,
            "filled": report.filled,
            "reach_posts": max(plan.reach),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
        }
    )


def bench_scale(
    sizes: tuple[int, ...] = (1024, 2048, 4096),
    *,
    tile: int = 1024,
    threads: int = 2,
    processes: int | None = None,
    dask: int | None = None,
    folder: str | Path | None = None,
    pixels: int | None = None,
) -> list[dict]:
    """For each size (posts a side): write the scene, then plan and run its orthophoto in a
    fresh process with ``threads`` threads, or ``processes`` processes, or a Dask
    LocalCluster of ``dask`` workers; tiles of ``tile`` posts; an image of ``pixels`` a side
    (default: as many as posts). Returns per size: posts, times
    (writing the inputs, planning, running), microseconds per post, seconds per phase summed
    over workers (read, mesh: mesh and BVH build, visibility: casting, sample, write) with
    their shares, and the peak RSS of the run's process and of its workers in MB."""
    rows = []
    for n in sizes:
        with tempfile.TemporaryDirectory(prefix="orthomvp-scale-", dir=folder) as tmp:
            t0 = time.perf_counter()
            dem, image, camera = write_scale_scene(tmp, n, pixels)
            writing = time.perf_counter() - t0
            ctx = multiprocessing.get_context("spawn")
            ours, theirs = ctx.Pipe()
            options = {"tile": tile, "folder": tmp, "threads": threads}
            options.update(processes=processes, dask=dask)
            child = ctx.Process(target=_measure, args=(theirs, dem, image, camera, options))
            child.start()
            theirs.close()
            try:
                row = ours.recv()
            except EOFError:
                raise OrthoMVPError(
                    f"the benchmark's process for {n} posts died (exit code {child.exitcode})"
                ) from None
            finally:
                child.join()
        total = sum(row["phases_s"].values())
        row.update(
            pixels=(pixels or n) ** 2,
            posts=n * n,
            size=n,
            mode=f"dask {dask}"
            if dask
            else f"processes {processes}"
            if processes
            else f"threads {threads}",
            inputs_s=writing,
            us_per_post=1e6 * (row["planning_s"] + row["run_s"]) / (n * n),
            shares={k: v / total for k, v in row["phases_s"].items()},
        )
        rows.append(row)
    return rows


def format_scale(rows: list[dict]) -> str:
    """A text table of :func:`bench_scale`."""
    lines = [
        "posts a side  mode          plan s   run s  us/post  peak RSS MB (workers)  "
        "mesh  visib.  sample  write  read"
    ]
    for row in rows:
        s = row["shares"]
        rss = f"{row['peak_rss_mb']:>8.0f} ({row['worker_peak_rss_mb']:>6.0f})"
        lines.append(
            f"{row['size']:>12,}  {row['mode']:<12} {row['planning_s']:>7.1f} "
            f"{row['run_s']:>7.1f} {row['us_per_post']:>8.2f}  {rss}        "
            f"{s.get('mesh', 0):>4.0%}  {s.get('visibility', 0):>5.0%}  "
            f"{s.get('sample', 0):>5.0%}  {s.get('write', 0):>5.0%}  {s.get('read', 0):>4.0%}"
        )
    return "\n".join(lines)
