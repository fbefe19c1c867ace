"""pwl biastable: the bias-table experiment on the turbofan (what it does and why:
:mod:`experiments.biastable`).

The experiment is :mod:`experiments.biastable` (imported inside the functions: ``pwl`` loads it
only to build this command's arguments and to run it); this module parses the arguments, prints
and plots.
"""
import numpy as np

from .output import check_output, plot_or_note

HELP = "the runtime's adaptive bias table on the turbofan: learn a sensor mismatch, then track health"


def add_arguments(p):
    from experiments.biastable import DEGRADED

    p.add_argument("--database", help="gain database (default: the shipped data/turbofan_demo.h5)")
    p.add_argument("--learn", type=int, default=3,
                   help="new-engine flights the table learns from (default %(default)s)")
    p.add_argument("--ratio", type=float, default=1e3,
                   help="table noise ratio sigma_x^2/sigma_theta^2 (default %(default)g)")
    p.add_argument("--offset", type=float, default=0.01,
                   help="T48 mismatch at 60 %% NfR, fraction (default %(default)g)")
    p.add_argument("--slope", type=float, default=0.01,
                   help="extra T48 mismatch at 100 %% NfR, fraction (default %(default)g)")
    p.add_argument("--health", default=",".join(f"{k}={v}" for k, v in DEGRADED.items()),
                   help="health of the degraded engine, name=fraction,... (default %(default)s)")
    p.add_argument("--cruise", type=float, default=None,
                   help="cruise duration of every flight, s (default: the short profile's)")
    p.add_argument("--seed", type=int, default=11,
                   help="seed of the first flight; flight k uses seed + k (default %(default)s)")
    p.add_argument("--plot", default="pwl_biastable.png",
                   help="PNG file for the plot, needs matplotlib (default %(default)s; '' for none)")


def run(args) -> int:
    from experiments.biastable import experiment

    from ..demo_data import demo_paths
    from .simulate import _pairs

    db = args.database or demo_paths()[0]
    check_output(args.plot)
    print(f"T48 mismatch {100 * args.offset:g} % at 60 % NfR to {100 * (args.offset + args.slope):g} % at "
          f"100 %; table ratio {args.ratio:g}; {args.learn} learning flights")
    out = experiment(db, args.learn, args.ratio, args.offset, args.slope, _pairs(args.health, "--health"),
                     args.cruise, args.seed)
    names, truth = out["names"], out["truth"]
    print(f"\nhealth of the degraded engine, % (median after 120 s), tuners {', '.join(out['tuners'])}:")
    print(f"{'':<15}" + "".join(f"{n:>10}" for n in names) + f"{'RMS err':>10}{'degraded':>10}")
    idx = np.flatnonzero(truth != 0)   # the parameters that did degrade
    rms = {}
    for label, h in [("truth", truth)] + list(out["estimates"].items()):
        e = 100 * (h - truth)
        rms[label] = (np.sqrt(np.mean(e ** 2)), np.sqrt(np.mean(e[idx] ** 2)) if idx.size else np.nan)
        print(f"{label:<15}" + "".join(f"{100 * v:>10.2f}" for v in h)
              + ("" if label == "truth" else f"{rms[label][0]:>10.3f}{rms[label][1]:>10.3f}"))
    print(f"\nhealth RMS error without the table / with it: {rms['without table'][0] / rms['with table'][0]:.1f}x "
          f"(degraded parameters only: {rms['without table'][1] / rms['with table'][1]:.1f}x)")
    bh = out["runs"]["with table"].channel("bias_hat", "T48")
    use = out["log"].time > 120
    err = bh[use] - out["true_bias"][use]
    print(f"learnt T48 bias on the degraded flight: RMS error {np.sqrt(np.mean(err ** 2)):.2f} K against a "
          f"true bias of {out['true_bias'][use].min():.1f}..{out['true_bias'][use].max():.1f} K")
    if args.plot:
        plot_or_note(_plot, args.plot, out)
    return 0


def _plot(out, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = out["log"].time / 60.0
    names = out["names"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2))
    ax = axes[0]
    ax.plot(t, out["true_bias"], "k", lw=1, label="true T48 sensor bias")
    ax.plot(t, out["runs"]["with table"].channel("bias_hat", "T48"), lw=0.8, label="bias table (locked)")
    ax.set_xlabel("time, min")
    ax.set_ylabel("T48 bias, K")
    ax.legend(fontsize=8, loc="upper left")   # a fixed place: "best" is slow on long lines
    ax.grid(alpha=0.3)
    for ax, label in zip(axes[1:], ("without table", "with table")):
        r = out["runs"][label]
        for j in np.flatnonzero(out["truth"] != 0):
            q = names[j]
            line, = ax.plot(t, 100 * r.h_hat[:, j], lw=0.8, label=q)
            ax.axhline(100 * out["truth"][j], color=line.get_color(), ls="--", lw=0.8)
        ax.set_title(f"degraded engine, {label} (dashed: truth)")
        ax.set_xlabel("time, min")
        ax.set_ylabel("health, %")
        ax.set_ylim(-5, 3)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
