"""Running a plan: tiles in threads, in processes, or on a Dask cluster; one writer (this process)
assembles the outputs.

Workers get the plan (paths and geometry, no pixels) and return finished tiles. At most ``inflight``
tiles run or wait to run at any time, besides those being written, so memory stays bounded by the
tile, its halo and the band count. Every tile is computed the same way wherever it runs, so outputs
are identical on threads, processes and a cluster."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import os
import pickle
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio

from orthomvp.codes import Code
from orthomvp.engine.cluster import (
    dask_tile,
    dask_wait,
    identity,
    tile_result,
    worker_deaths,
)
from orthomvp.engine.copies import Copies, image_copies, reread
from orthomvp.engine.grid import GDAL_CACHE
from orthomvp.engine.grid_choice import left_out_text
from orthomvp.engine.plan import Plan
from orthomvp.engine.progress import Progress
from orthomvp.engine.schedule import Schedule, all_local, schedule
from orthomvp.engine.survey import survey
from orthomvp.engine.tile import TileResult, empty_result, run_tile
from orthomvp.engine.writer import Outputs, output_bytes, output_set, plan_inputs
from orthomvp.errors import GeometryError, InputError, LeftOutWarning
from orthomvp.io.outputs import process_scratch
from orthomvp.io.raster import held_rasters
from orthomvp.ortho.balance import Correction
from orthomvp.ortho.holes import FLAGS
from orthomvp.validate import of_type


@dataclass
class RunReport:
    """What a run did: tiles run and skipped (no image sees them), wall-clock seconds, the
    workers' seconds per phase summed over tiles (read, mesh, visibility, sample) and the
    writer's (write), posts filled in ``ortho``, the grid's posts with a height (``valid``;
    tiles that no image sees count whole), and per view the posts inside the image, the posts
    taken from it (``taken``, when values or sources are made) and the posts of each
    visibility code (``counts``); for a mosaic, the radiometric ``correction`` applied and the
    ``blend`` width used (posts), and the posts of each :class:`~orthomvp.ortho.holes.Flag`
    value (``flags``: how each post was filled or why it is empty)."""

    tiles_run: int = 0
    tiles_skipped: int = 0
    seconds: float = 0.0
    phases: dict[str, float] = field(default_factory=dict)
    filled: int = 0
    valid: int = 0
    inside: list[int] = field(default_factory=list)
    taken: list[int] = field(default_factory=list)
    counts: list[list[int]] = field(default_factory=list)
    correction: Correction | None = None
    blend: int | None = None
    flags: list[int] = field(default_factory=lambda: [0] * FLAGS)


def available_memory() -> int:
    """Memory available to new work, bytes: MemAvailable of /proc/meminfo where there is
    one, else the free physical pages."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def preflight(plan: Plan, workers: int, processes: int, images: bool) -> int:
    """Expected peak memory of the run (:meth:`Plan.peak_memory`), bytes; InputError (one
    line, saying what to change) when it exceeds :func:`available_memory`."""
    return check_memory(plan, plan.peak_memory(workers, processes, images), workers)


def check_memory(
    plan: Any, need: int, workers: int, advice: str = "use smaller tiles or fewer threads/processes"
) -> int:
    """``need`` bytes for a run of ``plan`` with ``workers`` tiles at a time; InputError (one
    line, saying what to change: ``advice``) when it exceeds :func:`available_memory`."""
    have = available_memory()
    if need > have:
        raise InputError(
            f"the run needs about {need / 2**30:.1f} GiB of memory with {workers} tile(s) of "
            f"{plan.tile} posts at a time, {have / 2**30:.1f} GiB is available: {advice}"
        )
    return need


def _worker_init(plan_file: str, parent: int) -> None:
    """Set up a worker process of :func:`executor`: keep the plan pickled in ``plan_file``
    (a file, not start-up data: a worker that dies while it starts, as one that imports a
    script without the ``__main__`` guard does, would leave its parent blocked writing start-up
    data larger than a pipe holds, for good); keep the images' datasets
    open between its tiles (:func:`~orthomvp.io.raster.held_rasters`, for the life of the
    worker, which ends with the run); leave SIGINT to the parent ``parent`` (pid; a Ctrl-C
    reaches the whole process group, and the parent stops the pool: no traceback of every
    worker), and die with the parent, even when it is killed outright."""
    global _PLAN
    with open(plan_file, "rb") as f:
        _PLAN = pickle.load(f)
    _HELD.enter_context(held_rasters())
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, HELD_SIGNALS)  # held while it was started
    die_with_parent(parent)


HELD_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
"""Signals held back while a worker process is being started (:func:`_signals_held`)."""


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Within the block (in the main thread), SIGINT and SIGTERM are held back and delivered
    when it ends (never lost): a process started inside gets all it needs from this one
    before this one can stop (it would print a traceback reading its half-sent start-up
    data), and starts with them held too, until :func:`_worker_init`."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def die_with_parent(parent: int) -> None:
    """Make this process end (SIGKILL) when its parent ``parent`` (pid) ends: Linux's
    ``PR_SET_PDEATHSIG``, and a check that the parent did not end before that was set; a
    no-op elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:
        os._exit(1)


PR_SET_PDEATHSIG = 1
"""prctl's option: the signal this process gets when the thread that started it ends."""


_PLAN: Any = None
_HELD = contextlib.ExitStack()
"""A worker process's scope of held datasets (:func:`_worker_init`)."""


def _process_tile(work: Callable[..., Any], index: int, *args: Any) -> Any:
    """``work`` (a module-level tile function such as :func:`run_tile`) on the plan that
    :func:`_worker_init` gave this worker process."""
    assert _PLAN is not None
    return work(_PLAN, index, *args)


Submit = Callable[..., Any]
"""``submit(index, *args)``: start a tile; returns its future."""


@contextlib.contextmanager
def executor(
    plan: Any,
    work: Callable[..., Any],
    workers: int,
    processes: int | None = None,
    client: Any = None,
) -> Iterator[tuple[Submit, Callable]]:
    """(submit, wait) running ``work(plan, index, *args)`` (a module-level function, so that
    worker processes can import it) in a pool of ``workers`` threads, of ``processes``
    processes, or on a Dask ``client`` (the plan sent to every worker once); ``wait(futures)``
    returns (done, pending) as soon as one is done."""
    if client is not None:
        # The plan goes to the workers as the result of a task rather than scattered data:
        # a worker that dies takes its scattered copies with it for good (the tiles that need
        # them are then cancelled), while a task's result is computed again where needed.
        shared = client.submit(identity, plan, pure=False)
        try:
            yield (
                lambda i, *a: client.submit(dask_tile, work, shared, i, *a, pure=False),
                lambda fs: dask_wait(client, fs),
            )
        finally:
            with contextlib.suppress(Exception):  # a scheduler that is gone has nothing to cancel
                client.cancel([shared])
        return
    scope = contextlib.ExitStack()
    if processes:
        import multiprocessing

        folder = scope.enter_context(process_scratch("plan"))
        plan_file = os.path.join(folder, "plan.pickle")
        try:
            with open(plan_file, "wb") as f:
                pickle.dump(plan, f, protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException:
            scope.close()
            raise
        ctx = multiprocessing.get_context("spawn")
        pool: cf.Executor = cf.ProcessPoolExecutor(
            processes, mp_context=ctx, initializer=_worker_init, initargs=(plan_file, os.getpid())
        )

        def submit(i: int, *a: Any) -> cf.Future:
            with _signals_held():  # submit may start a worker process
                return pool.submit(_process_tile, work, i, *a)

    else:
        pool = cf.ThreadPoolExecutor(workers)
        submit = lambda i, *a: pool.submit(work, plan, i, *a)  # noqa: E731
    # the images' datasets kept open between tiles (threads; a worker process holds its own)
    with scope, held_rasters() if not processes else contextlib.nullcontext():
        try:
            yield submit, lambda fs: cf.wait(fs, return_when=cf.FIRST_COMPLETED)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def results(
    submit: Submit,
    wait: Callable,
    jobs: list[int],
    args: tuple,
    limit: int,
    copies: Copies | None = None,
) -> Iterator[Any]:
    """Run tiles ``jobs`` (indices, first ones first) with ``submit(index, *args)``, at most
    ``limit`` running or waiting to run at a time, and yield their results as they finish;
    WorkerError (one line) when a worker dies under a tile, any other exception of a tile as
    it is; ``copies`` (of the images the tiles read) hears of each tile as it is submitted
    and as its result is taken, before it is yielded. The next tiles are submitted before the
    finished ones are handed over, so workers do not wait while the caller writes; the
    finished tiles being written are the only others in memory. With ``limit`` = the
    workers, a Dask cluster gets no task beyond one per worker thread: a second one per
    worker would go where the plan it depends on lies, pile onto one worker and wait there
    for work stealing (measured: a worker idle for a second between 3-second tiles)."""
    queue, pending, index_of = list(reversed(jobs)), set(), {}
    done_count = 0  # tiles whose results came back: a worker died then, not as it started

    def top_up() -> None:
        while queue and len(pending) < limit:
            index = queue.pop()
            if copies is not None:
                copies.started(index)
            with worker_deaths(started=bool(done_count)):  # a broken pool refuses new work
                future = submit(index, *args)
            pending.add(future)
            index_of[future] = index

    top_up()
    while pending:  # empty only once the queue is (top_up refills it up to the limit)
        with worker_deaths(started=bool(done_count)):  # (Dask's wait raises for futures
            # cancelled with their scheduler)
            done, rest = wait(pending)
        pending.intersection_update(rest)
        top_up()
        for future in done:
            with worker_deaths(started=bool(done_count)):
                result = tile_result(future)
            done_count += 1
            index = index_of.pop(future)
            if copies is not None:
                copies.finished(index)
            yield result


def run_plan(
    plan: Plan,
    outputs: Outputs,
    *,
    threads: int | None = None,
    processes: int | None = None,
    client: Any = None,
    progress: bool | None = None,
    inflight: int | None = None,
) -> RunReport:
    """Run every tile of ``plan`` and write ``outputs``.

    Tiles run in ``threads`` threads (default: one per core), or in ``processes`` worker processes,
    or on the Dask ``client`` (see :func:`dask_client`); at most ``inflight`` tiles (default: the
    workers) run or wait to run at a time (see :func:`results`). A plain ``threads`` run gives each
    tile ``threads // tiles`` threads when there are fewer tiles than threads. ``progress``: a
    progress bar (or log lines) and the plan's summary on stderr; default as the plan was made
    (:func:`~orthomvp.engine.plan_ortho`'s ``progress``).

    A mosaic plan with blending or balancing first runs its survey
    (:func:`orthomvp.engine.survey.survey`): the balance's statistics and the widest overlap of the
    images' footprints, on a decimated grid.

    Raises InputError before any work when the expected peak memory exceeds what is available,
    GeometryError (and writes nothing) when an image sees no post of the grid or only posts facing
    away, and WorkerError (writing nothing) when a worker dies."""
    of_type(plan, Plan, "plan", " (from plan_ortho)")
    of_type(outputs, Outputs, "outputs", " (Outputs(ortho=...))")
    outputs.check(plan_inputs(plan))
    of_type(progress, (bool, type(None)), "progress")
    progress = plan.progress if progress is None else progress
    sched = schedule(plan.tiles, threads, processes, client, inflight)
    kinds = frozenset(outputs.paths())
    peak = preflight(plan, sched.at_once, sched.processes, bool(kinds - {"visibility"}))
    start = time.perf_counter()
    near = next(iter(outputs.paths().values()))
    local, reserve = all_local(client), output_bytes(plan, outputs)
    reads = sched.jobs if kinds - {"visibility"} else []  # (the codes alone read no pixel)
    copies = image_copies(plan, near, local=local, jobs=reads, reserve=reserve)
    with copies as plan:
        report = _run(plan, outputs, kinds, sched, processes, client, progress, peak)
    report.seconds = time.perf_counter() - start
    return report


def _run(
    plan: Plan,
    outputs: Outputs,
    kinds: frozenset[str],
    sched: Schedule,
    processes: int | None,
    client: Any,
    progress: bool,
    peak: int,
) -> RunReport:
    """:func:`run_plan` after its checks: the survey (when the mosaic needs one), then every
    tile, each image's copy (:mod:`~orthomvp.engine.copies`) removed once no tile still to run
    reads it."""
    workers, jobs, at_once = sched.workers, sched.jobs, sched.at_once
    warned: set[Path] = set()  # (images without room for a copy: said once, survey or not)
    if plan.mosaic is not None and kinds - {"visibility"}:
        if plan.mosaic.balance is not None or plan.mosaic.blend:

            def run_survey(
                coarse: Plan, todo: list[int], kinds: frozenset[str]
            ) -> Iterator[TileResult]:
                reads = todo if "stack" in kinds else []  # (the codes alone read no pixel)
                coarse = reread(coarse, reads)
                with (
                    executor(coarse, run_tile, workers, processes, client) as (submit, wait),
                    contextlib.closing(Copies(coarse, todo, warned)) as copies,
                ):
                    yield from results(submit, wait, todo, (kinds, 1), workers, copies)

            plan = survey(plan, run_survey)
    n = len(plan.views)
    report = RunReport(inside=[0] * n, taken=[0] * n, counts=[[0] * len(Code) for _ in range(n)])
    report.correction = plan.correction
    report.blend = plan.mosaic.blend if plan.mosaic is not None else None
    pool = executor(plan, run_tile, workers, processes, client)
    with (
        Progress("tiles", progress, len(plan.tiles)) as bar,
        pool as (submit, wait),
        contextlib.closing(Copies(plan, jobs, warned)) as copies,
    ):
        bar.note(plan.summary(peak, at_once))
        seen = [0] * len(plan.views)
        with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE), output_set(plan, outputs) as writer:
            for job in plan.tiles:
                if not job.views:
                    empty = empty_result(plan, job, kinds)
                    writer.write(empty)
                    _add_counts(report, empty)
                    report.tiles_skipped += 1
                    bar.update()
            args = (kinds, sched.inner)
            for result in results(submit, wait, jobs, args, sched.limit, copies):
                t0 = time.perf_counter()
                writer.write(result)
                _account(report, result, time.perf_counter() - t0)
                seen = [a + b for a, b in zip(seen, result.seen, strict=True)]
                bar.update()
            part = taking_part(plan, report.inside)
            inside = [report.inside[k] for k in part]
            check_views([plan.views[k] for k in part], inside, [seen[k] for k in part])
            if "ortho" in kinds:
                check_filled(plan.views, report)
            t0 = time.perf_counter()
        report.phases["write"] = report.phases.get("write", 0.0) + time.perf_counter() - t0
    return report


def _account(report: RunReport, result: TileResult, write_seconds: float) -> None:
    """Add one tile to the report."""
    report.tiles_run += 1
    for phase, seconds in result.seconds.items():
        report.phases[phase] = report.phases.get(phase, 0.0) + seconds
    report.phases["write"] = report.phases.get("write", 0.0) + write_seconds
    if result.data is not None:
        report.filled += int(np.isfinite(result.data).all(axis=0).sum())
    report.inside = [a + b for a, b in zip(report.inside, result.inside, strict=True)]
    _add_counts(report, result)
    report.taken = [a + b for a, b in zip(report.taken, result.taken, strict=True)]


def _add_counts(report: RunReport, result: TileResult) -> None:
    """Add a tile's valid posts and code counts to the report."""
    report.valid += result.valid
    for flag, count in enumerate(result.flags):
        report.flags[flag] += count
    for total, counts in zip(report.counts, result.counts, strict=True):
        for code, count in enumerate(counts):
            total[code] += count


def check_filled(views: Any, report: RunReport) -> None:
    """GeometryError when no post of the orthophoto was filled although the images see the
    grid: every post they see is occluded or faces away, as when a camera sits below the
    surface or the DEM's heights are not the cameras' (the message gives the counts)."""
    if report.filled:
        return
    parts = []
    for view, counts in zip(views, report.counts, strict=True):
        occluded, away = counts[Code.OCCLUDED], counts[Code.FACING_AWAY]
        parts.append(f"{view.path}: {occluded:,} occluded, {away:,} facing away")
    raise GeometryError(
        "no post of the grid is visible in any image (" + "; ".join(parts) + "): is a camera "
        "below or inside the surface, or are the DEM's heights not those of the cameras "
        "(vertical datum, height offset, radius values)?"
    )


def taking_part(plan: Plan, inside: list[int]) -> list[int]:
    """The views (0-based) whose posts :func:`check_views` checks: all of them in a plan of
    one view, or when none has a post ``inside`` its image; else those that have. Views that
    the plan kept but that have none (their image boxes only brush the grid) are left out as
    the plan's are, with a :class:`~orthomvp.errors.LeftOutWarning`."""
    every = list(range(len(plan.views)))
    some = [k for k in every if inside[k]]
    if len(every) == 1 or not some:
        return every
    late = [k for k in every if not inside[k] and k not in plan.left_out]
    if late:
        warnings.warn(left_out_text(plan.views, late), LeftOutWarning, stacklevel=2)
    return some


def check_views(views: Any, inside: list[int], seen: list[int]) -> None:
    """GeometryError when a view had no post ``inside`` its image in any tile, or only posts
    facing away (none ``seen``: visible or occluded), as
    :func:`~orthomvp.occlusion.visibility.compute_visibility` raises for a whole grid."""
    for view, n_inside, n_seen in zip(views, inside, seen, strict=True):
        if not n_inside:
            raise GeometryError(
                f"{view.path}: the image ({view.width} x {view.height} px) does not cover the "
                "output grid: none of its posts projects inside it"
            )
        if not n_seen:
            raise GeometryError(
                f"{view.path}: every post in the image faces away from the camera: it looks at "
                "the surface from below (is the camera inside the body, or the DEM upside down?)"
            )
