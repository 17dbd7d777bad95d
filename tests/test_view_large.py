"""``orthomvp view``'s clicks on a DEM far larger than a block: the crater scene's start DEM
inside a 4096^2 float32 tiled GeoTIFF. A click reads its block's window from the file alone and
finds the same objective as on the crater's own DEM."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from conftest import VIEW_NAMES as NAMES

from orthomvp.engine.grid import scan_dem

pytest.importorskip("uvicorn")

SIZE = 4096
OFFSET = 1100
"""Where the crater's posts start in the large DEM (rows and columns): inside block (2, 2)."""


def _large_dem(start: Path, out: Path) -> Path:
    """The crater's start DEM at (OFFSET, OFFSET) of a SIZE^2 float32 tiled GeoTIFF, its edges
    carried outwards (a plain at the edges' heights), on the same grid."""
    with rasterio.open(start) as src:
        values, profile = src.read(1), src.profile
    rows, cols = values.shape
    big = np.pad(values, ((OFFSET, SIZE - OFFSET - rows), (OFFSET, SIZE - OFFSET - cols)), "edge")
    profile.update(
        width=SIZE,
        height=SIZE,
        transform=profile["transform"] @ Affine.translation(-OFFSET, -OFFSET),
        tiled=True,
        blockxsize=512,
        blockysize=512,
        compress="deflate",
    )
    path = out / "large.tif"
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(big.astype(np.float32), 1)
    return path


def _posts(dem: Path, view_scene: dict):  # noqa: ANN202
    from orthomvp.camera import load_view
    from orthomvp.view import LayerSet, Posts

    d = view_scene["dir"]
    views = [load_view(d / f"{n}.tif", d / f"{n}.tsai") for n in NAMES]
    images, cameras = [v[0] for v in views], [v[1] for v in views]
    return Posts(LayerSet(dem), scan_dem(dem), images, cameras, list(NAMES))


@pytest.mark.slow
def test_a_click_on_a_large_dem_reads_its_block_alone(view_scene: dict, tmp_path: Path) -> None:
    """The post of flat ground that test_view clicks, on the 4096^2 DEM: the explorer holds
    the 768^2 window of the post's block (512 posts and 128 around), not the DEM (which is
    not held either), and rplot's minimum and the fit are those of the crater's own DEM."""
    from test_view import _flat_post

    from orthomvp.view.post import BLOCK, MARGIN, Controls

    large = _posts(_large_dem(view_scene["start"], tmp_path), view_scene)
    small = _posts(view_scene["start"], view_scene)
    assert large.dem.shape == (SIZE, SIZE) and large.dem.held is None
    c, r = _flat_post(view_scene)
    controls = Controls(hwin=5, h_range=60.0)
    x, y = small.grid.pixel_to_crs(np.array([c]), np.array([r]))
    assert large.post_of(float(x[0]), float(y[0])) == (c + OFFSET, r + OFFSET)
    got = large.click(float(x[0]), float(y[0]), controls)
    want = small.click(float(x[0]), float(y[0]), controls)
    assert "error" not in got, got
    assert got["post"] == [c + OFFSET, r + OFFSET]
    ex, cl, rl = large.explorer(c + OFFSET, r + OFFSET)
    side = BLOCK + 2 * MARGIN
    assert ex.terrain.shape == (side, side)  # a window, not 4096^2
    b0 = (OFFSET // BLOCK) * BLOCK - MARGIN  # the block's window starts here
    assert (cl, rl) == (c + OFFSET - b0, r + OFFSET - b0)
    np.testing.assert_array_equal(ex.terrain.values[rl - 3 : rl + 4, cl - 3 : cl + 4],
                                  small.terrain((r - 3, r + 4, c - 3, c + 4)).values)  # fmt: skip
    assert got["rplot"]["h_min"] == pytest.approx(want["rplot"]["h_min"], abs=1e-6)
    assert got["fit"]["h"] == pytest.approx(want["fit"]["h"], abs=1e-6)
    truth = float(view_scene["truth"].values[r, c])
    assert abs(got["rplot"]["h_min"] - truth) <= 3.0
    scene = large.scene(float(x[0]), float(y[0]), large.layers.layers["L0"])
    assert scene["shape"] == [81, 81] and scene["post"] == [c + OFFSET, r + OFFSET]
