"""The command line's outputs and voice: an existing output is refused unless --overwrite, an
input replaced only with --overwrite --replace-input; every informational line starts
``orthomvp:``, -q prints nothing on success, ``progress=False`` in the API prints nothing;
--help names every camera kind; ``mesh`` samples textures of any resolution at the posts."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
import trimesh
from affine import Affine
from PIL import Image

import orthomvp.engine.progress
from orthomvp.codes import CODE_RGB
from orthomvp.geometry.terrain import Terrain
from orthomvp.occlusion.mesh import terrain_mesh
from orthomvp.present.colours import NAN_RGB
from tests.test_cli import Result, assert_one_line_error, run

SENTINEL = b"not written by orthomvp"


def _views(d: Path, *names: str) -> list[str]:
    return [str(d / f"{name}.{ext}") for name in names for ext in ("tif", "tsai")]


def _commands(d: Path, out: Path) -> dict[str, tuple[list[str], list[Path]]]:
    """Each file-writing command on the crater scene: its arguments and the files it writes
    (all in ``out``)."""
    dem = str(d / "dem.tif")
    return {
        "visibility": (
            ["visibility", dem, *_views(d, "nadir"), "-o", str(out / "v.tif")],
            [out / "v.tif"],
        ),
        "ortho": (["ortho", dem, *_views(d, "nadir"), "-o", str(out / "o.tif")], [out / "o.tif"]),
        "mosaic": (
            ["mosaic", dem, *_views(d, "nadir", "oblique"), "-o", str(out / "m.tif")],
            [out / "m.tif"],
        ),
        "fit": (
            ["fit", dem, *_views(d, "nadir", "fore"), "-o", str(out / "f.tif")],
            [out / "f.tif"],
        ),
        "mesh": (["mesh", dem, "-o", str(out / "x.ply")], [out / "x.ply"]),
        "render": (["render", dem, "-o", str(out / "r.png")], [out / "r.png"]),
        "check": (
            ["check", dem, *_views(d, "nadir", "oblique"), "-o", str(out / "c")],
            [out / "c.png"],
        ),
        "eps-study": (["eps-study", str(d), "-o", str(out / "e")], [out / "e.csv"]),
        "bench": (["bench", "--json", str(out / "b.json")], [out / "b.json"]),
    }


@pytest.mark.parametrize(
    "command",
    ["visibility", "ortho", "mosaic", "fit", "mesh", "render", "check", "eps-study", "bench"],
)
def test_an_existing_output_is_refused(crater_dir: Path, tmp_path: Path, command: str) -> None:
    args, written = _commands(crater_dir, tmp_path)[command]
    existing = written[-1]
    existing.write_bytes(SENTINEL)
    proc = run(*args)
    assert_one_line_error(proc, str(existing), "exists", "--overwrite")
    assert proc.stdout == ""
    assert existing.read_bytes() == SENTINEL
    assert sorted(tmp_path.iterdir()) == [existing]  # nothing else written


def test_an_obj_mesh_refuses_an_existing_texture_image(crater_dir: Path, tmp_path: Path) -> None:
    """The OBJ's texture image and material, written beside it, count as outputs too."""
    dem, texture = crater_dir / "dem.tif", crater_dir / "truth_radiance.tif"
    for name in ("m.png", "m.mtl"):
        (tmp_path / name).write_bytes(SENTINEL)
        proc = run("mesh", str(dem), "-o", str(tmp_path / "m.obj"), "--texture", str(texture))
        assert_one_line_error(proc, str(tmp_path / name), "exists", "--overwrite")
        assert sorted(p.name for p in tmp_path.iterdir()) == [name]
        (tmp_path / name).unlink()
    proc = run(
        "mesh", str(dem), "-o", str(tmp_path / "m.obj"), "--texture", str(tmp_path / "m.png")
    )
    assert_one_line_error(proc, "would replace the input --texture")


@pytest.mark.parametrize("command", ["ortho", "mesh", "check"])
def test_overwrite_replaces_an_existing_output(
    crater_dir: Path, tmp_path: Path, command: str
) -> None:
    args, written = _commands(crater_dir, tmp_path)[command]
    for path in written:
        path.write_bytes(SENTINEL)
    proc = run(*args, "--overwrite")
    assert proc.returncode == 0, proc.stderr
    for path in written:
        assert path.read_bytes() != SENTINEL and path.stat().st_size > 100
    if command == "ortho":  # a whole orthophoto on the image's grid, not the sentinel
        with rasterio.open(written[0]) as src:
            assert src.crs is not None and np.isfinite(src.read(1)).mean() > 0.5


def test_an_output_replaces_an_input_only_with_replace_input(
    crater_dir: Path, tmp_path: Path
) -> None:
    image = tmp_path / "nadir.tif"
    shutil.copy(crater_dir / "nadir.tif", image)
    before = image.read_bytes()
    args = ["ortho", str(crater_dir / "dem.tif"), str(image), str(crater_dir / "nadir.tsai")]
    for extra in ([], ["--overwrite"], ["--replace-input"]):
        proc = run(*args, "-o", str(image), *extra)
        assert_one_line_error(proc, str(image), "input IMAGE", "--overwrite --replace-input")
        assert image.read_bytes() == before
    proc = run(*args, "-o", str(image), "--overwrite", "--replace-input", "--grid", "dem")
    assert proc.returncode == 0, proc.stderr
    with rasterio.open(image) as src, rasterio.open(crater_dir / "dem.tif") as dem:
        assert src.shape == dem.shape and src.transform == dem.transform  # the orthophoto
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nadir.tif"]


def test_output_directories(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """synth refuses a folder that holds files unless --overwrite; demo refreshes a folder
    that an earlier demo wrote (its index.html and summary.json), and refuses any other."""
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "notes.txt").write_bytes(SENTINEL)
    assert_one_line_error(run("synth", "hills", str(scene)), str(scene), "--overwrite")
    assert_one_line_error(run("demo", str(scene)), str(scene), "--overwrite")
    assert sorted(p.name for p in scene.iterdir()) == ["notes.txt"]
    proc = run("-q", "synth", "hills", str(scene), "--size", "16", "--supersample", "1")
    assert proc.returncode == 2
    proc = run(
        "-q", "synth", "hills", str(scene), "--size", "16", "--supersample", "1", "--overwrite"
    )
    assert proc.returncode == 0, proc.stderr
    assert (scene / "dem.tif").is_file() and (scene / "notes.txt").read_bytes() == SENTINEL
    calls = []
    monkeypatch.setattr("orthomvp.demo.run_demo", lambda outdir, quiet: calls.append(outdir))
    demo = tmp_path / "demo"
    demo.mkdir()
    (demo / "index.html").write_bytes(SENTINEL)
    assert_one_line_error(run("demo", str(demo)), str(demo), "not empty", "--overwrite")
    (demo / "summary.json").write_bytes(SENTINEL)  # an earlier demo's folder: refreshed
    assert run("demo", str(demo)).returncode == 0 and calls == [demo]


def _lines(proc: Result) -> list[str]:
    return proc.stdout.splitlines() + proc.stderr.splitlines()


def test_quiet_prints_nothing(crater_dir: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.setattr(orthomvp.engine.progress, "LOG_AFTER", 0.0)  # log lines at once
    commands = _commands(crater_dir, tmp_path)
    for name in ("visibility", "ortho", "mosaic", "mesh", "check"):
        args, _ = commands[name]
        proc = run("-q", *args)
        assert proc.returncode == 0, proc.stderr
        assert (proc.stdout, proc.stderr) == ("", ""), name
    proc = run("-q", "synth", "planar", str(tmp_path / "s"), "--size", "16", "--supersample", "1")
    assert proc.returncode == 0 and (proc.stdout, proc.stderr) == ("", "")


def test_every_line_starts_with_orthomvp(crater_dir: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    monkeypatch.setattr(orthomvp.engine.progress, "LOG_AFTER", 0.0)  # progress lines too
    commands = _commands(crater_dir, tmp_path)
    seen = []
    for name in ("visibility", "ortho", "mosaic", "mesh", "check"):
        args, _ = commands[name]
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
        lines = _lines(proc)
        assert lines and all(line.startswith("orthomvp: ") for line in lines), lines
        seen += lines
    proc = run("synth", "planar", str(tmp_path / "s"), "--size", "16", "--supersample", "1")
    assert proc.returncode == 0 and all(x.startswith("orthomvp: ") for x in _lines(proc))
    assert any(x.startswith("orthomvp: plan: ") for x in seen)
    assert any(x.startswith("orthomvp: tiles: ") for x in seen)  # a progress line
    assert sum(x.startswith("orthomvp: wrote ") for x in seen) == 5


def test_the_mosaic_summary_stays_short_for_many_images() -> None:
    from orthomvp.cli.ortho import NAMED_IMAGES, taken_text

    images = [Path(f"img{k}.tif") for k in range(64)]
    taken = [1000 + 10 * k if k % 9 else 0 for k in range(64)]
    text = taken_text(taken, images)
    assert text == f"{sum(taken):,} posts from 56 of 64 images (from 0 to 1,620 posts each)"
    few = taken_text(taken[:NAMED_IMAGES], images[:NAMED_IMAGES])
    assert few == "0 posts from img0.tif, 1,010 posts from img1.tif, 1,020 posts from " + (
        "img2.tif, 1,030 posts from img3.tif"
    )


@pytest.mark.slow
def test_fit_speaks_in_metres(crater_dir: Path, tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """fit's lines start with orthomvp:, and its summary's figures, in metres, are those of its
    outputs: the median and RMS of fitted - input, the median 1-sigma uncertainty."""
    monkeypatch.setattr(orthomvp.engine.progress, "LOG_AFTER", 0.0)
    d = crater_dir
    out, unc = tmp_path / "f.tif", tmp_path / "u.tif"
    proc = run(
        "fit", str(d / "dem.tif"), *_views(d, "nadir", "fore", "aft"), "-o", str(out),
        "--uncertainty", str(unc), "--hwin", "3", "--levels", "1",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = _lines(proc)
    assert all(line.startswith("orthomvp: ") for line in lines), lines
    assert any(x.startswith("orthomvp: plan: fit ") for x in lines)
    found = re.search(
        r"height change, fitted - input: median ([-+]\d+\.\d\d) m, RMS (\d+\.\d\d) m; median "
        r"1-sigma height uncertainty (\d+\.\d\d) m",
        proc.stdout,
    )
    assert found, proc.stdout
    with rasterio.open(out) as src:
        fitted = src.read(1).astype(np.float64)
    with rasterio.open(unc) as src:
        sigma = src.read(1).astype(np.float64)
    change = (fitted - Terrain.read(d / "dem.tif").values)[np.isfinite(fitted)]
    assert abs(float(found[1]) - np.median(change)) <= 0.006
    assert abs(float(found[2]) - np.sqrt(np.mean(change**2))) <= 0.006
    assert abs(float(found[3]) - np.median(sigma[np.isfinite(sigma)])) <= 0.006
    proc = run(
        "-q", "fit", str(d / "dem.tif"), *_views(d, "nadir", "fore"), "-o", str(out),
        "--overwrite", "--hwin", "3", "--levels", "1",
    )  # fmt: skip
    assert proc.returncode == 0 and (proc.stdout, proc.stderr) == ("", "")


def test_progress_false_prints_nothing(
    crater_dir: Path, tmp_path: Path, capsys, monkeypatch
) -> None:  # noqa: ANN001
    """plan_* with progress=False and run_* left at their default print nothing; with
    progress=True the same calls print the plan and progress lines (the test can fail)."""
    from orthomvp.engine import (
        FitOutputs,
        Outputs,
        plan_check,
        plan_fit,
        plan_ortho,
        run_check,
        run_fit,
        run_plan,
    )
    from orthomvp.mvp import FitOptions

    monkeypatch.setattr(orthomvp.engine.progress, "LOG_AFTER", 0.0)
    d = crater_dir
    dem = d / "dem.tif"
    views = [(d / "nadir.tif", d / "nadir.tsai"), (d / "fore.tif", d / "fore.tsai")]
    options = FitOptions(hwin=3, levels=1)
    for progress in (False, True):
        folder = tmp_path / str(progress)
        folder.mkdir()
        run_plan(plan_ortho(dem, views[:1], progress=progress), Outputs(ortho=folder / "o.tif"))
        run_fit(
            plan_fit(dem, views, options, progress=progress), FitOutputs(heights=folder / "f.tif")
        )
        run_check(plan_check(dem, views, progress=progress))
        out, err = capsys.readouterr()
        if progress:
            assert err.count("orthomvp: plan: ") == 3 and "orthomvp: tiles: " in err
        else:
            assert (out, err) == ("", "")


CAMERA_KINDS = {
    ".tsai text": ".tsai",
    "a .pinhole protobuf": ".pinhole",
    "JSON": "our .json",
    "Orthority CSV": "Orthority exterior file (.csv",
    "Orthority GeoJSON": ".geojson;",
    "Orthority interior parameters": "the one .yaml beside it",
    "Orthority RPC parameters": "or RPC .yaml",
    "OpenSfM reconstruction": "OpenSfM reconstruction.json",
    "ODM shots": "ODM shots.geojson",
    "OpenSfM/ODM cameras.json": "OpenSfM reconstruction.json",
    "USGS CSM ISD": "USGS CSM ISD",
    "USGS CSM model state": "model state .json (line scan, frame, push frame)",
    "GeoTIFF RPC metadata": "the image itself when its GeoTIFF holds RPC metadata",
    "RPC text (_RPC.TXT)": "an _RPC.TXT",
    "RPB": "an .RPB file",
    "an ISIS3 cube": "a spiceinit'd ISIS3 .cub",
}
"""Each camera format of the registry, and the words by which --help names it."""


def help_names(command: str, names: set[str], table: dict[str, str]) -> None:
    """``command --help`` names every one of ``names`` (a registry's) by its words in
    ``table``; a new entry in the registry must be named in help, and so in ``table``."""
    assert names == set(table)
    proc = run(command, "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())
    for words in table.values():
        assert words in text, words


@pytest.mark.parametrize("command", ["ortho", "visibility", "mosaic", "fit", "check"])
def test_help_names_every_camera_kind(command: str) -> None:
    from orthomvp.camera import FORMATS

    help_names(command, {fmt.name for fmt in FORMATS}, CAMERA_KINDS)


CUBE_INSTRUMENTS = {
    "LRO NAC (left and right)": "LRO NAC",
    "LRO WAC (UV and VIS)": "WAC",
    "MRO CTX": "MRO CTX",
    "Kaguya TC1/TC2": "Kaguya TC",
    "Mars Express HRSC": "Mars Express HRSC",
    "Apollo 15/16/17 Metric": "Apollo Metric",
    "MESSENGER MDIS (NAC and WAC filters)": "MESSENGER MDIS",
    "Dawn FC1/FC2": "Dawn FC",
}
"""Each instrument of the ISIS3 cube reader, and the words by which --help names it."""


@pytest.mark.parametrize("command", ["ortho", "isd"])
def test_help_names_every_cube_instrument(command: str) -> None:
    from orthomvp.camera.isis import INSTRUMENTS

    help_names(command, {i.name for i in INSTRUMENTS}, CUBE_INSTRUMENTS)


# ------------------------------------------------------------------------------- mesh textures
def _write(path: Path, values: np.ndarray, transform: Affine | None, crs: object, **kw) -> Path:  # noqa: ANN003
    profile = {"driver": "GTiff", "width": values.shape[-1], "height": values.shape[-2]}
    profile.update(count=1, dtype=values.dtype, crs=crs, **kw)
    if transform is not None:
        profile["transform"] = transform
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(values, 1)
    return path


def _sampled(texture: Path, x: np.ndarray, y: np.ndarray, table: np.ndarray, outside: tuple):  # noqa: ANN202
    """``table`` of the texture's values at the map points (``x``, ``y``): the texel of
    rasterio's ``rowcol`` (the one that ``index`` and ``sample`` pick), ``outside`` beyond the
    texture."""
    with rasterio.open(texture) as src:
        values = src.read(1)
        rows, cols = rasterio.transform.rowcol(src.transform, x, y)  # what index gives
        rows, cols = np.asarray(rows), np.asarray(cols)
        inside = (rows >= 0) & (rows < src.height) & (cols >= 0) & (cols < src.width)
        sampled = np.array([v[0] for v in src.sample(zip(x[inside], y[inside], strict=True))])
    assert (sampled == values[rows[inside], cols[inside]]).all()  # index and sample agree
    out = np.tile(np.asarray(outside, np.uint8), (len(x), 1))
    out[inside] = table[sampled.astype(np.int64)]
    return out


def _finer_texture(crater_dir: Path, tmp_path: Path, kind: str) -> tuple[Path, np.ndarray, tuple]:
    """A texture at twice the DEM's resolution, shifted by a fraction of its pixel, reaching
    past the DEM's top edge and leaving posts outside it on the other three sides: visibility
    codes or an image of 0 and 100 (colours 0 and 255 once stretched); with the colour table
    of its values and the colour outside it."""
    with rasterio.open(crater_dir / "dem.tif") as src:
        transform, crs, (rows, cols) = src.transform, src.crs, src.shape
    fine = transform @ Affine.translation(5.3, -3.7) @ Affine.scale(0.5)
    size = (2 * rows - 4, 2 * cols - 30)
    rng = np.random.default_rng(5)
    if kind == "visibility":
        codes = rng.integers(1, 4, size).astype(np.uint8)
        return _write(tmp_path / "t.tif", codes, fine, crs, nodata=0), CODE_RGB, CODE_RGB[0]
    values = np.where(rng.random(size) < 0.5, 0.0, 100.0).astype(np.float32)
    table = np.zeros((101, 3), np.uint8)
    table[100] = 255
    return _write(tmp_path / "t.tif", values, fine, crs), table, NAN_RGB


@pytest.mark.parametrize("kind", ["visibility", "image"])
def test_mesh_samples_a_finer_texture_at_the_posts(
    crater_dir: Path, tmp_path: Path, kind: str
) -> None:
    """PLY: every vertex gets the texel under its post, the posts outside the texture the
    no-data colour."""
    dem = crater_dir / "dem.tif"
    texture, table, outside = _finer_texture(crater_dir, tmp_path, kind)
    terrain = Terrain.read(dem)
    r, c = np.divmod(terrain_mesh(terrain).vertex_post, terrain.shape[1])
    expected = _sampled(texture, *(terrain.transform @ (c + 0.5, r + 0.5)), table, outside)
    assert (expected == np.asarray(outside)).all(axis=1).mean() > 0.1  # some posts outside
    out = tmp_path / "m.ply"
    args = ["mesh", str(dem), "-o", str(out), "--texture", str(texture)]
    proc = run(*args, *(["--colour-by", "visibility"] if kind == "visibility" else []))
    assert proc.returncode == 0, proc.stderr
    got = trimesh.load(out, process=False).visual.vertex_colors[:, :3]
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("fmt", ["obj", "glb"])
@pytest.mark.parametrize("kind", ["visibility", "image"])
def test_mesh_images_keep_a_finer_texture_resolution(
    crater_dir: Path, tmp_path: Path, kind: str, fmt: str
) -> None:
    """OBJ and GLB: the image texture is the texture at its own resolution over the DEM
    grid's extent (2 x 2 texels a post, each the texel under its centre), and the UVs put
    each vertex at its post's place in it."""
    dem = crater_dir / "dem.tif"
    texture, table, outside = _finer_texture(crater_dir, tmp_path, kind)
    terrain = Terrain.read(dem)
    rows, cols = terrain.shape
    i, j = np.mgrid[0 : 2 * rows, 0 : 2 * cols]
    centres = (terrain.transform @ Affine.scale(0.5)) @ (j.ravel() + 0.5, i.ravel() + 0.5)
    expected = _sampled(texture, *centres, table, outside).reshape(2 * rows, 2 * cols, 3)
    out = tmp_path / f"m.{fmt}"
    args = ["mesh", str(dem), "-o", str(out), "--texture", str(texture)]
    proc = run(*args, *(["--colour-by", "visibility"] if kind == "visibility" else []))
    assert proc.returncode == 0, proc.stderr
    if fmt == "obj":
        image = np.asarray(Image.open(tmp_path / "m.png").convert("RGB"))
        mesh = trimesh.load(out, process=False)
    else:
        mesh = trimesh.load(out, force="mesh", process=False)
        image = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
    np.testing.assert_array_equal(image, expected)
    r, c = np.divmod(terrain_mesh(terrain).vertex_post, cols)  # the UVs: the posts' centres
    uv = np.column_stack([(c + 0.5) / cols, 1 - (r + 0.5) / rows])
    np.testing.assert_allclose(mesh.visual.uv, uv, atol=1e-6)


def test_mesh_samples_a_coarser_texture_in_another_crs(crater_dir: Path, tmp_path: Path) -> None:
    """A texture at about three times the DEM's post spacing, in a projected CRS (equidistant
    cylindrical metres on the DEM's sphere, the DEM in degrees): each post takes the texel
    under it, as pyproj places the post."""
    from pyproj import CRS, Transformer

    dem = crater_dir / "dem.tif"
    terrain = Terrain.read(dem)
    own = CRS.from_user_input(terrain.crs.to_wkt())
    eqc = CRS.from_proj4("+proj=eqc +R=1737400 +units=m +no_defs")
    to_eqc = Transformer.from_crs(own, eqc, always_xy=True)
    x0, y0 = to_eqc.transform(*(terrain.transform @ (0, 0)))
    step = 3 * np.radians(terrain.transform.a) * 1737400
    # a quarter and a third of a texel beyond the DEM's corner: no post on a texel's edge
    coarse = Affine.translation(x0 - step / 4, y0 + step / 3) @ Affine.scale(step, -step)
    codes = np.random.default_rng(6).integers(1, 4, (30, 30)).astype(np.uint8)
    texture = _write(tmp_path / "t.tif", codes, coarse, eqc.to_wkt(), nodata=0)
    out = tmp_path / "m.ply"
    args = ["mesh", str(dem), "-o", str(out), "--texture", str(texture)]
    proc = run(*args, "--colour-by", "visibility")
    assert proc.returncode == 0, proc.stderr
    posts = terrain_mesh(terrain).vertex_post
    r, c = np.divmod(posts, terrain.shape[1])
    x, y = to_eqc.transform(*(terrain.transform @ (c + 0.5, r + 0.5)))
    tc, tr = ~coarse @ (np.asarray(x), np.asarray(y))
    assert tc.min() > 0 and tr.min() > 0 and max(tc.max(), tr.max()) < 30  # all inside
    expected = CODE_RGB[codes[np.floor(tr).astype(int), np.floor(tc).astype(int)]]
    got = trimesh.load(out, process=False).visual.vertex_colors[:, :3]
    np.testing.assert_array_equal(got, expected)
    assert len(np.unique(codes[np.floor(tr).astype(int), np.floor(tc).astype(int)])) == 3


@pytest.mark.parametrize("fmt", ["ply", "glb"])
def test_a_texture_without_georeference_must_match_the_dem(
    crater_dir: Path, tmp_path: Path, fmt: str
) -> None:
    texture = tmp_path / "t.tif"
    with pytest.warns(rasterio.errors.NotGeoreferencedWarning):
        _write(texture, np.ones((50, 70), np.float32), None, None)
    out = tmp_path / f"m.{fmt}"
    proc = run("mesh", str(crater_dir / "dem.tif"), "-o", str(out), "--texture", str(texture))
    assert_one_line_error(proc, "t.tif", "70 x 50 px", "64 x 64 posts", "georeference")
    assert not out.exists()


def test_render_drapes_a_texture_off_the_dem_grid(crater_dir: Path, tmp_path: Path) -> None:
    """render drapes a finer visibility raster as it drapes that raster sampled at the posts
    (by rasterio's rowcol) and written on the DEM grid: the same image."""
    dem = crater_dir / "dem.tif"
    with rasterio.open(dem) as src:
        transform, crs, (rows, cols) = src.transform, src.crs, src.shape
    fine = transform @ Affine.translation(2.2, 3.3) @ Affine.scale(0.5)
    codes = np.random.default_rng(7).integers(1, 4, (2 * rows, 2 * cols)).astype(np.uint8)
    texture = _write(tmp_path / "fine.tif", codes, fine, crs, nodata=0)
    r, c = np.mgrid[0:rows, 0:cols]
    x, y = transform @ (c.ravel() + 0.5, r.ravel() + 0.5)
    tr, tc = (np.asarray(v) for v in rasterio.transform.rowcol(fine, x, y))
    inside = (tr >= 0) & (tr < 2 * rows) & (tc >= 0) & (tc < 2 * cols)
    assert 0.5 < inside.mean() < 0.95
    on_grid = np.zeros(rows * cols, np.uint8)
    on_grid[inside] = codes[tr[inside], tc[inside]]
    sampled = _write(
        tmp_path / "on-grid.tif", on_grid.reshape(rows, cols), transform, crs, nodata=0
    )
    images = []
    for name, raster in (("a", texture), ("b", sampled)):
        out = tmp_path / f"{name}.png"
        args = ["render", str(dem), "-o", str(out), "--visibility", str(raster)]
        proc = run(*args, "--size", "240", "180", "--view", "top")
        assert proc.returncode == 0, proc.stderr
        images.append(np.asarray(Image.open(out)))
    np.testing.assert_array_equal(images[0], images[1])


def test_a_texture_on_another_body_is_refused(crater_dir: Path, tmp_path: Path) -> None:
    """A texture in an Earth CRS over the lunar DEM: one line naming it, nothing written."""
    texture = _write(
        tmp_path / "t.tif", np.ones((8, 8), np.uint8), Affine(30, 0, 5e5, 0, -30, 4e6), "EPSG:32633"
    )
    out = tmp_path / "m.ply"
    proc = run("mesh", str(crater_dir / "dem.tif"), "-o", str(out), "--texture", str(texture))
    assert_one_line_error(proc, "t.tif", "UTM zone 33N", "cannot be reached", "celestial body")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.tif"]
