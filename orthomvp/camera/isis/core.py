"""The cube reader's view of one cube: a spiceinit'd ISIS3 cube's label, ``NaifKeywords``,
clock times and AlphaCube (:class:`SpiceCube`; its tables are read by the
:class:`~.tables.TableReader` it inherits), and the :class:`Instrument` record each instrument
module fills in.

Conventions (ISIS's and ALE's, checked on real cubes):

- Times: ephemeris seconds past J2000 (TDB). ``NaifKeywords`` ``CLOCK_ET_<id>_<clock>_COMPUTED``
  holds the ET of a clock string as 16 hex digits of a little-endian IEEE double; label UTC
  becomes ET with the leap-second table (:func:`~.times.utc_to_et`).
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

from orthomvp.camera.isis.tables import NO_SPICE, TableReader, _item
from orthomvp.camera.isis.times import utc_to_et
from orthomvp.errors import FormatError
from orthomvp.io.isis import cached_label, label_text


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


class SpiceCube(TableReader):
    """The camera-related content of an ISIS3 cube: its label, ``NaifKeywords``, tables,
    AlphaCube and size. Errors are one-line FormatErrors naming the file and the key."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.text = label_text(self.path)
        self.label = cached_label(self.path, self.text)
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
