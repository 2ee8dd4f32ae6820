"""The newest committed detection report of a bundled scene still says what the code gives.

reports/detection/2026-11-24-<scene> went stale for a week: the scenes changed, the reports did not,
and the colonoscope's said 1 ok at precision 1.0 where its render gave 109 ok at 0.064. This test
re-runs ``simtest evaluate detection``'s scoring on the plane scene whose report a decision cites
(:data:`simtest.harness.metrics.MATCH_PX`: the two guides' highlights about 18 px apart) and checks
the figures a render on another processor's vector width keeps (its renders are other draws of the
same image, test_committed_reports.py): the targets, the ok estimates, which of them hit a target and
what the others fall on. A change that moves them regenerates the report
(``simtest evaluate detection colonoscope_plane -o reports/detection/<date>-colonoscope_plane``).
"""

from __future__ import annotations

import json

from simtest.evaluate.detection import evaluate_frames, rendered_frames
from simtest.resources import data_root

SCENE = "colonoscope_plane"


def test_the_newest_colonoscope_plane_detection_report_reproduces():
    folders = sorted((data_root() / "reports" / "detection").glob(f"*-{SCENE}"))
    assert folders, f"no committed detection report of {SCENE}"
    want = json.loads((folders[-1] / "results.json").read_text())["pooled"]
    got = evaluate_frames(rendered_frames(SCENE))["pooled"]
    keys = ("targets", "ok", "ok_tp", "targets_found_ok", "ok_on")
    assert {k: got[k] for k in keys} == {k: want[k] for k in keys}, f"regenerate {folders[-1].name}"
    assert got["ok_tp"] >= 1  # (the guides' lobes found: the report the decision cites)
