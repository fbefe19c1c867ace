"""The one gain formula against closed forms, scipy's DARE, python-control and the iterated
Riccati recursion (REFERENCES.md)."""
import control
import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from linearize.kalman import GainError, predictor_gain, riccati_residual, steady_state_gain


def test_scalar_closed_form():
    # a = 0.5, q = r = 1: P = (1 + sqrt 65) / 8, update gain M = P / (P + 1), predictor L = a M
    K, P = steady_state_gain([[0.5]], [[1.0]], [[1.0]], [[1.0]])
    assert P[0, 0] == pytest.approx((1 + np.sqrt(65)) / 8, rel=1e-12)
    assert K[0, 0] == pytest.approx(0.5311289, abs=1e-7)
    assert predictor_gain([[0.5]], K)[0, 0] == pytest.approx(0.2655644, abs=1e-7)


def test_update_vs_predictor_convention_python_control():
    # python-control's dlqe test: A = 0, G = 0.1, C = 1, QN = 10, RN = 2 -> P = 0.1, L = 0, M = 1/21
    K, P = steady_state_gain([[0.0]], [[1.0]], [[0.1 * 10 * 0.1]], [[2.0]])
    assert P[0, 0] == pytest.approx(0.1, rel=1e-12)
    assert K[0, 0] == pytest.approx(0.1 / 2.1, rel=1e-12)
    L, Pc, _ = control.dlqe(np.zeros((1, 1)), 0.1 * np.eye(1), np.eye(1), 10 * np.eye(1), 2 * np.eye(1))
    assert np.asarray(L)[0, 0] == pytest.approx(0.0, abs=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_random_systems_against_scipy_control_and_iteration(seed):
    rng = np.random.default_rng(seed)
    n, m = 4, 2
    A = rng.normal(size=(n, n))
    A *= 1.3 / np.abs(np.linalg.eigvals(A)).max()  # an unstable plant: the gain must stabilise it
    C = rng.normal(size=(m, n))
    W = rng.normal(size=(n, n))
    Q = W @ W.T * 0.1 + 1e-3 * np.eye(n)
    R = np.diag(rng.uniform(0.1, 1.0, m))
    K, P = steady_state_gain(A, C, Q, R)
    Pref = solve_discrete_are(A.T, C.T, Q, R)
    Kref = Pref @ C.T @ np.linalg.inv(C @ Pref @ C.T + R)
    np.testing.assert_allclose(K, Kref, rtol=1e-9, atol=1e-12)
    L, Pc, _ = control.dlqe(A, np.eye(n), C, Q, R)
    np.testing.assert_allclose(predictor_gain(A, K), np.asarray(L), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(P, np.asarray(Pc), rtol=1e-8, atol=1e-10)
    # the a-priori Riccati recursion converges to the same P
    Pi = np.eye(n)
    for _ in range(5000):
        Pi = A @ (Pi - Pi @ C.T @ np.linalg.solve(C @ Pi @ C.T + R, C @ Pi)) @ A.T + Q
    np.testing.assert_allclose(P, Pi, rtol=1e-8, atol=1e-10)
    assert riccati_residual(A, C, Q, R, P) < 1e-9 * np.abs(P).max()
    assert np.abs(np.linalg.eigvals((np.eye(n) - K @ C) @ A)).max() < 1


@pytest.mark.parametrize("n", [2, 3, 5])
def test_darex_4_1(n):
    # SLICOT DAREX 4.1 (control form): A = superdiagonal ones, B = e_n, Q = I: X = diag(1..n).
    # The filter form solves the dual: A_f = A^T, C_f = B^T.
    A = np.diag(np.ones(n - 1), 1)
    B = np.zeros((n, 1))
    B[-1] = 1
    K, P = steady_state_gain(A.T, B.T, np.eye(n), [[0.7]])
    np.testing.assert_allclose(P, np.diag(np.arange(1.0, n + 1)), atol=1e-10)


def test_undetectable_pair_is_a_named_error():
    # an unstable mode that C does not see
    A = np.diag([1.2, 0.5])
    C = np.array([[0.0, 1.0]])
    with pytest.raises(GainError, match="point 7"):
        steady_state_gain(A, C, np.eye(2), [[1.0]], where="point 7")
