"""Shared test fixtures: a small synthetic but internally consistent gain database."""
import numpy as np
import pytest

from linearize.kalman import steady_state_gain
from pwl.database import Correction, GainDatabase
from pwl.grid import Axis, Grid


def make_database(seed=0, nx=2, nu=1, ny=3, nz=2, nh=4, nq=2, trim_shape=(3, 4), dyn_shape=(2, 3),
                  policy="clip", correction=True, dt=0.015, spread=1.0, filled=False):
    """A random database whose matrices are stable and whose gains are the steady-state gains.

    Scheduling variables: p0 (trim and dynamics axis), p1 (both); trims vary smoothly.
    ``spread``: how much the matrices differ from node to node (1: independent draws; small:
    close to one common draw, so that gains shared between nodes, e.g. zones, stay stabilizing).
    ``filled``: random trim statuses (else every trim computed: a filled one flags its samples).
    """
    rng = np.random.default_rng(seed)
    na = nx + nq

    def axis(name, n, lo, hi):
        v = np.sort(rng.uniform(lo, hi, n))
        v[0], v[-1] = lo, hi
        return Axis(name, v, "u_" + name)

    tg = Grid([axis("p0", trim_shape[0], 0.0, 10.0), axis("p1", trim_shape[1], 50.0, 100.0)], policy)
    dg = Grid([axis("p0", dyn_shape[0], 0.0, 10.0), axis("p1", dyn_shape[1], 50.0, 100.0)], policy)
    T, D = tg.shape, dg.shape
    names = {"x": [f"x{i}" for i in range(nx)], "u": [f"u{i}" for i in range(nu)],
             "y": [f"y{i}" for i in range(ny)], "z": [f"z{i}" for i in range(nz)],
             "h": [f"h{i}" for i in range(nh)], "q": [f"q{i}" for i in range(nq)], "p": ["p0", "p1"]}
    units = {k: ["unit_" + n for n in v] for k, v in names.items()}
    units["h"] = ["-"] * nh
    trim = {k: 1.0 + rng.random(T + (len(names[k]),)) for k in "xuyz"}
    mats = {"A": (nx, nx), "B": (nx, nu), "C": (ny, nx), "D": (ny, nu), "F": (nz, nx), "G": (nz, nu),
            "L": (nx, nh), "M": (ny, nh), "N": (nz, nh)}
    dyn = {k: rng.normal(size=s) + spread * rng.normal(size=D + s) for k, s in mats.items()} if spread < 1 \
        else {k: rng.normal(size=D + s) for k, s in mats.items()}
    dyn["A"] = 0.9 * np.eye(nx) + 0.02 * dyn["A"]
    V = rng.normal(size=(nq, nh))
    Vp = np.linalg.pinv(V)
    # stabilizing steady-state gains of the augmented systems (so closed loops stay bounded)
    K = np.zeros(D + (na, ny))
    for idx in np.ndindex(*D):
        Aa = np.block([[dyn["A"][idx], dyn["L"][idx] @ Vp], [np.zeros((nq, nx)), np.eye(nq)]])
        Ca = np.hstack([dyn["C"][idx], dyn["M"][idx] @ Vp])
        K[idx] = steady_state_gain(Aa, Ca, np.eye(na) * 1e-2, np.eye(ny) * 1e-1)[0]
    db = GainDatabase(
        names=names, units=units, trim_grid=tg, dyn_grid=dg, trim=trim,
        trim_status=(lambda st: st if filled else np.zeros_like(st))(rng.integers(0, 3, T).astype(np.int8)),
        dynamics=dyn, dyn_status=np.zeros(D, np.int8), dyn_donor=-np.ones(D, np.int64),
        tuner={"V": V, "V_pinv": Vp, "h_ref": np.zeros(nh)},
        kalman={"K": K, "P": np.broadcast_to(np.eye(na), D + (na, na)).copy(),
                "Q": np.broadcast_to(np.eye(na) * 1e-4, D + (na, na)).copy(),
                "R": np.broadcast_to(np.eye(ny) * 1e-3, D + (ny, ny)).copy()},
        kalman_status=np.zeros(D, np.int8), kalman_donor=-np.ones(D, np.int64), dt=dt,
        schedule=[("p0", False, 1.0), ("c1", True, 2.0)],
        correction=Correction("Tin", "Pin", {k: rng.choice([0.0, 0.5, 1.0], (len(names[k]), 2))
                                             for k in "xuyz"}) if correction else None,
        attrs={"model": "synthetic", "spec": "[grid]\nx = 1\n", "tuner_method": "subset",
               "tuner_metric": 0.25},
        zones=({"centers": rng.random((3, 2))}, {"k": 3}),
        tables={"bias_T48": ({"values": rng.random((4, 5))}, {"law": "exact", "ratio": 0.1})},
    )
    return db


@pytest.fixture
def synthetic_db():
    return make_database()


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib figures a plot function closes (kept open for inspection)."""
    plt = pytest.importorskip("matplotlib.pyplot")
    close, kept = plt.close, []
    monkeypatch.setattr(plt, "close", kept.append)
    yield kept
    for fig in kept:
        close(fig)


@pytest.fixture
def unwritable(tmp_path):
    """A plot path whose folder can be neither found nor created (its parent is a file)."""
    f = tmp_path / "a_file"
    f.write_text("")
    return str(f / "sub" / "x.png")
