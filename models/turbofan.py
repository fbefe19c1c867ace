"""Two-spool separate-flow high-bypass turbofan: a smooth, fast component-level model.

Satisfies the Plant protocol of docs/plant-protocol.md (names, units, ``environment``, ``trim``,
``evaluate``, ``parameters``, correction exponents, schedule). The physics, assumptions and the
measured figures are in docs/turbofan.md; the numba kernels are in :mod:`models.gaspath`.

``python -m models.turbofan`` prints the design-point table (take-off and cruise).
"""
from __future__ import annotations

import math

import numpy as np

from . import gaspath as gp


class PlantError(RuntimeError):
    """A solve that did not converge (or inputs outside the model's valid region)."""


class HealthError(ValueError):
    """A health parameter the model does not have, or a value outside :data:`H_RANGE`."""


#: the design specification (sea-level static ISA take-off, corrected fan speed 100 %)
DEFAULTS = {
    # design cycle
    "W2": 540.0,            # inlet mass flow, kg/s
    "BPR": 5.0,             # bypass ratio
    "PR_fan": 1.75, "PR_lpc": 1.9, "PR_hpc": 9.8,
    "eta_fan": 0.90, "eta_lpc": 0.90, "eta_hpc": 0.87, "eta_hpt": 0.90, "eta_lpt": 0.92,
    "T40": 1700.0,          # combustor exit temperature at the design point, K
    "Nf_design": 4200.0,    # LP spool speed (= corrected fan speed at SLS ISA), rpm
    "Nc_design": 14500.0,   # HP spool speed, rpm
    # thermodynamics
    "cp_air": 1004.5, "gamma_air": 1.4, "cp_gas": 1150.0, "gamma_gas": 1.3326,
    "LHV": 42.8e6, "eta_burner": 0.999, "dp_burner": 0.04, "T_ref": 298.15,
    # losses, bleeds, loads
    "inlet_recovery": 0.995, "dp_bypass_duct": 0.015, "dp_lpc_hpc_duct": 0.015,
    "dp_core_exit": 0.01, "bleed_customer": 0.015, "cool_hpt": 0.05, "cool_lpt": 0.03,
    "eta_mech_lp": 0.995, "eta_mech_hp": 0.995, "P_ext_lp": 0.0, "P_ext_hp": 150e3,
    "Cv_bypass": 0.985, "Cv_core": 0.985, "nozzle_eps": 0.08, "Ps30_ratio": 0.96,
    "J_lp": 100.0, "J_hp": 20.0,       # shaft inertias, kg m^2
    # compressor maps: design beta, design stall margin (%), flow/PR speed exponents, line shape
    "fan_map": {"beta": 0.5, "SM": 20.0, "aw": 1.1, "ap": 1.9, "s1": 0.12, "qs": 1.5,
                "c2_c1": 1.0, "n_pk": 0.95, "ke_n": 0.6, "ke_b": 0.25},
    "lpc_map": {"beta": 0.5, "SM": 22.0, "aw": 1.5, "ap": 1.5, "s1": 0.12, "qs": 1.5,
                "c2_c1": 1.0, "n_pk": 0.95, "ke_n": 0.8, "ke_b": 0.25},
    "hpc_map": {"beta": 0.5, "SM": 25.0, "aw": 2.5, "ap": 1.5, "s1": 0.08, "qs": 1.5,
                "c2_c1": 1.0, "n_pk": 0.95, "ke_n": 1.0, "ke_b": 0.25},
    "hpt_map": {"a_phi": 4.0, "e": 1.0},
    "lpt_map": {"a_phi": 4.0, "e": 1.0},
    # the operating points of the design table
    "takeoff_NfR": 96.0,
    "cruise_NfR": 100.0,
}

X_NAMES = ("Nf", "Nc")
U_NAMES = ("Wf",)
Y_NAMES = ("Nf", "Nc", "T24", "Ps30", "T30", "T48", "P50", "P15")
Z_NAMES = ("Fn", "T40", "SmFan", "SmLPC", "SmHPC")
H_NAMES = ("fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff", "hpc_flow",
           "hpt_eff", "hpt_flow", "lpt_eff", "lpt_flow")
P_NAMES = ("alt", "Mach", "NfR")
#: the range of every health fraction (-0.02 = 2 % loss): beyond 10 % a component has failed
#: rather than degraded, far outside what its map represents
H_RANGE = (-0.1, 0.1)
UNITS = {"Nf": "rpm", "Nc": "rpm", "Wf": "kg/s", "T24": "K", "Ps30": "Pa", "T30": "K", "T48": "K",
         "P50": "Pa", "P15": "Pa", "Fn": "N", "T40": "K", "SmFan": "%", "SmLPC": "%", "SmHPC": "%",
         **{h: "-" for h in H_NAMES}, "alt": "m", "Mach": "-", "NfR": "%", "T2": "K", "P2": "Pa",
         "dTamb": "K", "TRA": "%", "NfR_demand": "%"}
#: plausible range of every log channel the estimator reads, in UNITS (spool speeds: see
#: SPEED_RANGE). Wide enough for the trim grid of specs/turbofan_demo.toml on days from ISA-30 K to
#: ISA+30 K and for the shipped flights; narrow enough that the usual unit mistakes fall outside:
#: pressures in kPa, hPa, bar or psi, T2 in degC or degF, fuel flow in g/s or kg/h, speeds in %.
RANGES = {"Wf": (0.01, 6.0), "T24": (150.0, 700.0), "T30": (150.0, 1200.0), "T48": (150.0, 1700.0),
          "Ps30": (5e3, 1e7), "P50": (3e3, 5e5), "P15": (3e3, 5e5), "T2": (170.0, 380.0),
          "P2": (5e3, 2e5), "alt": (-500.0, 15000.0), "Mach": (0.0, 1.0)}
#: plausible range of the spool speeds Nf, Nc: fractions of their design speeds
SPEED_RANGE = (0.1, 1.3)
# station indices of y and z in the station vector
Y_IDX = np.array([gp.S_NFRPM, gp.S_NCRPM, gp.S_T24, gp.S_PS3, gp.S_T3, gp.S_T48, gp.S_P50, gp.S_P17])
Z_IDX = np.array([gp.S_FN, gp.S_T4, gp.S_SMF, gp.S_SML, gp.S_SMH])

TOL = 1e-12          # max |residual| (relative flow / power errors) for convergence
MAXIT = 60


def check_health(health: dict) -> None:
    """Raise :class:`HealthError` naming the first unknown name or out-of-range value of
    ``health`` (name -> fraction, or an array of fractions over time)."""
    lo, hi = H_RANGE
    for name, v in health.items():
        if name not in H_NAMES:
            raise HealthError(f"unknown health parameter {name!r}; known: {', '.join(H_NAMES)}")
        v = np.asarray(v, dtype=np.float64)
        bad = v[~((v >= lo) & (v <= hi))]  # NaN is out of range too
        if bad.size:
            raise HealthError(f"health parameter {name} = {bad[0]:g} is outside the allowed range "
                              f"{lo:g}..{hi:g} (fractions: -0.02 is a 2 % loss)")


def _merge(defaults, overrides):
    out = {}
    for k, v in defaults.items():
        if isinstance(v, dict):
            o = overrides.get(k, {}) if overrides else {}
            bad = set(o) - set(v)
            if bad:
                raise ValueError(f"unknown keys {sorted(bad)} in {k!r}; known: {sorted(v)}")
            out[k] = {**v, **o}
        else:
            out[k] = float(overrides.get(k, v)) if overrides and k in overrides else v
    return out


def design_constants(spec: dict):
    """Size the engine at the design point: fill the constant vector C and the design unknowns.

    Returns (C, v_design (8,), design station vector). Every off-design quantity is computed by the
    same kernels, so the off-design solve reproduces the design point exactly (a test checks it).
    """
    C = np.zeros(gp.NC_CONST)
    cpa, ga, cpg, gg = spec["cp_air"], spec["gamma_air"], spec["cp_gas"], spec["gamma_gas"]
    C[gp.CPA], C[gp.GAMA], C[gp.CPG], C[gp.GAMG] = cpa, ga, cpg, gg
    C[gp.RA] = cpa * (ga - 1.0) / ga
    C[gp.RG] = cpg * (gg - 1.0) / gg
    C[gp.LHV], C[gp.ETA_B], C[gp.DP_B], C[gp.TREF] = spec["LHV"], spec["eta_burner"], spec["dp_burner"], spec["T_ref"]
    C[gp.REC], C[gp.DP_BYP], C[gp.DP_DUCT], C[gp.DP_CORE] = (spec["inlet_recovery"], spec["dp_bypass_duct"],
                                                              spec["dp_lpc_hpc_duct"], spec["dp_core_exit"])
    C[gp.F_CUST], C[gp.F_HPT], C[gp.F_LPT] = spec["bleed_customer"], spec["cool_hpt"], spec["cool_lpt"]
    C[gp.ETAM_LP], C[gp.ETAM_HP] = spec["eta_mech_lp"], spec["eta_mech_hp"]
    C[gp.PEXT_LP], C[gp.PEXT_HP] = spec["P_ext_lp"], spec["P_ext_hp"]
    C[gp.J_LP], C[gp.J_HP] = spec["J_lp"], spec["J_hp"]
    C[gp.CV_BYP], C[gp.CV_CORE], C[gp.NOZ_EPS] = spec["Cv_bypass"], spec["Cv_core"], spec["nozzle_eps"]
    Nf, Nc = spec["Nf_design"], spec["Nc_design"]
    C[gp.NF_D], C[gp.NC_D] = Nf, Nc
    ka, kg = (ga - 1) / ga, (gg - 1) / gg
    Tref = spec["T_ref"]
    amb = np.empty(5)
    gp.ambient(0.0, 0.0, 0.0, C, amb)
    T2, P2, P0 = amb[0], amb[1], amb[2]
    W2, bpr = spec["W2"], spec["BPR"]
    # fan
    T13 = T2 * (1 + (spec["PR_fan"] ** ka - 1) / spec["eta_fan"])
    P13 = P2 * spec["PR_fan"]
    Pwf = W2 * cpa * (T13 - T2)
    Wbyp, Wcore = W2 * bpr / (1 + bpr), W2 / (1 + bpr)
    P17 = P13 * (1 - C[gp.DP_BYP])
    wpa, _, ok = gp.nozzle(Wbyp, P17, T13, P0, 1.0, ga, cpa, C[gp.RA], 1.0, C[gp.NOZ_EPS])
    C[gp.A_BYP] = Wbyp / wpa
    # LPC
    C[gp.NLPC_D] = Nf / math.sqrt(T13 / gp.T_STD)
    T24 = T13 * (1 + (spec["PR_lpc"] ** ka - 1) / spec["eta_lpc"])
    P24 = P13 * spec["PR_lpc"]
    Pwl = Wcore * cpa * (T24 - T13)
    # HPC
    P25 = P24 * (1 - C[gp.DP_DUCT])
    C[gp.NHPC_D] = Nc / math.sqrt(T24 / gp.T_STD)
    T3 = T24 * (1 + (spec["PR_hpc"] ** ka - 1) / spec["eta_hpc"])
    P3 = P25 * spec["PR_hpc"]
    Pwh = Wcore * cpa * (T3 - T24)
    # HPC exit area from the design static/total pressure ratio
    q3 = (1 - spec["Ps30_ratio"]) * P3
    C[gp.A3] = Wcore * math.sqrt(C[gp.RA] * T3 / (2 * P3 * q3))
    W3 = Wcore * (1 - C[gp.F_CUST] - C[gp.F_HPT] - C[gp.F_LPT])
    # burner: fuel flow for the design T40
    T4 = spec["T40"]
    Wf = W3 * (cpg * (T4 - Tref) - cpa * (T3 - Tref)) / (C[gp.ETA_B] * C[gp.LHV] - cpg * (T4 - Tref))
    C[gp.WF_D], C[gp.W2_D] = Wf, W2
    P4 = P3 * (1 - C[gp.DP_B])
    W4 = W3 + Wf
    # HPT: work for the HPC and the HP extraction
    Pwht = (Pwh + C[gp.PEXT_HP]) / C[gp.ETAM_HP]
    T45 = T4 - Pwht / (W4 * cpg)
    pih = (1 - (1 - T45 / T4) / spec["eta_hpt"]) ** (-1 / kg)
    C[gp.NHPT_D] = Nc / math.sqrt(T4 / gp.T_STD)
    Wc4 = W4 * math.sqrt(T4 / gp.T_STD) / (P4 / gp.P_STD)
    for o, m, pi, eta in ((gp.HPT, spec["hpt_map"], pih, spec["eta_hpt"]),):
        C[o + gp.T_APHI], C[o + gp.T_ETA], C[o + gp.T_ET] = m["a_phi"], eta, m["e"]
        C[o + gp.T_QD] = 1 - pi ** (-kg)
        C[o + gp.T_CAP] = Wc4 / math.sqrt(1 - pi ** (-m["a_phi"]))
    P45 = P4 / pih
    Wch = C[gp.F_HPT] * Wcore
    W48 = W4 + Wch
    T48 = Tref + (W4 * cpg * (T45 - Tref) + Wch * cpa * (T3 - Tref)) / (W48 * cpg)
    # LPT: work for fan, LPC and the LP extraction
    Pwlt = (Pwf + Pwl + C[gp.PEXT_LP]) / C[gp.ETAM_LP]
    T5 = T48 - Pwlt / (W48 * cpg)
    pil = (1 - (1 - T5 / T48) / spec["eta_lpt"]) ** (-1 / kg)
    C[gp.NLPT_D] = Nf / math.sqrt(T48 / gp.T_STD)
    Wc48 = W48 * math.sqrt(T48 / gp.T_STD) / (P45 / gp.P_STD)
    m = spec["lpt_map"]
    C[gp.LPT + gp.T_APHI], C[gp.LPT + gp.T_ETA], C[gp.LPT + gp.T_ET] = m["a_phi"], spec["eta_lpt"], m["e"]
    C[gp.LPT + gp.T_QD] = 1 - pil ** (-kg)
    C[gp.LPT + gp.T_CAP] = Wc48 / math.sqrt(1 - pil ** (-m["a_phi"]))
    P5 = P45 / pil
    Wcl = C[gp.F_LPT] * Wcore
    W5 = W48 + Wcl
    T50 = Tref + (W48 * cpg * (T5 - Tref) + Wcl * cpa * (T3 - Tref)) / (W5 * cpg)
    P7 = P5 * (1 - C[gp.DP_CORE])
    wpa, _, ok2 = gp.nozzle(W5, P7, T50, P0, 1.0, gg, cpg, C[gp.RG], 1.0, C[gp.NOZ_EPS])
    if not (ok and ok2):
        raise PlantError("design point: a nozzle pressure ratio is below 1; check the design specification")
    C[gp.A_CORE] = W5 / wpa
    # compressor maps scaled to the design point
    for o, key, PR, eta, Wc in ((gp.FAN, "fan_map", spec["PR_fan"], spec["eta_fan"],
                                 W2 * math.sqrt(T2 / gp.T_STD) / (P2 / gp.P_STD)),
                                (gp.LPC, "lpc_map", spec["PR_lpc"], spec["eta_lpc"],
                                 Wcore * math.sqrt(T13 / gp.T_STD) / (P13 / gp.P_STD)),
                                (gp.HPC, "hpc_map", spec["PR_hpc"], spec["eta_hpc"],
                                 Wcore * math.sqrt(T24 / gp.T_STD) / (P25 / gp.P_STD))):
        m = spec[key]
        b, aw, ap, s1 = m["beta"], m["aw"], m["ap"], m["s1"]
        wr = 1 + s1 * b                       # design flow / stall-line flow at n = 1
        lnps = math.log(PR * (1 + m["SM"] / 100)) / wr ** (ap / aw)
        gd = math.log(PR) / lnps
        if not 0 < gd < 1:
            raise PlantError(f"{key}: design stall margin {m['SM']} % is not compatible with the map shape")
        c1 = (1 - gd) / (b + m["c2_c1"] * b * b)
        C[o + gp.M_WCS], C[o + gp.M_LNPR], C[o + gp.M_AW], C[o + gp.M_AP] = Wc / wr, lnps, aw, ap
        C[o + gp.M_S1], C[o + gp.M_QS], C[o + gp.M_C1], C[o + gp.M_C2] = s1, m["qs"], c1, m["c2_c1"] * c1
        C[o + gp.M_NPK], C[o + gp.M_KEN], C[o + gp.M_KEB], C[o + gp.M_BPK] = m["n_pk"], m["ke_n"], m["ke_b"], b
        C[o + gp.M_ETA] = eta / math.exp(-m["ke_n"] * (1 - m["n_pk"]) ** 2)
    v = np.array([spec["fan_map"]["beta"], bpr, spec["lpc_map"]["beta"], spec["hpc_map"]["beta"],
                  pih, pil, 1.0, 1.0])
    return C, v


class Turbofan:
    """Two-spool high-bypass turbofan (Plant protocol, continuous time).

    Keyword parameters override :data:`DEFAULTS` (map parameters as nested dicts, e.g.
    ``Turbofan(T40=1600.0, fan_map={"SM": 18.0})``).
    """

    name = "turbofan"
    time = "continuous"
    x_names = X_NAMES
    u_names = U_NAMES
    y_names = Y_NAMES
    z_names = Z_NAMES
    h_names = H_NAMES
    p_names = P_NAMES

    def __init__(self, **overrides):
        unknown = set(overrides) - set(DEFAULTS)
        if unknown:
            raise ValueError(f"unknown parameters {sorted(unknown)}; known: {sorted(DEFAULTS)}")
        self.spec = _merge(DEFAULTS, overrides)
        self.C, self.v_design = design_constants(self.spec)
        self.Nf_design = self.spec["Nf_design"]
        self.Nc_design = self.spec["Nc_design"]
        self.units = dict(UNITS)
        self.ranges = {**RANGES, "Nf": tuple(f * self.Nf_design for f in SPEED_RANGE),
                       "Nc": tuple(f * self.Nc_design for f in SPEED_RANGE),
                       **{h: H_RANGE for h in H_NAMES}}
        self.h_ref = np.zeros(len(H_NAMES))
        # central-difference perturbations: relative for x and u, absolute (fractions) for health
        self.perturbation = {"Nf": 1e-3, "Nc": 1e-3, "Wf": 1e-3, **{h: 1e-3 for h in H_NAMES}}
        self.sensor_noise = {"Nf": 0.0025, "Nc": 0.0025, "T24": 0.0075, "Ps30": 0.005,
                             "T30": 0.0075, "T48": 0.0075, "P50": 0.005, "P15": 0.005}
        ex = {"Nf": (0.5, 0.0), "Nc": (0.5, 0.0), "Wf": (0.5, 1.0), "T24": (1.0, 0.0),
              "T30": (1.0, 0.0), "T48": (1.0, 0.0), "T40": (1.0, 0.0), "Ps30": (0.0, 1.0),
              "P50": (0.0, 1.0), "P15": (0.0, 1.0), "Fn": (0.0, 1.0), "SmFan": (0.0, 0.0), "SmLPC": (0.0, 0.0),
              "SmHPC": (0.0, 0.0)}
        self.correction = {"theta": "T2", "delta": "P2", "T_std": gp.T_STD, "P_std": gp.P_STD,
                           "exponents": ex}
        self.schedule = {"alt": ("alt", False, 1.0), "Mach": ("Mach", False, 1.0),
                         "NfR": ("Nf", True, 100.0 / self.Nf_design)}
        # solver state: last converged unbalanced solve, converged trims (continuation sources)
        self._J = np.zeros((8, 8))
        self._last = None            # (v6, key) of the last converged evaluate
        self._tk = np.empty((0, 4))  # converged trims: keys (alt, Mach, dT, NfR), health, unknowns
        self._th = np.empty((0, 10))
        self._tv = np.empty((0, 8))
        self._trim_index = {}        # bytes(x, u, h, env) -> v8 (the solver unknowns of a trim)
        self._xu_index = {}          # bytes(x, u) -> v8 (to use a plain-dict guess)
        self._design_v = self.v_design.copy()
        self._check_design()

    # ---- protocol ---------------------------------------------------------------------------
    def parameters(self) -> dict:
        return {k: (dict(v) if isinstance(v, dict) else v) for k, v in self.spec.items()}

    def environment(self, p):
        p = np.asarray(p, dtype=np.float64)
        return np.array([p[0], p[1], 0.0])

    def theta_delta(self, env):
        amb = self._amb(env)
        return amb[0] / gp.T_STD, amb[1] / gp.P_STD

    def inlet(self, env):
        """(T2 K, P2 Pa) at the engine face for an ambient env = [alt, Mach, dTamb]."""
        amb = self._amb(env)
        return float(amb[0]), float(amb[1])

    def trim(self, p, h=None, env=None, guess=None):
        """Steady state at corrected fan speed NfR = p[2] (% of design) at ambient env."""
        p = np.asarray(p, dtype=np.float64)
        h = self._h(h)
        env = self.environment(p) if env is None else np.asarray(env, dtype=np.float64)
        if not np.all(np.isfinite(p)) or not np.all(np.isfinite(env)) or len(env) != 3:
            raise PlantError(f"trim: invalid operating point p={p}, env={env}")
        NfR = float(p[2])
        if not 5.0 < NfR < 150.0:
            raise PlantError(f"trim: corrected fan speed NfR={NfR} % is outside 5..150 %")
        amb = self._amb(env)
        Nf = NfR / 100.0 * self.Nf_design * math.sqrt(amb[0] / gp.T_STD)
        key = np.array([env[0], env[1], env[2], NfR])
        starts = []
        if guess is not None:
            vg = self._v_from_guess(guess)
            if vg is not None:
                starts.append(vg)
        s = np.empty(gp.NS)
        for v0 in starts:
            v = v0.copy()
            st, it, rm = gp.newton(v, 1, Nf, 0.0, 0.0, amb, h, self.C, TOL, MAXIT, s, self._J, 0)
            if st == gp.OK:
                return self._finish_trim(v, s, key, h, env)
        # continuation from the nearest converged trim (or the design point)
        src_key, src_h, src_v = self._nearest_trim(key, h)
        v, s, st, msg = self._continue_trim(src_key, src_h, src_v, key, h)
        if st != gp.OK:
            raise PlantError(f"trim did not converge at alt={env[0]:g} m, Mach={env[1]:g}, "
                             f"dTamb={env[2]:g} K, NfR={NfR:g} %: {msg}")
        return self._finish_trim(v, s, key, h, env)

    def evaluate(self, x, u, h=None, env=None):
        """Unbalanced solve at spool speeds x = (Nf, Nc) rpm and fuel flow u = (Wf,) kg/s:
        (f = (dNf/dt, dNc/dt) rpm/s, y, z). Raises PlantError if the flows cannot be balanced."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        u = np.asarray(u, dtype=np.float64).reshape(-1)
        h = self._h(h)
        env = np.asarray(env, dtype=np.float64)
        if x.shape != (2,) or u.shape != (1,) or env.shape != (3,):
            raise PlantError(f"evaluate: shapes x {x.shape}, u {u.shape}, env {env.shape}; expected (2,), (1,), (3,)")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u)) and np.all(np.isfinite(env))):
            raise PlantError(f"evaluate: non-finite input x={x}, u={u}, env={env}")
        s = self.solve_unbalanced(x, u, h, env)
        return (np.array([s[gp.S_DNF], s[gp.S_DNC]]), s[Y_IDX].copy(), s[Z_IDX].copy())

    # ---- solver internals -------------------------------------------------------------------
    def solve_unbalanced(self, x, u, h, env):
        """The station vector of the unbalanced solve (see models.gaspath for its layout)."""
        amb = self._amb(env)
        Nf, Nc, Wf = float(x[0]), float(x[1]), float(u[0])
        if not (Nf > 0 and Nc > 0 and Wf > 0):
            raise PlantError(f"evaluate: speeds and fuel flow must be positive (Nf={Nf}, Nc={Nc}, Wf={Wf})")
        s = np.empty(gp.NS)
        if self._last is not None:
            v = self._last.copy()
            st, it, rm = gp.newton(v, 0, Nf, Nc, Wf, amb, h, self.C, TOL, MAXIT, s, self._J, 0)
            if st == gp.OK:
                self._last = v
                return s
        # fallback: balanced trim at the same corrected fan speed, then continuation in (Nc, Wf)
        NfR = 100.0 * Nf / math.sqrt(amb[0] / gp.T_STD) / self.Nf_design
        try:
            t = self.trim(np.array([env[0], env[1], NfR]), h, env)
        except PlantError as e:
            raise PlantError(f"evaluate: no start point at Nf={Nf:g} rpm (NfR={NfR:.2f} %): {e}") from None
        v8 = self._trim_index[self._tkey(t["x"], t["u"], h, env)]
        v = v8[:6].copy()
        x0, w0 = t["x"][1], t["u"][0]
        frac, step = 0.0, 1.0
        msg = ""
        while frac < 1.0:
            f = min(1.0, frac + step)
            vt = v.copy()
            st, it, rm = gp.newton(vt, 0, Nf, x0 + f * (Nc - x0), w0 + f * (Wf - w0), amb, h, self.C,
                                   TOL, MAXIT, s, self._J, 0)
            if st == gp.OK:
                v, frac, step = vt, f, min(1.0, 2 * step)
            else:
                msg = gp.STATUS_TEXT[st]
                step *= 0.5
                if step < 1.0 / 512:
                    raise PlantError(f"evaluate did not converge at Nf={Nf:g} rpm, Nc={Nc:g} rpm, "
                                     f"Wf={Wf:g} kg/s, env={list(env)} ({msg}, reached {frac:.3f} of the "
                                     f"way from the trim at NfR={NfR:.2f} %)")
        self._last = v
        return s

    def _h(self, h):
        if h is None:
            return np.zeros(len(H_NAMES))
        h = np.asarray(h, dtype=np.float64).reshape(-1)
        if h.shape != (len(H_NAMES),) or not np.all(np.isfinite(h)):
            raise PlantError(f"health vector must be 10 finite fractions, got {h}")
        return h

    def _amb(self, env):
        amb = np.empty(5)
        gp.ambient(float(env[0]), float(env[1]), float(env[2]), self.C, amb)
        return amb

    @staticmethod
    def _tkey(x, u, h, env):
        return np.concatenate([np.asarray(x, float), np.asarray(u, float), h, np.asarray(env, float)]).tobytes()

    def _v_from_guess(self, guess):
        try:
            x = np.asarray(guess["x"], float)
            u = np.asarray(guess["u"], float)
        except (KeyError, TypeError):
            return None
        key = getattr(guess, "_key", None)
        if key is not None and key in self._trim_index:
            return self._trim_index[key].copy()
        v = self._xu_index.get(np.concatenate([x.reshape(-1), u.reshape(-1)]).tobytes())
        return None if v is None else v.copy()

    def _finish_trim(self, v, s, key, h, env):
        x = np.array([s[gp.S_NFRPM], s[gp.S_NCRPM]])
        u = np.array([s[gp.S_WF]])
        out = _TrimDict(x=x, u=u, y=s[Y_IDX].copy(), z=s[Z_IDX].copy())
        k = self._tkey(x, u, h, env)
        out._key = k
        self._trim_index[k] = v.copy()
        self._xu_index[np.concatenate([x, u]).tobytes()] = v.copy()
        for d in (self._trim_index, self._xu_index):
            if len(d) > 20000:
                d.pop(next(iter(d)))
        if len(self._tk) >= 5000:
            self._tk, self._th, self._tv = self._tk[1000:], self._th[1000:], self._tv[1000:]
        self._tk = np.vstack([self._tk, key])
        self._th = np.vstack([self._th, h])
        self._tv = np.vstack([self._tv, v])
        self._last = v[:6].copy()
        return out

    def _nearest_trim(self, key, h):
        best = (np.array([0.0, 0.0, 0.0, 100.0]), np.zeros(len(H_NAMES)), self._design_v)
        scale = np.array([12000.0, 0.85, 30.0, 40.0])
        dbest = np.sum(((key - best[0]) / scale) ** 2) + np.sum((h / 0.02) ** 2)
        if len(self._tk):
            d = np.sum(((self._tk - key) / scale) ** 2, axis=1) + np.sum(((self._th - h) / 0.02) ** 2, axis=1)
            i = int(np.argmin(d))
            if d[i] < dbest:
                best = (self._tk[i], self._th[i], self._tv[i])
        return best

    def _continue_trim(self, k0, h0, v0, k1, h1):
        """Natural-parameter continuation of the trim from (k0, h0, v0) to (k1, h1)."""
        v = v0.copy()
        s = np.empty(gp.NS)
        sbest = None
        frac, step = 0.0, 1.0
        msg = "no step"
        amb = np.empty(5)
        vprev, fprev = None, None
        while frac < 1.0:
            f = min(1.0, frac + step)
            k = k0 + f * (k1 - k0)
            hh = h0 + f * (h1 - h0)
            gp.ambient(k[0], k[1], k[2], self.C, amb)
            Nf = k[3] / 100.0 * self.Nf_design * math.sqrt(amb[0] / gp.T_STD)
            vt = v.copy()
            if vprev is not None and f - frac > 0:       # secant predictor
                vt = v + (v - vprev) * (f - frac) / (frac - fprev)
                vt = np.clip(vt, gp._LO + 1e-6, gp._HI - 1e-6)
            st, it, rm = gp.newton(vt, 1, Nf, 0.0, 0.0, amb, hh, self.C, TOL, MAXIT, s, self._J, 0)
            if st != gp.OK and vprev is not None:       # retry without the predictor
                vt = v.copy()
                st, it, rm = gp.newton(vt, 1, Nf, 0.0, 0.0, amb, hh, self.C, TOL, MAXIT, s, self._J, 0)
            if st == gp.OK:
                vprev, fprev = v, frac
                v, frac = vt, f
                sbest = s.copy()
                step = min(1.0, 2.0 * step)
            else:
                msg = f"{gp.STATUS_TEXT[st]} (max residual {rm:.2e}); continuation stopped at {frac:.3f} " \
                      f"of the way from alt={k0[0]:g}, Mach={k0[1]:g}, NfR={k0[3]:g}"
                step *= 0.5
                if step < 1.0 / 1024:
                    return v, s, st, msg
        return v, sbest, gp.OK, ""

    def _check_design(self):
        amb = self._amb([0.0, 0.0, 0.0])
        r = np.zeros(8)
        s = np.empty(gp.NS)
        ok = gp.gaspath(self.v_design, 1, self.Nf_design, 0.0, 0.0, amb, self.h_ref, self.C, r, s)
        if not ok or np.max(np.abs(r)) > 1e-9:
            raise PlantError(f"the design point does not reproduce itself (residuals {r})")

    # ---- reporting ---------------------------------------------------------------------------
    def stations(self, p, h=None, env=None):
        """Trim at p and return the full station vector as a dict (for tables and checks)."""
        t = self.trim(p, h, env)
        env = self.environment(p) if env is None else env
        s = self.solve_unbalanced(t["x"], t["u"], self._h(h), env)
        return {name[2:]: float(s[i]) for name, i in vars(gp).items()
                if name.startswith("S_") and isinstance(i, int)}


class _TrimDict(dict):
    """A trim result: a plain dict {"x","u","y","z"} that also remembers its solver unknowns."""
    _key = None


def operating_points(model: Turbofan):
    """The design-table operating points: (label, p, env)."""
    return [("design (SLS static, NfR 100 %)", np.array([0.0, 0.0, 100.0])),
            (f"take-off (SLS static, NfR {model.spec['takeoff_NfR']:g} %)",
             np.array([0.0, 0.0, model.spec["takeoff_NfR"]])),
            (f"cruise (10.7 km, M0.80, NfR {model.spec['cruise_NfR']:g} %)",
             np.array([10700.0, 0.8, model.spec["cruise_NfR"]]))]


def design_table(model: Turbofan | None = None) -> str:
    """The design-point table (take-off and cruise) as text."""
    m = model or Turbofan()
    rows = []
    cols = []
    for label, p in operating_points(m):
        st = m.stations(p)
        cols.append((label, st))
    to = cols[1][1]

    def line(name, fn, fmt):
        rows.append(f"| {name} | " + " | ".join(format(fn(st), fmt) for _, st in cols) + " |")

    rows.append("| quantity | " + " | ".join(c[0] for c in cols) + " |")
    rows.append("|---|" + "---|" * len(cols))
    line("net thrust Fn, kN", lambda s: s["FN"] / 1e3, ".1f")
    line("thrust / take-off thrust, %", lambda s: 100 * s["FN"] / to["FN"], ".1f")
    line("fuel flow Wf, kg/s", lambda s: s["WF"], ".3f")
    line("TSFC, g/(kN s)", lambda s: 1e6 * s["WF"] / s["FN"], ".2f")
    line("inlet flow W2, kg/s", lambda s: s["W2"], ".1f")
    line("bypass ratio", lambda s: s["BPR"], ".2f")
    line("overall pressure ratio P3/P2", lambda s: s["P3"] / s["P13"] * s["PRF"], ".2f")
    line("fan / LPC / HPC pressure ratio", lambda s: f"{s['PRF']:.3f} / {s['PRL']:.3f} / {s['PRH']:.2f}", "s")
    line("HPT / LPT pressure ratio", lambda s: f"{s['PIH']:.3f} / {s['PIL']:.3f}", "s")
    line("T2 / T24 / T30, K", lambda s: f"{s['T2']:.1f} / {s['T24']:.1f} / {s['T3']:.1f}", "s")
    line("T40 (combustor exit), K", lambda s: s["T4"], ".1f")
    line("T48 / T50, K", lambda s: f"{s['T48']:.1f} / {s['T50']:.1f}", "s")
    line("Ps30 / P50, kPa", lambda s: f"{s['PS3'] / 1e3:.1f} / {s['P50'] / 1e3:.1f}", "s")
    line("fuel-air ratio Wf/W3", lambda s: s["WF"] / s["W3"], ".4f")
    line("Nf / Nc, rpm", lambda s: f"{s['NFRPM']:.0f} / {s['NCRPM']:.0f}", "s")
    line("efficiencies fan/LPC/HPC/HPT/LPT",
         lambda s: "/".join(f"{s[k]:.3f}" for k in ("ETAF", "ETAL", "ETAH", "ETAHT", "ETALT")), "s")
    line("stall margin fan / LPC / HPC, %", lambda s: f"{s['SMF']:.1f} / {s['SML']:.1f} / {s['SMH']:.1f}", "s")
    line("gross thrust bypass / core, kN", lambda s: f"{s['FGB'] / 1e3:.1f} / {s['FGC'] / 1e3:.1f}", "s")
    line("ram drag, kN", lambda s: s["FRAM"] / 1e3, ".1f")
    return "\n".join(rows)


def influence(model: Turbofan, p, dh=-0.01):
    """Influence coefficients at fixed corrected fan speed: for dh on each health parameter, the
    change of Wf and of every y (%), and of every z (% for Fn and T40, points for stall margins).
    Returns (column names, {health name: row array})."""
    env = model.environment(p)
    t0 = model.trim(p, None, env)
    names = ["Wf"] + list(model.y_names[1:]) + list(model.z_names)
    a0 = np.concatenate([t0["u"], t0["y"][1:], t0["z"]])
    rows = {}
    for j, hn in enumerate(H_NAMES):
        h = np.zeros(len(H_NAMES))
        h[j] = dh
        t = model.trim(p, h, env, guess=t0)
        a = np.concatenate([t["u"], t["y"][1:], t["z"]])
        d = 100.0 * (a - a0) / np.abs(a0)
        d[-3:] = a[-3:] - a0[-3:]
        rows[hn] = d
    return names, rows


def influence_table(model: Turbofan | None = None, p=None, dh=-0.01) -> str:
    """The influence table as markdown (rows: health parameters; columns: Wf, y, z)."""
    m = model or Turbofan()
    p = np.asarray(p if p is not None else operating_points(m)[1][1], dtype=np.float64)
    names, rows = influence(m, p, dh)
    units = ["%"] * (len(names) - 3) + ["pt"] * 3
    out = ["| " + f"{dh:+g} on | " + " | ".join(f"{n} {u}" for n, u in zip(names, units)) + " |",
           "|---|" + "---:|" * len(names)]
    for hn, d in rows.items():
        out.append(f"| {hn} | " + " | ".join(f"{x:+.3f}" for x in d) + " |")
    return "\n".join(out)


if __name__ == "__main__":
    _m = Turbofan()
    print("Design-point table\n")
    print(design_table(_m))
    for _label, _p in operating_points(_m)[1:]:
        print(f"\nInfluence of -1 % on each health parameter at {_label}, fixed corrected fan speed "
              "(Wf, y, Fn, T40 in % of value; stall margins in points)\n")
        print(influence_table(_m, _p))
