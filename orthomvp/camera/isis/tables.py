"""The binary SPICE tables spiceinit attaches to a cube, read into the ISD's rotations and
positions (ALE's keys, as :mod:`orthomvp.camera.csm.isd` reads them): the :class:`Table`
records, their polynomial cache form, and :class:`TableReader`, the table half of
:class:`~.core.SpiceCube`.

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
- Times: ephemeris seconds past J2000 (TDB).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from orthomvp.camera.csm.ephemeris import matrix_wxyz
from orthomvp.io.isis import read_section

ISD_ROUTE = "give an ISD from ALE's isd_generate instead"
NO_SPICE = "run spiceinit (attach=yes), or give an ISD from ALE's isd_generate"

_FIELD_TYPES = {"double": ("f8", 8), "integer": ("i4", 4), "real": ("f4", 4), "text": ("S", 1)}


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


def _item(node: Any, key: str, kind: type | None = None) -> Any:
    """``node``'s first item ``key`` (case-insensitive; of type ``kind``), units dropped; None
    if absent."""
    for name, value in node.items():
        if name.casefold() == key.casefold() and (kind is None or isinstance(value, kind)):
            return value.value if hasattr(value, "units") and hasattr(value, "value") else value
    return None


class TableReader:
    """The tables of a cube: the half of :class:`~.core.SpiceCube` that reads them, which
    gives it ``path``, ``label``, ``error``, ``group`` and ``_finite``."""

    path: Path
    label: Any

    def table(self, name: str, *, missing: str | None = None) -> Table:
        """The attached table ``name``; FormatError for one that is absent (``missing``: what
        to say then; by default run spiceinit, or attach the kernels it names), described
        badly, or truncated."""
        for key, node in self.label.items():
            if key.casefold() == "table" and str(_item(node, "Name")) == name:
                return self._read_table(name, node)
        if missing is not None:
            raise self.error(f"no Table {name}: {missing}")
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
