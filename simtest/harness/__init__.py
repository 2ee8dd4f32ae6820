"""Validation harness: sweeps (TOML suites), two protocols, metrics, reports, nightly guard.

- :mod:`~simtest.harness.suite`: suite files -> cases, seeds per realisation.
- :mod:`~simtest.harness.protocols`: the ``paper`` and ``rendered`` per-case runners.
- :mod:`~simtest.harness.estimators`: the estimators scored side by side (a registry).
- :mod:`~simtest.harness.runner`: process-parallel runs with progress, worker-count independent.
- :mod:`~simtest.harness.metrics`, :mod:`~simtest.harness.report`: statistics and reports
  (results document, figures, Markdown and HTML); :mod:`~simtest.harness.claims`: the paper's
  claims and our predictions, checked on results.
- :mod:`~simtest.harness.nightly`: the gate against ``reports/baseline.json`` (tolerances from
  seed spread), its history.
- :mod:`~simtest.harness.readme`, :mod:`~simtest.harness.regenerate`: the README section from
  the committed reports; one command that regenerates them all.
- :mod:`~simtest.harness.cli`: ``simtest validate`` and ``simtest nightly``.

Importing this package is cheap (no Mitsuba, no Dask, no matplotlib).
"""
