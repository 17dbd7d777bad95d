"""What usgscsm's sensor models share: the focal plane (detector geometry, lens distortion),
the reference ellipsoid, the interpolated trajectory of a scanning sensor, and the pixel
convention.

usgscsm's projection is central and blind to the side: its rays are lines, and its
``imageToRemoteImagingLocus`` direction (camera +z) points into the scene for some ISDs and
away from it for others (its own orbital test ISDs). Each model therefore fixes
``look_sign`` (+1 or -1) once, so that sign x locus direction at the image centre points
towards the body's centre; rays, depths and image to ground use that side only.

Units: focal-plane coordinates and the focal length in millimetres, world (body-fixed)
coordinates in metres, times in seconds relative to the ISD's ``center_ephemeris_time``.
CSM image coordinates (line, sample) put the first pixel's centre at (0.5, 0.5); orthomvp's
pixels (u, v) = (column, row) put it at (0, 0): u = sample - 0.5, v = line - 0.5
(:func:`csm_to_uv`, :func:`uv_to_csm`, the one place where the conventions meet).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import ClassVar

import numpy as np

from orthomvp.camera.csm.distortion import CsmDistortion
from orthomvp.camera.csm.ephemeris import lagrange_polynomials, polynomial_values, xyzw_matrix
from orthomvp.camera.model import check_crop
from orthomvp.errors import InputError

EDGE = 1e-6
"""Lines by which a projected point may pass the first or last line's edge (rounding) and
still count as imaged."""
CHUNK = 1 << 16
"""Points per block in vectorised projections (bounds the memory of the interpolation)."""


def csm_to_uv(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """orthomvp pixels (..., 2) (u = column, v = row, integer pixel centres) of CSM image
    coordinates (line, sample) (first pixel centre at (0.5, 0.5))."""
    return np.stack([np.asarray(sample) - 0.5, np.asarray(line) - 0.5], axis=-1)


def uv_to_csm(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSM (line, sample) of orthomvp pixels ``uv`` (..., 2): the inverse of :func:`csm_to_uv`."""
    uv = np.asarray(uv, dtype=np.float64)
    return uv[..., 1] + 0.5, uv[..., 0] + 0.5


def as_points(value: object, what: str, n: int) -> np.ndarray:
    """``value`` as a float64 array of shape (..., n); InputError otherwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what} needs an array of shape (..., {n})") from None
    if arr.shape[-1:] != (n,):
        raise InputError(f"{what} needs an array of shape (..., {n}), got {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class FocalPlane:
    """usgscsm's detector geometry: ``focal_length`` (mm; negative for a camera that looks along
    its -z axis, as ALE writes ISIS's Apollo Metric camera), the focal-plane-to-detector affine
    transforms ``i_trans_s``/``i_trans_l`` (pixels from mm: detector sample/line =
    t[0] + t[1] x + t[2] y), the detector origin (``sample_origin``, ``line_origin``, the ISD's
    ``detector_center``), pixel summing, the first detector sample/line read out
    (``starting_sample``, ``starting_line``) and the lens ``distortion``."""

    focal_length: float
    i_trans_s: np.ndarray
    i_trans_l: np.ndarray
    sample_origin: float
    line_origin: float
    sample_summing: float
    line_summing: float
    starting_sample: float
    starting_line: float
    distortion: CsmDistortion

    def __post_init__(self) -> None:
        for name in ("i_trans_s", "i_trans_l"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (3,) or not np.isfinite(value).all():
                raise InputError(f"{name} must be 3 finite numbers")
            object.__setattr__(self, name, value)
        if abs(self.i_trans_l[1] * self.i_trans_s[2] - self.i_trans_l[2] * self.i_trans_s[1]) == 0:
            raise InputError("the focal-plane-to-pixel transforms are singular")
        if not (np.isfinite(self.focal_length) and self.focal_length != 0):
            raise InputError(f"focal_length must be non-zero, got {self.focal_length!r}")
        for name in ("sample_summing", "line_summing"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive, got {getattr(self, name)!r}")

    def distorted_focal(
        self, line: np.ndarray, sample: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distorted focal-plane (x, y), mm, of image (line, sample) (usgscsm
        ``computeDistortedFocalPlaneCoordinates``; line is within the detector)."""
        det_sample = sample * self.sample_summing + self.starting_sample
        det_line = line * self.line_summing + self.starting_line
        (l0, l1, l2), (s0, s1, s2) = self.i_trans_l, self.i_trans_s
        t1 = det_line - self.line_origin - l0
        t2 = det_sample - self.sample_origin - s0
        det = l1 * s2 - l2 * s1
        return (s2 * t1 - l2 * t2) / det, (-s1 * t1 + l1 * t2) / det

    def detector_line(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Image line offset of distorted focal-plane (x, y) (usgscsm's detector line,
        origin and starting line applied, divided by the summing)."""
        l0, l1, l2 = self.i_trans_l
        return (l0 + l1 * dx + l2 * dy + self.line_origin - self.starting_line) / self.line_summing

    def detector_sample(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Image sample of distorted focal-plane (x, y) (usgscsm ``computePixel``)."""
        s0, s1, s2 = self.i_trans_s
        return (
            s0 + s1 * dx + s2 * dy + self.sample_origin - self.starting_sample
        ) / self.sample_summing

    def camera_look(self, line: np.ndarray, sample: np.ndarray) -> np.ndarray:
        """Unit look vectors (..., 3) in the camera frame of image (line, sample), line within
        the detector: (x, y, f) of the undistorted focal-plane point, normalised."""
        dx, dy = self.distorted_focal(line, sample)
        ux, uy = self.distortion.undistort(dx, dy, self.focal_length)
        look = np.stack([ux, uy, np.full_like(ux, self.focal_length)], axis=-1)
        return look / np.linalg.norm(look, axis=-1, keepdims=True)

    def view(self, camera_xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted focal-plane (x, y), mm, of camera-frame vectors (..., 3) (usgscsm
        ``computeDetectorView`` then ``applyDistortion``: a central projection, blind to the
        side of the camera; callers check the depth)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = self.focal_length / camera_xyz[..., 2]
        fx, fy = camera_xyz[..., 0] * scale, camera_xyz[..., 1] * scale
        return self.distortion.distort(fx, fy, self.focal_length)

    @property
    def axis_sign(self) -> float:
        """+1 if the camera looks along its +z axis (positive focal length), else -1: a
        camera-frame point's depth along the view is ``look_sign * axis_sign * z``."""
        return 1.0 if self.focal_length > 0 else -1.0

    @property
    def focal_pixels(self) -> float:
        """The focal length in image pixels (mean over the two detector axes)."""
        scale_s = np.hypot(self.i_trans_s[1], self.i_trans_s[2]) / self.sample_summing
        scale_l = np.hypot(self.i_trans_l[1], self.i_trans_l[2]) / self.line_summing
        return float(abs(self.focal_length) * 0.5 * (scale_s + scale_l))


@dataclass(frozen=True)
class Ellipsoid:
    """The body's reference ellipsoid, ``semi_major`` and ``semi_minor`` radii in metres; a
    height h inflates both radii by h, as usgscsm does."""

    semi_major: float
    semi_minor: float

    def __post_init__(self) -> None:
        if not (self.semi_major > 0 and self.semi_minor > 0):
            raise InputError("the ellipsoid radii must be positive")

    def intersect(
        self, origins: np.ndarray, directions: np.ndarray, height: np.ndarray | float
    ) -> np.ndarray:
        """The first intersection (..., 3) in front of ``origins`` of rays along ``directions``
        with the ellipsoid inflated by ``height`` (metres); NaN where the ray misses it or
        starts inside it."""
        height = np.asarray(height, dtype=np.float64)
        ap, bp = self.semi_major + height, self.semi_minor + height
        k = np.where(np.arange(3) == 2, (ap * ap / (bp * bp))[..., None], 1.0)
        a = np.sum(k * directions * directions, axis=-1)
        b = 2.0 * np.sum(k * directions * origins, axis=-1)
        c = np.sum(k * origins * origins, axis=-1) - ap * ap
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore"):
            scale = (-b - np.sqrt(disc)) / (2.0 * a)
        ok = (disc >= 0) & (scale > 0) & (c > 0)
        return np.where(ok[..., None], origins + scale[..., None] * directions, np.nan)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A scanning sensor's ephemeris as usgscsm holds it: ``positions`` and ``velocities``
    (n, 3), body-fixed metres and m/s, at uniform times t0_ephem + i dt_ephem; pointing
    ``quaternions`` (m, 4), scalar-last (x, y, z, w), camera-to-body, at t0_quat + j dt_quat;
    Lagrange interpolation of order ``order`` (8, or 4 for usgscsm's platform flag 0)."""

    positions: np.ndarray
    velocities: np.ndarray
    t0_ephem: float
    dt_ephem: float
    quaternions: np.ndarray
    t0_quat: float
    dt_quat: float
    order: int = 8

    def __post_init__(self) -> None:
        for name, cols in (("positions", 3), ("velocities", 3), ("quaternions", 4)):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.ndim != 2 or value.shape[1] != cols or len(value) < 2:
                raise InputError(f"{name} must be at least 2 rows of {cols} numbers")
            if not np.isfinite(value).all():
                raise InputError(f"{name} must be finite")
            object.__setattr__(self, name, value)
        if len(self.velocities) != len(self.positions):
            raise InputError("positions and velocities must have the same length")
        if not (self.dt_ephem > 0 and self.dt_quat > 0):
            raise InputError("ephemeris time steps must be positive")

    @property
    def time_range(self) -> tuple[float, float]:
        """The times (s) both the positions and the pointing cover."""
        end_e = self.t0_ephem + (len(self.positions) - 1) * self.dt_ephem
        end_q = self.t0_quat + (len(self.quaternions) - 1) * self.dt_quat
        return max(self.t0_ephem, self.t0_quat), min(end_e, end_q)

    @cached_property
    def _position_poly(self) -> np.ndarray:
        return lagrange_polynomials(self.positions, self.order)

    @cached_property
    def _velocity_poly(self) -> np.ndarray:
        return lagrange_polynomials(self.velocities, self.order)

    @cached_property
    def _quaternion_poly(self) -> np.ndarray:
        return lagrange_polynomials(self.quaternions, self.order)

    def position(self, t: np.ndarray) -> np.ndarray:
        """Sensor positions (M, 3), metres, at times ``t`` (M,)."""
        return polynomial_values(self._position_poly, t, self.t0_ephem, self.dt_ephem)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """Sensor velocities (M, 3), m/s, at times ``t`` (M,)."""
        return polynomial_values(self._velocity_poly, t, self.t0_ephem, self.dt_ephem)

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """Camera-to-body rotation matrices (M, 3, 3) at times ``t`` (M,)."""
        q = polynomial_values(self._quaternion_poly, t, self.t0_quat, self.dt_quat)
        return xyzw_matrix(q)


@dataclass(frozen=True, eq=False)
class CsmImage:
    """The image part every CSM model shares: the full image's ``lines`` and ``samples``, and
    the window this camera describes (``col0``, ``row0``: its first pixel in the full image;
    ``width``, ``height``: its size, default the full image)."""

    lines: int
    samples: int
    col0: int = field(default=0, kw_only=True)
    row0: int = field(default=0, kw_only=True)
    width: int | None = field(default=None, kw_only=True)
    height: int | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        for name in ("lines", "samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise InputError(f"image {name} must be a positive integer, got {value!r}")
        if self.width is None and self.height is None and (self.col0, self.row0) == (0, 0):
            object.__setattr__(self, "width", int(self.samples))
            object.__setattr__(self, "height", int(self.lines))

    @cached_property
    def look_sign(self) -> int:
        """+1 if usgscsm's locus direction at the image centre points into the scene (towards
        the body centre), -1 if away (see the module docstring)."""
        origin, direction = self.csm_locus(np.array(self.lines / 2.0), np.array(self.samples / 2.0))
        return self._look_sign(origin, direction)

    @staticmethod
    def _look_sign(origin: np.ndarray, direction: np.ndarray) -> int:
        """+1 if ``direction`` from ``origin`` (3,) heads towards the body centre, else -1."""
        return 1 if float(np.dot(direction, -origin)) >= 0 else -1

    def csm_locus(self, line: np.ndarray, sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor positions and unit look directions (..., 3) of CSM (line, sample): each
        model's own."""
        raise NotImplementedError

    def csm_image_to_ground(
        self, line: np.ndarray, sample: np.ndarray, height: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Ground points (..., 3), metres, of CSM (line, sample) on the ellipsoid inflated by
        ``height`` metres (usgscsm ``imageToGround``); NaN where the ray misses it."""
        origin, direction = self.csm_locus(line, sample)
        return self.ellipsoid.intersect(
            origin, self.look_sign * direction, np.broadcast_to(height, origin.shape[:-1])
        )

    def _in_chunks(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(line, sample, depth) of ground points (..., 3) by the model's
        ``_ground_to_image_block`` on chunks of :data:`CHUNK` points."""
        xyz = as_points(xyz, "ground to image", 3)
        flat = xyz.reshape(-1, 3)
        out = np.empty((len(flat), 3))
        for start in range(0, len(flat), CHUNK):
            out[start : start + CHUNK] = self._ground_to_image_block(flat[start : start + CHUNK])
        out = out.reshape(xyz.shape[:-1] + (3,))
        return out[..., 0], out[..., 1], out[..., 2]

    def _ground_to_image_block(self, xyz: np.ndarray) -> np.ndarray:
        """(line, sample, depth) (n, 3) of ground points (n, 3): each scanning model's own."""
        raise NotImplementedError

    def _to_uv(self, line: np.ndarray, sample: np.ndarray) -> np.ndarray:
        return csm_to_uv(line, sample) - np.array([self.col0, self.row0], dtype=np.float64)

    def _to_csm(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        line, sample = uv_to_csm(uv)
        return line + self.row0, sample + self.col0

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixels ``uv`` (..., 2) lie on the image (window): within half a pixel of the
        outermost pixel centres; NaN is outside."""
        if self.width is None or self.height is None:
            raise InputError("the camera needs its image size (width, height)")
        uv = np.asarray(uv, dtype=np.float64)
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)

    _WINDOW_FREE: ClassVar[tuple[str, ...]] = ()
    """Cached properties that depend on the model only, not on the window: copies made by
    :meth:`with_image_size` and :meth:`crop` (one per engine tile) keep them."""

    def _window(self, **changes: int | None) -> CsmImage:
        copy = replace(self, **changes)
        for name in self._WINDOW_FREE:
            if name in self.__dict__:
                copy.__dict__[name] = self.__dict__[name]
        return copy

    def with_image_size(self, width: int | None, height: int | None) -> CsmImage:
        """A copy with the image (window) size set, pixels."""
        return self._window(width=width, height=height)

    def crop(self, c0: int, r0: int, width: int, height: int) -> CsmImage:
        """The camera of the ``width`` x ``height`` window whose first pixel is (``c0``,
        ``r0``) here: ``crop.project(x)`` is ``project(x) - (c0, r0)``."""
        check_crop(c0, r0, width, height)
        return self._window(
            col0=self.col0 + int(c0),
            row0=self.row0 + int(r0),
            width=int(width),
            height=int(height),
        )
