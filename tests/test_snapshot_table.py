"""Snapshot tables (pwl.fleet.snapshot_table): steady snapshots another system wrote, diagnosed
without flight logs. The fleet is the nonlinear plant's steady states (models.fleet.snapshot_rows:
the plant's trims with the engines' true health, day and sensor faults), not the database's."""
import csv
import os
import warnings

import numpy as np
import pytest

from models import fleet
from models.turbofan import Turbofan
from pwl.cli import main
from pwl.database import GainDatabase
from pwl.demo_data import demo_paths
from pwl.errors import PwlWarning
from pwl.fleet.diagnose import diagnose_fleet, engine_named, prepare
from pwl.fleet.signatures import DiagnosisError
from pwl.fleet.snapshot_table import read_snapshot_table

ENGINES, FLIGHTS = 12, 12


@pytest.fixture(scope="module")
def db():
    return GainDatabase.open(demo_paths()[0])


@pytest.fixture(scope="module")
def plan():
    return fleet.plan_fleet(ENGINES, FLIGHTS, seed=21, fault_fraction=0.5, classes=("hpt", "lpc", "sensor:T48"))


def table_rows(plan, samples=30):
    return [r for i in range(plan.engines) for j in range(plan.flights)
            for r in fleet.snapshot_rows(plan, i, j, samples)]


def write_table(path, rows, rename=None, convert=None):
    """A CSV of ``rows``; ``rename`` column -> header cell, ``convert`` column -> f(value)."""
    rename, convert = rename or {}, convert or {}
    cols = list(rows[0])
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([rename.get(c, c) for c in cols])
        for r in rows:
            w.writerow([repr(convert[c](r[c])) if c in convert else
                        (repr(r[c]) if isinstance(r[c], float) else r[c]) for c in cols])
    return str(path)


def test_snapshot_rows_are_the_plant_steady_state_with_the_fault(plan):
    """Without noise (a snapshot of 10^14 readings) the rows are the plant's own trims at the
    flight's operating points and day with the engine's true health, and a sensor fault is on the
    logged value only, from its onset."""
    m = Turbofan()
    i = next(k for k, c in enumerate(plan.fault_class) if c == "sensor:T48")
    for j in (0, FLIGHTS - 1):
        rows = fleet.snapshot_rows(plan, i, j, samples=10 ** 14)
        s = fleet.flight_settings(plan, i, j)
        cruise = rows[1]
        env = np.array([cruise["alt"], cruise["Mach"], s["dTamb"]])
        t = m.trim(np.array([cruise["alt"], cruise["Mach"], 62.0 + s["tra_cruise"] / 100.0 * 38.0]),
                   fleet.health_at(plan, i, j), env)
        bias = plan.bias[i] if fleet.fault_active(plan, i, j) else 0.0
        for k, name in enumerate(m.y_names):
            assert cruise[name] == pytest.approx(t["y"][k] + (bias if name == "T48" else 0.0), rel=1e-6), name
        assert (cruise["T2"], cruise["P2"]) == pytest.approx(m.inlet(env), rel=1e-6)
        assert rows[0]["alt"] == 0.0 and rows[0]["regime"] == "idle"
    to = fleet.snapshot_rows(plan, i, 0, regimes=("takeoff", "cruise"))       # ProDiMES's two
    assert [r["regime"] for r in to] == ["takeoff", "cruise"] and to[0]["Mach"] == fleet.TAKEOFF_MACH
    with pytest.raises(ValueError, match="unknown snapshot regimes"):
        fleet.snapshot_rows(plan, i, 0, regimes=("climb",))


def test_a_plant_snapshot_fleet_is_diagnosed_from_its_table(tmp_path, db, plan):
    """12 engines x 12 flights, HPT, LPC and T48 faults on half of them: every faulty engine is
    found from its onset flight (at most one flight late) with its class, every healthy engine
    and every flight before an onset is quiet, and the T48 biases are sized within 3 standard
    errors (noise-free snapshots: within 2.5 %, the linearisation's share)."""
    path = write_table(tmp_path / "snap.csv", table_rows(plan))
    records = read_snapshot_table(path, db)
    assert len(records) == ENGINES * FLIGHTS
    rows = diagnose_fleet(records, db)[0]
    by = {}
    for r in rows:
        by.setdefault(r.engine, []).append(r)
    assert sorted(by) == plan.serial
    for i, e in enumerate(plan.serial):
        got = by[e]
        assert [r.flight for r in got] == list(range(FLIGHTS))
        c, on = plan.fault_class[i], int(plan.onset[i])
        if c == "none":
            assert not any(r.detected for r in got), (e, [(r.flight, r.cls) for r in got if r.detected])
            continue
        assert not any(r.detected for r in got[:on]), (e, c, on)
        assert all(r.detected and r.cls == c for r in got[on + 1:]), (e, c, [(r.flight, r.cls) for r in got])
        if c == "sensor:T48":      # within 3 of its standard errors (about 1.7 K here)
            d = got[-1]
            assert abs(d.bias - plan.bias[i]) < 3.0 * d.magnitude_std / d.magnitude * d.bias, (d.bias, plan.bias[i])


def test_faults_from_delivery_are_levels_against_the_fleet(tmp_path, db, monkeypatch):
    """16 engines x 10 flights of the plant, three delivered with a fault (HPT -4 % and LPC -4 %
    efficiency, flows alike, and T48 +30 K from flight 0: benchmarks/delivered_faults.py): each
    reads its class, kind level, onset 0 from the first flight tested (n_base), and no healthy
    engine alarms. The fleet's level spread was the spread of its engines' health estimates, mostly
    their own noise for the weakly seen parameters: the HPT and LPC engines read 'ok' throughout."""
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
    import delivered_faults
    monkeypatch.setattr(delivered_faults, "DELIVERED", {1: ("hpt", -0.04), 4: ("lpc", -0.04), 7: ("sensor:T48", 30.0)})
    plan = delivered_faults._delivered(16, 10, seed=21, fault_fraction=0.0)
    rows = [r for i in range(16) for j in range(10) for r in fleet.snapshot_rows(plan, i, j, 5)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PwlWarning)
        decisions = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    for i, e in enumerate(plan.serial):
        got = [d for d in decisions if d.engine == e]
        if plan.fault_class[i] == "none":
            assert not any(d.detected for d in got), (e, [(d.flight, d.cls) for d in got if d.detected])
            continue
        assert all(d.detected and d.cls == plan.fault_class[i] and d.kind == "level" and d.onset == 0
                   for d in got[3:]), (e, [(d.flight, d.cls, d.kind) for d in got])


def test_snapshots_of_a_regime_few_engines_report_are_named_not_read(tmp_path, db, plan):
    """Two engines of twelve also report take-off snapshots: those rows (2 x 12) are in no regime
    (fewer than 30 % of the flights have one there) and were dropped without a word; now one
    warning names how many, the engines and the first row, and the diagnosis is the table's
    without them, row for row."""
    rows = table_rows(plan, 5)
    more = [r for i in (0, 1) for j in range(FLIGHTS)
            for r in fleet.snapshot_rows(plan, i, j, 5, regimes=("takeoff",))]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "a.csv", rows + more), db), db)[0]
    lines = [str(w.message) for w in caught if "too few flights share" in str(w.message)]
    assert len(lines) == 1 and lines[0].startswith(f"{2 * FLIGHTS} snapshots of 2 engines (ESN001, ESN002)"), lines
    assert f"a.csv:row {len(rows) + 2}, ESN001 flight 0 at alt 0, Mach {fleet.TAKEOFF_MACH:g}" in lines[0], lines[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PwlWarning)
        plain = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "b.csv", rows), db), db)[0]
    assert [(d.engine, d.flight, d.cls, d.kind, d.onset) for d in got] == \
        [(d.engine, d.flight, d.cls, d.kind, d.onset) for d in plain]


def test_a_sensor_dead_on_flights_in_a_row_is_named(tmp_path, db, plan):
    """ESN003's T48 reads nothing from flight 7 (its latest 5), ESN004's Ps30 nothing on flights
    2-5, ESN005's T48 nothing on flight 6 alone: the rows only listed them in 'missing'; now one
    warning per channel names the two runs (ESN005's one flight is a gap, not named)."""
    rows = table_rows(plan, 5)
    for r in rows:
        if (r["engine"] == "ESN003" and r["flight"] >= 7) or (r["engine"] == "ESN005" and r["flight"] == 6):
            r["T48"] = float("nan")
        if r["engine"] == "ESN004" and 2 <= r["flight"] <= 5:
            r["Ps30"] = float("nan")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        decisions = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "a.csv", rows), db), db)[0]
    lines = [str(w.message) for w in caught if "no value on" in str(w.message)]
    assert len(lines) == 2, lines
    t48 = next(x for x in lines if x.startswith("T48:"))
    assert "1 engine(s) (ESN003 flight 7 to flight 11 (5 flights, its latest))" in t48 and "ESN005" not in t48, t48
    ps30 = next(x for x in lines if x.startswith("Ps30:"))
    assert "(ESN004 flight 2 to flight 5 (4 flights))" in ps30, ps30
    assert all("T48" in d.missing for d in decisions if d.engine == "ESN003" and d.flight >= 7)


def test_a_flight_filed_under_another_engine_is_named(tmp_path, db, plan):
    """ESN001's flight 6 rows carry ESN009's flight 6 values (a row typed under the wrong serial;
    both healthy, the healthy pair farthest apart in this fleet: about 110 between their flights,
    squared and whitened, where the 1e-6 point of 18 channels is 62): one warning names that
    flight as ESN009's, and no other flight of the table (faults, onsets and all) is named.
    Engines nearer than that are not told apart (ESN001 and ESN003: 42)."""
    a, b = "ESN001", "ESN009"
    assert plan.fault_class[0] == plan.fault_class[8] == "none"
    rows = table_rows(plan, 5)
    theirs = {r["regime"]: r for r in rows if r["engine"] == b and r["flight"] == 6}
    for r in rows:
        if r["engine"] == a and r["flight"] == 6:
            r.update({k: v for k, v in theirs[r["regime"]].items() if k not in ("engine", "flight", "flight_time")})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        diagnose_fleet(read_snapshot_table(write_table(tmp_path / "a.csv", rows), db), db)
    lines = [str(w.message) for w in caught if "wrong engine" in str(w.message)]
    assert len(lines) == 1 and f"engine {a}'s flight 6 is {b}'s by its snapshots" in lines[0], lines


def test_a_sensor_under_another_name_is_pointed_at(tmp_path, db, plan):
    """T48 logged as 'EGT': the warning that T48 is missing names the numeric column not read
    (before: only 'no column for T48'); a text column (regime) is not named."""
    rows = [{("EGT" if k == "T48" else k): v for k, v in r.items()} for r in table_rows(plan)[:16]]
    with pytest.warns(PwlWarning, match="no column for T48: .* its numeric columns not read: 'EGT' [(]one of them "
                                        "under another name[?] a channel map, --channel-map, names it[)]$"):
        read_snapshot_table(write_table(tmp_path / "t.csv", rows), db)


def test_units_and_names_of_a_table(tmp_path, db, plan):
    """A table with its own column names and units read through a channel map (degC, kPa, lb/s,
    N1 in percent) and one with units declared in its header give the native table's operating
    points and channel values within 1e-9 relative."""
    rows = table_rows(plan)[:40]
    native = read_snapshot_table(write_table(tmp_path / "a.csv", rows), db)
    declared = read_snapshot_table(write_table(tmp_path / "b.csv", rows, rename={"T48": "T48[degC]", "P2": "P2[kPa]"},
                                               convert={"T48": lambda v: v - 273.15, "P2": lambda v: v / 1e3}), db)
    nf100 = Turbofan().Nf_design
    other = write_table(tmp_path / "c.csv", rows, rename={"engine": "ESN", "Nf": "N1_pct", "Wf": "FF_lbs", "T48": "EGT_C"},
                        convert={"Nf": lambda v: 100.0 * v / nf100, "Wf": lambda v: v / 0.45359237,
                                 "T48": lambda v: v - 273.15})
    cmap = tmp_path / "map.toml"
    lines = ["[channels]"] + [f'{c} = "{c}"' for c in ("alt", "Mach", "T2", "P2", "Nc", "T24", "Ps30", "T30", "P50", "P15")]
    lines += [f'Nf = {{ column = "N1_pct", unit = "rpm", scale = {nf100 / 100.0!r} }}',
              'Wf = { column = "FF_lbs", unit = "lb/s" }', 'T48 = { column = "EGT_C", unit = "degC" }']
    cmap.write_text("\n".join(lines) + "\n")
    mapped = read_snapshot_table(other, db, str(cmap))
    for recs in (declared, mapped):
        assert [r.engine for r in recs] == [r.engine for r in native]
        for a, b in zip(recs, native):
            ja = [a.snapshot.channels.index(c) for c in b.snapshot.channels]
            np.testing.assert_allclose(a.snapshot.mean[:, ja], b.snapshot.mean, rtol=1e-9)
            np.testing.assert_allclose(a.snapshot.p, b.snapshot.p, rtol=1e-9)


def test_a_table_in_another_unit_undeclared_is_named(tmp_path, db, plan):
    """P2 in kPa without saying so: implausible, named with the unit, no operating point; the
    diagnosis then says it has nothing steady to compare."""
    rows = table_rows(plan)[:40]
    path = write_table(tmp_path / "t.csv", rows, convert={"P2": lambda v: v / 1e3})
    with pytest.warns(PwlWarning, match=r"'P2'.*implausible.*kPa"):
        recs = read_snapshot_table(path, db)
    assert all(np.isnan(r.snapshot.p).all() for r in recs)
    with pytest.raises(DiagnosisError, match="no steady operating regime"):
        diagnose_fleet(recs, db)


@pytest.mark.parametrize("drop, match", [("engine", "no engine column"), ("T2", "channel 'T2' is missing")])
def test_a_table_without_what_it_needs_is_refused(tmp_path, db, plan, drop, match):
    rows = [{k: v for k, v in r.items() if k != drop} for r in table_rows(plan)[:8]]
    with pytest.raises(DiagnosisError, match=match):
        read_snapshot_table(write_table(tmp_path / "t.csv", rows), db)


@pytest.mark.parametrize("empty, said", [(False, "no column for P15: missing on every snapshot [(]an engine standard "
                                                "without it[?][)]$"),
                                         (True, "column 'P15' holds no value in any of the table's 16 rows")])
def test_a_table_without_a_sensor_reads_it_missing(tmp_path, db, plan, empty, said):
    """Without the column, or with a column the export left empty (said: it was not, before)."""
    rows = [{k: (float("nan") if empty and k == "P15" else v) for k, v in r.items() if empty or k != "P15"}
            for r in table_rows(plan)[:16]]
    with pytest.warns(PwlWarning, match=said):
        recs = read_snapshot_table(write_table(tmp_path / "t.csv", rows), db)
    j = recs[0].snapshot.channels.index("P15")
    assert np.isnan(recs[0].snapshot.mean[:, j]).all() and not recs[0].snapshot.finite[:, j].any()


def test_pwl_fleet_diagnose_takes_a_table(tmp_path, db, capsys, monkeypatch):
    """The command line: a table needs --database (exit 2, said); with it, one row per flight."""
    out = str(tmp_path / "d.csv")
    assert main(["fleet", "simulate", "--snapshots", "--engines", "4", "--flights", "6", "-o",
                 str(tmp_path / "F")]) == 0
    table = str(tmp_path / "F" / "snapshots.csv")
    assert main(["fleet", "diagnose", table, "-o", out]) == 2
    assert "give --database" in capsys.readouterr().err
    assert main(["fleet", "diagnose", str(tmp_path / "F"), "-o", out]) == 2      # the folder: a hint
    assert f"snapshot tables are given as files: pwl fleet diagnose {table}" in capsys.readouterr().err
    # one engine's trend from the table, judged against its fleet (the same table)
    assert main(["trend", table, "--database", demo_paths()[0], "--engine", "ESN001", "--fleet", table]) in (0, 1)
    text = capsys.readouterr().out
    assert "engine ESN001: 6 flights" in text and "snapshot tables carry no filter health" in text
    # its plot: the deviations the diagnosis tested (a table has no filter health to draw)
    from pwl.fleet.trending import engine_trend, plot_trend
    recs = read_snapshot_table(table, db)
    tr = engine_trend([r for r in recs if r.engine == "ESN001"], db, fleet=recs)
    assert tr.deviations.shape == (6, len(tr.channels)) and np.isfinite(tr.deviations).any()
    pytest.importorskip("matplotlib")
    import matplotlib.figure
    titles, real = [], matplotlib.figure.Figure.savefig
    def spy(fig, *a, **k):
        titles.extend(ax.get_title() for ax in fig.axes if ax.get_title())
        return real(fig, *a, **k)
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    plot_trend(tr, tmp_path / "t.png")
    assert titles == list(dict.fromkeys(c.split("@")[0] for c in tr.channels)) and os.path.getsize(tmp_path / "t.png") > 0
    assert main(["trend", table, "--database", demo_paths()[0], "--engine", "ESN404"]) == 2
    chart = tmp_path / "fleet.png"
    assert main(["fleet", "diagnose", table, "--database", demo_paths()[0], "-o", out, "-j", "1", "--plot",
                 str(chart)]) == 1
    assert f"plot: {chart}" in capsys.readouterr().out and chart.stat().st_size > 0
    with open(out) as fh:
        serial = list(csv.DictReader(fh))
    assert len(serial) == 4 * 6
    assert any(r["detected"] == "1" for r in serial if r["flight"] == "5")    # a fault at the latest flight: 1
    assert os.path.exists(tmp_path / "F" / "truth.csv")
    # two processes, an engine each at a time: the same rows, in the same order, and progress shown
    assert main(["fleet", "diagnose", table, "--database", demo_paths()[0], "-o", out, "-j", "2"]) == 1
    assert "engines" in capsys.readouterr().err
    with open(out) as fh:
        assert list(csv.DictReader(fh)) == serial
    # a sensor without a value anywhere: its scatter is not printed as if measured (the floor was)
    with open(table) as fh:
        rows = list(csv.DictReader(fh))
    write_table(tmp_path / "empty.csv", [dict(r, P15="nan") for r in rows])
    main(["fleet", "diagnose", str(tmp_path / "empty.csv"), "--database", demo_paths()[0], "-o", out, "-j", "1"])
    text = capsys.readouterr().out
    assert "P15@0 none (no value)" in text and "P15@1 none (no value)" in text and "T48@1 none" not in text, text


def test_a_table_without_the_inlet_pressure_takes_it_from_air_data(tmp_path, db, plan):
    """Engine-monitoring reports seldom carry P2: taken from pressure altitude and Mach with the
    plant's inlet recovery the build measured (said in a warning); the fleet's diagnosis is the
    one with the logged P2 (the same rows: detected, class, kind, onset)."""
    rows = table_rows(plan)
    native = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "a.csv", rows), db), db)[0]
    with pytest.warns(PwlWarning, match="no 'P2' column: the inlet pressure is taken from pressure altitude"):
        recs = read_snapshot_table(write_table(tmp_path / "b.csv", [{k: v for k, v in r.items() if k != "P2"}
                                                                    for r in rows]), db)
    j = recs[0].snapshot.channels.index("P2")
    np.testing.assert_allclose(recs[0].snapshot.mean[:, j], [rows[0]["P2"], rows[1]["P2"]], rtol=1e-3)
    got = diagnose_fleet(recs, db)[0]
    assert [(d.engine, d.flight, d.detected, d.cls, d.kind, d.onset) for d in got] == \
           [(d.engine, d.flight, d.detected, d.cls, d.kind, d.onset) for d in native]


def test_snapshots_off_for_one_flight_early_in_a_history_are_no_faults(tmp_path, db, plan):
    """A snapshot taken in a transient (every channel 2 % off) on a healthy engine's first flight
    and on another's third: no alarm on any flight (before, the first read as a step at the second
    flight on every later one; the third hid in the engine's own scatter of so few flights). And
    a fault on an engine's second flight is still that fault, not its first flight's excursion:
    the first flight is the one nearer the fleet's normal baseline."""
    import copy

    p = copy.deepcopy(plan)
    healthy = [i for i, c in enumerate(p.fault_class) if c == "none"]
    faulty = next(i for i, c in enumerate(p.fault_class) if c == "hpt")
    p.onset[faulty] = 1
    rows = table_rows(p)
    sensors = ("Nc", "T24", "Ps30", "T30", "T48", "P50", "P15", "Wf")
    for i, (flight, regime, f) in zip(healthy[:2], ((0, "cruise", 1.02), (2, "idle", 0.98))):
        r = next(r for r in rows if r["engine"] == p.serial[i] and r["flight"] == flight and r["regime"] == regime)
        r.update({c: r[c] * f for c in sensors})
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    by = {}
    for d in got:
        by.setdefault(d.engine, []).append(d)
    for i in healthy[:2]:
        assert not any(d.detected for d in by[p.serial[i]]), [(d.flight, d.cls) for d in by[p.serial[i]] if d.detected]
    late = by[p.serial[faulty]][3:]          # testing starts with the fourth flight
    assert all(d.detected and d.cls == "hpt" and d.onset == 1 for d in late), [(d.flight, d.cls, d.onset) for d in late]


def test_flights_off_in_a_row_and_a_glitch_after_a_fault(tmp_path, db, plan):
    """Two or three flights in a row off by the same pattern (a bleed left on, a borrowed
    instrument: every channel 1.5-2 % off) on three healthy engines alarm on those flights only
    (before: a step at the first and its 'return' read as another fault, every later flight
    alarmed); one
    channel 6 % off on the flight after a fault's onset (T24 for an HPT loss, T48 itself for a T48
    bias) leaves the fault reported from its onset on every later flight, the flight the glitch
    cleared on naming it in ``earlier`` if it does not report it (before: 'cleared', not detected,
    on every later flight, the fault found the flight before never confirmed)."""
    import copy

    p = copy.deepcopy(plan)
    healthy = [i for i, c in enumerate(p.fault_class) if c == "none"]
    hpt = next(i for i, c in enumerate(p.fault_class) if c == "hpt")
    t48 = next(i for i, c in enumerate(p.fault_class) if c == "sensor:T48")
    p.onset[hpt], p.onset[t48] = 5, 6
    rows = table_rows(p)
    sensors = ("Nc", "T24", "Ps30", "T30", "T48", "P50", "P15", "Wf")
    pattern = dict(zip(sensors, (1.02, 0.98, 1.015, 1.02, 0.985, 1.02, 0.98, 1.015)))
    pairs = {p.serial[healthy[0]]: (5, 6), p.serial[healthy[1]]: (8, 9), p.serial[healthy[2]]: (5, 6, 7)}
    glitch = {p.serial[hpt]: (6, "T24"), p.serial[t48]: (7, "T48")}
    for r in rows:
        if r["flight"] in pairs.get(r["engine"], ()):     # (the other way round on the three)
            r.update({c: r[c] * (f if r["engine"] != p.serial[healthy[2]] else 2.0 - f) for c, f in pattern.items()})
        if glitch.get(r["engine"], (None,))[0] == r["flight"]:
            c = glitch[r["engine"]][1]
            r[c] *= 1.06
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    by = {}
    for d in got:
        by.setdefault(d.engine, []).append(d)
    for e, bad in pairs.items():
        alarms = [d.flight for d in by[e] if d.detected]
        assert set(alarms) <= set(bad), (e, bad, [(d.flight, d.cls, d.kind) for d in by[e] if d.detected])
    for i, (e, (g, _)) in zip((hpt, t48), glitch.items()):
        fault = (p.fault_class[i], p.onset[i])
        cleared, after = by[e][g + 1], by[e][g + 2:]
        assert (cleared.detected and (cleared.cls, cleared.onset) == fault) or \
            (cleared.kind == "cleared" and cleared.earlier == f"{fault[0]}@{fault[1]}"), (e, cleared)
        assert all(d.detected and (d.cls, d.onset) == fault for d in after), \
            (e, [(d.flight, d.status, d.cls, d.kind, d.onset) for d in after])


def test_every_engine_off_on_one_flight_is_the_fleets_excursion(tmp_path, db, plan, recwarn):
    """Every engine's snapshots of flight 6 off alike (a ground station's processing, a fleet-wide
    data fault: every channel 1.5-2 % off): two fleet-wide changes that cancel, at 6 and 7, are
    one excursion of the fleet, and flight 6 is left out of every engine's tests. No healthy
    engine alarms, and every faulty one is found with its class and onset from the flight after
    its onset (before: the two fleet-wide steps were nuisances of every test, a fault from before
    them was measured from the flights before them only, one beginning with them was lost). One
    warning says so (before: two, of fleet-wide changes at 6 and at 7)."""
    rows = table_rows(plan)
    sensors = ("Nc", "T24", "Ps30", "T30", "T48", "P50", "P15", "Wf")
    pattern = dict(zip(sensors, (1.02, 0.98, 1.015, 1.02, 0.985, 1.02, 0.98, 1.015)))
    for r in rows:
        if r["flight"] == 6:
            r.update({c: r[c] * f for c, f in pattern.items()})
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    by = {}
    for d in got:
        by.setdefault(d.engine, []).append(d)
    for i, e in enumerate(plan.serial):
        c, on = plan.fault_class[i], int(plan.onset[i])
        if c == "none":
            assert not any(d.detected for d in by[e]), (e, [(d.flight, d.cls) for d in by[e] if d.detected])
            continue
        assert not any(d.detected for d in by[e][:on]), (e, c, on)
        assert all(d.detected and d.cls == c for d in by[e][max(on, 6) + 1:]), \
            (e, c, on, [(d.flight, d.cls, d.onset) for d in by[e]])
    said = [str(w.message) for w in recwarn if "fleet-wide" in str(w.message)]
    assert len(said) == 1 and "engines off on flight 6 only, back from flight 7" in said[0], said


def test_a_unit_change_mid_history_serials_in_other_cases_and_no_data_codes(tmp_path, db, plan, recwarn):
    """A ground station that began writing T48 in degC (inside T48's plausible range in K) on two
    healthy engines' last four flights, serials typed in lower case or with spaces on some rows,
    a -9999 'no data' code and a row sent twice: the same rows as the clean table, but T48 missing on those
    flights; each named in a warning. Before, the degC flights were T48 faults and every
    differently-spelt serial was an engine of its own."""
    rows = table_rows(plan)
    clean = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "clean.csv", rows), db), db)[0]
    healthy = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][:2]
    for k, r in enumerate(rows):
        if r["engine"] in healthy and r["flight"] >= FLIGHTS - 4:
            r["T48"] -= 273.15
        if k % 7 == 3:
            r["engine"] = r["engine"].lower() if k % 2 else f" {r['engine'][:3]} {r['engine'][3:]}"
    rows[5]["Ps30"] = -9999.0
    rows.insert(30, dict(rows[12]))      # one snapshot sent twice
    recwarn.clear()
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "messy.csv", rows), db), db)[0]
    said = [str(w.message) for w in recwarn.list]
    assert any("T48: 16 snapshot value(s) of 2 engine(s)" in s and "degC" in s for s in said), said
    assert any(f"{ENGINES} engine serial(s) spelt more than one way" in s for s in said), said
    assert any("'Ps30': 1 of" in s and "'no data' code" in s for s in said), said
    assert any("1 row(s) repeat an earlier row exactly (the first: row 32)" in s for s in said), said
    assert [(d.engine, d.flight) for d in got] == [(d.engine, d.flight) for d in clean]
    for a, b in zip(got, clean):
        assert (a.detected, a.cls) == (b.detected, b.cls), (a.engine, a.flight, a.cls, b.cls)
        if a.engine in healthy and a.flight >= FLIGHTS - 4:
            assert "T48" in a.missing.split()
    # a user's serial as they type it: the results' spelling
    assert engine_named(" esn 001", {"ESN001", "ESN002"}) == "ESN001"
    assert engine_named("ESN003", {"ESN001", "esn003", "ESN003"}) == "ESN003"
    assert engine_named("esn004", {"ESN001"}) == "esn004"


def test_a_channel_logged_in_degf_reads_missing_wherever_it_was(tmp_path, db, plan, recwarn):
    """A ground station writing T30 in degF on half the engines from flight 4 (degF and K meet at
    575 K: their T30 values are 6-28 % off the model in K, most under the 20 % of a gross
    deviation): every one of them reads missing, named in one warning with the unit, and each
    row is the row of the same table with those T30 values left blank (the reference). Before,
    only the values beyond 20 % were missing; the rest were used as they were."""
    rows = table_rows(plan)
    half = list(plan.serial[::2])
    degf = [r for r in rows if r["engine"] in half and r["flight"] >= 4]
    blank = [dict(r, T30=np.nan) if r in degf else r for r in rows]
    for r in degf:
        r["T30"] = (r["T30"] - 273.15) * 1.8 + 32.0
    recwarn.clear()
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "degf.csv", rows), db), db)[0]
    said = [str(w.message) for w in recwarn.list]
    assert any(f"T30: {len(degf)} snapshot value(s) of {len(half)} engine(s)" in s and "degF" in s for s in said), said
    ref = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "blank.csv", blank), db), db)[0]
    assert [(d.engine, d.flight) for d in got] == [(d.engine, d.flight) for d in ref]
    for a, b in zip(got, ref):
        assert (a.detected, a.cls, a.kind, a.onset, a.missing) == (b.detected, b.cls, b.kind, b.onset, b.missing), (a, b)


def test_two_engines_with_two_unit_mistakes_on_one_channel(tmp_path, db, plan, recwarn):
    """T30 in degC on one healthy engine (40-60 % off in K: gross) and in degF on another (6-28 %
    off, most under the 20 % of a gross value), both from flight 4: every one of those values
    reads missing, each engine's unit named in the warning, and the rows are those of the table
    with them blank. Before, the fleet's typical gross value (degC) set the one unit looked for:
    the degF engine's values under 20 % read as a T30 step (a probe fleet of logs: FPR 5.2 %)."""
    rows = table_rows(plan)
    healthy = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][:2]
    bad = {e: [r for r in rows if r["engine"] == e and r["flight"] >= 4] for e in healthy}
    blank = [dict(r, T30=np.nan) if r["engine"] in healthy and r["flight"] >= 4 else r for r in rows]
    for r in bad[healthy[0]]:
        r["T30"] = r["T30"] - 273.15
    for r in bad[healthy[1]]:
        r["T30"] = (r["T30"] - 273.15) * 1.8 + 32.0
    recwarn.clear()
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "two.csv", rows), db), db)[0]
    said = [str(w.message) for w in recwarn.list if str(w.message).startswith("T30:")]
    assert len(said) == 1 and f"degC on {healthy[0]}" in said[0] and f"degF on {healthy[1]}" in said[0], said
    ref = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "blank.csv", blank), db), db)[0]
    for a, b in zip(got, ref):
        assert (a.detected, a.cls, a.kind, a.onset, a.missing) == (b.detected, b.cls, b.kind, b.onset, b.missing), (a, b)


def test_snapshots_with_times_of_their_own_and_dates_day_or_month_first(tmp_path, db, plan):
    """A report per snapshot (idle at 06:00, cruise at 08:00) with no flight numbers, its dates day-
    first (27/01/2026 08:00) or month-first with AM/PM: each engine's snapshots grouped into its
    flights again, and the diagnosis is the flight-numbered table's. Before, each snapshot was a
    flight of its own (its regimes never met; unreadable dates were silently row order). With
    flight numbers too, a number repeated two weeks later (the counter reset) is two flights.
    Dates whose order cannot be told, and no readable time, are errors naming the column."""
    from datetime import datetime, timedelta

    rows = table_rows(plan)
    clean = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "clean.csv", rows), db), db)[0]
    when = [datetime.fromisoformat(r["flight_time"]) + timedelta(days=10, hours=6 + 2 * (r["regime"] == "cruise"))
            for r in rows]      # (from the 11th: a day above 12 tells the order)
    for fmt in ("%d/%m/%Y %H:%M", "%m/%d/%Y %I:%M %p"):
        timed = [{"engine": r["engine"], "date": t.strftime(fmt), **{k: v for k, v in r.items()
                 if k not in ("engine", "flight", "flight_time")}} for r, t in zip(rows, when)]
        timed = timed[1::2] + timed[::2]       # cruise reports first: the order is the times'
        with pytest.warns(PwlWarning, match=rf"{2 * ENGINES * FLIGHTS} times -> {ENGINES * FLIGHTS} flights"):
            got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", timed), db), db)[0]
        assert [(d.engine, d.detected, d.cls, d.onset) for d in got] == [(d.engine, d.detected, d.cls, d.onset)
                                                                         for d in clean], fmt
    reset = [dict(r, flight=r["flight"] % 6, flight_time=w.isoformat()) for r, w in zip(rows, when)]
    recs = read_snapshot_table(write_table(tmp_path / "r.csv", reset), db)
    assert len(recs) == ENGINES * FLIGHTS and all(len(r.snapshot) == 2 for r in recs)
    early = [{k: v for k, v in r.items() if k not in ("engine", "flight", "flight_time")} for r in rows[:40]]
    with pytest.raises(DiagnosisError, match=r"column 'date'.*day or the month first cannot be told"):
        read_snapshot_table(write_table(tmp_path / "a.csv", [dict(engine="E1", date=f"0{1 + k % 9}/01/2026", **r)
                                                            for k, r in enumerate(early)]), db)
    with pytest.raises(DiagnosisError, match=r"column 'date': 40 of 40 times unreadable.*no flight number"):
        read_snapshot_table(write_table(tmp_path / "b.csv", [dict(engine="E1", date="soon", **r) for r in early]), db)


def test_two_sensor_biases_at_once_and_one_after_the_other(tmp_path, db, plan):
    """T48 +1.5 % and Ps30 -1 % from one flight on (one ground-station calibration) on two
    healthy engines: read as the two biases, sized within 15 % (the noise-free biases: 1.5 % of
    T48, 1 % of Ps30 at the snapshot with the most readings). Before, one read a T48 bias with
    an HPC and HPT change, the other a 'recovery' and nothing after it. T48 from flight 3 and
    Ps30 from flight 7 on a third: the Ps30 step with the T48 bias in ``earlier``."""
    import copy

    p = copy.deepcopy(plan)
    healthy = [p.serial[i] for i, c in enumerate(p.fault_class) if c == "none"][2:5]
    rows = table_rows(p)
    onsets = {healthy[0]: (5, 5), healthy[1]: (5, 5), healthy[2]: (3, 7)}
    for r in rows:
        if r["engine"] in onsets:
            a, b = onsets[r["engine"]]
            r["T48"] *= 1.015 if r["flight"] >= a else 1.0
            r["Ps30"] *= 0.99 if r["flight"] >= b else 1.0
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    by = {}
    for d in got:
        by.setdefault(d.engine, []).append(d)
    for e in healthy[:2]:
        late = by[e][6:]
        assert all(d.detected and d.cls == "sensor:Ps30+sensor:T48" and d.onset == 5 for d in late), \
            [(d.flight, d.cls, d.kind, d.onset) for d in late]
        fit = dict(kv.split("=") for kv in late[-1].detail.split())
        level = {c: np.mean([r[c] for r in rows if r["engine"] == e and r["flight"] < 5]) for c in ("T48", "Ps30")}
        assert float(fit["sensor:T48"]) == pytest.approx(0.015 * level["T48"], rel=0.15)
        assert float(fit["sensor:Ps30"]) == pytest.approx(-0.01 * level["Ps30"], rel=0.15)
    late = by[healthy[2]][9:]
    assert all(d.detected and d.cls == "sensor:Ps30" and d.kind == "step" and d.onset == 7
               and d.earlier == "sensor:T48@3" for d in late), [(d.flight, d.cls, d.kind, d.onset, d.earlier) for d in late]


def test_a_step_first_fitted_as_a_drift_is_revised_and_not_lost(tmp_path, db):
    """The seed-11 fleet's ESN015 (healthy; five readings a snapshot) given a T48 bias of +1.5 %
    from flight 12 and a Ps30 bias of -1 % from flight 20, diagnosed with 16 other engines: two
    flights after its onset the Ps30 step fitted a drift from 19 as well and was confirmed so;
    as the flights after it stayed level its refit faded, and from flight 26 the row read no
    fault at all. Now the drift is fitted again as a step near its onset once four flights came
    after it (REVISE_FLIGHTS): from flight 24 the Ps30 step at 20, the T48 bias in ``earlier``."""
    p = fleet.plan_fleet(40, 30, seed=11)
    keep = [p.serial.index(e) for e in ["ESN015"] + [f"ESN{k:03d}" for k in range(24, 40)]]
    rows = [r for i in keep for j in range(p.flights) for r in fleet.snapshot_rows(p, i, j, 5)]
    for r in rows:
        if r["engine"] == "ESN015":
            r["T48"] *= 1.015 if r["flight"] >= 12 else 1.0
            r["Ps30"] *= 0.99 if r["flight"] >= 20 else 1.0
    got = [d for d in diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
           if d.engine == "ESN015"]
    late = got[24:]
    assert all(d.detected and d.cls == "sensor:Ps30" and d.kind == "step" and d.onset == 20
               and d.earlier == "sensor:T48@12" for d in late), [(d.flight, d.cls, d.kind, d.onset, d.earlier) for d in late]


def test_a_table_as_an_excel_workbook(tmp_path, db, plan):
    """The table saved from Excel (first sheet, a row of units under the header declaring T48 in
    degC, flight times as Excel date-times): the CSV's flights and values within 1e-12; a sheet
    pwl does not read (.ods) is an error saying what to do. Before, a workbook was 'unreadable
    results file (OSError: ... file signature not found)'."""
    import pandas as pd

    rows = table_rows(plan)[:48]
    native = read_snapshot_table(write_table(tmp_path / "a.csv", rows), db)
    df = pd.DataFrame(rows)
    df["flight_time"] = pd.to_datetime(df["flight_time"])
    df["T48"] = df["T48"] - 273.15
    units = pd.DataFrame([{c: "degC" if c == "T48" else "" for c in df.columns}])
    pd.concat([units, df.astype(object)]).to_excel(tmp_path / "t.xlsx", index=False)
    book = read_snapshot_table(str(tmp_path / "t.xlsx"), db)
    assert [(r.engine, r.label) for r in book] == [(r.engine, r.label) for r in native]
    for a, b in zip(book, native):
        ja = [a.snapshot.channels.index(c) for c in b.snapshot.channels]
        np.testing.assert_allclose(a.snapshot.mean[:, ja], b.snapshot.mean, rtol=1e-12)
    (tmp_path / "t.ods").write_bytes(b"PK")
    with pytest.raises(DiagnosisError, match=r"t.ods: a spreadsheet pwl does not read.*save the sheet as .xlsx or CSV"):
        read_snapshot_table(str(tmp_path / "t.ods"), db)


def test_airline_flight_numbers_are_labels(tmp_path, db, plan):
    """A flight column of airline flight numbers (LH400 one day, LH401 the next, ...): one warning
    for the column (before, one per flight), each day's flight a flight of its own in time order."""
    rows = [dict(r, flight=f"LH40{r['flight'] % 2}") for r in table_rows(plan)[:48]]
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        recs = read_snapshot_table(write_table(tmp_path / "t.csv", rows), db)
    said = [str(w.message) for w in got if issubclass(w.category, PwlWarning)]
    assert len(said) == 1 and "column 'flight': 2 of 2 flight values are not whole numbers (the first 'LH400')" in said[0]
    assert len(recs) == 24 and all(len(r.snapshot) == 2 and r.index == -1 for r in recs)
    for e in {r.engine for r in recs}:
        mine = sorted((r for r in recs if r.engine == e), key=lambda r: r.time)
        assert [r.label for r in mine] == [f"flight LH40{k % 2}" for k in range(12)]


def test_a_component_drift_from_mid_history_is_found_against_the_fleets_wear(tmp_path, db, monkeypatch):
    """The seed-11 fleet's ESN015 (healthy; five readings a snapshot) given an HPC losing 0.1 %
    efficiency and flow a flight from flight 10 (the plant's trims with that health), diagnosed
    with 11 other engines: its wear line held to the fleet's, the drift is found as an HPC
    drift by flight 22 (1.3 % lost) with an onset within 4 flights of 10, and nothing before
    flight 10. With a wear line free per channel it took up most of the drift: found at flight
    23-27 on three such engines of the 40-engine fleet, never on two."""
    p = fleet.plan_fleet(40, 30, seed=11)
    i = p.serial.index("ESN015")
    keep = [i] + [p.serial.index(f"ESN{k:03d}") for k in range(24, 35)]
    health = fleet.health_at

    def drifting(plan, e, j):
        h = health(plan, e, j)
        if e == i and j >= 10:
            h[[fleet.H_NAMES.index("hpc_eff"), fleet.H_NAMES.index("hpc_flow")]] -= 1e-3 * (j - 9)
        return h
    monkeypatch.setattr(fleet, "health_at", drifting)
    rows = [r for e in keep for j in range(p.flights) for r in fleet.snapshot_rows(p, e, j, 5)]
    monkeypatch.undo()
    got = [d for d in diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
           if d.engine == "ESN015"]
    assert not any(d.detected for d in got[:10])
    found = [d for d in got[10:23] if d.detected]
    assert found and all(d.cls == "hpc" and d.kind == "drift" and abs(d.onset - 10) <= 4 for d in found), \
        [(d.flight, d.cls, d.kind, d.onset) for d in got]


def test_a_slow_sensor_drift_from_mid_history_is_found(tmp_path, db):
    """The seed-11 fleet's ESN015 (healthy; five readings a snapshot; 40 flights) with its logged
    P50 drifting +0.05 %/flight from flight 8 (a sixth of its flight-to-flight scatter a flight),
    diagnosed with 11 other engines: named a P50 drift with an onset within 3 flights of 8 on at
    least 10 of flights 28-39 (1-1.6 % off), nothing before flight 8. Before, a sensor's drift
    slower than min_rate (0.1 %/flight over the channels) was never named, whatever it had added
    up to (and nothing else was: the drift was the best fit, then too slow)."""
    p = fleet.plan_fleet(40, 40, seed=11)
    keep = [p.serial.index(e) for e in ["ESN015"] + [f"ESN{k:03d}" for k in range(24, 35)]]
    rows = [r for i in keep for j in range(p.flights) for r in fleet.snapshot_rows(p, i, j, 5)]
    for r in rows:
        if r["engine"] == "ESN015" and r["flight"] >= 8:
            r["P50"] *= 1.0 + 5e-4 * (r["flight"] - 7)
    got = [d for d in diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
           if d.engine == "ESN015"]
    assert not any(d.detected for d in got[:8]), [(d.flight, d.cls, d.kind) for d in got if d.detected]
    late = [d for d in got[28:] if d.detected and d.cls == "sensor:P50" and d.kind == "drift" and abs(d.onset - 8) <= 3]
    assert len(late) >= 10, [(d.flight, d.cls, d.kind, d.onset) for d in got if d.detected]


def test_a_sensor_noisier_since_a_flight_is_erratic(tmp_path, db):
    """The seed-11 fleet's ESN015 (healthy; five readings a snapshot) with T30 six times as noisy
    from flight 15 (a loose connector), diagnosed with 11 other engines: T30 is named on at least
    8 of flights 20-29, ``erratic`` (onset within 2 of 15) on at least 4 of them; no other engine
    is erratic. Before, the noisy readings were steps or intermittent biases on a few flights,
    ``cleared`` or nothing on most."""
    p = fleet.plan_fleet(40, 30, seed=11)
    keep = [p.serial.index(e) for e in ["ESN015"] + [f"ESN{k:03d}" for k in range(24, 35)]]
    rows = [r for i in keep for j in range(p.flights) for r in fleet.snapshot_rows(p, i, j, 5)]
    rng = np.random.default_rng(7)
    for r in rows:
        if r["engine"] == "ESN015" and r["flight"] >= 15:
            r["T30"] *= 1.0 + rng.normal(0.0, 0.0075 / np.sqrt(5) * np.sqrt(35.0))
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    late = [d for d in got if d.engine == "ESN015" and d.flight >= 20]
    assert sum(d.detected and d.cls == "sensor:T30" for d in late) >= 8, [(d.flight, d.cls, d.kind) for d in late]
    assert sum(d.kind == "erratic" and abs(d.onset - 15) <= 2 for d in late) >= 4, [(d.flight, d.cls, d.kind) for d in late]
    assert not any(d.kind == "erratic" for d in got if d.engine != "ESN015")


def test_a_loss_of_flow_capacity_alone_is_a_fault_not_maintenance(tmp_path, db, monkeypatch):
    """Two healthy engines of the seed-11 fleet (five readings a snapshot) given a change of one
    component's flow capacity alone from flight 12 (the plant's trims with that health): ESN014's
    HPT eroded (flow +2 %), ESN021's LPC fouled in flow only (-2 %), diagnosed with 11 other
    engines. Each is found as its component's step from flight 12 and reported on every later
    flight. Before, a 'recovery' was read by the sign of the efficiency's noise (+0.09 +- 0.16 %,
    +0.19 +- 0.53 %) and the new baseline lost the fault for the rest of the history."""
    p = fleet.plan_fleet(40, 30, seed=11)
    change = {p.serial.index("ESN014"): ("hpt_flow", 0.02), p.serial.index("ESN021"): ("lpc_flow", -0.02)}
    keep = list(change) + [p.serial.index(f"ESN{k:03d}") for k in range(24, 35)]
    health = fleet.health_at

    def changed(plan, e, j):
        h = health(plan, e, j)
        if e in change and j >= 12:
            h[fleet.H_NAMES.index(change[e][0])] += change[e][1]
        return h
    monkeypatch.setattr(fleet, "health_at", changed)
    rows = [r for e in keep for j in range(p.flights) for r in fleet.snapshot_rows(p, e, j, 5)]
    monkeypatch.undo()
    rows_of = {}
    for d in diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]:
        rows_of.setdefault(d.engine, []).append(d)
    for serial, comp in (("ESN014", "hpt"), ("ESN021", "lpc")):
        got = rows_of[serial]
        assert not any(d.detected or d.kind == "recovery" for d in got[:12]), serial
        assert all(d.detected and d.cls == comp and d.onset == 12 for d in got[14:]), \
            [(d.flight, d.status, d.cls, d.kind, d.onset) for d in got]


@pytest.mark.parametrize("sensor, offset", [("Ps30", 30e3), ("P50", 4e3)])
def test_a_raw_offset_on_a_channel_whose_level_moves_between_flights_stays_one_step(tmp_path, db, plan, sensor,
                                                                                   offset):
    """A pressure sensor reading a constant offset from flight 4 on three healthy engines,
    snapshots of 300 readings (a flight log's): its relative deviation moves with each flight's
    cruise altitude (Ps30 30 kPa high: 1.7 to 2.9 % at cruise from one flight to the next in a
    probe fleet of logs). Every later row reads the sensor's step at 4, the last one sized within
    5 % of the offset (measured: Ps30 1-2 %, P50 1-4 %). Before, later tests found another change
    in that scatter: P50 read with a T48 or T24 bias on three rows here, and in the probe fleet
    an HPT step at 10 whose 'recovery' judged the Ps30 bias repaired (a component with a pressure
    sensor was never fitted there: their columns, per Pa and per unit of efficiency, 1e6 apart,
    read ill-conditioned)."""
    healthy = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][:3]
    rows = table_rows(plan, samples=300)
    for r in rows:
        if r["engine"] in healthy and r["flight"] >= 4:
            r[sensor] += offset
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    for e in healthy:
        late = [d for d in got if d.engine == e and d.flight >= 6]
        assert all(d.detected and d.cls == f"sensor:{sensor}" and d.kind == "step" and d.onset == 4 for d in late), \
            [(d.flight, d.cls, d.kind, d.onset, d.detail) for d in late]
        fit = dict(kv.split("=") for kv in late[-1].detail.split())
        assert float(fit[f"sensor:{sensor}"]) == pytest.approx(offset, rel=0.05)


def test_an_overhaul_restoring_every_component_is_a_recovery_not_a_sensor_fault(tmp_path, db, plan, monkeypatch):
    """Four healthy engines overhauled before flight 8 (every health parameter back to new: their
    delivery scatter and wear gone), not declared, snapshots of 300 readings: the flight it shows
    on reads a recovery, no later row a fault. Before, the recovery's refit of two components
    and a sensor (:func:`pwl.fleet.diagnose._sensor_part`) read a lasting sensor bias on two of
    them (T2, T24; in a probe fleet of logs T30 -2.9 K, Ps30 +3.2 kPa) on every flight after the
    overhaul: every component restored explains that sensor's part (its gain over them is not
    significant)."""
    healthy = [i for i, c in enumerate(plan.fault_class) if c == "none"][:4]
    real = fleet.health_at

    def overhauled(p, i, j):
        return p.rate[i] * (j - 8) if i in healthy and j >= 8 else real(p, i, j)
    monkeypatch.setattr(fleet, "health_at", overhauled)
    rows = table_rows(plan, samples=300)
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    for i in healthy:
        mine = [d for d in got if d.engine == plan.serial[i] and d.flight >= 8]
        assert mine[0].kind == "recovery" and not any(d.detected for d in mine), \
            [(d.flight, d.status, d.cls, d.kind, d.onset, d.detail) for d in mine]


def test_a_sensor_stuck_at_one_value_in_every_regime_is_read_so(tmp_path, db, plan, recwarn):
    """T48 reading 950 K at idle and cruise alike from flight 5 on two healthy engines (a
    thermocouple open, a frozen bus word), snapshots of 300 readings: every row from 5 reads
    'sensor:T48 stuck' from 5, T48 named missing there and in one warning with its value.
    Before, the frozen value was a deviation like any other: component changes (HPT, LPT, fan)
    on most rows of a probe fleet of logs."""
    healthy = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][:2]
    rows = table_rows(plan, samples=300)
    for r in rows:
        if r["engine"] in healthy and r["flight"] >= 5:
            r["T48"] = 950.0
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    for e in healthy:
        late = [d for d in got if d.engine == e and d.flight >= 5]
        assert all(d.detected and d.cls == "sensor:T48" and d.kind == "stuck" and d.onset == 5 and "T48" in d.missing
                   for d in late), [(d.flight, d.cls, d.kind, d.onset, d.missing) for d in late]
    assert any("T48: one value in every regime" in str(w.message) and "(950)" in str(w.message) for w in recwarn)


def test_a_gain_error_of_a_scheduling_sensor_is_that_sensor(tmp_path, db, plan):
    """Nf reading 1 % high from flight 4 on two healthy engines (snapshots of 300 readings): the
    offset it makes grows with the speed (about 25 rpm at idle, 39 at cruise) and moves the
    operating point the trims are taken at, unlike an offset. Every row from 6 reads `sensor:Nf`
    from 4, its bias at the mean level within 15 % of 1 % of Nf there (its detail holds the gain
    part). Before, the sensor's offset column alone read `fan+lpc` with an LPC efficiency rising
    0.4 % (a probe fleet of logs: Nf x1.01 and x1.005)."""
    healthy = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][:2]
    rows = table_rows(plan, samples=300)
    for r in rows:
        if r["engine"] in healthy and r["flight"] >= 4:
            r["Nf"] *= 1.01
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)[0]
    for e in healthy:
        late = [d for d in got if d.engine == e and d.flight >= 6]
        assert all(d.detected and d.cls == "sensor:Nf" and d.kind == "step" and d.onset == 4 for d in late), \
            [(d.flight, d.cls, d.kind, d.onset, d.detail) for d in late]
        assert "gain:Nf=" in late[-1].detail
        assert late[-1].magnitude == pytest.approx(0.01, rel=0.15)


def test_a_flight_sent_twice_with_other_values_is_named(tmp_path, db, plan, recwarn):
    """A healthy engine's flight 8 cruise row sent again at the end of the table with T48 30 K
    higher: one warning names the engine, flight, rows and T48 (the diagnosis reads one of the two
    and leaves the other out: before, without a word, and which one decided fault or no fault);
    the clean table gives none."""
    rows = table_rows(plan)
    e = [plan.serial[i] for i, c in enumerate(plan.fault_class) if c == "none"][0]
    recwarn.clear()
    diagnose_fleet(read_snapshot_table(write_table(tmp_path / "clean.csv", rows), db), db)
    assert not [w for w in recwarn.list if "two rows at one operating point" in str(w.message)]
    at = max(k for k, r in enumerate(rows) if r["engine"] == e and r["flight"] == 8)
    rows.append(dict(rows[at], T48=rows[at]["T48"] + 30.0))
    recwarn.clear()
    read_snapshot_table(write_table(tmp_path / "twice.csv", rows), db)
    said = [str(w.message) for w in recwarn.list if "two rows at one operating point" in str(w.message)]
    assert len(said) == 1 and f"engine {e} flight 8, rows {at + 2} and {len(rows) + 1}, T48" in said[0], said
    assert "sent twice and corrected" in said[0] and "one serial" not in said[0], said


def test_two_engines_under_one_serial_and_a_scheduling_channel_missing_are_named(tmp_path, db, plan, recwarn):
    """ESN012's rows filed as ESN011's (every flight then holds two rows per operating point): the
    warning said 'a flight sent twice and corrected?' and the rows left out were named again as
    'at an operating point too few flights share'; now it names two engines under one serial,
    once. ESN010's altitude in feet on its cruise rows (read missing, implausible): those rows
    have no operating point and are named as such, not as a rare regime."""
    rows = table_rows(plan, 5)
    for r in rows:
        if r["engine"] == "ESN012":
            r["engine"] = "ESN011"
        if r["engine"] == "ESN010" and r["alt"] > 0:
            r["alt"] = r["alt"] / 0.3048
    recwarn.clear()
    prepare(read_snapshot_table(write_table(tmp_path / "t.csv", rows), db), db)
    said = [str(w.message) for w in recwarn.list]
    twice = [m for m in said if "two rows at one operating point" in m]
    assert len(twice) == 1 and f"two engines' rows under one serial (ESN011: {FLIGHTS} of its {FLIGHTS} flights)" \
        in twice[0], said
    assert not [m for m in said if "too few flights share" in m], said
    blind = [m for m in said if "have no operating point" in m]
    assert len(blind) == 1 and blind[0].startswith(f"{FLIGHTS} snapshots of 1 engines (ESN010)"), said


def test_an_engine_whose_every_sensor_reads_missing_does_not_stop_the_fleet(tmp_path, db, plan, recwarn):
    """ESN003's sensors all 30 % high (another engine type's rows under its serial): each read
    missing as off the model (named), and the fleet diagnosed as without it. Before, its wear line
    (no health parameter moves what is left: the inlet pressure) made the fleet's spread of wear
    lines NaN and the diagnosis stopped on an internal error (LinAlgError)."""
    rows = table_rows(plan, 5)
    sensors = ["Nc", "T24", "Ps30", "T30", "T48", "P50", "P15", "Wf"]
    odd = [dict(r, **{c: 1.3 * r[c] for c in sensors}) if r["engine"] == "ESN003" else r for r in rows]
    recwarn.clear()
    got = diagnose_fleet(read_snapshot_table(write_table(tmp_path / "odd.csv", odd), db), db)[0]
    said = [str(w.message) for w in recwarn.list if "ESN003" in str(w.message) and "off the model" in str(w.message)]
    assert sorted(m.split(":")[0] for m in said) == sorted(sensors), said
    mine = [d for d in got if d.engine == "ESN003"]
    assert len(mine) == FLIGHTS and not any(d.detected for d in mine)
    assert all(set(d.missing.split()) == set(sensors) for d in mine), [d.missing for d in mine]
