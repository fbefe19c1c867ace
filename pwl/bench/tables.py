"""Adaptive-table benchmark: 2-D ``exact`` table updates per second, numba kernel versus a plain
numpy implementation of the same step in the same run (never asserted in tests).

One update = index search + corner weights + table output + exact gains + node update + visit
counts, i.e. what :func:`pwl.tables.table_run` does per sample.
"""
from __future__ import annotations

import time

import numpy as np

from numba import njit

from ..grid import Axis, Grid, locate
from ..interp import corner_weights
from ..tables import LAW_EXACT, table_predict, table_run, table_update
from .speed import _best_of

_NONE = np.zeros((0, 0))  # no covariance: the exact law




@njit(cache=True, nogil=True)
def _weights_of(bp, off, strides, points, W, R, M):
    """Corner weights and rows of every point (precomputed for the kernel-only loop)."""
    n = points.shape[1]
    idx = np.zeros(n, dtype=np.int64)
    frac = np.zeros(n, dtype=np.float64)
    for k in range(points.shape[0]):
        locate(bp, off, points[k], False, idx, frac)
        M[k] = corner_weights(idx, frac, strides, W[k], R[k])


@njit(cache=True, nogil=True)
def _update_loop(values, counts, W, R, M, refs, ratio, repeat):
    """Predict + exact update with given weights: the table's marginal cost per runtime step
    (the runtime has already searched the grid and computed the weights for its gains)."""
    for _ in range(repeat):
        for k in range(W.shape[0]):
            xh = table_predict(values, W[k], R[k], M[k])
            table_update(values, counts, W[k], R[k], M[k], refs[k] - xh, LAW_EXACT, ratio)


def engine_grid() -> Grid:
    """The paper's engine table (000 sec. 6): speed 500..5000 rpm by 500, fuel 0..80 mg/str by 5."""
    return Grid([Axis("n", np.arange(500.0, 5000.1, 500.0), "rpm"),
                 Axis("mf", np.arange(0.0, 80.1, 5.0), "mg/str")])


def numpy_run(values, counts, grid: Grid, points, refs, ratio):
    """Reference: the same predict-then-learn loop, one sample at a time, with numpy calls."""
    v = values.reshape(-1)
    c = counts.reshape(-1)
    axes = [a.values for a in grid.axes]
    n = grid.ndim
    corners = np.array([[(k >> j) & 1 for j in range(n)] for k in range(1 << n)])
    pred = np.empty(len(points))
    for k in range(len(points)):
        p = points[k]
        i = np.array([min(max(np.searchsorted(a, x, side="right") - 1, 0), len(a) - 2)
                      for a, x in zip(axes, p)])
        lo = np.array([a[j] for a, j in zip(axes, i)])
        hi = np.array([a[j + 1] for a, j in zip(axes, i)])
        t = np.clip((p - lo) / (hi - lo), 0.0, 1.0)
        w = np.prod(np.where(corners == 1, t, 1.0 - t), axis=1)
        rows = (i + corners) @ grid.strides
        xh = w @ v[rows]
        pred[k] = xh
        c2 = w @ w
        pbar = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * ratio / c2))
        v[rows] += w * ((refs[k] - xh) / (pbar * c2))
        c[rows[w != 0.0]] += 1
    return pred


def bench_tables(n_points: int = 2_000_000, n_ref: int = 20_000, ratio: float = 1.0, seed: int = 0) -> dict:
    """2-D exact-law updates per second: numba kernel (slowly moving and random operating points)
    and the numpy reference (random points), their ratio, and the largest difference of the two
    tables after the same n_ref updates."""
    from .speed import random_walk

    grid = engine_grid()
    rng = np.random.default_rng(seed)
    lo = np.array([a.lo for a in grid.axes])
    hi = np.array([a.hi for a in grid.axes])
    pts = {"walk": random_walk(grid, n_points, seed=seed),
           "random": np.ascontiguousarray(lo + rng.random((n_points, 2)) * (hi - lo))}
    nodes = grid.nodes()
    truth = np.sin(nodes[:, 0] / 1000.0) + 0.02 * nodes[:, 1]
    res = {"grid": list(grid.shape), "law": "exact", "ratio": ratio, "points": n_points}
    hist = np.empty((0, grid.size))
    pred = np.empty(n_points)
    for kind, p in pts.items():
        refs = np.ascontiguousarray(np.sin(p[:, 0] / 1000.0) + 0.02 * p[:, 1])
        vals = np.zeros(grid.size)
        cnts = np.zeros(grid.size, dtype=np.int64)
        table_run(vals, cnts, grid.bp, grid.off, grid.strides, False, p[:10], refs[:10], LAW_EXACT,
                  ratio, 0.0, False, pred, hist, _NONE, _NONE, 0.0)  # compile / load from cache

        def go():
            vals[:] = 0.0
            cnts[:] = 0
            table_run(vals, cnts, grid.bp, grid.off, grid.strides, False, p, refs, LAW_EXACT, ratio,
                      0.0, False, pred, hist, _NONE, _NONE, 0.0)
        t = _best_of(go)
        res[f"numba_updates_per_s_{kind}"] = n_points / t
        res[f"table_rms_error_{kind}"] = float(np.sqrt(np.mean((vals - truth) ** 2)))
    # kernel only: weights precomputed (200k points, looped)
    nk = min(200_000, n_points)
    rep = max(1, n_points // nk)
    p = pts["random"][:nk]
    W = np.zeros((nk, 4))
    R = np.zeros((nk, 4), dtype=np.int64)
    M = np.zeros(nk, dtype=np.int64)
    _weights_of(grid.bp, grid.off, grid.strides, p, W, R, M)
    refs = np.sin(p[:, 0] / 1000.0) + 0.02 * p[:, 1]
    vals = np.zeros(grid.size)
    cnts = np.zeros(grid.size, dtype=np.int64)
    _update_loop(vals, cnts, W, R, M, refs, ratio, 1)
    t = _best_of(lambda: _update_loop(vals, cnts, W, R, M, refs, ratio, rep))
    res["numba_predict_update_per_s_given_weights"] = nk * rep / t
    p = pts["random"][:n_ref]
    refs = np.sin(p[:, 0] / 1000.0) + 0.02 * p[:, 1]
    v_np = np.zeros(grid.size)
    c_np = np.zeros(grid.size, dtype=np.int64)
    t0 = time.perf_counter()
    numpy_run(v_np, c_np, grid, p, refs, ratio)
    t = time.perf_counter() - t0
    res["numpy_updates_per_s"] = n_ref / t
    res["speedup_random"] = res["numba_updates_per_s_random"] / res["numpy_updates_per_s"]
    v_nb = np.zeros(grid.size)
    c_nb = np.zeros(grid.size, dtype=np.int64)
    table_run(v_nb, c_nb, grid.bp, grid.off, grid.strides, False, np.ascontiguousarray(p),
              np.ascontiguousarray(refs), LAW_EXACT, ratio, 0.0, False, np.empty(n_ref), hist, _NONE, _NONE, 0.0)
    res["max_abs_diff_vs_numpy"] = float(np.abs(v_nb - v_np).max())
    res["counts_equal"] = bool(np.array_equal(c_nb, c_np))
    return res
