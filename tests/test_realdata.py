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
