"""pwl trend RESULTS...: health snapshots per flight, trends and fault flags over an engine's life."""
HELP = "health trends and fault flags over flights (results files of pwl run, oldest first)"


def add_arguments(p):
    p.add_argument("results", nargs="+", help="results files (*.estimates.h5), oldest flight first")
    p.add_argument("--settle", type=float, default=60.0, help="seconds ignored at the start of each flight")
    p.add_argument("--limit", type=float, default=-0.03, help="flag health parameters below this")
    p.add_argument("--plot", help="write a PNG of the trends (needs matplotlib)")


def run(args) -> int:
    from ..trending import plot_trend, snapshot_file, trend

    snaps = [snapshot_file(p, args.settle) for p in args.results]
    tr = trend(snaps, limit=args.limit)
    print(f"{len(snaps)} flights")
    print(tr.table())
    if args.plot:
        plot_trend(tr, args.plot)
        print(f"plot: {args.plot}")
    return 1 if tr.flags else 0
