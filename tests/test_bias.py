"""Bias observer with a slow delayed sensor (seed 004): gain, kernel, freezing, table, acceptance.

References: the iterated Riccati recursion of eq. (12) for K_inf; a plain-numpy implementation of
eqs. (7)-(11), (14)-(16) written here from the equations (not from the kernel) for the observer;
scipy.signal.lfilter for the sensor model of eq. (1).
"""
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from experiments.bias_observer import FLAG_F1, FLAG_F3, FLAG_F4, FLAG_F5, BiasObserver, FreezeRules, rms
from linearize.bias import observer_gain, observer_matrices
from models import diesel
from pwl.grid import Axis, Grid
from pwl.tables import AdaptiveTable

DT = 0.02
A_SENSOR = 0.96


def table_grid():
    """The paper's table density: speed every 500 rpm (500..5000), fuel every 1 mg/stroke."""
    return Grid([Axis("n", np.arange(500.0, 5001.0, 500.0), "rpm"),
                 Axis("mf", np.arange(0.0, 60.001, 1.0), "mg/stroke")])


# ------------------------------------------------------------------------------------------
# gain


def riccati_iterated(A, C, Q, R, iters=20000):
    """Eq. (12) iterated from P = I until it stops moving; returns the converged K_k."""
    P = np.eye(A.shape[0])
    K = None
    for _ in range(iters):
        Pm = A @ P @ A.T + Q
        K = Pm @ C.T / (C @ Pm @ C.T + R)
        Pn = (np.eye(A.shape[0]) - K @ C) @ Pm
        if np.abs(Pn - P).max() < 1e-15:
            break
        P = Pn
    return K[:, 0]


@pytest.mark.parametrize("a,ratio", [(0.96, 1 / 80), (0.96, 1 / 30), (0.9, 1e-3), (0.5, 1.0)])
def test_gain_matches_iterated_riccati(a, ratio):
    K, P = observer_gain(a, ratio)
    A, _, C = observer_matrices(a)
    K_ref = riccati_iterated(A, C, np.diag([ratio, 0.0]), 1.0)
    np.testing.assert_allclose(K, K_ref, rtol=1e-9, atol=1e-12)
    assert K[0] > 0 and K[1] > 0
    # the noise variances only enter through their ratio
    np.testing.assert_allclose(observer_gain(a, ratio, sigma_v2=1e-4)[0], K, rtol=1e-9)


def test_gain_grows_with_process_noise():
    """Fig. 10 of the paper: both gains rise with sigma_w^2 / sigma_v^2."""
    ks = np.array([observer_gain(A_SENSOR, r)[0] for r in (1e-4, 1e-3, 1 / 80, 1 / 30, 1.0)])
    assert np.all(np.diff(ks[:, 0]) > 0) and np.all(np.diff(ks[:, 1]) > 0)


# ------------------------------------------------------------------------------------------
# model


def test_sensor_matches_lfilter():
    rng = np.random.default_rng(3)
    x = np.clip(np.cumsum(rng.normal(0, 0.02, 2000)) + 0.4, 0, 1)
    s = diesel.SensorParams(noise=0.0, sat_level=-1.0)
    lam_f, reading, sat, spikes = diesel.sensor_response(x, DT, s, rng)
    d = int(round(s.tau / DT))
    xd = np.concatenate([np.full(d, x[0]), x[:-d]])
    ref = lfilter([1 - s.a], [1, -s.a], xd, zi=[s.a * x[0]])[0]
    np.testing.assert_allclose(lam_f, ref, atol=1e-12)
    np.testing.assert_array_equal(reading, lam_f)
    assert not sat.any() and not spikes.any()


def test_nedc_profile_and_drive_cycle():
    t, v = diesel.nedc_profile(dt=1.0)
    assert t.size == 1180 and v.max() == 120.0
    assert v[:11].max() == 0 and v[12] > 0               # first acceleration after 11 s idle
    for plateau in (15, 32, 50, 35, 70, 100):
        assert np.any(v == plateau)
    tr = diesel.nedc()
    assert len(tr) == 59000 and tr.dt == pytest.approx(DT)
    assert tr.n.min() == pytest.approx(800.0) and 2500 < tr.n.max() < 3500
    assert np.any(tr.mf == 0.0)                          # fuel cut on overrun
    assert 0 < tr.mf.max() <= diesel.EngineParams().mf_max


def test_simulation_bias_and_saturation():
    tr = diesel.nedc(urban_cycles=1)
    s = diesel.simulate(tr, seed=2)
    assert np.all(s.lam_sensor >= 0.1 - 1e-15)
    assert s.saturated.any() and np.all(s.lam_sensor[s.saturated] == 0.1)
    # the bias has the sign and size of the steady map where the engine sits still
    steady = diesel.steady_bias(s.n, s.mf, s.t)
    calm = (np.abs(np.gradient(s.boost, DT)) < 1e-3) & (s.mf > 2)
    assert rms((s.theta - steady)[calm]) < 0.25 * rms(steady[calm])
    assert rms(s.theta) > 0.02
    again = diesel.simulate(tr, seed=2)
    np.testing.assert_array_equal(again.lam_sensor, s.lam_sensor)   # seeded


# ------------------------------------------------------------------------------------------
# independent numpy reference of the observer


def bilinear(values, ax0, ax1, p0, p1):
    """Weights and flat rows of the bilinear cell of (p0, p1), clipped to the grid."""
    def axis(ax, x):
        x = min(max(x, ax[0]), ax[-1])
        i = min(max(np.searchsorted(ax, x, side="right") - 1, 0), ax.size - 2)
        return i, (x - ax[i]) / (ax[i + 1] - ax[i])
    i, s = axis(ax0, p0)
    j, t = axis(ax1, p1)
    n1 = ax1.size
    rows = np.array([i * n1 + j, i * n1 + j + 1, (i + 1) * n1 + j, (i + 1) * n1 + j + 1])
    w = np.array([(1 - s) * (1 - t), (1 - s) * t, s * (1 - t), s * t])
    return w, rows


def reference_observer(lam_m, lam_s, n, mf, K, a, d, thr, hold, table=None, ratio=0.1):
    """Eqs. (7)-(11), (14)-(16), plainly: returns lam_hat, theta, frozen (and the final table).

    Delayed inputs are lam_m[max(k - d, 0)] (the log is taken as steady before its start).
    Table learning: the exact steady-state law k = c / (pbar |c|^2),
    pbar = (1 + sqrt(1 + 4 r / |c|^2)) / 2 (DESIGN.md section 3).
    """
    A = np.array([[1.0, 0.0], [1 - a, a]])
    B = np.array([0.0, 1 - a])
    vals = None if table is None else table[2].copy().reshape(-1)
    N = lam_m.size
    lam_hat, theta_out, frozen = np.zeros(N), np.zeros(N), np.zeros(N, bool)
    x = None
    e_prev = y_prev = u_prev = None
    hold_left = 0
    for k in range(N):
        kd = max(k - d, 0)
        u = lam_m[kd]
        if table is not None:
            w, rows = bilinear(vals, table[0], table[1], n[kd], mf[kd])
            theta_prior = w @ vals[rows]
        if x is None:
            th0 = theta_prior if table is not None else 0.0
            x = np.array([th0, u + th0])
            e_prev, y_prev, u_prev = lam_s[0] - x[1], lam_s[0], u
        xp = A @ x + B * u
        if table is not None:
            xp[0] = theta_prior                                   # eq. (15)
        e = lam_s[k] - xp[1]
        est_d = u + xp[0]
        rules = [abs(e - e_prev) / DT > thr[0], abs(u - u_prev) / DT > thr[1],
                 abs(lam_s[k] - y_prev) / DT > thr[2], lam_s[k] < thr[3], lam_s[k] > thr[4],
                 est_d < thr[5], est_d > thr[6]]
        e_prev, y_prev, u_prev = e, lam_s[k], u
        if any(rules):
            hold_left = hold
            frozen[k] = True
        elif hold_left > 0:
            hold_left -= 1
            frozen[k] = True
        if frozen[k]:
            e = 0.0
        x = xp + K * e
        if table is not None:
            if e != 0.0:
                c2 = w @ w
                pbar = 0.5 * (1 + math.sqrt(1 + 4 * ratio / c2))
                vals[rows] += w / (pbar * c2) * (x[0] - theta_prior)
            wc, rc = bilinear(vals, table[0], table[1], n[k], mf[k])
            lam_hat[k] = lam_m[k] + wc @ vals[rc]                # eq. (16)
        else:
            lam_hat[k] = lam_m[k] + x[0]
        theta_out[k] = x[0]
    return lam_hat, theta_out, frozen, vals


def short_sim(seed=4, spikes=0.2, seconds=120.0):
    tr = diesel.nedc(urban_cycles=1, extra_urban=False)
    k = int(seconds / DT)
    tr = diesel.Trajectory(tr.t[:k], tr.n[:k], tr.mf[:k])
    return diesel.simulate(tr, seed=seed, sensor=diesel.SensorParams(spike_rate=spikes))


@pytest.mark.parametrize("use_table", [False, True])
def test_kernel_matches_numpy_reference(use_table):
    """Kernel vs plain numpy, same equations: agreement to 1e-12 absolute over 6000 steps."""
    s = short_sim()
    K, _ = observer_gain(A_SENSOR, 1 / 30)
    rules = FreezeRules(hold=0.2)
    grid = table_grid()
    v0 = np.random.default_rng(0).normal(0, 0.01, grid.shape)
    table = AdaptiveTable(grid, values=v0, ratio=0.1) if use_table else None
    obs = BiasObserver(K, a=A_SENSOR, tau=0.4, dt=DT, rules=rules, table=table)
    r = obs.run(s.lam_model, s.lam_sensor, s.n, s.mf)
    ref_tab = (grid.axes[0].values, grid.axes[1].values, v0) if use_table else None
    lam_hat, theta, frozen, vals = reference_observer(
        s.lam_model, s.lam_sensor, s.n, s.mf, K, A_SENSOR, 20, rules.array(), 10, ref_tab, 0.1)
    np.testing.assert_array_equal(r.frozen, frozen)
    assert 0.05 < frozen.mean() < 0.95                      # both branches exercised
    np.testing.assert_allclose(r.theta, theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.lam_hat, lam_hat, rtol=0, atol=1e-12)
    if use_table:
        np.testing.assert_allclose(table.values.reshape(-1), vals, rtol=0, atol=1e-12)
        assert np.abs(table.values - v0).max() > 1e-3         # it did learn
        assert table.n_updates == int((~frozen).sum())


def test_chunked_run_equals_whole_run():
    s = short_sim(seconds=60)
    K, _ = observer_gain(A_SENSOR, 1 / 80)
    t1, t2 = AdaptiveTable(table_grid(), ratio=0.1), AdaptiveTable(table_grid(), ratio=0.1)
    whole = BiasObserver(K, table=t1).run(s.lam_model, s.lam_sensor, s.n, s.mf)
    obs = BiasObserver(K, table=t2)
    parts = [obs.run(s.lam_model[i:j], s.lam_sensor[i:j], s.n[i:j], s.mf[i:j])
             for i, j in ((0, 7), (7, 1000), (1000, 1001), (1001, len(s.t)))]
    np.testing.assert_array_equal(np.concatenate([p.lam_hat for p in parts]), whole.lam_hat)
    np.testing.assert_array_equal(t1.values, t2.values)


# ------------------------------------------------------------------------------------------
# freezing


def steady_case(n_steps=1500, theta=0.05, lam=0.3):
    """Constant model, sensor = eq. (1) of lam_m + theta (noise free): the observer converges."""
    lam_m = np.full(n_steps, lam)
    lam_s = np.full(n_steps, lam + theta)
    return lam_m, lam_s


def test_converges_to_constant_bias_without_freezing_events():
    lam_m, lam_s = steady_case()
    K, _ = observer_gain(A_SENSOR, 1 / 80)
    r = BiasObserver(K, rules=FreezeRules()).run(lam_m, lam_s)
    assert abs(r.theta[-1] - 0.05) < 1e-6 and not r.frozen[-500:].any()
    assert abs(r.lam_hat[-1] - 0.35) < 1e-6


@pytest.mark.parametrize("use_table", [False, True])
def test_frozen_during_saturation_and_spikes(use_table):
    """Saturated readings (F4) and spikes (F3/F5 + hold) stop integration: theta and the table
    do not move while frozen; with the rules off the same data does move them."""
    rng = np.random.default_rng(7)
    k = 3000
    lam_m = np.full(k, 0.3)
    sat = slice(1000, 1400)
    lam_m[sat] = 0.0                                   # fuel cut: the sensor saturates at 0.1
    # sensor: eq. (1) of the truth lam_m + 0.05 (delay 20 samples, pole a), noise, saturation
    truth_d = np.concatenate([np.full(20, 0.35), lam_m[:-20] + 0.05])
    lam_s = lfilter([1 - A_SENSOR], [1, -A_SENSOR], truth_d, zi=[A_SENSOR * 0.35])[0]
    lam_s = np.maximum(lam_s + 0.002 * rng.standard_normal(k), 0.1)
    spike_at = [1800, 1801, 1802, 2200, 2500, 2501]
    lam_s[spike_at] += np.array([0.4, 0.4, 0.4, -0.3, 0.8, 0.8])
    n = np.full(k, 1500.0)
    mf = np.full(k, 20.0)
    K, _ = observer_gain(A_SENSOR, 1 / 30)
    results = {}
    for name, rules in (("on", FreezeRules(hold=0.3)), ("off", FreezeRules.off())):
        table = AdaptiveTable(table_grid(), ratio=0.1) if use_table else None
        obs = BiasObserver(K, rules=rules, table=table)
        r0 = obs.run(lam_m[:990], lam_s[:990], n[:990], mf[:990])
        snap_theta = obs.theta
        snap_table = None if table is None else table.values.copy()
        r1 = obs.run(lam_m[990:], lam_s[990:], n[990:], mf[990:])
        results[name] = (r0, r1, snap_theta, snap_table, table)
    r0, r1, th, tab, table = results["on"]
    fr = r1.frozen
    flags = r1.flags
    # the saturated stretch (reading at the floor), in the chunk's indices
    win = slice(1000 + 20 + 40 - 990, 1400 + 20 - 990)
    assert np.all(lam_s[990:][win] < 0.12)
    assert fr[win].all() and (flags[win] & FLAG_F4).all()
    for i in spike_at:
        assert fr[i - 990]                                # inside a flat spike: by the hold time
    for i in (1800, 2200, 2500):                          # a spike's first sample: by a rule
        assert flags[i - 990] & (FLAG_F1 | FLAG_F3 | FLAG_F5)
    # while frozen, theta holds its value exactly
    idx = np.flatnonzero(fr)
    prev = np.concatenate([[th], r1.theta[:-1]])
    if table is None:
        np.testing.assert_array_equal(r1.theta[idx], prev[idx])
    # the table does not move over a stretch where every step is frozen
    if table is not None:
        t2 = AdaptiveTable(table_grid(), ratio=0.1)
        obs = BiasObserver(K, rules=FreezeRules(hold=0.3), table=t2)
        obs.run(lam_m[:1020], lam_s[:1020], n[:1020], mf[:1020])
        before = t2.values.copy()
        rr = obs.run(lam_m[1020:1440], lam_s[1020:1440], n[1020:1440], mf[1020:1440])
        assert rr.frozen.all()
        np.testing.assert_array_equal(t2.values, before)
    # estimate after the events: still the true bias (0.05) where the rules froze
    assert abs(r1.bias[-1] - 0.05) < 0.005
    # the same data without the rules drags theta away during saturation and spikes
    r0o, r1o, _, _, _ = results["off"]
    after = slice(win.start, win.stop + 200)
    assert np.abs(r1o.bias[after] - 0.05).max() > 0.02
    assert np.abs(r1.bias[after] - 0.05).max() < 0.005


def test_nan_sensor_freezes_and_rules_count():
    lam_m, lam_s = steady_case(600)
    lam_s[300:310] = np.nan
    K, _ = observer_gain(A_SENSOR, 1 / 80)
    r = BiasObserver(K).run(lam_m, lam_s)
    assert r.frozen[300:310].all() and np.all(np.isfinite(r.lam_hat))
    assert r.rule_counts()["nan_sensor"] == 10


def test_bad_input_is_named():
    K, _ = observer_gain(A_SENSOR, 1 / 80)
    with pytest.raises(ValueError, match="K must be"):
        BiasObserver([1.0])
    with pytest.raises(ValueError, match="operating point"):
        BiasObserver(K, table=AdaptiveTable(table_grid())).run(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="lam_s"):
        BiasObserver(K).run(np.zeros(3), np.zeros(4))


# ------------------------------------------------------------------------------------------
# acceptance: fuel-to-air case on a (shortened) drive cycle, table learnt on a first pass


def drive_case(urban_cycles=1, seed=11, spikes=0.02):
    tr = diesel.nedc(urban_cycles=urban_cycles).repeat(2)
    s = diesel.simulate(tr, seed=seed, sensor=diesel.SensorParams(spike_rate=spikes))
    half = len(tr) // 2
    K, _ = observer_gain(A_SENSOR, 1 / 80)
    out = {"model": rms((s.lam_model - s.lam_true)[half:]),
           "sensor": rms((s.lam_sensor - s.lam_true)[half:])}
    for name, table, rules in (("observer", None, FreezeRules()),
                               ("table", AdaptiveTable(table_grid(), ratio=0.1), FreezeRules()),
                               ("table, rules off", AdaptiveTable(table_grid(), ratio=0.1), FreezeRules.off())):
        r = BiasObserver(K, table=table, rules=rules).run(s.lam_model, s.lam_sensor, s.n, s.mf)
        out[name] = rms((r.lam_hat - s.lam_true)[half:])
    return out


def test_drive_cycle_acceptance():
    e = drive_case()
    assert e["table"] <= 0.5 * e["model"], e
    assert e["table"] <= 0.7 * e["sensor"], e
    assert e["table"] < e["observer"] < e["model"], e
    assert e["table, rules off"] > 2 * e["table"], e      # the freezing rules are what makes it work
