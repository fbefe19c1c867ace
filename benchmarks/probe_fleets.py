"""Probe fleets for the fleet diagnostics: faults outside the ProDiMES classes.

    python benchmarks/probe_fleets.py wear OUT [--engines 24 --flights 30]
    python benchmarks/probe_fleets.py episodes OUT [--engines 16 --flights 30]
    python benchmarks/probe_fleets.py messy OUT [--engines 20 --flights 30]
    python benchmarks/probe_fleets.py routes OUT [--engines 12 --flights 24]
    pwl run data/turbofan_demo.h5 OUT -o RES -j 2 --every 1000
    pwl fleet diagnose RES -o diagnosis.csv      # compare with OUT/probe_truth.json

``wear`` (seed 11, no seeded fault): engines 0-7 wear faster than normal (0.01 %/flight at
most), hpc -0.03, hpt -0.03, hpc -0.05, fan -0.05 %/flight efficiency from flight 0 (flow with
the fleet's component ratio), hpt -0.05 and lpt -0.1 from flight 10, hpc -0.02 from flight 0 and
hpt -0.1 from flight 15. ``episodes`` (seed 23): engine 0 has a T48 bias of +5 sigma on random
flights from 8, engine 1 Ps30 -5 sigma on others from 10, engine 2 a T30 bias growing 0.5 sigma
per flight from 10, engine 3 P50 +5 sigma on flights 8-19 only (a repair). docs/diagnostics.md
gives what the diagnostics make of them.

``messy`` (seed 31, steps of efficiency and flow from a flight on): engines 0 and 1 are washed at
flight 15 (fan and hpc +1 %), engine 0 then loses 2 % hpt at 22; engine 2 loses 2 % hpc with a T48
bias of +4 sigma from 10, engine 3 2 % lpc at 12 and 2 % hpt at 13, engine 4 2 % hpt from flight
0, engine 12 2 % fan at 20, engine 14 2 % hpt at 18; engine 13 has a T30 bias of +4 sigma from 18.
Engines 5, 6 and 14 have 3, 2 and 3 times the sensor noise; on flight 12, engine 7 flies at
dTamb +40 K, engine 8 cruises at 5000 m, engine 9 at TRA 65 %, engine 10's log stops at 250 s and
engine 11's T48 is dead (NaN). ``routes`` (seed 41): over the first half of the flights, then the
second, engines 0-1 fly a season (dTamb -10..-5 K, then +15..+20 K), engines 2-3 change route
(cruise at 8000-8500 m, then 10500-11000 m), engine 4 its cruise throttle (TRA 80-81 %, then
87-88 %); engine 5 cruises at TRA 65 % on flights 8, 12 and 16; engine 6 is washed at flight 2 (fan
and hpc +1 %) and loses 2 % hpc at 14, engine 7 is washed at 12 and loses 2 % hpt at 13.
"""
from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from functools import partial

import numpy as np

import pwl.cli.fleet_simulate as fs
from models import fleet
from models.fleet import COMPONENT_RATIO, H_NAMES

#: kind -> (seed, default engines, default flights)
KINDS = {"wear": (11, 24, 30), "episodes": (23, 16, 30), "messy": (31, 20, 30), "routes": (41, 12, 24)}
#: engine -> (component, efficiency rate per flight, first flight)
WEAR = {0: ("hpc", -3e-4, 0), 1: ("hpt", -3e-4, 0), 2: ("hpc", -5e-4, 0), 3: ("fan", -5e-4, 0),
        4: ("hpt", -5e-4, 10), 5: ("lpt", -1e-3, 10), 6: ("hpc", -2e-4, 0), 7: ("hpt", -1e-3, 15)}
#: relative one-sigma noise of the sensors used (models.turbofan's)
SIGMA = {"T48": 0.0075, "T30": 0.0075, "Ps30": 0.005, "P50": 0.005}


def wash(at):
    """A fan and hpc wash at flight `at`: +1 % efficiency and flow."""
    return [("comp", "fan", +0.01, +0.01, at), ("comp", "hpc", +0.01, +0.01, at)]


#: messy and routes: engine -> events
#:   ("comp", comp, eff, flow, onset)  health step from onset on (+: a wash)
#:   ("bias", sensor, sigmas, onset)   absolute bias of the logged channel from onset on
#:   ("noise", scale)                  sensor noise scale of every flight
#:   ("trunc", flight, seconds)        that flight's log stops at `seconds`
#:   ("nan", flight, sensor)           dead sensor (all NaN) on that flight
EVENTS = {"messy": {0: wash(15) + [("comp", "hpt", -0.02, +0.01, 22)], 1: wash(15),
                    2: [("comp", "hpc", -0.02, -0.02, 10), ("bias", "T48", 4.0, 10)],
                    3: [("comp", "lpc", -0.02, -0.02, 12), ("comp", "hpt", -0.02, +0.01, 13)],
                    4: [("comp", "hpt", -0.02, +0.01, 0)], 5: [("noise", 3.0)], 6: [("noise", 2.0)],
                    10: [("trunc", 12, 250.0)], 11: [("nan", 12, "T48")],
                    12: [("comp", "fan", -0.02, -0.02, 20)], 13: [("bias", "T30", 4.0, 18)],
                    14: [("noise", 3.0), ("comp", "hpt", -0.02, +0.01, 18)]},
          "routes": {6: wash(2) + [("comp", "hpc", -0.02, -0.02, 14)],
                     7: wash(12) + [("comp", "hpt", -0.02, +0.01, 13)]}}
#: messy: engine -> (plan field, value) on flight 12
ODD = {7: ("dTamb", 40.0), 8: ("cruise_alt", 5000.0), 9: ("tra_cruise", 65.0)}
#: routes: engines -> (plan field, uniform range over the first half of the flights, over the
#: second half, truth); drawn in this order from default_rng(99)
ROUTES = {(0, 1): ("dTamb", (-10, -5), (15, 20), "season dTamb -10..-5 then +15..+20 from M/2"),
          (2, 3): ("cruise_alt", (8000, 8500), (10500, 11000), "cruise alt 8000-8500 then 10500-11000 from M/2"),
          (4,): ("tra_cruise", (80, 81), (87, 88), "tra_cruise 80-81 then 87-88 from M/2")}
#: routes: engine -> (plan field, value, flights)
DIPS = {5: ("tra_cruise", 65.0, (8, 12, 16))}


def episodes(flights: int) -> dict:
    """engine -> (sensor, sigmas or "drift", flights with the bias)."""
    on = np.random.default_rng(5).random(flights) < 0.45
    return {0: ("T48", 5.0, [j for j in range(flights) if j >= 8 and on[j]]),
            1: ("Ps30", -5.0, [j for j in range(flights) if j >= 10 and on[(j * 7) % flights]]),
            2: ("T30", "drift", list(range(10, flights))),
            3: ("P50", 5.0, list(range(8, min(20, flights))))}


_health_at, _simulate_flight, _simulate = fleet.health_at, fleet.simulate_flight, fleet.simulate
_events = {}


def _worn(plan, i, j):
    h = _health_at(plan, i, j)
    if i in WEAR:
        c, rate, start = WEAR[i]
        n = max(0, j - start)
        h[H_NAMES.index(c + "_eff")] += rate * n
        h[H_NAMES.index(c + "_flow")] += COMPONENT_RATIO[c] * rate * n
    return h


def _biased(plan, i, j, model=None, health=None):
    r = _simulate_flight(plan, i, j, model, health)
    ep = episodes(plan.flights)
    if i in ep and j in ep[i][2]:
        c, k, _ = ep[i]
        size = 0.5 * (j - 9) if k == "drift" else k
        r["channels"][c] = r["channels"][c] + size * SIGMA[c] * fleet.reference_outputs()[c]
    return r


def _stepped(plan, i, j):
    h = _health_at(plan, i, j)
    for e in _events.get(i, []):
        if e[0] == "comp" and j >= e[4]:
            h[H_NAMES.index(e[1] + "_eff")] += e[2]
            h[H_NAMES.index(e[1] + "_flow")] += e[3]
    return h


def _flight(plan, i, j, model=None, health=None):
    ev = _events.get(i, [])
    fleet.simulate = partial(_simulate, noise_scale=next((e[1] for e in ev if e[0] == "noise"), 1.0))
    r = _simulate_flight(plan, i, j, model, health)
    ch = r["channels"]
    for e in ev:
        if e[0] == "bias" and j >= e[3]:
            ch[e[1]] = ch[e[1]] + e[2] * SIGMA[e[1]] * fleet.reference_outputs()[e[1]]
        elif e[0] == "nan" and j == e[1]:
            ch[e[2]] = np.full_like(ch[e[2]], np.nan)
        elif e[0] == "trunc" and j == e[1]:
            n = int(np.searchsorted(r["time"], e[2]))
            r["time"], ch = r["time"][:n], {k: v[:n] for k, v in ch.items()}
            r["truth"] = {k: v[:n] if np.ndim(v) else v for k, v in r["truth"].items()}
    r["channels"] = ch
    return r


def _shape(plan) -> dict:
    """Set the routes fleet's seasons, route and throttle changes on the plan; their truth."""
    E, M, h = plan.engines, plan.flights, plan.flights // 2
    r, truth = np.random.default_rng(99), {}
    for engines, (k, first, second, what) in ROUTES.items():
        engines = [i for i in engines if i < E]
        for i in engines:
            getattr(plan, k)[i, :h] = r.uniform(*first, h)
            getattr(plan, k)[i, h:] = r.uniform(*second, M - h)
        if engines:
            truth[plan.serial[engines[0]] + "".join(f"-{i + 1}" for i in engines[1:])] = what
    for i, (k, v, flights) in DIPS.items():
        if i < E:
            getattr(plan, k)[i, [j for j in flights if j < M]] = v
            truth[plan.serial[i]] = f"{k} {v:g} on flights {','.join(map(str, flights))}"
    return truth


def _fleet(kind, engines, flights):
    """The kind's plan (shaped for messy and routes) and its truth for probe_truth.json."""
    E, M = engines, flights
    plan = fleet.plan_fleet(E, M, seed=KINDS[kind][0], fault_fraction=0.0)
    if kind == "wear":
        return plan, {plan.serial[i]: list(v) for i, v in WEAR.items() if i < E}
    if kind == "episodes":
        return plan, {plan.serial[i]: [v[0], str(v[1]), v[2]] for i, v in episodes(M).items() if i < E}
    truth = {plan.serial[i]: [list(map(str, e)) for e in v] for i, v in EVENTS[kind].items() if i < E}
    if kind == "routes":
        return plan, {**truth, **_shape(plan)}
    for i, (k, v) in ODD.items():
        if i < E and M > 12:
            getattr(plan, k)[i, 12] = v
            truth[plan.serial[i]] = [["odd flight 12", k, str(v)]]
    return plan, truth


def _init(kind, plan):
    global _events
    if kind == "wear":
        fleet.health_at = _worn
    elif kind == "episodes":
        fleet.simulate_flight = _biased
    else:
        _events = EVENTS[kind]
        fleet.health_at, fleet.simulate_flight = _stepped, _flight
    fs._init_worker(plan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=tuple(KINDS))
    ap.add_argument("out")
    ap.add_argument("--engines", type=int, default=None)
    ap.add_argument("--flights", type=int, default=None)
    ap.add_argument("-j", "--workers", type=int, default=2)
    a = ap.parse_args(argv)
    engines, flights = a.engines or KINDS[a.kind][1], a.flights or KINDS[a.kind][2]
    plan, truth = _fleet(a.kind, engines, flights)
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "probe_truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    jobs = [(i, j, fs.flight_path(a.out, plan.serial[i], j, flights)) for i in range(engines) for j in range(flights)]
    with ProcessPoolExecutor(a.workers, initializer=_init, initargs=(a.kind, plan)) as ex:
        errors = [r for r in ex.map(fs._one, *zip(*jobs), chunksize=8) if r[2]]
    print(f"{a.out}: {engines} engines x {flights} flights ({a.kind}), {len(errors)} failed")
    for e in errors:
        print("  ", e)
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
