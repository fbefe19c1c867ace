"""Log input formats (#15): CSV variants through pandas, Parquet, MAT v5 and v7.3, DataFrames and
channel maps give the same Log (and the same estimates) as pwl's own HDF5 log of the same data;
every defect is a LogError naming the file."""
import importlib.util
import sys

import h5py
import numpy as np
import pandas as pd
import pytest
import scipy.io

from pwl.channel_map import ChannelMap, ChannelMapError
from pwl.demo_data import demo_paths
from pwl.estimator import Estimator
from pwl.errors import PwlWarning
from pwl.logs import Log, LogError, read_log, write_log

M = 4000          # samples of the demo flight used (60 s at 15 ms: past the filter's 27 s settling)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """(estimator on the demo database, HDF5 path and Log of a demo-flight slice, its estimates).
    Wf and the last channel get a few missing samples: empty cells in CSV files."""
    tmp = tmp_path_factory.mktemp("formats")
    db_path, logs = demo_paths()
    full = read_log(logs[0])
    chans = {k: v[:M].copy() for k, v in full.channels.items()}
    chans["Wf"][[10, 11, 700]] = np.nan
    chans[sorted(chans)[-1]][M - 1] = np.nan       # and the last column (HDF5 orders by name)
    write_log(tmp / "ref.h5", Log(full.time[:M], chans, full.units))
    ref = read_log(tmp / "ref.h5")
    est = Estimator(db_path)
    return est, tmp / "ref.h5", ref, est.run(ref)


def frame(log, time="time[s]"):
    """The log as a DataFrame with pwl's ``name[unit]`` column names, time first."""
    return pd.DataFrame({time: log.time} | {f"{k}[{log.units[k]}]" if log.units[k] else k: v
                                            for k, v in log.channels.items()})


def assert_same_log(a, b, time_tol=0.0):
    assert list(a.channels) == list(b.channels) and a.units == b.units
    np.testing.assert_allclose(a.time, b.time, rtol=0, atol=time_tol) if time_tol else \
        np.testing.assert_array_equal(a.time, b.time)
    for k in b.channels:
        np.testing.assert_array_equal(a.channels[k], b.channels[k], err_msg=k)


def assert_same_estimates(a, b, rtol=0.0, scaled=False):
    """Equal flags and outputs, to ``rtol`` of each value (``scaled``: of its column's largest
    value, for inputs that differ in their last bits: residuals near 0 differ relatively more)."""
    np.testing.assert_array_equal(a.flags, b.flags)
    for o in b.outputs:
        if rtol:
            for j in range(b.outputs[o].shape[1]):
                x, y = a.outputs[o][:, j], b.outputs[o][:, j]
                atol = rtol * np.nanmax(np.abs(y)) if scaled else 0.0
                np.testing.assert_allclose(x, y, rtol=rtol, atol=atol, err_msg=f"{o}[:, {j}]")
        else:
            np.testing.assert_array_equal(a.outputs[o], b.outputs[o], err_msg=o)


# ---- CSV ----------------------------------------------------------------------------------------
STAMP0 = pd.Timestamp("2024-03-05T10:00:00+01:00")


@pytest.mark.parametrize("variant", ["pwl", "semicolon", "tab", "decimal-comma", "Time", "TIME",
                                     "timestamp", "t-milliseconds", "time-last", "blank-lines",
                                     "units-row", "units-in-parentheses", "comments-first", "spaces",
                                     "gzip", "zip", "txt", "no-extension"])
def test_csv_variants_read_as_the_hdf5_log(demo, tmp_path, variant):
    est, h5, ref, _ = demo
    df, kw, name, tol = frame(ref), {}, "log.csv", 0.0
    if variant == "pwl":
        write_log(tmp_path / name, ref)        # pwl's own writer (header units, repr values)
    else:
        if variant == "semicolon":
            kw = {"sep": ";"}
        elif variant == "tab":
            kw, name = {"sep": "\t"}, "log.tsv"
        elif variant == "decimal-comma":
            kw = {"sep": ";", "decimal": ","}
        elif variant in ("Time", "TIME"):
            df = df.rename(columns={"time[s]": variant})
        elif variant == "timestamp":       # ISO 8601 text with a time zone: seconds from the first
            df["time[s]"] = (STAMP0 + pd.to_timedelta(np.round(ref.time * 1e6), unit="us")).strftime(
                "%Y-%m-%dT%H:%M:%S.%f%z")
            df = df.rename(columns={"time[s]": "Timestamp"})
            tol = 1e-12
        elif variant == "t-milliseconds":
            df["time[s]"] = np.round(ref.time * 1e3, 9)
            df = df.rename(columns={"time[s]": "t[ms]"})
            tol = 1e-12
        elif variant == "time-last":
            df = df[list(df.columns[1:]) + ["time[s]"]]
        elif variant == "units-in-parentheses":     # Nf (rpm), Mach without a unit
            df = df.rename(columns=lambda c: c.replace("[", " (").replace("]", ")"))
        elif variant == "spaces":                   # space-separated columns, NaN written out
            kw, name = {"sep": " ", "na_rep": "NaN"}, "log.dat"
        elif variant in ("gzip", "zip"):
            name = f"log.csv.{'gz' if variant == 'gzip' else 'zip'}"
        elif variant in ("txt", "no-extension"):
            kw, name = {"sep": "\t"}, "log.txt" if variant == "txt" else "log"
        df.to_csv(tmp_path / name, index=False, **kw)
        if variant == "blank-lines":
            text = (tmp_path / name).read_text().splitlines()
            (tmp_path / name).write_text("\n".join(text[:5] + [""] + text[5:]) + "\n\n")
        elif variant == "units-row":                # a row of units (in capitals) under the names
            head = [c.split("[")[0] for c in df.columns]
            units = [(c.split("[")[1][:-1] if "[" in c else "").upper() for c in df.columns]
            text = (tmp_path / name).read_text().splitlines()
            (tmp_path / name).write_text("\n".join([",".join(head), ",".join(units)] + text[1:]) + "\n")
        elif variant == "comments-first":
            (tmp_path / name).write_text("# exported by a flight data tool\n#\n\n" + (tmp_path / name).read_text())
    log = read_log(tmp_path / name)
    if variant == "units-row":
        assert {k: u for k, u in log.units.items() if u} == {k: u.upper() for k, u in ref.units.items() if u}
        log.units = ref.units          # RPM and rpm are one unit (test_logs.py)
    assert_same_log(log, ref, tol)
    if variant == "timestamp":
        assert log.attrs["start_time"] == "2024-03-05T10:00:00+01:00"


def test_a_units_row_of_unknown_units_is_read_as_no_units_with_a_warning(demo, tmp_path):
    """A second row of text ("EU" for engineering units, a description) is not data: the log reads
    as without units, and a warning names the cells pwl does not know; known cells still count."""
    est, h5, ref, _ = demo
    df = frame(ref)
    head = [c.split("[")[0] for c in df.columns]
    units = ["s"] + ["EU"] * (len(head) - 2) + ["K" if head[-1].startswith("T") else "EU"]
    df.to_csv(tmp_path / "log.csv", index=False)
    text = (tmp_path / "log.csv").read_text().splitlines()
    (tmp_path / "log.csv").write_text("\n".join([",".join(head), ",".join(units)] + text[1:]) + "\n")
    with pytest.warns(PwlWarning, match=r"row 2 is read as the columns' units; not units pwl knows, so taken "
                                        rf"as undeclared: {head[1]} 'EU'"):
        log = read_log(tmp_path / "log.csv")
    assert {k: u for k, u in log.units.items() if u} == ({head[-1]: "K"} if units[-1] == "K" else {})
    np.testing.assert_array_equal(log.time, ref.time)
    for k in ref.channels:
        np.testing.assert_array_equal(log.channels[k], ref.channels[k], err_msg=k)


def test_timestamps_across_a_change_of_utc_offset_are_continuous(tmp_path):
    # a log recorded over the spring DST change in Europe: the offset goes from +01:00 to +02:00
    (tmp_path / "dst.csv").write_text("Timestamp,Nf[rpm]\n2024-03-31T01:59:59.970+01:00,1\n"
                                      "2024-03-31T01:59:59.985+01:00,2\n2024-03-31T03:00:00.000+02:00,3\n")
    log = read_log(tmp_path / "dst.csv")
    np.testing.assert_allclose(log.time, [0.0, 0.015, 0.030], rtol=0, atol=1e-12)
    assert log.attrs["start_time"] == "2024-03-31T00:59:59.970000+00:00"


def test_estimates_are_identical_from_every_format(demo, tmp_path):
    est, h5, ref, res = demo
    paths = {"csv": tmp_path / "log.csv", "mat5": tmp_path / "v5.mat", "mat73": tmp_path / "v73.mat"}
    frame(ref).to_csv(paths["csv"], sep=";", index=False)
    write_mat5(paths["mat5"], ref, "vectors")
    write_mat73(paths["mat73"], ref, "struct")
    if _has_pyarrow():
        paths["parquet"] = tmp_path / "log.parquet"
        frame(ref).to_parquet(paths["parquet"])
    for kind, p in paths.items():
        assert_same_estimates(est.run(p), res)        # the estimator reads the path itself
    assert_same_estimates(est.run(frame(ref)), res)   # Estimator.run(DataFrame)
    assert_same_estimates(est.run(frame(ref).set_index("time[s]")), res)
    assert est.run(paths["csv"]).source == str(paths["csv"])


# ---- Parquet ------------------------------------------------------------------------------------
def _has_pyarrow():
    return importlib.util.find_spec("pyarrow") is not None


@pytest.mark.skipif(not _has_pyarrow(), reason="pyarrow not installed (pip install 'pwl[parquet]')")
def test_parquet_reads_as_the_hdf5_log(demo, tmp_path):
    est, h5, ref, _ = demo
    frame(ref).to_parquet(tmp_path / "log.parquet")
    assert_same_log(read_log(tmp_path / "log.parquet"), ref)
    df = frame(ref).drop(columns="time[s]")       # datetime time column, native Parquet timestamps
    df.insert(0, "timestamp", pd.Timestamp("2024-01-01") + pd.to_timedelta(np.round(ref.time * 1e9), unit="ns"))
    df.to_parquet(tmp_path / "stamps.parquet")
    log = read_log(tmp_path / "stamps.parquet")
    assert_same_log(log, ref, 1e-12)
    assert log.attrs["start_time"] == "2024-01-01T00:00:00"


def test_parquet_without_pyarrow_says_what_to_install(demo, tmp_path, monkeypatch):
    (tmp_path / "log.parquet").write_bytes(b"PAR1")
    monkeypatch.setitem(sys.modules, "pyarrow", None)       # import pyarrow raises ImportError
    with pytest.raises(LogError, match=r"log.parquet: reading Parquet needs pyarrow: pip install 'pwl\[parquet\]'"):
        read_log(tmp_path / "log.parquet")


# ---- MAT ----------------------------------------------------------------------------------------
def write_mat5(path, log, layout):
    """MATLAB v5 through scipy: one variable per channel and a ``units`` struct ("vectors"), or one
    struct of vectors and a k x 2 ``units`` cell array ("struct"); plus text and scalar variables."""
    data = {"time": log.time} | dict(log.channels)
    if layout == "vectors":
        scipy.io.savemat(path, data | {"units": dict(log.units), "engine": "ESN001", "dt": 0.015})
    else:
        cell = np.array([[k, u] for k, u in log.units.items()], dtype=object)
        scipy.io.savemat(path, {"flight": data | {"engine": "ESN001"}, "units": cell})


def write_mat73(path, log, layout):
    """A MATLAB v7.3 MAT file laid out as MATLAB writes one (HDF5 behind a 512-byte MATLAB header;
    an n x 1 vector stored as (1, n) with MATLAB_class "double"; char as uint16 (len, 1); a struct
    as a group; a cell as object references into /#refs#), same layouts as :func:`write_mat5`."""
    def char(parent, name, text):
        if text:
            d = parent.create_dataset(name, data=np.array([[ord(c) for c in text]], np.uint16).T)
        else:
            d = parent.create_dataset(name, data=np.array([0, 0], np.uint64))
            d.attrs["MATLAB_empty"] = np.uint8(1)
        d.attrs["MATLAB_class"] = np.bytes_("char")
        return d

    with h5py.File(path, "w", userblock_size=512) as f:
        root = f
        if layout == "struct":
            root = f.create_group("flight")
            root.attrs["MATLAB_class"] = np.bytes_("struct")
        for k, v in ({"time": log.time} | log.channels).items():
            root.create_dataset(k, data=v.reshape(1, -1)).attrs["MATLAB_class"] = np.bytes_("double")
        char(root, "engine", "ESN001")
        if layout == "vectors":
            f.create_dataset("dt", data=np.array([[0.015]])).attrs["MATLAB_class"] = np.bytes_("double")
            g = f.create_group("units")
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for k, u in log.units.items():
                char(g, k, u)
        else:
            refs = f.create_group("#refs#")
            cells = [[char(refs, f"{k}_{j}", s).ref for j, s in enumerate((k, u))] for k, u in log.units.items()]
            d = f.create_dataset("units", data=np.array(cells, dtype=h5py.ref_dtype).T)   # k x 2 -> (2, k)
            d.attrs["MATLAB_class"] = np.bytes_("cell")
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Mar  5 10:00:00 2024 HDF5 "
                 b"schema 1.00 .".ljust(116) + bytes(8) + b"\x00\x02IM")


@pytest.mark.parametrize("version", ["v5", "v7.3"])
@pytest.mark.parametrize("layout", ["vectors", "struct"])
def test_mat_files_read_as_the_hdf5_log(demo, tmp_path, version, layout):
    est, h5, ref, _ = demo
    p = tmp_path / "log.mat"
    (write_mat5 if version == "v5" else write_mat73)(p, ref, layout)
    if version == "v7.3":   # independent check of the layout: scipy sees a v7.3 file and refuses it
        with pytest.raises(NotImplementedError, match="7.3"):
            scipy.io.loadmat(p)
    log = read_log(p)
    assert_same_log(log, ref)
    assert log.attrs["engine"] == "ESN001"
    if layout == "vectors":
        assert log.attrs["dt"] == 0.015


def test_mat_file_without_units_and_with_a_capitalised_time(demo, tmp_path):
    est, h5, ref, _ = demo
    scipy.io.savemat(tmp_path / "log.mat", {"Time": ref.time[:, None]} | dict(ref.channels))   # column vectors
    log = read_log(tmp_path / "log.mat")
    assert log.units == {k: "" for k in ref.channels}
    np.testing.assert_array_equal(log.require(list(ref.channels)), ref.require(list(ref.channels)))


# ---- DataFrames ---------------------------------------------------------------------------------
def test_dataframes_read_as_the_hdf5_log(demo):
    est, h5, ref, _ = demo
    df = frame(ref)
    assert_same_log(read_log(df), ref)                                    # time as a column
    assert_same_log(read_log(df.set_index("time[s]")), ref)               # numeric index named time
    stamps = pd.DatetimeIndex(pd.Timestamp("2024-01-01") + pd.to_timedelta(np.round(ref.time * 1e9), unit="ns"))
    log = read_log(df.drop(columns="time[s]").set_index(stamps))          # unnamed datetime index
    assert_same_log(log, ref, 1e-12)
    assert log.path == "<DataFrame>" and log.attrs["start_time"] == "2024-01-01T00:00:00"
    log = read_log(df)
    df.iloc[0, 1] = -1.0
    assert log.channels[df.columns[1].split("[")[0]][0] != -1.0          # the Log owns its arrays


# ---- channel maps -------------------------------------------------------------------------------
#: the user's columns for three channels, and their values from pwl's (K, Pa, kg/s)
USER = {"T2": ("TAT_C", "degC", lambda v: v - 273.15), "P2": ("P2_kPa", "kPa", lambda v: v / 1e3),
        "Wf": ("FuelFlow_lbs", "lb/s", lambda v: v / 0.45359237)}


def user_map(prefix=""):
    """[channels] lines of a channel map for :data:`USER`'s columns (``prefix``: an HDF5 group)."""
    lines = ["[channels]"]
    for k, (col, unit, _) in USER.items():
        lines.append(f'{k} = {{ column = "{prefix}{col}", unit = "{unit}" }}')
    return lines


def test_channel_map_reads_a_users_csv_and_hdf5_like_the_native_log(demo, tmp_path):
    est, h5, ref, res = demo
    others = [k for k in ref.channels if k not in USER]
    # a user's CSV: other names and units, time stamps, columns in another order, a text column
    df = pd.DataFrame({"Timestamp": (STAMP0 + pd.to_timedelta(np.round(ref.time * 1e6), unit="us")).strftime(
        "%Y-%m-%d %H:%M:%S.%f"), "Phase": "cruise"})
    for k, (col, unit, f) in USER.items():
        df[col] = f(ref.channels[k])
    for k in others:
        df[f"{k}[{ref.units[k]}]"] = ref.channels[k]
    df.to_csv(tmp_path / "user.csv", sep=";", index=False)
    (tmp_path / "user.toml").write_text("\n".join(['[time]', 'column = "Timestamp"'] + user_map("")
                                                  + [f'{k} = "{k}"' for k in others]) + "\n")
    cmap = ChannelMap.load(tmp_path / "user.toml")
    log = read_log(tmp_path / "user.csv", channel_map=tmp_path / "user.toml")
    assert sorted(log.channels) == sorted(ref.channels)            # "Phase" dropped, names mapped
    assert {k: log.units[k] for k in USER} == {k: u for k, (_, u, _) in USER.items()}
    assert log.attrs["channel_map"] == str(tmp_path / "user.toml")
    # the estimator converts the declared units back: same estimates as the native log
    assert_same_estimates(est.run(log), res, rtol=1e-9)
    assert_same_estimates(est.run(read_log(tmp_path / "user.csv", channel_map=cmap)), res, rtol=1e-9)
    # ChannelMap.apply on a log read without the map: the same channels
    plain = read_log(frame(ref).rename(columns={f"{k}[{ref.units[k]}]": USER[k][0] for k in USER}))
    applied = cmap.apply(plain)
    for k in USER:
        assert applied.units[k] == USER[k][1] and plain.units[USER[k][0]] == ""
    # an HDF5 file of another layout: one dataset per column in a group, time found beside them
    with h5py.File(tmp_path / "other.h5", "w") as f:
        g = f.create_group("data")
        g["Time"] = ref.time
        for k, (col, unit, fn) in USER.items():
            g[col] = fn(ref.channels[k])
        for k in others:
            g[k] = ref.channels[k]
            g[k].attrs["units"] = ref.units[k]
        f["notes"] = "not a column"
    (tmp_path / "h5.toml").write_text("\n".join(user_map("/data/") + [f'{k} = "data/{k}"' for k in others]) + "\n")
    log = read_log(tmp_path / "other.h5", channel_map=tmp_path / "h5.toml")
    assert log.units["Nf"] == "rpm" and log.units["Wf"] == "lb/s"
    assert_same_estimates(est.run(log), res, rtol=1e-9)


def test_speeds_in_percent_run_through_a_channel_map_scale(demo, tmp_path):
    """Engine data often log N1/N2 in percent of a reference speed: a declared '%' is refused
    with the way out named, and the map's scale gives the native estimates."""
    est, h5, ref, res = demo
    full = {"Nf": 4200.0, "Nc": 14600.0}      # rpm at 100 %
    df = frame(ref)
    for k, rpm in full.items():
        df = df.rename(columns={f"{k}[rpm]": f"{k}_pct[%]"})
        df[f"{k}_pct[%]"] = ref.channels[k] / rpm * 100.0
    df.to_csv(tmp_path / "pct.csv", index=False)
    bad = read_log(tmp_path / "pct.csv").channels
    renamed = read_log(pd.DataFrame({"time[s]": ref.time, "Nf[%]": bad["Nf_pct"]} |
                                    {f"{k}[{ref.units[k]}]": v for k, v in ref.channels.items() if k != "Nf"}))
    with pytest.raises(LogError, match=r"channel 'Nf': unit '%' \(percent\) cannot be converted to 'rpm' "
                                       r"\(rotational speed\); a channel map scales it"):
        est.run(renamed)
    others = [f'{k} = "{k}"' for k in ref.channels if k not in full]
    (tmp_path / "pct.toml").write_text("\n".join(["[channels]"] + others + [
        f'{k} = {{ column = "{k}_pct", unit = "rpm", scale = {rpm / 100.0} }}' for k, rpm in full.items()]) + "\n")
    log = read_log(tmp_path / "pct.csv", channel_map=tmp_path / "pct.toml")
    assert log.units["Nf"] == "rpm" and log.units["Nc"] == "rpm"
    np.testing.assert_allclose(log.channels["Nc"], ref.channels["Nc"], rtol=1e-15)   # to the last bits
    assert_same_estimates(est.run(log), res, rtol=1e-9, scaled=True)
    # an offset too: T2 logged in degC with no unit declared, mapped as K
    df["T2[K]"] = ref.channels["T2"] - 273.15
    df.rename(columns={"T2[K]": "TAT"}).to_csv(tmp_path / "c.csv", index=False)
    (tmp_path / "c.toml").write_text((tmp_path / "pct.toml").read_text().replace(
        'T2 = "T2"', 'T2 = { column = "TAT", unit = "K", offset = 273.15 }'))
    assert_same_estimates(est.run(read_log(tmp_path / "c.csv", channel_map=tmp_path / "c.toml")), res, rtol=1e-9,
                          scaled=True)


def test_channel_map_on_parquet_mat_and_dataframes(demo, tmp_path):
    est, h5, ref, _ = demo
    (tmp_path / "m.toml").write_text('[time]\ncolumn = "secs"\nunit = "min"\n[channels]\nFuel = "Wf"\n'
                                     'Tin = { column = "T2", unit = "K" }\n')
    df = frame(ref).rename(columns={"time[s]": "secs"})
    df["secs"] = ref.time / 60.0
    inputs = [df]
    scipy.io.savemat(tmp_path / "m.mat", {"secs": ref.time / 60.0} | dict(ref.channels))
    inputs.append(tmp_path / "m.mat")
    if _has_pyarrow():
        df.to_parquet(tmp_path / "m.parquet")
        inputs.append(tmp_path / "m.parquet")
    for source in inputs:
        log = read_log(source, channel_map=tmp_path / "m.toml")
        assert list(log.channels) == ["Fuel", "Tin"] and log.units["Tin"] == "K"
        np.testing.assert_allclose(log.time, ref.time, rtol=1e-14, atol=0)
        np.testing.assert_array_equal(log.channels["Fuel"], ref.channels["Wf"])
        np.testing.assert_array_equal(log.channels["Tin"], ref.channels["T2"])


# ---- errors -------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, content, match", [
    ("ragged.csv", b"time,Nf,T2\n0,1,2\n0.1,1\n", r"ragged.csv: row 3 has 2 field\(s\), the header has 3"),
    ("long.csv", b"time,Nf\n0,1,2\n0.1,1\n", "long.csv: row 2 has more fields than the header"),
    ("long2.csv", b"time,Nf\n0,1\n0.1,1,5\n", "long2.csv: unreadable CSV log.*Expected 2 fields in line 3"),
    ("badtime.csv", b"time,Nf\n0,1\nnoon,1\n", "badtime.csv: column 'time': non-numeric value 'noon'"
                                               ".*not ISO 8601 date-times or durations"),
    ("utf.csv", b"time,Nf\n0,1\n0.1,\x81\x8d1\n", "utf.csv: unreadable CSV log.*UnicodeDecodeError"),
    ("dup.csv", b"Time,Nf,Time\n0,1,0\n", r"dup.csv: columns \[.Time., .Time.\] could each be the time"),
    ("twotimes.csv", b"time,Time,Nf\n0,0,1\n", r"twotimes.csv: columns \['time', 'Time'\] could each be the time"),
    ("notime.csv", b"N1,N2\n0,1\n", "notime.csv: no 'time' column .*columns: 'N1', 'N2'"),
    ("unit.csv", b"time[fortnights],Nf\n0,1\n", "unit.csv: time column 'time': unit 'fortnights'"),
    ("empty.csv", b"", "empty.csv: the file is empty"),
    ("header.csv", b"time,Nf\n", "header.csv: the log is empty"),
    ("junk.parquet", b"not parquet at all", "junk.parquet: unreadable Parquet log"),
    ("junk.mat", b"MATLAB 5.0 MAT-file" + bytes(200), "junk.mat: unreadable MAT log"),
    ("junk.h5", b"\x89HDF\r\n" + bytes(100), "junk.h5: not a readable HDF5 log"),
])
def test_damaged_files_are_named_errors(tmp_path, name, content, match):
    if name.endswith(".parquet") and not _has_pyarrow():
        pytest.skip("pyarrow not installed")
    (tmp_path / name).write_bytes(content)
    with pytest.raises(LogError, match=match):
        read_log(tmp_path / name)


def test_mat_and_dataframe_errors_name_the_column(tmp_path):
    scipy.io.savemat(tmp_path / "m.mat", {"time": np.arange(3.0), "block": np.ones((3, 2))})
    with pytest.raises(LogError, match=r"m.mat: column 'block' has shape \(3, 2\)"):
        read_log(tmp_path / "m.mat").require(["block"])      # left out until a channel needs it
    scipy.io.savemat(tmp_path / "short.mat", {"time": np.arange(3.0), "Nf": np.ones(2)})
    with pytest.raises(LogError, match="short.mat: column 'Nf' has 2 samples, the time column 3"):
        read_log(tmp_path / "short.mat")
    with pytest.raises(LogError, match="<DataFrame>: no 'time' column"):
        read_log(pd.DataFrame({"Nf": [1.0, 2.0]}))
    with pytest.raises(LogError, match="<DataFrame>: column 'when' holds datetime64"):
        read_log(pd.DataFrame({"time": [0.0, 1.0], "when": pd.to_datetime(["2024-01-01", "2024-01-02"])})).require(["when"])
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["time"] = np.arange(3.0)
    with pytest.raises(LogError, match="other.h5: not a flight log.*reads with a channel map"):
        read_log(tmp_path / "other.h5")


@pytest.mark.parametrize("toml, match", [
    ('[channels\nWf = "a"', r"m.toml: not a readable TOML file"),
    ('[channels]\nWf = 3\n', r"m.toml: \[channels\] Wf: expected a table or a column name, got int 3"),
    ('[channels]\nWf = { column = "a", unit = 1 }\n', r"m.toml: \[channels\] Wf unit: expected a string"),
    ('[channels]\nWf = { column = "a", unit = "lbs" }\n',
     r"m.toml: \[channels\] Wf unit: 'lbs' is not a unit pwl knows"),
    ('[channels]\nWf = { col = "a" }\n', r"m.toml: \[channels\] Wf col: unknown key \(allowed: column, unit, scale, offset, lag\)"),
    ('[channels]\nWf = { column = "a", scale = 0 }\n', r"m.toml: \[channels\] Wf scale: must not be 0"),
    ('[channels]\nWf = { column = "a", scale = "2" }\n', r"m.toml: \[channels\] Wf scale: expected a finite number"),
    ('[channels]\nWf = { column = "a", scale = true }\n', r"m.toml: \[channels\] Wf scale: expected a finite"),
    ('[channels]\nWf = { column = "a", offset = nan }\n', r"m.toml: \[channels\] Wf offset: expected a finite"),
    ('[channels]\nWf = { unit = "kg/s" }\n', r"m.toml: \[channels\] Wf: needs a non-empty column"),
    ('[channel]\nWf = "a"\n', r"m.toml: channel: unknown key"),
    ('[time]\ncolumn = "t"\n', r"m.toml: \[channels\]: missing or empty"),
    ('[time]\nunit = "K"\n[channels]\nWf = "a"\n', r"m.toml: \[time\] unit: 'K' is not a unit of time"),
    ('time = 5\n[channels]\nWf = "a"\n', r"m.toml: \[time\]: expected a table or a column name, got int 5"),
])
def test_channel_map_errors_name_the_file_and_key(tmp_path, toml, match):
    (tmp_path / "m.toml").write_text(toml)
    with pytest.raises(ChannelMapError, match=match):
        ChannelMap.load(tmp_path / "m.toml")


def test_channel_map_errors_against_a_log_name_both_files(tmp_path):
    (tmp_path / "log.csv").write_text("time[s],FF[kg/s],T[K]\n0,1,2\n0.1,1,2\n")
    (tmp_path / "m.toml").write_text('[channels]\nWf = { column = "FuelFlow", unit = "lb/s" }\n')
    with pytest.raises(LogError, match=r"log.csv: column 'FuelFlow' is missing \(.*m.toml: \[channels\] Wf; "
                                       r"log has: time, FF, T\)"):
        read_log(tmp_path / "log.csv", channel_map=tmp_path / "m.toml")
    (tmp_path / "m.toml").write_text('[channels]\nWf = { column = "FF", unit = "lb/s" }\n')
    with pytest.raises(LogError, match=r"log.csv: column 'FF' \(.*m.toml: \[channels\] Wf\): the log declares "
                                       r"unit 'kg/s', the channel map 'lb/s'"):
        read_log(tmp_path / "log.csv", channel_map=tmp_path / "m.toml")
    (tmp_path / "m.toml").write_text('[time]\ncolumn = "clock"\n[channels]\nWf = "FF"\n')
    with pytest.raises(LogError, match=r"log.csv: no time column 'clock'"):
        read_log(tmp_path / "log.csv", channel_map=tmp_path / "m.toml")
    with pytest.raises(ChannelMapError, match="nope.toml: no such file"):
        read_log(tmp_path / "log.csv", channel_map=tmp_path / "nope.toml")
    # a column the map drops may hold anything; one it reads may not
    (tmp_path / "log.csv").write_text("time,FF,Note\n0,1,fine\n0.1,2,ok\n")
    (tmp_path / "m.toml").write_text('[channels]\nWf = "FF"\n')
    assert read_log(tmp_path / "log.csv", channel_map=tmp_path / "m.toml").channels["Wf"].tolist() == [1.0, 2.0]
    # without a map a text column is left out, named; a channel that needs it is refused
    log = read_log(tmp_path / "log.csv")
    assert list(log.channels) == ["FF"] and list(log.attrs["left_out"]) == ["Note"]
    with pytest.raises(LogError, match="log.csv: column 'Note': non-numeric value 'fine' at sample 0"):
        log.require(["Note"])
    (tmp_path / "text.csv").write_bytes(b"time;Nf\n0;1\n0.1;1.2.3\n")
    with pytest.raises(LogError, match=r"text.csv: column 'Nf': non-numeric value '1.2.3' at sample 1"):
        read_log(tmp_path / "text.csv").require(["Nf"])


def test_pwl_run_reads_a_folder_of_user_files_through_a_channel_map(demo, tmp_path):
    """pwl run --channel-map: a folder holding a user's CSV and an HDF5 file of another layout
    (and a gain database, skipped) gives the native log's estimates; the map is in the mode, so
    a rerun with it skips both logs and a run without it is refused for the HDF5 file."""
    from pwl.cli import main
    from pwl.results import Result

    est, h5, ref, res = demo
    logs = tmp_path / "logs"
    logs.mkdir()
    df = pd.DataFrame({"time": ref.time})
    for k, v in ref.channels.items():
        df[USER[k][0] if k in USER else k] = USER[k][2](v) if k in USER else v
    df.to_csv(logs / "user.csv", index=False)
    with h5py.File(logs / "other.h5", "w") as f:
        f["time"] = ref.time
        for c in df.columns[1:]:
            f[c] = df[c].to_numpy()
    (tmp_path / "map.toml").write_text("\n".join(user_map() + [
        f'{k} = {{ column = "{k}", unit = "{ref.units[k]}" }}' for k in ref.channels if k not in USER]) + "\n")
    import shutil
    shutil.copy(est.db.path, logs / "db.h5")
    argv = ["run", est.db.path, str(logs), "-o", str(tmp_path / "out"), "-j", "1",
            "--channel-map", str(tmp_path / "map.toml")]
    assert main(argv) == 0
    for name in ("user", "other"):
        got = Result.load(tmp_path / "out" / f"{name}.estimates.h5")
        np.testing.assert_allclose(got.outputs["z_hat"], res.z_hat, rtol=1e-9)
    assert main(argv) == 0       # resumed: both skipped (same map)
    assert main(["run", est.db.path, str(logs / "other.h5"), "-o", str(tmp_path / "o2"), "-j", "1"]) == 1


def test_a_few_text_cells_in_a_sensor_column_are_missing_values(tmp_path):
    """Loggers write ERR or - where a sensor had no value: fewer than half such cells are
    read as missing (NaN; counted in the log's attrs and warned about), so the flight still runs
    with the other sensors; a column mostly of text is left out, and refused, naming it, where
    the estimator needs it."""
    from pwl.errors import PwlWarning
    rows = ["time,Nf,T30"] + [f"{0.1 * i:.1f},{1000 + i},{700 + i}" for i in range(10)]
    rows[3] = "0.2,1002,ERR"
    rows[6] = "0.5,1005,-"
    (tmp_path / "log.csv").write_text("\n".join(rows) + "\n")
    with pytest.warns(PwlWarning, match=r"log.csv: column 'T30': 2 non-numeric value\(s\) read as missing "
                                        r"\(the first 'ERR' at sample 2\)"):
        log = read_log(tmp_path / "log.csv")
    want = 700.0 + np.arange(10)
    want[[2, 5]] = np.nan
    np.testing.assert_array_equal(log.channels["T30"], want)
    assert log.attrs["non_numeric"] == {"T30": 2}
    rows = ["time,Nf,T30"] + [f"{0.1 * i:.1f},{1000 + i},{'ERR' if i % 2 else 700}" for i in range(10)]
    (tmp_path / "bad.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(LogError, match=r"bad.csv: column 'T30': non-numeric value 'ERR' at sample 1 "
                                       r"\(5 of its 10 values are not numbers\)"):
        read_log(tmp_path / "bad.csv").require(["Nf", "T30"])


def test_a_row_logged_twice_is_dropped_and_a_conflicting_one_refused(tmp_path):
    """A logger that wrote a row twice: the copy (same time, same values, NaN where the first
    has NaN) is dropped, counted and warned about; two rows at one time with different values
    are refused, naming the sample."""
    from pwl.errors import PwlWarning
    rows = ["time,Nf,T30", "0.0,1000,700", "0.1,1001,", "0.1,1001,", "0.2,1002,702"]
    (tmp_path / "twice.csv").write_text("\n".join(rows) + "\n")
    with pytest.warns(PwlWarning, match=r"twice.csv: 1 repeated row\(s\) dropped .* sample 2, time 0.1"):
        log = read_log(tmp_path / "twice.csv")
    np.testing.assert_array_equal(log.time, [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(log.channels["Nf"], [1000.0, 1001.0, 1002.0])
    assert np.isnan(log.channels["T30"][1]) and log.attrs["repeated_rows"] == 1
    rows[3] = "0.1,1001,701"
    (tmp_path / "clash.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(LogError, match=r"clash.csv: time does not increase at sample 2 \(0.1 -> 0.1\)"):
        read_log(tmp_path / "clash.csv")


def test_rows_a_little_out_of_order_are_sorted_and_a_restarted_clock_refused(tmp_path):
    """Two neighbouring rows swapped and one row three places late (a logger merging buffers):
    sorted by time, values with their rows, counted and warned about. A clock that restarts
    (two flights in one file) is refused as before."""
    from pwl.errors import PwlWarning
    t = np.round(0.1 * np.arange(20), 1)
    order = np.arange(20)
    order[[3, 4]] = order[[4, 3]]
    order[10:14] = [11, 12, 13, 10]
    pd.DataFrame({"time": t[order], "Nf": 1000.0 + order}).to_csv(tmp_path / "merged.csv", index=False)
    with pytest.warns(PwlWarning, match=r"merged.csv: 2 row\(s\) out of time order put in order \(the first at "
                                        r"sample 4, time 0.3 after 0.4\)"):
        log = read_log(tmp_path / "merged.csv")
    np.testing.assert_array_equal(log.time, t)
    np.testing.assert_array_equal(log.channels["Nf"], 1000.0 + np.arange(20))
    assert log.attrs["reordered_rows"] == 2
    pd.DataFrame({"time": np.r_[t, t + 0.05], "Nf": 1.0}).to_csv(tmp_path / "restart.csv", index=False)
    with pytest.raises(LogError, match=r"restart.csv: time does not increase at sample 20"):
        read_log(tmp_path / "restart.csv")


@pytest.mark.parametrize("name, what", [("log.xlsx", "Excel"), ("log.json", "JSON")])
def test_formats_pwl_does_not_read_are_named_with_the_way_in(tmp_path, name, what):
    (tmp_path / name).write_text("{}")
    with pytest.raises(LogError, match=f"{name}: {what} is not a log format pwl reads .*pass the DataFrame"):
        read_log(tmp_path / name)


def test_an_hdf5_log_under_another_extension_is_read_as_hdf5(demo, tmp_path):
    import shutil
    _, h5, ref, _ = demo
    shutil.copy(h5, tmp_path / "flight.bin")
    assert_same_log(read_log(tmp_path / "flight.bin"), ref)


def test_an_empty_cell_in_space_separated_text_is_named_not_shifted(tmp_path):
    (tmp_path / "log.dat").write_text("time Nf Nc\n0 1 2\n0.015  2\n0.03 1 2\n")
    with pytest.raises(LogError, match="log.dat: row 3 has 2 field.*the header has 3 .*write NaN"):
        read_log(tmp_path / "log.dat")
