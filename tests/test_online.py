"""The online-covariance (full Kalman filter) and zone-gain modes of the runtime: against the numpy
reference, streaming vs batch, and convergence to scipy's DARE solution at a fixed operating point."""
import numpy as np
import pytest

from conftest import make_database
from linearize.kalman import steady_state_gain
from pwl.bench.reference import ReferenceFilter
from pwl.estimator import Estimator
from pwl.runtime import FLAG_PARTIAL
from test_runtime import inputs


def spd(rng, n, scale):
    G = rng.normal(size=(n, n))
    return scale * (G @ G.T / n + 0.5 * np.eye(n))


def assert_equals_reference(res, ref):
    """Every output of ``res`` equals the reference's to 1e-9 (relative to each output's size)."""
    for o, v in ref.items():
        np.testing.assert_allclose(res.outputs[o], v, rtol=1e-9, atol=1e-9 * np.nanmax(np.abs(v), initial=1.0),
                                   err_msg=o)


def online_db(**kw):
    """The synthetic database with different symmetric positive definite Q, R, P at every node."""
    db = make_database(**kw)
    db.schedule = [("p0", False, 1.0), ("y1", True, 2.0)]
    rng = np.random.default_rng(7)
    na, ny = db.n("x") + db.n("q"), db.n("y")
    for idx in np.ndindex(*db.dyn_grid.shape):
        db.kalman["Q"][idx] = spd(rng, na, 1e-4)
        db.kalman["R"][idx] = spd(rng, ny, 1e-3)
        db.kalman["P"][idx] = spd(rng, na, 1e-2)
    return db


@pytest.mark.parametrize("kw", [{}, {"correction": False}, {"trim_shape": (4, 3), "dyn_shape": (3, 2)}])
def test_online_equals_numpy_reference(kw):
    db = online_db(**kw)
    U, Y, S, TH, DE = inputs(db, margin=0.05)
    res = Estimator(db, "online").run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db, online=True).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    # without the health standard deviations: the same estimates, no h_std output
    lean = Estimator(db, "online", health_std=False).run_arrays(U, Y, S, TH, DE)
    assert "h_std" not in lean.outputs
    np.testing.assert_array_equal(lean.q_hat, res.q_hat)
    # and the online gains are not the stored ones: the steady filter gives other estimates
    steady = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.abs(steady.outputs["q_hat"] - res.outputs["q_hat"]).max() > 1e-6


def test_online_streaming_equals_batch_exactly():
    db = online_db()
    est = Estimator(db, "online")
    U, Y, S, TH, DE = inputs(db, n=60)
    Y[10:15, 0] = np.nan
    batch = est.run_arrays(U, Y, S, TH, DE)
    P_batch = est.covariance
    assert np.all(batch.flags[10:15] & FLAG_PARTIAL)   # the reduced update without sensor 0
    est.reset()
    for k in range(60):
        r = est.run_arrays(U[k:k + 1], Y[k:k + 1], S[k:k + 1], TH[k:k + 1], DE[k:k + 1])
        for o in batch.outputs:
            np.testing.assert_array_equal(r.outputs[o][0], batch.outputs[o][k])
    np.testing.assert_array_equal(est.covariance, P_batch)


def test_online_covariance_converges_to_dare_at_a_fixed_point():
    """At a constant operating point the matrices are constant, so the Riccati recursion of the
    online filter must reach scipy's DARE solution (a posteriori form P - K C P) at the matrices
    RegularGridInterpolator gives there; its gain then equals the steady-state gain."""
    db = online_db(correction=False)
    n = 3000
    p = np.array([3.7, 81.0])                       # inside the grid, off every node
    S = np.tile([p[0], p[1] / 2.0], (n, 1))          # schedule channel 2 has scale 2
    U = np.ones((n, db.n("u")))
    Y = 1.0 + 0.01 * np.random.default_rng(3).normal(size=(n, db.n("y")))
    est = Estimator(db, "online", misfit_sigmas=np.inf)   # Y is arbitrary: use every sensor
    est.run_arrays(U, Y, S)
    ref = ReferenceFilter(db)
    A, C, Q, R = (ref.mats[k](p)[0] for k in ("A", "C", "Q", "R"))
    K, P = steady_state_gain(A, C, Q, R)
    P_post = P - K @ C @ P
    np.testing.assert_allclose(est.covariance, P_post, rtol=1e-8, atol=1e-10 * np.abs(P_post).max())


@pytest.mark.parametrize("m", [1, 3])
def test_covariance_kernels_against_numpy(m):
    from pwl.covariance import correct, propagate_augmented

    rng = np.random.default_rng(m)
    n = 5
    P, Q, R = spd(rng, n, 1.0), spd(rng, n, 0.1), spd(rng, m, 0.5)
    A, C = rng.normal(size=(n, n)), rng.normal(size=(m, n))
    K_np = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    Pp_np = (np.eye(n) - K_np @ C) @ P
    Pk, K = P.copy(), np.empty((n, m))
    assert correct(Pk, C, R, np.empty((n, m)), np.empty((m, m)), np.empty((m, m)), K)
    np.testing.assert_allclose(K, K_np, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Pk, Pp_np, rtol=1e-11, atol=1e-13)
    # the time update of the augmented form [[A_top], [0 I]] (2 state rows, 3 random-walk tuners)
    Aa = np.vstack([A[:2], np.hstack([np.zeros((3, 2)), np.eye(3)])])
    Pa = P.copy()
    propagate_augmented(np.ascontiguousarray(A[:2]), Pa, Q, np.empty((2, n)))
    np.testing.assert_allclose(Pa, Aa @ P @ Aa.T + Q, rtol=1e-12, atol=1e-13)
    np.testing.assert_array_equal(Pa, Pa.T)
    # not positive definite: refused, nothing changed
    Pk2 = Pk.copy()
    assert not correct(Pk2, C, -10.0 * np.eye(m) - C @ Pk @ C.T, np.empty((n, m)), np.empty((m, m)),
                       np.empty((m, m)), K)
    np.testing.assert_array_equal(Pk2, Pk)


def test_one_mode_of_four():
    for bad in ("online+untuned", "Steady", ""):
        with pytest.raises(ValueError, match="mode .*one of steady, untuned, online, zones"):
            Estimator(online_db(), bad)


def test_pwl_run_online_writes_the_online_estimates(tmp_path):
    """``pwl run --online`` (chunked file processing) equals the in-memory online run."""
    import h5py

    from pwl.cli import main
    from pwl.logs import write_log
    from test_runtime import full_log

    db = online_db()
    db.save(tmp_path / "db.h5")
    write_log(tmp_path / "f0.h5", full_log(db, n=300))
    assert main(["run", str(tmp_path / "db.h5"), str(tmp_path / "f0.h5"), "-o", str(tmp_path / "out"),
                 "-j", "1", "--online", "--min-updated", "0"]) == 0   # random sensors: not trusted
    want = Estimator(tmp_path / "db.h5", "online").run(tmp_path / "f0.h5")
    steady = Estimator(tmp_path / "db.h5").run(tmp_path / "f0.h5")
    with h5py.File(tmp_path / "out" / "f0.estimates.h5") as f:
        np.testing.assert_array_equal(f["q_hat"][()], want.q_hat)
        assert np.abs(f["q_hat"][()] - steady.q_hat).max() > 1e-6
    # options the database cannot serve fail before any log is run, with the reason
    assert main(["run", str(tmp_path / "db.h5"), str(tmp_path / "f0.h5"), "-o", str(tmp_path / "o2"),
                 "--zones"]) == 2
    assert not (tmp_path / "o2").exists()


@pytest.mark.parametrize("kw", [{}, {"correction": False}])
def test_zone_gains_picked_per_step_equal_reference(kw):
    """Estimator(db, "zones") picks the centroid gain of the nearest dynamics node's zone."""
    from linearize.zones import database_zones
    from pwl.zones import ZoneTable

    db = online_db(dyn_shape=(4, 5), spread=0.1, **kw)    # zone gains that stabilize every node
    db.zones, _ = database_zones(db, k=3, seed=0)
    zt = ZoneTable.from_record(db.zones)
    assert len(set(zt.flat_labels)) == 3
    U, Y, S, TH, DE = inputs(db, margin=0.05)
    res = Estimator(db, "zones").run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db, zones=zt).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    interp = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.abs(interp.q_hat - res.q_hat).max() > 1e-6
    db.zones = None
    with pytest.raises(ValueError, match="no zones record"):
        Estimator(db, "zones")
