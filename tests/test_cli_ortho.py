"""The visibility, ortho, mosaic and eps-study commands, and their handling of bad input (run in
this process, see tests/test_cli.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.io.raster import read_image
from orthomvp.synthetic import away_from_boundaries
from tests.test_cli import assert_one_line_error, run


@pytest.mark.slow
def test_ortho_visibility_and_naive(crater_dir: Path, tmp_path: Path) -> None:
    d = crater_dir
    out, vis = tmp_path / "ortho.tif", tmp_path / "vis.tif"
    proc = run(
        "ortho",
        str(d / "dem.tif"),
        str(d / "oblique.tif"),
        str(d / "oblique.tsai"),
        "-o",
        str(out),
        "--visibility",
        str(vis),
        "--grid",
        "dem",
    )
    assert proc.returncode == 0, proc.stderr
    naive = tmp_path / "naive.tif"
    proc = run(
        "ortho",
        str(d / "dem.tif"),
        str(d / "oblique.tif"),
        str(d / "oblique.tsai"),
        "-o",
        str(naive),
        "--no-occlusion",
        "--grid",
        "dem",
        "--interp",
        "cubic",
    )
    assert proc.returncode == 0, proc.stderr
    truth = read_image(d / "oblique.visibility.tif")[0]
    hidden = (truth >= 2) & away_from_boundaries(truth)
    o, n = read_image(out)[0], read_image(naive)[0]
    assert not np.isfinite(o[hidden]).any() and np.isfinite(n[hidden]).all()
    with rasterio.open(out) as a, rasterio.open(d / "dem.tif") as b:
        assert a.transform == b.transform and a.crs == b.crs and a.dtypes[0] == "float32"
    codes = read_image(vis)[0]
    assert set(np.unique(codes[np.isfinite(codes)])) <= {1, 2, 3}
    # a coarser output grid on request
    coarse = tmp_path / "coarse.tif"
    with rasterio.open(d / "dem.tif") as b:
        res_x, res_y = abs(b.transform.a) * 2, abs(b.transform.e) * 2
    proc = run(
        "ortho",
        str(d / "dem.tif"),
        str(d / "oblique.tif"),
        str(d / "oblique.tsai"),
        "-o",
        str(coarse),
        "--res",
        str(res_x),
        str(res_y),
        "--grid",
        "dem",
    )
    assert proc.returncode == 0, proc.stderr
    assert read_image(coarse).shape == (1, 32, 32)


@pytest.mark.slow
def test_visibility_and_mosaic_commands(crater_dir: Path, tmp_path: Path) -> None:
    d = crater_dir
    proc = run(
        "visibility",
        str(d / "dem.tif"),
        str(d / "oblique.tif"),
        str(d / "oblique.tsai"),
        "-o",
        str(tmp_path / "v.tif"),
        "--eps",
        "2",
        "--grid",
        "dem",
    )
    assert proc.returncode == 0, proc.stderr
    assert "occluded" in proc.stdout
    proc = run(
        "mosaic",
        str(d / "dem.tif"),
        str(d / "oblique.tif"),
        str(d / "oblique.tsai"),
        str(d / "nadir.tif"),
        str(d / "nadir.tsai"),
        "-o",
        str(tmp_path / "m.tif"),
        "--source",
        str(tmp_path / "s.tif"),
        "--grid",
        "dem",
    )
    assert proc.returncode == 0, proc.stderr
    m = read_image(tmp_path / "m.tif")[0]
    with rasterio.open(tmp_path / "s.tif") as src:
        source = src.read(1)
    assert np.isfinite(m).all() and set(np.unique(source)) == {1, 2}
    assert_one_line_error(
        run("mosaic", str(d / "dem.tif"), str(d / "oblique.tif"), "-o", str(tmp_path / "x.tif")),
        "pairs",
    )


@pytest.mark.slow
def test_eps_study_command(crater_dir: Path, tmp_path: Path) -> None:
    prefix = tmp_path / "study_eps0.5"  # the suffixes go after the whole prefix
    proc = run("eps-study", str(crater_dir), "-o", str(prefix), "--eps", "0.5", "4", "40")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study_eps0.5.csv", "study_eps0.5.png"]
    lines = (tmp_path / "study_eps0.5.csv").read_text().splitlines()
    assert lines[0].startswith("noise_m,view,eps") and len(lines) == 1 + 4 * 4
    assert (tmp_path / "study_eps0.5.png").stat().st_size > 10_000
    assert_one_line_error(run("eps-study", str(tmp_path)), "scene.json")


@pytest.mark.slow
def test_bad_inputs_leave_nothing(crater_dir: Path, tmp_path: Path) -> None:
    d = crater_dir
    out = tmp_path / "o.tif"
    dem, img, cam = str(d / "dem.tif"), str(d / "oblique.tif"), str(d / "oblique.tsai")
    assert_one_line_error(
        run("ortho", dem, img, str(tmp_path / "nope.tsai"), "-o", str(out)), "nope.tsai"
    )
    bad_cam = tmp_path / "bad.tsai"
    bad_cam.write_text("VERSION_4\nPINHOLE\nfu = 12\nfv = x\n")
    assert_one_line_error(run("ortho", dem, img, str(bad_cam), "-o", str(out)), "bad.tsai")
    corrupt = tmp_path / "corrupt.tif"
    corrupt.write_bytes(b"II*\x00" + b"\x07" * 300)
    assert_one_line_error(run("ortho", dem, str(corrupt), cam, "-o", str(out)), "corrupt.tif")
    # an image of another size than the camera's scene: the camera no longer covers the DEM
    small = tmp_path / "small.tif"
    with rasterio.open(
        small, "w", driver="GTiff", width=10, height=10, count=2, dtype="uint16"
    ) as dst:
        dst.write(np.ones((2, 10, 10), np.uint16))
    assert_one_line_error(run("ortho", dem, str(small), cam, "-o", str(out)), "does not cover")
    # a camera far away from the DEM: no overlap
    text = (d / "oblique.tsai").read_text().splitlines()
    moved = [ln if not ln.startswith("C =") else "C = 0 0 -1900000" for ln in text]
    (tmp_path / "moved.tsai").write_text("\n".join(moved) + "\n")
    proc = run("ortho", dem, img, str(tmp_path / "moved.tsai"), "-o", str(out))
    assert_one_line_error(proc)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "bad.tsai",
        "corrupt.tif",
        "moved.tsai",
        "small.tif",
    ]


def test_partial_coverage_warns(crater_dir: Path, tmp_path: Path) -> None:
    d = crater_dir
    image = read_image(d / "nadir.tif")
    half = tmp_path / "half.tif"
    rows, cols = image.shape[1:]
    # the same camera, but the image cut to its left half: the camera keeps its geometry
    text = (d / "nadir.tsai").read_text()
    (tmp_path / "half.tsai").write_text(text)
    with rasterio.open(
        half, "w", driver="GTiff", width=cols // 2, height=rows, count=1, dtype="float32"
    ) as dst:
        dst.write(image[:, :, : cols // 2])
    out = tmp_path / "o.tif"
    half_cam = str(tmp_path / "half.tsai")
    proc = run("ortho", str(d / "dem.tif"), str(half), half_cam, "-o", str(out), "--grid", "dem")
    assert proc.returncode == 0, proc.stderr
    assert "warning" in proc.stderr and "covers" in proc.stderr
    o = read_image(out)[0]
    assert 0.2 < np.isfinite(o).mean() < 0.8
