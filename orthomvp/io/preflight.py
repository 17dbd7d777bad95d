"""Memory and disk preflight: refuse, before any work, a job that cannot fit in memory, with one
line that says how big it is and what to change ("this grid is 1.6e11 posts, about 370 GiB;
..."), and an output whose disk has no space left (:func:`check_space`).

The estimates are the peak memory of each job, measured on this project's machine and rounded
up (see the constants beside each caller); they are meant to catch sizes that are off by
orders of magnitude (a resolution in metres given as degrees), not to plan a tight budget.
"""

from __future__ import annotations

import os
import resource
import shutil
from pathlib import Path

from orthomvp.errors import InputError, OutputError

BASE = 300 << 20
"""What the process itself needs (Python, numpy, GDAL, Embree), bytes."""


def available_bytes() -> int:
    """Memory this process may still use: the kernel's estimate of available memory
    (``MemAvailable``), or the physical memory where that cannot be read, and no more than the
    address-space limit (``ulimit -v``)."""
    available = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if available is None:
        try:
            available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = 1 << 62  # unknown: do not refuse
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        available = min(available, soft)
    return int(available)


def size_text(nbytes: float) -> str:
    """``nbytes`` in KiB, MiB, GiB or TiB, two or three significant figures."""
    value = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if value < 1024 or unit == "PiB":
            return f"{value:.0f} {unit}" if value >= 100 or unit == "B" else f"{value:.2g} {unit}"
        value /= 1024
    raise AssertionError  # unreachable


def check_memory(what: str, nbytes: float, advice: str) -> None:
    """Raise :class:`InputError` when a job that needs about ``nbytes`` bytes (beyond
    :data:`BASE`) cannot fit in :func:`available_bytes`: ``"{what}, about {size}; {available}
    available: {advice}"``, e.g. what = "this grid is 1.6e11 posts", advice = "choose a coarser
    --res or a smaller --bounds"."""
    available = available_bytes()
    if not nbytes + BASE <= available:  # also refuses NaN
        raise InputError(
            f"{what}, about {size_text(nbytes)}; this machine has {size_text(available)} of "
            f"memory available: {advice}"
        )


def count_text(n: float) -> str:
    """A count for messages: ``12,345`` below a million, ``1.6e11`` above."""
    if n < 1e6:
        return f"{n:,.0f}"
    mantissa, exponent = f"{n:.1e}".split("e")
    return f"{mantissa.removesuffix('.0')}e{int(exponent)}"


def disk_size_text(size: int) -> str:
    """``size`` bytes in kB, MB or GB (powers of 1000, as file sizes and free space are
    given in messages about outputs)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{max(size, 1) / 1e3:.3g} kB"


def check_space(path: str | Path, need: int = 0) -> None:
    """OutputError unless the file system of ``path``'s directory has ``need`` bytes (and at
    least one) free."""
    path = Path(path)
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        return  # the directory is checked elsewhere
    if free < max(need, 1):
        note = f" (needs about {disk_size_text(need)}, {disk_size_text(free)} free)" if need else ""
        raise OutputError(f"cannot write {path}: no space left on device{note}")
