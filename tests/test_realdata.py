"""Real data from ../shared/data (skipped when it is absent)."""

from __future__ import annotations

import itertools

import numpy as np

from orthomvp.camera import read_camera
from orthomvp.ortho import check_image, orthorectify
from orthomvp.raster import read_image
from orthomvp.terrain import Terrain
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
