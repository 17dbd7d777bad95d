"""USGS Community Sensor Model cameras, usgscsm's published models in numpy: the line scanner
(:class:`LineScanCamera`), frame (:class:`CsmFrameCamera`) and push frame
(:class:`PushFrameCamera`), read from ISDs (:func:`read_isd`) or model states
(:func:`camera_from_state`), each implementing :class:`orthomvp.camera.model.Camera`.

World = the ISD's body-fixed frame, metres; pixels (u, v) = (column, row), integer pixel
centres (CSM's (line, sample) = (v + 0.5, u + 0.5), see :mod:`.geometry`).
"""

from orthomvp.camera.csm.distortion import CsmDistortion
from orthomvp.camera.csm.frame import CsmFrameCamera
from orthomvp.camera.csm.geometry import csm_to_uv, uv_to_csm
from orthomvp.camera.csm.isd import CsmCamera, camera_from_isd, line_scan_isd, read_isd, write_isd
from orthomvp.camera.csm.linescan import LineScanCamera, posts_per_second
from orthomvp.camera.csm.pushframe import PushFrameCamera
from orthomvp.camera.csm.state import camera_from_state

__all__ = [
    "CsmCamera",
    "CsmDistortion",
    "CsmFrameCamera",
    "LineScanCamera",
    "PushFrameCamera",
    "camera_from_isd",
    "camera_from_state",
    "csm_to_uv",
    "line_scan_isd",
    "posts_per_second",
    "read_isd",
    "uv_to_csm",
    "write_isd",
]
