"""Results files other tools open (issue #15): netCDF-4 readers (xarray with h5netcdf) see named
``time`` and channel coordinates and per-channel units, ``Result.to_dataframe`` is one column per
``output.channel`` with time as the index, and files of format version 1 still read."""
import os

import h5py
import numpy as np
import pytest

from pwl.estimator import Estimator
from pwl.fleet.runs import run_many
from pwl.h5io import write_strings
from pwl.results import FORMAT_VERSION, Result, ResultError, file_summary, open_results

from test_fleet_run import DB, slice_log


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One short log with a steady snapshot, its in-memory result and its results file (all outputs)."""
    d = tmp_path_factory.mktemp("interop")
    log = slice_log(d / "log.h5", n=4500)
    est = Estimator(DB)
    est.run_file(log, d / "log.estimates.h5")
    return est, est.run(log), str(d / "log.estimates.h5")


def test_xarray_opens_results_with_time_and_channel_coordinates(run, tmp_path):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    est, whole, path = run
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert not [d for d in ds.dims if str(d).startswith("phony_dim")]
        np.testing.assert_array_equal(ds["time"].values, whole.time)
        assert ds["time"].attrs["units"] == "s"
        np.testing.assert_array_equal(ds["flags"].values, whole.flags)
        assert ds["flags"].dims == ("time",)
        for o, names in est.names.items():
            assert ds[o].dims == ("time", f"{o}_channel")
            assert list(ds[f"{o}_channel"].values) == names
            np.testing.assert_array_equal(ds[o].values, whole.outputs[o])
        assert list(ds["z_hat"].attrs["units"]) == [est.db.units["z"][est.db.names["z"].index(c)]
                                                    for c in est.names["z_hat"]]
        assert list(ds["residual"].attrs["units"]) == list(est.db.units["y"])
        t40 = ds["z_hat"].sel(z_hat_channel="T40")               # select by channel name
        np.testing.assert_array_equal(t40.values, whole.channel("z_hat", "T40"))
    thin = str(tmp_path / "thin.estimates.h5")
    est.run_file(whole.source, thin, outputs=["h_hat"], every=4)
    with xr.open_dataset(thin, engine="h5netcdf") as ds:
        assert set(ds.data_vars) == {"flags", "h_hat"} and ds.sizes["time"] == 1125
        np.testing.assert_array_equal(ds["time"].values, whole.time[::4])


def test_to_dataframe_matches_the_arrays(run):
    pd = pytest.importorskip("pandas")
    est, whole, path = run
    for res in (whole, Result.load(path)):
        df = res.to_dataframe()
        assert df.index.name == "time"
        np.testing.assert_array_equal(df.index.to_numpy(), whole.time)
        np.testing.assert_array_equal(df["flags"].to_numpy(), whole.flags)
        assert len(df.columns) == 1 + sum(len(v) for v in est.names.values())
        for o, names in est.names.items():
            for j, c in enumerate(names):
                np.testing.assert_array_equal(df[f"{o}.{c}"].to_numpy(), whole.outputs[o][:, j])
        assert isinstance(df, pd.DataFrame)


def test_load_gives_the_run_with_units_and_attributes(run):
    est, whole, path = run
    back = Result.load(path)
    assert back.names == est.names
    for o in whole.outputs:
        np.testing.assert_array_equal(back.outputs[o], whole.outputs[o])
    assert back.units["h_hat"] == list(est.db.units["h"]) and back.units["x_hat"] == list(est.db.units["x"])
    assert int(back.attrs["format_version"]) == FORMAT_VERSION and back.attrs["every"] == 1
    assert back.attrs["database_digest"] == est.db.digest
    np.testing.assert_array_equal(back.snapshots.mean, whole.snapshots.mean)


def test_version_1_files_still_read(run, tmp_path):
    """A results file as pwl wrote it before dimension scales (format version 1)."""
    _, whole, _ = run
    path = tmp_path / "v1.estimates.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "pwl-estimates", "format_version": 1, "source": "log.h5",
                        "engine": "ESN7", "flight_index": 3} | whole.counts())
        f["time"], f["flags"], f["z_hat"] = whole.time, whole.flags, whole.z_hat
        write_strings(f.create_group("names"), "z_hat", whole.names["z_hat"])
        whole.snapshots.save(f.create_group("snapshots"))
    back = Result.load(path)
    np.testing.assert_array_equal(back.z_hat, whole.z_hat)
    assert back.units == {}
    with open_results(path) as f:
        row = file_summary(f)
    assert row["engine"] == "ESN7" and row["flight_index"] == 3 and row["samples"] == len(whole.time)
    assert row["h_hat.hpc_eff"] == whole.snapshots.outputs["h_hat"][-1, whole.names["h_hat"].index("hpc_eff")]
    assert not [k for k in row if k.startswith("rms.")]             # version 1 had no residual RMS


def test_foreign_and_newer_files_are_named_errors(run, tmp_path):
    _, whole, _ = run
    (tmp_path / "junk.h5").write_text("junk")
    with pytest.raises(ResultError, match="junk.h5"):
        Result.load(tmp_path / "junk.h5")
    with h5py.File(tmp_path / "new.h5", "w") as f:
        f.attrs["format"], f.attrs["format_version"] = "pwl-estimates", FORMAT_VERSION + 1
    with pytest.raises(ResultError, match=f"new.h5.*version {FORMAT_VERSION + 1}"):
        Result.load(tmp_path / "new.h5")


def test_every_fleet_results_file_opens_in_xarray(tmp_path):
    """What pwl run writes for a fleet (engine tree, thinned, lzf) opens as netCDF too."""
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    logs = [slice_log(tmp_path / "logs" / e / "f.h5", n=600, engine=e) for e in ("A", "B")]
    for r in run_many(DB, logs, tmp_path / "out", workers=1, outputs="z_hat", every=3,
                      compression="lzf"):
        with xr.open_dataset(r.output, engine="h5netcdf") as ds:
            assert ds.attrs["engine"] == os.path.basename(os.path.dirname(r.log))
            assert ds["z_hat"].sizes == {"time": 200, "z_hat_channel": 5}
