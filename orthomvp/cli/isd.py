"""``orthomvp isd``: the USGS CSM ISD of a spiceinit'd ISIS3 cube, as ALE's ``isd_generate``
writes it (with the cube's crop folded in), so that usgscsm and ASP can use the camera that
orthomvp reads from the cube."""

from __future__ import annotations

import json
from pathlib import Path

import click

from orthomvp.cli.command import Command
from orthomvp.cli.options import (
    PATH,
    Output,
    check_outputs,
    output_option,
    overwrite_option,
    say,
)


@click.command(cls=Command, short_help="write the USGS CSM ISD of a spiceinit'd ISIS3 cube")
@click.argument(
    "cube",
    type=PATH,
    metavar="CUBE",
    help="a level-1 ISIS3 cube after spiceinit (attach=yes): LRO NAC or WAC, MRO CTX, Kaguya "
    "TC, Mars Express HRSC, Apollo Metric, MESSENGER MDIS or Dawn FC",
)
@output_option("ISD.json", "the ISD (JSON, ALE's keys; the name_model line picks usgscsm's model)")
@overwrite_option
def isd(cube: Path, output: Path, overwrite: bool) -> None:
    """Write the camera of CUBE, read from its attached SPICE tables and NaifKeywords (no ISIS,
    ALE or kernels), as a USGS CSM ISD: the image support data that usgscsm, ASP's CSM cameras
    and every orthomvp command read. The cube's AlphaCube crop and reduction are folded in, which
    ALE's isd_generate leaves out; a lens model that usgscsm lacks (Apollo Metric's) cannot be
    carried and is named in a warning."""
    from orthomvp.camera.isis import instrument_of
    from orthomvp.camera.isis.core import SpiceCube
    from orthomvp.io.outputs import atomic_path

    check_outputs([Output("-o", output, (".json",), "a JSON file")], [("CUBE", cube)], overwrite)
    spice = SpiceCube(cube)
    instrument = instrument_of(spice)
    document = instrument.isd(spice)
    if instrument.distortion is not None:
        click.echo(
            f"orthomvp: warning: {cube}: {instrument.name}'s lens model is ISIS's, which the ISD "
            "format cannot hold: usgscsm computes without it (orthomvp reads the cube with it)",
            err=True,
        )
    text = json.dumps(document, indent=1)
    with atomic_path(output) as tmp:
        Path(tmp).write_text(text)
    say(f"wrote {output}: {document.get('name_model', 'an ISD')} of {instrument.name}")
