"""USGS CSM model states: what usgscsm's ``getModelState`` returns and the Ames Stereo
Pipeline writes for CSM cameras (``cam_gen``, ``bundle_adjust``, ``jitter_solve``): the model
name on the first line, then the model's JSON (``m_*`` keys, body-fixed metres, quaternions
scalar-last, times relative to ``m_centerEphemerisTime``). Line-scan and frame states are
read; adjustable parameters other than zero (not written by ASP, which applies its
corrections to the state itself) are refused.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera.csm.distortion import TYPE_CODES, CsmDistortion
from orthomvp.camera.csm.frame import MODEL_NAME as FRAME_MODEL
from orthomvp.camera.csm.frame import CsmFrameCamera
from orthomvp.camera.csm.geometry import Ellipsoid, FocalPlane, Trajectory
from orthomvp.camera.csm.linescan import MODEL_NAME as LINESCAN_MODEL
from orthomvp.camera.csm.linescan import LineScanCamera
from orthomvp.errors import FormatError, InputError

STATE_MODELS = (LINESCAN_MODEL, FRAME_MODEL)
"""The model names whose states are read."""


def state_model_name(text: str) -> str | None:
    """The model name of a model-state text (its first line), if it is one of usgscsm's."""
    first = text.lstrip().split("\n", 1)[0].strip()
    return first if first.startswith("USGS_ASTRO_") else None


def _numbers(path: Path, state: dict[str, Any], key: str, size: int | None = None) -> np.ndarray:
    if key not in state:
        raise FormatError(path, f"missing key {key!r}")
    try:
        arr = np.array(state[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(path, f"{key}: expected numbers") from None
    if size is not None and arr.size != size:
        raise FormatError(path, f"{key}: expected {size} numbers, got {arr.size}")
    if not np.isfinite(arr).all():
        raise FormatError(path, f"{key}: holds values that are not finite numbers")
    return arr


def _number(path: Path, state: dict[str, Any], key: str) -> float:
    return float(_numbers(path, state, key, 1).ravel()[0])


def _focal_plane(path: Path, s: dict[str, Any], origin: tuple[float, float]) -> FocalPlane:
    code = int(_number(path, s, "m_distortionType"))
    names = {v: k for k, v in TYPE_CODES.items()}
    if code not in names:
        raise FormatError(path, f"m_distortionType: unsupported distortion type {code}")
    distortion = CsmDistortion(names[code], _numbers(path, s, "m_opticalDistCoeffs"))
    return FocalPlane(
        focal_length=_number(path, s, "m_focalLength"),
        i_trans_s=_numbers(path, s, "m_iTransS", 3),
        i_trans_l=_numbers(path, s, "m_iTransL", 3),
        sample_origin=origin[1],
        line_origin=origin[0],
        sample_summing=_number(path, s, "m_detectorSampleSumming"),
        line_summing=_number(path, s, "m_detectorLineSumming"),
        starting_sample=_number(path, s, "m_startingDetectorSample"),
        starting_line=_number(path, s, "m_startingDetectorLine"),
        distortion=distortion,
    )


def camera_from_state(text: str, path: str | Path = "<state>") -> LineScanCamera | CsmFrameCamera:
    """The camera of a model-state text (model name line, then JSON)."""
    path = Path(path)
    name = state_model_name(text)
    if name not in STATE_MODELS:
        raise FormatError(path, f"model state of unsupported model {name!r}", 1)
    body = text[text.find("{") : text.rfind("}") + 1]
    try:
        s = json.loads(body)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"invalid JSON: {exc.msg}") from None
    if not isinstance(s, dict):
        raise FormatError(path, "the model state must be a JSON object")
    common = {
        "lines": int(_number(path, s, "m_nLines")),
        "samples": int(_number(path, s, "m_nSamples")),
        "ellipsoid": Ellipsoid(_number(path, s, "m_majorAxis"), _number(path, s, "m_minorAxis")),
    }
    try:
        if name == FRAME_MODEL:
            params = _numbers(path, s, "m_currentParameterValue", 7)
            center = _numbers(path, s, "m_ccdCenter", 2)
            return CsmFrameCamera(
                **common,
                focal_plane=_focal_plane(path, s, (center[0], center[1])),
                position=params[:3],
                velocity=_numbers(path, s, "m_spacecraftVelocity", 3),
                quaternion=params[3:],
            )
        if np.any(_numbers(path, s, "m_currentParameterValue") != 0):
            raise FormatError(
                path, "m_currentParameterValue: adjusted parameters are not supported"
            )
        origin = (
            _number(path, s, "m_detectorLineOrigin"),
            _number(path, s, "m_detectorSampleOrigin"),
        )
        trajectory = Trajectory(
            positions=_numbers(path, s, "m_positions").reshape(-1, 3),
            velocities=_numbers(path, s, "m_velocities").reshape(-1, 3),
            t0_ephem=_number(path, s, "m_t0Ephem"),
            dt_ephem=_number(path, s, "m_dtEphem"),
            quaternions=_numbers(path, s, "m_quaternions").reshape(-1, 4),
            t0_quat=_number(path, s, "m_t0Quat"),
            dt_quat=_number(path, s, "m_dtQuat"),
            order=8 if int(_number(path, s, "m_platformFlag")) else 4,
        )
        return LineScanCamera(
            **common,
            focal_plane=_focal_plane(path, s, origin),
            trajectory=trajectory,
            int_time_lines=_numbers(path, s, "m_intTimeLines"),
            int_time_start_times=_numbers(path, s, "m_intTimeStartTimes"),
            int_times=_numbers(path, s, "m_intTimes"),
            center_time=_number(path, s, "m_centerEphemerisTime"),
        )
    except (ValueError, InputError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(path, f"inconsistent model state: {exc}") from None
