"""A snapshot table whose faulty engines were delivered so: faults from their first flight.

    python benchmarks/delivered_faults.py OUT [--engines 30 --flights 30 --seed 31]
    pwl fleet diagnose OUT/snapshots.csv --database data/turbofan_demo.h5 -o diagnosis.csv
    pwl fleet score diagnosis.csv OUT/truth.csv

The seeded fleet of ``pwl fleet simulate --snapshots --snapshot-samples 5`` (the same engines,
health, flights and noise), its engines ESN011-ESN015 given, from flight 0, an HPT loss of 3 % and
of 4 % (efficiency; flow +half of it), an LPC loss of 4 %, an HPC loss of 3 % (flow alike) and T48
+30 K (truth.csv says so, onset 0). Such an engine has no change of its own: only the fleet's level
(``pwl.fleet.diagnose.level_reference``) tells it. docs/diagnostics.md gives what the diagnosis
makes of it.
"""
from __future__ import annotations

import argparse

import numpy as np

import pwl.cli.fleet_simulate as fs
from models import fleet

#: engine index -> (class, efficiency fraction or T48 bias in K), every one from flight 0
DELIVERED = {10: ("hpt", -0.03), 11: ("hpt", -0.04), 12: ("lpc", -0.04), 13: ("hpc", -0.03),
             14: ("sensor:T48", 30.0)}
_plan_fleet = fleet.plan_fleet


def _delivered(*args, **kwargs):
    plan = _plan_fleet(*args, **kwargs)
    for i, (cls, v) in DELIVERED.items():
        if i >= plan.engines:
            continue
        plan.fault_class[i], plan.onset[i] = cls, 0
        if cls in fleet.COMPONENTS:
            plan.magnitude[i], plan.eff[i], plan.flow[i] = v, v, fleet.COMPONENT_RATIO[cls] * v
            plan.bias[i] = np.nan
        else:
            sensor = cls.split(":", 1)[1]
            plan.bias[i], plan.eff[i], plan.flow[i] = v, 0.0, 0.0
            plan.magnitude[i] = v / (fleet.Turbofan().sensor_noise[sensor] * plan.y_ref[sensor])
    return plan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outdir")
    ap.add_argument("--engines", type=int, default=30)
    ap.add_argument("--flights", type=int, default=30)
    ap.add_argument("--seed", type=int, default=31)
    a = ap.parse_args(argv)
    fleet.plan_fleet = _delivered
    try:
        s = fs.simulate_snapshots(a.outdir, a.engines, a.flights, a.seed, samples=5)
    finally:
        fleet.plan_fleet = _plan_fleet
    print(f"{s['path']}: {s['engines']} engines x {s['flights']} flights, {s['failed']} failed")
    return 1 if s["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
