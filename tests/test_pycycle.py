"""The pyCycle turbojet adapter (models/pycycle_plant.py) against pyCycle itself.

Needs the optional extra: pip install -e '.[pycycle]' (om-pycycle, openmdao). A tiny database
(2 x 2 x 2 trims, 2 dynamics points) is built through the public builder API; the
piecewise-linear model is compared with the nonlinear pyCycle model (the adapter) at off-grid
points, and the adapter's own solves are checked (trim is steady, linearization is stable,
errors name the point, the object pickles without its OpenMDAO problems)."""
import pickle

import numpy as np
import pytest

pytest.importorskip("pycycle", reason="pyCycle is not installed: pip install -e '.[pycycle]' (the pycycle extra)")

import models.pycycle_plant as pcp

if pcp.UNAVAILABLE:   # installed, but e.g. with a NumPy pyCycle 4.4 cannot run on (>= 2.4)
    pytest.skip(pcp.UNAVAILABLE, allow_module_level=True)

from linearize.build import SerialExecutor, build
from linearize.jacobian import jacobians
from linearize.plant import check_plant
from linearize.spec import BuildSpec
from linearize.validate import steady_state
from pwl.database import GainDatabase

SPEC = """
[model]
plant = "models.pycycle_plant:PyCycleTurbojet"
[trim_grid]
alt = [0, 3000]
Mach = [0, 0.4]
NR = [90, 100]
[dynamics_grid]
NR = [90, 100]
[build]
power_axis = "NR"
dt = 0.05
dynamics_hold = {alt = 1500, Mach = 0.2}
[kalman]
q_x = 3e-4
q_h = 1e-4
[tuners]
method = "subset"
n = 4
targets = ["h", "Fn"]
"""


def quiet(*a, **k):
    pass


@pytest.fixture(scope="module")
def plant():
    return pcp.PyCycleTurbojet()


@pytest.fixture(scope="module")
def db(plant, tmp_path_factory):
    out = tmp_path_factory.mktemp("pc") / "pc.h5"
    build(BuildSpec.parse(SPEC, "pycycle_test.toml"), out, plant=plant, executor=SerialExecutor(),
          progress=False, log=quiet)
    return GainDatabase.open(out)


def test_check_plant_and_design_point(plant):
    assert check_plant(plant) is plant
    d = plant.design_point()
    # the off-design model reproduces the design point (sea-level static, NR 100 %)
    t = plant.trim(np.array([0.0, 0.0, 100.0]))
    np.testing.assert_allclose(t["x"], [plant.spec["N_design"]], rtol=1e-6)
    np.testing.assert_allclose(t["u"], [d["Wf"]], rtol=1e-5)
    np.testing.assert_allclose(t["y"], d["y"], rtol=1e-5)
    np.testing.assert_allclose(t["z"][:2], d["z"][:2], rtol=1e-5)   # Fn, T40


def test_every_point_built(db):
    assert db.trim_status.shape == (2, 2, 2) and np.all(db.trim_status == 0)
    assert db.dyn_status.size == 2 and np.all(db.dyn_status == 0)
    assert np.all(db.kalman_status == 0)
    A = db.dynamics["A"]              # discrete (ZOH at dt): 0 < a < 1 is a stable spool
    assert np.all((A > 0.0) & (A < 1.0))


def test_evaluate_at_trim_is_steady_and_A_negative(plant, monkeypatch):
    p = np.array([1500.0, 0.25, 93.0])
    env = plant.environment(p)
    t = plant.trim(p, np.zeros(4), env)
    f, y, z = plant.evaluate(t["x"], t["u"], np.zeros(4), env)
    # rpm/s: the Newton tolerance's residual shaft power (a 0.1 % speed error gives about -3 rpm/s)
    assert abs(f[0]) < 0.01
    np.testing.assert_allclose(y, t["y"], rtol=1e-6)
    np.testing.assert_allclose(z, t["z"], rtol=1e-6)
    mats, info = jacobians(plant, t, np.zeros(4), env)
    assert info["one_sided_columns"] == 0
    assert mats["A"][0, 0] < 0.0 and mats["B"][0, 0] > 0.0     # stable spool, fuel accelerates it
    # the inertia sets the time constant: dN/dt = dP / (I omega)
    f1 = plant.evaluate(t["x"] * 1.002, t["u"], np.zeros(4), env)[0]
    monkeypatch.setitem(plant.spec, "inertia", 2 * plant.spec["inertia"])
    f2 = plant.evaluate(t["x"] * 1.002, t["u"], np.zeros(4), env)[0]
    np.testing.assert_allclose(f2, f1 / 2, rtol=1e-6)


def test_model_matches_pycycle_off_grid(db, plant):
    """The piecewise-linear model at steady state (open loop, as pwl validate) against pyCycle's
    trim at random off-grid points inside the tiny grid."""
    errs, pts, failed = steady_state(db, plant, n=2, seed=3)
    assert not failed and len(pts) == 2
    assert np.all(np.isfinite(errs))
    assert np.abs(errs).max() < 2.0, errs             # % of value (stall margin: points)


def test_health_shift_matches_linear_model(plant):
    """A 1 % compressor efficiency loss at fixed corrected speed: the trims' difference against
    the linearization's prediction (Jacobians at the nominal trim, steady state)."""
    p = np.array([1500.0, 0.2, 95.0])
    env = plant.environment(p)
    t0 = plant.trim(p, np.zeros(4), env)
    mats, _ = jacobians(plant, t0, np.zeros(4), env)
    dh = np.array([-0.01, 0.0, 0.0, 0.0])
    t1 = plant.trim(p, dh, env, guess=t0)
    # same N (corrected speed held): du from the state equation, then dy = D du + M dh
    du = -np.linalg.solve(mats["B"], mats["L"] @ dh)
    dy = mats["D"] @ du + mats["M"] @ dh
    np.testing.assert_allclose(t1["u"] - t0["u"], du, rtol=0.05)
    dy_true = t1["y"] - t0["y"]
    assert np.all(np.abs(dy_true - dy) <= 0.1 * np.abs(dy_true) + 1e-4 * np.abs(t0["y"])), (dy_true, dy)


def test_pickles_without_openmdao_problems(plant):
    p = np.array([0.0, 0.1, 97.0])
    env = plant.environment(p)
    t = plant.trim(p, None, env)
    blob = pickle.dumps(plant)
    assert len(blob) < 100_000            # the problems stay behind: rebuilt lazily
    copy = pickle.loads(blob)
    _, y, _ = copy.evaluate(t["x"], t["u"], np.zeros(4), env)
    np.testing.assert_allclose(y, t["y"], rtol=1e-6)


def test_errors_name_the_point(plant, monkeypatch):
    with pytest.raises(pcp.PlantError, match="NR=150"):
        plant.trim(np.array([0.0, 0.0, 150.0]))
    with pytest.raises(pcp.PlantError, match="positive"):
        plant.evaluate(np.array([15000.0]), np.array([-0.1]), None, np.array([0.0, 0.0, 0.0]))
    with pytest.raises(pcp.HealthError, match="outside"):
        plant.trim(np.array([0.0, 0.0, 95.0]), np.array([-0.5, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="unknown parameters"):
        pcp.PyCycleTurbojet(T4=1400.0)
    monkeypatch.setattr(pcp, "_IMPORT_ERROR", ImportError("No module named 'pycycle'"))
    with pytest.raises(pcp.PyCycleMissing, match=r"pip install -e '\.\[pycycle\]'"):
        pcp.PyCycleTurbojet()
