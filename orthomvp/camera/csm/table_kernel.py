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


def _knot(line: float, step: float, last: int) -> tuple[np.int64, float]:
    """The knot of CSM ``line`` in a table of knots ``step`` lines apart whose last difference
    is number ``last``, and the fraction of the way to the next one, as
    ``LineScanCamera._states``: the floor of line / step clipped to 0..last (a NaN line takes
    knot 0, as ``np.nan_to_num``; the fraction beyond the ends extrapolates)."""
    big = np.finfo(np.float64).max
    x = line / step
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
    return k, x - np.float64(k)


_knot = cached_jit(_knot, fastmath=False, error_model="numpy", inline="always")


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
    for m in range(len(line)):
        k, frac = _knot(line[m], step, last)
        r0 = xyz[m, 0] - (diffs[k, 0] * frac + states[k, 0])
        r1 = xyz[m, 1] - (diffs[k, 1] * frac + states[k, 1])
        r2 = xyz[m, 2] - (diffs[k, 2] * frac + states[k, 2])
        for i in range(3):  # column i of the rotation: entries 3 + i, 6 + i, 9 + i
            a = diffs[k, 3 + i] * frac + states[k, 3 + i]
            b = diffs[k, 6 + i] * frac + states[k, 6 + i]
            c = diffs[k, 9 + i] * frac + states[k, 9 + i]
            out[m, i] = a * r0 + b * r1 + c * r2


_camera_coordinates = cached_jit(_camera_coordinates, fastmath=False, error_model="numpy")


def _table_point(
    states: np.ndarray, diffs: np.ndarray, step: float, line: float, columns: int, out: np.ndarray
) -> None:
    """Into ``out`` (columns,): the first ``columns`` table values at CSM ``line``, as
    ``LineScanCamera._states``."""
    k, frac = _knot(line, step, diffs.shape[0] - 1)
    for j in range(columns):
        out[j] = diffs[k, j] * frac + states[k, j]


_table_point = cached_jit(_table_point, fastmath=False, error_model="numpy", inline="always")


IDENTITY, RADIAL, LRONAC, TRANSVERSE, KAGUYA, DAWN, RADTAN = range(7)
"""The lens distortions the kernel applies (``plane[14]``, the coefficients in
``plane[15:35]``; ``orthomvp.camera.csm.linescan.KERNEL_DISTORTIONS`` names them): none, and
each of usgscsm's models as :mod:`orthomvp.camera.csm.distortion` applies it, point by point
with the same operations and stopping rules."""
_TOLERANCE = 1e-6  # as orthomvp.camera.csm.distortion's


def _radial(x: float, y: float, c: np.ndarray) -> tuple[float, float]:
    """``distortion._apply_radial`` of one point."""
    c0, c1, c2 = c[0], c[1], c[2]
    rp2 = x * x + y * y
    rp = np.sqrt(rp2)
    dr = c0 + rp2 * (c1 + rp2 * c2)
    r = rp + dr * rp
    active = True
    for _ in range(20):
        if r > 1e9:
            dr, active = 0.0, False
            break
        r_prev = r
        dr = c0 + r_prev * r_prev * (c1 + r_prev * r_prev * c2)
        r = rp + dr * r_prev
        active = np.abs(r - r_prev) > _TOLERANCE
        if not active:
            break
    if active:  # not converged in 20 iterations: left undistorted
        dr = 0.0
    return x / (1.0 - dr), y / (1.0 - dr)


def _lronac(x: float, y: float, c: np.ndarray) -> tuple[float, float]:
    """``distortion._apply_lronac`` of one point."""
    dk1 = c[0]
    yt, prev, done = y, 1e6, False
    for _ in range(50):
        new = y * (1.0 + dk1 * yt * yt)
        done = np.abs(new - prev) <= 1e-10
        prev, yt = new, new
        if done:
            break
    return x, yt if done and not np.abs(y) > 40 else y


def _transverse(x: float, y: float, c: np.ndarray) -> tuple[float, float]:
    """``distortion._apply_transverse`` of one point: the two cubic polynomials, their terms
    summed in order from zero."""
    xx, xy, yy = x * x, x * y, y * y
    terms = (1.0, x, y, xx, xy, yy, xx * x, xx * y, xy * y, yy * y)
    u = v = 0.0
    for k in range(10):
        u += terms[k] * c[k]
    for k in range(10):
        v += terms[k] * c[10 + k]
    return u, v


def _kaguya(x: float, y: float, c: np.ndarray) -> tuple[float, float]:
    """``distortion._apply_kaguya`` of one point."""
    xt, yt = x - c[0], y - c[5]
    prev_x, prev_y, done = 1e6, 1e6, False
    for _ in range(50):
        r2 = xt * xt + yt * yt
        r = np.sqrt(r2)
        drx = c[1] + c[2] * r + c[3] * r2 + c[4] * r2 * r
        dry = c[6] + c[7] * r + c[8] * r2 + c[9] * r2 * r
        nx, ny = x - drx - c[0], y - dry - c[5]
        done = np.abs(nx - prev_x) < 1e-6 and np.abs(ny - prev_y) < 1e-6
        prev_x, prev_y, xt, yt = nx, ny, nx, ny
        if done:
            break
    return (xt, yt) if done else (x, y)


def _radtan(x: float, y: float, c: np.ndarray, focal: float) -> tuple[float, float]:
    """``distortion._apply_radtan`` of one point (on focal-length-normalised coordinates)."""
    k1, k2, p1, p2, k3 = c[0], c[1], c[2], c[3], c[4]
    x, y = x / focal, y / focal
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    dx = x * radial + (2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x))
    dy = y * radial + (p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
    return dx * focal, dy * focal


_radial, _lronac, _transverse, _kaguya, _radtan = (
    cached_jit(f, fastmath=False, error_model="numpy")
    for f in (_radial, _lronac, _transverse, _kaguya, _radtan)
)


def _distort(x: float, y: float, plane: np.ndarray) -> tuple[float, float]:
    """The distorted focal-plane (x, y), mm, of undistorted ``x``, ``y`` by the lens of
    ``plane`` (:data:`IDENTITY` and the others)."""
    model = plane[14]
    if model == IDENTITY:
        return x, y
    c = plane[15:35]
    if model == RADIAL:
        return _radial(x, y, c)
    if model == LRONAC:
        return _lronac(x, y, c)
    if model == TRANSVERSE:
        return _transverse(x, y, c)
    if model == KAGUYA:
        return _kaguya(x, y, c)
    if model == DAWN:
        r2 = x * x + y * y
        return x * (1.0 + c[0] * r2), y * (1.0 + c[0] * r2)
    return _radtan(x, y, c, plane[0])


_distort = cached_jit(_distort, fastmath=False, error_model="numpy", inline="always")


def _line_offset(
    states: np.ndarray,
    diffs: np.ndarray,
    step: float,
    line: float,
    p: np.ndarray,
    plane: np.ndarray,
    s: np.ndarray,
    view: np.ndarray,
) -> float:
    """``LineScanCamera._line_error`` of one point ``p`` (3,) at CSM ``line`` on the table,
    the detector line offset, and into ``view`` (3,)
    the focal-plane x, y (mm) and the depth; ``plane`` as :func:`ground_to_image` takes it,
    ``s`` (12,) scratch."""
    _table_point(states, diffs, step, line, 12, s)
    r0, r1, r2 = p[0] - s[0], p[1] - s[1], p[2] - s[2]
    c0 = s[3] * r0 + s[6] * r1 + s[9] * r2
    c1 = s[4] * r0 + s[7] * r1 + s[10] * r2
    c2 = s[5] * r0 + s[8] * r1 + s[11] * r2
    scale = plane[0] / c2
    dx, dy = _distort(c0 * scale, c1 * scale, plane)
    view[0], view[1], view[2] = dx, dy, plane[1] * c2
    return (plane[2] + plane[3] * dx + plane[4] * dy + plane[5] - plane[6]) / plane[7]


_line_offset = cached_jit(_line_offset, fastmath=False, error_model="numpy", inline="always")


def _ground_to_image(
    states: np.ndarray,
    diffs: np.ndarray,
    step: float,
    plane: np.ndarray,
    search: np.ndarray,
    xyz: np.ndarray,
    out: np.ndarray,
    rays: np.ndarray,
) -> None:
    """Into ``out`` (M, 3): CSM line, sample and depth of ground points ``xyz`` (M, 3) (NaN
    where not imaged), and where ``rays`` has M rows, into it (M, 7) the sensor position at
    that line, the unit direction from there to the point and the GSD: ``LineScanCamera``'s
    table iteration point by point (module docstring). ``search``: the first guess (its four
    affine coefficients and ground0 (3,), then its slope; all NaN: from the first and last
    lines), the precision, the largest final offset, the image's lines, the edge slack, the
    iteration limit, the focal length in pixels."""
    guess = not np.isnan(search[7])
    precision, converged, lines, edge = search[8], search[9], search[10], search[11]
    limit, focal_pixels = int(search[12]), search[13]
    s, view, pos = np.empty(12), np.empty(3), np.empty(3)
    for m in range(len(xyz)):
        p = xyz[m]
        if guess:  # the affine line, then a Newton step with the centre's slope
            rel0, rel1, rel2 = p[0] - search[4], p[1] - search[5], p[2] - search[6]
            t0 = rel0 * search[0] + rel1 * search[1] + rel2 * search[2] + search[3]
        else:  # the first and last lines
            t0 = 0.0
        e0 = _line_offset(states, diffs, step, t0, p, plane, s, view)
        t1 = t0 - e0 / search[7] if guess else lines
        for n in range(limit + 1):  # the offset at t1, then up to ``limit`` secant steps
            e1 = _line_offset(states, diffs, step, t1, p, plane, s, view)
            active = np.abs(e1) > precision
            if n == limit or not (active and e1 != e0 and np.isfinite(e1)):
                break
            t2 = t1 - e1 * (t1 - t0) / (e1 - e0)
            t0, e0 = t1, e1
            t1 = t2
        line = t1 + e1 if np.abs(e1) <= precision else np.nan
        sample = plane[8] + plane[9] * view[0] + plane[10] * view[1] + plane[11] - plane[12]
        sample = sample / plane[13]
        depth = view[2]
        ok = (
            line >= -edge
            and line <= lines + edge
            and np.abs(e1) <= converged
            and depth > 0
            and np.isfinite(sample)
        )
        if not ok:
            line = sample = depth = np.nan
        out[m, 0], out[m, 1], out[m, 2] = line, sample, depth
        if rays.shape[0] == len(xyz):
            if ok:
                _table_point(states, diffs, step, line, 3, pos)
            else:
                pos[0] = pos[1] = pos[2] = np.nan
            d0, d1, d2 = p[0] - pos[0], p[1] - pos[1], p[2] - pos[2]
            rng = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            rays[m, 0], rays[m, 1], rays[m, 2] = pos[0], pos[1], pos[2]
            rays[m, 3], rays[m, 4], rays[m, 5] = d0 / rng, d1 / rng, d2 / rng
            rays[m, 6] = rng / focal_pixels


_ground_to_image = cached_jit(_ground_to_image, fastmath=False, error_model="numpy")


def ground_to_image(
    table: tuple[np.ndarray, np.ndarray, float],
    plane: np.ndarray,
    search: np.ndarray,
    xyz: np.ndarray,
    *,
    rays: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """CSM (line, sample, depth) (M, 3) of ground points ``xyz`` (M, 3) by the table's
    iteration, NaN where not imaged, and with ``rays`` the sensor positions, unit directions
    to the points and GSDs (M, 7) (else None). ``table``: ``LineScanCamera._table_rows``;
    ``plane``: the focal length (mm), the depth sign, the detector line's transform
    (i_trans_l, line origin, starting line, summing) and the sample's (i_trans_s, sample
    origin, starting sample, summing); ``search``: as :func:`_ground_to_image`."""
    out = np.empty((len(xyz), 3))
    extra = np.empty((len(xyz) if rays else 0, 7))
    states, diffs, step = table
    _ground_to_image(
        states, diffs, float(step), plane, search, np.ascontiguousarray(xyz, np.float64), out,
        extra,
    )  # fmt: skip
    return out, extra if rays else None


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
