"""Gain-scheduled EKF by k-means zones (SEKF) and the full EKF baseline (numba loops).

Seed paper 001 (Chen 2020). Plant x[k+1] = f(x[k], u[k]) + w, y[k] = h(x[k]) + v. One step k,
given the a-priori estimate x- = x(k|k-1), the measurement y[k] and the input u[k]::

    SEKF   zone j = zone of (u[k], x-)       nearest node of a fine lookup grid -> its label
           x+     = x- + K_j (y[k] - h(x-))   K_j the zone's centroid gain (update form)
           x-     = f(x+, u[k])              next a-priori estimate

    EKF    C = dh/dx(x-),  K = P C^T (C P C^T + R)^-1,  x+ = x- + K (y - h(x-)),
           P = P - K (P C^T)^T                           (paper eqs. 5-7)
           A = df/dx(x+, u),  x- = f(x+, u),  P = A P A^T + Q   (eqs. 8-9)

A NaN measurement skips the correction (prediction only). Both loops write the a-posteriori
estimate x(k|k) of every step and allocate nothing per step (work arrays are made once, before
the loop).

Plant functions are numba ``njit`` functions passed as first-class arguments, all with the
signature ``(x, u, p, out) -> None`` (``p`` a float64 parameter vector; see
:data:`models.chen2020.PlantFunctions`): ``f`` writes x[k+1] (n,), ``jac_f`` df/dx (n, n), ``h``
writes y (m,), ``jac_h`` dh/dx (m, n). Numba specialises (and inlines) each loop for the functions
it is given; the price is that such specialisations are not cached on disk, so the first call in
a process compiles (about a second per loop). Plant-specific loops would be cacheable but would
put a copy of the filter in every model; one generic kernel was preferred.

The zones themselves (:class:`pwl.zones.ZoneTable`, the online form of a database's ``/zones``
record, and its nearest-node lookup kernels) are core: this module holds only the filter loops
of the seed-paper reproduction (``pwl zones``, :mod:`experiments.zones`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from pwl.covariance import chol_solve_right
from pwl.zones import ZoneError, ZoneTable, nearest_node, nearest_node_uniform


@njit(nogil=True, inline="always")
def _innovation(h, xm, u, p, Y, k, yh, e):
    """e = Y[k] - h(xm, u); False when a measurement is NaN (no correction this step)."""
    h(xm, u, p, yh)
    ok = True
    for i in range(e.shape[0]):
        e[i] = Y[k, i] - yh[i]
        if np.isnan(e[i]):
            ok = False
    return ok


# ---- the filters ----------------------------------------------------------------------------------
@njit(nogil=True)
def sekf_loop(f, h, U, Y, x0, p, coords, uniform, lo, inv_h, nmax, bp, off, strides, labels,
              gains, X_out, Z_out):
    """Scheduled-gain EKF over T steps. U (T, nu), Y (T, m) (NaN: no correction), x0 (n,) the
    a-priori estimate of step 0, p the plant parameter vector; coords (d,) int64 the indices in
    the vector (u, x) of the lookup coordinates (all of them: arange(nu + n)); (uniform .. labels)
    the lookup grid and its flat node labels (:meth:`ZoneTable.kernel_args`), gains (k, n, m). Writes X_out (T, n) the
    a-posteriori estimates and, when Z_out has T entries, the zone used at each step (-1 when no
    correction). Returns the number of steps whose (u, x-) lay outside the lookup box."""
    n = x0.shape[0]
    nu = U.shape[1]
    m = Y.shape[1]
    T = U.shape[0]
    d = coords.shape[0]
    xm = x0.copy()
    xp = np.empty(n)
    yh = np.empty(m)
    e = np.empty(m)
    pt = np.empty(d)
    idx = np.zeros(d, dtype=np.int64)
    frac = np.zeros(d)
    u = np.empty(nu)
    store_zone = Z_out.shape[0] == T
    outside = 0
    for k in range(T):
        for i in range(nu):
            u[i] = U[k, i]
        ok = _innovation(h, xm, u, p, Y, k, yh, e)
        if ok:
            for j in range(d):
                c = coords[j]
                pt[j] = u[c] if c < nu else xm[c - nu]
            if uniform:
                r, fl = nearest_node_uniform(lo, inv_h, nmax, strides, pt)
            else:
                r, fl = nearest_node(bp, off, strides, pt, idx, frac)
            if fl != 0:
                outside += 1
            z = labels[r]
            for i in range(n):
                s = xm[i]
                for j in range(m):
                    s += gains[z, i, j] * e[j]
                xp[i] = s
        else:
            z = -1
            for i in range(n):
                xp[i] = xm[i]
        for i in range(n):
            X_out[k, i] = xp[i]
        if store_zone:
            Z_out[k] = z
        f(xp, u, p, xm)
    return outside


@njit(nogil=True)
def ekf_loop(f, jac_f, h, jac_h, U, Y, x0, P0, Q, R, p, X_out, Pd_out):
    """Full EKF over T steps (paper eqs. 5-9): online Jacobians, gain and covariance. x0 (n,),
    P0 (n, n) the a-priori estimate and covariance of step 0; Q (n, n), R (m, m). Writes X_out
    (T, n) the a-posteriori estimates and, when Pd_out has T rows, the diagonal of P(k|k).
    Returns the number of steps whose innovation covariance was not positive definite (no
    correction made).

    The gain step is :func:`pwl.covariance.correct` written out in the loop, with a dense time
    update P = A P A^T + Q (the plant's A has no structure to use). Called, or inlined by numba
    (which then adds reference counting of their arrays every step), the kernels cost 25-70 %
    more on the 2-state chen2020 system: 44 ns per step written out, 54 ns inlined, 74 ns
    called. Compiling the loop without reference counting and using the kernels gave 46 ns.
    This loop is the baseline the SEKF's speed is measured against. Both are tested against
    numpy (``tests/test_zones.py``, ``tests/test_online.py``)."""
    n = x0.shape[0]
    m = Y.shape[1]
    T = U.shape[0]
    xm = x0.copy()
    xp = np.empty(n)
    P = P0.copy()
    A = np.empty((n, n))
    C = np.empty((m, n))
    PCt = np.empty((n, m))
    S = np.empty((m, m))
    L = np.empty((m, m))
    K = np.empty((n, m))
    AP = np.empty((n, n))
    yh = np.empty(m)
    e = np.empty(m)
    u = np.empty(U.shape[1])
    store_p = Pd_out.shape[0] == T
    bad = 0
    for k in range(T):
        for i in range(u.shape[0]):
            u[i] = U[k, i]
        ok = _innovation(h, xm, u, p, Y, k, yh, e)
        if ok:
            jac_h(xm, u, p, C)
            for i in range(n):                      # PCt = P C^T
                for j in range(m):
                    s = 0.0
                    for c in range(n):
                        s += P[i, c] * C[j, c]
                    PCt[i, j] = s
            for i in range(m):                      # S = C P C^T + R
                for j in range(m):
                    s = R[i, j]
                    for c in range(n):
                        s += C[i, c] * PCt[c, j]
                    S[i, j] = s
            if m == 1:                              # K = P C^T S^-1
                ok = S[0, 0] > 0.0
                if ok:
                    si = 1.0 / S[0, 0]
                    for i in range(n):
                        K[i, 0] = PCt[i, 0] * si
            else:
                ok = chol_solve_right(S, PCt, L, K)
            if not ok:
                bad += 1
        if ok:
            for i in range(n):
                s = xm[i]
                for j in range(m):
                    s += K[i, j] * e[j]
                xp[i] = s
            for i in range(n):                      # P = P - K (P C^T)^T
                for j in range(n):
                    s = 0.0
                    for c in range(m):
                        s += K[i, c] * PCt[j, c]
                    P[i, j] -= s
        else:
            for i in range(n):
                xp[i] = xm[i]
        for i in range(n):
            X_out[k, i] = xp[i]
        if store_p:
            for i in range(n):
                Pd_out[k, i] = P[i, i]
        jac_f(xp, u, p, A)
        f(xp, u, p, xm)
        for i in range(n):                          # P = A P A^T + Q
            for j in range(n):
                s = 0.0
                for c in range(n):
                    s += A[i, c] * P[c, j]
                AP[i, j] = s
        for i in range(n):
            for j in range(i, n):
                s = Q[i, j]
                for c in range(n):
                    s += AP[i, c] * A[j, c]
                P[i, j] = s
                P[j, i] = s
    return bad


# ---- Python wrappers -------------------------------------------------------------------------------
def _prep(U, Y, x0):
    U = np.ascontiguousarray(U, dtype=np.float64)
    Y = np.ascontiguousarray(Y, dtype=np.float64)
    if U.ndim == 1:
        U = U[:, None]
    if Y.ndim == 1:
        Y = Y[:, None]
    if U.shape[0] != Y.shape[0]:
        raise ValueError(f"U has {U.shape[0]} steps, Y has {Y.shape[0]}")
    x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(-1)
    return U, Y, x0


def lookup_coords(zones: ZoneTable, names) -> np.ndarray:
    """Indices of the lookup axes of ``zones`` in the list ``names`` of the (u, x) coordinates
    (input names then state names), e.g. ``plant.u_names + plant.x_names``."""
    names = list(names)
    missing = [a for a in zones.grid.names if a not in names]
    if missing:
        raise ZoneError(f"zone lookup axes {missing} are not among the (u, x) coordinates {names}")
    return np.array([names.index(a) for a in zones.grid.names], dtype=np.int64)


def run_sekf(functions, p, zones: ZoneTable, U, Y, x0, return_zones: bool = False,
             force_search: bool = False, coords=None):
    """Scheduled-gain EKF: a-posteriori estimates X (T, n) [, zones (T,) int64], outside count.

    ``functions`` has attributes f and h (numba plant kernels), ``p`` the parameter vector.
    ``coords``: indices in (u, x) of the lookup axes (see :func:`lookup_coords`); default all of
    (u, x) in that order, which needs a lookup grid with nu + n axes.
    """
    U, Y, x0 = _prep(U, Y, x0)
    n = x0.size
    if coords is None:
        if zones.grid.ndim != U.shape[1] + n:
            raise ValueError(f"zone lookup grid has {zones.grid.ndim} axes {zones.grid.names}; "
                             f"(u, x) has {U.shape[1] + n}: give coords")
        coords = np.arange(U.shape[1] + n)
    coords = np.ascontiguousarray(coords, dtype=np.int64)
    if coords.shape != (zones.grid.ndim,) or coords.min() < 0 or coords.max() >= U.shape[1] + n:
        raise ValueError(f"coords {coords} must index {zones.grid.ndim} of the {U.shape[1] + n} "
                         "(u, x) coordinates")
    if zones.gains.shape[1:] != (n, Y.shape[1]):
        raise ValueError(f"zone gains have shape {zones.gains.shape[1:]}, expected {(n, Y.shape[1])}")
    T = U.shape[0]
    X = np.empty((T, n))
    Z = np.empty(T if return_zones else 0, dtype=np.int64)
    out = sekf_loop(functions.f, functions.h, U, Y, x0, np.asarray(p, dtype=np.float64), coords,
                    *zones.kernel_args(force_search), zones.gains, X, Z)
    return (X, Z, out) if return_zones else (X, out)


def run_ekf(functions, p, U, Y, x0, P0, Q, R, return_pdiag: bool = False):
    """Full EKF: a-posteriori estimates X (T, n) [, diag P(k|k) (T, n)], count of skipped
    corrections (innovation covariance not positive definite)."""
    U, Y, x0 = _prep(U, Y, x0)
    n, m = x0.size, Y.shape[1]
    f64 = lambda a, s: np.ascontiguousarray(np.atleast_2d(a), dtype=np.float64).reshape(s)  # noqa: E731
    P0, Q, R = f64(P0, (n, n)), f64(Q, (n, n)), f64(R, (m, m))
    T = U.shape[0]
    X = np.empty((T, n))
    Pd = np.empty((T if return_pdiag else 0, n))
    bad = ekf_loop(functions.f, functions.jac_f, functions.h, functions.jac_h, U, Y, x0, P0, Q, R,
                   np.asarray(p, dtype=np.float64), X, Pd)
    return (X, Pd, bad) if return_pdiag else (X, bad)
