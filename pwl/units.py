"""Units of log channels: the conversions pwl knows, and nothing it guesses.

A unit is a symbol (as declared in a log, e.g. ``kPa``); every known symbol maps to its dimension
and the affine map to that dimension's SI unit, value_SI = value * scale + offset. A log channel
whose declared unit differs from the database's is converted when both are known and of one
dimension, and refused otherwise (:class:`UnitError` names the channel and both units); a channel
with no declared unit is taken as it is (its plausible range still applies).
"""
from __future__ import annotations

import numpy as np

from .errors import PwlError

_F = 5.0 / 9.0
#: symbol -> (dimension, scale, offset) to the dimension's SI unit
UNITS = {
    # temperature (K)
    "K": ("temperature", 1.0, 0.0), "degC": ("temperature", 1.0, 273.15), "C": ("temperature", 1.0, 273.15),
    "°C": ("temperature", 1.0, 273.15), "degR": ("temperature", _F, 0.0), "R": ("temperature", _F, 0.0),
    "degF": ("temperature", _F, 459.67 * _F), "F": ("temperature", _F, 459.67 * _F),
    "°F": ("temperature", _F, 459.67 * _F),
    # pressure (Pa)
    "Pa": ("pressure", 1.0, 0.0), "hPa": ("pressure", 100.0, 0.0), "mbar": ("pressure", 100.0, 0.0),
    "kPa": ("pressure", 1e3, 0.0), "MPa": ("pressure", 1e6, 0.0), "bar": ("pressure", 1e5, 0.0),
    "psi": ("pressure", 6894.757293168361, 0.0), "psia": ("pressure", 6894.757293168361, 0.0),
    "atm": ("pressure", 101325.0, 0.0), "inHg": ("pressure", 3386.389, 0.0),
    # mass flow (kg/s)
    "kg/s": ("mass flow", 1.0, 0.0), "kg/h": ("mass flow", 1.0 / 3600.0, 0.0),
    "g/s": ("mass flow", 1e-3, 0.0), "lb/s": ("mass flow", 0.45359237, 0.0),
    "lbm/s": ("mass flow", 0.45359237, 0.0), "lb/h": ("mass flow", 0.45359237 / 3600.0, 0.0),
    "lbm/h": ("mass flow", 0.45359237 / 3600.0, 0.0), "pph": ("mass flow", 0.45359237 / 3600.0, 0.0),
    # rotational speed (rpm)
    "rpm": ("rotational speed", 1.0, 0.0), "rad/s": ("rotational speed", 60.0 / (2.0 * np.pi), 0.0),
    # length (m)
    "m": ("length", 1.0, 0.0), "km": ("length", 1e3, 0.0), "ft": ("length", 0.3048, 0.0),
    # force (N)
    "N": ("force", 1.0, 0.0), "kN": ("force", 1e3, 0.0), "lbf": ("force", 4.4482216152605, 0.0),
    # time (s): a log's time column
    "s": ("time", 1.0, 0.0), "ms": ("time", 1e-3, 0.0), "us": ("time", 1e-6, 0.0), "µs": ("time", 1e-6, 0.0),
    "ns": ("time", 1e-9, 0.0), "min": ("time", 60.0, 0.0), "h": ("time", 3600.0, 0.0),
    "d": ("time", 86400.0, 0.0),     # days: a spreadsheet's serial date numbers (Excel: days from 1899-12-30)
    # ratios: percent and fraction are not interchangeable silently ("-" is also Mach's unit)
    "%": ("percent", 1.0, 0.0), "-": ("dimensionless", 1.0, 0.0),
}


#: other spellings of known symbols, as data systems write them (matched case-insensitively)
ALIASES = {"lb/hr": "lb/h", "lbs/hr": "lb/h", "lbs/h": "lb/h", "lbm/hr": "lb/h", "pps": "lb/s",
           "lbs/s": "lb/s", "kg/hr": "kg/h", "deg c": "degC", "deg f": "degF", "deg r": "degR",
           "°r": "degR", "°k": "K", "rev/min": "rpm", "sec": "s", "secs": "s", "seconds": "s",
           "msec": "ms", "hr": "h", "hours": "h", "mins": "min", "days": "d", "day": "d", "feet": "ft",
           "bara": "bar", "celsius": "degC", "deg_c": "degC", "deg.c": "degC", "degrees c": "degC",
           "fahrenheit": "degF", "deg_f": "degF", "deg.f": "degF", "degrees f": "degF", "kelvin": "K",
           "deg_k": "K", "rankine": "degR", "deg_r": "degR"}


def _folded() -> dict:
    """Case-folded symbol -> symbol; the table has no two symbols equal but for case (checked)."""
    out = {}
    for sym in UNITS:
        key = sym.casefold()
        assert key not in out, f"units {out.get(key)!r} and {sym!r} differ by case only"
        out[key] = sym
    return out | {k.casefold(): v for k, v in ALIASES.items()}


_FOLDED = _folded()


def known(unit: str) -> str | None:
    """The symbol of :data:`UNITS` a declared unit means: itself, else the same symbol in
    another case or spacing (``RPM``, ``KPA``, ``DEGC``) or a spelling of :data:`ALIASES`
    (``lb/hr``, ``deg C``); None for a unit pwl does not know."""
    if unit in UNITS:
        return unit
    return _FOLDED.get(unit.strip().casefold()) or _FOLDED.get("".join(unit.split()).casefold())


class UnitError(PwlError, ValueError):
    """A log channel's declared unit cannot be converted to the one the database uses."""


def converter(have: str, want: str, where: str = ""):
    """(scale, offset) with value_want = value_have * scale + offset; (1, 0) when the units are
    equal or ``have`` is not declared. Raises :class:`UnitError` naming ``where`` otherwise."""
    if not have or have == want or not want:
        return 1.0, 0.0
    a, b = UNITS.get(known(have)), UNITS.get(known(want))
    if a is None or b is None:
        unknown = have if a is None else want
        raise UnitError(f"{where}: unit {have!r} cannot be converted to {want!r} ({unknown!r} is not "
                        f"a unit pwl knows: {', '.join(UNITS)})")
    if a[0] != b[0]:
        hint = (f"; a channel map scales it: {{ column = ..., unit = {want!r}, scale = <{want} per {have}> }}"
                if a[0] in ("percent", "dimensionless") else "")
        raise UnitError(f"{where}: unit {have!r} ({a[0]}) cannot be converted to {want!r} ({b[0]}){hint}")
    return a[1] / b[1], (a[2] - b[2]) / b[1]


def likely_units(value: float, unit: str, lo: float, hi: float) -> list[str]:
    """The known units of ``unit``'s dimension in which a typical logged ``value`` would fall in
    the plausible range [lo, hi] of ``unit`` (``30000`` for an altitude in m: ``ft``); for a
    rotational speed of 0..120, percent of a reference speed. For the warning about a channel
    whose samples are nearly all implausible: most often a unit not declared."""
    dim = UNITS.get(known(unit) or "", ("",))[0]
    if not dim or not np.isfinite(value):
        return []
    out, seen = [], set()
    for u, (d, scale, offset) in UNITS.items():     # one symbol per conversion: degC, not C, °C
        a, b = converter(u, unit) if d == dim else (np.nan, np.nan)
        if u != unit and (scale, offset) not in seen and lo <= value * a + b <= hi:
            out.append(u)
            seen.add((scale, offset))
    if dim == "rotational speed" and 0.0 < value <= 120.0:
        out.append("% of a reference speed (a channel map's scale)")
    return out


def implausible_hint(value: float, unit: str, lo: float, hi: float) -> str:
    """Why a channel's typical implausible ``value`` is outside its plausible [lo, hi] ``unit``:
    a "no data" code (all nines: -9999), else the units it would be plausible in
    (:func:`likely_units`: a unit not declared), else infinite values, a value below the range (the engine not running, a failed sensor) or above
    it. The end of the warnings that name such a channel (a log's, a snapshot table's)."""
    if abs(value) >= 99 and set(f"{abs(value):.6g}") <= {"9", "."}:      # -9999, 99999, -999.9 ...
        return f"{value:.6g} is a 'no data' code of the writer?"
    guess = likely_units(value, unit, lo, hi)
    if guess:
        return (f"logged in {' or '.join(guess)}? Declare the unit (a 'name[unit]' column, a row of units or a "
                "channel map)")
    return ("infinite values or spikes: a failed sensor, or a logger's overflow?" if np.isinf(value) else
            "the engine not running, or a failed sensor?" if value < lo else "a unit mistake or a failed sensor?")
