"""Issue 63, one pipeline: the harness's end-to-end figures are what `simtest render` followed by
`simtest reconstruct` give a user, for the same suite case and seed."""

from __future__ import annotations

import json
import math

import numpy as np
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry.angles import angle_between_deg
from simtest.harness.cases import realisation_seed
from simtest.harness.metrics import MATCH_PX, summarise_records
from simtest.harness.protocols import make_runner, realisation_overrides
from simtest.harness.suite import load_suite
from simtest.reconstruct.settings import ReconSettings
from simtest.render.truth import lobe_peak, smoothed_specular
from simtest.scene.spec import scene_to_toml, with_overrides

#: The harness and the command line make the same call on the same pixels, camera file and
#: settings, so statuses, BPs and normals are identical; the errors are compared to 1e-9 deg only
#: because estimates.json and highlights.json carry the normals as JSON decimals (Python's repr,
#: which round-trips float64 exactly: the bound is slack, not a spread).
ERROR_TOL_DEG = 1e-9


def _cli_records(render_dir, est_dir) -> list[dict]:
    """The end-to-end records a user would draw from the two commands' files."""
    truth = json.loads((render_dir / "highlights.json").read_text())
    found = json.loads((est_dir / "estimates.json").read_text())["specularities"]
    bps = [np.asarray(s["bp_px"], float) for s in found]
    out = []
    for h in truth["highlights"]:
        if not h.get("in_frame", True):
            continue
        d = [float(np.linalg.norm(b - np.asarray(h["bp_px"], float))) for b in bps]
        i = int(np.argmin(d)) if d else None
        s = found[i] if i is not None and d[i] <= MATCH_PX else None
        out.append({"detected": s is not None, "distance_px": d[i] if d else math.inf,
                    "status": "not_detected" if s is None else s["status"],
                    "normal_from": None if s is None else s["normal_from"],
                    "error_deg": math.nan if s is None or s["normal"] is None else
                    float(angle_between_deg(np.asarray(s["normal"], float), np.asarray(h["normal"], float)))})
    true_bps = [np.asarray(h["bp_px"], float) for h in truth["highlights"] + truth["relief_highlights"]]
    far = [(s, b) for s, b in zip(found, bps) if s["status"] == "ok" and all(
        float(np.linalg.norm(b - t)) > MATCH_PX for t in true_bps)]
    gt = np.load(render_dir / "ground_truth.npz")  # the specular-only image a user has beside the frame
    valid = gt["mask"] & (gt["field_stop"] if "field_stop" in gt.files else True)
    lobes = []
    for s, b in far:  # the error against the surface normal at the lobe's peak, light co-located
        peak = lobe_peak(smoothed_specular(gt["specular"]), valid, b)
        if peak is not None:
            n = gt["normals"][int(peak[1]), int(peak[0])].astype(float)
            lobes.append(float(angle_between_deg(np.asarray(s["normal"], float), n)))
    out[0]["frame_false_ok"] = float(len(far) - len(lobes))
    out[0]["frame_lobe_ok_deg"] = lobes
    return out


def test_the_command_line_defaults_are_the_harness_end_to_end_settings():
    # reconstruct_single's default settings are the ones `simtest reconstruct` builds from its options
    cli = ReconSettings.for_frames(isovalues=[0.7, 0.85], normalise="auto", allow_open=False,
                                   smooth_sigma_px=None, detection="local_peak", max_candidates=None)
    assert cli == ReconSettings.for_frames()


def test_the_harness_end_to_end_figures_are_what_render_then_reconstruct_give(tmp_path):
    suite = load_suite("quick")
    # the cheapest rendered case of `quick`: the bundled plane_58deg scene itself (tilt 58 deg)
    case = next(c for c in suite.cases if c.protocol == "rendered" and c.x == 58.0)
    seedseq = realisation_seed(suite.seed, case.key, 0)
    seed = realisation_overrides(case.scene_setting, seedseq)["render.seed"]
    rows = make_runner(case, suite.estimators).run(seedseq)
    harness = [r.e2e for r in rows]

    cli = CliRunner()
    r = cli.invoke(app, ["render", "plane_58deg", "--seed", str(seed), "--out", str(tmp_path / "r")])
    assert r.exit_code == 0, r.output
    r = cli.invoke(app, ["reconstruct", str(tmp_path / "r" / "frame.png"), "--intrinsics",
                         str(tmp_path / "r" / "camera.json"), "--out", str(tmp_path / "e"), "--no-overlay"])
    assert r.exit_code == 0, r.output
    user = _cli_records(tmp_path / "r", tmp_path / "e")

    assert len(user) == len(harness) >= 1
    for u, h in zip(user, harness):
        assert (u["detected"], u["status"], u["normal_from"]) == (h["detected"], h["status"], h["normal_from"])
        assert u["distance_px"] == h["distance_px"]
        assert abs(u["error_deg"] - h["error_deg"]) <= ERROR_TOL_DEG or (
            math.isnan(u["error_deg"]) and math.isnan(h["error_deg"]))
    # the figures of the case, as the report gives them, from either side
    a, b = summarise_records(harness), summarise_records([{**u, "truth": True, "depth_err_pct": math.nan}
                                                          for u in user])
    for key in ("n", "detected", "ok", "within_1deg", "within_5deg", "n_ok", "statuses", "normal_from",
                "false_ok_per_frame", "lobe_ok_per_frame"):
        assert a[key] == b[key], key
    assert abs(a["median_ok_deg"] - b["median_ok_deg"]) <= ERROR_TOL_DEG
    assert a["n_ok"] >= 1  # the case really reconstructs (equal NaNs would prove nothing)


def test_oks_on_specular_lobes_are_what_a_user_finds_beside_the_rendered_colon(tmp_path):
    # a curved scene where oks sit on lobe peaks with no exact BP: the harness's counts and errors are
    # what a user draws from the render's files and estimates.json (the colon's light is co-located, so
    # the estimate's one normal is the one scored)
    suite = load_suite("rendered")
    case = next(c for c in suite.cases if c.sweep == "colon" and c.x == 0.75)
    seedseq = realisation_seed(suite.seed, case.key, 0)
    runner = make_runner(case, suite.estimators)
    over = realisation_overrides(case.scene_setting, seedseq)
    (tmp_path / "scene.toml").write_text(scene_to_toml(with_overrides(runner.spec, over), tmp_path))
    harness = summarise_records([r.e2e for r in runner.run(seedseq)])

    cli = CliRunner()
    r = cli.invoke(app, ["render", str(tmp_path / "scene.toml"), "--seed", str(over["render.seed"]),
                         "--out", str(tmp_path / "r")])
    assert r.exit_code == 0, r.output
    r = cli.invoke(app, ["reconstruct", str(tmp_path / "r" / "frame.png"), "--intrinsics",
                         str(tmp_path / "r" / "camera.json"), "--out", str(tmp_path / "e"), "--no-overlay"])
    assert r.exit_code == 0, r.output
    user = _cli_records(tmp_path / "r", tmp_path / "e")
    user_lobes = user[0]["frame_lobe_ok_deg"]
    assert harness["lobe_ok_per_frame"] == len(user_lobes) >= 1  # the case has lobes to score
    assert harness["false_ok_per_frame"] == user[0]["frame_false_ok"]
    assert abs(harness["median_lobe_ok_deg"] - float(np.median(user_lobes))) <= ERROR_TOL_DEG


def _rec(status, err, **kw):
    return {"truth": True, "detected": status != "not_detected", "status": status,
            "normal_from": None if status == "not_detected" else kw.get("src", "photometric_fit"),
            "error_deg": err, "depth_err_pct": kw.get("depth", math.nan), **kw.get("frame", {})}


def test_the_figures_count_every_true_highlight_and_the_median_only_the_accepted():
    recs = [_rec("ok", 0.5, frame={"frame_false_ok": 2.0, "frame_lobe_ok_deg": [4.0, 1.0, 2.0]}),
            _rec("ok", 3.0, depth=1.0), _rec("cluster", 0.8, src="bp_ray"), _rec("not_detected", math.nan),
            {"truth": False, "frame_false_ok": 0.0}]  # a frame without an in-frame highlight
    e = summarise_records(recs)
    assert e["n"] == 4 and e["detected"] == 0.75 and e["ok"] == 0.5
    # what the user gets, whatever the status: the cluster's fallback within 1 deg counts
    assert e["within_1deg"] == 0.5 and e["within_5deg"] == 0.75
    assert e["n_ok"] == 2 and e["median_ok_deg"] == 1.75 and e["median_ok_depth_err_pct"] == 1.0
    assert e["false_ok_per_frame"] == 1.0  # two frames, two false ok
    # oks on lobe peaks count apart, never among the true highlights' figures above
    assert e["lobe_ok_per_frame"] == 1.5 and e["median_lobe_ok_deg"] == 2.0
    assert e["statuses"] == {"cluster": 1, "not_detected": 1, "ok": 2}
    assert e["normal_from"] == {"bp_ray": 1, "none": 1, "photometric_fit": 2}
    assert e["median_ok_bp_ray_deg"] is None  # no record carries the BP ray's error
    assert summarise_records([]) is None
    # the BP ray's median over the same accepted highlights (the cluster's 9 deg not among them)
    bp = [dict(r, bp_ray_error_deg=v) for r, v in zip(recs[:4], (2.0, 4.0, 9.0, math.nan))]
    assert summarise_records(bp)["median_ok_bp_ray_deg"] == 3.0


def test_the_report_and_the_readme_lead_with_the_end_to_end_figures(tmp_path):
    from simtest.harness.readme import section_text
    from simtest.harness.report.document import markdown_report

    from test_harness_report import synthetic_results

    doc = synthetic_results()
    fam = next(k for k, f in doc["families"].items() if f["protocol"] == "rendered")
    doc["families"][fam]["end_to_end"] = summarise_records([_rec("ok", 0.5), _rec("ok", 2.0),
                                                            _rec("merged", 7.0, src="bp_ray")])
    md = markdown_report(doc, [])
    assert md.index("## End to end") < md.index("## Summary given the highlight")
    e2e_row = next(ln for ln in md.splitlines() if ln.startswith(f"| {fam} | 3 |"))
    assert "33.3 %" in e2e_row and "66.7 %" in e2e_row and "1.25 (n 2)" in e2e_row
    run = tmp_path / "reports" / doc["suite"]["name"] / "run"
    run.mkdir(parents=True)
    (run / "results.json").write_text(json.dumps(doc))
    text = section_text(tmp_path / "reports", repo=tmp_path)
    header = next(ln for ln in text.splitlines() if ln.startswith("| report"))
    assert header.index("end to end") < header.index("given the highlight")
    row = next(ln for ln in text.splitlines() if f"| {fam} |" in ln)
    assert "| 33.3 / 66.7 % (n 3) | 1.25 (n 2) |" in row
