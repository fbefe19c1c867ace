"""On-line estimation, one sample at a time, through the batch kernel.

``Estimator.run`` processes whole logs; a :class:`Stream` takes one sample per call, for a filter
fed live (an engine monitoring unit, a test cell, a simulation in the loop)::

    est = Estimator("data/turbofan_demo.h5")
    stream = Stream(est)                 # compiled once (~15 s), then loaded from the cache
    row = np.empty(len(stream.channels))  # the log channels, in stream.channels order,
    ...                                  # in the database's units (stream.units)
    flags = stream.step(row)             # one sample: estimates in stream.x_hat, .z_hat, ...

``step`` calls the same numba step loop (:func:`pwl.runtime.step_loop`, on one row) with the same
screening before and the same reporting pass and air-data test (:mod:`pwl.airdata`) after,
through one compiled function whose only arguments are the stream's state (a numba structure)
and the sample: its numbers equal a batch run's bit for bit (but where a scheduling channel or
theta/delta jumps by more than 5 % of its span in one sample: unable to see ahead, the stream
holds the channel until it comes back or for 64 samples, :func:`_hold_jumps`, where the batch
holds only the runs that do come back). A step costs about 1.4 us from Python against 0.5 us per
sample in batch on the demo database (``pwl bench stream``): numba's call from Python (0.33 us),
the row's check (0.1 us), the step loop for one row (0.7 us; the kernel's records go by
reference, :mod:`pwl.byref`), the air-data test (0.1 us). An input frozen while the engine moves
(:meth:`pwl.Estimator._check_frozen_inputs`) is found as it goes: from the stuck detector's time
into the run on, as soon as a scheduling channel has moved, the steps are flagged FLAG_HELD_INPUT
and make no measurement update (a log run, seeing the whole run, does so from its first sample);
never for the estimator's ``may_hold`` inputs.
What needs the whole log is a log run's only: the second opinions
(``Estimator._second_opinions``: a stream leaves a misfitting sensor out for as long as it
misfits). Samples that arrive in packets (a data bus, a file being written) run at batch speed through
``Estimator.run_arrays``, which continues from the current state. The stream
shares the estimator's filter state: ``stream.reset()`` (or ``est.reset()``) restarts both.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, types

from .byref import fields, record
from .errors import UsageError
from .estimator import _SPIKE as _HELD, BURST_MAX, SPIKE_FRACTION
from .airdata import AIR_DATA_TOLERANCE, _disagree
from .runtime import (FLAG_AIR_DATA, FLAG_DYN_OUTSIDE, FLAG_HELD_INPUT, FLAG_NOT_STARTED, FLAG_TRIM_OUTSIDE,
                      Inputs, Kernel, blank_implausible, report, screen, state_layout, step_loop, workspace)


_F8 = np.dtype(np.float64)


_StreamState = record("StreamState", ["kern", "cols", "post", "jump", "air", "frozen", "still"],
                      "Everything a streamed step needs, by reference (one argument to unbox per call).")


@njit(cache=True, nogil=True)
def _hold_jumps(S, TH, DE, state, osl, jump, longest):
    """The stream's dropout test, causal: a value of a scheduling channel or theta/delta (S (1,
    ns), TH, DE (1,)) further than jump[1, c] from the channel's last value the filter took (the
    filter state's, from ``osl`` on: state_layout) is set to _HELD (implausible: the filter holds
    the channel) for up to ``longest`` samples in a row (counted in jump[0, c]), and for as long
    after as it stays exactly the first held value (jump[2, c]: a frozen bus word); the next one is
    taken (a step). A batch run, which sees ahead, holds only the runs that come back or freeze
    (:func:`pwl.runtime.burst_mask`)."""
    ns = S.shape[1]
    for c in range(ns + 2):
        v = S[0, c] if c < ns else (TH[0] if c == ns else DE[0])
        if abs(v - state[osl + c]) > jump[1, c] and (jump[0, c] < longest or v == jump[2, c]):   # NaN: no test
            if jump[0, c] == 0.0:
                jump[2, c] = v
            jump[0, c] += 1.0
            if c < ns:
                S[0, c] = _HELD
            elif c == ns:
                TH[0] = _HELD
            else:
                DE[0] = _HELD
        else:
            jump[0, c] = 0.0


@njit(cache=True, nogil=True, _nrt=False)
def _take_row(st, row):
    """Copy ``row`` into the kernel's one-row inputs, hold its jumps (:func:`_hold_jumps`) and
    screen it (:func:`pwl.runtime.screen`), as a batch run does before its step loop."""
    kern, cols, post, jump, _, _, _ = fields(st)
    io, _, _, filt, _, out, _ = fields(kern)
    U, Y, S, TH, DE = io
    iu, iy, i_s, ith, ide, t_std, p_std, osl = cols
    for j in range(iu.shape[0]):
        U[0, j] = row[iu[j]]
    for j in range(iy.shape[0]):
        Y[0, j] = row[iy[j]]
    for j in range(i_s.shape[0]):
        S[0, j] = row[i_s[j]]
    TH[0] = row[ith] / t_std if ith >= 0 else 1.0
    DE[0] = row[ide] / p_std if ide >= 0 else 1.0
    _hold_jumps(S, TH, DE, filt.state, osl, jump, BURST_MAX)
    lim, chan_count = post[0], post[1]
    if screen(U, Y, S, TH, DE, lim, chan_count, out.flags):
        blank_implausible(U, Y, S, TH, DE, lim)


@njit(cache=True, nogil=True, _nrt=False)
def _report(st):
    """The reporting pass of a batch run after its step loop (:func:`pwl.runtime.report`);
    returns the step's flags."""
    kern, _, post, _, _, _, _ = fields(st)
    flags = fields(kern)[5].flags
    _, _, q_hat, VT, h_ref, h_lo, h_hi, h_hat, h_held = post
    report(q_hat, VT, h_ref, h_lo, h_hi, h_hat, flags, h_held)
    return flags[0]


@njit(cache=True, nogil=True, inline="always")
def _frozen_inputs(U, S, run, still):
    """The stream's frozen-input test, causal (:meth:`pwl.Estimator._check_frozen_inputs`): True
    when an input j of ``U`` (1, nu) has repeated one value exactly for ``still[0][j]`` samples or
    more (``Estimator._hold_n``: the stuck detector's time, inf for an input that may hold) while a
    scheduling channel c of ``S`` (1, ns; NaN: held, no move) moved more than ``still[1][c]``
    (its units) within that run. ``run`` (2 + 2 ns, nu): each input's last value, its run's length
    and the run's minima and maxima of S, updated."""
    ns = S.shape[1]
    hold_n, move = still
    frozen = False
    for j in range(U.shape[1]):
        if U[0, j] == run[0, j]:
            run[1, j] += 1.0
        else:
            run[0, j] = U[0, j]
            run[1, j] = 1.0
            for c in range(ns):
                run[2 + c, j] = np.inf
                run[2 + ns + c, j] = -np.inf
        for c in range(ns):
            if S[0, c] == S[0, c]:
                run[2 + c, j] = min(run[2 + c, j], S[0, c])
                run[2 + ns + c, j] = max(run[2 + ns + c, j], S[0, c])
            if run[1, j] >= hold_n[j] and run[2 + ns + c, j] - run[2 + c, j] > move[c]:
                frozen = True
    return frozen


@njit(cache=True, nogil=True, _nrt=False)
def _stream_step(st, row):
    """One sample ``row`` (the stream's channels) through screen, the frozen-input test (a frozen
    input: no measurement update, FLAG_HELD_INPUT), the step loop, report and the air-data test
    (:meth:`pwl.Estimator._check_air_data`); the state ``st`` and the kernel's records are passed
    by reference (:mod:`pwl.byref`)."""
    _take_row(st, row)
    io = fields(fields(st)[0])[0]
    frozen = _frozen_inputs(io[0], io[2], fields(st)[5], fields(st)[6])
    if frozen:
        for j in range(io[1].shape[1]):
            io[1][0, j] = np.nan
    step_loop(fields(st)[0])
    f = _report(st)
    if frozen:
        f |= FLAG_HELD_INPUT
        fields(fields(st)[0])[5].flags[0] = f
    air = fields(st)[4]       # [altitude column, Mach column, altitude to m, delta to Pa, tolerance]
    if air[0] >= 0.0 and f & (FLAG_NOT_STARTED | FLAG_HELD_INPUT) == 0:
        S, DE = io[2], io[4]
        if _disagree(S[0, int(air[0])] * air[2], S[0, int(air[1])], DE[0] * air[3], air[4]):
            f |= FLAG_AIR_DATA
            fields(fields(st)[0])[5].flags[0] = f
    return f


class Stream:
    """One-sample-at-a-time estimation with an :class:`pwl.Estimator`: its database, mode, bias
    tables and filter state (shared: ``stream.reset()`` and ``est.reset()`` restart both).
    Configure the estimator (bias tables, learning) before making its stream. Numbers equal a
    batch run's bit for bit, but at a jump of a scheduling channel (module docstring).

    Parameters
    ----------
    est : Estimator
        The estimator to step.
    reset : bool
        Start a new flight (default: :meth:`reset`, the estimator's state and the missing-sample
        counts; a stream made after ``est.run`` started from the end of that flight, its health
        included); False continues from the estimator's state.

    Attributes
    ----------
    channels : list of str
        The log channels a sample holds, in order: inputs, sensed outputs, schedule channels,
        theta/delta channels.
    units : list of str
        Their units (the database's); a row must be in these units (no conversion).
    x_hat, q_hat, h_hat, y_hat, residual, z_hat : ndarray (k,)
        The last step's estimates in physical units (and ``bias_hat``, ``h_std`` when the
        estimator has them); overwritten by the next step: copy what you keep.
    outputs : dict
        Output name -> (1, k) array (the same buffers).
    """

    def __reduce__(self):
        raise UsageError("a Stream cannot be pickled or copied (its compiled records are not): pickle or "
                         "copy its Estimator, which holds the filter state, and make a new Stream(est, "
                         "reset=False) from the copy")

    def __init__(self, est, reset: bool = True):
        self.est = est
        db, pm = est.db, est.pm
        self.channels = list(est.input_channels)
        self.units = [est.channel_units.get(c, "") for c in self.channels]
        at = {c: i for i, c in enumerate(self.channels)}
        index = [np.array([at[c] for c in cols], dtype=np.int64)
                 for cols in (db.names["u"], db.names["y"], pm.schedule_channels)]
        corr = db.correction
        th = (at[pm.theta_channel], at[pm.delta_channel], corr.T_std, corr.P_std) if pm.theta_channel \
            else (-1, -1, 1.0, 1.0)
        nu, ny, ns = (len(i) for i in index)
        io = Inputs(np.zeros((1, nu)), np.zeros((1, ny)), np.zeros((1, ns)), np.ones(1), np.ones(1))
        self.outputs = {o: np.zeros((1, len(est.names[o]))) for o in est.names}
        records = est._records() + (est._outputs(self.outputs, np.zeros(1, dtype=np.int64)),)
        work = workspace(ns, *records[:4])
        self._chan_count = np.zeros((2, est._limits.shape[1]), dtype=np.int64)
        post = (est._limits, self._chan_count, self.outputs["q_hat"], est._VT,
                db.tuner["h_ref"], *est._h_range, self.outputs["h_hat"], est._h_held)
        with np.errstate(over="ignore", invalid="ignore"):
            span = np.diff(est._limits_of(2, 3, 4), axis=0)[0]    # scheduling, theta, delta (inf: none)
        self._jump = np.vstack([np.zeros(ns + 2), SPIKE_FRACTION * span, np.full(ns + 2, np.nan)])
        nx, _, _, _, nq, _ = est.pm.dims
        osl = state_layout(nx, nq, nu, ns, ny)[3]          # the filter state's last scheduling values
        ja, jm, ka, kp = est._air if est._air is not None else (-1, -1, 1.0, 1.0)
        air = np.array([ja, jm, ka, kp * (db.correction.P_std if db.correction else 1.0), AIR_DATA_TOLERANCE])
        self._run = np.zeros((2 + 2 * ns, nu))
        still = (np.ascontiguousarray(est._hold_n), SPIKE_FRACTION * span[:ns])
        self._st = _StreamState(Kernel(io, *records, work), tuple(index) + th + (osl,), post, self._jump, air,
                                self._run, still)
        self._stop = FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE if db.policy == "error" else 0
        self._n = len(self.channels)
        # numba's compiled entry for exactly these argument types (compiled or loaded here, not
        # run), called without the dispatcher's type resolution (0.8 us per call: hashing the
        # state's structure type); step() checks the row's type itself
        sig = (numba.typeof(self._st), types.Array(types.float64, 1, "A"))   # any strides
        _stream_step.compile(sig)
        self._call = _stream_step.overloads[sig].entry_point
        if reset:
            self.reset()
        self._step = self.step = self._fast_step()
        for o, a in self.outputs.items():
            setattr(self, o, a[0])

    def step(self, row) -> int:
        """One sample.

        Parameters
        ----------
        row : ndarray (len(channels),) float64
            The sample in :attr:`channels` order and :attr:`units`; NaN means missing.

        Returns
        -------
        int
            The step's flag bits (``pwl.runtime.FLAG_*``).

        Raises
        ------
        EnvelopeError
            The operating point left the grid and the database's policy is ``error``.
        """
        return self._step(row)

    def _fast_step(self):
        """:meth:`step` as a closure over everything it reads: no attribute lookup per call
        (0.1 us of a 1.4 us step). The instance's ``step`` is this closure."""
        call, st, n, stop, as_row, array, f8 = self._call, self._st, self._n, self._stop, self._as_row, np.ndarray, _F8

        def step(row):
            if not (type(row) is array and row.dtype is f8 and row.ndim == 1 and len(row) == n):
                row = as_row(row)
            f = call(st, row)
            if f & stop:
                from .estimator import EnvelopeError
                raise EnvelopeError("stream: operating point outside the database grid and the "
                                    "database's out-of-range policy is 'error'")
            return f
        step.__doc__ = Stream.step.__doc__
        return step

    def _as_row(self, row) -> np.ndarray:
        """``row`` as the float64 vector step() reads, or a UsageError naming what is wrong."""
        try:
            r = np.ascontiguousarray(row, dtype=np.float64)
        except (TypeError, ValueError):
            raise UsageError(f"stream: a sample row must be numbers, one per channel {self.channels}") from None
        if r.shape != (self._n,):
            raise UsageError(f"stream: a sample row has {len(self.channels)} values, one per channel "
                             f"{self.channels}; got shape {np.shape(row)}")
        return r

    def reset(self, q0=None) -> None:
        """Restart the filter (the estimator's state, shared), the missing-sample counts and the
        dropout holds."""
        self.est.reset(q0)
        self._chan_count[:] = 0
        self._jump[0] = 0.0
        self._jump[2] = np.nan
        self._run[0] = np.nan

    def row(self, sample: dict) -> np.ndarray:
        """The row of a sample given as channel name -> value (a number; None, NaN or a channel
        left out: missing). Other keys (``time``, channels it does not read) are ignored, unless
        a channel it reads is left out too: then the names are refused as a likely mismatch."""
        row = np.empty(len(self.channels))
        absent = []
        for j, c in enumerate(self.channels):
            v = sample.get(c)
            if v is None:
                row[j] = np.nan
                absent += [] if c in sample else [c]
                continue
            try:
                row[j] = float(v)
            except (TypeError, ValueError):
                raise UsageError(f"stream: channel {c}: {v!r} is not a number") from None
        if absent:
            unknown = sorted(set(sample) - set(self.channels) - {"time"})
            if unknown:
                raise UsageError(f"stream: channels {absent} are missing and {unknown} unknown (a naming "
                                 f"mismatch? give a missing value as None or NaN); it reads {self.channels}")
        return row

    def missing(self) -> dict:
        """Samples per channel that were missing (NaN, Inf or outside the plausible range)."""
        out = dict.fromkeys(self.channels, 0)
        for j, c in enumerate(c for cols in self.est._columns() for c in cols):
            if c is not None:
                out[c] = max(out[c], int(self._chan_count[0, j]))
        return out
