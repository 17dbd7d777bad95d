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

File formats: ASP/VW ``.tsai`` text (VERSION_4, VERSION_3 and the older unversioned form), VW's
binary ``.pinhole`` protobuf (``TsaiFile``, decoded here without a protobuf library) and a plain
JSON form of our own. Writers replace the destination atomically.
"""

from __future__ import annotations

import json
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


_DISTORTIONS: dict[str, type[Distortion]] = {
    cls.name.lower(): cls for cls in (NullDistortion, TsaiDistortion, BrownConradyDistortion)
}


def distortion_class(name: str) -> type[Distortion]:
    """The distortion model called ``name`` (case-insensitive); InputError if unsupported."""
    try:
        return _DISTORTIONS[name.strip().lower()]
    except KeyError:
        known = ", ".join(cls.name for cls in _DISTORTIONS.values())
        raise InputError(
            f"unsupported lens distortion model {name!r} (supported: {known})"
        ) from None


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


def read_camera(path: str | Path) -> PinholeCamera:
    """Read a camera from ``.tsai`` text, binary ``.pinhole`` or our ``.json``.

    Other extensions are recognised by their content. A missing or unreadable file raises
    InputError; a file that breaks its format raises FormatError naming it (and the line, for
    text formats).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: camera file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, not a camera file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read camera file ({exc.strerror})") from exc
    suffix = path.suffix.lower()
    if suffix == ".tsai":
        return _parse_tsai(path, _text(path, data))
    if suffix == ".pinhole":
        return _parse_pinhole(path, data)
    if suffix == ".json":
        return _parse_json(path, _text(path, data))
    return _sniff(path, data)


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
        name_line, model = lines.take("the lens distortion name (NULL, TSAI, BrownConrady)")
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
_PB_DISTORTION_COUNTS = {"null": (0,), "tsai": (4, 5), "brownconrady": (8,)}


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
    counts = _PB_DISTORTION_COUNTS.get(distortion_name.lower())
    if counts is not None and len(dist_values) not in counts:
        raise FormatError(
            path,
            f"{distortion_name} distortion needs {' or '.join(map(str, counts))} values, "
            f"got {len(dist_values)}",
        )
    cls = _DISTORTIONS.get(distortion_name.lower())
    names = cls.param_names() if cls is not None else ()
    distortion = _distortion(
        path, distortion_name, dict(zip(names, dist_values, strict=False)), None
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
