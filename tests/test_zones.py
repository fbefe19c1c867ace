"""k-means gain zones, the scheduled-gain EKF (SEKF) and the full EKF (issue 8, seed paper 001).

References are independent of the code under test: a plain numpy EKF/SEKF written here, scipy's
``solve_discrete_are`` and ``kmeans2``, brute-force nearest node / nearest sample / nearest
centre searches, the analytic Jacobians of the chen2020 model.
"""
import json

import numpy as np
import pytest
from numba import njit
from scipy.cluster.vq import kmeans2
from scipy.linalg import solve_discrete_are

from experiments.ekf import run_ekf, run_sekf
from linearize import zones as Z
from models.chen2020 import Chen2020, PlantFunctions, f as chen_f, jac_f as chen_jac_f
from pwl.database import GainDatabase
from pwl.zones import ZoneError, ZoneTable, load_zones, save_zones

from conftest import make_database


@pytest.fixture(scope="module")
def plant():
    return Chen2020()


@pytest.fixture(scope="module")
def build(plant):
    return Z.build_zones(plant, k=3, N=800, seed=3, lookup_shape=(7, 41, 9))


def simulate(plant, T, seed):
    rng = np.random.default_rng(seed)
    U = plant.input_signal(T, rng)
    X, Y = plant.simulate(U, rng)
    xh0 = plant.x0 + rng.multivariate_normal(np.zeros(2), plant.P0)
    return U, X, Y, xh0


# ---- independent references ---------------------------------------------------------------------
def numpy_ekf(plant, U, Y, x0, P0, Q, R, h=None, jac_h=None):
    """Textbook EKF of the paper, eqs. (5)-(9), in plain numpy."""
    h = h or (lambda x: x[:1])
    jac_h = jac_h or (lambda x: np.array([[1.0, 0.0]]))
    x, P = x0.astype(float).copy(), P0.astype(float).copy()
    X, Pd = [], []
    for k in range(len(U)):
        y = Y[k]
        if np.all(np.isfinite(y)):
            C = jac_h(x)
            K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
            x = x + K @ (y - h(x))
            P = P - K @ (P @ C.T).T
        X.append(x.copy())
        Pd.append(np.diag(P).copy())
        A, _ = plant.linearize(x, U[k])
        x, _, _ = plant.evaluate(x, U[k])
        P = A @ P @ A.T + Q
    return np.array(X), np.array(Pd)


def brute_nearest_node_labels(table, points):
    """Label of the nearest lookup node by exhaustive search in box-normalised coordinates."""
    g = table.grid
    nodes = g.nodes()
    lo, hi = nodes.min(0), nodes.max(0)
    pts = np.clip(points, lo, hi)
    d = (((pts[:, None, :] - nodes[None, :, :]) / (hi - lo)) ** 2).sum(-1)
    return table.flat_labels[d.argmin(1)]


# ---- the EKF kernel -------------------------------------------------------------------------------
def test_ekf_matches_numpy_reference(plant):
    U, X, Y, xh0 = simulate(plant, 600, 1)
    Y = Y.copy()
    Y[[50, 51, 300]] = np.nan                     # no correction on these steps
    Xk, Pd, bad = run_ekf(plant.functions, plant.p, U, Y, xh0, plant.P0, plant.Q, plant.R,
                          return_pdiag=True)
    Xr, Pr = numpy_ekf(plant, U, Y, xh0, plant.P0, plant.Q, plant.R)
    assert bad == 0
    np.testing.assert_allclose(Xk, Xr, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pd, Pr, rtol=1e-10, atol=1e-12)
    # the covariance converges to the steady-state (a-posteriori) covariance of the final point
    assert np.all(Pd[-1] < 1.5) and np.all(Pd[-1] > 0)


@njit(cache=False)
def _h2(x, u, p, out):
    out[0] = x[0]
    out[1] = x[0] + 0.5 * x[1] * x[1] / 10.0


@njit(cache=False)
def _jh2(x, u, p, out):
    out[0, 0] = 1.0
    out[0, 1] = 0.0
    out[1, 0] = 1.0
    out[1, 1] = 0.1 * x[1]


def test_ekf_two_outputs_cholesky_path(plant):
    """m = 2 goes through the in-place Cholesky solve; compare with numpy's inverse."""
    U, X, Y1, xh0 = simulate(plant, 300, 2)
    rng = np.random.default_rng(7)
    Y = np.column_stack([X[:-1, 0], X[:-1, 0] + 0.05 * X[:-1, 1] ** 2]) + 0.1 * rng.normal(size=(300, 2))
    R = np.array([[0.01, 0.002], [0.002, 0.02]])
    fns = PlantFunctions(chen_f, chen_jac_f, _h2, _jh2)
    Xk, Pd, bad = run_ekf(fns, plant.p, U, Y, xh0, plant.P0, plant.Q, R, return_pdiag=True)
    Xr, Pr = numpy_ekf(plant, U, Y, xh0, plant.P0, plant.Q, R,
                       h=lambda x: np.array([x[0], x[0] + 0.05 * x[1] ** 2]),
                       jac_h=lambda x: np.array([[1.0, 0.0], [1.0, 0.1 * x[1]]]))
    assert bad == 0
    # exact until x1 crosses the locally unstable band |x1| < 6.45 (steps 260-300), which amplifies
    # the rounding difference of the two solves (Cholesky vs inverse) by up to 5 % per step
    np.testing.assert_allclose(Xk[:200], Xr[:200], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pd[:200], Pr[:200], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Xk, Xr, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(Pd, Pr, rtol=1e-6, atol=1e-9)


# ---- the SEKF kernel --------------------------------------------------------------------------------
def test_sekf_matches_numpy_reference(plant, build):
    table = build.table
    U, X, Y, xh0 = simulate(plant, 400, 4)
    Y = Y.copy()
    Y[10] = np.nan
    Xk, zk, outside = run_sekf(plant.functions, plant.p, table, U, Y, xh0, return_zones=True)
    Xs, zs, _ = run_sekf(plant.functions, plant.p, table, U, Y, xh0, return_zones=True,
                         force_search=True)
    x = xh0.copy()
    Xr, zr = [], []
    for k in range(len(U)):
        if np.isfinite(Y[k, 0]):
            z = int(brute_nearest_node_labels(table, np.r_[U[k], x][None])[0])
            x = x + table.gains[z] @ (Y[k] - x[:1])
        else:
            z = -1
        Xr.append(x.copy())
        zr.append(z)
        x, _, _ = plant.evaluate(x, U[k])
    np.testing.assert_allclose(Xk, np.array(Xr), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(zk, zr)
    np.testing.assert_array_equal(zs, zr)          # search path == arithmetic path
    np.testing.assert_allclose(Xs, Xk, rtol=0, atol=0)
    assert zk[10] == -1 and outside == 0
    assert len(set(zk[zk >= 0].tolist())) >= 2     # the run crosses zones


def test_sekf_lookup_on_a_subset_of_coordinates(plant, build):
    """coords: a 1-D lookup over x1 only (index 1 of (u, x1, x2)) vs the numpy reference."""
    from experiments.ekf import lookup_coords
    from pwl.grid import Axis, Grid

    x1 = np.linspace(-20, 20, 81)
    lab = build.table.zone_of(np.column_stack([np.full(81, 0.5), x1, np.zeros(81)]))
    t1 = ZoneTable(gains=build.table.gains, grid=Grid([Axis("x1", x1)]), labels=lab,
                   centers=build.table.centers, scale=build.table.scale, counts=build.table.counts)
    co = lookup_coords(t1, plant.u_names + plant.x_names)
    assert co.tolist() == [1]
    with pytest.raises(ZoneError, match="not among"):
        lookup_coords(t1, ("u", "x2"))
    with pytest.raises(ValueError, match="give coords"):
        run_sekf(plant.functions, plant.p, t1, np.zeros((3, 1)), np.zeros((3, 1)), plant.x0)
    U, X, Y, xh0 = simulate(plant, 300, 6)
    Xk, zk, _ = run_sekf(plant.functions, plant.p, t1, U, Y, xh0, return_zones=True, coords=co)
    x, Xr = xh0.copy(), []
    for k in range(len(U)):
        z = lab[np.abs(x1 - np.clip(x[0], -20, 20)).argmin()]
        assert zk[k] == z
        x = x + t1.gains[z] @ (Y[k] - x[:1])
        Xr.append(x.copy())
        x, _, _ = plant.evaluate(x, U[k])
    np.testing.assert_allclose(Xk, np.array(Xr), rtol=1e-12, atol=1e-12)


# ---- zones: gains, k-means, lookup --------------------------------------------------------------
def test_zone_gains_are_mean_steady_state_gains(plant, build):
    """Each centroid gain = mean of scipy-DARE gains at its member operating points."""
    s, table = build.samples, build.table
    assert s.failed == 0 and s.points.shape == (800, 3)
    rng = np.random.default_rng(0)
    check = rng.choice(len(s.points), 100, replace=False)
    for i in check:                                 # per-point gains vs scipy directly
        u, x = s.points[i, :1], s.points[i, 1:]
        A, C = plant.linearize(x, u)
        P = solve_discrete_are(A.T, C.T, plant.Q, plant.R)
        K = P @ C.T / (C @ P @ C.T + plant.R)
        np.testing.assert_allclose(s.gains[i], K, rtol=1e-9, atol=1e-12)
    for j in range(table.k):
        np.testing.assert_allclose(table.gains[j], s.gains[build.labels == j].mean(0), rtol=1e-12)
    np.testing.assert_array_equal(table.counts, np.bincount(build.labels, minlength=3))
    # paper: clusters in (u, x) space are bands of |x1| (the gain depends on x1 only for m = 1)
    x1 = np.abs(s.points[:, 1])
    spans = sorted((x1[build.labels == j].min(), x1[build.labels == j].max()) for j in range(3))
    assert all(spans[i][1] <= spans[i + 1][0] + 1e-9 for i in range(2))


def test_kmeans_is_a_lloyd_fixed_point_and_beats_scipy(build):
    s, table = build.samples, build.table
    G = s.gains.reshape(len(s.gains), -1) / table.scale
    np.testing.assert_allclose(table.scale, s.gains.reshape(len(s.gains), -1).std(0), rtol=1e-12)
    c2, l2 = kmeans2(G, table.centers.copy(), iter=50, minit="matrix")
    np.testing.assert_allclose(c2, table.centers, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(l2, build.labels)
    # brute force: every point is in the cluster of its nearest centre
    d = ((G[:, None, :] - table.centers[None]) ** 2).sum(-1)
    np.testing.assert_array_equal(d.argmin(1), build.labels)
    best = min(((G - c[l]) ** 2).sum(1).mean()
               for c, l in (kmeans2(G, 3, minit="++", rng=np.random.default_rng(i)) for i in range(5)))
    assert build.distortion <= best * (1 + 1e-9)
    # deterministic for a seed
    c3, l3, _ = Z.kmeans(G, 3, seed=0)
    c4, l4, _ = Z.kmeans(G, 3, seed=0)
    np.testing.assert_array_equal(c3, c4)
    np.testing.assert_array_equal(l3, l4)


def test_lookup_vs_bruteforce(plant, build):
    table, s = build.table, build.samples
    rng = np.random.default_rng(5)
    pts = s.lo + (s.hi - s.lo) * rng.uniform(-0.05, 1.05, (400, 3))   # some outside: clipped
    ref = brute_nearest_node_labels(table, pts)
    np.testing.assert_array_equal(table.zone_of(pts), ref)
    # search path (pwl.grid.locate) on the same grid
    from pwl.zones import zone_many
    out = np.empty(len(pts), np.int64)
    n_out = zone_many(*table.kernel_args(force_search=True), np.ascontiguousarray(pts), out)
    np.testing.assert_array_equal(out, ref)
    inside = np.all((pts >= s.lo) & (pts <= s.hi), axis=1)
    assert n_out == int((~inside).sum())
    # node labels (label="nearest") = label of the nearest sample, by exhaustive search
    nodes = table.grid.nodes()
    sub = rng.choice(len(nodes), 300, replace=False)
    w = s.hi - s.lo
    d = ((((nodes[sub, None, :] - s.points[None]) / w)) ** 2).sum(-1)
    np.testing.assert_array_equal(table.flat_labels[sub], build.labels[d.argmin(1)])


def test_gain_labelled_lookup(plant, build):
    """label='gain': every node's zone is the nearest centre to the DARE gain at that node."""
    gb = Z.make_zones(build.samples, k=3, seed=3, lookup_shape=(3, 21, 3), label="gain", plant=plant)
    np.testing.assert_allclose(gb.table.gains, build.table.gains)     # same clustering
    nodes = gb.table.grid.nodes()
    for r in range(0, len(nodes), 5):
        A, C = plant.linearize(nodes[r, 1:], nodes[r, :1])
        P = solve_discrete_are(A.T, C.T, plant.Q, plant.R)
        K = (P @ C.T / (C @ P @ C.T + plant.R)).ravel() / gb.table.scale
        assert gb.table.flat_labels[r] == ((gb.table.centers - K) ** 2).sum(1).argmin()
    # the nearest-sample labels agree with the exact ones on most nodes
    near = Z.nearest_sample_labels(build.samples, build.labels, nodes)
    assert (near == gb.table.flat_labels).mean() > 0.8


class _NoJacobian:
    """chen2020 without its analytic linearize: the builder must use finite differences."""

    def __init__(self, p):
        self._p = p
        for a in ("name", "x_names", "u_names", "y_names", "time", "units", "Q", "R",
                  "box_lo", "box_hi", "evaluate"):
            setattr(self, a, getattr(p, a))


class _BlindBand(_NoJacobian):
    """C = 0 for |x1| < 4 where the x1 dynamics are unstable: no stabilising gain there."""

    def linearize(self, x, u):
        A, C = self._p.linearize(x, u)
        return A, (0.0 * C if abs(x[0]) < 4 else C)


def test_finite_difference_jacobians_and_failures(plant):
    rng = np.random.default_rng(2)
    fd = _NoJacobian(plant)
    for _ in range(20):
        x, u = rng.uniform([-20, -40], [20, 40]), rng.uniform(0, 1, 1)
        A, C = Z.jacobians(fd, x, u)
        Aa, Ca = plant.linearize(x, u)
        np.testing.assert_allclose(A, Aa, rtol=1e-7, atol=1e-8)
        np.testing.assert_allclose(C, Ca, rtol=1e-7, atol=1e-8)
    s = Z.sample_gains(_BlindBand(plant), N=300, seed=4)
    pts = plant.box_lo + (plant.box_hi - plant.box_lo) * np.random.default_rng(4).random((300, 3))
    expected = int((np.abs(pts[:, 1]) < 4).sum())
    assert s.failed == expected > 0
    assert s.points.shape[0] == 300 - expected and np.all(np.abs(s.points[:, 1]) >= 4)
    assert "not stable" in s.failures[0][1] or "DARE" in s.failures[0][1]
    zb = Z.make_zones(s, k=2, seed=0, lookup_shape=5)
    assert zb.table.attrs["failed"] == expected and zb.table.attrs["N"] == 300


# ---- storage ----------------------------------------------------------------------------------------
def test_zones_record_roundtrip_through_database(tmp_path, build):
    db = make_database()
    Z.attach(db, build.table)
    db.save(tmp_path / "db.h5")
    back = GainDatabase.open(tmp_path / "db.h5")
    t2 = ZoneTable.from_record(back.zones)
    for a in ("gains", "centers", "scale", "counts", "labels"):
        np.testing.assert_array_equal(getattr(t2, a), getattr(build.table, a))
    assert t2.grid == build.table.grid and t2.attrs["N"] == 800 and t2.k == 3
    pts = np.random.default_rng(0).uniform(build.samples.lo, build.samples.hi, (50, 3))
    np.testing.assert_array_equal(t2.zone_of(pts), build.table.zone_of(pts))
    save_zones(tmp_path / "z.h5", build.table)
    np.testing.assert_array_equal(load_zones(tmp_path / "z.h5").gains, build.table.gains)
    np.testing.assert_array_equal(load_zones(tmp_path / "db.h5").labels, build.table.labels)
    # the placeholder record of the synthetic database is not a zones record: named error
    with pytest.raises(ZoneError, match="not a pwl-zones record"):
        ZoneTable.from_record(make_database().zones)
    arrays, attrs = build.table.record()
    with pytest.raises(ZoneError, match="labels outside"):
        ZoneTable.from_record(({**arrays, "lookup_labels": arrays["lookup_labels"] + 5}, attrs))
    with pytest.raises(ZoneError, match="missing"):
        ZoneTable.from_record(({k: v for k, v in arrays.items() if k != "gains"}, attrs))


def test_database_zones(tmp_path):
    db = make_database(dyn_shape=(4, 5), spread=0.1)
    K0 = db.kalman["K"].copy()
    record, zoned = Z.database_zones(db, k=3, seed=1)
    np.testing.assert_array_equal(db.kalman["K"], K0)            # the original is untouched
    t = ZoneTable.from_record(record)
    G = K0.reshape(20, -1)
    np.testing.assert_allclose(t.scale, G.std(0), rtol=1e-12)
    lab = t.flat_labels
    # brute force: each node's zone is the nearest centre; centres are the member means
    d = (((G / t.scale)[:, None, :] - t.centers[None]) ** 2).sum(-1)
    np.testing.assert_array_equal(d.argmin(1), lab)
    for j in range(3):
        np.testing.assert_allclose(t.gains[j].ravel(), G[lab == j].mean(0), rtol=1e-12)
    Kz = zoned.kalman["K"].reshape(20, -1)
    np.testing.assert_allclose(Kz, t.gains.reshape(3, -1)[lab], rtol=0, atol=0)
    rel = np.linalg.norm(G - Kz, axis=1) / np.linalg.norm(G, axis=1)
    assert t.attrs["gain_rel_error_max"] == pytest.approx(rel.max())
    assert t.attrs["K_bytes"] == K0.nbytes and t.attrs["record_bytes"] == t.nbytes()
    # lookup on the dynamics grid: nodes map to their own labels (search path, non-uniform axes)
    assert not t.kernel_args()[0]
    np.testing.assert_array_equal(t.zone_of(db.dyn_grid.nodes()), lab)
    zoned.save(tmp_path / "zoned.h5")
    with pytest.raises(Z.GainError, match="k = 2 zone gains are not stabilizing.*use more zones"):
        Z.database_zones(make_database(dyn_shape=(4, 5)), k=2, seed=1)   # gains too far apart
    back = GainDatabase.open(tmp_path / "zoned.h5")
    np.testing.assert_array_equal(back.kalman["K"], zoned.kalman["K"])
    np.testing.assert_array_equal(ZoneTable.from_record(back.zones).labels, t.labels)
    with pytest.raises(ValueError, match="exceeds"):
        Z.database_zones(db, k=21)


# ---- the acceptance figure, small -------------------------------------------------------------------
def test_monte_carlo_sekf_close_to_ekf(plant, build):
    """k = 3: SEKF RMSE of x2 within 20 % of the EKF's, mean error within 2 standard errors.
    (Small: N = 800, 12 runs of 30 s; `pwl zones` produces the full figures.) A SEKF with the
    wrong gains (x2 row zeroed) must fail the same criterion, so the test can fail."""
    zb = build
    wrong = ZoneTable(**{**zb.table.__dict__, "gains": zb.table.gains * np.array([1.0, 0.0])[:, None]})
    rs, re, rw, ms = [], [], [], []
    for run in range(12):
        U, X, Y, xh0 = simulate(plant, 3000, 100 + run)
        Xs, _ = run_sekf(plant.functions, plant.p, zb.table, U, Y, xh0)
        Xe, _ = run_ekf(plant.functions, plant.p, U, Y, xh0, plant.P0, plant.Q, plant.R)
        Xw, _ = run_sekf(plant.functions, plant.p, wrong, U, Y, xh0)
        es, ee, ew = (Xq[:, 1] - X[:-1, 1] for Xq in (Xs, Xe, Xw))
        rs.append(np.sqrt(np.mean(es ** 2)))
        re.append(np.sqrt(np.mean(ee ** 2)))
        rw.append(np.sqrt(np.mean(ew ** 2)))
        ms.append(es.mean())
    ratio = np.mean(rs) / np.mean(re)
    assert ratio < 1.2, ratio
    assert np.mean(rw) / np.mean(re) > 1.2
    se = np.std(ms, ddof=1) / np.sqrt(len(ms))
    assert abs(np.mean(ms)) < 2 * se + 1e-12, (np.mean(ms), se)


def test_compare_database_zone_vs_interpolated(tmp_path):
    """The turbofan comparison's code path on the synthetic database: with the interpolated
    estimator's own outputs as truth, the interpolated error is 0 and the zone one is not."""
    from experiments.zones import compare_database
    from pwl.estimator import Estimator
    from pwl.logs import Log, write_log

    db = make_database(dyn_shape=(4, 5), correction=False, spread=0.1)
    db.schedule = [("p0", False, 1.0), ("p1", False, 1.0)]
    db.save(tmp_path / "db.h5")
    est = Estimator(db)
    n = 400
    t = np.arange(n) * db.dt
    rng = np.random.default_rng(0)
    ch = {c: 1.5 + 0.1 * rng.normal(size=n) for c in est.input_channels}
    ch.update(p0=np.linspace(1, 9, n), p1=np.linspace(52, 98, n))
    log = Log(t, ch, {c: est.channel_units.get(c, "") for c in ch})
    # sensors the model explains, within noise (random ones would fail for the log: left out)
    y_hat = est.run(log).outputs["y_hat"]
    log.channels.update({y: y_hat[:, j] * (1 + 0.002 * rng.normal(size=n)) for j, y in enumerate(db.names["y"])})
    r = est.run(log)
    assert json.loads(r.attrs["provenance"]["failed_channels"]) == []
    log.truth = {z: r.channel("z_hat", z) for z in db.names["z"]}
    log.truth.update({h: np.zeros(n) for h in db.names["h"]})
    write_log(tmp_path / "log.h5", log)
    res = compare_database(tmp_path / "db.h5", [tmp_path / "log.h5"], k=2, settle=0.0,
                           out=tmp_path / "zoned.h5")
    assert [row[1] for row in res["rows"]] == db.names["z"]
    for _, _, e in res["rows"]:
        assert e["interp"][0] == pytest.approx(0.0, abs=1e-9) and e["zones"][0] > 1e-6
        assert e["online"][0] > 1e-6 and np.isfinite(e["zones"][0]) and np.isfinite(e["online"][0])
    assert set(res["speed"]["steps_per_s"]) == {"interp", "zones", "online"}
    assert res["traces"]["channel"] == db.names["z"][0]
    np.testing.assert_allclose(res["traces"]["errors"]["interp"], 0.0, atol=1e-9)
    assert res["sizes"]["record_bytes"] == ZoneTable.from_record(res["record"]).nbytes()
    assert GainDatabase.open(tmp_path / "zoned.h5").zones is not None
    assert "zones RMS" in res["text"] and len(res["health"]) == 1
