"""pwl run DB.h5 LOG... -o OUTDIR: estimates for every log, one results file per log."""
import glob
import os
import sys
import time

HELP = "run the piecewise-linear Kalman filter over flight logs (HDF5, CSV, Parquet)"


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5)")
    p.add_argument("logs", nargs="+", help="log files or folders (every .h5/.csv/.parquet inside)")
    p.add_argument("-o", "--outdir", required=True, help="folder for the results")
    p.add_argument("--csv", action="store_true", help="write CSV results instead of HDF5")
    p.add_argument("-j", "--workers", type=int, default=None, help="parallel processes (default: cores)")
    p.add_argument("--online", action="store_true",
                   help="full Kalman filter: propagate the covariance and solve the gain every step "
                        "(about 7x slower than the database's steady gains; for comparison)")
    p.add_argument("--zones", action="store_true",
                   help="pick the gain of the database's k-means zones (/zones, from pwl zones --database "
                        "DB --out ZONED.h5) instead of interpolating it")


def expand(paths, with_names: bool = False):
    """Files as given; in folders (walked recursively, e.g. a fleet's ENGINE/flight.h5 tree) every
    .csv/.parquet and every HDF5 file that is a flight log (other HDF5 files there, e.g. a gain
    database or results, are skipped with a note). ``with_names``: also return each log's results
    name (its path relative to the folder given, the file name for files given directly)."""
    from ..h5io import attr_str
    from ..logs import FORMAT

    import h5py

    out, names = [], []
    for p in paths:
        if not os.path.isdir(p):
            out.append(p)
            names.append(os.path.basename(p))
            continue
        found = []
        for folder, dirs, files in os.walk(p):
            dirs.sort()
            found += [os.path.join(folder, f) for f in files
                      if f.lower().endswith((".h5", ".hdf5", ".csv", ".parquet"))
                      and not f.startswith(".") and ".estimates." not in f]
        for f in sorted(found):
            if f.lower().endswith((".h5", ".hdf5")):
                try:
                    with h5py.File(f, "r") as h:
                        fmt = attr_str(h, "format")
                except OSError:
                    fmt = None
                if fmt != FORMAT:
                    print(f"pwl run: skipping {f} (not a flight log: format {fmt!r})", file=sys.stderr)
                    continue
            elif os.path.basename(f) in ("truth.csv", "diagnosis.csv", "summary.csv"):
                continue
            out.append(f)
            names.append(os.path.relpath(f, p))
    return (out, names) if with_names else out


def run(args) -> int:
    from ..database import GainDatabase
    from ..estimator import Estimator, run_many

    db = GainDatabase.open(args.database)  # fail early, with the named error, on a bad database
    try:  # and on options the database cannot serve (no /zones, online with zones)
        Estimator(db, online=args.online, zones=args.zones)
    except ValueError as e:
        print(f"pwl run: {e}", file=sys.stderr)
        return 2
    logs, names = expand(args.logs, with_names=True)
    if not logs:
        print("pwl run: no logs found", file=sys.stderr)
        return 2
    t0 = time.perf_counter()

    def progress(done, total, item):
        log, out, counts, err = item
        status = f"error: {err}" if err else (
            f"{counts['samples']} samples, {counts['no_update']} without update, "
            f"{counts['trim_outside']} outside the grid -> {out}")
        print(f"[{done}/{total}] {log}: {status}", file=sys.stderr, flush=True)

    if len(set(names)) != len(names):       # files given directly with the same name
        names = None
    results = run_many(args.database, logs, args.outdir, args.workers, args.csv, progress, online=args.online,
                       zones=args.zones, names=names)
    failed = [r for r in results if r[3]]
    n = sum(r[2]["samples"] for r in results if r[2])
    dt = time.perf_counter() - t0
    print(f"{len(results) - len(failed)} of {len(results)} logs done, {n} samples in {dt:.2f} s "
          f"({n / dt:,.0f} samples/s including start-up and I/O)")
    return 1 if failed else 0
