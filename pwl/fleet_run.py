"""Many logs to many results files, in parallel worker processes (``pwl run``)."""
from __future__ import annotations

import os

from .errors import UsageError
from .estimator import Estimator

_worker_est = None


def _init_worker(db_path, online=False, zones=False, resample=False):
    global _worker_est
    _worker_est = Estimator(db_path, online=online, zones=zones, resample=resample)


def _run_one(log_path, out_path):
    try:
        return log_path, out_path, _worker_est.run_file(log_path, out_path), None
    except Exception as e:  # one bad log must not lose the others: report it, go on
        return log_path, out_path, None, f"{type(e).__name__}: {e}"


def output_path(log_path, outdir, csv: bool = False, name: str | None = None) -> str:
    """Results file of a log: ``outdir/<name without extension>.estimates.h5`` (``.csv``); ``name``
    defaults to the log's file name and may hold sub-folders (``ESN001/flight_003.h5``)."""
    base = os.path.splitext(os.fspath(name or os.path.basename(os.fspath(log_path))))[0]
    return os.path.join(os.fspath(outdir), base + (".estimates.csv" if csv else ".estimates.h5"))


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
    stems = [os.path.splitext(n)[0] for n in out]
    if len(set(stems)) != len(stems):
        dup = sorted({s for s in stems if stems.count(s) > 1})
        raise UsageError(f"logs {dup[:3]} would write the same results file; give them distinct names "
                         "or folders")
    return out


def run_many(db_path, log_paths, outdir, workers: int | None = None, csv: bool = False,
             progress=None, online: bool = False, zones: bool = False, names=None,
             resample: bool = False):
    """Estimate every log into ``outdir`` (one results file per log), in parallel processes
    (``online``, ``zones``, ``resample``: the full Kalman filter, the zone gains, logs resampled to
    the database's dt, as for :class:`Estimator`).
    ``names``: results names relative to ``outdir`` (see :func:`result_names`; folder trees such as
    a fleet's ``ESN001/flight_000.h5`` keep their sub-folders).

    Returns a list of (log, output, counts or None, error message or None) in input order; a log
    that fails is reported and the others still complete. ``progress(done, total, item)`` is
    called after each log.
    """
    from concurrent.futures import ProcessPoolExecutor

    logs = [os.fspath(p) for p in log_paths]
    outs = [output_path(p, outdir, csv, n) for p, n in zip(logs, result_names(logs, names))]
    os.makedirs(outdir, exist_ok=True)
    workers = max(1, min(len(logs), workers or os.cpu_count() or 1))
    results = []
    if workers == 1:
        _init_worker(db_path, online, zones, resample)
        for i, (lg, out) in enumerate(zip(logs, outs)):
            results.append(_run_one(lg, out))
            if progress:
                progress(i + 1, len(logs), results[-1])
        return results
    with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(os.fspath(db_path), online, zones, resample)) as ex:
        futs = [ex.submit(_run_one, lg, out) for lg, out in zip(logs, outs)]
        for i, fut in enumerate(futs):
            results.append(fut.result())
            if progress:
                progress(i + 1, len(logs), results[-1])
    return results
