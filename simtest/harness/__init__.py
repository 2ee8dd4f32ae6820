"""Validation harness: TOML suites of sweeps, two protocols, metrics, reports, nightly gate.

:mod:`~simtest.harness.suite` (suites -> cases), :mod:`~simtest.harness.protocols` (per-case
runners), :mod:`~simtest.harness.runner` (parallel runs), :mod:`~simtest.harness.report` and
:mod:`~simtest.harness.claims` (results, figures, claims), :mod:`~simtest.harness.nightly` (the
baseline gate), :mod:`~simtest.harness.cli` (``simtest validate`` and ``simtest nightly``).
Importing this package is cheap (no Mitsuba, no Dask, no matplotlib).
"""
