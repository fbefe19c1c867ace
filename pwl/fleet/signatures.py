"""Fault signatures at matched scheduling: how health changes and sensor biases move a snapshot.

The runtime schedules trims on the *measured* operating point (for the turbofan: altitude, Mach and
the corrected fan speed NfR computed from the Nf sensor). A steady snapshot compared with the trim
at its own measured operating point therefore has, by construction, zero deviation on the
scheduling sensors; every other sensed channel and every input (fuel flow) deviates. With the
database's linear model at p (discrete A, B, C, D, L, M, corrected units) the steady state obeys

    (I - A) dx - B du = L h                      (state derivatives zero)
    C_s dx + D_s du   = -M_s h - b_s             (scheduling sensors s read their trim value)

for health change h and biases b_s of the scheduling sensors; with as many scheduling sensors as
inputs the pair is square and gives dx, du. The relative deviations of the other channels are

    d_y = (C dx + D du + M h + b_y) / y_trim,    d_u = (du + b_u) / u_trim

so d = S [h; b] with one signature column per health parameter and per bias. A sensed output's
bias is an offset in its raw unit (a thermocouple reading 15 K high, at any power); an input's is
relative (a fuel-flow meter reading 2 % high); a scheduling sensor's has a gain column besides
(``gain:<channel>``, the offset column times its reading: a speed sensor reading 1 % high). Biases of non-scheduling channels move only their
own deviation; a scheduling-sensor bias moves the operating point and so every other channel, and
so does a bias of the inlet sensors that theta and delta come from (T2, P2: the correction, the
corrected operating point and the day's trims move), whose columns are taken numerically. Where
the database gives the inlet pressure from the air data (pressure altitude, Mach and the plant's
recovery), the logged one's deviation from it is one more channel, which only a P2 bias moves.
docs/diagnostics.md derives it; tests compare S with trims of the nonlinear model.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..database import GainDatabase
from ..interp import interpolate
from ..errors import PwlError


class DiagnosisError(PwlError, ValueError):
    """A database or results file that the diagnostics cannot use (the message says why)."""


@dataclass
class Deviation:
    """One snapshot reduced to relative deviations from the trim at its operating point.

    channels (m,) names; d (m,) relative deviations (NaN where the channel has no data); se (m,)
    standard errors of d from the snapshot's sample scatter; S (m, ncol) signature columns named
    ``columns`` (health parameters as fractions, then ``sensor:<channel>``: sensed outputs per raw
    unit of offset, inputs per relative bias, then the inlet sensors (theta and delta channels) per
    raw unit of offset); level (ncol,): the trim value of each channel in raw units at this
    snapshot, the inlet sensors' reading (NaN for health columns); p (np,) operating point."""

    channels: list[str]
    d: np.ndarray
    se: np.ndarray
    S: np.ndarray
    columns: list[str]
    level: np.ndarray
    p: np.ndarray


class Signatures:
    """Deviation channels and signature columns of a gain database (see the module docstring)."""

    def __init__(self, db: GainDatabase):
        self.db = db
        names = db.names
        sched = [c for c, corr, _ in db.schedule if c in names["y"] or c in names["u"]]
        self.sched_y = [c for c in sched if c in names["y"]]
        self.sched_u = [c for c in sched if c in names["u"] and c not in names["y"]]
        if self.sched_u or len(self.sched_y) != db.n("u"):
            raise DiagnosisError(
                f"{db.path}: diagnostics need the operating point to be set by as many sensed outputs as "
                f"there are inputs (the turbofan: NfR from Nf, one fuel flow); this database schedules on "
                f"{[c for c, _, _ in db.schedule]} with inputs {names['u']}")
        self.dev_y = [c for c in names["y"] if c not in self.sched_y]
        self.sensed = self.dev_y + list(names["u"])      # deviations from the trims
        self.channels = list(self.sensed)
        corr = db.correction
        # the inlet's temperature and pressure sensors (theta, delta) when no input or output is one
        self.inlet = [c for c in ((corr.theta_channel, corr.delta_channel) if corr else ())
                      if c not in names["y"] and c not in names["u"]]
        self.columns = list(names["h"]) + [f"sensor:{c}" for c in list(names["y"]) + list(names["u"]) + self.inlet]
        # a scheduling sensor's bias has a gain column too (per fraction of its reading): an
        # offset and a gain of it move the operating point differently at idle and at cruise
        # (Nf reading 1 % high, fitted as an offset only, read a fan and LPC change)
        self.columns += [f"gain:{c}" for c in self.sched_y]
        # the inlet pressure against the one the air data give (pressure altitude, Mach and the
        # plant's inlet recovery, :meth:`GainDatabase.inlet_from_air_data`), when the database can:
        # a channel only that sensor's bias moves (a fan and HPC wash read as a P2 bias of -0.3 %:
        # in the other channels an inlet sensor's bias fits a change of two components nearly as well)
        self.air = bool(corr) and corr.delta_channel in self.inlet and db.derives_inlet()
        if self.air:
            self.channels = self.channels + [corr.delta_channel]
        self.d_axes = [names["p"].index(a) for a in db.dyn_grid.names]

    def theta_delta(self, mean: dict) -> tuple[float, float]:
        c = self.db.correction
        if c is None:
            return 1.0, 1.0
        return mean[c.theta_channel] / c.T_std, mean[c.delta_channel] / c.P_std

    def _trims(self, mean: dict):
        """(theta, delta, operating point p (np,), trims u, y on this day) of raw channel means."""
        db = self.db
        th, de = self.theta_delta(mean)
        p = db.operating_point(np.array([[mean[c] for c, _, _ in db.schedule]]), th, de)[0]
        trim = {k: v[0] for k, v in db.trims_at(p[None], th).items()}    # on this day (db.ambient)
        return th, de, p, trim

    def _factors(self, th, de) -> tuple[np.ndarray, np.ndarray]:
        """The correction factors theta^a delta^b of every sensed output and input (fy, fu)."""
        return (self.db.correction_factor(self.db.names["y"], th, de)[0],
                self.db.correction_factor(self.db.names["u"], th, de)[0])

    def _relative(self, mean: dict, fy, fu, trim) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(d, fac, ref): relative deviations d = raw / fac / ref - 1 of ``self.channels``, with
        their correction factors and corrected trims."""
        ydev = [self.db.names["y"].index(c) for c in self.dev_y]
        fac, ref = np.r_[fy[ydev], fu], np.r_[trim["y"][ydev], trim["u"]]
        if self.air:
            air = self.db.inlet_from_air_data(np.array([[mean[c] for c, _, _ in self.db.schedule]]))
            fac, ref = np.r_[fac, 1.0], np.r_[ref, air]
        return np.array([mean[c] for c in self.channels]) / fac / ref - 1.0, fac, ref

    def at(self, mean: dict, se: dict) -> Deviation:
        """Deviation and signatures of one snapshot: ``mean``/``se`` map raw channel -> value.

        An inlet sensor's bias (theta or delta channel: T2, P2) moves the operating point, the
        correction and the day the trims are taken on: its column is the central difference of the
        deviations over +-0.1 % of its reading, per raw unit."""
        db, nm = self.db, self.db.names
        nx, nu, nh = db.n("x"), db.n("u"), db.n("h")
        th, de, p, trim = self._trims(mean)
        pd = p[self.d_axes][None]
        mat = {k: interpolate(db.dyn_grid, db.dynamics[k], pd)[0] for k in "ABCDLM"}
        iy = [nm["y"].index(c) for c in self.sched_y]
        # the square steady-state system of the module docstring
        Phi = np.block([[np.eye(nx) - mat["A"], -mat["B"]], [mat["C"][iy], mat["D"][iy]]])
        nb = db.n("y") + nu
        rhs = np.zeros((nx + len(iy), nh + nb))
        rhs[:nx, :nh] = mat["L"]
        rhs[nx:, :nh] = -mat["M"][iy]
        for r, j in enumerate(iy):
            rhs[nx + r, nh + j] = -trim["y"][j]          # relative bias b_s times the trim value
        try:
            v = np.linalg.solve(Phi, rhs)
        except np.linalg.LinAlgError:
            raise DiagnosisError(f"{db.path}: the steady-state system at p = {p} is singular") from None
        dx, du = v[:nx], v[nx:]
        Mh = np.zeros((db.n("y"), nh + nb))
        Mh[:, :nh] = mat["M"]
        dy = mat["C"] @ dx + mat["D"] @ du + Mh
        ydev = [nm["y"].index(c) for c in self.dev_y]
        S = np.vstack([dy[ydev] / trim["y"][ydev, None], du / trim["u"][:, None]] +
                      [np.zeros((1, nh + nb))] * self.air)          # (the air data's: no health moves it)
        for r, c in enumerate(self.sensed):                     # own biases: unit columns
            S[r, nh + (nm["y"].index(c) if c in nm["y"] else db.n("y") + nm["u"].index(c))] += 1.0
        fy, fu = self._factors(th, de)
        d, fac, ref = self._relative(mean, fy, fu, trim)
        if self.air and abs(d[-1]) < 1e-12:       # an inlet pressure taken from the air data: none of its own
            d[-1] = np.nan
        s = np.array([se.get(c, np.nan) for c in self.channels]) / fac / ref
        level = np.r_[np.full(nh, np.nan), trim["y"] * fy, trim["u"] * fu, [mean[c] for c in self.inlet]]
        S[:, nh:nh + db.n("y")] /= level[nh:nh + db.n("y")]     # sensed outputs: offsets in raw units
        cols = []
        for c in self.inlet:
            h = 1e-3 * abs(mean[c])
            side = []
            for sign in (1.0, -1.0):
                moved = dict(mean, **{c: mean[c] + sign * h})
                th_m, de_m, _, trim_m = self._trims(moved)
                side.append(self._relative(moved, *self._factors(th_m, de_m), trim_m)[0])
            cols.append((side[0] - side[1]) / (2.0 * h))
        if cols:
            S = np.hstack([S, np.column_stack(cols)])
        gains = [nh + nm["y"].index(c) for c in self.sched_y]      # a gain: the offset column x the reading
        S = np.hstack([S, S[:, gains] * level[gains]])
        level = np.r_[level, level[gains]]
        return Deviation(list(self.channels), d, s, S, list(self.columns), level, p)
