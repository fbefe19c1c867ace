"""pwl validate DB.h5: the piecewise-linear model open loop versus its nonlinear plant."""
import numpy as np

from .output import check_output, plot_or_note

#: default --max-error, % of the plant's value: the shipped demo database stays below 0.8 %
#: (steady state, 20 and 60 random points), 1.5 % (trim tables at 200 points, matched on the
#: scheduling variables) and 0.5 % (5 % step); a wrong matrix goes far above
MAX_ERROR = 2.0

HELP = ("compare the piecewise-linear model (open loop) with the nonlinear plant: steady state and "
        f"an input step; exit status 1 when any error is NaN or above --max-error (default {MAX_ERROR:g} "
        "percent of the plant's value)")   # no '%' here: argparse formats the command list with it


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5) built by pwl build")
    p.add_argument("-n", "--points", type=int, default=20,
                   help="random off-grid steady-state points (default %(default)s)")
    p.add_argument("--trim-points", type=int, default=200,
                   help="random off-grid points of the trim-table check at the runtime's scheduling "
                        "variables (default %(default)s; 0: skip)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random points (default %(default)s)")
    p.add_argument("--step", type=float, default=0.05,
                   help="input step of the transient, fraction of the trim input (default %(default)g)")
    p.add_argument("--max-error", type=float, default=MAX_ERROR, metavar="PCT",
                   help="largest acceptable |model - plant| of any output, %% of the plant's value, "
                        "in either check (default %(default)g; exit status 1 above it or on NaN)")
    p.add_argument("--plot", default="",
                   help="PNG file for the transient plot, needs matplotlib (default: none)")


def table(title, names, errs):
    print(title)
    print(f"  {'channel':<8} {'max |err| %':>12} {'RMS %':>8}")
    for j, n in enumerate(names):
        e = errs[:, j]
        print(f"  {n:<8} {np.abs(e).max():>12.3f} {np.sqrt(np.mean(e ** 2)):>8.3f}")


def failures(check, names, errs, max_error):
    """One line per output whose largest |error| (errs: (n, k) %) is NaN or above ``max_error`` %,
    naming the check, the output and by how much."""
    out = []
    for n, worst in zip(names, np.abs(errs).max(axis=0)):
        if np.isnan(worst):
            out.append(f"{check}: {n} error is NaN (limit {max_error:g} %)")
        elif worst > max_error:
            out.append(f"{check}: {n} max |error| {worst:.3f} % > {max_error:g} % "
                       f"(by {worst - max_error:.3f} %)")
    return out


def run(args) -> int:
    from linearize.validate import fuel_step, plant_of, scheduled_trims, steady_state
    from pwl.database import GainDatabase

    check_output(args.plot)
    db = GainDatabase.open(args.database)
    plant = plant_of(db)
    names = list(plant.y_names) + list(plant.z_names)
    errs, pts, failed = steady_state(db, plant, args.points, args.seed)
    if len(pts):
        table(f"steady state at {len(pts)} random off-grid points, model vs plant:", names, errs)
        bad = failures("steady state", names, errs, args.max_error)
    else:
        bad = [f"steady state: the plant's trim failed at every one of the {args.points} points"]
    for p, e in failed:
        print(f"  (plant trim failed at {np.round(p, 4).tolist()}: {e})")
    worst_trim = np.nan
    if args.trim_points > 0:
        te, tp, tfail = scheduled_trims(db, plant, args.trim_points, args.seed + 1)
        if len(tp):
            table(f"\ntrim tables at {len(tp)} random off-grid points, matched on the runtime's scheduling "
                  "variables, model vs plant:", names, te)
            bad += failures("trim tables", names, te, args.max_error)
            worst_trim = np.abs(te).max()
        for p_, e in tfail:
            print(f"  (plant trim failed at {np.round(p_, 4).tolist()}: {e})")
    tr = fuel_step(db, plant, step=args.step)
    p = ", ".join(f"{a.name}={v:.4g}" for a, v in zip(db.trim_grid.axes, tr["p"]))
    table(f"\ntransient: {100 * args.step:g} % input step at {p}, model vs plant:", names, tr["error"])
    bad += failures("transient", names, tr["error"], args.max_error)
    worst = np.abs(errs).max() if len(pts) else np.nan
    print(f"\nworst steady-state error {worst:.3f} %, trim tables {worst_trim:.3f} %, worst transient error "
          f"{np.abs(tr['error']).max():.3f} % (limit {args.max_error:g} %)")
    for line in bad:
        print(f"FAILED {line}")
    if not bad:
        print("passed: every error within the limit")
    if args.plot:
        plot_or_note(_plot, args.plot, tr)
    return 1 if bad else 0


def _plot(tr, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = tr["names"]
    cols = 3
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.6 * rows), squeeze=False)
    for j, n in enumerate(names):
        ax = axes[j // cols][j % cols]
        ax.plot(tr["time"], tr["truth"][:, j], label="nonlinear plant")
        ax.plot(tr["time"], tr["model"][:, j], "--", label="piecewise-linear, open loop")
        ax.set_title(n)
        ax.set_xlabel("time, s")
        ax.set_ylabel(f"{n}, {tr['units'][j]}")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower right")
    for j in range(len(names), rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
