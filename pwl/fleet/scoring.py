"""ProDiMES-style scoring of a fleet diagnosis against the fleet's truth.

Inputs are two CSV files, so any diagnostic method can be scored:

- the diagnosis, one row per engine and flight: ``engine``, ``flight`` (an integer, the flight
  number in the numbering of the truth's ``onset``: the logs' ``flight_index``, else the 0-based
  position in time order), ``detected`` (1/0, true/false or yes/no, any case), ``class`` (the
  assigned class; ignored when not detected); optional
  ``kind`` (step, drift, wear, level, stuck, intermittent, erratic; cleared and recovery are not detected), ``magnitude`` (efficiency change for components, relative bias for the
  fuel-flow measurement) and ``bias`` (sensor units, for sensor faults);
- the truth, one row per engine: ``engine``, ``class`` (``none`` for a healthy engine), ``onset``
  (first faulty flight, -1 for none), ``magnitude``, ``unit`` (``fraction`` or ``sigma``), ``bias``
  (sensor units, for sensor faults).

Every engine of the truth is scored on every flight number the diagnosis has (the fleet's flights):
an engine or an engine-flight the diagnosis leaves out counts as not detected, as a method that
says nothing has detected nothing, and the result's ``notes`` name them. A row repeating an earlier
one of the same engine and flight is counted once (and noted) when identical, else refused; an
engine the truth does not know, a flight or onset that is not an integer and a ``detected`` that is
not a boolean are refused (:class:`ScoreError`, naming the file, line, column and value), since any
guess would change the rates without a word.

Metrics (Simon 2010, NASA/TM-2010-215840): engine-flights with a fault present (faulty engine,
flight >= onset) and without (healthy engines, and faulty engines before onset).
true-positive rate = detected / fault present; false-positive rate = detected / no fault;
correct classification = detected fault-present engine-flights given the true class / detected
fault-present engine-flights; confusion matrix of true x assigned class over every engine-flight
(``none`` when nothing is detected); Cohen's kappa of that matrix; detection latency = first
detected flight - onset per faulty engine (undetected engines are counted, not given a latency);
sizing error = |estimate - truth| / |truth| at each faulty engine's last flight when it is
detected and correctly classified; sensor-as-component = detected sensor-fault engine-flights
assigned to a component class.
"""
from __future__ import annotations

import csv
import os

import numpy as np

from ..errors import PwlError

COMPONENT_PREFIXES = ("fan", "lpc", "hpc", "hpt", "lpt")


class ScoreError(PwlError, ValueError):
    """A diagnosis or truth file that cannot be scored (names the file and the column)."""


def _read(path, need):
    """The rows of CSV file ``path`` as (line number, row dict), checked for the columns ``need``."""
    path = os.fspath(path)
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            rows = [(reader.line_num, r) for r in reader]
    except OSError as e:
        raise ScoreError(f"{path}: cannot read ({e})") from None
    if not rows:
        raise ScoreError(f"{path}: no rows")
    missing = [c for c in need if c not in rows[0][1]]
    if missing:
        raise ScoreError(f"{path}: missing column(s) {missing}; has {list(rows[0][1])}")
    return rows


_TRUE = ("1", "1.0", "true", "t", "yes", "y")
_FALSE = ("0", "0.0", "false", "f", "no", "n")


def _flag(path, line, col, v) -> bool:
    """A boolean cell: 1/0, true/false, yes/no in any case; anything else is refused (read as 0 it
    would score every detection as a miss)."""
    s = (v or "").strip().lower()
    if s in _TRUE or s in _FALSE:
        return s in _TRUE
    raise ScoreError(f"{path}: line {line}: column '{col}' is {v!r}; expected 1/0, true/false or yes/no")


def _int(path, line, col, v) -> int:
    """An integer cell (a flight number, an onset; ``3.0`` reads as 3); anything else is refused
    (``flight_003`` read as -1 would put every flight before the fault's onset)."""
    x = _num(v)
    if not (np.isfinite(x) and x == int(x)):
        raise ScoreError(f"{path}: line {line}: column '{col}' is {v!r}; expected an integer flight "
                         "number (the numbering of the truth's onset)")
    return int(x)


def few(names, n=5) -> str:
    """The first ``n`` of ``names``, comma-separated, with '...' when there are more."""
    names = list(names)
    return ", ".join(names[:n]) + (", ..." if len(names) > n else "")


def _flights(ks) -> str:
    """Flight numbers as text: 'flight 7', 'flights 5-9' when consecutive, else the first few."""
    if len(ks) == 1:
        return f"flight {ks[0]}"
    run = ks == list(range(ks[0], ks[-1] + 1))
    return f"flights {ks[0]}-{ks[-1]}" if run else "flights " + few(map(str, ks), 3)


def _read_truth(path) -> dict:
    """Engine -> its truth row, ``onset`` read as an integer (empty for a healthy engine: -1); an
    engine given twice is refused unless both rows are identical."""
    truth, first = {}, {}                   # engine -> truth row; engine -> (line, row as read)
    for line, r in _read(path, ("engine", "class", "onset")):
        eng = r["engine"]
        if eng in first:
            if r != first[eng][1]:
                raise ScoreError(f"{path}: line {line}: engine {eng} is already on line {first[eng][0]} "
                                 "with a different truth")
            continue
        empty = r["class"] == "none" and not (r["onset"] or "").strip()
        first[eng] = line, r
        truth[eng] = dict(r, onset=-1 if empty else _int(path, line, "onset", r["onset"]))
    return truth


def _read_diagnosis(path, truth, truth_path):
    """Engine -> [(flight, detected, row)] in flight order for every engine of ``truth``
    (:func:`_complete`), and what the reading found: ``missing_engines``,
    ``missing_engine_flights``, ``repeated_rows`` and the ``notes`` that name them.

    One row per engine and flight: an identical repeat is dropped (noted), a different one refused.
    Engines not in the truth are refused: they cannot be scored, and dropping them would hide a
    diagnosis of another fleet."""
    rows = _read(path, ("engine", "flight", "detected", "class"))
    unknown = sorted({r["engine"] for _, r in rows} - set(truth))
    if unknown:
        raise ScoreError(f"{path}: {len(unknown)} engine{'s are' if len(unknown) > 1 else ' is'} "
                         f"not in {truth_path}: {few(unknown)}")
    seen, repeats = {}, []                  # (engine, flight) -> (line, detected, row)
    for line, r in rows:
        k = _int(path, line, "flight", r["flight"])
        key = (r["engine"], k)
        if key in seen:
            if r != seen[key][2]:
                raise ScoreError(f"{path}: line {line}: engine {key[0]} flight {k} is already on line "
                                 f"{seen[key][0]} with different values (one row per engine and flight)")
            repeats.append((line, key))
            continue
        seen[key] = (line, _flag(path, line, "detected", r["detected"]), r)
    by_engine, found = _complete(seen, truth)
    if repeats:
        (line, (eng, k)), n = repeats[0], len(repeats)
        note = (f"{n} row{'s repeat' if n > 1 else ' repeats'} an earlier row of the same engine and "
                f"flight, counted once (first: engine {eng} flight {k}, line {line})")
        found["notes"].insert(0, note)
    return by_engine, dict(found, repeated_rows=len(repeats))


def _complete(seen, truth):
    """Every engine of ``truth`` on every flight number of the diagnosis (``seen``: (engine,
    flight) -> (line, detected, row)); an engine-flight not in it is added as not detected (row
    None), as a method that says nothing has detected nothing, and the notes name them."""
    flights = sorted({k for _, k in seen})
    by_engine, absent, partial = {}, [], []
    for eng in truth:
        lacking = [k for k in flights if (eng, k) not in seen]
        if len(lacking) == len(flights):
            absent.append(eng)
        elif lacking:
            partial.append(f"{eng} ({len(lacking)}: {_flights(lacking)})")
        by_engine[eng] = [(k, *seen[eng, k][1:]) if (eng, k) in seen else (k, False, None)
                          for k in flights]
    notes = []
    if absent:
        notes.append(f"{len(absent)} engine{'s' if len(absent) > 1 else ''} of the truth not in the "
                     f"diagnosis, their {len(absent) * len(flights)} engine-flights counted as not "
                     f"detected: {few(absent)}")
    if partial:
        notes.append(f"{len(partial)} engine{'s lack' if len(partial) > 1 else ' lacks'} flights other "
                     f"engines have, counted as not detected: {few(partial)}")
    missing = sum(row is None for fl in by_engine.values() for *_, row in fl)
    return by_engine, {"missing_engines": absent, "missing_engine_flights": missing, "notes": notes}


def _num(v, default=float("nan")):
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def is_sensor(cls: str) -> bool:
    return cls.startswith("sensor:")


def is_component(cls: str) -> bool:
    return any(part in COMPONENT_PREFIXES or part.split("_")[0] in COMPONENT_PREFIXES
               for part in cls.split("+")) and not is_sensor(cls)


def _per_class(pairs, truth, engines_seen, latency, sizing) -> dict:
    """Per true fault class: engines, engines detected, TPR and correct share of its fault
    flights, median latency and sizing error (pairs: (true, assigned, engine, flight))."""
    out = {}
    for c in sorted({t["class"] for t in truth.values()} - {"none"}):
        fl = [(a, b) for a, b, *_ in pairs if a == c]
        engines = [e for e, t in truth.items() if t["class"] == c and e in engines_seen]
        out[c] = {
            "engines": len(engines),
            "detected_engines": sum(e in latency for e in engines),
            "tpr": _ratio(sum(b != "none" for _, b in fl), len(fl)),
            "correct": _ratio(sum(a == b for a, b in fl if b != "none"), sum(b != "none" for _, b in fl)),
            "latency_median": _median([latency[e] for e in engines if e in latency]),
            "sizing_error_median": _median([sizing[e] for e in engines if e in sizing]),
        }
    return out


def score(diagnosis_csv, truth_csv, min_component: float = 0.0, min_sensor_sigma: float = 0.0) -> dict:
    """Score ``diagnosis_csv`` against ``truth_csv`` (see the module docstring); returns a dict.

    ``min_component`` (|efficiency change|) and ``min_sensor_sigma`` (bias in noise sigmas) set the
    detectability magnitude: ``tpr_detectable`` counts only faults at or above it."""
    truth = _read_truth(truth_csv)
    by_engine, coverage = _read_diagnosis(diagnosis_csv, truth, truth_csv)
    pairs = []            # (true class of the flight, assigned class, engine, flight)
    latency, undetected, sizing = {}, [], {}
    tp = fn = fp = tn = tp_det = n_det = 0
    for eng, rows in by_engine.items():
        t = truth[eng]
        cls, onset = t["class"], t["onset"]
        detectable = cls != "none" and _detectable(t, min_component, min_sensor_sigma)
        first = None
        for k, det, r in rows:
            assigned = r["class"] if det else "none"
            faulty = cls != "none" and onset >= 0 and k >= onset
            pairs.append((cls if faulty else "none", assigned, eng, k))
            if faulty:
                tp, fn = tp + det, fn + (not det)
                if detectable:
                    tp_det, n_det = tp_det + det, n_det + 1
                if det and first is None:
                    first = k
            else:
                fp, tn = fp + det, tn + (not det)
        if cls != "none" and onset >= 0:
            if first is None:
                undetected.append(eng)
            else:
                latency[eng] = first - onset
            _, det, last = rows[-1]
            if det and last["class"] == cls:
                sizing[eng] = _size_error(t, last)
    labels = sorted({p[0] for p in pairs} | {p[1] for p in pairs}, key=lambda c: (c != "none", c))
    li = {c: i for i, c in enumerate(labels)}
    cm = np.zeros((len(labels), len(labels)), dtype=np.int64)
    for a, b, *_ in pairs:
        cm[li[a], li[b]] += 1
    det_fault = [(a, b) for a, b, *_ in pairs if a != "none" and b != "none"]
    correct = sum(a == b for a, b in det_fault)
    sens = [(a, b) for a, b in det_fault if is_sensor(a)]
    sens_as_comp = sum(is_component(b) for _, b in sens)
    lat = list(latency.values())
    return {
        "engines": len(by_engine), "engine_flights": len(pairs),
        "fault_flights": tp + fn, "no_fault_flights": fp + tn,
        "tpr": _ratio(tp, tp + fn), "fpr": _ratio(fp, fp + tn),
        "tpr_detectable": _ratio(tp_det, n_det), "detectable_flights": n_det,
        "correct_classification": _ratio(correct, len(det_fault)),
        "kappa": kappa(cm),
        "sensor_as_component": _ratio(sens_as_comp, len(sens)),
        "latency_median": _median(lat), "latency_mean": float(np.mean(lat)) if lat else float("nan"),
        "engines_detected": len(latency), "engines_undetected": len(undetected),
        "undetected": undetected,
        "sizing_error_median": _median(list(sizing.values())),
        "per_class": _per_class(pairs, truth, set(by_engine), latency, sizing),
        "confusion": {"labels": labels, "counts": cm.tolist()},
        **coverage,
    }


def _detectable(t, min_component, min_sensor_sigma):
    mag = abs(_num(t.get("magnitude")))
    if t.get("unit") == "sigma":
        return mag >= min_sensor_sigma
    return mag >= min_component if not is_sensor(t["class"]) else True


def _size_error(t, row):
    if is_sensor(t["class"]) and t.get("unit") == "sigma":
        est, true = _num(row.get("bias")), _num(t.get("bias"))
    else:
        est, true = _num(row.get("magnitude")), _num(t.get("magnitude"))
        if not is_sensor(t["class"]) and true > 0 and est < 0:   # magnitudes given as losses
            true = -true
    return abs(est - true) / abs(true) if np.isfinite(est) and np.isfinite(true) and true else float("nan")


def kappa(cm) -> float:
    """Cohen's kappa of a confusion matrix (rows truth, columns assigned)."""
    cm = np.asarray(cm, dtype=np.float64)
    n = cm.sum()
    if n == 0:
        return float("nan")
    po = np.trace(cm) / n
    pe = float(cm.sum(axis=1) @ cm.sum(axis=0)) / n ** 2
    return float((po - pe) / (1.0 - pe)) if pe < 1.0 else float("nan")


def _ratio(a, b):
    return float(a) / b if b else float("nan")


def _median(v):
    v = [x for x in v if np.isfinite(x)]
    return float(np.median(v)) if v else float("nan")


def table(res: dict) -> str:
    """The headline figures and the per-class table as text."""
    lines = [f"{res['engines']} engines, {res['engine_flights']} engine-flights "
             f"({res['fault_flights']} with a fault present, {res['no_fault_flights']} without)",
             *(f"note: {n}" for n in res.get("notes", ())),
             f"true-positive rate        {100 * res['tpr']:6.1f} %   (detectable faults: "
             f"{100 * res['tpr_detectable']:.1f} % of {res['detectable_flights']})",
             f"false-positive rate       {100 * res['fpr']:6.2f} %",
             f"correct classification    {100 * res['correct_classification']:6.1f} %   kappa {res['kappa']:.3f}",
             f"sensor read as component  {100 * res['sensor_as_component']:6.1f} %",
             f"detection latency         median {res['latency_median']:.1f} flights, "
             f"{res['engines_detected']} engines detected, {res['engines_undetected']} not",
             f"sizing error              median {100 * res['sizing_error_median']:.1f} %", "",
             f"{'class':<12} {'engines':>7} {'detected':>8} {'TPR %':>6} {'correct %':>9} {'latency':>7} {'size err %':>10}"]
    for c, r in res["per_class"].items():
        lines.append(f"{c:<12} {r['engines']:>7} {r['detected_engines']:>8} {_pct(r['tpr']):>6} "
                     f"{_pct(r['correct']):>9} {r['latency_median']:>7.1f} {_pct(r['sizing_error_median']):>10}")
    lab = res["confusion"]["labels"]
    short = [c.replace("sensor:", "s:") for c in lab]
    w = max(6, max(map(len, short)) + 1)
    lines += ["", "confusion matrix (rows: true class per engine-flight, columns: assigned)",
              " " * 12 + "".join(f"{s:>{w}}" for s in short)]
    for s, row in zip(short, res["confusion"]["counts"]):
        lines.append(f"{s:<12}" + "".join(f"{v:>{w}}" for v in row))
    return "\n".join(lines)


def _pct(v):
    return f"{100 * v:.1f}" if np.isfinite(v) else "-"


def plot_confusion(res: dict, path) -> None:
    """PNG of the confusion matrix, row-normalised (matplotlib, the ``plot`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lab = [c.replace("sensor:", "s:") for c in res["confusion"]["labels"]]
    cm = np.asarray(res["confusion"]["counts"], dtype=np.float64)
    frac = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    n = len(lab)
    fig, ax = plt.subplots(figsize=(1.0 + 0.45 * n, 0.8 + 0.4 * n))
    ax.imshow(frac, cmap="Blues", vmin=0, vmax=1)
    for i in range(n):
        for j in range(n):
            if cm[i, j]:
                ax.text(j, i, int(cm[i, j]), ha="center", va="center", fontsize=6,
                        color="white" if frac[i, j] > 0.6 else "black")
    ax.set_xticks(range(n), lab, rotation=90, fontsize=7)
    ax.set_yticks(range(n), lab, fontsize=7)
    ax.set_xlabel("assigned class")
    ax.set_ylabel("true class (per engine-flight)")
    ax.set_title(f"TPR {100 * res['tpr']:.1f} %, FPR {100 * res['fpr']:.2f} %, "
                 f"correct {100 * res['correct_classification']:.1f} %, kappa {res['kappa']:.2f}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
