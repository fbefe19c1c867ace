"""pwl.streaming.Stream: one sample per call gives exactly the batch run's numbers (the same
kernel), in every mode, with missing and implausible samples."""
import numpy as np
import pytest

from conftest import make_database
from linearize.build import with_sensor_out_gains
from pwl.errors import UsageError
from pwl.estimator import EnvelopeError, Estimator
from pwl.logs import Log
from pwl.runtime import FLAG_DYN_OUTSIDE, FLAG_HELD_INPUT, FLAG_TRIM_OUTSIDE
from pwl.streaming import Stream
from test_online import online_db
from test_runtime import inputs, names_db


def rows_of(stream, est, U, Y, S, TH, DE):
    """The stream's sample rows from the kernel's arrays (theta/delta back to raw channels)."""
    db, pm = est.db, est.pm
    cols = dict(zip(db.names["u"], U.T)) | dict(zip(db.names["y"], Y.T)) | dict(zip(pm.schedule_channels, S.T))
    if pm.theta_channel:
        cols[pm.theta_channel] = TH * db.correction.T_std
        cols[pm.delta_channel] = DE * db.correction.P_std
    rows = np.column_stack([cols[c] for c in stream.channels])
    if pm.theta_channel:   # what the batch gets from such a log (T / T_std, not TH, to the bit)
        TH[:] = rows[:, stream.channels.index(pm.theta_channel)] / db.correction.T_std
        DE[:] = rows[:, stream.channels.index(pm.delta_channel)] / db.correction.P_std
    return rows


def run_stream(stream, rows):
    out = {o: np.empty((len(rows), a.size)) for o, a in stream.outputs.items()}
    flags = np.empty(len(rows), dtype=np.int64)
    for k, row in enumerate(rows):
        flags[k] = stream.step(row)
        for o in out:
            out[o][k] = stream.outputs[o][0]
    return out, flags


@pytest.mark.parametrize("mode", ["steady", "online", "sensor-out", "health-held", "untuned"])
def test_stream_equals_batch_bit_for_bit(mode):
    out_gains = lambda: with_sensor_out_gains(names_db(), log=lambda *a: None)   # noqa: E731
    db = {"online": online_db, "sensor-out": out_gains, "health-held": out_gains}.get(mode, names_db)()
    est = Estimator(db, mode if mode in ("online", "untuned") else "steady",
                    health_hold=0.0 if mode == "health-held" else 3.0)
    U, Y, S, TH, DE = inputs(db, n=120)
    Y[10:20, 0] = np.nan          # a missing sensor
    U[30:35, 0] = np.inf          # a held input
    stream = Stream(est)
    rows = rows_of(stream, est, U, Y, S, TH, DE)
    est.reset()
    out, flags = run_stream(stream, rows)
    est.reset()
    batch = est.run_arrays(U, Y, S, TH, DE)
    np.testing.assert_array_equal(flags, batch.flags)
    for o in batch.outputs:
        np.testing.assert_array_equal(out[o], batch.outputs[o], err_msg=o)
    assert stream.missing()[est.db.names["y"][0]] == 10


def test_stream_with_a_learning_bias_table_equals_batch():
    db = names_db()
    est = Estimator(db)
    est.new_bias_tables([db.names["y"][2]], ratio=10.0)
    U, Y, S, TH, DE = inputs(db, n=80)
    stream = Stream(est)
    rows = rows_of(stream, est, U, Y, S, TH, DE)
    est.reset()
    before = est.bias[db.names["y"][2]].values.copy()
    out, _ = run_stream(stream, rows)
    learned = est.bias[db.names["y"][2]].values.copy()
    assert np.abs(learned - before).max() > 0
    est.bias[db.names["y"][2]].values[...] = before       # the same start for the batch run
    est.reset()
    batch = est.run_arrays(U, Y, S, TH, DE)
    np.testing.assert_array_equal(out["bias_hat"], batch.outputs["bias_hat"])
    np.testing.assert_array_equal(est.bias[db.names["y"][2]].values, learned)


def test_stream_rows_and_policy_errors():
    db = make_database(policy="error")
    db.schedule = [("p0", False, 1.0), ("y1", True, 2.0)]
    est = Estimator(db)
    stream = Stream(est)
    U, Y, S, TH, DE = inputs(db, n=5)
    rows = rows_of(stream, est, U, Y, S, TH, DE)
    assert not stream.step(rows[0]) & (FLAG_TRIM_OUTSIDE | FLAG_DYN_OUTSIDE)
    rows[1, stream.channels.index("p0")] = 50.0          # the grid spans 0..10
    with pytest.raises(EnvelopeError, match="outside the database grid"):
        stream.step(rows[1])
    r = stream.row({stream.channels[0]: 1.5})
    assert r[0] == 1.5 and np.isnan(r[1:]).all()
    with pytest.raises(UsageError, match=r"missing and \['nope'\] unknown \(a naming mismatch"):
        stream.row({"nope": 1.0})
    full = {c: 2.0 for c in stream.channels}
    np.testing.assert_array_equal(stream.row(dict(full, time=3.0, TRA=40.0)), 2.0)   # extras ignored
    none = stream.row(dict(full, **{stream.channels[1]: None}))
    assert np.isnan(none[1]) and (np.delete(none, 1) == 2.0).all()
    with pytest.raises(UsageError, match=f"channel {stream.channels[2]}: 'abc' is not a number"):
        stream.row(dict(full, **{stream.channels[2]: "abc"}))


def test_step_takes_any_row_of_numbers_and_refuses_the_wrong_length():
    """step() calls numba's compiled entry directly: rows of another type are converted first
    (same numbers), and a row of the wrong length is refused (it was read out of bounds)."""
    db = names_db()
    est = Estimator(db)
    stream = Stream(est)
    U, Y, S, TH, DE = inputs(db, n=6)
    rows = rows_of(stream, est, U, Y, S, TH, DE)
    est.reset()
    ref, _ = run_stream(stream, rows)
    variants = [lambda r: list(r), lambda r: np.column_stack([r, r])[:, 0]]   # a list; a strided view
    for make in variants:
        est.reset()
        got, _ = run_stream(stream, [make(r) for r in rows])
        for o in ref:
            np.testing.assert_array_equal(got[o], ref[o], err_msg=o)
    for bad in (rows[0][:-1], np.append(rows[0], 1.0), rows[:2]):
        with pytest.raises(UsageError, match=f"has {len(stream.channels)} values, one per channel"):
            stream.step(bad)
    with pytest.raises(UsageError, match="must be numbers"):
        stream.step(["x"] * len(stream.channels))
    ints = np.arange(len(stream.channels))            # an integer row: converted, not reinterpreted
    est.reset()
    f_int = stream.step(ints)
    z_int = stream.z_hat.copy()
    est.reset()
    assert stream.step(ints.astype(np.float64)) == f_int
    np.testing.assert_array_equal(stream.z_hat, z_int)


def test_a_new_stream_has_taken_no_sample():
    """Making a Stream compiles its step without running it: the first sample after it starts
    the filter as a batch run's first sample does, and nothing is counted missing."""
    db = names_db()
    est = Estimator(db)
    U, Y, S, TH, DE = inputs(db, n=20)
    stream = Stream(est)
    assert all(v == 0 for v in stream.missing().values())
    rows = rows_of(stream, est, U, Y, S, TH, DE)
    out, flags = run_stream(stream, rows)
    batch = Estimator(db).run_arrays(U, Y, S, TH, DE)
    np.testing.assert_array_equal(flags, batch.flags)
    for o in batch.outputs:
        np.testing.assert_array_equal(out[o], batch.outputs[o], err_msg=o)


def test_a_stream_keeps_the_arrays_its_kernel_reads():
    """The stream's compiled state reads its arrays without reference counting (pwl.byref.fields);
    its record must keep them alive: made and left alone, with the memory of freed arrays reused,
    it must still equal batch."""
    import gc
    db = names_db()
    U, Y, S, TH, DE = inputs(db, n=60)
    stream = Stream(Estimator(db))          # nothing else holds the estimator or the workspace
    rows = rows_of(stream, stream.est, U, Y, S, TH, DE)
    gc.collect()
    junk = [np.full(n, 1e300) for n in range(1, 400) for _ in range(3)]   # reuse freed memory
    out, flags = run_stream(stream, rows)
    del junk
    batch = Estimator(db).run_arrays(U, Y, S, TH, DE)
    np.testing.assert_array_equal(flags, batch.flags)
    for o in batch.outputs:
        np.testing.assert_array_equal(out[o], batch.outputs[o], err_msg=o)


def test_a_stream_holds_dropout_runs_of_a_scheduling_channel():
    """The stream cannot see ahead: a jump of a scheduling channel or theta/delta by more than
    5 % of its span is held until it comes back (or for 64 samples: then it is a step). The
    degraded demo flight with runs of 3 and 30 Mach zeros (0.1 % of the samples start one):
    without the test every stream sample fed them to the filter (Fn RMS 5.8 % / 16 % in batch
    before its run test); Fn within 1.25x of the clean flight's. On the clean flight the stream
    equals the batch run to the bit (no jump)."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    est = Estimator(db_path)
    stream = Stream(est)

    def run(channels):
        rows = np.column_stack([channels[c] for c in stream.channels])
        stream.reset()
        return run_stream(stream, rows)

    def fn_rms(z):
        return float(np.sqrt(np.mean(((z[:, est.names["z_hat"].index("Fn")] - log.truth["Fn"]) / log.truth["Fn"]) ** 2)))

    clean, flags = run(log.channels)
    batch = Estimator(db_path).run(log)
    np.testing.assert_array_equal(flags, batch.flags)
    np.testing.assert_array_equal(clean["z_hat"], batch.outputs["z_hat"])
    rng = np.random.default_rng(1)
    for burst in (3, 30):
        mach = log.channels["Mach"].copy()
        for k in rng.choice(len(log) - burst, len(log) // 1000, replace=False):
            mach[k:k + burst] = 0.0
        out, _ = run(dict(log.channels, Mach=mach))
        assert fn_rms(out["z_hat"]) <= 1.25 * fn_rms(clean["z_hat"]), burst
    # Mach 0 for 60 s (a dead bus word): held past the 64 samples while it stays the same word
    mach = log.channels["Mach"].copy()
    mid = len(log) // 2
    mach[mid:mid + 4000] = 0.0
    out, flags = run(dict(log.channels, Mach=mach))
    w = slice(mid, mid + 4000)
    fn = out["z_hat"][w, est.names["z_hat"].index("Fn")] / log.truth["Fn"][w] - 1
    assert np.sqrt(np.mean(fn ** 2)) < 0.005 and np.all(flags[w] & FLAG_HELD_INPUT)


def test_a_new_stream_starts_a_new_flight():
    """A stream made after a batch run of another flight starts afresh (it started from that
    flight's end, degraded health included: Fn up to 287 N off); reset=False continues."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    new, degraded = (read_log([p for p in logs if k in p][0]) for k in ("new", "degraded"))
    est = Estimator(db_path)
    rows = np.column_stack([new.channels[c] for c in est.input_channels])[:500]
    fresh = Estimator(db_path).run(Log(new.time[:500], {c: v[:500] for c, v in new.channels.items()}, new.units))
    est.run(degraded)
    out, _ = run_stream(Stream(est), rows)
    np.testing.assert_array_equal(out["z_hat"], fresh.outputs["z_hat"])
    est.run(degraded)
    carried, _ = run_stream(Stream(est, reset=False), rows)
    assert not np.array_equal(carried["z_hat"], fresh.outputs["z_hat"])


def test_an_estimator_stepped_one_sample_at_a_time_pickles_and_copies():
    """After est.step() the estimator held its Stream (compiled records) and could be neither
    pickled nor deep-copied (PicklingError, a numba TypingError): a user could not save the state
    of an on-line run, nor send it to a worker. Now both copy the filter state and continue
    exactly as the original does; a Stream itself says what to do instead."""
    import copy
    import pickle

    from pwl.demo_data import demo_paths
    from pwl.logs import read_log
    db, logs = demo_paths()
    log = read_log(logs[1])
    est = Estimator(db)
    rows = [{c: float(log.channels[c][i]) for c in est.input_channels} for i in range(2500)]
    for r in rows[:2000]:
        est.step(r)
    copies = [pickle.loads(pickle.dumps(est)), copy.deepcopy(est)]
    last = []
    for e in [est] + copies:
        for r in rows[2000:]:
            out = e.step(r)
        last.append(list(out["h_hat"].values()) + list(out["z_hat"].values()))
    np.testing.assert_array_equal(last[1], last[0])
    np.testing.assert_array_equal(last[2], last[0])
    with pytest.raises(UsageError, match="a Stream cannot be pickled or copied.*make a new Stream"):
        pickle.dumps(Stream(est, reset=False))
