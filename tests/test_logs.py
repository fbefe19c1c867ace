"""Flight-log files: HDF5 and CSV round trips, compact storage, named errors."""
import h5py
import numpy as np
import pytest

from pwl.logs import Log, LogError, read_header, read_log, read_rows, write_log


def sample_log(n=500):
    rng = np.random.default_rng(3)
    return Log(np.arange(n) * 0.015, {"Nf": 3000 + rng.normal(0, 5, n), "T48": 900 + rng.random(n)},
               {"Nf": "rpm", "T48": "K"}, {"Fn": rng.random(n)}, {"Fn": "N"}, {"dt": 0.015, "seed": 3})


def test_hdf5_and_csv_round_trip_exact(tmp_path):
    log = sample_log()
    for name in ("a.h5", "a.csv"):
        write_log(tmp_path / name, log)
        back = read_log(tmp_path / name)
        np.testing.assert_array_equal(back.time, log.time)
        for k in log.channels:
            np.testing.assert_array_equal(back.channels[k], log.channels[k])
            assert back.units[k] == log.units[k]
        np.testing.assert_array_equal(back.truth["Fn"], log.truth["Fn"])
        assert back.truth_units["Fn"] == "N"


def test_compact_is_float32_exact_and_smaller(tmp_path):
    log = sample_log(20000)
    write_log(tmp_path / "full.h5", log)
    write_log(tmp_path / "small.h5", log, compact=True)
    back = read_log(tmp_path / "small.h5")
    for k in log.channels:
        np.testing.assert_array_equal(back.channels[k], log.channels[k].astype(np.float32).astype(np.float64))
    assert (tmp_path / "small.h5").stat().st_size < 0.6 * (tmp_path / "full.h5").stat().st_size


def test_chunked_reading_equals_whole(tmp_path):
    log = sample_log(1000)
    write_log(tmp_path / "a.h5", log)
    head = read_header(tmp_path / "a.h5")
    parts = [read_rows(head, a, min(1000, a + 300)) for a in range(0, 1000, 300)]
    np.testing.assert_array_equal(np.concatenate([p.channels["Nf"] for p in parts]), log.channels["Nf"])


def test_require_names_missing_channel_and_units(tmp_path):
    log = sample_log(10)
    with pytest.raises(LogError, match="'Wf' is missing"):
        log.require(["Nf", "Wf"])
    # a known unit of the same quantity is converted (K -> degC, rpm -> rad/s) ...
    np.testing.assert_allclose(log.require(["T48", "Nf"], ["degC", "rad/s"]),
                               np.column_stack([log.channels["T48"] - 273.15, log.channels["Nf"] * np.pi / 30]),
                               rtol=1e-13)
    assert log.conversions({"T48": "degC", "Nf": "rpm"}) == {"T48": "K -> degC"}
    # ... another quantity or an unknown unit is refused, naming the file, the channel and the units
    with pytest.raises(LogError, match=r"<memory>: channel 'T48'.*'K' \(temperature\).*'Pa' \(pressure\)"):
        log.require(["T48"], ["Pa"])
    log.units["Nf"] = "furlongs"
    with pytest.raises(LogError, match="channel 'Nf'.*'furlongs' is not a unit pwl knows"):
        log.require(["Nf"], ["rpm"])
    log.units["Nf"] = ""     # not declared: taken as it is
    np.testing.assert_array_equal(log.require(["Nf"], ["rpm"])[:, 0], log.channels["Nf"])


def test_foreign_and_damaged_hdf5(tmp_path):
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f["a"] = 1
    with pytest.raises(LogError, match="not a flight log"):
        read_log(tmp_path / "x.h5")
    write_log(tmp_path / "b.h5", sample_log())
    with h5py.File(tmp_path / "b.h5", "r+") as f:
        del f["channels/Nf"]
        f["channels/Nf"] = np.zeros(3)
    with pytest.raises(LogError, match="b.h5: content does not match its seal"):   # pwl's own file
        read_log(tmp_path / "b.h5")
    unseal(tmp_path / "b.h5")                     # as if another tool had written it
    with pytest.raises(LogError, match="/channels/Nf has shape"):
        read_log(tmp_path / "b.h5")


def unseal(path):
    """Blank a file's seal (pwl.h5io): the file then reads as one written by another tool."""
    with open(path, "r+b") as f:
        f.write(bytes(512))


def test_csv_errors(tmp_path):
    (tmp_path / "bad.csv").write_text("time[s],Nf[rpm]\n0,1\n0.1,abc\n")
    with pytest.raises(LogError, match="bad.csv.*non-numeric"):
        read_log(tmp_path / "bad.csv").require(["Nf"])
    (tmp_path / "ragged.csv").write_text("time[s],Nf[rpm]\n0,1\n0.1\n")
    with pytest.raises(LogError, match="row 3"):
        read_log(tmp_path / "ragged.csv")
    (tmp_path / "notime.csv").write_text("Nf[rpm]\n1\n")
    with pytest.raises(LogError, match="no 'time' column"):
        read_log(tmp_path / "notime.csv")


def test_a_log_read_back_can_be_written_again(tmp_path):
    # attributes read from HDF5 come back as numpy scalars (a bool as numpy.bool_)
    log = sample_log(20)
    log.attrs.update({"fault_active": True, "engine": "ESN001", "flight_index": 3})
    write_log(tmp_path / "a.h5", log)
    again = read_log(tmp_path / "a.h5")
    write_log(tmp_path / "b.h5", again)
    back = read_log(tmp_path / "b.h5").attrs
    assert bool(back["fault_active"]) is True and back["engine"] == "ESN001" and int(back["flight_index"]) == 3


def test_duplicate_columns_and_bad_time_are_refused(tmp_path):
    """A name two columns of different values share is refused where it is needed (the time, a
    channel); unused, it is left out (test_log_dialects: duplicate columns)."""
    (tmp_path / "dup.csv").write_text("time[s],Wf[kg/s],Nf[rpm],Wf[kg/s]\n0,1,2,3\n0.1,1,2,3\n")
    with pytest.raises(LogError, match=r"dup.csv: duplicate column 'Wf': its copies differ"):
        read_log(tmp_path / "dup.csv").require(["Nf", "Wf"])
    (tmp_path / "dup.csv").write_text("time,time,Nf\n0,0,2\n0.1,0.1,2\n")
    with pytest.raises(LogError, match=r"dup.csv: columns \['time', 'time'\] could each be the time"):
        read_log(tmp_path / "dup.csv")
    back = "".join(f"{0.1 * k:.1f},1\n" for k in range(12)) + "0.05,1\n"   # 11 rows back: a clock reset
    for name, body, word in (("back.csv", back, "does not increase at sample 12"),
                             ("same.csv", "0,1\n0,2\n", "does not increase at sample 1"),   # (0,1 twice: dropped)
                             ("inf.csv", "0,1\ninf,1\n", "is not finite at sample 1"),
                             ("nan.csv", "nan,1\n0.1,1\n", "is not finite at sample 0")):
        (tmp_path / name).write_text("time[s],Nf[rpm]\n" + body)
        with pytest.raises(LogError, match=f"{name}: time {word}"):
            read_log(tmp_path / name)
    log = sample_log(20)
    log.time[7] = log.time[6]                        # the same check on HDF5 logs
    write_log(tmp_path / "t.h5", log)
    with pytest.raises(LogError, match="t.h5: time does not increase at sample 7"):
        read_header(tmp_path / "t.h5")


def test_units_in_other_cases_and_spellings_are_known_and_unknown_ones_are_not():
    from pwl.units import UNITS, UnitError, converter, known
    assert [known(u) for u in ("RPM", "Rpm", "KPA", "deg C", "DEGF", "lb/hr", "sec", "kg/s")] == \
        ["rpm", "rpm", "kPa", "degC", "degF", "lb/h", "s", "kg/s"]
    assert all(known(u.upper()) == u for u in UNITS)          # no two symbols equal but for case
    assert known("psig") is None and known("furlongs") is None   # gauge pressure needs ambient
    with pytest.raises(UnitError, match="'psig' is not a unit pwl knows"):
        converter("psig", "Pa", "x")


def test_an_hdf5_time_in_another_unit_is_read_in_seconds(tmp_path):
    """A flight log written by another tool with /time in ms and its 'unit' attribute saying so
    reads in seconds (before: refused as 1000 times the database's step, with a CSV header's
    advice); an unknown unit there is named."""
    log = sample_log()
    with h5py.File(tmp_path / "ms.h5", "w") as f:
        f.attrs.update({"format": "pwl-flight-log", "format_version": 1})
        d = f.create_dataset("time", data=log.time * 1000.0)
        d.attrs["unit"] = "ms"
        g = f.create_group("channels")
        for k, v in log.channels.items():
            g.create_dataset(k, data=v).attrs["unit"] = log.units[k]
    back = read_log(tmp_path / "ms.h5")
    np.testing.assert_allclose(back.time, log.time, rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(back.channels["Nf"], log.channels["Nf"])
    with h5py.File(tmp_path / "ms.h5", "a") as f:
        f["time"].attrs["unit"] = "fortnights"
    with pytest.raises(LogError, match=r"ms.h5: /time.*fortnights"):
        read_log(tmp_path / "ms.h5")
