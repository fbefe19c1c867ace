"""Logs slower than the database, and logs with a gap: estimation error against the simulation's truth.

    python benchmarks/slow_logs.py

The degraded demo flight (15 ms) is decimated to 30 ms, 150 ms, 1 s and 4 s and run with
``Estimator(resample=True)`` (updates on the logged samples only, docs/runtime.md); then 60 s
are cut from the middle of the 15 ms flight (run as it is) and of the 30 ms one (resampled: no
row inside the gap). Printed per case: result rows, Fn RMS error (% of truth, at the result's
rows) and the end-of-flight health RMS error (percentage points over the 10 health parameters).
"""
import warnings

import numpy as np


def main():
    from pwl import Estimator, GainDatabase
    from pwl.demo_data import demo_paths
    from pwl.logs import Log, read_log

    warnings.simplefilter("ignore")
    db_path, logs = demo_paths()
    db = GainDatabase.open(db_path)
    log = read_log([p for p in logs if "degraded" in p][0])
    n = len(log)

    def take(rows):
        return Log(log.time[rows], {k: v[rows] for k, v in log.channels.items()}, log.units, path="cut")

    def show(label, rows, resample):
        res = Estimator(db, resample=resample).run(take(rows))
        fn = np.interp(res.time, log.time, log.truth["Fn"])
        e_fn = 100 * np.sqrt(np.mean(((res.channel("z_hat", "Fn") - fn) / fn) ** 2))
        truth = np.array([log.truth[h][-1] for h in res.names["h_hat"]])
        e_h = 100 * np.sqrt(np.mean((res.outputs["h_hat"][-1] - truth) ** 2))
        gaps = res.attrs["provenance"]["time_gaps"]
        print(f"{label:<28} {res.time.size:>7} {e_fn:>9.3f} {e_h:>11.3f} {gaps:>5}")

    print(f"{'log':<28} {'rows':>7} {'Fn RMS %':>9} {'health pt':>11} {'gaps':>5}")
    show("15 ms (as logged)", np.arange(n), False)
    for step, label in ((2, "30 ms"), (10, "150 ms"), (67, "1 s"), (267, "4 s")):
        show(f"{label}, resampled", np.arange(0, n, step), True)
    cut = int(60 / 0.015)
    show("15 ms, 60 s gap", np.r_[0:n // 2, n // 2 + cut:n], False)
    show("30 ms, 60 s gap, resampled", np.r_[0:n // 2:2, n // 2 + cut:n:2], True)


if __name__ == "__main__":
    main()
