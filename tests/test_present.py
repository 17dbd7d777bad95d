"""The shared colour rules of export and snapshots, the lazily built trimesh view, and the soft
imports: the core never loads the heavy libraries, and a missing one fails with what to install."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from pyproj import CRS

from orthomvp.codes import CODE_RGB, Code, Interp
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion import embree
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.occlusion.raycast import RayCaster
from orthomvp.ortho.orthophoto import orthorectify, sample_image
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

HEAVY = ("trimesh", "scipy.spatial", "open3d", "pyvista")
MOON = CRS.from_proj4("+proj=longlat +R=1737400 +no_defs")


def plain_terrain(rows: int = 6, cols: int = 7) -> Terrain:
    values = np.random.default_rng(0).uniform(-20, 20, (rows, cols))
    step = np.degrees(30.0 / 1737400)
    return Terrain(values, Affine(step, 0, 10.0, 0, -step, 5.0), MOON)


def test_core_modules_import_no_heavy_library() -> None:
    code = (
        "import sys; import orthomvp.ortho.orthophoto, orthomvp.occlusion.visibility, "
        "orthomvp.occlusion.raycast; "
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


ORTHO_PATH_SPARE = (
    *HEAVY,
    *("scipy", "embreex", "orthomvp.mvp", "orthomvp.engine.fit"),
    *("orthomvp.camera.csm", "orthomvp.io.isis", "pvl", "yaml", "tqdm", "multiprocessing"),
)
"""What a quiet orthophoto or mosaic run from ``.tsai`` cameras never loads: the heavy
libraries, scipy at all, embreex's Python modules (only its Embree library), the MVP fit, the
other camera formats' models and parsers, the progress bar, and process pools."""


@pytest.mark.parametrize("command", ["ortho", "mosaic"])
def test_orthophoto_run_loads_no_heavy_module(
    crater_dir: Path, tmp_path: Path, command: str
) -> None:
    """The whole `orthomvp ortho` (or `mosaic` of two views) command, occlusion on, in a
    fresh process."""
    d = crater_dir
    views = ("oblique", "nadir") if command == "mosaic" else ("oblique",)
    args = [str(d / "dem.tif"), *(str(d / f"{v}.{e}") for v in views for e in ("tif", "tsai"))]
    out_path = str(tmp_path / "o.tif")
    code = (
        "import sys; from orthomvp.cli import main; "
        f"assert main(['--quiet', {command!r}, *{args!r}, '-o', {out_path!r}]) == 0; "
        f"print([m for m in {ORTHO_PATH_SPARE!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "o.tif").exists()


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
    "embreex": lambda tm, tmp: RayCaster(tm),
    "pyvista": lambda tm, tmp: snapshot(plain_terrain()),
}
"""A feature that needs each optional module."""


@pytest.mark.parametrize("module", list(USES))
def test_missing_library_fails_when_used_naming_the_package(
    module: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    tm = terrain_mesh(plain_terrain())
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    monkeypatch.setattr(embree, "_state", {})  # the Embree library not loaded yet
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


NO_LIBUSB = """
import importlib.abc, sys
class NoLibusb(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] == "open3d":  # as on Debian without libusb-1.0-0
            raise OSError("libusb-1.0.so.0: cannot open shared object file: No such file")
sys.meta_path.insert(0, NoLibusb())
"""


@pytest.mark.slow
def test_without_libusb_only_decimation_and_the_open3d_backend_fail(
    crater_dir: Path, tmp_path: Path
) -> None:
    """Open3D fails to import without the system library libusb-1.0 (an OSError): every module
    still imports and every command works, except mesh decimation and the Open3D ray-casting
    backend, which say what to install; the benchmark reports the backend as unavailable."""
    d = crater_dir
    dem, views = (
        d / "dem.tif",
        [d / "oblique.tif", d / "oblique.tsai", d / "nadir.tif", d / "nadir.tsai"],
    )
    commands = {
        "visibility": ["visibility", dem, *views[:2], "-o", tmp_path / "v.tif"],
        "ortho": ["ortho", dem, *views[:2], "-o", tmp_path / "o.tif", "--grid", "dem"],
        "mosaic": ["mosaic", dem, *views, "-o", tmp_path / "m.tif"],
        "fit": ["fit", dem, *views, "-o", tmp_path / "f.tif", "--hwin", "3", "--levels", "1"],
        "mesh": ["mesh", dem, "-o", tmp_path / "m.ply", "--texture", tmp_path / "o.tif"],
        "render": ["render", dem, "-o", tmp_path / "r.png", "--size", "64", "48"],
        "bench": [
            "bench",
            *("--size", "20", "--rays", "100", "--ortho-size", "0", "--mvp-size", "0"),
            *("--linescan-size", "0"),
        ],
        "decimate": ["mesh", dem, "-o", tmp_path / "d.ply", "--decimate", "100"],
    }
    script = NO_LIBUSB + (
        "import json, pkgutil, importlib, io, contextlib\n"
        "import orthomvp\n"
        "for m in pkgutil.walk_packages(orthomvp.__path__, 'orthomvp.'):\n"
        "    if m.name != 'orthomvp.__main__':\n"
        "        importlib.import_module(m.name)\n"
        "from orthomvp.cli import main\n"
        "results = {}\n"
        f"for name, args in { ({k: [str(a) for a in v] for k, v in commands.items()})!r}.items():\n"
        "    out, err = io.StringIO(), io.StringIO()\n"
        "    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):\n"
        "        results[name] = [main(['-q', *args]), out.getvalue(), err.getvalue()]\n"
        "from orthomvp.errors import InputError\n"
        "from orthomvp.occlusion.mesh import terrain_mesh\n"
        "from orthomvp.occlusion.raycast import RayCaster\n"
        "from orthomvp.geometry.terrain import Terrain\n"
        f"tm = terrain_mesh(Terrain.read({str(dem)!r}))\n"
        "try:\n"
        "    RayCaster(tm, 'open3d')\n"
        "except InputError as exc:\n"
        "    results['open3d backend'] = [2, '', str(exc)]\n"
        "RayCaster(tm)\n"
        "print(json.dumps(results))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    results = json.loads(proc.stdout)
    for name in ("visibility", "ortho", "mosaic", "fit", "mesh", "render", "bench"):
        assert results[name][0] == 0, (name, results[name][2])
    assert "open3d   not available" in results["bench"][1] and "embree" in results["bench"][1]
    for name in ("decimate", "open3d backend"):
        status, _, err = results[name]
        assert status == 2 and "libusb-1.0.so.0" in err and "apt-get install libusb-1.0-0" in err
    assert not (tmp_path / "d.ply").exists()


def test_figures_keep_their_legend_and_show_a_scale(monkeypatch: pytest.MonkeyPatch) -> None:
    """The overview's legend keeps all its rows inside the figure, and every 2D map carries a
    scale bar in metres or km."""
    from matplotlib.offsetbox import AnchoredOffsetbox

    from orthomvp.present import figures

    saved = []
    monkeypatch.setattr(figures, "_save", lambda fig, path: saved.append(fig))
    rng = np.random.default_rng(0)
    dem = rng.normal(size=(60, 60)).cumsum(0)
    codes = np.ones((60, 60), np.uint8)
    codes[20:30, 20:40], codes[40:50, 10:20] = Code.OCCLUDED, Code.FACING_AWAY
    figures.scene_overview(dem, 50.0, rng.random((70, 65)), codes, "o.png", gsd=40.0)
    maps = rng.random((3, 60, 60))
    figures.ortho_comparison(*maps, "c.png", spacing=50.0)
    figures.height_error_maps(maps[0] - 0.5, maps[1] - 0.5, 50.0, "e.png")
    overview, comparison, errors = saved
    overview.canvas.draw()  # lay the figure out as saving does
    renderer = overview.canvas.get_renderer()
    (legend,) = overview.legends
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["visible", "occluded", "facing away"]
    box = overview.bbox
    for text in legend.get_texts():
        extent = text.get_window_extent(renderer)
        assert box.x0 <= extent.x0 and extent.x1 <= box.x1 and box.y0 <= extent.y0, text
    for fig, n in ((overview, 3), (comparison, 3), (errors, 2)):
        bars = [a for ax in fig.axes for a in ax.artists if isinstance(a, AnchoredOffsetbox)]
        assert len(bars) == n, fig
        for bar in bars:
            label = bar.get_child().get_children()[1].get_children()[0].get_text()
            assert re.fullmatch(r"\d+ (m|km)( \(at the centre\))?", label), label


def _rotated_lonlat(theta_deg: float, k: float = 0.001):  # noqa: ANN202
    """A map grid turned ``theta`` degrees: lon = 3 + k (c cos t + r sin t), lat = 26 +
    k (c sin t - r cos t) degrees, whose north is the pixel direction (sin t, -cos t)."""
    t = np.radians(theta_deg)

    def lonlat(c: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, r = np.asarray(c, np.float64), np.asarray(r, np.float64)
        return 3 + k * (c * np.cos(t) + r * np.sin(t)), 26 + k * (c * np.sin(t) - r * np.cos(t))

    return lonlat, np.array([np.sin(t), -np.cos(t)])


def _north_arrow(ax) -> np.ndarray:  # noqa: ANN001
    """The unit (c, r) direction of the axes' north arrow (tail to tip)."""
    from matplotlib.text import Annotation

    (arrow,) = [t for t in ax.texts if isinstance(t, Annotation)]
    d = np.subtract(arrow.xy, arrow.xyann)
    return d / np.linalg.norm(d)


def _ticks(axis) -> tuple:  # noqa: ANN001
    """An axis's tick positions and labels."""
    return axis.get_ticklocs(), axis.get_ticklabels()


def _degrees_of(label: str) -> float:
    value, hemisphere = re.fullmatch(r"([\d.]+)\u00b0([NSEW])", label).groups()
    return float(value) * (-1 if hemisphere in "SW" else 1)


@pytest.mark.parametrize("theta", [0.0, 30.0])
def test_maps_have_lonlat_ticks_a_north_arrow_and_colour_bars_in_metres(
    monkeypatch: pytest.MonkeyPatch, theta: float
) -> None:
    """Every map of the three demo figures has longitude ticks on its bottom edge and latitude
    ticks on its left edge where those values cross the edge (the grid's own formula inverted),
    a north arrow along the meridian, and every colour bar is labelled in metres."""
    from orthomvp.present import figures

    saved = []
    monkeypatch.setattr(figures, "_save", lambda fig, path: saved.append(fig))
    lonlat, north = _rotated_lonlat(theta)
    rng = np.random.default_rng(0)
    rows = cols = 60
    dem = rng.normal(size=(rows, cols)).cumsum(0)
    codes = np.ones((rows, cols), np.uint8)
    codes[20:30, 20:40] = Code.OCCLUDED
    maps = rng.random((3, rows, cols))
    maps[1][codes == Code.OCCLUDED] = np.nan
    figures.scene_overview(dem, 50.0, rng.random((70, 65)), codes, "o.png", lonlat=lonlat)
    figures.ortho_comparison(*maps, "c.png", spacing=50.0, codes=codes, lonlat=lonlat)
    figures.height_error_maps(maps[0] - 0.5, maps[1] - 0.5, 50.0, "e.png", lonlat=lonlat)
    overview, comparison, errors = saved
    t = np.radians(theta)
    map_axes = [overview.axes[0], overview.axes[2], *comparison.axes[:3], *errors.axes[:2]]
    for ax in map_axes:
        xticks = [(p, _degrees_of(lb.get_text())) for p, lb in zip(*_ticks(ax.xaxis), strict=True)]
        yticks = [(p, _degrees_of(lb.get_text())) for p, lb in zip(*_ticks(ax.yaxis), strict=True)]
        assert len(xticks) >= 2 and len(yticks) >= 2
        r_bottom, c_left = rows - 0.5, -0.5
        for c, lon in xticks:  # lon = 3 + k (c cos t + r sin t) on the bottom edge
            assert -0.5 <= c <= cols - 0.5
            expect = ((lon - 3) / 0.001 - r_bottom * np.sin(t)) / np.cos(t)
            assert c == pytest.approx(expect, abs=0.02)
        for r, lat in yticks:  # lat = 26 + k (c sin t - r cos t) on the left edge
            expect = (c_left * np.sin(t) - (lat - 26) / 0.001) / np.cos(t)
            assert r == pytest.approx(expect, abs=0.02)
        np.testing.assert_allclose(_north_arrow(ax), north, atol=1e-9)
    assert not overview.axes[1].get_xticks().size  # the raw frame is no map
    bars = [ax for fig in saved for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 2
    for bar in bars:
        assert "(m)" in bar.get_ylabel(), bar.get_ylabel()
    # the empty posts of the occlusion-aware orthophoto are named by why they are empty
    (legend,) = comparison.legends
    assert [t.get_text() for t in legend.get_texts()] == ["empty: occluded"]


def test_one_colour_per_meaning() -> None:
    """Occluded and no-data posts are far (in RGB, 0-255) from every colour the height-error
    map gives an error beyond an eighth of its range (too high red, too low blue), cameras are
    drawn in none of the code colours, and the no-value colour is the no-data code's."""
    from matplotlib import colormaps

    from orthomvp.present.colours import CAMERA_COLOURS, ERROR_CMAP

    x = np.concatenate([np.linspace(0, 0.375, 64), np.linspace(0.625, 1, 64)])
    error_rgb = colormaps[ERROR_CMAP](x)[:, :3] * 255
    for code in (Code.OCCLUDED, Code.NODATA):
        nearest = np.linalg.norm(error_rgb - np.array(code.rgb), axis=1).min()
        assert nearest > 75, (code, nearest)
    assert tuple(NAN_RGB) == Code.NODATA.rgb
    codes = np.array([c.rgb for c in Code], float)
    for colour in CAMERA_COLOURS:
        rgb = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)])
        assert np.linalg.norm(codes - rgb, axis=1).min() > 60, colour
