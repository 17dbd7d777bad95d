"""USGS CSM cameras: ISD JSON (ALE's Image Support Data, recognised by its ``name_model`` key)
and usgscsm/ASP model-state files (a ``USGS_ASTRO_...`` model name line, then the state's
JSON). The models are :mod:`orthomvp.camera.csm`'s, imported when a file is tested or read
(so that reading a camera of another format does not load them)."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from orthomvp.camera.formats._common import CameraFile, CameraFormat
from orthomvp.errors import FormatError

if TYPE_CHECKING:
    from orthomvp.camera.csm.isd import CsmCamera


def _parsed(file: CameraFile) -> object:
    try:
        return json.loads(file.text)
    except json.JSONDecodeError as exc:
        raise FormatError(file.path, f"invalid JSON: {exc.msg}", exc.lineno) from None


def read_isd_file(file: CameraFile) -> CsmCamera:
    """The camera of an ISD file."""
    from orthomvp.camera.csm.isd import camera_from_isd

    return camera_from_isd(_parsed(file), file.path, file.text)


def is_isd(file: CameraFile) -> bool:
    """Whether the file is a JSON object with a ``name_model`` key (read only if it names one)."""
    if not file.head.startswith("{") or '"name_model"' not in file.head:
        return False
    from orthomvp.camera.csm.isd import isd_model_name

    try:
        return isd_model_name(json.loads(file.head)) is not None
    except json.JSONDecodeError:
        return False


def read_state_file(file: CameraFile) -> CsmCamera:
    """The camera of a usgscsm/ASP model-state file."""
    from orthomvp.camera.csm.state import camera_from_state

    return camera_from_state(file.text, file.path)


def is_state(file: CameraFile) -> bool:
    """Whether the file starts with a usgscsm model name line."""
    from orthomvp.camera.csm.state import state_model_name

    return state_model_name(file.head) is not None


FORMATS = (
    CameraFormat("USGS CSM ISD", (".json",), read_isd_file, is_isd),
    CameraFormat("USGS CSM model state", (".json",), read_state_file, is_state),
)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry."""
