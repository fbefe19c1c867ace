"""The speed floor of the runtime: a minimal fused loop doing the kernel's arithmetic and nothing else.

:func:`make_floor` compiles a loop that computes the same steady-gain estimates as
:func:`pwl.runtime.filter_loop` on a log with every sample present (parameter correction, one
search per grid, shared corner weights, the trims on the day's ambient, trim-shift adjustment,
time and measurement update, outputs in physical units), with plain two-dimensional arrays, the
database's sizes as compile-time constants, and no missing-value holds, flags, sensor checks,
bias tables, gain choices or health pass. ``pwl bench run`` reports the runtime's time per step
as a ratio to it: what the robustness and the generality (one compiled kernel for every
database) cost.

:func:`fma_peak` measures what one core does at best on this machine (a vectorised multiply-add
loop on data in L1 cache) to put the kernel's flops per second in proportion.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..airdata import ambient_offset
from ..grid import locate
from ..interp import corner_weights, interp_rows
from ..runtime import block_layout, correction_factors


def make_floor(dims, ns: int):
    """The floor loop compiled for one database's sizes: dims = [nx, nu, ny, nz, nq, ...]
    (:attr:`pwl.runtime.Model.dims`) and ns schedule channels are compile-time constants (the
    compiler unrolls the short loops and keeps the small vectors in registers, which the
    runtime, compiled once for every size, cannot). Compiled on each call (a benchmark)."""
    nx, nu, ny, nz, nq = (int(d) for d in dims[:5])
    na = nx + nq
    oA, oB, oC, oD, oF, oG, oK, _, _, _, _ = block_layout(nx, nu, ny, nz, nq)
    cy, cz, cs = nx + nu, nx + nu + ny, nx + nu + ny + nz

    @njit(nogil=True, fastmath={"reassoc", "contract"})   # as the kernel
    def floor_loop(U, Y, S, TH, DE, trim_tab, dyn_tab, ex, cls, s_scale, s_corr, amb_col, amb_p, amb_k,
                   t_bp, t_off, t_str, t_pidx, d_bp, d_off, d_str, d_pidx, x0, q0, x_hat, q_hat, y_hat,
                   residual, z_hat):
        """Steady-gain estimates of n complete samples (see the module docstring); the arrays
        are the packed model's (:class:`pwl.runtime.Model`, :class:`pwl.runtime.Grids`), the
        outputs (n, k) physical units. x0 (nx,) corrected absolute state, NaN: start at trim;
        q0 (nq,) tuners."""
        nt = nx + nu + ny + nz
        fac = np.ones(ex.shape[0])
        p = np.empty(S.shape[1])
        pt, pd = np.empty(t_pidx.shape[0]), np.empty(d_pidx.shape[0])
        t_idx, d_idx = np.zeros(pt.shape[0], np.int64), np.zeros(pd.shape[0], np.int64)
        t_frac, d_frac = np.empty(pt.shape[0]), np.empty(pd.shape[0])
        t_w, d_w = np.empty(1 << pt.shape[0]), np.empty(1 << pd.shape[0])
        t_r, d_r = np.empty(1 << pt.shape[0], np.int64), np.empty(1 << pd.shape[0], np.int64)
        tw, dw = np.empty(trim_tab.shape[1]), np.empty(dyn_tab.shape[1])
        A = dw[oA:oB].reshape((nx, na))
        B = dw[oB:oC].reshape((nx, nu))
        Ct = dw[oC:oD].reshape((na, ny))         # column-major C_a: row j is column j
        Dt = dw[oD:oF].reshape((nu, ny))
        Ft = dw[oF:oG].reshape((na, nz))
        Gt = dw[oG:oK].reshape((nu, nz))
        Kt = dw[oK:oK + na * ny].reshape((ny, na))
        xa, xi, xm = x0.copy(), np.empty(na), np.empty(na)
        du, yh, res = np.empty(nu), np.empty(ny), np.empty(ny)
        xi[nx:] = q0
        for k in range(U.shape[0]):
            correction_factors(ex, TH[k], DE[k], fac)
            for j in range(p.shape[0]):
                p[j] = S[k, j] * s_scale[j] / (fac[cls[cs + j]] if s_corr[j] else 1.0)
            for j in range(pt.shape[0]):
                pt[j] = p[t_pidx[j]]
            for j in range(pd.shape[0]):
                pd[j] = p[d_pidx[j]]
            locate(t_bp, t_off, pt, False, t_idx, t_frac)
            locate(d_bp, d_off, pd, False, d_idx, d_frac)
            interp_rows(trim_tab, t_w, t_r, corner_weights(t_idx, t_frac, t_str, t_w, t_r), tw)
            if amb_col >= 0:                          # the trims on this day
                dT = min(max(ambient_offset(TH[k] * amb_k[0], p[amb_p[0]], p[amb_p[1]]), -amb_k[1]), amb_k[1])
                for j in range(nt):
                    tw[j] += dT * (tw[amb_col + j] + dT * tw[amb_col + nt + j])
            interp_rows(dyn_tab, d_w, d_r, corner_weights(d_idx, d_frac, d_str, d_w, d_r), dw)
            if xa[0] != xa[0]:
                xa[:] = tw[:nx]
            for j in range(nx):
                xi[j] = xa[j] - tw[j]
            for j in range(nu):
                du[j] = U[k, j] / fac[cls[nx + j]] - tw[nx + j]
            for i in range(nx):                       # xm = A_a xi + B_a du (tuners: random walk)
                s = 0.0
                for j in range(na):
                    s += A[i, j] * xi[j]
                for j in range(nu):
                    s += B[i, j] * du[j]
                xm[i] = s
            for i in range(nx, na):
                xm[i] = xi[i]
            for i in range(ny):                       # y_hat = y_trim + C_a xm + D du
                yh[i] = tw[cy + i]
            for j in range(na):
                for i in range(ny):
                    yh[i] += Ct[j, i] * xm[j]
            for j in range(nu):
                for i in range(ny):
                    yh[i] += Dt[j, i] * du[j]
            for i in range(ny):
                f = fac[cls[cy + i]]
                res[i] = Y[k, i] / f - yh[i]
                y_hat[k, i] = yh[i] * f
                residual[k, i] = Y[k, i] - y_hat[k, i]
            for i in range(na):                       # xi = xm + K res
                xi[i] = xm[i]
            for j in range(ny):
                for i in range(na):
                    xi[i] += Kt[j, i] * res[j]
            for i in range(nz):                       # z_hat = z_trim + F_a xi + G du
                s = tw[cz + i]
                for j in range(na):
                    s += Ft[j, i] * xi[j]
                for j in range(nu):
                    s += Gt[j, i] * du[j]
                z_hat[k, i] = s * fac[cls[cz + i]]
            for j in range(nx):
                xa[j] = tw[j] + xi[j]
                x_hat[k, j] = xa[j] * fac[cls[j]]
            for j in range(nq):
                q_hat[k, j] = xi[nx + j]
        return U.shape[0]


    return floor_loop


def flops_per_step(model, grids) -> int:
    """Floating-point operations of one steady step (multiply-adds count two): the interpolation
    of the trim and dynamics rows over all corners, and the products of the update."""
    nx, nu, ny, nz, nq = (int(d) for d in model.dims[:5])
    na = nx + nq
    corners_t, corners_d = 1 << grids.t_pidx.shape[0], 1 << grids.d_pidx.shape[0]
    interp = 2 * (corners_t * model.trim_tab.shape[1] + corners_d * model.dyn_tab.shape[1])
    products = 2 * (nx * (na + nu) + ny * (na + nu) + na * ny + nz * (na + nu))
    return interp + products


@njit(cache=True, nogil=True, fastmath=True)
def _fma_loop(a, b, c, reps):
    for _ in range(reps):
        for i in range(a.shape[0]):
            c[i] = c[i] * a[i] + b[i]
    return c[0]


def fma_peak(repeat: int = 5) -> float:
    """Floating-point operations per second of a vectorised multiply-add loop on L1-resident
    arrays: what one core of this machine does at best from numba (a lower bound of its peak)."""
    import time
    n, reps = 512, 20000
    a, b, c = np.full(n, 0.999999), np.full(n, 1e-6), np.ones(n)
    _fma_loop(a, b, c, 1)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        _fma_loop(a, b, c, reps)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * n * reps / best
