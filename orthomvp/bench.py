"""Benchmarks reported as ratios against a baseline measured in the same run.

Shared machines are noisy, so every figure is printed next to its baseline: the ray-casting
wrapper against the bare backend call on the same rays, the orthophoto against the bare cast of
its rays, and the MVP fit against bare ``cv2.remap`` of as many bilinear samples.
"""

from __future__ import annotations

import importlib
import os
import tempfile
import threading
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from importlib.metadata import version
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import rasterio
from affine import Affine
from pyproj import CRS
from scipy.ndimage import gaussian_filter

from orthomvp.camera import PinholeCamera, load_view
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.mvp import patches
from orthomvp.mvp.fit import TILE, FitOptions, fit_dem
from orthomvp.ortho import orthorectify
from orthomvp.raster import open_raster, read_image, write_geotiff
from orthomvp.raycast import BACKENDS, RayCaster
from orthomvp.synth import ViewSpec, make_scene, orbital_camera
from orthomvp.terrain import Terrain, horizontal_crs, unit_vector
from orthomvp.visibility import compute_visibility
from orthomvp.world import detect_world

LUNAR_CRS = "+proj=longlat +R=1737400 +no_defs"


def best_time(fn: Callable[[], object], repeat: int = 3) -> float:
    """The shortest wall-clock time of ``repeat`` calls, seconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_terrain(size: int) -> Terrain:
    """A lunar DEM of ``size`` x ``size`` posts 20 m apart with 300 m rolling relief."""
    step = np.degrees(20.0 / 1737400.0)
    r, c = np.mgrid[0:size, 0:size].astype(np.float64)
    z = 300 * np.sin(c / 37.0) * np.cos(r / 53.0) + 80 * np.sin((c + r) / 11.0)
    transform = Affine(step, 0, 30.0, 0, -step, 10.0 + size * step)
    return Terrain(z, transform, CRS.from_proj4(LUNAR_CRS), name="bench")


def camera_rays(terrain: Terrain, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays from a point 110 km up and 40 km aside, towards random posts of ``terrain``."""
    rows, cols = terrain.shape
    rng = np.random.default_rng(seed)
    c, r = rng.uniform(0, cols - 1, n), rng.uniform(0, rows - 1, n)
    targets = terrain.to_world(c, r, np.zeros(n))
    lon, lat = terrain.pixel_to_lonlat(np.array((cols - 1) / 2), np.array((rows - 1) / 2))
    up = unit_vector(lon, lat)
    side = np.cross(up, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    origin = (1737400.0 + 110_000.0) * up + 40_000.0 * side
    return origin, targets - origin


def bench_raycast(size: int = 1000, rays: int = 1_000_000) -> list[dict]:
    """Rays per second of :meth:`RayCaster.first_hit` and of the bare backend call per backend."""
    terrain = bench_terrain(size)
    tmesh = terrain_mesh(terrain)
    origin, dirs = camera_rays(terrain, rays)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    o32 = np.tile((origin - tmesh.origin).astype(np.float32), (rays, 1))
    d32 = unit.astype(np.float32)
    rows = []
    for backend in BACKENDS:
        t0 = time.perf_counter()
        caster = RayCaster(tmesh, backend)
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


def format_raycast(rows: list[dict]) -> str:
    """A small text table of :func:`bench_raycast` results."""
    lines = [
        f"ray casting: {rows[0]['rays']:,} rays onto {rows[0]['triangles']:,} triangles",
        f"{'backend':<8} {'build s':>8} {'raw Mray/s':>11} {'wrapper Mray/s':>15} {'ratio':>6}",
    ]
    for r in rows:
        lines.append(
            f"{r['backend']:<8} {r['build_s']:>8.2f} {r['raw_rays_per_s'] / 1e6:>11.3f} "
            f"{r['wrapper_rays_per_s'] / 1e6:>15.3f} {r['ratio']:>6.2f}"
        )
    lines.append("ratio = wrapper throughput / bare backend call on the same rays, same run")
    return "\n".join(lines)


def bench_camera(terrain: Terrain, emission_deg: float = 30.0) -> PinholeCamera:
    """A camera 110 km up, ``emission_deg`` off the vertical towards the east, whose image
    (about one pixel per post) covers the whole DEM."""
    view = ViewSpec("bench", emission_deg, 90.0)
    return orbital_camera(terrain, view, float(np.mean(terrain.post_spacing())))


def bench_ortho(size: int = 2000) -> dict:
    """Occlusion-aware orthophoto of one image onto a ``size`` x ``size`` DEM, against the bare
    Embree cast of one ray per post (the same rays) in the same run. Mesh and BVH building
    are timed separately and excluded from both."""
    terrain = bench_terrain(size)
    t0 = time.perf_counter()
    caster = RayCaster(terrain_mesh(terrain))
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


def format_ortho(row: dict) -> str:
    """A text summary of :func:`bench_ortho`."""
    return "\n".join(
        [
            f"occlusion-aware orthophoto: {row['posts']:,} posts "
            f"(mesh + BVH build {row['build_s']:.1f} s, not counted)",
            f"  bare Embree cast, one ray per post: {row['raw_cast_s']:.2f} s",
            f"  orthophoto with occlusion:          {row['ortho_s']:.2f} s "
            f"({row['posts_per_s'] / 1e6:.2f} M posts/s), ratio {row['ratio']:.2f}",
            f"  naive orthophoto (--no-occlusion, no rays): {row['naive_ortho_s']:.2f} s",
            "ratio = orthophoto time / bare cast time on the same rays, same run",
        ]
    )


@contextmanager
def tally_samples(tally: Counter[int]) -> Iterator[None]:
    """Within the block, add the bilinear samples (positions times channels) that the fitter's
    :func:`orthomvp.mvp.patches.sample_patches` takes to ``tally[channels]``."""
    original = patches.sample_patches
    lock = threading.Lock()

    def counting(
        images: list[np.ndarray], H: np.ndarray, offsets: np.ndarray, channels: int = 3
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        with lock:
            tally[channels] += H.shape[0] * H.shape[1] * len(offsets) * channels
        return original(images, H, offsets, channels)

    patches.sample_patches = counting
    try:
        yield
    finally:
        patches.sample_patches = original


def remap_baseline(
    images: list[np.ndarray], samples: dict[int, int], window: int, repeat: int = 3, seed: int = 0
) -> float:
    """Seconds to take ``samples[channels]`` bilinear samples with bare ``cv2.remap`` (as in the
    fitter: INTER_LINEAR, BORDER_REPLICATE) from the (rows, cols) float32 ``images`` (1 channel)
    or their (rows, cols, 3) stacks of value and gradients (3 channels), at random positions
    inside them, in maps of TILE**2 rows x ``window`` samples (the fitter's full batch), spread
    evenly over the images; best of ``repeat``. cv2 parallelises each call with its own threads."""
    rng = np.random.default_rng(seed)
    rows_per_call = TILE * TILE
    calls = []
    for channels, count in samples.items():
        per_view, extra = divmod(count // channels // window, len(images))  # map rows
        for k, img in enumerate(images):
            if channels == 1:
                src = img
            else:
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

    return best_time(run, repeat)


def bench_mvp(size: int = 96) -> dict:
    """The MVP fit (hwin 10) of a ``size`` x ``size`` hills scene seen in its 4 views, from the
    truth smoothed (Gaussian, 3 posts) and raised 15 m, against bare ``cv2.remap`` of as many
    bilinear samples from the same images in the same run. Rendering and the visibility masks
    (computed once beforehand) are not timed; the fit runs once."""
    scene = make_scene("hills", size=size)
    truth = scene.terrain.values
    initial = scene.terrain.with_values(gaussian_filter(truth, 3) + 15.0)
    cameras = list(scene.cameras.values())
    images = [scene.render(camera) for camera in cameras]
    caster = RayCaster(terrain_mesh(initial))
    visible = np.stack(
        [compute_visibility(initial, c, caster=caster).codes == Code.VISIBLE for c in cameras]
    )
    options = FitOptions(hwin=10)
    tally: Counter[int] = Counter()
    with tally_samples(tally):
        t0 = time.perf_counter()
        result = fit_dem(initial, images, cameras, options, visible=visible)
        fit_s = time.perf_counter() - t0
    if sum(tally.values()) != result.samples:
        raise RuntimeError(
            f"sample tally {sum(tally.values()):,} differs from the fit's {result.samples:,}"
        )
    remap_s = remap_baseline(images, dict(tally), (2 * options.hwin + 1) ** 2)
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
        "samples_3ch": tally[3],
        "samples_1ch": tally[1],
        "remap_s": remap_s,
        "ratio": fit_s / remap_s,
        "rmse_m": float(np.sqrt(np.mean((result.heights[ok] - truth[ok]) ** 2))),
        "initial_rmse_m": float(np.sqrt(np.mean((initial.values[ok] - truth[ok]) ** 2))),
    }


def format_mvp(row: dict) -> str:
    """A text summary of :func:`bench_mvp`."""
    return "\n".join(
        [
            f"MVP fit, {row['size']} x {row['size']} posts, {row['views']} views, "
            f"hwin {row['hwin']}: {row['fitted']:,} posts fitted in {row['fit_s']:.1f} s "
            f"({row['posts_per_s']:,.0f} posts/s); height RMSE {row['rmse_m']:.2f} m "
            f"(initial {row['initial_rmse_m']:.2f} m)",
            f"  bilinear samples: {row['samples'] / 1e6:,.0f} M "
            f"({row['samples_3ch'] / 1e6:,.0f} M 3-channel, {row['samples_1ch'] / 1e6:,.0f} M "
            f"1-channel)",
            f"  bare cv2.remap of the same samples: {row['remap_s']:.2f} s; "
            f"ratio {row['ratio']:.1f}x",
            f"ratio = fit time ({row['fit_threads']} worker threads) / bare cv2.remap time "
            f"(one call at a time, {row['cv2_threads']} cv2 threads), same run",
        ]
    )


# ------------------------------------------------------------- side by side with Orthority
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
    cameras' z, metres), the image, and Orthority's interior (YAML) and exterior (CSV) files."""

    name: str
    dem: Path
    image: Path
    interior: Path
    exterior: Path


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
    )


def synthetic_case(workdir: Path, seed: int = 0) -> PeerCase:
    """A stand-in for :func:`ngi_case` when the real data is absent: rolling hills (149..781 m
    like the real DEM) on 327 x 508 posts 24 m apart in the ngi DEM's transverse Mercator, a
    640 x 1152 RGB noise image, and the same interior parameters (120 mm lens, 833 px) flown
    5 km up, slightly tilted."""
    rows, cols, step = 508, 327, 24.0
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = 465 + 220 * np.sin(c / 23.0) * np.cos(r / 37.0) + 90 * np.sin((c + r) / 9.0)
    transform = Affine(step, 0, -60454.0, 0, -step, -3723500.0)
    dem = workdir / "dem.tif"
    write_geotiff(dem, z.astype(np.float32), transform, SYNTHETIC_PEER_CRS, nodata=np.nan)
    rng = np.random.default_rng(seed)
    pixels = gaussian_filter(rng.random((3, 1152, 640)), (0, 1.5, 1.5))
    pixels = np.clip((pixels - pixels.mean()) * 1200 + 128, 0, 255).astype(np.uint8)
    image = workdir / "synthetic.tif"
    write_geotiff(image, pixels, Affine.identity(), None)
    interior, exterior = workdir / "int_param.yaml", workdir / "xyz_opk.csv"
    interior.write_text(
        "synthetic:\n  type: pinhole\n  im_size: [640, 1152]\n  focal_len: 120.0\n"
        "  sensor_size: [92.16, 165.888]\n  cx: 0.0\n  cy: 0.0\n"
    )
    exterior.write_text(
        "filename,x,y,z,omega,phi,kappa\nsynthetic,-56530.0,-3729600.0,5300.0,1.2,-0.8,-179.0\n"
    )
    return PeerCase("synthetic hills", dem, image, interior, exterior)


def run_orthority(case: PeerCase, out: Path, res: float) -> None:
    """Orthority's orthophoto of ``case`` at ``res`` metres (bilinear image and DEM
    interpolation, float32 with NaN nodata, deflate, no overviews), written to ``out``: the
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
            build_ovw=False,
            overwrite=True,
        )


RUN_STEPS = ("read", "mesh", "grid", "ortho", "write")
"""The steps that :func:`run_orthomvp` times, in order."""


def run_orthomvp(
    case: PeerCase, out: Path, res: float, bounds: tuple[float, ...], occlusion: bool
) -> dict[str, float]:
    """orthomvp's orthophoto of ``case`` onto the grid of ``res`` metres and ``bounds`` (left,
    bottom, right, top) in the DEM's CRS, written to ``out`` as float32 deflate GeoTIFF: the
    steps of ``orthomvp ortho --res --bounds`` with the world frame detected. Returns the
    seconds per step: ``read`` (image, camera, DEM, world frame), ``mesh`` (mesh + BVH build),
    ``grid`` (DEM resampled to the output grid), ``ortho`` (visibility and sampling),
    ``write``."""
    times = [time.perf_counter()]
    image, camera = load_view(case.image, case.exterior)
    terrain = Terrain.read(case.dem)
    terrain = replace(terrain, world=detect_world(terrain, camera.center[None]))
    times.append(time.perf_counter())
    caster = RayCaster(terrain_mesh(terrain))
    times.append(time.perf_counter())
    grid = terrain.regrid((res, res), bounds)
    times.append(time.perf_counter())
    scale = res / float(np.mean(terrain.post_spacing()))
    ortho = orthorectify(grid, image, camera, occlusion=occlusion, caster=caster, post_scale=scale)
    times.append(time.perf_counter())
    write_geotiff(out, ortho.data, ortho.transform, ortho.crs, nodata=np.nan)
    times.append(time.perf_counter())
    return dict(zip(RUN_STEPS, np.diff(times).tolist(), strict=True))


def bench_orthority(case: PeerCase, res: float | None = None, repeat: int = 3) -> dict:
    """orthomvp (occlusion on and off) against Orthority on ``case``: the same image onto the
    same grid (the DEM's CRS, ``res`` metres, default the DEM's post spacing; the bounds of
    Orthority's output, which crops to the image footprint). Each tool runs end to end from
    its input files to a float32 deflate GeoTIFF (reading and writing included for both), with
    all cores (Orthority: one tile thread per CPU; orthomvp: tiles in a thread pool). The
    three runs alternate ``repeat`` times after an untimed warm-up; best times are kept, with
    the steps of orthomvp's best run (see :func:`run_orthomvp`)."""
    import_orthority()
    with open_raster(case.dem) as dem:
        dem_res = abs(dem.transform.a)
    res = float(res or dem_res)
    with tempfile.TemporaryDirectory(prefix="orthomvp-bench-") as tmp:
        theirs, ours, naive = (Path(tmp) / f"{n}.tif" for n in ("oty", "ours", "naive"))
        run_orthority(case, theirs, res)
        with open_raster(theirs) as ds:
            bounds, shape = tuple(ds.bounds), ds.shape
        runs: dict[str, Callable[[], object]] = {
            "orthority_s": lambda: run_orthority(case, theirs, res),
            "orthomvp_s": lambda: run_orthomvp(case, ours, res, bounds, True),
            "orthomvp_naive_s": lambda: run_orthomvp(case, naive, res, bounds, False),
        }
        run_orthomvp(case, ours, res, bounds, True)  # warm-up
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
        "max_abs_diff": float(np.abs(a[:, both] - b[:, both]).max()),
    }


def format_orthority(row: dict) -> str:
    """A text summary of :func:`bench_orthority`."""
    rows, cols = row["grid"]
    return "\n".join(
        [
            f"side by side with Orthority {row['orthority_version']}: {row['case']} onto "
            f"{cols} x {rows} posts of {row['res_m']:g} m, best of {row['repeat']}, "
            f"{row['threads']} threads, file reading and writing included for both",
            f"  Orthority (no occlusion):      {row['orthority_s']:.3f} s",
            f"  orthomvp, occlusion on:        {row['orthomvp_s']:.3f} s, ratio {row['ratio']:.2f}",
            f"  orthomvp, occlusion off:       {row['orthomvp_naive_s']:.3f} s, ratio "
            f"{row['naive_ratio']:.2f}",
            "  orthomvp steps with occlusion: "
            + ", ".join(f"{k} {v:.3f} s" for k, v in row["orthomvp_steps_s"].items()),
            f"ratio = orthomvp time / Orthority time, same run; largest difference of the two "
            f"orthophotos where both have data: {row['max_abs_diff']:.3g}",
        ]
    )
