"""Flight logs: the one definition of pwl's log file format (HDF5 and CSV), its writer, and the
readers of every log format pwl takes (:func:`read_log`: HDF5, CSV, Parquet, MAT, DataFrames,
through a channel map if given; docs/runtime.md "Log formats").

HDF5 layout (format ``pwl-flight-log`` version 1)::

    /                 attrs: format, format_version, dt (s), and free metadata (model, seed, ...)
    /time             float64 (n,), seconds
    /channels/<name>  float64 (n,), attr ``unit``: logged (measured) channels
    /truth/<name>     float64 (n,), attr ``unit``: optional true values for validation

CSV layout: one header row of ``name[unit]`` cells (``[unit]`` may be omitted), the first column
``time[s]``, then one row per sample. Truth channels are written with a ``truth.`` prefix.
"""
from __future__ import annotations

import contextlib
import csv
import importlib
import json
import os
import re
import sys
import warnings
from dataclasses import dataclass, field
from importlib.metadata import version

import h5py
import numpy as np

from .errors import PwlError, PwlWarning
from .formats import FLIGHT_LOG, check, stamp
from .h5io import SealError, as_strings, atomic_h5, attr_str, check_seal
from .units import UnitError, converter

FORMAT = FLIGHT_LOG.name
VERSION = FLIGHT_LOG.version


class LogError(PwlError, ValueError):
    """A log file that cannot be used; the message names the file and the channel."""


@dataclass
class Log:
    """A flight log in memory (what :func:`read_log` returns and :func:`write_log` writes).

    Parameters
    ----------
    time : ndarray (n,)
        Sample times, seconds, strictly increasing.
    channels : dict
        Logged (measured) channel name -> float64 (n,) values.
    units : dict
        Channel name -> its declared unit ("" or absent: undeclared, taken as the model's).
    truth, truth_units : dict, optional
        True values (name -> (n,)) and their units, for validation (simulated logs).
    attrs : dict, optional
        Free metadata (``dt`` in s, ``engine``, ``flight_index``, ``flight_time``, model,
        seed, ...).
    path : str
        Where the log came from (``"<memory>"`` when built in memory); named in errors.
    """

    time: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    truth_units: dict[str, str] = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    path: str = "<memory>"

    def __len__(self):
        return self.time.size

    @property
    def dt(self) -> float:
        """The sample interval (s): the median time step; the ``dt`` attribute for a log of one
        sample (an attribute that the time column contradicts -- a converter's default -- is not
        believed: dt 1.0 on a 15 ms log made 1 s snapshot blocks of 67 s)."""
        dt = sample_interval(self.time)
        return float(self.attrs["dt"]) if not np.isfinite(dt) and "dt" in self.attrs else dt

    def require(self, names, units=None, absent_ok=(), rows=slice(None)) -> np.ndarray:
        """Stack channels ``names`` into a C-contiguous (n, k) array, in ``units`` if given: a
        channel declared in another known unit of the same quantity is converted (``kPa`` to
        ``Pa``, ``degC`` to ``K``, ...; :mod:`pwl.units`), one without a declared unit is taken
        as it is. A channel of ``absent_ok`` that the log lacks is NaN on every sample. ``rows``:
        the samples to take (a slice; default all).

        Raises :class:`LogError` naming the file and the missing channel, or the channel whose
        unit cannot be converted.
        """
        out = np.empty((len(range(*rows.indices(len(self)))), len(names)))
        for j, name in enumerate(names):
            if name not in self.channels:
                if name in absent_ok:
                    out[:, j] = np.nan
                    continue
                if name in self.attrs.get("left_out", {}):
                    raise LogError(self.attrs["left_out"][name])
                like = case_twin(self.channels, name)
                hint = (f"; {like!r} differs in case only: rename the column, or map it with a channel map"
                        if like else "")
                raise LogError(f"{self.path}: channel {name!r} is missing "
                               f"(log has: {', '.join(sorted(self.channels))}){hint}")
            out[:, j] = self.channels[name][rows]
            if units is not None:
                try:
                    scale, offset = converter(self.units.get(name, ""), units[j], f"{self.path}: channel {name!r}")
                except UnitError as e:
                    raise LogError(str(e)) from None
                if (scale, offset) != (1.0, 0.0):
                    out[:, j] = out[:, j] * scale + offset
        return out

    def conversions(self, units: dict) -> dict:
        """channel -> "have -> want" for every channel of ``units`` (name -> unit) that
        :meth:`require` converts."""
        return {c: f"{self.units[c]} -> {u}" for c, u in units.items()
                if self.units.get(c) and u and self.units[c] != u}


def write_log(path, log: Log, compact: bool = False) -> None:
    """Write a log to a file, atomically (temporary file renamed when complete).

    Parameters
    ----------
    path : str or path-like
        ``.csv``: CSV (:func:`write_csv`: a ``name[unit]`` header row, ``truth.`` columns);
        anything else: pwl's sealed HDF5 flight log (format ``pwl-flight-log``, module
        docstring).
    log : Log
        Every channel and truth channel must have the shape of ``log.time`` (n,).
    compact : bool
        HDF5 only: store channels as float32 with shuffle + gzip (for shipped sample data:
        sensor values need no more than float32's 7 digits); the reader always returns float64.

    Raises
    ------
    LogError
        A channel whose shape is not (n,).
    """
    if os.fspath(path).lower().endswith(".csv"):
        return write_csv(path, log)
    n = len(log)
    with atomic_h5(path) as f:
        stamp(f, FLIGHT_LOG)
        for k, v in log.attrs.items():
            f.attrs[k] = v if isinstance(v, (int, float, str, np.number, np.bool_)) else json.dumps(v)
        f.create_dataset("time", data=np.asarray(log.time, dtype=np.float64))
        for grp_name, data, units in (("channels", log.channels, log.units),
                                      ("truth", log.truth, log.truth_units)):
            if grp_name == "truth" and not data:
                continue
            g = f.create_group(grp_name)
            for name, v in data.items():
                v = np.asarray(v, dtype=np.float64)
                if v.shape != (n,):
                    raise LogError(f"{path}: channel {name!r} has shape {v.shape}, expected ({n},)")
                if compact:
                    d = g.create_dataset(name, data=v.astype(np.float32), shuffle=True,
                                         compression="gzip", compression_opts=6)
                else:
                    d = g.create_dataset(name, data=v, chunks=True if n > 4096 else None)
                d.attrs["unit"] = units.get(name, "")


def write_csv(path, log: Log) -> None:
    """CSV export: header ``name[unit]``, time first, truth channels prefixed ``truth.``."""
    cols = [("time", "s", log.time)]
    cols += [(k, log.units.get(k, ""), v) for k, v in log.channels.items()]
    cols += [("truth." + k, log.truth_units.get(k, ""), v) for k, v in log.truth.items()]
    tmp = os.fspath(path) + ".tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([f"{n}[{u}]" if u else n for n, u, _ in cols])
        data = np.column_stack([np.asarray(c[2], dtype=np.float64) for c in cols])
        for row in data:
            w.writerow([repr(float(x)) for x in row])
    os.replace(tmp, path)


@contextlib.contextmanager
def _named(path, what: str = "damaged log"):
    """Any exception but pwl's own while reading ``path`` becomes a :class:`LogError` naming it
    (HDF5, CSV, Parquet and MAT readers raise many kinds on a damaged file); text that is not
    UTF-8 with what to do."""
    try:
        yield
    except SealError as e:
        raise LogError(str(e)) from None
    except PwlError:
        raise
    except Exception as e:
        hint = (": not UTF-8 text (cp1252 is read when its first 64 KiB show it): save it as UTF-8 (Excel: 'CSV "
                "UTF-8'; UTF-16 with a byte-order mark reads too), or read it with pandas (pandas.read_csv(path, "
                "encoding=...)) and pass the DataFrame" if isinstance(e, UnicodeDecodeError) else "")
        raise LogError(f"{path}: {what} ({type(e).__name__}: {' '.join(str(e).split())}){hint}") from None


def read_log(source, channel_map=None) -> Log:
    """Read a flight log of any format pwl takes (docs/runtime.md "Log formats" has the rules).

    Parameters
    ----------
    source : str, path-like or pandas.DataFrame
        A path, by extension ``.csv``/``.tsv`` (CSV), ``.parquet``, ``.mat`` (MATLAB v5 or
        v7.3), anything else HDF5 (pwl's own ``pwl-flight-log``, or another layout with a
        channel map); or a pandas DataFrame (the time, s, as a column or as the index).
    channel_map : ChannelMap or str or path-like, optional
        A :class:`pwl.channel_map.ChannelMap` or the path of its TOML file: it picks, renames
        and declares the units of the columns the model reads. None: the log's own names.

    Returns
    -------
    Log
        Time (n,) s, channels name -> float64 (n,), their declared units, truth if present.

    Raises
    ------
    LogError
        Any defect, naming the file (and the column): no such file, another format or a newer
        version, a missing or non-numeric column, a time column that does not increase.
    """
    cmap = _channel_map(channel_map)
    pd = sys.modules.get("pandas")
    if pd is not None and isinstance(source, pd.DataFrame):
        with _named("<DataFrame>", "unusable DataFrame"):
            log = _from_frame("<DataFrame>", source, cmap)
    else:
        path = os.fspath(source)
        if not os.path.exists(path):
            raise LogError(f"{path}: no such file")
        what, reader = _reader(path)
        with _named(path, f"unreadable {what} log"):
            log = reader(path, cmap)
    return cmap.apply(log) if cmap is not None else log


def _channel_map(channel_map):
    if channel_map is None:
        return None
    from .channel_map import ChannelMap
    return channel_map if isinstance(channel_map, ChannelMap) else ChannelMap.load(channel_map)


def _read_hdf5(path, cmap) -> Log:
    if cmap is not None and not _is_flight_log(path):
        return _read_h5_columns(path, cmap)
    head = read_header(path)
    log = read_rows(head, 0, len(head))
    with _named(path, "damaged log, cannot read /truth"), h5py.File(path, "r") as f:
        if "truth" in f:
            log.truth, log.truth_units = _read_group(f, "truth", len(head), path)
    return log


def _is_flight_log(path) -> bool:
    with h5py.File(path, "r") as f:
        return attr_str(f, "format") == FORMAT


def read_header(path) -> Log:
    """An HDF5 flight log's time, channel units and attributes, validated, without channel data.

    With :func:`read_rows` this reads long logs in chunks with bounded memory
    (:meth:`pwl.Estimator.run_file`).

    Parameters
    ----------
    path : str or path-like
        A ``pwl-flight-log`` HDF5 file (:func:`write_log`).

    Returns
    -------
    Log
        ``time`` (n,) s (converted from the unit of /time's ``unit`` attribute, if any: ms, min, ...),
        ``units`` of every channel, ``attrs``; ``channels`` empty.

    Raises
    ------
    LogError
        No such file, a damaged file (seal), another format or a newer version (naming the
        format found and expected), a missing ``/time`` or ``/channels``, a channel whose length
        is not the time's, a time that does not increase.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise LogError(f"{path}: no such file")
    with _named(path, "not a readable HDF5 log"):
        check_seal(path)
        with h5py.File(path, "r") as f:
            check(FLIGHT_LOG, path, f, error=LogError,
                  hint="an HDF5 file of another layout reads with a channel map naming its columns by path: "
                       "1-D datasets (data/FuelFlow), fields of a compound dataset (records/FuelFlow) or columns "
                       "of a 2-D dataset with a 'names' attribute (table/FuelFlow)")
            if "time" not in f or "channels" not in f:
                raise LogError(f"{path}: /time or /channels is missing")
            time = np.asarray(f["time"][()], dtype=np.float64)
            unit = attr_str(f["time"], "unit", "") or "s"     # a writer that stored it in another unit
            if unit != "s":
                try:
                    scale, offset = converter(unit, "s", f"{path}: /time")
                except UnitError as e:
                    raise LogError(str(e)) from None
                time = time * scale + offset
            units = {}
            for k, d in f["channels"].items():
                if d.shape != time.shape:
                    raise LogError(f"{path}: /channels/{k} has shape {d.shape}, expected {time.shape} like /time")
                units[k] = attr_str(d, "unit", "")
            attrs = {k: attr_str(f, k) for k in f.attrs if k not in ("format", "format_version")}
    check_time(path, time)
    return Log(time, {}, units, attrs=attrs, path=path)


def case_twin(channels, name: str) -> str | None:
    """The channel among ``channels`` whose name differs from ``name`` in case only, else None."""
    return next((c for c in channels if c != name and c.casefold() == name.casefold()), None)


def sample_interval(time) -> float:
    """The log's sample interval (s): the median time step (NaN for fewer than 2 samples)."""
    return float(np.median(np.diff(time))) if len(time) > 1 else float("nan")


#: a time step longer than this many median steps is a gap in the log (a recorder dropout):
#: counted in the results' provenance, and never bridged by :func:`resample`
GAP_STEPS = 5.0


def gap_starts(time) -> np.ndarray:
    """Indices i of the gaps of a log's time column: time[i+1] - time[i] > :data:`GAP_STEPS`
    median steps."""
    step = np.diff(time)
    return np.flatnonzero(step > GAP_STEPS * np.median(step)) if step.size else np.zeros(0, np.int64)


def time_gaps(time) -> tuple[int, float]:
    """(number of gaps, longest gap in s) of a log's time column (:func:`gap_starts`)."""
    g = gap_starts(time)
    return int(g.size), float((time[g + 1] - time[g]).max()) if g.size else 0.0


def rows_missing(time, dt: float) -> int:
    """How many rows a log sampled every ``dt`` s lacks between its samples, gaps
    (:func:`gap_starts`) aside: a recorder that drops rows leaves steps of 2, 3, ... dt."""
    step = np.diff(time)
    if not step.size:
        return 0
    step = step[step <= GAP_STEPS * np.median(step)]
    return int(np.sum(np.maximum(np.rint(step / dt) - 1.0, 0.0)))


@dataclass
class Resampled:
    """A log on a uniform time grid (:func:`resample`) and which of its rows hold information.

    Attributes
    ----------
    log : Log
        Every channel and truth interpolated linearly onto ``t0 + k dt`` (a NaN sample spoils its
        neighbours' interval only); attrs ``dt``, ``resampled_from`` (the log's median step, s),
        ``rows_missing`` (:func:`rows_missing` at dt), ``time_gaps`` and ``longest_gap_s``.
    measured : ndarray (m,) bool
        The rows nearest to a logged sample (within dt/2): where a measurement exists. The
        others lie between samples of a slower log; their sensor values are interpolations
        that carry no new information (a filter updated on them counts one sample many times).
    in_gap : ndarray (m,) bool
        The rows inside a gap of the log (:data:`GAP_STEPS`): nothing was logged there.
    """

    log: Log
    measured: np.ndarray
    in_gap: np.ndarray


def resample(log: Log, dt: float) -> Resampled:
    """The log on a uniform time grid of step ``dt`` (s) from its first sample (:class:`Resampled`)."""
    time = log.time
    n = int(np.floor((time[-1] - time[0]) / dt + 1e-9)) + 1
    t = time[0] + np.arange(n) * dt
    def interp(d):
        return {k: np.interp(t, time, v) for k, v in d.items()}
    i = np.clip(np.searchsorted(time, t), 1, max(1, len(time) - 1))
    dist = np.abs(time[i - 1] - t) if len(time) == 1 else \
        np.minimum(np.abs(time[i - 1] - t), np.abs(time[i] - t))
    measured = dist <= dt / 2 * (1 + 1e-9)
    in_gap = np.zeros(n, dtype=bool)
    for g in gap_starts(time):
        in_gap |= (t > time[g]) & (t < time[g + 1])
    count, longest = time_gaps(time)
    attrs = {**log.attrs, "dt": dt, "resampled_from": sample_interval(time), "time_gaps": count,
             "longest_gap_s": longest, "rows_missing": rows_missing(time, dt)}
    return Resampled(Log(t, interp(log.channels), dict(log.units), interp(log.truth),
                         dict(log.truth_units), attrs, log.path), measured, in_gap & ~measured)


def check_time(path, time) -> None:
    """A log's time column must be non-empty, finite and strictly increasing (LogError naming the
    first bad sample otherwise): the filter's steps and the snapshots' windows rely on it."""
    if time.ndim != 1 or time.size == 0:
        raise LogError(f"{path}: the log is empty (no samples)")
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise LogError(f"{path}: time is not finite at sample {bad[0]} ({time[bad[0]]})")
    step = np.diff(time)
    back = np.flatnonzero(step <= 0)
    if back.size:
        k = back[0] + 1
        same = int(np.count_nonzero(step == 0))
        if same > 0.1 * step.size:
            hint = (f"; it repeats on {same} of {step.size} rows: time stamps coarser than the sampling? Export "
                    "the time with sub-second resolution")
        elif back.size == 1 and time[k] < time[0] + 0.1 * (time[k - 1] - time[0]):
            hint = "; it starts again there: two logs joined? One log is one flight: split the file"
        elif back.size > 1:
            hint = f" (and on {back.size - 1} more of its {step.size} steps: {same} repeat, {back.size - same} go back)"
        else:
            hint = ""
        raise LogError(f"{path}: time does not increase at sample {k} ({float(time[k - 1])!r} -> "
                       f"{float(time[k])!r}){hint}")


def read_rows(head: Log, a: int, b: int) -> Log:
    """Samples a..b of every channel of the HDF5 log described by ``head`` (from read_header)."""
    with _named(head.path, f"damaged log, cannot read samples {a}..{b}"), h5py.File(head.path, "r") as f:
        chans = {k: np.asarray(f["channels"][k][a:b], dtype=np.float64) for k in head.units}
    return Log(head.time[a:b], chans, head.units, attrs=head.attrs, path=head.path)


def _read_group(f, name, n, path):
    if name not in f:
        raise LogError(f"{path}: group /{name} is missing")
    data, units = {}, {}
    for k, d in f[name].items():
        v = np.asarray(d[()], dtype=np.float64)
        if v.shape != (n,):
            raise LogError(f"{path}: /{name}/{k} has shape {v.shape}, expected ({n},) like /time")
        data[k] = v
        units[k] = attr_str(d, "unit", "")
    return data, units


def _split_header(cell: str):
    """(name, unit) of a column header: ``name[unit]``, or ``name (unit)`` when the parentheses
    hold a unit pwl knows (``Nf (rpm)``; ``Flow (corrected)`` stays a name)."""
    from .units import known
    cell = cell.strip()
    if cell.endswith("]") and "[" in cell:
        i = cell.index("[")
        return cell[:i].strip(), cell[i + 1:-1].strip()
    if cell.endswith(")") and "(" in cell:
        i = cell.rindex("(")
        if cell[:i].strip() and known(cell[i + 1:-1].strip()) is not None:
            return cell[:i].strip(), cell[i + 1:-1].strip()
    return cell, ""


# ---- columns of any format -> Log ---------------------------------------------------------------
#: names of the time column, matched in this order and in any case (``Time``, ``TIME``, ...), on the
#: name before any ``[unit]``; a channel map's ``[time] column`` overrides them
TIME_NAMES = ("time", "timestamp", "datetime", "t")


def _find_time(path, names) -> str | None:
    """The time column of ``names``: the first of :data:`TIME_NAMES` that a column has (any case)."""
    for want in TIME_NAMES:
        hits = [n for n in names if n.lower() == want]
        if len(hits) > 1:
            raise LogError(f"{path}: columns {hits} could each be the time: name one in a channel map's "
                           "[time] column")
        if hits:
            return hits[0]
    return None


def _declared(header: str, mapped: str, where: str) -> str:
    """The unit of a column declared by the log (``header``) and/or a channel map (``mapped``)."""
    if header and mapped and header != mapped:
        raise LogError(f"{where}: the log declares unit {header!r}, the channel map {mapped!r}")
    return mapped or header


def _missing(path, column, where, have) -> LogError:
    """The error for a column a channel map names (``where``) that the log lacks (has ``have``)."""
    return LogError(f"{path}: column {column!r} is missing ({where}; log has: {', '.join(have)})")


def _vector(path, name, v):
    """A column as a 1-D array (a pandas Series as it is; (n, 1) and (1, n) arrays flattened)."""
    if hasattr(v, "dtype") and getattr(v, "ndim", 0) == 1:
        return v
    a = np.asarray(v)
    if a.ndim == 0 or a.size != max(a.shape):
        raise LogError(f"{path}: column {name!r} has shape {a.shape}, expected one value per sample")
    return a.reshape(-1)


def _numeric(path, name, v, text_as_missing: bool = False) -> tuple[np.ndarray, int]:
    """Column ``name`` as a new float64 (n,) array and how many of its values were text read as
    missing: numbers and booleans as they are, missing values (empty cells, None, NA) as NaN,
    text parsed as Python's ``float`` does (``1e400`` is inf), and also Fortran's D exponent
    (``1.0D+03``) and thousands separators (``1,000.96``; ``1,000`` only in a column written
    with decimal points). A number with a comma otherwise (``0,015``: a decimal comma) is a
    LogError naming it. Other text (``ERR``, ``#N/A``, ``-``): a LogError naming the first such
    value, or with ``text_as_missing`` NaN while fewer than half the column's values are such text
    (a :class:`PwlWarning` names the column, the count and the first)."""
    import pandas as pd
    s = v if isinstance(v, pd.Series) else pd.Series(v)
    if pd.api.types.is_numeric_dtype(s.dtype):
        return s.to_numpy(dtype=np.float64, na_value=np.nan, copy=True), 0
    if not (s.dtype == object or pd.api.types.is_string_dtype(s.dtype)):
        raise LogError(f"{path}: column {name!r} holds {s.dtype} values, not numbers")
    a = s.to_numpy(dtype=object, na_value=np.nan)
    try:
        return a.astype(np.float64), 0
    except (TypeError, ValueError):
        pass
    out = np.full(a.size, np.nan)
    bad = []
    for i, x in enumerate(a):
        try:
            out[i] = float(x)
        except (TypeError, ValueError):
            bad.append(i)
    points = any("." in str(x) for x in a[np.isfinite(out)])
    text = []
    for i in bad:
        x = str(a[i]).strip()
        if _FORTRAN.fullmatch(x):
            out[i] = float(x.replace("D", "E").replace("d", "e"))
        elif _THOUSANDS.fullmatch(x) and ("." in x or points):
            out[i] = float(x.replace(",", ""))
        elif _COMMA_NUMBER.fullmatch(x) or _THOUSANDS.fullmatch(x):
            raise LogError(f"{path}: column {name!r}: {a[i]!r} at sample {i} is a number with a comma, not read as "
                           "one (a decimal comma, or a thousands separator?): write the log with decimal points "
                           "and no thousands separators, or read it with pandas (pandas.read_csv(path, "
                           "decimal=',') or thousands=',') and pass the DataFrame")
        else:
            text.append(i)
    bad = text
    if not bad:
        return out, 0
    given = int(np.count_nonzero(~pd.isna(a)))
    if not text_as_missing or 2 * len(bad) >= given:
        raise LogError(f"{path}: column {name!r}: non-numeric value {a[bad[0]]!r} at sample {bad[0]}"
                       + (f" ({len(bad)} of its {given} values are not numbers)" if text_as_missing else ""))
    warnings.warn(PwlWarning(f"{path}: column {name!r}: {len(bad)} non-numeric value(s) read as missing "
                             f"(the first {a[bad[0]]!r} at sample {bad[0]})"), stacklevel=3)
    return out, len(bad)


def _seconds(path, name, unit, v):
    """The time column as float64 (n,) seconds and the attributes it gives: numbers (converted
    from ``unit``: ms, min, h, d) as they are; date-times (ISO 8601 text, datetime64, with or
    without time zone) and durations (``00:01:02.5``, timedelta64) as seconds from the first
    sample, the first date-time kept as the ``start_time`` attribute; times of day (durations
    under a day) continued past midnight (:func:`_past_midnight`). Numbers without a unit that
    look like spreadsheet day numbers (:func:`_looks_like_days`) are a LogError asking for the
    unit."""
    import pandas as pd
    s = v if isinstance(v, pd.Series) else pd.Series(v)
    if not (pd.api.types.is_datetime64_any_dtype(s.dtype) or pd.api.types.is_timedelta64_dtype(s.dtype)):
        try:
            t = _numeric(path, name, s)[0]
        except LogError as e:
            s = _parse_times(s, e)
        else:
            if not unit and _looks_like_days(t):
                fin = t[np.isfinite(t)]
                raise LogError(f"{path}: time column {name!r} holds {float(fin[0])!r}, {float(fin[1])!r}, ...: "
                               f"spreadsheet (Excel) serial day numbers, a sample every "
                               f"{np.median(np.diff(fin)) * 86400:.4g} s? Declare the unit, days: a '{name}[d]' "
                               f"header (a 'd' in a row of units, or the channel map's [time] unit = \"d\"); "
                               f"'{name}[s]' if they are seconds")
            try:
                scale, offset = converter(unit, "s", f"{path}: time column {name!r}")
            except UnitError as e:
                raise LogError(str(e)) from None
            return t * scale + offset, {}
    x = pd.Index(s)
    if not len(x):
        return np.zeros(0), {}
    start = {"start_time": x[0].isoformat()} if isinstance(x, pd.DatetimeIndex) and not pd.isna(x[0]) else {}
    t = np.asarray((x - x[0]).total_seconds(), dtype=np.float64)
    if isinstance(x, pd.TimedeltaIndex) and x.min() >= pd.Timedelta(0) and x.max() < pd.Timedelta(days=1):
        t = _past_midnight(t)
    return t, start


def _looks_like_days(t) -> bool:
    """Whether numbers of a time column look like spreadsheet serial day numbers (Excel's days
    from 1899-12-30: 20000 to 80000 is 1954 to 2119) a sample every 1e-8 to 1e-4 days (0.9 ms to
    8.6 s): as seconds they would be a log sampled at 10 kHz or faster, 5.5 h or more from its
    start."""
    fin = t[np.isfinite(t)]
    return fin.size > 1 and 2e4 <= fin.min() and fin.max() <= 8e4 and 1e-8 <= np.median(np.diff(fin)) <= 1e-4


def _past_midnight(t):
    """Seconds (n,) of times of day (``23:59:59.990``, ``00:00:00.005``) continued past midnight:
    each step back by nearly a day (the next step within an hour of midnight) adds a day to the
    samples after it."""
    step = np.diff(t)
    wrap = (step < 0) & (step + 86400.0 > 0) & (step + 86400.0 < 3600.0)
    return t + 86400.0 * np.r_[0, np.cumsum(wrap)] if wrap.any() else t


def _parse_times(s, err: LogError):
    """Text (or objects) of a time column that are not numbers as date-times or durations; ``err``
    (:func:`_numeric`'s) for a number with a decimal comma (``0,015`` is no duration of 15 ns)."""
    import pandas as pd
    if s.astype(str).str.strip().str.fullmatch(_COMMA_NUMBER).any():
        raise err
    for parse in (lambda x: pd.to_datetime(x, format="ISO8601"),             # naive or one time zone
                  lambda x: pd.to_datetime(x, format="ISO8601", utc=True),   # mixed offsets
                  pd.to_timedelta):
        try:
            with warnings.catch_warnings():   # pandas 2: mixed offsets give objects and a warning
                warnings.simplefilter("ignore", FutureWarning)
                out = parse(s)
        except (TypeError, ValueError):
            continue
        if pd.api.types.is_datetime64_any_dtype(out.dtype) or pd.api.types.is_timedelta64_dtype(out.dtype):
            return out
    raise LogError(f"{err}, and the column is not ISO 8601 date-times or durations either") from None


def _from_columns(path, names, units, data, time=None, time_unit="", keep=None) -> Log:
    """The Log of named columns: ``names[i]`` (without unit), ``units[i]`` ("" undeclared),
    ``data[i]`` one value per sample (numbers, numeric text; for the time column also date-times
    or durations). ``time``: the time column (default: found by :data:`TIME_NAMES`) and
    ``time_unit`` (a channel map's); ``keep``: the columns to read -> where a channel map names
    them (default all; the others are dropped unread). Columns ``truth.<name>`` are truth
    channels. Without ``keep``, a column mostly of text, and a name used by columns of different
    values, are left out (``attrs["left_out"]``: name -> why; the copies of a column of equal
    values are one column). LogError on a missing or ambiguous time column, duplicate names kept
    (the time, a channel map's), non-numeric values in a kept column, a column of another length."""
    time = time or _find_time(path, names)
    if time is None:
        raise LogError(f"{path}: no 'time' column (one named {', '.join(TIME_NAMES)} in any case, "
                       f"or a channel map's [time] column; columns: {', '.join(map(repr, names))})")
    if time not in names:
        raise LogError(f"{path}: no time column {time!r} (columns: {', '.join(map(repr, names))})")
    missing = [c for c in keep or {} if c not in names]
    if missing:
        raise _missing(path, missing[0], keep[missing[0]], names)
    wanted = [i for i, n in enumerate(names) if keep is None or n in keep or n == time]
    dup = sorted({names[i] for i in wanted if names.count(names[i]) > 1})
    if dup and (keep is not None or time in dup):
        raise LogError(f"{path}: duplicate column(s) {dup}: which one to use is ambiguous")
    it = names.index(time)
    seconds, attrs = _seconds(path, time, _declared(units[it], time_unit, f"{path}: time column {time!r}"),
                              _vector(path, time, data[it]))
    chans, cunits, truth, tunits = {}, {}, {}, {}
    for i in wanted:
        if i == it:
            continue
        try:
            v, n_text = _numeric(path, names[i], _vector(path, names[i], data[i]), text_as_missing=True)
        except LogError as e:
            if keep is not None:
                raise
            # a text column (flight phase, status) that no channel map asked for: left out; a
            # channel the estimator needs is then refused as text by Log.require
            attrs.setdefault("left_out", {})[names[i]] = str(e)
            continue
        if n_text:
            attrs.setdefault("non_numeric", {})[names[i]] = n_text
        if v.size != seconds.size:
            raise LogError(f"{path}: column {names[i]!r} has {v.size} samples, "
                           f"the time column {seconds.size}")
        name, d, u = ((names[i][6:], truth, tunits) if names[i].startswith("truth.")
                      else (names[i], chans, cunits))
        if name in d and not (units[i] == u[name] and np.array_equal(v, d[name], equal_nan=True)):
            attrs.setdefault("left_out", {})[names[i]] = (
                f"{path}: duplicate column {names[i]!r}: its copies differ, which one to use is ambiguous")
        d[name], u[name] = v, units[i]
    for n in set(dup) & set(attrs.get("left_out", ())):    # a copy of text or of other values
        for d in (chans, cunits, truth, tunits):
            d.pop(n[6:] if n.startswith("truth.") else n, None)
    seconds = _reorder_rows(path, seconds, chans, truth, attrs)
    seconds = _drop_repeated_rows(path, seconds, chans, truth, attrs)
    check_time(path, seconds)
    return Log(seconds, chans, cunits, truth, tunits, attrs, path)


#: rows a logger may have written out of time order: each at most this many rows from its place
REORDER_ROWS = 8


def _reorder_rows(path, seconds, chans, truth, attrs):
    """Rows written a little out of time order (a logger merging buffers): sorted by time when
    none is more than :data:`REORDER_ROWS` rows from its place (counted in
    ``attrs["reordered_rows"]``, a PwlWarning names the first); the time column sorted. Farther
    (a clock that restarted, two logs in one) is left for :func:`check_time` to refuse."""
    back = np.flatnonzero(np.diff(seconds) < 0)
    if not back.size:
        return seconds
    order = np.argsort(seconds, kind="stable")
    if np.abs(order - np.arange(seconds.size)).max() > REORDER_ROWS:
        return seconds
    for d in (chans, truth):
        for k in d:
            d[k] = d[k][order]
    attrs["reordered_rows"] = int(back.size)
    warnings.warn(PwlWarning(f"{path}: {back.size} row(s) out of time order put in order (the first at sample "
                             f"{back[0] + 1}, time {float(seconds[back[0] + 1])!r} after {float(seconds[back[0]])!r})"),
                  stacklevel=4)
    return seconds[order]


def _drop_repeated_rows(path, seconds, chans, truth, attrs):
    """A logger that wrote a row twice (same time, every value the same or missing in both):
    the copies are dropped (counted in ``attrs["repeated_rows"]``, a PwlWarning names the first);
    the time column without them. Rows at one time with different values are left for
    :func:`check_time` to refuse."""
    same = np.flatnonzero(np.diff(seconds) == 0) + 1
    if not same.size:
        return seconds
    for d in (chans, truth):
        for v in d.values():
            a, b = v[same], v[same - 1]
            same = same[(a == b) | (np.isnan(a) & np.isnan(b))]
    if not same.size:
        return seconds
    keep = np.ones(seconds.size, dtype=bool)
    keep[same] = False
    for d in (chans, truth):
        for k in d:
            d[k] = d[k][keep]
    attrs["repeated_rows"] = int(same.size)
    warnings.warn(PwlWarning(f"{path}: {same.size} repeated row(s) dropped (the same time and values as the "
                             f"row before; the first at sample {same[0]}, time {float(seconds[same[0]])!r})"), stacklevel=4)
    return seconds[keep]


def _select(cmap) -> dict:
    """_from_columns' time, time_unit and keep for a channel map (none: every column)."""
    return {} if cmap is None else {"time": cmap.time, "time_unit": cmap.time_unit, "keep": cmap.columns()}


# ---- formats ------------------------------------------------------------------------------------
def _from_frame(path, df, cmap, names=None) -> Log:
    """A Log of a pandas DataFrame (``names``: the header cells when pandas renamed duplicates).
    The index is a column too when it is named (``df.set_index("time")``) or holds date-times or
    durations; the latter is the time when no column is."""
    import pandas as pd
    heads = [_split_header(str(c)) for c in (names or df.columns)]
    names, units = [n for n, _ in heads], [u for _, u in heads]
    data = [df.iloc[:, j] for j in range(df.shape[1])]
    idx, sel = df.index, _select(cmap)
    if idx.name is not None or isinstance(idx, (pd.DatetimeIndex, pd.TimedeltaIndex)):
        name, unit = _split_header(str(idx.name if idx.name is not None else "index"))
        names, units, data = [name] + names, [unit] + units, [idx.to_series()] + data
        if not sel.get("time") and _find_time(path, names) is None:
            sel["time"] = name
    return _from_columns(path, names, units, data, **sel)


def _read_csv(path, cmap) -> Log:
    """A log of delimited text (:func:`csv_frame`)."""
    df, cells = csv_frame(path)
    return _from_frame(path, df, cmap, names=cells)


def csv_frame(path):
    """(DataFrame, header cells) of delimited text through pandas: separator sniffed from the
    header (comma, semicolon, tab, else runs of spaces); decimal comma or point (:func:`_decimal`); UTF-8, UTF-16 with a
    byte-order mark or cp1252 (:func:`_encoding`); empty cells NaN. Leading ``#`` comment lines
    and blank lines are skipped; a row of units under the header (``rpm, K, kPa, ...``: no cell a
    number) declares the units (:func:`_units_of_row`); rows that repeat the header (files joined
    end to end) are left out (:func:`_without_repeated_header`). Compressed files
    (:data:`_COMPRESSED`) are read as they are."""
    import pandas as pd
    encoding = _encoding(path)
    with _open_text(path, encoding) as fh:
        lines = [fh.readline() for _ in range(64)]
    skip = 0
    while skip < len(lines) and lines[skip] and (not lines[skip].strip() or lines[skip].lstrip().startswith("#")):
        skip += 1
    header, first = (lines[skip:] + ["", ""])[:2]
    if not header.strip():
        raise LogError(f"{path}: the file is empty")
    sep = max(",;\t", key=header.count)
    if not header.count(sep):
        sep = r"\s+" if len(header.split()) > 1 else sep
    def split(line):
        line = line.rstrip("\r\n")
        return line.split() if sep == r"\s+" else next(csv.reader([line], delimiter=sep), [])
    cells = split(header)
    again = [cells, split(first)]           # the header and the line under it, as a file joined on would repeat them
    unit_row = _unit_row(split(first), cells)
    skiprows = list(range(skip)) + ([skip + 1] if unit_row else [])
    if unit_row:
        cells = [c if _split_header(c)[1] or not u.strip() else f"{c.strip()}[{u.strip()}]"
                 for c, u in zip(cells, _units_of_row(path, skip + 2, cells, unit_row))]
    sample = pd.Series([c for line in lines[skip + 1 + bool(unit_row):] for c in split(line)], dtype=object)

    def read(decimal):
        return pd.read_csv(path, sep=sep, decimal=decimal, index_col=False, encoding=encoding,
                           skiprows=skiprows or None, compression=_COMPRESSED.get(os.path.splitext(path.lower())[1]),
                           **_EXACT_FLOATS)
    with warnings.catch_warnings():
        warnings.simplefilter("error", pd.errors.ParserWarning)   # pandas drops the extra fields
        try:
            decimal = _decimal(sample, sep)
            df = read(decimal)
            if decimal == "." and _decimal(_text_cells(df), sep) == ",":    # none in the first rows
                decimal, df = ",", read(",")
        except pd.errors.ParserWarning:
            raise LogError(f"{path}: row {len(skiprows) + 2} has more fields than the header ({len(cells)})") from None
    if len(cells) != df.shape[1]:
        raise LogError(f"{path}: the header has {len(cells)} fields, pandas read {df.shape[1]} columns")
    df = _without_repeated_header(path, df, again[: 1 + bool(unit_row)])
    if len(cells) > 1 and df.shape[0] and df.iloc[:, -1].isna().any():     # short rows read as NaN
        _check_row_lengths(path, sep, len(cells), skip=len(skiprows) + 1, encoding=encoding)
    if decimal == ",":
        _points(df)
    return df, cells


def _without_repeated_header(path, df, heads: list[list[str]]):
    """``df`` without its rows that repeat the header (or the row of units under it) cell for cell:
    files joined end to end (``cat a.csv b.csv``), each with its header; named in a PwlWarning.
    Their columns are then text, converted as numbers later (:func:`_numeric`)."""
    import pandas as pd
    text = [j for j in range(df.shape[1]) if not pd.api.types.is_numeric_dtype(df.dtypes.iloc[j])]
    if len(text) < df.shape[1] or not df.shape[0]:
        return df                            # (a numeric column holds no header cell)
    cells = [df.iloc[:, j].astype(str).str.strip() for j in range(df.shape[1])]
    hit = np.zeros(df.shape[0], dtype=bool)
    for head in heads:
        if len(head) == df.shape[1]:
            hit |= np.logical_and.reduce([(c == h.strip()).to_numpy() for c, h in zip(cells, head)])
    if not hit.any():
        return df
    warnings.warn(PwlWarning(f"{path}: {int(hit.sum())} row(s) repeat the header or its units (the first at sample "
                             f"{int(np.flatnonzero(hit)[0])}): files joined end to end? Read past them"), stacklevel=4)
    return df[~hit].reset_index(drop=True)


#: a number written with a decimal comma (``0,015``, ``-2,5E3``), or with thousands separators
#: (``1,000``, ``12,345.5``: the first group 1 to 3 digits, not 0), or with Fortran's D exponent
#: (``1.0D+03``), matched on a whole cell
_COMMA_NUMBER = re.compile(r"[+-]?\d*,\d+(?:[eE][+-]?\d+)?")
_THOUSANDS = re.compile(r"[+-]?[1-9]\d{0,2}(?:,\d{3})+(?:\.\d*)?")
_FORTRAN = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)[dD][+-]?\d+")
#: the start of a date (2024-05-01, 01/05/2024, 1.5.2024) or a time of day (10:00) in a cell
_DATE_OR_TIME = re.compile(r"\d{4}-\d\d-\d\d|\d{1,2}[./]\d{1,2}[./]\d{2,4}|\d{1,2}:\d\d")


def _decimal(cells, sep: str) -> str:
    """The decimal mark of delimited text whose cells (a pandas Series of str; NaN ignored) are
    ``cells``: "," when one of them is a number with a decimal comma (:data:`_COMMA_NUMBER`; in a
    ","-separated file, where such a number is quoted, not one that could be a number with
    thousands separators: ``"1,000"``), else ".". """
    s = cells.dropna().astype(str).str.strip()
    hit = s.str.fullmatch(_COMMA_NUMBER)
    if sep == ",":
        hit &= ~s.str.fullmatch(_THOUSANDS)
    return "," if hit.any() else "."


def _text_cells(df):
    """Every cell of ``df``'s text (not numeric) columns, as one Series."""
    import pandas as pd
    cols = [df.iloc[:, j] for j in range(df.shape[1]) if not pd.api.types.is_numeric_dtype(df.iloc[:, j].dtype)]
    return pd.concat(cols, ignore_index=True).astype(object) if cols else pd.Series([], dtype=object)


def _points(df) -> None:
    """In place: the numbers with a decimal comma in ``df``'s text columns (a decimal-comma file's
    column that pandas left as text for a cell of text among its numbers: ``ERR``) written with a
    decimal point, for :func:`_numeric`."""
    import pandas as pd
    for j in range(df.shape[1]):
        s = df.iloc[:, j]
        if not pd.api.types.is_numeric_dtype(s.dtype):
            hit = s.astype(object).astype(str).str.strip().str.fullmatch(_COMMA_NUMBER) & s.notna()
            if hit.any():
                df.isetitem(j, s.astype(object).where(~hit, s.astype(str).str.replace(",", ".", regex=False)))


def _units_of_row(path, row: int, header: list[str], units: list[str]) -> list[str]:
    """The units a row of units (row number ``row`` of the file) declares for the columns
    ``header``: as written when at least half of its cells are units pwl knows (an unknown one is
    then refused, naming it and the known units, where the model reads that channel: as in a
    ``name[unit]`` header); else the row holds no units ("EU", "eng units", a description) and
    every unknown cell is undeclared, named in a PwlWarning."""
    from .units import known
    odd = {c.strip(): u for c, u in zip(header, units) if u and known(u) is None}
    if not odd or 2 * len(odd) <= sum(1 for u in units if u):
        return units
    warnings.warn(PwlWarning(f"{path}: row {row} is read as the columns' units; not units pwl knows, "
                             f"so taken as undeclared: " + ", ".join(f"{c} {u!r}" for c, u in odd.items())),
                  stacklevel=4)
    return ["" if known(u) is None else u for u in units]


def _unit_row(row: list[str], header: list[str]) -> list[str] | None:
    """``row``'s cells (stripped of brackets) if it is a row of units under ``header``: as many
    cells, none a number (in any way :func:`_numeric` reads one), a date or a time of day; else
    None."""
    if len(row) != len(header):
        return None
    cells = [c.strip().strip("[]()") for c in row]
    full = [c for c in cells if c]
    def number(c):
        try:
            float(c.replace(",", "."))
            return True
        except ValueError:
            return bool(_FORTRAN.fullmatch(c) or _THOUSANDS.fullmatch(c) or _DATE_OR_TIME.match(c))
    if not full or any(number(c) for c in full):
        return None
    return cells


def _raw(path):
    """The file's bytes, decompressed per :data:`_COMPRESSED` (a binary file object)."""
    kind = _COMPRESSED.get(os.path.splitext(path.lower())[1])
    if kind == "zip":
        import zipfile
        z = zipfile.ZipFile(path)
        names = [n for n in z.namelist() if not n.endswith("/")]
        if len(names) != 1:
            raise LogError(f"{path}: a zip archive holds {len(names)} files, a compressed log one")
        return z.open(names[0])
    if kind:
        import bz2
        import gzip
        import lzma
        return {"gzip": gzip.open, "bz2": bz2.open, "xz": lzma.open}[kind](path, "rb")
    return open(path, "rb")


def _encoding(path) -> str:
    """A text log's encoding: "utf-16" when it starts with UTF-16's byte-order mark; "cp1252" (the
    Windows code page Excel saves CSV in) when its first 64 KiB are not UTF-8 but are cp1252 (a
    header's ``°C`` or ``µs``: the numbers are ASCII either way); else "utf-8"."""
    import codecs
    with _raw(path) as raw:
        head = raw.read(1 << 16)
    if head[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return "utf-16"
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)   # a character cut at the end is fine
    except UnicodeDecodeError:
        try:
            head.decode("cp1252")
            return "cp1252"
        except UnicodeDecodeError:
            pass
    return "utf-8"


def _open_text(path, encoding: str = "utf-8"):
    """The file as text (a byte-order mark dropped), decompressed per :data:`_COMPRESSED`."""
    import io
    return io.TextIOWrapper(_raw(path), encoding="utf-8-sig" if encoding == "utf-8" else encoding, newline="")


#: pandas < 3 parses floats to within an ulp unless asked for the exact "round_trip" parser (the
#: default and the only one from pandas 3 on); a CSV log must read back bit for bit
_EXACT_FLOATS = {"float_precision": "round_trip"} if int(version("pandas").split(".")[0]) < 3 else {}


def _check_row_lengths(path, sep, k, skip: int = 1, encoding: str = "utf-8") -> None:
    """LogError naming the first non-blank row after the first ``skip`` lines (header, units,
    comments) with fewer than ``k`` fields (pandas fills them with NaN). Fields are counted by
    separators; a quoted separator counts too, so this runs only when the last column has
    missing values. Space-separated text cannot have an empty cell: a row with fewer fields would
    shift its values into the wrong columns."""
    with _open_text(path, encoding) as fh:
        if sep == r"\s+":
            for row, line in enumerate(fh):
                if row >= skip and line.strip() and len(line.split()) < k:
                    raise LogError(f"{path}: row {row + 1} has {len(line.split())} field(s), the header has "
                                   f"{k} (space-separated text cannot have an empty cell: write NaN)")
            return
        b = np.frombuffer(fh.buffer.read() if encoding != "utf-16" else fh.read().encode(), dtype=np.uint8)
    ends = np.flatnonzero(b == 10)
    if b.size and b[-1] != 10:
        ends = np.append(ends, b.size)
    starts = np.r_[0, ends[:-1] + 1]
    seps = np.flatnonzero(b == ord(sep))
    fields = np.searchsorted(seps, ends) - np.searchsorted(seps, starts) + 1
    blank = (ends - starts) - (b[np.maximum(ends - 1, 0)] == 13) <= 0
    short = np.flatnonzero((fields < k) & ~blank & (np.arange(fields.size) >= skip))
    if short.size:
        raise LogError(f"{path}: row {short[0] + 1} has {fields[short[0]]} field(s), the header has {k}")


def _read_parquet(path, cmap) -> Log:
    return _from_frame(path, parquet_frame(path), cmap)


def parquet_frame(path):
    """The DataFrame of a Parquet file (pyarrow; a LogError saying how to install it)."""
    try:
        importlib.import_module("pyarrow")
    except ImportError:
        raise LogError(f"{path}: reading Parquet needs pyarrow: pip install 'pwl[parquet]'") from None
    import pandas as pd
    return pd.read_parquet(path, engine="pyarrow")


def excel_frame(path):
    """(DataFrame, header cells) of an Excel workbook's first sheet (``.xlsx``, ``.xlsm``; openpyxl,
    a LogError saying how to install it): the first non-empty row the header, a row of units under
    it read as :func:`csv_frame` reads one, empty rows skipped, cells as Excel holds them (numbers,
    date-times, text)."""
    try:
        importlib.import_module("openpyxl")
    except ImportError:
        raise LogError(f"{path}: reading an Excel workbook needs openpyxl: pip install 'pwl[excel]' "
                       "(or save the sheet as CSV)") from None
    import pandas as pd
    raw = pd.read_excel(path, sheet_name=0, header=None, engine="openpyxl").dropna(how="all")
    if raw.empty:
        raise LogError(f"{path}: the first sheet is empty")
    text = [["" if pd.isna(c) else str(c) for c in row] for row in raw.iloc[:2].itertuples(index=False)]
    cells = text[0]
    units = _unit_row(text[1], cells) if len(text) > 1 else None
    if units:
        cells = [c if _split_header(c)[1] or not u.strip() else f"{c.strip()}[{u.strip()}]"
                 for c, u in zip(cells, _units_of_row(path, 2, cells, units))]
    df = raw.iloc[1 + bool(units):].reset_index(drop=True)
    df.columns = range(df.shape[1])
    return df.infer_objects(), cells


#: MATLAB variables that are not data
_MAT_SKIP = ("__header__", "__version__", "__globals__", "#refs#", "#subsystem#")


def _read_mat(path, cmap) -> Log:
    """MAT file: v7.3 (HDF5) through h5py, older versions through scipy.io.loadmat. One vector
    variable per column, or a struct of them (its fields read as variables: :func:`_mat_structs`),
    or a 2-D matrix with a cell array of its column names (:func:`_mat_matrix`); text and scalar
    variables become attributes; units from an optional ``units`` variable (:func:`_mat_units`)."""
    if h5py.is_hdf5(path):
        with h5py.File(path, "r") as f:
            variables = {k: _mat73(f, f[k]) for k in f if k not in _MAT_SKIP}
    else:
        from scipy.io import loadmat
        variables = {k: v for k, v in loadmat(path, simplify_cells=True).items() if k not in _MAT_SKIP}
    units = variables.pop("units", {})
    variables = _mat_matrix(_mat_structs(path, variables))
    attrs, names, data = {}, [], []
    for k, v in variables.items():
        if isinstance(v, str) or (isinstance(v, np.ndarray) and v.dtype.kind == "U"):
            attrs[k] = _mat_text(v)
        elif np.ndim(v) == 0 or (isinstance(v, np.ndarray) and v.size == 1 and v.dtype.kind in "biuf"):
            attrs[k] = v.item() if isinstance(v, np.ndarray) else v
        else:
            names.append(k)
            data.append(v)
    units = _mat_units(path, units, names)
    log = _from_columns(path, names, [units.get(k, "") for k in names], data, **_select(cmap))
    log.attrs.update({k: v for k, v in attrs.items() if k not in log.attrs})
    return log


def _mat_vector(v) -> bool:
    """Whether a MAT variable is a numeric vector or matrix (more than one number)."""
    return isinstance(v, np.ndarray) and v.dtype.kind in "biuf" and v.size > 1


def _mat_structs(path, variables: dict) -> dict:
    """``variables`` with each struct replaced by its fields (``flight.Nf`` read as ``Nf``; a
    variable of the same name wins): the log's one struct of vectors beside text or scalars
    (``engine``), or a struct of those beside the vectors. LogError for two structs that hold
    vectors: which one is the log is ambiguous."""
    structs = {k: v for k, v in variables.items() if isinstance(v, dict)}
    tables = [k for k, v in structs.items() if any(_mat_vector(x) for x in v.values())]
    if len(tables) > 1:
        raise LogError(f"{path}: structs {', '.join(map(repr, tables))} each hold vectors: which one is the log is "
                       "ambiguous; save one log per MAT file")
    out = {k: v for k, v in variables.items() if k not in structs}
    for v in structs.values():
        out.update({k: x for k, x in v.items() if k not in out})
    return out


def _mat_matrix(variables: dict) -> dict:
    """``variables`` with a 2-D numeric matrix (``data``, n x k or k x n) split into its columns,
    named by the one cell or char array beside it of as many names as the matrix has columns
    (or rows) (``names = {'time', 'Wf', ...}``); the matrix and the names as they are when no
    such array, or more than one, is found."""
    lists = {k: [str(x).strip() for x in v.ravel()] for k, v in variables.items() if isinstance(v, np.ndarray)
             and v.size > 1 and v.dtype.kind in "OU" and all(isinstance(x, str) for x in v.ravel())}
    for m, a in list(variables.items()):
        if not (_mat_vector(a) and a.ndim == 2 and min(a.shape) > 1):
            continue
        fit = [k for k, n in lists.items() if len(n) in a.shape and k in variables]
        if len(fit) != 1:
            continue
        names = lists[fit[0]]
        cols = a if a.shape[1] == len(names) else a.T
        del variables[m], variables[fit[0]]
        variables.update({n: cols[:, j] for j, n in enumerate(names) if n not in variables})
    return variables


def _mat_units(path, units, names) -> dict:
    """Column name -> unit of a MAT file's ``units`` variable: a struct (``units.Wf = 'kg/s'``),
    or a cell array of {name, unit} pairs, k x 2 (``{'Wf','kg/s'; ...}``) or 2 x k: of the two,
    the one whose name cells name more of the columns ``names``. LogError when neither names one."""
    if isinstance(units, dict):
        return {k: _mat_text(u) for k, u in units.items()}
    a = np.asarray(units, dtype=object)
    a = a.reshape(1, 2) if a.shape == (2,) else a
    ways = [w for w in ((a if a.shape[1:] == (2,) else None), (a.T if a.shape[:1] == (2,) and a.ndim == 2 else None))
            if w is not None]
    named = [sum(_mat_text(n) in names for n in w[:, 0]) for w in ways]
    if not ways or max(named) == 0:
        raise LogError(f"{path}: variable 'units' (shape {a.shape}) pairs no column name with a unit: write it "
                       "as a k x 2 cell {'Wf', 'kg/s'; ...} or a struct (units.Wf = 'kg/s')")
    return {_mat_text(n): _mat_text(u) for n, u in ways[int(np.argmax(named))]}


def _mat_text(v) -> str:
    """MATLAB text as loadmat gives it (str, or an empty char array) as a str."""
    if isinstance(v, np.ndarray):
        return "".join(v.ravel().tolist())
    return str(v)


def _mat73(f, obj):
    """A v7.3 MAT variable: struct -> dict, char -> str (a char matrix of several rows, ``char('time',
    'Wf')``, -> an array of its rows), cell -> object array, numbers -> array. HDF5 holds MATLAB's
    arrays transposed (column-major)."""
    cls = attr_str(obj, "MATLAB_class", "")
    if isinstance(obj, h5py.Group):
        return {k: _mat73(f, obj[k]) for k in obj}
    if obj.attrs.get("MATLAB_empty", 0):
        return "" if cls == "char" else np.zeros(0)
    v = obj[()]
    if cls == "char":
        rows = ["".join(map(chr, r)) for r in np.atleast_2d(v.T)]
        return rows[0] if len(rows) == 1 else np.array(rows)
    if cls == "cell":
        return np.vectorize(lambda r: _mat73(f, f[r]), otypes=[object])(v.T)
    return v.T


def _read_h5_columns(path, cmap) -> Log:
    """An HDF5 file of another layout through a channel map: its columns (:func:`_h5_columns`)
    named by path (``data/FuelFlow``), units from a ``unit`` or ``units`` attribute; the time from
    the map's [time] column, else the column named by :data:`TIME_NAMES` beside the channels."""
    with h5py.File(path, "r") as f:
        have = _h5_columns(f)
        for col, where in cmap.columns().items():
            if col.strip("/") not in have:
                raise LogError(f"{path}: no dataset {col!r} ({where}; a column is a 1-D dataset, a field of a "
                               "compound dataset or a column of a 2-D dataset with a 'names' attribute)")
        cols = sorted(cmap.columns())
        time = cmap.time
        if not time:
            groups = {c.strip("/").rpartition("/")[0] for c in cmap.columns()}
            near = [c for c in have if c.rpartition("/")[0] in groups]
            found = _find_time(path, [c.rpartition("/")[2] for c in near])
            time = next((c for c in near if found and c.rpartition("/")[2] == found), None)
        cols += [time] if time and time not in cols and time.strip("/") in have else []
        read = {}
        def value(c):
            d, key, unit = have[c.strip("/")]
            if d.name not in read:
                read[d.name] = d.asstr()[()] if h5py.check_string_dtype(d.dtype) else d[()]
            v = read[d.name]
            if key is None or isinstance(key, str):
                return (v if key is None else v[key]), unit
            return (v[:, key[1]] if key[0] == 1 else v[key[1]]), unit
        data, units = zip(*(value(c) for c in cols)) if cols else ((), ())
    return _from_columns(path, cols, list(units), list(data), time=time, time_unit=cmap.time_unit)


def _h5_columns(f) -> dict:
    """The columns of an HDF5 file ``f`` of another layout: path -> (dataset, key, unit). Every
    dataset (key None; unit from its ``unit`` or ``units`` attribute); every field of a 1-D
    compound dataset (``records/Nf``: key the field name); every column of a 2-D dataset with a
    ``names`` attribute of as many names as it has columns (``data/Nf``: key (1, j)) or rows (key
    (0, j)). A compound or 2-D dataset's units: a ``units`` attribute of one unit per name."""
    out = {}
    def visit(name, d):
        if not isinstance(d, h5py.Dataset):
            return
        if d.ndim == 1 and d.dtype.names:
            names = list(d.dtype.names)
            keys = names
        elif d.ndim == 2 and "names" in d.attrs and len(np.ravel(d.attrs["names"])) in d.shape:
            names = as_strings(d.attrs["names"])
            axis = 1 if len(names) == d.shape[1] else 0
            keys = [(axis, j) for j in range(len(names))]
        else:
            out[name] = (d, None, attr_str(d, "unit", "") or attr_str(d, "units", ""))
            return
        units = as_strings(d.attrs.get("units", []))
        units = units if len(units) == len(names) else [""] * len(names)
        out.update({f"{name}/{n}": (d, k, u) for n, k, u in zip(names, keys, units)})
    f.visititems(visit)
    return out


def _reader(path):
    """(format name, reader) of a log file: by extension (:data:`_READERS`; a CSV compressed as
    ``.gz``, ``.bz2``, ``.xz`` or ``.zip`` too); ``.h5``, ``.hdf5`` HDF5; any other extension
    (``.txt``, ``.dat``, none) HDF5 when the file has HDF5's signature, else delimited text."""
    stem, ext = os.path.splitext(path.lower())
    if ext in _UNREAD:
        raise LogError(f"{path}: {_UNREAD[ext]} is not a log format pwl reads (HDF5, CSV or other "
                       "delimited text, Parquet, MAT); read it with pandas and pass the DataFrame "
                       "(read_log(df), Estimator.run(df))")
    if ext in _COMPRESSED:
        return "compressed CSV", _read_csv
    if ext in _READERS:
        return _READERS[ext]
    if ext in (".h5", ".hdf5", ".he5", ".nc") or h5py.is_hdf5(path):
        return "HDF5", _read_hdf5
    return "text (CSV)", _read_csv


#: formats people have logs in that pwl does not read itself (a DataFrame of them does)
_UNREAD = {".xlsx": "Excel", ".xls": "Excel", ".xlsm": "Excel", ".json": "JSON", ".feather": "Feather",
           ".pkl": "a pickle", ".pickle": "a pickle", ".ods": "OpenDocument"}

#: compressed text logs (pandas and the header sniffer decompress them)
_COMPRESSED = {".gz": "gzip", ".bz2": "bz2", ".xz": "xz", ".zip": "zip"}

#: file extension -> (format name, reader(path, channel map or None) -> Log); see :func:`_reader`
_READERS = {".csv": ("CSV", _read_csv), ".tsv": ("CSV", _read_csv),
            ".parquet": ("Parquet", _read_parquet), ".mat": ("MAT", _read_mat)}

#: the file name endings of logs that a folder walk (``pwl run FOLDER``) picks up
LOG_SUFFIXES = (".h5", ".hdf5", *_READERS, *(f".{t}{c}" for t in ("csv", "tsv") for c in _COMPRESSED))
