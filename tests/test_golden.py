"""Results unchanged for the same settings: the current code reproduces the stored outputs of
tests/data/golden (made by ``python tests/golden.py``, see its docstring) on the pinned inputs.

Statuses, point counts, BPs, ROIs and the selected index are compared exactly; the fitted floats
(normals, residuals, eigenvalue gaps) within ``TOL.golden_abs`` (why that size: its docstring).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from simtest.tolerances import TOL

sys.path.insert(0, str(Path(__file__).resolve().parent))
import golden  # noqa: E402

CASES = sorted(golden.cases())
FITTED = {"residual_px", "paper", "cone_axis", "gap", "joint"}


def _same(got, want, where: str) -> None:
    if isinstance(want, dict):
        assert set(got) == set(want), where
        for k in want:
            if k in FITTED and want[k] is not None and got[k] is not None:
                g, w = np.asarray(got[k], float), np.asarray(want[k], float)
                assert g.shape == w.shape and np.all(np.abs(g - w) <= TOL.golden_abs), (
                    f"{where}.{k}: got {got[k]}, want {want[k]}")
            else:
                _same(got[k], want[k], f"{where}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), f"{where}: {got} != {want}"
        for i, (g, w) in enumerate(zip(got, want)):
            _same(g, w, f"{where}[{i}]")
    else:
        assert got == want, f"{where}: got {got!r}, want {want!r}"


def test_every_case_has_a_golden_file_and_inputs_are_pinned():
    stored = {p.name[: -len(".json.gz")] for p in golden.GOLDEN.glob("*.json.gz")}
    assert set(golden.cases()) == stored
    # seven bundled scenes, each pinned as a render
    assert len([c for c in CASES if c.startswith("render_")]) == 3 * 7


@pytest.mark.parametrize("name", CASES)
def test_same_results_for_the_same_settings(name):
    _same(golden.run_case(name), golden.read_golden(name), name)


def test_the_comparison_catches_a_changed_status_and_a_moved_normal():
    want = golden.read_golden("frame10_paper")
    got = [dict(r, isophotes=[dict(i) for i in r["isophotes"]]) for r in want]
    _same(got, want, "copy")
    got[3]["isophotes"][0]["cone_axis"] = [c + 1e-6 for c in want[3]["isophotes"][0]["cone_axis"]]
    with pytest.raises(AssertionError, match="cone_axis"):
        _same(got, want, "moved")
    got = [dict(r) for r in want]
    got[0]["status"] = "merged"
    with pytest.raises(AssertionError, match="status"):
        _same(got, want, "status")
