"""The ``orthomvp`` command line.

Every user error becomes one line on stderr (``orthomvp: error: ...``) and exit status 2; outputs
are written atomically, so a failed command leaves nothing half-written.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from orthomvp import __version__
from orthomvp.camera import load_view
from orthomvp.errors import OrthoMVPError


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"orthomvp: error: {self.prog.removeprefix('orthomvp ')}: {message}\n")


def _add_dem_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--radius-values",
        action="store_true",
        help="DEM values are radii from the body centre in metres (the MVP paper's convention) "
        "instead of heights above the CRS's reference surface",
    )
    p.add_argument(
        "--dem-crs",
        metavar="CRS",
        help="CRS of the DEM (PROJ string, WKT or e.g. IAU_2015:30100); overrides the file's, "
        "needed when the file has none",
    )
    p.add_argument(
        "--world",
        choices=("auto", "body", "map"),
        default="auto",
        help="world frame of the cameras: body-fixed Cartesian metres, or the DEM's projected "
        "CRS taken as Cartesian (easting, northing, height); auto (default) picks it from the "
        "camera centres and the DEM (body for geographic CRSs and when no camera is given) "
        "and asks for body or map when that is ambiguous",
    )


def _add_eps_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--eps",
        type=float,
        help="visibility tolerance in DEM posts (default: max(4, image ground sample distance "
        "in posts); see the README)",
    )


def _pair_paths(args: argparse.Namespace, minimum: int = 1) -> list[tuple[Path, Path]]:
    """The IMAGE CAMERA pairs of ``args.pairs``; at least ``minimum`` of them."""
    from orthomvp.errors import InputError

    if len(args.pairs) % 2:
        raise InputError(f"{args.command} needs IMAGE CAMERA pairs: got an odd number of files")
    if len(args.pairs) < 2 * minimum:
        raise InputError(f"{args.command} needs at least {minimum} IMAGE CAMERA pairs")
    return list(zip(args.pairs[::2], args.pairs[1::2], strict=True))


def _warn_partial(vis, terrain, what: str) -> None:  # noqa: ANN001
    outside = int(((vis.codes == 0) & terrain.valid).sum())
    if outside:
        share = 100 * (1 - outside / int(terrain.valid.sum()))
        print(
            f"orthomvp: warning: {what} covers {share:.1f}% of the DEM's posts; the rest is nodata",
            file=sys.stderr,
        )


def _read_terrain(args: argparse.Namespace, cameras: Sequence = ()):  # noqa: ANN202
    """The DEM of ``args``; ``--world auto`` picks the frame from the ``cameras``' centres (see
    :func:`orthomvp.world.detect_world`), body-fixed when there are none."""
    from dataclasses import replace

    from orthomvp.terrain import Terrain
    from orthomvp.world import detect_world

    world = "body" if args.world == "auto" else args.world
    terrain = Terrain.read(args.dem, args.radius_values, world, args.dem_crs)
    if args.world == "auto" and cameras:
        centres = np.array([camera.center for camera in cameras])
        terrain = replace(terrain, world=detect_world(terrain, centres))
    return terrain


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with all subcommands."""
    parser = _Parser(
        prog="orthomvp",
        description="Occlusion-aware orthorectification and multi-view DEM refinement "
        "for planetary images.",
    )
    parser.add_argument("--version", action="version", version=f"orthomvp {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars or notes")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser(
        "demo",
        help="run the pipeline end to end on a built-in synthetic scene",
        description="Make the synthetic crater scene, mesh it, and write every output into "
        "OUTDIR (default ./orthomvp-demo), then print a summary.",
    )
    p.add_argument("outdir", nargs="?", default="orthomvp-demo", type=Path)

    p = sub.add_parser(
        "synth",
        help="write a synthetic scene with exact ground truth",
        description="Write a synthetic lunar scene: DEM GeoTIFF (heights in metres above the "
        "1737400 m sphere), rendered images (float32 TIFF), cameras (.tsai), truth rasters "
        "(radiance, per-camera visibility: 0 outside image, 1 visible, 2 occluded, 3 facing "
        "away) and scene.json.",
    )
    p.add_argument("kind", choices=("planar", "crater", "hills"))
    p.add_argument("outdir", type=Path)
    p.add_argument("--size", type=int, help="DEM posts per side (default per kind: 64/160/128)")
    p.add_argument("--spacing", type=float, help="DEM post spacing, metres (default 40/40/30)")
    p.add_argument(
        "--gsd-ratio",
        type=float,
        default=0.8,
        help="image ground sample distance / DEM post spacing (default 0.8)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed of terrain and albedo")
    p.add_argument(
        "--supersample", type=int, default=3, help="rays per pixel side when rendering (3)"
    )

    p = sub.add_parser(
        "mesh",
        help="export the DEM as a Cartesian mesh (PLY, OBJ, GLB)",
        description="Triangulate the DEM in body-fixed Cartesian metres (two triangles per "
        "grid cell, holes skipped) and export it. PLY gets vertex colours, OBJ (with OUT.mtl "
        "and OUT.png beside it) and GLB an image texture, from --texture or --error-against.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("-o", "--output", type=Path, required=True, help="OUT.ply, OUT.obj or OUT.glb")
    source = p.add_mutually_exclusive_group()
    source.add_argument(
        "--texture", type=Path, help="a raster on the DEM grid to colour the mesh (see --colour-by)"
    )
    source.add_argument(
        "--error-against",
        type=Path,
        metavar="TRUTH.tif",
        help="colour by the height error DEM - TRUTH in metres (TRUTH on the DEM grid)",
    )
    p.add_argument(
        "--colour-by",
        choices=("image", "visibility", "error"),
        help="what --texture holds: image (grey or RGB, stretched; the default), visibility "
        "(codes 0-3 of `orthomvp visibility`, in the figures' colours) or error (metres: blue "
        "below zero, red above; the default with --error-against)",
    )
    p.add_argument(
        "--error-limit",
        type=float,
        metavar="M",
        help="error colours saturate at +-M metres (default: the 99th percentile of |error|)",
    )
    p.add_argument(
        "--local-origin",
        action="store_true",
        help="write vertices relative to the mesh's local origin (printed) instead of "
        "body-fixed coordinates",
    )
    p.add_argument(
        "--decimate",
        type=int,
        metavar="TRIANGLES",
        help="simplify to about this many triangles (Open3D quadric decimation)",
    )
    _add_dem_options(p)

    p = sub.add_parser(
        "render",
        help="offscreen 3D snapshot of the DEM, its cameras and a result on its grid",
        description="Render the DEM mesh offscreen to an image: shaded relief, or draped with "
        "an orthophoto, or coloured by visibility codes (occluded posts green) or by the height "
        "error FITTED - TRUTH (metres); cameras drawn as numbered frusta, optionally with rays "
        "to their first hits.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("-o", "--output", type=Path, required=True, help="SNAP.png (or .jpg)")
    colour = p.add_mutually_exclusive_group()
    colour.add_argument("--ortho", type=Path, metavar="ORTHO.tif", help="drape an orthophoto")
    colour.add_argument(
        "--visibility", type=Path, metavar="VIS.tif", help="colour by visibility codes"
    )
    colour.add_argument(
        "--heights", type=Path, metavar="FITTED.tif", help="colour by height error (with --truth)"
    )
    p.add_argument("--truth", type=Path, metavar="TRUTH.tif", help="the truth for --heights")
    p.add_argument(
        "--camera",
        type=Path,
        nargs="+",
        action="extend",
        default=[],
        metavar="CAM",
        help="cameras to draw (.tsai, .pinhole or .json), numbered from 1",
    )
    p.add_argument("--rays", type=int, default=0, metavar="N", help="rays drawn per camera (0)")
    p.add_argument("--view", choices=("oblique", "top", "from-camera"), default="oblique")
    p.add_argument(
        "--camera-index",
        type=int,
        default=1,
        metavar="N",
        help="the camera that --view from-camera looks through (1-based, default 1)",
    )
    p.add_argument(
        "--azimuth",
        type=float,
        metavar="DEG",
        help="oblique view from this azimuth, degrees clockwise from grid north (default: "
        "opposite the first camera, else 210)",
    )
    p.add_argument(
        "--elevation", type=float, default=45.0, metavar="DEG", help="oblique view elevation (45)"
    )
    p.add_argument("--exaggerate", type=float, default=1.0, metavar="K", help="vertical (1)")
    p.add_argument(
        "--error-limit",
        type=float,
        metavar="M",
        help="height error colours saturate at +-M metres (default: 99th percentile of |error|)",
    )
    p.add_argument(
        "--size", type=int, nargs=2, metavar=("W", "H"), help="image size (default 1024 768)"
    )
    p.add_argument("--title", help="a caption in the upper left corner")
    p.add_argument("--no-legend", action="store_true", help="no legend or colour bar")
    _add_dem_options(p)

    p = sub.add_parser(
        "visibility",
        help="per-post visibility of one image: the epsilon round-trip test",
        description="Classify every DEM post for one camera: 0 no data / outside the image, "
        "1 visible, 2 occluded by terrain, 3 facing away. Written as a uint8 GeoTIFF on the "
        "DEM grid.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("image", type=Path, help="the image (gives the image size)")
    p.add_argument(
        "camera",
        type=Path,
        help="camera model: .tsai, .pinhole, .json, or an Orthority exterior file (.csv, .geojson; "
        "the row of IMAGE, the one .yaml beside it)",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="VIS.tif")
    _add_eps_option(p)
    _add_dem_options(p)

    p = sub.add_parser(
        "ortho",
        help="occlusion-aware orthophoto of one image",
        description="Orthorectify IMAGE through CAMERA onto the DEM grid (all bands, float32, "
        "NaN = nodata). Posts that are not visible (occluded, facing away, outside) are "
        "nodata unless --no-occlusion asks for the naive orthophoto.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("image", type=Path)
    p.add_argument(
        "camera",
        type=Path,
        help="camera model: .tsai, .pinhole, .json, or an Orthority exterior file (.csv, .geojson; "
        "the row of IMAGE, the one .yaml beside it)",
    )
    p.add_argument("-o", "--output", type=Path, required=True, help="ORTHO.tif")
    p.add_argument("--visibility", type=Path, metavar="VIS.tif", help="also write visibility")
    p.add_argument("--interp", choices=("nearest", "bilinear", "cubic"), default="bilinear")
    p.add_argument(
        "--no-occlusion",
        action="store_true",
        help="naive orthophoto: every post inside the image gets a value (ghosts included)",
    )
    p.add_argument(
        "--res",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="output pixel size in DEM CRS units (default: the DEM's)",
    )
    p.add_argument(
        "--bounds",
        type=float,
        nargs=4,
        metavar=("LEFT", "BOTTOM", "RIGHT", "TOP"),
        help="output extent in DEM CRS units (default: the DEM's)",
    )
    _add_eps_option(p)
    _add_dem_options(p)

    p = sub.add_parser(
        "mosaic",
        help="one orthophoto from many images, occluded posts filled from other views",
        description="Orthorectify every IMAGE CAMERA pair (mvpgui order) onto the DEM grid; "
        "each post takes its value from the visible view with the smallest emission angle. "
        "--source records which image (1-based, in command-line order; 0 = none) each post "
        "came from.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("pairs", type=Path, nargs="+", metavar="IMAGE CAMERA")
    p.add_argument("-o", "--output", type=Path, required=True, help="MOSAIC.tif")
    p.add_argument("--source", type=Path, metavar="SOURCE.tif", help="also write the sources")
    p.add_argument("--interp", choices=("nearest", "bilinear", "cubic"), default="bilinear")
    _add_eps_option(p)
    _add_dem_options(p)

    p = sub.add_parser(
        "explore",
        help="explore the MVP objective at one DEM post (interactive or scripted)",
        description="The objective explorer, successor of mvpgui: an mvp> prompt with "
        "commands to plot the MVP objective against height (rplot) and orientation (llplot), "
        "list the views, show the patches, run and trace the optimiser, and sweep the window "
        "size; 'help' lists them. -c and --script run the same commands without a prompt "
        "and stop with exit status 2 at the first bad one.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("pairs", type=Path, nargs="+", metavar="IMAGE CAMERA")
    p.add_argument(
        "-c", "--commands", metavar="CMDS", help="commands to run, separated by ';' or newlines"
    )
    p.add_argument("--script", type=Path, metavar="FILE", help="run the commands in FILE")
    p.add_argument(
        "--levels", type=int, default=3, help="coarse-to-fine pyramid levels for fit (3)"
    )
    _add_eps_option(p)
    _add_dem_options(p)

    p = sub.add_parser(
        "fit",
        help="refine the DEM with the multi-view plane fitter (MVP)",
        description="Fit a plane (height, normal) at every DEM post to the images in which "
        "the post is visible, so that the images projected onto it agree (MVP paper eqs. "
        "11-21; coarse to fine, Levenberg-Marquardt, outlier views dropped). Writes the "
        "refined DEM (heights in the input's convention, NaN where fewer than 2 views see a "
        "post) and, on request, the other per-post results, all on the DEM grid.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("pairs", type=Path, nargs="+", metavar="IMAGE CAMERA")
    p.add_argument("-o", "--output", type=Path, required=True, help="FITTED.tif")
    p.add_argument(
        "--normals",
        type=Path,
        metavar="N.tif",
        help="write the fitted normals: n_theta, n_phi (eq. 11, degrees) and the tilt from the "
        "local vertical (degrees)",
    )
    p.add_argument("--cost", type=Path, metavar="C.tif", help="write the final cost (eq. 20)")
    p.add_argument("--views", type=Path, metavar="V.tif", help="write the number of views used")
    p.add_argument(
        "--uncertainty",
        type=Path,
        metavar="U.tif",
        help="write the 1-sigma height uncertainty (metres) and a converged flag (band 2)",
    )
    p.add_argument("--hwin", type=int, default=10, help="window half-size in posts (10)")
    p.add_argument("--sigma", type=float, help="Gaussian window sigma in posts (default hwin / 2)")
    p.add_argument(
        "--levels", type=int, default=3, help="coarse-to-fine pyramid levels (3; 1 = off)"
    )
    p.add_argument(
        "--reject-below",
        type=float,
        default=0.5,
        metavar="RHO",
        help="drop a view whose patch correlates with the other views' mean below RHO (0.5)",
    )
    p.add_argument("--no-reject", action="store_true", help="keep every view (no outliers)")
    p.add_argument(
        "--deconvolve",
        type=int,
        default=1,
        metavar="STEPS",
        help="Van Cittert steps from plane heights to surface heights (1; 0 = plane heights)",
    )
    _add_eps_option(p)
    _add_dem_options(p)

    p = sub.add_parser(
        "eps-study",
        help="sweep the visibility tolerance on a synthetic scene with truth",
        description="Score the visibility test against the marched truth of a scene written "
        "by 'orthomvp synth', for a range of epsilons (DEM posts) and optional DEM noise: "
        "precision, recall and F1 per view (CSV) and a plot (PNG).",
    )
    p.add_argument("scene", type=Path, help="a scene directory from 'orthomvp synth'")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("eps-study"),
        help="output prefix: writes PREFIX.csv and PREFIX.png (default eps-study)",
    )
    p.add_argument("--eps", type=float, nargs="+", help="epsilons to try, DEM posts")
    p.add_argument(
        "--dem-noise",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="METRES",
        help="standard deviations of Gaussian noise added to the DEM (default 0)",
    )

    p = sub.add_parser(
        "bench",
        help="benchmarks, each reported as a ratio to a baseline measured in the same run",
        description="Ray casting: rays per second through orthomvp's first_hit and through "
        "the bare backend call on the same rays, for Embree and Open3D. Orthophoto: the "
        "occlusion-aware orthophoto of one image against the bare Embree cast of one ray per "
        "post, in the same run. MVP: the plane fit of a synthetic hills DEM from its 4 views "
        "against bare cv2.remap of as many bilinear samples from the same images, in the same "
        "run. --peer orthority runs instead the side-by-side comparison with Orthority (when "
        "installed): one ngi-aerial frame (or, without the data, a synthetic aerial scene) onto "
        "the same grid with both tools, end to end from files to GeoTIFF, best of --peer-repeat "
        "alternating runs; ratio = orthomvp time / Orthority time.",
    )
    p.add_argument("--size", type=int, default=1000, help="ray-casting DEM posts per side")
    p.add_argument("--rays", type=int, default=1_000_000, help="number of rays (1,000,000)")
    p.add_argument(
        "--ortho-size", type=int, default=2000, help="orthophoto DEM posts per side (2000; 0 skips)"
    )
    p.add_argument(
        "--mvp-size", type=int, default=96, help="MVP fit DEM posts per side (96; 0 skips)"
    )
    p.add_argument(
        "--peer",
        choices=("orthority",),
        help="only compare orthomvp (occlusion on and off) with this tool on the same grid",
    )
    p.add_argument(
        "--peer-data",
        type=Path,
        default=Path("../shared/data/ngi-aerial"),
        metavar="DIR",
        help="the ngi-aerial data for --peer (default ../shared/data/ngi-aerial; a synthetic "
        "scene when absent)",
    )
    p.add_argument(
        "--peer-res",
        type=float,
        metavar="M",
        help="output post spacing for --peer in metres (default: the DEM's, 24 m for ngi-aerial)",
    )
    p.add_argument(
        "--peer-repeat", type=int, default=3, metavar="N", help="--peer keeps the best of N (3)"
    )
    p.add_argument("--json", type=Path, help="also write the figures as JSON")
    return parser


def _cmd_synth(args: argparse.Namespace) -> None:
    from orthomvp.raster import atomic_dir
    from orthomvp.synthetic import make_scene

    scene = make_scene(args.kind, args.size, args.spacing, args.gsd_ratio, args.seed)
    with atomic_dir(args.outdir) as tmp:
        summary = scene.write(tmp, args.supersample, progress=not args.quiet)
    print(f"wrote {args.kind} scene with {len(summary['views'])} views to {args.outdir}")


def _cmd_mesh(args: argparse.Namespace) -> None:
    from orthomvp.errors import InputError
    from orthomvp.mesh import terrain_mesh
    from orthomvp.present.colours import error_colour_limit, height_error
    from orthomvp.present.export import export_mesh
    from orthomvp.raster import read_image
    from orthomvp.terrain import Terrain

    kind = args.colour_by or ("error" if args.error_against else "image")
    if args.error_against and kind != "error":
        raise InputError(f"--error-against colours by height error, not by {kind}")
    if args.colour_by and not (args.texture or args.error_against):
        raise InputError("--colour-by needs a raster: give --texture (or --error-against)")
    if args.error_limit is not None and kind != "error":
        raise InputError("--error-limit applies to error colours only (--colour-by error)")
    terrain = _read_terrain(args)
    tmesh = terrain_mesh(terrain)
    if args.error_against:
        truth = Terrain.read(args.error_against, args.radius_values, terrain.world, args.dem_crs)
        texture = height_error(terrain, truth)
    else:
        texture = read_image(args.texture) if args.texture else None
    export_mesh(
        tmesh, args.output, texture, args.local_origin, args.decimate, kind, args.error_limit
    )
    m = tmesh.mesh
    note = f", decimated to about {args.decimate:,} triangles" if args.decimate else ""
    print(f"wrote {args.output}: {len(m.vertices):,} vertices, {len(m.faces):,} triangles{note}")
    if kind == "error":
        limit = error_colour_limit(texture, args.error_limit)
        print(f"error colours: blue -{limit:.3g} m, white 0, red +{limit:.3g} m (clipped beyond)")
    if args.local_origin:
        print("local origin (body-fixed metres): {:.3f} {:.3f} {:.3f}".format(*tmesh.origin))


def _cmd_render(args: argparse.Namespace) -> None:
    from orthomvp.camera import read_camera
    from orthomvp.errors import InputError
    from orthomvp.present.snapshot import snapshot
    from orthomvp.raster import read_image

    if (args.heights is None) != (args.truth is None):
        raise InputError("--heights and --truth go together: the error is FITTED - TRUTH")
    cameras = [read_camera(path) for path in args.camera]
    if args.view == "from-camera" and not 1 <= args.camera_index <= len(cameras):
        raise InputError(
            f"--view from-camera needs --camera-index between 1 and the number of --camera "
            f"files ({len(cameras)}), got {args.camera_index}"
        )
    terrain = _read_terrain(args, cameras)
    rasters = {
        key: read_image(path)
        for key, path in (
            ("ortho", args.ortho),
            ("visibility", args.visibility),
            ("heights", args.heights),
            ("truth", args.truth),
        )
        if path is not None
    }
    snap = snapshot(
        terrain,
        **rasters,
        cameras=cameras,
        rays=args.rays,
        view=args.view,
        view_camera=args.camera_index - 1,
        azimuth=args.azimuth,
        elevation=args.elevation,
        exaggerate=args.exaggerate,
        size=tuple(args.size) if args.size else None,
        legend=not args.no_legend,
        title=args.title,
        error_limit=args.error_limit,
    )
    try:
        snap.save(args.output)
    finally:
        snap.close()
    height, width = snap.image.shape[:2]
    shown = next((k for k in ("ortho", "visibility", "heights") if k in rasters), "relief")
    print(
        f"wrote {args.output}: {width} x {height} {args.view} view, {shown}, "
        f"{len(cameras)} camera(s)"
    )


def _cmd_bench(args: argparse.Namespace) -> None:
    from orthomvp.bench import (
        bench_mvp,
        bench_ortho,
        bench_raycast,
        format_mvp,
        format_ortho,
        format_raycast,
    )
    from orthomvp.raster import atomic_path

    if args.peer:
        results = {"orthority": _bench_peer(args)}
    else:
        results = {"raycast": bench_raycast(args.size, args.rays)}
        print(format_raycast(results["raycast"]))
        if args.ortho_size:
            results["ortho"] = bench_ortho(args.ortho_size)
            print(format_ortho(results["ortho"]))
        if args.mvp_size:
            results["mvp"] = bench_mvp(args.mvp_size)
            print(format_mvp(results["mvp"]))
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(results, indent=2))


def _bench_peer(args: argparse.Namespace) -> dict:
    """``bench --peer orthority``: the side-by-side run, printed; returns its figures."""
    import tempfile

    from orthomvp.bench import (
        bench_orthority,
        format_orthority,
        import_orthority,
        ngi_case,
        synthetic_case,
    )
    from orthomvp.errors import InputError

    import_orthority()
    if args.peer_res is not None and not args.peer_res > 0:
        raise InputError(f"--peer-res must be a positive number of metres, got {args.peer_res}")
    if args.peer_repeat < 1:
        raise InputError(f"--peer-repeat must be at least 1, got {args.peer_repeat}")
    with tempfile.TemporaryDirectory(prefix="orthomvp-peer-") as tmp:
        if (args.peer_data / "dem.tif").is_file():
            case = ngi_case(args.peer_data, Path(tmp))
        else:
            print(f"no ngi-aerial data in {args.peer_data}: using a synthetic aerial scene")
            case = synthetic_case(Path(tmp))
        row = bench_orthority(case, args.peer_res, args.peer_repeat)
    print(format_orthority(row))
    return row


def _cmd_visibility(args: argparse.Namespace) -> None:
    from orthomvp.raster import write_geotiff
    from orthomvp.visibility import compute_visibility

    _, camera = load_view(args.image, args.camera)
    terrain = _read_terrain(args, [camera])
    vis = compute_visibility(terrain, camera, args.eps, progress=not args.quiet)
    _warn_partial(vis, terrain, str(args.image))
    write_geotiff(args.output, vis.codes, terrain.transform, terrain.crs, nodata=0)
    counts = ", ".join(f"{v:,} {k}" for k, v in vis.counts().items())
    print(f"wrote {args.output}: {counts}")


def _cmd_ortho(args: argparse.Namespace) -> None:
    from orthomvp.mesh import terrain_mesh
    from orthomvp.ortho import orthorectify
    from orthomvp.raster import write_geotiff
    from orthomvp.raycast import RayCaster

    image, camera = load_view(args.image, args.camera)
    terrain = _read_terrain(args, [camera])
    caster = RayCaster(terrain_mesh(terrain))
    grid = terrain.regrid(args.res, args.bounds) if args.res or args.bounds else terrain
    ortho = orthorectify(
        grid,
        image,
        camera,
        not args.no_occlusion,
        args.eps,
        args.interp,
        caster=caster,
        progress=not args.quiet,
        post_scale=_post_scale(grid, terrain),
    )
    _warn_partial(ortho.visibility, grid, str(args.image))
    write_geotiff(args.output, ortho.data, ortho.transform, ortho.crs, nodata=np.nan)
    if args.visibility:
        write_geotiff(args.visibility, ortho.visibility.codes, grid.transform, grid.crs, nodata=0)
    filled = int(np.isfinite(ortho.data).all(axis=0).sum())
    print(f"wrote {args.output}: {filled:,} of {grid.values.size:,} posts filled")


def _post_scale(grid, terrain) -> float:  # noqa: ANN001
    """Size of one output post in DEM posts (for the epsilon test on a resampled grid)."""
    return float(np.mean(grid.post_spacing()) / np.mean(terrain.post_spacing()))


def _cmd_mosaic(args: argparse.Namespace) -> None:
    from orthomvp.ortho import mosaic
    from orthomvp.raster import write_geotiff

    views = [load_view(image, camera) for image, camera in _pair_paths(args)]
    terrain = _read_terrain(args, [v[1] for v in views])
    result = mosaic(terrain, views, args.eps, args.interp, progress=not args.quiet)
    write_geotiff(args.output, result.data, result.transform, result.crs, nodata=np.nan)
    if args.source:
        write_geotiff(args.source, result.source, result.transform, result.crs, nodata=0)
    counts = np.bincount(result.source.ravel(), minlength=len(views) + 1)
    parts = ", ".join(
        f"{counts[k]:,} from {args.pairs[2 * k - 2]}" for k in range(1, len(views) + 1)
    )
    print(f"wrote {args.output}: {parts}; {counts[0]:,} posts visible in no image")


def _cmd_fit(args: argparse.Namespace) -> None:
    from orthomvp.errors import InputError
    from orthomvp.mvp import FitOptions, fit_dem
    from orthomvp.raster import write_geotiff

    pairs = _pair_paths(args, minimum=2)
    if args.hwin < 1 or (args.sigma is not None and not args.sigma > 0) or args.levels < 1:
        raise InputError("--hwin and --levels must be >= 1 and --sigma positive")
    views = [load_view(image, camera) for image, camera in pairs]
    terrain = _read_terrain(args, [v[1] for v in views])
    opts = FitOptions(
        hwin=args.hwin,
        sigma=args.sigma,
        levels=args.levels,
        reject_below=None if args.no_reject else args.reject_below,
        deconvolve=max(args.deconvolve, 0),
    )
    res = fit_dem(
        terrain,
        [v[0] for v in views],
        [v[1] for v in views],
        opts,
        eps=args.eps,
        progress=not args.quiet,
    )
    t, crs = terrain.transform, terrain.crs
    write_geotiff(args.output, res.heights.astype(np.float32), t, crs, nodata=np.nan)
    if args.normals:
        up = terrain.up_vectors(terrain.world_points())
        tilt = np.degrees(np.arccos(np.clip(np.sum(res.normals * up, axis=-1), -1, 1)))
        bands = np.stack([res.n_theta, res.n_phi, tilt]).astype(np.float32)
        names = ["n_theta_deg", "n_phi_deg", "tilt_deg"]
        write_geotiff(args.normals, bands, t, crs, nodata=np.nan, band_names=names)
    if args.cost:
        write_geotiff(args.cost, res.cost.astype(np.float32), t, crs, nodata=np.nan)
    if args.views:
        write_geotiff(args.views, res.views.astype(np.uint8), t, crs)
    if args.uncertainty:
        bands = np.stack([res.sigma_h, np.where(res.resolved, res.converged, np.nan)])
        names = ["sigma_h_m", "converged"]
        write_geotiff(
            args.uncertainty, bands.astype(np.float32), t, crs, nodata=np.nan, band_names=names
        )
    ok = res.resolved
    shift = res.heights[ok] - res.initial[ok]
    print(
        f"wrote {args.output}: {int(ok.sum()):,} of {ok.size:,} posts fitted "
        f"({int(res.converged.sum()):,} converged); change from the input: median "
        f"{np.median(shift):+.2f}, RMS {np.sqrt(np.mean(shift**2)):.2f}; median uncertainty "
        f"{np.nanmedian(res.sigma_h[ok]):.2f}"
    )


def _cmd_explore(args: argparse.Namespace) -> None:
    from orthomvp.errors import InputError
    from orthomvp.explore import Explorer, ExplorerShell, run_commands, split_commands

    pairs = _pair_paths(args)
    if args.commands is not None and args.script is not None:
        raise InputError("give -c or --script, not both")
    if args.levels < 1:
        raise InputError("--levels must be >= 1")
    script = None
    if args.script is not None:
        script = split_commands(args.script.read_text())
    elif args.commands is not None:
        script = split_commands(args.commands)
    elif not sys.stdin.isatty():
        script = split_commands(sys.stdin.read())
    if not args.quiet:
        print("Loading images...", end=" ", flush=True)
    views = [load_view(image, camera) for image, camera in pairs]
    terrain = _read_terrain(args, [v[1] for v in views])
    explorer = Explorer(
        terrain,
        [v[0] for v in views],
        [v[1] for v in views],
        [image.name for image, _ in pairs],
        eps=args.eps,
        levels=args.levels,
    )
    shell = ExplorerShell(explorer)
    if not args.quiet:
        rows, cols = terrain.shape
        print(
            f"Done! {len(views)} views, DEM {cols} x {rows} posts of "
            f"{explorer.spacing:.1f} m; type help for the commands."
        )
        shell.do_poi("")
    if script is None:
        shell.cmdloop()
    else:
        run_commands(shell, script)


def _cmd_eps_study(args: argparse.Namespace) -> None:
    from orthomvp.epsstudy import DEFAULT_EPS_VALUES, eps_study, plot, write_csv

    eps = tuple(args.eps) if args.eps else DEFAULT_EPS_VALUES
    rows = eps_study(args.scene, eps, tuple(args.dem_noise))
    prefix = args.output
    write_csv(rows, prefix.with_suffix(".csv"))
    plot(rows, prefix.with_suffix(".png"))
    for r in rows:
        if r["eps"] == "default":
            print(
                f"{r['view']:>10} noise {r['noise_m']:g} m: default rule F1 visible "
                f"{r['f1_visible']:.4f}, hidden {r['f1_hidden']:.4f}"
            )
    print(f"wrote {prefix.with_suffix('.csv')} and {prefix.with_suffix('.png')}")


def _cmd_demo(args: argparse.Namespace) -> None:
    from orthomvp.demo import run_demo

    run_demo(args.outdir, quiet=args.quiet)


COMMANDS = {
    "synth": _cmd_synth,
    "mesh": _cmd_mesh,
    "render": _cmd_render,
    "visibility": _cmd_visibility,
    "ortho": _cmd_ortho,
    "mosaic": _cmd_mosaic,
    "fit": _cmd_fit,
    "explore": _cmd_explore,
    "eps-study": _cmd_eps_study,
    "bench": _cmd_bench,
    "demo": _cmd_demo,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        COMMANDS[args.command](args)
    except OrthoMVPError as exc:
        print(f"orthomvp: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"orthomvp: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("orthomvp: interrupted; no partial output was kept", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not a user error: still one line, unless debugging
        if os.environ.get("ORTHOMVP_DEBUG"):
            raise
        print(
            f"orthomvp: error: internal error ({type(exc).__name__}: {exc}); rerun with "
            "ORTHOMVP_DEBUG=1 for a traceback and please report it",
            file=sys.stderr,
        )
        return 2
    return 0


def main_entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    main_entry()
