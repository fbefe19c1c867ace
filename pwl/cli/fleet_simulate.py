"""pwl fleet simulate: a ProDiMES-style fleet of simulated turbofan flights (models.fleet).

Writes FLEET/<serial>/flight_<NNN>.h5 (one flight log per engine and flight, truth inside, fleet
attrs: engine, flight_index, flight_time, fault class/magnitude/onset, fault_active, the flight's
settings), FLEET/truth.csv (one row per engine: the fault that was seeded) and FLEET/fleet.json
(the generation settings and every constant of the fleet, software version). With ``--snapshots``
FLEET/snapshots.csv instead of the logs: the steady snapshots an engine-monitoring report carries
(ground idle and cruise per flight, :func:`models.fleet.snapshot_rows`), as ProDiMES gives its
data, for ``pwl fleet diagnose FLEET/snapshots.csv --database DB``.
"""
from __future__ import annotations

import csv
import json
import math
import os
import sys
import time

HELP = "simulate a fleet of engines over many flights (health scatter, deterioration, seeded faults)"

_plan = None


def add_simulate_arguments(p):
    p.add_argument("--engines", type=int, default=100, help="number of engines (default %(default)s)")
    p.add_argument("--flights", type=int, default=20, help="flights per engine (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default %(default)s)")
    p.add_argument("-o", "--outdir", required=True, metavar="FLEET",
                   help="output folder (required; created if missing)")
    p.add_argument("-j", "--workers", type=int, default=None,
                   help="parallel processes (default: the number of cores)")
    p.add_argument("--fault-fraction", type=float, default=0.6,
                   help="fraction of engines with one abrupt fault, 0..1 (default %(default)g)")
    p.add_argument("--snapshots", action="store_true",
                   help="write FLEET/snapshots.csv (steady snapshots at ground idle and cruise per flight, "
                        "as engine-monitoring reports and ProDiMES give them) instead of flight logs "
                        "(default: flight logs)")
    p.add_argument("--snapshot-regimes", default="idle,cruise", metavar="LIST",
                   help="where the snapshots are taken, of idle, takeoff, cruise (default %(default)s; "
                        "ProDiMES: takeoff,cruise)")
    p.add_argument("--snapshot-samples", type=int, default=1, metavar="N",
                   help="readings each snapshot averages: its noise is the sensors' / sqrt(N) (default "
                        "%(default)s: one reading, as ProDiMES)")


def _init_worker(plan):
    global _plan
    _plan = plan


def flight_path(outdir, serial, flight, flights) -> str:
    return os.path.join(os.fspath(outdir), serial, f"flight_{flight:0{max(3, len(str(flights - 1)))}d}.h5")


def _one(i, j, path):
    """Simulate and write one flight in this process; (i, j, error message or None)."""
    from models.fleet import simulate_flight

    from ..logs import Log, write_log
    try:
        r = simulate_flight(_plan, i, j)
        write_log(path, Log(r["time"], r["channels"], r["units"], r["truth"], r["truth_units"],
                            r["attrs"]), compact=True)
    except Exception as e:  # one flight that fails must not lose the fleet: report it, go on
        return i, j, f"{type(e).__name__}: {e}"
    return i, j, None


def _write_csv(path, cols, rows):
    """``rows`` (dicts) as CSV columns ``cols``, floats written exactly; atomically."""
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow([repr(r[c]) if isinstance(r[c], float) else r[c] for c in cols])
    os.replace(tmp, path)


def _write_truth(outdir, rows):
    _write_csv(os.path.join(outdir, "truth.csv"), ("engine", "class", "magnitude", "unit", "bias", "bias_unit",
                                                    "onset", "eff", "flow"), rows)


def _write_json(outdir, data):
    path = os.path.join(outdir, "fleet.json")
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
        fh.write("\n")
    os.replace(tmp, path)


def simulate_fleet(outdir, engines, flights, seed=0, workers=None, fault_fraction=0.6, classes=None,
                   progress=True) -> dict:
    """Plan and simulate a fleet into ``outdir``; returns a summary: engines, flights, total,
    simulated, failed, failures [(serial, flight, message)], seconds, flights_per_s, workers.
    A flight that fails to simulate is recorded and the others still complete."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from models import fleet

    from .. import __version__

    plan = fleet.plan_fleet(engines, flights, seed, fault_fraction, classes)
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    outdir = os.fspath(outdir)
    os.makedirs(outdir, exist_ok=True)
    settings = fleet.settings(plan)
    settings["software"] = {"pwl": __version__}
    _write_json(outdir, settings)
    _write_truth(outdir, fleet.truth_rows(plan))
    jobs = [(i, j, flight_path(outdir, plan.serial[i], j, plan.flights))
            for i in range(plan.engines) for j in range(plan.flights)]
    total = len(jobs)
    workers = max(1, min(total, workers or os.cpu_count() or 1))
    step = max(1, math.ceil(total / 20))
    failures = []
    t0 = time.perf_counter()

    def done(k, res):
        i, j, err = res
        if err is not None:
            failures.append((plan.serial[i], j, err))
        if progress and (k % step == 0 or k == total):
            dt = time.perf_counter() - t0
            print(f"[{k}/{total}] flights simulated, {k / max(dt, 1e-9):.2f} flights/s",
                  file=sys.stderr, flush=True)

    if workers == 1:
        _init_worker(plan)
        for k, job in enumerate(jobs, 1):
            done(k, _one(*job))
    else:
        with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(plan,)) as ex:
            futs = [ex.submit(_one, *job) for job in jobs]
            for k, fut in enumerate(as_completed(futs), 1):
                done(k, fut.result())
    seconds = time.perf_counter() - t0
    failures.sort(key=lambda f: (f[0], f[1]))
    if progress and failures:
        print(f"{len(failures)} of {total} flights failed:", file=sys.stderr)
        for serial, j, err in failures:
            print(f"  {serial} flight {j}: {err}", file=sys.stderr)
    return {"outdir": outdir, "engines": plan.engines, "flights": plan.flights, "total": total,
            "simulated": total - len(failures), "failed": len(failures), "failures": failures,
            "seconds": seconds, "flights_per_s": total / max(seconds, 1e-9), "workers": workers,
            "faulty_engines": sum(c != "none" for c in plan.fault_class)}


def simulate_snapshots(outdir, engines, flights, seed=0, fault_fraction=0.6, samples=1, classes=None,
                       progress=True, regimes=None) -> dict:
    """Plan a fleet as :func:`simulate_fleet` does (the same engines, faults and flights for the
    same seed) and write its steady snapshots to ``outdir``/snapshots.csv (atomically), with
    truth.csv and fleet.json; returns the summary of :func:`simulate_fleet` (``path``: the table).
    A flight whose trim fails is recorded and left out."""
    from models import fleet

    from .. import __version__

    plan = fleet.plan_fleet(engines, flights, seed, fault_fraction, classes)
    regimes = tuple(regimes or fleet.DEFAULT_SNAPSHOT_REGIMES)
    fleet.snapshot_rows(plan, 0, 0, samples, regimes=regimes)      # a bad argument: ValueError, nothing written
    outdir = os.fspath(outdir)
    os.makedirs(outdir, exist_ok=True)
    settings = fleet.settings(plan)
    settings["software"] = {"pwl": __version__}
    settings["snapshots"] = {"samples": int(samples), "regimes": list(regimes),
                             "takeoff_mach": fleet.TAKEOFF_MACH}
    t0 = time.perf_counter()
    rows, failures = [], []
    total = plan.engines * plan.flights
    for i in range(plan.engines):
        for j in range(plan.flights):
            try:
                rows += fleet.snapshot_rows(plan, i, j, samples, regimes=regimes)
            except Exception as e:  # noqa: BLE001 -- one flight must not lose the fleet
                failures.append((plan.serial[i], j, f"{type(e).__name__}: {e}"))
        if progress and (i + 1) % max(1, plan.engines // 10) == 0:
            print(f"[{(i + 1) * plan.flights}/{total}] flights", file=sys.stderr, flush=True)
    path = os.path.join(outdir, "snapshots.csv")
    _write_csv(path, list(rows[0]) if rows else list(fleet.SNAPSHOT_KEYS), rows)
    _write_json(outdir, settings)
    _write_truth(outdir, fleet.truth_rows(plan))
    seconds = time.perf_counter() - t0
    return {"outdir": outdir, "path": path, "engines": plan.engines, "flights": plan.flights, "total": total,
            "simulated": total - len(failures), "failed": len(failures), "failures": failures,
            "seconds": seconds, "flights_per_s": total / max(seconds, 1e-9), "workers": 1,
            "faulty_engines": sum(c != "none" for c in plan.fault_class)}


def run_simulate(args) -> int:
    from .output import check_output

    check_output(args.outdir, folder=True)
    if args.snapshots:
        try:
            s = simulate_snapshots(args.outdir, args.engines, args.flights, args.seed, args.fault_fraction,
                                   args.snapshot_samples, regimes=[r.strip() for r in args.snapshot_regimes.split(",")])
        except ValueError as e:
            print(f"pwl fleet simulate: {e}", file=sys.stderr)
            return 2
        for serial, j, err in s["failures"]:
            print(f"  {serial} flight {j}: {err}", file=sys.stderr)
        print(f"{s['path']}: {s['engines']} engines x {s['flights']} flights ({s['faulty_engines']} faulty "
              f"engines), {s['simulated']} flights' snapshots, {s['failed']} failed, {s['seconds']:.1f} s")
        return 1 if s["failed"] else 0
    s = simulate_fleet(args.outdir, args.engines, args.flights, args.seed, args.workers,
                       args.fault_fraction, progress=True)
    print(f"{s['outdir']}: {s['engines']} engines x {s['flights']} flights ({s['faulty_engines']} "
          f"faulty engines), {s['simulated']} flights simulated, {s['failed']} failed, "
          f"{s['seconds']:.1f} s ({s['flights_per_s']:.2f} flights/s, {s['workers']} workers)")
    return 1 if s["failed"] else 0
