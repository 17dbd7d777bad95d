"""The streamed PLY of a DEM (orthomvp.present.mesh_stream) is byte for byte the file that the
in-memory mesh and its PLY writer make, also with holes in the DEM and blocks of a few rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

import orthomvp.present.mesh_stream as mesh_stream
from orthomvp.engine.grid import scan_dem
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.present.colours import height_error
from orthomvp.present.export import export_mesh
from orthomvp.present.texture import TextureSampler


def _holey(crater_dir: Path, tmp_path: Path) -> Path:
    """The crater DEM with holes (a block, a row, scattered posts) and a gap at one corner."""
    with rasterio.open(crater_dir / "dem.tif") as src:
        profile, values = src.profile, src.read(1).astype(np.float32)
    values[10:14, 20:30] = np.nan
    values[40, :] = np.nan
    values[np.random.default_rng(1).random(values.shape) < 0.01] = np.nan
    values[:3, :5] = np.nan
    profile.update(dtype="float32", nodata=np.nan)
    path = tmp_path / "holey.tif"
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(values, 1)
    return path


def _finer(path: Path, tmp_path: Path) -> Path:
    """``path`` at twice its resolution, shifted by a third of a new pixel, with noise: a
    texture off the DEM grid."""
    with rasterio.open(path) as src:
        profile, values = src.profile, src.read(1).astype(np.float32)
    fine = np.kron(values, np.ones((2, 2), np.float32))
    fine += np.random.default_rng(2).normal(0, 0.01, fine.shape).astype(np.float32)
    t = profile["transform"]
    profile.update(
        dtype="float32",
        width=fine.shape[1],
        height=fine.shape[0],
        transform=t @ rasterio.Affine.scale(0.5) @ rasterio.Affine.translation(1 / 3, 1 / 3),
    )
    out = tmp_path / "finer.tif"
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(fine, 1)
    return out


@pytest.mark.parametrize("local", [False, True])
@pytest.mark.parametrize("colour", ["none", "image", "finer", "visibility", "error"])
def test_streamed_ply_equals_the_in_memory_file(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, local: bool, colour: str
) -> None:
    monkeypatch.setattr(mesh_stream, "BLOCK_POSTS", 64 * 7)  # 7 rows a block: many blocks
    dem = _holey(crater_dir, tmp_path)
    source = scan_dem(dem)
    terrain = Terrain.read(dem)
    texture, colours, kind = None, None, "image"
    grid = (source.shape, source.transform, source.crs)
    if colour == "image":
        path = crater_dir / "truth_radiance.tif"
        colours = mesh_stream.image_stretch(TextureSampler(path, *grid))
        texture = read_image(path)
    elif colour == "finer":  # a texture off the DEM grid, sampled at the posts in both paths
        path = _finer(crater_dir / "truth_radiance.tif", tmp_path)
        colours = mesh_stream.image_stretch(TextureSampler(path, *grid))
        texture = TextureSampler(path, terrain.shape, terrain.transform, terrain.crs).grid()
    elif colour == "visibility":
        path = crater_dir / "oblique.visibility.tif"
        colours = mesh_stream.code_colours(TextureSampler(path, *grid))
        texture, kind = read_image(path), "visibility"
    elif colour == "error":
        truth = crater_dir / "dem.tif"
        colours, limit = mesh_stream.error_against(scan_dem(truth), source, None)
        texture, kind = height_error(terrain, Terrain.read(truth)), "error"
    n_vert, n_face, origin = mesh_stream.write_ply_stream(
        source, tmp_path / "a.ply", colours=colours, local=local
    )
    tmesh = terrain_mesh(terrain)
    export_mesh(tmesh, tmp_path / "b.ply", texture=texture, local=local, colour_kind=kind)
    assert (n_vert, n_face) == (len(tmesh.vertices), len(tmesh.faces))
    np.testing.assert_array_equal(origin, tmesh.origin)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


def test_the_mesh_command_streams_plys(crater_dir: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """`orthomvp mesh -o X.ply` never builds the whole mesh in memory."""
    import orthomvp.occlusion.mesh
    from orthomvp.cli import cli

    def refuse(*a: object, **k: object) -> None:
        raise AssertionError("the whole mesh was built")

    monkeypatch.setattr(orthomvp.occlusion.mesh, "terrain_mesh", refuse)
    out = tmp_path / "m.ply"
    from click.testing import CliRunner

    result = CliRunner().invoke(cli, ["mesh", str(crater_dir / "dem.tif"), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "4,096 vertices, 7,938 triangles" in result.output
    assert out.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")


def test_origin_past_a_hole_at_the_centre(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A hole at the grid centre wider than the windows searched about it: the origin (and so
    the local vertices) comes from the pass over blocks of rows, still the in-memory one."""
    monkeypatch.setattr(mesh_stream, "BLOCK_POSTS", 64 * 7)  # windows up to 18 x 18 posts
    dem = _holey(crater_dir, tmp_path)
    with rasterio.open(dem, "r+") as dst:
        values = dst.read(1)
        values[18:46, 18:46] = np.nan
        dst.write(values, 1)
    source = scan_dem(dem)
    _, _, origin = mesh_stream.write_ply_stream(source, tmp_path / "a.ply", local=True)
    tmesh = terrain_mesh(Terrain.read(dem))
    export_mesh(tmesh, tmp_path / "b.ply", local=True)
    np.testing.assert_array_equal(origin, tmesh.origin)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
