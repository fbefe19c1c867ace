"""Log dialects (tester's report B1-B10): decimal commas, thousands separators, Fortran exponents,
spreadsheet day numbers, MAT structs and unit cells, HDF5 attributes stored as arrays, tables in
one HDF5 or MAT variable, units rows of other spellings, infinite values. Each reads to the values
written (exactly unless a tolerance is stated) or is a LogError naming the file, the column and the
value with what to do."""
import contextlib
import warnings

import h5py
import numpy as np
import pandas as pd
import pytest
import scipy.io

from pwl.channel_map import ChannelMap
from pwl.errors import PwlWarning
from pwl.logs import Log, LogError, read_log

N = 120
T = np.arange(N) * 0.015
RNG = np.random.default_rng(7)
#: channel -> (values with 16-17 significant digits, unit): the log every test writes in its dialect
CHANNELS = {"Nf": (2609.9859296748114 + RNG.normal(0, 30, N), "rpm"),
            "T48": (938.873839429699 + RNG.normal(0, 80, N), "K"),      # about 10 % of them >= 1000
            "P2": (100789.72652875436 + RNG.normal(0, 500, N), "Pa"),
            "Wf": (0.6721895347098469 + RNG.normal(0, 0.01, N), "kg/s")}
NAMES = ["time", *CHANNELS]


def columns():
    """time and the channels as lists of floats, in NAMES order."""
    return [T] + [v for v, _ in CHANNELS.values()]


def write_rows(path, rows, header=None, sep=",", units=None):
    """A delimited text file: the header (NAMES), an optional row of units, then ``rows`` (lists of cells)."""
    lines = [sep.join(header or NAMES)] + ([sep.join(units)] if units else [])
    lines += [sep.join(r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def rows_of(fmt=repr):
    """The log's rows of cells, each value written by ``fmt``."""
    return [[fmt(float(c[i])) for c in columns()] for i in range(N)]


def assert_values(log, skip_first=False):
    """The log holds exactly the values written (the first row's channels empty if ``skip_first``)."""
    np.testing.assert_array_equal(log.time, T)
    for k, (v, _) in CHANNELS.items():
        want = v.copy()
        if skip_first:
            want[0] = np.nan
        np.testing.assert_array_equal(log.channels[k], want, err_msg=k)


@contextlib.contextmanager
def no_warnings():
    """A context in which any PwlWarning or RuntimeWarning fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", PwlWarning)
        warnings.simplefilter("error", RuntimeWarning)
        yield


# ---- B1, B2: decimal commas ---------------------------------------------------------------------
def test_decimal_comma_found_past_a_first_row_without_one(tmp_path):
    """';'-separated, decimal comma, the first row '0;;;;' (channels empty at a logger's start):
    '0,015' was read as a duration of 15 ns. The rows after the first show the decimal comma."""
    rows = [["0"] + [""] * len(CHANNELS)] + [[c.replace(".", ",") for c in r] for r in rows_of()[1:]]
    assert_values(read_log(write_rows(tmp_path / "dc.csv", rows, sep=";")), skip_first=True)


def test_decimal_comma_found_after_the_rows_sampled(tmp_path):
    """The first decimal comma after the 64 lines the separator is sniffed from (time stamps, the
    channels empty for 100 rows): the file is read again with a decimal comma."""
    k = np.arange(N + 100)
    stamps = (pd.Timestamp("2024-05-01T10:00:00") + pd.to_timedelta(k * 15, unit="ms")).strftime("%Y-%m-%dT%H:%M:%S.%f")
    rows = [[s] + [""] * len(CHANNELS) for s in stamps[:100]]
    rows += [[s] + [c.replace(".", ",") for c in r[1:]] for s, r in zip(stamps[100:], rows_of())]
    log = read_log(write_rows(tmp_path / "late.csv", rows, sep=";"))
    np.testing.assert_allclose(log.time, k * 0.015, rtol=0, atol=1e-9)
    for key, (v, _) in CHANNELS.items():
        np.testing.assert_array_equal(log.channels[key][100:], v, err_msg=key)


def test_a_time_with_a_decimal_comma_is_never_a_duration():
    """Text '0,015' in a time column (a DataFrame of strings) is refused, naming it: it is no
    duration of 15 ns."""
    df = pd.DataFrame({"time": ["0", "0,015", "0,030"], "Nf": [1.0, 2.0, 3.0]})
    with pytest.raises(LogError, match=r"<DataFrame>: column 'time': '0,015' at sample 1 is a number with a "
                                       r"comma, not read as one \(a decimal comma, or a thousands separator\?\): "
                                       r"write the log with decimal points"):
        read_log(df)


def test_quoted_decimal_commas_in_a_comma_separated_file(tmp_path):
    """','-separated with every number quoted and written with a decimal comma ("0,015")."""
    rows = [['"' + c.replace(".", ",") + '"' for c in r] for r in rows_of()]
    assert_values(read_log(write_rows(tmp_path / "q.csv", rows)))


def test_quoted_numbers_with_one_comma_that_could_be_thousands_are_refused(tmp_path):
    """"1,250" in a ','-separated file without decimal points: a thousands separator or a decimal
    comma? Refused, naming the column and the value, with the ways out."""
    rows = [[repr(float(T[i])), f'"{1 + i % 7},{250 + i:03d}"'] for i in range(N)]
    path = write_rows(tmp_path / "amb.csv", rows, header=["time", "Nf"])
    with pytest.raises(LogError, match=r"amb.csv: column 'Nf': '1,250' at sample 0 is a number with a comma.*"
                                       r"pandas.read_csv\(path, decimal=','\) or thousands=','"):
        read_log(path).require(["Nf"])
    df = pd.read_csv(path, thousands=",")                  # the hint, followed
    np.testing.assert_array_equal(read_log(df).channels["Nf"], [(1 + i % 7) * 1000 + 250 + i for i in range(N)])


def test_a_decimal_comma_column_with_a_text_cell_keeps_its_numbers(tmp_path):
    """A decimal-comma file's column with one 'ERR' cell (pandas leaves the column as text): the
    numbers are read, the cell is missing (warned)."""
    rows = [[c.replace(".", ",") for c in r] for r in rows_of()]
    rows[5][2] = "ERR"
    with pytest.warns(PwlWarning, match="column 'T48': 1 non-numeric value"):
        log = read_log(write_rows(tmp_path / "err.csv", rows, sep=";"))
    want = CHANNELS["T48"][0].copy()
    want[5] = np.nan
    np.testing.assert_array_equal(log.channels["T48"], want)


# ---- B3: spreadsheet day numbers ----------------------------------------------------------------
def test_excel_serial_days_are_named_and_read_when_declared(tmp_path):
    """Time as Excel serial days (45413.573...): refused, saying so and how to declare it (the
    --resample advice could not help); declared as days (time[d], or a channel map's [time] unit)
    it reads as seconds, to the 10 decimals written (8.6 us)."""
    days = [f"{45413.573 + t / 86400:.10f}" for t in T]
    rows = [[d] + r[1:] for d, r in zip(days, rows_of())]
    path = write_rows(tmp_path / "x.csv", rows)
    with pytest.raises(LogError, match=r"x.csv: time column 'time' holds 45413.573, 45413.5730001736, \.\.\.: "
                                       r"spreadsheet \(Excel\) serial day numbers, a sample every 0.015 s\? "
                                       r"Declare the unit, days: a 'time\[d\]' header"):
        read_log(path)
    log = read_log(write_rows(tmp_path / "d.csv", rows, header=["time[d]", *CHANNELS]))
    np.testing.assert_array_equal(log.time, [float(d) * 86400.0 for d in days])
    np.testing.assert_allclose(log.time - log.time[0], T, rtol=0, atol=8.7e-6)
    cmap = ChannelMap.from_dict({"time": {"column": "time", "unit": "d"}, "channels": {k: k for k in CHANNELS}})
    np.testing.assert_array_equal(read_log(path, cmap).time, log.time)


# ---- B4: thousands separators -------------------------------------------------------------------
def test_thousands_separators_on_some_values_of_a_column(tmp_path):
    """A US export writes "1,000.960033" (quoted) only where a value is >= 1000: those cells were
    read as missing (a warning, estimates off). Read as numbers, no warning."""
    def cell(x):
        return f'"{x:,.6f}"' if abs(x) >= 1000 else f"{x:.6f}"
    rows = [[cell(float(c[i])) for c in columns()] for i in range(N)]
    with no_warnings():
        log = read_log(write_rows(tmp_path / "us.csv", rows))
    assert (CHANNELS["T48"][0] >= 1000).sum() > 5
    for name, v in zip(NAMES, columns()):
        got = log.time if name == "time" else log.channels[name]
        np.testing.assert_array_equal(got, [float(f"{x:.6f}") for x in v], err_msg=name)


# ---- B5, B7: MAT structs and unit cells ---------------------------------------------------------
def test_mat_struct_beside_other_variables(tmp_path):
    """One struct of the channels beside a text variable (and a struct of metadata): unwrapped,
    the text and scalars attributes; two structs of vectors: refused, naming both."""
    data = {"time": T, **{k: v for k, (v, _) in CHANNELS.items()}}
    scipy.io.savemat(tmp_path / "m.mat", {"flight": data, "engine": "ESN123", "info": {"flight_no": 7.0}})
    log = read_log(tmp_path / "m.mat")
    assert_values(log)
    assert log.attrs["engine"] == "ESN123" and log.attrs["flight_no"] == 7.0
    scipy.io.savemat(tmp_path / "two.mat", {"a": data, "b": data})
    with pytest.raises(LogError, match=r"two.mat: structs 'a', 'b' each hold vectors: which one is the log is "
                                       r"ambiguous"):
        read_log(tmp_path / "two.mat")


@pytest.mark.parametrize("shape", ["k x 2", "2 x k"])
def test_mat_units_cell_either_way_round(tmp_path, shape):
    """A units cell {names; units} (2 x k) was paired name with name; k x 2 as before."""
    cell = np.array([["time", "s"]] + [[k, u] for k, (_, u) in CHANNELS.items()], dtype=object)
    data = {"time": T, **{k: v for k, (v, _) in CHANNELS.items()}}
    scipy.io.savemat(tmp_path / "u.mat", data | {"units": cell if shape == "k x 2" else cell.T})
    log = read_log(tmp_path / "u.mat")
    assert log.units == {k: u for k, (_, u) in CHANNELS.items()}
    assert_values(log)


def test_mat_units_cell_without_column_names_is_refused(tmp_path):
    scipy.io.savemat(tmp_path / "u.mat", {"time": T, "Nf": CHANNELS["Nf"][0],
                                          "units": np.array([["rpm", "K", "Pa"]], dtype=object)})
    with pytest.raises(LogError, match=r"u.mat: variable 'units' \(shape \(3,\)\) pairs no column name with a unit: "
                                       r"write it as a k x 2 cell"):
        read_log(tmp_path / "u.mat")


# ---- B6: HDF5 attributes stored as arrays -------------------------------------------------------
def test_hdf5_attributes_stored_as_one_element_arrays(tmp_path):
    """unit = np.array([b"K"]) was a TypeError (unhashable); engine and flight_index arrays reached
    the fleet summary as array([b'ESN1']) and None. Read as str and int."""
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f.attrs["format"], f.attrs["format_version"] = "pwl-flight-log", 1
        f.attrs["engine"], f.attrs["flight_index"] = np.array([b"ESN1"]), np.array([3])
        f.attrs["flight_time"] = np.array(["2024-05-01T13:45:10"], dtype=h5py.string_dtype())
        f["time"] = T
        for k, (v, u) in CHANNELS.items():
            f[f"channels/{k}"] = v
            f[f"channels/{k}"].attrs["unit"] = np.array([u.encode()])
    log = read_log(tmp_path / "a.h5")
    assert log.units == {k: u for k, (_, u) in CHANNELS.items()}
    assert log.attrs == {"engine": "ESN1", "flight_index": 3, "flight_time": "2024-05-01T13:45:10"}
    assert type(log.attrs["flight_index"]) is int
    assert_values(log)
    # another layout through a channel map: its unit attributes too
    with h5py.File(tmp_path / "o.h5", "w") as f:
        f["time"] = T
        for k, (v, u) in CHANNELS.items():
            f[k] = v
            f[k].attrs["units"] = np.array([u.encode()])
    log = read_log(tmp_path / "o.h5", ChannelMap.from_dict({"channels": {k: k for k in CHANNELS}}))
    assert log.units == {k: u for k, (_, u) in CHANNELS.items()}


# ---- B8: Fortran D exponents --------------------------------------------------------------------
def test_fortran_d_exponents_are_numbers_not_a_units_row(tmp_path):
    """1.0D+03: the first data row was taken for a row of units and the values refused."""
    rows = rows_of(lambda x: f"{x:.16E}".replace("E", "D"))
    with no_warnings():
        log = read_log(write_rows(tmp_path / "d.csv", rows))
    np.testing.assert_array_equal(log.time, [float(f"{t:.16E}") for t in T])
    for k, (v, _) in CHANNELS.items():
        np.testing.assert_array_equal(log.channels[k], [float(f"{x:.16E}") for x in v], err_msg=k)


# ---- B9: tables in one variable; infinite values -------------------------------------------------
def test_hdf5_two_dimensional_and_compound_tables_read_through_a_channel_map(tmp_path):
    """A 2-D dataset with a 'names' attribute (and 'units'), or a compound dataset: the map names
    its columns by path (data/Nf); the hint without a map says so."""
    table = np.column_stack(columns())
    rec = np.zeros(N, dtype=[(n, "<f8") for n in NAMES])
    for n, v in zip(NAMES, columns()):
        rec[n] = v
    with h5py.File(tmp_path / "t.h5", "w") as f:
        f["data"] = table
        f["data"].attrs["names"] = np.array(NAMES, dtype=object)
        f["data"].attrs["units"] = np.array(["s"] + [u for _, u in CHANNELS.values()], dtype=object)
        f["rows"] = table.T                                     # k x n: names along the rows
        f["rows"].attrs["names"] = np.array([n.encode() for n in NAMES])
        f["records"] = rec
    for group in ("data", "rows", "records"):
        log = read_log(tmp_path / "t.h5", ChannelMap.from_dict({"channels": {k: f"{group}/{k}" for k in CHANNELS}}))
        assert_values(log)
        declared = {k: u for k, (_, u) in CHANNELS.items()}
        assert log.units == (declared if group == "data" else dict.fromkeys(CHANNELS, ""))
    with pytest.raises(LogError, match=r"t.h5: not a flight log.*reads with a channel map naming its columns by path.*"
                                       r"fields of a compound dataset.*a 2-D dataset with a 'names' attribute"):
        read_log(tmp_path / "t.h5")


@pytest.mark.parametrize("names", ["cell", "char"])
def test_mat_matrix_with_a_cell_of_names(tmp_path, names):
    """A MAT file of one n x k matrix and its k column names (a cell, or a char matrix)."""
    cell = np.array(NAMES, dtype=object) if names == "cell" else np.array([n.ljust(5) for n in NAMES])
    scipy.io.savemat(tmp_path / "m.mat", {"data": np.column_stack(columns()), "names": cell})
    assert_values(read_log(tmp_path / "m.mat"))


def test_mat73_matrix_with_a_char_matrix_of_names(tmp_path):
    """v7.3 (HDF5, column-major: MATLAB's n x k matrix stored k x n, its k x 5 char matrix of names
    5 x k as uint16): the char matrix was read as one string of all names interleaved and the log
    refused for its missing time."""
    with h5py.File(tmp_path / "m.mat", "w", userblock_size=512) as f:
        f["data"] = np.column_stack(columns()).T
        f["data"].attrs["MATLAB_class"] = np.bytes_("double")
        f["names"] = np.array([[ord(c) for c in n.ljust(5)] for n in NAMES], np.uint16).T
        f["names"].attrs["MATLAB_class"] = np.bytes_("char")
        f["engine"] = np.array([[ord(c) for c in "ESN7"]], np.uint16).T
        f["engine"].attrs["MATLAB_class"] = np.bytes_("char")
    log = read_log(tmp_path / "m.mat")
    assert_values(log)
    assert log.attrs["engine"] == "ESN7"


def test_infinite_values_are_named_and_numpy_warnings_do_not_leak():
    """inf on a fifth of the samples of the inlet pressure (an input of the air-data check) and of
    a sensor: numpy's RuntimeWarnings (overflow in p2 = DE * ..., in the numba ufunc _disagree)
    leaked with source lines; the sensor's inf was counted as missing and named nowhere. Now each
    channel is counted implausible and named, and nothing else is printed."""
    from pwl.demo_data import demo_paths
    from pwl.estimator import Estimator
    db_path, logs = demo_paths()
    full = read_log(logs[0])
    n = 2000
    for name in ("P2", "T48"):
        chans = {k: v[:n].copy() for k, v in full.channels.items()}
        chans[name][::5] = np.inf
        est = Estimator(db_path)
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            est.run(Log(full.time[:n], chans, full.units, path="inf.csv"))
        assert est.implausible[name] == n // 5
        assert not [w for w in got if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in got]
        assert any(f"inf.csv: channel {name!r}: {n // 5} of {n} samples implausible, typically inf" in str(w.message)
                   and "infinite values or spikes: a failed sensor" in str(w.message) for w in got), \
            [str(w.message) for w in got]


# ---- B10: a row of units in other spellings ------------------------------------------------------
@pytest.mark.parametrize("spelling", ["Celsius", "DEG_C", "deg.C"])
def test_common_spellings_of_celsius_in_a_units_row_and_header(tmp_path, spelling):
    """A row of units with T48 'Celsius' was warned about and taken as undeclared (T48 then failed
    as a sensor, exit 0), while T48[Celsius] in the header was refused. Both read as degC now."""
    rows = [r[:2] + [repr(float(r[2]) - 273.15)] + r[3:] for r in rows_of()]
    units = ["s", "rpm", spelling, "Pa", "kg/s"]
    with no_warnings():
        a = read_log(write_rows(tmp_path / "row.csv", rows, units=units))
    b = read_log(write_rows(tmp_path / "head.csv", rows, header=[f"{n}[{u}]" for n, u in zip(NAMES, units)]))
    for log in (a, b):
        assert log.units["T48"] == spelling
        np.testing.assert_allclose(log.require(["T48"], ["K"])[:, 0], CHANNELS["T48"][0], rtol=1e-15)


def test_an_unknown_unit_in_a_units_row_is_refused_like_one_in_the_header(tmp_path):
    """A unit pwl does not know, in a row of otherwise known units, is declared as written: refused
    where the model reads the channel, naming it and the known units, as T48[degX] in the header.
    A row mostly of no units ('EU') is still taken as undeclared (test_log_formats)."""
    units = ["s", "rpm", "degX", "Pa", "kg/s"]
    a = read_log(write_rows(tmp_path / "row.csv", rows_of(), units=units))
    b = read_log(write_rows(tmp_path / "head.csv", rows_of(), header=[f"{n}[{u}]" for n, u in zip(NAMES, units)]))
    for log, name in ((a, "row.csv"), (b, "head.csv")):
        with pytest.raises(LogError, match=rf"{name}: channel 'T48': unit 'degX' cannot be converted to 'K' "
                                           r"\('degX' is not a unit pwl knows: K, degC"):
            log.require(["T48"], ["K"])
        np.testing.assert_array_equal(log.require(["Nf"], ["rpm"])[:, 0], CHANNELS["Nf"][0])


# ---- time of day past midnight; encodings ---------------------------------------------------------
def test_times_of_day_continue_past_midnight(tmp_path):
    """HH:MM:SS.fff time stamps crossing midnight: 'time does not increase' before; continuous now."""
    day = [(86399.0 + t) % 86400.0 for t in T]           # from 23:59:59
    stamps = [f"{int(s // 3600):02d}:{int(s % 3600 // 60):02d}:{s % 60:06.3f}" for s in day]
    assert stamps[0] == "23:59:59.000" and "00:00:00.005" in stamps
    rows = [[s] + r[1:] for s, r in zip(stamps, rows_of())]
    log = read_log(write_rows(tmp_path / "tod.csv", rows))
    np.testing.assert_allclose(log.time, T, rtol=0, atol=1e-9)


def test_utf16_with_a_byte_order_mark_and_cp1252_read(tmp_path):
    """UTF-16 with a byte-order mark reads; cp1252 (Excel's 'CSV' on Windows: '°C' is one byte, 0xB0)
    was refused before and now reads as the UTF-8 file; bytes that are neither, past the first 64 KiB,
    say to save the file as UTF-8."""
    df = pd.DataFrame(dict(zip(["time[s]", "Nf[rpm]", "T48[K]", "P2[Pa]", "Wf[kg/s]"], columns())))
    df.to_csv(tmp_path / "u16.txt", sep="\t", index=False, encoding="utf-16")
    assert_values(read_log(tmp_path / "u16.txt"))
    celsius = df.assign(**{"T48[K]": df["T48[K]"] - 273.15}).rename(columns={"T48[K]": "T48[°C]"})
    celsius.to_csv(tmp_path / "w.csv", index=False, encoding="cp1252")
    celsius.to_csv(tmp_path / "u8.csv", index=False, encoding="utf-8")
    assert b"T48[\xb0C]" in (tmp_path / "w.csv").read_bytes()
    a, b = read_log(tmp_path / "w.csv"), read_log(tmp_path / "u8.csv")
    assert a.units == b.units and a.units["T48"] == "°C"
    np.testing.assert_array_equal(a.channels["T48"], b.channels["T48"])
    np.testing.assert_allclose(a.require(["T48"], ["K"])[:, 0], df["T48[K]"], rtol=1e-14)
    rows = "".join(f"{0.015 * i!r},1,2,3,4\n" for i in range(4000)).encode()
    assert len(rows) > 1 << 16
    (tmp_path / "late.csv").write_bytes(b"time,Nf,T48,P2,Wf\n" + rows + "60,1,2,3,4\xb0\n".encode("cp1252"))
    with pytest.raises(LogError, match=r"late.csv: unreadable CSV log \(UnicodeDecodeError: .*\): not UTF-8 text .*save "
                                       r"it as UTF-8"):
        read_log(tmp_path / "late.csv")


def test_duplicate_columns_left_out_unless_needed(tmp_path):
    """Export tools repeat names (two 'Spare' columns, a channel written twice): every such log was
    refused. Now copies of equal values are one column, a name shared by different values is left
    out and named, refused only where it is needed (a sensor then runs without it, the warning
    saying why)."""
    from pwl.demo_data import demo_paths
    from pwl.estimator import Estimator
    rows = [r + [str(i), str(-i), r[1]] for i, r in enumerate(rows_of())]
    log = read_log(write_rows(tmp_path / "d.csv", rows, header=NAMES + ["Spare", "Spare", "Nf"]))
    assert_values(log)
    assert list(log.attrs["left_out"]) == ["Spare"] and "Spare" not in log.channels
    with pytest.raises(LogError, match=r"d.csv: duplicate column 'Spare': its copies differ"):
        log.require(["Spare"])
    db_path, logs = demo_paths()
    full = read_log(logs[0])
    n = 1500
    df = pd.DataFrame({"time[s]": full.time[:n]} | {f"{k}[{full.units[k]}]": v[:n] for k, v in full.channels.items()})
    df.insert(3, "T48[K]", full.channels["T48"][:n] + 5.0, allow_duplicates=True)
    df.to_csv(tmp_path / "t48.csv", index=False)
    with pytest.warns(PwlWarning, match=r"no 'T48' channel \(.*t48.csv: duplicate column 'T48': its copies differ"):
        Estimator(db_path).run(read_log(tmp_path / "t48.csv"))


@pytest.mark.parametrize("units", [None, ["s", "rpm", "K", "Pa", "kg/s"]])
def test_files_joined_end_to_end_are_read_past_their_headers(tmp_path, units):
    """A log exported in three parts and joined end to end (``cat``), each part with its header
    (and row of units): every value exactly as written, and one warning naming the repeats.
    Before, the repeated header was 'non-numeric value 'time' at sample ...' and the log failed."""
    rows = rows_of()
    lines = []
    for part in (rows[:40], rows[40:90], rows[90:]):
        lines += [",".join(NAMES)] + ([",".join(units)] if units else []) + [",".join(r) for r in part]
    path = tmp_path / "joined.csv"
    path.write_text("\n".join(lines) + "\n")
    n_rep = 2 * (1 + bool(units))
    with pytest.warns(PwlWarning, match=rf"{n_rep} row\(s\) repeat the header or its units \(the first at sample 40\)"):
        log = read_log(path)
    assert_values(log)
    if units:
        assert log.units["T48"] == "K" and log.units["Nf"] == "rpm"
