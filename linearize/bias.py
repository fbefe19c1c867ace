"""Offline steady-state gain of the bias observer (seed 004, eqs. 7-9 and 13).

The observer's system, with the sensor pole a (per sample) and the model input delayed by tau::

    x = [theta, lambda_f]^T,   A = [[1, 0], [1 - a, a]],   B = [0, 1 - a]^T,   C = [0, 1]
    W = diag(sigma_w^2, 0)     (random-walk bias),   V = sigma_v^2 (sensor noise)

Only the ratio sigma_w^2 / sigma_v^2 matters for the gain (the paper tunes with 1/80 and 1/30).
K_inf comes from the project's one gain formula :func:`linearize.kalman.steady_state_gain`
(update form: x[k|k] = x[k|k-1] + K e[k]), as the builder's gains do; the observer
(:mod:`experiments.bias_observer`) only receives the numbers.
"""
from __future__ import annotations

import numpy as np

from .kalman import steady_state_gain


def observer_matrices(a: float):
    """(A, B, C) of eq. (9) for the sensor pole a (0 <= a < 1)."""
    a = float(a)
    if not 0.0 <= a < 1.0:
        raise ValueError(f"sensor pole a must be in [0, 1), got {a}")
    A = np.array([[1.0, 0.0], [1.0 - a, a]])
    B = np.array([0.0, 1.0 - a])
    C = np.array([[0.0, 1.0]])
    return A, B, C


def observer_gain(a: float, ratio: float, sigma_v2: float = 1.0):
    """Steady-state update gain K_inf (2,) and a-priori covariance P (2, 2) of the bias observer.

    ``ratio`` = sigma_w^2 / sigma_v^2 (> 0), ``sigma_v2`` the sensor noise variance (scales P only).
    """
    if not ratio > 0:
        raise ValueError(f"noise ratio sigma_w^2/sigma_v^2 must be > 0, got {ratio}")
    A, _, C = observer_matrices(a)
    Q = np.diag([ratio * sigma_v2, 0.0])
    R = np.array([[sigma_v2]])
    K, P = steady_state_gain(A, C, Q, R, where=f"bias observer a={a:g}, ratio={ratio:g}")
    return K[:, 0].copy(), P
