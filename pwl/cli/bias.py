"""pwl bias: the fuel-to-air ratio bias observer of seed 004 on a simulated diesel engine.

The cycle (an NEDC-like drive cycle by default, or injection steps at constant speed) is driven
twice back to back; the observer runs over both passes, the bias table learning from the first
pass on (all nodes start at zero). Errors against the simulated truth are reported for the second
pass: the biased fast model, the slow delayed sensor, the observer without table and the observer
with table (plus, for reference, with the freezing rules off). A plot like the paper's Fig. 14/17
is written when matplotlib is installed.

The experiment is :func:`experiments.bias.drive_cycle` (imported inside ``run``); this module
parses the arguments, prints and plots.
"""
import math

import numpy as np

from .output import check_output, plot_or_note

HELP = "fuel-to-air ratio bias observer (seed 004) on a simulated diesel drive cycle"


def add_arguments(p):
    p.add_argument("--case", choices=("nedc", "steps"), default="nedc",
                   help="operating-point trajectory: NEDC-like drive cycle or injection steps at 1500 rpm "
                        "(default %(default)s)")
    p.add_argument("--urban-cycles", type=int, default=4,
                   help="nedc: ECE-15 cycles before the extra-urban part (default %(default)s)")
    p.add_argument("--passes", type=int, default=2,
                   help="times the cycle is driven, >= 2; the last is evaluated (default %(default)s)")
    p.add_argument("--seed", type=int, default=1,
                   help="seed of the simulation's noise and spikes (default %(default)s)")
    p.add_argument("--ratio", type=float, default=1 / 80,
                   help="observer tuning sigma_w^2 / sigma_v^2 (default 1/80, the paper's slow "
                        "observer; the fast one is 1/30)")
    p.add_argument("--table-ratio", type=float, default=0.1,
                   help="bias table noise ratio sigma_x^2 / sigma_theta^2 (default %(default)g)")
    p.add_argument("--table-law", choices=("exact", "paper"), default="exact",
                   help="gain law of the bias table (default %(default)s)")
    p.add_argument("--spikes", type=float, default=0.02,
                   help="spurious sensor spikes per second (default %(default)g)")
    p.add_argument("--sensor-a", type=float, default=0.96,
                   help="true sensor pole per 20 ms step; the observer assumes 0.96 (default %(default)g)")
    p.add_argument("--sensor-tau", type=float, default=0.4,
                   help="true sensor delay, s; the observer assumes 0.4 (default %(default)g)")
    p.add_argument("--model-scale", type=float, default=1.0,
                   help="extra model drift, a factor on the model's output (default %(default)g; "
                        "sec. 4 of the paper uses 1.05)")
    p.add_argument("--hold", type=float, default=0.2,
                   help="freeze hold time after a rule fires, s (default %(default)g)")
    p.add_argument("--freeze", nargs="*", default=[], metavar="NAME=VALUE",
                   help="freezing thresholds, e.g. model_rate=1.5 sensor_min=0.12 (names of "
                        "experiments.bias_observer.FreezeRules: e_rate model_rate sensor_rate sensor_min sensor_max "
                        "estimate_min estimate_max; inf switches a rule off; default: FreezeRules' own)")
    p.add_argument("--plot", default="pwl_bias.png",
                   help="PNG file for the plot, needs matplotlib (default %(default)s; '' for none)")


def run(args) -> int:
    from experiments.bias import drive_cycle

    if args.passes < 2:
        raise ValueError("--passes must be >= 2 (the table learns on the first pass)")
    check_output(args.plot)
    out = drive_cycle(args.case, args.urban_cycles, args.passes, args.seed, args.ratio, args.table_ratio,
                      args.table_law, args.spikes, args.sensor_a, args.sensor_tau, args.model_scale,
                      args.hold, _thresholds(args.freeze))
    one, traj, sim, sensor, K, grid = (out[k] for k in ("one", "traj", "sim", "sensor", "K", "grid"))
    dt, a_obs, tau_obs, k1, runs = out["dt"], out["a_obs"], out["tau_obs"], out["k1"], out["runs"]
    last = slice((args.passes - 1) * k1, None)
    print(f"case: {one.name}, {one.t[-1] + dt:.0f} s x {args.passes} passes at {1 / dt:g} Hz, seed {args.seed}")
    print(f"sensor: a = {args.sensor_a:g}, tau = {args.sensor_tau:g} s, noise {sensor.noise:g}, "
          f"saturation below {sensor.sat_level:g} ({100 * sim.saturated[last].mean():.1f} % of the "
          f"evaluated pass), spikes {args.spikes:g}/s; observer assumes a = {a_obs}, tau = {tau_obs} s")
    print(f"K_inf = [{K[0]:.5f}, {K[1]:.5f}]  (sigma_w^2/sigma_v^2 = {args.ratio:.5g}); table "
          f"{grid.shape[0]}x{grid.shape[1]} nodes, law {args.table_law}, ratio {args.table_ratio:g}")
    print(f"simulation {out['t_sim']:.2f} s; observer with table {len(traj) / out['timing']:,.0f} steps/s\n")
    e_model, e_sensor = out["e_model"], out["e_sensor"]
    print("RMS error of lambda^-1 versus truth (evaluated pass; first pass and sensor-valid samples "
          "for reference):")
    print(f"{'signal':<30} {'last pass':>10} {'/ model':>8} {'/ sensor':>9} {'first pass':>11} {'valid only':>11}")
    for name, el, ef, ev in out["errors"]:
        print(f"{name:<30} {el:>10.5f} {el / e_model:>8.3f} {el / e_sensor:>9.3f} {ef:>11.5f} "
              f"{ev:>11.5f}")
    res, table = runs["observer + table"]
    counts = res.rule_counts()
    print("\nfreezing (observer + table, whole run): "
          + ", ".join(f"{k} {v}" for k, v in counts.items() if v)
          + f" of {len(traj)} steps ({100 * res.frozen.mean():.1f} % frozen)")
    print(f"table: {table.n_updates} updates, {int(np.count_nonzero(table.counts))} nodes touched, "
          f"values {table.values.min():.4f}..{table.values.max():.4f}")
    e_tab, ok = out["e_table"], out["ok"]
    print(f"\nacceptance (table RMS <= 0.5 x model and <= 0.7 x sensor): {'met' if ok else 'NOT met'} "
          f"({e_tab / e_model:.3f} x model, {e_tab / e_sensor:.3f} x sensor)")
    if args.plot:
        plot_or_note(_plot, args.plot, sim, runs, k1, args)
    return 0


def _thresholds(items):
    from dataclasses import fields

    from experiments.bias_observer import FreezeRules

    names = {f.name for f in fields(FreezeRules)} - {"hold"}
    out = {}
    for item in items:
        key, sep, val = item.partition("=")
        if not sep or key not in names:
            raise ValueError(f"--freeze {item!r}: expected NAME=VALUE with NAME one of {sorted(names)}")
        out[key] = float(val)
    return out


def _window(sim, k1, args, pass_index):
    """An 80 s window of a pass with transients, idle and fuel cuts."""
    t = sim.t
    start = pass_index * k1
    t0 = t[start] + (117.0 if args.case == "nedc" else 0.0)   # NEDC: third hill of the first ECE
    return (t >= t0) & (t < t0 + 80.0)


def _panel(ax, sim, res, w, title):
    t = sim.t[w]
    ax.plot(t, sim.lam_sensor[w], color="k", lw=1.6, label="sensor $\\lambda^{-1}_s$")
    ax.plot(t, sim.lam_model[w], "k--", lw=0.8, label="model $\\lambda^{-1}_m$")
    ax.plot(t, sim.lam_true[w], color="tab:blue", lw=0.8, label="truth")
    ax.plot(t, res.lam_hat[w], color="0.5", lw=1.2, label="estimate $\\hat\\lambda^{-1}$")
    ax.fill_between(t, 0, 1, where=res.frozen[w], transform=ax.get_xaxis_transform(), color="tab:orange",
                    alpha=0.12, lw=0, label="frozen")
    e = res.lam_hat[w] - sim.lam_true[w]
    ax.set_title(f"{title}: window RMS error {math.sqrt(np.nanmean(e * e)):.4f}", fontsize=9)
    ax.set_ylabel("$\\lambda^{-1}$ [-]")
    ax.grid(alpha=0.3)


def _plot(sim, runs, k1, args, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 10))
    gs = fig.add_gridspec(3, 2)
    last = args.passes - 1
    for r, name in enumerate(("observer, no table", "observer + table")):
        for c, p in enumerate((0, last)):
            ax = fig.add_subplot(gs[r, c])
            _panel(ax, sim, runs[name][0], _window(sim, k1, args, p), f"{name}, pass {p + 1}")
            if r == 0 and c == 0:
                ax.legend(fontsize=7, ncol=3, loc="upper right")
    # zoom on the largest fuel step up (from a fuelled state) in the evaluated window (Fig. 17)
    res = runs["observer + table"][0]
    w = np.flatnonzero(_window(sim, k1, args, last))
    step = np.where(sim.mf[w[:-1]] > 2.0, np.diff(sim.mf[w]), 0.0)     # not a fuel-cut recovery
    i = w[int(np.argmax(step))]
    z = np.zeros(sim.t.size, bool)
    z[max(i - 150, 0):i + 350] = True
    ax = fig.add_subplot(gs[2, :])
    _panel(ax, sim, res, z, f"zoom on a fuel step, observer + table, pass {last + 1}")
    ax.set_xlabel("time [s]")
    ax.legend(fontsize=7, ncol=5, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
