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


def test_the_command_line_minimum_turns_less_confident_oks_into_low_confidence(tmp_path):
    runner = CliRunner()
    base = tmp_path / "default"
    res = runner.invoke(app, ["reconstruct", str(TILE), "-k", str(K_FILE), "-o", str(base), "--no-overlay"])
    assert res.exit_code == 0, res.output
    default = _statuses(base)
    oks = sorted(c for s, c in default if s == "ok")
    assert len(oks) >= 3, default  # the tile holds many isolated highlights
    assert DEFAULT_MIN_CONFIDENCE == 0.0 and not any(s == "low_confidence" for s, _ in default)
    cut = float(np.median(oks))
    high = tmp_path / "high"
    res = runner.invoke(app, ["reconstruct", str(TILE), "-k", str(K_FILE), "-o", str(high), "--no-overlay",
                              "--min-confidence", f"{cut}"])
    assert res.exit_code == 0, res.output
    raised = _statuses(high)
    assert len(raised) == len(default)
    for (s0, c0), (s1, c1) in zip(default, raised):
        assert c1 == c0  # the confidence itself does not change
        if s0 == "ok":
            assert s1 == ("ok" if c0 >= cut else "low_confidence")
        else:
            assert s1 == s0


def test_a_minimum_outside_zero_to_one_is_refused_in_one_line(tmp_path):
    res = CliRunner().invoke(app, ["reconstruct", str(TILE), "-k", str(K_FILE), "-o", str(tmp_path / "o"),
                                   "--min-confidence", "1.5"])
    assert res.exit_code == 2 and "min-confidence" in res.output
    with pytest.raises(ValueError, match="min_confidence must be in"):
        ReconSettings(min_confidence=-0.1)
