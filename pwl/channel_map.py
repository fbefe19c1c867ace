"""Channel maps: a log's own column names and units -> the model's channel names (#15).

A small TOML file read with the standard library's tomllib::

    [time]                       # optional
    column = "Timestamp"         # default: the column named time, timestamp, datetime or t
    unit = "ms"                  # optional: s (default), ms, min, h, d; date-times need none

    [channels]                   # model channel = log column, with its unit if the log has none
    Wf = { column = "FuelFlow_lbs", unit = "lb/s" }
    T2 = { column = "TAT_C", unit = "degC" }
    Nf = "N1"                    # a column name alone: the unit is the log's (or undeclared)
    Nc = { column = "N2_pct", unit = "rpm", scale = 145.5 }   # N2 in % of 14,550 rpm

A channel's ``scale`` and ``offset`` (numbers) make it column * scale + offset, in the map's
``unit``: speeds logged in percent of a reference speed, counts, volts. The column's own unit,
if the log declares one, is then not used. Its ``lag`` (seconds, negative: early) is how late the
column is logged (a bus's or a logger's latency): the channel at time t is the column's value at
t + lag, linearly interpolated; the last lag seconds are then missing (NaN). The run warns when
the inlet pressure runs behind or ahead of altitude and Mach (:mod:`pwl.airdata`)::

    P2 = { column = "P2", lag = 1.0 }     # P2 logged 1 s late

Every channel the model reads is listed: columns the map does not name (and truth channels) are
dropped, so a log's other columns (text, status words) never stop a run. A unit is any symbol of
:mod:`pwl.units`; the estimator converts it to the database's (``Log.require``). For HDF5 files of
other layouts a column is a dataset path (``data/FuelFlow``). Errors name the TOML file and key.
"""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass

import numpy as np

from .logs import Log, LogError, _declared, _missing
from .units import UNITS, known


class ChannelMapError(LogError):
    """A channel-map file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class ChannelMap:
    """How a log names and scales its channels: log columns -> the model's channel names.

    Usually read from a TOML file with :meth:`load` (module docstring) and given to
    :func:`pwl.read_log` or ``Estimator(..., channel_map=)``.

    Parameters
    ----------
    channels : dict
        Model channel -> (log column, unit, scale, offset, lag): the channel is column * scale +
        offset in ``unit`` ("" for the log's own declaration; with a scale or offset other than
        (1, 0), for none), logged ``lag`` s late; a unit is a symbol of :mod:`pwl.units`.
    time : str
        The log's time column ("" to find it by name: time, timestamp, datetime or t).
    time_unit : str
        Its unit: s, ms, min, h, d ("" for s; date-times need none).
    path : str
        The TOML file (named in errors).
    """

    channels: dict[str, tuple[str, str, float, float]]
    time: str = ""
    time_unit: str = ""
    path: str = "<channel map>"

    @classmethod
    def load(cls, path) -> "ChannelMap":
        """Read and check a channel-map TOML file.

        Parameters
        ----------
        path : str or path-like
            The TOML file: ``[time]`` (optional) and ``[channels]``.

        Returns
        -------
        ChannelMap

        Raises
        ------
        ChannelMapError
            No such file, not TOML, an unknown key, a unit pwl does not know, an empty
            ``[channels]``; naming the file and the key.
        """
        path = os.fspath(path)
        try:
            with open(path, "rb") as fh:
                doc = tomllib.load(fh)
        except FileNotFoundError:
            raise ChannelMapError(f"{path}: no such file") from None
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            raise ChannelMapError(f"{path}: not a readable TOML file ({e})") from None
        return cls.from_dict(doc, path)

    @classmethod
    def from_dict(cls, doc: dict, path: str = "<channel map>") -> "ChannelMap":
        """The map of a parsed TOML document ``doc``, checked: key types, known units."""
        def fail(key, msg):
            raise ChannelMapError(f"{path}: {key}: {msg}")

        for key in doc:
            if key not in ("time", "channels"):
                fail(key, "unknown key (a channel map has [time] and [channels])")
        time = doc.get("time", {})
        time = _entry({"column": time} if isinstance(time, str) else time, "[time]", ("column", "unit"), (), fail)
        if time.get("unit", "") and UNITS.get(known(time["unit"]), ("",))[0] != "time":
            fail("[time] unit", f"{time['unit']!r} is not a unit of time (s, ms, min, h, d)")
        chans = doc.get("channels")
        if not isinstance(chans, dict) or not chans:
            fail("[channels]", "missing or empty: a table of model channel = { column = ..., unit = ... }")
        channels = {}
        for name, spec in chans.items():
            key = f"[channels] {name}"
            e = _entry({"column": spec} if isinstance(spec, str) else spec, key, ("column", "unit"),
                       ("scale", "offset", "lag"), fail)
            if not e.get("column"):
                fail(key, "needs a non-empty column = \"...\" (the log's column)")
            if e.get("unit", "") and known(e["unit"]) is None:
                fail(f"{key} unit", f"{e['unit']!r} is not a unit pwl knows: {', '.join(UNITS)}")
            if e.get("scale", 1.0) == 0.0:
                fail(f"{key} scale", "must not be 0")
            channels[name] = (e["column"], e.get("unit", ""), float(e.get("scale", 1.0)), float(e.get("offset", 0.0)),
                              float(e.get("lag", 0.0)))
        return cls(channels, time.get("column", ""), time.get("unit", ""), path)

    def columns(self) -> dict[str, str]:
        """The log columns the map reads (the time column aside) -> where the map names them
        (``map.toml: [channels] Wf``), for error messages."""
        out = {}
        for name, (col, *_) in self.channels.items():
            out.setdefault(col, f"{self.path}: [channels] {name}")
        return out

    def apply(self, log: Log) -> Log:
        """The log with the model's channel names and units.

        Each mapped column is renamed (a column may feed several channels), scaled and shifted in
        time where the map says, its unit the map's or else the log's own; every other column and
        truth channel is dropped. The time stays
        as read (``read_log(path, channel_map=...)`` uses the map's [time] column while
        reading).

        Parameters
        ----------
        log : Log
            A log with the log's own column names.

        Returns
        -------
        Log
            Channels named as the model's (values as logged unless scaled, units declared; the
            estimator converts them), ``attrs["channel_map"]`` = the map's path.

        Raises
        ------
        LogError
            A mapped column the log does not have, or a log unit that differs from the map's
            (naming the log, the column and the map's key).
        """
        channels, units = {}, {}
        for name, (col, unit, scale, offset, lag) in self.channels.items():
            if col not in log.channels:
                raise _missing(log.path, col, f"{self.path}: [channels] {name}", sorted(log.channels))
            x = log.channels[col]
            if lag != 0.0:
                x = np.interp(log.time + lag, log.time, np.asarray(x, dtype=np.float64), left=np.nan, right=np.nan)
            if (scale, offset) != (1.0, 0.0):
                channels[name] = np.asarray(x, dtype=np.float64) * scale + offset
                units[name] = unit
                continue
            channels[name] = x
            units[name] = _declared(log.units.get(col, ""), unit,
                                    f"{log.path}: column {col!r} ({self.path}: [channels] {name})")
        return Log(log.time, channels, units, attrs={**log.attrs, "channel_map": self.path}, path=log.path)


def _entry(value, key: str, strings, numbers, fail) -> dict:
    """A TOML table with only the keys ``strings`` (string values) and ``numbers`` (finite
    numbers)."""
    if not isinstance(value, dict):
        fail(key, f"expected a table or a column name, got {type(value).__name__} {value!r}")
    for k, v in value.items():
        if k not in strings + numbers:
            fail(f"{key} {k}", f"unknown key (allowed: {', '.join(strings + numbers)})")
        if k in strings and not isinstance(v, str):
            fail(f"{key} {k}", f"expected a string, got {type(v).__name__} {v!r}")
        if k in numbers and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            fail(f"{key} {k}", f"expected a finite number, got {type(v).__name__} {v!r}")
    return value
