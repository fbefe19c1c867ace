"""Fleet-run benchmark (issue #15): many short flight logs through ``pwl.fleet.runs.run_many``.

    python benchmarks/fleet_run.py                  # 1000 logs of 90 s (the issue's figure)
    python benchmarks/fleet_run.py --logs 60        # quick figures (about 3 minutes on 2 cores)

The logs are slices of the shipped demo flights in an engine tree (ESN000/flight_000.h5 ...). It
reports, for a local process pool and a Dask LocalCluster (processes) of 1 and 2 workers: flights
per minute (after a warm-up run on each executor, so every worker has loaded numba's cache),
the speed-up of 2 workers over 1 (goal >= 1.8x) and the peak RSS of every worker (the kernel's
``ru_maxrss`` read inside the worker, exact where sampling with psutil would miss peaks). Then a
resume check: ``pwl run -j 2`` killed with SIGKILL once half the results files exist, run again,
counting the finished flights it computed again (goal 0). Last, a fresh worker process's
first-log time with an empty and with a warm numba cache (``NUMBA_CACHE_DIR``).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

from pwl.fleet.runs import FAILED, local_dask_cluster, run_many  # noqa: E402
from pwl.logs import Log, read_log, write_log  # noqa: E402
from pwl.results import COMPRESSIONS, DEFAULT_COMPRESSION  # noqa: E402

DB = os.path.join(ROOT, "data", "turbofan_demo.h5")
ENGINES = 10


def make_logs(folder: str, n: int, samples: int) -> list[str]:
    """``n`` logs of ``samples`` samples each, slices of the two demo flights at spread offsets,
    as ``folder/ESN<k>/flight_<j>.h5`` (engine and flight_index attributes set)."""
    flights = [read_log(os.path.join(ROOT, "data", f + ".h5")) for f in ("flight_new", "flight_degraded")]
    paths = []
    for i in range(n):
        src = flights[i % 2]
        a = (i * 7919) % (len(src) - samples)
        eng, j = f"ESN{i % ENGINES:03d}", i // ENGINES
        path = os.path.join(folder, eng, f"flight_{j:03d}.h5")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_log(path, Log(src.time[a:a + samples] - src.time[a],
                            {k: v[a:a + samples] for k, v in src.channels.items()}, dict(src.units),
                            attrs={"dt": 0.015, "engine": eng, "flight_index": j}))
        paths.append(path)
    return paths


def names_of(logs, folder):
    return [os.path.relpath(p, folder) for p in logs]


def peak_rss_mb() -> tuple[int, float]:
    """(pid, peak resident set size in MB) of the calling process (Linux: ru_maxrss in kB)."""
    import resource
    time.sleep(0.05)           # long enough for a pool to hand the next call to another worker
    return os.getpid(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def timed_run(executor, logs, folder, out, compression) -> tuple[float, int]:
    """Seconds of one run_many over ``logs`` into the fresh folder ``out``, and failed logs."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    res = run_many(DB, logs, out, names=names_of(logs, folder), executor=executor, compression=compression)
    return time.perf_counter() - t0, sum(r.status == FAILED for r in res)


def bench_executor(kind: str, workers: int, logs, folder, scratch, compression) -> dict:
    """One executor: warm-up run, timed run, peak RSS per worker."""
    warm = logs[: 2 * workers]
    if kind == "process pool":
        ex = ProcessPoolExecutor(workers)
        try:
            timed_run(ex, warm, folder, os.path.join(scratch, "warm"), compression)
            dt, failed = timed_run(ex, logs, folder, os.path.join(scratch, "out"), compression)
            rss = dict(f.result() for f in [ex.submit(peak_rss_mb) for _ in range(8 * workers)])
        finally:
            ex.shutdown()
    else:
        from dask.distributed import Client
        with local_dask_cluster(workers) as cluster, Client(cluster) as client:
            timed_run(client, warm, folder, os.path.join(scratch, "warm"), compression)
            dt, failed = timed_run(client, logs, folder, os.path.join(scratch, "out"), compression)
            rss = dict(client.run(peak_rss_mb).values())
    return {"executor": kind, "workers": workers, "seconds": dt, "flights_per_minute": 60 * len(logs) / dt,
            "failed": failed, "peak_rss_mb": sorted(rss.values())}


def stamps(folder) -> dict:
    """results file -> (inode, mtime) below ``folder``."""
    out = {}
    for d, _, files in os.walk(folder):
        for f in files:
            if f.endswith(".estimates.h5"):
                st = os.stat(os.path.join(d, f))
                out[os.path.join(d, f)] = (st.st_ino, st.st_mtime_ns)
    return out


def resume_check(folder, scratch, n) -> dict:
    """Kill ``pwl run -j 2`` once half the results exist, run it again: what was redone."""
    out = os.path.join(scratch, "resume")
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "pwl", "run", DB, folder, "-o", out, "-j", "2"]
    env = os.environ | {"PYTHONPATH": ROOT}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    while len(stamps(out)) < n // 2 and proc.poll() is None:
        time.sleep(0.01)
    workers = _children(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = stamps(out)
    time.sleep(1.0)                       # the pool's workers die with the run (PDEATHSIG)
    orphans = -1 if workers is None else sum(map(_alive, workers))
    if orphans > 0:
        os.killpg(proc.pid, signal.SIGKILL)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True)
    rerun = time.perf_counter() - t0
    after = stamps(out)
    skipped = next((int(w.split()[0]) for w in res.stdout.splitlines() if "skipped" in w), 0)
    return {"finished_at_kill": len(done), "skipped_on_rerun": skipped,
            "repeated": sum(after.get(k) != v for k, v in done.items()), "complete_after_rerun": len(after),
            "rerun_seconds": rerun, "rerun_status": res.returncode, "orphan_workers": orphans,
            "temporary_files_left": sum(f.endswith(".tmp") for _, _, fs in os.walk(out) for f in fs)}


def _children(pid):
    """The processes ``pid`` started (psutil), or None without psutil."""
    try:
        import psutil
    except ImportError:
        return None
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.Error:
        return []


def _alive(proc) -> bool:
    """Whether a psutil process still runs (a zombie has ended)."""
    import psutil
    try:
        return proc.is_running() and proc.status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


FIRST_LOG = """
import sys, time
t0 = time.perf_counter()
from pwl.fleet.runs import run_many
r = run_many(sys.argv[1], [sys.argv[2]], sys.argv[3], workers=1, force=True)
assert r[0].status == "ok", r[0].error
print(time.perf_counter() - t0)
"""


def first_log_times(log, scratch) -> dict:
    """A fresh worker process's first log (imports, database, kernels, the run), with an empty
    and then a warm numba cache."""
    cache = os.path.join(scratch, "numba-cache")
    shutil.rmtree(cache, ignore_errors=True)
    env = os.environ | {"NUMBA_CACHE_DIR": cache, "PYTHONPATH": ROOT}
    out = {}
    for label in ("cold", "warm"):
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-c", FIRST_LOG, DB, log, os.path.join(scratch, "first")],
                             env=env, capture_output=True, text=True, check=True)
        out[label] = {"process_seconds": time.perf_counter() - t0, "in_process_seconds": float(res.stdout)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--logs", type=int, default=1000, help="number of flight logs (default %(default)s)")
    p.add_argument("--samples", type=int, default=6000,
                   help="samples per log, 15 ms each (default %(default)s: 90 s)")
    p.add_argument("--compression", choices=sorted(COMPRESSIONS), default=DEFAULT_COMPRESSION,
                   help="results compression (default %(default)s)")
    p.add_argument("--no-dask", action="store_true", help="skip the Dask LocalCluster (default: run it)")
    p.add_argument("--no-cache-check", action="store_true",
                   help="skip the cold numba cache measurement (it compiles for about 40 s; default: run it)")
    p.add_argument("--json", action="store_true", help="print the figures as JSON (default: a table)")
    args = p.parse_args(argv)

    scratch = tempfile.mkdtemp(prefix="pwl-fleet-bench-")
    try:
        folder = os.path.join(scratch, "logs")
        t0 = time.perf_counter()
        logs = make_logs(folder, args.logs, args.samples)
        made = time.perf_counter() - t0
        run_many(DB, logs[:1], os.path.join(scratch, "compile"), workers=1)   # this process compiles
        dask = not args.no_dask and importlib.util.find_spec("distributed") is not None
        if not args.no_dask and not dask:
            print("dask.distributed is not installed: the process pool only", file=sys.stderr)
        kinds = ["process pool"] + (["dask LocalCluster"] if dask else [])
        rows = [bench_executor(k, w, logs, folder, scratch, args.compression) for k in kinds for w in (1, 2)]
        for r in rows:
            one = next(x for x in rows if x["executor"] == r["executor"] and x["workers"] == 1)
            r["speedup"] = one["seconds"] / r["seconds"]
        figures = {"logs": args.logs, "samples_per_log": args.samples, "compression": args.compression,
                   "cores": os.cpu_count(), "logs_written_seconds": made, "executors": rows,
                   "resume": resume_check(folder, scratch, args.logs)}
        if not args.no_cache_check:
            figures["first_log"] = first_log_times(logs[0], scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    if args.json:
        print(json.dumps(figures, indent=1))
        return 0
    print(f"{args.logs} logs of {args.samples} samples ({args.samples * 0.015:.0f} s of flight), "
          f"compression {args.compression}, {os.cpu_count()} cores")
    print(f"{'executor':<20} {'workers':>7} {'flights/min':>12} {'speed-up':>9}  peak RSS per worker (MB)")
    for r in rows:
        print(f"{r['executor']:<20} {r['workers']:>7} {r['flights_per_minute']:>12.0f} {r['speedup']:>8.2f}x  "
              + ", ".join(f"{m:.0f}" for m in r["peak_rss_mb"]) + (f"  ({r['failed']} FAILED)" if r["failed"] else ""))
    rs = figures["resume"]
    print(f"resume: killed with {rs['finished_at_kill']} of {args.logs} finished; the rerun skipped "
          f"{rs['skipped_on_rerun']}, repeated {rs['repeated']} finished flights, left "
          f"{rs['complete_after_rerun']} results, {rs['temporary_files_left']} temporary files and "
          f"{rs['orphan_workers']} orphan workers (exit status {rs['rerun_status']}, {rs['rerun_seconds']:.1f} s)")
    if "first_log" in figures:
        fl = figures["first_log"]
        print("fresh worker, first log (process start to results file): "
              + ", ".join(f"{k} numba cache {v['process_seconds']:.1f} s" for k, v in fl.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
