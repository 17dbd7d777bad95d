"""DEM and image values as the file means them: GDAL's scale and offset applied wherever a
raster is read as values (after the nodata test), and fill values that carry no nodata tag
(float32's lowest, 1e30) taken as nodata with a warning that counts them, or refused when a
value strays farther from the others than any body's relief allows. An orthophoto that
would be empty although its images see the grid is an error naming the counts."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.codes import Code
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.engine.run import RunReport, check_filled
from orthomvp.errors import GeometryError, InputError, OrthoMVPWarning
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image

SCALE, OFFSET = 0.5, 1000.0


def _heights(crater_dir: Path) -> tuple[np.ndarray, dict]:
    with rasterio.open(crater_dir / "dem.tif") as src:
        return src.read(1).astype(np.float64), src.profile


def _scaled_pair(crater_dir: Path, tmp_path: Path) -> tuple[Path, Path]:
    """The crater DEM as int16 with scale 0.5 and offset 1000, and the same heights as
    float32 (exactly: every stored number times 0.5 plus 1000)."""
    heights, profile = _heights(crater_dir)
    stored = np.round((heights - OFFSET) / SCALE)
    assert np.abs(stored).max() < 32767
    scaled, plain = tmp_path / "int16.tif", tmp_path / "float32.tif"
    with rasterio.open(scaled, "w", **(profile | {"dtype": "int16", "nodata": -32768})) as dst:
        dst.write(stored.astype(np.int16), 1)
        dst.scales, dst.offsets = (SCALE,), (OFFSET,)
    with rasterio.open(plain, "w", **(profile | {"dtype": "float32"})) as dst:
        dst.write((stored * SCALE + OFFSET).astype(np.float32), 1)
    return scaled, plain


def test_a_scaled_int16_dem_reads_as_its_heights(crater_dir: Path, tmp_path: Path) -> None:
    scaled, plain = _scaled_pair(crater_dir, tmp_path)
    a, b = Terrain.read(scaled), Terrain.read(plain)
    np.testing.assert_array_equal(a.values, b.values)
    with rasterio.open(scaled) as src:  # the file holds other numbers: the scale matters
        assert np.abs(src.read(1) - b.values).max() > 100
    view = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    filled, orthos = [], []
    for dem in (scaled, plain):
        plan = plan_ortho(dem, [view], grid="dem", progress=False)
        np.testing.assert_array_equal(plan.dem.read((3, 40, 5, 50)), b.values[3:40, 5:50])
        assert (plan.dem.h_min, plan.dem.h_max) == (np.nanmin(b.values), np.nanmax(b.values))
        out = tmp_path / f"o-{dem.stem}.tif"
        filled.append(run_plan(plan, Outputs(ortho=out), threads=1).filled)
        with rasterio.open(out) as src:
            orthos.append(src.read(1))
    assert filled[0] == filled[1] > 0
    np.testing.assert_array_equal(orthos[0], orthos[1])


def test_a_scaled_image_reads_as_its_values(crater_dir: Path, tmp_path: Path) -> None:
    with rasterio.open(crater_dir / "oblique.tif") as src:
        values, profile = src.read().astype(np.float64), src.profile
    scale, offset = 0.25, -3.0
    stored = np.round((values - offset) / scale)
    path = tmp_path / "scaled.tif"
    with rasterio.open(path, "w", **(profile | {"dtype": "uint16", "nodata": None})) as dst:
        dst.write(stored.astype(np.uint16))
        dst.scales, dst.offsets = (scale,) * dst.count, (offset,) * dst.count
    np.testing.assert_array_equal(read_image(path), (stored * scale + offset).astype(np.float32))


def _with(crater_dir: Path, path: Path, change, nodata: object = "keep") -> Path:
    heights, profile = _heights(crater_dir)
    changed = change(heights.copy())
    if nodata != "keep":
        profile = profile | {"nodata": nodata}
    with rasterio.open(path, "w", **(profile | {"dtype": "float32"})) as dst:
        dst.write(changed.astype(np.float32), 1)
    return path


def _collar(h: np.ndarray) -> np.ndarray:
    h[:6], h[:, :6] = np.finfo(np.float32).min, np.finfo(np.float32).min
    return h


def _four_huge(h: np.ndarray) -> np.ndarray:
    h[10, 10] = h[20, 30] = h[30, 20] = h[40, 40] = 1e30
    return h


@pytest.mark.parametrize(
    ("change", "count"), [(_collar, 64 * 6 + 58 * 6), (_four_huge, 4)], ids=["collar", "1e30"]
)
def test_fill_values_without_a_tag_are_nodata(
    crater_dir: Path, tmp_path: Path, change, count: int
) -> None:
    dem = _with(crater_dir, tmp_path / "dem.tif", change, nodata=None)
    with rasterio.open(dem) as src:
        assert src.nodata is None
    heights, _ = _heights(crater_dir)
    gone = change(np.zeros(heights.shape)) != 0
    assert gone.sum() == count
    message = f"{count:,} heights? of magnitude 1e\\+30 m or more .* taken as nodata"
    with pytest.warns(OrthoMVPWarning, match=message):
        terrain = Terrain.read(dem)
    np.testing.assert_array_equal(np.isnan(terrain.values), gone)
    view = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    with pytest.warns(OrthoMVPWarning, match=message):
        plan = plan_ortho(dem, [view], grid="dem", progress=False)
    assert np.isnan(plan.dem.read((0, 64, 0, 64))).sum() == count
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OrthoMVPWarning)
        report = run_plan(plan, Outputs(ortho=tmp_path / "o.tif"), threads=1)
    assert report.filled > 0.5 * (64 * 64 - count)


def test_a_value_beyond_any_relief_is_refused(crater_dir: Path, tmp_path: Path) -> None:
    def spike(h: np.ndarray) -> np.ndarray:
        h[30, 30] = 5e9
        return h

    dem = _with(crater_dir, tmp_path / "dem.tif", spike)
    match = r"a DEM value of 5e\+09 m is .* from the median, .* more than 1 times the body's radius"
    with pytest.raises(InputError, match=match):
        Terrain.read(dem)
    view = (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    with pytest.raises(InputError, match=match):
        plan_ortho(dem, [view], progress=False)


def test_an_orthophoto_with_nothing_visible_is_an_error(crater_dir: Path) -> None:
    class View:
        path = Path("a.tif")

    counts = [0] * len(Code)
    counts[Code.OCCLUDED], counts[Code.FACING_AWAY] = 1200, 30
    report = RunReport(inside=[1230], taken=[0], counts=[counts])
    with pytest.raises(GeometryError, match="a.tif: 1,200 occluded, 30 facing away"):
        check_filled([View()], report)
    report.filled = 1
    check_filled([View()], report)
