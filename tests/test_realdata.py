"""Real data from ../shared/data (skipped when it is absent)."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from scipy.ndimage import gaussian_filter
from scipy.ndimage import shift as nd_shift

from orthomvp.camera import check_image, load_view, read_camera
from orthomvp.cli import main
from orthomvp.codes import Code
from orthomvp.errors import InputError
from orthomvp.geometry.terrain import Terrain
from orthomvp.io.raster import read_image
from orthomvp.ortho.orthophoto import orthorectify
from tests.conftest import shared


def apollo_orthos(shift: float = 0.0) -> list[np.ndarray]:
    """Orthophotos of the four Apollo 15 views on the ground DEM (shifted up by ``shift``)."""
    d = shared("apollo15-mvp")
    terrain = Terrain.read(d / "ground-dem.tif")
    terrain = terrain.with_values(terrain.values + shift)
    out = []
    for k in range(4):
        image = read_image(d / f"image{k}.tif")[:1]  # band 2 is a weight band
        camera = check_image(image, read_camera(d / f"camera{k}.pinhole"))
        out.append(orthorectify(terrain, image, camera).data[0])
    return out


def pairwise(orthos: list[np.ndarray]) -> list[float]:
    out = []
    for a, b in itertools.combinations(orthos, 2):
        both = np.isfinite(a) & np.isfinite(b)
        out.append(float(np.corrcoef(a[both], b[both])[0, 1]))
    return out


@pytest.mark.realdata
def test_apollo15_orthophotos_agree() -> None:
    """Measured: pairwise r = 0.75..0.84, mean 0.80 (the data README says about 0.8)."""
    orthos = apollo_orthos()
    assert all(np.isfinite(o).all() for o in orthos)  # every post visible in every view
    corr = pairwise(orthos)
    assert min(corr) > 0.7 and np.mean(corr) > 0.78, corr
    # a DEM 300 m too high misregisters the views: agreement drops
    assert np.mean(pairwise(apollo_orthos(300.0))) < np.mean(corr) - 0.05


def _apollo_fit(shift: float, **options: object):  # noqa: ANN202
    from orthomvp.mvp import FitOptions, fit_dem

    d = shared("apollo15-mvp")
    ground = Terrain.read(d / "ground-dem.tif")
    images = [read_image(d / f"image{k}.tif")[:1] for k in range(4)]
    cams = [read_camera(d / f"camera{k}.pinhole") for k in range(4)]
    start = ground.with_values(ground.values + shift)
    return ground, fit_dem(start, images, cams, FitOptions(**options))


@pytest.mark.slow
@pytest.mark.realdata
def test_apollo15_fit_recovers_a_100_m_shift() -> None:
    """From the ground DEM raised by 100 m, the fit comes back: measured median residual
    +3.1 m (of 100 m). Mean pairwise patch correlation (1 - f / (n - 1), all four views,
    hwin 10, sigma 5): 0.51 at the raised DEM, 0.55 at the ground DEM, 0.60 after the fit."""
    ground, res = _apollo_fit(100.0)
    ok = res.resolved
    assert ok.sum() > 0.85 * ok.size
    residual = np.median((res.heights - ground.values)[ok])
    assert abs(residual) < 10.0, residual
    # agreement of the four views' patches, all views kept, before and after
    frozen = {"max_iter": 0, "levels": 1, "reject_below": None, "deconvolve": 0}
    _, before = _apollo_fit(100.0, **frozen)
    _, at_ground = _apollo_fit(0.0, **frozen)
    _, after = _apollo_fit(100.0, reject_below=None)
    both = before.resolved & after.resolved & at_ground.resolved

    def agreement(r) -> float:  # noqa: ANN001
        return float(np.mean(1 - r.cost[both] / (r.views[both] - 1)))

    assert agreement(before) < agreement(at_ground) - 0.02
    assert agreement(after) > agreement(at_ground)


# ------------------------------------------------------------------------------- ngi-aerial
NGI_FRAMES = (
    "3324c_2015_1004_05_0182_RGB",
    "3324c_2015_1004_05_0184_RGB",
    "3324c_2015_1004_06_0251_RGB",
    "3324c_2015_1004_06_0253_RGB",
)


@pytest.mark.realdata
def test_ngi_aerial_orthophotos_and_mosaic_through_the_cli(tmp_path: Path) -> None:
    """Orthority's own camera files, world frame detected (map). Measured: 41,947..43,524
    posts filled per frame; 42,029..43,636 visible, 0..18 occluded, 0..32 facing away (gentle
    terrain seen near nadir); the 6 overlapping pairs agree with r = 0.79..0.97 in
    band 1 (mean 0.89; 0.64..0.96 in band 3, 0.74..0.96 grey; 4,917..17,409 common posts);
    the mosaic takes 28,700..30,439 posts from each frame, and all visible posts but 2 that
    only doubtful views see."""
    d = shared("ngi-aerial")
    dem, exterior = d / "dem.tif", d / "orthority-format" / "ngi_xyz_opk.csv"
    orthos, codes = [], []
    for name in NGI_FRAMES:
        out, vis = tmp_path / f"{name}.tif", tmp_path / f"{name}.vis.tif"
        args = ["-q", "ortho", str(dem), str(d / f"{name}.tif"), str(exterior), "-o", str(out)]
        args += ["--grid", "dem"]  # the figures above are of the DEM's grid
        assert main([*args, "--visibility", str(vis)]) == 0
        orthos.append(read_image(out))
        codes.append(read_image(vis)[0])
    for data, code in zip(orthos, codes, strict=True):
        filled = np.isfinite(data).all(axis=0)
        inside = np.nan_to_num(code) > 0
        assert data.shape[0] == 3 and filled.sum() > 40_000
        assert not filled[code != Code.VISIBLE].any()  # only visible posts get values
        assert (code == Code.VISIBLE).sum() > 0.99 * inside.sum()  # gentle terrain, near nadir
    corr = pairwise([o[0] for o in orthos])  # band 1 (red)
    assert min(corr) > 0.75 and np.mean(corr) > 0.85, corr
    pairs = [str(p) for name in NGI_FRAMES for p in (d / f"{name}.tif", exterior)]
    out, source = tmp_path / "mosaic.tif", tmp_path / "source.tif"
    hard = ["--no-seamlines", "--blend", "0"]  # each post from its best view alone
    assert (
        main(
            [
                "-q",
                "mosaic",
                str(dem),
                *pairs,
                "-o",
                str(out),
                "--source",
                str(source),
                *hard,
                "--grid",
                "dem",
            ]
        )
        == 0
    )
    mosaic, src = read_image(out), np.nan_to_num(read_image(source)[0]).astype(int)
    counts = np.bincount(src.ravel(), minlength=5)
    assert (counts[1:] > 25_000).all()
    union = np.any([np.isfinite(o).all(axis=0) for o in orthos], axis=0)
    assert not (src > 0)[~union].any()
    # posts that only views doubtful there see (first hit in the last half post of epsilon)
    # stay empty: 2, both next to the few occluded posts
    assert (union & (src == 0)).sum() <= 2
    # each post is the frame's orthophoto, but where the frame's sample reaches an occluder
    # within 3 posts of its occlusion boundary (the clear pixels of orthomvp.ortho.support;
    # 543 of 117,495 posts here, all beside a post the frame does not see)
    box = np.ones((7, 7), np.uint8)
    changed = 0
    for k, (data, code) in enumerate(zip(orthos, codes, strict=True), start=1):
        at = src == k
        same = (mosaic[:, at] == data[:, at]).all(axis=0)
        unseen = (np.nan_to_num(code) != Code.VISIBLE).astype(np.uint8)
        near = cv2.dilate(unseen, box, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        assert near[at][~same].all()
        changed += int((~same).sum())
    assert changed < 0.005 * (src > 0).sum(), changed


def inner_box(mask: np.ndarray) -> tuple[slice, slice]:
    """A rectangle inside ``mask``: its bounding box, shrunk one edge row or column at a time
    (the edge with the most posts outside ``mask``) until every post is inside."""
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    while not mask[r0:r1, c0:c1].all():
        m = ~mask[r0:r1, c0:c1]
        edges = [m[0].sum(), m[-1].sum(), m[:, 0].sum(), m[:, -1].sum()]
        k = int(np.argmax(edges))
        r0, r1, c0, c1 = (r0 + (k == 0), r1 - (k == 1), c0 + (k == 2), c1 - (k == 3))
    return slice(r0, r1), slice(c0, c1)


def phase_shift(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Shift (dx, dy) in pixels of ``b`` relative to ``a`` (b(x) = a(x - dx)), by phase
    correlation on the largest :func:`inner_box` of ``mask`` (Hann window): the integer peak of
    the phase correlation, then the slope of the cross-power spectrum's phase over frequencies
    below 0.15 cycles per pixel, fitted by magnitude-weighted least squares."""
    box = inner_box(mask)
    a, b = (x[box].astype(np.float64) for x in (a, b))
    window = np.outer(np.hanning(a.shape[0]), np.hanning(a.shape[1]))
    cross = np.conj(np.fft.fft2((a - a.mean()) * window)) * np.fft.fft2((b - b.mean()) * window)
    peak = np.fft.ifft2(cross / np.maximum(np.abs(cross), 1e-300)).real
    iy, ix = np.unravel_index(np.argmax(peak), peak.shape)
    iy, ix = (i - n if i > n // 2 else i for i, n in ((iy, a.shape[0]), (ix, a.shape[1])))
    fy, fx = np.meshgrid(np.fft.fftfreq(a.shape[0]), np.fft.fftfreq(a.shape[1]), indexing="ij")
    cross = cross * np.exp(2j * np.pi * (fx * ix + fy * iy))
    low = (np.hypot(fx, fy) < 0.15) & (np.hypot(fx, fy) > 0)
    w = np.sqrt(np.abs(cross[low]))
    design = -2 * np.pi * np.column_stack([fx[low], fy[low]]) * w[:, None]
    (dx, dy), *_ = np.linalg.lstsq(design, np.angle(cross[low]) * w, rcond=None)
    return np.array([ix + dx, iy + dy])


def test_phase_shift_measures_known_shifts() -> None:
    rng = np.random.default_rng(0)
    a = gaussian_filter(rng.random((200, 160)), 2.0)
    mask = np.ones(a.shape, bool)
    mask[:30] = False
    for dx, dy in [(0.0, 0.0), (0.3, -0.2), (1.0, 0.5), (-3.4, 2.25)]:
        b = nd_shift(a, (dy, dx), order=3, mode="nearest")
        np.testing.assert_allclose(phase_shift(a, b, mask), [dx, dy], atol=0.02)


@pytest.mark.realdata
def test_ngi_aerial_agrees_with_orthority(tmp_path: Path) -> None:
    """The same frame onto the same grid (the DEM's CRS, 24 m posts, Orthority's bounds) with
    both tools, bilinear both. Where orthomvp calls a post visible and both have data, they agree
    exactly: measured shift 0.000 px, r = 1.000 and largest difference 0 DN in every band of
    all 4 frames (both sample the same positions with cv2.remap; Orthority's principal point is
    at ((w - 1) / 2, (h - 1) / 2) in pixel-centre coordinates, as the converted .tsai has it).
    Orthority reads a copy of the DEM whose CRS is only the horizontal part of 'Lo25 WGS84 +
    EGM2008 height', so it needs no geoid grid from the network; both tools take the DEM
    values as the cameras' z. (On a 6 m grid, where the DEM is interpolated, bilinearly by
    Orthority and on the mesh triangles by orthomvp, measured r >= 0.9996 and shifts <= 0.02 px.)
    """
    from orthomvp.bench import PeerCase, horizontal_dem, import_orthority, run_orthority

    try:
        import_orthority()
    except InputError as exc:
        pytest.skip(f"the peer tool is absent: {exc}")
    d = shared("ngi-aerial")
    params = d / "orthority-format"
    dem = horizontal_dem(d / "dem.tif", tmp_path / "dem.tif")
    terrain = Terrain.read(dem, world="map")
    for name in NGI_FRAMES:
        case = PeerCase(name, dem, d / f"{name}.tif", params / "ngi_int_param.yaml",
                        params / "ngi_xyz_opk.csv")  # fmt: skip
        image, camera = load_view(case.image, case.exterior)
        ours = orthorectify(terrain, image, camera)
        out = tmp_path / f"{name}.oty.tif"
        run_orthority(case, out, 24.0)
        theirs = np.full_like(ours.data, np.nan)
        with rasterio.open(out) as ds:
            col, row = ~terrain.transform @ (ds.transform.c, ds.transform.f)
            assert ds.transform.a == 24.0 and col == round(col) and row == round(row)
            window = (
                slice(round(row), round(row) + ds.height),
                slice(round(col), round(col) + ds.width),
            )
            theirs[:, window[0], window[1]] = ds.read()
        both = (ours.visibility.codes == Code.VISIBLE) & np.isfinite(ours.data).all(0)
        both &= np.isfinite(theirs).all(0)
        assert both.sum() > 40_000
        for a, b in zip(ours.data, theirs, strict=True):
            assert np.corrcoef(a[both], b[both])[0, 1] > 0.99
            assert np.abs(phase_shift(a, b, both)).max() < 0.5


# ------------------------------------------------------------------------------ as15-hadley
@pytest.mark.realdata
def test_as15_hadley_orthophoto_from_the_isis_cube() -> None:
    """The real Apollo 15 Metric frame (ISIS cube) onto the LOLA DEM (189 x 204 posts of
    about 110 m). Measured: 31,826 posts in the frame (89% of the DEM's 35,613 valid posts),
    all visible: 0 occluded, 0 facing away; 31,779 get a value (the rest lie within half a
    pixel of the image border); emission 0.7..57.9 degrees (median 26.8). No occlusion is
    possible here: the camera is 22.5 degrees off nadir, every line of sight rises at least
    61.1 degrees above the local horizontal, and the steepest DEM slope (the walls of Hadley
    Rille and the massifs) is 37.4 degrees, so no terrain can rise into a line of sight. Every
    visible post's ray comes back to it within 2e-5 posts (768 rays near the DEM's holes and
    borders hit nothing, which also means visible)."""
    d = shared("as15-hadley")
    terrain = Terrain.read(d / "LOLA_hadley_dem.tif")
    image = read_image(d / "AS15-M-1134-hadley.cub")
    camera = check_image(image, read_camera(d / "AS15-M-1134-hadley.converted.tsai"))
    ortho = orthorectify(terrain, image, camera)
    vis = ortho.visibility
    counts = vis.counts()
    inside = vis.codes > 0
    assert inside.sum() > 0.85 * terrain.valid.sum()
    # the geometry: lowest line-of-sight elevation against the steepest slope
    p = terrain.world_points()
    up = terrain.up_vectors(p)
    sight = camera.center - p
    sight /= np.linalg.norm(sight, axis=-1, keepdims=True)
    elevation = np.degrees(np.arcsin(np.einsum("...i,...i->...", sight, up)))[inside].min()
    normals_up = np.einsum("...i,...i->...", terrain.normals(), up)
    slope = np.degrees(np.arccos(np.clip(normals_up, -1, 1)))
    assert np.nanmax(slope) < elevation - 20
    assert counts["occluded"] == 0 and counts["facing away"] == 0
    assert counts["visible"] == inside.sum()
    hit = vis.miss[vis.codes == Code.VISIBLE]
    assert np.max(hit[np.isfinite(hit)]) < 1e-3 and np.isfinite(hit).mean() > 0.95
    filled = np.isfinite(ortho.data[0])
    assert filled.sum() > 0.99 * counts["visible"] and not filled[~inside].any()
    assert 0 < np.nanmin(vis.emission[inside]) < 5 and 50 < np.nanmax(vis.emission[inside]) < 65
