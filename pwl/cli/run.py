"""pwl run DB.h5 LOG... -o OUTDIR: estimates for every log, one results file per log."""
import glob
import os
import sys
import time

HELP = ("run the piecewise-linear Kalman filter over flight logs (HDF5, CSV, Parquet); exit status 1 "
        "when a log failed or had too few measurement updates")
MIN_UPDATED = 0.5


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5)")
    p.add_argument("logs", nargs="+", help="log files or folders (every .h5/.csv/.parquet inside)")
    p.add_argument("-o", "--outdir", required=True,
                   help="folder for the results (one LOG.estimates.h5 per log; created if missing)")
    p.add_argument("--csv", action="store_true", help="write CSV results instead of HDF5")
    p.add_argument("-j", "--workers", type=int, default=None,
                   help="parallel processes (default: the number of cores)")
    p.add_argument("--resample", action="store_true",
                   help="resample logs whose sample interval differs from the database's dt by more "
                        "than 1 %% (linear interpolation; default: such logs are refused)")
    p.add_argument("--min-updated", type=float, default=MIN_UPDATED, metavar="FRACTION",
                   help="exit status 1 when a log has a measurement update at fewer than this "
                        "fraction of its samples (default %(default)s): the estimates of such a log "
                        "are mostly open-loop predictions")
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
    from ..errors import EXIT_FINDINGS, EXIT_INPUT
    from ..estimator import Estimator
    from ..fleet_run import run_many

    from .output import check_output

    db = GainDatabase.open(args.database)  # fail early, with the named error, on a bad database
    Estimator(db, online=args.online, zones=args.zones)  # and on options it cannot serve
    check_output(args.outdir, folder=True)   # and on an output folder it cannot write
    logs, names = expand(args.logs, with_names=True)
    if not logs:
        print("pwl run: no logs found", file=sys.stderr)
        return EXIT_INPUT
    t0 = time.perf_counter()
    short = []

    def progress(done, total, item):
        log, out, counts, err = item
        if err:
            status = f"error: {err}"
        else:
            status = f"{describe(counts)} -> {out}"
            why = too_few(counts, args.min_updated)
            if why:
                short.append(log)
                status += f"\n    TOO FEW ESTIMATES: {why}"
        print(f"[{done}/{total}] {log}: {status}", file=sys.stderr, flush=True)

    if len(set(names)) != len(names):       # files given directly with the same name
        names = None
    results = run_many(args.database, logs, args.outdir, args.workers, args.csv, progress, online=args.online,
                       zones=args.zones, names=names, resample=args.resample)
    failed = [r for r in results if r[3]]
    n = sum(r[2]["samples"] for r in results if r[2])
    dt = time.perf_counter() - t0
    print(f"{len(results) - len(failed)} of {len(results)} logs done, {n} samples in {dt:.2f} s "
          f"({n / dt:,.0f} samples/s including start-up and I/O)")
    if failed or short:
        print(f"pwl run: {len(failed)} log(s) failed, {len(short)} with too few estimates "
              f"(fewer than {args.min_updated:.0%} of samples updated); see above", file=sys.stderr)
        return EXIT_FINDINGS
    return 0


#: flag counts in the order they are printed, with their labels
FLAG_LABELS = (("updated", "updated"), ("no_update", "without update"),
               ("held_input", "input held"), ("implausible", "implausible"), ("misfit", "misfit"),
               ("health_implausible", "implausible health"),
               ("trim_outside", "outside the trim grid"), ("dyn_outside", "outside the dynamics grid"),
               ("not_started", "before the first valid sample"))


def describe(counts: dict) -> str:
    """One line: the sample count and every flag count of a log's run."""
    n = max(counts["samples"], 1)
    parts = [f"{counts[k]} {label}" + (f" ({counts[k] / n:.0%})" if k == "updated" else "")
             for k, label in FLAG_LABELS if k in counts]
    return f"{counts['samples']} samples: " + ", ".join(parts)


def too_few(counts: dict, min_updated: float) -> str:
    """Why a log's estimates cannot be trusted (fewer than ``min_updated`` of its samples had a
    measurement update), naming the channels that were missing or implausible; "" if fine."""
    n = counts["samples"]
    if n and counts.get("updated", n) >= min_updated * n:
        return ""
    missing = sorted(((v, c) for c, v in (counts.get("missing_channels") or {}).items() if v), reverse=True)
    chans = ", ".join(f"{c} {v / max(n, 1):.0%}" for v, c in missing[:4])
    return (f"{counts.get('updated', 0)} of {n} samples had a measurement update"
            + (f"; missing or implausible: {chans}" if chans else ""))
