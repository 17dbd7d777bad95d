"""``orthomvp demo``: the whole pipeline on a built-in synthetic scene."""

from __future__ import annotations

from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import PATH, check_outdir, overwrite_option, quiet

DEMO_MARKS = ("index.html", "summary.json")
"""The files by which a folder is known as an earlier demo's (which the demo refreshes)."""


@click.command(cls=Command, short_help="run the pipeline end to end on a built-in synthetic scene")
@click.argument(
    "outdir",
    type=PATH,
    default=Path("orthomvp-demo"),
    required=False,
    metavar="[OUTDIR]",
    help="the directory for every output (created if absent; nothing is written on "
    "failure; default ./orthomvp-demo). A folder an earlier demo wrote is refreshed; any "
    "other folder that holds files needs --overwrite",
)
@overwrite_option
def demo(outdir: Path, overwrite: bool) -> None:
    """Make the synthetic crater scene, mesh it, and write every output into OUTDIR, then
    print a summary."""
    from orthomvp.demo import run_demo

    check_outdir(outdir, "OUTDIR", overwrite=overwrite, refresh=DEMO_MARKS)
    run_demo(outdir, quiet=quiet())
