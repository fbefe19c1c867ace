"""Health estimation on a flight simulated through the pyCycle turbojet adapter (docs/pycycle.md).

The engine carries a health fault (default: compressor efficiency -1 %, h = -0.01). The flight
holds altitude and Mach (off the trim grid) and steps the fuel flow between the steady values of
the degraded engine at a sequence of corrected speeds. The shaft speed is integrated from the
adapter's unbalanced solve (``evaluate``: dN/dt from pyCycle's net shaft power) by Heun's method
at the database's dt; once a step's transient has decayed to 1e-3 of the speed (the small-signal
range, where the response is linear to about 1e-6), the rest of it is the exact exponential approach to
the equilibrium, which is solved for with the adapter (secant on dN/dt = 0), and the outputs
follow linearly between the last solved point and the equilibrium. Sensor noise: the plant's
``sensor_noise`` (one-sigma fraction of the value), 0.1 % on T2 and P2; Wf exact.

The log is written (``--log``, pwl's HDF5 flight log, readable by ``pwl run``), the estimator
runs on it with the database, and the health estimate (median over the second half of the
flight) is printed against the truth, in points (percent), with the thrust and T40 errors.

    python benchmarks/pycycle_flight.py pc.h5 --log pc_flight.h5
    python benchmarks/pycycle_flight.py pc.h5 --fault turb_eff=-0.01 --seed 2
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from linearize.plant import load_plant
from pwl.database import GainDatabase
from pwl.estimator import Estimator
from pwl.logs import Log, write_log

INLET_NOISE = {"T2": 0.001, "P2": 0.001}
SETTLED = 1e-3       # |N - N_eq| / N below which the rest of a transient is the exponential tail


def parse_fault(text: str, names) -> np.ndarray:
    h = np.zeros(len(names))
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, _, val = item.partition("=")
        if name not in names:
            raise SystemExit(f"--fault {item!r}: unknown health parameter; known: {', '.join(names)}")
        h[list(names).index(name)] = float(val)
    return h


def equilibrium(plant, x, u, h, env, f0):
    """Shaft speed where dN/dt = 0 at fuel flow u, by secant steps from x (whose dN/dt is f0);
    returns (N_eq (1,), (y, z) there, slope a = d(dN/dt)/dN, 1/s)."""
    x1 = x * (1.0 + 1e-4 * (1.0 if f0[0] >= 0 else -1.0))   # towards the equilibrium
    f1, y, z = plant.evaluate(x1, u, h, env)
    xa, fa, xb, fb = x, f0, x1, f1
    for _ in range(8):
        a = (fb[0] - fa[0]) / (xb[0] - xa[0])
        if abs(fb[0]) == 0.0:
            return xb, (y, z), a
        xn = xb - fb / a
        fn, y, z = plant.evaluate(xn, u, h, env)
        xa, fa, xb, fb = xb, fb, xn, fn
        if abs(xn[0] - xa[0]) < 1e-9 * xn[0]:
            return xn, (y, z), a
    raise RuntimeError(f"no equilibrium found at Wf={u[0]:g} kg/s (last N={xb[0]:g} rpm, dN/dt={fb[0]:g})")


def simulate(plant, p, h, segments, dt):
    """Fuel-step flight at scheduling point p (alt, Mach, start NR) with health h: ``segments``
    is [(NR %, seconds)]: each sets Wf to the degraded engine's steady fuel flow at that
    corrected speed. Returns time (n,), Wf (n,), N (n,), Y (n, ny), Z (n, nz), evaluate count."""
    env = plant.environment(p)
    t0 = plant.trim(np.asarray(p, float), h, env)
    levels, guess = [], t0
    for nr, _ in segments:      # the fuel flows of the schedule (degraded engine, same ambient)
        guess = plant.trim(np.array([p[0], p[1], nr]), h, env, guess=guess)
        levels.append(guess["u"].copy())
    n = round(sum(s for _, s in segments) / dt)
    U = np.concatenate([np.repeat(u[None, :], round(s / dt), axis=0) for u, (_, s) in zip(levels, segments)])[:n]
    X = np.empty((n, 1))
    Y = np.empty((n, len(plant.y_names)))
    Z = np.empty((n, len(plant.z_names)))
    x = t0["x"].astype(float).copy()
    evals, k, a_est = 0, 0, None
    while k < n:
        u = U[k]
        f, y, z = plant.evaluate(x, u, h, env)
        evals += 1
        X[k], Y[k], Z[k] = x, y, z
        end = k + 1                     # the end of this fuel segment
        while end < n and np.array_equal(U[end], u):
            end += 1
        near = a_est is not None and a_est < 0 and abs(f[0] / a_est) < SETTLED * x[0]
        if end > k + 1 and (near or f[0] == 0.0):
            # small-signal range: the rest of the segment is the exponential tail to equilibrium
            xe, (ye, ze), a = equilibrium(plant, x, u, h, env, f)
            evals += 3
            tau = np.arange(1, end - k) * dt
            frac = np.exp(a * tau)[:, None]          # (x(t) - x_eq) / (x_k - x_eq)
            X[k + 1:end] = xe + (x - xe) * frac
            Y[k + 1:end] = ye + (y - ye) * frac
            Z[k + 1:end] = ze + (z - ze) * frac
            x = X[end - 1].copy()
            k, a_est = end, None
            print(f"  t={k * dt:6.1f} s  N={x[0]:8.1f} rpm  Wf={u[0]:.4f} kg/s  ({evals} evaluations)",
                  file=sys.stderr)
            continue
        f2 = plant.evaluate(x + dt * f, u, h, env)[0]      # Heun
        evals += 1
        if f[0] != 0.0:
            a_est = (f2[0] - f[0]) / (dt * f[0])           # local d(dN/dt)/dN
        x = x + 0.5 * dt * (f + f2)
        k += 1
    return np.arange(n) * dt, U, X, Y, Z, evals


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("database", help="gain database built from specs/pycycle_turbojet.toml")
    ap.add_argument("--fault", default="comp_eff=-0.01", help="true health, name=fraction,... (default %(default)s)")
    ap.add_argument("--alt", type=float, default=2000.0, help="flight altitude, m (default %(default)g)")
    ap.add_argument("--mach", type=float, default=0.3, help="flight Mach number (default %(default)g)")
    ap.add_argument("--schedule", default="95:25,90:20,93:20,87:20,91:20,96:25",
                    help="fuel steps as NR%%:seconds,... (default %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="sensor noise seed (default %(default)s)")
    ap.add_argument("--log", default="", help="write the simulated flight log here (HDF5 or .csv)")
    args = ap.parse_args(argv)

    db = GainDatabase.open(args.database)
    plant = load_plant(db.attrs["model"], db.attrs.get("model_parameters", {}))
    h = parse_fault(args.fault, plant.h_names)
    segments = [(float(a), float(b)) for a, b in (s.split(":") for s in args.schedule.split(","))]
    p = np.array([args.alt, args.mach, segments[0][0]])

    t_sim = time.perf_counter()
    t, U, _, Y, Z, evals = simulate(plant, p, h, segments, db.dt)
    t_sim = time.perf_counter() - t_sim
    env = plant.environment(p)
    T2, P2 = plant.inlet(env)
    rng = np.random.default_rng(args.seed)
    n = t.size
    ch = {"alt": np.full(n, args.alt), "Mach": np.full(n, args.mach), "Wf": U[:, 0].copy(),
          "T2": T2 * (1 + INLET_NOISE["T2"] * rng.standard_normal(n)),
          "P2": P2 * (1 + INLET_NOISE["P2"] * rng.standard_normal(n))}
    for j, name in enumerate(plant.y_names):
        ch[name] = Y[:, j] * (1 + plant.sensor_noise.get(name, 0.0) * rng.standard_normal(n))
    truth = {f"{name}": Y[:, j].copy() for j, name in enumerate(plant.y_names)}
    truth.update({name: Z[:, j].copy() for j, name in enumerate(plant.z_names)})
    truth.update({name: np.full(n, h[j]) for j, name in enumerate(plant.h_names)})
    log = Log(t, ch, {c: plant.units[c] for c in ch}, truth, {c: plant.units[c] for c in truth},
              attrs={"dt": db.dt, "model": plant.name, "seed": args.seed, "fault": args.fault,
                     "schedule": args.schedule})
    if args.log:
        write_log(args.log, log)

    t_est = time.perf_counter()
    res = Estimator(db).run(log)
    t_est = time.perf_counter() - t_est
    half = slice(n // 2, None)
    est = np.median(res.h_hat[half], axis=0)
    print(f"flight: {t[-1] + db.dt:g} s at alt {args.alt:g} m, Mach {args.mach:g}, fuel steps to NR "
          f"{', '.join(f'{a:g}' for a, _ in segments)} %; {evals} pyCycle evaluations in {t_sim:.0f} s; "
          f"estimator {1e3 * t_est:.0f} ms for {n} samples")
    print(f"true health: {args.fault}; estimate = median of h_hat over the second half (points = %)\n")
    print("| health parameter | truth, points | estimate, points | error, points |")
    print("|---|---:|---:|---:|")
    for j, name in enumerate(plant.h_names):
        print(f"| {name} | {100 * h[j]:+.2f} | {100 * est[j]:+.3f} | {100 * (est[j] - h[j]):+.3f} |")
    print()
    for name in ("Fn", "T40"):
        j = list(plant.z_names).index(name)
        e = 100 * (res.z_hat[half, j] - Z[half, j]) / np.abs(Z[half, j])
        print(f"{name}: second-half RMS error {np.sqrt(np.mean(e ** 2)):.3f} % of truth, median {np.median(e):+.3f} %")
    worst = float(np.max(np.abs(est - h)))
    print(f"\nlargest health error {100 * worst:.3f} points")
    return 0 if worst <= 0.003 else 1


if __name__ == "__main__":
    sys.exit(main())
