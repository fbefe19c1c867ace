"""Channels a flight data recorder samples at a lower rate (1-8 Hz) than its export's rows (66.7
Hz) and writes with sample-and-hold: each value repeated on the rows until the next sample. They
are found by the regular rows where their value changes (:func:`pwl.estimator.held_channels`, the
same test that finds channels logged with empty rows between their samples), named in the
provenance (``low_rate_channels``) and used as those are: each row takes the value between the
samples around it (:func:`pwl.estimator.interpolate_held`), not the last sample's, up to a period
stale. Used as logged, the stale Ps30 of the take-off misfit and was left out of the update, and
in a probe fleet out of 19 of 48 logs altogether (health held all flight, a false recovery and a
missed HPT loss in the fleet diagnosis)."""
import json
import warnings

import h5py
import numpy as np
import pytest

from pwl import estimator as E
from pwl.demo_data import demo_paths
from pwl.estimator import Estimator
from pwl.logs import Log, read_log, write_log

DB, LOGS = demo_paths()
DT = 0.015                     # the demo database's and flights' row interval, s
HZ1 = 1.0 / DT                 # rows per sample at 1 Hz: 66.7, not an integer
MAX_ROWS = 67                  # the longest period: LOW_RATE_GAP (1 s) on the 15 ms grid
HELD = ("P15", "T24", "T48", "Ps30")


def sample_rows(n: int, period: float, phase: float = 0.0) -> np.ndarray:
    """The rows a recorder samples at ``period`` rows (rounded to the grid), from row 0."""
    s = np.round(phase + np.arange(-1, n / period + 1) * period).astype(int)
    return np.unique(np.concatenate([[0], s[(s >= 0) & (s < n)]]))


def hold(x: np.ndarray, period: float, phase: float = 0.0) -> np.ndarray:
    """``x`` sampled every ``period`` rows and written with sample-and-hold."""
    s = sample_rows(len(x), period, phase)
    return x[s[np.searchsorted(s, np.arange(len(x)), side="right") - 1]]


def signal(n: int, seed: int = 1) -> np.ndarray:
    """A sensor at full rate: a slow swing and noise (no value repeats)."""
    rng = np.random.default_rng(seed)
    return 800.0 + 50.0 * np.sin(np.arange(n) / 3000.0) + rng.normal(0.0, 0.5, n)


def with_held(log: Log, channels=HELD, period: float = HZ1, phase: float = 0.0) -> Log:
    return Log(log.time, log.channels | {c: hold(log.channels[c], period, phase) for c in channels}, log.units,
               log.truth, log.truth_units, dict(log.attrs), log.path)


# ---- which channels are held -------------------------------------------------------------------
@pytest.mark.parametrize("period, phase", [(64.0, 0.0), (64.0, 37.0), (HZ1, 0.0), (HZ1, 40.0), (HZ1 / 2, 5.0),
                                           (HZ1 / 8, 3.0), (2.0, 1.0)],
                         ids=["64 rows", "64 rows, phase 37", "1 Hz", "1 Hz, phase 40", "2 Hz", "8 Hz", "2 rows"])
def test_a_channel_written_with_sample_and_hold_is_found_with_its_period(period, phase):
    """Every 64 rows (the probe fleet's), and at rates that do not divide the rows' (1 Hz on
    66.7 Hz: changes after 66 or 67 rows): the period to a hundredth of a row."""
    x = hold(signal(20000), period, phase)
    assert E.held_period(x, MAX_ROWS) == pytest.approx(period, abs=0.01)
    found = E.held_channels(np.column_stack([signal(20000, 2), x]), MAX_ROWS)
    assert list(found) == [1] and found[1][0] == pytest.approx(period, abs=0.01) and found[1][1] == 0


def test_a_held_channel_whose_samples_repeat_a_value_is_found():
    """Quantised to its noise: a third of its samples repeat the one before (a change skipped)."""
    x = np.round(signal(30000) / 1.0)
    held = hold(x, HZ1, 11.0)
    d = np.diff(np.flatnonzero(np.diff(held)))
    assert np.mean(d > 70) > 0.2                                  # many gaps of 2-4 periods
    assert E.held_period(held, MAX_ROWS) == pytest.approx(HZ1, abs=0.01)


def jittered_rows(n: int, period: float, jitter: int, walk: bool, seed: int = 3) -> np.ndarray:
    """The rows a recorder sampling asynchronously writes its samples on: each within ``jitter``
    rows of a lattice of ``period`` (``walk``: each gap ``period`` +- ``jitter`` rows apart)."""
    rng = np.random.default_rng(seed)
    k = int(n / period) + 2
    if walk:
        s = np.round(np.cumsum(period + rng.integers(-jitter, jitter + 1, k)) - period)
    else:
        s = np.round(np.arange(k) * period + rng.integers(-jitter, jitter + 1, k))
    s = s.astype(int)
    return np.unique(np.concatenate([[0], s[(s >= 0) & (s < n)]]))


def hold_at(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    return x[s[np.searchsorted(s, np.arange(len(x)), side="right") - 1]]


@pytest.mark.parametrize("walk", [False, True], ids=["about a lattice", "gaps jittered"])
def test_a_channel_held_with_jittered_samples_is_found_with_its_period(walk):
    """A bus sampled asynchronously: 1 Hz words 5 rows early or late (gaps of 57-77 rows, off
    any lattice by more than its 0.6 rows), found as held, its period the mean gap within 1 %."""
    x = hold_at(signal(20000), jittered_rows(20000, HZ1, 5, walk))
    assert E.held_period(x, MAX_ROWS) == pytest.approx(HZ1, rel=0.01)


def channels_not_held(n=20000):
    rng = np.random.default_rng(4)
    rows = np.arange(n)
    clean = signal(n)
    quantised = np.round((clean - 800.0) / 2.0) * 2.0           # 4 noise sigmas: long, irregular runs
    stuck = clean.copy()
    stuck[5000:17000] = stuck[5000]                               # frozen for 180 s: one long run
    stop = np.clip(2.0 + np.sin(rows / 900.0) + rng.normal(0, 0.01, n), 1.5, None)   # an input at its stop
    switches = np.cumsum(np.isin(rows, rng.choice(n, 300, replace=False)) * rng.normal(size=n))  # a lever
    few = hold(signal(n), 64.0)[: 19 * 64 + 10]                  # held, but 19 changes
    slow = hold(clean, 100.0)                                     # held, slower than 1 s
    return {"clean": clean, "quantised at rest": quantised, "stuck": stuck, "input at its stop": stop,
            "constant": np.full(n, 3.5), "moved at random rows": switches, "too few changes": few,
            "slower than 1 s": slow}


@pytest.mark.parametrize("name", list(channels_not_held()))
def test_channels_that_repeat_values_otherwise_are_not_taken_for_held(name):
    x = channels_not_held()[name]
    assert np.count_nonzero(np.diff(x) == 0) > 0 or name == "clean"
    assert E.held_period(x, MAX_ROWS) == 0.0
    assert E.held_channels([x], MAX_ROWS) == {}


def test_a_channel_logged_with_empty_rows_is_held_the_same_way():
    """One definition: samples at a regular period, logged with empty rows between them or each
    repeated until the next; at 1 Hz on the 66.7 Hz grid (steps of 66 or 67 rows, more than the
    66 rows that 1 s made before) both are found with the same period."""
    x = signal(20000)
    s = sample_rows(len(x), HZ1, 40.0)
    empty = np.full(len(x), np.nan)
    empty[s] = x[s]
    found = E.held_channels([empty, hold(x, HZ1, 40.0)], MAX_ROWS)
    assert found[0][1] == 67 and found[1][1] == 0                 # median step of the empty one
    assert found[0][0] == pytest.approx(HZ1, abs=0.01) and found[1][0] == pytest.approx(HZ1, abs=0.01)


def test_no_channel_of_the_demo_flights_is_taken_for_held():
    """Clean logs: nothing found, so nothing changes (their results are bit for bit as before)."""
    est = Estimator(DB)
    for path in LOGS:
        log = read_log(path)
        assert est._find_held(log) == {}
        assert json.loads(est.run(log).attrs["provenance"]["low_rate_channels"]) == {}


# ---- how a held channel is used ----------------------------------------------------------------
def test_held_values_are_interpolated_between_their_samples():
    """A ramp held every 8 rows reads as the ramp again (up to its last sample); a sample that
    repeats the one before makes the ramp to the next span its last period only; empty and spike
    rows stay as they are and give no value."""
    n = 400
    ramp = 3.0 + 0.25 * np.arange(n)
    a = np.column_stack([hold(ramp, 8.0), hold(ramp, 8.0)])
    last = sample_rows(n, 8.0)[-1]
    a[100:120, 1] = np.nan
    a[200:208, 1] = E._SPIKE
    E.interpolate_held(a, {0: 8.0, 1: 8.0})
    np.testing.assert_allclose(a[:last + 1, 0], ramp[:last + 1], rtol=0, atol=1e-12)
    assert np.all(a[last:, 0] == ramp[last])
    assert np.isnan(a[100:120, 1]).all() and np.all(a[200:208, 1] == E._SPIKE)
    ok = np.ones(n, bool)
    ok[96:128] = ok[192:216] = False                  # around the gap and the spike
    np.testing.assert_allclose(a[:last + 1, 1][ok[:last + 1]], ramp[:last + 1][ok[:last + 1]], atol=1e-12)

    steps = np.repeat([0.0, 0.0, 0.0, 8.0], 8)        # samples 0, 0, 0, 8 every 8 rows
    b = steps[:, None].copy()
    E.interpolate_held(b, {0: 8.0})
    np.testing.assert_array_equal(b[:17, 0], 0.0)
    np.testing.assert_allclose(b[16:25, 0], np.arange(9.0))


def test_held_values_are_left_out_where_their_samples_bend_more_than_the_tolerance():
    """A ramp of 2 per row (16 per 8-row period) that slows to 0.01 at row 200 (a throttle chop), held
    every 8 rows: the line between samples is exact on the ramp and the flat, off by up to 8 over
    the corner. With a tolerance of 0.5 % of the value (about 2 there: a quarter of the corner's
    second difference of 16 exceeds it) the rows between the samples of the two gaps next to the
    corner sample are NaN, every other row the ramp again; with 10 % nothing is left out."""
    n = 400
    r = np.arange(n)
    truth = 3.0 + 2.0 * np.minimum(r, 200) + 0.01 * np.maximum(r - 200, 0)
    a = np.column_stack([hold(truth, 8.0), hold(truth, 8.0)])
    E.interpolate_held(a, {0: 8.0, 1: 8.0}, {0: 0.005, 1: 0.1})
    gone = np.isnan(a[:, 0])
    np.testing.assert_array_equal(np.flatnonzero(gone), [*range(193, 200), *range(201, 208)])  # samples 192, 200, 208 kept
    last = sample_rows(n, 8.0)[-1]
    np.testing.assert_allclose(a[:last + 1, 0][~gone[:last + 1]], truth[:last + 1][~gone[:last + 1]], atol=1e-12)
    assert not np.isnan(a[:, 1]).any()


@pytest.fixture(scope="module")
def held_run():
    """The clean demo flight with P15, T24, T48 and Ps30 sampled at 1 Hz and held (rows 40, 107,
    173, ...): (held log, its run and estimator, the complete log's run)."""
    log = read_log(LOGS[0])
    held = with_held(log, phase=40.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = Estimator(DB)
        res = est.run(held)
        ref = Estimator(DB).run(log)
    return held, res, est, ref


def fn_rms(res, log) -> float:
    """Fn's RMS error against the simulation's truth after the first 120 s, percent."""
    k = log.time > 120.0
    return float(100 * np.sqrt(np.mean((res.channel("z_hat", "Fn")[k] / log.truth["Fn"][k] - 1) ** 2)))


def test_sensors_held_at_1_hz_are_not_left_out_for_misfit(held_run):
    """Held as logged, Ps30 misfit in the take-off (the value up to a second stale) on 3,858
    samples, and was left out of the update there (at 66.67 rows instead of 1 / 0.015: for the
    whole log, health held all flight); Fn 3.5 % RMS. Interpolated: no sensor misfits, Fn 0.67 %
    RMS (bound 1.0 %; the complete log 0.235 %), the snapshots' health within 0.29 pt of the
    complete log's (bound 0.4 pt) and their thrust within 0.07 % (bound 0.1 %); the four sensors
    named with their period (1.0 s)."""
    held, res, est, ref = held_run
    assert est.failed == [] and all(est.misfit[c] == 0 for c in est.misfit)
    assert json.loads(res.attrs["provenance"]["low_rate_channels"]) == {c: 1.0 for c in HELD}
    assert fn_rms(res, held) < 1.0
    assert len(res.snapshots) == len(ref.snapshots) == 3
    h, h0 = res.snapshots.outputs["h_hat"], ref.snapshots.outputs["h_hat"]
    assert np.abs(h - h0).max() < 4e-3
    fn, fn0 = res.snapshots.outputs["z_hat"][:, 0], ref.snapshots.outputs["z_hat"][:, 0]
    assert np.abs(fn / fn0 - 1).max() < 1e-3


def test_one_sensor_held_at_1_hz_is_not_left_out_for_misfit():
    """Ps30 alone on the degraded demo flight: as logged it misfit on 1,669 samples (Fn 0.285 %
    RMS); interpolated on none, Fn 0.244 % RMS (bound 0.26 %; complete log 0.233 %), snapshot
    health within 0.06 pt (bound 0.1 pt)."""
    log = read_log(LOGS[1])
    held = with_held(log, ("Ps30",))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = Estimator(DB)
        res, ref = est.run(held), Estimator(DB).run(log)
    assert est.misfit["Ps30"] == 0 and est.failed == []
    assert fn_rms(res, held) < 0.26
    assert np.abs(res.snapshots.outputs["h_hat"] - ref.snapshots.outputs["h_hat"]).max() < 1e-3


def test_sensors_held_with_jittered_samples_are_not_left_out_for_misfit():
    """The four sensors held at 1 Hz, each gap between their samples 66.7 +- 5 rows (a bus read
    asynchronously): before, not found as held (off any lattice by more than 0.6 rows), Ps30
    misfit and failed for the log (T48 misfit on 106 samples, P15 on 73), the snapshots' health
    NaN (the flight lost to the fleet diagnosis); found, each named with its period (1.0 s to
    0.5 %), no misfit, Fn 0.71 % RMS (bound 1.0 %, as on a regular lattice), the snapshots'
    health within 0.36 pt of the complete log's (bound 0.4 pt, as there)."""
    log = read_log(LOGS[0])
    rng_rows = {c: jittered_rows(len(log), HZ1, 5, True, seed) for seed, c in enumerate(HELD)}
    held = Log(log.time, log.channels | {c: hold_at(log.channels[c], r) for c, r in rng_rows.items()}, log.units,
               log.truth, log.truth_units, dict(log.attrs), log.path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = Estimator(DB)
        res = est.run(held)
    assert est.failed == [] and all(est.misfit[c] == 0 for c in est.misfit)
    periods = json.loads(res.attrs["provenance"]["low_rate_channels"])
    assert set(periods) == set(HELD) and all(abs(v - 1.0) < 5e-3 for v in periods.values())
    assert fn_rms(res, held) < 1.0
    ref = Estimator(DB).run(log)
    assert len(res.snapshots) == len(ref.snapshots) == 3
    assert np.abs(res.snapshots.outputs["h_hat"] - ref.snapshots.outputs["h_hat"]).max() < 4e-3


def test_a_chunked_run_of_a_held_log_equals_a_whole_run(held_run, tmp_path):
    """run_file reads the held channels' samples beyond each chunk's edges and finds them on the
    log's first rows, as a whole run does: equal bit for bit, chunks of 1000 rows (15 periods)."""
    held, res, est, ref = held_run
    write_log(tmp_path / "held.h5", held)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = Estimator(DB).run(read_log(tmp_path / "held.h5"))
        Estimator(DB).run_file(tmp_path / "held.h5", tmp_path / "held.estimates.h5", chunk=1000)
    with h5py.File(tmp_path / "held.estimates.h5") as f:
        np.testing.assert_array_equal(f["flags"][()], whole.flags)
        for o in ("q_hat", "h_hat", "z_hat", "y_hat"):
            np.testing.assert_array_equal(f[o][()], whole.outputs[o], err_msg=o)
        assert json.loads(f.attrs["low_rate_channels"]) == {c: 1.0 for c in HELD}


def test_a_sensor_logged_with_empty_rows_reads_as_the_same_sensor_held():
    """The kernel's arrays of a log whose four sensors come every 66 or 67 rows with empty rows
    between equal those of the same log written with sample-and-hold."""
    log = read_log(LOGS[0])
    n = len(log)
    s = sample_rows(n, HZ1, 40.0)
    empty = {}
    for c in HELD:
        empty[c] = np.full(n, np.nan)
        empty[c][s] = log.channels[c][s]
    gaps = Log(log.time, log.channels | empty, log.units, attrs=dict(log.attrs), path=log.path)
    est = Estimator(DB)
    a, b = est._split(gaps), est._split(with_held(log, phase=40.0))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
