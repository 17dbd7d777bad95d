"""``orthomvp view``'s application through Starlette's TestClient and in headless Chromium: the
token on every request, only the named files, tiles and hover values against the files, a
click's objective against the explorer's own and the crater scene's truth, the 3D scene."""

from __future__ import annotations

import io
import socket
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from conftest import VIEW_NAMES as NAMES
from conftest import VIEW_SIGMA as SIGMA
from conftest import chromium, hover_map, needs_chromium
from PIL import Image

from orthomvp.codes import CODE_RGB, Code
from orthomvp.engine.grid import scan_dem
from orthomvp.geometry.terrain import Terrain

with warnings.catch_warnings():  # starlette >= 1.x prefers httpx2 but works with httpx
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

pytest.importorskip("uvicorn")

TOKEN = "s3cret-token-for-tests"


def _layers(view_scene: dict):  # noqa: ANN202
    from orthomvp.view import LayerSet

    layers = LayerSet(view_scene["start"])
    layers.add("visibility", [view_scene["dir"] / "oblique.visibility.tif"])
    layers.add("source", [view_scene["source"]])
    layers.add("height", [view_scene["dir"] / "dem.tif"])
    layers.add("change", [view_scene["dir"] / "dem.tif", view_scene["start"]])
    layers.add("uncertainty", [view_scene["sigma"]])
    return layers


@pytest.fixture(scope="module")
def app(view_scene: dict):  # noqa: ANN201
    from orthomvp.camera import load_view
    from orthomvp.view import Posts, create_app

    layers = _layers(view_scene)
    views = [
        load_view(view_scene["dir"] / f"{n}.tif", view_scene["dir"] / f"{n}.tsai") for n in NAMES
    ]
    images, cameras = [v[0] for v in views], [v[1] for v in views]
    posts = Posts(layers, scan_dem(view_scene["start"]), images, cameras, list(NAMES))
    return create_app(layers, TOKEN, posts), layers, posts


def _client(app: tuple) -> TestClient:
    return TestClient(app[0])


def _flat_post(view_scene: dict) -> tuple[int, int]:
    """A post all four views see, 11 posts from the edges (room for the window), the
    farthest such from the crater's centre: flat ground, where a plane fits."""
    rows, cols = view_scene["vis"].shape[1:]
    r, c = np.mgrid[0:rows, 0:cols]
    ok = (view_scene["vis"] == Code.VISIBLE).all(axis=0)
    ok &= (r >= 11) & (r < rows - 11) & (c >= 11) & (c < cols - 11)
    dist = np.where(ok, np.hypot(r - rows / 2, c - cols / 2), -1)
    r0, c0 = np.unravel_index(np.argmax(dist), dist.shape)
    return int(c0), int(r0)


def _explorers_own(view_scene: dict, c: int, r: int) -> tuple[float, float]:
    """rplot's minimum and the fitted height at post (c, r) from the explorer itself, run as a
    click runs it: hwin 5, fit, rplot +-60 m in 61 steps."""
    from orthomvp.camera import load_view
    from orthomvp.explore import Explorer

    d = view_scene["dir"]
    views = [load_view(d / f"{n}.tif", d / f"{n}.tsai") for n in NAMES]
    ex = Explorer(Terrain.read(view_scene["start"]), [v[0] for v in views], [v[1] for v in views])
    ex.set_poi(c, r)
    ex.hwin = 5
    ex.fit()
    return ex.height_curve(60.0, 61).h_min, float(ex.theta[0])


def _centre(view_scene: dict, c: int, r: int) -> tuple[float, float]:
    x, y = view_scene["truth"].pixel_to_crs(np.array([c]), np.array([r]))
    return float(x[0]), float(y[0])


ENDPOINTS = (
    "/",
    "/static/view.js",
    "/static/vendor/leaflet-1.9.4/leaflet.js",
    "/tiles/L0/0/0/0.png",
    "/api/point?x=3.6&y=26.1",
    "/api/click?x=3.6&y=26.1",
    "/api/scene?x=3.6&y=26.1",
)


def test_every_endpoint_needs_the_token(app: tuple) -> None:
    client = _client(app)
    for url in ENDPOINTS:
        assert client.get(url).status_code == 403, url
        sep = "&" if "?" in url else "?"
        assert client.get(f"{url}{sep}token=wrong").status_code == 403, url
        client.cookies.set("orthomvp_view_token", "wrong")
        assert client.get(url).status_code == 403, url
        client.cookies.clear()
    # the token in the URL opens the page and sets the cookie, which then opens the rest
    first = client.get(f"/?token={TOKEN}")
    assert first.status_code == 200 and "orthomvp view" in first.text
    assert "HttpOnly" in first.headers["set-cookie"]
    assert "SameSite=Strict" in first.headers["set-cookie"]
    for url in ENDPOINTS[1:4]:
        assert client.get(url).status_code == 200, url


def test_only_the_named_files_are_served(app: tuple, view_scene: dict) -> None:
    from orthomvp.view.server import static_files

    client = _client(app)
    client.get(f"/?token={TOKEN}")
    root = Path(sys.modules["orthomvp.view"].__file__).parent / "static"
    assert all(p.resolve().is_relative_to(root.resolve()) for p in static_files().values())
    for url in (
        "/static/../server.py",
        "/static/%2e%2e/server.py",
        "/static/vendor/../../layers.py",
        "/static/..%2f..%2f__init__.py",
        f"/static/{view_scene['start']}",
        "/static//etc/passwd",
        "/tiles/L99/0/0/0.png",
        "/tiles/..%2fstart.tif/0/0/0.png",
        f"/tiles/{view_scene['start']}/0/0/0.png",
        "/tiles/L0/0/1/0.png",
        "/tiles/L0/99/0/0.png",
        "/etc/passwd",
    ):
        response = client.get(url)
        assert response.status_code == 404, url
        assert b"import" not in response.content and b"root:" not in response.content, url
    # a layer id from the scene's registry is all a tile request can name; nothing evaluates
    response = client.get("/api/point?x=__import__('os')&y=1")
    assert response.status_code == 400 and "number" in response.json()["error"]


def test_tiles_show_each_layer_in_its_colours(app: tuple, view_scene: dict) -> None:
    """Zoom 0 tile pixels: the visibility layer's colour at a post is its code's colour in
    the file, and switching layers changes the pixels."""
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    _, layers, _ = app
    tiles = {
        lid: np.asarray(Image.open(io.BytesIO(client.get(f"/tiles/{lid}/0/0/0.png").content)))
        for lid in layers.layers
    }
    assert (tiles["L0"] != tiles["L1"]).any(axis=-1).mean() > 0.5  # relief -> visibility
    # the change, truth - start, is -25 m everywhere: the bluest end of the error scale
    from matplotlib import colormaps

    from orthomvp.present.colours import ERROR_CMAP

    blue = colormaps[ERROR_CMAP](0.0, bytes=True)[:3]
    inside = tiles["L4"][..., 3] == 255
    assert inside.mean() > 0.5 and (tiles["L4"][inside][:, :3] == blue).all()
    left, bottom, right, top = layers.bounds
    span = max(right - left, top - bottom)
    codes = view_scene["vis"][0]
    checked = 0
    for i in range(5, 250, 17):
        for j in range(5, 250, 17):
            x, y = left + (j + 0.5) * span / 256, top - (i + 0.5) * span / 256
            c, r = (int(np.floor(v)) for v in ~view_scene["truth"].transform @ (x, y))
            px = tiles["L1"][i, j]
            if not (0 <= r < codes.shape[0] and 0 <= c < codes.shape[1]):
                assert px[3] == 0  # outside the DEM: transparent
                continue
            assert px[3] == 255 and tuple(px[:3]) == tuple(CODE_RGB[int(codes[r, c])])
            checked += 1
    assert checked > 100
    assert {tuple(p) for p in tiles["L1"][..., :3].reshape(-1, 3)} <= {
        tuple(c) for c in CODE_RGB
    } | {(0, 0, 0)}


def test_hover_reads_the_files_values(app: tuple, view_scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = 17, 40
    x, y = _centre(view_scene, c, r)
    got = client.get(f"/api/point?x={x}&y={y}").json()
    lon, lat = view_scene["truth"].pixel_to_lonlat(np.array([c]), np.array([r]))
    assert got["lon"] == pytest.approx(np.degrees(lon[0]), abs=1e-9)
    assert got["lat"] == pytest.approx(np.degrees(lat[0]), abs=1e-9)
    truth = float(view_scene["truth"].values[r, c])
    with rasterio.open(view_scene["start"]) as src:
        start = float(src.read(1)[r, c])
    assert got["values"] == {
        "L0": f"{start:.2f} m",
        "L1": Code(int(view_scene["vis"][0][r, c])).label,
        "L2": f"view {(r + c) % 5}" if (r + c) % 5 else "none",
        "L3": f"{truth:.2f} m",
        "L4": f"{truth - start:+.2f} m",
        "L5": f"± {SIGMA:.2f} m",
    }
    outside = client.get(f"/api/point?x={x + 100}&y={y}").json()
    assert all(v is None for v in outside["values"].values())


def test_export_hover_grid_holds_the_files_values(view_scene: dict) -> None:
    """The static export's hover grid (50 cells on the longer side over 64 posts): each cell of the
    visibility layer words the code of the post under the cell's centre, as the live readout
    does (but for centres on the line between two posts); the constant uncertainty everywhere."""
    from orthomvp.view.export import hover_grid

    layers = _layers(view_scene)
    grid = hover_grid(layers, cells=50)
    cols, rows = grid["cols"], grid["rows"]
    left, bottom, right, top = grid["bounds"]
    assert max(cols, rows) == 50 and grid["bounds"] == list(layers.bounds)
    x = left + (np.arange(cols) + 0.5) * (right - left) / cols
    y = top - (np.arange(rows) + 0.5) * (top - bottom) / rows
    c, r = view_scene["truth"].crs_to_pixel(*(a.ravel() for a in np.meshgrid(x, y)))
    codes = view_scene["vis"][NAMES.index("oblique")][
        np.rint(r).astype(int), np.rint(c).astype(int)
    ]
    tie = (np.abs(c % 1 - 0.5) < 1e-6) | (np.abs(r % 1 - 0.5) < 1e-6)  # between two posts
    layer = grid["values"]["L1"]
    got = np.array(layer["words"])[layer["cells"]]
    assert tie.mean() < 0.1  # one row of the 45 here
    assert (got[~tie] == [Code(int(k)).label for k in codes[~tie]]).all()
    assert grid["values"]["L5"]["words"] == [f"± {SIGMA:.2f} m"]


def test_click_gives_the_explorers_own_rplot_near_the_truth(app: tuple, view_scene: dict) -> None:
    """A click on a post of flat ground (hwin 5, rplot +-60 m in 2 m steps): the fit from the
    DEM 25 m too high, rplot's minimum equal to the explorer's own run of the same commands,
    and within the explorer test's 3 m of the truth height."""
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = _flat_post(view_scene)
    x, y = _centre(view_scene, c, r)
    got = client.get(f"/api/click?x={x}&y={y}&hwin=5&hrange=60&hsteps=61").json()
    assert "error" not in got, got
    assert got["post"] == [c, r]
    truth = float(view_scene["truth"].values[r, c])
    assert got["fitted_file"] == pytest.approx(truth, abs=1e-3)  # the truth as "fitted"
    assert got["sigma_file"] == pytest.approx(SIGMA)
    own, fitted = _explorers_own(view_scene, c, r)
    assert got["rplot"]["h_min"] == pytest.approx(own, abs=1e-9)
    assert got["fit"]["h"] == pytest.approx(fitted, abs=1e-9)
    assert abs(got["rplot"]["h_min"] - truth) <= 3.0
    for key in ("rplot", "llplot", "patches"):
        png = got[key]["png"]
        assert png.startswith("data:image/png;base64,") and len(png) > 5000
    assert [v["name"] for v in got["views"]] == list(NAMES)


@pytest.mark.slow
def test_live_fit_is_the_fits_plane_before_deconvolution(app: tuple, view_scene: dict) -> None:
    """Why a click's live fit and ``orthomvp fit``'s DEM differ (the page says so): the live fit
    is the plane the fitter finds at the post from the same start (its plane height, to the
    optimiser's tolerance),
    and the DEM holds that plane deconvolved with its neighbours' (``--deconvolve 1``), which
    moves it by metres on the crater's wall. Checked at a post all four views see where
    deconvolution moves the height by about 10 m, as at the README's crater picture's post."""
    from orthomvp.camera import load_view
    from orthomvp.mvp.fit import FitOptions, fit_dem
    from orthomvp.mvp.lm import LMSettings

    d = view_scene["dir"]
    views = [load_view(d / f"{n}.tif", d / f"{n}.tsai") for n in NAMES]
    start = Terrain.read(view_scene["start"])
    res = fit_dem(start, [v[0] for v in views], [v[1] for v in views], FitOptions(hwin=5))
    rows, cols = start.shape
    r, c = np.mgrid[0:rows, 0:cols]
    ok = res.view_mask.all(axis=0) & (view_scene["vis"] == Code.VISIBLE).all(axis=0)
    ok &= (r >= 11) & (r < rows - 11) & (c >= 11) & (c < cols - 11)
    moved = np.where(ok, np.abs(res.heights - res.plane_heights), np.inf)
    r0, c0 = np.unravel_index(np.argmin(np.abs(moved - 10.0)), moved.shape)
    assert 5.0 < moved[r0, c0] < 15.0  # deconvolution moves this post by about 10 m
    x, y = _centre(view_scene, int(c0), int(r0))
    got = _client(app).get(f"/api/click?x={x}&y={y}&hwin=5&token={TOKEN}").json()
    assert "error" not in got, got
    # each stops when a step moves the height by under htol post spacings (their paths differ:
    # the explorer tilts the normal about "up", the fitter about the DEM's normal)
    tol = 2 * LMSettings().htol * float(np.mean(start.post_spacing()))
    assert got["fit"]["h"] == pytest.approx(res.plane_heights[r0, c0], abs=tol)
    assert abs(got["fit"]["h"] - res.heights[r0, c0]) > 2.0


def test_click_outside_or_on_a_post_no_two_views_see(app: tuple, view_scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    left, bottom, right, top = app[1].bounds
    outside = client.get(f"/api/click?x={right + 1}&y={top + 1}")
    assert outside.status_code == 200 and "outside the DEM" in outside.json()["error"]
    x, y = _centre(view_scene, 30, 30)
    one = client.get(f"/api/click?x={x}&y={y}&views=1").json()  # the nadir view alone
    assert "needs 2 views" in one["error"] and "rplot" not in one


def test_scene_3d_around_a_post(app: tuple, view_scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = _flat_post(view_scene)
    x, y = _centre(view_scene, c, r)
    got = client.get(f"/api/scene?x={x}&y={y}&layer=L1").json()
    rows, cols = got["shape"]
    assert len(got["z"]) == rows * cols
    k = (r - max(r - 40, 0)) * cols + (c - max(c - 40, 0))
    assert got["x"][k] == 0 and got["y"][k] == 0 and got["z"][k] == 0  # the post is the origin
    for v in got["views"]:  # every view sees the post: its ray's first hit is the post
        assert v["code"] == "visible" and np.linalg.norm(v["hit"]) < 0.5 * got["spacing"]


# ---------------------------------------------------------------------- in a real browser
@pytest.fixture(scope="module")
def live(app: tuple):  # noqa: ANN201
    """The app served by uvicorn on a free loopback port, for the browser; its page URL."""
    import threading

    import uvicorn

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    server = uvicorn.Server(uvicorn.Config(app[0], log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    for _ in range(200):
        if server.started:
            break
        time.sleep(0.05)
    yield f"http://127.0.0.1:{sock.getsockname()[1]}/?token={TOKEN}"
    server.should_exit = True
    thread.join(10)
    sock.close()


def _wait_tiles(driver) -> None:  # noqa: ANN001
    driver.set_script_timeout(30)
    driver.execute_async_script(
        "const done = arguments[0], t = window.orthomvpView.state.tiles;"
        "if (!t.isLoading()) done(); else t.once('load', () => done());"
    )
    time.sleep(0.4)  # Leaflet fades tiles in


def _map_pixels(driver) -> np.ndarray:  # noqa: ANN001
    png = driver.find_element("id", "map").screenshot_as_png
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def _wait_for(driver, script: str, timeout: float = 60) -> object:  # noqa: ANN001
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if value := driver.execute_script(script):
            return value
        time.sleep(0.1)
    raise AssertionError(f"not within {timeout} s: {script}")


def _severe(driver) -> list:  # noqa: ANN001
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


@pytest.mark.slow
@needs_chromium
def test_page_in_a_browser(live: str, app: tuple, view_scene: dict) -> None:
    """Load, switch layers (the map's pixels change), hover a post (its values), click a post
    (rplot's minimum is the explorer's own), rotate the 3D view; no console errors."""
    from selenium.webdriver.common.action_chains import ActionChains

    driver = chromium(1300, 1000)
    try:
        driver.set_page_load_timeout(60)
        driver.get(live)
        _wait_tiles(driver)
        before = _map_pixels(driver)
        driver.find_element("css selector", 'input[value="L1"]').click()
        _wait_tiles(driver)
        assert (before != _map_pixels(driver)).any(axis=-1).mean() > 0.3
        legend = driver.find_element("id", "legend").text
        assert "occluded" in legend and "facing away" in legend
        # hover: the pointer over a post's centre reads the files' values there
        c, r = _flat_post(view_scene)
        at_post = hover_map(driver, *_centre(view_scene, c, r))
        with rasterio.open(view_scene["start"]) as src:
            start = float(src.read(1)[r, c])
        cell = "td[data-layer='L0']"
        _wait_for(driver, f'const e = document.querySelector("{cell}"); return e && e.textContent')
        assert driver.find_element("css selector", cell).text == f"{start:.2f} m"
        assert driver.find_element("css selector", "td[data-layer='L5']").text == "± 1.50 m"
        # click: the explorer's plots at hwin 5, rplot +-60 m
        for field, value in (("hwin", "5"), ("hrange", "60")):
            box = driver.find_element("id", field)
            box.clear()
            box.send_keys(value)
        at_post.click().perform()
        shown = _wait_for(driver, "const e = document.getElementById('hmin');"
                                  "return e && e.textContent")  # fmt: skip
        assert float(shown) == pytest.approx(_explorers_own(view_scene, c, r)[0], abs=5e-4)
        assert abs(float(shown) - float(view_scene["truth"].values[r, c])) <= 3.0
        sizes = driver.execute_script(
            "return Array.from(document.querySelectorAll('#below img')).map(i => i.naturalWidth)"
        )
        assert len(sizes) == 3 and min(sizes) > 200
        # 3D: the scene appears and rotates with a drag
        _wait_for(driver, "return window.orthomvp3d && window.orthomvp3d.camera")
        time.sleep(0.5)
        canvas = driver.find_element("css selector", "#three canvas")
        pos = "return window.orthomvp3d.camera.position.toArray()"
        shot = "return window.orthomvp3d.canvas.toDataURL()"
        p0, s0 = driver.execute_script(pos), driver.execute_script(shot)
        ActionChains(driver).move_to_element(canvas).click_and_hold().move_by_offset(
            120, 30
        ).release().perform()
        time.sleep(0.3)
        p1, s1 = driver.execute_script(pos), driver.execute_script(shot)
        r0, r1 = np.linalg.norm(p0), np.linalg.norm(p1)
        assert r1 == pytest.approx(r0, rel=1e-6) and np.linalg.norm(np.subtract(p0, p1)) > 0.1 * r0
        assert s0 != s1
        assert _severe(driver) == []
    finally:
        driver.quit()
