"""Ephemeris arithmetic of usgscsm and ALE, vectorised: Lagrange interpolation on uniform
nodes, quaternions, and ALE's states and orientations used to turn an ISD into a model.

Quaternions here are scalar-first (w, x, y, z) as ALE and Eigen hold them, except where a
function says it takes usgscsm's scalar-last (x, y, z, w) model-state layout. Rotation
matrices act on column vectors: ``R @ v``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P

_EIGEN_SLERP_EPS = 1e-12  # Eigen's dummy_precision for double


def lagrange_weights(
    times: np.ndarray, t0: float, dt: float, count: int, max_order: int
) -> tuple[np.ndarray, np.ndarray]:
    """usgscsm's ``lagrangeInterp`` on ``count`` uniform nodes t0 + i dt at ``times`` (M,):
    node indices (M, 8) and weights (M, 8) (unused slots: index 0, weight 0). The order is 8,
    lowered near the ends (6, 4, 2) as usgscsm does, and at most ``max_order``. Times outside
    the nodes extrapolate, as usgscsm's do; callers mask them. The reference form: the models
    evaluate the same interpolants as :func:`lagrange_polynomials`."""
    fndex = (np.asarray(times, dtype=np.float64) - t0) / dt
    index = np.clip(np.trunc(fndex), 0, count - 2).astype(np.int64)
    order = np.full(index.shape, 2, dtype=np.int64)
    order[(index >= 1) & (index < count - 2)] = 4
    order[(index >= 2) & (index < count - 3)] = 6
    order[(index >= 3) & (index < count - 4)] = 8
    order = np.minimum(order, max_order)
    first = index - order // 2 + 1
    s = fndex - first  # position in units of dt from the first node used
    nodes = np.zeros(index.shape + (8,), dtype=np.int64)
    weights = np.zeros(index.shape + (8,))
    for n in (2, 4, 6, 8):
        sel = order == n
        if not sel.any():
            continue
        k = np.arange(n)
        d = s[sel][:, None] - k  # (M, n): s - j
        ones = np.ones((d.shape[0], 1))
        before = np.cumprod(np.hstack([ones, d[:, :-1]]), axis=1)  # prod over j < k
        after = np.cumprod(np.hstack([ones, d[:, :0:-1]]), axis=1)[:, ::-1]  # over j > k
        denominator = np.array([np.prod([kk - j for j in k if j != kk]) for kk in k])
        nodes[sel, :n] = first[sel][:, None] + k
        weights[sel, :n] = before * after / denominator
    return nodes, weights


def lagrange(values: np.ndarray, nodes: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The interpolated values (M, k) from node values (count, k) and
    :func:`lagrange_weights`' output."""
    return np.einsum("mj,mjk->mk", weights, values[nodes])


def lagrange_polynomials(values: np.ndarray, max_order: int) -> np.ndarray:
    """usgscsm's Lagrange interpolants of node values (count, k) as one polynomial per node
    interval: coefficients (8, count - 1, k) of powers 0..7 of s = (t - t0) / dt - i on
    interval i (the nodes and order of :func:`lagrange_weights` there; times before the first
    or after the last interval extrapolate its polynomial, as usgscsm does). Evaluated by
    :func:`polynomial_values`, equal to :func:`lagrange` up to rounding (about 1e-15 of the
    values), at a fraction of the cost."""
    values = np.asarray(values, dtype=np.float64)
    count = len(values)
    index = np.arange(count - 1)
    order = np.full(index.shape, 2, dtype=np.int64)
    order[(index >= 1) & (index < count - 2)] = 4
    order[(index >= 2) & (index < count - 3)] = 6
    order[(index >= 3) & (index < count - 4)] = 8
    order = np.minimum(order, max_order)
    coeffs = np.zeros((count - 1, 8, values.shape[1]))
    for n in (2, 4, 6, 8):
        sel = np.flatnonzero(order == n)
        if not sel.size:
            continue
        nodes = np.arange(n) - n // 2 + 1  # node positions relative to the interval start
        basis = np.zeros((n, n))  # basis[j]: power coefficients of the j-th Lagrange basis
        for j in range(n):
            others = np.delete(nodes, j)
            basis[j] = P.polyfromroots(others) / np.prod(nodes[j] - others)
        first = sel - n // 2 + 1
        local = values[first[:, None] + np.arange(n)]  # (intervals, n, k)
        coeffs[sel, :n] = np.einsum("jd,ijk->idk", basis, local)
    return np.ascontiguousarray(coeffs.transpose(1, 0, 2))


def polynomial_values(coeffs: np.ndarray, times: np.ndarray, t0: float, dt: float) -> np.ndarray:
    """Values (M, k) at ``times`` (M,) of :func:`lagrange_polynomials`' ``coeffs`` for nodes
    at t0 + i dt (Horner's scheme on each time's interval)."""
    fndex = (np.asarray(times, dtype=np.float64) - t0) / dt
    index = np.clip(np.trunc(np.nan_to_num(fndex)), 0, coeffs.shape[1] - 1).astype(np.int64)
    s = (fndex - index)[:, None]  # NaN times give NaN values
    out = coeffs[7][index]
    for d in range(6, -1, -1):
        out *= s
        out += coeffs[d][index]
    return out


def xyzw_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) in usgscsm's scalar-last order
    (x, y, z, w), normalised first (usgscsm ``calculateRotationMatrixFromQuaternions``)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return wxyz_matrix(q[..., [3, 0, 1, 2]])


def wxyz_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) (w, x, y, z)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_wxyz(m: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation matrix (3, 3) (Eigen's method)."""
    trace = np.trace(m)
    if trace > 0:
        s = np.sqrt(trace + 1.0)
        w, s = 0.5 * s, 0.5 / s
        q = np.array([w, (m[2, 1] - m[1, 2]) * s, (m[0, 2] - m[2, 0]) * s, (m[1, 0] - m[0, 1]) * s])
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
        q = np.zeros(4)
        q[1 + i] = 0.5 * s
        s = 0.5 / s
        q[0] = (m[k, j] - m[j, k]) * s
        q[1 + j] = (m[j, i] + m[i, j]) * s
        q[1 + k] = (m[k, i] + m[i, k]) * s
    return q / np.linalg.norm(q)


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a b of quaternions (..., 4) (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def qinv(q: np.ndarray) -> np.ndarray:
    """Inverses of quaternions (..., 4) (w, x, y, z): the conjugate over the squared norm."""
    return q * np.array([1.0, -1.0, -1.0, -1.0]) / np.sum(q * q, axis=-1, keepdims=True)


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Eigen's ``Quaternion::slerp`` from a (t = 0) to b (t = 1), (..., 4) (w, x, y, z)."""
    d = np.sum(a * b, axis=-1)
    abs_d = np.abs(d)
    near = abs_d >= 1.0 - _EIGEN_SLERP_EPS
    theta = np.arccos(np.minimum(abs_d, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        sin_theta = np.sin(theta)
        s0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / sin_theta)
        s1 = np.where(near, t, np.sin(t * theta) / sin_theta)
    s1 = np.where(d < 0, -s1, s1)
    return s0[..., None] * a + s1[..., None] * b


def _interval(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """ALE's ``interpolationIndex``: the node at or before t, clamped to [0, n - 2]."""
    return np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(len(times) - 2, 0))


@dataclass(frozen=True)
class Orientations:
    """ALE ``Orientations``: time-dependent rotations (n, 4) (w, x, y, z) at ``times`` (n,),
    angular velocities ``avs`` (n, 3) rad/s, and a constant rotation applied after them."""

    rotations: np.ndarray
    times: np.ndarray
    avs: np.ndarray
    constant: np.ndarray

    def time_dependent(self, t: np.ndarray) -> np.ndarray:
        """SLERP between the bracketing nodes; one node turns at its angular velocity."""
        t = np.asarray(t, dtype=np.float64)
        if len(self.times) > 1:
            i = _interval(self.times, t)
            f = (t - self.times[i]) / (self.times[i + 1] - self.times[i])
            return slerp(self.rotations[i], self.rotations[i + 1], f)
        av = self.avs[0]
        norm = np.linalg.norm(av)
        angle = (t - self.times[0]) * norm
        axis = av / norm if norm > 0 else av
        turn = np.concatenate(
            [np.cos(angle / 2)[..., None], np.sin(angle / 2)[..., None] * axis], axis=-1
        )
        return qmul(turn, np.broadcast_to(self.rotations[0], turn.shape))

    def interpolate(self, t: np.ndarray) -> np.ndarray:
        """The rotation at times ``t`` (ALE ``interpolate`` with SLERP)."""
        q = self.time_dependent(t)
        return qmul(np.broadcast_to(self.constant, q.shape), q)

    def angular_velocity(self, t: np.ndarray) -> np.ndarray:
        """Angular velocities at ``t``, linear between nodes (ALE ``interpolateAV``)."""
        t = np.asarray(t, dtype=np.float64)
        if len(self.times) == 1:
            return np.broadcast_to(self.avs[0], t.shape + (3,)).copy()
        i = _interval(self.times, t)
        f = ((t - self.times[i]) / (self.times[i + 1] - self.times[i]))[..., None]
        return self.avs[i] + f * (self.avs[i + 1] - self.avs[i])

    def rotate_states(
        self, t: np.ndarray, positions: np.ndarray, velocities: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """ALE ``rotateStateAt``: positions R p and velocities R v + R [av]x p at times ``t``."""
        r = wxyz_matrix(self.interpolate(t))
        av = self.angular_velocity(t)
        ax, ay, az = np.moveaxis(av, -1, 0)
        px, py, pz = np.moveaxis(positions, -1, 0)
        skew_p = np.stack([az * py - ay * pz, -az * px + ax * pz, ay * px - ax * py], -1)
        pos = np.einsum("...ij,...j->...i", r, positions)
        vel = np.einsum("...ij,...j->...i", r, velocities + skew_p)
        return pos, vel

    def inverse(self) -> Orientations:
        """ALE ``Orientations::inverse``: rotations R_i^-1 C^-1, no constant rotation."""
        rotations = qmul(
            qinv(self.rotations), np.broadcast_to(qinv(self.constant), self.rotations.shape)
        )
        return Orientations(rotations, self.times, self.avs, np.array([1.0, 0.0, 0.0, 0.0]))

    def __mul__(self, rhs: Orientations) -> Orientations:
        """ALE's product: rotations at the merged times, this constant rotation kept."""
        times = np.unique(np.concatenate([self.times, rhs.times]))
        rotations = qmul(self.time_dependent(times), rhs.interpolate(times))
        return Orientations(rotations, times, np.zeros((len(times), 3)), self.constant)


def hermite_states(
    times: np.ndarray, positions: np.ndarray, velocities: np.ndarray | None, at: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """ALE ``States::getState`` with SPLINE at times ``at``: a node's own state at its time,
    else the cubic Hermite between the bracketing nodes (with velocities) or a Lagrange
    polynomial of up to 4 nodes and its derivative (without); one node with a velocity moves
    linearly."""
    at = np.asarray(at, dtype=np.float64)
    n = len(times)
    if n == 1:
        v = velocities[0] if velocities is not None else np.zeros(3)
        return positions[0] + v * (at - times[0])[:, None], np.broadcast_to(v, (len(at), 3)).copy()
    i = _interval(times, at)
    if velocities is not None:
        h = (times[i + 1] - times[i])[:, None]
        s = ((at - times[i]) / (times[i + 1] - times[i]))[:, None]
        y0, y1, m0, m1 = positions[i], positions[i + 1], velocities[i], velocities[i + 1]
        pos = (
            (2 * s**3 - 3 * s**2 + 1) * y0
            + (s**3 - 2 * s**2 + s) * h * m0
            + (-2 * s**3 + 3 * s**2) * y1
            + (s**3 - s**2) * h * m1
        )
        vel = (
            (6 * s**2 - 6 * s) * y0
            + (3 * s**2 - 4 * s + 1) * h * m0
            + (-6 * s**2 + 6 * s) * y1
            + (3 * s**2 - 2 * s) * h * m1
        ) / h
    else:
        pos, vel = np.empty((len(at), 3)), np.empty((len(at), 3))
        for m, (t, idx) in enumerate(zip(at, i, strict=True)):
            half = min(idx + 1, n - idx - 1, 2)
            k = np.arange(idx - half + 1, idx + half + 1)
            tk = times[k]
            w = np.array(
                [
                    np.prod([(t - tk[j]) / (tk[a] - tk[j]) for j in range(len(k)) if j != a])
                    for a in range(len(k))
                ]
            )
            dw = np.array(
                [
                    sum(
                        np.prod([(t - tk[j]) for j in range(len(k)) if j not in (a, b)])
                        / np.prod([(tk[a] - tk[j]) for j in range(len(k)) if j != a])
                        for b in range(len(k))
                        if b != a
                    )
                    for a in range(len(k))
                ]
            )
            pos[m], vel[m] = w @ positions[k], dw @ positions[k]
    exact = np.isin(at, times)
    if exact.any():
        j = np.searchsorted(times, at[exact])
        pos[exact] = positions[j]
        if velocities is not None:
            vel[exact] = velocities[j]
    return pos, vel
