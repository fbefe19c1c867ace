"""The turbofan plant (models.turbofan) and its flight simulation (models.flight, pwl simulate).

Every figure is checked against something independent of the code path that produced it: the
acceptance ranges of issue 3, a closed-form ISA / isentropic nozzle, global mass and energy
conservation recomputed from the station values, the closed-form design sizing versus the
iterative off-design solver, finite differences at two step sizes, the eigenvalues of the
perturbation Jacobian versus the simulated step response, and trims versus simulated steady states.
"""
import json
import math
import os

import numpy as np
import pytest

from models import flight
from models import gaspath as gp
from models.turbofan import H_NAMES, PlantError, Turbofan, design_table, operating_points

ALTS = np.linspace(0.0, 12000.0, 5)
MACHS = np.linspace(0.0, 0.85, 5)
NFRS = np.linspace(60.0, 100.0, 9)


@pytest.fixture(scope="module")
def model():
    return Turbofan()


def isa_reference(alt):
    """ISA (independent closed form): T, P at geometric altitude alt (m), troposphere + 11-20 km."""
    g0, R, L = 9.80665, 287.05287, 0.0065
    if alt <= 11000.0:
        T = 288.15 - L * alt
        return T, 101325.0 * (T / 288.15) ** (g0 / (R * L))
    T11 = 216.65
    P11 = 101325.0 * (T11 / 288.15) ** (g0 / (R * L))
    return T11, P11 * math.exp(-g0 * (alt - 11000.0) / (R * T11))


def ideal_nozzle_flow(Pt, Tt, Pamb, A, gam, R):
    """Isentropic convergent-nozzle mass flow (exact choked / unchoked switch)."""
    pr = min(Pt / Pamb, ((gam + 1) / 2) ** (gam / (gam - 1)))
    M2 = 2 / (gam - 1) * (pr ** ((gam - 1) / gam) - 1)
    return A * Pt / math.sqrt(R * Tt) * math.sqrt(gam * M2) * (1 + (gam - 1) / 2 * M2) ** (-(gam + 1) / (2 * (gam - 1)))


def stations(model, p, h=None):
    h = np.zeros(10) if h is None else np.asarray(h, float)
    env = model.environment(p)
    t = model.trim(p, h, env)
    s = model.solve_unbalanced(t["x"], t["u"], h, env)
    return t, s, env


# ---- protocol ------------------------------------------------------------------------------------
def test_protocol_names_units_and_metadata(model):
    assert model.name == "turbofan" and model.time == "continuous"
    assert model.x_names == ("Nf", "Nc") and model.u_names == ("Wf",)
    assert model.y_names == ("Nf", "Nc", "T24", "Ps30", "T30", "T48", "P50", "P15")
    assert model.z_names == ("Fn", "T40", "SmFan", "SmLPC", "SmHPC")
    assert model.h_names == H_NAMES and len(H_NAMES) == 10
    assert model.p_names == ("alt", "Mach", "NfR")
    expected = {"Nf": "rpm", "Nc": "rpm", "Wf": "kg/s", "T24": "K", "Ps30": "Pa", "T30": "K",
                "T48": "K", "P50": "Pa", "P15": "Pa", "Fn": "N", "T40": "K", "SmFan": "%", "SmLPC": "%",
                "SmHPC": "%", "alt": "m", "Mach": "-", "NfR": "%", "T2": "K", "P2": "Pa"}
    for k, v in expected.items():
        assert model.units[k] == v, k
    assert all(model.units[h] == "-" for h in H_NAMES)
    assert np.array_equal(model.h_ref, np.zeros(10))
    assert set(model.perturbation) == set(model.x_names + model.u_names + H_NAMES)
    assert model.sensor_noise == {"Nf": 0.0025, "Nc": 0.0025, "T24": 0.0075, "Ps30": 0.005,
                                  "T30": 0.0075, "T48": 0.0075, "P50": 0.005, "P15": 0.005}
    c = model.correction
    assert (c["theta"], c["delta"], c["T_std"], c["P_std"]) == ("T2", "P2", 288.15, 101325.0)
    ex = c["exponents"]
    for ch in ("Nf", "Nc"):
        assert ex[ch] == (0.5, 0.0)
    for ch in ("T24", "T30", "T48", "T40"):
        assert ex[ch] == (1.0, 0.0)
    for ch in ("Ps30", "P50", "Fn"):
        assert ex[ch] == (0.0, 1.0)
    assert ex["Wf"] == (0.5, 1.0)
    assert model.schedule["NfR"] == ("Nf", True, 100.0 / model.Nf_design)
    assert model.schedule["alt"] == ("alt", False, 1.0) and model.schedule["Mach"] == ("Mach", False, 1.0)
    assert np.array_equal(model.environment([3000.0, 0.5, 80.0]), [3000.0, 0.5, 0.0])
    # parameters are JSON-serialisable and rebuild the same engine
    params = json.loads(json.dumps(model.parameters()))
    assert np.array_equal(Turbofan(**params).C, model.C)
    with pytest.raises(ValueError):
        Turbofan(no_such_parameter=1.0)


@pytest.mark.parametrize("alt,mach,dT", [(0.0, 0.0, 0.0), (10700.0, 0.8, 0.0), (12000.0, 0.85, 0.0),
                                          (3000.0, 0.4, 15.0)])
def test_theta_delta_against_isa(model, alt, mach, dT):
    T0, P0 = isa_reference(alt)
    T0 += dT
    T2 = T0 * (1 + 0.2 * mach ** 2)
    P2 = P0 * (1 + 0.2 * mach ** 2) ** 3.5 * model.spec["inlet_recovery"]
    th, de = model.theta_delta(np.array([alt, mach, dT]))
    assert th == pytest.approx(T2 / 288.15, rel=1e-6)
    assert de == pytest.approx(P2 / 101325.0, rel=1e-5)


def test_schedule_recovers_the_trim_power_setting(model):
    p = np.array([6000.0, 0.6, 83.0])
    t = model.trim(p, None, model.environment(p))
    th, _ = model.theta_delta(model.environment(p))
    ch, corrected, scale = model.schedule["NfR"]
    a = model.correction["exponents"][ch][0]
    assert corrected and scale * t["x"][0] / th ** a == pytest.approx(83.0, rel=1e-12)


# ---- calibration ---------------------------------------------------------------------------------
def test_design_point_figures_within_the_issue_ranges(model):
    (_, p_des), (_, p_to), (_, p_cr) = operating_points(model)
    _, to, _ = stations(model, p_to)
    _, cr, _ = stations(model, p_cr)
    fn = to[gp.S_FN]
    assert 150e3 <= fn <= 200e3
    assert 4.5 <= to[gp.S_BPR] <= 8.0
    opr = to[gp.S_P3] / (isa_reference(0.0)[1] * model.spec["inlet_recovery"])     # P3 / P2
    assert 25.0 <= opr <= 35.0
    assert 1450.0 <= to[gp.S_T4] <= 1750.0
    assert 8.5 <= 1e6 * to[gp.S_WF] / fn <= 11.5            # TSFC, g/(kN s)
    assert p_cr[0] == 10700.0 and p_cr[1] == 0.8
    assert 0.18 <= cr[gp.S_FN] / fn <= 0.28
    assert 15.0 <= 1e6 * cr[gp.S_WF] / cr[gp.S_FN] <= 20.0
    table = design_table(model)
    assert "TSFC" in table and "take-off" in table and "cruise" in table


def test_off_design_solver_reproduces_the_closed_form_design_sizing(model):
    """The design point is sized in closed form; the iterative trim at SLS / NfR 100 % must return it."""
    _, s, _ = stations(model, np.array([0.0, 0.0, 100.0]))
    sp = model.spec
    for idx, val in ((gp.S_W2, sp["W2"]), (gp.S_BPR, sp["BPR"]), (gp.S_PRF, sp["PR_fan"]),
                     (gp.S_PRL, sp["PR_lpc"]), (gp.S_PRH, sp["PR_hpc"]), (gp.S_T4, sp["T40"]),
                     (gp.S_NCRPM, sp["Nc_design"]), (gp.S_ETAF, sp["eta_fan"]),
                     (gp.S_ETAH, sp["eta_hpc"]), (gp.S_ETAHT, sp["eta_hpt"])):
        assert s[idx] == pytest.approx(val, rel=1e-9)
    assert s[gp.S_SMF] == pytest.approx(sp["fan_map"]["SM"], rel=1e-9)
    assert s[gp.S_SMH] == pytest.approx(sp["hpc_map"]["SM"], rel=1e-9)


# ---- trim over the envelope ----------------------------------------------------------------------
def test_trim_converges_on_the_5x5x9_grid(model):
    m = Turbofan()
    failures, n_ok = [], 0
    for a in ALTS:
        for M in MACHS:
            g, wf, fn = None, [], []
            for N in NFRS[::-1]:                 # continuation down the power axis, like the builder
                p = np.array([a, M, N])
                try:
                    g = m.trim(p, None, m.environment(p), guess=g)
                    n_ok += 1
                    wf.append(g["u"][0])
                    fn.append(g["z"][0])
                    assert np.all(np.isfinite(g["y"])) and np.all(np.isfinite(g["z"]))
                except PlantError as e:
                    failures.append(f"alt={a:g} Mach={M:g} NfR={N:g}: {e}")
                    g = None
            # physical check: fuel flow and thrust fall with the power setting
            assert np.all(np.diff(wf) < 0) and np.all(np.diff(fn) < 0), (a, M)
    print(f"trim grid: {n_ok}/225 converged; failures: {failures or 'none'}")
    assert n_ok >= 0.98 * 225, failures


def test_trim_failure_raises_plant_error(model):
    with pytest.raises(PlantError, match="NfR"):
        model.trim(np.array([0.0, 0.0, 400.0]))
    with pytest.raises(PlantError):
        model.trim(np.array([0.0, 0.0, 6.0]))        # far below idle: no converged point
    with pytest.raises(PlantError):
        model.evaluate(np.array([4200.0, 5000.0]), np.array([2.0]), None, np.zeros(3))
    with pytest.raises(PlantError):
        model.evaluate(np.array([-1.0, 14000.0]), np.array([1.0]), None, np.zeros(3))
    with pytest.raises(PlantError):
        model.evaluate(np.array([4000.0, 14000.0]), np.array([np.nan]), None, np.zeros(3))


POINTS = [np.array([0.0, 0.0, 96.0]), np.array([10700.0, 0.8, 100.0]), np.array([12000.0, 0.85, 60.0]),
          np.array([0.0, 0.85, 60.0]), np.array([6000.0, 0.4, 75.0])]


@pytest.mark.parametrize("p", POINTS, ids=lambda p: f"{p[0]:g}m-M{p[1]:g}-{p[2]:g}")
def test_trim_conserves_mass_and_energy_and_balances_shafts(model, p):
    h = np.linspace(-0.02, 0.0, 10)
    t, s, env = stations(model, p, h)
    sp = model.spec
    C = model.C
    W2, Wf = s[gp.S_W2], s[gp.S_WF]
    W25 = s[gp.S_W25]
    Wcust = sp["bleed_customer"] * W25
    # recompute the nozzle flows independently of the solver's residual bookkeeping
    _, P0 = isa_reference(p[0])
    assert s[gp.S_WNB] + s[gp.S_WNC] + Wcust == pytest.approx(W2 + Wf, rel=1e-9)
    # global energy: inflow enthalpy + fuel heat = nozzle enthalpy flows + bleed + shaft extraction
    # + mechanical losses (enthalpy h = cp (T - Tref) per stream)
    cpa, cpg, Tref = sp["cp_air"], sp["cp_gas"], sp["T_ref"]
    e_in = W2 * cpa * (s[gp.S_T2] - Tref) + sp["eta_burner"] * Wf * sp["LHV"]
    e_out = (s[gp.S_WNB] * cpa * (s[gp.S_T13] - Tref) + s[gp.S_WNC] * cpg * (s[gp.S_T50] - Tref)
             + Wcust * cpa * (s[gp.S_T3] - Tref) + sp["P_ext_lp"] + sp["P_ext_hp"]
             + (1 - sp["eta_mech_lp"]) * s[gp.S_PWLT] + (1 - sp["eta_mech_hp"]) * s[gp.S_PWHT])
    assert abs(e_in - e_out) / (Wf * sp["LHV"]) < 1e-8
    # shaft power balances and state derivatives at trim
    lp = sp["eta_mech_lp"] * s[gp.S_PWLT] - s[gp.S_PWF] - s[gp.S_PWL] - sp["P_ext_lp"]
    hp = sp["eta_mech_hp"] * s[gp.S_PWHT] - s[gp.S_PWH] - sp["P_ext_hp"]
    assert abs(lp) / s[gp.S_PWLT] < 1e-8 and abs(hp) / s[gp.S_PWHT] < 1e-8
    f, y, z = model.evaluate(t["x"], t["u"], h, env)
    assert np.all(np.abs(f) / t["x"] < 1e-8)              # rpm/s relative to rpm (per second)
    np.testing.assert_allclose(y, t["y"], rtol=1e-8)
    np.testing.assert_allclose(z, t["z"], rtol=1e-8, atol=1e-8)
    # the nozzle flows agree with an exact isentropic nozzle where the pressure ratio is clear of
    # the smoothed choking band (the model blends choked/unchoked over a few eps)
    crit = {"air": 1.8929, "gas": ((C[gp.GAMG] + 1) / 2) ** (C[gp.GAMG] / (C[gp.GAMG] - 1))}
    for P, T, W, A, gam, R, kind in ((s[gp.S_P17], s[gp.S_T13], s[gp.S_WNB], C[gp.A_BYP], C[gp.GAMA], C[gp.RA], "air"),
                                     (s[gp.S_P7], s[gp.S_T50], s[gp.S_WNC], C[gp.A_CORE], C[gp.GAMG], C[gp.RG], "gas")):
        if abs(P / P0 - crit[kind]) > 6 * sp["nozzle_eps"]:
            assert W == pytest.approx(ideal_nozzle_flow(P, T, P0, A, gam, R), rel=2e-3)


def test_evaluate_does_not_depend_on_the_warm_start(model):
    p = np.array([5000.0, 0.5, 85.0])
    env = model.environment(p)
    h = np.full(10, -0.01)
    t = model.trim(p, h, env)
    x = t["x"] * np.array([1.004, 0.997])
    u = t["u"] * 1.02
    cold = Turbofan()                         # no cache: starts from its own trim + continuation
    r1 = cold.evaluate(x, u, h, env)
    far = model.trim(np.array([12000.0, 0.85, 60.0]))       # move the warm start far away
    model.evaluate(far["x"] * 1.01, far["u"], None, np.array([12000.0, 0.85, 0.0]))
    r2 = model.evaluate(x, u, h, env)
    for a, b in zip(r1, r2):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)


# ---- health influence ----------------------------------------------------------------------------
@pytest.mark.parametrize("p", [np.array([0.0, 0.0, 96.0]), np.array([10700.0, 0.8, 100.0])],
                         ids=["take-off", "cruise"])
def test_influence_signs(model, p):
    env = model.environment(p)
    t0 = model.trim(p, None, env)
    d = {}
    for j, name in enumerate(H_NAMES):
        h = np.zeros(10)
        h[j] = -0.01
        t = model.trim(p, h, env, guess=t0)
        d[name] = {"Wf": t["u"][0] / t0["u"][0] - 1,
                   **{k: t["y"][i] / t0["y"][i] - 1 for i, k in enumerate(model.y_names)},
                   **{k: t["z"][i] - t0["z"][i] for i, k in enumerate(model.z_names)}}
        assert t["y"][0] == pytest.approx(t0["y"][0], rel=1e-12)      # fixed corrected fan speed
    for c in ("fan", "lpc", "hpc", "hpt", "lpt"):
        e = d[c + "_eff"]
        assert e["Wf"] > 0 and e["T48"] > 0 and e["T40"] > 0, c    # efficiency losses cost fuel, heat
    assert d["hpt_eff"]["T48"] > 0.003                              # ~ +10 K EGT per -1 % HPT efficiency
    assert d["fan_flow"]["Fn"] < 0                                  # less fan flow: less thrust
    assert d["hpt_flow"]["Ps30"] > 0 and d["hpt_flow"]["SmHPC"] < 0   # HPT throat closes: HPC back-pressured
    assert d["hpc_flow"]["Nc"] > 0                                  # the core spins up to pass its flow
    assert d["lpt_flow"]["P50"] < 0 and d["lpt_flow"]["Nc"] < 0     # more LPT work per unit flow


# ---- smoothness of the unbalanced solve ----------------------------------------------------------
def test_central_differences_agree_at_two_step_sizes(model):
    """dy/dv, dz/dv, df/dv at relative steps 1e-4 and 1e-5 (absolute for health) agree to 1e-4,
    relative to the larger of |derivative| and 5 % of |output| / |input| (outputs insensitive to an
    input are compared on that scale)."""
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(5):
        p = np.array([rng.uniform(0, 12000), rng.uniform(0, 0.85), rng.uniform(60, 100)])
        env = model.environment(p)
        h = rng.uniform(-0.03, 0.0, 10)
        t = model.trim(p, h, env)
        base = np.concatenate([t["x"], t["u"], h])

        def F(v):
            f, y, z = model.evaluate(v[:2], v[2:3], v[3:], env)
            return np.concatenate([f, y, z])

        out_scale = np.abs(F(base))
        out_scale[:2] = t["x"]            # derivatives (rpm/s) on the scale of the speeds per second
        out_scale[-3:] = 100.0            # stall margins (%) on the scale of the pressure ratios
        for j in range(13):
            in_scale = abs(base[j]) if j < 3 else 1.0
            ds = []
            for rel in (1e-4, 1e-5):
                e = np.zeros(13)
                e[j] = rel * in_scale
                ds.append((F(base + e) - F(base - e)) / (2 * e[j]))
            den = np.maximum(np.abs(ds[1]), 0.05 * out_scale / in_scale)
            worst = max(worst, float(np.max(np.abs(ds[0] - ds[1]) / den)))
    print(f"worst relative disagreement of central differences: {worst:.2e}")
    assert worst < 1e-4


# ---- dynamics ------------------------------------------------------------------------------------
@pytest.mark.parametrize("p", [np.array([0.0, 0.0, 80.0]), np.array([10700.0, 0.8, 80.0])],
                         ids=["SLS-80%", "cruise-80%"])
def test_fuel_step_time_constants(model, p):
    env = model.environment(p)
    t = model.trim(p, None, env)
    # eigenvalues of the perturbation Jacobian A = df/dx (central differences)
    A = np.zeros((2, 2))
    for j in range(2):
        dx = np.zeros(2)
        dx[j] = 1e-3 * t["x"][j]
        A[:, j] = (model.evaluate(t["x"] + dx, t["u"], None, env)[0]
                   - model.evaluate(t["x"] - dx, t["u"], None, env)[0]) / (2 * dx[j])
    lam = np.linalg.eigvals(A)
    assert np.all(lam.real < 0)
    tau = np.sort(-1.0 / lam.real)
    assert 0.3 <= tau[0] and tau[1] <= 3.0, tau
    # simulated 5 % fuel step (open loop) settles on the trim that burns 1.05 Wf
    n = int(25.0 / flight.DT)
    wf = np.full(n, 1.05 * t["u"][0])
    r = flight.open_loop(model, p, wf)
    from scipy.optimize import brentq
    nfr = brentq(lambda N: model.trim(np.array([p[0], p[1], N]), None, env)["u"][0] - 1.05 * t["u"][0],
                 p[2], p[2] + 8.0, xtol=1e-10)
    t1 = model.trim(np.array([p[0], p[1], nfr]), None, env)
    assert r["Nf"][-1] == pytest.approx(t1["x"][0], rel=2e-5)
    assert r["Nc"][-1] == pytest.approx(t1["x"][1], rel=2e-5)
    # 63 % rise times of both spools lie between the two time constants' bounds
    for k in ("Nf", "Nc"):
        d = r[k] - r[k][0]
        t63 = r["time"][np.argmax(d >= 0.632 * (t1["x"][0 if k == "Nf" else 1] - r[k][0]))]
        assert 0.3 <= t63 <= 3.0, (k, t63)


# ---- flight simulation ---------------------------------------------------------------------------
SHORT = {"taxi_out": 20.0, "takeoff": 30.0, "climb": 60.0, "cruise": 45.0, "descent": 30.0,
         "approach": 20.0, "taxi_in": 15.0}


@pytest.fixture(scope="module")
def sim(model):
    prof = flight.flight_profile("short", SHORT, cruise_alt=3000.0, cruise_mach=0.5, dither=False)
    health = flight.drift({"hpt_eff": -0.005}, {"hpt_eff": -0.015, "fan_flow": -0.01}, prof["time"])
    return prof, health, flight.simulate(model, prof, health=health, seed=3)


def test_simulation_channels_noise_and_health(model, sim):
    prof, health, r = sim
    need = ["alt", "Mach", "T2", "P2", "Wf", "Nf", "Nc", "T24", "Ps30", "T30", "T48", "P50"]
    assert all(k in r["channels"] for k in need)
    for k in need:
        assert r["units"][k] == model.units[k]
    for k in list(model.y_names) + list(model.z_names) + list(H_NAMES):
        assert k in r["truth"] and r["truth_units"][k] == model.units[k]
    n = r["time"].size
    assert np.allclose(np.diff(r["time"]), flight.DT)
    for j, k in enumerate(H_NAMES):
        np.testing.assert_array_equal(r["truth"][k], health[:, j])
    # noise: relative one-sigma as configured (n ~ 14 000 samples: 3 % statistical tolerance)
    for k, sig in model.sensor_noise.items():
        rel = r["channels"][k] / r["truth"][k] - 1
        assert np.std(rel) == pytest.approx(sig, rel=0.03), k
        assert abs(np.mean(rel)) < 4 * sig / math.sqrt(n)
    # seeded: same seed, same noise
    r2 = flight.simulate(model, prof, health=health, seed=3)
    np.testing.assert_array_equal(r2["channels"]["T48"], r["channels"]["T48"])
    assert not np.array_equal(flight.simulate(model, prof, health=health, seed=4)["channels"]["T48"],
                              r["channels"]["T48"])


def test_simulated_steady_cruise_matches_the_trim(model, sim):
    """After 45 s of steady cruise the closed loop sits on the trim at the demanded corrected speed."""
    prof, health, r = sim
    k = np.flatnonzero(prof["phase"] == 3)[-1]
    tr = r["truth"]
    env = np.array([prof["alt"][k], prof["Mach"][k], 0.0])
    nfr = tr["NfR_demand"][k]
    t = model.trim(np.array([env[0], env[1], nfr]), health[k], env)
    assert tr["Nf"][k] == pytest.approx(t["x"][0], rel=2e-5)
    assert tr["Wf"][k] == pytest.approx(t["u"][0], rel=1e-4)
    for j, name in enumerate(model.y_names):
        assert tr[name][k] == pytest.approx(t["y"][j], rel=1e-4), name
    assert tr["Fn"][k] == pytest.approx(t["z"][0], rel=1e-4)
    # the profile stays inside the trim grid's power range
    nfr_all = 100 * tr["Nf"] / np.sqrt(tr["T2"] / 288.15) / model.Nf_design
    assert nfr_all.min() > 59.0 and nfr_all.max() < 100.5


def test_profile_presets():
    p = flight.flight_profile("long", dither=False)
    assert p["time"][-1] == pytest.approx(3600.0)
    assert p["alt"].max() == pytest.approx(10700.0) and p["Mach"].max() == pytest.approx(0.8)
    assert p["alt"][0] == 0.0 and p["alt"][-1] == 0.0 and p["Mach"][-1] == pytest.approx(0.0)
    s = flight.flight_profile("short")
    assert 600.0 <= s["time"][-1] <= 900.0
    with pytest.raises(ValueError):
        flight.flight_profile("short", {"cruise": -1.0})
    with pytest.raises(ValueError):
        flight.flight_profile("short", {"holding": 10.0})


def test_pwl_simulate_writes_a_readable_log(tmp_path, model):
    from pwl.cli import main
    from pwl.logs import read_log

    dur = "taxi_out=5,takeoff=15,climb=20,cruise=5,descent=10,approach=5,taxi_in=5"
    out = tmp_path / "f.h5"
    assert main(["simulate", "-o", str(out), "--durations", dur, "--cruise-alt", "1500",
                 "--cruise-mach", "0.4", "--health", "fan_eff=-0.02,hpt_eff=-0.01", "--seed", "5",
                 "--compact"]) == 0
    log = read_log(out)
    for k in ("alt", "Mach", "T2", "P2", "Wf") + model.y_names:
        assert log.units[k] == model.units[k]
    assert np.all(log.truth["fan_eff"] == np.float32(-0.02))
    assert set(H_NAMES) <= set(log.truth) and set(model.z_names) <= set(log.truth)
    csv = tmp_path / "f.csv"
    assert main(["simulate", "-o", str(csv), "--durations", dur, "--cruise-alt", "1500",
                 "--cruise-mach", "0.4", "--noise-scale", "0"]) == 0
    log2 = read_log(csv)
    np.testing.assert_allclose(log2.channels["T48"], log2.truth["T48"], rtol=1e-15)
    assert main(["simulate", "-o", str(csv), "--health", "bogus=1"]) == 2


# ---- plausible ranges of the log channels -----------------------------------------------------------
def _outside(ranges, values: dict) -> list[str]:
    """Channels of ``values`` (name -> array) with a value outside its range: 'name: min..max'."""
    out = []
    for c, v in values.items():
        lo, hi = ranges[c]
        v = np.asarray(v, dtype=np.float64)
        if not np.all((v >= lo) & (v <= hi)):
            out.append(f"{c}: {v.min():g}..{v.max():g} outside {lo:g}..{hi:g}")
    return out


def test_ranges_hold_the_shipped_flights(model):
    from linearize.plant import log_channels
    from pwl.logs import read_log

    channels = list(log_channels(model))
    assert set(model.ranges) == set(channels) | set(H_NAMES)   # every log channel and health parameter
    for name in ("flight_new.h5", "flight_degraded.h5"):
        path = os.path.join(os.path.dirname(__file__), "..", "data", name)
        log = read_log(path)
        assert not _outside(model.ranges, {c: log.channels[c] for c in channels}), path


def test_ranges_hold_the_demo_grid_on_hot_and_cold_days_and_catch_unit_mistakes(model):
    """Trims at every node of the demo spec's trim grid (standard day), and at its corners and
    middles on days ISA-30 K and ISA+30 K."""
    from linearize.spec import BuildSpec

    grid = BuildSpec.load(os.path.join(os.path.dirname(__file__), "..", "specs", "turbofan_demo.toml")).trim_grid
    points = [(p, 0.0) for p in grid.nodes()]
    points += [(np.array([alt, mach, nfr]), dT) for alt in (0.0, 6000.0, 12000.0) for mach in (0.0, 0.4, 0.85)
               for nfr in (60.0, 80.0, 100.0) for dT in (-30.0, 30.0)]
    values = {}
    for p, dT in points:
        env = np.array([p[0], p[1], dT])
        t = model.trim(p, None, env)
        T2, P2 = model.inlet(env)
        row = {"Wf": t["u"][0], **dict(zip(model.y_names, t["y"])), "alt": p[0], "Mach": p[1], "T2": T2, "P2": P2}
        for c, v in row.items():
            values.setdefault(c, []).append(v)
    assert not _outside(model.ranges, values)
    # the same values in a usual wrong unit fall outside
    wrong = {"Ps30": np.array(values["Ps30"]) / 1e3, "P15": np.array(values["P15"]) / 1e5,
             "P2": np.array(values["P2"]) / 6894.76, "T2": np.array(values["T2"]) - 273.15,
             "Wf": np.array(values["Wf"]) * 1e3, "Nf": 100.0 * np.array(values["Nf"]) / model.Nf_design}
    for c, v in wrong.items():
        lo, hi = model.ranges[c]
        assert np.all((v < lo) | (v > hi)), c
