"""Output resolutions with units: parsing (``5m``, ``0.0003deg``, a bare number in the CRS's
units), the clean values a default resolution is rounded to, the conversion into a CRS's units,
and the check that catches a resolution given in the wrong units (30 meant as metres on a
degree CRS) before anything is planned.

Lengths on the ground convert to CRS units nominally: a projected CRS by its axis unit
(metres, feet; the projection's scale factor is left out), a geographic CRS by the body's
equatorial radius (one degree is ``a * pi / 180`` metres, in longitude as in latitude:
square in degrees, as gdalwarp and ASP's mapproject take a resolution), so that far from the
equator the posts crowd east-west; :func:`east_west_text` warns of it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from orthomvp.errors import InputError

if TYPE_CHECKING:
    from pyproj import CRS
    from rasterio.crs import CRS as FileCRS

UNITS: dict[str, tuple[str, float]] = {
    "m": ("m", 1.0),
    "cm": ("m", 0.01),
    "mm": ("m", 0.001),
    "km": ("m", 1000.0),
    "deg": ("deg", 1.0),
    "arcmin": ("deg", 1 / 60),
    "arcsec": ("deg", 1 / 3600),
}
"""Unit suffixes a resolution takes: each as metres ("m") or degrees ("deg") times a factor."""

CLEAN = (1.0, 2.0, 2.5, 5.0)
"""The mantissas of clean resolutions: 1, 2, 2.5 and 5 times a power of ten (metres)."""

FINEST_METRES = 1e-3
"""A resolution finer than this on the ground (metres) is refused as a mistake of units."""

_LENGTH = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-z]*)\s*$")


@dataclass(frozen=True)
class Length:
    """A resolution as given: ``value`` in ``unit`` ("m", "deg", or None for the CRS's own
    units), already scaled by its suffix (``2km`` is 2000 m); ``text`` as written."""

    value: float
    unit: str | None
    text: str


def parse_length(value: object) -> Length:
    """A positive finite resolution: a number (the CRS's units) or a string with an optional
    unit suffix of :data:`UNITS` (``"5m"``, ``"0.0003deg"``, ``"2 km"``, ``"1.5arcsec"``);
    InputError otherwise."""
    if isinstance(value, bool):
        raise InputError(f"resolution must be a number or a length such as '5m', got {value!r}")
    if isinstance(value, int | float):
        number, unit, text = float(value), None, f"{value:g}"
    elif isinstance(value, str) and (match := _LENGTH.match(value.lower())):
        suffix = match.group(2)
        if suffix and suffix not in UNITS:
            raise InputError(
                f"resolution {value!r}: unknown unit {suffix!r}; give one of "
                f"{', '.join(UNITS)}, or a bare number in the CRS's units"
            )
        number, text = float(match.group(1)), value.strip()
        unit, scale = UNITS[suffix] if suffix else (None, 1.0)
        number *= scale
    else:
        try:  # numpy scalars and the like
            number, unit, text = float(value), None, f"{float(value):g}"  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise InputError(
                f"resolution must be a number or a length such as '5m' or '0.0003deg', "
                f"got {value!r}"
            ) from None
    if not (math.isfinite(number) and number > 0):
        raise InputError(f"resolution must be positive and finite, got {text}")
    return Length(number, unit, text)


def parse_res(res: object) -> tuple[Length, Length] | None:
    """``res`` as (x, y) lengths: None, one value for both axes, or a pair (see
    :func:`parse_length`)."""
    if res is None:
        return None
    if isinstance(res, str | int | float) or not isinstance(res, Sequence):
        one = parse_length(res)
        return one, one
    if len(res) == 1:
        return parse_length(res[0]), parse_length(res[0])
    if len(res) != 2:
        raise InputError(f"resolution must be one value or two (x, y), got {len(res)}")
    return parse_length(res[0]), parse_length(res[1])


def clean_metres(metres: float) -> float:
    """The clean value nearest ``metres`` on a logarithmic scale: 1, 2, 2.5 or 5 times a power
    of ten (5.6 -> 5, 31 -> 25, 0.37 -> 0.5)."""
    if not (math.isfinite(metres) and metres > 0):
        raise InputError(f"a ground sample distance must be positive, got {metres}")
    power = math.floor(math.log10(metres))
    candidates = [m * 10.0**k for k in (power - 1, power, power + 1) for m in CLEAN]
    return min(candidates, key=lambda c: abs(math.log(c / metres)))


def unit_scale(crs: CRS | FileCRS, radius: float) -> tuple[float, str]:
    """Metres on the ground per unit of ``crs`` (nominal: see the module docstring) and the
    unit's name; ``radius``: the body's equatorial radius, metres. ``crs`` as pyproj or
    rasterio gives it (a file's CRS needs no pyproj: its import takes about 45 ms)."""
    if hasattr(crs, "units_factor"):  # rasterio's (GDAL's) view
        unit_name, factor = crs.units_factor
    else:
        axis = crs.axis_info[0]
        unit_name, factor = axis.unit_name, axis.unit_conversion_factor
    factor = float(factor)
    if crs.is_geographic:  # the conversion factor is radians per unit
        name = "degrees" if math.isclose(factor, math.pi / 180) else _plural(unit_name)
        return radius * factor, name
    return factor, "m" if math.isclose(factor, 1.0) else _plural(unit_name)


def check_latitudes(bounds: tuple[float, float, float, float], crs: CRS | FileCRS) -> None:
    """InputError, one line, when ``bounds`` (left, bottom, right, top in the units of ``crs``)
    on a geographic ``crs`` put the bottom or the top beyond a pole: bounds given in metres,
    say, where the CRS counts degrees."""
    if not crs.is_geographic:
        return
    per_unit, unit = unit_scale(crs, 1.0)  # (radians per unit)
    pole = math.pi / 2 / per_unit
    for latitude in (bounds[1], bounds[3]):
        if abs(latitude) > pole * (1 + 1e-12):
            raise InputError(
                f"bounds: latitude {latitude:.10g} lies outside +-{pole:g} {unit}: bounds "
                f"(left bottom right top) are in the output CRS's units, {unit} here (for "
                "metres, choose a projected output CRS)"
            )


EAST_WEST_SHARE = 0.5
"""A grid of a geographic CRS whose posts lie this share of their north-south spacing apart
east-west, or closer, at its centre (beyond latitude 60) is warned about
(:func:`east_west_text`)."""


def east_west_text(
    res: tuple[float, float], latitude: float, crs: CRS | FileCRS, radius: float
) -> str | None:
    """The warning for a grid of post spacing ``res`` (x, y; units of ``crs``) centred at
    ``latitude`` (the CRS's units) on a geographic ``crs`` whose posts lie
    :data:`EAST_WEST_SHARE` of their north-south spacing apart east-west or closer (a spacing
    in metres converts to degrees at the equator, as gdalwarp and ASP's mapproject take it:
    square in degrees); None otherwise. It gives the spacing in degrees that would make the
    posts square on the ground there, and the projected alternative."""
    if not crs.is_geographic:
        return None
    per_unit, unit = unit_scale(crs, 1.0)  # (radians per unit)
    cos = math.cos(latitude * per_unit)
    if not cos < EAST_WEST_SHARE * res[1] / res[0]:
        return None
    metres = radius * per_unit
    east, north = res[0] * metres * cos, res[1] * metres
    degrees = per_unit * 180 / math.pi  # (degrees per unit)
    square = res[1] / max(cos, 1e-12) * degrees
    return (
        f"the output grid is centred at latitude {latitude:.4g} {unit} of a geographic CRS, "
        f"where its posts lie {_metres_text(east)} apart east-west and {_metres_text(north)} "
        "north-south (metres convert to degrees at the equator): for square posts give "
        f"--res {square:.3g}deg {res[1] * degrees:.3g}deg, "
        f"or --crs with a polar stereographic CRS of the body (+proj=stere +lat_0="
        f"{90 if latitude > 0 else -90})"
    )


def _plural(name: str) -> str:
    """The plural of a unit's name as PROJ and GDAL spell it: "US survey foot" -> "US survey
    feet", "British yard (Sears 1922)" -> "British yards (Sears 1922)", "grad" -> "grads"."""
    head, space, qualifier = name.partition(" (")
    if head.endswith("foot"):
        head = f"{head[: -len('foot')]}feet"
    elif not head.endswith("s"):
        head = f"{head}s"
    return f"{head}{space}{qualifier}"


def to_units(
    lengths: tuple[Length, Length], crs: CRS | FileCRS, radius: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """``lengths`` in the units of ``crs`` (x, y), and on the ground in metres (x, y)."""
    per_unit, _ = unit_scale(crs, radius)
    per_degree = radius * math.pi / 180
    units, metres = [], []
    for length in lengths:
        if length.unit is None:
            m = length.value * per_unit
        else:
            m = length.value * (per_degree if length.unit == "deg" else 1.0)
        units.append(m / per_unit)
        metres.append(m)
    return (units[0], units[1]), (metres[0], metres[1])


def check_res(
    lengths: tuple[Length, Length],
    metres: tuple[float, float],
    crs: CRS | FileCRS,
    radius: float,
    extent_metres: float,
) -> None:
    """InputError, one line saying what the resolution means and what was probably meant,
    when it is finer than :data:`FINEST_METRES` or wider than the DEM's ``extent_metres``
    (fewer than two posts across: 30 on a degree CRS, meant as metres)."""
    per_unit, unit = unit_scale(crs, radius)
    for length, m in zip(lengths, metres, strict=True):
        meaning = f"{length.text}" + (f" ({unit}: the CRS's units)" if length.unit is None else "")
        if m < FINEST_METRES:
            hint = "give a unit, e.g. 5m"
            if length.unit is None and not crs.is_geographic:
                degrees = length.value * radius * math.pi / 180
                hint = f"probably meant degrees: {length.value:g}deg, {_metres_text(degrees)}"
            raise InputError(
                f"resolution {meaning} is {_metres_text(m)} on the ground, finer than a "
                f"millimetre: {hint}"
            )
        if m > extent_metres:
            hint = "give a smaller value with its unit, e.g. 5m"
            if length.unit is None and crs.is_geographic:
                as_units = length.value / per_unit
                hint = f"probably meant metres: {length.value:g}m ({as_units:.3g} {unit})"
            raise InputError(
                f"resolution {meaning} is {_metres_text(m)} on the ground, more than the DEM's "
                f"whole extent ({_metres_text(extent_metres)}): {hint}"
            )


def _metres_text(m: float) -> str:
    """A ground distance in km, m, cm or mm, three significant figures."""
    for unit, scale in (("km", 1e3), ("m", 1.0), ("cm", 1e-2)):
        if m >= scale:
            return f"{m / scale:.3g} {unit}"
    return f"{m / 1e-3:.3g} mm"
