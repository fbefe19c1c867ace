"""The error budget of an estimate (#17): how much of the Fn, T40 and health error on the demo
flights is model mismatch, how much the tuners' projection of the health parameters, how much
sensor noise through the filter.

    python benchmarks/error_budget.py [--db data/turbofan_demo.h5] [--settle 120]

Runs per flight (RMS over the settled flight, % of truth; health: RMS over the parameters of the
median estimate's error, percentage points):

- ``tuned, as logged``: the normal run (noisy sensors, inputs and ambient channels);
- ``tuned, noise-free``: the same with every logged channel replaced by the simulation's noise-free
  value (the log's truth group): the difference to the first row is what the sensor noise adds;
- ``untuned at the best tuners, noise-free``: tuners held at q* = the least-squares tuners of the
  true health, h_ref + V_pinv q* closest to it (no estimation at all): what is left is the
  piecewise-linear model's mismatch plus the projection of ten health parameters onto the tuners;
- ``untuned at q = 0, noise-free``: the model at nominal health: on the new engine pure model
  mismatch (its true health is nominal), on the degraded one mismatch plus the whole health
  effect the tuners must explain.

Reading it: mismatch = the new engine's last row; projection = the degraded engine's best-tuner
row against mismatch; noise = the first row against the second.
"""
from __future__ import annotations

import argparse
import os

import numpy as np


def main(argv=None) -> int:
    from pwl.cli.demo import errors
    from pwl.demo_data import demo_paths
    from pwl.estimator import Estimator
    from pwl.logs import Log, read_log

    db_default, logs = demo_paths()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", default=db_default, help="gain database (default: the demo's)")
    ap.add_argument("--settle", type=float, default=120.0, help="seconds ignored at the start (default %(default)s)")
    args = ap.parse_args(argv)
    est = Estimator(args.db)
    db = est.db
    Vp = db.tuner["V_pinv"]
    print(f"{'flight':<20}{'run':<42}{'Fn RMS %':>10}{'T40 RMS %':>11}{'health pt':>11}")
    for path in logs:
        log = read_log(path)
        settled = log.time >= log.time[0] + args.settle
        h_true = np.column_stack([log.truth[h] for h in db.names["h"]])
        clean = Log(log.time, {c: log.truth.get(c, v) for c, v in log.channels.items()}, log.units,
                    attrs=log.attrs, path=log.path)
        q_best = np.linalg.lstsq(Vp, np.median(h_true[settled], axis=0) - db.tuner["h_ref"], rcond=None)[0]
        runs = [("tuned, as logged", Estimator(db), log), ("tuned, noise-free", Estimator(db), clean),
                ("untuned at the best tuners, noise-free", Estimator(db, "untuned", q0=q_best), clean),
                ("untuned at q = 0, noise-free", Estimator(db, "untuned"), clean)]
        for label, e, lg in runs:
            r = e.run(lg)
            fn = errors(r.channel("z_hat", "Fn"), log.truth["Fn"], settled)[0]
            t40 = errors(r.channel("z_hat", "T40"), log.truth["T40"], settled)[0]
            dh = 100 * (np.median(r.h_hat[settled], axis=0) - np.median(h_true[settled], axis=0))
            print(f"{os.path.basename(path):<20}{label:<42}{fn:>10.3f}{t40:>11.3f}"
                  f"{float(np.sqrt(np.mean(dh ** 2))):>11.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
