"""Fleet gas-path diagnostics: detect, isolate and size a fault from per-flight steady snapshots.

Per engine, every flight's longest steady snapshot (:mod:`pwl.snapshots`) is reduced to relative
deviations d from the trim at its measured operating point, with signature columns S for every
health parameter and sensor bias (:mod:`pwl.fleet.signatures`). Over the flights 0..k seen so far:

    d_j = a + b t_j + f_j(tau) S_c theta + e_j,     e_j ~ N(0, Sigma)

with a the engine's own level (engine-to-engine scatter and model offset, never needed) and b its
own wear line (normal wear; ``DiagnosisConfig.wear``), f the shape of the change (a step
1[j >= tau], or a ramp max(0, j - tau + 1) for a drift starting after the first flights), c one
hypothesis of a fixed bank (one component's efficiency and flow; two components; a component
and a sensor; one sensor or the fuel-flow measurement) and theta its size. After whitening with Sigma and projecting out
the level, the generalised likelihood ratio of hypothesis c at change point tau is
T_c = |P_c v|^2 with v the whitened change estimate: chi-square with rank(c) degrees of freedom
when nothing changed.

- **Change point**: the tau and shape with the largest likelihood gain of an unconstrained
  change (T saturates under the signature uncertainty for large changes). Wear faster than
  ``min_rate`` per flight from the first flight on is tested separately (the wear line itself,
  level-only ramp) when no step or late drift is found.
- **Detection** at flight k: the chi-square p-value of the chosen change, times the number of
  change points, shapes and hypotheses tested (Bonferroni), below ``alpha``; and a change of at least
  ``min_step`` (relative deviation, norm over channels) so that tiny but significant model
  effects do not flag. Recomputed on the whole history each flight: a persistent fault stays
  flagged.
- **Isolation**: the hypothesis maximising T_c - kappa * rank(c) at that change point (a fixed
  cost per free parameter, plus ``pair_cost`` for two components, so a sensor bias is not read
  as a two-parameter component change that fits it equally well); confidence = its share of exp((T - kappa * rank) / 2) over the bank.
- **Sizing**: theta with its standard error from the same least squares.
- **Drift**: a ramp that wins is reported as kind ``drift`` with its rate per flight.
- **Wear**: in a fleet, the whole-history ramp is tested against the fleet's normal wear
  (:func:`wear_reference`) instead of ``min_rate``: kind ``wear``, its rate beyond the fleet's.
  Each engine's rate in it is fitted off its own steps, so a change most engines show alike at
  one flight or over a few (a fleet-wide recalibration or a software update rolled out:
  :func:`common_steps`, named in a warning) is not wear; it is a nuisance of the tests of each
  engine that changed alike, not its fault. A sensor is named for a trend from the first flight only
  when the components' wear does not fit it better (:func:`_component_wear`).
- **Sensor episodes**: a sensor bias that goes away is ``cleared`` (not a fault), one that comes
  back is ``intermittent`` (:func:`_episodes`), judged flight by flight against the sensor's
  reading before its first step; one whose readings scatter more since some flight is
  ``erratic`` (:func:`_erratic`).
- **Recovery**: a component step whose efficiencies all rise (a compressor wash, a repair) is
  not a fault: status and kind ``recovery``, ``detected`` 0. From its onset on the engine is
  diagnosed on a new baseline (the flights before it are left out), so that a later fault is
  measured from the recovered level, unless it left part of a fault found before it (a
  partial repair, a wash of another component: :func:`_remaining`), which later rows still
  report. A sensor bias that came with it is a fault, never maintenance (:func:`_sensor_part`).
- **Level**: in a fleet, an engine whose first flights are off the fleet's normal baseline
  (:func:`level_reference`) and which changed no further is kind ``level``, onset its first
  flight: a component delivered with a defect, or a sensor calibrated off. A sensor's offset is
  constant in its raw unit, so its relative deviation moves with each flight's operating point;
  that moving part is taken out of every test of the engine (:func:`_calibration`).
- **History**: a finding confirmed on two flights (a step, a drift, a level, a wear) stays
  named in ``earlier`` on the rows of a later fault, and a step or drift is a nuisance of the
  tests for it.

Sigma, the flight-to-flight scatter of a snapshot's deviations (sensor noise averaged over the
window plus the model's interpolation error at changing conditions), is estimated from the data:
for a fleet, robustly from successive flight differences pooled over engines (big changes are
trimmed); for one engine from its own differences, with a floor. An engine that scatters more
than the fleet is tested against its own scatter (:func:`own_scatter`: without its sensors' toggles,
at most OWN_MAX times the fleet's, a warning above OWN_WARN). docs/diagnostics.md gives the
equations, the false-alarm design and the benchmark.
"""
from __future__ import annotations

import csv
import os
import re
import warnings
from concurrent.futures import as_completed
from copy import copy
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from typing import NamedTuple

import h5py
import numpy as np
from scipy import optimize, stats

from ..database import GainDatabase
from ..errors import PwlWarning
from ..formats import RESULTS, check
from ..h5io import SealError, attr_str, check_seal
from .scoring import few
from .signatures import DiagnosisError, Signatures
from ..snapshots import Snapshots
from ..workers import SerialExecutor


@dataclass(frozen=True)
class DiagnosisConfig:
    """Settings of the detector (documented in docs/diagnostics.md).

    alpha: family-wise false-alarm probability per engine and flight; kappa: cost per free
    parameter in isolation; n_base: testing starts with n_base + 1 flights (a change may be at any flight but the first);
    min_step: smallest change reported (norm of the relative deviation change); min_rate: smallest
    drift reported (per flight, same norm; a sensor's drift from after the first flights tested
    is held to min_step accumulated only); floor: smallest flight-to-flight scatter assumed per
    channel (relative); wear_engines, wear_flights: a fleet of at least wear_engines engines
    with wear_flights complete flights each gives the normal wear its engines are tested against
    (:func:`wear_reference`); eps: relative uncertainty of the signatures per channel;
    curvature: a component's loss's second-order error in every channel, per unit of the mean
    square of its change over the channels (:func:`_curved`); pairs: also test
    changes of two causes (two components, a component and a sensor), at an extra cost ``pair_cost`` (a combined fault is rarer than a single
    one, and must explain more than a large single fault's nonlinearity); wear: the engine's own
    wear line is a nuisance of the step tests (normal wear is not a fault), held to the fleet's
    when the fleet gives a wear reference (:func:`_held_slope`); rollout: a change of
    the whole fleet may be rolled out over this many consecutive flights (:func:`common_steps`);
    level_floor: the engine-to-engine spread of what health does not explain in a baseline level is
    taken as at least this many times each channel's flight-to-flight scatter (:func:`level_reference`);
    window: a new change is looked for at the latest ``window`` flights, fitted on them (a change
    further back that no test found in as many flights after it is below what the data show; wear
    is no straight line over hundreds of flights, :func:`_stages`; a flight's tests cost in
    proportion)."""

    alpha: float = 1e-3
    kappa: float = 6.0
    n_base: int = 3
    min_step: float = 0.002
    min_rate: float = 0.001
    wear_engines: int = 8
    wear_flights: int = 8
    floor: float = 2e-4
    eps: float = 0.1
    curvature: float = 4.0
    pairs: bool = True
    pair_cost: float = 10.0
    wear: bool = True
    rollout: int = 4
    level_floor: float = 2.0
    window: int = 50


@dataclass
class Hypothesis:
    name: str
    columns: list[int]

    def cost(self, cfg: "DiagnosisConfig") -> float:
        """Isolation cost: kappa per free parameter, plus pair_cost for a two-component change."""
        return cfg.kappa * len(self.columns) + (cfg.pair_cost if "+" in self.name else 0.0)


def component(column: str) -> str:
    """The component a health column belongs to: the name before its last ``_`` (fan_eff -> fan)."""
    return column.rsplit("_", 1)[0] if "_" in column else column


def single_sensor(cls: str) -> bool:
    """Whether a class names one sensor's bias (``sensor:T48``; not ``sensor:T48+sensor:Ps30``)."""
    return cls.startswith("sensor:") and "+" not in cls


def sensor_pair(cls: str) -> bool:
    """Whether a class names two sensors' biases (``sensor:Ps30+sensor:T48``)."""
    return cls.startswith("sensor:") and "+" in cls


def _testable(h: Hypothesis, S: np.ndarray) -> bool:
    """Whether the channels of signatures S (m, ncol) can test ``h``: each of its columns moves
    one of them (a bias of a sensor without data cannot be tested)."""
    return bool(np.linalg.norm(S[:, h.columns], axis=0).min() > 1e-9)


def hypotheses(columns: list[str], pairs: bool = True) -> list[Hypothesis]:
    """The bank: one component (all its health parameters, grouped by the name before the last
    ``_``: fan_eff, fan_flow -> fan), every pair of components, every component with every sensor
    bias (``hpt+sensor:T30``), every sensor bias (pairs of sensors: :func:`sensor_pairs`)."""
    comps: dict[str, list[int]] = {}
    out = []
    for j, c in enumerate(columns):
        if c.startswith("sensor:"):                # with its gain column, if it has one
            out.append(Hypothesis(c, [j] + [i for i, g in enumerate(columns) if g == f"gain:{c[7:]}"]))
        elif not c.startswith("gain:"):
            comps.setdefault(component(c), []).append(j)
    bank = [Hypothesis(k, v) for k, v in comps.items()]
    if pairs:
        keys = list(comps)
        bank += [Hypothesis(f"{a}+{b}", comps[a] + comps[b]) for i, a in enumerate(keys) for b in keys[i + 1:]]
        bank += [Hypothesis(f"{a}+{h.name}", comps[a] + h.columns) for a in keys for h in out]
    return bank + out


def sensor_pairs(bank: list[Hypothesis]) -> list[Hypothesis]:
    """Every pair of the sensor biases of ``bank`` (``sensor:Ps30+sensor:T48``): two biases at once
    (one ground-station calibration, one harness) read as one bias and a component, or as a
    'recovery'. They isolate steps and drifts, never detect (:func:`_decide`), and are tried there
    only: not for wear or a level from the first flight (two sensors drifting from delivery
    fitted an engine wearing every component as well as the components)."""
    one = [h for h in bank if single_sensor(h.name)]
    return [Hypothesis(f"{a.name}+{b.name}", a.columns + b.columns) for i, a in enumerate(one) for b in one[i + 1:]]


# ---- reading results ----------------------------------------------------------------------------
@dataclass
class FlightRecord:
    """One flight of one engine: where it came from, its order key and its chosen snapshot."""

    engine: str
    order: tuple
    source: str
    label: str
    snapshot: Snapshots
    database: str | None = None
    database_digest: str = ""
    mode: str = ""
    windows: dict = field(default_factory=dict)     # regime -> window index (assign_regimes)
    unplaced: list = field(default_factory=list)    # windows in no regime (assign_regimes)

    @property
    def time(self) -> float:
        """The flight time in seconds (:func:`flight_seconds`; NaN when missing or unreadable)."""
        return flight_seconds(self.order[0])

    @property
    def index(self) -> int:
        """The log's flight_index (-1 when none)."""
        return self.order[1]


def _natural(s: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


#: date-times that ISO 8601 (datetime.fromisoformat) does not read but data systems write; day
#: first or month first (01/02/2026) is ambiguous and is not read
_TIME_FORMATS = ("%Y-%m-%d %H:%M", "%Y-%m-%d %H:%M:%S", "%Y-%m-%d %H:%M:%S.%f", "%Y/%m/%d", "%Y/%m/%d %H:%M",
                 "%Y/%m/%d %H:%M:%S")


def flight_seconds(text: str) -> float:
    """A flight_time attribute as seconds: a number as it is (a counter, seconds), a date-time
    (ISO 8601, or :data:`_TIME_FORMATS`; without a zone taken as UTC) as seconds since 1970;
    NaN when empty or unreadable. Compared as text, '9:30' came after '14:45', 500 after 14500
    and float seconds or day-first dates across months out of order."""
    from datetime import datetime, timezone
    text = str(text).strip()
    if not text:
        return float("nan")
    try:
        v = float(text)
        return v if np.isfinite(v) else float("nan")
    except ValueError:
        pass
    for parse in [datetime.fromisoformat] + [lambda t, f=f: datetime.strptime(t, f) for f in _TIME_FORMATS]:
        try:
            t = parse(text.replace("Z", "+00:00"))
        except ValueError:
            continue
        return (t if t.tzinfo else t.replace(tzinfo=timezone.utc)).timestamp()
    return float("nan")


def in_flight_order(flights: list[FlightRecord]) -> tuple[list[FlightRecord], str]:
    """One engine's flights in time order, and a note ("" when none) when the order had to be
    chosen: by flight time (:func:`flight_seconds`) when every flight has a readable one, then
    flight_index, then the file name in natural order (flight_2 before flight_10); else by
    flight_index when every flight has a distinct one; else by file name. The note names flights
    without a readable time, and a flight time order that contradicts flight_index."""
    def nat(r):
        return _natural(os.path.basename(r.source))
    times = [r.time for r in flights]
    idx = [r.index for r in flights]
    indexed = min(idx, default=0) >= 0 and len(set(idx)) == len(idx)
    timeless = [r for r, t in zip(flights, times) if not np.isfinite(t)]
    if not timeless:
        out = sorted(flights, key=lambda r: (r.time, r.index, nat(r)))
        back = [(a, b) for a, b in zip(out, out[1:]) if a.index > b.index >= 0] if indexed else []
        note = (f"its flight times order {back[0][0].source} (flight_index {back[0][0].index}) before "
                f"{back[0][1].source} ({back[0][1].index}): ordered by flight time" if back else "")
        return out, note
    why = (f"{len(timeless)} of its {len(flights)} flights have no readable flight_time "
           f"({timeless[0].source}: {timeless[0].order[0]!r})")
    if indexed:
        return sorted(flights, key=lambda r: (r.index, nat(r))), (
            f"{why}: ordered by flight_index" if len(timeless) < len(flights) else "")
    some = len(timeless) < len(flights) or min(idx, default=-1) >= 0     # a time or an index to go by
    out = sorted(flights, key=nat)
    if some:
        return out, f"{why} and no distinct flight_index: ordered by file name"
    return out, (f"{NAMES_ONLY} ({os.path.basename(out[0].source)} first, {os.path.basename(out[-1].source)} last)"
                 if len(out) > 1 else "")


#: the note of an engine whose flights have neither a flight time nor a flight index
#: (:func:`in_flight_order`): before, such flights were ordered by file name without a word, and
#: files named by day-first dates (05-02-2026) put an LPC loss at the wrong flights
NAMES_ONLY = ("no flight has a flight_time or a flight_index: ordered by file name in natural order (name the "
              "files so that they sort in flight order, dates as YYYY-MM-DD, or record flight_time)")


def order_notes(records: list[FlightRecord]) -> list[str]:
    """A line for every engine whose flight order had to be chosen (:func:`in_flight_order`)."""
    out, named = [], []
    for engine, flights in group_engines(records).items():
        note = in_flight_order(flights)[1]
        if note.startswith(NAMES_ONLY):
            named.append((engine, note))
        elif note:
            out.append(f"engine {engine}: {note}")
    if len(named) == 1:
        out.append(f"engine {named[0][0]}: {named[0][1]}")
    elif named:                                   # one line for the fleet, not one per engine
        out.append(f"{len(named)} engines ({few((e for e, _ in named), 3)}): {NAMES_ONLY}")
    return out


def read_flight(path, engine_pattern: str | None = None) -> FlightRecord:
    """The engine serial, flight order and longest steady snapshot of a ``pwl run`` results file.

    Engine: the first group (or the whole match) of the regular expression ``engine_pattern``
    searched in the file name when given (``ESN\\d+`` for ``ESN012_flight_3.estimates.h5``), else
    the ``engine`` attribute (from the log), else the results file's folder name. A pattern's
    engine that contradicts the file's attribute is used, with a :class:`PwlWarning` naming both
    (a renamed file, or a pattern that picks the wrong part of the name?). Order:
    ``flight_time``, then ``flight_index``, then the file name in natural order (flight_2 before
    flight_10)."""
    path = os.fspath(path)
    named = None
    if engine_pattern:
        m = re.search(engine_pattern, os.path.basename(path))
        if m is None:
            raise DiagnosisError(f"{path}: the engine pattern {engine_pattern!r} does not match its name")
        named = m.group(1) if m.groups() else m.group(0)
    try:
        check_seal(path)
        with h5py.File(path, "r") as f:
            check(RESULTS, path, f, error=DiagnosisError)
            if "snapshots" not in f:
                raise DiagnosisError(f"{path}: has no /snapshots (results of an older pwl run: run it again)")
            snaps = Snapshots.load(f["snapshots"])
            stored = attr_str(f, "engine")
            engine = named or stored or os.path.basename(os.path.dirname(os.path.abspath(path)))
            ftime = attr_str(f, "flight_time", "")        # (a counter's 0 is a time)
            fidx = _whole(f.attrs.get("flight_index", -1), path)
            prov = [attr_str(f, k) or "" for k in ("database", "database_digest", "mode")]
    except (DiagnosisError, SealError) as e:
        raise DiagnosisError(str(e)) from None
    except Exception as e:  # h5py raises many kinds on a damaged file
        raise DiagnosisError(f"{path}: unreadable results file ({type(e).__name__}: {e})") from None
    if named and stored and named != stored:
        warnings.warn(PwlWarning(f"{path}: the engine pattern names engine {named!r}, the file's 'engine' "
                                 f"attribute {stored!r}: diagnosed as {named!r}"), stacklevel=2)
    name = os.path.basename(path)
    label = name.split(".estimates")[0]
    return FlightRecord(str(engine), (str(ftime), fidx, _natural(name)), path, label, snaps, *prov)


def whole_number(v) -> int | None:
    """A flight number (an attribute, a table cell) as an int; None when it is not a whole number
    (text such as 'F003' or 'LH400', NaN)."""
    try:
        f = float(np.asarray(v).reshape(-1)[0] if np.ndim(v) else v)
        if f == int(f):
            return int(f)
    except (TypeError, ValueError, OverflowError, IndexError):
        pass
    return None


def _whole(v, path) -> int:
    """A flight_index attribute as an int (:func:`whole_number`); -1 (none), named in a
    PwlWarning, when it is not a whole number."""
    if (n := whole_number(v)) is not None:
        return n
    warnings.warn(PwlWarning(f"{path}: flight_index {v!r} is not a whole number: ignored"), stacklevel=3)
    return -1


def serial_key(engine: str) -> str:
    """An engine serial without case, spaces and leading zeros of its numbers (ESN007, esn 007,
    ESN7): what two spellings of one serial share. A ground station dropping the zeros on some
    rows (ESN7 from flight 12) made two engines, and ESN007's Nc bias was lost in both."""
    return re.sub(r"\d+", lambda m: str(int(m.group())), "".join(engine.split()).casefold())


def engine_named(name: str, engines) -> str:
    """The engine of ``engines`` that ``name`` (given by a user) means: itself, else the one
    spelt alike but for case and spaces; ``name`` when none is."""
    if name in engines:
        return name
    alike = [e for e in engines if serial_key(e) == serial_key(name)]
    return alike[0] if len(alike) == 1 else name


def one_spelling(names: list[str], what: str = "flights") -> tuple[dict[str, str], list[str]]:
    """Engine serials that differ only in case, whitespace or leading zeros (``ESN001``, ``esn001``,
    ``ESN 001``, ``ESN1``: typed by hand, or two systems' exports) are one engine, spelt as most of ``names`` (one per
    flight, or per table row: ``what``) spell it (the first in natural order on a tie). Returns
    (spelling -> the one kept, for the serials merged; a line naming them, or none)."""
    spell: dict[str, dict[str, int]] = {}
    for e in names:
        n = spell.setdefault(serial_key(e), {})
        n[e] = n.get(e, 0) + 1
    to, merged = {}, []
    for n in spell.values():
        if len(n) > 1:
            # the zero-padded spelling (ESN007, not ESN7), then the most used
            best = min(n, key=lambda e: (-sum(map(len, re.findall(r"\d+", e))), -n[e], _natural(e)))
            to.update({e: best for e in n if e != best})
            merged.append(f"{best!r} (also {', '.join(repr(e) for e in n if e != best)}: "
                          f"{sum(v for e, v in n.items() if e != best)} of its {sum(n.values())} {what})")
    if not merged:
        return to, []
    return to, [f"{len(merged)} engine serial(s) spelt more than one way, differing only in case, spaces or leading zeros, "
                f"each read as one engine: {'; '.join(merged[:3])}{'; ...' if len(merged) > 3 else ''}"]


def same_engines(records: list[FlightRecord]) -> list[str]:
    """Give the records of one engine spelt differently one serial (:func:`one_spelling`); the
    line naming the serials so merged, or none."""
    to, out = one_spelling([r.engine for r in records])
    for r in records:
        r.engine = to.get(r.engine, r.engine)
    return out


def mixed_engines(records: list[FlightRecord]) -> list[str]:
    """A line for every engine whose flights repeat a flight index (or, without indices, a flight
    time): several engines' logs in one folder, without an ``engine`` attribute, diagnosed as one;
    or one flight exported twice (the first pair named); when every flight has a time of its own,
    they order the flights (a counter reset) and the line says so. Flight times alone may repeat
    (a date without the time of day: two flights a day)."""
    out = []
    for engine, flights in group_engines(records).items():
        indexed = all(r.index >= 0 for r in flights)
        what, key = ("flight index", lambda r: r.index) if indexed else ("flight time", lambda r: r.order[0])
        seen: dict = {}
        pairs = [(seen[k], r) for r in flights if (k := key(r)) not in ("", -1) and seen.setdefault(k, r) is not r]
        if not pairs:
            continue
        a, b = pairs[0]
        times = [r.time for r in flights]
        head = f"engine {engine}: {len(pairs)} of its {len(flights)} flights repeat another's {what} ({b.source} and {a.source})"
        if indexed and np.all(np.isfinite(times)) and len(set(times)) == len(times):
            out.append(f"{head}, each at a flight time of its own: ordered by flight time (the counter reset, or "
                       "two engines' data under one serial?)")
        elif b.mode == "table":
            out.append(f"{head}: two engines' rows under one serial, or one flight sent twice? Give each engine "
                       "its own serial; remove a flight's second copy")
        else:
            out.append(f"{head}: several engines' logs in one folder, or one flight exported twice? Give each engine "
                       "its own folder or an 'engine' attribute, or name it from the file names (--engine-pattern); "
                       "remove a flight's second export")
    return out


def assign_regimes(records: list[FlightRecord], spans, radius: float = 0.35, min_share: float = 0.3) -> np.ndarray:
    """Group the steady windows of all flights into operating regimes (e.g. ground idle, cruise).

    Operating points are scaled by ``spans`` (np,); windows are taken longest first and join the
    nearest regime within ``radius`` (scaled distance) or start a new one. Regimes seen in fewer
    than ``min_share`` of the flights are dropped. Sets each record's ``windows`` (regime ->
    its longest window there) and ``unplaced`` (its windows in no regime kept, or without an
    operating point) and returns the regime centres (R, np), lowest power first."""
    spans = np.asarray(spans, dtype=np.float64)
    wins = [(int(s), i, w) for i, r in enumerate(records) for w, s in enumerate(r.snapshot.samples)]
    wins.sort(key=lambda x: -x[0])
    centers, members = [], []
    for _, i, w in wins:
        q = records[i].snapshot.p[w] / spans
        if not np.all(np.isfinite(q)):
            continue
        dist = [np.linalg.norm(q - c) for c in centers]
        j = int(np.argmin(dist)) if dist else -1
        if j < 0 or dist[j] > radius:
            centers.append(q)
            members.append([])
            j = len(centers) - 1
        members[j].append((i, w))
    keep = [j for j in range(len(centers)) if len({i for i, _ in members[j]}) >= min_share * len(records)]
    keep.sort(key=lambda j: float(np.sum(centers[j])))
    placed = set()
    for r in records:
        r.windows = {}
    for new, j in enumerate(keep):
        for i, w in members[j]:          # longest first, so the first one seen per flight stays
            records[i].windows.setdefault(new, w)
            placed.add((i, w))
    for i, r in enumerate(records):
        r.unplaced = [w for w in range(len(r.snapshot)) if (i, w) not in placed]
    return np.array([centers[j] * spans for j in keep]).reshape(len(keep), spans.size)


# ---- one engine --------------------------------------------------------------------------------
@dataclass
class EngineSeries:
    """Deviations of one engine's flights in time order, regimes stacked: D (n, m R), SE (n, m R),
    S (n, m R, ncol) with channel names ``<channel>@<regime>``; level (n, ncol) raw-unit channel
    levels and h_hat (n, nh) filter health estimates, both at each flight's longest window."""

    engine: str
    flights: list[FlightRecord]
    channels: list[str]
    columns: list[str]
    D: np.ndarray
    SE: np.ndarray
    S: np.ndarray
    level: np.ndarray
    h_hat: np.ndarray
    h_names: list[str]
    input_names: list[str] = field(default_factory=list)
    #: values read as missing for a deviation beyond :data:`GROSS_DEVIATION`: (flight position,
    #: channel, relative deviation, raw value)
    gross: list[tuple] = field(default_factory=list)
    #: (n, m R) the snapshots' channel values as read (the database's units), for
    #: :func:`read_in_other_units`; None where not kept
    raw: np.ndarray | None = None
    #: channels read as missing on a flight for one value in every regime (:func:`_stuck_across`):
    #: (flight position, channel, value)
    stuck: list[tuple] = field(default_factory=list)


#: a channel more than this far (relative) from the model's value at its operating point is no
#: state of the engine but a unit mistake (T48 in degC: 25-29 % low, inside T48's plausible
#: range in K) or a failed sensor: read as missing and named (:func:`gross_note`). The largest
#: deviation a fault of the engine gives in the simulated fleets is 7.5 % (the 100 x 20 snapshot
#: table of seed 0, ESN010's T48; 6.5 % on the seed-11 40 x 30 one, 4.6 % on the seed-1 logs).
GROSS_DEVIATION = 0.2


def engine_series(flights: list[FlightRecord], sig: Signatures, n_regimes: int) -> EngineSeries:
    """Deviations of every flight and regime (NaN where a flight has no window in a regime, and
    where a channel is off by more than :data:`GROSS_DEVIATION`: ``gross``)."""
    flights = in_flight_order(flights)[0]
    m, ncol, R = len(sig.channels), len(sig.columns), n_regimes
    n = len(flights)
    D, SE, Y = np.full((n, m * R), np.nan), np.full((n, m * R), np.nan), np.full((n, m * R), np.nan)
    S, level = np.full((n, m * R, ncol), np.nan), np.full((n, ncol), np.nan)
    H = np.full((n, sig.db.n("h")), np.nan)
    gross = []
    for i, r in enumerate(flights):
        s = r.snapshot
        longest = -1
        for reg, w in r.windows.items():
            mean = dict(zip(s.channels, s.mean[w]))
            try:
                dev = sig.at(mean, dict(zip(s.channels, s.se[w])))
            except KeyError as e:
                raise DiagnosisError(f"{r.source}: snapshot lacks channel {e} the database needs") from None
            for j in np.flatnonzero(np.abs(dev.d) > GROSS_DEVIATION):
                gross.append((i, dev.channels[j], float(dev.d[j]), float(mean[dev.channels[j]])))
                dev.d[j] = dev.se[j] = np.nan
            cols = slice(reg * m, (reg + 1) * m)
            D[i, cols], SE[i, cols], S[i, cols] = dev.d, dev.se, dev.S
            Y[i, cols] = [mean[c] for c in dev.channels]
            if longest < 0 or s.samples[w] > s.samples[longest]:
                longest = w
                level[i] = dev.level
        if longest >= 0 and "h_hat" in s.outputs:
            H[i] = s.outputs["h_hat"][longest]
    names = [f"{c}@{reg}" for reg in range(R) for c in sig.channels]
    stuck = _stuck_across(Y, sig.channels, R)
    for i, c, _ in stuck:
        cols = [reg * m + sig.channels.index(c) for reg in range(R)]
        D[i, cols] = SE[i, cols] = np.nan
    return EngineSeries(flights[0].engine if flights else "", flights, names, list(sig.columns),
                        D, SE, S, level, H, list(sig.db.names["h"]), list(sig.db.names["u"]), gross, Y, stuck)


def _stuck_across(Y: np.ndarray, channels: list[str], R: int) -> list[tuple]:
    """(flight position, channel, value) of every channel whose snapshot value is one and the
    same in two regimes or more of a flight (Y (n, m R), raw means, regimes stacked): a live
    sensor reads idle and cruise hundreds of units apart, a stuck one (a thermocouple open, a
    frozen bus word) not. Read as it was, T48 stuck at 950 K on seven flights read HPT, LPT and
    fan changes on most of them."""
    m, out = len(channels), []
    for j, c in enumerate(channels):
        v = Y[:, [reg * m + j for reg in range(R)]]
        ok = np.isfinite(v)
        for i in np.flatnonzero(ok.sum(axis=1) >= 2):
            x = v[i, ok[i]]
            if np.all(x == x[0]):
                out.append((int(i), c, float(x[0])))
    return out


def stuck_note(series: list[EngineSeries]) -> list[str]:
    """A line per channel read as missing for one value in every regime of a flight
    (``EngineSeries.stuck``): how many flights, of which engines, from which flight, the value."""
    by: dict[str, list] = {}
    for es in series:
        for i, c, v in es.stuck:
            by.setdefault(c, []).append((es.engine, es.flights[i].label, v))
    out = []
    for c, hits in by.items():
        engines = list(dict.fromkeys(h[0] for h in hits))
        first = {e: next((h[1], h[2]) for h in hits if h[0] == e) for e in engines[:3]}
        where = few([f"{e} from {lb} ({v:.6g})" for e, (lb, v) in first.items()] + engines[3:], 3)
        out.append(f"{c}: one value in every regime (idle and cruise alike) on {len(hits)} flight(s) of "
                   f"{len(engines)} engine(s) ({where}): a stuck sensor; read as missing there, the flight's "
                   f"row 'sensor:{c} stuck' unless another fault is found")
    return out


#: a sensor that read nothing on this many of an engine's flights in a row (its latest: half as
#: many), while it read on most of its other flights, is named (:func:`dead_note`)
DEAD_FLIGHTS = 4


def dead_note(series: list[EngineSeries]) -> list[str]:
    """A line per channel that read nothing (no value as read, in any regime of flights with a
    snapshot) on :data:`DEAD_FLIGHTS` flights of an engine in a row, or on its latest half as many,
    while it read on most of the engine's other flights: a dead sensor, harness or bus word, which
    the rows only list in ``missing`` while the diagnosis runs without it. An engine without that
    sensor (another standard) reads nothing on most flights and is not named."""
    by: dict[str, list] = {}
    for es in series:
        if es.raw is None or not es.flights:
            continue
        base = [c.split("@")[0] for c in es.channels]
        flown = np.isfinite(es.raw).any(axis=1)
        pos = np.flatnonzero(flown)
        for c in dict.fromkeys(base):
            cols = [j for j, b in enumerate(base) if b == c]
            none = ~np.isfinite(es.raw[np.ix_(pos, cols)]).any(axis=1)
            if none.sum() * 2 > pos.size:
                continue
            runs, start = [], None
            for k, off in enumerate(list(none) + [False]):
                if off and start is None:
                    start = k
                elif not off and start is not None:
                    runs.append((start, k))
                    start = None
            for a, b in runs:
                if b - a >= DEAD_FLIGHTS or (b == pos.size and 2 * (b - a) >= DEAD_FLIGHTS):
                    by.setdefault(c, []).append((es.engine, es.flights[pos[a]].label, es.flights[pos[b - 1]].label,
                                                 b - a, b == pos.size))
    out = []
    for c, hits in by.items():
        where = few([f"{e} {lo} to {hi} ({k} flights{', its latest' if last else ''})" for e, lo, hi, k, last in hits], 3)
        out.append(f"{c}: no value on {len(hits)} run(s) of flights of {len({h[0] for h in hits})} engine(s) "
                   f"({where}) while it read on their other flights: a dead sensor, harness or bus word? "
                   "Those flights are diagnosed without it (their rows list it in 'missing')")
    return out


#: a flight is named as another engine's (:func:`misfiled_note`) when it is off its engine's
#: flights before it and after it beyond the chi-square point at MISFILED_ALPHA, and within the
#: point at MISFILED_NEAR of another engine's flights around it (squared whitened distances)
MISFILED_ALPHA = 1e-6
MISFILED_NEAR = 0.99
#: ... the flights before it and after it: up to this many on each side (at least 2)
MISFILED_WIDTH = 5


def _flights_near(es: EngineSeries, rows) -> tuple[np.ndarray | None, int]:
    """(the channel-wise median (m,) of the engine's flights ``rows`` that have data, or None with
    fewer than 2 of them; their number)."""
    rows = [j for j in rows if 0 <= j < es.D.shape[0] and np.isfinite(es.D[j]).any()]
    if len(rows) < 2:
        return None, len(rows)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(es.D[rows], axis=0), len(rows)


def misfiled_note(series: list[EngineSeries], Sigma: np.ndarray) -> list[str]:
    """A line per flight that is another engine's by its snapshots: off its own engine's flights
    before it and after it (beyond the chi-square point at :data:`MISFILED_ALPHA`, each) and within
    the point at :data:`MISFILED_NEAR` of another engine's flights at the same place in its history
    (a log filed in the wrong engine's folder, a table row under the wrong serial). Left as it is,
    such a flight read a fault of its engine on that flight and the next and a 'recovery' after
    them, and the engine started a new baseline there (a probe table: ESN020's flight 15 as
    ESN012's)."""
    out = []

    def dist(x, near):
        """x's squared whitened distance from a median of n flights, over its variance's share of
        one flight's (a median of n normal values varies as pi / 2n of one), and the channels."""
        ref, n = near
        ok = np.isfinite(x) & np.isfinite(ref) if ref is not None else np.zeros(x.size, bool)
        if ok.sum() < 2:
            return -np.inf, 0
        d = whitening(Sigma, np.flatnonzero(ok)) @ (x[ok] - ref[ok])
        return float(d @ d) / (1.0 + np.pi / (2.0 * n)), int(ok.sum())

    for es in series:
        for k in range(es.D.shape[0]):
            if not np.isfinite(es.D[k]).any():
                continue
            # off its own engine's flights before it and after it, each (a change between them is
            # the engine's; a flight without two after it, the latest, is not judged: a fault found
            # there and another engine's with the same fault read as that engine's)
            d_own, m = min(dist(es.D[k], _flights_near(es, range(k - MISFILED_WIDTH, k))),
                           dist(es.D[k], _flights_near(es, range(k + 1, k + 1 + MISFILED_WIDTH))))
            if not (np.isfinite(d_own) and d_own > stats.chi2.ppf(1.0 - MISFILED_ALPHA, max(m, 1))):
                continue
            best = min(((d, n, other.engine) for other in series if other is not es
                        for d, n in [dist(es.D[k], _flights_near(other, range(k - MISFILED_WIDTH, k + MISFILED_WIDTH + 1)))]
                        if n), default=(np.inf, 0, ""))
            if best[0] <= stats.chi2.ppf(MISFILED_NEAR, max(best[1], 1)):
                out.append(f"{es.flights[k].source}: engine {es.engine}'s {es.flights[k].label} is {best[2]}'s by its "
                           f"snapshots (distance {best[0]:.3g} from {best[2]}'s flights around it, {d_own:.3g} from "
                           f"{es.engine}'s): a log or row filed under the wrong engine? Diagnosed as {es.engine}'s "
                           f"(--exclude {es.engine}:{int(flight_numbers(es)[k])} leaves it out)")
    return out


#: a value off the model by more than this (beyond the largest deviation a fault gives in the
#: simulated fleets, 7.5 %: :data:`GROSS_DEVIATION`) and within UNIT_FIT of it when read in the unit
#: its channel's gross values point to is in that unit (:func:`read_in_other_units`)
UNIT_SUSPECT = 0.1
UNIT_FIT = 0.05


def read_in_other_units(series: list[EngineSeries], units: dict) -> None:
    """A unit mistake is a channel's over a stretch of flights, not a value's. Where a channel's
    gross values (``EngineSeries.gross``, any engine) point to a unit not declared
    (:func:`_gross_units`), each engine's values of it from the first to the last flight in that
    unit (off the model by more than UNIT_SUSPECT, or gross, and within UNIT_FIT of it read in
    that unit) are read as missing and added to ``gross``. T30 in degF is 6 to 28 % off the model
    in K with the operating point (degF and K meet at 575 K): written so on six healthy engines
    from flight 15 of the seed-11 table, 149 of their 180 values were under GROSS_DEVIATION and
    read as T30 faults (FPR 9.55 %). A fault's deviation (at most 7.5 % in the simulated fleets)
    starts no stretch. In place."""
    from ..units import converter
    by: dict[str, list] = {}
    for es in series:
        for _, c, d, raw in es.gross:
            by.setdefault(c, []).append((d, raw))
    def ways_of(hits, c):
        return [converter(u, units.get(c, "")) for u in _gross_units(*np.array(hits).T, units.get(c, ""))]

    def other_unit(raw, d, ways):
        """Whether values ``raw`` (relative deviations ``d``) are off and in one of ``ways``."""
        with np.errstate(invalid="ignore", divide="ignore"):
            fits = [np.abs((raw * a + b) * (1.0 + d) / raw - 1.0) < UNIT_FIT for a, b in ways]
            return (np.abs(d) > UNIT_SUSPECT) & np.any(fits, axis=0)

    for c, hits in by.items():
        fleet_ways = ways_of(hits, c)
        for es in [es for es in series if es.raw is not None]:
            # the engine's own gross values' unit first: two engines' mistakes may differ (one
            # engine's T30 in degC, another's in degF: the fleet's median pointed to degC only)
            own = [(d, raw) for _, cc, d, raw in es.gross if cc == c]
            ways = (ways_of(own, c) if own else []) or fleet_ways
            if not ways:
                continue
            cols = [j for j, name in enumerate(es.channels) if name.split("@")[0] == c]
            at = [i for i, cc, d, raw in es.gross if cc == c and other_unit(np.array(raw), np.array(d), ways)]
            at += np.flatnonzero(other_unit(es.raw[:, cols], es.D[:, cols], ways).any(axis=1)).tolist()
            if not at:
                continue
            for i in range(min(at), max(at) + 1):          # the stretch: every value of it, not only the off ones
                for j in cols:
                    if np.isfinite(es.D[i, j]):
                        es.gross.append((i, c, float(es.D[i, j]), float(es.raw[i, j])))
                        es.D[i, j] = es.SE[i, j] = np.nan


def _gross_units(d: np.ndarray, raw: np.ndarray, unit: str) -> list[str]:
    """The units (:func:`pwl.units.likely_units`) in which a channel's typical gross value (of
    the relative deviations ``d`` beyond GROSS_DEVIATION, else all, the median's; values ``raw`` in
    ``unit``) would be within 5 % of the model."""
    from ..units import likely_units
    big = np.abs(d) > GROSS_DEVIATION
    d, raw = (d[big], raw[big]) if big.any() else (d, raw)
    k = int(np.argsort(d)[d.size // 2])
    model = raw[k] / (1.0 + d[k])
    return likely_units(raw[k], unit, 0.95 * model, 1.05 * model)


def gross_note(series: list[EngineSeries], units: dict) -> list[str]:
    """A line per channel with values read as missing for a gross deviation (``EngineSeries.gross``):
    how many, on which engines and flights, how far off, and the units that would bring the
    typical one within 5 % of the model (:func:`pwl.units.likely_units`)."""
    by: dict[str, list] = {}
    for es in series:
        for i, c, d, raw in sorted(es.gross, key=lambda g: g[0]):
            by.setdefault(c, []).append((es.engine, es.flights[i].label, d, raw))
    out = []
    for c, hits in by.items():
        engines = list(dict.fromkeys(h[0] for h in hits))
        d, raw = np.array([h[2:] for h in hits]).T
        per: dict[tuple, list] = {}              # each engine's own unit (two mistakes may differ)
        for e in engines:
            de, re_ = np.array([h[2:] for h in hits if h[0] == e]).T
            per.setdefault(tuple(_gross_units(de, re_, units.get(c, ""))), []).append(e)
        if len(per) > 1 and all(per):
            why = "logged in " + "; in ".join(
                f"{' or '.join(g)} on {few(es, 3)}" for g, es in per.items()) \
                + " there? Declare the unit"
        else:
            guess = _gross_units(d, raw, units.get(c, ""))
            why = (f"logged in {' or '.join(guess)} there? Declare the unit" if guess
                   else "a failed sensor, or a unit mistake?")
        first = {e: next(h[1] for h in hits if h[0] == e) for e in engines[:3]}
        where = few([f"{e} from {lb}" for e, lb in first.items()] + engines[3:], 3)
        out.append(f"{c}: {len(hits)} snapshot value(s) of {len(engines)} engine(s) ({where}) "
                   f"{100 * d.min():+.0f} to {100 * d.max():+.0f} % off the model at their operating point, "
                   f"beyond any fault of the engine or between such values: {why}; read as missing")
    return out


def robust_sd(X: np.ndarray, axis=0) -> np.ndarray:
    """1.4826 x the median absolute deviation of X along ``axis`` (NaN left out): a normal
    sample's standard deviation, robust to a share of outliers below a half."""
    return 1.4826 * np.nanmedian(np.abs(X - np.nanmedian(X, axis=axis, keepdims=True)), axis=axis)


def noise_covariance(series: list[EngineSeries], floor: float) -> np.ndarray:
    """Flight-to-flight scatter Sigma (m, m) of the deviations.

    Successive differences of each engine's flights (the engine's own level cancels) pooled over
    the fleet: Cov(d_k - d_k-1) = 2 Sigma. Differences that hold an abrupt change are trimmed in
    three passes (squared Mahalanobis distance beyond the chi-square 99.9 % point). With fewer
    than 4 m complete differences (one engine alone) the robust variances with shrunk
    correlations (:func:`_shrunk_covariance`). Every
    channel's variance is at least floor^2 plus its median snapshot standard error squared; one
    that no flight has (read as missing throughout: a unit mistake) floor^2, uncorrelated."""
    m = series[0].D.shape[1]
    have = np.any([np.isfinite(s.D).any(axis=0) for s in series], axis=0)
    if not have.all():
        C = np.diag(np.full(m, floor ** 2))
        if have.any():
            C[np.ix_(have, have)] = noise_covariance([replace(s, D=s.D[:, have], SE=s.SE[:, have])
                                                      for s in series], floor)
        return C
    diffs, partial = [], []
    ses = []
    for s in series:
        ok = np.all(np.isfinite(s.D), axis=1)
        Dk = s.D[ok]
        if Dk.shape[0] >= 2:
            diffs.append(np.diff(Dk, axis=0))
        if s.D.shape[0] >= 2:
            partial.append(np.diff(s.D, axis=0))        # NaN where a flight lacks the channel
        ses.append(s.SE[ok])
    X = np.concatenate(diffs) if diffs else np.zeros((0, m))
    se = np.concatenate(ses) if ses else np.zeros((0, m))
    if not se.size:       # no flight has every channel (two instrumentation standards): all flights
        se = np.concatenate([s.SE for s in series])
    with warnings.catch_warnings():      # a channel without any standard error (snapshot tables)
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(se, axis=0) if se.size else np.zeros(m)
    base = np.nan_to_num(floor ** 2 + med ** 2, nan=floor ** 2)
    if X.shape[0] >= 4 * m:
        # start from the channels' median absolute differences, not from the covariance of all
        # differences: a few noisy or intermittently faulty engines (a fifth of the differences)
        # inflated that start 4-17x and nothing was then far enough out to be trimmed
        mad = robust_sd(X)
        md = np.sum((X / np.maximum(mad, 1e-300)) ** 2, axis=1)
        cut = stats.chi2.ppf(0.999, m)
        def enough(keep):           # the channels' differences are correlated: keep at least 2 m
            return keep if keep.sum() >= 2 * m else md <= np.sort(md)[2 * m - 1]
        keep = md < cut
        for _ in range(5):
            C = np.cov(X[enough(keep)].T, bias=False) / 2.0 + np.diag(base) * 1e-9
            md = np.einsum("ij,jk,ik->i", X, np.linalg.inv(2.0 * C), X)
            keep = md < cut
        C = np.cov(X[enough(keep)].T) / 2.0
        C = C / 0.99   # trimming at the 99.9 % point shrinks the estimate slightly
    elif partial and np.isfinite(np.concatenate(partial)).any():
        C = _shrunk_covariance(np.concatenate(partial)) / 2.0
    else:
        C = np.zeros((m, m))
    d = np.diag(C).copy()
    up = np.maximum(d, base)
    scale = np.sqrt(up / np.maximum(d, 1e-300))
    C = C * np.outer(scale, scale)
    np.fill_diagonal(C, up)
    return C


def _shrunk_covariance(X: np.ndarray) -> np.ndarray:
    """Covariance (m, m) of differences X (n, m; NaN where a flight lacks the channel) too few for
    a full estimate (n < 4 m: one engine, ``pwl trend`` alone; or no flight with every channel: a
    fleet of two instrumentation standards): the channels' robust variances (median absolute
    deviation) with their pairwise correlations (over the differences holding both) shrunk toward
    none by the Schaefer-Strimmer weight (the estimated variance of the sample correlations over
    their sum of squares), on the differences whose squared standardised norm is below the
    chi-square 99.9 % point (an abrupt change left out). A pair seen together on fewer than 4
    differences is uncorrelated; with pairs missing, the correlations are made positive definite.
    The channels' scatter is strongly correlated (Wf at idle and cruise, T48 and Wf: |r| 0.94-0.98
    over a fleet); taken as independent, a healthy engine's common pattern read as lpt+sensor:T48
    on 83 of 600 flights of ten 60-flight engines. A fleet without a flight of every channel had
    no estimate at all (zeros: the floor; 65 of 78 healthy engine-flights alarmed)."""
    X = X[np.isfinite(X).any(axis=1)]
    m = X.shape[1]
    if not X.shape[0]:
        return np.zeros((m, m))
    med = np.nanmedian(X, axis=0)
    mad = np.nan_to_num(robust_sd(X))
    C = np.diag(mad ** 2)
    Z = (X - med) / np.maximum(mad, 1e-300)
    ok = np.isfinite(Z)
    Z = Z[np.nansum(Z ** 2, axis=1) < stats.chi2.ppf(0.999, np.maximum(ok.sum(axis=1), 1))]
    ok = np.isfinite(Z)
    n = ok.T.astype(float) @ ok                              # (m, m) differences holding both
    if n.max(initial=0) < 4:
        return C
    with np.errstate(invalid="ignore", divide="ignore"):
        Z = np.nan_to_num((Z - np.nanmean(Z, axis=0)) / np.nanstd(Z, axis=0, ddof=1))
        W = Z[:, :, None] * Z[:, None, :]                    # (rows, m, m); 0 where a channel lacks
        mean = W.sum(axis=0) / n
        R = W.sum(axis=0) / (n - 1)
        var = ((W ** 2).sum(axis=0) - n * mean ** 2) * n / (n - 1) ** 3
    seen = (n >= 4) & ~np.eye(m, dtype=bool)
    lam = float(np.clip(var[seen].sum() / max((R[seen] ** 2).sum(), 1e-300), 0.0, 1.0))
    R = np.where(seen, (1.0 - lam) * R, 0.0) + np.eye(m)
    if not ok.all():             # correlations of different pairs of rows: made positive definite
        w, V = np.linalg.eigh(R)
        R = (V * np.maximum(w, 1e-3)) @ V.T
        d = np.sqrt(np.diag(R))
        R = (R + R.T) / (2.0 * np.outer(d, d))
    return R * np.outer(mad, mad)


def flight_numbers(es: EngineSeries) -> np.ndarray:
    """The flights' numbers (n,): the logs' flight_index when every flight has one and they do
    not decrease in time order (a missing flight then leaves a gap, and onsets and rates are in
    the logs' numbering; a flight exported twice shares its number), else their positions."""
    fidx = np.array([f.index for f in es.flights], float)
    ok = fidx.size and fidx.min() >= 0 and np.all(np.diff(fidx) >= 0)
    return fidx if ok else np.arange(fidx.size, dtype=float)


def excluding(es: EngineSeries, flights) -> EngineSeries:
    """``es`` without the flights numbered ``flights`` (:func:`flight_numbers`): their deviations and
    health NaN, as flights without a snapshot. Flights the user knows were flown off the engine's
    usual configuration (anti-ice or a customer bleed on, another generator load, a ground run):
    the trims do not hold that, and such flights read as faults (``pwl fleet diagnose --exclude``)."""
    drop = np.isin(flight_numbers(es), np.asarray(list(flights), dtype=float))
    if not drop.any():
        return es
    D, SE, H = es.D.copy(), es.SE.copy(), es.h_hat.copy()
    D[drop], SE[drop], H[drop] = np.nan, np.nan, np.nan
    return replace(es, D=D, SE=SE, h_hat=H)


def mark_excluded(rows: list, excluded: dict) -> list:
    """The rows (:class:`Decision`, each engine's in flight order) of flights the user excluded
    (engine -> flight numbers): status ``excluded``, and the engine's diagnosis as of its flight
    before (a fault found stays reported while such flights come)."""
    before: dict = {}
    for i, r in enumerate(rows):
        if r.flight in excluded.get(r.engine, ()):
            prev = before.get(r.engine)
            if prev is not None:
                keep = (r.engine, r.flight, r.label, r.source, r.missing)
                r = rows[i] = replace(prev)
                r.engine, r.flight, r.label, r.source, r.missing = keep
            r.status = "excluded"
            r.detail = "left out: declared off the usual configuration (--exclude)" + (
                "; as of the flight before: " + r.detail if prev is not None and r.detail else "")
        before[r.engine] = r
    return rows


@dataclass
class FleetNorm:
    """A fleet's normal engine in health-parameter space: per health parameter (``columns``,
    indices into the signature columns, and their ``names``) the median over ``engines`` engines
    and its robust spread, of wear rates (fraction per flight, :func:`wear_reference`)."""

    columns: np.ndarray
    names: list[str]
    median: np.ndarray
    spread: np.ndarray
    engines: int
    rest: np.ndarray     # (m,) robust spread per deviation channel of what health does not explain
    rest_median: np.ndarray | None = None   # (m,) its median over the engines
    trend_spread: tuple | None = None       # (s2, rho2) of :meth:`trend` (wear only)
    common: list = field(default_factory=list)   # the fleet-wide steps left out (:func:`common_steps`)
    away: list = field(default_factory=list)     # the pairs of them that are one excursion (:func:`_fleet_excursions`)

    def at(self, S: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean (k,), covariance (k, k)) in the deviation channels ``idx`` (k,) with signatures
        S (k, ncol): S_h median, S_h diag(spread^2) S_h^T + diag(rest[idx]^2) (engine-to-engine
        differences no health parameter explains, such as sensor calibrations). A channel no
        health parameter moves (the inlet pressure against the air data) has the engines' median
        as its mean: what the air-data relation leaves in common (measured -0.005 % and +0.0006 %
        at the turbofan's ground idle and cruise; with full ram recovery instead of the plant's,
        -0.5 %: every engine read a P2 level)."""
        Sh = S[:, self.columns]
        alone = np.where(np.any(Sh != 0.0, axis=1), 0.0, self.rest_median[idx])
        return Sh @ self.median + alone, (Sh * self.spread ** 2) @ Sh.T + np.diag(self.rest[idx] ** 2)

    def trend(self, S: np.ndarray, idx: np.ndarray, Sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean (k,), covariance (k, k)) of a healthy engine's wear line (deviation per flight) in
        the channels ``idx`` (k,) with signatures S (k, ncol), Sigma the flight-to-flight scatter
        (m, m): the fleet's median slope per channel, and what ``trend_spread`` (s2, rho2) gives
        of its engine-to-engine spread without the slopes' own scatter (:func:`_trend_spread`):
        s2 S_h S_h^T + rho2 Sigma. The ``slope`` of :func:`_fit_changes`."""
        Sh = S[:, self.columns]
        s2, rho2 = self.trend_spread
        return Sh @ self.median + self.rest_median[idx], s2 * Sh @ Sh.T + rho2 * Sigma[np.ix_(idx, idx)]


def whitening(Sigma: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Wt (k, k) with Wt @ d ~ N(0, I) for deviations d of the channels ``idx`` (k,) of scatter Sigma."""
    return np.linalg.inv(np.linalg.cholesky(Sigma[np.ix_(idx, idx)]))


def _usable(es: EngineSeries, Sigma: np.ndarray):
    """(flights (n,) bool, channels (k,) int, whitening (k, k)) of an engine for the fleet's
    references: the channels it has on at least half of its flights with data (an engine without a
    sensor, an older standard, is judged on the others), the flights holding all of them, and the
    whitening of Sigma on them. An engine with every channel: all of them, as before. Counting
    only flights with every channel of the fleet, a fleet of two instrumentation standards had no
    reference at all: a fleet-wide T48 recalibration alarmed every engine, a calibration level of
    +31 K on T48 was missed. An engine whose channels no health parameter moves (every sensor
    read missing: the inlet pressure left) has no flight for them: its zero health rates joined
    the fleet's wear and made its spread of wear lines NaN (a LinAlgError stopped the fleet)."""
    have = np.isfinite(es.D)
    flown = have.any(axis=1)
    idx = np.flatnonzero(have[flown].mean(axis=0) >= 0.5) if flown.any() else np.arange(es.D.shape[1])
    ok = np.all(have[:, idx], axis=1)
    health = [j for j, c in enumerate(es.columns) if not c.startswith(("sensor:", "gain:"))]
    if ok.any() and not np.any(es.S[ok][:, idx][:, :, health]):
        ok[:] = False
    return ok, idx, whitening(Sigma, idx)


def _fleet_norm(series: list[EngineSeries], Sigma: np.ndarray, cfg: "DiagnosisConfig", per_engine) -> FleetNorm | None:
    """The median and 1.4826 x median absolute deviation over the engines with at least
    ``cfg.wear_flights`` complete flights (None with fewer than ``cfg.wear_engines``) of
    ``per_engine(D, t, engine)`` (a vector of deviations from an engine's complete flights D at flight
    numbers t) read as health-parameter values (whitened least squares on the mean signatures of
    its component columns), and of what they leave per channel. Robust to the engines with a
    fault, up to half of them."""
    cols = np.array([j for j, c in enumerate(series[0].columns) if not c.startswith(("sensor:", "gain:"))] if series else [])
    if cols.size == 0:
        return None
    vals, rest = [], []
    m = series[0].D.shape[1]
    for es in series:
        ok, idx, Wt = _usable(es, Sigma)
        if ok.sum() < cfg.wear_flights:
            continue
        Sh = np.nanmean(es.S[ok][:, idx], axis=0)[:, cols]
        v = per_engine(es.D[ok][:, idx], flight_numbers(es)[ok], es.engine, Wt)
        vals.append(np.linalg.lstsq(Wt @ Sh, Wt @ v, rcond=None)[0])
        r = v - Sh @ vals[-1]
        rest.append(np.full(m, np.nan))
        rest[-1][idx] = r
    if len(vals) < cfg.wear_engines:
        return None
    def robust(V):
        med = np.nanmedian(V, axis=0)
        return med, robust_sd(V)
    med, spread = robust(np.array(vals))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # a channel no engine of the fleet has
        left_median, left = robust(np.array(rest))
    left = np.where(np.isfinite(left), left, np.nanmax(left) if np.isfinite(left).any() else 0.0)
    return FleetNorm(cols, [series[0].columns[j] for j in cols], med, spread, len(vals), left,
                     np.where(np.isfinite(left_median), left_median, 0.0))


def wear_reference(series: list[EngineSeries], Sigma: np.ndarray,
                   cfg: DiagnosisConfig = DiagnosisConfig(), steps: dict | None = None) -> FleetNorm | None:
    """The normal wear of a fleet (:func:`_fleet_norm`): each engine's deviation rate
    (least-squares slope per channel over its flight numbers, its level and its own steps,
    :func:`engine_steps`, as nuisances) as health-parameter rates. Like Sigma it uses every
    engine's whole history: an engine is compared with its fleet's wear, not with its own.
    Without its steps as nuisances, a fault's step was part of the engine's rate, which the
    median over the engines tolerated only while fewer than half of them changed at once: a T48
    recalibration from flight 10 of 20 on 10 of 12 engines became every engine's "wear" (lpt_eff
    -0.26 %/flight; truth at most 0.01) and, subtracted from each engine's flights, made its
    flights before it a sensor drift from flight 0. ``steps``: engine -> its steps, when
    already found (:func:`fleet_steps`)."""
    fits = {}
    def slope(D, t, engine, Wt):
        own = steps[engine] if steps is not None else engine_steps(D, Wt, t, cfg)
        X = np.column_stack([np.ones_like(t), t - t.mean()] + [_shape(t, s, "step") for s in own])
        fits[engine] = (np.linalg.lstsq(X, D, rcond=None)[0][1], float(np.linalg.pinv(X.T @ X)[1, 1]))
        return fits[engine][0]
    norm = _fleet_norm(series, Sigma, cfg, slope)
    if norm is not None:
        norm.trend_spread = _trend_spread(series, Sigma, norm, fits)
    return norm


def _trend_spread(series: list[EngineSeries], Sigma: np.ndarray, norm: FleetNorm, fits: dict) -> tuple:
    """(s2, rho2): how much the healthy engines' wear lines differ, without the scatter of their
    estimates (:meth:`FleetNorm.trend`). ``fits``: engine -> (slope per channel of its usable
    channels (k,), the slope's variance in units of the flight-to-flight scatter, c). The whitened
    slopes off the fleet's median, over sqrt(c), have covariance I + (s2 A A^T + rho2 Sigma_w) / c,
    A = Wt S_h: the median over the engines of their squared norm outside A's span and in it (per
    degree of freedom, over its chi-square median) gives rho2 / c and then s2, each at its upper
    two-standard-error bound (what the fleet's data do not rule out). The robust spread of the
    health rates themselves (``spread``) was 5-20 times the truth on a 40-engine fleet: the rates
    of the weakly seen components are mostly the estimates' scatter, and an engine's drift from
    mid-history took it for normal wear."""
    out, inside, trace, cs, ranks, rests = [], [], [], [], [], []
    for es in series:
        if es.engine not in fits:
            continue
        v, c = fits[es.engine]
        ok, idx, Wt = _usable(es, Sigma)
        Sh = np.nanmean(es.S[ok][:, idx], axis=0)[:, norm.columns]
        A = Wt @ Sh
        y = Wt @ (v - Sh @ norm.median - norm.rest_median[idx]) / np.sqrt(c)
        Q = np.linalg.qr(A, mode="complete")[0]
        r = np.linalg.matrix_rank(A)
        if r < A.shape[0]:
            out.append(float(np.sum((Q[:, r:].T @ y) ** 2)) / stats.chi2.median(A.shape[0] - r))
        inside.append(float(np.sum((Q[:, :r].T @ y) ** 2)) / stats.chi2.median(r))
        trace.append(float(np.sum(A * A)) / r)
        cs.append(c)
        ranks.append(r)
        rests.append(A.shape[0] - r)
    # (the standard error of a median of n chi-square(k)/k: 1.253 sqrt(2 / k / n); k the engines'
    # median degrees of freedom, each engine's own channels)
    n, c, r = len(cs), float(np.median(cs)), float(np.median(ranks))
    k_out = float(np.median([k for k in rests if k > 0])) if out else 0.0
    rho = max(0.0, float(np.median(out)) - 1.0) + 2.0 * 1.253 * np.sqrt(2.0 / k_out / len(out)) if out else 0.0
    s = max(0.0, float(np.median(inside)) - 1.0 - rho) + 2.0 * 1.253 * np.sqrt(2.0 / r / n)
    return s * c / float(np.median(trace)), rho * c


def _largest_step(D, Wt, t, steps=()):
    """(flight number, relative size |delta|, Bonferroni p-value over the change points tried)
    of the largest step of deviations D (n, m) at flight numbers t, off the engine's level and
    wear line and the steps at ``steps`` (flight numbers): the largest likelihood gain E = g^T g
    |Wt delta|^2 (as :func:`_fit_changes`), chi-square with m degrees of freedom when nothing
    changed at that flight."""
    X = np.column_stack([np.ones_like(t), t - t.mean()] + [(t >= s).astype(float) for s in steps])
    Xp = np.linalg.pinv(X)
    best = (np.nan, -1.0, 0.0)
    taus = [tau for tau in t[1:] if tau not in steps]
    for tau in taus:
        f = (t >= tau).astype(float)
        g = f - X @ (Xp @ f)
        g2 = float(g @ g)
        if g2 < 1e-9:
            continue
        delta = D.T @ g / g2
        E = g2 * float(np.sum((Wt @ delta) ** 2))
        if E > best[1]:
            best = (float(tau), E, float(np.linalg.norm(delta)))
    p = float(stats.chi2.sf(best[1], D.shape[1])) * max(1, len(taus)) if best[1] >= 0 else 1.0
    return best[0], best[2], p


def engine_steps(D: np.ndarray, Wt: np.ndarray, t: np.ndarray, cfg: DiagnosisConfig = DiagnosisConfig(),
                 most: int = 3) -> list[float]:
    """The flight numbers of an engine's steps over its whole history (deviations D (n, m) at
    flight numbers t, whitening Wt), largest first: the largest step off its level, wear line
    and the steps already found, while significant (chi-square, Bonferroni over the change
    points, below ``cfg.alpha``) and at least ``cfg.min_step``; at most ``most``."""
    steps: list[float] = []
    while len(steps) < most and t.size >= 4:
        tau, size, p = _largest_step(D, Wt, t, steps)
        if not (p < cfg.alpha and size >= cfg.min_step):
            break
        steps.append(tau)
    return steps


@dataclass
class CommonStep:
    """A change most of a fleet's engines show alike (:func:`common_steps`): at one flight, or
    over a few (``rollout``); its first flight ``onset``, the ``engines`` with a step there, out
    of ``eligible``; ``cls`` the hypothesis most of them are isolated as (``alike`` engines,
    ``onsets``: engine -> the flight number of its step, for those) and ``detail`` its median fit
    over those (as a decision's detail: fractions, sensor biases in their unit)."""

    onset: float
    engines: list[str]
    eligible: int
    cls: str
    alike: int
    detail: str
    onsets: dict = field(default_factory=dict)
    rollout: bool = False
    fit: np.ndarray = field(default_factory=lambda: np.zeros(0))    # the median fit ``detail`` reads

    def describe(self, units: dict | None = None) -> str:
        """One line for people: "10 of 12 engines changed alike from flight 10 (sensor:T48
        +30.6 K): ..." (units: :func:`pwl.fleet.trending.detail_units`)."""
        from .trending import readable_detail
        what = readable_detail(self.detail, units or {})
        if self.rollout:
            return (f"{len(self.engines)} of {self.eligible} engines changed alike over flights {self.onset:g}-"
                    f"{max(self.onsets.values()):g} ({what}): a fleet-wide change rolled out (a software or "
                    "calibration update)? Left out of the fleet's normal wear and of each engine's faults: its "
                    "diagnosis is measured from it")
        how = (f"alike from flight {self.onset:g} ({what})" if self.alike == len(self.engines) else
               f"from flight {self.onset:g} ({self.alike} of them alike: {what})")
        return (f"{len(self.engines)} of {self.eligible} engines changed {how}: a fleet-wide change (a sensor "
                "recalibration, a software or fuel change)? Left out of the fleet's normal wear and of the faults "
                "of the engines that changed alike: their diagnosis is measured from it")


def fleet_steps(series: list[EngineSeries], Sigma: np.ndarray, cfg: DiagnosisConfig = DiagnosisConfig()) -> dict:
    """engine -> the flight numbers of its steps (:func:`engine_steps`) over its complete
    flights, for every engine with at least ``cfg.wear_flights`` of them: found once for the
    fleet's normal wear and its common steps."""
    out = {}
    for es in series:
        ok, idx, Wt = _usable(es, Sigma)
        if ok.sum() >= cfg.wear_flights:
            out[es.engine] = engine_steps(es.D[ok][:, idx], Wt, flight_numbers(es)[ok], cfg)
    return out


def common_steps(series: list[EngineSeries], Sigma: np.ndarray,
                 cfg: DiagnosisConfig = DiagnosisConfig(), steps: dict | None = None) -> list[CommonStep]:
    """Changes most of the fleet shows alike (a fleet-wide sensor recalibration, a software or
    fuel change): of the engines with at least ``cfg.wear_flights`` complete flights (none with
    fewer than ``cfg.wear_engines``), more than half have a step (:func:`engine_steps`) isolated
    alike (the same hypothesis) at the same flight number, or, rolled out, within ``cfg.rollout``
    consecutive flights (:func:`_rollouts`). Every step is isolated on its engine (the bank's
    hypothesis with the largest T - cost, the engine's other steps as nuisances); the class most
    of them share is named with its median fit. Different faults at one flight are not one
    change (probe fleet P4: 12 engines, five classes at flight 10, raised the fleet-wide
    warning). ``steps``: as :func:`fleet_steps`, when already found."""
    eng = []
    steps = fleet_steps(series, Sigma, cfg) if steps is None else steps
    for es in series:
        ok, idx, Wt = _usable(es, Sigma)
        if es.engine in steps:
            eng.append((es, es.D[ok][:, idx], Wt, flight_numbers(es)[ok], np.nanmean(es.S[ok][:, idx], axis=0),
                        steps[es.engine]))
    if len(eng) < cfg.wear_engines:
        return []
    bank = hypotheses(series[0].columns, cfg.pairs)
    isolated = []                                # (engine, flight number, hypothesis index, fit)
    for es, D, Wt, t, S, taus in eng:
        # the hypotheses its channels can test (a bias of a sensor it lacks is not)
        can = [i for i, h in enumerate(bank) if _testable(h, S)]
        for tau in taus:
            got = _fit_changes(D, Wt, S, t, [tau], "step", [bank[i] for i in can], cfg, trend=cfg.wear,
                               steps=[s for s in taus if s != tau])
            _, hi, _, th, _, _ = max(got, key=lambda f: f[2] - bank[can[f[1]]].cost(cfg))
            isolated.append((es.engine, tau, can[hi], th))
    at: dict = {}
    for s in isolated:
        at.setdefault(s[1], []).append(s)
    common = partial(_common, eligible=len(eng), bank=bank, columns=series[0].columns)
    found = [c for c in (common(at[tau]) for tau in sorted(at) if 2 * len(at[tau]) > len(eng))
             if 2 * c.alike > len(eng)]
    rest = [s for s in isolated if 2 * len(at[s[1]]) <= len(eng)]
    found += [common(w, rollout=True) for w in _rollouts(rest, len(eng), cfg.rollout)]
    pooled = _pooled_step(eng, bank, cfg, series[0].columns, {c.onset for c in found})
    return found + ([pooled] if pooled is not None else [])


#: a change of the whole fleet too small for any one engine's test (:func:`_pooled_step`) must show,
#: along its fitted change, on at least this share of the engines
POOLED_SHARE = 2.0 / 3.0


def _pooled_step(eng: list, bank: list[Hypothesis], cfg: DiagnosisConfig, columns: list[str],
                 known: set) -> CommonStep | None:
    """A step every engine shows alike at one flight number, found on the fleet pooled, not on
    any one engine (a T48 recalibration of +3 K from flight 15, a tenth of a sensor's noise: its
    share of every engine's wear line made the fleet's normal wear a fan efficiency gaining
    0.1 %/flight, and nothing named it). ``eng``: (series, deviations D (n, k), whitening Wt, flight
    numbers t, signatures S, its own steps) of the engines judged (:func:`common_steps`); those
    with every channel count. At each flight number (not one of ``known``), each engine's step
    off its level, a wear curve (line and curvature: wear that levels off made a fleet-wide 'step'
    otherwise) and its own steps (an engine with one within a flight of it left out), the median
    of the engines' steps per channel (robust to a few engines' faults there), against its
    variance (pi / 2 of their mean's); the largest likelihood gain, chi-square with as many
    degrees of freedom as channels, Bonferroni over the flight numbers, below ``cfg.alpha`` and at
    least ``cfg.min_step``, shown along the pooled step on :data:`POOLED_SHARE` of the engines: a
    :class:`CommonStep` of every such engine, isolated as the bank's hypothesis with the largest
    T - cost."""
    m = max(D.shape[1] for _, D, _, _, _, _ in eng)
    full = [e for e in eng if e[1].shape[1] == m]
    if len(full) < cfg.wear_engines:
        return None
    taus = sorted({float(x) for _, _, _, t, _, _ in full for x in t[2:-1]} - set(known))
    Wt = full[0][2]
    best = (-1.0, None, None, None, None)
    for tau in taus:
        each, w = [], []
        for _, D, _, t, _, own in full:
            if any(abs(o - tau) <= 1 for o in own):
                continue                  # its own change there: not the fleet's to judge by
            u = (t - t.mean()) / max(float(np.ptp(t)), 1.0)
            X = np.column_stack([np.ones_like(t), u, u ** 2] + [(t >= o).astype(float) for o in own])
            f = (t >= tau).astype(float)
            g = f - X @ (np.linalg.pinv(X) @ f)
            g2 = float(g @ g)
            if g2 < 1e-9:
                continue
            each.append(D.T @ g / g2)
            w.append(g2)
        if 2 * len(each) <= len(full):
            continue
        # the engines' median step, per channel: a few engines' faults near it do not make it
        delta = np.median(np.array(each), axis=0)
        den = len(each) / (np.pi / 2.0 * float(np.mean(1.0 / np.array(w))))
        E = den * float(np.sum((Wt @ delta) ** 2))
        if E > best[0]:
            best = (E, tau, delta, den, each)
    E, tau, delta, den, each = best
    if tau is None:
        return None
    p = float(stats.chi2.sf(E, m)) * len(taus)
    shown = np.mean([float((Wt @ d) @ (Wt @ delta)) > 0.0 for d in each])
    if not (p < cfg.alpha and np.linalg.norm(delta) >= cfg.min_step and shown >= POOLED_SHARE):
        return None
    S = np.median(np.array([e[4] for e in full]), axis=0)
    v = np.sqrt(den) * (Wt @ delta)
    fits = []
    for i, h in enumerate(bank):
        if not _testable(h, S):
            continue
        A = np.sqrt(den) * (Wt @ S[:, h.columns])
        th = np.linalg.lstsq(A, v, rcond=None)[0]
        fits.append((float(v @ (A @ th)) - h.cost(cfg), i, th))
    _, hi, th = max(fits, key=lambda f: f[0])
    detail = " ".join(f"{columns[c]}={x:+.5g}" for c, x in zip(bank[hi].columns, th))
    names = [e[0].engine for e in full]
    return CommonStep(tau, names, len(eng), bank[hi].name, len(names), detail, {n: tau for n in names}, False, th)


def _common(steps: list, eligible: int, bank: list[Hypothesis], columns: list[str],
            rollout: bool = False) -> CommonStep:
    """The :class:`CommonStep` of ``steps`` ((engine, flight number, hypothesis index, fit) of
    each engine's step): the hypothesis most of them are isolated as, named with its median fit."""
    fits: dict = {}
    for _, _, hi, th in steps:
        fits.setdefault(hi, []).append(th)
    hi = max(fits, key=lambda h: len(fits[h]))
    med = np.median(np.array(fits[hi]), axis=0)
    detail = " ".join(f"{columns[c]}={v:+.5g}" for c, v in zip(bank[hi].columns, med))
    return CommonStep(min(s[1] for s in steps), [s[0] for s in steps], eligible, bank[hi].name, len(fits[hi]),
                      detail, {s[0]: s[1] for s in steps if s[2] == hi}, rollout, med)


def _rollouts(steps: list, eligible: int, width: int) -> list[list]:
    """Groups of ``steps`` ((engine, flight number, hypothesis index, fit), each engine's
    steps) that are one change rolled out over the fleet: isolated alike (the same hypothesis)
    within ``width`` consecutive flights, on more than half of ``eligible`` engines (an engine's
    first step of it); the largest such window first. Independent faults do not gather so: the
    seed-1 and seed-7 benchmark fleets (one fault on 60-80 % of the engines, at a random flight,
    of 14 classes) have at most 3 and 5 of their 50 engines' steps alike within 4 flights."""
    groups = []
    for hi in sorted({s[2] for s in steps}):
        alike = sorted((s for s in steps if s[2] == hi), key=lambda s: s[1])
        while alike:
            windows = [[s for s in alike if a <= s[1] < a + width] for a in sorted({s[1] for s in alike})]
            best = max(windows, key=lambda w: len({s[0] for s in w}))
            first = {}
            for s in best:
                first.setdefault(s[0], s)
            if 2 * len(first) <= eligible:
                break
            groups.append(list(first.values()))
            alike = [s for s in alike if all(s is not b for b in best)]
    return sorted(groups, key=lambda g: min(s[1] for s in g))


def fleet_norms(series: list[EngineSeries], Sigma: np.ndarray, cfg: DiagnosisConfig = DiagnosisConfig(),
                units: dict | None = None) -> tuple:
    """(normal wear (None without ``cfg.wear``), normal level) an engine of ``series`` is judged
    against (:func:`wear_reference`, :func:`level_reference`). A change most engines show at
    the same flight (:func:`common_steps`) is a nuisance of the normal wear (kept in the wear's
    ``common``) and named once in a :class:`PwlWarning` (``units``: for its size, as
    :func:`pwl.fleet.trending.detail_units`). The level (the engines' first n_base + 1 flights)
    holds such a step only when it is among those flights, and then on every engine alike."""
    steps = fleet_steps(series, Sigma, cfg)
    common = common_steps(series, Sigma, cfg, steps)
    for c in common:               # (one found pooled, on no engine by itself: in every engine's wear)
        for e, o in c.onsets.items():
            if e in steps and o not in steps[e]:
                steps[e] = steps[e] + [o]
    away = _fleet_excursions(common)
    from .trending import readable_detail
    for a, b in away:
        last = f"s {a.onset:g}-{b.onset - 1:g}" if b.onset - a.onset > 1 else f" {a.onset:g}"
        warnings.warn(PwlWarning(
            f"{len(a.engines)} of {a.eligible} engines off on flight{last} only, back from flight {b.onset:g} "
            f"({a.alike} of them alike: {readable_detail(a.detail, units or {})}): a fleet-wide data fault (a "
            "ground station's processing, a change undone)? Those flights are left out of the engines' tests"),
            stacklevel=2)
    for c in common:
        if all(c is not x for pair in away for x in pair):
            warnings.warn(PwlWarning(c.describe(units)), stacklevel=2)
    wear = wear_reference(series, Sigma, cfg, steps) if cfg.wear else None
    if wear is not None:
        wear.common, wear.away = common, away
    return wear, level_reference(series, Sigma, cfg)


#: the tail probability at which the fleet's level spread is widened for its estimation from a few
#: engines (:func:`level_reference`): about alpha (1e-3) over the thousand tests of a flight
LEVEL_TAIL = 1e-6
#: the chance that a healthy engine of the fleet is left out of its level reference (a Bonferroni
#: bound over the engines, :func:`level_reference`)
LEVEL_OFF = 0.05


@dataclass
class FleetLevel:
    """A fleet's normal baseline level (:func:`level_reference`): per deviation channel the mean
    of the engines kept ``mean`` (m,); the engine-to-engine variances of the health parameters
    ``columns`` (signature columns) ``health``, of each channel beside them ``rest`` (m,) and
    ``common`` (m, m, a multiple of the flight-to-flight scatter), without the baselines' own noise; ``wider`` the factor they are widened by for their
    estimation from the ``kept`` of ``engines`` engines (the others off it), ``floor`` (m,) the
    least variance per channel."""

    mean: np.ndarray
    columns: np.ndarray
    health: np.ndarray
    rest: np.ndarray
    common: np.ndarray
    wider: float
    floor: np.ndarray
    kept: int
    names: list[str]               # the engines' serials, as ``baselines``
    baselines: np.ndarray          # (engines, m) their baselines, NaN: missing
    noise: np.ndarray              # (m, m) a baseline's own noise covariance

    @property
    def engines(self) -> int:
        """How many engines' baselines the reference was made from (``kept`` of them kept)."""
        return len(self.names)

    def at(self, S: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean (k,), covariance (k, k)) of a healthy engine's baseline less its noise in the
        channels ``idx`` (k,) with signatures S (k, ncol): wider x (S_h diag(health) S_h^T +
        diag(rest) + common), each variance at least its floor."""
        Sh = S[:, self.columns]
        B = self.wider * ((Sh * self.health) @ Sh.T + np.diag(self.rest[idx]) + self.common[np.ix_(idx, idx)])
        return self.mean[idx], B + np.diag(np.maximum(self.floor[idx] - np.diag(B), 0.0))

    def off(self, engine: str, x: np.ndarray, S: np.ndarray, idx: np.ndarray, bank: list) -> set[str]:
        """The names of the hypotheses of ``bank`` along which the baseline x (k,) of ``engine`` in
        the channels ``idx`` (signatures S (k, ncol)) is off the other engines' baselines by their
        own scatter (:func:`_fleet_outlier`), each estimated as the level test does (generalised
        least squares against :meth:`at`'s covariance plus the noise): the spread above is a model
        (health parameters, channels), and a healthy engine far in a direction it holds too little
        of (a log fleet whose flight-to-flight scatter is a fraction of its engines' differences)
        read a sensor level (a probe fleet's ESN016: 'sensor:Ps30 level', -5.5 kPa)."""
        rows = [f for f, n in enumerate(self.names) if n != engine and np.all(np.isfinite(self.baselines[f, idx]))]
        if len(rows) < 3:
            return {h.name for h in bank}
        mean, B = self.at(S, idx)
        L = np.linalg.cholesky(B + self.noise[np.ix_(idx, idx)])
        X = np.linalg.solve(L, (self.baselines[rows][:, idx] - mean).T)      # (k, others)
        xe, SL = np.linalg.solve(L, x - mean), np.linalg.solve(L, S)
        out = set()
        for h in bank:
            P = np.linalg.pinv(SL[:, h.columns])
            if _fleet_outlier(P @ xe, (P @ X).T):
                out.add(h.name)
        return out


#: the chance at which an engine's level estimate is off the other engines' (:func:`_fleet_outlier`)
LEVEL_GUARD = 1e-3
#: an engine's estimate beyond this many robust standard deviations of the others' in a component
#: is left out of their spread (:func:`_fleet_outlier`)
LEVEL_TRIM = 4.0


def _fleet_outlier(theta: np.ndarray, others: np.ndarray) -> bool:
    """Whether the estimate theta (r,) is off the other engines' ``others`` (n, r): those within
    LEVEL_TRIM robust standard deviations of their median in every component give a mean and a
    covariance, and theta is beyond their Hotelling prediction bound at LEVEL_GUARD ((n - r) n /
    (r (n + 1) (n - 1)) d2 ~ F(r, n - r)). True when they cannot tell (n < r + 2)."""
    r = theta.size
    med = np.median(others, axis=0)
    s = robust_sd(others)
    keep = np.all(np.abs(others - med) <= LEVEL_TRIM * np.where(s > 0.0, s, np.inf), axis=1)
    n = int(keep.sum())
    if n < r + 2:
        return True
    mu = others[keep].mean(axis=0)
    C = np.atleast_2d(np.cov(others[keep].T))
    d = theta - mu
    d2 = float(d @ np.linalg.lstsq(C, d, rcond=None)[0])
    return (n - r) * n / (r * (n + 1) * (n - 1)) * d2 > stats.f.ppf(1.0 - LEVEL_GUARD, r, n - r)


def level_reference(series: list[EngineSeries], Sigma: np.ndarray,
                    cfg: DiagnosisConfig = DiagnosisConfig()) -> FleetLevel | None:
    """The fleet's normal baseline when its engines' records begin: each engine's mean deviation
    over its first n_base + 1 complete flights (its baseline; engines with at least
    ``cfg.wear_flights`` of them, None with fewer than ``cfg.wear_engines``), their mean per
    channel and their spread: the engine-to-engine variance of each health parameter, of each
    channel beside them (calibrations, what the model does not hold) and one of Sigma's shape,
    without the baselines' own noise (Sigma / (n_base + 1)): :func:`_level_spread` fitted to a
    robust covariance of the baselines, then to the covariance of the engines not off it (their
    squared Mahalanobis distance, the spread first brought up to the engines' median distance
    (:func:`_scaled`), beyond the chi-square point at :data:`LEVEL_OFF` over the engines: a fault
    from the first flight), twice. An engine whose baseline is off it (a fault before its first
    flight, an engine delivered or repaired with a defect) has no step of its own to find; it
    must be off the other engines themselves too (:meth:`FleetLevel.off`), the spread being a
    model.

    The spread was the robust spread of each engine's health estimate and, per channel, of what
    it left: the weakly seen health parameters' estimates are mostly their own noise (lpc_eff
    2.1 % against a delivery scatter of 0.3 %), and an HPT loss of 3-4 %, an LPC or HPC loss of
    3-4 % and T48 +30 K from the first flight read 'ok' on every flight of a 30-engine table. A
    covariance in the channels themselves, free, was too many numbers for 20-30 engines (robust
    searches left healthy engines of its tails out, tests of whole baselines could not tell the
    faulty ones). The spread is widened by Student's t against the normal at :data:`LEVEL_TAIL`
    (x1.7 for 26 engines, x10 for 8: an engine judged against a spread estimated from a few
    others). Each channel's variance is at least ``cfg.level_floor`` squared times its
    flight-to-flight variance: engines are compared on baselines flown on other days, aircraft,
    bleeds and loads, which the trims do not hold; with the trims on the day's ambient (the
    database's ambient terms) the scatter of Wf and T48 fell 4-7x and a fleet whose baselines were
    all flown with anti-ice on read them as sensor calibration offsets (probe fleet WINTER: 77
    false 'level' rows on 9 of 12 engines; none with the floor)."""
    nb = cfg.n_base + 1
    cols = np.array([j for j, c in enumerate(series[0].columns) if not c.startswith(("sensor:", "gain:"))] if series else [])
    V, Ss, names = [], [], []
    for es in series:
        ok, idx, _ = _usable(es, Sigma)
        if ok.sum() >= cfg.wear_flights:
            names.append(es.engine)
            V.append(np.full(es.D.shape[1], np.nan))
            V[-1][idx] = es.D[ok][:nb][:, idx].mean(axis=0)
            Ss.append(np.full(es.S.shape[1:], np.nan))
            Ss[-1][idx] = np.mean(es.S[ok][:, idx], axis=0)      # (a channel the engine lacks: NaN)
    if len(V) < cfg.wear_engines or cols.size == 0:
        return None
    V = np.array(V)
    have = np.isfinite(V)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # a channel no engine of the fleet has
        Sh = np.nan_to_num(np.nanmedian(np.array(Ss), axis=0)[:, cols])
        mean = np.nan_to_num(np.nanmedian(V, axis=0))
    noise = Sigma / nb
    X = np.where(have, V - mean, 0.0)
    spread = _level_spread(_pairwise_robust(X, have), Sh, Sigma, noise)
    kept = np.ones(len(V), bool)
    for _ in range(2):
        # the spread brought up to the engines' median distance (the model of it holds the health
        # parameters' directions, the channels and Sigma's shape; the rest of what engines differ
        # by is in no one of them), then the engines beyond the Bonferroni point left out
        between = _scaled(spread, Sh, Sigma, X, have, noise)
        d2 = _distances(X, have, noise + between)
        cut = stats.chi2.ppf(1.0 - LEVEL_OFF / len(V), np.maximum(have.sum(axis=1), 1))
        kept = d2 <= cut
        if kept.sum() * 2 < len(V):        # more than half off: the model, not the engines
            kept = d2 / cut <= np.sort(d2 / cut)[(len(V) - 1) // 2]
        w = (kept[:, None] & have).astype(float)
        mean = np.where(w.sum(axis=0) > 0, np.sum(np.where(have, V, 0.0) * w, axis=0) / np.maximum(w.sum(axis=0), 1.0), mean)
        X = np.where(have, V - mean, 0.0)
        Xw = X * w
        spread = _level_spread((Xw.T @ Xw) / np.maximum(w.T @ w - 1.0, 1.0), Sh, Sigma, noise)
    health, rest, common = spread
    c = _scaled(spread, Sh, Sigma, X[kept], have[kept], noise, factor=True)
    n = int(kept.sum())
    wider = c * stats.f.ppf(1.0 - LEVEL_TAIL, 1, max(n - 1, 1)) / stats.chi2.ppf(1.0 - LEVEL_TAIL, 1)
    return FleetLevel(mean, cols, health, rest, common * Sigma, float(wider), cfg.level_floor ** 2 * np.diag(Sigma),
                      n, names, V, noise)


def _distances(X: np.ndarray, have: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(n,) each row's squared Mahalanobis distance against ``cov`` on its channels ``have``."""
    return np.array([X[e, have[e]] @ np.linalg.solve(cov[np.ix_(have[e], have[e])], X[e, have[e]])
                     for e in range(X.shape[0])])


def _scaled(spread: tuple, Sh: np.ndarray, Sigma: np.ndarray, X: np.ndarray, have: np.ndarray,
            noise: np.ndarray, factor: bool = False):
    """The between-engine covariance of ``spread`` (health, rest, common of :func:`_level_spread`
    with its Sh and Sigma) times the least factor c >= 1 that brings the rows of X (deviations
    from the mean; ``have``: not missing) to a median squared Mahalanobis distance against noise +
    c between at most the chi-square median of their channels (``factor``: c itself)."""
    health, rest, common = spread
    between = (Sh * health) @ Sh.T + np.diag(rest) + common * Sigma
    med = stats.chi2.median(np.maximum(have.sum(axis=1), 1))

    def over(c):
        return float(np.median(_distances(X, have, noise + c * between) / med)) - 1.0
    c = 1.0
    if over(1.0) > 0.0 and np.any(between):
        hi = 2.0
        while over(hi) > 0.0 and hi < 1e6:
            hi *= 2.0
        c = optimize.brentq(over, hi / 2.0 if hi > 2.0 else 1.0, hi, xtol=1e-3, rtol=1e-3) if over(hi) <= 0.0 else hi
    return c if factor else c * between


def _pairwise_robust(X: np.ndarray, have: np.ndarray) -> np.ndarray:
    """A robust covariance (m, m) of the rows of X (n, m) (False in ``have``: missing), each pair
    of channels on the rows that have both: (s(a + b)^2 - s(a - b)^2) / 4 of the channels a, b
    scaled to unit robust spread s (1.4826 x the median absolute deviation), scaled back
    (Gnanadesikan and Kettenring); robust to a share of outlying rows below a half, not positive
    semi-definite in general."""
    def scale(x):
        return float(robust_sd(x)) if x.size >= 3 else 0.0
    m = X.shape[1]
    s = np.array([scale(X[have[:, j], j]) for j in range(m)])
    s = np.where(s > 0.0, s, 1.0)
    Z = X / s
    C = np.eye(m)
    for j in range(m):
        for k in range(j):
            both = have[:, j] & have[:, k]
            C[j, k] = C[k, j] = (scale(Z[both, j] + Z[both, k]) ** 2 - scale(Z[both, j] - Z[both, k]) ** 2) / 4.0
    return C * np.outer(s, s)


def _level_spread(C: np.ndarray, Sh: np.ndarray, Sigma: np.ndarray, noise: np.ndarray) -> tuple:
    """(health (p,), rest (m,), common) >= 0 with Sh diag(health) Sh^T + diag(rest) + common Sigma
    + noise nearest the covariance C (m, m) of the baselines, Sh (m, p) the health signatures,
    Sigma the flight-to-flight scatter: non-negative least squares on C's entries, each relative to
    its sampling error (sqrt(C_jj C_kk + C_jk^2): every entry counts, not only the largest
    variances)."""
    m, p = Sh.shape
    iu = np.triu_indices(m)
    d = np.maximum(np.diag(C), np.diag(noise))
    err = np.sqrt(d[iu[0]] * d[iu[1]] + C[iu] ** 2)
    basis = ([np.outer(Sh[:, j], Sh[:, j])[iu] for j in range(p)] +
             [(np.eye(m)[i][iu[0]] * (iu[0] == iu[1])) for i in range(m)] + [Sigma[iu]])
    x = optimize.nnls(np.array(basis).T / err[:, None], (C - noise)[iu] / err)[0]
    return x[:p], x[p: p + m], float(x[-1])


@dataclass
class Decision:
    """The diagnosis of one engine at one flight (one row of ``diagnosis.csv``)."""

    engine: str
    flight: int
    label: str
    source: str
    status: str
    detected: int = 0
    cls: str = "none"
    kind: str = ""
    onset: int = -1
    magnitude: float = float("nan")
    magnitude_std: float = float("nan")
    bias: float = float("nan")
    confidence: float = float("nan")
    runner_up: str = ""
    p_value: float = float("nan")
    statistic: float = float("nan")
    detail: str = ""
    missing: str = ""
    earlier: str = ""


CSV_FIELDS = ("engine", "flight", "label", "status", "detected", "class", "kind", "onset", "magnitude",
              "magnitude_std", "bias", "confidence", "runner_up", "p_value", "statistic", "detail",
              "missing", "earlier", "source")


def _shape(t: np.ndarray, tau: float, shape: str) -> np.ndarray:
    """f(tau) at flight numbers t (n,): a ramp max(0, t - tau + 1) (shape ``ramp``: a drift from
    tau, per flight), else a step 1[t >= tau]."""
    return np.maximum(0.0, t - tau + 1.0) if shape == "ramp" else (t >= tau).astype(float)


def _fit_changes(D, Wt, S, t, taus, shape, bank, cfg, trend=False, steps=(), spread=None, level=True, ramps=(),
                 slope=None):
    """For each change point tau and hypothesis: statistic, estimate, its covariance.

    D (n, m) deviations at flights t (n,), Wt (m, m) whitening (Wt @ d ~ N(0, I)), S (m, ncol)
    signatures. The engine's own level is a nuisance (unless ``level`` is False: D is then
    measured from the fleet's level), and with ``trend`` also a straight line in
    t per channel (the engine's normal wear), so that a step is a jump off the engine's own wear
    line; and a step per channel at each flight number of ``steps`` (faults already found: a new
    change is measured from them, its uncertainty growing by eps of their size), and a ramp
    per channel from each (onset, rate (m,)) of ``ramps`` (drifts found, with their fitted
    rates). The signatures are uncertain by a fraction ``cfg.eps`` of the change they describe
    (linearisation at the database's nodes, fault sizes beyond the linear range), so the
    covariance of the change estimate grows by (eps * change)^2 per channel, the change being
    the observed one (common to every hypothesis, which keeps their statistics comparable). A
    pair that is one of its components' curvature (:func:`_curved`) is not fitted.
    ``spread`` (m, m): a covariance the change estimate also has (the fleet's normal wear rates
    for a wear ramp, :func:`wear_reference`). ``slope``: (mean (m,), covariance (m, m)) the
    wear line is held to with ``trend`` (:func:`_held_slope`; default: free per channel).
    Returns a list of (tau, hypothesis index, T, theta, cov, E) with E = g2 |Wt delta|^2 the
    likelihood gain of an unconstrained change at tau (no signature uncertainty; with a held
    line or ``spread``, Wt delta's norm in the metric of its covariance without that uncertainty):
    what locates the change point, since T saturates near 1/eps^2 per channel for a large change
    at any tau."""
    out = []
    n = t.size
    groups = []
    for r in sorted({len(h.columns) for h in bank}):
        his = [i for i, h in enumerate(bank) if len(h.columns) == r]
        groups.append((his, np.array([bank[i].columns for i in his])))
    if not level:
        X = np.zeros((n, 0))
    elif trend and n >= 4:
        X = np.column_stack([np.ones(n), t - t.mean()])
    else:
        X = np.ones((n, 1))
    X = np.column_stack([X] + [_shape(t, r, "ramp") for r, _ in ramps] + [_shape(t, s, "step") for s in steps])
    Xp = np.linalg.pinv(X)
    # a fault found varies from flight to flight by the signatures' uncertainty too: what it
    # leaves in a new change is eps of its own size per channel: a step's coefficient here; a
    # drift's rate as found times its flights so far (its coefficient here would hold much of
    # any later change)
    eps = cfg.eps
    sizes = [(Xp @ D)[X.shape[1] - len(steps):]] + [rate[None] * (t[-1] - r + 1.0) for r, rate in ramps]
    known = np.sum((eps * np.vstack(sizes)) ** 2, axis=0)
    within = _within(tuple((h.name, tuple(h.columns)) for h in bank))
    wnorm2 = float(np.linalg.norm(Wt, 2)) ** 2 if within else 0.0
    # every change point at once (stacks over the change points; the fits are per point)
    taus = np.asarray(taus, dtype=float)
    if n < 2 or taus.size == 0:
        return out
    F = _shape(t[:, None], taus[None, :], shape)           # (n, K)
    G = F - X @ (Xp @ F)                                  # the nuisance (level, wear line) projected out
    g2 = np.sum(G * G, axis=0)
    use = g2 >= 1e-9
    taus, G, g2 = taus[use], G[:, use], g2[use]
    if taus.size == 0:
        return out
    delta = (D.T @ G / g2).T                              # (K, m) the observed change (per unit of f), relative
    WD = delta @ Wt.T                                     # whitened
    m = D.shape[1]
    C0 = np.eye(m)[None] / g2[:, None, None]             # its whitened covariance
    held = slope is not None and trend and n >= 4
    if held:
        WD, C0 = _held_slope(D, Wt, X, Xp, F[:, use], WD, g2, slope)
        delta = np.linalg.solve(Wt, WD.T).T
    if spread is not None:
        C0 = C0 + Wt @ spread @ Wt.T
    E = (np.einsum("ki,ki->k", WD, np.linalg.solve(C0, WD[:, :, None])[:, :, 0]) if held or spread is not None
         else g2 * np.sum(WD * WD, axis=1))
    Cw = C0 + (Wt[None] * ((eps * delta) ** 2 + known)[:, None, :]) @ Wt.T
    Lw = np.linalg.cholesky(Cw)
    v = np.linalg.solve(Lw, WD[:, :, None])[:, :, 0]      # whitened change estimate, N(0, I) if none
    Sw = np.linalg.solve(Lw, np.broadcast_to(Wt @ S, (taus.size,) + S.shape))
    per = [dict() for _ in taus]
    tl, El = list(taus), E.tolist()
    for his, cols in groups:                              # the hypotheses of one rank at once
        A = Sw[:, :, cols].transpose(0, 2, 1, 3)          # (K, hypotheses, m, rank)
        At = A.transpose(0, 1, 3, 2)
        GA = At @ A
        # conditioned with unit columns: a sensor's column is per raw unit (per Pa of a pressure:
        # 1e-6 of a component's), and a component with a pressure sensor read ill-conditioned, so
        # never fitted (a recovery judged every sensor fault before it repaired)
        g = np.sqrt(np.einsum("...ii->...i", GA))
        g = np.where(g > 0.0, g, 1.0)
        gg = g[..., :, None] * g[..., None, :]
        w = np.linalg.eigvalsh(GA / gg)                  # (its condition number below 1e12)
        ok = w[..., 0] > 1e-12 * w[..., -1]
        Gi = np.linalg.inv(np.where(ok[..., None, None], GA / gg, np.eye(GA.shape[-1]))) / gg
        b = (At @ v[:, None, :, None])[..., 0]
        th = (Gi @ b[..., None])[..., 0]
        T = np.sum(b * th, axis=-1)
        # (one tuple per fit: Python lists and row views, not numpy scalar indexing, which took
        # a fifth of a long history's time)
        thetas, covs = list(th.reshape(-1, th.shape[-1])), list(Gi.reshape((-1,) + Gi.shape[-2:]))
        T, ok = T.tolist(), ok.tolist()
        for k, (tau, e) in enumerate(zip(tl, El)):
            at, Tk, fits = k * len(his), T[k], per[k]
            for i, hi in enumerate(his):
                if ok[k][i]:
                    fits[hi] = (tau, hi, Tk[i], thetas[at + i], covs[at + i], e)
    for k, fits in enumerate(per):
        curved = _curved(fits, within, bank, S, Wt, Cw[k], delta[k], g2[k] * wnorm2, cfg)
        out += [f for hi, f in fits.items() if hi not in curved]
    return out


def _held_slope(D, Wt, X, Xp, F, WD, g2, slope):
    """The whitened change estimates WD (K, m) and their covariance (K, m, m) with the engine's
    wear line (column 1 of the nuisances X (n, p), pseudo-inverse Xp) held to the fleet's normal
    wear, ``slope`` = (mean (m,), covariance (m, m)) of :meth:`FleetNorm.trend`, instead of free
    per channel: a free slope took up most of a drift that starts mid-history (an HPC losing
    0.1 %/flight from flight 10: T 13 at flight 22 with a free slope, 148 with none). F (n, K):
    the change shapes, g2 (K,) their squared norms off the nuisances. The Gaussian conditioning
    of the change on the slope estimated with it."""
    mean, cov = slope
    m = WD.shape[1]
    c = (Xp @ F)[1]                                        # (K,) the slope's share of each shape
    p_bd, p_bb = -c / g2, (Xp @ Xp.T)[1, 1] + c ** 2 / g2
    beta = (Xp @ D)[1][None] @ Wt.T - c[:, None] * WD - Wt @ mean       # (K, m) whitened slope off the fleet's
    lam, U = np.linalg.eigh(Wt @ cov @ Wt.T)
    inv = 1.0 / (np.maximum(lam, 0.0)[None] + p_bb[:, None])            # (K, m)
    WD = WD - p_bd[:, None] * (((beta @ U) * inv) @ U.T)
    C0 = np.eye(m)[None] / g2[:, None, None] - (p_bd ** 2)[:, None, None] * ((U[None] * inv[:, None, :]) @ U.T)
    return WD, C0


@lru_cache(maxsize=64)
def _within(bank: tuple) -> dict[int, list[int]]:
    """Bank index of each single component -> the indices of the pairs that hold it; ``bank``
    ((name, columns), ...) as a key (the same few banks are fitted thousands of times)."""
    single = [i for i, (name, _) in enumerate(bank) if "+" not in name and not name.startswith("sensor:")]
    return {i: [j for j, (name, cols) in enumerate(bank) if "+" in name and set(bank[i][1]) < set(cols)]
            for i in single}


def _curved(fits: dict, within: dict, bank, S, Wt, Cw, delta, scale, cfg) -> set:
    """The pairs (bank indices) that are a single component's loss beyond the signatures' linear
    range. A loss of one component moves the channels by more than its signature of the fitted
    size says, second order in the size and as much in channels the signature barely moves as in
    the others (the turbofan's HPT at -8 %: T30 +0.9 % where its signature gives -0.6 %); a
    second component takes that up: HPT and HPC losses of 8 % read 'lpc+hpt' and 'lpc+hpc', LPC
    at -5 to -11 %. With the component's own curvature, ``cfg.curvature`` times the mean square
    of its fitted change over the channels per channel, added to the covariance ``Cw`` (whitened
    by ``Wt``), a pair holding it that no longer gains more than its extra cost is that
    component's curvature (``scale``: g^T g |Wt|^2, what a variance per channel is at most in
    units of the change's whitened covariance). ``benchmarks/curvature.py`` measures what a plant
    needs."""
    out = set()
    for c, pairs in within.items():
        if c not in fits or not any(p in fits for p in pairs):
            continue
        a2 = (cfg.curvature * float(np.mean((S[:, bank[c].columns] @ fits[c][3]) ** 2))) ** 2
        if a2 * scale < 1e-2:                 # negligible against the scatter of the change
            continue
        L = np.linalg.cholesky(Cw + a2 * (Wt @ Wt.T))
        v, Sw = np.linalg.solve(L, Wt @ delta), np.linalg.solve(L, Wt @ S)

        tried = [p for p in pairs if p in fits]
        gain = {}                              # the pair's fit over the component's, v^T A (A^T A)^-1 A^T v
        for r in {len(bank[h].columns) for h in [c] + tried}:
            his = [h for h in [c] + tried if len(bank[h].columns) == r]
            A = Sw[:, np.array([bank[h].columns for h in his])].transpose(1, 0, 2)
            b = A.transpose(0, 2, 1) @ v
            gain.update(zip(his, np.sum(b * np.linalg.solve(A.transpose(0, 2, 1) @ A, b[:, :, None])[:, :, 0], axis=1)))
        out.update(p for p in tried if gain[p] - gain[c] < bank[p].cost(cfg) - bank[c].cost(cfg))
    return out


#: a component change is its flow capacity's alone (not maintenance: :func:`_maintenance`) when its
#: efficiency rose by less than this share of its flow's change and by less than MAINTENANCE_Z
#: standard errors, the flow's change beyond them: flow-only changes of 2 % read 0.05-0.27 (the
#: LPC's efficiency +0.5 +- 0.5 % one flight after), fan and HPC washes on their first flights
#: 0.65-0.95 (probe_tables), their fan efficiency 1.6-2.3 se
MAINTENANCE_SHARE = 0.5
MAINTENANCE_Z = 2.0


def _maintenance(names: list[str], th: np.ndarray, cov: np.ndarray) -> bool:
    """Whether a change of health columns ``names`` (fitted ``th``, covariance ``cov``; sensor
    columns may be among them) is maintenance, a wash or a repair: every efficiency rises, and no
    component's change is its flow capacity's alone (:data:`MAINTENANCE_SHARE`). An HPT eroding
    2 % of flow capacity with its efficiency unmoved (+0.09 +- 0.16 %), an LPC fouled 2 % in flow
    only (+0.19 +- 0.53 %), read as recoveries by the sign of the efficiency's noise, and the new
    baseline lost the fault."""
    effs = [i for i, n in enumerate(names) if n.endswith("_eff")]
    if not effs or min(th[i] for i in effs) <= 0:
        return False
    sd = np.sqrt(np.diag(cov))
    for i in effs:
        for k, n in enumerate(names):
            if k != i and component(n) == component(names[i]) and abs(th[k]) >= MAINTENANCE_Z * sd[k] and \
                    th[i] < min(MAINTENANCE_SHARE * abs(th[k]), MAINTENANCE_Z * sd[i]):
                return False
    return True


def _decide(dec, stage, bank, S, t, es, rowsok, n_tests, cfg, held=False) -> bool:
    """The change point and shape of one stage with the largest likelihood gain of an
    unconstrained change, then the hypothesis there with the largest T - cost; fill ``dec`` and
    return True if it is detected (Bonferroni p below alpha and big enough). Shape ``wear``: a
    ramp from the first flight tested against the fleet's normal wear (its size need not reach
    min_rate, only min_step over the history); ``level``: the baseline against the fleet's
    normal level (min_step). Wear or a level whose efficiencies are all better than the fleet's
    is not a fault."""
    by_point = {}
    for shape, fits in stage:
        for f in fits:
            by_point.setdefault((shape, f[0]), []).append(f)
    # a drift whose efficiencies all rise is no engine's: components do not get better by
    # themselves, a flight at a time (a loss from the second flight fitted a step at 1 or, as
    # well with the wear line, an LPC "drift" of +1.5 %/flight from 2); the next change point.
    # The pairs that are a component's curvature are left out at the points tried only (testing
    # every fit took a fifth of a long history's time)
    for shape, tau in sorted(by_point, key=lambda k: -by_point[k][0][5]):
        here = [f for f in by_point[(shape, tau)] if not _curvature(bank[f[1]], f[3], S, es.columns)
                and not (shape in ("wear", "level") and sensor_pair(bank[f[1]].name))]
        if not here:
            continue
        _, hi, T, th, cov, _ = max(here, key=lambda f: f[2] - bank[f[1]].cost(cfg))
        better = _maintenance([es.columns[c] for c in bank[hi].columns], th, cov)
        if not (shape in ("ramp", "wear") and better):
            break
    else:
        return False
    h = bank[hi]
    # detected on the bank without the pairs of sensors (they only isolate: two biases at once
    # were one bias and a component, or a 'recovery'), so that the test and its bound are theirs
    _, di, T_d, th_d, _, _ = max((f for f in here if not sensor_pair(bank[f[1]].name)),
                                 key=lambda f: f[2] - bank[f[1]].cost(cfg))
    p = float(stats.chi2.sf(T_d, len(bank[di].columns))) * n_tests
    size = float(np.linalg.norm(S[:, bank[di].columns] @ th_d))   # fitted change (rate for ramps), relative
    # wear is the components': a sensor has no fleet wear to compare with, so its trend from the
    # first flight (or the first flights tested) is a drift held to min_rate (a slower one is as
    # likely the seasons in the model's error: fuel flow "wearing" 0.03 %/flight over a winter and
    # a summer). A sensor's drift from a later flight, level before it, is not: T48 drifting
    # 0.05 %/flight from flight 10 was 15 K off at flight 40 and never named
    sensor = "sensor:" in bank[di].name
    early = tau <= t[min(2, t.size - 1)]
    sensor_trend = sensor and (shape == "wear" or (shape == "ramp" and early))
    if shape in ("ramp", "wear"):
        # a component's drift off a wear line ``held`` to the fleet's (:func:`_held_slope`) is
        # judged against the fleet, as its wear is: no min_rate (an engine wearing its fan
        # 0.05 %/flight from flight 0 fitted a drift from flight 2, held to min_rate it was lost)
        floor = cfg.min_rate if (shape == "ramp" and not held and not sensor) or sensor_trend else 0.0
        big = size >= floor and size * (t[-1] - tau + 1) >= cfg.min_step
    else:
        big = size >= cfg.min_step
    if not (p < cfg.alpha and big) or (shape in ("wear", "level") and better):
        return False
    # confidence among the bank at the chosen change point and shape
    sc = np.array([f[2] - bank[f[1]].cost(cfg) for f in here])
    w = np.exp((sc - sc.max()) / 2.0)
    w /= w.sum()
    order = np.argsort(-w)
    dec.detected, dec.cls, dec.statistic = 1, h.name, T
    dec.kind = "drift" if shape == "ramp" or sensor_trend else shape
    if held and shape == "ramp" and early:
        # the first ramp a held wear line leaves room for is a trend from the first flight (a
        # component's: wear; a fan wearing 0.05 %/flight from flight 0 read a drift from flight 2)
        tau = t[0]
        dec.kind = "drift" if "sensor:" in h.name else "wear"
    if shape == "step" and better:     # every efficiency up: maintenance, not a fault
        dec.detected, dec.kind, dec.status = 0, "recovery", "recovery"
    dec.onset = int(tau)
    dec.confidence = float(w[order[0]])
    dec.runner_up = bank[here[order[1]][1]].name if len(order) > 1 else ""
    _size(dec, es, rowsok, h.columns, th, cov, 0 if h.name.startswith("sensor:") else None)
    return True


#: the largest share of a two-component fit the component whose efficiency rises may hold (its
#: part of the fitted change over the other's) for the pair to be a single fault's curvature
#: (:func:`_curvature`): LPC losses of 3-5 % read 'lpc+hpc' with shares 0.11-0.15 (seed-1, seed-3
#: benchmarks); an engine given another's health (a swap) makes mixed pairs of shares 0.43-0.88
CURVATURE_SHARE = 0.25


def _curvature(h: Hypothesis, th: np.ndarray, S: np.ndarray, columns: list[str]) -> bool:
    """Whether ``h``, two components fitted ``th`` (signatures S (m, ncol)), is one component's
    loss beyond the signatures' linear range with the other taking up the curvature: one
    efficiency falls, the other rises (neither a combined fault nor maintenance), and the rising
    component's part of the fitted change is at most CURVATURE_SHARE of the other's. An LPC loss
    of 3-5 % read 'lpc+hpc' (hpc efficiency +0.2 %) on 9 flights of the seed-1 benchmark and 8
    of a seed-3 fleet; the single component is reported."""
    if "+" not in h.name or "sensor:" in h.name:
        return False
    parts: dict[str, list[int]] = {}
    for i, c in enumerate(h.columns):
        parts.setdefault(component(columns[c]), []).append(i)
    eff = {k: next((th[i] for i in ix if columns[h.columns[i]].endswith("_eff")), 0.0) for k, ix in parts.items()}
    if len(parts) != 2 or min(eff.values()) >= 0 or max(eff.values()) <= 0:
        return False
    size = {k: float(np.linalg.norm(S[:, [h.columns[i] for i in ix]] @ th[ix])) for k, ix in parts.items()}
    up, down = max(eff, key=eff.get), min(eff, key=eff.get)
    return size[up] <= CURVATURE_SHARE * size[down]


def _size(dec, es, rowsok, cols, th, cov, sensor=None) -> None:
    """Fill ``dec``'s detail (every fitted parameter: columns ``cols`` of ``es``, values ``th``,
    covariance ``cov``) and magnitude with its standard error: the first efficiency's change (else
    the first parameter's), or, ``sensor`` being the index in ``cols`` of the decision's sensor,
    that sensor's bias (:func:`_sensor_size`)."""
    names = [es.columns[c] for c in cols]
    sd = np.sqrt(np.diag(cov))
    dec.detail = " ".join(f"{c}={v:+.5f}" for c, v in zip(names, th))
    main = next((i for i, c in enumerate(names) if c.endswith("_eff")), 0)
    dec.magnitude, dec.magnitude_std = float(th[main]), float(sd[main])
    if sensor is not None:
        # a scheduling sensor's gain part (its next column): the bias at its mean level is both
        g = sensor + 1
        gain = (th[g], cov[g, g], cov[sensor, g]) if g < len(cols) and names[g] == f"gain:{names[sensor][7:]}" else None
        dec.magnitude, dec.magnitude_std, dec.bias = _sensor_size(es, rowsok, cols[sensor], th[sensor], sd[sensor], gain)


def _sensor_size(es, rowsok, col, value, sd, gain=None) -> tuple[float, float, float]:
    """(magnitude, its standard error, bias) of a bias ``value`` +- ``sd`` of the sensor in
    signature column ``col``: a sensed output's bias is fitted in raw units (the bias) and reported
    as a fraction of its level; an input's (fuel flow) is relative, its bias value * level. A
    scheduling sensor's ``gain`` (value, variance, covariance with ``value``) adds gain x its mean
    level to the offset."""
    lev = float(np.nanmean(es.level[rowsok][:, col]))
    if gain is not None:
        g, var, c = gain
        value, sd = value + g * lev, np.sqrt(max(sd ** 2 + lev ** 2 * var + 2.0 * lev * c, 0.0))
    if es.columns[col][7:] in es.input_names:
        return float(value), float(sd), float(value * lev)
    return float(value / lev), float(sd / abs(lev)), float(value)


def _sensor_part(dec, D, Wt, S, t, bank, cfg, known, n_tests, es, rowsok) -> None:
    """A sensor's part of a change is a fault, never maintenance. ``dec`` is a recovery (a step
    whose efficiencies all rise). The same step (deviations D at flight numbers t, whitening Wt,
    signatures S, the changes found before it, ``known`` as in :func:`_stages`, as nuisances,
    as in the stage that found it) is
    fitted with every component hypothesis c of the bank (one component or two), alone and with
    each sensor's bias (the bank holds no pair of components with a sensor, and a single flight
    may pair the wrong component with the right sensor). When the best of them (largest T -
    cost) holds a sensor whose likelihood gain over its c alone pays its isolation cost, is
    significant (chi-square, 1 degree of freedom, Bonferroni over ``n_tests`` as a detection)
    and is at least ``min_step``, ``dec`` becomes that sensor's step fault, detected, its detail
    listing the components fitted with it (the recovery); the engine is then not put on a new
    baseline, which would hide the bias for ever. Probe fleet D: a fan and HPC wash with T48
    reading 38 K high from the same flight was a fan+hpc recovery and the bias never reported;
    an HPT repair with T30 26 K high an hpt+sensor:T30 recovery. There a pure recovery's best
    sensor gains at most 3.5 (five washes and repairs), those biases 147-208."""
    comps = [h for h in bank if "sensor:" not in h.name]
    sensors = [h for h in bank if single_sensor(h.name)]
    cands = comps + [Hypothesis(f"{c.name}+{x.name}", c.columns + x.columns) for c in comps for x in sensors]
    fits = _fit_changes(D, Wt, S, t, [float(dec.onset)], "step", cands, cfg, trend=cfg.wear,
                        **_nuisance(known, dec.onset))
    if not fits:
        return
    score = {f[1]: f[2] - cands[f[1]].cost(cfg) for f in fits}
    _, hi, T, th, cov, _ = max(fits, key=lambda f: score[f[1]])
    if hi < len(comps):
        return
    c, h = comps[(hi - len(comps)) // len(sensors)], cands[hi]
    x = sensors[(hi - len(comps)) % len(sensors)]
    r = len(x.columns)                             # its offset (and a scheduling sensor's gain)
    alone = next((f[2] for f in fits if f[1] == comps.index(c)), None)
    size = float(np.linalg.norm(S[:, h.columns[-r:]] @ th[-r:]))
    if alone is None or T - alone < h.cost(cfg) - c.cost(cfg) or \
            stats.chi2.sf(T - alone, r) * n_tests >= cfg.alpha or size < cfg.min_step:
        return
    # nor what every component restored explains: an overhaul (every health parameter back to
    # new) fitted two components with T30 2.9 K or Ps30 3 kPa off, a lasting false sensor fault
    health = [i for i, n in enumerate(es.columns) if not n.startswith(("sensor:", "gain:"))]
    wide = _fit_changes(D, Wt, S, t, [float(dec.onset)], "step",
                        [Hypothesis("", health), Hypothesis("", health + x.columns)], cfg, trend=cfg.wear,
                        **_nuisance(known, dec.onset))
    if len(wide) == 2 and stats.chi2.sf(wide[1][2] - wide[0][2], r) * n_tests >= cfg.alpha:
        return
    sc = np.array(sorted(score.values(), reverse=True))
    w = np.exp((sc - sc[0]) / 2.0)
    dec.detected, dec.kind, dec.status, dec.cls = 1, "step", "ok", x.name
    dec.statistic, dec.confidence = T, float(w[0] / w.sum())
    dec.runner_up = cands[sorted(score, key=lambda i: -score[i])[1]].name
    _size(dec, es, rowsok, h.columns, th, cov, len(h.columns) - r)


#: the quantile of an engine's flight-to-flight differences that gives its own scatter: a step
#: fault is one large difference, a bias on random flights about half of them; one on every other
#: flight is all of them after it began, hence the sensors seen are left out (:func:`own_scatter`)
OWN_QUANTILE = 0.3
#: the most an engine's own scatter may exceed the fleet's (variance ratio; 5 x its standard
#: deviation). Probe fleet A: a T48 bias of 38 K on the even flights from 8 raised it from 1.1 to
#: 542 at flight 22 and the fault was dropped there (now 1.0: T48 left out). Measured besides: at
#: most 1.5 on the seed-1 and seed-7 benchmarks (12.5 with a P50 bias, whose relative deviation
#: varies with the flight conditions, before the sensors seen were left out); on probe fleet C 20
#: for an LPT wearing 0.2 % a flight, 52 for a T30 drifting 0.5 noise sigma a flight (before its
#: first step is seen)
OWN_MAX = 25.0
#: an engine judged against more than this ratio (3 x the fleet's standard deviation) is named
#: in a warning: a noisier engine, or a fault of its own it is less sensitive to
OWN_WARN = 9.0


def own_scatter(D: np.ndarray, Wt: np.ndarray, faults: np.ndarray | None = None) -> float:
    """How much more an engine's deviations D (n, m) scatter from flight to flight than the
    fleet's (whitening Wt): the OWN_QUANTILE quantile of its successive differences' squared
    whitened norms over that of 2 chi-square(m), at least 1 (1 with fewer than 2 differences) and
    at most OWN_MAX. An engine with noisier sensors than the fleet's (a worn harness, a sensor of
    another make) is then tested against its own noise, not flagged for it. ``faults`` (m, k):
    signatures of the sensors whose steps were seen on the engine; the differences are measured
    without them (k fewer degrees of freedom), so that a bias toggling on most flights does not
    make the engine's own scatter; OWN_MAX bounds what other faults of its own (a drift) make."""
    X = np.diff(D, axis=0) @ Wt.T
    if X.shape[0] < 2:
        return 1.0
    dof = D.shape[1]
    if faults is not None and faults.size:
        Q = np.linalg.qr(Wt @ faults)[0]
        X = X - (X @ Q) @ Q.T
        dof -= Q.shape[1]
    md = np.sum(X ** 2, axis=1) / 2.0
    return min(OWN_MAX, max(1.0, float(np.quantile(md, OWN_QUANTILE) / stats.chi2.ppf(OWN_QUANTILE, dof))))


def _frozen(es: EngineSeries, k: int, base: int, sensor: str) -> bool:
    """Whether the sensor's snapshot value did not vary on flight k (standard error, in every
    regime with data, below a thousandth of the baseline's first flight ``base``: 0 but for
    rounding) where it did vary on that flight: a stuck sensor, not a bias."""
    cols = [i for i, c in enumerate(es.channels) if c.split("@")[0] == sensor
            and np.isfinite(es.SE[k, i]) and np.isfinite(es.SE[base, i])]
    return bool(cols) and bool(np.all(es.SE[k, cols] <= 1e-3 * es.SE[base, cols])) \
        and bool(es.SE[base, cols].max() > 0.0)


def _stuck_row(dec: Decision, es: EngineSeries, k: int, number: np.ndarray) -> None:
    """Make ``dec`` (flight position k, no fault found without the channel) the row of a sensor
    stuck there (:func:`_stuck_across`): ``sensor:<channel> stuck``, onset the first flight of its
    run of stuck flights (no fit: ``detail`` empty; its value is in the warning, :func:`stuck_note`)."""
    mine = [c for i, c, _ in es.stuck if i == k]
    if not mine:
        return
    c = mine[0]
    at = {i for i, c2, _ in es.stuck if c2 == c}
    first = k
    while first - 1 in at:
        first -= 1
    dec.detected, dec.status, dec.kind, dec.cls, dec.onset = 1, "ok", "stuck", f"sensor:{c}", int(number[first])
    dec.confidence = 1.0


def _nuisance(known: list, before: float = np.inf) -> dict:
    """The ``steps`` and ``ramps`` of :func:`_fit_changes` for the changes ``known``
    (:class:`Known`) with onsets before ``before``."""
    return {"steps": [k.onset for k in known if k.shape != "ramp" and k.onset < before],
            "ramps": [(k.onset, k.rate) for k in known if k.shape == "ramp" and k.onset < before]}


#: a change found as a drift is fitted again as a step, its onset moved by up to this many
#: flights, once twice as many flights came after it (:func:`_stages`)
REVISE_FLIGHTS = 2


def _stages(D, Wt, S, t, bank, cfg, wear, known, level=None, slope=None):
    """The fits of the stages of a flight's tests, in the order they are decided (each a list of
    (shape, fits of :func:`_fit_changes`)): deviations D (n, m) at flight numbers t (n,),
    whitening Wt, the signatures S (m, ncol) (they hardly move with the operating point: their
    mean over the flights), the fleet's normal ``wear`` and ``level`` in these channels
    ((mean (m,), covariance (m, m)) of :meth:`FleetNorm.at` and :meth:`FleetLevel.at`, or for the
    wear of an engine found to wear faster :meth:`FleetNorm.trend`) or None, ``known`` the changes
    found, in the order found (:func:`_known`), and the engine's steps of a fleet-wide change
    (shape ``fleet``: a nuisance of every test, never a decision); ``slope``: the fleet's wear
    line the engine's is held to (:meth:`FleetNorm.trend`), or None (free).

    A new change is looked for at the latest ``cfg.window`` flights, fitted on them and the
    flight before: an engine's wear is no straight line over hundreds of flights (fast at
    first, then levelling off; fouling washed off), and a line through all of them left steps
    of its curvature (a healthy engine of 150 flights read an HPT loss from flight 87). The
    change found last is fitted again on those flights and the half window before its onset;
    a drift found is fitted from before its onset (a shorter stretch is a straight line)."""
    def since(lo, known):
        """:func:`_fit_changes` on the flights from number ``lo`` on, measured from the changes
        ``known`` among them."""
        lo = min([lo] + [k.onset - cfg.n_base - 1 for k in known if k.shape == "ramp"])
        u = t >= lo
        return partial(_fit_changes, D[u], Wt, S, t[u], bank=bank, cfg=cfg, trend=cfg.wear, slope=slope,
                       **_nuisance([k for k in known if k.onset > t[u][0]]))
    recent = t[max(0, t.size - cfg.window - 1)]
    found = [k for k in known if k.shape != "fleet"]
    if found:   # a new change after the changes found, measured from them; else the last one again
        last, fit = found[-1], since(recent, known)
        new = t[t > max(last.onset, recent)]
        local = since(min(recent, last.onset - cfg.window // 2), [k for k in known if k is not last])
        again = local(np.array([last.onset]), last.shape)
        stages = [[("step", fit(new, "step")), ("ramp", fit(new, "ramp"))], [(last.shape, again)]]
        # a drift also as a step near its onset, first when that locates the change better, once
        # as many flights came after it as the shapes need to part (a step two flights old fitted
        # a drift as well: confirmed so, its refit faded as the flights after stayed level, and the
        # bias was lost). Not a step as a drift: early in a history the wear line takes a step's
        # flights apart (a bias from the second flight read a drift from the third every other flight)
        near = t[(np.abs(t - last.onset) <= REVISE_FLIGHTS) & (t > t[0])]
        if last.shape == "ramp" and t[-1] - last.onset >= 2 * REVISE_FLIGHTS and near.size:
            other = local(near, "step")
            if other and again and max(f[5] for f in other) > max(f[5] for f in again):
                stages.insert(1, [("step", other)])
        return stages
    fit = partial(_fit_changes, D, Wt, S, t, bank=bank, cfg=cfg, trend=cfg.wear, slope=slope, **_nuisance(known))
    stages = _first_stages(fit, since(recent, known), D, Wt, S, t, bank, cfg, wear, _nuisance(known)["steps"], slope)
    if level is not None:
        # 3. nothing changed since the first flight: is the baseline itself off the fleet's?
        stages.append([("level", _level_fits(D, Wt, S, t, bank, cfg, level))])
    return stages


def _level_fits(D, Wt, S, t, bank, cfg, level) -> list:
    """The fits (:func:`_fit_changes`) of the engine's baseline (its first n_base + 1 flights of
    deviations D at flight numbers t) less the fleet's normal ``level`` (mean, covariance, the
    names of the hypotheses along which it is off the other engines: :meth:`FleetLevel.off`), with
    that covariance and no level nuisance: how it is off the fleet's from its first flight."""
    mean, spread, off = level
    base = slice(0, cfg.n_base + 1)
    return [f for f in _fit_changes(D[base] - mean, Wt, S, t[base], t[:1], "step", bank, cfg, spread=spread, level=False)
            if bank[f[1]].name in off]


def _calibration(D, Wt, S, t, bank, cfg, level, n_tests, columns) -> list[tuple[int, float]]:
    """The raw-unit offsets [(signature column, offset)] of the sensors the engine's baseline
    is off the fleet's by (:func:`_level_fits`: the best hypothesis holds a sensor, Bonferroni p
    below alpha over ``n_tests``, at least min_step): a thermocouple or transducer calibrated off
    by a constant from its first flight. Such an offset is constant in its raw unit, not in the
    relative deviations, which move with each flight's operating point (the trims move up to
    10 % between flights): read against the engine's relative level it made steps, drifts and
    intermittent biases of the wrong sign on most flights (probe fleet P1: T48 +39 K from flight
    0 -> 'sensor:T48 intermittent -2.7 K' on 12 of 21 flights). :func:`_calibrated` takes the
    part that moves out."""
    fits = _level_fits(D, Wt, S, t, bank, cfg, level)
    if not fits:
        return []
    _, hi, T, th, _, _ = max(fits, key=lambda f: f[2] - bank[f[1]].cost(cfg))
    h = bank[hi]
    sensors = [(c, float(v)) for c, v in zip(h.columns, th) if columns[c].startswith("sensor:")]
    big = float(np.linalg.norm(S[:, [c for c, _ in sensors]] @ np.array([v for _, v in sensors]))) if sensors else 0.0
    if not sensors or stats.chi2.sf(T, len(h.columns)) * n_tests >= cfg.alpha or big < cfg.min_step:
        return []
    return sensors


def _calibrated(D, Sk, offsets, base: int) -> np.ndarray:
    """Deviations D (n, m) less the part of the raw-unit sensor ``offsets`` (:func:`_calibration`)
    that moves from flight to flight: sum of offset x (S_k - its mean over the first ``base``
    flights) in the offset's signature column, Sk (n, m, ncol) each flight's signatures. The
    baseline's mean stays: the level test still sees the offset."""
    for c, v in offsets:
        col = Sk[:, :, c]
        D = D - v * (col - col[:base].mean(axis=0))
    return D


def _steadied(D, Sk, t, Wt, found: list, columns: list[str]) -> np.ndarray:
    """Deviations D (n, m) at flight numbers t (n,) less the part of each sensor offset of a step
    found (``found``: Decisions; its raw-unit size in the fit of its ``detail``) that moves from
    flight to flight after its onset: offset x (S_k - its mean over those flights) in its
    signature column, Sk (n, m, ncol) each flight's signatures (as :func:`_calibrated` for an
    offset from the first flight), where that leaves the flights after it steadier (whitening
    Wt): a raw-unit offset is no constant share of a channel whose level moves with each
    flight's operating point (Ps30 30 kPa high read 1.7-2.9 % at cruise from one flight to the
    next, later tests found an HPT change in that scatter, whose 'recovery' then repaired the
    bias), but a sensor reading a share off (a gain) is."""
    def spread(x):
        return float(np.sum(((x - x.mean(axis=0)) @ Wt.T) ** 2))
    for f in found:
        if f.kind != "step" or not f.detail:
            continue
        after = t >= f.onset
        for name, v in (kv.split("=") for kv in f.detail.split()):
            if name.startswith("sensor:") and name in columns and after.sum() >= 3:
                alt = _calibrated(D[after], Sk[after], [(columns.index(name), float(v))], int(after.sum()))
                if spread(alt) < spread(D[after]):
                    D = D.copy()
                    D[after] = alt
    return D


def _first_stages(fit, recent, D, Wt, S, t, bank, cfg, wear, fleet, slope=None):
    """Stages 1 and 2 of :func:`_stages` on an engine without a fault found (``fleet``: the
    flight numbers of its steps of a fleet-wide change, nuisances of ``fit`` too; ``slope``: the
    fleet's wear line its own is held to, or None). ``fit``: :func:`_fit_changes` on every flight,
    ``recent`` on the latest ``cfg.window`` and the flight before (:func:`_stages`)."""
    # 1. a step or a drift that starts after the first flights, off the engine's wear line; held
    #    to the fleet's, with wear faster than the fleet's among them (a ramp from the first
    #    flight, its estimate carrying the fleet's spread of wear lines): else an engine wearing
    #    every component faster than its fleet read a sensor step at flight 1 (the change the
    #    held line left room for that fitted its trend best)
    def faster(normal):
        """The fits of wear faster than ``normal`` (mean, covariance): a ramp from the first flight."""
        mean, spread = normal
        return ("wear", _component_wear(partial(_fit_changes, D - np.outer(t, mean), Wt, S, t, cfg=cfg,
                                                spread=spread, steps=fleet), bank, t[:1], "ramp"))
    taus = t[1:][-cfg.window:]
    stage1 = [("step", recent(taus, "step")), ("ramp", recent(taus, "ramp"))]
    if slope is not None and cfg.wear:
        stage1.append(faster(slope))
    # 2. with the wear line as nuisance, wear faster than normal is tested on its own: the
    #    engine's whole-history rate (a ramp from the first flight, level only), against the
    #    fleet's normal wear when there is a fleet
    if not cfg.wear:
        return [stage1]
    if wear is None:
        return [stage1, [("ramp", _component_wear(partial(fit, trend=False), bank, t[:1], "ramp"))]]
    return [stage1, [faster(wear)]]


#: a trend from the first flight is read as a sensor's (alone or with a component) only when all
#: the components together do not fit it significantly better, at this level (:func:`_component_wear`)
SENSOR_TREND_LEVEL = 0.05


def _component_wear(fit, bank, taus, shape) -> list:
    """The fits ``fit(taus, shape, bank=...)`` (:func:`_fit_changes`) of a trend from the first
    flight, less those of the hypotheses holding a sensor that every health parameter free (the
    wear of any mix of components) fits significantly better: T_all - T beyond the chi-square
    point at 1 - SENSOR_TREND_LEVEL with the difference in parameters. Wear is the components',
    and the bank holds at most two: an engine wearing all five components 0.05 %/flight (probe
    fleet H1, docs/diagnostics.md) fitted no hypothesis (at flight 27 the best two left
    residuals of 45 and 68, chi-square with 13 and 12 degrees of freedom; all ten health
    parameters 0.3), and the cost per parameter then chose a cheap one holding a sensor:
    fan+sensor:Ps30 drift on every flight from 5 (at 0.03 %/flight, probe fleet C: sensor:Wf at
    5-6). A real sensor trend is a change the components fit worse (a T48 drift of 0.3 sigma a
    flight: T_all - T = +0.3 at flight 3, -110 at 17)."""
    fits = [f for f in fit(taus, shape, bank=bank) if not sensor_pair(bank[f[1]].name)]   # (not from delivery)
    comps = sorted({c for h in bank if "sensor:" not in h.name for c in h.columns})
    every = fit(taus, shape, bank=[Hypothesis("components", comps)]) if comps else []
    if not every:              # fewer channels than health parameters (or none any moves): no such comparison
        return fits
    T_all = every[0][2]
    cut = {r: stats.chi2.ppf(1 - SENSOR_TREND_LEVEL, max(1, len(comps) - r)) for r in {len(h.columns) for h in bank}}
    return [f for f in fits if "sensor:" not in bank[f[1]].name or T_all - f[2] < cut[len(bank[f[1]].columns)]]


#: a flight is a transition (:func:`_transition`) when its regimes differ in how far they have
#: moved from the flights before to the flight after with this significance (chi-square, as many
#: degrees of freedom as regimes less one), and their shares by at least TRANSITION_SPREAD
TRANSITION_ALPHA = 1e-6
TRANSITION_SPREAD = 0.3


def _around(D: np.ndarray, Wt: np.ndarray, k: int, start: int = 0, run: int = 1):
    """The ``run`` flights before the latest (rows -1-run .. -2 of deviations D (n, m)) against the
    mean b of up to k flights before them, from row ``start`` on: (X, y, b, scale, cut, one_state)
    with X (run, m) those rows and y the latest less b, whitened (Wt), scale the variance factor of
    a flight's difference from b, cut the :data:`TRANSITION_ALPHA` chi-square quantile, one_state
    whether each of those k flights lies within cut of b (:func:`_transition`, :func:`_excursion`)."""
    end = D.shape[0] - 1 - run
    before = D[max(start, end - k): end]
    b = before.mean(axis=0)
    X, y = (D[end:-1] - b) @ Wt.T, Wt @ (D[-1] - b)
    cut = stats.chi2.ppf(1.0 - TRANSITION_ALPHA, y.size)
    one_state = np.max(np.sum(((before - b) @ Wt.T) ** 2, axis=1)) <= cut
    return X, y, b, 1.0 + 1.0 / before.shape[0], cut, one_state


def _transition(D: np.ndarray, Wt: np.ndarray, regime: np.ndarray) -> bool:
    """Whether the flight before the latest (row -2 of deviations D (n, m), whitening Wt (m, m),
    ``regime`` (m,) each channel's regime) changed during the flight: a fault that began in
    flight (a bird strike at climb, a loss at cruise). Its windows straddle the change: the
    ground-idle one before take-off as the flights before, the cruise one part way or as the
    flight after. From the mean of up to three flights before (b) to the latest (a), the flight's
    deviation d is fitted as b + alpha (a - b) with one share alpha, and with one share per regime:
    a transition when the flights before are one state, the change a - b is significant, the
    per-regime shares fit significantly better (:data:`TRANSITION_ALPHA`), differ by
    :data:`TRANSITION_SPREAD` or more and each lies within the way (-0.25..1.25). A step between
    flights has every share near 1 (or 0), a drift every share near a half."""
    regimes = np.unique(regime)
    if D.shape[0] < 4 or regimes.size < 2:
        return False
    X, y, b, scale, cut, one_state = _around(D, Wt, 3)
    x = X[0]
    if y @ y < cut * scale or not one_state:
        return False                              # no change to share out, or no one state before it
    Y = np.column_stack([Wt @ np.where(regime == r, D[-1] - b, 0.0) for r in regimes])
    shares = np.linalg.lstsq(Y, x, rcond=None)[0]
    one = (x @ y) / (y @ y)
    gain = (np.sum((x - one * y) ** 2) - np.sum((x - Y @ shares) ** 2)) / (scale * (1.0 + one ** 2))
    return bool(stats.chi2.sf(gain, regimes.size - 1) < TRANSITION_ALPHA and np.ptp(shares) >= TRANSITION_SPREAD
                and -0.25 <= shares.min() and shares.max() <= 1.25)    # each regime part of the way


#: the latest flight is back from an excursion (:func:`_excursion`) when not significantly off the
#: flights before it, or within this fraction of the excursion (its norm, whitened): an engine's
#: flights scatter more than the fleet's now and then (a normal flight 1.2 times the 1e-6 cut
#: after a bleed excursion 30 times it)
EXCURSION_BACK = 0.1


def _excursion(D: np.ndarray, Wt: np.ndarray, S: np.ndarray, bank: list[Hypothesis], start: int = 0,
               run: int = 1) -> bool:
    """Whether the ``run`` flights before the latest (rows -1-run .. -2 of deviations D (n, m),
    whitening Wt, mean signatures S (m, ncol)) were off for those flights only: the flights before
    them (from row ``start``: the latest change found; an excursion on the flight after a fault's
    onset read as a second fault) one state, each of them significantly off that state, the latest
    back (not significantly off it or within :data:`EXCURSION_BACK` of the excursion, and
    significantly off each of them), and no single sensor's bias explaining their mean (an
    intermittent sensor fault is its own finding, :func:`_episodes`). An engine flown with
    anti-ice or a customer bleed on, or a generator load changed, for a few flights (the bleed
    and the load are no inputs of the model): taken for a fault, its reversal on the next flight
    confirmed it as a second one (a bleed of 0.005 instead of 0.015 for one flight: 'sensor:Nc',
    then 'lpc+sensor:Wf' on every later flight), a flight better than normal was a recovery and
    the baseline started on it, and a real fault found near it took a fuel-meter bias in (probe
    fleets with one such flight on 7 engines: 50 false alarms, 44 on the normal flights after it;
    two such flights in a row on each of 40 healthy engines of a snapshot table: 351 false alarms
    after them, a step found on the first and its 'return' read as another fault). Components do
    not get better by themselves a flight later."""
    if D.shape[0] < 3 + run or D.shape[0] - 1 - run - start < run:
        return False              # as many flights before as in the run (one state to judge it by)
    X, y, _, scale, cut, one_state = _around(D, Wt, 4, start, run)
    off = np.sum(X ** 2, axis=1)
    back = y @ y <= max(cut * scale, EXCURSION_BACK ** 2 * off.min())
    if not (off.min() > cut * scale and back and np.sum((X - y) ** 2, axis=1).min() > 2.0 * cut and one_state):
        return False
    return not _one_sensor(X.mean(axis=0), Wt, S, bank, cut * scale)


#: the most flights in a row an excursion may last (:func:`_excursion`): longer is a state of the
#: engine (a fault repaired, an operational change), judged as such. Runs of two and three flights
#: off alike on 40 healthy engines of a snapshot table left 351 and 311 false alarms after them;
#: none with runs of up to 5 (a fault repaired to its exact level within 5 flights reads 'ok', not
#: 'recovery', after it: each run flight must be off at the 1e-6 level and the latest back)
EXCURSION_FLIGHTS = 5


def _one_sensor(x: np.ndarray, Wt: np.ndarray, S: np.ndarray, bank: list[Hypothesis], cut: float) -> bool:
    """Whether one sensor's bias explains the whitened change ``x`` to within ``cut`` (chi-square):
    an intermittent sensor fault, its own finding (:func:`_episodes`), not an excursion."""
    for h in bank:
        if single_sensor(h.name):
            a = Wt @ S[:, h.columns[0]]
            if a @ a > 0 and x @ x - (a @ x) ** 2 / (a @ a) <= cut:
                return True
    return False


def _since(rows: list[Decision], numbers: np.ndarray) -> int:
    """The first of the flights ``numbers`` (the rows tested) at or after the onset of the latest
    detection of ``rows`` (the decisions so far; 0 when none)."""
    onsets = [r.onset for r in rows if r.detected and r.onset >= 0]
    return int(np.searchsorted(numbers, onsets[-1])) if onsets else 0


#: a flight of the baseline's first is off alone (:func:`_isolated`) when at least this many times
#: as far (whitened norm) from the others' mean as any of them
ISOLATED_RATIO = 3.0


def _isolated(D: np.ndarray, j: int, Wt: np.ndarray, S: np.ndarray, bank: list[Hypothesis],
              fleet: tuple | None = None) -> bool:
    """Whether flight ``j`` of the first flights of a baseline (rows of deviations D (n, m), n >= 4)
    was off for that flight only: the others one state, it significantly off their mean
    (:data:`TRANSITION_ALPHA`), no single sensor's bias explaining it. :func:`_excursion` judges a
    flight by the flights before it and the one after, once there are three before; the first
    flights have fewer, and one of them off (a snapshot taken in a transient, a bleed on for that
    flight) read as a step on every later flight (a snapshot table with 1 % of its snapshots taken
    in transients: two healthy engines alarmed on all 19 flights after the first, one on six after
    its second). The first flight off the others is also what a fault on the second flight looks
    like: with ``fleet`` (the fleet's normal baseline in these channels, mean and covariance, and
    the flight-to-flight scatter Sigma: :meth:`FleetLevel.at`) the side nearer the fleet's normal
    is the engine's (an LPC loss of 1.5 % on the second flight of a probe engine was lost as its
    first flight's excursion); without a fleet, the first flight is the one that was off."""
    others = np.delete(D, j, axis=0)
    b = others.mean(axis=0)
    x = Wt @ (D[j] - b)
    cut = stats.chi2.ppf(1.0 - TRANSITION_ALPHA, x.size)
    spread = np.max(np.sum(((others - b) @ Wt.T) ** 2, axis=1))
    scale = 1.0 + 1.0 / others.shape[0]
    # off alone: at least three times as far from the others as any of them (a fast drift puts
    # its first flight twice as far as the third: an engine wearing every component fast from its
    # first flight lost that flight and was found a flight late)
    alone = x @ x > max(cut * scale, ISOLATED_RATIO ** 2 * spread)
    if not (spread <= cut and alone) or _one_sensor(x, Wt, S, bank, cut * scale):
        return False
    if j == 0 and fleet is not None:
        (mean, cov), Sigma = fleet
        def far(d, n):
            return float((d - mean) @ np.linalg.solve(cov + Sigma / n, d - mean))
        return far(D[0], 1) > far(b, others.shape[0])
    return True


def diagnose_engine(es: EngineSeries, Sigma: np.ndarray, cfg: DiagnosisConfig = DiagnosisConfig(),
                    wear: FleetNorm | None = None, level: FleetLevel | None = None,
                    new_baselines: tuple = ()) -> list[Decision]:
    """Causal diagnosis of one engine: one :class:`Decision` per flight, using flights 0..k.
    ``wear``: the fleet's normal wear (:func:`wear_reference`); without it, wear is reported
    when faster than ``cfg.min_rate``. Its ``common`` fleet-wide changes (at one flight or
    rolled out, :func:`common_steps`) that this engine took part in alike are nuisances of every
    test, never its faults. ``level``: the fleet's normal baseline (:func:`level_reference`); with it, an
    engine whose first flights are already off the fleet's (and which changed no further) is
    kind ``level``, onset its first flight.

    A finding on two flights in a row (a step, a drift, a level or a wear: :func:`_finding`) is
    confirmed: later rows name it in ``earlier`` while a later fault is reported, and steps and
    drifts are nuisances of the tests for a later change. A recovery (every efficiency up) that
    leaves part of a fault found before it is not a new baseline: after its first flight the
    rows report what is left (:func:`_remaining`).

    ``new_baselines``: flight numbers from which the engine starts a new baseline, declared by the
    user (a shop visit, a module change, the engine moved to another aircraft with another bleed
    and load): what changed there is not a fault, and the flights before it are not compared with
    the flights after (an engine moved to another aircraft alarmed on every later flight, as a
    fuel-meter bias or an HPT loss of 0.65 %)."""
    n, m = es.D.shape
    bank_all = hypotheses(es.columns, cfg.pairs)
    rows = []
    present = np.isfinite(es.D)
    number = flight_numbers(es)
    first = 0                  # the first flight of the current baseline (moved by a recovery)
    found: list[Decision] = []              # findings confirmed, in the order found (:func:`_finding`)
    finding: dict = {}                      # row index -> the finding it detected (:func:`_finding`)
    seen: list[tuple[float, str]] = []      # every sensor step detected: (onset, class)
    own = (1.0, -1)                         # the largest own scatter used, and its flight
    offsets = None                          # raw-unit sensor offsets of its baseline (:func:`_calibration`)
    common, away = (wear.common, wear.away) if wear else ([], [])
    away = [(a, b) for a, b in away if es.engine in a.engines or es.engine in a.onsets]
    rolled = [Known(c.onsets[es.engine], "fleet", c.cls) for c in common if es.engine in c.onsets
              and all(c is not x for pair in away for x in pair)]          # its steps of fleet-wide changes
    changed_in_flight: list[int] = []       # transition flights (:func:`_transition`), left out
    # flights off for that flight (or a few) only (:func:`_excursion`; the fleet's too), left out
    off_once: list[int] = [int(j) for a, b in away for j in np.flatnonzero(
        (number >= a.onsets.get(es.engine, a.onset)) & (number < b.onsets.get(es.engine, b.onset)))]
    judged_first: set[int] = set()          # baselines (first) whose first flights were judged (:func:`_isolated`)
    undo = None                             # (row, first, found) before a recovery's new baseline
    guard: dict = {}                        # (baseline rows, channels, hypotheses) -> FleetLevel.off

    def fleet_level(idx, Sb, bank):
        """(mean, covariance, names of the hypotheses off the other engines) of the fleet's level in
        the channels idx (signatures Sb), for the engine's baseline of its first flights (rowsok)."""
        rows = tuple(rowsok[: cfg.n_base + 1].tolist())
        key = (rows, tuple(idx.tolist()), tuple(h.name for h in bank))
        if key not in guard:
            guard[key] = level.off(es.engine, es.D[list(rows)][:, idx].mean(axis=0), Sb, idx, bank)
        return (*level.at(Sb, idx), guard[key])
    regime = np.array([c.split("@")[-1] for c in es.channels])
    for k in range(n):
        r = es.flights[k]
        dec = Decision(es.engine, int(number[k]), r.label, r.source, "ok")
        if any(number[k] >= b > (number[k - 1] if k else -np.inf) for b in new_baselines):
            first, undo = k, None               # declared: a new baseline from this flight
        if not present[k].any():
            dec.status = "no steady snapshot"
            rows.append(dec)
            continue
        # channels with data on this flight and on most earlier flights; flights lacking one are skipped
        upto = present[: k + 1]
        with_data = upto[upto.any(axis=1)]        # the flights so far with a snapshot
        # ... and on most of the baseline's first flights: a sensor fitted later (or dead from
        # delivery) taken in once present on half the flights dropped every flight before it, the
        # baseline with them, and a fault found before was no longer seen (an HPC loss 'ok' from
        # flight 11 when T24 had been missing on flights 0-5)
        def usable(first):
            # the baseline: its first n_base + 1 flights with a snapshot (an engine whose first
            # flights had none, or were excluded, kept no channel and failed)
            base = first + np.flatnonzero(present[first: k + 1].any(axis=1))[: cfg.n_base + 1]
            return present[k] & (with_data.mean(axis=0) >= 0.5) & (present[base].mean(axis=0) >= 0.5)
        keep = usable(first)
        dec.missing = _missing(es.channels, present[k])
        rowsok = np.flatnonzero(np.all(upto[:, keep], axis=1))
        run = k - undo[0] if undo is not None else 0
        if 1 <= run <= EXCURSION_FLIGHTS:
            # the recovery a few flights before started a new baseline on: back on this flight
            # to the state before it, it was an excursion (a lighter load for a few flights),
            # not maintenance: the old baseline again, those flights left out
            was = rowsok[(rowsok >= undo[1]) & ~np.isin(rowsok, changed_in_flight + off_once)]
            if was.size > cfg.n_base + 1 + run and np.array_equal(was[-1 - run: -1], np.arange(k - run, k)):
                ix = np.flatnonzero(keep)
                Sb = np.nanmean(es.S[was][:, ix], axis=0)
                if _excursion(es.D[was][:, ix], whitening(Sigma, ix), Sb,
                              [h for h in bank_all if _testable(h, Sb)], run=run):
                    first, found = undo[1], undo[2]
                    off_once += list(range(k - run, k))
                    keep = usable(first)
                    rowsok = np.flatnonzero(np.all(upto[:, keep], axis=1))
        rowsok = rowsok[(rowsok >= first) & ~np.isin(rowsok, changed_in_flight + off_once)]
        if rowsok.size == cfg.n_base + 1 and keep.any() and first not in judged_first:
            # the baseline's first flights, once, when testing starts: the flights the excursion
            # test (below) cannot judge, each against the others
            judged_first.add(first)
            ix = np.flatnonzero(keep)
            Sb = np.nanmean(es.S[rowsok][:, ix], axis=0)
            bank = [h for h in bank_all if _testable(h, Sb)]
            D0, Wfleet = es.D[rowsok][:, ix], whitening(Sigma, ix)
            fleet = (level.at(Sb, ix), Sigma[np.ix_(ix, ix)]) if level is not None and first == 0 else None
            off = [int(rowsok[j]) for j in range(rowsok.size - 2) if _isolated(D0, j, Wfleet, Sb, bank, fleet)]
            if len(off) == 1:                    # one off the others (two: no one state to judge by)
                off_once += off
                rowsok = rowsok[rowsok != off[0]]
        if rowsok.size < cfg.n_base + 1 or not keep.any():
            dec.status = "baseline"
            rows.append(dec)
            continue
        idx = np.flatnonzero(keep)
        while True:
            D = es.D[rowsok][:, idx]
            Sk = es.S[rowsok][:, idx]                 # each flight's signatures
            Sbar_all = np.nanmean(Sk, axis=0)
            # hypotheses testable with these channels (a bias of a channel without data is not)
            bank = [h for h in bank_all if _testable(h, Sbar_all)]
            t = number[rowsok]
            Wt = whitening(Sigma, idx)
            if offsets is None and level is not None and first == 0:
                offsets = _calibration(D, Wt, Sbar_all, t, bank, cfg, fleet_level(idx, Sbar_all, bank), len(bank),
                                       es.columns)
            if offsets:
                D = _calibrated(D, Sk, offsets, cfg.n_base + 1)
            D = _steadied(D, Sk, t, Wt, [f for f in found if f.onset >= number[first]], es.columns)
            toggled = sorted({es.columns.index(c) for o, c in seen if o >= number[first]})
            Wfleet = Wt.copy()
            ratio = own_scatter(D, Wt, Sbar_all[:, toggled])
            Wt /= np.sqrt(ratio)
            if not (rowsok.size >= 4 and rowsok[-2] == k - 1):    # two before, it, the latest
                break
            # the flight (or the run of flights) before the latest judged against the engine's own
            # scatter without it: in a short history its own differences made that scatter (an
            # excursion on the third flight hid itself and read as a step on the flights after)
            def scatter_without(run):
                lo = D.shape[0] - 1 - run
                return Wfleet / np.sqrt(own_scatter(np.delete(D, np.arange(lo, lo + run), axis=0), Wfleet,
                                                    Sbar_all[:, toggled]))
            if _transition(D, scatter_without(1), regime[idx]):
                changed_in_flight.append(k - 1)   # its windows straddle a change: not a state of the engine
                rowsok = np.delete(rowsok, -2)
                continue
            def excursion(r):
                """Whether the r flights before the latest (in a row, with flights before) were off
                for those flights only (:func:`_excursion`)."""
                return (rowsok.size >= 3 + r and rowsok[-1 - r] == k - r and
                        _excursion(D, scatter_without(r), Sbar_all, bank, _since(rows[: k - r], number[rowsok]), r))
            run = next((r for r in range(1, EXCURSION_FLIGHTS + 1) if excursion(r)), 0)
            if not run:
                break
            # off for those flights only: not a state of the engine, nor what was found on them
            off_once += list(range(k - run, k))
            there = set(number[k - run: k].tolist())
            found = [f for f in found if f.onset not in there]
            seen = [(o, c) for o, c in seen if o not in there]
            rowsok = np.delete(rowsok, np.arange(rowsok.size - 1 - run, rowsok.size - 1))
        own = max(own, (ratio, int(number[k])), key=lambda x: x[0])
        mine = [f for f in found if f.onset >= number[first]]
        known = _known(mine, t[0], Sbar_all, es.columns) + [c for c in rolled if t[0] < c.onset <= t[-1]]

        def decide(dec, known, use=None):
            """dec decided on the tests of the flights ``use`` (bool over rowsok; default every one)
            measured from ``known``; the number of tests (0: none)."""
            u = np.ones(t.size, bool) if use is None else use
            wide = bank + (sensor_pairs(bank) if cfg.pairs else [])      # (appended: bank's indices hold)
            # the engine's wear line held to the fleet's (:func:`_held_slope`) until it is found to
            # wear faster; then free again, and its wear tested against the fleet's spread of wear
            # lines (the spread of the rates was 5-20 times it: a slow wear found at flight 10 was
            # lost at 12-24)
            trend = wear.trend(Sbar_all, idx, Sigma) if wear and wear.trend_spread else None
            freed = any(f.kind == "wear" for f in mine)
            slope = None if freed else trend
            normal = (trend if freed and trend is not None else wear.at(Sbar_all, idx)) if wear else None
            stages = _stages(D[u], Wt, Sbar_all, t[u], wide, cfg, normal, known,
                             fleet_level(idx, Sbar_all, wide) if level and first == 0 else None, slope)
            every = [f for stage in stages for _, fits in stage for f in fits if f[1] < len(bank)]
            if every:
                p_all = stats.chi2.sf([f[2] for f in every], [len(bank[f[1]].columns) for f in every]) * len(every)
                dec.p_value = min(float(p_all.min()), 1.0)
                for stage in stages:
                    if stage and _decide(dec, stage, wide, Sbar_all, t[u], es, rowsok[u], len(every), cfg,
                                         slope is not None):
                        break
            return len(every)
        n_tests = decide(dec, known)
        if not n_tests:
            rows.append(dec)
            continue
        # a step found on the flight before (not yet confirmed) and another change on this one: two
        # faults a flight apart were one fit of neither (HPC at 5, LPT at 6: the HPC lost, its
        # 'recoveries' reported); measured from that step, this flight's own change is tested
        prev = finding.get(len(rows) - 1)
        if (prev and prev[2] == "step" and prev[1] == number[rowsok[-2]] and _finding(dec) != prev
                and prev[1] not in [f.onset for f in found]):
            then = known + [Known(prev[1], "step", prev[0])]
            second = Decision(es.engine, int(number[k]), r.label, r.source, "ok")
            second.missing = dec.missing
            tests = decide(second, then)
            if second.detected and second.onset == number[k] and second.kind == "step" and \
                    _finding(rows[-1]) == prev and not set(second.cls.split("+")) & set(prev[0].split("+")):
                # (of other components or sensors: the same one again is a change still going on)
                found.append(copy(rows[-1]))
                dec, known, n_tests = second, then, tests
        if dec.kind == "recovery":
            _sensor_part(dec, D, Wt, Sbar_all, t, bank, cfg, known, n_tests, es, rowsok)
        if dec.kind == "recovery":
            faults = [f for f in mine if f.kind in ("step", "stuck") and f.onset < dec.onset]
            left = _remaining(dec, faults, known, D, Wt, Sbar_all, t, bank, cfg, n_tests, es)
            repaired = [f for f in faults if all(f is not g for g, *_ in left)]
            was, found = found, [f for f in found if all(f is not r for r in repaired)]
            if not left:                     # nothing found before it is left: a new baseline
                undo = (k, first, was) if dec.onset == number[k] else None
                first = int(np.searchsorted(number, dec.onset))
            elif any(f.kind == "recovery" and f.onset == dec.onset for f in found):
                _left(dec, *left[-1], bank, es, rowsok)     # after its first flight: what is left
            else:
                found.append(copy(dec))          # later flights measure a new change from it
        if dec.detected and single_sensor(dec.cls) and _frozen(es, k, rowsok[0], dec.cls[7:]):
            dec.kind = "stuck"
        if dec.detected and any(number[j] < dec.onset and not np.any((number[rowsok] > number[j])
                                                                      & (number[rowsok] < dec.onset))
                                for j in changed_in_flight):
            dec.onset = int(max(number[j] for j in changed_in_flight if number[j] < dec.onset))   # began in it
        j = int(np.searchsorted(number, dec.onset)) - 1
        if (dec.detected and dec.kind == "step" and j >= first and j not in rowsok and j not in changed_in_flight
                and rows[j].detected and (rows[j].cls, rows[j].kind, rows[j].onset) == (dec.cls, "step", number[j])):
            # the flight before, left out for lacking a channel this test uses, found this step
            # beginning there on its own channels: it began there (a T48 missing on alternate
            # flights put an LPT loss's onset on every other row a flight late)
            dec.onset = int(number[j])
        # a finding on two flights in a row is confirmed: later flights look for a new change
        # after it (a second fault, a repair) measured from it, and name it in ``earlier``
        finding[len(rows)] = _finding(dec)
        if finding[len(rows)] is not None and finding.get(len(rows) - 1) == finding[len(rows)] \
                and dec.onset not in [f.onset for f in found]:
            found = [f for f in found if not _same_trend(f, dec)] + [copy(dec)]
        if (dec.detected and dec.kind == "step" and mine and mine[-1].kind == "drift" and dec.cls == mine[-1].cls
                and abs(dec.onset - mine[-1].onset) <= REVISE_FLIGHTS and dec.onset != dec.flight):
            found = [f for f in found if f is not mine[-1]] + [copy(dec)]     # a drift revised: a step (_stages)
        if finding[len(rows)] is not None and finding[len(rows)][2] == "step" and single_sensor(dec.cls):
            seen.append((dec.onset, dec.cls))
        biased = _episodes(dec, known, seen, es, rowsok, D, Wt, Sbar_all, t, bank, cfg)
        mine = [f for f in found if f.onset >= number[first]]
        dec.earlier = _earlier(dec, mine)
        if biased.size and not dec.earlier:
            # a sensor's bias gone, no fault confirmed before it: the engine's own state, the
            # flights it read biased on left out (a fault found on the flight before a one-flight
            # sensor glitch was never confirmed, the glitch being the next flight's decision: its
            # later flights read 'cleared', not detected). As for a fault confirmed before it
            # (:func:`_standing`): named in ``earlier`` on the flight it cleared on, the row after
            state = Decision(es.engine, int(number[k]), r.label, r.source, "ok")
            state.missing = dec.missing
            episode = set(biased.tolist()) | {dec.onset}          # its steps on and off
            decide(state, [c for c in known if not (c.cls == dec.cls and c.onset in episode)], ~np.isin(t, biased))
            if state.detected and (state.cls != dec.cls or state.onset < biased.min()):
                # (the same sensor: a smaller bias from before the episode)
                if dec.onset < dec.flight:
                    dec, state.earlier = state, _earlier(state, mine)
                else:
                    dec.earlier = f"{state.cls}@{state.onset:g}"
        # (on every flight of the baseline with these channels: the flights left out as off for a
        # flight or in transition are what an erratic sensor makes)
        flown = first + np.flatnonzero(np.all(present[first: k + 1][:, idx], axis=1))
        if not dec.detected and dec.status in ("ok", "cleared") and (
                _erratic(dec, es, es.D[flown][:, idx], idx, number[flown], [c.onset for c in known], Sigma, cfg)
                or _noisier(dec, es, flown, idx, number, cfg.n_base + 1)):
            dec.earlier = _earlier(dec, mine)
        if not dec.detected and dec.status in ("ok", "cleared"):
            _stuck_row(dec, es, k, number)
        rows.append(_standing(dec, mine) if dec.status == "cleared" and dec.earlier and dec.onset < dec.flight else dec)
    if own[0] > OWN_WARN:
        warnings.warn(PwlWarning(f"engine {es.engine}: judged against its own flight-to-flight scatter, "
                                 f"{own[0]:.3g} x the fleet's (variance; at most {OWN_MAX:g}) at flight {own[1]}: "
                                 "a noisier engine, or a fault of its own (a drift?), to which it is then less "
                                 "sensitive"), stacklevel=2)
    return rows


def _fleet_excursions(common: list[CommonStep]) -> list[tuple[CommonStep, CommonStep]]:
    """The pairs of fleet-wide changes (:func:`common_steps`) that are one excursion of the fleet:
    the second undoes the first (the same class, each part of its median fit the first's reversed
    within a third of it) at most :data:`EXCURSION_FLIGHTS` flights later. Every engine's
    snapshots off on one day (a ground station's processing, a fleet-wide data fault) were two
    fleet-wide steps, nuisances of every later test: a fault from before them was measured from
    the flights before the first only, and one that began with the second was lost in it (a
    snapshot table of 100 engines with every channel 1.5-2 % off on flight 10: TPR 100 -> 81.4 %,
    FPR 0 -> 0.54 %). The engines that changed with the first leave out its flights."""
    out = []
    for a in common:
        for b in common:
            if (b is not a and 0 < b.onset - a.onset <= EXCURSION_FLIGHTS and a.cls == b.cls and not a.rollout
                    and not b.rollout and a.fit.size == b.fit.size > 0
                    and np.all(np.abs(a.fit + b.fit) <= np.abs(a.fit) / 3)
                    and all(a is not x and b is not y for x, y in out)):
                out.append((a, b))
    return out


class Known(NamedTuple):
    """A change found on an engine that later tests are measured from (a nuisance of them):
    its ``onset`` (flight number), ``shape`` (``step``: a fault or a repair; ``ramp``: a drift,
    its fitted change per flight ``rate`` (m,) in the deviation channels; ``fleet``: the engine's
    step of a fleet-wide change, :func:`common_steps`) and class ``cls``."""

    onset: float
    shape: str
    cls: str
    rate: np.ndarray | None = None


#: the shape of the change each kind of finding is a nuisance of later tests as (:func:`_known`)
SHAPES = {"step": "step", "stuck": "step", "recovery": "step", "drift": "ramp"}


def _known(found: list[Decision], start: float, S: np.ndarray, columns: list[str]) -> list[Known]:
    """The findings ``found`` later changes are measured from, the baseline starting at flight
    number ``start``: faults and repairs (steps) and drifts (ramps, their rate in the channels
    of signatures S (m, ncol), columns named ``columns``). A level, a wear or a drift from the
    baseline's first flight is the engine's own level or wear line, a nuisance of every test
    already."""
    return [Known(f.onset, SHAPES[f.kind], f.cls, _change(f, S, columns) if f.kind == "drift" else None)
            for f in found if f.kind in SHAPES and not (f.kind == "drift" and f.onset <= start)]


def _change(dec: Decision, S: np.ndarray, columns: list[str]) -> np.ndarray:
    """The change (m,) a decision's fit (its ``detail``) makes in the channels of signatures S."""
    fit = dict(kv.split("=") for kv in dec.detail.split())
    return S[:, [columns.index(c) for c in fit]] @ np.array([float(v) for v in fit.values()])


def _finding(dec: Decision) -> tuple | None:
    """(class, onset, kind) of a detected step (a stuck sensor is one), drift, level or wear:
    what the engine is confirmed to have when the next flight's decision is the same."""
    kind = "step" if dec.kind == "stuck" else dec.kind
    return (dec.cls, dec.onset, kind) if dec.detected and kind in ("step", "drift", "level", "wear") else None


def _same_trend(a: Decision, b: Decision) -> bool:
    """Whether ``a`` is a level, drift or wear that ``b`` estimates again (its class, any onset):
    a trend's onset moves as flights come in."""
    return a.cls == b.cls and a.kind in ("level", "drift", "wear") and b.kind in ("level", "drift", "wear")


def _earlier(dec: Decision, found: list[Decision]) -> str:
    """The ``earlier`` column: the faults confirmed before ``dec``'s onset (``found``, of the
    current baseline) and still present, ``class@onset`` with the kind of a level, drift or
    wear (``hpc@0(level)``); a sensor's own earlier steps are the story of its episodes, and a
    trend the decision estimates again is the decision."""
    episode = dec.kind in ("intermittent", "cleared")
    return " ".join(f"{f.cls}@{f.onset:g}" + (f"({f.kind})" if f.kind in ("level", "drift", "wear") else "")
                    for f in found if f.onset < dec.onset and f.kind != "recovery"
                    and not (episode and f.cls == dec.cls) and not _same_trend(f, dec))


def _standing(dec: Decision, found: list[Decision]) -> Decision:
    """The row of a flight after the one where its own change went away (``dec``: a sensor bias
    ``cleared``, shown on its first flight as a repair's recovery is) while a fault confirmed
    before it stands (``found``): that fault as last sized, on this flight's row, with what else
    stands in ``earlier``. Such rows said ``detected`` 0 with the fault only in ``earlier``
    (probe fleet P7 ESN003: an HPC loss from flight 6 and fuel flow read 2 % low on flight 14
    only -> flights 15-23 'cleared', not detected, the engine off the list of engines with a
    fault)."""
    row = copy([f for f in found if f.kind != "recovery" and f.cls != dec.cls and f.onset < dec.onset][-1])
    row.flight, row.label, row.source, row.missing, row.status = dec.flight, dec.label, dec.source, dec.missing, "ok"
    row.earlier = _earlier(row, [f for f in found if f.cls != dec.cls])
    return row


def _remaining(dec, faults, known, D, Wt, S, t, bank, cfg, n_tests, es) -> list:
    """What a recovery ``dec`` (a step at its onset whose efficiencies all rise) left of the
    step faults found before it (``faults``, Decisions; ``known`` the changes found, as in
    :func:`_stages`): a repair of part of a loss, or a wash of another component. Deviations D
    at flight numbers t, whitening Wt, signatures S. The flights from the first fault's onset to
    the recovery are left out, and the change between the flights before and those from the
    recovery on is fitted as one step with the columns of every fault and of the recovery
    (:func:`_fit_changes`, the drifts found before as nuisances). A fault is left when its own
    columns' part is significant (Wald, chi-square with as many degrees of freedom, Bonferroni
    over ``n_tests`` as a detection), at least ``min_step`` and not better than before it (not
    every efficiency up). Returns (fault, theta, cov) of each fault left, in the order found.
    Before, every recovery put the engine on a new baseline: an HPT loss of 2 % repaired by 1 %
    was reported as nothing from the repair on."""
    cols = {h.name: h.columns for h in bank}
    if not faults or dec.cls not in cols or any(f.cls not in cols for f in faults):
        return []
    union = sorted(set(cols[dec.cls]).union(*(cols[f.cls] for f in faults)))
    begin = min(f.onset for f in faults)
    if any(begin <= k.onset < dec.onset for k in known if k.shape == "fleet"):
        return []              # a fleet-wide change in between: what is left cannot be told from it
    use = (t < begin) | (t >= dec.onset)
    fits = _fit_changes(D[use], Wt, S, t[use], [float(dec.onset)], "step", [Hypothesis("", union)], cfg,
                        trend=cfg.wear, **_nuisance([k for k in known if k.onset < begin or k.shape == "fleet"]))
    if not fits:
        return []
    _, _, _, th, cov, _ = fits[0]
    left = []
    for f in faults:
        at = [union.index(c) for c in cols[f.cls]]
        part, pcov = th[at], cov[np.ix_(at, at)]
        wald = float(part @ np.linalg.solve(pcov, part))
        if stats.chi2.sf(wald, len(at)) * n_tests < cfg.alpha and np.linalg.norm(S[:, cols[f.cls]] @ part) \
                >= cfg.min_step and not _maintenance([es.columns[c] for c in cols[f.cls]], part, pcov):
            left.append((f, part, pcov))
    return left


def _left(dec, fault, th, cov, bank, es, rowsok) -> None:
    """Make ``dec`` (a recovery) the row of what it left of ``fault`` (its decision when
    confirmed): that fault, detected, sized ``th`` +- ``cov`` (:func:`_remaining`)."""
    h = next(h for h in bank if h.name == fault.cls)
    dec.detected, dec.status, dec.kind, dec.cls, dec.onset = 1, "ok", fault.kind, fault.cls, fault.onset
    dec.confidence, dec.runner_up = fault.confidence, fault.runner_up
    dec.statistic = float(th @ np.linalg.solve(cov, th))
    _size(dec, es, rowsok, h.columns, th, cov, 0 if h.name.startswith("sensor:") else None)


def _missing(channels: list[str], present: np.ndarray) -> str:
    """What a flight lacks, for the ``missing`` column: ``regime:R`` for an operating regime it
    has no steady window in, and each sensor missing in a regime it does have (``channel@R``
    names, ``present`` (m,) bool)."""
    regimes = dict.fromkeys(c.split("@")[1] for c in channels)
    flown = {r for c, ok in zip(channels, present) if ok for r in [c.split("@")[1]]}
    lost = [f"regime:{r}" for r in regimes if r not in flown]
    lost += dict.fromkeys(c.split("@")[0] for c, ok in zip(channels, present) if not ok and c.split("@")[1] in flown)
    return " ".join(lost)


#: a sensor bias standing at least this many of its per-flight standard deviations (its bias while
#: on, :func:`_episode_size`, over the engine's whitened scatter) off its baseline is read on or
#: off flight by flight: each flight is then 4 of them from the other state. A smaller one is
#: read between the steps found (their segments' means). Measured: the seed-1 benchmark's sensor
#: biases stand 30-500 of them off (fuel flow the least), the probe fleets' intermittent T48
#: biases (38 K) about 300
EPISODE_SEPARATION = 8.0


def _episode_size(readings: np.ndarray) -> float:
    """The bias of a sensor while on, from its readings (flights or segments): signed as the
    largest reading, the median of the readings of that sign at least half of it. Not the largest
    itself: that is the bias plus its largest noise, so a constant bias about 6 of its standard
    deviations off read one flight under half of it as off and the sensor 'intermittent' (a Ps30
    1 % low from flight 12, seed-11 table: from flight 21 on)."""
    big = readings[np.argmax(np.abs(readings))]
    return float(np.median(readings[readings * np.sign(big) >= 0.5 * abs(big)]))


#: the chance at which a sensor's readings since its first step scatter too much around one level
#: to be one bias, and too little around two (on and off) not to be a bias that comes and goes
#: (:func:`_two_states`)
TWO_STATES_ALPHA = 1e-3


def _two_states(b: np.ndarray, sd: float) -> bool:
    """Whether a sensor's readings b (k,) on the flights since its first step (standard deviation
    sd each) are a bias that comes and goes, however small against sd: around their mean they
    scatter beyond chi-square's 1 - TWO_STATES_ALPHA point, read as on (at least half the bias
    while on, :func:`_episode_size`, about their mean) or off (about none) within its
    TWO_STATES_ALPHA point, and they go off and on again at least once. A T48 +20 K on every other
    flight (8 per-flight standard deviations: below :data:`EPISODE_SEPARATION`) read a step of
    +9 to +10 K, its first step's segment's mean, on 11 flights of a 30-engine table."""
    k = b.size
    if k < 3:
        return False
    size = _episode_size(b)
    on = b * np.sign(size) >= 0.5 * abs(size)
    if on.all() or not on.any() or np.sum(on[1:] & ~on[:-1]) < 1:
        return False
    one = float(np.sum((b - b.mean()) ** 2)) / sd ** 2
    two = float(np.sum((b[on] - b[on].mean()) ** 2) + np.sum(b[~on] ** 2)) / sd ** 2
    return one > stats.chi2.ppf(1.0 - TWO_STATES_ALPHA, k - 1) and two < stats.chi2.ppf(1.0 - TWO_STATES_ALPHA, k - 1)


def _episodes(dec: Decision, found: list, seen: list, es: EngineSeries, rowsok, D, Wt, S, t, bank,
              cfg: DiagnosisConfig) -> np.ndarray:
    """A sensor bias that goes away, or comes and goes: relabel a detected step of a sensor class
    by that sensor's readings against its **baseline**, the flights before the first step of it
    seen (``seen``: (onset, class) of every sensor step detected, confirmed or not: a one-flight
    episode is never confirmed) and after the last other change found before that (``found``:
    :class:`Known`).

    The readings: deviations D (rows at flight numbers t, whitening Wt, signatures S) fitted, by
    whitened least squares, with the engine's level, its wear line (with n_base + 1 baseline
    flights or more), the other faults found since (``bank`` hypotheses' steps: an HPT loss
    moves T48 too) and the sensor's bias on each flight from the first step on. A flight (or,
    when the bias while on (:func:`_episode_size`) is less than EPISODE_SEPARATION per-flight
    standard deviations, a segment between the steps found: their mean) is on when its reading
    is at least half that bias, of its sign. One episode, on: a step, sized from the baseline
    unless the step found is the one that turned it on. One, off now: kind ``cleared``, not
    detected (status ``cleared``: a repair), onset when it went off, sized as the bias that went
    away. Two or more, on or off: kind ``intermittent``, detected (a loose connector is a fault
    also on the flights it reads right), onset the first episode's, sized as the latest
    episode's bias.

    Before, the steps found were read in turn from "off", the first turning the bias on: an
    intermittent T48 (+38 K on flights 4, 6, 9-13, 20, 21, 23; probe fleet C) whose one-flight
    episodes were not confirmed had its first step found at 7, the bias going off, read as a
    -34 K bias going on; flights 9-13 (on) came out ``cleared``, 14-19 (off) a -51..-55 K
    intermittent.

    Returns the flight numbers the sensor read biased on when its bias is gone (``cleared``),
    else none."""
    none = np.zeros(0)
    if not (dec.detected and dec.kind == "step" and single_sensor(dec.cls)):
        return none
    begin = min([o for o, c in seen if c == dec.cls and o >= t[0]] + [dec.onset])
    start = max([t[0]] + [k.onset for k in found if k.cls != dec.cls and k.onset < begin])
    use = t >= start
    tt, Y = t[use], D[use] @ Wt.T
    n, m = Y.shape
    after = tt >= begin
    if after.all():
        return none
    col = es.columns.index(dec.cls)
    cols = {h.name: [c for c in h.columns if c != col] for h in bank}
    w = Wt @ S[:, col]
    X = [np.kron(np.ones((n, 1)), np.eye(m))]                                    # the level
    if (~after).sum() >= cfg.n_base + 1:
        X.append(np.kron((tt - tt.mean())[:, None], np.eye(m)))                  # the wear line
    X += [np.kron(_shape(tt, k.onset, k.shape)[:, None], Wt @ S[:, cols[k.cls]])   # other changes
          for k in found if k.cls != dec.cls and k.onset >= begin and cols.get(k.cls)]

    def readings(biased):
        """The sensor's bias on the flights ``biased`` (n,) bool, none on the others."""
        A = np.hstack(X + [np.kron(np.eye(n)[:, biased], w[:, None])])
        return np.linalg.lstsq(A, Y.ravel(), rcond=None)[0][-biased.sum():]

    b = readings(after)
    ta, sd = tt[after], 1.0 / float(np.linalg.norm(w))
    if abs(_episode_size(b)) >= EPISODE_SEPARATION * sd or _two_states(b, sd):
        cuts = ta
    else:
        again = {k.onset for k in found if k.cls == dec.cls and k.onset > begin}
        cuts = np.array(sorted({begin, dec.onset} | again))
    unit = np.searchsorted(cuts, ta, side="right") - 1
    units = np.unique(unit)
    level = np.array([b[unit == u].mean() for u in units])
    while_on = _episode_size(level)
    on = level * np.sign(while_on) >= 0.5 * abs(while_on)      # a reading the other way is not the bias
    rises = np.flatnonzero(on & ~np.r_[False, on[:-1]])          # where an episode begins
    last = np.flatnonzero(on)[-1]
    run = (unit >= units[rises[-1]]) & (unit <= units[last])     # the latest episode's flights
    if len(rises) >= 2:
        dec.kind, dec.onset = "intermittent", int(ta[unit == units[rises[0]]].min())
    elif not on[-1]:
        dec.detected, dec.kind, dec.status = 0, "cleared", "cleared"
        dec.onset = int(ta[unit == units[last + 1]].min())
    elif ta[run].min() == dec.onset:       # the step found turned it on: its fit stands
        return none
    # its size, with the flights it was off on in the baseline (and in its wear line)
    ison = np.isin(unit, units[on])
    size = float(readings(np.r_[np.zeros(n - after.sum(), bool), ison])[run[ison]].mean())
    std = sd / np.sqrt(run.sum())
    fit = dict(kv.split("=") for kv in dec.detail.split())
    fit[dec.cls] = f"{size:+.5f}"
    dec.detail = " ".join(f"{k}={v}" for k, v in fit.items())
    dec.magnitude, dec.magnitude_std, dec.bias = _sensor_size(es, rowsok, col, size, std)
    return ta[ison] if dec.kind == "cleared" else none


#: a sensor whose flight-to-flight scatter grew to at least this many times (variance, medians)
#: what it was before is ``erratic`` (:func:`_erratic`), with at least ERRATIC_BEFORE successive
#: differences before and ERRATIC_AFTER after its onset
ERRATIC_RATIO = 4.0
ERRATIC_BEFORE = 6
ERRATIC_AFTER = 4
#: the quantile of a difference's null distribution whose exceedances are counted (:func:`_erratic`)
ERRATIC_QUANTILE = 0.9


def _erratic(dec: Decision, es: EngineSeries, D: np.ndarray, idx: np.ndarray, t: np.ndarray, onsets,
             Sigma: np.ndarray, cfg: DiagnosisConfig) -> bool:
    """A sensor whose readings scatter more from flight to flight since some flight (a loose
    connector, a failing thermocouple): ``dec`` (no fault found, or that sensor's bias read
    ``cleared``: a reading far off on one flight and back on the next) becomes that sensor's
    ``erratic`` fault, onset where it began, its detail the ratio of standard deviations; True
    then. Per sensor (its L channels of ``idx``, every regime), each successive difference of the
    deviations D (n, k) at flight numbers t, squared over twice the fleet's scatter Sigma and
    summed, is chi-square(L) when nothing changed, scaled by the sensor's own before the candidate
    onset or the engine's other sensors' since, if larger (medians); the differences at
    ``onsets`` (changes confirmed) are left out. After each candidate onset, the count above the
    ERRATIC_QUANTILE quantile is binomial: its tail probability, Bonferroni over the sensors and
    onsets, below ``alpha``, and the median after it at least ERRATIC_RATIO times the null's.
    Counting, not summing: a bias on for a while and off again (two large differences) is no
    scatter. A sensor six times as noisy from flight 15 (T30, five engines of a 40-engine
    snapshot table) read a T30 step, drift or intermittent bias on a few later flights,
    ``cleared`` or nothing on most."""
    if t.size < ERRATIC_BEFORE + ERRATIC_AFTER + 1:
        return False
    names = [es.channels[i].split("@")[0] for i in idx]
    sensors = list(dict.fromkeys(names))
    sq = np.diff(D, axis=0) ** 2 / (2.0 * np.diag(Sigma)[idx])
    keep = ~np.isin(t[1:], list(onsets)) & np.all(np.isfinite(sq), axis=1)
    at = t[1:][keep]
    # each sensor's differences (columns) in units of its null's median, and its null's
    # ERRATIC_QUANTILE point
    L = np.array([names.count(s) for s in sensors])
    y = np.column_stack([sq[keep][:, [j for j, nm in enumerate(names) if nm == s]].sum(axis=1) for s in sensors])
    y = y / stats.chi2.median(L)
    cut = stats.chi2.ppf(ERRATIC_QUANTILE, L) / stats.chi2.median(L)
    onset = np.arange(ERRATIC_BEFORE, at.size - ERRATIC_AFTER + 1)
    if onset.size == 0:
        return False
    level = np.array([np.median(y[j:], axis=0) for j in onset])          # (onsets, sensors)
    before = np.array([np.median(y[:j], axis=0) for j in onset])
    # against the fleet, its own before, and the engine's other sensors since (an engine noisier
    # than its fleet throughout, its T48 quieter on its first flights by chance, read an erratic T48)
    others = (np.nanmedian(np.where(np.eye(len(sensors), dtype=bool)[None], np.nan, level[:, None, :]), axis=2)
              if len(sensors) > 1 else np.zeros_like(level))
    scale = np.maximum(np.maximum(1.0, before), others)
    count = np.array([np.sum(y[j:] > scale[i] * cut, axis=0) for i, j in enumerate(onset)])
    p = stats.binom.sf(count - 1, (at.size - onset)[:, None], 1.0 - ERRATIC_QUANTILE)
    ratio = level / scale
    # the smallest p (ties: the smaller ratio, the sensor first by name, the earlier onset)
    rank = np.broadcast_to(np.argsort(np.argsort(sensors)), p.shape)
    i, c = np.unravel_index(np.lexsort([np.broadcast_to(onset[:, None], p.shape).ravel(), rank.ravel(),
                                        ratio.ravel(), p.ravel()])[0], p.shape)
    n_tests, p, ratio, sensor = p.size, float(p[i, c]), float(ratio[i, c]), sensors[c]
    if p * n_tests < cfg.alpha and ratio >= ERRATIC_RATIO and (dec.status == "ok" or dec.cls == f"sensor:{sensor}"):
        dec.status = "ok"
        dec.detected, dec.cls, dec.kind, dec.onset = 1, f"sensor:{sensor}", "erratic", int(at[onset[i]])
        dec.p_value, dec.statistic, dec.detail = min(1.0, p * n_tests), ratio, f"scatter_ratio={np.sqrt(ratio):.3g}"
        return True
    return False


#: a sensor whose readings scatter within its snapshots NOISY_RATIO times as much as on its
#: baseline's first flights (their standard errors, over the engine's other sensors' on the same
#: flight), on the latest flight and the one before, is ``erratic`` (:func:`_noisier`)
NOISY_RATIO = 3.0


def _noisier(dec: Decision, es: EngineSeries, flown: np.ndarray, idx: np.ndarray, number: np.ndarray,
             base: int) -> bool:
    """A sensor noisier within each snapshot since some flight (a failing thermocouple, a loose
    connector): ``dec`` becomes its ``erratic`` fault, onset the first flight of the run, its detail
    the ratio of standard errors (``noise_ratio``); True then. Per sensor (its channels of ``idx``,
    every regime), each flight's standard errors (``es.SE``) over their median on the first
    ``base`` flights of ``flown`` (the baseline's flights with these channels, positions), the
    median over its regimes, over the median of the engine's other sensors on that flight (a
    shorter or less steady window raises every sensor's alike): at least :data:`NOISY_RATIO` on
    the latest two flights. Snapshot tables carry no standard errors: never. T30 five times as
    noisy from flight 6 in a probe fleet of logs: every row 'ok' (its snapshot means, of
    thousands of samples, hardly moved), the misfits only in the run's counts."""
    if flown.size < base + 2 or flown[-2] != flown[-1] - 1:
        return False
    names = np.array([es.channels[i].split("@")[0] for i in idx])
    sensors = list(dict.fromkeys(names.tolist()))
    if len(sensors) < 3:
        return False
    se = es.SE[flown][:, idx]
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)        # channels without standard errors
        ref = np.nanmedian(se[:base], axis=0)
        r = np.where(ref > 0.0, se / ref, np.nan)
        per = np.column_stack([np.nanmedian(r[:, names == s], axis=1) for s in sensors])     # (flights, sensors)
        rel = np.column_stack([per[:, j] / np.nanmedian(np.delete(per, j, axis=1), axis=1)
                               for j in range(len(sensors))])
    last = np.where(np.isfinite(rel[-2:]), rel[-2:], 0.0).min(axis=0)
    j = int(np.argmax(last))
    if last[j] < NOISY_RATIO:
        return False
    start = rel.shape[0] - 1
    while start - 1 >= base and rel[start - 1, j] >= NOISY_RATIO and flown[start - 1] == flown[start] - 1:
        start -= 1
    dec.status, dec.detected, dec.cls, dec.kind = "ok", 1, f"sensor:{sensors[j]}", "erratic"
    dec.onset, dec.statistic = int(number[flown[start]]), float(last[j])
    dec.detail, dec.confidence = f"noise_ratio={last[j]:.3g}", 1.0
    return True


def recoveries(decisions: list[Decision]) -> list[Decision]:
    """The first decision of every recovery in one engine's decisions (time order)."""
    out, seen = [], set()
    for d in decisions:
        if d.kind == "recovery" and (d.cls, d.onset) not in seen:
            seen.add((d.cls, d.onset))
            out.append(d)
    return out


# ---- many engines -------------------------------------------------------------------------------
def _copy_key(r: FlightRecord) -> tuple:
    """What two results files of one flight share: engine, flight time and index, snapshots."""
    s = r.snapshot
    return r.engine, r.order[:2], s.t0.tobytes(), s.samples.tobytes(), s.mean.tobytes()


def _first_of_each_flight(records: list[FlightRecord]) -> tuple[list, dict]:
    """(the records without copies; copy -> the record it repeats): a copy has the
    :func:`_copy_key` of a record before it in natural order of the file paths."""
    first: dict = {}
    kept, repeats = [], {}
    for r in sorted(records, key=lambda r: _natural(r.source)):      # 'flight_3' before 'flight_3 copy'
        k = _copy_key(r)
        if k in first:
            repeats[r.source] = first[k]
        else:
            first[k] = r
            kept.append(r)
    return kept, repeats


def copies(records: list[FlightRecord]) -> list[str]:
    """A line for every flight whose results are a copy of another's (the same engine, flight
    time, flight index and snapshots: a log sent twice under two names), which
    :func:`group_engines` leaves out."""
    return [f"engine {orig.engine}: {src} repeats {orig.source} (the same flight time, index and snapshots: "
            "one flight sent twice?): left out" for src, orig in _first_of_each_flight(records)[1].items()]


def group_engines(records: list[FlightRecord]) -> dict[str, list[FlightRecord]]:
    """Engine -> its flights, in natural order of the engine names; a copy of a flight already
    there (:func:`copies`) is left out, so flight numbers and fits count each flight once."""
    out: dict[str, list[FlightRecord]] = {}
    for r in _first_of_each_flight(records)[0]:
        out.setdefault(r.engine, []).append(r)
    return {k: in_flight_order(out[k])[0] for k in sorted(out, key=_natural)}


def prepare(records: list[FlightRecord], db: GainDatabase) -> tuple[Signatures, np.ndarray]:
    """Signatures of the database and the operating regimes of ``records`` (sets their windows;
    serials that differ only in case, spaces or leading zeros made one, :func:`same_engines`); a
    :class:`PwlWarning` for that, and when some results were computed with another database
    (their recorded digest differs from ``db``'s)."""
    if not records:
        raise DiagnosisError("no flights to diagnose")
    for line in same_engines(records):      # (the CLI has done it as it read them)
        warnings.warn(PwlWarning(line), stacklevel=3)
    sig = Signatures(db)
    for r in records:
        if r.snapshot.p_names != list(db.names["p"]) or not set(sig.channels) <= set(r.snapshot.channels):
            raise DiagnosisError(f"{r.source}: its snapshots ({r.snapshot.p_names}, {r.snapshot.channels}) "
                                 f"do not match the database {db.path}")
    other = [r for r in records if r.database_digest and db.digest and r.database_digest != db.digest]
    if other:
        digests = sorted({r.database_digest[:12] for r in other})
        warnings.warn(PwlWarning(
            f"{len(other)} of {len(records)} results files were computed with another database than "
            f"{db.path} (sha256 {', '.join(d + '...' for d in digests)}, not {db.digest[:12]}...; rebuilt "
            f"since, or another one?), e.g. {other[0].source}: their deviations are measured from this "
            "one's trims, their filter health is the other's (run them again to match)"), stacklevel=2)
    centers = assign_regimes(records, db.p_spans())
    if not len(centers):
        placed = sum(int(np.all(np.isfinite(r.snapshot.p), axis=1).sum()) for r in records)
        why = "" if placed else (f": none has an operating point ({', '.join(db.names['p'])}; a channel they are "
                                 "computed from is missing or implausible throughout, see the warnings above)")
        raise DiagnosisError(f"no steady operating regime common to the flights ({len(records)} flights, "
                             f"{sum(len(r.snapshot) for r in records)} steady windows{why})")
    for line in unread_note(records):
        warnings.warn(PwlWarning(line), stacklevel=3)
    return sig, centers


def unread_note(records: list[FlightRecord]) -> list[str]:
    """Lines naming the snapshots of a table (records of mode ``table``) that are in no regime
    (:func:`assign_regimes`: an operating point fewer than its share of the flights flew, such as
    take-off rows on two engines of a fleet reporting idle and cruise; or none, a scheduling
    channel missing) and so not read; empty when there are none. A flight log's windows outside
    the regimes (climb, descent) are not named: they are most of its windows."""
    rare, blind = [], []
    for r in records:
        if r.mode == "table":
            for w in r.unplaced:
                (rare if np.all(np.isfinite(r.snapshot.p[w])) else blind).append((r, w))
    out = []
    for hits, what, why in ((rare, "are at an operating point too few flights share", "a regime not every engine "
                             "reports?"),
                            (blind, f"have no operating point ({', '.join(records[0].snapshot.p_names)}: a "
                             "channel they are computed from is missing there)", "a unit mistake? see above")):
        if not hits:
            continue
        r, w = hits[0]
        point = ", ".join(f"{n} {v:.6g}" for n, v in zip(r.snapshot.p_names, r.snapshot.p[w]))
        engines = sorted({r.engine for r, _ in hits}, key=_natural)
        out.append(f"{len(hits)} snapshots of {len(engines)} engines ({few(engines, 3)}) {what} (the first: "
                   f"{r.source.rsplit(':row', 1)[0]}:row {int(r.snapshot.t0[w]) + 2}, {r.engine} {r.label}"
                   f"{' at ' + point if hits is rare else ''}): not read ({why})")
    return out


#: engines per task of :func:`_series_of` in :func:`diagnose_fleet`
SERIES_CHUNK = 25


def _series_of(flights: list[list[FlightRecord]], sig: Signatures, n_regimes: int) -> list[EngineSeries]:
    """:func:`engine_series` of each engine's flights (a task of :func:`diagnose_fleet`)."""
    return [engine_series(f, sig, n_regimes) for f in flights]


def diagnose_fleet(records: list[FlightRecord], db: GainDatabase,
                   cfg: DiagnosisConfig = DiagnosisConfig(), new_baselines: dict | None = None,
                   excluded: dict | None = None, executor=None, progress=None) -> tuple:
    """Every engine of ``records``; returns (decisions, Sigma, deviation channel names, regime
    centres (R, np), the fleet's normal wear (:class:`FleetNorm`, or None)). Each engine is
    judged against the fleet's scatter, normal wear and normal baseline level.
    ``new_baselines``: engine -> flight numbers where it starts a new baseline
    (:func:`diagnose_engine`); ``excluded``: engine -> flight numbers left out (:func:`excluding`;
    their rows say ``excluded``). ``executor``: where the engines are diagnosed, one task each
    (a process pool, :func:`pwl.workers.process_pool`; default: here, one after the other);
    ``progress(done, total)`` is called as engines finish."""
    sig, centers = prepare(records, db)
    excluded = excluded or {}
    executor = executor or SerialExecutor()
    # the engines' series in the executor too: their signatures at every flight's operating
    # points were a third of a 300-engine table's diagnosis, on one core (a chunk of engines a
    # task: the signatures, 1 MB pickled, sent once per chunk)
    flights = list(group_engines(records).values())
    parts = [executor.submit(_series_of, flights[i: i + SERIES_CHUNK], sig, len(centers))
             for i in range(0, len(flights), SERIES_CHUNK)]
    series = [excluding(es, excluded.get(es.engine, ())) for part in parts for es in part.result()]
    read_in_other_units(series, db.channel_units())
    for line in gross_note(series, db.channel_units()) + stuck_note(series) + dead_note(series):
        warnings.warn(PwlWarning(line), stacklevel=2)
    Sigma = noise_covariance(series, cfg.floor)
    for line in misfiled_note(series, Sigma):
        warnings.warn(PwlWarning(line), stacklevel=2)
    from .trending import detail_units
    wear, level = fleet_norms(series, Sigma, cfg, detail_units(db))
    tasks = [executor.submit(diagnose_engine, es, Sigma, cfg, wear, level,
                             tuple((new_baselines or {}).get(es.engine, ()))) for es in series]
    for done, _ in enumerate(as_completed(tasks), 1):
        if progress:
            progress(done, len(tasks))
    rows = [d for task in tasks for d in task.result()]
    return mark_excluded(rows, excluded), Sigma, series[0].channels, centers, wear


def write_diagnosis(rows: list[Decision], path) -> None:
    """``diagnosis.csv``: one row per engine and flight (columns :data:`CSV_FIELDS`), atomic."""
    path = os.fspath(path)
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for r in rows:
            w.writerow([r.engine, r.flight, r.label, r.status, r.detected, r.cls, r.kind, r.onset,
                        _fmt(r.magnitude), _fmt(r.magnitude_std), _fmt(r.bias), _fmt(r.confidence),
                        r.runner_up, _fmt(r.p_value), _fmt(r.statistic), r.detail, r.missing, r.earlier,
                        r.source])
    os.replace(tmp, path)


def _fmt(v):
    return "" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.6g}"
