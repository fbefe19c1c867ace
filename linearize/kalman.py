"""The one steady-state Kalman gain formula of the project (DESIGN.md section 3).

For x[k+1] = A x[k] + w, y[k] = C x[k] + v, w ~ N(0, Q), v ~ N(0, R):

    P = DARE(A^T, C^T, Q, R)                  a-priori steady-state error covariance
    K = P C^T (C P C^T + R)^-1                update (current-estimator, "filter") gain

so that x[k|k] = x[k|k-1] + K (y[k] - C x[k|k-1] - D u[k]). python-control's ``dlqe`` returns the
predictor gain A K instead (see :func:`predictor_gain`).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_discrete_are

from pwl.errors import PwlError


class GainError(PwlError, ValueError):
    """No usable steady-state gain (undetectable pair, DARE failure, residual or stability check)."""


def steady_state_gain(A, C, Q, R, *, residual_tol: float = 1e-8, where: str = ""):
    """Update gain K (n, m) and a-priori covariance P (n, n) of the steady-state Kalman filter.

    A (n, n), C (m, n), Q (n, n) symmetric PSD, R (m, m) symmetric PD. Checks the relative Riccati
    residual (<= residual_tol) and that the error dynamics (I - K C) A are strictly stable;
    raises :class:`GainError` (naming ``where``) otherwise.
    """
    A, C, Q, R = (np.atleast_2d(np.asarray(M, dtype=np.float64)) for M in (A, C, Q, R))
    at = f" at {where}" if where else ""
    n = A.shape[0]
    try:
        P = solve_discrete_are(A.T, C.T, Q, R)
    except (np.linalg.LinAlgError, ValueError) as e:
        raise GainError(f"DARE has no stabilizing solution{at} (undetectable pair?): {e}") from None
    P = 0.5 * (P + P.T)
    S = C @ P @ C.T + R
    K = np.linalg.solve(S, C @ P).T
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(K))):
        raise GainError(f"non-finite gain{at}")
    res = riccati_residual(A, C, Q, R, P)
    scale = max(np.abs(P).max(), np.abs(Q).max(), 1e-300)
    if res > residual_tol * scale:
        raise GainError(f"Riccati residual {res:.3g} exceeds {residual_tol:g} x {scale:.3g}{at}")
    rho = np.abs(np.linalg.eigvals((np.eye(n) - K @ C) @ A)).max()
    if not rho < 1.0:
        raise GainError(f"error dynamics (I - K C) A not stable{at}: spectral radius {rho:.6g}")
    return K, P


def riccati_residual(A, C, Q, R, P) -> float:
    """max |A P A^T - P - A P C^T (C P C^T + R)^-1 C P A^T + Q| (filter form of the DARE)."""
    APC = A @ P @ C.T
    S = C @ P @ C.T + R
    F = A @ P @ A.T - P - APC @ np.linalg.solve(S, APC.T) + Q
    return float(np.abs(F).max())


def predictor_gain(A, K):
    """Predictor gain L = A K, as returned by python-control's ``dlqe``."""
    return np.asarray(A) @ np.asarray(K)
