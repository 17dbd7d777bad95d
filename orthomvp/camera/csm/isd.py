"""Reading USGS CSM ISDs (the Image Support Data JSON that ALE writes and usgscsm reads) into
camera models, and writing a line-scan ISD.

The reader does what usgscsm's ``constructStateFromIsd`` does with ALE: instrument positions
resampled to at least 25 uniform nodes (ALE's cubic Hermite on positions and velocities),
rotated from J2000 into the body-fixed frame by ``body_rotation`` (SLERP, angular velocities
for the velocity), pointing quaternions of sensor-to-body rotations at uniform times
(``body_rotation`` x ``instrument_pointing``^-1). ISD quaternions are scalar-first (w, x, y, z)
J2000-to-frame rotations; lengths in ``unit`` (km by default) become metres.

Every defect (a missing key, a wrong type or length, an unknown model or distortion, image
times outside the ephemeris) raises FormatError naming the file and the key.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera.csm.distortion import MODELS, CsmDistortion
from orthomvp.camera.csm.ephemeris import (
    Orientations,
    hermite_states,
    matrix_wxyz,
    qinv,
)
from orthomvp.camera.csm.frame import MODEL_NAME as FRAME_MODEL
from orthomvp.camera.csm.frame import CsmFrameCamera
from orthomvp.camera.csm.geometry import Ellipsoid, FocalPlane, Trajectory
from orthomvp.camera.csm.linescan import MODEL_NAME as LINESCAN_MODEL
from orthomvp.camera.csm.linescan import LineScanCamera
from orthomvp.camera.csm.pushframe import MODEL_NAME as PUSHFRAME_MODEL
from orthomvp.camera.csm.pushframe import PushFrameCamera
from orthomvp.errors import FormatError, InputError

CsmCamera = LineScanCamera | CsmFrameCamera | PushFrameCamera
"""Any of the CSM camera models."""

MODEL_NAMES = (LINESCAN_MODEL, FRAME_MODEL, PUSHFRAME_MODEL)
"""The ``name_model`` values read."""

_UNITS = {"km": 1000.0, "m": 1.0}
_MIN_NODES = 25  # usgscsm resamples positions to at least this many uniform nodes


class _Isd:
    """An ISD's parsed JSON with typed, checked access; errors name the file, key and line."""

    def __init__(self, path: Path, text: str, obj: dict[str, Any]) -> None:
        self.path, self.text, self.obj = path, text, obj

    def error(self, key: str, message: str) -> FormatError:
        leaf = key.rsplit(".", 1)[-1]
        match = re.search(rf'"{re.escape(leaf)}"\s*:', self.text)
        line = self.text.count("\n", 0, match.start()) + 1 if match else None
        return FormatError(self.path, f"{key}: {message}", line)

    def has(self, key: str) -> bool:
        node: Any = self.obj
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return False
            node = node[part]
        return True

    def get(self, key: str) -> Any:
        node: Any = self.obj
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                raise FormatError(self.path, f"missing key {key!r}")
            node = node[part]
        return node

    def number(self, key: str, default: float | None = None) -> float:
        if default is not None and not self.has(key):
            return default
        value = self.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise self.error(key, f"{value!r} is not a finite number")
        return float(value)

    def integer(self, key: str, default: int | None = None) -> int:
        value = self.number(key, None if default is None else float(default))
        if value != int(value) or value <= 0:
            raise self.error(key, f"{value!r} is not a positive integer")
        return int(value)

    def array(self, key: str, shape: tuple[int | None, ...]) -> np.ndarray:
        value = self.get(key)
        try:
            arr = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(key, "expected an array of numbers") from None
        if arr.ndim != len(shape) or any(
            s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)
        ):
            want = " x ".join("N" if s is None else str(s) for s in shape)
            raise self.error(key, f"expected an array of shape {want}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise self.error(key, "holds values that are not finite numbers")
        return arr

    def length_unit(self, key: str) -> float:
        unit = (
            self.obj.get(key, {}).get("unit", "km") if isinstance(self.obj.get(key), dict) else "km"
        )
        if unit not in _UNITS:
            raise self.error(f"{key}.unit", f"unknown unit {unit!r} (km or m)")
        return _UNITS[unit]


def _sequence(
    isd: _Isd, key: str, columns: int, times_key: str = "ephemeris_times"
) -> tuple[np.ndarray, np.ndarray]:
    """The values (n, columns) of ``key`` and the ``ephemeris_times`` of its parent, checked
    to have the same length and increasing times."""
    parent = key.rsplit(".", 1)[0]
    values = isd.array(key, (None, columns))
    times = isd.array(f"{parent}.{times_key}", (None,))
    if len(values) != len(times) or len(times) == 0:
        raise isd.error(key, f"{len(values)} rows but {len(times)} {parent}.{times_key}")
    if (np.diff(times) <= 0).any():
        raise isd.error(f"{parent}.{times_key}", "times must increase")
    return values, times


def _orientations(isd: _Isd, key: str) -> Orientations:
    quats, times = _sequence(isd, f"{key}.quaternions", 4)
    if (np.linalg.norm(quats, axis=1) == 0).any():
        raise isd.error(f"{key}.quaternions", "a quaternion is zero")
    avs = np.zeros((len(times), 3))
    if isd.has(f"{key}.angular_velocities"):
        avs = isd.array(f"{key}.angular_velocities", (len(times), 3))
    constant = np.array([1.0, 0.0, 0.0, 0.0])
    if isd.has(f"{key}.constant_rotation"):
        constant = matrix_wxyz(isd.array(f"{key}.constant_rotation", (9,)).reshape(3, 3))
    return Orientations(quats, times, avs, constant)


def _focal_plane(isd: _Isd) -> FocalPlane:
    spec = isd.get("optical_distortion")
    if not isinstance(spec, dict) or not spec:
        raise isd.error("optical_distortion", "expected an object naming one distortion model")
    name = next(iter(spec))
    key = f"optical_distortion.{name}"
    if name not in MODELS:
        raise isd.error(key, f"unsupported distortion model {name!r} (known: {', '.join(MODELS)})")
    if name == "transverse":
        x, y = isd.array(f"{key}.x", (None,)), isd.array(f"{key}.y", (None,))
        if len(x) > 10 or len(y) > 10:
            raise isd.error(key, "at most 10 x and 10 y coefficients")
        coeffs = np.concatenate([np.pad(x, (0, 10 - len(x))), np.pad(y, (0, 10 - len(y)))])
    elif name == "kaguyalism":
        x, y = isd.array(f"{key}.x", (None,)), isd.array(f"{key}.y", (None,))
        if len(x) > 4 or len(y) > 4:
            raise isd.error(key, "at most 4 x and 4 y coefficients")
        bx, by = isd.number(f"{key}.boresight_x"), isd.number(f"{key}.boresight_y")
        coeffs = np.concatenate(
            [[bx], np.pad(x, (0, 4 - len(x))), [by], np.pad(y, (0, 4 - len(y)))]
        )
    else:
        coeffs = isd.array(f"{key}.coefficients", (None,))
    try:
        distortion = CsmDistortion(name, coeffs)
    except InputError as exc:
        raise isd.error(key, str(exc)) from None
    try:
        return FocalPlane(
            focal_length=isd.number("focal_length_model.focal_length"),
            i_trans_s=isd.array("focal2pixel_samples", (3,)),
            i_trans_l=isd.array("focal2pixel_lines", (3,)),
            sample_origin=isd.number("detector_center.sample"),
            line_origin=isd.number("detector_center.line"),
            sample_summing=isd.number("detector_sample_summing"),
            line_summing=isd.number("detector_line_summing"),
            starting_sample=isd.number("starting_detector_sample"),
            starting_line=isd.number("starting_detector_line"),
            distortion=distortion,
        )
    except InputError as exc:
        if isinstance(exc, FormatError):
            raise
        raise isd.error("focal2pixel_lines", str(exc)) from None


def _ellipsoid(isd: _Isd) -> Ellipsoid:
    scale = isd.length_unit("radii")
    a, b = isd.number("radii.semimajor") * scale, isd.number("radii.semiminor") * scale
    if not (a > 0 and b > 0):
        raise isd.error("radii", "radii must be positive")
    return Ellipsoid(a, b)


def _body_states(isd: _Isd, times: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Instrument positions and velocities (metres, m/s) rotated into the body frame, at
    ``times`` (None: the ISD's own times), and those times."""
    scale = isd.length_unit("instrument_position")
    positions, node_times = _sequence(isd, "instrument_position.positions", 3)
    velocities = None
    if isd.has("instrument_position.velocities"):
        velocities = isd.array("instrument_position.velocities", (len(node_times), 3))
    body = _orientations(isd, "body_rotation")
    if times is None:
        times = node_times
        pos, vel = positions, velocities if velocities is not None else np.zeros_like(positions)
    else:
        pos, vel = hermite_states(node_times, positions, velocities, times)
    pos, vel = body.rotate_states(times, pos, vel)
    return pos * scale, vel * scale, times


def _pointing(isd: _Isd) -> Orientations:
    """Sensor-to-body orientations (ALE's ``body_rotation * instrument_pointing.inverse()``)."""
    return _orientations(isd, "body_rotation") * _orientations(isd, "instrument_pointing").inverse()


def _xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    q = q_wxyz / np.linalg.norm(q_wxyz, axis=-1, keepdims=True)
    return q[..., [1, 2, 3, 0]]


def _trajectory(isd: _Isd, center: float) -> Trajectory:
    _, node_times = _sequence(isd, "instrument_position.positions", 3)
    count = max(len(node_times), _MIN_NODES)
    if len(node_times) < 2:
        raise isd.error(
            "instrument_position.positions", "a scanning sensor needs at least 2 positions"
        )
    step = (node_times[-1] - node_times[0]) / (count - 1)
    times = node_times[0] + step * np.arange(count)
    pos, vel, _ = _body_states(isd, times)
    pointing = _pointing(isd)
    if len(pointing.times) < 2:
        raise isd.error(
            "instrument_pointing.quaternions", "a scanning sensor needs at least 2 quaternions"
        )
    q_step = (pointing.times[-1] - pointing.times[0]) / (len(pointing.times) - 1)
    quats = _xyzw(pointing.interpolate(pointing.times[0] + q_step * np.arange(len(pointing.times))))
    return Trajectory(
        positions=pos,
        velocities=vel,
        t0_ephem=node_times[0] - center,
        dt_ephem=step,
        quaternions=quats,
        t0_quat=pointing.times[0] - center,
        dt_quat=q_step,
    )


def _common(isd: _Isd) -> dict[str, Any]:
    return {
        "lines": isd.integer("image_lines"),
        "samples": isd.integer("image_samples"),
        "focal_plane": _focal_plane(isd),
        "ellipsoid": _ellipsoid(isd),
    }


def _line_scan(isd: _Isd) -> LineScanCamera:
    center = isd.number("center_ephemeris_time")
    rate = isd.array("line_scan_rate", (None, 3))
    if len(rate) == 0:
        raise isd.error("line_scan_rate", "needs at least one row")
    if (rate[:, 2] <= 0).any():
        raise isd.error("line_scan_rate", "line durations must be positive")
    try:
        return LineScanCamera(
            **_common(isd),
            trajectory=_trajectory(isd, center),
            int_time_lines=rate[:, 0],
            int_time_start_times=rate[:, 1],
            int_times=rate[:, 2],
            center_time=center,
        )
    except InputError as exc:
        if isinstance(exc, FormatError):
            raise
        raise isd.error("line_scan_rate", str(exc)) from None


def _push_frame(isd: _Isd) -> PushFrameCamera:
    center = isd.number("center_ephemeris_time")
    overlap = int(isd.number("num_lines_overlap", 0.0)) if isd.has("num_lines_overlap") else 0
    try:
        return PushFrameCamera(
            **_common(isd),
            trajectory=_trajectory(isd, center),
            starting_time=isd.number("starting_ephemeris_time") - center,
            exposure_duration=isd.number("exposure_duration"),
            interframe_delay=isd.number("interframe_delay"),
            framelet_height=isd.integer("framelet_height"),
            framelets_flipped=bool(isd.get("framelets_flipped")),
            framelet_order_reversed=bool(isd.get("framelet_order_reversed")),
            overlap_lines=overlap,
            center_time=center,
        )
    except InputError as exc:
        if isinstance(exc, FormatError):
            raise
        raise isd.error("framelet_height", str(exc)) from None


def _frame(isd: _Isd) -> CsmFrameCamera:
    if isd.has("jitter"):
        raise isd.error("jitter", "rolling-shutter jitter is not supported")
    pos, vel, times = _body_states(isd, None)
    if len(times) != 1:
        raise isd.error(
            "instrument_position.positions", f"a frame camera has 1 position, got {len(times)}"
        )
    pointing = _pointing(isd)
    if len(pointing.times) != 1:
        raise isd.error("instrument_pointing.quaternions", "a frame camera has 1 quaternion")
    quat = _xyzw(pointing.interpolate(pointing.times))[0]
    return CsmFrameCamera(**_common(isd), position=pos[0], velocity=vel[0], quaternion=quat)


_READERS = {LINESCAN_MODEL: _line_scan, FRAME_MODEL: _frame, PUSHFRAME_MODEL: _push_frame}


def isd_model_name(obj: object) -> str | None:
    """The ``name_model`` of a parsed ISD, if it is a JSON object holding one."""
    return (
        obj.get("name_model")
        if isinstance(obj, dict) and isinstance(obj.get("name_model"), str)
        else None
    )


def camera_from_isd(obj: object, path: str | Path = "<isd>", text: str = "") -> CsmCamera:
    """The camera model of a parsed ISD ``obj``; errors name ``path`` (``text``: the file's
    text, to point at lines)."""
    path = Path(path)
    if not isinstance(obj, dict):
        raise FormatError(path, "an ISD must be a JSON object")
    isd = _Isd(path, text, obj)
    name = isd.get("name_model")
    if name not in _READERS:
        raise isd.error(
            "name_model", f"unknown sensor model {name!r} (known: {', '.join(MODEL_NAMES)})"
        )
    return _READERS[name](isd)


def read_isd(path: str | Path) -> CsmCamera:
    """Read the camera of an ISD file (line scan, frame or push frame, by ``name_model``)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{path}: ISD not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ISD ({exc})") from None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}", exc.lineno) from None
    return camera_from_isd(obj, path, text)


def line_scan_isd(camera: LineScanCamera) -> dict[str, Any]:
    """An ISD (a JSON-able dict) of a line-scan camera, which :func:`camera_from_isd` reads
    back to the same model: positions in km in the body frame (identity body rotation),
    pointing as J2000(= body)-to-sensor quaternions (w, x, y, z), at the model's own nodes.
    Needs at least 25 position nodes for an exact round trip (fewer are resampled on reading,
    as usgscsm does). Distortion other than radial, dawnfc, lrolrocnac, radtan is written in
    its ISD form too."""
    traj, fp = camera.trajectory, camera.focal_plane
    center = camera.center_time
    t_pos = center + traj.t0_ephem + traj.dt_ephem * np.arange(len(traj.positions))
    t_quat = center + traj.t0_quat + traj.dt_quat * np.arange(len(traj.quaternions))
    q = traj.quaternions[:, [3, 0, 1, 2]]  # camera-to-body, (w, x, y, z)
    q_isd = qinv(q / np.linalg.norm(q, axis=1, keepdims=True))
    c = fp.distortion.coefficients
    name = fp.distortion.model
    if name == "transverse":
        distortion: dict[str, Any] = {"x": c[:10].tolist(), "y": c[10:].tolist()}
    elif name == "kaguyalism":
        distortion = {
            "x": c[1:5].tolist(),
            "y": c[6:].tolist(),
            "boresight_x": float(c[0]),
            "boresight_y": float(c[5]),
        }
    else:
        distortion = {"coefficients": c.tolist()}
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (len(t_quat), 1))
    rate = np.stack([camera.int_time_lines, camera.int_time_start_times, camera.int_times], -1)
    first, last = camera.image_time(np.array([0.0, float(camera.lines)]))
    return {
        "name_model": LINESCAN_MODEL,
        "image_lines": camera.lines,
        "image_samples": camera.samples,
        "center_ephemeris_time": center,
        "starting_ephemeris_time": center + min(first, last),
        "line_scan_rate": rate.tolist(),
        "focal_length_model": {"focal_length": fp.focal_length},
        "focal2pixel_lines": fp.i_trans_l.tolist(),
        "focal2pixel_samples": fp.i_trans_s.tolist(),
        "detector_center": {"line": fp.line_origin, "sample": fp.sample_origin},
        "detector_line_summing": fp.line_summing,
        "detector_sample_summing": fp.sample_summing,
        "starting_detector_line": fp.starting_line,
        "starting_detector_sample": fp.starting_sample,
        "optical_distortion": {name: distortion},
        "radii": {
            "semimajor": camera.ellipsoid.semi_major / 1000.0,
            "semiminor": camera.ellipsoid.semi_minor / 1000.0,
            "unit": "km",
        },
        "interpolation_method": "lagrange",
        "instrument_position": {
            "unit": "km",
            "positions": (traj.positions / 1000.0).tolist(),
            "velocities": (traj.velocities / 1000.0).tolist(),
            "ephemeris_times": t_pos.tolist(),
            "reference_frame": 1,
        },
        "instrument_pointing": {
            "quaternions": q_isd.tolist(),
            "ephemeris_times": t_quat.tolist(),
            "angular_velocities": np.zeros((len(t_quat), 3)).tolist(),
            "reference_frame": 1,
        },
        "body_rotation": {
            "quaternions": identity.tolist(),
            "ephemeris_times": t_quat.tolist(),
            "angular_velocities": np.zeros((len(t_quat), 3)).tolist(),
            "reference_frame": 1,
        },
    }


def write_isd(camera: LineScanCamera, path: str | Path) -> None:
    """Write :func:`line_scan_isd` of ``camera`` to ``path`` (JSON, numbers exact)."""
    from orthomvp.camera.formats._common import write_text

    write_text(path, json.dumps(line_scan_isd(camera), indent=1) + "\n")
