"""A plain numpy + scipy per-step reference of the runtime filter (for tests and benchmarks).

Written independently of the numba kernel: scipy's RegularGridInterpolator on the unpacked
database arrays, ``np.block`` augmentation, numpy matrix products, its own parameter correction.
It is slow on purpose-free grounds (Python per step); it exists to be obviously right.
"""
from __future__ import annotations

import numpy as np

from ..airdata import ambient_offset
from ..database import AMBIENT_REACH, OUT_NONE, GainDatabase
from ..runtime import NOISY_CHANGES


def node_weights(axes, point):
    """Multilinear weights of every grid node at ``point`` (inside the grid), shape (size,):
    the tensor product of per-axis hat functions, from np.interp of unit vectors."""
    w = np.ones(1)
    for a, x in zip(axes, point):
        wa = np.array([np.interp(x, a, np.eye(len(a))[i]) for i in range(len(a))])
        w = np.multiply.outer(w, wa).reshape(-1)
    return w


class ReferenceFilter:
    """``bias``: optional channel -> (axes list of breakpoint arrays, axis names, values
    (grid shape, corrected units; updated in place), noise ratio) with the exact table gain
    written out from its closed form (DESIGN.md section 3).

    ``online``: the time-varying Kalman filter instead (the runtime's online mode): P from the
    interpolated steady-state P at the first sample, then P = A P A^T + Q, K = P C^T (C P C^T +
    R)^-1 by ``np.linalg.solve``, P = (I - K C) P every step. ``zones``: a ZoneTable on the
    dynamics grid; K is the centroid gain of the zone of the nearest node (per axis argmin).
    ``health_hold``: steady gains, one sensor out: the tuners keep their prediction (and h_hat
    its last value) where a node of non-zero weight has a health standard-deviation ratio above
    it without that sensor. Steady
    gains and sensors missing without a stored gain for the set (two or more, or none stored):
    the present sensors' gain from the interpolated steady-state P and R, tuners and h_hat held.

    Sensor checks (each sensor's noise std ``sd`` relative to its value: the median over the
    grid of sqrt(R_ii) over the median |y_trim|): a value repeated ``stuck_after`` seconds (in
    samples of db.dt), while more than half the other present sensors changed in this sample, and
    either the prediction moved more than ``stuck_sigmas`` sd plus the sensor's resolution (its
    smallest relative change so far) since it froze, or its relative sample-to-sample changes
    had averaged more than sd / 2 over at least as long before and it had changed on
    NOISY_CHANGES of those samples, is left out (stuck) until the value changes; then the sensors whose residual exceeds
    ``misfit_sigmas`` sd of the prediction are left out too, unless they are half the remaining
    ones or more (counting all that misfit), or have misfit on more than ``readmit`` samples in a row (its present, unstuck
    samples; default: never)."""

    def __init__(self, db: GainDatabase, bias=None, online: bool = False, zones=None,
                 health_hold: float = 3.0, misfit_sigmas: float = 12.0, stuck_sigmas: float = 4.0,
                 stuck_after: float = 2.0, readmit: int | None = None):
        from scipy.interpolate import RegularGridInterpolator

        self.db = db
        self.bias = bias or {}
        self.online = online
        self.zones = zones
        self.health_hold = health_hold
        ny = db.n("y")
        R = db.kalman["R"].reshape(-1, ny, ny)
        sd = np.sqrt(np.median(np.diagonal(R, axis1=1, axis2=2), axis=0)) / np.median(
            np.abs(db.trim["y"].reshape(-1, ny)), axis=0)
        self.misfit_gate, self.stuck_gate, self.sd = misfit_sigmas * sd, stuck_sigmas * sd, sd
        self.stuck_n = np.ceil(stuck_after / db.dt)
        self.readmit = np.inf if readmit is None else readmit
        ext = db.policy == "extrapolate"
        self.ext = ext

        def rgi(grid, values):
            return RegularGridInterpolator([a.values for a in grid.axes], values, method="linear",
                                           bounds_error=False, fill_value=None)
        self.trim = {k: rgi(db.trim_grid, db.trim[k]) for k in "xuyz"}
        self.ambient = None if db.ambient is None else {k: rgi(db.trim_grid, db.ambient.coef[k]) for k in "xuyz"}
        Vp = db.tuner["V_pinv"]
        nx, nq = db.n("x"), db.n("q")
        d = db.dynamics
        mats = {}
        for idx in np.ndindex(*db.dyn_grid.shape):
            Aa = np.block([[d["A"][idx], d["L"][idx] @ Vp], [np.zeros((nq, nx)), np.eye(nq)]])
            Ba = np.vstack([d["B"][idx], np.zeros((nq, db.n("u")))])
            Ca = np.hstack([d["C"][idx], d["M"][idx] @ Vp])
            Fa = np.hstack([d["F"][idx], d["N"][idx] @ Vp])
            for k, v in (("A", Aa), ("B", Ba), ("C", Ca), ("D", d["D"][idx]), ("F", Fa),
                         ("G", d["G"][idx]), ("K", db.kalman["K"][idx])):
                mats.setdefault(k, np.zeros(db.dyn_grid.shape + v.shape))[idx] = v
        for k in ("Q", "R", "P"):
            mats[k] = db.kalman[k]
        self.sensor_out = "K_out" in db.kalman and zones is None and not online
        if self.sensor_out:   # the gain without sensor j, where one exists
            for j in range(db.n("y")):
                if (db.kalman["out_status"][j] != OUT_NONE).any():
                    mats[f"K_out{j}"] = db.kalman["K_out"][j]
        self.mats = {k: rgi(db.dyn_grid, v) for k, v in mats.items()}
        self.tax = [db.names["p"].index(n) for n in db.trim_grid.names]
        self.dax = [db.names["p"].index(n) for n in db.dyn_grid.names]
        self.tlo = np.array([a.lo for a in db.trim_grid.axes])
        self.thi = np.array([a.hi for a in db.trim_grid.axes])
        self.dlo = np.array([a.lo for a in db.dyn_grid.axes])
        self.dhi = np.array([a.hi for a in db.dyn_grid.axes])

    def factor(self, kind, theta, delta):
        c = self.db.correction
        if c is None:
            return np.ones(self.db.n(kind))
        e = c.exponents[kind]
        return theta ** e[:, 0] * delta ** e[:, 1]

    def run(self, U, Y, S, TH, DE):
        """Same inputs as :meth:`pwl.estimator.Estimator.run_arrays`; NaN only in Y (a missing
        sensor: online, the update from the others; steady, one missing with its sensor-out gain;
        else no update; bias tables learn from complete updates only)."""
        db = self.db
        nx, nq = db.n("x"), db.n("q")
        corr = {n: e for k in "xuyz" for n, e in zip(db.names[k], (
            db.correction.exponents[k] if db.correction else np.zeros((db.n(k), 2))))}
        out = {o: [] for o in ("x_hat", "q_hat", "h_hat", "y_hat", "residual", "z_hat")
               + (("h_std",) if self.online else ())}
        xa = None
        q = np.zeros(nq)
        h_held = db.tuner["h_ref"].copy()
        ny = db.n("y")
        y_last, repeats, froze_at = np.full(ny, np.nan), np.zeros(ny), np.zeros(ny)
        change_sum, seen, changes, resolution = np.zeros(ny), np.zeros(ny), np.zeros(ny), np.full(ny, np.inf)
        misfit_run = np.zeros(ny)
        for k in range(U.shape[0]):
            th, de = TH[k], DE[k]
            p = np.empty(len(db.schedule))
            for j, (c, corrected, scale) in enumerate(db.schedule):
                v = S[k, j] * scale
                if corrected:
                    a, b = corr[c]
                    v = v / (th ** a * de ** b)
                p[j] = v
            pt, pd = p[self.tax], p[self.dax]
            if not self.ext:
                pt = np.clip(pt, self.tlo, self.thi)
                pd = np.clip(pd, self.dlo, self.dhi)
            tr = {n: f(pt)[0] for n, f in self.trim.items()}
            if self.ambient is not None:      # the trims on this day: + c1 dT + c2 dT^2
                a = db.ambient
                dT = float(ambient_offset(th * db.correction.T_std, p[db.names["p"].index(a.alt)],
                                          p[db.names["p"].index(a.mach)]))
                dT = float(np.clip(dT, -AMBIENT_REACH * a.span, AMBIENT_REACH * a.span))
                for n, f in self.ambient.items():
                    c = f(pt)[0]
                    tr[n] = tr[n] + dT * c[0] + dT * dT * c[1]
            M = {n: f(pd)[0] for n, f in self.mats.items()}
            if xa is None:
                xa = tr["x"].copy()
                P = M["P"]
            elif self.online:
                P = M["A"] @ P @ M["A"].T + M["Q"]
            xi = np.concatenate([xa - tr["x"], q])
            du = U[k] / self.factor("u", th, de) - tr["u"]
            xm = M["A"] @ xi + M["B"] @ du
            fy = self.factor("y", th, de)
            yh = tr["y"] + M["C"] @ xm + M["D"] @ du
            learn = []
            for c, (axes, names, vals, ratio) in self.bias.items():
                pb = np.array([p[db.names["p"].index(n)] for n in names])
                inside = all(a[0] <= v <= a[-1] for a, v in zip(axes, pb))
                pb = np.clip(pb, [a[0] for a in axes], [a[-1] for a in axes])
                w = node_weights(axes, pb)
                i = db.names["y"].index(c)
                yh[i] += w @ vals.reshape(-1)
                learn.append((i, w, vals, ratio, inside))
            r = Y[k] / fy - yh
            pred, res = yh * fy, Y[k] - yh * fy
            present = np.isfinite(r)
            seen += present
            same = present & (Y[k] == y_last)
            others_change = 2 * (present & ~same).sum() > present.sum() - 1
            moved = present & ~same & np.isfinite(y_last) & (Y[k] != 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                wander = np.where(moved, np.abs(Y[k] - y_last) / np.abs(Y[k]), 0.0)
            change_sum += wander
            changes += moved
            resolution = np.where(moved, np.minimum(resolution, wander), resolution)
            repeats = np.where(same, repeats + 1, np.where(present, 0.0, repeats))   # a gap keeps the run
            froze_at = np.where(present & ~same, pred, froze_at)
            y_last = np.where(present, Y[k], y_last)
            before = seen - repeats
            stuck = same & (repeats >= self.stuck_n) & (
                (repeats == np.inf) | others_change & (
                    (np.abs(pred - froze_at) > (self.stuck_gate + np.where(np.isinf(resolution), 0.0, resolution))
                     * np.abs(pred))
                    | (before >= self.stuck_n) & (change_sum > 0.5 * self.sd * before)
                    & (changes >= NOISY_CHANGES * before)))
            repeats[stuck] = np.inf       # stuck until the value changes
            have = present & ~stuck
            misfit = have & (np.abs(res) > self.misfit_gate * np.abs(pred))
            misfit_run = np.where(misfit, misfit_run + 1, np.where(have, 0.0, misfit_run))
            if 2 * misfit.sum() < have.sum():
                have &= ~(misfit & (misfit_run <= self.readmit))
            r = np.where(have, r, 0.0)
            for i, w, vals, ratio, inside in learn:
                if inside and have.all():
                    c2 = w @ w
                    pbar = (1 + np.sqrt(1 + 4 * ratio / c2)) / 2
                    vals.reshape(-1)[:] += pbar * w / (pbar * c2 + ratio) * r[i]
            out_j = int(np.flatnonzero(~have)[0]) if (~have).sum() == 1 else -1
            if out_j >= 0 and f"K_out{out_j}" in self.mats:   # every node around pd has that gain
                w = node_weights([a.values for a in db.dyn_grid.axes], pd)
                out_ok = bool(np.all(db.kalman["out_status"][out_j].reshape(-1)[w != 0] != OUT_NONE))
                ratio = db.kalman.get("out_h_ratio")
                hold = out_ok and ratio is not None and bool(
                    np.any(ratio[out_j].reshape(len(w), -1)[w != 0] > self.health_hold))
            else:
                out_ok = hold = False
            # steady, sensors missing and no stored gain for the set: the present sensors' gain
            # from the interpolated steady-state P and R (health held)
            subset = have.any() and not have.all() and not self.online and not out_ok and self.zones is None
            if not have.any() or (not have.all() and not self.online and not out_ok and not subset):
                K = np.zeros((len(xm), len(r)))          # no update
            elif subset:
                C, R, P0 = M["C"][have], M["R"][np.ix_(have, have)], M["P"]
                K = np.zeros((len(xm), len(r)))
                K[:, have] = np.linalg.solve(C @ P0 @ C.T + R, C @ P0).T
                hold = True
            elif self.online:
                C, R = M["C"][have], M["R"][np.ix_(have, have)]
                K = np.zeros((len(xm), len(r)))
                K[:, have] = np.linalg.solve(C @ P @ C.T + R, C @ P).T
                P = (np.eye(len(P)) - K[:, have] @ C) @ P
            elif not have.all():
                K = M[f"K_out{out_j}"]
            elif self.zones is not None:
                node = tuple(int(np.argmin(np.abs(a.values - v))) for a, v in zip(db.dyn_grid.axes, pd))
                K = self.zones.gains[self.zones.labels[node]]
            else:
                K = M["K"]
            xp = xm + K @ r
            if hold:                      # health held: the tuners keep their prediction too
                xp[nx:] = xm[nx:]
            z = tr["z"] + M["F"] @ xp + M["G"] @ du
            xa = tr["x"] + xp[:nx]
            q = xp[nx:]
            out["x_hat"].append(xa * self.factor("x", th, de))
            out["q_hat"].append(q.copy())
            if not hold:
                h_held = db.tuner["h_ref"] + db.tuner["V_pinv"] @ q
            out["h_hat"].append(h_held)
            out["y_hat"].append(yh * fy)
            out["residual"].append(np.where(present, res, np.nan))
            out["z_hat"].append(z * self.factor("z", th, de))
            if self.online:
                Vp = db.tuner["V_pinv"]
                out["h_std"].append(np.sqrt(np.diag(Vp @ P[nx:, nx:] @ Vp.T)))
        return {k: np.array(v) for k, v in out.items()}
