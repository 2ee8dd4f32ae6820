"""Rejected candidates get no light-aware fit by default, and those judged no specular highlight
of the tissue never (issue 39, item 4: the frame's fits ran on 567 candidates of a rendered
colonoscope frame, one of them accepted)."""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.light_fits import NOT_FITTED, with_light_aware
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import plane_case


ONE_LIGHT = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
TWO_LIGHTS = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),
                       Light((-3.0, 0.0, 0.0), 1.0, "inverse_square")))


def _candidates(rig=ONE_LIGHT):
    # one light's highlight (which statuses get fits does not depend on the image)
    img, K, _, _, _ = plane_case(20.0, 30.0, ONE_LIGHT, size=120)
    (est,) = [e for e in reconstruct(img, K, settings=ReconSettings.for_frames()) if e.status == "ok"]
    cands = [dataclasses.replace(est, status=s) for s in ("ok", "merged", "not_elliptical", "cluster",
                                                           *NOT_FITTED)]
    return img, K, rig, cands


def _marked(e, c) -> bool:
    """``e`` is the candidate ``c`` as given, marked with no fits (``light_aware`` {}: a rig off the
    camera centre is known, so its recommended normal is the BP ray's, rule 1)."""
    return (e.light_aware == {} and c.light_aware is None and e.recommended.normal_from == "bp_ray"
            and all(getattr(e, f.name) is getattr(c, f.name)
                    for f in dataclasses.fields(c) if f.name != "light_aware"))


def test_only_accepted_highlights_are_fitted_by_default():
    for rig in (ONE_LIGHT, TWO_LIGHTS):
        img, K, rig, cands = _candidates(rig)
        calls = []
        out = with_light_aware(img, cands, K, rig, on_highlight=lambda d, t: calls.append((d, t)))
        assert [bool(e.light_aware) for e in out] == [c.status == "ok" for c in cands]
        for e, c in zip(out[1:], cands[1:]):
            assert _marked(e, c)
        assert calls == [(1, 1)]


def test_rejected_candidates_fitted_on_request_but_never_those_not_specular():
    img, K, rig, cands = _candidates()
    calls = []
    out = with_light_aware(img, cands, K, rig, fit_rejected=True,
                           on_highlight=lambda d, t: calls.append((d, t)))
    fitted = {e.status for e in out if e.light_aware}
    assert fitted == {"ok", "merged", "not_elliptical", "cluster"}
    for e, c in zip(out, cands):
        if e.status in NOT_FITTED:
            assert _marked(e, c)
    assert calls[-1] == (4, 4)
    # the fits of a fitted candidate do not depend on its status
    ok, merged = out[0].light_aware["photometric_fit"], out[1].light_aware["photometric_fit"]
    assert np.array_equal(ok.normal, merged.normal)
