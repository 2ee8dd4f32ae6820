"""Runner, metrics and reports: worker-count independence, failures kept, report files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.harness import protocols
from simtest.harness.metrics import summarise
from simtest.harness.report import build_results, evaluate_paper_claim, write_report
from simtest.harness.runner import run_suite
from simtest.harness.suite import suite_from_dict

SMALL = {
    "suite": {"name": "small", "realisations": 5, "seed": 11},
    "base": {"joint_isovalues": [0.1, 0.3, 0.5]},
    "sweep": [
        {"name": "theta", "parameter": "theta_deg", "values": [20.0, 58.0]},
        {"name": "eps", "parameter": "epsilon_px", "values": [300.0], "set": {"n": 100.0}},
        {"name": "plane", "protocol": "rendered", "scene": "plane_58deg",
         "parameter": "geometry.tilt_deg", "values": [58.0], "realisations": 2,
         "set": {"isovalue": 0.3, "joint_isovalues": [0.2, 0.3, 0.5]}},
    ],
}


def _numbers(results: dict) -> list:
    """Everything in results.json that must not depend on the run (not provenance or times)."""
    return [(c["id"], c["key"], c["samples"], c["metrics"]) for c in results["cases"]]


def test_same_seed_any_worker_count_identical_numbers():
    suite = suite_from_dict(SMALL)
    r1 = build_results(run_suite(suite, workers=1, progress=False), "w1")
    r2 = build_results(run_suite(suite, workers=2, progress=False), "w2")
    assert _numbers(r1) == _numbers(r2)  # exact equality, floats included
    # and the rendered case really ran (a render failure would hide behind equal NaNs)
    plane = next(c for c in r1["cases"] if c["sweep"] == "plane")
    assert plane["metrics"]["estimators"]["cone_axis"]["n_ok"] == 2
    assert plane["metrics"]["end_to_end"]["n"] == 2  # and its end-to-end records, equal too
    assert r1["provenance"]["mitsuba_variants"]


def test_another_seed_changes_the_numbers():
    suite = suite_from_dict({**SMALL, "sweep": SMALL["sweep"][:1]})
    a = build_results(run_suite(suite, workers=1, progress=False), "a")
    b = build_results(run_suite(suite.with_overrides(seed=12), workers=1, progress=False), "b")
    assert _numbers(a) != _numbers(b)


def test_exceptions_are_counted_not_dropped(monkeypatch):
    # A failure planted in realisation 1: the chunk's batched run raises, so the chunk is run one
    # realisation at a time, and only realisation 1 is lost.
    real_many = protocols.PaperRunner.run_many

    def flaky(self, seedseqs):
        if any(s.entropy[-1] == 1 for s in seedseqs):
            raise RuntimeError("planted failure")
        return real_many(self, seedseqs)

    monkeypatch.setattr(protocols.PaperRunner, "run_many", flaky)
    suite = suite_from_dict({**SMALL, "sweep": SMALL["sweep"][:1]})
    res = build_results(run_suite(suite, workers=1, progress=False), "x")
    m = res["cases"][0]["metrics"]["estimators"]["paper_oracle"]
    assert m["n"] == 5 and m["n_ok"] == 4
    assert m["failures"] == {"exception:RuntimeError": 1}
    assert m["failure_rate"] == pytest.approx(0.2)
    assert "planted failure" in res["cases"][0]["exceptions"][0]


def test_summarise_matches_numpy_and_counts_causes():
    rng = np.random.default_rng(0)
    e = rng.gamma(2.0, 1.0, 50)
    e[[3, 7, 9]] = np.nan
    causes = [None] * 50
    causes[3], causes[7], causes[9] = "contour_cut", "contour_cut", "not_detected"
    s = summarise(e, causes)
    ok = e[np.isfinite(e)]
    assert (s["n"], s["n_ok"]) == (50, 47)
    assert s["failures"] == {"contour_cut": 2, "not_detected": 1}
    assert s["mean"] == np.mean(ok) and s["std"] == np.std(ok) and s["max"] == np.max(ok)
    assert s["p95"] == np.percentile(ok, 95) and s["median"] == np.median(ok)
    none = summarise([np.nan], ["x"])
    assert none["mean"] is None and none["failure_rate"] == 1.0
    with pytest.raises(ValueError, match="causes"):
        summarise([1.0, 2.0], [None])


def test_report_files_self_contained(tmp_path):
    raw = {**SMALL, "sweep": [dict(SMALL["sweep"][0], paper={
        "claim": "below 7 deg", "check": ["max_mean_below", "increasing"], "value": [7.0, 0.0],
        "note": "why"})]}
    run = run_suite(suite_from_dict(raw), workers=1, progress=False)
    folder = write_report(run, tmp_path, run_id="r1")
    assert folder == tmp_path / "small" / "r1"
    res = json.loads((folder / "results.json").read_text())
    assert res["schema"] == "simtest.validation" and res["schema_version"] == 2
    prov = res["provenance"]
    for k in ("git_commit", "packages", "machine", "wall_time_s", "realisations_per_s", "workers"):
        assert k in prov
    assert res["suite"]["seed"] == 11 and "SeedSequence" in res["seeding"]
    assert res["open_parameters"]["smoothing_px"]["value"] == [2.0]
    comp = res["sweeps"][0]["comparison"]
    assert [c["check"] for c in comp] == ["max_mean_below", "increasing"]
    html = (folder / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 2  # bars and curves of the one sweep
    assert "src=\"http" not in html and "<link" not in html  # nothing external
    md = (folder / "report.md").read_text()
    assert "below 7 deg" in md and "why" in md
    assert sorted(p.name for p in (folder / "figures").iterdir()) == ["theta_bars.png",
                                                                       "theta_curves.png"]


def _cases(xs, means):
    return [{"x": x, "metrics": {"estimators": {"paper_oracle": {"mean": m, "max": m}}}}
            for x, m in zip(xs, means)]


def test_paper_checks_on_known_curves():
    xs = np.linspace(30, 120, 10)
    line = list(0.5 + 0.01 * xs)
    (slope,) = evaluate_paper_claim({"check": "slope_in_range", "value": [0.009, 0.011]},
                                    _cases(xs, line))
    assert slope["holds"] is True
    u = list((xs - 75.0) ** 2)
    (arg,) = evaluate_paper_claim({"check": "argmin_in_range", "value": [70, 80]}, _cases(xs, u))
    (arg2,) = evaluate_paper_claim({"check": "argmin_in_range", "value": [100, 120]},
                                   _cases(xs, u))
    assert arg["holds"] is True and arg2["holds"] is False
    (inc,) = evaluate_paper_claim({"check": "increasing", "value": 0.9}, _cases(xs, u))
    assert inc["holds"] is False


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.1, 10.0))
def test_the_curvature_between_two_lights_specular_points(seed, scale):
    # the partner is the nearest highlight of another light (never one of the same light); the
    # change is symmetric, 0 for equal curvatures, unchanged when every curvature is scaled, and
    # the separation is the distance between the specular points
    from simtest.harness.protocols import curvature_between_lights
    from simtest.simulate.truth import HighlightTruth

    rng = np.random.default_rng(seed)

    def hl(light, uv, k):
        return HighlightTruth(np.asarray(uv, float), rng.normal(0, 5, 3) + [0, 0, 30],
                              np.array([0.0, 0.0, -1.0]), float(max(k)), float(min(k)), True, light)

    a = hl(0, [100, 100], rng.normal(0, 0.05, 2))
    near = hl(1, [104, 101], rng.normal(0, 0.05, 2))
    far = hl(1, [160, 40], rng.normal(0, 0.05, 2))
    same_light = hl(0, [101, 100], rng.normal(0, 0.05, 2))
    assert curvature_between_lights(a, [a, same_light]) == {}
    got = curvature_between_lights(a, [a, same_light, far, near])
    back = curvature_between_lights(near, [a, near, far])
    assert got["specular_separation_mm"] == pytest.approx(np.linalg.norm(a.bp_mm - near.bp_mm), rel=1e-12)
    assert got["curvature_change_rel"] == pytest.approx(back["curvature_change_rel"], rel=1e-12)
    ka, kn = np.array([a.k1, a.k2]), np.array([near.k1, near.k2])
    want = np.linalg.norm(ka - kn) / max(np.linalg.norm(ka), np.linalg.norm(kn))
    assert got["curvature_change_rel"] == pytest.approx(want, rel=1e-12)
    assert 0.0 <= got["curvature_change_rel"] <= 2.0  # |a - b| <= |a| + |b| <= 2 max
    twin = hl(1, [103, 99], [a.k1, a.k2])
    assert curvature_between_lights(a, [a, twin])["curvature_change_rel"] == 0.0
    scaled = [HighlightTruth(x.bp_px, x.bp_mm, x.normal, scale * x.k1, scale * x.k2, True, x.light)
              for x in (a, near)]
    assert curvature_between_lights(scaled[0], scaled)["curvature_change_rel"] == pytest.approx(
        got["curvature_change_rel"], rel=1e-9)


def _same_fit(a, b) -> bool:
    """Two LightAwareEstimate equal field by field (arrays bit for bit, NaN equal to NaN)."""
    import dataclasses

    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray)
                    and np.array_equal(x, y, equal_nan=True)):
                return False
        elif x != y and not (isinstance(x, float) and isinstance(y, float) and np.isnan(x) and np.isnan(y)):
            return False
    return True


def test_the_scored_detections_fitted_alone_get_what_fitting_every_detection_gives(monkeypatch):
    # RenderedRunner fits only the detections ground-truth highlights are matched to
    # (protocols.fit_scored): on a frame of ten highlights lit 3 mm off the camera, two scored
    # (one of them matched twice) and one highlight not detected, their light-aware fits are
    # those of fitting all ten, and the unmatched ones are not fitted
    from benchmarks.inputs import synthetic_frame
    from simtest.reconstruct import reconstruct
    from simtest.reconstruct.light_fits import with_light_aware
    from simtest.geometry.lights import Light, LightRig

    frame, K, _ = synthetic_frame()
    ests = [e for e in reconstruct(frame, K) if e.ok]
    assert len(ests) == 10
    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
    every = with_light_aware(frame, ests, K, rig)
    matched = [("h0", ests[2], 0.5), ("h1", None, np.inf), ("h2", ests[7], 1.0), ("h3", ests[7], 2.0)]
    calls = []

    def spy(image, estimates, *args, **kwargs):
        calls.append(len(estimates))
        return with_light_aware(image, estimates, *args, **kwargs)

    monkeypatch.setattr(protocols, "with_light_aware", spy)
    got = protocols.fit_scored(frame, matched, K, rig)
    assert calls == [2]  # ests[2] and ests[7], once each
    assert [(h, d) for h, _, d in got] == [(h, d) for h, _, d in matched]
    assert got[1][1] is None
    for (_, e, _), k in zip([got[0], got[2], got[3]], (2, 7, 7)):
        assert set(e.light_aware) == set(every[k].light_aware) and e.light_aware
        for name in e.light_aware:
            assert _same_fit(e.light_aware[name], every[k].light_aware[name]), name


def test_the_harness_bench_rate_is_the_marginal_cost_of_a_realisation(monkeypatch):
    # each worker's first calls (imports) cost a fixed time that a short
    # run would spread over its few realisations: the rate is the slope between n and 2 n
    from types import SimpleNamespace

    from benchmarks import harness as hbench

    fixed_s, each_s = 1.5, 0.003
    seen = []

    def fake_run_suite(suite, workers, progress):
        n = suite.cases[0].realisations
        seen.append(n)
        return SimpleNamespace(cpu_s_by_protocol={"paper": fixed_s + each_s * n},
                               realisations_by_protocol={"paper": n}, wall_s=0.1 * n)

    monkeypatch.setattr(hbench, "run_suite", fake_run_suite)
    d = {"suite": {"name": "b", "realisations": 100},
         "sweep": [{"name": "s", "parameter": "theta_deg", "values": [58.0]}]}
    ms, rate, wall, n = hbench._rate(d, 2)
    assert seen == [100, 200] and n == 200 and wall == pytest.approx(20.0)
    assert ms == pytest.approx(1e3 * each_s) and rate == pytest.approx(2 / each_s)
    # a loaded machine can make the larger run cheaper: then the larger run's mean, not a negative
    each_s = -0.001
    ms, _, _, _ = hbench._rate(d, 2)
    assert ms == pytest.approx(1e3 * (fixed_s - 0.001 * 200) / 200)
