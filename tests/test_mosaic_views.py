"""Mosaics of one image (the same outputs and semantics as of several: source flags, hole
policies, empty-post reasons) and of several images some of which see no post of the grid
(left out with one warning; the others' mosaic bit for bit, in the user's numbering)."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from orthomvp.camera import load_view, write_tsai
from orthomvp.cli import main
from orthomvp.codes import Code
from orthomvp.engine import Outputs, plan_fit, plan_ortho, run_fit, run_plan
from orthomvp.engine.fit import FitOutputs
from orthomvp.errors import GeometryError, InputError, LeftOutWarning
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.mvp import FitOptions
from orthomvp.ortho.composite import MosaicOptions
from orthomvp.ortho.holes import FLAGS, HOLES, Flag
from orthomvp.ortho.orthophoto import mosaic
from tests.conftest import shared
from tests.test_mosaic import nadir_quarter_views

KINDS = ("ortho", "source", "visibility")


def read(path: Path) -> np.ndarray:
    with rasterio.open(path) as src:
        return src.read()


def engine(dem: Path, views: list, tmp: Path, name: str, options: MosaicOptions | None) -> dict:
    """The engine's run of ``views`` on the DEM's grid in tiles of 32 posts: its outputs (a
    mosaic's, or with ``options`` None an orthophoto's), the report and the plan."""
    plan = plan_ortho(dem, views, tile=32, progress=False, grid="dem", mosaic=options)
    kinds = KINDS if options is not None else ("ortho", "visibility")
    outputs = Outputs(**{k: tmp / f"{name}-{k}.tif" for k in kinds})
    report = run_plan(plan, outputs, threads=2, progress=False)
    return {k: read(tmp / f"{name}-{k}.tif") for k in kinds} | {"report": report, "plan": plan}


@pytest.mark.parametrize("holes", HOLES)
def test_one_image_mosaic_is_a_mosaic(crater_dir: Path, tmp_path: Path, holes: str) -> None:
    """The crater's oblique view alone (its hidden posts: occluded and facing away): a mosaic
    with the source's view, flag and weight bands; visible posts take the orthophoto's values
    bit for bit, but where the clear pixels (which act near the image's own occlusion
    boundary, as for every view of a mosaic) resample them, and everywhere with clear=False;
    every post carries the flag its code gives under the policy (behind fills the posts facing
    away from the same view, naive every post inside the image, both with the naive
    orthophoto's values; inpaint fills small holes, from no view); the report counts the
    flags. The mosaic of the view given twice (the N-view path, views that agree) and the
    in-memory mosaic give the same flags and values."""
    dem, view = crater_dir / "dem.tif", (crater_dir / "oblique.tif", crater_dir / "oblique.tsai")
    got = engine(dem, [view], tmp_path, "one", MosaicOptions(holes=holes))
    assert got["plan"].mosaic is not None
    data, src, codes = got["ortho"], got["source"], got["visibility"][0]
    assert src.shape[0] == 3
    view_band, flags, weights = src
    ortho = engine(dem, [view], tmp_path, "ortho", None)["ortho"]
    visible = flags == Flag.VISIBLE
    assert visible.sum() > 1000 and (codes[visible] == Code.VISIBLE).all()
    memory = mosaic(Terrain.read(dem), [load_view(*view)], holes=holes)
    moved = (data != ortho).any(axis=0) & visible
    assert 20 < moved.sum() < 0.1 * visible.sum()
    np.testing.assert_array_equal(moved, memory.resampled[0] & visible)
    plain = engine(dem, [view], tmp_path, "plain", MosaicOptions(holes=holes, clear=False))
    np.testing.assert_array_equal(plain["ortho"][:, visible], ortho[:, visible])
    filled = np.isfinite(data).all(axis=0)
    fill = {"behind": Flag.BEHIND, "naive": Flag.NAIVE, "inpaint": Flag.INPAINTED}.get(holes)
    expect = np.select(
        [codes == Code.NODATA, codes == Code.VISIBLE, codes == Code.FACING_AWAY],
        [Flag.OUTSIDE, Flag.VISIBLE, Flag.FACING_AWAY],
        Flag.OCCLUDED,
    )
    if holes == "behind":
        expect[codes == Code.FACING_AWAY] = Flag.BEHIND
    if holes == "naive":
        expect[(codes == Code.FACING_AWAY) | (codes == Code.OCCLUDED)] = Flag.NAIVE
    if holes == "inpaint":
        expect[flags == Flag.INPAINTED] = Flag.INPAINTED
    assert not (codes[~visible] == Code.VISIBLE).any()  # (no doubtful post on the crater)
    np.testing.assert_array_equal(flags, expect)
    assert fill is None or (flags == fill).sum() > 20
    np.testing.assert_array_equal(filled, np.isin(flags, (Flag.VISIBLE, fill)))
    np.testing.assert_array_equal(view_band, np.where(filled & (flags != Flag.INPAINTED), 1, 0))
    np.testing.assert_array_equal(weights, np.where(view_band == 1, 255, 0))
    if holes in ("behind", "naive"):
        plan = plan_ortho(dem, [view], tile=32, progress=False, grid="dem", occlusion=False)
        run_plan(plan, Outputs(ortho=tmp_path / "n.tif"), threads=2, progress=False)
        at = flags == fill
        np.testing.assert_array_equal(data[:, at], read(tmp_path / "n.tif")[:, at])
        assert np.isnan(ortho[:, at]).all()
    assert got["report"].flags == np.bincount(flags.ravel(), minlength=FLAGS).tolist()
    copy = shutil.copy(view[0], tmp_path / "copy.tif")
    two = engine(dem, [view, (copy, view[1])], tmp_path, "two", MosaicOptions(holes=holes))
    np.testing.assert_array_equal(two["source"][1], flags)
    np.testing.assert_allclose(two["ortho"], data, rtol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(memory.flags, flags)
    np.testing.assert_array_equal(memory.source, view_band)
    np.testing.assert_allclose(memory.data, data, rtol=1e-6, equal_nan=True)


def summary(out: str) -> tuple[int, list[int], str]:
    """The mosaic summary's posts from no image, the counts of its holes line, and that line."""
    taken, holes = out.strip().splitlines()[-2:]
    none = int(taken.rsplit("; ", 1)[1].split()[0].replace(",", ""))
    text = holes.split(": ", 2)[2].split("; filled holes")[0]
    counts = [int(p.split()[0].replace(",", "")) for p in text.split(", ") if p != "none"]
    return none, counts, holes


def test_one_image_on_the_command_line(crater_dir: Path, tmp_path: Path, capsys) -> None:
    """`mosaic` of one image: the source has the view and flag bands; the summary counts the
    empty posts by reason (together the posts from no image: never "none" when some are
    empty), and --holes naive fills the occluded posts, flagged naive."""
    dem = str(crater_dir / "dem.tif")
    pair = [str(crater_dir / "oblique.tif"), str(crater_dir / "oblique.tsai")]
    for holes in ("empty", "naive"):
        out, src = tmp_path / f"{holes}.tif", tmp_path / f"{holes}-s.tif"
        args = ["mosaic", dem, *pair, "-o", str(out), "--source", str(src), "--grid", "dem"]
        assert main([*args, "--holes", holes, "--balance", "gain-offset"]) == 0
        none, counts, line = summary(capsys.readouterr().out)
        flags = read(src)[1]
        assert read(src).shape[0] == 3
        empty = int(np.isnan(read(out)[0]).sum())
        assert (
            none == empty == sum(counts) == int(np.isin(flags, [f for f in Flag if f.empty]).sum())
        )
        assert ("empty posts: none" in line) == (empty == 0), line
        if holes == "empty":
            assert f"{(flags == Flag.OCCLUDED).sum():,} occluded in every view" in line, line
        else:
            assert f"{(flags == Flag.NAIVE).sum():,} filled naive" in line, line
            assert (flags == Flag.NAIVE).sum() > 100


def crop_rows(dem: Path, out: Path, first: int) -> Path:
    """The DEM's rows from ``first`` on, written to ``out``."""
    with rasterio.open(dem) as src:
        window = rasterio.windows.Window(0, first, src.width, src.height - first)
        move = src.transform @ Affine.translation(0, first)
        profile = src.profile | {"height": window.height, "transform": move}
        with rasterio.open(out, "w", **profile) as dst:
            dst.write(src.read(window=window))
    return out


@pytest.fixture(scope="module")
def partial(crater_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The crater's DEM rows 36 and below, and its views with the nadir image cropped to its
    top-left quarter (camera cropped alike), which images DEM rows 0 to 30 only."""
    out = tmp_path_factory.mktemp("left-out")
    crop_rows(crater_dir / "dem.tif", out / "dem.tif", 36)
    views = nadir_quarter_views(crater_dir, out)
    copy = (shutil.copy(views[1][0], out / "nadir-copy.tif"), views[1][1])
    return {"dem": out / "dem.tif", "views": views, "copy": copy}


@pytest.mark.parametrize(
    "options", [{}, {"balance": "gain", "holes": "behind", "priority": "order"}], ids=str
)
def test_an_image_that_sees_no_post_is_left_out(
    partial: dict, tmp_path: Path, options: dict
) -> None:
    """Of three images, one sees no post of the grid: one LeftOutWarning naming it; the
    mosaic is that of the other two bit for bit (balanced too), in the user's numbering:
    source band 1 never holds 2 and maps 2 -> 3, the left-out image's weight and visibility
    bands are all 0; the plan lists it and no tile has it."""
    dem, views = partial["dem"], partial["views"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        three = engine(dem, views, tmp_path, "three", MosaicOptions(**options))
    left = [w for w in caught if issubclass(w.category, LeftOutWarning)]
    assert len(left) == 1, [str(w.message) for w in caught]
    assert str(left[0].message) == (
        f"1 of 3 images sees no post of the output grid and is left out: {views[1][0]}"
    )
    assert three["plan"].left_out == (1,) and all(1 not in j.views for j in three["plan"].tiles)
    two = engine(dem, [views[0], views[2]], tmp_path, "two", MosaicOptions(**options))
    np.testing.assert_array_equal(three["ortho"], two["ortho"])
    src3, src2 = three["source"], two["source"]
    np.testing.assert_array_equal(src3[0], np.array([0, 1, 3])[src2[0]])
    assert 2 not in src3[0] and (src3[0] > 0).sum() > 1000
    np.testing.assert_array_equal(src3[1], src2[1])
    np.testing.assert_array_equal(src3[[2, 4]], src2[2:])
    assert not src3[3].any() and not three["visibility"][1].any()
    np.testing.assert_array_equal(three["visibility"][[0, 2]], two["visibility"])
    assert three["report"].taken == [two["report"].taken[0], 0, two["report"].taken[1]]


def test_an_image_whose_box_only_brushes_the_grid(
    crater_dir: Path, partial: dict, tmp_path: Path
) -> None:
    """From DEM row 32 on, the nadir quarter's image box (with its margin of 2.5 pixels) meets
    some tiles, so the plan keeps it, but no post projects inside the image: the run leaves
    it out with one LeftOutWarning (it raised before), and the mosaic is the oblique image's
    alone bit for bit."""
    dem = crop_rows(crater_dir / "dem.tif", tmp_path / "dem.tif", 32)
    views = partial["views"][:2]
    with pytest.warns(LeftOutWarning, match="1 of 2 images sees no post") as caught:
        two = engine(dem, views, tmp_path, "two", MosaicOptions())
    assert len(caught) == 1 and two["plan"].left_out == ()
    assert any(1 in job.views for job in two["plan"].tiles) and two["report"].inside[1] == 0
    one = engine(dem, views[:1], tmp_path, "one", MosaicOptions())
    np.testing.assert_array_equal(two["ortho"], one["ortho"])
    np.testing.assert_array_equal(two["source"][:3], one["source"])


def test_left_out_errors_and_the_in_memory_mosaic(partial: dict, tmp_path: Path) -> None:
    """No image sees the grid: GeometryError (for one image, the orthophoto's reason); a
    balance held on the left-out image: InputError. The in-memory mosaic leaves the view out
    the same way, with one warning."""
    dem, views = partial["dem"], partial["views"]
    with pytest.raises(GeometryError, match="does not cover the output grid"):
        plan_ortho(dem, [views[1]], progress=False, grid="dem")
    with pytest.raises(GeometryError, match="does not cover the output grid"):
        plan_ortho(dem, [views[1]], progress=False, grid="dem", mosaic=MosaicOptions())
    with pytest.raises(GeometryError, match="none of the 2 images sees a post"):
        plan_ortho(dem, [views[1], partial["copy"]], progress=False, grid="dem")
    with (
        pytest.raises(InputError, match="balance reference 2 sees no post"),
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("ignore", LeftOutWarning)
        plan_ortho(
            dem,
            views,
            progress=False,
            grid="dem",
            mosaic=MosaicOptions(balance="gain", reference=1),
        )
    terrain = Terrain.read(dem)
    loaded = [(read_image(image), camera) for image, camera in views]
    with pytest.warns(LeftOutWarning, match="1 of 3 views sees no post of the grid") as caught:
        three = mosaic(terrain, loaded, options=MosaicOptions(balance="gain"))
    assert len(caught) == 1
    two = mosaic(terrain, [loaded[0], loaded[2]], options=MosaicOptions(balance="gain"))
    np.testing.assert_array_equal(three.data, two.data)
    np.testing.assert_array_equal(three.source, np.array([0, 1, 3])[two.source])
    with pytest.raises(GeometryError, match="none of the 2 views"):
        mosaic(terrain, [loaded[1], (read_image(partial["copy"][0]), partial["copy"][1])])


def test_left_out_on_the_command_line(partial: dict, tmp_path: Path, capsys) -> None:
    """`mosaic` and `fit` with an image that sees no post: one warning line naming it, exit 0,
    the others' results; --balance-reference on it, or `fit` with one image left that sees
    the DEM: one error line, exit 2."""
    dem, views = partial["dem"], partial["views"]
    pairs = []
    for image, camera in views:
        path = tmp_path / f"{Path(image).stem}.tsai"
        write_tsai(camera, path)
        pairs += [str(image), str(path)]
    base = ["mosaic", str(partial["dem"]), *pairs, "-o", str(tmp_path / "m.tif"), "--grid", "dem"]
    assert main(base) == 0
    err = capsys.readouterr().err.strip().splitlines()
    warned = [line for line in err if "left out" in line]
    assert warned == [
        f"orthomvp: warning: 1 of 3 images sees no post of the output grid and is left out: "
        f"{views[1][0]}"
    ], err
    assert main([*base, "--overwrite", "--balance", "gain", "--balance-reference", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "orthomvp: error: balance reference 2 sees no post of the grid", err
    fit = ["fit", str(dem), *pairs[:4], "-o", str(tmp_path / "f.tif")]
    assert main(fit) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "only 1 of the 2 images sees the DEM" in err[0], err


def test_fit_leaves_out_an_image_that_sees_no_post(partial: dict, tmp_path: Path) -> None:
    """The fit of three images of which one sees no post of the DEM is the fit of the other
    two bit for bit, with one LeftOutWarning."""
    dem, views = partial["dem"], partial["views"]
    options = FitOptions(hwin=4, levels=1)
    with pytest.warns(LeftOutWarning) as caught:
        three = plan_fit(dem, views, options, tile=64, progress=False)
    assert len(caught) == 1
    two = plan_fit(dem, [views[0], views[2]], options, tile=64, progress=False)
    for name, plan in (("three", three), ("two", two)):
        run_fit(plan, FitOutputs(heights=tmp_path / f"{name}.tif"), threads=2, progress=False)
    np.testing.assert_array_equal(read(tmp_path / "three.tif"), read(tmp_path / "two.tif"))
    assert np.isfinite(read(tmp_path / "two.tif")).mean() > 0.5


@pytest.mark.realdata
def test_whole_flight_over_a_dem_tile(tmp_path: Path, capsys) -> None:
    """ngi-aerial: a DEM tile that image 0182 misses and 0184 covers: the mosaic of both is
    that of 0184 alone bit for bit, its posts numbered 2, with one warning line naming 0182."""
    ngi = shared("ngi-aerial")
    opk = str(ngi / "orthority-format" / "ngi_xyz_opk.csv")
    dem = tmp_path / "dem.tif"
    with rasterio.open(ngi / "dem.tif") as src:
        window = rasterio.windows.Window(0, 0, 120, 150)
        profile = src.profile | {"width": 120, "height": 150}
        with rasterio.open(dem, "w", **profile) as dst:
            dst.write(src.read(window=window))
    miss, cover = (str(ngi / f"3324c_2015_1004_05_{n}_RGB.tif") for n in ("0182", "0184"))
    runs = {}
    for name, pairs in (("both", [miss, opk, cover, opk]), ("one", [cover, opk])):
        out = tmp_path / f"{name}.tif"
        args = [
            "mosaic",
            str(dem),
            *pairs,
            "-o",
            str(out),
            "--source",
            str(tmp_path / f"{name}-s.tif"),
        ]
        assert main([*args, "--res", "5m"]) == 0
        runs[name] = (read(out), read(tmp_path / f"{name}-s.tif"), capsys.readouterr().err)
    (both, src_both, err), (one, src_one, err_one) = runs["both"], runs["one"]
    assert [line for line in err.splitlines() if "warning" in line] == [
        f"orthomvp: warning: 1 of 2 images sees no post of the output grid and is left out: {miss}"
    ]
    assert "warning" not in err_one
    np.testing.assert_array_equal(both, one)
    np.testing.assert_array_equal(src_both[0], 2 * src_one[0])
    assert set(np.unique(src_both[0])) == {0, 2}
    np.testing.assert_array_equal(src_both[1], src_one[1])


def test_an_image_left_out_of_a_fit_does_not_set_its_pyramid(partial: dict, tmp_path: Path) -> None:
    """The image left out (the nadir quarter) is too small for the pyramid the other two allow:
    it no longer sets the levels, and the fit is the other two's bit for bit."""
    from orthomvp.mvp.problem import levels_for

    dem, views = partial["dem"], partial["views"]
    sizes = []
    for image, _ in views:
        with rasterio.open(image) as src:
            sizes.append(min(src.width, src.height))
    options = FitOptions(hwin=4, levels=3)
    kept = levels_for(min(sizes[0], sizes[2]), 3)
    assert levels_for(sizes[1], 3) < kept  # (what the test is about)
    with pytest.warns(LeftOutWarning):
        three = plan_fit(dem, views, options, tile=64, progress=False)
    two = plan_fit(dem, [views[0], views[2]], options, tile=64, progress=False)
    assert three.options.levels == two.options.levels == kept
    for name, plan in (("three", three), ("two", two)):
        run_fit(plan, FitOutputs(heights=tmp_path / f"{name}.tif"), threads=2, progress=False)
    np.testing.assert_array_equal(read(tmp_path / "three.tif"), read(tmp_path / "two.tif"))


def test_an_image_over_another_part_of_the_body_is_left_out(
    crater_dir: Path, tmp_path: Path
) -> None:
    """Found by a new user's audit: a camera over another region of the body stopped every
    command ("beyond the DEM's horizon", blaming the CRS). Of several images it is left out as
    one that sees no post, the mosaic that of the others bit for bit; alone it is refused in
    one line that says where it looks and what the DEM covers."""
    from dataclasses import replace

    d = crater_dir
    oblique = load_view(d / "oblique.tif", d / "oblique.tsai")[1]
    far = replace(oblique, center=-oblique.center)  # over the far side of the body
    write_tsai(far, tmp_path / "far.tsai")
    views = [(d / "oblique.tif", d / "oblique.tsai"), (d / "nadir.tif", tmp_path / "far.tsai")]
    with pytest.warns(LeftOutWarning, match=r"1 of 2 images sees no post .*nadir\.tif"):
        two = engine(d / "dem.tif", views, tmp_path, "two", MosaicOptions())
    one = engine(d / "dem.tif", views[:1], tmp_path, "one", MosaicOptions())
    np.testing.assert_array_equal(two["ortho"], one["ortho"])
    with pytest.raises(GeometryError) as caught:
        plan_ortho(d / "dem.tif", views[1:], progress=False)
    text = str(caught.value)
    assert "camera 1 is beyond the DEM's horizon (over longitude" in text
    assert "the DEM covers longitude" in text and "is it the DEM of these images" in text
