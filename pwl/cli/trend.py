"""pwl trend RESULTS...: one engine's health over its flights, trend lines and the diagnosis."""
from .fleet import EXCLUDE_HELP, NEW_BASELINE_HELP

HELP = ("health trends (in percent) and fault diagnosis of one engine over its flights (results files "
        "of pwl run, in any order: sorted by flight_time, then flight_index, then file name); exit "
        "status 1 when a fault is detected at the latest flight, or a results file could not be read "
        "(skipped and named)")


def add_arguments(p):
    p.add_argument("results", nargs="+",
                   help="results files (*.estimates.h5) of pwl run, or folders holding them (walked recursively), "
                        "or snapshot tables (.csv, .parquet; they need --database; --engine picks one engine)")
    p.add_argument("--database", help="gain database (default: the one recorded in the results)")
    p.add_argument("--channel-map", metavar="TOML",
                   help="the snapshot tables' column names and units -> the model's (default: the tables' own)")
    p.add_argument("--engine", action="append", metavar="SERIAL",
                   help="only this engine (repeatable; default: every engine of the results)")
    p.add_argument("--fleet", action="append", metavar="RESULTS",
                   help="results of the engine's fleet (a folder, a file or a snapshot table; repeatable): judge "
                        "the engine against the fleet's flight-to-flight scatter and normal wear, as pwl fleet "
                        "diagnose does (default: none, the engine against its own scatter)")
    p.add_argument("--plot", help="PNG file of the health trends, needs matplotlib (default: none; "
                                  "with several engines, one file each: NAME_ENGINE.png)")
    p.add_argument("--new-baseline", metavar="ENGINE:FLIGHT", action="append", default=[], help=NEW_BASELINE_HELP)
    p.add_argument("--exclude", metavar="ENGINE:FLIGHT", action="append", default=[], help=EXCLUDE_HELP)


def run(args) -> int:
    import sys

    from ..database import GainDatabase
    from ..fleet.diagnose import copies, engine_named, group_engines, mixed_engines, order_notes
    from ..fleet.trending import engine_trend, plot_trend
    from .fleet import database_of, engine_flights, read_inputs
    from .output import check_output, plot_or_note

    check_output(args.plot)
    records, skipped = read_inputs("pwl trend", args.results, args.database, args.channel_map)
    if records is None:
        return 2
    if args.engine:
        have = {r.engine for r in records}
        args.engine = [engine_named(e, have) for e in args.engine]
        unknown = [e for e in args.engine if e not in have]
        if unknown:
            print(f"pwl trend: no engine {unknown[0]!r} in the results (engines: {', '.join(sorted(have)[:20])})",
                  file=sys.stderr)
            return 2
        records = [r for r in records if r.engine in args.engine]
    if len(records) < 2:
        print("pwl trend: a trend needs at least two flights", file=sys.stderr)
        return 2
    db = GainDatabase.open(database_of(records, args.database))
    for line in copies(records) + mixed_engines(records) + order_notes(records):
        print(f"pwl: warning: {line}", file=sys.stderr)
    fleet, fleet_skipped = (read_inputs("pwl trend --fleet", args.fleet, db.path, args.channel_map) if args.fleet
                            else (None, []))
    if args.fleet and fleet is None:
        return 2
    engines = group_engines(records)
    baselines = engine_flights(args.new_baseline, records)
    excluded = engine_flights(args.exclude, records, "--exclude")
    status = int(bool(skipped or fleet_skipped))   # as pwl fleet diagnose: a file it could not read is a finding
    for i, (eng, recs) in enumerate(engines.items()):
        tr = engine_trend(recs, db, fleet=fleet, new_baselines=tuple(baselines.get(eng, ())), excluded=excluded)
        print(("\n" if i else "") + tr.table())
        if args.plot:
            path = args.plot if len(engines) == 1 else args.plot.replace(".png", f"_{eng}.png")
            plot_or_note(plot_trend, path, tr)
        status |= int(tr.latest.detected)
    return status
