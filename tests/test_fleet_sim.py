"""Fleet simulator (models.fleet, pwl.cli.fleet_simulate): plan determinism and ranges, health,
sensor and component faults, parallel runs identical to serial ones, failure handling."""
import argparse
import copy
import csv
import json
import math

import numpy as np
import pytest

from models import fleet
from models.flight import TRA, flight_profile
from models.turbofan import H_NAMES, PlantError, Turbofan
from pwl import __version__
from pwl.cli import fleet_simulate as fs
from pwl.logs import read_log

PLAN_FIELDS = ("serial", "h0", "rate", "fault_class", "magnitude", "bias", "onset", "eff", "flow",
               "dTamb", "cruise_alt", "cruise_mach", "tra_takeoff", "tra_cruise", "noise_seed")


def assert_plans_equal(a, b):
    for f in PLAN_FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)), err_msg=f)


def test_plan_is_deterministic_and_engine_draws_do_not_depend_on_fleet_size():
    a, b = fleet.plan_fleet(6, 7, seed=3), fleet.plan_fleet(6, 7, seed=3)
    assert_plans_equal(a, b)
    c = fleet.plan_fleet(6, 7, seed=4)
    assert not np.array_equal(a.h0, c.h0) and not np.array_equal(a.dTamb, c.dTamb)
    big = fleet.plan_fleet(9, 7, seed=3)
    for f in ("h0", "rate", "dTamb", "cruise_alt", "cruise_mach", "tra_takeoff", "tra_cruise", "noise_seed"):
        np.testing.assert_array_equal(getattr(big, f)[:6], getattr(a, f), err_msg=f)
    assert a.serial == ["ESN001", "ESN002", "ESN003", "ESN004", "ESN005", "ESN006"]
    assert fleet.plan_fleet(1000, 2).serial[-1] == "ESN1000"


def test_plan_ranges():
    E, M = 300, 12
    p = fleet.plan_fleet(E, M, seed=1)
    eff = np.array([n.endswith("_eff") for n in H_NAMES])
    turb = np.array([n in ("hpt_flow", "lpt_flow") for n in H_NAMES])
    comp = ~eff & ~turb
    assert np.all(p.h0[:, eff] <= 0) and np.all(p.h0[:, comp] <= 0) and np.all(p.h0[:, turb] >= 0)
    assert abs(np.mean(p.h0[:, turb]) - 0.003) < 0.0005          # N(+0.003, 0.002), rarely clipped
    assert np.all((p.rate[:, eff] >= -1e-4) & (p.rate[:, eff] <= 0))
    assert np.all((p.rate[:, comp] >= -7.5e-5) & (p.rate[:, comp] <= 0))
    assert np.all((p.rate[:, turb] >= 0) & (p.rate[:, turb] <= 5e-5))
    for k, (lo, hi) in fleet.FLIGHT_VARIATION.items():
        v = getattr(p, k)
        assert v.shape == (E, M) and v.min() >= lo and v.max() <= hi, k
    faulty = np.array([c != "none" for c in p.fault_class])
    assert faulty.sum() == round(0.6 * E)
    assert set(p.fault_class) == set(fleet.CLASSES)            # 180 draws over 14 classes
    assert np.all(p.onset[~faulty] == -1)
    assert p.onset[faulty].min() >= max(3, M // 4) and p.onset[faulty].max() <= M - 2
    sig, yref = Turbofan().sensor_noise, fleet.reference_outputs()
    for i, c in enumerate(p.fault_class):
        m = p.magnitude[i]
        if c in fleet.COMPONENTS:
            assert -0.04 <= m <= -0.01
            assert p.eff[i] == m and p.flow[i] == fleet.COMPONENT_RATIO[c] * m
        elif c == "sensor:Wf":
            assert 0.01 <= abs(m) <= 0.04 and np.isnan(p.bias[i])
        elif c != "none":
            s = c.split(":")[1]
            assert 2.0 <= abs(m) <= 6.0
            assert p.bias[i] == pytest.approx(m * sig[s] * yref[s], rel=1e-14)
        else:
            assert m == 0 and p.eff[i] == 0 and p.flow[i] == 0
    signs = np.sign(p.magnitude[[c.startswith("sensor:") for c in p.fault_class]])
    assert (signs > 0).any() and (signs < 0).any()
    # the reference trim: cruise at 9000 m, Mach 0.78, NfR 92 %
    assert yref["Nf"] == pytest.approx(0.92 * 4200.0 * math.sqrt(fleet._pristine_model().inlet(
        [9000.0, 0.78, 0.0])[0] / 288.15), rel=1e-9)
    # short fleets: the onset clamps to the last flight
    for M, on in ((2, 1), (3, 2), (4, 3), (5, 3)):
        q = fleet.plan_fleet(20, M, fault_fraction=1.0)
        assert set(q.onset.tolist()) == {on}, M


def test_health_at_hand_computation():
    p = fleet.plan_fleet(2, 6, seed=2, fault_fraction=1.0, classes=["lpc"])
    for i in range(2):
        on = p.onset[i]
        assert 3 <= on <= 4
        np.testing.assert_allclose(fleet.health_at(p, i, on - 1), p.h0[i] + (on - 1) * p.rate[i], rtol=0, atol=1e-15)
        h = p.h0[i] + 5 * p.rate[i]
        h[H_NAMES.index("lpc_eff")] += p.magnitude[i]
        h[H_NAMES.index("lpc_flow")] += p.magnitude[i]
        np.testing.assert_allclose(fleet.health_at(p, i, 5), h, rtol=0, atol=1e-15)
        assert fleet.fault_active(p, i, on) and not fleet.fault_active(p, i, on - 1)
    q = fleet.plan_fleet(3, 4, fault_fraction=0.0)
    assert q.fault_class == ["none"] * 3
    np.testing.assert_allclose(fleet.health_at(q, 1, 3), q.h0[1] + 3 * q.rate[1], atol=1e-15)
    with pytest.raises(ValueError, match="flight index 4"):
        fleet.health_at(q, 0, 4)
    with pytest.raises(ValueError, match="engine index 3"):
        fleet.health_at(q, 3, 0)


def test_classes_restriction_and_bad_arguments():
    p = fleet.plan_fleet(10, 5, fault_fraction=1.0, classes=["hpt", "sensor:P50"])
    assert set(p.fault_class) <= {"hpt", "sensor:P50"} and len(set(p.fault_class)) == 2
    assert fleet.plan_fleet(5, 5, fault_fraction=1.0, classes=["none"]).fault_class == ["none"] * 5
    for kw, word in ((dict(engines=0, flights=5), "engines"), (dict(engines=2, flights=1), "flights"),
                     (dict(engines=2, flights=5, fault_fraction=1.5), "1.5"),
                     (dict(engines=2, flights=5, fault_fraction=-0.1), "-0.1"),
                     (dict(engines=2, flights=5, classes=["hpc", "compressor"]), "compressor"),
                     (dict(engines=2, flights=5, classes=[]), "at least one"),
                     (dict(engines=2.5, flights=5), "2.5"), (dict(engines=2, flights=5, seed=-1), "-1")):
        with pytest.raises(ValueError, match=word):
            fleet.plan_fleet(**kw)


def test_flight_profile_tra_override():
    a = flight_profile("short", dither=False)
    for b in (flight_profile("short", dither=False, tra=None), flight_profile("short", dither=False, tra={})):
        for k in ("time", "alt", "Mach", "TRA"):
            np.testing.assert_array_equal(a[k], b[k])
    c = flight_profile("short", dither=False, tra={"takeoff": 85.0, "cruise": 84.0})
    cruise, takeoff = c["phase"] == 3, c["phase"] == 1
    assert np.isclose(c["TRA"][cruise][-1], 84.0) and np.isclose(a["TRA"][cruise][-1], TRA["cruise"])
    assert np.isclose(c["TRA"][takeoff][-1], 85.0)
    np.testing.assert_array_equal(c["TRA"][c["phase"] == 6], a["TRA"][a["phase"] == 6])
    with pytest.raises(ValueError, match="holding"):
        flight_profile("short", tra={"holding": 50.0})
    with pytest.raises(ValueError, match="120"):
        flight_profile("short", tra={"cruise": 120.0})


def _without_fault(plan, i):
    q = copy.deepcopy(plan)
    q.fault_class[i], q.onset[i] = "none", -1
    q.magnitude[i] = q.eff[i] = q.flow[i] = 0.0
    q.bias[i] = np.nan
    return q


def test_sensor_fault_changes_only_the_logged_channel_from_the_onset():
    p = fleet.plan_fleet(1, 2, seed=5, fault_fraction=1.0, classes=["sensor:T48"])
    assert p.onset[0] == 1 and p.bias[0] != 0
    clean = _without_fault(p, 0)
    # before the onset: identical to the fault-free engine
    r0, c0 = fleet.simulate_flight(p, 0, 0), fleet.simulate_flight(clean, 0, 0)
    assert r0["attrs"]["fault_active"] is False and r0["attrs"]["fault_class"] == "sensor:T48"
    for k in c0["channels"]:
        np.testing.assert_array_equal(r0["channels"][k], c0["channels"][k])
    # from the onset: the T48 channel is offset by exactly the bias, nothing else changes
    r1, c1 = fleet.simulate_flight(p, 0, 1), fleet.simulate_flight(clean, 0, 1)
    a = r1["attrs"]
    assert a["fault_active"] is True and a["fault_onset"] == 1 and a["engine"] == "ESN001"
    assert a["flight_index"] == 1 and a["flight_time"] == "2026-01-02T00:00:00"
    assert a["fault_bias"] == p.bias[0] and a["fault_unit"] == "sigma"
    for k in c1["channels"]:
        if k == "T48":
            np.testing.assert_allclose(r1["channels"][k] - c1["channels"][k], p.bias[0], rtol=1e-9, atol=1e-9)
        else:
            np.testing.assert_array_equal(r1["channels"][k], c1["channels"][k])
    for k in c1["truth"]:
        np.testing.assert_array_equal(r1["truth"][k], c1["truth"][k])
    # the noise: logged minus truth of the fault-free flight is noise of the documented size
    rel = c1["channels"]["T48"] / c1["truth"]["T48"] - 1.0
    assert 0.9 * 0.0075 < np.std(rel) < 1.1 * 0.0075
    # a fuel-flow bias is relative and affects only the logged Wf
    w = copy.deepcopy(p)
    w.fault_class[0], w.magnitude[0], w.bias[0] = "sensor:Wf", -0.03, np.nan
    rw = fleet.simulate_flight(w, 0, 1)
    np.testing.assert_allclose(rw["channels"]["Wf"], c1["channels"]["Wf"] * 0.97, rtol=1e-14)
    np.testing.assert_array_equal(rw["truth"]["Wf"], c1["truth"]["Wf"])
    np.testing.assert_array_equal(rw["channels"]["T48"], c1["channels"]["T48"])


def test_component_fault_changes_truth_health_in_the_documented_ratio():
    p = fleet.plan_fleet(1, 2, seed=7, fault_fraction=1.0, classes=["hpt"])
    assert p.onset[0] == 1 and -0.04 <= p.magnitude[0] <= -0.01
    r = fleet.simulate_flight(p, 0, 1)
    base = p.h0[0] + p.rate[0]
    d = np.array([r["truth"][n][0] for n in H_NAMES]) - base
    m = p.magnitude[0]
    expect = np.zeros(10)
    expect[H_NAMES.index("hpt_eff")], expect[H_NAMES.index("hpt_flow")] = m, -0.5 * m
    np.testing.assert_allclose(d, expect, atol=1e-15)
    assert r["attrs"]["fault_active"] is True and r["attrs"]["fault_unit"] == "fraction"
    rows = fleet.truth_rows(p)
    assert rows[0]["class"] == "hpt" and rows[0]["eff"] == m and rows[0]["flow"] == -0.5 * m
    assert rows[0]["bias"] == "" and rows[0]["unit"] == "fraction" and rows[0]["onset"] == 1
    for c in fleet.COMPONENTS:                 # every component: the ratio of COMPONENT_RATIO
        q = fleet.plan_fleet(1, 2, fault_fraction=1.0, classes=[c])
        dh = fleet.health_at(q, 0, 1) - fleet.health_at(_without_fault(q, 0), 0, 1)
        assert dh[H_NAMES.index(c + "_flow")] == pytest.approx(fleet.COMPONENT_RATIO[c] * dh[H_NAMES.index(c + "_eff")])
        assert np.count_nonzero(np.abs(dh) > 1e-15) == 2


def test_parallel_fleet_equals_serial_fleet(tmp_path, capsys):
    a = fs.simulate_fleet(tmp_path / "a", 2, 2, seed=11, workers=1)
    b = fs.simulate_fleet(tmp_path / "b", 2, 2, seed=11, workers=2, progress=False)
    assert a["failed"] == b["failed"] == 0 and a["total"] == 4 and b["workers"] == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("[4/4] flights simulated,") and err[-1].endswith("flights/s")
    for serial in ("ESN001", "ESN002"):
        for j in (0, 1):
            la = read_log(tmp_path / "a" / serial / f"flight_{j:03d}.h5")
            lb = read_log(tmp_path / "b" / serial / f"flight_{j:03d}.h5")
            for grp in ("channels", "truth"):
                ga, gb = getattr(la, grp), getattr(lb, grp)
                assert set(ga) == set(gb)
                for k in ga:
                    np.testing.assert_array_equal(ga[k], gb[k], err_msg=f"{serial} {j} {grp} {k}")
            assert la.attrs["engine"] == serial and int(la.attrs["flight_index"]) == j
            assert la.attrs["fault_class"] == lb.attrs["fault_class"]
    for name in ("truth.csv", "fleet.json"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()
    with open(tmp_path / "a" / "truth.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    ref = fleet.truth_rows(fleet.plan_fleet(2, 2, seed=11))
    assert [r["engine"] for r in rows] == ["ESN001", "ESN002"]
    assert [r["class"] for r in rows] == [r["class"] for r in ref]
    assert [int(r["onset"]) for r in rows] == [r["onset"] for r in ref]
    meta = json.loads((tmp_path / "a" / "fleet.json").read_text())
    assert meta["engines"] == 2 and meta["seed"] == 11 and meta["software"]["pwl"] == __version__
    assert meta["component_range"] == [0.01, 0.04] and meta["flight_durations"]["cruise"] == 150.0


def test_failed_flight_is_recorded_and_the_fleet_continues(tmp_path, monkeypatch, capsys):
    real = fleet.simulate_flight

    def flaky(plan, i, j, model=None):
        if j == 0:
            raise PlantError("trim did not converge (test)")
        return real(plan, i, j, model)

    monkeypatch.setattr(fleet, "simulate_flight", flaky)
    p = argparse.ArgumentParser()
    fs.add_simulate_arguments(p)
    args = p.parse_args(["--engines", "1", "--flights", "2", "-j", "1", "-o", str(tmp_path / "f"),
                         "--fault-fraction", "0"])
    assert fs.run_simulate(args) == 1
    err = capsys.readouterr().err
    assert "1 of 2 flights failed" in err and "ESN001 flight 0: PlantError: trim did not converge" in err
    assert not (tmp_path / "f" / "ESN001" / "flight_000.h5").exists()
    assert read_log(tmp_path / "f" / "ESN001" / "flight_001.h5").attrs["fault_class"] == "none"
    assert (tmp_path / "f" / "truth.csv").exists() and (tmp_path / "f" / "fleet.json").exists()
    with pytest.raises(ValueError, match="engines"):
        fs.simulate_fleet(tmp_path / "g", 0, 2)
