"""An exact median of values that arrive tile by tile, in bounded memory (the fit's summary
line: the median change from the input and the median uncertainty)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


class Median:
    """The median of a stream of float64 values, as :func:`numpy.median` gives it, in bounded
    memory: up to ``budget`` values are kept in memory; beyond, all go to a temporary file
    (in ``folder``) and the middle ones are selected in passes over it, 16 bits of their
    sort keys at a time. Use as a context manager (the file is removed on exit)."""

    def __init__(self, budget: int = 1 << 23, folder: str | Path | None = None):
        self.budget, self.folder = budget, folder
        self.parts: list[np.ndarray] = []
        self.count = 0
        self.file: Any = None

    def __enter__(self) -> Median:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None

    def add(self, values: np.ndarray) -> None:
        values = np.asarray(values, np.float64).ravel()
        if not len(values):
            return
        self.count += len(values)
        if self.file is None and self.count <= self.budget:
            self.parts.append(values)
            return
        if self.file is None:
            self.file = tempfile.TemporaryFile(dir=self.folder)
            for part in self.parts:
                part.tofile(self.file)
            self.parts = []
        values.tofile(self.file)

    def value(self) -> float:
        """The median (NaN without values)."""
        if not self.count:
            return math.nan
        n = self.count
        ranks = [n // 2] if n % 2 else [n // 2 - 1, n // 2]
        if self.file is None:
            return float(np.median(np.concatenate(self.parts)))
        picked = [self._select(rank) for rank in ranks]
        return picked[0] if len(picked) == 1 else float(np.mean(picked))

    def _chunks(self) -> Any:
        self.file.flush()
        self.file.seek(0)
        step = max(self.budget // 4, 1 << 16)
        while True:
            chunk = np.fromfile(self.file, np.float64, step)
            if not len(chunk):
                return
            yield chunk

    @staticmethod
    def _keys(values: np.ndarray) -> np.ndarray:
        """Unsigned keys in the order of the values (negative values' bits flipped)."""
        bits = values.view(np.uint64)
        sign = bits >> np.uint64(63)
        return np.where(sign == 1, ~bits, bits | np.uint64(1 << 63))

    def _select(self, rank: int) -> float:
        """The value of 0-based ``rank`` in sorted order, in passes over the file: each pass
        narrows the candidates to those whose keys share 16 more leading bits, until they
        fit in the budget (or are all equal)."""
        prefix, shift = 0, 64  # candidates: keys whose leading 64 - shift bits are prefix
        while True:
            counts = np.zeros(1 << 16, np.int64)
            inside = 0
            for keys in self._candidates(prefix, shift):
                inside += len(keys)
                if shift:
                    counts += np.bincount(
                        ((keys >> np.uint64(shift - 16)) & np.uint64(0xFFFF)).astype(np.int64),
                        minlength=1 << 16,
                    )
            if inside <= self.budget or not shift:
                break
            cumulative = np.cumsum(counts)
            b = int(np.searchsorted(cumulative, rank, side="right"))
            rank -= int(cumulative[b - 1]) if b else 0
            prefix, shift = (prefix << 16) | b, shift - 16
        if not shift:  # every candidate has the same key: the same value
            return self._value(prefix)
        values = np.concatenate(
            [chunk[self._match(self._keys(chunk), prefix, shift)] for chunk in self._chunks()]
        )
        return float(np.partition(values, rank)[rank])

    @staticmethod
    def _value(key: int) -> float:
        """The value of a key (inverse of :meth:`_keys`)."""
        k = np.array([key], np.uint64)
        bits = k ^ np.uint64(1 << 63) if key >> 63 else ~k
        return float(bits.view(np.float64)[0])

    @staticmethod
    def _match(keys: np.ndarray, prefix: int, shift: int) -> np.ndarray:
        """Which ``keys`` have the leading bits ``prefix`` (all of them when ``shift`` is 64)."""
        if shift >= 64:
            return np.ones(len(keys), bool)
        return (keys >> np.uint64(shift)) == np.uint64(prefix)

    def _candidates(self, prefix: int, shift: int) -> Any:
        for chunk in self._chunks():
            keys = self._keys(chunk)
            yield keys[self._match(keys, prefix, shift)]
