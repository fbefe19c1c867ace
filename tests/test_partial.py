"""Partial measurements (#15): the builder's sensor-out gains, the runtime's update from the
present sensors (steady: one sensor out with its stored gain; online: the reduced update of any
subset), against independent references: the iterated Riccati recursion, the numpy reference
filter, and the simulation's truth on the demo flight with a dead T48."""
import numpy as np
import pytest

from conftest import make_database
from linearize.build import with_sensor_out_gains
from pwl.bench.reference import ReferenceFilter
from pwl.database import OUT_NONE, DatabaseError, GainDatabase, UnstableGainError
from pwl.estimator import Estimator
from pwl.runtime import FLAG_HEALTH_HELD, FLAG_NO_UPDATE, FLAG_PARTIAL, augment
from test_online import assert_equals_reference, online_db
from test_runtime import inputs, names_db


def riccati_iterated(A, C, Q, R, steps=20000, covariance=False):
    """Steady-state update gain (and with ``covariance`` the a-priori P) by iterating the Riccati
    recursion from P = Q (independent of scipy's DARE solver)."""
    P = Q.copy()
    for _ in range(steps):
        S = C @ P @ C.T + R
        K = P @ C.T @ np.linalg.inv(S)
        P_new = A @ (P - K @ C @ P) @ A.T + Q
        if np.abs(P_new - P).max() <= 1e-15 * np.abs(P).max():
            break
        P = P_new
    K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    return (K, P) if covariance else K


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
    Y[100:110, [0, 2]] = np.nan     # two out: the gain of the others from the steady P and R
    Y[130:135] = np.nan             # all out: no update
    res = Estimator(db).run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    assert np.all(res.flags[20:60] & FLAG_PARTIAL) and not np.any(res.flags[20:60] & FLAG_NO_UPDATE)
    assert np.all(res.flags[80:90] & FLAG_PARTIAL)
    assert np.all(res.flags[100:110] & FLAG_PARTIAL) and np.all(res.flags[100:110] & FLAG_HEALTH_HELD)
    assert np.all(res.flags[130:135] & FLAG_NO_UPDATE) and not np.any(res.flags[130:135] & FLAG_PARTIAL)
    assert not np.any(res.flags[:20] & (FLAG_PARTIAL | FLAG_NO_UPDATE))
    # the tuners move during the partial updates (a skipped update would hold them)
    assert np.abs(np.diff(res.q_hat[20:60], axis=0)).max() > 0


def test_without_sensor_out_gains_the_steady_covariance_gives_the_update():
    """A database built before sensor-out gains: a missing sensor's update comes from the
    present sensors' gain P C^T (C P C^T + R)^-1 with the interpolated steady-state P and R
    (health held); zone gains have neither and skip the update."""
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=60)
    Y[20:30, 0] = np.nan
    res = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.all(res.flags[20:30] & FLAG_PARTIAL) and np.all(res.flags[20:30] & FLAG_HEALTH_HELD)
    assert not np.any(res.flags & FLAG_NO_UPDATE)
    assert_equals_reference(res, ReferenceFilter(db).run(U, Y, S, TH, DE))
    untuned = Estimator(db, "untuned").run_arrays(U, Y, S, TH, DE)   # tuners held: no subset gain
    assert np.all(untuned.flags[20:30] & FLAG_NO_UPDATE)


def test_online_reduced_update_equals_reference():
    db = online_db()
    U, Y, S, TH, DE = inputs(db, n=150)
    Y[20:40, 0] = np.nan            # any subset: one out, two out
    Y[60:70, [0, 2]] = np.nan
    res = Estimator(db, "online").run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db, online=True).run(U, Y, S, TH, DE)
    assert_equals_reference(res, ref)
    assert np.all(res.flags[20:40] & FLAG_PARTIAL) and np.all(res.flags[60:70] & FLAG_PARTIAL)
    assert not np.any(res.flags & FLAG_NO_UPDATE)


def test_dead_t48_from_takeoff_keeps_fn_error_within_1_5x_of_all_sensors():
    """The demo flight of the degraded engine with T48 dead from the start: the Fn error against
    the simulation's truth stays within 1.5x of the all-sensor run (open-loop, as before the
    sensor-out gains, it was 18x)."""
    from pwl.demo_data import demo_paths
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


def test_points_without_a_sensor_out_gain_use_the_steady_covariance_around_them():
    """A point where the tuners are undetectable without sensor j has no gain without it
    (out_status 2): between such a node and the others the update comes from the steady P and R
    (health held), elsewhere from the stored gain; the reference filter does the same."""
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
    assert np.all(res.flags[near] & FLAG_HEALTH_HELD) and np.all(res.flags & FLAG_PARTIAL)
    assert not np.any(res.flags & FLAG_NO_UPDATE)


def test_health_std_ratios_equal_the_iterated_riccati_recursion():
    """/kalman/out_h_ratio: the health estimates' steady-state standard deviation without sensor
    j over its all-sensor value, from the iterated recursion's covariances."""
    db = with_sensor_out_gains(make_database(ny=4), log=lambda *a: None)
    ny, nx, Vp = db.n("y"), db.n("x"), db.tuner["V_pinv"]
    aug = augment(db.dynamics, Vp)

    def h_std(P):
        return np.sqrt(np.diag(Vp @ P[nx:, nx:] @ Vp.T))
    for idx in np.ndindex(*db.dyn_grid.shape):
        A, C, Q, R = aug["A"][idx], aug["C"][idx], db.kalman["Q"][idx], db.kalman["R"][idx]
        s_all = h_std(riccati_iterated(A, C, Q, R, covariance=True)[1])
        for j in range(ny):
            if db.kalman["out_status"][(j,) + idx] == OUT_NONE:
                assert np.all(db.kalman["out_h_ratio"][(j,) + idx] == 0.0)
                continue
            keep = np.arange(ny) != j
            P = riccati_iterated(A, C[keep], Q, R[np.ix_(keep, keep)], covariance=True)[1]
            np.testing.assert_allclose(db.kalman["out_h_ratio"][(j,) + idx], h_std(P) / s_all, rtol=1e-6)
            assert np.all(db.kalman["out_h_ratio"][(j,) + idx] >= 1.0 - 1e-9)   # a sensor never hurts


def test_health_estimates_hold_while_a_sensor_they_need_is_out():
    db = with_sensor_out_gains(names_db(), log=lambda *a: None)
    U, Y, S, TH, DE = inputs(db, n=120)
    Y[40:70, 1] = np.nan
    held = Estimator(db, health_hold=0.0).run_arrays(U, Y, S, TH, DE)    # every sensor is needed
    assert_equals_reference(held, ReferenceFilter(db, health_hold=0.0).run(U, Y, S, TH, DE))
    assert np.all(held.flags[40:70] & FLAG_HEALTH_HELD) and not np.any(np.delete(held.flags, np.s_[40:70]) & FLAG_HEALTH_HELD)
    np.testing.assert_array_equal(held.h_hat[40:70], np.repeat(held.h_hat[39:40], 30, axis=0))
    np.testing.assert_array_equal(held.q_hat[40:70], np.repeat(held.q_hat[39:40], 30, axis=0))  # tuners too
    assert np.abs(np.diff(held.x_hat[40:70], axis=0)).max() > 0     # the states go on
    assert np.abs(np.diff(held.q_hat[70:], axis=0)).max() > 0       # and the tuners resume
    free = Estimator(db, health_hold=np.inf).run_arrays(U, Y, S, TH, DE)
    assert not np.any(free.flags & FLAG_HEALTH_HELD)
    np.testing.assert_array_equal(free.q_hat[:40], held.q_hat[:40])
    assert np.abs(np.diff(free.q_hat[40:70], axis=0)).max() > 0     # not held: the tuners move


def test_dead_ps30_mid_flight_keeps_health_and_fn_errors_near_the_all_sensor_run():
    """The degraded engine's demo flight with Ps30 dead from half-way: without Ps30 several
    health parameters are 10-30x less observable (/kalman/out_h_ratio), and updating them anyway
    gave a 2.5 point health RMS error; held, it stays within 1.2x of the all-sensor run while the
    Fn error (the tuners go on) stays within 1.2x too."""
    from pwl.demo_data import demo_paths
    from pwl.logs import Log, read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    k0 = len(log) // 2
    ps30 = np.array(log.channels["Ps30"], dtype=np.float64)
    ps30[k0:] = np.nan
    dead = Log(log.time, dict(log.channels, Ps30=ps30), log.units, attrs=log.attrs, path=log.path)
    est = Estimator(db_path)
    h_true = np.column_stack([log.truth[h] for h in est.db.names["h"]])
    after = np.arange(len(log)) >= k0

    def errors(r):
        e = (r.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return np.sqrt(np.mean(e[after] ** 2)), np.sqrt(np.mean((r.h_hat[after] - h_true[after]) ** 2))
    (fn_all, h_all), part = errors(est.run(log)), est.run(dead)
    assert np.all(part.flags[after] & FLAG_HEALTH_HELD)
    fn, h = errors(part)
    assert fn <= 1.2 * fn_all and h <= 1.2 * h_all


@pytest.mark.parametrize("dead", [("T48", "P50"), ("T24", "T30", "P15")])
def test_two_or_three_dead_sensors_keep_the_fn_error_near_the_all_sensor_run(dead):
    """The degraded engine's demo flight with several sensors dead from half-way: the update
    from the others (steady P and R) keeps the Fn error within 1.35x of the all-sensor run (the
    filter open-loop, as before, gave 6x) and the health estimates held."""
    from pwl.demo_data import demo_paths
    from pwl.logs import Log, read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    k0 = len(log) // 2
    ch = dict(log.channels)
    for c in dead:
        ch[c] = np.where(np.arange(len(log)) >= k0, np.nan, ch[c])
    est = Estimator(db_path)
    after = np.arange(len(log)) >= k0

    def fn_rms(r):
        e = (r.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return np.sqrt(np.mean(e[after] ** 2))
    full, part = est.run(log), est.run(Log(log.time, ch, log.units, attrs=log.attrs, path=log.path))
    assert np.all(part.flags[after] & FLAG_PARTIAL) and np.all(part.flags[after] & FLAG_HEALTH_HELD)
    assert fn_rms(part) <= 1.35 * fn_rms(full)


def test_a_dead_schedule_sensor_is_replaced_by_its_estimate():
    """Nf is a sensor, a state and the power scheduling channel (NfR = Nf / sqrt(theta) / 42).
    Dead from half-way, its estimate schedules the model (held at its last value, the operating
    point froze: Fn error 15x the all-sensor run) and the update goes on from the others: the
    degraded flight's Fn error stays within 1.5x of the all-sensor run."""
    from pwl.demo_data import demo_paths
    from pwl.logs import Log, read_log
    from pwl.runtime import FLAG_HELD_INPUT

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    after = np.arange(len(log)) >= len(log) // 2
    dead = Log(log.time, dict(log.channels, Nf=np.where(after, np.nan, log.channels["Nf"])), log.units,
               attrs=log.attrs, path=log.path)
    est = Estimator(db_path)

    def fn_rms(r):
        e = (r.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return np.sqrt(np.mean(e[after] ** 2))
    full, part = est.run(log), est.run(dead)
    assert np.all(part.flags[after] & FLAG_HELD_INPUT) and np.all(part.flags[after] & FLAG_PARTIAL)
    assert fn_rms(part) <= 1.5 * fn_rms(full)
    nf = part.channel("x_hat", "Nf")[after]        # and the speed estimate follows the truth
    assert np.sqrt(np.mean((nf / log.truth["Nf"][after] - 1) ** 2)) < 0.025   # measured 1.65 %
