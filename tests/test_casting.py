"""Orthophoto values as written: cast to an integer ``--dtype`` (orthomvp.engine.casting),
what the cast loses (clipped values, a range rounded to a few levels) counted and said once a
run; the colour interpretation of an orthophoto of RGB images."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.errors

from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.engine.casting import FEW_LEVELS, IntegerCast, to_dtype
from orthomvp.errors import OrthoMVPWarning
from tests.test_cli import run as cli_run


def tiles(rng: np.random.Generator, low: float, high: float) -> list[np.ndarray]:
    """Three float32 tiles (2 bands, 40 x 30) of values uniform in [low, high), a quarter
    of them empty (NaN)."""
    out = []
    for _ in range(3):
        data = rng.uniform(low, high, (2, 40, 30)).astype(np.float32)
        data[rng.random(data.shape) < 0.25] = np.nan
        out.append(data)
    return out


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "int16"])
def test_clipped_values_are_counted_exactly(dtype: str) -> None:
    """Over tiles that reach past both ends of the type, the count of clipped filled values
    equals the values whose rounding lies outside it, and the cast equals :func:`to_dtype`."""
    info = np.iinfo(dtype)
    rng = np.random.default_rng(3)
    data = tiles(rng, info.min - 300.0, info.max + 300.0)
    data[0][0, 0, :4] = [info.min - 0.5, info.max + 0.5, info.min - 0.51, info.max + 0.49]
    cast = IntegerCast(Path("out.tif"), dtype, 0 if dtype != "int16" else info.min)
    for tile in data:
        np.testing.assert_array_equal(cast(tile), to_dtype(tile, dtype, cast.nodata))
    values = np.concatenate([tile[np.isfinite(tile)] for tile in data]).astype(np.float64)
    rounded = np.rint(values)
    clipped = int(((rounded < info.min) | (rounded > info.max)).sum())
    assert cast.filled == values.size and cast.low + cast.high == clipped > 0
    loss = cast.loss()
    assert loss is not None and loss.startswith("out.tif: ")
    assert f"{clipped:,} of {values.size:,} filled values" in loss
    assert f"{dtype}'s {info.min}..{info.max}" in loss
    assert f"from {values.min():.6g} to {values.max():.6g}" in loss


def test_a_range_rounded_to_few_levels_is_said() -> None:
    """Radiances in 0..1 as uint16 keep 2 levels: said; an 8-bit image's values, a mask of
    whole numbers and a tile with no filled post: nothing to say."""
    rng = np.random.default_rng(4)
    flat = IntegerCast(Path("r.tif"), "uint16", 0)
    for tile in tiles(rng, 0.01, 0.94):
        flat(tile)
    assert flat.loss() == (
        "r.tif: the values run from "
        f"{flat.least:.6g} to {flat.most:.6g}: rounded to uint16 they keep 2 levels; "
        "--dtype float32 (the default) keeps them"
    )
    eight = IntegerCast(Path("e.tif"), "uint8", 0)
    for tile in tiles(rng, 3.0, 250.0):
        eight(tile)
    assert eight.loss() is None
    mask = IntegerCast(Path("m.tif"), "uint8", 0)
    for tile in tiles(rng, 0.0, 2.0):
        mask(np.floor(tile))
    assert mask.loss() is None  # whole numbers, 2 levels: nothing lost
    dim = IntegerCast(Path("d.tif"), "uint8", 0)
    for tile in tiles(rng, 10.2, 10.2 + FEW_LEVELS - 1):
        dim(tile)
    assert dim.loss() is None  # FEW_LEVELS levels: enough
    empty = IntegerCast(Path("n.tif"), "uint8", 0)
    empty(np.full((1, 4, 4), np.nan, np.float32))
    assert empty.loss() is None


def test_a_run_says_it_once(crater_dir: Path, tmp_path: Path) -> None:
    """The crater's radiances (0..1) as uint16 in tiles of 32 posts: one warning for the run,
    naming the output, and the file holds what to_dtype makes of the float32 orthophoto;
    float32 itself says nothing."""
    view = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    plan = plan_ortho(crater_dir / "dem.tif", [view], tile=32, progress=False, grid="dem")
    assert len(plan.tiles) > 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_plan(plan, Outputs(ortho=tmp_path / "f.tif"), progress=False)
        run_plan(plan, Outputs(ortho=tmp_path / "u.tif", dtype="uint16"), progress=False)
    said = [str(w.message) for w in caught if issubclass(w.category, OrthoMVPWarning)]
    assert len(said) == 1 and said[0].startswith(f"{tmp_path / 'u.tif'}: the values run from")
    assert "rounded to uint16 they keep 2 levels" in said[0]
    with rasterio.open(tmp_path / "f.tif") as f, rasterio.open(tmp_path / "u.tif") as u:
        np.testing.assert_array_equal(u.read(), to_dtype(f.read(), "uint16", 0))


def test_the_command_line_says_it_in_one_line(crater_dir: Path, tmp_path: Path) -> None:
    """``orthomvp ortho --dtype uint8`` of the crater with its radiances scaled by 400 (past
    255): exit 0, one warning line counting the clipped values."""
    with rasterio.open(crater_dir / "oblique.tif") as src:
        profile, image = src.profile, src.read()
    bright = tmp_path / "bright.tif"
    with warnings.catch_warnings():  # (the scene's images have no georeference)
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(bright, "w", **profile) as dst:
            dst.write(image * 400)
    result = cli_run(
        "ortho", crater_dir / "dem.tif", bright, crater_dir / "oblique.tsai",
        "-o", tmp_path / "o.tif",
        "--dtype", "uint8", "--grid", "dem",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = [x for x in result.stderr.splitlines() if x.startswith("orthomvp: warning:")]
    assert len(lines) == 1 and "filled values" in lines[0] and "were clipped" in lines[0]
    assert "uint8's 0..255" in lines[0]


def test_an_integer_image_of_few_levels_says_nothing(crater_dir: Path, tmp_path: Path) -> None:
    """The crater's image as uint8 digital numbers 10..19 (a dark, low-contrast frame) written
    as uint8: its few levels are its own, so no warning; its float radiances as uint8 warn."""
    with rasterio.open(crater_dir / "oblique.tif") as src:
        profile, image = src.profile, src.read()
    dark = tmp_path / "dark.tif"
    numbers = (10 + np.floor(9.99 * np.clip(image, 0, 1))).astype(np.uint8)
    with warnings.catch_warnings():  # (the scene's images have no georeference)
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(dark, "w", **(profile | {"dtype": "uint8", "nodata": None})) as dst:
            dst.write(numbers)
    for image_path, warned in ((dark, False), (crater_dir / "oblique.tif", True)):
        result = cli_run(
            "ortho", crater_dir / "dem.tif", image_path, crater_dir / "oblique.tsai",
            "-o", tmp_path / f"{image_path.stem}-u8.tif", "--dtype", "uint8", "--grid", "dem",
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        lines = [x for x in result.stderr.splitlines() if x.startswith("orthomvp: warning:")]
        assert len(lines) == int(warned), result.stderr


def test_rgb_images_give_an_rgb_orthophoto(crater_dir: Path, tmp_path: Path) -> None:
    """Three bands that GDAL reads as red, green and blue give an orthophoto read so too, as
    float32 (GDAL's default for other than bytes would be grey) and as uint8, COG and plain
    GeoTIFF; the crater's grey image stays grey, and the values are the same either way."""
    with rasterio.open(crater_dir / "oblique.tif") as src:
        profile, grey = src.profile, src.read(1)
    rgb = tmp_path / "rgb.tif"
    bands = np.stack([grey, 0.5 * grey, 0.25 * grey]).astype(np.float32)
    with warnings.catch_warnings():  # (the scene's images have no georeference)
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(rgb, "w", **(profile | {"count": 3, "photometric": "RGB"})) as dst:
            dst.write(bands)
    base = [crater_dir / "dem.tif", rgb, crater_dir / "oblique.tsai", "--grid", "dem", "-q"]
    colours = ("red", "green", "blue")
    runs = {"cog": [], "gtiff": ["--format", "gtiff"], "u8": ["--dtype", "uint8"]}
    for name, extra in runs.items():
        out = tmp_path / f"{name}.tif"
        assert cli_run("ortho", *base, "-o", out, *extra).returncode == 0
        with rasterio.open(out) as o:
            assert tuple(c.name for c in o.colorinterp) == colours, name
    plain = tmp_path / "grey.tif"
    grey_args = [crater_dir / "dem.tif", crater_dir / "oblique.tif", crater_dir / "oblique.tsai"]
    assert cli_run("ortho", *grey_args, "--grid", "dem", "-q", "-o", plain).returncode == 0
    with rasterio.open(plain) as o, rasterio.open(tmp_path / "cog.tif") as c:
        assert o.colorinterp[0].name == "gray"
        np.testing.assert_array_equal(c.read(1), o.read(1))
