"""Many logs to many results files through any executor (``pwl run``).

:func:`run_many` submits one task per log (:func:`run_log`) to a ``concurrent.futures``-style
executor: a local process pool by default, or anything with ``submit`` returning futures with
``result()``, such as a ``dask.distributed.Client``. Every worker process opens the gain database
once (a per-process cache keyed by its path, digest and the estimator options) and keeps one
:class:`Estimator` per thread. A results file whose provenance shows the same database, mode, log
and output selection is not computed again (``force`` recomputes); results files appear
atomically, so a killed run leaves finished files and temporary files only, which the next run
removes. :func:`write_summary` writes the fleet summary from the results files.
"""
from __future__ import annotations

import csv
import errno
import importlib.util
import json
import os
import socket
import sys
import threading
from collections import deque
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, Future, as_completed, wait
from dataclasses import dataclass
from typing import NamedTuple

from threadpoolctl import threadpool_limits

from .. import kernel_cache
from ..database import DatabaseError, GainDatabase
from ..errors import PwlError, UsageError
from ..formats import FLEET_SUMMARY, check
from ..estimator import Estimator
from ..h5io import attr_str, file_digest
from ..workers import process_pool
from ..results import (COUNT_KEYS, DEFAULT_COMPRESSION, ResultError, check_every, compression_filters,
                      file_summary, open_results, select_outputs, selection_record)

OK, SKIPPED, FAILED = "ok", "skipped", "failed"
DISK_FULL = "disk full: "     # how a LogRun's error starts when its results did not fit


class DiskFullError(PwlError, OSError):
    """The results filled the disk: :func:`run_many` stops (every further log would fail too)."""


def _disk_full(e: BaseException) -> bool:
    """An error from a write that found no space (h5py reports errno 28 in its message)."""
    return getattr(e, "errno", None) == errno.ENOSPC or "No space left on device" in str(e)

#: the shared user cache of numba's compiled code (NUMBA_CACHE_DIR unless the user set it)
USER_NUMBA_CACHE = os.path.join("~", ".cache", "pwl", "numba")


class LogRun(NamedTuple):
    """One log of :func:`run_many`: its results file, the flag counts (None when failed), the
    error message (None when not failed), status ``ok``, ``skipped`` (finished by an earlier run)
    or ``failed``, and its row of the fleet summary (from the results file)."""

    log: str
    output: str
    counts: dict | None
    error: str | None
    status: str
    row: dict


@dataclass(frozen=True)
class Job:
    """What every log of one :func:`run_many` call is run with (sent to the workers).

    ``database``: absolute path; ``digest``: the database's digest when the run started (a
    worker refuses a database that changed since); ``outputs``: selected output names (None:
    all); ``host``: the machine that submitted the run (workers elsewhere use the user numba
    cache); ``checks``: the estimator's sensor-check options, sorted (name, value) pairs."""

    database: str
    digest: str
    mode: str = "steady"
    resample: bool = False
    channel_map: str | None = None
    outputs: tuple | None = None
    every: int = 1
    compression: str | None = DEFAULT_COMPRESSION
    force: bool = False
    host: str = ""
    checks: tuple = ()

    def estimator_key(self) -> tuple:
        return (self.database, self.digest, self.mode, self.resample, self.channel_map, self.checks)


# ---- worker side ---------------------------------------------------------------------------------
_DATABASES: dict = {}             # (path, digest) -> GainDatabase: opened once per process
_THREAD = threading.local()       # .estimators: key -> Estimator (an Estimator is not thread-safe)
_LOCK = threading.Lock()
_NUMBA_READY = []                 # [cache folder or None] once this process has chosen its cache


def numba_cache_dir(remote: bool = False) -> str | None:
    """Where this process should keep numba's compiled kernels: ``NUMBA_CACHE_DIR`` when the
    user set it; None (numba's ``cache=True`` default, ``__pycache__`` beside pwl's sources)
    when that folder is writable and this is not a worker on another machine (``remote``); else
    the shared user cache ``~/.cache/pwl/numba``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    if not remote and os.access(here if os.path.isdir(here) else os.path.dirname(here), os.W_OK):
        return None
    return os.path.expanduser(USER_NUMBA_CACHE)


def use_numba_cache(path: str) -> int:
    """Cache pwl's numba kernels in ``path`` from now on: sets ``NUMBA_CACHE_DIR`` and numba's
    config, and re-points every pwl kernel that has not compiled yet (numba chooses a kernel's
    cache folder when its module is imported, before a worker can set the variable). Returns
    how many kernels were re-pointed."""
    from numba.core import config
    from numba.core.dispatcher import Dispatcher

    os.makedirs(path, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = config.CACHE_DIR = path
    kernel_cache.check()   # kernels cached there from older sources are not loaded
    seen, n = set(), 0
    for name, mod in list(sys.modules.items()):
        if not (name == "pwl" or name.startswith("pwl.")) or mod is None:
            continue
        for obj in list(vars(mod).values()):
            cache = getattr(obj, "_cache", None)
            if (isinstance(obj, Dispatcher) and id(obj) not in seen and not obj.overloads
                    and type(cache).__name__ == "FunctionCache"):   # cache=True, nothing compiled yet
                seen.add(id(obj))
                obj.enable_caching()
                n += 1
    return n


def _prepare_numba(job: Job) -> None:
    """Choose this process's numba cache once, before its first kernel compiles."""
    if not _NUMBA_READY:
        path = numba_cache_dir(remote=bool(job.host) and job.host != socket.gethostname())
        if path:
            use_numba_cache(path)
        _NUMBA_READY.append(path)


def _estimator(job: Job) -> Estimator:
    """This thread's estimator for ``job`` (the database opened once per process)."""
    cache = _THREAD.__dict__.setdefault("estimators", {})
    key = job.estimator_key()
    if key not in cache:
        with _LOCK:
            _prepare_numba(job)
            db = _DATABASES.get(key[:2])
            if db is None:
                db = GainDatabase.open(job.database)
                if db.digest != job.digest:
                    raise DatabaseError(f"{job.database}: changed since this run started (sha256 "
                                        f"{db.digest[:12]}... instead of {job.digest[:12]}...); run again")
                _DATABASES[key[:2]] = db
        cache[key] = Estimator(db, job.mode, resample=job.resample, channel_map=job.channel_map,
                               **dict(job.checks))
    return cache[key]


def finished(est: Estimator, job: Job, log_path: str, out_path: str) -> tuple[dict, dict] | None:
    """The summary row of ``out_path``, its missing and misfit samples per channel and its failed sensors, when it already
    holds what ``job`` would write for ``log_path`` (same database digest, mode, log digest,
    outputs, ``every`` and pwl version: a new version may estimate otherwise; its seal intact);
    None when it must be computed (missing, unreadable, or made otherwise)."""
    if not os.path.exists(out_path):
        return None
    try:
        want = {"database_digest": est.db.digest, "mode": est.provenance["mode"],
                "log_digest": file_digest(log_path), "pwl_version": est.provenance["pwl_version"]}
    except OSError:            # the log is missing: run_file names it
        return None
    want |= selection_record(select_outputs(est.names, job.outputs), job.every)
    try:
        with open_results(out_path) as f:
            if all(str(attr_str(f, k)) == str(v) for k, v in want.items()):
                return file_summary(f), {k: json.loads(attr_str(f, k) or "{}") for k in (
                    "missing_channels", "misfit_channels", "failed_channels")}
    except ResultError:
        pass
    return None


def run_log(job: Job, log_path: str, out_path: str) -> LogRun:
    """Worker task: one log to its results file, or skipped when it is already there (see
    :func:`finished`). Any error is returned in the :class:`LogRun`, never raised: one bad log
    must not lose the others. BLAS runs on one thread here: the logs are the parallelism, and
    OpenBLAS's own threads wait for the cores other workers use (2 workers ran 1.6-1.7x one
    worker's rate with them, 1.9x without)."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _run_log(job, log_path, out_path)


def _run_log(job: Job, log_path: str, out_path: str) -> LogRun:
    csv_out = out_path.lower().endswith(".csv")
    try:
        est = _estimator(job)
        if not job.force and not csv_out:
            done = finished(est, job, log_path, out_path)
            if done is not None:
                row, channels = done
                counts = {k: row[k] for k in COUNT_KEYS} | channels
                return LogRun(log_path, out_path, counts, None, SKIPPED, row)
        counts = est.run_file(log_path, out_path, outputs=job.outputs, every=job.every,
                              compression=job.compression)
        if csv_out:
            row = {k: counts[k] for k in COUNT_KEYS} | {f"rms.{s}": v for s, v in counts["residual_rms"].items()}
        else:
            with open_results(out_path, verify=False) as f:    # just written and sealed here
                row = file_summary(f)
        return LogRun(log_path, out_path, counts, None, OK, row)
    except Exception as e:  # reported with the log; the others go on
        why = f"{DISK_FULL if _disk_full(e) else ''}{type(e).__name__}: {e}"
        return LogRun(log_path, out_path, None, why, FAILED, {})


# ---- the submitting side -------------------------------------------------------------------------
def output_path(log_path, outdir, csv: bool = False, name: str | None = None) -> str:
    """Results file of a log: ``outdir/<name without extension>.estimates.h5`` (``.csv``); ``name``
    defaults to the log's file name and may hold sub-folders (``ESN001/flight_003.h5``)."""
    base = _stem(os.fspath(name or os.path.basename(os.fspath(log_path))))
    return os.path.join(os.fspath(outdir), base + (".estimates.csv" if csv else ".estimates.h5"))


def _stem(name: str) -> str:
    """A log's name without its extension, and without the compression's (``flight.csv.gz``)."""
    base, ext = os.path.splitext(name)
    return os.path.splitext(base)[0] if ext.lower() in (".gz", ".bz2", ".xz", ".zip") else base


def result_names(log_paths, names=None) -> list[str]:
    """Names of the results of ``log_paths`` relative to the output folder: ``names`` when given,
    else the file names; logs of the same file name in different folders keep their folder
    (``ESN1/flight_001.h5`` and ``ESN2/flight_001.h5``). Two logs that would still collide are an
    error."""
    logs = [os.fspath(p) for p in log_paths]
    out = list(names) if names is not None else [os.path.basename(p) for p in logs]
    if names is None:
        seen: dict[str, int] = {}
        for n in out:
            seen[n] = seen.get(n, 0) + 1
        out = [os.path.join(os.path.basename(os.path.dirname(os.path.abspath(p))), n) if seen[n] > 1 else n
               for p, n in zip(logs, out)]
    stems = [_stem(n) for n in out]
    if len(set(stems)) != len(stems):
        dup = sorted({s for s in stems if stems.count(s) > 1})
        raise UsageError(f"logs {dup[:3]} would write the same results file; give them distinct names "
                         "or folders")
    return out


def remove_stale_temporaries(outs) -> int:
    """Remove the temporary files a killed run left beside the results files ``outs`` (HDF5
    writes go to ``.NAME.<random>.tmp`` and are renamed when complete); returns how many. Only
    while holding the folder's lock (:func:`lock_folder`): another run's are not stale."""
    prefixes: dict[str, set] = {}
    for out in outs:
        prefixes.setdefault(os.path.dirname(out) or ".", set()).add("." + os.path.basename(out))
    n = 0
    for folder, mine in prefixes.items():
        try:
            names = os.listdir(folder)
        except FileNotFoundError:
            continue
        for name in names:
            if name.endswith(".tmp") and name[:-4].rpartition(".")[0] in mine:
                try:
                    os.remove(os.path.join(folder, name))
                    n += 1
                except FileNotFoundError:
                    pass
    return n


def lock_folder(outdir):
    """An exclusive lock on the output folder (``outdir/.pwl-run.lock``, an OS file lock released
    when the run ends or dies), or a :class:`UsageError` when another run holds it: two runs
    writing one folder removed each other's unfinished results files and failed logs. Returns
    the open lock file (close it to release); None where the OS has no such lock."""
    try:
        import fcntl
    except ImportError:
        return None
    fh = open(os.path.join(os.fspath(outdir), ".pwl-run.lock"), "a")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        raise UsageError(f"{outdir}: another pwl run is writing into this folder; wait for it to end or "
                         "give another output folder") from None
    return fh


def run_many(db_path, log_paths, outdir, workers: int | None = None, csv: bool = False,
             progress=None, mode: str = "steady", names=None,
             resample: bool = False, *, channel_map=None, executor=None, outputs=None, every: int = 1,
             compression: str | None = DEFAULT_COMPRESSION, force: bool = False,
             checks: dict | None = None) -> list[LogRun]:
    """Estimate every log into ``outdir``: one results file per log (see :func:`run_log`).

    A log whose results file already holds what this call would write (same database digest,
    mode, outputs, thinning) is skipped (resume); a log that fails is reported and the others
    still complete. Write the fleet summary with :func:`write_summary`.

    Parameters
    ----------
    db_path : str, path-like or GainDatabase
        The gain database.
    log_paths : sequence of str or path-like
        The logs (any format :func:`pwl.read_log` reads).
    outdir : str or path-like
        Folder of the results files (created).
    workers : int, optional
        Processes of the default process pool (one: this process; None: the cores).
    csv : bool
        Write CSV results instead of HDF5.
    progress : callable, optional
        ``progress(done, total, item)``, called as each log finishes (item: its :class:`LogRun`).
    mode : {"steady", "untuned", "online", "zones"}
        The estimator's mode (:class:`pwl.Estimator`).
    names : sequence of str, optional
        Results names relative to ``outdir`` (see :func:`result_names`; default: folder trees
        such as a fleet's ``ESN001/flight_000.h5`` keep their sub-folders).
    resample : bool
        Resample logs not sampled at the database's dt (else such a log fails).
    channel_map : str or path-like, optional
        A channel-map TOML file every log is read through (:mod:`pwl.channel_map`).
    executor : object, optional
        Anything whose ``submit(fn, *args)`` returns a future with ``result()``: a
        ``concurrent.futures`` executor, a ``dask.distributed.Client`` (its workers must see the
        database, the logs and ``outdir`` at the same paths); default: a process pool of
        ``workers`` processes. It is not shut down here.
    outputs, every, compression
        What the results files hold (see :meth:`pwl.Estimator.run_file`).
    force : bool
        Recompute logs whose results are already there.
    checks : dict, optional
        Sensor-check options of the estimator (``health_hold``, ``misfit_sigmas``,
        ``stuck_after``; :class:`pwl.Estimator`); default: its defaults.

    Returns
    -------
    list of LogRun
        One per log, in input order: its results path, status (``ok``, ``skipped`` or
        ``failed``), flag counts, error message and summary row.

    Raises
    ------
    DiskFullError
        A results file did not fit on the disk: the run stops there (the finished results stay;
        a rerun resumes after space is freed).
    DatabaseError
        The database cannot be opened.
    UsageError
        A bad mode, output name, ``every`` or compression (before any log runs).
    """
    logs = [os.fspath(p) for p in log_paths]
    outs = [output_path(p, outdir, csv, n) for p, n in zip(logs, result_names(logs, names))]
    db = db_path if isinstance(db_path, GainDatabase) else GainDatabase.open(db_path)
    checks = tuple(sorted((checks or {}).items()))
    est = Estimator(db, mode, resample=resample, channel_map=channel_map, **dict(checks))  # named errors first
    keep = select_outputs(est.names, outputs)
    compression_filters(compression)
    cmap = None if channel_map is None else os.path.abspath(os.fspath(channel_map))
    job = Job(os.path.abspath(db.path), db.digest, mode, resample, cmap, None if outputs is None else tuple(keep),
              check_every(every), compression, force, socket.gethostname(), checks)
    _DATABASES.setdefault((job.database, job.digest), db)   # this process and forked workers
    os.makedirs(outdir, exist_ok=True)
    lock = lock_folder(outdir)
    remove_stale_temporaries(outs)
    if executor is None:
        n = max(1, min(len(logs), workers or os.cpu_count() or 1))
        each = _each_result_own_pool(n, job, logs, outs) if n > 1 else _each_result(None, job, logs, outs)
    else:
        batch = DASK_BATCH if hasattr(executor, "get_executor") else 1
        if batch > 1:                                  # a dask.distributed.Client
            executor = executor.get_executor(pure=False)
        each = _each_result(executor, job, logs, outs, batch)
    results: list = [None] * len(logs)
    try:
        for done, (i, item) in enumerate(each, 1):
            results[i] = item
            if progress:
                progress(done, len(logs), item)
            if item.error and item.error.startswith(DISK_FULL):
                raise _stopped_by_full_disk(item, results, outdir)
    finally:
        each.close()           # stops the pool of this run, if any
        if lock is not None:
            lock.close()
    return results


def _stopped_by_full_disk(item: LogRun, results: list, outdir) -> DiskFullError:
    """The error that stops a run whose results file ``item`` did not fit on the disk."""
    ok = sum(r is not None and r.status != FAILED for r in results)
    return DiskFullError(f"{item.output}: no space left on the disk ({ok} of {len(results)} logs done, "
                         f"their results kept; the run stops). Free space in {outdir}, or write "
                         f"less: --every N, --outputs, --compression; a rerun resumes")


def local_dask_cluster(workers: int):
    """A ``dask.distributed.LocalCluster`` of ``workers`` single-threaded worker processes for
    :func:`run_many` (no dashboard). Its workers keep Dask's one BLAS thread but not Dask's
    ``MALLOC_TRIM_THRESHOLD_=65536``: every log frees and allocates arrays of a few MB, and
    trimming them each time made a log 25-30 % slower (set it likewise on clusters of your own)."""
    import dask
    from dask.distributed import LocalCluster

    key = "distributed.nanny.pre-spawn-environ"
    env = {k: v for k, v in (dask.config.get(key) or {}).items() if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({key: env}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)


#: logs per Dask task: a task's round trip through the scheduler (which shares the cores) cost
#: about a quarter of a 90 s log's time; 8 per task took 2 local workers from 1.67x to 1.98x one
DASK_BATCH = 8


def run_logs(job: Job, pairs) -> list:
    """Worker task: :func:`run_log` for each (log, output) pair, in order."""
    return [run_log(job, lg, out) for lg, out in pairs]


def _each_result(executor, job: Job, logs, outs, batch: int = 1):
    """(index, LogRun) of every log as it finishes (in this process when ``executor`` is None);
    ``batch`` logs per task."""
    if executor is None:
        for i, (lg, out) in enumerate(zip(logs, outs)):
            yield i, run_log(job, lg, out)
        return
    starts = range(0, len(logs), batch)
    futs = {executor.submit(run_logs, job, list(zip(logs[a:a + batch], outs[a:a + batch]))): a for a in starts}
    order = as_completed(futs) if all(isinstance(f, Future) for f in futs) else list(futs)
    try:
        for fut in order:
            a = futs[fut]
            try:
                items = fut.result()
            except Exception as e:  # the worker itself was lost (killed process, lost Dask worker)
                why = f"{type(e).__name__}: {e}"
                if isinstance(e, BrokenExecutor):   # every log not finished fails with the pool
                    why = (f"{type(e).__name__}: a worker process died (killed, out of memory?) before this log "
                           "was done; a rerun resumes with the logs not done")
                items = [LogRun(logs[i], outs[i], None, why, FAILED, {}) for i in range(a, min(a + batch, len(logs)))]
            for k, item in enumerate(items):
                yield a + k, item
    finally:   # stopped early (the caller gave up): the tasks not started are not run
        for fut in futs:
            fut.cancel()


#: what a log's LogRun says when its worker process died with it alone in the pool
WORKER_DIED = ("a worker process died (killed, out of memory?) while it ran this log, also when the log "
               "ran alone; the other logs are done")


def _each_result_own_pool(workers: int, job: Job, logs, outs):
    """(index, LogRun) of every log as it finishes, on a pool of ``workers`` processes that end
    with this one (:func:`pwl.workers.process_pool`).

    At most ``2 * workers`` logs are in the pool at once. When a worker process dies (killed, out
    of memory) the pool breaks and fails every log in it: a fresh pool takes over, and the logs
    that were in the broken pool run again, each alone. A log whose worker dies while it runs
    alone fails (:data:`WORKER_DIED`); no other log is lost."""
    todo = deque(range(len(logs)))
    suspect: set[int] = set()          # in a pool that broke: runs again alone
    running: dict = {}                 # future -> log index
    pool = process_pool(workers)

    def may_submit() -> bool:
        if not todo or len(running) >= 2 * workers or suspect.intersection(running.values()):
            return False
        return todo[0] not in suspect or not running

    try:
        while todo or running:
            while may_submit():
                i = todo.popleft()
                running[pool.submit(run_log, job, logs[i], outs[i])] = i
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            if not any(isinstance(f.exception(), BrokenExecutor) for f in done):
                for fut in done:
                    i = running.pop(fut)
                    yield i, _task_result(fut, logs[i], outs[i])
                continue
            wait(running)               # a broken pool fails everything in it at once
            lost = sorted(i for f, i in running.items() if isinstance(f.exception(), BrokenExecutor))
            for fut, i in list(running.items()):
                if i not in lost:
                    yield i, _task_result(fut, logs[i], outs[i])
            running.clear()
            pool.shutdown(wait=True)
            if len(lost) == 1 and lost[0] in suspect:
                yield lost[0], LogRun(logs[lost[0]], outs[lost[0]], None, WORKER_DIED, FAILED, {})
            else:
                suspect.update(lost)
                todo.extendleft(reversed(lost))
            if todo:
                pool = process_pool(workers)
    finally:
        pool.shutdown(cancel_futures=True)


def _task_result(fut, log: str, out: str) -> LogRun:
    """The LogRun a finished :func:`run_log` task returned, or a failed one when it raised."""
    try:
        return fut.result()
    except Exception as e:
        return LogRun(log, out, None, f"{type(e).__name__}: {e}", FAILED, {})


# ---- the fleet summary ---------------------------------------------------------------------------
#: the summary's first columns; then h_hat.<parameter> (last snapshot) and rms.<sensor>
SUMMARY_COLUMNS = ("log", "results", "engine", "flight_index", "flight_time", "status", "error", *COUNT_KEYS)


def summary_rows(results) -> list[dict]:
    """One row per log of :func:`run_many`'s results (columns: :data:`SUMMARY_COLUMNS`, then
    ``h_hat.<parameter>`` of the last steady snapshot and ``rms.<sensor>``)."""
    rows = []
    for r in results:
        base = {"log": r.log, "results": "" if r.status == FAILED else r.output, "engine": "",
                "flight_index": None, "flight_time": "", "status": r.status, "error": r.error or ""}
        rows.append(base | dict.fromkeys(COUNT_KEYS) | dict(r.row))
    return rows


class SummaryError(PwlError, ValueError):
    """A file that is not a fleet summary this pwl reads (names the file and what it found)."""


def remove_summary(outdir) -> None:
    """Remove the fleet summary of ``outdir`` (both forms), before a run that will write it again:
    a run stopped half-way must not leave the previous run's summary as if it were its own."""
    for name in ("summary.parquet", "summary.csv"):
        try:
            os.remove(os.path.join(os.fspath(outdir), name))
        except FileNotFoundError:
            pass


def write_summary(results, outdir) -> str:
    """Write the fleet summary of ``results`` (:func:`run_many`) to ``outdir/summary.parquet``
    (with pandas and pyarrow; its format ``pwl-fleet-summary`` and version in the file's
    metadata) or else ``outdir/summary.csv`` (known by its header row), atomically; removes the
    other of the two so no stale summary is left. Returns the path written."""
    rows = summary_rows(results)
    cols = list(dict.fromkeys([*SUMMARY_COLUMNS, *(c for r in rows for c in r)]))
    try:
        import pandas as pd
    except ImportError:
        pd = None
    if importlib.util.find_spec("pyarrow") is None:     # pandas' Parquet engine
        pd = None
    path = os.path.join(os.fspath(outdir), "summary.parquet" if pd is not None else "summary.csv")
    tmp = os.path.join(os.fspath(outdir), f".{os.path.basename(path)}.{os.getpid()}.tmp")
    if pd is not None:
        df = pd.DataFrame(rows, columns=cols)
        df.attrs.update(FLEET_SUMMARY.stamp())     # stored in the Parquet metadata by pandas
        df.to_parquet(tmp, index=False)
    else:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, cols, restval="")
            w.writeheader()
            w.writerows({k: "" if v is None else v for k, v in r.items()} for r in rows)
    os.replace(tmp, path)
    other = os.path.join(os.fspath(outdir), "summary.csv" if pd is not None else "summary.parquet")
    if os.path.exists(other):
        os.remove(other)
    return path


def _summary_stamp(columns, attrs=None) -> tuple:
    """(format, version) of a summary: its stored stamp, else (a CSV, or Parquet written before
    the stamp) the fleet summary's when its columns begin with :data:`SUMMARY_COLUMNS`."""
    if attrs and "format" in attrs:
        return attrs.get("format"), int(attrs.get("format_version", -1))
    n = len(SUMMARY_COLUMNS)
    return (FLEET_SUMMARY.name if tuple(columns[:n]) == SUMMARY_COLUMNS else None), None


def read_summary(path) -> list[dict]:
    """The rows of a fleet summary written by :func:`write_summary` (Parquet needs pandas and
    pyarrow; CSV values are strings, empty where None).

    Raises
    ------
    SummaryError
        Not a fleet summary (another format, or other columns) or of a newer version; names the
        file and what it found.
    """
    if os.fspath(path).endswith(".parquet"):
        import pandas as pd
        df = pd.read_parquet(path)
        check(FLEET_SUMMARY, path, *_summary_stamp(list(df.columns), df.attrs), error=SummaryError)
        return df.to_dict("records")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        check(FLEET_SUMMARY, path, *_summary_stamp(list(reader.fieldnames or [])), error=SummaryError)
        return list(reader)
