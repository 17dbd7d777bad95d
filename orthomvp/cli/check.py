"""``orthomvp check``: a truth-free check of the visibility flags by cross-view correlation,
tile by tile through the streaming engine (:func:`orthomvp.engine.plan_check`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from orthomvp.cli.command import Command, Variadic
from orthomvp.cli.engine_options import EngineInput, engine_options, warnings_as_lines
from orthomvp.cli.odm import command_views, odm_option
from orthomvp.cli.options import (
    POSITIVE,
    DemInput,
    Output,
    check_outputs,
    dem_options,
    optional_dem_argument,
    overwrite_options,
    pairs_argument,
    prefix_files,
    prefix_option,
    quiet,
    say,
)

if TYPE_CHECKING:
    from orthomvp.camera import Camera

DEFAULT_EPS = (1.0, 2.0, 4.0, 8.0)
"""the epsilons of :data:`orthomvp.quality.check.DEFAULT_EPS` (not imported: --help stays fast)"""


@click.command(
    cls=Command,
    short_help="truth-free check of the visibility flags: cross-view NCC by miss distance",
)
@optional_dem_argument
@pairs_argument(minimum=2, optional=True)
@odm_option
@prefix_option("check")
@click.option(
    "--eps",
    cls=Variadic,
    type=POSITIVE,
    default=DEFAULT_EPS,
    metavar="POSTS ...",
    help="visibility tolerances to check, DEM posts",
)
@click.option(
    "--window",
    type=click.IntRange(min=3, max=51),
    default=7,
    metavar="POSTS",
    help="side of the NCC window, DEM posts (odd)",
)
@engine_options(dtype=False, grid=False, rasters=False)
@overwrite_options
@dem_options
def check(
    dem: DemInput,
    pairs: list[tuple[Path, Path | Camera]],
    odm: Path | None,
    output: Path,
    eps: tuple[float, ...],
    window: int,
    engine: EngineInput,
    overwrite: bool,
    replace_input: bool,
) -> None:
    """For every pair of overlapping views, the local NCC between their orthophotos at posts
    visible in both, and at posts one view calls occluded (its naive value against the other
    view), binned by the first-hit miss distance, per epsilon: CSV and a plot. High NCC at
    visible posts at every miss distance and low NCC at occluded posts say that the flags and
    epsilon fit the data; no ground truth is needed. Runs tile by tile on the DEM's grid in
    bounded memory; medians come from a histogram, within 0.00025 of the exact ones. --odm DIR
    takes the DEM, images and cameras of an OpenDroneMap dataset (the cameras in the DEM's
    CRS)."""
    from orthomvp.engine import plan_check, run_check
    from orthomvp.quality import check as lib

    if window % 2 == 0:
        raise click.UsageError(f"--window must be odd, got {window}", click.get_current_context())
    csv, png = prefix_files(output)
    outputs = [Output("-o", csv, (".csv",), "CSV"), Output("-o", png, (".png",), "a PNG")]
    dem, pairs, inputs = command_views(dem, pairs, odm)
    check_outputs(outputs, inputs, overwrite, replace_input)
    names = [str(image) for image, _ in pairs]
    with warnings_as_lines():
        plan = plan_check(
            dem.path,
            pairs,
            eps_values=eps,
            window=window,
            names=names,
            tile=engine.tile,
            **dem.plan_options(),
            progress=not quiet(),
        )
        with engine.workers() as executor:
            result = run_check(plan, progress=not quiet(), **executor)
    left = set(plan.base.left_out)  # (said once, as left out, by the plan's warning)
    for a, b in result.apart:
        if a - 1 not in left and b - 1 not in left:
            say(f"{names[a - 1]} and {names[b - 1]} do not overlap: that pair is not checked")
    for e in eps:
        vis, occ = result.pooled(e, "visible"), result.pooled(e, "occluded")
        say(
            f"eps {e:g} posts: median NCC {_text(vis)} at posts visible in both, {_text(occ)} at "
            "posts called occluded (naive value)"
        )
    lib.save(result, csv, png, overwrite=True)  # (checked with the command's options)
    say(f"wrote {csv} and {png}")


def _text(row: dict) -> str:
    return f"{row['ncc_median']:.3f} ({row['scored']:,} posts)" if row["scored"] else "- (0 posts)"
