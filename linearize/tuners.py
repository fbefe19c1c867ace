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
import warnings
from concurrent.futures import as_completed

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from pwl.errors import PwlError
from pwl.runtime import augment

from . import threads
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


#: point_mse calls per task of an evaluation through an executor (at most): 0.07-0.1 s of work
#: (1.6 ms a call on the 2-core test machine), so that pickling a task's points and tuner
#: matrices and its round trip (about 1 ms to a process pool, a few ms to Dask) cost 1-5 %,
#: while a batch still balances over the workers (the 22 evaluations of a gradient on 110
#: points: 55 tasks of 44 calls; the 120 subsets of 7 in 10: 220 tasks of 56-64)
TASK_CALLS = 64

#: finite-difference step of the optimal tuners' gradient, in the units of W (tuner weights)
FD_STEP = 1e-5


def point_mses(points: list, Vs: list, Ph, targets) -> np.ndarray:
    """(nV, npoints, ntargets) :func:`point_mse` of every tuner matrix in ``Vs`` (each (nq, nh))
    at every point (dicts with mats, Qx, Qh, R, z_scale): the task an executor runs.

    Without scipy's 'Input "a" has an eigenvalue pair whose sum is very close to or exactly zero'
    RuntimeWarning (here, so also in a worker process): the discrete Lyapunov solve warns for a
    candidate V that leaves a health direction undetectable at some point (the joint error
    dynamics keep an eigenvalue at 1); that candidate's metric is infinite and never chosen."""
    out = np.empty((len(Vs), len(points), len(targets)))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message='Input "a" has an eigenvalue pair', category=RuntimeWarning)
        for a, V in enumerate(Vs):
            for i, pt in enumerate(points):
                out[a, i] = point_mse(pt["mats"], V, pt["Qx"], pt["Qh"], pt["R"], Ph, pt["z_scale"], targets)
    return out


def task_blocks(n_v: int, n_points: int, task_calls: int = TASK_CALLS) -> list:
    """Cover the (n_v, n_points) evaluations with tasks of about ``task_calls`` each: a list of
    (V slice, point slice); points are split in near-equal contiguous chunks (a task ships only
    its own points), the tuner matrices in blocks when one point already fills a task."""
    per_task = max(1, min(n_points, task_calls // max(n_v, 1)))
    chunks = -(-n_points // per_task)
    edges = np.linspace(0, n_points, chunks + 1).round().astype(int)
    v_block = max(1, task_calls // max(int(np.diff(edges).max()), 1))
    return [(slice(v, min(v + v_block, n_v)), slice(int(a), int(b)))
            for a, b in zip(edges[:-1], edges[1:]) for v in range(0, n_v, v_block)]


def _per_point(points, Vs, Ph, targets, executor, progress):
    """(nV, npoints, ntargets) of :func:`point_mses`, in this process (``executor`` None) or
    as tasks of :func:`task_blocks` through ``executor``; ``progress(done, total)`` per task."""
    out = np.empty((len(Vs), len(points), len(targets)))
    blocks = task_blocks(len(Vs), len(points))
    if executor is None:
        for k, (vs, ps) in enumerate(blocks):
            out[vs, ps] = point_mses(points[ps], Vs[vs], Ph, targets)
            if progress:
                progress(k + 1, len(blocks))
        return out
    futs = {executor.submit(threads.call, point_mses, points[ps], Vs[vs], Ph, targets): (vs, ps)
            for vs, ps in blocks}
    for k, fut in enumerate(as_completed(futs)):
        vs, ps = futs[fut]
        out[vs, ps] = fut.result()
        if progress:
            progress(k + 1, len(blocks))
    return out


def envelope_mses(points: list, Vs: list, Ph, targets, executor=None, progress=None) -> np.ndarray:
    """(nV, ntargets) target mean squares of each tuner matrix in ``Vs`` averaged over ``points``.

    ``executor``: a ``concurrent.futures.Executor`` (process pool, Dask ``client.get_executor()``)
    to spread the evaluations over, or None (here). Each point's contribution is added in point
    order whatever ran it, so the result is bit-for-bit the serial one."""
    points, Vs = list(points), [np.atleast_2d(V) for V in Vs]
    per = _per_point(points, Vs, Ph, targets, executor, progress)
    acc = np.zeros((len(Vs), len(targets)))
    for i in range(len(points)):
        acc += per[:, i]
    return acc / len(points)


def envelope_mse(points: list, V, Ph, targets, executor=None) -> np.ndarray:
    """(ntargets,) target mean squares of V averaged over ``points``: dicts with mats, Qx, Qh, R,
    z_scale (see :func:`envelope_mses` for ``executor``)."""
    return envelope_mses(points, [V], Ph, targets, executor)[0]


def select_subset(points, nq: int, Ph, targets, progress=None, executor=None):
    """Exhaustive subset selection: the nq health parameters whose tuners minimise the metric.

    Every subset is scored in one batch (through ``executor`` when given: the same numbers).
    Returns (V (nq, nh) selection matrix, metric, per-target mse, ranking list of (metric, subset)).
    """
    nh = Ph.shape[0]
    if not 1 <= nq <= nh:
        raise TunerError(f"number of tuners {nq} must be in 1..{nh}")
    subsets = list(itertools.combinations(range(nh), nq))
    n = len(subsets)
    tick = (lambda d, total: progress(d * n // total, n)) if progress else None
    mses = envelope_mses(points, [np.eye(nh)[list(S)] for S in subsets], Ph, targets, executor, tick)
    ranking = sorted(((float(mse.sum()), S, mse) for S, mse in zip(subsets, mses)), key=lambda r: r[0])
    best = ranking[0]
    if not np.isfinite(best[0]):
        raise TunerError(f"no subset of {nq} tuners gives a detectable system at every point")
    return np.eye(nh)[list(best[1])], best[0], best[2], [(m, S) for m, S, _ in ranking]


def fd_gradient(costs, w, step: float = FD_STEP):
    """Forward-difference gradient of a scalar cost at ``w`` (n,): ``costs`` maps a list of
    points to their costs in one batch (n + 1 here: w and each w + step e_i). The steps are
    scipy's '2-point' ones with an absolute step (dx = (w_i + step) - w_i), so L-BFGS-B follows
    the same path as with its own finite differences. Returns (cost at w, gradient (n,))."""
    w = np.asarray(w, dtype=np.float64)
    xs = [w]
    for i in range(w.size):
        x = w.copy()
        x[i] = w[i] + step
        xs.append(x)
    f = np.asarray(costs(xs), dtype=np.float64)
    dx = (w + step) - w
    return float(f[0]), (f[1:] - f[0]) / dx


def optimal_tuners(points, V0, Ph, targets, maxiter: int = 40, progress=None, executor=None):
    """Optimal tuner selection: a dense V minimising the same metric over the envelope.

    The metric depends on the row space of V only (q -> T q leaves the estimates unchanged), so
    V is parametrised as V[:, S] = I, V[:, rest] = W with S the columns of the starting subset
    ``V0`` (its metric is the starting value: the result is never worse). L-BFGS-B on a
    forward-difference gradient (:func:`fd_gradient`) whose nq (nh - nq) + 1 evaluations go
    through ``executor`` in one batch when given (the same numbers as without).
    Returns (V, metric, mse).
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

    def costs(ws):
        mse = envelope_mses(points, [make(w) for w in ws], Ph, targets, executor)
        return [m if np.isfinite(m) else 1e30 for m in (float(r.sum()) for r in mse)]

    w0 = np.zeros(nq * len(rest))
    f0 = costs([w0])[0]
    it = [0]

    def cb(_w):
        it[0] += 1
        if progress:
            progress(it[0], maxiter)

    res = minimize(lambda w: fd_gradient(costs, w), w0, jac=True, method="L-BFGS-B", callback=cb,
                   options={"maxiter": maxiter})
    w = res.x if res.fun <= f0 else w0
    V = make(w)
    mse = envelope_mse(points, V, Ph, targets, executor)
    return V, float(mse.sum()), mse
