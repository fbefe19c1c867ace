"""The offline builder against independent references: the known matrices of a linear plant,
scipy's cont2discrete and DARE, python-control's dlqe, a Monte-Carlo run of the true system with
the filter (tuner metric), and failure handling with test-double plants."""
import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.signal import cont2discrete

from linearize.build import RESUME_NOTE, SerialExecutor, build, fill_line
from linearize.jacobian import zoh
from linearize.kalman import predictor_gain
from linearize.spec import BuildSpec, SpecError
from linearize.tuners import point_mse
from models.linear import LinearPlant
from pwl.database import GainDatabase
from pwl.runtime import augment

SPEC = """
[model]
plant = "models.linear:LinearPlant"
[trim_grid]
level = [0, 1, 2]
power = [0, 0.5, 1.0, 1.5]
[dynamics_grid]
level = [0, 2]
power = [0.25, 1.25]
[build]
dt = 0.05
[kalman]
q_x = 1e-3
q_h = 1e-4
[tuners]
method = "{method}"
n = 2
targets = ["h", "z1"]
"""


def spec(method="subset", extra=""):
    return BuildSpec.parse(SPEC.format(method=method) + extra, "test.toml")


def quiet(*a, **k):
    pass


@pytest.fixture(scope="module")
def linear_db(tmp_path_factory):
    out = tmp_path_factory.mktemp("db") / "lin.h5"
    build(spec(), out, executor=SerialExecutor(), progress=False, log=quiet)
    return GainDatabase.open(out)


def test_linear_plant_matrices_recovered(linear_db):
    pl = LinearPlant()
    dt = 0.05
    Ad, BL, _, _, _ = cont2discrete((pl.A, np.hstack([pl.B, pl.L]), np.eye(2), np.zeros((2, 4))), dt, "zoh")
    d = linear_db.dynamics
    for idx in np.ndindex(*linear_db.dyn_grid.shape):
        np.testing.assert_allclose(d["A"][idx], Ad, atol=1e-9)
        np.testing.assert_allclose(d["B"][idx], BL[:, :1], atol=1e-9)
        np.testing.assert_allclose(d["L"][idx], BL[:, 1:], atol=1e-9)
        for k in "CDFGMN":
            np.testing.assert_allclose(d[k][idx], getattr(pl, k), atol=1e-9)


def test_trims_equal_the_plant(linear_db):
    pl = LinearPlant()
    nodes = linear_db.trim_grid.nodes()
    for i, p in enumerate(nodes):
        t = pl.trim(p, np.zeros(3), pl.environment(p))
        for k in "xuyz":
            np.testing.assert_allclose(linear_db.trim[k].reshape(len(nodes), -1)[i], t[k], rtol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_zoh_matches_cont2discrete(seed):
    rng = np.random.default_rng(seed)
    A, B = rng.normal(size=(4, 4)), rng.normal(size=(4, 3))
    Ad, Bd = zoh(A, B, 0.015)
    Ar, Br, *_ = cont2discrete((A, B, np.eye(4), np.zeros((4, 3))), 0.015, "zoh")
    np.testing.assert_allclose(Ad, Ar, atol=1e-12)
    np.testing.assert_allclose(Bd, Br, atol=1e-12)


def test_gains_are_the_dare_update_gains(linear_db):
    import control

    db = linear_db
    aug = augment(db.dynamics, db.tuner["V_pinv"])
    for idx in np.ndindex(*db.dyn_grid.shape):
        A, C, Q, R = aug["A"][idx], aug["C"][idx], db.kalman["Q"][idx], db.kalman["R"][idx]
        P = solve_discrete_are(A.T, C.T, Q, R)
        K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
        np.testing.assert_allclose(db.kalman["K"][idx], K, rtol=1e-8, atol=1e-12)
        L, _, _ = control.dlqe(A, np.eye(A.shape[0]), C, Q, R)
        np.testing.assert_allclose(predictor_gain(A, db.kalman["K"][idx]), L, rtol=1e-7, atol=1e-12)
        K_ = db.kalman["K"][idx]
        assert np.abs(np.linalg.eigvals((np.eye(A.shape[0]) - K_ @ C) @ A)).max() < 1


def test_tuner_metric_matches_monte_carlo():
    """The covariance analysis against a simulation of the true system (full health, constant
    random) with the reduced-order filter, averaged over many draws."""
    pl = LinearPlant()
    dt = 0.05
    Ad, BL = zoh(pl.A, np.hstack([pl.B, pl.L]), dt)
    mats = {"A": Ad, "B": BL[:, :1], "L": BL[:, 1:], "C": pl.C, "D": pl.D, "F": pl.F, "G": pl.G,
            "M": pl.M, "N": pl.N}
    V = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.0]])
    Qx = np.diag([1e-4, 4e-4])
    Qh = np.diag([1e-4] * 3)
    R = np.diag([4e-4, 1e-3, 9e-4])
    Ph = np.diag([0.02, 0.01, 0.03]) ** 2
    z_scale = np.array([100.0, 50.0])
    targets = [0, 1, 2, 3, 4]
    mse = point_mse(mats, V, Qx, Qh, R, Ph, z_scale, targets)

    # Monte Carlo: many engines at once, run to steady state, average the squared errors
    from linearize.kalman import steady_state_gain
    Vp = np.linalg.pinv(V)
    aug = augment(mats, Vp)
    Qa = np.zeros((4, 4))
    Qa[:2, :2], Qa[2:, 2:] = Qx, V @ Qh @ V.T
    K, _ = steady_state_gain(aug["A"], aug["C"], Qa, R)
    rng = np.random.default_rng(1)
    runs, steps, settle = 4000, 1500, 500
    h = rng.multivariate_normal(np.zeros(3), Ph, runs)
    x = np.zeros((runs, 2))
    xi = np.zeros((runs, 4))  # a-priori filter state
    acc = np.zeros(5)
    cnt = 0
    for k in range(steps):
        y = x @ pl.C.T + h @ pl.M.T + rng.multivariate_normal(np.zeros(3), R, runs)
        xp = xi + (y - xi @ aug["C"].T) @ K.T
        if k >= settle:
            eh = h - xp[:, 2:] @ Vp.T
            ez = ((x @ pl.F.T + h @ pl.N.T) - xp @ aug["F"].T) / z_scale
            acc += np.mean(np.hstack([eh, ez]) ** 2, axis=0)
            cnt += 1
        x = x @ Ad.T + h @ mats["L"].T + rng.multivariate_normal(np.zeros(2), Qx, runs)
        xi = xp @ aug["A"].T
    mc = acc / cnt
    # sampling error of a mean square over 4000 independent draws: ~ sqrt(2/4000) = 2.2 %
    np.testing.assert_allclose(mse, mc, rtol=0.08)


def test_optimal_tuners_not_worse_than_best_subset(tmp_path):
    db = build(spec("optimal"), tmp_path / "opt.h5", executor=SerialExecutor(), progress=False, log=quiet)
    assert db.attrs["tuner_method"] == "optimal"
    assert db.attrs["tuner_metric"] <= db.attrs["tuner_subset_metric"] * (1 + 1e-12)
    assert db.tuner["V"].shape == (2, 3)
    np.testing.assert_allclose(db.tuner["V_pinv"], np.linalg.pinv(db.tuner["V"]), atol=1e-12)


class FailingPlant(LinearPlant):
    """Fails trims at chosen (level, power) points."""

    def __init__(self, fail=()):
        super().__init__()
        self.fail = [tuple(map(float, p)) for p in fail]

    def trim(self, p, h, env, guess=None):
        if tuple(map(float, p)) in self.fail:
            raise RuntimeError(f"trim did not converge at {tuple(p)}")
        return super().trim(p, h, env, guess)


def test_failed_points_are_filled_and_replaced(tmp_path):
    # trims fail inside a power line (filled), at its top (extrapolated), and at a dynamics point
    plant = FailingPlant(fail=[(1, 0.5), (2, 1.5), (2, 1.25)])
    db = build(spec(), tmp_path / "f.h5", plant=plant, executor=SerialExecutor(), progress=False, log=quiet)
    db = GainDatabase.open(tmp_path / "f.h5")
    st = db.trim_status
    assert st[1, 1] == 1 and st[2, 3] == 2 and (st != 0).sum() == 2
    # the plant is linear in power: filled and extrapolated trims are exact
    ref = LinearPlant()
    for (i, j) in [(1, 1), (2, 3)]:
        p = np.array([db.trim_grid.axes[0].values[i], db.trim_grid.axes[1].values[j]])
        np.testing.assert_allclose(db.trim["y"][i, j], ref.trim(p, np.zeros(3), None)["y"], rtol=1e-12)
    # dynamics point (level 2, power 1.25) = flat index 3 failed; nearest good (ties: lowest) = 1
    assert db.dyn_status[1, 1] == 1 and db.dyn_donor[1, 1] == 1
    assert (db.dyn_status != 0).sum() == 1 and db.dyn_donor[0, 0] == -1
    np.testing.assert_array_equal(db.dynamics["A"][1, 1], db.dynamics["A"][0, 1])
    assert db.kalman_status[1, 1] == 1 and db.kalman_donor[1, 1] == 1
    assert list(db.attrs["dynamics_failures"]) == ["level=2, power=1.25"]
    assert set(db.attrs["trim_failures"]) == {"level=1, power=0.5", "level=2, power=1.5", }


def test_fill_line_extrapolates_both_ends():
    v = np.array([[np.nan], [1.0], [2.0], [np.nan], [4.0], [np.nan]])
    ok = np.isfinite(v[:, 0])
    out, st = fill_line(v, ok, np.arange(6.0))
    np.testing.assert_allclose(out[:, 0], [0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(st, [2, 0, 0, 1, 0, 2])


class InterruptingPlant(LinearPlant):
    """Counts trims; raises KeyboardInterrupt (a kill) after ``limit`` of them."""

    def __init__(self, limit=None):
        super().__init__()
        self.limit, self.calls = limit, 0

    def trim(self, p, h, env, guess=None):
        self.calls += 1
        if self.limit is not None and self.calls > self.limit:
            raise KeyboardInterrupt
        return super().trim(p, h, env, guess)


def test_interrupted_build_resumes(tmp_path):
    out = tmp_path / "r.h5"
    with pytest.raises(KeyboardInterrupt):
        build(spec(), out, plant=InterruptingPlant(limit=9), executor=SerialExecutor(), progress=False,
              log=quiet)
    assert not out.exists()
    kept = sorted(p.name for p in (tmp_path / "r.h5.parts").iterdir())
    assert len([k for k in kept if k.startswith("trim_")]) == 2  # 2 of 3 power lines finished
    again = InterruptingPlant()
    db = build(spec(), out, plant=again, executor=SerialExecutor(), progress=False, log=quiet)
    assert again.calls == 4 + 4  # the one missing power line + the four dynamics trims
    assert not (tmp_path / "r.h5.parts").exists()
    full = build(spec(), tmp_path / "full.h5", executor=SerialExecutor(), progress=False, log=quiet)
    for k in "xuyz":
        np.testing.assert_array_equal(db.trim[k], full.trim[k])
    np.testing.assert_array_equal(db.kalman["K"], full.kalman["K"])


def test_parts_are_reused_for_other_tuners_and_cleared_for_another_grid(tmp_path, capsys):
    """Kept parts serve a spec that differs in [tuners] only (phases 3-4); another trim grid
    removes them, saying so."""
    out = tmp_path / "x.h5"
    build(spec(), out, executor=SerialExecutor(), progress=False, log=quiet, keep_parts=True)
    build(spec("optimal"), out, executor=SerialExecutor(), progress=False, log=quiet, keep_parts=True)
    assert capsys.readouterr().err.splitlines() == [
        f"resuming: reusing 12 of 12 trim points from {out}.parts/" + RESUME_NOTE,
        f"resuming: reusing 4 of 4 dynamics points from {out}.parts/" + RESUME_NOTE]
    other = BuildSpec.parse(SPEC.format(method="subset").replace("level = [0, 1, 2]", "level = [0, 1, 3]"),
                            "other.toml")
    db = build(other, out, executor=SerialExecutor(), progress=False, log=quiet)
    assert capsys.readouterr().err.splitlines() == [
        f"removed 7 file(s) from {out}.parts/: partial results of a build with another spec or plant"]
    assert db.trim_grid.axes[0].values.tolist() == [0, 1, 3] and not (tmp_path / "x.h5.parts").exists()


def test_process_pool_gives_the_same_database(tmp_path, linear_db):
    db = build(spec(), tmp_path / "pp.h5", workers=2, progress=False, log=quiet)
    for k in "ABCLMN":
        np.testing.assert_array_equal(db.dynamics[k], linear_db.dynamics[k])
    np.testing.assert_array_equal(db.kalman["K"], linear_db.kalman["K"])


def test_dask_local_cluster(tmp_path, linear_db):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        db = build(spec(), tmp_path / "dask.h5", executor=client.get_executor(), progress=False, log=quiet)
    np.testing.assert_array_equal(db.kalman["K"], linear_db.kalman["K"])


@pytest.mark.parametrize("extra, msg", [
    ("[build]\nout_of_range = 'wrap'\n", "out_of_range"),
    ("[bogus]\nx = 1\n", "unknown section"),
])
def test_bad_specs_are_named(extra, msg):
    text = SPEC.format(method="subset")
    if extra.startswith("[build]"):
        text = text.replace("[build]\n", extra)
    else:
        text += extra
    with pytest.raises(SpecError, match=msg):
        BuildSpec.parse(text, "bad.toml")


@pytest.mark.parametrize("change, msg", [
    (("q_h = 1e-4", "q_h = -1e-4"), r"\[kalman\] q_h for 'h1' is -0.0001: a standard deviation, it must be finite and >= 0"),
    (("q_x = 1e-3", "q_x = nan"), r"\[kalman\] q_x for 'x1' is nan"),
    (("n = 2", "n = 2\nhealth_sigma = 0"), r"\[tuners\] health_sigma for 'h1' is 0.0: .* > 0"),
    (("q_h = 1e-4", "q_h = 1e-4\nr = {y1 = -0.01}"), r"sensor noise \(the plant's sensor_noise, then \[kalman\] r\) for 'y1' is -0.01"),
])
def test_noise_sigmas_that_are_not_standard_deviations_are_named(tmp_path, change, msg):
    s = BuildSpec.parse(SPEC.format(method="subset").replace(*change), "sig.toml")
    with pytest.raises(SpecError, match=msg):
        build(s, tmp_path / "a.h5", executor=SerialExecutor(), progress=False, log=quiet)
    assert not (tmp_path / "a.h5").exists()


def test_spec_with_wrong_axes_is_named(tmp_path):
    s = BuildSpec.parse(SPEC.format(method="subset").replace("level", "altitude"), "axes.toml")
    with pytest.raises(SpecError, match="scheduling variables"):
        build(s, tmp_path / "a.h5", executor=SerialExecutor(), progress=False, log=quiet)


def test_validate_linear_plant(tmp_path):
    """Open-loop model vs plant: exact at steady state for a linear plant; the transient differs
    only by the runtime's sample convention (the input of sample k drives the step into k)."""
    from linearize.validate import fuel_step, steady_state

    out = tmp_path / "v.h5"
    build(spec(), out, executor=SerialExecutor(), progress=False, log=quiet)
    db = GainDatabase.open(out)
    errs, pts, failed = steady_state(db, n=4, settle_steps=2000)
    assert not failed and len(pts) == 4
    assert np.abs(errs).max() < 1e-8
    tr = fuel_step(db, step=0.05, seconds=4.0)
    assert np.abs(tr["error"]).max() < 0.1
    # the trim tables at the runtime's scheduling variables: a linear plant's trims are linear
    # in p, so multilinear interpolation is exact (the plant's own trim is the reference)
    from linearize.validate import scheduled_trims
    errs, pts, failed = scheduled_trims(db, n=5)
    assert not failed and len(pts) == 5 and np.abs(errs).max() < 1e-8
    moved = np.abs(tr["truth"][-1] - tr["truth"][0]) / np.abs(tr["truth"][0])
    assert moved.max() > 1e-3  # the step did move the plant


def test_killed_build_process_resumes(tmp_path):
    """SIGKILL a `pwl build` process half-way; the next build reuses every finished power line."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import slow_plant

    text = SPEC.format(method="subset").replace('plant = "models.linear:LinearPlant"',
                                                'plant = "slow_plant:SlowPlant"\nparameters = {delay = 0.15}')
    spec_path = tmp_path / "slow.toml"
    spec_path.write_text(text)
    out = tmp_path / "k.h5"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.dirname(__file__)] + sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "pwl", "build", str(spec_path), "-o", str(out),
                             "--serial", "-q"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parts = tmp_path / "k.h5.parts"
    deadline = time.time() + 60
    while time.time() < deadline and len(list(parts.glob("trim_*.npz"))) < 1:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = sorted(p.name for p in parts.glob("trim_*.npz"))
    assert 1 <= len(done) < 3 and not out.exists()
    slow_plant.CALLS["trim"] = 0
    db = build(BuildSpec.parse(text, str(spec_path)), out, executor=SerialExecutor(), progress=False, log=quiet)
    # only the unfinished power lines (4 trims each) and the 4 dynamics points were trimmed again
    assert slow_plant.CALLS["trim"] == 4 * (3 - len(done)) + 4
    ref = build(spec(), tmp_path / "ref.h5", executor=SerialExecutor(), progress=False, log=quiet)
    np.testing.assert_array_equal(db.trim["y"], ref.trim["y"])


def test_dynamics_grid_on_some_scheduling_variables(tmp_path):
    """Matrices scheduled on `power` only, `level` held: the runtime interpolates them on one axis;
    the linear plant's matrices do not depend on the point, so they are still recovered exactly."""
    text = SPEC.format(method="subset").replace("[dynamics_grid]\nlevel = [0, 2]\n", "[dynamics_grid]\n")
    text = text.replace("[build]\n", "[build]\ndynamics_hold = {level = 0.5}\n")
    db = build(BuildSpec.parse(text, "sub.toml"), tmp_path / "s.h5", executor=SerialExecutor(),
               progress=False, log=quiet)
    db = GainDatabase.open(tmp_path / "s.h5")
    assert db.dyn_grid.names == ("power",) and db.attrs["dynamics_hold"] == {"level": 0.5}
    full = build(spec(), tmp_path / "f.h5", executor=SerialExecutor(), progress=False, log=quiet)
    np.testing.assert_allclose(db.dynamics["A"][0], full.dynamics["A"][0, 0], atol=1e-12)
    np.testing.assert_allclose(db.kalman["K"][1], full.kalman["K"][0, 1], rtol=1e-8, atol=1e-12)
    from linearize.validate import steady_state
    errs, pts, failed = steady_state(db, n=3, settle_steps=1500)
    assert not failed and np.abs(errs).max() < 1e-8
    with pytest.raises(SpecError, match="dynamics_hold"):
        build(BuildSpec.parse(text.replace("level = 0.5", "power = 0.5"), "bad.toml"), tmp_path / "b.h5",
              executor=SerialExecutor(), progress=False, log=quiet)


def test_retune_equals_a_fresh_build(linear_db, tmp_path):
    """Tuners and gains recomputed from a saved database equal a build from the plant."""
    from linearize.build import retune

    again = retune(linear_db, n_tuners=1, targets=["h", "z1"], q_h=1e-4, log=quiet)
    text = SPEC.format(method="subset").replace("n = 2", "n = 1")
    fresh = build(BuildSpec.parse(text, "n1.toml"), tmp_path / "n1.h5", executor=SerialExecutor(),
                  progress=False, log=quiet)
    assert again.names["q"] == fresh.names["q"]
    np.testing.assert_allclose(again.tuner["V"], fresh.tuner["V"])
    np.testing.assert_allclose(again.kalman["K"], fresh.kalman["K"], rtol=1e-9, atol=1e-13)
    assert again.attrs["tuner_metric"] == pytest.approx(fresh.attrs["tuner_metric"], rel=1e-9)
