"""The ISD assembly of the cube reader: a :class:`~.core.SpiceCube` and an instrument's
timing and detector numbers turned into the USGS CSM ISD (ALE's keys) of a frame camera
(:func:`frame_isd`, its tables reduced to the exposure time by :func:`states_at`), a line
scanner (:func:`line_scan_isd`, one line rate or several) or a push-frame camera
(:func:`push_frame_isd`), all built on the keys every instrument shares (:func:`base_isd`),
with the cube's AlphaCube crop and reduction folded in (refused for a push frame).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from orthomvp.camera.csm.ephemeris import Orientations, hermite_states
from orthomvp.camera.isis.core import SpiceCube
from orthomvp.camera.isis.tables import NO_SPICE, _item
from orthomvp.errors import InputError

_SINGLE_RECORD_SLACK = 0.01  # s: a one-record table serves an image time this close to its own


def states_at(cube: SpiceCube, spice: dict[str, Any], time: float) -> dict[str, Any]:
    """The ISD tables (``spice``, :attr:`SpiceCube.spice`) reduced to one record at ``time``
    for a frame camera: a one-record table as it is (if within 0.01 s of ``time``), a longer
    one interpolated (positions by cubic Hermite, rotations by SLERP); InputError for a time
    outside a table's span (never extrapolated)."""
    out = {}
    for key, part in spice.items():
        times = np.asarray(part["ephemeris_times"])
        if len(times) == 1:
            if abs(times[0] - time) > _SINGLE_RECORD_SLACK:
                raise InputError(
                    f"{cube.path}: the image time {time:.6f} is {time - times[0]:+.6f} s from "
                    f"the one record of its {key} table"
                )
            out[key] = part
            continue
        if not times[0] <= time <= times[-1]:
            raise InputError(
                f"{cube.path}: the image time {time:.6f} lies outside its {key} table "
                f"[{times[0]:.6f}, {times[-1]:.6f}]"
            )
        new = dict(part, ephemeris_times=[time])
        if "positions" in part:
            vel = np.asarray(part["velocities"]) if "velocities" in part else None
            pos, v = hermite_states(times, np.asarray(part["positions"]), vel, np.array([time]))
            new["positions"], new["velocities"] = pos.tolist(), v.tolist()
        else:
            avs = np.asarray(part.get("angular_velocities", np.zeros((len(times), 3))))
            rot = Orientations(
                np.asarray(part["quaternions"]), times, avs, np.array([1.0, 0, 0, 0])
            )
            new["quaternions"] = rot.time_dependent(np.array([time])).tolist()
            new["angular_velocities"] = rot.angular_velocity(np.array([time])).tolist()
        out[key] = new
    return out


def base_isd(cube: SpiceCube, ikid: int) -> dict[str, Any]:
    """The ISD keys every instrument shares: image size, names, radii, the focal plane's
    ``focal2pixel`` transforms (``NaifKeywords`` ``INS<ikid>_ITRANSS/ITRANSL``) and focal
    length (``INS<ikid>_FOCAL_LENGTH``), and the SPICE tables."""
    samples, lines = cube.size
    ins = f"INS{ikid}"
    return {
        "image_lines": lines,
        "image_samples": samples,
        "name_platform": str(cube.keyword("Instrument", "SpacecraftName")),
        "name_sensor": str(
            _item(cube.group("Instrument"), "InstrumentName")
            or cube.keyword("Instrument", "InstrumentId")
        ),
        "reference_height": {"maxheight": 1000, "minheight": -1000, "unit": "m"},
        "radii": cube.radii,
        "focal_length_model": {"focal_length": cube.naif_number(f"{ins}_FOCAL_LENGTH")},
        "focal2pixel_lines": cube.naif_array(f"{ins}_ITRANSL", 3),
        "focal2pixel_samples": cube.naif_array(f"{ins}_ITRANSS", 3),
        **cube.spice,
    }


def ikid_of(cube: SpiceCube) -> int:
    """The instrument's NAIF code, ``Kernels`` ``NaifIkCode`` or else ``NaifFrameCode``."""
    kernels = cube.group("Kernels")
    if kernels is None:
        raise cube.error(f"no Kernels group: no SPICE attached: {NO_SPICE}")
    code = _item(kernels, "NaifIkCode") or _item(kernels, "NaifFrameCode")
    if code is None:
        raise cube.error("the label lacks Kernels NaifFrameCode (IsisCube > Group = Kernels)")
    return int(code)


def frame_isd(
    cube: SpiceCube,
    ikid: int,
    *,
    time: float,
    center: tuple[float, float],
    summing: float = 1.0,
    first: tuple[float, float] = (0.0, 0.0),
) -> dict[str, Any]:
    """The ISD of a frame camera exposed at ET ``time``: detector ``center`` (line, sample) in
    usgscsm's 0-based detector pixels, the instrument's pixel ``summing`` and ``first`` detector
    (line, sample) read out, with the cube's AlphaCube crop and reduction folded in."""
    alpha = cube.alpha
    isd = base_isd(cube, ikid)
    isd.update(states_at(cube, cube.spice, time))
    isd.update(
        name_model="USGS_ASTRO_FRAME_SENSOR_MODEL",
        center_ephemeris_time=time,
        detector_center={"line": center[0], "sample": center[1]},
        detector_sample_summing=summing * alpha.sample_slope,
        detector_line_summing=summing * alpha.line_slope,
        starting_detector_sample=summing * alpha.full_sample(0.0) + first[1],
        starting_detector_line=summing * alpha.full_line(0.0) + first[0],
    )
    return isd


def line_scan_isd(
    cube: SpiceCube,
    ikid: int,
    *,
    start_time: float = 0.0,
    line_rate: float = 0.0,
    rows: Sequence[tuple[float, float, float]] = (),
    center: tuple[float, float],
    summing: float = 1.0,
    first_sample: float = 0.0,
) -> dict[str, Any]:
    """The ISD of a line scanner whose original image starts (the top edge of its first line,
    CSM line 0; ISIS's and ALE's start time) at ET ``start_time``, each line lasting
    ``line_rate`` seconds, or, for a rate that changes, whose ``rows`` (CSM line of the
    original image where a rate begins, ET there, seconds per line) say so: detector ``center``
    (line, sample), the instrument's cross-track ``summing`` and ``first_sample`` read out,
    the AlphaCube folded in (the cube's lines start later, and a reduced cube's lines last
    longer)."""
    rows = list(rows) or [(0.0, start_time, line_rate)]
    if any(not rate > 0 for _, _, rate in rows):
        raise cube.error(f"the line rates {[r for _, _, r in rows]!r} s are not all positive")
    alpha = cube.alpha
    isd = base_isd(cube, ikid)
    lines = isd["image_lines"]
    # the rows on the cube's lines: line b of the original image is the cube's (b - b0) / slope
    b0 = alpha.full_line(0.0)
    cube_rows = [((b - b0) / alpha.line_slope, t, r * alpha.line_slope) for b, t, r in rows]
    before = [k for k, row in enumerate(cube_rows) if row[0] <= 0.0]
    if not before:
        raise cube.error("the line times begin after the cube's first line")
    first = before[-1]
    b, t, r = cube_rows[first]
    kept = [(0.0, t - b * r, r)] + [row for row in cube_rows[first + 1 :] if row[0] < lines]
    b, t, r = kept[-1]
    start, end = kept[0][1], t + (lines - b) * r
    for key in ("instrument_pointing", "instrument_position"):
        times = isd[key]["ephemeris_times"]
        if start < times[0] - 0.5 * kept[0][2] or end > times[-1] + 0.5 * r:
            raise cube.error(
                f"the cube's lines are exposed over ET [{start:.6f}, {end:.6f}], beyond its "
                f"{key} table's [{times[0]:.6f}, {times[-1]:.6f}] (never extrapolated)"
            )
    # one rate: the middle as ALE writes it (equal to (start + end) / 2 but for rounding)
    middle = (start + end) / 2.0 if len(kept) > 1 else start + 0.5 * lines * kept[0][2]
    isd.update(
        name_model="USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL",
        interpolation_method="lagrange",
        line_scan_rate=[[b + 0.5, t - middle, r] for b, t, r in kept],
        starting_ephemeris_time=start,
        center_ephemeris_time=middle,
        detector_center={"line": center[0], "sample": center[1]},
        detector_sample_summing=summing * alpha.sample_slope,
        detector_line_summing=summing,
        starting_detector_sample=summing * alpha.full_sample(0.0) + first_sample,
        starting_detector_line=0.0,
    )
    return isd


def push_frame_isd(
    cube: SpiceCube,
    ikid: int,
    *,
    start_time: float,
    exposure: float,
    interframe_delay: float,
    framelet_height: int,
    center: tuple[float, float],
    summing: float = 1.0,
    first_line: float = 0.0,
    flipped: bool = False,
) -> dict[str, Any]:
    """The ISD of a push-frame camera (usgscsm's): framelets of ``framelet_height`` detector
    lines, framelet n exposed around ET ``start_time`` (the ISD's start) + ``exposure`` / 2 +
    n x ``interframe_delay`` (usgscsm's rule); detector ``center`` (line, sample),
    ``summing`` both ways, the framelet's ``first_line`` on the detector. A cube cropped or
    reduced (AlphaCube) is refused: its lines no longer fall into whole framelets."""
    alpha = cube.alpha
    samples, lines = cube.size
    if (alpha.samples, alpha.lines, alpha.start_sample, alpha.start_line) != (
        samples,
        lines,
        0.5,
        0.5,
    ) or (alpha.sample_slope, alpha.line_slope) != (1.0, 1.0):
        raise cube.error(
            "a cropped or reduced push-frame cube (AlphaCube) is not supported: give the "
            "whole image"
        )
    per_framelet = framelet_height / summing
    if per_framelet != int(per_framelet) or lines % int(per_framelet):
        raise cube.error(
            f"the cube's {lines} lines are not whole framelets of {per_framelet:g} lines"
        )
    isd = base_isd(cube, ikid)
    frames = lines // int(per_framelet)
    end = start_time + frames * interframe_delay
    for key in ("instrument_pointing", "instrument_position"):
        times = isd[key]["ephemeris_times"]
        if start_time < times[0] - interframe_delay or end > times[-1] + interframe_delay:
            raise cube.error(
                f"the cube's framelets are exposed over ET [{start_time:.6f}, {end:.6f}], "
                f"beyond its {key} table's [{times[0]:.6f}, {times[-1]:.6f}] (never "
                "extrapolated)"
            )
    isd.update(
        name_model="USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL",
        starting_ephemeris_time=start_time,
        ending_ephemeris_time=end,
        center_ephemeris_time=(start_time + end) / 2.0,
        exposure_duration=exposure,
        interframe_delay=interframe_delay,
        framelet_order_reversed=False,
        framelets_flipped=flipped,
        framelet_height=framelet_height,
        num_lines_overlap=0,
        detector_center={"line": center[0], "sample": center[1]},
        detector_sample_summing=summing,
        detector_line_summing=summing,
        starting_detector_sample=0.0,
        starting_detector_line=first_line,
    )
    return isd
