"""Mars Express's High Resolution Stereo Camera, HRSC (ISIS's HrscCamera with its
VariableLineScanCameraDetectorMap; ALE's MexHrscIsisLabelNaifSpiceDriver): nine push-broom
line scanners (the stereo, photometric and colour lines) on one focal plane, each cube one of
them (``Archive`` ``DetectorId``, ``Kernels`` ``NaifIkCode``).

- Timing: the line rate changes during the image; the cube's table ``LineScanTimes`` holds
  each rate's first line (``LineStart``, ISIS's 1-based), its ET (``EphemerisTime``) and the
  line time (``ExposureTime``, s).
- Detector: the filter's ``ITRANSS/L`` (its place on the focal plane is in their offsets),
  origin at sample ``BORESIGHT_SAMPLE`` - 0.5 and line 0, ``Instrument`` ``Summing`` both
  ways (1 if absent).
- No lens model (as ISIS and ALE).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import ikid_of, line_scan_isd
from orthomvp.camera.isis.tables import _item


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The line-scan ISD of an HRSC cube."""
    ikid = ikid_of(cube)
    table = cube.table(
        "LineScanTimes",
        missing="HRSC's line times, which hrsc2isis writes from the PDS image; import the "
        "image again with hrsc2isis",
    )
    starts, times, rates = (
        cube._column(table, key) for key in ("LineStart", "EphemerisTime", "ExposureTime")
    )
    if (np.diff(starts) <= 0).any() or (np.diff(times) <= 0).any():
        raise cube.error("Table LineScanTimes: its lines and times do not increase")
    summing = _item(cube.group("Instrument"), "Summing") or 1
    summing = cube._finite(summing, "Instrument Summing")
    out = line_scan_isd(
        cube,
        ikid,
        rows=[
            (float(b) - 1.0, float(t), float(r))
            for b, t, r in zip(starts, times, rates, strict=True)
        ],
        center=(0.0, cube.naif_number(f"INS{ikid}_BORESIGHT_SAMPLE") - 0.5),
        summing=summing,
    )
    out["detector_line_summing"] = summing
    out["optical_distortion"] = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
    return out


INSTRUMENT = Instrument(name="Mars Express HRSC", ids=(("MARS EXPRESS", "HRSC"),), isd=isd)
