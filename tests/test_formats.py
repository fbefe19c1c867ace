"""One place for file formats (pwl.formats): every writer stamps its kind's format name and
version, and every reader refuses a file of another kind, or of a newer version, with a message
naming the file, the format found and the format expected."""
import csv
import os

import h5py
import numpy as np
import pytest

from conftest import make_database
from pwl import formats
from pwl.database import ForeignFormatError, GainDatabase, VersionError
from pwl.fleet.diagnose import DiagnosisError, read_flight
from pwl.fleet.runs import SUMMARY_COLUMNS, LogRun, SummaryError, read_summary, write_summary
from pwl.grid import Axis, Grid
from pwl.h5io import seal
from pwl.logs import Log, LogError, read_log, write_log
from pwl.results import Result, ResultError
from pwl.tables import AdaptiveTable, TableError
from pwl.zones import ZoneError, ZoneTable, load_zones, save_zones

GRID = Grid([Axis("p0", [0.0, 5.0, 10.0]), Axis("p1", [50.0, 100.0])])


def zone_table():
    return ZoneTable(gains=np.ones((2, 2, 1)), grid=GRID, labels=np.array([[0, 1], [1, 0], [0, 0]]),
                     centers=np.ones((2, 2)), scale=np.ones(2), counts=np.array([4, 2]))


def result():
    n = 5
    return Result(np.arange(n) * 0.1, {"h_hat": np.zeros((n, 2))}, np.zeros(n, np.int64),
                  {"h_hat": ["a", "b"]})


# kind -> (write a file of it at path, read it, the error its reader raises)
HDF5_KINDS = {
    formats.GAIN_DATABASE: (lambda p: make_database().save(p), GainDatabase.open, ForeignFormatError),
    formats.RESULTS: (lambda p: result().save(p), Result.load, ResultError),
    formats.FLIGHT_LOG: (lambda p: write_log(p, Log(np.arange(4) * 0.5, {"Wf": np.ones(4)}, {"Wf": "kg/s"})),
                         read_log, LogError),
    formats.TABLES_FILE: (lambda p: AdaptiveTable(GRID).save(p, "t"), lambda p: AdaptiveTable.load(p, "t"),
                          TableError),
    formats.ZONES_FILE: (lambda p: save_zones(p, zone_table()), load_zones, ZoneError),
}


def relabel(path, fmt=None, version=None):
    """Change a written file's format name or version with h5py, and seal it again (so what is
    left to catch is the format, not a damaged file)."""
    with h5py.File(path, "r+") as f:
        if fmt is not None:
            f.attrs["format"] = fmt
        if version is not None:
            f.attrs["format_version"] = version
    seal(path)


@pytest.mark.parametrize("kind", list(HDF5_KINDS), ids=lambda k: k.name)
def test_every_hdf5_writer_stamps_its_format_and_its_reader_reads_it(tmp_path, kind):
    write, read, _ = HDF5_KINDS[kind]
    path = tmp_path / "f.h5"
    write(path)
    with h5py.File(path, "r") as f:
        assert formats.found_stamp(f) == (kind.name, kind.version)
    read(path)


@pytest.mark.parametrize("kind", list(HDF5_KINDS), ids=lambda k: k.name)
def test_every_hdf5_reader_refuses_another_format_naming_the_file(tmp_path, kind):
    write, read, error = HDF5_KINDS[kind]
    # a file of every other kind this project writes
    for other in HDF5_KINDS:
        if other is kind or {kind, other} <= {formats.TABLES_FILE, formats.ZONES_FILE, formats.GAIN_DATABASE} \
                and other is formats.GAIN_DATABASE:
            continue          # a gain database holds tables and zones: their readers take it
        path = tmp_path / f"{other.name}.h5"
        HDF5_KINDS[other][0](path)
        with pytest.raises(error) as e:
            read(path)
        msg = str(e.value)
        assert str(path) in msg and repr(other.name) in msg and repr(kind.name) in msg, msg
    # a format name nobody writes
    path = tmp_path / "mine.h5"
    write(path)
    relabel(path, fmt="someone-elses")
    with pytest.raises(error, match=rf"mine\.h5: not .*'someone-elses'.*{kind.name}"):
        read(path)


@pytest.mark.parametrize("kind", list(HDF5_KINDS), ids=lambda k: k.name)
def test_every_hdf5_reader_refuses_a_newer_version(tmp_path, kind):
    write, read, error = HDF5_KINDS[kind]
    path = tmp_path / "new.h5"
    write(path)
    relabel(path, version=kind.version + 1)
    with pytest.raises(VersionError if kind is formats.GAIN_DATABASE else error,
                       match=rf"new\.h5: .*{kind.name}.*version {kind.version + 1} is newer"):
        read(path)


def test_records_are_stamped_and_checked():
    arrays, attrs = AdaptiveTable(GRID).to_record()
    assert formats.found_stamp(attrs) == (formats.TABLE_RECORD.name, formats.TABLE_RECORD.version)
    arrays_z, attrs_z = zone_table().record()
    assert formats.found_stamp(attrs_z) == (formats.ZONES_RECORD.name, formats.ZONES_RECORD.version)
    with pytest.raises(TableError, match="here: not an adaptive-table record.*'pwl-zones'"):
        AdaptiveTable.from_record(arrays, attrs_z, where="here")
    with pytest.raises(ZoneError, match="there: not a pwl-zones record.*'pwl-adaptive-table'"):
        ZoneTable.from_record((arrays_z, attrs), where="there")
    with pytest.raises(TableError, match="version 2 is newer"):
        AdaptiveTable.from_record(arrays, attrs | {"format_version": 2})


def test_tables_and_zones_go_into_a_gain_database_through_their_one_writer(tmp_path):
    path = tmp_path / "db.h5"
    make_database().save(path)
    AdaptiveTable(GRID).save(path, "extra")
    with h5py.File(path, "r") as f:                  # still a sealed gain database
        assert formats.found_stamp(f) == (formats.GAIN_DATABASE.name, formats.GAIN_DATABASE.version)
    db = GainDatabase.open(path)
    assert set(db.tables) == {"bias_T48", "extra"} and db.sealed
    assert AdaptiveTable.load(path, "extra").grid == GRID
    # into a file of another kind: refused, the file untouched
    log = tmp_path / "log.h5"
    HDF5_KINDS[formats.FLIGHT_LOG][0](log)
    before = log.read_bytes()
    with pytest.raises(TableError, match=r"log\.h5: not a gain database or an adaptive-tables file .*'pwl-flight-log'"):
        AdaptiveTable(GRID).save(log, "x")
    assert log.read_bytes() == before


def test_old_zones_file_without_a_version_still_reads(tmp_path):
    path = tmp_path / "z.h5"
    save_zones(path, zone_table())
    with h5py.File(path, "r+") as f:                 # as written before the version was stamped
        del f.attrs["format_version"]
    assert load_zones(path).k == 2


def test_fleet_summary_is_stamped_and_checked(tmp_path, monkeypatch):
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "pyarrow" else real(n, *a))
    runs = [LogRun("a.h5", "a.estimates.h5", None, "boom", "failed", {})]
    path = write_summary(runs, tmp_path)
    assert os.path.basename(path) == "summary.csv"
    assert read_summary(path)[0]["error"] == "boom"
    other = tmp_path / "truth.csv"
    with open(other, "w", newline="") as fh:
        csv.writer(fh).writerows([["engine", "fault"], ["E1", "none"]])
    with pytest.raises(SummaryError, match=r"truth\.csv: not a fleet summary .*'pwl-fleet-summary'"):
        read_summary(other)
    assert tuple(next(csv.reader(open(path)))[:len(SUMMARY_COLUMNS)]) == SUMMARY_COLUMNS


def test_fleet_summary_parquet_carries_its_stamp(tmp_path):
    pd = pytest.importorskip("pandas")
    pytest.importorskip("pyarrow")
    path = write_summary([LogRun("a.h5", "a.estimates.h5", None, "boom", "failed", {})], tmp_path)
    assert formats.found_stamp(pd.read_parquet(path).attrs) == (formats.FLEET_SUMMARY.name, 1)
    df = pd.read_parquet(path)
    df.attrs.update(format="pwl-estimates", format_version=2)
    df.to_parquet(tmp_path / "x.parquet")
    with pytest.raises(SummaryError, match="x.parquet: not a fleet summary"):
        read_summary(tmp_path / "x.parquet")


def test_diagnosis_reads_results_files_only(tmp_path):
    path = tmp_path / "log.h5"
    HDF5_KINDS[formats.FLIGHT_LOG][0](path)
    with pytest.raises(DiagnosisError, match=r"log\.h5: not a pwl results file .*'pwl-flight-log'"):
        read_flight(path)


def test_every_kind_is_defined_once():
    assert set(formats.KINDS.values()) == {*HDF5_KINDS, formats.TABLE_RECORD, formats.ZONES_RECORD,
                                           formats.FLEET_SUMMARY}
    for k in formats.KINDS.values():
        assert k.version in k.reads and k.name.startswith("pwl-") and k.writer and k.reader
