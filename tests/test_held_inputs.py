"""Inputs that may legitimately hold a value while the engine moves (``Estimator(may_hold=...)``,
``pwl run --may-hold``): variable geometry at a mechanical stop, a closed bleed valve. Left to
the frozen-input test they were taken for a frozen word: samples without measurement update,
health held, a misleading warning, and ``stuck_after=inf`` -- which also turns off the stuck
SENSOR test -- the only way out. And a sensor logged but NaN on every sample, which ran without
it silently where an absent one is named."""
import os
import warnings

import h5py
import numpy as np
import pytest

from pwl.cli import main
from pwl.demo_data import demo_paths
from pwl.errors import EXIT_INPUT, PwlWarning, UsageError
from pwl.estimator import Estimator
from pwl.logs import Log, read_log, write_log
from pwl.runtime import FLAG_HELD_INPUT, FLAG_NO_UPDATE, FLAG_STUCK

DB, LOGS = demo_paths()
DT = 0.015                      # the demo database's
HOLD = (200.0, 230.0)           # s: the clean demo flight climbs from 1,900 to 2,800 m here


def with_channels(log: Log, **chans) -> Log:
    return Log(log.time, log.channels | chans, log.units, log.truth, log.truth_units, dict(log.attrs), log.path)


def wf_held(log: Log) -> tuple[Log, np.ndarray]:
    """The log with its fuel flow (the demo turbofan's one input) exactly constant through
    :data:`HOLD`, and the (n,) mask of those samples."""
    k = (log.time >= HOLD[0]) & (log.time < HOLD[1])
    wf = log.channels["Wf"].copy()
    wf[k] = wf[np.flatnonzero(k)[0]]
    return with_channels(log, Wf=wf), k


def run(log: Log, **options):
    """(result, estimator, PwlWarning texts) of a whole-log run."""
    est = Estimator(DB, **options)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always", PwlWarning)
        res = est.run(log)
    return res, est, [str(w.message) for w in got if issubclass(w.category, PwlWarning)]


def assert_same_run(a, b):
    np.testing.assert_array_equal(a.flags, b.flags)
    for o in a.outputs:
        np.testing.assert_array_equal(a.outputs[o], b.outputs[o], err_msg=o)


# ---- bug 1: an input that may hold ------------------------------------------------------------
def test_an_input_that_may_hold_is_not_taken_for_a_frozen_word():
    """Fuel flow held exactly for 30 s of the climb: by default flagged held on exactly those
    samples (no update there) and named with the option that says it may hold; with
    ``may_hold=("Wf",)`` not flagged, no warning, and the run equals one with the frozen-input
    test off the only old way (``stuck_after=inf``: the same here, where no sensor is stuck),
    bit for bit; the provenance records the option."""
    log, k = wf_held(read_log(LOGS[0]))
    alt = log.channels["alt"][k]
    assert np.ptp(alt) > 0.05 * 15500           # altitude moves 5 % of its plausible span
    res, _, said = run(log)
    np.testing.assert_array_equal((res.flags & FLAG_HELD_INPUT) != 0, k)
    assert ((res.flags[k] & FLAG_NO_UPDATE) != 0).all()
    assert len(said) == 1 and "input 'Wf' held" in said[0]
    assert "Estimator(may_hold=('Wf',)), pwl run --may-hold Wf" in said[0]
    assert "may_hold" not in res.attrs["provenance"]["mode"]

    res, est, said = run(log, may_hold=("Wf",))
    assert said == [] and res.counts()["held_input"] == 0 and res.counts()["no_update"] == 0
    assert est.may_hold == ("Wf",) and res.attrs["provenance"]["mode"] == "steady+may_hold:Wf"
    off, _, _ = run(log, stuck_after=float("inf"))
    assert not (off.flags & FLAG_STUCK).any()
    assert_same_run(res, off)


def test_a_stuck_sensor_is_still_flagged_with_an_input_that_may_hold():
    """``may_hold`` leaves the stuck-sensor test as it is (``stuck_after=inf`` turned both off):
    T48 frozen from 240 to 400 s is flagged stuck from the sample at which it has repeated for
    2 s (the default stuck_after) to the end of the freeze, and nowhere else."""
    log, _ = wf_held(read_log(LOGS[0]))
    f = (log.time >= 240.0) & (log.time < 400.0)
    first, last = np.flatnonzero(f)[[0, -1]]
    t48 = log.channels["T48"].copy()
    t48[f] = t48[first]
    log = with_channels(log, T48=t48)
    expect = np.zeros(len(log), dtype=bool)
    expect[first + int(np.ceil(2.0 / DT)):last + 1] = True
    res, _, _ = run(log, may_hold=("Wf",))
    np.testing.assert_array_equal((res.flags & FLAG_STUCK) != 0, expect)
    assert res.counts()["held_input"] == 0
    off, _, _ = run(log, stuck_after=float("inf"))
    assert off.counts()["stuck"] == 0


def test_a_stream_lets_an_input_that_may_hold_hold():
    """The Stream's frozen-input test reads the same option: by default it flags the held fuel
    flow once altitude has moved; with ``may_hold`` it flags none and its flags and health equal
    a stream with the test off (``stuck_after=inf``), step for step."""
    from pwl.streaming import Stream
    log, k = wf_held(read_log(LOGS[0]))
    part = (log.time >= 150.0) & (log.time < 300.0)

    def stream(**options):
        s = Stream(Estimator(DB, **options))
        rows = np.column_stack([log.channels[c][part] for c in s.channels])
        flags, h = np.empty(len(rows), dtype=np.int64), np.empty((len(rows), len(s.h_hat)))
        for i, r in enumerate(rows):
            flags[i] = s.step(r)
            h[i] = s.h_hat
        return flags, h

    # causal: from the sample at which Wf has repeated for 2 s (stuck_after) on, once alt, Mach or
    # Nf has moved more than 5 % of its plausible span since the hold began
    first = np.flatnonzero(k)[0]
    since = np.arange(len(log)) - first + 1
    ranges = Estimator(DB).ranges
    moved = np.zeros(len(log), dtype=bool)
    for c in ("alt", "Mach", "Nf"):
        x = np.where(k, log.channels[c], np.nan)
        moved |= np.fmax.accumulate(x) - np.fmin.accumulate(x) > 0.05 * (ranges[c][1] - ranges[c][0])
    expect = k & (since >= np.ceil(2.0 / DT)) & moved
    flags, _ = stream()
    assert expect[part].sum() > 500
    np.testing.assert_array_equal((flags & FLAG_HELD_INPUT) != 0, expect[part])
    flags, h = stream(may_hold=("Wf",))
    flags_off, h_off = stream(stuck_after=float("inf"))
    assert not (flags & FLAG_HELD_INPUT).any() and not (flags_off & FLAG_STUCK).any()
    np.testing.assert_array_equal(flags, flags_off)
    np.testing.assert_array_equal(h, h_off)


@pytest.mark.parametrize("name", ["Nf", "wf", "A8"])
def test_may_hold_names_only_inputs(name):
    """A sensor (Nf), a name in the wrong case or another plant's input: a UsageError naming it
    and the database's inputs."""
    with pytest.raises(UsageError, match=rf"may_hold '{name}': not an input of .*turbofan_demo.h5 \(its inputs: Wf\)"):
        Estimator(DB, may_hold=(name,))


def test_pwl_run_may_hold(tmp_path, capsys):
    """``pwl run --may-hold Wf``: the held fuel flow neither flagged nor warned of, the option in
    the results' provenance; without it the warning names the option; an unknown name is refused
    (exit 2) naming the inputs, before anything is written."""
    log, _ = wf_held(read_log(LOGS[0]))
    cut = log.time < 300.0
    path = str(tmp_path / "climb.h5")
    write_log(path, Log(log.time[cut], {c: v[cut] for c, v in log.channels.items()}, log.units))
    assert main(["run", DB, path, "-o", str(tmp_path / "a"), "-j", "1"]) == 0
    assert "pwl run --may-hold Wf" in capsys.readouterr().err
    assert main(["run", DB, path, "-o", str(tmp_path / "b"), "-j", "1", "--may-hold", "Wf"]) == 0
    assert "held" not in capsys.readouterr().err
    with h5py.File(tmp_path / "b" / "climb.estimates.h5", "r") as f:
        assert f.attrs["mode"] == "steady+may_hold:Wf"
        assert not (f["flags"][()] & FLAG_HELD_INPUT).any()
    assert main(["run", DB, path, "-o", str(tmp_path / "c"), "--may-hold", "Wf,EGT"]) == EXIT_INPUT
    assert "may_hold 'EGT': not an input" in capsys.readouterr().err and not os.path.exists(tmp_path / "c")


# ---- bug 2: a sensor NaN on every sample ------------------------------------------------------
def test_a_sensor_nan_on_every_sample_is_named_like_an_absent_one():
    """T48 logged but NaN throughout ran silently; it is now named once, and the run equals the
    one of the log without the T48 column (which names it as absent), bit for bit."""
    log = read_log(LOGS[1])
    dead, _, said = run(with_channels(log, T48=np.full(len(log), np.nan)))
    assert said == [f"{log.path}: sensor 'T48' NaN on all {len(log)} samples (dead for the whole log?): run "
                    "without that sensor (missing on every sample)"]
    absent, _, said = run(Log(log.time, {c: v for c, v in log.channels.items() if c != "T48"}, log.units,
                              path=log.path))
    assert len(said) == 1 and "no 'T48' channel" in said[0]
    assert_same_run(dead, absent)


def test_a_dead_sensor_is_named_in_a_chunked_run_and_a_live_one_is_not(tmp_path):
    """``run_file`` (what ``pwl run`` calls) reads an HDF5 log a chunk at a time: P50 NaN on every
    sample is named; T48 NaN on all but the last sample (in the last chunk) is not."""
    log = read_log(LOGS[1])
    t48 = np.full(len(log), np.nan)
    t48[-1] = log.channels["T48"][-1]
    path = str(tmp_path / "dead.h5")
    write_log(path, with_channels(log, P50=np.full(len(log), np.nan), T48=t48))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always", PwlWarning)
        Estimator(DB).run_file(path, str(tmp_path / "dead.estimates.h5"), chunk=10000)
    said = [str(w.message) for w in got if issubclass(w.category, PwlWarning)]
    assert said == [f"{path}: sensor 'P50' NaN on all {len(log)} samples (dead for the whole log?): run "
                    "without that sensor (missing on every sample)"]
