"""Validation harness: sweeps (TOML suites), two protocols, metrics, reports, nightly guard.

- :mod:`~simtest.harness.suite`: suite files -> cases, seeds per realisation.
- :mod:`~simtest.harness.protocols`: the ``paper`` and ``rendered`` per-case runners.
- :mod:`~simtest.harness.estimators`: the estimators scored side by side (a registry).
- :mod:`~simtest.harness.runner`: process-parallel runs with progress, worker-count independent.
- :mod:`~simtest.harness.metrics`, :mod:`~simtest.harness.report`: statistics and reports.
- :mod:`~simtest.harness.nightly`: comparison with ``reports/baseline.json``.
- :mod:`~simtest.harness.cli`: ``simtest validate`` and ``simtest nightly``.

Importing this package is cheap (no Mitsuba, no Dask, no matplotlib).
"""
