"""``orthomvp explore``: the MVP objective at one DEM post, interactive or scripted."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    PATH,
    DemInput,
    dem_argument,
    dem_options,
    eps_option,
    levels_option,
    pairs_argument,
    quiet,
    view_inputs,
)


@click.command(
    cls=Command,
    exclusive=[("commands", "script")],
    short_help="explore the MVP objective at one DEM post (interactive or scripted)",
)
@dem_argument
@pairs_argument()
@click.option(
    "-c", "--commands", metavar="CMDS", help="commands to run, separated by ';' or newlines"
)
@click.option("--script", type=PATH, metavar="FILE", help="run the commands in FILE")
@levels_option("coarse-to-fine pyramid levels for fit")
@eps_option
@click.option(
    "--overwrite",
    is_flag=True,
    help="let save replace files that exist (without it an existing file is refused; an input "
    "never is)",
)
@dem_options
def explore(
    dem: DemInput,
    pairs: list[tuple[Path, Path]],
    commands: str | None,
    script: Path | None,
    levels: int,
    eps: float | None,
    overwrite: bool,
) -> None:
    """The objective explorer, successor of mvpgui: an mvp> prompt with commands to plot the
    MVP objective against height (rplot) and orientation (llplot), list the views, show the
    patches, run and trace the optimiser, and sweep the window size; 'help' lists them. -c
    and --script (or commands piped in) run the same commands without a prompt and stop with
    exit status 2 at the first bad one."""
    from orthomvp.camera import load_view
    from orthomvp.explore import Explorer, ExplorerShell, run_commands, split_commands

    lines = None
    if script is not None:
        lines = split_commands(script.read_text())
    elif commands is not None:
        lines = split_commands(commands)
    elif not sys.stdin.isatty():
        lines = split_commands(sys.stdin.read())
    if not quiet():
        print("orthomvp: loading the images...", flush=True)
    views = [load_view(image, camera) for image, camera in pairs]
    terrain = dem.read([v[1] for v in views])
    explorer = Explorer(
        terrain,
        [v[0] for v in views],
        [v[1] for v in views],
        names=[image.name for image, _ in pairs],
        eps=eps,
        levels=levels,
    )
    shell = ExplorerShell(explorer, inputs=view_inputs(dem, pairs), overwrite=overwrite)
    if not quiet():
        rows, cols = terrain.shape
        print(
            f"orthomvp: {len(views)} views, DEM {cols} x {rows} posts of "
            f"{explorer.spacing:.1f} m; type help for the commands."
        )
        shell.do_poi("")
    if lines is None:
        shell.cmdloop()
    else:
        run_commands(shell, lines)
