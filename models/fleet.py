"""Fleet simulator of a ProDiMES-style engine fleet benchmark (NASA/TM-2010-215840).

N engines x M flights of the two-spool turbofan (:mod:`models.turbofan`, flown by
:func:`models.flight.simulate`). Every engine starts with its own health scatter, deteriorates
gradually every flight, flies a varied profile in a varied ambient each flight, and its sensors
carry the model's documented noise; a seeded fraction of the engines gets ONE abrupt fault at a
random flight. Imports only numpy and the models (never pwl or linearize).

Fault classes (:data:`CLASSES`): ``none``; the components ``fan``, ``lpc``, ``hpc``, ``hpt``,
``lpt``; the sensor biases ``sensor:Nf``, ``sensor:Nc``, ``sensor:T24``, ``sensor:Ps30``,
``sensor:T30``, ``sensor:T48``, ``sensor:P50``, ``sensor:P15`` and the fuel-flow measurement bias
``sensor:Wf``.

Component faults (:data:`COMPONENT_RANGE`, :data:`COMPONENT_RATIO`): an efficiency change m with
|m| uniform in 0.01..0.04 and m always negative (a loss); it sets ``<comp>_eff += m`` and
``<comp>_flow += ratio * m`` with ratio 1.0 for fan, lpc and hpc (fouling: flow capacity drops
with the efficiency) and -0.5 for hpt and lpt (erosion: flow capacity rises). The fault changes
the engine itself (the truth health parameters) from the onset flight on.

Sensor faults (:data:`SENSOR_SIGMA_RANGE`): a constant bias of k noise sigmas, k uniform in
2..6, random sign. The bias is an ABSOLUTE offset in the sensor's unit,
``k * sigma_rel * y_ref``, with sigma_rel the relative one-sigma noise of
``Turbofan().sensor_noise`` (Nf, Nc 0.25 %; Ps30, P50, P15 0.5 %; T24, T30, T48 0.75 %) and
y_ref the sensor's value at the reference cruise trim :data:`REFERENCE_TRIM` (alt 9000 m,
Mach 0.78, ISA, corrected fan speed NfR 92 %, nominal health); see :func:`reference_outputs`.

Fuel-flow bias (:data:`FUEL_BIAS_RANGE`): relative, logged Wf = true Wf * (1 + b) with |b|
uniform in 0.01..0.04, random sign.

Sensor and fuel-flow biases are applied to the LOGGED channel only, from the onset flight on:
the engine is unaffected and the fuel controller uses the true values; the truth group of a
flight is always noise-free and bias-free (it is what the engine did).

Engine-to-engine scatter of the initial health (fractions, :data:`SCATTER`): efficiencies
N(-0.005, 0.003) clipped to <= 0; compressor flows (fan, lpc, hpc) N(-0.004, 0.003) clipped
to <= 0; turbine flows (hpt, lpt) N(+0.003, 0.002) clipped to >= 0.

Gradual deterioration (:data:`DETERIORATION`), linear in the flight index, the rate drawn once
per engine: efficiencies lose U(0, 1e-4) per flight, compressor flows lose U(0, 7.5e-5) per
flight, turbine flows gain U(0, 5e-5) per flight: at most 0.2 % efficiency over 20 flights, the
slow wear every engine has, well below the abrupt faults' 1..4 %.

Per-flight variation (:data:`FLIGHT_VARIATION`): ISA temperature offset dTamb U(-10, 20) K,
cruise altitude U(8000, 11000) m, cruise Mach U(0.74, 0.82), take-off throttle TRA
U(82, 89.5) %, cruise throttle TRA U(80, 88) %; no throttle dither (steady cruise). Phase
durations :data:`FLIGHT_DURATIONS`: taxi_out 30, takeoff 45, climb 240, cruise 150, descent
40, approach 30, taxi_in 20 s (555 s per flight, 37 001 samples at dt = 0.015 s). The other
throttle settings are those of :data:`models.flight.TRA`.

Faults (:data:`FAULT_FRACTION`): by default round(0.6 N) engines, chosen at random, are faulty;
a faulty engine's class is drawn uniformly among the 14 fault classes (or among ``classes``);
the onset flight (0-based) is a uniform integer in [max(3, M // 4), M - 2], so that the
diagnostics have a few fault-free flights as a baseline, as in ProDiMES. For M < 5 that range
is empty and the onset is the last flight, M - 1 (M >= 2 is required, so there is always at
least one fault-free flight before it).

Flight j of an engine starts at :data:`START` + j days (``flight_start``, the log attr ``flight_time``), so the time order
of the flights is explicit.

Randomness: every draw comes from ``numpy.random.SeedSequence(seed)`` spawned children: one
stream for the choice of the faulty engines, and per engine one stream for its health, one for
its fault and one child per flight (ambient, profile, noise seed). Results therefore do not
depend on the number of worker processes or the order of simulation, and an engine's health,
fault draws and flights do not depend on the number of engines. Each flight is simulated from a
fresh copy of the same pristine model, so its output does not depend on which flights a process
simulated before.
"""
from __future__ import annotations

import copy
import datetime as _dt
from dataclasses import dataclass, field

import numpy as np

from .flight import DT, flight_profile, simulate
from .turbofan import H_NAMES, Y_NAMES, Turbofan

#: fault classes; "none" is the fault-free class, the other 14 are the fault classes
CLASSES = ("none", "fan", "lpc", "hpc", "hpt", "lpt", "sensor:Nf", "sensor:Nc", "sensor:T24",
           "sensor:Ps30", "sensor:T30", "sensor:T48", "sensor:P50", "sensor:P15", "sensor:Wf")
FAULT_CLASSES = CLASSES[1:]
COMPONENTS = ("fan", "lpc", "hpc", "hpt", "lpt")
#: flow-capacity change per unit efficiency change of a component fault
COMPONENT_RATIO = {"fan": 1.0, "lpc": 1.0, "hpc": 1.0, "hpt": -0.5, "lpt": -0.5}
#: |efficiency loss| of a component fault, uniform (the sign is always negative)
COMPONENT_RANGE = (0.01, 0.04)
#: sensor bias in noise sigmas, uniform, random sign
SENSOR_SIGMA_RANGE = (2.0, 6.0)
#: relative fuel-flow measurement bias, uniform magnitude, random sign
FUEL_BIAS_RANGE = (0.01, 0.04)
#: default fraction of faulty engines
FAULT_FRACTION = 0.6
#: reference cruise trim of the absolute sensor biases: alt m, Mach, NfR %, nominal health, ISA
REFERENCE_TRIM = {"alt": 9000.0, "Mach": 0.78, "NfR": 92.0}
#: engine-to-engine scatter of the initial health: (mean, sd, clip) with clip "<=0" or ">=0"
SCATTER = {"eff": (-0.005, 0.003, "<=0"), "compressor_flow": (-0.004, 0.003, "<=0"),
           "turbine_flow": (0.003, 0.002, ">=0")}
#: per-flight deterioration rates, uniform (lo, hi) per flight, drawn once per engine
DETERIORATION = {"eff": (-1e-4, 0.0), "compressor_flow": (-7.5e-5, 0.0), "turbine_flow": (0.0, 5e-5)}
#: per-flight variation, uniform (lo, hi)
FLIGHT_VARIATION = {"dTamb": (-10.0, 20.0), "cruise_alt": (8000.0, 11000.0),
                    "cruise_mach": (0.74, 0.82), "tra_takeoff": (82.0, 89.5),
                    "tra_cruise": (80.0, 88.0)}
#: phase durations of every fleet flight, seconds
FLIGHT_DURATIONS = {"taxi_out": 30.0, "takeoff": 45.0, "climb": 240.0, "cruise": 150.0,
                    "descent": 40.0, "approach": 30.0, "taxi_in": 20.0}
#: start of flight 0; flight j starts j days later
START = _dt.datetime(2026, 1, 1)

SENSORS = Y_NAMES + ("Wf",)
# which health group each of the 10 parameters belongs to
_GROUP = tuple("eff" if n.endswith("_eff") else
               ("turbine_flow" if n.startswith(("hpt", "lpt")) else "compressor_flow")
               for n in H_NAMES)


@dataclass
class FleetPlan:
    """Every random draw of a fleet. Per engine i: ``serial[i]``, ``h0[i]`` (10,) initial health,
    ``rate[i]`` (10,) deterioration per flight, ``fault_class[i]``, ``magnitude[i]`` (signed:
    efficiency fraction for components, noise sigmas for sensors, fraction for Wf), ``bias[i]``
    (sensor unit; NaN unless an absolute sensor bias), ``onset[i]`` (-1 for none), ``eff[i]`` and
    ``flow[i]`` (the component fault's parameter changes, 0 otherwise). Per engine and flight
    (engines, flights): ``dTamb``, ``cruise_alt``, ``cruise_mach``, ``tra_takeoff``,
    ``tra_cruise``, ``noise_seed``."""

    engines: int
    flights: int
    seed: int
    fault_fraction: float
    classes: tuple
    serial: list
    h0: np.ndarray
    rate: np.ndarray
    fault_class: list
    magnitude: np.ndarray
    bias: np.ndarray
    onset: np.ndarray
    eff: np.ndarray
    flow: np.ndarray
    dTamb: np.ndarray
    cruise_alt: np.ndarray
    cruise_mach: np.ndarray
    tra_takeoff: np.ndarray
    tra_cruise: np.ndarray
    noise_seed: np.ndarray
    y_ref: dict = field(default_factory=dict)


_REF = None
_PRISTINE = None


def reference_outputs() -> dict:
    """Sensor values (model units) at :data:`REFERENCE_TRIM`, nominal health (computed once)."""
    global _REF
    if _REF is None:
        m = Turbofan()
        r = REFERENCE_TRIM
        p = np.array([r["alt"], r["Mach"], r["NfR"]])
        t = m.trim(p, None, m.environment(p))
        _REF = {name: float(t["y"][j]) for j, name in enumerate(m.y_names)}
    return dict(_REF)


def _pristine_model() -> Turbofan:
    global _PRISTINE
    if _PRISTINE is None:
        _PRISTINE = Turbofan()
    return _PRISTINE


def _serial(i, n):
    return f"ESN{i + 1:0{max(3, len(str(n)))}d}"


def _onset_range(flights):
    lo, hi = max(3, flights // 4), flights - 2
    return (lo, hi) if lo <= hi else (flights - 1, flights - 1)


def plan_fleet(engines: int, flights: int, seed: int = 0, fault_fraction: float = FAULT_FRACTION,
               classes=None) -> FleetPlan:
    """Draw a fleet (see the module docstring for every range). ``classes`` restricts the fault
    classes drawn for the faulty engines (names of :data:`CLASSES`; a drawn "none" leaves that
    engine fault-free). Raises ValueError naming a bad argument."""
    if isinstance(engines, bool) or not isinstance(engines, (int, np.integer)) or engines < 1:
        raise ValueError(f"engines must be an integer >= 1, got {engines!r}")
    if isinstance(flights, bool) or not isinstance(flights, (int, np.integer)) or flights < 2:
        raise ValueError(f"flights must be an integer >= 2, got {flights!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    try:
        ff = float(fault_fraction)
    except (TypeError, ValueError):
        raise ValueError(f"fault_fraction must be a number in 0..1, got {fault_fraction!r}") from None
    if not 0.0 <= ff <= 1.0:
        raise ValueError(f"fault_fraction must be in 0..1, got {fault_fraction!r}")
    if classes is None:
        cls = FAULT_CLASSES
    else:
        cls = (classes,) if isinstance(classes, str) else tuple(classes)
        bad = [c for c in cls if c not in CLASSES]
        if bad or not cls:
            raise ValueError(f"unknown fault classes {bad}; known: {', '.join(CLASSES)}" if bad
                             else "classes must name at least one fault class")
    E, M = int(engines), int(flights)
    fleet_ss, eng_root = np.random.SeedSequence(int(seed)).spawn(2)
    n_faulty = int(np.floor(ff * E + 0.5))
    faulty = np.zeros(E, bool)
    faulty[np.random.default_rng(fleet_ss).permutation(E)[:n_faulty]] = True
    y_ref = reference_outputs()
    sig = _pristine_model().sensor_noise
    h0, rate = np.zeros((E, 10)), np.zeros((E, 10))
    mag, bias, eff, flow = np.zeros(E), np.full(E, np.nan), np.zeros(E), np.zeros(E)
    onset = np.full(E, -1, np.int64)
    fclass = []
    per = {k: np.zeros((E, M)) for k in FLIGHT_VARIATION}
    noise_seed = np.zeros((E, M), np.int64)
    lo_on, hi_on = _onset_range(M)
    for i, e_ss in enumerate(eng_root.spawn(E)):
        h_ss, f_ss, fl_root = e_ss.spawn(3)
        rh = np.random.default_rng(h_ss)
        for j, g in enumerate(_GROUP):
            mu, sd, clip = SCATTER[g]
            v = rh.normal(mu, sd)
            h0[i, j] = min(v, 0.0) if clip == "<=0" else max(v, 0.0)
            a, b = DETERIORATION[g]
            rate[i, j] = rh.uniform(a, b)
        # the fault draws: always the same number, in the same order, whatever the class
        rf = np.random.default_rng(f_ss)
        c = cls[int(rf.integers(len(cls)))]
        u = rf.uniform()
        sign = -1.0 if rf.uniform() < 0.5 else 1.0
        on = int(rf.integers(lo_on, hi_on + 1))
        if not faulty[i] or c == "none":
            fclass.append("none")
        else:
            fclass.append(c)
            onset[i] = on
            if c in COMPONENTS:
                lo, hi = COMPONENT_RANGE
                mag[i] = -(lo + u * (hi - lo))
                eff[i], flow[i] = mag[i], COMPONENT_RATIO[c] * mag[i]
            elif c == "sensor:Wf":
                lo, hi = FUEL_BIAS_RANGE
                mag[i] = sign * (lo + u * (hi - lo))
            else:
                s = c.split(":", 1)[1]
                lo, hi = SENSOR_SIGMA_RANGE
                mag[i] = sign * (lo + u * (hi - lo))
                bias[i] = mag[i] * sig[s] * y_ref[s]
        for j, fs in enumerate(fl_root.spawn(M)):
            r = np.random.default_rng(fs)
            for k, (a, b) in FLIGHT_VARIATION.items():
                per[k][i, j] = r.uniform(a, b)
            noise_seed[i, j] = int(r.integers(0, 2**31 - 1))
    return FleetPlan(E, M, int(seed), ff, tuple(cls), [_serial(i, E) for i in range(E)], h0, rate,
                     fclass, mag, bias, onset, eff, flow, per["dTamb"], per["cruise_alt"],
                     per["cruise_mach"], per["tra_takeoff"], per["tra_cruise"], noise_seed, y_ref)


def _check_index(plan, i, j):
    if not (0 <= int(i) < plan.engines):
        raise ValueError(f"engine index {i} outside 0..{plan.engines - 1}")
    if not (0 <= int(j) < plan.flights):
        raise ValueError(f"flight index {j} outside 0..{plan.flights - 1}")
    return int(i), int(j)


def fault_active(plan: FleetPlan, engine_index: int, flight_index: int) -> bool:
    """Whether the engine's fault (if any) is present on this flight."""
    i, j = _check_index(plan, engine_index, flight_index)
    return plan.fault_class[i] != "none" and 0 <= plan.onset[i] <= j


def health_at(plan: FleetPlan, engine_index: int, flight_index: int) -> np.ndarray:
    """True health (10,) in the order of ``H_NAMES``: initial + rate * flight, plus the component
    fault from its onset flight on."""
    i, j = _check_index(plan, engine_index, flight_index)
    h = plan.h0[i] + plan.rate[i] * j
    c = plan.fault_class[i]
    if c in COMPONENTS and fault_active(plan, i, j):
        h[H_NAMES.index(c + "_eff")] += plan.eff[i]
        h[H_NAMES.index(c + "_flow")] += plan.flow[i]
    return h


def flight_start(flight_index: int) -> str:
    """ISO start time of flight j (START + j days)."""
    return (START + _dt.timedelta(days=int(flight_index))).isoformat()


def flight_settings(plan: FleetPlan, engine_index: int, flight_index: int) -> dict:
    """The flight's ambient and profile settings and noise seed."""
    i, j = _check_index(plan, engine_index, flight_index)
    return {"dTamb": float(plan.dTamb[i, j]), "cruise_alt": float(plan.cruise_alt[i, j]),
            "cruise_mach": float(plan.cruise_mach[i, j]), "tra_takeoff": float(plan.tra_takeoff[i, j]),
            "tra_cruise": float(plan.tra_cruise[i, j]), "noise_seed": int(plan.noise_seed[i, j])}


def fault_unit(cls: str) -> str:
    return "sigma" if cls.startswith("sensor:") and cls != "sensor:Wf" else ("fraction" if cls != "none" else "")


def simulate_flight(plan: FleetPlan, engine_index: int, flight_index: int, model=None,
                    health=None) -> dict:
    """Fly one flight of one engine; the dict of :func:`models.flight.simulate` with the sensor
    fault (if active) applied to the logged channel only, and fleet attrs: engine, flight_index,
    flight_time (ISO start), fault_class, fault_magnitude, fault_unit, fault_bias, fault_onset,
    fault_active and the flight's settings. ``model``: default a fresh copy of a pristine
    :class:`Turbofan` (so the result does not depend on earlier simulations in the process).
    ``health`` (10,) overrides the engine's true health for this flight (what-if studies, e.g. a
    fault outside the classes); default :func:`health_at`.
    Raises models.turbofan.PlantError if the flight cannot be simulated."""
    i, j = _check_index(plan, engine_index, flight_index)
    s = flight_settings(plan, i, j)
    prof = flight_profile("short", FLIGHT_DURATIONS, s["cruise_alt"], s["cruise_mach"], s["dTamb"],
                          DT, s["noise_seed"], False,
                          {"takeoff": s["tra_takeoff"], "cruise": s["tra_cruise"]})
    m = model if model is not None else copy.deepcopy(_pristine_model())
    h = health_at(plan, i, j) if health is None else np.asarray(health, float).reshape(len(H_NAMES))
    r = simulate(m, prof, health=h, seed=s["noise_seed"])
    c = plan.fault_class[i]
    active = fault_active(plan, i, j)
    if active and c == "sensor:Wf":
        r["channels"]["Wf"] = r["channels"]["Wf"] * (1.0 + plan.magnitude[i])
    elif active and c.startswith("sensor:"):
        name = c.split(":", 1)[1]
        r["channels"][name] = r["channels"][name] + plan.bias[i]
    r["attrs"].update({
        "engine": plan.serial[i], "engine_index": i, "flight_index": j, "flight_time": flight_start(j),
        "fleet_seed": plan.seed, "fault_class": c, "fault_magnitude": float(plan.magnitude[i]),
        "fault_unit": fault_unit(c), "fault_bias": float(plan.bias[i]),
        "fault_onset": int(plan.onset[i]), "fault_active": bool(active),
        "dTamb": s["dTamb"], "cruise_alt": s["cruise_alt"], "cruise_mach": s["cruise_mach"],
        "tra_takeoff": s["tra_takeoff"], "tra_cruise": s["tra_cruise"]})
    return r


def truth_rows(plan: FleetPlan) -> list[dict]:
    """One row per engine: engine, class, magnitude, unit, bias, bias_unit, onset, eff, flow
    (bias and bias_unit blank unless an absolute sensor bias)."""
    rows = []
    units = _pristine_model().units
    for i in range(plan.engines):
        c = plan.fault_class[i]
        absolute = c.startswith("sensor:") and c != "sensor:Wf"
        rows.append({"engine": plan.serial[i], "class": c, "magnitude": float(plan.magnitude[i]),
                     "unit": fault_unit(c),
                     "bias": float(plan.bias[i]) if absolute else "",
                     "bias_unit": units[c.split(":", 1)[1]] if absolute else "",
                     "onset": int(plan.onset[i]), "eff": float(plan.eff[i]), "flow": float(plan.flow[i])})
    return rows


def settings(plan: FleetPlan) -> dict:
    """The generation settings and every constant of the fleet (JSON-serialisable)."""
    return {"engines": plan.engines, "flights": plan.flights, "seed": plan.seed,
            "fault_fraction": plan.fault_fraction, "classes": list(plan.classes),
            "all_classes": list(CLASSES), "component_ratio": dict(COMPONENT_RATIO),
            "component_range": list(COMPONENT_RANGE), "sensor_sigma_range": list(SENSOR_SIGMA_RANGE),
            "fuel_bias_range": list(FUEL_BIAS_RANGE), "reference_trim": dict(REFERENCE_TRIM),
            "reference_outputs": dict(plan.y_ref),
            "sensor_noise": dict(_pristine_model().sensor_noise),
            "scatter": {k: list(v) for k, v in SCATTER.items()},
            "deterioration_per_flight": {k: list(v) for k, v in DETERIORATION.items()},
            "flight_variation": {k: list(v) for k, v in FLIGHT_VARIATION.items()},
            "flight_durations": dict(FLIGHT_DURATIONS), "dither": False, "dt": DT,
            "onset_range": list(_onset_range(plan.flights)), "start": START.isoformat(),
            "flight_interval_days": 1, "health_names": list(H_NAMES)}


#: the steady operating points an engine-monitoring report's snapshots may be taken at: ground
#: idle (alt 0, Mach 0, throttle :data:`models.flight.TRA` idle), take-off (alt 0, Mach
#: :data:`TAKEOFF_MACH`, the flight's take-off throttle) and the flight's cruise
SNAPSHOT_REGIMES = ("idle", "takeoff", "cruise")
#: the regimes :func:`snapshot_rows` writes by default (those ``pwl run`` finds steady in a log)
DEFAULT_SNAPSHOT_REGIMES = ("idle", "cruise")
#: flight Mach number of a take-off snapshot (ProDiMES takes one near lift-off)
TAKEOFF_MACH = 0.2
#: what the columns of :func:`snapshot_rows` hold besides the sensors: who, when, where
SNAPSHOT_KEYS = ("engine", "flight", "flight_time", "regime", "alt", "Mach", "T2", "P2")


def snapshot_rows(plan: FleetPlan, engine_index: int, flight_index: int, samples: int = 1,
                  model=None, regimes=DEFAULT_SNAPSHOT_REGIMES) -> list[dict]:
    """The flight's steady snapshots as an engine-monitoring report carries them (ProDiMES gives
    its data so): one row per regime of ``regimes`` (of :data:`SNAPSHOT_REGIMES`; ProDiMES:
    take-off and cruise), the engine's steady state there
    on the flight's day (:func:`health_at`, ``dTamb``; cruise at the flight's altitude, Mach and
    cruise throttle), every sensor with its noise averaged over ``samples`` readings (relative
    one-sigma ``Turbofan().sensor_noise`` / sqrt(samples); T2, P2 as :data:`models.flight.CHANNEL_NOISE`;
    alt, Mach and Wf as the logs carry them, without noise) and the sensor fault applied as in
    :func:`simulate_flight`. Columns :data:`SNAPSHOT_KEYS`, then the sensors and Wf, model units;
    seeded by the flight's noise seed. Raises models.turbofan.PlantError if a trim fails."""
    from .flight import CHANNEL_NOISE, TRA, nfr_demand

    i, j = _check_index(plan, engine_index, flight_index)
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    bad = [r for r in regimes if r not in SNAPSHOT_REGIMES]
    if bad or not regimes:
        raise ValueError(f"unknown snapshot regimes {bad}; known: {', '.join(SNAPSHOT_REGIMES)}" if bad
                         else "regimes must name at least one of " + ", ".join(SNAPSHOT_REGIMES))
    s = flight_settings(plan, i, j)
    m = model if model is not None else _pristine_model()
    h = health_at(plan, i, j)
    rng = np.random.default_rng([s["noise_seed"], 1])    # not the log's noise stream
    scale = 1.0 / np.sqrt(samples)

    points = {"idle": (0.0, 0.0, nfr_demand(TRA["idle"])),
              "takeoff": (0.0, TAKEOFF_MACH, nfr_demand(s["tra_takeoff"])),
              "cruise": (s["cruise_alt"], s["cruise_mach"], nfr_demand(s["tra_cruise"]))}
    c, active = plan.fault_class[i], fault_active(plan, i, j)
    rows = []
    for regime in regimes:
        alt, mach, nf = points[regime]
        env = np.array([alt, mach, s["dTamb"]])
        t = m.trim(np.array([alt, mach, nf]), h, env)
        T2, P2 = m.inlet(env)
        row = {"engine": plan.serial[i], "flight": j, "flight_time": flight_start(j), "regime": regime,
               "alt": alt, "Mach": mach}
        for name, v in (("T2", T2), ("P2", P2)):
            row[name] = float(v * (1.0 + scale * CHANNEL_NOISE[name] * rng.standard_normal()))
        for k, name in enumerate(m.y_names):
            noise = scale * m.sensor_noise.get(name, 0.0) * rng.standard_normal()
            row[name] = float(t["y"][k] * (1.0 + noise))
        row["Wf"] = float(t["u"][0])
        if active and c == "sensor:Wf":
            row["Wf"] *= 1.0 + float(plan.magnitude[i])
        elif active and c.startswith("sensor:"):
            row[c.split(":", 1)[1]] += float(plan.bias[i])
        rows.append(row)
    return rows
