"""The Plant protocol as the builder sees it (docs/plant-protocol.md): loading, checking, and the
few derived quantities every build step needs (sizes, perturbation sizes, correction factors).

A plant is duck-typed: any object with the documented attributes works, including plants
written outside this repository. Nothing here imports a model.
"""
from __future__ import annotations

import difflib
import importlib
import math
from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from pwl.errors import PwlError

KINDS = ("x", "u", "y", "z", "h")


@runtime_checkable
class Plant(Protocol):
    """What the builder needs of a plant (docs/plant-protocol.md has the optional attributes:
    time, dt, h_ref, perturbation, sensor_noise, correction, theta_delta, schedule, ranges).
    Structural: a plant does not inherit from it; :func:`check_plant` checks an object
    against it and names what is missing."""

    name: str
    x_names: Sequence[str]     # states
    u_names: Sequence[str]     # inputs (actuators)
    y_names: Sequence[str]     # sensed outputs
    z_names: Sequence[str]     # unmeasured outputs
    h_names: Sequence[str]     # health parameters
    p_names: Sequence[str]     # scheduling variables (the grid axes)
    units: Mapping[str, str]   # unit of every name above and of every log channel the runtime reads

    def environment(self, p: np.ndarray) -> np.ndarray:
        """The ambient condition (float64 array) of scheduling point p."""

    def trim(self, p: np.ndarray, h: np.ndarray, env: np.ndarray, guess: dict | None = None) -> dict:
        """Steady state at p with health h: {"x", "u", "y", "z"} float64 arrays; raises on failure."""

    def evaluate(self, x: np.ndarray, u: np.ndarray, h: np.ndarray, env: np.ndarray) -> tuple:
        """(f, y, z) with states and inputs held: f = dx/dt (continuous) or x[k+1] (discrete)."""

    def parameters(self) -> dict:
        """JSON-serialisable model parameters (stored in the database)."""


#: the members every plant must have: the protocol's, in its order
REQUIRED = tuple(Plant.__annotations__) + ("environment", "trim", "evaluate", "parameters")


class PlantProtocolError(PwlError, TypeError):
    """An object that does not satisfy the Plant protocol (names what is missing or wrong)."""


def load_plant(target: str, parameters: dict | None = None):
    """Instantiate ``"package.module:ClassName"`` with keyword ``parameters``."""
    return check_plant(import_plant(target)(**(parameters or {})))


def import_plant(target: str):
    """The class named by ``"package.module:ClassName"``; :class:`PlantProtocolError` naming the
    target when the module or the class cannot be found (or the module fails to import)."""
    if ":" not in target:
        raise PlantProtocolError(f"model {target!r}: expected 'package.module:ClassName'")
    mod, cls = target.split(":", 1)
    try:
        module = importlib.import_module(mod)
    except Exception as e:  # not found, or the module's own error while importing
        raise PlantProtocolError(f"model {target!r} cannot be imported: {type(e).__name__}: {e}") from None
    if not hasattr(module, cls):
        close = difflib.get_close_matches(cls, [n for n in dir(module) if not n.startswith("_")], n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise PlantProtocolError(f"model {target!r}: module {mod!r} has no {cls!r}{hint}")
    return getattr(module, cls)


def check_plant(plant) -> Plant:
    """Return ``plant`` if it satisfies the :class:`Plant` protocol (and its optional parts are
    consistent), else raise :class:`PlantProtocolError` naming what is missing or wrong."""
    missing = [a for a in REQUIRED if not hasattr(plant, a)]
    if missing:
        raise PlantProtocolError(f"plant {type(plant).__name__} lacks {', '.join(missing)} "
                                 f"(see docs/plant-protocol.md)")
    uncallable = [a for a in REQUIRED[-4:] if not callable(getattr(plant, a))]
    if uncallable:
        raise PlantProtocolError(f"plant {type(plant).__name__}: {', '.join(uncallable)} must be methods")
    t = getattr(plant, "time", "continuous")
    if t not in ("continuous", "discrete"):
        raise PlantProtocolError(f"plant.time must be 'continuous' or 'discrete', got {t!r}")
    if t == "discrete" and not hasattr(plant, "dt"):
        raise PlantProtocolError("a discrete-time plant needs a dt attribute")
    every = [n for k in KINDS + ("p",) for n in names(plant, k)]
    nounit = [n for n in every if n not in plant.units]
    if nounit:
        raise PlantProtocolError(f"plant.units has no entry for {', '.join(nounit)}")
    if getattr(plant, "correction", None) is not None and not hasattr(plant, "theta_delta"):
        raise PlantProtocolError("a plant with a correction needs theta_delta(env)")
    nounit = [c for c in _log_channel_names(plant) if c not in plant.units]
    if nounit:
        raise PlantProtocolError(f"plant.units has no entry for the log channel(s) {', '.join(nounit)}")
    _check_ranges(plant)
    return plant


def _check_ranges(plant) -> None:
    """``plant.ranges`` (optional): channel -> (lo, hi) numbers, lo < hi, for channels with a unit."""
    for c, r in (getattr(plant, "ranges", None) or {}).items():
        try:
            lo, hi = (float(v) for v in r)
        except (TypeError, ValueError):
            raise PlantProtocolError(f"plant.ranges[{c!r}] = {r!r}: expected (lo, hi) numbers") from None
        if not lo < hi:
            raise PlantProtocolError(f"plant.ranges[{c!r}] = {r!r}: lo must be below hi")
        if c not in plant.units:
            raise PlantProtocolError(f"plant.ranges names {c!r}, which has no entry in plant.units")


def names(plant, kind: str) -> list[str]:
    return list(getattr(plant, f"{kind}_names"))


def h_ref(plant) -> np.ndarray:
    h = getattr(plant, "h_ref", None)
    return np.zeros(len(plant.h_names)) if h is None else np.asarray(h, dtype=np.float64).copy()


def perturbation_sizes(plant, values: np.ndarray, kind: str, overrides: dict | None = None) -> np.ndarray:
    """Absolute perturbation per channel: relative size x max(|value|, 1) for x and u; absolute
    for health (fractions). Sizes come from ``overrides`` (spec), then ``plant.perturbation``,
    then 1e-3."""
    table = dict(getattr(plant, "perturbation", None) or {})
    table.update(overrides or {})
    out = np.empty(len(values))
    for j, n in enumerate(names(plant, kind)):
        rel = float(table.get(n, 1e-3))
        out[j] = rel if kind == "h" else rel * max(abs(float(values[j])), 1.0)
    return out


def correction_exponents(plant) -> dict[str, np.ndarray] | None:
    """kind -> (n, 2) exponents (a, b) for x, u, y, z, or None when the plant has no correction."""
    corr = getattr(plant, "correction", None)
    if corr is None:
        return None
    ex = corr.get("exponents", {})
    return {k: np.array([ex.get(n, (0.0, 0.0)) for n in names(plant, k)], dtype=np.float64).reshape(-1, 2)
            for k in ("x", "u", "y", "z")}


def correction_factors(plant, env) -> dict[str, np.ndarray]:
    """kind -> (n,) factors theta^a delta^b at ambient ``env`` (ones without a correction)."""
    ex = correction_exponents(plant)
    if ex is None:
        return {k: np.ones(len(names(plant, k))) for k in ("x", "u", "y", "z")}
    theta, delta = plant.theta_delta(env)
    return {k: theta ** e[:, 0] * delta ** e[:, 1] for k, e in ex.items()}


#: the most a trim's state may move in one step of the database's dt, relative to its value (the
#: plant's evaluate at the trim's states and inputs), and the most evaluate's outputs may differ
#: from the trim's: a trim solved to a solver's tolerance moves its states by ~1e-9 a step
STEADY_TOLERANCE = 1e-4


def check_steady(plant, t: dict, h: np.ndarray, env: np.ndarray, dt: float) -> None:
    """A ValueError naming the channel when the trim ``t`` ({"x", "u", "y", "z"}) is not the
    plant's steady state: ``plant.evaluate`` at its states and inputs moves a state by more than
    :data:`STEADY_TOLERANCE` of its value in a step of ``dt`` s (continuous: dx/dt dt; discrete:
    x[k+1] - x), or gives outputs that differ from the trim's by more than that (a trim solver
    that stopped early, outputs in another order than evaluate's). A user's plant whose trim
    returned its input 5 % high built a database that read a clean engine 21 % off."""
    x, u = (np.asarray(t[k], dtype=np.float64).reshape(-1) for k in "xu")
    f, y, z = plant.evaluate(x, u, h, env)
    f = np.asarray(f, dtype=np.float64).reshape(-1)
    move = f - x if getattr(plant, "time", "continuous") == "discrete" else f * dt

    def worst(k, d, ref):
        """(name, unit, index, share) of the kind-k channel whose difference d is the largest
        share of its value ref, None when every one is within STEADY_TOLERANCE."""
        rel = np.abs(d) / np.maximum(np.abs(ref), 1e-9)
        if not rel.size or rel.max() <= STEADY_TOLERANCE:
            return None
        i = int(np.argmax(rel))
        return names(plant, k)[i], plant.units.get(names(plant, k)[i], ""), i, rel[i]

    if (w := worst("x", move, x)) is not None:
        n, unit, i, rel = w
        raise ValueError(f"not a steady state: state {n!r} (trim value {x[i]:.6g} {unit}) moves {move[i]:.4g} {unit} "
                         f"in a step of {dt:g} s by the plant's evaluate ({rel:.2g} of its value; at most "
                         f"{STEADY_TOLERANCE:g})")
    for k, v in (("y", y), ("z", z)):
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        ref = np.asarray(t[k], dtype=np.float64).reshape(-1)
        if v.shape != ref.shape:
            raise ValueError(f"the plant's evaluate gives {v.size} {k} values at the trim, the trim {ref.size}")
        if (w := worst(k, v - ref, ref)) is not None:
            n, unit, i, rel = w
            raise ValueError(f"not a steady state: output {n!r} is {ref[i]:.6g} {unit} in the trim, {v[i]:.6g} {unit} "
                             f"by the plant's evaluate at the trim's states and inputs ({rel:.2g} of its value; at "
                             f"most {STEADY_TOLERANCE:g}): a trim that stopped early, outputs in another order?")


def schedule(plant) -> list[tuple[str, bool, float]]:
    """How the runtime computes each scheduling variable from a log: (channel, corrected, scale)."""
    s = getattr(plant, "schedule", None) or {}
    return [tuple(s.get(p, (p, False, 1.0))) for p in plant.p_names]


def _log_channel_names(plant) -> list[str]:
    """The log channels the runtime filter reads, once each: inputs, sensed outputs, schedule
    channels, then the correction's theta and delta channels."""
    chans = names(plant, "u") + names(plant, "y") + [c for c, _, _ in schedule(plant)]
    corr = getattr(plant, "correction", None)
    if corr is not None:
        chans += [corr["theta"], corr["delta"]]
    return list(dict.fromkeys(chans))


def health_ranges(plant) -> dict[str, list[float]]:
    """Health parameter -> [lo, hi] plausible range, from ``plant.ranges`` (health names only);
    what a gain database stores as attrs["health_ranges"] (estimates outside are flagged)."""
    ranges = getattr(plant, "ranges", None) or {}
    return {h: [float(ranges[h][0]), float(ranges[h][1])] for h in plant.h_names if h in ranges}


def log_channels(plant) -> dict[str, tuple[str, float, float]]:
    """Every log channel the runtime filter reads -> (unit, lo, hi): the plant's unit and its
    plausible range from ``plant.ranges`` ((-inf, inf) where the plant declares none); what a
    gain database stores as ``log_channels``."""
    ranges = getattr(plant, "ranges", None) or {}
    out = {}
    for c in _log_channel_names(plant):
        lo, hi = ranges.get(c, (-math.inf, math.inf))
        out[c] = (plant.units[c], float(lo), float(hi))
    return out


def ambient_offset_index(plant, env) -> int | None:
    """Index of the ambient temperature offset (dTamb, K) in the plant's environment vector
    ``env``: the position of "dTamb" in the plant's optional ``env_names``, else the Plant
    protocol's turbofan layout [alt, Mach, dTamb] when the plant's units name "dTamb" and env
    has three entries; None when the plant has no such entry (no hot or cold days)."""
    names = getattr(plant, "env_names", None)
    if names is not None:
        return list(names).index("dTamb") if "dTamb" in names else None
    if "dTamb" in getattr(plant, "units", {}) and len(env) == 3:
        return 2
    return None


def day_environment(plant, p, dT: float = 0.0) -> np.ndarray:
    """The plant's environment at scheduling point ``p`` with the ambient temperature ``dT`` K
    off its standard day (0: ``plant.environment(p)`` itself); a :class:`PlantProtocolError`
    when the environment has no ambient offset (dTamb) and dT is not 0."""
    env = np.array(plant.environment(p), dtype=np.float64)
    if dT == 0.0:
        return env
    i = ambient_offset_index(plant, env)
    if i is None:
        raise PlantProtocolError(f"plant {getattr(plant, 'name', type(plant).__name__)}: its environment "
                                 "has no ambient temperature offset (dTamb), so no hot or cold day")
    env[i] += dT
    return env


def ambient_axes(plant) -> tuple[int, int] | None:
    """(index of "alt", index of "Mach") among the plant's scheduling variables when its trims can
    be moved to the day's ambient at run time: an environment with an ambient temperature offset
    (:func:`ambient_offset_index`), a parameter correction (theta from the inlet temperature) and
    the pressure altitude (m) and flight Mach number among the scheduling variables; else None."""
    p = list(plant.p_names)
    if getattr(plant, "correction", None) is None or "alt" not in p or "Mach" not in p:
        return None
    probe = np.zeros(len(p))
    if ambient_offset_index(plant, plant.environment(probe)) is None:
        return None
    return p.index("alt"), p.index("Mach")
