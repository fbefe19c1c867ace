"""pwl run DB.h5 LOG... -o OUTDIR: estimates for every log, one results file per log."""
import contextlib
import os
import sys
import time

from ..results import COMPRESSIONS, DEFAULT_COMPRESSION
from ..errors import UsageError
from ..estimator import MODES
from ..runtime import HEALTH_HOLD_RATIO, MISFIT_SIGMAS, STUCK_AFTER

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
                   help="parallel processes on this machine (default: the number of cores)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run the logs on a Dask cluster: a scheduler address (tcp://host:8786), or "
                        "local:N for a local cluster of N worker processes; its workers must see the "
                        "database, the logs and OUTDIR at the same paths (default: a local process pool)")
    p.add_argument("--force", action="store_true",
                   help="recompute every log (default: a log whose results file holds results of the same "
                        "database, mode, log and outputs is skipped, so an interrupted run resumes)")
    p.add_argument("--outputs", metavar="NAMES",
                   help="comma-separated outputs to write, e.g. h_hat,z_hat (time and flags are always "
                        "written; default: all: x_hat,q_hat,h_hat,y_hat,residual,z_hat and h_std online)")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="write every N-th sample only (the flag counts, residual RMS and steady snapshots "
                        "still use every sample; default %(default)s)")
    p.add_argument("--compression", choices=sorted(COMPRESSIONS), default=DEFAULT_COMPRESSION,
                   help="HDF5 compression of the results: gzip (deflate 4 + shuffle, read by every HDF5 "
                        "tool), lzf (faster, h5py only) or none (default %(default)s; docs/runtime.md)")
    p.add_argument("--channel-map", metavar="MAP.toml",
                   help="read every log through this channel map: the log's column names and units -> "
                        "the model's channels (docs/runtime.md, Log formats; default: none)")
    p.add_argument("--resample", action="store_true",
                   help="resample logs whose sample interval differs from the database's dt by more "
                        "than 1 %% (inputs interpolated linearly; the filter updates on the logged samples only "
                        "and reports one row per sample; default: such logs are refused)")
    p.add_argument("--min-updated", type=float, default=MIN_UPDATED, metavar="FRACTION",
                   help="exit status 1 when a log has a measurement update, trusted estimates, or health "
                        "estimates (not held), at fewer than this fraction of its samples (default "
                        "%(default)s): such a log's estimates are mostly open-loop predictions, or with "
                        "implausible health, or the model explains none of its sensors, or a sensor the "
                        "health estimates need was missing")
    p.add_argument("--mode", choices=MODES, default=None,
                   help="how the update gain is made: steady (default) the database's steady-state "
                        "gains; untuned: the same with the tuners held at 0; online: the full Kalman "
                        "filter, covariance propagated and gain solved every step (about 7x slower; for "
                        "comparison); zones: the gain of the database's k-means zones (/zones, from pwl "
                        "zones --database DB --out ZONED.h5)")
    p.add_argument("--misfit-sigmas", type=float, default=MISFIT_SIGMAS, metavar="N",
                   help="leave a sensor out of a step's update when its residual exceeds N sensor "
                        "standard deviations (while fewer than half misfit; default %(default)g; inf: never)")
    p.add_argument("--stuck-after", type=float, default=STUCK_AFTER, metavar="SECONDS",
                   help="a sensor whose value stays exactly the same this long (and whose prediction "
                        "moved, or which used to change every sample) is stuck and left out "
                        "(default %(default)g; inf: never)")
    p.add_argument("--may-hold", type=may_hold, default=(), metavar="INPUT[,INPUT]",
                   help="inputs that may legitimately hold one value exactly while altitude, Mach or the "
                        "engine move (variable geometry at a stop, a closed bleed valve): never flagged as a "
                        "frozen word or a meter at the end of its range (input held); default: none")
    p.add_argument("--settle", type=float, default=None, metavar="SECONDS",
                   help="the filter's settling time: samples this long after its start (or after an outage "
                        "longer than it) are flagged settling and not trusted (default: 3 time constants of "
                        "the database's slowest error dynamics, `pwl info`; a slow plant's 10-minute logs may "
                        "need less)")
    p.add_argument("--health-hold", type=float, default=HEALTH_HOLD_RATIO, metavar="RATIO",
                   help="hold the health estimates while a sensor is out without which their "
                        "standard deviation grows more than RATIO times (default %(default)g; inf: never)")
    p.add_argument("--online", action="store_true", help="the same as --mode online")
    p.add_argument("--zones", action="store_true", help="the same as --mode zones")


def may_hold(text: str) -> tuple:
    """The input names of ``--may-hold A8,B`` (a tuple: the checks travel to the workers hashed)."""
    return tuple(c.strip() for c in text.split(",") if c.strip())


def run_mode(args) -> str:
    """The estimator mode of --mode, --online, --zones (one of them at most)."""
    given = [m for m in (args.mode, "online" if args.online else None, "zones" if args.zones else None) if m]
    if len(set(given)) > 1:
        raise UsageError(f"choose one estimator mode (given: {', '.join(given)})")
    return given[0] if given else "steady"


def expand(paths, with_names: bool = False, any_hdf5: bool = False):
    """Files as given; in folders (walked recursively, e.g. a fleet's ENGINE/flight.h5 tree) every
    .csv/.tsv/.parquet/.mat and every HDF5 file that is a flight log (other HDF5 files there, e.g.
    a gain database or results, are skipped with a note; ``any_hdf5``: every HDF5 file but pwl's
    databases and results, for logs read through a channel map). ``with_names``: also return each
    log's results name (its path relative to the folder given, the file name for files given
    directly)."""
    from ..h5io import attr_str
    from ..logs import FORMAT, LOG_SUFFIXES

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
                      if f.lower().endswith(LOG_SUFFIXES)
                      and not f.startswith(".") and ".estimates." not in f]
        for f in sorted(found):
            if f.lower().endswith((".h5", ".hdf5")):
                try:
                    with h5py.File(f, "r") as h:
                        fmt = attr_str(h, "format")
                except OSError:
                    fmt = None
                other_layout = any_hdf5 and not str(fmt or "").startswith("pwl-")
                if fmt != FORMAT and not other_layout:
                    print(f"pwl run: skipping {f} (not a flight log: format {fmt!r})", file=sys.stderr)
                    continue
            elif os.path.basename(f) in ("truth.csv", "diagnosis.csv", "summary.csv", "summary.parquet"):
                continue
            out.append(f)
            names.append(os.path.relpath(f, p))
    return (out, names) if with_names else out


def run(args) -> int:
    from linearize.build import Progress

    from ..database import GainDatabase
    from ..errors import EXIT_FINDINGS, EXIT_INPUT, UsageError
    from ..estimator import Estimator
    from ..fleet.runs import FAILED, SKIPPED, remove_summary, run_many, write_summary
    from ..results import check_every, select_outputs

    from .output import check_output

    db = GainDatabase.open(args.database)  # fail early, with the named error, on a bad database
    mode = run_mode(args)
    checks = {"misfit_sigmas": args.misfit_sigmas, "stuck_after": args.stuck_after,
              "health_hold": args.health_hold, "may_hold": args.may_hold, "settle": args.settle}
    est = Estimator(db, mode, channel_map=args.channel_map, **checks)   # and on options it cannot serve
    select_outputs(est.names, args.outputs, where="--outputs")
    check_every(args.every)
    if not 0.0 <= args.min_updated <= 1.0:
        raise UsageError(f"--min-updated {args.min_updated}: a fraction of the samples, 0 to 1")
    if args.dask and args.workers:
        raise UsageError("-j/--workers sizes the local process pool; with --dask the cluster's workers "
                         "run the logs (use --dask local:N for N local workers)")
    check_output(args.outdir, folder=True)   # and on an output folder it cannot write
    logs, names = expand(args.logs, with_names=True, any_hdf5=args.channel_map is not None)
    if not logs:
        print("pwl run: no logs found", file=sys.stderr)
        return EXIT_INPUT
    if len(set(names)) != len(names):       # files given directly with the same name
        names = None
    remove_summary(args.outdir)      # an interrupted run must not leave the last run's summary
    t0 = time.perf_counter()
    short = []
    bar = Progress("logs", len(logs))
    bar.EVERY_FRACTION = 0.05      # off a terminal: a line per 5 % of the logs (and 5 s)

    def say(msg):
        print(("\r\x1b[K" if bar.tty else "") + msg, file=sys.stderr, flush=True)

    def progress(done, total, item):
        if item.error:
            say(f"{item.log}: error: {item.error}")
        else:                                   # skipped logs too: a rerun exits as the run did
            why = too_few(item.counts, args.min_updated)
            if why:
                short.append(item.log)
                say(f"{item.log}: {describe(item.counts)} -> {item.output}\n    TOO FEW ESTIMATES: {why}")
        bar.update(done)

    with _executor(args, len(logs)) as executor:
        results = run_many(db, logs, args.outdir, args.workers, args.csv, progress, mode=mode,
                           names=names, resample=args.resample,
                       channel_map=args.channel_map, executor=executor,
                           outputs=args.outputs, every=args.every, compression=args.compression,
                           force=args.force, checks=checks)
    failed = [r for r in results if r.status == FAILED]
    skipped = [r for r in results if r.status == SKIPPED]
    n = sum(r.counts["samples"] for r in results if r.counts and r.status != SKIPPED)
    dt = time.perf_counter() - t0
    path = write_summary(results, args.outdir)
    print(f"{len(results) - len(failed)} of {len(results)} logs done, {n} samples computed in {dt:.2f} s "
          f"({n / dt:,.0f} samples/s including start-up and I/O)")
    done = [r.counts for r in results if r.counts]
    if done:
        print("all logs: " + describe({k: sum(c.get(k) or 0 for c in done) for k in done[0]
                                       if k in dict(FLAG_LABELS) or k == "samples"}))
    if skipped:
        print(f"{len(skipped)} log(s) skipped: their results files already hold results of the same "
              f"database, mode, log and outputs (--force recomputes them)")
    print(f"fleet summary: {path}" + ("" if path.endswith(".parquet") else
                                      " (CSV: Parquet needs pandas and pyarrow)"))
    if failed or short:
        print(f"pwl run: {len(failed)} log(s) failed, {len(short)} with too few estimates "
              f"(fewer than {args.min_updated:.0%} of samples updated, trusted or with health estimated); see above",
              file=sys.stderr)
        return EXIT_FINDINGS
    return 0


@contextlib.contextmanager
def _executor(args, n_logs: int):
    """The executor of ``pwl run``: a Dask client (``--dask``), a process pool whose workers die
    with this process (``-j`` > 1), or None (one log after the other in this process)."""
    from ..errors import UsageError

    if args.dask:
        try:
            from dask.distributed import Client
        except ImportError:
            raise UsageError("--dask needs dask.distributed: pip install 'dask[distributed]'") from None
        if args.dask.startswith("local:"):
            from ..fleet.runs import local_dask_cluster
            try:
                n = int(args.dask[len("local:"):])
            except ValueError:
                n = 0
            if n < 1:
                raise UsageError(f"--dask {args.dask}: local:N needs a number of workers N >= 1")
            with local_dask_cluster(n) as cluster, Client(cluster) as c:
                yield c
        else:
            try:
                client = Client(args.dask, timeout="20s")
            except OSError as e:
                raise UsageError(f"--dask {args.dask}: cannot reach the Dask scheduler ({e})") from None
            with client:
                yield client
        return
    workers = max(1, min(n_logs, args.workers or os.cpu_count() or 1))
    if workers == 1:
        yield None
        return
    from ..workers import process_pool
    pool = process_pool(workers)
    try:
        yield pool
    finally:
        pool.shutdown(cancel_futures=True)


#: flag counts in the order they are printed, with their labels
FLAG_LABELS = (("updated", "updated"), ("trusted", "trusted"), ("no_update", "without update"), ("partial", "partial update"),
               ("held_input", "input held"), ("implausible", "implausible"), ("misfit", "misfit"),
               ("health_implausible", "implausible health"), ("health_held", "health held"), ("stuck", "stuck sensor"),
               ("trim_outside", "outside the trim grid"), ("dyn_outside", "outside the dynamics grid"),
               ("not_started", "before the first valid sample"), ("settling", "settling"),
               ("air_data", "air data disagree"), ("trim_filled", "trims filled by the build"),
               ("far_outside", "far outside the trim grid"))


def describe(counts: dict) -> str:
    """One line: the sample count and every flag count of a log's run."""
    n = max(counts["samples"], 1)
    parts = [f"{counts[k]} {label}" + (f" ({counts[k] / n:.0%})" if k in ("updated", "trusted") else "")
             for k, label in FLAG_LABELS if counts.get(k) is not None]   # None: an older file's
    return f"{counts['samples']} samples: " + ", ".join(parts)


def too_few(counts: dict, min_updated: float) -> str:
    """Why a log's estimates cannot be trusted -- fewer than ``min_updated`` of its samples had a
    measurement update, or were trusted (:func:`pwl.results.trusted`: plausible health, a model
    that explains the sensors), or had their health estimated (not held) -- naming the channels
    that were missing or implausible, or misfit, and what else was flagged; "" if fine. The
    samples before the filter's start (an engine not yet running) do not count."""
    total = counts["samples"]
    n = total - (counts.get("not_started") or 0)
    updated = counts.get("updated", n)
    good = counts.get("trusted", updated)      # results files written before "trusted"
    held = counts.get("health_held", 0)
    if n and good >= min_updated * n and n - held >= min_updated * n:
        return ""
    def worst(key):    # the four channels with the most samples under ``key``, as percentages
        top = sorted(((v, c) for c, v in (counts.get(key) or {}).items() if v), reverse=True)[:4]
        return ", ".join(f"{c} {v / max(total, 1):.0%}" for v, c in top)
    chans = [f"{label}: {worst(key)}" for key, label in (("missing_channels", "missing or implausible"),
                                                          ("misfit_channels", "misfit")) if worst(key)]
    if counts.get("failed_channels"):
        chans.insert(0, "failed for the log (misfit, left out): " + ", ".join(counts["failed_channels"]))
    after = f" after the filter's start ({total - n} before it)" if total > n else ""
    if not n:
        why = f"the filter never started: none of the {total} samples had every input and scheduling channel valid"
    elif updated < min_updated * n:
        why = f"{updated} of {n} samples had a measurement update{after}"
    elif good < min_updated * n and (counts.get("settling") or 0) >= n - good:
        why = (f"{good} of {n} samples trusted{after}, {counts['settling']} within the filter's settling time from its "
               "first valid sample (its estimates still converging): the log is too short")
    elif good < min_updated * n:
        flagged = ", ".join(f"{label} {counts[k] / n:.0%}" for k, label in (
            ("air_data", "altitude, Mach and inlet pressure disagree"), ("held_input", "input held"),
            ("misfit", "misfit"), ("health_implausible", "implausible health"),
            ("far_outside", "far outside the trim grid"), ("trim_filled", "trims the build filled"),
            ("settling", "within the filter's settling time")) if counts.get(k))
        why = (f"{good} of {n} samples trusted{after} ({flagged}: a unit mistake, a wrong or failed channel or the "
               "wrong database?)")
    else:
        why = (f"health held on {held} of {n} samples{after} (not estimated: a sensor the health estimates need was "
               "missing, stuck or misfitting)")
    return why + "".join(f"; {c}" for c in chans)