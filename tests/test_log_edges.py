"""Where a log starts and how it is sampled: the filter's settling time (the samples right after
its start are flagged FLAG_SETTLING and not trusted, so a log of a few seconds cannot pass as
trusted estimates), an engine not yet running, a recorder that drops rows."""
import json

import numpy as np
import pytest

from pwl.cli import main
from pwl.database import GainDatabase
from pwl.errors import PwlWarning
from pwl.demo_data import demo_paths
from pwl.estimator import Estimator
from pwl.logs import Log, read_log, write_log
from pwl.results import Result, trusted
from pwl.runtime import FLAG_FAR_OUTSIDE, FLAG_NOT_STARTED, FLAG_SETTLING

DB, LOGS = demo_paths()


def test_settling_time_is_three_time_constants_of_the_slowest_error_dynamics():
    """Against the closed-loop matrices written out here with numpy (not pwl's augmentation)."""
    db = GainDatabase.open(DB)
    d, Vp, K = db.dynamics, db.tuner["V_pinv"], db.kalman["K"]
    nx, nq = d["A"].shape[-1], Vp.shape[1]
    rho = 0.0
    for i in np.ndindex(db.dyn_grid.shape):
        Aa = np.block([[d["A"][i], d["L"][i] @ Vp], [np.zeros((nq, nx)), np.eye(nq)]])
        Ca = np.hstack([d["C"][i], d["M"][i] @ Vp])
        rho = max(rho, np.abs(np.linalg.eigvals((np.eye(nx + nq) - K[i] @ Ca) @ Aa)).max())
    assert db.settling_time() == pytest.approx(3 * db.dt / -np.log(rho), rel=1e-9)
    assert db.settling_time(1.0) == pytest.approx(db.settling_time() / 3, rel=1e-12)


def test_the_first_samples_after_the_start_are_flagged_settling_and_not_trusted():
    """A cruise slice (mid-flight start) whose first 50 samples have no Nf: the filter starts
    at sample 50 and settles over the next ceil(settle / dt) samples; at their end the health
    estimates are within 0.2 pt RMS of where they settle for good (0.95 pt off after 0.5 s)."""
    log = read_log(LOGS[1])
    a = 25000
    chans = {c: v[a:a + 9000].copy() for c, v in log.channels.items()}
    chans["Nf"][:50] = np.nan
    cut = Log(log.time[a:a + 9000] - log.time[a], chans, log.units, attrs={"dt": 0.015})
    est = Estimator(DB)
    res = est.run(cut)
    n = int(np.ceil(est.settle / est.db.dt))
    settling = (res.flags & FLAG_SETTLING) != 0
    assert est.settle == pytest.approx(est.db.settling_time()) and 10 < est.settle < 60
    assert np.all((res.flags[:50] & FLAG_NOT_STARTED) != 0) and not settling[:50].any()
    assert settling[50:50 + n].all() and not settling[50 + n:].any()
    assert not trusted(res.flags)[:50 + n].any() and res.counts()["settling"] == n
    settled = res.h_hat[-3000:].mean(axis=0)
    def off(k):  # RMS over the health parameters, percent points
        return 100 * np.sqrt(np.mean((res.h_hat[k] - settled) ** 2))
    assert off(50 + n) < 0.2 < 0.8 < off(50 + int(0.5 / est.db.dt))
    assert Estimator(DB, settle=0.0).run(cut).counts()["settling"] == 0


def test_a_log_shorter_than_the_settling_time_fails_pwl_run(tmp_path, capsys):
    log = read_log(LOGS[1])
    short = Log(log.time[:300], {c: v[:300] for c, v in log.channels.items()}, log.units, attrs={"dt": 0.015})
    write_log(tmp_path / "short.h5", short)
    code = main(["run", DB, str(tmp_path / "short.h5"), "-o", str(tmp_path / "out"), "-j", "1"])
    out = capsys.readouterr()
    assert code == 1 and "too short" in out.out + out.err and "300 within the filter's settling time" in out.out + out.err


def test_a_log_that_drops_rows_runs_on_the_database_time_grid():
    """A recorder that drops rows (45 % of the steps skip two rows: 15 or 45 ms, median 15 ms):
    the filter predicts through the missing rows instead of stepping once per row. Fn RMS error
    against the simulation's truth within 1.1x of the complete log's (one step per row: 1.7x);
    the provenance counts the missing rows."""
    log = read_log(LOGS[1])
    n = len(log.time)
    steps = np.where(np.random.default_rng(3).random(n) < 0.55, 1, 3)
    idx = np.concatenate([[0], np.cumsum(steps)])
    idx = idx[idx < n]
    holes = Log(log.time[idx], {c: v[idx] for c, v in log.channels.items()}, log.units,
                {c: np.asarray(v)[idx] for c, v in log.truth.items()}, log.truth_units)

    def fn_error(res, lg):
        truth = lg.truth["Fn"]
        return np.sqrt(np.nanmean((res.channel("z_hat", "Fn") / truth - 1) ** 2))
    est = Estimator(DB)
    full = fn_error(est.run(log), log)
    res = est.run(holes)
    assert len(res.time) == idx.size and res.attrs["provenance"]["rows_missing"] == idx[-1] - (idx.size - 1)
    assert fn_error(res, holes) < 1.1 * full
    est.MISSING_ROWS = np.inf                  # one filter step per logged row, as before
    assert fn_error(est.run(holes), holes) > 1.5 * full


def test_an_engine_off_before_the_flight_does_not_fail_the_log(tmp_path, capsys):
    """15 minutes of an engine not running (speeds and fuel flow 0: implausible, so the filter
    waits) before the 13.5-minute degraded demo flight: pwl run passes it (the samples before
    the filter's start do not count; it failed as 'too few'), and once the filter starts the
    estimates are the flight's alone."""
    log = read_log(LOGS[1])
    off = 60000
    chans = {c: np.concatenate([np.full(off, 0.0 if c in ("Nf", "Nc", "Wf") else v[0]), v])
             for c, v in log.channels.items()}
    write_log(tmp_path / "late.h5", Log(np.arange(off + len(log.time)) * 0.015, chans, log.units,
                                         attrs={"dt": 0.015}))
    code = main(["run", DB, str(tmp_path / "late.h5"), "-o", str(tmp_path / "out"), "-j", "1"])
    out = capsys.readouterr()
    assert code == 0 and "TOO FEW" not in out.out + out.err
    with pytest.warns(PwlWarning, match=r"channel 'Wf': 60000 of 114001 samples implausible, typically 0 where "
                                        r"0.01 to 6 kg/s is plausible: the engine not running"):
        res = Estimator(DB).run(str(tmp_path / "late.h5"))      # (it guessed lb/s from the flight's values)
    assert res.counts()["not_started"] == off
    np.testing.assert_allclose(res.z_hat[off:], Estimator(DB).run(log).z_hat, rtol=1e-9, atol=0)


def test_a_sensor_that_fails_for_a_whole_log_is_left_out_of_it(tmp_path):
    """P50 and P15 swapped on the degraded demo flight: each misfits on 35 % of the samples and
    was used on the others (health 4 points off, Fn 4.4 % RMS, 98 % trusted). Now the log runs
    again without them (named in a warning and the provenance): Fn within 1 % RMS of the
    simulation's truth, health held (not estimable without them), and pwl run fails the log.
    The chunked file run gives the same estimates; a clean flight loses no sensor."""
    log = read_log(LOGS[1])
    swapped = Log(log.time, dict(log.channels, P50=log.channels["P15"], P15=log.channels["P50"]), log.units,
                  attrs={"dt": 0.015})
    est = Estimator(DB)
    with pytest.warns(PwlWarning, match=r"sensor 'P50' misfit on 35% of the samples where the model should fit .*"
                                        r"sensor 'P15' .*Estimated again without them"):
        res = est.run(swapped)
    assert json.loads(res.attrs["provenance"]["failed_channels"]) == ["P50", "P15"]
    fn = res.channel("z_hat", "Fn") / log.truth["Fn"] - 1
    assert np.sqrt(np.mean(fn ** 2)) < 0.01 and res.counts()["health_held"] == len(log.time)
    write_log(tmp_path / "swapped.h5", swapped)
    counts = est.run_file(tmp_path / "swapped.h5", tmp_path / "s.estimates.h5", chunk=20000)
    np.testing.assert_array_equal(Result.load(tmp_path / "s.estimates.h5").z_hat, res.z_hat)
    assert counts["health_held"] == len(log.time)
    assert main(["run", DB, str(tmp_path / "swapped.h5"), "-o", str(tmp_path / "out"), "-j", "1"]) == 1
    assert json.loads(est.run(log).attrs["provenance"]["failed_channels"]) == []


def test_messages_for_coarse_time_stamps_and_channel_names_in_another_case():
    from pwl.logs import LogError, check_time
    with pytest.raises(LogError, match=r"x.csv: time does not increase at sample 1 \(0.0 -> 0.0\); it repeats on 30 "
                                       r"of 39 rows: time stamps coarser than the sampling\?"):
        check_time("x.csv", np.repeat(np.arange(10.0), 4))          # 1 s stamps on a 0.25 s log
    with pytest.raises(LogError, match=r"time does not increase at sample 2 \(1.0 -> 0.5\)$"):
        check_time("x.csv", np.array([0.0, 1.0, 0.5, 2.0]))           # no hint for a time going back
    t = np.arange(40.0)
    t[[1, 20]], t[30] = t[[0, 19]], 28.5                             # two rows repeat, one goes back
    with pytest.raises(LogError, match=r"at sample 1 \(0.0 -> 0.0\) \(and on 2 more of its 39 steps: 2 repeat, 1 "
                                       r"go back\)$"):
        check_time("x.csv", t)
    with pytest.raises(LogError, match=r"at sample 5 \(4.0 -> 0.0\); it starts again there: two logs joined\?"):
        check_time("x.csv", np.r_[np.arange(5.0), np.arange(5.0)])
    log = Log(np.arange(3.0), {"wf": np.ones(3)}, {"wf": ""})
    with pytest.raises(LogError, match=r"channel 'Wf' is missing \(log has: wf\); 'wf' differs in case only"):
        log.require(["Wf"])


def test_the_filter_settles_again_after_an_outage_longer_than_its_settling_time():
    """Two cruise slices of different engines in one log, 60 s of nothing between (an engine shut
    down and restarted, a recorder's bus lost): the first update after the outage and the settling
    time after it are flagged FLAG_SETTLING, not trusted (the health there was the first engine's,
    2.5 points off); an outage shorter than the settling time is not."""
    est = Estimator(DB)
    a, b = read_log(LOGS[0]), read_log(LOGS[1])
    n = int(np.ceil(est.settle / est.db.dt))

    def joined(gap):
        chans = {c: np.concatenate([a.channels[c][25000:29000], np.full(gap, np.nan), b.channels[c][25000:29000]])
                 for c in a.channels}
        return Log(np.arange(8000 + gap) * est.db.dt, chans, a.units)
    long_gap = int(60.0 / est.db.dt)
    res = est.run(joined(long_gap))
    settling = (res.flags & FLAG_SETTLING) != 0
    back = 4000 + long_gap
    np.testing.assert_array_equal(np.flatnonzero(settling), np.r_[0:n, back:back + n])
    assert not trusted(res.flags)[back:back + n].any() and trusted(res.flags)[back + n:].all()
    short = est.run(joined(n // 2))
    assert np.flatnonzero(short.flags & FLAG_SETTLING).max() == n - 1


def test_samples_interpolated_from_trims_the_build_filled_are_flagged_and_not_trusted():
    """The demo database with every trim at 0 m altitude marked filled (/trim/status, as a build
    whose trims failed there stores it): exactly the samples whose trim interpolation puts weight
    on those nodes (altitude below the next breakpoint, 2000 m; the ground clipped to 0 m) are
    flagged, not trusted, kept out of the snapshots and named in a warning; the estimates are the
    same numbers. Before, nothing was flagged (a user's plant read a new engine 5.5 % off there)."""
    from pwl.database import FILLED
    from pwl.runtime import FLAG_TRIM_FILLED
    log = read_log(LOGS[1])
    n = 30000
    cut = Log(log.time[:n], {c: v[:n] for c, v in log.channels.items()}, log.units, attrs={"dt": 0.015})
    ref = Estimator(DB).run(cut)
    db = GainDatabase.open(DB)
    db.trim_status = np.zeros_like(db.trim_status)
    db.trim_status[0] = FILLED
    assert db.trim_grid.axes[0].name == "alt" and db.trim_grid.axes[0].values[1] == 2000.0
    with pytest.warns(PwlWarning, match=r"samples interpolated from trims the build did not compute \(204 of 1428 "
                                        r"nodes filled or extrapolated from their line: alt 0, Mach 0, NfR 60;"):
        res = Estimator(db).run(cut)
    started = (ref.flags & FLAG_NOT_STARTED) == 0
    expect = started & (cut.channels["alt"] < 2000.0)
    assert 0 < expect.sum() < started.sum()
    np.testing.assert_array_equal((res.flags & FLAG_TRIM_FILLED) != 0, expect)
    np.testing.assert_array_equal(res.flags & ~FLAG_TRIM_FILLED, ref.flags)
    for o in ref.outputs:
        np.testing.assert_array_equal(res.outputs[o], ref.outputs[o])
    np.testing.assert_array_equal(trusted(res.flags), trusted(ref.flags) & ~expect)
    assert res.counts()["trim_filled"] == expect.sum()
    assert len(res.snapshots) < len(ref.snapshots)


def test_rows_a_recorder_did_not_write_are_the_rows_it_wrote_empty():
    """A demo flight whose recorder paused for 60 s in the climb and wrote one row a second of
    the second half (the median step still the database's dt): its estimates at the rows it has
    equal, to 1e-9, those of the whole flight with the rows it lacks empty (every channel NaN: the
    filter predicts, inputs held), the pause is named and the filter settles again after it.
    Before, each gap was one 15 ms step of the filter: the second half's thrust 9 % RMS off."""
    est = Estimator(DB)
    log = read_log(LOGS[0])
    n = len(log)
    lost = np.zeros(n, dtype=bool)
    lost[6000:6000 + int(60.0 / est.db.dt)] = True
    slow = np.arange(n) >= n // 2
    lost[slow] = (np.arange(n)[slow] - n // 2) % 67 != 0
    empty = Log(log.time, {c: np.where(lost, np.nan, v) for c, v in log.channels.items()}, log.units)
    ref = est.run(empty)
    cut = Log(log.time[~lost], {c: v[~lost] for c, v in log.channels.items()}, log.units, path="cut.h5")
    with pytest.warns(PwlWarning, match=r"cut.h5: \d+ gap\(s\) in the time column.*lower rate there"):
        res = est.run(cut)
    np.testing.assert_allclose(res.time, log.time[~lost], rtol=0, atol=1e-9)
    for o in ref.outputs:
        want = ref.outputs[o][~lost]
        scale = np.nanmax(np.abs(want), axis=0)
        assert np.nanmax(np.abs(res.outputs[o] - want) / scale) <= 1e-9, o
        np.testing.assert_array_equal(np.isnan(res.outputs[o]), np.isnan(want))
    np.testing.assert_array_equal(res.flags, ref.flags[~lost])
    back = np.searchsorted(res.time, log.time[6000] + 60.0)
    assert res.flags[back] & FLAG_SETTLING and not trusted(res.flags[back:back + 10]).any()


def test_an_engine_start_in_the_log_does_not_cost_the_flight():
    """The degraded demo flight with 30 s of engine start before it (speeds and fuel flow rising
    from 0, pressures and temperatures from the inlet's: far below the grid's 60 % NfR) and a
    shutdown after it: the samples far outside the grid make no update and are not trusted, no
    sensor fails for the log, and the steady snapshots' health is the flight's alone (within 0.1
    pt). Before, the start left the filter off for 3 minutes: Nc and Ps30 failed for the log, the
    health was held all flight, and the warning blamed a wrong input or database."""
    log = read_log(LOGS[1])
    est = Estimator(DB)
    ref = est.run(log)
    m = int(30.0 / est.db.dt)
    ramp = np.linspace(0.0, 1.0, m) ** 2

    def edge(k, r):
        out = {}
        for c, v in log.channels.items():
            base = v[k]
            if c in ("Wf", "Nf", "Nc"):
                out[c] = base * r
            elif c in ("T24", "T30", "T48"):
                out[c] = log.channels["T2"][k] + (base - log.channels["T2"][k]) * r
            elif c in ("Ps30", "P50", "P15"):
                out[c] = log.channels["P2"][k] + (base - log.channels["P2"][k]) * r
            else:
                out[c] = np.full(m, base)
        return out
    pre, post = edge(0, ramp), edge(-1, ramp[::-1])
    chans = {c: np.concatenate([pre[c], log.channels[c], post[c]]) for c in log.channels}
    n = len(log) + 2 * m
    started = Log(log.time[0] + np.arange(n) * est.db.dt, chans, log.units, path="started.h5")
    res = est.run(started)
    assert est.failed == []
    far = (res.flags & FLAG_FAR_OUTSIDE) != 0
    assert far[:m].sum() > m // 2 and far[-m:].sum() > m // 2 and not trusted(res.flags)[far].any()
    a, b = ref.snapshots.outputs["h_hat"], res.snapshots.outputs["h_hat"]
    assert a.shape == b.shape and np.abs(a - b).max() < 1e-3


def test_pwl_run_takes_the_settling_time(tmp_path, capsys):
    """``pwl run --settle 5`` flags the first ceil(5 / dt) samples after the filter's start
    settling (the default: the database's 27 s), records it in the results' mode, and a rerun
    with another settling time computes again (not skipped as done)."""
    import h5py

    log = read_log(LOGS[1])
    n = 20000
    write_log(tmp_path / "f.h5", Log(log.time[:n], {c: v[:n] for c, v in log.channels.items()}, log.units))
    assert main(["run", DB, str(tmp_path / "f.h5"), "-o", str(tmp_path / "a"), "-j", "1", "--settle", "5"]) == 0
    res = Result.load(tmp_path / "a" / "f.estimates.h5")
    settling = np.flatnonzero(res.flags & FLAG_SETTLING)
    started = np.flatnonzero((res.flags & FLAG_NOT_STARTED) == 0)[0]
    np.testing.assert_array_equal(settling, started + np.arange(int(np.ceil(5.0 / GainDatabase.open(DB).dt))))
    with h5py.File(tmp_path / "a" / "f.estimates.h5") as f:
        assert "+settle:5" in f.attrs["mode"]
    assert main(["run", DB, str(tmp_path / "f.h5"), "-o", str(tmp_path / "a"), "-j", "1"]) == 0
    assert np.count_nonzero(Result.load(tmp_path / "a" / "f.estimates.h5").flags & FLAG_SETTLING) == int(
        np.ceil(Estimator(DB).settle / GainDatabase.open(DB).dt))
    capsys.readouterr()
