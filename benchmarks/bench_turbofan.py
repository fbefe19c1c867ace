"""Speed of the turbofan model (a benchmark, not a test).

    python benchmarks/bench_turbofan.py [--json]

* a 1-hour flight (long preset, dt = 0.015 s, 240 001 steps, two unbalanced solves per step):
  wall time and times real time (acceptance: >= 50x);
* the 5 x 5 x 9 trim grid (cold model, continuation along the power axis): trims per second;
* ``evaluate`` through the Python API (what the gain-database builder calls): calls per second.

Every figure is the best of a few runs after a warm-up run (numba compilation and cache loading
are excluded), measured in this process.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from models import flight  # noqa: E402
from models.turbofan import Turbofan  # noqa: E402


def _best(fn, repeat):
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_flight(repeat=2):
    m = Turbofan()
    prof = flight.flight_profile("long")
    flight.simulate(m, flight.flight_profile("short", {k: 5.0 for k in flight.PHASES}))   # warm-up
    wall, r = _best(lambda: flight.simulate(m, prof, health={"hpt_eff": -0.01}), repeat)
    T = float(r["time"][-1] - r["time"][0])
    return {"flight_s": T, "steps": int(r["time"].size), "wall_s": wall, "x_real_time": T / wall,
            "steps_per_s": r["time"].size / wall,
            "newton_iterations_per_solve": r["attrs"]["newton_iterations"] / (2 * r["time"].size)}


def bench_trim_grid(repeat=3):
    alts, machs, nfrs = np.linspace(0, 12000, 5), np.linspace(0, 0.85, 5), np.linspace(100, 60, 9)

    def run():
        m = Turbofan()
        n = 0
        for a in alts:
            for M in machs:
                g = None
                for N in nfrs:
                    p = np.array([a, M, N])
                    g = m.trim(p, None, m.environment(p), guess=g)
                    n += 1
        return n

    run()
    wall, n = _best(run, repeat)
    return {"trims": n, "wall_s": wall, "trims_per_s": n / wall}


def bench_evaluate(n=2000, repeat=3):
    m = Turbofan()
    p = np.array([6000.0, 0.5, 85.0])
    env = m.environment(p)
    t = m.trim(p, None, env)
    h = np.zeros(10)
    rng = np.random.default_rng(0)
    dx = 1.0 + 1e-3 * rng.choice([-1.0, 1.0], (n, 2))

    def run():
        for k in range(n):
            m.evaluate(t["x"] * dx[k], t["u"], h, env)

    run()
    wall, _ = _best(run, repeat)
    return {"calls": n, "wall_s": wall, "calls_per_s": n / wall}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    res = {"flight_1h": bench_flight(), "trim_grid": bench_trim_grid(), "evaluate": bench_evaluate()}
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    f = res["flight_1h"]
    print(f"1-hour flight: {f['steps']} steps in {f['wall_s']:.2f} s = {f['x_real_time']:,.0f} x real time "
          f"({f['steps_per_s']:,.0f} steps/s, {f['newton_iterations_per_solve']:.2f} Newton iterations per solve)")
    g = res["trim_grid"]
    print(f"trim grid 5x5x9: {g['trims']} trims in {g['wall_s'] * 1e3:.1f} ms = {g['trims_per_s']:,.0f} trims/s")
    e = res["evaluate"]
    print(f"evaluate (Python API): {e['calls_per_s']:,.0f} calls/s ({1e6 / e['calls_per_s']:.0f} us per call)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
