"""Adaptive look-up tables: node updates with steady-state Kalman gains (seed papers 000 and 003).

A table holds one value per node of a :class:`pwl.Grid`; its output at an operating point p is
the multilinear interpolation ``x_hat = c(p)^T theta`` where ``c(p)`` are the 2^n corner weights
of :func:`pwl.interp.corner_weights` (after the one index search :func:`pwl.grid.locate`). A
reference x (a sensor, an observer) gives the error ``e = x - x_hat`` and the table learns

    theta[rows[i]] += k_i * e                                    (000, eq. 19)

with one of three gain laws (docs/adaptive-tables.md derives them):

``exact`` (default, :data:`LAW_EXACT`)
    the limit of the Kalman gain of the random walk theta_k = theta_{k-1} + w (Q = I), measured
    through x = c^T theta + v (R = ratio), at a fixed point c, in any dimension::

        k = pbar c / (pbar |c|^2 + r) = c / (pbar |c|^2),   pbar = (1 + sqrt(1 + 4 r / |c|^2)) / 2

``paper`` (:data:`LAW_PAPER`)
    000's (A.4)-(A.6) per axis and the product rule (A.7) across axes, generalised to n-D as the
    paper says. Equal to ``exact`` in 1-D, not in 2-D and up (kept for reproduction).

``correlated`` (:data:`LAW_CORRELATED`)
    003: a full Kalman filter over all nodes, theta_{k+1} = theta_k + w, w ~ N(0, Sigma) with
    Sigma_ij = rho_ij sigma_i sigma_j, rho_ij = exp(-|p_i - p_j| / length) over normalised axes,
    R = ratio * mean(sigma_i^2). The covariance P is kept; every node moves, visited or not.

``r = ratio = sigma_x^2 / sigma_theta^2`` (measurement over process noise variance). The numba
kernels take plain arrays and allocate nothing; :class:`AdaptiveTable` holds the state, checks
input, applies the out-of-range policy of its grid and saves to a database's ``/tables/<name>``.
"""
from __future__ import annotations

import contextlib
import math
import os

import h5py
import numpy as np
from numba import njit

from .errors import PwlError
from . import formats
from .formats import GAIN_DATABASE, TABLE_RECORD, TABLES_FILE, check, open_checked, stamp
from .grid import Axis, Grid, locate
from .h5io import atomic_h5
from .interp import corner_weights, interp_many

#: gain-law codes of the kernels
LAW_EXACT = 0
LAW_PAPER = 1
LAW_CORRELATED = 2
LAWS = {"exact": LAW_EXACT, "paper": LAW_PAPER, "correlated": LAW_CORRELATED}


class TableError(PwlError, ValueError):
    """An adaptive table or table record that cannot be used (the message says what is wrong)."""


# ---------------------------------------------------------------------------------------------
# numba kernels (plain arrays; usable inside other numba loops)
# ---------------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def table_predict(values, wts, rows, m):
    """Table output sum_i wts[i] * values[rows[i]] (values: flat node array).

    This is :func:`pwl.interp.interp_rows` for a one-value block, written as a dot product so
    that a scalar needs no output buffer (the weights and rows come from ``corner_weights``).
    """
    s = 0.0
    for i in range(m):
        s += wts[i] * values[rows[i]]
    return s


@njit(cache=True, nogil=True, inline="always")
def exact_scale(wts, m, ratio):
    """The factor g of the exact gain k_i = g * c_i: g = 1 / (pbar |c|^2) (0 if c = 0)."""
    c2 = 0.0
    for i in range(m):
        c2 += wts[i] * wts[i]
    if c2 <= 0.0:
        return 0.0
    # pbar |c|^2 = (|c|^2 + sqrt(|c|^4 + 4 r |c|^2)) / 2: one square root, one division
    return 2.0 / (c2 + math.sqrt(c2 * (c2 + 4.0 * ratio)))


@njit(cache=True, nogil=True)
def exact_gains(wts, m, ratio, out):
    """Exact steady-state gains of the m active nodes into out[:m]; returns m."""
    g = exact_scale(wts, m, ratio)
    for i in range(m):
        out[i] = g * wts[i]
    return m


@njit(cache=True, nogil=True)
def paper_gain_1d(a, ratio):
    """000 (A.4)-(A.5) for the node whose 1-D interpolation weight is a (a = 1 - eta)."""
    q = a * a + (1.0 - a) * (1.0 - a)  # = 1 - 2 eta + 2 eta^2
    s = math.sqrt(1.0 + 4.0 * ratio / q)
    return 0.5 * a * (1.0 + s) / (0.5 * (1.0 + s) * q + ratio)


@njit(cache=True, nogil=True, inline="always")
def paper_corner(frac, c, ratio):
    """Corner c (bit j set: upper node on axis j): its weight and its product-rule gain (A.7)."""
    w = 1.0
    g = 1.0
    for j in range(frac.shape[0]):
        a = frac[j] if (c >> j) & 1 else 1.0 - frac[j]
        w *= a
        g *= paper_gain_1d(a, ratio)
    return w, g


@njit(cache=True, nogil=True)
def paper_gains(frac, ratio, out):
    """000 (A.7) generalised to n-D: the product over axes of the 1-D gains (A.4)/(A.6).

    Corners are enumerated and dropped exactly as in ``corner_weights`` (same order, zero-weight
    corners skipped), so out[i] belongs to rows[i]. Returns the number of corners m.
    """
    m = 0
    for c in range(1 << frac.shape[0]):
        w, g = paper_corner(frac, c, ratio)
        if w != 0.0:
            out[m] = g
            m += 1
    return m


@njit(cache=True, nogil=True, inline="always")
def table_update(values, counts, wts, rows, m, error, law, ratio, frac=None):
    """In place: values[rows[i]] += k_i * error and counts[rows[i]] += 1 for the m active nodes.

    law: :data:`LAW_EXACT` (needs wts only) or :data:`LAW_PAPER` (needs ``frac``, the per-axis
    fractions from ``locate``: the product rule is per axis). values and counts are flat.
    """
    if law == LAW_EXACT:
        g = exact_scale(wts, m, ratio) * error
        for i in range(m):
            r = rows[i]
            values[r] += g * wts[i]
            counts[r] += 1
    elif law == LAW_PAPER:
        if frac is None:
            raise ValueError("table_update: the paper law needs the axis fractions (frac)")
        i = 0
        for c in range(1 << frac.shape[0]):
            w, g = paper_corner(frac, c, ratio)
            if w != 0.0:
                r = rows[i]
                values[r] += g * error
                counts[r] += 1
                i += 1
    else:
        raise ValueError("table_update: unknown law code (0 exact, 1 paper)")


@njit(cache=True, nogil=True)
def count_ratio(counts, wts, rows, m, ratio, warmup):
    """Noise ratio varied from visit counts (000 sec. 4): ratio * min(1, (n + 1) / warmup) where
    n = sum |w_i| counts_i is the visit count of the cell; warmup <= 0 returns ratio unchanged.
    Fresh cells get a small ratio (large gains), well-visited cells the nominal one."""
    if warmup <= 0.0:
        return ratio
    n = 0.0
    for i in range(m):
        n += abs(wts[i]) * counts[rows[i]]
    f = (n + 1.0) / warmup
    return ratio * f if f < 1.0 else ratio


@njit(cache=True, nogil=True)
def correlated_update(values, P, Sigma, counts, wts, rows, m, error, noise_var, work):
    """One Kalman step of the whole table (003): P += Sigma, then the update with row c.

    values (N,), P and Sigma (N, N), counts (N,), work (N,) scratch. Returns the change of the
    table output at the measured point, c^T K e = e (S - R) / S.
    """
    N = values.shape[0]
    for i in range(N):
        for j in range(N):
            P[i, j] += Sigma[i, j]
    for i in range(N):
        s = 0.0
        for k in range(m):
            s += P[i, rows[k]] * wts[k]
        work[i] = s
    S = noise_var
    for k in range(m):
        S += wts[k] * work[rows[k]]
    if not S > 0.0:
        return 0.0
    g = error / S
    for i in range(N):
        values[i] += work[i] * g
    for i in range(N):
        a = work[i] / S
        for j in range(N):
            P[i, j] -= a * work[j]
    for k in range(m):
        counts[rows[k]] += 1
    return error * (S - noise_var) / S


@njit(cache=True, nogil=True)
def table_run(values, counts, bp, off, strides, extrapolate, points, refs, law, ratio, warmup,
              update_outside, pred, history, P, Sigma, noise_var):
    """Predict, then learn, at every row of points (k, n) against refs (k,), in order.

    pred (k,) receives the a-priori table outputs; if history has k rows, row i receives the
    node values after step i. NaN points or references: prediction only (NaN for a NaN point).
    law: LAW_EXACT / LAW_PAPER (ratio, warmup: :func:`count_ratio`) or LAW_CORRELATED (full
    covariance P updated in place, process noise Sigma, measurement noise_var; empty arrays
    otherwise). Returns (number of points outside the grid, number of updates made).
    """
    n = points.shape[1]
    work = (np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.float64), np.zeros(1 << n, dtype=np.float64),
            np.zeros(1 << n, dtype=np.int64),
            np.zeros(values.shape[0] if law == LAW_CORRELATED else 0, dtype=np.float64))
    return _table_steps(values, counts, bp, off, strides, extrapolate, points, refs, law, ratio, warmup,
                        update_outside, pred, history, P, Sigma, noise_var, work)


@njit(cache=True, nogil=True, _nrt=False)
def _table_steps(values, counts, bp, off, strides, extrapolate, points, refs, law, ratio, warmup,
                 update_outside, pred, history, P, Sigma, noise_var, work):
    """The loop of :func:`table_run` (same arguments plus its workspace), compiled without numba's
    reference counting like :func:`pwl.runtime.step_loop`."""
    idx, frac, wts, rows, cwork = work
    n = points.shape[1]
    keep = history.shape[0] == points.shape[0]
    outside = 0
    updated = 0
    for k in range(points.shape[0]):
        ok = True
        for j in range(n):
            if not math.isfinite(points[k, j]):
                ok = False
        if not ok:
            pred[k] = np.nan
        else:
            flags = locate(bp, off, points[k], extrapolate, idx, frac)
            m = corner_weights(idx, frac, strides, wts, rows)
            xh = table_predict(values, wts, rows, m)
            pred[k] = xh
            if flags != 0:
                outside += 1
            if (flags == 0 or update_outside) and math.isfinite(refs[k]):
                if law == LAW_CORRELATED:
                    correlated_update(values, P, Sigma, counts, wts, rows, m, refs[k] - xh, noise_var, cwork)
                else:
                    r = ratio if warmup <= 0.0 else count_ratio(counts, wts, rows, m, ratio, warmup)
                    table_update(values, counts, wts, rows, m, refs[k] - xh, law, r, frac)
                updated += 1
        if keep:
            for i in range(values.shape[0]):
                history[k, i] = values[i]
    return outside, updated


# ---------------------------------------------------------------------------------------------
# the Python object
# ---------------------------------------------------------------------------------------------
def correlation_matrix(grid: Grid, length: float) -> np.ndarray:
    """rho_ij = exp(-|p_i - p_j| / length), Euclidean distance between nodes on axes normalised
    to [0, 1] (row-major node order)."""
    if not (np.isfinite(length) and length > 0):
        raise TableError(f"correlation length must be a positive number, got {length}")
    z = grid.normalized(grid.nodes())
    d = np.sqrt(((z[:, None, :] - z[None, :, :]) ** 2).sum(axis=2))
    return np.exp(-d / length)


class AdaptiveTable:
    """An adaptive look-up table on a grid (state + input checks around the kernels).

    Parameters: ``grid``; ``values`` (grid.shape, default zeros); ``law`` exact | paper |
    correlated; ``ratio`` = sigma_x^2 / sigma_theta^2 >= 0; ``ratio_warmup`` > 0 varies the ratio
    from the visit counts (:func:`count_ratio`; exact and paper laws); ``enabled`` (False: the
    table predicts but never learns; :meth:`lock`/:meth:`unlock`); ``update_outside`` (default
    False: a point outside the grid is predicted with the grid's policy, clip or extrapolate, but
    does not update; policy ``error`` raises). Correlated law only: ``sigma`` (scalar or per node,
    grid.shape), ``length`` (correlation length on normalised axes), or a full ``Sigma``
    (size x size); ``noise_var`` (default ratio * mean(sigma^2)); ``P`` initial covariance
    (default Sigma).

    Attributes: ``grid``, ``values`` (grid.shape), ``counts`` (int64, grid.shape: updates that
    touched each node), ``n_updates``, ``n_outside``; correlated: ``Sigma``, ``P``, ``noise_var``.
    """

    def __init__(self, grid: Grid, values=None, law: str = "exact", ratio: float = 1.0, *,
                 counts=None, enabled: bool = True, update_outside: bool = False,
                 ratio_warmup: float = 0.0, sigma=1.0, length: float = 0.5, Sigma=None,
                 noise_var: float | None = None, P=None):
        if not isinstance(grid, Grid):
            raise TableError(f"grid must be a pwl.Grid, got {type(grid).__name__}")
        if law not in LAWS:
            raise TableError(f"unknown gain law {law!r}; choose one of {sorted(LAWS)}")
        ratio = float(ratio)
        if not (np.isfinite(ratio) and ratio >= 0):
            raise TableError(f"noise ratio sigma_x^2/sigma_theta^2 must be finite and >= 0, got {ratio}")
        self.grid = grid
        self.law = law
        self.ratio = ratio
        self.ratio_warmup = float(ratio_warmup)
        self.enabled = bool(enabled)
        self.update_outside = bool(update_outside)
        self.values = self._array(values, 0.0, np.float64, "values")
        self.counts = self._array(counts, 0, np.int64, "counts")
        self.n_updates = 0
        self.n_outside = 0
        self.Sigma = self.P = None
        self.noise_var = None
        self.length = float(length)
        if law == "correlated":
            N = grid.size
            if Sigma is None:
                s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), grid.shape).reshape(-1)
                if not np.all(np.isfinite(s)) or np.any(s < 0):
                    raise TableError("sigma must be finite and >= 0 at every node")
                Sigma = correlation_matrix(grid, self.length) * np.outer(s, s)
            Sigma = np.array(Sigma, dtype=np.float64)
            if Sigma.shape != (N, N):
                raise TableError(f"Sigma must have shape {(N, N)}, got {Sigma.shape}")
            if not np.allclose(Sigma, Sigma.T) or np.linalg.eigvalsh(Sigma).min() < -1e-9 * max(
                    1.0, np.abs(Sigma).max()):
                raise TableError("Sigma must be symmetric positive semi-definite")
            self.Sigma = np.ascontiguousarray(Sigma)
            self.noise_var = float(ratio * np.mean(np.diag(Sigma)) if noise_var is None else noise_var)
            if not (np.isfinite(self.noise_var) and self.noise_var >= 0):
                raise TableError(f"noise_var must be finite and >= 0, got {self.noise_var}")
            self.P = np.ascontiguousarray(np.array(self.Sigma if P is None else P, dtype=np.float64))
            if self.P.shape != (N, N):
                raise TableError(f"P must have shape {(N, N)}, got {self.P.shape}")
            self._work = np.zeros(N)
        self._idx, self._frac = grid.workspace()
        self._wts = np.zeros(1 << grid.ndim)
        self._rows = np.zeros(1 << grid.ndim, dtype=np.int64)

    def _array(self, a, fill, dtype, what):
        if a is None:
            return np.full(self.grid.shape, fill, dtype=dtype)
        a = np.array(a, dtype=dtype)
        if a.shape != self.grid.shape:
            raise TableError(f"{what} must have the grid shape {self.grid.shape}, got {a.shape}")
        if dtype == np.float64 and not np.all(np.isfinite(a)):
            raise TableError(f"{what} must be finite")
        return np.ascontiguousarray(a)

    # ---- state -------------------------------------------------------------------------------
    @property
    def law_code(self) -> int:
        return LAWS[self.law]

    def lock(self):
        """Stop learning (predictions continue)."""
        self.enabled = False

    def unlock(self):
        self.enabled = True

    def copy(self) -> "AdaptiveTable":
        return AdaptiveTable.from_record(*self.to_record())

    def __repr__(self):
        return (f"AdaptiveTable({self.grid!r}, law={self.law}, ratio={self.ratio:g}, "
                f"{'enabled' if self.enabled else 'locked'}, {self.n_updates} updates)")

    # ---- points ------------------------------------------------------------------------------
    def _single(self, p) -> bool:
        """One point: shape (ndim,), or a scalar for a 1-D table."""
        return np.ndim(p) == 0 or (np.ndim(p) == 1 and np.size(p) == self.grid.ndim)

    def _points(self, p):
        """Points as (k, ndim); a 1-D table also takes a scalar or a (k,) vector of points."""
        a = np.asarray(p, dtype=np.float64)
        if self.grid.ndim == 1 and a.ndim <= 1:
            a = a.reshape(-1, 1)
        pts = np.ascontiguousarray(np.atleast_2d(a))
        if pts.ndim != 2 or pts.shape[1] != self.grid.ndim:
            raise TableError(f"points must have shape ({self.grid.ndim},) or (k, {self.grid.ndim}), "
                             f"got {np.shape(p)}")
        if self.grid.policy == "error":
            lo = np.array([a.lo for a in self.grid.axes])
            hi = np.array([a.hi for a in self.grid.axes])
            bad = np.flatnonzero(np.any((pts < lo) | (pts > hi), axis=1))
            if bad.size:
                raise TableError(f"point {pts[bad[0]].tolist()} is outside the table grid {self.grid!r}")
        return pts

    def _weights(self, p):
        flags = locate(self.grid.bp, self.grid.off, p, self.grid.extrapolate, self._idx, self._frac)
        m = corner_weights(self._idx, self._frac, self.grid.strides, self._wts, self._rows)
        return flags, m

    def predict(self, p):
        """Table output at p: (ndim,) -> float, (k, ndim) -> (k,). Uses the grid's policy outside."""
        single = self._single(p)
        pts = self._points(p)
        out = np.empty((pts.shape[0], 1))
        interp_many(self.values.reshape(-1, 1), self.grid.bp, self.grid.off, self.grid.strides,
                    self.grid.extrapolate, pts, out)
        return float(out[0, 0]) if single else out[:, 0]

    def gains(self, p):
        """(rows, gains): flat node indices and gains of the update at p (law exact or paper);
        for the correlated law the whole gain vector K = P' c / (c^T P' c + R), P' = P + Sigma."""
        pts = self._points(p)
        if pts.shape[0] != 1:
            raise TableError("gains(p) takes one point")
        _, m = self._weights(pts[0])
        wts, rows = self._wts[:m].copy(), self._rows[:m].copy()
        if self.law == "correlated":
            Pp = self.P + self.Sigma
            pc = Pp[:, rows] @ wts
            return np.arange(self.grid.size), pc / (wts @ pc[rows] + self.noise_var)
        out = np.zeros(m)
        r = count_ratio(self.counts.reshape(-1), wts, rows, m, self.ratio, self.ratio_warmup)
        if self.law == "exact":
            exact_gains(wts, m, r, out)
        else:
            paper_gains(self._frac, r, out)
        return rows, out

    def update(self, p, error):
        """Learn from error = reference - prediction at p (one point, or k points in order with k
        errors). Returns the change of the table output at p (0 where nothing was learnt:
        locked table, NaN error, point outside the grid unless update_outside)."""
        single = self._single(p)
        pts = self._points(p)
        err = np.broadcast_to(np.asarray(error, dtype=np.float64), (pts.shape[0],))
        out = np.zeros(pts.shape[0])
        vals = self.values.reshape(-1)
        cnts = self.counts.reshape(-1)
        for k in range(pts.shape[0]):
            if not self.enabled or not np.isfinite(err[k]) or not np.all(np.isfinite(pts[k])):
                continue
            flags, m = self._weights(pts[k])
            if flags:
                self.n_outside += 1
                if not self.update_outside:
                    continue
            wts, rows = self._wts, self._rows
            before = table_predict(vals, wts, rows, m)
            if self.law == "correlated":
                out[k] = correlated_update(vals, self.P, self.Sigma, cnts, wts, rows, m, err[k],
                                           self.noise_var, self._work)
            else:
                r = count_ratio(cnts, wts, rows, m, self.ratio, self.ratio_warmup)
                table_update(vals, cnts, wts, rows, m, err[k], self.law_code, r, self._frac)
                out[k] = table_predict(vals, wts, rows, m) - before
            self.n_updates += 1
        return float(out[0]) if single else out

    def learn(self, points, refs, history: bool = False):
        """Run through points (k, ndim) with references (k,): predict, then learn, in order.

        Returns the a-priori predictions (k,), and with ``history=True`` also the node values
        after every step (k, size). A locked table only predicts.
        """
        pts = self._points(points)
        refs = np.ascontiguousarray(np.broadcast_to(np.asarray(refs, dtype=np.float64), (pts.shape[0],)))
        pred = np.empty(pts.shape[0])
        hist = np.empty((pts.shape[0] if history else 0, self.grid.size))
        if not self.enabled:
            refs = np.full_like(refs, np.nan)
        g = self.grid
        vals = self.values.reshape(-1)
        cnts = self.counts.reshape(-1)
        corr = self.law == "correlated"
        none = np.zeros((0, 0))
        out, upd = table_run(vals, cnts, g.bp, g.off, g.strides, g.extrapolate, pts, refs, self.law_code,
                             self.ratio, self.ratio_warmup, self.update_outside, pred, hist,
                             self.P if corr else none, self.Sigma if corr else none,
                             self.noise_var if corr else 0.0)
        self.n_outside += int(out)
        self.n_updates += int(upd)
        return (pred, hist) if history else pred

    def propagate(self, steps: float = 1.0):
        """Correlated law: let time pass without a measurement (P += steps * Sigma)."""
        if self.law == "correlated":
            self.P += float(steps) * self.Sigma

    # ---- records and files -------------------------------------------------------------------
    def to_record(self) -> tuple[dict, dict]:
        """(arrays, attrs) as stored in a database's /tables/<name> (``GainDatabase.tables``)."""
        arrays = {"values": self.values.copy(), "counts": self.counts.copy()}
        for j, a in enumerate(self.grid.axes):
            arrays[f"axis_{j}"] = a.values.copy()
        attrs = {**TABLE_RECORD.stamp(),
                 "axes": [a.name for a in self.grid.axes], "units": [a.unit for a in self.grid.axes],
                 "policy": self.grid.policy, "law": self.law, "ratio": self.ratio,
                 "ratio_warmup": self.ratio_warmup, "enabled": self.enabled,
                 "update_outside": self.update_outside, "n_updates": self.n_updates,
                 "n_outside": self.n_outside}
        if self.law == "correlated":
            arrays["Sigma"] = self.Sigma.copy()
            arrays["P"] = self.P.copy()
            attrs["noise_var"] = self.noise_var
            attrs["length"] = self.length
        return arrays, attrs

    @classmethod
    def from_record(cls, arrays: dict, attrs: dict, where: str = "record") -> "AdaptiveTable":
        """The table of a record ``(arrays, attrs)`` (:meth:`to_record`); ``where`` names it in
        errors (:class:`TableError`: another format, a newer version, a missing item)."""
        check(TABLE_RECORD, where, attrs, error=TableError)
        try:
            names = list(attrs["axes"])
            units = list(attrs.get("units", [""] * len(names)))
            axes = [Axis(nm, arrays[f"axis_{j}"], un) for j, (nm, un) in enumerate(zip(names, units))]
            grid = Grid(axes, attrs.get("policy", "clip"))
            law = attrs.get("law", "exact")
            kw = {}
            if law == "correlated":
                kw = {"Sigma": arrays["Sigma"], "P": arrays["P"], "noise_var": attrs["noise_var"],
                      "length": attrs.get("length", 0.5)}
            t = cls(grid, arrays["values"], law, attrs.get("ratio", 1.0), counts=arrays.get("counts"),
                    enabled=attrs.get("enabled", True), update_outside=attrs.get("update_outside", False),
                    ratio_warmup=attrs.get("ratio_warmup", 0.0), **kw)
        except KeyError as e:
            raise TableError(f"{where}: adaptive-table record is missing {e.args[0]!r}") from None
        t.n_updates = int(attrs.get("n_updates", 0))
        t.n_outside = int(attrs.get("n_outside", 0))
        return t

    def save(self, path, name: str) -> None:
        """Write this table to ``/tables/<name>`` of the HDF5 file ``path`` (:func:`save_tables`:
        a new adaptive-tables file if missing; an existing gain database or tables file keeps
        everything else). Atomic: the new content is written to a temporary copy that replaces
        the file only when complete."""
        save_tables(path, {name: self.to_record()})

    @classmethod
    def load(cls, path, name: str) -> "AdaptiveTable":
        """Read ``/tables/<name>`` of an HDF5 file (a gain database or a tables file)."""
        path = os.fspath(path)
        with open_checked(path, (GAIN_DATABASE, TABLES_FILE), TableError) as f:
            tables = read_tables(f)
        if name not in tables:
            raise TableError(f"{path}: no table /tables/{name} (tables: {list(tables) or 'none'})")
        return cls.from_record(*tables[name], where=f"{path}: /tables/{name}")


# ---- the one writer and reader of tables: /tables/<name> of a gain database or a tables file -------
def write_tables(f, records: dict) -> None:
    """Write ``records`` (name -> ``(arrays, attrs)``, e.g. :meth:`AdaptiveTable.to_record`) as
    ``/tables/<name>`` of the open HDF5 file ``f``, replacing tables of the same names."""
    if not records:
        return
    g = f.require_group("tables")
    for name, rec in records.items():
        if not name or "/" in name:
            raise TableError(f"table name must be non-empty without '/', got {name!r}")
        if name in g:
            del g[name]
        formats.write_record(g.create_group(name), *rec)


def read_tables(f) -> dict:
    """name -> ``(arrays, attrs)`` of every ``/tables/<name>`` of the open HDF5 file ``f``."""
    return {k: formats.read_record(g) for k, g in f["tables"].items()} if "tables" in f else {}


def save_tables(path, records: dict) -> None:
    """Write ``records`` (:func:`write_tables`) into the file ``path``: a new adaptive-tables file
    (format ``pwl-adaptive-tables``) when it does not exist, else an existing gain database or
    tables file, atomically (a temporary copy renamed onto ``path``; its seal renewed).

    Raises
    ------
    TableError
        ``path`` is not HDF5, or of another format (named), or a table name is empty or has '/'.
    """
    path = os.fspath(path)
    if os.path.exists(path) and h5py.is_hdf5(path):
        with h5py.File(path, "r") as f:
            check((GAIN_DATABASE, TABLES_FILE), path, f, error=TableError)
    with _modify_h5(path) as f:
        write_tables(f, records)


@contextlib.contextmanager
def _modify_h5(path):
    """A temporary copy of ``path`` (or a new tables file) renamed onto ``path`` on success."""
    new = not os.path.exists(path)
    try:
        with atomic_h5(path, modify=True) as f:
            if new:
                stamp(f, TABLES_FILE)
            yield f
    except OSError as e:
        if "not an HDF5 file" in str(e):
            raise TableError(str(e)) from None
        raise
