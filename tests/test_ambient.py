"""Trims on hot and cold days: the database's ambient terms (pwl.database.Ambient), built from the
plant's own trims off the standard day and checked against the nonlinear plant, the numpy
reference filter and the diagnosis."""
import copy

import numpy as np
import pytest

from linearize import plant as proto
from linearize.build import SerialExecutor, build
from linearize.spec import BuildSpec, SpecError
from models.turbofan import Turbofan
from pwl.airdata import ambient_offset
from pwl.bench.reference import ReferenceFilter
from pwl.database import DatabaseError, GainDatabase
from pwl.estimator import Estimator
from pwl.fleet.signatures import Signatures
from pwl.logs import Log
from pwl.errors import PwlWarning

SPEC = """
[model]
plant = "models.turbofan:Turbofan"
[trim_grid]
alt = [0, 6000, 12000]
Mach = [0, 0.4, 0.85]
NfR = [60, 70, 80, 90, 100]
[dynamics_grid]
alt = [0, 12000]
Mach = [0, 0.85]
NfR = [60, 80, 100]
[build]
{span}
[tuners]
n = 4
"""


def _build(tmp_path_factory, name, span_line):
    out = str(tmp_path_factory.mktemp("ambient") / f"{name}.h5")
    return build(BuildSpec.parse(SPEC.format(span=span_line)), out, executor=SerialExecutor(), progress=False,
                 log=lambda *a: None)


@pytest.fixture(scope="module")
def dbs(tmp_path_factory):
    """(database with the ambient terms (default span 30 K), the same build without them)."""
    return _build(tmp_path_factory, "hot_cold", ""), _build(tmp_path_factory, "std", "ambient_span = 0")


def plant_day(plant, p, dT):
    """The plant's trim at p on a day dT K off ISA: (corrected u and y, theta, delta, raw trim)."""
    env = proto.day_environment(plant, p, dT)
    t = plant.trim(np.asarray(p, dtype=np.float64), None, env)
    fac = proto.correction_factors(plant, env)
    th, de = plant.theta_delta(env)
    return np.r_[t["u"] / fac["u"], t["y"] / fac["y"]], th, de, t


def test_ambient_offset_gives_back_the_plants_day():
    plant = Turbofan()
    for alt, mach, dT in [(0, 0, 0), (0, 0.3, -45), (5500, 0.6, 12.5), (10999, 0.78, 30), (12500, 0.85, -20)]:
        theta = plant.theta_delta(np.array([alt, mach, dT], dtype=float))[0]
        assert abs(ambient_offset(theta * 288.15, alt, mach) - dT) < 1e-9, (alt, mach, dT)


def test_trims_follow_the_plant_on_hot_and_cold_days(dbs):
    """At trim nodes on days 15-45 K off ISA (the build trimmed at +-30 K): the database's trims on
    that day are within 0.03 % of the plant's corrected trims; without the ambient terms they are
    off by the day's effect (0.3-1 % here: corrected parameters are not invariant in this plant)."""
    amb, std = dbs
    plant = Turbofan()
    nodes = amb.trim_grid.nodes()
    rng = np.random.default_rng(1)
    for dT in (-40.0, -15.0, 20.0, 45.0):
        err_a, err_s = [], []
        for p in nodes[rng.choice(len(nodes), 6, replace=False)]:
            want, th, _, _ = plant_day(plant, p, dT)
            for db, err in ((amb, err_a), (std, err_s)):
                tr = db.trims_at(p[None], th)
                err.append(np.abs(np.r_[tr["u"][0], tr["y"][0]] / want - 1.0).max())
        assert max(err_a) < 3e-4, (dT, max(err_a))
        assert max(err_s) > 10 * max(err_a), (dT, max(err_s), max(err_a))


def _log(db, plant, n=600, seed=0, swing=75.0):
    """Raw channels of a random walk through the trim grid on a day swinging +-``swing`` K around
    ISA (part of it beyond the +-60 K the runtime holds): schedule channels, theta, delta, and the
    plant's own trim values as measurements (kernel arrays U, Y, S, TH, DE), and the day's offset."""
    rng = np.random.default_rng(seed)
    lo = np.array([a.lo for a in db.trim_grid.axes])
    hi = np.array([a.hi for a in db.trim_grid.axes])
    u01 = np.clip(0.5 + np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0), 0.02, 0.98)
    P = lo + u01 * (hi - lo)
    dT = swing * np.sin(3 * np.pi * np.arange(n) / n)
    ram = 1.0 + 0.2 * P[:, 1] ** 2        # inlet temperature kept in its plausible range (170-380 K)
    t_isa = 288.15 - 0.0065 * np.minimum(P[:, 0], 11000.0)
    dT = np.clip(dT, 180.0 / ram - t_isa, 370.0 / ram - t_isa)
    TH, DE = np.empty(n), np.empty(n)
    for k in range(n):
        TH[k], DE[k] = plant.theta_delta(np.array([P[k, 0], P[k, 1], dT[k]]))
    S = np.column_stack([P[:, 0], P[:, 1], P[:, 2] / 100 * plant.Nf_design * np.sqrt(TH)])
    tr = db.trims_at(P, TH)
    fy = db.correction_factor(db.names["y"], TH, DE)
    fu = db.correction_factor(db.names["u"], TH, DE)
    Y = tr["y"] * fy * (1 + 0.002 * rng.standard_normal((n, db.n("y"))))
    Y[:, db.names["y"].index("Nf")] = S[:, 2]
    return tr["u"] * fu, Y, S, TH, DE, dT


def test_kernel_equals_the_reference_filter_on_changing_days(dbs):
    amb, _ = dbs
    plant = Turbofan()
    U, Y, S, TH, DE, dT = _log(amb, plant)
    assert (np.abs(dT) > 60).any() and (np.abs(dT) < 60).mean() > 0.5
    res = Estimator(amb).run_arrays(U, Y, S, TH, DE)
    ref = ReferenceFilter(amb).run(U, Y, S, TH, DE)
    for o, v in ref.items():
        np.testing.assert_allclose(res.outputs[o], v, rtol=1e-10, atol=1e-10 * np.abs(v).max(initial=1.0), err_msg=o)


def test_far_days_are_held_at_the_reach_and_named(dbs):
    """A theta whose day is 100 K off ISA (a T2 reading high, still plausible) estimates what 60 K
    does (the same corrected measurements), unflagged (the best the database has), and a log run
    names it in a warning."""
    amb, _ = dbs
    plant = Turbofan()
    p = np.array([9000.0, 0.6, 85.0])
    runs, logs = [], []
    for dT in (60.0, 100.0):
        th, de = plant.theta_delta(np.array([p[0], p[1], dT]))
        n = 50
        S = np.tile([p[0], p[1], p[2] / 100 * plant.Nf_design * np.sqrt(th)], (n, 1))
        t60 = amb.trims_at(p[None], plant.theta_delta(np.array([p[0], p[1], 60.0]))[0])  # the trims at 60 K
        U = np.tile(t60["u"] * amb.correction_factor(amb.names["u"], [th], [de]), (n, 1))
        Y = np.tile(t60["y"] * amb.correction_factor(amb.names["y"], [th], [de]), (n, 1))
        Y[:, amb.names["y"].index("Nf")] = S[:, 2]
        runs.append(Estimator(amb).run_arrays(U, Y, S, np.full(n, th), np.full(n, de)))
        chans = dict(zip(amb.names["u"], U.T)) | dict(zip(amb.names["y"], Y.T)) | {
            "alt": S[:, 0], "Mach": S[:, 1], "T2": np.full(n, th * 288.15), "P2": np.full(n, de * 101325.0)}
        logs.append(Log(np.arange(n) * amb.dt, chans, {}))
    hold, far = runs
    assert np.array_equal(hold.flags, far.flags)
    th60 = plant.theta_delta(np.array([p[0], p[1], 60.0]))[0]
    th100 = plant.theta_delta(np.array([p[0], p[1], 100.0]))[0]
    fy = amb.correction_factor(amb.names["y"], [th60, th100], [1.0, 1.0])
    np.testing.assert_allclose(hold.outputs["y_hat"][-1] / fy[0], far.outputs["y_hat"][-1] / fy[1], rtol=1e-12)
    with pytest.warns(PwlWarning, match=r"50 of 50 samples on a day \+100 K off the standard atmosphere .*"
                                        r"held at \+60 K there. A T2 reading high"):
        Estimator(amb).run(logs[1])


def test_steady_state_on_hot_and_cold_days_matches_the_standard_days_error(dbs):
    """The open-loop runtime against the plant (pwl validate's check): on days 15 K off ISA the
    model's error at each point stays what it is on the standard day (the grid's own interpolation
    error), within 0.05 %; without the ambient terms the day adds up to 0.2-0.4 %."""
    from linearize import validate as V

    amb, std = dbs
    added = {}
    for label, db in (("ambient", amb), ("standard", std)):
        base = V.steady_state(db, n=6, seed=3, settle_steps=400)[0]
        added[label] = max(np.abs(V.steady_state(db, n=6, seed=3, settle_steps=400, dT=d)[0][:, :8] - base[:, :8]).max()
                           for d in (-15.0, 15.0))
    assert added["ambient"] < 0.05, added
    assert added["standard"] > 4 * added["ambient"], added


def test_diagnosis_deviations_on_a_hot_day(dbs):
    """A healthy engine's snapshot on a day 35 K above ISA deviates from the database's trims as on
    the standard day within 0.05 % per channel (0.039 % on Wf); without the ambient terms the day
    moves it by 0.65 % (Wf)."""
    amb, std = dbs
    plant = Turbofan()
    p = np.array([9000.0, 0.78, 88.0])      # off the grid's nodes
    _, th, de, t = plant_day(plant, p, 35.0)
    T2, P2 = plant.inlet(proto.day_environment(plant, p, 35.0))
    mean = dict(zip(amb.names["y"], t["y"])) | dict(zip(amb.names["u"], t["u"]))
    mean |= {"alt": p[0], "Mach": p[1], "T2": T2, "P2": P2}
    d_amb = Signatures(amb).at(mean, {}).d
    d_std = Signatures(std).at(mean, {}).d
    # off the grid's nodes both have the interpolation error: compare with the standard day's
    _, th0, de0, t0 = plant_day(plant, p, 0.0)
    T20, P20 = plant.inlet(proto.day_environment(plant, p, 0.0))
    mean0 = dict(zip(amb.names["y"], t0["y"])) | dict(zip(amb.names["u"], t0["u"]))
    mean0 |= {"alt": p[0], "Mach": p[1], "T2": T20, "P2": P20}
    d0 = Signatures(amb).at(mean0, {}).d
    assert np.abs(d_amb - d0).max() < 5e-4, np.abs(d_amb - d0).max()
    # (the standard-day database has no inlet recovery, so no air-data channel: its channels first)
    assert np.abs(d_std - d0[:d_std.size]).max() > 10 * np.abs(d_amb - d0).max()


def test_ambient_record_round_trip_and_checks(dbs, tmp_path):
    amb, std = dbs
    assert std.ambient is None and amb.ambient.span == 30.0
    path = str(tmp_path / "copy.h5")
    amb.save(path)
    back = GainDatabase.open(path)
    for k in "xuyz":
        np.testing.assert_array_equal(back.ambient.coef[k], amb.ambient.coef[k])
    assert (back.ambient.span, back.ambient.alt, back.ambient.mach) == (30.0, "alt", "Mach")
    assert "hot and cold days" in back.summary()
    bad = copy.copy(amb)
    bad.ambient = copy.copy(amb.ambient)
    bad.ambient.mach = "M"
    with pytest.raises(DatabaseError, match="scheduling variables 'alt' and 'M'"):
        bad.validate()
    bad.ambient = copy.copy(amb.ambient)
    bad.ambient.coef = dict(amb.ambient.coef, y=amb.ambient.coef["y"][..., :1, :])
    with pytest.raises(DatabaseError, match="trim/ambient_y has shape"):
        bad.validate()


def test_spec_ambient_span():
    with pytest.raises(SpecError, match="ambient_span = -5"):
        BuildSpec.parse(SPEC.format(span="ambient_span = -5"))
    assert BuildSpec.parse(SPEC.format(span="")).ambient_span == 30.0


def test_health_estimates_of_a_flight_do_not_follow_the_day(tmp_path):
    """The shipped database on simulated flights of one engine (HPT efficiency -1 %) on days 30 K
    below, at and above ISA: the filter's health estimates over the settled flight are the same
    on every day within 0.05 pt (measured 0.01); without the ambient terms the HPT loss read
    -1.80 / -0.79 / +0.10 % (the hot day hid it): more than 0.5 pt apart."""
    from pwl.cli import main
    from pwl.demo_data import demo_paths
    from pwl.logs import read_log

    db = GainDatabase.open(demo_paths()[0])
    bare = copy.copy(db)
    bare.ambient = None
    hpt = db.names["h"].index("hpt_eff")
    est = {}
    for dT in (-30, 0, 30):
        path = str(tmp_path / f"f{dT}.h5")
        assert main(["simulate", "-o", path, "--dtamb", str(dT), "--health", "hpt_eff=-0.01", "--seed", "3",
                     "--durations", "climb=200,cruise=150,descent=60"]) == 0
        log = read_log(path)
        for label, d in (("ambient", db), ("bare", bare)):
            h = Estimator(d).run(log).outputs["h_hat"]
            est.setdefault(label, []).append(np.median(h[h.shape[0] // 3:], axis=0))
    amb, bare_h = np.array(est["ambient"]), np.array(est["bare"])
    assert np.ptp(amb, axis=0).max() < 5e-4, np.ptp(amb, axis=0)
    assert np.ptp(bare_h[:, hpt]) > 5e-3, bare_h[:, hpt]
    assert amb[1, hpt] < -0.005      # the loss is seen on every day


def test_no_ambient_terms_where_the_runtime_cannot_find_the_day():
    """A plant without an ambient offset in its environment (the linear example) gets none,
    silently; a plant whose inlet temperature does not give its day back by the runtime's formula
    (here 1 % hotter than the ram rise says) gets none, with a log line saying why; a zero span
    asks for none."""
    from linearize.build import ambient_span
    from models.linear import LinearPlant

    spec = BuildSpec.parse(SPEC.format(span=""))
    said = []
    assert ambient_span(LinearPlant(), spec, spec.trim_grid, said.append) == 0.0 and not said
    assert ambient_span(Turbofan(), spec, spec.trim_grid, said.append) == 30.0 and not said

    class WarmInlet(Turbofan):
        def theta_delta(self, env):
            th, de = super().theta_delta(env)
            return 1.01 * th, de

    assert ambient_span(WarmInlet(), spec, spec.trim_grid, said.append) == 0.0
    assert len(said) == 1 and "no hot/cold-day trims" in said[0] and "runtime's formula" in said[0]
    off = BuildSpec.parse(SPEC.format(span="ambient_span = 0"))
    assert ambient_span(Turbofan(), off, off.trim_grid, said.append) == 0.0
