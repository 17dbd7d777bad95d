"""docs/cli.md is the commands' own help, as :mod:`orthomvp.cli.reference` makes it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from orthomvp.cli.reference import markdown

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"


def test_the_reference_is_in_step_with_the_commands() -> None:
    assert DOC.read_text() == markdown(), (
        "docs/cli.md is out of date: python -m orthomvp.cli.reference > docs/cli.md"
    )


def test_the_reference_holds_every_command_and_option() -> None:
    text = DOC.read_text()
    for command in ("ortho", "mosaic", "visibility", "fit", "mesh", "render", "synth", "demo"):
        assert f"## orthomvp {command}\n" in text
        out = subprocess.run(
            [sys.executable, "-m", "orthomvp", command, "--help"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        options = {w.rstrip(",") for w in out.split() if w.startswith("--")}
        section = text.split(f"## orthomvp {command}\n")[1].split("\n## ")[0]
        assert options and all(o in section for o in options), command
