"""pwl: piecewise-linear self-tuning engine models (online runtime).

Imports numpy, numba and h5py only; never ``linearize`` or ``models``.
"""
__version__ = "0.1.0"

from .grid import Axis, Grid  # noqa: F401
from .interp import interpolate  # noqa: F401
