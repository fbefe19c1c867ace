"""Executors for work spread over processes: builds (linearize.build) and many-log runs
(pwl.fleet.runs) use the same ones."""
from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import Executor, Future, ProcessPoolExecutor


class SerialExecutor(Executor):
    """Runs every task at once in this process (tests, debugging, plants that cannot be pickled)."""

    def submit(self, fn, /, *args, **kwargs):
        fut = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:  # delivered through the future, as a real executor would
            fut.set_exception(e)
        return fut


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A process pool whose workers end when this process dies, even by SIGKILL (no orphans)."""
    ctx = multiprocessing.get_context()
    # with fork and spawn this process is the workers' parent (with forkserver, the server is)
    builder = os.getpid() if ctx.get_start_method() in ("fork", "spawn") else None
    return ProcessPoolExecutor(workers, mp_context=ctx, initializer=_die_with_parent, initargs=(builder,))


def _die_with_parent(builder: int | None) -> None:
    """Worker initializer: end this worker when the process that started it dies.

    Linux: the kernel sends SIGKILL when the parent dies (prctl PR_SET_PDEATHSIG). Everywhere: a
    daemon thread exits the worker once its parent pid changes (it was re-parented). ``builder``,
    the build's pid when it is the direct parent, catches a build killed before this ran. A TERM
    ends a worker as it would without pwl (the CLI turns it into an interrupt in the parent)."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _kill_me_with_parent()
    parent = os.getppid()
    if builder is not None and parent != builder:
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="pwl-watch-parent").start()


def _kill_me_with_parent() -> None:
    """Linux: ask the kernel for SIGKILL when the parent dies; a no-op where prctl is missing.

    The kernel ties the signal to the parent *thread* that forked the worker: the pool forks its
    workers from the thread that submits the first task (the build's own), which outlives them."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass  # the watch thread still ends the worker


def _watch_parent(parent: int, interval: float = 0.5) -> None:
    """Exit this process as soon as its parent is no longer ``parent``."""
    while os.getppid() == parent:
        time.sleep(interval)
    os._exit(1)
