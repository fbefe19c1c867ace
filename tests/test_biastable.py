"""The runtime's bias table on the turbofan (issue 7): learnt on a new engine's flights, it keeps
the degraded engine's health estimates right despite a sensor mismatch. The reference is the
simulation's truth (and the same flight without the mismatch)."""
import numpy as np

from experiments.biastable import experiment
from pwl.demo_data import demo_paths


def test_bias_table_restores_health_estimates():
    out = experiment(demo_paths()[0], learn=3, cruise=150.0, seed=21, log=lambda *a: None)
    truth = out["truth"]
    err = {k: np.sqrt(np.mean((100 * (h - truth)) ** 2)) for k, h in out["estimates"].items()}
    assert err["without table"] > 3 * err["with table"], err
    # with the table, about as good as without any mismatch (within 0.15 percentage points RMS)
    assert err["with table"] < err["no mismatch"] + 0.15, err
    # the learnt bias follows the true one (tens of K) to a few K where the flight is settled
    use = out["log"].time > 120
    bh = out["runs"]["with table"].channel("bias_hat", "T48")[use]
    assert np.sqrt(np.mean((bh - out["true_bias"][use]) ** 2)) < 5.0
