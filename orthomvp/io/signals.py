"""Signal holding around the steps of writing outputs. This module owns :class:`HeldSignals`:
within its block SIGINT, SIGTERM and SIGHUP (:data:`SIGNALS_HELD`) wait, and are delivered at
its end to the handlers of before, so that creating a temporary output and noting its name, renaming
it or removing it is never cut in half by a signal; within :meth:`HeldSignals.released` (the
long work, such as writing the file) they are not held. Used by the atomic output writer
(:mod:`orthomvp.io.outputs`) and the capture of GDAL's stderr (:mod:`orthomvp.io.write_errors`).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType
from typing import Any

SIGNALS_HELD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that :class:`HeldSignals` holds (Ctrl-C, ``timeout``'s or a scheduler's, and
a closed terminal's)."""


def _deliver(signum: int, handler: Any, frame: FrameType | None) -> None:
    """Hand signal ``signum`` to ``handler`` as returned by :func:`signal.getsignal`."""
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL:
        signal.signal(signum, signal.SIG_DFL)
        signal.raise_signal(signum)


class HeldSignals:
    """Within the block, SIGINT, SIGTERM and SIGHUP are held, and delivered at its end to the
    handlers of before; within :meth:`released` (the long work, such as writing the file) they are
    not. So everything around that work (creating a temporary file and noting its name,
    renaming it, removing it) is never cut in half by a signal: one arriving there waits,
    and one arriving during the work raises where the clean-up that follows is held again.
    Only the main thread runs Python's signal handlers: elsewhere nothing is held."""

    def __init__(self) -> None:
        self.previous: dict[int, Any] = {}
        self.held: list[int] = []
        self.holding = False

    def _hold(self, signum: int, frame: FrameType | None) -> None:
        if self.holding:
            self.held.append(signum)
        else:  # left installed: a signal cut short putting the handlers back
            _deliver(signum, self.previous[signum], frame)

    def __enter__(self) -> HeldSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS_HELD:
                handler = signal.getsignal(sig)
                if handler is None:  # not installed from Python: cannot be put back
                    continue
                if handler != self._hold:  # (still installed if putting it back was cut)
                    self.previous[sig] = handler
                signal.signal(sig, self._hold)
            self.holding = True
        return self

    def __exit__(self, *exc: object) -> None:
        if not self.holding:  # released, and never taken back (see released)
            return
        self.holding = False
        try:
            for sig, handler in self.previous.items():
                signal.signal(sig, handler)
        finally:
            held, self.held = self.held, []
            for sig in dict.fromkeys(held):
                signal.raise_signal(sig)

    @contextlib.contextmanager
    def released(self) -> Iterator[None]:
        """Within this block the signals are not held (those held so far are delivered)."""
        self.__exit__()
        try:
            yield
        except GeneratorExit:  # closed by the garbage collector, long after: leave them alone
            raise
        except BaseException:
            self.__enter__()
            raise
        self.__enter__()
