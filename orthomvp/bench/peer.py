"""Side by side with Orthority (``orthomvp bench --peer orthority``): the same frame onto the
same grid by both tools, end to end from files to a float32 GeoTIFF with overviews, bilinear;
and every frame of the survey, as orthomvp's one mosaic against Orthority's orthophotos of each
frame (one ``oty frame`` process).

Each tool writes its own default format for float32: Orthority a tiled GeoTIFF with deflate
(GDAL's level 6) and internal overviews (``--build-ovw``, its default); orthomvp a
Cloud-Optimized GeoTIFF with zstd at level 1."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from types import ModuleType

import numpy as np
import rasterio
from affine import Affine
from pyproj import CRS
from scipy.ndimage import gaussian_filter

from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.errors import InputError
from orthomvp.geometry.crs import horizontal_crs
from orthomvp.io.raster import open_raster, read_image, write_geotiff

PEER_IMAGE = "3324c_2015_1004_05_0182_RGB"
"""The ngi-aerial frame that ``orthomvp bench --peer orthority`` orthorectifies."""

SYNTHETIC_PEER_CRS = "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m"
"""The CRS of :func:`synthetic_case`: the ngi-aerial DEM's transverse Mercator (Lo25)."""


def import_orthority() -> ModuleType:
    """Import Orthority (AGPL-3.0; run as a peer tool, none of its code is copied here).

    Orthority switches on PROJ's network access (``PROJ_NETWORK=ON``) when imported; the
    previous setting is restored so that the rest of the process stays offline. Raises
    InputError when Orthority is not installed.
    """
    before = os.environ.get("PROJ_NETWORK")
    try:
        return importlib.import_module("orthority")
    except ImportError as exc:
        raise InputError(
            f"the peer tool orthority is not installed ({exc}); pip install orthority"
        ) from exc
    finally:
        if before is None:
            os.environ.pop("PROJ_NETWORK", None)
        else:
            os.environ["PROJ_NETWORK"] = before


@dataclass(frozen=True)
class PeerCase:
    """One frame as files both tools read: a DEM GeoTIFF whose CRS is the horizontal part of
    the original (so that Orthority needs no geoid grid: both tools take the DEM values as the
    cameras' z, metres), the image, and Orthority's interior (YAML) and exterior (CSV) files
    (which also hold the other ``frames`` of the survey, the image among them; none: the image
    alone)."""

    name: str
    dem: Path
    image: Path
    interior: Path
    exterior: Path
    frames: tuple[Path, ...] = ()


def horizontal_dem(src: Path, dst: Path) -> Path:
    """Copy the DEM GeoTIFF ``src`` to ``dst`` with only the horizontal part of its CRS."""
    with open_raster(src) as ds:
        profile, data = ds.profile, ds.read()
        if ds.crs is None:
            raise InputError(f"{src}: the DEM has no CRS")
        crs = horizontal_crs(CRS.from_wkt(ds.crs.to_wkt()))
    profile.update(crs=crs.to_wkt())
    with rasterio.open(dst, "w", **profile) as out:
        out.write(data)
    return dst


def ngi_case(data_dir: Path, workdir: Path) -> PeerCase:
    """The ngi-aerial frame :data:`PEER_IMAGE` from ``data_dir`` (``shared/data/ngi-aerial``)."""
    params = data_dir / "orthority-format"
    return PeerCase(
        f"ngi-aerial {PEER_IMAGE}",
        horizontal_dem(data_dir / "dem.tif", workdir / "dem.tif"),
        data_dir / f"{PEER_IMAGE}.tif",
        params / "ngi_int_param.yaml",
        params / "ngi_xyz_opk.csv",
        tuple(sorted(data_dir.glob("*_RGB.tif"))),
    )


def synthetic_case(workdir: Path, seed: int = 0) -> PeerCase:
    """A stand-in for :func:`ngi_case` when the real data is absent: rolling hills (149..781 m
    like the real DEM) on 327 x 508 posts 24 m apart in the ngi DEM's transverse Mercator, a
    640 x 1152 RGB noise image, and the same interior parameters (120 mm lens, 833 px) flown
    5 km up, slightly tilted; a second frame (its own noise) 1.5 km north for the mosaic."""
    rows, cols, step = 508, 327, 24.0
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = 465 + 220 * np.sin(c / 23.0) * np.cos(r / 37.0) + 90 * np.sin((c + r) / 9.0)
    transform = Affine(step, 0, -60454.0, 0, -step, -3723500.0)
    dem = workdir / "dem.tif"
    write_geotiff(dem, z.astype(np.float32), transform, SYNTHETIC_PEER_CRS, nodata=np.nan)
    rng = np.random.default_rng(seed)
    frames = (workdir / "synthetic.tif", workdir / "synthetic2.tif")
    for frame in frames:
        pixels = gaussian_filter(rng.random((3, 1152, 640)), (0, 1.5, 1.5))
        pixels = np.clip((pixels - pixels.mean()) * 1200 + 128, 0, 255).astype(np.uint8)
        write_geotiff(frame, pixels, Affine.identity(), None)
    interior, exterior = workdir / "int_param.yaml", workdir / "xyz_opk.csv"
    interior.write_text(
        "synthetic:\n  type: pinhole\n  im_size: [640, 1152]\n  focal_len: 120.0\n"
        "  sensor_size: [92.16, 165.888]\n  cx: 0.0\n  cy: 0.0\n"
    )
    exterior.write_text(
        "filename,x,y,z,omega,phi,kappa\nsynthetic,-56530.0,-3729600.0,5300.0,1.2,-0.8,-179.0\n"
        "synthetic2,-56530.0,-3728100.0,5300.0,-0.6,0.9,-179.0\n"
    )
    return PeerCase("synthetic hills", dem, frames[0], interior, exterior, frames)


def run_orthority(case: PeerCase, out: Path, res: float) -> None:
    """Orthority's orthophoto of ``case`` at ``res`` metres (bilinear image and DEM
    interpolation, float32 with NaN nodata, deflate, overviews), written to ``out``: the
    camera files, DEM and image are read inside, as ``oty frame`` does."""
    oty = import_orthority()
    with warnings.catch_warnings(), open_raster(case.dem) as dem:
        warnings.simplefilter("ignore")  # partial DEM coverage, size mismatch: checked by us
        camera = oty.FrameCameras(case.interior, case.exterior).get(case.image)
        ortho = oty.Ortho(case.image, case.dem, camera, crs=dem.crs)
        ortho.process(
            out,
            resolution=(res, res),
            interp="bilinear",
            dem_interp="bilinear",
            dtype="float32",
            compress="deflate",
            build_ovw=True,
            overwrite=True,
        )


RUN_STEPS = ("plan", "run")
"""The steps that :func:`run_orthomvp` times, in order."""


def run_orthomvp(
    case: PeerCase, out: Path, res: float, bounds: tuple[float, ...], occlusion: bool
) -> dict[str, float]:
    """orthomvp's orthophoto of ``case`` onto the grid of ``res`` metres and ``bounds`` (left,
    bottom, right, top) in the DEM's CRS, written to ``out`` (its default COG) through the
    engine as ``orthomvp ortho --res --bounds`` runs it. Returns the seconds per step:
    ``plan`` (cameras, DEM scan, tiles) and ``run`` (tiles on all cores, and the writing)."""
    t0 = time.perf_counter()
    plan = plan_ortho(
        case.dem,
        [(case.image, case.exterior)],
        res=(res, res),
        bounds=bounds,
        occlusion=occlusion,
        progress=False,
    )
    t1 = time.perf_counter()
    run_plan(plan, Outputs(ortho=out, overwrite=True), progress=False)  # repeated runs
    return {"plan": t1 - t0, "run": time.perf_counter() - t1}


def _orthority_args(case: PeerCase, res: float) -> list[str]:
    """``oty frame`` with ``case``'s DEM (its CRS as the world CRS) and camera files at
    ``res`` metres, bilinear image and DEM interpolation, float32, deflate, overviews; from
    its console entry point's own function."""
    oty = "import sys; from orthority.cli import cli; sys.exit(cli())"
    return [
        *(sys.executable, "-c", oty, "frame", "--dem", str(case.dem), "-c", str(case.dem)),
        *("-ip", str(case.interior), "-ep", str(case.exterior), "--res", str(res)),
        *("-i", "bilinear", "-di", "bilinear", "-dt", "float32", "-cm", "deflate", "-bo"),
    ]


def command_lines(
    case: PeerCase, folder: Path, res: float, bounds: tuple[float, ...]
) -> dict[str, list[str]]:
    """The whole-process runs, as a user times them: ``oty frame`` (bilinear image and DEM
    interpolation, float32, deflate, overviews) and ``orthomvp ortho`` with and without occlusion
    onto the grid of Orthority's output (``res``, ``bounds``), each writing into ``folder``;
    Orthority takes the DEM's CRS as its world CRS, as in process. Orthority runs from its console
    entry point's own function."""
    ours = [sys.executable, "-m", "orthomvp", "-q", "ortho", str(case.dem), str(case.image)]
    ours += [str(case.exterior), "--res", str(res), str(res), "--bounds"]
    ours += [str(b) for b in bounds]
    return {
        "orthority_cli_s": [
            *_orthority_args(case, res),
            *("-od", str(folder), "-o", str(case.image)),
        ],
        "orthomvp_cli_s": [*ours, "-o", str(folder / "ours-cli.tif"), "--overwrite"],
        "orthomvp_naive_cli_s": [
            *ours,
            *("--no-occlusion", "-o", str(folder / "naive-cli.tif"), "--overwrite"),
        ],
    }


def mosaic_command_lines(case: PeerCase, folder: Path, res: float) -> dict[str, list[str]]:
    """The whole-process runs over every frame of ``case``: ``oty frame`` with all of them (one
    orthophoto per frame, options as in :func:`command_lines`) into ``folder``/oty, and
    ``orthomvp mosaic`` of all of them at ``res`` onto the union of Orthority's outputs (read
    from ``folder``/oty, so Orthority's command runs first) into ``folder``/mosaic.tif."""
    oty = _orthority_args(case, res) + ["-od", str(folder / "oty"), "-o", *map(str, case.frames)]
    lines = {"orthority_mosaic_cli_s": oty}
    (folder / "oty").mkdir(parents=True, exist_ok=True)
    run_command(oty)
    boxes = []
    for frame in case.frames:
        with open_raster(folder / "oty" / f"{frame.stem}_ORTHO.tif") as ds:
            boxes.append(tuple(ds.bounds))
    union = (*np.min(boxes, axis=0)[:2], *np.max(boxes, axis=0)[2:])
    ours = [sys.executable, "-m", "orthomvp", "-q", "mosaic", str(case.dem)]
    for frame in case.frames:
        ours += [str(frame), str(case.exterior)]
    ours += ["--res", str(res), str(res), "--bounds", *(f"{b:.6f}" for b in union)]
    lines["orthomvp_mosaic_cli_s"] = [*ours, "-o", str(folder / "mosaic.tif"), "--overwrite"]
    return lines


def run_command(args: list[str]) -> None:
    """Run one whole-process command quietly; RuntimeError with its last error line when it
    fails."""
    done = subprocess.run(args, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{args[2] if args[1] == '-m' else 'oty'} failed: {last}")


def bench_orthority(case: PeerCase, res: float | None = None, repeat: int = 3) -> dict:
    """orthomvp (occlusion on and off) against Orthority on ``case``: the same image onto the same
    grid (the DEM's CRS, ``res`` metres, default the DEM's post spacing; the bounds of Orthority's
    output, which crops to the image footprint), from input files to a GeoTIFF with overviews (each
    tool's default format and compression for float32), with all cores (Orthority: one tile thread
    per CPU; orthomvp: the engine's tiles on one thread per core). Measured two ways, each
    alternating its runs ``repeat`` times after an untimed warm-up and keeping the best: in this
    process (both libraries imported) and as whole processes from the command line, start-up and
    imports included (what a user times). With several frames also the mosaic of all of them
    against Orthority's orthophoto of each, whole processes (:func:`mosaic_command_lines`)."""
    import_orthority()
    with open_raster(case.dem) as dem:
        dem_res = abs(dem.transform.a)
    res = float(res or dem_res)
    with tempfile.TemporaryDirectory(prefix="orthomvp-bench-") as tmp:
        folder = Path(tmp)
        theirs, ours, naive = (folder / f"{n}.tif" for n in ("oty", "ours", "naive"))
        run_orthority(case, theirs, res)
        with open_raster(theirs) as ds:
            bounds, shape = tuple(ds.bounds), ds.shape
        runs: dict[str, Callable[[], object]] = {
            "orthority_s": lambda: run_orthority(case, theirs, res),
            "orthomvp_s": lambda: run_orthomvp(case, ours, res, bounds, True),
            "orthomvp_naive_s": lambda: run_orthomvp(case, naive, res, bounds, False),
        }
        (folder / "cli").mkdir()
        lines = command_lines(case, folder / "cli", res, bounds)
        mosaic = len(case.frames) > 1
        if mosaic:
            lines |= mosaic_command_lines(case, folder / "mosaic", res)
        for key, args in lines.items():
            runs[key] = lambda args=args: run_command(args)
        for fn in runs.values():  # warm-up: caches, compiled bytecode
            fn()
        best, steps = dict.fromkeys(runs, np.inf), {}
        for _ in range(repeat):
            for key, fn in runs.items():
                t0 = time.perf_counter()
                result = fn()
                seconds = time.perf_counter() - t0
                if seconds < best[key]:
                    best[key] = seconds
                    if key == "orthomvp_s":
                        steps = result
        a, b = read_image(ours), read_image(theirs)
        same_cli = np.array_equal(read_image(folder / "cli" / "ours-cli.tif"), a, equal_nan=True)
        extra: dict[str, object] = {}
        if mosaic:
            with open_raster(folder / "mosaic" / "mosaic.tif") as ds:
                extra["mosaic_grid"] = list(ds.shape)
            extra["mosaic_frames"] = len(case.frames)
            extra["mosaic_cli_ratio"] = (
                best["orthomvp_mosaic_cli_s"] / best["orthority_mosaic_cli_s"]
            )
    if a.shape != b.shape:
        raise RuntimeError(f"output grids differ: orthomvp {a.shape}, orthority {b.shape}")
    both = np.isfinite(a).all(axis=0) & np.isfinite(b).all(axis=0)
    return {
        "case": case.name,
        "orthority_version": version("orthority"),
        "res_m": res,
        "grid": list(shape),
        "posts": int(shape[0] * shape[1]),
        "repeat": repeat,
        "threads": os.cpu_count() or 1,
        **best,
        "orthomvp_steps_s": steps,
        "ratio": best["orthomvp_s"] / best["orthority_s"],
        "naive_ratio": best["orthomvp_naive_s"] / best["orthority_s"],
        "cli_ratio": best["orthomvp_cli_s"] / best["orthority_cli_s"],
        "cli_naive_ratio": best["orthomvp_naive_cli_s"] / best["orthority_cli_s"],
        "cli_equals_api": bool(same_cli),
        "max_abs_diff": float(np.abs(a[:, both] - b[:, both]).max()),
        **extra,
    }
