"""Gain zones, online form: the ``/zones`` record of a gain database as a :class:`ZoneTable`.

A :class:`ZoneTable` is the online form of the ``/zones`` record of a gain database (built offline
by :mod:`linearize.zones`, seed paper 001): k centroid gains and a lookup grid over the
scheduling box whose nodes carry a zone label. The runtime (``Estimator(db, "zones")``,
:meth:`pwl.runtime.PackedModel.from_database`) reads the centroid gains and the node labels of
zones built on the database's dynamics grid.

The lookup of a point's zone (:meth:`ZoneTable.zone_of`; the scheduled-gain EKF of
:mod:`experiments.ekf` uses the same kernels) is the nearest node: on a uniform grid (what
:mod:`linearize.zones` builds) by index arithmetic, i = round((v - lo) / step), O(1) with no
search; on any other grid (zones of a database's dynamics grid) by :func:`pwl.grid.locate`, the
project's one index search (O(1) with the previous step's index as hint, binary search
otherwise), rounded to the nearer breakpoint. One table read gives the zone. Points outside the
box are clipped to its edge (counted).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .errors import PwlError
from . import formats
from .formats import GAIN_DATABASE, ZONES_FILE, ZONES_RECORD, check, open_checked, stamp
from .grid import Axis, AxisError, Grid, locate
from .h5io import atomic_h5


class ZoneError(PwlError, ValueError):
    """A zones record that cannot be used (names what is wrong)."""


# ---- zone lookup --------------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def nearest_node(bp, off, strides, point, idx, frac):
    """Flat index of the grid node nearest to ``point`` (per axis: the closer breakpoint of the
    bracketing cell; clipped outside). idx (hint in/out) and frac are work arrays as for
    :func:`pwl.grid.locate`. Returns (node, outside flags)."""
    flags = locate(bp, off, point, False, idx, frac)
    r = 0
    for j in range(point.shape[0]):
        i = idx[j]
        if frac[j] >= 0.5:
            i += 1
        r += i * strides[j]
    return r, flags


@njit(cache=True, nogil=True, inline="always")
def nearest_node_uniform(lo, inv_h, nmax, strides, point):
    """:func:`nearest_node` for a uniform grid (axis j: lo[j] + i / inv_h[j], i = 0..nmax[j]) by
    index arithmetic, no search: i = round((x - lo) inv_h), clipped. Returns (node, flags)."""
    r = 0
    flags = 0
    for j in range(point.shape[0]):
        t = (point[j] - lo[j]) * inv_h[j]
        if t < 0.0:
            i = 0
            flags |= 1 << j
        elif t > nmax[j]:
            i = nmax[j]
            flags |= 1 << j
        else:
            i = int(t + 0.5)
        r += i * strides[j]
    return r, flags


@njit(cache=True, nogil=True, inline="always")
def zone_node(uniform, lo, inv_h, nmax, bp, off, strides, point, idx, frac):
    """Lookup node of ``point``: :func:`nearest_node_uniform` when ``uniform``, else
    :func:`nearest_node` (the arguments of both; see :meth:`ZoneTable.kernel_args`)."""
    if uniform:
        return nearest_node_uniform(lo, inv_h, nmax, strides, point)
    return nearest_node(bp, off, strides, point, idx, frac)


@njit(cache=True, nogil=True)
def zone_many(uniform, lo, inv_h, nmax, bp, off, strides, labels, points, out):
    """Zone label of every row of ``points`` (k, d) into ``out`` (k,) int64; returns how many
    points lay outside the lookup box (clipped)."""
    d = points.shape[1]
    idx = np.zeros(d, dtype=np.int64)
    frac = np.zeros(d, dtype=np.float64)
    outside = 0
    for i in range(points.shape[0]):
        r, fl = zone_node(uniform, lo, inv_h, nmax, bp, off, strides, points[i], idx, frac)
        out[i] = labels[r]
        if fl != 0:
            outside += 1
    return outside


@dataclass
class ZoneTable:
    """Online zones: centroid gains and the lookup grid with a zone label per node.

    ``gains`` (k, n, m) update gains; ``grid`` a :class:`pwl.grid.Grid` over the scheduling
    coordinates ``grid.names`` (for operating-point zones: the input names, then the state names);
    ``labels`` int64 of shape ``grid.shape`` with values in 0..k-1; ``centers`` (k, n*m) the
    centroids in normalised gain space (gain / ``scale``, element-wise, flattened row-major);
    ``attrs`` the record's metadata (JSON-able).
    """

    gains: np.ndarray
    grid: Grid
    labels: np.ndarray
    centers: np.ndarray
    scale: np.ndarray
    counts: np.ndarray
    attrs: dict = field(default_factory=dict)

    def __post_init__(self):
        self.gains = np.ascontiguousarray(self.gains, dtype=np.float64)
        self.labels = np.ascontiguousarray(self.labels, dtype=np.int64)
        self.centers = np.asarray(self.centers, dtype=np.float64)
        self.scale = np.asarray(self.scale, dtype=np.float64)
        self.counts = np.asarray(self.counts, dtype=np.int64)
        self.validate()

    @property
    def k(self) -> int:
        return self.gains.shape[0]

    @property
    def flat_labels(self) -> np.ndarray:
        return self.labels.reshape(-1)

    def validate(self, where: str = "zones") -> None:
        k = self.gains.shape[0]
        if self.gains.ndim != 3 or k < 1:
            raise ZoneError(f"{where}: gains must have shape (k, n, m), got {self.gains.shape}")
        nm = self.gains.shape[1] * self.gains.shape[2]
        if self.centers.shape != (k, nm):
            raise ZoneError(f"{where}: centers has shape {self.centers.shape}, expected {(k, nm)}")
        if self.scale.shape != (nm,) or not np.all(self.scale > 0):
            raise ZoneError(f"{where}: scale must be positive with shape {(nm,)}, got {self.scale}")
        if self.counts.shape != (k,):
            raise ZoneError(f"{where}: counts has shape {self.counts.shape}, expected {(k,)}")
        if self.labels.shape != self.grid.shape:
            raise ZoneError(f"{where}: lookup labels have shape {self.labels.shape}, "
                            f"grid is {self.grid.shape}")
        if self.labels.size and (self.labels.min() < 0 or self.labels.max() >= k):
            raise ZoneError(f"{where}: lookup labels outside 0..{k - 1}")
        if not np.all(np.isfinite(self.gains)):
            raise ZoneError(f"{where}: non-finite centroid gains")

    def zone_of(self, points) -> np.ndarray:
        """Zone labels (int64) at points (d,) or (k, d) in the grid's coordinates."""
        pts = np.ascontiguousarray(np.atleast_2d(points), dtype=np.float64)
        if pts.shape[1] != self.grid.ndim:
            raise ValueError(f"points need {self.grid.ndim} columns {self.grid.names}, "
                             f"got shape {pts.shape}")
        out = np.empty(pts.shape[0], dtype=np.int64)
        zone_many(*self.kernel_args(), pts, out)
        return out

    def kernel_args(self, force_search: bool = False):
        """(uniform, lo, inv_h, nmax, bp, off, strides, labels) for the kernels. ``uniform`` is
        True when every lookup axis is equally spaced (to 1e-12 of its span) and not
        ``force_search``: the lookup is then index arithmetic instead of the grid search."""
        g = self.grid
        lo = np.array([a.lo for a in g.axes])
        span = np.array([a.hi - a.lo for a in g.axes])
        nmax = np.array([len(a) - 1 for a in g.axes], dtype=np.int64)
        uniform = not force_search and all(
            np.abs(a.values - np.linspace(a.lo, a.hi, len(a))).max() <= 1e-12 * (a.hi - a.lo)
            for a in g.axes)
        return (uniform, lo, nmax / span, nmax, g.bp, g.off, g.strides, self.flat_labels)

    # ---- the /zones record of a gain database -------------------------------------------------
    def record(self) -> tuple[dict, dict]:
        """(arrays, attrs), the ``/zones`` record (``GainDatabase.zones``; written by :func:`write_zones`)."""
        lab_dtype = np.int8 if self.k <= 127 else np.int16 if self.k <= 32767 else np.int64
        arrays = {"centers": self.centers, "gains": self.gains, "scale": self.scale,
                  "counts": self.counts, "lookup_bp": self.grid.bp, "lookup_off": self.grid.off,
                  "lookup_labels": self.labels.astype(lab_dtype)}
        attrs = dict(self.attrs)
        stamp(attrs, ZONES_RECORD)
        attrs.update(k=int(self.k), gain_form="update", lookup_names=list(self.grid.names),
                     lookup_units=[a.unit for a in self.grid.axes])
        return arrays, attrs

    @classmethod
    def from_record(cls, record, where: str = "/zones") -> "ZoneTable":
        """Check and unpack a record read by :func:`read_zones`."""
        if record is None:
            raise ZoneError(f"{where}: the database has no zones record (make a zoned copy with "
                            "'pwl zones --database DB --out ZONED.h5' and run ZONED.h5 with --mode zones)")
        arrays, attrs = record
        check(ZONES_RECORD, where, attrs, error=ZoneError, hint="build zones with linearize.zones")
        need = ("centers", "gains", "scale", "counts", "lookup_bp", "lookup_off", "lookup_labels")
        missing = [n for n in need if n not in arrays]
        if missing:
            raise ZoneError(f"{where}: datasets {missing} are missing")
        names = list(attrs.get("lookup_names", []))
        units = list(attrs.get("lookup_units", [""] * len(names)))
        bp = np.asarray(arrays["lookup_bp"], dtype=np.float64)
        off = np.asarray(arrays["lookup_off"], dtype=np.int64)
        if off.shape != (len(names) + 1,) or off[0] != 0 or off[-1] != bp.size:
            raise ZoneError(f"{where}: lookup_off {off} does not match {len(names)} axes "
                            f"and {bp.size} breakpoints")
        try:
            grid = Grid([Axis(nm, bp[off[j]:off[j + 1]], un)
                         for j, (nm, un) in enumerate(zip(names, units))])
        except AxisError as e:
            raise ZoneError(f"{where}: lookup grid: {e}") from None
        extra = {k: v for k, v in attrs.items()
                 if k not in ("format", "format_version", "k", "gain_form", "lookup_names",
                              "lookup_units")}
        return cls(gains=arrays["gains"], grid=grid, labels=arrays["lookup_labels"],
                   centers=arrays["centers"], scale=arrays["scale"], counts=arrays["counts"],
                   attrs=extra)

    def nbytes(self) -> int:
        """Bytes of the stored record's arrays (what the zones add to a database)."""
        return int(sum(np.asarray(v).nbytes for v in self.record()[0].values()))


# ---- the one writer and reader of zones: a database's /zones group, a stand-alone zones file -------
def write_zones(f, record) -> None:
    """Write the record ``(arrays, attrs)`` (:meth:`ZoneTable.record`) as the ``/zones`` group of
    the open HDF5 file ``f`` (a gain database being written, or a zones file)."""
    formats.write_record(f.create_group("zones"), *record)


def read_zones(f):
    """The ``/zones`` record ``(arrays, attrs)`` of the open HDF5 file ``f``; None without one."""
    return formats.read_record(f["zones"]) if "zones" in f else None


def save_zones(path, table: ZoneTable) -> None:
    """A stand-alone zones file (format ``pwl-zones-file``): one ``/zones`` group laid out as
    inside a gain database; atomic."""
    with atomic_h5(path) as f:
        stamp(f, ZONES_FILE)
        write_zones(f, table.record())


def load_zones(path) -> ZoneTable:
    """The zones of a gain database or of a stand-alone zones file (:func:`save_zones`).

    Raises
    ------
    ZoneError
        Not a gain database or zones file (naming the file, the format found and the formats
        read), no ``/zones`` group, or a record that cannot be used.
    """
    path = os.fspath(path)
    with open_checked(path, (GAIN_DATABASE, ZONES_FILE), ZoneError) as f:
        if "zones" not in f:
            raise ZoneError(f"{path}: no /zones group")
        record = read_zones(f)
    return ZoneTable.from_record(record, where=f"{path}:/zones")
