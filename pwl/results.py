"""Estimation results: the :class:`Result` of a run and the results-file format
(``pwl-estimates``: time, flags and one (n, k) dataset per output, names, counts and provenance
as attributes, snapshots)."""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .h5io import atomic_h5, write_strings
from .logs import Log
from .runtime import (FLAG_DYN_OUTSIDE, FLAG_HEALTH, FLAG_HELD_INPUT, FLAG_IMPLAUSIBLE, FLAG_MISFIT,
                      FLAG_NO_UPDATE, FLAG_NOT_STARTED, FLAG_PARTIAL, FLAG_TRIM_OUTSIDE)
from .snapshots import Snapshots


@dataclass
class Result:
    """Estimates for one log: each output (n, k) in physical units, flags (n,) int64.

    Outputs: x_hat, q_hat, h_hat, y_hat (a priori, bias included), residual, z_hat, and
    ``bias_hat`` (the bias tables' values at the operating point) when the estimator has them,
    ``h_std`` (standard deviation of every health estimate, from the filter's covariance) when it
    is an online-covariance estimator."""

    time: np.ndarray
    outputs: dict[str, np.ndarray]
    flags: np.ndarray
    names: dict[str, list[str]]
    source: str = "<memory>"
    attrs: dict = field(default_factory=dict)
    snapshots: Snapshots | None = None

    def __getattr__(self, name):
        if name in self.__dict__.get("outputs", {}):
            return self.outputs[name]
        raise AttributeError(name)

    def channel(self, output: str, name: str) -> np.ndarray:
        """One column, e.g. ``channel("z_hat", "T40")``."""
        return self.outputs[output][:, self.names[output].index(name)]

    def counts(self) -> dict:
        f = self.flags
        return {"samples": int(f.size),
                "no_update": int(np.count_nonzero(f & FLAG_NO_UPDATE)),
                "partial": int(np.count_nonzero(f & FLAG_PARTIAL)),
                "held_input": int(np.count_nonzero(f & FLAG_HELD_INPUT)),
                "trim_outside": int(np.count_nonzero(f & FLAG_TRIM_OUTSIDE)),
                "dyn_outside": int(np.count_nonzero(f & FLAG_DYN_OUTSIDE)),
                "not_started": int(np.count_nonzero(f & FLAG_NOT_STARTED)),
                "implausible": int(np.count_nonzero(f & FLAG_IMPLAUSIBLE)),
                "misfit": int(np.count_nonzero(f & FLAG_MISFIT)),
                "health_implausible": int(np.count_nonzero(f & FLAG_HEALTH)),
                "updated": int(np.count_nonzero((f & (FLAG_NO_UPDATE | FLAG_NOT_STARTED)) == 0))}

    def save(self, path) -> None:
        """HDF5 (atomic) or, for a ``.csv`` path, CSV with ``output.name`` columns."""
        if os.fspath(path).lower().endswith(".csv"):
            cols = {"time": self.time, "flags": self.flags}
            for o in self.names:
                for j, n in enumerate(self.names[o]):
                    cols[f"{o}.{n}"] = self.outputs[o][:, j]
            from .logs import write_csv
            write_csv(path, Log(self.time, {k: v for k, v in cols.items() if k != "time"}, {}, path=str(path)))
            return
        with atomic_h5(path) as f:
            init_result_file(f, self.names, self.source, self.counts(), 0, self.attrs,
                              self.attrs.get("provenance"))
            append_rows(f, self.time, self.outputs, self.flags)
            if self.snapshots is not None:
                self.snapshots.save(f.create_group("snapshots"))


#: log attributes copied into results files (who flew what, when: the fleet's bookkeeping)
LOG_ATTRS = ("engine", "flight_index", "flight_time")


def init_result_file(f, names, source, counts, n, attrs=None, provenance=None):
    f.attrs["format"] = "pwl-estimates"
    f.attrs["format_version"] = 1
    f.attrs["source"] = str(source)
    for k, v in (attrs or {}).items():
        if k in LOG_ATTRS:
            f.attrs[k] = v
    for k, v in (provenance or {}).items():
        f.attrs[k] = v
    f.create_dataset("time", shape=(n,), maxshape=(None,), dtype="f8", chunks=(8192,))
    f.create_dataset("flags", shape=(n,), maxshape=(None,), dtype="i8", chunks=(8192,))
    for o in names:
        k = len(names[o])
        f.create_dataset(o, shape=(n, k), maxshape=(None, k), dtype="f8", chunks=(8192, max(k, 1)))
        write_strings(f.require_group("names"), o, names[o])
    for k, v in counts.items():
        f.attrs[k] = v


def append_rows(f, time, outputs, flags):
    n0 = f["time"].shape[0]
    n1 = n0 + time.size
    for name, data in [("time", time), ("flags", flags)] + list(outputs.items()):
        d = f[name]
        d.resize(n1, axis=0)
        d[n0:n1] = data
