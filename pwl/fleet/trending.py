"""Health trending of one engine: per-flight health, trend lines, and the fleet diagnostics' verdict.

Two views of the same flights, in time order (``flight_time``, ``flight_index``, then file names
in natural order, so flight_2 comes before flight_10):

- the Kalman filter's health estimates per flight (the mean over the flight's steady snapshot, or
  :func:`health_summary` of a whole run) with a least-squares line per parameter (level at the
  newest flight, slope per flight, standard error);
- the diagnosis of :mod:`pwl.fleet.diagnose` for this engine alone (detection over the whole history,
  isolation among components and sensors, size, drift rate): the tuner estimates are projections
  of 10 health parameters and 8 sensors onto 7 tuners, so they show *that* the engine changed but
  cannot by themselves say which component or sensor did; the diagnosis does.

With one engine the flight-to-flight scatter comes from the engine's own flights (robust, with a
floor), so the verdict is less sharp than in a fleet run (``pwl fleet diagnose``).
"""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..database import GainDatabase
from ..errors import PwlWarning
from .diagnose import (DiagnosisConfig, Decision, FlightRecord, dead_note, diagnose_engine, engine_series,
                       excluding, fleet_norms, gross_note, group_engines, mark_excluded, noise_covariance, prepare,
                       read_in_other_units, recoveries, stuck_note)


@dataclass
class HealthSummary:
    """Health of one run: names (nh,), values (nh,) median estimates, spread (nh,) IQR/1.349."""

    source: str
    names: list[str]
    values: np.ndarray
    spread: np.ndarray
    samples: int


def health_summary(time, h_hat, flags, names, source="<memory>", settle: float = 60.0) -> HealthSummary:
    """Median health estimates of one run: time (n,) s, h_hat (n, nh), flags (n,) int; samples
    after ``settle`` s with flags == 0."""
    time, h_hat, flags = np.asarray(time), np.asarray(h_hat), np.asarray(flags)
    use = (time >= time[0] + settle) & (flags == 0) & np.all(np.isfinite(h_hat), axis=1)
    if not use.any():
        raise ValueError(f"{source}: no settled, unflagged samples after {settle:g} s to summarise")
    h = h_hat[use]
    q75, q50, q25 = np.percentile(h, [75, 50, 25], axis=0)
    return HealthSummary(os.fspath(source), list(names), q50, (q75 - q25) / 1.349, int(use.sum()))


def _kind(d: Decision) -> str:
    """A decision's kind as the trend table says it."""
    return "off its fleet" if d.kind == "level" else d.kind


def line(x, y):
    """Least-squares y = a + b x per column of y: returns a, b, se(b), residual std."""
    X = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    dof = max(len(x) - 2, 1)
    s = np.sqrt((r ** 2).sum(axis=0) / dof)
    sxx = ((x - x.mean()) ** 2).sum()
    se = s / np.sqrt(sxx) if sxx > 0 else np.full_like(s, np.inf)
    return coef[0], coef[1], se, s


def detail_units(db: GainDatabase) -> dict[str, str]:
    """The unit of every fitted parameter a diagnosis ``detail`` can name ('%': a fraction, shown
    in percent): health parameters and input biases are fractions, sensed-output biases are
    offsets in the sensor's unit (:mod:`pwl.fleet.signatures`)."""
    units = dict.fromkeys(db.names["h"], "%")
    units.update({f"sensor:{c}": "%" for c in db.names["u"]})
    units.update({f"sensor:{c}": u for c, u in zip(db.names["y"], db.units["y"])})
    units.update({f"gain:{c}": "%" for c in db.names["y"]})     # a scheduling sensor's gain part
    if db.correction is not None:         # the inlet sensors (pwl.fleet.signatures)
        for c in (db.correction.theta_channel, db.correction.delta_channel):
            units.setdefault(f"sensor:{c}", (db.log_channels or {}).get(c, ("",))[0])
    return units


def readable_detail(detail: str, units: dict[str, str]) -> str:
    """A diagnosis ``detail`` ("hpt_eff=-0.01735 sensor:T48=+15.2", fractions and sensor units)
    for people: "hpt_eff -1.74 %, sensor:T48 +15.2 K" (a name without a unit is kept as it is)."""
    parts = []
    for item in detail.split():
        name, _, value = item.partition("=")
        unit = units.get(name)
        if unit == "%":
            parts.append(f"{name} {100 * float(value):+.2f} %")
        elif unit is not None:
            parts.append(f"{name} {float(value):+.4g} {unit}")
        else:
            parts.append(item)
    return ", ".join(parts)


@dataclass
class EngineTrend:
    """One engine over its flights: labels (n,), health H (n, nh) fractions (NaN without a
    snapshot), per parameter level at the newest flight, slope per flight and its standard error,
    the diagnosis per flight, and the units of the diagnosis details (:func:`detail_units`).
    Printed and plotted health values are in percent."""

    engine: str
    labels: list[str]
    names: list[str]
    H: np.ndarray
    level: np.ndarray
    slope: np.ndarray
    slope_se: np.ndarray
    decisions: list[Decision]
    units: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: the snapshots' relative deviations from the model (n, m R), channels ``<channel>@<regime>``
    #: (:class:`~pwl.fleet.diagnose.EngineSeries`): what the diagnosis tests, plotted when there is
    #: no filter health (snapshot tables)
    deviations: np.ndarray | None = None
    channels: list[str] = field(default_factory=list)

    @property
    def latest(self) -> Decision:
        return self.decisions[-1]

    def detail(self, d: Decision) -> str:
        return readable_detail(d.detail, self.units)

    def table(self) -> str:
        """Health in percent per flight, the trend lines and the verdict per flight."""
        short = [n.replace("_eff", "_e").replace("_flow", "_w") for n in self.names]
        lines = [f"engine {self.engine}: {len(self.labels)} flights (health estimates in %)",
                 f"{'flight':<14}" + "".join(f"{s:>8}" for s in short) + "  diagnosis"]
        for i, lab in enumerate(self.labels):
            d = self.decisions[i]
            verdict = f"{d.cls} {_kind(d)} since flight {d.onset}: {self.detail(d)}" \
                if d.detected or d.kind in ("recovery", "cleared") else d.status
            lines.append(f"{lab[:14]:<14}" + _percents(self.H[i], 2) + f"  {verdict}")
        lines.append(f"{'level':<14}" + _percents(self.level, 2))
        lines.append(f"{'slope/flight':<14}" + _percents(self.slope, 3))
        lines.append(f"{'  +-':<14}" + _percents(self.slope_se, 3))
        lines += self.notes
        d = self.latest
        if d.detected:
            rate = d.kind in ("drift", "wear")
            what = "rate" if rate else ("bias when on" if d.kind == "intermittent" else "size")
            size = (f"{what} {100 * d.magnitude:+.2f} "
                    f"+- {100 * d.magnitude_std:.2f} %{'/flight' if rate else ''}")
            if d.kind == "erratic":
                size = f"scatter {d.detail.partition('=')[2]} x its own before"
            elif d.kind == "stuck" and not d.detail:
                size = "one value in every regime (read as missing)"
            elif np.isfinite(d.bias):
                size += f", bias {d.bias:+.4g} (sensor units)"
            lines.append(f"FAULT: {d.cls} ({_kind(d)} since flight {d.onset}), {size}, confidence "
                         f"{d.confidence:.2f} (next: {d.runner_up}); {self.detail(d)}")
            if d.earlier:
                lines.append(f"  after an earlier fault still present: {', '.join(d.earlier.split())} "
                             "(class@onset flight, and its kind when a level, drift or wear)")
        elif d.kind == "cleared":
            lines.append(f"no fault: the {d.cls} bias found earlier went away at flight {d.onset} (a repair?); "
                         f"{self.detail(d)}")
        else:
            lines.append(f"no fault detected (p = {d.p_value:.3g})" if np.isfinite(d.p_value) else
                         f"no fault detected ({d.status})")
            if d.p_value < DiagnosisConfig.alpha:
                lines.append("  a change is significant but smaller than the sizes reported (min_step, and "
                             "min_rate per flight for wear): normal wear? Judge the engine against its "
                             "fleet: pwl trend ... --fleet FLEET_RESULTS")
        for r in recoveries(self.decisions):
            lines.append(f"RECOVERY (maintenance?): {r.cls} at flight {r.onset}, size {100 * r.magnitude:+.2f} "
                         f"+- {100 * r.magnitude_std:.2f} %; {self.detail(r)}; later changes measured from it"
                         + (f" (what it left of {', '.join(r.earlier.split())} still reported)" if r.earlier else ""))
        return "\n".join(lines)


def _percents(v: np.ndarray, digits: int) -> str:
    """Fractions v as percent columns of width 8, '-' where there is no value."""
    return "".join(f"{100 * x:>8.{digits}f}" if np.isfinite(x) else f"{'-':>8}" for x in v)


def health_notes(es) -> list[str]:
    """Why flights of ``es`` (:class:`~pwl.fleet.diagnose.EngineSeries`) have no filter health:
    the filter holds its health where a sensor it needs is absent (an engine without P15, whose
    table was all NaN with nothing said), and the sensors absent on every such flight."""
    none = ~np.all(np.isfinite(es.h_hat), axis=1)
    if not none.any():
        return []
    tables = sum(r.mode == "table" for r, n in zip(es.flights, none) if n)
    if tables == none.sum():
        return [f"no health estimate on {int(none.sum())} of {none.size} flights (snapshot tables carry no filter "
                "health); the diagnosis uses the snapshots' deviations, which do not need them"]
    channels = sorted({c.split("@")[0] for c in es.channels}, key=[c.split("@")[0] for c in es.channels].index)
    absent = [c for c in channels if c not in es.input_names and
              not np.isfinite(es.D[np.ix_(none, [j for j, k in enumerate(es.channels) if k.split("@")[0] == c])]).any()]
    why = (f"the filter held its health where the sensors it needs were absent: {', '.join(absent)} "
           f"not in these logs" if absent else "the filter's health was held or not settled in every steady window")
    return [f"no health estimate on {int(none.sum())} of {none.size} flights ({why}); the diagnosis uses "
            f"the snapshots' deviations, which do not need them"]


def engine_trend(records: list[FlightRecord], db: GainDatabase,
                 cfg: DiagnosisConfig = DiagnosisConfig(), fleet: list[FlightRecord] | None = None,
                 new_baselines: tuple = (), excluded: dict | None = None) -> EngineTrend:
    """Trend and diagnosis of one engine's flights (any order: they are sorted by time).

    ``fleet``: the flights of the engine's fleet (may include its own). Then the engine is judged
    as ``pwl fleet diagnose`` judges it: against the fleet's flight-to-flight scatter and its
    normal wear and baseline level (:func:`pwl.fleet.diagnose.wear_reference`,
    :func:`~pwl.fleet.diagnose.level_reference`). Alone, against its own scatter (which
    holds an intermittent fault's toggles) and ``min_rate`` for wear. ``new_baselines``: flight
    numbers where the engine starts a new baseline (:func:`~pwl.fleet.diagnose.diagnose_engine`);
    ``excluded``: engine -> flight numbers left out, of this engine and its fleet's
    (:func:`~pwl.fleet.diagnose.excluding`)."""
    mine = {os.path.realpath(r.source) for r in records}     # however the paths were spelt
    others = [r for r in (fleet or []) if os.path.realpath(r.source) not in mine]
    sig, centers = prepare(records + others, db)
    excluded = excluded or {}
    es = engine_series(records, sig, len(centers))
    es = excluding(es, excluded.get(es.engine, ()))
    series = [es] + [excluding(engine_series(v, sig, len(centers)), excluded.get(e, ()))
                     for e, v in group_engines(others).items()]
    read_in_other_units(series, db.channel_units())
    for note in gross_note([es], db.channel_units()) + stuck_note([es]) + dead_note([es]):
        warnings.warn(PwlWarning(note), stacklevel=2)
    wear = level = None
    if others:
        Sigma = noise_covariance(series, cfg.floor)
        wear, level = fleet_norms(series, Sigma, cfg, detail_units(db))
    else:
        Sigma = noise_covariance([es], cfg.floor)
    dec = mark_excluded(diagnose_engine(es, Sigma, cfg, wear, level, new_baselines), excluded)
    H = es.h_hat
    ok = np.all(np.isfinite(H), axis=1)
    x = np.flatnonzero(ok).astype(float)
    nh = H.shape[1]
    if x.size >= 2:
        a, b, se, _ = line(x, H[ok])
        level = a + b * (H.shape[0] - 1)
    else:
        level, b, se = (H[ok][-1] if x.size else np.full(nh, np.nan)), np.full(nh, np.nan), np.full(nh, np.nan)
    return EngineTrend(es.engine, [f.label for f in es.flights], es.h_names, H, level, b, se, dec,
                       detail_units(db), health_notes(es), es.D, list(es.channels))


def plot_trend(tr: EngineTrend, path, truth: np.ndarray | None = None) -> None:
    """PNG of every health estimate (%) over flights with its trend line and the detected fault
    (matplotlib, the ``plot`` extra); without any health estimate (a snapshot table), of the
    snapshots' relative deviations from the model the diagnosis tested instead: a panel per
    channel, a series per operating regime, the fault's sensors in red."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = tr.latest
    parts = d.cls.split("+") if d.detected else []
    x = np.arange(tr.H.shape[0])
    if not np.isfinite(tr.H).any() and tr.deviations is not None:
        names = list(dict.fromkeys(c.split("@")[0] for c in tr.channels))
        flagged = {p.split(":", 1)[1] for p in parts if p.startswith("sensor:")}

        def draw(ax, j, name):
            for k, c in enumerate(tr.channels):
                if c.split("@")[0] == name:
                    ax.plot(x, 100 * tr.deviations[:, k], "o-", ms=3, lw=0.6, label=f"regime {c.split('@')[1]}")
            ax.legend(fontsize=6, loc="upper left")
        how = ("deviation from the model, %", 4, " -- snapshot deviations (no filter health)")
    else:
        names = tr.names
        flagged = {n for n in names for p in parts if n.startswith(p + "_") or n == p}

        def draw(ax, j, name):
            ax.plot(x, 100 * tr.H[:, j], "o", ms=3, label="estimate")
            if np.isfinite(tr.slope[j]):
                ax.plot(x, 100 * (tr.level[j] + tr.slope[j] * (x - x[-1])), "-", lw=1, color="C1",
                        label=f"trend {100 * tr.slope[j]:+.3f} %/flight")
            if truth is not None:
                ax.plot(x, 100 * truth[:, j], "k--", lw=1, label="truth")
            ax.legend(fontsize=6, loc="lower left")
        how = ("health estimate, %", 5, "")
    ylabel, most, note = how
    cols = min(len(names), most)
    rows = (len(names) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows + 0.5), squeeze=False)
    for j, name in enumerate(names):
        ax = axes[j // cols][j % cols]
        draw(ax, j, name)
        if d.detected and d.onset >= 0:
            ax.axvline(d.onset - 0.5, color="red", lw=0.8, ls=":")
        ax.set_title(name, fontsize=8, color="red" if name in flagged else "black")
        ax.set_xlabel("flight")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for j in range(len(names), rows * cols):
        axes[j // cols][j % cols].axis("off")
    title = (f"engine {tr.engine}: {d.cls} {d.kind} from flight {d.onset} ({tr.detail(d)})" if d.detected
             else f"engine {tr.engine}: no fault detected")
    fig.suptitle(title + note, fontsize=9, color="red" if d.detected else "black")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
