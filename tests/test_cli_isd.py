"""``orthomvp isd``: the ISD written from a cube is the camera read from the cube, and usgscsm's
truth holds on it; refusals are one line with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from orthomvp.camera import read_camera
from orthomvp.camera.isis import read_cube_camera
from tests.conftest import shared

LRO = ("isis", "M143947267L.cal.echo.crop")
APOLLO = ("as15-hadley", "AS15-M-1134-hadley")


def run(*args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "orthomvp", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.realdata
def test_the_lro_nac_isd_gives_usgscsms_pixels(tmp_path: Path) -> None:
    folder, name = LRO
    out = tmp_path / "nac.json"
    proc = run("isd", shared(folder, f"{name}.cub"), "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == "" and proc.stdout.startswith("orthomvp: wrote ")
    assert json.loads(out.read_text())["name_model"] == "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
    truth = json.loads(shared("isis", f"{name}.truth.json").read_text())
    pts = truth["points"]
    camera = read_camera(out)
    for k, _height in enumerate(truth["settings"]["heights_m"]):
        ground = np.array([p["heights"][k]["ground"] for p in pts])
        line, sample, _ = camera.csm_ground_to_image(ground)
        want = np.array([[p["heights"][k]["g2i"][a] for a in ("line", "sample")] for p in pts])
        assert np.abs(np.stack([line, sample], -1) - want).max() < 0.01


@pytest.mark.realdata
def test_the_apollo_isd_is_the_cube_camera_without_isis_lens(tmp_path: Path) -> None:
    folder, name = APOLLO
    cube = shared(folder, f"{name}.cub")
    out = tmp_path / "apollo.json"
    proc = run("isd", cube, "-o", out)
    assert proc.returncode == 0, proc.stderr
    (warning,) = proc.stderr.splitlines()
    assert warning.startswith("orthomvp: warning:") and "lens model" in warning
    from_isd, from_cube = read_camera(out), read_cube_camera(cube)
    # body-fixed points under the frame: the cube's camera (with ISIS's lens) and the ISD's
    # (without it) see them within the lens's reach (1.8 px over the crop), and the same
    # line of sight through the frame's centre
    u, v = np.meshgrid(np.linspace(50, 700, 5), np.linspace(50, 700, 5))
    uv = np.stack([u.ravel(), v.ravel()], -1)
    origins, dirs = from_isd.ray(uv)
    points = origins + dirs * 117_000.0
    uv_cube, _ = from_cube.project(points)
    shift = np.linalg.norm(uv_cube - uv, axis=1)
    assert shift.max() < 2.0 and shift.max() > 0.1


def test_refusals_are_one_line_with_exit_2(tmp_path: Path) -> None:
    not_a_cube = tmp_path / "x.cub"
    not_a_cube.write_text("this is no cube\n")
    existing = tmp_path / "exists.json"
    existing.write_text("{}")
    for args in (
        [not_a_cube, "-o", tmp_path / "a.json"],
        [tmp_path / "missing.cub", "-o", tmp_path / "b.json"],
        [not_a_cube, "-o", tmp_path / "c.txt"],
        [not_a_cube, "-o", existing],
    ):
        proc = run("isd", *args)
        assert proc.returncode == 2, (args, proc.stderr)
        assert proc.stderr.startswith("orthomvp: error:") and proc.stderr.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists.json", "x.cub"]
    assert existing.read_text() == "{}"
