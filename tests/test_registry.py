"""The estimator registry: a new estimator is one function and one registration, and the places
that list estimators read their names from it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.harness import estimators as hest
from simtest.harness import suite as hsuite
from simtest.harness.report import write_report
from simtest.harness.runner import run_suite
from simtest.harness.suite import suite_from_dict
from simtest.reconstruct import io as rio
from simtest.reconstruct import recommend, registry

TOY = "toy_mid_axis"


def _toy(est, truth):
    """The cone axis and the BP ray averaged: a normal of the highlight's own, not the truth's."""
    a, b = registry.unit_or_none(getattr(est, "cone_axis", None)), registry.unit_or_none(est.bp_ray)
    return None if a is None or b is None else a + b


@pytest.fixture
def toy():
    registry.register(TOY, _toy, kind="isophote", description="toy: the cone axis and the BP ray averaged")
    yield TOY
    registry.unregister(TOY)


def test_the_lists_are_the_registry_s():
    # what every place listed by hand before: same names, same order
    assert hsuite.ESTIMATOR_NAMES == ("paper_oracle", "paper_selected", "cone_axis", "joint_cone_axis",
                                      "bp_ray")
    assert hest.LIGHT_AWARE_FITS == rio.LIGHT_AWARE_NORMALS == (
        "isocurve_fit", "photometric_fit", "quadric_fit", "cubic_patch_fit", "rig_centroid", "rig_pair")
    assert recommend.LIGHT_AWARE == ("photometric_fit", "cubic_patch_fit", "quadric_fit", "isocurve_fit")
    assert recommend.COLOCATED_ORDER == ("joint_cone_axis", "cone_axis", "bp_ray")
    assert set(hest.STATUS_FREE) == {"bp_ray", "photometric_fit", "quadric_fit", "cubic_patch_fit",
                                     "rig_centroid", "rig_pair", "recommended", "photometric_fit_on_specular",
                                     "photometric_fit_on_radiance"}
    assert hest.ORACLE_INPUTS == {"photometric_fit_on_specular": "specular",
                                  "photometric_fit_on_radiance": "linear"}
    assert hest.ESTIMATORS is registry.NORMAL_READERS


def test_a_bad_registration_is_refused():
    with pytest.raises(ValueError, match="kind 'cone'"):
        registry.register("x", _toy, kind="cone", description="")
    with pytest.raises(ValueError, match="outputs"):
        registry.register("x", _toy, kind="isophote", description="", outputs=("curvature",))
    assert "x" not in registry.names()


def test_a_registered_estimator_is_scored_and_reported(toy, tmp_path):
    # one registration: the suite takes the name, the harness scores it, and the report's tables
    # and results.json list it with its description (the paper protocol, end to end)
    assert toy in hest.ESTIMATORS and toy in registry.names("isophote")
    raw = {"suite": {"name": "toy", "realisations": 3, "seed": 5, "estimators": ["cone_axis", "bp_ray", toy]},
           "sweep": [{"name": "theta", "parameter": "theta_deg", "values": [40.0]}]}
    run = run_suite(suite_from_dict(raw), workers=1, progress=False)
    folder = write_report(run, tmp_path, run_id="r1")
    res = json.loads((folder / "results.json").read_text())
    assert toy in res["suite"]["estimators"]
    assert res["estimators"][toy] == "toy: the cone axis and the BP ray averaged"
    m = res["cases"][0]["metrics"]["estimators"]
    assert m[toy]["n_ok"] == 3 and m["cone_axis"]["n_ok"] == 3
    # the mean of two unit normals lies on the arc between them: its error is at most the larger
    # of theirs (a sum of the two means bounds it however the samples pair)
    assert 0.0 < m[toy]["mean"] <= m["cone_axis"]["mean"] + m["bp_ray"]["mean"]
    assert toy in (folder / "report.md").read_text()


def test_an_unregistered_name_is_refused_by_the_suite():
    raw = {"suite": {"name": "toy", "realisations": 1, "estimators": [TOY]},
           "sweep": [{"name": "theta", "parameter": "theta_deg", "values": [40.0]}]}
    with pytest.raises(Exception, match=TOY):
        suite_from_dict(raw)


def test_score_reads_the_registry_s_status_rule(toy):
    class Est:
        status = "merged"
        cone_axis = np.array([0.0, 0.0, -1.0])
        bp_ray = np.array([0.0, 0.0, -1.0])

    got = hest.score(Est(), np.array([0.0, 0.0, -1.0]), [toy, "bp_ray"])
    assert got[toy][1] == "merged"  # an isophote estimator: not scored on a flagged highlight
    assert got["bp_ray"] == (0.0, None)  # the baseline is status-free
