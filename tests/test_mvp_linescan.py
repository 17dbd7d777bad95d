"""The MVP fit through cameras that are not pinholes: two line scanners over the crater
(per-post local projection matrices, :mod:`orthomvp.mvp.local`) against the analytic truth
and against frame cameras of the same geometry; the tiled engine against the in-memory fit;
a pinhole and a line scanner together."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from scipy import ndimage

from orthomvp.camera import load_view
from orthomvp.camera.csm import write_isd
from orthomvp.engine import FitOutputs, plan_fit, run_fit
from orthomvp.geometry.terrain import Terrain
from orthomvp.mvp import FitOptions, fit_dem
from orthomvp.mvp.local import ERROR_BOUND, local_projections
from orthomvp.synthetic import make_scene
from orthomvp.synthetic.cameras import ViewSpec
from orthomvp.synthetic.linescan import orbital_line_scanner

OPTIONS = FitOptions(levels=2)
"""The default patches (hwin 10, whose local matrices stay within the bound here: 0.03 and
0.06 px), and two levels (the coarsest patch inside these small images)."""
FORE = ViewSpec("fore", 18.0, 0.0)
"""The second view: the frame crater's fore geometry, flown as a line scanner."""


def _scene(sensor: str) -> dict:
    scene = make_scene("crater", size=64, spacing=80.0, sensor=sensor)
    if sensor == "linescan":
        cams = [scene.cameras["linescan"], orbital_line_scanner(scene.terrain, FORE, scene.gsd)]
    else:
        cams = [scene.cameras["oblique"], scene.cameras["fore"]]
    truth = scene.terrain.values
    start = scene.terrain.with_values(ndimage.gaussian_filter(truth, 2) + 15.0)
    images = [scene.render(cam, 2) for cam in cams]
    return {"scene": scene, "cams": cams, "images": images, "start": start}


@pytest.fixture(scope="module")
def linescan() -> dict:
    return _scene("linescan")


def _scores(data: dict, res) -> tuple[float, float, float]:  # noqa: ANN001
    """(fraction resolved, RMSE, median |error| in ground pixels) of posts 8 from the border."""
    truth = data["scene"].terrain.values
    inner = np.zeros(truth.shape, bool)
    inner[8:-8, 8:-8] = True
    ok = res.resolved & inner
    err = (res.heights - truth)[ok]
    return (
        ok.sum() / inner.sum(),
        float(np.sqrt(np.mean(err**2))),
        float(np.median(np.abs(err)) / data["scene"].gsd),
    )


def test_local_matrices_reproduce_the_line_scanner(linescan: dict) -> None:
    """Over each post's finest patch at the default hwin (hwin posts either way, heights +-
    hwin spacings; posts whose patch lies in the image), the local matrix reprojects random
    points (not its lattice) within ERROR_BOUND of the line scanner's own projection, for
    both line scanners; the reported errors agree."""
    scene, rng = linescan["scene"], np.random.default_rng(0)
    terrain, hwin = scene.terrain, OPTIONS.hwin
    r, c = (x.ravel().astype(float) for x in np.mgrid[12:53:5, 12:53:5])
    h = terrain.values[r.astype(int), c.astype(int)]
    for cam in linescan["cams"]:
        P, errors = local_projections(cam, terrain, c, r, h, hwin=hwin, spacing=scene.spacing)
        assert np.isfinite(P).all() and (errors > 1e-4).all() and (errors <= ERROR_BOUND).all()
        d = rng.uniform(-1, 1, (len(c), 50, 3))
        xyz = terrain.to_world(
            c[:, None] + hwin * d[..., 0],
            r[:, None] + hwin * d[..., 1],
            h[:, None] + hwin * scene.spacing * d[..., 2],
        )
        uv, _ = cam.project(xyz)
        p = np.einsum("bij,bnj->bni", P, np.concatenate([xyz, np.ones((*xyz.shape[:2], 1))], -1))
        miss = np.linalg.norm(p[..., :2] / p[..., 2:] - uv, axis=-1).max(axis=1)
        assert (miss <= errors * 1.05 + 1e-6).all()


@pytest.mark.parametrize("hwin", [FitOptions().hwin, 5])
def test_line_scan_fit_matches_the_frame_fit(linescan: dict, hwin: int) -> None:
    """Two line scanners recover the crater from a smoothed, offset DEM as well as frame
    cameras of the same geometry (within 5% in RMSE and median error), at the default hwin
    and at 5; at 5 (whose patches resolve the crater's walls; the default's smooth them for
    either kind of camera) better than the start where it is not occluded (median error)."""
    frame, options = _scene("frame"), replace(OPTIONS, hwin=hwin)
    got = {}
    for name, data in (("linescan", linescan), ("frame", frame)):
        res = fit_dem(data["start"], data["images"], data["cams"], options, threads=2)
        got[name] = _scores(data, res)
    (f_ls, rmse_ls, med_ls), (f_fr, rmse_fr, med_fr) = got["linescan"], got["frame"]
    assert f_ls > 0.8 and abs(f_ls - f_fr) < 0.05
    assert rmse_ls < 1.05 * rmse_fr and med_ls < 1.05 * med_fr
    if hwin == 5:
        start = np.abs(linescan["start"].values - linescan["scene"].terrain.values)
        assert med_ls < 0.9 * np.median(start[8:-8, 8:-8]) / linescan["scene"].gsd


def test_mixed_pinhole_and_line_scanner(linescan: dict) -> None:
    """A frame camera and a line scanner of the same geometry fit together as well as two
    line scanners do."""
    frame = make_scene("crater", size=64, spacing=80.0)
    cam = frame.cameras["fore"]
    cams = [linescan["cams"][0], cam]
    images = [linescan["images"][0], frame.render(cam, 2)]
    res = fit_dem(linescan["start"], images, cams, OPTIONS, threads=2)
    both = fit_dem(linescan["start"], linescan["images"], linescan["cams"], OPTIONS, threads=2)
    f_mix, rmse_mix, med_mix = _scores(linescan, res)
    f_ls, rmse_ls, med_ls = _scores(linescan, both)
    assert f_mix > 0.8 and rmse_mix < 1.15 * rmse_ls and med_mix < 1.15 * med_ls


def test_tiled_line_scan_fit_equals_the_in_memory_fit(linescan: dict, tmp_path: Path) -> None:
    """Tiles of 16 posts from windows of the line scanners' images give the in-memory fit's
    heights and views bit for bit."""
    paths = []
    for k, (cam, image) in enumerate(zip(linescan["cams"], linescan["images"], strict=True)):
        path = tmp_path / f"ls{k}.tif"
        with rasterio.open(
            path, "w", driver="GTiff", width=image.shape[1], height=image.shape[0], count=1,
            dtype="float32",
        ) as dst:  # fmt: skip
            dst.write(image.astype(np.float32), 1)
        write_isd(cam, tmp_path / f"ls{k}.json")
        paths.append((path, tmp_path / f"ls{k}.json"))
    linescan["start"].write(tmp_path / "start.tif")
    start = Terrain.read(tmp_path / "start.tif")
    loaded = [load_view(*p) for p in paths]  # the cameras as the engine reads them
    res = fit_dem(start, [v[0] for v in loaded], [v[1] for v in loaded], OPTIONS, threads=2)
    plan = plan_fit(tmp_path / "start.tif", paths, OPTIONS, tile=16, progress=False)
    outputs = FitOutputs(tmp_path / "h.tif", views=tmp_path / "v.tif")
    report = run_fit(plan, outputs, threads=2, progress=False)
    with rasterio.open(tmp_path / "h.tif") as src:
        np.testing.assert_array_equal(src.read(1), res.heights.astype(np.float32))
    with rasterio.open(tmp_path / "v.tif") as src:
        np.testing.assert_array_equal(src.read(1), res.views)
    assert report.fitted == res.resolved.sum() > 2000
