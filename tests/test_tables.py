"""Adaptive look-up tables (pwl.tables): gains against independent references, the correlated
whole-table update against a plain numpy Kalman filter, state handling, records, and the claims
of the seed 000 / seed 003 experiments on small seeded runs."""
import math

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import RegularGridInterpolator

from pwl import Axis, Grid
from pwl.database import GainDatabase
from pwl.interp import corner_weights
from pwl.tables import (LAW_EXACT, LAW_PAPER, AdaptiveTable, TableError, exact_gains, paper_gains,
                        table_predict, table_update)


# ---- independent references (numpy, written from the papers' formulas) ----------------------
def riccati_limit_gain(c, r, tol=1e-13, max_iter=20_000):
    """Iterate P <- P - P c c^T P / (c^T P c + r) + I (A = I, Q = I, R = r, a-priori P) from P = I
    and return the limit of K = P c / (c^T P c + r). P itself diverges (not detectable): only
    K converges, so stop when K has stopped changing for 20 iterations (the contraction factor
    is at most r / (r + pbar |c|^2) < 0.976 here: what is left is below 40 tol = 4e-12)."""
    m = c.size
    P = np.eye(m)
    K_old = np.full(m, np.inf)
    quiet = 0
    for _ in range(max_iter):
        Pc = P @ c
        S = c @ Pc + r
        K = Pc / S
        P = P - np.outer(Pc, Pc) / S + np.eye(m)
        P = 0.5 * (P + P.T)
        quiet = quiet + 1 if np.max(np.abs(K - K_old)) < tol else 0
        if quiet >= 20:
            return K
        K_old = K
    return K


def ki(eta, r):
    """000 (A.4)-(A.5): gain of node i for relative position eta of the point in [x_i, x_i+1]."""
    q = 1 - 2 * eta + 2 * eta ** 2
    s = math.sqrt(1 + 4 * r / q)
    return 0.5 * (1 - eta) * (1 + s) / (0.5 * (1 + s) * q + r)


def weights(grid, p):
    idx, frac, flags = grid.locate(np.asarray(p, dtype=float))
    n = grid.ndim
    wts, rows = np.zeros(1 << n), np.zeros(1 << n, dtype=np.int64)
    m = corner_weights(idx, frac, grid.strides, wts, rows)
    return wts[:m].copy(), rows[:m].copy(), m, frac.copy(), flags


def random_grid(rng, ndim, nmax=5):
    return Grid([Axis(f"a{j}", np.cumsum(rng.uniform(0.3, 2.0, rng.integers(2, nmax + 1))) - 1.0)
                 for j in range(ndim)])


# ---- gain laws ------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(ndim=st.integers(1, 4), log_ratio=st.floats(-2.0, 2.0), seed=st.integers(0, 2 ** 32 - 1))
def test_exact_gain_is_the_riccati_limit(ndim, log_ratio, seed):
    rng = np.random.default_rng(seed)
    grid = random_grid(rng, ndim)
    p = [rng.uniform(a.lo, a.hi) for a in grid.axes]
    wts, rows, m, _, _ = weights(grid, p)
    r = 10.0 ** log_ratio
    k = np.zeros(m)
    exact_gains(wts, m, r, k)
    ref = riccati_limit_gain(wts, r)
    assert np.max(np.abs(k - ref)) < 1e-10
    # the update kernel applies exactly these gains and counts the nodes
    v = rng.normal(size=grid.size)
    v0 = v.copy()
    counts = np.zeros(grid.size, dtype=np.int64)
    table_update(v, counts, wts, rows, m, 0.7, LAW_EXACT, r)
    dv = np.zeros(grid.size)
    dv[rows] = 0.7 * ref
    assert np.max(np.abs(v - v0 - dv)) < 1e-10
    assert counts.sum() == m and np.all(counts[rows] == 1)


@pytest.mark.parametrize("r", [1e-2, 0.3, 1.0, 7.0, 100.0])
def test_exact_gain_riccati_at_nodes_faces_and_centres(r):
    """Points on a node (1 active corner), on a face (2) and at a 3-D cell centre (8)."""
    grid = Grid([Axis("x", [0, 1, 2]), Axis("y", [0, 1, 2]), Axis("z", [0, 1])])
    for p in ([1, 1, 0], [0.5, 1, 0], [0.5, 0.5, 0.5], [1.9, 0.1, 0.25]):
        wts, rows, m, _, _ = weights(grid, p)
        k = np.zeros(m)
        exact_gains(wts, m, r, k)
        assert np.max(np.abs(k - riccati_limit_gain(wts, r))) < 1e-10


def test_exact_equals_paper_in_1d_and_not_in_2d():
    g1 = Grid([Axis("u", [0.0, 1.0, 3.0])])
    for r in (0.0, 0.01, 1.0, 50.0):
        for x in (0.0, 0.2, 0.5, 0.93, 2.2):
            wts, rows, m, frac, _ = weights(g1, [x])
            ke, kp = np.zeros(m), np.zeros(m)
            exact_gains(wts, m, r, ke)
            paper_gains(frac, r, kp)
            assert np.allclose(ke, kp, rtol=1e-13, atol=1e-15)
    # DESIGN.md: at a node of a 2-D table with r = 1, A.7 gives 0.382 where the steady state is 0.618
    g2 = Grid([Axis("u", [0, 1, 2]), Axis("v", [0, 1, 2])])
    wts, rows, m, frac, _ = weights(g2, [1.0, 1.0])
    ke, kp = np.zeros(m), np.zeros(m)
    exact_gains(wts, m, 1.0, ke)
    paper_gains(frac, 1.0, kp)
    golden = (math.sqrt(5) - 1) / 2
    assert m == 1 and abs(ke[0] - golden) < 1e-14 and abs(kp[0] - golden ** 2) < 1e-14
    assert abs(riccati_limit_gain(wts, 1.0)[0] - golden) < 1e-10


@pytest.mark.parametrize("r", [0.0, 0.01, 1.0, 20.0])
def test_paper_law_reproduces_A4_to_A7(r):
    rng = np.random.default_rng(3)
    # 1-D: (A.4) for node i, (A.6) k_{i+1} = k_i(1 - eta)
    g1 = Grid([Axis("u", [0.0, 0.5, 2.0, 2.5])])
    for _ in range(20):
        x = rng.uniform(0, 2.5)
        wts, rows, m, frac, _ = weights(g1, [x])
        i = int(np.searchsorted(g1.axes[0].values, x, side="right") - 1)
        i = min(i, 2)
        eta = (x - g1.axes[0].values[i]) / (g1.axes[0].values[i + 1] - g1.axes[0].values[i])
        want = {i: ki(eta, r), i + 1: ki(1 - eta, r)}
        k = np.zeros(m)
        paper_gains(frac, r, k)
        for row, kk in zip(rows, k):
            assert abs(kk - want[row]) < 1e-13
    # 2-D: (A.7) k_ij = k_i(eta1) k_i(eta2), k_i,j+1 = k_i(eta1) k_i(1-eta2), ...
    ax1, ax2 = np.array([0.0, 1.0, 2.0, 4.0]), np.array([10.0, 11.0, 15.0])
    g2 = Grid([Axis("u1", ax1), Axis("u2", ax2)])
    for _ in range(20):
        p = [rng.uniform(0, 4), rng.uniform(10, 15)]
        i = min(int(np.searchsorted(ax1, p[0], side="right") - 1), 2)
        j = min(int(np.searchsorted(ax2, p[1], side="right") - 1), 1)
        e1 = (p[0] - ax1[i]) / (ax1[i + 1] - ax1[i])
        e2 = (p[1] - ax2[j]) / (ax2[j + 1] - ax2[j])
        want = {(i, j): ki(e1, r) * ki(e2, r), (i, j + 1): ki(e1, r) * ki(1 - e2, r),
                (i + 1, j): ki(1 - e1, r) * ki(e2, r), (i + 1, j + 1): ki(1 - e1, r) * ki(1 - e2, r)}
        wts, rows, m, frac, _ = weights(g2, p)
        k = np.zeros(m)
        assert paper_gains(frac, r, k) == m == 4
        for row, kk in zip(rows, k):
            assert abs(kk - want[tuple(int(v) for v in np.unravel_index(row, g2.shape))]) < 1e-13
        # and the update kernel applies them
        v = np.zeros(g2.size)
        counts = np.zeros(g2.size, dtype=np.int64)
        table_update(v, counts, wts, rows, m, 0.5, LAW_PAPER, r, frac)
        assert np.allclose(v[rows], 0.5 * k, atol=1e-15) and counts.sum() == 4


def test_paper_law_needs_the_fractions():
    wts, rows = np.array([0.5, 0.5]), np.array([0, 1])
    with pytest.raises(ValueError, match="frac"):
        table_update(np.zeros(2), np.zeros(2, np.int64), wts, rows, 2, 1.0, LAW_PAPER, 1.0)
    with pytest.raises(ValueError, match="law"):
        table_update(np.zeros(2), np.zeros(2, np.int64), wts, rows, 2, 1.0, 7, 1.0)


def test_predict_matches_regular_grid_interpolator():
    rng = np.random.default_rng(5)
    grid = random_grid(rng, 3)
    vals = rng.normal(size=grid.shape)
    t = AdaptiveTable(grid, vals)
    pts = np.array([[rng.uniform(a.lo, a.hi) for a in grid.axes] for _ in range(50)])
    ref = RegularGridInterpolator([a.values for a in grid.axes], vals)(pts)
    assert np.max(np.abs(t.predict(pts) - ref)) < 1e-12
    for p, want in zip(pts[:10], ref[:10]):
        wts, rows, m, _, _ = weights(grid, p)
        assert abs(table_predict(vals.reshape(-1), wts, rows, m) - want) < 1e-12
        assert abs(t.predict(p) - want) < 1e-12


# ---- correlated whole-table law ---------------------------------------------------------------
def hat_row(axes, p):
    """Interpolation row over all nodes from 1-D hat functions (np.interp of unit vectors)."""
    c = np.ones(1)
    for a, x in zip(axes, p):
        c = np.kron(c, np.array([np.interp(x, a, e) for e in np.eye(a.size)]))
    return c


def test_correlated_update_matches_numpy_kalman():
    rng = np.random.default_rng(11)
    ax = [np.array([0.0, 1.0, 2.5, 4.0]), np.array([-1.0, 0.0, 3.0])]
    grid = Grid([Axis("a", ax[0]), Axis("b", ax[1])])
    sigma = rng.uniform(0.5, 2.0, grid.shape)
    length, r = 0.4, 0.3
    t = AdaptiveTable(grid, law="correlated", ratio=r, sigma=sigma, length=length)
    # independent Sigma: normalised node coordinates, Euclidean distance
    z = np.array([[(x - ax[0][0]) / (ax[0][-1] - ax[0][0]), (y - ax[1][0]) / (ax[1][-1] - ax[1][0])]
                  for x in ax[0] for y in ax[1]])
    d = np.linalg.norm(z[:, None] - z[None], axis=2)
    s = sigma.reshape(-1)
    Sigma = np.exp(-d / length) * np.outer(s, s)
    R = r * np.mean(s ** 2)
    assert np.allclose(t.Sigma, Sigma, rtol=1e-14, atol=0)
    theta, P = np.zeros(grid.size), Sigma.copy()
    pts = np.column_stack([rng.uniform(0, 4, 60), rng.uniform(-1, 3, 60)])
    refs = np.sin(pts[:, 0]) + 0.3 * pts[:, 1] + rng.normal(0, 0.1, 60)
    pred = t.learn(pts[:30], refs[:30])
    for k in range(30, 60):  # the single-point update path too
        t.update(pts[k], refs[k] - t.predict(pts[k]))
    for k in range(60):
        P = P + Sigma
        c = hat_row(ax, pts[k])
        if k < 30:
            assert abs(pred[k] - c @ theta) < 1e-10
        S = c @ P @ c + R
        K = P @ c / S
        theta = theta + K * (refs[k] - c @ theta)
        P = (np.eye(grid.size) - np.outer(K, c)) @ P
    assert np.max(np.abs(t.values.reshape(-1) - theta)) < 1e-9
    assert np.max(np.abs(t.P - P)) < 1e-9 * np.abs(P).max()
    assert t.n_updates == 60 and t.counts.sum() == 60 * 4


def test_correlated_without_correlation_converges_to_the_exact_gain():
    """rho -> I, sigma = 1, R = r, the same point again and again: the Kalman gain tends to the
    closed-form exact gain (the steady state the exact law precomputes)."""
    grid = Grid([Axis("a", [0, 1, 2]), Axis("b", [0, 1, 2])])
    r = 2.0
    t = AdaptiveTable(grid, law="correlated", ratio=r, sigma=1.0, length=1e-6)
    p = np.array([0.3, 1.6])
    for _ in range(400):
        t.update(p, 0.0)
    _, K = t.gains(p)
    wts, rows, m, _, _ = weights(grid, p)
    k = np.zeros(m)
    exact_gains(wts, m, r, k)
    assert np.max(np.abs(K[rows] - k)) < 1e-10
    assert np.max(np.abs(np.delete(K, rows))) < 1e-12


# ---- state handling -------------------------------------------------------------------------
def test_out_of_range_lock_and_counts():
    grid = Grid([Axis("a", [0, 1, 2]), Axis("b", [0, 1])])
    t = AdaptiveTable(grid, law="exact", ratio=0.0)
    assert t.update([3.0, 0.5], 1.0) == 0.0 and t.n_outside == 1 and not t.values.any()
    assert t.predict([3.0, 0.5]) == t.predict([2.0, 0.5])  # clip policy
    d = t.update([0.5, 0.5], 1.0)  # r = 0: the point is matched exactly
    assert abs(d - 1.0) < 1e-14 and abs(t.predict([0.5, 0.5]) - 1.0) < 1e-14
    assert t.counts.tolist() == [[1, 1], [1, 1], [0, 0]] and t.n_updates == 1
    t.lock()
    before = t.values.copy()
    assert t.update([1.5, 0.2], 5.0) == 0.0
    t.learn([[1.5, 0.2]] * 3, [9.0] * 3)
    assert np.array_equal(t.values, before)
    t.unlock()
    t2 = AdaptiveTable(grid, update_outside=True, ratio=0.0)
    t2.update([-1.0, 0.0], 1.0)
    assert t2.values[0, 0] == 1.0
    te = AdaptiveTable(Grid(grid.axes, policy="error"))
    with pytest.raises(TableError, match="outside"):
        te.predict([0.0, 2.0])
    with pytest.raises(TableError, match="law"):
        AdaptiveTable(grid, law="kalman")
    with pytest.raises(TableError, match="ratio"):
        AdaptiveTable(grid, ratio=-1.0)
    with pytest.raises(TableError, match="shape"):
        AdaptiveTable(grid, values=np.zeros(5))
    # NaN references and points do not learn
    pred = t.learn([[0.5, 0.5], [np.nan, 0.2], [1.5, 0.5]], [np.nan, 1.0, np.nan])
    assert np.isnan(pred[1]) and t.n_updates == 1


def test_point_shapes():
    t1 = AdaptiveTable(Grid([Axis("a", [0.0, 1.0, 2.0])]), [0.0, 1.0, 4.0])
    assert t1.predict(1.5) == t1.predict([1.5]) == 2.5
    assert np.allclose(t1.predict([0.5, 1.5, 2.0]), [0.5, 2.5, 4.0])
    assert np.allclose(t1.predict([[0.5], [1.5]]), [0.5, 2.5])
    assert isinstance(t1.update(1.0, 0.1), float) and t1.update([0.5, 1.5], [0.1, 0.1]).shape == (2,)
    t2 = AdaptiveTable(Grid([Axis("a", [0.0, 1.0]), Axis("b", [0.0, 1.0])]))
    assert isinstance(t2.predict([0.5, 0.5]), float) and t2.predict([[0.5, 0.5]]).shape == (1,)
    with pytest.raises(TableError, match="shape"):
        t2.predict([0.5, 0.5, 0.5])


def test_ratio_varied_from_visit_counts():
    grid = Grid([Axis("a", [0.0, 1.0])])
    t = AdaptiveTable(grid, ratio=4.0, ratio_warmup=10.0)
    g_first = t.gains([0.0])[1][0]
    assert abs(g_first - 2 / (1 + math.sqrt(1 + 4 * 0.4))) < 1e-14  # ratio * (0 + 1) / 10
    t.learn(np.zeros((20, 1)), np.ones(20))
    assert abs(t.gains([0.0])[1][0] - 2 / (1 + math.sqrt(1 + 16))) < 1e-14  # nominal after warm-up


def test_record_roundtrip_and_database_tables(tmp_path, synthetic_db):
    rng = np.random.default_rng(2)
    grid = Grid([Axis("p0", [0, 5, 10], "kg/s"), Axis("p1", [50, 75, 100], "K")], policy="extrapolate")
    for law in ("exact", "paper", "correlated"):
        t = AdaptiveTable(grid, rng.normal(size=grid.shape), law, 0.5, ratio_warmup=3.0, length=0.7)
        t.learn(rng.uniform([0, 50], [10, 100], (15, 2)), rng.normal(size=15))
        u = AdaptiveTable.from_record(*t.to_record())
        assert u.grid == t.grid and u.law == law and u.ratio == 0.5 and u.ratio_warmup == 3.0
        assert np.array_equal(u.values, t.values) and np.array_equal(u.counts, t.counts)
        if law == "correlated":
            assert np.array_equal(u.P, t.P) and np.array_equal(u.Sigma, t.Sigma)
    # into an existing gain database: its own tables and data stay
    path = tmp_path / "db.h5"
    synthetic_db.save(path)
    t.save(path, "bias_Wf")
    db = GainDatabase.open(path)
    assert set(db.tables) == {"bias_T48", "bias_Wf"}
    u = AdaptiveTable.from_record(*db.tables["bias_Wf"])
    assert np.array_equal(u.P, t.P) and u.law == "correlated"
    assert np.array_equal(AdaptiveTable.load(path, "bias_Wf").values, t.values)
    # a database written with the table in memory
    db.tables["again"] = t.to_record()
    db.save(tmp_path / "db2.h5")
    assert np.array_equal(AdaptiveTable.load(tmp_path / "db2.h5", "again").values, t.values)
    # a new tables file, overwrite by name
    t.save(tmp_path / "t.h5", "x")
    t.values[...] = 1.0
    t.save(tmp_path / "t.h5", "x")
    assert np.all(AdaptiveTable.load(tmp_path / "t.h5", "x").values == 1.0)
    # errors name the problem, and a foreign file is not touched
    bad = tmp_path / "notes.txt"
    bad.write_text("hello")
    with pytest.raises(TableError, match="not an HDF5"):
        t.save(bad, "x")
    assert bad.read_text() == "hello" and sorted(p.name for p in tmp_path.iterdir()) == [
        "db.h5", "db2.h5", "notes.txt", "t.h5"]
    with pytest.raises(TableError, match="no table"):
        AdaptiveTable.load(path, "nope")
    with pytest.raises(TableError, match="not an adaptive-table record"):
        AdaptiveTable.load(path, "bias_T48")
    with h5py.File(tmp_path / "t.h5", "a") as f:
        del f["tables/x/axis_1"]
    with pytest.raises(TableError, match="axis_1"):
        AdaptiveTable.load(tmp_path / "t.h5", "x")


# ---- the experiments' claims (small seeded runs) ---------------------------------------------
def test_seed000_reliable_reference_and_bias_step():
    from experiments.tables import seed000_run

    for seed in (0, 1):
        for law in ("exact", "paper"):
            for sr in (0.0, 0.1):
                eq1 = seed000_run(1, law, sr, seed=seed)
                eq2 = seed000_run(2, law, sr, seed=seed)
                assert eq1[0] == eq2[0] == 100.0
                assert eq1[200] < 1.0 and eq2[1000] < 1.0
                eb = seed000_run(2, law, sr, step=0.6, step_at=200, seed=seed)
                assert np.array_equal(eb[:201], eq2[:201])
                assert eb[201] > 20.0 and eb[201] > 5 * eb[200]  # the step shows
                assert eb[1000] < 1.0  # and is recovered


def test_seed000_noise_larger_ratio_lower_steady_error():
    from experiments.tables import seed000_run

    for amp in (0.2, 0.4):
        for law in ("exact", "paper"):
            steady = np.array([[seed000_run(2, law, sr, noise=amp, seed=s)[-300:].mean()
                                for sr in (0.0, 0.1, 1.0)] for s in range(3)])
            assert np.all(np.diff(steady, axis=1) < 0), steady


def test_battery_correlated_beats_local_at_never_excited_temperatures():
    from models import battery
    from experiments.tables import battery_compare

    sim = battery.simulate(n=3000, seed=1)
    r = battery_compare(sim)
    assert r["never"].sum() >= 3  # the cold end is never excited
    assert np.all(r["local"][r["never"]] == sim["table0"][r["never"]])  # local cannot move them
    assert r["rms_corr_never"] < 0.3 * r["rms_local_never"]
    assert r["rms_corr_rare"] < r["rms_local_rare"]


def test_bench_tables_agrees_with_numpy_reference():
    from pwl.bench.tables import bench_tables

    res = bench_tables(n_points=20_000, n_ref=300)
    assert res["max_abs_diff_vs_numpy"] < 1e-12 and res["counts_equal"]
    assert res["numba_updates_per_s_walk"] > 0 and res["speedup_random"] > 0


def test_cli_battery_prints_and_writes(tmp_path, capsys):
    from pwl.cli import main

    assert main(["tables", "battery", "--out", str(tmp_path), "--no-plot", "--n", "1500"]) == 0
    out = capsys.readouterr().out
    assert "never" in out and (tmp_path / "battery.txt").exists()
