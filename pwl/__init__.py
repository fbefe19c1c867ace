"""pwl: piecewise-linear self-tuning engine models (online runtime).

The public face, importable from ``pwl`` directly::

    from pwl import Estimator, GainDatabase, Stream, read_log, run_many

Names are loaded on first use, so ``import pwl`` stays light. pwl imports numpy, numba, h5py
(and pandas to read CSV/Parquet logs); never ``linearize`` or ``models``.
"""
__version__ = "0.8.0"

from . import kernel_cache as _kernel_cache

_kernel_cache.check()   # before any kernel loads from numba's cache: none compiled from old sources

from .grid import Axis, Grid  # noqa: F401
from .interp import interpolate  # noqa: F401

#: public name -> module that defines it
_PUBLIC = {
    "GainDatabase": "database",
    "Estimator": "estimator",
    "Result": "results",
    "Stream": "streaming",
    "Log": "logs",
    "read_log": "logs",
    "write_log": "logs",
    "ChannelMap": "channel_map",
    "run_many": "fleet.runs",
    "PwlError": "errors",
}

__all__ = ["Axis", "Grid", "interpolate", "__version__", *_PUBLIC]


def __getattr__(name):
    if name in _PUBLIC:
        import importlib

        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pwl' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
