"""How separable are the fault classes with the turbofan's sensors? Angles between signatures.

For every fault hypothesis of pwl.fleet.diagnose (a component: its efficiency and flow free, 2-D; a
sensor or fuel-flow bias, 1-D) the signature columns at a steady snapshot are computed by
pwl.fleet.signatures from the database, at snapshots made by the nonlinear model's own trims (nominal
health, ISA) at a cruise point and at ground idle. The columns are whitened by the flight-to-flight
scatter of the snapshot deviations (1 sigma per channel, relative; default: the scatter measured by
``pwl fleet diagnose`` on the 100 x 20 benchmark fleet) and the smallest principal angle between
every two hypotheses is printed (scipy.linalg.subspace_angles): 90 deg is orthogonal (easy to tell
apart), a few degrees means that a change of one is almost exactly a change of the other.

    python benchmarks/signature_angles.py [--database data/turbofan_demo.h5]

Two views: cruise alone, and cruise and idle stacked (what the diagnostics use when a fleet's
flights have both steady regimes). Also printed: the angle between each component's simulated
fault direction (efficiency with flow in the fleet simulator's ratio) and its nearest other
hypothesis, single components or pairs.
"""
import argparse
import os

import numpy as np
from scipy.linalg import subspace_angles

from models.fleet import COMPONENT_RATIO
from models.turbofan import Turbofan
from pwl.database import GainDatabase
from pwl.fleet.diagnose import hypotheses
from pwl.fleet.signatures import Signatures

HERE = os.path.dirname(os.path.abspath(__file__))
# flight-to-flight 1-sigma scatter of the deviations (relative) per regime, as printed by
# `pwl fleet diagnose` on the seed-0 benchmark fleet
SCATTER = {"cruise": {"Nc": 2.1e-4, "T24": 2.7e-4, "Ps30": 3.0e-4, "T30": 2.7e-4, "T48": 1.35e-3,
                      "P50": 2.3e-4, "P15": 2.3e-4, "Wf": 1.9e-3},
           "idle": {"Nc": 2.0e-4, "T24": 2.1e-4, "Ps30": 8.6e-4, "T30": 2.1e-4, "T48": 1.22e-3,
                    "P50": 6.9e-4, "P15": 2.1e-4, "Wf": 3.6e-3}}
POINTS = {"cruise": np.array([9500.0, 0.78, 92.0]), "idle": np.array([0.0, 0.0, 62.0])}


def snapshot_of_trim(m, p):
    """The channel means a steady snapshot of the nominal engine at p would have."""
    env = m.environment(p)
    t = m.trim(p, None, env)
    d = dict(zip(m.y_names, t["y"]))
    d.update(zip(m.u_names, t["u"]))
    d["alt"], d["Mach"] = p[0], p[1]
    th, de = m.theta_delta(env)
    d["T2"], d["P2"] = th * 288.15, de * 101325.0
    return d


def whitened(sig, m, regime):
    dev = sig.at(snapshot_of_trim(m, POINTS[regime]), {})
    w = np.array([1.0 / SCATTER[regime][c] for c in dev.channels])
    S = dev.S * w[:, None]
    # sensor columns are per raw unit: scale each to one noise sigma so that columns compare
    return S, dev.columns


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--database", default=os.path.join(HERE, "..", "data", "turbofan_demo.h5"))
    args = ap.parse_args()
    db = GainDatabase.open(args.database)
    sig, m = Signatures(db), Turbofan()
    Sc, cols = whitened(sig, m, "cruise")
    Si, _ = whitened(sig, m, "idle")
    views = {"cruise": Sc, "cruise+idle": np.vstack([Sc, Si])}
    bank = hypotheses(cols, pairs=False)
    names = [h.name for h in bank]
    short = [n.replace("sensor:", "s:") for n in names]
    for view, S in views.items():
        print(f"\nsmallest angle (deg) between hypotheses, {view}")
        print(f"{'':>7}" + "".join(f"{s:>7}" for s in short))
        for a, ha in enumerate(bank):
            row = []
            for b, hb in enumerate(bank):
                ang = np.degrees(subspace_angles(S[:, ha.columns], S[:, hb.columns]).min())
                row.append("      ." if a == b else f"{ang:7.1f}")
            print(f"{short[a]:>7}" + "".join(row))
    # each simulated component fault direction against the nearest other hypothesis (pairs too)
    full = hypotheses(cols, pairs=True)
    print("\nsimulated component faults (efficiency with flow in the simulator's ratio): angle to "
          "the nearest hypothesis that does not contain the component")
    print(f"{'fault':<8}{'view':<13}{'nearest':<12}{'angle deg':>9}")
    for comp, ratio in COMPONENT_RATIO.items():
        e, f = cols.index(comp + "_eff"), cols.index(comp + "_flow")
        for view, S in views.items():
            v = S[:, e] + ratio * S[:, f]
            best = min(((np.degrees(subspace_angles(v[:, None], S[:, h.columns]).min()), h.name)
                        for h in full if comp not in h.name.split("+")), key=lambda x: x[0])
            print(f"{comp:<8}{view:<13}{best[1]:<12}{best[0]:9.1f}")
    # the combination of issue #13: hpt efficiency loss with an lpt flow gain
    e, f = cols.index("hpt_eff"), cols.index("lpt_flow")
    print("\nhpt_eff -2 % with lpt_flow +1.5 %: angle to the lpt hypothesis alone")
    for view, S in views.items():
        v = -0.02 * S[:, e] + 0.015 * S[:, f]
        lpt = [h for h in full if h.name == "lpt"][0]
        print(f"  {view:<13}{np.degrees(subspace_angles(v[:, None], S[:, lpt.columns]).min()):6.1f} deg")


if __name__ == "__main__":
    main()
