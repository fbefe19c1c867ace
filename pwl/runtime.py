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
value (flagged); the first valid sample starts the filter at trim.

Flags per step (bit mask): see ``FLAG_*``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .covariance import correct, propagate_augmented
from .database import OUT_NONE, DatabaseError, GainDatabase
from .errors import UsageError
from .grid import locate
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
                          # explain the sample (unit mistake, failed sensor, wrong database); the
                          # update still happens, the flag only reports it
MISFIT_SIGMAS = 12.0
FLAG_HEALTH = 128         # a health estimate left the plant's plausible health range (e.g. an
                          # efficiency 10 % better than new): the estimates cannot be trusted
FLAG_PARTIAL = 256        # some sensors were missing: the update used the others (steady gains:
                          # the stored gain without the one missing sensor; online: the reduced
                          # update); FLAG_NO_UPDATE is set instead when it could not
FLAG_HEALTH_HELD = 512    # the missing sensor is one the health estimates depend on (without it
                          # their steady-state standard deviation grows more than HEALTH_HOLD_RATIO
                          # times): h_hat holds its last value from before (the tuners and the other
                          # estimates go on, and the health estimates resume when it is back)
HEALTH_HOLD_RATIO = 3.0

# layout of the per-filter state vector (float64): [x_abs (nx), q (nq), u_last (nu), s_last (ns),
# theta_last, delta_last, started]


@njit(cache=True, nogil=True)
def _power(v, a):
    """v**a with the exponents of parameter correction (0, 1/2, 1, 3/2, ...) done without pow."""
    if a == 0.0:
        return 1.0
    if a == 1.0:
        return v
    if a == 0.5:
        return math.sqrt(v)
    if a == -0.5:
        return 1.0 / math.sqrt(v)
    if a == 1.5:
        return v * math.sqrt(v)
    return v ** a


@njit(cache=True, nogil=True)
def correction_factors(ex, theta, delta, fac):
    """fac[c] = theta^a_c delta^b_c for every distinct exponent pair ex[c] = (a_c, b_c)."""
    for c in range(ex.shape[0]):
        fac[c] = _power(theta, ex[c, 0]) * _power(delta, ex[c, 1])


@njit(cache=True, nogil=True, inline="always")
def _add_product(dw, o, rows, v, out):
    """out[:rows] += M v for the column-major matrix M stored at dw[o:] (rows x v.size): one
    contiguous axpy per column, four rows per pass. The columns are short (2-12 rows): a
    compiler-vectorised loop pays its alias checks and remainder per column, which cost more
    than the arithmetic (measured 19 ns per step slower on the demo database)."""
    for j in range(v.shape[0]):
        c = v[j]
        b = o + j * rows
        i = 0
        while i + 4 <= rows:
            out[i] += dw[b + i] * c
            out[i + 1] += dw[b + i + 1] * c
            out[i + 2] += dw[b + i + 2] * c
            out[i + 3] += dw[b + i + 3] * c
            i += 4
        while i < rows:
            out[i] += dw[b + i] * c
            i += 1


@njit(cache=True, nogil=True, inline="always")
def _bias_learn(b_chan, b_vals, b_counts, b_wts, b_rows, bm, b_frac, b_law, b_ratio, b_learn, learn,
                bias, res, fac, cls, cy, out_bias, k):
    """Bias tables after the residuals: record the bias (physical units), learn from res."""
    for c in range(b_chan.shape[0]):
        i = b_chan[c]
        out_bias[k, c] = bias[c] * fac[cls[cy + i]]
        if learn and b_learn[c]:
            table_update(b_vals[c], b_counts[c], b_wts, b_rows, bm, res[i], b_law, b_ratio, b_frac)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"}, _nrt=False)
def _steps(U, Y, S, TH, DE,
           trim_tab, t_bp, t_off, t_str, t_pidx,
           dyn_tab, d_bp, d_off, d_str, d_pidx, extrapolate,
           dims, ex, cls, s_scale, s_corr,
           state, t_idx, d_idx,
           b_chan, b_vals, b_counts, b_bp, b_off, b_str, b_pidx, b_idx, b_share, b_law, b_ratio,
           b_learn, online, p_tab, cov, V_pinv, z_gains, z_labels, gate, ko_tab, ko_avail,
           out_x, out_q, out_yhat, out_res, out_z, out_bias, out_hstd, out_flags, work):
    """The step loop of :func:`filter_loop` (same arguments, plus its workspace ``work``).

    Compiled without numba's reference counting (``_nrt=False``): the inlined helpers take
    arrays, and the atomic increments and decrements of their reference counts were a fifth
    of the time per step (perf; 418 -> 360 ns on the demo flight). It also makes any
    allocation in the loop a compile error."""
    (tw, dw, t_frac, d_frac, t_wts, t_rows, d_wts, d_rows, p, pt, pd, du, xi, xm, res, yh, zh,
     fac, b_frac, b_wts, b_rows, pb, bias, P, Aa, Ca, Qa, Ra, PCt, Sw, Lw, Kw, AP, ko_rows, kw) = work
    nx, nu, ny, nz, nq, nh = dims[0], dims[1], dims[2], dims[3], dims[4], dims[5]
    na = nx + nq
    ns = S.shape[1]
    n = U.shape[0]
    # packed offsets (must match PackedModel)
    oA = 0
    oB = oA + nx * na        # only the state rows of A_a, B_a: the tuner rows are [0 I], [0]
    oC = oB + nx * nu
    oD = oC + ny * na
    oF = oD + ny * nu
    oG = oF + nz * na
    oK = oG + nz * nu
    oQ = oK + na * ny        # online only: Q_a (na, na) and R (ny, ny), row-major
    oR = oQ + na * na
    tx, tu, ty, tz = 0, nx, nx + nu, nx + nu + ny
    nt = t_pidx.shape[0]
    nd = d_pidx.shape[0]
    nb = b_vals.shape[0]
    nbd = b_pidx.shape[0]
    bm = 0
    b_out = 0
    cx, cu, cy, cz, cs = 0, nx, nx + nu, nx + nu + ny, nx + nu + ny + nz
    th_prev = -1.0
    de_prev = -1.0
    ox = 0
    oq = nx
    ou = nx + nq
    osl = ou + nu
    oth = osl + ns
    ode = oth + 1
    ost = ode + 1
    for k in range(n):
        flags = out_flags[k]   # FLAG_IMPLAUSIBLE from screen(), or 0
        # ---- hold NaN/Inf inputs / schedule / theta, delta at their last valid values
        for j in range(nu):
            v = U[k, j]
            if not np.isfinite(v):
                flags |= FLAG_HELD_INPUT
            else:
                state[ou + j] = v
        for j in range(ns):
            v = S[k, j]
            if not np.isfinite(v):
                flags |= FLAG_HELD_INPUT
            else:
                state[osl + j] = v
        if not np.isfinite(TH[k]) or TH[k] <= 0.0:
            flags |= FLAG_HELD_INPUT
        else:
            state[oth] = TH[k]
        if not np.isfinite(DE[k]) or DE[k] <= 0.0:
            flags |= FLAG_HELD_INPUT
        else:
            state[ode] = DE[k]
        ok = True
        for j in range(ou, ost):
            if state[j] != state[j]:
                ok = False
        if not ok:  # nothing valid yet to predict from
            flags |= FLAG_NOT_STARTED
            out_flags[k] = flags
            for j in range(nx):
                out_x[k, j] = np.nan
            for j in range(nq):
                out_q[k, j] = np.nan
            for j in range(ny):
                out_yhat[k, j] = np.nan
                out_res[k, j] = np.nan
            for j in range(nz):
                out_z[k, j] = np.nan
            for j in range(nb):
                out_bias[k, j] = np.nan
            for j in range(out_hstd.shape[1]):
                out_hstd[k, j] = np.nan
            continue
        if state[oth] != th_prev or state[ode] != de_prev:
            th_prev = state[oth]
            de_prev = state[ode]
            correction_factors(ex, th_prev, de_prev, fac)
        # ---- scheduling variables and the two grid searches (shared weights)
        for j in range(ns):
            v = state[osl + j] * s_scale[j]
            if s_corr[j]:
                v /= fac[cls[cs + j]]
            p[j] = v
        for j in range(nt):
            pt[j] = p[t_pidx[j]]
        for j in range(nd):
            pd[j] = p[d_pidx[j]]
        if locate(t_bp, t_off, pt, extrapolate, t_idx, t_frac) != 0:
            flags |= FLAG_TRIM_OUTSIDE
        d_out = locate(d_bp, d_off, pd, extrapolate, d_idx, d_frac)
        if d_out != 0:
            flags |= FLAG_DYN_OUTSIDE
        m = corner_weights(t_idx, t_frac, t_str, t_wts, t_rows)
        interp_rows(trim_tab, t_wts, t_rows, m, tw)
        m = corner_weights(d_idx, d_frac, d_str, d_wts, d_rows)
        interp_rows(dyn_tab, d_wts, d_rows, m, dw)
        if nb > 0 and b_share:  # the bias tables are on the dynamics grid: its weights serve
            b_out = d_out
            bm = m
            for j in range(m):
                b_wts[j] = d_wts[j]
                b_rows[j] = d_rows[j]
            for j in range(nd):
                b_frac[j] = d_frac[j]
        elif nb > 0:  # their own grid: one more search, weights shared by all bias tables
            for j in range(nbd):
                pb[j] = p[b_pidx[j]]
            b_out = locate(b_bp, b_off, pb, extrapolate, b_idx, b_frac)
            bm = corner_weights(b_idx, b_frac, b_str, b_wts, b_rows)
        if nb > 0:
            for c in range(nb):
                bias[c] = table_predict(b_vals[c], b_wts, b_rows, bm)
        # ---- start at trim on the first valid sample
        first = state[ost] == 0.0
        if first:
            for j in range(nx):
                state[ox + j] = tw[tx + j]
            state[ost] = 1.0
        if online:  # covariance time update (the first step starts from the steady-state P)
            if first:
                interp_rows(p_tab, d_wts, d_rows, m, cov)
            else:
                for i in range(nx):
                    for j in range(na):
                        Aa[i, j] = dw[oA + i * na + j]
                for i in range(na):
                    for j in range(na):
                        Qa[i, j] = dw[oQ + i * na + j]
                propagate_augmented(Aa, P, Qa, AP)
        # ---- trim-shift adjustment and time update
        for j in range(nx):
            xi[j] = state[ox + j] - tw[tx + j]
        for j in range(nq):
            xi[nx + j] = state[oq + j]
        for j in range(nu):
            du[j] = state[ou + j] / fac[cls[cu + j]] - tw[tu + j]
        for i in range(nx):
            s = 0.0
            for j in range(na):
                s += dw[oA + i * na + j] * xi[j]
            for j in range(nu):
                s += dw[oB + i * nu + j] * du[j]
            xm[i] = s
        for i in range(nx, na):  # tuners: random walk, A_a rows [0 I]
            xm[i] = xi[i]
        # ---- predicted measurements and residuals (corrected units); C, D, K, F, G are stored
        # column by column, so every product is a few contiguous axpys (vectorised)
        for i in range(ny):
            yh[i] = tw[ty + i]
        _add_product(dw, oC, ny, xm, yh)
        _add_product(dw, oD, ny, du, yh)
        for c in range(nb):
            yh[b_chan[c]] += bias[c]
        n_miss = 0
        miss = 0
        for i in range(ny):
            s = yh[i]
            fy = fac[cls[cy + i]]
            yk = Y[k, i]
            if not np.isfinite(yk):          # NaN or +-Inf: no update from this sensor
                n_miss += 1
                miss = i
                res[i] = 0.0
                out_res[k, i] = np.nan
            else:
                res[i] = yk / fy - s
                r = yk - s * fy
                out_res[k, i] = r
                if abs(r) > gate[i] * abs(s * fy):
                    flags |= FLAG_MISFIT
            out_yhat[k, i] = s * fy
        # a missing sensor: the update goes on from the others (online: any subset, the reduced
        # update below; steady: one sensor out, with its stored gain), else it is skipped
        update = n_miss == 0
        partial = n_miss > 0 and n_miss < ny and (online or (n_miss == 1 and ko_tab.shape[1] > 0))
        hold = False
        if partial and not online:   # every corner around p has a gain without that sensor
            for c in range(m):
                if d_wts[c] != 0.0:
                    a = ko_avail[d_rows[c] * ny + miss]
                    partial &= a != 0
                    hold |= a == 2
        if partial:
            flags |= FLAG_PARTIAL | (FLAG_HEALTH_HELD if hold else 0)
        elif not update:
            flags |= FLAG_NO_UPDATE
        if nb > 0:  # the bias tables learn from complete updates only
            _bias_learn(b_chan, b_vals, b_counts, b_wts, b_rows, bm, b_frac, b_law, b_ratio, b_learn,
                        update and b_out == 0, bias, res, fac, cls, cy, out_bias, k)
        update = update or partial
        # ---- measurement update
        if online and update:  # the gain from P replaces the interpolated one
            mo = 0                 # rows of the present sensors only
            for i in range(ny):
                if np.isfinite(Y[k, i]):
                    for j in range(na):
                        Ca[mo, j] = dw[oC + j * ny + i]
                    mi = 0
                    for j in range(ny):
                        if np.isfinite(Y[k, j]):
                            Ra[mo, mi] = dw[oR + i * ny + j]
                            mi += 1
                    mo += 1
            if correct(P, Ca[:mo], Ra[:mo, :mo], PCt[:, :mo], Sw[:mo, :mo], Lw[:mo, :mo], Kw[:, :mo]):
                mi = 0
                for j in range(ny):
                    present = np.isfinite(Y[k, j])
                    for i in range(na):
                        dw[oK + j * na + i] = Kw[i, mi] if present else 0.0
                    if present:
                        mi += 1
            else:  # C P C^T + R not positive definite: prediction only
                update = False
                flags = (flags & ~FLAG_PARTIAL) | FLAG_NO_UPDATE
        elif partial:  # steady gains: the stored gain without the missing sensor
            for c in range(m):
                ko_rows[c] = d_rows[c] * ny + miss
            interp_rows(ko_tab, d_wts, ko_rows, m, kw)
            for i in range(na * ny):
                dw[oK + i] = kw[i]
        for i in range(na):
            xi[i] = xm[i]
        if update and z_gains.shape[0] > 0:  # the zone gain of the nearest dynamics node
            node = 0
            for j in range(nd):
                node += (d_idx[j] + (1 if d_frac[j] >= 0.5 else 0)) * d_str[j]
            _add_product(z_gains, z_labels[node] * na * ny, na, res, xi)
        elif update:
            _add_product(dw, oK, na, res, xi)
        # ---- outputs
        for i in range(nz):
            zh[i] = tw[tz + i]
        _add_product(dw, oF, nz, xi, zh)
        _add_product(dw, oG, nz, du, zh)
        for i in range(nz):
            out_z[k, i] = zh[i] * fac[cls[cz + i]]
        for j in range(nx):
            xa = tw[tx + j] + xi[j]
            state[ox + j] = xa
            out_x[k, j] = xa * fac[cls[cx + j]]
        for j in range(nq):
            state[oq + j] = xi[nx + j]
            out_q[k, j] = xi[nx + j]
        if online and out_hstd.shape[1] > 0:  # health standard deviations from P(k|k)
            for i in range(nh):
                v = 0.0
                for j in range(nq):
                    a = 0.0
                    for c in range(nq):
                        a += P[nx + j, nx + c] * V_pinv[i, c]
                    v += V_pinv[i, j] * a
                out_hstd[k, i] = math.sqrt(max(v, 0.0))
        out_flags[k] = flags
    return n


@njit(cache=True, nogil=True)
def filter_loop(U, Y, S, TH, DE,
                trim_tab, t_bp, t_off, t_str, t_pidx,
                dyn_tab, d_bp, d_off, d_str, d_pidx, extrapolate,
                dims, ex, cls, s_scale, s_corr,
                state, t_idx, d_idx,
                b_chan, b_vals, b_counts, b_bp, b_off, b_str, b_pidx, b_idx, b_share, b_law, b_ratio,
                b_learn, online, p_tab, cov, V_pinv, z_gains, z_labels, gate, ko_tab, ko_avail,
                out_x, out_q, out_yhat, out_res, out_z, out_bias, out_hstd, out_flags):
    """Run the filter over n samples; state and search hints are updated in place (chunkable).

    U (n, nu), Y (n, ny), S (n, ns) raw log channels; TH, DE (n,) theta and delta (ones when the
    database has no correction). trim_tab (trim nodes, nx+nu+ny+nz), dyn_tab (dyn nodes, block)
    packed as in :class:`PackedModel`. dims = [nx, nu, ny, nz, nq, nh]. Parameter correction:
    ex (nc, 2) the distinct exponent pairs, cls (nx+nu+ny+nz+ns,) int64 the pair of every channel
    in the order x, u, y, z, schedule (pair 0 is (0, 0)). Outputs (n, .) in
    physical (uncorrected) units: x_hat, q_hat, y_hat (a priori), residual y - y_hat,
    z_hat (a posteriori); out_flags (n,) int64. Returns the number of samples processed.

    Bias tables (the tuning element; nb = b_vals.shape[0], 0 for none): one adaptive table per
    biased sensed channel, all on one grid (b_bp, b_off, b_str; b_pidx its axes among the
    scheduling variables; b_idx the search hint; b_share: the grid is the dynamics grid, whose
    search and weights are reused), values (nb, nodes) and visit counts in
    corrected units. b_chan (nb,) the sensed channel of each table. Each step the
    tables' prediction is added to the predicted measurement (the bias is pre-positioned at the
    operating point) and, when the point is inside the table grid and the step has a
    measurement update, every table with b_learn[c] learns from its channel's innovation with the
    steady-state table gain (law b_law, noise ratio b_ratio; pwl.tables). out_bias (n, nb) in
    physical units.

    Online covariance (``online`` True; the full Kalman filter of the piecewise-linear model, an
    EKF whose Jacobians are the interpolated matrices): dyn_tab blocks also hold Q_a and R
    (row-major, after K); cov (na*na,) is the error covariance P (a posteriori between steps,
    kept in place like ``state``), started from the interpolated steady-state P of p_tab (dyn nodes,
    na*na) on the first valid sample. Each step P <- A_a P A_a^T + Q_a, then the gain and P(k|k)
    from :func:`pwl.covariance.correct` replace the interpolated gain; out_hstd (n, nh) gets the
    standard deviation of every health estimate, sqrt(diag(V_pinv P_qq V_pinv^T)) with P_qq the
    tuner block of P(k|k) (V_pinv (nh, nq)), unless it has no columns. Not online: p_tab, cov,
    V_pinv and out_hstd are unused (may be empty).

    Missing values: NaN or +-Inf (and theta, delta <= 0) inputs, schedule and theta/delta values
    are held at their last valid value, a missing sensor value skips the update. Values outside
    their plausible range were turned into NaN before, by :func:`screen`; out_flags holds its
    flags on entry (FLAG_IMPLAUSIBLE, or 0) and the step's flags are added to them.

    Missing sensors (NaN/Inf in Y; FLAG_PARTIAL when the update goes on without them): online,
    the update uses the rows of the present sensors (any subset); steady gains, one missing sensor
    j takes the gain without it, interpolated with the dynamics weights from ko_tab (dyn nodes *
    ny, ny * na): row node * ny + j, column-major like K (column j zero), when every corner node
    of non-zero weight has one (ko_avail (dyn nodes * ny,) int64, same rows, non-zero);
    else (two or more missing, no sensor-out gains: ko_tab (1, 0), zone gains) no update
    (FLAG_NO_UPDATE). Bias tables learn from complete updates only.

    Zone gains (z_gains non-empty; :mod:`linearize.zones` database zones): the gain is picked,
    not interpolated: the zone label z_labels[node] of the dynamics node nearest to the operating
    point (per axis the closer breakpoint) selects the centroid gain z_gains[label * na * ny:]
    (column-major, na x ny); dyn_tab blocks then hold no K.
    """
    work = workspace(S.shape[1], trim_tab, dyn_tab, t_pidx, d_pidx, dims, ex, b_vals, b_pidx, online,
                     cov, ko_tab)
    return _steps(U, Y, S, TH, DE, trim_tab, t_bp, t_off, t_str, t_pidx, dyn_tab, d_bp, d_off,
                  d_str, d_pidx, extrapolate, dims, ex, cls, s_scale, s_corr, state, t_idx, d_idx,
                  b_chan, b_vals, b_counts, b_bp, b_off, b_str, b_pidx, b_idx, b_share, b_law,
                  b_ratio, b_learn, online, p_tab, cov, V_pinv, z_gains, z_labels, gate, ko_tab, ko_avail,
                  out_x, out_q, out_yhat, out_res, out_z, out_bias, out_hstd, out_flags, work)


@njit(cache=True, nogil=True)
def workspace(ns, trim_tab, dyn_tab, t_pidx, d_pidx, dims, ex, b_vals, b_pidx, online, cov, ko_tab):
    """The work arrays of :func:`_steps` (its last argument), for ns schedule channels and the
    packed model's sizes; cov the online covariance (P is a view of it). Allocated once per
    :func:`filter_loop` call, or once per :class:`pwl.streaming.Stream`."""
    nx, nu, ny, nz, nq = dims[0], dims[1], dims[2], dims[3], dims[4]
    na = nx + nq
    nt = t_pidx.shape[0]
    nd = d_pidx.shape[0]
    nb = b_vals.shape[0]
    nbd = b_pidx.shape[0]
    no = na if online else 0    # online-covariance work arrays (empty otherwise)
    mo = ny if online else 0
    tw = np.empty(trim_tab.shape[1])
    dw = np.empty(dyn_tab.shape[1])
    t_frac = np.empty(nt)
    d_frac = np.empty(nd)
    t_wts = np.empty(1 << nt)
    t_rows = np.empty(1 << nt, dtype=np.int64)
    d_wts = np.empty(1 << nd)
    d_rows = np.empty(1 << nd, dtype=np.int64)
    p = np.empty(ns)
    pt = np.empty(nt)
    pd = np.empty(nd)
    du = np.empty(nu)
    xi = np.empty(na)
    xm = np.empty(na)
    res = np.empty(ny)
    yh = np.empty(ny)
    zh = np.empty(nz)
    fac = np.ones(ex.shape[0])
    b_frac = np.empty(nbd)
    b_wts = np.empty(1 << nbd)
    b_rows = np.empty(1 << nbd, dtype=np.int64)
    pb = np.empty(nbd)
    bias = np.zeros(max(nb, 1))
    P = cov[:no * no].reshape((no, no))
    ro = nx if online else 0
    Aa = np.empty((ro, no))     # the state rows of A_a; its tuner rows [0 I] are implied
    Ca = np.empty((mo, no))
    Qa = np.empty((no, no))
    Ra = np.empty((mo, mo))
    PCt = np.empty((no, mo))
    Sw = np.empty((mo, mo))
    Lw = np.empty((mo, mo))
    Kw = np.empty((no, mo))
    AP = np.empty((ro, no))
    ko_rows = np.empty(1 << nd, dtype=np.int64)
    kw = np.empty(ko_tab.shape[1])
    work = (tw, dw, t_frac, d_frac, t_wts, t_rows, d_wts, d_rows, p, pt, pd, du, xi, xm, res, yh, zh,
            fac, b_frac, b_wts, b_rows, pb, bias, P, Aa, Ca, Qa, Ra, PCt, Sw, Lw, Kw, AP, ko_rows, kw)
    return work


@njit(cache=True, nogil=True, inline="always")
def _screen_value(v, lim, c, chan_count):
    """Screen one value of column c (see :func:`screen`); its flag bits."""
    if lim[0, c] <= v <= lim[1, c]:
        return 0
    chan_count[0, c] += 1
    if not np.isfinite(v):
        return 0
    chan_count[1, c] += 1
    return FLAG_IMPLAUSIBLE


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
        if not lim[0, c0 + j] <= A[k, j] <= lim[1, c0 + j]:
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
        if not lim[0, c] <= TH[k] <= lim[1, c]:
            TH[k] = np.nan
        if not lim[0, c + 1] <= DE[k] <= lim[1, c + 1]:
            DE[k] = np.nan


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
    for k in range(q_hat.shape[0]):
        if flags[k] & FLAG_HEALTH_HELD:
            for i in range(nh):
                h_out[k, i] = h_held[i]
        else:
            for i in range(nh):
                h_out[k, i] = h_ref[i]
            for j in range(q_hat.shape[1]):   # column by column: the loop over i vectorises
                c = q_hat[k, j]
                for i in range(nh):
                    h_out[k, i] += VT[j, i] * c
            if np.isfinite(h_out[k, 0]):
                for i in range(nh):
                    h_held[i] = h_out[k, i]
        out = False
        for i in range(nh):
            out |= (h_out[k, i] < h_lo[i]) | (h_out[k, i] > h_hi[i])   # no branch here: it costs ~40 %
        if out:
            flags[k] |= FLAG_HEALTH


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

    trim_tab: (trim nodes, nx+nu+ny+nz) = [x, u, y, z]; dyn_tab: (dyn nodes, block) =
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

    @classmethod
    def from_database(cls, db: GainDatabase, tune: bool = True, online: bool = False,
                      zones=None, health_hold: float = HEALTH_HOLD_RATIO) -> "PackedModel":
        """Pack ``db``; ``tune=False`` zeroes the tuner rows of K: the untuned model (states are
        still filtered, the tuners stay at their initial value). ``online``: also pack Q_a, R and
        the steady-state P for the online-covariance filter (needs ``tune``). ``zones``: a
        :class:`pwl.ekf.ZoneTable` on the dynamics grid whose centroid gains are picked per step
        instead of interpolating K. ``health_hold``: with one sensor out, the health estimates
        hold (FLAG_HEALTH_HELD) where some health parameter's standard deviation without it is more
        than this many times its all-sensor value (``/kalman/out_h_ratio``; inf: never)."""
        if online and not tune:
            raise UsageError("the online-covariance filter estimates the tuners: tune=False is a "
                             "steady-gain option only")
        if online and zones is not None:
            raise UsageError("online covariance and zone gains exclude each other")
        tg, dg = db.trim_grid, db.dyn_grid
        trim_tab = np.ascontiguousarray(np.concatenate(
            [db.trim[k].reshape(tg.size, -1) for k in "xuyz"], axis=1))
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
        z_gains, z_labels = np.zeros(0), np.zeros(0, dtype=np.int64)
        if zones is not None:
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
                zg[:, nx:, :] = 0.0
            z_gains = np.ascontiguousarray(np.swapaxes(zg, -1, -2).reshape(-1))
            z_labels = np.ascontiguousarray(zones.flat_labels, dtype=np.int64)
        if online:
            aug["Q"], aug["R"] = db.kalman["Q"], db.kalman["R"]
        dyn_tab = np.ascontiguousarray(np.concatenate(
            [aug[k].reshape(dg.size, -1) for k in parts], axis=1))
        na = nx + db.n("q")
        p_tab = np.ascontiguousarray(db.kalman["P"].reshape(dg.size, na * na) if online
                                     else np.zeros((1, 0)))
        p = db.names["p"]
        t_pidx = np.array([p.index(n) for n in tg.names], dtype=np.int64)
        d_pidx = np.array([p.index(n) for n in dg.names], dtype=np.int64)
        dims = np.array([db.n(k) for k in "xuyzqh"], dtype=np.int64)
        zero = {k: np.zeros((db.n(k), 2)) for k in "xuyz"}
        ex = db.correction.exponents if db.correction is not None else zero
        # exponents of the schedule channels: from whichever kind names the channel
        by_name = {}
        for k in "xuyz":
            for j, name in enumerate(db.names[k]):
                by_name.setdefault(name, ex[k][j])
        chans = [c for c, _, _ in db.schedule]
        s_corr = np.array([bool(c) for _, c, _ in db.schedule])
        ex_s = np.zeros((len(chans), 2))
        for j, (c, corr, _) in enumerate(db.schedule):
            if corr:
                if c not in by_name:
                    raise DatabaseError(f"{db.path}: scheduling channel {c!r} is marked corrected but has "
                                     f"no correction exponents")
                ex_s[j] = by_name[c]
        every = np.concatenate([ex[k] for k in "xuyz"] + [ex_s]).astype(np.float64)
        pairs = [(0.0, 0.0)] + sorted({tuple(e) for e in every} - {(0.0, 0.0)})
        classes = np.array([pairs.index(tuple(e)) for e in every], dtype=np.int64)
        ny = db.n("y")
        ko_tab, ko_avail = np.zeros((1, 0)), np.zeros(ny, dtype=np.int64)
        if "K_out" in db.kalman and zones is None and not online:
            ko = np.moveaxis(db.kalman["K_out"].reshape((ny, dg.size, na, ny)), 0, 1).copy()
            if not tune:
                ko[..., nx:, :] = 0.0
            ko_tab = np.ascontiguousarray(np.swapaxes(ko, -1, -2).reshape(dg.size * ny, ny * na))
            avail = (db.kalman["out_status"].reshape(ny, -1) != OUT_NONE).astype(np.int64)
            if "out_h_ratio" in db.kalman and tune:   # 2: available, the health estimates hold
                weak = db.kalman["out_h_ratio"].reshape(ny, dg.size, -1).max(axis=-1) > health_hold
                avail += avail * weak
            ko_avail = np.ascontiguousarray(avail.T.reshape(-1))
        return cls(trim_tab, dyn_tab, t_pidx, d_pidx, dims, np.array(pairs, dtype=np.float64), classes,
                   np.array([float(s) for _, _, s in db.schedule]), s_corr, chans,
                   db.correction.theta_channel if db.correction else None,
                   db.correction.delta_channel if db.correction else None, online, p_tab,
                   z_gains, z_labels, ko_tab, ko_avail)

    def state_size(self) -> int:
        nx, nu, ny, nz, nq, nh = self.dims
        return int(nx + nq + nu + len(self.schedule_channels) + 3)
