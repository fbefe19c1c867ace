"""Fleet diagnostics end to end on the nonlinear turbofan: the four field scenarios of issue #13
(each must come out with the right class and sign), the one-engine trend view, and a tiny fleet
through the command line (simulate -> run -> diagnose -> score, the score checked against a hand
count of the CSVs).

The scenario fleet: 6 engines x 10 flights of :mod:`models.fleet` (scatter, wear, varied
ambient and profile, sensor noise), faults from flight 5 on:

- ESN001 hpc_eff -3 % step (efficiency only);
- ESN002 hpt_eff -2 % together with lpt_flow +1.5 % (a combination no single class has);
- ESN003 fan_eff drifting linearly to -2 % at flight 9;
- ESN004 T48 reading +15 K;
- ESN005, ESN006 no fault.
"""
import copy
import csv
import json
import math
import os

import numpy as np
import pytest

from models import fleet
from models.turbofan import H_NAMES, Turbofan
from pwl.cli import main
from pwl.database import GainDatabase
from pwl.fleet.diagnose import diagnose_fleet, prepare, read_flight
from pwl.estimator import Estimator
from pwl.logs import Log, write_log
from pwl.fleet.trending import engine_trend, health_summary, line

DB = os.path.join(os.path.dirname(__file__), "..", "data", "turbofan_demo.h5")
ONSET, FLIGHTS = 5, 10



def latest_detected(path) -> list:
    """The engines of a diagnosis CSV whose latest flight's row is detected (the exit status of
    ``pwl fleet diagnose`` is 1 when there is one)."""
    last = {}
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            last[r["engine"]] = r
    return [e for e, r in last.items() if r["detected"] == "1"]

def scenario_plan():
    p = fleet.plan_fleet(6, FLIGHTS, seed=0, fault_fraction=0.0)
    p.fault_class[0], p.onset[0], p.eff[0], p.flow[0], p.magnitude[0] = "hpc", ONSET, -0.03, 0.0, -0.03
    p.rate[2, H_NAMES.index("fan_eff")] = -0.02 / (FLIGHTS - 1)
    p.h0[2, H_NAMES.index("fan_eff")] = 0.0
    y_ref, sig = fleet.reference_outputs(), Turbofan().sensor_noise
    p.fault_class[3], p.onset[3], p.bias[3] = "sensor:T48", ONSET, 15.0
    p.magnitude[3] = 15.0 / (sig["T48"] * y_ref["T48"])
    return p


def combined_health(p, j):
    h = fleet.health_at(p, 1, j)
    if j >= ONSET:
        h[H_NAMES.index("hpt_eff")] -= 0.02
        h[H_NAMES.index("lpt_flow")] += 0.015
    return h


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenario")
    p = scenario_plan()
    est = Estimator(DB)
    records = []
    for i in range(p.engines):
        for j in range(p.flights):
            r = fleet.simulate_flight(p, i, j, health=combined_health(p, j) if i == 1 else None)
            log = os.path.join(root, "logs", p.serial[i], f"flight_{j:03d}.h5")
            os.makedirs(os.path.dirname(log), exist_ok=True)
            write_log(log, Log(r["time"], r["channels"], r["units"], r["truth"], r["truth_units"],
                               r["attrs"]), compact=True)
            out = os.path.join(root, "results", p.serial[i], f"flight_{j:03d}.estimates.h5")
            os.makedirs(os.path.dirname(out), exist_ok=True)
            est.run_file(log, out)
            records.append(read_flight(out))
    rows, Sigma, channels, centers, _ = diagnose_fleet(records, GainDatabase.open(DB))
    by = {}
    for r in rows:
        by.setdefault(r.engine, []).append(r)
    return {"root": root, "plan": p, "rows": by, "records": records}


def values(dec):
    """The fitted parameters of a decision: {column: value} from its detail."""
    return {k: float(v) for k, v in (kv.split("=") for kv in dec.detail.split())}


def test_no_false_alarm_before_the_onset_and_on_healthy_engines(scenario):
    rows = scenario["rows"]
    for e in ("ESN005", "ESN006"):
        assert [r.detected for r in rows[e]] == [0] * FLIGHTS, e
    for e in ("ESN001", "ESN002", "ESN004"):
        assert [r.detected for r in rows[e][:ONSET]] == [0] * ONSET, e
    # flight numbers come from the logs' flight_index
    assert [r.flight for r in rows["ESN001"]] == list(range(FLIGHTS))


def test_hpc_step_is_isolated_sized_and_stays_flagged(scenario):
    after = scenario["rows"]["ESN001"][ONSET:]
    for d in after:                               # every flight from the onset on, not only once
        assert d.detected and d.cls == "hpc" and d.kind == "step" and d.onset == ONSET, d
    d = after[-1]
    # truth: -3 % plus the engine's own wear since the baseline (< 0.1 %)
    assert d.magnitude == pytest.approx(-0.03, abs=0.003)
    assert 0 < d.magnitude_std < 0.003
    assert abs(values(d)["hpc_flow"]) < 0.004     # an efficiency-only fault: no flow change


def test_hpt_loss_with_lpt_flow_gain_is_a_two_component_fault_with_the_right_signs(scenario):
    d = scenario["rows"]["ESN002"][-1]
    assert d.detected and d.cls == "hpt+lpt" and d.onset == ONSET, d
    v = values(d)
    assert v["hpt_eff"] == pytest.approx(-0.02, abs=0.005)
    assert v["lpt_flow"] == pytest.approx(0.015, abs=0.005)
    assert abs(v["hpt_flow"]) < 0.005 and abs(v["lpt_eff"]) < 0.005


def test_fan_drift_is_reported_as_a_drift_with_its_rate(scenario):
    rows = scenario["rows"]["ESN003"]
    d = rows[-1]
    assert d.detected and d.cls == "fan" and d.kind == "drift", d
    # truth: -2 % / 9 flights = -0.222 %/flight (plus a little wear)
    assert d.magnitude == pytest.approx(-0.02 / 9, abs=0.0006)
    assert not any(r.detected for r in rows[:3])   # three flights in, the drift is below 0.5 %


def test_t48_bias_is_a_sensor_fault_not_a_component_fault(scenario):
    rows = scenario["rows"]["ESN004"]
    for d in rows[ONSET:]:
        assert d.detected and d.cls == "sensor:T48", d
        assert d.bias == pytest.approx(15.0, abs=3.0)
    assert not any(r.detected and not r.cls.startswith("sensor:") for r in rows)


def test_trend_of_one_engine_matches_polyfit_and_names_the_drift(scenario, tmp_path, capsys):
    recs = [r for r in scenario["records"] if r.engine == "ESN003"]
    tr = engine_trend(recs[::-1], GainDatabase.open(DB))      # any order in: time order out
    assert tr.labels == [f"flight_{j:03d}" for j in range(FLIGHTS)]
    x = np.arange(FLIGHTS)
    for j in range(len(tr.names)):
        b, a = np.polyfit(x, tr.H[:, j], 1)
        assert tr.slope[j] == pytest.approx(b, rel=1e-8, abs=1e-12)
        assert tr.level[j] == pytest.approx(a + b * (FLIGHTS - 1), rel=1e-8, abs=1e-12)
    assert tr.latest.detected and tr.latest.cls == "fan" and tr.latest.kind == "drift"
    assert "FAULT: fan (drift since flight" in tr.table()
    res = os.path.join(scenario["root"], "results")
    png = tmp_path / "trend.png"
    assert main(["trend", os.path.join(res, "ESN003"), "--plot", str(png)]) == 1   # fault at latest
    out = capsys.readouterr().out
    assert "FAULT: fan" in out and "slope/flight" in out
    pytest.importorskip("matplotlib")
    assert png.stat().st_size > 10_000
    assert main(["trend", os.path.join(res, "ESN005")]) == 0
    assert "no fault detected" in capsys.readouterr().out


def test_health_summary_and_line_against_numpy():
    rng = np.random.default_rng(1)
    t = np.arange(0, 200, 0.5)
    h = rng.normal(0, 1e-3, (t.size, 2)) + [-0.02, 0.01]
    h[t < 30, 0] = 5.0                               # start-up transient
    flags = np.zeros(t.size, int)
    flags[200:210], h[200:210, 1] = 1, 9.0           # a flagged excursion
    s = health_summary(t, h, flags, ["a", "b"], settle=60.0)
    use = (t >= 60) & (flags == 0)
    np.testing.assert_allclose(s.values, np.median(h[use], axis=0), rtol=1e-12)
    q75, q25 = np.percentile(h[use], [75, 25], axis=0)
    np.testing.assert_allclose(s.spread, (q75 - q25) / 1.349, rtol=1e-12)
    assert s.samples == use.sum()
    with pytest.raises(ValueError, match="no settled"):
        health_summary(t[:10], h[:10], flags[:10], ["a", "b"])
    x = np.arange(12.0)
    y = np.column_stack([0.3 - 0.01 * x + rng.normal(0, 0.01, 12), rng.normal(0, 1, 12)])
    a, b, se, sd = line(x, y)
    for j in range(2):
        bb, aa = np.polyfit(x, y[:, j], 1)
        assert (a[j], b[j]) == pytest.approx((aa, bb), rel=1e-10)
        r = y[:, j] - (aa + bb * x)
        s2 = (r @ r) / (12 - 2)
        assert se[j] == pytest.approx(math.sqrt(s2 / ((x - x.mean()) ** 2).sum()), rel=1e-10)


def test_tiny_fleet_simulate_run_diagnose_score(tmp_path, capsys):
    F, R = tmp_path / "F", tmp_path / "R"
    assert main(["fleet", "simulate", "--engines", "6", "--flights", "6", "--seed", "5",
                 "-o", str(F), "-j", "2"]) == 0
    assert main(["run", DB, str(F), "-o", str(R)]) == 0
    for e in ("ESN001", "ESN006"):                  # the engine folders are kept
        assert sorted(os.listdir(R / e)) == [f"flight_{j:03d}.estimates.h5" for j in range(6)]
    diag = tmp_path / "diagnosis.csv"
    rc = main(["fleet", "diagnose", str(R), "-o", str(diag)])
    assert rc == (1 if latest_detected(diag) else 0)         # a fault at an engine's latest flight: a finding
    assert "too few engines for the fleet's normal wear and level (at least 8 with 8" in capsys.readouterr().out
    png = tmp_path / "confusion.png"
    assert main(["fleet", "score", str(diag), str(F / "truth.csv"), "--json", "--plot", str(png)]) == 0
    res = json.loads(capsys.readouterr().out)         # stdout is JSON only, the plot note on stderr
    with open(F / "truth.csv", newline="") as fh:
        truth = {r["engine"]: r for r in csv.DictReader(fh)}
    with open(diag, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 36 and {r["engine"] for r in rows} == set(truth)
    # a hand count of the false and true positives
    fp = n_neg = tp = n_pos = 0
    for r in rows:
        t = truth[r["engine"]]
        faulty = t["class"] != "none" and int(r["flight"]) >= int(t["onset"])
        det = r["detected"] == "1"
        n_pos += faulty
        n_neg += not faulty
        tp += faulty and det
        fp += det and not faulty
    assert res["fpr"] == pytest.approx(fp / n_neg) and res["tpr"] == pytest.approx(tp / n_pos)
    assert fp == 0
    assert n_pos > 0 and tp / n_pos >= 0.5
    # a corrupt results file among the others is named and skipped; the rest is still diagnosed
    (R / "ESN002" / "flight_006.estimates.h5").write_bytes(b"not HDF5")
    assert main(["fleet", "diagnose", str(R), "-o", str(diag)]) == 1
    assert "flight_006.estimates.h5: unreadable results file" in capsys.readouterr().err
    with open(diag, newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 36


def test_engines_named_from_file_names_and_mixed_engines_warned(scenario, tmp_path, capsys):
    """Logs without an engine attribute in one flat folder were diagnosed as one engine, the
    folder. --engine-pattern names each from its file name (the same decisions as from the
    attribute); an engine whose flights repeat flight indices is named in a warning."""
    import dataclasses
    import shutil

    from pwl.fleet.diagnose import DiagnosisError, mixed_engines
    flat = tmp_path / "flat"
    flat.mkdir()
    for r in scenario["records"]:
        if r.engine in ("ESN001", "ESN005"):
            shutil.copy(r.source, flat / f"{r.engine}_{os.path.basename(r.source)}")
    with pytest.raises(DiagnosisError, match=r"the engine pattern 'XYZ\[0-9\]' does not match its name"):
        read_flight(next(flat.iterdir()), r"XYZ[0-9]")
    assert {read_flight(f, r"(ESN\d+)_").engine for f in flat.iterdir()} == {"ESN001", "ESN005"}
    rc = main(["fleet", "diagnose", str(flat), "--engine-pattern", r"(ESN\d+)_", "-o", str(tmp_path / "d.csv")])
    assert rc == (1 if latest_detected(tmp_path / "d.csv") else 0)
    got = {(r["engine"], r["flight"]): (r["detected"], r["class"]) for r in csv.DictReader(open(tmp_path / "d.csv"))}
    for e in ("ESN001", "ESN005"):
        for d in scenario["rows"][e]:
            assert got[(e, str(d.flight))] == (str(d.detected), d.cls)
    assert "repeat" not in capsys.readouterr().err
    one = [dataclasses.replace(r, engine="flat") for r in scenario["records"] if r.engine in ("ESN001", "ESN005")]
    (line,) = mixed_engines(one)
    assert line.startswith(f"engine flat: {FLIGHTS} of its {2 * FLIGHTS} flights repeat another's flight index")


def test_trend_against_its_fleet_equals_the_fleet_diagnosis(scenario, capsys):
    """pwl trend ENGINE --fleet RESULTS judges the engine as pwl fleet diagnose does (the fleet's
    scatter; its wear, with enough engines): every flight's decision equals the fleet's."""
    db = GainDatabase.open(DB)
    for eng in ("ESN001", "ESN004", "ESN005"):
        recs = [r for r in scenario["records"] if r.engine == eng]
        tr = engine_trend(recs, db, fleet=scenario["records"])
        fleet_rows = scenario["rows"][eng]
        assert [(d.detected, d.cls, d.kind, d.onset) for d in tr.decisions] == \
            [(d.detected, d.cls, d.kind, d.onset) for d in fleet_rows]
    res = os.path.join(scenario["root"], "results")
    assert main(["trend", os.path.join(res, "ESN004"), "--fleet", res]) == 1
    assert "FAULT: sensor:T48" in capsys.readouterr().out


def test_results_of_another_database_are_named(scenario, tmp_path):
    """Results computed with one database and diagnosed with another (the same path rebuilt, or
    another file) are named in a warning with both digests; with their own database, none."""
    import warnings

    from pwl.errors import PwlWarning
    records = scenario["records"]
    db = GainDatabase.open(DB)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PwlWarning)
        prepare(records, db)
    other = copy.copy(db)
    other.attrs = dict(db.attrs, note="rebuilt")
    path = str(tmp_path / "rebuilt.h5")
    other.save(path)
    rebuilt = GainDatabase.open(path)
    with pytest.warns(PwlWarning, match=rf"{len(records)} of {len(records)} results files were computed with "
                                        rf"another database than .*rebuilt\.h5 \(sha256 {db.digest[:12]}\.\.\., "
                                        rf"not {rebuilt.digest[:12]}"):
        prepare(records, rebuilt)


def test_diagnose_and_trend_exclude_flights(scenario, tmp_path, capsys):
    """pwl fleet diagnose / pwl trend --exclude ENGINE:FLIGHT: that flight's row says 'excluded'
    and carries the engine's diagnosis as of the flight before; no other row is excluded."""
    import csv as _csv
    res = os.path.join(scenario["root"], "results")
    engine = scenario["plan"].serial[0]
    out = str(tmp_path / "d.csv")
    assert main(["fleet", "diagnose", res, "-o", out, "--exclude", f"{engine}:5"]) == (1 if latest_detected(out) else 0)
    rows = [r for r in _csv.DictReader(open(out)) if r["engine"] == engine]
    by = {int(r["flight"]): r for r in rows}
    assert by[5]["status"] == "excluded" and by[5]["detected"] == by[4]["detected"]
    assert [r["status"] for r in rows].count("excluded") == 1
    capsys.readouterr()
    rc = main(["trend", os.path.join(res, engine), "--fleet", res])       # 1: its latest flight is flagged
    assert "excluded" not in capsys.readouterr().out
    assert main(["trend", os.path.join(res, engine), "--fleet", res, "--exclude", f"{engine}:5"]) == rc
    assert "excluded" in capsys.readouterr().out


def test_a_snapshot_table_of_the_same_snapshots_gives_the_same_diagnosis(scenario, tmp_path):
    """The scenario's snapshots (each flight's window per regime) written as a snapshot table, as
    another system would report them: the same rows (detected, class, kind, onset) and sizes
    within 2 % (the table carries no standard errors; the fleet's scatter is what counts)."""
    import pandas as pd

    from pwl.fleet.snapshot_table import read_snapshot_table

    db = GainDatabase.open(DB)
    rows = []
    for r in scenario["records"]:
        s = r.snapshot
        for w in r.windows.values():
            rows.append({"engine": r.engine, "flight": r.index, "flight_time": r.order[0], "samples": s.samples[w]}
                        | dict(zip(s.channels, s.mean[w])))
    got = diagnose_fleet(read_snapshot_table(pd.DataFrame(rows), db), db)[0]
    want = [d for e in sorted(scenario["rows"]) for d in scenario["rows"][e]]
    got.sort(key=lambda d: (d.engine, d.flight))
    assert [(d.engine, d.flight, d.detected, d.cls, d.kind, d.onset) for d in got] == \
           [(d.engine, d.flight, d.detected, d.cls, d.kind, d.onset) for d in want]
    for a, b in zip(got, want):
        if b.detected:
            assert a.magnitude == pytest.approx(b.magnitude, rel=0.02), (a.engine, a.flight)
