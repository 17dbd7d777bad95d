"""An Orthority exterior file whose interior file cannot be told (none, or several ``.yaml``
beside it) on the command line: one line with exit status 2 that says what a command-line user
can do (keep only its interior file beside it) and what a Python user can (``interior=``),
and both remedies work."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import rasterio

from orthomvp.cli import main
from tests.conftest import shared


@pytest.mark.realdata
def test_orthority_interior_file_advice_on_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    import orthomvp as om

    ngi = shared("ngi-aerial")
    frame = "3324c_2015_1004_05_0182_RGB.tif"
    for name in (frame, "orthority-format/ngi_xyz_opk.csv", "orthority-format/ngi_int_param.yaml"):
        shutil.copy(ngi / name, tmp_path)
    interior, exterior = tmp_path / "ngi_int_param.yaml", tmp_path / "ngi_xyz_opk.csv"
    other = tmp_path / "b.yaml"
    shutil.copy(interior, other)
    out = tmp_path / "o.tif"
    args = ["ortho", str(ngi / "dem.tif"), str(tmp_path / frame), str(exterior), "-o", str(out)]
    args += ["--res", "48m", "--height-offset", "28"]
    assert main(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: error:"), err
    assert "there are 2 (b.yaml, ngi_int_param.yaml): keep only theirs there" in err[0], err
    assert "read_camera(..., interior=FILE)" in err[0], err
    assert not out.exists()
    # the Python remedy: the interior file named
    camera = om.read_camera(exterior, frame, interior=interior)
    assert camera.center.shape == (3,)
    # the command line's: the other .yaml moved away
    other.unlink()
    assert main(args) == 0
    with rasterio.open(out) as o:
        assert o.count == 3 and o.read(1, masked=True).count() > 0
    capsys.readouterr()
    interior.unlink()
    out.unlink()
    assert main(args) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "and there is none: put it there" in err[0], err
