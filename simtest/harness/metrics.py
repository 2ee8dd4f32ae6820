"""Statistics of angular errors per case and estimator.

For each case and estimator: the number of scored specularities ``n``, of successes ``n_ok``, the
failure rate and the failures by cause, and over the successes the mean, standard deviation
(population, ddof = 0: the spread of the realisations drawn, as the paper's black bars), median,
5th and 95th percentiles (linear interpolation, numpy's default), min and max, in degrees. Statistics of an
estimator that never succeeded are None.

Numbers are computed from arrays in realisation order, so the same realisations give bit-identical
statistics whatever the number of workers that produced them.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from simtest.harness.end_to_end import summarise_records
__all__ = ["summarise", "case_metrics", "STAT_KEYS", "MEDIAN_SUFFIX", "MEDIAN_DIAGNOSTICS",
           "COUNTED_DIAGNOSTICS", "COUNT_SUFFIX"]

#: The statistics reported for each case and estimator (degrees, except failure_rate and counts).
STAT_KEYS = ("mean", "std", "median", "p5", "p95", "min", "max")

#: Diagnostics (by suffix) whose median is reported beside their mean, as ``<key>_median``: a
#: depth error's distribution is skewed (a few highlights far off lift the mean), and issue 39's
#: must-hold on the flat mucosa bounds its median.
MEDIAN_DIAGNOSTICS = ("_depth_err_pct",)

#: The suffix of a diagnostic's median (``recommended_depth_err_pct_median``).
MEDIAN_SUFFIX = "_median"

#: Diagnostics (by suffix) whose number of finite values is reported beside their mean, as
#: ``<key>_n``: a share over the highlights that have it (``recommended_within_2sigma``,
#: ``recommended_beyond_bp_ray``: those with a stated sigma), which a suite pools over its cases
#: weighted by these counts.
COUNTED_DIAGNOSTICS = ("_within_2sigma", "_beyond_bp_ray")

#: The suffix of a diagnostic's count (``recommended_within_2sigma_n``).
COUNT_SUFFIX = "_n"


def summarise(errors, causes) -> dict:
    """Statistics of one estimator on one case.

    Parameters
    ----------
    errors : array_like of shape (S,)
        Errors in degrees, NaN where the estimator failed.
    causes : sequence of (str or None), length S
        The failure cause of each NaN (None where it succeeded).

    Returns
    -------
    dict
        ``n, n_ok, failure_rate, failures ({cause: count}), mean, std, median, p5, p95, min, max``.

    Raises
    ------
    ValueError
        If ``errors`` and ``causes`` differ in length, or a failure has no cause.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if len(causes) != e.size:
        raise ValueError(f"{e.size} errors but {len(causes)} causes")
    ok = np.isfinite(e)
    fails = Counter()
    for good, c in zip(ok, causes):
        if not good:
            fails[c if c else "nan_error"] += 1
    n, n_ok = int(e.size), int(ok.sum())
    out = {"n": n, "n_ok": n_ok, "failure_rate": (n - n_ok) / n if n else 0.0,
           "failures": dict(sorted(fails.items()))}
    if n_ok:
        v = e[ok]
        out.update(mean=float(np.mean(v)), std=float(np.std(v)), median=float(np.median(v)),
                   p5=float(np.percentile(v, 5)), p95=float(np.percentile(v, 95)),
                   min=float(np.min(v)), max=float(np.max(v)))
    else:
        out.update({k: None for k in STAT_KEYS})
    return out


def case_metrics(result) -> dict:
    """Statistics of every estimator of one case, plus the means of its diagnostics.

    Parameters
    ----------
    result : simtest.harness.runner.CaseResult
        The scored rows of the case.

    Returns
    -------
    dict
        ``{"estimators": {name: summarise(...)}, "diagnostics": {extra: mean or None}}``; a
        diagnostic's mean is over its finite values (eigenvalue gap, fit residual in px, BP error
        in px, curvatures in 1/mm), None if it has none. A diagnostic whose key ends with one of
        :data:`MEDIAN_DIAGNOSTICS` (the depth errors, %) has its median over its finite values
        beside it, as ``<key>_median``; one ending with one of :data:`COUNTED_DIAGNOSTICS` its
        number of finite values, as ``<key>_n``.

    Raises
    ------
    ValueError
        If an estimator's errors and causes differ in length (see :func:`summarise`).
    """
    est = {k: summarise(result.errors[k], result.causes[k]) for k in result.errors}
    extras = {}
    for k, v in result.extras.items():
        v = np.asarray(v, dtype=np.float64)
        f = v[np.isfinite(v)]
        extras[k] = float(np.mean(f)) if f.size else None
        if k.endswith(MEDIAN_DIAGNOSTICS):
            extras[k + MEDIAN_SUFFIX] = float(np.median(f)) if f.size else None
        if k.endswith(COUNTED_DIAGNOSTICS):
            extras[k + COUNT_SUFFIX] = int(f.size)
    return {"end_to_end": summarise_records(getattr(result, "e2e", [])), "estimators": est,
            "diagnostics": extras}
