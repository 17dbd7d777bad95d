"""Fault injection on the command line: outputs that would overwrite each other or an input,
extensions that do not match the format, unusable output directories, signals and internal
errors. After each case: the exit status is right, the error is one line that names the path
(or the cause), and nothing half-written or partial is left; inputs are unchanged.

(Full disks, failing writes and outputs atomic as a set belong to the output writer; its tests
are its own.)"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from io import StringIO
from pathlib import Path

import pytest

from orthomvp.cli import main

CRATER = ("dem.tif", "oblique.tif", "oblique.tsai", "nadir.tif", "nadir.tsai")


def run(*args: object) -> tuple[int, str, str]:
    """``orthomvp ARGS`` in this process: exit status, stdout, stderr."""
    out, err = StringIO(), StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        status = main([str(a) for a in args])
    return status, out.getvalue(), err.getvalue()


def state(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones included) with a digest of its content."""
    return {
        str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "/"
        for p in sorted(root.rglob("*"))
    }


def assert_refused(result: tuple[int, str, str], status: int, *words: object) -> str:
    """One error line on stderr with the status and the words; returns the line."""
    code, _, err = result
    # before the error only the engine's one-line plan may stand
    lines = [x for x in err.strip().splitlines() if not x.startswith("orthomvp: plan:")]
    assert code == status, err
    assert len(lines) == 1 and lines[0].startswith("orthomvp: "), err
    assert "Traceback" not in err
    for word in words:
        assert str(word) in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def scene(crater_dir: Path, tmp_path: Path) -> Path:
    """A copy of the crater scene's DEM, two images and their cameras in ``tmp_path/in``
    (outputs may be pointed at them without harming the session's scene)."""
    d = tmp_path / "in"
    d.mkdir()
    for name in CRATER:
        shutil.copy(crater_dir / name, d / name)
    return d


def views(d: Path) -> list[Path]:
    return [d / "oblique.tif", d / "oblique.tsai", d / "nadir.tif", d / "nadir.tsai"]


# ------------------------------------------------------------------ two outputs, one path
def test_two_outputs_on_one_path_are_refused_before_any_work(scene: Path, tmp_path: Path) -> None:
    before = state(tmp_path)
    out = tmp_path / "o.tif"
    link = tmp_path / "link.tif"
    link.symlink_to(out)  # a dangling link to the same file
    before = state(tmp_path)
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    cases = [
        (["ortho", dem, image, camera, "-o", out, "--visibility", out], "--visibility", out),
        (["ortho", dem, image, camera, "-o", out, "--visibility", tmp_path / "." / "o.tif"],
         "--visibility", out),
        (["ortho", dem, image, camera, "-o", out, "--visibility", scene / ".." / "o.tif"],
         "(as", out),
        (["ortho", dem, image, camera, "-o", out, "--visibility", link], link, out),
        (["mosaic", dem, *views(scene), "-o", out, "--source", out], "--source", out),
        (["fit", dem, *views(scene), "-o", out, "--cost", out], "--cost", out),
        (["fit", dem, *views(scene), "-o", out, "--normals", tmp_path / "n.tif", "--views",
          tmp_path / "sub" / ".." / "n.tif"], "--normals and --views", "n.tif"),
    ]  # fmt: skip
    for args, *words in cases:
        assert_refused(run(*args), 2, "given to both", *words)
    assert state(tmp_path) == before


# -------------------------------------------------------------- an output over an input
def test_an_output_over_an_input_needs_overwrite(scene: Path, tmp_path: Path) -> None:
    dem, (image, camera, image2, _) = scene / "dem.tif", views(scene)
    hard = tmp_path / "hardlink.tif"
    os.link(dem, hard)  # another name for the DEM
    before = state(tmp_path)
    cases = [
        (["visibility", dem, image, camera, "-o", dem], dem, "DEM"),
        (["visibility", dem, image, camera, "-o", hard], hard, "DEM"),
        (["ortho", dem, image, camera, "-o", image], image, "IMAGE"),
        (["ortho", dem, image, camera, "-o", tmp_path / "o.tif", "--visibility", dem], dem, "DEM"),
        (["mosaic", dem, *views(scene), "-o", image2], image2, "IMAGE 2"),
        (["fit", dem, *views(scene), "-o", dem], dem, "DEM"),
        (["fit", dem, *views(scene), "-o", tmp_path / "f.tif", "--cost", image], image, "IMAGE 1"),
        (
            ["render", dem, "-o", tmp_path / "s.png", "--ortho", tmp_path / "s.png"],
            "s.png",
            "--ortho",
        ),
    ]
    for args, path, label in cases:
        assert_refused(run(*args), 2, path, f"the input {label}", "--overwrite")
    assert state(tmp_path) == before
    # --overwrite lets it happen (the inputs are read in full first)
    code, out, err = run("visibility", dem, image, camera, "-o", image, "--overwrite")
    assert code == 0 and f"wrote {image}" in out, err
    assert state(tmp_path)["in/oblique.tif"] != before["in/oblique.tif"]


# ------------------------------------------------------------------------- extensions
def test_an_extension_that_does_not_match_the_format_is_refused(
    scene: Path, tmp_path: Path
) -> None:
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    before = state(tmp_path)
    cases = [
        (["ortho", dem, image, camera, "-o", tmp_path / "o.png"], "o.png", ".tif or .tiff"),
        (["ortho", dem, image, camera, "-o", tmp_path / "o"], "-o writes a GeoTIFF", ".tif"),
        (["visibility", dem, image, camera, "-o", tmp_path / "v.txt"], "v.txt", "not .txt"),
        (["mosaic", dem, *views(scene), "-o", tmp_path / "m.tif", "--source", tmp_path / "s.jpg"],
         "s.jpg", "--source writes a GeoTIFF"),
        (["fit", dem, *views(scene), "-o", tmp_path / "f.tif", "--normals", tmp_path / "n.jpg"],
         "n.jpg", "--normals"),
        (["render", dem, "-o", tmp_path / "r.ply"], "r.ply", "writes an image", ".png or .jpg"),
        (["mesh", dem, "-o", tmp_path / "m.stl"], "m.stl", ".ply or .obj or .glb"),
    ]  # fmt: skip
    for args, *words in cases:
        assert_refused(run(*args), 2, *words)
    assert state(tmp_path) == before
    code, _, err = run("visibility", dem, image, camera, "-o", tmp_path / "v.TIFF")
    assert code == 0 and (tmp_path / "v.TIFF").is_file(), err  # the case does not matter


# -------------------------------------------------------------------- output directories
def test_unusable_output_directories_are_refused_before_any_work(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    vis = ["visibility", dem, image, camera, "-o"]
    before = state(tmp_path)
    assert_refused(run(*vis, tmp_path / "nodir" / "v.tif"), 2, "nodir", "does not exist")
    assert_refused(run(*vis, scene), 2, scene, "names a directory")
    assert_refused(run(*vis, dem / "v.tif"), 2, dem, "is not a directory")
    assert_refused(run("synth", "crater", tmp_path / "nodir" / "s"), 2, "nodir", "does not exist")
    assert_refused(run("synth", "crater", dem), 2, dem, "is a file")
    assert_refused(run("demo", tmp_path / "nodir" / "d"), 2, "nodir", "does not exist")
    assert_refused(run("demo", dem), 2, dem, "is a file")
    assert_refused(
        run("eps-study", tmp_path, "-o", tmp_path / "nodir" / "p"), 2, "nodir", "does not exist"
    )
    assert_refused(run("bench", "--json", tmp_path / "nodir" / "b.json"), 2, "nodir")
    # a directory without write permission (root may write anyway: ask os.access as a user)
    real_access = os.access
    locked = tmp_path / "locked"
    locked.mkdir()
    before = state(tmp_path)
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == locked else real_access(p, mode)
    )
    assert_refused(run(*vis, locked / "v.tif"), 2, locked, "permission denied")
    assert state(tmp_path) == before


# ------------------------------------------------------------------------- exit status
def test_exit_status_of_each_kind_of_failure(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import orthomvp.engine.tile

    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    out = tmp_path / "v.tif"
    args = ["visibility", dem, image, camera, "-o", out]
    before = state(tmp_path)
    assert_refused(run("visibility", dem, image, "-o", out), 2, "Missing argument")  # usage
    assert_refused(run(*args[:-2], "--eps=-1", "-o", out), 2, "--eps")
    assert_refused(run("visibility", tmp_path / "no.tif", image, camera, "-o", out), 2, "no.tif")

    def fail(kind: type[BaseException]):  # noqa: ANN202
        def compute(*a: object, **k: object) -> None:
            if kind is SystemExit:  # a real SIGTERM, delivered to this process
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)  # the handler raises before this ends
            raise kind("an injected failure")

        return compute

    for kind, status, words in (
        (RuntimeError, 1, ("internal error: RuntimeError: an injected failure", "ORTHOMVP_DEBUG")),
        (MemoryError, 1, ("out of memory",)),
        (KeyboardInterrupt, 130, ("interrupted; no partial output was kept",)),
        (SystemExit, 143, ("interrupted; no partial output was kept",)),
    ):
        monkeypatch.setattr(orthomvp.engine.tile, "compute_visibility", fail(kind))
        assert_refused(run(*args), status, *words)
    assert state(tmp_path) == before
    # the SIGTERM handler is the previous one again after main returns
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_warnings_are_one_line(scene: Path, tmp_path: Path) -> None:
    import numpy as np
    import rasterio

    with rasterio.open(scene / "dem.tif") as src:
        profile, values = src.profile, src.read(1)
    values[10:12, 20:25] = np.inf
    with rasterio.open(scene / "inf.tif", "w", **profile) as dst:
        dst.write(values, 1)
    image, camera, *_ = views(scene)
    code, out, err = run("visibility", scene / "inf.tif", image, camera, "-o", tmp_path / "v.tif")
    assert code == 0, err
    lines = [x for x in err.splitlines() if not x.startswith("orthomvp: plan:")]
    assert lines == [f"orthomvp: warning: {scene / 'inf.tif'}: 10 infinite heights taken as nodata"]


# ----------------------------------------------------------------------------- signals
def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def test_sigterm_during_the_write_keeps_nothing(scene: Path, tmp_path: Path) -> None:
    """SIGTERM while the GeoTIFF is being written (the signal is sent from inside the write,
    so that it lands there every time): exit 143, one line, no temporary file."""
    out = tmp_path / "out"
    out.mkdir()
    image, camera, *_ = views(scene)
    script = (
        "import os, signal, sys, time, rasterio.io\n"
        "write = rasterio.io.DatasetWriter.write\n"
        "def slow(self, *a, **k):\n"
        "    write(self, *a, **k)\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    time.sleep(10)\n"
        "rasterio.io.DatasetWriter.write = slow\n"
        "from orthomvp.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    args = ["visibility", scene / "dem.tif", image, camera, "-o", out / "v.tif"]
    proc = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 143, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if not x.startswith("orthomvp: plan:")]
    assert lines == ["orthomvp: interrupted; no partial output was kept"]
    assert list(out.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_during_a_long_command_keeps_nothing(
    tmp_path: Path, sig: signal.Signals, status: int
) -> None:
    """A signal from outside (``timeout``, a scheduler, Ctrl-C) while ``synth`` renders into
    its temporary directory: the status of the signal, one line, and no trace left."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "orthomvp", "-q", "synth", "hills", str(tmp_path / "scene")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not list(tmp_path.iterdir()) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)  # until the temporary scene directory appears
    assert proc.poll() is None, "synth ended before the signal"
    time.sleep(0.5)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err
    assert err == "orthomvp: interrupted; no partial output was kept\n"
    assert list(tmp_path.iterdir()) == []
