"""Dawn's Framing Cameras FC1 and FC2 (ISIS's DawnFcCamera and DawnFcDistortionMap): frame
cameras of 1024 x 1024 pixels, one NAIF code per filter (``Kernels`` ``NaifFrameCode``,
-2031xy for FC1, -2032xy for FC2).

- Time: the middle of the exposure, the ET of ``Instrument`` ``SpacecraftClockStartCount`` +
  193 ms (the CCD's clearing) + ``ExposureDuration`` (ms) / 2.
- Detector: origin at ``CCD_CENTER`` + 1 (ISIS's 1-based pixels; + 0.5 in usgscsm's), no
  summing.
- Lens: ``RAD_DIST_COEFF`` k, x_d = x_u (1 + k r_u^2) (usgscsm's ``dawnfc``).
"""

from __future__ import annotations

from typing import Any

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import frame_isd, ikid_of

_CLEARING = 0.193  # s between the clock start count and the exposure's start


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The frame ISD of a Dawn FC cube."""
    ikid = ikid_of(cube)
    if not -203130 < ikid <= -203110:
        raise cube.error(f"Kernels NaifFrameCode = {ikid} is not a Dawn FC filter's code")
    alpha = cube.alpha
    if (alpha.samples, alpha.lines) != (1024, 1024):
        raise cube.error(
            f"the Dawn FC model expects a 1024 x 1024 image, not {alpha.samples:g} x "
            f"{alpha.lines:g} (AlphaCube or the cube's size)"
        )
    ins = f"INS{ikid}"
    start = cube.clock_et(cube.keyword("Instrument", "SpacecraftClockStartCount"))
    time = start + _CLEARING + cube.number("Instrument", "ExposureDuration") / 2000.0
    out = frame_isd(
        cube,
        ikid,
        time=time,
        center=(
            cube.naif_number(f"{ins}_CCD_CENTER", 1) + 0.5,
            cube.naif_number(f"{ins}_CCD_CENTER", 0) + 0.5,
        ),
    )
    out["optical_distortion"] = {
        "dawnfc": {"coefficients": [cube.naif_number(f"{ins}_RAD_DIST_COEFF")]}
    }
    return out


INSTRUMENT = Instrument(name="Dawn FC1/FC2", ids=(("DAWN", "FC1"), ("DAWN", "FC2")), isd=isd)
