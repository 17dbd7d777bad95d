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
    with rasterio.open(out) as src:
        assert src.count >= 1


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
