"""Perturbation linearization at a trim point and zero-order-hold discretization.

Columns by perturbation (DESIGN.md section 3, paper 002 sec. 3.1.3): perturb one state, input or
health parameter with the others held, run the plant's unbalanced solve, and difference the
state derivatives f and the outputs y, z. Central differences by default; where one direction
fails (infeasible: an exception or a non-finite value) the other is used one-sided; a column whose both directions fail fails the
point.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from pwl.errors import PwlError

from .plant import perturbation_sizes

MATRICES = ("A", "B", "C", "D", "F", "G", "L", "M", "N")


class LinearizationError(PwlError, RuntimeError):
    """The plant could not be evaluated around this point (names the variable)."""


def jacobians(plant, trim: dict, h, env, method: str = "central", overrides: dict | None = None):
    """Continuous (or the plant's discrete) A..N at a trim point.

    trim: {"x": (nx,), "u": (nu,), ...} from ``plant.trim``; h (nh,) health; env from
    ``plant.environment``. Returns (mats, info): mats maps A (nx,nx), B (nx,nu), C (ny,nx),
    D (ny,nu), F (nz,nx), G (nz,nu), L (nx,nh), M (ny,nh), N (nz,nh); info counts one-sided columns.
    """
    if method not in ("central", "forward"):
        raise ValueError(f"perturbation method must be 'central' or 'forward', got {method!r}")
    x0 = np.asarray(trim["x"], dtype=np.float64)
    u0 = np.asarray(trim["u"], dtype=np.float64)
    h0 = np.asarray(h, dtype=np.float64)
    base = None
    one_sided = 0

    sizes = {"f": x0.size, "y": len(plant.y_names), "z": len(plant.z_names)}

    def ev(x, u, hh):
        """[f; y; z] at (x, u, hh). LinearizationError for a wrong length or integer values (a
        plant's mistake at every point); FloatingPointError for a non-finite value (a failed
        direction, like an exception)."""
        parts = []
        for (name, n), a in zip(sizes.items(), plant.evaluate(x, u, hh, env)):
            a = np.ravel(np.asarray(a))
            if a.size != n:
                raise LinearizationError(f"plant.evaluate returned {a.size} values of {name}, the plant has {n}")
            if a.dtype.kind not in "f":
                raise LinearizationError(f"plant.evaluate returned {name} as {a.dtype}: return floats (integers "
                                         "have no derivative to perturb)")
            parts.append(a)
        v = np.concatenate(parts).astype(np.float64)
        if not np.all(np.isfinite(v)):
            bad = [k for (k, n), a in zip(sizes.items(), parts) if not np.all(np.isfinite(a))]
            raise FloatingPointError(f"plant.evaluate returned non-finite {', '.join(bad)}")
        return v

    def evaluate_base():
        nonlocal base
        if base is None:
            base = ev(x0, u0, h0)
        return base

    cols = {}
    for kind, v0 in (("x", x0), ("u", u0), ("h", h0)):
        steps = perturbation_sizes(plant, v0, kind, overrides)
        out = np.empty((evaluate_base().size, v0.size))
        for j in range(v0.size):
            vals = {}
            for sgn in ((+1, -1) if method == "central" else (+1,)):
                v = v0.copy()
                v[j] += sgn * steps[j]
                args = {"x": x0, "u": u0, "h": h0}
                args[kind] = v
                try:
                    vals[sgn] = ev(args["x"], args["u"], args["h"])
                except LinearizationError:
                    raise
                except Exception as e:  # a failed direction (or NaN): try the other one (one-sided)
                    vals[sgn] = e
            ok = {s: r for s, r in vals.items() if not isinstance(r, Exception)}
            if len(ok) == 2:
                out[:, j] = (ok[1] - ok[-1]) / (2.0 * steps[j])
            elif ok:
                s, r = next(iter(ok.items()))
                out[:, j] = s * (r - evaluate_base()) / steps[j]
                one_sided += method == "central"
            else:
                err = next(iter(vals.values()))
                raise LinearizationError(f"perturbing {getattr(plant, kind + '_names')[j]} failed in "
                                         f"every direction: {type(err).__name__}: {err}")
        cols[kind] = out
    nx, ny = x0.size, len(plant.y_names)
    rows = {"x": slice(0, nx), "y": slice(nx, nx + ny), "z": slice(nx + ny, None)}
    mats = {"A": cols["x"][rows["x"]], "B": cols["u"][rows["x"]], "C": cols["x"][rows["y"]],
            "D": cols["u"][rows["y"]], "F": cols["x"][rows["z"]], "G": cols["u"][rows["z"]],
            "L": cols["h"][rows["x"]], "M": cols["h"][rows["y"]], "N": cols["h"][rows["z"]]}
    return {k: np.ascontiguousarray(v) for k, v in mats.items()}, {"one_sided_columns": one_sided}


def zoh(A, B, dt: float):
    """Zero-order-hold discretization: (Ad, Bd) = (e^{A dt}, int_0^dt e^{A s} ds B), by the
    matrix exponential of the block matrix [[A, B], [0, 0]] dt. B may hold several input groups
    side by side (inputs and health parameters are both held over a step)."""
    A = np.atleast_2d(np.asarray(A, dtype=np.float64))
    B = np.asarray(B, dtype=np.float64).reshape(A.shape[0], -1)
    n, m = A.shape[0], B.shape[1]
    E = np.zeros((n + m, n + m))
    E[:n, :n] = A * dt
    E[:n, n:] = B * dt
    X = expm(E)
    return X[:n, :n], X[:n, n:]


def discretize(mats: dict, dt: float) -> dict:
    """A, B, L continuous -> discrete by ZOH at dt (C, D, F, G, M, N are unchanged)."""
    nu = mats["B"].shape[1]
    Ad, BL = zoh(mats["A"], np.hstack([mats["B"], mats["L"]]), dt)
    out = dict(mats)
    out["A"], out["B"], out["L"] = Ad, np.ascontiguousarray(BL[:, :nu]), np.ascontiguousarray(BL[:, nu:])
    return out


def correct(mats: dict, fac: dict) -> dict:
    """Matrices in corrected units: each block scaled by diag(1/f_row) M diag(f_col), with the
    correction factors ``fac`` (kind -> (n,)) at the point; health columns are never corrected."""
    fx, fu, fy, fz = fac["x"], fac["u"], fac["y"], fac["z"]
    rows = {"A": fx, "B": fx, "L": fx, "C": fy, "D": fy, "M": fy, "F": fz, "G": fz, "N": fz}
    cols = {"A": fx, "C": fx, "F": fx, "B": fu, "D": fu, "G": fu}
    out = {}
    for k, M in mats.items():
        c = cols.get(k)
        out[k] = (M / rows[k][:, None]) * (c[None, :] if c is not None else 1.0)
    return out
