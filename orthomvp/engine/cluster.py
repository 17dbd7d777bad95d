"""Dask for the engine: :func:`dask_client` connects to a scheduler (after a bounded probe that
it is one, with workers) or starts a LocalCluster whose processes leave Ctrl-C to this one and
whose scratch space goes with it; :func:`dask_tile`, :func:`dask_wait` and :func:`tile_result`
run tiles there and turn a cluster that cannot go on (no worker left, a scheduler gone) into
one :class:`WorkerError` line instead of a wait without end."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import importlib
import logging
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from orthomvp.engine.tile import run_tile
from orthomvp.errors import InputError, OrthoMVPError
from orthomvp.optional import require
from orthomvp.validate import number, of_type


class WorkerError(OrthoMVPError):
    """A worker died (killed, out of memory, crashed) while running a tile."""


@contextlib.contextmanager
def dask_client(
    workers: int | None = None, address: str | None = None, timeout: float = 10.0
) -> Iterator[Any]:
    """A ``dask.distributed.Client``: connected to the scheduler at ``address``, or to a
    LocalCluster of ``workers`` processes (one thread each, default one per core) started
    here, with its scratch space in a temporary directory, both removed on exit. Every worker
    imports the engine before the client is handed out (the import costs a second or two per
    worker, outside any run). While inside, Dask's own log lines are silenced (its errors
    reach the caller as exceptions), and the local cluster's processes leave Ctrl-C to this
    one (which stops them).

    InputError (one line) when Dask's ``distributed`` is not installed (the ``dask`` extra),
    when ``address`` is not a Dask address, when no Dask scheduler answers there within
    ``timeout`` seconds (nothing listens, or something that is not a Dask scheduler), when
    the scheduler has no worker within ``timeout`` seconds, or when its workers cannot import
    orthomvp (a remote cluster needs orthomvp installed, and the plan's files at the same
    paths)."""
    check_dask_options(workers, address, timeout)
    distributed = require("distributed", "running tiles on Dask (--dask)", "dask[distributed]")
    with _dask_logs_silenced():
        if address is not None:
            _probe_scheduler(address, timeout)
            try:
                client = distributed.Client(address, timeout=timeout)
            except (OSError, TimeoutError) as exc:
                reason = " ".join(str(exc).split()) or type(exc).__name__
                raise InputError(f"no Dask scheduler answers at {address} ({reason})") from None
            with client:
                try:
                    client.wait_for_workers(1, timeout=timeout)
                except TimeoutError:
                    raise InputError(
                        f"the Dask scheduler at {address} has no workers (none joined within "
                        f"{timeout:g} s): start some with 'dask worker {address}'"
                    ) from None
                _warm_up(client, address)
                yield client
            return
        import dask

        # every process's scratch space (the scheduler's too) in a directory removed after
        scratch_dir = tempfile.TemporaryDirectory(
            prefix="orthomvp-dask-", ignore_cleanup_errors=True
        )
        with scratch_dir as scratch, dask.config.set({"temporary-directory": scratch}):
            try:
                # the worker processes print to a log of their own (a Ctrl-C while one starts,
                # before its preload ignores it, would print its traceback here), also while a
                # cluster cut short as it starts is forgotten (its loop may still be starting a
                # process, which then inherits this process's stderr)
                with _stderr_to(os.path.join(scratch, "workers.log")):
                    try:
                        cluster = distributed.LocalCluster(
                            n_workers=workers or os.cpu_count() or 1,
                            threads_per_worker=1,
                            processes=True,
                            dashboard_address=None,
                            silence_logs=logging.CRITICAL,
                            local_directory=scratch,
                            preload=[LOCAL_PRELOAD],
                        )
                    except BaseException as exc:
                        _forget_clusters()
                        log = os.path.join(scratch, "workers.log")
                        failure = _start_failure(log) if isinstance(exc, RuntimeError) else None
                        if failure is not None:
                            raise failure from exc
                        raise
                with cluster, distributed.Client(cluster) as client:
                    _warm_up(client, "the local cluster")
                    yield client
            except BaseException:  # Ctrl-C, SIGTERM or an error while it runs or stops
                _forget_clusters()
                raise


BOOTSTRAP = "bootstrapping phase"
"""multiprocessing's words in a worker process that ran a main script which starts processes
at import: a script without ``if __name__ == "__main__":``."""
RERUN = "_fixup_main_from_path"
"""The function in a worker's traceback that failed running the main script again."""
_ERROR_LINE = re.compile(r"^[A-Za-z_][\w.]*(Error|Exception): ")


def _start_failure(log: str) -> InputError | None:
    """The error for a local cluster whose workers did not start, from their ``log``: a
    script without the ``__main__`` guard (multiprocessing's bootstrapping message), or a
    worker that failed running the main script again (its last error line, and the guard as
    the likely cure); None where the log says neither."""
    try:
        with open(log, errors="replace") as f:
            lines = [line.strip() for line in f]
    except OSError:
        return None
    head = "the local Dask cluster's workers could not start"
    guard = "'if __name__ == \"__main__\":'"
    if any(BOOTSTRAP in line for line in lines):
        return InputError(
            f"{head}: they import the main script again, so a script that starts a cluster "
            f"needs its code under {guard}"
        )
    if not any(RERUN in line for line in lines):
        return None
    errors = [line for line in lines if _ERROR_LINE.match(line) and "failed to start" not in line]
    reason = f" ({errors[-1][:200]})" if errors else ""
    return InputError(
        f"{head}: running the main script again, as every worker does, they failed{reason}; "
        f"if the script starts the cluster at import, put its code under {guard}"
    )


@contextlib.contextmanager
def _stderr_to(path: str) -> Iterator[None]:
    """Within the block, file descriptor 2 (this process's and that of the processes started
    inside) writes to the file ``path``; then it is given back."""
    sys.stderr.flush()
    saved = os.dup(2)
    log = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
    try:
        os.dup2(log, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(log)


LOCAL_PRELOAD = "orthomvp.engine.dask_worker"
"""The module every worker process of a local cluster runs first (its nannies run here)."""


def _forget_clusters() -> None:
    """Close the local clusters that did not finish starting, quietly (their start-up's
    failed tasks unreported), and take them off Dask's list of clusters to close at exit
    (which would fail with a traceback on one cut short while it started); their processes
    end with this one (they are its daemons)."""
    from distributed.core import Status
    from distributed.deploy.spec import SpecCluster

    for cluster in list(SpecCluster._instances):
        if cluster.status == Status.closed:
            continue
        with contextlib.suppress(BaseException):
            # the start-up's tasks that failed with it: not "never retrieved" at exit
            cluster.loop.asyncio_loop.set_exception_handler(lambda loop, context: None)
        with contextlib.suppress(BaseException):
            cluster.close(timeout=FORGET_SECONDS)
        SpecCluster._instances.discard(cluster)


FORGET_SECONDS = 5.0
"""How long closing a local cluster cut short while it started may take."""


def _probe_scheduler(address: str, timeout: float) -> None:
    """InputError (one line) unless a Dask scheduler at ``address`` answers Dask's handshake
    and an identity request within ``timeout`` seconds in all (Dask's own connect waits
    forever for a listener that accepts and never answers, such as an HTTP server)."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    async def identity() -> Any:
        # TLS as configured for Dask's clients (distributed.comm.tls), as the Client connects
        comm = await connect(address, timeout=timeout, **Security().get_connection_args("client"))
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        answer = asyncio.run(asyncio.wait_for(identity(), timeout))
    except (ValueError, TypeError) as exc:  # Dask's parse of the address, TLS without config
        reason = " ".join(str(exc).split())
        raise InputError(f"{address} is not a usable Dask scheduler address ({reason})") from None
    except TimeoutError:
        raise InputError(
            f"no Dask scheduler answers at {address}: something accepts connections there but "
            f"did not answer Dask's handshake within {timeout:g} s (is it a Dask scheduler?)"
        ) from None
    except OSError as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"no Dask scheduler answers at {address} ({reason})") from None
    except Exception as exc:  # noqa: BLE001 - any garbage sent back by a stranger
        raise InputError(
            f"{address} is not a Dask scheduler (it answered {type(exc).__name__}: "
            f"{' '.join(str(exc).split())[:100]})"
        ) from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        raise InputError(f"{address} is not a Dask scheduler (it answered {str(answer)[:100]})")


@contextlib.contextmanager
def _dask_logs_silenced() -> Iterator[None]:
    """Within the block, the ``distributed`` loggers of this process print nothing below
    CRITICAL (their errors reach the caller as exceptions); their level comes back after."""
    manager = logging.Logger.manager
    names = ["distributed", *(n for n in manager.loggerDict if n.startswith("distributed."))]
    loggers = [logging.getLogger(name) for name in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def check_dask_options(workers: Any, address: Any, timeout: Any) -> None:
    """InputError unless ``workers`` is None or an integer of at least 1, ``address`` None
    or a string, and ``timeout`` a number of seconds > 0 (:func:`dask_client`'s options)."""
    if workers is not None:
        number(workers, "Dask workers", minimum=1, integer=True)
    of_type(address, (str, type(None)), "Dask scheduler address")
    number(timeout, "Dask timeout (seconds)", minimum=0, min_open=True)


def _warm_up(client: Any, where: str) -> None:
    """Import the engine in every worker of ``client``; InputError when a worker cannot."""
    try:
        client.run(importlib.import_module, run_tile.__module__)
    except ImportError as exc:
        raise InputError(f"the Dask workers at {where} cannot import orthomvp ({exc})") from None


def dask_tile(work: Callable[..., Any], plan: Any, index: int, *args: Any) -> Any:
    """``work(plan, index, *args)`` on a Dask worker. An orthomvp error leaves without the
    exceptions it was raised from (a GDAL error, say): Dask sends an exception whose chain
    does not pickle as a bare ``Exception`` of its text, which the caller would take for a
    bug rather than the user error it is."""
    try:
        return work(plan, index, *args)
    except OrthoMVPError as exc:
        exc.__cause__ = exc.__context__ = None
        exc.__suppress_context__ = True
        raise


def dask_wait(client: Any, futures: Any) -> Any:
    """(done, pending) of Dask ``futures`` as soon as one is done; WorkerError as
    :class:`_Watch` says."""
    from distributed import wait

    watch = _Watch(client)
    while True:
        try:
            return wait(futures, timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
        except TimeoutError:
            watch.check()


def tile_result(future: Any) -> Any:
    """The result of a tile's future; for a Dask future, WorkerError as :class:`_Watch` says
    (a finished tile whose worker died is computed again, and waits for a worker)."""
    client = getattr(future, "client", None)
    if client is None or not type(future).__module__.startswith("distributed"):
        return future.result()
    watch = _Watch(client)
    while True:
        try:
            return future.result(timeout=POLL_SECONDS)
        except TimeoutError:
            watch.check()
        except OSError as exc:
            from distributed.comm import CommClosedError

            if not isinstance(exc, (CommClosedError, ConnectionError)):  # the tile's own
                raise
            raise WorkerError(
                f"lost the connection to the Dask scheduler while gathering a tile "
                f"({type(exc).__name__}: {' '.join(str(exc).split())[:100]}); nothing was written"
            ) from None


class _Watch:
    """A Dask cluster watched while waiting for tiles: :meth:`check` raises WorkerError (one
    line) once it has had no worker for :data:`NO_WORKER_SECONDS` (its last one died: the
    tiles would wait forever) or its scheduler stops answering."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.alone_since: float | None = None

    def check(self) -> None:
        client = self.client
        try:
            workers = client.sync(client.scheduler.ncores, callback_timeout=NO_WORKER_SECONDS)
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, a closed client
            raise WorkerError(
                f"the Dask scheduler stopped answering ({type(exc).__name__}: "
                f"{' '.join(str(exc).split())[:100]}); nothing was written"
            ) from None
        if workers:
            self.alone_since = None
        elif self.alone_since is None:
            self.alone_since = time.monotonic()
        elif time.monotonic() - self.alone_since > NO_WORKER_SECONDS:
            raise WorkerError(
                f"the Dask cluster has had no worker for {NO_WORKER_SECONDS:g} s (its last "
                "one died or left); nothing was written"
            )


POLL_SECONDS = 1.0
"""How often a Dask run that waits for its tiles checks that the cluster still has workers."""

NO_WORKER_SECONDS = 10.0
"""How long a Dask run waits for a worker when the cluster has none (a nanny restarts a dead
worker within a few seconds), and for its scheduler to answer, before it gives up."""


def identity(value: Any) -> Any:
    """``value`` itself (a Dask task whose result is its argument)."""
    return value


@contextlib.contextmanager
def worker_deaths(*, started: bool = True) -> Iterator[None]:
    """Within the block, an exception that says a worker died (:func:`_died`, from its pool or
    cluster) becomes one WorkerError line; any other passes as it is. Before any tile came
    back (not ``started``) a broken pool under a script names the ``__main__`` guard."""
    try:
        yield
    except Exception as exc:
        if not _died(exc):
            raise
        if "scheduler-connection-lost" in str(exc):
            raise WorkerError(
                "lost the connection to the Dask scheduler while running tiles (did it stop?); "
                "nothing was written"
            ) from None
        raise WorkerError(
            f"a worker died while running a tile ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())[:200]}){'' if started else _guard_hint(exc)}; "
            "nothing was written"
        ) from None


def _guard_hint(exc: BaseException) -> str:
    """For a process pool broken under a script (a ``__main__`` module with a file): the
    usual cause, a script without the ``__main__`` guard, whose every worker process imports
    it again and so starts its own run."""
    main = sys.modules.get("__main__")
    script = getattr(main, "__file__", None)
    if (
        not isinstance(exc, cf.BrokenExecutor)
        or script is None
        or getattr(main, "__spec__", None) is not None  # (python -m MODULE)
        or Path(script).name == "orthomvp"  # (the command line's entry point)
    ):
        return ""
    return (
        f" (if {Path(script).name} starts this run at import, put its code under "
        "'if __name__ == \"__main__\":': every worker process imports it again)"
    )


def _died(exc: BaseException) -> bool:
    """Whether ``exc`` says that a worker died under a tile (Dask's KilledWorker after its
    retries, or a future cancelled because the data it needed died with a worker)."""
    if isinstance(exc, cf.BrokenExecutor):  # a process pool whose worker died
        return True
    return type(exc).__name__ in ("KilledWorker", "FuturesCancelledError", "CancelledError")
