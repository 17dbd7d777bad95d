"""The ``orthomvp`` command line.

Every user error becomes one line on stderr (``orthomvp: error: ...``) and exit status 2; outputs
are written atomically, so a failed command leaves nothing half-written.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from orthomvp import __version__
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
        choices=("body", "map"),
        default="body",
        help="world frame of the cameras: body-fixed Cartesian metres (default) or the DEM's "
        "projected CRS taken as Cartesian (easting, northing, height)",
    )


def _read_terrain(args: argparse.Namespace):  # noqa: ANN202
    from orthomvp.terrain import Terrain

    return Terrain.read(args.dem, args.radius_values, args.world, args.dem_crs)


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
        "grid cell, holes skipped) and export it. PLY gets vertex colours, OBJ and GLB an image "
        "texture, from --texture.",
    )
    p.add_argument("dem", type=Path)
    p.add_argument("-o", "--output", type=Path, required=True, help="OUT.ply, OUT.obj or OUT.glb")
    p.add_argument("--texture", type=Path, help="a raster on the DEM grid to colour the mesh")
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
        "bench",
        help="benchmarks, each reported as a ratio to a baseline measured in the same run",
        description="Ray casting: rays per second through orthomvp's first_hit and through "
        "the bare backend call on the same rays, for Embree and Open3D.",
    )
    p.add_argument("--size", type=int, default=1000, help="DEM posts per side (1000)")
    p.add_argument("--rays", type=int, default=1_000_000, help="number of rays (1,000,000)")
    p.add_argument("--json", type=Path, help="also write the figures as JSON")
    return parser


def _cmd_synth(args: argparse.Namespace) -> None:
    from orthomvp.raster import atomic_dir
    from orthomvp.synth import make_scene

    scene = make_scene(args.kind, args.size, args.spacing, args.gsd_ratio, args.seed)
    with atomic_dir(args.outdir) as tmp:
        summary = scene.write(tmp, args.supersample, progress=not args.quiet)
    print(f"wrote {args.kind} scene with {len(summary['views'])} views to {args.outdir}")


def _cmd_mesh(args: argparse.Namespace) -> None:
    from orthomvp.mesh import export_mesh, terrain_mesh
    from orthomvp.raster import read_image

    terrain = _read_terrain(args)
    tmesh = terrain_mesh(terrain)
    texture = read_image(args.texture) if args.texture else None
    export_mesh(tmesh, args.output, texture, args.local_origin, args.decimate)
    m = tmesh.mesh
    note = f", decimated to about {args.decimate:,} triangles" if args.decimate else ""
    print(f"wrote {args.output}: {len(m.vertices):,} vertices, {len(m.faces):,} triangles{note}")
    if args.local_origin:
        print("local origin (body-fixed metres): {:.3f} {:.3f} {:.3f}".format(*tmesh.origin))


def _cmd_bench(args: argparse.Namespace) -> None:
    from orthomvp.bench import bench_raycast, format_raycast
    from orthomvp.raster import atomic_path

    rows = bench_raycast(args.size, args.rays)
    print(format_raycast(rows))
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps({"raycast": rows}, indent=2))


def _cmd_demo(args: argparse.Namespace) -> None:
    from orthomvp.demo import run_demo

    run_demo(args.outdir, quiet=args.quiet)


COMMANDS = {"synth": _cmd_synth, "mesh": _cmd_mesh, "bench": _cmd_bench, "demo": _cmd_demo}


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
    return 0


def main_entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    main_entry()
