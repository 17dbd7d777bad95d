"""``orthomvp bench --mosaic-scale``: the growing set's grid grows as the number of images,
each run's figures are its own, and counts the growing set cannot make are refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from orthomvp.bench.mosaic import growing_scene
from tests.test_cli import assert_one_line_error, run


def test_growing_set_tiles_the_seen_dem_k_by_k(tmp_path: Path) -> None:
    """N = 16: the DEM is the N = 4 one tiled 2 x 2, and each camera is one of the four shifted
    by whole extents of it (synthetic frames)."""
    from orthomvp.io.raster import open_raster

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    dem4, views4, _ = growing_scene(None, 4, tmp_path / "a")
    dem16, views16, _ = growing_scene(None, 16, tmp_path / "b")
    with open_raster(dem4) as a, open_raster(dem16) as b:
        small, big = a.read(1), b.read(1)
        width, height = a.width * a.transform.a, a.height * a.transform.e
        assert b.transform == a.transform
    rows, cols = small.shape
    assert big.shape == (2 * rows, 2 * cols)
    assert (big[rows:, cols:] == small).all() and (big[:rows, cols:] == small).all()
    assert len(views16) == 16
    for k, (image, camera) in enumerate(views16):
        i, j = divmod(k // 4, 2)
        base = views4[k % 4][1]
        assert image.name == views4[k % 4][0].name
        assert (camera.center == base.center + [j * width, i * height, 0.0]).all()


@pytest.mark.slow
def test_bench_mosaic_scale_reports_every_count(tmp_path: Path) -> None:
    """Two counts of the growing set at 48 m and of the fixed set at 48 m (synthetic frames):
    a row per set and count, the first count's time per image 1, the fixed set's grid the
    same for both counts, the growing set's four times as large."""
    out = tmp_path / "m.json"
    proc = run(
        "bench", "--mosaic-scale", "4", "16", "--mosaic-res", "48", "--mosaic-fixed", "48",
        "--peer-data", str(tmp_path), "--json", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(out.read_text())["mosaic"]
    assert [(r["set"], r["images"]) for r in rows] == [
        ("growing", 4), ("growing", 16), ("fixed", 4), ("fixed", 16)
    ]  # fmt: skip
    assert rows[0]["per_image"] == 1 and rows[2]["per_image"] == 1 == rows[2]["cpu_per_image"]
    assert all(r["cpu_s"] > 0 for r in rows)
    assert rows[3]["posts"] == rows[2]["posts"]
    assert 3.5 < rows[1]["posts"] / rows[0]["posts"] < 4.5
    assert all(r["peak_rss_mb"] > 50 and r["tiles"] >= 1 for r in rows)
    assert "synthetic aerial scene" in proc.stdout


def test_bench_mosaic_refuses_counts_the_growing_set_cannot_make(tmp_path: Path) -> None:
    assert_one_line_error(run("bench", "--mosaic-scale", "4", "12"), "4 K^2", "12")
