"""Tuner selection (phase 3 of a build) in this process versus through a process pool.

    python benchmarks/tuner_selection.py                  # 110 dynamics points, 1 vs 2 workers
    python benchmarks/tuner_selection.py --workers 1 2 4 --mach 11 --nfr 10

The points are those of the demo turbofan (``specs/turbofan_demo.toml``) with a denser dynamics
grid (``--mach`` x ``--nfr`` points at 6000 m): a database is built once (phases 1-2 through a
process pool, then a 1-tuner subset selection to keep it short) and the exact point list the
build handed to ``design_filter`` is kept in ``--cache`` (a pickle; delete it to rebuild). Then
``select_subset`` and ``optimal_tuners`` (the demo's 7 tuners, targets h, Fn, T40) run once in
this process and once per worker count through ``linearize.build.process_pool``; the tuner
matrices must be identical (every point's contribution is summed in point order whatever ran
it), and the wall-clock ratio is printed. The pool is started and its workers have imported the
tuner code before the clock starts, as a build's pool has in phases 1-2. The CPU seconds of this
process and of the pool's workers are printed too: on a machine shared with other work the
wall-clock ratio measures the load, while CPU seconds equal to the serial run's say that the
pool adds no work (the speed-up on free cores is then the worker count, less the last task's
wait).
"""
from __future__ import annotations

import argparse
import os
import pickle
import resource
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from linearize import build as B  # noqa: E402
from linearize import threads  # noqa: E402
from linearize.spec import BuildSpec  # noqa: E402
from linearize.tuners import optimal_tuners, point_mses, select_subset  # noqa: E402

DEMO_SPEC = os.path.join(os.path.dirname(HERE), "specs", "turbofan_demo.toml")


def dense_spec(n_mach: int, n_nfr: int) -> BuildSpec:
    """The demo spec with an n_mach x n_nfr dynamics grid and a 1-tuner subset selection."""
    text = open(DEMO_SPEC).read()
    mach = ", ".join(f"{v:.4g}" for v in np.linspace(0.0, 0.85, n_mach))
    nfr = ", ".join(f"{v:.4g}" for v in np.linspace(60.0, 100.0, n_nfr))
    text = text.replace("Mach = [0, 0.4, 0.85]", f"Mach = [{mach}]").replace(
        "NfR = [60, 70, 80, 90, 100]", f"NfR = [{nfr}]")
    text = text.replace('method = "optimal"', 'method = "subset"').replace("n = 7", "n = 1")
    assert f"Mach = [{mach}]" in text and f"NfR = [{nfr}]" in text, "the demo spec changed"
    return BuildSpec.parse(text, f"turbofan_dense_{n_mach}x{n_nfr}.toml")


def points(n_mach: int, n_nfr: int, cache: str):
    """(points, Ph, targets) of the dense grid: from ``cache`` or from a build (kept there)."""
    if os.path.exists(cache):
        with open(cache, "rb") as f:
            return pickle.load(f)
    got = {}
    design_filter = B.design_filter

    def keep(pts, names, dg, dyn_status, n_tuners, method, Ph, targets, *a, **k):
        got["v"] = (pts, Ph, targets)
        return design_filter(pts, names, dg, dyn_status, n_tuners, method, Ph, targets, *a, **k)

    B.design_filter = keep   # the build's own point list, not a copy of how it is made
    try:
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            B.build(dense_spec(n_mach, n_nfr), os.path.join(tmp, "dense.h5"), workers=2,
                    progress=False, log=lambda *a: None)
            print(f"built the {n_mach} x {n_nfr} dynamics grid in {time.perf_counter() - t:.1f} s")
    finally:
        B.design_filter = design_filter
    with open(cache, "wb") as f:
        pickle.dump(got["v"], f)
    return got["v"]


def warm_up(ex, workers: int, pts, Ph, targets) -> None:
    """Start every worker and import the tuner code there (numba, scipy: about 1 CPU second
    each), as phases 1-2 of a build have done before phase 3."""
    V = np.eye(Ph.shape[0])[:1]
    list(ex.map(threads.call, [point_mses] * (2 * workers), [pts[:1]] * (2 * workers),
                [[V]] * (2 * workers), [Ph] * (2 * workers), [targets] * (2 * workers)))


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its finished (joined) children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@threads.one_blas_thread
def select(pts, Ph, targets, n_tuners: int, executor=None, maxiter: int = 40):
    """Subset then optimal tuners; returns (V, metric, wall-clock seconds)."""
    t = time.perf_counter()
    V, _, _, _ = select_subset(pts, n_tuners, Ph, targets, executor=executor)
    V, metric, _ = optimal_tuners(pts, V, Ph, targets, maxiter=maxiter, executor=executor)
    return V, metric, time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mach", type=int, default=11, help="Mach points of the dynamics grid (default 11)")
    ap.add_argument("--nfr", type=int, default=10, help="NfR points of the dynamics grid (default 10)")
    ap.add_argument("--tuners", type=int, default=7, help="number of tuners (default 7, as the demo)")
    ap.add_argument("--workers", type=int, nargs="+", default=[2], help="pool sizes to time (default 2)")
    ap.add_argument("--maxiter", type=int, default=40, help="L-BFGS-B iterations (default 40, as a build)")
    ap.add_argument("--cache", default="", help="pickle of the points (default: in the temp folder)")
    a = ap.parse_args(argv)
    cache = a.cache or os.path.join(tempfile.gettempdir(), f"pwl_tuner_points_{a.mach}x{a.nfr}.pkl")
    pts, Ph, targets = points(a.mach, a.nfr, cache)
    print(f"{len(pts)} dynamics points, {Ph.shape[0]} health parameters, {a.tuners} tuners, "
          f"{len(targets)} targets; points cached in {cache}")
    c = cpu_seconds()
    V1, m1, t1 = select(pts, Ph, targets, a.tuners, maxiter=a.maxiter)
    c1 = cpu_seconds() - c
    print(f"  in this process: {t1:7.2f} s   CPU {c1:7.2f} s   metric {m1:.6g}   load {os.getloadavg()[0]:.1f}")
    for w in a.workers:
        with B.process_pool(w) as ex:
            warm_up(ex, w, pts, Ph, targets)
            c = cpu_seconds()
            V, m, t = select(pts, Ph, targets, a.tuners, ex, a.maxiter)
        c = cpu_seconds() - c   # the workers' CPU counts once the pool has joined them
        same = "identical V" if np.array_equal(V, V1) else f"V differs by {np.abs(V - V1).max():.3g}"
        print(f"  {w} worker(s):    {t:7.2f} s   CPU {c:7.2f} s   metric {m:.6g}   {same}   "
              f"speed-up {t1 / t:.2f}x   load {os.getloadavg()[0]:.1f}")
        if not np.array_equal(V, V1):
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
