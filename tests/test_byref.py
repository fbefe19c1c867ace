"""Records by reference (pwl.byref): fields() reads what numba's own structref attribute access
reads, in a kernel compiled without reference counting, and the record keeps its values alive."""
import gc

import numpy as np
from numba import njit

from pwl.byref import fields, record

Rec = record("Rec", ["a", "pair", "x", "n"], "A test record.")


@njit(_nrt=False)
def _read(rec):
    a, pair, x, n = fields(rec)
    a[0] += 1.0                      # writes go to the record's array
    return a.sum() + pair[0][1] + pair[1][2] * x + n


@njit
def _read_attr(rec):
    return rec.a.sum() + rec.pair[0][1] + rec.pair[1][2] * rec.x + rec.n


def test_fields_read_what_structref_attributes_read():
    a = np.arange(5.0)
    rec = Rec(a, (np.linspace(0, 1, 3), np.array([[1, 2, 3]], dtype=np.int64)[0]), 2.5, 7)
    got = _read(rec)                  # after a[0] += 1
    assert a[0] == 1.0                # the record holds the caller's array, not a copy
    assert got == _read_attr(rec) == a.sum() + 0.5 + 3 * 2.5 + 7


def test_a_record_keeps_its_arrays_alive():
    rec = Rec(np.full(1000, 2.0), (np.zeros(3), np.zeros(3, dtype=np.int64)), 0.0, 0)
    gc.collect()
    junk = [np.full(1000, 1e300) for _ in range(200)]     # reuse freed memory, were it freed
    assert _read(rec) == 2.0 * 999 + 3.0
    del junk
