"""pwl zones: k-means gain zones (seed paper 001) on the chen2020 system, or on a gain database.

Default (the paper's experiment, docs/zones.md): N random operating points (u, x), steady gains,
k-means into k zones, then a Monte-Carlo comparison of the scheduled-gain EKF (SEKF) with the
full EKF on the estimate of x2 (RMSE, mean error), a k sweep, the paper's figures (gain clusters
in gain space and in (u, x) space, x2 traces, SEKF error histogram) and, with ``--bench``, the
per-step time of both filters measured in the same run.

With ``--database DB``: cluster the database's per-node update gains into k zones and write a
copy whose gains are the zone centroids (``--out``), printing the gain error and the sizes.

The computations are :mod:`experiments.zones`'s (imported inside ``run``); this module parses
the arguments, prints and draws the figures.
"""
from __future__ import annotations

import time

import numpy as np

HELP = "k-means gain zones: SEKF vs full EKF on the chen2020 system (figures, k sweep, Monte Carlo, speed)"


def add_arguments(p):
    p.add_argument("--N", type=int, default=10_000, help="random operating points (default %(default)s)")
    p.add_argument("-k", "--k", type=int, default=3, help="number of zones (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the operating points and k-means (default %(default)s)")
    p.add_argument("--runs", type=int, default=100, help="Monte-Carlo runs (default %(default)s)")
    p.add_argument("--steps", type=int, default=6000,
                   help="steps per run, 10 ms each (default %(default)s = 60 s)")
    p.add_argument("--kmax", type=int, default=10, help="k sweep 1..kmax (default %(default)s; 0: no sweep)")
    p.add_argument("--lookup", type=int, default=41, help="lookup grid points per axis (default %(default)s)")
    p.add_argument("--label", choices=("nearest", "gain"), default="nearest",
                   help="lookup-node labels: nearest sample (default) or nearest centre to the node's gain")
    p.add_argument("--x2-power", type=int, choices=(1, 2), default=1,
                   help="exponent of x2 in the x2 equation (docs/zones.md; default %(default)s)")
    p.add_argument("--bench", action="store_true",
                   help="time SEKF vs EKF per step in this run (default: no timing)")
    p.add_argument("--bench-steps", type=int, default=200_000,
                   help="with --bench: steps per timed run (default %(default)s)")
    p.add_argument("--bench-n", default="2,4,8,12",
                   help="with --bench: state sizes of a synthetic plant for the speed-ratio scaling "
                        "(default %(default)s; '' for none)")
    p.add_argument("--plots", default="pwl_zones",
                   help="prefix of the PNG figures, PREFIX_<figure>.png; needs matplotlib "
                        "(default %(default)s; '' for none)")
    p.add_argument("--save", help="write the k-zone record to this HDF5 file, /zones group (default: not written)")
    p.add_argument("--database", help="cluster the gains of this gain database instead (default: the chen2020 system)")
    p.add_argument("--out", help="with --database: write the zone-gain copy here (default: not written)")
    p.add_argument("--logs", nargs="+", help="with --database: logs with truth to compare zone "
                   "gains with interpolated gains (default: the shipped demo flights for the demo database)")
    p.add_argument("--settle", type=float, default=120.0,
                   help="with --logs: time at the start of a log left out of the error figures, s "
                        "(default %(default)g)")


def run(args) -> int:
    import os

    from .output import check_output

    check_output(args.save)
    check_output(args.out)
    if args.plots:
        check_output(os.path.dirname(os.path.abspath(args.plots)), folder=True)
    if args.database:
        return _run_database(args)
    from experiments.zones import monte_carlo, simulate_runs
    from linearize.zones import make_zones, sample_gains
    from pwl.zones import save_zones
    from models.chen2020 import Chen2020

    plant = Chen2020(x2_power=args.x2_power)
    t0 = time.perf_counter()
    samples = sample_gains(plant, args.N, args.seed)
    t_gain = time.perf_counter() - t0
    print(f"chen2020 (x2 power {args.x2_power}): {args.N} random operating points (u, x) in "
          f"u {plant.box_lo[0]:g}..{plant.box_hi[0]:g}, x1 {plant.box_lo[1]:g}..{plant.box_hi[1]:g}, "
          f"x2 {plant.box_lo[2]:g}..{plant.box_hi[2]:g}; steady gains in {t_gain:.1f} s; "
          f"{samples.failed} failed (excluded)")
    for i, msg in samples.failures[:3]:
        print(f"  failure: {msg}")
    zb = make_zones(samples, args.k, args.seed, args.lookup, args.label, plant=plant)
    _print_zones(zb)
    if args.save:
        save_zones(args.save, zb.table)
        print(f"zones record written to {args.save} (/zones, {zb.table.nbytes() / 1e3:.1f} kB)")

    print(f"\nMonte Carlo: {args.runs} runs x {args.steps} steps ({args.steps * plant.dt:g} s), "
          f"plant noise Q_sim = diag({', '.join(f'{v:g}' for v in np.diag(plant.Q_sim))}), R_sim = {plant.R_sim[0, 0]:g}; "
          f"filters Q = 0.01 I, R = 0.01")
    runs = simulate_runs(plant, args.runs, args.steps)
    mc = monte_carlo(plant, zb.table, runs)
    _print_mc(mc, args.k)

    sweep = None
    if args.kmax > 0:
        sweep = []
        for k in range(1, args.kmax + 1):
            t = zb.table if k == args.k else make_zones(samples, k, args.seed, args.lookup, args.label,
                                                        plant=plant).table
            r = monte_carlo(plant, t, runs, ekf=mc)
            sweep.append((k, r))
        print(f"\nk sweep ({args.runs} runs each, same runs): RMSE of x2; per-run ratio SEKF/EKF "
              "(paired: mean +- standard error)")
        print(f"{'k':>3} {'SEKF RMSE':>10} {'EKF RMSE':>9} {'ratio':>7} {'per-run ratio':>14} "
              f"{'mean err':>9} {'2 SE':>7}")
        for k, r in sweep:
            pr = r["rmse_s"] / r["rmse_e"]
            print(f"{k:>3} {r['rmse_s'].mean():>10.4f} {r['rmse_e'].mean():>9.4f} {r['ratio']:>7.4f} "
                  f"{pr.mean():>8.4f}+-{pr.std(ddof=1) / np.sqrt(len(pr)):.4f} "
                  f"{r['mean_s']:>+9.4f} {2 * r['se_s']:>7.4f}")

    bench = _bench(plant, zb.table, args.bench_steps) if args.bench else None
    if args.bench and args.bench_n:
        _bench_scaling([int(v) for v in args.bench_n.split(",")], args.bench_steps // 4)
    if args.plots:
        try:
            files = _plots(args.plots, zb, runs, mc, sweep, plant)
            print("\nfigures: " + ", ".join(files))
        except ImportError:
            print("\n(no figures: install the plot extra, pip install -e '.[plot]')")
    ok = mc["ratio"] <= 1.2 and abs(mc["mean_s"]) <= 2 * mc["se_s"]
    print(f"\nacceptance: RMSE ratio {mc['ratio']:.4f} (<= 1.2: {'yes' if mc['ratio'] <= 1.2 else 'NO'}, "
          f"goal 1.1: {'yes' if mc['ratio'] <= 1.1 else 'no'}); mean error {mc['mean_s']:+.4f} vs 2 SE "
          f"{2 * mc['se_s']:.4f} ({'yes' if abs(mc['mean_s']) <= 2 * mc['se_s'] else 'NO'})"
          + (f"; speed ratio {bench:.2f}x (>= 5: {'yes' if bench >= 5 else 'no'}; on the turbofan: "
             "pwl zones --database data/turbofan_demo.h5)" if bench else ""))
    return 0 if ok else 1


# ---- pieces ---------------------------------------------------------------------------------------
def _print_zones(zb):
    t, s = zb.table, zb.samples
    print(f"k-means: k = {t.k}, gains scaled by their std {np.array2string(t.scale, precision=4)}, "
          f"distortion {zb.distortion:.4f}; lookup grid {' x '.join(map(str, t.grid.shape))} "
          f"({t.attrs['label_method']} labels), record {t.nbytes() / 1e3:.1f} kB")
    names = [f"K{i + 1}" for i in range(t.gains.shape[1])]
    print(f"{'zone':>4} {'points':>7} " + " ".join(f"{n:>9}" for n in names) + "   |x1| range of members")
    for j in range(t.k):
        m = zb.labels == j
        x1 = np.abs(s.points[m, 1])
        print(f"{j:>4} {int(m.sum()):>7} " + " ".join(f"{v:>9.4f}" for v in t.gains[j].ravel())
              + f"   {x1.min():6.2f} .. {x1.max():6.2f}")


def _print_mc(mc, k):
    n = len(mc["rmse_s"])
    print(f"{'filter':<10} {'RMSE x2 mean':>13} {'sd':>7} {'min':>7} {'max':>7} {'mean err':>9} {'SE':>7}")
    for name, r, m, se in (("EKF", mc["rmse_e"], mc["mean_e"], mc["se_e"]),
                           (f"SEKF k={k}", mc["rmse_s"], mc["mean_s"], mc["se_s"])):
        print(f"{name:<10} {r.mean():>13.4f} {r.std(ddof=1) if n > 1 else 0:>7.4f} {r.min():>7.4f} "
              f"{r.max():>7.4f} {m:>+9.4f} {se:>7.4f}")
    worse = (mc["rmse_s"] > mc["rmse_e"]).mean()
    print(f"SEKF / EKF RMSE ratio {mc['ratio']:.4f} (per run: median "
          f"{np.median(mc['rmse_s'] / mc['rmse_e']):.4f}, max {np.max(mc['rmse_s'] / mc['rmse_e']):.4f}; "
          f"SEKF worse in {100 * worse:.0f} % of runs); SEKF steps outside the lookup box: {mc['outside']}")


def _bench(plant, table, steps, reps=9):
    """Print the per-step times of the SEKF and the EKF (:func:`experiments.zones.filter_timing`);
    the speed ratio EKF / SEKF (uniform lookup)."""
    from experiments.zones import filter_timing

    best = filter_timing(plant, table, steps, reps)
    print(f"\nspeed, {steps} steps per run, min of {reps} alternating runs (ns per step, steps/s):")
    for name, t in best.items():
        print(f"  {name:<22} {1e9 * t / steps:7.1f} ns   {steps / t:>12,.0f} /s   "
              f"EKF / this = {best['EKF'] / t:.2f}x")
    return best["EKF"] / best["SEKF (uniform lookup)"]


def _bench_scaling(sizes, steps, reps=5):
    """Print SEKF vs EKF per step against the state size (:func:`experiments.zones.speed_scaling`)."""
    from experiments.zones import speed_scaling

    rows = speed_scaling(sizes, steps, reps)
    print(f"\nspeed ratio versus state size (synthetic plant x+ = x + Ts (-x + s - 0.05 s^3 + u), "
          f"s = W x, y = x[:m]; {steps} steps, min of {reps}):")
    print(f"{'n':>4} {'m':>3} {'SEKF ns':>8} {'EKF ns':>8} {'EKF/SEKF':>9}")
    for n, m, t_s, t_e in rows:
        print(f"{n:>4} {m:>3} {1e9 * t_s / steps:>8.1f} {1e9 * t_e / steps:>8.1f} "
              f"{t_e / t_s:>8.2f}x")


def _plots(prefix, zb, runs, mc, sweep, plant):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, s = zb.table, zb.samples
    files = []
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(f"{prefix}_{name}.png", dpi=110)
        plt.close(fig)
        files.append(f"{prefix}_{name}.png")

    G = s.gains.reshape(len(s.gains), -1)
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for j in range(t.k):
        m = zb.labels == j
        ax.scatter(G[m, 0], G[m, 1], s=4, color=colors[j % 10], label=f"zone {j} ({m.sum()} points)")
    g = t.gains.reshape(t.k, -1)
    ax.scatter(g[:, 0], g[:, 1], marker="x", s=80, color="k", label="centroids")
    ax.set_xlabel("K1 (gain on x1)")
    ax.set_ylabel("K2 (gain on x2)")
    ax.set_title(f"Fig. 1: steady gains, k = {t.k} clusters")
    ax.legend(fontsize=8, loc="upper right")   # fixed places: "best" is slow with many points
    save(fig, "fig1_gain_clusters")

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for j in range(t.k):
        m = zb.labels == j
        axes[0].scatter(s.points[m, 0], s.points[m, 1], s=2, color=colors[j % 10], label=f"zone {j}")
        axes[1].scatter(s.points[m, 2], s.points[m, 1], s=2, color=colors[j % 10], label=f"zone {j}")
    axes[0].set_xlabel("u")
    axes[1].set_xlabel("x2")
    for a in axes:
        a.set_ylabel("x1")
        a.legend(fontsize=8, markerscale=4, loc="upper right")
    fig.suptitle("Fig. 2: zones in the operating space (u, x)")
    save(fig, "fig2_operating_space")

    x2, xe, xs = mc["traces"]
    tt = np.arange(len(x2)) * plant.dt
    fig, axes = plt.subplots(2, 1, figsize=(9, 6.5))
    for a, sl in ((axes[0], slice(None)), (axes[1], slice(len(tt) // 2, len(tt) // 2 + int(5 / plant.dt)))):
        a.plot(tt[sl], x2[sl], "k", lw=1.2, label="true x2")
        a.plot(tt[sl], xe[sl], lw=1.6, alpha=0.8, label="EKF")
        a.plot(tt[sl], xs[sl], "--", lw=0.9, label=f"SEKF (k = {t.k})")
        a.set_ylabel("x2")
        a.grid(alpha=0.3)
        a.legend(fontsize=8, loc="upper right")
    axes[0].set_title("Fig. 3: x2, true vs EKF vs SEKF (Monte-Carlo run 0)")
    axes[1].set_title("Fig. 4: zoom (5 s)")
    axes[1].set_xlabel("time, s")
    save(fig, "fig3_x2_traces")

    es = np.concatenate(mc["err_s"])
    ee = np.concatenate(mc["err_e"])
    fig, ax = plt.subplots(figsize=(6, 4.2))
    bins = np.linspace(np.percentile(es, 0.1), np.percentile(es, 99.9), 80)
    ax.hist(es, bins=bins, alpha=0.7, label=f"SEKF: mean {es.mean():+.3f}, sd {es.std():.3f}")
    ax.hist(ee, bins=bins, histtype="step", color="k", label=f"EKF: mean {ee.mean():+.3f}, sd {ee.std():.3f}")
    ax.set_xlabel("x2 estimation error")
    ax.set_ylabel("samples")
    ax.set_title(f"Fig. 5: SEKF x2 error, {len(mc['err_s'])} runs pooled")
    ax.legend(fontsize=8, loc="upper right")
    save(fig, "fig5_error_histogram")

    if sweep:
        ks = [k for k, _ in sweep]
        fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
        rm = np.array([r["rmse_s"].mean() for _, r in sweep])
        axes[0].plot(ks, rm, marker="o", label="SEKF")
        axes[0].axhline(sweep[0][1]["rmse_e"].mean(), color="k", ls="--", label="full EKF")
        axes[0].set_ylabel("RMSE of x2, mean over runs")
        pr = [r["rmse_s"] / r["rmse_e"] for _, r in sweep]
        axes[1].errorbar(ks, [v.mean() for v in pr], yerr=[v.std(ddof=1) / np.sqrt(len(v)) for v in pr],
                         marker="o", capsize=3, label="per-run RMSE ratio, mean +- SE")
        axes[1].axhline(1.0, color="k", ls="--", lw=0.8)
        axes[1].set_ylabel("SEKF / EKF RMSE (paired runs)")
        for a in axes:
            a.set_xlabel("number of zones k")
            a.set_xticks(ks)
            a.grid(alpha=0.3)
            a.legend(fontsize=8, loc="upper right")
        fig.suptitle(f"k sweep, {len(sweep[0][1]['rmse_s'])} Monte-Carlo runs")
        save(fig, "k_sweep")
    return files


def _run_database(args) -> int:
    """Zones of a gain database; with logs (default: the shipped demo flights when the demo
    database is used), the estimation errors with zone gains versus interpolated gains."""
    import os

    from experiments.zones import compare_database

    from ..demo_data import demo_paths

    logs = args.logs
    if logs is None:
        d_db, d_logs = demo_paths()
        if os.path.abspath(args.database) == os.path.abspath(d_db):
            logs = [p for p in d_logs if os.path.exists(p)]
    res = compare_database(args.database, logs or [], args.k, args.seed, args.settle, args.out)
    print(res["text"])
    if args.plots:
        try:
            files = _plot_database(args.plots, res)
            print("\nfigures: " + ", ".join(files))
        except ImportError:
            print("\n(no figures: install the plot extra, pip install -e '.[plot]')")
    return 0


def _plot_database(prefix, res):
    """The zone of every dynamics node (first two axes) and, with logs, the error traces of the
    three estimators on the last log."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..zones import ZoneTable

    t = ZoneTable.from_record(res["record"])
    tr = res.get("traces")
    fig, axes = plt.subplots(1, 2 if tr else 1, figsize=(11 if tr else 5.5, 4.2), squeeze=False)
    ax = axes[0, 0]
    g = t.grid
    nodes = g.nodes()
    lab = t.flat_labels
    x, y = (nodes[:, 0], nodes[:, 1]) if g.ndim > 1 else (nodes[:, 0], np.zeros(len(nodes)))
    sc = ax.scatter(x, y, c=lab, cmap="viridis", s=120, vmin=0, vmax=max(t.k - 1, 1))
    for xi, yi, li in zip(x, y, lab):
        ax.annotate(str(li), (xi, yi), ha="center", va="center", fontsize=8, color="w")
    ax.set_xlabel(f"{g.axes[0].name} [{g.axes[0].unit}]")
    if g.ndim > 1:
        ax.set_ylabel(f"{g.axes[1].name} [{g.axes[1].unit}]")
    ax.set_title(f"gain zones of the dynamics nodes (k = {t.k})")
    fig.colorbar(sc, ax=ax, label="zone", ticks=range(t.k))
    if tr:
        ax = axes[0, 1]
        w = max(1, int(round(2.0 / max(np.median(np.diff(tr["time"])), 1e-9))))
        for f, e in tr["errors"].items():  # 2-s running means: the sample noise hides the curves
            ax.plot(tr["time"][w - 1:], np.convolve(e, np.ones(w) / w, mode="valid"), lw=0.9, label=f)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"{tr['channel']} error [% of truth], 2-s mean")
        ax.set_title(f"{tr['log']}: interpolated, zone and full-Kalman gains")
        ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    name = f"{prefix}_database.png"
    fig.savefig(name, dpi=110)
    plt.close(fig)
    return [name]
