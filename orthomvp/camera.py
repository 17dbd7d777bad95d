"""Frame (pinhole) cameras as defined by Vision Workbench's ``PinholeModel``, and their files.

Conventions, those of VW and the Ames Stereo Pipeline (ASP):

- World coordinates are metres. ``rotation`` R is camera-to-world, ``center`` C the camera centre,
  so a world point X has camera coordinates q = R^T (X - C).
- ``u_direction``, ``v_direction``, ``w_direction`` (orthonormal, default the camera x, y, z axes)
  give the image axes: s = (u.q, v.q, w.q); w is the optical axis, s_w the depth.
- ``fu``, ``fv``, ``cu``, ``cv`` and all lens distortion parameters are in units of ``pitch``
  (pixels when ``pitch`` is 1, else millimetres or metres). The undistorted position is
  (fu s_u / s_w + cu, fv s_v / s_w + cv); lens distortion maps it, in these same units, to the
  distorted position, which divided by ``pitch`` is the pixel.
- Pixels are (u, v) = (column, row); integer values are pixel centres, as in VW.

Lens distortion models: ASP's NULL, TSAI, BrownConrady, Photometrix, FISHEYE and FOV, as VW's
LensDistortion.cc computes them, and OpenCV's full model (ours; for Orthority's ``opencv``).
ASP's AdjustableTSAI and RPC models are recognised and refused by name.

File formats: ASP/VW ``.tsai`` text (VERSION_1 to VERSION_4 and the unversioned form), VW's
binary ``.pinhole`` protobuf (``TsaiFile``, decoded here without a protobuf library), a plain
JSON form of our own, and Orthority's interior (YAML) and exterior (CSV, GeoJSON) parameter
files (:func:`read_orthority_cameras`; :func:`read_camera` picks one image's camera from them).
Writers replace the destination atomically.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import secrets
import struct
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path
from typing import ClassVar

import numpy as np

from orthomvp.errors import FormatError, InputError

ORTHONORMAL_TOLERANCE = 1e-6
"""Largest |R^T R - I| entry accepted for a rotation (and for the u, v, w frame)."""

_NEWTON_TOLERANCE = 1e-12  # step size at convergence, relative to max(1, |x|)
_NEWTON_RESIDUAL = 1e-10  # largest accepted residual, relative to max(1, |target|)
_NEWTON_MAX_ITER = 50
_ROUND_TRIP_TOLERANCE = 1e-8  # focal-normalised units, for the project() distortion check


# ---------------------------------------------------------------------------------------------
# Lens distortion


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


# ---------------------------------------------------------------------------------------------
# The camera


class _FieldError(InputError):
    """An invalid camera parameter; ``field`` names it so that readers can point at its line."""

    def __init__(self, field_name: str, message: str) -> None:
        self.field = field_name
        super().__init__(message)


def _orthonormality_error(m: np.ndarray) -> float:
    """Largest entry of |M^T M - I|."""
    return float(np.abs(m.T @ m - np.eye(3)).max())


def _finite(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a read-only float64 array of ``shape`` with finite entries."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _FieldError(name, f"{name} must be numbers, got {value!r}") from None
    if arr.shape != shape:
        raise _FieldError(name, f"{name} must have shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise _FieldError(name, f"{name} must be finite, got {value!r}")
    arr.setflags(write=False)
    return arr


def _default_axis(index: int) -> Callable[[], np.ndarray]:
    """A factory of the unit vector along axis ``index`` (VW's default u, v, w)."""
    return lambda: np.eye(3)[index]


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """A VW/ASP pinhole camera (see the module docstring for conventions and units).

    ``fu``, ``fv``, ``cu``, ``cv``: focal lengths and principal point in units of ``pitch``
    (pixel = value / pitch). ``center``: camera centre C (3,), world metres. ``rotation``: R
    (3, 3), camera-to-world. ``width``, ``height``: optional image size in pixels.
    Construction validates everything and raises InputError: R must be a rotation (orthonormal
    within 1e-6, determinant +1), u, v, w orthonormal, fu, fv and pitch positive.
    """

    fu: float
    fv: float
    cu: float
    cv: float
    center: np.ndarray
    rotation: np.ndarray
    u_direction: np.ndarray = field(default_factory=_default_axis(0))
    v_direction: np.ndarray = field(default_factory=_default_axis(1))
    w_direction: np.ndarray = field(default_factory=_default_axis(2))
    pitch: float = 1.0
    distortion: Distortion = field(default_factory=NullDistortion)
    width: int | None = None
    height: int | None = None

    def __post_init__(self) -> None:
        for name in ("fu", "fv", "cu", "cv", "pitch"):
            value = float(_finite(name, getattr(self, name), ()))
            if name in ("fu", "fv", "pitch") and value <= 0:
                raise _FieldError(name, f"{name} must be positive, got {value!r}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "center", _finite("center", self.center, (3,)))
        rotation = _finite("rotation", self.rotation, (3, 3))
        error = _orthonormality_error(rotation)
        if error > ORTHONORMAL_TOLERANCE:
            raise _FieldError(
                "rotation", f"R is not a rotation: |R^T R - I| reaches {error:.2g} (limit 1e-6)"
            )
        if np.linalg.det(rotation) < 0:
            raise _FieldError("rotation", "R is a reflection (determinant -1), not a rotation")
        object.__setattr__(self, "rotation", rotation)
        for name in ("u_direction", "v_direction", "w_direction"):
            object.__setattr__(self, name, _finite(name, getattr(self, name), (3,)))
        error = _orthonormality_error(self._frame.T)
        if error > ORTHONORMAL_TOLERANCE:
            raise _FieldError(
                "u_direction",
                f"u, v, w directions are not orthonormal: error {error:.2g} (limit 1e-6)",
            )
        if not isinstance(self.distortion, Distortion):
            raise _FieldError("distortion", f"not a lens distortion model: {self.distortion!r}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None and (
                isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0
            ):
                raise _FieldError(name, f"{name} must be a positive integer or None, got {value!r}")
            object.__setattr__(self, name, None if value is None else int(value))

    @property
    def _frame(self) -> np.ndarray:
        """The (3, 3) matrix whose rows are u, v, w."""
        return np.stack([self.u_direction, self.v_direction, self.w_direction])

    @property
    def world_to_image_axes(self) -> np.ndarray:
        """A = [u; v; w] R^T (3, 3): s = A (X - C) are the image-axis coordinates of X."""
        return self._frame @ self.rotation.T

    @property
    def _focal(self) -> np.ndarray:
        return np.array([self.fu, self.fv])

    @property
    def _offset(self) -> np.ndarray:
        return np.array([self.cu, self.cv])

    @property
    def K(self) -> np.ndarray:
        """The (3, 3) intrinsic matrix in pixels: [[fu, 0, cu], [0, fv, cv], [0, 0, 1]] / pitch."""
        k = np.array([[self.fu, 0.0, self.cu], [0.0, self.fv, self.cv], [0.0, 0.0, self.pitch]])
        return k / self.pitch

    @property
    def F(self) -> np.ndarray:
        """The (3, 4) projection matrix of eq. (9), (u, v, 1) ~ F (X, 1), pixels from metres.

        Only defined without lens distortion: raises InputError otherwise.
        """
        if not isinstance(self.distortion, NullDistortion):
            raise InputError(
                f"a camera with {self.distortion.name} lens distortion has no projection matrix"
            )
        a = self.world_to_image_axes
        return self.K @ np.hstack([a, -(a @ self.center)[:, None]])

    @property
    def look_direction(self) -> np.ndarray:
        """Unit world vector of the optical axis (+w), pointing into the scene."""
        d = np.linalg.solve(self.world_to_image_axes, np.array([0.0, 0.0, 1.0]))
        return d / np.linalg.norm(d)

    def with_image_size(self, width: int | None, height: int | None) -> PinholeCamera:
        """A copy with the image size (pixels) set."""
        return replace(self, width=width, height=height)

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``xyz`` (..., 3), metres, into the image (VW ``point_to_pixel``).

        Returns ``uv`` (..., 2), pixels (u = column, v = row, integer values at pixel centres),
        and ``depth`` (...), metres along the optical axis, > 0 in front of the camera. Points
        not in front, and (as VW's point_to_pixel check) points whose distorted pixel does not
        map back to them through :meth:`ray`, e.g. beyond a fold of the distortion, get NaN uv.
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        if xyz.shape[-1:] != (3,):
            raise InputError(f"project needs points of shape (..., 3), got {xyz.shape}")
        s = (xyz - self.center) @ self.world_to_image_axes.T
        depth = s[..., 2]
        valid = depth > 0
        # points at depth 0 give inf/NaN here; they are masked out below
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            normalised = s[..., :2] / depth[..., None]
            undistorted = normalised * self._focal + self._offset
            distorted = self.distortion.distort(undistorted, self._focal, self._offset)
            if not isinstance(self.distortion, NullDistortion):
                back = self.distortion.undistort(distorted, self._focal, self._offset)
                miss = np.abs((back - undistorted) / self._focal).max(axis=-1)
                limit = _ROUND_TRIP_TOLERANCE * np.maximum(1.0, np.abs(normalised).max(axis=-1))
                valid = valid & (miss <= limit)
        uv = np.where(np.asarray(valid)[..., None], distorted / self.pitch, np.nan)
        return uv, depth

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays through pixels ``uv`` (..., 2) (VW ``pixel_to_vector``).

        Returns ``origins`` (..., 3), the camera centre in world metres, and unit ``directions``
        (..., 3) pointing into the scene. Pixels where the distortion cannot be inverted get NaN.
        """
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape[-1:] != (2,):
            raise InputError(f"ray needs pixels of shape (..., 2), got {uv.shape}")
        undistorted = self.distortion.undistort(uv * self.pitch, self._focal, self._offset)
        normalised = (undistorted - self._offset) / self._focal
        s = np.concatenate([normalised, np.ones_like(normalised[..., :1])], axis=-1)
        directions = s @ np.linalg.inv(self.world_to_image_axes).T
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        origins = np.broadcast_to(self.center, directions.shape).copy()
        return origins, directions


# ---------------------------------------------------------------------------------------------
# Reading


def read_camera(
    path: str | Path, image: str | Path | None = None, *, interior: str | Path | None = None
) -> PinholeCamera:
    """Read a camera: ``.tsai`` text, binary ``.pinhole``, our ``.json``, or Orthority files.

    Single-camera files (``.tsai``, ``.pinhole``, ``.json``; other extensions are recognised by
    their content) ignore ``image`` and ``interior``.

    Orthority's exterior parameter files (``.csv``, ``.geojson``, or a ``.json`` holding a
    GeoJSON FeatureCollection) hold many images: ``image`` (a path or a name) picks the row
    whose ``filename`` has the same stem (file name without directory and extension); without
    ``image`` the file must hold one camera. The interior parameters come from ``interior``, or
    else from the one ``.yaml``/``.yml`` file in the exterior file's directory. CSV angles are
    in degrees (see :func:`read_orthority_cameras`). An interior ``.yaml`` alone holds no
    camera pose and raises InputError.

    A missing or unreadable file raises InputError; a file that breaks its format raises
    FormatError naming it (and the line, for text formats).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in _INTERIOR_SUFFIXES:
        raise InputError(
            f"{path}: Orthority interior parameters hold no camera position; give the exterior "
            "parameter file (.csv or .geojson) as the camera, with this file beside it"
        )
    data = _read_bytes(path, "camera file")
    if suffix in _EXTERIOR_SUFFIXES or (
        suffix == ".json" and _FEATURE_COLLECTION.search(_text(path, data))
    ):
        return _orthority_camera(path, image, interior)
    if suffix == ".tsai":
        return _parse_tsai(path, _text(path, data))
    if suffix == ".pinhole":
        return _parse_pinhole(path, data)
    if suffix == ".json":
        return _parse_json(path, _text(path, data))
    return _sniff(path, data)


def _read_bytes(path: Path, what: str) -> bytes:
    """The contents of ``path``; InputError naming ``what`` if it cannot be read."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not a {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what} ({exc.strerror})") from exc


def _text(path: Path, data: bytes) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not a text file (invalid UTF-8 at byte {exc.start})") from None


def _sniff(path: Path, data: bytes) -> PinholeCamera:
    """Recognise a camera file by its content."""
    try:
        head = data.decode("utf-8-sig").lstrip()
    except UnicodeDecodeError:
        head = ""
    if head.startswith("{"):
        return _parse_json(path, _text(path, data))
    if re.match(r"VERSION_|fu\s*=", head):
        return _parse_tsai(path, _text(path, data))
    try:
        decoded = _decode_protobuf(data)
    except ValueError as exc:
        raise FormatError(
            path, f"not a camera file: not .tsai text, not JSON, not a .pinhole protobuf ({exc})"
        ) from exc
    return _camera_from_protobuf(path, decoded)


def _build(path: Path, where: Callable[[str], int | None], **kwargs: object) -> PinholeCamera:
    """PinholeCamera(**kwargs), its validation errors as FormatError at the field's line."""
    try:
        return PinholeCamera(**kwargs)
    except _FieldError as exc:
        raise FormatError(path, str(exc), where(exc.field)) from exc


def _distortion(path: Path, name: str, values: Mapping[str, float], line: int | None) -> Distortion:
    """The distortion model ``name`` with parameters ``values``; FormatError at ``line``."""
    try:
        cls = distortion_class(name)
    except InputError as exc:
        raise FormatError(path, str(exc), line) from None
    missing = [p for p in cls.required_params() if p not in values]
    if missing:
        raise FormatError(path, f"{cls.name} distortion is missing {', '.join(missing)}", line)
    unknown = [p for p in values if p not in cls.param_names()]
    if unknown:
        raise FormatError(path, f"{cls.name} distortion has no parameter {unknown[0]!r}", line)
    try:
        return cls(**values)
    except InputError as exc:
        raise FormatError(path, str(exc), line) from None


# .tsai text

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_KEY_VALUES = re.compile(r"(\w+)\s*=\s*(.*)")
_TSAI_KEYS = (
    ("fu", "fu", 1),
    ("fv", "fv", 1),
    ("cu", "cu", 1),
    ("cv", "cv", 1),
    ("u_direction", "u_direction", 3),
    ("v_direction", "v_direction", 3),
    ("w_direction", "w_direction", 3),
    ("C", "center", 3),
    ("R", "rotation", 9),
)


class _Lines:
    """The non-blank lines of a text file, read one by one with their 1-based numbers."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        lines = text.splitlines()
        self.items = [(i + 1, s.strip()) for i, s in enumerate(lines) if s.strip()]
        self.end = len(lines) + 1
        self.pos = 0

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def take(self, expected: str) -> tuple[int, str]:
        """The next line; FormatError saying ``expected`` at the end of the file."""
        item = self.peek()
        if item is None:
            raise FormatError(self.path, f"file ends where {expected} was expected", self.end)
        self.pos += 1
        return item

    def numbers(self, key: str, count: int) -> tuple[list[float], int]:
        """Parse the next line as ``key = n1 ... n<count>``; returns the numbers and line."""
        line, text = self.take(f"'{key} = ...'")
        match = _KEY_VALUES.fullmatch(text)
        if match is None or match[1] != key:
            raise FormatError(self.path, f"expected '{key} = ...', found {text!r}", line)
        tokens = match[2].split()
        if len(tokens) != count:
            plural = "number" if count == 1 else "numbers"
            raise FormatError(
                self.path, f"expected {count} {plural} after '{key} =', found {len(tokens)}", line
            )
        return [_number(self.path, t, key, line) for t in tokens], line


def _number(path: Path, token: str, key: str, line: int) -> float:
    if not _NUMBER.fullmatch(token):
        raise FormatError(path, f"{token!r} after '{key} =' is not a number", line)
    return float(token)


def _parse_tsai(path: Path, text: str) -> PinholeCamera:
    """Parse ASP/VW ``.tsai`` text, following VW's ``PinholeModel::read``.

    VERSION_4 has a ``PINHOLE`` line after the version; VERSION_3 and 4 need ``pitch`` and the
    distortion name. The unversioned (and VERSION_1/2) form may omit ``pitch`` (1) and the name,
    in which case TSAI parameters follow directly.
    """
    lines = _Lines(path, text)
    version = 1
    first = lines.peek()
    if first is None:
        raise FormatError(path, "empty camera file", 1)
    if first[1].startswith("VERSION"):
        line, header = lines.take("VERSION_4")
        match = re.fullmatch(r"VERSION_(\d+)", header)
        if match is None or not 1 <= int(match[1]) <= 4:
            raise FormatError(path, f"unsupported version {header!r} (expected VERSION_1..4)", line)
        version = int(match[1])
        if version == 4:
            line, kind = lines.take("'PINHOLE'")
            if kind != "PINHOLE":
                raise FormatError(
                    path, f"camera type {kind!r} is not supported, only PINHOLE", line
                )
    values: dict[str, object] = {}
    where: dict[str, int] = {}
    for key, name, count in _TSAI_KEYS:
        numbers, where[name] = lines.numbers(key, count)
        values[name] = (
            numbers[0] if count == 1 else np.reshape(numbers, (3, 3) if count == 9 else 3)
        )
    nxt = lines.peek()
    if version >= 3 or (nxt is not None and nxt[1].startswith("pitch")):
        (values["pitch"],), where["pitch"] = lines.numbers("pitch", 1)
    nxt = lines.peek()
    if version <= 2 and nxt is not None and _KEY_VALUES.fullmatch(nxt[1]):
        model, name_line = "TSAI", nxt[0]  # old files: TSAI parameters without a name line
    else:
        name_line, model = lines.take("the lens distortion name (NULL, TSAI, ...)")
    try:
        names = distortion_class(model).param_names()
    except InputError as exc:
        raise FormatError(path, str(exc), name_line) from None
    params: dict[str, float] = {}
    while lines.peek() is not None:
        line, text_ = lines.take("")
        match = _KEY_VALUES.fullmatch(text_)
        if match is None or len(match[2].split()) != 1:
            raise FormatError(path, f"expected '<parameter> = <number>', found {text_!r}", line)
        if match[1] not in names:
            raise FormatError(path, f"{model} distortion has no parameter {match[1]!r}", line)
        if match[1] in params:
            raise FormatError(path, f"distortion parameter {match[1]!r} given twice", line)
        params[match[1]] = _number(path, match[2].strip(), match[1], line)
    values["distortion"] = _distortion(path, model, params, name_line)
    return _build(path, where.get, **values)


# .pinhole protobuf

_PB_DOUBLES = {
    2: ("focal_length", 2),
    3: ("center_point", 2),
    4: ("u_direction", 3),
    5: ("v_direction", 3),
    6: ("w_direction", 3),
    7: ("camera_center", 3),
    8: ("camera_rotation", 9),
    10: ("distortion_vector", None),
    11: ("pixel_pitch", 1),
}


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    """Decode a base-128 varint at ``pos``; returns the value and the position after it."""
    start, value, shift = pos, 0, 0
    while True:
        if pos >= len(data):
            raise ValueError(f"truncated varint at byte {start}")
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7
        if shift >= 70:
            raise ValueError(f"varint longer than 10 bytes at byte {start}")


def _decode_protobuf(data: bytes) -> dict[int, list[tuple[int, bytes]]]:
    """Split a protobuf message into its fields: number -> [(wire type, raw bytes), ...].

    Handles wire types 0 (varint; the value is dropped, TsaiFile has no varint field),
    1 (64-bit), 2 (length-delimited) and 5 (32-bit); raises ValueError, naming the byte offset,
    on anything malformed.
    """
    if not data:
        raise ValueError("empty file")
    out: dict[int, list[tuple[int, bytes]]] = {}
    pos = 0
    while pos < len(data):
        start = pos
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise ValueError(f"invalid field number 0 at byte {start}")
        if wire == 0:
            pos = _varint(data, pos)[1]
            size = 0
        elif wire == 2:
            size, pos = _varint(data, pos)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
        else:
            raise ValueError(f"unsupported wire type {wire} (field {number}) at byte {start}")
        if pos + size > len(data):
            raise ValueError(f"field {number} at byte {start} runs past the end of the file")
        out.setdefault(number, []).append((wire, data[pos : pos + size]))
        pos += size
    return out


def _pb_doubles(number: int, entries: list[tuple[int, bytes]]) -> list[float]:
    """The doubles of a repeated double field, packed (wire type 2) or not (wire type 1)."""
    values: list[float] = []
    for wire, raw in entries:
        if wire not in (1, 2):
            raise ValueError(f"field {number} has wire type {wire}, expected doubles")
        if len(raw) % 8:
            raise ValueError(f"field {number}: {len(raw)} bytes of packed doubles")
        values.extend(struct.unpack(f"<{len(raw) // 8}d", raw))
    return values


def _parse_pinhole(path: Path, data: bytes) -> PinholeCamera:
    try:
        decoded = _decode_protobuf(data)
    except ValueError as exc:
        raise FormatError(path, f"corrupt .pinhole protobuf: {exc}") from exc
    return _camera_from_protobuf(path, decoded)


def _camera_from_protobuf(path: Path, decoded: dict[int, list[tuple[int, bytes]]]) -> PinholeCamera:
    """A camera from the fields of a VW ``TsaiFile`` message (see TsaiFile.proto)."""
    try:
        entries = decoded.get(9, [])
        if not entries or entries[-1][0] != 2:
            raise ValueError("the required distortion_name (field 9) is missing")
        distortion_name = entries[-1][1].decode("utf-8")
        got: dict[str, list[float]] = {}
        for number, (name, count) in _PB_DOUBLES.items():
            values = _pb_doubles(number, decoded.get(number, []))
            if number == 11 and values:
                values = values[-1:]  # a non-repeated field: the last value wins
            if count is not None and len(values) != count:
                raise ValueError(
                    f"{name} (field {number}) has {len(values)} values, expected {count}"
                )
            got[name] = values
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"bad .pinhole camera: {exc}") from exc
    dist_values = got["distortion_vector"]
    try:
        cls = distortion_class(distortion_name)
    except InputError as exc:
        raise FormatError(path, str(exc)) from None
    counts = range(len(cls.required_params()), len(cls.param_names()) + 1)
    if len(dist_values) not in counts:
        raise FormatError(
            path,
            f"{distortion_name} distortion needs {' or '.join(map(str, counts))} values, "
            f"got {len(dist_values)}",
        )
    distortion = _distortion(
        path, cls.name, dict(zip(cls.param_names(), dist_values, strict=False)), None
    )
    return _build(
        path,
        lambda _: None,
        fu=got["focal_length"][0],
        fv=got["focal_length"][1],
        cu=got["center_point"][0],
        cv=got["center_point"][1],
        u_direction=got["u_direction"],
        v_direction=got["v_direction"],
        w_direction=got["w_direction"],
        center=got["camera_center"],
        rotation=np.reshape(got["camera_rotation"], (3, 3)),  # row-major, as VW's MatrixProxy
        pitch=got["pixel_pitch"][0],
        distortion=distortion,
    )


# .json

_JSON_REQUIRED = ("fu", "fv", "cu", "cv", "center", "rotation")
_JSON_OPTIONAL = ("type", "u_direction", "v_direction", "w_direction", "pitch", "distortion")
_JSON_OPTIONAL_SIZE = ("width", "height")


def _json_line(text: str, key: str) -> int | None:
    """The line of the first ``"key":`` in ``text``, if any."""
    match = re.search(rf'"{re.escape(key)}"\s*:', text)
    return text.count("\n", 0, match.start()) + 1 if match else None


def _json_numbers(path: Path, text: str, key: str, value: object, shape: tuple[int, ...]) -> object:
    """``value`` checked to be a number, or nested lists of numbers of ``shape``."""
    if shape:
        if not isinstance(value, list) or len(value) != shape[0]:
            raise FormatError(
                path, f"{key} must be a list of {shape[0]} items", _json_line(text, key)
            )
        return [_json_numbers(path, text, key, item, shape[1:]) for item in value]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FormatError(path, f"{key}: {value!r} is not a number", _json_line(text, key))
    return float(value)


def _parse_json(path: Path, text: str) -> PinholeCamera:
    """Parse our JSON form (see :func:`camera_to_dict`)."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}", exc.lineno) from None
    if not isinstance(obj, dict):
        raise FormatError(path, "expected a JSON object with the camera's fields", 1)
    for key in obj:
        if key not in _JSON_REQUIRED + _JSON_OPTIONAL + _JSON_OPTIONAL_SIZE:
            raise FormatError(path, f"unknown key {key!r}", _json_line(text, key))
    for key in _JSON_REQUIRED:
        if key not in obj:
            raise FormatError(path, f"missing key {key!r}")
    if obj.get("type", "pinhole") != "pinhole":
        raise FormatError(path, f"camera type {obj['type']!r} is not supported, only 'pinhole'", 1)
    shapes = {"center": (3,), "rotation": (3, 3), "pitch": ()}
    shapes |= {name: (3,) for name in ("u_direction", "v_direction", "w_direction")}
    values: dict[str, object] = {}
    for key in ("fu", "fv", "cu", "cv", *shapes):
        if key in obj:
            values[key] = _json_numbers(path, text, key, obj[key], shapes.get(key, ()))
    for key in _JSON_OPTIONAL_SIZE:
        size = obj.get(key)
        if size is not None and (isinstance(size, bool) or not isinstance(size, int)):
            raise FormatError(path, f"{key} must be an integer or null", _json_line(text, key))
        values[key] = size
    spec = obj.get("distortion", {"model": "NULL"})
    line = _json_line(text, "distortion")
    if not isinstance(spec, dict) or not isinstance(spec.get("model"), str):
        raise FormatError(path, 'distortion must be an object with a "model" name', line)
    params = {k: _json_numbers(path, text, k, v, ()) for k, v in spec.items() if k != "model"}
    values["distortion"] = _distortion(path, spec["model"], params, line)
    return _build(path, lambda name: _json_line(text, name), **values)


# Orthority parameter files: interior (.yaml), exterior (.csv, .geojson)

_ORTHORITY_MODELS: dict[str, tuple[str, ...]] = {
    "pinhole": (),
    "brown": ("k1", "k2", "p1", "p2", "k3"),
    "fisheye": FisheyeDistortion.param_names(),
    "opencv": OpenCVDistortion.param_names(),
}
_ORTHORITY_COMMON = ("type", "im_size", "focal_len", "sensor_size", "cx", "cy")
_CSV_LEGACY_FIELDS = ("filename", "x", "y", "z", "omega", "phi", "kappa")
_FEATURE_COLLECTION = re.compile(r'"type"\s*:\s*"FeatureCollection"')
_EXTERIOR_SUFFIXES = (".csv", ".geojson")
_INTERIOR_SUFFIXES = (".yaml", ".yml")


def orthority_rotation(omega: float, phi: float, kappa: float) -> np.ndarray:
    """Camera-to-world R (3, 3) of Orthority/PATB angles (radians), for VW's camera axes.

    R = Rx(omega) Ry(phi) Rz(kappa) diag(1, -1, -1), with the right-handed rotations
    Rx(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]] (Ry, Rz alike): the angles rotate
    PATB camera axes (x right, y up, z backward) to the world; diag(1, -1, -1) turns them into
    the OpenCV/VW axes used here (x right, y down, z forward, u = x, v = y, w = z).
    """
    co, so, cp, sp, ck, sk = (f(a) for a in (omega, phi, kappa) for f in (np.cos, np.sin))
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, co, -so], [0.0, so, co]])
    rot_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rot_z = np.array([[ck, -sk, 0.0], [sk, ck, 0.0], [0.0, 0.0, 1.0]])
    return rot_x @ rot_y @ rot_z @ np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class _Interior:
    """One camera of an interior parameter file, in pixels."""

    fu: float
    fv: float
    cu: float
    cv: float
    width: int
    height: int
    distortion: Distortion


@dataclass(frozen=True)
class _Exterior:
    """One image of an exterior parameter file: position (world units), angles in radians."""

    filename: str
    camera: str | None
    xyz: tuple[float, float, float]
    opk: tuple[float, float, float]
    line: int | None


def read_orthority_cameras(
    interior: str | Path, exterior: str | Path, *, radians: bool = False
) -> dict[str, PinholeCamera]:
    """The cameras of Orthority interior and exterior parameter files, by image file stem.

    ``interior``: Orthority's YAML interior parameters, a mapping of camera id to ``type``
    (``pinhole``, ``brown``, ``opencv`` or ``fisheye``), ``im_size`` [width, height] pixels,
    ``focal_len`` (a number or [fx, fy]) in the units of the optional ``sensor_size``
    [width, height] (absent: ``focal_len`` is normalised by the image width, as Orthority does),
    ``cx``, ``cy`` (principal point offsets in OpenSfM normalised image coordinates: the
    principal point is ((w - 1) / 2 + cx max(w, h), (h - 1) / 2 + cy max(w, h)) pixels) and the
    model's distortion coefficients (default 0): ``brown`` k1 k2 p1 p2 k3 and ``opencv`` k1..k6
    p1 p2 s1..s4 tx ty, both OpenCV's model (TSAI here, or :class:`OpenCVDistortion` when a
    coefficient beyond TSAI's is set); ``fisheye`` k1..k4 (FISHEYE). Without any coefficient the
    camera has no distortion.

    ``exterior``: Orthority's CSV (header naming ``filename``, ``x``, ``y``, ``z``, ``omega``,
    ``phi``, ``kappa`` and optionally ``camera``, or no header and those seven in that order;
    angles in degrees unless ``radians``) or GeoJSON (a FeatureCollection whose features have
    ``filename``, ``camera``, ``xyz`` and ``opk`` in radians). Positions are world coordinates
    as given (a projected CRS taken as Cartesian); the angles give R by
    :func:`orthority_rotation`. A row's ``camera`` names its interior camera; without it, the
    interior file must hold one camera.

    Returns the cameras (pitch 1, intrinsics in pixels, image size set), keyed by the stem of
    each ``filename`` (the name without directory and extension). FormatError for bad files.
    """
    interior, exterior = Path(interior), Path(exterior)
    cameras = _read_interior(interior)
    out: dict[str, PinholeCamera] = {}
    for ext in _read_exterior(exterior, radians):
        key = Path(ext.filename).stem
        if key in out:
            raise FormatError(exterior, f"image {key!r} appears twice", ext.line)
        if ext.camera is not None:
            if ext.camera not in cameras:
                raise FormatError(
                    exterior,
                    f"camera {ext.camera!r} of image {key!r} is not in {interior} "
                    f"(it has {', '.join(map(repr, cameras))})",
                    ext.line,
                )
            intr = cameras[ext.camera]
        elif len(cameras) == 1:
            intr = next(iter(cameras.values()))
        else:
            raise FormatError(
                exterior,
                f"image {key!r} names no camera, and {interior} holds {len(cameras)}",
                ext.line,
            )
        out[key] = _build(
            exterior,
            lambda _, line=ext.line: line,
            fu=intr.fu,
            fv=intr.fv,
            cu=intr.cu,
            cv=intr.cv,
            center=ext.xyz,
            rotation=orthority_rotation(*ext.opk),
            distortion=intr.distortion,
            width=intr.width,
            height=intr.height,
        )
    return out


def _orthority_camera(
    path: Path, image: str | Path | None, interior: str | Path | None
) -> PinholeCamera:
    """The camera of ``image`` in the Orthority exterior file ``path`` (see :func:`read_camera`)."""
    if interior is None:
        found = sorted(p for p in path.parent.iterdir() if p.suffix.lower() in _INTERIOR_SUFFIXES)
        if len(found) != 1:
            what = "no" if not found else f"{len(found)} ({', '.join(p.name for p in found)})"
            raise InputError(
                f"{path}: Orthority exterior parameters need the interior parameter file: "
                f"{what} .yaml files beside it; give it explicitly"
            )
        interior = found[0]
    cameras = read_orthority_cameras(interior, path)
    if image is None:
        if len(cameras) != 1:
            raise InputError(
                f"{path}: holds {len(cameras)} cameras; name the image to pick one by its stem"
            )
        return next(iter(cameras.values()))
    stem = Path(image).stem
    if stem not in cameras:
        raise InputError(
            f"{path}: no camera for image {stem!r} (it has {', '.join(map(repr, cameras))})"
        )
    return cameras[stem]


def _read_interior(path: Path) -> dict[str, _Interior]:
    """The cameras of an Orthority interior parameter (YAML) file, by camera id."""
    data, where = _yaml_load(path, _text(path, _read_bytes(path, "interior parameter file")))
    if not isinstance(data, dict) or not data:
        raise FormatError(path, "expected a mapping of camera ids to their parameters", 1)
    out: dict[str, _Interior] = {}
    for cam_id, params in data.items():
        line = where[(cam_id,)]
        if not isinstance(params, dict):
            raise FormatError(path, f"camera {cam_id!r}: expected a mapping of parameters", line)
        lines = {key: where.get((cam_id, key), line) for key in params}
        out[cam_id] = _interior(path, cam_id, params, line, lines)
    return out


def _interior(
    path: Path, cam_id: str, params: dict[str, object], line: int, lines: dict[str, int]
) -> _Interior:
    """One camera of an interior parameter file (see :func:`read_orthority_cameras`);
    ``line`` is the camera id's line, ``lines`` each parameter's."""

    def fail(key: str, message: str) -> FormatError:
        return FormatError(path, f"camera {cam_id!r}: {message}", lines.get(key, line))

    def numbers(key: str, sizes: tuple[int, ...], positive: bool = False) -> list[float]:
        value = params[key]
        items = value if isinstance(value, list) else [value]
        if len(items) not in sizes or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in items
        ):
            count = " or ".join(map(str, sizes))
            raise fail(key, f"{key} must be {count} finite number(s), got {value!r}")
        if positive and min(items) <= 0:
            raise fail(key, f"{key} must be positive, got {value!r}")
        return [float(v) for v in items]

    kind = params.get("type")
    if kind not in _ORTHORITY_MODELS:
        known = ", ".join(_ORTHORITY_MODELS)
        raise fail("type", f"camera type {kind!r} is not supported (supported: {known})")
    coefficients = _ORTHORITY_MODELS[str(kind)]
    for key in params:
        if key not in _ORTHORITY_COMMON + coefficients:
            raise fail(key, f"{kind} cameras have no parameter {key!r}")
    for key in ("im_size", "focal_len"):
        if key not in params:
            raise fail(key, f"missing {key}")
    size = numbers("im_size", (2,), positive=True)
    if not all(v == int(v) for v in size):
        raise fail("im_size", f"im_size must be whole pixels, got {params['im_size']!r}")
    width, height = int(size[0]), int(size[1])
    focal = numbers("focal_len", (1, 2), positive=True)  # [f] or [fx, fy]
    if "sensor_size" in params:
        sensor = numbers("sensor_size", (2,), positive=True)
        fu, fv = focal[0] * width / sensor[0], focal[-1] * height / sensor[1]
    else:
        fu, fv = focal[0] * width, focal[-1] * width
    cx, cy = (numbers(key, (1,))[0] if key in params else 0.0 for key in ("cx", "cy"))
    coeffs = {key: numbers(key, (1,))[0] for key in coefficients if key in params}
    tsai = TsaiDistortion.param_names()
    distortion: Distortion
    if kind == "fisheye":
        distortion = FisheyeDistortion(**{key: coeffs.get(key, 0.0) for key in coefficients})
    elif not any(coeffs.values()):
        distortion = NullDistortion()
    elif not any(value for key, value in coeffs.items() if key not in tsai):
        distortion = TsaiDistortion(**{key: coeffs.get(key, 0.0) for key in tsai})
    else:
        distortion = OpenCVDistortion(**coeffs)
    big = max(width, height)
    return _Interior(
        fu=fu,
        fv=fv,
        cu=(width - 1) / 2 + big * cx,
        cv=(height - 1) / 2 + big * cy,
        width=width,
        height=height,
        distortion=distortion,
    )


def _read_exterior(path: Path, radians: bool) -> list[_Exterior]:
    """The images of an Orthority exterior parameter file (CSV, or GeoJSON)."""
    text = _text(path, _read_bytes(path, "exterior parameter file"))
    if path.suffix.lower() == ".csv":
        return _csv_exterior(path, text, radians)
    return _geojson_exterior(path, text)


def _csv_exterior(path: Path, text: str, radians: bool) -> list[_Exterior]:
    """Orthority CSV exterior parameters (see :func:`read_orthority_cameras`)."""
    try:
        dialect: type[csv.Dialect] | csv.Dialect = csv.Sniffer().sniff(
            text[:4096], delimiters=",;: \t"
        )
    except csv.Error:
        dialect = csv.excel
    reader = csv.reader(io.StringIO(text), dialect)
    rows: list[tuple[int, list[str]]] = []
    try:
        for row in reader:
            if any(cell.strip() for cell in row):
                rows.append((reader.line_num, [cell.strip() for cell in row]))
    except csv.Error as exc:
        raise FormatError(path, f"bad CSV: {exc}", reader.line_num) from None
    if not rows:
        raise FormatError(path, "no images in the file", 1)
    if "filename" in rows[0][1]:
        fields, rows = rows[0][1], rows[1:]
    else:
        fields = list(_CSV_LEGACY_FIELDS)
    missing = [f for f in _CSV_LEGACY_FIELDS if f not in fields]
    if missing:
        other = [
            f for f in ("latitude", "longitude", "altitude", "roll", "pitch", "yaw") if f in fields
        ]
        hint = (
            f"; {', '.join(other)} would need Orthority's CRS conversions, not supported"
            if other
            else ""
        )
        raise FormatError(path, f"missing field(s) {', '.join(missing)}{hint}", 1)
    out = []
    for line, row in rows:
        if len(row) != len(fields):
            raise FormatError(path, f"expected {len(fields)} fields, found {len(row)}", line)
        values = dict(zip(fields, row, strict=True))
        numbers = [_number(path, values[key], key, line) for key in _CSV_LEGACY_FIELDS[1:]]
        angles = numbers[3:] if radians else [math.radians(a) for a in numbers[3:]]
        out.append(
            _Exterior(
                filename=values["filename"],
                camera=values.get("camera") or None,
                xyz=(numbers[0], numbers[1], numbers[2]),
                opk=(angles[0], angles[1], angles[2]),
                line=line,
            )
        )
    return out


def _geojson_exterior(path: Path, text: str) -> list[_Exterior]:
    """Orthority GeoJSON exterior parameters (see :func:`read_orthority_cameras`)."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}", exc.lineno) from None
    if not isinstance(obj, dict) or obj.get("type") != "FeatureCollection":
        raise FormatError(path, "expected a GeoJSON FeatureCollection", 1)
    features = obj.get("features")
    if not isinstance(features, list) or not features:
        raise FormatError(path, "the FeatureCollection has no features")
    out = []
    for i, feature in enumerate(features):
        props = feature.get("properties") if isinstance(feature, dict) else None
        if not isinstance(props, dict):
            raise FormatError(path, f"feature {i} has no properties")
        name = props.get("filename")
        camera = props.get("camera")
        if not isinstance(name, str) or not (camera is None or isinstance(camera, str)):
            raise FormatError(path, f"feature {i}: filename (and camera) must be strings")
        vectors = []
        for key in ("xyz", "opk"):
            value = props.get(key)
            if not (
                isinstance(value, list)
                and len(value) == 3
                and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            ):
                raise FormatError(path, f"feature {i} ({name}): {key} must be 3 numbers")
            vectors.append((float(value[0]), float(value[1]), float(value[2])))
        out.append(_Exterior(name, camera, vectors[0], vectors[1], None))
    return out


# The YAML subset of interior parameter files: block mappings and sequences, flow lists and
# mappings, plain and quoted scalars, comments. Anchors, tags, multi-line scalars and
# multi-document streams raise FormatError.

_YAML_INT = re.compile(r"[-+]?\d+")
_YAML_NULL = ("", "~", "null", "Null", "NULL")
_YAML_BOOL = {
    word: word.lower() == "true" for word in ("true", "True", "TRUE", "false", "False", "FALSE")
}
_YamlPath = tuple[str, ...]


def _yaml_load(path: Path, text: str) -> tuple[object, dict[_YamlPath, int]]:
    """Parse ``text``; returns the value and the line of every mapping key, by key path."""
    lines: list[tuple[int, int, str]] = []  # (line number, indent, content)
    for number, raw in enumerate(text.splitlines(), start=1):
        content = _yaml_uncomment(path, raw, number).rstrip()
        stripped = content.lstrip(" ")
        if not stripped or (stripped == "---" and not lines):
            continue
        if stripped == "...":
            break
        if stripped[0] == "\t" or stripped == "---":
            raise FormatError(path, "tabs and multi-document YAML are not supported", number)
        lines.append((number, len(content) - len(stripped), stripped))
    if not lines:
        raise FormatError(path, "empty YAML file", 1)
    where: dict[_YamlPath, int] = {}
    value, pos = _yaml_block(path, lines, 0, (), where)
    if pos < len(lines):
        raise FormatError(path, "unexpected indentation", lines[pos][0])
    return value, where


def _yaml_uncomment(path: Path, raw: str, number: int) -> str:
    """``raw`` without its comment (a ``#`` at the start or after a space, outside quotes;
    a quote opens a quoted string only where a token starts)."""
    quote = ""
    for i, char in enumerate(raw):
        if quote:
            if char == quote:
                quote = ""
        elif char in "'\"" and (i == 0 or raw[i - 1] in " \t[{,:"):
            quote = char
        elif char == "#" and (i == 0 or raw[i - 1] in " \t"):
            return raw[:i]
    if quote:
        raise FormatError(
            path, "unterminated quoted string (multi-line strings unsupported)", number
        )
    return raw


def _yaml_block(
    path: Path,
    lines: list[tuple[int, int, str]],
    pos: int,
    key_path: _YamlPath,
    where: dict[_YamlPath, int],
) -> tuple[object, int]:
    """The block mapping or sequence starting at ``lines[pos]``; returns it and the next pos."""
    indent = lines[pos][1]
    if lines[pos][2] == "-" or lines[pos][2].startswith("- "):
        items = []
        while pos < len(lines) and lines[pos][1] == indent and lines[pos][2].startswith("-"):
            number, _, content = lines[pos]
            if content != "-" and not content.startswith("- "):
                break
            if not content[1:].strip():
                raise FormatError(path, "nested block sequences are not supported", number)
            items.append(_yaml_flow(path, content[1:].strip(), number))
            pos += 1
        return items, pos
    mapping: dict[str, object] = {}
    while pos < len(lines) and lines[pos][1] == indent:
        number, _, content = lines[pos]
        key, rest = _yaml_key(path, content, number)
        if key in mapping:
            raise FormatError(path, f"key {key!r} given twice", number)
        where[(*key_path, key)] = number
        pos += 1
        nested = pos < len(lines) and (
            lines[pos][1] > indent or (lines[pos][1] == indent and lines[pos][2][:2] in ("-", "- "))
        )
        if rest:
            mapping[key] = _yaml_flow(path, rest, number)
            if pos < len(lines) and lines[pos][1] > indent:
                raise FormatError(path, "unexpected indentation", lines[pos][0])
        elif nested:
            mapping[key], pos = _yaml_block(path, lines, pos, (*key_path, key), where)
        else:
            mapping[key] = None
    return mapping, pos


def _yaml_key(path: Path, content: str, number: int) -> tuple[str, str]:
    """Split a ``key: value`` line; the key may be quoted."""
    if content[0] in "'\"":
        key, end = _yaml_quoted(path, content, 0, number)
        if not content[end:].lstrip().startswith(":"):
            raise FormatError(path, f"expected ':' after the key {key!r}", number)
        return key, content[end:].lstrip()[1:].strip()
    match = re.search(r":(\s|$)", content)
    if match is None or content[0] in "?[{&*!|>%@`":
        raise FormatError(path, f"expected 'key: value', found {content!r}", number)
    return content[: match.start()].strip(), content[match.end() :].strip()


def _yaml_quoted(path: Path, text: str, start: int, number: int) -> tuple[str, int]:
    """The quoted string starting at ``text[start]``, and the index after it."""
    quote = text[start]
    end = text.find(quote, start + 1)
    while quote == "'" and end + 1 < len(text) and end >= 0 and text[end + 1] == "'":
        end = text.find(quote, end + 2)  # '' is an escaped quote
    if end < 0:
        raise FormatError(path, "unterminated quoted string", number)
    body = text[start + 1 : end]
    if quote == "'":
        return body.replace("''", "'"), end + 1
    if "\\" in body:
        raise FormatError(path, "escapes in double-quoted strings are not supported", number)
    return body, end + 1


def _yaml_flow(path: Path, text: str, number: int) -> object:
    """A scalar or flow collection filling all of ``text``."""
    value, end = _yaml_flow_value(path, text, 0, number, top=True)
    if text[end:].strip():
        raise FormatError(path, f"unexpected {text[end:].strip()!r}", number)
    return value


def _yaml_flow_value(path: Path, text: str, i: int, number: int, top: bool) -> tuple[object, int]:
    """The value starting at ``text[i]`` (after spaces); returns it and the index after it."""
    while i < len(text) and text[i] == " ":
        i += 1
    if i < len(text) and text[i] in "[{":
        closing = "]" if text[i] == "[" else "}"
        items: list[object] = []
        mapping: dict[str, object] = {}
        i += 1
        while True:
            while i < len(text) and text[i] == " ":
                i += 1
            if i < len(text) and text[i] == closing:
                return (items if closing == "]" else mapping), i + 1
            value, i = _yaml_flow_value(path, text, i, number, top=False)
            if closing == "}":
                if i >= len(text) or text[i] != ":":
                    raise FormatError(path, "expected 'key: value' in a flow mapping", number)
                mapping[str(value)], i = _yaml_flow_value(path, text, i + 1, number, top=False)
            else:
                items.append(value)
            while i < len(text) and text[i] == " ":
                i += 1
            if i < len(text) and text[i] == ",":
                i += 1
            elif i >= len(text) or text[i] != closing:
                raise FormatError(path, f"unterminated flow collection in {text!r}", number)
    if i < len(text) and text[i] in "'\"":
        return _yaml_quoted(path, text, i, number)
    if i < len(text) and text[i] in "&*!|>%@`":
        raise FormatError(path, f"unsupported YAML syntax {text[i:]!r}", number)
    end = (
        len(text)
        if top
        else next(
            (j for j in range(i, len(text)) if text[j] in ",]}" or text[j : j + 2] in (": ", ":")),
            len(text),
        )
    )
    return _yaml_scalar(text[i:end].strip()), end


def _yaml_scalar(token: str) -> object:
    """A plain scalar: null, boolean, integer, float (with or without a dot) or string."""
    if token in _YAML_NULL:
        return None
    if token in _YAML_BOOL:
        return _YAML_BOOL[token]
    if _YAML_INT.fullmatch(token):
        return int(token)
    if _NUMBER.fullmatch(token):
        return float(token)
    return token


# ---------------------------------------------------------------------------------------------
# Writing


def _fmt(*values: float) -> str:
    """Shortest round-trip text of each value (Python repr), space-separated."""
    return " ".join(repr(float(v)) for v in values)


def tsai_text(camera: PinholeCamera) -> str:
    """The camera as ASP/VW VERSION_4 ``.tsai`` text, every number exact."""
    lines = [
        "VERSION_4",
        "PINHOLE",
        f"fu = {_fmt(camera.fu)}",
        f"fv = {_fmt(camera.fv)}",
        f"cu = {_fmt(camera.cu)}",
        f"cv = {_fmt(camera.cv)}",
        f"u_direction = {_fmt(*camera.u_direction)}",
        f"v_direction = {_fmt(*camera.v_direction)}",
        f"w_direction = {_fmt(*camera.w_direction)}",
        f"C = {_fmt(*camera.center)}",
        f"R = {_fmt(*camera.rotation.ravel())}",
        f"pitch = {_fmt(camera.pitch)}",
        camera.distortion.name,
    ]
    lines += [f"{name} = {_fmt(value)}" for name, value in camera.distortion.params().items()]
    return "\n".join(lines) + "\n"


def camera_to_dict(camera: PinholeCamera) -> dict[str, object]:
    """The camera as plain JSON-able data: every field by name, distortion as {"model", params}."""
    return {
        "type": "pinhole",
        "fu": camera.fu,
        "fv": camera.fv,
        "cu": camera.cu,
        "cv": camera.cv,
        "pitch": camera.pitch,
        "center": camera.center.tolist(),
        "rotation": camera.rotation.tolist(),
        "u_direction": camera.u_direction.tolist(),
        "v_direction": camera.v_direction.tolist(),
        "w_direction": camera.w_direction.tolist(),
        "distortion": {"model": camera.distortion.name, **camera.distortion.params()},
        "width": camera.width,
        "height": camera.height,
    }


def _write_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it onto ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write camera file ({exc.strerror})") from exc
    finally:
        tmp.unlink(missing_ok=True)


def write_tsai(camera: PinholeCamera, path: str | Path) -> None:
    """Write ``camera`` as VERSION_4 ``.tsai`` text (the image size is not stored)."""
    _write_atomic(path, tsai_text(camera))


def write_json(camera: PinholeCamera, path: str | Path) -> None:
    """Write ``camera`` in our JSON form, every number exact."""
    _write_atomic(path, json.dumps(camera_to_dict(camera), indent=2) + "\n")
