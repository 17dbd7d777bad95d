"""How a run's tiles are spread over workers: threads, processes or a Dask cluster's, and
which of them run on this machine."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from orthomvp.errors import InputError
from orthomvp.validate import number


def workers_of(threads: int | None, processes: int | None, client: Any) -> int:
    """Tiles that can run at once: threads (default one per core), processes, or the Dask
    client's worker threads; InputError for several of them or counts under 1."""
    if sum(x is not None for x in (threads, processes, client)) > 1:
        raise InputError("give threads, processes or a Dask client, not several")
    for name, value in (("threads", threads), ("processes", processes)):
        if value is not None:
            number(value, name, minimum=1, integer=True)
            if not isinstance(value, int | np.integer):  # 2.0: pools want an int
                raise InputError(f"{name} must be an integer, got float {value!r}")
    if client is not None:
        if not callable(getattr(client, "nthreads", None)):
            raise InputError(
                f"client must be a dask.distributed Client (see dask_client), got "
                f"{type(client).__name__}"
            )
        return max(sum(client.nthreads().values()), 1)
    return processes or threads or os.cpu_count() or 1


@dataclass(frozen=True)
class Schedule:
    """How a run's tiles are spread: ``workers`` that can run a tile at once, the ``jobs``
    (indices of the tiles some view sees), ``at_once`` tiles in memory together, ``inner``
    threads per tile (a plain threads run with fewer tiles than threads shares them out), the
    ``limit`` of tiles running or waiting to run (:func:`results`) and the worker
    ``processes`` on this machine besides this one (:func:`local_processes`)."""

    workers: int
    jobs: list[int]
    at_once: int
    inner: int
    limit: int
    processes: int = 0


def schedule(
    tiles: Sequence[Any],
    threads: int | None,
    processes: int | None,
    client: Any,
    inflight: int | None,
) -> Schedule:
    """The :class:`Schedule` of ``tiles`` (with their ``index`` and ``views``) on ``threads``,
    ``processes`` or the Dask ``client``, at most ``inflight`` in flight (default the workers);
    InputError for a count under 1 or several of the three."""
    workers = workers_of(threads, processes, client)
    if inflight is not None:
        inflight = number(inflight, "inflight", minimum=1, integer=True)
    jobs = [job.index for job in tiles if job.views]
    local = client is None and not processes
    inner = max(1, workers // max(len(jobs), 1)) if local else 1
    at_once = min(workers, max(len(jobs), 1))
    here = local_processes(processes, client)
    return Schedule(workers, jobs, at_once, inner, inflight or workers, here)


def local_processes(processes: int | None, client: Any) -> int:
    """Worker processes that run on this machine besides this one: the ``processes`` of a pool,
    or the Dask ``client``'s workers whose address is a loopback or this host's (0 for
    threads). Their memory counts in the preflight (:func:`~orthomvp.engine.tiling.peak_bytes`)."""
    if client is None:
        return processes or 0
    import socket

    from distributed.comm import get_address_host

    here = {"localhost", socket.gethostname()}
    with contextlib.suppress(OSError):
        here.update(socket.gethostbyname_ex(socket.gethostname())[2])
    hosts = [get_address_host(address) for address in client.nthreads()]
    return sum(host in here or host.startswith("127.") or host == "::1" for host in hosts)


def all_local(client: Any) -> bool:
    """Whether every worker runs on this machine: no Dask ``client``, or one whose workers
    are all :func:`local_processes`."""
    return client is None or local_processes(None, client) == len(client.nthreads())
