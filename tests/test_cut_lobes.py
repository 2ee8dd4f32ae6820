"""A lobe the frame's edge cuts: its top inside the frame, or the shoulder of a lobe outside it.

A broad lobe near the frame's edge gives a region that reaches the edge (``touches_border``). Its joint plane fit
reads the pixels the frame holds, so the guides' rows need no whole region: what must be told apart is a lobe whose
top lies inside (its luma falls off toward the edge) from the shoulder of a lobe outside (its luma rises to the
edge, which then holds the region's highest values). A clipped top is inside by construction; an unclipped one is
where its BP stands ``SIGNIFICANCE_MIN`` noise sigmas above the edge (``interior_top``).
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from _cases import bench_frame_rows
from benchmarks import sensor_like
from simtest.decisions import SIGNIFICANCE_MIN
from simtest.reconstruct.detect_pixels import interior_top

#: The issue's bar for the median error of a light-aware normal on sensor-like frames, deg, met here by each row.
ROW_MAX_DEG = 0.5


def _lobe(centre_u: float, sigma: float, width: int = 120, height: int = 90, noise: float = 0.0, seed: int = 0):
    """A Gaussian lobe of height 100 over a background of 50 (H, W), its centre at column ``centre_u``, row 45."""
    vv, uu = np.mgrid[0:height, 0:width].astype(float)
    img = 50.0 + 100.0 * np.exp(-((uu - centre_u) ** 2 + (vv - 45.0) ** 2) / (2.0 * sigma ** 2))
    return img + np.random.default_rng(seed).normal(0.0, noise, img.shape) if noise else img


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 60.0), st.floats(5.0, 40.0))
def test_the_shoulder_of_a_lobe_outside_the_frame_is_no_top(outside, sigma):
    # the lobe's centre at or beyond the right edge: the luma rises to the edge, whose pixels hold the box's
    # highest value, so the BP (the box's brightest pixel) stands nowhere above it
    img = _lobe(119.0 + outside, sigma)
    box = (20, 70, 60, 120)
    r, c = np.unravel_index(np.argmax(img[20:70, 60:120]), (50, 60))
    assert not interior_top(img, (60 + c, 20 + r), box)


@settings(max_examples=60, deadline=None)
@given(st.floats(8.0, 50.0), st.floats(4.0, 20.0), st.floats(0.2, 3.0), st.integers(0, 10_000))
def test_a_top_inside_is_one_where_its_fall_to_the_edge_is_significant(inside, sigma, noise, seed):
    # the lobe's centre ``inside`` px from the right edge: a top where its fall to the edge (noise-free
    # values) exceeds the bar by the noise's largest excursions, none where it falls short of the bar by them.
    # Above, 6 sigma: the BP's one pixel down and the edge's highest near the lobe up reach about 3 sigma each,
    # the estimate of sigma a few per cent more (20,000 draws each: 0.6 % miss at 4 sigma past the bar, 0.05 %
    # at 5, none at 6; a random-seed run drew inside 8, sigma 10.5, noise 2: 4.3 sigma short). Below, 4 sigma:
    # the edge's highest pixel only lowers the rise (none of 20,000 a top at 4 sigma under the bar)
    u = 119.0 - inside
    img = _lobe(u, sigma, noise=noise, seed=seed)
    box = (20, 70, 60, 120)
    fall = 100.0 * (1.0 - np.exp(-inside ** 2 / (2.0 * sigma ** 2)))  # the top above the edge's highest, noise-free
    got = interior_top(img, (u, 45.0), box)
    if fall >= (SIGNIFICANCE_MIN + 6.0) * noise:
        assert got
    elif fall <= (SIGNIFICANCE_MIN - 4.0) * noise:
        assert not got


def test_a_box_that_meets_no_edge_is_not_cut():
    img = _lobe(60.0, 10.0)
    assert not interior_top(img, (60.0, 45.0), (20, 70, 30, 90))


def test_broad_lobes_the_frames_edge_cuts_get_light_aware_normals(tmp_path):
    # tuning frame (CODED_NOISE, root 5, frame 59): two broad Blinn lobes (exponent 100, unclipped, peaks 241 and
    # 232) 27 and 86 px from the bottom edge, noise 1.4 % added to the 8-bit codes, JPEG quality 89. Their fused
    # region reaches the edge; the wider square's second look dropped it as touches_border, so neither guide's
    # highlight was even a candidate (not_detected twice). The top stands 12 levels above the edge, 20 times the
    # box's noise sigma (JPEG smooths the codes' noise): both guides' rows now come from the joint plane fit
    _, rows = bench_frame_rows(tmp_path, 5, 59, sensor_like.CODED_NOISE)
    assert all(s == "ok" and e is not None and e <= ROW_MAX_DEG for s, e in rows), rows


def test_a_region_of_the_image_is_read_in_its_own_coordinates():
    # reconstruct(roi=...) detects in a region of the image: a candidate there has image coordinates and the luma is
    # the region's, its [0, 0] at the region's corner (origin). The lobe's top inside, its region cut by the region's
    # right edge, is a top exactly as the same candidate in the region's own coordinates is
    from types import SimpleNamespace

    from simtest.reconstruct.rig_lobes import splittable

    gray = _lobe(100.0, 8.0)  # the region's luma: a top 19 px inside its right edge
    local = SimpleNamespace(status="touches_border", saturated=False, bp_px=np.array([100.0, 45.0]),
                            roi=(20, 70, 60, 120))
    moved = SimpleNamespace(status="touches_border", saturated=False, bp_px=np.array([100.0 + 300, 45.0 + 200]),
                            roi=(220, 270, 360, 420))
    assert splittable(local, gray) and splittable(moved, gray, (200, 300))
    clipped = SimpleNamespace(**{**vars(local), "saturated": True})
    assert not splittable(local) and splittable(clipped)  # (without a luma: a clipped top only)
