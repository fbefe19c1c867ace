"""Estimation results: the :class:`Result` of a run and the results-file format
(``pwl-estimates``: time, flags and one (n, k) dataset per output, names, units, counts and
provenance as attributes, snapshots).

Results files are plain HDF5 that netCDF-4 readers open as well: ``/time`` is the dimension scale
of axis 0 of every output and of ``/flags``, and ``/<output>_channel`` (the column names) the
dimension scale of axis 1 of ``/<output>``, so ``xarray.open_dataset(path, engine="h5netcdf")``
gives named ``time`` and ``<output>_channel`` coordinates. Version 2 added the scales, ``units``,
output selection, thinning (``every``) and ``residual_rms``; version-1 files still read.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import h5py
import numpy as np

from .errors import PwlError, UsageError
from .formats import RESULTS, check, stamp
from .h5io import as_strings, atomic_h5, attr_str, check_seal, read_strings, write_strings
from .logs import Log
from .runtime import (FLAG_AIR_DATA, FLAG_DYN_OUTSIDE, FLAG_FAR_OUTSIDE, FLAG_HEALTH, FLAG_HEALTH_HELD, FLAG_HELD_INPUT, FLAG_IMPLAUSIBLE,
                      FLAG_MISFIT, FLAG_NO_UPDATE, FLAG_NOT_STARTED, FLAG_PARTIAL, FLAG_SETTLING, FLAG_STUCK,
                      FLAG_TRIM_FILLED, FLAG_TRIM_OUTSIDE)
from .snapshots import Snapshots

FORMAT = RESULTS.name
FORMAT_VERSION = RESULTS.version

#: flag count -> the flag bit it counts (Result.counts, results-file attributes, fleet summary)
FLAG_COUNTS = {"no_update": FLAG_NO_UPDATE, "partial": FLAG_PARTIAL, "held_input": FLAG_HELD_INPUT,
               "trim_outside": FLAG_TRIM_OUTSIDE, "dyn_outside": FLAG_DYN_OUTSIDE,
               "not_started": FLAG_NOT_STARTED, "implausible": FLAG_IMPLAUSIBLE,
               "misfit": FLAG_MISFIT, "health_implausible": FLAG_HEALTH, "health_held": FLAG_HEALTH_HELD,
               "stuck": FLAG_STUCK, "settling": FLAG_SETTLING, "air_data": FLAG_AIR_DATA,
               "trim_filled": FLAG_TRIM_FILLED, "far_outside": FLAG_FAR_OUTSIDE}
#: every key of :meth:`Result.counts`, in order
COUNT_KEYS = ("samples", *FLAG_COUNTS, "updated", "trusted")


def trusted(flags: np.ndarray) -> np.ndarray:
    """(n,) bool: the samples whose estimates nothing flags as suspect -- a measurement update,
    past the filter's settling time, no input, scheduling or theta/delta channel held (its value
    is not the sample's: Mach logged in knots, held on 92 % of a flight,
    read Fn 30 % off on a tenth of its samples), health estimates in their plausible
    range, scheduling and inlet pressure in agreement (:mod:`pwl.airdata`), trims the build computed
    (not filled or extrapolated), and no misfit the update could not leave out (most sensors misfit:
    the model does not explain the sample). Leaving the trim grid by a little is not suspect (a
    test cell at -300 m pressure altitude is clipped to 0 m at no cost in accuracy: Fn 0.234 % vs
    0.233 % on the degraded demo flight); farther than :data:`pwl.runtime.FAR_OUTSIDE` of an
    axis's span it is (a user's plant 20 K below a grid of 250-320 K read a clean engine's turbine
    9 points off with residuals small: the filter takes the clipped model's error into health)."""
    f = np.asarray(flags)
    bad = (f & (FLAG_NO_UPDATE | FLAG_NOT_STARTED | FLAG_HEALTH | FLAG_SETTLING | FLAG_HELD_INPUT
                 | FLAG_AIR_DATA | FLAG_TRIM_FILLED | FLAG_FAR_OUTSIDE)) != 0
    return ~bad & ~(((f & FLAG_MISFIT) != 0) & ((f & FLAG_PARTIAL) == 0))

#: HDF5 filters of the outputs and flags. gzip (deflate) is in every HDF5 library, so every tool
#: reads it; lzf only in h5py (and tools built on it, such as h5netcdf). Off by default: on the
#: demo flight gzip saves 29 % of the size for 2.7x the time per flight, lzf 25 % for 1.6x
#: (docs/runtime.md); choosing outputs and thinning save far more.
COMPRESSIONS = {"gzip": {"compression": "gzip", "compression_opts": 4, "shuffle": True},
                "lzf": {"compression": "lzf", "shuffle": True},
                "none": {}}
DEFAULT_COMPRESSION = "none"

#: the database name kind of each output's columns (their units are the database's units of it)
OUTPUT_KINDS = {"x_hat": "x", "q_hat": "q", "h_hat": "h", "h_std": "h", "y_hat": "y", "residual": "y",
                "z_hat": "z", "bias_hat": "y"}

#: samples per HDF5 chunk of the time axis
CHUNK_ROWS = 8192


class ResultError(PwlError, ValueError):
    """A results file that cannot be read (names the file and what is wrong)."""


@dataclass
class Result:
    """Estimates for one log (what :meth:`pwl.Estimator.run` returns; :meth:`save`, :meth:`load`).

    An output is also an attribute: ``res.h_hat`` is ``res.outputs["h_hat"]``.

    Parameters
    ----------
    time : ndarray (n,)
        Sample times, s.
    outputs : dict
        Output name -> float64 (n, k) in physical units: ``x_hat`` (states), ``q_hat``
        (tuners), ``h_hat`` (health parameters, fractions), ``y_hat`` (a-priori predicted sensed
        outputs, bias included), ``residual`` (measured minus ``y_hat``, sensor units),
        ``z_hat`` (unmeasured outputs); ``bias_hat`` (the bias tables' values at the operating
        point) with bias tables; ``h_std`` (standard deviation of every health estimate, from the
        filter's covariance) in online mode.
    flags : ndarray (n,) int64
        Bit mask per sample (:data:`pwl.runtime.FLAG_*`; docs/runtime.md section 5).
    names : dict
        Output -> its k column names (the database's names).
    source : str
        The log it came from.
    attrs : dict
        The log's ``engine``, ``flight_index``, ``flight_time`` and ``provenance``
        (:attr:`pwl.Estimator.provenance` and the log's identity).
    snapshots : Snapshots, optional
        The steady-state snapshots (:mod:`pwl.snapshots`).
    units : dict
        Output -> its k units (empty when not known).
    """

    time: np.ndarray
    outputs: dict[str, np.ndarray]
    flags: np.ndarray
    names: dict[str, list[str]]
    source: str = "<memory>"
    attrs: dict = field(default_factory=dict)
    snapshots: Snapshots | None = None
    units: dict[str, list[str]] = field(default_factory=dict)

    def __getattr__(self, name):
        if name in self.__dict__.get("outputs", {}):
            return self.outputs[name]
        raise AttributeError(name)

    def channel(self, output: str, name: str) -> np.ndarray:
        """One column of an output.

        Parameters
        ----------
        output : str
            An output name (``"z_hat"``, ``"h_hat"``, ...).
        name : str
            One of its columns (``"T40"``, ``"hpt_eff"``, ...).

        Returns
        -------
        ndarray (n,)
            A view of that column, physical units.

        Raises
        ------
        KeyError
            No such output.
        ValueError
            No such column.
        """
        return self.outputs[output][:, self.names[output].index(name)]

    def counts(self) -> dict:
        """How many samples carry each flag.

        Returns
        -------
        dict
            ``samples`` (n), one count per flag of :data:`FLAG_COUNTS` (``no_update``,
            ``partial``, ``held_input``, ``trim_outside``, ...), ``updated`` (the samples with
            a measurement update) and ``trusted`` (:func:`trusted`); keys in
            :data:`COUNT_KEYS` order, int.
        """
        f = self.flags
        out = {"samples": int(f.size)}
        out.update({k: int(np.count_nonzero(f & bit)) for k, bit in FLAG_COUNTS.items()})
        out["updated"] = int(np.count_nonzero((f & (FLAG_NO_UPDATE | FLAG_NOT_STARTED)) == 0))
        out["trusted"] = int(np.count_nonzero(trusted(f)))
        return out

    def to_dataframe(self):
        """The estimates as a pandas DataFrame.

        Returns
        -------
        pandas.DataFrame
            Index ``time`` (s); one float64 column per ``output.channel`` (e.g. ``z_hat.T40``),
            physical units; and ``flags`` (int64).

        Raises
        ------
        UsageError
            pandas is not installed.
        """
        try:
            import pandas as pd
        except ImportError:
            raise UsageError("Result.to_dataframe needs pandas (pip install pandas)") from None
        cols = {f"{o}.{n}": self.outputs[o][:, j] for o in self.names for j, n in enumerate(self.names[o])}
        cols["flags"] = self.flags
        return pd.DataFrame(cols, index=pd.Index(self.time, name="time"))

    def save(self, path, outputs=None, every: int = 1,
             compression: str | None = DEFAULT_COMPRESSION) -> None:
        """Write a results file, atomically.

        Parameters
        ----------
        path : str or path-like
            HDF5 (format ``pwl-estimates``, :mod:`pwl.formats`; netCDF-4 readers open it too) or,
            for a ``.csv`` path, CSV with ``time``, ``flags`` and ``output.name`` columns.
        outputs : sequence of str or str, optional
            The outputs to keep (None: all); time and flags always.
        every : int
            Keep samples 0, N, 2N, ... (the counts in the file still count every sample).
        compression : {"none", "gzip", "lzf"} or None
            HDF5 filter of the outputs (:data:`COMPRESSIONS`).

        Raises
        ------
        UsageError
            An unknown output, ``every`` < 1, an unknown compression.
        """
        keep = select_outputs(self.names, outputs)
        rows = thin_rows(0, self.time.size, every)
        if os.fspath(path).lower().endswith(".csv"):
            cols = {"flags": self.flags[rows]}
            for o in keep:
                for j, n in enumerate(self.names[o]):
                    cols[f"{o}.{n}"] = self.outputs[o][rows, j]
            from .logs import write_csv
            write_csv(path, Log(self.time[rows], cols, {}, path=str(path)))
            return
        totals = Totals()
        totals.add(self)
        prov = dict(self.attrs.get("provenance") or {}) | selection_record(keep, every)
        with atomic_h5(path) as f:
            init_result_file(f, {o: self.names[o] for o in keep}, self.source, totals.attrs(), 0, self.attrs,
                             prov, {o: u for o, u in self.units.items() if o in keep}, compression,
                             rows=len(self.time[rows]))
            append_rows(f, self.time[rows], {o: self.outputs[o][rows] for o in keep}, self.flags[rows])
            if self.snapshots is not None:
                self.snapshots.save(f.create_group("snapshots"))

    @classmethod
    def load(cls, path) -> "Result":
        """Read a results file.

        Parameters
        ----------
        path : str or path-like
            A results file (``pwl-estimates`` version 1 or 2; its seal checked).

        Returns
        -------
        Result
            The outputs the file holds, at the samples it kept (see its ``every`` attribute), its
            units, its attributes (flat: counts, provenance keys, log identity) and snapshots.

        Raises
        ------
        ResultError
            Naming the file: not HDF5, damaged (seal), another format or a newer version
            (naming the format and version found and expected).
        """
        path = os.fspath(path)
        with open_results(path) as f:
            names = {o: read_strings(f["names"][o]) for o in f.get("names", {})}
            outputs = {o: np.asarray(f[o][()]) for o in names}
            units = {o: as_strings(f[o].attrs["units"])
                     for o in names if "units" in f[o].attrs}
            attrs = {k: attr_str(f, k) for k in f.attrs}
            snaps = Snapshots.load(f["snapshots"]) if "snapshots" in f else None
            return cls(np.asarray(f["time"][()]), outputs, np.asarray(f["flags"][()]), names,
                       attr_str(f, "source", path), attrs, snaps, units)


def select_outputs(names, outputs=None, where: str = "") -> list[str]:
    """The outputs to write, in the estimator's order: ``outputs`` (names, or one comma-separated
    string; ``time`` and ``flags`` are always written and may be named) or, when None, all of
    ``names`` (output -> columns). :class:`UsageError` naming an unknown output and the known ones."""
    if outputs is None:
        return list(names)
    want = [o.strip() for o in (outputs.split(",") if isinstance(outputs, str) else outputs)]
    want = [o for o in want if o and o not in ("time", "flags")]
    bad = [o for o in want if o not in names]
    if bad:
        raise UsageError(f"{where + ': ' if where else ''}unknown output(s) {', '.join(map(repr, bad))}; "
                         f"this estimator has {', '.join(names)} (time and flags are always kept)")
    return [o for o in names if o in want]


def check_every(every) -> int:
    """``every`` as a positive int (:class:`UsageError` naming the value otherwise)."""
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise UsageError(f"every = {every!r}: keep every N-th sample needs a whole number N >= 1")
    return int(every)


def thin_rows(start: int, n: int, every: int) -> slice:
    """The rows of a block of ``n`` samples starting at sample ``start`` of a log that thinning
    keeps: the samples whose index in the log is a multiple of ``every``."""
    return slice((-start) % check_every(every), n, every)


def selection_record(outputs, every: int) -> dict:
    """Attributes naming what a results file holds: ``outputs`` (comma-separated) and ``every``."""
    return {"outputs": ",".join(outputs), "every": check_every(every)}


def output_units(names, db_names, db_units) -> dict[str, list[str]]:
    """output -> the unit of each column (``names``: output -> column names; ``db_names``,
    ``db_units``: a database's names and units per kind, x u y z h q p); "" where not known."""
    by_kind = {k: dict(zip(db_names.get(k, []), u)) for k, u in db_units.items()}
    return {o: [by_kind.get(OUTPUT_KINDS.get(o, ""), {}).get(c, "") for c in cols] for o, cols in names.items()}


def compression_filters(compression) -> dict:
    """h5py's dataset keywords for ``compression`` (a key of :data:`COMPRESSIONS` or None);
    :class:`UsageError` naming the value otherwise."""
    key = "none" if compression is None else str(compression)
    if key not in COMPRESSIONS:
        raise UsageError(f"compression {compression!r}: choose one of {', '.join(COMPRESSIONS)}")
    return COMPRESSIONS[key]


def init_result_file(f, names, source, counts, n, attrs=None, provenance=None, units=None,
                     compression: str | None = DEFAULT_COMPRESSION, rows: int | None = None):
    """Start a results file in the open, empty HDF5 file ``f``: attributes, and ``n`` rows of
    /time (s), /flags and one (n, k) float64 dataset per output of ``names`` (output -> k column
    names), extendable along axis 0 with :func:`append_rows`, with their dimension scales and
    ``units`` (output -> k units). ``rows``: how many rows the file will hold, if known: chunks
    are no longer (HDF5 stores whole chunks: 38 thinned rows in 8192-row chunks took 2.7 MB)."""
    stamp(f, RESULTS)
    f.attrs["source"] = str(source)
    for k, v in (attrs or {}).items():
        if k in LOG_ATTRS:
            f.attrs[k] = v
    for k, v in (provenance or {}).items():
        f.attrs[k] = v
    filters = compression_filters(compression)
    c = min(CHUNK_ROWS, max(1, CHUNK_ROWS if rows is None else int(rows)))
    f.attrs["compression"] = "none" if compression is None else str(compression)
    time = f.create_dataset("time", shape=(n,), maxshape=(None,), dtype="f8", chunks=(c,), **filters)
    time.make_scale("time")
    time.attrs["units"] = "s"
    flags = f.create_dataset("flags", shape=(n,), maxshape=(None,), dtype="i8", chunks=(c,), **filters)
    flags.dims[0].attach_scale(time)
    flags.attrs["description"] = "bit mask per sample (pwl.runtime.FLAG_*; docs/runtime.md section 5)"
    for o in names:
        k = len(names[o])
        d = f.create_dataset(o, shape=(n, k), maxshape=(None, k), dtype="f8", chunks=(c, max(k, 1)),
                             **filters)
        write_strings(f.require_group("names"), o, names[o])
        write_strings(f, o + "_channel", names[o])
        f[o + "_channel"].make_scale(o + "_channel")
        d.dims[0].attach_scale(time)
        d.dims[1].attach_scale(f[o + "_channel"])
        d.attrs["units"] = list((units or {}).get(o) or [""] * k)
    for k, v in counts.items():
        f.attrs[k] = v


def append_rows(f, time, outputs, flags):
    """Append rows to /time (n,), /flags (n,) and each output (n, k) of an open results file."""
    n0 = f["time"].shape[0]
    n1 = n0 + time.size
    for name, data in [("time", time), ("flags", flags)] + list(outputs.items()):
        d = f[name]
        d.resize(n1, axis=0)
        d[n0:n1] = data


class Totals:
    """Flag counts and residual RMS over every sample of a run, added result by result (chunks)."""

    def __init__(self):
        self.counts: dict = dict.fromkeys(COUNT_KEYS, 0)
        self.sensors: list[str] = []
        self._ss = self._n = None

    def add(self, res: Result) -> None:
        """Add a result's flag counts and residual squares (sensor units squared)."""
        self.counts = {k: self.counts[k] + v for k, v in res.counts().items()}
        if "residual" in res.outputs:
            r = res.outputs["residual"]
            ok = np.isfinite(r)
            z = np.where(ok, r, 0.0)
            ss, n = (z * z).sum(axis=0), ok.sum(axis=0)
            self._ss, self._n = (ss, n) if self._ss is None else (self._ss + ss, self._n + n)
            self.sensors = list(res.names["residual"])

    def residual_rms(self) -> np.ndarray:
        """(ny,) root mean square of every sensor's finite residuals (NaN: none), sensor units."""
        if self._ss is None:
            return np.zeros(0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self._n > 0, np.sqrt(self._ss / np.maximum(self._n, 1)), np.nan)

    def attrs(self) -> dict:
        """The results file's attributes: every count, ``residual_rms`` and its ``residual_sensors``."""
        return self.counts | {"residual_rms": self.residual_rms(), "residual_sensors": list(self.sensors)}


#: log attributes copied into results files (who flew what, when: the fleet's bookkeeping)
LOG_ATTRS = ("engine", "flight_index", "flight_time")


def open_results(path, verify: bool = True) -> h5py.File:
    """The results file ``path`` open for reading, its format and version checked, and its seal
    first when ``verify`` (reads the whole file: skip it for a file this process just wrote).
    :class:`ResultError` naming the file when it is not a results file this pwl reads."""
    path = os.fspath(path)
    try:
        if verify:
            check_seal(path)
        f = h5py.File(path, "r")
    except PwlError as e:
        raise ResultError(str(e)) from None
    except OSError as e:
        raise ResultError(f"{path}: not a readable HDF5 results file ({e})") from None
    try:
        check(RESULTS, path, f, error=ResultError)
    except ResultError:
        f.close()
        raise
    return f


def file_summary(f) -> dict:
    """One flight of a fleet summary, from its open results file ``f`` (:func:`open_results`):
    engine, flight_index (None when the log had none), flight_time, every count of
    :data:`COUNT_KEYS`, ``h_hat.<parameter>`` of the last steady snapshot (fractions; NaN without
    a snapshot) and ``rms.<sensor>`` (residual RMS over every sample, sensor units; absent in
    version-1 files) and ``air_data_lag_s`` (how late the inlet pressure ran behind the air
    data: :attr:`pwl.Estimator.air_data_lag`; NaN when not measured)."""
    a = f.attrs
    fi = str(a.get("flight_index", ""))
    row = {"engine": attr_str(f, "engine") or "", "flight_index": int(fi) if fi.lstrip("-").isdigit() else None,
           "flight_time": attr_str(f, "flight_time") or ""}
    row.update({k: int(a[k]) if k in a else None for k in COUNT_KEYS})
    if "snapshots" in f and "out_h_hat" in f["snapshots"]:
        g = f["snapshots"]
        h = np.asarray(g["out_h_hat"][()])
        last = h[-1] if h.shape[0] else np.full(h.shape[1], np.nan)
        row.update({f"h_hat.{n}": float(v) for n, v in zip(read_strings(g["names_h_hat"]), last)})
    sensors = as_strings(a.get("residual_sensors", []))
    row.update({f"rms.{s}": float(v) for s, v in zip(sensors, a.get("residual_rms", []))})
    row["air_data_lag_s"] = float(a.get("air_data_lag_s", np.nan))
    return row
