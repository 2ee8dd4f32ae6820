"""A researcher's own method on the suites (simtest.harness.external), through the command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from simtest.geometry.cameras import PinholeCamera
from simtest.harness.external import (ExternalError, external_estimators, load_external, score_external,
                                      with_external)
from simtest.harness.suite import load_suite

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE / "data" / "external"
README = HERE.parent / "README.md"


def test_the_readme_shows_the_example_as_it_is_tested():
    code = (EXAMPLE / "my_method.py").read_text(encoding="utf-8")
    body = code.split('"""', 2)[2].strip()  # the module without its docstring
    assert body in README.read_text(encoding="utf-8")
    assert len(code.splitlines()) <= 20


def _flat_truth(n=(0.0, 0.0, -1.0)):
    cam = PinholeCamera(np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]]), image_size=(101, 101))
    return cam, np.asarray(n) / np.linalg.norm(n)


def test_score_external_matches_within_the_radius_and_scores_the_angle(monkeypatch):
    cam, n = _flat_truth()
    mod = type(sys)("_ext_probe")
    # the answer: a BP 2 px off the truth with a normal 10 deg off, and a far one
    tilt = np.deg2rad(10.0)
    mod.f = lambda frame, camera, rig, response: {
        "bp_px": [[52.0, 50.0], [90.0, 90.0]],
        "normal": [[0.0, np.sin(tilt), -np.cos(tilt)], [0, 0, -1]]}
    monkeypatch.setitem(sys.modules, "_ext_probe", mod)
    got = score_external("_ext_probe:f", np.zeros((101, 101)), cam, None, None,
                         [((50.0, 50.0), n), ((10.0, 10.0), n)], match_px=3.0)
    assert got[0][1] is None and abs(got[0][0] - 10.0) < 1e-9
    assert np.isnan(got[1][0]) and got[1][1] == "not_detected"


def test_a_malformed_answer_is_named(monkeypatch):
    cam, n = _flat_truth()
    mod = type(sys)("_ext_bad")
    mod.f = lambda *a: {"bp_px": [[1.0, 2.0]], "normal": [[0, 0, -1], [0, 0, -1]]}
    monkeypatch.setitem(sys.modules, "_ext_bad", mod)
    with pytest.raises(ExternalError, match="1 rows and 'normal' 2"):
        score_external("_ext_bad:f", np.zeros((5, 5)), cam, None, None, [((1, 2), n)], 3.0)


@pytest.mark.parametrize("spec, why", [("nonsense", "expected package.module:function"),
                                       ("no_such_module_xyz:f", "cannot import"),
                                       ("json:no_such_function", "has no function"),
                                       ("bp_ray=os.path:join", "is taken"),
                                       # the protocol's four arguments: refused before any render, not per realisation
                                       ("json:dumps", r"dumps\(obj, \*, .*\) cannot be called as f\(frame, camera"),
                                       ("math:hypot", None), ("os.path:join", None)])
def test_a_bad_spec_is_refused_in_one_line(spec, why):
    if why is None:  # four positional arguments fit (hypot(*coordinates), join(a, *p))
        assert load_external(spec).__name__ == spec.split(":")[1]
        return
    with pytest.raises(ExternalError, match=why):
        external_estimators([spec], taken=("bp_ray",))


def test_the_suite_keeps_its_external_estimators_through_overrides(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    s = with_external(load_suite("quick"), ["mine=my_method:bp_ray_cv"])
    t = s.with_overrides(seed=3, realisations=2)
    assert t.estimators[-1] == "mine" and t.external == (("mine", "my_method:bp_ray_cv"),)


#: The README's line that runs the example (tests/test_readme_examples.py runs it and checks its
#: run with :func:`check_external_run`: the suite runs once for both).
README_LINE = ("PYTHONPATH=tests/data/external simtest validate quick --estimator my_method:bp_ray_cv "
               "-o out/reports")


def check_external_run(folder: Path) -> None:
    """The run folder of ``simtest validate quick --estimator my_method:bp_ray_cv``, as the README
    shows it: the external column is reported beside the built-in ones, and an OpenCV BP ray errs
    as the built-in BP ray does on the paper protocol's planes."""
    res = json.loads((folder / "results.json").read_text())
    assert res["suite"]["estimators"][-1] == "bp_ray_cv"
    assert "bp_ray_cv" in (folder / "report.md").read_text()
    for case in res["cases"]:
        m = case["metrics"]["estimators"]
        assert m["bp_ray_cv"]["n_ok"] > 0, case["id"]
        if case["id"].startswith("paper_"):
            # its BP is the brightest pixel of the smoothed image, the built-in's a sub-pixel
            # peak: at f of hundreds of px, a pixel moves the ray by a fraction of a degree; 1 deg
            # is several pixels
            assert abs(m["bp_ray_cv"]["median"] - m["bp_ray"]["median"]) < 1.0, case["id"]


def test_the_readme_runs_the_example_and_its_test_checks_the_run():
    """The command line's run of the example is the README's own line (one run of the quick suite
    in worker processes, each importing ``my_method``); the README examples' test runs it and
    checks its folder with :func:`check_external_run`."""
    assert README_LINE in README.read_text(encoding="utf-8").splitlines()
    examples = (HERE / "test_readme_examples.py").read_text(encoding="utf-8")
    assert "check_external_run(" in examples
