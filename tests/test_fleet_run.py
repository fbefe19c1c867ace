"""Fleet runs (issue #15): run_many on any executor gives exactly the serial results, resumes
without repeating a finished flight (also after a SIGKILL), thins and selects exactly the asked
samples and outputs, writes a fleet summary that matches the results files, and points numba's
cache where workers can share it."""
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import h5py
import numpy as np
import pytest

import pwl
from pwl.errors import UsageError
from pwl.estimator import Estimator
from pwl.fleet.runs import (FAILED, OK, SKIPPED, read_summary, run_many, summary_rows,
                           write_summary)
from pwl.fleet.runs import run_log as _run_log
from pwl.logs import Log, read_log, write_log
from pwl.results import FLAG_COUNTS, Result
from pwl.runtime import FLAG_NO_UPDATE, FLAG_NOT_STARTED

ROOT = os.path.join(os.path.dirname(__file__), "..")
DATA = os.path.join(ROOT, "data")
DB = os.path.join(DATA, "turbofan_demo.h5")
CRUISE = 29900          # the demo flights are steady from about here (448 s) for 75 s
_FLIGHTS = {}


def demo_flight(name: str) -> Log:
    if name not in _FLIGHTS:
        _FLIGHTS[name] = read_log(os.path.join(DATA, name + ".h5"))
    return _FLIGHTS[name]


def slice_log(path, source="flight_new", start=CRUISE, n=4500, engine=None, flight_index=None, scale=1.0):
    """Write samples start..start+n of a demo flight as a log (a steady snapshot fits in 4500
    cruise samples); ``scale`` multiplies the fuel flow (a different log of the same length)."""
    src = demo_flight(source)
    chans = {k: v[start:start + n] * (scale if k == "Wf" else 1.0) for k, v in src.channels.items()}
    attrs = {"dt": 0.015} | ({"engine": engine} if engine else {}) | (
        {"flight_index": flight_index} if flight_index is not None else {})
    os.makedirs(os.path.dirname(os.fspath(path)), exist_ok=True)
    write_log(path, Log(src.time[start:start + n] - src.time[start], chans, dict(src.units), attrs=attrs))
    return os.fspath(path)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Four short logs in an engine tree (two engines, same file names), one flight degraded."""
    d = tmp_path_factory.mktemp("fleet")
    logs = []
    for e, eng in enumerate(("ESN1", "ESN2")):
        for k in range(2):
            src = "flight_degraded" if (e, k) == (1, 1) else "flight_new"
            logs.append(slice_log(d / eng / f"flight_{k:03d}.h5", src, CRUISE + 600 * k + 300 * e,
                                  engine=eng, flight_index=k))
    return logs


def datasets(path) -> dict:
    """Every dataset of a results file (snapshots included) as arrays."""
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def assert_same_results(a, b):
    da, db = datasets(a), datasets(b)
    assert sorted(da) == sorted(db)
    for k in da:
        np.testing.assert_array_equal(da[k], db[k], err_msg=k)


def stamps(folder) -> dict:
    """results file -> (inode, mtime) of every results file below ``folder``."""
    out = {}
    for d, _, files in os.walk(folder):
        for f in files:
            if f.endswith(".estimates.h5"):
                st = os.stat(os.path.join(d, f))
                out[os.path.relpath(os.path.join(d, f), folder)] = (st.st_ino, st.st_mtime_ns)
    return out


# ---- executors ---------------------------------------------------------------------------------
def test_process_pool_results_equal_serial_results_exactly(fleet, tmp_path):
    serial = run_many(DB, fleet, tmp_path / "serial", workers=1)
    with ProcessPoolExecutor(2) as ex:
        pooled = run_many(DB, fleet, tmp_path / "pool", executor=ex)
    assert [r.status for r in serial] == [r.status for r in pooled] == [OK] * 4
    # folder trees keep the engine: ESN1/flight_000 and ESN2/flight_000 stay apart
    assert [os.path.relpath(r.output, tmp_path / "serial") for r in serial] == [
        os.path.join(e, f"flight_{k:03d}.estimates.h5") for e in ("ESN1", "ESN2") for k in range(2)]
    for s, p in zip(serial, pooled):
        assert_same_results(s.output, p.output)
    # and both equal the in-memory run of the whole log (another code path: no chunks, no files)
    whole = Estimator(DB).run(fleet[3])
    with h5py.File(serial[3].output, "r") as f:
        for o in whole.outputs:
            np.testing.assert_array_equal(f[o][()], whole.outputs[o], err_msg=o)
        np.testing.assert_array_equal(f["flags"][()], whole.flags)


def test_dask_cluster_results_equal_serial_and_resume(fleet, tmp_path):
    distributed = pytest.importorskip("distributed", reason="dask.distributed is not installed "
                                      "(pip install -e '.[test]')")
    from pwl.fleet.runs import local_dask_cluster

    serial = run_many(DB, fleet, tmp_path / "serial", workers=1)
    with local_dask_cluster(2) as cluster, distributed.Client(cluster) as client:    # 2 processes
        first = run_many(DB, fleet, tmp_path / "dask", executor=client)
        again = run_many(DB, fleet, tmp_path / "dask", executor=client)
        env = client.run(lambda: (os.getpid(), os.environ.get("MALLOC_TRIM_THRESHOLD_"),
                                  os.environ.get("OPENBLAS_NUM_THREADS")))
    assert [r.status for r in first] == [OK] * 4, [r.error for r in first]
    assert [r.status for r in again] == [SKIPPED] * 4
    pids = {pid for pid, _, _ in env.values()}
    assert os.getpid() not in pids and len(pids) == 2
    assert {(trim, blas) for _, trim, blas in env.values()} == {(None, "1")}
    for s, d in zip(serial, first):
        assert_same_results(s.output, d.output)


def test_workers_open_the_database_once_per_process(fleet, tmp_path, monkeypatch):
    """The per-process cache that executors without initializers (Dask) rely on."""
    from pwl.fleet import runs as fleet_run
    from pwl.database import GainDatabase

    real = GainDatabase.open.__func__
    opened = []

    def counting(cls, path, *a, **k):
        opened.append(path)
        return real(cls, path, *a, **k)

    job = fleet_run.Job(os.path.abspath(DB), GainDatabase.open(DB).digest)
    monkeypatch.setattr(fleet_run, "_DATABASES", {})
    monkeypatch.setattr(fleet_run, "_THREAD", type(fleet_run._THREAD)())
    monkeypatch.setattr(GainDatabase, "open", classmethod(counting))
    for i, log in enumerate(fleet):
        assert fleet_run.run_log(job, log, str(tmp_path / f"r{i}.estimates.h5")).status == OK
    assert opened == [os.path.abspath(DB)]
    changed = fleet_run.Job(job.database, "0" * 64)          # the database changed since the run began
    monkeypatch.setattr(fleet_run, "_THREAD", type(fleet_run._THREAD)())
    item = fleet_run.run_log(changed, fleet[0], str(tmp_path / "c.estimates.h5"))
    assert item.status == FAILED and "changed since this run started" in item.error


# ---- resume ------------------------------------------------------------------------------------
def test_rerun_skips_finished_logs_and_recomputes_changed_ones(fleet, tmp_path, monkeypatch):
    logs = [slice_log(tmp_path / "logs" / f"f{i}.h5", start=CRUISE + 100 * i, n=1500) for i in range(4)]
    out = tmp_path / "out"
    gappy = read_log(logs[3])
    gappy.channels["T48"][:10] = np.nan                    # missing samples: named again when skipped
    write_log(logs[3], gappy)
    first = run_many(DB, logs, out, workers=1)
    assert {r.status for r in first} == {OK}
    before = stamps(out)
    again = run_many(DB, logs, out, workers=1)
    assert [r.status for r in again] == [SKIPPED] * 4 and stamps(out) == before
    assert again[0].counts["samples"] == 1500                 # counts of a skipped log: from its file
    assert again[3].counts["missing_channels"] == {"T48": 10} == {
        c: v for c, v in first[3].counts["missing_channels"].items() if v}
    slice_log(logs[1], n=1500, start=CRUISE + 100, scale=1.001)  # the log changed: new digest
    with open(again[2].output, "r+b") as fh:                 # a damaged results file
        fh.seek(-100, os.SEEK_END)
        fh.write(b"\xff" * 10)
    third = run_many(DB, logs, out, workers=1)
    assert [r.status for r in third] == [SKIPPED, OK, OK, SKIPPED]
    want = Estimator(DB).run(logs[1]).z_hat
    with h5py.File(third[1].output, "r") as f:
        np.testing.assert_array_equal(f["z_hat"][()], want)
    # results of another pwl version are recomputed (it may estimate otherwise)
    with h5py.File(third[3].output, "r") as f:
        assert f.attrs["pwl_version"] == pwl.__version__
    monkeypatch.setattr(pwl, "__version__", "0.0.1")
    assert [r.status for r in run_many(DB, logs, out, workers=1)] == [OK] * 4
    monkeypatch.undo()
    # another output selection or thinning is another result; --force recomputes everything
    assert {r.status for r in run_many(DB, logs, out, workers=1, outputs=["h_hat"])} == {OK}
    assert {r.status for r in run_many(DB, logs, out, workers=1, outputs=["h_hat"])} == {SKIPPED}
    assert {r.status for r in run_many(DB, logs, out, workers=1, outputs=["h_hat"], every=2)} == {OK}
    forced = run_many(DB, logs, out, workers=1, outputs=["h_hat"], every=2, force=True)
    assert {r.status for r in forced} == {OK}


def test_a_full_disk_stops_the_run_and_a_rerun_resumes(fleet, tmp_path, monkeypatch):
    """The third results file finds no space (errno 28, as h5py reports it): the run stops there
    with a DiskFullError naming the file and what to do, the two finished results stay, the
    fourth log is not tried, and a rerun with space again skips the two and runs the rest."""
    import errno

    from pwl.fleet.runs import DiskFullError
    real, calls = Estimator.run_file, []

    def run_file(self, log_path, out_path, **kw):
        calls.append(log_path)
        if len(calls) == 3:
            raise OSError(f"Can't write data (file write failed: errno = {errno.ENOSPC}, error message = "
                          f"'No space left on device')")
        return real(self, log_path, out_path, **kw)
    monkeypatch.setattr(Estimator, "run_file", run_file)
    with pytest.raises(DiskFullError, match=r"flight_000.estimates.h5: no space left on the disk \(2 of 4 logs "
                                            r"done, their results kept; the run stops\).*--every N"):
        run_many(DB, fleet, tmp_path / "out", workers=1)
    assert len(calls) == 3 and len(stamps(tmp_path / "out")) == 2
    monkeypatch.setattr(Estimator, "run_file", real)
    assert [r.status for r in run_many(DB, fleet, tmp_path / "out", workers=1)] == [SKIPPED, SKIPPED, OK, OK]


def test_run_many_own_pool_is_one_whose_workers_die_with_it(tmp_path, monkeypatch):
    """Without an executor, run_many makes its pool with pwl.workers.process_pool (workers end
    when the process that started them dies, even by SIGKILL), not a plain process pool."""
    import pwl.fleet.runs as runs
    from pwl import workers

    made = []

    def recording_pool(n):
        made.append(n)
        return workers.process_pool(n)
    monkeypatch.setattr(runs, "process_pool", recording_pool)
    logs = [slice_log(tmp_path / "logs" / f"f{i}.h5", "flight_new", 3000 * i, n=600) for i in range(2)]
    res = run_many(DB, logs, tmp_path / "out", workers=2)
    assert made == [2] and {r.status for r in res} == {OK}


def _run_log_that_kills_workers(job, log_path, out_path):
    """run_log, except that a log named ``killer`` kills its worker process every time and one
    named ``flaky`` the first time only (a worker the kernel killed for memory other logs held)."""
    name = os.path.basename(log_path)
    first = os.path.join(os.path.dirname(out_path), "flaky-died")
    if name.startswith("killer") or (name.startswith("flaky") and not os.path.exists(first)):
        if name.startswith("flaky"):
            open(first, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return _run_log(job, log_path, out_path)


def test_a_worker_killed_fails_only_the_log_that_kills_it(tmp_path, monkeypatch):
    """A worker process that dies breaks the whole pool: the logs in it run again, each alone, on a
    fresh pool; only a log whose worker dies while it runs alone fails, and it says why."""
    import pwl.fleet.runs as runs
    names = ["flaky", "a", "killer", "b", "c", "d"]        # flaky dies first, in a full pool
    logs = [slice_log(tmp_path / "logs" / f"{n}.h5", "flight_new", 2000 * i, n=600) for i, n in enumerate(names)]
    monkeypatch.setattr(runs, "run_log", _run_log_that_kills_workers)
    res = run_many(DB, logs, tmp_path / "out", workers=2)
    # a log whose file was written just before the pool broke is found done when it runs again
    assert [r.status in (OK, SKIPPED) for r in res] == [True, True, False, True, True, True], [r.error for r in res]
    assert res[0].status == OK and res[2].status == FAILED
    assert res[2].error == runs.WORKER_DIED
    assert os.path.exists(tmp_path / "out" / "flaky-died")      # it did die once, then ran alone
    monkeypatch.undo()
    serial = run_many(DB, [logs[i] for i in (0, 1)], tmp_path / "serial", workers=1)
    for s, p in zip(serial, res):
        assert_same_results(s.output, p.output)


def test_killed_run_then_rerun_repeats_no_finished_flight(tmp_path):
    n = 12
    for i in range(n):
        slice_log(tmp_path / "logs" / f"f{i:02d}.h5", "flight_new", 3000 * i, n=15000)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pwl", "run", DB, str(tmp_path / "logs"), "-o", str(out), "-j", "2"]
    env = os.environ | {"PYTHONPATH": os.path.abspath(ROOT)}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(stamps(out)) < n // 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        workers = _children(proc.pid)
        proc.send_signal(signal.SIGKILL)          # the run only: its pool workers must follow
        proc.wait()
        done = stamps(out)
        assert n // 2 <= len(done) < n, "the run was not killed half-way"
        if workers is not None:
            _wait_gone(workers)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"{len(done)} log(s) skipped" in res.stdout
    after = stamps(out)
    assert len(after) == n and {k: after[k] for k in done} == done     # no finished flight redone
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]      # the killed writes are gone


def _children(pid):
    """The processes ``pid`` started (psutil), or None without psutil (not checked then)."""
    try:
        import psutil
    except ImportError:
        return None
    return psutil.Process(pid).children(recursive=True)


def _wait_gone(procs, timeout=10.0):
    """Every process of ``procs`` (psutil) ends within ``timeout`` s (workers die with their run;
    a zombie has ended)."""
    import psutil

    def alive(p):
        try:
            return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
        except psutil.Error:
            return False

    deadline = time.monotonic() + timeout
    while any(map(alive, procs)) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [p for p in procs if alive(p)]
    for p in left:
        p.kill()
    assert not left, f"worker processes outlived the killed run: {[p.pid for p in left]}"


# ---- summary -----------------------------------------------------------------------------------
def independent_row(path) -> dict:
    """What a summary row must say, from a results file's datasets (not its attributes)."""
    d = datasets(path)
    flags = d["flags"]
    row = {"samples": flags.size, **{k: int(np.count_nonzero(flags & bit)) for k, bit in FLAG_COUNTS.items()}}
    row["updated"] = int(np.count_nonzero((flags & (FLAG_NO_UPDATE | FLAG_NOT_STARTED)) == 0))
    r = d["residual"]
    with h5py.File(path, "r") as f:
        sensors = [s.decode() for s in f["names/residual"][()]]
        hn = [s.decode() for s in f["snapshots/names_h_hat"][()]]
    row |= {f"rms.{s}": float(np.sqrt(np.nanmean(r[:, j] ** 2))) for j, s in enumerate(sensors)}
    return row | {f"h_hat.{h}": float(v) for h, v in zip(hn, d["snapshots/out_h_hat"][-1])}


@pytest.mark.parametrize("parquet", [True, False])
def test_summary_rows_match_the_results_files(fleet, tmp_path, monkeypatch, parquet):
    bad = tmp_path / "logs" / "bad.h5"
    bad.parent.mkdir()
    bad.write_text("not a log")
    out = tmp_path / "out"
    results = run_many(DB, fleet + [str(bad)], out, workers=1)
    if parquet:
        pytest.importorskip("pandas")
        pytest.importorskip("pyarrow")
    else:
        import importlib.util
        real = importlib.util.find_spec
        monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "pyarrow" else real(n, *a))
        (out / "summary.parquet").write_text("stale")
    path = write_summary(results, out)
    assert os.path.basename(path) == ("summary.parquet" if parquet else "summary.csv")
    assert os.listdir(out).count("summary.csv") + os.listdir(out).count("summary.parquet") == 1
    rows = read_summary(path)
    assert [r["status"] for r in rows] == [OK] * 4 + [FAILED]
    assert "bad.h5" in rows[4]["error"] and rows[4]["results"] in ("", None)
    for r, log in zip(rows[:4], fleet):
        want = independent_row(r["results"])
        assert r["log"] == log
        assert r["engine"] == os.path.basename(os.path.dirname(log))
        assert int(r["flight_index"]) == int(os.path.basename(log)[7:10])
        for k, v in want.items():
            assert float(r[k]) == pytest.approx(v, rel=1e-12, abs=1e-15), k
    # the degraded flight's snapshot health is lower than the new engine's (hpc_eff: -2 % seeded)
    assert float(rows[3]["h_hat.hpc_eff"]) < float(rows[2]["h_hat.hpc_eff"]) - 0.005


def test_a_resumed_runs_summary_covers_every_flight(fleet, tmp_path):
    out = tmp_path / "out"
    for r in run_many(DB, fleet, out, workers=1)[2:]:
        os.remove(r.output)                                  # as if the first run was stopped there
    rows = summary_rows(run_many(DB, fleet, out, workers=1))
    assert [r["status"] for r in rows] == [SKIPPED, SKIPPED, OK, OK]
    assert all(r["samples"] == 4500 and np.isfinite(r["h_hat.hpc_eff"]) for r in rows)


# ---- thinning and output selection ---------------------------------------------------------------
def test_thinning_and_selection_keep_exactly_the_right_samples_and_datasets(fleet, tmp_path):
    est = Estimator(DB)
    whole = est.run(fleet[0])
    out = tmp_path / "thin.estimates.h5"
    counts = est.run_file(fleet[0], out, chunk=1000, outputs="h_hat, z_hat,flags", every=7)
    d = datasets(out)
    assert {k for k in d if "/" not in k} == {"time", "flags", "h_hat", "z_hat", "h_hat_channel", "z_hat_channel"}
    np.testing.assert_array_equal(d["time"], whole.time[::7])
    np.testing.assert_array_equal(d["flags"], whole.flags[::7])
    np.testing.assert_array_equal(d["h_hat"], whole.h_hat[::7])
    np.testing.assert_array_equal(d["z_hat"], whole.z_hat[::7])
    # counts and snapshots still come from every sample
    assert {k: counts[k] for k in whole.counts()} == whole.counts()
    # (a block split across two chunks sums in another order: equal to rounding)
    np.testing.assert_allclose(d["snapshots/out_h_hat"], whole.snapshots.outputs["h_hat"], rtol=1e-12, atol=0)
    with h5py.File(out, "r") as f:
        assert f.attrs["every"] == 7 and f.attrs["outputs"] == "h_hat,z_hat"
        assert f.attrs["samples"] == len(whole.time)
    with pytest.raises(UsageError, match="'nope'.*x_hat, q_hat"):
        est.run_file(fleet[0], tmp_path / "x.estimates.h5", outputs="h_hat,nope")
    with pytest.raises(UsageError, match="every = 0"):
        est.run_file(fleet[0], tmp_path / "x.estimates.h5", every=0)
    assert not (tmp_path / "x.estimates.h5").exists()


def test_readers_work_on_thinned_files(fleet, tmp_path, capsys):
    """pwl fleet diagnose and pwl trend read snapshots and attributes only: a thinned file without
    the trajectories gives them the same flight records."""
    from pwl.cli import main
    from pwl.fleet.diagnose import read_flight

    full = run_many(DB, fleet[2:], tmp_path / "full", workers=1)
    thin = run_many(DB, fleet[2:], tmp_path / "thin", workers=1, outputs=["h_hat"], every=50)
    for a, b in zip(full, thin):
        ra, rb = read_flight(a.output), read_flight(b.output)
        assert (ra.engine, ra.order) == (rb.engine, rb.order)
        np.testing.assert_array_equal(ra.snapshot.mean, rb.snapshot.mean)
    assert main(["trend", str(tmp_path / "thin")]) in (0, 1)
    assert "ESN2" in capsys.readouterr().out


def test_compression_options_and_csv_results(fleet, tmp_path):
    est = Estimator(DB)
    for comp, want in (("gzip", "gzip"), ("lzf", "lzf"), (None, None)):
        out = tmp_path / f"{comp}.estimates.h5"
        est.run_file(fleet[0], out, outputs=["z_hat"], compression=comp)
        with h5py.File(out, "r") as f:
            assert f["z_hat"].compression == want and f["flags"].compression == want
    with pytest.raises(UsageError, match="'zip'"):
        est.run_file(fleet[0], tmp_path / "y.estimates.h5", compression="zip")
    res = run_many(DB, fleet[:1], tmp_path / "csv", workers=1, csv=True, outputs=["z_hat"], every=10)
    assert res[0].status == OK and res[0].output.endswith(".csv")
    log = read_log(res[0].output)
    whole = Estimator(DB).run(fleet[0])
    np.testing.assert_array_equal(log.time, whole.time[::10])
    assert sorted(log.channels) == sorted(["flags"] + [f"z_hat.{n}" for n in whole.names["z_hat"]])
    np.testing.assert_allclose(log.channels["z_hat.Fn"], whole.channel("z_hat", "Fn")[::10], rtol=1e-15)
    np.testing.assert_array_equal(log.channels["flags"], whole.flags[::10])


def test_one_result_save_with_selection(fleet, tmp_path):
    whole = Estimator(DB).run(fleet[0])
    whole.save(tmp_path / "s.estimates.h5", outputs=["q_hat"], every=3)
    back = Result.load(tmp_path / "s.estimates.h5")
    assert list(back.outputs) == ["q_hat"]
    np.testing.assert_array_equal(back.q_hat, whole.q_hat[::3])
    assert int(back.attrs["samples"]) == len(whole.time)


# ---- the numba cache of workers ------------------------------------------------------------------
NUMBA_PROBE = """
import os, sys
import numpy as np
import pwl.runtime
from pwl import Axis, Grid, interpolate
from pwl.fleet import runs as fleet_run
fleet_run._prepare_numba(fleet_run.Job('db', 'x', host=sys.argv[1]))
if sys.argv[2:]:
    interpolate(Grid([Axis('a', [0.0, 1.0])]), np.array([0.0, 2.0]), np.array([[0.5]]))  # compiles
print(fleet_run._NUMBA_READY[0], pwl.runtime.filter_loop._cache._cache_path, os.environ.get('NUMBA_CACHE_DIR'))
"""


def numba_probe(env, host, compile=False) -> list[str]:
    """A fresh worker process: the cache it chose, filter_loop's cache folder, NUMBA_CACHE_DIR
    (``compile``: after compiling a small kernel)."""
    out = subprocess.run([sys.executable, "-c", NUMBA_PROBE, host] + (["compile"] if compile else []),
                         env=env, capture_output=True, text=True, check=True, timeout=120)
    return out.stdout.split()


def test_workers_elsewhere_use_the_shared_user_numba_cache(tmp_path):
    """A worker on another machine caches pwl's kernels in ~/.cache/pwl/numba unless
    NUMBA_CACHE_DIR is set (numba picks a kernel's cache folder at import: the worker re-points
    them), and kernels compiled afterwards are cached there; on this machine, with pwl's folder
    writable, numba's own cache beside the sources stays in use."""
    import socket

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"} | {
        "HOME": str(tmp_path), "PYTHONPATH": os.path.abspath(ROOT)}
    user = os.path.join(str(tmp_path), ".cache", "pwl", "numba")
    chosen, kernel, variable = numba_probe(env, "another-machine", compile=True)
    assert chosen == variable == user and kernel.startswith(user)
    assert any(f.startswith("interp.interp_many") and f.endswith(".nbi")
               for _, _, files in os.walk(user) for f in files)
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    chosen, kernel, _ = numba_probe(env, "another-machine")
    assert chosen == str(tmp_path / "mine") and kernel.startswith(chosen)
    if os.access(os.path.join(ROOT, "pwl"), os.W_OK):
        del env["NUMBA_CACHE_DIR"]
        chosen, kernel, _ = numba_probe(env, socket.gethostname())
        assert chosen == "None"
        assert os.path.realpath(kernel) == os.path.realpath(os.path.join(ROOT, "pwl", "__pycache__"))


def test_a_second_run_into_a_folder_in_use_is_refused(fleet, tmp_path):
    """Two runs writing one folder removed each other's unfinished results files (2 of 24 logs
    failed): the second is refused while the first holds the folder's lock; afterwards it runs.
    A run stopped half-way leaves no summary of the run before it."""
    from pwl.errors import UsageError
    from pwl.fleet.runs import lock_folder, remove_summary
    out = tmp_path / "out"
    out.mkdir()
    held = lock_folder(out)
    with pytest.raises(UsageError, match="another pwl run is writing into this folder"):
        run_many(DB, fleet[:1], out, workers=1)
    held.close()
    assert run_many(DB, fleet[:1], out, workers=1)[0].status == OK
    (out / "summary.csv").write_text("an older run's")
    remove_summary(out)
    assert not (out / "summary.csv").exists()


def test_a_results_file_that_cannot_fit_is_not_started(fleet, tmp_path, monkeypatch):
    """Less free space than a results file needs: an ENOSPC error naming the file and the sizes
    before any HDF5 write (HDF5 failing half-way on a full disk left objects that crashed the
    process at exit: pwl run -j 1 ended in a segmentation fault)."""
    import errno
    import shutil
    from collections import namedtuple
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 ** 9, 10 ** 9 - 2 * 10 ** 6, 2 * 10 ** 6))
    with pytest.raises(OSError, match=r"needs about [0-9.]+ MB, 2.0 MB free") as e:
        Estimator(DB).run_file(fleet[0], tmp_path / "r.estimates.h5")
    assert e.value.errno == errno.ENOSPC and not os.listdir(tmp_path)
    Estimator(DB).run_file(fleet[0], tmp_path / "r.estimates.h5", every=1000)    # thinned, it fits
