"""Seeded mutation testing of the inputs pwl reads: gain databases and flight logs (#14).

Every mutant is a damaged copy of a clean database or log; running the estimator on it must end
in one of three acceptable outcomes, never in a fourth:

- ``named``: a pwl error (:class:`pwl.errors.PwlError`) naming what is wrong;
- ``equal``: estimates equal to the clean run's (relative 1e-9; e.g. a flipped padding byte);
- ``flagged``: estimates differ, and the flag counts say something is off (implausible, held,
  without update, misfit, ... counts differ from the clean run's);
- ``traceback`` (any other exception), ``hang`` (see benchmarks/fuzz.py) and ``silent``
  (different estimates, same flags, no error) are failures.

Database mutants: byte-level damage of the file (bit flips, bytes set, truncation, appended or
zeroed blocks: the seal's job), edits through h5py as another tool would make them (deleted
datasets, wrong shapes, garbage attributes, NaN/Inf values), and the same edits sealed again, as
if a faulty writer had produced them (then the content checks must catch them). Log mutants: byte
damage of a sealed HDF5 log, NaN/Inf runs, wild values, negative flows, unit mistakes (values in
another unit, declared or not, and unknown unit symbols), broken time columns, wrong sample
intervals, dropped channels, empty logs and broken CSV files.
"""
from __future__ import annotations

import os

import h5py
import numpy as np

from ..errors import PwlError
from ..h5io import seal
from ..logs import Log, write_log
from ..results import FLAG_COUNTS

DB_KINDS = ("bitflip", "byte", "truncate", "append", "zero-block", "h5-delete", "h5-reshape",
            "h5-attr", "h5-nonfinite", "sealed-delete", "sealed-reshape", "sealed-attr",
            "sealed-nonfinite", "sealed-unstable")
LOG_KINDS = ("h5-bitflip", "h5-truncate", "nan-run", "inf-run", "huge", "negative", "unit-factor",
             "unit-declared", "unit-unknown", "time-backwards", "time-nan", "time-duplicate",
             "dt-change", "drop-channel", "empty", "csv-duplicate-column", "csv-ragged",
             "csv-text", "csv-non-utf8")
OUTCOMES = ("named", "equal", "flagged", "traceback", "hang", "silent")
FAILURES = ("traceback", "hang", "silent")

#: (dimension of the unit, factor, offset) of unit mistakes: a value in another unit than declared
UNIT_SLIPS = {"K": [(1.0, -273.15), (1.8, 0.0), (1.8, -459.67)],
              "Pa": [(1e-3, 0.0), (1.450377e-4, 0.0), (1e-5, 0.0), (1e-2, 0.0)],
              "kg/s": [(2.204623, 0.0), (3600.0, 0.0), (7936.641, 0.0), (1e3, 0.0)],
              "rpm": [(0.1047198, 0.0), (1 / 60, 0.0), (1e-2, 0.0)],
              "m": [(3.28084, 0.0), (1e-3, 0.0)], "-": [(100.0, 0.0)], "%": [(1e-2, 0.0)]}
#: units a log may wrongly declare, per the database's unit
WRONG_DECLARED = {"K": ["degC", "degR", "degF"], "Pa": ["kPa", "psi", "bar", "hPa"],
                  "kg/s": ["lb/s", "kg/h", "lb/h"], "rpm": ["rad/s"], "m": ["ft", "km"]}


# ---- databases ---------------------------------------------------------------------------------
def _float_datasets(f):
    out = []
    f.visititems(lambda n, o: out.append(n) if isinstance(o, h5py.Dataset) and o.dtype.kind == "f"
                 and o.size > 0 else None)
    return out


def _all_datasets(f):
    out = []
    f.visititems(lambda n, o: out.append(n) if isinstance(o, h5py.Dataset) else None)
    return out


def mutate_database(clean: bytes, path, kind: str, rng) -> None:
    """Write a ``kind`` mutant of the database file content ``clean`` to ``path``."""
    b = bytearray(clean)
    n = len(b)
    if kind == "bitflip":
        i = int(rng.integers(n))
        b[i] ^= 1 << int(rng.integers(8))
    elif kind == "byte":
        i = int(rng.integers(n))
        b[i] = (b[i] + int(rng.integers(1, 256))) % 256
    elif kind == "truncate":
        b = b[:int(rng.integers(n))]
    elif kind == "append":
        b += bytes(rng.integers(0, 256, int(rng.integers(1, 4096)), dtype=np.uint8))
    elif kind == "zero-block":
        i = int(rng.integers(n))
        m = min(int(rng.integers(1, 4096)), n - i)
        b[i:i + m] = bytes(m)
    with open(path, "wb") as fh:
        fh.write(bytes(b))
    if kind.startswith(("h5-", "sealed-")):
        with h5py.File(path, "r+") as f:
            _edit(f, kind.split("-", 1)[1], rng)
        if kind.startswith("sealed-"):
            seal(path)


def _edit(f, what: str, rng) -> None:
    if what == "delete":
        names = _all_datasets(f)
        del f[names[int(rng.integers(len(names)))]]
    elif what == "reshape":
        names = [d for d in _all_datasets(f) if f[d].ndim >= 1 and f[d].shape[-1] > 1]
        d = names[int(rng.integers(len(names)))]
        a = f[d][()]
        del f[d]
        f[d] = a[..., :-1]
    elif what == "attr":
        objs = [f] + [f[d] for d in _all_datasets(f)] + [f[g] for g in f if isinstance(f[g], h5py.Group)]
        objs = [o for o in objs if len(o.attrs)]
        o = objs[int(rng.integers(len(objs)))]
        k = list(o.attrs)[int(rng.integers(len(o.attrs)))]
        o.attrs[k] = [b"garbage", -1, np.nan, 1e300, "", "clip "][int(rng.integers(6))]
    elif what == "nonfinite":
        names = _float_datasets(f)
        d = f[names[int(rng.integers(len(names)))]]
        a = d[()]
        a.reshape(-1)[int(rng.integers(a.size))] = [np.nan, np.inf, -np.inf][int(rng.integers(3))]
        d[...] = a
    elif what == "unstable":
        K = f["kalman/K"]
        a = K[()]
        idx = tuple(int(rng.integers(s)) for s in a.shape[:-2])
        a[idx] = a[idx] * -float(rng.uniform(20, 200))
        K[...] = a


# ---- logs --------------------------------------------------------------------------------------
def mutate_log(clean: Log, folder, kind: str, rng, db_units: dict) -> str:
    """Write a ``kind`` mutant of the log ``clean`` into ``folder``; returns its path.
    ``db_units``: the database's unit of every channel it reads (for unit mistakes)."""
    folder = os.fspath(folder)
    t = clean.time.copy()
    ch = {k: v.copy() for k, v in clean.channels.items()}
    units = dict(clean.units)
    names = [c for c in db_units if c in ch]
    c = names[int(rng.integers(len(names)))]
    n = t.size
    a = int(rng.integers(n))
    span = slice(a, min(n, a + int(rng.integers(1, max(2, n // 4)))))
    path = os.path.join(folder, "log.h5")
    if kind in ("h5-bitflip", "h5-truncate"):
        write_log(path, Log(t, ch, units, attrs=dict(clean.attrs)))
        with open(path, "rb") as fh:
            b = bytearray(fh.read())
        if kind == "h5-bitflip":
            i = int(rng.integers(len(b)))
            b[i] ^= 1 << int(rng.integers(8))
        else:
            b = b[:int(rng.integers(len(b)))]
        with open(path, "wb") as fh:
            fh.write(bytes(b))
        return path
    if kind == "nan-run":
        ch[c][span] = np.nan
    elif kind == "inf-run":
        ch[c][span] = np.inf if rng.random() < 0.5 else -np.inf
    elif kind == "huge":
        ch[c][span] = [1e30, -1e30, 1e300, 3.4e38][int(rng.integers(4))]
    elif kind == "negative":
        ch[c][span] = -np.abs(ch[c][span])
    elif kind == "unit-factor":
        slips = UNIT_SLIPS.get(db_units[c]) or [(1e3, 0.0)]
        fac, off = slips[int(rng.integers(len(slips)))]
        ch[c] = ch[c] * fac + off
    elif kind == "unit-declared":
        wrong = [(k, w) for k, w in ((k, WRONG_DECLARED.get(db_units[k])) for k in names) if w]
        c, w = wrong[int(rng.integers(len(wrong)))]
        units[c] = w[int(rng.integers(len(w)))]
    elif kind == "unit-unknown":
        units[c] = ["furlong/fortnight", "degK", "KPA", "lbs"][int(rng.integers(4))]
    elif kind == "time-backwards":
        t[a], t[a - 1] = t[a - 1], t[a]
    elif kind == "time-nan":
        t[a] = np.nan
    elif kind == "time-duplicate":
        t[a] = t[a - 1] if a else t[1]
    elif kind == "dt-change":
        t = t[0] + (t - t[0]) * [2.0, 4.0, 0.5, 1.5, 1 / 3][int(rng.integers(5))]
    elif kind == "drop-channel":
        del ch[c]
    elif kind == "empty":
        t = t[:0]
        ch = {k: v[:0] for k, v in ch.items()}
    elif kind.startswith("csv-"):
        return _broken_csv(t, ch, units, folder, kind, rng)
    if kind == "empty":
        path = os.path.join(folder, "log.csv")
        with open(path, "w") as fh:
            fh.write("time[s]," + ",".join(f"{k}[{units.get(k, '')}]" for k in ch) + "\n")
        return path
    write_log(path, Log(t, ch, units, attrs=dict(clean.attrs)))
    return path


def _broken_csv(t, ch, units, folder, kind, rng) -> str:
    path = os.path.join(folder, "log.csv")
    m = min(t.size, 400)
    head = ["time[s]"] + [f"{k}[{units.get(k, '')}]" for k in ch]
    rows = [[repr(float(t[i]))] + [repr(float(v[i])) for v in ch.values()] for i in range(m)]
    i = int(rng.integers(1, m))
    if kind == "csv-duplicate-column":
        j = int(rng.integers(1, len(head)))
        head.append(head[j])
        rows = [r + [r[j]] for r in rows]
    elif kind == "csv-ragged":
        rows[i] = rows[i][:-int(rng.integers(1, len(rows[i])))]
    elif kind == "csv-text":
        rows[i][int(rng.integers(len(rows[i])))] = ["abc", "1.2.3", "--", "nan%", "0x1g"][int(rng.integers(5))]
    text = "\n".join(",".join(r) for r in [head] + rows) + "\n"
    data = text.encode()
    if kind == "csv-non-utf8":
        k = int(rng.integers(len(data)))
        data = data[:k] + bytes([0xff, 0xfe]) + data[k:]
    with open(path, "wb") as fh:
        fh.write(data)
    return path


# ---- outcome -----------------------------------------------------------------------------------
def outcome(run, clean) -> tuple[str, str]:
    """Classify one mutant: ``run()`` returns a :class:`pwl.results.Result` or raises; ``clean``
    is the clean run's Result. Returns (outcome, detail)."""
    try:
        res = run()
    except PwlError as e:
        return "named", f"{type(e).__name__}: {e}"
    except Exception as e:  # noqa: BLE001 - what the test is looking for
        return "traceback", f"{type(e).__name__}: {e}"
    if _equal(res, clean):
        return "equal", ""
    a, b = res.counts(), clean.counts()
    keys = tuple(FLAG_COUNTS)
    if any(a[k] != b[k] for k in keys):
        return "flagged", ", ".join(f"{k} {b[k]} -> {a[k]}" for k in keys if a[k] != b[k])
    return "silent", "estimates differ with the same flags"


def _equal(res, clean, rtol: float = 1e-9) -> bool:
    if res.time.shape != clean.time.shape or not np.array_equal(res.flags, clean.flags):
        return False
    for o, v in clean.outputs.items():
        w = res.outputs.get(o)
        if w is None or w.shape != v.shape:
            return False
        if not np.allclose(w, v, rtol=rtol, atol=0.0, equal_nan=True):
            return False
    return True
