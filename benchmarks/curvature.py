"""How far from linear are the fault signatures? The curvature the diagnostics allow for.

pwl.fleet.signatures gives each health parameter's signature from the database's linear model.
A large loss of one component moves the channels by more than its signature of the fitted size
says, most in channels the signature barely moves; unallowed for, that curvature was fitted as a
second component (probe fleets: an HPT loss of 8 % read 'lpc+hpt' with the LPC -6 %). The
diagnostics allow per channel an error of ``DiagnosisConfig.curvature`` times the change's mean
square over the channels (relative units). This script measures, with the nonlinear model as
reference, what the plant needs: for each component's loss (efficiency with flow in the fleet
simulator's ratio) of 2-8 % at a cruise and an idle snapshot, the deviation d (faulty trim less
healthy trim, both against the database's trims), its best fit by the component's own signature
columns (weighted by the fleet's scatter) and the residual r:

    rms(d)          the size of the change (relative)
    max|r| / ms     the curvature coefficient: the worst channel's residual per unit of the
                    change's mean square over the channels (constant in the size for a
                    second-order error)
    needed          the smallest ``curvature`` for which the component's own fit leaves a
                    residual within the scatter of ten flights' mean (chi-square at most the
                    number of channels): what the diagnostics need to name the loss alone
                    when it has been seen on ten flights

    python benchmarks/curvature.py [--database data/turbofan_demo.h5]

``DiagnosisConfig.curvature`` should be at least the largest "needed" of the losses that matter
(4.0 by default; the turbofan's losses of up to 8 % need at most 3.0, the HPT's at cruise).
"""
import argparse
import os

import numpy as np

from models.fleet import COMPONENT_RATIO
from models.turbofan import Turbofan
from pwl.database import GainDatabase
from pwl.fleet.signatures import Signatures
from signature_angles import POINTS, SCATTER, snapshot_of_trim

HERE = os.path.dirname(os.path.abspath(__file__))


def deviation(sig, m, p, h):
    """The relative deviations and signatures of a steady snapshot of health h at p."""
    snap = snapshot_of_trim(m, p) if h is None else faulty_snapshot(m, p, h)
    return sig.at(snap, {})


def faulty_snapshot(m, p, h):
    """snapshot_of_trim with health h (the plant's health vector)."""
    env = m.environment(p)
    t = m.trim(p, h, env)
    d = snapshot_of_trim(m, p)
    d.update(zip(m.y_names, t["y"]))
    d.update(zip(m.u_names, t["u"]))
    return d


#: flights after the change whose mean the residual is judged against
FLIGHTS = 10


def needed(r, var, ms) -> float:
    """The smallest c >= 0 with sum r^2 / (var + (c ms)^2) <= len(r) (bisection; 0 if none needed)."""
    chi2 = lambda c: float(np.sum(r ** 2 / (var + (c * ms) ** 2)))
    if chi2(0.0) <= r.size:
        return 0.0
    lo, hi = 0.0, 1.0
    while chi2(hi) > r.size:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2(mid) > r.size else (lo, mid)
    return hi


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--database", default=os.path.join(HERE, "..", "data", "turbofan_demo.h5"))
    args = ap.parse_args(argv)
    db = GainDatabase.open(args.database)
    sig, m = Signatures(db), Turbofan()
    hn = list(db.names["h"])
    healthy = {r: deviation(sig, m, p, None) for r, p in POINTS.items()}
    print(f"{'loss':12s} {'regime':7s} {'rms(d) %':>9s} {'max|r|/ms':>10s} {'needed':>7s}  worst channel")
    worst = 0.0
    for comp, ratio in COMPONENT_RATIO.items():
        for size in (0.02, 0.04, 0.06, 0.08):
            h = np.zeros(len(hn))
            h[hn.index(comp + "_eff")], h[hn.index(comp + "_flow")] = -size, -size * ratio
            for regime, p in POINTS.items():
                dev = deviation(sig, m, p, h)
                d = dev.d - healthy[regime].d
                w = np.array([1.0 / SCATTER[regime][c] for c in dev.channels])
                cols = [dev.columns.index(comp + "_eff"), dev.columns.index(comp + "_flow")]
                A = dev.S[:, cols]
                theta = np.linalg.lstsq(A * w[:, None], d * w, rcond=None)[0]
                r = d - A @ theta
                ms = float(np.mean(d ** 2))
                k = int(np.argmax(np.abs(r)))
                need = needed(r, 1.0 / w ** 2 / FLIGHTS, ms)
                worst = max(worst, need)
                print(f"{comp} -{size:.0%}{'':5s} {regime:7s} {100 * np.sqrt(ms):9.2f} {abs(r[k]) / ms:10.2f} "
                      f"{need:7.2f}  {dev.channels[k]} {100 * d[k]:+.2f} % (signature {100 * (A @ theta)[k]:+.2f} %)")
    print(f"largest needed: {worst:.2f} (DiagnosisConfig.curvature, default 4.0)")


if __name__ == "__main__":
    main()
