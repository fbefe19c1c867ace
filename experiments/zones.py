"""Seed paper 001 (Chen 2020): k-means gain zones, the scheduled-gain EKF (SEKF) against the full
EKF on the chen2020 system, and the zones of a gain database against interpolated gains.

The computations of ``pwl zones`` (which parses the arguments, prints and draws the figures):
the seeded Monte-Carlo runs (:func:`simulate_runs`, :func:`monte_carlo`), the per-step times of
the filters measured in the same process (:func:`filter_timing`, :func:`speed_scaling` on a
synthetic n-state plant), and the database comparison (:func:`compare_database`,
:func:`filter_speed`). docs/zones.md has the set-up and the results.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from pwl.grid import Axis, Grid
from pwl.zones import ZoneTable

from .ekf import ekf_loop, run_ekf, run_sekf, sekf_loop

njit_lazy = njit(nogil=True)       # the synthetic bench plant compiles only when used


def simulate_runs(plant, runs, steps):
    """``runs`` seeded simulations (U, X, Y, xh0) of ``steps`` steps each (run r: seed 10000 + r),
    xh0 the initial estimate drawn around the plant's x0 with covariance P0."""
    out = []
    for r in range(runs):
        rng = np.random.default_rng(10_000 + r)
        U = plant.input_signal(steps, rng)
        X, Y = plant.simulate(U, rng)
        xh0 = plant.x0 + rng.multivariate_normal(np.zeros(2), plant.P0)
        out.append((U, X, Y, xh0))
    return out


def monte_carlo(plant, table, runs, ekf=None):
    """RMSE and mean of the x2 error (a-posteriori estimate minus truth) per run, SEKF and EKF.
    ``ekf``: a previous result on the same runs whose EKF figures are reused (k sweep)."""
    rs, ms, outside, errs = [], [], 0, []
    re, me, errs_e, traces = [], [], [], []
    for i, (U, X, Y, xh0) in enumerate(runs):
        Xs, o = run_sekf(plant.functions, plant.p, table, U, Y, xh0)
        outside += o
        es = Xs[:, 1] - X[:-1, 1]
        rs.append(np.sqrt(np.mean(es ** 2)))
        ms.append(es.mean())
        errs.append(es)
        if ekf is None:
            Xe, _ = run_ekf(plant.functions, plant.p, U, Y, xh0, plant.P0, plant.Q, plant.R)
            ee = Xe[:, 1] - X[:-1, 1]
            re.append(np.sqrt(np.mean(ee ** 2)))
            me.append(ee.mean())
            errs_e.append(ee)
            if i == 0:
                traces = (X[:-1, 1], Xe[:, 1], Xs[:, 1])
    if ekf is not None:
        re, me, errs_e, traces = ekf["rmse_e"], ekf["mean_runs_e"], ekf["err_e"], ekf["traces"]
    rs, ms, re, me = map(np.asarray, (rs, ms, re, me))
    n = len(runs)
    return {"rmse_s": rs, "rmse_e": re, "ratio": rs.mean() / re.mean(), "mean_runs_s": ms,
            "mean_runs_e": me, "mean_s": ms.mean(), "se_s": ms.std(ddof=1) / np.sqrt(n) if n > 1 else np.inf,
            "mean_e": me.mean(), "se_e": me.std(ddof=1) / np.sqrt(n) if n > 1 else np.inf,
            "err_s": errs, "err_e": errs_e, "outside": outside, "traces": traces}


def filter_timing(plant, table, steps, reps=9) -> dict:
    """Per-step time of the SEKF (uniform lookup and grid-search lookup) and the EKF on the same
    data, alternating repetitions in this process; min over repetitions: {case: seconds per run of ``steps`` steps}."""
    rng = np.random.default_rng(1)
    U = plant.input_signal(steps, rng)
    X, Y = plant.simulate(U, rng)
    fn, p = plant.functions, plant.p
    co = np.arange(3)
    Xo = np.empty((steps, 2))
    Z = np.empty(0, np.int64)
    Pd = np.empty((0, 2))
    cases = {
        "SEKF (uniform lookup)": lambda: sekf_loop(fn.f, fn.h, U, Y, plant.x0, p, co, *table.kernel_args(),
                                                   table.gains, Xo, Z),
        "SEKF (grid search)": lambda: sekf_loop(fn.f, fn.h, U, Y, plant.x0, p, co,
                                                *table.kernel_args(force_search=True), table.gains, Xo, Z),
        "EKF": lambda: ekf_loop(fn.f, fn.jac_f, fn.h, fn.jac_h, U, Y, plant.x0, plant.P0, plant.Q,
                                plant.R, p, Xo, Pd),
    }
    best = {}
    for c in cases.values():
        c()                                    # compile / warm up
    for _ in range(reps):
        for name, c in cases.items():
            t0 = time.perf_counter()
            c()
            best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
    return best


# a synthetic n-state plant for the speed scaling only (polynomial like chen2020):
# x+ = x + Ts (-x + s - 0.05 s^3 + u), s = W x;  y = x[:m]
@njit_lazy
def _syn_f(x, u, p, out):
    n, Ts = int(p[0]), p[2]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += p[3 + i * n + j] * x[j]
        out[i] = x[i] + Ts * (-x[i] + s - 0.05 * s * s * s + u[0])


@njit_lazy
def _syn_jf(x, u, p, out):
    n, Ts = int(p[0]), p[2]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += p[3 + i * n + j] * x[j]
        d = 1.0 - 0.15 * s * s
        for j in range(n):
            out[i, j] = Ts * d * p[3 + i * n + j] + ((1.0 - Ts) if i == j else 0.0)


@njit_lazy
def _syn_h(x, u, p, out):
    for i in range(int(p[1])):
        out[i] = x[i]


@njit_lazy
def _syn_jh(x, u, p, out):
    n = int(p[0])
    for i in range(int(p[1])):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0


def speed_scaling(sizes, steps, reps=5) -> list:
    """SEKF vs EKF per step on the synthetic plant for several state sizes n (m = max(1, n // 4)
    outputs; lookup over (u, x1, x2), 9 nodes per axis, arbitrary zone labels: the cost of a
    lookup does not depend on the labels). Rows (n, m, SEKF s per run, EKF s per run)."""
    rows = []
    rng = np.random.default_rng(0)
    for n in sizes:
        m = max(1, n // 4)
        W = rng.normal(size=(n, n)) / np.sqrt(n)
        p = np.r_[n, m, 0.01, W.ravel()].astype(np.float64)
        U = rng.uniform(-0.5, 0.5, (steps, 1))
        Y = 0.1 * rng.normal(size=(steps, m))
        grid = Grid([Axis(f"c{j}", np.linspace(-1.0, 1.0, 9)) for j in range(3)])
        co = np.arange(3)
        k = 3
        zt = ZoneTable(gains=rng.normal(size=(k, n, m)) * 0.1, grid=grid,
                       labels=rng.integers(0, k, grid.shape), centers=np.zeros((k, n * m)),
                       scale=np.ones(n * m), counts=np.ones(k, np.int64))
        x0, P0, Q, R = np.zeros(n), np.eye(n), 0.01 * np.eye(n), 0.01 * np.eye(m)
        Xo, Z, Pd = np.empty((steps, n)), np.empty(0, np.int64), np.empty((0, n))
        cases = {"s": lambda: sekf_loop(_syn_f, _syn_h, U, Y, x0, p, co, *zt.kernel_args(), zt.gains, Xo, Z),
                 "e": lambda: ekf_loop(_syn_f, _syn_jf, _syn_h, _syn_jh, U, Y, x0, P0, Q, R, p, Xo, Pd)}
        best = {}
        for c in cases.values():
            c()
        for _ in range(reps):
            for name, c in cases.items():
                t0 = time.perf_counter()
                c()
                best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
        rows.append((n, m, best["s"], best["e"]))
    return rows


def filter_speed(ests: dict, log, repeat: int = 5) -> dict:
    """Steps per second of each estimator on ``log`` (whole log, output buffers reused), minimum
    of ``repeat`` alternating runs in this process; "ratio" = zones / online when both exist."""
    args = {f: e._split(log) for f, e in ests.items()}
    bufs = {}
    for f, e in ests.items():
        r = e.run_arrays(*args[f])
        bufs[f] = dict(r.outputs, flags=r.flags)
    best = dict.fromkeys(ests, np.inf)
    for _ in range(repeat):
        for f, e in ests.items():
            e.reset()
            t0 = time.perf_counter()
            e.run_arrays(*args[f], out=dict(bufs[f]))
            best[f] = min(best[f], time.perf_counter() - t0)
    n = len(log.time)
    st = {f: n / t for f, t in best.items()}
    ratio = st["zones"] / st["online"] if "zones" in st and "online" in st else None
    return {"log": log.path, "samples": n, "repeat": repeat, "steps_per_s": st, "ratio": ratio}


def compare_database(db_path, logs, k: int = 3, seed: int = 0, settle: float = 120.0, out=None) -> dict:
    """Cluster a database's gains into k zones (:func:`linearize.zones.database_zones`) and run
    the estimator with interpolated gains and with zone gains over ``logs`` that carry truth.

    Three estimators: "interp" (the database's steady gains, interpolated), "zones" (the zone
    centroid gain of the nearest dynamics node, picked per step: ``Estimator(db, "zones")``) and "online" (the full Kalman filter of the same model, :class:`Estimator`
    ``"online"``: the EKF baseline). Returns {"text": printable report, "rows": [(log, channel,
    {estimator: (RMS, mean)})] in % of truth, "health": [(log, names, {estimator: median
    estimates}, truth)], "sizes": {...} bytes, "record", "speed": :func:`filter_speed` on the
    first log, "traces": the last log's % error of its first unmeasured output with truth, per
    estimator, or None}."""
    import os
    import tempfile

    from linearize.zones import database_zones

    from pwl.cli.demo import errors
    from pwl.database import GainDatabase
    from pwl.estimator import Estimator
    from pwl.logs import read_log
    from pwl.fleet.trending import health_summary

    db = GainDatabase.open(db_path)
    record, zoned = database_zones(db, k, seed)
    t = ZoneTable.from_record(record)
    a = t.attrs
    lines = [f"{db_path}: {a['N']} dynamics nodes, gains K {db.kalman['K'].shape[-2:]} clustered into "
             f"k = {t.k} zones (counts {t.counts.tolist()})",
             f"  within-zone gain error |K - K_zone| / |K|: max {a['gain_rel_error_max']:.3g}, "
             f"mean {a['gain_rel_error_mean']:.3g}"]
    if out:
        zoned.save(out)
        zpath = out
    else:
        fd, zpath = tempfile.mkstemp(suffix=".h5")
        os.close(fd)
        zoned.save(zpath)
    sizes = {"K_bytes": a["K_bytes"], "record_bytes": a["record_bytes"],
             "file_bytes": os.path.getsize(db_path), "zoned_file_bytes": os.path.getsize(zpath)}
    if not out:
        os.remove(zpath)
    lines.append(f"  gains: /kalman/K {sizes['K_bytes'] / 1e3:.1f} kB (one gain per node, interpolated) "
                 f"vs zones record {sizes['record_bytes'] / 1e3:.1f} kB (k gains + a label per node); "
                 f"files {sizes['file_bytes'] / 1e6:.2f} MB vs {sizes['zoned_file_bytes'] / 1e6:.2f} MB "
                 "(the zoned copy keeps a K per node for the runtime, holding its zone's centroid)")
    if out:
        lines.append(f"  zone-gain copy written to {out}")
    rows, health, speed, traces = [], [], {}, None
    if logs:
        ests = {"interp": Estimator(db, settle=settle), "zones": Estimator(zoned, "zones", settle=settle),
                "online": Estimator(db, "online", health_std=False, settle=settle)}   # settling: the summaries' own
        for path in logs:
            log = read_log(path)
            res = {f: e.run(log) for f, e in ests.items()}
            name = os.path.splitext(os.path.basename(os.fspath(path)))[0]
            settled = log.time >= log.time[0] + settle
            ch0 = next((c for c in db.names["z"] if c in log.truth), None)
            if ch0 is not None:  # the last log's error traces, for the figure
                traces = {"log": name, "channel": ch0, "time": log.time,
                          "errors": {f: 100.0 * (r.channel("z_hat", ch0) - log.truth[ch0])
                                     / np.abs(log.truth[ch0]) for f, r in res.items()}}
            for ch in db.names["z"]:
                if ch in log.truth:
                    rows.append((name, ch, {f: errors(r.channel("z_hat", ch), log.truth[ch], settled)
                                            for f, r in res.items()}))
            names = db.names["h"]
            if names and any(h in log.truth for h in names):
                tr = np.array([np.mean(log.truth[h]) if h in log.truth else np.nan for h in names])
                health.append((name, list(names), {f: health_summary(r.time, r.h_hat, r.flags, names, path,
                                                               settle).values for f, r in res.items()}, tr))
        speed = filter_speed(ests, read_log(logs[0]))
        lines.append(f"\nestimation error, % of truth after the first {settle:g} s (RMS / mean); "
                     "interp: interpolated steady gains, zones: the zone gain of the nearest node, online: full Kalman filter "
                     "(covariance propagated every step)")
        lines.append(f"{'log':<20} {'output':<8} " + " ".join(f"{f + ' RMS':>11}" for f in ests) + " "
                     + " ".join(f"{f + ' mean':>12}" for f in ests))
        for name, ch, e in rows:
            lines.append(f"{name:<20} {ch:<8} " + " ".join(f"{e[f][0]:>11.3f}" for f in ests) + " "
                         + " ".join(f"{e[f][1]:>12.3f}" for f in ests))
        for name, names, h, tr in health:
            lines.append(f"health, % (median estimate), {name}:")
            lines.append(f"  {'':<8} " + " ".join(f"{n:>10}" for n in names))
            for lab, v in list(h.items()) + [("truth", tr)]:
                lines.append(f"  {lab:<8} " + " ".join(f"{100 * x:>10.3f}" for x in v))
        st = speed["steps_per_s"]
        lines.append(f"\nspeed on {speed['log']} ({speed['samples']} samples, min of {speed['repeat']} "
                     "alternating runs, this process):")
        for f, v in st.items():
            lines.append(f"  {f:<8} {1e9 / v:8.0f} ns per step  {v:>12,.0f} steps/s   "
                         f"{v / st['online']:5.2f}x the online filter's speed")
        lines.append(f"  zone gains (SEKF) are {speed['ratio']:.1f}x faster per step than the full "
                     "Kalman filter (EKF) of the same model")
    return {"text": "\n".join(lines), "rows": rows, "health": health, "sizes": sizes, "record": record,
            "speed": speed, "traces": traces}
