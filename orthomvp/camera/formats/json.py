"""orthomvp's own camera JSON: every :class:`~orthomvp.camera.model.PinholeCamera` field by name.

``{"type": "pinhole", "fu": ..., "fv": ..., "cu": ..., "cv": ..., "pitch": ..., "center": [3],
"rotation": [[3] x 3], "u_direction": [3], "v_direction": [3], "w_direction": [3],
"distortion": {"model": NAME, PARAMETER: value, ...}, "width": ..., "height": ...}``, in the
units of :mod:`orthomvp.camera.model`. ``fu``, ``fv``, ``cu``, ``cv``, ``center`` and ``rotation``
are required, the others default as in PinholeCamera (the image size may be null). Numbers are
written exactly (shortest round-trip form).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from orthomvp.camera.formats._common import (
    CameraFile,
    CameraFormat,
    build_camera,
    build_distortion,
    write_text,
)
from orthomvp.camera.model import PinholeCamera
from orthomvp.errors import FormatError

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


def read_json(file: CameraFile) -> PinholeCamera:
    """The camera of a file in our JSON form (see :func:`camera_to_dict`)."""
    path, text = file.path, file.text
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
    values["distortion"] = build_distortion(path, spec["model"], params, line)
    return build_camera(path, lambda name: _json_line(text, name), **values)


def is_json(file: CameraFile) -> bool:
    """Whether the file looks like JSON: its text starts with ``{``."""
    return file.head.startswith("{")


FORMATS = (CameraFormat("JSON", (".json",), read_json, is_json),)
"""The formats this module reads, for :mod:`orthomvp.camera`'s registry."""


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


def write_json(camera: PinholeCamera, path: str | Path) -> None:
    """Write ``camera`` in our JSON form, every number exact."""
    write_text(path, json.dumps(camera_to_dict(camera), indent=2) + "\n")
