"""The reports' 2-sigma coverage of the recommended normal (issue 39: at least 0.9 of the
highlights' errors within twice their stated sigma)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from hypothesis import given, strategies as st

from simtest.harness.protocols import _sigma_coverage


def _est(sigma):
    return SimpleNamespace(recommended=SimpleNamespace(normal_sigma_deg=sigma))


@given(err=st.floats(0.0, 30.0), sigma=st.floats(1e-3, 10.0))
def test_covered_exactly_when_the_error_is_within_twice_sigma(err, sigma):
    got = _sigma_coverage(_est(sigma), {"recommended": (err, None)})["recommended_within_2sigma"]
    assert got == (1.0 if err <= 2.0 * sigma else 0.0)


@pytest.mark.parametrize("est, errs", [
    (_est(None), {"recommended": (1.0, None)}),          # the BP ray states no sigma
    (_est(0.5), {"recommended": (math.nan, "merged")}),  # not scored
    (None, {"recommended": (math.nan, "not_detected")}),
    (_est(0.5), {}),                                      # the estimator not in the suite
])
def test_no_sigma_or_no_score_is_no_sample(est, errs):
    assert math.isnan(_sigma_coverage(est, errs)["recommended_within_2sigma"])
