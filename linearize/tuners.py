"""Tuner selection q = V (h - h_ref): subset selection and optimal tuners (Simon & Garg 2010;
Simon, Armstrong & Garg 2011), both scored by the same covariance analysis.

Covariance analysis at one dynamics point (discrete, deviation variables). The true system
carries the full health vector h, a constant random vector with covariance Ph:

    x[k+1] = A x + L h + w        w ~ N(0, Qx)
    y[k]   = C x + M h + v        v ~ N(0, R)
    z[k]   = F x + N h

The filter runs on the reduced augmented model [x; q] (``pwl.runtime.augment``) with its
steady-state update gain K (tuners modelled as random walks of covariance V Qh V^T). With the
joint state s = [x; xi_minus]:

    s[k+1] = Phi s + Gh h + Gw w + Gv v,   Phi = [[A, 0], [Aa K C, Aa (I - K Ca)]]

so the estimation error of any target e = Ts s + Th h + Tv v has a bias part (steady response to
the constant h) and a noise part (discrete Lyapunov equation); its mean square, averaged over h,
is tr(Ts S Ts^T) + tr(Tv R Tv^T) + tr(G Ph G^T), G = Ts (I - Phi)^-1 Gh + Th.

Targets are health parameters (errors in fractions) and unmeasured outputs (errors relative to
the trim value); the metric is the sum of their mean squares, averaged over the envelope points.
"""
from __future__ import annotations

import itertools

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from pwl.errors import PwlError
from pwl.runtime import augment

from .kalman import GainError, steady_state_gain


class TunerError(PwlError, ValueError):
    """No tuner choice gives a usable filter (names the reason)."""


def point_mse(mats: dict, V, Qx, Qh, R, Ph, z_scale, targets) -> np.ndarray:
    """Mean squared estimation error of each target at one point (inf if no stable gain).

    mats: discrete A, B, C, D, F, G, L, M, N (one point); V (nq, nh); Qx (nx, nx); Qh (nh, nh)
    health random-walk covariance of the filter; R (ny, ny); Ph (nh, nh) prior covariance of the
    true health; z_scale (nz,) normalisation of z errors; targets: indices into [h (nh); z (nz)].
    """
    V = np.atleast_2d(V)
    # work in units of the noise (x / sigma_x, y / sigma_y): the metric is invariant under this
    # similarity, and engine states in rpm next to fractions would make the Lyapunov solve singular
    sx = np.sqrt(np.diag(Qx))
    sy = np.sqrt(np.diag(R))
    mats = dict(mats)
    mats["A"] = mats["A"] * sx[None, :] / sx[:, None]
    mats["L"] = mats["L"] / sx[:, None]
    mats["C"] = mats["C"] * sx[None, :] / sy[:, None]
    mats["M"] = mats["M"] / sy[:, None]
    mats["F"] = mats["F"] * sx[None, :]
    mats["B"] = mats["B"] / sx[:, None]
    mats["D"] = mats["D"] / sy[:, None]
    Qx = Qx / np.outer(sx, sx)
    R = R / np.outer(sy, sy)
    Vp = np.linalg.pinv(V)
    nx, nh, nq = mats["A"].shape[0], V.shape[1], V.shape[0]
    aug = augment(mats, Vp)
    Aa, Ca, Fa = aug["A"], aug["C"], aug["F"]
    na = nx + nq
    Qa = np.zeros((na, na))
    Qa[:nx, :nx] = Qx
    Qa[nx:, nx:] = V @ Qh @ V.T
    try:
        K, _ = steady_state_gain(Aa, Ca, Qa, R)
    except GainError:
        return np.full(len(targets), np.inf)
    A, C, F, L, M, N = (mats[k] for k in "ACFLMN")
    I_na = np.eye(na)
    J = np.hstack([K @ C, I_na - K @ Ca])                      # xi_plus = J s + K M h + K v
    Phi = np.block([[A, np.zeros((nx, na))], [Aa @ K @ C, Aa @ (I_na - K @ Ca)]])
    Gh = np.vstack([L, Aa @ K @ M])
    Gw = np.vstack([np.eye(nx), np.zeros((na, nx))])
    Gv = np.vstack([np.zeros((nx, C.shape[0])), Aa @ K])
    Eq = np.hstack([np.zeros((nq, nx)), np.eye(nq)])
    Sx = np.hstack([np.eye(nx), np.zeros((nx, na))])
    # targets: h errors, then z errors relative to z_scale
    Ts = np.vstack([-Vp @ Eq @ J, (F @ Sx - Fa @ J) / z_scale[:, None]])
    Th = np.vstack([np.eye(nh) - Vp @ Eq @ K @ M, (N - Fa @ K @ M) / z_scale[:, None]])
    Tv = np.vstack([-Vp @ Eq @ K, -Fa @ K / z_scale[:, None]])
    Ts, Th, Tv = Ts[targets], Th[targets], Tv[targets]
    S = solve_discrete_lyapunov(Phi, Gw @ Qx @ Gw.T + Gv @ R @ Gv.T)
    G = Ts @ np.linalg.solve(np.eye(nx + na) - Phi, Gh) + Th
    mse = (np.einsum("ij,jk,ik->i", Ts, S, Ts) + np.einsum("ij,jk,ik->i", Tv, R, Tv)
           + np.einsum("ij,jk,ik->i", G, Ph, G))
    return mse


def envelope_mse(points: list, V, Ph, targets) -> np.ndarray:
    """Target mean squares averaged over ``points``: dicts with mats, Qx, Qh, R, z_scale."""
    acc = np.zeros(len(targets))
    for pt in points:
        acc += point_mse(pt["mats"], V, pt["Qx"], pt["Qh"], pt["R"], Ph, pt["z_scale"], targets)
    return acc / len(points)


def select_subset(points, nq: int, Ph, targets, progress=None):
    """Exhaustive subset selection: the nq health parameters whose tuners minimise the metric.

    Returns (V (nq, nh) selection matrix, metric, per-target mse, ranking list of (metric, subset)).
    """
    nh = Ph.shape[0]
    if not 1 <= nq <= nh:
        raise TunerError(f"number of tuners {nq} must be in 1..{nh}")
    subsets = list(itertools.combinations(range(nh), nq))
    ranking = []
    for i, S in enumerate(subsets):
        V = np.eye(nh)[list(S)]
        mse = envelope_mse(points, V, Ph, targets)
        ranking.append((float(mse.sum()), S, mse))
        if progress:
            progress(i + 1, len(subsets))
    ranking.sort(key=lambda r: r[0])
    best = ranking[0]
    if not np.isfinite(best[0]):
        raise TunerError(f"no subset of {nq} tuners gives a detectable system at every point")
    return np.eye(nh)[list(best[1])], best[0], best[2], [(m, S) for m, S, _ in ranking]


def optimal_tuners(points, V0, Ph, targets, maxiter: int = 40, progress=None):
    """Optimal tuner selection: a dense V minimising the same metric over the envelope.

    The metric depends on the row space of V only (q -> T q leaves the estimates unchanged), so
    V is parametrised as V[:, S] = I, V[:, rest] = W with S the columns of the starting subset
    ``V0`` (its metric is the starting value: the result is never worse). Returns (V, metric, mse).
    """
    from scipy.optimize import minimize

    nq, nh = V0.shape
    S = [int(np.argmax(r)) for r in V0]
    rest = [j for j in range(nh) if j not in S]

    def make(w):
        V = np.zeros((nq, nh))
        V[:, S] = np.eye(nq)
        V[:, rest] = w.reshape(nq, len(rest))
        return V

    calls = [0]

    def cost(w):
        calls[0] += 1
        m = float(envelope_mse(points, make(w), Ph, targets).sum())
        return m if np.isfinite(m) else 1e30

    w0 = np.zeros(nq * len(rest))
    f0 = cost(w0)
    it = [0]

    def cb(_w):
        it[0] += 1
        if progress:
            progress(it[0], maxiter)

    res = minimize(cost, w0, method="L-BFGS-B", callback=cb,
                   options={"maxiter": maxiter, "eps": 1e-5})
    w = res.x if res.fun <= f0 else w0
    V = make(w)
    mse = envelope_mse(points, V, Ph, targets)
    return V, float(mse.sum()), mse
