"""A render's candidate on no target falls on ``specular`` where the render's light is mostly specular.

The render's truth holds its specular and total radiance per pixel, so a candidate that is no isolated
highlight can be told apart: on a glint of a glint field, a streak or a sheen (``specular``), or on
nothing specular (``unlabelled``: vessels, texture, noise). The scores (precision, recall) read the
targets alone and stay as they were.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from hypothesis.extra.numpy import arrays
from typer.testing import CliRunner

from simtest.cli import app
from simtest.evaluate import detection
from simtest.evaluate.detection import SPECULAR_KIND, SPECULAR_REACH_PX, Structure, score_frame
from simtest.render.truth import SPECULAR_SHARE, specular_pixels


@pytest.fixture(autouse=True)
def _figures_closed():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


radiance = arrays(np.float64, (6, 7), elements=st.floats(0.0, 10.0))


@given(radiance, radiance, arrays(bool, (6, 7)))
def test_specular_pixels_are_where_the_specular_term_holds_half_the_light(specular, diffuse, valid):
    linear = specular + diffuse
    got = specular_pixels(specular, linear, valid)
    for (r, c), v in np.ndenumerate(got):
        # (equal specular and diffuse radiance is half: the pixel counts)
        assert v == bool(valid[r, c] and specular[r, c] > 0 and specular[r, c] >= diffuse[r, c]), (r, c)
    assert SPECULAR_SHARE == 0.5  # (the statement above is the share of one half)


@hsettings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 40), st.floats(0, 30), st.floats(1, 30), st.sampled_from(["isolated", "cluster"])),
                max_size=5),
       st.lists(st.tuples(st.floats(-3, 43), st.floats(-3, 33), st.booleans()), min_size=1, max_size=12),
       arrays(bool, (31, 41)))
def test_the_mask_names_what_an_unmatched_candidate_falls_on_and_leaves_the_scores(structs, cands, mask):
    structures = [Structure(u, v, a, k) for u, v, a, k in structs]
    specs = [{"bp_px": [u, v], "status": "ok" if ok else "cluster"} for u, v, ok in cands]
    plain, rows = score_frame("f", specs, structures)
    masked, rows_m = score_frame("f", specs, structures, mask)
    assert {k: v for k, v in masked.as_dict().items() if k != "ok_on"} == \
           {k: v for k, v in plain.as_dict().items() if k != "ok_on"}
    for spec, r, rm in zip(specs, rows, rows_m):
        assert {k: v for k, v in rm.items() if k != "on"} == {k: v for k, v in r.items() if k != "on"}
        if r["on"] != "unlabelled":
            assert rm["on"] == r["on"]  # a label wins over the mask
            continue
        c, rr = (int(round(x)) for x in spec["bp_px"])
        k = SPECULAR_REACH_PX
        near = [mask[i, j] for i in range(rr - k, rr + k + 1) for j in range(c - k, c + k + 1)
                if 0 <= i < mask.shape[0] and 0 <= j < mask.shape[1]]
        assert rm["on"] == (SPECULAR_KIND if any(near) else "unlabelled")


def test_a_renders_report_names_the_candidates_on_its_glints(tmp_path, monkeypatch):
    # through the command a user types; the render is captured to check each candidate against its
    # own radiances (the physical statement, written here without the package's mask)
    renders = []
    render = detection.render_scene

    def capture(*args, **kwargs):
        renders.append(render(*args, **kwargs))
        return renders[-1]

    monkeypatch.setattr(detection, "render_scene", capture)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["evaluate", "detection", "colonoscope_pinhole", "-o", str(out), "--detection-only"])
    assert res.exit_code == 0, res.output
    (rr,) = renders
    results = json.loads((out / "results.json").read_text())
    assert results["light_aware"] is False  # (the candidates' labels are the detection's: no fits needed)
    rows = results["frames"][0]["candidates_detail"]
    specular = rr.mask & (rr.specular > 0) & (rr.specular >= 0.5 * rr.linear)
    seen = set()
    for row in rows:
        c, r = (int(round(x)) for x in row["bp_px"])
        near = specular[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].any()
        if row["target"] is None:
            assert row["on"] == (SPECULAR_KIND if near else "unlabelled"), row
        seen.add(row["on"])
    assert {SPECULAR_KIND, "unlabelled"} <= seen  # the render holds both: the test can tell them apart
    assert "`specular`" in (out / "report.md").read_text()
