"""Overview levels of an output, made from its tiles as they are written.

Level k (k = 1, 2, ...) has a post for every 2^k x 2^k block of the full-resolution grid, and
is made from level k - 1 by :func:`halve` (as GDAL cascades its overviews): each post is the
mean of the valid posts of its 2 x 2 block ("average"; nodata where none is valid), or the
lower-right post of the block, the last one at an odd edge ("nearest"). A tile makes every
level whose blocks it holds whole (its window starts on a multiple of 2^k and ends on one or
at the grid's edge); the levels no tile could make are made at the end from the level
before, in windows, so memory does not grow with the grid.
"""

from __future__ import annotations

import numpy as np

AVERAGE, NEAREST = "average", "nearest"


def empty_mask(data: np.ndarray, nodata: float | None) -> np.ndarray:
    """Where ``data`` holds no value: NaN, or equal to ``nodata`` (None: nowhere)."""
    if np.issubdtype(data.dtype, np.floating):
        empty = np.isnan(data)
        if nodata is not None and not np.isnan(nodata):
            empty |= data == nodata
        return empty
    if nodata is None:
        return np.zeros(data.shape, bool)
    return data == nodata


def _pairs(a: np.ndarray, axis: int) -> np.ndarray:
    """Sums of neighbouring pairs along ``axis`` (-1 or -2; the last element alone at an odd
    end)."""
    n = a.shape[axis]

    def part(sl: slice) -> np.ndarray:
        return a[..., sl] if axis == -1 else a[..., sl, :]

    out = part(slice(0, n - 1, 2)) + part(slice(1, n, 2))
    if n % 2:
        out = np.concatenate([out, part(slice(n - 1, n))], axis=axis)
    return out


def _sizes(n: int) -> np.ndarray:
    """Posts in each pair of ``n`` along an axis (uint8: 2, and 1 for the last at an odd end)."""
    sizes = np.full(-(-n // 2), 2, np.uint8)
    if n % 2:
        sizes[-1] = 1
    return sizes


def halve(data: np.ndarray, resampling: str, nodata: float | None) -> np.ndarray:
    """The next overview level of ``data`` ((bands, rows, cols)): (bands, ceil(rows / 2),
    ceil(cols / 2)). ``average``: float32 means of the valid posts of each 2 x 2 block (summed
    in float32, rows first), NaN where none is valid
    (``nodata`` marks the empty ones, with NaN); ``nearest``: the block's
    lower-right post (its last at an odd edge), of ``data``'s type."""
    rows, cols = data.shape[-2:]
    if resampling == NEAREST:
        r = np.minimum(np.arange(1, rows + 1, 2), rows - 1)
        c = np.minimum(np.arange(1, cols + 1, 2), cols - 1)
        return data[..., r[:, None], c]
    if resampling != AVERAGE:
        raise ValueError(f"resampling must be {AVERAGE!r} or {NEAREST!r}, not {resampling!r}")
    empty = empty_mask(data, nodata)
    if empty.any():
        values = np.where(empty, np.float32(0), data.astype(np.float32, copy=False))
        counts = _pairs(_pairs(np.logical_not(empty).view(np.uint8), -2), -1)  # 0 to 4
    else:  # every post valid: the counts are the blocks' sizes (the same values, 2x faster)
        values = data.astype(np.float32, copy=False)
        counts = np.outer(_sizes(rows), _sizes(cols))
    sums = _pairs(_pairs(values, -2), -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.divide(sums, counts, dtype=np.float32)  # 0 / 0: NaN where no post is valid


def window_level(window: tuple[int, int, int, int], shape: tuple[int, int], factor: int):
    """The window (r0, r1, c0, c1) of level ``factor`` (a power of two) that the full
    resolution ``window`` of a grid of ``shape`` makes whole, or None when it does not hold
    whole blocks of that level."""
    r0, r1, c0, c1 = window
    rows, cols = shape
    if r0 % factor or c0 % factor:
        return None
    if (r1 % factor and r1 != rows) or (c1 % factor and c1 != cols):
        return None
    return r0 // factor, -(-r1 // factor), c0 // factor, -(-c1 // factor)
