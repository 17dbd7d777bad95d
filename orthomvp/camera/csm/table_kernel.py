"""The sensor-state table of :class:`~orthomvp.camera.csm.LineScanCamera` as one numba kernel:
the camera-frame coordinates of ground points seen at the times of given lines, the inner step
of ground to image, without the numpy path's (12, M) gathers and temporaries.

The kernel gives the numpy path's values (``LineScanCamera._states`` then the rotation in
``LineScanCamera._line_error``) bit for bit, which stays as its reference: the same float64
operations in the same order (the knot from the clipped floor of line / step, the state as
difference x fraction + knot value, each camera coordinate as three products summed left to
right), no fused multiply-add.

This module imports numba (through :mod:`orthomvp.jit`): the line scanner imports it only for
blocks of at least :data:`orthomvp.camera.csm.linescan.KERNEL_POINTS` points."""

from __future__ import annotations

import numpy as np

from orthomvp.jit import cached_jit


def _camera_coordinates(
    states: np.ndarray,
    diffs: np.ndarray,
    step: float,
    line: np.ndarray,
    xyz: np.ndarray,
    out: np.ndarray,
) -> None:
    """Into ``out`` (M, 3): the camera-frame coordinates (metres) of ground points ``xyz``
    (M, 3) seen from the sensor state at CSM lines ``line`` (M,), interpolated linearly in the
    table whose knots ``step`` lines apart hold ``states`` (knots, 12: position, then the
    camera-to-body rotation row-major) with ``diffs`` (knots - 1, 12) to the next knot
    (extrapolated beyond the ends; a NaN line takes the first knot, as ``np.nan_to_num``)."""
    last = diffs.shape[0] - 1
    big = np.finfo(np.float64).max
    for m in range(len(line)):
        x = line[m] / step
        f = x
        if np.isnan(f):
            f = 0.0
        elif f > big:
            f = big
        elif f < -big:
            f = -big
        kf = np.floor(f)
        if kf < 0:
            kf = 0.0
        elif kf > last:
            kf = np.float64(last)
        k = np.int64(kf)
        frac = x - np.float64(k)
        r0 = xyz[m, 0] - (diffs[k, 0] * frac + states[k, 0])
        r1 = xyz[m, 1] - (diffs[k, 1] * frac + states[k, 1])
        r2 = xyz[m, 2] - (diffs[k, 2] * frac + states[k, 2])
        for i in range(3):  # column i of the rotation: entries 3 + i, 6 + i, 9 + i
            a = diffs[k, 3 + i] * frac + states[k, 3 + i]
            b = diffs[k, 6 + i] * frac + states[k, 6 + i]
            c = diffs[k, 9 + i] * frac + states[k, 9 + i]
            out[m, i] = a * r0 + b * r1 + c * r2


_camera_coordinates = cached_jit(_camera_coordinates, fastmath=False, error_model="numpy")


def camera_coordinates(
    states: np.ndarray, diffs: np.ndarray, step: float, line: np.ndarray, xyz: np.ndarray
) -> np.ndarray:
    """The camera-frame coordinates (M, 3), metres, of ground points ``xyz`` (M, 3) at CSM
    lines ``line`` (M,) from the table (``states``, ``diffs``: (knots, 12) and (knots - 1, 12),
    C-contiguous; ``step``: lines between knots), as :func:`_camera_coordinates`."""
    out = np.empty((len(line), 3))
    _camera_coordinates(
        states, diffs, float(step), np.ascontiguousarray(line, np.float64),
        np.ascontiguousarray(xyz, np.float64), out,
    )  # fmt: skip
    return out
