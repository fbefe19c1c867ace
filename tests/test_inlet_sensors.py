"""Biases of the inlet sensors that theta and delta come from (T2, P2): their signature columns
(pwl.fleet.signatures, taken numerically) against the deviations of the nonlinear plant's own
trims read through a biased sensor, and their diagnosis."""
import numpy as np
import pytest

from linearize import plant as proto
from models.turbofan import Turbofan
from pwl.database import GainDatabase
from pwl.demo_data import demo_paths
from pwl.fleet.signatures import Signatures

REGIMES = (((0.0, 0.0, 80.0), -5.0), ((9000.0, 0.78, 90.0), 10.0))   # ground idle-ish, cruise; day K


def snapshot(db, plant, p, dT):
    """Raw channel means of the plant's trim at p on a day dT K off ISA (a healthy engine)."""
    p = np.asarray(p)
    env = proto.day_environment(plant, p, dT)
    t = plant.trim(p, None, env)
    T2, P2 = plant.inlet(env)
    return dict(zip(db.names["y"], t["y"])) | dict(zip(db.names["u"], t["u"])) | {"alt": p[0], "Mach": p[1],
                                                                                  "T2": T2, "P2": P2}


@pytest.mark.parametrize("channel, bias", [("T2", 3.0), ("P2", -600.0)])
def test_an_inlet_sensor_bias_is_its_column_and_no_component(channel, bias):
    """The deviations a biased T2 (+3 K) or P2 (-600 Pa) reading makes of a healthy engine's
    snapshot: its column times the bias within 5 % (the bias fitted on its column within 3 %), in
    both regimes; the best single component (two health parameters) leaves at least 10 % of the
    two regimes' change unexplained (T2 alone: 50 %; P2 at cruise alone is close to a
    component's, 1.5 %: the ground regime tells them apart)."""
    db = GainDatabase.open(demo_paths()[0])
    sig, plant = Signatures(db), Turbofan()
    col_j = sig.columns.index(f"sensor:{channel}")
    comps = {}
    for j, c in enumerate(sig.columns):
        if not c.startswith("sensor:"):
            comps.setdefault(c.rsplit("_", 1)[0], []).append(j)
    deltas, S = [], []
    for p, dT in REGIMES:
        mean = snapshot(db, plant, p, dT)
        base = sig.at(mean, {})
        delta = sig.at(dict(mean, **{channel: mean[channel] + bias}), {}).d - base.d
        col = base.S[:, col_j]
        assert col @ delta / (col @ col) == pytest.approx(bias, rel=0.03)
        assert np.linalg.norm(delta - col * bias) < 0.05 * np.linalg.norm(delta)
        deltas.append(delta)
        S.append(base.S)
    delta, S = np.concatenate(deltas), np.vstack(S)
    left = min(np.linalg.norm(delta - S[:, js] @ np.linalg.lstsq(S[:, js], delta, rcond=None)[0])
               for js in comps.values())
    assert left > 0.1 * np.linalg.norm(delta)


@pytest.mark.parametrize("channel, bias", [("T2", 3.0), ("P2", -600.0)])
def test_an_inlet_sensor_column_against_the_plant(channel, bias):
    """Independent of the database: what a biased inlet reading makes of a healthy engine's
    deviations, from the nonlinear plant alone. The runtime, reading T2 + b (or P2 + b), takes the
    operating point NfR' = Nf / sqrt(theta') and the day dT' (pwl.airdata.ambient_offset) and
    compares the measurements corrected with theta', delta' against the corrected trim there: the
    plant's own trim at (alt, Mach, NfR') on that day. The change of those deviations from b = 0 to
    b (the interpolation error cancels) is the signature column times b within 10 % of its size
    (measured 0.5-1.3 %: the database's linear model and ambient terms against the plant),
    in both regimes."""
    from pwl.airdata import ambient_offset

    db = GainDatabase.open(demo_paths()[0])
    sig, plant = Signatures(db), Turbofan()
    corr = db.correction
    ex = {n: corr.exponents[k][j] for k in "yu" for j, n in enumerate(db.names[k])}

    def deviations(mean):
        th, de = mean["T2"] / corr.T_std, mean["P2"] / corr.P_std
        nfr = mean["Nf"] / (plant.Nf_design / 100.0) / np.sqrt(th)
        day = float(ambient_offset(mean["T2"], mean["alt"], mean["Mach"]))
        env = np.array([mean["alt"], mean["Mach"], day])
        t = plant.trim(np.array([mean["alt"], mean["Mach"], nfr]), None, env)
        pth, pde = plant.theta_delta(env)
        trim = dict(zip(db.names["y"], t["y"])) | dict(zip(db.names["u"], t["u"]))
        # the inlet pressure against the plant's at the air data (Signatures.air)
        air = [mean["P2"] / plant.inlet(env)[1] - 1.0] if sig.air else []
        return np.array([(mean[c] / (th ** ex[c][0] * de ** ex[c][1]))
                         / (trim[c] / (pth ** ex[c][0] * pde ** ex[c][1])) - 1.0
                         for c in sig.sensed] + air)

    for p, dT in REGIMES:
        mean = snapshot(db, plant, p, dT)
        want = deviations(dict(mean, **{channel: mean[channel] + bias})) - deviations(mean)
        got = sig.at(mean, {}).S[:, sig.columns.index(f"sensor:{channel}")] * bias
        assert np.linalg.norm(got - want) < 0.1 * np.linalg.norm(want), (p, got, want)
