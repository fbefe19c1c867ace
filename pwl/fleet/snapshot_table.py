"""Snapshot tables: steady snapshots another system wrote, diagnosed like those of ``pwl run``.

Engine-monitoring reports (and ProDiMES) give no flight logs but a few steady readings per flight,
at take-off, climb or cruise. A snapshot table holds them, one row per snapshot (CSV, Parquet, an
Excel workbook's first sheet, or a pandas DataFrame)::

    engine,flight,flight_time,regime,alt,Mach,T2,P2,Nf,Nc,T24,Ps30,T30,T48,P50,P15,Wf
    ESN001,0,2026-01-01T00:00:00,cruise,9166.5,0.782,260.93,44759.8,3718.8,13245.5,...

Columns, names in any case:

- ``engine`` (or ``esn``, ``serial``, ``engine_serial``): the engine serial (spellings that differ
  only in case, spaces or leading zeros are one engine: :func:`pwl.fleet.diagnose.one_spelling`);
- ``flight`` (or ``flight_index``, ``flight_number``, ``cycle``; a whole number) and/or
  ``flight_time`` (or ``date``, ``datetime``, ``timestamp``; ISO 8601, or day- or month-first
  dates: :func:`_times`): the flights' order, as for results files
  (:func:`pwl.fleet.diagnose.in_flight_order`); rows of one engine and flight number are that
  flight's snapshots (:func:`_numbered_flights`); without numbers, snapshots with times of their
  own are grouped into flights (:func:`_timed_flights`);
- the channels the database reads (its scheduling channels, e.g. alt, Mach, Nf; the inlet's
  T2, P2; its sensors and inputs), in the database's units unless declared (``T48[degC]``, a row
  of units under the header) or mapped and declared by a channel map
  (:mod:`pwl.channel_map`, whose ``lag`` means nothing here and is refused);
- ``samples`` (optional): the readings each snapshot averages (default 1): a flight's
  snapshot with the most is the one whose levels size a sensor's bias as a fraction;
- anything else (a ``regime`` label, status words) is not read: regimes are found from the
  operating point, as for results files.

A row that repeats an earlier one exactly (a snapshot sent twice) is read once, named in a
warning.

A sensor column may be missing (an engine standard without it: NaN, as a dead sensor); the
scheduling and inlet channels may not, but for the inlet pressure with a database that knows its
plant's inlet pressure recovery (builds since 0.7.1): it is then taken from pressure altitude and
Mach, as the runtime does (``Estimator.inlet_from_air_data``). A value outside the channel's plausible range
(``/log_channels``) is missing, counted and named in a warning with its first row and the units
that would make it plausible (pressures in psi undeclared); one inside that range but far from
the model at its operating point (a T48 in degC undeclared) is missing too, named by the
diagnosis (:data:`pwl.fleet.diagnose.GROSS_DEVIATION`). A snapshot
carries no sample scatter (its standard error is NaN): the diagnosis takes the flight-to-flight
scatter from the fleet.
"""
from __future__ import annotations

import os
import re
import sys
import warnings
from collections import Counter
from functools import partial

import numpy as np

from ..database import GainDatabase
from ..errors import PwlWarning
from ..logs import LogError, _from_columns, _split_header, csv_frame, excel_frame, parquet_frame
from ..snapshots import Snapshots
from ..units import implausible_hint
from .diagnose import FlightRecord, _natural, assign_regimes, flight_seconds, one_spelling, whole_number
from .scoring import few
from .signatures import DiagnosisError

ENGINE_NAMES = ("engine", "esn", "serial", "engine_serial")
FLIGHT_NAMES = ("flight", "flight_index", "flight_number", "cycle")
TIME_NAMES = ("flight_time", "date", "datetime", "timestamp")
#: the row number read as the Log's time (a table's rows are not a time series)
_ROW = "__row__"


def is_snapshot_table(path) -> bool:
    """Whether ``path`` names a snapshot table by its extension (CSV, TSV, Parquet, a spreadsheet;
    compressed CSV too)."""
    p = os.fspath(path).lower()
    for z in (".gz", ".bz2", ".xz", ".zip"):
        if p.endswith(z):
            p = p[: -len(z)]
    return p.endswith((".csv", ".tsv", ".parquet") + _SPREADSHEETS)


#: spreadsheet extensions: Excel's own read (:func:`pwl.logs.excel_frame`), the others named
_SPREADSHEETS = (".xlsx", ".xlsm", ".xls", ".ods")


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
        if path.lower().endswith((".xlsx", ".xlsm")):
            df, cells = excel_frame(path)
            return path, df, cells
        if path.lower().endswith(_SPREADSHEETS):
            raise DiagnosisError(f"{path}: a spreadsheet pwl does not read (.xls, .ods): save the sheet as .xlsx or CSV")
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
        The table: ``.csv``/``.tsv`` (compressed too), ``.parquet`` or ``.xlsx``/``.xlsm`` (the first
        sheet; openpyxl), or a DataFrame.
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
        channel missing, a unit that cannot be converted (a flight value that is not a whole
        number is a label: warned, :func:`_flight_numbers`).
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
    if it is not None:
        column["time"] = _times(path, names[it], column["time"], i_f is None)
    to, merged = one_spelling([e for e in column["engine"] if e], "rows")
    for line in merged:
        warnings.warn(PwlWarning(f"{path}: {line}"), stacklevel=2)
    column["engine"] = [to.get(e, e) for e in column["engine"]]
    repeat = df.duplicated().to_numpy()
    if repeat.any():
        k = int(np.flatnonzero(repeat)[0])
        warnings.warn(PwlWarning(f"{path}: {int(repeat.sum())} row(s) repeat an earlier row exactly (the first: row "
                                 f"{k + 2}): one snapshot sent twice? Read once"), stacklevel=2)
    for k, (e, fl, tm) in enumerate(zip(column["engine"], column["flight"], column["time"])):
        if not e:
            raise DiagnosisError(f"{path}: row {k + 2} has no engine")
        if not fl and not tm:
            raise DiagnosisError(f"{path}: row {k + 2} (engine {e}) has neither flight number nor time")
    record = partial(_record, path, db, chans, X, P, count, _flight_numbers(path, names[i_f], column["flight"])
                     if i_f is not None else {})
    keep = np.flatnonzero(~repeat)
    if i_f is not None:
        flights = _numbered_flights(column, keep)
        _warn_twice(path, flights, P / db.p_spans(), X, chans)
        return [record(e, fl, tm, rows) for e, fl, tm, rows in flights]
    records = [record(column["engine"][k], "", column["time"][k], np.array([k])) for k in keep]
    return _timed_flights(path, records, record, db)


_NUMERIC_DATE = re.compile(r"^(\d{1,2})([/.-])(\d{1,2})\2(\d{4}|\d{2})(?:[ T]+(.*))?$")
_CLOCK = ("%H:%M", "%H:%M:%S", "%H:%M:%S.%f", "%I:%M %p", "%I:%M:%S %p")


def _times(path, name: str, values: list[str], needed: bool) -> list[str]:
    """The time column's cells as ISO 8601 text where they are dates written with the day or the
    month first (27/11/2026 06:12, 11/27/2026 6:12 AM, 27.11.26): which comes first is read from
    the column (a first field above 12: the day; a second one: the month); other cells as they
    are (:func:`pwl.fleet.diagnose.flight_seconds` reads ISO 8601 and numbers). A column whose
    order cannot be told (no field above 12, or both), and cells that stay unreadable, are named
    in a PwlWarning, or a DiagnosisError when the column is all the table has to tell flights
    apart (``needed``: no flight numbers)."""
    from datetime import datetime
    hits = [(k, m) for k, v in enumerate(values) if v and not np.isfinite(flight_seconds(v))
            and (m := _NUMERIC_DATE.match(v))]
    out = list(values)
    if hits:
        day_first = any(int(m.group(1)) > 12 for _, m in hits)
        month_first = any(int(m.group(3)) > 12 for _, m in hits)
        if day_first == month_first:
            k = hits[0][0]
            what = (f"{path}: column {name!r}: whether {values[k]!r} (row {k + 2}) has the day or the month first "
                    f"cannot be told ({'both occur' if day_first else 'no field above 12'}): write ISO 8601 dates "
                    "(2026-11-27 06:12)")
            if needed:
                raise DiagnosisError(what)
            warnings.warn(PwlWarning(f"{what}; the flights are ordered by their numbers"), stacklevel=3)
            return out
        for k, m in hits:
            d, mo = (m.group(1), m.group(3)) if day_first else (m.group(3), m.group(1))
            y = int(m.group(4)) + (2000 if len(m.group(4)) == 2 else 0)
            for clock in _CLOCK if m.group(5) else ("",):
                try:
                    t = datetime.strptime(m.group(5) or "", clock)
                    out[k] = datetime(y, int(mo), int(d), t.hour, t.minute, t.second, t.microsecond).isoformat()
                    break
                except ValueError:
                    continue
    bad = [k for k, v in enumerate(out) if v and not np.isfinite(flight_seconds(v))]
    if bad:
        what = (f"{path}: column {name!r}: {len(bad)} of {len(out)} times unreadable (the first {values[bad[0]]!r} on row "
                f"{bad[0] + 2}); ISO 8601 (2026-11-27 06:12) or day- or month-first dates are read")
        if needed and len(bad) == len(out):
            raise DiagnosisError(f"{what}, and the table has no flight number column")
        warnings.warn(PwlWarning(f"{what}: those rows are ordered by their flight number or row"), stacklevel=3)
    return out


#: without flight numbers, two snapshots of an engine more than this far apart (hours) are of two
#: flights; with them, two rows of one flight number so far apart are (the counter reset)
FLIGHT_GAP_HOURS = 12.0


def _flight_numbers(path, name: str, values: list[str]) -> dict[str, int]:
    """The flight column's cells -> whole numbers (-1 for one that is not: an airline's flight
    number 'LH400' is a label, the flights then ordered by their times), the cells that are not
    named once in a PwlWarning."""
    out = {v: whole_number(v) for v in dict.fromkeys(v for v in values if v)}
    bad = [v for v, n in out.items() if n is None]
    out = {v: -1 if n is None else n for v, n in out.items()}
    if bad:
        warnings.warn(PwlWarning(f"{path}: column {name!r}: {len(bad)} of {len(out)} flight values are not whole "
                                 f"numbers (the first {bad[0]!r}): read as labels, the flights ordered by their "
                                 "times (else by their labels)"), stacklevel=3)
    return out


def _record(path, db, chans, X, P, count, numbers, engine, fl, tm, rows) -> FlightRecord:
    """The FlightRecord of one engine's flight: table rows ``rows`` (sorted), flight ``fl`` ('' when
    none; its number from ``numbers``, :func:`_flight_numbers`) and time ``tm``."""
    rows = np.sort(np.asarray(rows))
    fidx = numbers.get(fl, -1)
    snap = Snapshots(chans, list(db.names["p"]), rows.astype(np.float64), rows.astype(np.float64),
                     count[rows], X[rows], np.full((rows.size, len(chans)), np.nan),
                     np.isfinite(X[rows]).astype(np.float64), P[rows])
    label = f"flight {fl}" if fl else tm
    return FlightRecord(engine, (tm, fidx, _natural(label)), f"{path}:row {rows[0] + 2}", label, snap,
                        db.path, db.digest, "table")


#: two rows of one engine and flight number whose operating points are within this share of
#: every scheduling axis's span are one snapshot sent twice (:func:`_warn_twice`)
TWICE_SHARE = 0.02
#: an engine with two different rows at one operating point on at least this share of its flights
#: (and this many) holds two engines' histories under one serial (:func:`_warn_twice`)
TWINNED_SHARE = 0.5
TWINNED_FLIGHTS = 3


def _warn_twice(path, flights: list[tuple], P: np.ndarray, X: np.ndarray, chans: list[str]) -> None:
    """A PwlWarning for the flights (engine, number, time, rows) holding two rows at one operating
    point (``P`` (rows, np) over the axes' spans, within :data:`TWICE_SHARE`) with different values
    (``X`` (rows, channels)): one flight sent twice, with a correction or a fault of its own? Of
    the two, the diagnosis reads the one with more readings (the first of equal ones) and leaves
    the other out: the file's order decided. A copy with T48 30 K high read as no fault, or as a
    T48 bias, by which came first; exact repeats are named as such already."""
    hits = []
    for e, fl, _, rows in flights:
        rows = np.asarray(rows)
        for i, a in enumerate(rows):
            for b in rows[i + 1:]:
                if np.all(np.abs(P[a] - P[b]) <= TWICE_SHARE) and not np.array_equal(X[a], X[b], equal_nan=True):
                    with np.errstate(invalid="ignore", divide="ignore"):
                        rel = np.abs(X[b] / X[a] - 1.0)
                    j = int(np.nanargmax(np.where(np.isfinite(rel), rel, -1.0)))
                    hits.append((e, fl, a, b, chans[j], float(rel[j])))
    if not hits:
        return
    e, fl, a, b, c, r = hits[0]
    flown = Counter(f[0] for f in flights)
    twinned = Counter(x for x, _ in {(h[0], h[1]) for h in hits})       # flights with twins, per engine
    # two rows on (nearly) every flight of a serial are two engines' histories, not one corrected flight
    shared = sorted((x for x, k in twinned.items() if k >= TWINNED_FLIGHTS and k >= TWINNED_SHARE * flown[x]),
                    key=_natural)
    why = (f"two engines' rows under one serial ({few(shared, 3)}: {twinned[shared[0]]} of its "
           f"{flown[shared[0]]} flights)? give each engine its own serial" if shared else
           "a flight sent twice and corrected? remove the stale row")
    warnings.warn(PwlWarning(
        f"{path}: {sum(twinned.values())} flight(s) hold two rows at one operating point with different "
        f"values (the first: engine {e} flight {fl}, rows {a + 2} and {b + 2}, {c} {100 * r:.2g} % apart): of each "
        f"pair the row with more readings (else the first) is read and the other left out ({why})"),
        stacklevel=3)


def _numbered_flights(column: dict, keep: np.ndarray) -> list[tuple]:
    """(engine, flight number, time, rows) of each flight of a table with flight numbers: the
    rows of one engine and number, split where their times are more than FLIGHT_GAP_HOURS apart
    (the counter reset: the same number on another day); a row without a number is a flight of
    its own time. The time is the flight's first."""
    groups: dict[tuple, list[int]] = {}
    for k in keep:
        e, fl, tm = column["engine"][k], column["flight"][k], column["time"][k]
        groups.setdefault((e, fl) if fl else (e, fl, tm), []).append(int(k))
    out = []
    for rows in groups.values():
        t = np.array([flight_seconds(column["time"][k]) for k in rows])
        order = np.argsort(np.where(np.isfinite(t), t, np.inf), kind="stable")
        rows, t = [rows[i] for i in order], t[order]
        cut = [0] + [i for i in range(1, len(rows)) if t[i] - t[i - 1] > 3600.0 * FLIGHT_GAP_HOURS] + [len(rows)]
        for a, b in zip(cut, cut[1:]):
            k = rows[a]
            out.append((column["engine"][k], column["flight"][k], column["time"][k], rows[a:b]))
    return out


def _timed_flights(path, records: list[FlightRecord], record, db) -> list[FlightRecord]:
    """A table without flight numbers whose snapshots have times of their own (a take-off report
    at 06:12, a cruise report at 07:40): an engine's snapshots in time order are one flight until
    one repeats an operating regime already in it (:func:`pwl.fleet.diagnose.assign_regimes`) or
    comes more than FLIGHT_GAP_HOURS after the one before. Snapshots without a readable time are
    flights of their own; rows sharing one time (a date per flight) part only where a regime
    repeats (two flights a day). A PwlWarning says so when snapshots of distinct times were made
    one flight."""
    assign_regimes(records, db.p_spans(), min_share=0.0)
    flights, by = [], {}
    for r in records:
        by.setdefault(r.engine, []).append(r)
    for e, recs in by.items():
        recs.sort(key=lambda r: (r.time if np.isfinite(r.time) else np.inf, r.snapshot.t0[0]))
        cur, seen, last = [], set(), np.nan
        for r in recs:
            regimes = set(r.windows)
            if cur and not (r.time - last <= 3600.0 * FLIGHT_GAP_HOURS and not regimes & seen):
                flights.append(cur)
                cur, seen = [], set()
            cur.append(r)
            seen |= regimes
            last = r.time
        flights.append(cur)
    grouped = [record(f[0].engine, "", f[0].order[0], np.concatenate([r.snapshot.t0 for r in f]).astype(np.int64))
               for f in flights]
    if any(len({r.order[0] for r in f}) > 1 for f in flights):
        warnings.warn(PwlWarning(
            f"{path}: no flight numbers, and snapshots with times of their own: an engine's snapshots in time order "
            f"are one flight until an operating regime repeats or {FLIGHT_GAP_HOURS:g} h pass ({len(records)} "
            f"times -> {len(grouped)} flights); give a flight column to say which flight each snapshot is of"),
            stacklevel=3)
    return grouped


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
        read = cmap.columns() if cmap is not None else chans
        unread = [c[0] for c in columns if c[0] not in read and np.isfinite(_numbers(c[2])).any()]
        other = (f"; its numeric columns not read: {few([repr(c) for c in unread], 6)} (one of them under another "
                 "name? a channel map, --channel-map, names it)" if unread else "")
        warnings.warn(PwlWarning(f"{path}: no column for {', '.join(absent)}: missing on every snapshot "
                                 f"(an engine standard without it?){other}"), stacklevel=3)
    empty = [c for j, c in enumerate(chans) if c not in absent and np.isnan(X[:, j]).all()
             and not (derive and c == inlet[1])]
    if empty and n:
        warnings.warn(PwlWarning(f"{path}: column{'s' if len(empty) > 1 else ''} {', '.join(map(repr, empty))} "
                                 f"hold{'' if len(empty) > 1 else 's'} no value in any of the table's {n} rows: missing on "
                                 "every snapshot (not recorded, or a column the export left empty?)"), stacklevel=3)
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
    """X with every value outside its channel's plausible range NaN; a PwlWarning names each such
    channel: how many, the first row, the units that would make its typical value plausible."""
    ranges, units = db.channel_ranges(), db.channel_units()
    X = X.copy()
    for j, c in enumerate(chans):
        lo, hi = ranges.get(c, (-np.inf, np.inf))
        col = X[:, j]
        bad = np.isfinite(col) & ((col < lo) | (col > hi)) | np.isinf(col)
        if not bad.any():
            continue
        med = float(np.median(col[bad]))
        had = f" (declared {declared[c]})" if declared.get(c) else ""
        warnings.warn(PwlWarning(f"{path}: channel {c!r}{had}: {int(bad.sum())} of {col.size} snapshots "
                                 f"implausible (the first on row {int(np.flatnonzero(bad)[0]) + 2}), typically "
                                 f"{med:.6g} where {lo:.6g} to {hi:.6g} {units.get(c, '')} is plausible: "
                                 f"{implausible_hint(med, units.get(c, ''), lo, hi)}; read as missing"), stacklevel=3)
        col[bad] = np.nan
    return X
