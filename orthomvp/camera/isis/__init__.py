"""The camera of a spiceinit'd ISIS3 cube, read from the cube alone (no ISIS, ALE, SPICE
kernels or network): its attached tables ``InstrumentPointing``, ``InstrumentPosition``,
``BodyRotation``, ``SunPosition`` and its ``NaifKeywords``.

The cube becomes the USGS CSM ISD that ALE's driver for its instrument writes (with the cube's
AlphaCube crop and reduction folded in, which ALE leaves out), and that ISD the line-scan or
frame model of :mod:`orthomvp.camera.csm`; a lens model usgscsm lacks (Apollo Metric) replaces
the ISD's. The shared part: :mod:`.core` (the cube: label, NaifKeywords, AlphaCube),
:mod:`.tables` (the binary tables and their polynomial cache, as ISD rotations and positions),
:mod:`.times` (UTC to ephemeris time) and :mod:`.isd` (the frame and line-scan ISDs, summing);
each instrument is a module with its :class:`~.core.Instrument` (keys, timing rule,
distortion), listed in :data:`INSTRUMENTS`:

- line scanners: LRO NAC left and right (:mod:`.lro_nac`), MRO CTX (:mod:`.mro_ctx`), Kaguya
  TC1 and TC2 (:mod:`.kaguya_tc`), Mars Express HRSC (:mod:`.mex_hrsc`, a changing line rate);
- push frame: LRO WAC UV and VIS (:mod:`.lro_wac`);
- frame cameras: Apollo 15, 16 and 17 Metric (:mod:`.apollo_metric`), MESSENGER MDIS NAC and
  WAC filters (:mod:`.messenger_mdis`), Dawn FC1 and FC2 (:mod:`.dawn_fc`).

World = the target's body-fixed frame, metres; pixels (u, v) = (column, row) of the cube, integer
values at pixel centres.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from orthomvp.camera.csm.isd import CsmCamera, camera_from_isd
from orthomvp.camera.isis import (
    apollo_metric,
    dawn_fc,
    kaguya_tc,
    lro_nac,
    lro_wac,
    messenger_mdis,
    mex_hrsc,
    mro_ctx,
)
from orthomvp.camera.isis.core import Instrument, SpiceCube, instrument_key
from orthomvp.camera.isis.tables import ISD_ROUTE
from orthomvp.camera.isis.times import utc_to_et
from orthomvp.errors import FormatError

__all__ = ["INSTRUMENTS", "Instrument", "SpiceCube", "cube_isd", "read_cube_camera", "utc_to_et"]

INSTRUMENTS: tuple[Instrument, ...] = (
    lro_nac.INSTRUMENT,
    mro_ctx.INSTRUMENT,
    kaguya_tc.INSTRUMENT,
    lro_wac.INSTRUMENT,
    mex_hrsc.INSTRUMENT,
    apollo_metric.INSTRUMENT,
    messenger_mdis.INSTRUMENT,
    dawn_fc.INSTRUMENT,
)
"""The instruments the cube reader knows."""


def instrument_of(cube: SpiceCube) -> Instrument:
    """The registered instrument of ``cube``; FormatError for a map-projected cube, a cube
    without an Instrument group, and an instrument not supported (ALE's route suggested)."""
    if cube.group("Mapping") is not None:
        raise cube.error(
            "a map-projected (level 2) cube (IsisCube > Group = Mapping) has no camera: give "
            "the level-1 cube it was projected from"
        )
    if cube.group("Instrument") is None:
        raise cube.error("the label lacks IsisCube > Group = Instrument: not an instrument's cube")
    spacecraft = str(cube.keyword("Instrument", "SpacecraftName"))
    instrument = str(cube.keyword("Instrument", "InstrumentId"))
    key = instrument_key(spacecraft, instrument)
    for known in INSTRUMENTS:
        if key in {instrument_key(*pair) for pair in known.ids}:
            return known
    names = "; ".join(i.name for i in INSTRUMENTS)
    raise cube.error(
        f"instrument {instrument!r} of {spacecraft!r} is not supported by the cube reader "
        f"(supported: {names}): {ISD_ROUTE}"
    )


def cube_isd(path: str | Path) -> dict[str, Any]:
    """The USGS CSM ISD (a JSON-able dict, ALE's keys) of the spiceinit'd cube at ``path``."""
    cube = SpiceCube(path)
    return instrument_of(cube).isd(cube)


def read_cube_camera(path: str | Path) -> CsmCamera:
    """The camera of the spiceinit'd ISIS3 cube at ``path`` (a :mod:`orthomvp.camera.csm`
    model). InputError/FormatError, one line naming the file and the key, for a cube without
    SPICE attached (run spiceinit), tables that name kernels instead of being attached, an
    instrument not supported, a map-projected cube, a truncated table."""
    cube = SpiceCube(path)
    instrument = instrument_of(cube)
    isd = instrument.isd(cube)
    try:
        camera = camera_from_isd(isd, cube.path)
    except FormatError as exc:
        raise FormatError(
            cube.path, f"the camera built from the cube's tables: {exc.reason}"
        ) from None
    if instrument.distortion is not None:
        plane = replace(camera.focal_plane, distortion=instrument.distortion(cube))
        camera = replace(camera, focal_plane=plane)
    return camera
