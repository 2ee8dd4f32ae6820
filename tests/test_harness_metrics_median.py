"""The depth error's median beside its mean in a case's diagnostics (issue 39's flat-mucosa
must-hold bounds the median of the specular point's depth error)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.harness.metrics import case_metrics


def _result(extras):
    n = len(next(iter(extras.values())))
    return SimpleNamespace(errors={"bp_ray": np.ones(n)}, causes={"bp_ray": [None] * n},
                           extras={k: np.asarray(v, dtype=np.float64) for k, v in extras.items()})


def test_depth_error_median_beside_its_mean():
    # a skewed case (one highlight far off): mean 22 %, median 2 %; NaN rows (no depth) left out
    d = case_metrics(_result({"recommended_depth_err_pct": [1.0, 2.0, 3.0, 82.0, np.nan],
                              "bp_error_px": [0.1, 0.2, 0.3, 0.4, 0.5]}))["diagnostics"]
    assert d["recommended_depth_err_pct"] == 22.0
    assert d["recommended_depth_err_pct_median"] == 2.5
    assert "bp_error_px_median" not in d  # only the depth errors have a median
    none = case_metrics(_result({"photometric_fit_depth_err_pct": [np.nan, np.nan]}))["diagnostics"]
    assert none["photometric_fit_depth_err_pct"] is None
    assert none["photometric_fit_depth_err_pct_median"] is None


@settings(max_examples=30, deadline=None)
@given(st.lists(st.one_of(st.floats(0, 1e3), st.just(float("nan"))), min_size=1, max_size=30))
def test_depth_error_median_is_numpys_over_finite_rows(v):
    d = case_metrics(_result({"recommended_depth_err_pct": v}))["diagnostics"]
    f = np.asarray(v)[np.isfinite(v)]
    assert d["recommended_depth_err_pct_median"] == (float(np.median(f)) if f.size else None)
