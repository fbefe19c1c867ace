"""Flight logs: the one definition of the log file format (HDF5 and CSV), writer and reader.

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
import json
import os
from dataclasses import dataclass, field

import h5py
import numpy as np

from .errors import PwlError
from .h5io import SealError, atomic_h5, attr_str, check_seal
from .units import UnitError, converter

FORMAT = "pwl-flight-log"
VERSION = 1


class LogError(PwlError, ValueError):
    """A log file that cannot be used; the message names the file and the channel."""


@dataclass
class Log:
    """A flight log in memory: time (n,), channels and truth as name -> float64 (n,) arrays."""

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
        """The sample interval (s): the ``dt`` attribute, else the median time step."""
        if "dt" in self.attrs:
            return float(self.attrs["dt"])
        return sample_interval(self.time)

    def require(self, names, units=None) -> np.ndarray:
        """Stack channels ``names`` into a C-contiguous (n, k) array, in ``units`` if given: a
        channel declared in another known unit of the same quantity is converted (``kPa`` to
        ``Pa``, ``degC`` to ``K``, ...; :mod:`pwl.units`), one without a declared unit is taken
        as it is.

        Raises :class:`LogError` naming the file and the missing channel, or the channel whose
        unit cannot be converted.
        """
        out = np.empty((len(self), len(names)))
        for j, name in enumerate(names):
            if name not in self.channels:
                raise LogError(f"{self.path}: channel {name!r} is missing "
                               f"(log has: {', '.join(sorted(self.channels))})")
            out[:, j] = self.channels[name]
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
    """Write ``log`` as HDF5 (atomically); ``.csv`` paths go to :func:`write_csv`.

    ``compact`` stores channels as float32 with shuffle + gzip (for shipped sample data: sensor
    values need no more than float32's 7 digits); the reader always returns float64.
    """
    if os.fspath(path).lower().endswith(".csv"):
        return write_csv(path, log)
    n = len(log)
    with atomic_h5(path) as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = VERSION
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
    (HDF5, CSV and Parquet readers raise many kinds on a damaged file)."""
    try:
        yield
    except SealError as e:
        raise LogError(str(e)) from None
    except PwlError:
        raise
    except Exception as e:
        raise LogError(f"{path}: {what} ({type(e).__name__}: {' '.join(str(e).split())})") from None


def read_log(path) -> Log:
    """Read an HDF5, CSV or Parquet log; raises :class:`LogError` naming the file on any defect."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise LogError(f"{path}: no such file")
    if path.lower().endswith(".csv"):
        with _named(path, "unreadable CSV log"):
            return _read_csv(path)
    if path.lower().endswith(".parquet"):
        with _named(path, "unreadable Parquet log"):
            return _read_parquet(path)
    head = read_header(path)
    log = read_rows(head, 0, len(head))
    with _named(path, "damaged log, cannot read /truth"), h5py.File(path, "r") as f:
        if "truth" in f:
            log.truth, log.truth_units = _read_group(f, "truth", len(head), path)
    return log


def read_header(path) -> Log:
    """An HDF5 log's time, channel units and attributes, validated, without channel data.

    With :func:`read_rows` this reads long logs in chunks with bounded memory.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise LogError(f"{path}: no such file")
    with _named(path, "not a readable HDF5 log"):
        check_seal(path)
        with h5py.File(path, "r") as f:
            fmt = attr_str(f, "format")
            if fmt != FORMAT:
                raise LogError(f"{path}: not a flight log (format attribute {fmt!r}, expected {FORMAT!r})")
            ver = int(f.attrs.get("format_version", -1))
            if ver > VERSION:
                raise LogError(f"{path}: flight-log format version {ver} is newer than this pwl reads ({VERSION})")
            if "time" not in f or "channels" not in f:
                raise LogError(f"{path}: /time or /channels is missing")
            time = np.asarray(f["time"][()], dtype=np.float64)
            units = {}
            for k, d in f["channels"].items():
                if d.shape != time.shape:
                    raise LogError(f"{path}: /channels/{k} has shape {d.shape}, expected {time.shape} like /time")
                units[k] = attr_str(d, "unit", "")
            attrs = {k: attr_str(f, k) for k in f.attrs if k not in ("format", "format_version")}
    check_time(path, time)
    return Log(time, {}, units, attrs=attrs, path=path)


def sample_interval(time) -> float:
    """The log's sample interval (s): the median time step (NaN for fewer than 2 samples)."""
    return float(np.median(np.diff(time))) if len(time) > 1 else float("nan")


def resample(log: Log, dt: float) -> Log:
    """The log on a uniform time grid of step ``dt`` (s) from its first sample, every channel and
    truth interpolated linearly (a NaN sample spoils its neighbours' interval only)."""
    t = log.time[0] + np.arange(int(np.floor((log.time[-1] - log.time[0]) / dt + 1e-9)) + 1) * dt
    def interp(d):
        return {k: np.interp(t, log.time, v) for k, v in d.items()}
    return Log(t, interp(log.channels), dict(log.units), interp(log.truth), dict(log.truth_units),
               {**log.attrs, "dt": dt, "resampled_from": sample_interval(log.time)}, log.path)


def check_time(path, time) -> None:
    """A log's time column must be non-empty, finite and strictly increasing (LogError naming the
    first bad sample otherwise): the filter's steps and the snapshots' windows rely on it."""
    if time.ndim != 1 or time.size == 0:
        raise LogError(f"{path}: the log is empty (no samples)")
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise LogError(f"{path}: time is not finite at sample {bad[0]} ({time[bad[0]]})")
    back = np.flatnonzero(np.diff(time) <= 0)
    if back.size:
        k = back[0] + 1
        raise LogError(f"{path}: time does not increase at sample {k} ({float(time[k - 1])!r} -> {float(time[k])!r})")


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
    cell = cell.strip()
    if cell.endswith("]") and "[" in cell:
        i = cell.index("[")
        return cell[:i].strip(), cell[i + 1:-1].strip()
    return cell, ""


def _from_columns(path, names, units, data) -> Log:
    if "time" not in names:
        raise LogError(f"{path}: no 'time' column")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise LogError(f"{path}: duplicate column(s) {dup}: which one to use is ambiguous")
    cols = dict(zip(names, data))
    cunits = dict(zip(names, units))
    time = cols.pop("time")
    cunits.pop("time")
    chans = {k: v for k, v in cols.items() if not k.startswith("truth.")}
    truth = {k[6:]: v for k, v in cols.items() if k.startswith("truth.")}
    check_time(path, time)
    return Log(time, chans, {k: cunits[k] for k in chans}, truth,
               {k[6:]: cunits[k] for k in cunits if k.startswith("truth.")}, {}, path)


def _read_csv(path) -> Log:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise LogError(f"{path}: the file is empty")
    names, units = zip(*[_split_header(c) for c in rows[0]])
    body = [r for r in rows[1:] if r]
    for i, r in enumerate(body):
        if len(r) != len(names):
            raise LogError(f"{path}: row {i + 2} has {len(r)} fields, header has {len(names)}")
    try:
        arr = np.array(body, dtype=np.float64).reshape(len(body), len(names))
    except ValueError as e:
        raise LogError(f"{path}: non-numeric value ({e})") from None
    return _from_columns(path, list(names), list(units), list(arr.T))


def _read_parquet(path) -> Log:
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise LogError(f"{path}: reading Parquet needs pyarrow (pip install pyarrow)") from None
    t = pq.read_table(path)
    names, units = zip(*[_split_header(c) for c in t.column_names])
    data = [np.asarray(t.column(i).to_numpy(), dtype=np.float64) for i in range(t.num_columns)]
    return _from_columns(path, list(names), list(units), data)
