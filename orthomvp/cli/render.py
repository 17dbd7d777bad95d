"""``orthomvp render``: an offscreen 3D snapshot of the DEM, its cameras and a result on its
grid."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command, Variadic
from orthomvp.cli.options import (
    FINITE,
    PATH,
    POSITIVE,
    DemInput,
    Number,
    Output,
    check_outputs,
    dem_argument,
    dem_options,
    enum_choice,
    error_limit_option,
    output_option,
    overwrite_options,
    say,
    usage_error,
)
from orthomvp.codes import View

MAX_RAYS = 10_000
"""as :data:`orthomvp.present.snapshot.MAX_RAYS` (not imported: --help stays fast)"""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".bmp")
"""the image formats a snapshot is saved in, by the extension (all written by Pillow)"""


@click.command(
    cls=Command,
    exclusive=[("ortho", "visibility", "heights")],
    short_help="offscreen 3D snapshot of the DEM, its cameras and a result on its grid",
)
@dem_argument
@output_option("SNAP", "SNAP.png (or .jpg, .tif, .webp, .bmp)")
@click.option("--ortho", type=PATH, metavar="ORTHO.tif", help="drape an orthophoto")
@click.option("--visibility", type=PATH, metavar="VIS.tif", help="colour by visibility codes")
@click.option(
    "--heights", type=PATH, metavar="FITTED.tif", help="colour by height error (with --truth)"
)
@click.option("--truth", type=PATH, metavar="TRUTH.tif", help="the truth for --heights")
@click.option(
    "--camera",
    "cameras",
    cls=Variadic,
    type=PATH,
    metavar="CAM ...",
    help="cameras to draw, numbered from 1: a camera file as the other commands read it "
    "(.tsai, .pinhole, our .json, a USGS CSM ISD or model state, an RPC file or a GeoTIFF with "
    "RPCs, a spiceinit'd ISIS3 .cub); an Orthority, OpenSfM or ODM file only when it holds one "
    "camera (no image picks the row here)",
)
@click.option(
    "--rays",
    type=click.IntRange(min=0, max=MAX_RAYS),
    default=0,
    metavar="N",
    help="rays drawn per camera",
)
@click.option(
    "--view",
    default=View.OBLIQUE.value,
    **enum_choice(View),
    help="oblique from --azimuth and --elevation, straight down, or through a frame camera "
    "(pinhole, CSM or ISIS frame; --camera-index)",
)
@click.option(
    "--camera-index",
    type=click.IntRange(min=1),
    default=1,
    metavar="N",
    help="the camera that --view from-camera looks through (1-based)",
)
@click.option(
    "--azimuth",
    type=FINITE,
    metavar="DEG",
    show_default="opposite the first camera, else 210",
    help="oblique view from this azimuth, degrees clockwise from grid north",
)
@click.option(
    "--elevation",
    type=Number(min=0, max=90, min_open=True),
    default=45.0,
    metavar="DEG",
    help="oblique view elevation, degrees",
)
@click.option("--exaggerate", type=POSITIVE, default=1.0, metavar="K", help="vertical exaggeration")
@error_limit_option("height error colours saturate at +-M metres")
@click.option(
    "--size",
    type=click.IntRange(min=16, max=8192),
    nargs=2,
    metavar="W H",
    show_default="1024 768",
    help="image size in pixels",
)
@click.option("--title", help="a caption in the upper left corner")
@click.option("--no-legend", is_flag=True, help="no legend or colour bar")
@click.option(
    "--crop",
    is_flag=True,
    help="cut the empty background around the scene (the image gets smaller than --size)",
)
@overwrite_options
@dem_options
def render(
    dem: DemInput,
    output: Path,
    ortho: Path | None,
    visibility: Path | None,
    heights: Path | None,
    truth: Path | None,
    cameras: tuple[Path, ...],
    rays: int,
    view: View,
    camera_index: int,
    azimuth: float | None,
    elevation: float,
    exaggerate: float,
    error_limit: float | None,
    size: tuple[int, int] | None,
    title: str | None,
    no_legend: bool,
    crop: bool,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """Render the DEM mesh offscreen to an image: shaded relief, or draped with an
    orthophoto, or coloured by visibility codes (occluded posts green) or by the height error
    FITTED - TRUTH (metres); cameras drawn as numbered frusta, optionally with rays to their
    first hits. A raster on the DEM grid is draped as it is; any other georeferenced raster
    (finer, coarser, another extent or CRS) is sampled at the posts (the texel under each
    post; posts outside it have no value)."""
    from orthomvp.camera import read_camera
    from orthomvp.present.snapshot import SnapshotOptions, snapshot
    from orthomvp.present.texture import on_dem_grid

    if (heights is None) != (truth is None):
        raise usage_error("--heights and --truth go together: the error is FITTED - TRUTH")
    if error_limit is not None and heights is None:
        raise usage_error("--error-limit applies to the height error only (--heights, --truth)")
    if rays and not cameras:
        raise usage_error("--rays draws rays from cameras: give --camera")
    given = {"ortho": ortho, "visibility": visibility, "heights": heights, "truth": truth}
    inputs = [("DEM", dem.path)] + [(f"--{key}", path) for key, path in given.items()]
    inputs += [(f"--camera {k}", path) for k, path in enumerate(cameras, start=1)]
    check_outputs(
        [Output("-o", output, IMAGE_SUFFIXES, "an image")], inputs, overwrite, replace_input
    )
    models = [read_camera(path) for path in cameras]
    if view == View.FROM_CAMERA and not camera_index <= len(models):
        raise usage_error(
            f"--view from-camera needs --camera-index between 1 and the number of --camera "
            f"files ({len(models)}), got {camera_index}"
        )
    terrain = dem.read(models, spare=True)  # (a camera elsewhere is drawn where it is)
    rasters = {
        key: on_dem_grid(path, terrain, f"--{key} raster")
        for key, path in given.items()
        if path is not None
    }
    snap = snapshot(
        terrain,
        **rasters,
        cameras=models,
        options=SnapshotOptions(
            rays=rays,
            view=view,
            view_camera=camera_index - 1,
            azimuth=azimuth,
            elevation=elevation,
            exaggerate=exaggerate,
            size=size,
            legend=not no_legend,
            title=title,
            error_limit=error_limit,
            crop=crop,
        ),
    )
    try:
        snap.save(output)
    finally:
        snap.close()
    height, width = snap.image.shape[:2]
    shown = next((k for k in ("ortho", "visibility", "heights") if k in rasters), "relief")
    say(f"wrote {output}: {width} x {height} px {view} view, {shown}, {len(models)} camera(s)")
