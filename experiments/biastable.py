"""The runtime's tuning element on the turbofan: a bias table learns a sensor's
operating-point-dependent mismatch on a new engine, then keeps the health estimates of the
degraded engine right.

The experiment (each flight simulated with models.flight, short profile):

1. the engine's T48 sensor reads high by an amount that grows with power (``offset`` at 60 %
   corrected fan speed to ``offset + slope`` at 100 %): a unit-to-unit thermocouple mismatch
   that the gain database (built from the nominal model) does not know;
2. learning: ``--learn`` flights of the engine while new (nominal health), run with the tuners
   held (mode ``"untuned"``: a new engine defines nominal health) and a bias table on T48 over the
   dynamics grid's scheduling variables learning from the innovations;
3. the table is locked and the degraded engine is flown: health estimates with the table versus
   without it, against the truth, and for reference on the same flight without the mismatch.

Identifiability: a sensor bias and a health shift both move the residuals, so they cannot be
learnt at the same time from the same data; learn the table while the engine is new (health is
nominal by definition), then lock it (or give it a much larger noise ratio) and track health.

``pwl biastable`` runs :func:`experiment` and prints and plots its result.
"""
import numpy as np

DEGRADED = {"fan_eff": -0.015, "hpc_eff": -0.02, "hpc_flow": -0.015, "hpt_flow": 0.01}


def mismatch(truth, nf_design, offset, slope):
    """Fractional T48 sensor error along a flight: offset + slope * (NfR - 60) / 40."""
    nfr = 100.0 * truth["Nf"] / np.sqrt(truth["T2"] / 288.15) / nf_design
    return offset + slope * (nfr - 60.0) / 40.0


def fly(model, seed, health, offset, slope, cruise=None):
    """One short flight as a Log, the T48 channel carrying the mismatch (None: no mismatch)."""
    from models.flight import DT, flight_profile, simulate
    from pwl.logs import Log

    prof = flight_profile("short", {"cruise": cruise} if cruise else None, None, 0.8, 0.0, DT, seed, True)
    r = simulate(model, prof, health=health, seed=seed)
    ch = dict(r["channels"])
    if offset is not None:
        ch["T48"] = ch["T48"] * (1.0 + mismatch(r["truth"], model.Nf_design, offset, slope))
    return Log(r["time"], ch, r["units"], r["truth"], r["truth_units"], r["attrs"], path=f"flight(seed {seed})")


def experiment(db_path, learn=3, ratio=1e3, offset=0.01, slope=0.01, health=None, cruise=None,
               seed=11, settle=120.0, log=print):
    """Run the three steps; returns a dict with the health truth, the median estimates of the
    degraded flight (with table, without, without mismatch), the tuner names and the results."""
    from models.turbofan import H_NAMES, Turbofan
    from pwl.estimator import Estimator

    model = Turbofan()
    health = DEGRADED if health is None else health
    learner = Estimator(db_path, "untuned")
    tables = learner.new_bias_tables(["T48"], ratio=ratio)
    for k in range(learn):
        learner.run(fly(model, seed + k, None, offset, slope, cruise))
        log(f"  learning flight {k + 1}/{learn}: {int(tables['T48'].counts.sum())} node updates")
    tables["T48"].lock()
    deg = fly(model, seed + learn, health, offset, slope, cruise)
    ref = fly(model, seed + learn, health, None, slope, cruise)
    use = deg.time >= deg.time[0] + settle
    runs = {"with table": Estimator(learner.db, bias=tables).run(deg),
            "without table": Estimator(learner.db).run(deg),
            "no mismatch": Estimator(learner.db).run(ref)}
    est = {k: np.median(r.h_hat[use], axis=0) for k, r in runs.items()}
    truth = np.array([health.get(h, 0.0) for h in H_NAMES])
    true_bias = mismatch(deg.truth, model.Nf_design, offset, slope) * deg.truth["T48"]
    return {"names": list(H_NAMES), "tuners": list(learner.db.names["q"]), "truth": truth,
            "estimates": est, "runs": runs, "log": deg, "true_bias": true_bias, "tables": tables}
