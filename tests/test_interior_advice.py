"""An Orthority exterior file whose interior file cannot be told (none, or several ``.yaml``
beside it) on the command line: one line with exit status 2 that says what a command-line user
can do (keep only its interior file beside it) and what a Python user can (``interior=``),
and both remedies work. An Orthority file that holds no exterior parameters (a GCP file), or a
``.yaml`` beside one that holds RPCs, is named as what it is."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import rasterio

from orthomvp.camera import read_camera
from orthomvp.cli import main
from orthomvp.errors import InputError
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


def _gcp_file(path: Path, image: str) -> Path:
    """A minimal Orthority GCP file: a FeatureCollection of Points (lon, lat, height) with the
    image's pixel coordinates ``ji`` (column, row), its ``filename`` and an ``id``."""
    features = [
        {
            "type": "Feature",
            "properties": {"ji": [12.5, 40.0], "filename": image, "id": "gcp-1"},
            "geometry": {"type": "Point", "coordinates": [24.4, -33.6, 210.0]},
        }
    ]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def test_a_gcp_file_given_as_a_camera_is_named_as_such(tmp_path: Path) -> None:
    """With no interior file beside it (it needs none) the GCP file is named, not the missing
    .yaml; with an RPC parameter file beside it, the GCP file still, not the .yaml."""
    gcps = _gcp_file(tmp_path / "gcps.geojson", "qb.tif")
    words = f"{gcps}: an Orthority GCP file (ground control points"
    with pytest.raises(InputError, match=re.escape(words)) as caught:
        read_camera(gcps, "qb.tif")
    assert "not camera exterior parameters ('xyz' and 'opk')" in str(caught.value)
    (tmp_path / "rpc_param.yaml").write_text("qb.tif:\n    im_size: [850, 1450]\n    rpc: {}\n")
    with pytest.raises(InputError, match=re.escape(words)):
        read_camera(gcps, "qb.tif")


@pytest.mark.realdata
def test_the_audits_gcp_and_rpc_files_are_named_on_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The audit's case: `info DEM qb2_basic1b.tif gcps.geojson` blamed rpc_param.yaml, a file
    the user did not give ("camera type None is not supported"); and an exterior file beside an
    RPC parameter file is told that the .yaml holds RPCs."""
    qb, ngi = shared("rpc-quickbird"), shared("ngi-aerial")
    dem = str(ngi / "dem.tif")
    assert main(["info", dem, str(qb / "qb2_basic1b.tif"), str(qb / "gcps.geojson")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"orthomvp: error: {qb / 'gcps.geojson'}: an Orthority GCP file (ground control points"
    ), err
    assert "rpc_param.yaml" not in err[0]
    shutil.copy(ngi / "orthority-format" / "ngi_ext_param.geojson", tmp_path)
    shutil.copy(qb / "rpc_param.yaml", tmp_path)
    frame = str(ngi / "3324c_2015_1004_05_0182_RGB.tif")
    assert main(["info", dem, frame, str(tmp_path / "ngi_ext_param.geojson")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"{tmp_path / 'rpc_param.yaml'}, line " in err[0], err
    assert "holds RPC parameters (an Orthority RPC file), not the interior parameters" in err[0]
