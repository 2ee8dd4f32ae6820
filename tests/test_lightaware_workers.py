"""A frame's light-aware fits shared among worker processes give what one process gives, bit for
bit (``with_light_aware(workers=...)``, ``simtest reconstruct -j`` on a single image): each
highlight's fits read the image in its own ROI only, and every process runs BLAS on one thread."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import SensorResponse
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.light_fits import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import plane_case

TWO_GUIDES = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),
                       Light((-3.0, 0.0, 0.0), 1.0, "inverse_square")))


def _frame():
    """Four copies of a plane's highlight, each on its tile edged out to 150 px (so that no fit's ROI holds
    another: a glint field, not fitted), with a little seeded read noise (so that their fits differ), as an
    8-bit RGB frame: four accepted highlights to share."""
    img, K, _, _, _ = plane_case(20.0, 30.0, LightRig(TWO_GUIDES.lights[:1]), size=70)
    tile = np.pad(img / img.max() * 230.0, 40, mode="edge")
    frame = np.concatenate([np.concatenate([tile, tile], axis=1)] * 2, axis=0)
    frame = frame + np.random.default_rng(5).normal(0.0, 2.0, frame.shape)
    gray = np.clip(np.rint(frame), 0, 255).astype(np.uint8)
    return np.repeat(gray[..., None], 3, axis=2), K


def _light_aware_bytes(ests) -> list[bytes]:
    return [pickle.dumps({k: dataclasses.asdict(v) for k, v in sorted(e.light_aware.items())})
            if e.light_aware else b"" for e in ests]


def test_workers_give_the_fits_of_one_process_bit_for_bit():
    rgb, K = _frame()
    ests = reconstruct(rgb, K, settings=ReconSettings.for_frames())
    assert sum(e.ok for e in ests) >= 3, [e.status for e in ests]
    response = SensorResponse("srgb", clip=255.0)
    calls = []
    one = with_light_aware(rgb, ests, K, TWO_GUIDES, response=response)
    two = with_light_aware(rgb, ests, K, TWO_GUIDES, response=response, workers=2,
                           on_highlight=lambda done, total: calls.append((done, total)))
    assert [e.status for e in two] == [e.status for e in ests]  # in the order given
    assert _light_aware_bytes(two) == _light_aware_bytes(one)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a.recommended.normal, b.recommended.normal)
    n_fitted = sum(bool(e.light_aware) for e in one)
    assert calls == [(i, n_fitted) for i in range(1, n_fitted + 1)]
    for e, c in zip(two, ests):
        if not e.light_aware:
            assert e is c  # a candidate not fitted is returned as given


def test_workers_must_be_at_least_one():
    rgb, K = _frame()
    with pytest.raises(ValueError, match="workers must be at least 1, got 0"):
        with_light_aware(rgb, [], K, TWO_GUIDES, workers=0)


def test_fused_lobes_are_fitted_in_the_workers_bit_for_bit():
    # The rejected candidates whose region runs along the rig (two guides' lobes fused into one)
    # are fitted with the plane only, in the accepted highlights' workers (light_aware_with_rig),
    # and split into one row per guide: the rows on two workers are those of one process, bit
    # for bit, and a rejected row that is not split carries no fits.
    from test_rig_pairs import GUIDES_MM, _jpeg, sensor_plane

    from simtest.reconstruct.rig_centroid import light_aware_with_rig
    from simtest.reconstruct.detect_pixels import luma
    from simtest.reconstruct.rig_lobes import fused_lobe_candidates
    # broad lobes through JPEG q25: their clipped tops stay two plateaus, the candidate `merged`
    img, K, _, _ = sensor_plane(20.0, 30.0, 0, spec=1.5, shininess=600.0)
    img = _jpeg(img, 25)
    rig = LightRig(tuple(Light(tuple(L), 1.0, "inverse_square") for L in GUIDES_MM))
    response = SensorResponse("srgb", clip=255.0)
    ests = reconstruct(img, K, settings=ReconSettings.for_frames())
    assert fused_lobe_candidates(luma(img), ests, K, rig), [e.status for e in ests]  # else nothing is tested
    one = light_aware_with_rig(img, ests, K, rig, workers=1, response=response)
    two = light_aware_with_rig(img, ests, K, rig, workers=2, response=response)
    assert [(e.status, e.detail) for e in two] == [(e.status, e.detail) for e in one]
    assert sum("fused into one highlight" in e.detail for e in two) == 2
    assert _light_aware_bytes(two) == _light_aware_bytes(one)
    assert all(e.ok or not e.light_aware for e in two)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a.bp_px, b.bp_px)
        np.testing.assert_array_equal(a.recommended.normal, b.recommended.normal)


def test_a_solve_asked_for_again_is_the_solve_remembered_and_other_pixels_are_solved_anew(monkeypatch):
    # the fit's stages ask for one solve again (a retry's starts hold the first try's): the solve
    # remembered is the solve redone, bit for bit, and a ROI one pixel apart is solved anew
    from collections import OrderedDict

    from simtest.reconstruct.lightaware import photometric_fit, plane_solve

    rig = LightRig(TWO_GUIDES.lights[:1])
    img, K, _, _, bp = plane_case(20.0, 30.0, rig, size=70)
    roi = img / img.max() * 230.0 + np.random.default_rng(7).normal(0.0, 2.0, img.shape)
    solves = []
    solve = plane_solve._solve_again
    monkeypatch.setattr(plane_solve, "_solve_again", lambda *a: solves.append(1) or solve(*a))
    monkeypatch.setattr(plane_solve, "_SOLVES", OrderedDict())

    def fit(values):
        solves.clear()
        est = photometric_fit(values, (0, 0), bp, K, rig)
        return est, len(solves)

    first, n_first = fit(roi)
    again, n_again = fit(roi)
    assert first.ok and n_first > 0 and n_again == 0
    monkeypatch.setattr(plane_solve, "_SOLVES_KEPT", 0)  # nothing remembered: every solve redone
    plane_solve._SOLVES.clear()
    redone, n_redone = fit(roi)
    for est in (again, redone):
        assert (est.status, est.depth_mm, est.normal_sigma_deg) == (first.status, first.depth_mm, first.normal_sigma_deg)
        assert np.array_equal(est.normal, first.normal)
    assert n_redone >= n_first
    monkeypatch.setattr(plane_solve, "_SOLVES_KEPT", 64)
    moved = roi.copy()
    moved[int(bp[1]), int(bp[0]) + 3] += 1.0
    assert fit(moved)[1] > 0
