"""The one multilinear interpolation kernel: shared corner weights, packed-block row additions.

A dataset stored on a grid is a 2-D C-contiguous ``table`` of shape (grid.size, block): row r holds
every value of grid node r (row-major node order) in one contiguous block. Interpolation at a
point is then the 2^n-term sum ``out = sum_c w_c * table[row_c]``.

Per step and grid: :func:`pwl.grid.locate` (one search) -> :func:`corner_weights` (once) ->
:func:`interp_rows` for every table on that grid (shared weights). Nothing allocates.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .grid import Grid, locate


@njit(cache=True, nogil=True, inline="always")
def corner_weights(idx, frac, strides, wts, rows):
    """Fill the 2^n corner weights and table rows of the cell (idx, frac); return how many.

    wts (float64) and rows (int64) need room for 2^n entries. Corner c has bit j set when it is
    the upper node on axis j, weight prod_j (frac_j or 1 - frac_j). Built axis by axis, the
    corners so far doubled by each (2^n - 1 products instead of n 2^n). An axis whose fraction is
    exactly 0 or 1 (the point lies on a cell face) does not double them: a point on a node costs
    one row copy.
    """
    r = 0
    for j in range(idx.shape[0]):
        r += idx[j] * strides[j]
    wts[0] = 1.0
    rows[0] = r
    m = 1
    for j in range(idx.shape[0]):
        f = frac[j]
        s = strides[j]
        if f == 0.0:
            continue
        if f == 1.0:
            for c in range(m):
                rows[c] += s
            continue
        g = 1.0 - f
        for c in range(m):
            wts[m + c] = wts[c] * f
            rows[m + c] = rows[c] + s
            wts[c] *= g
        m *= 2
    return m


@njit(cache=True, nogil=True, inline="always")
def interp_rows(table, wts, rows, m, out):
    """out[k] = sum_{c<m} wts[c] * table[rows[c], k] for k < out.size (out: float64, block).

    Corners are taken four at a time so that each pass over ``out`` streams four table rows
    (fewer passes over the output, vectorisable along k).
    """
    nb = out.shape[0]
    c = 0
    first = True
    while c < m:
        left = m - c
        if left >= 4:
            w0, w1, w2, w3 = wts[c], wts[c + 1], wts[c + 2], wts[c + 3]
            r0, r1, r2, r3 = rows[c], rows[c + 1], rows[c + 2], rows[c + 3]
            if first:
                for k in range(nb):
                    out[k] = (w0 * table[r0, k] + w1 * table[r1, k]) + (w2 * table[r2, k] + w3 * table[r3, k])
            else:
                for k in range(nb):
                    out[k] += (w0 * table[r0, k] + w1 * table[r1, k]) + (w2 * table[r2, k] + w3 * table[r3, k])
            c += 4
        elif left >= 2:
            w0, w1 = wts[c], wts[c + 1]
            r0, r1 = rows[c], rows[c + 1]
            if first:
                for k in range(nb):
                    out[k] = w0 * table[r0, k] + w1 * table[r1, k]
            else:
                for k in range(nb):
                    out[k] += w0 * table[r0, k] + w1 * table[r1, k]
            c += 2
        else:
            w0 = wts[c]
            r0 = rows[c]
            if first:
                for k in range(nb):
                    out[k] = w0 * table[r0, k]
            else:
                for k in range(nb):
                    out[k] += w0 * table[r0, k]
            c += 1
        first = False


@njit(cache=True, nogil=True)
def interp_point(table, bp, off, strides, extrapolate, point, idx, frac, wts, rows, out):
    """Search + weights + interpolation of one table at one point; returns the clip flags."""
    flags = locate(bp, off, point, extrapolate, idx, frac)
    m = corner_weights(idx, frac, strides, wts, rows)
    interp_rows(table, wts, rows, m, out)
    return flags


@njit(cache=True, nogil=True)
def interp_many(table, bp, off, strides, extrapolate, points, out):
    """Interpolate ``table`` at every row of ``points`` (k, n) into ``out`` (k, block).

    The bracketing index of one point is the search hint of the next. Returns the number of
    points that lay outside the grid on at least one axis.
    """
    n = points.shape[1]
    idx = np.zeros(n, dtype=np.int64)
    frac = np.zeros(n, dtype=np.float64)
    wts = np.zeros(1 << n, dtype=np.float64)
    rows = np.zeros(1 << n, dtype=np.int64)
    outside = 0
    for i in range(points.shape[0]):
        f = interp_point(table, bp, off, strides, extrapolate, points[i], idx, frac, wts, rows, out[i])
        if f != 0:
            outside += 1
    return outside


def as_table(grid: Grid, values: np.ndarray) -> np.ndarray:
    """Pack values of shape grid.shape + block_shape into a (grid.size, prod(block_shape)) table."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[: grid.ndim] != grid.shape:
        raise ValueError(f"values of shape {values.shape} do not start with the grid shape {grid.shape}")
    return np.ascontiguousarray(values.reshape(grid.size, -1))


def interpolate(grid: Grid, values: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Interpolate gridded values (grid.shape + block_shape) at points (k, n) -> (k,) + block_shape.

    Convenience for analysis code and tests; the runtime calls the kernels directly.
    """
    values = np.asarray(values, dtype=np.float64)
    block_shape = values.shape[grid.ndim:]
    table = as_table(grid, values)
    pts = np.ascontiguousarray(np.atleast_2d(points), dtype=np.float64)
    if pts.shape[1] != grid.ndim:
        raise ValueError(f"points must have {grid.ndim} columns, got shape {pts.shape}")
    out = np.empty((pts.shape[0], table.shape[1]))
    interp_many(table, grid.bp, grid.off, grid.strides, grid.extrapolate, pts, out)
    return out.reshape((pts.shape[0],) + block_shape)
