"""LRO's Wide Angle Camera, UV and VIS (ISIS's LroWideAngleCamera; ALE's
LroLrocWacIsisLabelNaifSpiceDriver): a push-frame camera, each framelet a few detector lines
behind one filter; the cube's first band is its camera.

- Filter: ``BandBin`` ``FilterNumber`` (the first band's); its NAIF code is -85640 - filter
  (UV, filters 1-2) or -85628 - filter (VIS, filters 3-7), which holds its focal length,
  focal plane (``ITRANSS/L``), origin (``BORESIGHT_SAMPLE/LINE`` - 0.5) and lens.
- Framelets: 16 detector lines summed 4 x 4 (UV) or 14 lines unsummed (VIS), starting on the
  detector at the camera's ``FILTER_OFFSET`` for the filter; ``DataFlipped`` flips them.
- Timing: the first framelet at the ET of ``SpacecraftClockStartCount`` + ``ExposureDuration``
  / 2, then every ``InterframeDelay`` (both ms), as ALE has it (the ISD's start time; usgscsm
  adds another half exposure for the framelet's middle).
- Lens: radial, the filter's ``OD_K`` negated (ALE's reading of ISIS's
  LroWideAngleCameraDistortionMap for usgscsm's ``radial``).
"""

from __future__ import annotations

from typing import Any

from orthomvp.camera.isis.core import Instrument, SpiceCube
from orthomvp.camera.isis.isd import ikid_of, push_frame_isd

_UV = {"base": -85640, "filters": (1, 2), "framelet": 16, "summing": 4}
_VIS = {"base": -85628, "filters": (3, 4, 5, 6, 7), "framelet": 14, "summing": 1}


def isd(cube: SpiceCube) -> dict[str, Any]:
    """The push-frame ISD of an LRO WAC cube (its first band)."""
    camera = ikid_of(cube)
    kind = str(cube.keyword("Instrument", "InstrumentId")).upper().replace("_", "-")
    spec = _UV if kind == "WAC-UV" else _VIS
    filters = cube.keyword("BandBin", "FilterNumber")
    filters = list(filters) if isinstance(filters, list | tuple) else [filters]
    number = int(cube._finite(filters[0], "BandBin FilterNumber"))
    if number not in spec["filters"]:
        raise cube.error(f"BandBin FilterNumber = {number} is not a filter of the {kind} camera")
    ins = f"INS{spec['base'] - number}"
    offsets = cube.naif(f"INS{camera}_FILTER_OFFSET")
    offsets = list(offsets) if isinstance(offsets, list | tuple) else [offsets]
    index = spec["filters"].index(number)
    if index >= len(offsets):
        raise cube.error(f"NaifKeywords INS{camera}_FILTER_OFFSET has no value {index + 1}")
    exposure = cube.number("Instrument", "ExposureDuration") / 1000.0
    start = cube.clock_et(cube.keyword("Instrument", "SpacecraftClockStartCount"))
    out = push_frame_isd(
        cube,
        spec["base"] - number,
        start_time=start + exposure / 2.0,
        exposure=exposure,
        interframe_delay=cube.number("Instrument", "InterframeDelay") / 1000.0,
        framelet_height=spec["framelet"],
        center=(
            cube.naif_number(f"{ins}_BORESIGHT_LINE") - 0.5,
            cube.naif_number(f"{ins}_BORESIGHT_SAMPLE") - 0.5,
        ),
        summing=float(spec["summing"]),
        first_line=cube._finite(offsets[index], f"NaifKeywords INS{camera}_FILTER_OFFSET"),
        flipped=str(cube.keyword("Instrument", "DataFlipped")).upper() in {"YES", "TRUE"},
    )
    out["optical_distortion"] = {
        "radial": {"coefficients": [-k for k in cube.naif_array(f"{ins}_OD_K", 3)]}
    }
    return out


INSTRUMENT = Instrument(
    name="LRO WAC (UV and VIS)",
    ids=(("LUNAR RECONNAISSANCE ORBITER", "WAC-UV"), ("LUNAR RECONNAISSANCE ORBITER", "WAC-VIS")),
    isd=isd,
)
