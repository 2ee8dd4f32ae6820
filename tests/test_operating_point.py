"""``--min-confidence``: the operating point a user sets, and the curve that shows where it lies."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from simtest.cli import app
from simtest.decisions import DEFAULT_MIN_CONFIDENCE
from simtest.evaluate.operating import precision_recall
from simtest.reconstruct import read_estimates
from simtest.reconstruct.settings import ReconSettings

REAL = Path(__file__).parent / "data" / "real"
TILE = REAL / "hyperkvasir_tile_r1c7_mucosa.png"
K_FILE = REAL / "intrinsics_assumed_f140.json"


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1), st.booleans()), max_size=40), st.integers(0, 50))
def test_raising_the_minimum_keeps_a_subset(pairs, extra_targets):
    conf = np.array([c for c, _ in pairs])
    tp = np.array([t for _, t in pairs], dtype=bool)
    targets = int(tp.sum()) + extra_targets
    rows = precision_recall(conf, tp, targets)
    kept = [r["kept"] for r in rows]
    recall = [r["recall"] for r in rows]
    assert kept == sorted(kept, reverse=True) and kept[0] == len(pairs)
    if targets:
        assert recall == sorted(recall, reverse=True)
        assert recall[0] == pytest.approx(tp.sum() / targets)
    for r in rows:
        keep = conf >= r["min_confidence"]
        want = tp[keep].sum() / keep.sum() if keep.any() else None
        assert r["precision"] == (pytest.approx(want) if want is not None else None)


def test_lengths_must_agree():
    with pytest.raises(ValueError, match="3 confidences but 2 labels"):
        precision_recall([0.1, 0.2, 0.3], [True, False], 4)


def _statuses(out):
    doc = read_estimates(out / "estimates.json")
    return [(s["status"], s["confidence"]) for s in doc["specularities"]]


def _run(tmp_path, name, image, camera, *extra):
    out = tmp_path / name
    res = CliRunner().invoke(app, ["reconstruct", str(image), "-k", str(camera), "-o", str(out), "--no-overlay",
                                   *extra])
    assert res.exit_code == 0, res.output
    return _statuses(out)


def test_the_command_line_minimum_turns_less_confident_oks_into_low_confidence(tmp_path):
    every = _run(tmp_path, "zero", TILE, K_FILE, "--min-confidence", "0")
    assert not any(s == "low_confidence" for s, _ in every)
    oks = sorted(c for s, c in every if s == "ok")
    assert len(oks) >= 3, every  # the tile holds many isolated highlights
    # a colour frame without a rig: the default minimum applies
    default = _run(tmp_path, "default", TILE, K_FILE)
    cut = float(np.median(oks))
    raised = _run(tmp_path, "high", TILE, K_FILE, "--min-confidence", f"{cut}")
    for run, floor in ((default, DEFAULT_MIN_CONFIDENCE), (raised, cut)):
        assert len(run) == len(every)
        for (s0, c0), (s1, c1) in zip(every, run):
            assert c1 == c0  # the confidence itself does not change
            if s0 == "ok":
                assert s1 == ("ok" if c0 >= floor else "low_confidence")
            else:
                assert s1 == s0
    assert any(s == "low_confidence" for s, _ in default)  # the tile has oks below it


def test_the_default_minimum_holds_only_where_the_confidence_models_the_frame(tmp_path):
    """Under a camera file's rig of separate lights, and on a grey frame, the default keeps every
    fit that passes the checks (simtest.decisions.MIN_CONFIDENCE_UNMODELLED)."""
    import json

    from PIL import Image

    every = _run(tmp_path, "zero", TILE, K_FILE, "--min-confidence", "0")
    low = {i for i, (s, c) in enumerate(every) if s == "ok" and c < DEFAULT_MIN_CONFIDENCE}
    assert low  # the default would turn these low_confidence on the colour frame alone
    # under the rig, the tile's corner that holds its least confident highlight (the light-aware
    # fits of every highlight of the whole tile take half a minute): the pinhole moved with it
    rows, cols = slice(0, 72), slice(64, 144)
    Image.open(TILE).crop((cols.start, rows.start, cols.stop, rows.stop)).save(tmp_path / "corner.png")
    cam = json.loads(K_FILE.read_text())
    cam["K"][0][2] -= cols.start
    cam["K"][1][2] -= rows.start
    cam["image_size"] = [cols.stop - cols.start, rows.stop - rows.start]
    cam["lights"] = [{"position_mm": [x, 0.0, 0.0]} for x in (-4.0, 4.0)]
    (tmp_path / "rig.json").write_text(json.dumps(cam))
    rigged = _run(tmp_path, "rig", tmp_path / "corner.png", tmp_path / "rig.json")
    assert any(s == "ok" and c < DEFAULT_MIN_CONFIDENCE for s, c in rigged), rigged  # kept: the rig models it
    assert not any(s == "low_confidence" for s, _ in rigged)
    grey = np.asarray(Image.open(TILE).convert("L"))
    Image.fromarray(np.repeat(grey[..., None], 3, axis=2)).save(tmp_path / "grey.png")
    assert not any(s == "low_confidence" for s, _ in _run(tmp_path, "grey", tmp_path / "grey.png", K_FILE))


def test_a_minimum_outside_zero_to_one_is_refused_in_one_line(tmp_path):
    res = CliRunner().invoke(app, ["reconstruct", str(TILE), "-k", str(K_FILE), "-o", str(tmp_path / "o"),
                                   "--min-confidence", "1.5"])
    assert res.exit_code == 2 and "min-confidence" in res.output
    with pytest.raises(ValueError, match="min_confidence: must be in"):
        ReconSettings(min_confidence=-0.1)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["grey", "single", "colour"]), st.sampled_from([None, 1, 2]))
def test_the_default_minimum_by_frame_kind_and_rig(seed, kind, lights):
    """The threshold applies on colour frames (a white share measured) without a rig of separate
    lights only; a one-light rig at the lens is no rig of separate lights."""
    from simtest.decisions import MIN_CONFIDENCE_UNMODELLED
    from simtest.geometry.lights import Light, LightRig
    from simtest.reconstruct.frame_verify import default_min_confidence

    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    if kind == "grey":
        img[..., 1] = img[..., 2] = img[..., 0]
    elif kind == "single":
        img = img[..., 0]
    elif np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 0], img[..., 2]):
        img[0, 0, 1] ^= 1  # a colour frame differs somewhere
    rig = None if lights is None else LightRig(tuple(Light((4.0 * k, 0.0, 0.0)) for k in range(lights)))
    modelled = kind == "colour" and (rig is None or not rig.has_separate_lights)
    assert default_min_confidence(img, rig) == (DEFAULT_MIN_CONFIDENCE if modelled else MIN_CONFIDENCE_UNMODELLED)
