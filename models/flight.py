"""Flight simulation of the turbofan: profile generator, fuel controller, spool dynamics, sensors.

* :func:`flight_profile` -- altitude, Mach and throttle (TRA, %) versus time for taxi, take-off,
  climb, cruise, descent, approach and taxi-in, parameterised by phase durations (presets
  ``short`` ~12.5 min and ``long`` = 1 hour). Transitions are cosine-smoothed.
* :func:`simulate` -- fixed step dt = 0.015 s. The fuel controller is a PI on corrected fan speed
  (demand NfR = idle + TRA (max - idle)) whose output is the ratio unit RU = Wf / Ps30, limited by
  acceleration and deceleration schedules (multiples of the steady-state RU line versus corrected
  HP speed). The spool ODE is integrated by Heun's method (two unbalanced solves per step, each a
  warm-started Newton with a reused Jacobian), the whole flight in one numba loop.
  Sensor noise is added afterwards (seeded ``numpy.random.Generator``); health is constant, a
  per-sample array, or drifts linearly.

Returns plain dicts of numpy arrays; ``pwl simulate`` turns them into a flight-log file.
Imports only numpy/numba and the model (never pwl or linearize).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import gaspath as gp
from .turbofan import H_NAMES, Y_IDX, Z_IDX, PlantError, Turbofan, check_health

DT = 0.015

#: phase durations in seconds
PRESETS = {
    "short": {"taxi_out": 60.0, "takeoff": 45.0, "climb": 300.0, "cruise": 180.0, "descent": 120.0,
              "approach": 60.0, "taxi_in": 45.0},
    "long": {"taxi_out": 240.0, "takeoff": 50.0, "climb": 900.0, "cruise": 1500.0, "descent": 600.0,
             "approach": 210.0, "taxi_in": 100.0},
}
PHASES = ("taxi_out", "takeoff", "climb", "cruise", "descent", "approach", "taxi_in")

#: controller settings (NfR in %, RU normalised by its design value)
CONTROL = {"NfR_idle": 62.0, "NfR_max": 100.0, "Kp": 0.08, "Ki": 0.05,
           "accel": 1.35, "decel": 0.55}
#: throttle (TRA, %) per phase; NfR demand = idle + TRA/100 (max - idle)
TRA = {"idle": 0.0, "takeoff": 89.5, "climb": 91.0, "cruise": 86.0, "approach": 45.0}
CHANNEL_NOISE = {"T2": 0.001, "P2": 0.001}     # one-sigma fractions of the inlet sensors


def nfr_demand(tra: float) -> float:
    """The controller's corrected fan speed demand (% of design) at throttle ``tra`` (%):
    idle + TRA/100 (max - idle) of :data:`CONTROL`."""
    return CONTROL["NfR_idle"] + tra / 100.0 * (CONTROL["NfR_max"] - CONTROL["NfR_idle"])


def _smooth(t, kt, kv):
    """Cosine-smoothed interpolation through knots (kt increasing, kv values)."""
    out = np.empty_like(t)
    idx = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
    t0, t1 = kt[idx], kt[idx + 1]
    s = np.clip((t - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)
    w = 0.5 * (1.0 - np.cos(np.pi * s))
    out[:] = kv[idx] + (kv[idx + 1] - kv[idx]) * w
    return out


def flight_profile(preset="short", durations=None, cruise_alt=None, cruise_mach=0.8, dTamb=0.0,
                   dt=DT, seed=0, dither=True, tra=None):
    """Altitude (m), Mach, TRA (%) and dTamb (K) versus time; returns a dict of arrays.

    ``durations`` overrides the preset's phase durations (seconds, keys of :data:`PHASES`).
    ``cruise_alt`` defaults to 10 700 m for the long preset and 9 000 m for the short one.
    ``dither`` adds seeded throttle steps of +-2..4 % TRA every 40..90 s in climb and cruise
    (they excite the spool dynamics for estimation demos).
    ``tra`` overrides entries of :data:`TRA` (throttle %, 0..100) for this profile, e.g.
    ``{"takeoff": 85.0, "cruise": 84.0}``; unknown keys raise ValueError.
    """
    tr = dict(TRA)
    if tra:
        bad = set(tra) - set(TRA)
        if bad:
            raise ValueError(f"unknown throttle settings {sorted(bad)}; known: {', '.join(TRA)}")
        for k, v in tra.items():
            v = float(v)
            if not 0.0 <= v <= 100.0:
                raise ValueError(f"throttle {k}={v} % outside 0..100 %")
            tr[k] = v
    d = dict(PRESETS[preset]) if preset else dict(PRESETS["short"])
    if durations:
        bad = set(durations) - set(PHASES)
        if bad:
            raise ValueError(f"unknown flight phases {sorted(bad)}; known: {', '.join(PHASES)}")
        d.update({k: float(v) for k, v in durations.items()})
    if any(v <= 0 for v in d.values()):
        raise ValueError(f"phase durations must be positive: {d}")
    if cruise_alt is None:
        cruise_alt = 10700.0 if preset == "long" else 9000.0
    if not (0.0 <= cruise_alt <= 13000.0 and 0.3 <= cruise_mach <= 0.9):
        raise ValueError(f"cruise altitude {cruise_alt} m / Mach {cruise_mach} outside 0..13 km, 0.3..0.9")
    edges = np.cumsum([0.0] + [d[p] for p in PHASES])
    T = edges[-1]
    n = int(round(T / dt)) + 1
    t = np.arange(n) * dt
    e = dict(zip(PHASES, edges[:-1]))
    e_end = dict(zip(PHASES, edges[1:]))
    roll = min(40.0, 0.8 * d["takeoff"])          # ground roll within the take-off phase
    # altitude knots
    ka = [0.0, e["takeoff"] + roll, e["cruise"], e["descent"], e["approach"], e["taxi_in"], T]
    va = [0.0, 0.0, cruise_alt, cruise_alt, min(1000.0, cruise_alt), 0.0, 0.0]
    # Mach knots
    km = [0.0, e["takeoff"], e["takeoff"] + roll, e["climb"] + 0.25 * d["climb"], e["cruise"],
          e["descent"], e["approach"], e["taxi_in"], e["taxi_in"] + 0.5 * d["taxi_in"], T]
    vm = [0.0, 0.0, 0.25, min(0.6, cruise_mach), cruise_mach, cruise_mach, 0.3, 0.2, 0.02, 0.0]
    # throttle knots (short pushes/pulls of 5 s)
    kt_, vt_ = [0.0], [tr["idle"]]

    def seg(t0, t1, val):
        kt_.extend([t0, min(t0 + 5.0, t1)])
        vt_.extend([vt_[-1], val])
        kt_.append(t1)
        vt_.append(val)

    seg(e["takeoff"], e_end["takeoff"], tr["takeoff"])
    seg(e["climb"], e_end["climb"], tr["climb"])
    seg(e["cruise"], e_end["cruise"], tr["cruise"])
    seg(e["descent"], e_end["descent"], tr["idle"])
    seg(e["approach"], e_end["approach"], tr["approach"])
    seg(e["taxi_in"], e_end["taxi_in"], tr["idle"])
    kt_ = np.array(kt_)
    vt_ = np.array(vt_)
    keep = np.concatenate([[True], np.diff(kt_) > 0])
    alt = _smooth(t, np.array(ka, float), np.array(va, float))
    mach = _smooth(t, np.array(km, float), np.array(vm, float))
    tra = _smooth(t, kt_[keep], vt_[keep])
    if dither:
        rng = np.random.default_rng(seed)
        for ph in ("climb", "cruise"):
            tt = e[ph] + 20.0
            while tt < e_end[ph] - 30.0:
                dur = rng.uniform(10.0, 25.0)
                amp = rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 4.0)
                m = (t >= tt) & (t < tt + dur)
                tra[m] += amp
                tt += dur + rng.uniform(40.0, 90.0)
    tra = np.clip(tra, 0.0, 100.0)
    phase = np.searchsorted(edges[1:-1], t, side="right").astype(np.int8)
    return {"time": t, "alt": alt, "Mach": mach, "TRA": tra, "dTamb": np.full(n, float(dTamb)),
            "phase": phase, "phases": PHASES, "durations": d}


# ---- the numba simulation loop ------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _loop(alt, mach, dTa, tra, H, C, ctl, ru_n, ru_hi, ru_lo, x0, v0, wf0, dt, tol,
          X, U, Y, Z, AMB, NFRD, iters):
    """Closed-loop flight simulation. Returns (k_fail or -1, status, iterations total)."""
    n = alt.shape[0]
    amb = np.empty(5)
    s = np.empty(gp.NS)
    J = np.zeros((8, 8))
    v = v0.copy()
    x = x0.copy()
    h = np.empty(10)
    nfr_idle, nfr_max, kp, ki, acc, dec, ru_d = ctl[0], ctl[1], ctl[2], ctl[3], ctl[4], ctl[5], ctl[6]
    integ = 0.0
    ps30 = -1.0
    reuse = 0
    total = 0
    for k in range(n):
        gp.ambient(alt[k], mach[k], dTa[k], C, amb)
        for j in range(10):
            h[j] = H[k, j] if H.shape[0] > 1 else H[0, j]
        th = amb[0] / gp.T_STD
        sq = math.sqrt(th)
        nfr = 100.0 * x[0] / sq / C[gp.NF_D]
        ncr = x[1] / sq / C[gp.NC_D]
        dem = nfr_idle + tra[k] / 100.0 * (nfr_max - nfr_idle)
        NFRD[k] = dem
        e = dem - nfr
        hi = acc * np.interp(ncr, ru_n, ru_hi)
        lo = dec * np.interp(ncr, ru_n, ru_lo)
        integ += ki * e * dt
        ru = kp * e + integ
        if ru > hi or ru < lo:       # limited: the integrator tracks the limit (no wind-up)
            ru = hi if ru > hi else lo
            integ = ru - kp * e
        if ps30 < 0.0:           # first step: the trim's fuel flow
            wf = wf0
        else:
            wf = ru * ru_d * ps30
        U[k] = wf
        # Heun step: solve at x_k, then at the Euler predictor
        st, it, rm = gp.newton(v, 0, x[0], x[1], wf, amb, h, C, tol, 60, s, J, reuse)
        total += it
        if st != gp.OK:
            return k, st, total
        reuse = 1
        f0 = s[gp.S_DNF]
        f1 = s[gp.S_DNC]
        X[k, 0] = x[0]
        X[k, 1] = x[1]
        for j in range(Y_IDX.shape[0]):
            Y[k, j] = s[Y_IDX[j]]
        for j in range(Z_IDX.shape[0]):
            Z[k, j] = s[Z_IDX[j]]
        AMB[k, 0] = amb[0]
        AMB[k, 1] = amb[1]
        ps30 = s[gp.S_PS3]
        if k == 0:
            integ = wf / (ru_d * ps30) - kp * e
        xp0 = x[0] + dt * f0
        xp1 = x[1] + dt * f1
        st, it, rm = gp.newton(v, 0, xp0, xp1, wf, amb, h, C, tol, 60, s, J, reuse)
        total += it
        if st != gp.OK:
            return k, st, total
        x[0] += 0.5 * dt * (f0 + s[gp.S_DNF])
        x[1] += 0.5 * dt * (f1 + s[gp.S_DNC])
    iters[0] = total
    return -1, 0, total


@njit(cache=True, nogil=True)
def _open_loop(env, H, C, x0, v0, WF, dt, tol, X, Y, Z):
    """Open-loop response to a fuel-flow history WF (n,) at a fixed ambient (Heun, dt)."""
    n = WF.shape[0]
    amb = np.empty(5)
    gp.ambient(env[0], env[1], env[2], C, amb)
    s = np.empty(gp.NS)
    J = np.zeros((8, 8))
    v = v0.copy()
    x = x0.copy()
    reuse = 0
    for k in range(n):
        st, it, rm = gp.newton(v, 0, x[0], x[1], WF[k], amb, H, C, tol, 60, s, J, reuse)
        if st != gp.OK:
            return k
        reuse = 1
        X[k, 0] = x[0]
        X[k, 1] = x[1]
        Y[k, 0] = s[gp.S_T24]
        Y[k, 1] = s[gp.S_PS3]
        Y[k, 2] = s[gp.S_T3]
        Y[k, 3] = s[gp.S_T48]
        Y[k, 4] = s[gp.S_P50]
        Z[k, 0] = s[gp.S_FN]
        Z[k, 1] = s[gp.S_T4]
        f0 = s[gp.S_DNF]
        f1 = s[gp.S_DNC]
        st, it, rm = gp.newton(v, 0, x[0] + dt * f0, x[1] + dt * f1, WF[k], amb, H, C, tol, 60, s, J, reuse)
        if st != gp.OK:
            return k
        x[0] += 0.5 * dt * (f0 + s[gp.S_DNF])
        x[1] += 0.5 * dt * (f1 + s[gp.S_DNC])
    return -1


def open_loop(model: Turbofan, p, Wf, h=None, dt=DT):
    """Spool response (dict of arrays) to the fuel-flow history ``Wf`` starting from the trim at p."""
    h = model._h(h)
    env = model.environment(p)
    t = model.trim(p, h, env)
    v0 = model._trim_index[model._tkey(t["x"], t["u"], h, env)][:6].copy()
    WF = np.ascontiguousarray(Wf, dtype=np.float64)
    n = WF.size
    X, Y, Z = np.empty((n, 2)), np.empty((n, 5)), np.empty((n, 2))
    k = _open_loop(env, h, model.C, t["x"].copy(), v0, WF, dt, 1e-11, X, Y, Z)
    if k >= 0:
        raise PlantError(f"open-loop simulation failed at step {k} (t = {k * dt:.3f} s)")
    return {"time": np.arange(n) * dt, "Nf": X[:, 0], "Nc": X[:, 1], "T48": Y[:, 3], "Fn": Z[:, 0],
            "trim": t}


def steady_ru_line(model: Turbofan, nfr=(50.0, 56.0, 62.0, 70.0, 80.0, 90.0, 100.0, 104.0)):
    """The steady-state ratio unit Wf/Ps30 (normalised by its design value) versus corrected HP
    speed Nc/sqrt(theta2)/Nc_design: max over sea-level static and 10.7 km / M0.8 (acceleration
    basis) and min (deceleration basis). Returns (ncr, ru_max, ru_min) increasing in ncr."""
    ru_d = model.C[gp.WF_D] / model.stations(np.array([0.0, 0.0, 100.0]))["PS3"]
    lines = []
    for alt, mach in ((0.0, 0.0), (10700.0, 0.8)):
        pts = []
        for N in nfr:
            p = np.array([alt, mach, N])
            t = model.trim(p, None, model.environment(p))
            th, _ = model.theta_delta(model.environment(p))
            pts.append((t["x"][1] / math.sqrt(th) / model.Nc_design, t["u"][0] / t["y"][3] / ru_d))
        lines.append(np.array(sorted(pts)))
    grid = np.linspace(min(l[0, 0] for l in lines), max(l[-1, 0] for l in lines), 24)
    vals = np.array([np.interp(grid, l[:, 0], l[:, 1]) for l in lines])
    return grid, vals.max(axis=0), vals.min(axis=0), ru_d


def _health_array(health, n, t):
    """Health as a (1, 10) or (n, 10) array; HealthError (a ValueError) names an unknown
    parameter or a value outside ``H_RANGE``."""
    if health is None:
        return np.zeros((1, 10))
    if callable(health):
        H = np.asarray(health(t), dtype=np.float64)
    elif isinstance(health, dict):
        check_health(health)
        H = np.zeros((1, 10))
        for k, v in health.items():
            H[0, H_NAMES.index(k)] = float(v)
    else:
        H = np.asarray(health, dtype=np.float64)
    if H.ndim == 1:
        H = H.reshape(1, -1)
    if H.shape not in ((1, 10), (n, 10)):
        raise ValueError(f"health must be 10 fractions, or (n, 10) per sample; got shape {H.shape}")
    check_health(dict(zip(H_NAMES, H.T)))
    return np.ascontiguousarray(H)


def drift(start, end, t):
    """Linear health drift from ``start`` to ``end`` (dicts name -> fraction) over times t."""
    a = _health_array(start or {}, 1, t)[0]
    b = _health_array(end or {}, 1, t)[0]
    w = (t - t[0]) / max(t[-1] - t[0], 1e-12)
    return a[None, :] + w[:, None] * (b - a)[None, :]


def simulate(model: Turbofan | None = None, profile=None, health=None, seed=0, noise_scale=1.0,
             sensor_noise=None, dt=DT):
    """Closed-loop flight simulation with sensor noise.

    ``profile``: a dict from :func:`flight_profile` (default: the short preset). ``health``: None,
    10 fractions (array or dict name -> value), an (n, 10) array per sample, or a callable
    t -> (n, 10). Returns {"time", "dt", "channels", "units", "truth", "truth_units", "attrs"}:
    channels alt, Mach, T2, P2, TRA, Wf and the noisy sensors y; truth = noise-free y, z, Wf,
    NfR demand and the 10 health parameters per sample.
    """
    m = model or Turbofan()
    prof = profile or flight_profile(dt=dt)
    t = np.asarray(prof["time"], dtype=np.float64)
    n = t.size
    if n < 2:
        raise ValueError("the profile needs at least two samples")
    dt_p = float(t[1] - t[0])
    if abs(dt_p - dt) > 1e-9:
        raise ValueError(f"profile step {dt_p} s differs from the simulation step {dt} s")
    H = _health_array(health, n, t)
    alt = np.ascontiguousarray(prof["alt"], dtype=np.float64)
    mach = np.ascontiguousarray(prof["Mach"], dtype=np.float64)
    dTa = np.ascontiguousarray(prof.get("dTamb", np.zeros(n)), dtype=np.float64)
    tra = np.ascontiguousarray(prof["TRA"], dtype=np.float64)
    ncr, ru_hi, ru_lo, ru_d = steady_ru_line(m)
    c = CONTROL
    ctl = np.array([c["NfR_idle"], c["NfR_max"], c["Kp"], c["Ki"], c["accel"], c["decel"], ru_d])
    # the accel limit multiplies the max steady line, the decel limit the min one: pass one
    # table and fold the ratio of the two lines into the multipliers' table
    # initial trim at the first sample
    nfr0 = nfr_demand(tra[0])
    env0 = np.array([alt[0], mach[0], dTa[0]])
    t0 = m.trim(np.array([alt[0], mach[0], nfr0]), H[0], env0)
    v0 = m._trim_index[m._tkey(t0["x"], t0["u"], H[0], env0)][:6].copy()
    X, U = np.empty((n, 2)), np.empty(n)
    Y, Z = np.empty((n, Y_IDX.size)), np.empty((n, Z_IDX.size))
    AMB, NFRD = np.empty((n, 2)), np.empty(n)
    iters = np.zeros(1, dtype=np.int64)
    k, st, total = _loop(alt, mach, dTa, tra, H, m.C, ctl, ncr, ru_hi, ru_lo, t0["x"].copy(), v0,
                         t0["u"][0], dt, 1e-11, X, U, Y, Z, AMB, NFRD, iters)
    if k >= 0:
        raise PlantError(f"flight simulation failed at t = {t[k]:.3f} s (alt {alt[k]:.0f} m, Mach "
                         f"{mach[k]:.3f}, TRA {tra[k]:.1f} %): {gp.STATUS_TEXT.get(st, st)}")
    rng = np.random.default_rng(seed)
    sig = dict(m.sensor_noise)
    if sensor_noise:
        sig.update(sensor_noise)
    channels = {"alt": alt.copy(), "Mach": mach.copy()}
    for j, name in enumerate(("T2", "P2")):
        channels[name] = AMB[:, j] * (1.0 + noise_scale * CHANNEL_NOISE[name] * rng.standard_normal(n))
    channels["TRA"] = tra.copy()
    channels["Wf"] = U.copy()
    for j, name in enumerate(m.y_names):
        channels[name] = Y[:, j] * (1.0 + noise_scale * sig.get(name, 0.0) * rng.standard_normal(n))
    truth = {name: Y[:, j].copy() for j, name in enumerate(m.y_names)}
    truth.update({name: Z[:, j].copy() for j, name in enumerate(m.z_names)})
    truth["Wf"] = U.copy()
    truth["T2"] = AMB[:, 0].copy()
    truth["P2"] = AMB[:, 1].copy()
    truth["NfR_demand"] = NFRD.copy()
    Hn = np.broadcast_to(H, (n, 10))
    for j, name in enumerate(H_NAMES):
        truth[name] = Hn[:, j].copy()
    units = m.units
    attrs = {"model": m.name, "dt": dt, "seed": int(seed), "noise_scale": float(noise_scale),
             "sensor_noise": {k: sig.get(k, 0.0) for k in m.y_names} | CHANNEL_NOISE,
             "newton_iterations": int(total), "durations": prof.get("durations", {}),
             "model_parameters": m.parameters()}
    return {"time": t.copy(), "dt": dt,
            "channels": channels, "units": {k: units[k] for k in channels},
            "truth": truth, "truth_units": {k: units[k] for k in truth}, "attrs": attrs}
