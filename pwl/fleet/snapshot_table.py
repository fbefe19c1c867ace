"""Snapshot tables: steady snapshots another system wrote, diagnosed like those of ``pwl run``.

Engine-monitoring reports (and ProDiMES) give no flight logs but a few steady readings per flight,
at take-off, climb or cruise. A snapshot table holds them, one row per snapshot (CSV, Parquet, or
a pandas DataFrame)::

    engine,flight,flight_time,regime,alt,Mach,T2,P2,Nf,Nc,T24,Ps30,T30,T48,P50,P15,Wf
    ESN001,0,2026-01-01T00:00:00,cruise,9166.5,0.782,260.93,44759.8,3718.8,13245.5,...

Columns, names in any case:

- ``engine`` (or ``esn``, ``serial``, ``engine_serial``): the engine serial;
- ``flight`` (or ``flight_index``, ``flight_number``, ``cycle``; a whole number) and/or
  ``flight_time`` (or ``date``, ``datetime``, ``timestamp``): the flights' order, as for results
  files (:func:`pwl.fleet.diagnose.in_flight_order`); rows of one engine and flight are that
  flight's snapshots;
- the channels the database reads (its scheduling channels, e.g. alt, Mach, Nf; the inlet's
  T2, P2; its sensors and inputs), in the database's units unless declared (``T48[degC]``, a row
  of units under the header) or mapped and declared by a channel map
  (:mod:`pwl.channel_map`, whose ``lag`` means nothing here and is refused);
- ``samples`` (optional): the readings each snapshot averages (default 1): a flight's
  snapshot with the most is the one whose levels size a sensor's bias as a fraction;
- anything else (a ``regime`` label, status words) is not read: regimes are found from the
  operating point, as for results files.

A sensor column may be missing (an engine standard without it: NaN, as a dead sensor); the
scheduling and inlet channels may not, but for the inlet pressure with a database that knows its
plant's inlet pressure recovery (builds since 0.7.1): it is then taken from pressure altitude and
Mach, as the runtime does (``Estimator.inlet_from_air_data``). A value outside the channel's plausible range
(``/log_channels``) is missing, counted and, when a tenth of a channel's rows are, named in a
warning with the units that would make it plausible (a T48 in degC undeclared). A snapshot
carries no sample scatter (its standard error is NaN): the diagnosis takes the flight-to-flight
scatter from the fleet.
"""
from __future__ import annotations

import os
import sys
import warnings

import numpy as np

from ..database import GainDatabase
from ..errors import PwlWarning
from ..logs import LogError, _from_columns, _split_header, csv_frame, parquet_frame
from ..snapshots import Snapshots
from ..units import implausible_hint
from .diagnose import FlightRecord, _natural, _whole
from .signatures import DiagnosisError

ENGINE_NAMES = ("engine", "esn", "serial", "engine_serial")
FLIGHT_NAMES = ("flight", "flight_index", "flight_number", "cycle")
TIME_NAMES = ("flight_time", "date", "datetime", "timestamp")
#: the row number read as the Log's time (a table's rows are not a time series)
_ROW = "__row__"


def is_snapshot_table(path) -> bool:
    """Whether ``path`` names a snapshot table by its extension (CSV, TSV, Parquet; compressed
    CSV too)."""
    p = os.fspath(path).lower()
    for z in (".gz", ".bz2", ".xz", ".zip"):
        if p.endswith(z):
            p = p[: -len(z)]
    return p.endswith((".csv", ".tsv", ".parquet"))


def _frame(source):
    """(path for messages, DataFrame, header cells) of a path or a DataFrame."""
    pd = sys.modules.get("pandas")
    if pd is not None and isinstance(source, pd.DataFrame):
        return "<DataFrame>", source, [str(c) for c in source.columns]
    path = os.fspath(source)
    if not os.path.exists(path):
        raise DiagnosisError(f"{path}: no such snapshot table")
    try:
        if path.lower().endswith(".parquet"):
            df = parquet_frame(path)
            return path, df, [str(c) for c in df.columns]
        df, cells = csv_frame(path)
        return path, df, cells
    except LogError as e:
        raise DiagnosisError(str(e)) from None
    except Exception as e:  # pandas and pyarrow raise many kinds on a damaged file
        raise DiagnosisError(f"{path}: unreadable snapshot table ({type(e).__name__}: {e})") from None


def _find(path, names: list[str], wanted: tuple, what: str, required: bool) -> int | None:
    """The column index of the first of ``wanted`` in ``names`` (any case; one column only)."""
    low = [n.casefold() for n in names]
    for w in wanted:
        hits = [i for i, n in enumerate(low) if n == w]
        if len(hits) > 1:
            raise DiagnosisError(f"{path}: {len(hits)} columns named {w!r}: which one to use is ambiguous")
        if hits:
            return hits[0]
    if required:
        raise DiagnosisError(f"{path}: no {what} column (one named {', '.join(wanted)}; columns: "
                             f"{', '.join(map(repr, names))})")
    return None


def _text(v) -> str:
    """A cell as text: '' for a missing one, whole numbers without '.0'."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    if isinstance(v, (float, np.floating)) and float(v).is_integer():
        return str(int(v))
    return str(v).strip()


def read_snapshot_table(source, db: GainDatabase, channel_map=None) -> list[FlightRecord]:
    """FlightRecords of a snapshot table (module docstring), one per engine and flight.

    Parameters
    ----------
    source : str, path-like or pandas.DataFrame
        The table: ``.csv``/``.tsv`` (compressed too) or ``.parquet``, or a DataFrame.
    db : GainDatabase
        The database the snapshots are diagnosed with: which channels are read, their units
        and plausible ranges, and the operating point of each row.
    channel_map : ChannelMap or str or path-like, optional
        The table's column names and units -> the model's (:mod:`pwl.channel_map`).

    Returns
    -------
    list of FlightRecord
        ``source`` ``<table>:row <k>`` (the flight's first row, 1-based under the header),
        ``label`` ``flight <n>`` (else the flight time), ``database`` the database's path and digest, ``mode``
        ``"table"``; each snapshot's windows are its rows (``samples`` the table's, else 1; ``se``
        NaN).

    Raises
    ------
    DiagnosisError
        Naming the table and the column or row: no engine or flight column, a scheduling or inlet
        channel missing, a unit that cannot be converted, a flight number that is not whole.
    """
    path, df, cells = _frame(source)
    heads = [_split_header(c) for c in cells]
    names, units = [n for n, _ in heads], [u for _, u in heads]
    ie = _find(path, names, ENGINE_NAMES, "engine", True)
    i_f = _find(path, names, FLIGHT_NAMES, "flight", False)
    it = _find(path, names, TIME_NAMES, "flight time", False)
    i_n = _find(path, names, ("samples",), "samples", False)
    if i_f is None and it is None:
        raise DiagnosisError(f"{path}: no flight column (a flight number named {', '.join(FLIGHT_NAMES)}, or a "
                             f"flight time named {', '.join(TIME_NAMES)}; columns: {', '.join(map(repr, names))})")
    if not df.shape[0]:
        raise DiagnosisError(f"{path}: the snapshot table has no rows")
    ids = {ie, i_f, it, i_n} - {None}
    chans, X = _channels(path, [(nm, u, df.iloc[:, j]) for j, (nm, u) in enumerate(heads) if j not in ids], db,
                         channel_map)
    P = _operating_points(db, chans, X)
    count = _samples(path, df, i_n)
    column = {k: [_text(v) for v in df.iloc[:, j]] if j is not None else [""] * df.shape[0]
              for k, j in (("engine", ie), ("flight", i_f), ("time", it))}
    groups: dict[tuple, list[int]] = {}
    for k, (e, fl, tm) in enumerate(zip(column["engine"], column["flight"], column["time"])):
        if not e:
            raise DiagnosisError(f"{path}: row {k + 2} has no engine")
        if not fl and not tm:
            raise DiagnosisError(f"{path}: row {k + 2} (engine {e}) has neither flight number nor time")
        groups.setdefault((e, fl, tm), []).append(k)
    records = []
    for (e, fl, tm), rows in groups.items():
        fidx = _whole(fl, f"{path}: row {rows[0] + 2}") if fl else -1
        rows = np.array(rows)
        snap = Snapshots(chans, list(db.names["p"]), rows.astype(np.float64), rows.astype(np.float64),
                         count[rows], X[rows], np.full((rows.size, len(chans)), np.nan),
                         np.isfinite(X[rows]).astype(np.float64), P[rows])
        label = f"flight {fl}" if fl else tm
        records.append(FlightRecord(e, (tm, fidx, _natural(label)), f"{path}:row {rows[0] + 2}", label, snap,
                                    db.path, db.digest, "table"))
    return records


def _channels(path, columns: list[tuple], db: GainDatabase, channel_map) -> tuple[list[str], np.ndarray]:
    """(channels, X (rows, channels)) of a table's ``columns`` [(name, unit, values)]: the
    database's scheduling and inlet channels, then its sensors and inputs, in its units (declared
    units converted; a channel map applied), implausible values NaN (:func:`_plausible`), an absent
    sensor NaN and an absent inlet pressure from the air data (warned)."""
    from ..channel_map import ChannelMap

    cmap = channel_map if channel_map is None or isinstance(channel_map, ChannelMap) else ChannelMap.load(channel_map)
    if cmap is not None:
        lagged = [c for c, entry in cmap.channels.items() if entry[4] != 0.0]
        if lagged:
            raise DiagnosisError(f"{cmap.path}: [channels] {lagged[0]} has a lag: a snapshot table's rows are "
                                 "no time series")
    n = len(columns[0][2]) if columns else 0
    db_units, corr = db.channel_units(), db.correction
    sched = [c for c, _, _ in db.schedule]
    inlet = [corr.theta_channel, corr.delta_channel] if corr else []
    need = list(dict.fromkeys(sched + inlet))
    sensors = [c for c in dict.fromkeys(list(db.names["y"]) + list(db.names["u"])) if c not in need]
    chans = need + sensors
    try:
        log = _from_columns(path, [_ROW] + [c[0] for c in columns], [""] + [c[1] for c in columns],
                            [np.arange(n, dtype=np.float64)] + [c[2] for c in columns], time=_ROW,
                            keep=None if cmap is None else cmap.columns())
        if cmap is not None:
            log = cmap.apply(log)
        absent = [c for c in sensors if c not in log.channels]
        derive = bool(inlet) and inlet[1] not in log.channels and db.derives_inlet()
        X = log.require(chans, [db_units.get(c, "") for c in chans], absent_ok=absent + (inlet[1:] if derive else []))
    except LogError as e:
        raise DiagnosisError(str(e)) from None
    if derive:      # as the runtime does (Estimator.inlet_from_air_data)
        X[:, chans.index(inlet[1])] = db.inlet_from_air_data(X[:, [chans.index(c) for c in sched]])
        warnings.warn(PwlWarning(f"{path}: no {inlet[1]!r} column: the inlet pressure is taken from pressure "
                                 "altitude and Mach with the inlet's pressure recovery of the database's build "
                                 f"({db.ambient.recovery:.4f})"), stacklevel=3)
    if absent:
        warnings.warn(PwlWarning(f"{path}: no column for {', '.join(absent)}: missing on every snapshot "
                                 "(an engine standard without it?)"), stacklevel=3)
    return chans, _plausible(path, X, chans, db, log.units)


def _operating_points(db: GainDatabase, chans: list[str], X: np.ndarray) -> np.ndarray:
    """(rows, np) the operating point of every row as the runtime computes it (NaN where a
    scheduling or inlet channel is missing)."""
    corr = db.correction
    sched = [c for c, _, _ in db.schedule]
    th = X[:, chans.index(corr.theta_channel)] / corr.T_std if corr else np.ones(X.shape[0])
    de = X[:, chans.index(corr.delta_channel)] / corr.P_std if corr else np.ones(X.shape[0])
    with np.errstate(invalid="ignore", divide="ignore"):
        P = db.operating_point(X[:, [chans.index(c) for c in sched]], th, de)
    need = sched + ([corr.theta_channel, corr.delta_channel] if corr else [])
    P[~np.all(np.isfinite(X[:, [chans.index(c) for c in need]]), axis=1)] = np.nan
    return P


def _samples(path, df, i_n) -> np.ndarray:
    """(rows,) int64 the table's ``samples`` column (whole numbers >= 1; none: ones)."""
    if i_n is None:
        return np.ones(df.shape[0], dtype=np.int64)
    v = _numbers(df.iloc[:, i_n])
    bad = ~(np.isfinite(v) & (v >= 1) & (v == np.round(v)))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise DiagnosisError(f"{path}: row {k + 2}: samples {df.iloc[k, i_n]!r} is not a whole number >= 1")
    return v.astype(np.int64)


def _numbers(column) -> np.ndarray:
    """A column as float64, text that is no number NaN."""
    import pandas as pd
    return pd.to_numeric(column, errors="coerce").to_numpy(dtype=np.float64)


def _plausible(path, X, chans, db: GainDatabase, declared: dict) -> np.ndarray:
    """X with every value outside its channel's plausible range NaN; a PwlWarning names a channel
    with a tenth of its rows so, with the units that would make its typical value plausible."""
    ranges, units = db.channel_ranges(), db.channel_units()
    X = X.copy()
    for j, c in enumerate(chans):
        lo, hi = ranges.get(c, (-np.inf, np.inf))
        col = X[:, j]
        bad = np.isfinite(col) & ((col < lo) | (col > hi)) | np.isinf(col)
        if not bad.any():
            continue
        if bad.sum() >= max(1, col.size // 10):
            med = float(np.median(col[bad]))
            had = f" (declared {declared[c]})" if declared.get(c) else ""
            warnings.warn(PwlWarning(f"{path}: channel {c!r}{had}: {int(bad.sum())} of {col.size} snapshots "
                                     f"implausible, typically {med:.6g} where {lo:.6g} to {hi:.6g} "
                                     f"{units.get(c, '')} is plausible: "
                                     f"{implausible_hint(med, units.get(c, ''), lo, hi)}; read as missing"), stacklevel=3)
        col[bad] = np.nan
    return X
