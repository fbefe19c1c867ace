"""Seed 004: the fuel-to-air ratio bias observer on a simulated diesel engine's drive cycle.

The cycle (an NEDC-like drive cycle, or injection steps at constant speed; ``models.diesel``) is
driven ``passes`` times back to back; the observer (:mod:`experiments.bias_observer`) runs over
all passes, the bias table learning from the first pass on (all nodes start at zero). Three
observers: without table, with table, and with table but the freezing rules off. Errors against
the simulated truth: the biased fast model, the slow delayed sensor and each observer, on the
last (evaluated) pass, the first pass, and the sensor-valid samples of the last pass.

``pwl bias`` runs :func:`drive_cycle` and prints and plots its result.
"""
from __future__ import annotations

import time

import numpy as np

from pwl.grid import Axis, Grid
from pwl.tables import AdaptiveTable

from .bias_observer import BiasObserver, FreezeRules, rms

DT = 0.02                     # sample time, s
A_OBS, TAU_OBS = 0.96, 0.4    # the sensor pole and delay the observer assumes


def drive_cycle(case: str = "nedc", urban_cycles: int = 4, passes: int = 2, seed: int = 1,
                ratio: float = 1 / 80, table_ratio: float = 0.1, table_law: str = "exact",
                spikes: float = 0.02, sensor_a: float = 0.96, sensor_tau: float = 0.4,
                model_scale: float = 1.0, hold: float = 0.2, thresholds: dict | None = None) -> dict:
    """Simulate the cycle and run the three observers. ``ratio``: observer tuning
    sigma_w^2 / sigma_v^2; ``table_ratio``, ``table_law``: the bias table's; ``sensor_a``,
    ``sensor_tau``, ``spikes``: the true sensor's; ``thresholds``: :class:`FreezeRules` fields.

    Returns {"one": one pass, "traj": all passes, "sim", "sensor", "K", "grid", "dt", "a_obs",
    "tau_obs", "k1": samples per pass, "t_sim": s, "timing": s per table run (best of two),
    "runs": {name: (result, table)}, "errors": [(signal, RMS last pass, first pass, valid samples
    of the last pass)], "e_model", "e_sensor", "e_table": RMS last pass, "ok": acceptance (table
    <= 0.5 x model and <= 0.7 x sensor)}."""
    from linearize.bias import observer_gain
    from models import diesel

    if passes < 2:
        raise ValueError("passes must be >= 2 (the table learns on the first pass)")
    dt = DT
    if case == "nedc":
        one = diesel.nedc(dt=dt, urban_cycles=urban_cycles)
    else:
        one = diesel.injection_steps(dt=dt)
    traj = one.repeat(passes)
    engine = diesel.EngineParams(model_scale=model_scale)
    sensor = diesel.SensorParams(a=sensor_a, tau=sensor_tau, spike_rate=spikes)
    t0 = time.perf_counter()
    sim = diesel.simulate(traj, seed=seed, engine=engine, sensor=sensor)
    t_sim = time.perf_counter() - t0
    a_obs, tau_obs = A_OBS, TAU_OBS
    K, _ = observer_gain(a_obs, ratio)
    grid = Grid([Axis("n", np.arange(500.0, 5001.0, 500.0), "rpm"),
                 Axis("mf", np.arange(0.0, 60.001, 1.0), "mg/stroke")])
    rules = FreezeRules(hold=hold, **(thresholds or {}))
    runs = {}
    timing = None
    for name, use_table, r in (("observer, no table", False, rules), ("observer + table", True, rules),
                               ("observer + table, rules off", True, FreezeRules.off())):
        table = AdaptiveTable(grid, law=table_law, ratio=table_ratio) if use_table else None
        obs = BiasObserver(K, a=a_obs, tau=tau_obs, dt=dt, rules=r, table=table)
        t0 = time.perf_counter()
        res = obs.run(sim.lam_model, sim.lam_sensor, sim.n, sim.mf)
        if use_table and timing is None:
            timing = time.perf_counter() - t0
        runs[name] = (res, table)
    # a second timing of the table run (the first call may include loading compiled code)
    obs = BiasObserver(K, a=a_obs, tau=tau_obs, dt=dt, rules=rules, table=AdaptiveTable(grid, ratio=table_ratio))
    t0 = time.perf_counter()
    obs.run(sim.lam_model, sim.lam_sensor, sim.n, sim.mf)
    timing = min(timing, time.perf_counter() - t0)

    k1 = len(one)
    last = slice((passes - 1) * k1, None)
    first = slice(0, k1)
    truth = sim.lam_true
    valid = ~sim.saturated
    e_model = rms((sim.lam_model - truth)[last])
    e_sensor = rms((sim.lam_sensor - truth)[last])
    rows = [("biased model lambda_m", sim.lam_model), ("delayed sensor lambda_s", sim.lam_sensor)]
    rows += [(name, res.lam_hat) for name, (res, _) in runs.items()]
    errors = []
    for name, x in rows:
        e = x - truth
        errors.append((name, rms(e[last]), rms(e[first]), rms(e[last][valid[last]])))
    e_tab = rms((runs["observer + table"][0].lam_hat - truth)[last])
    ok = e_tab <= 0.5 * e_model and e_tab <= 0.7 * e_sensor
    return {"one": one, "traj": traj, "sim": sim, "sensor": sensor, "K": K, "grid": grid, "dt": dt,
            "a_obs": a_obs, "tau_obs": tau_obs, "k1": k1, "t_sim": t_sim, "timing": timing,
            "runs": runs, "errors": errors, "e_model": e_model, "e_sensor": e_sensor,
            "e_table": e_tab, "ok": ok}
