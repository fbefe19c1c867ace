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
    ambient_span = 30.0       # K: trims also at ISA -+ this, for the trims' change on hot and cold
                              # days (a plant with dTamb, alt and Mach; 0: none; docs/building.md)

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

import numbers
import tomllib
from dataclasses import dataclass, field

import numpy as np

from pwl.errors import PwlError
from pwl.grid import POLICIES, Axis, AxisError, Grid


class SpecError(PwlError, ValueError):
    """A build spec that cannot be used; names the file and the key."""


@dataclass
class BuildSpec:
    """How to build a gain database (``pwl build SPEC``, :func:`linearize.build.build`): the
    parsed TOML of the module docstring. Made with :meth:`load` (a file) or :meth:`parse` (text);
    the text is stored in the database it builds (``attrs["spec"]``).

    Parameters
    ----------
    plant : str
        The plant class, ``"package.module:Class"`` ([model] plant).
    parameters : dict
        Keyword arguments of the plant class ([model] parameters).
    trim_grid, dyn_grid : Grid
        The trim and dynamics grids over scheduling variables ([trim_grid], [dynamics_grid]:
        name = breakpoints, in the plant's units), with the out-of-range policy.
    power_axis : str
        The trim-grid axis along which trims are warm-started and failed trims filled.
    dt : float
        Runtime sample time, s (zero-order hold).
    differences : {"central", "forward"}
        Perturbation differences of the Jacobians.
    perturbation : dict
        Name -> relative perturbation size (overrides the plant's).
    health_reference : dict
        Health parameter -> reference value h_ref (fraction; overrides the plant's).
    dynamics_hold : dict
        Scheduling variables left out of the dynamics grid -> the value they are linearized at.
    ambient_span : float
        K: the trim grid is also trimmed at ISA -+ ambient_span, and the database stores the trims'
        change with the day's ambient (quadratic in the offset; :class:`pwl.database.Ambient`),
        for a plant whose environment has dTamb and whose scheduling has alt and Mach; 0: not.
    q_x, q_h : float or dict
        Process noise, one sigma per step: states (fraction of the trim value) and health random
        walk (fraction); a number, or name -> number with ``default``.
    r : dict
        Sensor -> noise one sigma (fraction of the value; default: the plant's).
    tuner_method : {"subset", "optimal"}
        How the tuners V* are chosen.
    n_tuners : int
        Number of tuners (<= number of sensors).
    targets : list of str
        What the tuners should estimate well: ``"h"`` (all health parameters), health or
        unmeasured-output names.
    health_sigma : float or dict
        Prior one-sigma of the true health (fraction), for the tuner selection.
    text : str
        The spec's TOML text.
    path : str
        Its file (named in errors).
    """

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
    ambient_span: float = 30.0
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
        """Read and check a build spec file.

        Parameters
        ----------
        path : str or path-like
            A UTF-8 TOML file (module docstring; ``specs/*.toml``).

        Returns
        -------
        BuildSpec

        Raises
        ------
        SpecError
            Not UTF-8 or not TOML, an unknown section or key, a missing [model] plant, a value
            of the wrong type, bad breakpoints, a non-positive dt; naming the file and the key.
        OSError
            The file cannot be read (FileNotFoundError when it does not exist).
        """
        with open(path, "rb") as fh:
            raw = fh.read()
        try:
            text = raw.decode()
        except UnicodeDecodeError as e:
            raise SpecError(f"{path}: not UTF-8 text ({e})") from None
        return cls.parse(text, str(path))

    @classmethod
    def parse(cls, text: str, path: str = "<string>") -> "BuildSpec":
        """The spec of TOML ``text`` (as :meth:`load`; ``path`` names it in :class:`SpecError`)."""
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise SpecError(f"{path}: not valid TOML ({e})") from None
        known = {"model": {"plant", "parameters"}, "build": {"power_axis", "dt", "differences", "out_of_range",
                                                           "perturbation", "health_reference", "dynamics_hold",
                                                           "ambient_span"},
                 "kalman": {"q_x", "q_h", "r"}, "tuners": {"method", "n", "targets", "health_sigma"}}
        extra = set(d) - set(known) - {"trim_grid", "dynamics_grid"}
        if extra:
            raise SpecError(f"{path}: unknown section(s) {sorted(extra)}")
        model, build, kal, tun = (_Table(d, name, path, keys) for name, keys in known.items())
        if "plant" not in model:
            raise SpecError(f"{path}: [model] plant = 'package.module:Class' is missing")
        policy = build.string("out_of_range", "clip", POLICIES)
        tg, dg = _grid(d, "trim_grid", path, policy), _grid(d, "dynamics_grid", path, policy)
        power = build.string("power_axis", tg.names[-1], tg.names)
        dt = build.number("dt", 0.015)
        if not dt > 0:
            raise SpecError(f"{path}: [build] dt = {dt} must be positive")
        span = build.number("ambient_span", 30.0)
        if not (0.0 <= span <= 100.0):
            raise SpecError(f"{path}: [build] ambient_span = {span} K must be in 0..100 (0: no ambient trims)")
        if not tun.strings("targets", ["h"]):
            raise SpecError(f"{path}: [tuners] targets is empty: name what the tuners should estimate "
                            '("h" for every health parameter, or health and unmeasured-output names)')
        return cls(plant=model.string("plant", None), parameters=model.table("parameters"), trim_grid=tg,
                   dyn_grid=dg, power_axis=power, dt=dt,
                   differences=build.string("differences", "central", ("central", "forward")),
                   perturbation=build.numbers("perturbation"), health_reference=build.numbers("health_reference"),
                   dynamics_hold=build.numbers("dynamics_hold"), ambient_span=span,
                   q_x=kal.number_or_numbers("q_x", 1e-3), q_h=kal.number_or_numbers("q_h", 1e-4),
                   r=kal.numbers("r"), tuner_method=tun.string("method", "subset", ("subset", "optimal")),
                   n_tuners=tun.integer("n", 4),
                   targets=tun.strings("targets", ["h"]),
                   health_sigma=tun.number_or_numbers("health_sigma", 0.02), text=text, path=path)


def is_number(v) -> bool:
    """True for a real number (booleans are not numbers here)."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


class _Table:
    """One section of a spec, with typed getters that name the file, section and key when a value
    has the wrong type."""

    def __init__(self, doc: dict, name: str, path: str, keys: set):
        self.name, self.path = name, path
        t = doc.get(name, {})
        if not isinstance(t, dict):
            raise SpecError(f"{path}: [{name}] must be a table")
        extra = set(t) - keys
        if extra:
            raise SpecError(f"{path}: unknown key(s) {sorted(extra)} in [{name}] (known: {sorted(keys)})")
        self.t = t

    def __contains__(self, key):
        return key in self.t

    def _wrong(self, key, expected):
        return SpecError(f"{self.path}: [{self.name}] {key} = {self.t[key]!r}: expected {expected}")

    def number(self, key, default) -> float:
        v = self.t.get(key, default)
        if not is_number(v):
            raise self._wrong(key, "a number")
        return float(v)

    def integer(self, key, default) -> int:
        v = self.t.get(key, default)
        if not (is_number(v) and float(v).is_integer()):
            raise self._wrong(key, "an integer")
        return int(v)

    def string(self, key, default, choices=None) -> str:
        v = self.t.get(key, default)
        if not isinstance(v, str):
            raise self._wrong(key, "a string")
        if choices is not None and v not in choices:
            raise self._wrong(key, f"one of {list(choices)}")
        return v

    def strings(self, key, default) -> list:
        """A list of strings (a single string is a list of one)."""
        v = self.t.get(key, default)
        if isinstance(v, str):
            return [v]
        if not (isinstance(v, list) and all(isinstance(s, str) for s in v)):
            raise self._wrong(key, "a string or a list of strings")
        return list(v)

    def table(self, key) -> dict:
        v = self.t.get(key, {})
        if not isinstance(v, dict):
            raise self._wrong(key, "a table {name = value, ...}")
        return dict(v)

    def numbers(self, key) -> dict:
        """A table of numbers (name -> float)."""
        v = self.table(key)
        if not all(is_number(x) for x in v.values()):
            raise self._wrong(key, "a table of numbers {name = number, ...}")
        return {k: float(x) for k, x in v.items()}

    def number_or_numbers(self, key, default):
        """A number, or a table of numbers {name = number, default = number}."""
        v = self.t.get(key, default)
        if isinstance(v, dict):
            return self.numbers(key)
        if not is_number(v):
            raise self._wrong(key, "a number or a table {name = number, default = number}")
        return float(v)


def _grid(doc: dict, name: str, path: str, policy: str) -> Grid:
    """The grid of section ``name``: one axis per key, each a list of numbers."""
    axes = doc.get(name)
    if axes is None:
        raise SpecError(f"{path}: section [{name}] is missing")
    if not isinstance(axes, dict) or not axes:
        raise SpecError(f"{path}: [{name}] must be a table of axes (name = [breakpoints])")
    out = []
    for k, v in axes.items():
        if not (isinstance(v, list) and all(is_number(x) for x in v)):
            raise SpecError(f"{path}: [{name}] {k} = {v!r}: expected a list of numbers (breakpoints)")
        try:
            out.append(Axis(k, np.asarray(v, dtype=np.float64)))
        except AxisError as e:
            raise SpecError(f"{path}: [{name}]: {e}") from None
    return Grid(out, policy)


def per_channel(value, names, what: str, where: str, positive: bool = False) -> np.ndarray:
    """A scalar or a name -> value table as an array over ``names`` (names the unknown key).
    Every value is a standard deviation: finite and >= 0 (> 0 with ``positive``), else a
    :class:`SpecError` naming it (a negative sigma is a sign mistake its square would hide)."""
    out = _per_channel(value, names, what, where)
    bad = ~np.isfinite(out) | (out <= 0 if positive else out < 0)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise SpecError(f"{where}: {what} for {names[j]!r} is {float(out[j])!r}: a standard deviation, it must be "
                        f"finite and {'> 0' if positive else '>= 0'}")
    return out


def _per_channel(value, names, what: str, where: str) -> np.ndarray:
    values = value.values() if isinstance(value, dict) else [value]
    if not all(is_number(v) for v in values):
        raise SpecError(f"{where}: {what} = {value!r}: expected a number or a table of numbers")
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
