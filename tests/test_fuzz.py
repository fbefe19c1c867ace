"""Seeded mutation test (#14): damaged databases and logs end in a named error, an equal result or
a flag; never a traceback or silently different estimates (pwl.bench.fuzz; benchmarks/fuzz.py runs
10,000 + 1,000 mutants with a hang watchdog)."""
import collections

import numpy as np
import pytest

from pwl.bench import fuzz
from pwl.database import GainDatabase
from pwl.demo_data import demo_paths
from pwl.estimator import Estimator
from pwl.logs import Log, read_log


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    db_path, logs = demo_paths()
    GainDatabase.open(db_path).save(tmp / "clean.h5")          # sealed, whatever the shipped one is
    full = read_log(logs[0])
    m = 1500
    log = Log(full.time[:m], {k: v[:m] for k, v in full.channels.items()}, full.units,
              attrs={"dt": full.attrs.get("dt")})
    est = Estimator(tmp / "clean.h5")
    return tmp, est, log, est.run(log)


def test_database_mutants(clean):
    tmp, est, log, ref = clean
    data = (tmp / "clean.h5").read_bytes()
    rng = np.random.default_rng(2026)
    seen = collections.Counter()
    for i in range(3 * len(fuzz.DB_KINDS)):
        kind = fuzz.DB_KINDS[i % len(fuzz.DB_KINDS)]
        p = tmp / f"db_{i}.h5"
        fuzz.mutate_database(data, p, kind, rng)
        out, detail = fuzz.outcome(lambda: Estimator(p).run(log), ref)
        assert out not in fuzz.FAILURES, f"{kind} mutant {i}: {out}: {detail}"
        seen[out] += 1
    assert seen["named"] >= 2 * len(fuzz.DB_KINDS)      # most damage is caught by name


def test_log_mutants(clean):
    tmp, est, log, ref = clean
    units = {c: est.channel_units.get(c, "") for c in est.input_channels}
    rng = np.random.default_rng(2027)
    seen = collections.Counter()
    for i in range(3 * len(fuzz.LOG_KINDS)):
        kind = fuzz.LOG_KINDS[i % len(fuzz.LOG_KINDS)]
        folder = tmp / f"log_{i}"
        folder.mkdir()
        path = fuzz.mutate_log(log, folder, kind, rng, units)
        out, detail = fuzz.outcome(lambda: est.run(path), ref)
        assert out not in fuzz.FAILURES, f"{kind} mutant {i}: {out}: {detail}"
        seen[out] += 1
    assert seen["named"] > 0 and seen["flagged"] > 0


def test_the_outcome_classifier_can_fail(clean):
    # the oracle itself: a different result with the same flags is "silent", an exception that is
    # not pwl's is a "traceback"
    tmp, est, log, ref = clean
    shifted = Log(log.time, dict(log.channels, T48=log.channels["T48"] * 1.001), log.units)
    assert fuzz.outcome(lambda: est.run(shifted), ref)[0] == "silent"
    assert fuzz.outcome(lambda: {}["x"], ref)[0] == "traceback"
    assert fuzz.outcome(lambda: est.run(log), ref)[0] == "equal"
