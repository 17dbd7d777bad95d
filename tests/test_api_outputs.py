"""The API's writers of single files refuse what the engine's outputs refuse (found by a new
user's audit: they replaced any file, the DEM they were read from included): a file that
exists unless ``overwrite=True``, values of another shape, another file type; nothing is
written then."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.present.export import export_mesh


@pytest.fixture()
def dem() -> Terrain:
    r, c = np.mgrid[0:16, 0:20]
    values = 50.0 * np.sin(r / 5.0) + 3.0 * c
    return Terrain(values, Affine(10.0, 0, 500000.0, 0, -10.0, 4000000.0), "EPSG:32633")


def test_terrain_write_refuses_an_existing_file_unless_told(dem: Terrain, tmp_path: Path) -> None:
    path = tmp_path / "dem.tif"
    dem.write(path)
    before = path.read_bytes()
    with pytest.raises(InputError, match=r"dem.tif: the output file of Terrain.write exists; "
                       r"give overwrite=True"):  # fmt: skip
        dem.write(path, dem.values + 1.0)
    assert path.read_bytes() == before
    dem.write(path, dem.values + 1.0, overwrite=True)
    with rasterio.open(path) as ds:
        assert np.array_equal(ds.read(1), (dem.values + 1.0).astype(np.float32))
        assert ds.transform == dem.transform
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.tif"]  # (no temporary left)


@pytest.mark.parametrize(
    ("name", "values", "words"),
    [
        ("small.tif", np.zeros((3, 3)), "must have the DEM's shape (16, 20)"),
        ("dem.ply", None, "name it .tif or .tiff"),
    ],
)
def test_terrain_write_refuses_other_shapes_and_types(
    dem: Terrain, tmp_path: Path, name: str, values: np.ndarray | None, words: str
) -> None:
    with pytest.raises(InputError) as caught:
        dem.write(tmp_path / name, values)
    assert words in str(caught.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".ply", ".glb", ".obj"])
def test_export_mesh_refuses_an_existing_file_unless_told(
    dem: Terrain, tmp_path: Path, suffix: str
) -> None:
    mesh = terrain_mesh(dem)
    texture = np.broadcast_to(np.linspace(0, 1, 20), (1, 16, 20))
    path = tmp_path / f"m{suffix}"
    export_mesh(mesh, path, texture)
    written = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(InputError, match="exists; give overwrite=True"):
        export_mesh(mesh, path, texture)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == written
    export_mesh(mesh, path, texture, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(written)


def test_an_obj_does_not_replace_a_material_or_image_beside_it(
    dem: Terrain, tmp_path: Path
) -> None:
    mesh = terrain_mesh(dem)
    texture = np.broadcast_to(np.linspace(0, 1, 20), (1, 16, 20))
    export_mesh(mesh, tmp_path / "first.obj", texture)
    (tmp_path / "first.obj").rename(tmp_path / "kept.obj")  # its .mtl and .png stay
    beside = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(InputError, match=r"first\.(mtl|png): the output file"):
        export_mesh(mesh, tmp_path / "first.obj", texture)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == beside


def test_tables_and_figures_refuse_existing_files_unless_told(tmp_path: Path) -> None:
    """check's and eps_study's ``save`` (through ``save_with_table``) replaced any file: both
    files are refused when either exists, and nothing is written then."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from orthomvp.present.figures import save_with_table

    table, figure = tmp_path / "t.csv", tmp_path / "t.png"
    rows = [{"eps": 1.0, "n": 3}]
    save_with_table(plt.figure(), figure, rows, ["eps", "n"], table)
    assert table.read_text() == "eps,n\n1,3\n"
    table.write_text("mine")
    figure.unlink()
    with pytest.raises(InputError, match=r"t\.csv: the output file of table exists"):
        save_with_table(plt.figure(), figure, rows, ["eps", "n"], table)
    assert table.read_text() == "mine" and not figure.exists()
    save_with_table(plt.figure(), figure, rows, ["eps", "n"], table, overwrite=True)
    assert table.read_text() == "eps,n\n1,3\n" and figure.stat().st_size > 100
    assert plt.get_fignums() == []  # (every figure closed, refused or written)
