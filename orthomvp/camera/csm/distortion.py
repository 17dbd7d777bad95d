"""The optical distortion models of usgscsm, vectorised.

Focal-plane coordinates are millimetres (x, y as the ISD's ``focal2pixel`` transforms take them).
``distort`` maps undistorted to distorted coordinates (usgscsm ``applyDistortion``), ``undistort``
the reverse (``removeDistortion``), each with usgscsm's own algorithm, iteration limits and
tolerances, so that results agree with usgscsm's to rounding (including its quirks: a Newton
step stops at a near-singular Jacobian, an iteration that does not converge returns its input).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orthomvp.errors import InputError

MODELS = ("radial", "transverse", "kaguyalism", "dawnfc", "lrolrocnac", "radtan")
"""The ISD ``optical_distortion`` names supported, in usgscsm's ``DistortionType`` order
(radial 0, transverse 1, kaguyalism 2, dawnfc 3, lrolrocnac 4; radtan is 7)."""

TYPE_CODES = {
    "radial": 0,
    "transverse": 1,
    "kaguyalism": 2,
    "dawnfc": 3,
    "lrolrocnac": 4,
    "radtan": 7,
}
"""usgscsm's ``DistortionType`` number of each model (model-state files store the number)."""

_TOLERANCE = 1e-6  # usgscsm's default tolerance and desired precision, mm
_SIZES = {
    "radial": (3,),
    "transverse": (20,),
    "kaguyalism": (10,),
    "dawnfc": (1,),
    "lrolrocnac": (1,),
    "radtan": (5,),
}


@dataclass(frozen=True, eq=False)
class CsmDistortion:
    """A usgscsm distortion model: ``model`` (one of :data:`MODELS`) and its ``coefficients`` as
    usgscsm holds them (transverse: 10 x then 10 y; kaguyalism: boresight x, 4 x, boresight y,
    4 y; radtan: k1, k2, p1, p2, k3, on focal-length-normalised coordinates)."""

    model: str
    coefficients: np.ndarray

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise InputError(
                f"unsupported distortion model {self.model!r} (known: {', '.join(MODELS)})"
            )
        c = np.asarray(self.coefficients, dtype=np.float64).ravel()
        if self.model == "radial" and c.size < 3:
            c = np.concatenate([c, np.zeros(3 - c.size)])
        if c.shape != _SIZES[self.model]:
            raise InputError(
                f"{self.model} distortion needs {_SIZES[self.model][0]} coefficients, got {c.size}"
            )
        if not np.isfinite(c).all():
            raise InputError(f"{self.model} distortion coefficients must be finite")
        c.setflags(write=False)
        object.__setattr__(self, "coefficients", c)
        # all-zero coefficients are no distortion, except for transverse's polynomials
        object.__setattr__(self, "_identity", self.model != "transverse" and not c.any())

    @property
    def is_identity(self) -> bool:
        """Whether the model leaves coordinates as they are (all coefficients zero, but for
        the transverse model's polynomials)."""
        return self._identity

    def distort(self, x: np.ndarray, y: np.ndarray, focal: float) -> tuple[np.ndarray, np.ndarray]:
        """Distorted focal-plane coordinates (mm) of undistorted ones (``focal`` in mm)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self._identity:
            return x, y
        return _APPLY[self.model](x, y, self.coefficients, focal)

    def undistort(
        self, x: np.ndarray, y: np.ndarray, focal: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted focal-plane coordinates (mm) of distorted ones (``focal`` in mm)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self._identity:
            return x, y
        return _REMOVE[self.model](x, y, self.coefficients, focal)


def _transverse(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    terms = (np.ones_like(x), x, y, x * x, x * y, y * y, x * x * x, x * x * y, x * y * y, y * y * y)
    return sum(t * k for t, k in zip(terms, c[:10], strict=True)), sum(
        t * k for t, k in zip(terms, c[10:], strict=True)
    )


def _transverse_jacobian(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, ...]:
    zero, one = np.zeros_like(x), np.ones_like(x)
    d_dx = (zero, one, zero, 2 * x, y, zero, 3 * x * x, 2 * x * y, y * y, zero)
    d_dy = (zero, zero, one, zero, x, 2 * y, zero, x * x, 2 * x * y, 3 * y * y)

    def dot(terms: tuple[np.ndarray, ...], k: np.ndarray) -> np.ndarray:
        return sum(t * v for t, v in zip(terms, k, strict=True))

    return dot(d_dx, c[:10]), dot(d_dy, c[:10]), dot(d_dx, c[10:]), dot(d_dy, c[10:])


def _radtan(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p1, p2, k3 = c
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    return (
        x * radial + (2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)),
        y * radial + (p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y),
    )


def _radtan_jacobian(x: np.ndarray, y: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, ...]:
    k1, k2, p1, p2, k3 = c
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    dradial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2  # d radial / d r2
    return (
        radial + x * dradial * 2 * x + 2.0 * p1 * y + p2 * 6.0 * x,
        x * dradial * 2 * y + 2.0 * p1 * x + p2 * 2 * y,
        y * dradial * 2 * x + p1 * 2 * x + 2.0 * p2 * y,
        radial + y * dradial * 2 * y + p1 * 6.0 * y + 2.0 * p2 * x,
    )


def _newton(dx: np.ndarray, dy: np.ndarray, c: np.ndarray, func, jac) -> tuple[np.ndarray, ...]:
    """usgscsm's ``newtonRaphson``: solve func(u) = d from u = d, at most 19 steps, stopping
    where the residual's 1-norm is within tolerance or the Jacobian nearly singular."""
    ux, uy = dx.copy(), dy.copy()
    fx, fy = func(ux, uy, c)
    active = np.abs(fx) + np.abs(fy) > _TOLERANCE
    for _ in range(1, 20):
        if not active.any():
            break
        fx, fy = func(ux, uy, c)
        rx, ry = dx - fx, dy - fy
        jxx, jxy, jyx, jyy = jac(ux, uy, c)
        det = jxx * jyy - jxy * jyx
        step = active & (np.abs(det) >= 1e-6)
        with np.errstate(divide="ignore", invalid="ignore"):
            ux = np.where(step, ux + (jyy * rx - jxy * ry) / det, ux)
            uy = np.where(step, uy + (jxx * ry - jyx * rx) / det, uy)
        active = step & (np.abs(rx) + np.abs(ry) > _TOLERANCE)
    return ux, uy


def _apply_radial(x, y, c, focal):
    rp2 = x * x + y * y
    rp = np.sqrt(rp2)
    dr = c[0] + rp2 * (c[1] + rp2 * c[2])
    r = rp + dr * rp
    active = np.ones(r.shape, dtype=bool)
    for _ in range(20):
        stop = active & (r > 1e9)
        dr = np.where(stop, 0.0, dr)
        active &= ~stop
        if not active.any():
            break
        r_prev = r
        dr_new = c[0] + r_prev * r_prev * (c[1] + r_prev * r_prev * c[2])
        r_new = rp + dr_new * r_prev
        dr = np.where(active, dr_new, dr)
        r = np.where(active, r_new, r)
        active &= np.abs(r - r_prev) > _TOLERANCE
    dr = np.where(active, 0.0, dr)  # not converged in 20 iterations: left undistorted
    return x / (1.0 - dr), y / (1.0 - dr)


def _remove_radial(x, y, c, focal):
    rr = x * x + y * y
    dr = c[0] + rr * (c[1] + rr * c[2])
    return x * (1.0 - dr), y * (1.0 - dr)


def _apply_transverse(x, y, c, focal):
    return _transverse(x, y, c)


def _remove_transverse(x, y, c, focal):
    return _newton(x, y, c, _transverse, _transverse_jacobian)


def _kaguya_terms(x, y, c):
    r2 = x * x + y * y
    r = np.sqrt(r2)
    return (
        c[1] + c[2] * r + c[3] * r2 + c[4] * r2 * r,
        c[6] + c[7] * r + c[8] * r2 + c[9] * r2 * r,
    )


def _apply_kaguya(x, y, c, focal):
    xt, yt = x - c[0], y - c[5]
    prev_x, prev_y = np.full_like(x, 1e6), np.full_like(y, 1e6)
    finite = np.isfinite(x) & np.isfinite(y)
    done = ~finite  # (left as they are, as when NaN ran all 50 steps)
    for _ in range(50):
        drx, dry = _kaguya_terms(xt, yt, c)
        nx, ny = np.where(done, xt, x - drx - c[0]), np.where(done, yt, y - dry - c[5])
        done |= (np.abs(nx - prev_x) < 1e-6) & (np.abs(ny - prev_y) < 1e-6)
        prev_x, prev_y, xt, yt = nx, ny, nx, ny
        if done.all():
            break
    done &= finite
    return np.where(done, xt, x), np.where(done, yt, y)


def _remove_kaguya(x, y, c, focal):
    drx, dry = _kaguya_terms(x, y, c)
    return x + drx + c[0], y + dry + c[5]


def _apply_dawn(x, y, c, focal):
    r2 = x * x + y * y
    return x * (1.0 + c[0] * r2), y * (1.0 + c[0] * r2)


def _remove_dawn(x, y, c, focal):
    r2 = x * x + y * y
    ux, uy = x, y
    done = ~(np.isfinite(x) & np.isfinite(y))  # (left as they are, as after all 19 steps)
    for _ in range(19):
        gx, gy = x / (1.0 + c[0] * r2), y / (1.0 + c[0] * r2)
        r2 = np.where(done, r2, gx * gx + gy * gy)
        ok = ~done & (np.abs(gx * (1.0 + c[0] * r2) - x) < _TOLERANCE)
        ok &= np.abs(gy * (1.0 + c[0] * r2) - y) < _TOLERANCE
        ux, uy = np.where(ok, gx, ux), np.where(ok, gy, uy)
        done |= ok
        if done.all():
            break
    return ux, uy


def _apply_lronac(x, y, c, focal):
    dk1 = c[0]
    yt = y.copy()
    prev = np.full_like(y, 1e6)
    done = ~np.isfinite(y)  # (left as it is, as after all 50 steps)
    for _ in range(50):
        new = np.where(done, yt, y * (1.0 + dk1 * yt * yt))
        done |= np.abs(new - prev) <= 1e-10
        prev, yt = new, new
        if done.all():
            break
    far = np.abs(y) > 40  # no root: usgscsm leaves the point as it is
    return x, np.where(done & ~far, yt, y)


def _remove_lronac(x, y, c, focal):
    return x, y / (1.0 + c[0] * y * y)


def _apply_radtan(x, y, c, focal):
    dx, dy = _radtan(x / focal, y / focal, c)
    return dx * focal, dy * focal


def _remove_radtan(x, y, c, focal):
    ux, uy = _newton(x / focal, y / focal, c, _radtan, _radtan_jacobian)
    return ux * focal, uy * focal


_APPLY = {
    "radial": _apply_radial,
    "transverse": _apply_transverse,
    "kaguyalism": _apply_kaguya,
    "dawnfc": _apply_dawn,
    "lrolrocnac": _apply_lronac,
    "radtan": _apply_radtan,
}
_REMOVE = {
    "radial": _remove_radial,
    "transverse": _remove_transverse,
    "kaguyalism": _remove_kaguya,
    "dawnfc": _remove_dawn,
    "lrolrocnac": _remove_lronac,
    "radtan": _remove_radtan,
}
