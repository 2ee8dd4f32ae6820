"""The co-located claims' verdicts follow their numbers exactly (the paper's figure-3 statements and
our curvature predictions, simtest.harness.claims): each verdict is drawn over random case
statistics and compared with its rule, and a case outside a claim's scope never decides it."""

from __future__ import annotations

from hypothesis import given, settings, strategies as st

from simtest.harness.claims import evaluate_claims
from simtest.tolerances import TOL


def _case(i, family, est=None, diag=None, params=None):
    """A co-located rendered case of ``family`` with estimator statistics ``est`` ({name: {stat:
    value}}) and diagnostics ``diag``."""
    return {"id": f"{family}@{i}", "key": f"{family}{i}", "protocol": "rendered", "colocated": True,
            "family": family, "params": params or {},
            "metrics": {"estimators": est or {}, "diagnostics": diag or {}}}


def _verdicts(cases):
    return {v["id"]: v for v in evaluate_claims({"cases": cases, "sweeps": []})}


_DEG = st.floats(0.0, 5.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(_DEG, min_size=1, max_size=6), _DEG)
def test_the_bp_ray_is_exact_exactly_when_every_clean_case_is_within_the_bound(medians, noisy):
    cases = [_case(i, "plane", {"bp_ray": {"median": m}}) for i, m in enumerate(medians)]
    # a noisy sensor's case is outside the claim's scope, however far off
    cases.append(_case(99, "plane", {"bp_ray": {"median": 100.0 + noisy}}, params={"sensor.gaussian_sigma": 0.01}))
    v = _verdicts(cases)["bp_ray_exact_colocated"]
    assert v["holds"] is (max(medians) <= TOL.claim_bp_ray_colocated_deg)
    assert f"over {len(medians)} cases" in v["measured"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(_DEG, _DEG), min_size=1, max_size=6))
def test_the_bp_ray_beats_the_cone_axis_exactly_when_it_is_lower_on_every_curved_case(pairs):
    cases = [_case(i, "sphere", {"bp_ray": {"median": b}, "cone_axis": {"median": c}})
             for i, (b, c) in enumerate(pairs)]
    cases.append(_case(99, "plane", {"bp_ray": {"median": 9.0}, "cone_axis": {"median": 0.0}}))  # not curved
    v = _verdicts(cases)["bp_ray_beats_cone_axis_curved"]
    wins = sum(b < c for b, c in pairs)
    assert v["holds"] is (wins == len(pairs))
    assert v["measured"].startswith(f"bp_ray lower in {wins} of {len(pairs)} cases")


_GAP = st.floats(0.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(_GAP, st.floats(-0.05, 0.05)), min_size=1, max_size=6), st.floats(0.0, 1.0))
def test_rho_predicts_the_gap_exactly_within_its_bound_on_the_analytic_quadrics(rows, liver_dev):
    # measured = predicted + dev on spheres; a liver (no analytic quadric) is reported, never decides
    cases = [_case(i, "sphere", diag={"predicted_gap": g, "eigenvalue_gap": g + d}) for i, (g, d) in enumerate(rows)]
    cases.append(_case(99, "liver", diag={"predicted_gap": 0.0, "eigenvalue_gap": liver_dev}))
    v = _verdicts(cases)["rho_predicts_gap"]
    dev = max(abs((g + d) - g) for g, d in rows)
    assert v["holds"] is (dev <= TOL.claim_rho_gap_abs)
    assert "liver: largest |measured - predicted|" in v["measured"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 30.0), st.floats(-3.0, 3.0)), min_size=1, max_size=6))
def test_rho_predicts_the_pose_error_exactly_within_its_bound_on_the_analytic_quadrics(rows):
    cases = [_case(i, "cylinder", {"paper_oracle": {"mean": p + d}}, {"predicted_gap": 0.5, "predicted_pose_deg": p})
             for i, (p, d) in enumerate(rows)]
    v = _verdicts(cases)["rho_predicts_pose_error"]
    assert v["holds"] is (max(abs((p + d) - p) for p, d in rows) <= TOL.claim_rho_pose_deg)
