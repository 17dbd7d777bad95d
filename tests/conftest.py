"""Shared test fixtures: the real-data directory and small synthetic scenes made once.

The real data lives in the directory named by the ORTHOMVP_DATA environment variable, by
default ``../shared/data`` beside the repository; tests that need it are marked ``realdata``
and skip when it is absent.
"""

from __future__ import annotations

import functools
import os
import shutil
from pathlib import Path
from types import ModuleType

import pytest

SHARED_DATA = Path(
    os.environ.get("ORTHOMVP_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data"
).absolute()


def shared(*parts: str) -> Path:
    """A path under the real-data directory; skips the test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(
            f"real data not available: {path} is absent "
            "(set ORTHOMVP_DATA to the data directory; default ../shared/data)"
        )
    return path


@functools.cache
def open3d_missing() -> str | None:
    """Why Open3D cannot be imported (on Debian, without the system library libusb-1.0, it
    fails with an OSError), or None when it can."""
    try:
        import open3d  # noqa: F401
    except (ImportError, OSError) as exc:
        return (
            f"Open3D cannot be imported ({exc}); on Debian or Ubuntu: apt-get install libusb-1.0-0"
        )
    return None


def require_open3d() -> ModuleType:
    """The open3d module; skips the test, saying why, when it cannot be imported."""
    if reason := open3d_missing():
        pytest.skip(reason)
    import open3d

    return open3d


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests run on the Open3D ray-casting backend skip when Open3D cannot be imported."""
    on_open3d = [
        item
        for item in items
        if getattr(item, "callspec", None) and item.callspec.params.get("backend") == "open3d"
    ]
    if on_open3d and (reason := open3d_missing()):
        for item in on_open3d:
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(scope="session")
def crater_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small crater scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("crater")
    make_scene("crater", size=64, spacing=80.0).write(out, supersample=2)
    return out


@pytest.fixture(scope="session")
def city_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small city scene written once per test session."""
    from orthomvp.synthetic import make_scene

    out = tmp_path_factory.mktemp("city")
    make_scene("city", size=64).write(out, supersample=1)
    return out


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="needs Debian's chromium and chromium-driver (.ci/run installs them)",
)


def chromium(width: int = 1000, height: int = 900, *, offline: bool = False):  # noqa: ANN201
    """A headless Chromium WebDriver (Debian's chromium and chromium-driver) that keeps the
    console log and the network requests (performance log); WebGL through SwiftShader;
    ``offline``: every host name fails to resolve (no network)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    flags = [
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        f"--window-size={width},{height}",
    ]
    if offline:
        flags.append("--host-resolver-rules=MAP * ~NOTFOUND")
    for flag in flags:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))


def hover_map(driver, x: float, y: float):  # noqa: ANN001, ANN201
    """Move the pointer of the viewer page in ``driver`` over map point (x, y); returns the
    ActionChains at that point (``.click().perform()`` clicks there)."""
    from selenium.webdriver.common.action_chains import ActionChains

    mapel = driver.find_element("id", "map")
    px, py = driver.execute_script(
        "const p = orthomvpView.map.latLngToContainerPoint([arguments[1], arguments[0]]);"
        "return [p.x, p.y];",
        x,
        y,
    )
    w, h = mapel.size["width"], mapel.size["height"]
    offset = (int(round(px - w / 2)), int(round(py - h / 2)))
    ActionChains(driver).move_to_element_with_offset(mapel, *offset).perform()
    return ActionChains(driver).move_to_element_with_offset(mapel, *offset)


VIEW_NAMES = ("oblique", "nadir", "fore", "aft")
"""The crater scene's views, in the order the viewer tests give them."""
VIEW_START_OFFSET = 25.0
"""Metres: the viewer tests' DEM is the crater's truth raised by this much (a fit's start)."""
VIEW_SIGMA = 1.5
"""Metres: the viewer tests' constant uncertainty raster."""


@pytest.fixture(scope="session")
def view_scene(crater_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The crater scene with a DEM VIEW_START_OFFSET above the truth (the fit's start), the truth
    as the "fitted" DEM, a constant uncertainty and a source raster of views 0..4."""
    out = tmp_path_factory.mktemp("view")
    import numpy as np
    import rasterio

    from orthomvp.geometry.terrain import Terrain

    truth = Terrain.read(crater_dir / "dem.tif")
    with rasterio.open(crater_dir / "dem.tif") as src:
        profile = src.profile | {"dtype": "float32", "nodata": None}
        values = src.read(1).astype(np.float32)
    files = {"start": out / "start.tif", "sigma": out / "sigma.tif", "source": out / "source.tif"}
    for key, data in (
        ("start", values + VIEW_START_OFFSET),
        ("sigma", np.full_like(values, VIEW_SIGMA)),
        ("source", (np.indices(values.shape).sum(axis=0) % 5).astype(np.float32)),
    ):
        with rasterio.open(files[key], "w", **profile) as dst:
            dst.write(data, 1)
    vis = np.stack([Terrain.read(crater_dir / f"{n}.visibility.tif").values for n in VIEW_NAMES])
    return {"dir": crater_dir, "truth": truth, "vis": vis, **files}
