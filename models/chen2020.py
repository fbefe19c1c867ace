"""The two-state nonlinear test system of Chen (2020), seed paper 001, eqs. (10)-(12), Table 1.

Discrete time, sample time Ts = 0.01 s (dimensionless states)::

    x1[k+1] = x1 + Ts (k1 x1^3 + k2 x1 - k3 - x2 + k4 u) + w1
    x2[k+1] = x2 + Ts a (b x1 - k5 x2^m)                + w2        m = 1 (default) or 2
    y[k]    = x1[k] + v[k]

Table 1: k1 = -0.04, k2 = 5, k3 = 140, k4 = 300, k5 = 0.4, a = 0.02, b = 0.2, c = -50, Ts = 0.01.
Filter covariances (Table 2): Q = 0.01 I2, R = 0.01.

Assumptions (the text extraction of the paper is garbled; docs/zones.md gives the reasoning):

* **x2 equation, exponent m.** The extraction gives the x2 line twice, once as
  ``a(b x1 - k5 x2^2)`` and once as ``a(b x1 - k5 x2)``. The default is the linear form m = 1:
  it is the recovery equation a (b v - u) of the Izhikevich / FitzHugh-Nagumo neuron model this
  system is built from (a = 0.02, b = 0.2, c = -50 are Izhikevich's constants), and it is
  globally stable; with m = 2 the x2 equation has a finite escape for x2 < 0 and the plant
  diverges under the paper's noise level (x2 is a slow random walk). ``x2_power=2`` selects the
  other reading.
* **c = -50** appears in Table 1 but in none of the surviving equations. It is Izhikevich's
  after-spike reset of the fast variable; the cubic k1 x1^3 term (k1 < 0) replaces the spike and
  reset, so c is kept in the parameters (stored, reported) and unused by the dynamics.
* **Input.** The paper gives no input range or signal. u in [0, 1] is used for the operating
  points: 300 u - 140 spans the range where x1 switches between its negative and positive stable
  branches (|x1| > 6.45 is locally stable, near 0 the x1 dynamics are unstable). The test signal
  is a random piecewise-constant level in [0.2, 0.8] held for 1 to 3 s, which makes x1 jump
  between branches (the regime where the gain changes most).
* **Plant noise.** The paper says the noise used to simulate the plant differs from the filter's
  Q, R but gives no values. Default plant noise: Q_sim = diag(0.005, 0.02) (x1 half, x2 double
  the filter's) and R_sim = 0.02 (double). Both can be set.
* **Initial state.** x0 = (-16, -6) (near the negative-branch equilibrium at u = 0.5 level
  switching), filter start x_hat0 = x0 + N(0, P0) drawn per run, P0 = diag(1, 1).

Numba kernels (``cache=True``) take a parameter vector ``p`` (see :data:`P_NAMES`) and write
into caller-provided output arrays (no allocation), so the pwl runtime can call them per step.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

#: layout of the float64 parameter vector p of the kernels
P_NAMES = ("k1", "k2", "k3", "k4", "k5", "a", "b", "c", "Ts", "x2_power")
TABLE1 = {"k1": -0.04, "k2": 5.0, "k3": 140.0, "k4": 300.0, "k5": 0.4, "a": 0.02, "b": 0.2,
          "c": -50.0, "Ts": 0.01}

PlantFunctions = namedtuple("PlantFunctions", "f jac_f h jac_h")
PlantFunctions.__doc__ = """The numba kernels of a discrete plant, all ``(x, u, p, out) -> None``:
f writes x[k+1] (n,), jac_f df/dx (n, n), h writes y (m,), jac_h dh/dx (m, n)."""


@njit(cache=True, nogil=True)
def _x2_term(x2, m):
    return x2 * x2 if m == 2.0 else x2


@njit(cache=True, nogil=True)
def f(x, u, p, out):
    """Noise-free next state: x (2,), u (1,), p (10,) -> out (2,)."""
    x1 = x[0]
    x2 = x[1]
    Ts = p[8]
    out[0] = x1 + Ts * (p[0] * x1 * x1 * x1 + p[1] * x1 - p[2] - x2 + p[3] * u[0])
    out[1] = x2 + Ts * p[5] * (p[6] * x1 - p[4] * _x2_term(x2, p[9]))


@njit(cache=True, nogil=True)
def jac_f(x, u, p, out):
    """Analytic df/dx at (x, u): out (2, 2)."""
    x1 = x[0]
    Ts = p[8]
    out[0, 0] = 1.0 + Ts * (3.0 * p[0] * x1 * x1 + p[1])
    out[0, 1] = -Ts
    out[1, 0] = Ts * p[5] * p[6]
    d2 = 2.0 * x[1] if p[9] == 2.0 else 1.0
    out[1, 1] = 1.0 - Ts * p[5] * p[4] * d2


@njit(cache=True, nogil=True)
def h(x, u, p, out):
    """Measurement y = x1: out (1,)."""
    out[0] = x[0]


@njit(cache=True, nogil=True)
def jac_h(x, u, p, out):
    """dh/dx: out (1, 2) = [1, 0]."""
    out[0, 0] = 1.0
    out[0, 1] = 0.0


@njit(cache=True, nogil=True)
def _simulate(x0, U, W, V, p, X, Y):
    """X[k] true state (T+1, 2) from x0; Y[k] = h(X[k]) + V[k] (T, 1); W (T, 2) process noise."""
    xn = np.empty(2)
    yk = np.empty(1)
    X[0] = x0
    for k in range(U.shape[0]):
        h(X[k], U[k], p, yk)
        Y[k, 0] = yk[0] + V[k, 0]
        f(X[k], U[k], p, xn)
        X[k + 1, 0] = xn[0] + W[k, 0]
        X[k + 1, 1] = xn[1] + W[k, 1]


class Chen2020:
    """The plant object: names, parameters, kernels, covariances, operating box, simulation.

    Satisfies the discrete-time part of the Plant protocol (``evaluate``); ``functions`` holds
    the numba kernels used by :mod:`experiments.ekf` (SEKF and EKF loops) and the zone builder.
    """

    name = "chen2020"
    x_names = ("x1", "x2")
    u_names = ("u",)
    y_names = ("y",)
    z_names = ()
    h_names = ()
    p_names = ("u", "x1", "x2")      # the scheduling coordinates of the zones: (u, x)
    units = {"x1": "-", "x2": "-", "u": "-", "y": "-"}
    time = "discrete"
    functions = PlantFunctions(f, jac_f, h, jac_h)

    def __init__(self, x2_power: int = 1, Q_sim=None, R_sim=None, **overrides):
        if x2_power not in (1, 2):
            raise ValueError(f"x2_power must be 1 or 2, got {x2_power!r}")
        unknown = set(overrides) - set(TABLE1)
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}; known: {sorted(TABLE1)}")
        self.params = dict(TABLE1, **overrides, x2_power=float(x2_power))
        self.p = np.array([self.params[k] for k in P_NAMES], dtype=np.float64)
        self.dt = self.params["Ts"]
        self.Q = np.diag([0.01, 0.01])                  # filter process noise (Table 2)
        self.R = np.array([[0.01]])                     # filter measurement noise (Table 2)
        self.Q_sim = np.diag([0.005, 0.02]) if Q_sim is None else np.atleast_2d(Q_sim).astype(float)
        self.R_sim = np.array([[0.02]]) if R_sim is None else np.atleast_2d(R_sim).astype(float)
        self.x0 = np.array([-16.0, -6.0])
        self.P0 = np.eye(2)
        # operating box for the random operating points: u, x1, x2. It covers the test
        # trajectories: x1 stays within +-18; x2 is a slow random walk under the plant noise
        # (stationary std ~ 11, see docs/zones.md) and reaches +-35 in rare runs.
        self.box_lo = np.array([0.0, -20.0, -40.0])
        self.box_hi = np.array([1.0, 20.0, 40.0])

    # ---- Plant protocol (discrete) -----------------------------------------------------------
    def parameters(self) -> dict:
        return dict(self.params)

    def evaluate(self, x, u, h_=None, env=None):
        """(x[k+1] (2,), y (1,), z (0,)) at x (2,), u (1,); h and env unused."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        u = np.ascontiguousarray(np.atleast_1d(u), dtype=np.float64)
        xn, y = np.empty(2), np.empty(1)
        f(x, u, self.p, xn)
        h(x, u, self.p, y)
        return xn, y, np.empty(0)

    def linearize(self, x, u):
        """Analytic (A (2, 2), C (1, 2)) at (x, u)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        u = np.ascontiguousarray(np.atleast_1d(u), dtype=np.float64)
        A, C = np.empty((2, 2)), np.empty((1, 2))
        jac_f(x, u, self.p, A)
        jac_h(x, u, self.p, C)
        return A, C

    # ---- experiment ----------------------------------------------------------------------------
    def input_signal(self, T: int, rng) -> np.ndarray:
        """Random piecewise-constant u (T, 1): levels U[0.2, 0.8], each held 1..3 s."""
        u = np.empty(T)
        k = 0
        while k < T:
            n = int(rng.integers(int(1.0 / self.dt), int(3.0 / self.dt) + 1))
            u[k:k + n] = rng.uniform(0.2, 0.8)
            k += n
        return u[:, None]

    def simulate(self, U, rng, x0=None):
        """True states X (T+1, 2) and measurements Y (T, 1) for inputs U (T, 1) with plant noise
        Q_sim, R_sim drawn from ``rng``; y[k] = x1[k] + v[k], x[k+1] = f(x[k], u[k]) + w[k]."""
        U = np.ascontiguousarray(U, dtype=np.float64).reshape(-1, 1)
        T = U.shape[0]
        W = rng.multivariate_normal(np.zeros(2), self.Q_sim, size=T)
        V = rng.multivariate_normal(np.zeros(1), self.R_sim, size=T)
        X = np.empty((T + 1, 2))
        Y = np.empty((T, 1))
        x0 = self.x0 if x0 is None else np.asarray(x0, dtype=np.float64)
        _simulate(x0, U, W, V, self.p, X, Y)
        return X, Y
