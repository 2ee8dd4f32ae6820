"""The verifier's and the detector's pixel helpers against the library calls or exact truths they
stand for: the neighbour count against a per-candidate loop (a k-d tree's ball and OpenCV's
labels), the enlargement at points against ``cv2.resize``, the local maxima against numpy's
rolled comparisons, the colour gathers against numpy, the panel counts against the panel map,
and the candidate table's order and luma against their definitions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from _surround import surround_fraction

from simtest.reconstruct import evidence_pixels as px


def _neighbours_by_loop(top, xs, ys, bps, ij, reach, min_top, level, ellipses, area_rel):
    """The neighbour count as its definition reads: per candidate, the peaks in the ball of
    ``reach`` around the BP (``cKDTree``), in the window, high enough, outside the ellipse, then
    OpenCV's labels of the window above the valley level, one count per region."""
    from scipy.spatial import cKDTree

    h, w = top.shape
    out = np.zeros(len(bps), np.int64)
    tree = cKDTree(np.c_[xs, ys].astype(np.float64))
    for k, idx in enumerate(tree.query_ball_point(bps, reach)):
        if not idx:
            continue
        x, y = xs[idx], ys[idx]
        r0, r1 = max(0, int(ij[k, 1] - reach[k])), min(h, int(ij[k, 1] + reach[k]) + 1)
        c0, c1 = max(0, int(ij[k, 0] - reach[k])), min(w, int(ij[k, 0] + reach[k]) + 1)
        sel = (top[y, x] >= min_top[k]) & (y >= r0) & (y < r1) & (x >= c0) & (x < c1)
        if ellipses is not None and ellipses[k] is not None:
            sel &= px.ellipse_level(ellipses[k], x, y) > 1.0
        if not sel.any():
            continue
        _, lab, stats, _ = cv2.connectedComponentsWithStats((top[r0:r1, c0:c1] >= level[k]).astype(np.uint8),
                                                            connectivity=8)
        own = lab[int(ij[k, 1]) - r0, int(ij[k, 0]) - c0]
        other = lab[y[sel] - r0, x[sel] - c0]
        area = stats[:, cv2.CC_STAT_AREA]
        big = area[other] >= area_rel * area[own] if own > 0 else np.ones(len(other), bool)
        counted = ((other != own) | (own == 0)) & big
        # a region above the level is one peak, however many maxima the noise breaks it into
        out[k] = len(np.unique(other[counted & (other > 0)])) + np.count_nonzero(counted & (other == 0))
    return out


@given(seed=st.integers(0, 2**32 - 1), with_ellipses=st.booleans())
@settings(max_examples=150, deadline=None)
def test_the_neighbour_count_by_pairs_is_the_per_candidate_loop(seed, with_ellipses):
    """On random top-hats of Gaussian lobes, plateaus and noise (valleys above and below the
    level, peaks on the BP's own lobe and on others, BPs at the edges, off any peak, inside and
    outside their ellipses)."""
    from simtest.geometry.conics import Ellipse

    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(20, 90)), int(rng.integers(20, 90))
    yy, xx = np.mgrid[0:h, 0:w]
    top = rng.normal(0, 0.5, (h, w))
    for _ in range(int(rng.integers(1, 12))):
        cy, cx, s, a = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.7, 6), rng.uniform(5, 60)
        top += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    top = np.maximum(np.round(top, int(rng.integers(0, 2))), 0.0).astype(np.float32)
    ys, xs = np.nonzero(px.top_hat_maxima(top, np.zeros_like(top), np.float32(2))[1])
    xs, ys = xs.astype(np.int64), ys.astype(np.int64)
    if not len(xs):
        return
    n = int(rng.integers(1, 15))
    pick = rng.integers(0, len(xs), n)
    bps = np.c_[xs[pick], ys[pick]] + rng.uniform(-0.6, 0.6, (n, 2))
    bps[rng.random(n) < 0.2] = rng.uniform(0, [w, h], (1, 2))
    ij = np.clip(np.rint(bps).astype(np.int64), 0, [w - 1, h - 1])
    reach = rng.uniform(1, 40, n)
    height = top[ij[:, 1], ij[:, 0]]
    ellipses = None
    if with_ellipses:
        ellipses = [None if rng.random() < 0.2 else
                    Ellipse(center=bps[k] + rng.normal(0, 1, 2), semi_axes=np.sort(rng.uniform(0.5, 12, 2))[::-1],
                            angle_rad=float(rng.uniform(-np.pi, np.pi))) for k in range(n)]
    noise = float(rng.uniform(0, 3))
    args = (top, xs, ys, bps, ij, reach, 0.7 * height, 0.5 * height - 3.0 * noise, ellipses, 0.1)
    np.testing.assert_array_equal(px.other_peaks(*args), _neighbours_by_loop(*args))


def test_the_neighbour_count_meets_each_case():
    """A peak on the BP's own lobe, one beyond a valley, one too small, one on the background."""
    top = np.zeros((30, 60), np.float32)
    top[10:20, 5:15] = 100.0  # the candidate's lobe, 100 px
    top[14, 12] = 101.0  # a peak on its own lobe: not a neighbour
    top[10:20, 30:40] = 90.0  # another lobe beyond a valley: a neighbour
    top[15, 50] = 95.0  # a one-pixel glint: under a tenth of the lobe's area
    xs, ys = np.array([12, 35, 50], np.int64), np.array([14, 15, 15], np.int64)
    bps = np.array([[12.0, 14.0]])
    got = px.other_peaks(top, xs, ys, bps, bps.astype(np.int64), np.array([45.0]), np.array([70.0]),
                         np.array([49.0]), None, 0.1)
    assert got.tolist() == [1]


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 20), st.integers(2, 20), st.integers(2, 8), st.sampled_from([1, 3]), st.integers(0, 2**31 - 1))
def test_the_enlargement_at_points_is_opencvs_read_at_those_pixels(sh, sw, f, channels, seed):
    # OpenCV's INTER_LINEAR values, up to float32 rounding of values below 256 (2^-15 relative)
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (sh, sw, channels)).astype(np.float32)
    if channels == 1:
        small = small[:, :, 0]
    h, w = sh * f, sw * f
    big = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    rows, cols = rng.integers(0, h, 40), rng.integers(0, w, 40)
    assert np.allclose(px.linear_at_points(small, (h, w), rows, cols), big[rows, cols], rtol=0, atol=255 * 2.0 ** -15)


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 30), w=st.integers(1, 30), plateau=st.booleans())
@settings(max_examples=100, deadline=None)
def test_the_top_hats_maxima_are_each_pixel_against_its_neighbours(seed, h, w, plateau):
    rng = np.random.default_rng(seed)
    g = rng.integers(0, 6 if plateau else 1000, (h, w)).astype(np.float32)
    bg = rng.integers(0, 3, (h, w)).astype(np.float32)
    top, mask = px.top_hat_maxima(g, bg, np.float32(1.0))
    want_top = np.maximum(g - bg, 0)
    pad = np.pad(want_top, 1, constant_values=-np.inf)
    nb = np.max([pad[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w] for dr in (-1, 0, 1) for dc in (-1, 0, 1)], axis=0)
    assert np.array_equal(top, want_top)
    assert np.array_equal(mask, (want_top >= nb) & (want_top > 1.0))


def test_the_colour_gathers_are_numpys():
    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, (7, 9, 3)).astype(np.uint8)
    rows, cols = np.array([0, 3, 6]), np.array([0, 8, 4])
    assert np.array_equal(px.rgb_at(img, rows, cols), img[rows, cols].astype(float))
    pad = np.pad(img.astype(float), ((1, 1), (1, 1), (0, 0)), mode="edge")
    want = np.array([pad[r : r + 3, c : c + 3].reshape(-1, 3).max(axis=0) for r, c in zip(rows, cols)])
    assert np.array_equal(px.rgb_max9(img, rows, cols), want)
    grey = img[..., :1]
    assert np.array_equal(px.rgb_at(grey, rows, cols), np.repeat(grey[rows, cols].astype(float), 3, 1))


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(8, 40), w=st.integers(8, 40))
@settings(max_examples=60, deadline=None)
def test_the_panel_counts_are_the_panel_maps_sums(seed, h, w):
    rng = np.random.default_rng(seed)
    g = rng.normal(100, 5, (h, w)).astype(np.float32)
    r0, c0 = int(rng.integers(0, h - 4)), int(rng.integers(0, w - 4))
    g[r0 : r0 + int(rng.integers(4, h)), c0 : c0 + int(rng.integers(4, w))] = 50.0
    rr = np.array([[0, h, 0, w], [r0, min(h, r0 + 3), c0, min(w, c0 + 3)], [0, 1, 0, 1]], np.int64)
    panel = px.panels(g, 1.0, 10)
    got = px.pixels_in(panel, rr)
    assert got.tolist() == [int(panel[a:b, c:d].sum()) for a, b, c, d in rr]


def test_the_candidates_come_by_decreasing_peak_and_the_luma_is_its_formula():
    from simtest.constants import LUMA_BT601
    from simtest.reconstruct.detect import detect_specularities, luma

    rng = np.random.default_rng(2)
    img = rng.integers(0, 256, (60, 80, 3)).astype(np.uint8)
    np.testing.assert_allclose(luma(img), img.astype(np.float64) @ np.array(LUMA_BT601), rtol=1e-12, atol=1e-9)
    yy, xx = np.mgrid[:120, :160]
    frame = np.zeros((120, 160))
    for (cy, cx, a) in ((30, 40, 0.9), (80, 100, 0.95), (60, 130, 0.9), (90, 30, 0.8)):
        frame += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / 18.0)
    cands = detect_specularities(np.clip(frame * 255, 0, 255).astype(np.uint8)).candidates
    peaks = [c.peak for c in cands]
    assert len(cands) == 4 and peaks == sorted(peaks, reverse=True)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_the_batched_surround_is_the_one_by_one_surround(seed):
    """:func:`surround_fractions` against the one-by-one reference (tests/_surround.py), to the bit:
    glints near the frame's sides (clipped squares), reaches sharing a whole px and not."""
    from simtest.geometry.conics import Ellipse

    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(20, 90)), int(rng.integers(20, 90))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    gray = rng.uniform(0, 30, (h, w))
    for _ in range(int(rng.integers(1, 6))):
        cy, cx, s, a = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.7, 6), rng.uniform(20, 200)
        gray += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    gray = gray.astype(np.float32) if rng.random() < 0.5 else gray
    n = int(rng.integers(1, 12))
    ij = np.c_[rng.integers(0, w, n), rng.integers(0, h, n)].astype(np.int64)
    reach = np.where(rng.random(n) < 0.5, 6.5, rng.uniform(2, 30, n))
    ells = [Ellipse(center=ij[k] + rng.normal(0, 1, 2), semi_axes=np.sort(rng.uniform(0.5, 8, 2))[::-1],
                    angle_rad=float(rng.uniform(-np.pi, np.pi))) for k in range(n)]
    want = [surround_fraction(gray, ells[k], ij[k], float(reach[k]), 2.0, 0.3) for k in range(n)]
    np.testing.assert_array_equal(px.surround_fractions(gray, ells, ij, reach, 2.0, 0.3), want)


def _drop_clipped_whole_frame(flat, rgb, std_max, ceiling):
    """drop_clipped's rule written plainly over the whole frame (the reference)."""
    clip = np.ascontiguousarray((rgb >= ceiling).any(axis=-1)).view(np.uint8)
    near = cv2.dilate(clip, np.ones((5, 5), np.uint8))
    every = flat.copy()
    for c in range(rgb.shape[-1]):
        every &= px.flat_mask(rgb[..., c], std_max)
    white = (rgb >= ceiling).all(axis=-1) if clip.any() else False  # the sensor's clip in every channel
    return np.where(white, 0, np.where(near != 0, every, flat)).astype(np.uint8)


@pytest.mark.parametrize("seed", range(8))
def test_drop_clipped_in_its_window_equals_the_whole_frame_rule(seed):
    # uint8 sums of 25 values and squares are exact in float32, so the windowed box filters give
    # the whole frame's bits: equality, no tolerance
    rng = np.random.default_rng(seed)
    f = rng.integers(0, 256, (90, 130, 3)).astype(np.uint8)
    f[rng.random((90, 130)) < 0.5] = rng.integers(0, 256, 3).astype(np.uint8)  # flat patches
    f[rng.integers(0, 90, 6)[:, None], rng.integers(0, 130, 6)] = 255
    f[:rng.integers(1, 20), :, int(rng.integers(0, 3))] = 255  # a clipped channel at the top edge
    r, c = rng.integers(0, 70), rng.integers(0, 110)
    f[r:r + 20, c:c + 20] = 255  # a plateau clipped in every channel: flat, yet no panel
    gray = cv2.cvtColor(f, cv2.COLOR_RGB2GRAY).astype(np.float32)
    for std_max in (0.5, 3.0, 30.0):
        flat = px.flat_mask(gray, std_max)
        np.testing.assert_array_equal(px.drop_clipped(flat, f, std_max, 255.0),
                                      _drop_clipped_whole_frame(flat, f, std_max, 255.0))


@pytest.mark.parametrize("std_max", [1e-3, 0.5, 2.2, 3.0, 7.7, 30.0])
def test_the_variance_bound_is_the_square_root_rule_at_every_float32(std_max):
    # flat_mask compares the variance with _variance_below(std_max) instead of taking its root:
    # the same pixels, checked at the 200 float32 values about the bound, specials and spread
    t = px._variance_below(std_max)
    around = (np.array([t], np.float32).view(np.uint32) + np.arange(-100, 100).astype(np.uint32)).view(np.float32)
    v = np.concatenate([around, np.float32([np.nan, np.inf, -np.inf, -1.0, 0.0]),
                        np.random.default_rng(1).random(10_000).astype(np.float32) * np.float32(4 * std_max ** 2)])
    np.testing.assert_array_equal(v < t, np.sqrt(np.maximum(v, np.float32(0))) < np.float32(std_max))


def test_no_standard_deviation_is_below_zero():
    g = np.zeros((20, 20), np.float32)
    assert not px.flat_mask(g, 0.0).any() and px.flat_mask(g, 0.5).all()


@settings(max_examples=200, deadline=None)
@given(st.tuples(st.floats(0.05, 1.0), st.floats(0.05, 1.0), st.floats(0.05, 1.0)), st.floats(0.0, 2.0),
       st.floats(0.0, 2.0))
def test_the_white_share_splits_tissue_colour_from_white_exactly(t, a, s):
    # the dichromatic model's excess a t + s (1, 1, 1) gives back s over its brightest channel's
    # a t_max + s, whatever the tissue's colour (one pale enough for colour not to tell: 1)
    from simtest.decisions import WHITE_CHROMA
    t = np.array(t)
    got = float(px.white_share(a * t + s, t))
    if 1.0 - t.min() / t.max() < WHITE_CHROMA:
        assert got == 1.0
    elif a * t.max() + s > 1e-3:  # (a vanishing excess: the share is noise)
        # the solve's rounding over the channels' difference (>= WHITE_CHROMA of t_max)
        assert got == pytest.approx(s / (a * t.max() + s), abs=1e-9)


def test_texture_is_no_white_light_and_a_glint_is():
    from simtest.geometry.response import srgb_inverse

    # a window of tissue (sRGB 190, 90, 70) with a bump of the tissue's own colour (+30 % in
    # linear light) and a bump of white light: the shares at the two peaks
    lin = np.broadcast_to(srgb_inverse(np.array([190, 90, 70]) / 255.0), (41, 41, 3)).copy()
    yy, xx = np.mgrid[0:41, 0:41]
    bump = lambda u, v: np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / 4.0)[..., None]  # noqa: E731
    lin = lin * (1 + 0.3 * bump(10, 20)) + 0.3 * bump(30, 20)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.maximum(lin, 0.0031308) ** (1 / 2.4) - 0.055)
    img = np.rint(np.clip(srgb, 0, 1) * 255)
    share = px.white_share_in(img, cv2.getStructuringElement(cv2.MORPH_RECT, (15, 15)), (20, 20), 255.0)
    # 8-bit rounding of a 30 % bump moves the split by a few hundredths
    assert abs(share[20, 10]) < 0.1 and share[20, 30] > 0.9


@pytest.mark.parametrize("curve, gamma", [("linear", 1.0), ("gamma", 1.8)])
def test_the_white_share_undoes_the_camera_files_curve(curve, gamma):
    # the window of the test above through a camera file's other curves: with its response
    # given, texture stays tissue light and the glint white light; read as sRGB, the glint's
    # white share was 0.25 (linear) and 0.73 (gamma 1.8), the linear one under WHITE_SHARE_MIN
    from simtest.geometry.response import SensorResponse

    lin = np.broadcast_to(np.array([0.5, 0.1, 0.06]), (41, 41, 3)).copy()
    yy, xx = np.mgrid[0:41, 0:41]
    bump = lambda u, v: np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / 4.0)[..., None]  # noqa: E731
    lin = lin * (1 + 0.3 * bump(10, 20)) + 0.3 * bump(30, 20)
    img = np.rint(np.clip(lin, 0, 1) ** (1.0 / gamma) * 255).astype(np.uint8)
    se = cv2.getStructuringElement(cv2.MORPH_RECT, (15, 15))
    share = px.white_share_in(img, se, (20, 20), 255.0, SensorResponse(curve=curve, gamma=gamma))
    # 8-bit rounding of a 30 % bump moves the split by a few hundredths
    assert abs(share[20, 10]) < 0.1 and share[20, 30] > 0.9
    assert px.white_share_in(img, se, (20, 20), 255.0)[20, 30] < 0.8
