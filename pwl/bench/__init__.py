"""Benchmarks and the reference filter: measuring the core, never on the path of a log sample.

- :mod:`pwl.bench.speed`: interpolation kernel vs scipy, the runtime vs the reference filter,
  streaming vs batch (``pwl bench interp|run|stream``); ``_best_of`` and ``random_walk`` helpers;
- :mod:`pwl.bench.tables`: adaptive-table updates vs numpy (``pwl bench table``,
  ``pwl tables bench``);
- :mod:`pwl.bench.reference`: a plain numpy + scipy per-step reference of the runtime filter
  (for tests and benchmarks);
- :mod:`pwl.bench.fuzz`: seeded mutants of databases and logs (``tests/test_fuzz.py``,
  ``benchmarks/fuzz.py``).

Speed is reported as ratios against a reference run in the same process, never asserted in
tests. These modules import the core (``pwl``); the core never imports them.
"""
