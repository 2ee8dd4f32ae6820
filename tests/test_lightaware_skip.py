"""Candidates judged no specular highlight of the tissue get no light-aware fit (issue 39, item 4:
the frame's fits ran on 567 candidates of a rendered colonoscope frame, 297 of them rejected)."""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import NOT_FITTED, with_light_aware
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import plane_case


def test_rejected_candidates_get_no_light_aware_fit():
    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
    img, K, _, _, _ = plane_case(20.0, 30.0, rig, size=120)
    (est,) = [e for e in reconstruct(img, K, settings=ReconSettings.for_frames()) if e.status == "ok"]
    cands = [dataclasses.replace(est, status=s) for s in ("ok", "merged", "not_elliptical", *NOT_FITTED)]
    calls = []
    out = with_light_aware(img, cands, K, rig, on_highlight=lambda d, t: calls.append((d, t)))
    fitted = {e.status for e in out if e.light_aware}
    assert fitted == {"ok", "merged", "not_elliptical"}
    for e, c in zip(out, cands):
        if e.status in NOT_FITTED:
            assert e is c  # returned as given
    assert calls[-1] == (3, 3)
    # the fits of a fitted candidate do not depend on its status
    ok, merged = out[0].light_aware["photometric_fit"], out[1].light_aware["photometric_fit"]
    assert np.array_equal(ok.normal, merged.normal)
