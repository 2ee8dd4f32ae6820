"""Results unchanged for the same settings: the current code reproduces the stored outputs of
tests/data/golden (made by ``python tests/golden.py``, see its docstring) on the pinned inputs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import golden  # noqa: E402

#: The banner cases take tens of seconds with the code that wrote them; they join the test once
#: the fast path makes them cheap.
SLOW = {"banner_paper", "banner_local"}
CASES = sorted(n for n in golden.cases() if n not in SLOW)


def test_every_case_has_a_golden_file_and_inputs_are_pinned():
    stored = {p.name[: -len(".json.gz")] for p in golden.GOLDEN.glob("*.json.gz")}
    assert set(golden.cases()) == stored
    # seven bundled scenes, each pinned as a render
    assert len([c for c in CASES if c.startswith("render_")]) == 2 * 7


@pytest.mark.parametrize("name", CASES)
def test_same_results_for_the_same_settings(name):
    want = golden.read_golden(name)
    got = json.loads(json.dumps(golden.run_case(name)))  # same float repr round trip
    assert len(got) == len(want)
    for k, (g, w) in enumerate(zip(got, want)):
        assert g == w, f"{name}: estimate {k} differs\n got  {g}\n want {w}"
