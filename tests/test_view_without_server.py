"""The static page (``orthomvp view --export`` and the demo's ``index.html``) needs no server:
with Starlette and uvicorn absent, as after a plain ``pip install orthomvp``, the export path
imports and writes a page, and only the live server asks for the ``view`` extra."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

BLOCK = "import sys\nfor m in ('starlette', 'uvicorn', 'httpx'):\n    sys.modules[m] = None\n"


def test_export_needs_no_starlette(tmp_path: Path) -> None:
    dem = tmp_path / "dem.tif"
    profile = {"driver": "GTiff", "width": 32, "height": 24, "count": 1, "dtype": "float32"}
    transform = Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 4000000.0)
    with rasterio.open(dem, "w", crs="EPSG:32633", transform=transform, **profile) as dst:
        dst.write(np.linspace(0, 50, 32 * 24, dtype=np.float32).reshape(1, 24, 32))
    script = BLOCK + (
        "from pathlib import Path\n"
        "from orthomvp.view import LayerSet, write_export\n"
        f"layers = LayerSet(Path({str(dem)!r}))\n"
        f"print(write_export(layers, Path({str(tmp_path / 'page')!r})))\n"
        "import orthomvp.view.server\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    # the export is written; only importing the live server then fails, for want of Starlette
    assert (tmp_path / "page" / "index.html").is_file(), run.stderr
    assert int(run.stdout.split()[0]) >= 1
    assert "starlette" in run.stderr.splitlines()[-1]
