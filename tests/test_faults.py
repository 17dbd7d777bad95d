"""Fault injection on the command line: outputs that would overwrite each other or an input,
extensions that do not match the format, unusable output directories, signals and internal
errors. After each case: the exit status is right, the error is one line that names the path
(or the cause), and nothing half-written or partial is left; inputs are unchanged.

(Full disks, failing writes and outputs atomic as a set belong to the output writer; its tests
are its own.)"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
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
def test_an_output_over_an_input_needs_replace_input(scene: Path, tmp_path: Path) -> None:
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
    # --overwrite alone does not; with --replace-input it happens (inputs are read in full first)
    args = ["visibility", dem, image, camera, "-o", image, "--overwrite"]
    assert_refused(run(*args), 2, image, "the input IMAGE", "--overwrite --replace-input")
    assert state(tmp_path) == before
    code, out, err = run(*args, "--replace-input")
    assert code == 0 and f"orthomvp: wrote {image}" in out, err
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
    check = ["check", dem, *views(scene), "-o", tmp_path / "chk"]
    before = state(tmp_path)
    assert_refused(run("visibility", dem, image, "-o", out), 2, "no CAMERA given")  # usage
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
        (
            lambda text: OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)),
            2,
            ("orthomvp: error: no space left on device",),
        ),
    ):
        monkeypatch.setattr(orthomvp.engine.tile, "compute_visibility", fail(kind))
        assert_refused(run(*args), status, *words)
        assert_refused(run(*check), status, *words)
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


# --------------------------------------------------------------------- the output writer
def hidden(directory: Path) -> list[str]:
    """Hidden entries (temporary files) under ``directory``."""
    return sorted(str(p.relative_to(directory)) for p in directory.rglob(".*"))


def one_line(result: tuple[int, str, str], capfd: pytest.CaptureFixture, *words: object) -> str:
    """Exit 2 and one error line with the words; nothing GDAL or libtiff printed reached the
    real stderr (file descriptor 2, where they print)."""
    line = assert_refused(result, 2, *words)
    printed = capfd.readouterr().err
    assert "_tiff" not in printed and "TIFF" not in printed and "Errno" not in line, printed
    return line


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Callable[[int], Path]]:
    """``disk(free)``: a real 256 kB tmpfs with about ``free`` bytes left, mounted under
    ``tmp_path`` (root only; skips elsewhere, where the monkeypatched tests stand in)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root; the monkeypatched full disk stands in")
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True
    )
    if proc.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({proc.stderr.strip()!r}); monkeypatched stands in")

    def fill(free: int) -> Path:
        for p in mnt.iterdir():
            shutil.rmtree(p) if p.is_dir() else p.unlink()
        now = shutil.disk_usage(mnt).free
        with open(mnt / "fill", "wb") as fh:
            fh.write(bytes(max(now - free, 0)))
        return mnt

    try:
        yield fill
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=True)


def test_a_full_disk_is_refused_before_any_work(
    scene: Path, crater_dir: Path, disk: Callable[[int], Path], capfd: pytest.CaptureFixture
) -> None:
    full = disk(0)
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    cases = [
        (["visibility", dem, image, camera, "-o", full / "v.tif"], "v.tif"),
        (["ortho", dem, image, camera, "-o", full / "o.tif"], "o.tif"),
        (["mosaic", dem, *views(scene), "-o", scene / "m.tif", "--source", full / "s.tif"],
         "s.tif"),
        (["fit", dem, *views(scene), "-o", full / "f.tif"], "f.tif"),
        (["fit", dem, *views(scene), "-o", scene / "f.tif", "--uncertainty", full / "u.tif"],
         "u.tif"),
        (["mesh", dem, "-o", full / "m.obj"], "m.obj"),
        (["render", dem, "-o", full / "r.png"], "r.png"),
        (["synth", "crater", full / "s"], "s"),
        (["demo", full / "d"], "d"),
        (["eps-study", crater_dir, "-o", full / "e"], "e.csv"),
    ]  # fmt: skip
    for args, name in cases:
        one_line(run(*args), capfd, f"cannot write {full / name}: no space left on device")
        assert sorted(p.name for p in full.iterdir()) == ["fill"], args
    assert not (scene / "m.tif").exists() and not (scene / "f.tif").exists()


@pytest.mark.slow
def test_a_disk_that_fills_up_while_writing(
    scene: Path, crater_dir: Path, disk: Callable[[int], Path], capfd: pytest.CaptureFixture
) -> None:
    """About 40 kB free (12 kB for eps-study): enough to start, not to finish. GDAL's and
    libtiff's complaints (also of a failure they do not raise) become one line naming the
    output."""
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    cases = [
        (lambda d: ["ortho", dem, image, camera, "-o", d / "o.tif", "--visibility", d / "v.tif",
                    "--grid", "dem"]),
        (lambda d: ["ortho", dem, image, camera, "-o", d / "o.tif", "--format", "gtiff",
                    "--compress", "none", "--grid", "dem"]),
        (lambda d: ["mosaic", dem, *views(scene), "-o", d / "m.tif", "--source", d / "s.tif",
                    "--grid", "dem"]),
        (lambda d: ["mesh", dem, "-o", d / "m.obj", "--texture", dem]),
        (lambda d: ["mesh", dem, "-o", d / "m.ply", "--texture", dem]),
        (lambda d: ["mesh", dem, "-o", d / "m.glb"]),
        (lambda d: ["synth", "crater", d / "s", "--size", "64"]),
    ]  # fmt: skip
    # the table fits, its plot not
    cases.append(lambda d: ["eps-study", crater_dir, "-o", d / "e", "--eps", "1"])
    for case in cases:
        full = disk(12_000 if case is cases[-1] else 40_000)
        args = case(full)
        line = one_line(run(*args), capfd, "cannot write", "no space left on device")
        assert str(full) in line
        assert sorted(p.name for p in full.iterdir()) == ["fill"], (args, line)


def test_a_failing_write_is_one_line_naming_the_output(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture
) -> None:
    """Where no small disk can be mounted: GDAL's write and Python's fail with ENOSPC."""
    import rasterio.io

    def full(*a: object, **k: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(rasterio.io.DatasetWriter, "write", full)
    line = one_line(
        run("visibility", dem, image, camera, "-o", out / "v.tif"),
        capfd,
        f"cannot write {out / 'v.tif'}: no space left on device (needs up to",
    )
    assert line.endswith("kB)")
    import orthomvp.present.mesh_stream

    monkeypatch.setattr(Path, "write_bytes", full)
    monkeypatch.setattr(
        orthomvp.present.mesh_stream, "open", full, raising=False
    )  # the streamed PLY
    one_line(
        run("mesh", dem, "-o", out / "m.ply"),
        capfd,
        f"cannot write {out / 'm.ply'}: no space left on device (needs up to",
    )
    assert list(out.iterdir()) == []


def test_what_gdal_and_libtiff_print_becomes_the_error(
    tmp_path: Path, capfd: pytest.CaptureFixture
) -> None:
    """libtiff prints its I/O errors on file descriptor 2 and GDAL may not raise (a full disk
    at close): within :func:`orthomvp.io.write_errors.writing` they become one OutputError
    naming the output and the cause, and nothing reaches stderr; messages of no failure pass
    through."""
    from orthomvp.errors import OutputError
    from orthomvp.io.write_errors import writing

    out = tmp_path / "o.tif"
    with pytest.raises(OutputError) as caught:
        with writing(out, 145_000_000):
            os.write(2, b"_tiffSeekProc: No space left on device.\n" * 3)
    assert str(caught.value) == (
        f"cannot write {out}: no space left on device (needs up to 145 MB)"
    )
    with pytest.raises(OutputError, match=f"cannot write {out}: disk quota exceeded$"):
        with writing(out):
            os.write(2, f"TIFFAppendToStrip: {os.strerror(errno.EDQUOT)}.\n".encode())
            raise __import__("rasterio").errors.RasterioIOError("Write failed. See previous")
    assert capfd.readouterr().err == ""
    with writing(out):
        os.write(2, b"Warning 1: something GDAL recovered from\n")
    assert capfd.readouterr().err == "Warning 1: something GDAL recovered from\n"


def test_the_second_of_two_outputs_failing_keeps_neither(
    scene: Path, crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """The second output fails when it is created, or at its first tile: the first one,
    written or not, is not kept either."""
    import rasterio
    import rasterio.io

    out = tmp_path / "out"
    out.mkdir()
    second = ("second.tif", "second.png")
    opened, written = rasterio.open, rasterio.io.DatasetWriter.write

    def fail_second(name: object) -> None:
        if Path(str(name)).name.startswith(tuple(f".{s}." for s in second)):
            raise OSError(errno.EIO, os.strerror(errno.EIO))

    def open_(path: object, mode: str = "r", *a: object, **k: object) -> object:
        if mode == "w":
            fail_second(path)
        return opened(path, mode, *a, **k)

    def write(self: rasterio.io.DatasetWriter, *a: object, **k: object) -> None:
        fail_second(self.name)
        written(self, *a, **k)

    def savefig(self: object, fname: object, *a: object, **k: object) -> None:
        fail_second(fname)
        Path(str(fname)).write_bytes(b"png")

    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    first, sec = out / "first.tif", out / "second.tif"
    cases = [
        (rasterio, "open", open_, ["ortho", dem, image, camera, "-o", first, "--visibility", sec]),
        (rasterio.io.DatasetWriter, "write", write,
         ["ortho", dem, image, camera, "-o", first, "--visibility", sec]),
        (rasterio.io.DatasetWriter, "write", write,
         ["mosaic", dem, *views(scene), "-o", first, "--source", sec]),
        (rasterio, "open", open_,
         ["-q", "fit", dem, *views(scene), "-o", first, "--cost", sec]),
        (rasterio, "open", open_,
         ["-q", "fit", dem, *views(scene), "-o", first, "--uncertainty", sec]),
        (__import__("matplotlib.figure").figure.Figure, "savefig", savefig,
         ["eps-study", crater_dir, "-o", out / "second", "--eps", "1"]),
        (__import__("matplotlib.figure").figure.Figure, "savefig", savefig,
         ["-q", "check", dem, *views(scene), "-o", out / "second", "--eps", "4"]),
    ]  # fmt: skip
    for owner, name, fake, args in cases:
        with monkeypatch.context() as patch:
            patch.setattr(owner, name, fake)
            path = out / "second.png" if {"eps-study", "check"} & set(args) else sec
            one_line(run(*args), capfd, f"cannot write {path}: input/output error")
        assert list(out.iterdir()) == [], args
    # mesh: the OBJ and its .mtl are written, its texture image fails
    real_write_bytes = Path.write_bytes

    def write_bytes(self: Path, data: bytes) -> int:
        if self.name.startswith(".m.png."):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    one_line(
        run("mesh", dem, "-o", out / "m.obj", "--texture", dem),
        capfd,
        f"cannot write {out / 'm.png'}: no space left on device",
    )
    assert list(out.iterdir()) == []


def test_a_read_only_directory(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture
) -> None:
    """Refused before any work; and when it became read-only after that check, the write
    fails with one line naming the output. Root writes anywhere on a writable file system,
    so as root the directory is a read-only tmpfs; as a user, a directory without write
    permission."""
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() == 0:
        proc = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(locked)],
            capture_output=True,
        )
        if proc.returncode:
            pytest.skip(f"cannot mount a read-only tmpfs here ({proc.stderr.strip()!r})")
        cause = "read-only file system"
    else:
        locked.chmod(0o555)
        cause = "permission denied"
    try:
        dem, (image, camera, *_) = scene / "dem.tif", views(scene)
        args = ["visibility", dem, image, camera, "-o", locked / "v.tif"]
        refused = "a read-only file system" if os.geteuid() == 0 else cause
        one_line(run(*args), capfd, locked, f"cannot write in the directory {locked}", refused)
        monkeypatch.setattr(os, "access", lambda *a, **k: True)
        one_line(run(*args), capfd, f"cannot write {locked / 'v.tif'}: {cause}")
        assert list(locked.iterdir()) == []
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", "-l", str(locked)], check=True)


def test_stale_temporaries_of_a_killed_run_are_removed(scene: Path, tmp_path: Path) -> None:
    """A run killed with SIGKILL in the middle of its write leaves its temporary file; the
    next run writing that output removes it (its process is gone), not one of a live run;
    so are temporary directories (synth, demo)."""
    from orthomvp.io.outputs import temp_name

    out = tmp_path / "out"
    out.mkdir()
    image, camera, *_ = views(scene)
    script = (
        "import os, signal, sys, rasterio.io\n"
        "write = rasterio.io.DatasetWriter.write\n"
        "def killed(self, *a, **k):\n"
        "    write(self, *a, **k)\n"
        "    os.kill(os.getpid(), signal.SIGKILL)\n"
        "rasterio.io.DatasetWriter.write = killed\n"
        "from orthomvp.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    args = ["visibility", scene / "dem.tif", image, camera, "-o", out / "v.tif"]
    proc = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)], capture_output=True, timeout=120
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    stale = leftovers(out)
    assert stale and all(name.startswith(".v.tif.orthomvp-") for name in stale), stale
    live = temp_name(out / "v.tif")  # this process's: alive
    live.write_bytes(b"in progress")
    code, _, err = run(*args)
    assert code == 0, err
    assert leftovers(out) == [live.name] and (out / "v.tif").is_file()
    # a temporary directory (synth, demo) of a process that is gone
    gone = subprocess.Popen(["true"])
    gone.wait()
    name = temp_name(out / "scene").name.replace(f"-{os.getpid()}-", f"-{gone.pid}-", 1)
    (out / name / "sub").mkdir(parents=True)
    code, _, err = run("-q", "synth", "planar", out / "scene", "--size", "16")
    assert code == 0, err
    assert leftovers(out) == [live.name] and (out / "scene" / "dem.tif").is_file()


def _traced(files: tuple[str, ...], at: int, sig: signal.Signals, opcodes: bool) -> list[int]:
    """Trace lines (or opcodes) in ``files``; at event number ``at`` raise ``sig`` in this
    process. Returns a one-item list counting the events seen, growing while tracing."""
    seen = [0]

    def trace(frame, event, arg):  # noqa: ANN001, ANN202
        if frame.f_code.co_filename not in files:
            return None
        frame.f_trace_opcodes = opcodes
        if event in ("line", "opcode"):
            seen[0] += 1
            if seen[0] == at:
                signal.raise_signal(sig)
        return trace

    sys.settrace(trace)
    return seen


def signal_at_every_step(
    write: Callable[[], None],
    check: Callable[[], None],
    out: Path,
    opcodes: bool,
    signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM),
) -> int:
    """Run ``write`` again and again with each of ``signals`` (SIGTERM with the CLI's handler, see
    :func:`orthomvp.cli.sigterm_raises`) raised at its first, second, ... traced step in the
    output writer (``orthomvp.io``'s outputs, signals, write_errors, preflight and raster, and
    contextlib), until a run ends before the step; after an interrupt,
    :func:`orthomvp.io.outputs.remove_temporaries` runs, as the CLI runs it.
    After each: the signal was not lost, the handlers of before still get the signals,
    stderr is the one of before, no temporary file is left, and ``check`` passes. Returns the
    number of steps."""
    import contextlib as ctx

    from orthomvp.cli import Terminated, sigterm_raises
    from orthomvp.io import outputs, preflight, raster, write_errors
    from orthomvp.io import signals as holding  # (``signals`` is the argument)

    writer = (outputs, holding, write_errors, preflight, raster)
    files = (*(m.__file__ for m in writer), ctx.__file__)
    stderr = os.fstat(2)
    kinds = {
        signal.SIGINT: KeyboardInterrupt,
        signal.SIGTERM: Terminated,
        signal.SIGHUP: Terminated,
    }
    for sig in signals:
        kind, at = kinds[sig], 1
        while True:
            with sigterm_raises():
                seen = _traced(files, at, sig, opcodes)
                try:
                    write()
                    interrupted = False
                except kind:
                    interrupted = True
                    outputs.remove_temporaries()  # as orthomvp.cli.main does
                finally:
                    sys.settrace(None)
                # the handlers of before still get the signals
                with pytest.raises(KeyboardInterrupt):
                    signal.raise_signal(signal.SIGINT)
                if interrupted and sig != signal.SIGINT:  # the CLI's handler: once only
                    assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
                else:
                    with pytest.raises(Terminated):
                        signal.raise_signal(signal.SIGTERM)
            signal.signal(signal.SIGINT, signal.default_int_handler)
            assert interrupted == (seen[0] >= at), f"{sig.name} at step {at} was lost"
            assert (os.fstat(2).st_ino, os.fstat(2).st_dev) == (stderr.st_ino, stderr.st_dev)
            assert hidden(out) == [], f"{sig.name} at step {at} of {seen[0]}"
            check()
            if not interrupted:
                break
            at += 1
    return at


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_signal_at_any_step_of_writing_a_set_leaves_all_or_nothing(
    tmp_path: Path, sig: signal.Signals
) -> None:
    """SIGTERM or SIGHUP (with the CLI's handler) arriving at every line of creating, writing,
    renaming and removing a set of two outputs: both or neither are there, and no temporary file
    (SIGINT at every opcode: the slow test below)."""
    from orthomvp.io.outputs import write_set

    out = tmp_path / "out"
    out.mkdir()
    a, b = out / "a.txt", out / "b.txt"

    def write() -> None:
        for p in (a, b):
            p.unlink(missing_ok=True)
        write_set({a: lambda t: t.write_text("a"), b: lambda t: t.write_text("b")})

    def check() -> None:
        assert sorted(p.name for p in out.iterdir()) in ([], ["a.txt", "b.txt"])
        assert not a.exists() or (a.read_text(), b.read_text()) == ("a", "b")

    assert signal_at_every_step(write, check, out, False, (sig,)) > 100


@pytest.mark.slow
def test_a_signal_at_any_opcode_of_write_geotiff_leaves_nothing_partial(tmp_path: Path) -> None:
    """The race of issue 16: SIGINT at every bytecode instruction of
    :func:`orthomvp.io.raster.write_geotiff`'s temporary file handling never leaves
    ``.o.tif.*.tif``; the output is there complete or not at all."""
    import numpy as np
    import rasterio
    from affine import Affine

    from orthomvp.io.raster import write_geotiff

    out = tmp_path / "out"
    out.mkdir()
    data = np.arange(64, dtype=np.float32).reshape(8, 8)

    def write() -> None:
        (out / "o.tif").unlink(missing_ok=True)
        write_geotiff(out / "o.tif", data, Affine(1, 0, 0, 0, -1, 0), "EPSG:4326")

    def check() -> None:
        if (out / "o.tif").exists():
            with rasterio.open(out / "o.tif") as src:
                assert (src.read(1) == data).all()

    assert signal_at_every_step(write, check, out, True, (signal.SIGINT,)) > 1000
