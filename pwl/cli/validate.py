"""pwl validate DB.h5: the piecewise-linear model open loop versus its nonlinear plant."""
import numpy as np

from .output import plot_or_note

HELP = "compare the piecewise-linear model (open loop) with the nonlinear plant: steady state and a fuel step"


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5) built by pwl build")
    p.add_argument("-n", "--points", type=int, default=20, help="random off-grid steady-state points")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", type=float, default=0.05, help="input step, fraction (default 0.05)")
    p.add_argument("--plot", default="", help="PNG file for the transient plot (needs matplotlib)")


def table(title, names, errs):
    print(title)
    print(f"  {'channel':<8} {'max |err| %':>12} {'RMS %':>8}")
    for j, n in enumerate(names):
        e = errs[:, j]
        print(f"  {n:<8} {np.abs(e).max():>12.3f} {np.sqrt(np.mean(e ** 2)):>8.3f}")


def run(args) -> int:
    from linearize.validate import fuel_step, plant_of, steady_state
    from pwl.database import GainDatabase

    db = GainDatabase.open(args.database)
    plant = plant_of(db)
    names = list(plant.y_names) + list(plant.z_names)
    errs, pts, failed = steady_state(db, plant, args.points, args.seed)
    table(f"steady state at {len(pts)} random off-grid points, model vs plant:", names, errs)
    for p, e in failed:
        print(f"  (plant trim failed at {np.round(p, 4).tolist()}: {e})")
    worst = float(np.abs(errs).max())
    tr = fuel_step(db, plant, step=args.step)
    p = ", ".join(f"{a.name}={v:.4g}" for a, v in zip(db.trim_grid.axes, tr["p"]))
    table(f"\ntransient: {100 * args.step:g} % input step at {p}, model vs plant:", names, tr["error"])
    worst_tr = float(np.abs(tr["error"]).max())
    print(f"\nworst steady-state error {worst:.3f} %, worst transient error {worst_tr:.3f} %")
    if args.plot:
        plot_or_note(_plot, args.plot, tr)
    return 0


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
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    for j in range(len(names), rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
