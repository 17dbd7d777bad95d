"""The command line: subcommands, one-line errors with exit status 2, no half-written output."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import trimesh
from affine import Affine

from orthomvp.cli import main

COMMANDS = (
    "demo", "synth", "mesh", "render", "visibility", "ortho", "mosaic", "fit", "explore",
    "eps-study", "bench",
)  # fmt: skip


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``python -m orthomvp ARGS`` in a subprocess, as a user would."""
    return subprocess.run(
        [sys.executable, "-m", "orthomvp", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=600,
    )


def assert_one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("orthomvp: error:")
    assert "Traceback" not in proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


def test_help_lists_subcommands() -> None:
    proc = run("--help")
    assert proc.returncode == 0
    for cmd in COMMANDS:
        assert cmd in proc.stdout
    for cmd in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([cmd, "--help"])
        assert exc.value.code == 0


def test_usage_errors_are_one_line() -> None:
    assert_one_line_error(run("synth", "volcano", "x"), "invalid choice")
    assert_one_line_error(run("mesh", "dem.tif"), "-o/--output")


@pytest.mark.slow
def test_synth_then_mesh(tmp_path: Path) -> None:
    out = tmp_path / "scene"
    proc = run("synth", "hills", str(out), "--size", "24", "--supersample", "1")
    assert proc.returncode == 0, proc.stderr
    for name in ("dem.tif", "scene.json", "truth_radiance.tif", "fore1.tif", "fore1.tsai"):
        assert (out / name).is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    ply = tmp_path / "hills.ply"
    proc = run(
        "mesh", str(out / "dem.tif"), "-o", str(ply), "--texture", str(out / "truth_radiance.tif")
    )
    assert proc.returncode == 0, proc.stderr
    mesh = trimesh.load(ply, process=False)
    assert len(mesh.faces) == 2 * 23 * 23 and len(mesh.vertices) == 24 * 24
    # body-fixed coordinates: every vertex is about one lunar radius from the centre
    radii = np.linalg.norm(mesh.vertices, axis=1)
    assert np.all(np.abs(radii - 1737400) < 5000)


@pytest.mark.slow
def test_mesh_bad_inputs_leave_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out.ply"
    assert_one_line_error(
        run("mesh", str(tmp_path / "missing.tif"), "-o", str(out)), "missing.tif", "no such file"
    )
    (tmp_path / "corrupt.tif").write_bytes(b"II*\x00" + bytes(range(200)))
    assert_one_line_error(run("mesh", str(tmp_path / "corrupt.tif"), "-o", str(out)), "corrupt.tif")
    profile = dict(
        driver="GTiff",
        width=8,
        height=8,
        count=1,
        dtype="float32",
        transform=Affine(0.01, 0, 0, 0, -0.01, 0),
    )
    with rasterio.open(tmp_path / "nocrs.tif", "w", **profile) as dst:
        dst.write(np.zeros((8, 8), np.float32), 1)
    assert_one_line_error(run("mesh", str(tmp_path / "nocrs.tif"), "-o", str(out)), "no CRS")
    proc = run(
        "mesh", str(tmp_path / "nocrs.tif"), "-o", str(out), "--dem-crs", "+proj=longlat +R=1737400"
    )
    assert proc.returncode == 0, proc.stderr
    out.unlink()
    assert_one_line_error(
        run(
            "mesh",
            str(tmp_path / "nocrs.tif"),
            "-o",
            str(tmp_path / "out.stl"),
            "--dem-crs",
            "+proj=longlat +R=1737400",
        ),
        "format",
    )
    assert_one_line_error(
        run(
            "mesh",
            str(tmp_path / "nocrs.tif"),
            "-o",
            str(tmp_path / "nodir" / "out.ply"),
            "--dem-crs",
            "+proj=longlat +R=1737400",
        ),
        "does not exist",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corrupt.tif", "nocrs.tif"]


@pytest.mark.slow
def test_bench_prints_ratios(tmp_path: Path) -> None:
    proc = run(
        "bench",
        "--size",
        "60",
        "--rays",
        "20000",
        "--ortho-size",
        "80",
        "--mvp-size",
        "40",
        "--json",
        str(tmp_path / "b.json"),
    )
    assert proc.returncode == 0, proc.stderr
    assert "embree" in proc.stdout and "open3d" in proc.stdout and "ratio" in proc.stdout
    assert "occlusion-aware orthophoto" in proc.stdout
    assert "MVP fit" in proc.stdout
    assert (tmp_path / "b.json").is_file()
