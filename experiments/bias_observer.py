"""Bias observer for a fast biased model and a slow, delayed, accurate sensor (seed 004).

The model output lambda_m is fast but biased (lambda = lambda_m + theta, eq. 3); the sensor sees the
truth delayed by tau and low-pass filtered (eq. 1). Steady-state Kalman observer (eqs. 7-11, 13)::

    x = [theta, lambda_f],  A = [[1, 0], [1 - a, a]],  B = [0, 1 - a]^T,  C = [0, 1]
    u_k = lambda_m[k - d],  d = round(tau / T)             (model delayed like the sensor)
    x_k|k-1 = A x_k-1 + B u_k                                eq. (10)
    e_k     = y_k - C x_k|k-1,   e_k := 0 when frozen        eq. (11a), (14)
    x_k     = x_k|k-1 + K e_k                                eq. (11b), K = K_inf computed offline

With the bias table Theta over the operating point p = (n, m_f):

    theta_k|k-1 = Theta_k-1(p[k - d])                        eq. (15): inputs delayed by tau
    Theta_k     = table update at p[k - d] towards theta_k   (learns from the filter's estimate)
    lambda_hat_k = lambda_m[k] + Theta_k(p[k])                eq. (16): current inputs

and without a table lambda_hat_k = lambda_m[k] + theta_k. The table update error is
theta_k - theta_k|k-1 = K_1 e_k, so a frozen step (e_k = 0) moves neither theta nor the table; the
lambda_f state keeps being predicted from the model (the prediction is never frozen).

Freezing rules (eq. 14; any true -> e_k = 0). Rates are backward differences over one sample,
in lambda^-1 units per second, compared by absolute value (the paper's text gives the signed
difference; a fall is as untrustworthy as a rise). A threshold of +inf (or -inf for the lower
bounds F4, F6) switches a rule off.

    F1  |e_k - e_k-1| / T          > F1   innovation rate: sensor-model mismatch in transients,
                                          spikes (the raw, unfrozen innovation is differenced)
    F2  |u_k - u_k-1| / T          > F2   rate of the (delayed) model input: fast transient in
                                          what the sensor is seeing now
    F3  |y_k - y_k-1| / T          > F3   sensor rate: spikes, fast transients
    F4  y_k                        < F4   sensor saturated (reads ~0.1 at high O2) or invalid
    F5  y_k                        > F5   sensor out of range (outliers)
    F6  lambda_hat_d               < F6   estimate range, low (the sensor cannot be trusted there)
    F7  lambda_hat_d               > F7   estimate range, high
        lambda_hat_d = u_k + theta_k|k-1: the a-priori estimate of the delayed lambda^-1, the
        quantity the sensor is measuring at step k (the paper writes lambda_hat without an index).

Two additions, both optional: ``hold`` keeps the freeze for that many seconds after the last
step on which a rule fired (the sensor lag spreads a transient over ~3 a/(1-a) samples and a
multi-sample spike is flat inside; hold = 0 is the paper's rule), and a NaN sensor reading
freezes the step (flagged). A NaN model sample: no prediction through it (the state holds), NaN
estimate for that step.

The kernel :func:`observe` runs over a whole log (or a chunk of one: state, delay line and search
hints carry over) with no per-step allocation; :class:`BiasObserver` holds the state and checks
input. The gain K is an argument: compute it offline (``linearize.bias.observer_gain``, which uses
the project's one steady-state gain formula); this module imports numpy, numba and pwl's grid,
interpolation and table kernels only.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numba import njit

from pwl.grid import locate
from pwl.interp import corner_weights
from pwl.tables import LAWS, count_ratio, table_predict, table_update

#: flag bits per step: F1..F7 -> bits 0..6
FLAG_F1, FLAG_F2, FLAG_F3, FLAG_F4, FLAG_F5, FLAG_F6, FLAG_F7 = (1 << i for i in range(7))
FLAG_HOLD = 1 << 7         # frozen only by the hold time after a rule fired
FLAG_NAN_SENSOR = 1 << 8   # sensor sample NaN: frozen
FLAG_NAN_MODEL = 1 << 9    # model sample NaN: no prediction, estimate NaN
FLAG_OUTSIDE = 1 << 10     # an operating point (delayed or current) left the table grid (clipped)
FLAG_FROZEN_MASK = (1 << 10) - 1   # any of these bits set: the step did not integrate

RULES = ("F1", "F2", "F3", "F4", "F5", "F6", "F7")

# layout of the state vector
_S_THETA, _S_LAMF, _S_EPREV, _S_UPREV, _S_YPREV, _S_HOLD, _S_POS, _S_STARTED = range(8)
STATE_SIZE = 8
# layout of the parameter vector
_P_A, _P_K1, _P_K2, _P_DT = range(4)
_P_F = 4           # F1..F7 at 4..10
_P_HOLD = 11       # hold, samples (float)
PARAM_SIZE = 12


@njit(cache=True, nogil=True)
def observe(lam_m, lam_s, n_eng, mf, par, hist, state,
            use_table, learn, values, counts, bp, off, strides, extrapolate, law, ratio, warmup,
            update_outside,
            idx_d, frac_d, wts_d, rows_d, idx_c, frac_c, wts_c, rows_c, point,
            out_hat, out_theta, out_lamf, out_bias, out_flags):
    """Run the bias observer over k samples; state, delay line, table and hints change in place.

    lam_m, lam_s, n_eng, mf (k,) float64: model lambda^-1, sensor reading, table scheduling inputs
    (speed, fuel). par (PARAM_SIZE,): a, K1, K2, T, F1..F7, hold (samples). hist (d + 1, 3): delay
    line of (lam_m, n, mf); state (STATE_SIZE,). Table (when use_table): values, counts flat
    row-major over the grid (bp, off, strides, extrapolate), update law code, ratio and ratio
    warm-up of :mod:`pwl.tables` (:func:`pwl.tables.count_ratio`, :func:`pwl.tables.table_update`);
    a delayed point outside the grid updates only if ``update_outside``. Work arrays:
    idx_*/frac_* (2,), wts_*/rows_* (4,), point (2,). Outputs (k,): estimate lambda_hat (eq. 16),
    filter bias theta_k (at the delayed point), filter lambda_f, bias used in the estimate, flags.
    Returns (frozen steps, table updates, steps whose delayed point was outside the grid).
    """
    a = par[_P_A]
    k1 = par[_P_K1]
    k2 = par[_P_K2]
    dt = par[_P_DT]
    hold = par[_P_HOLD]
    nh = hist.shape[0]
    frozen_count = 0
    n_updates = 0
    n_outside = 0
    for k in range(lam_m.shape[0]):
        flags = 0
        # --- delay line: write sample k, read sample k - d (the oldest slot)
        pos = int(state[_S_POS])
        if state[_S_STARTED] == 0.0:
            for j in range(nh):
                hist[j, 0] = lam_m[k]
                hist[j, 1] = n_eng[k]
                hist[j, 2] = mf[k]
        hist[pos, 0] = lam_m[k]
        hist[pos, 1] = n_eng[k]
        hist[pos, 2] = mf[k]
        dpos = pos + 1
        if dpos == nh:
            dpos = 0
        state[_S_POS] = dpos
        u = hist[dpos, 0]
        y = lam_s[k]
        # --- a-priori bias: the table at the delayed operating point (eq. 15) or the last estimate
        m_d = 0
        outside_d = False
        if use_table:
            point[0] = hist[dpos, 1]
            point[1] = hist[dpos, 2]
            if locate(bp, off, point, extrapolate, idx_d, frac_d) != 0:
                flags |= FLAG_OUTSIDE
                outside_d = True
                n_outside += 1
            m_d = corner_weights(idx_d, frac_d, strides, wts_d, rows_d)
            theta_prior = table_predict(values, wts_d, rows_d, m_d)
        else:
            theta_prior = state[_S_THETA]
        if state[_S_STARTED] == 0.0:
            # start in steady state: lambda_f equals the delayed estimate (or the reading)
            state[_S_THETA] = theta_prior
            state[_S_LAMF] = u + theta_prior
            if math.isfinite(y) and not math.isfinite(state[_S_LAMF]):
                state[_S_LAMF] = y
            state[_S_EPREV] = 0.0
            state[_S_UPREV] = u
            state[_S_YPREV] = y
            state[_S_HOLD] = 0.0
            state[_S_STARTED] = 1.0
            if math.isfinite(y) and math.isfinite(state[_S_LAMF]):
                state[_S_EPREV] = y - state[_S_LAMF]
        if not math.isfinite(u):
            # no model sample to predict with: hold the state, no integration
            flags |= FLAG_NAN_MODEL
            out_theta[k] = state[_S_THETA]
            out_lamf[k] = state[_S_LAMF]
            out_bias[k] = math.nan
            out_hat[k] = math.nan
            out_flags[k] = flags
            frozen_count += 1
            continue
        # --- prediction, eq. (10): lambda_f uses the previous posterior theta (row 2 of A)
        lamf_prior = (1.0 - a) * state[_S_THETA] + a * state[_S_LAMF] + (1.0 - a) * u
        lam_hat_d = u + theta_prior
        # --- innovation and freezing rules, eq. (11a), (14)
        fired = 0
        if math.isfinite(y):
            e = y - lamf_prior
            if abs(e - state[_S_EPREV]) > par[_P_F + 0] * dt:
                fired |= FLAG_F1
            if abs(y - state[_S_YPREV]) > par[_P_F + 2] * dt:
                fired |= FLAG_F3
            if y < par[_P_F + 3]:
                fired |= FLAG_F4
            if y > par[_P_F + 4]:
                fired |= FLAG_F5
            state[_S_EPREV] = e
            state[_S_YPREV] = y
        else:
            e = 0.0
            flags |= FLAG_NAN_SENSOR
        if math.isfinite(state[_S_UPREV]) and abs(u - state[_S_UPREV]) > par[_P_F + 1] * dt:
            fired |= FLAG_F2
        state[_S_UPREV] = u
        if lam_hat_d < par[_P_F + 5]:
            fired |= FLAG_F6
        if lam_hat_d > par[_P_F + 6]:
            fired |= FLAG_F7
        if fired != 0:
            state[_S_HOLD] = hold
        elif state[_S_HOLD] > 0.0:
            state[_S_HOLD] -= 1.0
            flags |= FLAG_HOLD
        flags |= fired
        if flags & FLAG_FROZEN_MASK:
            e = 0.0
            frozen_count += 1
        # --- update, eq. (11b)
        theta = theta_prior + k1 * e
        state[_S_THETA] = theta
        state[_S_LAMF] = lamf_prior + k2 * e
        if use_table and learn and e != 0.0 and (update_outside or not outside_d):
            r = count_ratio(counts, wts_d, rows_d, m_d, ratio, warmup)
            table_update(values, counts, wts_d, rows_d, m_d, theta - theta_prior, law, r, frac_d)
            n_updates += 1
        # --- final estimate, eq. (16)
        if use_table:
            point[0] = n_eng[k]
            point[1] = mf[k]
            if locate(bp, off, point, extrapolate, idx_c, frac_c) != 0:
                flags |= FLAG_OUTSIDE
            m_c = corner_weights(idx_c, frac_c, strides, wts_c, rows_c)
            bias = table_predict(values, wts_c, rows_c, m_c)
        else:
            bias = theta
        out_hat[k] = lam_m[k] + bias
        out_theta[k] = theta
        out_lamf[k] = state[_S_LAMF]
        out_bias[k] = bias
        out_flags[k] = flags
    return frozen_count, n_updates, n_outside


# ----------------------------------------------------------------------------------------------
# Python wrapper


@dataclass(frozen=True)
class FreezeRules:
    """Thresholds of eq. (14) (lambda^-1 units; rates per second) and the hold time (s).

    Defaults are for a lambda^-1 model and sensor at 50 Hz with noise of a few 1e-3 (see
    docs/bias-observer.md); ``FreezeRules.off()`` disables every rule.
    """

    e_rate: float = 1.0           # F1
    model_rate: float = 2.0       # F2
    sensor_rate: float = 1.0      # F3
    sensor_min: float = 0.12      # F4 (the sensor saturates at about 0.1)
    sensor_max: float = 1.2       # F5
    estimate_min: float = 0.12    # F6
    estimate_max: float = 1.0     # F7
    hold: float = 0.2             # s

    @classmethod
    def off(cls) -> "FreezeRules":
        inf = math.inf
        return cls(inf, inf, inf, -inf, inf, -inf, inf, 0.0)

    def array(self):
        """F1..F7 as float64 (7,)."""
        return np.array([self.e_rate, self.model_rate, self.sensor_rate, self.sensor_min,
                         self.sensor_max, self.estimate_min, self.estimate_max], dtype=np.float64)


@dataclass
class BiasResult:
    """Outputs of :meth:`BiasObserver.run` (arrays of the input length)."""

    lam_hat: np.ndarray
    theta: np.ndarray
    lam_f: np.ndarray
    bias: np.ndarray
    flags: np.ndarray

    @property
    def frozen(self) -> np.ndarray:
        return (self.flags & FLAG_FROZEN_MASK) != 0

    def rule_counts(self) -> dict:
        """Steps on which each rule fired (a step can count for several), plus hold/NaN/outside."""
        out = {r: int(np.count_nonzero(self.flags & (1 << i))) for i, r in enumerate(RULES)}
        out["hold"] = int(np.count_nonzero(self.flags & FLAG_HOLD))
        out["nan_sensor"] = int(np.count_nonzero(self.flags & FLAG_NAN_SENSOR))
        out["nan_model"] = int(np.count_nonzero(self.flags & FLAG_NAN_MODEL))
        out["outside"] = int(np.count_nonzero(self.flags & FLAG_OUTSIDE))
        out["frozen"] = int(np.count_nonzero(self.frozen))
        return out


class BiasObserver:
    """Steady-state bias observer with freezing rules and an optional bias table over (n, m_f).

    ``K`` (2,) is the steady-state update gain for the observer's ``a`` (compute it offline, e.g.
    ``linearize.bias.observer_gain(a, ratio)``). ``tau`` in seconds is rounded to whole samples of
    ``dt``. ``table``: an adaptive table (:class:`pwl.tables.AdaptiveTable`) on a 2-D grid whose
    axes are (speed, fuel); its values are learned in place. ``learn=False`` uses a table without
    changing it. Calls to :meth:`run` continue where the previous call stopped (chunked logs).
    """

    def __init__(self, K, a=0.96, tau=0.4, dt=0.02, rules: FreezeRules = FreezeRules(), table=None,
                 learn=True, theta0=0.0):
        K = np.asarray(K, dtype=np.float64).reshape(-1)
        if K.shape != (2,) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be 2 finite numbers, got {K}")
        if not 0.0 <= a < 1.0:
            raise ValueError(f"sensor pole a must be in [0, 1), got {a}")
        if not dt > 0 or not tau >= 0:
            raise ValueError(f"need dt > 0 and tau >= 0, got dt={dt}, tau={tau}")
        self.K, self.a, self.dt, self.rules, self.learn = K, float(a), float(dt), rules, bool(learn)
        self.delay = int(round(tau / dt))
        self.tau = self.delay * self.dt
        self.table = table
        if table is not None:
            grid = table.grid
            if grid.ndim != 2:
                raise ValueError(f"the bias table needs a 2-D grid (speed, fuel), got {grid}")
            if table.law not in ("exact", "paper"):
                raise ValueError(f"the bias table's law must be exact or paper, got {table.law!r}")
            if grid.policy == "error":
                raise ValueError("the bias table's grid policy must be clip or extrapolate "
                                 "(the observer runs over whole logs)")
        self.theta0 = float(theta0)
        self.reset()

    def params(self) -> np.ndarray:
        p = np.zeros(PARAM_SIZE)
        p[_P_A], p[_P_K1], p[_P_K2], p[_P_DT] = self.a, self.K[0], self.K[1], self.dt
        p[_P_F:_P_F + 7] = self.rules.array()
        p[_P_HOLD] = round(self.rules.hold / self.dt)
        return p

    def reset(self):
        """Forget the filter state and the delay line (the table keeps what it learned)."""
        self.state = np.zeros(STATE_SIZE)
        self.state[_S_THETA] = self.theta0
        self.hist = np.zeros((self.delay + 1, 3))
        self._idx = [np.zeros(2, np.int64) for _ in range(2)]
        self._frac = [np.zeros(2) for _ in range(2)]
        self._wts = [np.zeros(4) for _ in range(2)]
        self._rows = [np.zeros(4, np.int64) for _ in range(2)]
        self._point = np.zeros(2)

    @property
    def theta(self) -> float:
        return float(self.state[_S_THETA])

    def run(self, lam_m, lam_s, n=None, mf=None) -> BiasResult:
        """Observe a log (or the next chunk): model and sensor lambda^-1, speed and fuel (k,)."""
        lam_m = np.ascontiguousarray(lam_m, dtype=np.float64)
        k = lam_m.size
        lam_s = np.ascontiguousarray(lam_s, dtype=np.float64)
        if self.table is not None and (n is None or mf is None):
            raise ValueError("the bias table needs the operating point (n and mf)")
        n = np.zeros(k) if n is None else np.ascontiguousarray(n, dtype=np.float64)
        mf = np.zeros(k) if mf is None else np.ascontiguousarray(mf, dtype=np.float64)
        for name, x in (("lam_s", lam_s), ("n", n), ("mf", mf)):
            if x.shape != lam_m.shape:
                raise ValueError(f"{name} has shape {x.shape}, lam_m {lam_m.shape}")
        out = BiasResult(np.empty(k), np.empty(k), np.empty(k), np.empty(k), np.zeros(k, np.int32))
        t = self.table
        if t is not None:
            g = t.grid
            values, counts = _flat(t.values), _flat(t.counts)
            law, ratio, warmup = LAWS[t.law], float(t.ratio), float(t.ratio_warmup)
            bp, off, strides, ext, outside = g.bp, g.off, g.strides, g.extrapolate, t.update_outside
            learn = self.learn and t.enabled
        else:
            values, counts = np.zeros(1), np.zeros(1, np.int64)
            law, ratio, warmup, learn, outside = 0, 1.0, 0.0, False, False
            bp, off, strides, ext = np.zeros(2), np.array([0, 2], np.int64), np.ones(1, np.int64), False
        _, n_upd, n_out = observe(
            lam_m, lam_s, n, mf, self.params(), self.hist, self.state,
            t is not None, learn, values, counts, bp, off, strides, ext, law, ratio, warmup, outside,
            self._idx[0], self._frac[0], self._wts[0], self._rows[0],
            self._idx[1], self._frac[1], self._wts[1], self._rows[1], self._point,
            out.lam_hat, out.theta, out.lam_f, out.bias, out.flags)
        if t is not None:
            t.n_updates += int(n_upd)
            t.n_outside += int(n_out)
        return out

    def settings(self) -> dict:
        return {"K": self.K.tolist(), "a": self.a, "tau": self.tau, "dt": self.dt,
                "rules": asdict(self.rules), "learn": self.learn}


def _flat(a):
    """A flat view of a C-contiguous array (so the kernel writes the table's own memory)."""
    if not (isinstance(a, np.ndarray) and a.flags.c_contiguous):
        raise ValueError("the table's values/counts must be C-contiguous arrays")
    return a.reshape(-1)


def rms(x) -> float:
    """Root mean square over the finite entries."""
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan
