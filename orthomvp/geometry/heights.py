"""Which DEM values are heights: infinities and fill values (of magnitude :data:`EXTREME` or
more, as tools write them without a nodata tag) are taken as nodata with one warning that
counts them, and a value farther from the DEM's median than a body's radius is refused as a
fill value or a height in the wrong unit."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from orthomvp.errors import InputError, OrthoMVPWarning

EXTREME = 1e30
"""Heights (or radii) of at least this magnitude, in metres, are no heights but fill values:
float32's lowest and highest (±3.4028235e38, the collar ArcGIS writes with no nodata tag),
-1e38 or 1e30 of other tools. They and infinite values are taken as nodata."""


def unusable(values: np.ndarray) -> np.ndarray:
    """Where ``values`` are infinite or of magnitude at least :data:`EXTREME` (NaN: not)."""
    with np.errstate(invalid="ignore"):
        return np.abs(values) >= EXTREME


def warn_infinite(path: str | Path, count: int, extreme: int = 0) -> None:
    """One warning when ``count`` infinite heights and ``extreme`` finite ones of magnitude
    :data:`EXTREME` or more of the DEM at ``path`` became nodata."""
    causes = []
    if count:
        causes.append(f"{count:,} infinite height{'s' if count > 1 else ''}")
    if extreme:
        causes.append(
            f"{extreme:,} height{'s' if extreme > 1 else ''} of magnitude {EXTREME:g} m or more "
            "(fill values without a nodata tag, such as float32's lowest)"
        )
    if causes:
        warnings.warn(
            f"{path}: {' and '.join(causes)} taken as nodata", OrthoMVPWarning, stacklevel=3
        )


def count_unusable(values: np.ndarray) -> tuple[int, int]:
    """(infinite, extreme finite) counts of :func:`unusable` ``values``."""
    bad = unusable(values)
    infinite = int(np.isinf(values[bad]).sum())
    return infinite, int(bad.sum()) - infinite


RELIEF = 1.0
"""The largest distance, in body radii, of a DEM value from the DEM's median: more is no
relief of any body (Olympus Mons rises 0.006 Mars radii; a height below minus one radius lies
past the centre), but a fill value or a height in the wrong unit. One radius leaves room for
the DEMs of irregular small bodies on a mean sphere."""


def check_relief(name: str, low: float, high: float, median: float, radius: float) -> None:
    """InputError when DEM values from ``low`` to ``high`` stray more than :data:`RELIEF`
    body radii (``radius``, metres) from their ``median``: naming the value, which is most
    likely an undeclared fill value."""
    worst = low if median - low > high - median else high
    if abs(worst - median) > RELIEF * radius:
        raise InputError(
            f"{name}: a DEM value of {worst:,.6g} m is {abs(worst - median):,.0f} m from the "
            f"median, {median:,.0f} m, more than {RELIEF:g} times the body's radius "
            f"({radius:,.0f} m): is it a fill value without a nodata tag? Give the file "
            "its nodata value (gdal_edit.py -a_nodata VALUE)"
        )
