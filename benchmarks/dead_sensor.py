"""A sensor dead from take-off (#15): estimation error with the sensor-out gains against the
all-sensor run and against the old behaviour (no update while any sensor is missing).

    python benchmarks/dead_sensor.py [--db data/turbofan_demo.h5] [--sensor T48] [--at 0.5]

For each demo flight and each mode (steady-state gains, online covariance): RMS % error of Fn and
T40 against the simulation's truth over the settled flight after the sensor died (--at, a fraction
of the flight: 0 = from take-off), and the RMS error of the health estimates (percentage points)
over the same samples; "held" counts the steps whose health estimates were held
(FLAG_HEALTH_HELD: a sensor the health estimates depend on is out). "no update" is the filter run
open-loop after the sensor died, as every version before the sensor-out gains did.
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
    from pwl.runtime import FLAG_HEALTH_HELD, FLAG_PARTIAL

    db_default, logs = demo_paths()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", default=db_default, help="gain database (default: the demo's)")
    ap.add_argument("--sensor", default="T48",
                    help="the dead sensor, or several separated by commas (default %(default)s)")
    ap.add_argument("--settle", type=float, default=120.0, help="seconds ignored at the start (default %(default)s)")
    ap.add_argument("--at", type=float, default=0.0,
                    help="when the sensor dies, fraction of the flight (default %(default)s: from take-off)")
    args = ap.parse_args(argv)
    print(f"{'flight':<20}{'mode':<8}{'run':<22}{'Fn RMS %':>10}{'T40 RMS %':>11}{'health RMS pt':>15}"
          f"{'partial':>9}{'held':>7}")
    for path in logs:
        log = read_log(path)
        k0 = int(args.at * len(log))
        chans = dict(log.channels)
        for c in args.sensor.split(","):
            chans[c] = np.where(np.arange(len(log)) >= k0, np.nan, log.channels[c])
        dead = Log(log.time, chans, log.units, attrs=log.attrs, path=log.path)
        settled = (log.time >= log.time[0] + args.settle) & (np.arange(len(log)) >= k0)
        h_true = None
        for online in (False, True):
            est = Estimator(args.db, "online" if online else "steady")
            if h_true is None:
                h_true = np.column_stack([log.truth[h] for h in est.db.names["h"]])
            old = Estimator(est.db, est.mode)
            old._model = old._model._replace(ko_tab=np.zeros((1, 0)), sub_tab=np.zeros((1, 0)))  # no update
            runs = [("all sensors", est, log), (f"{args.sensor} dead", est, dead)]
            if not online:
                runs.append((f"{args.sensor} dead, no update", old, dead))
            for label, e, lg in runs:
                r = e.run(lg)
                fn = errors(r.channel("z_hat", "Fn"), log.truth["Fn"], settled)[0]
                t40 = errors(r.channel("z_hat", "T40"), log.truth["T40"], settled)[0]
                dh = 100 * (r.h_hat[settled] - h_true[settled])
                hr = float(np.sqrt(np.nanmean(dh ** 2)))
                part = int(np.count_nonzero(r.flags & FLAG_PARTIAL))
                held = int(np.count_nonzero(r.flags & FLAG_HEALTH_HELD))
                print(f"{os.path.basename(path):<20}{'online' if online else 'steady':<8}{label:<22}"
                      f"{fn:>10.3f}{t40:>11.3f}{hr:>15.3f}{part:>9}{held:>7}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
