"""Nightly gate: seed noise passes, a doubled error fails, bad numbers fail by name.

The runs use the quick suite (seconds each). One module fixture builds a fresh baseline from 4
seed-varied runs, so that these tests do not depend on the machine that made the committed one;
one test checks the committed baseline itself.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from typer.testing import CliRunner

import simtest.harness.cli as hcli
from simtest.cli import app
from simtest.harness import estimators
from simtest.harness.nightly import (CAPS, POLICY, baseline_section, check_section, compare,
                                     gate_summary, metric_class, undetectable_doublings)

#: Largest error (deg) that a rotation away from the truth doubles exactly (2 x 60 < 180).
DOUBLE_MAX_DEG = 60.0


def _rotate_away(n, truth, deg):
    """Rotate unit n by ``deg`` in the plane of (n, truth), away from truth: the error grows by
    exactly ``deg`` (while it stays below 180)."""
    n = np.asarray(n, float)
    truth = np.asarray(truth, float)
    perp = n - np.dot(n, truth) * truth
    if np.linalg.norm(perp) < 1e-12:  # n == truth: any perpendicular direction
        perp = np.cross(truth, [1.0, 0.0, 0.0] if abs(truth[0]) < 0.9 else [0.0, 1.0, 0.0])
    perp /= np.linalg.norm(perp)
    a = np.radians(deg)
    return np.cos(a) * n + np.sin(a) * perp


def _doubled(real):
    """An estimator whose error is twice ``real``'s (for errors below 90 deg)."""

    def f(est, truth):
        n = real(est, truth)
        if n is None:
            return None
        t = np.asarray(truth, float) / np.linalg.norm(truth)
        err = math.degrees(math.atan2(np.linalg.norm(np.cross(n, t)), float(np.dot(n, t))))
        return _rotate_away(n, t, err)

    return f


def _flagged(output: str) -> set[str]:
    """Metric names of the REGRESSION lines (``REGRESSION: <metric>: <a> -> <b> (...)``)."""
    return {m.group(1) for m in re.finditer(r"^REGRESSION: (.*?): \S+ -> ", output, re.M)}


def _nightly(*args):
    return CliRunner().invoke(app, ["nightly", "--quick", "--workers", "1", "--no-progress",
                                    *map(str, args)])


@pytest.fixture(scope="module", autouse=True)
def _renders_once(shared_renders):
    """Each of the quick suite's frames rendered once in this module (conftest's shared_renders):
    the dozen runs at its seed score the same frames, which is what the gate's tests rely on."""
    yield


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("nightly")
    path = d / "baseline.json"
    r = _nightly("--update-baseline", "--repeats", 4, "--baseline", path, "--out", d / "reports")
    assert r.exit_code == 0, r.output
    return path, d


@pytest.fixture
def no_reports(monkeypatch):
    """The run's verdict without its report files: a test that reads the exit code and the
    output only skips drawing them (seconds of matplotlib a run; the report of a nightly run is
    checked by test_unchanged_code_passes_and_keeps_a_history and the README's example)."""
    monkeypatch.setattr(hcli, "write_report_files", lambda results, folder, **kw: folder)


def _edit(src, dst, fn):
    b = json.loads(src.read_text())
    fn(b["suites"]["quick"]["metrics"])
    dst.write_text(json.dumps(b))  # allow_nan: a NaN is written as NaN, as a careless edit would
    return dst


@pytest.mark.slow
def test_unchanged_code_passes_and_keeps_a_history(made):
    path, d = made
    b = json.loads(path.read_text())
    sec = b["suites"]["quick"]
    assert b["schema_version"] == 2 and sec["seeds"] == [0, 1, 2, 3] and sec["policy"] == POLICY
    r = _nightly("--baseline", path, "--out", d / "reports", "--run-id", "same")
    assert r.exit_code == 0, r.output
    assert "REGRESSION" not in r.output and "no regression" in r.output
    hist = (d / "reports" / "quick" / "history.jsonl").read_text().splitlines()
    line = json.loads(hist[-1])
    assert line["verdict"] == "pass" and line["run_id"] == "same"
    assert line["families"]["plane"]["cone_axis"] > 0
    html = (d / "reports" / "quick" / "same" / "report.html").read_text()
    assert "Nightly gate" in html and "nightly_trend.png" in html


@pytest.mark.parametrize("seed", [101, 202])
def test_runs_with_other_seeds_pass(made, seed, no_reports):
    path, d = made
    r = _nightly("--baseline", path, "--out", d / "reports", "--seed", seed)
    assert r.exit_code == 0, r.output


def test_committed_baseline_passes(tmp_path, no_reports):
    r = _nightly("--out", tmp_path, "--seed", 7)
    assert r.exit_code == 0, r.output


def _colocated_cone_axis(name):
    return ":cone_axis:" in name and (name.startswith("family:plane:")
                                      or name.startswith("case:rendered_plane@"))


def test_baseline_claiming_cone_axis_3x_better_fails(made, tmp_path, no_reports):
    path, _ = made

    def better(metrics):
        for k, m in metrics.items():
            if _colocated_cone_axis(k) and m["value"]:
                m["value"] /= 3
                m["spread"] /= 3
                m["tolerance"] = min(POLICY["k_spread"] * m["spread"] + POLICY["rel_floor"]
                                     * m["value"] + POLICY["abs_floor"]["deg"],
                                     CAPS[metric_class(k)])

    edited = _edit(path, tmp_path / "b.json", better)
    r = _nightly("--baseline", edited, "--out", tmp_path)
    assert r.exit_code == 1, r.output
    bad = _flagged(r.output)
    assert "family:plane:cone_axis:median" in bad, r.output
    assert all(_colocated_cone_axis(k) for k in bad), bad


@pytest.mark.parametrize("value, why", [(float("nan"), "NaN"), (float("inf"), "infinite"),
                                        ("0.5", "non-numeric '0.5'")])
def test_baseline_with_one_bad_metric_fails_naming_it(made, tmp_path, value, why):
    path, _ = made
    name = "family:paper protocol:paper_oracle:median"

    def spoil(metrics):
        metrics[name]["value"] = value

    r = _nightly("--baseline", _edit(path, tmp_path / "b.json", spoil), "--out", tmp_path)
    assert r.exit_code == 3, r.output  # a bad baseline, not a regression nor a usage error
    lines = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and f"{name} ({why})" in lines[0], r.output


@pytest.mark.slow
def test_planted_regressions_per_estimator_family(made, tmp_path, monkeypatch, no_reports):
    """Double one estimator at a time: exactly its detectable metrics regress, nothing else.

    The run repeats the baseline's seed, so every error of the planted estimator is exactly
    twice the baseline's (below 90 deg) and every other metric is unchanged.
    """
    path, _ = made
    sec = json.loads(path.read_text())["suites"]["quick"]
    weak = set(undetectable_doublings(sec))
    ests = sorted({k.split(":")[-2] for k in sec["metrics"]} - {"*"})
    assert {"paper_oracle", "paper_selected", "cone_axis", "joint_cone_axis", "bp_ray"} <= set(ests)
    real = dict(estimators.ESTIMATORS)
    for est in ests:
        monkeypatch.setitem(estimators.ESTIMATORS, est, _doubled(real[est]))
        r = _nightly("--baseline", path, "--out", tmp_path)
        monkeypatch.setitem(estimators.ESTIMATORS, est, real[est])
        assert r.exit_code == 1, (est, r.output)
        flagged = _flagged(r.output)
        expect = {k for k, m in sec["metrics"].items()
                  if k.split(":")[-2] == est and k.endswith(":median") and k not in weak
                  and m["value"] and m["value"] < DOUBLE_MAX_DEG}
        assert expect, est  # every estimator family has metrics that catch a doubling
        assert expect <= flagged, (est, sorted(expect - flagged))
        assert all(k.split(":")[-2] == est for k in flagged), (est, flagged)
        if est == "cone_axis":  # the co-located cone axis at 2x
            assert "family:plane:cone_axis:median" in flagged


def _results(values: dict, fam="plane"):
    return {"suite": {"sha256": "", "seed": 0, "realisations": 1, "name": "s"},
            "created_utc": "", "provenance": {},
            "families": {fam: {"estimators": {e: {"median": v, "failure_rate": 0.0}
                                              for e, v in values.items()}}},
            "cases": []}


def test_compare_verdicts_and_one_line_per_kind():
    base = baseline_section([_results({"cone_axis": 1.0, "bp_ray": 2.0, "x": None})])
    tol = base["metrics"]["family:plane:cone_axis:median"]["tolerance"]
    assert tol == pytest.approx(POLICY["rel_floor"] * 1.0 + POLICY["abs_floor"]["deg"])

    def verdicts(values):
        return {c.metric: c.verdict for c in compare(base, _results(values))}

    v = verdicts({"cone_axis": 1.0 + 0.9 * tol, "bp_ray": 2.0, "x": None})
    assert v["family:plane:cone_axis:median"] == "ok"
    v = verdicts({"cone_axis": 2.0, "bp_ray": 0.5, "x": 1.0})
    assert v["family:plane:cone_axis:median"] == "regression"
    assert v["family:plane:bp_ray:median"] == "improved"  # better is reported, not fatal
    assert v["family:plane:x:median"] == "improved"  # never succeeded before, does now
    v = verdicts({"cone_axis": None, "bp_ray": 2.0, "x": None})
    assert v["family:plane:cone_axis:median"] == "regression"  # never succeeds any more
    ch = compare(base, _results({"cone_axis": float("nan"), "bp_ray": "2", "x": None}))
    ok, lines, counts = gate_summary(ch)
    assert not ok and counts["invalid"] == 2
    (inv,) = [ln for ln in lines if ln.startswith("INVALID")]
    assert "family:plane:cone_axis:median" in inv and "family:plane:bp_ray:median" in inv
    ok, lines, _ = gate_summary(compare(base, _results({"cone_axis": 1.0}, fam="other")))
    assert not ok and any(ln.startswith("MISSING: 6 metric(s)") for ln in lines)


def test_bad_baseline_section_is_named():
    sec = baseline_section([_results({"cone_axis": 1.0})])
    assert check_section(sec, "b.json") is None
    sec["metrics"]["family:plane:cone_axis:median"]["tolerance"] = None
    assert "family:plane:cone_axis:median (missing tolerance)" in check_section(sec, "b.json")
    with pytest.raises(ValueError, match=r"family:plane:cone_axis:median \(NaN\)"):
        baseline_section([_results({"cone_axis": float("nan")})])


def test_missing_baseline_is_a_clear_error(tmp_path):
    p = tmp_path / "b.json"
    p.write_text(json.dumps({"schema": "simtest.baseline", "schema_version": 2, "suites": {}}))
    r = _nightly("--baseline", p, "--out", tmp_path)
    assert r.exit_code == 3
    assert "no baseline for this suite" in r.output
