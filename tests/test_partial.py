"""Partial measurements (#15): the builder's sensor-out gains, the runtime's update from the
present sensors (steady: one sensor out with its stored gain; online: the reduced update of any
subset), against independent references: the iterated Riccati recursion, the numpy reference
filter, and the simulation's truth on the demo flight with a dead T48."""
import numpy as np
import pytest

from conftest import make_database
from linearize.build import with_sensor_out_gains
from pwl.database import OUT_NONE, DatabaseError, GainDatabase, UnstableGainError
from pwl.estimator import Estimator
from pwl.reference import ReferenceFilter
from pwl.runtime import FLAG_NO_UPDATE, FLAG_PARTIAL, augment
from test_online import assert_equals_reference, online_db
from test_runtime import inputs, names_db


def riccati_iterated(A, C, Q, R, steps=20000):
    """Steady-state update gain by iterating the Riccati recursion from P = Q (independent of
    scipy's DARE solver)."""
    P = Q.copy()
    for _ in range(steps):
        S = C @ P @ C.T + R
        K = P @ C.T @ np.linalg.inv(S)
        P_new = A @ (P - K @ C @ P) @ A.T + Q
        if np.abs(P_new - P).max() <= 1e-15 * np.abs(P).max():
            break
        P = P_new
    return P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


def test_sensor_out_gains_equal_the_iterated_riccati_recursion():
    db = with_sensor_out_gains(make_database(ny=4), log=lambda *a: None)
    ny = db.n("y")
    aug = augment(db.dynamics, db.tuner["V_pinv"])
    for j in range(ny):
        keep = np.arange(ny) != j
        for idx in np.ndindex(*db.dyn_grid.shape):
            if db.kalman["out_status"][(j,) + idx] == OUT_NONE:
                continue
            K = riccati_iterated(aug["A"][idx], aug["C"][idx][keep], db.kalman["Q"][idx],
                                 db.kalman["R"][idx][np.ix_(keep, keep)])
            Kj = db.kalman["K_out"][(j,) + idx]
            np.testing.assert_allclose(Kj[:, keep], K, rtol=1e-6, atol=1e-9 * np.abs(K).max())
            assert np.all(Kj[:, j] == 0.0)


def test_sensor_out_gains_round_trip_and_are_checked(tmp_path):
    db = with_sensor_out_gains(make_database(), log=lambda *a: None)
    p = tmp_path / "db.h5"
    db.save(p)
    back = GainDatabase.open(p)
    np.testing.assert_array_equal(back.kalman["K_out"], db.kalman["K_out"])
    np.testing.assert_array_equal(back.kalman["out_status"], db.kalman["out_status"])
    bad = with_sensor_out_gains(make_database(), log=lambda *a: None)
    bad.kalman["K_out"][1][..., 1] = 0.5                   # the gain without y1 uses y1
    with pytest.raises(DatabaseError, match=r"K_out\[1\] \(without y1\) uses y1"):
        bad.save(tmp_path / "bad.h5")
    bad = with_sensor_out_gains(make_database(), log=lambda *a: None)
    bad.kalman["K_out"][0][0, 1, :, 1:] *= -80.0          # unstable at one node
    with pytest.raises(UnstableGainError, match=r"K_out\[0\] \(without y0\)"):
        bad.save(tmp_path / "bad.h5")


@pytest.mark.parametrize("kw", [{}, {"correction": False}, {"trim_shape": (4, 3), "dyn_shape": (3, 2)}])
def test_steady_partial_update_equals_reference(kw):
    db = with_sensor_out_gains(names_db(**kw), log=lambda *a: None)
    U, Y, S, TH, DE = inputs(db, n=200)
    Y[20:60, 0] = np.nan            # one sensor out: its sensor-out gain
    Y[80:90, 2] = np.inf
    Y[100:110, [0, 2]] = np.nan     # two out: no update
    res = Estimator(db).run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    assert np.all(res.flags[20:60] & FLAG_PARTIAL) and not np.any(res.flags[20:60] & FLAG_NO_UPDATE)
    assert np.all(res.flags[80:90] & FLAG_PARTIAL)
    assert np.all(res.flags[100:110] & FLAG_NO_UPDATE) and not np.any(res.flags[100:110] & FLAG_PARTIAL)
    assert not np.any(res.flags[:20] & (FLAG_PARTIAL | FLAG_NO_UPDATE))
    # the tuners move during the partial updates (a skipped update would hold them)
    assert np.abs(np.diff(res.q_hat[20:60], axis=0)).max() > 0


def test_without_sensor_out_gains_a_missing_sensor_skips_the_update():
    db = names_db()                 # built before sensor-out gains: the old behaviour
    U, Y, S, TH, DE = inputs(db, n=60)
    Y[20:30, 0] = np.nan
    res = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.all(res.flags[20:30] & FLAG_NO_UPDATE) and not np.any(res.flags & FLAG_PARTIAL)
    assert_equals_reference(res, ReferenceFilter(db).run(U, Y, S, TH, DE))


def test_online_reduced_update_equals_reference():
    db = online_db()
    U, Y, S, TH, DE = inputs(db, n=150)
    Y[20:40, 0] = np.nan            # any subset: one out, two out
    Y[60:70, [0, 2]] = np.nan
    res = Estimator(db, online=True).run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db, online=True).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    assert np.all(res.flags[20:40] & FLAG_PARTIAL) and np.all(res.flags[60:70] & FLAG_PARTIAL)
    assert not np.any(res.flags & FLAG_NO_UPDATE)


def test_dead_t48_from_takeoff_keeps_fn_error_within_1_5x_of_all_sensors():
    """The demo flight of the degraded engine with T48 dead from the start: the Fn error against
    the simulation's truth stays within 1.5x of the all-sensor run (open-loop, as before the
    sensor-out gains, it was 18x)."""
    from pwl.bench import demo_paths
    from pwl.logs import Log, read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    dead = Log(log.time, dict(log.channels, T48=np.full(len(log), np.nan)), log.units,
               attrs=log.attrs, path=log.path)
    est = Estimator(db_path)
    assert "K_out" in est.db.kalman
    settled = log.time >= log.time[0] + 120.0

    def fn_rms(r):
        e = (r.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return np.sqrt(np.mean(e[settled] ** 2))
    full, part = est.run(log), est.run(dead)
    assert np.all(part.flags & FLAG_PARTIAL)
    assert fn_rms(part) <= 1.5 * fn_rms(full)


def test_points_without_a_sensor_out_gain_skip_the_update_around_them():
    """A point where the tuners are undetectable without sensor j has no gain without it
    (out_status 2): between such a node and the others the update is skipped, elsewhere it goes
    on; the reference filter does the same."""
    db = with_sensor_out_gains(names_db(dyn_shape=(2, 3)), log=lambda *a: None)
    db.kalman["K_out"][0][1, 2] = 0.0
    db.kalman["out_status"][0][1, 2] = OUT_NONE
    U, Y, S, TH, DE = inputs(db, n=300)
    Y[:, 0] = np.nan
    res = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert_equals_reference(res, ReferenceFilter(db).run(U, Y, S, TH, DE))
    p = db.operating_point(S, TH, DE)
    dg = db.dyn_grid
    near = np.ones(len(p), bool)   # inside the last cell of both axes: a corner is node (1, 2)
    for j, a in enumerate(dg.axes):
        near &= p[:, db.names["p"].index(a.name)] > a.values[-2]
    assert near.any() and (~near).any()
    assert np.all(res.flags[near] & FLAG_NO_UPDATE)
    assert np.all(res.flags[~near] & FLAG_PARTIAL)
