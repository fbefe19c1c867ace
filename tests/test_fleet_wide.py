"""A change most of the fleet shows at the same flight (a fleet-wide sensor recalibration, a
software or fuel change) on synthetic fleets built as tests/test_diagnose.py builds its series:
it must not be taken for the fleet's normal wear, must not make the flights before it look
faulty, and is named once. Before, the fleet's normal wear was fitted on every engine's whole
history, the common step included: it became every engine's "wear", and each engine's flights
before the step, less that wear, came out as a sensor drift from flight 0."""
import warnings

import numpy as np
import pytest

from pwl.errors import PwlWarning
from pwl.fleet.diagnose import DiagnosisConfig, diagnose_engine, fleet_norms, hypotheses, wear_reference
from test_diagnose import COLUMNS, series, synthetic_signatures

SD = 1e-3          # flight-to-flight scatter per channel (relative)
N_FLIGHTS = 20
ONSET = 10


def fleet(changed, cls="sensor:B", theta=(2.0,), onset=ONSET, n_engines=12, seed=5):
    """``n_engines`` engines x 20 flights, health (COLUMNS[:4]) wearing at rates drawn
    U(-2e-4, 0) per flight (the simulated fleets wear at most 1e-4), each engine offset N(0, 0.01) per channel, noise SD; the engines in
    ``changed`` change by hypothesis ``cls`` of size ``theta`` from flight ``onset`` on (sensor B:
    1 unit = 1 % on its channel, i.e. 2 units = 20 SD)."""
    rng = np.random.default_rng(seed)
    S = synthetic_signatures()
    rates = rng.uniform(-2e-4, 0.0, (n_engines, 4))
    step = S[:, {h.name: h for h in hypotheses(COLUMNS)}[cls].columns] @ np.array(theta)
    t = np.arange(N_FLIGHTS, dtype=float)
    out = []
    for e in range(n_engines):
        D = t[:, None] * (S[:, :4] @ rates[e]) + rng.normal(0, 0.01, 6) + rng.normal(0, SD, (N_FLIGHTS, 6))
        if e in changed:
            D[onset:] += step
        out.append(series(D, S, engine=f"E{e:02d}"))
    return out, rates, np.eye(6) * SD ** 2



def judged(fl, Sigma, cfg=DiagnosisConfig()):
    """Every engine diagnosed as diagnose_fleet does (the fleet's scatter, wear and level), and
    the PwlWarnings the fleet's norms raised."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        wear, level = fleet_norms(fl, Sigma, cfg)
    rows = {es.engine: diagnose_engine(es, Sigma, cfg, wear, level) for es in fl}
    return rows, wear, [str(w.message) for w in caught if issubclass(w.category, PwlWarning)]


# the tolerance of a wear rate: the slope of 20 flights' noise (SD / sqrt(sum (t - mean)^2) =
# 1.5e-4 per channel x sqrt(2) with the step as a nuisance) read as 4 health rates on 6 channels
RATE_TOL = 2e-4


@pytest.mark.parametrize("cls,theta,changed", [
    ("sensor:B", (2.0,), range(12)),                # a recalibration of every engine's sensor B
    ("sensor:B", (2.0,), range(2, 12)),             # ... of 10 of 12 (two not yet done)
    ("hpt", (-0.01, 0.005), range(1, 12)),           # a software change moving the hpt's match
])
def test_a_fleet_wide_step_is_not_wear_and_leaves_the_earlier_flights_ok(cls, theta, changed):
    """The fleet's normal wear is the rates drawn, not the step; no flight before the step
    alarms; the step is the fleet's (its onsets, class and median size as drawn) and no engine's
    fault: every engine that changed alike is measured from it, so none alarms (before, each
    reported it as its own fault from the step on, while the same change rolled out over a few
    flights was already left out of each engine's faults)."""
    fl, rates, Sigma = fleet(set(changed), cls, theta)
    rows, wear, _ = judged(fl, Sigma)
    # the fleet's normal wear is that of the rates drawn (numpy's median), not the step's
    np.testing.assert_allclose(wear.median, np.median(rates, axis=0), atol=RATE_TOL)
    (c,) = wear.common
    assert c.cls == cls and c.onsets == {f"E{e:02d}": ONSET for e in changed}
    # the median fit within 10 % (sensor B) or 1e-3 (health: 4 SD read as 4 health parameters on 6 channels)
    np.testing.assert_allclose([float(x.split("=")[1]) for x in c.detail.split()], theta, rtol=0.1, atol=1e-3)
    # no alarm on any engine, before or after the step
    alarms = [(e, r.flight, r.cls, r.kind) for e, rs in rows.items() for r in rs if r.detected]
    assert alarms == []


def test_a_fleet_wide_step_is_named_once_with_its_class_onset_and_size():
    fl, rates, Sigma = fleet(set(range(2, 12)))
    _, wear, said = judged(fl, Sigma)
    assert len(said) == 1 and said[0].startswith("10 of 12 engines changed alike from flight 10 (sensor:B=+"), said
    assert "fleet-wide change" in said[0]
    (c,) = wear.common
    assert (c.onset, c.cls, c.alike, c.eligible) == (ONSET, "sensor:B", 10, 12)
    assert c.engines == [f"E{e:02d}" for e in range(2, 12)]
    assert float(c.detail.split("=")[1]) == pytest.approx(2.0, abs=0.05)    # 2 units, 20 SD


def test_steps_of_fewer_than_half_the_engines_at_one_flight_are_faults_not_a_fleet_change():
    """5 of 12 engines change at flight 10: not a fleet change (no warning, the wear reference
    is the one fitted without any step as nuisance); each of the five is a fault there, the
    seven others raise no alarm."""
    fl, rates, Sigma = fleet(set(range(5)))
    rows, wear, said = judged(fl, Sigma)
    assert said == [] and wear.common == []
    np.testing.assert_array_equal(wear.median, wear_reference(fl, Sigma, DiagnosisConfig()).median)
    np.testing.assert_allclose(wear.median, np.median(rates, axis=0), atol=RATE_TOL)
    for e, rs in rows.items():
        if int(e[1:]) < 5:
            assert all(r.detected and r.cls == "sensor:B" and r.onset == ONSET for r in rs[ONSET + 1:]), e
            assert not any(r.detected for r in rs[:ONSET]), e
        else:
            assert not any(r.detected for r in rs), e


def test_a_fleet_without_a_common_step_has_no_warning_and_the_same_wear():
    fl, rates, Sigma = fleet(set())
    rows, wear, said = judged(fl, Sigma)
    assert said == [] and wear.common == []
    assert not any(r.detected for rs in rows.values() for r in rs)
    np.testing.assert_allclose(wear.median, np.median(rates, axis=0), atol=RATE_TOL)
