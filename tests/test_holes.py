"""The mosaic's hole policies (orthomvp/ortho/holes.py) against the city's exact truth, their
flags and reasons, inpainting against a known plane, and identical results for any tiling."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio

from orthomvp.cli import main
from orthomvp.codes import Code
from orthomvp.engine import Outputs, plan_ortho, run_plan
from orthomvp.errors import InputError
from orthomvp.ortho.composite import MosaicOptions
from orthomvp.ortho.holes import FLAGS, HOLES, INPAINT_SIZE, Flag, inpaint
from orthomvp.ortho.orthophoto import mosaic
from orthomvp.synthetic import make_scene
from orthomvp.synthetic.loader import load_scene

NAMES = ("ne", "se", "sw", "nw")


@pytest.fixture(scope="module")
def city(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 96-post city (more holes than the 64-post one), one ray a pixel."""
    out = tmp_path_factory.mktemp("city96")
    make_scene("city", size=96).write(out, supersample=1)
    return out


def test_inpaint_recovers_a_plane_and_leaves_large_holes() -> None:
    """A plane with a 4 x 5 hole comes back within 1% of its range; a hole wider than
    INPAINT_SIZE and one at the window's edge stay empty."""
    rows, cols = np.mgrid[0:60, 0:70].astype(np.float32)
    plane = (0.2 + 0.004 * rows + 0.003 * cols)[None]
    hole = np.zeros(plane.shape[1:], bool)
    hole[20:24, 30:35] = True  # small: inpainted
    hole[40:45, 10 : 11 + INPAINT_SIZE] = True  # one post too wide
    hole[0:3, 50:53] = True  # at the edge
    data = np.where(hole, np.nan, plane).astype(np.float32)
    done = inpaint(data, hole)
    small = np.zeros_like(hole)
    small[20:24, 30:35] = True
    np.testing.assert_array_equal(done, small)
    span = float(plane.max() - plane.min())
    assert np.abs(data[:, done] - plane[:, done]).max() < 0.01 * span
    assert np.isnan(data[:, hole & ~done]).all()


@pytest.mark.parametrize("holes", HOLES)
def test_hole_policies_against_the_city_truth(city: Path, holes: str) -> None:
    """Every policy: at most 0.05% of the posts flagged visible take weight from a view whose
    truth occludes them (the trust test's: 1 of 9,016 on this city, 0 on those of 64 and 160
    posts); every post with a value is flagged with how, every empty one
    with its reason; fills take a single view (inpainted posts none). Inpainting is closer to
    the true radiance than the naive value of the most nadir view at the same posts (mean
    absolute error); the naive policy fills every post inside an image."""
    scene = load_scene(city)
    views = [(scene.views[n].image, scene.views[n].camera) for n in NAMES]
    truth = np.array([scene.views[n].truth for n in NAMES])
    got = mosaic(scene.terrain, views, holes=holes)
    flags, data, weights = got.flags, got.data[0], got.weights
    visible = flags == Flag.VISIBLE
    assert visible.mean() > 0.97
    assert ((weights > 0) & (truth == Code.OCCLUDED))[:, visible].any(axis=0).sum() <= 0.0005 * (
        visible.sum()
    )
    filled = np.isfinite(data)
    assert all(Flag(f).empty for f in np.unique(flags[~filled]))
    assert not any(Flag(f).empty for f in np.unique(flags[filled]))
    fills = filled & ~visible
    np.testing.assert_array_equal(got.source[fills] > 0, flags[fills] != Flag.INPAINTED)
    np.testing.assert_array_equal((weights[:, fills] > 0).sum(axis=0), got.source[fills] > 0)
    if holes == "empty":  # (only doubtful posts with a clear pixel are filled: none here)
        assert (~filled).sum() > 20 and (flags[fills] == Flag.DOUBTFUL).all()
        reason = flags[~filled]
        assert set(np.unique(reason)) <= {Flag.OCCLUDED, Flag.HIDDEN, Flag.DOUBTFUL_EMPTY}
        # (the 160-post city: 86% / 88% of its occluded / hidden holes are truly hidden)
        assert (truth != Code.VISIBLE).all(axis=0)[~filled].mean() > 0.75
    if holes == "inpaint":
        done = flags == Flag.INPAINTED
        assert done.sum() > 10
        naive = mosaic(scene.terrain, views, holes="naive").data[0]
        err = np.abs(data[done] - scene.radiance[done]).mean()
        assert err < np.abs(naive[done] - scene.radiance[done]).mean()
    if holes == "naive":
        inside = (truth != Code.NODATA).any(axis=0)
        np.testing.assert_array_equal(filled, inside)
        assert (flags == Flag.NAIVE).sum() > 10


def engine_run(city: Path, tmp_path: Path, tile: int, holes: str) -> dict:
    views = [(city / f"{n}.tif", city / f"{n}.tsai") for n in NAMES]
    plan = plan_ortho(
        city / "dem.tif", views, tile=tile, progress=False, mosaic=MosaicOptions(holes=holes),
        grid="dem",
    )  # fmt: skip
    outputs = Outputs(ortho=tmp_path / f"{tile}.tif", source=tmp_path / f"{tile}-s.tif")
    report = run_plan(plan, outputs, threads=2, progress=False)
    with rasterio.open(outputs.ortho) as a, rasterio.open(outputs.source) as b:
        return {"ortho": a.read(), "source": b.read(), "report": report}


@pytest.mark.slow
@pytest.mark.parametrize("holes", HOLES)
def test_any_tiling_gives_the_same_holes(city: Path, tmp_path: Path, holes: str) -> None:
    """Tiles of 16 and 40 posts give the untiled mosaic bit for bit, inpainted and resampled
    posts (clear pixels at blocked samples, orthomvp.ortho.support.sharpen) included, and the
    in-memory one's flags; the report counts the flags. Every policy."""
    whole = engine_run(city, tmp_path, 128, holes)
    flags = whole["source"][1]
    fill = {
        "empty": Flag.DOUBTFUL_EMPTY,
        "behind": Flag.BEHIND,
        "inpaint": Flag.INPAINTED,
        "naive": Flag.NAIVE,
    }
    assert (flags == fill[holes]).sum() > 0
    for tile in (16, 40):
        tiled = engine_run(city, tmp_path, tile, holes)
        assert tiled["report"].tiles_run > 4
        np.testing.assert_array_equal(tiled["ortho"], whole["ortho"])
        np.testing.assert_array_equal(tiled["source"], whole["source"])
        assert tiled["report"].flags == np.bincount(flags.ravel(), minlength=FLAGS).tolist()
    scene = load_scene(city)
    memory = mosaic(scene.terrain, [(scene.views[n].image, scene.views[n].camera) for n in NAMES])
    empty = memory.flags != Flag.VISIBLE
    assert (flags[~empty] == Flag.VISIBLE).all() and empty.sum() == (flags != Flag.VISIBLE).sum()


def test_the_fill_option_is_a_deprecated_alias(crater_dir: Path, tmp_path: Path, capsys) -> None:
    """fill="any-view" is holes="behind" with a DeprecationWarning (a contradiction is an
    error); --fill works with one warning line."""
    with pytest.warns(DeprecationWarning, match="holes='behind'"):
        assert MosaicOptions(fill="any-view") == MosaicOptions(holes="behind")
    with pytest.raises(InputError, match="contradicts"):
        MosaicOptions(fill="naive", holes="behind")
    with pytest.raises(InputError, match="holes must be one of"):
        MosaicOptions(holes="blur")
    pairs = [str(crater_dir / f"oblique.{e}") for e in ("tif", "tsai")]
    base = ["-q", "mosaic", str(crater_dir / "dem.tif"), *pairs, "--overwrite"]
    assert main([*base, "-o", str(tmp_path / "a.tif"), "--fill", "any-view"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["orthomvp: warning: --fill is deprecated; use --holes behind"], err
    assert main([*base, "-o", str(tmp_path / "b.tif"), "--holes", "behind"]) == 0
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        np.testing.assert_array_equal(a.read(), b.read())


def test_occluder_share_against_the_city_truth(city: Path) -> None:
    """The occluder share of a view's sample is 1 at posts its truth occludes well inside
    their shadow (every ray of every tap meets the occluder) and 0 at visible posts away from
    every truth class boundary on open ground (no surface but the post's own near them)."""
    from scipy.ndimage import binary_erosion

    from orthomvp.synthetic.ghosts import occluder_share

    scene = make_scene("city", size=96)
    x, y = scene.post_local()
    posts = np.stack([x, y, scene.surface.height(x, y)], axis=-1)
    ground = scene.surface.pieces(x, y)[3] == 0
    loaded = load_scene(city)
    for name in ("ne", "sw"):
        truth = loaded.views[name].truth
        uv = mosaic(scene.terrain, [(loaded.views[name].image, scene.cameras[name])]).visibilities
        uv = uv[0].uv
        deep = binary_erosion(truth == Code.OCCLUDED, np.ones((7, 7), bool))
        clear = binary_erosion((truth == Code.VISIBLE) & ground, np.ones((9, 9), bool))
        assert deep.sum() > 20 and clear.sum() > 1000
        np.testing.assert_array_equal(occluder_share(scene, name, uv[deep], posts[deep]), 1.0)
        np.testing.assert_array_equal(occluder_share(scene, name, uv[clear], posts[clear]), 0.0)


def test_blocked_samples_hold_the_occluders(city: Path) -> None:
    """The support test (orthomvp/ortho/support.py) against the city's exact geometry: near
    occlusion boundaries, the samples it calls blocked have an occluder in them more than
    three times as often as those it clears."""
    from orthomvp.occlusion.visibility import occluder_caster
    from orthomvp.ortho.composite import doubtful
    from orthomvp.ortho.support import blocked, candidates, window_samples
    from orthomvp.synthetic.ghosts import occluder_share

    scene = make_scene("city", size=96)
    x, y = scene.post_local()
    posts = np.stack([x, y, scene.surface.height(x, y)], axis=-1)
    loaded = load_scene(city)
    views = [(loaded.views[n].image, scene.cameras[n]) for n in NAMES]
    vis = mosaic(scene.terrain, views).visibilities
    seen = np.array([v.codes == Code.VISIBLE for v in vis])
    tests = candidates(seen & ~np.array([doubtful(v.miss, v.eps) for v in vis]))
    caster, whole = occluder_caster(scene.terrain), (slice(None), slice(None))
    shares = {True: [], False: []}
    for k, (v, name) in enumerate(zip(vis, NAMES, strict=True)):
        camera = scene.cameras[name]
        samples = window_samples(v.uv, v.gsd)
        hit = blocked(scene.terrain, whole, camera, samples, v.emission, tests[k], caster)
        assert not (hit & ~tests[k]).any()
        for flag in (True, False):
            at = tests[k] & (hit == flag)
            shares[flag].append(occluder_share(scene, name, v.uv[at], posts[at]))
    dirty = {flag: float((np.concatenate(s) > 0).mean()) for flag, s in shares.items()}
    assert len(np.concatenate(shares[True])) > 50
    assert dirty[True] > 3 * dirty[False], dirty


def test_shun_moves_blocked_weight_to_the_others() -> None:
    """At a post blending a blocked and two clear views, the blocked one's weight goes to the
    others in proportion to theirs and the value is their blend; a post whose weighted views
    are all blocked, and one with a single view, stay as they were."""
    from orthomvp.ortho.support import shun

    weights = np.array([[[0.5, 1.0, 0.5]], [[0.25, 0.0, 0.5]], [[0.25, 0.0, 0.0]]], np.float32)
    values = np.array([[[[1.0, 1.0, 1.0]]], [[[2.0, 2.0, 2.0]]], [[[4.0, 4.0, 4.0]]]], np.float32)
    data = np.einsum("krc,kbrc->brc", weights, values).astype(np.float32)
    blocked = np.zeros(weights.shape, bool)
    blocked[0, 0, :] = True  # view 0: blocked everywhere
    blocked[1, 0, 2] = True  # post 2: both its views blocked
    asked = []
    before = data.copy()

    def support(posts: np.ndarray) -> np.ndarray:
        asked.append(posts.copy())
        return blocked & posts

    moved = shun(weights, data, values, None, support)
    np.testing.assert_array_equal(moved, [[True, False, False]])
    np.testing.assert_array_equal(asked[0][:, 0], [[1, 0, 1], [1, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(weights[:, 0, 0], [0.0, 0.5, 0.5])
    assert data[0, 0, 0] == 3.0
    np.testing.assert_array_equal(data[:, 0, 1:], before[:, 0, 1:])
    np.testing.assert_array_equal(weights[:, 0, 1:], [[1.0, 0.5], [0.0, 0.5], [0.0, 0.0]])


@pytest.mark.slow
def test_the_feather_avoids_partial_ghosts(city: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Against the city's exact geometry: with the feather's support test (shun), fewer of
    the posts each view gives weight to have an occluder in their sample (as rendered, one
    ray a pixel) than without it, in two views at least and more in none, with the same
    posts filled and no more weight from views whose truth occludes the post."""
    from orthomvp.ortho import composite
    from orthomvp.synthetic.ghosts import occluder_share

    scene = make_scene("city", size=96)
    x, y = scene.post_local()
    posts = np.stack([x, y, scene.surface.height(x, y)], axis=-1)
    loaded = load_scene(city)
    views = [(loaded.views[n].image, scene.cameras[n]) for n in NAMES]
    truth = np.array([loaded.views[n].truth for n in NAMES])
    shunned = mosaic(scene.terrain, views)
    monkeypatch.setattr(composite, "shun", lambda *args: None)
    plain = mosaic(scene.terrain, views)
    np.testing.assert_array_equal(np.isfinite(shunned.data), np.isfinite(plain.data))
    hiding = [int(((m.weights > 0) & (truth == Code.OCCLUDED)).sum()) for m in (plain, shunned)]
    assert hiding[1] <= hiding[0] <= 1, hiding  # (the trust test's one post on this city)
    fewer = 0
    for k, name in enumerate(NAMES):
        uv = shunned.visibilities[k].uv
        counts = []
        for got in (plain, shunned):
            used = got.weights[k] > 0
            share = occluder_share(scene, name, uv[used], posts[used], supersample=1)
            counts.append(int((share > 0).sum()))
        assert counts[1] <= counts[0], (name, counts)
        fewer += counts[1] < counts[0]
    assert fewer >= 2


def test_clear_pixels_remove_the_partial_ghosts(city: Path) -> None:
    """Against the city's exact geometry (as rendered, one ray a pixel): where a view with
    weight is still blocked after the feather's test, the mosaic takes the blend of its clear
    pixels (orthomvp.ortho.support.sharpen); those posts' samples held an occluder at 24
    posts of the four views, their clear pixels at none (at most a quarter asserted). Only
    posts with weight are resampled, and the values are those of clear_taps and clear_blend,
    recomputed here from the image; MosaicOptions(clear=False) gives the same fill, labels
    and weights, with other values exactly at the resampled posts."""
    from orthomvp.occlusion.visibility import occluder_caster
    from orthomvp.ortho.orthophoto import sample_image
    from orthomvp.ortho.support import clear_blend, clear_taps, window_samples
    from orthomvp.synthetic.ghosts import occluder_share

    scene = make_scene("city", size=96)
    x, y = scene.post_local()
    posts = np.stack([x, y, scene.surface.height(x, y)], axis=-1)
    loaded = load_scene(city)
    views = [(loaded.views[n].image, scene.cameras[n]) for n in NAMES]
    got = mosaic(scene.terrain, views)
    assert got.resampled is not None and not (got.resampled & (got.weights == 0)).any()
    caster, whole = occluder_caster(scene.terrain), (slice(None), slice(None))
    dirty = {"bilinear": 0, "clear": 0}
    for k, name in enumerate(NAMES):
        at, vis = got.resampled[k], got.visibilities[k]
        assert at.sum() > 20
        samples = window_samples(vis.uv, vis.gsd)
        taps, w = clear_taps(
            scene.terrain, whole, scene.cameras[name], samples, vis.emission, at, caster
        )
        assert (w.sum(axis=0) > 0).all()  # (a post with no clear pixel is not resampled)
        for how, weights in (("bilinear", None), ("clear", w)):
            share = occluder_share(
                scene, name, vis.uv[at], posts[at], supersample=1, weights=weights
            )
            dirty[how] += int((share > 0).sum())
        one = at & (got.weights.sum(axis=0) == got.weights[k])  # posts from this view alone
        image = loaded.views[name].image
        pixels = sample_image(image, taps.reshape(-1, 2), "nearest").reshape(1, *w.shape)
        mine = clear_blend(pixels.swapaxes(0, 1), w)[0][0]
        np.testing.assert_allclose(got.data[0][one], mine[one[at]], rtol=1e-6)
    assert dirty["bilinear"] >= 10 and dirty["clear"] <= dirty["bilinear"] / 4, dirty
    plain = mosaic(scene.terrain, views, options=MosaicOptions(clear=False))
    assert plain.resampled is None or not plain.resampled.any()
    np.testing.assert_array_equal(plain.flags, got.flags)
    np.testing.assert_array_equal(plain.weights, got.weights)
    moved = (plain.data != got.data).any(axis=0) & np.isfinite(got.data).all(axis=0)
    np.testing.assert_array_equal(moved, got.resampled.any(axis=0))


def test_clear_blend_and_the_heaviest_view() -> None:
    """clear_blend renormalises the weights of the pixels that have a value (NaN where none
    is left); where the feather's test moved the weights, the source names the view of
    largest weight (its label where that is as heavy), elsewhere the label."""
    from orthomvp.ortho.support import clear_blend, heaviest

    pixels = np.array([[[1.0, 1.0, 1.0]], [[3.0, np.nan, 3.0]], [[5.0, 5.0, 5.0]], [[7.0] * 3]])
    weights = np.array([[0.5, 0.0, 0.0], [0.25, 0.5, 0.0], [0.0, 0.5, 0.0], [0.25, 0.0, 0.0]])
    value, clear = clear_blend(pixels, weights)
    np.testing.assert_array_equal(value[0], [3.0, 5.0, np.nan])
    np.testing.assert_array_equal(clear, [1.0, 0.5, 0.0])
    label = np.array([[0, 1, 2, -1]])
    w = np.array([[[0.5, 0.2, 0.0, 0.0]], [[0.5, 0.3, 0.0, 0.0]], [[0.0, 0.5, 1.0, 0.0]]])
    np.testing.assert_array_equal(heaviest(label, w, np.ones((1, 4), bool)), [[0, 2, 2, -1]])
    moved = np.array([[True, False, True, True]])
    np.testing.assert_array_equal(heaviest(label, w, moved), [[0, 1, 2, -1]])


def test_fill_doubtful_takes_the_clearest_doubtful_view() -> None:
    """A hole that views see only doubtfully takes the clear-pixel sample of the view whose
    clear pixels weigh most, one-hot, labelled with it; a hole whose doubtful views have no
    clear pixel, and a post a trusted view gives, stay as they were."""
    from orthomvp.ortho.support import fill_doubtful

    data = np.array([[[np.nan, np.nan, 9.0]]], np.float32)
    label = np.array([[-1, -1, 0]])
    weights = np.array([[[0.0, 0.0, 1.0]], [[0.0, 0.0, 0.0]]], np.float32)
    doubtful = np.array([[[True, True, True]], [[True, False, False]]])
    asked = []

    def resample(posts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        asked.append(posts.copy())  # posts in np.nonzero order: (0,0,0), (0,0,1), (1,0,0)
        return np.array([[1.0, 2.0, 3.0]], np.float32), np.array([0.25, 0.0, 0.5])

    got = fill_doubtful(data, label, weights, doubtful, resample)
    np.testing.assert_array_equal(asked[0], [[[True, True, False]], [[True, False, False]]])
    np.testing.assert_array_equal(got, [[True, False, False]])
    np.testing.assert_array_equal(data[0, 0], [3.0, np.nan, 9.0])
    np.testing.assert_array_equal(label, [[1, -1, 0]])
    np.testing.assert_array_equal(weights[:, 0, 0], [0.0, 1.0])


def test_no_clear_pixels_on_the_command_line(city: Path, tmp_path: Path) -> None:
    """--no-clear-pixels gives the mosaic of MosaicOptions(clear=False); the default differs
    from it at a few posts only; a non-boolean clear is an InputError."""
    pairs = [str(city / f"{n}.{e}") for n in NAMES for e in ("tif", "tsai")]
    base = ["-q", "mosaic", str(city / "dem.tif"), *pairs, "--grid", "dem"]
    assert main([*base, "-o", str(tmp_path / "a.tif"), "--no-clear-pixels"]) == 0
    assert main([*base, "-o", str(tmp_path / "b.tif")]) == 0
    scene = load_scene(city)
    views = [(scene.views[n].image, scene.views[n].camera) for n in NAMES]
    plain = mosaic(scene.terrain, views, options=MosaicOptions(clear=False))
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        off, on = a.read(), b.read()
    np.testing.assert_allclose(off, plain.data, rtol=1e-6, equal_nan=True)
    moved = (off != on).any(axis=0) & np.isfinite(on).all(axis=0)
    assert 0 < moved.sum() < 0.05 * np.isfinite(on).all(axis=0).sum()
    with pytest.raises(InputError, match="clear must be True or False"):
        MosaicOptions(clear=1)
