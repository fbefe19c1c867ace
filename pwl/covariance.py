"""Online Kalman covariance steps (numba, in place, no allocation): the time-varying filter.

The steady-state filter of the runtime uses gains solved offline (:mod:`linearize.kalman`, the DARE).
A full (extended) Kalman filter instead carries the error covariance P and solves the gain every
step from the current Jacobians; these kernels are that step, used by the online-covariance mode
of :mod:`pwl.runtime` (and, written out, by the EKF of :mod:`pwl.ekf`)::

    correct:    S = C P C^T + R,  K = P C^T S^-1,  P <- P - K (P C^T)^T      (measurement update)
    propagate:  P <- A P A^T + Q                                             (time update)

P is the a-priori covariance before ``correct`` and the a-posteriori one after it; ``K`` is the
update ("filter") gain of :mod:`linearize.kalman`, x(k|k) = x(k|k-1) + K (y - y_hat).

:func:`pwl.ekf.ekf_loop` writes ``correct`` and ``propagate`` out in its loop (see there why).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def chol_solve_right(S, B, L, out):
    """out = B S^-1 for symmetric positive definite S (m, m), B (n, m); L (m, m) work array.
    Returns False (out untouched) when S is not positive definite."""
    m = S.shape[0]
    for i in range(m):
        for j in range(i + 1):
            s = S[i, j]
            for c in range(j):
                s -= L[i, c] * L[j, c]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    # rows of out solve S out_r^T = b_r^T: forward (L) then backward (L^T)
    for r in range(B.shape[0]):
        for i in range(m):
            s = B[r, i]
            for c in range(i):
                s -= L[i, c] * out[r, c]
            out[r, i] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = out[r, i]
            for c in range(i + 1, m):
                s -= L[c, i] * out[r, c]
            out[r, i] = s / L[i, i]
    return True


@njit(cache=True, nogil=True)
def correct(P, C, R, PCt, S, L, K):
    """Measurement update of the covariance: K (n, m) = P C^T (C P C^T + R)^-1 and P (n, n) <-
    P - K (P C^T)^T. C (m, n), R (m, m); PCt (n, m), S and L (m, m) work arrays. Returns False
    (P and K untouched) when C P C^T + R is not positive definite."""
    n = P.shape[0]
    m = C.shape[0]
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
    if ok:
        for i in range(n):                  # P = P - K (P C^T)^T
            for j in range(n):
                s = 0.0
                for c in range(m):
                    s += K[i, c] * PCt[j, c]
                P[i, j] -= s
    return ok


@njit(cache=True, nogil=True)
def propagate(A, P, Q, AP):
    """Time update of the covariance: P (n, n) <- A P A^T + Q (kept exactly symmetric); AP (n, n)
    a work array."""
    n = P.shape[0]
    for i in range(n):
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
