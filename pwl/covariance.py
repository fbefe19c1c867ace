"""Online Kalman covariance steps (numba, in place, no allocation): the time-varying filter.

The steady-state filter of the runtime uses gains solved offline (:mod:`linearize.kalman`, the DARE).
A full (extended) Kalman filter instead carries the error covariance P and solves the gain every
step from the current Jacobians; these kernels are that step, used by the online-covariance mode
of :mod:`pwl.runtime`::

    correct:    S = C P C^T + R,  K = P C^T S^-1,  P <- P - K (P C^T)^T      (measurement update)
    propagate_augmented:  P <- A P A^T + Q  for A = [[A_top], [0 I]]             (time update)

The time update is written for the augmented model, whose tuner rows are a random walk: 2 r n^2
flops instead of the 2 n^3 of a dense product (r = rows of A_top; 324 instead of 1,458 for the
demo database), so the online filter is not slower than it needs to be.

P is the a-priori covariance before ``correct`` and the a-posteriori one after it; ``K`` is the
update ("filter") gain of :mod:`linearize.kalman`, x(k|k) = x(k|k-1) + K (y - y_hat).

:func:`experiments.ekf.ekf_loop` (the seed-001 baseline) writes ``correct`` and a dense time update
out in its loop (see there why).
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
def propagate_augmented(A_top, P, Q, AP):
    """P (n, n) <- A P A^T + Q for the augmented matrix A = [[A_top], [0 I]] of the piecewise-linear
    model (its tuner rows are a random walk): A_top (r, n) the state rows, P and Q (n, n), AP
    (r, n) a work array. Only the products with A_top are formed; P stays exactly symmetric."""
    r, n = A_top.shape
    for i in range(r):                      # AP = A_top P (the top rows of A P)
        for j in range(n):
            s = 0.0
            for c in range(n):
                s += A_top[i, c] * P[c, j]
            AP[i, j] = s
    for i in range(r):                      # top-left and top-right blocks: A_top P A^T
        for j in range(i, r):
            s = Q[i, j]
            for c in range(n):
                s += AP[i, c] * A_top[j, c]
            P[i, j] = s
            P[j, i] = s
        for j in range(r, n):               # rows of A below r are unit rows: (A P A^T)[i, j] = AP[i, j]
            s = AP[i, j] + Q[i, j]
            P[i, j] = s
            P[j, i] = s
    for i in range(r, n):                   # bottom-right block: P_qq + Q_qq
        for j in range(i, n):
            s = P[i, j] + Q[i, j]
            P[i, j] = s
            P[j, i] = s
