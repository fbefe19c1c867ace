"""Build a gain database from a plant and a build spec (DESIGN.md section 2).

Phases, each over grid points in parallel through a ``concurrent.futures.Executor``:

1. trims on the trim grid, one task per line along the power axis (warm-started from the top of
   the line down); failed trims are filled by linear interpolation along the power axis between
   the nearest good neighbours, extrapolated linearly where not bounded (status 1 / 2);
2. at every dynamics grid point: trim, perturbation Jacobians A..N, zero-order hold, parameter
   correction; a failed point is replaced by the nearest good point (normalised scheduling
   distance), its donor recorded;
3. tuner selection (subset, optionally refined to optimal tuners) by covariance analysis;
4. the steady-state update gain of the augmented system at every dynamics point; failed points
   replaced by the nearest good one.

Per-task results of phases 1-2 are kept in ``<output>.parts/`` as they arrive, so a build that is
interrupted or failed and is started again reuses them (results of another spec are removed);
the folder is removed after a successful save. A plant's own exception is recorded with the
grid point it happened at, and a build it makes fail is a :class:`BuildError` naming the plant
and the point.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import sys
import time
import zipfile
from concurrent.futures import Executor, as_completed

import numpy as np

from pwl.airdata import ambient_offset, inlet_pressure
from pwl.database import COMPUTED, EXTRAPOLATED, FILLED, OUT_NONE, REPLACED, Ambient, Correction, GainDatabase
from pwl.errors import PwlError
from pwl.grid import Axis, Grid
from pwl.runtime import augment
from pwl.workers import SerialExecutor, process_pool

from . import plant as proto
from . import threads
from .jacobian import correct, discretize, jacobians
from .kalman import GainError, steady_state_gain
from .spec import BuildSpec, SpecError, per_channel
from .tuners import optimal_tuners, select_subset


class BuildError(PwlError, RuntimeError):
    """A build that cannot produce a valid database (names the phase and the points)."""


class TaskError(PwlError, RuntimeError):
    """A task that failed in a worker, as ``"Type: message"`` of what it raised: a plant's own
    exception class may not survive the trip back to the builder (pickling), its text does."""


# ---- executors ----------------------------------------------------------------------------------
class Progress:
    """Progress of one build phase on stderr: a live one-line bar on a terminal; elsewhere (a log
    file, a pipe) a line at most every 10 % of the work and 5 s, whichever is rarer, and a final
    line saying the phase completed."""

    EVERY_FRACTION = 0.1
    EVERY_SECONDS = 5.0

    def __init__(self, label: str, total: int, enabled: bool = True, stream=None, clock=time.perf_counter):
        self.label, self.total, self.enabled = label, max(total, 1), enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.clock = clock
        self.t0 = clock()
        self.done = 0
        self.printed = (0, self.t0)  # work done and time at the last line (not on a terminal)
        self.finished = False

    def update(self, done: int, note: str = "") -> None:
        """``done`` units of work are done: redraw the bar, print a line when due, or finish."""
        self.done = done
        if not self.enabled or self.finished:
            return
        if done >= self.total:
            self.finish(note)
            return
        now = self.clock()
        if self.tty:
            print("\r" + self._line(now, note), end="", file=self.stream, flush=True)
        elif (done - self.printed[0] >= self.EVERY_FRACTION * self.total
              and now - self.printed[1] >= self.EVERY_SECONDS):
            self.printed = (done, now)
            print(self._line(now, note), file=self.stream, flush=True)

    def finish(self, note: str = "") -> None:
        """Print the final line, once (the work may end below ``total``: an optimiser converged)."""
        if not self.enabled or self.finished:
            return
        self.finished = True
        el = self.clock() - self.t0
        line = f"{self._bar()} {self.done}/{self.total} completed in {el:.1f} s {note}".rstrip()
        print(("\r" if self.tty else "") + line, file=self.stream, flush=True)

    def _bar(self) -> str:
        """'label [#####.....]'."""
        n = int(30 * min(self.done / self.total, 1.0))
        return f"{self.label:<10} [{'#' * n}{'.' * (30 - n)}]"

    def _line(self, now: float, note: str) -> str:
        """The bar with the work done, the time elapsed and the time left."""
        frac = self.done / self.total
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        return f"{self._bar()} {self.done}/{self.total} {el:6.1f} s, eta {eta:5.0f} s {note}"


def notice(msg: str) -> None:
    """One line on stderr that is not progress: files a build removed or reuses."""
    print(msg, file=sys.stderr, flush=True)


# ---- worker-side tasks (module level: picklable) ----------------------------------------------
_PLANTS: dict = {}


def _plant(ref):
    """The plant of a task: ``ref`` is a plant object or ("import", target, parameters JSON)."""
    if not (isinstance(ref, tuple) and ref and ref[0] == "import"):
        return ref
    if ref not in _PLANTS:
        _PLANTS[ref] = proto.load_plant(ref[1], json.loads(ref[2]))
    return _PLANTS[ref]


#: what a resumed build says of what it compared (docs/building.md)
RESUME_NOTE = (" (same spec, plant parameters and Python code; data files the plant reads are not compared: "
               "remove the folder if one changed)")


def trim_line(ref, points, h, dt: float, span: float = 0.0):
    """Trims at ``points`` (k, np) in the given order, each warm-started from the last success,
    each checked to be the plant's steady state (:func:`linearize.plant.check_steady` at step
    ``dt`` s).

    With ``span`` > 0 K also the trims' change with the day's ambient at each point: trimmed again
    at ISA +- span (warm-started from the standard day's trim), in corrected units,
    ``ambient_<kind>`` (k, 2, n) = [c1, c2] of trim(dT) = trim + c1 dT + c2 dT^2 (:func:`ambient_terms`).

    Returns (x, u, y, z arrays (k, n) with NaN rows where the trim failed [, ambient_x..z (k, 2, n)
    NaN where no ambient trim converged], list of error strings).
    """
    plant = _plant(ref)
    out = {k: np.full((len(points), len(proto.names(plant, k))), np.nan) for k in "xuyz"}
    if span > 0.0:
        out |= {f"ambient_{k}": np.full((len(points), 2, len(proto.names(plant, k))), np.nan) for k in "xuyz"}
    errors = [""] * len(points)
    guess = None
    for i, p in enumerate(points):
        try:
            env = plant.environment(p)
            t = plant.trim(np.asarray(p, dtype=np.float64), h, env, guess=guess)
            vals = {k: np.asarray(t[k], dtype=np.float64).reshape(-1) for k in "xuyz"}
            for k, v in vals.items():
                if v.size != out[k].shape[1]:
                    raise ValueError(f"trim returned {v.size} {k} values, the plant names {out[k].shape[1]} "
                                     f"({', '.join(proto.names(plant, k))})")
            bad = [k for k, v in vals.items() if not np.all(np.isfinite(v))]
            if bad:
                raise ValueError(f"trim returned non-finite values in {', '.join(bad)}")
            proto.check_steady(plant, vals, h, env, dt)
            for k in "xuyz":
                out[k][i] = vals[k]
            guess = t
        except Exception as e:  # recorded per point, filled later
            errors[i] = f"{type(e).__name__}: {e}"
            continue
        if span > 0.0:
            for k, c in ambient_terms(plant, p, h, t, span).items():
                out[f"ambient_{k}"][i] = c
    return out, errors


def ambient_terms(plant, p, h, trim, span: float) -> dict:
    """kind -> (2, n) [c1 (per K), c2 (per K^2)] of the corrected trim's change with the day's
    ambient temperature offset dT at scheduling point ``p``: trim_c(dT) = trim_c + c1 dT + c2 dT^2
    through the plant's trims at dT = -span, 0, +span (``trim``: the standard day's as the plant
    returned it, the others' start; each day corrected with its own theta, delta). One day
    failing: linear through the other (c2 = 0); both: NaN (filled along the power line by the
    builder)."""
    p = np.asarray(p, dtype=np.float64)
    env0 = plant.environment(p)
    fac0 = proto.correction_factors(plant, env0)
    base = {k: np.asarray(trim[k], dtype=np.float64).reshape(-1) / fac0[k] for k in "xuyz"}
    days = {}
    for dT in (span, -span):
        env = proto.day_environment(plant, p, dT)
        try:
            t = plant.trim(p, h, env, guess=trim)
            fac = proto.correction_factors(plant, env)
            v = {k: np.asarray(t[k], dtype=np.float64).reshape(-1) / fac[k] for k in "xuyz"}
        except Exception:  # the plant's own failure on that day: the other day serves
            continue
        if all(np.all(np.isfinite(a)) for a in v.values()):
            days[dT] = v
    out = {}
    for k in "xuyz":
        c = np.full((2, base[k].size), np.nan)
        if len(days) == 2:
            hot, cold = days[span][k], days[-span][k]
            c[0] = (hot - cold) / (2.0 * span)
            c[1] = (hot + cold - 2.0 * base[k]) / (2.0 * span * span)
        elif days:
            (dT, v), = days.items()
            c[0], c[1] = (v[k] - base[k]) / dT, 0.0
        out[k] = c
    return out


def dynamics_point(ref, p, h, guess, dt, method, overrides):
    """Trim, Jacobians, ZOH and correction at one dynamics point.

    Returns a dict: corrected trim x, u, y, z and discrete corrected matrices A..N, one-sided
    column count; raises on failure (the caller records it).
    """
    plant = _plant(ref)
    env = plant.environment(p)
    t = plant.trim(np.asarray(p, dtype=np.float64), h, env, guess=guess)
    proto.check_steady(plant, t, h, env, dt)
    mats, info = jacobians(plant, t, h, env, method, overrides)
    if getattr(plant, "time", "continuous") == "continuous":
        mats = discretize(mats, dt)
    fac = proto.correction_factors(plant, env)
    out = {f"trim_{k}": np.asarray(t[k], dtype=np.float64).reshape(-1) / fac[k] for k in "xuyz"}
    out.update(correct(mats, fac))
    out["one_sided"] = info["one_sided_columns"]
    for k, v in out.items():
        if not np.all(np.isfinite(v)):
            raise ValueError(f"non-finite {k}")
    return out


# ---- checkpoints --------------------------------------------------------------------------------
class Parts:
    """Per-task results on disk (``<output>.parts/``), written atomically as they arrive.

    The folder is stamped with the build key (:func:`_key`); whatever it holds under another
    stamp is the leftover of a build of another spec or plant and is removed, with a notice on
    stderr. A folder with files but no stamp was not made by a build and is left alone (refused)."""

    def __init__(self, out_path: str, key: str):
        self.dir = os.fspath(out_path) + ".parts"
        os.makedirs(self.dir, exist_ok=True)
        stamp = os.path.join(self.dir, "build-key")
        try:
            with open(stamp) as fh:
                old = fh.read().strip()
        except FileNotFoundError:
            old = None
        if old != key:
            stale = [f for f in os.listdir(self.dir) if f != "build-key"]
            if old is None and stale:
                raise BuildError(f"{self.dir}/ holds files but no build-key: not the partial results of a "
                                 f"build; move it away or choose another output name")
            self.clear()
            if stale:
                notice(f"removed {len(stale)} file(s) from {self.dir}/: partial results of a build with "
                       f"another spec or plant")
            with open(stamp, "w") as fh:
                fh.write(key)

    def _path(self, name):
        return os.path.join(self.dir, name + ".npz")

    def get(self, name):
        """The arrays stored as ``name``, or None (not there, or unreadable: computed again)."""
        p = self._path(name)
        if not os.path.exists(p):
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            return None

    def put(self, name, arrays: dict):
        tmp = os.path.join(self.dir, f".{name}.tmp.npz")  # hidden until complete
        np.savez(tmp, **arrays)
        os.replace(tmp, self._path(name))

    def clear(self):
        """Remove every file of the folder."""
        for f in os.listdir(self.dir):
            os.remove(os.path.join(self.dir, f))

    def remove(self):
        """Remove the folder."""
        self.clear()
        os.rmdir(self.dir)


# ---- helpers ------------------------------------------------------------------------------------
def nearest_good(grid, good: np.ndarray) -> np.ndarray:
    """Flat donor index for every node: itself if good, else the nearest good node (normalised
    scheduling distance; ties to the lowest index). ``good`` is a flat bool array."""
    if not good.any():
        return np.full(good.size, -1, dtype=np.int64)
    u = grid.normalized(grid.nodes())
    gi = np.flatnonzero(good)
    d = ((u[:, None, :] - u[None, gi, :]) ** 2).sum(-1)
    donor = gi[np.argmin(d, axis=1)]
    donor[good] = np.flatnonzero(good)
    return donor.astype(np.int64)


def fill_line(values: np.ndarray, ok: np.ndarray, power: np.ndarray):
    """Fill failed rows of one power line: linear interpolation between the nearest good
    neighbours, linear extrapolation from the two nearest good ones outside them (one good point:
    held). Returns (filled values, status per point)."""
    status = np.where(ok, COMPUTED, FILLED).astype(np.int8)
    good = np.flatnonzero(ok)
    out = values.copy()
    if good.size == 0:
        raise BuildError("no trim converged on this power line")
    for i in np.flatnonzero(~ok):
        lo, hi = good[good < i], good[good > i]
        if lo.size and hi.size:
            a, b = lo[-1], hi[0]
        else:
            status[i] = EXTRAPOLATED
            side = lo if lo.size else hi
            if side.size == 1:
                out[i] = values[side[0]]
                continue
            a, b = (side[-2], side[-1]) if lo.size else (side[0], side[1])
        w = (power[i] - power[a]) / (power[b] - power[a])
        out[i] = (1 - w) * values[a] + w * values[b]
    return out, status


def _key(spec: BuildSpec, ref, code: str = "") -> str:
    """The build key of the per-task results: a hash of what phases 1-2 depend on (the plant,
    its code (:func:`_plant_code`), the grids and the [build] settings; not [kalman] or
    [tuners], used by phases 3-4 only)."""
    plant = list(ref[1:]) if isinstance(ref, tuple) else [_plant_name(ref), ref.parameters()]
    what = {"plant": plant, "code": code, "power_axis": spec.power_axis, "dt": spec.dt, "differences": spec.differences,
            "perturbation": spec.perturbation, "health_reference": spec.health_reference,
            "dynamics_hold": spec.dynamics_hold, "ambient_span": spec.ambient_span,
            "grids": [{a.name: a.values.tolist() for a in g.axes} for g in (spec.trim_grid, spec.dyn_grid)]}
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()


def _plant_code(plant) -> str:
    """A digest of the plant's code: every .py file of the top-level package its class is defined
    in (or its module's file alone), so results kept from a build of the plant before an edit
    are not reused (a resumed build reused trims of the old code: outputs x2 stored as before)."""
    path = getattr(sys.modules.get(type(plant).__module__), "__file__", None)
    if not path:
        return ""
    top = sys.modules.get(type(plant).__module__.split(".")[0])
    folders = list(getattr(top, "__path__", []))          # a package: all of it
    files = sorted(f for d in folders for f in glob.glob(os.path.join(d, "**", "*.py"), recursive=True)) or [path]
    h = hashlib.sha256()
    for f in files:
        with open(f, "rb") as fh:
            h.update(f.encode() + b"\0" + fh.read() + b"\0")
    return h.hexdigest()


def _plant_name(plant) -> str:
    """'module:Class' of a plant object, for messages."""
    return f"{type(plant).__module__}:{type(plant).__qualname__}"


def _describe(e: BaseException) -> str:
    """'Type: message' of an exception."""
    return f"{type(e).__name__}: {e}"


def _reason(label: str, e: BaseException | str) -> str:
    """Why a point failed, naming it: 'alt=0, Mach=0.4, NfR=60: PlantError: ...'."""
    return f"{label}: {e if isinstance(e, (str, TaskError)) else _describe(e)}"


def _task(fn, *args):
    """fn(*args), where a task runs; an exception comes back as a :class:`TaskError` with its text."""
    try:
        return fn(*args)
    except Exception as e:
        raise TaskError(_describe(e)) from None


def _run(executor, fn, tasks, progress: Progress, on_result):
    """Submit ``tasks`` (name, args) and hand each (name, result or exception) to ``on_result``."""
    if isinstance(executor, SerialExecutor):  # one at a time, each result kept before the next
        # (in this process, already on one BLAS thread: build and retune set it)
        pairs = ((name, executor.submit(_task, fn, *args)) for name, args in tasks)
    else:
        futs = {executor.submit(threads.call, _task, fn, *args): name for name, args in tasks}
        pairs = ((futs[f], f) for f in as_completed(futs))
    abort = None
    for name, fut in pairs:
        try:
            res = fut.result()
        except Exception as e:  # a failed task is a failed point, recorded by the caller
            res = e
        except BaseException as e:  # an interrupt: keep every other finished result, then stop
            abort = e
            if isinstance(executor, SerialExecutor):
                break
            continue
        on_result(name, res)
        progress.update(progress.done + 1)
    if abort is not None:
        raise abort


# ---- the build ----------------------------------------------------------------------------------
def spec_plant(spec: BuildSpec):
    """The plant of the spec's [model]; a :class:`SpecError` naming the file and the key when
    the class cannot be found or refuses its parameters."""
    try:
        cls = proto.import_plant(spec.plant)
    except proto.PlantProtocolError as e:
        raise SpecError(f"{spec.path}: [model] plant: {e}") from None
    try:
        plant = cls(**spec.parameters)
    except Exception as e:  # the plant's own constructor refused them
        raise SpecError(f"{spec.path}: [model] parameters = {spec.parameters} refused by {spec.plant}: "
                        f"{_describe(e)}") from None
    try:
        return proto.check_plant(plant)
    except proto.PlantProtocolError as e:
        raise SpecError(f"{spec.path}: [model] plant = {spec.plant!r}: {e}") from None


@threads.one_blas_thread
def build(spec: BuildSpec, out_path, *, plant=None, executor: Executor | None = None,
          workers: int | None = None, progress: bool = True, keep_parts: bool = False,
          log=print) -> GainDatabase:
    """Build the database described by ``spec`` and save it atomically to ``out_path``.

    ``plant``: a plant object to use instead of importing ``spec.plant`` (it must be picklable for
    a process executor). ``executor``: any ``concurrent.futures.Executor`` (a Dask cluster's
    ``client.get_executor()`` works); default: a process pool of ``workers`` processes.
    """
    if plant is None:
        plant = spec_plant(spec)
        ref = ("import", spec.plant, json.dumps(spec.parameters, sort_keys=True))
        who = f"plant {spec.plant}"
    else:
        ref = proto.check_plant(plant)
        who = f"plant {_plant_name(plant)}"
    names = {k: proto.names(plant, k) for k in ("x", "u", "y", "z", "h", "p")}
    if list(spec.trim_grid.names) != names["p"]:
        raise SpecError(f"{spec.path}: [trim_grid] axes {list(spec.trim_grid.names)} must be the plant's "
                        f"scheduling variables in order {names['p']}")
    hold = dynamics_hold(spec, names["p"])
    h0 = proto.h_ref(plant)
    for k, v in spec.health_reference.items():
        if k not in names["h"]:
            raise SpecError(f"{spec.path}: [build] health_reference names unknown {k!r}")
        h0[names["h"].index(k)] = float(v)
    for k, v in spec.perturbation.items():      # a typo would leave the plant's size in place
        if k not in names["x"] + names["u"] + names["h"]:
            raise SpecError(f"{spec.path}: [build] perturbation names unknown {k!r} (states, inputs and health "
                            f"parameters: {', '.join(names['x'] + names['u'] + names['h'])})")
        if not (np.isfinite(v) and v > 0):
            raise SpecError(f"{spec.path}: [build] perturbation {k} = {v}: must be a finite size > 0")
    noise = dict(getattr(plant, "sensor_noise", None) or {})
    noise.update(spec.r)
    r_frac = per_channel(noise, names["y"], "sensor noise (the plant's sensor_noise, then [kalman] r)", spec.path,
                         positive=True)
    q_x = per_channel(spec.q_x, names["x"], "[kalman] q_x", spec.path)
    q_h = per_channel(spec.q_h, names["h"], "[kalman] q_h", spec.path)
    h_sig = per_channel(spec.health_sigma, names["h"], "[tuners] health_sigma", spec.path, positive=True)
    targets = _targets(spec.targets, names, spec.path)
    if not 1 <= spec.n_tuners <= len(names["h"]):
        raise SpecError(f"{spec.path}: [tuners] n = {spec.n_tuners} must be in 1..{len(names['h'])} "
                        f"(the plant's health parameters)")
    if spec.n_tuners > len(names["y"]):
        # a tuner is constant in the filter's model: with more of them than sensors, some
        # combination of tuners moves no sensor at steady state and the system is not detectable
        raise SpecError(f"{spec.path}: [tuners] n = {spec.n_tuners} is more than the plant's {len(names['y'])} "
                        f"sensors ({', '.join(names['y'])}): at most as many tuners as sensors can be estimated")
    if getattr(plant, "time", "continuous") == "discrete" and abs(plant.dt - spec.dt) > 1e-12 * spec.dt:
        raise SpecError(f"{spec.path}: dt = {spec.dt} but the discrete plant's dt is {plant.dt}")

    parts = Parts(out_path, _key(spec, ref, _plant_code(plant)))
    own = executor is None
    if own:
        executor = process_pool(max(1, workers or os.cpu_count() or 1))
    t_start = time.perf_counter()
    try:
        span = ambient_span(plant, spec, spec.trim_grid, log)
        trim, trim_status, trim_errors, no_ambient = _trims(spec, ref, who, names, h0, executor, parts, progress,
                                                            span)
        dyn, dyn_errors = _dynamics(spec, ref, who, names, h0, trim, hold, executor, parts, progress)
        log(f"trims: {spec.trim_grid.size - len(trim_errors)}/{spec.trim_grid.size} converged"
            + "".join(f"\n  failed {e}" for e in trim_errors.values()))
        if span > 0.0:
            log(f"ambient: trims at ISA -+ {span:g} K on {spec.trim_grid.size - no_ambient}/{spec.trim_grid.size} "
                "points (the others filled along the power axis)")
        log(f"dynamics: {spec.dyn_grid.size - len(dyn_errors)}/{spec.dyn_grid.size} computed"
            + "".join(f"\n  failed {e}" for e in dyn_errors.values()))

        # ---- trims in corrected units; grid axes carry the plant's units
        tg, dg = (Grid([Axis(a.name, a.values, plant.units.get(a.name, "")) for a in g.axes], g.policy)
                  for g in (spec.trim_grid, spec.dyn_grid))
        for i, p in enumerate(tg.nodes()):
            try:
                fac = proto.correction_factors(plant, plant.environment(p))
            except Exception as e:  # the plant's own error, in this process
                raise BuildError(f"{who}: correcting the trim failed at {_reason(point_label(tg, p), e)}") from e
            for k in "xuyz":
                trim[k].reshape(tg.size, -1)[i] /= fac[k]
        ambient = None
        if span > 0.0:
            ambient = Ambient({k: trim[f"ambient_{k}"] for k in "xuyz"}, span, "alt", "Mach",
                              inlet_recovery(plant, spec.trim_grid, log))

        # ---- noise covariances per dynamics point (corrected units: noise scales with the value)
        pts = []
        for i in range(dg.size):
            d = dyn["point"][i]
            pts.append({"mats": {m: dyn[m][i] for m in "ABCDFGLMN"},
                        "Qx": np.diag((q_x * np.maximum(np.abs(d["trim_x"]), 1e-12)) ** 2),
                        "Qh": np.diag(q_h ** 2),
                        "R": np.diag((r_frac * np.maximum(np.abs(d["trim_y"]), 1e-12)) ** 2),
                        "z_scale": np.maximum(np.abs(d["trim_z"]), 1e-9)})
        fd = design_filter(pts, names, dg, dyn["status"], spec.n_tuners, spec.tuner_method,
                           np.diag(h_sig ** 2), targets, progress, log, executor=executor)
    finally:  # the pool serves phases 1-3 (tuner selection: tuners.envelope_mses)
        if own:
            executor.shutdown()
    D = dg.shape

    ex = proto.correction_exponents(plant)
    corr = None
    if ex is not None:
        c = plant.correction
        corr = Correction(c["theta"], c["delta"], ex, float(c.get("T_std", 288.15)),
                          float(c.get("P_std", 101325.0)))
    units = {k: [plant.units[n] for n in names[k]] for k in names}
    units["q"] = ["-"] * spec.n_tuners
    db = GainDatabase(
        names={**names, "q": fd["q_names"]}, units=units, trim_grid=tg, dyn_grid=dg,
        trim={k: trim[k] for k in "xuyz"}, trim_status=trim_status,
        dynamics={m: dyn[m].reshape(D + dyn[m].shape[1:]) for m in "ABCDFGLMN"},
        dyn_status=dyn["status"].reshape(D), dyn_donor=dyn["donor"].reshape(D),
        tuner={"V": fd["V"], "V_pinv": np.linalg.pinv(fd["V"]), "h_ref": h0},
        kalman=kalman_arrays(fd, D),
        kalman_status=fd["status"].reshape(D), kalman_donor=fd["donor"].reshape(D), dt=spec.dt,
        schedule=proto.schedule(plant), correction=corr, ambient=ambient, log_channels=proto.log_channels(plant),
        attrs={"model": spec.plant if isinstance(ref, tuple) else _plant_name(plant), "model_name": plant.name,
               "health_ranges": proto.health_ranges(plant),
               "model_parameters": plant.parameters(), "spec": spec.text,
               "tuner_method": spec.tuner_method, "tuner_metric": fd["metric"],
               "tuner_subset_metric": fd["subset_metric"], "tuner_rms_error": fd["rms_error"],
               "tuner_targets": list(fd["rms_error"]), "discretization": "zoh",
               "dynamics_hold": hold,
               "build_seconds": time.perf_counter() - t_start,
               "trim_failures": trim_errors,
               "dynamics_failures": dyn_errors},
        path=os.fspath(out_path))
    if not db.attrs["health_ranges"]:
        log(f"warning: {who} declares no plausible range of its health parameters (plant.ranges, "
            "docs/plant-protocol.md): an estimate far out (a sensor bias read as health) is not flagged implausible")
    db.save(out_path)
    if not keep_parts:
        parts.remove()
    log(f"wrote {out_path} in {time.perf_counter() - t_start:.1f} s")
    return db


def _warn_unseen(pts, h_names, h_sigma, log) -> None:
    """Log a warning naming every health parameter no sensor sees at any point: its steady-state
    effect on the sensors, C (I - A)^-1 L + M, in sensor standard deviations for a one-sigma
    change, below 1e-6 everywhere (the filter cannot estimate it: it stays at its prior)."""
    seen = np.zeros(len(h_names))
    for pt in pts:
        m = pt["mats"]
        try:
            G = m["C"] @ np.linalg.solve(np.eye(m["A"].shape[0]) - m["A"], m["L"]) + m["M"]
        except np.linalg.LinAlgError:      # a pure integrator: no steady state to judge by
            continue
        G = G / np.sqrt(np.diag(pt["R"]))[:, None] * h_sigma[None, :]
        seen = np.maximum(seen, np.linalg.norm(G, axis=0))
    unseen = [h for h, v in zip(h_names, seen) if v < 1e-6]
    if unseen:
        log(f"warning: no sensor sees {', '.join(unseen)} at any operating point (steady-state effect 0): "
            "the filter cannot estimate it; its estimate stays at its prior")


def design_filter(pts, names, dg, dyn_status, n_tuners, method, Ph, targets, progress=False,
                  log=print, executor=None) -> dict:
    """Phases 3-4: tuners V by covariance analysis, then the steady-state gain at every point.

    pts: per dynamics point (flat order) dicts of discrete corrected ``mats`` A..N, ``Qx``,
    ``Qh`` (health random walk), ``R`` and ``z_scale``; dyn_status (flat) marks replaced points,
    which take their donor's gain. Returns V (nq, nh), q_names, metric, subset_metric,
    rms_error (target -> RMS error), K, P, Q, R stacked over the points, status and donor.
    ``executor``: where the tuner selection's covariance analyses run (``tuners.envelope_mses``;
    the same numbers as in this process, None).
    """
    nx, ny = len(names["x"]), len(names["y"])
    every = names["h"] + names["z"]
    rho = np.array([np.abs(np.linalg.eigvals(pt["mats"]["A"])).max() for pt in pts])
    tuned = [pt for pt, r in zip(pts, rho) if r < 1.0] or pts   # the metric's points
    if len(tuned) < len(pts):
        log(f"warning: {len(pts) - len(tuned)} of {len(pts)} dynamics points are open-loop unstable (largest "
            f"|eig A| {rho.max():.4g}): their estimation error has no steady state to rank tuners by, so they "
            "are left out of the tuner metric (the gains there are still computed)")
    _warn_unseen(tuned, names["h"], np.sqrt(np.diag(Ph)), log)
    bar = Progress("tuners", 1, progress)
    V, metric, mse, ranking = select_subset(tuned, n_tuners, Ph, targets,
                                            lambda d, n: (setattr(bar, "total", n), bar.update(d)),
                                            executor=executor)
    bar.finish()
    subset_metric = metric
    q_names = [names["h"][int(np.argmax(r))] for r in V]
    log(f"tuners (subset, n = {n_tuners}): {', '.join(q_names)}; metric {metric:.4g}" + (
        "; runner-up " + ", ".join(f"{[names['h'][j] for j in S]} {m:.4g}" for m, S in ranking[1:3])
        if len(ranking) > 1 else ""))
    left = [h for h in names["h"] if h not in q_names]
    if method == "subset" and left:
        log(f"not estimated: {', '.join(left)} (no tuner: its estimate stays 0, a change of it is read in "
            "the tuners; the tuner metric weighs that error)")
    if method == "optimal":
        bar = Progress("optimal", 40, progress)
        V, metric, mse = optimal_tuners(tuned, V, Ph, targets, progress=lambda d, n: bar.update(d),
                                        executor=executor)
        bar.finish()
        q_names = [f"q{j + 1}" for j in range(n_tuners)]
        log(f"optimal tuners: metric {metric:.4g} (best subset {subset_metric:.4g})")
    Vp = np.linalg.pinv(V)
    na = nx + n_tuners
    n = len(pts)
    K, P, Q, R = np.zeros((n, na, ny)), np.zeros((n, na, na)), np.zeros((n, na, na)), np.zeros((n, ny, ny))
    ok = np.ones(n, bool)
    errs = {}
    for i, pt in enumerate(pts):
        aug = augment(pt["mats"], Vp)
        Q[i, :nx, :nx] = pt["Qx"]
        Q[i, nx:, nx:] = V @ pt["Qh"] @ V.T
        R[i] = pt["R"]
        try:
            K[i], P[i] = steady_state_gain(aug["A"], aug["C"], Q[i], R[i], where=f"dynamics point {i}")
        except GainError as e:
            ok[i] = False
            errs[i] = str(e)
    ok &= np.asarray(dyn_status).reshape(-1) == COMPUTED  # a replaced point takes its donor's gain
    donor = nearest_good(dg, ok)
    if (donor < 0).any():
        raise BuildError(f"no dynamics point has a usable Kalman gain: {errs}")
    for i in np.flatnonzero(~ok):
        K[i], P[i], Q[i], R[i] = K[donor[i]], P[donor[i]], Q[donor[i]], R[donor[i]]
    donor[ok] = -1
    if errs:
        log(f"kalman: {len(errs)} gains replaced by the nearest good point: {errs}")
    K_out, out_status, out_h_ratio = sensor_out_gains([augment(pt["mats"], Vp) for pt in pts], Q, R,
                                                      Vp, dg, ok, names["y"], log)
    return {"V": V, "q_names": q_names, "metric": metric, "subset_metric": subset_metric,
            "rms_error": {every[t]: float(np.sqrt(m)) for t, m in zip(targets, mse)},
            "K": K, "P": P, "Q": Q, "R": R, "status": np.where(ok, COMPUTED, REPLACED).astype(np.int8),
            "donor": donor, "K_out": K_out, "out_status": out_status, "out_h_ratio": out_h_ratio}


def health_std(P, V_pinv, nx: int) -> np.ndarray:
    """Standard deviation (nh,) of the health estimates h = h_ref + V_pinv q under the augmented
    error covariance P (na, na) whose tuner block is P[nx:, nx:]."""
    return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", V_pinv, P[nx:, nx:], V_pinv), 0.0))


#: largest stored health std ratio (a parameter a sensor-out set cannot see at all)
RATIO_CAP = 1e6


def sensor_out_gains(aug, Q, R, V_pinv, dg, usable, sensors, log=print):
    """Steady-state gains for every sensor-out set (all sensors but one), so that the runtime
    keeps updating from the others when one sensor is missing (a dead thermocouple), and how much
    each health parameter's observability suffers without that sensor.

    aug: per dynamics point (flat order) the augmented system (A, C of :func:`augment`); Q (n, na,
    na), R (n, ny, ny) its noise covariances; V_pinv (nh, nq); usable (n,) bool: points whose
    full gain was computed (the others take their donor's). Returns K_out (ny, n, na, ny) -- K_out[j] the update gain without sensor j, its
    column j zero --, out_status (ny, n) int8: COMPUTED, REPLACED (the nearest point's gain
    without that sensor) or OUT_NONE (no point can do without sensor j: the tuners are not
    detectable without it; the runtime then skips the update), and out_h_ratio (ny, n, nh): the
    steady-state standard deviation of each health estimate without sensor j over its value with
    all sensors (1: that sensor adds nothing to it; at most RATIO_CAP; 0 where OUT_NONE): the
    runtime holds the health estimates while a sensor they depend on is out
    (``pwl.runtime.HEALTH_HOLD_RATIO``).
    Cost: ny more Riccati solves per point, ny times the size of /kalman/K in the file."""
    ny, n = R.shape[-1], len(aug)
    na = Q.shape[-1]
    nx = na - V_pinv.shape[1]
    K_out = np.zeros((ny, n, na, ny))
    status = np.full((ny, n), OUT_NONE, dtype=np.int8)
    ratio = np.zeros((ny, n, V_pinv.shape[0]))
    s_all = np.zeros((n, V_pinv.shape[0]))
    for i in np.flatnonzero(usable):
        s_all[i] = health_std(steady_state_gain(aug[i]["A"], aug[i]["C"], Q[i], R[i])[1], V_pinv, nx)
    for j in range(ny):
        keep = np.arange(ny) != j
        ok = np.zeros(n, bool)
        for i in np.flatnonzero(usable):
            try:
                K_out[j, i][:, keep], Pj = steady_state_gain(aug[i]["A"], aug[i]["C"][keep], Q[i],
                                                             R[i][np.ix_(keep, keep)])
            except GainError:
                continue
            ok[i] = True
            s = health_std(Pj, V_pinv, nx)   # a parameter no tuner reaches has 0 / 0: ratio 1
            r = np.where(s_all[i] > 0, s / np.where(s_all[i] > 0, s_all[i], 1.0), 1.0)
            ratio[j, i] = np.nan_to_num(np.minimum(r, RATIO_CAP), nan=RATIO_CAP)   # stored finite
        donor = nearest_good(dg, ok)
        if (donor < 0).all():
            log(f"kalman: without sensor {sensors[j]} no point has a detectable gain "
                "(the runtime skips the update when it is missing)")
            continue
        K_out[j], ratio[j] = K_out[j][donor], ratio[j][donor]
        status[j] = np.where(ok, COMPUTED, REPLACED)
        for i in np.flatnonzero(~ok):   # a donor's gain must stabilize this point too
            closed = (np.eye(na) - K_out[j, i] @ aug[i]["C"]) @ aug[i]["A"]
            if not np.abs(np.linalg.eigvals(closed)).max() < 1.0:
                K_out[j, i], ratio[j, i] = 0.0, 0.0
                status[j, i] = OUT_NONE
        if (~ok).any():
            none = int((status[j] == OUT_NONE).sum())
            log(f"kalman: without sensor {sensors[j]}: {int((~ok).sum()) - none} of {n} gains from "
                f"the nearest point, {none} points without (no update there when it is missing)")
    return K_out, status, ratio


def with_sensor_out_gains(db: GainDatabase, log=print) -> GainDatabase:
    """A copy of ``db`` with sensor-out gains (:func:`sensor_out_gains`) from its stored matrices
    and noise covariances: for databases built before they existed (``pwl regain``-free upgrade;
    every other dataset unchanged)."""
    import dataclasses

    dg = db.dyn_grid
    n, na, ny = dg.size, db.na, db.n("y")
    flat = {m: db.dynamics[m].reshape((n,) + db.dynamics[m].shape[dg.ndim:]) for m in "ABCDFGLMN"}
    aug = [augment({m: flat[m][i] for m in flat}, db.tuner["V_pinv"]) for i in range(n)]
    usable = db.kalman_status.reshape(-1) == COMPUTED
    K_out, st, ratio = sensor_out_gains(aug, db.kalman["Q"].reshape(n, na, na),
                                        db.kalman["R"].reshape(n, ny, ny), db.tuner["V_pinv"], dg, usable,
                                        db.names["y"], log)
    kalman = dict(db.kalman, K_out=K_out.reshape((ny,) + dg.shape + (na, ny)),
                  out_status=st.reshape((ny,) + dg.shape), out_h_ratio=ratio.reshape((ny,) + dg.shape + (-1,)))
    return dataclasses.replace(db, kalman=kalman)


def kalman_arrays(fd: dict, D: tuple) -> dict:
    """The /kalman datasets of a database from :func:`design_filter`'s flat arrays (points ->
    dynamics grid shape D)."""
    out = {k: fd[k].reshape(D + fd[k].shape[1:]) for k in ("K", "P", "Q", "R")}
    ny = fd["K_out"].shape[0]
    out["K_out"] = fd["K_out"].reshape((ny,) + D + fd["K_out"].shape[2:])
    out["out_status"] = fd["out_status"].reshape((ny,) + D)
    out["out_h_ratio"] = fd["out_h_ratio"].reshape((ny,) + D + fd["out_h_ratio"].shape[2:])
    return out


def point_label(grid, p) -> str:
    """'alt=3000, Mach=0.4, ...' for messages and the failure lists stored in the database."""
    return ", ".join(f"{n}={float(v):g}" for n, v in zip(grid.names, p))


def _targets(targets, names, where):
    """Indices into [h; z] of the tuner-selection targets ("h" = every health parameter)."""
    nh = len(names["h"])
    out = []
    for t in targets:
        if t == "h":
            out += list(range(nh))
        elif t in names["h"]:
            out.append(names["h"].index(t))
        elif t in names["z"]:
            out.append(nh + names["z"].index(t))
        else:
            raise SpecError(f"{where}: [tuners] target {t!r} is neither 'h' nor a health or "
                            f"unmeasured-output name")
    return list(dict.fromkeys(out))


def _trims(spec, ref, who, names, h0, executor, parts, progress, span=0.0):
    """Phase 1: trims on the trim grid, one task per power line; failed trims filled along it.

    With ``span`` > 0 also the ambient terms (:func:`ambient_terms`): ``ambient_<kind>`` (grid shape +
    (2, n)), filled along the power line like the trims where neither day converged (zero on a line
    without any: that line's trims do not move with the ambient; counted in the build log).

    Returns (trims x, u, y, z (grid shape + (n,)) [and ambient_x..z], status, {point label:
    reason} of failures, the number of points without an ambient day of their own)."""
    tg = spec.trim_grid
    pa = tg.names.index(spec.power_axis)
    nodes = tg.nodes().reshape(tg.shape + (tg.ndim,))
    other = [s for j, s in enumerate(tg.shape) if j != pa]
    n = tg.shape[pa]
    trim = {k: np.full(tg.shape + (len(names[k]),), np.nan) for k in "xuyz"}
    keys = list("xuyz")
    if span > 0.0:
        keys += [f"ambient_{k}" for k in "xuyz"]
        trim |= {f"ambient_{k}": np.full(tg.shape + (2, len(names[k])), np.nan) for k in "xuyz"}
    ok = np.zeros(tg.shape, bool)
    errors = {}
    lines = {}
    for oi in np.ndindex(*other):
        idx = list(oi)
        idx.insert(pa, slice(None))
        lines["trim_" + "_".join(map(str, oi))] = tuple(idx)
    bar = Progress("trims", len(lines), progress)

    def record(sl, out, errs):
        """Results of one power line, in grid order."""
        for k in keys:
            trim[k][sl] = out[k]
        for j, e in enumerate(errs):
            node = list(sl)
            node[pa] = j
            ok[tuple(node)] = not e
            if e:
                label = point_label(tg, nodes[tuple(node)])
                errors[label] = _reason(label, e)

    def store(name, res):
        if isinstance(res, Exception):  # the task itself died: every point failed
            record(lines[name], {k: np.full((n,) + trim[k].shape[len(tg.shape):], np.nan) for k in keys},
                   [res] * n)
            return
        out, errs = res  # solved from the top of the power axis down: reverse to grid order
        out = {k: out[k][::-1] for k in keys}
        errs = list(errs)[::-1]
        if not any(errs):  # a line with a failure is solved again by a resumed build
            parts.put(name, out)
        record(lines[name], out, errs)

    tasks = []
    for name, sl in lines.items():
        got = parts.get(name)
        if got is not None:
            record(sl, got, [""] * n)
        else:  # from the top of the power axis down: trims converge best near design power
            tasks.append((name, (ref, nodes[sl][::-1], h0, spec.dt, span)))
    if len(tasks) < len(lines):
        notice(f"resuming: reusing {(len(lines) - len(tasks)) * n} of {tg.size} trim points from {parts.dir}/" + RESUME_NOTE)
        bar.update(len(lines) - len(tasks))
    _run(executor, trim_line, tasks, bar, store)
    errors = _in_order(errors, tg, tg.nodes())

    if not ok.any():
        raise BuildError(f"{who}: every trim failed ({tg.size} points), e.g. at {next(iter(errors.values()))}")
    status = np.zeros(tg.shape, np.int8)
    power = tg.axes[pa].values
    no_ambient = 0
    for sl in lines.values():
        if not ok[sl].any():
            first = errors[point_label(tg, nodes[sl][0])]
            raise BuildError(f"{who}: no trim converged on the power line {_line_label(tg, pa, nodes[sl][0])} "
                             f"({n} points), e.g. at {first}")
        for k in "xuyz":
            trim[k][sl], st = fill_line(trim[k][sl], ok[sl], power)
        status[sl] = st
        for k in keys[4:]:
            a = trim[k][sl].reshape(n, -1)
            good = np.isfinite(a).all(axis=1)
            if k == keys[4]:
                no_ambient += int(n - good.sum())
            trim[k][sl] = (fill_line(a, good, power)[0] if good.any() else np.zeros_like(a)).reshape(trim[k][sl].shape)
    return trim, status, errors, no_ambient


def ambient_span(plant, spec: BuildSpec, grid, log=print) -> float:
    """The ISA offset (K) the build trims hot and cold days at: ``spec.ambient_span`` for a plant
    whose trims can follow the day's ambient at run time (:func:`linearize.plant.ambient_axes`)
    and whose inlet temperature gives back the day's offset by the runtime's formula
    (:func:`pwl.airdata.ambient_offset`, checked at every trim-grid node within 0.1 K); else 0, with
    a log line saying why when the spec asked for it."""
    span = float(spec.ambient_span)
    if span <= 0.0:
        return 0.0
    axes = proto.ambient_axes(plant)
    if axes is None:
        return 0.0
    t_std = float(plant.correction.get("T_std", 288.15))
    worst = 0.0
    for p in grid.nodes():
        for dT in (span, -span):
            theta, _ = plant.theta_delta(proto.day_environment(plant, p, dT))
            worst = max(worst, abs(float(ambient_offset(theta * t_std, p[axes[0]], p[axes[1]])) - dT))
    if worst > 0.1:
        log(f"ambient: no hot/cold-day trims: the plant's inlet temperature on a day {span:g} K off ISA "
            f"gives the day's offset {worst:.2g} K off by the runtime's formula (ISA, ram rise gamma 1.4)")
        return 0.0
    return span


def inlet_recovery(plant, grid, log=print) -> float:
    """The plant's inlet total-pressure recovery: its inlet pressure over the full ram rise of
    pressure altitude and Mach (:func:`pwl.airdata.inlet_pressure`) on the standard day, the median
    over the trim grid's nodes (for a plant with the ambient axes, :func:`ambient_span`); logged
    with its spread. A log without the inlet pressure takes it from altitude and Mach with it."""
    axes = proto.ambient_axes(plant)
    p_std = float(plant.correction.get("P_std", 101325.0))
    r = np.array([plant.theta_delta(plant.environment(p))[1] * p_std / float(inlet_pressure(p[axes[0]], p[axes[1]]))
                  for p in grid.nodes()])
    rec = float(np.median(r))
    log(f"inlet: pressure recovery {rec:.4f} ({r.min():.4f}-{r.max():.4f} over the trim grid): a log without "
        "the inlet pressure takes it from altitude and Mach")
    return rec


def _in_order(errors: dict, grid, points) -> dict:
    """``errors`` (point label -> reason) in the order of ``points`` (results arrive in any order)."""
    labels = (point_label(grid, p) for p in points)
    return {label: errors[label] for label in labels if label in errors}


def _line_label(grid, axis: int, p) -> str:
    """'alt=0, Mach=0.4' of a line along ``axis`` through point ``p``."""
    keep = [j for j in range(grid.ndim) if j != axis]
    return ", ".join(f"{grid.names[j]}={float(p[j]):g}" for j in keep)


def dynamics_hold(spec, p_names) -> dict:
    """Scheduling variables the dynamics grid leaves out -> the value they are linearized at.

    The dynamics grid's axes must be some of the plant's scheduling variables, in order; the
    others are held (``[build] dynamics_hold``, default: the middle of the trim grid's axis).
    The runtime then schedules the matrices and gains on the dynamics axes only: fewer corners
    per step, for variables the corrected dynamics hardly depend on."""
    dn = list(spec.dyn_grid.names)
    if [p for p in p_names if p in dn] != dn:
        raise SpecError(f"{spec.path}: [dynamics_grid] axes {dn} must be scheduling variables of the plant, "
                        f"in the order {list(p_names)}")
    extra = set(spec.dynamics_hold) - (set(p_names) - set(dn))
    if extra:
        raise SpecError(f"{spec.path}: [build] dynamics_hold names {sorted(extra)}, which are not scheduling "
                        f"variables left out of [dynamics_grid]")
    tg = spec.trim_grid
    return {p: float(spec.dynamics_hold.get(p, 0.5 * (tg.axes[j].lo + tg.axes[j].hi)))
            for j, p in enumerate(p_names) if p not in dn}


def full_points(dg, p_names, hold) -> np.ndarray:
    """Every dynamics grid node as a full scheduling point (size, len(p_names)): held variables
    at their ``hold`` value."""
    nodes = dg.nodes()
    out = np.empty((dg.size, len(p_names)))
    for j, p in enumerate(p_names):
        out[:, j] = nodes[:, dg.names.index(p)] if p in dg.names else hold[p]
    return out


def _dynamics(spec, ref, who, names, h0, trim, hold, executor, parts, progress):
    """Phase 2. ``trim`` (physical units) gives each dynamics point a warm start.

    Returns (stacked results with status and donor, {point label: reason} of failures)."""
    tg, dg = spec.trim_grid, spec.dyn_grid
    t_nodes = tg.normalized(tg.nodes())
    d_nodes = full_points(dg, names["p"], hold)
    keys = ("trim_x", "trim_u", "trim_y", "trim_z") + tuple("ABCDFGLMN")
    res = [None] * dg.size
    errors = {}
    bar = Progress("dynamics", dg.size, progress)
    tasks = []
    for i, p in enumerate(d_nodes):
        res[i] = parts.get(f"dyn_{i}")
        if res[i] is None:
            j = int(np.argmin(((t_nodes - tg.normalized(p[None, :])) ** 2).sum(-1)))
            guess = {k: trim[k].reshape(tg.size, -1)[j] for k in "xuyz"}
            tasks.append((i, (ref, p, h0, guess, spec.dt, spec.differences, spec.perturbation)))
    if len(tasks) < dg.size:
        notice(f"resuming: reusing {dg.size - len(tasks)} of {dg.size} dynamics points from {parts.dir}/" + RESUME_NOTE)
        bar.update(dg.size - len(tasks))

    def store(i, r):
        if isinstance(r, Exception):  # a failed point is computed again by a resumed build
            label = point_label(tg, d_nodes[i])
            errors[label] = _reason(label, r)
        else:
            res[i] = r
            parts.put(f"dyn_{i}", {k: np.asarray(v) for k, v in r.items()})

    _run(executor, dynamics_point, tasks, bar, store)
    errors = _in_order(errors, tg, d_nodes)
    good = np.array([r is not None for r in res])
    if not good.any():
        raise BuildError(f"{who}: no dynamics point could be linearized ({dg.size} points), "
                         f"e.g. at {next(iter(errors.values()))}")
    donor = nearest_good(dg, good)
    out = {k: np.stack([res[donor[i]][k] for i in range(dg.size)]) for k in keys[4:]}
    out["point"] = [{k: res[donor[i]][k] for k in keys[:4]} for i in range(dg.size)]
    out["status"] = np.where(good, COMPUTED, REPLACED).astype(np.int8)
    donor[good] = -1
    out["donor"] = donor
    return out, errors


@threads.one_blas_thread
def retune(db: GainDatabase, *, n_tuners: int, method: str = "subset", targets=("h",),
           q_x=None, q_h=1e-4, health_sigma=0.02, progress: bool = False, log=print) -> GainDatabase:
    """A copy of ``db`` with new tuners and gains, from its stored matrices and covariances:
    phases 3-4 without the plant. Sensor noise as stored; state noise as stored or from ``q_x``
    (fraction of the trim value per step), tuner noise from ``q_h``."""
    import dataclasses

    from pwl.interp import interpolate

    names = {k: db.names[k] for k in ("x", "u", "y", "z", "h")}
    dg, nx = db.dyn_grid, db.n("x")
    pts_full = full_points(dg, db.names["p"], db.attrs.get("dynamics_hold", {}))
    z_trim = interpolate(db.trim_grid, db.trim["z"], pts_full)
    x_trim = interpolate(db.trim_grid, db.trim["x"], pts_full)
    q_h = per_channel(q_h, names["h"], "q_h", db.path)
    Qx = db.kalman["Q"].reshape(dg.size, nx + db.n("q"), -1)[:, :nx, :nx]
    if q_x is not None:
        Qx = np.stack([np.diag((per_channel(q_x, names["x"], "q_x", db.path) * np.abs(x)) ** 2)
                       for x in x_trim])
    pts = [{"mats": {m: db.dynamics[m].reshape((dg.size,) + db.dynamics[m].shape[dg.ndim:])[i]
                     for m in "ABCDFGLMN"},
            "Qx": Qx[i],
            "Qh": np.diag(q_h ** 2),
            "R": db.kalman["R"].reshape(dg.size, db.n("y"), -1)[i],
            "z_scale": np.maximum(np.abs(z_trim[i]), 1e-9)} for i in range(dg.size)]
    fd = design_filter(pts, names, dg, db.dyn_status, n_tuners, method,
                       np.diag(per_channel(health_sigma, names["h"], "health_sigma", db.path, positive=True) ** 2),
                       _targets(targets, names, db.path), progress, log)
    D = dg.shape
    attrs = dict(db.attrs, tuner_method=method, tuner_metric=fd["metric"],
                 tuner_subset_metric=fd["subset_metric"], tuner_rms_error=fd["rms_error"],
                 tuner_targets=list(fd["rms_error"]), retuned={"q_h": q_h.tolist(), "n": n_tuners})
    return dataclasses.replace(
        db, names={**db.names, "q": fd["q_names"]}, units={**db.units, "q": ["-"] * n_tuners},
        tuner={"V": fd["V"], "V_pinv": np.linalg.pinv(fd["V"]), "h_ref": db.tuner["h_ref"]},
        kalman=kalman_arrays(fd, D),
        kalman_status=fd["status"].reshape(D), kalman_donor=fd["donor"].reshape(D), attrs=attrs)
