"""MESSENGER's Mercury Dual Imaging System, narrow and wide angle (ISIS's MdisCamera and
TaylorCameraDistortionMap; ALE's MessengerMdisIsisLabelIsisSpiceDriver): frame cameras.

- Codes: NAC -236820; WAC -236800, its filters' codes -236800 - ``BandBin`` ``Number``. The
  detector origin (``BORESIGHT_SAMPLE`` - 0.5, ``BORESIGHT_LINE`` - 0.5) is the camera's; the
  focal plane (``ITRANSS/L``), focal length and lens are the filter's.
- Focal length: ``NaifKeywords`` ``TempDependentFocalLength`` when spiceinit stored it, else
  the filter's ``FL_TEMP_COEFFS`` polynomial (6 terms) at ``Instrument``
  ``FocalPlaneTemperature`` (ISIS's rule; ``DISABLE_MDIS_TD_FOCAL_LENGTH`` = TRUE: the
  filter's ``FOCAL_LENGTH``).
- Time: the middle of the exposure, the ET of ``SpacecraftClockCount`` + ``ExposureDuration``
  (ms) / 2.
- Summing: ``PixelBinningMode`` (0 is 1), doubled by ``FpuBinningMode`` = 1.
- Lens: the filter's Taylor polynomials ``OD_T_X``, ``OD_T_Y`` (10 terms each, usgscsm's
  ``transverse``).
"""

from __future__ import annotations

from typing import Any

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import frame_isd, ikid_of

_NAC, _WAC = -236820, -236800


def _focal_length(cube: SpiceCube, filter_code: int) -> float:
    stored = cube.naif_keywords.get("TempDependentFocalLength")
    if stored is not None:
        value = stored[0] if isinstance(stored, list | tuple) else stored
        return float(value)
    if str(cube.naif_keywords.get("DISABLE_MDIS_TD_FOCAL_LENGTH", "")).upper() == "TRUE":
        return cube.naif_number(f"INS{filter_code}_FOCAL_LENGTH")
    coeffs = cube.naif_array(f"INS{filter_code}_FL_TEMP_COEFFS", 6)
    temperature = cube.number("Instrument", "FocalPlaneTemperature")
    return sum(c * temperature**i for i, c in enumerate(coeffs))


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The frame ISD of an MDIS cube."""
    ikid = ikid_of(cube)
    if ikid == _NAC:
        code = ikid
    elif _WAC - 12 <= ikid <= _WAC:
        code = ikid - int(cube.number("BandBin", "Number"))
    else:
        raise cube.error(f"Kernels NaifFrameCode = {ikid} is neither MDIS-NAC nor MDIS-WAC")
    binning = int(cube.number("Instrument", "PixelBinningMode")) or 1
    summing = binning * (2 if int(cube.number("Instrument", "FpuBinningMode")) == 1 else 1)
    start = cube.clock_et(cube.keyword("Instrument", "SpacecraftClockCount"))
    time = start + cube.number("Instrument", "ExposureDuration") / 2000.0
    ins = f"INS{ikid}"
    out = frame_isd(
        cube,
        code,
        time=time,
        center=(
            cube.naif_number(f"{ins}_BORESIGHT_LINE") - 0.5,
            cube.naif_number(f"{ins}_BORESIGHT_SAMPLE") - 0.5,
        ),
        summing=float(summing),
    )
    out["focal_length_model"] = {"focal_length": _focal_length(cube, code)}
    out["optical_distortion"] = {
        "transverse": {
            "x": cube.naif_array(f"INS{code}_OD_T_X", 10),
            "y": cube.naif_array(f"INS{code}_OD_T_Y", 10),
        }
    }
    return out


INSTRUMENT = Instrument(
    name="MESSENGER MDIS (NAC and WAC filters)",
    ids=(("MESSENGER", "MDIS-NAC"), ("MESSENGER", "MDIS-WAC")),
    isd=isd,
)
