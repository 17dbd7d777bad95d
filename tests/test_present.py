"""The shared colour rules of export and snapshots, the lazily built trimesh view, and the soft
imports: the core never loads the heavy libraries, and a missing one fails with what to install."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS

from orthomvp.codes import CODE_RGB, Code, Interp
from orthomvp.errors import InputError
from orthomvp.mesh import terrain_mesh
from orthomvp.ortho import orthorectify, sample_image
from orthomvp.present.colours import (
    NAN_RGB,
    error_colours,
    image_colours,
    post_colours,
    raster_bands,
    visibility_codes,
)
from orthomvp.present.export import export_mesh
from orthomvp.present.snapshot import snapshot
from orthomvp.raycast import RayCaster
from orthomvp.terrain import Terrain

HEAVY = ("trimesh", "scipy.spatial", "open3d", "pyvista")
MOON = CRS.from_proj4("+proj=longlat +R=1737400 +no_defs")


def plain_terrain(rows: int = 6, cols: int = 7) -> Terrain:
    values = np.random.default_rng(0).uniform(-20, 20, (rows, cols))
    step = np.degrees(30.0 / 1737400)
    return Terrain(values, Affine(step, 0, 10.0, 0, -step, 5.0), MOON)


def test_core_modules_import_no_heavy_library() -> None:
    code = (
        "import sys; import orthomvp.ortho, orthomvp.visibility, orthomvp.raycast; "
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_trimesh_view_is_built_once_from_the_arrays() -> None:
    tm = terrain_mesh(plain_terrain())
    assert tm.vertices.dtype == np.float64 and tm.faces.shape[1] == 3
    assert "mesh" not in vars(tm)  # not built by meshing
    m = tm.mesh
    assert tm.mesh is m
    np.testing.assert_array_equal(m.vertices, tm.vertices)
    np.testing.assert_array_equal(m.faces, tm.faces)


USES = {
    "trimesh": lambda tm, tmp: export_mesh(tm, tmp / "m.ply"),
    "open3d": lambda tm, tmp: RayCaster(tm, "open3d"),
    "embreex.rtcore_scene": lambda tm, tmp: RayCaster(tm),
    "pyvista": lambda tm, tmp: snapshot(plain_terrain()),
}
"""A feature that needs each optional module."""


@pytest.mark.parametrize("module", list(USES))
def test_missing_library_fails_when_used_naming_the_package(
    module: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    tm = terrain_mesh(plain_terrain())
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    package = module.partition(".")[0]
    with pytest.raises(InputError, match=f"pip install {package}"):
        USES[module](tm, tmp_path)
    assert not list(tmp_path.iterdir())


def test_one_nan_colour_for_every_kind() -> None:
    shape = (3, 4)
    grey = np.arange(12, dtype=np.float32).reshape(shape)
    grey[1, 2] = np.nan
    rgb = np.stack([grey, grey * 2, grey + 1])
    error = grey - 5.0
    nan = np.isnan(grey).ravel()
    for colours in (
        post_colours(grey, shape),
        post_colours(rgb, shape),
        post_colours(np.moveaxis(rgb, 0, -1), shape),  # bands last: the same
        post_colours(error, shape, "error", 3.0),
        image_colours(raster_bands(rgb, shape)),
        error_colours(error),
    ):
        assert colours.shape == (12, 3) and colours.dtype == np.uint8
        np.testing.assert_array_equal(colours[nan], [NAN_RGB])
        assert not (colours[~nan] == NAN_RGB).all(axis=1).any()


def test_image_stretch_and_uint8() -> None:
    shape = (10, 10)
    ramp = np.linspace(-1.0, 1.0, 100).reshape(shape)
    grey = image_colours(raster_bands(ramp, shape))[:, 0].astype(float)
    lo, hi = np.percentile(ramp, [1, 99])
    np.testing.assert_allclose(grey, np.floor(np.clip((ramp.ravel() - lo) / (hi - lo), 0, 1) * 255))
    photo = np.random.default_rng(1).integers(0, 256, (3, *shape), dtype=np.uint8)
    np.testing.assert_array_equal(post_colours(photo, shape), photo.reshape(3, -1).T)
    with pytest.raises(InputError, match="not 2"):
        post_colours(photo[:2], shape)


def test_visibility_colours_are_the_code_table() -> None:
    codes = np.array([[0, 1], [2, 3]], np.float32)
    codes[0, 0] = np.nan  # no data
    np.testing.assert_array_equal(visibility_codes(codes, (2, 2)), [[0, 1], [2, 3]])
    rgb = post_colours(codes, (2, 2), "visibility")
    np.testing.assert_array_equal(rgb, [c.rgb for c in Code])
    np.testing.assert_array_equal(rgb, CODE_RGB)
    with pytest.raises(InputError, match="codes"):
        visibility_codes(codes + 0.5, (2, 2))
    with pytest.raises(InputError, match="DEM grid"):
        visibility_codes(codes, (3, 2))


def test_interpolation_names_and_keyword_only_options() -> None:
    image = np.arange(20, dtype=np.float32).reshape(1, 4, 5)
    uv = np.array([[1.5, 2.0]])
    assert sample_image(image, uv, "bilinear")[0, 0] == 11.5
    assert sample_image(image, uv, Interp.NEAREST)[0, 0] in (11.0, 12.0)
    with pytest.raises(InputError, match="nearest, bilinear, cubic"):
        sample_image(image, uv, "linear")
    with pytest.raises(TypeError):
        orthorectify(plain_terrain(), image, None, False)  # options are keyword-only
