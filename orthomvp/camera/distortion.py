"""Lens distortion models of Vision Workbench's ``LensDistortion``, and the registry by name.

Positions are (..., 2) arrays in units of the camera's pixel pitch (pixels when the pitch is
1); each model maps undistorted to distorted positions (``distort``) and back (``undistort``,
by Newton's method where there is no closed form), given the camera's focal length (fu, fv)
and principal point (cu, cv) in the same units.

Models: ASP's NULL, TSAI, BrownConrady, Photometrix, FISHEYE and FOV, as VW's
LensDistortion.cc computes them, and OpenCV's full model (ours; for Orthority's ``opencv``).
ASP's AdjustableTSAI and RPC models are recognised and refused by name
(:func:`distortion_class`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields
from typing import ClassVar

import numpy as np

from orthomvp.errors import InputError

_NEWTON_TOLERANCE = 1e-12  # step size at convergence, relative to max(1, |x|)
_NEWTON_RESIDUAL = 1e-10  # largest accepted residual, relative to max(1, |target|)
_NEWTON_MAX_ITER = 50

_Arrays = tuple[np.ndarray, ...]


def _newton(func: Callable[[np.ndarray, np.ndarray], _Arrays], target: np.ndarray) -> np.ndarray:
    """Solve func(x) = target for x (..., 2) by vectorised Newton iteration from x = target.

    ``func(x, y)`` returns the two components of the value and the Jacobian entries
    (fx, fy, dfx/dx, dfx/dy, dfy/dx, dfy/dy). Each point iterates until its step is below
    ``_NEWTON_TOLERANCE``; points whose residual then exceeds ``_NEWTON_RESIDUAL`` come back NaN.
    """
    tx, ty = target[..., 0].ravel(), target[..., 1].ravel()
    x, y = tx.copy(), ty.copy()
    active = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(_NEWTON_MAX_ITER):
            if not active.size:
                break
            xa, ya = x[active], y[active]
            fx, fy, a, b, c, d = func(xa, ya)
            rx, ry = tx[active] - fx, ty[active] - fy
            det = a * d - b * c
            sx, sy = (d * rx - b * ry) / det, (a * ry - c * rx) / det
            xa += sx
            ya += sy
            x[active], y[active] = xa, ya
            scale = np.maximum(1.0, np.maximum(np.abs(xa), np.abs(ya)))
            moving = np.maximum(np.abs(sx), np.abs(sy)) > _NEWTON_TOLERANCE * scale
            active = active[moving & np.isfinite(xa) & np.isfinite(ya)]
        fx, fy = func(x, y)[:2]
        residual = np.maximum(np.abs(fx - tx), np.abs(fy - ty))
        limit = _NEWTON_RESIDUAL * np.maximum(1.0, np.maximum(np.abs(tx), np.abs(ty)))
    bad = ~(residual <= limit)
    x[bad] = np.nan
    y[bad] = np.nan
    return np.stack([x, y], axis=-1).reshape(target.shape)


@dataclass(frozen=True)
class Distortion(ABC):
    """A VW lens distortion model. Coordinates are (..., 2) positions in units of the pitch.

    ``distort`` maps undistorted to distorted positions, ``undistort`` the reverse; both take the
    camera's focal length (fu, fv) and principal point (cu, cv), in the same units. Positions
    where the model cannot be inverted come back NaN.
    """

    name: ClassVar[str]
    """The model's name in ``.tsai`` files."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                raise InputError(
                    f"{self.name} distortion: {f.name} = {value!r} is not a number"
                ) from None
            if not np.isfinite(number):
                raise InputError(f"{self.name} distortion: {f.name} = {value!r} is not finite")
            object.__setattr__(self, f.name, number)

    @abstractmethod
    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Distorted positions of undistorted positions ``xy``."""

    @abstractmethod
    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Undistorted positions of distorted positions ``xy``."""

    def params(self) -> dict[str, float]:
        """The parameters by name, in VW's order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        """All parameter names, in VW's order."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def required_params(cls) -> tuple[str, ...]:
        """The parameters a file must give (the others default to 0)."""
        return tuple(f.name for f in fields(cls) if f.default is MISSING)


@dataclass(frozen=True)
class NullDistortion(Distortion):
    """No lens distortion (VW ``NullLensDistortion``, ``NULL`` in files)."""

    name: ClassVar[str] = "NULL"

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """``xy`` unchanged."""
        return xy

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """``xy`` unchanged."""
        return xy


@dataclass(frozen=True)
class TsaiDistortion(Distortion):
    """VW ``TsaiLensDistortion`` (``TSAI``): OpenCV's radial-tangential model.

    With (x, y) = ((X - cu) / fu, (Y - cv) / fv) the undistorted position normalised by the focal
    length and r2 = x^2 + y^2, the distorted normalised position is
    ``x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)`` and
    ``y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y``, scaled back by the focal
    length and shifted by (cu, cv). Undistortion solves this by Newton's method. The parameters
    are dimensionless; ``k3`` is optional (0) and stored last, as in VW.
    """

    name: ClassVar[str] = "TSAI"
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float = 0.0

    def _normalised(self, x: np.ndarray, y: np.ndarray) -> _Arrays:
        """Distorted normalised position of (x, y) and the Jacobian, as for :func:`_newton`."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)  # d radial / d r2
        fx = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        fy = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        cross = 2.0 * x * y * dradial + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        dxx = radial + 2.0 * x * x * dradial + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        dyy = radial + 2.0 * y * y * dradial + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return fx, fy, dxx, cross, cross, dyy

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        n = (xy - offset) / focal
        fx, fy = self._normalised(n[..., 0], n[..., 1])[:2]
        return np.stack([fx, fy], axis=-1) * focal + offset

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Newton's method, starting from the distorted position, to a step of 1e-12."""
        return _newton(self._normalised, (xy - offset) / focal) * focal + offset


@dataclass(frozen=True)
class BrownConradyDistortion(Distortion):
    """VW ``BrownConradyDistortion`` (``BrownConrady``), in pitch units, *not* normalised.

    The explicit formula goes from distorted to undistorted positions: with
    (x, y) = (X - cu - xp, Y - cv - yp), r2 = x^2 + y^2, radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3 and
    t = p1 r2 + p2 r2^2, the undistorted position is
    ``(x radial - t sin(phi) + cu, y radial + t cos(phi) + cv)`` (VW adds back (cu, cv) but not
    (xp, yp)). Distortion solves this by Newton's method. ``xp``, ``yp`` are in pitch units, ``k1``
    in 1/unit^2, ``k2`` 1/unit^4, ``k3`` 1/unit^6, ``p1`` 1/unit, ``p2`` 1/unit^3, ``phi`` radians.
    """

    name: ClassVar[str] = "BrownConrady"
    xp: float
    yp: float
    k1: float
    k2: float
    k3: float
    p1: float
    p2: float
    phi: float

    def _relative(self, ax: np.ndarray, ay: np.ndarray) -> _Arrays:
        """Undistorted position, relative to (cu, cv), of the distorted one (ax, ay) relative to
        (cu, cv), and the Jacobian, as for :func:`_newton`."""
        bx, by = ax - self.xp, ay - self.yp
        r2 = bx * bx + by * by
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)
        t = r2 * (self.p1 + r2 * self.p2)
        dt = self.p1 + 2.0 * self.p2 * r2
        tx, ty = -np.sin(self.phi), np.cos(self.phi)
        # d f_i / d b_j = radial delta_ij + 2 b_j g_i, with g_i = b_i radial' + tangent_i t'
        gx, gy = bx * dradial + dt * tx, by * dradial + dt * ty
        return (
            bx * radial + t * tx,
            by * radial + t * ty,
            radial + 2.0 * gx * bx,
            2.0 * gx * by,
            2.0 * gy * bx,
            radial + 2.0 * gy * by,
        )

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Newton's method on the undistortion formula, from the undistorted position."""
        return _newton(self._relative, xy - offset) + offset

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        a = xy - offset
        fx, fy = self._relative(a[..., 0], a[..., 1])[:2]
        return np.stack([fx, fy], axis=-1) + offset


@dataclass(frozen=True)
class PhotometrixDistortion(Distortion):
    """VW ``PhotometrixLensDistortion`` (``Photometrix``, Australis conventions), in pitch units.

    Like Brown-Conrady, the explicit formula goes from distorted to undistorted positions: with
    (x, y) = (X - cu - xp, Y - cv - yp), r2 = x^2 + y^2 and d = k1 r2 + k2 r2^2 + k3 r2^3, the
    undistorted position is ``(X + x d + p1 (r2 + 2 x^2) + 2 p2 x y,
    Y + y d + p2 (r2 + 2 y^2) + 2 p1 x y)``. Distortion solves this by Newton's method. ``b1``,
    ``b2`` are carried but unused, as in VW. ``xp``, ``yp`` in pitch units, ``k1`` 1/unit^2,
    ``k2`` 1/unit^4, ``k3`` 1/unit^6, ``p1``, ``p2`` 1/unit.
    """

    name: ClassVar[str] = "Photometrix"
    xp: float
    yp: float
    k1: float
    k2: float
    k3: float
    p1: float
    p2: float
    b1: float
    b2: float

    def _relative(self, ax: np.ndarray, ay: np.ndarray) -> _Arrays:
        """Undistorted position, relative to (cu, cv), of the distorted one (ax, ay) relative to
        (cu, cv), and the Jacobian, as for :func:`_newton`."""
        x, y = ax - self.xp, ay - self.yp
        r2 = x * x + y * y
        d = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dd = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)  # d d / d r2
        p1, p2 = self.p1, self.p2
        return (
            ax + x * d + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * x * y,
            ay + y * d + p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * x * y,
            1.0 + d + 2.0 * x * x * dd + 6.0 * p1 * x + 2.0 * p2 * y,
            2.0 * x * y * dd + 2.0 * p1 * y + 2.0 * p2 * x,
            2.0 * x * y * dd + 2.0 * p2 * x + 2.0 * p1 * y,
            1.0 + d + 2.0 * y * y * dd + 6.0 * p2 * y + 2.0 * p1 * x,
        )

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Newton's method on the undistortion formula, from the undistorted position."""
        return _newton(self._relative, xy - offset) + offset

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        a = xy - offset
        fx, fy = self._relative(a[..., 0], a[..., 1])[:2]
        return np.stack([fx, fy], axis=-1) + offset


_SMALL_RADIUS = 1e-8  # normalised radius below which the radial models are the identity, as VW


@dataclass(frozen=True)
class FisheyeDistortion(Distortion):
    """VW ``FisheyeLensDistortion`` (``FISHEYE``), OpenCV's fisheye model (and Orthority's).

    With (x, y) the undistorted position normalised by the focal length, r = |(x, y)|,
    theta = atan(r) and theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8),
    the distorted normalised position is (x, y) theta_d / r ((x, y) itself where r <= 1e-8).
    Undistortion solves this by Newton's method. The parameters are dimensionless.
    """

    name: ClassVar[str] = "FISHEYE"
    k1: float
    k2: float
    k3: float
    k4: float

    def _normalised(self, x: np.ndarray, y: np.ndarray) -> _Arrays:
        """Distorted normalised position of (x, y) and the Jacobian, as for :func:`_newton`."""
        r2 = x * x + y * y
        r = np.sqrt(r2)
        small = r <= _SMALL_RADIUS
        rs = np.where(small, 1.0, r)
        t = np.arctan(rs)
        t2 = t * t
        poly = 1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4)))
        dpoly = 1.0 + t2 * (
            3 * self.k1 + t2 * (5 * self.k2 + t2 * (7 * self.k3 + 9 * self.k4 * t2))
        )
        scale = np.where(small, 1.0, t * poly / rs)
        # d scale / d r, divided by r: the Jacobian is scale I + (scale' / r) (x, y) (x, y)^T
        q = np.where(small, 0.0, (dpoly / (1.0 + rs * rs) - scale) / (rs * rs))
        return x * scale, y * scale, scale + q * x * x, q * x * y, q * x * y, scale + q * y * y

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        n = (xy - offset) / focal
        fx, fy = self._normalised(n[..., 0], n[..., 1])[:2]
        return np.stack([fx, fy], axis=-1) * focal + offset

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Newton's method, starting from the distorted position."""
        return _newton(self._normalised, (xy - offset) / focal) * focal + offset


@dataclass(frozen=True)
class FovDistortion(Distortion):
    """VW ``FovLensDistortion`` (``FOV``): the one-parameter field-of-view model, k1 > 0.

    With r_u the radius of the undistorted position normalised by the focal length, the distorted
    radius is r_d = atan(2 r_u tan(k1 / 2)) / k1, and the inverse r_u = tan(r_d k1) / (2 tan(k1 /
    2)); positions scale by r_d / r_u (unchanged where the radius is <= 1e-8). Both directions are
    explicit. ``k1`` is dimensionless (radians).
    """

    name: ClassVar[str] = "FOV"
    k1: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.k1 <= 0:
            raise InputError(f"FOV distortion: k1 = {self.k1!r} must be positive")

    def _scaled(
        self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray, forward: bool
    ) -> np.ndarray:
        n = (xy - offset) / focal
        r = np.hypot(n[..., 0], n[..., 1])
        small = r <= _SMALL_RADIUS
        rs = np.where(small, 1.0, r)
        two_tan = 2.0 * np.tan(self.k1 / 2.0)
        with np.errstate(invalid="ignore"):
            other = np.arctan(rs * two_tan) / self.k1 if forward else np.tan(rs * self.k1) / two_tan
            if not forward:  # beyond r_d = pi / (2 k1) no undistorted position exists
                other = np.where(rs * self.k1 < np.pi / 2, other, np.nan)
        scale = np.where(small, 1.0, other / rs)
        return n * scale[..., None] * focal + offset

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        return self._scaled(xy, focal, offset, forward=True)

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring); NaN where r_d k1 >= pi / 2."""
        return self._scaled(xy, focal, offset, forward=False)


@dataclass(frozen=True)
class OpenCVDistortion(Distortion):
    """OpenCV's full camera model (``OpenCV``: an orthomvp name, ASP does not read it).

    Used for Orthority's ``opencv`` cameras when they need more than TSAI. With (x, y) the
    undistorted position normalised by the focal length and r2 = x^2 + y^2, first
    ``x'' = x g + 2 p1 x y + p2 (r2 + 2 x^2) + s1 r2 + s2 r2^2`` and
    ``y'' = y g + p1 (r2 + 2 y^2) + 2 p2 x y + s3 r2 + s4 r2^2``, where
    g = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3); then the tilted-sensor
    homography of angles (tx, ty), radians: with T = Ry(ty) Rx(tx) (OpenCV's rotations,
    Rx(a) = [[1, 0, 0], [0, cos a, sin a], [0, -sin a, cos a]],
    Ry(a) = [[cos a, 0, -sin a], [0, 1, 0], [sin a, 0, cos a]]), H = [[T33, 0, -T13],
    [0, T33, -T23], [0, 0, 1]] T maps (x'', y'', 1) to the distorted normalised position
    (homogeneous). Undistortion inverts H exactly and the rest by Newton's method. Every
    parameter defaults to 0 (OpenCV's k1..k6, p1, p2, s1..s4, tau_x, tau_y).
    """

    name: ClassVar[str] = "OpenCV"
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0
    s1: float = 0.0
    s2: float = 0.0
    s3: float = 0.0
    s4: float = 0.0
    tx: float = 0.0
    ty: float = 0.0

    @property
    def tilt(self) -> np.ndarray:
        """The (3, 3) tilted-sensor homography H (the identity when tx = ty = 0)."""
        cx, sx, cy, sy = np.cos(self.tx), np.sin(self.tx), np.cos(self.ty), np.sin(self.ty)
        rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
        rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
        t = rot_y @ rot_x
        proj = np.array([[t[2, 2], 0.0, -t[0, 2]], [0.0, t[2, 2], -t[1, 2]], [0.0, 0.0, 1.0]])
        return proj @ t

    def _untilted(self, x: np.ndarray, y: np.ndarray) -> _Arrays:
        """(x'', y'') of the normalised position (x, y) and the Jacobian, as for :func:`_newton`."""
        r2 = x * x + y * y
        num = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        den = 1.0 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6))
        dnum = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)
        dden = self.k4 + r2 * (2.0 * self.k5 + 3.0 * self.k6 * r2)
        g = num / den
        dg = (dnum * den - num * dden) / (den * den)  # d g / d r2
        px = self.s1 + 2.0 * self.s2 * r2  # d prism_x / d r2
        py = self.s3 + 2.0 * self.s4 * r2
        p1, p2 = self.p1, self.p2
        fx = x * g + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (self.s1 + self.s2 * r2)
        fy = y * g + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (self.s3 + self.s4 * r2)
        dxx = g + 2.0 * x * x * dg + 2.0 * p1 * y + 6.0 * p2 * x + 2.0 * x * px
        dxy = 2.0 * x * y * dg + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * y * px
        dyx = 2.0 * x * y * dg + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * x * py
        dyy = g + 2.0 * y * y * dg + 6.0 * p1 * y + 2.0 * p2 * x + 2.0 * y * py
        return fx, fy, dxx, dxy, dyx, dyy

    def distort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Explicit formula (see the class docstring)."""
        n = (xy - offset) / focal
        fx, fy = self._untilted(n[..., 0], n[..., 1])[:2]
        h = np.stack([fx, fy, np.ones_like(fx)], axis=-1) @ self.tilt.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return h[..., :2] / h[..., 2:] * focal + offset

    def undistort(self, xy: np.ndarray, focal: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """The inverse homography, then Newton's method from its result."""
        n = (xy - offset) / focal
        h = np.concatenate([n, np.ones_like(n[..., :1])], axis=-1) @ np.linalg.inv(self.tilt).T
        with np.errstate(divide="ignore", invalid="ignore"):
            untilted = h[..., :2] / h[..., 2:]
        return _newton(self._untilted, untilted) * focal + offset


_DISTORTIONS: dict[str, type[Distortion]] = {
    cls.name.lower(): cls
    for cls in (
        NullDistortion,
        TsaiDistortion,
        BrownConradyDistortion,
        PhotometrixDistortion,
        FisheyeDistortion,
        FovDistortion,
        OpenCVDistortion,
    )
}
_UNSUPPORTED_DISTORTIONS = {
    "adjustabletsai": "AdjustableTSAI",
    "rpc": "RPC",
}


def distortion_class(name: str) -> type[Distortion]:
    """The distortion model called ``name`` (case-insensitive); InputError if unsupported."""
    key = name.strip().lower()
    if key in _DISTORTIONS:
        return _DISTORTIONS[key]
    known = ", ".join(cls.name for cls in _DISTORTIONS.values())
    if key in _UNSUPPORTED_DISTORTIONS:
        raise InputError(
            f"ASP's {_UNSUPPORTED_DISTORTIONS[key]} lens distortion is not supported (supported: "
            f"{known}); ASP's convert_pinhole_model can convert it to TSAI"
        )
    raise InputError(f"unsupported lens distortion model {name!r} (supported: {known})")
