"""Sensors that fail (#15, the unclean world): estimation error with one or more sensors failed
from some point of the flight, against the all-sensor run.

    python benchmarks/sensor_faults.py [--db data/turbofan_demo.h5] [--sensor T48] [--at 0.5]
                                       [--fault dead|stuck|spikes|offset|drift|noisy]

Faults (from --at on): dead = NaN; stuck = frozen at its value then; spikes = 1 % of the samples
20 % high; offset = 3 % high; drift = growing to 5 % high at the end; noisy = 2 % (of the value)
extra Gaussian noise. Dead sensors are also run the old way (no update while any sensor is
missing, the filter open-loop).

For each demo flight and each mode (steady-state gains, online covariance): RMS % error of Fn and
T40 against the simulation's truth over the settled flight after the sensor died (--at, a fraction
of the flight: 0 = from take-off), and the RMS error of the health estimates (percentage points)
over the same samples; "held" counts the steps whose health estimates were held
(FLAG_HEALTH_HELD: a sensor the health estimates depend on is out); "left out" counts the steps
the runtime's checks left a present sensor out (FLAG_STUCK, or FLAG_MISFIT with a partial update).
"""
from __future__ import annotations

import argparse
import os

import numpy as np

FAULTS = ("dead", "stuck", "spikes", "offset", "drift", "noisy")


def fail(kind: str, x: np.ndarray, k0: int, rng) -> np.ndarray:
    """The channel ``x`` with fault ``kind`` from sample k0 on (a copy)."""
    x = np.array(x, dtype=np.float64)
    n = len(x)
    after = np.arange(n) >= k0
    if kind == "dead":
        x[after] = np.nan
    elif kind == "stuck":
        x[after] = x[k0]
    elif kind == "spikes":
        x[after & (rng.random(n) < 0.01)] *= 1.2
    elif kind == "offset":
        x[after] *= 1.03
    elif kind == "drift":
        x[after] *= 1.0 + 0.05 * np.arange(n - k0) / max(n - k0, 1)
    elif kind == "noisy":
        x[after] += 0.02 * np.abs(x[after]) * rng.standard_normal(n - k0)
    return x


def main(argv=None) -> int:
    from pwl.cli.demo import errors
    from pwl.demo_data import demo_paths
    from pwl.estimator import Estimator
    from pwl.logs import Log, read_log
    from pwl.runtime import FLAG_HEALTH_HELD, FLAG_MISFIT, FLAG_PARTIAL, FLAG_STUCK

    db_default, logs = demo_paths()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", default=db_default, help="gain database (default: the demo's)")
    ap.add_argument("--sensor", default="T48",
                    help="the dead sensor, or several separated by commas (default %(default)s)")
    ap.add_argument("--settle", type=float, default=120.0, help="seconds ignored at the start (default %(default)s)")
    ap.add_argument("--at", type=float, default=0.0,
                    help="when the sensor dies, fraction of the flight (default %(default)s: from take-off)")
    ap.add_argument("--fault", choices=FAULTS, default="dead", help="how it fails (default %(default)s)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"{'flight':<20}{'mode':<8}{'run':<26}{'Fn RMS %':>10}{'T40 RMS %':>11}{'health RMS pt':>15}"
          f"{'partial':>9}{'held':>7}{'left out':>10}")
    for path in logs:
        log = read_log(path)
        k0 = int(args.at * len(log))
        chans = dict(log.channels)
        for c in args.sensor.split(","):
            chans[c] = fail(args.fault, log.channels[c], k0, rng)
        dead = Log(log.time, chans, log.units, attrs=log.attrs, path=log.path)
        settled = (log.time >= log.time[0] + args.settle) & (np.arange(len(log)) >= k0)
        h_true = None
        for online in (False, True):
            est = Estimator(args.db, "online" if online else "steady")
            if h_true is None:
                h_true = np.column_stack([log.truth[h] for h in est.db.names["h"]])
            old = Estimator(est.db, est.mode)
            old._model = old._model._replace(ko_tab=np.zeros((1, 0)), sub_tab=np.zeros((1, 0)))  # no update
            runs = [("all sensors", est, log), (f"{args.sensor} {args.fault}", est, dead)]
            if not online and args.fault == "dead":
                runs.append((f"{args.sensor} dead, no update", old, dead))
            for label, e, lg in runs:
                r = e.run(lg)
                fn = errors(r.channel("z_hat", "Fn"), log.truth["Fn"], settled)[0]
                t40 = errors(r.channel("z_hat", "T40"), log.truth["T40"], settled)[0]
                dh = 100 * (r.h_hat[settled] - h_true[settled])
                hr = float(np.sqrt(np.nanmean(dh ** 2)))
                part = int(np.count_nonzero(r.flags & FLAG_PARTIAL))
                held = int(np.count_nonzero(r.flags & FLAG_HEALTH_HELD))
                out = int(np.count_nonzero(((r.flags & FLAG_STUCK) != 0)
                                           | (((r.flags & FLAG_MISFIT) != 0) & ((r.flags & FLAG_PARTIAL) != 0))))
                print(f"{os.path.basename(path):<20}{'online' if online else 'steady':<8}{label:<26}"
                      f"{fn:>10.3f}{t40:>11.3f}{hr:>15.3f}{part:>9}{held:>7}{out:>10}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
