"""The gain database: one schema, one writer, one reader (format ``pwl-gain-database``).

The schema is documented in docs/database-format.md and defined here once, in :func:`schema`:
every dataset with its dtype kind and its shape in terms of the system sizes. ``save`` writes
exactly that list; ``open`` checks exactly that list and names the file and dataset of the first
thing that is wrong.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass, field

import h5py
import numpy as np

from . import __version__
from .grid import POLICIES, Axis, AxisError, Grid, check_breakpoints
from .errors import PwlError
from .formats import GAIN_DATABASE, check, stamp
from .h5io import SealError, atomic_h5, attr_str, check_seal, file_digest, read_strings, write_strings
from .tables import read_tables, write_tables
from .zones import read_zones, write_zones

FORMAT = GAIN_DATABASE.name
VERSION = GAIN_DATABASE.version   # 2: the file is sealed (pwl.h5io); version 1 files (unsealed) are still read
KINDS = ("x", "u", "y", "z", "h", "q", "p")
MATRICES = ("A", "B", "C", "D", "F", "G", "L", "M", "N")

# status codes
COMPUTED, FILLED, EXTRAPOLATED = 0, 1, 2   # /trim/status
REPLACED = 1                               # /dynamics/status, /kalman/status (donor index recorded)
OUT_NONE = 2                               # /kalman/out_status: no gain without that sensor


class DatabaseError(PwlError, ValueError):
    """A gain database that cannot be used. The message names the file and the dataset."""


class NotHDF5Error(DatabaseError):
    pass


class ForeignFormatError(DatabaseError):
    pass


class VersionError(DatabaseError):
    pass


class MissingDataError(DatabaseError):
    pass


class ShapeError(DatabaseError):
    pass


class BadAxisError(DatabaseError):
    pass


class CorruptError(DatabaseError):
    """The file does not match its seal, or HDF5 cannot read it: corrupted or truncated."""


class NonFiniteError(DatabaseError):
    pass


class UnstableGainError(DatabaseError):
    pass


@dataclass
class Correction:
    """Parameter correction v_c = v / (theta**a * delta**b), theta = T_in/T_std, delta = P_in/P_std.

    ``exponents`` maps kind (x, u, y, z) -> float64 (n, 2) array of (a, b) per channel.
    """

    theta_channel: str
    delta_channel: str
    exponents: dict[str, np.ndarray]
    T_std: float = 288.15
    P_std: float = 101325.0


#: the runtime holds the day's ambient offset within this many times the span its trims were built
#: over (quadratic beyond the span, held beyond the reach, named in a warning)
AMBIENT_REACH = 2.0


@dataclass
class Ambient:
    """The trims' change with the day's ambient temperature at a fixed corrected operating point:

        trim(p, dT) = trim(p) + c1(p) dT + c2(p) dT^2          (corrected units)

    with dT (K) the day's offset from the standard atmosphere, which the runtime computes from the
    correction's theta channel (the inlet's total temperature) and the scheduling variables
    ``alt`` (pressure altitude, m) and ``mach`` (:func:`pwl.airdata.ambient_offset`), held within
    +-AMBIENT_REACH * span. ``coef`` maps kind (x, u, y, z) -> trim grid shape + (2, n): [c1 per K,
    c2 per K^2], through the plant's trims at ISA -span, 0, +span (``span`` K). ``recovery``: the
    plant's inlet total-pressure recovery, the inlet pressure over the full ram rise of pressure
    altitude and Mach (:func:`pwl.airdata.inlet_pressure`), median over the trim grid's nodes
    (NaN: not known): a log without the inlet pressure takes it from altitude and Mach with it."""

    coef: dict[str, np.ndarray]
    span: float
    alt: str = "alt"
    mach: str = "Mach"
    recovery: float = float("nan")

    def inlet_pressure(self, alt_m, mach):
        """The inlet total pressure (Pa) at pressure altitude ``alt_m`` (m) and Mach ``mach``
        (arrays) with the plant's :attr:`recovery` (NaN when not known)."""
        from .airdata import inlet_pressure
        return self.recovery * inlet_pressure(np.asarray(alt_m, dtype=np.float64), np.asarray(mach, dtype=np.float64))


@dataclass
class GainDatabase:
    """A gain database in memory (written by ``pwl build`` / :mod:`linearize`; read with
    :meth:`open`, written with :meth:`save`; format in docs/database-format.md).

    Fields, with their shapes (T = trim grid shape, D = dynamics grid shape, na = nx + nq
    augmented states):

    - ``names``/``units``: kind (x u y z h q p) -> list of str
    - ``schedule``: per p: (log channel, corrected, scale): p = scale * channel (corrected first)
    - ``trim``: x, u, y, z -> T + (n,); ``trim_status`` int8 T (0 computed, 1 filled, 2 extrapolated)
    - ``ambient``: optional (builds since 0.7) :class:`Ambient`: the trims on hot and cold days,
      ``/trim/ambient_<kind>`` T + (2, n)
    - ``dynamics``: A..N discrete-time (dt seconds) -> D + (rows, cols); ``dyn_status`` int8 D
      (0 computed, 1 replaced), ``dyn_donor`` int64 D (flat index of the donor node, -1 none)
    - ``tuner``: V (nq, nh), V_pinv (nh, nq), h_ref (nh,)
    - ``kalman``: K D + (na, ny) update gain, P D + (na, na) a-priori covariance, and the
      covariances used, Q D + (na, na), R D + (ny, ny) (noise scales with the operating point);
      ``kalman_status``/``kalman_donor`` as for dynamics; optional (builds since #15) sensor-out
      gains K_out (ny,) + D + (na, ny), K_out[j] the gain without sensor j (column j zero), and
      out_status int8 (ny,) + D (COMPUTED, REPLACED by the nearest point's, OUT_NONE); and (builds
      since the health hold) out_h_ratio (ny,) + D + (nh,): the steady-state standard deviation
      of each health estimate without sensor j over its value with all sensors (0: OUT_NONE)
    - ``log_channels``: every log channel the filter reads (inputs, sensed outputs, schedule and
      theta/delta channels) -> (unit, lo, hi): the plant's unit and plausible range (+-inf when
      unbounded); None for databases built before it was recorded (then units come from
      ``names``/``units`` and no range is checked)
    - ``attrs``: free metadata (model, model_parameters, spec, tuner_method, tuner_metric, ...)
    - ``zones``: optional record; ``tables``: name -> record; a record is (arrays, attrs)
    """

    names: dict[str, list[str]]
    units: dict[str, list[str]]
    trim_grid: Grid
    dyn_grid: Grid
    trim: dict[str, np.ndarray]
    trim_status: np.ndarray
    dynamics: dict[str, np.ndarray]
    dyn_status: np.ndarray
    dyn_donor: np.ndarray
    tuner: dict[str, np.ndarray]
    kalman: dict[str, np.ndarray]
    kalman_status: np.ndarray
    kalman_donor: np.ndarray
    dt: float
    schedule: list[tuple[str, bool, float]] | None = None
    correction: Correction | None = None
    ambient: Ambient | None = None
    attrs: dict = field(default_factory=dict)
    zones: tuple[dict, dict] | None = None
    tables: dict[str, tuple[dict, dict]] = field(default_factory=dict)
    log_channels: dict[str, tuple[str, float, float]] | None = None
    path: str = "<memory>"
    digest: str = ""   # sha256 of the file it was read from ("" in memory): its identity
    sealed: bool = False   # read from a sealed file (pwl.h5io)
    format_version: int = VERSION

    # ---- sizes -------------------------------------------------------------------------------
    def n(self, kind: str) -> int:
        return len(self.names[kind])

    @property
    def na(self) -> int:
        return self.n("x") + self.n("q")

    @property
    def policy(self) -> str:
        return self.trim_grid.policy

    def __post_init__(self):
        if self.schedule is None:
            self.schedule = [(p, False, 1.0) for p in self.names["p"]]
        self.validate()

    # ---- parameter correction and the operating point ------------------------------------
    def exponents_of(self, channel: str) -> np.ndarray:
        """(a, b) correction exponents of a channel (the first kind x, u, y, z naming it; zeros
        without correction or for a channel no kind names)."""
        if self.correction is not None:
            for k in "xuyz":
                if channel in self.names[k]:
                    return self.correction.exponents[k][self.names[k].index(channel)]
        return np.zeros(2)

    def correction_factor(self, channels, theta, delta) -> np.ndarray:
        """theta**a * delta**b per channel: theta, delta (n,) -> (n, len(channels)); a raw value
        divided by it is the corrected value the database's trims and matrices use."""
        th = np.asarray(theta, dtype=np.float64).reshape(-1, 1)
        de = np.asarray(delta, dtype=np.float64).reshape(-1, 1)
        ex = np.array([self.exponents_of(c) for c in channels]).reshape(-1, 2)
        return th ** ex[:, 0] * de ** ex[:, 1]

    def channel_units(self) -> dict[str, str]:
        """Log channel -> the unit the runtime reads it in: inputs, outputs and scheduling
        channels taken as they are (their database units), then ``log_channels``' (the inlet's
        T2, P2, ...)."""
        units = {n: u for k in "xuyz" for n, u in zip(self.names[k], self.units[k])}
        for (c, corr, scale), pu in zip(self.schedule, self.units["p"]):
            if not corr and scale == 1.0:
                units.setdefault(c, pu)
        return units | {c: u for c, (u, _, _) in (self.log_channels or {}).items()}

    def channel_ranges(self) -> dict[str, tuple[float, float]]:
        """Log channel -> its plausible (lo, hi) in :meth:`channel_units` (``log_channels``;
        channels without one are absent)."""
        return {c: (lo, hi) for c, (_, lo, hi) in (self.log_channels or {}).items()}

    def air_data(self) -> tuple | None:
        """(altitude column, Mach column, altitude's scale to m, the inlet pressure's scale to Pa)
        of the schedule channels (:func:`pwl.airdata.air_data_channels`), None without them."""
        from .airdata import air_data_channels
        return air_data_channels([c for c, _, _ in self.schedule], self.channel_units(),
                                 self.correction.delta_channel if self.correction else None)

    def inlet_from_air_data(self, S: np.ndarray) -> np.ndarray | None:
        """(n,) the inlet pressure (the delta channel, in its unit) from the schedule channels S
        (n, ns; :meth:`channel_units`) with the plant's inlet recovery (:meth:`Ambient.inlet_pressure`):
        for a log or a snapshot table without it. None when the database cannot (no air data in
        the schedule, or no recovery: built before 0.7.1)."""
        if not self.derives_inlet():
            return None
        ja, jm, ka, kp = self.air_data()
        return self.ambient.inlet_pressure(S[:, ja] * ka, S[:, jm]) / kp

    def derives_inlet(self) -> bool:
        """Whether :meth:`inlet_from_air_data` can give the inlet pressure."""
        return (self.air_data() is not None and self.ambient is not None
                and bool(np.isfinite(self.ambient.recovery)))

    def p_spans(self) -> np.ndarray:
        """(np,) span hi - lo of every scheduling variable's axis (trim grid, else dynamics grid,
        else 1): the scale of "steady" and of operating regimes."""
        ax = {a.name: a for a in self.dyn_grid.axes + self.trim_grid.axes}
        return np.array([ax[p].hi - ax[p].lo if p in ax else 1.0 for p in self.names["p"]])

    def statespace(self, p):
        """The piecewise-linear model at operating point ``p`` as a discrete python-control
        ``StateSpace`` (dt = the database's dt, seconds; needs the ``control`` package):

            x[k+1] = A x[k] + B u[k] + L h[k]        inputs  [u; h]  (nu + nh)
            [y; z][k] = [C; F] x[k] + [D M; G N] [u; h][k]           (ny + nz outputs)

        deviations from the trim at p, in corrected units, the matrices interpolated on the
        dynamics grid exactly as the runtime does. ``p``: scheduling variables in
        ``names["p"]`` order, a sequence or a dict name -> value (variables the dynamics grid
        does not have are ignored: its matrices are held there; attrs["dynamics_hold"]).
        Signal names follow the database's names.

        Parameters
        ----------
        p : sequence of float (np,) or dict
            The operating point: scheduling variables in ``names["p"]`` order (their units,
            ``units["p"]``), or name -> value (at least every dynamics-grid axis).

        Returns
        -------
        control.StateSpace
            Discrete (dt s), nx states, nu + nh inputs, ny + nz outputs, named.

        Raises
        ------
        DatabaseError
            An unknown scheduling variable, a missing dynamics axis, a wrong number of values.
        ImportError
            python-control is not installed.
        """
        import control

        from .interp import interpolate

        names = self.names["p"]
        if isinstance(p, dict):
            unknown = set(p) - set(names)
            if unknown:
                raise DatabaseError(f"{self.path}: unknown scheduling variables {sorted(unknown)} "
                                    f"(the database has {names})")
            missing = [a.name for a in self.dyn_grid.axes if a.name not in p]
            if missing:
                raise DatabaseError(f"{self.path}: the operating point needs {missing}")
            pd = [float(p[a.name]) for a in self.dyn_grid.axes]
        else:
            p = np.asarray(p, dtype=np.float64).reshape(-1)
            if p.size != len(names):
                raise DatabaseError(f"{self.path}: the operating point has {p.size} values for "
                                    f"{len(names)} scheduling variables {names}")
            pd = [p[names.index(a.name)] for a in self.dyn_grid.axes]
        m = {k: interpolate(self.dyn_grid, self.dynamics[k], np.array(pd))[0] for k in MATRICES}
        return control.ss(m["A"], np.hstack([m["B"], m["L"]]), np.vstack([m["C"], m["F"]]),
                          np.block([[m["D"], m["M"]], [m["G"], m["N"]]]), self.dt,
                          states=list(self.names["x"]), inputs=self.names["u"] + self.names["h"],
                          outputs=self.names["y"] + self.names["z"])

    def operating_point(self, S, theta, delta) -> np.ndarray:
        """The scheduling variables, from raw log channels, as the runtime computes them:
        p = scale * channel, divided by the channel's correction factor theta^a delta^b where
        the schedule says ``corrected``.

        Parameters
        ----------
        S : array_like (n, np)
            The raw schedule channels, ``[c for c, _, _ in schedule]`` order, log units.
        theta, delta : array_like (n,)
            The inlet ratios T_in / T_std and P_in / P_std (dimensionless).

        Returns
        -------
        ndarray (n, np)
            Scheduling variables in ``names["p"]`` order, ``units["p"]``.
        """
        S = np.atleast_2d(np.asarray(S, dtype=np.float64))
        fac = self.correction_factor([c for c, _, _ in self.schedule], theta, delta)
        corr = np.array([bool(c) for _, c, _ in self.schedule])
        scale = np.array([float(s) for _, _, s in self.schedule])
        return S * scale / np.where(corr, fac, 1.0)

    def ambient_offset(self, p, theta, hold: bool = True) -> np.ndarray:
        """The day's ambient offset dT (n,) in K that the trims are moved by at operating points
        ``p`` (n, np) with inlet temperature ratio ``theta`` (n,), as the runtime computes it
        (held at +-AMBIENT_REACH * span unless ``hold`` is False); zeros without an ambient record."""
        p = np.atleast_2d(np.asarray(p, dtype=np.float64))
        if self.ambient is None:
            return np.zeros(p.shape[0])
        from .airdata import ambient_offset

        a, names = self.ambient, self.names["p"]
        dT = ambient_offset(np.asarray(theta, dtype=np.float64) * self.correction.T_std,
                            p[:, names.index(a.alt)], p[:, names.index(a.mach)])
        reach = AMBIENT_REACH * a.span
        return np.clip(dT, -reach, reach) if hold else dT

    def trims_at(self, p, theta=1.0) -> dict[str, np.ndarray]:
        """Trims x, u, y, z (n, n_kind), corrected units, at operating points ``p`` (n, np) on the
        day of inlet temperature ratio ``theta`` (n,) (the ambient record's change with the day;
        the interpolation and out-of-range policy of the runtime)."""
        from .interp import interpolate

        p = np.atleast_2d(np.asarray(p, dtype=np.float64))
        names = self.names["p"]
        pt = p[:, [names.index(a) for a in self.trim_grid.names]]
        out = {k: interpolate(self.trim_grid, self.trim[k], pt) for k in "xuyz"}
        if self.ambient is not None:
            dT = self.ambient_offset(p, np.broadcast_to(theta, (p.shape[0],)))[:, None]
            for k in "xuyz":
                c = interpolate(self.trim_grid, self.ambient.coef[k], pt)
                out[k] = out[k] + dT * (c[:, 0] + dT * c[:, 1])
        return out

    # ---- the schema --------------------------------------------------------------------------
    def schema(self):
        """(path, dtype kind, shape) of every dataset, from the sizes. The one schema definition."""
        nx, nu, ny, nz, nh, nq = (self.n(k) for k in "xuyzhq")
        na = nx + nq
        T, D = self.trim_grid.shape, self.dyn_grid.shape
        mats = {"A": (nx, nx), "B": (nx, nu), "C": (ny, nx), "D": (ny, nu), "F": (nz, nx),
                "G": (nz, nu), "L": (nx, nh), "M": (ny, nh), "N": (nz, nh)}
        out = [(f"trim/{k}", "f", T + (self.n(k),)) for k in "xuyz"]
        out.append(("trim/status", "i1", T))
        if self.ambient is not None:
            out += [(f"trim/ambient_{k}", "f", T + (2, self.n(k))) for k in "xuyz"]
        out += [(f"dynamics/{k}", "f", D + s) for k, s in mats.items()]
        out += [("dynamics/status", "i1", D), ("dynamics/donor", "i8", D)]
        out += [("tuner/V", "f", (nq, nh)), ("tuner/V_pinv", "f", (nh, nq)), ("tuner/h_ref", "f", (nh,))]
        out += [("kalman/K", "f", D + (na, ny)), ("kalman/P", "f", D + (na, na)),
                ("kalman/Q", "f", D + (na, na)), ("kalman/R", "f", D + (ny, ny)),
                ("kalman/status", "i1", D), ("kalman/donor", "i8", D)]
        if "K_out" in self.kalman:
            out += [("kalman/K_out", "f", (ny,) + D + (na, ny)), ("kalman/out_status", "i1", (ny,) + D)]
        if "out_h_ratio" in self.kalman:
            out += [("kalman/out_h_ratio", "f", (ny,) + D + (nh,))]
        if self.correction is not None:
            out += [(f"correction/{k}", "f", (self.n(k), 2)) for k in "xuyz"]
        return out

    def _get(self, path: str) -> np.ndarray:
        grp, name = path.split("/")
        if grp == "trim":
            if name.startswith("ambient_"):
                return self.ambient.coef[name[len("ambient_"):]]
            return self.trim_status if name == "status" else self.trim[name]
        if grp == "dynamics":
            extra = {"status": self.dyn_status, "donor": self.dyn_donor}
            return extra[name] if name in extra else self.dynamics[name]
        if grp == "kalman":
            extra = {"status": self.kalman_status, "donor": self.kalman_donor}
            return extra[name] if name in extra else self.kalman[name]
        if grp == "tuner":
            return self.tuner[name]
        if grp == "correction":
            return self.correction.exponents[name]
        raise KeyError(path)

    def validate(self) -> None:
        """Check names, grids and every dataset's presence, dtype kind and shape."""
        where = self.path
        for k in KINDS:
            if k not in self.names or k not in self.units:
                raise MissingDataError(f"{where}: /names/{k} or /units/{k} is missing")
            if len(self.units[k]) != len(self.names[k]):
                raise ShapeError(f"{where}: /units/{k} has {len(self.units[k])} entries, "
                                 f"/names/{k} has {len(self.names[k])}")
        for g, label in ((self.trim_grid, "trim"), (self.dyn_grid, "dynamics")):
            missing = [a.name for a in g.axes if a.name not in self.names["p"]]
            if missing:
                raise BadAxisError(f"{where}: /{label}/axes {missing} are not scheduling variables "
                                   f"{self.names['p']}")
        if len(self.schedule) != self.n("p"):
            raise ShapeError(f"{where}: schedule has {len(self.schedule)} entries for "
                             f"{self.n('p')} scheduling variables")
        for path, kind, shape in self.schema():
            try:
                a = self._get(path)
            except KeyError:
                raise MissingDataError(f"{where}: dataset /{path} is missing") from None
            a = np.asarray(a)
            if a.shape != shape:
                raise ShapeError(f"{where}: dataset /{path} has shape {a.shape}, expected {shape}")
            if kind == "f" and a.dtype != np.float64:
                raise ShapeError(f"{where}: dataset /{path} has dtype {a.dtype}, expected float64")
            if kind != "f" and a.dtype.kind != "i":
                raise ShapeError(f"{where}: dataset /{path} has dtype {a.dtype}, expected integer")
            if kind == "f" and not np.all(np.isfinite(a)):
                bad = np.argwhere(~np.isfinite(a))
                raise NonFiniteError(f"{where}: dataset /{path} has {len(bad)} non-finite values "
                                     f"(first at index {tuple(int(i) for i in bad[0])}: {a[tuple(bad[0])]})")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise DatabaseError(f"{where}: /dynamics attribute dt = {self.dt} is not a positive number")
        scale = np.array([float(v) for _, _, v in self.schedule])
        if not np.all(np.isfinite(scale) & (scale != 0)):
            raise DatabaseError(f"{where}: /schedule/scale {scale.tolist()} must be finite and non-zero")
        for k in KINDS:
            names = self.names[k]
            if any(not isinstance(n, str) or not n.strip() for n in names) or len(set(names)) != len(names):
                raise DatabaseError(f"{where}: /names/{k} {names} must be distinct, non-empty names")
        channels = [c for c, _, _ in self.schedule]
        if self.correction is not None:
            c = self.correction
            if not all(np.isfinite(v) and v > 0 for v in (c.T_std, c.P_std)):
                raise DatabaseError(f"{where}: /correction T_std, P_std must be positive numbers")
            channels += [c.theta_channel, c.delta_channel]
            if c.theta_channel == c.delta_channel:
                raise DatabaseError(f"{where}: /correction theta and delta channels are both {c.theta_channel!r}")
        if self.ambient is not None:
            a = self.ambient
            if self.correction is None or a.alt not in self.names["p"] or a.mach not in self.names["p"]:
                raise DatabaseError(f"{where}: /trim/ambient_* need a parameter correction and the scheduling "
                                    f"variables {a.alt!r} and {a.mach!r} (have {self.names['p']})")
            if not (np.isfinite(a.span) and a.span > 0):
                raise DatabaseError(f"{where}: /trim attribute ambient_span = {a.span} must be a positive number")
            if not (np.isnan(a.recovery) or 0.5 < a.recovery <= 1.1):
                raise DatabaseError(f"{where}: /trim attribute ambient_recovery = {a.recovery} must be in (0.5, 1.1]")
        for c in channels:
            if not isinstance(c, str) or not c.strip() or (self.log_channels is not None
                                                             and c not in self.log_channels):
                raise DatabaseError(f"{where}: log channel {c!r} of /schedule or /correction is not "
                                    f"a declared log channel")
        for c, (unit, lo, hi) in (self.log_channels or {}).items():
            if np.isnan(lo) or np.isnan(hi) or lo > hi:
                raise DatabaseError(f"{where}: /log_channels range of {c!r} is [{lo}, {hi}]")
        self.check_gains()

    def gain_radius(self, K=None) -> np.ndarray:
        """Spectral radius of the error dynamics (I - K C_a) A_a of the augmented system at every
        dynamics node: D-shaped array, < 1 where the gain is stable. K: D + (na, ny), default the
        stored /kalman/K."""
        from .runtime import augment   # runtime imports this module

        aug = augment(self.dynamics, self.tuner["V_pinv"])
        K = self.kalman["K"] if K is None else K
        closed = (np.eye(self.na) - K @ aug["C"]) @ aug["A"]
        return np.abs(np.linalg.eigvals(closed.reshape((-1,) + closed.shape[-2:]))).max(axis=-1) \
            .reshape(self.dyn_grid.shape)

    def settling_time(self, taus: float = 3.0) -> float:
        """``taus`` time constants (s) of the slowest error dynamics over the dynamics grid (the
        stored gains, :meth:`gain_radius`): how long after its start the filter's estimates are
        still converging from the initial tuners (e^-3 = 5 % of the initial error left at 3).
        Demo database: time constants 3.0-9.1 s, 27 s at 3."""
        rho = float(np.max(self.gain_radius()))
        return taus * self.dt / -np.log(rho) if 0.0 < rho < 1.0 else 0.0

    def check_gains(self) -> None:
        """Every stored gain gives strictly stable error dynamics (the builder's own check, redone
        at every open: a gain changed after the build is refused, naming the node)."""
        sets = [("/kalman/K", self.kalman["K"], None)]
        if "K_out" in self.kalman:
            st = self.kalman["out_status"]
            if not np.isin(st, (COMPUTED, REPLACED, OUT_NONE)).all():
                raise DatabaseError(f"{self.path}: /kalman/out_status holds values other than "
                                    f"{COMPUTED}, {REPLACED}, {OUT_NONE}")
            for j, name in enumerate(self.names["y"]):
                Kj = self.kalman["K_out"][j]
                if np.any(Kj[..., j] != 0.0):
                    raise DatabaseError(f"{self.path}: /kalman/K_out[{j}] (without {name}) uses {name}")
                sets.append((f"/kalman/K_out[{j}] (without {name})", Kj, st[j] != OUT_NONE))
            ratio = self.kalman.get("out_h_ratio")
            if ratio is not None and not np.all(ratio >= 0.0):
                raise DatabaseError(f"{self.path}: /kalman/out_h_ratio holds negative values")
        for label, K, used in sets:
            rho = np.nan_to_num(self.gain_radius(K), nan=np.inf)
            bad = (rho >= 1.0) & (True if used is None else used)
            if bad.any():
                i = np.unravel_index(int(np.argmax(np.where(bad, rho, -1.0))), rho.shape)
                at = ", ".join(f"{a.name} = {a.values[j]:g}" for a, j in zip(self.dyn_grid.axes, i))
                raise UnstableGainError(f"{self.path}: {label} gives unstable error dynamics at "
                                        f"{int(np.sum(bad))} nodes (worst at {at}: spectral radius "
                                        f"{rho[i]:.6g})")

    # ---- writing -----------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write the database to a file (format ``pwl-gain-database``, :mod:`pwl.formats`),
        atomically: a temporary file in the same folder, sealed, renamed onto ``path`` when
        complete; a crash leaves any previous file untouched.

        Parameters
        ----------
        path : str or path-like
            The database file (folders created).

        Raises
        ------
        DatabaseError
            The database in memory is inconsistent (:meth:`validate`: names, grids, every
            dataset's presence, dtype and shape), naming what is wrong.
        """
        self.validate()
        self.attrs.setdefault("created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
        with atomic_h5(path) as f:
            stamp(f, GAIN_DATABASE)
            f.attrs["created"] = self.attrs["created"]
            f.attrs["software_version"] = __version__
            f.attrs["out_of_range"] = self.policy
            f.attrs["attrs_json"] = json.dumps(self.attrs, sort_keys=True)
            for k in KINDS:
                write_strings(f.require_group("names"), k, self.names[k])
                write_strings(f.require_group("units"), k, self.units[k])
            s = f.create_group("schedule")
            write_strings(s, "channel", [c for c, _, _ in self.schedule])
            s.create_dataset("corrected", data=np.array([bool(c) for _, c, _ in self.schedule]))
            s.create_dataset("scale", data=np.array([float(v) for _, _, v in self.schedule]))
            for grid, grp in ((self.trim_grid, "trim"), (self.dyn_grid, "dynamics")):
                ax = f.require_group(grp).create_group("axes")
                write_strings(ax, "order", grid.names)
                for a in grid.axes:
                    d = ax.create_dataset(a.name, data=a.values)
                    d.attrs["unit"] = a.unit
            f["dynamics"].attrs["dt"] = float(self.dt)
            f["dynamics"].attrs["method"] = self.attrs.get("discretization", "zoh")
            f.require_group("kalman").attrs["form"] = "update"
            if self.ambient is not None:
                f["trim"].attrs.update({"ambient_span": float(self.ambient.span), "ambient_alt": self.ambient.alt,
                                        "ambient_mach": self.ambient.mach})
                if np.isfinite(self.ambient.recovery):
                    f["trim"].attrs["ambient_recovery"] = float(self.ambient.recovery)
            if self.correction is not None:
                c = f.require_group("correction")
                c.attrs.update({"theta_channel": self.correction.theta_channel,
                                "delta_channel": self.correction.delta_channel,
                                "T_std": self.correction.T_std, "P_std": self.correction.P_std})
            for path_, kind, _ in self.schema():
                a = np.asarray(self._get(path_))
                f.create_dataset(path_, data=a.astype({"f": np.float64, "i1": np.int8, "i8": np.int64}[kind]))
            if self.log_channels is not None:
                g = f.create_group("log_channels")
                write_strings(g, "name", list(self.log_channels))
                write_strings(g, "unit", [u for u, _, _ in self.log_channels.values()])
                g.create_dataset("range", data=np.array([[lo, hi] for _, lo, hi in self.log_channels.values()],
                                                        dtype=np.float64).reshape(-1, 2))
            if self.zones is not None:
                write_zones(f, self.zones)
            write_tables(f, self.tables)
        self.sealed, self.format_version = True, VERSION    # as written (its summary says so)

    # ---- reading -----------------------------------------------------------------------------
    @classmethod
    def open(cls, path) -> "GainDatabase":
        """Read and validate a gain database.

        Checks the seal, the format and version (:func:`pwl.formats.check`), every dataset of
        the schema (presence, shape, dtype, finite values), the axes, and that every stored gain
        gives stable error dynamics.

        Parameters
        ----------
        path : str or path-like
            A ``pwl-gain-database`` file, version 1 or 2.

        Returns
        -------
        GainDatabase
            With ``path``, ``digest`` (sha256 hex of the sealed content) and ``sealed`` set.

        Raises
        ------
        DatabaseError
            A subclass naming the file and what is wrong: ``CorruptError`` (seal, damaged HDF5),
            ``NotHDF5Error``, ``ForeignFormatError`` (another format), ``VersionError`` (newer,
            missing or invalid version), ``MissingDataError``, ``ShapeError``,
            ``NonFiniteError``, ``UnstableGainError``, ``BadAxisError``.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise DatabaseError(f"{path}: no such file")
        if os.path.isdir(path):
            raise DatabaseError(f"{path}: is a folder, not a gain database file")
        try:
            digest = check_seal(path)
        except SealError as e:
            raise CorruptError(str(e)) from None
        if not h5py.is_hdf5(path):
            raise NotHDF5Error(f"{path}: not an HDF5 file")
        try:
            db = cls._open(path, sealed=digest is not None)
        except DatabaseError:
            raise
        except (OSError, ValueError, TypeError, KeyError, IndexError, AttributeError,
                OverflowError, RuntimeError) as e:  # what HDF5/h5py/numpy raise on damaged content
            # (not everything: a bug of pwl's own must stay a bug, not read as a damaged file)
            raise CorruptError(f"{path}: damaged file, cannot be read ({type(e).__name__}: "
                               f"{' '.join(str(e).split())})") from None
        db.digest = digest or file_digest(path)
        db.sealed = digest is not None
        return db

    @classmethod
    def _open(cls, path, sealed: bool):
        f = h5py.File(path, "r")
        with f:
            _, ver = check(GAIN_DATABASE, path, f, error=ForeignFormatError, version_error=VersionError)
            if ver >= 2 and not sealed:
                raise CorruptError(f"{path}: format version {ver} files are sealed, this one's seal "
                                   f"is missing (corrupted user block, or edited outside pwl)")
            try:
                return cls._read(f, path)
            except KeyError as e:
                raise MissingDataError(f"{path}: {e.args[0] if e.args else 'a dataset'} is missing") from None

    @classmethod
    def _read(cls, f, path):
        def need(p):
            if p not in f:
                raise MissingDataError(f"{path}: dataset /{p} is missing")
            return f[p]

        names = {k: read_strings(need(f"names/{k}")) for k in KINDS}
        units = {k: read_strings(need(f"units/{k}")) for k in KINDS}
        policy = attr_str(f, "out_of_range", "clip")
        if policy not in POLICIES:
            raise DatabaseError(f"{path}: attribute out_of_range = {policy!r} is not one of {POLICIES}")
        grids = {}
        for grp in ("trim", "dynamics"):
            order = read_strings(need(f"{grp}/axes/order"))
            axes = []
            for name in order:
                d = need(f"{grp}/axes/{name}")
                v = np.asarray(d[()], dtype=np.float64)
                try:
                    check_breakpoints(v, f"/{grp}/axes/{name}")
                except AxisError as e:
                    raise BadAxisError(f"{path}: {e}") from None
                axes.append(Axis(name, v, attr_str(d, "unit", "")))
            grids[grp] = Grid(axes, policy)
        s = need("schedule")
        schedule = list(zip(read_strings(need("schedule/channel")),
                            [bool(b) for b in s["corrected"][()]], [float(v) for v in s["scale"][()]]))
        correction = None
        if "correction" in f:
            c = f["correction"]
            correction = Correction(attr_str(c, "theta_channel"), attr_str(c, "delta_channel"),
                                    {k: need(f"correction/{k}")[()] for k in "xuyz"},
                                    float(c.attrs["T_std"]), float(c.attrs["P_std"]))
        dyn = need("dynamics")
        db = cls.__new__(cls)
        db.names, db.units, db.schedule, db.correction = names, units, schedule, correction
        db.trim_grid, db.dyn_grid, db.path, db.digest, db.sealed = grids["trim"], grids["dynamics"], path, "", False
        db.dt = float(dyn.attrs.get("dt", np.nan))
        db.attrs = json.loads(attr_str(f, "attrs_json", "{}"))
        db.attrs.setdefault("created", attr_str(f, "created", ""))
        db.format_version = int(f.attrs.get("format_version", VERSION))
        db.trim = {k: need(f"trim/{k}")[()] for k in "xuyz"}
        db.trim_status = need("trim/status")[()]
        db.ambient = None
        if "trim/ambient_x" in f:
            t = f["trim"]
            db.ambient = Ambient({k: need(f"trim/ambient_{k}")[()] for k in "xuyz"},
                                 float(t.attrs.get("ambient_span", np.nan)), attr_str(t, "ambient_alt", "alt"),
                                 attr_str(t, "ambient_mach", "Mach"), float(t.attrs.get("ambient_recovery", np.nan)))
        db.dynamics = {k: need(f"dynamics/{k}")[()] for k in MATRICES}
        db.dyn_status, db.dyn_donor = need("dynamics/status")[()], need("dynamics/donor")[()]
        db.tuner = {k: need(f"tuner/{k}")[()] for k in ("V", "V_pinv", "h_ref")}
        db.kalman = {k: need(f"kalman/{k}")[()] for k in ("K", "P", "Q", "R")}
        if "kalman/K_out" in f:
            db.kalman |= {k: need(f"kalman/{k}")[()] for k in ("K_out", "out_status")}
        if "kalman/out_h_ratio" in f:
            db.kalman["out_h_ratio"] = need("kalman/out_h_ratio")[()]
        db.kalman_status, db.kalman_donor = need("kalman/status")[()], need("kalman/donor")[()]
        db.log_channels = None
        if "log_channels" in f:
            rng = np.asarray(need("log_channels/range")[()], dtype=np.float64).reshape(-1, 2)
            cn, cu = read_strings(need("log_channels/name")), read_strings(need("log_channels/unit"))
            if not len(cn) == len(cu) == len(rng):
                raise ShapeError(f"{path}: /log_channels name, unit and range differ in length")
            db.log_channels = {n: (u, float(lo), float(hi)) for n, u, (lo, hi) in zip(cn, cu, rng)}
        db.zones = read_zones(f)
        db.tables = read_tables(f)
        db.validate()
        return db

    # ---- summary -----------------------------------------------------------------------------
    def summary(self) -> str:
        """A readable multi-line summary (what ``pwl info`` prints)."""
        lines = [f"gain database {self.path}",
                 f"  format {FORMAT} v{self.format_version}{'' if self.sealed else ' (unsealed)'}, "
                 f"model {self.attrs.get('model', '?')}, "
                 f"created {self.attrs.get('created', '?')}, dt = {self.dt:g} s, "
                 f"out-of-range policy {self.policy}"]
        if os.path.exists(self.path):
            lines[0] += f" ({os.path.getsize(self.path) / 1e6:.2f} MB)"
        hold = self.attrs.get("dynamics_hold") or {}
        for label, g in (("trim grid", self.trim_grid), ("dynamics grid", self.dyn_grid)):
            held = (", at " + ", ".join(f"{k} = {v:g}" for k, v in hold.items())) if g is self.dyn_grid and hold else ""
            lines.append(f"  {label}: {' x '.join(map(str, g.shape))} = {g.size} points{held}")
            for a in g.axes:
                lines.append(f"    {a.name:<8} [{a.unit}] {a.lo:g} .. {a.hi:g} ({len(a)})")
        for k, title in zip(KINDS, ("states", "inputs", "sensed outputs", "unmeasured outputs",
                                    "health parameters", "tuners", "scheduling")):
            items = ", ".join(f"{n} [{u}]" if u else n for n, u in zip(self.names[k], self.units[k]))
            lines.append(f"  {k} ({title}, {self.n(k)}): {items}")
        ts = np.bincount(self.trim_status.reshape(-1).astype(np.int64), minlength=3)
        lines.append(f"  trim status: {ts[0]} computed, {ts[1]} filled, {ts[2]} extrapolated")
        lines.append(f"  dynamics: {int((self.dyn_status == 0).sum())} computed, "
                     f"{int((self.dyn_status != 0).sum())} replaced by nearest")
        lines.append(f"  kalman gains: {int((self.kalman_status == 0).sum())} computed, "
                     f"{int((self.kalman_status != 0).sum())} replaced by nearest; settling time "
                     f"{self.settling_time():.3g} s (3 time constants of the slowest error dynamics)")
        if "K_out" in self.kalman:
            none = [n for j, n in enumerate(self.names["y"]) if (self.kalman["out_status"][j] == OUT_NONE).all()]
            lines.append(f"  sensor-out gains: for {self.n('y') - len(none)} of {self.n('y')} sensors"
                         + (f" (none without {', '.join(none)})" if none else ""))
        lines.append(f"  tuner: {self.attrs.get('tuner_method', '?')}, metric "
                     f"{self.attrs.get('tuner_metric', float('nan')):.4g}")
        if self.correction is not None:
            lines.append(f"  parameter correction: theta = {self.correction.theta_channel}/"
                         f"{self.correction.T_std:g}, delta = {self.correction.delta_channel}/"
                         f"{self.correction.P_std:g}")
        if self.ambient is not None:
            lines.append(f"  hot and cold days: trims quadratic in the ISA offset (built at -+{self.ambient.span:g} K, "
                         f"held beyond -+{AMBIENT_REACH * self.ambient.span:g} K)")
        if self.zones is not None:
            lines.append(f"  gain zones: {self.zones[1].get('k', '?')}")
        if self.tables:
            lines.append(f"  adaptive tables: {', '.join(self.tables)}")
        if self.log_channels:
            lines.append("  log channels (unit, plausible range; values outside are flagged and held):")
            for c, (u, lo, hi) in self.log_channels.items():
                lines.append(f"    {c:<8} [{u}] {lo:g} .. {hi:g}")
        if self.digest:
            lines.append(f"  sha256 {self.digest}")
        return "\n".join(lines)

