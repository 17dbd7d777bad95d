"""Fault injection for the engine's worker processes and Dask, with real processes and signals:
a real Dask scheduler and workers on 127.0.0.1 (``dask scheduler``, ``dask worker``), an HTTP
server and a listener that never answers as false schedulers, workers and schedulers killed
mid-run, SIGINT and SIGTERM during runs on ``--processes`` and ``--dask local:N``, and the parent
killed outright. Each case ends in bounded time (every wait has a timeout) with one line on
stderr, the exit status of its kind, no output, no leftover process and no Dask scratch folder.

Exit status rule: a cluster that cannot be used (no scheduler, not a scheduler, no workers,
workers or scheduler gone mid-run) is the user's environment, not a bug: 2, as every user error."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("distributed")

pytestmark = pytest.mark.slow

CASE_SECONDS = 30.0
"""Every case ends within this (the brief's bound; the engine's own give-up is 10 s)."""


# ---------------------------------------------------------------------------- helpers


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The crater scene of 160 x 160 posts: with 8-post tiles, 400 tiles and a run of several
    seconds on one Dask worker, long enough to kill something mid-run."""
    return crater(tmp_path_factory.mktemp("scene"), 160, 40)


@pytest.fixture(scope="module")
def long_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The crater scene of 200 x 200 posts (625 8-post tiles) for runs on two worker
    processes that a test stops once they log their tiles: the log's first line comes after
    2 s of tiles (``orthomvp.engine.progress.LOG_AFTER``), and on a quiet machine two
    processes finish :func:`scene`'s 400 tiles about then, so the signal found the outputs
    complete."""
    return crater(tmp_path_factory.mktemp("long"), 200, 32)


def crater(folder: Path, size: int, spacing: float) -> Path:
    """A crater scene of ``size`` x ``size`` posts ``spacing`` metres apart written by
    ``orthomvp synth`` into ``folder``/scene."""
    out = folder / "scene"
    args = ["--size", str(size), "--spacing", str(spacing)]
    subprocess.run(
        [*ORTHOMVP, "-q", "synth", "crater", str(out), *args], check=True, timeout=120, env=ENV
    )
    return out


ORTHOMVP = [sys.executable, "-c", "from orthomvp.cli import main_entry; main_entry()"]
ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])}


def ortho_args(scene: Path, out: Path, *extra: str) -> list[str]:
    return [
        *ORTHOMVP,
        "-q",
        "ortho",
        str(scene / "dem.tif"),
        str(scene / "oblique.tif"),
        str(scene / "oblique.tsai"),
        "-o",
        str(out),
        *extra,
    ]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        with contextlib.suppress(OSError, ValueError, IndexError):
            ppid = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
            children.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def alive(pids: set[int]) -> set[int]:
    """Those of ``pids`` still running (zombies count as gone)."""
    left = set()
    for pid in pids:
        with contextlib.suppress(OSError):
            if Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z":
                left.add(pid)
    return left


def wait_gone(pids: set[int], seconds: float) -> set[int]:
    """Wait up to ``seconds`` for ``pids`` to end; those still alive."""
    deadline = time.monotonic() + seconds
    while alive(pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return alive(pids)


@contextlib.contextmanager
def started(args: list[str], **kw: object) -> Iterator[subprocess.Popen]:
    """A process of its own group, killed with its group at the end."""
    kw.setdefault("env", ENV)
    proc = subprocess.Popen(args, start_new_session=True, **kw)  # type: ignore[call-overload]
    try:
        yield proc
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)


def wait_listening(port: int, seconds: float = 20.0) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        with socket.socket() as s, contextlib.suppress(OSError):
            s.settimeout(0.5)
            s.connect(("127.0.0.1", port))
            return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on port {port} after {seconds} s")


@contextlib.contextmanager
def scheduler() -> Iterator[tuple[str, subprocess.Popen]]:
    """A real ``dask scheduler`` on 127.0.0.1: (address, process)."""
    port = free_port()
    args = [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1"]
    args += ["--port", str(port), "--no-dashboard"]
    with started(args, stderr=subprocess.DEVNULL) as proc:
        wait_listening(port)
        yield f"tcp://127.0.0.1:{port}", proc


@contextlib.contextmanager
def worker(address: str) -> Iterator[subprocess.Popen]:
    """A real ``dask worker`` (a nanny and its worker process, one thread) of ``address``,
    registered with the scheduler before it is handed out."""
    args = [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1"]
    args += ["--nworkers", "1", "--no-dashboard"]
    with started(args, stderr=subprocess.PIPE, text=True) as proc:
        deadline = time.monotonic() + 25
        seen = ""
        while "Registered to" not in seen and time.monotonic() < deadline:
            seen += available(proc)
            time.sleep(0.1)
        assert "Registered to" in seen, seen
        yield proc


def finish(proc: subprocess.Popen, seconds: float = CASE_SECONDS) -> tuple[int, str, float]:
    """Wait for ``proc`` (bounded): exit status, stderr, seconds waited."""
    t0 = time.monotonic()
    try:
        _, err = proc.communicate(timeout=seconds)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        _, err = proc.communicate(timeout=10)
        raise AssertionError(f"no exit within {seconds} s: {err}") from None
    return proc.returncode, err, time.monotonic() - t0


def assert_one_line(status: int, err: str, expected: int, *words: str) -> str:
    lines = err.strip().splitlines()
    assert status == expected, err
    assert len(lines) == 1 and lines[0].startswith("orthomvp: "), err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def assert_nothing_left(out: Path, tmp: Path | None = None) -> None:
    """No output, no temporary beside it, no Dask scratch folder in ``tmp``."""
    assert not out.exists()
    assert not [p.name for p in out.parent.iterdir() if p.name.startswith(".")]
    if tmp is not None:
        assert not list(tmp.iterdir()), list(tmp.iterdir())


def wait_progress(proc: subprocess.Popen, seconds: float, word: str = "tiles") -> str:
    """Read ``proc``'s stderr until a progress line with ``word`` (the run has started its
    tiles), bounded."""
    seen, deadline = "", time.monotonic() + seconds
    while word not in seen and time.monotonic() < deadline and proc.poll() is None:
        seen += available(proc)
        time.sleep(0.05)
    assert word in seen, seen
    return seen


def available(proc: subprocess.Popen) -> str:
    """What ``proc`` has written to its stderr pipe so far, without waiting for more."""
    assert proc.stderr is not None
    fd = proc.stderr.fileno()
    os.set_blocking(fd, False)
    chunks = []
    try:
        while chunk := os.read(fd, 1 << 16):
            chunks.append(chunk)
    except BlockingIOError:
        pass
    finally:
        os.set_blocking(fd, True)
    return b"".join(chunks).decode(errors="replace")


# ------------------------------------------------------------------- false schedulers


def test_an_http_server_is_not_a_scheduler(scene: Path, tmp_path: Path) -> None:
    port = free_port()
    http = [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"]
    with started(http, stderr=subprocess.DEVNULL, stdout=subprocess.DEVNULL):
        wait_listening(port)
        out = tmp_path / "o.tif"
        args = ortho_args(scene, out, "--dask", f"tcp://127.0.0.1:{port}")
        with started(args, stderr=subprocess.PIPE, text=True) as proc:
            status, err, seconds = finish(proc)
    assert_one_line(status, err, 2, "no Dask scheduler answers", "handshake")
    assert seconds < CASE_SECONDS
    assert_nothing_left(out)


def test_a_listener_that_never_answers(scene: Path, tmp_path: Path) -> None:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)  # accepted by the kernel, never read
        address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
        out = tmp_path / "o.tif"
        with started(
            ortho_args(scene, out, "--dask", address), stderr=subprocess.PIPE, text=True
        ) as proc:
            status, err, _ = finish(proc)
    assert_one_line(status, err, 2, "no Dask scheduler answers", address)
    assert_nothing_left(out)


@pytest.mark.parametrize(
    ("address", "words"),
    [
        ("tcp://", "missing port"),
        ("tcp://127.0.0.1", "missing port"),
        ("inproc://x", "not a usable Dask scheduler address"),
        ("tls://127.0.0.1:1", "TLS"),
        ("http://127.0.0.1:1", "unknown address scheme 'http'"),
    ],
)
def test_a_malformed_address_is_one_line(
    scene: Path, tmp_path: Path, address: str, words: str
) -> None:
    out = tmp_path / "o.tif"
    with started(
        ortho_args(scene, out, "--dask", address), stderr=subprocess.PIPE, text=True
    ) as proc:
        status, err, _ = finish(proc)
    assert_one_line(status, err, 2, address, words)
    assert_nothing_left(out)


def test_a_scheduler_with_no_workers(scene: Path, tmp_path: Path) -> None:
    out = tmp_path / "o.tif"
    with scheduler() as (address, _):
        args = ortho_args(scene, out, "--dask", address)
        with started(args, stderr=subprocess.PIPE, text=True) as proc:
            status, err, _ = finish(proc)
    assert_one_line(status, err, 2, "has no workers", address)
    assert_nothing_left(out)


# -------------------------------------------------------------------- deaths mid-run


def kill_tree(proc: subprocess.Popen) -> set[int]:
    """SIGKILL ``proc`` and every process below it (a nanny and its worker): their pids."""
    pids = {proc.pid, *descendants(proc.pid)}
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return pids


def test_the_last_worker_killed_mid_run(scene: Path, tmp_path: Path) -> None:
    """The only worker and its nanny SIGKILLed while tiles run: the run gives up after its
    10 s without a worker, one line, nothing written."""
    out = tmp_path / "o.tif"
    with scheduler() as (address, _), worker(address) as w:
        args = ortho_args(scene, out, "--dask", address, "--tile", "8")
        args.remove("-q")
        with started(args, stderr=subprocess.PIPE, text=True) as proc:
            wait_progress(proc, 25, "tiles:")
            assert not wait_gone(kill_tree(w), 5)
            status, err, seconds = finish(proc)
    lines = [x for x in err.strip().splitlines() if "tiles" not in x and "plan" not in x]
    assert_one_line(status, "\n".join(lines), 2, "no worker for 10 s", "nothing was written")
    assert "Traceback" not in err and "distributed." not in err
    assert seconds < CASE_SECONDS
    assert_nothing_left(out)


def test_one_worker_of_two_killed_mid_run_still_completes(scene: Path, tmp_path: Path) -> None:
    """One of two workers SIGKILLed (with its nanny) mid-run: its tiles run on the other one,
    and the orthophoto is the same as a run on threads."""
    import numpy as np
    import rasterio

    out, reference = tmp_path / "o.tif", tmp_path / "t.tif"
    subprocess.run(ortho_args(scene, reference, "--tile", "8"), check=True, timeout=60, env=ENV)
    with scheduler() as (address, _), worker(address) as w1, worker(address):
        args = ortho_args(scene, out, "--dask", address, "--tile", "8")
        args.remove("-q")
        with started(args, stderr=subprocess.PIPE, text=True) as proc:
            wait_progress(proc, 25, "tiles:")
            kill_tree(w1)
            status, err, _ = finish(proc)
    assert status == 0, err
    with rasterio.open(out) as a, rasterio.open(reference) as b:
        assert np.array_equal(a.read(), b.read(), equal_nan=True)


def test_the_scheduler_killed_mid_run(scene: Path, tmp_path: Path) -> None:
    out = tmp_path / "o.tif"
    with scheduler() as (address, sched), worker(address):
        args = ortho_args(scene, out, "--dask", address, "--tile", "8")
        args.remove("-q")
        with started(args, stderr=subprocess.PIPE, text=True) as proc:
            wait_progress(proc, 25, "tiles:")
            os.killpg(sched.pid, signal.SIGKILL)
            status, err, _ = finish(proc)
    progress = ("orthomvp: tiles:", "orthomvp: plan:", "orthomvp: planning")
    lines = [x for x in err.strip().splitlines() if not x.startswith(progress)]
    assert_one_line(status, "\n".join(lines), 2, "Dask scheduler", "nothing was written")
    assert "Traceback" not in err and "distributed." not in err
    assert_nothing_left(out)


# ----------------------------------------------------------------- the local cluster


def garbled_copy(scene: Path, tmp_path: Path) -> tuple[Path, Path]:
    """The oblique image with the middle third of its bytes replaced by noise (its header and
    block offsets intact: it opens, and fails only when a tile reads its pixels), and its
    camera."""
    import numpy as np

    image, camera = tmp_path / "garbled.tif", tmp_path / "garbled.tsai"
    data = bytearray((scene / "oblique.tif").read_bytes())
    third = len(data) // 3
    noise = np.random.default_rng(0).integers(0, 256, third, dtype=np.uint8)
    data[third : 2 * third] = noise.tobytes()
    image.write_bytes(bytes(data))
    shutil.copy(scene / "oblique.tsai", camera)
    return image, camera


def test_a_user_error_on_a_local_cluster_is_one_line(scene: Path, tmp_path: Path) -> None:
    """A corrupt image on ``--dask local:2`` (ortho and check), found by a worker: the same
    line and status as on threads (not an internal error), no Dask log, and no scratch folder
    left in TMPDIR."""
    image, camera = garbled_copy(scene, tmp_path)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**ENV, "TMPDIR": str(tmp)}
    dem = str(scene / "dem.tif")
    out = tmp_path / "o.tif"
    ortho = [*ORTHOMVP, "-q", "ortho", dem, str(image), str(camera), "-o", str(out)]
    check = [*ORTHOMVP, "-q", "check", dem, str(image), str(camera)]
    check += [str(scene / "nadir.tif"), str(scene / "nadir.tsai"), "-o", str(tmp_path / "chk")]
    for args in (ortho, check):
        threads = subprocess.run(args, capture_output=True, text=True, timeout=60, env=env)
        line = assert_one_line(threads.returncode, threads.stderr, 2, str(image))
        dask = subprocess.run(
            [*args, "--dask", "local:2"], capture_output=True, text=True, timeout=60, env=env
        )
        assert assert_one_line(dask.returncode, dask.stderr, 2) == line
        assert "corrupt or truncated raster data" in line
    assert_nothing_left(out, tmp)
    assert not (tmp_path / "chk").exists()


def test_a_local_cluster_leaves_no_scratch_space(scene: Path, tmp_path: Path) -> None:
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = tmp_path / "o.tif"
    done = subprocess.run(
        ortho_args(scene, out, "--dask", "local:2"),
        capture_output=True,
        text=True,
        timeout=90,
        env={**ENV, "TMPDIR": str(tmp)},
    )
    assert done.returncode == 0, done.stderr
    assert out.exists()
    assert not list(tmp.iterdir())


def past_the_end(scene: Path, tmp_path: Path) -> tuple[Path, Path]:
    """The oblique image as a tiled GeoTIFF of 16 x 16 blocks whose last block's offset points
    100 kB past the end of the file (the rest intact)."""
    import struct

    import rasterio

    image, camera = tmp_path / "past.tif", tmp_path / "past.tsai"
    with rasterio.open(scene / "oblique.tif") as src:
        profile, data = src.profile, src.read()
    profile.update(tiled=True, blockxsize=16, blockysize=16, compress="deflate")
    with rasterio.open(image, "w", **profile) as dst:
        dst.write(data)
    raw = bytearray(image.read_bytes())
    assert raw[:4] == b"II*\0"
    ifd = struct.unpack_from("<I", raw, 4)[0]
    for i in range(struct.unpack_from("<H", raw, ifd)[0]):
        entry = ifd + 2 + 12 * i
        tag, kind, count, value = struct.unpack_from("<HHII", raw, entry)
        if tag == 324:  # TileOffsets, LONG
            assert kind == 4 and count > 1
            struct.pack_into("<I", raw, value + 4 * (count - 1), len(raw) + 100_000)
    image.write_bytes(raw)
    shutil.copy(scene / "oblique.tsai", camera)
    return image, camera


def test_a_block_past_the_end_of_the_file_fails_on_every_backend(
    scene: Path, tmp_path: Path
) -> None:
    """One rule everywhere: the last block lies past the end of the file: exit 2, the same one
    line on threads (default and one), processes and a local Dask cluster, nothing written.
    (Before, only the default threads failed: their prefetch read the tile's whole window,
    the others only the pixels sampled, which miss that corner.)"""
    image, camera = past_the_end(scene, tmp_path)
    out = tmp_path / "o.tif"
    base = [*ORTHOMVP, "-q", "ortho", str(scene / "dem.tif"), str(image), str(camera)]
    lines = set()
    for backend in ([], ["--threads", "1"], ["--processes", "2"], ["--dask", "local:2"]):
        done = subprocess.run(
            [*base, "-o", str(out), *backend], capture_output=True, text=True, timeout=90, env=ENV
        )
        lines.add(assert_one_line(done.returncode, done.stderr, 2, str(image), "past the end"))
        assert_nothing_left(out)
    assert len(lines) == 1


# ------------------------------------------------------------------------- signals


def signal_run(
    scene: Path, tmp_path: Path, backend: list[str], sig: signal.Signals, group: bool
) -> tuple[int, str, set[int], Path]:
    """Start an orthophoto on ``backend``, send ``sig`` once its tiles run (to the process
    group, as a terminal's Ctrl-C, or to the command alone): status, stderr, the processes
    that were below it, the output path."""
    out = tmp_path / "o.tif"
    args = ortho_args(scene, out, "--tile", "8", *backend)
    args.remove("-q")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    with started(args, stderr=subprocess.PIPE, text=True, env={**ENV, "TMPDIR": str(tmp)}) as proc:
        before = wait_progress(proc, 25, "tiles:")
        below = descendants(proc.pid)
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        status, err, _ = finish(proc)
    return status, before + err, below, out


@pytest.mark.parametrize("backend", [["--processes", "2"], ["--dask", "local:2"]])
@pytest.mark.parametrize(
    ("sig", "group"),
    [(signal.SIGINT, True), (signal.SIGINT, False), (signal.SIGTERM, False)],
)
def test_a_signal_during_a_run_with_workers_is_one_line(
    long_scene: Path, tmp_path: Path, backend: list[str], sig: signal.Signals, group: bool
) -> None:
    """SIGINT (to the group, or the command alone) or SIGTERM while the workers run tiles:
    the signal's status and one line (no worker's traceback), nothing kept, and no worker
    left."""
    status, err, below, out = signal_run(long_scene, tmp_path, backend, sig, group)
    lines = [x for x in err.strip().splitlines() if "tiles" not in x and "plan" not in x]
    expected = 130 if sig == signal.SIGINT else 143
    assert_one_line(status, "\n".join(lines), expected, "interrupted; no partial output")
    assert "Traceback" not in err
    assert not wait_gone(below, 10)
    assert_nothing_left(out, tmp_path / "tmp")


def test_processes_die_with_their_parent(long_scene: Path, tmp_path: Path) -> None:
    """``--processes 2`` with the command SIGKILLed mid-run: its workers and multiprocessing's
    resource tracker end within seconds."""
    out = tmp_path / "o.tif"
    args = ortho_args(long_scene, out, "--tile", "8", "--processes", "2")
    args.remove("-q")
    with started(args, stderr=subprocess.PIPE, text=True) as proc:
        wait_progress(proc, 25, "tiles:")
        below = descendants(proc.pid)
        assert len(below) >= 3  # two workers and the resource tracker
        proc.kill()
        proc.wait(timeout=10)
        assert not wait_gone(below, 5)


# ------------------------------------------------------------------- memory preflight


def resident(pid: int) -> int:
    """Resident set of process ``pid``, bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmRSS for {pid}")


def tile_noting_process(plan: object, index: int, *args: object) -> object:
    """:func:`orthomvp.engine.tile.run_tile`, the worker's process id appended to the file
    ``$ORTHOMVP_TEST_PIDS``."""
    from orthomvp.engine.tile import run_tile

    result = run_tile(plan, index, *args)
    with open(os.environ["ORTHOMVP_TEST_PIDS"], "a") as out:
        out.write(f"{os.getpid()}\n")
    return result


def test_the_preflight_counts_each_worker_process_as_measured(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Worker processes (of a pool and of a local Dask cluster) measured after running tiles
    (the pool's tiles run again until each of its workers ran some: a loaded machine may give
    one worker every tile): each within :data:`WORKER_BYTES` and above half of it (the figure
    is neither low nor padded), and the plan's peak memory counts one per local worker."""
    from orthomvp.engine import dask_client, plan_ortho
    from orthomvp.engine.run import executor, results
    from orthomvp.engine.schedule import local_processes
    from orthomvp.engine.tile import run_tile
    from orthomvp.engine.tiling import WORKER_BYTES

    views = [(crater_dir / "oblique.tif", crater_dir / "oblique.tsai")]
    plan = plan_ortho(crater_dir / "dem.tif", views, tile=16, progress=False)
    jobs = [job.index for job in plan.tiles if job.views]
    kinds = (frozenset({"ortho"}), 1)
    pids = tmp_path / "pids.txt"
    monkeypatch.setenv("ORTHOMVP_TEST_PIDS", str(pids))
    with executor(plan, tile_noting_process, 2, 2) as (submit, wait):
        for _ in range(10):
            assert len(list(results(submit, wait, jobs, kinds, 2))) == len(jobs)
            if len(set(pids.read_text().split())) == 2:
                break
        assert len(set(pids.read_text().split())) == 2
        workers = [pid for pid in descendants(os.getpid()) if resident(pid) > 50 << 20]
        sizes = [resident(pid) for pid in workers]
    assert len(sizes) == 2 and all(WORKER_BYTES / 2 < size <= WORKER_BYTES for size in sizes)
    with dask_client(workers=2) as client:
        assert local_processes(None, client) == 2
        with executor(plan, run_tile, 2, None, client) as (submit, wait):
            assert len(list(results(submit, wait, jobs, kinds, 2))) == len(jobs)
        sizes = [resident(pid) for pid in client.run(os.getpid).values()]
        assert len(sizes) == 2 and all(WORKER_BYTES / 2 < s <= WORKER_BYTES for s in sizes)
        assert plan.peak_memory(1, 2) - plan.peak_memory(1, 0) == 2 * WORKER_BYTES


def test_a_signal_after_the_outputs_were_renamed_says_they_are_complete(
    scene: Path, tmp_path: Path
) -> None:
    """SIGTERM as soon as the orthophoto is in place, while the local cluster stops: either the
    command had ended (0), or it says that the outputs are complete (143), which they are."""
    import rasterio

    out = tmp_path / "o.tif"
    args = ortho_args(scene, out, "--dask", "local:2", "--grid", "dem")
    with started(args, stderr=subprocess.PIPE, text=True) as proc:
        deadline = time.monotonic() + CASE_SECONDS
        while not out.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGTERM)
        status, err, _ = finish(proc)
    if status == 143:
        assert_one_line(
            status, err, 143, "interrupted; the outputs were already complete", str(out)
        )
    else:
        assert (status, err) == (0, "")
    with rasterio.open(out) as src:  # complete: the DEM's whole grid
        assert src.read(1).shape == (160, 160)


DROPPED = (
    "import os, signal, sys, time\n"
    "import orthomvp.engine.run as run\n"
    "class Dropped:\n"
    "    def __del__(self):\n"
    "        os.kill(os.getpid(), signal.SIGTERM)\n"
    "        for _ in range(10**6): pass  # the handler raises in here\n"
)
"""The start of a script whose ``Dropped()`` objects raise SIGTERM's exception in their
``__del__``, where Python drops it."""


def _run_dropping(patch: str, crater_dir: Path, out: Path, *extra: str) -> tuple[int, str]:
    """(status, stderr) of ``orthomvp -q ortho`` on the crater scene into ``out`` (with
    ``extra`` options) in a script that first runs ``patch`` (code that makes Dropped()s)."""
    script = (
        DROPPED + patch + "from orthomvp.cli import main_entry\n"
        "sys.argv = ['orthomvp', *sys.argv[1:]]\n"
        "main_entry()\n"
    )
    args = ["-q", "ortho", crater_dir / "dem.tif", crater_dir / "oblique.tif"]
    args += [crater_dir / "oblique.tsai", "-o", out, *extra]
    done = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=60,
        env=ENV,
    )
    return done.returncode, done.stderr


def test_a_sigterm_dropped_in_a_del_is_not_lost(crater_dir: Path, tmp_path: Path) -> None:
    """A SIGTERM whose exception Python drops (raised in a ``__del__``, as in Dask's
    ``Future.__del__``) still ends the command with 143 and one line, no "Exception ignored"."""
    out = tmp_path / "o.tif"
    patch = (
        "original = run.check_views\n"
        "def check_views(*a):\n"
        "    Dropped()\n"
        "    return original(*a)\n"
        "run.check_views = check_views\n"
    )
    status, err = _run_dropping(patch, crater_dir, out)
    assert_one_line(status, err, 143, "interrupted", "already complete", str(out))
    assert out.exists()


def test_a_ctrl_c_while_the_local_cluster_starts_is_one_line(scene: Path, tmp_path: Path) -> None:
    """Ctrl-C to the whole process group as soon as the local cluster's first worker process
    exists (it is still importing, before it can ignore SIGINT): 130, one line, no worker's
    traceback, nothing left."""
    out = tmp_path / "o.tif"
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    args = ortho_args(scene, out, "--dask", "local:2")
    env = {**ENV, "TMPDIR": str(tmp)}
    with started(args, stderr=subprocess.PIPE, text=True, env=env) as proc:
        deadline = time.monotonic() + CASE_SECONDS
        while not descendants(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        below = descendants(proc.pid)
        assert below, "no worker process started"
        os.killpg(proc.pid, signal.SIGINT)
        status, err, _ = finish(proc)
    assert_one_line(status, err, 130, "interrupted; no partial output was kept")
    assert not wait_gone(below | descendants(proc.pid), 10)
    assert_nothing_left(out, tmp)


def test_a_sigterm_dropped_mid_run_still_stops_the_run(crater_dir: Path, tmp_path: Path) -> None:
    """A SIGTERM dropped in a ``__del__`` while tiles still run is delivered again: the run
    stops there (143, one line, no output), and does not go on with SIGTERM ignored (found
    in review: it ran to its end, deaf to further signals)."""
    out = tmp_path / "o.tif"
    patch = (
        "original = run.results\n"
        "def results(*a, **k):\n"
        "    for i, r in enumerate(original(*a, **k)):\n"
        "        if i == 1:\n"
        "            Dropped()\n"
        "        yield r\n"
        "        time.sleep(0.05)\n"
        "run.results = results\n"
    )
    status, err = _run_dropping(patch, crater_dir, out, "--grid", "dem", "--tile", "8")
    assert_one_line(status, err, 143, "interrupted", "no partial output")
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
