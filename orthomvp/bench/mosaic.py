"""Mosaics as the number of images grows (``orthomvp bench --mosaic-scale 4 16 64``).

Two sets, each N run in a fresh process (so that its peak resident set size is its own):

- growing: the four ngi-aerial frames (or, without the data, four synthetic frames over
  synthetic hills) tiled K x K over the part of their DEM they see, tiled K x K (cameras
  shifted by whole extents of that part), N = 4 K^2, so that every image covers the same
  number of posts and the grid (the part of the DEM the images see, at ``res`` metres) grows
  as N;
- fixed: N copies of one frame (their centres spread over a few metres) all over one grid
  at ``res`` metres, the worst case of overlap.

Time per image relative to N = 4: 1.0 is linear scaling.
"""

from __future__ import annotations

import math
import multiprocessing
import resource
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from affine import Affine
from scipy.ndimage import gaussian_filter

from orthomvp.bench.peer import PEER_IMAGE, SYNTHETIC_PEER_CRS
from orthomvp.camera import PinholeCamera
from orthomvp.engine.images import image_source
from orthomvp.errors import InputError, OrthoMVPError
from orthomvp.io.raster import open_raster, write_geotiff

View = tuple[Path, PinholeCamera]


def _frames(data: Path | None, workdir: Path) -> tuple[Path, list[View], str]:
    """The DEM, four frames and their cameras (the ngi-aerial data in ``data`` when it holds
    ``dem.tif``, else synthetic), and the scene's name."""
    if data is not None and (data / "dem.tif").is_file():
        views = []
        for image in sorted(data.glob("*_RGB.tif")):
            source = image_source(image, image.with_suffix(".converted.tsai"))  # sized
            views.append((image, source.camera))
        return data / "dem.tif", views, "ngi-aerial"
    rows, cols, step = 508, 327, 24.0
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = 465 + 220 * np.sin(c / 23.0) * np.cos(r / 37.0) + 90 * np.sin((c + r) / 9.0)
    x0, y0 = -60454.0, -3723500.0
    dem = workdir / "hills.tif"
    transform = Affine(step, 0, x0, 0, -step, y0)
    write_geotiff(dem, z.astype(np.float32), transform, SYNTHETIC_PEER_CRS, nodata=np.nan)
    rng = np.random.default_rng(0)
    down = np.diag([1.0, -1.0, -1.0])  # x east, y south, z down: looking at nadir
    views = []
    for k, (fr, fc) in enumerate(((0.3, 0.3), (0.3, 0.7), (0.7, 0.3), (0.7, 0.7))):
        image = workdir / f"frame{k}.tif"
        pixels = gaussian_filter(rng.random((3, 1152, 640)), (0, 1.5, 1.5))
        pixels = np.clip((pixels - pixels.mean()) * 1200 + 128, 0, 255).astype(np.uint8)
        write_geotiff(image, pixels, Affine.identity(), None)
        centre = np.array([x0 + fc * cols * step, y0 - fr * rows * step, 5300.0])
        camera = PinholeCamera(833.3, 833.3, 320.0, 576.0, centre, down, width=640, height=1152)
        views.append((image, camera))
    return dem, views, "synthetic hills"


def growing_scene(data: Path | None, n: int, workdir: Path) -> tuple[Path, list[View], str]:
    """The growing set's DEM (written to ``workdir``) and its ``n`` = 4 K^2 views."""
    k = math.isqrt(n // 4)
    if n < 4 or 4 * k * k != n:
        raise InputError(f"the growing mosaic set needs N = 4 K^2 images (4, 16, 36, 64), got {n}")
    dem, frames, name = _frames(data, workdir)
    r0, r1, c0, c1 = _seen_window(dem, frames)
    with open_raster(dem) as src:
        values, profile = src.read()[:, r0:r1, c0:c1], src.profile
        transform = src.transform @ Affine.translation(c0, r0)
    rows, cols = values.shape[1:]
    profile.update(height=rows * k, width=cols * k, transform=transform)
    tiled = workdir / f"dem-{k}x{k}.tif"
    with _write(tiled, profile) as dst:
        dst.write(np.tile(values, (1, k, k)))
    width, height = cols * transform.a, rows * transform.e
    views = [
        (image, replace(camera, center=camera.center + [j * width, i * height, 0.0]))
        for i in range(k)
        for j in range(k)
        for image, camera in frames
    ]
    return tiled, views, name


def _seen_window(dem: Path, frames: list[View]) -> tuple[int, int, int, int]:
    """The window (r0, r1, c0, c1) of the DEM posts that some frame sees (projects into its
    image): the DEM of the growing set is this window tiled, so that its grid grows as the
    number of images."""
    from orthomvp.geometry.terrain import Terrain

    terrain = Terrain.read(dem, world="map")
    points = terrain.world_points()
    seen = np.zeros(terrain.shape, bool)
    for _, camera in frames:
        uv, _ = camera.project(points)
        ok = np.isfinite(uv).all(axis=-1)
        ok[ok] = camera.in_image(uv[ok])
        seen |= ok
    rows, cols = np.nonzero(seen)
    return int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1


def fixed_scene(data: Path | None, n: int, workdir: Path) -> tuple[Path, list[View], str]:
    """The fixed set: ``n`` copies of one frame over one grid, their centres moved by up to
    20 m in a square pattern."""
    dem, frames, name = _frames(data, workdir)
    pick = next((v for v in frames if v[0].stem == PEER_IMAGE), frames[0])
    side = math.ceil(math.sqrt(n))
    views = []
    for j in range(n):
        shift = 5.0 * np.array([j % side - (side - 1) / 2, j // side - (side - 1) / 2, 0.0])
        views.append((pick[0], replace(pick[1], center=pick[1].center + shift)))
    return dem, views, name


def _write(path: Path, profile: dict):  # noqa: ANN202 (rasterio's writer)
    import rasterio

    return rasterio.open(path, "w", **profile)


def _cpu() -> float:
    """CPU seconds (user and system) of this process and its threads so far."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _measure(conn: object, dem: Path, views: list[View], options: dict) -> None:
    """Child process: plan and run the mosaic, send back the figures."""
    from orthomvp.engine import Outputs, plan_ortho, run_plan

    cpu0, t0 = _cpu(), time.perf_counter()
    plan = plan_ortho(dem, views, res=options["res"], world="map", progress=False)
    planning = time.perf_counter() - t0
    report = run_plan(
        plan, Outputs(ortho=Path(options["folder"]) / "mosaic.tif", overwrite=True), progress=False
    )
    conn.send(  # type: ignore[attr-defined]
        {
            "planning_s": planning,
            "run_s": report.seconds,
            "seconds": planning + report.seconds,
            "cpu_s": _cpu() - cpu0,
            "phases_s": report.phases,
            "tiles": report.tiles_run,
            "tile": plan.tile,
            "posts": plan.grid.shape[0] * plan.grid.shape[1],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        }
    )


def measure(dem: Path, views: list[View], res: float, folder: Path) -> dict:
    """Plan and run one mosaic of ``views`` on ``dem`` at ``res`` metres in a fresh process
    (threads, one per core): seconds planning and running, CPU seconds of both (all threads;
    steadier than wall-clock time on a shared machine), tiles, peak RSS (MB)."""
    ctx = multiprocessing.get_context("spawn")
    ours, theirs = ctx.Pipe()
    options = {"res": res, "folder": str(folder)}
    child = ctx.Process(target=_measure, args=(theirs, dem, views, options))
    child.start()
    theirs.close()
    try:
        return ours.recv()
    except EOFError:
        raise OrthoMVPError(
            f"the mosaic benchmark's process for {len(views)} images died "
            f"(exit code {child.exitcode})"
        ) from None
    finally:
        child.join()


def bench_mosaic(
    counts: tuple[int, ...],
    *,
    data: Path | None,
    folder: Path,
    res: tuple[float, ...] = (24.0,),
    fixed_res: float | None = 6.0,
    repeat: int = 1,
) -> list[dict]:
    """Per set (growing at each of ``res``, fixed at ``fixed_res``; None skips it) and per
    image count of ``counts``: the best of ``repeat`` runs (the counts alternating), with
    seconds per image over that of the smallest count (``per_image``, 1.0 = linear; and
    ``cpu_per_image`` in CPU seconds) and the peak RSS (MB)."""
    odd = [n for n in counts if n < 4 or 4 * math.isqrt(n // 4) ** 2 != n]
    if res and odd:
        raise InputError(
            f"the growing mosaic set needs N = 4 K^2 images (4, 16, 36, 64), got {odd[0]}"
        )
    sets = [("growing", r, growing_scene) for r in res]
    if fixed_res:
        sets.append(("fixed", fixed_res, fixed_scene))
    rows = []
    for kind, r, scene in sets:
        best: dict[int, dict] = {}
        for _ in range(repeat):
            for n in counts:
                work = folder / f"{kind}-{n}"
                work.mkdir(exist_ok=True)
                dem, views, name = scene(data, n, work)
                row = measure(dem, views, r, work)
                if n not in best or row["seconds"] < best[n]["seconds"]:
                    best[n] = dict(row, set=kind, res=r, images=n, scene=name)
        base = best[counts[0]]["seconds"] / counts[0]
        cpu = best[counts[0]]["cpu_s"] / counts[0]
        for n in counts:
            best[n]["per_image"] = best[n]["seconds"] / n / base
            best[n]["cpu_per_image"] = best[n]["cpu_s"] / n / cpu
            rows.append(best[n])
    return rows


def format_mosaic(rows: list[dict]) -> str:
    """A text table of :func:`bench_mosaic`."""
    lines = [
        "set      grid  images   posts        tile  plan s   run s   CPU s  per image (x N=first): "
        "wall   CPU  peak RSS MB"
    ]
    for row in rows:
        lines.append(
            f"{row['set']:<8} {row['res']:>3g} m  {row['images']:>6}  {row['posts']:>11,}  "
            f"{row['tile']:>5}  {row['planning_s']:>6.1f}  {row['run_s']:>6.1f}  "
            f"{row['cpu_s']:>6.1f}  {row['per_image']:>28.2f}  {row['cpu_per_image']:>4.2f}  "
            f"{row['peak_rss_mb']:>11.0f}"
        )
    return "\n".join(lines)
