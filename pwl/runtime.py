"""The piecewise-linear steady-state Kalman filter over logged data (numba core).

Per step k (DESIGN.md section 3), everything in corrected units when the database has a
parameter correction:

    p_k        scheduling variables from the log (scale * channel, corrected where asked)
    trims, A_a..G_a, K   interpolated at p_k: one search per grid, shared corner weights
    dx'        = x_abs[k-1] - x_trim(p_k)              trim-shift adjustment (eq. 7)
    xi_minus   = A_a [dx'; q] + B_a du,   du = u_k - u_trim(p_k)
    y_hat      = y_trim + C_a xi_minus + D_a du
    xi_plus    = xi_minus + K (y_k - y_hat)           (skipped when a measurement is NaN)
    z_hat      = z_trim + F_a xi_plus + G_a du
    h_hat      = h_ref + V_pinv q        (after the loop, for all samples at once: report)

The filter keeps the absolute state x_abs = x_trim + dx, which is equivalent to the trim-shift
adjustment. Inputs, schedule channels or theta/delta that are NaN are held at their last valid
value (flagged); with the ambient terms a missing theta or delta is carried by the day instead
(:func:`_carry_day`); the first valid sample starts the filter at trim.

Flags per step (bit mask): see ``FLAG_*``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from .airdata import ambient_offset, inlet_pressure, inlet_temperature
from .byref import fields, record
from .covariance import correct, propagate_augmented
from .database import AMBIENT_REACH, OUT_NONE, DatabaseError, GainDatabase
from .errors import UsageError
from .grid import beyond, locate
from .interp import corner_weights, interp_rows
from .tables import table_predict, table_update

FLAG_NO_UPDATE = 1        # a measurement was NaN: prediction only
FLAG_HELD_INPUT = 2       # an input, schedule or theta/delta channel was NaN: last value held
FLAG_TRIM_OUTSIDE = 4     # the operating point left the trim grid (clipped or extrapolated)
FLAG_DYN_OUTSIDE = 8      # the operating point left the dynamics grid
FLAG_NOT_STARTED = 16     # no valid sample yet: outputs are NaN
FLAG_IMPLAUSIBLE = 32     # a channel was outside its plausible range: treated as missing (held
                          # input, or no update)
FLAG_MISFIT = 64          # a sensed output differed from its prediction by more than the misfit
                          # gate (MISFIT_SIGMAS sensor standard deviations): the model does not
                          # explain the sample (stuck or failed sensor, spike, unit mistake). While
                          # the misfitting sensors are fewer than half the present ones they are
                          # left out of the update like missing ones (FLAG_PARTIAL path); when
                          # most misfit, the model as a whole is off and all are used; a sensor
                          # that has misfit for Model.readmit_n steps in a row is used again (the
                          # filter's state, not the sensor, is then the likelier cause: left out,
                          # it could never come back)
MISFIT_SIGMAS = 12.0
FLAG_HEALTH = 128         # a health estimate left the plant's plausible health range (e.g. an
                          # efficiency 10 % better than new): the estimates cannot be trusted
FLAG_PARTIAL = 256        # some sensors were missing: the update used the others (steady gains:
                          # the stored gain without the one missing sensor; online: the reduced
                          # update); FLAG_NO_UPDATE is set instead when it could not
FLAG_HEALTH_HELD = 512    # the missing sensor is one the health estimates depend on (without it
                          # their steady-state standard deviation grows more than HEALTH_HOLD_RATIO
                          # times), or two or more are missing: the tuners and h_hat hold their
                          # last values (the states and outputs are still updated); they resume
                          # when the sensors are back
HEALTH_HOLD_RATIO = 3.0
FLAG_STUCK = 1024         # a sensor's value has not changed for STUCK_AFTER seconds and its
                          # prediction moved more than STUCK_SIGMAS sensor standard deviations
                          # meanwhile, or it was a noisy signal that stopped (:func:`_stuck`): a
                          # frozen sensor, left out of the update like a missing one from then
                          # until its value changes
STUCK_SIGMAS = 4.0
STUCK_AFTER = 2.0
STUCK_ROWS = 8            # the sensor record per sensor in the filter state: the stuck detector's 7
                          # rows (_stuck), then the steps it has misfit in a row (_predict_measurements)
SMALLEST_ROW = 6          # the record's row of each sensor's smallest relative change seen (_stuck)
MISFIT_ROW = 7
NEVER = 2 ** 62           # a step count never reached (Model.readmit_n: misfitting sensors stay out)
FLAG_SETTLING = 2048      # within the filter's settling time of its first valid sample, or of its
                          # first update after more steps without one than that
                          # (Model.settle_n steps): the estimates are still converging from q0 and
                          # the trims (Estimator(settle=...): 3 time constants of the database's
                          # slowest error dynamics); counted, not trusted (pwl.results.trusted)
FLAG_AIR_DATA = 4096      # pressure altitude, Mach and the inlet total pressure disagree (set after the
                          # step loop by the estimator, pwl.airdata): one of them is wrong; not trusted
NOISY_CHANGES = 0.9       # a noisy signal changes on at least this fraction of its samples
FLAG_TRIM_FILLED = 8192   # the trims were interpolated with weight on a node whose trim the build
                          # did not compute (filled or extrapolated from its line: /trim/status):
                          # not the plant's; not trusted
FLAG_FAR_OUTSIDE = 16384  # the operating point is farther outside the trim grid than FAR_OUTSIDE of
                          # an axis's span: no measurement update (the model clipped or extrapolated
                          # that far is not the plant's: an engine start from 0 rpm updated from it
                          # left the filter off for 3 minutes of the taxi and take-off); not trusted
FAR_OUTSIDE = 0.1



@njit(cache=True, nogil=True)
def _power(v, r, a):
    """v**a with the exponents of parameter correction (0, 1/2, 1, 3/2, ...) done without pow;
    r = sqrt(v)."""
    if a == 0.0:
        return 1.0
    if a == 1.0:
        return v
    if a == 0.5:
        return r
    if a == -0.5:
        return 1.0 / r
    if a == 1.5:
        return v * r
    return v ** a


@njit(cache=True, nogil=True)
def correction_factors(ex, theta, delta, fac):
    """fac[c] = theta^a_c delta^b_c for every distinct exponent pair ex[c] = (a_c, b_c)."""
    rt, rd = math.sqrt(theta), math.sqrt(delta)
    for c in range(ex.shape[0]):
        fac[c] = _power(theta, rt, ex[c, 0]) * _power(delta, rd, ex[c, 1])


@njit(cache=True, nogil=True, inline="always")
def _u(i):
    """An array index as unsigned: numba then leaves out the negative-index wraparound (a
    compare and select per access, which also keeps loops from vectorising)."""
    return np.uint64(i)


@njit(cache=True, nogil=True, inline="always")
def _factor(model, w, c):
    """The parameter-correction factor theta^a delta^b of channel c (order x u y z s: Model.cls)."""
    return w.fac[_u(model.cls[_u(c)])]


# ---- the kernel's records: each layout defined here once ---------------------------------------
class Inputs(NamedTuple):
    """Log samples of one call, raw units: U (n, nu), Y (n, ny), S (n, ns) schedule channels,
    TH, DE (n,) theta and delta (ones without parameter correction)."""
    U: np.ndarray
    Y: np.ndarray
    S: np.ndarray
    TH: np.ndarray
    DE: np.ndarray


class Model(NamedTuple):
    """The packed model (read only; :meth:`PackedModel.record`)."""
    trim_tab: np.ndarray   # (trim nodes, nt [+1] [+2 nt]) trims x u y z (nt values), corrected
                           # units [; 1 if filled] [; the ambient terms c1 (nt), c2 (nt)]
    dyn_tab: np.ndarray    # (dyn nodes, block) A_a..K (+ Q_a, R online): :func:`block_layout`
    dims: np.ndarray       # int64 [nx, nu, ny, nz, nq, nh]
    ex: np.ndarray         # (nc, 2) the distinct correction exponent pairs; pair 0 is (0, 0)
    cls: np.ndarray        # int64 (nx+nu+ny+nz+ns,) the pair of every channel, order x u y z s
    s_scale: np.ndarray    # (ns,) schedule scale
    s_corr: np.ndarray     # bool (ns,) schedule channel corrected
    s_state: np.ndarray    # int64 (ns,) the state a schedule channel measures (-1: none): its
                           # estimate stands in while the channel is missing
    online: bool           # online covariance: dyn_tab holds Q_a and R
    p_tab: np.ndarray      # (dyn nodes, na*na) steady P (online; else (1, 0))
    V_pinv: np.ndarray     # (nh, nq)
    z_gains: np.ndarray    # zone gains, flat column-major (na x ny) per zone, or empty
    z_labels: np.ndarray   # int64 zone of every dynamics node, or empty
    gate: np.ndarray       # (3, ny) misfit gate, stuck gate and sensor noise (standard deviation),
                           # fractions of the prediction
    stuck_n: int           # samples a sensor's value must repeat before the stuck gate applies
    settle_n: int          # steps from the first valid sample flagged FLAG_SETTLING
    readmit_n: int         # steps a sensor may misfit in a row and stay out of the update
    ko_tab: np.ndarray     # (dyn nodes * ny, ny * na) sensor-out gains, or (1, 0)
    ko_avail: np.ndarray   # int64 (dyn nodes * ny,) 0 none, 1 gain, 2 gain and health held
    sub_tab: np.ndarray    # (dyn nodes, na*na + ny*ny) steady a-priori P and R, row-major: the
                           # update from any subset of sensors (steady mode; else (1, 0))
    filled_col: int        # trim_tab's column that is 1 on filled nodes (FLAG_TRIM_FILLED); -1: none
    amb_col: int           # trim_tab's first ambient column (c1 of x..z, then c2); -1: none
    amb_p: np.ndarray      # int64 (2,) the scheduling variables pressure altitude (m) and Mach
    amb_k: np.ndarray      # (4,) T_std of theta (K), the largest |dT| used (K), P_std of delta (Pa), inlet recovery


class Grids(NamedTuple):
    """The trim and dynamics grids' locators (:class:`pwl.grid.Grid` bp, off, strides) and the
    scheduling variables each is on (t_pidx, d_pidx)."""
    t_bp: np.ndarray
    t_off: np.ndarray
    t_str: np.ndarray
    t_pidx: np.ndarray
    d_bp: np.ndarray
    d_off: np.ndarray
    d_str: np.ndarray
    d_pidx: np.ndarray
    extrapolate: bool


class Filter(NamedTuple):
    """The filter state, updated in place across calls: ``state`` (:func:`state_layout`), the
    grid search hints t_idx, d_idx, and the online covariance cov (na*na,; else empty)."""
    state: np.ndarray
    t_idx: np.ndarray
    d_idx: np.ndarray
    cov: np.ndarray


class Bias(NamedTuple):
    """Adaptive bias tables (the tuning element), nb = vals.shape[0] (0: none), all on one grid:
    chan (nb,) sensed channel of each; vals, counts (nb, nodes) corrected units; bp, off,
    strides, pidx (its axes among the scheduling variables), idx (search hint); share: the grid is
    the dynamics grid; law, ratio: the table gain (pwl.tables); learn (nb,) bool."""
    chan: np.ndarray
    vals: np.ndarray
    counts: np.ndarray
    bp: np.ndarray
    off: np.ndarray
    strides: np.ndarray
    pidx: np.ndarray
    idx: np.ndarray
    share: bool
    law: int
    ratio: float
    learn: np.ndarray


class Outputs(NamedTuple):
    """Per-sample outputs (n, .) in physical units, and flags (n,) int64."""
    x_hat: np.ndarray
    q_hat: np.ndarray
    y_hat: np.ndarray
    residual: np.ndarray
    z_hat: np.ndarray
    bias_hat: np.ndarray
    h_std: np.ndarray
    flags: np.ndarray


Kernel = record("Kernel", ["io", "model", "grids", "filt", "bias", "out", "work"],
                """The step loop's records (:class:`Inputs`, :class:`Model`, :class:`Grids`, :class:`Filter`,
                :class:`Bias`, :class:`Outputs`, :class:`Work`) by reference (:mod:`pwl.byref`).""")


class Work(NamedTuple):
    """Scratch arrays of :func:`step_loop` (:func:`workspace`)."""
    tw: np.ndarray       # interpolated trims
    dw: np.ndarray       # interpolated dynamics block
    t_frac: np.ndarray
    d_frac: np.ndarray
    t_wts: np.ndarray
    t_rows: np.ndarray
    d_wts: np.ndarray
    d_rows: np.ndarray
    p: np.ndarray        # scheduling variables
    pt: np.ndarray
    pd: np.ndarray
    du: np.ndarray
    xi: np.ndarray       # augmented state [dx; q]
    xm: np.ndarray       # its prediction
    res: np.ndarray      # residuals, corrected units
    yh: np.ndarray
    zh: np.ndarray
    fac: np.ndarray      # correction factor of every exponent pair
    thde: np.ndarray     # (2,) the theta, delta fac was computed for (-1: not yet)
    b_frac: np.ndarray
    b_wts: np.ndarray
    b_rows: np.ndarray
    pb: np.ndarray
    bias: np.ndarray     # the tables' predictions
    P: np.ndarray        # online covariance (a view of Filter.cov)
    Aa: np.ndarray
    Ca: np.ndarray
    Qa: np.ndarray
    Ra: np.ndarray
    PCt: np.ndarray
    Sw: np.ndarray
    Lw: np.ndarray
    Kw: np.ndarray
    AP: np.ndarray
    ko_rows: np.ndarray
    kw: np.ndarray
    pr: np.ndarray       # interpolated sub_tab row: steady P and R
    Ps: np.ndarray       # its P (na, na), a view of pr
    use: np.ndarray      # bool (ny,) the sensors this step's update uses


@njit(cache=True, nogil=True)
def block_layout(nx, nu, ny, nz, nq):
    """Offsets of A_a (state rows, row-major), B_a (state rows), C_a, D, F_a, G, K (column-major)
    and, online, Q_a, R (row-major) in a dynamics block, and its width without and with Q_a, R:
    (oA, oB, oC, oD, oF, oG, oK, oQ, oR, width, width_online). The tuner rows of A_a, B_a are
    [0 I], [0] and not stored."""
    na = nx + nq
    oA = 0
    oB = oA + nx * na
    oC = oB + nx * nu
    oD = oC + ny * na
    oF = oD + ny * nu
    oG = oF + nz * na
    oK = oG + nz * nu
    oQ = oK + na * ny
    oR = oQ + na * na
    return oA, oB, oC, oD, oF, oG, oK, oQ, oR, oQ, oR + ny * ny


@njit(cache=True, nogil=True)
def state_layout(nx, nq, nu, ns, ny):
    """Offsets in the filter state vector [x_abs (nx), q (nq), u_last (nu), s_last (ns),
    theta_last, delta_last, the sensor record (STUCK_ROWS x ny: :func:`_stuck`, MISFIT_ROW), steps since
    the first valid sample (0: not started), steps without a measurement update in a row]
    and its size: (ox, oq, ou, osl, oth, ode, oyl, ost, size)."""
    ou = nx + nq
    osl = ou + nu
    oth = osl + ns
    oyl = oth + 2
    ost = oyl + STUCK_ROWS * ny
    return 0, nx, ou, osl, oth, oth + 1, oyl, ost, ost + 2


@njit(cache=True, nogil=True, inline="always")
def _add_product(dw, o, rows, v, out):
    """out[:rows] += M v for the column-major matrix M stored at dw[o:] (rows x v.size): one
    contiguous axpy per column, four rows per pass. The columns are short (2-12 rows): a
    compiler-vectorised loop pays its alias checks and remainder per column, which cost more
    than the arithmetic (measured 19 ns per step slower on the demo database)."""
    n = _u(rows)
    for j in range(v.shape[0]):
        c = v[j]
        b = _u(o + j * rows)
        i = _u(0)
        while i + _u(4) <= n:
            out[i] += dw[b + i] * c
            out[i + _u(1)] += dw[b + i + _u(1)] * c
            out[i + _u(2)] += dw[b + i + _u(2)] * c
            out[i + _u(3)] += dw[b + i + _u(3)] * c
            i += _u(4)
        while i < n:
            out[i] += dw[b + i] * c
            i += _u(1)


@njit(cache=True, nogil=True, inline="always")
def _hold(v, state, o):
    """state[o] = v if v is valid (finite); returns FLAG_HELD_INPUT if it was not."""
    if np.isfinite(v):
        state[o] = v
        return 0
    return FLAG_HELD_INPUT


@njit(cache=True, nogil=True, inline="always")
def _hold_inputs(io, model, k, state, ou, osl, oth):
    """Inputs, schedule channels, theta and delta of sample k into the state, each held at its
    last valid value when NaN/Inf (theta, delta also when <= 0). With the ambient terms (altitude
    and Mach known) a missing theta or delta is carried by the day instead (:func:`_carry_day`).
    Returns the flags."""
    flags = 0
    for j in range(io.U.shape[1]):
        flags |= _hold(io.U[k, j], state, ou + j)
    th = io.TH[k] if io.TH[k] > 0.0 else np.nan
    de = io.DE[k] if io.DE[k] > 0.0 else np.nan
    carry = model.amb_col >= 0 and not (np.isfinite(th) and np.isfinite(de))
    day, recovery = 0.0, 0.0
    if carry:       # of the last sample's air data, before this one's
        alt, mach = _air_data(model, state, osl)
        day = ambient_offset(state[oth] * model.amb_k[0], alt, mach)
        recovery = state[oth + 1] * model.amb_k[2] / inlet_pressure(alt, mach)
    for j in range(io.S.shape[1]):
        flags |= _hold(io.S[k, j], state, osl + j)
    flags |= _hold(th, state, oth)
    flags |= _hold(de, state, oth + 1)
    if carry:
        _carry_day(model, state, osl, oth, th, de, day, recovery)
    return flags


@njit(cache=True, nogil=True, inline="always")
def _air_data(model, state, osl):
    """(pressure altitude m, Mach) of the held scheduling channels (the ambient terms' axes)."""
    a, m = model.amb_p[0], model.amb_p[1]
    return state[osl + a] * model.s_scale[a], state[osl + m] * model.s_scale[m]


@njit(cache=True, nogil=True, inline="always")
def _carry_day(model, state, osl, oth, th, de, day, recovery):
    """A missing theta or delta from this sample's altitude and Mach: the inlet temperature of the
    day's offset from ISA (``day``, K) and the inlet pressure of the pressure recovery
    (``recovery``: P2 over full ram recovery), both as the last valid sample had them (before any
    valid delta, the plant's recovery from the build: a stream without P2). Held at
    their last value through a climb, they read as a change of the engine (on the demo flight
    with P2 dead through the climb, Fn 69 % RMS off there; T2 dead, 0.76 %); carried, 0.20 % and
    0.14 %, as with every sensor (``tests/test_inlet_dropout.py``)."""
    alt, mach = _air_data(model, state, osl)
    if not np.isfinite(th):
        state[oth] = inlet_temperature(alt, mach, day) / model.amb_k[0]
    if not np.isfinite(de):
        if not np.isfinite(recovery):   # none valid yet: the plant's, as the build measured it (or NaN)
            recovery = model.amb_k[3]
        state[oth + 1] = recovery * inlet_pressure(alt, mach) / model.amb_k[2]


@njit(cache=True, nogil=True, inline="always")
def _nan_row(a, k):
    for j in range(a.shape[1]):
        a[k, j] = np.nan


@njit(cache=True, nogil=True, inline="always")
def _not_started(out, k):
    """Sample k before the first valid one: every output NaN."""
    _nan_row(out.x_hat, k)
    _nan_row(out.q_hat, k)
    _nan_row(out.y_hat, k)
    _nan_row(out.residual, k)
    _nan_row(out.z_hat, k)
    _nan_row(out.bias_hat, k)
    _nan_row(out.h_std, k)


@njit(cache=True, nogil=True, inline="always")
def _interpolate(io, model, grids, filt, w, k, osl, ost, cs):
    """p_k = scale * channel (corrected where asked; a missing channel that measures a state:
    the state's estimate, else its last valid value); trims into w.tw and the dynamics block
    into w.dw at p_k, one search per grid and shared corner weights. Returns (flags, number of
    dynamics corners m, the dynamics grid's out-of-range mask)."""
    flags = 0
    for j in range(w.p.shape[0]):
        i = model.s_state[j]
        if i >= 0 and not np.isfinite(io.S[k, j]) and filt.state[ost] != 0.0:
            v = filt.state[i] * _factor(model, w, i) * model.s_scale[j]   # the estimate, physical
        else:
            v = filt.state[_u(osl + j)] * model.s_scale[j]
        if model.s_corr[j]:
            v /= _factor(model, w, cs + j)
        w.p[j] = v
    for j in range(w.pt.shape[0]):
        w.pt[j] = w.p[grids.t_pidx[j]]
    for j in range(w.pd.shape[0]):
        w.pd[j] = w.p[grids.d_pidx[j]]
    if locate(grids.t_bp, grids.t_off, w.pt, grids.extrapolate, filt.t_idx, w.t_frac) != 0:
        flags |= FLAG_TRIM_OUTSIDE
    d_out = locate(grids.d_bp, grids.d_off, w.pd, grids.extrapolate, filt.d_idx, w.d_frac)
    if d_out != 0:
        flags |= FLAG_DYN_OUTSIDE
    m = corner_weights(filt.t_idx, w.t_frac, grids.t_str, w.t_wts, w.t_rows)
    interp_rows(model.trim_tab, w.t_wts, w.t_rows, m, w.tw)
    nt = model.filled_col       # the trim table's column that is 1 on filled nodes (-1: none filled)
    if nt >= 0 and w.tw[_u(nt)] > 1e-9:
        flags |= FLAG_TRIM_FILLED
    if model.amb_col >= 0:
        _ambient_trims(model, w)
    m = corner_weights(filt.d_idx, w.d_frac, grids.d_str, w.d_wts, w.d_rows)
    interp_rows(model.dyn_tab, w.d_wts, w.d_rows, m, w.dw)
    return flags, m, d_out


@njit(cache=True, nogil=True, inline="always")
def _ambient_trims(model, w):
    """trim += c1 dT + c2 dT^2 in w.tw (the interpolated ambient terms, :class:`pwl.database.Ambient`),
    dT the day's offset from ISA from theta and the operating point, held within +-amb_k[1] (not
    flagged: the estimate there is still the best the database has; a log that goes beyond is
    named in a warning, :meth:`pwl.estimator.Estimator.run`)."""
    dT = ambient_offset(w.thde[0] * model.amb_k[0], w.p[model.amb_p[0]], w.p[model.amb_p[1]])
    dT = min(max(dT, -model.amb_k[1]), model.amb_k[1])
    o = model.amb_col
    nt = (w.tw.shape[0] - o) // 2
    for j in range(nt):
        w.tw[j] += dT * (w.tw[_u(o + j)] + dT * w.tw[_u(o + nt + j)])


@njit(cache=True, nogil=True, inline="always")
def _bias_predict(bias, w, m, d_out, extrapolate):
    """Every bias table's value at p_k into w.bias. Returns (corners bm, out-of-range mask)."""
    if bias.share:  # the bias tables are on the dynamics grid: its weights serve
        for j in range(m):
            w.b_wts[j] = w.d_wts[j]
            w.b_rows[j] = w.d_rows[j]
        for j in range(w.d_frac.shape[0]):
            w.b_frac[j] = w.d_frac[j]
        bm, b_out = m, d_out
    else:  # their own grid: one more search, weights shared by all bias tables
        for j in range(bias.pidx.shape[0]):
            w.pb[j] = w.p[bias.pidx[j]]
        b_out = locate(bias.bp, bias.off, w.pb, extrapolate, bias.idx, w.b_frac)
        bm = corner_weights(bias.idx, w.b_frac, bias.strides, w.b_wts, w.b_rows)
    for c in range(bias.vals.shape[0]):
        w.bias[c] = table_predict(bias.vals[c], w.b_wts, w.b_rows, bm)
    return bm, b_out


@njit(cache=True, nogil=True, inline="always")
def _time_update(model, state, w, oA, oB, nx, nu, nq, ou, tu):
    """Trim-shift adjustment and time update: xi = [x_abs - x_trim(p_k); q],
    du = u_k - u_trim(p_k), xm = A_a xi + B_a du (tuners: random walk, A_a rows [0 I])."""
    na = nx + nq
    for j in range(nx):
        w.xi[j] = state[j] - w.tw[j]
    for j in range(nq):
        w.xi[nx + j] = state[_u(nx + j)]
    for j in range(nu):
        w.du[j] = state[_u(ou + j)] / _factor(model, w, nx + j) - w.tw[_u(tu + j)]
    for i in range(nx):
        s = 0.0
        a = _u(oA + i * na)
        for j in range(na):
            s += w.dw[a + _u(j)] * w.xi[j]
        b = _u(oB + i * nu)
        for j in range(nu):
            s += w.dw[b + _u(j)] * w.du[j]
        w.xm[i] = s
    for i in range(nx, na):
        w.xm[i] = w.xi[i]


@njit(cache=True, nogil=True, inline="always")
def _online_propagate(model, filt, w, first, m, oA, oQ, nx, na):
    """Online covariance time update P <- A_a P A_a^T + Q_a (the first step: the interpolated
    steady-state P)."""
    if first:
        interp_rows(model.p_tab, w.d_wts, w.d_rows, m, filt.cov)
        return
    for i in range(nx):
        for j in range(na):
            w.Aa[i, j] = w.dw[oA + i * na + j]
    for i in range(na):
        for j in range(na):
            w.Qa[i, j] = w.dw[oQ + i * na + j]
    propagate_augmented(w.Aa, w.P, w.Qa, w.AP)


@njit(cache=True, nogil=True, inline="always")
def _stuck(model, state, o, ny, i, yk, s, others_change):
    """Whether sensor i's value yk (present; prediction s, physical) is stuck: the same value
    for model.stuck_n samples or more while most other sensors still change (``others_change``:
    not a whole log at rest, e.g. a noise-free simulation at steady state) and, since it froze,
    either the prediction moved more than the stuck gate plus the sensor's resolution (its
    smallest change seen: a reading quantised coarser than its noise holds a value while the
    engine moves within one step) or it was a noisy signal that stopped (before it froze it
    changed on NOISY_CHANGES of its samples by more than half the sensor's noise, model.gate[2],
    on average, over at least as many samples; a sample-and-hold or coarsely quantised channel
    is not noisy); then stuck until the value changes. Sensor record in state[o:]: rows of ny
    [last value, repeats (inf once stuck), prediction when it came, sum of |change| / |value|,
    samples, changes, smallest |change| / |value|], reset to [NaN, 0, 0, 0, 0, 0, inf]."""
    d = _u(ny)
    j = _u(o + i)          # unsigned indices: no wraparound code (see _u)
    state[j + _u(4) * d] += 1.0
    last = state[j]
    if yk != last:
        if last == last and yk != 0.0:
            c = abs(yk - last) / abs(yk)
            state[j + _u(3) * d] += c
            state[j + _u(5) * d] += 1.0
            state[j + _u(SMALLEST_ROW) * d] = min(state[j + _u(SMALLEST_ROW) * d], c)
        state[j] = yk
        state[j + d] = 0.0
        state[j + _u(2) * d] = s
        return False
    state[j + d] += 1.0
    rep = state[j + d]
    if rep < model.stuck_n:
        return False
    before = state[j + _u(4) * d] - rep
    res = state[j + _u(SMALLEST_ROW) * d]
    if rep == np.inf or (others_change and (
            abs(s - state[j + _u(2) * d]) > (model.gate[1, i] + (res if res < np.inf else 0.0)) * abs(s)
            or (before >= model.stuck_n and state[j + _u(3) * d] > 0.5 * model.gate[2, i] * before
                and state[j + _u(5) * d] >= NOISY_CHANGES * before))):
        state[j + d] = np.inf
        return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _predict_measurements(io, model, bias, state, out, w, k, oC, oD, ny, ty, cy, oyl, blind):
    """y_hat = y_trim + C_a xm + D du (+ the bias tables), residuals (corrected units into w.res,
    physical into the outputs; NaN for a missing sensor; every sensor missing when ``blind``: the
    operating point far outside the trim grid), the stuck detector and the misfit gate:
    w.use[i] is False for a missing or stuck sensor and, while they are fewer than half the
    present ones, for a misfitting one (its residual is still reported) that has not misfit for
    more than model.readmit_n steps in a row (counted in the sensor record's MISFIT_ROW). Returns
    (flags, number of sensors left out, the last one left out)."""
    flags = 0
    for i in range(ny):
        w.yh[i] = w.tw[_u(ty + i)]
    _add_product(w.dw, oC, ny, w.xm, w.yh)
    _add_product(w.dw, oD, ny, w.du, w.yh)
    for c in range(bias.vals.shape[0]):
        w.yh[bias.chan[c]] += w.bias[c]
    n_miss = 0
    n_mis = 0        # misfitting sensors
    n_new = 0        # of which misfitting for at most readmit_n steps in a row
    n_present = 0
    n_changed = 0
    for i in range(ny):
        if np.isfinite(io.Y[k, i]) and not blind:
            n_present += 1
            n_changed += io.Y[k, i] != state[_u(oyl + i)]
    for i in range(ny):
        s = w.yh[i] * _factor(model, w, cy + i)
        yk = np.nan if blind else io.Y[k, i]
        w.use[i] = np.isfinite(yk)      # NaN or +-Inf: no update from this sensor
        out.y_hat[k, i] = s
        if not w.use[i]:
            n_miss += 1
            w.res[i] = 0.0
            out.residual[k, i] = np.nan
            continue
        w.res[i] = yk / _factor(model, w, cy + i) - w.yh[i]
        r = yk - s
        out.residual[k, i] = r
        if _stuck(model, state, oyl, ny, i, yk, s, 2 * n_changed > n_present - 1):
            flags |= FLAG_STUCK
            w.use[i] = False
            w.res[i] = 0.0
            n_miss += 1
            continue
        run = _u(oyl + i) + _u(MISFIT_ROW) * _u(ny)
        if abs(r) > model.gate[0, i] * abs(s):
            flags |= FLAG_MISFIT
            state[run] += 1.0
            n_mis += 1
            n_new += state[run] <= model.readmit_n
        else:
            state[run] = 0.0
    exclude = n_new > 0 and 2 * n_mis < ny - n_miss
    n_out = n_miss + (n_new if exclude else 0)
    miss = 0
    if n_out > 0:   # (the common step has every sensor: no second pass)
        for i in range(ny):
            if (w.use[i] and exclude and abs(out.residual[k, i]) > model.gate[0, i] * abs(out.y_hat[k, i])
                    and state[_u(oyl + i) + _u(MISFIT_ROW) * _u(ny)] <= model.readmit_n):
                w.use[i] = False
                w.res[i] = 0.0
            if not w.use[i]:
                miss = i
    return flags, n_out, miss


# how a step's update gain is made (:func:`_gain_choice`)
GAIN_FULL, GAIN_ONLINE, GAIN_OUT, GAIN_SUBSET, GAIN_NONE = 0, 1, 2, 3, 4


@njit(cache=True, nogil=True, inline="always")
def _gain_choice(model, w, m, n_miss, miss, ny):
    """How the update goes on with ``n_miss`` sensors missing (the last one ``miss``). Returns
    (flags, GAIN_*): all present, the stored or online gain (GAIN_FULL); online, the reduced
    update of the present sensors (GAIN_ONLINE, FLAG_PARTIAL); steady, one sensor out with its
    stored gain at every corner of non-zero weight (GAIN_OUT, FLAG_PARTIAL, + FLAG_HEALTH_HELD
    where the health estimates need it); else the update of the present sensors from the
    interpolated steady-state P and R (GAIN_SUBSET, FLAG_PARTIAL | FLAG_HEALTH_HELD: how well
    health is observed without them is unknown); else none (GAIN_NONE, FLAG_NO_UPDATE)."""
    if n_miss == 0:
        return 0, GAIN_FULL
    if n_miss == ny:
        return FLAG_NO_UPDATE, GAIN_NONE
    if model.online:
        return FLAG_PARTIAL, GAIN_ONLINE
    if n_miss == 1 and model.ko_tab.shape[1] > 0:
        ok, hold = True, False
        for c in range(m):
            if w.d_wts[c] != 0.0:
                a = model.ko_avail[w.d_rows[c] * ny + miss]
                ok &= a != 0
                hold |= a == 2
        if ok:
            return FLAG_PARTIAL | (FLAG_HEALTH_HELD if hold else 0), GAIN_OUT
    if model.sub_tab.shape[1] > 0:
        return FLAG_PARTIAL | FLAG_HEALTH_HELD, GAIN_SUBSET
    return FLAG_NO_UPDATE, GAIN_NONE


@njit(cache=True, nogil=True, inline="always")
def _subset_gain(w, P, R, oR, oC, oK, ny, na):
    """The Kalman gain of the sensors in use (w.use) from the covariance P (na, na) and the
    row-major R stored at R[oR:], into the dynamics block's K (columns of missing sensors zero),
    and P <- P(k|k). Returns False when C P C^T + R is not positive definite (no update)."""
    mo = 0
    for i in range(ny):
        if w.use[i]:
            for j in range(na):
                w.Ca[mo, j] = w.dw[oC + j * ny + i]
            mi = 0
            for j in range(ny):
                if w.use[j]:
                    w.Ra[mo, mi] = R[oR + i * ny + j]
                    mi += 1
            mo += 1
    if not correct(P, w.Ca[:mo], w.Ra[:mo, :mo], w.PCt[:, :mo], w.Sw[:mo, :mo], w.Lw[:mo, :mo],
                   w.Kw[:, :mo]):
        return False
    mi = 0
    for j in range(ny):
        present = w.use[j]
        for i in range(na):
            w.dw[oK + j * na + i] = w.Kw[i, mi] if present else 0.0
        if present:
            mi += 1
    return True


@njit(cache=True, nogil=True, inline="always")
def _sensor_out_gain(model, w, m, miss, oK, ny, na):
    """Steady gains, sensor ``miss`` out: its stored gain, interpolated with the dynamics
    weights, replaces K in the dynamics block."""
    for c in range(m):
        w.ko_rows[c] = w.d_rows[c] * ny + miss
    interp_rows(model.ko_tab, w.d_wts, w.ko_rows, m, w.kw)
    for i in range(na * ny):
        w.dw[oK + i] = w.kw[i]


@njit(cache=True, nogil=True, inline="always")
def _measurement_update(model, grids, filt, w, update, oK, nx, na, ny, hold_q):
    """xi = xm + K res: K interpolated (or chosen above), or the zone gain of the nearest
    dynamics node; xi = xm without an update; with ``hold_q`` the tuners keep their prediction
    (the health estimates are held: the states alone are updated)."""
    for i in range(na):
        w.xi[i] = w.xm[i]
    if not update:
        return
    if model.z_gains.shape[0] > 0:
        node = 0
        for j in range(w.d_frac.shape[0]):
            node += (filt.d_idx[j] + (1 if w.d_frac[j] >= 0.5 else 0)) * grids.d_str[j]
        _add_product(model.z_gains, model.z_labels[node] * na * ny, na, w.res, w.xi)
    else:
        _add_product(w.dw, oK, na, w.res, w.xi)
    if hold_q:
        for i in range(nx, na):
            w.xi[i] = w.xm[i]


@njit(cache=True, nogil=True, inline="always")
def _outputs(model, state, out, w, k, oF, oG, nx, nq, nz, tz, cz):
    """z_hat = z_trim + F_a xi + G du; x_abs = x_trim + dx and q into the state; physical
    units out; online, the health standard deviations from P(k|k)."""
    for i in range(nz):
        w.zh[i] = w.tw[_u(tz + i)]
    _add_product(w.dw, oF, nz, w.xi, w.zh)
    _add_product(w.dw, oG, nz, w.du, w.zh)
    for i in range(nz):
        out.z_hat[k, i] = w.zh[i] * _factor(model, w, cz + i)
    for j in range(nx):
        xa = w.tw[j] + w.xi[j]
        state[j] = xa
        out.x_hat[k, j] = xa * _factor(model, w, j)
    for j in range(nq):
        state[_u(nx + j)] = w.xi[nx + j]
        out.q_hat[k, j] = w.xi[nx + j]
    if model.online and out.h_std.shape[1] > 0:   # sqrt(diag(V_pinv P_qq V_pinv^T))
        Vp = model.V_pinv
        for i in range(Vp.shape[0]):
            v = 0.0
            for j in range(nq):
                a = 0.0
                for c in range(nq):
                    a += w.P[nx + j, nx + c] * Vp[i, c]
                v += Vp[i, j] * a
            out.h_std[k, i] = math.sqrt(max(v, 0.0))


@njit(cache=True, nogil=True, inline="always")
def _sizes(io, model, bias):
    """The sizes and offsets every step uses, computed once per call (loads from the records
    inside the loop are not hoisted out of it: the compiler cannot tell they are not written)."""
    nx, nu, ny, nz, nq = model.dims[0], model.dims[1], model.dims[2], model.dims[3], model.dims[4]
    return (nx, nu, ny, nz, nq, io.S.shape[1], bias.vals.shape[0]) + block_layout(nx, nu, ny, nz, nq) \
        + state_layout(nx, nq, nu, io.S.shape[1], ny)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"}, _nrt=False)
def step_loop(kern):
    """The step loop of :func:`filter_loop` over the :class:`Kernel` ``kern`` (its records, plus the workspace), one
    helper per line of the equations in the module docstring. Also the stream's step
    (:class:`pwl.streaming.Stream`, one row). The body is written in the loop: as a function of
    its own inlined by numba (``inline="always"``) it took the kernel's compilation from 50 to
    80 s, and its own compilation for streaming another 77 s.

    Compiled without numba's reference counting (``_nrt=False``): the inlined helpers take
    arrays, and the atomic increments and decrements of their reference counts were a fifth
    of the time per step (perf; 418 -> 360 ns on the demo flight). It also makes any
    allocation in the loop a compile error."""
    io, model, grids, filt, bias, out, w = fields(kern)
    sizes = _sizes(io, model, bias)
    for k in range(io.U.shape[0]):
        nx, nu, ny, nz, nq, ns, nb, oA, oB, oC, oD, oF, oG, oK, oQ, oR, _, _, \
            ox, oq, ou, osl, oth, ode, oyl, ost, _ = sizes
        na = nx + nq
        tu, ty, tz = nx, nx + nu, nx + nu + ny                    # trims: x u y z
        cy, cz, cs = nx + nu, nx + nu + ny, nx + nu + ny + nz      # channel classes: x u y z s
        state = filt.state
        flags = out.flags[k] | _hold_inputs(io, model, k, state, ou, osl, oth)   # + FLAG_IMPLAUSIBLE of screen()
        ok = True
        for j in range(ou, oyl):
            ok &= state[j] == state[j]
        if not ok:  # nothing valid yet to predict from
            out.flags[k] = flags | FLAG_NOT_STARTED
            _not_started(out, k)
            continue
        if state[oth] != w.thde[0] or state[ode] != w.thde[1]:   # w.fac: theta^a delta^b
            w.thde[0], w.thde[1] = state[oth], state[ode]
            correction_factors(model.ex, state[oth], state[ode], w.fac)
        f, m, d_out = _interpolate(io, model, grids, filt, w, k, osl, ost, cs)
        blind = (f & FLAG_TRIM_OUTSIDE) != 0 and beyond(grids.t_bp, grids.t_off, w.pt, FAR_OUTSIDE)
        if blind:
            f |= FLAG_FAR_OUTSIDE
        flags |= f
        bm, b_out = 0, 0
        if nb > 0:
            bm, b_out = _bias_predict(bias, w, m, d_out, grids.extrapolate)
        first = state[ost] == 0.0
        if first:  # start at trim on the first valid sample
            for j in range(nx):
                state[ox + j] = w.tw[j]
        state[ost] += 1.0
        if state[ost] <= model.settle_n:
            flags |= FLAG_SETTLING
        if model.online:
            _online_propagate(model, filt, w, first, m, oA, oQ, nx, na)
        _time_update(model, state, w, oA, oB, nx, nu, nq, ou, tu)
        f, n_miss, miss = _predict_measurements(io, model, bias, state, out, w, k, oC, oD, ny, ty, cy, oyl, blind)
        part, how = _gain_choice(model, w, m, n_miss, miss, ny)
        flags |= f | part
        if nb > 0:  # the bias tables learn from complete updates only
            for c in range(nb):
                out.bias_hat[k, c] = w.bias[c] * _factor(model, w, cy + bias.chan[c])
                if n_miss == 0 and b_out == 0 and bias.learn[c]:
                    table_update(bias.vals[c], bias.counts[c], w.b_wts, w.b_rows, bm,
                                 w.res[bias.chan[c]], bias.law, bias.ratio, w.b_frac)
        update = how != GAIN_NONE
        if model.online and update:  # the gain from P replaces the interpolated one
            update = _subset_gain(w, w.P, w.dw, oR, oC, oK, ny, na)
        elif how == GAIN_OUT:        # the stored gain without the missing sensor
            _sensor_out_gain(model, w, m, miss, oK, ny, na)
        elif how == GAIN_SUBSET:     # the present sensors' gain from the steady P and R
            interp_rows(model.sub_tab, w.d_wts, w.d_rows, m, w.pr)
            update = _subset_gain(w, w.Ps, w.pr, na * na, oC, oK, ny, na)
        if not update:
            flags = (flags & ~(FLAG_PARTIAL | FLAG_HEALTH_HELD)) | FLAG_NO_UPDATE
            state[ost + 1] += 1.0
        else:
            if state[ost + 1] > model.settle_n:   # back from an outage longer than the settling time
                state[ost] = 1.0                  # (an engine restarted, a sensor bus back): settle again
                flags |= FLAG_SETTLING
            state[ost + 1] = 0.0
        _measurement_update(model, grids, filt, w, update, oK, nx, na, ny, (flags & FLAG_HEALTH_HELD) != 0)
        _outputs(model, state, out, w, k, oF, oG, nx, nq, nz, tz, cz)
        out.flags[k] = flags
    return io.U.shape[0]


@njit(cache=True, nogil=True)
def filter_loop(io, model, grids, filt, bias, out):
    """Run the filter over the n samples of ``io`` (:class:`Inputs`); ``filt`` and the bias
    tables are updated in place (chunkable); outputs into ``out`` (:class:`Outputs`), whose
    flags hold the flags of :func:`screen` on entry. Returns n.

    Records: :class:`Model` the packed database, :class:`Grids` the trim and dynamics grids,
    :class:`Filter` the filter state, :class:`Bias` the adaptive bias tables, each field's shape
    and units in its definition.

    Bias tables (the tuning element; nb = bias.vals.shape[0], 0 for none): each step their
    prediction is added to the predicted measurement (the bias is pre-positioned at the
    operating point) and, when the point is inside the table grid and the step has a complete
    measurement update, every table with learn[c] learns from its channel's innovation with the
    steady-state table gain (law, ratio; pwl.tables). bias_hat (n, nb) in physical units.

    Online covariance (``model.online``; the full Kalman filter of the piecewise-linear model, an
    EKF whose Jacobians are the interpolated matrices): the dynamics blocks also hold Q_a and R;
    filt.cov (na*na,) is the error covariance P (a posteriori between steps), started from the
    interpolated steady-state P of model.p_tab on the first valid sample. Each step P <- A_a P
    A_a^T + Q_a, then the gain and P(k|k) from :func:`pwl.covariance.correct` replace the
    interpolated gain; h_std (n, nh) gets sqrt(diag(V_pinv P_qq V_pinv^T)) unless it has no
    columns.

    Missing values: NaN or +-Inf (and theta, delta <= 0) inputs, schedule and theta/delta values
    are held at their last valid value (FLAG_HELD_INPUT). Values outside their plausible range
    were turned into NaN before, by :func:`screen`.

    Missing sensors (NaN/Inf in Y; FLAG_PARTIAL when the update goes on without them): online,
    the update uses the rows of the present sensors (any subset); steady gains, one missing sensor
    j takes the gain without it, interpolated with the dynamics weights from model.ko_tab (row
    node * ny + j, column-major like K, column j zero), when every corner node of non-zero weight
    has one (model.ko_avail non-zero; 2: and the health estimates hold, FLAG_HEALTH_HELD, see
    :func:`report`); else (two or more missing, no sensor-out gains, zone gains) no update
    (FLAG_NO_UPDATE).

    Sensors that lie (:func:`_predict_measurements`): a stuck sensor (:func:`_stuck`,
    FLAG_STUCK) and, while they are fewer than half the present ones, sensors whose residual
    exceeds model.gate[0] of the prediction (FLAG_MISFIT) are left out of the update as if they
    were missing; their residuals are still reported.

    Zone gains (model.z_gains non-empty; :mod:`linearize.zones` database zones): the gain is
    picked, not interpolated: the zone label of the dynamics node nearest to the operating point
    (per axis the closer breakpoint) selects the centroid gain (column-major, na x ny); the
    dynamics blocks then hold no K.
    """
    return step_loop(Kernel(io, model, grids, filt, bias, out, workspace(io.S.shape[1], model, grids, filt, bias)))


@njit(cache=True, nogil=True)
def workspace(ns, model, grids, filt, bias):
    """The :class:`Work` arrays of :func:`step_loop` for ns schedule channels. Allocated once per
    :func:`filter_loop` call, or once per :class:`pwl.streaming.Stream`."""
    nx, nu, ny, nz, nq = model.dims[0], model.dims[1], model.dims[2], model.dims[3], model.dims[4]
    na = nx + nq
    nt = grids.t_pidx.shape[0]
    nd = grids.d_pidx.shape[0]
    nb = bias.vals.shape[0]
    nbd = bias.pidx.shape[0]
    no = na if model.online else 0    # online-covariance work arrays (empty otherwise)
    ro = nx if model.online else 0
    sub = model.sub_tab.shape[1] > 0   # steady update from any subset of sensors
    ng = na if model.online or sub else 0    # the subset gain's work arrays
    mo = ny if model.online or sub else 0
    ns_ = na if sub else 0
    pr = np.empty(model.sub_tab.shape[1])
    return Work(np.empty(model.trim_tab.shape[1]), np.empty(model.dyn_tab.shape[1]),
                np.empty(nt), np.empty(nd), np.empty(1 << nt), np.empty(1 << nt, dtype=np.int64),
                np.empty(1 << nd), np.empty(1 << nd, dtype=np.int64),
                np.empty(ns), np.empty(nt), np.empty(nd), np.empty(nu), np.empty(na), np.empty(na),
                np.empty(ny), np.empty(ny), np.empty(nz), np.ones(model.ex.shape[0]), np.full(2, -1.0),
                np.empty(nbd), np.empty(1 << nbd), np.empty(1 << nbd, dtype=np.int64), np.empty(nbd),
                np.zeros(max(nb, 1)), filt.cov[:no * no].reshape((no, no)),
                np.empty((ro, no)), np.empty((mo, ng)), np.empty((no, no)), np.empty((mo, mo)),
                np.empty((ng, mo)), np.empty((mo, mo)), np.empty((mo, mo)), np.empty((ng, mo)),
                np.empty((ro, no)), np.empty(1 << nd, dtype=np.int64), np.empty(model.ko_tab.shape[1]),
                pr, pr[:ns_ * ns_].reshape((ns_, ns_)), np.empty(ny, dtype=np.bool_))


@njit(cache=True, nogil=True, inline="always")
def _in_range(v, lim, c):
    """v inside column c's plausible range lim[:, c] (False for NaN; no branch)."""
    return (lim[0, c] <= v) & (v <= lim[1, c])


@njit(cache=True, nogil=True, inline="always")
def _screen_value(v, lim, c, chan_count):
    """Screen one value of column c (see :func:`screen`); its flag bits."""
    if _in_range(v, lim, c):
        return 0
    chan_count[0, c] += 1
    if not np.isfinite(v):
        return 0
    chan_count[1, c] += 1
    return FLAG_IMPLAUSIBLE


@njit(cache=True, nogil=True, inline="always")
def _block_in(A, k, lim, c0):
    """Every value of row k of A inside its column's range (see :func:`screen`)."""
    ok = True
    for j in range(A.shape[1]):
        ok &= _in_range(A[k, j], lim, c0 + j)
    return ok


@njit(cache=True, nogil=True, inline="always")
def _screen_block(A, k, lim, c0, chan_count):
    """Screen row k of A (n, m) whose columns are c0.. of lim/chan_count (see :func:`screen`)."""
    f = 0
    for j in range(A.shape[1]):
        f |= _screen_value(A[k, j], lim, c0 + j, chan_count)
    return f


@njit(cache=True, nogil=True, _nrt=False)
def screen(U, Y, S, TH, DE, lim, chan_count, flags):
    """The plausibility pass before :func:`filter_loop`: U (n, nu), Y (n, ny), S (n, ns), TH, DE
    (n,) as the filter gets them; lim (2, nu+ny+ns+2) the plausible [lo, hi] of every column
    (finite: +-the largest float for none, so NaN and +-Inf fail). Counts every column's missing
    values (outside its range, NaN or +-Inf) in chan_count[0] and the implausible ones (finite
    but outside) in chan_count[1] ((2, nu+ny+ns+2) int64, accumulated); writes flags (n,):
    FLAG_IMPLAUSIBLE on the samples with an implausible value, else 0. Returns the number of
    such samples: when there are any, blank them (:func:`blank_implausible`, on copies of the
    caller's arrays) before the filter.
    A pass of its own: the step loop stays short (a range test per channel in it cost ~10 %)."""
    nu, ny, ns = U.shape[1], Y.shape[1], S.shape[1]
    c = nu + ny + ns
    bad = 0
    for k in range(U.shape[0]):
        if _block_in(U, k, lim, 0) & _block_in(Y, k, lim, nu) & _block_in(S, k, lim, nu + ny) \
                & _in_range(TH[k], lim, c) & _in_range(DE[k], lim, c + 1):
            flags[k] = 0    # the common row, tested without a branch per value
            continue
        f = _screen_block(U, k, lim, 0, chan_count) | _screen_block(Y, k, lim, nu, chan_count) \
            | _screen_block(S, k, lim, nu + ny, chan_count) \
            | _screen_value(TH[k], lim, c, chan_count) | _screen_value(DE[k], lim, c + 1, chan_count)
        flags[k] = f
        if f:
            bad += 1
    return bad


@njit(cache=True, nogil=True, inline="always")
def _blank_block(A, k, lim, c0):
    for j in range(A.shape[1]):
        if not _in_range(A[k, j], lim, c0 + j):
            A[k, j] = np.nan


@njit(cache=True, nogil=True, _nrt=False)
def blank_implausible(U, Y, S, TH, DE, lim):
    """NaN, in place, for every value of U, Y, S, TH, DE outside its column's range in lim (see
    :func:`screen`): the filter then treats it as missing (NaN and +-Inf already are)."""
    nu, ny, ns = U.shape[1], Y.shape[1], S.shape[1]
    c = nu + ny + ns
    for k in range(U.shape[0]):
        _blank_block(U, k, lim, 0)
        _blank_block(Y, k, lim, nu)
        _blank_block(S, k, lim, nu + ny)
        if not _in_range(TH[k], lim, c):
            TH[k] = np.nan
        if not _in_range(DE[k], lim, c + 1):
            DE[k] = np.nan


@njit(cache=True, nogil=True)
def spike_mask(a, span, width, fraction, out):
    """out (n, k) bool: the values of a (n, k) further than fraction * span[j] from the median of
    their centred window of 2 * width + 1 samples (cut at the ends, NaN left out; the mean of the
    two middle values of an even count). :func:`pwl.estimator.spikes` documents why."""
    n, k = a.shape
    buf = np.empty(2 * width + 1)
    for j in range(k):
        tol = fraction * span[j]
        for i in range(n):
            m = 0
            for t in range(max(0, i - width), min(n, i + width + 1)):
                v = a[t, j]
                if v == v:          # insertion into the sorted buf[:m]
                    p = m
                    while p > 0 and buf[p - 1] > v:
                        buf[p] = buf[p - 1]
                        p -= 1
                    buf[p] = v
                    m += 1
            if m == 0:
                out[i, j] = False
                continue
            med = buf[m // 2] if m % 2 else 0.5 * (buf[m // 2 - 1] + buf[m // 2])
            out[i, j] = abs(a[i, j] - med) > tol
    return out


@njit(cache=True, nogil=True)
def burst_mask(a, span, longest, fraction, frozen, out):
    """out (n, k) bool, or-ed in place: the runs of 1..longest values of a (n, k) that are all
    further than fraction * span[j] from the value just before the run and are followed by a
    value back within it (a recorder or bus dropout: zeros or a stale word for a few samples),
    and, in the columns where ``frozen`` (k,) bool, a value that jumps so and then stays exactly
    the same for more than ``longest`` samples, the whole frozen run (a dead bus word: Mach 0 for
    a minute at cruise, where no measured channel moves that far in one sample; not an input, a
    demand that may be held exactly after a start-up step). A step (no return within ``longest``, not frozen), a NaN inside the
    run or at either end is left alone. Returns out."""
    n, k = a.shape
    for j in range(k):
        tol = fraction * span[j]
        i = 1
        while i < n:
            ref = a[i - 1, j]
            if not abs(a[i, j] - ref) > tol:     # no jump (or NaN)
                i += 1
                continue
            e = i + 1
            while e < n and e - i < longest and abs(a[e, j] - ref) > tol:
                e += 1
            f = i + 1
            while f < n and a[f, j] == a[i, j]:
                f += 1
            if e < n and e - i <= longest and abs(a[e, j] - ref) <= tol:
                for m in range(i, e):
                    out[m, j] = True
                i = e + 1
            elif frozen[j] and longest > 0 and f - i > longest:     # (longest 0: no run test at all)
                for m in range(i, f):
                    out[m, j] = True
                i = f + 1       # the value after it is measured from before the run, not from the word
            else:
                i += 1
    return out


@njit(cache=True, nogil=True, _nrt=False)
def report(q_hat, VT, h_ref, h_lo, h_hi, h_out, flags, h_held):
    """The pass after :func:`filter_loop`: health estimates h = h_ref + V_pinv q into h_out (n, nh)
    from q_hat (n, nq), VT = V_pinv^T (nq, nh) C-contiguous (sample by sample in a fixed order,
    so a one-sample call gives the same bits as a long one; NaN tuners give NaN health). Where
    flags (n,) has FLAG_HEALTH_HELD, h_out takes h_held (nh,), the last estimate of a step
    without it (kept across calls like the filter state). FLAG_HEALTH added where a health
    estimate is outside [h_lo, h_hi] (nh,) (it only reports). Allocates nothing and returns
    nothing (compiled without reference counting, an array returned to a caller with it would
    be freed twice)."""
    nh = h_ref.shape[0]
    last = -1            # the last sample whose estimate h_held takes (copied once, at the end)
    for k in range(q_hat.shape[0]):
        if flags[k] & FLAG_HEALTH_HELD:
            for i in range(nh):
                h_out[k, i] = h_out[last, i] if last >= 0 else h_held[i]
        else:
            for i in range(nh):
                h_out[k, i] = h_ref[i]
            for j in range(q_hat.shape[1]):   # column by column: the loop over i vectorises
                c = q_hat[k, j]
                for i in range(nh):
                    h_out[k, i] += VT[j, i] * c
            if np.isfinite(h_out[k, 0]):
                last = k
        out = False
        for i in range(nh):
            out |= (h_out[k, i] < h_lo[i]) | (h_out[k, i] > h_hi[i])   # no branch here: it costs ~40 %
        if out:
            flags[k] |= FLAG_HEALTH
    if last >= 0:
        for i in range(nh):
            h_held[i] = h_out[last, i]


def augment(d: dict, V_pinv: np.ndarray) -> dict:
    """The augmented discrete system of DESIGN.md section 3 (the one definition of it).

    ``d`` maps A..N to arrays of shape S + (rows, cols) for any leading shape S (one point: S = ());
    ``V_pinv`` is (nh, nq). Returns A, B, C, D, F, G of the augmented state [dx; q]:
    A_a = [[A, L V+], [0, I]], B_a = [[B], [0]], C_a = [C, M V+], D_a = D, F_a = [F, N V+], G_a = G.
    """
    A = np.asarray(d["A"])
    S, nx = A.shape[:-2], A.shape[-1]
    nq = V_pinv.shape[1]
    A_a = np.zeros(S + (nx + nq, nx + nq))
    A_a[..., :nx, :nx] = A
    A_a[..., :nx, nx:] = d["L"] @ V_pinv
    A_a[..., nx:, nx:] = np.eye(nq)
    B = np.asarray(d["B"])
    B_a = np.zeros(S + (nx + nq, B.shape[-1]))
    B_a[..., :nx, :] = B
    C_a = np.concatenate([d["C"], d["M"] @ V_pinv], axis=-1)
    F_a = np.concatenate([d["F"], d["N"] @ V_pinv], axis=-1)
    return {"A": A_a, "B": B_a, "C": C_a, "D": np.asarray(d["D"]), "F": F_a, "G": np.asarray(d["G"])}


def augmented(db: GainDatabase):
    """Augmented matrices over the dynamics grid (each D + (rows, cols)) and the stored gain K."""
    out = augment(db.dynamics, db.tuner["V_pinv"])
    out["K"] = db.kalman["K"]
    return out


@dataclass
class PackedModel:
    """A database packed for the kernel: one contiguous row per grid node.

    trim_tab: (trim nodes, columns) = [x, u, y, z (, filled) (, ambient terms)] (:func:`_pack_trims`:
    filled, when the build did not compute some trim: 1 on those nodes, FLAG_TRIM_FILLED); dyn_tab: (dyn nodes, block) =
    [A_a[:nx], B_a[:nx] row-major; C_a, D_a, F_a, G_a, K column-major] (the tuner rows of A_a
    and B_a, [0 I] and [0], are not stored: the kernel applies them), and with ``online`` also
    [Q_a, R] row-major, with p_tab (dyn nodes, na*na) the steady-state a-priori P; the rest are
    plain arrays.
    """

    trim_tab: np.ndarray
    dyn_tab: np.ndarray
    t_pidx: np.ndarray
    d_pidx: np.ndarray
    dims: np.ndarray
    ex: np.ndarray
    cls: np.ndarray
    s_scale: np.ndarray
    s_corr: np.ndarray
    schedule_channels: list
    theta_channel: str | None
    delta_channel: str | None
    online: bool = False
    p_tab: np.ndarray | None = None
    z_gains: np.ndarray | None = None
    z_labels: np.ndarray | None = None
    ko_tab: np.ndarray | None = None
    ko_avail: np.ndarray | None = None
    sub_tab: np.ndarray | None = None
    s_state: np.ndarray | None = None
    filled_col: int = -1
    amb_col: int = -1
    amb_p: np.ndarray | None = None
    amb_k: np.ndarray | None = None

    @classmethod
    def from_database(cls, db: GainDatabase, tune: bool = True, online: bool = False,
                      zones=None, health_hold: float = HEALTH_HOLD_RATIO) -> "PackedModel":
        """Pack ``db``; ``tune=False`` zeroes the tuner rows of K: the untuned model (states are
        still filtered, the tuners stay at their initial value). ``online``: also pack Q_a, R and
        the steady-state P for the online-covariance filter (needs ``tune``). ``zones``: a
        :class:`pwl.zones.ZoneTable` on the dynamics grid whose centroid gains are picked per step
        instead of interpolating K. ``health_hold``: with one sensor out, the health estimates
        hold (FLAG_HEALTH_HELD) where some health parameter's standard deviation without it is more
        than this many times its all-sensor value (``/kalman/out_h_ratio``; inf: never)."""
        if online and not tune:
            raise UsageError("the online-covariance filter estimates the tuners: tune=False is a "
                             "steady-gain option only")
        if online and zones is not None:
            raise UsageError("online covariance and zone gains exclude each other")
        tg, dg = db.trim_grid, db.dyn_grid
        trim_tab, filled_col, ambient = _pack_trims(db)
        aug = augmented(db)
        if not tune:
            aug["K"] = aug["K"].copy()
            aug["K"][..., db.n("x"):, :] = 0.0
        nx = db.n("x")
        aug["A"], aug["B"] = aug["A"][..., :nx, :], aug["B"][..., :nx, :]
        for k in ("C", "D", "F", "G", "K"):  # column-major: the kernel's products are axpys
            aug[k] = np.swapaxes(aug[k], -1, -2)
        parts = ("A", "B", "C", "D", "F", "G") + (() if zones is not None else ("K",)) + (
            ("Q", "R") if online else ())
        z_gains, z_labels = _pack_zones(db, zones, tune)
        if online:
            aug["Q"], aug["R"] = db.kalman["Q"], db.kalman["R"]
        dyn_tab = np.ascontiguousarray(np.concatenate(
            [aug[k].reshape(dg.size, -1) for k in parts], axis=1))
        na = nx + db.n("q")
        p_tab = np.ascontiguousarray(db.kalman["P"].reshape(dg.size, na * na) if online
                                     else np.zeros((1, 0)))
        sub_tab = np.zeros((1, 0))    # steady, tuned, interpolated gains: any subset of sensors
        if not online and tune and zones is None:
            sub_tab = np.ascontiguousarray(np.concatenate(
                [db.kalman["P"].reshape(dg.size, -1), db.kalman["R"].reshape(dg.size, -1)], axis=1))
        p = db.names["p"]
        t_pidx = np.array([p.index(n) for n in tg.names], dtype=np.int64)
        d_pidx = np.array([p.index(n) for n in dg.names], dtype=np.int64)
        dims = np.array([db.n(k) for k in "xuyzqh"], dtype=np.int64)
        chans = [c for c, _, _ in db.schedule]
        s_corr = np.array([bool(c) for _, c, _ in db.schedule])
        pairs, classes = _correction_classes(db)
        ko_tab, ko_avail = np.zeros((1, 0)), np.zeros(db.n("y"), dtype=np.int64)
        if "K_out" in db.kalman and zones is None and not online:
            ko_tab, ko_avail = _pack_sensor_out(db, tune, health_hold)
        return cls(trim_tab, dyn_tab, t_pidx, d_pidx, dims, pairs, classes,
                   np.array([float(s) for _, _, s in db.schedule]), s_corr, chans,
                   db.correction.theta_channel if db.correction else None,
                   db.correction.delta_channel if db.correction else None, online, p_tab,
                   z_gains, z_labels, ko_tab, ko_avail, sub_tab,
                   np.array([db.names["x"].index(c) if c in db.names["x"] else -1 for c in chans],
                            dtype=np.int64), filled_col, *ambient)

    def state_size(self) -> int:
        """Length of the filter state vector (:func:`state_layout`)."""
        nx, nu, ny, nz, nq, nh = (int(d) for d in self.dims)
        return int(state_layout(nx, nq, nu, len(self.schedule_channels), ny)[-1])

    def record(self, V_pinv: np.ndarray, gate: np.ndarray, stuck_n: int, settle_n: int, readmit_n: int) -> Model:
        """The kernel's :class:`Model` record: these tables, with V_pinv (nh, nq), the misfit gate,
        stuck gate and sensor noise (3, ny; :attr:`Model.gate`), the stuck detector's repeat
        count, the settling steps and the misfit steps before a sensor is used again (samples)."""
        nx, nu, ny, nz, nq, nh = (int(d) for d in self.dims)
        lay = block_layout(nx, nu, ny, nz, nq)
        width = lay[-1] if self.online else lay[-2] - (nx + nq) * ny * (self.z_gains.shape[0] > 0)
        if self.dyn_tab.shape[1] != width:   # zone gains: no K in the block
            raise DatabaseError(f"packed dynamics block of {self.dyn_tab.shape[1]} values, the kernel's "
                                f"layout has {width}: PackedModel and block_layout disagree")
        return Model(self.trim_tab, self.dyn_tab, self.dims, self.ex, self.cls, self.s_scale, self.s_corr,
                     self.s_state,
                     bool(self.online), self.p_tab, np.ascontiguousarray(V_pinv), self.z_gains,
                     self.z_labels, np.ascontiguousarray(gate, dtype=np.float64), int(stuck_n), int(settle_n),
                     int(readmit_n), self.ko_tab, self.ko_avail,
                     self.sub_tab, int(self.filled_col), int(self.amb_col), self.amb_p, self.amb_k)

    def grids(self, db: GainDatabase) -> Grids:
        """The kernel's :class:`Grids` record of ``db`` (the database this model packs)."""
        tg, dg = db.trim_grid, db.dyn_grid
        return Grids(tg.bp, tg.off, tg.strides, self.t_pidx, dg.bp, dg.off, dg.strides, self.d_pidx,
                     bool(tg.extrapolate))


def _pack_trims(db: GainDatabase):
    """(trim_tab, filled_col, (amb_col, amb_p, amb_k)) of :class:`Model`: the trim table, one row per
    trim node, [x, u, y, z (nt values) (, 1 on nodes the build filled: only when there are some)
    (, the ambient terms c1 of x..z, then c2)], the filled column and the first ambient column (-1
    when absent), the ambient's scheduling variables altitude and Mach and [T_std, the largest |dT|
    used, P_std, the plant's inlet pressure recovery (NaN: not known)]."""
    tg = db.trim_grid
    cols = [db.trim[k].reshape(tg.size, -1) for k in "xuyz"]
    nt = sum(c.shape[1] for c in cols)
    filled_col = amb_col = -1
    amb_p, amb_k = np.zeros(2, dtype=np.int64), np.zeros(4)
    if np.any(db.trim_status != 0):
        filled_col = nt
        cols.append((db.trim_status != 0).astype(float).reshape(tg.size, 1))
    if db.ambient is not None:
        a, names = db.ambient, db.names["p"]
        amb_col = sum(c.shape[1] for c in cols)
        cols += [a.coef[k][..., j, :].reshape(tg.size, -1) for j in (0, 1) for k in "xuyz"]
        amb_p = np.array([names.index(a.alt), names.index(a.mach)], dtype=np.int64)
        amb_k = np.array([db.correction.T_std, AMBIENT_REACH * a.span, db.correction.P_std, a.recovery])
    return np.ascontiguousarray(np.concatenate(cols, axis=1)), filled_col, (amb_col, amb_p, amb_k)


def _pack_zones(db: GainDatabase, zones, tune: bool):
    """(z_gains flat column-major (zones * na * ny,), z_labels (dyn nodes,) int64) of a
    :class:`pwl.zones.ZoneTable` on ``db``'s dynamics grid, or empty arrays without zones."""
    if zones is None:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    dg = db.dyn_grid
    same = zones.grid.names == dg.names and all(
        np.array_equal(a.values, b.values) for a, b in zip(zones.grid.axes, dg.axes))
    if not same:
        raise DatabaseError(f"{db.path}: the zones' lookup grid {zones.grid.names} is not the "
                            f"dynamics grid {dg.names}: zones of this database are built by "
                            "linearize.zones.database_zones")
    zg = zones.gains.copy()
    if zg.shape[1:] != db.kalman["K"].shape[-2:]:
        raise DatabaseError(f"{db.path}: zone gains {zg.shape[1:]} do not match K "
                            f"{db.kalman['K'].shape[-2:]}")
    if not tune:
        zg[:, db.n("x"):, :] = 0.0
    return (np.ascontiguousarray(np.swapaxes(zg, -1, -2).reshape(-1)),
            np.ascontiguousarray(zones.flat_labels, dtype=np.int64))


def _correction_classes(db: GainDatabase):
    """The distinct parameter-correction exponent pairs (nc, 2), pair 0 = (0, 0), and the pair
    of every channel (nx+nu+ny+nz+ns,) int64 in the order x, u, y, z, schedule (a schedule
    channel takes the exponents of the x/u/y/z channel of its name)."""
    zero = {k: np.zeros((db.n(k), 2)) for k in "xuyz"}
    ex = db.correction.exponents if db.correction is not None else zero
    by_name = {}
    for k in "xuyz":
        for j, name in enumerate(db.names[k]):
            by_name.setdefault(name, ex[k][j])
    ex_s = np.zeros((len(db.schedule), 2))
    for j, (c, corr, _) in enumerate(db.schedule):
        if corr:
            if c not in by_name:
                raise DatabaseError(f"{db.path}: scheduling channel {c!r} is marked corrected but has "
                                    f"no correction exponents")
            ex_s[j] = by_name[c]
    every = np.concatenate([ex[k] for k in "xuyz"] + [ex_s]).astype(np.float64)
    pairs = [(0.0, 0.0)] + sorted({tuple(e) for e in every} - {(0.0, 0.0)})
    return (np.array(pairs, dtype=np.float64),
            np.array([pairs.index(tuple(e)) for e in every], dtype=np.int64))


def _pack_sensor_out(db: GainDatabase, tune: bool, health_hold: float):
    """(ko_tab (dyn nodes * ny, ny * na) the sensor-out gains column-major, row node * ny + j;
    ko_avail (dyn nodes * ny,) int64: 0 none, 1 gain, 2 gain and the health estimates hold)."""
    dg, ny, nx = db.dyn_grid, db.n("y"), db.n("x")
    na = nx + db.n("q")
    ko = np.moveaxis(db.kalman["K_out"].reshape((ny, dg.size, na, ny)), 0, 1).copy()
    if not tune:
        ko[..., nx:, :] = 0.0
    ko_tab = np.ascontiguousarray(np.swapaxes(ko, -1, -2).reshape(dg.size * ny, ny * na))
    avail = (db.kalman["out_status"].reshape(ny, -1) != OUT_NONE).astype(np.int64)
    if "out_h_ratio" in db.kalman and tune:
        weak = db.kalman["out_h_ratio"].reshape(ny, dg.size, -1).max(axis=-1) > health_hold
        avail += avail * weak
    return ko_tab, np.ascontiguousarray(avail.T.reshape(-1))
