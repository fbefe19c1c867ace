"""Steady-state snapshots of a flight: the averages that gas-path diagnosis compares across flights.

A flight's logged channels are summed in blocks of ``block`` seconds while the filter runs (chunk
by chunk: memory does not grow with the log). A *steady window* is a run of blocks over which every
scheduling variable, as the runtime computes it (corrected, scaled), stays inside a band of
``band`` times its trim-axis span (e.g. 1 % of 0..12 km altitude = 120 m, 0.4 % NfR on a 60-100 %
axis) and whose samples are mostly inside the grid. The first ``settle`` seconds of a window are
dropped (spools and sensors still settling); windows shorter than ``min_seconds`` after that are
not kept.

Each snapshot holds, per logged channel the filter reads, the mean over its finite samples, the
standard error of that mean and the finite fraction (a dead sensor is NaN, not a zero), the mean
operating point p, and the means of the filter's estimates (h_hat, q_hat, z_hat) over the window.

Results files carry them in ``/snapshots`` (see docs/diagnostics.md); :mod:`pwl.fleet.diagnose` reads
them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from numba import njit

from .h5io import read_strings, write_strings

SNAPSHOT_OUTPUTS = ("h_hat", "q_hat", "z_hat")

#: the fewest samples a block of a steady window averages
MIN_BLOCK = 8


@dataclass(frozen=True)
class SteadyConfig:
    """How steady windows are found: ``block`` s per block, ``band`` (fraction of each trim axis's
    span), ``min_seconds`` kept per window after dropping ``settle`` s at its start, blocks with
    more than ``max_outside`` of their samples outside the grid end a window."""

    block: float = 1.0
    band: float = 0.01
    min_seconds: float = 20.0
    settle: float = 5.0
    max_outside: float = 0.1


@dataclass
class Snapshots:
    """Steady windows of one flight (w windows, nc channels, np scheduling variables).

    t0, t1 (w,) s; samples (w,); mean, se, finite (w, nc) over ``channels`` (raw log units);
    p (w, np) mean operating point; outputs name -> (w, k) means of the filter's estimates."""

    channels: list[str]
    p_names: list[str]
    t0: np.ndarray
    t1: np.ndarray
    samples: np.ndarray
    mean: np.ndarray
    se: np.ndarray
    finite: np.ndarray
    p: np.ndarray
    outputs: dict[str, np.ndarray] = field(default_factory=dict)
    output_names: dict[str, list[str]] = field(default_factory=dict)

    def __len__(self):
        return self.t0.size

    def longest(self) -> int:
        """Index of the window with the most samples (-1 when there is none)."""
        return int(np.argmax(self.samples)) if len(self) else -1

    def value(self, i: int, channel: str) -> float:
        return float(self.mean[i, self.channels.index(channel)])

    def save(self, group) -> None:
        """Write into an open HDF5 group (``/snapshots`` of a results file)."""
        write_strings(group, "channels", self.channels)
        write_strings(group, "p_names", self.p_names)
        for k in ("t0", "t1", "samples", "mean", "se", "finite", "p"):
            group.create_dataset(k, data=getattr(self, k))
        for k, v in self.outputs.items():
            group.create_dataset("out_" + k, data=v)
            write_strings(group, "names_" + k, self.output_names[k])

    @classmethod
    def load(cls, group) -> "Snapshots":
        outs = {k[4:]: group[k][()] for k in group if k.startswith("out_")}
        return cls(read_strings(group["channels"]), read_strings(group["p_names"]),
                   *(np.asarray(group[k][()]) for k in ("t0", "t1", "samples", "mean", "se", "finite", "p")),
                   outs, {k: read_strings(group["names_" + k]) for k in outs})


@njit(cache=True, nogil=True)
def block_sums(a, starts, squares, out, c0):
    """Per block b of rows starts[b]..starts[b+1] (the last to the end) of a (k, m): the finite
    count, the sum and, with ``squares``, the sum of squares of every column (a value whose
    square overflows counts as missing then), into out[b, c0 + (0, m, 2m) + j], row by row in
    order (as ``np.add.reduceat`` adds them). Returns the next free column."""
    k, m = a.shape
    nb = starts.shape[0]
    for b in range(nb):
        e = starts[b + 1] if b + 1 < nb else k
        for j in range(m):
            n, s, q = 0.0, 0.0, 0.0
            for i in range(starts[b], e):
                v = a[i, j]
                if np.isfinite(v * v if squares else v):
                    n += 1.0
                    s += v
                    q += v * v
            out[b, c0 + j] = n
            out[b, c0 + m + j] = s
            if squares:
                out[b, c0 + 2 * m + j] = q
    return c0 + (3 if squares else 2) * m


class SnapshotAccumulator:
    """Block sums of one flight, fed chunk by chunk; :meth:`snapshots` finds the steady windows.

    ``channels``: names of the columns of ``raw`` in :meth:`add`; ``spans`` (np,): the trim-axis
    span of every scheduling variable (the band is a fraction of it); ``dt`` s per sample;
    ``outputs``: name -> column names of the estimates averaged per window.

    Per block one row of sums: [samples, outside, then (finite count, sum, sum of squares) of
    every raw channel, (count, sum) of every scheduling variable and estimate column].
    """

    def __init__(self, channels, p_names, spans, dt: float, outputs: dict[str, list[str]],
                 config: SteadyConfig = SteadyConfig()):
        self.channels, self.p_names = list(channels), list(p_names)
        self.spans = np.asarray(spans, dtype=np.float64)
        self.dt, self.cfg = float(dt), config
        # a block averages at least MIN_BLOCK samples: one noisy sample per block (a 1 Hz log)
        # would leave the operating point's band at every block
        self.bs = max(MIN_BLOCK, int(round(config.block / self.dt)))
        self.output_names = {k: list(v) for k, v in outputs.items()}
        self._ids, self._rows, self._t0, self._t1 = [], [], [], []

    def add(self, start: int, time, raw, p, outputs: dict, outside) -> None:
        """Samples start..start+k: time (k,), raw (k, nc) channels, p (k, np) operating points,
        outputs name -> (k, m) estimates, outside (k,) bool (sample outside the grid)."""
        k = raw.shape[0]
        if k == 0:
            return
        blk = (start + np.arange(k)) // self.bs
        starts = np.r_[0, np.flatnonzero(np.diff(blk)) + 1]
        parts = [(np.ascontiguousarray(a, dtype=np.float64).reshape(k, -1), sq) for a, sq in
                 [(raw, True), (p, False)] + [(outputs[o], False) for o in self.output_names]]
        rows = np.empty((starts.size, 2 + sum((3 if sq else 2) * a.shape[1] for a, sq in parts)))
        rows[:, 0] = np.diff(np.r_[starts, k])
        rows[:, 1] = np.add.reduceat(np.asarray(outside, dtype=np.float64), starts)
        c = 2
        for a, sq in parts:
            c = block_sums(a, starts, sq, rows, c)
        t = np.asarray(time, dtype=np.float64)
        ends = np.r_[starts[1:] - 1, k - 1]
        ids = blk[starts]
        if self._ids and ids[0] == self._ids[-1][-1]:   # a block split across two chunks
            self._rows[-1][-1] += rows[0]
            self._t1[-1][-1] = t[ends[0]]
            ids, rows, starts, ends = ids[1:], rows[1:], starts[1:], ends[1:]
        self._ids.append(ids)
        self._rows.append(rows)
        self._t0.append(t[starts])
        self._t1.append(t[ends])

    def _cols(self, rows):
        """Split block rows into named column groups."""
        nc, npv = len(self.channels), len(self.p_names)
        out, j = {"n": rows[:, 0], "outside": rows[:, 1]}, 2
        for name, width, parts in [("raw", nc, 3), ("p", npv, 2)] + [
                (o, len(v), 2) for o, v in self.output_names.items()]:
            out[name] = [rows[:, j + i * width: j + (i + 1) * width] for i in range(parts)]
            j += parts * width
        return out

    def windows(self) -> list[tuple[int, int]]:
        """Steady windows as (first block, last block + 1) into the stored blocks, settle dropped."""
        if not self._ids:
            return []
        ids = np.concatenate(self._ids)
        b = self._cols(np.concatenate(self._rows))
        cnt, s = b["p"]
        with np.errstate(invalid="ignore", divide="ignore"):
            pm = s / cnt
        ok = (np.all(cnt >= 0.5 * b["n"][:, None], axis=1) & (b["outside"] <= self.cfg.max_outside * b["n"])
              & np.all(np.isfinite(pm), axis=1))
        joined = np.r_[False, np.diff(ids) == 1]
        tol = self.cfg.band * self.spans
        block_s = self.bs * self.dt
        drop, need = int(np.ceil(self.cfg.settle / block_s)), int(np.ceil(self.cfg.min_seconds / block_s))
        out, a, nb = [], 0, ids.size
        while a < nb:
            if not ok[a]:
                a += 1
                continue
            lo, hi, e = pm[a].copy(), pm[a].copy(), a + 1
            while e < nb and ok[e] and joined[e]:
                lo2, hi2 = np.minimum(lo, pm[e]), np.maximum(hi, pm[e])
                if np.any(hi2 - lo2 > tol):
                    break
                lo, hi, e = lo2, hi2, e + 1
            if e - (a + drop) >= need:
                out.append((a + drop, e))
            a = e
        return out

    def snapshots(self) -> Snapshots:
        """The steady windows' means (see :class:`Snapshots`)."""
        nc, npv = len(self.channels), len(self.p_names)
        wins = self.windows()
        w = len(wins)
        res = Snapshots(self.channels, self.p_names, np.zeros(w), np.zeros(w), np.zeros(w, np.int64),
                        np.zeros((w, nc)), np.zeros((w, nc)), np.zeros((w, nc)), np.zeros((w, npv)),
                        {k: np.zeros((w, len(v))) for k, v in self.output_names.items()},
                        dict(self.output_names))
        if not w:
            return res
        rows = np.concatenate(self._rows)
        t0, t1 = np.concatenate(self._t0), np.concatenate(self._t1)
        for i, (a, e) in enumerate(wins):
            b = self._cols(rows[a:e].sum(axis=0, keepdims=True))
            n = b["n"][0]
            res.t0[i], res.t1[i], res.samples[i] = t0[a], t1[e - 1], int(n)
            c, s, q = (x[0] for x in b["raw"])
            with np.errstate(invalid="ignore", divide="ignore"):
                m = s / c
                var = np.maximum(q / c - m * m, 0.0) * c / np.maximum(c - 1, 1)
                res.mean[i] = np.where(c > 0, m, np.nan)
                res.se[i] = np.where(c > 1, np.sqrt(var / c), np.nan)
                res.finite[i] = c / n
                res.p[i] = b["p"][1][0] / b["p"][0][0]
                for o in self.output_names:
                    oc, osum = (x[0] for x in b[o])
                    res.outputs[o][i] = np.where(oc > 0, osum / oc, np.nan)
        return res
