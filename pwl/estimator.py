"""The estimator object: opens a gain database, checks logs, runs the numba filter.

Batch ``run(log)`` and streaming ``step(sample)`` call the same kernel
(:func:`pwl.runtime.filter_loop`), so their numbers are identical. ``run_file`` processes an
HDF5 log in chunks with bounded memory and writes results as it goes.
"""
from __future__ import annotations

import os
import warnings

import numpy as np

from .airdata import (INLET_BANDS, INLET_BINS, INLET_OFFSET, LAG_SIGMAS, LAG_WARN, altitude_slip, disagree, inlet_pressure,
                      inlet_temperature, lag, lag_sums)
from .database import AMBIENT_REACH, GainDatabase
from .grid import Axis, Grid
from .h5io import atomic_h5
from .logs import (Log, LogError, case_twin, check_time, gap_starts, read_header, read_log, read_rows, resample, rows_missing,
                   sample_interval, time_gaps)
from .runtime import (FAR_OUTSIDE, NEVER, SMALLEST_ROW, FLAG_AIR_DATA, FLAG_DYN_OUTSIDE, FLAG_FAR_OUTSIDE, FLAG_HEALTH_HELD, FLAG_HELD_INPUT, FLAG_IMPLAUSIBLE, FLAG_NO_UPDATE, FLAG_NOT_STARTED,
                      FLAG_SETTLING, FLAG_STUCK, FLAG_TRIM_FILLED, FLAG_TRIM_OUTSIDE, HEALTH_HOLD_RATIO, MISFIT_SIGMAS, STUCK_AFTER,
                      STUCK_SIGMAS, Bias, Filter, Inputs, Outputs, PackedModel, blank_implausible, filter_loop, report, screen, spike_mask, burst_mask, state_layout)
from .results import LOG_ATTRS, Result, append_rows, init_result_file
from .snapshots import SNAPSHOT_OUTPUTS, SnapshotAccumulator, SteadyConfig
from .errors import PwlError, PwlWarning, UsageError
from .tables import LAWS, AdaptiveTable, TableError, save_tables
from .units import UNITS, implausible_hint, likely_units

OUTPUTS = ("x_hat", "q_hat", "h_hat", "y_hat", "residual", "z_hat")
BIAS_PREFIX = "bias_"   # bias tables are stored as /tables/bias_<channel>


#: a value of an input, a scheduling channel or theta/delta further than SPIKE_FRACTION of its
#: channel's plausible span from the median of the 2 * SPIKE_WIDTH + 1 samples around it is a
#: spike (a data-bus dropout written as 0, a bit error), and so is a run of up to BURST_MAX
#: values that jumps that far from the value before it and comes back: see :func:`spikes`
SPIKE_WIDTH = 2
SPIKE_FRACTION = 0.05
BURST_MAX = 64
#: samples either side of a chunk that its spike test reads
SPIKE_REACH = max(SPIKE_WIDTH, BURST_MAX + 1)
#: what a spike is replaced with: outside every plausible range, so screen() counts and flags it
#: as implausible (FLAG_IMPLAUSIBLE) and the filter holds that channel's last value
_SPIKE = np.finfo(np.float64).max


#: a channel logged at a lower rate than the log's rows (empty between its samples: a flight data
#: recorder's 1-8 Hz words in a 66 Hz export) is filled between its samples (then interpolated as
#: one written with sample-and-hold: :func:`interpolate_held`): at least LOW_RATE_SHARE of its rows
#: empty, and nine in ten of the steps between its samples at most twice their median, which is at
#: most LOW_RATE_GAP seconds (67 rows at 15 ms: 1 Hz steps 66 or 67 rows). Left empty, the
#: operating point had no snapshot, and sensors logged in turn left two or more out on every row:
#: health never estimated
LOW_RATE_SHARE = 0.4
LOW_RATE_GAP = 1.0
#: a channel written with sample-and-hold (each sample of a 1-8 Hz word repeated on the rows of a
#: 66 Hz export until the next one) is one whose value changes at HELD_CHANGES rows or more, nine
#: in ten of them (HELD_SHARE) within HELD_JITTER rows of a regular lattice of 2 rows or more and at
#: most LOW_RATE_GAP seconds (fitted: 1 Hz on a 66.7 Hz grid changes after 66 or 67 rows), or,
#: for a recorder whose words come with a jitter (a bus sampled asynchronously: 1 Hz words after
#: 57-77 rows), nine in ten of the gaps between them within HELD_SPREAD of a whole number of
#: periods, where samples changing at random rows could not have fitted it (HELD_CHANCE): not a
#: channel that changes on most rows, a constant or frozen one, nor a quantised one at rest,
#: whose changes come at irregular intervals. Held channels are found on a log's first HELD_ROWS
#: rows (a run in chunks finds the same ones as a whole run)
HELD_CHANGES = 20
HELD_SHARE = 0.9
HELD_JITTER = 0.6
HELD_SPREAD = 0.15
#: a held sensor's rows between two samples whose line may be off by more than HELD_BEND of its
#: noise standard deviations are left out of the update (:func:`interpolate_held`)
HELD_BEND = 3.0
HELD_CHANCE = 1e-6
HELD_ROWS = 1 << 16


def _low_rate_step(x: np.ndarray, max_rows: int) -> int:
    """The median step (rows) between the samples of channel ``x`` (n,) if it is logged at a
    lower rate (:data:`LOW_RATE_SHARE`; its samples at most ``max_rows`` rows apart), else 0."""
    ok = np.isfinite(x)
    count = np.count_nonzero(ok)
    if not 3 <= count <= (1.0 - LOW_RATE_SHARE) * x.size:
        return 0
    steps = np.diff(np.flatnonzero(ok))
    med = int(np.median(steps))
    return med if 2 <= med <= max_rows and np.mean(steps <= 2 * med) >= 0.9 else 0


def _fill_low_rate(a: np.ndarray, j: int, med: int) -> None:
    """In place: column j of ``a`` holds each sample over the empty rows after it, up to twice
    ``med`` rows (a longer gap stays empty: a dropout)."""
    ok = np.isfinite(a[:, j])
    rows = np.arange(a.shape[0])
    last = np.maximum.accumulate(np.where(ok, rows, -1))
    fill = ~ok & (last >= 0) & (rows - last <= 2 * med)
    a[fill, j] = a[last[fill], j]


def hold_low_rate(a: np.ndarray, max_rows: int) -> dict[int, int]:
    """In place: every low-rate column of ``a`` (n, k) (:data:`LOW_RATE_SHARE`; its samples at most
    ``max_rows`` rows apart) holds each sample over the empty rows after it, up to twice the
    median step between its samples (a longer gap stays empty: a dropout). Returns column ->
    median step (rows) of the columns held."""
    held = {j: m for j in range(a.shape[1]) if (m := _low_rate_step(a[:, j], max_rows))}
    for j, med in held.items():
        _fill_low_rate(a, j, med)
    return held


def _gap_period(d: np.ndarray) -> float:
    """The period (rows) of samples whose starts are ``d`` (float, at least one) rows apart: from
    the gaps of one to three periods (longer gaps: samples that repeated a value)."""
    med = float(np.median(d))
    p = float(d[d <= 1.5 * med].mean())         # one period: 66 or 67 rows at 1 Hz on 66.7 Hz
    for _ in range(2):
        m = np.maximum(np.rint(d / p), 1.0)
        few = m <= 3
        p = float(d[few].sum() / m[few].sum())
    return p


def _lattice(new: np.ndarray) -> tuple[float, int]:
    """(period, how many of them lie on it) of the regular lattice fitted to the rows ``new``
    (sorted, at least two: where samples start): the period from their gaps of one to three
    periods (longer gaps: samples that repeated a value), then by least squares, rows ~ phase +
    period * index, over all of them and again over those within :data:`HELD_JITTER` of it."""
    d = np.diff(new).astype(np.float64)
    p = _gap_period(d)
    m = np.concatenate([[0.0], np.cumsum(np.maximum(np.rint(d / p), 1.0))])
    on = np.ones(new.size, dtype=bool)
    for _ in range(2):
        if np.count_nonzero(on) < 2 or m[on][0] == m[on][-1]:
            break
        mc = m[on] - m[on].mean()
        p = float(np.dot(mc, new[on] - new[on].mean()) / np.dot(mc, mc))
        r = new - p * m
        on = np.abs(r - np.median(r[on])) <= HELD_JITTER
    return p, int(np.count_nonzero(on))


def held_period(x: np.ndarray, max_rows: float) -> float:
    """The period in rows (2 or more, at most ``max_rows``; not an integer for a rate that does
    not divide the row rate) of the samples of channel ``x`` (n,) if it is written with
    sample-and-hold (:data:`HELD_CHANGES`), else 0.0. Vectorised: the rows where a new value
    starts, the lattice fitted to them (:func:`_lattice`), the share of them on it."""
    if 2.5 * np.count_nonzero(x[1:] == x[:-1]) < x.size - 1:
        return 0.0                              # a new value on most rows (cheap: most channels)
    rows = np.flatnonzero(np.isfinite(x))
    v = x[rows]
    new = rows[1:][v[1:] != v[:-1]]             # the rows where a new value starts
    if new.size < HELD_CHANGES or new.size > 0.6 * rows.size:
        return 0.0                              # too few to tell, or a value on most rows
    if not 2.0 <= np.median(np.diff(new)) <= max_rows + 1.0:
        return 0.0
    p, on = _lattice(new)
    chance = min(1.0, 2.0 * HELD_JITTER / p)    # of a change at a random row to fall that close
    if not (on >= HELD_SHARE * new.size and on * np.log(chance) <= np.log(HELD_CHANCE)):
        d = np.diff(new).astype(np.float64)     # not on one lattice: gaps of whole periods?
        p = _gap_period(d)
        on = np.count_nonzero(np.abs(d - p * np.maximum(np.rint(d / p), 1.0)) <= HELD_SPREAD * p)
        if on < HELD_SHARE * d.size or on * np.log(2.0 * HELD_SPREAD) > np.log(HELD_CHANCE):
            return 0.0
    return p if 2.0 <= p <= max_rows + 0.5 else 0.0


def held_channels(a, max_rows: float) -> dict[int, tuple[float, int]]:
    """The held columns of ``a`` ((n, k), or a sequence of k channels (n,)): column -> (period in
    rows, and for a channel logged with empty rows between its samples the median step between
    them, else 0): the low-rate ones (:func:`hold_low_rate`'s test; their period that of the
    lattice of their samples, :func:`_lattice`) and the ones written with sample-and-hold
    (:func:`held_period`). Both are the same channel: samples at a regular period, logged two
    ways."""
    held = {}
    for j, x in enumerate(a.T if isinstance(a, np.ndarray) else a):
        med = _low_rate_step(x, int(max_rows))
        if med:
            held[j] = (_lattice(np.flatnonzero(np.isfinite(x)))[0], med)
        elif p := held_period(x, max_rows):
            held[j] = (p, 0)
    return held


def interpolate_held(a: np.ndarray, periods: dict[int, float], tol: dict[int, float] | None = None) -> None:
    """In place: every column j of ``a`` (n, k) in ``periods`` (its period in rows), written with
    sample-and-hold, takes on each row the value linearly between the sample before and the
    sample after it, rather than the last sample's: a sample starts where a new value does, and a
    value kept longer than 1.5 periods was sampled again unchanged, so the ramp to the next value
    spans its last period. Held, a value was up to a period late and every row a new measurement
    of it: in the take-off's spool-up Ps30 held every 64 rows read up to 35 % low, misfit, was
    left out and stayed out (the health held without it), in a probe fleet for the whole log in
    19 of 48 logs. Rows not finite or :data:`_SPIKE` stay as they are and give no value.

    ``tol`` (column -> share of its value): where the samples bend so much that the line between
    two of them may be off by more than that (a quarter of the larger second difference at its
    ends: the chord's error over a corner), the rows between them are NaN (missing: the filter
    updates from the other sensors there). Interpolated through the throttle chop of the descent,
    four sensors held at 1 Hz put thrust 5 % off on samples taken as trusted."""
    tol = tol or {}
    for j, p in periods.items():
        x = a[:, j]
        rows = np.flatnonzero(np.isfinite(x) & (x != _SPIKE))
        v = x[rows]
        k = np.concatenate([[0], np.flatnonzero(v[1:] != v[:-1]) + 1])   # the samples (into rows)
        if k.size < 2:
            continue
        at, val = rows[k], v[k]
        step = max(1, int(round(p)))
        start = np.where(np.diff(at) <= 1.5 * p, at[:-1], np.maximum(at[:-1], at[1:] - step))
        start[0] = max(at[0], at[1] - step)     # the log began with a sample already held
        seg = np.searchsorted(at, rows, side="right") - 1
        inner = seg < at.size - 1
        r, s = rows[inner], seg[inner]
        frac = np.clip((r - start[s]) / (at[s + 1] - start[s]), 0.0, 1.0)
        x[r] = val[s] + frac * (val[s + 1] - val[s])
        if j in tol and val.size > 2:
            bend = np.abs(np.concatenate([[0.0], np.diff(val, 2), [0.0]]))
            off = np.maximum(bend[:-1], bend[1:]) / 4.0 > tol[j] * np.abs(val[:-1])    # per gap between samples
            x[r[off[s] & (r != at[s])]] = np.nan                                      # not the samples


def repeat_runs(x: np.ndarray, n: float) -> list[tuple[int, int]]:
    """(a, b) of every run of ``x`` (rows,) holding one value exactly on rows a..b-1 (its first
    value, then its repeats) for ``n`` rows or more; NaN never repeats."""
    starts, stops = true_runs(np.concatenate([[False], x[1:] == x[:-1]]))
    return [(int(a), int(b)) for a, b in zip(starts - 1, stops) if b - a >= n]


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, stops) of the runs of True in the bool vector ``mask``: mask[starts[i]:stops[i]]."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return edges[::2], edges[1::2]


def _longest_runs(hit: np.ndarray, runs: np.ndarray) -> None:
    """Update ``runs`` (2, k): [longest run of True in each column of ``hit`` (n, k) so far, the
    run going on at its end], continuing the runs of the rows before ``hit``'s."""
    for j in range(hit.shape[1]):
        starts, stops = true_runs(hit[:, j])
        if not starts.size:
            runs[1, j] = 0.0
            continue
        lens = (stops - starts).astype(np.float64)
        if starts[0] == 0:
            lens[0] += runs[1, j]
        runs[0, j] = max(runs[0, j], lens.max())
        runs[1, j] = lens[-1] if stops[-1] == hit.shape[0] else 0.0


def spikes(a: np.ndarray, span: np.ndarray, width: int = SPIKE_WIDTH, fraction: float = SPIKE_FRACTION,
           longest: int = BURST_MAX, frozen=False):
    """(n, k) bool: the values of ``a`` (n, k) further than ``fraction * span[j]`` (span (k,),
    the channels' plausible spans; inf: no test) from the median of their centred window of
    2 * width + 1 samples (cut at the ends; NaN left out), and the runs of up to ``longest``
    values that jump that far from the value before them and come back within it after, and in
    the columns where ``frozen`` (bool, (k,) or one for all) a jump to a word repeated exactly for
    longer (:func:`pwl.runtime.burst_mask`). A step is none of these.
    Degraded demo flight with 1 % of its Mach samples 0 (a dropout): Fn RMS 9.8 % and no cruise
    snapshot without the median test, 0.227 % and all three with it; with 0.1 % of its samples
    starting a run of 3, 10 or 30 zeros: 5.8, 9.5, 16 % without the run test, 0.227 % with it."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    span = np.ascontiguousarray(np.broadcast_to(np.asarray(span, dtype=np.float64), a.shape[1:]))
    out = spike_mask(a, span, width, fraction, np.empty(a.shape, dtype=np.bool_))
    frozen = np.ascontiguousarray(np.broadcast_to(np.asarray(frozen, dtype=np.bool_), a.shape[1:]))
    return burst_mask(a, span, longest, fraction, frozen, out)


class EnvelopeError(PwlError, ValueError):
    """The operating point left the grid and the database's policy is ``error``."""


#: the estimator's modes: how the update gain is made (:class:`Estimator`)
MODES = ("steady", "untuned", "online", "zones")


def _hist_median(h: np.ndarray) -> float:
    """The median relative offset (expm1 of the bin centre) of a histogram over :data:`INLET_BINS`;
    NaN when empty."""
    n = h.sum()
    if n == 0:
        return float("nan")
    k = int(np.searchsorted(np.cumsum(h), n / 2.0))
    return float(np.expm1(0.5 * (INLET_BINS[k] + INLET_BINS[k + 1])))


class Estimator:
    """A piecewise-linear self-tuning model with its steady-state Kalman filter.

    Parameters
    ----------
    db : GainDatabase or path
        The gain database (``pwl build``).
    mode : {"steady", "untuned", "online", "zones"}
        How the update gain is made (:data:`MODES`):

        - ``"steady"`` (default): the stored steady-state gains, interpolated at the operating
          point;
        - ``"untuned"``: the same with the tuners held at ``q0`` (default 0: nominal health),
          the untuned model;
        - ``"online"``: the full Kalman filter of the same piecewise-linear model: the error
          covariance is propagated every step with the interpolated A_a, Q_a and the gain solved
          from it (an EKF whose Jacobians are the database's matrices; the baseline the steady
          gains are measured against). Slower (``pwl zones --database``); the current covariance
          is :attr:`covariance`, and results carry ``h_std``, the standard deviation of every
          health estimate (docs/zones.md says how to read it);
        - ``"zones"``: the gain picked from the database's k-means zones (``/zones``, built by
          :func:`linearize.zones.database_zones`): the centroid gain of the zone of the nearest
          dynamics node, instead of the interpolated K.
    q0 : array (nq,), optional
        Initial tuners (default 0), e.g. the last flight's: where every :meth:`reset` (and so
        every ``run``) starts them unless it is given other ones.
    bias : dict, optional
        The tuning element, adaptive bias tables on sensed channels: channel ->
        :class:`pwl.tables.AdaptiveTable` (from :meth:`new_bias_tables` or
        :func:`load_bias_tables`), all on one grid over scheduling variables, values in
        corrected units. They learn from the filter's innovations during runs (unless locked)
        and keep what they learnt across :meth:`reset` and flights; :meth:`save_bias_tables`
        persists them.
    health_std : bool
        Online mode: compute ``h_std`` (False saves about 0.2 microseconds per step).
    resample : bool
        Resample logs whose sample interval is not the database's dt (else refused).
    channel_map : ChannelMap or path, optional
        How log files name and scale their channels (:mod:`pwl.channel_map`).
    health_hold : float
        See below.
    misfit_sigmas : float
        The misfit gate in sensor standard deviations (the database's R relative to the trims;
        default 12): a sensor whose residual exceeds it is flagged FLAG_MISFIT and, while such
        sensors are fewer than half the present ones, left out of the update like a missing one
        (a spike, a failed sensor); ``float("inf")``: never.
    stuck_after : float
        Seconds (default 2) a sensor's value must stay exactly the same before it counts as stuck:
        from then on, while its prediction has moved more than STUCK_SIGMAS (4) sensor standard
        deviations since the value froze -- or at once if it was a noisy signal (its changes
        averaged more than half a standard deviation) and the other sensors still change -- it is
        left out of the update (FLAG_STUCK) until its value changes. ``float("inf")``: never.
        The same time makes an input that repeats one value exactly while the operating point
        moves count as frozen (FLAG_HELD_INPUT, :meth:`_check_frozen_inputs`), except the inputs
        of ``may_hold``.
    may_hold : sequence of str
        Inputs (``db.names["u"]``) that may legitimately hold one value exactly while the engine
        moves -- variable geometry at a mechanical stop, a closed bleed valve -- and so are never
        taken for a frozen word (default none; recorded in :attr:`provenance`). The stuck-sensor
        test and the other inputs' frozen-input test stay as they are.
    settle : float, optional
        Seconds from the filter's first valid sample during which its estimates are flagged
        FLAG_SETTLING (converging from q0: not trusted, not in the snapshots' estimates); default 3 time constants
        of the database's slowest error dynamics (:meth:`GainDatabase.settling_time`, 27 s on
        the demo database); 0: never.

    State persists across ``run`` / ``step`` calls until :meth:`reset` (one flight = reset,
    then run).

    ``health_hold``: with steady gains and one sensor missing, the update goes on from the others
    (FLAG_PARTIAL); when that sensor is one the health estimates depend on -- without it some
    health parameter's steady-state standard deviation is more than ``health_hold`` times its
    all-sensor value (the database's ``/kalman/out_h_ratio``) -- the tuners and ``h_hat`` hold
    their last values (from before the sensor went, or q0 and h_ref + V_pinv q0) and the step is
    flagged FLAG_HEALTH_HELD; the states and outputs are still updated. Left free, the tuners
    wander where the remaining sensors barely see them (T30 dead on the degraded demo flight: T40
    0.43 % RMS instead of 0.13 %). ``float("inf")``: never hold.
    """

    def __init__(self, db, mode: str = "steady", *, q0=None, bias: dict | None = None,
                 health_std: bool = True, resample: bool = False, channel_map=None,
                 health_hold: float = HEALTH_HOLD_RATIO, misfit_sigmas: float = MISFIT_SIGMAS,
                 stuck_after: float = STUCK_AFTER, may_hold=(), settle: float | None = None):
        if mode not in MODES:
            raise UsageError(f"estimator mode {mode!r}: one of {', '.join(MODES)}")
        self.mode = mode
        tune, online, zones = mode != "untuned", mode == "online", mode == "zones"
        self.db = db if isinstance(db, GainDatabase) else GainDatabase.open(db)
        if channel_map is not None and not hasattr(channel_map, "apply"):
            from .channel_map import ChannelMap
            channel_map = ChannelMap.load(channel_map)
        self.channel_map = channel_map   # logs read from files go through it (pwl.channel_map)
        self.failed: list[str] = []      # sensors failed for the last log (_failed_sensors): left out
        self._inlet_replaced = False     # the inlet pressure taken from the air data (_inlet_biased)
        self._logged_delta = None        # its logged values on the rows last split, for the snapshots
        self._blind: list = []          # (first, last) times without measurement updates (_second_opinions)
        self._inlet_dead: list = []     # (theta or delta channel, first, last time) run as missing (_second_opinions)
        self.resample = resample
        zt = None
        if zones:
            from .zones import ZoneTable
            zt = ZoneTable.from_record(self.db.zones, where=f"{self.db.path}:/zones")
        self.pm = PackedModel.from_database(self.db, tune=tune, online=online, zones=zt,
                                            health_hold=health_hold)
        na = self.db.n("x") + self.db.n("q")
        self.cov = np.zeros(na * na if online else 0)
        db = self.db
        self.names = {"x_hat": db.names["x"], "q_hat": db.names["q"], "h_hat": db.names["h"],
                      "y_hat": db.names["y"], "residual": db.names["y"], "z_hat": db.names["z"]}
        if online and health_std:
            self.names["h_std"] = db.names["h"]
        self.channel_units = db.channel_units()
        self.ranges = db.channel_ranges()
        self._limits = self._column_limits()
        self._air = db.air_data()
        self._VT = np.ascontiguousarray(self.db.tuner["V_pinv"].T)
        default_settle = self.db.settling_time()
        self.settle = default_settle if settle is None else float(settle)
        for name, value, ok, want in (("misfit_sigmas", misfit_sigmas, misfit_sigmas > 0, "> 0"),
                                      ("stuck_after", stuck_after, stuck_after >= 0, ">= 0 s"),
                                      ("settle", settle, settle is None or 0 <= settle < np.inf, "finite and >= 0 s")):
            if not ok:
                raise UsageError(f"{name} {value}: must be {want}")
        self._checks = {"hold": (health_hold, HEALTH_HOLD_RATIO), "misfit": (misfit_sigmas, MISFIT_SIGMAS),
                        "stuck": (stuck_after, STUCK_AFTER), "settle": (self.settle, default_settle)}   # (value, default)
        self._sd = sd = self._sensor_sd()
        stuck_n = min(np.ceil(stuck_after / self.db.dt), 2.0 ** 62)
        # a log whose sensors misfit longer than the filter settles is run again with them used
        # after so long (_second_opinions, pwl.runtime.FLAG_MISFIT)
        self._readmit_n = max(1, int(np.ceil(default_settle / self.db.dt)))
        self._model = self.pm.record(self.db.tuner["V_pinv"], np.stack([misfit_sigmas * sd, STUCK_SIGMAS * sd, sd]),
                                     int(stuck_n), int(np.ceil(self.settle / self.db.dt)), NEVER)
        names = (may_hold,) if isinstance(may_hold, str) else tuple(may_hold)
        unknown = [c for c in names if c not in db.names["u"]]
        if unknown:
            raise UsageError(f"may_hold {', '.join(map(repr, unknown))}: not an input of {db.path} (its inputs: "
                             f"{', '.join(db.names['u'])}); only inputs are tested for a value held while the "
                             "engine moves")
        self.may_hold = tuple(c for c in db.names["u"] if c in names)
        #: (nu,) samples an input must repeat one value exactly, while the operating point moves, to
        #: count as frozen: the stuck detector's, inf for an input that may hold (batch and Stream)
        self._hold_n = np.array([np.inf if c in self.may_hold else float(self._model.stuck_n)
                                 for c in db.names["u"]])
        self._grids = self.pm.grids(self.db)
        hr = db.attrs.get("health_ranges") or {}
        self._h_range = tuple(np.array([hr.get(h, (-np.inf, np.inf))[i] for h in db.names["h"]],
                                       dtype=np.float64) for i in (0, 1))
        self._set_bias(bias or {})
        self.steady = SteadyConfig()
        nq = self.db.n("q")
        self.q0 = np.zeros(nq) if q0 is None else np.array(q0, dtype=np.float64).reshape(-1)
        if self.q0.shape != (nq,) or not np.isfinite(self.q0).all():
            raise UsageError(f"q0 {q0!r}: expected {nq} finite tuner values ({', '.join(self.db.names['q'])})")
        self.reset()

    # ---- bias tables (the tuning element) ---------------------------------------------------
    def new_bias_tables(self, channels, axes=None, ratio: float = 100.0, law: str = "exact") -> dict:
        """Fresh zero bias tables, installed in this estimator (they learn during runs) and returned.

        Parameters
        ----------
        channels : sequence of str
            Sensed outputs (``db.names["y"]``) to give a bias table each.
        axes : Grid, optional
            The tables' grid over scheduling variables (``db.names["p"]``); None: the dynamics
            grid's axes.
        ratio : float
            sigma_x^2 / sigma_theta^2, measurement over process noise variance of the tables'
            gain law (larger: slower learning).
        law : {"exact", "paper"}
            The gain law (:mod:`pwl.tables`); every bias table has the same.

        Returns
        -------
        dict
            channel -> :class:`pwl.tables.AdaptiveTable`, values 0 in the channel's corrected
            units (the same objects as ``self.bias``).

        Raises
        ------
        TableError
            An axis that is not a scheduling variable, or a law other than exact/paper.
        """
        grid = axes if isinstance(axes, Grid) else Grid(
            [Axis(a.name, a.values, a.unit) for a in self.db.dyn_grid.axes], self.db.policy)
        tables = {c: AdaptiveTable(grid, law=law, ratio=ratio) for c in channels}
        self._set_bias(tables)
        return tables

    def _set_bias(self, tables: dict) -> None:
        db = self.db
        grids = {id(t.grid): t.grid for t in tables.values()}
        grid = next(iter(grids.values())) if tables else Grid([Axis("none", [0.0, 1.0])])
        for c, t in tables.items():
            if c not in db.names["y"]:
                raise TableError(f"bias table {c!r}: not a sensed channel of {db.path} ({db.names['y']})")
            if t.grid != grid:
                raise TableError(f"bias table {c!r}: every bias table must share one grid")
            if t.law not in ("exact", "paper") or t.ratio != next(iter(tables.values())).ratio or \
                    t.law != next(iter(tables.values())).law:
                raise TableError(f"bias table {c!r}: law must be exact or paper, the same for all tables")
        missing = [a.name for a in grid.axes if tables and a.name not in db.names["p"]]
        if missing:
            raise TableError(f"bias tables: axes {missing} are not scheduling variables {db.names['p']}")
        nb = len(tables)
        self.bias = dict(tables)
        self._b_chan = np.array([db.names["y"].index(c) for c in tables], dtype=np.int64)
        vals = np.zeros((nb, grid.size))
        counts = np.zeros((nb, grid.size), dtype=np.int64)
        for j, (c, t) in enumerate(tables.items()):
            vals[j] = t.values.reshape(-1)
            counts[j] = t.counts.reshape(-1)
            t.values, t.counts = vals[j].reshape(grid.shape), counts[j].reshape(grid.shape)  # views
        self._b_vals, self._b_counts, self._b_grid = vals, counts, grid
        self._b_pidx = np.array([db.names["p"].index(a.name) for a in grid.axes] if tables else [],
                                dtype=np.int64)
        self._b_idx = np.zeros(len(self._b_pidx), dtype=np.int64)
        self._b_share = bool(tables) and tuple(a.name for a in grid.axes) == db.dyn_grid.names and all(
            np.array_equal(a.values, b.values) for a, b in zip(grid.axes, db.dyn_grid.axes))
        first = next(iter(tables.values()), None)
        self._b_law = LAWS[first.law] if first else 0
        self._b_ratio = float(first.ratio) if first else 1.0
        self.names = {k: v for k, v in self.names.items() if k != "bias_hat"}
        if tables:
            self.names["bias_hat"] = list(tables)

    def save_bias_tables(self, path) -> None:
        """Write every bias table to ``/tables/bias_<channel>`` of a file, atomically.

        Parameters
        ----------
        path : str or path-like
            A gain database (its other content is kept, its seal renewed) or an adaptive-tables
            file; created as an adaptive-tables file (``pwl-adaptive-tables``) if missing. Read
            back with :func:`load_bias_tables`.

        Raises
        ------
        TableError
            ``path`` is not HDF5, or a file of another kind (named with the format found).
        """
        save_tables(path, {BIAS_PREFIX + c: t.to_record() for c, t in self.bias.items()})

    # ---- state -------------------------------------------------------------------------------
    def reset(self, q0=None) -> None:
        """Forget the filter state (start of a flight): the next valid sample starts at trim.

        Bias tables keep what they learnt; the channel counts (``missing``, ``implausible``)
        start again from 0.

        Parameters
        ----------
        q0 : array_like (nq,), optional
            Initial tuners (default: the estimator's ``q0``, 0 unless given), e.g. the last
            flight's final ``q_hat``.
        """
        nx, nu, ny, nz, nq, nh = self.pm.dims
        if getattr(self, "state", None) is None:   # arrays kept: a Stream holds them
            self.state = np.empty(self.pm.state_size())
            self.t_idx = np.zeros(len(self.pm.t_pidx), dtype=np.int64)
            self.d_idx = np.zeros(len(self.pm.d_pidx), dtype=np.int64)
            self._h_held = np.empty(nh)
        *_, oyl, ost, _ = state_layout(nx, nq, nu, len(self.pm.schedule_channels), ny)
        self.state[:] = np.nan
        self.state[nx:nx + nq] = self.q0 if q0 is None else np.asarray(q0, dtype=np.float64)
        self._h_held[:] = self.db.tuner["h_ref"] + self.db.tuner["V_pinv"] @ self.state[nx:nx + nq]
        self.state[oyl + ny:ost + 2] = 0.0     # the sensor record's counts, not started, no outage
        self.state[oyl + SMALLEST_ROW * ny:oyl + (SMALLEST_ROW + 1) * ny] = np.inf   # no change seen yet
        self.t_idx[:] = 0
        self.d_idx[:] = 0
        self._b_idx[:] = 0
        self.missing = dict.fromkeys(self.input_channels, 0)
        self.misfit = dict.fromkeys(self.db.names["y"], 0)
        self.implausible = dict.fromkeys(self.input_channels, 0)
        self._evidence = {}      # channel or ("misfit", sensor) -> kept values (_checked)
        self.low_rate = {}       # channel held between its samples -> their period, s (_find_held)
        self.air_data = 0        # samples whose scheduling and inlet pressure disagree (_check_air_data)
        self.trim_filled = 0     # samples interpolated from trims the build filled (FLAG_TRIM_FILLED)
        self.far_outside = 0     # samples far outside the trim grid (FLAG_FAR_OUTSIDE)
        self._lag_sums = np.zeros(6)   # the inlet pressure's lag behind the air data (air_data_lag)
        # ln(logged / air-data inlet pressure) below, between and above INLET_BANDS m (inlet_offset)
        self._inlet_hist = np.zeros((3, INLET_BINS.size - 1))
        self.frozen = {}         # input -> [samples frozen while the engine moved, the value] (_check_frozen_inputs)
        self._frozen_spans = []  # their (first, last) times
        self._inlet_frozen_spans = []   # (theta or delta channel, first, last time, value, move) (_check_frozen_inlet)
        self._logged = np.zeros(len(self.db.names["y"]), dtype=bool)   # sensors with a value, not NaN (_split)
        self._fit_rows, self._misfit_in = 0, {}   # samples where the model should fit, misfits there
        self._misfit_runs = np.zeros((2, len(self.db.names["y"])))   # longest misfit run, the run going on
        na = len(self.db.trim_grid.axes)   # samples outside the trim grid; each axis's extremes (_accumulate)
        self._envelope = [0, np.full(na, np.inf), np.full(na, -np.inf)]
        self._day = [0, np.inf, -np.inf]   # samples whose day is beyond the ambient terms' reach; extremes, K

    @property
    def covariance(self) -> np.ndarray | None:
        """Online mode: the error covariance P(k|k) after the last step, (na, na) over the
        augmented state [dx; q] in corrected units (zeros before the first sample); else None."""
        if not self.pm.online:
            return None
        na = int(self.pm.dims[0] + self.pm.dims[4])
        return self.cov.reshape(na, na).copy()

    @property
    def input_channels(self) -> list[str]:
        """Log channels the filter reads: inputs, sensed outputs, schedule, theta, delta."""
        ch = list(self.db.names["u"]) + list(self.db.names["y"]) + list(self.pm.schedule_channels)
        if self.pm.theta_channel:
            ch += [self.pm.theta_channel, self.pm.delta_channel]
        return list(dict.fromkeys(ch))

    # ---- core --------------------------------------------------------------------------------
    def run_arrays(self, U, Y, S, TH=None, DE=None, time=None, out=None) -> Result:
        """Run the filter on arrays of raw log channels, continuing from the current state.

        Parameters
        ----------
        U : array_like (n, nu)
            Inputs, ``db.names["u"]`` order, database units (uncorrected).
        Y : array_like (n, ny)
            Sensed outputs, ``db.names["y"]`` order, database units; NaN: missing (no update
            from it that step).
        S : array_like (n, ns)
            Schedule channels, ``[c for c, _, _ in db.schedule]`` order (raw log channels; the
            scheduling variables are computed from them as :meth:`GainDatabase.operating_point`).
        TH, DE : array_like (n,), optional
            theta = T_in / T_std and delta = P_in / P_std (dimensionless) for the parameter
            correction; default 1.
        time : array_like (n,), optional
            Sample times (s); default ``arange(n) * db.dt``.
        out : dict, optional
            Buffers to reuse, as returned in an earlier result's ``outputs`` plus ``"flags"``
            (same n); saves the allocation (and page faults) of long runs.

        Returns
        -------
        Result
            Every output of :attr:`names` (n, k) in physical units, flags (n,), time (n,) s;
            without provenance or snapshots (:meth:`run` adds them).
        """
        U, Y, S = (np.ascontiguousarray(np.atleast_2d(a), dtype=np.float64) for a in (U, Y, S))
        n = U.shape[0]
        one = np.ones(n)
        TH = one if TH is None else np.ascontiguousarray(TH, dtype=np.float64)
        DE = one if DE is None else np.ascontiguousarray(DE, dtype=np.float64)
        nx, nu, ny, nz, nq, nh = self.pm.dims
        if out is None or any(o not in out or out[o].shape != (n, len(self.names[o])) for o in self.names):
            out = {o: np.empty((n, len(self.names[o]))) for o in self.names}
            out["flags"] = np.empty(n, dtype=np.int64)
        flags = out.pop("flags") if "flags" in out else np.empty(n, dtype=np.int64)
        chan_count = np.zeros((2, self._limits.shape[1]), dtype=np.int64)
        if screen(U, Y, S, TH, DE, self._limits, chan_count, flags):
            U, Y, S, TH, DE = (a.copy() for a in (U, Y, S, TH, DE))   # the caller's stay as they are
            blank_implausible(U, Y, S, TH, DE, self._limits)
        db = self.db
        filter_loop(Inputs(U, Y, S, TH, DE), *self._records(), self._outputs(out, flags))
        report(out["q_hat"], self._VT, db.tuner["h_ref"], *self._h_range, out["h_hat"], flags, self._h_held)
        self._count_channels(chan_count)
        t = np.arange(n, dtype=np.float64) * db.dt if time is None else np.asarray(time, dtype=np.float64)
        return Result(t, out, flags, self.names)

    def _bias_record(self) -> Bias:
        """The kernel's :class:`pwl.runtime.Bias` record of the bias tables (their learn flags as
        they are now)."""
        bg = self._b_grid
        learn = np.array([t.enabled for t in self.bias.values()], dtype=np.bool_)
        return Bias(self._b_chan, self._b_vals, self._b_counts, bg.bp, bg.off, bg.strides, self._b_pidx,
                    self._b_idx, self._b_share, self._b_law, self._b_ratio, learn)

    def _records(self) -> tuple:
        """The kernel's records after its inputs: Model, Grids, Filter (updated in place), Bias."""
        return self._model, self._grids, Filter(self.state, self.t_idx, self.d_idx, self.cov), self._bias_record()

    @staticmethod
    def _outputs(out: dict, flags: np.ndarray) -> Outputs:
        """The kernel's :class:`pwl.runtime.Outputs` record of output buffers ``out`` (name ->
        (n, k); bias_hat and h_std may be absent) and ``flags`` (n,)."""
        n = flags.shape[0]
        return Outputs(out["x_hat"], out["q_hat"], out["y_hat"], out["residual"], out["z_hat"],
                       out.get("bias_hat", np.empty((n, 0))), out.get("h_std", np.empty((n, 0))), flags)

    # ---- what reaches the kernel: plausible values only ----------------------------------------
    def _columns(self) -> list[list[str]]:
        """The log channel of every column of the kernel's U, Y, S, TH, DE."""
        pm = self.pm
        th = [pm.theta_channel, pm.delta_channel] if pm.theta_channel else [None, None]
        return [list(self.db.names["u"]), list(self.db.names["y"]), list(pm.schedule_channels),
                [th[0]], [th[1]]]

    def _column_limits(self) -> np.ndarray:
        """(2, columns) plausible [lo, hi] of every column of the kernel's U, Y, S, TH, DE from
        the channels' ranges, in the kernel's units (theta, delta: divided by T_std, P_std, and
        always > 0); finite (no range: +-the largest float), so NaN and +-Inf fail every range."""
        corr = self.db.correction
        std = [1.0, 1.0, 1.0, corr.T_std if corr else 1.0, corr.P_std if corr else 1.0]
        lim = []
        for k, (cols, s) in enumerate(zip(self._columns(), std)):
            for c in cols:
                lo, hi = self.ranges.get(c, (-np.inf, np.inf))
                lim.append((max(lo / s, 5e-324) if k >= 3 else lo, hi / s))
        big = np.finfo(np.float64).max
        return np.ascontiguousarray(np.clip(np.array(lim, dtype=np.float64).T, -big, big))

    def _limits_of(self, *blocks: int) -> np.ndarray:
        """(2, k) the :attr:`_limits` columns of the kernel's arrays ``blocks`` (0 U, 1 Y, 2 S,
        3 TH, 4 DE; the order of :meth:`_columns`), in that order."""
        start = np.cumsum([0] + [len(c) for c in self._columns()])
        return self._limits[:, np.concatenate([np.arange(start[b], start[b + 1]) for b in blocks])]

    def _sensor_sd(self) -> np.ndarray:
        """(ny,) every sensor's noise standard deviation relative to its value (the database's R
        over its trims, medians over the grid; inf where that is not a positive number)."""
        db = self.db
        ny = db.n("y")
        R = db.kalman["R"].reshape(-1, ny, ny)
        sd = np.sqrt(np.median(R[:, np.arange(ny), np.arange(ny)], axis=0))
        level = np.median(np.abs(db.trim["y"].reshape(-1, ny)), axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = sd / level
        return np.where(np.isfinite(g) & (g > 0), g, np.inf)

    def _count_channels(self, chan_count) -> None:
        """Add a run's per-column missing and implausible counts to the per-channel totals (a
        channel read twice, e.g. a sensor that is also a schedule channel, counts once)."""
        seen = set()
        j = 0
        for cols in self._columns():
            for c in cols:
                if c is not None and c not in seen:
                    seen.add(c)
                    self.missing[c] = self.missing.get(c, 0) + int(chan_count[0, j])
                    self.implausible[c] = self.implausible.get(c, 0) + int(chan_count[1, j])
                j += 1

    def absent_sensors(self, log: Log) -> list[str]:
        """The sensed outputs (``db.names["y"]``) that a log lacks altogether, the turbofan's P15
        or T48 for instance: they run as dead sensors, missing on every sample (the update uses
        the others, as for a sensor that died). An input, a scheduling channel (even one that
        is also a sensor, such as the turbofan's Nf: the filter cannot start without it) or
        theta/delta cannot be done without: :meth:`run` raises a :class:`LogError` naming it."""
        have = set(log.channels or log.units)        # a header (read_header) has units only
        needed = set(self.pm.schedule_channels)      # the filter cannot start without them
        return [c for c in self.db.names["y"] if c not in have and c not in needed]

    def inlet_from_air_data(self, log: Log) -> bool:
        """Whether ``log`` lacks the inlet total pressure (the delta channel; flight data recorders
        and engine-monitoring reports seldom carry it) and the run takes it from pressure altitude
        and Mach instead, with the inlet's pressure recovery of the database's build
        (:meth:`pwl.database.Ambient.inlet_pressure`; databases with the ambient terms). On the
        demo flights the estimates equal the logged P2's within 0.01 pt of health (full ram
        recovery, 1.0 instead of the plant's 0.995, read 2 pt)."""
        delta = self.pm.delta_channel
        return bool(delta and (delta not in (log.channels or log.units) or self._inlet_replaced)
                    and self.db.derives_inlet())

    def dead_sensors(self, log: Log) -> list[str]:
        """The sensed outputs that a log has but that were NaN on every sample run since the last
        :meth:`reset` (a sensor dead for the whole log, a column never recorded): they run as
        absent ones do (:meth:`absent_sensors`; scheduling channels left out, as there). Known
        once the log has run (:meth:`_split` notes the sensors with a value)."""
        gone = set(self.absent_sensors(log)) | set(self.pm.schedule_channels)
        return [c for c, seen in zip(self.db.names["y"], self._logged) if not seen and c not in gone]

    def _warn_absent(self, log: Log, dead: bool = False) -> None:
        """Warn of the sensors run without: the log's absent ones (:meth:`absent_sensors`), or
        with ``dead``, after the run, those it has NaN on every sample (:meth:`dead_sensors`)."""
        if not dead and self.inlet_from_air_data(log):
            warnings.warn(f"{log.path}: no {self.pm.delta_channel!r} channel: the inlet pressure is taken from pressure "
                          "altitude and Mach (standard atmosphere, ram rise) with the inlet's pressure recovery of "
                          f"the database's build ({self.db.ambient.recovery:.4f})", PwlWarning, stacklevel=3)
        absent = self.dead_sensors(log) if dead else self.absent_sensors(log)
        if not absent:
            return
        names, one = ", ".join(map(repr, absent)), len(absent) == 1
        if dead:
            what = f"{'sensor' if one else 'sensors'} {names} NaN on all {len(log)} samples (dead for the whole log?)"
        else:
            text = [log.attrs["left_out"][c] for c in absent if c in log.attrs.get("left_out", {})]
            text += [f"{t!r} differs in case only: rename the column, or map it with a channel map"
                     for c in absent if (t := case_twin(log.channels or log.units, c))]
            what = f"no {names} channel{''.join(f' ({t})' for t in text)}"
        warnings.warn(f"{log.path}: {what}: run without {'that sensor' if one else 'those sensors'} (missing on "
                      "every sample" + ("" if dead else "; a channel map renames a channel logged under another name")
                      + ")", PwlWarning, stacklevel=3)

    #: values of each channel kept per run chunk for the warnings' typical values
    EVIDENCE = 2000

    def _checked(self, res: Result, path, arrays) -> None:
        """After a run of the kernel on ``arrays`` (:meth:`_split`): the envelope policy
        (:meth:`_check_envelope`), the misfit samples per sensor counted, and some of every
        channel's implausible values and every sensor's misfitting ones with their predictions
        kept (:attr:`EVIDENCE` per chunk) for the warnings."""
        self._check_envelope(res.flags, res.time, path)
        self.trim_filled += int(np.count_nonzero(res.flags & FLAG_TRIM_FILLED))
        self._check_air_data(res.flags, arrays)
        self.far_outside += int(np.count_nonzero(res.flags & FLAG_FAR_OUTSIDE))
        self._check_frozen_inputs(res.flags, res.time, arrays[0], arrays[2])
        self._check_frozen_inlet(res.flags, res.time, arrays)
        corr = self.db.correction
        std = [1.0, 1.0, 1.0, corr.T_std if corr else 1.0, corr.P_std if corr else 1.0]
        for cols, a, sc in zip(self._columns(), arrays, std):
            for j, c in enumerate(cols):
                if c is None or a is None or not self.implausible.get(c):   # screen() counted none
                    continue
                lo, hi = self.ranges.get(c, (-np.inf, np.inf))
                with np.errstate(over="ignore", invalid="ignore"):  # spikes (_SPIKE) overflow: inf
                    v = (a[:, j] if a.ndim == 2 else a) * sc
                    v = v[(v < lo) | (v > hi)]
                v[np.abs(v) >= _SPIKE] = np.inf                     # a spike or an infinite value
                if v.size:
                    self._evidence.setdefault(c, []).append(v[: self.EVIDENCE])
        y, y_hat = arrays[1], res.outputs["y_hat"]
        with np.errstate(invalid="ignore"):
            hit = np.abs(res.outputs["residual"]) > self._model.gate[0] * np.abs(y_hat)
        # where the model should fit: started, updated (open loop, every sensor drifts off), inside
        # the grid, no implausible channel, no sensor already left out as stuck (a frozen sensor
        # misfits once its prediction moves)
        fit = (res.flags & (FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE | FLAG_NOT_STARTED | FLAG_IMPLAUSIBLE | FLAG_STUCK
                            | FLAG_NO_UPDATE | FLAG_AIR_DATA | FLAG_HELD_INPUT | FLAG_TRIM_FILLED)) == 0
        self._fit_rows += int(fit.sum())
        _longest_runs(hit, self._misfit_runs)
        for i, (c, k) in enumerate(zip(self.db.names["y"], hit.sum(axis=0))):
            self.misfit[c] += int(k)
            self._misfit_in[c] = self._misfit_in.get(c, 0) + int(np.count_nonzero(hit[fit, i]))
            if k:
                rows = np.flatnonzero(hit[:, i])[: self.EVIDENCE]
                self._evidence.setdefault(("misfit", c), []).append(np.column_stack([y[rows, i], y_hat[rows, i]]))

    def _check_air_data(self, flags, arrays) -> None:
        """Flag FLAG_AIR_DATA on the started samples, no input held, whose pressure altitude, Mach
        and inlet total pressure disagree (:func:`pwl.airdata.disagree`); count them and keep
        some (altitude m, Mach, P2 Pa) for the warning; add the agreeing samples to the fit of
        the inlet pressure's lag (:attr:`air_data_lag`)."""
        if self._air is None:
            return
        ja, jm, ka, kp = self._air
        _, _, S, _, DE = arrays
        # spikes (_SPIKE) and infinite values overflow here: flagged implausible, named by their channel
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            p2 = DE * (self.db.correction.P_std * kp)
            off = disagree(S[:, ja] * ka, S[:, jm], p2) & ((flags & (FLAG_NOT_STARTED | FLAG_HELD_INPUT)) == 0)
            if off.any():
                flags[off] |= FLAG_AIR_DATA
                self.air_data += int(off.sum())
                rows = np.flatnonzero(off)[: self.EVIDENCE]
                alt = S[rows, ja] * ka
                self._evidence.setdefault("air_data", []).append(np.column_stack(
                    [np.log(p2[rows] / inlet_pressure(alt, S[rows, jm])), alt, S[rows, jm], p2[rows]]))
            use = (flags & (FLAG_NOT_STARTED | FLAG_HELD_INPUT | FLAG_AIR_DATA)) == 0
            self._lag_sums += lag_sums(S[:, ja] * ka, S[:, jm], p2, self.db.dt, use)
            if self.db.derives_inlet() and not self._inlet_replaced:
                alt = S[use, ja] * ka
                ratio = np.log(p2[use] / self.db.ambient.inlet_pressure(alt, S[use, jm]))
                ok = np.isfinite(ratio) & (ratio >= INLET_BINS[0]) & (ratio < INLET_BINS[-1])
                nb = INLET_BINS.size - 1
                k = np.searchsorted(INLET_BANDS, alt[ok]) * nb + ((ratio[ok] - INLET_BINS[0]) / (
                    INLET_BINS[1] - INLET_BINS[0])).astype(np.int64).clip(0, nb - 1)
                self._inlet_hist += np.bincount(k, minlength=3 * nb).reshape(3, nb)

    @property
    def air_data_lag(self) -> tuple[float, float]:
        """(lag s, standard error s) of the inlet pressure (theta/delta's delta channel) behind
        pressure altitude and Mach over the samples run since the last reset, fitted on how the
        pressure they give changes (:func:`pwl.airdata.lag`): a channel logged late, by a bus's
        or a logger's latency; positive: the inlet pressure late or the air data early. (nan,
        nan) without the three channels or a change of pressure."""
        return lag(self._lag_sums)

    @property
    def inlet_offset(self) -> float:
        """The median relative offset of the logged inlet pressure (delta channel) from the one
        pressure altitude, Mach and the plant's recovery give (:meth:`GainDatabase.inlet_from_air_data`),
        over the samples run since the last reset where the air data agree (to the 0.1 %
        bins of :data:`INLET_BINS`); NaN without them (no air data, a database without the recovery,
        the inlet pressure taken from the air data). :meth:`_inlet_offsets` has it by altitude."""
        return _hist_median(self._inlet_hist.sum(axis=0))

    def _inlet_offsets(self) -> tuple[float, float]:
        """:attr:`inlet_offset` below and above :data:`INLET_BANDS` (NaN with fewer than
        :attr:`INLET_SAMPLES` samples there)."""
        return tuple(_hist_median(h) if h.sum() >= self.INLET_SAMPLES else float("nan") for h in self._inlet_hist[[0, 2]])

    def _check_frozen_inputs(self, flags, t, U, S) -> None:
        """Flag FLAG_HELD_INPUT on the runs where an input repeats one value exactly for the stuck
        detector's time or longer (:attr:`_hold_n`: never for the inputs of ``may_hold``) while a
        scheduling channel moves more than SPIKE_FRACTION of its plausible span (U (n, nu), S (n,
        ns) as from :meth:`_split`, t (n,) s): a frozen word or a meter at the end of its range,
        whose value is not the engine's. Fuel flow clipped at 2.0 kg/s
        through the degraded demo flight's take-off read T40 up to 7.6 % low, frozen for a minute
        of its descent 4.9 % RMS (two sensors blamed and dropped), both trusted; the clean demo and
        seed-7 flights repeat their fuel flow only where altitude and Mach hold still (Nf moves
        1.5 % of its span with its noise)."""
        lim = self._limits_of(2)
        with np.errstate(over="ignore", invalid="ignore"):
            span = SPIKE_FRACTION * (lim[1] - lim[0])
            S = np.where((S >= lim[0]) & (S <= lim[1]), S, np.nan)      # held (spikes, implausible): no move
        for j, (c, n) in enumerate(zip(self.db.names["u"], self._hold_n)):
            x = U[:, j]
            for a, b in repeat_runs(x, n):
                with np.errstate(invalid="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)     # a column held all along
                    moved = np.nanmax(S[a:b], axis=0) - np.nanmin(S[a:b], axis=0) > span
                if moved.any():
                    flags[a:b] |= FLAG_HELD_INPUT
                    got = self.frozen.setdefault(c, [0, 0.0])
                    got[0] += int(b - a)
                    got[1] = float(x[a])
                    self._frozen_spans.append((float(t[a]), float(t[b - 1])))

    #: the least relative change of the inlet temperature or pressure that pressure altitude and
    #: Mach make over a run of exact repeats for it to be a frozen inlet sensor (:meth:`_check_frozen_inlet`):
    #: 1 %, about 3 K or 1 kPa at sea level; a quantised reading holds at a steady cruise or through
    #: a throttle change, where neither moves
    FROZEN_INLET = 0.01

    def _check_frozen_inlet(self, flags, t, arrays) -> None:
        """Flag FLAG_HELD_INPUT on the runs where the inlet temperature or pressure (theta, delta)
        repeats one value exactly for the stuck detector's time or longer while pressure altitude
        and Mach change it by :attr:`FROZEN_INLET` or more (the standard day's inlet temperature,
        full-ram inlet pressure), and keep their spans: the log is run again with the channel
        missing there, carried by the day as a dead one is (:meth:`_second_opinions`). T2 frozen
        from the cruise on read fan efficiency -13 % and HPC flow -32 % in the descent, named
        nowhere; T2 written 288.15 K all flight (a converter's fill value) fan efficiency +10 %."""
        if self._air is None or self.pm.theta_channel is None:
            return
        ja, jm, ka, _ = self._air
        _, _, S, TH, DE = arrays
        alt, mach = S[:, ja] * ka, S[:, jm]
        with np.errstate(invalid="ignore", over="ignore"):
            expect = {0: np.log(inlet_temperature(alt, mach, 0.0)), 1: np.log(inlet_pressure(alt, mach))}
        for k, (c, x) in enumerate(((self.pm.theta_channel, TH), (self.pm.delta_channel, DE))):
            for a, b in repeat_runs(x, self._model.stuck_n):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)     # altitude or Mach missing throughout
                    moved = np.nanmax(expect[k][a:b]) - np.nanmin(expect[k][a:b])
                if moved >= self.FROZEN_INLET:
                    flags[a:b] |= FLAG_HELD_INPUT
                    value = float(x[a] * (self.db.correction.T_std if k == 0 else self.db.correction.P_std))
                    self._inlet_frozen_spans.append((c, float(t[a]), float(t[b - 1]), value, float(np.expm1(moved))))

    def _typical(self, key):
        """Median of the values kept for ``key`` (:meth:`_checked`), per column."""
        with np.errstate(over="ignore", invalid="ignore"):      # infinite values: inf (or nan)
            return np.median(np.concatenate(self._evidence[key]), axis=0)

    def _warn_channels(self, path, n: int) -> None:
        """Warn of every channel implausible on at least a tenth of a log's ``n`` samples, with
        the typical implausible value (the median of those kept) and the units in which that
        value would be plausible: most often a unit the log does not declare (a temperature in
        degC, an altitude in ft, a speed in percent); and of every sensor that misfit on at
        least a tenth, with its typical logged value and prediction where it misfit and the
        units that would make them agree: a unit mistake inside the plausible range (a T48 in
        degC read as K) or a failed sensor, left out of the update."""
        for c, k in self.implausible.items():
            if k < max(n, 1) / 10 or c not in self._evidence:
                continue
            med = float(self._typical(c))
            lo, hi = self.ranges.get(c, (-np.inf, np.inf))
            unit = self.channel_units.get(c, "")
            warnings.warn(f"{path}: channel {c!r}: {k} of {n} samples implausible, typically {med:.6g} "
                          f"where {lo:.6g} to {hi:.6g} {unit} is plausible: {implausible_hint(med, unit, lo, hi)}",
                          PwlWarning, stacklevel=4)
        k, low, high = self._envelope
        if k >= max(n, 1) / 100:
            axes = self.db.trim_grid.axes
            far = ", ".join(f"{a.name} {lo:g} .. {hi:g} (grid {a.values[0]:g} .. {a.values[-1]:g})"
                            for a, lo, hi in zip(axes, low, high) if lo < a.values[0] or hi > a.values[-1])
            how = "extrapolated from" if self.db.policy == "extrapolate" else "clipped to"
            beyond = (f"; {self.far_outside} samples run farther out than {FAR_OUTSIDE:.0%} of an axis's span "
                      "(where a channel was missing: at its last value) made no measurement update and are not "
                      "trusted" if self.far_outside else "")
            warnings.warn(f"{path}: {k} of {n} samples outside the database's grid, {far}: the model there "
                          f"is {how} the grid's edge (the farther out, the less its estimates hold{beyond}); a "
                          "database built over the log's envelope fixes it", PwlWarning, stacklevel=4)
        k, cold, hot = self._day
        if k >= max(n, 1) / 100:
            reach = AMBIENT_REACH * self.db.ambient.span
            worst = cold if -cold > hot else hot
            theta = self.db.correction.theta_channel
            warnings.warn(f"{path}: {k} of {n} samples on a day {worst:+.0f} K off the standard atmosphere (from "
                          f"{theta!r}, altitude and Mach), beyond the +-{reach:g} K the database's hot- and "
                          f"cold-day trims reach: held at {np.copysign(reach, worst):+g} K there. A {theta} "
                          f"reading {'high' if worst > 0 else 'low'} (its unit?), or a day that "
                          f"{'hot' if worst > 0 else 'cold'}?", PwlWarning, stacklevel=4)
        if self.trim_filled:
            st = self.db.trim_status
            nodes = "; ".join(", ".join(f"{a.name} {a.values[i]:g}" for a, i in zip(self.db.trim_grid.axes, idx))
                              for idx in np.argwhere(st != 0)[:4]) + ("; ..." if np.count_nonzero(st) > 4 else "")
            warnings.warn(f"{path}: {self.trim_filled} of {n} samples interpolated from trims the build did not "
                          f"compute ({np.count_nonzero(st)} of {st.size} nodes filled or extrapolated from their line: "
                          f"{nodes}): not the plant's, so not trusted; a build whose trims converge there fixes it "
                          "(`pwl info` counts them)", PwlWarning, stacklevel=4)
        for c, (k, v) in self.frozen.items():
            warnings.warn(f"{path}: input {c!r} held {v:.6g} {self.channel_units.get(c, '')} exactly on {k} of {n} "
                          f"samples ({k * self.db.dt:.3g} s) while the operating point moved: a frozen word, or a meter "
                          "at the end of its range? Those samples are not trusted. An input that may hold a value "
                          f"(variable geometry at a stop, a closed valve): Estimator(may_hold=({c!r},)), pwl run "
                          f"--may-hold {c}", PwlWarning, stacklevel=4)
        if self.air_data >= max(n, 1) / 100:
            kept = np.concatenate(self._evidence["air_data"])
            _, alt, mach, p2 = kept[np.argsort(kept[:, 0])[kept.shape[0] // 2]]      # the median disagreement
            sa, sm = (self.pm.schedule_channels[j] for j in self._air[:2])
            slip, unit = altitude_slip(kept[:, 1], kept[:, 2], kept[:, 3])
            fix = f"declare its unit: '{sa}[{unit}]' in the header or a units row" if unit else "scale it in a channel map"
            why = (f"{slip} ({fix})" if slip else
                   "a wrong, frozen or missing altitude or Mach (logged as 0?), or a wrong inlet pressure?")
            warnings.warn(f"{path}: {sa!r}, {sm!r} and {self.pm.delta_channel!r} disagree on {self.air_data} of {n} "
                          f"samples: typically {p2 / 1e3:.4g} kPa inlet pressure where pressure altitude {alt:.5g} m "
                          f"and Mach {mach:.3g} give {inlet_pressure(alt, mach) / 1e3:.4g} kPa (standard "
                          f"atmosphere): {why} Those samples are not trusted", PwlWarning, stacklevel=4)
        tau, se = self.air_data_lag       # meaningless where the air data disagree (warned above)
        if abs(tau) >= LAG_WARN and abs(tau) >= LAG_SIGMAS * se and self.air_data < max(n, 1) / 100:
            sa, sm = (self.pm.schedule_channels[j] for j in self._air[:2])
            warnings.warn(f"{path}: {self.pm.delta_channel!r} runs {abs(tau):.2g} s {'behind' if tau > 0 else 'ahead of'} "
                          f"{sa!r} and {sm!r} (fitted on how the pressure they give changes, +-{se:.1g} s): a channel "
                          "logged late (a bus's or a logger's latency)? The transients read wrong; shift the late "
                          "channel with the channel map's lag (seconds late)", PwlWarning, stacklevel=4)
        for c, k in self.misfit.items():
            if k >= max(n, 1) / 10 and ("misfit", c) in self._evidence:
                warnings.warn(f"{path}: sensor {c!r} misfit on {k} of {n} samples ({self._misfit_text(c)}) and was "
                              "left out of the update there", PwlWarning, stacklevel=4)

    def _misfit_text(self, c: str) -> str:
        """Sensor c's typical logged value and prediction where it misfit, and the units that would
        make them agree (a unit mistake inside the plausible range: a T48 in degC read as K); or,
        when it logged one value on every sample kept while the prediction moved, that value."""
        have, want = (float(v) for v in self._typical(("misfit", c)))
        unit = self.channel_units.get(c, "")
        kept = np.concatenate(self._evidence[("misfit", c)])
        if kept.shape[0] > 1 and np.all(kept[:, 0] == kept[0, 0]) and np.ptp(kept[:, 1]) > 0.0:
            # one value where the model moved: no unit makes that fit (T48 stuck at 950 K read
            # "logged in degC?", its prediction 1228 K on the cruise)
            return (f"one value, {kept[0, 0]:.6g} {unit}, on every sample kept where it misfit, while its "
                    f"prediction moved {kept[:, 1].min():.6g} to {kept[:, 1].max():.6g}: a stuck sensor or a frozen "
                    "bus word?")
        tol = self._model.gate[0, self.db.names["y"].index(c)] * abs(want)
        guess = likely_units(have, unit, want - tol, want + tol)
        why = (f"logged in {' or '.join(guess)}? Declare the unit (a 'name[unit]' column, a row of units or "
               "a channel map)") if guess else "a failed or biased sensor, or a unit mistake?"
        return f"typically {have:.6g} {unit} against {want:.6g} predicted: {why}"

    def _split(self, log: Log, rows=slice(None), held=None):
        """The kernel's input arrays from a log's ``rows`` (a slice; checks presence and units of
        every channel; :meth:`absent_sensors` and the sensors failed for the log NaN; spikes of the inputs, scheduling channels and
        theta/delta set outside their plausible range, judged with the samples around the rows:
        :func:`spikes`; held channels, ``held`` as from :meth:`_find_held` (None: found on
        ``log``), their empty rows filled (:func:`_fill_low_rate`), then every row interpolated
        between their samples (:func:`interpolate_held`), sensors, inputs and scheduling
        channels alike)."""
        db, pm = self.db, self.pm
        units = self.channel_units
        absent = self.absent_sensors(log)
        a, b, _ = rows.indices(len(log))
        reach = self._reach
        wide = slice(max(0, a - reach), min(len(log), b + reach))
        def take(names, r=wide):
            return log.require(names, [units.get(n, "") for n in names], absent, r)
        U, S, Y = take(db.names["u"]), take(pm.schedule_channels), take(db.names["y"])
        if not pm.theta_channel:
            TD = np.ones((U.shape[0], 2))
        elif self.inlet_from_air_data(log):
            TD = np.column_stack([take([pm.theta_channel])[:, 0], db.inlet_from_air_data(S)])
            TD /= [db.correction.T_std, db.correction.P_std]
            if self._inlet_replaced:      # the logged one, biased, for the snapshots (the fleet diagnosis names it)
                self._logged_delta = take([pm.delta_channel])[a - wide.start: b - wide.start, 0]
        else:
            TD = take([pm.theta_channel, pm.delta_channel]) / [db.correction.T_std, db.correction.P_std]
        cols = np.hstack([U, S, TD])
        held = self._find_held(log) if held is None else held
        self.low_rate.update({c: max(self.low_rate.get(c, 0.0), h[2]) for c, h in held.items()})
        held_cols = self._held_in(held, [*db.names["u"], *pm.schedule_channels, pm.theta_channel, pm.delta_channel])
        held_y = self._held_in(held, db.names["y"])
        for a_, h in ((cols, held_cols), (Y, held_y)):
            for j, (_, med) in h.items():
                if med:                               # empty rows between samples: held first
                    _fill_low_rate(a_, j, med)
        lim = self._limits_of(0, 2, 3, 4)             # U, S, TH, DE
        with np.errstate(over="ignore"):
            span = lim[1] - lim[0]                    # inf for a channel without a range
        # a frozen word after a jump: a measured channel's failure; an input may be a demand held exactly
        cols[spikes(cols, span, frozen=np.arange(cols.shape[1]) >= U.shape[1])] = _SPIKE
        cols[np.isinf(cols)] = _SPIKE          # implausible, as screen() counts and names them (not missing)
        Y[np.isinf(Y)] = _SPIKE
        interpolate_held(cols, {j: p for j, (p, _) in held_cols.items()})
        interpolate_held(Y, {j: p for j, (p, _) in held_y.items()},
                         {j: HELD_BEND * self._sd[j] for j in held_y})
        cols = cols[a - wide.start: b - wide.start]
        U, S = np.ascontiguousarray(cols[:, :U.shape[1]]), np.ascontiguousarray(cols[:, U.shape[1]:-2])
        TH, DE = (np.ascontiguousarray(cols[:, -2]), np.ascontiguousarray(cols[:, -1])) \
            if pm.theta_channel else (None, None)
        Y = Y[a - wide.start: b - wide.start]
        self._logged |= ~np.isnan(Y).all(axis=0)
        Y[:, [db.names["y"].index(c) for c in self.failed]] = np.nan      # failed for this log
        t = log.time[a:b]
        for t0, t1 in self._blind:        # an input frozen there: no measurement update
            Y[(t >= t0) & (t <= t1)] = np.nan
        for c, t0, t1 in self._inlet_dead:     # an inlet sensor frozen there: missing (carried by the day)
            (TH if c == pm.theta_channel else DE)[(t >= t0) & (t <= t1)] = np.nan
        return U, Y, S, TH, DE

    @property
    def _reach(self) -> int:
        """Rows either side of a chunk that :meth:`_split` reads: the spike test's
        (:data:`SPIKE_REACH`) and a held channel's, whose rows take values from the samples up to
        two of its longest periods away (:func:`interpolate_held`, :func:`_fill_low_rate`)."""
        return max(SPIKE_REACH, int(np.ceil(4 * LOW_RATE_GAP / self.db.dt)) + 2)

    def _find_held(self, log: Log) -> dict[str, tuple[float, int, float]]:
        """The channels the filter reads that ``log`` holds between their samples, judged on its
        first :data:`HELD_ROWS` rows (:func:`held_channels`): logged at a lower rate (empty rows
        between samples) or written with sample-and-hold (each sample repeated until the next);
        channel -> (period in rows, median step between samples logged with empty rows between
        them else 0, period in s)."""
        dt = sample_interval(log.time)
        if not np.isfinite(dt) or dt <= 0:
            return {}
        pm = self.pm
        names = [c for c in dict.fromkeys([*self.db.names["u"], *pm.schedule_channels, *self.db.names["y"],
                                           pm.theta_channel, pm.delta_channel]) if c in log.channels]
        if not names:
            return {}
        n = min(len(log), HELD_ROWS)
        # a period is at most LOW_RATE_GAP: 66 or 67 rows at 1 Hz on a 66.7 Hz grid
        found = held_channels([np.asarray(log.channels[c][:n], dtype=np.float64) for c in names],
                              np.ceil(LOW_RATE_GAP / dt - 1e-6))
        return {names[j]: (p, med, float(f"{p * dt:.4g}")) for j, (p, med) in found.items()}

    @staticmethod
    def _held_in(held: dict, names) -> dict[int, tuple[float, int]]:
        """Column -> (period in rows, median step if logged with empty rows) of the channels ``names`` (in
        column order; None for none) that ``held`` (:meth:`_find_held`) names."""
        return {j: held[c][:2] for j, c in enumerate(names) if c is not None and c in held}

    def run(self, log, reset: bool = True) -> Result:
        """Estimates for a whole log.

        Parameters
        ----------
        log : Log or str or path-like
            A :class:`pwl.logs.Log`, or a log file read with :func:`pwl.logs.read_log` through
            this estimator's channel map. Sampled at the database's dt (else refused unless
            ``resample``); channel units are converted to the database's.
        reset : bool
            Reset the filter first (default; one log = one flight), else continue from the
            current state.

        Returns
        -------
        Result
            Outputs (n, k), flags (n,), time (n,) s, ``attrs["provenance"]`` (:attr:`provenance`
            and the log's identity) and the steady-state ``snapshots``.

        Raises
        ------
        LogError
            An unreadable log, a channel it lacks, a unit that does not convert, another sample
            interval.
        EnvelopeError
            The operating point left the grid and the database's policy is ``error``.
        """
        if isinstance(log, Log):
            check_time(log.path, log.time)     # as read_log does for files
        else:
            log = read_log(log, channel_map=self.channel_map)
        self._warn_absent(log)
        self._warn_gaps(log)
        if reset:
            res = self._second_opinions(log.path, lambda: self._run_log(log, True))
        else:
            res = self._run_log(log, False)
        self._warn_absent(log, dead=True)
        self._warn_channels(log.path, len(res.time))
        return res

    def _warn_gaps(self, log: Log) -> None:
        """A warning naming the gaps of a log's time column (:func:`pwl.logs.gap_starts`), if any:
        the filter predicts through them on the database's time grid (:meth:`_run_resampled`)."""
        g = gap_starts(log.time)
        if not g.size:
            return
        t = log.time
        span = float(np.sum(t[g + 1] - t[g]))
        runs = np.split(g, np.flatnonzero(np.diff(g) != 1) + 1)      # gaps one after the other
        run = max(runs, key=len)
        slow = (f"; every step from t = {t[run[0]]:.6g} to {t[run[-1] + 1]:.6g} s is one: logged at a lower rate "
                "there?" if run.size >= 10 else "")
        warnings.warn(f"{log.path}: {g.size} gap(s) in the time column, {span:.4g} s of the log's "
                      f"{t[-1] - t[0]:.4g} s (the first at t = {t[g[0]]:.6g} s, the longest "
                      f"{float(np.max(t[g + 1] - t[g])):.4g} s{slow}); the filter predicts through them, inputs "
                      f"held, and settles again after one longer than its settling time ({self.settle:.3g} s)",
                      PwlWarning, stacklevel=3)

    #: a run again with sensors used after misfitting for the filter's settling time is kept when it
    #: misfits on at most this share of the first run's misfitting samples (P2 frozen for a minute
    #: of the climb: Ps30, P50 and P15 misfit and left out on 47 % of the flight, health 10-20
    #: points off for 6 minutes, then 3 % and 1.5 minutes; P50 and P15 swapped: 70 % then 72 %)
    READMIT_SHARE = 0.5

    def _second_opinions(self, path, once):
        """``once()`` (a run from a reset) and again when it may be wrong; the result kept.

        A sensor left out for misfitting longer than the filter settles may have been locked out
        by a state that something else pushed the filter to (a frozen input): left out, it cannot
        pull the filter back, and with the health held without it nothing else does. The log is
        run again with misfitting sensors used after ``readmit_n`` steps in a row
        (:class:`pwl.runtime.Model`), kept if it misfits far less (:attr:`READMIT_SHARE`); a
        failed sensor misfits as much used or not, and its first run is kept. Then the log runs
        again without the sensors that failed for it (:meth:`_failed_sensors`), if any.

        First of all, an input found frozen (:meth:`_check_frozen_inputs`) pushed the filter with
        a value that is not the engine's: the log runs again with no measurement update there
        (prediction only), so that the tuners keep what they knew before (Wf frozen for a minute of
        the degraded demo flight's descent: Nc and T48 misfit on a fifth of the flight after it,
        were dropped for the log, health held all flight)."""
        self.failed, self._blind, self._inlet_replaced, self._inlet_dead = [], [], False, []
        self._readmit(False)
        out = once()
        if self._inlet_frozen_spans:
            self._inlet_dead = [f[:3] for f in self._inlet_frozen_spans]
            for c in dict.fromkeys(f[0] for f in self._inlet_frozen_spans):
                spans = [f for f in self._inlet_frozen_spans if f[0] == c]
                _, t0, t1, v, moved = max(spans, key=lambda f: f[2] - f[1])
                warnings.warn(f"{path}: {c!r} held {v:.6g} {self.channel_units.get(c, '')} exactly on "
                              f"{sum(f[2] - f[1] for f in spans):.4g} s of the log (the longest from t = {t0:.6g} to "
                              f"{t1:.6g} s) while pressure altitude and Mach moved it by {moved:.0%}: a frozen sensor "
                              "or a fill value? Run again with it missing there (carried by the day, as a dead "
                              "inlet sensor is); those samples are not trusted", PwlWarning, stacklevel=4)
            self.reset()
            out = once()
        if self._inlet_biased(path):
            self._inlet_replaced = True
            self.reset()
            out = once()
        if self._frozen_spans:
            self._blind = list(self._frozen_spans)
            self.reset()
            out = once()
        if self._misfit_runs[0].max() > self._readmit_n:
            first = sum(self._misfit_in.values())
            self._readmit(True)
            self.reset()
            out = once()
            if sum(self._misfit_in.values()) > self.READMIT_SHARE * first:
                self._readmit(False)
                self.reset()
                out = once()
        if self._failed_sensors(path):
            self.reset()
            out = once()
        return out

    def _inlet_biased(self, path) -> bool:
        """Whether the logged inlet pressure is off the air data's by more than
        :data:`INLET_OFFSET` over the log (:attr:`inlet_offset`), warned. By the same share low and
        high (within a tenth of it, or two bins: a probe's or its transducer's scale), it is biased: the log is
        then run with the inlet pressure from the air data, as a log without it is. By a share that
        grows with altitude it is rather the altitude that is off (the demo flight 300 m low: 3.5 %
        below 3000 m, 4.4 % above 6000 m, and the estimates are right with the logged P2), or it cannot be told (a
        flight at one altitude): the warning says so and the log is run as it is."""
        off, n = self.inlet_offset, self._inlet_hist.sum()
        # the air data themselves in doubt (an altitude in feet: most samples disagree), not P2
        if not abs(off) > INLET_OFFSET or n < self.INLET_SAMPLES or self.air_data > 0.1 * (n + self.air_data):
            return False
        low, high = self._inlet_offsets()
        scale = abs(low - high) <= max(0.1 * abs(off), 2 * (INLET_BINS[1] - INLET_BINS[0]))
        delta, (sa, sm) = self.pm.delta_channel, (self.pm.schedule_channels[j] for j in self._air[:2])
        bands = (f"{low:+.1%} below {INLET_BANDS[0]:g} m, {high:+.1%} above {INLET_BANDS[1]:g} m" if np.isfinite(low - high)
                 else "not measured both low and high")
        why = (f"a biased inlet pressure sensor? Read as the engine's, it moves the health estimates (1.5 % low: "
               f"HPT efficiency 1.9 points). Estimated again with {delta!r} from the air data" if scale else
               f"a biased inlet pressure sensor, or an altitude or Mach off (a pressure altitude 300 m low reads "
               f"more off the higher it is)? Estimated with the logged {delta!r}; if it is the one that is "
               f"off, leave it out of the log (the run then takes it from the air data)")
        warnings.warn(f"{path}: {delta!r} reads {abs(off):.1%} {'above' if off > 0 else 'below'} the inlet pressure "
                      f"{sa!r}, {sm!r} and the plant's inlet recovery give (the median over {int(n)} samples; "
                      f"{bands}; within {INLET_OFFSET:.0%} on clean flights): {why}", PwlWarning, stacklevel=4)
        return scale

    #: samples of agreeing air data :meth:`_inlet_biased` needs (10 s at the demo's 15 ms)
    INLET_SAMPLES = 667

    def _readmit(self, on: bool) -> None:
        """Use sensors again after misfitting for the filter's settling time (on), or never."""
        self._model = self._model._replace(readmit_n=self._readmit_n if on else NEVER)

    def _run_log(self, log: Log, reset: bool) -> Result:
        """:meth:`run` once (the sensors of :attr:`failed` left out), without the channel warnings."""
        if reset:
            self.reset()
        if self._check_interval(log):
            res, arrays, run_log = self._run_resampled(log)
            dt = sample_interval(res.time)
        else:
            arrays = self._split(log)
            res = self.run_arrays(*arrays, time=log.time)
            run_log, dt = log, log.dt
        res.source = log.path
        self._checked(res, log.path, arrays)
        res.attrs = {k: v for k, v in log.attrs.items() if k in LOG_ATTRS} | {
            "provenance": self.provenance | self._log_record(run_log)}
        acc = self._snapshot_accumulator(dt)
        self._accumulate(acc, 0, res, arrays)
        res.snapshots = acc.snapshots()
        return res

    #: a sensor that misfits on this share of a log's samples where the model should fit (inside
    #: the grid, started, no implausible channel, no stuck sensor) has failed for that log: it is
    #: run again without it, from its first sample (swapped P50 and P15: 35 %; the demo flights,
    #: engine-off segments, a T48 step of 15 K in flight: 0)
    FAILED_SHARE = 0.1
    #: this many sensors failing a log at once (scheduling sensors that misfit as often counted)
    #: are named as a likely wrong input or database, not as failed sensors
    MANY_FAILED = 3

    def _failed_sensors(self, path) -> list[str]:
        """After a run: the sensors that failed for the log (:attr:`FAILED_SHARE`; not a
        scheduling channel, which the filter cannot run without), added to :attr:`failed` for a
        run again, and a warning naming them with their typical values; [] if none."""
        n = self._fit_rows
        off = [c for c in self.db.names["y"] if c not in self.failed and n >= 100
               and self._misfit_in.get(c, 0) >= self.FAILED_SHARE * n]
        failed = [c for c in off if c not in self.pm.schedule_channels]
        if failed:
            # many at once (a scheduling sensor among them: the operating point itself) are rather
            # the model that does not fit: fuel flow logged 30 % high on the degraded demo flight
            # failed Ps30, T48 and P50, with Nf misfitting on 90 % of the samples
            why = (f" {len(off)} sensors at once ({', '.join(off)}): rather an input that is wrong (a meter "
                   "mis-scaled, a unit mistake) or a database made for another engine?" if len(off) >= self.MANY_FAILED
                   else "")
            warnings.warn(f"{path}: " + "; ".join(
                f"sensor {c!r} misfit on {self._misfit_in[c] / n:.0%} of the samples where the model should fit "
                f"({self._misfit_text(c)})" for c in failed) + ": a failed, swapped or mis-scaled sensor? "
                f"Estimated again without {'it' if len(failed) == 1 else 'them'}." + why, PwlWarning, stacklevel=3)
            self.failed = self.failed + failed
        return failed

    def _run_resampled(self, log: Log):
        """(result, kernel arrays, resampled log) of a log resampled to the database's dt.

        Measurement updates happen only where the log has a sample: the sensed outputs are NaN
        on the rows between two samples of a slower log (prediction steps on interpolated
        inputs), every channel is NaN inside a gap (inputs held). Updating on interpolated
        sensor values would count each sample many times (a 1 Hz log on the 15 ms demo
        database: health error 0.83 pt instead of 0.27 pt). The result and the channel counts
        keep the measured rows only: one row per logged sample (or per dt for a faster log).
        Spikes (:func:`spikes`) are judged on the logged samples and left out of the
        interpolation (missing): interpolated, a 1 Hz dropout would become a 2 s ramp."""
        rs = resample(self._without_spikes(log), self.db.dt)
        U, Y, S, TH, DE = arrays = self._split(rs.log)
        Y[~rs.measured] = np.nan
        for a in (U, S, TH, DE):
            if a is not None:
                a[rs.in_gap] = np.nan
        res = self.run_arrays(*arrays, time=rs.log.time)
        keep, drop = rs.measured, ~rs.measured
        one = np.ones(int(drop.sum()))
        dropped = np.zeros((2, self._limits.shape[1]), dtype=np.int64)
        screen(U[drop], Y[drop], S[drop], one if TH is None else TH[drop], one if DE is None else DE[drop],
               self._limits, dropped, np.empty(one.size, dtype=np.int64))
        self._count_channels(-dropped)     # the rows dropped are not the log's samples
        res = Result(res.time[keep], {o: v[keep] for o, v in res.outputs.items()}, res.flags[keep], res.names)
        if self._logged_delta is not None and self._logged_delta.size == keep.size:
            self._logged_delta = self._logged_delta[keep]
        return res, tuple(None if a is None else a[keep] for a in arrays), rs.log

    #: relative difference between a log's sample interval and the database's dt that is refused
    DT_TOLERANCE = 0.01
    #: a log at the database's dt lacking more than this share of its rows runs on the uniform
    #: grid (the filter predicts through the missing rows, :meth:`_run_resampled`); below, one
    #: filter step per row (a missing row shortens one step of the dynamics)
    MISSING_ROWS = 0.01

    def _without_spikes(self, log: Log) -> Log:
        """The log with the spikes of its inputs, scheduling channels and theta/delta
        (:func:`spikes`) NaN."""
        pm = self.pm
        U, _, S, TH, DE = self._split(log)
        cols = [(self.db.names["u"], U), (pm.schedule_channels, S)]
        if pm.theta_channel:
            cols.append(([pm.theta_channel, pm.delta_channel], np.column_stack([TH, DE])))
        chans = dict(log.channels)
        for names, a in cols:
            for j, c in enumerate(names):
                hit = a[:, j] == _SPIKE
                if hit.any():
                    chans[c] = np.where(hit, np.nan, chans[c])
        return Log(log.time, chans, log.units, log.truth, log.truth_units, log.attrs, log.path)

    def _check_interval(self, log: Log) -> bool:
        """Whether the log runs on the database's uniform time grid (:meth:`_run_resampled`):
        False if it is sampled at the database's dt (median step within :attr:`DT_TOLERANCE`)
        with at most :attr:`MISSING_ROWS` of its rows missing; True with more missing (a recorder
        that drops rows: one filter step per row would run the dynamics up to several times too
        fast), or at another interval when the estimator was made with ``resample=True``; else a
        :class:`LogError`: the discrete matrices and gains hold for one step size only."""
        dt, want = sample_interval(log.time), self.db.dt
        if not np.isfinite(dt):
            return False
        if abs(dt / want - 1.0) <= self.DT_TOLERANCE:    # rows missing or gaps: no rate change, no opt-in
            return rows_missing(log.time, want) > self.MISSING_ROWS * len(log) or time_gaps(log.time)[0] > 0
        # a step that is a time unit's factor times dt (a time column in ms read as s) is refused
        # even with resample, which would make 1000x the samples out of nothing
        for unit, (quantity, seconds, _) in UNITS.items():
            factor = 1.0 / seconds
            if quantity == "time" and seconds != 1.0 and abs(dt / want / factor - 1.0) <= self.DT_TOLERANCE:
                raise LogError(f"{log.path}: sampled every {dt:.6g} s, {factor:g} times the database's "
                               f"{want:.6g} s: is its time column in {unit}? Declare the unit (a "
                               f"'time[{unit}]' header, or the channel map's [time] unit)")
        top = float(np.max(np.abs(log.time)))
        grain = float(np.spacing(np.float32(top)))
        if grain > 0.05 * want and np.array_equal(log.time, log.time.astype(np.float32)):
            raise LogError(f"{log.path}: the time column has a resolution of {grain * 1e3:.4g} ms at "
                           f"t = {top:.8g} s (single-precision numbers?), too coarse for the database's "
                           f"{want * 1e3:.6g} ms step: store it in double precision, or from the start "
                           "of the log")
        if not self.resample:
            raise LogError(f"{log.path}: sampled every {dt * 1e3:.6g} ms, the database "
                           f"{os.path.basename(self.db.path)} is discretized for {want * 1e3:.6g} ms; "
                           f"resample the log (pwl run --resample: the filter steps at the database's dt on "
                           "interpolated inputs and updates on the logged samples)")
        return True

    def _log_record(self, log: Log) -> dict:
        """Provenance of one log: its file and digest, unit conversions, implausible and missing
        samples per channel (JSON strings, as HDF5 attributes)."""
        import json

        from .h5io import file_digest
        rec = {"log": os.path.abspath(log.path) if os.path.exists(log.path) else log.path,
               "log_digest": file_digest(log.path) if os.path.isfile(log.path) else "",
               "units_converted": json.dumps(log.conversions(
                   {c: self.channel_units.get(c, "") for c in self.input_channels})),
               "implausible_channels": json.dumps({c: n for c, n in self.implausible.items() if n}),
               "missing_channels": json.dumps({c: n for c, n in self.missing.items() if n}),
               "misfit_channels": json.dumps({c: n for c, n in self.misfit.items() if n}),
               "absent_channels": json.dumps(self.absent_sensors(log)),
               "from_air_data": json.dumps([self.pm.delta_channel] if self.inlet_from_air_data(log) else []),
               "failed_channels": json.dumps(self.failed),
               "low_rate_channels": json.dumps(self.low_rate),
               "air_data_lag_s": float(self.air_data_lag[0])}
        if "resampled_from" in log.attrs:
            rec["resampled_from_dt"] = float(log.attrs["resampled_from"])
            rec["time_gaps"], rec["longest_gap_s"] = log.attrs["time_gaps"], log.attrs["longest_gap_s"]
            rec["rows_missing"] = log.attrs["rows_missing"]
        else:
            rec["time_gaps"], rec["longest_gap_s"] = time_gaps(log.time)
            rec["rows_missing"] = rows_missing(log.time, self.db.dt)
        return rec

    @property
    def provenance(self) -> dict:
        """What produced a results file (stored as results-file attributes; resume compares them).

        Returns
        -------
        dict
            ``database`` (absolute path, or ``"<memory>"``), ``database_digest`` (sha256 hex),
            ``mode`` (the estimator mode, ``+bias`` with bias tables, ``+map:<digest>`` with a
            channel map, ``+hold:3.5`` etc. for a health hold, misfit gate or stuck time not
            the default, ``+may_hold:A8,B`` for inputs that may hold), ``pwl_version``,
            ``created`` (ISO 8601 UTC, seconds).
        """
        import datetime

        from . import __version__
        mode = {"untuned": "steady+untuned"}.get(self.mode, self.mode)   # as recorded before modes
        if self.bias:
            mode += "+bias"
        mode += "".join(f"+{k}:{v:g}" for k, (v, d) in self._checks.items() if v != d)
        if self.may_hold:
            mode += "+may_hold:" + ",".join(self.may_hold)
        if self.channel_map is not None:   # another map, another reading of the same log
            from .h5io import file_digest
            cm = self.channel_map.path
            mode += f"+map:{file_digest(cm)[:16] if os.path.isfile(cm) else cm}"
        return {"database": os.path.abspath(self.db.path) if self.db.path != "<memory>" else "<memory>",
                "database_digest": self.db.digest, "mode": mode, "pwl_version": __version__,
                "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}

    # ---- steady-state snapshots (for diagnostics) --------------------------------------------
    def _snapshot_accumulator(self, dt) -> SnapshotAccumulator:
        """Snapshots average the raw input channels (inputs, sensed outputs, schedule, theta/delta)."""
        db = self.db
        dt = dt if np.isfinite(dt) and dt > 0 else db.dt
        return SnapshotAccumulator(self.input_channels, db.names["p"], db.p_spans(), dt,
                                   {o: self.names[o] for o in SNAPSHOT_OUTPUTS}, self.steady)

    def _accumulate(self, acc, start, res, arrays):
        """Add one run's samples (``arrays`` as from :meth:`_split`) to a snapshot accumulator."""
        U, Y, S, TH, DE = arrays
        db, pm = self.db, self.pm
        n = U.shape[0]
        th = np.ones(n) if TH is None else TH
        de = np.ones(n) if DE is None else DE
        cols = dict(zip(db.names["u"], U.T)) | dict(zip(db.names["y"], Y.T)) | dict(
            zip(pm.schedule_channels, S.T))
        if pm.theta_channel:
            with np.errstate(over="ignore"):    # a spike (pwl.estimator._SPIKE) overflows: inf
                cols[pm.theta_channel] = th * db.correction.T_std
                cols[pm.delta_channel] = de * db.correction.P_std
            if self._inlet_replaced and self._logged_delta is not None and self._logged_delta.size == n:
                cols[pm.delta_channel] = self._logged_delta     # as logged (biased): _inlet_biased
        raw = np.column_stack([cols[c] for c in acc.channels])
        lo = np.array([self.ranges.get(c, (-np.inf, np.inf))[0] for c in acc.channels])
        hi = np.array([self.ranges.get(c, (-np.inf, np.inf))[1] for c in acc.channels])
        with np.errstate(invalid="ignore"):
            raw = np.where((raw >= lo) & (raw <= hi), raw, np.nan)   # implausible: missing
        with np.errstate(invalid="ignore", over="ignore"):
            p = db.operating_point(S, th, de)
            lim = self._limits_of(2, 3, 4)
            sched = np.column_stack([S, th, de])
            p[~np.all((sched >= lim[0]) & (sched <= lim[1]), axis=1)] = np.nan   # implausible: no point
        axes = db.trim_grid.axes
        pt = p[:, [db.names["p"].index(a.name) for a in axes]]
        lo, hi = np.array([a.values[0] for a in axes]), np.array([a.values[-1] for a in axes])
        env = self._envelope
        with np.errstate(invalid="ignore"):
            env[0] += int(np.count_nonzero(np.any((pt < lo) | (pt > hi), axis=1)))
        if np.isfinite(pt).any():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)      # an all-NaN axis
                env[1], env[2] = np.fmin(env[1], np.nanmin(pt, axis=0)), np.fmax(env[2], np.nanmax(pt, axis=0))
        if db.ambient is not None:
            with np.errstate(invalid="ignore"):
                dT = db.ambient_offset(p, th, hold=False)
                far = np.abs(dT) > AMBIENT_REACH * db.ambient.span
            if far.any():
                self._day = [self._day[0] + int(far.sum()), min(self._day[1], float(np.nanmin(dT[far]))),
                             max(self._day[2], float(np.nanmax(dT[far])))]
        outside = (res.flags & (FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE | FLAG_NOT_STARTED | FLAG_AIR_DATA
                                | FLAG_TRIM_FILLED)) != 0
        outs = {o: res.outputs[o] for o in SNAPSHOT_OUTPUTS}
        # no snapshot value of what was not estimated there: health held, or any estimate while
        # the filter settles (the window's logged channels count: the diagnosis reads those)
        settling = (res.flags & FLAG_SETTLING) != 0
        held = settling | ((res.flags & FLAG_HEALTH_HELD) != 0)
        for o, no in (("h_hat", held), ("q_hat", held), ("z_hat", settling)):
            outs[o] = np.where(no[:, None], np.nan, outs[o]) if no.any() else outs[o]
        acc.add(start, res.time, raw, p, outs, outside)

    def __getstate__(self) -> dict:
        """Pickling and copying leave out the stream :meth:`step` made (compiled records, not
        picklable; a copy makes its own on its first step, from the state it copied)."""
        state = self.__dict__.copy()
        state.pop("_stream", None)
        return state

    def step(self, sample: dict) -> dict:
        """One sample through the filter, continuing from the current state.

        Convenient, not fast: for on-line use at batch speed use a :class:`pwl.streaming.Stream`
        (made here once and shared).

        Parameters
        ----------
        sample : dict
            Log channel name -> value in the database's units, for every channel of
            :attr:`input_channels` (NaN or a missing sensed output: no update from it).

        Returns
        -------
        dict
            Output name (``x_hat``, ``q_hat``, ``h_hat``, ``y_hat``, ``residual``, ``z_hat``, ...)
            -> {column name: value} in physical units, and ``"flags"`` -> the step's flag bits
            (int; :data:`pwl.runtime.FLAG_*`).
        """
        if getattr(self, "_stream", None) is None:
            from .streaming import Stream
            self._stream = Stream(self, reset=False)     # step continues from the current state
        s = self._stream
        flags = s.step(s.row(sample))
        out = {o: dict(zip(self.names[o], s.outputs[o][0])) for o in self.names}
        out["flags"] = flags
        return out

    def _check_envelope(self, flags, time, where):
        if self.db.policy != "error":
            return
        bad = np.flatnonzero(flags & (FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE))
        if bad.size:
            i = int(bad[0])
            raise EnvelopeError(f"{where}: operating point outside the database grid at sample {i} "
                                f"(t = {time[i]:g} s) and the database's out-of-range policy is 'error'")

    def _chunks(self, log_path: str):
        """(log, part): the log (an HDF5 flight log's header, read chunk by chunk; any other
        format or a log through a channel map: read whole) and ``part(a, b)``, the kernel's
        arrays (:meth:`_split`) and time of samples a..b."""
        held = None      # the log's held channels (_find_held), found on its first rows at the first chunk
        if self.channel_map is None and log_path.lower().endswith((".h5", ".hdf5")):
            head = read_header(log_path)
            def part(a, b):     # with the samples around the chunk, for its spikes and held channels (_split)
                nonlocal held
                if held is None:
                    held = self._find_held(read_rows(head, 0, min(len(head), HELD_ROWS)))
                lo = max(0, a - self._reach)
                p = read_rows(head, lo, min(len(head), b + self._reach))
                return self._split(p, slice(a - lo, b - lo), held), head.time[a:b]
        else:
            head = read_log(log_path, channel_map=self.channel_map)
            def part(a, b):
                nonlocal held
                if held is None:
                    held = self._find_held(head)
                return self._split(head, slice(a, b), held), head.time[a:b]
        return head, part

    def run_file(self, log_path, out_path, chunk: int = 1 << 16, outputs=None, every: int = 1,
                 compression: str | None = None) -> dict:
        """Process one log file to one results file, chunk by chunk (bounded memory).

        Resets the filter first. The counts, the residual RMS and the snapshots always come from
        every sample. The results file (``pwl-estimates``) appears only when complete.

        Parameters
        ----------
        log_path : str or path-like
            The log (any format :func:`pwl.logs.read_log` reads). HDF5 flight logs are read
            ``chunk`` samples at a time; other formats (and logs through a channel map) are read
            whole. The filter runs and writes ``chunk`` samples at a time (logs that need
            resampling, and CSV results, whole).
        out_path : str or path-like
            The results file (HDF5; a ``.csv`` path writes CSV).
        chunk : int
            Samples per chunk.
        outputs : sequence of str or str, optional
            The outputs to write (names, or a comma-separated string; None: all of
            :attr:`names`); time and flags are always written.
        every : int
            Write samples 0, N, 2N, ... of the log only.
        compression : {None, "gzip", "lzf"}
            HDF5 filter of the outputs (:data:`pwl.results.COMPRESSIONS`); None: none.

        Returns
        -------
        dict
            The flag counts (:data:`pwl.results.COUNT_KEYS`), ``snapshots`` (how many),
            ``missing_channels`` (channel -> samples) and ``residual_rms`` (sensor -> RMS of its
            residuals, sensor units).

        Raises
        ------
        LogError
            The log cannot be read or lacks a channel.
        UsageError
            An unknown output name, ``every`` < 1, an unknown compression.
        EnvelopeError
            The operating point left the grid and the database's policy is ``error``.
        """
        from .results import Totals, output_units, select_outputs, selection_record

        log_path = os.fspath(log_path)
        keep = select_outputs(self.names, outputs, where=f"{log_path} -> {os.fspath(out_path)}")
        record = selection_record(keep, every)
        units = output_units(self.names, self.db.names, self.db.units)
        self.reset()
        head, part = self._chunks(log_path)
        if compression in (None, "none") and not os.fspath(out_path).lower().endswith(".csv"):
            self._check_space(out_path, -(-len(head) // every) * (2 + sum(len(self.names[o]) for o in keep)) * 8)
        if os.fspath(out_path).lower().endswith(".csv") or self._check_interval(head):
            res = self.run(head if head.channels else log_path)
            res.units = units
            res.save(out_path, keep, every, compression)
            totals = Totals()
            totals.add(res)
            snaps = res.snapshots
        else:
            self._warn_absent(head)
            args = (log_path, out_path, head, part, chunk, keep, every, self.provenance | record, units, compression)
            totals, snaps = self._second_opinions(log_path, lambda: self._write_chunks(*args))
            self._warn_absent(head, dead=True)
            self._warn_channels(log_path, len(head))
        return totals.counts | {"snapshots": len(snaps), "missing_channels": dict(self.missing), "misfit_channels":
                                dict(self.misfit), "failed_channels": list(self.failed),
                                "residual_rms": dict(zip(totals.sensors, totals.residual_rms().tolist()))}

    @staticmethod
    def _check_space(out_path, need: int) -> None:
        """An OSError (ENOSPC) naming the file when its disk has less than ``need`` bytes (and 1 MB)
        free: before the write, since HDF5 failing half-way on a full disk left objects that
        crashed the process at exit."""
        import errno
        import shutil
        folder = os.path.dirname(os.path.abspath(os.fspath(out_path)))
        while not os.path.isdir(folder) and os.path.dirname(folder) != folder:   # made when written
            folder = os.path.dirname(folder)
        free = shutil.disk_usage(folder).free
        if free < need + (1 << 20):
            raise OSError(errno.ENOSPC, f"No space left on device: {os.fspath(out_path)} needs about "
                                        f"{need / 1e6:.1f} MB, {free / 1e6:.1f} MB free")

    def _write_chunks(self, log_path, out_path, head, part, chunk, keep, every, prov, units, compression):
        """:meth:`run_file`'s chunked run of an HDF5 log (``head``, ``part``: :meth:`_chunks`):
        (Totals, Snapshots)."""
        from .results import Totals, thin_rows

        n = len(head)
        totals = Totals()
        acc = self._snapshot_accumulator(head.dt)
        with atomic_h5(out_path) as f:
            init_result_file(f, {o: self.names[o] for o in keep}, log_path, {}, 0, head.attrs, prov, units,
                             compression, rows=-(-n // every))
            for a in range(0, n, chunk):     # outputs a chunk at a time, whatever the format
                arrays, time = part(a, min(n, a + chunk))
                res = self.run_arrays(*arrays, time=time)
                self._checked(res, log_path, arrays)
                rows = thin_rows(a, len(time), every)
                append_rows(f, res.time[rows], {o: res.outputs[o][rows] for o in keep}, res.flags[rows])
                self._accumulate(acc, a, res, arrays)
                totals.add(res)
            for k, v in (totals.attrs() | self._log_record(head)).items():
                f.attrs[k] = v
            snaps = acc.snapshots()
            snaps.save(f.create_group("snapshots"))
        return totals, snaps


def load_bias_tables(path) -> dict:
    """Bias tables saved by :meth:`Estimator.save_bias_tables`: channel -> AdaptiveTable."""
    import h5py

    with h5py.File(path, "r") as f:
        names = [k for k in f.get("tables", {}) if k.startswith(BIAS_PREFIX)]
    return {k[len(BIAS_PREFIX):]: AdaptiveTable.load(path, k) for k in names}
