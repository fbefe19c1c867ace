"""The build spec: a TOML file that says how to build a gain database (stored inside it).

Example (every key but ``model.plant``, ``trim_grid`` and ``dynamics_grid`` has a default)::

    [model]
    plant = "models.turbofan:Turbofan"     # import path "package.module:Class"
    parameters = {}                         # keyword arguments of the class

    [trim_grid]                             # axes in grid order: name = breakpoints
    alt = [0, 3000, 6000, 9000, 12000]
    Mach = [0, 0.2, 0.4, 0.6, 0.85]
    NfR = [60, 65, 70, 75, 80, 85, 90, 95, 100]

    [dynamics_grid]
    alt = [0, 6000, 12000]
    Mach = [0, 0.4, 0.85]
    NfR = [60, 70, 80, 90, 100]

    [build]
    power_axis = "NfR"        # trims are warm-started and failed trims filled along this axis
    dt = 0.015                # runtime sample time, s (zero-order hold)
    differences = "central"   # or "forward"
    out_of_range = "clip"     # clip | extrapolate | error
    perturbation = {}         # name -> relative size (overrides the plant's)
    health_reference = {}     # name -> value (overrides the plant's h_ref)
    dynamics_hold = {}        # scheduling variables left out of [dynamics_grid] -> value they are
                              # linearized at (default: the middle of the trim grid's axis)

    [kalman]
    q_x = 1e-3                # state process noise, one sigma per step, fraction of the trim value
    q_h = 1e-4                # health random walk, one sigma per step (fraction), tuners: V Qh V^T
    r = {}                    # sensor noise, one sigma, fraction of the value (default: the plant's)

    [tuners]
    method = "subset"         # subset | optimal
    n = 4                     # number of tuners (<= number of sensors)
    targets = ["h"]           # "h" (all health parameters), health or unmeasured-output names
    health_sigma = 0.02       # prior one-sigma of the true health, for the covariance analysis
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field

import numpy as np

from pwl.errors import PwlError
from pwl.grid import POLICIES, Axis, AxisError, Grid


class SpecError(PwlError, ValueError):
    """A build spec that cannot be used; names the file and the key."""


@dataclass
class BuildSpec:
    plant: str
    parameters: dict
    trim_grid: Grid
    dyn_grid: Grid
    power_axis: str
    dt: float = 0.015
    differences: str = "central"
    perturbation: dict = field(default_factory=dict)
    health_reference: dict = field(default_factory=dict)
    dynamics_hold: dict = field(default_factory=dict)
    q_x: float | dict = 1e-3
    q_h: float | dict = 1e-4
    r: dict = field(default_factory=dict)
    tuner_method: str = "subset"
    n_tuners: int = 4
    targets: list = field(default_factory=lambda: ["h"])
    health_sigma: float | dict = 0.02
    text: str = ""
    path: str = "<string>"

    @classmethod
    def load(cls, path) -> "BuildSpec":
        with open(path, "rb") as fh:
            text = fh.read().decode()
        return cls.parse(text, str(path))

    @classmethod
    def parse(cls, text: str, path: str = "<string>") -> "BuildSpec":
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise SpecError(f"{path}: not valid TOML ({e})") from None

        def section(name, required=False):
            s = d.get(name)
            if s is None:
                if required:
                    raise SpecError(f"{path}: section [{name}] is missing")
                return {}
            if not isinstance(s, dict):
                raise SpecError(f"{path}: [{name}] must be a table")
            return s

        model, build, kal, tun = section("model", True), section("build"), section("kalman"), section("tuners")
        known = {"model": {"plant", "parameters"}, "build": {"power_axis", "dt", "differences", "out_of_range",
                                                           "perturbation", "health_reference", "dynamics_hold"},
                 "kalman": {"q_x", "q_h", "r"}, "tuners": {"method", "n", "targets", "health_sigma"}}
        for name, keys in known.items():
            extra = set(section(name)) - keys
            if extra:
                raise SpecError(f"{path}: unknown key(s) {sorted(extra)} in [{name}] (known: {sorted(keys)})")
        extra = set(d) - set(known) - {"trim_grid", "dynamics_grid"}
        if extra:
            raise SpecError(f"{path}: unknown section(s) {sorted(extra)}")
        if "plant" not in model:
            raise SpecError(f"{path}: [model] plant = 'package.module:Class' is missing")
        policy = build.get("out_of_range", "clip")
        if policy not in POLICIES:
            raise SpecError(f"{path}: [build] out_of_range = {policy!r} is not one of {POLICIES}")

        def grid(name):
            axes = section(name, True)
            if not axes:
                raise SpecError(f"{path}: [{name}] has no axes")
            try:
                return Grid([Axis(k, np.asarray(v, dtype=np.float64)) for k, v in axes.items()], policy)
            except (AxisError, ValueError, TypeError) as e:
                raise SpecError(f"{path}: [{name}]: {e}") from None

        tg, dg = grid("trim_grid"), grid("dynamics_grid")
        power = build.get("power_axis", tg.names[-1])
        if power not in tg.names:
            raise SpecError(f"{path}: [build] power_axis {power!r} is not a trim grid axis {tg.names}")
        dt = float(build.get("dt", 0.015))
        if not dt > 0:
            raise SpecError(f"{path}: [build] dt = {dt} must be positive")
        diff = build.get("differences", "central")
        if diff not in ("central", "forward"):
            raise SpecError(f"{path}: [build] differences = {diff!r} must be 'central' or 'forward'")
        method = tun.get("method", "subset")
        if method not in ("subset", "optimal"):
            raise SpecError(f"{path}: [tuners] method = {method!r} must be 'subset' or 'optimal'")
        targets = tun.get("targets", ["h"])
        if isinstance(targets, str):
            targets = [targets]
        return cls(plant=model["plant"], parameters=dict(model.get("parameters", {})), trim_grid=tg,
                   dyn_grid=dg, power_axis=power, dt=dt, differences=diff,
                   perturbation=dict(build.get("perturbation", {})),
                   health_reference=dict(build.get("health_reference", {})),
                   dynamics_hold={k: float(v) for k, v in build.get("dynamics_hold", {}).items()},
                   q_x=kal.get("q_x", 1e-3), q_h=kal.get("q_h", 1e-4), r=dict(kal.get("r", {})),
                   tuner_method=method, n_tuners=int(tun.get("n", 4)), targets=list(targets),
                   health_sigma=tun.get("health_sigma", 0.02), text=text, path=path)


def per_channel(value, names, what: str, where: str) -> np.ndarray:
    """A scalar or a name -> value table as an array over ``names`` (names the unknown key)."""
    if isinstance(value, dict):
        unknown = set(value) - set(names) - {"default"}
        if unknown:
            raise SpecError(f"{where}: {what} names unknown channel(s) {sorted(unknown)}; known: {names}")
        d = value.get("default")
        missing = [n for n in names if n not in value and d is None]
        if missing:
            raise SpecError(f"{where}: {what} has no value for {missing} (give them or a 'default')")
        return np.array([float(value.get(n, d)) for n in names])
    return np.full(len(names), float(value))
