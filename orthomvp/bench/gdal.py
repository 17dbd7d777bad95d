"""Side by side with GDAL (``orthomvp bench --peer gdal``): the QuickBird RPC image of
``rpc-quickbird/`` onto the ngi-aerial DEM by ``gdalwarp -rpc -to RPC_DEM=dem.tif -r bilinear``
(Debian's ``gdal-bin``) and by ``orthomvp ortho`` (with occlusion and ``--no-occlusion``), as
whole processes on the same grid, from files to a float32 GeoTIFF.

Both tools read one DEM: the ngi-aerial heights plus the geoid undulation there
(:data:`UNDULATION`, as the README's recipe gives it), under the horizontal part of its CRS,
so that the heights are ellipsoidal as RPCs want them and neither tool needs a geoid grid.
GDAL's downsampling filter is off (``-wo XSCALE=1 -wo YSCALE=1``) and it reads the image
itself, not an overview (``-ovr NONE``): one bilinear sample of the image a post, as orthomvp
takes. GDAL keeps its default approximate transformer (0.125 px) and runs on one thread (its
default), orthomvp on one per core. Each tool writes its own default: GDAL a plain striped
GeoTIFF, orthomvp a Cloud-Optimized GeoTIFF with overviews.

Each tool's start-up is measured too: the same whole process on a grid of
:data:`STARTUP_POSTS` x :data:`STARTUP_POSTS` posts at the footprint's centre (interpreter,
imports, numba's kernels loaded from its cache, the files opened and closed), timed in turn with
each grid's runs, so that the ratio of the times beyond it (``net_ratio``) shows the work
that grows with the grid."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Hashable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import rasterio

from orthomvp.bench.peer import horizontal_dem
from orthomvp.errors import InputError
from orthomvp.io.raster import open_raster, read_image

K = TypeVar("K", bound=Hashable)

GDAL_RES = (24.0, 6.0, 2.0)
"""The output post spacings (m) of ``orthomvp bench --peer gdal``; 2 m on the central half of
the footprint in each direction (as the issue measured it)."""

UNDULATION = 28.0
"""The EGM2008 geoid undulation over the QuickBird scene (m): ellipsoidal = orthometric + N."""

STARTUP_POSTS = 4
"""Posts a side of the grid whose whole run measures a tool's start-up (24 m posts)."""

IMAGE = "qb2_basic1b.tif"
"""The RPC image in ``rpc-quickbird/``."""


def gdalwarp() -> str:
    """The path of ``gdalwarp``; InputError naming the package when it is not on PATH."""
    path = shutil.which("gdalwarp")
    if path is None:
        raise InputError(
            "the peer tool gdalwarp is not on PATH; install GDAL's command-line tools "
            "(Debian: apt-get install gdal-bin)"
        )
    return path


@dataclass(frozen=True)
class GdalCase:
    """The files both tools read: the ellipsoidal ``dem`` (see the module docstring), the
    RPC ``image`` (its own camera), and ``footprint``: the image's footprint on the DEM's
    lattice (left, bottom, right, top; metres in the DEM's CRS, pixel corners)."""

    dem: Path
    image: Path
    footprint: tuple[float, float, float, float]


def ellipsoidal_dem(src: Path, dst: Path, undulation: float = UNDULATION) -> Path:
    """``src`` with only the horizontal part of its CRS and ``undulation`` metres added to
    every height (NaN stays NaN), written to ``dst``."""
    horizontal_dem(src, dst)
    with rasterio.open(dst, "r+") as ds:
        z = ds.read(1)
        nodata = ds.nodata
        hole = ~np.isfinite(z) if nodata is None or np.isnan(nodata) else z == nodata
        ds.write(np.where(hole, z, z + undulation).astype(z.dtype), 1)
    return dst


def gdal_case(data: Path, workdir: Path) -> GdalCase:
    """The case from the data folder ``data`` (holding ``ngi-aerial/`` and ``rpc-quickbird/``),
    its DEM written into ``workdir``: the footprint is that of GDAL's own output at 24 m
    (its default extent), shrunk to the DEM's lattice of 24 m posts and clipped to the DEM."""
    image = data / "rpc-quickbird" / IMAGE
    src = data / "ngi-aerial" / "dem.tif"
    for path in (image, src):
        if not path.is_file():
            raise InputError(f"--peer gdal needs {path} (the shared data folder, --peer-data)")
    dem = ellipsoidal_dem(src, workdir / "dem.tif")
    probe = workdir / "probe.tif"
    run(_warp_args(dem, image, probe, 24.0, None))
    with open_raster(probe) as ds:
        left, bottom, right, top = ds.bounds
    with open_raster(dem) as ds:
        x0, y0, step = ds.transform.c, ds.transform.f, 24.0
        dl, db, dr, dt = ds.bounds
    probe.unlink()
    box = (
        max(x0 + math.ceil((left - x0) / step) * step, dl),
        max(y0 + math.ceil((bottom - y0) / step) * step, db),
        min(x0 + math.floor((right - x0) / step) * step, dr),
        min(y0 + math.floor((top - y0) / step) * step, dt),
    )
    return GdalCase(dem, image, box)


def grid_bounds(case: GdalCase, res: float) -> tuple[float, float, float, float]:
    """The output extent at ``res`` m: the footprint, or below 6 m its central half in each
    direction, on the DEM's 24 m lattice (so that every spacing of :data:`GDAL_RES` fits)."""
    left, bottom, right, top = case.footprint
    if res >= 6:
        return case.footprint
    w, h = (right - left) / 4, (top - bottom) / 4
    snap = 24.0

    def on(x: float, base: float) -> float:
        return base + round((x - base) / snap) * snap

    return (on(left + w, left), on(bottom + h, bottom), on(right - w, left), on(top - h, bottom))


def _warp_args(
    dem: Path, image: Path, out: Path, res: float, bounds: tuple[float, ...] | None
) -> list[str]:
    """``gdalwarp -rpc`` of ``image`` onto ``dem``'s CRS at ``res`` m (``bounds``: its
    extent, else GDAL's default), bilinear, downsampling filter off and the image's own
    pixels (no overview), float32, NaN nodata."""
    with open_raster(dem) as ds:
        wkt = ds.crs.to_wkt()
    args = [gdalwarp(), "-q", "-overwrite", "-rpc", "-to", f"RPC_DEM={dem}", "-t_srs", wkt]
    args += ["-tr", str(res), str(res), "-r", "bilinear", "-wo", "XSCALE=1", "-wo", "YSCALE=1"]
    args += ["-ovr", "NONE"]
    args += ["-ot", "Float32", "-dstnodata", "nan"]
    if bounds is not None:
        args += ["-te", *(repr(float(b)) for b in bounds)]
    return [*args, str(image), str(out)]


def startup_bounds(case: GdalCase) -> tuple[float, float, float, float]:
    """The extent of the start-up runs: :data:`STARTUP_POSTS` x :data:`STARTUP_POSTS` posts of
    24 m on the DEM's lattice at the footprint's centre."""
    left, bottom, right, top = case.footprint
    step = 24.0
    x = left + math.floor((right - left) / 2 / step) * step
    y = bottom + math.floor((top - bottom) / 2 / step) * step
    side = STARTUP_POSTS * step
    return x, y, x + side, y + side


def command_lines(
    case: GdalCase, folder: Path, res: float, bounds: tuple[float, ...]
) -> dict[str, list[str]]:
    """The whole-process runs at ``res`` m on ``bounds``: gdalwarp, ``orthomvp ortho`` with
    occlusion and with ``--no-occlusion`` (the image as its own camera), each into ``folder``."""
    ours = [sys.executable, "-m", "orthomvp", "-q", "ortho", str(case.dem), str(case.image)]
    ours += ["--res", str(res), str(res), "--bounds", *(repr(float(b)) for b in bounds)]
    return {
        "gdal": _warp_args(case.dem, case.image, folder / "gdal.tif", res, bounds),
        "orthomvp": [*ours, "-o", str(folder / "ours.tif"), "--overwrite"],
        "orthomvp_naive": [*ours, "--no-occlusion", "-o", str(folder / "naive.tif"), "--overwrite"],
    }


def run(args: list[str]) -> tuple[float, float]:
    """Run one whole process quietly: its wall time (s) and peak resident memory (MB, from
    the kernel's accounting of that child, ``wait4``); RuntimeError with its last error line
    when it fails."""
    with tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        child = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(child.pid, 0)
        seconds = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode != 0:
            err.seek(0)
            lines = err.read().decode(errors="replace").strip().splitlines() or ["no message"]
            raise RuntimeError(f"{Path(args[0]).name} {args[1:3]} failed: {lines[-1]}")
    return seconds, usage.ru_maxrss / 1024  # (kB on Linux)


def best_runs(commands: dict[K, list[str]], repeat: int) -> tuple[dict[K, float], dict[K, float]]:
    """Each of ``commands`` (whole processes, :func:`run`) once untimed (caches, compiled
    bytecode), then all of them in turn ``repeat`` times: per key the best wall time (s) and
    the largest peak resident memory (MB)."""
    for args in commands.values():
        run(args)
    best = dict.fromkeys(commands, np.inf)
    rss = dict.fromkeys(commands, 0.0)
    for _ in range(repeat):
        for key, args in commands.items():
            seconds, mb = run(args)
            best[key], rss[key] = min(best[key], seconds), max(rss[key], mb)
    return best, rss


def agreement(ours: np.ndarray, theirs: np.ndarray) -> dict[str, float]:
    """Pearson r of two single-band orthophotos (rows, cols) over the posts where both hold a
    value, and the phase-correlation shift (``cv2.phaseCorrelate``, Hanning window) of the
    one from the other in posts (x, y and its length), the posts where either is empty set to
    the common mean in both."""
    import cv2

    both = np.isfinite(ours) & np.isfinite(theirs)
    a, b = ours[both].astype(np.float64), theirs[both].astype(np.float64)
    r = float(np.corrcoef(a, b)[0, 1])
    mean = 0.5 * (a.mean() + b.mean())
    fa, fb = (np.where(both, x, mean).astype(np.float64) for x in (ours, theirs))
    window = cv2.createHanningWindow(fa.shape[::-1], cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(fb, fa, window)
    return {"r": r, "shift_x": dx, "shift_y": dy, "shift": float(np.hypot(dx, dy)),
            "common_posts": int(both.sum())}  # fmt: skip


def bench_gdal(
    case: GdalCase, resolutions: tuple[float, ...] = GDAL_RES, repeat: int = 3
) -> list[dict]:
    """orthomvp (occlusion on and off) against gdalwarp on ``case`` at each of
    ``resolutions`` (m; :func:`grid_bounds`): whole processes, alternating ``repeat`` times
    after an untimed warm-up, best wall time and peak RSS of each; ratio = orthomvp's time
    over gdalwarp's; each tool's start-up (:func:`startup_bounds`, timed in turn with them)
    and the ratio of the times beyond it; the agreement (:func:`agreement`) of orthomvp's
    occlusion-aware output with GDAL's over the posts both fill. One row per resolution."""
    gdalwarp()
    rows = []
    with tempfile.TemporaryDirectory(prefix="orthomvp-gdal-") as tmp:
        folder = Path(tmp)
        tiny = command_lines(case, folder / "startup", 24.0, startup_bounds(case))
        (folder / "startup").mkdir()
        for res in resolutions:
            bounds = grid_bounds(case, res)
            commands = command_lines(case, folder, res, bounds)
            commands |= {f"{k}_startup": tiny[k] for k in ("gdal", "orthomvp")}
            best, rss = best_runs(commands, repeat)
            startup = {k: best.pop(f"{k}_startup") for k in ("gdal", "orthomvp")}
            ours, theirs = read_image(folder / "ours.tif"), read_image(folder / "gdal.tif")
            if ours.shape != theirs.shape:
                raise RuntimeError(
                    f"output grids differ: orthomvp {ours.shape}, GDAL {theirs.shape}"
                )
            rows.append(
                {
                    "res_m": res,
                    "grid": list(ours.shape[1:]),
                    "bounds": list(bounds),
                    "repeat": repeat,
                    "threads": os.cpu_count() or 1,
                    **{f"{k}_s": v for k, v in best.items()},
                    **{f"{k}_rss_mb": rss[k] for k in best},
                    "ratio": best["orthomvp"] / best["gdal"],
                    "naive_ratio": best["orthomvp_naive"] / best["gdal"],
                    "gdal_startup_s": startup["gdal"],
                    "orthomvp_startup_s": startup["orthomvp"],
                    "net_ratio": _net_ratio(best, startup),
                    **agreement(ours[0], theirs[0]),
                }
            )
    return rows


def _net_ratio(best: dict[str, float], startup: dict[str, float]) -> float:
    """orthomvp's time beyond its start-up over gdalwarp's beyond its own (NaN where
    gdalwarp's run took no longer than its start-up)."""
    theirs = best["gdal"] - startup["gdal"]
    return (best["orthomvp"] - startup["orthomvp"]) / theirs if theirs > 0 else math.nan


def format_gdal(rows: list[dict]) -> str:
    """A text table of :func:`bench_gdal`'s rows."""
    lines = [
        "side by side with gdalwarp -rpc -to RPC_DEM (one thread; downsampling filter off): "
        f"QuickBird onto the ngi-aerial DEM, whole processes, best of {rows[0]['repeat']}, "
        f"orthomvp on {rows[0]['threads']} threads",
        "  grid                  gdalwarp   orthomvp  --no-occlusion  beyond start-up"
        "  peak RSS MB gdal/ours   r         shift px",
    ]
    for row in rows:
        r, c = row["grid"]
        lines.append(
            f"  {row['res_m']:4g} m {c:5d} x {r:5d}  {row['gdal_s']:7.3f} s  "
            f"{row['ratio']:6.2f}x  {row['naive_ratio']:6.2f}x          {row['net_ratio']:6.2f}x"
            f"          {row['gdal_rss_mb']:5.0f} / {row['orthomvp_rss_mb']:5.0f}       "
            f"{row['r']:.6f}  {row['shift']:.4f}"
        )
    starts = ", ".join(
        f"{row['res_m']:g} m: {row['gdal_startup_s']:.3f} / {row['orthomvp_startup_s']:.3f} s"
        for row in rows
    )
    lines += [
        "ratio = orthomvp wall time / gdalwarp wall time in the same run",
        f"start-up = the same run on {STARTUP_POSTS} x {STARTUP_POSTS} posts, alternating with "
        f"each grid's runs (gdalwarp / orthomvp): {starts}",
        "beyond start-up = (time - start-up) / (gdalwarp's time - its start-up)",
    ]
    return "\n".join(lines)
