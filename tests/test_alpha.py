"""An image whose last band is alpha (an RGBA PNG, a TIFF's extra sample): the alpha band is the
mask of the others (orthomvp.io.raster.image_bands), not a band of values, in the whole-image
read, the engine's orthophoto and a mosaic with an RGB image."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from orthomvp.io.raster import read_image
from tests.test_cli import run as cli_run


def write(path: Path, bands: np.ndarray, **options: object) -> Path:
    """``bands`` (uint8 (count, rows, cols)) written to ``path`` (its driver from the suffix)."""
    driver = "PNG" if path.suffix == ".png" else "GTiff"
    count, rows, cols = bands.shape
    profile = dict(driver=driver, width=cols, height=rows, count=count, dtype="uint8", **options)
    with warnings.catch_warnings():  # (images have no georeference)
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as dst:
            dst.write(bands)
    return path


@pytest.fixture(scope="module")
def images(crater_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The crater's oblique image as 8-bit RGB, and as RGBA (PNG and TIFF) whose alpha hides
    a block of it."""
    out = tmp_path_factory.mktemp("alpha")
    with rasterio.open(crater_dir / "oblique.tif") as src:
        grey = src.read(1)
    level = np.clip(np.rint(255 * grey), 0, 255).astype(np.uint8)
    rgb = np.stack([level, level // 2, level // 4])
    alpha = np.full(level.shape, 255, np.uint8)
    rows, cols = level.shape
    alpha[rows // 4 : rows // 2, cols // 4 : cols // 2] = 0
    return {
        "rgb": write(out / "rgb.tif", rgb, photometric="RGB"),
        "png": write(out / "rgba.png", np.concatenate([rgb, alpha[None]])),
        "tif": write(
            out / "rgba.tif",
            np.concatenate([rgb, alpha[None]]),
            photometric="RGB",
            alpha="YES",
        ),  # fmt: skip
        "hidden": alpha == 0,
    }


@pytest.mark.parametrize("kind", ["png", "tif"])
def test_the_alpha_band_masks_and_is_not_read(
    kind: str, images: dict, crater_dir: Path, tmp_path: Path
) -> None:
    """Three bands read, NaN where alpha is 0 and the RGB image's values elsewhere; the
    orthophoto has three bands (RGB), equal to the RGB image's where that one's pixels are
    all valid, and empty where only hidden pixels are sampled."""
    rgba, rgb = read_image(images[kind]), read_image(images["rgb"])
    assert rgba.shape == rgb.shape == (3, *images["hidden"].shape)
    assert np.isnan(rgba[:, images["hidden"]]).all()
    np.testing.assert_array_equal(rgba[:, ~images["hidden"]], rgb[:, ~images["hidden"]])
    tsai = crater_dir / "oblique.tsai"
    outs = {}
    for name in (kind, "rgb"):
        out = tmp_path / f"{name}-ortho.tif"
        args = [crater_dir / "dem.tif", images[name], tsai, "-o", out, "--grid", "dem", "-q"]
        assert cli_run("ortho", *args).returncode == 0
        with rasterio.open(out) as o:
            assert o.count == 3 and [c.name for c in o.colorinterp] == ["red", "green", "blue"]
            outs[name] = o.read()
    masked, full = outs[kind], outs["rgb"]
    both = np.isfinite(masked[0])
    assert 0 < both.sum() < np.isfinite(full[0]).sum()  # the hidden block is empty
    np.testing.assert_array_equal(masked[:, both], full[:, both])


def test_a_mosaic_of_an_rgba_and_an_rgb_image(
    images: dict, crater_dir: Path, tmp_path: Path
) -> None:
    """An RGBA image beside an RGB one mosaics into three bands (the alpha band would have
    made four against three)."""
    tsai = crater_dir / "oblique.tsai"
    out = tmp_path / "m.tif"
    args = [crater_dir / "dem.tif", images["png"], tsai, images["rgb"], tsai]
    result = cli_run("mosaic", *args, "-o", out, "--grid", "dem", "-q")
    assert result.returncode == 0, result.stderr
    with rasterio.open(out) as o:
        assert o.count == 3 and np.isfinite(o.read(1)).sum() > 1000
