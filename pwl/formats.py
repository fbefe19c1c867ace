"""File formats: every kind of file (and stored record) pwl writes, defined once.

Each :class:`FileKind` names its ``format`` attribute, the version this pwl writes, the versions
it reads, and its one writer and reader; :func:`check` is the one check every reader makes (the
message names the file, the format and version found and what this pwl reads). The table of
kinds is in docs/database-format.md ("File kinds").

HDF5 files carry the two root attributes ``format`` and ``format_version``; records (a group of
datasets plus a JSON attribute ``attrs_json``, :func:`write_record`) carry them in their JSON
attributes; the fleet summary (Parquet or CSV, written by :func:`pwl.fleet.runs.write_summary`)
in the Parquet file's metadata, and a CSV summary is known by its header row.
"""
from __future__ import annotations

import json
import os
from contextlib import contextmanager
from dataclasses import dataclass

import h5py
import numpy as np

from .errors import PwlError
from .h5io import attr_str


class FormatError(PwlError, ValueError):
    """A file (or record) of another format, or of a version this pwl does not read."""


@dataclass(frozen=True)
class FileKind:
    """One kind of file pwl writes.

    Attributes
    ----------
    name : str
        The ``format`` attribute (``"pwl-gain-database"``, ...).
    version : int
        The ``format_version`` this pwl writes.
    reads : tuple of int
        The versions this pwl reads.
    what : str
        The kind in words, with its article, for messages ("a gain database").
    writer, reader : str
        The one function that writes it and the one that reads it (for the documentation).
    unversioned : int or None
        The version assumed when ``format_version`` is missing (files of older pwl versions or
        records that never had one); None: such a file is refused.
    """

    name: str
    version: int
    reads: tuple
    what: str
    writer: str
    reader: str
    unversioned: int | None = None

    def stamp(self) -> dict:
        """``{"format": name, "format_version": version}``: what every writer stores."""
        return {"format": self.name, "format_version": self.version}


GAIN_DATABASE = FileKind("pwl-gain-database", 2, (1, 2), "a gain database",
                         "pwl.database.GainDatabase.save", "pwl.database.GainDatabase.open")
RESULTS = FileKind("pwl-estimates", 2, (1, 2), "a pwl results file",
                   "pwl.results.init_result_file (Result.save, Estimator.run_file)",
                   "pwl.results.open_results (Result.load, pwl.fleet)", unversioned=1)
FLIGHT_LOG = FileKind("pwl-flight-log", 1, (1,), "a flight log", "pwl.logs.write_log",
                      "pwl.logs.read_header (read_log)", unversioned=1)
TABLES_FILE = FileKind("pwl-adaptive-tables", 1, (1,), "an adaptive-tables file",
                       "pwl.tables.save_tables (AdaptiveTable.save, Estimator.save_bias_tables)",
                       "pwl.tables.AdaptiveTable.load", unversioned=1)
TABLE_RECORD = FileKind("pwl-adaptive-table", 1, (1,), "an adaptive-table record",
                        "pwl.tables.AdaptiveTable.to_record -> pwl.tables.write_tables",
                        "pwl.tables.AdaptiveTable.from_record", unversioned=1)
ZONES_FILE = FileKind("pwl-zones-file", 1, (1,), "a zones file", "pwl.zones.save_zones",
                      "pwl.zones.load_zones", unversioned=1)
ZONES_RECORD = FileKind("pwl-zones", 1, (1,), "a pwl-zones record",
                        "pwl.zones.ZoneTable.record -> pwl.zones.write_zones",
                        "pwl.zones.ZoneTable.from_record", unversioned=1)
FLEET_SUMMARY = FileKind("pwl-fleet-summary", 1, (1,), "a fleet summary",
                         "pwl.fleet.runs.write_summary", "pwl.fleet.runs.read_summary", unversioned=1)

#: every kind, by format name
KINDS = {k.name: k for k in (GAIN_DATABASE, RESULTS, FLIGHT_LOG, TABLES_FILE, TABLE_RECORD,
                             ZONES_FILE, ZONES_RECORD, FLEET_SUMMARY)}


def found_stamp(attrs) -> tuple:
    """(format, version) stored in ``attrs`` (HDF5 attributes, or a record's or a DataFrame's
    attribute dict); None for what is missing."""
    if hasattr(attrs, "attrs"):        # an HDF5 file or group, a DataFrame
        attrs = attrs.attrs
    fmt = attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    ver = attrs.get("format_version")
    try:
        ver = None if ver is None else int(np.asarray(ver).reshape(-1)[0])
    except (TypeError, ValueError, IndexError):
        ver = -1
    return (None if fmt is None else str(fmt)), ver


def check(kinds, where, found=None, version=None, *, error=FormatError, version_error=None,
          hint: str = "") -> tuple:
    """The one format check of every reader: refuse unless ``found`` is the format name of one of
    ``kinds`` (a :class:`FileKind` or a tuple of them) and ``version`` one it reads.

    Parameters
    ----------
    kinds : FileKind or tuple of FileKind
        The kinds the reader takes.
    where : str or path
        The file (and the group, for a record) named in the message.
    found : str, h5py object or dict, optional
        The format name found, or an object with attributes (an open HDF5 file or group, a
        record's attribute dict) to take ``format`` and ``format_version`` from.
    version : int, optional
        The version found (None: missing; then the kind's ``unversioned`` applies).
    error, version_error : exception classes
        What to raise for another format, and for an unreadable version (default ``error``).
    hint : str
        Appended to the message of another format (what to do instead).

    Returns
    -------
    (FileKind, int)
        The kind found and its version.

    Raises
    ------
    error
        Another format: "<where>: not <what> (format 'x' version v; expected 'name' version(s) ...)".
    version_error
        A version this pwl does not read (newer: "... is newer than this pwl reads ...; upgrade pwl").
    """
    kinds = kinds if isinstance(kinds, tuple) else (kinds,)
    if found is not None and not isinstance(found, str):
        found, version = found_stamp(found)
    expected = " or ".join(f"{k.name!r} version {', '.join(map(str, k.reads))}" for k in kinds)
    kind = next((k for k in kinds if k.name == found), None)
    if kind is None:
        what = " or ".join(k.what for k in kinds)
        raise error(f"{where}: not {what} (format {found!r}, version {version}; expected {expected})"
                    + (f"; {hint}" if hint else ""))
    ver = kind.unversioned if version is None else version
    if ver not in kind.reads:
        newer = ver is not None and ver > max(kind.reads)
        raise (version_error or error)(
            f"{where}: {kind.what[kind.what.index(' ') + 1:]} (format {kind.name!r}) version {ver} "
            + (f"is newer than this pwl reads (up to {max(kind.reads)}); upgrade pwl" if newer
               else f"is not one this pwl reads ({', '.join(map(str, kind.reads))})"))
    return kind, ver


def stamp(target, kind: FileKind) -> None:
    """Write ``kind``'s ``format`` and ``format_version`` into ``target`` (an HDF5 file's or
    group's attributes, or a record's attribute dict)."""
    (target.attrs if hasattr(target, "attrs") else target).update(kind.stamp())


# ---- records: a group of datasets plus JSON attributes (zones, adaptive tables) -------------------
def write_record(group, arrays: dict, attrs: dict) -> None:
    """Store a record (name -> ndarray, JSON-able attrs) in an HDF5 group."""
    for k, v in arrays.items():
        group.create_dataset(k, data=np.asarray(v))
    group.attrs["attrs_json"] = json.dumps(attrs, sort_keys=True)


def read_record(group) -> tuple[dict, dict]:
    """(arrays, attrs) of a record written by :func:`write_record`."""
    arrays = {k: d[()] for k, d in group.items() if isinstance(d, h5py.Dataset)}
    return arrays, json.loads(attr_str(group, "attrs_json", "{}"))


@contextmanager
def open_checked(path, kinds, error=FormatError):
    """Open the HDF5 file ``path`` read-only after the checks every reader makes (it exists, it
    is HDF5, its format is one of ``kinds``: :func:`check`); yields the open file. ``error``: the
    reader's exception class, raised with a message naming the file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise error(f"{path}: no such file")
    if not h5py.is_hdf5(path):
        raise error(f"{path}: not an HDF5 file")
    with h5py.File(path, "r") as f:
        check(kinds, path, f, error=error)
        yield f
