"""pwl tables WHAT: adaptive look-up table experiments (seed 000 sec. 5, seed 003 battery) and
the table benchmark. Prints tables; writes PNG plots into --out when matplotlib is installed.

The experiments are :mod:`experiments.tables` (imported inside ``run``), the benchmark
:mod:`pwl.bench.tables`; this module parses the arguments, prints and plots."""
import json
import os

import numpy as np

from .output import check_output, print_result

HELP = "adaptive look-up tables: seed000 (paper 000 sec. 5), battery (paper 003), bench"


def add_arguments(p):
    p.add_argument("what", choices=("seed000", "battery", "bench"),
                   help="seed000: learning, bias step and noise experiments, exact vs paper gains; "
                        "battery: correlated whole-table vs local updates over a battery life; "
                        "bench: 2-D exact updates per second vs numpy")
    p.add_argument("--out", default="pwl_tables",
                   help="seed000, battery: folder for plots and text tables, created if missing (default %(default)s)")
    p.add_argument("--no-plot", action="store_true",
                   help="seed000, battery: print and write the text tables only (default: also PNG plots)")
    p.add_argument("--seeds", type=int, default=10,
                   help="seed000: random point sets averaged (default %(default)s)")
    p.add_argument("--n", type=int, default=None,
                   help="seed000: iterations (default 1000); battery: local estimates over the life (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="battery: random seed (default %(default)s)")
    p.add_argument("--length", type=float, default=2.0,
                   help="battery: correlation length on the temperature axis normalised to 0..1, "
                        "i.e. in table spans (default %(default)g)")
    p.add_argument("--points", type=int, default=2_000_000,
                   help="bench: updates per timed run (default %(default)s)")
    p.add_argument("--json", action="store_true", help="bench: print one JSON object (default: a table)")


def run(args) -> int:
    if args.what == "bench":
        return _bench(args)
    check_output(args.out, folder=True)
    return _seed000(args) if args.what == "seed000" else _battery(args)


def _bench(args) -> int:
    from ..bench.tables import bench_tables

    print_result(bench_tables(n_points=args.points), args.json)
    return 0


def _plots_ok(args):
    if args.no_plot:
        return None
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        return plt
    except ImportError:
        print("(no plots: install the plot extra, pip install -e '.[plot]')")
        return None


def _seed000(args) -> int:
    from experiments.tables import format_seed000, seed000

    n = args.n or 1000
    res = seed000(n=n, seeds=args.seeds)
    text = format_seed000(res)
    print(text)
    path = os.path.join(args.out, "seed000.txt")
    with open(path, "w") as f:
        f.write(text + "\n")
    print(f"\ntable: {path}")
    plt = _plots_ok(args)
    if plt is None:
        return 0
    curves = res["curves"]
    k = np.arange(n + 1)
    styles = {"exact": "-", "paper": "--"}
    panels = [("reliable", 1, 0.0, "1-D, reliable reference"), ("reliable", 2, 0.0, "2-D, reliable reference"),
              ("bias", 2, 0.0, f"2-D, +{res['step']:g} step at iteration {res['step_at']}"),
              ("noise", 2, 0.2, "2-D, uniform reference noise +-0.2"),
              ("noise", 2, 0.4, "2-D, uniform reference noise +-0.4")]
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    axes = axes.ravel()
    for ax, (case, dim, amp, title) in zip(axes, panels):
        for (c, d, law, sr, a), eq in curves.items():
            if (c, d, a) != (case, dim, amp):
                continue
            ax.plot(k, eq, styles[law], lw=1.0, label=f"{law}, sx/st = {sr:g}")
        ax.set_yscale("log")
        ax.axhline(1.0, color="k", lw=0.5, ls=":")
        ax.set_title(title)
        ax.set_xlabel("iteration k")
        ax.set_ylabel("eq_k, %")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    ax = axes[5]
    for (c, d, law, sr, a), eq in curves.items():
        if c == "noise" and a == 0.2:
            ax.plot(k[400:], eq[400:], styles[law], lw=1.0, label=f"{law}, sx/st = {sr:g}")
    ax.set_title("2-D, noise +-0.2, iterations 400..1000 (linear)")
    ax.set_xlabel("iteration k")
    ax.set_ylabel("eq_k, %")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Seed 000 sec. 5: adaptive table learning (mean of {res['seeds']} random point sets)")
    fig.tight_layout()
    png = os.path.join(args.out, "seed000.png")
    fig.savefig(png, dpi=100)
    plt.close(fig)
    print(f"plot: {png}")
    return 0


def _battery(args) -> int:
    from experiments.tables import battery_compare
    from models import battery

    sim = battery.simulate(n=args.n or 5000, seed=args.seed)
    r = battery_compare(sim, length=args.length)
    nodes = r["nodes"]
    print(f"battery ohmic resistance, mOhm: {len(sim['measured'])} noisy local estimates over one life "
          f"(noise std {sim['noise_std']:g} mOhm), table over {nodes[0]:g}..{nodes[-1]:g} C\n"
          f"local = exact law (ratio {r['ratio_local']:.3g}); correlated = whole-table Kalman "
          f"(length {r['length']:g}, ratio {r['ratio_corr']:.3g})\n")
    print(f"{'T, C':>6} {'visits':>7} {'BoL':>7} {'truth EoL':>10} {'local':>7} {'correl.':>8} "
          f"{'err local':>10} {'err corr':>9}  class")
    for i, T in enumerate(nodes):
        cls = "never" if r["never"][i] else ("rare" if r["rare"][i] else "")
        print(f"{T:>6g} {r['counts'][i]:>7d} {r['table0'][i]:>7.3f} {r['truth_end'][i]:>10.3f} "
              f"{r['local'][i]:>7.3f} {r['correlated'][i]:>8.3f} {r['err_local'][i]:>10.3f} "
              f"{r['err_corr'][i]:>9.3f}  {cls}")
    print("\nRMS error at the end of life, mOhm (correlated / local):")
    for name in ("never", "rare", "visited"):
        if f"rms_local_{name}" in r:
            print(f"  {name:<8} local {r[f'rms_local_{name}']:.4f}  correlated {r[f'rms_corr_{name}']:.4f}"
                  f"  ratio {r[f'ratio_{name}']:.3f}")
    path = os.path.join(args.out, "battery.txt")
    with open(path, "w") as f:
        json.dump({k: (v.tolist() if isinstance(v, np.ndarray) and v.ndim == 1 else v)
                   for k, v in r.items() if not k.startswith("hist")}, f, indent=1)
    print(f"\nfigures: {path}")
    plt = _plots_ok(args)
    if plt is None:
        return 0
    fig, axes = plt.subplots(2, 2, figsize=(13, 8.5))
    ax = axes[0][0]
    fine = np.linspace(nodes[0], nodes[-1], 300)
    ax.plot(fine, battery.resistance_new(fine), "k:", lw=1, label="begin of life")
    ax.plot(fine, battery.resistance(fine, sim["life"][-1]), "k-", lw=1, label="truth, end of life")
    ax.plot(nodes, r["local"], "o-", ms=4, lw=1, label="local updates (exact law)")
    ax.errorbar(nodes, r["correlated"], yerr=r["sd_corr"], fmt="s-", ms=4, lw=1, capsize=2,
                label="correlated whole table (+- 1 sd)")
    ax.set_yscale("log")
    ax.set_xlabel("temperature, C")
    ax.set_ylabel("ohmic resistance, mOhm")
    ax.set_title("tables at the end of life")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    ax = axes[0][1]
    ax.bar(nodes, r["counts"], width=3.5, color="0.6")
    for i in np.flatnonzero(r["never"]):
        ax.axvspan(nodes[i] - 2.5, nodes[i] + 2.5, color="r", alpha=0.1)
    ax.set_yscale("symlog", linthresh=1)
    ax.set_xlabel("temperature, C")
    ax.set_ylabel("updates touching the node")
    ax.set_title("excitation (red: never excited)")
    ax.grid(alpha=0.3)
    ax = axes[1][0]
    ax.plot(nodes, np.abs(r["err_local"]), "o-", ms=4, label="local")
    ax.plot(nodes, np.abs(r["err_corr"]), "s-", ms=4, label="correlated")
    ax.set_yscale("log")
    ax.set_xlabel("temperature, C")
    ax.set_ylabel("|error| at end of life, mOhm")
    ax.set_title(f"never excited: RMS ratio correlated/local = {r.get('ratio_never', np.nan):.3f}")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    ax = axes[1][1]
    life = sim["life"]
    for T, c in ((-20.0, "C0"), (0.0, "C1"), (20.0, "C2")):
        i = int(np.argmin(np.abs(nodes - T)))
        ax.plot(sim["step"], battery.resistance(nodes[i], life), "-", color=c, lw=1.5, alpha=0.5,
                label=f"truth {nodes[i]:g} C")
        ax.plot(sim["step"], r["hist_local"][:, i], ":", color=c, lw=1, label=f"local {nodes[i]:g} C")
        ax.plot(sim["step"], r["hist_corr"][:, i], "--", color=c, lw=1, label=f"correlated {nodes[i]:g} C")
    ax.set_yscale("log")
    ax.set_xlabel("local estimate number (battery life)")
    ax.set_ylabel("resistance, mOhm")
    ax.set_title("table nodes over the life")
    ax.legend(fontsize=7, ncol=3, loc="upper left")
    ax.grid(alpha=0.3)
    fig.suptitle("Seed 003: battery ohmic resistance table, correlated ageing")
    fig.tight_layout()
    png = os.path.join(args.out, "battery.png")
    fig.savefig(png, dpi=100)
    plt.close(fig)
    print(f"plot: {png}")
    return 0
