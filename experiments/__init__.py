"""experiments: the seed-paper reproductions and their drivers (DESIGN.md section 1).

They use ``pwl`` (the core), ``linearize`` and ``models``; nothing in ``pwl``, ``linearize`` or
``models`` imports them, except the ``pwl`` command's modules (``pwl/cli``), lazily inside the
command's ``run``. Plain functions returning numbers: the commands print and plot them, the
tests check the claims on small seeded runs.

- :mod:`experiments.tables`: adaptive look-up tables, seed 000 sec. 5 and the seed 003 battery
  case (``pwl tables seed000|battery``);
- :mod:`experiments.bias_observer`: the fuel-to-air ratio bias observer of seed 004 (numba
  kernel, ``BiasObserver``, ``FreezeRules``); :mod:`experiments.bias`: its drive-cycle run on
  the simulated diesel engine (``pwl bias``);
- :mod:`experiments.ekf`: the scheduled-gain EKF (SEKF) and full EKF loops of seed 001;
  :mod:`experiments.zones`: its Monte Carlo, speed runs and the gain-database comparison
  (``pwl zones``);
- :mod:`experiments.biastable`: the runtime's bias table on the turbofan (``pwl biastable``).
"""
