"""One BLAS/LAPACK thread for the builder's small matrices.

Every LAPACK call of a build is small (trims, Jacobians, DAREs of at most a few dozen states),
far below the size where threads pay. OpenBLAS still wakes its thread pool for each call; on a
loaded machine those threads wait for cores, and the demo build took 27 s instead of 7 s with two
other busy processes on 2 cores (docs/building.md). ``threadpoolctl`` sets the limit at run time,
after numpy is imported, which an environment variable cannot; the parallelism of a build is
its processes.
"""
from __future__ import annotations

from threadpoolctl import threadpool_limits


def one_blas_thread(fn):
    """Decorator: ``fn`` runs with BLAS/LAPACK limited to one thread (restored after)."""
    return threadpool_limits.wrap(limits=1, user_api="blas")(fn)


@one_blas_thread
def call(fn, *args):
    """fn(*args) with one BLAS thread: what the builder submits to executors (the limit must be
    set in the worker process; about 1 ms per call)."""
    return fn(*args)
