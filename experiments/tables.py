"""Experiments with adaptive tables: seed 000 section 5 and the seed 003 battery case.

Plain functions returning numbers (the ``pwl tables`` command prints and plots them; the tests
check the claims on small seeded runs). pwl core only (the adaptive tables): the battery case
takes the simulated data as arrays (``models.battery.simulate`` makes them).

Seed 000 section 5, as set up here (the paper gives no functions or grid sizes; docs explain):

* 1-D target f1(u) = 1 + 0.5 sin(2 pi u) on 11 nodes, 2-D target
  f2(u1, u2) = 1 + 0.4 sin(2 pi u1) cos(pi u2) + 0.3 u1 u2 on 7 x 7 nodes, u in [0, 1]^n;
* T_r = the target at the nodes; the reference is the table T_r itself at the point,
  x_k = c(u_k)^T T_r (+ bias)(+ noise), so T_k can converge to T_r exactly (eq. 9);
* 1000 uniformly random points, table from zero, eq_k = 100 sum (theta - theta_r)^2 / equ with
  equ = sum (theta_0 - theta_r,0)^2 (eq. 8: 100 % at the start; the bias case keeps equ);
* noise zeta_k uniform on [-A, A] ("amplitude" A = 0.2 in the text, 0.4 in the caption).
"""
from __future__ import annotations

import numpy as np

from pwl.grid import Axis, Grid
from pwl.interp import interpolate
from pwl.tables import AdaptiveTable

SIGMA_RATIOS = (0.0, 0.1, 1.0)  # sigma_x / sigma_theta; the gain laws take its square


def target_1d(u):
    u = np.asarray(u, dtype=np.float64)
    return 1.0 + 0.5 * np.sin(2 * np.pi * u[..., 0])


def target_2d(u):
    u = np.asarray(u, dtype=np.float64)
    return 1.0 + 0.4 * np.sin(2 * np.pi * u[..., 0]) * np.cos(np.pi * u[..., 1]) + 0.3 * u[..., 0] * u[..., 1]


def seed000_grid(dim: int) -> Grid:
    if dim == 1:
        return Grid([Axis("u", np.linspace(0.0, 1.0, 11))])
    if dim == 2:
        return Grid([Axis("u1", np.linspace(0.0, 1.0, 7)), Axis("u2", np.linspace(0.0, 1.0, 7))])
    raise ValueError(f"seed 000 cases are 1-D or 2-D, got {dim}")


def seed000_run(dim: int, law: str = "exact", sigma_ratio: float = 0.0, noise: float = 0.0,
                step: float = 0.0, step_at: int = 200, n: int = 1000, seed: int = 0) -> np.ndarray:
    """One learning run; returns eq_k for k = 0..n (eq_0 = 100 %).

    sigma_ratio = sigma_x / sigma_theta (the law's ratio is its square); noise = amplitude A of
    the uniform reference noise; step = bias added to the whole function from iteration step_at.
    """
    grid = seed000_grid(dim)
    rng = np.random.default_rng(seed)
    tr = (target_1d if dim == 1 else target_2d)(grid.nodes()).reshape(grid.shape)
    pts = rng.random((n, dim))
    x = interpolate(grid, tr, pts)
    bias = np.where(np.arange(n) >= step_at, step, 0.0)
    zeta = rng.uniform(-noise, noise, n) if noise > 0 else np.zeros(n)
    table = AdaptiveTable(grid, law=law, ratio=sigma_ratio ** 2)
    _, hist = table.learn(pts, x + bias + zeta, history=True)
    ref = tr.reshape(1, -1) + bias[:, None]
    equ = np.sum(tr ** 2)
    eq = np.empty(n + 1)
    eq[0] = 100.0
    eq[1:] = 100.0 * np.sum((hist - ref) ** 2, axis=1) / equ
    return eq


def first_below(eq: np.ndarray, level: float, start: int = 0) -> int:
    """First iteration k >= start with eq_k < level (-1 if never)."""
    hit = np.flatnonzero(eq[start:] < level)
    return int(hit[0] + start) if hit.size else -1


def seed000(n: int = 1000, seeds: int = 10, laws=("exact", "paper"), sigma_ratios=SIGMA_RATIOS,
            noises=(0.2, 0.4), step: float = 0.6, step_at: int = 200) -> dict:
    """All seed-000 cases, eq_k averaged over ``seeds`` point sets (the same sets for every case).

    Returns {"curves": {(case, dim, law, sigma_ratio, noise): mean eq (n+1,)}, "rows": [dict]}.
    Cases: "reliable" (1-D and 2-D), "bias" (2-D, +step at step_at), "noise" (2-D, each noise).
    """
    specs = [("reliable", d, 0.0) for d in (1, 2)] + [("bias", 2, 0.0)] + [("noise", 2, a) for a in noises]
    curves, rows = {}, []
    for case, dim, amp in specs:
        for law in laws:
            for sr in sigma_ratios:
                runs = np.array([seed000_run(dim, law, sr, noise=amp, step=step if case == "bias" else 0.0,
                                             step_at=step_at, n=n, seed=s) for s in range(seeds)])
                eq = runs.mean(axis=0)
                curves[(case, dim, law, sr, amp)] = eq
                tail = max(1, n * 3 // 10)
                row = {"case": case, "dim": dim, "law": law, "sigma_ratio": sr, "noise": amp,
                       "eq100": eq[min(100, n)], "eq200": eq[min(200, n)], "eq500": eq[min(500, n)],
                       "eq_end": eq[n], "k_below_1pct": first_below(eq, 1.0),
                       "steady": float(runs[:, -tail:].mean()),
                       "steady_std": float(runs[:, -tail:].mean(axis=1).std(ddof=1)) if seeds > 1 else 0.0}
                if case == "bias":
                    row["eq_after_step"] = float(eq[step_at + 1]) if step_at < n else np.nan
                    row["k_recovered"] = first_below(eq, 1.0, step_at + 1)
                rows.append(row)
    return {"curves": curves, "rows": rows, "n": n, "seeds": seeds, "step": step, "step_at": step_at}


def format_seed000(res: dict) -> str:
    """The seed-000 table as text."""
    lines = [f"seed 000 section 5: eq_k in % (mean of {res['seeds']} random point sets, {res['n']} "
             f"iterations); steady = mean eq over the last 30 % (+- std over sets)",
             f"{'case':<9}{'dim':>4} {'law':<6}{'sx/st':>6}{'noise':>6}{'eq100':>9}{'eq200':>9}"
             f"{'eq500':>9}{'eq_end':>9}{'k<1%':>6}{'steady':>16}{'after step':>11}{'k rec<1%':>9}"]
    for r in res["rows"]:
        extra = (f"{r['eq_after_step']:>11.2f}{r['k_recovered']:>9d}" if r["case"] == "bias" else "")
        lines.append(f"{r['case']:<9}{r['dim']:>4} {r['law']:<6}{r['sigma_ratio']:>6g}{r['noise']:>6g}"
                     f"{r['eq100']:>9.3f}{r['eq200']:>9.3f}{r['eq500']:>9.3f}{r['eq_end']:>9.4f}"
                     f"{r['k_below_1pct']:>6d}{r['steady']:>9.4f} +-{r['steady_std']:<5.3f}{extra}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# seed 003: battery ohmic resistance over temperature, correlated ageing
# ---------------------------------------------------------------------------------------------
def battery_compare(sim: dict, *, length: float = 2.0, ratio_local: float | None = None,
                    ratio_corr: float | None = None) -> dict:
    """Local (exact law) versus correlated whole-table learning on one simulated battery life.

    sim (``models.battery.simulate``): "temperature" (k,) and "measured" (k,) noisy local
    resistance estimates, "nodes" (table breakpoints), "table0" (begin-of-life table),
    "truth_end" (true resistance at the nodes at the end), "sigma_prior" (ageing random-walk
    std per node and step), "noise_std". Both laws use the same noise model: ratio =
    noise_std^2 / sigma^2 (local: sigma at the most visited node; correlated: mean sigma^2).
    Returns end-of-life errors per node, RMS errors over never / rarely (< 1 % of the
    estimates) / often visited nodes and their ratios correlated / local, the visit counts and
    the histories of both tables.
    """
    nodes = np.asarray(sim["nodes"], dtype=np.float64)
    table0 = np.asarray(sim["table0"], dtype=np.float64)
    sig = np.asarray(sim["sigma_prior"], dtype=np.float64)
    grid = Grid([Axis("T", nodes, "degC")])
    T = np.asarray(sim["temperature"], dtype=np.float64)[:, None]
    y = np.asarray(sim["measured"], dtype=np.float64)
    truth = np.asarray(sim["truth_end"], dtype=np.float64)
    noise2 = float(sim["noise_std"]) ** 2
    if ratio_corr is None:
        ratio_corr = noise2 / float(np.mean(sig ** 2))
    if ratio_local is None:
        busiest = np.argmin(np.abs(nodes[:, None] - T[None, :, 0]), axis=0)
        ratio_local = noise2 / float(sig[np.bincount(busiest, minlength=nodes.size).argmax()] ** 2)
    local = AdaptiveTable(grid, table0, "exact", ratio_local)
    corr = AdaptiveTable(grid, table0, "correlated", ratio_corr, sigma=sig, length=length,
                         P=np.zeros((grid.size, grid.size)))
    _, h_loc = local.learn(T, y, history=True)
    _, h_cor = corr.learn(T, y, history=True)
    err_loc = local.values - truth
    err_cor = corr.values - truth
    counts = local.counts.copy()
    never = counts == 0
    rare = (counts > 0) & (counts < 0.01 * len(y))
    out = {"nodes": np.asarray(nodes, dtype=np.float64), "counts": counts, "truth_end": truth,
           "table0": np.asarray(table0, dtype=np.float64), "local": local.values.copy(),
           "correlated": corr.values.copy(), "err_local": err_loc, "err_corr": err_cor,
           "never": never, "rare": rare, "ratio_local": ratio_local, "ratio_corr": ratio_corr,
           "length": length, "hist_local": h_loc, "hist_corr": h_cor,
           "sd_corr": np.sqrt(np.maximum(np.diag(corr.P), 0.0))}
    for name, mask in (("never", never), ("rare", rare), ("visited", counts >= 0.01 * len(y))):
        if np.any(mask):
            el = float(np.sqrt(np.mean(err_loc[mask] ** 2)))
            ec = float(np.sqrt(np.mean(err_cor[mask] ** 2)))
            out[f"rms_local_{name}"] = el
            out[f"rms_corr_{name}"] = ec
            out[f"ratio_{name}"] = ec / el if el > 0 else np.nan
    return out
