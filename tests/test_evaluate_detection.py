"""Scoring detection against labelled structures: exact counts on constructed frames."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from PIL import Image
from typer.testing import CliRunner

from simtest.cli import app
from simtest.evaluate.detection import (TOLERANCE_PX, Structure, labelled_real_frames,
                                        match_candidates, pooled, score_frame)
from simtest.render.truth import HighlightTarget


@pytest.fixture(autouse=True)
def _figures_closed():
    """``simtest evaluate detection`` writes its three figures and leaves them open in pyplot
    (nothing in its own process); closed after each test here, so that an xdist worker that runs
    many modules does not gather them (matplotlib warns past 20 open figures)."""
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


def _spec(u, v, status="ok"):
    return {"bp_px": [u, v], "status": status}


def test_counts_on_a_constructed_frame():
    labels = [Structure(10, 10, 12, "isolated"), Structure(50, 50, 12, "isolated"),
              Structure(90, 90, 40, "cluster"), Structure(30, 70, 12, "isolated")]
    cands = [_spec(10.5, 10.2),                     # on target 0: hit
             _spec(11.0, 9.5),                      # on target 0 again: duplicate
             _spec(50, 51, "not_elliptical"),       # on target 1, not ok: candidate hit only
             _spec(90, 91),                         # on the cluster: ok false positive
             _spec(150, 150)]                       # on nothing: unlabelled
    sc, rows = score_frame("f", cands, labels)
    d = sc.as_dict()
    assert (d["targets"], d["candidates"], d["candidates_tp"], d["ok"], d["ok_tp"]) == (3, 5, 2, 4, 1)
    assert (d["targets_found"], d["targets_found_ok"]) == (2, 1)
    assert d["precision_candidates"] == pytest.approx(2 / 5) and d["recall_candidates"] == pytest.approx(2 / 3)
    assert d["precision_ok"] == pytest.approx(1 / 4) and d["recall_ok"] == pytest.approx(1 / 3)
    assert d["f1_ok"] == pytest.approx(2 * (1 / 4) * (1 / 3) / (1 / 4 + 1 / 3))
    assert d["ok_on"] == {"cluster": 1, "duplicate": 1, "isolated": 1, "unlabelled": 1}
    assert [r["on"] for r in rows] == ["isolated", "duplicate", "isolated", "cluster", "unlabelled"]


def test_no_denominator_gives_no_ratio():
    d = score_frame("empty", [], [])[0].as_dict()
    assert d["precision_ok"] is None and d["recall_ok"] is None and d["f1_ok"] is None


@hsettings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 200), st.floats(0, 200), st.floats(1, 200)), max_size=8),
       st.lists(st.tuples(st.floats(0, 200), st.floats(0, 200)), max_size=12))
def test_a_match_is_always_within_reach_and_the_nearest(structs, bps):
    labels = [Structure(u, v, a, "isolated") for u, v, a in structs]
    hit = match_candidates(np.array(bps).reshape(-1, 2), labels)
    for (u, v), j in zip(bps, hit):
        d = [np.hypot(u - s.u, v - s.v) for s in labels]
        reach = [d_ <= s.reach_px for d_, s in zip(d, labels)]
        if j is None:
            assert not any(reach)
        else:
            assert reach[j] and d[j] == min(x for x, r in zip(d, reach) if r)
    # pooled ratios are ratios of summed counts; every target is found at most once
    sc, _ = score_frame("p", [_spec(u, v) for u, v in bps], labels)
    assert sc.targets_found <= sc.targets and sc.ok_tp <= sc.ok
    both = pooled([sc, sc]).as_dict()
    assert both["ok"] == 2 * sc.ok and both["precision_ok"] == sc.as_dict()["precision_ok"]


def test_reach_is_the_structures_radius_plus_the_slack():
    s = Structure(0, 0, np.pi * 9, "isolated")
    assert s.reach_px == pytest.approx(3 + TOLERANCE_PX)


@hsettings(max_examples=60, deadline=None)
@given(st.floats(5.0, 40.0), st.floats(0.0, 1.0), st.floats(-30.0, 30.0), st.floats(1.0, 200.0))
def test_a_rendered_target_of_two_guides_is_reached_from_either_lobe(sep, along, off, area):
    # two lights' BPs (the guides' lobes that run together) and the peak at the second: a
    # candidate's distance is to the segment between them, so a candidate on the first lobe,
    # beyond the disc around the peak, falls on the target; the plain centroid rule is the
    # special case of one BP
    a, b = np.array([100.0, 50.0]), np.array([100.0 + sep, 50.0])
    target = HighlightTarget(np.array([a, b]), (0, 1), (), b, int(area))
    s = Structure(float(b[0]), float(b[1]), area, "isolated", target)
    q = a + along * (b - a) + np.array([0.0, off])
    assert s.distance_px(q) == pytest.approx(abs(off), abs=1e-9)
    (hit,) = match_candidates(q[None], [s])
    assert (hit == 0) == (abs(off) <= s.reach_px)
    one = Structure(float(b[0]), float(b[1]), area, "isolated",
                    HighlightTarget(b[None], (1,), (), b, int(area)))
    assert one.distance_px(q) == pytest.approx(np.hypot(*(q - b)))


@pytest.mark.parametrize("lights", [1, 2, 3])
def test_a_target_of_k_lights_takes_k_ok_estimates_and_is_found_once(lights):
    # a rig's pairing gives each guide's lobe its own estimate: on a target gathering k lights'
    # highlights, the first k ok estimates are true highlights, a (k+1)-th a duplicate; recall
    # counts the target once
    bps = np.array([[100.0 + 6 * i, 50.0] for i in range(lights)])
    s = Structure(100.0, 50.0, 200.0, "isolated", HighlightTarget(bps, tuple(range(lights)), (), bps[0], 200))
    ests = [_spec(u, v) for u, v in bps] + [_spec(101.0, 50.0)]
    sc, rows = score_frame("rig", ests, [s])
    assert (sc.ok, sc.ok_tp, sc.targets_found_ok, sc.candidates_tp) == (lights + 1, lights, 1, lights)
    assert [r["on"] for r in rows] == ["isolated"] * lights + ["duplicate"]
    assert sc.ok_on == Counter({"isolated": lights, "duplicate": 1})


def _labelled_set(tmp_path):
    img = np.full((40, 80, 3), 60, np.uint8)
    yy, xx = np.mgrid[0:40, 0:40]
    for c0, (u, v) in ((0, (12, 20)), (40, (25, 15))):
        blob = np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 1.8 ** 2))
        img[:, c0:c0 + 40] = np.maximum(img[:, c0:c0 + 40], (60 + 190 * blob)[..., None]).astype(np.uint8)
    Image.fromarray(img).save(tmp_path / "frames.png")
    doc = {"header": {"image": "frames.png", "tile_px": 40},
           "tiles": {"r0c0": [{"u": 12, "v": 20, "area_px": 12, "kind": "isolated"}],
                     "r0c1": [{"u": 25, "v": 15, "area_px": 12, "kind": "overlay"}]}}
    (tmp_path / "labels.json").write_text(json.dumps(doc))
    return tmp_path / "labels.json"


def test_a_labelled_set_is_read_tile_by_tile(tmp_path):
    frames = labelled_real_frames(_labelled_set(tmp_path))
    assert [f.name for f in frames] == ["r0c0", "r0c1"]
    assert frames[1].image.shape == (40, 40, 3) and frames[1].structures[0].kind == "overlay"
    bad = json.loads((tmp_path / "labels.json").read_text())
    bad["tiles"]["r0c0"][0]["kind"] = "glint"
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"tiles.r0c0\[0\].kind"):
        labelled_real_frames(tmp_path / "bad.json")


def test_the_command_writes_its_five_files(tmp_path):
    res = CliRunner().invoke(app, ["evaluate", "detection", str(_labelled_set(tmp_path)),
                                   "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "detection.png", "precision_recall.png", "reliability.png", "report.md", "results.json"]
    r = json.loads((tmp_path / "out" / "results.json").read_text())
    assert r["pooled"]["targets"] == 1 and len(r["frames"]) == 2
    # the curve's default operating point (min confidence 0) is the run's own ok figures
    first = r["precision_recall"][0]
    assert first["min_confidence"] == 0.0 and first["kept"] == r["pooled"]["ok"]
    assert first["recall"] == r["pooled"]["recall_ok"]
    assert sum(r["missed_by"].values()) == r["pooled"]["targets"] - r["pooled"]["targets_found_ok"]
    assert "The targets no ok estimate found (pooled)" in (tmp_path / "out" / "report.md").read_text()
    res = CliRunner().invoke(app, ["evaluate", "detection", str(tmp_path / "nothere.json"),
                                   "-o", str(tmp_path / "o2")])
    assert res.exit_code == 2 and len(res.output.strip().splitlines()) == 1


def test_a_missed_target_is_counted_by_what_the_first_candidate_on_it_got(tmp_path):
    from simtest.evaluate.detection import evaluate_frames

    path = _labelled_set(tmp_path)
    doc = json.loads(path.read_text())
    doc["tiles"]["r0c1"].append({"u": 5, "v": 35, "area_px": 6, "kind": "isolated"})  # flat background there
    path.write_text(json.dumps(doc))
    res = evaluate_frames(labelled_real_frames(path))
    f = res["frames"][1]
    assert [5.0, 35.0] in f["missed_targets_ok"] and f["missed_by"] == {"no candidate": 1}
    for f in res["frames"]:  # every target is found by an ok estimate or missed, never both
        found = {r["target"] for r in f["candidates_detail"] if r["tp_ok"]}
        assert len(f["missed_targets_ok"]) == f["targets"] - len(found) == sum(f["missed_by"].values())
    assert sum(res["missed_by"].values()) == res["pooled"]["targets"] - res["pooled"]["targets_found_ok"]


def test_the_committed_labelled_set_loads_with_its_stated_counts():
    from collections import Counter

    from simtest.resources import data_root

    path = data_root() / "tests" / "data" / "real" / "structures_labelled.json"
    frames = labelled_real_frames(path)
    head = json.loads(path.read_text())["header"]
    assert len(frames) == head["frames"] >= 10
    kinds = Counter(s.kind for f in frames for s in f.structures)
    assert dict(kinds) == {k: v for k, v in head["counts"].items() if v}
    assert sum(kinds.values()) == head["structures"] >= 300
    for f in frames:
        assert f.image.shape[:2] == (head["tile_px"], head["tile_px"])
        assert all(0 <= s.u < head["tile_px"] and 0 <= s.v < head["tile_px"] for s in f.structures)
    # the label map holds each structure's pixels: as many as its area, centred on its centroid (the
    # JSON rounds to 0.01 px), its peak among them
    rows = [r for tile in json.loads(path.read_text())["tiles"].values() for r in tile]
    pix = [np.argwhere(f.label_px == k + 1) for f in frames for k in range(len(f.structures))]
    assert len(pix) == len(rows)
    for r, rc in zip(rows, pix):
        assert len(rc) == r["area_px"]
        assert abs(rc[:, 1].mean() - r["u"]) <= 0.0051 and abs(rc[:, 0].mean() - r["v"]) <= 0.0051
        assert [r["v_peak"], r["u_peak"]] in rc.tolist()


def _plateau(peak_at_left: bool):
    """A 3 x 21 px clipped plateau (rows 9-11, columns 10-30) labelled with its peak at one end."""
    label_px = np.zeros((40, 60), np.int32)
    label_px[9:12, 10:31] = 1
    s = Structure(10.0 if peak_at_left else 30.0, 10.0, 63.0, "isolated")
    return s, label_px


@hsettings(max_examples=40, deadline=None)
@given(st.integers(10, 30), st.integers(9, 11), st.booleans())
def test_a_bp_anywhere_on_a_labelled_plateau_falls_on_it(col, row, left):
    # a clipped plateau has no one peak: its BP may sit at any of its pixels, far beyond the disc
    # of its area about the labelled peak; the label map places it there, distances alone do not
    s, label_px = _plateau(left)
    bp = np.array([[col + 0.3, row - 0.4]])
    assert match_candidates(bp, [s], label_px) == [0]
    beyond = np.hypot(bp[0, 0] - s.u, bp[0, 1] - s.v) > s.reach_px
    assert match_candidates(bp, [s]) == [None if beyond else 0]


@hsettings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 59), st.floats(0, 39), st.floats(1, 200)), max_size=6),
       st.lists(st.tuples(st.floats(-5, 65), st.floats(-5, 45)), max_size=10))
def test_off_every_labelled_pixel_the_distance_rule_decides(structs, bps):
    labels = [Structure(u, v, a, "isolated") for u, v, a in structs]
    label_px = np.zeros((40, 60), np.int32)
    label_px[:3, :3] = 1 if labels else 0  # one structure's pixels in a corner
    off = [(u, v) for u, v in bps if not (round(u) < 3 and round(v) < 3 and labels)]
    q = np.array(off, np.float64).reshape(-1, 2)
    assert match_candidates(q, labels, label_px) == match_candidates(q, labels)
    assert match_candidates(q, labels, np.zeros_like(label_px)) == match_candidates(q, labels)


def test_a_labelled_set_with_a_label_map_maps_its_indexes_tile_by_tile(tmp_path):
    path = _labelled_set(tmp_path)
    doc = json.loads(path.read_text())
    labels = np.zeros((40, 80), np.uint16)
    labels[18:23, 10:15], labels[13:18, 63:68] = 7, 3  # the rows' own indexes, not their order
    Image.fromarray(labels).save(tmp_path / "map.png")
    doc["header"]["labelmap"] = "map.png"
    doc["tiles"]["r0c0"][0]["index"], doc["tiles"]["r0c1"][0]["index"] = 7, 3
    path.write_text(json.dumps(doc))
    frames = labelled_real_frames(path)
    assert [int(f.label_px.max()) for f in frames] == [1, 1]
    assert frames[0].label_px[20, 12] == 1 and frames[1].label_px[15, 25] == 1 and frames[1].label_px[15, 5] == 0
    Image.fromarray(labels[:, :40]).save(tmp_path / "map.png")
    with pytest.raises(ValueError, match=r"key 'labelmap'.*shape \(40, 40\)"):
        labelled_real_frames(path)
    Image.fromarray(labels).save(tmp_path / "map.png")
    del doc["tiles"]["r0c1"][0]["index"]
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"tiles.r0c1: .*'index'"):
        labelled_real_frames(path)


def test_labeller_agreement_scores_each_pass_against_the_other(tmp_path):
    from simtest.evaluate.detection import labeller_agreement

    def s(p1, p2, kind):
        return {"u": 1, "v": 1, "area_px": 4, "kind": kind, "pass1": p1, "pass2": p2}
    doc = {"header": {"image": "x.png"}, "tiles": {"r0c0": [
        s("isolated", "isolated", "isolated"), s("isolated", "cluster", "isolated"),
        s("cluster", "isolated", "cluster"), s("texture", "texture", "texture")]}}
    (tmp_path / "l.json").write_text(json.dumps(doc))
    a = labeller_agreement(tmp_path / "l.json")
    # pass 2 says isolated twice, once where pass 1 does; pass 1 says it twice
    assert a["pass2_vs_pass1"] == {"precision": 0.5, "recall": 0.5, "labelled": 2, "truth": 2}
    assert a["pass1_vs_resolved"]["precision"] == 1.0 and a["pass1_vs_resolved"]["recall"] == 1.0
    for item in doc["tiles"]["r0c0"]:
        del item["pass2"]
    (tmp_path / "l.json").write_text(json.dumps(doc))
    assert labeller_agreement(tmp_path / "l.json") is None


SUITE = """
[suite]
name = "tiny"
description = "two renders of the flat mucosa"
protocol = "rendered"
scene = "colonoscope_plane"
realisations = 1
seed = 3
estimators = ["bp_ray"]

[[sweep]]
name = "distance"
parameter = "geometry.distance_mm"
values = [20.0, 30.0]
"""


def test_a_suite_is_scored_render_by_render_with_the_seeds_validate_gives(tmp_path):
    from simtest.constants import MAX_SEED
    from simtest.evaluate.detection import is_suite, suite_frames
    from simtest.harness.suite import load_suite, realisation_seed

    path = tmp_path / "tiny.toml"
    path.write_text(SUITE)
    assert is_suite(str(path)) and is_suite("endoscope") and not is_suite("colonoscope")
    seen = []
    frames = suite_frames(str(path), progress=lambda d, n: seen.append((d, n)))
    assert [f.name for f in frames] == ["distance@20#0", "distance@30#0"]
    assert seen == [(1, 2), (2, 2)]
    # the render of a case is the one validate makes: same scene change, same seed
    case = load_suite(path).cases[0]
    seed = int(realisation_seed(3, case.key, 0).generate_state(1, np.uint32)[0]) & MAX_SEED
    from simtest.render.render import render_scene
    from simtest.scene import load_scene, with_overrides
    spec = with_overrides(load_scene("colonoscope_plane"), {"geometry.distance_mm": 20.0, "render.seed": seed})
    np.testing.assert_array_equal(frames[0].image, render_scene(spec, seed=seed).frame)
    res = CliRunner().invoke(app, ["evaluate", "detection", str(path), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    r = json.loads((tmp_path / "out" / "results.json").read_text())
    assert r["light_aware"] is True  # the command's default: what `simtest reconstruct -k camera.json` gives
    (g,) = r["groups"]
    assert g["name"] == "distance" and g["frames"] == 2
    assert g["targets"] == sum(f["targets"] for f in r["frames"])
    assert "| distance (2 frames) |" in (tmp_path / "out" / "report.md").read_text()


def test_a_paper_suite_is_refused_in_one_line(tmp_path):
    res = CliRunner().invoke(app, ["evaluate", "detection", "quick", "-o", str(tmp_path / "out")])
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1 and "rendered" in res.output


def test_an_image_as_the_source_is_refused_in_one_line_naming_what_is_taken(tmp_path):
    # a frame given where labels, a scene or a suite belong was parsed as TOML ("<toml>: Expected '='")
    frame = tmp_path / "frame.png"
    frame.write_bytes(b"not a png")
    res = CliRunner().invoke(app, ["evaluate", "detection", str(frame), "-o", str(tmp_path / "out")])
    assert res.exit_code == 2 and res.output.strip().splitlines() == [
        f"error: {frame}: not a labelled set (.json), a scene or a suite (.toml or a bundled name)"]
    assert not (tmp_path / "out").exists()


def test_a_missing_labelled_set_is_one_plain_line(tmp_path):
    # it read "not a labelled set (FileNotFoundError: [Errno 2] No such file or directory: '...')"
    missing = tmp_path / "labels.json"
    res = CliRunner().invoke(app, ["evaluate", "detection", str(missing), "-o", str(tmp_path / "out")])
    assert res.exit_code == 2 and res.output.strip().splitlines() == [
        f"error: {missing}: not a labelled set (No such file or directory)"]


def test_the_cross_validation_takes_the_estimates_the_scoring_made():
    """`evaluate detection` on a labelled set reconstructs each frame once for its scores and hands
    those estimates to the confidence's cross-validation (evaluate_frames' keep): the same report
    as the cross-validation reconstructing the frames itself, and the estimates kept are the
    frames' own, in order."""
    from simtest.evaluate.detection import cross_validated_report, evaluate_frames
    from simtest.reconstruct import reconstruct
    from simtest.resources import data_root

    frames = labelled_real_frames(data_root() / "tests" / "data" / "real" / "structures_labelled.json")[:6]
    kept: list = []
    evaluate_frames(frames, keep=kept)
    assert len(kept) == len(frames)
    assert [e.bp_px.tolist() for e in kept[2]] == [e.bp_px.tolist() for e in reconstruct(frames[2].image,
                                                                                          frames[2].camera)]
    assert cross_validated_report(frames, verified=kept) == cross_validated_report(frames)


def test_recall_over_the_confidence_counts_a_k_light_target_once():
    # two ok estimates on one two-light target and one on a one-light target: precision counts
    # all three, recall the two targets
    from simtest.evaluate.operating import precision_recall
    rows = precision_recall([0.9, 0.8, 0.2], [True, True, True], 2, thresholds=(0.0, 0.5),
                            target_ids=[("f", 0), ("f", 0), ("f", 1)])
    assert [(r["kept"], r["precision"], r["recall"]) for r in rows] == [(3, 1.0, 1.0), (2, 1.0, 0.5)]


@hsettings(max_examples=10, deadline=None)
@given(st.floats(0.5, 60.0), st.floats(0.0, 2 * np.pi))
def test_a_renders_ok_normals_are_scored_against_the_true_normal_at_their_bp(theta, phi):
    # the true normal at each ok estimate's BP pixel is its own recommended normal turned by theta (about an axis
    # across it at angle phi): each error is theta to round-off, counted under what it fell on; a BP off the
    # surface (NaN) is left out; real frames (no true normals) get no section
    import dataclasses
    import tempfile
    from pathlib import Path

    from simtest.evaluate.detection import evaluate_frames
    from simtest.reconstruct.io import estimate_to_dict
    from simtest.reconstruct.pipeline import reconstruct
    from simtest.reconstruct.settings import ReconSettings

    with tempfile.TemporaryDirectory() as tmp:
        frames = labelled_real_frames(_labelled_set(Path(tmp)))
    assert evaluate_frames(frames)["normal_error_deg"] == {}
    posed, oks = [], 0
    for fr in frames:
        normals = np.full(fr.image.shape[:2] + (3,), np.nan)
        for s in (estimate_to_dict(e) for e in reconstruct(fr.image, fr.camera, settings=ReconSettings.for_frames())):
            if s["status"] != "ok":
                continue
            n = np.asarray(s["normal"], dtype=np.float64)
            a = np.cross(n, [np.cos(phi), np.sin(phi), 0.0])
            a /= np.linalg.norm(a)
            t = np.radians(theta)  # Rodrigues' rotation of n about a (a is across n)
            u, v = (int(round(x)) for x in s["bp_px"])
            normals[v, u] = n * np.cos(t) + np.cross(a, n) * np.sin(t)
            oks += 1
        posed.append(dataclasses.replace(fr, normals_px=normals))
    res = evaluate_frames(posed)
    errors = [r["error_deg"] for f in res["frames"] for r in f["candidates_detail"] if r.get("error_deg") is not None]
    assert oks >= 1 and len(errors) == oks
    np.testing.assert_allclose(errors, theta, atol=1e-6)  # (atan2 of unit vectors: round-off near 1e-12 deg)
    assert sum(e["n"] for e in res["normal_error_deg"].values()) == oks
    from simtest.evaluate.cli import _detection_markdown  # (the report's table: a row per what they fell on)

    md = _detection_markdown(res | {"source": "posed"})
    for on, e in res["normal_error_deg"].items():
        assert e["median"] == pytest.approx(theta, abs=1e-6) and f"| {on} | {e['n']} | {e['median']:.2f} |" in md


@hsettings(max_examples=4, deadline=None)
@given(rising=st.booleans(), scale=st.floats(0.1, 20.0))
def test_the_confidence_is_ranked_against_the_normals_error(rising, scale):
    # the true normal at each ok BP is its own normal turned by an angle that rises (or falls) strictly with the
    # estimate's confidence: Spearman's rho is +1 (or -1) exactly, whatever the scale, and the report says it
    import dataclasses
    import tempfile
    from pathlib import Path

    from simtest.evaluate.cli import _detection_markdown
    from simtest.evaluate.detection import evaluate_frames
    from simtest.reconstruct.io import estimate_to_dict
    from simtest.reconstruct.pipeline import reconstruct
    from simtest.reconstruct.settings import ReconSettings

    with tempfile.TemporaryDirectory() as tmp:  # four tiles, a glint each, 80 to 190 levels over the tissue
        rng = np.random.default_rng(7)
        img = np.clip(60 + rng.normal(0.0, 2.0, (40, 160, 3)), 0, 255)  # (the noise the significance reads)
        yy, xx = np.mgrid[0:40, 0:40]
        for k, top in enumerate((80, 120, 160, 190)):
            blob = top * np.exp(-((xx - 20) ** 2 + (yy - 20) ** 2) / (2 * 1.8 ** 2))
            img[:, 40 * k:40 * k + 40] += blob[..., None]
        Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)).save(Path(tmp) / "frames.png")
        (Path(tmp) / "labels.json").write_text(json.dumps({"header": {"image": "frames.png", "tile_px": 40}, "tiles": {
            f"r0c{k}": [{"u": 20, "v": 20, "area_px": 12, "kind": "isolated"}] for k in range(4)}}))
        frames = labelled_real_frames(Path(tmp) / "labels.json")
    assert evaluate_frames(frames)["confidence_vs_error"] is None  # (no true normals: nothing to rank)
    posed, confs = [], []
    for fr in frames:
        normals = np.full(fr.image.shape[:2] + (3,), np.nan)
        for s in (estimate_to_dict(e) for e in reconstruct(fr.image, fr.camera, settings=ReconSettings.for_frames())):
            if s["status"] == "ok":
                n = np.asarray(s["normal"], dtype=np.float64)
                a = np.cross(n, [1.0, 0.0, 0.0])
                a /= np.linalg.norm(a)
                t = np.radians(scale * (s["confidence"] if rising else 1.0 - s["confidence"]))
                u, v = (int(round(x)) for x in s["bp_px"])
                normals[v, u] = n * np.cos(t) + np.cross(a, n) * np.sin(t)
                confs.append(s["confidence"])
        posed.append(dataclasses.replace(fr, normals_px=normals))
    assert len(set(confs)) >= 3  # (the premise: confidences to rank)
    res = evaluate_frames(posed)
    got = res["confidence_vs_error"]
    assert got["n"] == len(confs) and got["rho"] == pytest.approx(1.0 if rising else -1.0, abs=1e-12)
    assert f"Spearman's rho {got['rho']:+.2f} (n {got['n']}," in _detection_markdown(res | {"source": "posed"})


def test_light_aware_scoring_scores_what_the_command_gives(tmp_path):
    # a sensor-like plane under the two guides (test_rig_pairs' frame), written with its camera file: with
    # light_aware, the evaluation's statuses and normals are the command's, bit for bit, and each ok normal's
    # error is its angle to the plane's normal; without, the fits do not run (no light-aware normal scored)
    from simtest.evaluate.detection import LabelledFrame, evaluate_frames
    from simtest.geometry import angle_between_deg
    from simtest.geometry.camera_file import load_camera
    from test_rig_pairs import _reconstruct, _write, sensor_plane

    img, K, n, truth = sensor_plane(20.0, 20.0, 1)
    _write(tmp_path, img, K)
    specs = _reconstruct(tmp_path)
    cam = load_camera(tmp_path / "camera.json")
    frame = LabelledFrame("plane", img, cam.model, [Structure(float(u), float(v), 12.0, "isolated") for u, v in truth],
                          cam.lights, normals_px=np.broadcast_to(n, img.shape[:2] + (3,)).astype(np.float16),
                          response=cam.response)
    rows = evaluate_frames([frame], light_aware=True)["frames"][0]["candidates_detail"]
    assert [r["status"] for r in rows] == [s["status"] for s in specs]
    # the fits in two worker processes (the command's default on this machine): the same rows, every number
    assert evaluate_frames([frame], light_aware=True, workers=2)["frames"][0]["candidates_detail"] == rows
    assert any(s["status"] == "ok" and s["normal_from"] != "bp_ray" for s in specs)  # (the premise: fits ran)
    n16 = n.astype(np.float16).astype(np.float64)
    for r, s in zip(rows, specs):
        if s["status"] == "ok":  # (1e-6 deg: the same angle of the same two vectors)
            assert r["error_deg"] == pytest.approx(angle_between_deg(np.asarray(s["normal"]), n16), abs=1e-6)
    plain = evaluate_frames([frame])  # (the detection alone: other normals than the command's light-aware ones)
    errors = [[r["error_deg"] for r in res if r["status"] == "ok"] for res in (rows, plain["frames"][0][
        "candidates_detail"])]
    assert plain["light_aware"] is False and errors[0] != errors[1]


def test_evaluate_frames_reports_each_frame_done(tmp_path):
    # a long evaluation (a suite with --light-aware) shows its progress frame by frame
    from simtest.evaluate.detection import evaluate_frames

    calls = []
    evaluate_frames(labelled_real_frames(_labelled_set(tmp_path)), progress=lambda *a: calls.append(a))
    assert calls == [(1, 2), (2, 2)]
