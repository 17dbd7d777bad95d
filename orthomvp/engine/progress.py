"""Feedback on long work: a tqdm bar on a terminal, plain log lines when stderr is not one
(every :data:`LOG_EVERY` of the work or :data:`LOG_SECONDS` seconds, once a phase has run
:data:`LOG_AFTER` seconds: short phases stay silent in logs), nothing when quiet."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tqdm import tqdm

LOG_EVERY = 0.1
LOG_SECONDS = 30.0
LOG_AFTER = 2.0


class Progress:
    """Progress of one phase of ``total`` units (set now or later with :meth:`set_total`).

    Use as a context manager; ``enabled=False`` is quiet mode."""

    def __init__(
        self, desc: str, enabled: bool = True, total: int | None = None, unit: str = "tile"
    ):
        self.desc, self.unit, self.total = desc, unit, total
        self.enabled = enabled
        self.done = 0
        self._bar: tqdm | None = None
        self._start = time.monotonic()
        self._logged = (-1.0, self._start)
        if enabled and sys.stderr.isatty():
            from tqdm import tqdm  # only for a bar on a terminal

            self._bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def set_total(self, total: int) -> None:
        """Set the amount of work once it is known."""
        self.total = total
        if self._bar is not None:
            self._bar.total = total
            self._bar.refresh()

    def update(self, n: int = 1) -> None:
        """``n`` more units done."""
        self.done += n
        if self._bar is not None:
            self._bar.update(n)
        elif self.enabled:
            share = self.done / self.total if self.total else 0.0
            now = time.monotonic()
            due = share >= self._logged[0] + LOG_EVERY or now >= self._logged[1] + LOG_SECONDS
            if due and now >= self._start + LOG_AFTER:
                self._log()

    def note(self, line: str) -> None:
        """Print one line to stderr (above the bar on a terminal); nothing when quiet."""
        if self._bar is not None:
            self._bar.write(line, file=sys.stderr)
        elif self.enabled:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        """Finish the bar (or log the last line)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self.enabled and self._logged[0] >= 0.0 and self._logged[0] < 1.0:
            self._log(final=True)
        self.enabled = False

    def _log(self, final: bool = False) -> None:
        now = time.monotonic()
        share = self.done / self.total if self.total else 0.0
        of = f"/{self.total:,}" if self.total is not None else ""
        end = ", done" if final else ""
        print(
            f"orthomvp: {self.desc}: {self.done:,}{of} {self.unit}s ({100 * share:.0f}%), "
            f"{now - self._start:.1f} s{end}",
            file=sys.stderr,
            flush=True,
        )
        self._logged = (1.0 if final else share, now)
