"""Times of the cube reader: label UTC to ephemeris time (TDB seconds past J2000) as SPICE's
``str2et`` does with NAIF's leap-second kernel naif0012, without SPICE. Spacecraft clock
strings are not here: their ETs are the cube's ``NaifKeywords`` (:meth:`.core.SpiceCube.clock_et`).
"""

from __future__ import annotations

import datetime as dt
import math

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
