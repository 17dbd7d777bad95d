"""Frame (pinhole) cameras as defined by Vision Workbench's ``PinholeModel``, and reading them.

Conventions, those of VW and the Ames Stereo Pipeline (ASP):

- World coordinates are metres. ``rotation`` R is camera-to-world, ``center`` C the camera centre,
  so a world point X has camera coordinates q = R^T (X - C).
- ``u_direction``, ``v_direction``, ``w_direction`` (orthonormal, default the camera x, y, z axes)
  give the image axes: s = (u.q, v.q, w.q); w is the optical axis, s_w the depth.
- ``fu``, ``fv``, ``cu``, ``cv`` and all lens distortion parameters are in units of ``pitch``
  (pixels when ``pitch`` is 1, else millimetres or metres). The undistorted position is
  (fu s_u / s_w + cu, fv s_v / s_w + cv); lens distortion (:mod:`orthomvp.distortion`) maps it,
  in these same units, to the distorted position, which divided by ``pitch`` is the pixel.
- Pixels are (u, v) = (column, row); integer values are pixel centres, as in VW.

:func:`read_camera` reads any supported camera file: ASP/VW ``.tsai`` text and binary
``.pinhole`` (:mod:`orthomvp.tsai`), a plain JSON form of our own (here), and Orthority's
interior and exterior parameter files (:mod:`orthomvp.orthority`). Writers replace the
destination atomically. The format modules import this one, so it imports them lazily.
"""

from __future__ import annotations

import json
import os
import re
import secrets
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from orthomvp.distortion import Distortion, NullDistortion, distortion_class
from orthomvp.errors import FormatError, InputError

ORTHONORMAL_TOLERANCE = 1e-6
"""Largest |R^T R - I| entry accepted for a rotation (and for the u, v, w frame)."""

_ROUND_TRIP_TOLERANCE = 1e-8  # focal-normalised units, for the project() distortion check


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
    in degrees (see :func:`~orthomvp.orthority.read_orthority_cameras`). An interior ``.yaml``
    alone holds no camera pose and raises InputError.

    A missing or unreadable file raises InputError; a file that breaks its format raises
    FormatError naming it (and the line, for text formats).
    """
    from orthomvp import orthority, tsai

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in orthority.INTERIOR_SUFFIXES:
        raise InputError(
            f"{path}: Orthority interior parameters hold no camera position; give the exterior "
            "parameter file (.csv or .geojson) as the camera, with this file beside it"
        )
    data = _read_bytes(path, "camera file")
    if suffix in orthority.EXTERIOR_SUFFIXES or (
        suffix == ".json" and orthority.is_geojson(_text(path, data))
    ):
        return orthority.orthority_camera(path, image, interior)
    if suffix == ".tsai":
        return tsai.parse_tsai(path, _text(path, data))
    if suffix == ".pinhole":
        return tsai.parse_pinhole(path, data)
    if suffix == ".json":
        return _parse_json(path, _text(path, data))
    return _sniff(path, data)


def _sniff(path: Path, data: bytes) -> PinholeCamera:
    """Recognise a camera file by its content."""
    from orthomvp import tsai

    try:
        head = data.decode("utf-8-sig").lstrip()
    except UnicodeDecodeError:
        head = ""
    if head.startswith("{"):
        return _parse_json(path, _text(path, data))
    if re.match(r"VERSION_|fu\s*=", head):
        return tsai.parse_tsai(path, _text(path, data))
    try:
        decoded = tsai.decode_protobuf(data)
    except ValueError as exc:
        raise FormatError(
            path, f"not a camera file: not .tsai text, not JSON, not a .pinhole protobuf ({exc})"
        ) from exc
    return tsai.camera_from_protobuf(path, decoded)


# Helpers of the readers here and in orthomvp.tsai and orthomvp.orthority


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
    """``data`` decoded as UTF-8 (a byte-order mark dropped); FormatError if it is not text."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not a text file (invalid UTF-8 at byte {exc.start})") from None


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


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def _number(path: Path, token: str, key: str, line: int) -> float:
    """The number ``token`` given for ``key`` at ``line``; FormatError if it is not one."""
    if not _NUMBER.fullmatch(token):
        raise FormatError(path, f"{token!r} after '{key} =' is not a number", line)
    return float(token)


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


def write_json(camera: PinholeCamera, path: str | Path) -> None:
    """Write ``camera`` in our JSON form, every number exact."""
    _write_atomic(path, json.dumps(camera_to_dict(camera), indent=2) + "\n")


def check_image(image: np.ndarray, camera: PinholeCamera, name: str = "image") -> PinholeCamera:
    """Validate a (bands, rows, cols) image and return the camera with the image's size."""
    if image.ndim != 3 or image.shape[0] < 1 or min(image.shape[1:]) < 2:
        raise InputError(
            f"{name}: expected an image of shape (bands, rows, cols), got {image.shape}"
        )
    rows, cols = image.shape[1:]
    if camera.width is not None and (camera.width, camera.height) != (cols, rows):
        raise InputError(
            f"{name} is {cols} x {rows} px but its camera says {camera.width} x {camera.height}"
        )
    return camera.with_image_size(cols, rows)


def load_view(image_path: str | Path, camera_path: str | Path) -> tuple[np.ndarray, PinholeCamera]:
    """Read an image (float32 (bands, rows, cols), see :func:`orthomvp.raster.read_image`) and
    its camera (:func:`read_camera`, the image's name picking its row in multi-camera files),
    checked against each other; the camera carries the image's size."""
    from orthomvp.raster import read_image

    image = read_image(image_path)
    return image, check_image(image, read_camera(camera_path, image_path), str(image_path))
