"""pwl demo: the self-tuning model on the shipped demo database and sample flights.

For a new and a degraded engine's flight: estimation errors of thrust (Fn) and combustor exit
temperature (T40) against the simulation's truth, untuned versus tuned; health estimates versus
truth; speed in steps per second and times real time; a PNG plot when matplotlib is installed.
"""
import os
import time

import numpy as np

from .output import check_output, plot_or_note

HELP = "run the self-tuning model on the shipped demo database and sample flights"


def add_arguments(p):
    p.add_argument("--database", help="gain database (default: the shipped data/turbofan_demo.h5)")
    p.add_argument("--logs", nargs="+", metavar="LOG",
                   help="flight logs with a truth group (default: the shipped data/flight_*.h5 samples)")
    p.add_argument("--settle", type=float, default=120.0,
                   help="time at the start of a flight left out of the error figures, s (default %(default)g)")
    p.add_argument("--plot", default="pwl_demo.png",
                   help="PNG file for the plot, needs matplotlib (default %(default)s; '' for none)")


def steady_mask(log, hold: float = 60.0):
    """Samples in steady operation: the throttle (TRA) and the altitude have not changed for
    ``hold`` seconds (throttle steps > 0.1, climb or descent faster than 1 m/s). All False when
    the log has no TRA or alt channel."""
    if "TRA" not in log.channels or "alt" not in log.channels:
        return np.zeros(len(log), bool)
    t = log.time
    moving = np.abs(np.gradient(log.channels["alt"], t)) > 1.0
    moving[1:] |= np.abs(np.diff(log.channels["TRA"])) > 0.1
    last = np.maximum.accumulate(np.where(moving, t, t[0] - hold))
    return t - last >= hold


def errors(est, truth, settle_mask):
    """Percent errors (estimate - truth) / |truth| over the settled samples: RMS and mean."""
    e = 100.0 * (est - truth) / np.abs(truth)
    e = e[settle_mask & np.isfinite(e)]
    return float(np.sqrt(np.mean(e ** 2))), float(np.mean(e))


def run(args) -> int:
    from ..demo_data import demo_paths
    from ..estimator import Estimator
    from ..logs import read_log
    from ..fleet.trending import health_summary

    d_db, d_logs = demo_paths()
    db_path = args.database or d_db
    logs = args.logs or d_logs
    for p in [db_path] + list(logs):
        if not os.path.exists(p):
            raise FileNotFoundError(f"{p}: missing (the demo needs the shipped data/ folder of a checkout)")
    check_output(args.plot)
    tuned = Estimator(db_path)
    untuned = Estimator(tuned.db, "untuned")
    print(f"database: {db_path}  ({tuned.db.trim_grid.size} trim points, "
          f"{tuned.db.dyn_grid.size} dynamics points, tuners {', '.join(tuned.db.names['q'])})\n")
    rows, health_rows, plots = [], [], []
    for path in logs:
        log = read_log(path)
        t0 = time.perf_counter()
        rt = tuned.run(log)
        t_run = time.perf_counter() - t0
        t0 = time.perf_counter()
        tuned.run(log)  # again: the first run may include loading compiled code
        t_run = min(t_run, time.perf_counter() - t0)
        ru = untuned.run(log)
        name = os.path.splitext(os.path.basename(path))[0]
        settled = log.time >= log.time[0] + args.settle
        steady = steady_mask(log) & settled
        for ch in ("Fn", "T40"):
            if ch not in log.truth:
                raise ValueError(f"{path}: truth channel {ch!r} missing; the demo needs simulated logs")
            for label, mask in (("flight", settled), ("steady", steady)):
                if mask.any():
                    eu = errors(ru.channel("z_hat", ch), log.truth[ch], mask)
                    et = errors(rt.channel("z_hat", ch), log.truth[ch], mask)
                    rows.append((name, ch, label, eu, et))
        snap = health_summary(rt.time, rt.h_hat, rt.flags, tuned.names["h_hat"], path, args.settle)
        truth_h = np.array([np.mean(log.truth[h]) if h in log.truth else np.nan for h in snap.names])
        health_rows.append((name, snap, truth_h))
        n = len(log)
        print(f"{name}: {n} samples ({log.time[-1] - log.time[0]:.0f} s of flight) in {t_run * 1e3:.1f} ms: "
              f"{n / t_run:,.0f} steps/s, {n / t_run * tuned.db.dt:,.0f} x real time; "
              f"flags: {rt.counts()}")
        plots.append((name, log, rt, ru))
    print("\nEstimation error of unmeasured outputs, % of truth, RMS / mean; 'flight': every sample "
          f"after the first {args.settle:g} s, 'steady': throttle and altitude unchanged for 60 s:")
    print(f"{'flight':<18} {'output':<6} {'samples':<8} {'untuned RMS':>12} {'tuned RMS':>10} "
          f"{'untuned mean':>13} {'tuned mean':>11} {'RMS ratio':>10}")
    for name, ch, label, eu, et in rows:
        print(f"{name:<18} {ch:<6} {label:<8} {eu[0]:>12.3f} {et[0]:>10.3f} {eu[1]:>13.3f} {et[1]:>11.3f} "
              f"{eu[0] / max(et[0], 1e-12):>10.1f}x")
    print("\nHealth parameters, % (median estimate over the settled flight vs truth):")
    names = health_rows[0][1].names
    print(f"{'flight':<20} " + " ".join(f"{n:>9}" for n in names))
    for name, snap, truth_h in health_rows:
        print(f"{name + ' est':<20} " + " ".join(f"{100 * v:>9.2f}" for v in snap.values))
        print(f"{name + ' truth':<20} " + " ".join(f"{100 * v:>9.2f}" for v in truth_h))
    if args.plot:
        plot_or_note(_plot, args.plot, plots, names, lead="\n")
    return 0


def _plot(plots, hnames, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(plots), figsize=(6.5 * len(plots), 9), squeeze=False)
    for c, (name, log, rt, ru) in enumerate(plots):
        t = log.time / 60.0
        for r, ch in enumerate(("Fn", "T40")):
            ax = axes[r][c]
            tr = log.truth[ch]
            ax.plot(t, 100 * (ru.channel("z_hat", ch) - tr) / np.abs(tr), lw=0.8, label="untuned")
            ax.plot(t, 100 * (rt.channel("z_hat", ch) - tr) / np.abs(tr), lw=0.8, label="tuned")
            ax.axhline(0, color="k", lw=0.5)
            ax.set_ylabel(f"{ch} error, %")
            ax.set_title(f"{name}: {ch}")
            ax.legend(fontsize=8, loc="upper left")  # a fixed place: "best" is slow on long lines
            ax.grid(alpha=0.3)
        ax = axes[2][c]
        for j, h in enumerate(hnames):
            line, = ax.plot(t, 100 * rt.h_hat[:, j], lw=0.8, label=h)
            if h in log.truth:
                ax.plot(t, 100 * log.truth[h], "--", lw=0.8, color=line.get_color())
        ax.set_ylabel("health, % (dashed: truth)")
        ax.set_xlabel("time, min")
        ax.grid(alpha=0.3)
    axes[2][-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the panels
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
