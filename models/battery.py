"""Seed 003 case: ohmic resistance of a Li-ion cell versus temperature, with correlated ageing.

Plain numpy (no pwl, no linearize). Units: temperature in degC, resistance in milliohm.

* **New cell.** Arrhenius-type temperature dependence
  R_new(T) = R25 exp(B (1/(T + 273.15) - 1/298.15)), R25 = 1.5 mOhm, B = 2800 K
  (about 8 mOhm at -20 C, 0.7 mOhm at 50 C).
* **Ageing** driven by one life variable s in [0, 1] (s = (k / n)^0.8 over the n estimates of a
  life), two mechanisms acting at every temperature at once, with a temperature shape that is
  NOT the new cell's (the estimator's prior assumes growth proportional to R_new):
  film growth dR_f = a_f s R25 exp(B_f (1/(T + 273.15) - 1/298.15)), a_f = 0.5, B_f = 2000 K
  (weaker temperature dependence than the electrolyte's), and contact/collector corrosion
  dR_c = a_c s R25, a_c = 0.15 (no temperature dependence). End of life: +34 % at -20 C,
  +65 % at 25 C, +93 % at 50 C (relative growth differs from the prior's uniform one).
* **Local estimates.** Each sample is a noisy resistance estimate at the current cell temperature
  (e.g. from a current pulse; Gaussian, std ``noise_std`` = 0.08 mOhm), as a recursive local
  estimator at the operating point would give.
* **Excitation** concentrated at a few temperatures: clusters at 8, 22 and 32 C (weights 0.3,
  0.5, 0.2, std 1.5 C), rare excursions to -3 C and 40 C (0.4 % each, std 1 C); the table nodes
  below -5 C and at 50 C are never excited.
"""
from __future__ import annotations

import numpy as np

#: default parameters
PARAMS = {"R25": 1.5, "B": 2800.0, "a_film": 0.5, "B_film": 2000.0, "a_contact": 0.15,
          "life_exponent": 0.8, "noise_std": 0.08}
#: (centre degC, std degC, weight) of the usage temperature clusters
CLUSTERS = ((8.0, 1.5, 0.3), (22.0, 1.5, 0.492), (32.0, 1.5, 0.2), (-3.0, 1.0, 0.004), (40.0, 1.0, 0.004))
#: breakpoints of the resistance table, degC
NODES = np.arange(-20.0, 50.1, 5.0)
T_REF = 298.15


def _arrhenius(T, B):
    return np.exp(B * (1.0 / (np.asarray(T, dtype=np.float64) + 273.15) - 1.0 / T_REF))


def resistance_new(T, params=None):
    """Begin-of-life ohmic resistance (mOhm) at temperature T (degC)."""
    p = {**PARAMS, **(params or {})}
    return p["R25"] * _arrhenius(T, p["B"])


def ageing_increase(T, s, params=None):
    """Resistance increase (mOhm) at temperature T and life variable s in [0, 1]."""
    p = {**PARAMS, **(params or {})}
    return np.asarray(s, dtype=np.float64) * p["R25"] * (p["a_film"] * _arrhenius(T, p["B_film"])
                                                         + p["a_contact"])


def resistance(T, s, params=None):
    """True ohmic resistance (mOhm) at temperature T (degC) and life s."""
    return resistance_new(T, params) + ageing_increase(T, s, params)


def usage_temperatures(n, rng, clusters=CLUSTERS):
    """n cell temperatures drawn from the usage clusters (centre, std, weight)."""
    c = np.array(clusters, dtype=np.float64)
    w = c[:, 2] / c[:, 2].sum()
    k = rng.choice(len(c), size=n, p=w)
    return c[k, 0] + c[k, 1] * rng.standard_normal(n)


def prior_sigma(nodes, n, rel=0.6, params=None):
    """Ageing random-walk std per estimate and node for an estimator that expects the resistance
    to grow by about ``rel`` x R_new over n estimates at every temperature (sigma ~ R_new)."""
    return rel * resistance_new(nodes, params) / np.sqrt(n)


def simulate(n=5000, seed=0, params=None, clusters=CLUSTERS, nodes=NODES):
    """One battery life of n local resistance estimates. Returns a dict of arrays:

    step, life s, temperature, truth (true resistance), measured (noisy estimate), noise_std,
    nodes, table0 (begin-of-life table R_new at the nodes), truth_end (true resistance at the
    nodes at the end of life), sigma_prior (:func:`prior_sigma`).
    """
    p = {**PARAMS, **(params or {})}
    rng = np.random.default_rng(seed)
    step = np.arange(n)
    s = ((step + 1) / n) ** p["life_exponent"]
    T = usage_temperatures(n, rng, clusters)
    truth = resistance(T, s, p)
    meas = truth + p["noise_std"] * rng.standard_normal(n)
    nodes = np.asarray(nodes, dtype=np.float64)
    return {"step": step, "life": s, "temperature": T, "truth": truth, "measured": meas,
            "noise_std": p["noise_std"], "nodes": nodes, "table0": resistance_new(nodes, p),
            "truth_end": resistance(nodes, s[-1], p), "sigma_prior": prior_sigma(nodes, n, params=p)}
