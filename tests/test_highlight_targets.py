"""Which ground-truth highlights a render shows (simtest.render.truth.highlight_targets)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.render.truth import LOBE_MATCH_PX, highlight_targets, lobe_peak, smoothed_specular
from simtest.simulate.truth import HighlightTruth


def _lobe(shape, uv, sigma, peak=1.0):
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    return peak * np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma**2))


def _truth(uv, light=0, in_frame=True):
    return HighlightTruth(np.asarray(uv, float), np.array([0.0, 0.0, 20.0]), np.array([0.0, 0.0, -1.0]),
                          0.0, 0.0, in_frame, light)


SHAPE = (100, 160)
VALID = np.ones(SHAPE, bool)


def test_lights_whose_highlights_run_together_are_one_target():
    # two guides' lobes (sigma 5 px) 6 px apart: one highlight to a person; 60 px apart: two
    near = _lobe(SHAPE, (50, 50), 5.0) + _lobe(SHAPE, (56, 50), 5.0, 0.9)
    (t,) = highlight_targets([_truth((50, 50), 0), _truth((56, 50), 1)], near, VALID)
    assert t.lights == (0, 1) and t.bp_px.tolist() == [[50, 50], [56, 50]]
    far = _lobe(SHAPE, (40, 50), 5.0) + _lobe(SHAPE, (100, 50), 5.0, 0.9)
    ts = highlight_targets([_truth((40, 50), 0), _truth((100, 50), 1)], far, VALID)
    assert [t.lights for t in ts] == [(0,), (1,)]  # brightest first


def test_a_highlight_cut_by_the_field_stop_or_the_frame_is_no_target():
    spec = _lobe(SHAPE, (50, 50), 5.0)
    valid = VALID.copy()
    valid[:, 55:] = False  # the half-maximum disc (radius 5.9 px) crosses column 55
    assert highlight_targets([_truth((50, 50))], spec, valid) == []
    valid = VALID.copy()
    valid[:, 57:] = False  # ... but not column 57
    assert len(highlight_targets([_truth((50, 50))], spec, valid)) == 1
    at_edge = _lobe(SHAPE, (2, 50), 5.0)
    assert highlight_targets([_truth((2, 50))], at_edge, VALID) == []


def test_a_broad_irregular_sheen_is_no_target_and_out_of_frame_or_dark_bps_are_dropped():
    # an L-shaped sheen (ellipticity ~0.6) holding a BP
    sheen = np.zeros(SHAPE)
    sheen[30:40, 20:90] = 1.0
    sheen[30:80, 80:90] = 1.0
    assert highlight_targets([_truth((50, 35))], sheen, VALID) == []
    spec = _lobe(SHAPE, (50, 50), 5.0)
    assert highlight_targets([_truth((50, 50), in_frame=False)], spec, VALID) == []
    spec[:, 120:] = 0.0
    assert highlight_targets([_truth((150, 90))], spec, VALID) == []  # no specular light there


@given(n=st.integers(2, 5), extra=st.integers(0, 3))
@settings(max_examples=20, deadline=None)
def test_a_sheen_holding_several_bps_of_one_light_is_no_target(n, extra):
    # n specular points of light 0 (sparkle of micro-relief) under one smooth envelope: a sheen,
    # whatever other lights' BPs it holds; one BP each of n + extra lights under the same
    # envelope (a laparoscope's ring): a target
    spec = _lobe(SHAPE, (80, 50), 8.0)
    spots = [(77 + k, 49 + k % 3) for k in range(n + extra)]  # all within the half-maximum disc
    one_light = [_truth(uv, 0 if k < n else k) for k, uv in enumerate(spots)]
    assert highlight_targets(one_light, spec, VALID) == []
    ring = [_truth(uv, k) for k, uv in enumerate(spots)]
    (t,) = highlight_targets(ring, spec, VALID)
    assert sorted(t.lights) == list(range(n + extra))


@given(dx=st.integers(-3, 3), dy=st.integers(-3, 3))
@settings(max_examples=20, deadline=None)
def test_the_peak_is_the_lobe_maximum_the_bp_lies_on(dx, dy):
    # micro-relief moves the image's peak off the macro BP: the target's peak is the local
    # maximum of the smoothed specular image reached from the BP, not the brighter lobe beside it
    spec = _lobe(SHAPE, (50, 50), 5.0) + _lobe(SHAPE, (120, 50), 5.0, 3.0)
    ts = highlight_targets([_truth((50 + dx, 50 + dy))], spec, VALID)
    assert len(ts) == 1 and ts[0].peak_px.tolist() == [50, 50]


def test_distance_to_a_target_is_to_the_hull_of_its_points():
    spec = _lobe(SHAPE, (50, 50), 5.0) + _lobe(SHAPE, (56, 50), 5.0)
    (t,) = highlight_targets([_truth((50, 50), 0), _truth((56, 50), 1)], spec, VALID)
    assert t.peak_px[1] == 50 and 50 <= t.peak_px[0] <= 56  # the peak lies on the segment
    assert t.distance_px((53.0, 50.0)) == 0.0
    assert t.distance_px((53.0, 54.0)) == pytest.approx(4.0)
    assert t.distance_px((46.0, 47.0)) == pytest.approx(5.0)  # 3-4-5 from the end (50, 50)
    # a ring of 8 lights (a laparoscope): every point inside their hull is at distance 0
    ring = [(80 + 4 * np.cos(a), 50 + 4 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)]
    spec = sum(_lobe(SHAPE, uv, 8.0) for uv in ring)
    (t,) = highlight_targets([_truth(uv, i) for i, uv in enumerate(ring)], spec, VALID)
    assert len(t.lights) == 8
    assert t.distance_px((80.0, 50.0)) == 0.0 and t.distance_px((81.0, 51.5)) == 0.0
    assert t.distance_px((80.0, 60.0)) == pytest.approx(6.0, abs=0.4)  # the hull's edge is ~4 px out


@settings(max_examples=40, deadline=None)
@given(st.floats(10.0, 150.0), st.floats(10.0, 90.0), st.floats(1.5, 6.0), st.floats(-1.8, 1.8), st.floats(-1.8, 1.8))
@example(10.5, 10.0, 2.0, 1.0, 0.0)  # two maximum pixels: the climb from the right ends on the right one
def test_a_lobe_peak_is_found_from_a_bp_on_it_and_nowhere_else(u, v, sigma, du, dv):
    # an isolated Gaussian lobe: the climb from a BP within LOBE_MATCH_PX ends on the lobe's maximum pixel
    # (offsets of at most 1.8 px a side, plus a pixel of rounding each, stay within the 4 px bound)
    spec = _lobe(SHAPE, (u, v), sigma)
    sm = smoothed_specular(spec)
    if not highlight_targets([_truth((u, v))], spec, VALID):
        return  # a lobe cut by the frame border is no isolated highlight either way
    peak = lobe_peak(sm, VALID, (u + du, v + dv))
    assert peak is not None
    r, c = np.unravel_index(int(np.argmax(sm)), sm.shape)
    # a maximum pixel (a lobe centred between two pixels has two, the climb may end on either)
    assert sm[int(peak[1]), int(peak[0])] == sm.max() and np.hypot(peak[0] - c, peak[1] - r) <= 1.5
    # a detection on the lobe's flank farther than the bound climbs to the same peak, too far to be its own
    far = (c + 3 * LOBE_MATCH_PX, r) if c + 3 * LOBE_MATCH_PX < SHAPE[1] else (c - 3 * LOBE_MATCH_PX, r)
    assert lobe_peak(sm, VALID, far) is None


def test_a_speckle_field_or_a_lobe_outside_the_valid_pixels_has_no_lobe_peak():
    rng = np.random.default_rng(0)
    # micro-relief sparkle over the whole view: its half-maximum regions run together and reach the border
    speckle = rng.exponential(1.0, SHAPE).astype(np.float32)
    sm = smoothed_specular(speckle)
    assert all(lobe_peak(sm, VALID, (u, v)) is None for u in range(20, 140, 20) for v in range(20, 80, 20))
    spec = _lobe(SHAPE, (50, 50), 4.0)
    valid = VALID.copy()
    valid[:, 48:] = False  # the field stop cuts the lobe
    assert lobe_peak(smoothed_specular(spec), valid, (50, 50)) is None
    assert lobe_peak(smoothed_specular(spec), VALID, (50, 50)).tolist() == [50, 50]
