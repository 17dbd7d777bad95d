"""A camera checked end to end through ``orthomvp ortho`` against usgscsm's truth table: an
image whose two bands hold each pixel's own column and row, orthorectified onto a flat DEM of
the body's sphere (height 0) that covers the image's footprint, must hold at usgscsm's ground
points usgscsm's own ground-to-image pixel (bilinear between the orthophoto's posts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

from orthomvp.camera import Camera
from orthomvp.cli import main


def ramp_ortho_checks(
    tmp_path: Path,
    camera: Camera,
    camera_file: Path,
    truth: dict,
    *,
    rows: int,
    cols: int,
    radius: float,
) -> int:
    """Run the check for ``camera`` (read from ``camera_file``, imaging ``cols`` x ``rows``
    pixels) on a sphere of ``radius`` metres; asserts each truth point within 0.02 px and
    returns how many were checked (those with neighbours to interpolate from)."""
    u, v = np.meshgrid(np.arange(cols, dtype=np.float32), np.arange(rows, dtype=np.float32))
    image = tmp_path / "ramp.tif"
    with rasterio.open(
        image, "w", driver="GTiff", width=cols, height=rows, count=2, dtype="float32"
    ) as dst:
        dst.write(np.stack([u, v]))
    corners = camera.image_to_ground(
        np.array([[0, 0], [cols - 1, 0], [0, rows - 1], [cols - 1, rows - 1]], float), 0.0
    )
    lon = np.degrees(np.arctan2(corners[:, 1], corners[:, 0]))
    lat = np.degrees(np.arcsin(corners[:, 2] / radius))
    step = (lon.max() - lon.min() + lat.max() - lat.min()) / 2 / 150  # about 150 posts a side
    west, north = lon.min() - 10 * step, lat.max() + 10 * step
    n_c = int((lon.max() + 10 * step - west) / step) + 1
    n_r = int((north - (lat.min() - 10 * step)) / step) + 1
    transform = Affine.translation(west, north) @ Affine.scale(step, -step)
    dem = tmp_path / "dem.tif"
    profile = dict(driver="GTiff", width=n_c, height=n_r, count=1, dtype="float32")
    with rasterio.open(
        dem, "w", crs=f"+proj=longlat +R={radius} +no_defs", transform=transform, **profile
    ) as dst:
        dst.write(np.zeros((1, n_r, n_c), np.float32))
    out = tmp_path / "o.tif"
    args = ["-q", "ortho", str(dem), str(image), str(camera_file), "-o", str(out), "--grid", "dem"]
    assert main(args) == 0
    with rasterio.open(out) as src:
        ortho = src.read().astype(np.float64)
    checked = 0
    for point in truth["points"]:
        line, sample = point["line"], point["sample"]
        if not (1 <= line <= rows - 1 and 1 <= sample <= cols - 1):
            continue  # the image's outer half pixel: no neighbours to interpolate from
        ground = np.array(point["heights"][0]["ground"])
        g2i = point["heights"][0]["g2i"]
        c, r = ~transform @ (
            np.degrees(np.arctan2(ground[1], ground[0])),
            np.degrees(np.arcsin(ground[2] / np.linalg.norm(ground))),
        )
        c, r = c - 0.5, r - 0.5  # pixel-centre coordinates
        c0, r0 = int(np.floor(c)), int(np.floor(r))
        fc, fr = c - c0, r - r0
        cell = ortho[:, r0 : r0 + 2, c0 : c0 + 2]
        value = (
            cell[:, 0, 0] * (1 - fc) * (1 - fr)
            + cell[:, 0, 1] * fc * (1 - fr)
            + cell[:, 1, 0] * (1 - fc) * fr
            + cell[:, 1, 1] * fc * fr
        )
        np.testing.assert_allclose(value, [g2i["sample"] - 0.5, g2i["line"] - 0.5], atol=0.02)
        checked += 1
    return checked
