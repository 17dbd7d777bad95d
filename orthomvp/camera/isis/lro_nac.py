"""LRO's Narrow Angle Cameras, left and right (ISIS's LroNarrowAngleCamera; ALE's
LroLrocNacIsisLabelIsisSpiceDriver): push-broom line scanners.

- Timing: the first line is exposed at the ET of ``Instrument`` ``SpacecraftClockPrerollCount``
  (``NaifKeywords`` ``CLOCK_ET_-85_<count>_COMPUTED``) + ``CONSTANT_TIME_OFFSET`` +
  ``ADDITIONAL_PREROLL`` line times, a line lasting ``LineExposureDuration`` (ms)
  x (1 + ``MULTIPLI_LINE_ERROR``) + ``ADDITIVE_LINE_ERROR`` (s).
- Detector: origin at ``BORESIGHT_SAMPLE`` - 0.5 (usgscsm's 0-based pixels) and
  ``BORESIGHT_LINE``, ``SpatialSumming`` across track, ``SampleFirstPixel`` the first sample
  read out.
- Lens: ISIS's LroNarrowAngleDistortionMap, one coefficient ``OD_K``: x_u = x,
  y_u = y / (1 + k y^2) with y across track (usgscsm's ``lrolrocnac``).
- The focal plane's line axis follows the flight direction: ALE negates ``ITRANSL`` when the
  spacecraft flies backwards (the sensor frame's x velocity is negative; the right camera's
  frame is turned by 180 degrees, so its sign is the opposite).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from orthomvp.camera.csm.ephemeris import matrix_wxyz, qmul, wxyz_matrix
from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import ikid_of, line_scan_isd

_CAMERAS = {-85600: "NACL", -85610: "NACR"}


def _flight_sign(isd: dict[str, Any], right: bool) -> float:
    """+1 if the spacecraft flies along the sensor frame's +x (-x for the right camera)."""
    pointing, position = isd["instrument_pointing"], isd["instrument_position"]
    if "velocities" not in position:
        return 1.0
    q = np.asarray(pointing["quaternions"][0])
    if "constant_rotation" in pointing:
        q = qmul(matrix_wxyz(np.reshape(pointing["constant_rotation"], (3, 3))), q)
    vx = (wxyz_matrix(q / np.linalg.norm(q)) @ np.asarray(position["velocities"][0]))[0]
    return -1.0 if (vx < 0) != right else 1.0


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The line-scan ISD of an LRO NAC cube."""
    ikid = ikid_of(cube)
    if ikid not in _CAMERAS:
        raise cube.error(
            f"Kernels NaifFrameCode = {ikid} is neither NAC-L (-85600) nor NAC-R (-85610)"
        )
    ins = f"INS{ikid}"
    rate = cube.number("Instrument", "LineExposureDuration") / 1000.0
    rate = rate * (1.0 + cube.naif_number(f"{ins}_MULTIPLI_LINE_ERROR"))
    rate += cube.naif_number(f"{ins}_ADDITIVE_LINE_ERROR")
    start = cube.clock_et(cube.keyword("Instrument", "SpacecraftClockPrerollCount"))
    start += cube.naif_number(f"{ins}_CONSTANT_TIME_OFFSET")
    start += cube.naif_number(f"{ins}_ADDITIONAL_PREROLL") * rate
    out = line_scan_isd(
        cube,
        ikid,
        start_time=start,
        line_rate=rate,
        center=(
            cube.naif_number(f"{ins}_BORESIGHT_LINE"),
            cube.naif_number(f"{ins}_BORESIGHT_SAMPLE") - 0.5,
        ),
        summing=cube.number("Instrument", "SpatialSumming"),
        first_sample=cube.number("Instrument", "SampleFirstPixel"),
    )
    out["focal2pixel_lines"] = [
        _flight_sign(out, _CAMERAS[ikid] == "NACR") * v for v in out["focal2pixel_lines"]
    ]
    out["optical_distortion"] = {"lrolrocnac": {"coefficients": [cube.naif_number(f"{ins}_OD_K")]}}
    return out


INSTRUMENT = Instrument(
    name="LRO NAC (left and right)",
    ids=(("LUNAR RECONNAISSANCE ORBITER", "NACL"), ("LUNAR RECONNAISSANCE ORBITER", "NACR")),
    isd=isd,
)
