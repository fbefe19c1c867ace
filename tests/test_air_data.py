"""Channels that are wrong without being implausible: pressure altitude, Mach and the inlet total
pressure that disagree (pwl.airdata, FLAG_AIR_DATA), inputs held for want of a value (not
trusted), channels logged at a lower rate than the log's rows (held between their samples), and a
log's ``dt`` attribute that its time column contradicts."""
import json
import os
import warnings

import numpy as np
import pytest

from models.gaspath import P_STD, isa
from pwl.airdata import AIR_DATA_TOLERANCE, air_data_channels, disagree, inlet_pressure, isa_pressure
from pwl.cli import main
from pwl.demo_data import demo_paths
from pwl.errors import PwlWarning
from pwl.estimator import Estimator, hold_low_rate
from pwl.logs import Log, read_log, write_log
from pwl.results import trusted
from pwl.runtime import FLAG_AIR_DATA, FLAG_HELD_INPUT, FLAG_NO_UPDATE
from pwl.snapshots import SteadyConfig

DB, LOGS = demo_paths()
_RUNS = {}


def degraded():
    return read_log(LOGS[1])


def with_channels(log: Log, **chans) -> Log:
    return Log(log.time, log.channels | chans, log.units, log.truth, log.truth_units, dict(log.attrs), log.path)


def clean_run():
    if "clean" not in _RUNS:
        _RUNS["clean"] = Estimator(DB).run(degraded())
    return _RUNS["clean"]


def test_standard_atmosphere_and_ram_pressure_match_the_plant_model():
    """pwl.airdata against the turbofan model's own ISA (models.gaspath.isa) and the isentropic
    ram rise written out here; the demo flight's P2 is the plant's, recovery 0.995."""
    for h in (-300.0, 0.0, 5000.0, 10999.0, 11000.0, 15000.0):
        assert isa_pressure(h) == pytest.approx(isa(h, 0.0)[1], rel=1e-6)
    assert P_STD == pytest.approx(101325.0)
    assert inlet_pressure(10000.0, 0.8) == pytest.approx(isa(10000.0, 0.0)[1] * 1.128 ** 3.5, rel=1e-6)
    log = degraded()
    ratio = log.channels["P2"] / inlet_pressure(log.channels["alt"], log.channels["Mach"])
    assert np.nanmax(np.abs(ratio - 0.995)) < 0.006
    assert not disagree(log.channels["alt"], log.channels["Mach"], log.channels["P2"]).any()
    assert disagree([10000.0, 10000.0], [0.0, 0.8], [inlet_pressure(10000.0, 0.8)] * 2).tolist() == [True, False]
    assert disagree([np.nan], [0.8], [5e4]).tolist() == [False]


def test_which_channels_are_air_data():
    units = {"alt": "ft", "Mach": "-", "Nf": "rpm", "P2": "kPa"}
    assert air_data_channels(["alt", "Mach", "Nf"], units, "P2") == (0, 1, pytest.approx(0.3048), 1000.0)
    assert air_data_channels(["alt", "Nf"], units, "P2") is None            # no Mach
    assert air_data_channels(["alt", "Mach"], units, None) is None          # no inlet pressure
    assert air_data_channels(["alt", "Mach"], units | {"P2": "K"}, "P2") is None


@pytest.mark.parametrize("case", ["Mach 0", "altitude 0", "Mach frozen in the climb"])
def test_disagreeing_air_data_is_flagged_untrusted_and_named(case, tmp_path, capsys):
    """A log whose Mach or altitude is wrong, but plausible, was trusted (Fn 88 % off with Mach 0):
    the samples where altitude, Mach and P2 disagree by more than 6 % are flagged FLAG_AIR_DATA
    -- exactly those, per pwl.airdata.disagree on the logged values -- not trusted and kept out of
    the snapshots; pwl run names the channels and fails the log."""
    log = degraded()
    mach, alt = log.channels["Mach"].copy(), log.channels["alt"].copy()
    if case == "Mach 0":
        mach[:] = 0.0
    elif case == "altitude 0":
        alt[:] = 0.0
    else:
        k = slice(int(150 / 0.015), int(270 / 0.015))
        mach[k] = mach[k.start]
    bad = with_channels(log, Mach=mach, alt=alt)
    with pytest.warns(PwlWarning, match=r"'alt', 'Mach' and 'P2' disagree on \d+ of 54001 samples"):
        res = Estimator(DB).run(bad)
    # the reference: the plant model's own standard atmosphere and the ram rise written out here
    p_amb = np.array([isa(h, 0.0)[1] for h in alt])
    off = np.abs(np.log(log.channels["P2"] / (p_amb * (1 + 0.2 * mach ** 2) ** 3.5))) > np.log1p(AIR_DATA_TOLERANCE)
    expect = off & ((res.flags & FLAG_HELD_INPUT) == 0)
    np.testing.assert_array_equal((res.flags & FLAG_AIR_DATA) != 0, expect)
    assert expect.sum() > (2000 if "frozen" in case else 30000)
    assert not trusted(res.flags)[expect].any()
    assert res.counts()["air_data"] == expect.sum()
    assert (clean_run().flags & FLAG_AIR_DATA == 0).all()
    # no snapshot where they disagree (as outside the grid: at most max_outside of a window's samples)
    for t0, t1 in zip(res.snapshots.t0, res.snapshots.t1):
        inside = (res.time >= t0) & (res.time <= t1)
        assert expect[inside].mean() <= SteadyConfig().max_outside
    if case != "Mach frozen in the climb":
        write_log(tmp_path / "bad.h5", bad)
        assert main(["run", DB, str(tmp_path / "bad.h5"), "-o", str(tmp_path / "out"), "-j", "1"]) == 1
        out = capsys.readouterr()
        assert "TOO FEW ESTIMATES" in out.out + out.err
        assert "altitude, Mach and inlet pressure disagree" in out.out + out.err


def test_held_inputs_are_not_trusted():
    flags = np.array([0, FLAG_HELD_INPUT, FLAG_AIR_DATA, FLAG_NO_UPDATE, 0])
    np.testing.assert_array_equal(trusted(flags), [True, False, False, False, True])


def test_hold_low_rate_fills_between_samples_only_for_channels_logged_at_a_lower_rate():
    """Against a forward fill written out here; random dropouts (a steady channel with 45 % of its
    rows missing at random) and long gaps are left as they are."""
    rng = np.random.default_rng(3)
    n = 400
    a = rng.normal(size=(n, 3))
    a[np.arange(n) % 4 != 1, 0] = np.nan            # every 4th row
    a[rng.random(n) < 0.45, 1] = np.nan              # dropouts at random
    a[np.arange(n) % 3 != 0, 2] = np.nan             # every 3rd row, with a 40-row gap
    a[200:240, 2] = np.nan
    ref = a.copy()
    held = hold_low_rate(a, max_rows=20)
    assert held == {0: 4, 2: 3}
    np.testing.assert_array_equal(a[:, 1], ref[:, 1])
    for j, med in held.items():
        last = np.nan
        since = n
        for i in range(n):
            if np.isfinite(ref[i, j]):
                last, since = ref[i, j], 0
                assert a[i, j] == ref[i, j]
            else:
                since += 1
                if since <= 2 * med:
                    assert a[i, j] == last
                else:
                    assert np.isnan(a[i, j])
    assert np.isnan(a[205:240, 2]).all()
    assert hold_low_rate(ref.copy(), max_rows=3) == {2: 3}    # a 4-row step is more than max_rows


def test_a_log_with_channels_at_lower_rates_reads_like_the_complete_log(tmp_path):
    """Air data every 4th row and the six gas-path sensors every 4th row in turn (a merged
    multi-rate export): snapshots as the complete log's (there were none: the operating point
    was empty on 3 rows in 4) and their health within 0.3 pt of its; the channels held are named in the
    provenance."""
    log = degraded()
    n = len(log)
    rows = np.arange(n)
    chans = {}
    for c in ("alt", "Mach", "P2", "T2"):
        chans[c] = np.where(rows % 4 == 0, log.channels[c], np.nan)
    for j, c in enumerate(("T24", "T30", "T48", "Ps30", "P50", "P15")):
        chans[c] = np.where(rows % 4 == j % 4, log.channels[c], np.nan)
    res = Estimator(DB).run(with_channels(log, **chans))
    ref = clean_run()
    assert len(res.snapshots) == len(ref.snapshots) > 0
    h, h0 = res.snapshots.outputs["h_hat"], ref.snapshots.outputs["h_hat"]
    assert np.abs(h - h0).max() < 3e-3          # 0.19 pt measured
    assert res.counts()["trusted"] >= 0.99 * ref.counts()["trusted"]
    held = json.loads(res.attrs["provenance"]["low_rate_channels"])
    assert sorted(held) == sorted(chans) and all(v == pytest.approx(0.06) for v in held.values())
    assert json.loads(ref.attrs["provenance"]["low_rate_channels"]) == {}


def test_a_dt_attribute_the_time_column_contradicts_is_not_believed():
    log = degraded()
    log.attrs["dt"] = 1.0
    assert log.dt == pytest.approx(0.015)
    one = Log(log.time[:1], {c: v[:1] for c, v in log.channels.items()}, log.units, attrs={"dt": 0.015})
    assert one.dt == 0.015


@pytest.mark.parametrize("case", ["clipped at 2.0 kg/s", "frozen a minute in the descent"])
def test_an_input_frozen_while_the_engine_moves_is_not_trusted_and_blinds_the_update(case):
    """Fuel flow clipped through the take-off and climb (T40 up to 7.6 % low, trusted, no word), or
    frozen for a minute of the descent (Nc and T48 then misfit on a fifth of the flight, were
    dropped for the log and the health held all flight): the runs of exactly one value longer than
    the stuck detector's time while altitude, Mach or Nf move more than 5 % of their span are
    flagged held (not trusted) and named, and the log runs again without measurement updates
    there, so the filter keeps what it knew: no sensor dropped, health within 0.05 pt RMS of the
    clean flight's after the run. The clean flight repeats its fuel flow only at cruise, with
    altitude and Mach still."""
    log = degraded()
    wf = log.channels["Wf"].copy()
    if case.startswith("clipped"):
        wf = np.minimum(wf, 2.0)
    else:
        k = (log.time >= 600) & (log.time < 660)
        wf[k] = wf[np.flatnonzero(k)[0]]
    est = Estimator(DB)
    with pytest.warns(PwlWarning, match=r"input 'Wf' held [0-9.]+ kg/s exactly on \d+ of 54001 samples .* while "
                                        r"the operating point moved"):
        res = est.run(with_channels(log, Wf=wf))
    held = (res.flags & FLAG_HELD_INPUT) != 0
    n = int(np.ceil(2.0 / est.db.dt))              # Estimator(stuck_after=2.0 s), its default
    same = np.concatenate([[False], wf[1:] == wf[:-1]])
    runs = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    expect = np.zeros(len(log), dtype=bool)
    alt, mach = log.channels["alt"], log.channels["Mach"]
    for a, b in zip(runs[::2] - 1, runs[1::2]):
        if b - a >= n and (np.ptp(alt[a:b]) > 0.05 * 15500 or np.ptp(mach[a:b]) > 0.05):
            expect[a:b] = True
    assert expect.sum() >= 4000
    np.testing.assert_array_equal(held, expect)
    assert not trusted(res.flags)[expect].any()
    assert ((res.flags[expect] & FLAG_NO_UPDATE) != 0).all() and est.failed == []
    after = np.arange(len(log)) > np.flatnonzero(expect)[-1] + 1000
    h_true = np.column_stack([log.truth[h] for h in est.db.names["h"]])
    rms = lambda r: np.sqrt(np.mean((r.h_hat[after] - h_true[after]) ** 2))
    assert rms(res) < rms(clean_run()) + 5e-4
    assert clean_run().counts()["held_input"] == 0


def test_a_stream_flags_disagreeing_air_data_as_a_log_run_does():
    """pwl.streaming.Stream runs the same test (the ufunc pwl.airdata._disagree, in its compiled
    step) on each sample: the same samples flagged as Estimator.run's on the Mach-0 flight."""
    from pwl.streaming import Stream
    log = degraded()
    sl = slice(20000, 30000)
    chans = {c: v[sl].copy() for c, v in log.channels.items()}
    chans["Mach"][:] = 0.0
    bad = Log(log.time[sl] - log.time[sl][0], chans, log.units)
    est = Estimator(DB)
    with pytest.warns(PwlWarning, match="disagree"):
        batch = est.run(bad)
    stream = Stream(est)
    rows = np.column_stack([chans[c] for c in stream.channels])
    flags = np.array([stream.step(r) for r in rows])
    air = (flags & FLAG_AIR_DATA) != 0
    np.testing.assert_array_equal(air, (batch.flags & FLAG_AIR_DATA) != 0)
    assert air.sum() > 5000


def late(x: np.ndarray, seconds: float, dt: float = 0.015) -> np.ndarray:
    """x logged ``seconds`` late (a whole number of samples; the first value held before)."""
    k = int(round(seconds / dt))
    return np.concatenate([np.full(k, x[0]), x[:len(x) - k]])


def fn_error(res, log) -> float:
    """Fn RMS error (%) against the log's truth after the first 120 s."""
    settled = res.time >= res.time[0] + 120.0
    e = 100 * (res.channel("z_hat", "Fn") - log.truth["Fn"]) / log.truth["Fn"]
    return float(np.sqrt(np.mean(e[settled] ** 2)))


@pytest.mark.parametrize("seconds", [0.3, 2.1])
def test_an_inlet_pressure_logged_late_is_measured_named_and_fixed_by_the_channel_map(seconds, tmp_path):
    """P2 logged late (a bus's latency) read Fn 3.3 % RMS off in the transients (2 s; 0.23 % on
    time) and said nothing. The fitted lag recovers the shift that was applied (within 0.02 s;
    the clean flight's within 0.01 s, no warning), the run names P2 and the lag, and the channel
    map's lag shifts it back: Fn within 1.1x of the clean flight's error (before: over 2.5x)."""
    from pwl.channel_map import ChannelMap
    log = degraded()
    clean = Estimator(DB)
    clean_res = clean.run(log)
    assert abs(clean.air_data_lag[0]) < 0.01
    bad = with_channels(log, P2=late(log.channels["P2"], seconds))
    est = Estimator(DB)
    with pytest.warns(PwlWarning, match=rf"'P2' runs {seconds:.2g} s behind 'alt' and 'Mach'"):
        res = est.run(bad)
    assert est.air_data_lag[0] == pytest.approx(seconds, abs=0.02)
    assert res.attrs["provenance"]["air_data_lag_s"] == pytest.approx(seconds, abs=0.02)
    assert fn_error(res, log) > 2.5 * fn_error(clean_res, log)
    cmap = ChannelMap.from_dict({"channels": {c: {"column": c, "lag": seconds} if c == "P2" else c
                                              for c in log.channels}})
    fixed = cmap.apply(bad)
    k = int(round(seconds / 0.015))
    np.testing.assert_allclose(fixed.channels["P2"][k:-k], log.channels["P2"][k:-k], rtol=1e-9)
    assert np.isnan(fixed.channels["P2"][-1])
    fixed = Log(fixed.time, fixed.channels, fixed.units, log.truth, log.truth_units, {}, log.path)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PwlWarning)
        est.run(fixed)
    assert fn_error(est.run(fixed), log) < 1.1 * fn_error(clean_res, log)


def test_air_data_lag_fit_adds_over_chunks():
    """The lag's sums of a log cut in pieces add up to the whole log's fit (chunked runs)."""
    from pwl.airdata import lag, lag_sums
    log = degraded()
    alt, mach, p2 = log.channels["alt"], log.channels["Mach"], late(log.channels["P2"], 1.0)
    whole = lag(lag_sums(alt, mach, p2, 0.015))
    parts = sum(lag_sums(alt[a:a + 10000], mach[a:a + 10000], p2[a:a + 10000], 0.015) for a in range(0, len(p2), 10000))
    assert lag(parts)[0] == pytest.approx(whole[0], abs=0.01)
    assert whole[0] == pytest.approx(1.0, abs=0.02)
    assert np.isnan(lag(lag_sums(np.full(500, 3000.0), np.full(500, 0.5), np.full(500, 8e4), 0.015))[0])


def test_a_stream_finds_a_frozen_input_as_it_goes():
    """Fuel flow frozen a minute in the descent, streamed: the stream left Nc and T48 out while
    they misfit and its health was up to 39 points off after the freeze. It now flags the frozen
    steps held (from the stuck detector's 2 s into the run, once altitude has moved 5 % of its
    span: within 15 s) and makes no measurement update there, so its health after the freeze is
    as close to the truth as the log run's (within 0.05 pt of it) and the clean stream flags none."""
    from pwl.streaming import Stream
    log = degraded()
    wf = log.channels["Wf"].copy()
    k = (log.time >= 600) & (log.time < 660)
    wf[k] = wf[np.flatnonzero(k)[0]]
    bad = with_channels(log, Wf=wf)
    est = Estimator(DB)
    with pytest.warns(PwlWarning, match="input 'Wf' held"):
        batch = est.run(bad)
    stream = Stream(Estimator(DB))
    rows = np.column_stack([bad.channels[c] for c in stream.channels])
    flags, h = np.empty(len(rows), dtype=np.int64), np.empty((len(rows), len(stream.h_hat)))
    for i, r in enumerate(rows):
        flags[i] = stream.step(r)
        h[i] = stream.h_hat
    held = (flags & FLAG_HELD_INPUT) != 0
    assert not (held & ((batch.flags & FLAG_HELD_INPUT) == 0)).any()
    assert 600 < log.time[held][0] < 615 and held[k].mean() > 0.7
    assert ((flags[held] & FLAG_NO_UPDATE) != 0).all()
    h_true = np.column_stack([log.truth[c] for c in est.db.names["h"]])
    after = log.time > 680
    err = lambda hh: np.abs(hh[after] - h_true[after]).max()
    assert err(h) < err(batch.h_hat) + 5e-4
    clean = Stream(Estimator(DB))
    assert not any(clean.step(r) & FLAG_HELD_INPUT for r in np.column_stack([log.channels[c] for c in clean.channels]))


def test_the_fleet_summary_gives_each_flights_inlet_pressure_lag(tmp_path):
    """pwl run on a folder: the summary row of a flight whose P2 was logged 1.2 s late says so
    (air_data_lag_s within 0.02 s of the shift applied; the flight on time within 0.01 s)."""
    from pwl.fleet.runs import read_summary
    log = degraded()
    sl = slice(0, 30000)
    cut = lambda chans: Log(log.time[sl], {c: v[sl] for c, v in chans.items()}, log.units)
    (tmp_path / "logs").mkdir()
    write_log(tmp_path / "logs" / "on_time.h5", cut(log.channels))
    write_log(tmp_path / "logs" / "late.h5", cut(log.channels | {"P2": late(log.channels["P2"], 1.2)}))
    assert main(["run", DB, str(tmp_path / "logs"), "-o", str(tmp_path / "out"), "-j", "1"]) in (0, 1)
    out = [f for f in os.listdir(tmp_path / "out") if f.startswith("summary.")][0]
    rows = {os.path.basename(r["log"]): r for r in read_summary(tmp_path / "out" / out)}
    assert float(rows["late.h5"]["air_data_lag_s"]) == pytest.approx(1.2, abs=0.02)
    assert abs(float(rows["on_time.h5"]["air_data_lag_s"])) < 0.01


def test_many_sensors_failing_at_once_point_at_an_input_or_the_database():
    """Fuel flow logged 30 % high (a mis-scaled meter, or a log of another engine): Ps30, T48 and
    P50 fail for the log (and Nf, a scheduling sensor, misfits on most samples). Naming them as
    three failed sensors sent the user to the wrong place: the warning now says so many at once
    point at an input or the database. Two swapped sensors (P50, P15) do not get that hint."""
    log = degraded()
    with pytest.warns(PwlWarning, match=r"3 sensors at once \(Ps30, T48, P50\): rather an input that is wrong"):
        Estimator(DB).run(with_channels(log, Wf=log.channels["Wf"] * 1.3))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        Estimator(DB).run(with_channels(log, P50=log.channels["P15"], P15=log.channels["P50"]))
    said = " ".join(str(w.message) for w in got)
    assert "Estimated again without them" in said and "at once" not in said


@pytest.mark.parametrize("factor,unit,says", [(1 / 0.3048, "ft", "feet read as metres"),
                                              (1e-3, "km", "kilometres read as metres"),
                                              (1.0, None, None)])
def test_an_altitude_in_the_wrong_unit_is_named_as_such(factor, unit, says):
    """An altitude logged in feet (or km) but declared in metres is plausible on most samples and
    disagrees with the inlet pressure; the warning said 'a wrong, frozen or missing altitude or
    Mach?' and not which. Now it gives the scale of the logged altitude against the pressure
    altitude P2 and Mach give (pwl.airdata.altitude_slip; reference: the plant model's ISA) and the
    unit to declare; a correct altitude, or one merely frozen, gets no such guess."""
    from pwl.airdata import altitude_slip, pressure_altitude
    for h in (0.0, 3000.0, 10999.0, 13000.0):
        assert pressure_altitude(isa(h, 0.0)[1]) == pytest.approx(h, abs=0.01)      # 1e-6 in pressure
    log = degraded()
    alt = log.channels["alt"] * factor
    if unit is None:
        k = slice(int(150 / 0.015), int(270 / 0.015))
        alt[k] = alt[k.start]                       # frozen in the climb: disagrees, no unit slip
    with pytest.warns(PwlWarning, match=r"disagree on") as got:
        Estimator(DB).run(with_channels(log, alt=alt))
    text = " ".join(str(w.message) for w in got if "disagree on" in str(w.message))
    if unit:
        assert says in text and f"'alt[{unit}]'" in text, text
    else:
        assert "times the pressure altitude" not in text and "a wrong, frozen or missing altitude" in text
    assert altitude_slip(log.channels["alt"], log.channels["Mach"], log.channels["P2"]) == ("", "")
