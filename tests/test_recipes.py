"""Every recipe of the README's "Your own data" runs as written, from a folder beside which
``../shared/data`` is the real data, and writes outputs that hold what the recipe says."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rasterio

from tests.conftest import shared

README = Path(__file__).resolve().parents[1] / "README.md"


def recipes() -> list[str]:
    """The bash blocks of the README's "Your own data" section, in order."""
    text = README.read_text()
    section = re.search(r"^## Your own data\n(.*?)(?=^## )", text, re.S | re.M).group(1)
    return re.findall(r"```bash\n(.*?)```", section, re.S)


def _filled(path: Path) -> float:
    """The share of posts of a raster's first band with a value."""
    with rasterio.open(path) as src:
        band = src.read(1, masked=True)
        values = band.filled(np.nan).astype(np.float64)
    return float(np.isfinite(values).mean())


EXPECTED = {
    "hadley.tif": 0.5,
    "nac.tif": 0.5,
    "ls-ortho.tif": 0.3,
    "ngi-0182.tif": 0.5,
    "quickbird.tif": 0.5,
    "ngi-mosaic.tif": 0.5,
    "apollo-fitted.tif": 0.5,
}
"""Each recipe's main output and the least share of its posts that must hold a value."""


def _output(block: str) -> str | None:
    """The recipe's main output (its ``-o``), if it writes one."""
    found = re.search(r"-o (\S+)", block)
    return found.group(1) if found else None


def test_the_readme_has_the_recipes_the_test_knows() -> None:
    outputs = [_output(block) for block in recipes()]
    assert outputs == [None, *EXPECTED]


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(EXPECTED) + 1), ids=["info", *EXPECTED])
def test_recipe_runs_as_written(index: int, tmp_path: Path) -> None:
    data = shared()  # skips, saying why, without the data
    (tmp_path / "shared").mkdir()
    (tmp_path / "shared" / "data").symlink_to(data)
    work = tmp_path / "work"
    work.mkdir()
    block = recipes()[index]
    out = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", block],
        cwd=work,
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "ORTHOMVP_DATA": str(data)},
    )
    assert out.returncode == 0, out.stderr
    name = _output(block)
    if name is None:  # info: what it says
        assert "footprint" in out.stdout and "GSD" in out.stdout, out.stdout
        return
    assert _filled(work / name) >= EXPECTED[name], (name, _filled(work / name))
