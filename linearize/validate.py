"""Validate a gain database against its nonlinear plant (``pwl validate``).

The piecewise-linear model runs open loop (every Kalman gain zero: no filtering) through the
runtime kernel itself, fed with what a log of the nonlinear plant would hold:

- steady state: at random off-grid operating points the plant is trimmed and the
  piecewise-linear model is run to steady state on the plant's inputs;
- trim tables: at random off-grid points the trims interpolated at the scheduling variables the
  runtime computes from the plant's channels, un-corrected, against the plant's own trim;
- both on a standard day and, for a plant whose environment carries the ambient temperature
  offset (the turbofan's [alt, Mach, dTamb]), on hot and cold days (``dT`` K): the runtime
  schedules on corrected speed and corrects with theta/delta, so these test the correction;
- transient: from a trim the fuel (every input) steps by ``step`` (5 %); the plant is integrated
  with its own unbalanced solve (RK4 at the database's dt, in as many substeps as the fastest
  eigenvalue of the plant's Jacobian at the trim needs: :func:`substeps`) and the model follows
  open loop on the same inputs and scheduling channels; at the middle of the envelope and at
  several values of one scheduling variable (altitudes). A plant whose own response stops being
  finite (an open-loop-unstable point) gives no comparison but a message naming the point and
  the unstable eigenvalue (:func:`divergence`).

Errors are in % of the plant's value, except stall margins (channels named ``Sm...``, themselves
in %): their errors are absolute, in percentage points (:func:`output_errors`).
"""
from __future__ import annotations

import copy
import warnings

import numpy as np

from pwl.database import GainDatabase
from pwl.errors import PwlError, PwlWarning
from pwl.estimator import Estimator
from pwl.logs import Log

from . import plant as proto

#: stall margins: channels whose name starts with this; their errors are in percentage points
MARGIN_PREFIX = "Sm"
#: percentage points per unit of a stall margin's value ("%" as stored; "-" a fraction)
POINTS_PER_UNIT = {"%": 1.0, "-": 100.0}
#: the days of ``pwl validate --days``: sign of the ambient temperature offset dT
DAYS = {"std": 0.0, "hot": 1.0, "cold": -1.0}
#: largest |eigenvalue| x RK4 step of the plant-side integration (:func:`substeps`): RK4 is stable
#: up to 2.79 on the negative real axis and 2.83 on the imaginary one, a margin of 2.8 for the
#: Jacobian of a nonlinear plant moving during the step; the demo turbofan (0.05 at dt 15 ms) and
#: the linear example (0.11 at 50 ms) keep one step per sample
RK4_REACH = 1.0


class ValidateError(PwlError, ValueError):
    """A check the plant or the database cannot do (names what is missing)."""


def is_margin(name: str) -> bool:
    """True for a stall margin channel (errors in percentage points, not % of value)."""
    return name.startswith(MARGIN_PREFIX)


def output_errors(names, units, model, truth) -> np.ndarray:
    """Errors (..., k) of ``model`` against the plant's ``truth`` (same shape, channels ``names``
    with ``units`` last): 100 (model - truth) / |truth| (% of the plant's value), except stall
    margins (:func:`is_margin`): model - truth in percentage points (absolute; a margin near
    zero has no meaningful relative error)."""
    model = np.asarray(model, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    err = 100.0 * (model - truth) / np.abs(truth)
    for j, (n, u) in enumerate(zip(names, units)):
        if is_margin(n):
            if u not in POINTS_PER_UNIT:
                raise ValidateError(f"stall margin {n}: unit {u!r}, expected one of {sorted(POINTS_PER_UNIT)}")
            err[..., j] = POINTS_PER_UNIT[u] * (model[..., j] - truth[..., j])
    return err


def error_unit(name: str) -> str:
    """The unit of :func:`output_errors` for channel ``name``: "%" or "points"."""
    return "points" if is_margin(name) else "%"


def outputs(plant) -> tuple[list, list]:
    """(names, units) of the plant's sensed then unmeasured outputs: the validated channels."""
    names = list(plant.y_names) + list(plant.z_names)
    return names, [plant.units[n] for n in names]


def open_loop(db: GainDatabase) -> Estimator:
    """An estimator with every gain zero: the piecewise-linear model alone. A shallow copy, not
    ``dataclasses.replace``: that would re-validate the database, and zero gains are refused there
    (the tuners' integrators make the error dynamics marginally stable, on purpose here)."""
    model = copy.copy(db)
    model.kalman = dict(db.kalman, K=np.zeros_like(db.kalman["K"]))
    return Estimator(model)


def _runs_away(out: np.ndarray, m: int) -> bool:
    """Whether outputs ``out`` (n, k) of the model run from a trim grow away from it: not finite,
    or moving over the last ``m`` samples by more than 1e-6 of their value and more than over the
    ``m`` before (a stable model's slow mode still settling moves less and less)."""
    if not np.all(np.isfinite(out[-1])):
        return True
    last, prev = np.abs(out[-1] - out[-1 - m]), np.abs(out[-1 - m] - out[-1 - 2 * m])
    return bool(np.any((last > 1e-6 * np.maximum(np.abs(out[-1]), 1e-9)) & (last > prev)))


def quiet_run(est: Estimator, log: Log):
    """``est.run(log)`` without the runtime's warnings: their advice is for logged data (a unit
    to declare, a sensor failed for the log), not for the plant's own simulation compared open
    loop (a plant with outputs in another order read 'EGT logged in degF?' eight times)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PwlWarning)
        return est.run(log)


def plant_of(db: GainDatabase):
    """The database's plant, made as the build made it: ``model`` with the parameters the build's
    plant reported (attrs ``model_parameters``: a plant object passed to the build may differ from
    the stored spec's [model] parameters), else the spec's. :class:`PlantProtocolError` naming the
    plant when that fails (a constructor that does not take its own ``parameters()``)."""
    args = db.attrs.get("model_parameters")
    if args is None:
        from .spec import BuildSpec
        args = BuildSpec.parse(db.attrs["spec"], db.path).parameters if db.attrs.get("spec") else {}
    try:
        return proto.load_plant(db.attrs["model"], args)
    except (TypeError, ValueError) as e:
        raise proto.PlantProtocolError(f"{db.path}: cannot make the plant {db.attrs['model']} again with "
                                       f"{args}: {e} (pass the plant object instead)") from None


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


def plant_trims(db: GainDatabase, plant, n: int, seed: int, failed: list, dT: float = 0.0):
    """(p, env, trim) of the plant at n random off-grid points of the trim grid (which spans every
    scheduling variable), at the database's reference health, on a day ``dT`` K off standard
    (:func:`day_environment`); points whose trim fails are appended to ``failed`` as
    (p, message) and skipped (reported, not hidden). The same seed gives the same points on
    every day."""
    h = db.tuner["h_ref"]
    for p in random_points(db.trim_grid, n, seed):
        env = proto.day_environment(plant, p, dT)
        try:
            t = plant.trim(p, h, env)
        except Exception as e:  # the plant's own error
            failed.append((p, str(e)))
            continue
        yield p, env, t


def steady_state(db: GainDatabase, plant=None, n: int = 20, seed: int = 0, settle_steps: int = 3000,
                 dT: float = 0.0):
    """Errors (n_points, ny + nz) of the open-loop model at random off-grid points on a day
    ``dT`` K off standard (% of value; stall margins in points: :func:`output_errors`), the
    points (n, np), and any points where the plant's trim failed or the model ran away from it
    (open-loop unstable there: :func:`_runs_away`; skipped, with why)."""
    plant = plant or plant_of(db)
    names, units = outputs(plant)
    est = open_loop(db)
    pts, errs, failed = [], [], []
    for p, env, t in plant_trims(db, plant, n, seed, failed, dT):
        rep = lambda v: np.repeat(np.asarray(v, dtype=np.float64)[None, :], settle_steps, axis=0)  # noqa: E731
        log = log_of(plant, db, p, env, rep(t["x"]), rep(t["u"]), rep(t["y"]), rep(t["z"]))
        res = quiet_run(est, log)
        out = np.hstack([res.y_hat, res.z_hat])
        model = out[-1]
        if _runs_away(out, settle_steps // 10):
            # an open-loop-unstable point runs away from the plant's trim: no steady state to compare
            # (a user's plant above 8500 rpm read EGT 2.5e9 % off)
            failed.append((p, f"the model ran away in {settle_steps} steps (open-loop unstable there?)"))
            continue
        errs.append(output_errors(names, units, model, np.concatenate([t["y"], t["z"]])))
        pts.append(p)
    return np.array(errs).reshape(-1, len(names)), np.array(pts), failed


def runtime_point(db: GainDatabase, log: Log) -> np.ndarray:
    """(n, np) scheduling variables the runtime computes from the log's channels (the schedule
    channels, corrected with the log's theta/delta channels), and theta, delta (n,)."""
    S = np.column_stack([log.channels[c] for c, _, _ in db.schedule])
    th = de = np.ones(S.shape[0])
    if db.correction is not None:
        th = log.channels[db.correction.theta_channel] / db.correction.T_std
        de = log.channels[db.correction.delta_channel] / db.correction.P_std
    return db.operating_point(S, th, de), th, de


def scheduled_trims(db: GainDatabase, plant=None, n: int = 200, seed: int = 1, dT: float = 0.0):
    """Errors (n_points, ny + nz) of the interpolated trims at random off-grid points on a day
    ``dT`` K off standard, matched on the scheduling variables the runtime computes from the
    plant's own channels (its corrected fan speed, not its fuel flow): the plant is trimmed at
    p, the runtime's p is formed from that trim's log channels (:func:`runtime_point`), the
    trim tables are interpolated there and un-corrected, and compared with the plant's y and z
    (% of value; stall margins in points). This is the offset every estimate inherits at steady
    state. Returns (errors, points, failed)."""
    plant = plant or plant_of(db)
    names, units = outputs(plant)
    pts, errs, failed = [], [], []
    for p, env, t in plant_trims(db, plant, n, seed, failed, dT):
        log = log_of(plant, db, p, env, *(np.asarray(t[k], dtype=np.float64)[None, :] for k in "xuyz"))
        q, th, de = runtime_point(db, log)
        trims = db.trims_at(q, th)           # on the plant's day, as the runtime moves them
        model = np.concatenate([trims[k][0] * db.correction_factor(db.names[k], th, de)[0] for k in "yz"])
        errs.append(output_errors(names, units, model, np.concatenate([t["y"], t["z"]])))
        pts.append(p)
    return np.array(errs).reshape(-1, len(names)), np.array(pts), failed


def plant_eigenvalues(plant, trim: dict, h, env) -> np.ndarray:
    """Eigenvalues (nx,) of the plant's Jacobian df/dx at a trim (``trim`` from ``plant.trim``, h
    (nh,) health, env its environment), by the builder's perturbations (:mod:`linearize.jacobian`):
    complex, 1/s for a continuous plant; for a discrete plant the multipliers of one step."""
    from .jacobian import jacobians

    return np.linalg.eigvals(jacobians(plant, trim, h, env)[0]["A"])


def substeps(eig, dt: float) -> int:
    """RK4 steps per sample of ``dt`` s for a continuous plant whose Jacobian has the eigenvalues
    ``eig`` (1/s): ceil(max |eig| dt / :data:`RK4_REACH`), at least 1 (a 1 ms pole at dt 50 ms: 50)."""
    return max(1, int(np.ceil(np.abs(eig).max() * dt / RK4_REACH)))


def simulate(plant, x0, U, h, env, dt: float, steps: int = 1):
    """Integrate the plant over inputs U (n, nu), each held for one sample of ``dt`` s: RK4 on its
    unbalanced solve in ``steps`` steps of dt / steps per sample (a discrete plant: its own step);
    returns x, y, z at every sample (n, .). Where the state stops being finite (or the plant
    raises OverflowError or FloatingPointError) the integration stops, every row from that sample
    on is NaN and the warnings raised on the way there (overflow) are dropped: the divergence is
    reported instead (:func:`divergence`); otherwise the plant's warnings are passed on."""
    n = U.shape[0]
    x = np.asarray(x0, dtype=np.float64).copy()
    X = np.full((n, x.size), np.nan)
    Y = np.full((n, len(plant.y_names)), np.nan)
    Z = np.full((n, len(plant.z_names)), np.nan)
    hs = dt / steps
    discrete = getattr(plant, "time", "continuous") == "discrete"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            for k in range(n):
                if not np.all(np.isfinite(x)):
                    break
                u = U[k]
                f1, y, z = plant.evaluate(x, u, h, env)
                X[k], Y[k], Z[k] = x, y, z
                if discrete:
                    x = np.asarray(f1, dtype=np.float64)
                    continue
                for i in range(steps):
                    if i:
                        f1 = plant.evaluate(x, u, h, env)[0]
                    f2 = plant.evaluate(x + 0.5 * hs * f1, u, h, env)[0]
                    f3 = plant.evaluate(x + 0.5 * hs * f2, u, h, env)[0]
                    f4 = plant.evaluate(x + hs * f3, u, h, env)[0]
                    x = x + hs / 6.0 * (f1 + 2 * f2 + 2 * f3 + f4)
        except (OverflowError, FloatingPointError):
            pass                            # the rows not reached stay NaN
    if np.all(np.isfinite(X)):
        seen = {}
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, registry=seen)
    return X, Y, Z


def divergence(point: str, eig, discrete: bool, t_bad: float, steps: int, dt: float) -> str:
    """Why the plant's own response stopped being finite at ``t_bad`` s in a transient from a trim
    at ``point`` ("alt=0, NR=85"): its unstable eigenvalue there (``eig`` (nx,) of its Jacobian:
    1/s; for a ``discrete`` plant multipliers per step), else that it grew without bound from a
    stable trim (the step took it elsewhere, or ``steps`` RK4 steps per ``dt`` s were too few)."""
    grew = f"the plant's own response grew without bound (not finite from t = {t_bad:.3g} s)"
    fmt = lambda e: f"{e.real:+.4g}" if e.imag == 0 else f"{e.real:+.4g}{e.imag:+.4g}j"  # noqa: E731
    worst = eig[np.argmax(np.abs(eig) if discrete else eig.real)]
    if discrete and abs(worst) > 1.0:
        return (f"{grew}: the plant is open-loop unstable at {point} (its Jacobian there has the "
                f"multiplier {fmt(worst)} per step, magnitude {abs(worst):.4g} > 1): no transient to compare")
    if not discrete and worst.real > 0.0:
        return (f"{grew}: the plant is open-loop unstable at {point} (its Jacobian there has the "
                f"eigenvalue {fmt(worst)} 1/s, growing e-fold every {1.0 / worst.real:.3g} s): no "
                "transient to compare")
    return (f"{grew} from a stable trim at {point} (eigenvalues {', '.join(fmt(e) for e in eig)}"
            f"{'' if discrete else ' 1/s'}): the step took it somewhere unstable, or {steps} RK4 "
            f"step(s) per {dt:g} s sample were too few")


def step_point(db: GainDatabase, axis: str | None = None, value: float | None = None) -> np.ndarray:
    """The transient's trim point (np,): the middle of the trim grid box, 1e-3 off it (off-grid),
    with scheduling variable ``axis`` (e.g. "alt") set to ``value`` when given (within the
    grid's range, else a :class:`ValidateError` naming both)."""
    p = np.array([0.5 * (a.lo + a.hi) for a in db.trim_grid.axes]) + 1e-3
    if axis is None:
        return p
    names = [a.name for a in db.trim_grid.axes]
    if axis not in names:
        raise ValidateError(f"the trim grid has no axis {axis!r} (axes {names})")
    ax = db.trim_grid.axes[names.index(axis)]
    if not ax.lo <= value <= ax.hi:
        raise ValidateError(f"{axis}={value:g} is outside the trim grid's {axis} range {ax.lo:g}..{ax.hi:g}")
    p[names.index(axis)] = value
    return p


def fuel_step(db: GainDatabase, plant=None, p=None, step: float = 0.05, seconds: float = 8.0,
              t_step: float = 1.0):
    """Open-loop model vs plant after an input step of ``step`` (fraction) at ``t_step`` s from a
    trim at ``p`` (default: :func:`step_point`). Returns a dict with time (n,) s, the plant's
    ("truth") and the model's y and z (n, ny + nz), their names and units, ``p``, and the errors
    (n, ny + nz; % of value, stall margins in points: :func:`output_errors`), ``t_step``; ``eigenvalues``
    (nx,) of the plant's Jacobian at the trim (1/s), the RK4 ``steps`` per sample
    (:func:`substeps`) and ``diverged``: None, or when the plant's own response stopped being
    finite the reason (:func:`divergence`), the truth NaN from there on and the model and the
    errors NaN throughout (not run: there is nothing to compare)."""
    plant = plant or plant_of(db)
    if p is None:
        p = step_point(db)
    env = plant.environment(p)
    h = db.tuner["h_ref"]
    t = plant.trim(p, h, env)
    eig = plant_eigenvalues(plant, t, h, env)
    discrete = getattr(plant, "time", "continuous") == "discrete"
    steps = 1 if discrete else substeps(eig, db.dt)
    n = int(round(seconds / db.dt))
    time = np.arange(n) * db.dt
    U = np.repeat(np.asarray(t["u"], dtype=np.float64)[None, :], n, axis=0)
    U[time >= t_step] *= 1.0 + step
    X, Y, Z = simulate(plant, t["x"], U, h, env, db.dt, steps)
    truth = np.hstack([Y, Z])
    names, units = outputs(plant)
    bad = ~np.all(np.isfinite(X), axis=1)
    diverged = None
    if bad.any():
        point = ", ".join(f"{a.name}={v:.4g}" for a, v in zip(db.trim_grid.axes, p))
        diverged = divergence(point, eig, discrete, float(time[np.argmax(bad)]), steps, db.dt)
        model = np.full_like(truth, np.nan)
    else:
        res = quiet_run(open_loop(db), log_of(plant, db, p, env, X, U, Y, Z))
        model = np.hstack([res.y_hat, res.z_hat])
    return {"time": time, "truth": truth, "model": model, "p": p, "names": names, "units": units,
            "error": output_errors(names, units, model, truth), "t_step": t_step, "eigenvalues": eig,
            "steps": steps, "diverged": diverged}


def transients(db: GainDatabase, plant=None, axis: str = "alt", values=(0.0, 6000.0, 12000.0),
               step: float = 0.05, seconds: float = 8.0) -> list[dict]:
    """:func:`fuel_step` from a trim at each of ``values`` of scheduling variable ``axis`` (the
    other variables at the middle of the envelope, :func:`step_point`); each result also holds
    ``rms`` and ``max`` (ny + nz,): RMS and largest |error| over the run (% / points)."""
    plant = plant or plant_of(db)
    out = []
    for v in values:
        tr = fuel_step(db, plant, step_point(db, axis, float(v)), step=step, seconds=seconds)
        tr["rms"] = np.sqrt(np.mean(tr["error"] ** 2, axis=0))
        tr["max"] = np.abs(tr["error"]).max(axis=0)
        out.append(tr)
    return out
