"""Probe snapshot tables for the fleet diagnostics: wear as engines have it, not a straight line.

    python benchmarks/probe_tables.py OUT [--engines 40 --flights 150 --seed 11] [--linear]
    pwl fleet diagnose OUT/snapshots.csv --database data/turbofan_demo.h5 -o diagnosis.csv
    pwl fleet score diagnosis.csv OUT/truth.csv

The seeded fleet of ``pwl fleet simulate --snapshots --snapshot-samples 5`` (its faults and truth
unchanged), each engine's drawn deterioration rate made a curve that starts at twice the rate and
levels off (time constant TAU flights), and every other engine (ESN001, ESN003, ...) fouling its
fan and HPC by FOUL per flight in efficiency and flow, washed off every WASH flights. ``--linear``:
the plain fleet, for comparison. docs/diagnostics.md gives what the diagnostics make of them.
"""
from __future__ import annotations

import argparse

import numpy as np

import pwl.cli.fleet_simulate as fs
from models import fleet
from models.fleet import H_NAMES

TAU, FOUL, WASH = 60.0, -2e-4, 50
_health_at = fleet.health_at


def _worn(plan, i, j):
    h = _health_at(plan, i, j)
    r = plan.rate[i]
    h = h - r * j + 2.0 * r * TAU * (1.0 - np.exp(-j / TAU))
    if i % 2 == 0:
        for c in ("hpc", "fan"):
            for p in ("_eff", "_flow"):
                h[H_NAMES.index(c + p)] += FOUL * (j % WASH)
    return h


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir")
    ap.add_argument("--engines", type=int, default=40)
    ap.add_argument("--flights", type=int, default=150)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--linear", action="store_true", help="the plain fleet (straight-line wear, no fouling)")
    a = ap.parse_args(argv)
    if not a.linear:
        fleet.health_at = _worn          # snapshot_rows reads it from the module
    s = fs.simulate_snapshots(a.outdir, a.engines, a.flights, a.seed, samples=5)
    print(f"{s['path']}: {s['engines']} engines x {a.flights} flights, {s['faulty_engines']} faulty, "
          f"{s['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
