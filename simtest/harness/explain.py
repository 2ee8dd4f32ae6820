"""Explanations of a report's alarming cells: for each family x estimator whose median error is
above :data:`~simtest.harness.claims.ALARM_DEG`, the measured reason, when one of its rules applies
(the paper protocol's slanted camera and fronto-parallel breakdown, curvature anisotropy, a depth
the light-aware fit cannot observe)."""

from __future__ import annotations

import numpy as np

from simtest.harness.claims import ALARM_DEG, _diag, _range, _rendered, _stat, _unique
from simtest.tolerances import TOL

__all__ = ["THETA0_FACTOR", "explanations"]

#: A paper-protocol case at theta = 0 whose oracle error exceeds this many times its family's
#: median is explained as the fronto-parallel breakdown.
THETA0_FACTOR = 3.0


def _paper_theta_cases(results):
    return _unique([c for c in results["cases"] if c["protocol"] == "paper"
                    and c["params"].get("theta_deg") is not None])


def _explain_paper(results, est):
    cs = [c for c in _paper_theta_cases(results) if _stat(c, est, "mean") is not None]
    if not cs:
        return None
    th = np.array([c["params"]["theta_deg"] for c in cs])
    err = np.array([_stat(c, est, "mean") for c in cs])
    if est == "paper_oracle":
        z = [c for c in cs if c["params"]["theta_deg"] == 0 and _diag(c, "eigenvalue_gap")]
        if not z:
            return None
        g = np.array([_diag(c, "eigenvalue_gap") for c in z])
        pred = np.degrees(np.arcsin(np.sqrt(np.clip(g, 0, 1))))
        return (f"at theta = 0 the isophote cone is nearly right circular (mean eigenvalue gap "
                f"{_range(g)}), and N+- leave its axis by asin(sqrt(gap)) = {_range(pred)} deg; "
                f"measured oracle error there {_range([_stat(c, est, 'mean') for c in z])} deg")
    pos = th > 0
    ratio = err[pos] / th[pos]
    dev = np.abs(err - th)
    txt = (f"the paper protocol's camera is slanted by theta and does not carry the light: mean "
           f"error / theta = {_range(ratio)} over {int(pos.sum())} cases with theta > 0 "
           f"(largest |error - theta| {dev.max():.3g} deg)")
    if est == "paper_selected":
        txt += ("; choosing between N+ and N- by closeness to the BP ray, itself theta off the "
                "normal, picks the wrong one")
    return txt


def _explain_rendered(results, family, est):
    cs = [c for c in _rendered(results, colocated=not family.endswith("light offset"))
          if c.get("family") == family and _stat(c, est) is not None]
    if not cs:
        return None
    if est in ("paper_oracle", "paper_selected"):
        pc = [c for c in cs if _diag(c, "predicted_pose_deg") is not None]
        if pc:
            return (f"curvature anisotropy: asin(sqrt(1 - rho^2)) predicts "
                    f"{_range([_diag(c, 'predicted_pose_deg') for c in pc])} deg on these cases "
                    f"(measured mean {_range([_stat(c, est, 'mean') for c in pc])} deg)")
    worst = max(cs, key=lambda c: _stat(c, est))
    parts = [f"worst case {worst['id']}: median {_stat(worst, est):.3g} deg"]
    sig = _diag(worst, f"{est}_depth_rel_sigma")
    if sig is not None:  # a curved light-aware fit: whether its depth, hence its normal, is fixed
        parts.append(f"its relative depth sigma {sig:.3g}"
                     + (f" (above {TOL.depth_rel_sigma_max:g}: the depth, and with it the "
                        f"normal, is not observable)" if sig > TOL.depth_rel_sigma_max else ""))
    for key, lab in (("residual_px", "fit residual {:.3g} px"), ("rho", "rho {:.3g}"),
                     ("eigenvalue_gap", "eigenvalue gap {:.3g}")):
        v = _diag(worst, key)
        if v is not None:
            parts.append(lab.format(v))
    return ", ".join(parts)


def explanations(results: dict) -> list[dict]:
    """The measured reason behind each alarming family x estimator cell, where a rule applies.

    Parameters
    ----------
    results : dict
        A ``results.json`` document with ``families``.

    Returns
    -------
    list of dict
        ``{"family", "estimator", "median", "text"}`` for every cell whose pooled median exceeds
        :data:`ALARM_DEG`, and for the paper protocol's oracle at theta = 0 when it exceeds
        :data:`THETA0_FACTOR` times its family median; ``text`` is None where no rule explains
        it (the report says so).
    """
    out = []
    for fam, f in results.get("families", {}).items():
        for est, m in f["estimators"].items():
            if m.get("median") is None or m["median"] <= ALARM_DEG:
                continue
            text = (_explain_paper(results, est) if f["protocol"] == "paper" else _explain_rendered(results, fam, est))
            out.append({"family": fam, "estimator": est, "median": m["median"], "text": text})
    # the fronto-parallel breakdown stands out of its family even below ALARM_DEG
    fam = results.get("families", {}).get("paper protocol", {})
    fmed = (fam.get("estimators", {}).get("paper_oracle") or {}).get("median")
    z = [c for c in _paper_theta_cases(results) if c["params"]["theta_deg"] == 0
         and _stat(c, "paper_oracle", "mean") is not None]
    if fmed and z and max(_stat(c, "paper_oracle", "mean") for c in z) > THETA0_FACTOR * fmed:
        out.append({"family": "paper protocol at theta = 0", "estimator": "paper_oracle",
                    "median": max(_stat(c, "paper_oracle") or 0.0 for c in z),
                    "text": _explain_paper(results, "paper_oracle")})
    return out
