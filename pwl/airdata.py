"""Air-data agreement: pressure altitude, flight Mach number and the inlet total pressure.

Pressure altitude fixes the ambient pressure (ICAO standard atmosphere, whatever the day's
temperature) and Mach the ram rise to the inlet's total pressure, so the three channels a flight
log carries for scheduling and correction must agree to within the inlet's pressure recovery and
the sensors' errors. A log where they do not has a wrong channel (Mach or altitude missing and
written as 0, a frozen word, a unit mistake, a geometric altitude far from the pressure altitude,
a lagging P2) that the filter would read as a change of the engine: the degraded demo flight with
Mach logged as 0 read Fn 88 % off and 85 % of its samples trusted; with Mach frozen for 2 minutes
of the climb, 11 % off.

:func:`air_data_channels` finds the three in a database's schedule (an altitude channel in a unit
of length, a channel named Mach, the delta channel of the theta/delta correction); a database
without them is not checked. :func:`disagree` tests samples (vectorised); :func:`lag_sums` and
:func:`lag` measure how far in time the inlet pressure runs behind the air data (a channel logged
late: P2 2 s late read Fn 3.3 % RMS off on the degraded demo flight, 0.23 % on time).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, vectorize

from .units import UnitError, converter, known

#: |ln(P2 / P2 expected)| above ln(1 + AIR_DATA_TOLERANCE) disagrees: 6 % is a Mach error of about
#: 0.06 at Mach 0.8, an altitude error of about 400 m at 10 km (1.1 km at sea level). The demo
#: plant's inlet recovery is 0.995, and its flights (and the seed-7 fleet's) stay within 0.990-1.000
#: of full recovery; a flight-test P2 sensor is good to 1 %. Mach frozen for 2 minutes of the
#: demo climb drifts more than 6 % off on 83 % of that time (8 %: 45 %); a whole flight logged
#: 300 m below its pressure altitude, harmless to the estimates (the correction reads P2), is off
#: by at most 5.2 % (5 % flagged its cruise)
AIR_DATA_TOLERANCE = 0.06

#: The lag is fitted on the expected inlet pressure's rate of change over +-LAG_BASE s (long enough
#: that the air data's noise does not bias it, short against a climb's changes) and reported when
#: at least LAG_WARN s and LAG_SIGMAS standard errors. On the demo and seed-7 flights the fit gives
#: 0.000 +- 0.001 s; P2 logged 0.3 s late gives 0.30 s and reads Fn 0.63 % RMS off (0.23 % on time).
#: Altitude late by 1 s reads -1.3 s, Mach late by 1 s +0.35 s: the lag is between P2 and the
#: air data, which of them is late the data cannot tell
LAG_BASE, LAG_WARN, LAG_SIGMAS = 1.0, 0.25, 5.0

#: a logged inlet pressure whose median over a log is off the air data's (pressure altitude, Mach
#: and the plant's recovery) by more than this is biased (the runtime takes it from the air data
#: instead): the demo flights and 12 of a fleet (seed 9, ambient -10..+20 K) read within +-0.05 %
#: (the bins' resolution); P2 1.5 % low read HPT efficiency 1.9 points off, trusted. Bins of
#: ln(logged / air data), 0.1 % wide, for that median
INLET_OFFSET = 0.01
INLET_BINS = np.linspace(-0.1, 0.1, 201)
#: pressure altitudes (m) below and above which the offset is measured apart: a scale error of
#: the inlet pressure is the same share at both, an altitude off by some metres is not
INLET_BANDS = np.array([3000.0, 6000.0])

_P_SL, _T_SL, _LAPSE, _G, _R = 101325.0, 288.15, 0.0065, 9.80665, 287.05287
_H_TROP, _P_TROP, _T_TROP = 11000.0, 22632.06, 216.65
_GAMMA = 1.4


@njit(cache=True, nogil=True)
def _isa(alt_m):
    if alt_m <= _H_TROP:
        return _P_SL * max(1.0 - _LAPSE * alt_m / _T_SL, 1e-9) ** (_G / (_LAPSE * _R))
    return _P_TROP * math.exp(-_G * (alt_m - _H_TROP) / (_R * _T_TROP))


@vectorize(["float64(float64)"], cache=True, nopython=True)
def isa_pressure(alt_m):
    """Ambient static pressure (Pa) of the ICAO standard atmosphere at pressure altitude ``alt_m``
    (m; troposphere and lower stratosphere, up to 20 km). A ufunc: arrays or scalars, and callable
    from numba code."""
    return _isa(alt_m)


@vectorize(["float64(float64, float64, float64)"], cache=True, nopython=True)
def ambient_offset(t_inlet, alt_m, mach):
    """The day's ambient temperature offset from the ICAO standard atmosphere (K): the static
    temperature the inlet's total temperature ``t_inlet`` (K) gives at flight Mach ``mach`` (ram
    rise 1 + (gamma - 1)/2 M^2, gamma 1.4) minus the standard temperature at pressure altitude
    ``alt_m`` (m; 6.5 K/km lapse to the tropopause at 11 km, 216.65 K above). A ufunc: arrays or
    scalars, and callable from numba code (the runtime's trims on hot and cold days)."""
    t_std = _T_SL - _LAPSE * min(alt_m, _H_TROP)
    return t_inlet / (1.0 + 0.5 * (_GAMMA - 1.0) * mach * mach) - t_std


@vectorize(["float64(float64, float64, float64)"], cache=True, nopython=True)
def inlet_temperature(alt_m, mach, offset):
    """The inlet total temperature (K) at pressure altitude ``alt_m`` (m) and flight Mach ``mach``
    on a day ``offset`` K off the standard atmosphere: the inverse of :func:`ambient_offset`. A
    ufunc, callable from numba code (a missing inlet temperature carried by the day)."""
    t_std = _T_SL - _LAPSE * min(alt_m, _H_TROP)
    return (t_std + offset) * (1.0 + 0.5 * (_GAMMA - 1.0) * mach * mach)


@vectorize(["float64(float64, float64)"], cache=True, nopython=True)
def inlet_pressure(alt_m, mach):
    """The inlet total pressure (Pa) of full ram recovery at pressure altitude ``alt_m`` (m) and
    flight Mach ``mach`` (subsonic isentropic compression, gamma 1.4). A ufunc."""
    return _isa(alt_m) * (1.0 + 0.5 * (_GAMMA - 1.0) * mach * mach) ** (_GAMMA / (_GAMMA - 1.0))


@vectorize(["boolean(float64, float64, float64, float64)"], cache=True, nopython=True)
def _disagree(alt_m, mach, p2, tolerance):
    want = inlet_pressure(alt_m, mach)
    if not (p2 > 0.0 and want > 0.0):       # missing (NaN) or not a pressure: no test
        return False
    return abs(math.log(p2 / want)) > math.log1p(tolerance)


def air_data_channels(schedule_channels, units: dict, delta_channel) -> tuple | None:
    """(altitude column, Mach column, altitude scale to m, delta channel's scale to Pa) when
    ``schedule_channels`` has an altitude channel (a unit of length), a channel named Mach (any
    case) and the inlet total pressure ``delta_channel`` is in a unit of pressure (``units``: the
    database's, channel -> unit); else None (no check)."""
    def scale(c, to):
        if known(units.get(c, "") or "") is None:
            return None
        try:
            k, offset = converter(units[c], to)
        except UnitError:
            return None
        return k if offset == 0.0 else None
    p_scale = scale(delta_channel, "Pa") if delta_channel else None
    mach = [j for j, c in enumerate(schedule_channels) if c.lower() == "mach"]
    alt = [(j, k) for j, c in enumerate(schedule_channels) if (k := scale(c, "m")) is not None]
    if p_scale is None or len(mach) != 1 or len(alt) != 1:
        return None
    return alt[0][0], mach[0], alt[0][1], p_scale


def disagree(alt_m, mach, p2, tolerance: float = AIR_DATA_TOLERANCE):
    """bool (array): the samples whose inlet total pressure ``p2`` (Pa) is off the one pressure
    altitude ``alt_m`` (m) and Mach ``mach`` give (:func:`inlet_pressure`) by more than
    ``tolerance`` (relative, on a log scale); a sample missing any of the three: False. Numba code
    calls the ufunc ``_disagree(alt_m, mach, p2, tolerance)`` (:class:`pwl.streaming.Stream`)."""
    return _disagree(alt_m, mach, p2, tolerance)


def pressure_altitude(p_static):
    """The ICAO standard atmosphere's pressure altitude (m) of static pressure ``p_static`` (Pa;
    the inverse of :func:`isa_pressure`, troposphere and lower stratosphere)."""
    p = np.asarray(p_static, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        low = _T_SL / _LAPSE * (1.0 - (p / _P_SL) ** (_LAPSE * _R / _G))
        high = _H_TROP + _R * _T_TROP / _G * np.log(_P_TROP / p)
    return np.where(p >= _P_TROP, low, high)


#: altitude units a log may be in while declared (or taken) in another: the factor the logged
#: altitude is then off by, what it is and the unit it is in (a recorder's flight level is in
#: hundreds of feet: no unit of pwl's)
_ALTITUDE_SLIPS = ((1.0 / 0.3048, "feet read as metres", "ft"), (0.3048, "metres read as feet", "m"),
                   (1e-3, "kilometres read as metres", "km"), (1e3, "metres read as kilometres", "m"),
                   (0.01, "a flight level (hundreds of feet) read as feet", ""),
                   (0.01 / 0.3048, "a flight level (hundreds of feet) read as metres", ""))


def altitude_slip(alt_m, mach, p2) -> tuple[str, str]:
    """(what an altitude that disagrees with the inlet pressure looks like, the unit it is in), or
    ('', '') if nothing: how the
    logged altitude ``alt_m`` (m, as converted) scales with the pressure altitude h that ``p2``
    (Pa) and ``mach`` give (full ram recovery): the slope of a straight line through them where h
    spans 500 m or more (its intercept takes the inlet's recovery and a static-pressure error up:
    a 0.5 % low P2 is 40 m at sea level), else their median ratio above 1 km; within 5 % of a unit
    slip of :data:`_ALTITUDE_SLIPS` (an altitude in feet declared in metres read 3.28 times the
    true one: 'a wrong, frozen or missing altitude or Mach?' said nothing of which)."""
    alt_m, mach, p2 = (np.asarray(v, dtype=np.float64) for v in (alt_m, mach, p2))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ram = (1.0 + 0.5 * (_GAMMA - 1.0) * mach * mach) ** (_GAMMA / (_GAMMA - 1.0))
        h = pressure_altitude(p2 / ram)
    ok = np.isfinite(alt_m) & np.isfinite(h)
    alt_m, h = alt_m[ok], h[ok]
    if h.size >= 5 and np.ptp(h) >= 500.0:
        ratio = float(np.polyfit(h, alt_m, 1)[0])
    elif np.count_nonzero(h > 1000.0) >= 5:
        ratio = float(np.median(alt_m[h > 1000.0] / h[h > 1000.0]))
    else:
        return "", ""
    for k, what, unit in _ALTITUDE_SLIPS:
        if abs(ratio / k - 1.0) < 0.05:
            return (f"the altitude reads {ratio:.3g} times the pressure altitude the inlet pressure and "
                    f"Mach give: {what}?", unit)
    return "", ""


def lag_sums(alt_m, mach, p2, dt: float, use=None, base: float = LAG_BASE) -> np.ndarray:
    """The sums (6,) over one stretch of samples from which :func:`lag` fits how late ``p2`` is
    against ``alt_m`` and ``mach`` (arrays (n,) in m, -, any pressure unit; ``dt`` s between
    samples; ``use`` (n,) bool: the samples to fit, default all): n, sum w, sum d, sum w^2,
    sum w d, sum d^2 with d = ln p2 - ln p_expected and w the rate of change of ln p_expected
    (1/s). Sums of several stretches (chunks of one log) add."""
    k = max(1, int(round(base / dt)))
    out = np.zeros(6)
    if len(p2) <= 2 * k:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        lw = np.log(inlet_pressure(alt_m, mach))
        w = (lw[2 * k:] - lw[:-2 * k]) / (2 * k * dt)
        d = np.log(p2[k:-k]) - lw[k:-k]
    ok = np.isfinite(w) & np.isfinite(d) & (True if use is None else use[k:-k])
    w, d = w[ok], d[ok]
    out[:] = len(w), w.sum(), d.sum(), w @ w, w @ d, d @ d
    return out


def lag(sums) -> tuple[float, float]:
    """(lag s, its standard error s) of the inlet pressure behind the air data, fitted by least
    squares d = c - lag * w on :func:`lag_sums`'s sums (a late P2 reads the expected pressure of
    lag seconds before); (nan, nan) without a change of pressure to fit on."""
    n, sw, sd, sww, swd, sdd = sums
    if n < 3:
        return math.nan, math.nan
    vww, vwd, vdd = sww - sw * sw / n, swd - sw * sd / n, sdd - sd * sd / n
    if not vww > 0.0:
        return math.nan, math.nan
    tau = -vwd / vww
    rss = max(vdd - vwd * vwd / vww, 0.0)
    return tau, math.sqrt(rss / (n - 2) / vww)
