"""The shared core of the cube reader: a spiceinit'd ISIS3 cube's label, ``NaifKeywords``,
binary SPICE tables, AlphaCube and times, turned into the parts of a USGS CSM ISD (ALE's
keys, as :mod:`orthomvp.camera.csm.isd` reads them).

Conventions (ISIS's and ALE's, checked on real cubes):

- Tables: ``InstrumentPointing`` and ``BodyRotation`` hold quaternions ``J2000Q0..Q3``
  (scalar first), each the rotation from J2000 into the table's frame (its
  ``TimeDependentFrames[0]``), optional angular velocities ``AV1..3`` (rad/s) and times ``ET``;
  a label ``ConstantRotation`` (9 numbers, row-major) then takes that frame to
  ``ConstantFrames[0]``. ``InstrumentPosition`` and ``SunPosition`` hold target-centred J2000
  positions ``J2000X..Z`` (km), velocities ``J2000XV..ZV`` (km/s) and ``ET``.
- The polynomial cache: rotations as coefficients of ZXZ Euler angles ``J2000Ang1..3`` (rad),
  positions as coefficients of ``J2000SVX..Z`` (km), in t = (ET - base) / scale, the last record
  holding (base, scale, degree); they are evaluated, as ALE does, at the ``Ck``/``SpkTable``
  ``OriginalSize`` times spread evenly from ``...StartTime`` to ``...EndTime``.
- Times: ephemeris seconds past J2000 (TDB). ``NaifKeywords`` ``CLOCK_ET_<id>_<clock>_COMPUTED``
  holds the ET of a clock string as 16 hex digits of a little-endian IEEE double; label UTC
  becomes ET with the leap-second table (:func:`utc_to_et`).
- AlphaCube: cube pixel (1-based) beta maps to the original image's alpha =
  slope (beta - 0.5) + AlphaStarting, slope = (AlphaEnding - AlphaStarting) / Beta (any real
  reduction factor).
"""

from __future__ import annotations

import datetime as dt
import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera.csm.ephemeris import Orientations, hermite_states, matrix_wxyz
from orthomvp.errors import FormatError, InputError
from orthomvp.io.isis import label_text, parse_label, read_section

ISD_ROUTE = "give an ISD from ALE's isd_generate instead"
NO_SPICE = "run spiceinit (attach=yes), or give an ISD from ALE's isd_generate"
TABLES = ("InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition")
"""The tables spiceinit attaches (attach=yes)."""

_FIELD_TYPES = {"double": ("f8", 8), "integer": ("i4", 4), "real": ("f4", 4), "text": ("S", 1)}
_SINGLE_RECORD_SLACK = 0.01  # s: a one-record table serves an image time this close to its own

# NAIF's leap-second kernel (naif0012.tls): TAI - UTC (s) from each date (UTC midnight) on;
# before the first date SPICE takes one second less.
_LEAP_DATES = (
    "1972-01-01 1972-07-01 1973-01-01 1974-01-01 1975-01-01 1976-01-01 1977-01-01 1978-01-01 "
    "1979-01-01 1980-01-01 1981-07-01 1982-07-01 1983-07-01 1985-07-01 1988-01-01 1990-01-01 "
    "1991-01-01 1992-07-01 1993-07-01 1994-07-01 1996-01-01 1997-07-01 1999-01-01 2006-01-01 "
    "2009-01-01 2012-07-01 2015-07-01 2017-01-01"
).split()
_J2000 = dt.datetime(2000, 1, 1, 12, 0, 0)
_LEAPS = tuple(
    ((dt.datetime.fromisoformat(d) - _J2000).total_seconds(), 10 + i)
    for i, d in enumerate(_LEAP_DATES)
)
_TT_TAI, _K, _EB, _M0, _M1 = 32.184, 1.657e-3, 1.671e-2, 6.239996, 1.99096871e-7


def utc_to_et(utc: str) -> float:
    """Ephemeris time (TDB seconds past J2000) of an ISO UTC string (``2010-11-09T13:06:40.356``,
    a trailing ``Z`` allowed), as SPICE's ``str2et`` with the leap-second kernel naif0012:
    ET = UTC + (TAI - UTC) + 32.184 + K sin(E), E = M + EB sin M, M = M0 + M1 (TT - J2000)."""
    when = dt.datetime.fromisoformat(utc.strip().rstrip("Zz"))
    if when.tzinfo is not None:
        when = when.astimezone(dt.timezone.utc).replace(tzinfo=None)
    seconds = (when - _J2000).total_seconds()
    delta_at = _LEAPS[0][1] - 1
    for start, value in _LEAPS:
        if seconds >= start:
            delta_at = value
    tt = seconds + delta_at + _TT_TAI
    m = _M0 + _M1 * tt
    return tt + _K * math.sin(m + _EB * math.sin(m))


def _euler_zxz_matrices(a1: np.ndarray, a2: np.ndarray, a3: np.ndarray) -> np.ndarray:
    """SPICE ``eul2m(a3, a2, a1, 3, 1, 3)``: [a3]_3 [a2]_1 [a1]_3, each [a]_i the frame
    rotation by a about axis i; (n, 3, 3)."""

    def frame(angle: np.ndarray, axis: int) -> np.ndarray:
        c, s = np.cos(angle), np.sin(angle)
        m = np.zeros(angle.shape + (3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        m[:, axis, axis] = 1.0
        m[:, i, i], m[:, j, j], m[:, i, j], m[:, j, i] = c, c, s, -s
        return m

    return frame(a3, 2) @ frame(a2, 0) @ frame(a1, 2)


@dataclass(frozen=True)
class Table:
    """An ISIS binary table: its ``name``, the label ``keywords`` of its Table object (fields
    excluded) and its ``columns`` (field name -> (records,) or (records, size) array)."""

    name: str
    keywords: dict[str, Any]
    columns: dict[str, np.ndarray]

    @property
    def records(self) -> int:
        """The number of records."""
        return len(next(iter(self.columns.values())))


@dataclass(frozen=True)
class AlphaCube:
    """A cube's place in its original image (ISIS's AlphaCube group): 1-based alpha =
    slope (beta - 0.5) + start, per axis; the identity for a cube that is the whole image."""

    samples: float
    lines: float
    start_sample: float = 0.5
    start_line: float = 0.5
    sample_slope: float = 1.0
    line_slope: float = 1.0

    def full_sample(self, csm_sample: float) -> float:
        """The original image's CSM sample (0.5 = the first pixel's centre) of this cube's."""
        return self.sample_slope * csm_sample + self.start_sample - 0.5

    def full_line(self, csm_line: float) -> float:
        """The original image's CSM line of this cube's."""
        return self.line_slope * csm_line + self.start_line - 0.5


@dataclass(frozen=True)
class Instrument:
    """A camera the reader knows: ``name`` for messages, the (``SpacecraftName``,
    ``InstrumentId``) pairs of the label's Instrument group that select it (compared as
    :func:`instrument_key` has them), ``isd``: the ISD (a dict) of a cube, and
    ``distortion``: the lens model to use instead of the ISD's, for models usgscsm lacks (None:
    the ISD's)."""

    name: str
    ids: tuple[tuple[str, str], ...]
    isd: Callable[[SpiceCube], dict[str, Any]]
    distortion: Callable[[SpiceCube], Any] | None = None


def instrument_key(spacecraft: str, instrument: str) -> tuple[str, str]:
    """The (spacecraft, instrument id) pair as ISIS's camera factory compares them: upper case,
    without spaces or underscores."""
    return tuple(re.sub(r"[\s_]", "", str(v)).upper() for v in (spacecraft, instrument))


def _item(node: Any, key: str, kind: type | None = None) -> Any:
    """``node``'s first item ``key`` (case-insensitive; of type ``kind``), units dropped; None
    if absent."""
    for name, value in node.items():
        if name.casefold() == key.casefold() and (kind is None or isinstance(value, kind)):
            return value.value if hasattr(value, "units") and hasattr(value, "value") else value
    return None


class SpiceCube:
    """The camera-related content of an ISIS3 cube: its label, ``NaifKeywords``, tables,
    AlphaCube and size. Errors are one-line FormatErrors naming the file and the key."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.text = label_text(self.path)
        self.label = parse_label(self.path, self.text)
        cube = _item(self.label, "IsisCube", dict)
        if cube is None:
            raise self.error("the label has no Object = IsisCube")
        self.cube = cube

    def error(self, message: str) -> FormatError:
        """A FormatError naming the cube."""
        return FormatError(self.path, message)

    def group(self, name: str) -> Any | None:
        """The ``IsisCube`` group ``name``, or None."""
        return _item(self.cube, name, dict)

    def keyword(self, group: str, key: str) -> Any:
        """The value of ``IsisCube > Group = group`` ``key``; FormatError naming both if absent."""
        node = self.group(group)
        value = None if node is None else _item(node, key)
        if value is None:
            raise self.error(f"the label lacks {group} {key} (IsisCube > Group = {group})")
        return value

    def number(self, group: str, key: str) -> float:
        """The number ``group`` ``key``; FormatError if absent or not a finite number."""
        return self._finite(self.keyword(group, key), f"{group} {key}")

    def _finite(self, value: Any, what: str) -> float:
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise self.error(f"{what} = {value!r} is not a finite number")
        return float(value)

    @cached_property
    def size(self) -> tuple[int, int]:
        """(samples, lines) of the cube."""
        core = _item(self.cube, "Core", dict)
        dims = None if core is None else _item(core, "Dimensions", dict)
        if dims is None:
            raise self.error("the label lacks IsisCube > Core > Group = Dimensions")
        size = _item(dims, "Samples"), _item(dims, "Lines")
        if not all(isinstance(n, int) and n > 0 for n in size):
            raise self.error(f"Dimensions Samples, Lines = {size} are not positive integers")
        return size

    # NaifKeywords --------------------------------------------------------------------------

    @cached_property
    def naif_keywords(self) -> dict[str, Any]:
        """The ``NaifKeywords`` object; FormatError (run spiceinit) if absent."""
        node = _item(self.label, "NaifKeywords", dict)
        if node is None:
            raise self.error(f"no Object = NaifKeywords: no SPICE attached: {NO_SPICE}")
        return dict(node.items())

    def naif(self, key: str) -> Any:
        """``NaifKeywords`` ``key``; FormatError naming it if absent."""
        if key not in self.naif_keywords:
            raise self.error(f"NaifKeywords lacks {key}")
        return self.naif_keywords[key]

    def naif_number(self, key: str, index: int | None = None) -> float:
        """The number ``NaifKeywords`` ``key`` (its ``index``-th value for an array)."""
        value = self.naif(key)
        if index is not None:
            if not isinstance(value, list | tuple) or len(value) <= index:
                raise self.error(f"NaifKeywords {key} has no value {index + 1}")
            value = value[index]
        return self._finite(value, f"NaifKeywords {key}")

    def naif_array(self, key: str, count: int) -> list[float]:
        """The ``count`` numbers of ``NaifKeywords`` ``key``."""
        value = self.naif(key)
        if not isinstance(value, list | tuple) or len(value) != count:
            raise self.error(f"NaifKeywords {key} must hold {count} numbers, got {value!r}")
        return [self._finite(v, f"NaifKeywords {key}") for v in value]

    def clock_et(self, clock: str) -> float:
        """The ET of spacecraft clock string ``clock``: ``NaifKeywords``
        ``CLOCK_ET_<id>_<clock>_COMPUTED``, 16 hex digits of a little-endian double (read from
        the label's text: PVL readers drop leading zeros and may take the digits for a number)."""
        self.naif_keywords  # noqa: B018 (no NaifKeywords: the run-spiceinit error)
        key = rf"CLOCK_ET_\S*?_{re.escape(str(clock))}_COMPUTED"
        match = re.search(rf"^\s*({key})\s*=\s*\"?([0-9A-Fa-f]+)\"?\s*$", self.text, re.MULTILINE)
        if match is None:
            raise self.error(f"NaifKeywords lacks CLOCK_ET_<id>_{clock}_COMPUTED")
        digits = match.group(2).zfill(16)
        if len(digits) != 16:
            raise self.error(f"NaifKeywords {match.group(1)} = {digits!r} is not 16 hex digits")
        value = struct.unpack("<d", bytes.fromhex(digits))[0]
        return self._finite(value, f"NaifKeywords {match.group(1)}")

    def utc(self, group: str, key: str) -> float:
        """The ET of the label's UTC ``group`` ``key``."""
        value = self.keyword(group, key)
        text = value.isoformat() if isinstance(value, dt.datetime | dt.date) else str(value)
        try:
            return utc_to_et(text)
        except ValueError:
            raise self.error(f"{group} {key} = {text!r} is not a UTC time") from None

    @cached_property
    def radii(self) -> dict[str, Any]:
        """The ISD ``radii`` (km) from ``NaifKeywords`` ``BODY<code>_RADII``."""
        keys = [k for k in self.naif_keywords if re.fullmatch(r"BODY-?\d+_RADII", k)]
        if not keys:
            raise self.error("NaifKeywords lacks BODY<code>_RADII")
        radii = self.naif_array(keys[0], 3)
        return {"semimajor": radii[0], "semiminor": radii[2], "unit": "km"}

    # tables --------------------------------------------------------------------------------

    def table(self, name: str) -> Table:
        """The attached table ``name``; FormatError for one that is absent (run spiceinit, or
        attach the kernels it names), described badly, or truncated."""
        for key, node in self.label.items():
            if key.casefold() == "table" and str(_item(node, "Name")) == name:
                return self._read_table(name, node)
        kernels = self.group("Kernels")
        source = None if kernels is None else _item(kernels, name)
        values = source if isinstance(source, list | tuple) else [source]
        if source is not None and str(values[0]).casefold() != "table":
            named = ", ".join(str(v) for v in values)
            raise self.error(
                f"Table {name} is not attached: Kernels {name} points to kernels ({named}); "
                f"run spiceinit with attach=yes, or {ISD_ROUTE}"
            )
        raise self.error(f"no Table {name}: no SPICE attached: {NO_SPICE}")

    def _read_table(self, name: str, node: Any) -> Table:
        def need(key: str) -> Any:
            value = _item(node, key)
            if value is None:
                raise self.error(f"Table {name} lacks {key}")
            return value

        start, nbytes, records = int(need("StartByte")), int(need("Bytes")), int(need("Records"))
        order = "<" if str(_item(node, "ByteOrder") or "Lsb").casefold() == "lsb" else ">"
        fields = []
        for key, field in node.items():
            if key.casefold() != "field":
                continue
            kind = str(_item(field, "Type")).casefold()
            if kind not in _FIELD_TYPES:
                raise self.error(f"Table {name} field {_item(field, 'Name')}: type {kind!r}")
            code, width = _FIELD_TYPES[kind]
            size = int(_item(field, "Size") or 1)
            fmt = f"S{size}" if code == "S" else f"{order}{code}"
            fields.append(
                (str(_item(field, "Name")), fmt, () if code == "S" or size == 1 else (size,))
            )
        if not fields:
            raise self.error(f"Table {name} has no Field groups")
        dtype = np.dtype([(n, f, s) for n, f, s in fields])
        if records < 1 or nbytes < records * dtype.itemsize:
            raise self.error(
                f"Table {name}: {records} records of {dtype.itemsize} bytes do not fit its "
                f"Bytes = {nbytes}"
            )
        data = read_section(self.path, start - 1, records * dtype.itemsize)
        if len(data) < records * dtype.itemsize:
            raise self.error(
                f"truncated Table {name}: {records * dtype.itemsize} bytes expected from byte "
                f"{start}, the file holds {len(data)}"
            )
        rows = np.frombuffer(data, dtype)
        columns = {n: np.asarray(rows[n], dtype=np.float64) for n, f, _ in fields if f[0] != "S"}
        keywords = {k: v for k, v in node.items() if not isinstance(v, dict)}
        return Table(name, keywords, columns)

    def _column(self, table: Table, key: str) -> np.ndarray:
        if key not in table.columns:
            raise self.error(f"Table {table.name} lacks field {key}")
        values = table.columns[key]
        if not np.isfinite(values).all():
            raise self.error(f"Table {table.name} field {key} holds values that are not finite")
        return values

    def _label_number(self, table: Table, key: str) -> float:
        value = _item(table.keywords, key)
        if value is None:
            raise self.error(f"Table {table.name} lacks {key}")
        return self._finite(value, f"Table {table.name} {key}")

    def _cache_times(self, table: Table, prefix: str) -> np.ndarray:
        """The times at which ALE evaluates a polynomial cache (``prefix``: Ck or Spk)."""
        start = self._label_number(table, f"{prefix}TableStartTime")
        end = self._label_number(table, f"{prefix}TableEndTime")
        size = int(self._label_number(table, f"{prefix}TableOriginalSize"))
        if size < 1:
            raise self.error(f"Table {table.name} {prefix}TableOriginalSize must be >= 1")
        return np.linspace(start, end, size)

    def _polynomial(self, table: Table, names: tuple[str, ...], times: np.ndarray) -> np.ndarray:
        """Values (n, 3) and derivatives (n, 3) per second of a polynomial cache at ``times``."""
        coeffs = np.stack([self._column(table, n) for n in names], -1)
        if len(coeffs) < 2:
            raise self.error(f"Table {table.name}: a polynomial cache needs at least 2 records")
        base, scale = coeffs[-1, 0], coeffs[-1, 1]
        if scale == 0:
            raise self.error(f"Table {table.name}: the polynomial's time scale is 0")
        c = coeffs[:-1]
        t = (times - base) / scale
        powers = t[:, None] ** np.arange(len(c))
        dpowers = np.zeros_like(powers)
        dpowers[:, 1:] = np.arange(1, len(c)) * powers[:, :-1]
        return powers @ c, dpowers @ c / scale

    def rotation(self, name: str) -> dict[str, Any]:
        """An ISD rotation (``instrument_pointing``, ``body_rotation``) from table ``name``."""
        table = self.table(name)
        frames = _item(table.keywords, "TimeDependentFrames")
        out: dict[str, Any] = {"time_dependent_frames": list(frames or [])}
        if "J2000Q0" in table.columns:
            times = self._column(table, "ET")
            quats = np.stack([self._column(table, f"J2000Q{i}") for i in range(4)], -1)
            if "AV1" in table.columns:
                avs = np.stack([self._column(table, f"AV{i}") for i in (1, 2, 3)], -1)
                out["angular_velocities"] = avs.tolist()
        elif "J2000Ang1" in table.columns:
            times = self._cache_times(table, "Ck")
            angles, _ = self._polynomial(table, ("J2000Ang1", "J2000Ang2", "J2000Ang3"), times)
            matrices = _euler_zxz_matrices(angles[:, 0], angles[:, 1], angles[:, 2])
            quats = np.array([matrix_wxyz(m) for m in matrices])
        else:
            raise self.error(f"Table {name} holds neither J2000Q0..3 nor J2000Ang1..3")
        if (np.linalg.norm(quats, axis=1) == 0).any():
            raise self.error(f"Table {name} holds a zero quaternion")
        self._check_times(name, times)
        out["ephemeris_times"], out["quaternions"] = times.tolist(), quats.tolist()
        constant = _item(table.keywords, "ConstantRotation")
        if constant is not None:
            values = [self._finite(v, f"Table {name} ConstantRotation") for v in constant]
            if len(values) != 9:
                raise self.error(f"Table {name} ConstantRotation must hold 9 numbers")
            out["constant_frames"] = list(_item(table.keywords, "ConstantFrames") or [])
            out["constant_rotation"] = values
        out["reference_frame"] = 1
        return out

    def position(self, name: str) -> dict[str, Any]:
        """An ISD position (``instrument_position``, ``sun_position``) from table ``name``."""
        table = self.table(name)
        out: dict[str, Any] = {"unit": "km", "reference_frame": 1}
        if "J2000X" in table.columns:
            times = self._column(table, "ET")
            pos = np.stack([self._column(table, f"J2000{a}") for a in "XYZ"], -1)
            if "J2000XV" in table.columns:
                vel = np.stack([self._column(table, f"J2000{a}V") for a in "XYZ"], -1)
                out["velocities"] = vel.tolist()
        elif "J2000SVX" in table.columns:
            times = self._cache_times(table, "Spk")
            pos, vel = self._polynomial(table, ("J2000SVX", "J2000SVY", "J2000SVZ"), times)
            out["velocities"] = vel.tolist()
        else:
            raise self.error(f"Table {name} holds neither J2000X..Z nor J2000SVX..Z")
        self._check_times(name, times)
        out["ephemeris_times"], out["positions"] = times.tolist(), pos.tolist()
        return out

    def _check_times(self, name: str, times: np.ndarray) -> None:
        if (np.diff(times) <= 0).any():
            raise self.error(f"Table {name}: its times do not increase")

    @cached_property
    def spice(self) -> dict[str, dict[str, Any]]:
        """The ISD's ``instrument_pointing``, ``instrument_position``, ``body_rotation`` and
        ``sun_position`` from the cube's tables."""
        return {
            "instrument_pointing": self.rotation("InstrumentPointing"),
            "instrument_position": self.position("InstrumentPosition"),
            "body_rotation": self.rotation("BodyRotation"),
            "sun_position": self.position("SunPosition"),
        }

    # AlphaCube ----------------------------------------------------------------------------

    @cached_property
    def alpha(self) -> AlphaCube:
        """The cube's AlphaCube (the identity for a cube that is its whole image)."""
        samples, lines = self.size
        if self.group("AlphaCube") is None:
            return AlphaCube(float(samples), float(lines))

        def get(key: str) -> float:
            return self.number("AlphaCube", key)

        beta_s, beta_l = get("BetaSamples"), get("BetaLines")
        if (beta_s, beta_l) != (samples, lines):
            raise self.error(
                f"AlphaCube BetaSamples/BetaLines = {beta_s:g}/{beta_l:g} are not the cube's "
                f"size {samples}/{lines}"
            )
        s0, l0 = get("AlphaStartingSample"), get("AlphaStartingLine")
        slope_s = (get("AlphaEndingSample") - s0) / beta_s
        slope_l = (get("AlphaEndingLine") - l0) / beta_l
        if not (slope_s > 0 and slope_l > 0):
            raise self.error("AlphaCube: the ending sample and line must follow the starting ones")
        return AlphaCube(get("AlphaSamples"), get("AlphaLines"), s0, l0, slope_s, slope_l)


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
    start_time: float,
    line_rate: float,
    center: tuple[float, float],
    summing: float = 1.0,
    first_sample: float = 0.0,
) -> dict[str, Any]:
    """The ISD of a line scanner whose original image starts (the top edge of its first line,
    CSM line 0; ISIS's and ALE's start time) at ET ``start_time``, each line lasting
    ``line_rate`` seconds: detector ``center`` (line, sample), the instrument's cross-track
    ``summing`` and ``first_sample`` read out, the AlphaCube folded in (the cube's lines start
    later, and a reduced cube's lines last longer)."""
    if not line_rate > 0:
        raise cube.error(f"the line rate {line_rate!r} s is not positive")
    alpha = cube.alpha
    isd = base_isd(cube, ikid)
    rate = line_rate * alpha.line_slope
    start = start_time + alpha.full_line(0.0) * line_rate
    end = start + isd["image_lines"] * rate
    for key in ("instrument_pointing", "instrument_position"):
        times = isd[key]["ephemeris_times"]
        if start < times[0] - 0.5 * rate or end > times[-1] + 0.5 * rate:
            raise cube.error(
                f"the cube's lines are exposed over ET [{start:.6f}, {end:.6f}], beyond its "
                f"{key} table's [{times[0]:.6f}, {times[-1]:.6f}] (never extrapolated)"
            )
    middle = start + 0.5 * isd["image_lines"] * rate
    isd.update(
        name_model="USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL",
        interpolation_method="lagrange",
        line_scan_rate=[[0.5, start - middle, rate]],
        starting_ephemeris_time=start,
        center_ephemeris_time=middle,
        detector_center={"line": center[0], "sample": center[1]},
        detector_sample_summing=summing * alpha.sample_slope,
        detector_line_summing=summing,
        starting_detector_sample=summing * alpha.full_sample(0.0) + first_sample,
        starting_detector_line=0.0,
    )
    return isd
