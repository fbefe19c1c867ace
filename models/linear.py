"""A complete minimal plant: a linear time-invariant system written against the Plant protocol.

It is the example of docs/plant-protocol.md and the builder's exact test case (its Jacobians are
known). Continuous time::

    dx/dt = A (x - x0) + B (u - u0) + L h
    y     = y0 + C (x - x0) + D (u - u0) + M h
    z     = z0 + F (x - x0) + G (u - u0) + N h

Scheduling variables: ``level`` (an ambient-like variable the system ignores) and ``power``,
which sets the steady input u = u0 + power * e (e = ones). Nothing here imports pwl or linearize.
"""
from __future__ import annotations

import numpy as np

DEFAULT = {
    "A": [[-2.0, 0.5], [0.3, -1.0]], "B": [[1.0], [0.2]],
    "C": [[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]], "D": [[0.0], [0.1], [0.3]],
    "F": [[0.2, 1.0], [1.0, -0.4]], "G": [[0.5], [0.0]],
    "L": [[0.4, -0.3, 0.1], [0.0, 0.6, -0.2]], "M": [[0.0, 0.1, 0.3], [0.2, 0.0, 0.1], [0.1, 0.1, 0.0]],
    "N": [[1.0, 0.0, 0.2], [0.0, 0.5, 0.5]],
    "x0": [10.0, 20.0], "u0": [1.0], "y0": [10.0, 20.0, 15.0], "z0": [100.0, 50.0],
}


class LinearPlant:
    name = "linear-example"
    time = "continuous"
    x_names = ("x1", "x2")
    u_names = ("u1",)
    y_names = ("y1", "y2", "y3")
    z_names = ("z1", "z2")
    h_names = ("h1", "h2", "h3")
    p_names = ("level", "power")
    units = {"x1": "-", "x2": "-", "u1": "-", "y1": "-", "y2": "-", "y3": "-", "z1": "-", "z2": "-",
             "h1": "-", "h2": "-", "h3": "-", "level": "-", "power": "-"}
    sensor_noise = {"y1": 0.002, "y2": 0.002, "y3": 0.003}

    def __init__(self, **matrices):
        unknown = set(matrices) - set(DEFAULT)
        if unknown:
            raise TypeError(f"LinearPlant: unknown parameters {sorted(unknown)}")
        self._params = {k: matrices.get(k, v) for k, v in DEFAULT.items()}
        for k, v in self._params.items():
            setattr(self, k, np.array(v, dtype=np.float64))
        self.h_ref = np.zeros(self.L.shape[1])

    def parameters(self) -> dict:
        return {k: np.asarray(v).tolist() for k, v in self._params.items()}

    def environment(self, p):
        return np.array([float(p[0])])

    def evaluate(self, x, u, h, env):
        dx, du = np.asarray(x) - self.x0, np.asarray(u) - self.u0
        f = self.A @ dx + self.B @ du + self.L @ h
        y = self.y0 + self.C @ dx + self.D @ du + self.M @ h
        z = self.z0 + self.F @ dx + self.G @ du + self.N @ h
        return f, y, z

    def trim(self, p, h, env, guess=None):
        u = self.u0 + float(p[1]) * np.ones(self.B.shape[1])
        x = self.x0 - np.linalg.solve(self.A, self.B @ (u - self.u0) + self.L @ h)
        f, y, z = self.evaluate(x, u, h, env)
        return {"x": x, "u": u, "y": y, "z": z}
