"""Rectilinear grids: validated axes, the bracketed index search and per-axis weights.

This module holds the one index search and the one weight computation of the project. Every
interpolation (trims, matrices, gains, adaptive tables) goes through :func:`locate`, then
:func:`corner_weights` (in :mod:`pwl.interp`), so a grid is searched once per step and its
weights are shared by every dataset stored on it.

Kernels take plain arrays (numba ``njit``): the breakpoints of all axes of one grid are stored
concatenated in ``bp`` (float64) with ``off`` (int64, n_axes + 1) marking where each axis starts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .errors import PwlError

#: Out-of-range policies. ``clip`` holds the point at the grid edge (counted and flagged),
#: ``extrapolate`` extends the edge cells linearly (flagged too); ``error`` is a Python-level
#: policy (the runtime stops with a named error) and behaves as ``clip`` inside kernels.
POLICIES = ("clip", "extrapolate", "error")


class AxisError(PwlError, ValueError):
    """An axis that is not a valid breakpoint vector (names the axis)."""


@dataclass(frozen=True)
class Axis:
    """One grid axis: a name, a unit and strictly increasing finite breakpoints (>= 2).

    ``values`` is a read-only float64 array of shape (n,).
    """

    name: str
    values: np.ndarray
    unit: str = ""

    def __post_init__(self):
        v = np.array(self.values, dtype=np.float64, copy=True)
        object.__setattr__(self, "values", v)
        check_breakpoints(v, self.name)
        v.setflags(write=False)

    def __len__(self):
        return self.values.size

    def __eq__(self, other):
        return (isinstance(other, Axis) and self.name == other.name and self.unit == other.unit
                and np.array_equal(self.values, other.values))

    def __hash__(self):
        return hash((self.name, self.unit, self.values.tobytes()))

    @property
    def lo(self) -> float:
        return float(self.values[0])

    @property
    def hi(self) -> float:
        return float(self.values[-1])


def check_breakpoints(v: np.ndarray, where: str) -> None:
    """Raise :class:`AxisError` naming ``where`` unless ``v`` is finite, strictly increasing, n >= 2."""
    v = np.asarray(v)
    if v.ndim != 1:
        raise AxisError(f"axis {where!r}: breakpoints must be 1-D, got shape {v.shape}")
    if v.size < 2:
        raise AxisError(f"axis {where!r}: needs at least 2 breakpoints, got {v.size}")
    if not np.all(np.isfinite(v)):
        bad = int(np.flatnonzero(~np.isfinite(v))[0])
        raise AxisError(f"axis {where!r}: breakpoint {bad} is not finite ({v[bad]})")
    d = np.diff(v)
    if np.any(d <= 0):
        bad = int(np.flatnonzero(d <= 0)[0])
        raise AxisError(f"axis {where!r}: breakpoints not strictly increasing at index {bad + 1} "
                        f"({v[bad]} then {v[bad + 1]})")


class Grid:
    """An n-D rectilinear grid (n = 1..6) with its packed breakpoint arrays for the kernels.

    Attributes: ``axes`` (tuple of :class:`Axis`), ``shape`` (tuple of int), ``bp`` (float64,
    sum of axis sizes), ``off`` (int64, n + 1), ``strides`` (int64, n: row-major flat index of a
    grid node is ``sum(i_j * strides_j)``), ``policy`` (one of :data:`POLICIES`).
    """

    MAX_DIMS = 6

    def __init__(self, axes, policy: str = "clip"):
        axes = tuple(a if isinstance(a, Axis) else Axis(*a) for a in axes)
        if not 1 <= len(axes) <= self.MAX_DIMS:
            raise AxisError(f"a grid has 1..{self.MAX_DIMS} axes, got {len(axes)}")
        names = [a.name for a in axes]
        if len(set(names)) != len(names):
            raise AxisError(f"duplicate axis names {names}")
        if policy not in POLICIES:
            raise ValueError(f"out-of-range policy must be one of {POLICIES}, got {policy!r}")
        self.axes = axes
        self.policy = policy
        self.shape = tuple(len(a) for a in axes)
        self.bp = np.ascontiguousarray(np.concatenate([a.values for a in axes]))
        self.off = np.zeros(len(axes) + 1, dtype=np.int64)
        self.off[1:] = np.cumsum(self.shape)
        self.strides = np.ones(len(axes), dtype=np.int64)
        for j in range(len(axes) - 2, -1, -1):
            self.strides[j] = self.strides[j + 1] * self.shape[j + 1]

    @property
    def ndim(self) -> int:
        return len(self.axes)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    @property
    def extrapolate(self) -> bool:
        return self.policy == "extrapolate"

    def nodes(self) -> np.ndarray:
        """All grid nodes in row-major order, shape (size, ndim)."""
        mesh = np.meshgrid(*[a.values for a in self.axes], indexing="ij")
        return np.stack([m.reshape(-1) for m in mesh], axis=1)

    def normalized(self, points: np.ndarray) -> np.ndarray:
        """Points scaled so that every axis spans [0, 1] (for distances across axes)."""
        lo = np.array([a.lo for a in self.axes])
        hi = np.array([a.hi for a in self.axes])
        return (np.asarray(points, dtype=np.float64) - lo) / (hi - lo)

    def workspace(self):
        """Fresh (idx, frac) arrays for :func:`locate`; ``idx`` doubles as the previous-step hint."""
        return np.zeros(self.ndim, dtype=np.int64), np.zeros(self.ndim, dtype=np.float64)

    def locate(self, point, idx=None, frac=None):
        """Python convenience wrapper of :func:`locate`: returns (idx, frac, flags)."""
        if idx is None:
            idx, frac = self.workspace()
        p = np.ascontiguousarray(point, dtype=np.float64)
        if p.shape != (self.ndim,):
            raise ValueError(f"point must have shape ({self.ndim},), got {p.shape}")
        flags = locate(self.bp, self.off, p, self.extrapolate, idx, frac)
        return idx, frac, flags

    def __eq__(self, other):
        return isinstance(other, Grid) and self.axes == other.axes and self.policy == other.policy

    def __repr__(self):
        ax = ", ".join(f"{a.name}[{len(a)}: {a.lo:g}..{a.hi:g}]" for a in self.axes)
        return f"Grid({ax}; policy={self.policy})"


@njit(cache=True, nogil=True, inline="always")
def find_interval(bp, lo, n, x, hint):
    """Index i in [0, n-2] of the cell of axis ``bp[lo:lo+n]`` that holds x (x inside the axis).

    Tries the hint (the previous step's index) and its two neighbours first: O(1) when the point
    moves slowly; falls back to binary search. Ties go to the lower cell except at the top end.
    """
    if 0 <= hint <= n - 2:
        if bp[lo + hint] <= x <= bp[lo + hint + 1]:
            return hint
        if hint + 1 <= n - 2 and bp[lo + hint + 1] <= x <= bp[lo + hint + 2]:
            return hint + 1
        if hint >= 1 and bp[lo + hint - 1] <= x <= bp[lo + hint]:
            return hint - 1
    a = 0
    b = n - 1  # invariant: bp[lo+a] <= x <= bp[lo+b]
    while b - a > 1:
        m = (a + b) >> 1
        if x < bp[lo + m]:
            b = m
        else:
            a = m
    return a


@njit(cache=True, nogil=True, inline="always")
def beyond(bp, off, point, share):
    """True when ``point`` (float64, n) lies farther outside an axis of the grid (breakpoints
    ``bp[off[j]:off[j + 1]]``) than ``share`` of that axis's span."""
    for j in range(point.shape[0]):
        lo, hi = bp[off[j]], bp[off[j + 1] - 1]
        reach = share * (hi - lo)
        if point[j] < lo - reach or point[j] > hi + reach:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def locate(bp, off, point, extrapolate, idx, frac):
    """Bracket ``point`` (float64, n) on the grid; write cell indices and fractions in place.

    idx (int64, n) holds the previous indices on entry (the search hint) and the lower bracketing
    index of each axis on exit; frac (float64, n) the fraction t in [0, 1] of the way to the next
    breakpoint (outside [0, 1] when extrapolating). Returns a bit mask of the axes on which the
    point lay outside the grid (bit j set: axis j was clipped or extrapolated). A NaN coordinate
    is the caller's business (the runtime skips such samples before calling).
    """
    flags = 0
    for j in range(point.shape[0]):
        lo = off[j]
        n = off[j + 1] - lo
        x = point[j]
        if x < bp[lo]:
            flags |= 1 << j
            i = 0
            t = (x - bp[lo]) / (bp[lo + 1] - bp[lo]) if extrapolate else 0.0
        elif x > bp[lo + n - 1]:
            flags |= 1 << j
            i = n - 2
            t = (x - bp[lo + i]) / (bp[lo + i + 1] - bp[lo + i]) if extrapolate else 1.0
        else:
            i = find_interval(bp, lo, n, x, idx[j])
            t = (x - bp[lo + i]) / (bp[lo + i + 1] - bp[lo + i])
        idx[j] = i
        frac[j] = t
    return flags
