"""Run first by every worker process of the local Dask cluster of
:func:`orthomvp.engine.cluster.dask_client` (Dask's ``preload``)."""

from __future__ import annotations

import signal
import threading
from typing import Any


def dask_setup(server: Any) -> None:
    """Leave Ctrl-C to the process that started the cluster: a SIGINT sent to the whole
    process group (a terminal's Ctrl-C) would otherwise print a traceback in every worker;
    that process stops the cluster instead. (A Ctrl-C in the second or so while a worker
    imports, before this runs, gives a traceback in the cluster's log, not on the terminal.)"""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
