"""Test doubles for the build tests, importable by a build running in another process (a spec
names them as ``slow_plant:Class``): the linear example plant slowed down and counting its trims
(module-level counter), and one that raises its own exceptions at chosen points."""
import time

import numpy as np

from models.linear import DEFAULT, LinearPlant

CALLS = {"trim": 0}
#: levels at which every FailingPlant's trims fail too (a plant bug that is fixed later)
BROKEN_LEVELS = set()


class SlowPlant(LinearPlant):
    def __init__(self, delay=0.05):
        super().__init__()
        self.delay = delay

    def parameters(self):
        return {"delay": self.delay}

    def trim(self, p, h, env, guess=None):
        CALLS["trim"] += 1
        time.sleep(self.delay)
        return super().trim(p, h, env, guess)


class MapError(Exception):
    """A plant's own exception that cannot be rebuilt from its pickle (two required arguments),
    as many are: it cannot come back from a worker process as itself."""

    def __init__(self, level, power):
        super().__init__(f"no steady state at level {level:g}, power {power:g}")


class FailingPlant(LinearPlant):
    """Trims raise :class:`MapError` at ``trim_points`` ([level, power] pairs) and at the levels
    of :data:`BROKEN_LEVELS`; ``evaluate`` raises KeyError for a non-zero health at
    ``jacobian_levels`` (so the health columns of the Jacobians fail in both directions)."""

    def __init__(self, trim_points=(), jacobian_levels=()):
        super().__init__()
        self.trim_points = [tuple(map(float, p)) for p in trim_points]
        self.jacobian_levels = [float(v) for v in jacobian_levels]

    def parameters(self):
        return {"trim_points": self.trim_points, "jacobian_levels": self.jacobian_levels}

    def trim(self, p, h, env, guess=None):
        level, power = map(float, p)
        if (level, power) in self.trim_points or level in BROKEN_LEVELS:
            raise MapError(level, power)
        return super().trim(p, h, env, guess)

    def evaluate(self, x, u, h, env):
        if float(env[0]) in self.jacobian_levels and np.any(np.asarray(h) != 0):
            raise KeyError("health map missing")
        return super().evaluate(x, u, h, env)


class UnsteadyPlant(LinearPlant):
    """Its trims at ``unsteady_points`` ([level, power] pairs) return the input 5 % high (a trim
    solver that stopped early), with the outputs evaluate gives there; ``swap_y`` returns the
    trim's outputs in another order than evaluate's, ``short_y`` one output short."""

    def __init__(self, unsteady_points=(), swap_y=False, short_y=False):
        super().__init__()
        self.unsteady_points = [tuple(map(float, p)) for p in unsteady_points]
        self.swap_y, self.short_y = bool(swap_y), bool(short_y)

    def parameters(self):
        return {"unsteady_points": self.unsteady_points, "swap_y": self.swap_y, "short_y": self.short_y}

    def trim(self, p, h, env, guess=None):
        t = super().trim(p, h, env, guess)
        if tuple(map(float, p)) in self.unsteady_points:
            t["u"] = t["u"] * 1.05
            _, t["y"], t["z"] = self.evaluate(t["x"], t["u"], h, env)
        if self.swap_y:
            t["y"] = t["y"][::-1].copy()
        if self.short_y:
            t["y"] = t["y"][:-1]
        return t


class TwoSensorPlant(LinearPlant):
    """The linear example plant with its first two sensors only."""
    y_names = ("y1", "y2")
    sensor_noise = {"y1": 0.002, "y2": 0.002}

    def __init__(self):
        super().__init__(C=DEFAULT["C"][:2], D=DEFAULT["D"][:2], M=DEFAULT["M"][:2], y0=DEFAULT["y0"][:2])
