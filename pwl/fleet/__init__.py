"""pwl.fleet: many logs and what comes after the estimate (not on the path of a log sample).

- :mod:`pwl.fleet.runs`: :func:`~pwl.fleet.runs.run_many` (many logs through one database on a
  process pool or a Dask cluster, resume, per-log errors) and the fleet summary
  (:func:`~pwl.fleet.runs.write_summary`, :func:`~pwl.fleet.runs.read_summary`);
- fleet diagnostics on results files: :mod:`pwl.fleet.signatures` (fault signatures at matched
  scheduling), :mod:`pwl.fleet.diagnose` (detection, isolation, sizing),
  :mod:`pwl.fleet.trending` (one engine's health trend and verdict), :mod:`pwl.fleet.scoring`
  (ProDiMES-style scoring of a diagnosis against the fleet's truth).

This room imports pwl core (and numpy, scipy, h5py; pandas, matplotlib and Dask inside the
functions that need them); core never imports it. ``run_many`` is also exported lazily as
``pwl.run_many``.
"""
