"""Statistics of angular errors per case and estimator.

``n``, ``n_ok``, failure rate and failures by cause, and over the successes the mean, standard
deviation (ddof = 0, as the paper's bars), median, 5th and 95th percentiles (linear
interpolation), min and max, in degrees; None for an estimator that never succeeded. Computed in
realisation order, so bit-identical whatever the number of workers.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

__all__ = ["summarise", "case_metrics", "summarise_records", "MATCH_PX", "WITHIN_DEG", "STAT_KEYS",
           "MEDIAN_SUFFIX", "MEDIAN_DIAGNOSTICS", "COUNTED_DIAGNOSTICS", "COUNT_SUFFIX"]

#: The statistics reported for each case and estimator (degrees, except failure_rate and counts).
STAT_KEYS = ("mean", "std", "median", "p5", "p95", "min", "max")

#: Diagnostics (by suffix) whose median is reported beside their mean (skewed depth errors).
MEDIAN_DIAGNOSTICS = ("_depth_err_pct",)

#: The suffix of a diagnostic's median (``recommended_depth_err_pct_median``).
MEDIAN_SUFFIX = "_median"

#: Diagnostics (by suffix) whose count of finite values is reported beside their mean, as
#: ``<key>_n``: shares a suite pools over its cases weighted by these counts.
COUNTED_DIAGNOSTICS = ("_within_2sigma", "_beyond_bp_ray")

#: The suffix of a diagnostic's count (``recommended_within_2sigma_n``).
COUNT_SUFFIX = "_n"

#: How far a detection's BP may lie from a true highlight's BP to be that highlight's, px; also
#: the default ``match_px`` of a case. The two guides' highlights of the endoscope plane lie about
#: 18 px apart (``reports/detection/2026-12-02-colonoscope_plane``).
MATCH_PX = 15.0

#: Errors (deg) that count as a usable normal (issue 63's headline shares).
WITHIN_DEG = (1.0, 5.0)


def summarise(errors, causes) -> dict:
    """Statistics of one estimator on one case.

    Parameters
    ----------
    errors : array_like of shape (S,)
        Errors in degrees, NaN where the estimator failed.
    causes : sequence of (str or None), length S
        The failure cause of each NaN.

    Returns
    -------
    dict
        ``n, n_ok, failure_rate, failures ({cause: count}), mean, std, median, p5, p95, min, max``.

    Raises
    ------
    ValueError
        If ``errors`` and ``causes`` differ in length.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if len(causes) != e.size:
        raise ValueError(f"{e.size} errors but {len(causes)} causes")
    ok = np.isfinite(e)
    fails = Counter(c if c else "nan_error" for good, c in zip(ok, causes) if not good)
    n, n_ok = int(e.size), int(ok.sum())
    out = {"n": n, "n_ok": n_ok, "failure_rate": (n - n_ok) / n if n else 0.0, "failures": dict(sorted(fails.items()))}
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
    return {"end_to_end": summarise_records(getattr(result, "e2e", [])), "estimators": est, "diagnostics": extras}


def summarise_records(records) -> dict | None:
    """The end-to-end figures of a case or a family (None without a record).

    Returns
    -------
    dict or None
        ``n`` (true highlights), ``detected`` and ``ok`` (shares), ``within_1deg`` and
        ``within_5deg`` (shares whose recommended normal errs at most that much, whatever its
        status), ``n_ok`` and ``median_ok_deg``, ``median_ok_bp_ray_deg`` (the BP ray's on those of
        them whose records carry ``bp_ray_error_deg``; None where none does), ``median_ok_depth_err_pct``,
        ``false_ok_per_frame`` (ok detections on no listed highlight and no specular lobe),
        ``lobe_ok_per_frame`` and ``median_lobe_ok_deg`` (those on a lobe peak with no exact BP,
        scored against the surface normal there), ``n_sigma`` and ``within_2sigma`` (the true
        highlights whose recommended normal states a sigma and is scored, whatever its status, and
        the share of them that err by at most twice it; None without one; records without
        ``sigma_deg`` state none), ``n_depth_sigma`` and ``depth_within_2sigma`` (the same for the
        recommended depth, from the records' ``depth_within_2sigma``), ``statuses`` and
        ``normal_from`` (counts), ``match_px``.
    """
    records = list(records)
    if not records:
        return None
    t = [r for r in records if r.get("truth")]
    err = np.array([r["error_deg"] for r in t], dtype=np.float64)
    ok = np.array([r["status"] == "ok" for r in t], dtype=bool)
    fo = np.array([r["frame_false_ok"] for r in records if "frame_false_ok" in r], dtype=np.float64)
    lobe = np.array([x for r in records for x in r.get("frame_lobe_ok_deg", ())], dtype=np.float64)
    dep = np.array([r["depth_err_pct"] for r in t], dtype=np.float64)[ok] if t else np.zeros(0)
    dep = dep[np.isfinite(dep)]
    okerr = err[ok & np.isfinite(err)] if t else err
    bp = np.array([r.get("bp_ray_error_deg", np.nan) for r in t], dtype=np.float64)
    okbp = bp[ok & np.isfinite(err) & np.isfinite(bp)] if t else bp
    sig = np.array([np.nan if r.get("sigma_deg") is None else r["sigma_deg"] for r in t], dtype=np.float64)
    stated = np.isfinite(sig) & np.isfinite(err)
    dcov = np.array([r.get("depth_within_2sigma", np.nan) for r in t], dtype=np.float64)
    dcov = dcov[np.isfinite(dcov)]
    n = len(t)
    share = (lambda m: float(np.mean(m)) if n else None)  # noqa: E731
    return {"n": n, "detected": share([r["detected"] for r in t]), "ok": share(ok),
            **{f"within_{d:g}deg": share(np.nan_to_num(err, nan=np.inf) <= d) for d in WITHIN_DEG},
            "n_ok": int(okerr.size), "median_ok_deg": float(np.median(okerr)) if okerr.size else None,
            "median_ok_bp_ray_deg": float(np.median(okbp)) if okbp.size else None,
            "median_ok_depth_err_pct": float(np.median(dep)) if dep.size else None,
            "false_ok_per_frame": float(np.mean(fo)) if fo.size else None,
            "lobe_ok_per_frame": lobe.size / fo.size if fo.size else None,
            "median_lobe_ok_deg": float(np.median(lobe[np.isfinite(lobe)])) if np.isfinite(lobe).any() else None,
            "n_sigma": int(stated.sum()),
            "within_2sigma": float(np.mean(err[stated] <= 2.0 * sig[stated])) if stated.any() else None,
            "n_depth_sigma": int(dcov.size), "depth_within_2sigma": float(np.mean(dcov)) if dcov.size else None,
            "statuses": dict(sorted(Counter(r["status"] for r in t).items())),
            "normal_from": dict(sorted(Counter(r["normal_from"] or "none" for r in t).items())),
            "match_px": MATCH_PX}
