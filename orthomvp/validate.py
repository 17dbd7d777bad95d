"""Argument checks shared by the library's functions and option objects, so that the Python API
refuses what the command line refuses, with an :class:`~orthomvp.errors.InputError` that names
the argument and its valid range."""

from __future__ import annotations

import math
import numbers
from typing import Any

from orthomvp.errors import InputError


def of_type(value: Any, types: type | tuple[type, ...], what: str, hint: str = "") -> Any:
    """``value`` when it is an instance of ``types``; InputError otherwise."""
    if not isinstance(value, types):
        names = " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))
        article = "an" if names[0] in "AEIOU" else "a"
        raise InputError(
            f"{what} must be {article} {names}{hint}, got {type(value).__name__} {_short(value)}"
        )
    return value


def number(
    value: Any,
    what: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    min_open: bool = False,
    integer: bool = False,
) -> Any:
    """``value`` when it is a finite real number (an integer, or a float with an integer value,
    if ``integer``; booleans and strings are not numbers) within [``minimum``, ``maximum``]
    (``minimum`` excluded when ``min_open``); InputError naming ``what`` and the range
    otherwise. Returns an int or a float."""
    whole = isinstance(value, numbers.Integral) or (
        isinstance(value, numbers.Real) and float(value).is_integer()
    )
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or (integer and not whole):
        noun = "an integer" if integer else "a number"
        raise InputError(f"{what} must be {noun}, got {type(value).__name__} {_short(value)}")
    result = int(value) if integer else float(value)
    too_low = minimum is not None and (result <= minimum if min_open else result < minimum)
    too_high = maximum is not None and result > maximum
    if not math.isfinite(result) or too_low or too_high:
        raise InputError(f"{what} must be {range_text(minimum, maximum, min_open)}, got {value}")
    return result


def range_text(minimum: float | None, maximum: float | None, min_open: bool = False) -> str:
    """``"> 0"``, ``">= 1"``, ``"in [-1, 1]"``, ``"finite"``."""
    if minimum is not None and maximum is not None:
        return f"in {'(' if min_open else '['}{minimum:g}, {maximum:g}]"
    if minimum is not None:
        return f"{'>' if min_open else '>='} {minimum:g}"
    if maximum is not None:
        return f"<= {maximum:g}"
    return "finite"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
