"""``orthomvp view`` through Starlette's TestClient and the command line: the token on every
request, only the named files, tiles and hover values against the files, a click's objective
against the explorer's own and the crater scene's truth, bad input, the static export."""

from __future__ import annotations

import io
import os
import signal
import socket
import subprocess
import sys
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from PIL import Image

from orthomvp.cli import main
from orthomvp.codes import CODE_RGB, Code
from orthomvp.geometry.terrain import Terrain

with warnings.catch_warnings():  # starlette >= 1.x prefers httpx2 but works with httpx
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

pytest.importorskip("uvicorn")

NAMES = ("oblique", "nadir", "fore", "aft")
TOKEN = "s3cret-token-for-tests"
START_OFFSET = 25.0  # metres: the viewed DEM is the truth raised by this much
SIGMA = 1.5  # metres: the constant uncertainty raster


@pytest.fixture(scope="module")
def scene(crater_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The crater scene with a DEM START_OFFSET above the truth (the fit's start), the truth
    as the "fitted" DEM, a constant uncertainty and a source raster of views 0..4."""
    out = tmp_path_factory.mktemp("view")
    truth = Terrain.read(crater_dir / "dem.tif")
    with rasterio.open(crater_dir / "dem.tif") as src:
        profile = src.profile | {"dtype": "float32", "nodata": None}
        values = src.read(1).astype(np.float32)
    files = {"start": out / "start.tif", "sigma": out / "sigma.tif", "source": out / "source.tif"}
    for key, data in (
        ("start", values + START_OFFSET),
        ("sigma", np.full_like(values, SIGMA)),
        ("source", (np.indices(values.shape).sum(axis=0) % 5).astype(np.float32)),
    ):
        with rasterio.open(files[key], "w", **profile) as dst:
            dst.write(data, 1)
    vis = np.stack([Terrain.read(crater_dir / f"{n}.visibility.tif").values for n in NAMES])
    return {"dir": crater_dir, "truth": truth, "vis": vis, **files}


def _layers(scene: dict):  # noqa: ANN202
    from orthomvp.view import LayerSet

    layers = LayerSet(scene["start"])
    layers.add("visibility", [scene["dir"] / "oblique.visibility.tif"])
    layers.add("source", [scene["source"]])
    layers.add("height", [scene["dir"] / "dem.tif"])
    layers.add("change", [scene["dir"] / "dem.tif", scene["start"]])
    layers.add("uncertainty", [scene["sigma"]])
    return layers


@pytest.fixture(scope="module")
def app(scene: dict):  # noqa: ANN201
    from orthomvp.camera import load_view
    from orthomvp.view import Posts, create_app

    layers = _layers(scene)
    views = [load_view(scene["dir"] / f"{n}.tif", scene["dir"] / f"{n}.tsai") for n in NAMES]
    terrain = Terrain.read(scene["start"])
    posts = Posts(layers, terrain, [v[0] for v in views], [v[1] for v in views], list(NAMES))
    return create_app(layers, TOKEN, posts), layers, posts


def _client(app: tuple) -> TestClient:
    return TestClient(app[0])


def _flat_post(scene: dict) -> tuple[int, int]:
    """A post all four views see, 11 posts from the edges (room for the window), the
    farthest such from the crater's centre: flat ground, where a plane fits."""
    rows, cols = scene["vis"].shape[1:]
    r, c = np.mgrid[0:rows, 0:cols]
    ok = (scene["vis"] == Code.VISIBLE).all(axis=0)
    ok &= (r >= 11) & (r < rows - 11) & (c >= 11) & (c < cols - 11)
    dist = np.where(ok, np.hypot(r - rows / 2, c - cols / 2), -1)
    r0, c0 = np.unravel_index(np.argmax(dist), dist.shape)
    return int(c0), int(r0)


def _centre(scene: dict, c: int, r: int) -> tuple[float, float]:
    x, y = scene["truth"].pixel_to_crs(np.array([c]), np.array([r]))
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


def test_only_the_named_files_are_served(app: tuple, scene: dict) -> None:
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
        f"/static/{scene['start']}",
        "/static//etc/passwd",
        "/tiles/L99/0/0/0.png",
        "/tiles/..%2fstart.tif/0/0/0.png",
        f"/tiles/{scene['start']}/0/0/0.png",
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


def test_tiles_show_each_layer_in_its_colours(app: tuple, scene: dict) -> None:
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
    codes = scene["vis"][0]
    checked = 0
    for i in range(5, 250, 17):
        for j in range(5, 250, 17):
            x, y = left + (j + 0.5) * span / 256, top - (i + 0.5) * span / 256
            c, r = (int(np.floor(v)) for v in ~scene["truth"].transform @ (x, y))
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


def test_hover_reads_the_files_values(app: tuple, scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = 17, 40
    x, y = _centre(scene, c, r)
    got = client.get(f"/api/point?x={x}&y={y}").json()
    lon, lat = scene["truth"].pixel_to_lonlat(np.array([c]), np.array([r]))
    assert got["lon"] == pytest.approx(np.degrees(lon[0]), abs=1e-9)
    assert got["lat"] == pytest.approx(np.degrees(lat[0]), abs=1e-9)
    truth = float(scene["truth"].values[r, c])
    with rasterio.open(scene["start"]) as src:
        start = float(src.read(1)[r, c])
    assert got["values"] == {
        "L0": f"{start:.2f} m",
        "L1": Code(int(scene["vis"][0][r, c])).label,
        "L2": f"view {(r + c) % 5}" if (r + c) % 5 else "none",
        "L3": f"{truth:.2f} m",
        "L4": f"{truth - start:+.2f} m",
        "L5": f"± {SIGMA:.2f} m",
    }
    outside = client.get(f"/api/point?x={x + 100}&y={y}").json()
    assert all(v is None for v in outside["values"].values())


def test_click_gives_the_explorers_own_rplot_near_the_truth(app: tuple, scene: dict) -> None:
    """A click on a post of flat ground (hwin 5, rplot +-60 m in 2 m steps): the fit from the
    DEM 25 m too high, rplot's minimum equal to the explorer's own run of the same commands,
    and within the explorer test's 3 m of the truth height."""
    from orthomvp.camera import load_view
    from orthomvp.explore import Explorer

    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = _flat_post(scene)
    x, y = _centre(scene, c, r)
    got = client.get(f"/api/click?x={x}&y={y}&hwin=5&hrange=60&hsteps=61").json()
    assert "error" not in got, got
    assert got["post"] == [c, r]
    truth = float(scene["truth"].values[r, c])
    assert got["fitted_file"] == pytest.approx(truth, abs=1e-3)  # the truth as "fitted"
    assert got["sigma_file"] == pytest.approx(SIGMA)
    d = scene["dir"]
    views = [load_view(d / f"{n}.tif", d / f"{n}.tsai") for n in NAMES]
    ex = Explorer(Terrain.read(scene["start"]), [v[0] for v in views], [v[1] for v in views])
    ex.set_poi(c, r)
    ex.hwin = 5
    ex.fit()
    own = ex.height_curve(60.0, 61)
    assert got["rplot"]["h_min"] == pytest.approx(own.h_min, abs=1e-9)
    assert got["fit"]["h"] == pytest.approx(float(ex.theta[0]), abs=1e-9)
    assert abs(got["rplot"]["h_min"] - truth) <= 3.0
    for key in ("rplot", "llplot", "patches"):
        png = got[key]["png"]
        assert png.startswith("data:image/png;base64,") and len(png) > 5000
    assert [v["name"] for v in got["views"]] == list(NAMES)


def test_click_outside_or_on_a_post_no_two_views_see(app: tuple, scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    left, bottom, right, top = app[1].bounds
    outside = client.get(f"/api/click?x={right + 1}&y={top + 1}")
    assert outside.status_code == 400 and "outside the DEM" in outside.json()["error"]
    x, y = _centre(scene, 30, 30)
    one = client.get(f"/api/click?x={x}&y={y}&views=1").json()  # the nadir view alone
    assert "needs 2 views" in one["error"] and "rplot" not in one


def test_scene_3d_around_a_post(app: tuple, scene: dict) -> None:
    client = _client(app)
    client.get(f"/?token={TOKEN}")
    c, r = _flat_post(scene)
    x, y = _centre(scene, c, r)
    got = client.get(f"/api/scene?x={x}&y={y}&layer=L1").json()
    rows, cols = got["shape"]
    assert len(got["z"]) == rows * cols
    k = (r - max(r - 40, 0)) * cols + (c - max(c - 40, 0))
    assert got["x"][k] == 0 and got["y"][k] == 0 and got["z"][k] == 0  # the post is the origin
    for v in got["views"]:  # every view sees the post: its ray's first hit is the post
        assert v["code"] == "visible" and np.linalg.norm(v["hit"]) < 0.5 * got["spacing"]


def _no_serve(monkeypatch: pytest.MonkeyPatch) -> list:
    served: list = []
    monkeypatch.setattr(
        "orthomvp.cli.view._serve", lambda layers, posts, sock, host, nb: served.append(layers)
    )
    return served


def test_host_warning_bad_files_and_port_in_use(
    scene: dict, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    served = _no_serve(monkeypatch)
    dem = str(scene["start"])
    assert main(["view", dem, "--port", "0"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["view", dem, "--port", "0", "--host", "0.0.0.0"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: warning: serving on 0.0.0.0")
    # a missing and an off-grid layer are named (stderr and page); the rest is served
    other = tmp_path / "other.tif"
    Terrain(np.zeros((4, 4)), Affine(10, 0, 5e5, 0, -10, 0), "EPSG:32633").write(other)
    args = ["view", dem, "--port", "0", "--ortho", str(tmp_path / "gone.tif")]
    args += ["--ortho", str(other)]
    assert main([*args, "--visibility", str(scene["dir"] / "nadir.visibility.tif")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "gone.tif" in err[0] and "not on the DEM's grid" in err[1]
    assert [lay.kind.name for lay in served[-1].layers.values()] == ["relief", "visibility"]
    assert len(served[-1].problems) == 2
    # bad input: one line, status 2
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["view", dem, "--port", str(port)]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and f"cannot serve on 127.0.0.1 port {port}" in err[0], err
    for argv, words in (
        (["view", str(tmp_path / "none.tif")], "none.tif"),
        (["view", __file__], "test_view.py"),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("orthomvp: error:") and words in err[0], err


@pytest.mark.slow
def test_serves_until_ctrl_c(scene: dict) -> None:
    """The command as a user runs it: prints the URL, serves a tile with the token (403
    without), and Ctrl-C stops it cleanly."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-m", "orthomvp", "view", str(scene["start"]), "--port", "0",
         "--no-browser"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("orthomvp: view at http://127.0.0.1:"), line
        url = line.split()[3]
        base, token = url.split("/?token=")
        with urllib.request.urlopen(f"{base}/tiles/L0/0/0/0.png?token={token}") as resp:
            assert resp.status == 200 and resp.read(8) == b"\x89PNG\r\n\x1a\n"
        with pytest.raises(urllib.error.HTTPError, match="403"):
            urllib.request.urlopen(f"{base}/tiles/L0/0/0/0.png")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode in (0, 130), err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("orthomvp: ")
