"""``orthomvp bench``: benchmarks, each a ratio to a baseline measured in the same run."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import click

from orthomvp.cli.command import Command, Variadic
from orthomvp.cli.options import (
    PATH,
    POSITIVE,
    Output,
    SizeOrZero,
    check_outputs,
    overwrite_option,
)
from orthomvp.errors import InputError

PEER_DATA_ENV = "ORTHOMVP_DATA"
"""The environment variable naming the data folder that holds ``ngi-aerial/``."""


def peer_data_default() -> Path | None:
    """$ORTHOMVP_DATA/ngi-aerial when ORTHOMVP_DATA is set, else None (a synthetic scene)."""
    root = os.environ.get(PEER_DATA_ENV)
    return Path(root) / "ngi-aerial" if root else None


@click.command(
    cls=Command,
    short_help="benchmarks, each reported as a ratio to a baseline measured in the same run",
)
@click.option(
    "--size",
    type=click.IntRange(min=2),
    default=1000,
    metavar="N",
    help="ray-casting DEM posts per side",
)
@click.option(
    "--rays", type=click.IntRange(min=1), default=1_000_000, metavar="N", help="number of rays"
)
@click.option(
    "--ortho-size",
    type=SizeOrZero(2),
    default=2000,
    metavar="N",
    help="orthophoto DEM posts per side (0 skips)",
)
@click.option(
    "--linescan-size",
    type=SizeOrZero(2),
    default=1000,
    metavar="N",
    help="line-scan vs frame orthophoto DEM posts per side (0 skips)",
)
@click.option(
    "--linescan-points",
    type=click.IntRange(min=1),
    default=1_000_000,
    metavar="N",
    help="ground points projected through the line scanner",
)
@click.option(
    "--mvp-size",
    type=SizeOrZero(8),
    default=96,
    metavar="N",
    help="MVP fit DEM posts per side (0 skips)",
)
@click.option(
    "--peer",
    type=click.Choice(("orthority", "gdal")),
    help="only compare orthomvp (occlusion on and off) with this tool on the same grid: "
    "orthority (a frame camera), gdal (gdalwarp -rpc on the QuickBird RPC image)",
)
@click.option(
    "--peer-data",
    type=PATH,
    default=peer_data_default,
    metavar="DIR",
    show_default=f"${PEER_DATA_ENV}/ngi-aerial when {PEER_DATA_ENV} is set, else a synthetic "
    "aerial scene",
    help="the ngi-aerial data for --peer (a synthetic scene when it holds no dem.tif); "
    "--peer gdal reads rpc-quickbird/ beside it",
)
@click.option(
    "--peer-res",
    type=POSITIVE,
    metavar="M",
    show_default="the DEM's, 24 m for ngi-aerial; for gdal 24, 6 and 2 m",
    help="output post spacing for --peer in metres",
)
@click.option(
    "--peer-repeat",
    type=click.IntRange(min=1),
    default=3,
    metavar="N",
    help="--peer keeps the best of N",
)
@click.option(
    "--scale",
    "scale_sizes",
    cls=Variadic,
    type=click.IntRange(min=64),
    metavar="N [N ...]",
    help="only the scale benchmark: ortho of a synthetic DEM of N x N posts (written tile by "
    "tile, with an image of about as many pixels) through the engine, per size: time per post, "
    "peak memory, share of each phase; e.g. --scale 1024 2048 4096 8192 16384",
)
@click.option(
    "--scale-dask",
    type=click.IntRange(min=1),
    metavar="N",
    help="--scale also runs each size on a Dask LocalCluster of N workers and reports its time "
    "over the threaded run's",
)
@click.option(
    "--view",
    is_flag=True,
    help="only the viewer benchmark: orthomvp view's first map paint, tiles and clicks at hwin "
    "10 on the demo's crater scene and, with --peer-data, the ngi-aerial mosaic",
)
@click.option(
    "--formats",
    is_flag=True,
    help="only the image-format benchmark: one frame (from --peer-data, else synthetic) "
    "enlarged to 2560 x 4608 px and stored as a tiled GeoTIFF, a JPEG, a PNG and a GeoTIFF "
    "of one strip; orthomvp "
    "ortho of each at 2 m with default tiles and with --tile 128, whole processes, best of "
    "--peer-repeat; time over the GeoTIFF's",
)
@click.option(
    "--mosaic-scale",
    "mosaic_counts",
    cls=Variadic,
    type=click.IntRange(min=2),
    metavar="N...",
    help="only the mosaic benchmark: mosaics of N images (4 K^2 for the growing set), each in "
    "a fresh process; time per image relative to the first N, and peak memory; e.g. "
    "--mosaic-scale 4 16 64",
)
@click.option(
    "--mosaic-res",
    cls=Variadic,
    type=POSITIVE,
    metavar="M...",
    help="--mosaic-scale: grid spacings (metres) of the growing set (the ngi-aerial frames "
    "tiled K x K over the part of their DEM they see, tiled to match; from --peer-data) "
    "[default: 24]",
)
@click.option(
    "--mosaic-fixed",
    type=click.FloatRange(min=0),
    default=6.0,
    show_default=True,
    metavar="M",
    help="--mosaic-scale: grid spacing (metres) of the fixed set, N copies of one frame over "
    "one grid (0 skips)",
)
@click.option(
    "--mosaic-repeat",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    metavar="N",
    help="--mosaic-scale keeps the best of N runs of each count (alternating)",
)
@click.option(
    "--json", "json_path", type=PATH, metavar="FILE", help="also write the figures as JSON"
)
@overwrite_option
def bench(
    size: int,
    rays: int,
    ortho_size: int,
    linescan_size: int,
    linescan_points: int,
    mvp_size: int,
    peer: str | None,
    peer_data: Path | None,
    peer_res: float | None,
    peer_repeat: int,
    scale_sizes: tuple[int, ...],
    scale_dask: int | None,
    view: bool,
    formats: bool,
    mosaic_counts: tuple[int, ...],
    mosaic_res: tuple[float, ...],
    mosaic_fixed: float,
    mosaic_repeat: int,
    json_path: Path | None,
    overwrite: bool,
) -> None:
    """Ray casting: rays per second through orthomvp's first_hit and through the bare backend
    call on the same rays, for Embree and Open3D. Orthophoto: the occlusion-aware orthophoto
    of one image against the bare Embree cast of one ray per post, in the same run. Line
    scan: ground-to-image points per second of a USGS CSM line scanner, and its orthophoto
    against a frame camera's of the same grid (same emission angle), in the same run. MVP: the
    plane fit of a synthetic hills DEM from its 4 views against bare cv2.remap of as many
    bilinear samples from the same images, in the same run. --peer orthority runs instead the
    side-by-side comparison with Orthority (when installed): one ngi-aerial frame (or, without
    the data, a synthetic aerial scene) onto the same grid with both tools, end to end from
    files to GeoTIFF, best of --peer-repeat alternating runs; ratio = orthomvp time /
    Orthority time. --peer gdal: the QuickBird RPC image onto the ngi-aerial DEM by gdalwarp
    -rpc -to RPC_DEM (when on PATH) and by orthomvp at 24, 6 and 2 m, whole processes, with
    peak memory and the agreement of the two orthophotos. --scale runs instead the engine's
    scale benchmark (threads = cores). --mosaic-scale runs instead the mosaic benchmark
    (threads = cores). --view runs instead the viewer benchmark. --formats runs instead the
    image-format benchmark."""
    from orthomvp import bench as b
    from orthomvp.bench.workload import check_ortho_memory, check_raycast_memory
    from orthomvp.io.outputs import atomic_path
    from orthomvp.synthetic.scene import check_scene_memory

    check_outputs([Output("--json", json_path, ())], overwrite=overwrite)
    if not peer and not view and not formats:  # every check before the first benchmark runs
        check_raycast_memory(size, rays, "choose a smaller --size or fewer --rays")
        if ortho_size:
            check_ortho_memory(ortho_size, "choose a smaller --ortho-size (0 skips)")
        if linescan_size:
            check_ortho_memory(linescan_size, "choose a smaller --linescan-size (0 skips)")
        if mvp_size:
            check_scene_memory(mvp_size, 0.8, "choose a smaller --mvp-size (0 skips)")
    if view:
        results = {"view": bench_view(peer_data)}
    elif formats:
        results = {"formats": bench_formats(peer_data, peer_repeat)}
    elif peer == "gdal":
        results = {"gdal": bench_gdal_peer(peer_data, peer_res, peer_repeat)}
    elif peer:
        results = {"orthority": bench_peer(peer_data, peer_res, peer_repeat)}
    elif scale_sizes:
        results = {"scale": bench_scale(scale_sizes, scale_dask)}
    elif mosaic_counts:
        res = mosaic_res or (24.0,)
        results = {
            "mosaic": bench_mosaic(mosaic_counts, peer_data, res, mosaic_fixed, mosaic_repeat)
        }
    else:
        results = {"raycast": b.bench_raycast(size=size, rays=rays)}
        print(b.format_raycast(results["raycast"]))
        if ortho_size:
            results["ortho"] = b.bench_ortho(size=ortho_size)
            print(b.format_ortho(results["ortho"]))
        if linescan_size:
            results["linescan"] = b.bench_linescan(size=linescan_size, posts=linescan_points)
            print(b.format_linescan(results["linescan"]))
        if mvp_size:
            results["mvp"] = b.bench_mvp(size=mvp_size)
            print(b.format_mvp(results["mvp"]))
    if json_path:
        with atomic_path(json_path) as tmp:
            tmp.write_text(json.dumps(results, indent=2))


def bench_view(data: Path | None) -> list[dict]:
    """``bench --view``: the viewer on the demo's crater scene, and on the ngi-aerial mosaic
    when ``data`` holds it; printed."""
    from orthomvp.bench import view as v

    rows = []
    with tempfile.TemporaryDirectory(prefix="orthomvp-view-") as tmp:
        cases = [v.demo_case(Path(tmp) / "demo")]
        if data is not None and (data / "dem.tif").is_file():
            (Path(tmp) / "ngi").mkdir()
            cases.append(v.ngi_case(data, Path(tmp) / "ngi"))
        else:
            print("orthomvp: no ngi-aerial data (--peer-data or $ORTHOMVP_DATA): the demo only")
        for case in cases:
            rows.append(v.bench_view(case))
            print(v.format_view(rows[-1]), flush=True)
    return rows


def bench_formats(data: Path | None, repeat: int) -> list[dict]:
    """``bench --formats``: :mod:`orthomvp.bench.formats` on the ngi-aerial frame in ``data``
    (a synthetic frame without it), printed."""
    from orthomvp.bench import formats as f

    if not (data is not None and (data / "dem.tif").is_file()):
        print("orthomvp: no ngi-aerial data given: using a synthetic aerial frame")
    with tempfile.TemporaryDirectory(prefix="orthomvp-formats-") as tmp:
        rows = f.bench_formats(data, Path(tmp), repeat=repeat)
    print(f.format_formats(rows))
    return rows


def bench_scale(sizes: tuple[int, ...], dask: int | None) -> list[dict]:
    """``bench --scale``: the engine on synthetic DEMs of ``sizes`` posts a side with threads
    (one per core), and on a Dask LocalCluster of ``dask`` workers when asked; printed."""
    from orthomvp.engine.scale import bench_scale as run
    from orthomvp.engine.scale import format_scale

    rows = []
    for n in sizes:
        row = run((n,), threads=os.cpu_count() or 1)[0]
        print(format_scale([row]).splitlines()[-1] if rows else format_scale([row]), flush=True)
        rows.append(row)
        if dask:
            other = run((n,), dask=dask)[0]
            other["over_threads"] = other["us_per_post"] / row["us_per_post"]
            line = format_scale([other]).splitlines()[-1]
            print(f"{line}  ({other['over_threads']:.2f}x the threaded run)", flush=True)
            rows.append(other)
    return rows


def bench_mosaic(
    counts: tuple[int, ...],
    data: Path | None,
    res: tuple[float, ...],
    fixed_res: float,
    repeat: int,
) -> list[dict]:
    """``bench --mosaic-scale``: the growing and fixed mosaic sets of
    :mod:`orthomvp.bench.mosaic` (on the ngi-aerial frames in ``data``, synthetic ones
    without), printed."""
    from orthomvp.bench.mosaic import bench_mosaic as run
    from orthomvp.bench.mosaic import format_mosaic

    if not (data is not None and (data / "dem.tif").is_file()):
        print("orthomvp: no ngi-aerial data given: using a synthetic aerial scene")
    with tempfile.TemporaryDirectory(prefix="orthomvp-mosaic-") as tmp:
        rows = run(
            counts,
            data=data,
            folder=Path(tmp),
            res=res,
            fixed_res=fixed_res or None,
            repeat=repeat,
        )
    print(format_mosaic(rows))
    return rows


def bench_peer(data: Path | None, res: float | None, repeat: int) -> dict:
    """``bench --peer orthority``: the side-by-side run on the ngi-aerial frame in ``data``
    (a synthetic aerial scene without it), printed; returns its figures."""
    from orthomvp import bench as b

    b.import_orthority()
    with tempfile.TemporaryDirectory(prefix="orthomvp-peer-") as tmp:
        if data is not None and (data / "dem.tif").is_file():
            case = b.ngi_case(data, Path(tmp))
        else:
            where = f"in {data}" if data else f"given (--peer-data, or ${PEER_DATA_ENV})"
            print(f"orthomvp: no ngi-aerial data {where}: using a synthetic aerial scene")
            case = b.synthetic_case(Path(tmp))
        row = b.bench_orthority(case, res=res, repeat=repeat)
    print(b.format_orthority(row))
    return row


def bench_gdal_peer(data: Path | None, res: float | None, repeat: int) -> list[dict]:
    """``bench --peer gdal``: gdalwarp against orthomvp on the QuickBird RPC image, from the
    data folder above the ngi-aerial folder ``data`` (InputError without it or without
    gdalwarp), at ``res`` m or each of :data:`~orthomvp.bench.gdal.GDAL_RES`; printed."""
    from orthomvp.bench import gdal

    gdal.gdalwarp()
    if data is None:
        raise InputError(
            f"--peer gdal needs the shared data folder: give --peer-data DIR/ngi-aerial or set "
            f"${PEER_DATA_ENV}"
        )
    with tempfile.TemporaryDirectory(prefix="orthomvp-gdal-") as tmp:
        case = gdal.gdal_case(Path(data).parent, Path(tmp))
        rows = gdal.bench_gdal(case, (res,) if res else gdal.GDAL_RES, repeat)
    print(gdal.format_gdal(rows))
    return rows
