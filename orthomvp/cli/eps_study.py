"""``orthomvp eps-study``: sweep the visibility tolerance against a synthetic scene's truth."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command, Variadic
from orthomvp.cli.options import (
    NON_NEGATIVE,
    PATH,
    POSITIVE,
    Output,
    check_outputs,
    overwrite_option,
    prefix_files,
    prefix_option,
    say,
)


@click.command(
    "eps-study",
    cls=Command,
    short_help="sweep the visibility tolerance on a synthetic scene with truth",
)
@click.argument(
    "scene",
    type=PATH,
    metavar="SCENE",
    help="a scene directory written by 'orthomvp synth'",
)
@prefix_option("eps-study")
@click.option(
    "--eps",
    cls=Variadic,
    type=POSITIVE,
    metavar="POSTS ...",
    show_default="19 values from 0.02 to 20, evenly spaced in log",
    help="epsilons to try, DEM posts",
)
@click.option(
    "--dem-noise",
    cls=Variadic,
    type=NON_NEGATIVE,
    default=(0.0,),
    metavar="METRES ...",
    help="standard deviations of Gaussian noise added to the DEM",
)
@overwrite_option
def eps_study(
    scene: Path,
    output: Path,
    eps: tuple[float, ...],
    dem_noise: tuple[float, ...],
    overwrite: bool,
) -> None:
    """Score the visibility test against the marched truth of a scene written by 'orthomvp
    synth', for a range of epsilons (DEM posts) and optional DEM noise: precision, recall
    and F1 per view (CSV) and a plot (PNG)."""
    from orthomvp.quality import eps_study as epsstudy

    csv, png = prefix_files(output)
    check_outputs([Output("-o", csv, ()), Output("-o", png, ())], overwrite=overwrite)
    values = eps or epsstudy.DEFAULT_EPS_VALUES
    rows = epsstudy.eps_study(scene, eps_values=values, noise=dem_noise)
    epsstudy.save(rows, csv, png, overwrite=True)  # (checked with the command's options)
    for r in rows:
        if r["eps"] == "default":
            say(
                f"{r['view']}, DEM noise {r['noise_m']:g} m: default rule F1 visible "
                f"{r['f1_visible']:.4f}, hidden {r['f1_hidden']:.4f}"
            )
    say(f"wrote {csv} and {png}")
