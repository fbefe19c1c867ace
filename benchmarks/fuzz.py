"""Fuzz benchmark (#14): thousands of damaged databases and logs through the estimator.

    python benchmarks/fuzz.py --db-mutants 10000 --log-mutants 1000 --seed 0 [--workers 2]

Mutants come from :mod:`pwl.bench.fuzz` (the shipped demo database, sealed; the first 1500 samples of
the new-engine demo flight). Each runs in a worker process under a watchdog: a mutant that does
not finish within ``--timeout`` seconds is a ``hang`` (the worker is killed and replaced). Prints
the counts by mutant kind and outcome and every failure (traceback, hang, silent); exit status 1
when there is any.
"""
from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import os
import sys
import tempfile
import threading
import time

import numpy as np


def _worker(conn, tmp):
    from pwl.bench import fuzz
    from pwl.demo_data import demo_paths
    from pwl.estimator import Estimator
    from pwl.logs import Log, read_log

    _, logs = demo_paths()
    clean_db = os.path.join(tmp, "clean.h5")
    full = read_log(logs[0])
    log = Log(full.time[:1500], {k: v[:1500] for k, v in full.channels.items()}, full.units,
              attrs={"dt": full.attrs.get("dt")})
    est = Estimator(clean_db)
    ref = est.run(log)
    data = open(clean_db, "rb").read()
    units = {c: est.channel_units.get(c, "") for c in est.input_channels}
    own = tempfile.mkdtemp(dir=tmp)
    while True:
        job = conn.recv()
        if job is None:
            return
        i, target, kind, seed = job
        rng = np.random.default_rng(seed)
        if target == "db":
            p = os.path.join(own, "db.h5")
            fuzz.mutate_database(data, p, kind, rng)
            res = fuzz.outcome(lambda: Estimator(p).run(log), ref)
        else:
            folder = tempfile.mkdtemp(dir=own)
            p = fuzz.mutate_log(log, folder, kind, rng, units)
            res = fuzz.outcome(lambda: est.run(p), ref)
        conn.send((i,) + res)


class Runner:
    """One worker process and the pipe to it; restarted after a hang."""

    def __init__(self, tmp):
        self.tmp = tmp
        self.start()

    def start(self):
        self.conn, child = mp.Pipe()
        self.proc = mp.get_context("fork").Process(target=_worker, args=(child, self.tmp), daemon=True)
        self.proc.start()

    def run(self, job, timeout):
        self.conn.send(job)
        if self.conn.poll(timeout):
            return self.conn.recv()[1:]
        self.proc.kill()
        self.proc.join()
        self.start()
        return "hang", f"no answer within {timeout:g} s"


def main(argv=None) -> int:
    from pwl.bench import fuzz
    from pwl.demo_data import demo_paths
    from pwl.database import GainDatabase

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db-mutants", type=int, default=10000, help="database mutants (default %(default)s)")
    ap.add_argument("--log-mutants", type=int, default=1000, help="log mutants (default %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the mutations (default %(default)s)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="worker processes (default: the number of cores)")
    ap.add_argument("--timeout", type=float, default=20.0,
                    help="seconds after which a mutant counts as a hang (default %(default)s)")
    args = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="pwl-fuzz-")
    GainDatabase.open(demo_paths()[0]).save(os.path.join(tmp, "clean.h5"))
    ss = np.random.SeedSequence(args.seed)
    seeds = ss.generate_state(args.db_mutants + args.log_mutants)
    jobs = [(i, "db", fuzz.DB_KINDS[i % len(fuzz.DB_KINDS)], int(seeds[i])) for i in range(args.db_mutants)]
    jobs += [(args.db_mutants + j, "log", fuzz.LOG_KINDS[j % len(fuzz.LOG_KINDS)],
              int(seeds[args.db_mutants + j])) for j in range(args.log_mutants)]
    counts = collections.Counter()
    failures = []
    lock = threading.Lock()
    todo = iter(jobs)
    t0 = time.perf_counter()
    done = [0]
    tty = sys.stderr.isatty()

    def drive():
        runner = Runner(tmp)
        while True:
            with lock:
                job = next(todo, None)
            if job is None:
                runner.conn.send(None)
                return
            out, detail = runner.run(job, args.timeout)
            with lock:
                counts[(job[1], job[2], out)] += 1
                if out in fuzz.FAILURES:
                    failures.append((job, out, detail))
                done[0] += 1
                if done[0] % max(1, len(jobs) // 20) == 0:   # one line per 5 % (a live line on a tty)
                    line = (f"{done[0]}/{len(jobs)} mutants, {len(failures)} failures, "
                            f"{time.perf_counter() - t0:.0f} s")
                    print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)

    threads = [threading.Thread(target=drive) for _ in range(max(1, args.workers))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if tty:
        print(file=sys.stderr)
    for target in ("db", "log"):
        kinds = fuzz.DB_KINDS if target == "db" else fuzz.LOG_KINDS
        total = sum(v for k, v in counts.items() if k[0] == target)
        print(f"\n{target} mutants: {total}")
        print(f"  {'kind':<22}" + "".join(f"{o:>10}" for o in fuzz.OUTCOMES))
        for kind in kinds:
            print(f"  {kind:<22}" + "".join(f"{counts[(target, kind, o)]:>10}" for o in fuzz.OUTCOMES))
        print(f"  {'all':<22}" + "".join(f"{sum(v for k, v in counts.items() if k[0] == target and k[2] == o):>10}"
                                           for o in fuzz.OUTCOMES))
    print(f"\n{len(jobs)} mutants in {time.perf_counter() - t0:.0f} s; failures: {len(failures)}")
    for job, out, detail in failures[:50]:
        print(f"  {out}: {job[1]} {job[2]} (seed {job[3]}): {detail}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
