"""Heights taken for radii and the reverse, in the engine (ortho, visibility, fit, info and the
API's plans): named as that mix-up before the cameras are judged against the DEM, as
``Terrain.read`` names it, not as a camera below the surface or beyond the horizon."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rasterio

import orthomvp as om
from orthomvp.cli import main
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from tests.conftest import shared

RADII = "are they radii from its centre (--radius-values)?"
HEIGHTS = "are they heights above it?"


def _radii(dem: Path, out: Path) -> Path:
    """``dem``'s heights written as radii from the body centre (height + equatorial radius)."""
    radius = Terrain.read(dem).radii[0]
    with rasterio.open(dem) as src:
        profile, heights = src.profile, src.read(1).astype(np.float64)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write((heights + radius).astype(profile["dtype"]), 1)
    return out


def test_heights_and_radii_mixed_up_on_the_synthetic_crater(
    crater_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    dem, image, camera = (
        crater_dir / "dem.tif",
        crater_dir / "oblique.tif",
        crater_dir / "oblique.tsai",
    )
    radii = _radii(dem, tmp_path / "radii.tif")
    out = tmp_path / "o.tif"
    cases = (
        (["ortho", str(radii)], RADII),
        (["visibility", str(radii)], RADII),
        (["ortho", str(dem), "--radius-values"], HEIGHTS),
        (["info", str(radii)], RADII),
    )
    for (command, path, *options), words in cases:
        outputs = [] if command == "info" else ["-o", str(out)]
        assert main([command, path, str(image), str(camera), *outputs, *options]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("orthomvp: error:"), err
        assert words in err[0] and path in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["radii.tif"]
    # the viewer's clicks read the DEM for the cameras as the engine does
    monkeypatch.setattr("orthomvp.cli.view._serve", lambda *args: pytest.fail("served"))
    nadir = [str(crater_dir / "nadir.tif"), str(crater_dir / "nadir.tsai")]
    assert main(["view", str(radii), str(image), str(camera), *nadir, "--port", "0"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and RADII in err[0], err
    with pytest.raises(InputError, match=re.escape(RADII)):
        om.plan_ortho(radii, [(image, camera)], progress=False)
    with pytest.raises(InputError, match=re.escape(HEIGHTS)):
        om.plan_ortho(dem, [(image, camera)], radius_values=True, progress=False)
    # the convention as given is right: radii with --radius-values, heights without
    assert (
        main(["ortho", str(radii), str(image), str(camera), "-o", str(out), "--radius-values"]) == 0
    )
    with rasterio.open(out) as a:
        assert np.isfinite(a.read(1)).mean() > 0.5


@pytest.mark.realdata
def test_lunar_radii_read_as_heights_are_named_as_such(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The audit's case: LOLA's heights as radii, read as heights, were "camera 1 is beyond
    the DEM's horizon"; the heights read as radii were "the camera is below the surface"."""
    dem = shared("as15-hadley", "LOLA_hadley_dem.tif")
    cube = str(shared("as15-hadley", "AS15-M-1134-hadley.cub"))
    radii = _radii(dem, tmp_path / "lola-radius.tif")
    out = str(tmp_path / "rr.tif")
    for path, options, words in ((radii, [], RADII), (dem, ["--radius-values"], HEIGHTS)):
        assert main(["ortho", str(path), cube, "-o", out, *options]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and words in err[0], err
    assert not Path(out).exists()


def test_mesh_and_info_name_the_mix_up_on_every_path(
    crater_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The audit's cases: `mesh radii.tif -o x.ply` (streamed) wrote vertices at twice the
    body's radius, `mesh heights.tif --radius-values -o x.ply` a mesh near the centre, and `info
    heights.tif --radius-values` printed radii of -1,162 m; each is now the one-line mix-up
    error, and the convention as given right puts every vertex at radius + height."""
    import trimesh

    dem = crater_dir / "dem.tif"
    radii = _radii(dem, tmp_path / "radii.tif")
    out = tmp_path / "x.ply"
    cases = (
        (["mesh", str(radii), "-o", str(out)], RADII),
        (["mesh", str(dem), "--radius-values", "-o", str(out)], HEIGHTS),
        (["mesh", str(radii), "-o", str(tmp_path / "x.glb")], RADII),
        (["mesh", str(dem), "--error-against", str(radii), "-o", str(out)], RADII),
        (["info", str(dem), "--radius-values"], HEIGHTS),
        (["info", str(radii)], RADII),
    )
    for args, words in cases:
        assert main(args) == 2, args
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("orthomvp: error:") and words in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["radii.tif"]
    terrain = Terrain.read(dem)
    radius = terrain.radii[0]
    assert terrain.radii[0] == terrain.radii[1]  # a sphere: |vertex| = radius + height
    heights = np.sort(terrain.values[np.isfinite(terrain.values)].ravel())
    for path, options in ((dem, []), (radii, ["--radius-values"])):
        ply = tmp_path / f"{path.stem}.ply"
        assert main(["-q", "mesh", str(path), *options, "-o", str(ply)]) == 0
        vertices = trimesh.load(ply, process=False).vertices
        got = np.sort(np.linalg.norm(vertices, axis=1)) - radius
        assert len(got) == len(heights)
        assert np.abs(got - heights).max() < 0.2  # radii as float32 near 1,737 km: 0.125 m steps
