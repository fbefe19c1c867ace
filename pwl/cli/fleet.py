"""pwl fleet simulate|diagnose|score: a ProDiMES-style fleet benchmark of the diagnostics.

  pwl fleet simulate --engines 100 --flights 20 --seed 0 -o FLEET/   # logs + FLEET/truth.csv
  pwl run data/turbofan_demo.h5 FLEET/ -o RESULTS/                    # estimates + snapshots
  pwl fleet diagnose RESULTS/ -o diagnosis.csv                        # detect, isolate, size
  pwl fleet score diagnosis.csv FLEET/truth.csv --json                # TPR, FPR, kappa, ...
"""
import glob
import json
import os
import re
import sys
from functools import partial

from .output import check_output, plot_or_note

HELP = "fleet benchmark: simulate a fleet with faults, diagnose it, score a diagnosis"
#: ``pwl fleet diagnose --plot`` draws every engine of a fleet up to this size, else those with a finding
CHART_ALL = 40


def add_arguments(p):
    sub = p.add_subparsers(dest="fleet_command", metavar="STEP")
    sub.required = True
    from .fleet_simulate import add_simulate_arguments, run_simulate
    s = sub.add_parser("simulate", help="simulate N engines x M flights with faults (logs and truth.csv)",
                       description="simulate N engines x M flights with faults (logs and truth.csv)")
    add_simulate_arguments(s)
    s.set_defaults(_step=run_simulate)

    d = sub.add_parser("diagnose", help="detect, isolate and size faults from pwl run results",
                       description="detect, isolate and size faults from pwl run results, one row per "
                                   "engine and flight (docs/diagnostics.md); exit status 1 when an engine "
                                   "has a fault at its latest flight (a finding, as for pwl trend) or an "
                                   "unreadable results file was skipped (named)")
    d.add_argument("results", nargs="+",
                   help="results files or folders (walked recursively) of pwl run, or snapshot tables "
                        "(.csv, .tsv, .parquet, .xlsx: one row per steady snapshot, docs/diagnostics.md; they need "
                        "--database)")
    d.add_argument("-o", "--output", default="diagnosis.csv", help="CSV to write (default %(default)s)")
    d.add_argument("--database", help="gain database (default: the one recorded in the results)")
    d.add_argument("--channel-map", metavar="TOML",
                   help="the snapshot tables' column names and units -> the model's (docs/runtime.md; "
                        "default: the tables' own)")
    d.add_argument("--alpha", type=float, default=None,
                   help="false-alarm probability per engine and flight (default 1e-3)")
    d.add_argument("--kappa", type=float, default=None,
                   help="isolation cost per free parameter of a hypothesis, in units of the "
                        "chi-square test statistic (default 6)")
    d.add_argument("--engine-pattern", metavar="REGEX",
                   help="the engine serial from each results file's name: the regular expression's first "
                        "group, or its match (e.g. 'ESN\\d+'); default: the logs' engine attribute, else the "
                        "folder name")
    d.add_argument("--no-pairs", action="store_true",
                   help="do not test changes of two causes: two components, a component and a sensor "
                        "(default: tested)")
    d.add_argument("--new-baseline", metavar="ENGINE:FLIGHT", action="append", default=[], help=NEW_BASELINE_HELP)
    d.add_argument("--exclude", metavar="ENGINE:FLIGHT", action="append", default=[], help=EXCLUDE_HELP)
    d.add_argument("-j", "--workers", type=int, default=os.cpu_count() or 1,
                   help="engines diagnosed at once, in as many processes (default: the number of cores)")
    d.add_argument("--plot", metavar="PNG",
                   help="the fleet at a glance: an engine a line, a flight a column, coloured by the class "
                        f"found (every engine of a fleet of up to {CHART_ALL} engines, else those with a "
                        "finding), needs matplotlib (default: none)")
    d.set_defaults(_step=run_diagnose)

    c = sub.add_parser("score", help="score a diagnosis CSV against a fleet's truth.csv",
                       description="ProDiMES-style metrics of a diagnosis (any method writing the "
                                   "diagnosis.csv columns engine, flight, detected, class)")
    c.add_argument("diagnosis", help="diagnosis CSV (pwl fleet diagnose, or another method's)")
    c.add_argument("truth", help="truth.csv of the fleet (pwl fleet simulate)")
    c.add_argument("--json", action="store_true", help="print the metrics as JSON (default: a table)")
    c.add_argument("--plot", help="PNG file of the confusion matrix, needs matplotlib (default: none)")
    c.add_argument("--min-component", type=float, default=0.0,
                   help="detectability magnitude of component faults, |efficiency change| as a fraction, "
                        "e.g. 0.01 for 1 %% (default 0: all)")
    c.add_argument("--min-sensor-sigma", type=float, default=0.0,
                   help="detectability magnitude of sensor biases, in sensor noise sigmas (default 0: all)")
    c.set_defaults(_step=run_score)


def run(args) -> int:
    return args._step(args)


def results_files(paths) -> list[str]:
    """The results files of ``paths`` (files, or folders walked recursively), each file once: a
    folder given twice, or reached again through a symbolic link (a link to a parent folder
    repeated its files thousands of times), is read once."""
    out, seen = [], set()
    for p in paths:
        found = sorted(glob.glob(os.path.join(p, "**", "*.estimates.h5"), recursive=True)) if os.path.isdir(p) else [p]
        for f in found:
            real = os.path.realpath(f)
            if real not in seen:
                seen.add(real)
                out.append(f)
    return out


def read_flights(files, engine_pattern=None):
    """FlightRecords of the readable results files, and (file, reason) for the others (reported on
    stderr: one corrupt or foreign file must not stop a fleet's diagnosis)."""
    from ..fleet.diagnose import DiagnosisError, read_flight
    records, skipped = [], []
    for f in files:
        try:
            records.append(read_flight(f, engine_pattern))
        except DiagnosisError as e:
            skipped.append((f, str(e)))
    if skipped:
        print(f"{len(skipped)} of {len(files)} results files skipped:", file=sys.stderr)
        for f, why in skipped:
            print(f"  {why}", file=sys.stderr)
    return records, skipped


def read_inputs(command, paths, database=None, channel_map=None, engine_pattern=None):
    """(records, skipped) of ``paths``: results files and folders of ``pwl run`` (:func:`read_flights`)
    and snapshot tables (files, :func:`pwl.fleet.snapshot_table.read_snapshot_table`, which need
    ``database``), serials that differ only in case, spaces or leading zeros made one (named:
    :func:`pwl.fleet.diagnose.same_engines`); (None, []) after printing why when there is nothing
    to read or no database."""
    from ..database import GainDatabase
    from ..fleet.diagnose import same_engines
    from ..fleet.snapshot_table import is_snapshot_table, read_snapshot_table
    tables = [p for p in paths if not os.path.isdir(p) and is_snapshot_table(p)]
    files = results_files([p for p in paths if p not in tables])
    if not files and not tables:
        found = [os.path.join(d, f) for p in paths if os.path.isdir(p)
                 for d, _, fs in os.walk(p) for f in sorted(fs) if is_snapshot_table(f)][:1]
        hint = f"; snapshot tables are given as files: {command} {found[0]} --database DB" if found else ""
        print(f"{command}: no results files (*.estimates.h5) found{hint}", file=sys.stderr)
        return None, []
    if tables and not database:
        print(f"{command}: {tables[0]}: a snapshot table records no database: give --database", file=sys.stderr)
        return None, []
    records, skipped = read_flights(files, engine_pattern)
    if tables:
        db = GainDatabase.open(database)
        for t in tables:
            records += read_snapshot_table(t, db, channel_map)
    for line in same_engines(records):
        print(f"pwl: warning: {line}", file=sys.stderr)
    return records, skipped


def database_of(records, given=None) -> str:
    """The gain database to diagnose with: ``given``, else the one every results file names
    (a UsageError naming them when they differ or name none)."""
    from ..errors import UsageError
    if given:
        return given
    dbs = sorted({r.database for r in records if r.database})
    if len(dbs) != 1:
        raise UsageError(("the results name several databases: " + ", ".join(dbs) if dbs else
                          "the results do not name their database") + "; give --database")
    return dbs[0]


NEW_BASELINE_HELP = ("the engine starts a new baseline at that flight number (a shop visit, a module change, "
                     "moved to another aircraft): what changed there is not a fault; repeat for more "
                     "(default: none)")
EXCLUDE_HELP = ("leave that flight out (flown off the engine's usual configuration: anti-ice or a customer "
                "bleed on, another generator load, a ground run); its row says 'excluded'; repeat for more, "
                "or give a CSV file with columns engine and flight (default: none)")


def engine_flights(items: list[str], records, option: str = "--new-baseline") -> dict[str, list[int]]:
    """engine -> flight numbers of ``option ENGINE:FLIGHT`` items (``--new-baseline``,
    ``--exclude``; for ``--exclude`` an item may also be a CSV file with columns engine and flight).
    An engine is named as the results spell it (``esn012`` for ESN012: :func:`pwl.fleet.diagnose.engine_named`). A
    UsageError names an item that is not that, a CSV line without a flight number, or an engine
    the results do not have."""
    from ..errors import UsageError
    from ..fleet.diagnose import engine_named
    out: dict[str, list[int]] = {}
    for item in items:
        if option == "--exclude" and item.lower().endswith(".csv"):
            for engine, number in _flights_csv(item):
                out.setdefault(engine, []).append(number)
            continue
        engine, _, flight = item.rpartition(":")
        try:
            number = int(flight)
        except ValueError:
            engine = ""
        if not engine:
            raise UsageError(f"{option} {item!r}: expected ENGINE:FLIGHT (a flight number)")
        out.setdefault(engine, []).append(number)
    have = {r.engine for r in records}
    merged: dict[str, list[int]] = {}
    for engine, numbers in out.items():
        merged.setdefault(engine_named(engine, have), []).extend(numbers)
    out = merged
    unknown = sorted(set(out) - have)
    if unknown:
        raise UsageError(f"{option} names engines the results do not have: {', '.join(unknown)}")
    return out


def _flights_csv(path: str) -> list[tuple[str, int]]:
    """(engine, flight number) of every row of a CSV file with columns engine and flight (others
    ignored); a UsageError naming the file, and the line of a flight that is not a whole number."""
    import csv

    from ..errors import UsageError
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            if not {"engine", "flight"} <= set(reader.fieldnames or ()):
                raise UsageError(f"{path}: needs columns engine and flight (has {reader.fieldnames})")
            rows = []
            for line, row in enumerate(reader, start=2):
                try:
                    rows.append((row["engine"].strip(), int(row["flight"])))
                except (TypeError, ValueError):
                    raise UsageError(f"{path}, line {line}: flight {row['flight']!r} is not a flight number") from None
            return rows
    except OSError as e:
        raise UsageError(f"{path}: cannot read it ({e.strerror or e})") from None


def run_diagnose(args) -> int:
    from dataclasses import replace

    import numpy as np

    from ..database import GainDatabase
    from ..fleet.diagnose import (DiagnosisConfig, copies, diagnose_fleet, mixed_engines, order_notes, recoveries,
                                  write_diagnosis)
    from ..fleet.trending import detail_units, readable_detail

    check_output(args.output)
    check_output(args.plot)
    if args.engine_pattern:
        try:
            re.compile(args.engine_pattern)
        except re.error as e:
            print(f"pwl fleet diagnose: --engine-pattern {args.engine_pattern!r}: {e}", file=sys.stderr)
            return 2
    records, skipped = read_inputs("pwl fleet diagnose", args.results, args.database, args.channel_map,
                                   args.engine_pattern)
    if records is None:
        return 2
    if not records:
        print("pwl fleet diagnose: no readable results files", file=sys.stderr)
        return 2
    for line in copies(records) + mixed_engines(records) + order_notes(records):
        print(f"pwl: warning: {line}", file=sys.stderr)
    db_path = database_of(records, args.database)
    cfg = DiagnosisConfig()
    if args.alpha is not None:
        cfg = replace(cfg, alpha=args.alpha)
    if args.kappa is not None:
        cfg = replace(cfg, kappa=args.kappa)
    if args.no_pairs:
        cfg = replace(cfg, pairs=False)
    baselines = engine_flights(args.new_baseline, records)
    excluded = engine_flights(args.exclude, records, "--exclude")
    db = GainDatabase.open(db_path)
    from linearize.build import Progress
    from ..workers import SerialExecutor, process_pool
    n_engines = len({r.engine for r in records})
    bar = Progress("engines", n_engines)
    workers = max(1, min(args.workers, n_engines))
    with (process_pool(workers) if workers > 1 else SerialExecutor()) as executor:
        rows, Sigma, channels, centers, wear = diagnose_fleet(records, db, cfg, baselines, excluded, executor,
                                                              lambda done, total: bar.update(done))
    write_diagnosis(rows, args.output)
    engines = sorted({r.engine for r in rows})
    latest = {r.engine: r for r in rows}            # rows are in time order per engine
    flagged = {e: r for e, r in latest.items() if r.detected}
    units = detail_units(db)
    print(f"{len(engines)} engines, {len(rows)} flights -> {args.output}")
    for j, c in enumerate(centers):
        print(f"  regime {j}: steady near " + ", ".join(f"{n} {v:.4g}" for n, v in zip(db.names["p"], c)))
    read = {f"{c}@{g}" for r in records for g, w in r.windows.items()
            for j, c in enumerate(r.snapshot.channels) if np.isfinite(r.snapshot.mean[w, j])}
    print("flight-to-flight scatter of the snapshot deviations (1 sigma, %): " +
          ", ".join(f"{c} {100 * s:.3f}" if c in read else f"{c} none (no value)"
                    for c, s in zip(channels, np.sqrt(np.diag(Sigma)))))
    if wear is not None:
        print(f"normal wear of the fleet (median over {wear.engines} engines +- robust spread, % per flight): " +
              ", ".join(f"{n} {100 * m:+.4f} +- {100 * s:.4f}" for n, m, s in zip(wear.names, wear.median, wear.spread)))
        if wear.trend_spread:
            print(f"an engine's wear line is held to the fleet's: engine-to-engine spread without the rates' own "
                  f"scatter at most {100 * np.sqrt(wear.trend_spread[0]):.4f} % per flight per health parameter, "
                  f"{np.sqrt(wear.trend_spread[1]):.3g} x the flight-to-flight scatter per flight beyond health")
    elif cfg.wear:
        print(f"too few engines for the fleet's normal wear and level (at least {cfg.wear_engines} with "
              f"{cfg.wear_flights} complete flights each): wear is reported from {100 * cfg.min_rate:g} % per "
              "flight, and an engine off its fleet from its first flight is not tested")
    nosnap = sum(r.status == "no steady snapshot" for r in rows)
    if nosnap:
        print(f"{nosnap} flights without a steady snapshot (not diagnosed)")
    print(f"{len(flagged)} engines with a fault at their latest flight:")
    for e, r in flagged.items():
        what = f"{r.kind} {readable_detail(r.detail, units)}" + {
            "drift": " per flight", "wear": " per flight beyond the fleet's normal wear",
            "level": " against the fleet's median (off its fleet from its first flight)"}.get(r.kind, "")
        if r.kind == "stuck" and not r.detail:
            what = "stuck (one value in every regime: read as missing)"
        elif r.kind == "intermittent":
            what = f"intermittent (its bias came and went; when on {readable_detail(r.detail, units)} from its baseline)"
        elif r.kind == "erratic":
            where = "within each snapshot" if r.detail.startswith("noise_ratio") else "from flight to flight"
            what = (f"erratic (its readings scatter {r.detail.partition('=')[2]} times as much {where} "
                    "as before: a loose connector, a failing sensor?)")
        after = f" (after {', '.join(r.earlier.split())}, still present)" if r.earlier else ""
        print(f"  {e}: {r.cls} from flight {r.onset}, {what}, confidence {r.confidence:.2f}{after}")
    by_engine: dict = {}
    for d in rows:
        by_engine.setdefault(d.engine, []).append(d)
    gone = [(e, by_engine[e][-1]) for e in engines if by_engine[e][-1].kind == "cleared"]
    if gone:
        print(f"{len(gone)} engines whose sensor bias went away (a repair?):")
        for e, r in gone:
            print(f"  {e}: {r.cls} at flight {r.onset}, {readable_detail(r.detail, units)}")
    rec = [(e, r) for e in engines for r in recoveries(by_engine[e])]
    if rec:
        print(f"{len(rec)} recoveries (every efficiency up: a wash or a repair; diagnosed on a new baseline since):")
        for e, r in rec:
            print(f"  {e}: {r.cls} at flight {r.onset}, {readable_detail(r.detail, units)}")
    if args.plot:
        from ..fleet.chart import plot_fleet
        plot_or_note(partial(plot_fleet, every=len(engines) <= CHART_ALL), args.plot, rows)
    return 1 if skipped or flagged else 0


def run_score(args) -> int:
    from ..fleet.scoring import plot_confusion, score, table

    check_output(args.plot)
    res = score(args.diagnosis, args.truth, args.min_component, args.min_sensor_sigma)
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(table(res))
    if args.plot:
        plot_or_note(plot_confusion, args.plot, res, file=sys.stderr if args.json else None)
    return 0
