"""``orthomvp bench --formats``: the frame's three stored forms hold the same pixels (the JPEG
within its compression), and the benchmark reports every form at both tile sizes with the
lossless forms' orthophotos equal."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.bench.formats import ENLARGE, formats_case
from orthomvp.bench.peer import synthetic_case
from orthomvp.io.raster import read_image
from tests.test_cli import run


def test_the_forms_hold_the_enlarged_frame(tmp_path: Path) -> None:
    """Without the data: the synthetic frame enlarged ENLARGE times; the PNG's and the one
    strip's pixels are the GeoTIFF's, the JPEG's within a few levels of them; the interior file
    gives the new size."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    small = synthetic_case(tmp_path / "a").image
    case, images, camera = formats_case(None, tmp_path / "b")
    with rasterio.open(small) as src:
        rows, cols = src.height, src.width
    tiff = read_image(images["GTiff"])
    assert tiff.shape == (3, rows * ENLARGE, cols * ENLARGE)
    np.testing.assert_array_equal(read_image(images["PNG"]), tiff)
    np.testing.assert_array_equal(read_image(images["strip"]), tiff)
    with rasterio.open(images["strip"]) as src:
        assert src.block_shapes[0] == (1, cols * ENLARGE)  # (GDAL reads it line by line)
    assert np.abs(read_image(images["JPEG"]) - tiff).mean() < 6
    assert (
        f"im_size: [{cols * ENLARGE}, {rows * ENLARGE}]"
        in (camera.parent / "int_param.yaml").read_text()
    )
    with rasterio.open(images["JPEG"]) as src:
        assert src.driver == "JPEG"


@pytest.mark.slow
def test_bench_formats_reports_every_form(tmp_path: Path) -> None:
    """One run of each (synthetic frame): a row per tile size and form, the GeoTIFF's ratio 1,
    the lossless forms' orthophotos equal to the GeoTIFF's and the JPEG's not."""
    out = tmp_path / "f.json"
    proc = run(
        "bench", "--formats", "--peer-repeat", "1", "--peer-data", str(tmp_path),
        "--json", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(out.read_text())["formats"]
    assert [(r["tile"], r["format"]) for r in rows] == [
        (t, f) for t in ("default", 128) for f in ("GTiff", "JPEG", "PNG", "strip")
    ]
    for row in rows:
        if row["format"] == "GTiff":
            assert row["ratio"] == 1
        assert row["equal"] == (row["format"] != "JPEG")
        assert row["seconds"] > 0 and row["rss_mb"] > 50
    assert "synthetic aerial frame" in proc.stdout and "equals the GeoTIFF's" in proc.stdout
