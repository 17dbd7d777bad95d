"""Multi-camera files (Orthority's exterior CSV, OpenSfM's reconstruction.json, ODM's
shots.geojson, Orthority's RPC YAML) are read once per run, not once per image: a mosaic's images
pick their cameras from one file, and reading all of it for each image made planning grow as the
square of the number of images. Each file is read again when its contents (or its interior
file's) change; the cameras are those of the file as written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from orthomvp.camera import read_camera
from orthomvp.camera.formats import opensfm, orthority

NAMES = ("a", "b", "c")
INTERIOR = "cam:\n  type: pinhole\n  im_size: [640, 480]\n  focal_len: 0.8\n"


def counted(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[int]:
    """Replace ``module.name`` by a wrapper that counts its calls (the list's length)."""
    calls: list[int] = []
    inner = getattr(module, name)
    monkeypatch.setattr(module, name, lambda *a, **k: calls.append(1) or inner(*a, **k))
    return calls


def exterior_csv(x0: float) -> str:
    """An Orthority exterior CSV of NAMES, image i at x = x0 + 10 i, looking down."""
    rows = [f"{n}.tif,{x0 + 10 * i},{5 * i},1000,0,0,{30 * i}" for i, n in enumerate(NAMES)]
    return "filename,x,y,z,omega,phi,kappa\n" + "\n".join(rows) + "\n"


def test_orthority_exterior_read_once_per_contents(tmp_path: Path, monkeypatch) -> None:
    csv, interior = tmp_path / "ext.csv", tmp_path / "int.yaml"
    csv.write_text(exterior_csv(100.0))
    interior.write_text(INTERIOR)
    truth = orthority.read_orthority_cameras(interior, csv)
    calls = counted(monkeypatch, orthority, "_combine")
    cameras = {n: read_camera(csv, f"images/{n}.tif") for n in NAMES}
    assert len(calls) == 1
    for i, name in enumerate(NAMES):
        np.testing.assert_array_equal(cameras[name].center, [100.0 + 10 * i, 5 * i, 1000])
        np.testing.assert_array_equal(cameras[name].rotation, truth[name].rotation)
        assert (cameras[name].fu, cameras[name].width) == (truth[name].fu, 640)
    csv.write_text(exterior_csv(200.0))  # new contents: read again
    assert read_camera(csv, "b").center[0] == 210.0 and len(calls) == 2
    interior.write_text(INTERIOR.replace("0.8", "0.4"))  # a new interior: read again
    assert read_camera(csv, "b").fu == pytest.approx(truth["b"].fu / 2) and len(calls) == 3


def reconstruction(x0: float) -> list[dict]:
    """A reconstruction.json of NAMES, shot i at x = x0 + i metres east of the reference."""
    spec = {"projection_type": "perspective", "width": 200, "height": 100, "focal": 0.5}
    shots = {
        f"{n}.JPG": {"rotation": [math.pi, 0, 0], "translation": [-x0 - i, 0, 100], "camera": "c"}
        for i, n in enumerate(NAMES)
    }
    ref = {"latitude": 0.0, "longitude": 3.0, "altitude": 10.0}  # UTM 31N: easting 500,000 m
    return [{"cameras": {"c": spec}, "shots": shots, "reference_lla": ref}]


def test_opensfm_reconstruction_read_once_per_contents(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "reconstruction.json"
    path.write_text(json.dumps(reconstruction(10.0)))
    calls = counted(monkeypatch, opensfm, "_reconstruction")
    centres = [read_camera(path, f"{n}.tif").center for n in NAMES]
    assert len(calls) == 1
    # Rodrigues (pi, 0, 0) is diag(1, -1, -1): the centre is -R^T t = (x0 + i, 0, 100) + ref
    np.testing.assert_allclose(centres, [[500_010.0 + i, 0, 110] for i in range(3)], atol=1e-6)
    path.write_text(json.dumps(reconstruction(20.0)))
    assert read_camera(path, "a").center[0] == pytest.approx(500_020.0) and len(calls) == 2


def test_odm_shots_read_once_per_contents(tmp_path: Path, monkeypatch) -> None:
    cams = {"cam": {"projection_type": "perspective", "width": 200, "height": 100, "focal": 0.5}}
    (tmp_path / "cameras.json").write_text(json.dumps(cams))

    def shots(x0: float) -> str:
        props = [
            {"filename": f"{n}.JPG", "focal": 0.5, "width": 200, "height": 100,
             "translation": [x0 + i, 0.0, 100.0], "rotation": [math.pi, 0.0, 0.0]}
            for i, n in enumerate(NAMES)
        ]  # fmt: skip
        features = [{"type": "Feature", "properties": p, "geometry": None} for p in props]
        return json.dumps({"type": "FeatureCollection", "features": features})

    path = tmp_path / "odm_report" / "shots.geojson"
    path.parent.mkdir()
    path.write_text(shots(10.0))
    calls = counted(monkeypatch, opensfm, "_shots")
    centres = [read_camera(path, n).center for n in NAMES]
    assert len(calls) == 1
    np.testing.assert_array_equal(centres, [[10.0 + i, 0, 100] for i in range(3)])
    path.write_text(shots(20.0))
    assert read_camera(path, "a").center[0] == 20.0 and len(calls) == 2
    cams["cam"]["focal"] = 0.25  # another cameras.json: read again (no camera of focal 0.5)
    (tmp_path / "cameras.json").write_text(json.dumps(cams))
    with pytest.raises(ValueError, match="no camera of"):
        read_camera(path, "a")
    assert len(calls) == 3


def rpc_file(line_off: float) -> str:
    """Orthority RPC YAML of NAMES: image i has line offset line_off + i."""
    values = {
        "line_off": line_off, "samp_off": 60.0, "lat_off": -33.0, "long_off": 24.0,
        "height_off": 100.0, "line_scale": 50.0, "samp_scale": 60.0, "lat_scale": 0.01,
        "long_scale": 0.01, "height_scale": 100.0,
        "line_num_coeff": [0.0, 0.0, -1.0] + [0.0] * 17, "line_den_coeff": [1.0] + [0.0] * 19,
        "samp_num_coeff": [0.0, 1.0] + [0.0] * 18, "samp_den_coeff": [1.0] + [0.0] * 19,
    }  # fmt: skip
    entries = {
        f"{n}.tif": {"im_size": [120, 100], "rpc": values | {"line_off": line_off + i}}
        for i, n in enumerate(NAMES)
    }
    return yaml.safe_dump(entries)


def test_orthority_rpc_yaml_read_once_per_contents(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "rpc_param.yaml"
    path.write_text(rpc_file(50.0))
    calls = counted(monkeypatch, yaml, "safe_load")
    offsets = [read_camera(path, f"{n}.tif").rpc.line_off for n in NAMES]
    assert offsets == [50.0, 51.0, 52.0] and len(calls) == 1
    path.write_text(rpc_file(70.0))
    assert read_camera(path, "b").rpc.line_off == 71.0 and len(calls) == 2
