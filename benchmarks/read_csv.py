"""CSV log reading speed (#15): ``read_log`` against ``pandas.read_csv`` on the same file.

    python benchmarks/read_csv.py [--hours 1] [--repeat 5] [--keep FILE.csv]

Writes a log of ``--hours`` at the demo flights' sample interval (the demo flight's channels
repeated end to end, time continuous) to CSV with :func:`pwl.logs.write_csv`, then times the
best of ``--repeat`` reads of that file by ``read_log`` (pwl's full checks: separator, header
units, time column, ragged rows, numeric conversion) and by a bare ``pandas.read_csv``, in the
same run, and prints both and their ratio (the #15 acceptance: ratio <= 1.5). It also checks that
``read_log`` gave back every value written, bit for bit.
"""
from __future__ import annotations

import argparse
import os
import tempfile

import numpy as np


def main(argv=None):
    import pandas as pd

    from pwl.bench.speed import _best_of as best_of
    from pwl.demo_data import demo_paths
    from pwl.logs import Log, read_log, write_csv

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--hours", type=float, default=1.0)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--keep", help="write the CSV here (default: a temporary file, removed after)")
    args = p.parse_args(argv)

    flight = read_log(demo_paths()[1][0])
    dt = flight.dt
    n = int(round(args.hours * 3600 / dt)) + 1
    reps = -(-n // len(flight))
    log = Log(np.arange(n) * dt, {k: np.tile(v, reps)[:n] for k, v in flight.channels.items()},
              dict(flight.units), attrs={"dt": dt})
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or os.path.join(tmp, "hour.csv")
        write_csv(path, log)
        back = read_log(path)
        assert np.array_equal(back.time, log.time) and all(
            np.array_equal(back.channels[k], v) for k, v in log.channels.items()), "values differ"
        t_pwl = best_of(lambda: read_log(path), args.repeat)
        t_pd = best_of(lambda: pd.read_csv(path), args.repeat)
        size = os.path.getsize(path)
    print(f"log: {n} samples x {len(log.channels)} channels + time (dt = {dt * 1e3:g} ms, "
          f"{args.hours:g} h), CSV {size / 1e6:.1f} MB; pandas {pd.__version__}")
    print(f"read_log         best of {args.repeat}: {t_pwl:.3f} s")
    print(f"pandas.read_csv  best of {args.repeat}: {t_pd:.3f} s")
    print(f"ratio read_log / pandas.read_csv: {t_pwl / t_pd:.2f} (acceptance: <= 1.5)")


if __name__ == "__main__":
    main()
