"""Validate a gain database against its nonlinear plant (``pwl validate``).

The piecewise-linear model runs open loop (every Kalman gain zero: no filtering) through the
runtime kernel itself, fed with what a log of the nonlinear plant would hold:

- steady state: at random off-grid operating points the plant is trimmed and the
  piecewise-linear model is run to steady state on the plant's inputs; errors of y and z in % of
  the plant's values;
- transient: from a trim at mid power the fuel (every input) steps by ``step`` (5 %); the plant
  is integrated with its own unbalanced solve (RK4 at the database's dt) and the model follows
  open loop on the same inputs and scheduling channels; errors in % of the plant's values.
"""
from __future__ import annotations

import copy

import numpy as np

from pwl.database import GainDatabase
from pwl.estimator import Estimator
from pwl.logs import Log

from . import plant as proto


def open_loop(db: GainDatabase) -> Estimator:
    """An estimator with every gain zero: the piecewise-linear model alone. A shallow copy, not
    ``dataclasses.replace``: that would re-validate the database, and zero gains are refused there
    (the tuners' integrators make the error dynamics marginally stable, on purpose here)."""
    model = copy.copy(db)
    model.kalman = dict(db.kalman, K=np.zeros_like(db.kalman["K"]))
    return Estimator(model)


def plant_of(db: GainDatabase):
    return proto.load_plant(db.attrs["model"], db.attrs.get("model_parameters", {}))


def log_of(plant, db: GainDatabase, p: np.ndarray, env, x, u, y, z) -> Log:
    """A log (n samples) of the plant's channels as the runtime reads them: inputs, sensed
    outputs, scheduling channels and the correction's theta/delta channels."""
    n = x.shape[0]
    vals = {}
    for k, arr in (("x", x), ("u", u), ("y", y), ("z", z)):
        for j, name in enumerate(proto.names(plant, k)):
            vals.setdefault(name, arr[:, j])
    for j, name in enumerate(plant.p_names):
        vals.setdefault(name, np.full(n, float(p[j])))
    if db.correction is not None:
        th, de = plant.theta_delta(env)
        vals[db.correction.theta_channel] = np.full(n, th * db.correction.T_std)
        vals[db.correction.delta_channel] = np.full(n, de * db.correction.P_std)
    return Log(np.arange(n) * db.dt, vals, {}, path="<plant>")


def random_points(grid, n: int, seed: int, margin: float = 0.02) -> np.ndarray:
    """n points uniformly inside the grid box, ``margin`` (fraction of each span) off its edges."""
    rng = np.random.default_rng(seed)
    lo = np.array([a.lo for a in grid.axes])
    hi = np.array([a.hi for a in grid.axes])
    span = hi - lo
    return lo + margin * span + rng.random((n, grid.ndim)) * (1 - 2 * margin) * span


def plant_trims(db: GainDatabase, plant, n: int, seed: int, failed: list):
    """(p, env, trim) of the plant at n random off-grid points of the trim grid (which spans every
    scheduling variable), at the database's reference health; points whose trim fails are
    appended to ``failed`` as (p, message) and skipped (reported, not hidden)."""
    h = db.tuner["h_ref"]
    for p in random_points(db.trim_grid, n, seed):
        env = plant.environment(p)
        try:
            t = plant.trim(p, h, env)
        except Exception as e:  # the plant's own error
            failed.append((p, str(e)))
            continue
        yield p, env, t


def steady_state(db: GainDatabase, plant=None, n: int = 20, seed: int = 0, settle_steps: int = 3000):
    """Percent errors (n_points, ny + nz) of the open-loop model at random off-grid points, the
    points (n, np), and any points where the plant's trim failed (skipped)."""
    plant = plant or plant_of(db)
    est = open_loop(db)
    pts, errs, failed = [], [], []
    for p, env, t in plant_trims(db, plant, n, seed, failed):
        rep = lambda v: np.repeat(np.asarray(v, dtype=np.float64)[None, :], settle_steps, axis=0)  # noqa: E731
        log = log_of(plant, db, p, env, rep(t["x"]), rep(t["u"]), rep(t["y"]), rep(t["z"]))
        res = est.run(log)
        model = np.concatenate([res.y_hat[-1], res.z_hat[-1]])
        truth = np.concatenate([t["y"], t["z"]])
        errs.append(100.0 * (model - truth) / np.abs(truth))
        pts.append(p)
    return np.array(errs), np.array(pts), failed


def scheduled_trims(db: GainDatabase, plant=None, n: int = 200, seed: int = 1):
    """Percent errors (n_points, ny + nz) of the interpolated trims at random off-grid points,
    matched on the scheduling variables the runtime computes from the plant's own channels (its
    corrected fan speed, not its fuel flow): the plant is trimmed at p, the runtime's p is
    formed from that trim's log channels (:meth:`GainDatabase.operating_point`), the trim tables
    are interpolated there and un-corrected, and compared with the plant's y and z. This is the
    offset every estimate inherits at steady state. Returns (errors, points, failed)."""
    from pwl.interp import interpolate

    plant = plant or plant_of(db)
    chans = [c for c, _, _ in db.schedule]
    pts, errs, failed = [], [], []
    for p, env, t in plant_trims(db, plant, n, seed, failed):
        log = log_of(plant, db, p, env, *(np.asarray(t[k], dtype=np.float64)[None, :] for k in "xuyz"))
        S = np.column_stack([log.channels[c] for c in chans])
        th = de = np.ones(1)
        if db.correction is not None:
            th = log.channels[db.correction.theta_channel] / db.correction.T_std
            de = log.channels[db.correction.delta_channel] / db.correction.P_std
        q = db.operating_point(S, th, de)[0]
        at = [q[db.names["p"].index(a.name)] for a in db.trim_grid.axes]
        model = np.concatenate([
            interpolate(db.trim_grid, db.trim[k], np.array(at))[0]
            * db.correction_factor(db.names[k], th, de)[0] for k in "yz"])
        truth = np.concatenate([t["y"], t["z"]])
        errs.append(100.0 * (model - truth) / np.abs(truth))
        pts.append(p)
    return np.array(errs), np.array(pts), failed


def simulate(plant, x0, U, h, env, dt: float):
    """Integrate the plant over inputs U (n, nu) held per step (RK4 on the unbalanced solve);
    returns x, y, z at every sample (n, .)."""
    n = U.shape[0]
    x = np.asarray(x0, dtype=np.float64).copy()
    X = np.empty((n, x.size))
    Y = np.empty((n, len(plant.y_names)))
    Z = np.empty((n, len(plant.z_names)))
    for k in range(n):
        u = U[k]
        f1, y, z = plant.evaluate(x, u, h, env)
        X[k], Y[k], Z[k] = x, y, z
        if getattr(plant, "time", "continuous") == "discrete":
            x = np.asarray(f1, dtype=np.float64)
            continue
        f2 = plant.evaluate(x + 0.5 * dt * f1, u, h, env)[0]
        f3 = plant.evaluate(x + 0.5 * dt * f2, u, h, env)[0]
        f4 = plant.evaluate(x + dt * f3, u, h, env)[0]
        x = x + dt / 6.0 * (f1 + 2 * f2 + 2 * f3 + f4)
    return X, Y, Z


def fuel_step(db: GainDatabase, plant=None, p=None, step: float = 0.05, seconds: float = 8.0,
              t_step: float = 1.0):
    """Open-loop model vs plant after an input step of ``step`` (fraction) at ``t_step`` s from a
    trim at ``p`` (default: the middle of the trim grid box, off-grid). Returns a dict with
    time, the plant's and the model's y and z (n, .), their names and units, and the percent
    errors."""
    plant = plant or plant_of(db)
    if p is None:
        p = np.array([0.5 * (a.lo + a.hi) for a in db.trim_grid.axes]) + 1e-3
    env = plant.environment(p)
    h = db.tuner["h_ref"]
    t = plant.trim(p, h, env)
    n = int(round(seconds / db.dt))
    time = np.arange(n) * db.dt
    U = np.repeat(np.asarray(t["u"], dtype=np.float64)[None, :], n, axis=0)
    U[time >= t_step] *= 1.0 + step
    X, Y, Z = simulate(plant, t["x"], U, h, env, db.dt)
    res = open_loop(db).run(log_of(plant, db, p, env, X, U, Y, Z))
    truth = np.hstack([Y, Z])
    model = np.hstack([res.y_hat, res.z_hat])
    names = list(plant.y_names) + list(plant.z_names)
    return {"time": time, "truth": truth, "model": model, "p": p, "names": names,
            "units": [plant.units[n] for n in names], "error": 100.0 * (model - truth) / np.abs(truth)}
