"""The builder when things go wrong: a plant's own exceptions (named with the grid point and the
plant), bad specs and `pwl simulate` inputs (one-line named errors, exit code 2), leftovers of
failed builds (reused or cleared), a killed build (no orphan workers), progress off a terminal,
no RuntimeWarning from a turbofan build, and the plausible log-channel ranges it records.

The plants are the test doubles of tests/slow_plant.py (the linear example plant, which makes
reference values exact) and the turbofan on a tiny grid."""
import io
import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

import slow_plant
from linearize.build import RESUME_NOTE, BuildError, Progress, SerialExecutor, build
from linearize.spec import BuildSpec, SpecError
from pwl.cli import main
from pwl.database import GainDatabase

SPEC = """
[model]
plant = "slow_plant:FailingPlant"
parameters = {parameters}
[trim_grid]
level = [0, 1, 2]
power = [0, 0.5, 1.0, 1.5]
[dynamics_grid]
level = [0, 2]
power = [0.25, 1.25]
[build]
dt = 0.05
[tuners]
n = 2
"""
LINES = {level: [[level, p] for p in (0, 0.5, 1.0, 1.5)] for level in (0, 1, 2)}


def spec_text(parameters="{}"):
    return SPEC.format(parameters=parameters)


def write_spec(tmp_path, parameters="{}", name="s.toml"):
    path = tmp_path / name
    path.write_text(spec_text(parameters))
    return str(path)


def quiet(*a, **k):
    pass


def serial_build(text, out, **kw):
    return build(BuildSpec.parse(text, "s.toml"), out, executor=SerialExecutor(), progress=False,
                 log=quiet, **kw)


def run_cli(capsys, *argv):
    """``pwl ARGV`` in this process: (exit code, stderr lines)."""
    code = main(list(argv))
    return code, capsys.readouterr().err.splitlines()


# ---- 1. a plant's own exceptions name the grid point and the plant -----------------------------
def test_plant_error_in_a_worker_names_the_point(tmp_path):
    """A dynamics point's trim raises an exception that cannot be rebuilt from its pickle: the
    point is replaced and its recorded reason names it, the other points are unaffected (the
    process pool used to break, failing every pending point as BrokenProcessPool)."""
    text = spec_text("{trim_points = [[2, 1.25]]}")
    db = build(BuildSpec.parse(text, "s.toml"), tmp_path / "w.h5", workers=2, progress=False, log=quiet)
    assert db.attrs["dynamics_failures"] == {
        "level=2, power=1.25": "level=2, power=1.25: MapError: no steady state at level 2, power 1.25"}
    assert (db.dyn_status != 0).sum() == 1 and db.dyn_status[1, 1] == 1


def test_jacobian_failure_is_recorded_with_the_point(tmp_path):
    db = serial_build(spec_text("{jacobian_levels = [2]}"), tmp_path / "j.h5")
    reasons = db.attrs["dynamics_failures"]
    assert list(reasons) == ["level=2, power=0.25", "level=2, power=1.25"]
    assert reasons["level=2, power=0.25"] == ("level=2, power=0.25: LinearizationError: perturbing h1 "
                                              "failed in every direction: KeyError: 'health map missing'")
    assert db.attrs["trim_failures"] == {}


@pytest.mark.parametrize("parameters, message", [
    ("{trim_points = %s}" % (LINES[0] + LINES[1] + LINES[2]),
     "plant slow_plant:FailingPlant: every trim failed (12 points), e.g. at level=0, power=0: "
     "MapError: no steady state at level 0, power 0"),
    ("{trim_points = %s}" % LINES[1],
     "plant slow_plant:FailingPlant: no trim converged on the power line level=1 (4 points), e.g. at "
     "level=1, power=0: MapError: no steady state at level 1, power 0"),
    ("{jacobian_levels = [0, 1, 2]}",
     "plant slow_plant:FailingPlant: no dynamics point could be linearized (4 points), e.g. at "
     "level=0, power=0.25: LinearizationError: perturbing h1 failed in every direction: KeyError"),
])
def test_a_build_the_plant_makes_fail_is_one_named_line(tmp_path, capsys, parameters, message):
    code, err = run_cli(capsys, "build", write_spec(tmp_path, parameters), "-o", str(tmp_path / "f.h5"),
                        "--serial", "-q")
    assert code == 2
    assert len(err) == 1 and err[0].startswith(f"pwl build: error: {message}"), err


@pytest.mark.parametrize("edit, key", [
    (("slow_plant:FailingPlant", "slow_plant:FailngPlant"), "[model] plant"),
    (("slow_plant:FailingPlant", "no_such_module:FailingPlant"), "[model] plant"),
    (("dt = 0.05", 'dt = "0.05"'), "[build] dt"),
    (("n = 2", 'n = "two"'), "[tuners] n"),
    (("n = 2", "n = 2\nhealth_sigma = [0.01, 0.02]"), "[tuners] health_sigma"),
    (("n = 2", "n = 2\ntargets = [1, 2]"), "[tuners] targets"),
    (("n = 2", 'n = 2\n[kalman]\nq_x = "big"'), "[kalman] q_x"),
    (("dt = 0.05", "dt = 0.05\nq_x = 1e-3"), "unknown key(s) ['q_x'] in [build]"),
    (("level = [0, 1, 2]", 'level = [0, "1", 2]'), "[trim_grid] level"),
    (("parameters = {}", "parameters = [1, 2]"), "[model] parameters"),
    (("parameters = {}", "parameters = {trim_points = 3}"), "[model] parameters"),
    (("n = 2", "n = 2\ntargets = []"), "[tuners] targets is empty"),
    (("dt = 0.05", "dt = 0.05\nperturbation = {xx = 1e-3}"), "[build] perturbation names unknown 'xx'"),
    (("dt = 0.05", "dt = 0.05\nperturbation = {x1 = -1e-3}"), "[build] perturbation x1 = -0.001: must be"),
])
def test_bad_specs_are_one_line_naming_file_and_key(tmp_path, capsys, edit, key):
    text = spec_text().replace(*edit)
    assert text != spec_text()
    path = tmp_path / "bad.toml"
    path.write_text(text)
    code, err = run_cli(capsys, "build", str(path), "-o", str(tmp_path / "b.h5"), "--serial", "-q")
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"pwl build: error: {path}: ") and key in err[0], err
    assert not (tmp_path / "b.h5").exists()


def test_misspelt_plant_class_suggests_the_name(tmp_path, capsys):
    path = write_spec(tmp_path)
    with open(path, "w") as fh:
        fh.write(spec_text().replace("slow_plant:FailingPlant", "models.turbofan:Turbofn"))
    code, err = run_cli(capsys, "build", path, "-o", str(tmp_path / "b.h5"))
    assert code == 2
    assert err == [f"pwl build: error: {path}: [model] plant: model 'models.turbofan:Turbofn': module "
                   f"'models.turbofan' has no 'Turbofn' (did you mean 'Turbofan'?)"]


@pytest.mark.parametrize("argv, message", [
    (["--health", "hpt_eff=-0.9"], "--health: health parameter hpt_eff = -0.9 is outside the allowed "
                                   "range -0.1..0.1"),
    (["--health", "hpt_eff=-0.01", "--health-end", "hpt_eff=0.5"],
     "--health-end: health parameter hpt_eff = 0.5 is outside the allowed range -0.1..0.1"),
    (["--health", "hpt_efff=-0.01"], "--health: unknown health parameter 'hpt_efff'; known: fan_eff,"),
    (["--health", "hpt_eff=nan"], "--health: health parameter hpt_eff = nan is outside"),
    (["--health", "hpt_eff"], "--health: expected name=value, got 'hpt_eff'"),
])
def test_simulate_bad_health_is_one_named_line(tmp_path, capsys, argv, message):
    out = tmp_path / "f.h5"
    code, err = run_cli(capsys, "simulate", *argv, "-o", str(out))
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"pwl simulate: error: {message}"), err
    assert not out.exists()


# ---- 2. failed builds never block the next one ------------------------------------------------
def test_failed_build_then_a_changed_spec_clears_the_parts(tmp_path, capsys):
    out = str(tmp_path / "c.h5")
    code, err = run_cli(capsys, "build", write_spec(tmp_path, "{trim_points = %s}" % LINES[2]), "-o", out,
                        "--serial", "-q")
    assert code == 2 and "no trim converged on the power line level=2" in err[0]
    assert sorted(os.listdir(out + ".parts")) == ["build-key", "trim_0.npz", "trim_1.npz"]
    code, err = run_cli(capsys, "build", write_spec(tmp_path), "-o", out, "--serial", "-q")
    assert code == 0
    assert err == [f"removed 2 file(s) from {out}.parts/: partial results of a build with another "
                   f"spec or plant"]
    assert os.path.exists(out) and not os.path.exists(out + ".parts")


def test_failed_build_rerun_reuses_the_parts_and_equals_a_clean_build(tmp_path, capsys, monkeypatch):
    """The plant fails on a whole power line, then is fixed: the rerun with the same spec trims
    only that line and gives the database of a clean build."""
    text, out = spec_text(), str(tmp_path / "r.h5")
    monkeypatch.setattr(slow_plant, "BROKEN_LEVELS", {2.0})
    with pytest.raises(BuildError, match="power line level=2 .* MapError: no steady state"):
        serial_build(text, out)
    capsys.readouterr()
    monkeypatch.setattr(slow_plant, "BROKEN_LEVELS", set())
    db = serial_build(text, out)
    assert capsys.readouterr().err.splitlines() == [
        f"resuming: reusing 8 of 12 trim points from {out}.parts/" + RESUME_NOTE]
    clean = serial_build(text, tmp_path / "clean.h5")
    for k in "xuyz":
        np.testing.assert_array_equal(db.trim[k], clean.trim[k])
    for k in "ABCDFGLMN":
        np.testing.assert_array_equal(db.dynamics[k], clean.dynamics[k])
    for k in "KPQR":
        np.testing.assert_array_equal(db.kalman[k], clean.kalman[k])
    np.testing.assert_array_equal(db.trim_status, clean.trim_status)
    np.testing.assert_array_equal(db.tuner["V"], clean.tuner["V"])


def test_a_parts_folder_not_made_by_a_build_is_left_alone(tmp_path):
    out = tmp_path / "n.h5"
    os.makedirs(f"{out}.parts")
    with open(f"{out}.parts/notes.txt", "w") as fh:
        fh.write("mine")
    with pytest.raises(BuildError, match="holds files but no build-key"):
        serial_build(spec_text(), out)
    assert os.listdir(f"{out}.parts") == ["notes.txt"]


# ---- 3. a killed build leaves no orphan workers -----------------------------------------------
def _children(pid: int) -> set[int]:
    """Live (not zombie) processes whose parent is ``pid``, from /proc."""
    out = set()
    for d in os.listdir("/proc"):
        if d.isdigit():
            stat = _stat(int(d))
            if stat and stat[1] != "Z" and int(stat[2]) == pid:
                out.add(int(d))
    return out


def _stat(pid: int):
    """Fields of /proc/PID/stat after the command name (state, ppid, ...), or None."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            text = fh.read()
    except OSError:
        return None
    return [""] + text[text.rindex(")") + 2:].split()


def _alive(pid: int) -> bool:
    stat = _stat(pid)
    return stat is not None and stat[1] != "Z"


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc (Linux)")
def test_sigkill_of_the_build_leaves_no_orphan_workers(tmp_path):
    spec_path = tmp_path / "slow.toml"
    spec_path.write_text(spec_text().replace('"slow_plant:FailingPlant"', '"slow_plant:SlowPlant"')
                         .replace("parameters = {}", "parameters = {delay = 0.3}"))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.dirname(__file__)] + sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "pwl", "build", str(spec_path), "-o", str(tmp_path / "k.h5"),
                             "-j", "2", "-q"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = set()
    try:
        deadline = time.time() + 60
        while time.time() < deadline and len(workers) < 2 and proc.poll() is None:
            workers = _children(proc.pid)
            time.sleep(0.05)
        assert len(workers) >= 2, "the build did not start its workers"
        time.sleep(0.5)  # the workers are trimming (12 trims of 0.3 s on 2 workers)
        assert not (tmp_path / "k.h5").exists()
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        deadline = time.time() + 5
        while time.time() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.05)
        assert not [w for w in workers if _alive(w)]
    finally:
        for w in workers:  # a failed test must not leave them behind either
            if _alive(w):
                os.kill(w, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()


# ---- 5. progress off a terminal ---------------------------------------------------------------
class FakeClock:
    def __init__(self, step):
        self.t, self.step = 0.0, step

    def __call__(self):
        self.t += self.step
        return self.t


@pytest.mark.parametrize("seconds, least, most", [(0.5, 1, 1), (30.0, 5, 7), (1000.0, 9, 11)])
def test_progress_off_a_terminal_prints_a_bounded_number_of_lines(capsys, seconds, least, most):
    """1000 steps taking ``seconds`` in all: at most a line per 10 % and per 5 s, plus the last
    (30 s: a line every 5 s, at 5, 10, ..., 25 s; 1000 s: a line per 10 %)."""
    bar = Progress("trims", 1000, clock=FakeClock(seconds / 1000))
    for i in range(1, 1001):
        bar.update(i)
    for i in range(1001, 1100):  # an optimiser may report beyond its budget: nothing more
        bar.update(i)
    bar.finish()
    lines = capsys.readouterr().err.splitlines()
    assert least <= len(lines) <= most, lines
    assert lines[-1].startswith("trims      [##############################] 1000/1000 completed in")
    assert all("\r" not in line for line in lines)


def test_fast_phase_prints_its_final_line_only(capsys):
    """With the real clock: a fast phase of many steps gives its final line only (it used to
    print one per 10 %)."""
    bar = Progress("dynamics", 500)
    for i in range(1, 501):
        bar.update(i)
    assert len(capsys.readouterr().err.splitlines()) == 1


def test_progress_on_a_terminal_is_a_live_bar():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    bar = Progress("trims", 50, stream=term)
    for i in range(1, 51):
        bar.update(i)
    text = term.getvalue()
    assert text.count("\r") == 50 and text.count("\n") == 1 and text.endswith("\n")
    assert "50/50 completed in" in text.rsplit("\r", 1)[1]


# ---- 4 and 6. a turbofan build: no RuntimeWarning, log channels with their ranges -------------
TINY_TURBOFAN = """
[model]
plant = "models.turbofan:Turbofan"
[trim_grid]
alt = [0, 9000]
Mach = [0, 0.8]
NfR = [70, 100]
[dynamics_grid]
Mach = [0, 0.8]
NfR = [70, 100]
[build]
dynamics_hold = {alt = 6000}
[tuners]
n = 7
targets = ["h", "Fn", "T40"]
"""

#: what the turbofan database must record: unit and plausible range of every log channel it reads
TURBOFAN_LOG_CHANNELS = {
    "Wf": ("kg/s", 0.01, 6.0), "Nf": ("rpm", 420.0, 5460.0), "Nc": ("rpm", 1450.0, 18850.0),
    "T24": ("K", 150.0, 700.0), "Ps30": ("Pa", 5e3, 1e7), "T30": ("K", 150.0, 1200.0),
    "T48": ("K", 150.0, 1700.0), "P50": ("Pa", 3e3, 5e5), "P15": ("Pa", 3e3, 5e5),
    "alt": ("m", -500.0, 15000.0), "Mach": ("-", 0.0, 1.0), "T2": ("K", 170.0, 380.0),
    "P2": ("Pa", 5e3, 2e5)}


@pytest.fixture(scope="module")
def turbofan_db(tmp_path_factory):
    """A tiny turbofan build (7 tuners of 10: 120 candidate subsets, some of them undetectable)
    with every RuntimeWarning an error."""
    out = tmp_path_factory.mktemp("tf") / "tf.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        build(BuildSpec.parse(TINY_TURBOFAN, "tiny.toml"), out, executor=SerialExecutor(), progress=False,
              log=quiet)
    return GainDatabase.open(out)


def test_turbofan_build_has_no_runtime_warning(turbofan_db):
    assert turbofan_db.n("q") == 7 and (turbofan_db.kalman_status == 0).all()


def test_turbofan_database_records_the_log_channels(turbofan_db):
    lc = turbofan_db.log_channels
    assert list(lc) == list(TURBOFAN_LOG_CHANNELS)
    for c, (unit, lo, hi) in TURBOFAN_LOG_CHANNELS.items():
        assert lc[c][0] == unit
        assert lc[c][1:] == pytest.approx((lo, hi), rel=1e-12), c


def test_linear_plant_log_channels_are_unbounded(tmp_path):
    db = serial_build(spec_text(), tmp_path / "l.h5")
    inf = float("inf")
    assert GainDatabase.open(tmp_path / "l.h5").log_channels == db.log_channels == {
        "u1": ("-", -inf, inf), "y1": ("-", -inf, inf), "y2": ("-", -inf, inf), "y3": ("-", -inf, inf),
        "level": ("-", -inf, inf), "power": ("-", -inf, inf)}


def test_the_build_key_changes_with_the_plant_code(tmp_path, monkeypatch):
    """Results kept from an interrupted build are reused only for the same plant code: the key
    of a plant module changes when its file does (a resumed build reused the trims of the code
    before an edit: outputs x2 stored as before)."""
    import importlib
    import sys
    from linearize.build import _plant_code
    (tmp_path / "edited_plant.py").write_text("class P:\n    gain = 1.0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("edited_plant")
    before = _plant_code(mod.P())
    (tmp_path / "edited_plant.py").write_text("class P:\n    gain = 2.0\n")
    assert _plant_code(mod.P()) != before                 # the file changed (the class object did not)
    from models.linear import LinearPlant
    assert _plant_code(LinearPlant()) == _plant_code(LinearPlant()) != ""
    sys.modules.pop("edited_plant", None)


def test_build_will_not_overwrite_a_file_that_is_not_a_database(tmp_path, capsys):
    """-o pointing at the spec (or any file that is not HDF5) is refused before the build (the spec
    was overwritten, exit 0); -j 0 is refused."""
    path = write_spec(tmp_path)
    before = open(path).read()
    code, err = run_cli(capsys, "build", path, "-o", path, "--serial", "-q")
    assert code == 2 and "the file exists and is not an HDF5 file" in err[0] and open(path).read() == before
    code, err = run_cli(capsys, "build", path, "-o", str(tmp_path / "x.h5"), "-j", "0", "-q")
    assert code == 2 and "-j 0" in err[0]


def test_a_health_parameter_no_sensor_sees_is_named():
    """Steady-state effect on the sensors C (I - A)^-1 L + M of the second of three health
    parameters zero at every point (its columns of L and M zero): a warning names it; the
    others are seen."""
    from linearize.build import _warn_unseen
    rng = np.random.default_rng(0)
    pts = []
    for _ in range(3):
        L, M = rng.normal(size=(2, 3)), rng.normal(size=(4, 3))
        L[:, 1] = M[:, 1] = 0.0
        pts.append({"mats": {"A": np.diag([0.9, 0.5]), "C": rng.normal(size=(4, 2)), "L": L, "M": M},
                    "R": np.eye(4) * 1e-4})
    said = []
    _warn_unseen(pts, ["h1", "h2", "h3"], np.full(3, 0.02), said.append)
    assert len(said) == 1 and "no sensor sees h2 at any operating point" in said[0]
    pts[0]["mats"]["M"][0, 1] = 1e-3
    said.clear()
    _warn_unseen(pts, ["h1", "h2", "h3"], np.full(3, 0.02), said.append)
    assert not said


def test_jacobians_take_a_nan_direction_as_failed_and_refuse_wrong_lengths_and_integers():
    """A plant that returns NaN on one side of a perturbation (instead of raising) gets the other
    side's one-sided difference, as one that raises does (before: every point failed with
    'non-finite A', no variable named); an f one longer than the states shifted the rows of C..N
    silently (the build later failed on detectability); integer outputs (all differences zero)
    crashed the tuner selection with a LinAlgError. Reference: the one-sided difference by hand."""
    from linearize.jacobian import LinearizationError, jacobians
    from models.linear import LinearPlant
    pl = LinearPlant()
    p = np.array([1.0, 0.5])
    env = pl.environment(p)
    t = pl.trim(p, np.zeros(3), env)

    class Side(LinearPlant):
        def __init__(self, fail):
            super().__init__()
            self.fail = fail

        def evaluate(self, x, u, h, env):
            f, y, z = super().evaluate(x, u, h, env)
            if h[1] > 0:                           # the + side of the second health parameter
                if self.fail == "raise":
                    raise ValueError("infeasible")
                f = f * np.nan
            return f, y, z
    ref, _ = jacobians(pl, t, np.zeros(3), env)
    nan, info = jacobians(Side("nan"), t, np.zeros(3), env)
    raised, _ = jacobians(Side("raise"), t, np.zeros(3), env)
    assert info["one_sided_columns"] == 1
    for k in ref:
        np.testing.assert_array_equal(nan[k], raised[k])
        np.testing.assert_allclose(nan[k], ref[k], rtol=1e-6, atol=1e-9)   # a linear plant: exact either way

    class Long(LinearPlant):
        def evaluate(self, x, u, h, env):
            f, y, z = super().evaluate(x, u, h, env)
            return np.r_[f, 0.0], y, z

    class Ints(LinearPlant):
        def evaluate(self, x, u, h, env):
            f, y, z = super().evaluate(x, u, h, env)
            return f, np.rint(y).astype(int), z
    with pytest.raises(LinearizationError, match="plant.evaluate returned 3 values of f, the plant has 2"):
        jacobians(Long(), t, np.zeros(3), env)
    with pytest.raises(LinearizationError, match="plant.evaluate returned y as int64: return floats"):
        jacobians(Ints(), t, np.zeros(3), env)


def test_a_trim_that_is_not_the_plants_steady_state_is_a_failed_point(tmp_path):
    """A plant whose trim at one point returns its input 5 % high (its states then move 1.2 % of
    their value in a step of dt by its own evaluate) fails there, named, and the point is filled
    along its power line: for this linear plant the fill is the true trim (to 1e-12, against a
    build of the plant without the fault). Outputs in another order than evaluate's fail every
    point, as do outputs one short (named, not a numpy broadcast error). Before, the first two
    were stored as trims: a user's plant with a 5 % input error read a clean engine 21 % off."""
    text = spec_text().replace("slow_plant:FailingPlant", "slow_plant:UnsteadyPlant")
    clean = serial_build(text, tmp_path / "clean.h5")
    db = serial_build(text.replace("parameters = {}", "parameters = {unsteady_points = [[1, 0.5]]}"),
                      tmp_path / "u.h5")
    assert list(db.attrs["trim_failures"]) == ["level=1, power=0.5"]
    assert "not a steady state: state 'x1' (trim value " in db.attrs["trim_failures"]["level=1, power=0.5"]
    assert db.trim_status[1, 1] != 0 and (db.trim_status != 0).sum() == 1
    for k in "xuyz":
        np.testing.assert_allclose(db.trim[k], clean.trim[k], rtol=1e-12, atol=1e-12)
    with pytest.raises(BuildError, match=r"every trim failed .* not a steady state: output 'y3' is 10 - in the trim, 15 - by "):
        serial_build(text.replace("parameters = {}", "parameters = {swap_y = true}"), tmp_path / "s.h5")
    with pytest.raises(BuildError, match=r"every trim failed .* trim returned 2 y values, the plant names 3 \(y1, y2, y3\)"):
        serial_build(text.replace("parameters = {}", "parameters = {short_y = true}"), tmp_path / "b.h5")


def test_more_tuners_than_sensors_is_refused_before_any_trim(tmp_path):
    text = spec_text().replace("slow_plant:FailingPlant", "slow_plant:TwoSensorPlant").replace("n = 2", "n = 3")
    with pytest.raises(SpecError, match=r"s.toml: \[tuners\] n = 3 is more than the plant's 2 sensors \(y1, y2\)"):
        serial_build(text, tmp_path / "t.h5")
    assert not os.path.exists(tmp_path / "t.h5.parts")


def test_a_failed_build_says_where_its_partial_results_are(tmp_path, capsys, monkeypatch):
    """pwl build failing on a whole power line names the folder of the lines it finished (a rerun
    resumes from them) in its one error line (exit 2); a build that failed before any task
    finished does not."""
    spec, out = write_spec(tmp_path), str(tmp_path / "p.h5")
    monkeypatch.setattr(slow_plant, "BROKEN_LEVELS", {2.0})
    code, err = run_cli(capsys, "build", spec, "-o", out, "--serial", "-q")
    assert code == 2 and len(err) == 1 and err[0].endswith(
        f"; partial results of 2 task(s) kept in {out}.parts/: the same command resumes from them; remove the "
        "folder to start over")
    monkeypatch.setattr(slow_plant, "BROKEN_LEVELS", {0.0, 1.0, 2.0})
    code, err = run_cli(capsys, "build", spec, "-o", str(tmp_path / "q.h5"), "--serial", "-q")
    assert code == 2 and not any("partial results" in e for e in err)
