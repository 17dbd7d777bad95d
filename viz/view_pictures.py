"""Screenshots of ``orthomvp view`` for the README (the ``view`` part of ``gallery.py``).

``view-ngi.png``: the ngi-aerial mosaic (4 frames) with a click's plots and the 3D view;
``view-crater.png``: the crater scene's fit from a start DEM 25 m too high (the change layer)
with a click's plots and the 3D view. Each is the page as headless Chromium draws it.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import rasterio

HERE = Path(__file__).resolve().parent


def _run(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "orthomvp", "-q", *args], check=True)


def _serve(dem: Path, pairs: list[tuple[Path, Path]], layers: list[tuple[str, list[Path]]]):  # noqa: ANN202
    """The viewer in this process, on a free port; (url, server, layer set)."""
    import socket

    import uvicorn

    from orthomvp.camera import load_view
    from orthomvp.engine.grid import scan_dem, with_world
    from orthomvp.geometry.terrain import Terrain
    from orthomvp.geometry.world import detect_world
    from orthomvp.view import LayerSet, Posts, create_app

    layer_set = LayerSet(dem)
    for kind, paths in layers:
        layer_set.add(kind, paths)
    for problem in layer_set.problems:
        print(f"view_pictures: not shown: {problem.reason}", file=sys.stderr)
    views = [load_view(i, c) for i, c in pairs]
    raw = Terrain.read(dem, vertical_datum="ignore")
    world = detect_world(raw, np.array([v[1].center for v in views]))
    source = with_world(scan_dem(dem), world)
    names = [i.name for i, _ in pairs]
    posts = Posts(layer_set, source, [v[0] for v in views], [v[1] for v in views], names)
    posts.warm()
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    server = uvicorn.Server(
        uvicorn.Config(create_app(layer_set, "gallery", posts), log_level="warning")
    )
    threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    return f"http://127.0.0.1:{sock.getsockname()[1]}/?token=gallery", server


def _shot(url: str, layer: str, click: tuple[float, float], hwin: int, out: Path) -> None:
    """Load the page, show ``layer``, click map point ``click`` (x, y) at ``hwin``, wait for
    the plots and the 3D view, and save the page."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from conftest import chromium
    from selenium.webdriver.common.action_chains import ActionChains

    driver = chromium(1500, 1800)
    try:
        driver.get(url)
        time.sleep(1.5)
        driver.find_element("css selector", f'input[value="{layer}"]').click()
        box = driver.find_element("id", "hwin")
        box.clear()
        box.send_keys(str(hwin))
        mapel = driver.find_element("id", "map")
        px, py = driver.execute_script(
            "const p = orthomvpView.map.latLngToContainerPoint([arguments[1], arguments[0]]);"
            "return [p.x, p.y];",
            *click,
        )
        w, h = mapel.size["width"], mapel.size["height"]
        ActionChains(driver).move_to_element_with_offset(
            mapel, int(px - w / 2), int(py - h / 2)
        ).click().perform()
        for _ in range(300):
            if driver.execute_script("return !!(window.orthomvp3d && window.orthomvp3d.camera)"):
                break
            time.sleep(0.1)
        time.sleep(2)
        driver.execute_script("window.scrollTo(0, 0)")
        driver.save_screenshot(str(out))
    finally:
        driver.quit()
    _shrink(out)


def _shrink(path: Path, width: int = 1200) -> None:
    """Scale a screenshot to ``width`` pixels and 256 colours (a README picture, not a map)."""
    from PIL import Image

    img = Image.open(path).convert("RGB")
    img = img.resize((width, round(img.height * width / img.width)), Image.Resampling.LANCZOS)
    img.quantize(256, method=Image.Quantize.FASTOCTREE).save(path, optimize=True)


def ngi_picture(data: Path, tmp: Path) -> None:
    cams = data / "orthority-format" / "ngi_xyz_opk.csv"
    frames = sorted(data.glob("*_RGB.tif"))
    pairs = [(f, cams) for f in frames]
    files = [str(p) for pair in pairs for p in pair]
    _run("mosaic", str(data / "dem.tif"), *files, "-o", str(tmp / "ngi-mosaic.tif"),
         "--source", str(tmp / "ngi-source.tif"))  # fmt: skip
    _run("visibility", str(data / "dem.tif"), str(frames[0]), str(cams),
         "-o", str(tmp / "ngi-vis.tif"))  # fmt: skip
    url, server = _serve(
        data / "dem.tif",
        pairs,
        [("image", [tmp / "ngi-mosaic.tif"]), ("source", [tmp / "ngi-source.tif"]),
         ("visibility", [tmp / "ngi-vis.tif"])],
    )  # fmt: skip
    with rasterio.open(data / "dem.tif") as src:
        b = src.bounds
    _shot(url, "L1", ((b.left + b.right) / 2, (b.bottom + b.top) / 2), 10, HERE / "view-ngi.png")
    server.should_exit = True


def crater_picture(tmp: Path) -> None:
    from orthomvp.synthetic import make_scene

    scene = tmp / "crater"
    make_scene("crater", size=96, spacing=50.0, image_margin=14.0).write(scene)
    info = json.loads((scene / "scene.json").read_text())
    pairs = [(scene / v["image"], scene / v["camera"]) for v in info["views"].values()]
    with rasterio.open(scene / "dem.tif") as src:
        profile, truth = src.profile, src.read(1)
    start = tmp / "start.tif"
    with rasterio.open(start, "w", **profile) as dst:
        dst.write(truth + 25.0, 1)
    files = [str(p) for pair in pairs for p in pair]
    _run("fit", str(start), *files, "-o", str(tmp / "fitted.tif"), "--uncertainty",
         str(tmp / "sigma.tif"), "--hwin", "5")  # fmt: skip
    layers = [
        ("image", [scene / "truth_radiance.tif"]),
        ("height", [tmp / "fitted.tif"]),
        ("change", [tmp / "fitted.tif", start]),
        ("uncertainty", [tmp / "sigma.tif"]),
    ]
    layers = [lay for lay in layers if lay[1][0].exists()]
    url, server = _serve(start, pairs, layers)
    with rasterio.open(start) as src:
        x, y = src.xy(20, 24)
    change = f"L{[k for k, _ in layers].index('change') + 1}"
    _shot(url, change, (x, y), 5, HERE / "view-crater.png")
    server.should_exit = True
    shutil.rmtree(scene, ignore_errors=True)


def view_pictures(tmp: Path, data: Path) -> None:
    crater_picture(tmp)
    if (data / "ngi-aerial" / "dem.tif").is_file():
        ngi_picture(data / "ngi-aerial", tmp)
