"""Issue 38's rendered must-hold: on the endoscope suite, ``ok`` estimates have a precision of at
least 0.95 against the rendered targets and find at least 0.9 of them (pooled).

The committed report (``reports/detection/<date>-endoscope``, ``simtest evaluate detection
endoscope``) scores the suite's 5 realisations of every setting (135 renders, about two minutes on
one core); this test scores one realisation of each (27 renders at the seeds ``validate`` gives
them), so each of the suite's sweeps (guide offset, working distance, micro-relief, film roughness,
read noise, JPEG quality) is in it.
"""

from __future__ import annotations

import pytest

from simtest.evaluate.detection import evaluate_frames, suite_frames

#: The must-hold's bars (issue 38).
OK_PRECISION_MIN = 0.95
OK_RECALL_MIN = 0.9


@pytest.mark.render
def test_ok_estimates_on_the_endoscope_suite_meet_the_rendered_bars():
    frames = suite_frames("endoscope", realisations=1)
    assert {f.name.split("@")[0] for f in frames} == {"guide_offset", "working_distance", "micro_relief",
                                                      "film_roughness", "read_noise", "jpeg_quality"}
    pooled = evaluate_frames(frames)["pooled"]
    assert pooled["targets"] >= 20  # every sweep shows targets, not a few frames' worth
    assert pooled["precision_ok"] >= OK_PRECISION_MIN, pooled
    assert pooled["recall_ok"] >= OK_RECALL_MIN, pooled
