"""Probe fleets for the fleet diagnostics: faults outside the ProDiMES classes.

    python benchmarks/probe_fleets.py wear OUT [--engines 24 --flights 30]
    python benchmarks/probe_fleets.py episodes OUT [--engines 16 --flights 30]
    pwl run data/turbofan_demo.h5 OUT -o RES -j 2 --every 1000
    pwl fleet diagnose RES -o diagnosis.csv      # compare with OUT/probe_truth.json

``wear`` (seed 11, no seeded fault): engines 0-7 wear faster than normal (0.01 %/flight at
most), hpc -0.03, hpt -0.03, hpc -0.05, fan -0.05 %/flight efficiency from flight 0 (flow with
the fleet's component ratio), hpt -0.05 and lpt -0.1 from flight 10, hpc -0.02 from flight 0 and
hpt -0.1 from flight 15. ``episodes`` (seed 23): engine 0 has a T48 bias of +5 sigma on random
flights from 8, engine 1 Ps30 -5 sigma on others from 10, engine 2 a T30 bias growing 0.5 sigma
per flight from 10, engine 3 P50 +5 sigma on flights 8-19 only (a repair). docs/diagnostics.md
gives what the diagnostics make of them.
"""
from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np

import pwl.cli.fleet_simulate as fs
from models import fleet
from models.fleet import COMPONENT_RATIO, H_NAMES

#: engine -> (component, efficiency rate per flight, first flight)
WEAR = {0: ("hpc", -3e-4, 0), 1: ("hpt", -3e-4, 0), 2: ("hpc", -5e-4, 0), 3: ("fan", -5e-4, 0),
        4: ("hpt", -5e-4, 10), 5: ("lpt", -1e-3, 10), 6: ("hpc", -2e-4, 0), 7: ("hpt", -1e-3, 15)}
#: relative one-sigma noise of the sensors used (models.turbofan's)
SIGMA = {"T48": 0.0075, "T30": 0.0075, "Ps30": 0.005, "P50": 0.005}


def episodes(flights: int) -> dict:
    """engine -> (sensor, sigmas or "drift", flights with the bias)."""
    on = np.random.default_rng(5).random(flights) < 0.45
    return {0: ("T48", 5.0, [j for j in range(flights) if j >= 8 and on[j]]),
            1: ("Ps30", -5.0, [j for j in range(flights) if j >= 10 and on[(j * 7) % flights]]),
            2: ("T30", "drift", list(range(10, flights))),
            3: ("P50", 5.0, list(range(8, min(20, flights))))}


_health_at, _simulate_flight = fleet.health_at, fleet.simulate_flight


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


def _init(kind, plan):
    if kind == "wear":
        fleet.health_at = _worn
    else:
        fleet.simulate_flight = _biased
    fs._init_worker(plan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=("wear", "episodes"))
    ap.add_argument("out")
    ap.add_argument("--engines", type=int, default=None)
    ap.add_argument("--flights", type=int, default=30)
    ap.add_argument("-j", "--workers", type=int, default=2)
    a = ap.parse_args(argv)
    engines = a.engines or (24 if a.kind == "wear" else 16)
    plan = fleet.plan_fleet(engines, a.flights, seed=11 if a.kind == "wear" else 23, fault_fraction=0.0)
    os.makedirs(a.out, exist_ok=True)
    truth = ({plan.serial[i]: list(v) for i, v in WEAR.items() if i < engines} if a.kind == "wear" else
             {plan.serial[i]: [v[0], str(v[1]), v[2]] for i, v in episodes(a.flights).items() if i < engines})
    with open(os.path.join(a.out, "probe_truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    jobs = [(i, j, fs.flight_path(a.out, plan.serial[i], j, a.flights)) for i in range(engines) for j in range(a.flights)]
    with ProcessPoolExecutor(a.workers, initializer=_init, initargs=(a.kind, plan)) as ex:
        errors = [r for r in ex.map(fs._one, *zip(*jobs), chunksize=8) if r[2]]
    print(f"{a.out}: {engines} engines x {a.flights} flights ({a.kind}), {len(errors)} failed")
    for e in errors:
        print("  ", e)
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
