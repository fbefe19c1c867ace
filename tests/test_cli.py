"""What a new user of the command line meets: output paths checked before any computation, fixed
legend places (``loc="best"`` is slow on long lines), ``pwl trend`` in percent and in flight-time
order, and a help text stating every option's default (``pwl validate``'s limits and verdicts:
tests/test_validate.py)."""
import argparse
import ast
import importlib
import os

import numpy as np
import pytest

from pwl.cli import COMMANDS, main
from pwl.cli.output import OutputPathError, check_output
from pwl.errors import PwlError

DATA = os.path.join(os.path.dirname(__file__), "..", "data")
DB = os.path.join(DATA, "turbofan_demo.h5")
ROOT = os.path.join(os.path.dirname(__file__), "..")

#: the modules that make plots (and so legends)
PLOTTING = ["pwl/cli/demo.py", "pwl/cli/validate.py", "pwl/cli/bias.py", "pwl/cli/biastable.py",
            "pwl/cli/tables.py", "pwl/cli/zones.py", "pwl/fleet/trending.py"]


# ---- 1. fixed legend places -------------------------------------------------------------------
@pytest.mark.parametrize("path", PLOTTING)
def test_every_legend_has_a_fixed_place(path):
    with open(os.path.join(ROOT, path)) as f:
        tree = ast.parse(f.read())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
             and n.func.attr == "legend"]
    assert calls, path
    for c in calls:
        loc = [k.value for k in c.keywords if k.arg == "loc"]
        assert loc and isinstance(loc[0], ast.Constant) and loc[0].value != "best", \
            f"{path}:{c.lineno}: legend without a fixed loc"


def test_demo_plot_legends_are_fixed(figures):
    from types import SimpleNamespace

    from pwl.cli import demo

    n = 2000
    t = np.arange(n) * 0.015
    truth = {"Fn": np.full(n, 3e4), "T40": np.full(n, 1300.0), "hpc_eff": np.full(n, -0.01)}
    log = SimpleNamespace(time=t, truth=truth)
    res = SimpleNamespace(channel=lambda kind, ch: truth[ch] * 1.001, h_hat=np.full((n, 2), -0.01))
    demo._plot([("flight", log, res, res)], ["hpc_eff", "hpt_eff"], os.devnull)
    legends = [ax.get_legend() for ax in figures[0].axes if ax.get_legend() is not None]
    assert len(legends) == 3
    assert all(lg._loc != 0 for lg in legends)      # 0 is matplotlib's code of "best"


# ---- 2. output paths checked before computing -------------------------------------------------
def test_check_output_creates_a_missing_folder_and_names_bad_paths(tmp_path, unwritable):
    check_output(tmp_path / "new" / "deeper" / "x.png")
    assert (tmp_path / "new" / "deeper").is_dir()
    assert not list((tmp_path / "new" / "deeper").iterdir())     # the probe file is gone
    check_output(tmp_path / "out", folder=True)
    assert (tmp_path / "out").is_dir()
    check_output("")                                             # no output: nothing to check
    with pytest.raises(OutputPathError, match="sub"):
        check_output(unwritable)
    with pytest.raises(OutputPathError, match="is a folder"):
        check_output(tmp_path)
    assert issubclass(OutputPathError, PwlError)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes anywhere")
def test_check_output_refuses_a_read_only_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(OutputPathError, match="not writable"):
            check_output(ro / "x.png")
    finally:
        ro.chmod(0o755)


def test_demo_checks_its_plot_path_before_computing(monkeypatch, capsys, unwritable):
    import pwl.estimator

    def no_estimator(*a, **k):
        raise AssertionError("the demo computed before checking its plot path")

    monkeypatch.setattr(pwl.estimator, "Estimator", no_estimator)
    assert main(["demo", "--plot", unwritable]) == 2
    err = capsys.readouterr().err
    assert unwritable in err and "cannot create the folder" in err


@pytest.mark.parametrize("argv", [
    ["validate", DB, "--plot", "{bad}"],
    ["trend", "r1.estimates.h5", "r2.estimates.h5", "--plot", "{bad}"],
    ["fleet", "diagnose", "results/", "-o", "{bad}"],
    ["fleet", "score", "diagnosis.csv", "truth.csv", "--plot", "{bad}"],
    ["fleet", "simulate", "--engines", "1", "--flights", "1", "-o", "{bad}"],
    ["tables", "seed000", "--out", "{bad}"],
    ["zones", "--save", "{bad}"],
    ["zones", "--database", DB, "--out", "{bad}"],
    ["zones", "--plots", "{bad}"],
    ["bias", "--plot", "{bad}"],
    ["biastable", "--plot", "{bad}"],
], ids=lambda a: " ".join(a[:2]))
def test_every_output_path_is_checked_first(argv, capsys, unwritable):
    assert main([a.replace("{bad}", unwritable) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "cannot create the folder" in err and os.path.dirname(unwritable) in err


# ---- 3. pwl trend: percent and time order -----------------------------------------------------
def test_trend_prints_the_diagnosis_in_percent():
    from pwl.fleet.diagnose import Decision
    from pwl.fleet.trending import EngineTrend, readable_detail

    units = {"hpt_eff": "%", "hpt_flow": "%", "sensor:T48": "K", "sensor:Wf": "%"}
    assert readable_detail("hpt_eff=-0.01735 hpt_flow=+0.00760", units) == "hpt_eff -1.74 %, hpt_flow +0.76 %"
    assert readable_detail("sensor:T48=+15.20000", units) == "sensor:T48 +15.2 K"
    assert readable_detail("sensor:Wf=-0.01000 other=1", units) == "sensor:Wf -1.00 %, other=1"
    d = Decision("E1", 1, "f1", "f1.h5", "ok", detected=1, cls="hpt", kind="step", onset=1,
                 magnitude=-0.0174, magnitude_std=0.001, confidence=0.9, runner_up="lpt",
                 detail="hpt_eff=-0.01735 hpt_flow=+0.00760")
    base = Decision("E1", 0, "f0", "f0.h5", "baseline")
    H = np.array([[0.0, 0.0], [-0.0174, 0.0076]])
    tr = EngineTrend("E1", ["f0", "f1"], ["hpt_eff", "hpt_flow"], H, H[-1], H[-1] - H[0],
                     np.zeros(2), [base, d], units)
    text = tr.table()
    assert "-0.01735" not in text and "+0.00760" not in text
    assert "hpt step since flight 1: hpt_eff -1.74 %, hpt_flow +0.76 %" in text
    assert "FAULT: hpt (step since flight 1), size -1.74 +- 0.10 %" in text


def test_trend_orders_flights_by_flight_time_not_by_file_name(tmp_path, capsys):
    from pwl.logs import read_log, write_log

    logs = tmp_path / "logs"
    logs.mkdir()
    # alphabetical order (a, b) is the reverse of time order: b is the new engine, flown first
    for name, src, when in (("b_first", "flight_new.h5", "2024-01-01T08:00:00"),
                            ("a_second", "flight_degraded.h5", "2024-03-01T08:00:00")):
        log = read_log(os.path.join(DATA, src))
        log.attrs["flight_time"] = when
        write_log(logs / f"{name}.h5", log)
    out = tmp_path / "out"
    assert main(["run", DB, str(logs), "-o", str(out), "-j", "1"]) == 0
    capsys.readouterr()
    assert main(["trend", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = [ln.split()[0] for ln in lines if ln.startswith(("a_second", "b_first"))]
    assert rows == ["b_first", "a_second"]
    slope = next(ln for ln in lines if ln.startswith("slope/flight")).split()[1:]
    header = next(ln for ln in lines if ln.startswith("flight ")).split()[1:]
    assert float(slope[header.index("hpc_e")]) == pytest.approx(-2.0, abs=0.5)   # % per flight


def test_trend_help_states_the_exit_status(capsys):
    with pytest.raises(SystemExit):
        main(["trend", "-h"])
    out = " ".join(capsys.readouterr().out.split())
    assert "exit status 1 when a fault is detected" in out and "percent" in out


# ---- 4. every option says what it is and its default ------------------------------------------
def _options(parser, where):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield from _options(sub, f"{where} {name}")
        elif not isinstance(a, argparse._HelpAction):
            yield where, a


OWN = [c for c in COMMANDS if c not in ("run", "build", "simulate")]


@pytest.mark.parametrize("command", OWN)
def test_every_option_has_help_stating_its_default(command):
    p = argparse.ArgumentParser(prog=f"pwl {command}")
    importlib.import_module(COMMANDS[command]).add_arguments(p)
    for where, a in _options(p, command):
        name = a.option_strings[-1] if a.option_strings else a.dest
        assert a.help, f"pwl {where} {name}: no help"
        if a.option_strings and not a.required:
            assert "default" in a.help, f"pwl {where} {name}: default not stated"
    p.format_help()     # the %(default)s placeholders format


def test_pwl_run_says_which_sensor_a_log_lacks_in_one_line(tmp_path, capsys):
    """A log without P15 runs (P15 dead on every sample); ``pwl run`` says so on one line and
    leaves Python's warning display as it was. The health estimates need P15: held on most
    samples, the log counts as one with too few estimates (exit 1, saying why)."""
    import warnings

    from pwl.logs import Log, read_log, write_log
    log = read_log(os.path.join(DATA, "flight_new.h5"))
    keep = [c for c in log.channels if c != "P15"]
    write_log(tmp_path / "nop15.h5", Log(log.time[:4000], {c: log.channels[c][:4000] for c in keep},
                                         {c: log.units[c] for c in keep}))
    shown = warnings.showwarning
    assert main(["run", DB, str(tmp_path / "nop15.h5"), "-o", str(tmp_path / "out"), "-j", "1"]) == 1
    cap = capsys.readouterr()
    assert "TOO FEW ESTIMATES: health held on " in cap.err and "missing or implausible: P15 100%" in cap.err
    assert "pwl: warning: " + str(tmp_path / "nop15.h5") + ": no 'P15' channel: run without that sensor" in cap.err
    assert "4000 partial update" in cap.out + cap.err
    assert warnings.showwarning is shown


def test_a_reader_that_closes_the_pipe_ends_the_command_quietly(tmp_path):
    """pwl fleet score ... | head: the pipe closes while pwl still prints; exit 0 without an
    'error: [Errno 32] Broken pipe' line (a subprocess whose stdout is a pipe closed at once)."""
    import subprocess
    import sys
    code = ("import sys\nfrom pwl.cli import main\nimport pwl.cli.info as info\n"
            "def loud(args):\n    for _ in range(100000):\n        print('x' * 80)\n"
            "info.run = loud\nsys.exit(main(['info', 'x.h5']))\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.read(10)
    proc.stdout.close()                      # the reader goes away
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err
