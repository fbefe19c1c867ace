"""Benchmarks: speed as ratios against a reference run in the same process (never asserted)."""
from __future__ import annotations

import time

import numpy as np

from numba import njit

from ..demo_data import demo_paths
from ..grid import Axis, Grid, locate
from ..interp import as_table, corner_weights, interp_many, interp_rows
from .floor import flops_per_step, fma_peak, make_floor


def _best_of(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def random_walk(grid: Grid, n: int, step: float = 0.002, seed: int = 0) -> np.ndarray:
    """n points (n, ndim) wandering through the grid box (steps of ``step`` x the axis span)."""
    rng = np.random.default_rng(seed)
    lo = np.array([a.lo for a in grid.axes])
    hi = np.array([a.hi for a in grid.axes])
    u = np.cumsum(rng.normal(0.0, step, (n, grid.ndim)), axis=0) + 0.5
    u = np.abs((u + 1.0) % 2.0 - 1.0)  # reflect into [0, 1]
    return np.ascontiguousarray(lo + u * (hi - lo))


@njit(cache=True)
def _interp_loop(table, bp, off, strides, points, out):
    """What the runtime does per step: search, weights, one block into a reused buffer."""
    n = points.shape[1]
    idx = np.zeros(n, dtype=np.int64)
    frac = np.zeros(n, dtype=np.float64)
    wts = np.zeros(1 << n, dtype=np.float64)
    rows = np.zeros(1 << n, dtype=np.int64)
    check = 0.0
    for i in range(points.shape[0]):
        locate(bp, off, points[i], False, idx, frac)
        m = corner_weights(idx, frac, strides, wts, rows)
        interp_rows(table, wts, rows, m, out)
        check += out[i % out.shape[0]]
    return check


def bench_interp(n_points: int = 200_000, block: int = 200, shape=(9, 7, 5), seed: int = 0) -> dict:
    """Block interpolations per second: our kernel (search + weights + 2^n row additions, one
    point at a time as the runtime does) versus scipy's RegularGridInterpolator on the same data,
    called per point and vectorised over all points."""
    from scipy.interpolate import RegularGridInterpolator

    rng = np.random.default_rng(seed)
    grid = Grid([Axis(f"a{j}", np.cumsum(rng.uniform(0.5, 1.5, n))) for j, n in enumerate(shape)])
    values = rng.normal(size=grid.shape + (block,))
    table = as_table(grid, values)
    out = np.empty(block)
    res = {"grid": list(shape), "block_doubles": block, "points": n_points}
    for kind, pts in (("walk", random_walk(grid, n_points, seed=seed)),
                      ("random", np.ascontiguousarray(
                          [a.lo for a in grid.axes] + rng.random((n_points, grid.ndim))
                          * [a.hi - a.lo for a in grid.axes]))):
        _interp_loop(table, grid.bp, grid.off, grid.strides, pts[:10], out)  # compile
        t = _best_of(lambda: _interp_loop(table, grid.bp, grid.off, grid.strides, pts, out))
        res[f"pwl_per_s_{kind}"] = n_points / t
    rgi = RegularGridInterpolator([a.values for a in grid.axes], values)
    pts = random_walk(grid, n_points, seed=seed)
    m = 2000
    t = _best_of(lambda: [rgi(pts[i]) for i in range(m)])
    res["rgi_per_s_single"] = m / t
    t = _best_of(lambda: rgi(pts[:20000]))
    res["rgi_per_s_vectorised"] = 20000 / t
    ref = rgi(pts[:1000])
    got = np.empty((1000, block))
    interp_many(table, grid.bp, grid.off, grid.strides, False, pts[:1000], got)
    res["max_abs_diff_vs_rgi"] = float(np.abs(got - ref).max())
    res["ratio_vs_rgi_single"] = res["pwl_per_s_walk"] / res["rgi_per_s_single"]
    res["ratio_vs_rgi_vectorised"] = res["pwl_per_s_walk"] / res["rgi_per_s_vectorised"]
    return res


def _floor_run(est, U, Y, S, TH, DE):
    """A function running the floor loop (:func:`pwl.bench.floor.make_floor`) over the log with
    ``est``'s packed model; it returns z_hat (the same estimates as the kernel's on a log with
    every sample present: bench_run reports their largest difference)."""
    m, g = est._model, est._grids
    nx, nq = int(m.dims[0]), int(m.dims[4])
    out = {o: np.empty((U.shape[0], len(est.names[o]))) for o in ("x_hat", "q_hat", "y_hat", "residual", "z_hat")}

    floor_loop = make_floor(m.dims, S.shape[1])

    def run():   # returns z_hat
        floor_loop(U, Y, S, TH, DE, m.trim_tab, m.dyn_tab, m.ex, m.cls, m.s_scale, m.s_corr,
                   m.amb_col, m.amb_p, m.amb_k,
                   g.t_bp, g.t_off, g.t_str, g.t_pidx, g.d_bp, g.d_off, g.d_str, g.d_pidx,
                   np.full(nx, np.nan), np.zeros(nq), out["x_hat"], out["q_hat"], out["y_hat"],
                   out["residual"], out["z_hat"])
        return out["z_hat"]
    return run


def bench_run(db_path=None, log_path=None, n_ref: int = 2000) -> dict:
    """Steps per second of the numba runtime on a whole log versus the plain numpy +
    RegularGridInterpolator reference (:mod:`pwl.bench.reference`) on its first ``n_ref`` samples,
    in the same run; also their largest difference on those samples, the speed with a
    learning bias table and of the online-covariance (full Kalman filter) mode, and against the
    floor (:mod:`pwl.bench.floor`, a minimal fused loop doing the same arithmetic: ratio_to_floor
    is the runtime's time per step over the floor's), with its flops per step as a fraction of
    what a multiply-add loop does on this machine."""
    from ..estimator import Estimator
    from ..logs import read_log
    from .reference import ReferenceFilter

    d_db, d_logs = demo_paths()
    est = Estimator(db_path or d_db)
    log = read_log(log_path or d_logs[-1])
    U, Y, S, TH, DE = est._split(log)
    one = np.ones(len(log))
    TH = one if TH is None else TH
    DE = one if DE is None else DE
    n = len(log)
    est.run_arrays(U[:10], Y[:10], S[:10], TH[:10], DE[:10])  # compile / load from cache

    buf = est.run_arrays(U, Y, S, TH, DE)
    bufs = dict(buf.outputs, flags=buf.flags)

    def go():  # output buffers reused: the kernel's speed, not the allocator's
        est.reset()
        est.run_arrays(U, Y, S, TH, DE, out=dict(bufs))
    floor = _floor_run(est, U, Y, S, TH, DE)
    est.reset()
    z = est.run_arrays(U, Y, S, TH, DE).z_hat
    floor_diff = float(np.nanmax(np.abs(floor() - z) / (1.0 + np.abs(z))))   # the same estimates
    t, t_floor = np.inf, np.inf
    for _ in range(5):   # alternated: the machine's drift hits both alike
        t = min(t, _best_of(go, repeat=1))
        t_floor = min(t_floor, _best_of(floor, repeat=1))
    est.new_bias_tables([est.db.names["y"][-2]], ratio=1e3)  # a learning bias table on one sensor
    buf = est.run_arrays(U, Y, S, TH, DE)
    bufs_b = dict(buf.outputs, flags=buf.flags)

    def go_bias():
        est.reset()
        est.run_arrays(U, Y, S, TH, DE, out=dict(bufs_b))
    t_bias = _best_of(go_bias, repeat=5)
    est.new_bias_tables([])
    onl = Estimator(est.db, "online", health_std=False)  # the filter alone
    onl.run_arrays(U, Y, S, TH, DE, out=dict(bufs))

    def go_online():
        onl.reset()
        onl.run_arrays(U, Y, S, TH, DE, out=dict(bufs))
    t_onl = _best_of(go_online, repeat=3)
    ref = ReferenceFilter(est.db)
    m = min(n_ref, n)
    t0 = time.perf_counter()
    r = ref.run(U[:m], Y[:m], S[:m], TH[:m], DE[:m])
    t_ref = time.perf_counter() - t0
    est.reset()
    got = est.run_arrays(U[:m], Y[:m], S[:m], TH[:m], DE[:m])
    # relative to each output's size; a residual is a small difference of large sensor values, so
    # it is measured against the sensor value it came from
    scale = {o: 1.0 + np.abs(r["y_hat" if o == "residual" else o]) for o in r}
    diff = max(float(np.max(np.abs(got.outputs[o] - r[o]) / scale[o])) for o in r)
    dt = est.db.dt
    flops = flops_per_step(est._model, est._grids)
    peak = fma_peak()
    return {"database": est.db.path, "log": log.path, "samples": n,
            "pwl_steps_per_s": n / t, "x_real_time": n / t * dt, "ns_per_step": t / n * 1e9,
            "floor_steps_per_s": n / t_floor, "ratio_to_floor": t / t_floor,
            "floor_max_rel_diff_z": floor_diff,
            "flops_per_step": flops, "fma_loop_flops_per_s": peak,
            "fraction_of_fma_loop": flops * n / t / peak,
            "pwl_steps_per_s_with_bias_table": n / t_bias,
            "online_covariance_steps_per_s": n / t_onl,
            "reference_steps_per_s": m / t_ref, "ratio": (n / t) / (m / t_ref),
            "max_rel_diff_vs_reference": diff}


def bench_stream(db_path=None, log_path=None, n: int = 20000) -> dict:
    """Per-sample cost of :class:`pwl.streaming.Stream` (one ``step`` call per sample from Python,
    the sample a row of an array) against a batch run of the same ``n`` samples of the demo
    flight, in the same run; and their largest difference (the numbers must be equal: a separate,
    untimed pass copies each step's z_hat)."""
    from ..estimator import Estimator
    from ..logs import read_log
    from ..streaming import Stream

    d_db, d_logs = demo_paths()
    est = Estimator(db_path or d_db)
    log = read_log(log_path or d_logs[-1])
    stream = Stream(est)
    rows = np.ascontiguousarray(np.column_stack([log.channels[c] for c in stream.channels])[:n])
    n = rows.shape[0]
    z = np.empty((n, len(stream.z_hat)))
    est.reset()
    for k in range(n):
        stream.step(rows[k])
        z[k] = stream.z_hat

    def go_stream():
        est.reset()
        step = stream.step
        for k in range(n):
            step(rows[k])
    t_stream = _best_of(go_stream, repeat=3)
    U, Y, S, TH, DE = est._split(log, slice(0, n))
    est.reset()
    batch = est.run_arrays(U, Y, S, TH, DE)

    def go_batch():
        est.reset()
        est.run_arrays(U, Y, S, TH, DE)
    t_batch = _best_of(go_batch, repeat=5)
    return {"samples": n, "stream_us_per_step": t_stream / n * 1e6,
            "batch_us_per_step": t_batch / n * 1e6, "ratio": t_stream / t_batch,
            "max_abs_diff_z": float(np.nanmax(np.abs(z - batch.z_hat)))}
