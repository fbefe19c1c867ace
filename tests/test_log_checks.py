"""What a log must be before the filter sees it (#14): plausible values, known units, the
database's sample interval; and run summaries that cannot hide a log without estimates."""
import json
import warnings

import h5py
import numpy as np
import pytest

from conftest import make_database
from pwl.errors import PwlWarning
from pwl.estimator import Estimator
from pwl.h5io import file_digest
from pwl.logs import Log, LogError, write_log
from pwl.runtime import FLAG_FAR_OUTSIDE, FLAG_HELD_INPUT, FLAG_IMPLAUSIBLE, FLAG_NO_UPDATE
from test_runtime import full_log, inputs, names_db, open_loop_y


def ranged_db(**kw):
    """names_db whose log channels carry units and plausible ranges (as a plant declares them)."""
    db = names_db(**kw)
    db.log_channels = {"u0": ("kg/s", 0.0, 5.0), "y0": ("K", 0.5, 2.0), "y1": ("", -np.inf, np.inf),
                       "y2": ("Pa", 0.5, 2.0), "p0": ("", -np.inf, np.inf),
                       "Tin": ("K", 150.0, 350.0), "Pin": ("Pa", 1e3, 1.2e5)}
    return db


def log_of(db, n=300):
    """full_log with units, and inlet channels that move slowly as an atmosphere does (full_log's
    are white noise of 14 K and 20 kPa, which the spike test would take apart)."""
    log = full_log(db, n=n)
    k = np.arange(n)
    log.channels["Tin"] = 288.15 * (1.0 + 0.025 * (1 + np.sin(2 * np.pi * k / 300)))
    # delta 0.95..1: the corrected schedule channel 2 y1 / delta stays within 10 % of its axis
    # (50..100) of the grid (farther out the filter makes no update: FLAG_FAR_OUTSIDE)
    log.channels["Pin"] = 101325.0 * (0.975 + 0.025 * np.cos(2 * np.pi * k / 250))
    log.units = {c: db.log_channels[c][0] for c in log.channels}
    return log


def test_implausible_values_are_flagged_and_held_like_missing_samples():
    db = ranged_db()
    log = log_of(db)
    bad = log_of(db)
    bad.channels["u0"][100:110] = -1.0          # negative fuel flow
    bad.channels["y2"][200:205] = 1e30          # a wild sensor value
    bad.channels["Tin"][50] = 5000.0            # an inlet temperature no atmosphere has
    gaps = log_of(db)                           # the same samples missing (NaN): the reference
    gaps.channels["u0"][100:110] = np.nan
    gaps.channels["y2"][200:205] = np.nan
    gaps.channels["Tin"][50] = np.nan
    est = Estimator(db)
    est.FAILED_SHARE = np.inf    # (a synthetic log the model does not explain: its sensors would fail)
    r_bad = est.run(bad)
    assert est.implausible == {"u0": 10, "y0": 0, "y1": 0, "y2": 5, "p0": 0, "Tin": 1, "Pin": 0}
    r_gap = est.run(gaps)
    for o in r_bad.outputs:
        np.testing.assert_array_equal(r_bad.outputs[o], r_gap.outputs[o])
    expect = np.zeros(len(log), bool)
    expect[[*range(100, 110), *range(200, 205), 50]] = True
    np.testing.assert_array_equal((r_bad.flags & FLAG_IMPLAUSIBLE) != 0, expect)
    np.testing.assert_array_equal(r_bad.flags & ~FLAG_IMPLAUSIBLE, r_gap.flags)
    assert r_bad.counts()["implausible"] == 16
    assert json.loads(r_bad.attrs["provenance"]["implausible_channels"]) == {"u0": 10, "y2": 5, "Tin": 1}
    # the caller's arrays are not modified
    assert bad.channels["u0"][100] == -1.0


@pytest.mark.parametrize("chan, unit, scale, offset", [("u0", "lb/s", 1 / 0.45359237, 0.0),
                                                         ("Tin", "degC", 1.0, -273.15),
                                                         ("Pin", "kPa", 1e-3, 0.0),
                                                         ("y0", "degF", 1.8, -459.67),
                                                         # as data systems write them
                                                         ("u0", "LBS/HR", 3600 / 0.45359237, 0.0),
                                                         ("Tin", "DEG C", 1.0, -273.15),
                                                         ("Pin", "KPA", 1e-3, 0.0),
                                                         ("Pin", "PSIA", 1 / 6894.757293168361, 0.0),
                                                         ("y0", "°R", 1.8, 0.0)])
def test_declared_units_are_converted(chan, unit, scale, offset):
    db = ranged_db()
    ref = Estimator(db).run(log_of(db))
    log = log_of(db)
    log.channels[chan] = log.channels[chan] * scale + offset
    log.units[chan] = unit
    res = Estimator(db).run(log)
    for o in ref.outputs:
        np.testing.assert_allclose(res.outputs[o], ref.outputs[o], rtol=1e-9, atol=1e-9)
    assert json.loads(res.attrs["provenance"]["units_converted"]) == {chan: f"{unit} -> {db.log_channels[chan][0]}"}


def test_undeclared_wrong_units_are_caught_by_the_ranges():
    # P2 in kPa without saying so: every sample is implausible, nothing starts, and the counts say it
    db = ranged_db()
    log = log_of(db)
    log.channels["Pin"] = log.channels["Pin"] / 1e3
    log.units["Pin"] = ""
    est = Estimator(db)
    c = est.run(log).counts()
    assert c["implausible"] == c["samples"] == c["not_started"] and c["updated"] == 0
    assert est.missing["Pin"] == c["samples"]
    log.units["Pin"] = "psi/furlong"
    with pytest.raises(LogError, match="channel 'Pin'.*'psi/furlong' is not a unit pwl knows"):
        Estimator(db).run(log)


def test_a_channel_mostly_implausible_is_named_with_the_units_it_would_fit():
    """Undeclared units (an inlet temperature in degC, a pressure in kPa) and a sentinel value
    (-999 on every sample: a dead channel) are each named in one warning, with the units in
    which their typical value would be plausible; a clean log gives none."""
    db = ranged_db()
    log = log_of(db)
    with warnings.catch_warnings(record=True) as clean:     # (its sensors are random: they misfit)
        warnings.simplefilter("always")
        Estimator(db).run(log)
    assert not [w for w in clean if "implausible, typically" in str(w.message)]
    log.channels["Tin"] = log.channels["Tin"] - 273.15
    log.channels["Pin"] = log.channels["Pin"] / 1e3
    log.channels["y0"] = np.full(len(log), -999.0)
    log.units.update(Tin="", Pin="", y0="")
    with pytest.warns(PwlWarning) as got:
        Estimator(db).run(log)
    said = sorted(str(w.message) for w in got if "implausible, typically" in str(w.message))
    assert len(said) == 3
    assert "channel 'Pin': 300 of 300 samples implausible" in said[0] and "kPa" in said[0]
    assert "channel 'Tin'" in said[1] and "logged in degC or degF?" in said[1]
    assert "channel 'y0'" in said[2] and "typically -999 " in said[2] and "'no data' code" in said[2]


@pytest.mark.parametrize("value, unit, lo, hi, want", [
    (15.0, "K", 200.0, 350.0, ["degC", "degF"]),          # 288.15 K; 15 degF = 263.7 K
    (30000.0, "m", -500.0, 15000.0, ["ft"]),              # 9144 m
    (101.3, "Pa", 5e4, 1.2e5, ["kPa"]),
    (72.0, "rpm", 2000.0, 6000.0, ["% of a reference speed (a channel map's scale)"]),
    (-999.0, "K", 150.0, 1700.0, []),
    (5.0, "", 0.0, 1.0, []),                              # no unit: nothing to compare
])
def test_likely_units(value, unit, lo, hi, want):
    from pwl.units import likely_units
    assert likely_units(value, unit, lo, hi) == want


def test_sample_interval_must_match_the_database():
    db = ranged_db()
    log = log_of(db, n=400)
    slow = Log(log.time * 4, log.channels, log.units, path="slow.h5")    # 60 ms on a 15 ms database
    with pytest.raises(LogError, match="slow.h5: sampled every 60 ms.*discretized for 15 ms"):
        Estimator(db).run(slow)
    est = Estimator(db, resample=True)
    est.FAILED_SHARE = np.inf    # (a synthetic log the model does not explain: its sensors would fail)
    res = est.run(slow)
    # independent: np.interp of every channel onto the database's step; the sensors NaN on the
    # rows between two logged samples (no measurement there; the schedule channel y1 stays);
    # the kernel on those arrays; every 4th row
    t = np.arange(0, slow.time[-1] + 1e-12, db.dt)
    col = {k: np.interp(t, slow.time, v) for k, v in slow.channels.items()}
    Y = np.column_stack([col[y] for y in db.names["y"]])
    Y[np.arange(t.size) % 4 != 0] = np.nan
    ref = Estimator(db).run_arrays(np.column_stack([col[u] for u in db.names["u"]]), Y,
                                   np.column_stack([col[c] for c, _, _ in db.schedule]),
                                   col["Tin"] / db.correction.T_std, col["Pin"] / db.correction.P_std)
    np.testing.assert_allclose(res.time, slow.time, rtol=0, atol=1e-12)    # one row per logged sample
    np.testing.assert_array_equal(res.outputs["h_hat"], ref.outputs["h_hat"][::4])
    # the kernel's flags (FLAG_FAR_OUTSIDE is the estimator's, after it: this log leaves its grid)
    np.testing.assert_array_equal(res.flags & ~FLAG_FAR_OUTSIDE, ref.flags[::4])
    assert res.attrs["provenance"]["resampled_from_dt"] == pytest.approx(4 * db.dt)
    assert not any(est.missing.values())          # the prediction rows are not missing samples
    # within 1 %: accepted as it is
    near = Log(log.time * 1.005, log.channels, log.units)
    assert Estimator(db).run(near).counts()["samples"] == 400


def test_resampling_does_not_bridge_a_gap_and_provenance_counts_gaps():
    db = ranged_db()
    log = log_of(db, n=400)
    keep = np.r_[0:150, 250:400]                   # 100 samples lost: a recorder dropout
    cut = Log(log.time[keep], {k: v[keep] for k, v in log.channels.items()}, log.units, path="cut.h5")
    res = Estimator(db).run(cut)                   # at the database's rate: run as it is, counted
    prov = res.attrs["provenance"]
    assert (prov["time_gaps"], prov["longest_gap_s"]) == (1, pytest.approx(101 * db.dt))
    slow = Log(cut.time * 2, cut.channels, cut.units, path="slow.h5")
    res = Estimator(db, resample=True).run(slow)
    # no row of the result inside the gap: nothing was logged there to estimate from
    t_gap = (slow.time[149], slow.time[150])
    assert not np.any((res.time > t_gap[0] + db.dt) & (res.time < t_gap[1] - db.dt))
    assert res.time.size == slow.time.size
    assert res.attrs["provenance"]["time_gaps"] == 1
    assert Estimator(db).run(log).attrs["provenance"]["time_gaps"] == 0


def explained_log(db):
    """:func:`log_of` whose sensors (but y1, the schedule channel) read what the model predicts
    open-loop (a run without measurements): a log the model explains."""
    log = log_of(db)
    U, _, S, TH, DE = inputs(db, n=len(log))         # what full_log wrote
    y_hat = open_loop_y(db, U, S, TH, DE)
    log.channels.update({c: y_hat[:, j] for j, c in enumerate(db.names["y"]) if c != "y1"})
    return log


def test_run_prints_every_flag_count_and_fails_a_log_without_estimates(tmp_path, capsys):
    from pwl.cli import main
    db = ranged_db()
    db.save(tmp_path / "db.h5")
    good = explained_log(db)
    dead = log_of(db)
    for c in db.names["y"]:                         # every sensor dead: no measurement update at all
        dead.channels[c][:] = np.nan
    write_log(tmp_path / "logs" / "good.h5", good)
    write_log(tmp_path / "logs" / "dead.h5", dead)
    # (the synthetic "good" log has its health held on 93 % of its samples: a bar of 5 % lets it pass)
    code = main(["run", str(tmp_path / "db.h5"), str(tmp_path / "logs"), "-o", str(tmp_path / "out"), "-j", "1",
                 "--min-updated", "0.05"])
    err = capsys.readouterr().err
    assert code == 1
    for label in ("updated", "without update", "input held", "implausible", "outside the trim grid",
                  "outside the dynamics grid", "before the first valid sample"):
        assert label in err
    assert "dead.h5" in err and "TOO FEW ESTIMATES: the filter never started: none of the 300 samples had " \
                                "every input and scheduling channel valid; missing or implausible: y2 100%, " \
                                "y1 100%, y0 100%" in err
    assert err.count("TOO FEW") == 1
    # provenance: the database and the log by path and digest
    with h5py.File(tmp_path / "out" / "good.estimates.h5") as f:
        assert f.attrs["database_digest"] == file_digest(tmp_path / "db.h5")
        assert f.attrs["log_digest"] == file_digest(tmp_path / "logs" / "good.h5")
        assert f.attrs["mode"] == "steady" and f.attrs["updated"] == 300
    # the same logs with a lower bar pass
    assert main(["run", str(tmp_path / "db.h5"), str(tmp_path / "logs" / "good.h5"), "-o",
                 str(tmp_path / "out2"), "-j", "1", "--min-updated", "0.05"]) == 0
    # at the default bar it fails for its health, held on most samples
    assert main(["run", str(tmp_path / "db.h5"), str(tmp_path / "logs" / "good.h5"), "-o",
                 str(tmp_path / "out3"), "-j", "1"]) == 1
    assert "TOO FEW ESTIMATES: health held on 278 of 300 samples" in capsys.readouterr().err


def test_database_without_ranges_still_runs():
    db = make_database()
    assert db.log_channels is None
    db.schedule = [("p0", False, 1.0), ("y1", True, 2.0)]
    assert Estimator(db).run(full_log(db)).counts()["implausible"] == 0


def test_misfit_flags_where_the_model_cannot_explain_a_sensor():
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log
    from pwl.runtime import FLAG_MISFIT, MISFIT_SIGMAS
    db_path, logs = demo_paths()
    est = Estimator(db_path)
    log = read_log(logs[0])
    log = Log(log.time[:6000], {k: v[:6000] for k, v in log.channels.items()}, log.units)
    clean = est.run(log)
    assert clean.counts()["misfit"] == 0            # the model explains a clean flight
    log.channels["Wf"] = log.channels["Wf"] * 2.2046     # fuel flow logged in lb/s, declared kg/s
    res = est.run(log)
    # independent: the gate from the database's sensor noise (R) and trims, by numpy
    ny = est.db.n("y")
    R = est.db.kalman["R"].reshape(-1, ny, ny)
    gate = MISFIT_SIGMAS * np.sqrt(np.median(R[:, range(ny), range(ny)], axis=0)) / np.median(
        np.abs(est.db.trim["y"].reshape(-1, ny)), axis=0)
    want = np.any(np.abs(res.outputs["residual"]) > gate * np.abs(res.outputs["y_hat"]), axis=1)
    np.testing.assert_array_equal((res.flags & FLAG_MISFIT) != 0, want)
    assert want.mean() > 0.5


def test_trusted_samples_leave_out_what_the_flags_call_suspect():
    from pwl.results import trusted
    from pwl.runtime import (FLAG_HEALTH, FLAG_MISFIT, FLAG_NO_UPDATE, FLAG_PARTIAL, FLAG_STUCK,
                             FLAG_TRIM_OUTSIDE)
    flags = np.array([0, FLAG_PARTIAL, FLAG_MISFIT | FLAG_PARTIAL, FLAG_STUCK | FLAG_PARTIAL,   # trusted
                      FLAG_TRIM_OUTSIDE | FLAG_PARTIAL,
                      FLAG_MISFIT, FLAG_NO_UPDATE, FLAG_HEALTH, FLAG_TRIM_OUTSIDE | FLAG_HEALTH])
    np.testing.assert_array_equal(trusted(flags), [True] * 5 + [False] * 4)


def test_a_unit_mistake_on_the_schedule_sensor_fails_the_run(tmp_path, capsys):
    """Nf logged in rad/s instead of rpm, no unit declared: most samples still pass the range
    check and get an update (92 %), but the operating point is off the grid and the model explains
    none of it; before, pwl run exited 0 with a 42 % Fn error. Now no sample is trusted and the
    run exits 1 naming what was flagged."""
    from pwl.cli import main
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log(logs[0])
    write_log(tmp_path / "rads.h5", Log(log.time, dict(log.channels, Nf=log.channels["Nf"] * 2 * np.pi / 60),
                                        {c: u for c, u in log.units.items() if c != "Nf"}, attrs=log.attrs))
    code = main(["run", db_path, str(tmp_path / "rads.h5"), logs[0], "-o", str(tmp_path / "out"), "-j", "1"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("TOO FEW") == 1
    line = err[err.index("TOO FEW"):].splitlines()[0]
    assert "samples trusted" in line and "misfit" in line and "outside the trim grid" in line and "Nf" in line


def test_a_log_just_below_the_grid_is_trusted():
    """A test cell on a high-pressure day logs -300 m pressure altitude: the operating point is
    clipped to the grid's 0 m (flagged, counted) and the estimates are as good (Fn RMS within 2 %
    of the unshifted run's), so the samples stay trusted and pwl run does not fail the log. P2,
    off the air data by a share growing with altitude, is kept (not taken from the air data)."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log(logs[1])
    low = Log(log.time, dict(log.channels, alt=log.channels["alt"] - 300.0), log.units, attrs=log.attrs)
    est = Estimator(db_path)
    a = est.run(log)
    with pytest.warns(PwlWarning, match=r"samples outside the database's grid, alt -300 \.\. [0-9]+ \(grid 0 \.\. "
                                        r"12000\): the model there is clipped to the grid's edge"):
        b = est.run(low)
    c = b.counts()
    assert c["trim_outside"] > 10000 and c["updated"] == c["samples"]
    # P2 3.5 % off the air data low, 4.4 % high: the altitude rather than P2, which is kept
    assert json.loads(b.attrs["provenance"]["from_air_data"]) == []
    assert c["trusted"] == c["samples"] - c["settling"] == a.counts()["trusted"]
    rows = log.time >= log.time[0] + 120

    def fn(r):
        e = (r.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return np.sqrt(np.mean(e[rows] ** 2))
    assert fn(b) <= 1.02 * fn(a)


@pytest.mark.parametrize("scale, unit", [(1000.0, "ms"), (1e6, "us"), (1 / 60, "min")])
def test_a_time_column_in_another_unit_is_named_not_resampled(scale, unit):
    """Time logged in ms but read as s looks like a log sampled every 15 s: resampling it to the
    database's 15 ms would make 1000x the samples out of nothing. Refused, with or without
    resample, naming the likely unit."""
    db = names_db()
    log = full_log(db, n=50)
    wrong = Log(log.time * scale, log.channels, log.units, attrs={})
    for resample in (False, True):
        with pytest.raises(LogError, match=f"is its time column in {unit}\\? Declare the unit"):
            Estimator(db, resample=resample).run(wrong)


def test_a_slow_log_updates_only_on_its_samples():
    """The degraded demo flight logged at 1 Hz (every 67th sample), resampled to the database's
    15 ms: its end-of-flight health error against the simulation's truth stays within 1.5x of
    the 15 ms log's (measured 0.27 vs 0.29 pt). Updating on the interpolated rows counted each
    sample 67 times: 0.83 pt. Steady snapshots are still found (8-sample blocks at least)."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    k = np.arange(0, len(log), 67)
    slow = Log(log.time[k], {c: v[k] for c, v in log.channels.items()}, log.units, path="1hz.h5")

    def health_rms(res):
        truth = np.array([log.truth[h][-1] for h in res.names["h_hat"]])
        return float(np.sqrt(np.mean((res.outputs["h_hat"][-1] - truth) ** 2)))

    native = Estimator(db_path).run(log)
    res = Estimator(db_path, resample=True).run(slow)
    assert res.time.size == k.size and res.counts()["updated"] == k.size
    assert health_rms(res) <= 1.5 * health_rms(native)
    assert len(res.snapshots) >= 1


def test_a_log_without_a_sensor_channel_runs_as_that_sensor_dead(tmp_path):
    """A sensed output the log lacks altogether (an engine without that sensor) runs as a sensor
    missing on every sample, with a warning naming it; the result equals the run of the log
    with that channel all NaN, in memory and through the chunked file run; a column of it under
    another case is named in the warning. A scheduling channel
    (y1 here, also a sensor) or an input cannot be done without."""
    from pwl.errors import PwlWarning
    from pwl.results import Result

    db = ranged_db()
    log = log_of(db, n=300)
    dead = Log(log.time, dict(log.channels, y2=np.full(300, np.nan)), log.units, path="dead.h5")
    ref = Estimator(db).run(dead)
    assert ref.counts()["partial"] == 300
    lacks = Log(log.time, {k: v for k, v in log.channels.items() if k != "y2"}, log.units, path="lacks.h5")
    with pytest.warns(PwlWarning, match="lacks.h5: no 'y2' channel: run without that sensor"):
        res = Estimator(db).run(lacks)
    np.testing.assert_array_equal(res.outputs["h_hat"], ref.outputs["h_hat"])
    np.testing.assert_array_equal(res.flags, ref.flags)
    assert json.loads(res.attrs["provenance"]["absent_channels"]) == ["y2"]
    # a column of the sensor under another case is named with the warning (it is not read)
    cased = Log(log.time, {("Y2" if k == "y2" else k): v for k, v in log.channels.items()},
                {("Y2" if k == "y2" else k): u for k, u in log.units.items()}, path="cased.h5")
    with pytest.warns(PwlWarning, match=r"cased.h5: no 'y2' channel \('Y2' differs in case only: rename the column"):
        np.testing.assert_array_equal(Estimator(db).run(cased).outputs["h_hat"], ref.outputs["h_hat"])
    write_log(tmp_path / "lacks.h5", Log(lacks.time, lacks.channels, {k: u for k, u in log.units.items() if k != "y2"}))
    with pytest.warns(PwlWarning, match="no 'y2' channel"):
        Estimator(db).run_file(tmp_path / "lacks.h5", tmp_path / "res.h5", chunk=77)
    np.testing.assert_array_equal(Result.load(tmp_path / "res.h5").outputs["q_hat"], ref.outputs["q_hat"])
    for needed in ("y1", "u0", "Tin"):
        without = Log(log.time, {k: v for k, v in log.channels.items() if k != needed}, log.units, path="x.h5")
        with pytest.raises(LogError, match=f"x.h5: channel '{needed}' is missing"):
            Estimator(db).run(without)


def test_a_time_column_in_single_precision_is_named():
    """Seconds since midnight stored as float32: at 50,000 s they step by 3.9 ms, so a 15 ms log
    reads as sampled every 15.6 ms. Named as a precision problem, not a sampling interval to
    resample."""
    db = ranged_db()
    log = log_of(db, n=400)
    late = Log((50000.0 + log.time).astype(np.float32).astype(np.float64), log.channels, log.units, path="f32.h5")
    for resample in (False, True):
        with pytest.raises(LogError, match=r"f32.h5: the time column has a resolution of 3.906 ms at t = 5000\d.* "
                                           r"\(single-precision numbers\?\)"):
            Estimator(db, resample=resample).run(late)


def test_spike_mask_matches_a_numpy_running_median():
    """pwl.estimator.spikes (a numba kernel) against np.nanmedian over the centred windows."""
    from numpy.lib.stride_tricks import sliding_window_view

    from pwl.estimator import spikes
    rng = np.random.default_rng(7)
    a = np.cumsum(rng.normal(0, 0.01, (500, 4)), axis=0)
    a[rng.choice(500, 25, replace=False), rng.integers(0, 4, 25)] = 0.0          # dropouts
    a[rng.choice(500, 15, replace=False), rng.integers(0, 4, 15)] = np.nan
    a[100:103, 1] = 5.0                                                          # a run of 3
    span = np.array([1.0, 2.0, 0.5, np.inf])
    for width in (1, 2, 3):
        win = sliding_window_view(np.pad(a, ((width, width), (0, 0)), constant_values=np.nan),
                                  2 * width + 1, axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(win, axis=2)
        with np.errstate(invalid="ignore"):
            ref = np.abs(a - med) > 0.05 * span
        np.testing.assert_array_equal(spikes(a, span, width=width, longest=0), ref)   # the median test alone
    assert not spikes(a, span)[:, 3].any()                      # no range: no test
    assert not spikes(a, span, width=2, longest=0)[100:103, 1].any()   # 3 in a row: a step for width 2
    assert spikes(a, span, width=2)[100:103, 1].all()           # ... but a run that jumps and comes back


def test_dropouts_of_a_scheduling_channel_are_held_not_used():
    """The degraded demo flight with 1 % of its Mach samples 0 (a data-bus dropout, inside
    Mach's plausible range 0..1): used, they gave a 9.8 % Fn RMS error and broke up every cruise
    snapshot; as spikes they are counted implausible and held. Fn within 1.1x of the clean run,
    the same snapshots."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log
    from pwl.results import Result

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    mach = log.channels["Mach"].copy()
    mach[np.random.default_rng(0).choice(len(log), len(log) // 100, replace=False)] = 0.0
    bad = Log(log.time, dict(log.channels, Mach=mach), log.units, path="dropouts.h5")

    def fn_rms(res):
        e = (res.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
        return float(np.sqrt(np.mean(e ** 2)))

    clean, est = Estimator(db_path).run(log), Estimator(db_path)
    res = est.run(bad)
    assert fn_rms(res) <= 1.1 * fn_rms(clean)
    assert len(res.snapshots) == len(clean.snapshots) == 3
    assert 0 < est.implausible["Mach"] <= len(log) // 100
    assert np.count_nonzero(res.flags & FLAG_IMPLAUSIBLE) == est.implausible["Mach"]


def test_spikes_at_chunk_edges_are_judged_as_in_a_whole_run(tmp_path):
    """run_file judges each chunk's spikes with the samples beyond its edges: equal to a whole
    run bit for bit, with dropouts of u0 (fuel, range 0..5) on and around the edges."""
    import h5py
    db = ranged_db()
    log = log_of(db, n=600)
    for k in (136, 137, 273, 275, 411):           # chunks of 137: edges at 137, 274, 411
        log.channels["u0"][k] = 4.9
    write_log(tmp_path / "log.h5", log)
    whole = Estimator(db).run(log)
    assert np.count_nonzero(whole.flags & FLAG_IMPLAUSIBLE) == 5
    Estimator(db).run_file(tmp_path / "log.h5", tmp_path / "res.h5", chunk=137)
    with h5py.File(tmp_path / "res.h5") as f:
        np.testing.assert_array_equal(f["flags"][()], whole.flags)
        np.testing.assert_array_equal(f["q_hat"][()], whole.outputs["q_hat"])


def burst_reference(a, tol, longest, frozen=True):  # frozen: test frozen words
    """The runs burst_mask marks, found another way: every pair (i, e) with a[i-1] and a[e]
    within tol, all of a[i:e] (1..longest of them) further, scanned left to right; and a jump
    further than tol followed by the same value more than ``longest`` times (a frozen word)."""
    out = np.zeros(a.shape, bool)
    for j in range(a.shape[1]):
        x = a[:, j]
        i = 1
        while i < len(x):
            far = np.abs(x[i:i + longest + 1] - x[i - 1]) > tol[j]
            run = int(np.argmin(far)) if not far.all() else len(far)   # far values before the first near one
            back = i + run < len(x) and abs(x[i + run] - x[i - 1]) <= tol[j]
            same = np.flatnonzero(x[i:] != x[i])
            repeat = int(same[0]) if same.size else len(x) - i   # x[i] repeated this many times
            if run >= 1 and run <= longest and back:
                out[i:i + run, j] = True
                i += run + 1
            elif frozen and far[0] and longest > 0 and repeat > longest:
                out[i:i + repeat, j] = True
                i += repeat + 1
            else:
                i += 1
    return out


def test_burst_mask_matches_a_reference_scan():
    from pwl.runtime import burst_mask
    rng = np.random.default_rng(3)
    a = np.cumsum(rng.normal(0, 0.01, (3000, 3)), axis=0)
    for k in rng.choice(2900, 60, replace=False):            # runs of zeros of 1..80 samples
        a[k:k + rng.integers(1, 81), rng.integers(0, 3)] = -5.0
    a[1500:, 1] += 3.0                                        # a step
    a[700, 2] = np.nan
    span = np.array([20.0, 20.0, 20.0])
    a[2200:2400, 0] = 7.0                                     # a frozen word for 200 samples
    got = burst_mask(a, span, 64, 0.05, np.ones(3, bool), np.zeros(a.shape, bool))
    np.testing.assert_array_equal(got, burst_reference(a, 0.05 * span, 64))
    assert got.sum() > 500 and not got[1500, 1] and got[2200:2400, 0].all() and not got[2400, 0]
    inputs = burst_mask(a, span, 64, 0.05, np.zeros(3, bool), np.zeros(a.shape, bool))   # no frozen test
    np.testing.assert_array_equal(inputs, burst_reference(a, 0.05 * span, 64, frozen=False))
    assert not inputs[2200:2400, 0].any()


def test_dropout_runs_of_a_scheduling_channel_are_held():
    """Runs of 3 to 30 Mach zeros (0.1 % of the degraded demo flight's samples start one): the
    median test sees runs of 2 at most, so they were used: Fn RMS 5.8 % (runs of 3), 16 % (30).
    Caught as runs that jump and come back: Fn within 1.25x of the clean run; in a chunked run
    (HDF5, 4096-sample chunks) the same as in a whole one."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    clean = Estimator(db_path).run(log)
    e = lambda res: float(np.sqrt(np.mean(((res.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]) ** 2)))  # noqa: E731
    rng = np.random.default_rng(1)
    for burst in (3, 30):
        mach = log.channels["Mach"].copy()
        for k in rng.choice(len(log) - burst, len(log) // 1000, replace=False):
            mach[k:k + burst] = 0.0
        res = Estimator(db_path).run(Log(log.time, dict(log.channels, Mach=mach), log.units, path="runs.h5"))
        assert e(res) <= 1.25 * e(clean), burst
    # Mach 0 for 60 s at cruise (a dead bus word): Fn was 20 % off there, unflagged; now held
    mach = log.channels["Mach"].copy()
    mid = len(log) // 2
    mach[mid:mid + 4000] = 0.0
    res = Estimator(db_path).run(Log(log.time, dict(log.channels, Mach=mach), log.units, path="dead.h5"))
    w = slice(mid, mid + 4000)
    fn = (res.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
    assert np.sqrt(np.mean(fn[w] ** 2)) < 0.005 and np.all(res.flags[w] & FLAG_HELD_INPUT)
    assert res.counts()["held_input"] == 4000


def test_dropout_runs_at_chunk_edges_are_judged_as_in_a_whole_run(tmp_path):
    import h5py
    db = ranged_db()
    log = log_of(db, n=600)
    for k, m in ((120, 30), (270, 10), (405, 12)):    # chunks of 137: edges at 137, 274, 411
        log.channels["u0"][k:k + m] = 4.9
    write_log(tmp_path / "log.h5", log)
    whole = Estimator(db).run(log)
    assert np.count_nonzero(whole.flags & FLAG_IMPLAUSIBLE) == 52
    Estimator(db).run_file(tmp_path / "log.h5", tmp_path / "res.h5", chunk=137)
    with h5py.File(tmp_path / "res.h5") as f:
        np.testing.assert_array_equal(f["flags"][()], whole.flags)
        np.testing.assert_array_equal(f["q_hat"][()], whole.outputs["q_hat"])


def test_spikes_of_a_slow_log_are_judged_before_resampling():
    """A 1 Hz log (the degraded demo flight, every 67th sample) with 8 Mach samples 0: judged
    after interpolation, each dropout became a 2 s ramp that the spike test could not see (Fn
    RMS 6.2 %); judged on the logged samples, left out of the interpolation: Fn within 1.05x of
    the clean 1 Hz run (0.727 %)."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    k = np.arange(0, len(log), 67)
    mach = log.channels["Mach"][k].copy()
    clean = Log(log.time[k], {c: v[k] for c, v in log.channels.items()}, log.units, path="1hz.h5")
    mach[np.random.default_rng(0).choice(k.size, 8, replace=False)] = 0.0
    bad = Log(clean.time, dict(clean.channels, Mach=mach), log.units, path="1hz.h5")

    def fn_rms(res):
        fn = np.interp(res.time, log.time, log.truth["Fn"])
        return float(np.sqrt(np.mean(((res.channel("z_hat", "Fn") - fn) / fn) ** 2)))

    est = Estimator(db_path, resample=True)
    res = est.run(bad)
    assert fn_rms(res) <= 1.05 * fn_rms(Estimator(db_path, resample=True).run(clean))
    assert 0 < est.missing["Mach"] <= 8


def test_a_step_at_an_hdf5_chunk_edge_is_not_a_spike(tmp_path):
    """An HDF5 log is read a chunk at a time: a step of u0 one sample before a chunk edge is a
    step in the whole log (most of the window around it after the step), and must be one in the
    chunked run too; with only the chunk's own samples its window was two old values and it."""
    import h5py
    db = ranged_db()
    log = log_of(db, n=400)
    log.channels["u0"][136:] += 2.0                # fuel up by 2 of its 0..5 range at 136; edge 137
    write_log(tmp_path / "log.h5", log)
    whole = Estimator(db).run(log)
    assert not np.any(whole.flags & FLAG_IMPLAUSIBLE)
    Estimator(db).run_file(tmp_path / "log.h5", tmp_path / "res.h5", chunk=137)
    with h5py.File(tmp_path / "res.h5") as f:
        np.testing.assert_array_equal(f["flags"][()], whole.flags)


@pytest.mark.parametrize("bad, match", [("repeat", r"mem: time does not increase at sample 40 \("),
                                        ("nan", r"mem: time is not finite at sample 40 \(nan\)"),
                                        ("back", r"mem: time does not increase at sample 40 ")])
def test_a_log_made_in_memory_has_its_time_checked_as_a_file_log(bad, match):
    """Estimator.run on a Log built in code: a repeated, NaN or backward time was accepted (a
    NaN time even switched the sample-interval check off); refused as read_log refuses it."""
    db = ranged_db()
    log = log_of(db)
    log.time = log.time.copy()
    log.time[40] = {"repeat": log.time[39], "nan": np.nan, "back": log.time[10]}[bad]
    log.path = "mem"
    with pytest.raises(LogError, match=match):
        Estimator(db).run(log)


def test_a_sensor_in_another_unit_inside_its_range_is_named_and_its_health_failure_fails_the_run(
        tmp_path, capsys):
    """T48 or T30 logged in degC with no unit declared: inside the plausible range in K, so not
    implausible; each misfit on every sample and was left out, and the run said nothing about
    which (T30: the health estimates held all flight, exit 0). Now a warning names the sensor
    and the unit that would make it agree, and a log whose health was held on most samples fails
    (exit 1) naming the misfitting sensor."""
    from pwl.cli import main
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log(logs[0])
    for c in ("T48", "T30"):
        write_log(tmp_path / f"{c}.h5", Log(log.time, dict(log.channels, **{c: log.channels[c] - 273.15}),
                                            dict(log.units, **{c: ""}), attrs=log.attrs))
    with pytest.warns(PwlWarning, match=r"T48.h5: sensor 'T48' misfit on 100% of the samples where the model should "
                                        r"fit .* logged in degC\?.*Estimated again without it"):
        res = Estimator(db_path).run(tmp_path / "T48.h5")
    assert res.counts()["health_held"] < 0.1 * len(log)       # estimated without T48
    code = main(["run", db_path, str(tmp_path / "T30.h5"), "-o", str(tmp_path / "out"), "-j", "1"])
    err = capsys.readouterr().err
    assert code == 1 and "sensor 'T30' misfit" in err and "logged in degC?" in err
    line = err[err.index("TOO FEW"):].splitlines()[0]
    assert "health held on" in line and "failed for the log (misfit, left out): T30" in line


def test_a_snapshot_has_no_health_where_it_was_held():
    """Without Ps30 the health estimates are held at h_ref all flight: the steady snapshots (what
    pwl trend, the fleet summary and diagnosis show) took h_ref as the engine's health, a new
    engine's; now NaN (not estimated). With every sensor they are the filter's estimates (the
    mean over the window's samples past the filter's settling time)."""
    from pwl.runtime import FLAG_SETTLING
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" in p][0])
    keep = [c for c in log.channels if c != "Ps30"]
    res = Estimator(db_path).run(Log(log.time, {c: log.channels[c] for c in keep}, {c: log.units[c] for c in keep}))
    assert len(res.snapshots) == 3 and np.isnan(res.snapshots.outputs["h_hat"]).all()
    assert np.isnan(res.snapshots.outputs["q_hat"]).all() and np.isfinite(res.snapshots.outputs["z_hat"]).all()
    full = Estimator(db_path).run(log)
    w = full.snapshots
    for i in range(len(w)):
        rows = (full.time >= w.t0[i]) & (full.time <= w.t1[i]) & ((full.flags & FLAG_SETTLING) == 0)
        np.testing.assert_allclose(w.outputs["h_hat"][i], full.outputs["h_hat"][rows].mean(axis=0), rtol=1e-10)


def test_samples_far_outside_the_trim_grid_are_flagged_and_not_trusted():
    """Samples whose operating point is farther outside the trim grid than 10 % of an axis's span
    (pwl.runtime.FAR_OUTSIDE) are flagged FLAG_FAR_OUTSIDE, make no measurement update (the tuners
    do not take the clipped model's error in), are not trusted, counted and named; those just
    outside are not. Against the schedule written out here: p1 = 2 y1 / delta on the axis
    50..100. Before, a user's plant 20 K below its ambient axis read a clean engine's turbine 9
    points off, trusted, exit 0."""
    from pwl.results import trusted

    db = ranged_db()
    log = log_of(db, n=400)
    log.channels["Pin"] = 101325.0 * (0.9 + 0.1 * np.cos(2 * np.pi * np.arange(400) / 250))
    est = Estimator(db)
    est.FAILED_SHARE = np.inf    # (a synthetic log the model does not explain: its sensors would fail)
    with pytest.warns(PwlWarning, match=r"samples outside the database's grid, .* \d+ samples run farther out "
                                        r"than 10% of an axis's span .* made no measurement update and are not "
                                        r"trusted"):
        res = est.run(log)
    p1 = 2.0 * log.channels["y1"] / (log.channels["Pin"] / 101325.0)
    far = (p1 > 100.0 + 5.0) | (p1 < 50.0 - 5.0)
    near = ((p1 > 100.0) & (p1 <= 105.0)) | ((p1 < 50.0) & (p1 >= 45.0))
    assert far.sum() > 20 and near.sum() > 20
    np.testing.assert_array_equal((res.flags & FLAG_FAR_OUTSIDE) != 0, far)
    assert not trusted(res.flags)[far].any() and np.all(res.flags[far] & FLAG_NO_UPDATE)
    assert res.counts()["far_outside"] == far.sum()


def test_a_stream_flags_samples_far_outside_the_trim_grid_as_a_log_run_does():
    """The kernel's step makes the test (pwl.grid.beyond), so a Stream fed the same samples one
    at a time flags the same ones and makes no update there; its outputs equal the log run's
    kernel (run_arrays on the log's arrays) bit for bit. Before, a stream had no such test: it
    updated from the clipped model far outside the grid."""
    from pwl.streaming import Stream

    db = ranged_db()
    log = log_of(db, n=400)
    log.channels["Pin"] = 101325.0 * (0.9 + 0.1 * np.cos(2 * np.pi * np.arange(400) / 250))
    p1 = 2.0 * log.channels["y1"] / (log.channels["Pin"] / 101325.0)
    far = (p1 > 100.0 + 5.0) | (p1 < 50.0 - 5.0)
    est = Estimator(db)
    stream = Stream(est)
    flags = np.array([stream.step(stream.row({c: log.channels[c][k] for c in stream.channels}))
                      for k in range(len(log))])
    np.testing.assert_array_equal((flags & FLAG_FAR_OUTSIDE) != 0, far)
    assert np.all(flags[far] & FLAG_NO_UPDATE)
    est.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = est.run_arrays(*est._split(log))
    np.testing.assert_array_equal(flags, batch.flags)


def test_a_sensor_stuck_at_one_value_is_named_so_not_given_a_unit():
    """T48 written 950 K on every sample of the clean demo flight (a thermocouple open, a frozen
    bus word): the misfit warning names the one value and the range its prediction moved over.
    Before, it guessed a unit ("logged in degC?": 950 K is about 1228 K less 273 on the cruise)."""
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db_path, logs = demo_paths()
    log = read_log([p for p in logs if "degraded" not in p][0])
    log.channels["T48"] = np.full_like(log.channels["T48"], 950.0)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        Estimator(db_path).run(log)
    said = [str(w.message) for w in got if "'T48' misfit" in str(w.message)]
    assert said and all("one value, 950 K, on every sample kept where it misfit" in s and "degC" not in s
                        for s in said), said
