"""Health trending: one health snapshot per flight, trends over an engine's life, fault flags.

A flight's snapshot is the median of the health estimates over its settled, unflagged samples
(after ``settle`` seconds, flags == 0): robust to the filter's start-up transient and to short
excursions. Over many flights, each health parameter gets a least-squares line (level and slope
per flight with standard errors) and two kinds of flag:

- ``step``: the newest snapshot departs from the line fitted to the flights before it by more than
  ``step_sigma`` residual standard deviations and at least ``step_min`` (absolute);
- ``limit``: the newest snapshot is below ``limit`` (health parameters are negative when degraded).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import h5py
import numpy as np

from .h5io import read_strings


@dataclass
class Snapshot:
    """Health of one flight: names (nh,), values (nh,) median estimates, spread (nh,) IQR/1.349."""

    source: str
    names: list[str]
    values: np.ndarray
    spread: np.ndarray
    samples: int


def snapshot(time, h_hat, flags, names, source="<memory>", settle: float = 60.0) -> Snapshot:
    """Snapshot from one flight's estimates: time (n,) s, h_hat (n, nh), flags (n,) int."""
    time, h_hat, flags = np.asarray(time), np.asarray(h_hat), np.asarray(flags)
    use = (time >= time[0] + settle) & (flags == 0) & np.all(np.isfinite(h_hat), axis=1)
    if not use.any():
        raise ValueError(f"{source}: no settled, unflagged samples after {settle:g} s to summarise")
    h = h_hat[use]
    q75, q50, q25 = np.percentile(h, [75, 50, 25], axis=0)
    return Snapshot(os.fspath(source), list(names), q50, (q75 - q25) / 1.349, int(use.sum()))


def snapshot_file(path, settle: float = 60.0) -> Snapshot:
    """Snapshot from a results file written by ``pwl run``."""
    with h5py.File(path, "r") as f:
        if f.attrs.get("format") not in ("pwl-estimates", b"pwl-estimates"):
            raise ValueError(f"{path}: not a pwl results file")
        return snapshot(f["time"][()], f["h_hat"][()], f["flags"][()],
                        read_strings(f["names/h_hat"]), path, settle)


@dataclass
class Trend:
    """Per health parameter over flights 0..m-1: level at the newest flight, slope per flight,
    their standard errors, and the flags raised (parameter name -> list of reasons)."""

    names: list[str]
    values: np.ndarray          # (m, nh) snapshots
    level: np.ndarray           # (nh,)
    slope: np.ndarray           # (nh,) per flight
    slope_se: np.ndarray        # (nh,)
    flags: dict[str, list[str]]

    def table(self) -> str:
        lines = [f"{'parameter':<10} {'latest':>9} {'level':>9} {'slope/flight':>13} {'+-':>9}  flags"]
        for j, n in enumerate(self.names):
            lines.append(f"{n:<10} {self.values[-1, j]:>9.4f} {self.level[j]:>9.4f} "
                         f"{self.slope[j]:>13.2e} {self.slope_se[j]:>9.1e}  {', '.join(self.flags.get(n, []))}")
        return "\n".join(lines)


def _line(x, y):
    """Least-squares y = a + b x; returns a, b, se(b), residual std (columns of y independently)."""
    X = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    dof = max(len(x) - 2, 1)
    s = np.sqrt((r ** 2).sum(axis=0) / dof)
    sxx = ((x - x.mean()) ** 2).sum()
    se = s / np.sqrt(sxx) if sxx > 0 else np.full_like(s, np.inf)
    return coef[0], coef[1], se, s


def trend(snaps: list[Snapshot], step_sigma: float = 4.0, step_min: float = 0.005,
          limit: float = -0.03) -> Trend:
    """Trend and fault flags over flights in order (oldest first); needs >= 2 snapshots."""
    if len(snaps) < 2:
        raise ValueError("a trend needs at least two flights")
    names = snaps[0].names
    for s in snaps:
        if s.names != names:
            raise ValueError(f"{s.source}: health parameters {s.names} differ from {names}")
    Y = np.array([s.values for s in snaps])
    x = np.arange(len(snaps), dtype=np.float64)
    a, b, se, _ = _line(x, Y)
    flags: dict[str, list[str]] = {}
    if len(snaps) >= 4:
        a0, b0, _, s0 = _line(x[:-1], Y[:-1])
        pred = a0 + b0 * x[-1]
        dev = Y[-1] - pred
        for j, n in enumerate(names):
            if abs(dev[j]) > max(step_sigma * s0[j], step_min):
                flags.setdefault(n, []).append(f"step {dev[j]:+.4f}")
    for j, n in enumerate(names):
        if Y[-1, j] < limit:
            flags.setdefault(n, []).append(f"below {limit:g}")
    return Trend(list(names), Y, a + b * x[-1], b, se, flags)


def plot_trend(tr: Trend, path, truth: np.ndarray | None = None) -> None:
    """PNG of every health parameter over flights (matplotlib, the ``plot`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nh = len(tr.names)
    cols = min(nh, 5)
    rows = (nh + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    x = np.arange(tr.values.shape[0])
    for j, n in enumerate(tr.names):
        ax = axes[j // cols][j % cols]
        ax.plot(x, 100 * tr.values[:, j], "o-", ms=3, label="estimate")
        if truth is not None:
            ax.plot(x, 100 * truth[:, j], "k--", lw=1, label="truth")
        ax.set_title(n + ("  [" + "; ".join(tr.flags[n]) + "]" if n in tr.flags else ""), fontsize=8,
                     color="red" if n in tr.flags else "black")
        ax.set_xlabel("flight")
        ax.set_ylabel("%")
        ax.grid(alpha=0.3)
    for j in range(nh, rows * cols):
        axes[j // cols][j % cols].axis("off")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
