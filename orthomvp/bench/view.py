"""Viewer benchmark (``orthomvp bench --view``): ``orthomvp view`` run as a user runs it, timed
over HTTP against its goals (first map paint < 2 s, a tile < 100 ms, a click's plots < 1 s at
hwin 10), on the demo's crater scene and, with the data, the ngi-aerial mosaic.

The first paint is measured in headless Chromium (Debian's chromium and chromium-driver, with
Selenium) from the page's request to its first tiles drawn; without them it is left out. Tiles
are distinct ones at the finest zoom (no cache); clicks are at hwin 10 on posts near the DEM's
centre, the first one apart (it waits for the explorer to be made)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from orthomvp.synthetic import make_scene

DEMO_SCENE = {"size": 120, "spacing": 50.0, "image_margin": 14.0}
"""The crater scene as ``orthomvp demo`` makes it."""
TILES = 16
CLICKS = 4
GOALS = {"paint_s": 2.0, "tile_ms": 100.0, "click_s": 1.0}


@dataclass
class ViewCase:
    """What a benchmark views: a DEM, IMAGE CAMERA pairs and layer options of the command."""

    name: str
    dem: Path
    pairs: list[tuple[Path, Path]]
    options: list[str] = field(default_factory=list)


def _mosaic(dem: Path, pairs: list[tuple[Path, Path]], work: Path) -> list[str]:
    """Mosaic the pairs with the command line; returns the viewer's layer options."""
    out, source = work / "mosaic.tif", work / "source.tif"
    files = [str(p) for pair in pairs for p in pair]
    cmd = [sys.executable, "-m", "orthomvp", "-q", "mosaic", str(dem), *files]
    subprocess.run([*cmd, "-o", str(out), "--source", str(source)], check=True)
    return ["--mosaic", str(out), "--source", str(source)]


def demo_case(work: Path) -> ViewCase:
    """The demo's crater scene (120 x 120 posts of 50 m, 4 views), its mosaic and truth
    visibility."""
    scene = work / "crater"
    make_scene("crater", **DEMO_SCENE).write(scene)
    info = json.loads((scene / "scene.json").read_text())
    pairs = [(scene / v["image"], scene / v["camera"]) for v in info["views"].values()]
    options = _mosaic(scene / "dem.tif", pairs, work)
    for v in info["views"].values():
        options += ["--visibility", str(scene / v["visibility"])]
    return ViewCase("demo crater 120 x 120 posts", scene / "dem.tif", pairs, options)


def ngi_case(data: Path, work: Path) -> ViewCase:
    """The ngi-aerial DEM (327 x 508 posts of 24 m), its 4 frames and their mosaic."""
    cameras = data / "orthority-format" / "ngi_xyz_opk.csv"
    pairs = [(image, cameras) for image in sorted(data.glob("*_RGB.tif"))]
    return ViewCase(
        "ngi-aerial mosaic", data / "dem.tif", pairs, _mosaic(data / "dem.tif", pairs, work)
    )


def _get(url: str) -> tuple[float, bytes]:
    t0 = time.perf_counter()
    with urllib.request.urlopen(url, timeout=120) as resp:
        body = resp.read()
    return time.perf_counter() - t0, body


def _paint(url: str) -> float | None:
    """Seconds from the page's request to its first tiles drawn, in headless Chromium; None
    without Chromium, its driver or Selenium."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        return None
    if browser is None or driver_path is None:
        return None
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                 "--window-size=1300,900"):  # fmt: skip
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=Service(driver_path))
    try:
        driver.set_script_timeout(60)
        t0 = time.perf_counter()
        driver.get(url)
        driver.execute_async_script(
            "const done = arguments[0], t = window.orthomvpView.state.tiles;"
            "if (!t.isLoading()) done(); else t.once('load', () => done());"
        )
        return time.perf_counter() - t0
    finally:
        driver.quit()


def bench_view(case: ViewCase) -> dict:
    """Run ``orthomvp view`` on ``case`` and time the first paint, tiles and clicks."""
    files = [str(p) for pair in case.pairs for p in pair]
    cmd = [sys.executable, "-m", "orthomvp", "view", str(case.dem), *files, *case.options]
    proc = subprocess.Popen(
        [*cmd, "--port", "0", "--no-browser"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        line = ""
        while not line.startswith("orthomvp: view at"):
            line = proc.stdout.readline()
            if not line:
                raise RuntimeError("orthomvp view stopped before printing its URL")
        url = line.split()[3]
        base, token = url.split("/?token=")
        paint = _paint(url)
        _, page = _get(url)
        cfg = json.loads(re.search(rb'id="config" type="application/json">(.*?)</script>', page,
                                   re.S).group(1))  # fmt: skip
        tiles = _tile_times(base, token, cfg)
        clicks = _click_times(base, token, cfg)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
    return {"case": case.name, "paint_s": paint, **tiles, **clicks}


def _tile_times(base: str, token: str, cfg: dict) -> dict:
    z = cfg["maxNativeZoom"]
    a, b, c, d = cfg["transformation"]
    (bottom, left), (top, right) = cfg["bounds"]
    scale = 2**z / 256
    x0, x1 = int((a * left + b) * scale), int((a * right + b) * scale)
    y0, y1 = int((c * top + d) * scale), int((c * bottom + d) * scale)
    last = 2**z - 1
    cells = [(x, y) for x in range(x0, min(x1, last) + 1) for y in range(y0, min(y1, last) + 1)]
    pick = [cells[i] for i in np.linspace(0, len(cells) - 1, min(TILES, len(cells))).astype(int)]
    layer = cfg["layers"][1]["id"] if len(cfg["layers"]) > 1 else "L0"
    times = [_get(f"{base}/tiles/{layer}/{z}/{x}/{y}.png?token={token}")[0] for x, y in pick]
    return {"tile_ms_median": 1e3 * float(np.median(times)), "tile_ms_max": 1e3 * max(times),
            "tiles": len(times), "zoom": z}  # fmt: skip


def _click_times(base: str, token: str, cfg: dict) -> dict:
    (bottom, left), (top, right) = cfg["bounds"]
    times, plotted = [], 0
    for k in range(CLICKS + 1):
        f = 0.5 + 0.08 * np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1]])[k]
        x, y = left + f[0] * (right - left), bottom + f[1] * (top - bottom)
        t, body = _get(f"{base}/api/click?x={x}&y={y}&hwin=10&token={token}")
        times.append(t)
        plotted += k > 0 and "rplot" in json.loads(body)
    return {"first_click_s": times[0], "click_s_median": float(np.median(times[1:])),
            "clicks_plotted": plotted, "clicks": CLICKS}  # fmt: skip


def format_view(row: dict) -> str:
    """One line per case, against the goals."""
    paint = "n/a (no Chromium)" if row["paint_s"] is None else f"{row['paint_s']:.2f} s"
    return (
        f"view     {row['case']}: first paint {paint} (goal < {GOALS['paint_s']:g} s), tile "
        f"{row['tile_ms_median']:.0f} ms median, {row['tile_ms_max']:.0f} max of {row['tiles']} "
        f"at zoom {row['zoom']} (goal < {GOALS['tile_ms']:g} ms), click at hwin 10 "
        f"{row['click_s_median']:.2f} s median of {row['clicks']} ({row['clicks_plotted']} with "
        f"plots; goal < {GOALS['click_s']:g} s), the first {row['first_click_s']:.2f} s "
        "(the explorer made)"
    )
