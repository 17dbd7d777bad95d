"""MRO's Context Camera, CTX (ISIS's CTXCamera; ALE's MroCtxIsisLabelIsisSpiceDriver): a
push-broom line scanner.

- Timing: the first line starts at the ET of ``Instrument`` ``SpacecraftClockCount``
  (``NaifKeywords`` ``CLOCK_ET_-74_<count>_COMPUTED``); a line lasts ``LineExposureDuration``
  (ms) x ``SpatialSumming`` (ISIS's rule: summed lines take as many exposures).
- Detector: origin at ``BORESIGHT_SAMPLE`` - 0.5 and ``BORESIGHT_LINE``, ``SpatialSumming``
  across track, the first sample read out ``SampleFirstPixel``.
- Lens: ISIS's CameraDistortionMap, radial ``OD_K`` (3 coefficients; usgscsm's ``radial``).
"""

from __future__ import annotations

from typing import Any

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import ikid_of, line_scan_isd


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The line-scan ISD of a CTX cube."""
    ikid = ikid_of(cube)
    ins = f"INS{ikid}"
    summing = cube.number("Instrument", "SpatialSumming")
    out = line_scan_isd(
        cube,
        ikid,
        start_time=cube.clock_et(cube.keyword("Instrument", "SpacecraftClockCount")),
        line_rate=cube.number("Instrument", "LineExposureDuration") / 1000.0 * summing,
        center=(
            cube.naif_number(f"{ins}_BORESIGHT_LINE"),
            cube.naif_number(f"{ins}_BORESIGHT_SAMPLE") - 0.5,
        ),
        summing=summing,
        first_sample=cube.number("Instrument", "SampleFirstPixel"),
    )
    out["optical_distortion"] = {"radial": {"coefficients": cube.naif_array(f"{ins}_OD_K", 3)}}
    return out


INSTRUMENT = Instrument(
    name="MRO CTX",
    ids=(("MARS RECONNAISSANCE ORBITER", "CTX"),),
    isd=isd,
)
