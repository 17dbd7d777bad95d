"""The long tail of faults (issue 29, points 9-13): SIGHUP, an output directory renamed during
the run, closed standard streams, camera files that are too large or not files, long and
non-UTF-8 output names, deeply nested JSON, and read errors that name their real cause.

After each case: the exit status is right, the error is one line that names the path and
the cause, and no temporary output is left. Every wait is bounded in time."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rasterio

from tests.test_faults import CRATER, assert_refused, run, views


@pytest.fixture
def scene(crater_dir: Path, tmp_path: Path) -> Path:
    """A copy of the crater scene's DEM, two images and their cameras in ``tmp_path/in``."""
    d = tmp_path / "in"
    d.mkdir()
    for name in CRATER:
        shutil.copy(crater_dir / name, d / name)
    return d


def hidden(directory: Path) -> list[str]:
    """Hidden entries (temporary outputs) anywhere under ``directory``."""
    return sorted(str(p.relative_to(directory)) for p in directory.rglob(".*"))


def long_ortho(scene: Path, out: Path, *extra: str) -> list[str]:
    """An ``orthomvp ortho`` command line on a fine grid (about 4 million posts, a few
    seconds), writing an orthophoto and a visibility into ``out``."""
    with rasterio.open(scene / "dem.tif") as src:
        res = max(src.bounds.right - src.bounds.left, src.bounds.top - src.bounds.bottom) / 2000
    image, camera, *_ = views(scene)
    return [
        sys.executable, "-m", "orthomvp", "-q", "ortho", str(scene / "dem.tif"), str(image),
        str(camera), "-o", str(out / "o.tif"), "--visibility", str(out / "v.tif"),
        "--res", str(res), str(res), "--tile", "256", "--threads", "1", *extra,
    ]  # fmt: skip


def wait_for_temporaries(proc: subprocess.Popen, out: Path, timeout: float = 120) -> None:
    """Wait (at most ``timeout`` s) until the run has created its temporary outputs in
    ``out``; the run must still be going."""
    deadline = time.monotonic() + timeout
    while not hidden(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert hidden(out), "no temporary output appeared"
    assert proc.poll() is None, "the run ended before the fault"


# --------------------------------------------------------------------------- 9: SIGHUP
@pytest.mark.slow
def test_sighup_during_a_run_is_handled_like_sigterm(scene: Path, tmp_path: Path) -> None:
    """SIGHUP (a closed terminal or SSH session) to a running ``orthomvp ortho``: exit 129,
    one line, and none of its temporary outputs left (before: 8 were)."""
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen(
        long_ortho(scene, out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        wait_for_temporaries(proc, out)
        time.sleep(0.3)
        proc.send_signal(signal.SIGHUP)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGHUP, err
    assert err == "orthomvp: interrupted; no partial output was kept\n"
    assert list(out.iterdir()) == []


def test_sighup_in_process_raises_like_sigterm(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A real SIGHUP delivered to this process while a command runs: status 129 and one line;
    the previous handler is back afterwards."""
    import orthomvp.engine.tile

    def hang_up(*a: object, **k: object) -> None:
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(5)  # (in a worker thread: the main thread's handler raises meanwhile)

    monkeypatch.setattr(orthomvp.engine.tile, "compute_visibility", hang_up)
    before = signal.getsignal(signal.SIGHUP)
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    result = run("visibility", dem, image, camera, "-o", tmp_path / "v.tif")
    assert_refused(result, 129, "interrupted; no partial output was kept")
    assert signal.getsignal(signal.SIGHUP) == before
    assert hidden(tmp_path) == [] and not (tmp_path / "v.tif").exists()


def test_sighup_ignored_as_nohup_ignores_it_stays_ignored(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under ``nohup`` (SIGHUP ignored when the command starts) a SIGHUP mid-run changes
    nothing: exit 0 and the output written."""
    import orthomvp.engine.tile

    real = orthomvp.engine.tile.compute_visibility

    def hang_up(*a: object, **k: object) -> object:
        os.kill(os.getpid(), signal.SIGHUP)
        return real(*a, **k)

    monkeypatch.setattr(orthomvp.engine.tile, "compute_visibility", hang_up)
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        dem, (image, camera, *_) = scene / "dem.tif", views(scene)
        code, _, err = run("visibility", dem, image, camera, "-o", tmp_path / "v.tif")
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert code == 0, err
    assert (tmp_path / "v.tif").is_file() and hidden(tmp_path) == []


# ---------------------------------------------------- 10: an output directory renamed
def test_an_output_directory_renamed_during_the_run_keeps_no_temporaries(
    scene: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The output directory is renamed while the GeoTIFFs are written: one line naming the
    output and the cause, and no temporary output left in the renamed directory (they are
    removed where they are now, not where they were)."""
    import rasterio.io

    out, moved = tmp_path / "out", tmp_path / "moved"
    out.mkdir()
    written = rasterio.io.DatasetWriter.write

    def write_then_rename(self: rasterio.io.DatasetWriter, *a: object, **k: object) -> None:
        written(self, *a, **k)
        if out.exists():
            out.rename(moved)

    monkeypatch.setattr(rasterio.io.DatasetWriter, "write", write_then_rename)
    dem, (image, camera, *_) = scene / "dem.tif", views(scene)
    args = ["ortho", dem, image, camera, "-o", out / "o.tif", "--visibility", out / "v.tif"]
    assert_refused(run(*args), 2, f"cannot write {out}/", f"its directory {out} was moved")
    assert not out.exists() and list(moved.iterdir()) == []


def test_a_temporary_directory_is_removed_where_its_parent_went(tmp_path: Path) -> None:
    """:func:`orthomvp.io.outputs.atomic_dir` with its parent renamed in the block: the
    temporary directory (files and subdirectories) is removed in the renamed parent."""
    from orthomvp.errors import OrthoMVPError
    from orthomvp.io.outputs import atomic_dir

    parent, moved = tmp_path / "p", tmp_path / "q"
    parent.mkdir()
    with pytest.raises((OrthoMVPError, OSError)):
        with atomic_dir(parent / "scene") as tmp:
            (tmp / "sub").mkdir()
            (tmp / "sub" / "a.txt").write_text("a")
            (tmp / "sub" / "link").symlink_to(tmp_path)  # not followed
            parent.rename(moved)
    assert list(moved.iterdir()) == [] and tmp_path.is_dir()


def test_a_directory_written_again_merges_its_folders(tmp_path: Path) -> None:
    """:func:`orthomvp.io.outputs.atomic_dir` into a directory that holds an earlier run's
    files and folders (the demo's ``scene/``): files are replaced, folders merge (a rename
    cannot replace a folder that holds files: the demo run twice failed 'directory not
    empty'), and what else is there stays."""
    from orthomvp.io.outputs import atomic_dir

    out = tmp_path / "out"
    for text in ("first", "second"):
        with atomic_dir(out) as tmp:
            (tmp / "index.html").write_text(text)
            (tmp / "scene" / "deep").mkdir(parents=True)
            (tmp / "scene" / "dem.tif").write_text(text)
            (tmp / "scene" / "deep" / "a.txt").write_text(text)
        if text == "first":
            (out / "scene" / "notes.txt").write_text("mine")
    assert (out / "index.html").read_text() == "second"
    assert (out / "scene" / "dem.tif").read_text() == "second"
    assert (out / "scene" / "deep" / "a.txt").read_text() == "second"
    assert (out / "scene" / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary left


def test_a_directory_written_again_refuses_a_clash_before_moving_anything(
    tmp_path: Path,
) -> None:
    """A new run's folder where the earlier directory holds a file of its name (or a link to
    a folder elsewhere), or the reverse: one OutputError naming it, and nothing moved."""
    from orthomvp.errors import OutputError
    from orthomvp.io.outputs import atomic_dir

    outside = tmp_path / "outside"
    outside.mkdir()
    for clash in ("file", "link", "folder"):
        out = tmp_path / clash
        (out / "scene").mkdir(parents=True)
        if clash == "file":
            (out / "scene" / "deep").write_text("mine")
        elif clash == "link":
            (out / "scene" / "deep").symlink_to(outside, target_is_directory=True)
        else:
            (out / "scene" / "dem.tif").mkdir()
        before = sorted(str(p.relative_to(tmp_path)) for p in out.rglob("*"))
        with pytest.raises(OutputError, match="scene/(deep|dem.tif)"):
            with atomic_dir(out) as tmp:
                (tmp / "index.html").write_text("new")
                (tmp / "scene" / "deep").mkdir(parents=True)
                (tmp / "scene" / "deep" / "a.txt").write_text("new")
                (tmp / "scene" / "dem.tif").write_text("new")
        assert sorted(str(p.relative_to(tmp_path)) for p in out.rglob("*")) == before
    assert list(outside.iterdir()) == []  # nothing followed the link out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder", "link", "outside"]


# -------------------------------------------------------------- 11: standard streams
def _closed(fd: int) -> None:
    os.close(fd)


@pytest.mark.parametrize("closed", [0, 1])
def test_a_closed_stdin_or_stdout_does_not_fail_a_run(
    scene: Path, tmp_path: Path, closed: int
) -> None:
    """``orthomvp ... >&-`` (or ``<&-``): the output is written and the exit status is 0 (before:
    1, with an AttributeError traceback); nothing else takes file descriptor 1's place."""
    image, camera, *_ = views(scene)
    out = tmp_path / "o.tif"
    proc = subprocess.run(
        [sys.executable, "-m", "orthomvp", "ortho", scene / "dem.tif", image, camera, "-o", out],
        stdout=None if closed == 1 else subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: _closed(closed),
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and out.is_file()
    ref = tmp_path / "ref.tif"
    assert run("ortho", scene / "dem.tif", image, camera, "-o", ref)[0] == 0
    with rasterio.open(out) as src, rasterio.open(ref) as want:  # (nothing printed into it)
        assert src.read().tobytes() == want.read().tobytes()


def test_a_closed_stderr_keeps_errors_off_stdout(scene: Path, tmp_path: Path) -> None:
    """``orthomvp ... 2>&-``: an error still exits 2, and is not printed on stdout instead."""
    image, *_ = views(scene)
    proc = subprocess.run(
        [sys.executable, "-m", "orthomvp", "ortho", scene / "dem.tif", image,
         scene / "none.tsai", "-o", tmp_path / "o.tif"],
        stdout=subprocess.PIPE,
        preexec_fn=lambda: _closed(2),
        text=True,
        timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert list(tmp_path.iterdir()) == [scene]


# ------------------------------------------------------------ 12: camera files, bounded
CAMERA_SUFFIXES = (
    ".tsai", ".pinhole", ".json", ".csv", ".geojson", ".yaml", ".yml", ".rpb", ".txt", ".tif",
    ".tiff", ".cub", "",
)  # fmt: skip
"""A suffix of every camera format in orthomvp.camera.FORMATS (and none: sniffed)."""


def test_every_camera_suffix_is_covered() -> None:
    from orthomvp.camera import FORMATS

    assert {s for fmt in FORMATS for s in fmt.suffixes} <= set(CAMERA_SUFFIXES)


def _bounded(call: object, timeout: float = 20) -> BaseException | None:
    """Run ``call`` in a daemon thread for at most ``timeout`` s; returns what it raised
    (None if nothing). Fails if it is still running (blocked on a FIFO, reading endlessly)."""
    import threading

    raised: list[BaseException | None] = [None]

    def target() -> None:
        try:
            call()  # type: ignore[operator]
        except BaseException as exc:  # noqa: BLE001 (returned to the test)
            raised[0] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(timeout)
    assert not thread.is_alive(), f"still running after {timeout} s"
    return raised[0]


@pytest.mark.parametrize("suffix", CAMERA_SUFFIXES)
def test_a_camera_that_is_dev_zero_or_a_fifo_is_refused_at_once(
    tmp_path: Path, suffix: str
) -> None:
    """Every camera reader refuses a symbolic link to /dev/zero (which grew until memory ran
    out) and a FIFO (which waited for a writer) by what it is, at once."""
    from orthomvp.camera import read_camera
    from orthomvp.errors import InputError

    zero, fifo = tmp_path / f"zero{suffix}", tmp_path / f"fifo{suffix}"
    zero.symlink_to("/dev/zero")
    os.mkfifo(fifo)
    for path, words in ((zero, "a character device (/dev/zero)"), (fifo, "a FIFO")):
        exc = _bounded(lambda path=path: read_camera(path, "image.tif"))
        assert isinstance(exc, InputError), repr(exc)
        assert str(exc).startswith(f"{path}: ") and words in str(exc), str(exc)
        assert "not a regular file" in str(exc)


@pytest.mark.parametrize(
    "suffix", [s for s in CAMERA_SUFFIXES if s not in (".tif", ".tiff", ".cub")]
)
def test_a_camera_file_larger_than_the_limit_is_refused_before_it_is_read(
    tmp_path: Path, suffix: str
) -> None:
    """A sparse 2 GB camera file (zeros, as in the issue: it peaked at 14.7 GB as a .tsai) is
    refused from its size, reading nothing: well under 1 MB of memory and a second."""
    import tracemalloc

    from orthomvp.camera import read_camera
    from orthomvp.errors import InputError
    from orthomvp.io.files import MAX_SMALL_FILE

    big = tmp_path / f"big{suffix}"
    with open(big, "wb") as fh:
        fh.truncate(2_000_000_000)
    tracemalloc.start()
    start = time.monotonic()
    try:
        with pytest.raises(InputError) as caught:
            read_camera(big, "image.tif")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.monotonic() - start < 5 and peak < 1_000_000
    assert str(caught.value) == (
        f"{big}: 2 GB is more than a camera file may be ({MAX_SMALL_FILE >> 20} MiB at most)"
    )


def test_the_bounded_read_takes_up_to_the_limit_and_no_more(tmp_path: Path) -> None:
    from orthomvp.errors import InputError
    from orthomvp.io.files import read_bounded

    f = tmp_path / "f.txt"
    f.write_bytes(b"x" * 1000)
    assert read_bounded(f, "test file", limit=1000) == b"x" * 1000
    with pytest.raises(InputError, match=r"f.txt: 1 kB is more than a test file may be"):
        read_bounded(f, "test file", limit=999)
    with pytest.raises(InputError, match=r"test file not found \(no such file\)"):
        read_bounded(tmp_path / "none", "test file")
    with pytest.raises(InputError, match=r"the test file is a directory, not a regular file"):
        read_bounded(tmp_path, "test file")


def test_the_isis_label_reader_is_bounded(tmp_path: Path) -> None:
    """An ISIS3 label without its End line in its first 64 MiB (a sparse 80 MB file), /dev/zero
    and a FIFO as a cube: refused, in bounded time."""
    from orthomvp.errors import InputError
    from orthomvp.io.isis import label_text

    endless = tmp_path / "endless.cub"
    with open(endless, "wb") as fh:
        fh.write(b"Object = IsisCube\n")
        fh.truncate(80_000_000)
    exc = _bounded(lambda: label_text(endless))
    assert isinstance(exc, InputError) and "no End line in the label's first 64 MiB" in str(exc)
    zero, fifo = tmp_path / "zero.cub", tmp_path / "fifo.cub"
    zero.symlink_to("/dev/zero")
    os.mkfifo(fifo)
    for path, words in ((zero, "a character device (/dev/zero)"), (fifo, "a FIFO")):
        exc = _bounded(lambda path=path: label_text(path))
        assert isinstance(exc, InputError) and words in str(exc), repr(exc)


@pytest.mark.parametrize("kind", ["fifo", "null"])
def test_an_image_that_is_a_fifo_or_dev_null_is_named_as_such(
    scene: Path, tmp_path: Path, kind: str
) -> None:
    """Not "no such file" (as before): what the file is."""
    image = tmp_path / "image.tif"
    if kind == "fifo":
        os.mkfifo(image)
    else:
        image.symlink_to(os.devnull)
    _, camera, *_ = views(scene)
    words = "a FIFO" if kind == "fifo" else f"a character device ({os.devnull})"
    result = _run_bounded("ortho", scene / "dem.tif", image, camera, "-o", tmp_path / "o.tif")
    assert_refused(result, 2, image, words, "not a regular file")
    assert not (tmp_path / "o.tif").exists() and hidden(tmp_path) == []


def _run_bounded(*args: object) -> tuple[int, str, str]:
    """:func:`run` in a thread, failing after 60 s."""
    result: list[tuple[int, str, str]] = []
    exc = _bounded(lambda: result.append(run(*args)), 60)
    assert exc is None, repr(exc)
    return result[0]


# ------------------------------------------------------------- 13: names and messages
def test_a_long_output_name_is_written_not_refused(scene: Path, tmp_path: Path) -> None:
    """A 244-byte output name (valid: at most 255) was refused because its temporary's name
    was too long, with an atexit traceback; now the temporary's name is shortened."""
    image, camera, *_ = views(scene)
    out = tmp_path / ("a" * 240 + ".tif")
    assert len(out.name) == 244
    code, _, err = run("ortho", scene / "dem.tif", image, camera, "-o", out,
                       "--visibility", tmp_path / ("v" * 250 + ".tif"))  # fmt: skip
    assert code == 0, err
    assert out.is_file() and hidden(tmp_path) == []
    with rasterio.open(out) as src:
        assert src.count >= 1


def test_the_temporaries_of_a_long_name_fit_and_are_recognised_when_stale(
    tmp_path: Path,
) -> None:
    """A temporary's name stays within 255 bytes for any valid output name (long, multi-byte,
    with a long suffix), and :func:`remove_stale` still recognises it as the output's."""
    from orthomvp.io.outputs import remove_stale, temp_name

    gone = subprocess.Popen(["true"])
    gone.wait()
    for name in ("é" * 125 + ".tif", "x." + "y" * 250, "b" * 255, os.fsdecode(b"\xff" * 200)):
        out = tmp_path / name
        tmp = temp_name(out, ".ovr16")
        assert len(os.fsencode(tmp.name)) <= 200
        stale = tmp.with_name(tmp.name.replace(f"-{os.getpid()}-", f"-{gone.pid}-", 1))
        stale.write_bytes(b"left by a killed run")
        assert remove_stale(out) == [stale] and not stale.exists()


def test_a_non_utf8_output_name_is_written(scene: Path, tmp_path: Path) -> None:
    """An output name that is not UTF-8 (bytes 0xff 0xfe) was a UnicodeEncodeError (GDAL takes
    UTF-8 names): the temporary's name is UTF-8 and is renamed onto the name as given."""
    image, camera, *_ = views(scene)
    out = tmp_path / os.fsdecode(b"\xff\xfe.tif")
    code, _, err = run("ortho", scene / "dem.tif", image, camera, "-o", out)
    assert code == 0, err
    assert b"\xff\xfe.tif" in os.listdir(os.fsencode(tmp_path)) and hidden(tmp_path) == []
    assert_refused(
        run("ortho", out, image, camera, "-o", tmp_path / "o.tif"), 2, "whose name is not UTF-8"
    )


def test_a_camera_json_nested_200000_deep_is_a_format_error(tmp_path: Path) -> None:
    """A RecursionError before; now one FormatError naming the file."""
    from orthomvp.camera import read_camera
    from orthomvp.errors import FormatError

    for name, text in (
        ("deep.json", '{"fu": ' + "[" * 200_000 + "]" * 200_000 + "}"),
        ("list.json", "[" * 200_000 + "]" * 200_000),
    ):
        (tmp_path / name).write_text(text)
        with pytest.raises(FormatError, match="nested too deeply to be a camera file"):
            read_camera(tmp_path / name)


def _cut(src: Path, dst: Path, size: float) -> int:
    """Write the first ``size`` bytes of ``src`` (a fraction of it, if below 1) to ``dst``;
    returns how many."""
    data = src.read_bytes()
    n = int(len(data) * size) if size < 1 else int(size)
    assert n < len(data)
    dst.write_bytes(data[:n])
    return n


@pytest.mark.parametrize("size", [400, 2000, 0.3, 0.6, 0.9])
def test_a_truncated_dem_or_image_names_gdals_cause(
    scene: Path, tmp_path: Path, size: float
) -> None:
    """A DEM or an image cut short (at 400 B, 2000 B, 30 %, 60 %, 90 % of it): "corrupt or
    truncated" and the file's size, with GDAL's own cause for the DEM (libtiff's read error,
    not "Read failed. See previous exception for details.") and, for the image, the first
    block past the end of the file (its blocks are checked before any work, so that every
    backend refuses it alike). A DEM cut at 400 B was reported as having "no CRS"."""
    image, camera, *_ = views(scene)
    dem, cut = tmp_path / "dem.tif", tmp_path / "image.tif"
    n = _cut(scene / "dem.tif", dem, size)
    line = assert_refused(
        run("ortho", dem, image, camera, "-o", tmp_path / "o.tif"), 2, dem,
        "corrupt or truncated", f"the file has {n:,} bytes",
    )  # fmt: skip
    assert "See previous" not in line and "no CRS" not in line
    assert "IO error" in line or "Read error" in line, line
    n = _cut(image, cut, size)
    line = assert_refused(
        run("ortho", scene / "dem.tif", cut, camera, "-o", tmp_path / "o.tif"), 2, cut,
        "corrupt or truncated", f"past the end of the file ({n:,} bytes)",
    )  # fmt: skip
    assert "See previous" not in line
    assert hidden(tmp_path) == [] and not (tmp_path / "o.tif").exists()


def test_corrupt_data_gives_the_deepest_cause() -> None:
    from rasterio.errors import RasterioIOError

    from orthomvp.io.raster import corrupt_data

    try:
        try:
            raise OSError("TIFFFillStrip:Read error at scanline 0; got 1 bytes, expected 9")
        except OSError as inner:
            raise RasterioIOError("Read failed. See previous exception for details.") from inner
    except RasterioIOError as exc:
        text = str(corrupt_data("/nonexistent/x.tif", exc))
    assert text == (
        "/nonexistent/x.tif: corrupt or truncated raster data (TIFFFillStrip:Read error at "
        "scanline 0; got 1 bytes, expected 9)"
    )


def _dem_variant(scene: Path, out: Path, change: str) -> Path:
    import numpy as np
    from affine import Affine

    with rasterio.open(scene / "dem.tif") as src:
        profile, values = src.profile, src.read(1)
    if change == "checkerboard":
        values[::2, ::2] = np.nan
        values[1::2, 1::2] = np.nan
    elif change == "columns":
        values[:, ::2] = np.nan
    elif change == "past the pole":
        t = profile["transform"]
        profile["transform"] = Affine(t.a, t.b, t.c, t.d, t.e, 95.0)
    elif change == "complex":
        profile.update(dtype="complex64", nodata=None)
        values = values.astype(np.complex64) * (1 + 1j)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(values, 1)
    return out


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ("checkerboard", "no 2 x 2 posts of the DEM all have heights"),
        ("columns", "no 2 x 2 posts of the DEM all have heights"),
        ("past the pole", "past the pole"),
        ("complex", "band 1 holds complex numbers (complex64)"),
    ],
)
def test_a_dem_is_refused_for_its_real_cause(
    scene: Path, tmp_path: Path, change: str, words: str
) -> None:
    """NaN on every other post and a DEM past latitude 90 were reported as "camera 1 is beyond
    the DEM's horizon"; a complex DEM was taken as its real part."""
    dem = _dem_variant(scene, tmp_path / "dem.tif", change)
    image, camera, *_ = views(scene)
    line = assert_refused(run("ortho", dem, image, camera, "-o", tmp_path / "o.tif"), 2, dem, words)
    assert "horizon" not in line
    assert not (tmp_path / "o.tif").exists() and hidden(tmp_path) == []


def test_the_body_frame_test_samples_valid_posts(scene: Path, tmp_path: Path) -> None:
    """:func:`body_plausible` on a DEM with NaN on every other post: a camera 100 km above the
    DEM's centre post (the DEM's own transformation to body-fixed metres) is above it, one at
    the body's centre is not."""
    import numpy as np

    from orthomvp.geometry.terrain import Terrain
    from orthomvp.geometry.world import body_plausible

    terrain = Terrain.read(_dem_variant(scene, tmp_path / "dem.tif", "checkerboard"))
    rows, cols = terrain.shape
    c, r = terrain.grid()
    centre = terrain.to_world(c[rows // 2, cols // 2 + 1], r[rows // 2, cols // 2 + 1], 0.0)
    above = centre * (1 + 100_000 / np.linalg.norm(centre))
    assert body_plausible(terrain, np.array([above, [0.0, 0.0, 0.0]])).tolist() == [True, False]


def test_an_output_name_ending_in_a_slash_is_refused(scene: Path, tmp_path: Path) -> None:
    """``-o o.tif/`` wrote ``o.tif``: a trailing slash names a directory."""
    image, camera, *_ = views(scene)
    dem = scene / "dem.tif"
    for args in (
        ["ortho", dem, image, camera, "-o", f"{tmp_path / 'o.tif'}/"],
        ["ortho", dem, image, camera, "-o", tmp_path / "o.tif", "--visibility",
         f"{tmp_path / 'v.tif'}/"],
        ["fit", dem, *views(scene), "-o", tmp_path / "f.tif", "--cost", f"{tmp_path / 'c.tif'}/"],
    ):  # fmt: skip
        assert_refused(run(*args), 2, "ends in '/', so names a directory")
    assert list(tmp_path.iterdir()) == [scene]


def test_sizes_from_a_cube_label_are_not_allocated_beyond_the_file(tmp_path: Path) -> None:
    """A cube label claiming 10^12 samples x lines: the pixels are read up to the file's end
    and refused as truncated (``read(n)`` allocated n bytes first: a MemoryError)."""
    import re

    import numpy as np

    from orthomvp.errors import FormatError
    from orthomvp.io.raster import read_image
    from tests.test_isis import write_cube

    path = tmp_path / "cube.cub"
    write_cube(path, np.zeros((2, 5, 6), np.uint16), "UnsignedWord", "Msb", (4, 4))
    data = path.read_bytes()
    label = re.sub(rb"Samples\s*=\s*6", b"Samples = 1000000", data[:1024])
    label = re.sub(rb"Lines\s*=\s*5", b"Lines   = 1000000", label)
    path.write_bytes(label[:1024] + data[1024:])
    with pytest.raises(FormatError, match="truncated cube: .* the file has 256"):
        read_image(path)


@pytest.mark.realdata
def test_a_cube_table_larger_than_its_file_is_truncated_not_allocated(tmp_path: Path) -> None:
    """A spiceinit'd cube's table claiming 4e11 records: a one-line FormatError naming the
    table, not a MemoryError."""
    import re

    from orthomvp.camera import read_camera
    from orthomvp.errors import FormatError
    from tests.test_isis_camera import LRO, _edited

    def edit(text: str) -> str:
        return re.sub(
            r"(Name\s*= InstrumentPointing\n\s*StartByte\s*= \d+\n\s*)Bytes(\s*)= 256\n"
            r"(\s*)Records(\s*)= 4\n",
            r"\1Bytes\2= 25600000000000\n\3Records\4= 400000000000\n",
            text,
            count=1,
        )

    path = _edited(tmp_path, LRO, edit)
    with pytest.raises(FormatError, match=r"truncated Table .* the file holds"):
        read_camera(path)


def test_a_ctrl_c_while_the_command_line_is_imported_is_one_line() -> None:
    """A Ctrl-C that lands while ``orthomvp`` still imports its modules (before its own
    handling runs) ends as one line with exit status 130, not Python's traceback."""
    code = (
        "import sys\n"
        "class Interrupting:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'orthomvp.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupting())\n"
        "from orthomvp._entry import main\n"
        "main()\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 130
    assert proc.stderr == "orthomvp: interrupted; no partial output was kept\n"
