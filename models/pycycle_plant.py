"""A pyCycle single-spool turbojet as a Plant (docs/plant-protocol.md, docs/pycycle.md).

pyCycle (NASA's thermodynamic cycle library on OpenMDAO, PyPI ``om-pycycle``) is an optional
dependency: ``pip install -e '.[pycycle]'`` (om-pycycle 4.4 needs NumPy < 2.4, which the extra
pins). This module imports without it; building a :class:`PyCycleTurbojet` without a working
pyCycle raises :class:`PyCycleMissing` saying how to install it (:data:`UNAVAILABLE` says why).

The engine (built here through pyCycle's public API: ``pycycle.api`` elements, ``Cycle``,
OpenMDAO ``BalanceComp`` and ``NewtonSolver``)::

    fc (flight conditions) -> inlet -> comp (AXI5 map) -> burner -> turb (LPT2269 map) -> nozz
                                       '------------- shaft (Nmech) --------------'

OpenMDAO problems, each set up once per plant object, lazily, and reused by every solve (the
object pickles without them, so process-pool workers rebuild their own; a fourth, ``ambient``,
holds the flight conditions alone for ``theta_delta``):

- ``design`` (run once in the constructor, then dropped): sea-level static ISA design point
  (inlet flow, pressure ratio, efficiencies, T4, shaft speed given; balances: fuel-air ratio ->
  T4, turbine pressure ratio -> shaft power 0). It yields the map scalars (``s_Wc, s_PR, s_eff,
  s_Nc`` of the compressor, ``s_Wp, s_PR, s_eff, s_Np`` of the turbine) and the compressor exit
  and nozzle throat areas that the off-design problems take as inputs. The health parameters
  scale those map scalars.
- ``trim`` (off-design, pyCycle's balances): inlet flow -> nozzle throat area equals its design
  area; fuel-air ratio -> corrected shaft speed ``comp.Nc`` equals ``NR`` % of its design value;
  shaft speed -> net shaft power 0. One Newton solve gives the steady state.
- ``fixed`` (off-design, the "unbalanced" evaluation): shaft speed ``Nmech`` is an input (the
  state), the fuel-air ratio balances the burner fuel flow to the input ``Wf``, the inlet flow
  balances the throat area; the net shaft power ``dP`` is what is left, and
  ``dN/dt = dP / (I omega)`` (converted to rpm/s) with the documented rotor inertia ``I``.

Channels (SI; N-CMAPSS-like station names of a single-spool turbojet)::

    x = (N,)                         shaft speed, rpm
    u = (Wf,)                        fuel flow, kg/s
    y = (N, T30, Ps30, T50, P50)     rpm, K, Pa, K, Pa (compressor exit total temperature and
                                     static pressure, turbine exit total temperature and pressure)
    z = (Fn, T40, SmComp, W2)        net thrust N, burner exit temperature K, compressor stall
                                     margin at constant speed % (pyCycle's SMN), inlet flow kg/s
    h = (comp_eff, comp_flow, turb_eff, turb_flow)
                                     fractional deltas of the compressor efficiency and flow map
                                     scalars and of the turbine efficiency and flow-parameter map
                                     scalars (-0.01 = 1 % loss), h_ref = 0
    p = (alt, Mach, NR)              m, -, corrected shaft speed % of design
    env = [alt m, Mach, dTamb K]     (dTamb: deviation from the standard day; 0 at grid points)

Corrected form: ``correction`` uses the engine-face total temperature ``T2`` and pressure ``P2``
(inlet exit, after the ram recovery) with the usual exponents, and ``schedule`` computes ``NR``
from the logged shaft speed as ``100 N / sqrt(T2 / 288.15 K) / Nc_design``.

Trims start from the ``guess`` trim's solver state (every implicit output of the problem), else
from the nearest converged trim, and fall back to natural-parameter continuation (halving steps)
from it or from the design point; ``evaluate`` starts from the last unbalanced solve, else from a
trim at the same corrected speed and continues in fuel flow and health. A solve that still fails
raises :class:`PlantError` naming the point.

``python -m models.pycycle_plant`` prints the design point.
"""
from __future__ import annotations

import contextlib
import io
import itertools
import math
import warnings

import numpy as np

try:  # optional dependency: the 'pycycle' extra
    import openmdao.api as om
    import pycycle.api as pyc
except ImportError as _e:  # pragma: no cover - exercised only without the extra
    om = pyc = None
    _IMPORT_ERROR = _e
else:
    _IMPORT_ERROR = None


def _numpy_incompatibility() -> str:
    """Why this NumPy cannot run pyCycle 4.4, or "": pyCycle's thermodynamics (CEA and tabular)
    store 1-element arrays into array elements, which NumPy 2.4 turned from a deprecation
    warning into ``ValueError: setting an array element with a sequence``."""
    a = np.zeros(2)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            a[0] += np.ones(1)
    except (ValueError, TypeError):
        return (f"pyCycle (om-pycycle 4.4) does not run with NumPy {np.__version__}: it stores 1-element "
                "arrays into array elements, an error since NumPy 2.4; install the pycycle extra, which "
                "pins numpy<2.4: pip install -e '.[pycycle]'")
    return ""


#: why pyCycle cannot run here ("" when it can): missing, or a NumPy it does not support
UNAVAILABLE = (f"models.pycycle_plant needs pyCycle and OpenMDAO ({_IMPORT_ERROR}); install the pycycle "
               "extra: pip install -e '.[pycycle]'  (om-pycycle, openmdao)") if _IMPORT_ERROR is not None \
    else _numpy_incompatibility()


class PyCycleMissing(ImportError):
    """pyCycle / OpenMDAO are not installed (the optional extra ``pycycle``), or cannot run with
    the installed NumPy."""


class PlantError(RuntimeError):
    """A pyCycle solve that did not converge, or inputs outside the model's valid region."""


class HealthError(ValueError):
    """A health vector of the wrong size or outside :data:`H_RANGE`."""


#: the design specification: sea-level static ISA, corrected speed 100 %
DEFAULTS = {
    "thermo": "TABULAR",    # pyCycle thermodynamics: "TABULAR" (air/Jet-A tables, fast) or "CEA" (3-4x slower)
    "table_refine_T": 4,    # TABULAR: pyCycle's table resampled this many times finer in temperature
    "table_refine_P": 4,    # ... and in pressure (1: pyCycle's table as it is; see _thermo_table)
    "W_design": 20.0,       # inlet mass flow at the design point, kg/s
    "PR_design": 9.0,       # compressor total pressure ratio
    "eff_comp": 0.84,       # compressor adiabatic efficiency
    "eff_turb": 0.88,       # turbine adiabatic efficiency
    "T4_design": 1380.0,    # burner exit total temperature, K
    "N_design": 16000.0,    # mechanical shaft speed, rpm
    "ram_recovery": 0.99,   # inlet total pressure recovery
    "burner_dPqP": 0.04,    # burner total pressure loss, fraction
    "nozzle_Cv": 0.985,     # nozzle velocity coefficient (convergent nozzle)
    "MN_comp": 0.3,         # compressor exit Mach number at the design point (sets Ps30 / P30)
    "inertia": 2.0,         # rotor polar moment of inertia, kg m^2
    "map_interp": "scipy_cubic",  # map interpolation: scipy_cubic (smooth; linear along alphaMap) | slinear
    "tol": 1e-9,            # Newton absolute and relative residual tolerance
    "maxiter": 25,          # Newton iterations per solve
}

X_NAMES = ("N",)
U_NAMES = ("Wf",)
Y_NAMES = ("N", "T30", "Ps30", "T50", "P50")
Z_NAMES = ("Fn", "T40", "SmComp", "W2")
H_NAMES = ("comp_eff", "comp_flow", "turb_eff", "turb_flow")
P_NAMES = ("alt", "Mach", "NR")
#: allowed health fractions: beyond 10 % a component has failed rather than degraded
H_RANGE = (-0.1, 0.1)
UNITS = {"N": "rpm", "Wf": "kg/s", "T30": "K", "Ps30": "Pa", "T50": "K", "P50": "Pa",
         "Fn": "N", "T40": "K", "SmComp": "%", "W2": "kg/s", **{h: "-" for h in H_NAMES},
         "alt": "m", "Mach": "-", "NR": "%", "T2": "K", "P2": "Pa", "dTamb": "K"}
#: plausible ranges of the log channels (catch unit mistakes: kPa, degC, g/s, % speeds); the
#: speed range is a fraction of the design speed, set per object
RANGES = {"Wf": (0.005, 3.0), "T30": (150.0, 1100.0), "Ps30": (1e4, 5e6), "T50": (150.0, 1500.0),
          "P50": (5e3, 1e6), "T2": (170.0, 380.0), "P2": (5e3, 2e5), "alt": (-500.0, 15000.0),
          "Mach": (0.0, 1.0)}
SPEED_RANGE = (0.2, 1.3)
T_STD, P_STD = 288.15, 101325.0
#: the smallest flight Mach number handed to pyCycle (its flow stations need a moving stream)
MN_MIN = 1e-4
RPM = 2.0 * math.pi / 60.0   # rad/s per rpm


class _Discard(io.TextIOBase):
    """Swallows what pyCycle's thermodynamics print while a Newton step wanders (the failure
    itself is reported through the solver)."""

    def write(self, s):
        return len(s)


_QUIET = _Discard()

#: y, z channels -> (path in the cycle, unit it is read in)
_OUT = {"N": ("Nmech", "rpm"), "T30": ("comp.Fl_O:tot:T", "K"), "Ps30": ("comp.Fl_O:stat:P", "Pa"),
        "T50": ("turb.Fl_O:tot:T", "K"), "P50": ("turb.Fl_O:tot:P", "Pa"), "Fn": ("perf.Fn", "N"),
        "T40": ("burner.Fl_O:tot:T", "K"), "SmComp": ("comp.SMN", None), "W2": ("inlet.Fl_O:stat:W", "kg/s")}
#: what the off-design problems take from the design point: compressor and turbine map scalars
#: (the health parameters scale the efficiency and flow ones) and the flow areas
_COMP_SCALARS = ("s_Wc", "s_PR", "s_eff", "s_Nc")
_TURB_SCALARS = ("s_Wp", "s_PR", "s_eff", "s_Np")
_AREAS = {"comp.area": "comp.Fl_O:stat:area"}
#: health parameter -> (element, map scalar)
_HEALTH = {"comp_eff": ("comp", "s_eff"), "comp_flow": ("comp", "s_Wc"),
           "turb_eff": ("turb", "s_eff"), "turb_flow": ("turb", "s_Wp")}


_TABLES: dict = {}


def _thermo_table(refine_T: int, refine_P: int) -> dict:
    """pyCycle's air / Jet-A property table (``pycycle.api.AIR_JETA_TAB_SPEC``: FAR x P x T =
    20 x 110 x 100 nodes, 34 K and 16 % pressure steps), resampled ``refine_T`` times finer in T
    and ``refine_P`` times finer in ln P by cubic splines through its own nodes (rho in ln rho).

    pyCycle interpolates the table linearly, so every property has a slope jump at each node;
    on the original table the cycle's derivatives jump by up to 25 % from one node to the next
    (dWf/dNR along a trim line, dN/dt per fuel flow), and the sensitivity of dN/dt to fuel flow
    is 25 % below the CEA value. Resampled 4 x 4, both are within about 3 % of pyCycle's CEA
    thermodynamics (docs/pycycle.md) at a third of its cost. No new thermodynamic data: the
    nodes of the original table are kept exactly. Cached per process."""
    key = (int(refine_T), int(refine_P))
    if key in _TABLES:
        return _TABLES[key]
    from scipy.interpolate import CubicSpline

    base = pyc.AIR_JETA_TAB_SPEC
    if key == (1, 1):
        _TABLES[key] = base
        return base
    tab = {k: np.asarray(v, dtype=np.float64) for k, v in base.items()}
    props = ("h", "S", "gamma", "Cp", "Cv", "rho", "R")
    for name, axis, k in (("T", 2, key[0]), ("P", 1, key[1])):
        if k <= 1:
            continue
        g = np.log(tab[name]) if name == "P" else tab[name]
        fine = np.concatenate([np.linspace(g[i], g[i + 1], k + 1)[:-1] for i in range(len(g) - 1)] + [g[-1:]])
        for pr in props:
            v = np.log(tab[pr]) if pr == "rho" else tab[pr]
            out = CubicSpline(g, v, axis=axis)(fine)
            tab[pr] = np.exp(out) if pr == "rho" else out
        new = np.exp(fine) if name == "P" else fine
        new[::k] = tab[name]          # the original nodes exactly
        tab[name] = new
    _TABLES[key] = tab
    return tab


def _require_pycycle():
    if _IMPORT_ERROR is not None:
        raise PyCycleMissing(f"models.pycycle_plant needs pyCycle and OpenMDAO ({_IMPORT_ERROR}); install "
                             "the pycycle extra: pip install -e '.[pycycle]'  (om-pycycle, openmdao)")
    if UNAVAILABLE:
        raise PyCycleMissing(UNAVAILABLE)


def _merge(overrides: dict) -> dict:
    unknown = set(overrides) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"PyCycleTurbojet: unknown parameters {sorted(unknown)}; known: {sorted(DEFAULTS)}")
    spec = dict(DEFAULTS)
    for k, v in overrides.items():
        spec[k] = v if isinstance(DEFAULTS[k], str) else type(DEFAULTS[k])(v)
    if spec["thermo"] not in ("TABULAR", "CEA"):
        raise ValueError(f"PyCycleTurbojet: thermo must be 'TABULAR' or 'CEA', got {spec['thermo']!r}")
    return spec


def _cycle(mode: str, spec: dict):
    """The turbojet as a pyCycle ``Cycle`` in one of the modes "design", "trim", "fixed" (see the
    module docstring); every connection and balance is made here."""
    _require_pycycle()

    class SingleSpoolTurbojet(pyc.Cycle):
        def setup(self):
            if spec["thermo"] == "TABULAR":
                self.options["thermo_method"] = "TABULAR"
                self.options["thermo_data"] = _thermo_table(spec["table_refine_T"], spec["table_refine_P"])
                fuel = "FAR"
            else:
                self.options["thermo_method"] = "CEA"
                self.options["thermo_data"] = pyc.species_data.janaf
                fuel = "Jet-A(g)"
            interp = spec["map_interp"]
            add = self.add_subsystem
            add("fc", pyc.FlightConditions())
            if mode == "ambient":      # the flight conditions alone (engine-face T2, P2)
                self._solver()
                return super().setup()
            add("inlet", pyc.Inlet(statics=False))
            add("comp", pyc.Compressor(map_data=pyc.AXI5, map_extrap=True, map_interp_method=interp),
                promotes_inputs=["Nmech"])
            add("burner", pyc.Combustor(fuel_type=fuel, statics=False))
            add("turb", pyc.Turbine(map_data=pyc.LPT2269, map_extrap=True, map_interp_method=interp, statics=False),
                promotes_inputs=["Nmech"])
            add("nozz", pyc.Nozzle(nozzType="CV", lossCoef="Cv"))
            add("shaft", pyc.Shaft(num_ports=2), promotes_inputs=["Nmech"])
            add("perf", pyc.Performance(num_nozzles=1, num_burners=1))

            stations = ("fc", "inlet", "comp", "burner", "turb", "nozz")
            # static properties are computed at the flight condition and the compressor exit only
            # (Ps30); the other stations carry totals, which is all their neighbours need
            for a, b in itertools.pairwise(stations):
                self.pyc_connect_flow(f"{a}.Fl_O", f"{b}.Fl_I", connect_w=(a != "fc"),
                                      connect_stat=(a in ("fc", "comp")))
            self.connect("comp.trq", "shaft.trq_0")
            self.connect("turb.trq", "shaft.trq_1")
            self.connect("fc.Fl_O:stat:P", "nozz.Ps_exhaust")
            self.connect("inlet.Fl_O:tot:P", "perf.Pt2")
            self.connect("comp.Fl_O:tot:P", "perf.Pt3")
            self.connect("burner.Wfuel", "perf.Wfuel_0")
            self.connect("inlet.F_ram", "perf.ram_drag")
            self.connect("nozz.Fg", "perf.Fg_0")

            bal = add("balance", om.BalanceComp())
            if mode == "design":
                bal.add_balance("FAR", val=0.02, lower=1e-4, upper=0.06, eq_units="K", rhs_name="T4_target")
                self.connect("burner.Fl_O:tot:T", "balance.lhs:FAR")
                bal.add_balance("turb_PR", val=4.0, lower=1.001, upper=20.0, eq_units="W", rhs_val=0.0)
                self.connect("balance.turb_PR", "turb.PR")
                self.connect("shaft.pwr_net", "balance.lhs:turb_PR")
                self.set_input_defaults("Nmech", spec["N_design"], units="rpm")
                self.set_input_defaults("inlet.Fl_I:stat:W", spec["W_design"], units="kg/s")
            else:
                bal.add_balance("W", val=spec["W_design"], units="kg/s", lower=1e-3, eq_units="m**2",
                                rhs_name="throat_area")
                self.connect("balance.W", "inlet.Fl_I:stat:W")
                self.connect("nozz.Throat:stat:area", "balance.lhs:W")
                if mode == "trim":
                    bal.add_balance("FAR", val=0.02, lower=1e-4, upper=0.06, eq_units="rpm", rhs_name="Nc_target")
                    self.connect("comp.Nc", "balance.lhs:FAR")
                    bal.add_balance("Nmech", val=spec["N_design"], units="rpm", lower=100.0, eq_units="W",
                                    rhs_val=0.0)
                    self.connect("balance.Nmech", "Nmech")
                    self.connect("shaft.pwr_net", "balance.lhs:Nmech")
                else:  # fixed: shaft speed held (an input), fuel flow held through the fuel-air ratio
                    bal.add_balance("FAR", val=0.02, lower=1e-5, upper=0.06, eq_units="kg/s", rhs_name="Wf_target")
                    self.connect("burner.Wfuel", "balance.lhs:FAR")
                    self.set_input_defaults("Nmech", spec["N_design"], units="rpm")
            self.connect("balance.FAR", "burner.Fl_I:FAR")
            self._solver()
            super().setup()

        def _solver(self):
            newton = self.nonlinear_solver = om.NewtonSolver()
            newton.options["atol"] = spec["tol"]
            newton.options["rtol"] = spec["tol"]
            newton.options["maxiter"] = int(spec["maxiter"])
            newton.options["iprint"] = -1
            newton.options["solve_subsystems"] = True
            newton.options["max_sub_solves"] = 50
            newton.options["err_on_non_converge"] = True
            newton.options["reraise_child_analysiserror"] = False
            ls = newton.linesearch = om.BoundsEnforceLS()
            ls.options["bound_enforcement"] = "scalar"
            self.linear_solver = om.DirectSolver(assemble_jac=True)

    return SingleSpoolTurbojet(design=(mode == "design"))


def _problem(mode: str, spec: dict):
    """A set-up OpenMDAO problem holding the cycle as ``cyc`` (no reports, no files written)."""
    prob = om.Problem(reports=None)
    prob.model.add_subsystem("cyc", _cycle(mode, spec))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prob.setup(check=False)
    prob.set_solver_print(level=-1)
    if mode == "ambient":
        return prob
    c = "cyc."
    prob.set_val(c + "inlet.ram_recovery", spec["ram_recovery"])
    prob.set_val(c + "burner.dPqP", spec["burner_dPqP"])
    prob.set_val(c + "nozz.Cv", spec["nozzle_Cv"])
    return prob


class _TrimDict(dict):
    """A trim result: a plain dict {"x", "u", "y", "z"} that also carries the trim problem's
    solver state (``_state``), so a later trim started from it (``guess``) begins there."""
    _state = None


class PyCycleTurbojet:
    """A single-spool pyCycle turbojet (Plant protocol, continuous time). Keyword parameters
    override :data:`DEFAULTS`, e.g. ``PyCycleTurbojet(T4_design=1450.0, inertia=0.8)``."""

    name = "pycycle-turbojet"
    time = "continuous"
    x_names = X_NAMES
    u_names = U_NAMES
    y_names = Y_NAMES
    z_names = Z_NAMES
    h_names = H_NAMES
    p_names = P_NAMES
    env_names = ("alt", "Mach", "dTamb")

    def __init__(self, **overrides):
        _require_pycycle()
        self.spec = _merge(overrides)
        self.units = dict(UNITS)
        N = self.spec["N_design"]
        self.ranges = {**RANGES, "N": (SPEED_RANGE[0] * N, SPEED_RANGE[1] * N), **{h: H_RANGE for h in H_NAMES}}
        self.h_ref = np.zeros(len(H_NAMES))
        self.perturbation = {"N": 1e-3, "Wf": 1e-3, **{h: 1e-3 for h in H_NAMES}}
        self.sensor_noise = {"N": 0.0025, "T30": 0.0075, "Ps30": 0.005, "T50": 0.0075, "P50": 0.005}
        ex = {"N": (0.5, 0.0), "Wf": (0.5, 1.0), "T30": (1.0, 0.0), "T50": (1.0, 0.0), "T40": (1.0, 0.0),
              "Ps30": (0.0, 1.0), "P50": (0.0, 1.0), "Fn": (0.0, 1.0), "SmComp": (0.0, 0.0), "W2": (-0.5, 1.0)}
        self.correction = {"theta": "T2", "delta": "P2", "T_std": T_STD, "P_std": P_STD, "exponents": ex}
        self._probs = {}
        self._design = None
        self._reset_caches()
        self._run_design()
        self.schedule = {"alt": ("alt", False, 1.0), "Mach": ("Mach", False, 1.0),
                         "NR": ("N", True, 100.0 / self.Nc_design)}

    def _reset_caches(self):
        self._trims = []          # converged trims: (key (alt, Mach, dTamb, NR), h, trim-problem state)
        self._amb_cache = {}      # env bytes -> (T2, P2)
        self._last_eval = None    # [N, Wf, h (4), env (3)] the fixed problem last converged at, or None
        self._state_names = {}    # mode -> names of the implicit outputs (the solver state)

    # ---- pickling: the OpenMDAO problems stay behind and are rebuilt lazily -------------------
    def __getstate__(self):
        d = dict(self.__dict__)
        d["_probs"] = {}
        d["_trims"], d["_amb_cache"], d["_last_eval"], d["_state_names"] = [], {}, None, {}
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)

    # ---- protocol ------------------------------------------------------------------------------
    def parameters(self) -> dict:
        return dict(self.spec)

    def environment(self, p):
        """Ambient condition [alt m, Mach, dTamb K] of scheduling point p = (alt, Mach, NR): a
        standard day."""
        p = np.asarray(p, dtype=np.float64)
        return np.array([p[0], p[1], 0.0])

    def theta_delta(self, env):
        """(T2 / 288.15 K, P2 / 101325 Pa) at ambient ``env`` (engine-face totals from pyCycle)."""
        T2, P2 = self.inlet(env)
        return T2 / T_STD, P2 / P_STD

    def inlet(self, env):
        """(T2 K, P2 Pa): engine-face total temperature and pressure (inlet exit) at ``env``,
        computed by pyCycle's flight conditions and the inlet's ram recovery."""
        env = self._env(env)
        k = env.tobytes()
        if k not in self._amb_cache:
            prob = self._prob("ambient")
            self._set_env(prob, env)
            self._solve(prob, f"ambient conditions at {self._where(env)}")
            T2 = float(prob.get_val("cyc.fc.Fl_O:tot:T", units="K")[0])
            P2 = float(prob.get_val("cyc.fc.Fl_O:tot:P", units="Pa")[0]) * self.spec["ram_recovery"]
            if len(self._amb_cache) > 5000:
                self._amb_cache.clear()
            self._amb_cache[k] = (T2, P2)
        return self._amb_cache[k]

    def trim(self, p, h=None, env=None, guess=None):
        """Steady state at scheduling point p = (alt m, Mach, NR %) with health h (4,) at ambient
        env (default: the standard day of p), from pyCycle's own balances. Returns
        {"x": (1,), "u": (1,), "y": (5,), "z": (4,)} float64; ``guess`` (an earlier trim) is the
        starting point. Raises :class:`PlantError` naming the point when the solve fails."""
        p = np.asarray(p, dtype=np.float64).reshape(-1)
        h = self._h(h)
        env = self.environment(p) if env is None else self._env(env)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise PlantError(f"trim: invalid scheduling point p={p} (expected finite alt, Mach, NR)")
        NR = float(p[2])
        if not 20.0 <= NR <= 120.0:
            raise PlantError(f"trim: corrected speed NR={NR:g} % is outside 20..120 % of design")
        key = np.array([env[0], env[1], env[2], NR])
        prob = self._prob("trim")
        starts = []
        st = getattr(guess, "_state", None) if guess is not None else None
        if st is not None:
            starts.append(st)
        near = self._nearest_trim(key, h)
        if near is not None and (not starts or near[2] is not st):
            starts.append(near[2])
        msg = "no start point"
        for s0 in starts:
            self._set_state(prob, "trim", s0)
            self._set_trim_inputs(prob, key, h)
            try:
                self._solve(prob, "", "trim")
                return self._finish_trim(prob, key, h)
            except PlantError as e:
                msg = str(e)
        # continuation from the nearest converged trim (or the design point)
        k0, h0, s0 = near if near is not None else (self._design_key(), np.zeros(len(H_NAMES)), self._design_state())
        try:
            self._continue(prob, "trim", s0, lambda f: self._set_trim_inputs(prob, k0 + f * (key - k0),
                                                                             h0 + f * (h - h0)))
        except PlantError as e:
            raise PlantError(f"trim did not converge at alt={env[0]:g} m, Mach={env[1]:g}, dTamb={env[2]:g} K, "
                             f"NR={NR:g} %, health={h.tolist()}: {e} (continuation from alt={k0[0]:g}, "
                             f"Mach={k0[1]:g}, NR={k0[3]:g}; direct start: {msg})") from None
        return self._finish_trim(prob, key, h)

    def evaluate(self, x, u, h=None, env=None):
        """The unbalanced solve at shaft speed x = (N,) rpm and fuel flow u = (Wf,) kg/s, health h
        (4,), ambient env [alt m, Mach, dTamb K]: returns (f, y, z) with f = (dN/dt,) rpm/s =
        dP / (I omega) converted to rpm/s (dP the net shaft power, W; omega rad/s), y (5,), z (4,).
        Raises :class:`PlantError` naming the point when the flows cannot be balanced."""
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        u = np.asarray(u, dtype=np.float64).reshape(-1)
        h = self._h(h)
        env = self._env(env)
        if x.shape != (1,) or u.shape != (1,):
            raise PlantError(f"evaluate: shapes x {x.shape}, u {u.shape}; expected (1,), (1,)")
        N, Wf = float(x[0]), float(u[0])
        if not (np.isfinite(N) and np.isfinite(Wf) and N > 0 and Wf > 0):
            raise PlantError(f"evaluate: shaft speed and fuel flow must be finite and positive (N={N}, Wf={Wf})")
        prob = self._prob("fixed")
        where = f"N={N:g} rpm, Wf={Wf:g} kg/s, {self._where(env)}, health={h.tolist()}"
        target = np.concatenate([[N, Wf], h, env])
        ok = False
        if self._last_eval is not None:
            saved = self._get_state(prob, "fixed")
            self._set_fixed_inputs(prob, target)
            try:
                self._solve(prob, "", "fixed")
                ok = True
            except PlantError:
                self._set_state(prob, "fixed", saved)
        if not ok:
            # start from a trim at the same corrected speed and continue in fuel flow (and health)
            T2, _ = self.inlet(env)
            NR = 100.0 * N / math.sqrt(T2 / T_STD) / self.Nc_design
            try:
                t = self.trim(np.array([env[0], env[1], NR]), h, env)
            except PlantError as e:
                raise PlantError(f"evaluate: no start point at {where}: {e}") from None
            start = np.concatenate([t["x"], t["u"], h, env])
            self._set_state(prob, "fixed", self._transfer(self._get_state(self._prob("trim"), "trim"), "fixed"))
            try:
                self._continue(prob, "fixed", self._get_state(prob, "fixed"),
                               lambda f: self._set_fixed_inputs(prob, start + f * (target - start)))
            except PlantError as e:
                self._last_eval = None
                raise PlantError(f"evaluate did not converge at {where}: {e} (continuation from the trim "
                                 f"at NR={NR:.2f} %)") from None
        self._last_eval = target
        y, z = self._outputs(prob)
        dP = float(prob.get_val("cyc.shaft.pwr_net", units="W")[0])
        omega = N * RPM
        dNdt = dP / (self.spec["inertia"] * omega) / RPM
        return np.array([dNdt]), y, z

    # ---- the OpenMDAO problems -------------------------------------------------------------------
    def _prob(self, mode):
        prob = self._probs.get(mode)
        if prob is None:
            prob = _problem(mode, self.spec)
            if mode != "ambient":
                self._set_design_inputs(prob)
            self._probs[mode] = prob
        return prob

    def _run_design(self):
        """Solve the design point once and keep what the off-design problems need."""
        if self._design is not None:
            return
        s = self.spec
        prob = _problem("design", s)
        c = "cyc."
        prob.set_val(c + "fc.alt", 0.0, units="m")
        prob.set_val(c + "fc.MN", MN_MIN)
        prob.set_val(c + "fc.dTs", 0.0, units="degR")
        prob.set_val(c + "inlet.Fl_I:stat:W", s["W_design"], units="kg/s")
        prob.set_val(c + "balance.T4_target", s["T4_design"], units="K")
        prob.set_val(c + "comp.PR", s["PR_design"])
        prob.set_val(c + "comp.eff", s["eff_comp"])
        prob.set_val(c + "turb.eff", s["eff_turb"])
        prob.set_val(c + "Nmech", s["N_design"], units="rpm")
        prob.set_val(c + "comp.MN", s["MN_comp"])
        prob.set_val(c + "balance.turb_PR", 4.0)
        prob.set_val(c + "balance.FAR", 0.02)
        prob.set_val(c + "fc.balance.Pt", 14.7, units="psi")
        prob.set_val(c + "fc.balance.Tt", 518.67, units="degR")
        self._solve(prob, "the design point (sea-level static ISA)")
        d = {}
        for n in _COMP_SCALARS:
            d["comp." + n] = float(prob.get_val(c + "comp." + n)[0])
        for n in _TURB_SCALARS:
            d["turb." + n] = float(prob.get_val(c + "turb." + n)[0])
        for target, src in _AREAS.items():
            d[target] = float(prob.get_val(c + src, units="m**2")[0])
        d["throat_area"] = float(prob.get_val(c + "nozz.Throat:stat:area", units="m**2")[0])
        d["Nc"] = float(prob.get_val(c + "comp.Nc", units="rpm")[0])
        y, z = self._outputs(prob)
        d["Wf"] = float(prob.get_val(c + "burner.Wfuel", units="kg/s")[0])
        d["y"], d["z"] = y.tolist(), z.tolist()
        d["turb_PR"] = float(prob.get_val(c + "balance.turb_PR")[0])
        self._design = d
        self.Nc_design = d["Nc"]
        # the design trim state seeds the trim problem's first start
        self._design_trim = {"W": s["W_design"], "FAR": float(prob.get_val(c + "balance.FAR")[0]),
                             "Nmech": s["N_design"], "turb_PR": d["turb_PR"]}

    def design_point(self) -> dict:
        """The design point: map scalars, areas (m^2), corrected speed Nc (rpm), Wf (kg/s), y, z."""
        return dict(self._design)

    def _set_design_inputs(self, prob):
        d, c = self._design, "cyc."
        for name in (*(f"comp.{n}" for n in _COMP_SCALARS), *(f"turb.{n}" for n in _TURB_SCALARS)):
            prob.set_val(c + name, d[name])
        for target in _AREAS:
            prob.set_val(c + target, d[target], units="m**2")
        prob.set_val(c + "balance.throat_area", d["throat_area"], units="m**2")
        prob.set_val(c + "fc.MN", MN_MIN)
        prob.set_val(c + "balance.W", self.spec["W_design"], units="kg/s")
        prob.set_val(c + "balance.FAR", self._design_trim["FAR"])
        prob.set_val(c + "turb.PR", self._design_trim["turb_PR"])
        prob.set_val(c + "fc.balance.Pt", 14.7, units="psi")
        prob.set_val(c + "fc.balance.Tt", 518.67, units="degR")
        if prob.model.cyc.options["design"] is False and "cyc.balance.Nmech" in self._names(prob):
            prob.set_val(c + "balance.Nmech", self.spec["N_design"], units="rpm")

    def _set_health(self, prob, h):
        d = self._design
        for j, name in enumerate(H_NAMES):
            el, sc = _HEALTH[name]
            prob.set_val(f"cyc.{el}.{sc}", d[f"{el}.{sc}"] * (1.0 + float(h[j])))

    @staticmethod
    def _set_env(prob, env):
        prob.set_val("cyc.fc.alt", float(env[0]), units="m")
        prob.set_val("cyc.fc.MN", max(float(env[1]), MN_MIN))
        prob.set_val("cyc.fc.dTs", float(env[2]), units="K")

    def _set_trim_inputs(self, prob, key, h):
        self._set_env(prob, key[:3])
        self._set_health(prob, h)
        prob.set_val("cyc.balance.Nc_target", key[3] / 100.0 * self.Nc_design, units="rpm")

    def _set_fixed_inputs(self, prob, v):
        """v = [N, Wf, h (4), env (3)]."""
        prob.set_val("cyc.Nmech", v[0], units="rpm")
        prob.set_val("cyc.balance.Wf_target", v[1], units="kg/s")
        self._set_health(prob, v[2:6])
        self._set_env(prob, v[6:9])

    def _solve(self, prob, where, mode=None):
        """Run the problem's Newton solve. With ``mode`` (a problem with a saved state), a fast
        monolithic Newton (all implicit states at once; TABULAR thermodynamics only) is tried first
        and, when it fails, the
        robust one that also solves every subsystem (pyCycle's usual setting) from the same
        start. Raises :class:`PlantError` with the solver's message."""
        newton = prob.model.cyc.nonlinear_solver
        if mode is not None and self.spec["thermo"] == "TABULAR":   # CEA's equilibrium needs sub-solves
            start = self._get_state(prob, mode)
            newton.options["solve_subsystems"] = False
            try:
                return self._run(prob, where)
            except PlantError:
                self._set_state(prob, mode, start)
            finally:
                newton.options["solve_subsystems"] = True
        self._run(prob, where)

    @staticmethod
    def _run(prob, where):
        try:
            with warnings.catch_warnings(), contextlib.redirect_stdout(_QUIET):
                warnings.simplefilter("ignore")
                with np.errstate(all="ignore"):
                    prob.run_model()
        except om.AnalysisError as e:
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise PlantError(f"pyCycle Newton solve failed{' at ' + where if where else ''}: {first}") from None
        except (ValueError, FloatingPointError, ZeroDivisionError, np.linalg.LinAlgError) as e:
            raise PlantError(f"pyCycle solve failed{' at ' + where if where else ''}: "
                             f"{type(e).__name__}: {e}") from None

    def _outputs(self, prob):
        vals = {n: float(prob.get_val("cyc." + path, units=unit)[0]) if unit else float(prob.get_val("cyc." + path)[0])
                for n, (path, unit) in _OUT.items()}
        y = np.array([vals[n] for n in Y_NAMES])
        z = np.array([vals[n] for n in Z_NAMES])
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
            raise PlantError(f"pyCycle returned non-finite outputs y={y}, z={z}")
        return y, z

    # ---- solver state: the implicit outputs of a problem -------------------------------------------
    def _names(self, prob):
        return {n for n, _ in prob.model.list_outputs(out_stream=None, prom_name=False)}

    def _implicit(self, prob, mode):
        names = self._state_names.get(mode)
        if names is None:
            names = tuple(n for n, _ in prob.model.list_outputs(explicit=False, implicit=True, out_stream=None))
            self._state_names[mode] = names
        return names

    def _get_state(self, prob, mode) -> dict:
        return {n: prob.get_val(n).copy() for n in self._implicit(prob, mode)}

    def _set_state(self, prob, mode, state: dict):
        for n, v in state.items():
            prob.set_val(n, v)

    def _transfer(self, state: dict, dst: str) -> dict:
        """The entries of a solver state (implicit output -> value) that problem ``dst`` also has
        (the elements share their names across the trim and fixed problems)."""
        names = set(self._implicit(self._prob(dst), dst))
        return {n: v for n, v in state.items() if n in names}

    def _design_key(self):
        return np.array([0.0, MN_MIN, 0.0, 100.0])

    def _design_state(self):
        prob = self._prob("trim")
        if not hasattr(self, "_trim_design_state") or self._trim_design_state is None:
            self._set_design_inputs(prob)
            self._set_trim_inputs(prob, self._design_key(), np.zeros(len(H_NAMES)))
            self._solve(prob, "the design point (off-design model)")
            self._trim_design_state = self._get_state(prob, "trim")
        return self._trim_design_state

    def _nearest_trim(self, key, h):
        if not self._trims:
            return None
        scale = np.array([6000.0, 0.6, 30.0, 20.0])
        d = [np.sum(((k - key) / scale) ** 2) + np.sum(((hh - h) / 0.02) ** 2) for k, hh, _ in self._trims]
        return self._trims[int(np.argmin(d))]

    def _finish_trim(self, prob, key, h):
        x = np.array([float(prob.get_val("cyc.Nmech", units="rpm")[0])])
        u = np.array([float(prob.get_val("cyc.burner.Wfuel", units="kg/s")[0])])
        y, z = self._outputs(prob)
        state = self._get_state(prob, "trim")
        if len(self._trims) >= 2000:
            self._trims = self._trims[500:]
        self._trims.append((key.copy(), h.copy(), state))
        out = _TrimDict(x=x, u=u, y=y, z=z)
        out._state = state
        return out

    def _continue(self, prob, mode, s0, set_inputs):
        """Natural-parameter continuation: ``set_inputs(f)`` sets the inputs at fraction f of the
        way (f = 0: where state ``s0`` is converged); steps halve on failure down to 1/256."""
        state, frac, step, msg = s0, 0.0, 0.25, ""
        while frac < 1.0:
            f = min(1.0, frac + step)
            self._set_state(prob, mode, state)
            set_inputs(f)
            try:
                self._solve(prob, "", mode)
                state, frac, step = self._get_state(prob, mode), f, min(1.0, 2.0 * step)
            except PlantError as e:
                msg = str(e)
                step *= 0.5
                if step < 1.0 / 256:
                    self._set_state(prob, mode, state)
                    raise PlantError(f"{msg}; continuation stopped at {frac:.3f} of the way") from None

    # ---- checks ------------------------------------------------------------------------------------
    @staticmethod
    def _where(env):
        return f"alt={env[0]:g} m, Mach={env[1]:g}, dTamb={env[2]:g} K"

    @staticmethod
    def _env(env):
        env = np.asarray(env, dtype=np.float64).reshape(-1)
        if env.shape != (3,) or not np.all(np.isfinite(env)):
            raise PlantError(f"ambient condition must be finite [alt m, Mach, dTamb K], got {env}")
        if not (-1000.0 <= env[0] <= 20000.0 and 0.0 <= env[1] <= 1.0 and -60.0 <= env[2] <= 60.0):
            raise PlantError(f"ambient condition {env.tolist()} is outside alt -1000..20000 m, Mach 0..1, "
                             "dTamb -60..60 K")
        return env

    @staticmethod
    def _h(h):
        if h is None:
            return np.zeros(len(H_NAMES))
        h = np.asarray(h, dtype=np.float64).reshape(-1)
        if h.shape != (len(H_NAMES),) or not np.all(np.isfinite(h)):
            raise HealthError(f"health vector must be {len(H_NAMES)} finite fractions {H_NAMES}, got {h}")
        lo, hi = H_RANGE
        if np.any(h < lo) or np.any(h > hi):
            raise HealthError(f"health {h.tolist()} outside {lo:g}..{hi:g} (fractions: -0.01 is a 1 % loss)")
        return h


if __name__ == "__main__":
    import time as _time
    _t = _time.perf_counter()
    _m = PyCycleTurbojet()
    print(f"design point ({_time.perf_counter() - _t:.1f} s):", _m.design_point())
