"""The Python examples of the README and docs/ run as written, on a synthetic scene."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import rasterio

ROOT = Path(__file__).resolve().parents[1]
GUIDES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _run_block(marker: str, folder: Path) -> dict:
    """Run the one Python block of the README or docs/ that contains ``marker`` in ``folder``;
    its names. It runs as a script does (``__name__ == "__main__"``), guarded code included."""
    blocks = [b for g in GUIDES for b in re.findall(r"```python\n(.*?)```", g.read_text(), re.S)]
    (block,) = [b for b in blocks if marker in b]
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        namespace: dict = {"__name__": "__main__"}
        exec(compile(block, "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    return namespace


def test_readme_engine_example(tmp_path: Path) -> None:
    from orthomvp.io.raster import read_image
    from orthomvp.synthetic import make_scene

    make_scene("crater", size=48, spacing=100.0).write(tmp_path / "scene", supersample=1)
    namespace = _run_block("dask_client(", tmp_path)
    assert namespace["report"].filled > 0
    threaded, dask = read_image(tmp_path / "ortho.tif"), read_image(tmp_path / "ortho-dask.tif")
    np.testing.assert_array_equal(threaded, dask)
    # on the camera's grid: the part of the 48 x 48-post DEM the image sees, at its GSD
    grid = namespace["plan"].grid
    assert read_image(tmp_path / "vis.tif").shape == (1, *grid.shape)
    assert grid.transform.a < 100.0 and not grid.on_dem
    check = namespace["check"]
    assert check.pairs == [(1, 2)] and check.pooled(4, "visible")["scored"] > 500
    assert (tmp_path / "check.csv").is_file() and (tmp_path / "check.png").is_file()


def test_readme_python_example(tmp_path: Path) -> None:
    from orthomvp.synthetic import make_scene

    make_scene("crater", size=48, spacing=100.0).write(tmp_path / "scene", supersample=1)
    namespace = _run_block("om.fit_dem(", tmp_path)
    np.testing.assert_allclose(namespace["c2"], namespace["c"], atol=1e-7)
    assert (namespace["mos"].source > 0).all()
    fit, dem = namespace["fit"], namespace["dem"]
    # away from the crater, whose 2-post-wide peak no 17-post window resolves, the fit comes
    # back towards the truth from 20 m off (accuracy is tested in tests/test_mvp_fit.py)
    rows, cols = np.mgrid[0:48, 0:48]
    outside = fit.resolved & (np.hypot(rows - 23.5, cols - 23.5) > 24)
    assert outside.sum() > 50
    assert np.median(np.abs(fit.heights - dem.values)[outside]) < 15.0
    assert (tmp_path / "crater.ply").is_file()
    # the engine's fit from files is the in-memory fit's (of the start as written), bit for bit
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.mvp import FitOptions, fit_dem

    n = namespace
    start = Terrain.read(tmp_path / "start.tif")
    again = fit_dem(start, [n["image"], n["nadir"]], [n["cam"], n["nadir_cam"]], FitOptions(hwin=8))
    with rasterio.open(tmp_path / "fitted.tif") as src:
        np.testing.assert_array_equal(src.read(1), again.heights.astype(np.float32))
    assert n["report"].fitted == int(again.resolved.sum())
    # the page shows what the block wrote: the fitted DEM and the true radiance over the DEM
    layers = n["layers"]
    assert not layers.problems
    assert [layer.kind.name for layer in layers.layers.values()] == ["relief", "height", "image"]
    assert (tmp_path / "page" / "index.html").is_file()


def test_readme_front_example(tmp_path: Path) -> None:
    from orthomvp.io.raster import read_image
    from orthomvp.synthetic import make_scene

    make_scene("crater", size=48, spacing=100.0).write(tmp_path / "scene", supersample=1)
    n = _run_block("import orthomvp as om\nfrom orthomvp.io.raster import read_image\n\n", tmp_path)
    # in memory: a value exactly where the post is visible
    visible = n["vis"].codes == 1
    assert visible.sum() > 500
    np.testing.assert_array_equal(np.isfinite(n["ortho"].data[0]), visible)
    # from files: the plan's grid (the image's footprint), which the image fills nearly whole
    on_file = read_image(tmp_path / "ortho.tif")
    assert on_file.shape[1:] == n["plan"].grid.shape
    assert n["report"].filled == int(np.isfinite(on_file[0]).sum())
    assert np.isfinite(on_file[0]).mean() > 0.8
    image = n["image"]
    assert np.nanmin(on_file) >= image.min() - 1e-3 and np.nanmax(on_file) <= image.max() + 1e-3
