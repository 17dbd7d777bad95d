"""``orthomvp bench --peer orthority``: figures consistent, a clear error without Orthority."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import shared

from orthomvp import bench
from orthomvp.camera import read_camera
from orthomvp.cli import main
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.geometry.world import detect_world
from orthomvp.io.raster import read_image


def require_orthority() -> None:
    try:
        bench.import_orthority()
    except InputError as exc:
        pytest.skip(f"the peer tool is absent: {exc}")


def test_without_orthority_one_line_and_exit_2(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "orthority", None)  # makes the import fail
    assert main(["bench", "--peer", "orthority", "--json", str(tmp_path / "b.json")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and not (tmp_path / "b.json").exists()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("orthomvp: error:")
    assert "orthority is not installed" in lines[0] and "pip install orthority" in lines[0]


def test_import_keeps_proj_offline(monkeypatch: pytest.MonkeyPatch) -> None:
    require_orthority()
    monkeypatch.delitem(sys.modules, "orthority")
    monkeypatch.setenv("PROJ_NETWORK", "OFF")
    bench.import_orthority()  # a fresh import sets PROJ_NETWORK=ON
    assert os.environ["PROJ_NETWORK"] == "OFF"


def test_synthetic_case_is_an_aerial_map_frame_scene(tmp_path: Path) -> None:
    case = bench.synthetic_case(tmp_path)
    terrain = Terrain.read(case.dem)
    assert terrain.crs.is_projected and terrain.shape == (508, 327)
    assert read_image(case.image).shape == (3, 1152, 640)
    assert len(case.frames) == 2 and case.frames[0] == case.image
    camera = read_camera(case.exterior, case.image)
    assert detect_world(terrain, camera.center[None]) == "map"


def test_bench_orthority_figures_are_consistent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    require_orthority()
    out = tmp_path / "bench.json"
    args = ["bench", "--peer", "orthority", "--peer-data", str(tmp_path / "absent")]
    assert main([*args, "--peer-repeat", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "synthetic aerial scene" in text and "ratio" in text
    (key,) = json.loads(out.read_text())
    row = json.loads(out.read_text())[key]
    assert key == "orthority" and row["case"] == "synthetic hills" and row["res_m"] == 24.0
    for name in ("orthority_s", "orthomvp_s", "orthomvp_naive_s"):
        assert row[name] > 0
    assert row["ratio"] == pytest.approx(row["orthomvp_s"] / row["orthority_s"])
    assert row["naive_ratio"] == pytest.approx(row["orthomvp_naive_s"] / row["orthority_s"])
    for name in ("orthority_cli_s", "orthomvp_cli_s", "orthomvp_naive_cli_s"):
        assert row[name] > 0
    assert row["cli_ratio"] == pytest.approx(row["orthomvp_cli_s"] / row["orthority_cli_s"])
    assert row["cli_equals_api"]  # the command line writes what the engine does in process
    assert row["mosaic_frames"] == 2 and row["orthomvp_mosaic_cli_s"] > 0
    ratio = row["orthomvp_mosaic_cli_s"] / row["orthority_mosaic_cli_s"]
    assert row["mosaic_cli_ratio"] == pytest.approx(ratio) and "mosaic" in text
    rows, cols = row["mosaic_grid"]
    assert rows * cols > row["posts"]  # the union of both frames' grids
    steps = row["orthomvp_steps_s"]
    assert tuple(steps) == bench.RUN_STEPS
    assert sum(steps.values()) == pytest.approx(row["orthomvp_s"], rel=0.05)
    assert row["posts"] == np.prod(row["grid"]) > 10_000
    assert row["max_abs_diff"] == 0.0  # same grid and positions: the same bilinear samples
    assert main([*args, "--peer-res", "0"]) == 2


def test_without_gdalwarp_one_line_and_exit_2(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no gdalwarp on it
    assert main(["bench", "--peer", "gdal", "--json", str(tmp_path / "b.json")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and not (tmp_path / "b.json").exists()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("orthomvp: error:")
    assert "gdalwarp is not on PATH" in lines[0] and "gdal-bin" in lines[0]


@pytest.mark.realdata
@pytest.mark.slow
def test_bench_gdal_figures_are_consistent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``bench --peer gdal`` on its coarsest grid (24 m): both tools' times, ratios, peak
    memory, and the two orthophotos agree as the goal says (r >= 0.9999, shift <= 0.01 px;
    coarser, GDAL's approximate transformer's 0.125 px tell on the 6.4 m image)."""
    if shutil.which("gdalwarp") is None:
        pytest.skip("the peer tool gdalwarp is absent (Debian: gdal-bin)")
    shared("rpc-quickbird", "qb2_basic1b.tif")
    out = tmp_path / "bench.json"
    args = ["bench", "--peer", "gdal", "--peer-data", str(shared("ngi-aerial"))]
    assert main([*args, "--peer-res", "24", "--peer-repeat", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "gdalwarp" in text and "ratio" in text
    (row,) = json.loads(out.read_text())["gdal"]
    assert row["res_m"] == 24.0 and row["grid"] == [396, 236]
    for name in ("gdal", "orthomvp", "orthomvp_naive"):
        assert row[f"{name}_s"] > 0 and row[f"{name}_rss_mb"] > 10
    assert row["ratio"] == pytest.approx(row["orthomvp_s"] / row["gdal_s"])
    assert row["naive_ratio"] == pytest.approx(row["orthomvp_naive_s"] / row["gdal_s"])
    assert 0 < row["gdal_startup_s"] and 0 < row["orthomvp_startup_s"] < row["orthomvp_s"] * 1.5
    net = (row["orthomvp_s"] - row["orthomvp_startup_s"]) / (row["gdal_s"] - row["gdal_startup_s"])
    assert row["net_ratio"] == pytest.approx(net) or row["gdal_s"] <= row["gdal_startup_s"]
    assert "beyond start-up" in text and "4 x 4 posts" in text
    assert row["common_posts"] > 0.9 * 396 * 236
    assert row["r"] > 0.9999 and row["shift"] < 0.01
