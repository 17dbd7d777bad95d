"""``orthomvp visibility``, ``ortho`` and ``mosaic``: per-post visibility of an image, its
occlusion-aware orthophoto, and the orthophoto of many images with hidden posts filled from
other views. All three run through the streaming engine (:mod:`orthomvp.engine`): tiles of
the output grid in bounded memory, written as Cloud-Optimized or tiled GeoTIFF."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from orthomvp.cli.command import Command
from orthomvp.cli.engine_options import EngineInput, engine_options, warnings_as_lines
from orthomvp.cli.odm import command_views, odm_option
from orthomvp.cli.options import (
    OUT_FILE,
    DemInput,
    Output,
    camera_argument,
    check_outputs,
    dem_argument,
    dem_options,
    eps_option,
    image_argument,
    interp_option,
    optional_dem_argument,
    output_option,
    overwrite_options,
    own_camera,
    pairs_argument,
    quiet,
    say,
    usage_error,
    view_inputs,
)
from orthomvp.codes import Code, Interp

if TYPE_CHECKING:
    from orthomvp.camera import Camera
    from orthomvp.engine import Outputs, Plan, RunReport
    from orthomvp.ortho.composite import MosaicOptions

PRIORITIES = ("emission", "gsd", "nadir", "order")
FILLS = ("none", "any-view", "naive")
HOLES = ("empty", "behind", "inpaint", "naive")
BALANCES = ("none", "gain", "gain-offset")
"""As :data:`orthomvp.ortho.composite.PRIORITIES` and ``FILLS``, :data:`orthomvp.ortho.holes.HOLES`,
and
:data:`orthomvp.ortho.balance.BALANCES` (not imported: --help stays fast; a test checks that they
agree)."""
NAMED_IMAGES = 4
"""The mosaic's summary names each image up to this many, else counts them."""


def _reference(ctx: click.Context, param: click.Parameter, value: str) -> int | None:
    """--balance-reference: "mean", or a 1-based image number -> 0-based index."""
    if value == "mean":
        return None
    if not value.isdigit() or int(value) < 1:
        raise usage_error(f"--balance-reference must be 'mean' or an image number, not {value!r}")
    return int(value) - 1


def _plan(
    dem: DemInput,
    views: list[tuple[Path, Path | Camera]],
    engine: EngineInput,
    output: Path,
    *,
    occlusion: bool = True,
    eps: float | None = None,
    interp: Interp = Interp.BILINEAR,
    mosaic: MosaicOptions | None = None,
) -> Plan:
    from orthomvp.engine import plan_ortho

    return plan_ortho(
        dem.path,
        views,
        tile=engine.tile,
        grid=engine.grid,
        res=engine.res,
        bounds=engine.bounds,
        crs=engine.crs,
        output_dir=output.parent,
        occlusion=occlusion,
        eps=eps,
        interp=interp,
        **dem.plan_options(),
        progress=not quiet(),
        mosaic=mosaic,
    )


def _run(
    plan: Plan, engine: EngineInput, *, overwrite: bool, replace_input: bool, **paths: Path | None
) -> RunReport:
    from orthomvp.engine import Outputs

    outputs: Outputs = Outputs(
        **paths,
        format=engine.format,
        compress=engine.compress,
        dtype=engine.dtype,
        overwrite=overwrite,
        replace_input=replace_input,
    )
    return engine.run(plan, outputs, progress=not quiet())


@click.command(
    cls=Command, short_help="per-post visibility of one image: the epsilon round-trip test"
)
@dem_argument
@image_argument
@camera_argument
@output_option("VIS.tif", "the visibility codes (uint8 GeoTIFF on the output grid)")
@eps_option
@engine_options(dtype=False)
@overwrite_options
@dem_options
def visibility(
    dem: DemInput,
    image: Path,
    camera: Path | None,
    output: Path,
    eps: float | None,
    engine: EngineInput,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """Classify every post of the output grid (by default the part of the DEM the image
    sees, at its own ground sample distance; --grid dem, --res, --bounds, --crs) for one
    camera: 0 no data / outside the image, 1 visible, 2 occluded by terrain, 3 facing away.
    Written as a uint8 GeoTIFF."""
    check_outputs(
        [Output("-o", output)],
        view_inputs(dem, [(image, camera or image)]),
        overwrite,
        replace_input,
    )
    view = (image, camera or own_camera(image))
    with warnings_as_lines():
        plan = _plan(dem, [view], engine, output, eps=eps)
        report = _run(
            plan, engine, visibility=output, overwrite=overwrite, replace_input=replace_input
        )
    warn_partial(report, 0, str(image), engine)
    counts = ", ".join(f"{n:,} {Code(k).label}" for k, n in enumerate(report.counts[0]))
    say(f"wrote {output}: {sum(report.counts[0]):,} posts, {counts}")


@click.command(cls=Command, short_help="occlusion-aware orthophoto of one image")
@dem_argument
@image_argument
@camera_argument
@output_option("ORTHO.tif", "the orthophoto (all bands; float32 with NaN = nodata by default)")
@click.option(
    "--visibility",
    "visibility_out",
    type=OUT_FILE,
    metavar="VIS.tif",
    help="also write the visibility codes on the output grid",
)
@interp_option
@click.option(
    "--no-occlusion",
    is_flag=True,
    help="naive orthophoto: every post inside the image gets a value (ghosts included)",
)
@eps_option
@engine_options(dtype=True)
@overwrite_options
@dem_options
def ortho(
    dem: DemInput,
    image: Path,
    camera: Path | None,
    output: Path,
    visibility_out: Path | None,
    interp: Interp,
    no_occlusion: bool,
    eps: float | None,
    engine: EngineInput,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """Orthorectify IMAGE through CAMERA onto the output grid (by default the part of the DEM
    the image sees, at its own ground sample distance; --grid dem, --res, --bounds, --crs).
    Posts that are not visible (occluded, facing away, outside) are nodata unless
    --no-occlusion asks for the naive orthophoto."""
    outputs = [Output("-o", output), Output("--visibility", visibility_out)]
    check_outputs(outputs, view_inputs(dem, [(image, camera or image)]), overwrite, replace_input)
    view = (image, camera or own_camera(image))
    with warnings_as_lines():
        plan = _plan(
            dem,
            [view],
            engine,
            output,
            occlusion=not no_occlusion,
            eps=eps,
            interp=interp,
        )
        report = _run(
            plan,
            engine,
            ortho=output,
            visibility=visibility_out,
            overwrite=overwrite,
            replace_input=replace_input,
        )
    warn_partial(report, 0, str(image), engine)
    rows, cols = plan.grid.shape
    say(f"wrote {output}: {report.filled:,} of {rows * cols:,} posts filled")


@click.command(
    cls=Command,
    short_help="one orthophoto from many images, occluded posts filled from other views",
)
@optional_dem_argument
@pairs_argument(optional=True)
@odm_option
@output_option("MOSAIC.tif", "the mosaic (all bands; float32 with NaN = nodata by default)")
@click.option(
    "--source",
    type=OUT_FILE,
    metavar="SOURCE.tif",
    help="also write which image each post came from (band 1), how or why not (band 2: 1 "
    "visible, 2 from behind, 3 naive, 4 doubtful, 5 inpainted; empty: 0 outside every image, "
    "8 facing away, 9 occluded, 10 occluded or facing away in every image, 11 seen only "
    "doubtfully, 12 no pixel value) and each image's blend weight (bands 3.., /255)",
)
@click.option(
    "--priority",
    type=click.Choice(PRIORITIES),
    default="emission",
    show_default=True,
    help="which image a post prefers: smallest emission angle, finest GSD, most nadir, or "
    "the first given",
)
@click.option(
    "--seamlines/--no-seamlines",
    default=True,
    show_default=True,
    help="seams away from occlusion boundaries and where images disagree (off: each post "
    "from its preferred image)",
)
@click.option(
    "--blend",
    type=click.IntRange(min=0),
    default=8,
    show_default=True,
    metavar="WIDTH",
    help="feather seams over WIDTH posts (0: hard seams; clamped to the widest overlap)",
)
@click.option(
    "--balance",
    type=click.Choice(BALANCES),
    default="none",
    show_default=True,
    help="radiometric balance: per-image gain, or gain and offset, by least squares on overlaps",
)
@click.option(
    "--balance-reference",
    default="mean",
    show_default=True,
    metavar="N|mean",
    callback=_reference,
    help="image held fixed by --balance (1-based), or the mean gain 1 and offset 0",
)
@click.option(
    "--holes",
    type=click.Choice(HOLES),
    default=None,
    help="posts no image sees with trust: leave empty [default]; or, after those seen only "
    "doubtfully (from the clear pixels of a doubtful image, else the image of largest "
    "margin): from an image that sees them from behind "
    "(never occluded), inpainted from the posts around (holes up to 16 posts), or the most "
    "nadir naive value (ghosts); flagged in --source",
)
@click.option(
    "--clear-pixels/--no-clear-pixels",
    default=True,
    show_default=True,
    help="where an image's sample near an occlusion boundary reaches an occluder, take only "
    "its clear pixels (fewer partial ghosts at wall feet; off: bilinear samples throughout)",
)
@click.option(
    "--fill",
    type=click.Choice(FILLS),
    help="deprecated: --holes (none = empty, any-view = behind, naive = naive)",
)
@click.option(
    "--visibility",
    "visibility_out",
    type=OUT_FILE,
    metavar="VIS.tif",
    help="also write the visibility codes of every image, one band per image",
)
@interp_option
@eps_option
@engine_options(dtype=True)
@overwrite_options
@dem_options
def mosaic(
    dem: DemInput,
    pairs: list[tuple[Path, Path | Camera]],
    odm: Path | None,
    output: Path,
    source: Path | None,
    priority: str,
    seamlines: bool,
    blend: int,
    balance: str,
    balance_reference: int | None,
    holes: str | None,
    clear_pixels: bool,
    fill: str | None,
    visibility_out: Path | None,
    interp: Interp,
    eps: float | None,
    engine: EngineInput,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """Orthorectify every IMAGE CAMERA pair (mvpgui order) onto the output grid (by default
    the union of the images' footprints on the DEM, at their ground sample distance; --grid
    dem, --res, --bounds, --crs) into one seamless mosaic: each post prefers the visible image
    of --priority, seamlines run away from occlusion boundaries and disagreement, seams are
    feathered over --blend posts, optionally balanced; an image never gives a post it does
    not see (except --holes naive, flagged); the summary counts the empty posts by reason.
    --source records which image (1-based, in command-line order; 0 = none) each post came
    from, how (or why it is empty), and the blend weights. One image makes a mosaic too;
    images that see no post of the grid are left out, with one warning. --odm DIR
    takes the DEM, images and cameras of an OpenDroneMap dataset (the cameras in the DEM's
    CRS)."""
    outputs = [
        Output("-o", output),
        Output("--source", source),
        Output("--visibility", visibility_out),
    ]
    dem, pairs, inputs = command_views(dem, pairs, odm)
    check_outputs(outputs, inputs, overwrite, replace_input)
    from orthomvp.errors import InputError
    from orthomvp.ortho.composite import MosaicOptions
    from orthomvp.ortho.holes import FILL_ALIASES

    if fill is not None:
        if holes is not None and holes != FILL_ALIASES[fill]:
            raise usage_error(f"--fill {fill} contradicts --holes {holes}")
        print(
            f"orthomvp: warning: --fill is deprecated; use --holes {FILL_ALIASES[fill]}",
            file=sys.stderr,
        )
        holes = FILL_ALIASES[fill]

    if balance_reference is not None and balance_reference >= len(pairs):
        raise InputError(
            f"--balance-reference {balance_reference + 1}: there are {len(pairs)} images"
        )
    options = MosaicOptions(
        priority=priority,
        seamlines=seamlines,
        blend=blend,
        balance=None if balance == "none" else balance,
        reference=balance_reference,
        holes=holes or "empty",
        clear=clear_pixels,
    )
    with warnings_as_lines():
        plan = _plan(dem, pairs, engine, output, eps=eps, interp=interp, mosaic=options)
        report = _run(
            plan,
            engine,
            ortho=output,
            source=source,
            visibility=visibility_out,
            overwrite=overwrite,
            replace_input=replace_input,
        )
    rows, cols = plan.grid.shape
    none = rows * cols - sum(report.taken)
    say(
        f"wrote {output}: {taken_text(report.taken, [image for image, _ in pairs])}; {none:,} "
        "posts from no image"
    )
    say(holes_text(report.flags))


def holes_text(flags: list[int]) -> str:
    """The summary's line on holes: the posts of each reason for an empty post and of each
    way a hole was filled (:class:`orthomvp.ortho.holes.Flag`, counted in ``flags``), those
    with posts."""
    from orthomvp.ortho.holes import EMPTY_REASONS, Flag

    filled = [f for f in (Flag.DOUBTFUL, Flag.BEHIND, Flag.INPAINTED, Flag.NAIVE) if flags[f]]
    empty = [f for f in (Flag.OUTSIDE, *EMPTY_REASONS) if flags[f]]
    text = "empty posts: " + (
        ", ".join(f"{flags[f]:,} {f.label}" for f in empty) if empty else "none"
    )
    if filled:
        text += "; filled holes: " + ", ".join(f"{flags[f]:,} {f.label}" for f in filled)
    return text


def taken_text(taken: list[int], images: list[Path]) -> str:
    """How many posts came from each image: each one named when there are at most
    :data:`NAMED_IMAGES`, else the count of images and the range of their shares."""
    if len(images) <= NAMED_IMAGES:
        return ", ".join(
            f"{n:,} posts from {image}" for n, image in zip(taken, images, strict=True)
        )
    used = sum(1 for n in taken if n)
    return (
        f"{sum(taken):,} posts from {used} of {len(images)} images (from {min(taken):,} to "
        f"{max(taken):,} posts each)"
    )


def warn_partial(report: RunReport, view: int, what: str, engine: EngineInput) -> None:
    """A warning on stderr when the image covers only part of the grid's posts with heights,
    on a grid whose extent was not chosen from the image (--grid dem, or --bounds)."""
    from_image = engine.grid == "camera" and engine.bounds is None
    if not from_image and report.valid and report.inside[view] < report.valid:
        share = 100 * report.inside[view] / report.valid
        print(
            f"orthomvp: warning: {what} covers {share:.1f}% of the output grid's posts with "
            "heights; the rest is nodata",
            file=sys.stderr,
        )
