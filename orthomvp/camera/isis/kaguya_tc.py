"""Kaguya's (SELENE's) Terrain Cameras TC1 and TC2 (ISIS's KaguyaTcCamera; ALE's
KaguyaTcIsisLabelNaifSpiceDriver): push-broom line scanners.

- Timing: the first line at the ET of ``Instrument`` ``SpacecraftClockStartCount``
  (``NaifKeywords`` ``CLOCK_ET_-131_<count>_COMPUTED``); a line lasts
  ``LineSamplingInterval`` (ms; the first value when it is a list; ``ExposureDuration`` is not
  the line time).
- Detector: origin at ``BORESIGHT_LINE`` - 0.5, ``BORESIGHT_SAMPLE`` - 0.5 (ISIS's 1-based
  addendum values); the first sample read out by ``SwathModeId`` (FULL 1, NOMINAL 297, HALF
  1172; - 0.5) and detector line 1, as ALE writes them.
- Focal plane: 1 / ``PIXEL_PITCH`` per mm, samples along -x (ALE's signs).
- Lens: ``DISTORTION_COEF_X``/``_Y`` cubics about ``BORESIGHT`` (usgscsm's ``kaguyalism``).
"""

from __future__ import annotations

from typing import Any

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import ikid_of, line_scan_isd

_FIRST_SAMPLE = {"FULL": 1.0, "NOMINAL": 297.0, "HALF": 1172.0}


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The line-scan ISD of a Kaguya TC cube."""
    ikid = ikid_of(cube)
    ins = f"INS{ikid}"
    interval = cube.keyword("Instrument", "LineSamplingInterval")
    if isinstance(interval, list | tuple):
        interval = interval[0]
    interval = getattr(interval, "value", interval)
    rate = cube._finite(interval, "Instrument LineSamplingInterval") / 1000.0
    swath = str(cube.keyword("Instrument", "SwathModeId")).upper()
    if swath not in _FIRST_SAMPLE:
        raise cube.error(f"Instrument SwathModeId = {swath!r} is not one of {list(_FIRST_SAMPLE)}")
    out = line_scan_isd(
        cube,
        ikid,
        start_time=cube.clock_et(cube.keyword("Instrument", "SpacecraftClockStartCount")),
        line_rate=rate,
        center=(
            cube.naif_number(f"{ins}_BORESIGHT_LINE") - 0.5,
            cube.naif_number(f"{ins}_BORESIGHT_SAMPLE") - 0.5,
        ),
        first_sample=_FIRST_SAMPLE[swath] - 0.5,
    )
    pitch = cube.naif_number(f"{ins}_PIXEL_PITCH")
    boresight = cube.naif_number(f"{ins}_BORESIGHT", 0), cube.naif_number(f"{ins}_BORESIGHT", 1)
    out.update(
        starting_detector_line=1.0,
        focal2pixel_lines=[0.0, 1.0 / pitch, 0.0],
        focal2pixel_samples=[0.0, 0.0, -1.0 / pitch],
        optical_distortion={
            "kaguyalism": {
                "x": cube.naif_array(f"{ins}_DISTORTION_COEF_X", 4),
                "y": cube.naif_array(f"{ins}_DISTORTION_COEF_Y", 4),
                "boresight_x": boresight[0],
                "boresight_y": boresight[1],
            }
        },
    )
    return out


INSTRUMENT = Instrument(
    name="Kaguya TC1/TC2",
    ids=tuple((craft, tc) for craft in ("KAGUYA", "SELENE") for tc in ("TC1", "TC2")),
    isd=isd,
)
