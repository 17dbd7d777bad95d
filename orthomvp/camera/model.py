"""Frame (pinhole) cameras as defined by Vision Workbench's ``PinholeModel``.

Conventions, those of VW and the Ames Stereo Pipeline (ASP):

- World coordinates are metres. ``rotation`` R is camera-to-world, ``center`` C the camera centre,
  so a world point X has camera coordinates q = R^T (X - C).
- ``u_direction``, ``v_direction``, ``w_direction`` (orthonormal, default the camera x, y, z axes)
  give the image axes: s = (u.q, v.q, w.q); w is the optical axis, s_w the depth.
- ``fu``, ``fv``, ``cu``, ``cv`` and all lens distortion parameters are in units of ``pitch``
  (pixels when ``pitch`` is 1, else millimetres or metres). The undistorted position is
  (fu s_u / s_w + cu, fv s_v / s_w + cv); lens distortion (:mod:`orthomvp.camera.distortion`)
  maps it, in these same units, to the distorted position, which divided by ``pitch`` is the
  pixel.
- Pixels are (u, v) = (column, row); integer values are pixel centres, as in VW.

Reading and writing camera files is :mod:`orthomvp.camera`'s (``read_camera``) and its
``formats`` modules'.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np

from orthomvp.camera.distortion import Distortion, NullDistortion
from orthomvp.errors import InputError
from orthomvp.geometry.vectors import row_norms

ORTHONORMAL_TOLERANCE = 1e-6
"""Largest |R^T R - I| entry accepted for a rotation (and for the u, v, w frame)."""

_ROUND_TRIP_TOLERANCE = 1e-8  # focal-normalised units, for the project() distortion check


class FieldError(InputError):
    """An invalid camera parameter; ``field`` names it so that readers can point at its line."""

    def __init__(self, field_name: str, message: str) -> None:
        self.field = field_name
        super().__init__(message)

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        """Pickle by the constructor's arguments (see :class:`orthomvp.errors.FormatError`)."""
        return type(self), (self.field, str(self))


def _orthonormality_error(m: np.ndarray) -> float:
    """Largest entry of |M^T M - I|."""
    return float(np.abs(m.T @ m - np.eye(3)).max())


def _finite(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a read-only float64 array of ``shape`` with finite entries."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FieldError(name, f"{name} must be numbers, got {value!r}") from None
    if arr.shape != shape:
        raise FieldError(name, f"{name} must have shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise FieldError(name, f"{name} must be finite, got {value!r}")
    arr.setflags(write=False)
    return arr


def _points(value: object, what: str, n: int) -> np.ndarray:
    """``value`` as a float64 array; InputError when it is not numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"{what} needs an array of shape (..., {n}), got {type(value).__name__}"
        ) from None


def image_size(name: str, value: object) -> int | None:
    """An image ``width`` or ``height`` (``name``): a positive integer, or None; FieldError
    otherwise."""
    if value is not None and (
        isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0
    ):
        raise FieldError(name, f"{name} must be a positive integer or None, got {value!r}")
    return None if value is None else int(value)


def check_crop(c0: object, r0: object, width: object, height: object) -> None:
    """InputError unless a crop window's first pixel (``c0``, ``r0``) and size are integers."""
    for name, value in (("c0", c0), ("r0", r0), ("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise InputError(f"crop {name} must be an integer number of pixels, got {value!r}")


def _default_axis(index: int) -> Callable[[], np.ndarray]:
    """A factory of the unit vector along axis ``index`` (VW's default u, v, w)."""
    return lambda: np.eye(3)[index]


@runtime_checkable
class Camera(Protocol):
    """What every camera model offers; visibility, orthophotos and the engine use only this.

    World points are metres in the world frame the camera was read for; pixels are (u, v) =
    (column, row) with integer values at pixel centres (readers convert other conventions,
    e.g. CSM's (line, sample) with the first pixel's centre at (0.5, 0.5), once). A camera
    need not have one centre: a line scanner images each line from the sensor position at
    that line's time, an RPC camera's rays are lines between two heights.
    """

    width: int | None
    height: int | None

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``uv`` (..., 2) of world points ``xyz`` (..., 3), NaN where the point is not
        imaged (behind the sensor, outside the time range, beyond the model's domain), and
        ``depth`` (...), metres, > 0 in front of the sensor."""
        ...

    def ray(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``origins`` (..., 3), world metres, and unit ``directions`` (..., 3) into the scene
        of the rays through pixels ``uv`` (..., 2); NaN where the model has no ray. Origins
        lie above all terrain the camera sees (the sensor, or a point high on the ray)."""
        ...

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The ``origins`` of :meth:`ray` alone (..., 3), often much cheaper."""
        ...

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Ground sample distance (...), metres per pixel, at world points ``xyz`` (..., 3) on
        a surface perpendicular to the line of sight (divide by the cosine of the emission
        angle for a tilted surface)."""
        ...

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixels ``uv`` (..., 2) lie on the image (within half a pixel of the
        outermost pixel centres); NaN is outside."""
        ...

    def with_image_size(self, width: int | None, height: int | None) -> Camera:
        """A copy with the image size (pixels) set."""
        ...

    def crop(self, c0: int, r0: int, width: int, height: int) -> Camera:
        """The camera of the ``width`` x ``height`` pixel window whose first pixel is pixel
        (``c0``, ``r0``) here: ``crop.project(x)`` is ``project(x) - (c0, r0)``."""
        ...


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
                raise FieldError(name, f"{name} must be positive, got {value!r}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "center", _finite("center", self.center, (3,)))
        rotation = _finite("rotation", self.rotation, (3, 3))
        error = _orthonormality_error(rotation)
        if error > ORTHONORMAL_TOLERANCE:
            raise FieldError(
                "rotation", f"R is not a rotation: |R^T R - I| reaches {error:.2g} (limit 1e-6)"
            )
        if np.linalg.det(rotation) < 0:
            raise FieldError("rotation", "R is a reflection (determinant -1), not a rotation")
        object.__setattr__(self, "rotation", rotation)
        for name in ("u_direction", "v_direction", "w_direction"):
            object.__setattr__(self, name, _finite(name, getattr(self, name), (3,)))
        error = _orthonormality_error(self._frame.T)
        if error > ORTHONORMAL_TOLERANCE:
            raise FieldError(
                "u_direction",
                f"u, v, w directions are not orthonormal: error {error:.2g} (limit 1e-6)",
            )
        if not isinstance(self.distortion, Distortion):
            raise FieldError("distortion", f"not a lens distortion model: {self.distortion!r}")
        for name in ("width", "height"):
            object.__setattr__(self, name, image_size(name, getattr(self, name)))

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

    def crop(self, c0: int, r0: int, width: int, height: int) -> PinholeCamera:
        """The camera of the ``width`` x ``height`` pixel window of this camera's image whose
        first pixel is pixel (``c0``, ``r0``) here: the principal point moves by the offset,
        nothing else changes (every lens distortion model is relative to the principal
        point), so ``crop.project(x)`` is ``project(x) - (c0, r0)`` and ``crop.ray(uv)`` is
        ``ray(uv + (c0, r0))``, to rounding. The offset may be negative or reach beyond the
        image (a window partly off the image)."""
        check_crop(c0, r0, width, height)
        return replace(
            self,
            cu=self.cu - int(c0) * self.pitch,
            cv=self.cv - int(r0) * self.pitch,
            width=int(width),
            height=int(height),
        )

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixel positions ``uv`` (..., 2) lie on the image: within half a pixel of the
        outermost pixel centres, ``-0.5 <= u <= width - 0.5`` and likewise for v. NaN is
        outside. Needs the image size."""
        if self.width is None or self.height is None:
            raise InputError("the camera needs its image size (width, height)")
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``xyz`` (..., 3), metres, into the image (VW ``point_to_pixel``).

        Returns ``uv`` (..., 2), pixels (u = column, v = row, integer values at pixel centres),
        and ``depth`` (...), metres along the optical axis, > 0 in front of the camera. Points
        not in front, and (as VW's point_to_pixel check) points whose distorted pixel does not
        map back to them through :meth:`ray`, e.g. beyond a fold of the distortion, get NaN uv.
        """
        xyz = _points(xyz, "project", 3)
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
        uv = _points(uv, "ray", 2)
        if uv.shape[-1:] != (2,):
            raise InputError(f"ray needs pixels of shape (..., 2), got {uv.shape}")
        undistorted = self.distortion.undistort(uv * self.pitch, self._focal, self._offset)
        normalised = (undistorted - self._offset) / self._focal
        s = np.concatenate([normalised, np.ones_like(normalised[..., :1])], axis=-1)
        directions = s @ np.linalg.inv(self.world_to_image_axes).T
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        origins = np.broadcast_to(self.center, directions.shape).copy()
        return origins, directions

    def origins(self, uv: np.ndarray) -> np.ndarray:
        """The camera centre for every pixel ``uv`` (..., 2): (..., 3), world metres."""
        uv = _points(uv, "origins", 2)
        return np.broadcast_to(self.center, uv.shape[:-1] + (3,)).copy()

    def gsd(self, xyz: np.ndarray) -> np.ndarray:
        """Metres per pixel at world points ``xyz`` (..., 3) on a surface perpendicular to the
        line of sight: range / focal length in pixels (the mean of fu and fv; lens distortion
        left out)."""
        xyz = _points(xyz, "gsd", 3)
        focal = 0.5 * (self.fu + self.fv) / self.pitch
        return row_norms(xyz - self.center) / focal


def as_image(image: object, name: str = "image") -> np.ndarray:
    """``image`` as a float32 (bands, rows, cols) array: a (rows, cols) array is one band;
    integer images keep their values (a uint8 image becomes float32 0 to 255). Refused with
    InputError: anything that is not an array of real numbers (booleans, complex numbers,
    strings), arrays of other dimensions, and a (rows, cols, bands) image such as PIL and
    OpenCV give (move its last axis first: ``np.moveaxis(image, -1, 0)``)."""
    if not isinstance(image, np.ndarray):
        raise InputError(
            f"{name}: expected an image array (bands, rows, cols), got {type(image).__name__}"
        )
    if not (np.issubdtype(image.dtype, np.floating) or np.issubdtype(image.dtype, np.integer)):
        raise InputError(f"{name}: image pixels must be real numbers, got {image.dtype}")
    img = image[None] if image.ndim == 2 else image
    if img.ndim != 3 or img.shape[0] < 1 or min(img.shape[1:]) < 2:
        raise InputError(
            f"{name}: expected an image of shape (bands, rows, cols) or (rows, cols), got "
            f"{image.shape}"
        )
    if img.shape[2] <= 4 < img.shape[0]:
        raise InputError(
            f"{name}: the image's shape {image.shape} looks like (rows, cols, bands); orthomvp "
            "takes (bands, rows, cols): pass np.moveaxis(image, -1, 0)"
        )
    return img if img.dtype == np.float32 else img.astype(np.float32)


def check_image(image: np.ndarray, camera: Camera, name: str = "image") -> Camera:
    """Validate an image (as :func:`as_image` takes it) against ``camera`` and return the camera
    with the image's size."""
    img = as_image(image, name)
    if not isinstance(camera, Camera):
        raise InputError(
            f"{name}: its camera must be a camera model (orthomvp.camera.read_camera), got "
            f"{type(camera).__name__}"
        )
    rows, cols = img.shape[1:]
    if camera.width is not None and (camera.width, camera.height) != (cols, rows):
        raise InputError(
            f"{name} is {cols} x {rows} px but its camera says {camera.width} x {camera.height}"
        )
    return camera.with_image_size(cols, rows)


def require_pinhole(camera: Camera, name: str, needs: str) -> PinholeCamera:
    """``camera`` when it is a frame (pinhole) camera; else InputError naming ``name`` and what
    ``needs`` one."""
    if not isinstance(camera, PinholeCamera):
        raise InputError(
            f"{name}: {needs} needs frame (pinhole) cameras; this one is a {type(camera).__name__}"
        )
    return camera


def in_world(camera: Camera, terrain: object) -> Camera:
    """``camera`` in the world frame of ``terrain`` (a :class:`~orthomvp.geometry.terrain.Terrain`):
    models defined on geodetic coordinates (RPC) offer ``bind(terrain)`` and are bound to it;
    the others live in one frame already and come back unchanged."""
    bind = getattr(camera, "bind", None)
    return bind(terrain) if callable(bind) else camera


def sensor_positions(camera: Camera, lattice: int = 3) -> np.ndarray:
    """Where ``camera`` images from: the ray origins (k, 3), world metres, of a ``lattice`` x
    ``lattice`` grid of pixels spanning the image (its centre alone without an image size),
    NaN rows dropped. One point for a frame camera; along the track for a line scanner."""
    if camera.width is None or camera.height is None:
        uv = np.zeros((1, 2))
    else:
        u, v = np.meshgrid(
            np.linspace(0, camera.width - 1, lattice), np.linspace(0, camera.height - 1, lattice)
        )
        uv = np.column_stack([u.ravel(), v.ravel()])
    points = camera.origins(uv)
    # distinct rows, sorted (np.unique's axis=0 path imports numpy.ma: 10 ms of a run)
    distinct = sorted({tuple(p) for p in points[np.isfinite(points).all(axis=1)].tolist()})
    return np.array(distinct, float).reshape(-1, 3)


def camera_centres(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """The :func:`sensor_positions` of all ``cameras`` (n, 3), and the index of the camera
    each comes from (n,): a line scanner gives several, so that messages count cameras, not
    positions."""
    each = [sensor_positions(camera) for camera in cameras]
    centres = np.concatenate(each) if each else np.empty((0, 3))
    return centres, np.repeat(np.arange(len(each)), [len(e) for e in each])
