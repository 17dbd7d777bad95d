"""Orthophoto values to the output's data type (``--dtype``, :class:`~orthomvp.engine.writer.
Outputs`): float32 as they are, integers rounded and clipped to the type's range, as GDAL's
``gdal_translate -ot`` does; :class:`IntegerCast` also counts what the cast loses, so that a run
says so once at its end (an :class:`~orthomvp.errors.OrthoMVPWarning`) instead of writing a
clipped or flattened image in silence."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FEW_LEVELS = 16
"""A cast that leaves the filled values fewer integer levels than this, from values that were
not whole numbers, is reported (float values between 0 and 1 as uint8 or uint16)."""


def to_dtype(data: np.ndarray, dtype: str, nodata: float) -> np.ndarray:
    """Float32 values (NaN = empty) as ``dtype`` with ``nodata``: integers rounded and clipped
    to the type's range; valid values equal to ``nodata`` move one step into the range."""
    if dtype == "float32":
        return data if np.isnan(nodata) else np.where(np.isfinite(data), data, np.float32(nodata))
    empty = ~np.isfinite(data)
    info = np.iinfo(dtype)
    with np.errstate(invalid="ignore"):
        values = np.clip(np.rint(data), info.min, info.max)
    step = 1 if nodata < info.max else -1
    values = np.where(values == nodata, nodata + step, values)
    return np.where(empty, nodata, values).astype(dtype)


@dataclass
class IntegerCast:
    """:func:`to_dtype` of every tile of an output of integer ``dtype`` (``path``, named in
    :meth:`loss`), counting the filled values (all bands) it clips and their range;
    ``from_integers``: the images' pixels are integers, so a range of few levels is theirs."""

    path: Path
    dtype: str
    nodata: float
    from_integers: bool = False  # the images hold integers: their levels are all there are
    filled: int = 0
    low: int = 0
    high: int = 0
    least: float = np.inf
    most: float = -np.inf
    whole: bool = True
    _info: np.iinfo = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._info = np.iinfo(self.dtype)

    def __call__(self, data: np.ndarray) -> np.ndarray:
        """``data`` (float32, NaN = empty) cast, its values counted."""
        values = data[np.isfinite(data)]
        if values.size:
            self.filled += values.size
            rounded = np.rint(values)
            self.low += int(np.count_nonzero(rounded < self._info.min))
            self.high += int(np.count_nonzero(rounded > self._info.max))
            self.least = min(self.least, float(values.min()))
            self.most = max(self.most, float(values.max()))
            self.whole = self.whole and bool(np.all(values == rounded))
        return to_dtype(data, self.dtype, self.nodata)

    def loss(self) -> str | None:
        """What the cast lost, in one line (None: nothing worth saying): the filled values it
        clipped to the type's range, or a range of values (not the images' own integers)
        that rounding left fewer than :data:`FEW_LEVELS` integer levels."""
        if not self.filled:
            return None
        lo, hi = self._info.min, self._info.max
        span = f"the values run from {self.least:.6g} to {self.most:.6g}"
        keep = "--dtype float32 (the default) keeps them"
        clipped = self.low + self.high
        if clipped:
            share = f"{clipped:,} of {self.filled:,} filled values ({clipped / self.filled:.2%})"
            clip = f"lie outside {self.dtype}'s {lo}..{hi} and were clipped"
            return f"{self.path}: {share} {clip} ({span}); {keep}"
        first = int(np.clip(np.rint(self.least), lo, hi))
        levels = int(np.clip(np.rint(self.most), lo, hi)) - first + 1
        if not (self.whole or self.from_integers) and levels < FEW_LEVELS:
            kept = f"{levels} level" + "s" * (levels > 1)
            return f"{self.path}: {span}: rounded to {self.dtype} they keep {kept}; {keep}"
        return None
