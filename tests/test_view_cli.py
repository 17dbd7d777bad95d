"""``orthomvp view`` on the command line: the host warning, files it cannot show, bad input,
Ctrl-C, and ``--export``'s static page opened from file:// with no server and no network."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from conftest import chromium, hover_map, needs_chromium
from test_view import TestClient, _centre, _flat_post, _map_pixels, _severe, _wait_for, _wait_tiles

from orthomvp.cli import main
from orthomvp.codes import Code
from orthomvp.geometry.terrain import Terrain

pytest.importorskip("uvicorn")


def _no_serve(monkeypatch: pytest.MonkeyPatch) -> list:
    served: list = []
    monkeypatch.setattr(
        "orthomvp.cli.view._serve", lambda layers, posts, sock, host, nb: served.append(layers)
    )
    return served


def test_host_warning_bad_files_and_port_in_use(
    view_scene: dict, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    served = _no_serve(monkeypatch)
    dem = str(view_scene["start"])
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
    assert main([*args, "--visibility", str(view_scene["dir"] / "nadir.visibility.tif")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "gone.tif" in err[0] and "not on the DEM's grid" in err[1]
    assert [lay.kind.name for lay in served[-1].layers.values()] == ["relief", "visibility"]
    assert len(served[-1].problems) == 2
    from orthomvp.view import create_app

    page = TestClient(create_app(served[-1], "t")).get("/?token=t").text
    assert "gone.tif: raster not found" in page and "other.tif: not on the DEM" in page
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
        (["view", __file__], "not a readable raster"),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("orthomvp: error:") and words in err[0], err


@pytest.mark.slow
def test_serves_until_ctrl_c(view_scene: dict) -> None:
    """The command as a user runs it: prints the URL, serves a tile with the token (403
    without), and Ctrl-C stops it cleanly."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-m", "orthomvp", "view", str(view_scene["start"]), "--port", "0",
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
    assert proc.returncode == 130, err  # the command line's status for Ctrl-C
    assert err.strip().splitlines() == ["orthomvp: interrupted; no partial output was kept"]


@pytest.mark.slow
@needs_chromium
def test_export_opens_from_file_with_no_server_and_no_network(
    view_scene: dict, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:

    out = tmp_path / "page"
    args = ["view", str(view_scene["start"]), "--export", str(out)]
    assert main([*args, "--visibility", str(view_scene["dir"] / "oblique.visibility.tif")]) == 0
    assert "tiles of 2 layers" in capsys.readouterr().out
    driver = chromium(1000, 800, offline=True)
    try:
        driver.get((out / "index.html").as_uri())
        _wait_tiles(driver)
        before = _map_pixels(driver)
        driver.find_element("css selector", 'input[value="L1"]').click()
        _wait_tiles(driver)
        assert (before != _map_pixels(driver)).any(axis=-1).mean() > 0.3
        # hover: the export's value grid under the pointer, on a post of flat ground
        c, r = _flat_post(view_scene)
        hover_map(driver, *_centre(view_scene, c, r))
        cell = "td[data-layer='L1']"
        _wait_for(driver, f'const e = document.querySelector("{cell}"); return e && e.textContent')
        assert driver.find_element("css selector", cell).text == Code.VISIBLE.label
        assert driver.find_element("css selector", "td[data-layer='L0']").text.endswith(" m")
        tiles = driver.execute_script(
            "return Array.from(document.querySelectorAll('img.leaflet-tile'))"
            ".map(i => [i.complete && i.naturalWidth > 0, i.src])"
        )
        assert tiles and all(ok for ok, _ in tiles), tiles
        requests = [
            json.loads(e["message"])["message"]["params"]["request"]["url"]
            for e in driver.get_log("performance")
            if '"Network.requestWillBeSent"' in e["message"]
        ]
        assert requests and all(u.startswith(("file://", "data:")) for u in requests), requests
        assert _severe(driver) == []
    finally:
        driver.quit()


def test_export_refuses_a_users_folder_and_refreshes_its_own(
    view_scene: dict, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """--export into a folder of the user's is refused without --overwrite (one line, status 2,
    the folder untouched) and keeps the user's other files with it; an earlier export is
    refreshed whole: re-exported with fewer layers it holds exactly what a fresh export
    holds. The API's write_export follows the same rule (InputError naming overwrite=True)."""
    from orthomvp.errors import InputError
    from orthomvp.view import LayerSet, write_export

    def files(folder: Path) -> set[str]:
        return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}

    dem = str(view_scene["start"])
    vis = ["--visibility", str(view_scene["dir"] / "oblique.visibility.tif")]
    user = tmp_path / "user"
    user.mkdir()
    (user / "index.html").write_text("mine")
    (user / "notes.txt").write_text("notes")
    for sub in ("tiles", "static"):  # folders of the export's names, holding the user's files
        (user / sub).mkdir()
        (user / sub / "keep.txt").write_text(sub)
    assert main(["view", dem, "--export", str(user)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: error:"), err
    assert "--export exists and is not empty; give --overwrite" in err[0], err
    mine = {"index.html", "notes.txt", "tiles/keep.txt", "static/keep.txt"}
    assert files(user) == mine
    assert (user / "index.html").read_text() == "mine"
    with pytest.raises(InputError, match="overwrite=True"):
        write_export(LayerSet(Path(dem)), user)
    assert files(user) == mine
    assert main(["view", dem, "--export", str(user), "--overwrite"]) == 0
    assert (user / "index.html").read_text().startswith("<!doctype html>")
    assert (user / "notes.txt").read_text() == "notes"
    for sub in ("tiles", "static"):  # merged into, not replaced: the user's files stay
        assert (user / sub / "keep.txt").read_text() == sub
    # an earlier export (two layers) refreshed with one layer: no tile of the other stays
    page, fresh = tmp_path / "page", tmp_path / "fresh"
    assert main(["view", dem, "--export", str(page), *vis]) == 0
    assert any(name.startswith("tiles/L1/") for name in files(page))
    assert main(["view", dem, "--export", str(page)]) == 0
    assert main(["view", dem, "--export", str(fresh)]) == 0
    assert files(page) == files(fresh) and not any(n.startswith("tiles/L1") for n in files(page))
    assert (page / "index.html").read_text() == (fresh / "index.html").read_text()
    assert write_export(LayerSet(Path(dem)), page) > 0  # the API refreshes it too
    assert files(page) == files(fresh)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fresh", "page", "user"]  # no temporaries


def test_a_failed_refresh_keeps_the_earlier_export(
    view_scene: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A rename that fails while an earlier export is refreshed (no permission, a full disk)
    leaves its tiles and page as they were; ``--export .`` (the working folder) works."""
    from orthomvp.errors import OutputError
    from orthomvp.io import outputs
    from orthomvp.view import LayerSet, write_export

    dem = str(view_scene["start"])
    page = tmp_path / "page"
    assert main(["view", dem, "--export", str(page)]) == 0
    before = {p: p.read_bytes() for p in page.rglob("*") if p.is_file()}
    real, refused = outputs.os.replace, []

    def refuse(src: object, dst: object) -> None:  # the new tiles' move fails, once
        if str(dst) == str(page / "tiles") and not refused:
            refused.append(dst)
            raise PermissionError(13, "Permission denied", str(src), None, str(dst))
        real(src, dst)

    monkeypatch.setattr(outputs.os, "replace", refuse)
    with pytest.raises(OutputError):
        write_export(LayerSet(Path(dem)), page)
    monkeypatch.setattr(outputs.os, "replace", real)
    assert {p: p.read_bytes() for p in page.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["page"]  # no temporaries
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    assert main(["view", dem, "--export", "."]) == 0
    assert (here / "index.html").is_file()


def test_export_of_a_south_up_dem_and_layers_is_the_north_up_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A south-up DEM (rows flipped, positive pixel height) and south-up layers are shown as
    their north-up originals: the same values read on the DEM's posts and at a point, the same
    tiles and page; a DEM the viewer cannot show at all is one line, not an internal error."""
    import rasterio

    from orthomvp.errors import InputError
    from orthomvp.view import LayerSet

    rows, cols = 48, 64  # 4 tile pixels a post at zoom 0: no pixel centre on a post's edge
    y, x = np.mgrid[0:rows, 0:cols]
    heights = 300 + 40 * np.exp(-((x - 20) ** 2 + (y - 30) ** 2) / 200) + 0.3 * x
    codes = np.random.default_rng(3).integers(0, 4, (rows, cols))
    files = {}
    for name, data, dtype in (("dem", heights, "float32"), ("vis", codes, "uint8")):
        for up, flip, t in (
            ("north", lambda a: a, Affine(5.0, 0, 500000.0, 0, -5.0, 4000000.0)),
            ("south", lambda a: a[::-1], Affine(5.0, 0, 500000.0, 0, 5.0, 4000000.0 - 5 * rows)),
        ):
            path = files[name, up] = tmp_path / f"{up}-{name}.tif"
            profile = {"driver": "GTiff", "width": cols, "height": rows, "count": 1}
            profile |= {"dtype": dtype, "crs": "EPSG:32633", "transform": t}
            with rasterio.open(path, "w", **profile) as dst:
                dst.write(flip(data).astype(dtype), 1)
    north_bounds = (500000.0, 4000000.0 - 5 * rows, 500000.0 + 5 * cols, 4000000.0)
    for d, v in (("north", "south"), ("south", "south"), ("south", "north")):
        layers = LayerSet(files["dem", d])
        layers.add("visibility", [files["vis", v]])
        assert not layers.problems, layers.problems
        assert layers.bounds == north_bounds
        relief, shown = layers.layers["L0"], layers.layers["L1"]
        assert np.array_equal(relief.read(layers.bounds, (cols, rows))[0], heights.astype("f4"))
        assert np.array_equal(shown.read(layers.bounds, (cols, rows))[0], codes), (d, v)
        assert shown.value_at(500000.0 + 5 * 2.5, 4000000.0 - 5 * 3.5)[0] == codes[3, 2]
    pages = {}
    for up in ("north", "south"):
        out = tmp_path / f"page-{up}"
        args = [str(files["dem", up]), "--visibility", str(files["vis", up]), "--export", str(out)]
        assert main(["view", *args]) == 0
        assert "not shown" not in capsys.readouterr().err
        pages[up] = {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    north, south = pages["north"], pages["south"]
    assert north.keys() == south.keys() and any(k.startswith("tiles/L1/") for k in north)
    assert all(north[k] == south[k] for k in north if k != "index.html")
    assert south["index.html"].replace(b"south-", b"north-") == north["index.html"]

    def refused(self, path: Path) -> None:  # noqa: ANN001
        raise InputError(f"{path}: not on the DEM's grid (cannot be shown)")

    monkeypatch.setattr(LayerSet, "_open", refused)
    dem = files["dem", "north"]
    assert main(["view", str(dem), "--export", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"orthomvp: error: {dem}: not on the DEM's grid (cannot be shown)"], err
    assert not (tmp_path / "none").exists()


def test_export_says_it_ignores_the_views(
    view_scene: dict, tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The static page has no clicks or 3D: IMAGE CAMERA pairs given with --export are not
    read (even a missing camera), and one warning line says so; the page is the one written
    without them. The live viewer reads them (a missing camera is an error there)."""
    d = view_scene["dir"]
    dem = str(view_scene["start"])
    pairs = [str(d / "nadir.tif"), str(tmp_path / "nope.tsai"), str(d / "oblique.tif")]
    pairs.append(str(d / "oblique.tsai"))
    assert main(["-q", "view", dem, *pairs, "--export", str(tmp_path / "with")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "orthomvp: warning: --export ignores the 2 IMAGE CAMERA pairs (not read): the static "
        "page has no clicks or 3D; view without --export serves them"
    ], err
    assert main(["-q", "view", dem, "--export", str(tmp_path / "without")]) == 0
    assert capsys.readouterr().err == ""
    for name in ("index.html", "tiles/L0/0/0/0.png"):
        assert (tmp_path / "with" / name).read_bytes() == (tmp_path / "without" / name).read_bytes()
    _no_serve(monkeypatch)
    assert main(["view", dem, *pairs, "--port", "0"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("orthomvp: error:") and "nope.tsai" in err[0], err
