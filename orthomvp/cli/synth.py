"""``orthomvp synth``: a synthetic scene with exact ground truth."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import PATH, Number, check_outdir, overwrite_option, quiet, say

KINDS = ("planar", "crater", "hills", "city")
"""the scene kinds of :func:`orthomvp.synthetic.make_scene` (not imported: --help stays fast)"""
SPACING_RANGE = (0.01, 10_000.0)
GSD_RATIO_RANGE = (0.05, 20.0)
MAX_SUPERSAMPLE = 16
SENSORS = ("frame", "linescan")
"""the ranges and sensors of :mod:`orthomvp.synthetic` (tests check that they agree)"""


@click.command(cls=Command, short_help="write a synthetic scene with exact ground truth")
@click.argument(
    "kind",
    type=click.Choice(KINDS),
    metavar="KIND",
    help="planar (a tilted plane under four orbital frames), crater (a complex crater, one "
    "oblique, one near-nadir and two along-track views), hills (rolling terrain under four "
    "along-track frames) or city (box buildings with gabled roofs and trees on gentle ground, "
    "UTM 33N, four oblique aerial frames in the map frame)",
)
@click.argument(
    "outdir",
    type=PATH,
    metavar="OUTDIR",
    help="the scene directory (created if absent; one that holds files needs --overwrite; "
    "nothing is written on failure)",
)
@click.option(
    "--size",
    type=click.IntRange(min=8),
    metavar="N",
    show_default="per kind: 64/160/128/160",
    help="DEM posts per side",
)
@click.option(
    "--spacing",
    type=Number(min=SPACING_RANGE[0], max=SPACING_RANGE[1]),
    metavar="METRES",
    show_default="per kind: 40/40/30/0.5",
    help="DEM post spacing, metres",
)
@click.option(
    "--gsd-ratio",
    type=Number(min=GSD_RATIO_RANGE[0], max=GSD_RATIO_RANGE[1]),
    metavar="RATIO",
    show_default="per kind: 0.8/0.8/0.8/0.5",
    help="image ground sample distance / DEM post spacing",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    metavar="N",
    help="random seed of terrain and albedo",
)
@click.option(
    "--sensor",
    type=click.Choice(SENSORS),
    default="frame",
    help="frame: the kind's pinhole views (.tsai); linescan: one line scanner (USGS CSM ISD "
    "linescan.json) on a circular orbit looking 55 degrees off nadir across track, at the "
    "crater's oblique frame's geometry",
)
@click.option(
    "--supersample",
    type=click.IntRange(min=1, max=MAX_SUPERSAMPLE),
    default=3,
    metavar="N",
    help="rays per pixel side when rendering",
)
@overwrite_option
def synth(
    kind: str,
    outdir: Path,
    size: int | None,
    spacing: float | None,
    gsd_ratio: float | None,
    seed: int,
    sensor: str,
    supersample: int,
    overwrite: bool,
) -> None:
    """Write a synthetic scene: DEM GeoTIFF (heights in metres; lunar kinds above the
    1737400 m sphere, city in UTM 33N with cameras in its map frame), rendered images (float32
    TIFF), cameras (.tsai, or ISD .json for --sensor linescan: each line rendered from its own
    sensor position), truth rasters (radiance, per-camera visibility: 0 outside image, 1
    visible, 2 occluded, 3 facing away) and scene.json."""
    from orthomvp.io.outputs import atomic_dir
    from orthomvp.synthetic import make_scene
    from orthomvp.synthetic.kinds import DEFAULTS
    from orthomvp.synthetic.scene import check_scene_memory

    check_outdir(outdir, "OUTDIR", overwrite=overwrite)
    size = size or DEFAULTS[kind][0]
    check_scene_memory(size, gsd_ratio or DEFAULTS[kind][2], "choose a smaller --size")
    scene = make_scene(
        kind, size=size, spacing=spacing, gsd_ratio=gsd_ratio, seed=seed, sensor=sensor
    )
    with atomic_dir(outdir) as tmp:
        summary = scene.write(tmp, supersample=supersample, progress=not quiet())
    say(f"wrote {kind} scene with {len(summary['views'])} views to {outdir}")
