"""pyproj transformers made once a process and used from every worker thread
(orthomvp.geometry.crs.cheap_per_thread): the same numbers as pyproj's transformer between the
two CRSs, in new threads and after pickling, without searching PROJ's database again."""

from __future__ import annotations

import pickle
import threading
from collections.abc import Callable

import numpy as np
import pytest
from pyproj import CRS, Transformer
from pyproj import transformer as pyproj_transformer

from orthomvp.camera.rpc import _to_wgs84
from orthomvp.geometry.crs import cheap_per_thread, geocentric_transformer, lonlat_transformer
from tests.test_datum import EGM96, needs_egm96

LO25 = "+proj=tmerc +lat_0=0 +lon_0=25 +k=1 +x_0=0 +y_0=0 +axis=wsu +ellps=WGS84 +units=m +no_defs"
MARS = "+proj=eqc +lat_ts=0 +lon_0=0 +a=3396190 +b=3376200 +units=m +no_defs"


def points(low: tuple[float, float, float], high: tuple[float, float, float]) -> np.ndarray:
    """1,000 points (x, y, z) uniform within ``low`` and ``high``, fixed seed."""
    return np.random.default_rng(7).uniform(low, high, (1000, 3))


def in_thread(fn: Callable[[], object]) -> object:
    """``fn()`` run in a new thread: its result."""
    out: list[object] = []
    worker = threading.Thread(target=lambda: out.append(fn()))
    worker.start()
    worker.join()
    return out[0]


# (what is made, the transformer pyproj makes between the same CRSs, points in its domain)
CASES = {
    "projected to lon/lat (South African Lo25, westing-southing axes)": (
        lambda: lonlat_transformer(CRS.from_proj4(LO25)),
        lambda: Transformer.from_crs(
            CRS.from_proj4(LO25), CRS.from_proj4(LO25).geodetic_crs, always_xy=True
        ),
        points((-1e5, 3.6e6, 0), (1e5, 3.8e6, 0)),
    ),
    "UTM to geocentric on WGS84": (
        lambda: geocentric_transformer(CRS.from_epsg(32633), (6378137.0, 6356752.314245179)),
        lambda: Transformer.from_crs(
            CRS.from_epsg(4326).to_3d(),
            CRS.from_proj4("+proj=geocent +a=6378137.0 +b=6356752.314245179 +units=m"),
            always_xy=True,
        ),
        points((10, -60, -400), (20, 70, 8000)),
    ),
    "lat/lon axis order to geocentric": (
        lambda: geocentric_transformer(CRS.from_epsg(4326), (6378137.0, 6356752.314245179)),
        lambda: Transformer.from_crs(
            CRS.from_epsg(4979),
            CRS.from_proj4("+proj=geocent +a=6378137.0 +b=6356752.314245179 +units=m"),
            always_xy=True,
        ),
        points((-180, -89, -400), (180, 89, 8000)),
    ),
    "Mars equirectangular to lon/lat": (
        lambda: lonlat_transformer(CRS.from_proj4(MARS)),
        lambda: Transformer.from_crs(
            CRS.from_proj4(MARS), CRS.from_proj4(MARS).geodetic_crs, always_xy=True
        ),
        points((-1e7, -5e6, 0), (1e7, 5e6, 0)),
    ),
    "Mars ellipsoid to geocentric": (
        lambda: geocentric_transformer(CRS.from_proj4(MARS), (3396190.0, 3376200.0)),
        lambda: Transformer.from_crs(
            CRS.from_proj4(MARS).geodetic_crs.to_3d(),
            CRS.from_proj4("+proj=geocent +a=3396190.0 +b=3376200.0 +units=m"),
            always_xy=True,
        ),
        points((-180, -89, -8000), (180, 89, 21000)),
    ),
    "an RPC camera's world (UTM) to WGS84": (
        lambda: _to_wgs84(CRS.from_epsg(32634)),
        lambda: Transformer.from_crs(
            CRS.from_epsg(32634).to_3d(), CRS.from_epsg(4979), always_xy=True
        ),
        points((3e5, 6.6e6, -100), (7e5, 7.0e6, 3000)),
    ),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_same_numbers_in_new_threads_and_after_pickling(case: str) -> None:
    """Forward and inverse, exactly pyproj's numbers between the two CRSs: in this thread, in a
    new thread (where pyproj makes its PROJ object again) and from a pickled copy."""
    made, reference, xyz = CASES[case]
    mine, theirs = made(), reference()
    for direction in ("FORWARD", "INVERSE"):
        if direction == "INVERSE":
            xyz = np.stack(theirs.transform(*xyz.T), axis=-1)
        want = np.stack(theirs.transform(*xyz.T, direction=direction), axis=-1)
        assert np.isfinite(want).all()
        for transformer in (mine, pickle.loads(pickle.dumps(mine))):
            here = np.stack(transformer.transform(*xyz.T, direction=direction), axis=-1)
            there = in_thread(
                lambda t=transformer, p=xyz, d=direction: np.stack(
                    t.transform(*p.T, direction=d), -1
                )
            )
            np.testing.assert_array_equal(here, want)
            np.testing.assert_array_equal(there, want)


def test_a_new_thread_does_not_search_the_database(monkeypatch: pytest.MonkeyPatch) -> None:
    """pyproj remakes a transformer between two CRSs in every thread by searching PROJ's
    database; the transformers made once a process are remade from their PROJ string."""
    transformers = [case[0]() for case in CASES.values()]
    searches: list[object] = []
    search = pyproj_transformer.TransformerFromCRS.__call__
    monkeypatch.setattr(
        pyproj_transformer.TransformerFromCRS,
        "__call__",
        lambda self: searches.append(self) or search(self),
    )
    for transformer in transformers:
        in_thread(lambda t=transformer: t.transform(0.0, 0.0, 0.0))
    assert searches == []
    # (the check can fail: pyproj's own transformer searches again in a new thread)
    in_thread(lambda: CASES["UTM to geocentric on WGS84"][1]().transform(0.0, 0.0, 0.0))
    assert searches


def test_a_geoid_transformer_gives_pyproj_numbers() -> None:
    """EGM96 heights to WGS84 (the grid from Debian's proj-data): the same numbers as the first
    of pyproj's transformations that need no ballpark, in a new thread too."""
    needs_egm96()
    from pyproj.crs import CompoundCRS
    from pyproj.transformer import TransformerGroup

    from orthomvp.geometry.datum import geoid_transformer

    compound = CompoundCRS("utm + egm96", [CRS.from_epsg(32634), CRS.from_epsg(EGM96)])
    target = CRS.from_epsg(4979)
    theirs = TransformerGroup(compound, target, always_xy=True, allow_ballpark=False)
    mine = geoid_transformer(compound, "test", target)
    xyz = points((3e5, 6.6e6, -100), (7e5, 7.0e6, 3000))
    want = np.stack(theirs.transformers[0].transform(*xyz.T), axis=-1)
    np.testing.assert_array_equal(np.stack(mine.transform(*xyz.T), axis=-1), want)
    there = in_thread(lambda: np.stack(mine.transform(*xyz.T), axis=-1))
    np.testing.assert_array_equal(there, want)


def test_several_candidate_operations_are_left_to_pyproj() -> None:
    """ED50 to WGS84 has several operations, chosen point by point by their areas: no single
    PROJ string gives it, and the transformer is returned as it is."""
    transformer = Transformer.from_crs(CRS.from_epsg(4230), CRS.from_epsg(4326), always_xy=True)
    assert cheap_per_thread(transformer) is transformer
