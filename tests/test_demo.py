"""``orthomvp demo`` end to end, as a user runs it: outputs, measured figures, meshes, and the
index page loaded in a real headless browser."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import trimesh
from conftest import require_open3d
from PIL import Image

import orthomvp

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.slow  # every test runs the whole demo


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo") / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "orthomvp", "demo", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return out, proc.stdout


def test_demo_outputs_and_figures(demo: tuple[Path, str]) -> None:
    out, stdout = demo
    summary = json.loads((out / "summary.json").read_text())
    assert summary["f1_visible"] > 0.99 and summary["f1_hidden"] > 0.99
    assert summary["ghosts_orthomvp"] == 0 and summary["ghosts_naive"] == summary["hidden_posts"]
    assert summary["mosaic_fills_hidden"] == 1.0
    # the fit from the perturbed start: away from the crater, under 0.15 of the start's error
    assert summary["fit_rmse_outside_crater"] < 0.15 * summary["fit_rmse_start_outside_crater"]
    assert summary["fit_rmse"] < 0.6 * summary["fit_rmse_start"]
    # every post is fitted, the outermost too: the images leave room for the fit's window, so
    # the height-error maps have no unresolved strips along the edges
    assert summary["fit_resolved"] == 1.0
    with rasterio.open(out / "fitted-dem.tif") as src:
        assert np.isfinite(src.read(1)).all()
    assert "ghosts among" in stdout and "orthomvp 0" in stdout and "MVP fit" in stdout
    assert all(line.startswith("orthomvp: ") for line in stdout.splitlines())
    for name in ("objective-rplot.csv", "objective-llplot.csv"):
        assert len((out / name).read_text().splitlines()) > 50
    for name in ("snap-visibility.png", "snap-mosaic.png", "snap-error-fitted.png"):
        img = np.asarray(Image.open(out / name).convert("RGB"))
        assert img.std() > 15 and len(np.unique(img.reshape(-1, 3), axis=0)) > 500, name
    vis = np.asarray(Image.open(out / "snap-visibility.png").convert("RGB")).astype(int)
    green = (vis[..., 1] > 150) & (vis[..., 0] < 90) & (vis[..., 2] < 90)
    assert green.mean() > 0.002  # the occluded posts of the oblique view


def test_demo_meshes_open_in_trimesh_and_open3d(demo: tuple[Path, str]) -> None:
    o3d = require_open3d()
    out, _ = demo
    posts = 120 * 120
    for name in ("crater.ply", "fitted.ply"):
        tm = trimesh.load(out / name, process=False)
        o3 = o3d.io.read_triangle_mesh(str(out / name))
        assert len(tm.vertices) == len(o3.vertices) <= posts
        assert len(tm.faces) == len(o3.triangles) > 0.9 * 2 * 119 * 119
        assert o3.has_vertex_colors() and np.asarray(o3.vertex_colors).std() > 0.05
    scene = trimesh.load(out / "crater.glb")
    (geom,) = scene.geometry.values()
    assert len(geom.vertices) == posts and geom.visual.material is not None


def page_report(page: Path, width: int = 1000) -> dict:
    """Load ``page`` in headless Chromium, ``width`` pixels wide, and report every <img> outside
    the map (its tiles are the viewer test's) with whether it loaded and its natural size,
    whether the summary <pre> and the page fit their width, and the page's text."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--allow-file-access-from-files",
        f"--window-size={width},900",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
    try:
        driver.set_page_load_timeout(60)
        driver.get(page.resolve().as_uri())
        return driver.execute_script(
            "const pre = document.querySelector('pre');"
            "return {images: Array.from(document.images)"
            "  .filter(i => !i.closest('.leaflet-container')).map(i => [i.getAttribute('src'),"
            "  i.complete && i.naturalWidth > 0, i.naturalWidth, i.naturalHeight]),"
            " pre: [pre.scrollWidth, pre.clientWidth],"
            " page: [document.documentElement.scrollWidth, window.innerWidth],"
            " text: document.body.innerText};"
        )
    finally:
        driver.quit()


def image_report(page: Path) -> list[tuple[str, bool]]:
    """Every <img> of ``page`` in headless Chromium with whether it loaded."""
    return [(src, bool(ok)) for src, ok, *_ in page_report(page)["images"]]


@pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="needs Debian's chromium and chromium-driver (.ci/run installs them)",
)
def test_index_page_loads_every_picture_in_a_browser(
    demo: tuple[Path, str], tmp_path: Path
) -> None:
    out, _ = demo
    pngs = sorted(p.name for p in out.glob("*.png"))
    report = image_report(out / "index.html")
    assert sorted(src for src, _ in report) == pngs  # every picture is on the page
    assert all(ok for _, ok in report), [src for src, ok in report if not ok]
    for width in (1000, 700):  # the summary wraps inside the page, which never scrolls sideways
        page = page_report(out / "index.html", width)
        (pre_scroll, pre_width), (page_scroll, window) = page["pre"], page["page"]
        assert pre_scroll <= pre_width and page_scroll <= window, (width, page)
    # the page is orthomvp view's export: its map holds the outputs, each layer's tiles written
    assert "Layers" in page["text"] and "fitted - truth (height error)" in page["text"]
    for layer in range(9):
        assert (out / "tiles" / f"L{layer}" / "0" / "0" / "0.png").is_file(), layer
    # the page says what made it: the version, the date and the demo's parameters
    text = page["text"]
    assert f"orthomvp\t{orthomvp.__version__}" in text
    assert re.search(r"made\t\d{4}-\d\d-\d\d \d\d:\d\d UTC", text)
    for words in ("120 x 120 posts of 50 m", "hwin 5", "oblique (55 degrees", "seed 1"):
        assert words in text, words
    # the captions say what the pictures' colours, scales and exaggeration are
    for words in (
        "colour bar in metres",
        "red too high, blue too low",
        "green occluded, orange facing away",
        "3D, vertical exaggeration 1.5x",
        "3D, no vertical exaggeration",
        "longitude and latitude ticks, a north arrow and a scale bar",
    ):
        assert words in text, words
    # the 3D snapshots are cropped to the scene: smaller than the 900 x 640 rendered
    sizes = {src: (w, h) for src, _, w, h in page["images"] if src.startswith("snap-")}
    assert len(sizes) == 4 and all(w * h < 0.8 * 900 * 640 for w, h in sizes.values()), sizes
    # the check can fail: a copy of the page with one picture missing is caught
    broken = tmp_path / "broken"
    shutil.copytree(out, broken, ignore=shutil.ignore_patterns("scene", "*.tif", "*.ply", "tiles"))
    (broken / "snap-mosaic.png").unlink()
    bad = [src for src, ok in image_report(broken / "index.html") if not ok]
    assert bad == ["snap-mosaic.png"]


def test_a_second_demo_refreshes_the_first_ones_folder(demo: tuple[Path, str]) -> None:
    """The README's demo run again into the same folder refreshes it (it failed once on its
    own ``scene/`` folder: 'directory not empty')."""
    out, _ = demo
    before = (out / "summary.json").stat().st_mtime_ns
    proc = subprocess.run(
        [sys.executable, "-m", "orthomvp", "-q", "demo", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert (out / "summary.json").stat().st_mtime_ns > before
    assert json.loads((out / "summary.json").read_text())
    assert sorted(p.name for p in out.parent.iterdir()) == ["out"]  # no temporary left
