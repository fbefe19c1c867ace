"""The numba runtime against the plain numpy/scipy reference; streaming vs batch; bad logs."""
import os
import numpy as np
import pytest

from conftest import make_database
from pwl.bench.reference import ReferenceFilter
from pwl.estimator import EnvelopeError, Estimator
from pwl.logs import Log, LogError, write_log
from pwl.runtime import FLAG_DYN_OUTSIDE, FLAG_HELD_INPUT, FLAG_NO_UPDATE, FLAG_PARTIAL, FLAG_TRIM_OUTSIDE


def inputs(db, n=400, seed=0, outside=False, margin=0.2):
    """Random-walk operating point through the grid box (optionally leaving it), noisy channels."""
    rng = np.random.default_rng(seed)
    lo = np.array([a.lo for a in db.trim_grid.axes])
    hi = np.array([a.hi for a in db.trim_grid.axes])
    u01 = np.abs(((np.cumsum(rng.normal(0, 0.03, (n, 2)), axis=0) + 0.5) + 1) % 2 - 1)
    if outside:
        u01 = u01 * (1 + 2 * margin) - margin
    p = lo + u01 * (hi - lo)
    TH = 1.0 + 0.05 * rng.random(n)
    DE = 0.8 + 0.2 * rng.random(n)
    # schedule channel 1 is "c1" corrected, scale 2: raw = p1 / 2 * theta^a delta^b
    S = np.empty((n, 2))
    S[:, 0] = p[:, 0]
    c = db.correction
    a, b = (c.exponents["y"][1] if c is not None else (0.0, 0.0))
    S[:, 1] = p[:, 1] / 2.0 * TH ** a * DE ** b
    U = 1.0 + 0.1 * rng.random((n, db.n("u")))
    Y = 1.0 + 0.1 * rng.random((n, db.n("y")))
    Y[:, 1] = S[:, 1]  # the corrected schedule channel is the measured y1
    return U, Y, S, TH, DE


def open_loop_y(db, U, S, TH, DE):
    """(n, ny) what the model predicts the sensors read, open loop (a run without measurements):
    inputs for a log the model explains."""
    Y = np.full((U.shape[0], db.n("y")), np.nan)
    return Estimator(db).run_arrays(U, Y, S, TH, DE).outputs["y_hat"]


def names_db(**kw):
    db = make_database(**kw)
    db.schedule = [("p0", False, 1.0), ("y1", True, 2.0)]   # p1 from channel y1, corrected
    return db


@pytest.mark.parametrize("kw", [{}, {"policy": "extrapolate"}, {"correction": False},
                                {"trim_shape": (4, 3), "dyn_shape": (2, 2), "nq": 0}])
def test_runtime_equals_numpy_reference(kw):
    db = names_db(**kw)
    est = Estimator(db)
    # extrapolated random matrices soon make an unstable filter: leave the grid by 5 % only
    U, Y, S, TH, DE = inputs(db, outside="policy" in kw, margin=0.05)
    res = est.run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db).run(U, Y, S, TH, DE)
    for o, v in ref.items():
        np.testing.assert_allclose(res.outputs[o], v, rtol=1e-10, atol=1e-10 * np.abs(v).max(initial=1.0), err_msg=o)


def test_streaming_equals_batch_exactly():
    db = names_db()
    est = Estimator(db)
    U, Y, S, TH, DE = inputs(db, n=100)
    Y[10:15, 0] = np.nan
    batch = est.run_arrays(U, Y, S, TH, DE)
    est.reset()
    for k in range(100):
        r = est.run_arrays(U[k:k + 1], Y[k:k + 1], S[k:k + 1], TH[k:k + 1], DE[k:k + 1])
        for o in batch.outputs:
            np.testing.assert_array_equal(r.outputs[o][0], batch.outputs[o][k])
        assert r.flags[0] == batch.flags[k]


def test_step_api_matches_run(tmp_path):
    db = names_db()
    est = Estimator(db)
    U, Y, S, TH, DE = inputs(db, n=30)
    chans = {"u0": U[:, 0], "p0": S[:, 0], "Tin": TH * 288.15, "Pin": DE * 101325.0}
    chans.update({f"y{j}": Y[:, j] for j in range(db.n("y"))})
    units = {"u0": "unit_u0", "p0": "unit_p0", **{f"y{j}": f"unit_y{j}" for j in range(db.n("y"))}}
    log = Log(np.arange(30) * db.dt, chans, units, path="mem")
    batch = est.run(log)
    est.reset()
    for k in range(30):
        r = est.step({c: v[k] for c, v in chans.items()})
        assert r["z_hat"]["z1"] == batch.channel("z_hat", "z1")[k]
        assert r["h_hat"]["h2"] == batch.channel("h_hat", "h2")[k]


def test_all_measurements_nan_is_prediction_only():
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=60)
    Y2 = Y.copy()
    Y2[20:30] = np.nan
    a = Estimator(db).run_arrays(U, Y, S, TH, DE)
    b = Estimator(db).run_arrays(U, Y2, S, TH, DE)
    assert np.all(b.flags[20:30] & FLAG_NO_UPDATE) and not np.any(b.flags[:20] & FLAG_NO_UPDATE)
    np.testing.assert_array_equal(a.q_hat[:20], b.q_hat[:20])
    # no update: the tuners (random walk, A = I on q) stay where they were (interpolated
    # identity: the corner weights sum to 1 within rounding)
    np.testing.assert_allclose(b.q_hat[20:30], np.repeat(b.q_hat[19:20], 10, axis=0), rtol=1e-14)
    assert np.all(np.isfinite(b.z_hat))


def test_nan_input_is_held_and_flagged():
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=40)
    U2, S2 = U.copy(), S.copy()
    U2[10] = np.nan
    S2[11, 0] = np.nan
    U3, S3 = U.copy(), S.copy()
    U3[10] = U3[9]
    S3[11, 0] = S3[10, 0]
    b = Estimator(db).run_arrays(U2, Y, S2, TH, DE)
    c = Estimator(db).run_arrays(U3, Y, S3, TH, DE)
    assert b.flags[10] & FLAG_HELD_INPUT and b.flags[11] & FLAG_HELD_INPUT
    for o in b.outputs:
        np.testing.assert_array_equal(b.outputs[o], c.outputs[o])


def test_inf_samples_are_treated_like_nan():
    # ten +-Inf samples in a sensor, an input and theta: exactly the run with NaN there (the
    # filter recovers), not NaN estimates from then on
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=60)
    runs = []
    for bad in (np.nan, np.inf):
        Y2, U2, TH2 = Y.copy(), U.copy(), TH.copy()
        Y2[20:30, 1] = bad
        U2[33:35, 0] = -bad
        TH2[40] = bad
        runs.append(Estimator(db).run_arrays(U2, Y2, S, TH2, DE))
    a, b = runs
    np.testing.assert_array_equal(a.flags, b.flags)
    assert np.all(b.flags[20:30] & FLAG_PARTIAL) and b.flags[33] & FLAG_HELD_INPUT and b.flags[40] & FLAG_HELD_INPUT
    for o in a.outputs:
        np.testing.assert_array_equal(a.outputs[o][np.isfinite(a.outputs[o])],
                                      b.outputs[o][np.isfinite(a.outputs[o])])
    assert np.all(np.isfinite(b.z_hat[30:]))


def test_leading_nans_start_later():
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=20)
    U[:3] = np.nan
    r = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.all(np.isnan(r.z_hat[:3])) and np.all(np.isfinite(r.z_hat[3:]))
    ref = Estimator(db).run_arrays(U[3:], Y[3:], S[3:], TH[3:], DE[3:])
    np.testing.assert_array_equal(r.z_hat[3:], ref.z_hat)


def test_out_of_envelope_clip_flags_and_error_policy():
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=200, outside=True)
    r = Estimator(db).run_arrays(U, Y, S, TH, DE)
    out = r.flags & (FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE)
    assert 0 < np.count_nonzero(out) < 200
    assert r.counts()["trim_outside"] == np.count_nonzero(r.flags & FLAG_TRIM_OUTSIDE)
    db_err = names_db(policy="error")
    est = Estimator(db_err)
    with pytest.raises(EnvelopeError, match="outside the database grid at sample"):
        est._check_envelope(r.flags, np.arange(200.0), "log.h5")


def full_log(db, n=300, seed=0):
    U, Y, S, TH, DE = inputs(db, n=n, seed=seed)
    chans = {"u0": U[:, 0], "p0": S[:, 0], "Tin": TH * 288.15, "Pin": DE * 101325.0}
    chans.update({f"y{j}": Y[:, j] for j in range(db.n("y"))})
    units = {"u0": "unit_u0", "p0": "unit_p0", **{f"y{j}": f"unit_y{j}" for j in range(db.n("y"))}}
    return Log(np.arange(n) * db.dt, chans, units, attrs={"dt": db.dt})


@pytest.mark.parametrize("name", ["log.h5", "log.csv"])
def test_chunked_file_run_equals_whole_run(tmp_path, name):
    """HDF5 logs are read a chunk at a time, CSV logs whole; both are filtered and written a
    chunk at a time (bounded output memory): the results file equals the whole in-memory run bit
    for bit."""
    import h5py
    db = names_db()
    log = full_log(db, n=1000)
    write_log(tmp_path / name, log)
    est = Estimator(db)
    whole = est.run(tmp_path / name)
    counts = est.run_file(tmp_path / name, tmp_path / "res.h5", chunk=137)
    with h5py.File(tmp_path / "res.h5") as f:
        for o in whole.outputs:
            np.testing.assert_array_equal(f[o][()], whole.outputs[o])
        np.testing.assert_array_equal(f["flags"][()], whole.flags)
        assert f.attrs["samples"] == 1000 == counts["samples"]
        assert counts["snapshots"] == len(whole.snapshots)


def test_csv_log_gives_same_result(tmp_path):
    db = names_db()
    log = full_log(db, n=50)
    write_log(tmp_path / "log.h5", log)
    write_log(tmp_path / "log.csv", log)
    est = Estimator(db)
    a = est.run(tmp_path / "log.h5")
    b = est.run(tmp_path / "log.csv")
    for o in a.outputs:
        np.testing.assert_array_equal(a.outputs[o], b.outputs[o])


def test_missing_channel_is_named(tmp_path):
    db = names_db()
    log = full_log(db, n=20)
    del log.channels["u0"]     # an input (a sensor the log lacks runs as dead: test_log_checks.py)
    write_log(tmp_path / "log.h5", log)
    with pytest.raises(LogError, match="log.h5.*'u0' is missing"):
        Estimator(db).run(tmp_path / "log.h5")


def test_wrong_units_are_named(tmp_path):
    db = names_db()
    log = full_log(db, n=20)
    log.units["u0"] = "lbm/s"
    write_log(tmp_path / "log.h5", log)
    with pytest.raises(LogError, match="log.h5: channel 'u0': unit 'lbm/s' cannot be converted to 'unit_u0'"):
        Estimator(db).run(tmp_path / "log.h5")


def test_empty_and_truncated_logs(tmp_path):
    db = names_db()
    est = Estimator(db)
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(LogError, match="empty.csv.*empty"):
        est.run(tmp_path / "empty.csv")
    (tmp_path / "header.csv").write_text("time[s],u0[unit_u0]\n")
    with pytest.raises(LogError, match="header.csv.*empty"):
        est.run(tmp_path / "header.csv")
    write_log(tmp_path / "log.h5", full_log(db, n=5000))
    data = (tmp_path / "log.h5").read_bytes()
    (tmp_path / "trunc.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(LogError, match="trunc.h5"):
        est.run(tmp_path / "trunc.h5")
    with pytest.raises(LogError, match="no such file"):
        est.run(tmp_path / "nope.h5")


def test_many_logs_one_bad_does_not_lose_others(tmp_path):
    db = names_db()
    db.save(tmp_path / "db.h5")
    for i in range(3):
        write_log(tmp_path / f"f{i}.h5", full_log(db, n=200, seed=i))
    (tmp_path / "f3.h5").write_text("garbage")
    from pwl.cli import main
    rc = main(["run", str(tmp_path / "db.h5"), str(tmp_path / "f0.h5"), str(tmp_path / "f1.h5"),
               str(tmp_path / "f3.h5"), str(tmp_path / "f2.h5"), "-o", str(tmp_path / "out"), "-j", "2"])
    assert rc == 1
    import h5py
    est = Estimator(tmp_path / "db.h5")
    for i in range(3):
        with h5py.File(tmp_path / "out" / f"f{i}.estimates.h5") as f:
            np.testing.assert_array_equal(f["z_hat"][()], est.run(tmp_path / f"f{i}.h5").z_hat)
    assert not (tmp_path / "out" / "f3.estimates.h5").exists()


def test_untuned_model_keeps_tuners_fixed():
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=50)
    r = Estimator(db, "untuned", q0=[0.5, -0.25]).run_arrays(U, Y, S, TH, DE)
    np.testing.assert_allclose(r.q_hat, np.tile([0.5, -0.25], (50, 1)), rtol=1e-14)
    tuned = Estimator(db).run_arrays(U, Y, S, TH, DE)
    assert np.abs(tuned.q_hat[-1]).max() > 1e-3


@pytest.mark.parametrize("axes", [None, ("p1",)])
def test_bias_tables_equal_reference(axes, tmp_path):
    """The runtime's bias tables (pre-positioned bias + exact-gain learning from the innovation)
    against the reference's closed-form table update and RegularGridInterpolator-free weights."""
    from pwl.grid import Axis, Grid

    db = names_db()
    est = Estimator(db)
    grid = None
    if axes:
        grid = Grid([Axis("p1", [50.0, 70.0, 80.0, 100.0])])
    tabs = est.new_bias_tables(["y0", "y2"], grid, ratio=5.0)
    tabs["y2"].values[...] = np.linspace(-0.1, 0.1, tabs["y2"].grid.size).reshape(tabs["y2"].grid.shape)
    g = tabs["y0"].grid
    ref_bias = {c: ([a.values for a in g.axes], [a.name for a in g.axes], t.values.copy(), 5.0)
                for c, t in tabs.items()}
    U, Y, S, TH, DE = inputs(db, n=300)
    Y[:, 0] += 0.05  # a sensor offset to learn
    res = est.run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(db, bias=ref_bias).run(U, Y, S, TH, DE)
    for o, v in ref.items():
        np.testing.assert_allclose(res.outputs[o], v, rtol=1e-10, atol=1e-10 * np.abs(v).max(initial=1.0),
                                   err_msg=o)
    for c, t in tabs.items():
        np.testing.assert_allclose(t.values, ref_bias[c][2], rtol=1e-10, atol=1e-12)
    assert tabs["y0"].counts.sum() > 0 and np.abs(tabs["y0"].values).max() > 1e-3
    # persisted and reloaded: a new estimator continues from what was learnt
    from pwl.estimator import load_bias_tables
    est.save_bias_tables(tmp_path / "bias.h5")
    again = load_bias_tables(tmp_path / "bias.h5")
    np.testing.assert_array_equal(again["y0"].values, tabs["y0"].values)
    est2 = Estimator(db, bias=again)
    assert est2.names["bias_hat"] == ["y0", "y2"]
    # a locked table predicts but does not learn
    again["y0"].lock()
    before = again["y0"].values.copy()
    est2.run_arrays(U, Y, S, TH, DE)
    np.testing.assert_array_equal(again["y0"].values, before)
    assert not np.array_equal(again["y2"].values, ref_bias["y2"][2] * 0)


def test_bias_table_on_unknown_channel_is_named():
    from pwl.tables import TableError

    est = Estimator(names_db())
    with pytest.raises(TableError, match="'nope'"):
        est.new_bias_tables(["nope"])


def test_run_folder_takes_only_flight_logs(tmp_path):
    from pwl.cli.run import expand

    db = names_db()
    db.save(tmp_path / "db.h5")
    U, Y, S, TH, DE = inputs(db, n=20)
    write_log(tmp_path / "a.h5", Log(np.arange(20) * 0.015, {"u0": U[:, 0]}, {}))
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    (tmp_path / "notes.txt").write_text("a README beside the logs")
    (tmp_path / "b.csv.gz").write_bytes(b"")                 # a compressed CSV log is a log
    assert expand([str(tmp_path)]) == [str(tmp_path / "a.h5"), str(tmp_path / "b.csv.gz")]
    assert expand([str(tmp_path / "db.h5")]) == [str(tmp_path / "db.h5")]  # named files are kept


def test_result_names_keep_folders_and_refuse_collisions():
    from pwl.fleet.runs import result_names
    assert result_names(["a/f1.h5", "b/f2.h5"]) == ["f1.h5", "f2.h5"]
    assert result_names(["x/ESN1/f.h5", "x/ESN2/f.h5"]) == [os.path.join("ESN1", "f.h5"), os.path.join("ESN2", "f.h5")]
    assert result_names(["q.h5"], ["ESN9/q.h5"]) == ["ESN9/q.h5"]
    with pytest.raises(ValueError, match="same results file"):
        result_names(["d1/f.h5", "d1/f.csv"])
    with pytest.raises(ValueError, match="same results file"):
        result_names(["d1/f.h5", "d1/f.csv.gz"])
