"""Specularity detection: candidates, BP, ROI, rejection reasons, image types, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct.detect import (
    BACKGROUND_DIV,
    BACKGROUND_PLATEAU_FACTOR,
    background_side_px,
    clipped_mask,
    connected_components_with_stats,
    detect_specularities,
    ellipticity,
    image_noise_sigma,
    mask_labels,
    noise_sigma,
    validate_image,
)
from simtest.reconstruct.detect_pixels import _gray_and_grey, _gray_native, wide_lobe_boxes
from simtest.reconstruct.frame_prep import _is_gray


def gaussian(shape, centre_uv, sigma, peak=1.0, aspect=1.0):
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    q = ((u - centre_uv[0]) / sigma) ** 2 + ((v - centre_uv[1]) / (aspect * sigma)) ** 2
    return peak * np.exp(-q / 2)


def three_blobs(shape=(120, 200)):
    centres = [(40.3, 40.6), (100.0, 80.2), (160.7, 35.1)]
    img = sum(gaussian(shape, c, 4.0, p) for c, p in zip(centres, (0.95, 0.9, 0.85)))
    return img, centres


def test_finds_every_blob_and_its_bp():
    img, centres = three_blobs()
    det = detect_specularities(img)
    assert [c.status for c in det.candidates] == ["ok"] * 3
    # sorted by peak, brightest first, same order as built
    for cand, c in zip(det.candidates, centres):
        # the 3-point parabola through a sampled Gaussian of sigma 4 px is biased by < 0.05 px
        assert np.allclose(cand.bp_uv, c, atol=0.05)
        assert not cand.saturated
        r0, r1, c0, c1 = cand.roi
        assert r0 <= c[1] < r1 and c0 <= c[0] < c1


@given(dx=st.floats(-0.5, 0.5), dy=st.floats(-0.5, 0.5))
@settings(max_examples=30, deadline=None)
def test_saturated_plateau_centroid_is_the_bp(dx, dy):
    centre = (50 + dx, 40 + dy)
    img = np.clip(gaussian((80, 100), centre, 6.0, 400.0), 0, 255).astype(np.uint8)
    (cand,) = detect_specularities(img).candidates
    assert cand.saturated and cand.status == "ok"
    # the clipped disc (about 100 px) is symmetric about the centre up to the pixel quantisation of
    # its rim: each rim pixel in or out moves the centroid by ~0.05 px, and a sub-pixel shift flips
    # a few of them on one side only. Over a 1/64 px grid of shifts the centroid of the clipped
    # pixels is at most 0.257 px off (shifts near +-0.47 px, where one axis still shows the pixel
    # set of a centred disc; hypothesis found dy = 0.46875): 0.3 px bounds it.
    assert np.allclose(cand.bp_uv, centre, atol=0.3)


def test_rejection_reasons():
    img = np.zeros((100, 160))
    img[10:12, 10] = 1.0  # 2 px speck
    img += gaussian(img.shape, (2, 60), 3.0)  # at the left border
    img[60:66, 20:50] = 1.0  # an L shape: ellipticity ~ 0.6
    img[40:66, 44:50] = 1.0
    v, u = np.mgrid[0:100, 0:160]
    r = np.hypot(u - 120, v - 60)
    img += 0.95 * ((r > 10) & (r < 14))  # a ring
    det = detect_specularities(img)
    reasons = sorted(c.status for c in det.candidates)
    assert reasons == ["not_elliptical", "not_elliptical", "too_small", "touches_border"]
    for c in (c for c in det.candidates if c.status != "ok"):
        assert c.detail  # every rejection says why with numbers


def test_two_saturated_plateaus_in_one_component_are_merged():
    img = gaussian((80, 140), (50, 40), 6, 400) + gaussian((80, 140), (70, 40), 6, 400)
    img = np.clip(img, 0, 255).astype(np.uint8)  # midpoint 199 >= 0.7 * 255 but < 255
    (cand,) = detect_specularities(img).candidates
    assert cand.status == "merged" and "2 saturated plateaus" in cand.detail


@pytest.mark.parametrize("radius", [12.0, 30.0, 45.0])
def test_a_clipped_highlight_wider_than_the_default_background_square_is_one_candidate(radius):
    # a clipped disc on a lit falloff, as the auto-exposure makes of a lobe close to the scope:
    # wider than the default square (31 px here) it used to be taken for background and its rim
    # cut into pieces; the square now grows to twice the plateau
    shape = (200, 200)
    bg = 120.0 * gaussian(shape, (100, 100), 60.0)
    img = np.clip(bg + gaussian(shape, (100.3, 99.6), radius / 1.8, 400.0), 0, 255).astype(np.uint8)
    clip = clipped_mask(img, 255)
    ext = max(np.ptp(np.nonzero(clip)[0]), np.ptp(np.nonzero(clip)[1])) + 1
    assert background_side_px(shape, clip) == max(31, 2 * ext + 1)
    det = detect_specularities(img, method="local_peak")
    (cand,) = [c for c in det.candidates if c.saturated]
    assert cand.status == "ok", (cand.status, cand.detail)
    # the BP is the centroid of the clipped disc (see test_saturated_plateau_centroid_is_the_bp)
    assert np.allclose(cand.bp_uv, (100.3, 99.6), atol=0.25)
    assert [c for c in det.candidates if c.status == "ok"] == [cand]


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([np.uint8, np.uint16]), st.sampled_from([(9, 11), (9, 11, 3), (9, 11, 4)]),
       st.floats(-3.0, 70000.0), st.integers(0, 2**32 - 1))
def test_clipped_mask_is_every_channel_at_or_above_the_level(dtype, shape, level, seed):
    # the OpenCV form (inRange at the ceiling of the level) against the definition, for levels
    # below zero, between integers, at the dtype maximum and above it
    top = np.iinfo(dtype).max
    rng = np.random.default_rng(seed)
    img = rng.integers(0, top, shape, dtype=dtype, endpoint=True)
    img[rng.random(shape[:2]) < 0.3] = top
    level = min(level, top + 2.0) if rng.random() < 0.5 else float(top)
    img = validate_image(img)
    want = np.all((img >= level).reshape(*img.shape[:2], -1), axis=2)
    got = clipped_mask(img, level)
    assert got.dtype == np.uint8 and np.array_equal(got, want.view(np.uint8))
    # the rows examined are those where OpenCV's luma reaches the level: the same mask, with
    # clipped pixels in a few rows only, and with pixels at the level in one channel short of it
    sparse = img.copy()
    sparse[rng.random(shape[:2]) < 0.9] = 0
    if sparse.ndim == 3:
        sparse[rng.random(shape[:2]) < 0.2, rng.integers(0, sparse.shape[2])] = int(np.clip(np.ceil(level) - 1, 0, top))
    for im in (img, sparse):
        want = np.all((im >= level).reshape(*im.shape[:2], -1), axis=2)
        got = clipped_mask(im, level, _gray_native(im))
        assert got.dtype == np.uint8 and np.array_equal(got, want.view(np.uint8))
    # a gray frame (R = G = B) whose gray the caller knows is the channel: the gray's mask
    if img.ndim == 3 and img.shape[2] == 3:
        grey = np.repeat(sparse[:, :, :1], 3, axis=2)
        want = np.all((grey >= level).reshape(*grey.shape[:2], -1), axis=2)
        got = clipped_mask(grey, level, np.ascontiguousarray(grey[:, :, 0]), grey=True)
        assert got.dtype == np.uint8 and np.array_equal(got, want.view(np.uint8))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.6), st.booleans())
def test_components_band_by_band_are_those_of_one_pass_over_the_mask(seed, fill, blobs):
    # sparse blobs (empty rows between them: several bands) and dense speckle (one band), with
    # components nested in the holes of others
    rng = np.random.default_rng(seed)
    mask = (rng.random((37, 53)) < fill).astype(np.uint8)
    if blobs:
        mask[:] = 0
        for _ in range(rng.integers(1, 6)):
            r, c = rng.integers(0, 34), rng.integers(0, 50)
            mask[r : r + rng.integers(1, 4), c : c + rng.integers(1, 4)] = 1
    mask[30:37, 40:47] = 1
    mask[31:36, 41:46] = 0
    mask[33, 43] = 1
    n, lab, stats, _ = connected_components_with_stats(mask)
    got_n, got_lab, got_stats = mask_labels(mask)
    assert got_n == n - 1 and np.array_equal(got_lab, lab) and np.array_equal(got_stats, stats[1:])
    assert mask_labels(np.zeros((5, 5), np.uint8))[0] == 0


def test_the_background_square_is_set_by_the_widest_plateau_even_one_in_a_hole():
    clip = np.zeros((200, 200), np.uint8)
    clip[20:80, 20:80] = 1
    clip[30:70, 30:70] = 0  # a ring 60 px wide, and a plateau in its hole
    clip[40:45, 40:45] = 1
    clip[150:152, 100:131] = 1  # a bar 31 px long
    assert background_side_px((200, 200), clip) == 2 * 60 + 1
    clip[10:12, 120:195] = 1  # a bar 75 px long
    assert background_side_px((200, 200), clip) == 2 * 75 + 1


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 6))
def test_the_background_square_is_that_of_the_widest_8_connected_plateau(seed, n_blobs):
    # the definition, by labelling the whole mask closed by a 3 x 3 square (scipy.ndimage's
    # dilation, then erosion with the frame's edge neutral), against background_side_px (which closes and
    # contours only the rows that hold clipped pixels); empty masks included, and blobs with
    # pixels knocked out (a plateau broken by noise)
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(1, 150, 2))
    clip = np.zeros((h, w), np.uint8)
    for _ in range(n_blobs):
        r, c = rng.integers(0, h), rng.integers(0, w)
        clip[r : r + rng.integers(1, 60), c : c + rng.integers(1, 60)] = 1
    clip &= (rng.random((h, w)) > rng.choice([0.0, 0.3])).astype(np.uint8)
    square = np.ones((3, 3), bool)
    closed = ndimage.binary_erosion(ndimage.binary_dilation(clip, square), square, border_value=1)
    n, _, stats, _ = connected_components_with_stats(closed.astype(np.uint8))
    ext = max((max(int(x[2]), int(x[3])) for x in stats[1:]), default=0)
    default = max(31, min(h, w) // BACKGROUND_DIV)
    widest = BACKGROUND_PLATEAU_FACTOR * ext + 1
    assert background_side_px((h, w), clip) == (max(default, widest) if n > 1 else default)


def test_the_default_background_square_is_unchanged_without_wide_plateaus():
    assert background_side_px((1080, 1350)) == 108
    assert background_side_px((280, 280)) == 31
    small = np.zeros((406, 406), np.uint8)
    small[100:110, 200:210] = 1  # 10 px plateau: 2 x 10 + 1 < 40
    assert background_side_px((406, 406), small) == 40


@pytest.mark.parametrize("period", [5.0, 6.0, 7.0])
def test_a_clipped_top_broken_by_speckle_is_one_plateau_on_a_noisy_image(period):
    # one clipped lobe striped by the relief's speckle (a grating of period 5 to 7 px whose dark
    # bands, about 3 px wide, cut its clipped top into 2 or 3 plateaus that a 3 x 3 closing leaves
    # apart) under 2 % read noise: the smoothing chosen from the noise (sigma ~2 px) makes the
    # closing 2 ceil(2 sigma) + 1 px wide, which joins the pieces into one plateau; a second
    # lobe 90 px away stays its own candidate
    rng = np.random.default_rng(3)
    shape = (160, 240)
    v = np.mgrid[0 : shape[0], 0 : shape[1]][0].astype(float)
    lobe = gaussian(shape, (80.0, 80.0), 9.0, 400.0) * (0.5 + 0.5 * np.cos(2 * np.pi * v / period))
    img = lobe + gaussian(shape, (170.0, 80.0), 5.0, 600.0) + rng.normal(0, 0.02 * 255, shape)
    img = np.clip(img, 0, 255).astype(np.uint8)
    det = detect_specularities(img, method="local_peak", smooth_sigma_px=None)
    sat = sorted((c for c in det.candidates if c.saturated), key=lambda c: c.bp_uv[0])
    assert [c.status for c in sat] == ["ok", "ok"], [(c.status, c.detail) for c in sat]
    # the BP is the centroid of the joined plateau: the stripes are symmetric about the lobe's
    # centre up to one band (half a period)
    assert np.allclose(sat[0].bp_uv, (80, 80), atol=period / 2)
    assert np.allclose(sat[1].bp_uv, (170, 80), atol=0.25)


def test_ellipticity_of_simple_shapes():
    v, u = np.mgrid[0:200, 0:200]
    disc = np.hypot(u - 100, v - 100) < 60
    ell = ((u - 100) / 80.0) ** 2 + ((v - 100) / 30.0) ** 2 < 1
    # pixelisation of a large filled ellipse: area and moments to ~1e-3
    assert abs(ellipticity(disc) - 1) < 0.01 and abs(ellipticity(ell) - 1) < 0.01
    square = np.zeros((50, 50), bool)
    square[10:40, 10:40] = True
    assert abs(ellipticity(square) - 3 / np.pi) < 0.01  # a square: A / (4 pi A / 12) = 3 / pi


@pytest.mark.parametrize(
    "convert",
    [
        lambda g: (g * 255).round().astype(np.uint8),
        lambda g: (g * 65535).round().astype(np.uint16),
        lambda g: g.astype(np.float32),
        lambda g: g,
        lambda g: np.repeat((g * 255).round().astype(np.uint8)[:, :, None], 3, axis=2),
        lambda g: np.dstack([g, g, g, np.ones_like(g)]),
        lambda g: g[:, :, None],
    ],
    ids=["uint8", "uint16", "float32", "float64", "rgb_uint8", "rgba_float", "hw1"],
)
def test_image_types_give_the_same_candidates(convert):
    img, centres = three_blobs()
    det = detect_specularities(convert(img))
    assert [c.status for c in det.candidates] == ["ok"] * 3
    for cand, c in zip(det.candidates, centres):
        # 8-bit quantisation moves the parabola peak by up to ~0.1 px on a sigma-4 Gaussian
        assert np.allclose(cand.bp_uv, c, atol=0.15)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((10, 10), np.int64), "dtype"),
        (np.zeros((10, 10), bool), "dtype"),
        (np.zeros((10, 10), complex), "dtype"),
        (np.zeros(10), "shape"),
        (np.zeros((4, 10, 10, 3)), "shape"),
        (np.zeros((10, 10, 2)), "shape"),
        (np.zeros((0, 10)), "empty"),
        (np.full((10, 10), np.nan), "non-finite"),
        ("image.png", "array"),
        (None, "array"),
    ],
)
def test_bad_images_raise_value_error_naming_the_problem(bad, match):
    with pytest.raises(ValueError, match=match):
        detect_specularities(bad)
    with pytest.raises(ValueError, match=match):
        validate_image(bad)


def test_constant_and_empty_scenes():
    assert detect_specularities(np.full((50, 50), 0.5)).candidates == []
    assert detect_specularities(np.zeros((50, 50), np.uint8)).candidates == []
    # a white frame is one highlight that touches every border
    (c,) = detect_specularities(np.full((50, 50), 255, np.uint8)).candidates
    assert c.status == "touches_border"


def test_bad_options():
    with pytest.raises(ValueError, match="brightness_rel"):
        detect_specularities(np.zeros((10, 10)), brightness_rel=1.5)
    with pytest.raises(ValueError, match="full_scale"):
        detect_specularities(np.zeros((10, 10)), full_scale=-1)


def test_a_single_clipped_channel_is_not_saturation():
    # reddish tissue: the red channel clips over a broad area; the specular BP must come from the
    # white (all channels clipped) plateau, not from the red plateau's centroid
    g = gaussian((100, 160), (100.0, 50.0), 5.0, 400.0)
    red = np.clip(gaussian((100, 160), (70.0, 50.0), 25.0, 300.0) + g, 0, 255)
    rgb = np.dstack([red, np.clip(0.6 * g + 60, 0, 255), np.clip(0.6 * g + 60, 0, 255)])
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    cands = [c for c in detect_specularities(rgb).candidates if c.saturated]
    assert len(cands) == 1
    # the white plateau (where 0.6 * g + 60 >= 255) is a disc about (100, 50)
    assert np.allclose(cands[0].bp_uv, (100.0, 50.0), atol=0.25)


def test_candidate_cap_counts_what_it_leaves_out():
    img = np.zeros((60, 60))
    img[5:55:4, 5:55:4] = 1.0  # 13 x 13 isolated single-pixel specks
    det = detect_specularities(img, max_candidates=100)
    assert len(det.candidates) == 100 and det.n_unexamined == 169 - 100
    assert all(c.status == "too_small" for c in det.candidates)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_ellipticity_is_its_formula_with_numpys_covariance(seed):
    # ellipticity() is its formula with np.cov's second moments, to the bit
    rng = np.random.default_rng(seed)
    mask = rng.random((int(rng.integers(2, 40)), int(rng.integers(2, 40)))) < rng.uniform(0.1, 0.9)
    rr, cc = np.nonzero(mask)
    if rr.size < 3:
        assert np.isnan(ellipticity(mask))
        return
    cov = np.cov(np.stack([rr, cc]).astype(np.float64), bias=True)
    det = (cov[0, 0] + 1 / 12) * (cov[1, 1] + 1 / 12) - cov[0, 1] ** 2
    want = rr.size / (4 * np.pi * np.sqrt(det)) if det > 0 else float("nan")
    assert ellipticity(mask) == want or (np.isnan(want) and np.isnan(ellipticity(mask)))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]),
       st.booleans())
def test_the_noise_read_on_its_rows_alone_is_that_of_the_whole_luma(seed, dtype, rgb):
    # the pipeline converts only the rows the noise estimate reads to luma: the same noise (and so
    # the same smoothing), to the bit, as from the luma of the whole image (_gray_native: the detector's)
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(3, 400)), int(rng.integers(3, 200))) + ((3,) if rgb else ())
    if dtype in (np.uint8, np.uint16):
        img = rng.integers(0, np.iinfo(dtype).max, shape, dtype=dtype, endpoint=True)
    else:
        img = (rng.random(shape) * rng.uniform(0.5, 2.0)).astype(dtype)
    assert image_noise_sigma(img) == noise_sigma(_gray_native(img))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 9), st.integers(3, 60), st.sampled_from(["uniform", "noisy", "flat", "ramp"]))
def test_the_noise_of_uint8_rows_is_numpys_median(seed, h, w, kind):
    # two np.median calls on the float32 differences (the MAD), ties and even counts included: an
    # 8-bit path by histograms of integers stood here and had to give the same float
    from simtest.reconstruct.detect_pixels import _noise_sigma_of_rows

    rng = np.random.default_rng(seed)
    if kind == "uniform":
        rows = rng.integers(0, 256, (h, w))
    elif kind == "noisy":
        rows = np.clip(rng.normal(128, rng.uniform(0, 30), (h, w)), 0, 255)
    elif kind == "flat":  # mostly one value: the medians are ties
        rows = np.where(rng.random((h, w)) < 0.3, 255, rng.integers(0, 256))
    else:
        rows = np.linspace(0, 255, w)[None] + rng.integers(0, 3, (h, w))
    rows = np.clip(rows, 0, 255).astype(np.uint8)
    g = rows.astype(np.float32)
    d = g[:, 1:-1] - 0.5 * (g[:, :-2] + g[:, 2:])
    want = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(1.5))
    assert _noise_sigma_of_rows(rows) == want


def _dark_corner_components_by_labels(dark):
    """The dark components holding the corners as they were found: one labelling of the whole
    reduced image (the reference of the corners' flood fills)."""
    import cv2

    from simtest.reconstruct.detect_pixels import connected_components_with_stats

    n, lab, stats = connected_components_with_stats(dark)[:3]
    if n <= 1:
        return None
    corners = np.array([lab[0, 0], lab[0, -1], lab[-1, 0], lab[-1, -1]])
    edge = np.unique(corners[corners > 0])
    if len(corners[corners > 0]) < 2:
        return None
    frac = stats[edge, cv2.CC_STAT_AREA].sum() / dark.size
    if not 0.01 <= frac <= 0.6:
        return None
    return np.isin(lab, edge).view(np.uint8)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from([(1, 1), (2, 7), (10, 12), (40, 33)]),
       radius=st.floats(0.2, 0.8), speckle=st.floats(0.0, 0.3))
def test_the_dark_corner_components_by_flood_fill_are_the_labellings(seed, shape, radius, speckle):
    # a lit disc (the field of view) of random size and centre on a dark mask, dark speckle
    # inside it and lit speckle outside (text on the border): the components holding the
    # corners, their areas (the 1 % to 60 % test) and the None cases must be the labelling's
    from simtest.reconstruct.detect_pixels import _dark_corner_components

    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[:h, :w]
    cy, cx = rng.uniform(0, h), rng.uniform(0, w)
    lit = (yy - cy) ** 2 + (xx - cx) ** 2 < (radius * max(h, w)) ** 2
    dark = (~(lit ^ (rng.random((h, w)) < speckle))).view(np.uint8)
    want = _dark_corner_components_by_labels(dark)
    got = _dark_corner_components(dark.copy())
    assert (got is None) == (want is None)
    if want is not None:
        assert np.array_equal(got, want)


def test_detection_hands_over_its_smoothing_and_the_pipeline_smooths_the_unrounded_luma():
    """One smoothing per frame: Detection.smoothed is the frame's luma smoothed once (read-only):
    for a colour frame its unrounded float32 luma (handed over as Detection.luma32, which the
    pipeline reads as its own), not OpenCV's gray rounded to whole levels; for a gray frame the
    gray itself. The pipeline contours many ROIs in that smoothing without a second blur. None
    when not smoothed."""
    from unittest import mock

    import cv2

    from simtest.reconstruct import frame_prep, pipeline
    from simtest.reconstruct.detect import luma
    from simtest.reconstruct.frame_prep import _frame_luma_smoothing

    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    det = detect_specularities(img, smooth_sigma_px=1.5, method="local_peak")
    want = cv2.GaussianBlur(det.luma32, (0, 0), 1.5, borderType=cv2.BORDER_REFLECT)
    assert det.smoothed.dtype == np.float32 and not det.smoothed.flags.writeable
    assert np.array_equal(det.smoothed, want)
    # the float32 luma (OpenCV's weighted sum in float32) is the float64 luma to float32 rounding
    np.testing.assert_allclose(det.luma32, luma(img), rtol=2.0**-22, atol=0)
    assert not det.luma32.flags.writeable
    assert np.array_equal(_frame_luma_smoothing(img, det.smoothed, 1.5, det.luma32), want)
    grey = np.repeat(img[:, :, :1], 3, axis=2)
    det = detect_specularities(grey, smooth_sigma_px=1.5, method="local_peak")
    assert det.luma32 is None
    assert _frame_luma_smoothing(grey, det.smoothed, 1.5) is det.smoothed
    assert detect_specularities(img, smooth_sigma_px=0.0).smoothed is None
    # a whole colour frame with many highlights, smoothed at full resolution (the banner's
    # path): one full-frame blur in all, detection's, and the pipeline contours in it
    from benchmarks.inputs import banner_frame

    got = banner_frame()
    if got is None:
        return
    frame, K = got
    blurs = []
    real_blur = cv2.GaussianBlur

    def counting(src, *a, **k):
        if src.shape[:2] == frame.shape[:2]:
            blurs.append(src.dtype)
        return real_blur(src, *a, **k)

    seen = {}
    real_with = frame_prep._Frame.with_detection_smoothing

    def spy(self, smoothed):
        seen["smoothed"] = smoothed
        return real_with(self, smoothed)

    with mock.patch.object(cv2, "GaussianBlur", counting), \
            mock.patch.object(frame_prep._Frame, "with_detection_smoothing", spy):
        pipeline.reconstruct(frame, K)
    assert blurs == [np.float32]
    assert seen["smoothed"] is not None and not seen["smoothed"].flags.writeable


def test_a_smoothed_frame_detected_at_half_resolution_has_the_full_resolutions_candidates(monkeypatch):
    """Issue 41: local-peak detection of a frame smoothed by >= 2 px looks for its components on
    the frame reduced twice and examines each at full resolution: on the bench's noisy frame
    (2 % noise, sigma 2.5 px, two clipped highlights) the statuses and ROIs are those of the
    full-resolution detection, the BPs and peaks to float32 rounding of the smoothing, the areas
    within 1 %, the levels within 0.1 grey
    level (the background enlarged from the same blocks' means, to float32 rounding)."""
    from benchmarks import inputs as bench
    from simtest.reconstruct import detect

    img, _, _ = bench.noisy_frame()
    half = detect.detect_specularities(img, method="local_peak", smooth_sigma_px=2.5)
    monkeypatch.setattr(detect, "MULTIRES_SIGMA_MIN_PX", np.inf)
    full = detect.detect_specularities(img, method="local_peak", smooth_sigma_px=2.5)
    assert half.smoothed is None and full.smoothed is not None  # the path taken
    assert len(half.candidates) == len(full.candidates) == 10
    for a, b in zip(half.candidates, full.candidates):
        # each window is smoothed by OpenCV alone (its own taps and rounding against the
        # frame's): the peaks within 1e-3 grey levels (a few float32 ulps of 255), the BPs
        # (parabola vertices of those values, or a plateau's centroid) within 0.01 px
        assert np.abs(a.bp_uv - b.bp_uv).max() < 0.01 and abs(a.peak - b.peak) < 1e-3
        assert a.saturated == b.saturated
        assert (a.status, a.roi) == (b.status, b.roi)
        assert abs(a.area_px - b.area_px) <= 0.01 * b.area_px
        assert abs(a.level - b.level) < 0.1
    # more candidates than MULTIRES_CANDIDATES_MAX: the full resolution's, unchanged
    monkeypatch.setattr(detect, "MULTIRES_SIGMA_MIN_PX", 2.0)
    monkeypatch.setattr(detect, "MULTIRES_CANDIDATES_MAX", 5)
    again = detect.detect_specularities(img, method="local_peak", smooth_sigma_px=2.5)
    assert again.smoothed is not None
    assert [c.bp_uv.tolist() for c in again.candidates] == [c.bp_uv.tolist() for c in full.candidates]


@given(seed=st.integers(0, 2**32 - 1), colour_at=st.one_of(st.none(), st.integers(0, 40 * 50 - 1)))
@settings(max_examples=40, deadline=None)
def test_gray_and_grey_is_opencvs_gray_and_the_gray_test(seed, colour_at):
    # the R channel of a gray 8-bit frame is OpenCV's gray of it (its fixed-point weights sum to
    # one), and the one-pass test says gray exactly where R = G = B everywhere (a single colour
    # pixel anywhere makes it a colour frame, converted by OpenCV)
    rng = np.random.default_rng(seed)
    img = np.repeat(rng.integers(0, 256, (40, 50, 1), dtype=np.uint8), 3, axis=2)
    if colour_at is not None:
        r, c = divmod(colour_at, 50)
        img[r, c, rng.integers(0, 3)] ^= np.uint8(rng.integers(1, 256))
    gray, grey = _gray_and_grey(img)
    assert grey == _is_gray(img) == (colour_at is None)
    assert np.array_equal(gray, cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
    assert _gray_and_grey(img.astype(np.uint16))[1] is None  # not asked: 16-bit


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 12),
       dtype=st.sampled_from([np.uint8, np.uint16, np.float32]), channels=st.sampled_from([3, 4]),
       channel=st.integers(-1, 2), flip=st.booleans())
@settings(max_examples=80, deadline=None)
def test_the_gray_test_is_r_g_and_b_equal_at_every_pixel(seed, h, w, dtype, channels, channel, flip):
    # frame_prep._is_gray says gray exactly where R = G = B everywhere (the fourth channel aside):
    # one pixel's channel changed anywhere (off the rows it samples first too) makes it colour;
    # 8-, 16-bit and float frames, RGBA, a view that is not contiguous; a NaN is no match
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max if np.dtype(dtype).kind == "u" else 1.0
    img = np.repeat(rng.integers(0, top, (h, w, 1), endpoint=True).astype(dtype), channels, axis=2)
    if channels == 4:
        img[..., 3] = rng.integers(0, top, (h, w), endpoint=True)
    if channel >= 0:
        r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
        img[r, c, channel] = img[r, c, channel] ^ 1 if np.dtype(dtype).kind == "u" else np.nan
    want = channel < 0
    assert _is_gray(img) is want
    assert _is_gray(img[:, ::-1] if flip else img[::-1]) is want


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(16, 80), w=st.integers(16, 80))
def test_the_scope_border_from_the_frames_2x2_means_is_its_own(seed, h, w):
    """``_scope_border`` given the means of the gray's 2 x 2 blocks (``local_peak_mask``'s first
    reduction) reduces from them: the same border as from the gray itself, on frames with a dark
    ring and odd sides (the rows and columns no 4 x 4 block fills are left out alike)."""
    from simtest.reconstruct.detect_pixels import _area_reduced, _scope_border

    rng = np.random.default_rng(seed)
    h, w = 2 * h + int(rng.integers(0, 2)), 2 * w + int(rng.integers(0, 2))
    yy, xx = np.mgrid[:h, :w]
    inside = (yy - h / 2) ** 2 / (h / 2) ** 2 + (xx - w / 2) ** 2 / (w / 2) ** 2 < rng.uniform(0.6, 1.2)
    gray = np.where(inside, rng.uniform(60, 255, (h, w)), rng.uniform(0, 10, (h, w))).astype(np.float32)
    half = _area_reduced(np.ascontiguousarray(gray[: h // 2 * 2, : w // 2 * 2]), 2)
    own, given_half = _scope_border(gray, 20.0), _scope_border(gray, 20.0, half)
    assert (own is None) == (given_half is None)
    if own is not None:
        assert np.array_equal(own, given_half)


def test_detection_gives_the_native_grays_2x2_means_where_it_reduced_it_unsmoothed():
    """A frame detected at full resolution without smoothing hands the verifier the means of its
    gray's 2 x 2 blocks (``Detection.half``, from ``local_peak_mask``); a smoothed one does not
    (those would be the smoothed gray's)."""
    from benchmarks.inputs import synthetic_frame

    img, _, _ = synthetic_frame()
    det = detect_specularities(img, method="local_peak", smooth_sigma_px=0.0)
    g = det.gray.astype(np.float32)
    ref = cv2.resize(g, (g.shape[1] // 2, g.shape[0] // 2), interpolation=cv2.INTER_AREA)
    assert det.half is not None and not det.half.flags.writeable
    np.testing.assert_array_equal(det.half, ref)
    assert detect_specularities(img, method="local_peak", smooth_sigma_px=1.0).half is None


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(3, 400), w=st.integers(8, 120),
       kind=st.sampled_from(["uint8", "float32", "float64", "flat"]))
def test_noise_level_table_is_its_definition(seed, h, w, kind):
    """``noise_level_table`` (bins selected by a sort, medians by ``np.median``) equals its
    definition: each bin's samples gathered by a stable sort and ``np.median``'s MAD, on integer
    (ties), float and partly flat frames."""
    from simtest.decisions import NOISE_LEVEL_BINS, NOISE_LEVEL_MIN_SAMPLES
    from simtest.reconstruct.detect_pixels import _level_bin, noise_level_table

    rng = np.random.default_rng(seed)
    gray = rng.normal(128.0, 20.0, (h, w)) + np.linspace(-120, 120, w)[None]
    if kind == "flat":
        gray[:, : w // 2] = 40.0
    gray = np.clip(np.round(gray) if kind in ("uint8", "flat") else gray, 0, 255).astype(
        np.float64 if kind == "float64" else np.float32)
    g = gray[:: max(1, h // 192)].astype(np.float32)
    d = (g[:, 1:-1] - 0.5 * (g[:, :-2] + g[:, 2:])).ravel()
    k = _level_bin((g[:, 1:-1] + g[:, :-2] + g[:, 2:]).ravel() / 3.0, 255.0)
    d = d[np.argsort(k, kind="stable")]
    ends = np.cumsum(np.bincount(k, minlength=NOISE_LEVEL_BINS))
    want = np.full(NOISE_LEVEL_BINS, np.nan)
    for b in range(NOISE_LEVEL_BINS):
        db = d[ends[b] - np.bincount(k, minlength=NOISE_LEVEL_BINS)[b]:ends[b]]
        if len(db) >= NOISE_LEVEL_MIN_SAMPLES:
            want[b] = 1.4826 * float(np.median(np.abs(db - np.median(db)))) / np.sqrt(1.5)
    got = noise_level_table(gray, 255.0, 1.5)
    full = np.flatnonzero(want > 0)
    if not len(full):
        assert np.array_equal(got, np.full(NOISE_LEVEL_BINS, 1.5))
        return
    t = np.pad(want[full[np.abs(np.arange(NOISE_LEVEL_BINS)[:, None] - full[None, :]).argmin(1)]], 1, mode="edge")
    assert np.array_equal(got, np.maximum(np.maximum(t[:-2], t[1:-1]), t[2:]))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.2, 0.7), st.floats(0.0, 0.2))
def test_a_broken_tops_pieces_are_the_masks_pieces_joined_to_the_ceiling(seed, p_mask, p_seed):
    # candidates._joined is morphological reconstruction by dilation (8-connected) of the ceiling
    # pixels under the near-ceiling mask: scikit-image's, on random masks, exactly
    from skimage.morphology import reconstruction

    from simtest.reconstruct.candidates import _joined

    rng = np.random.default_rng(seed)
    mask = (rng.random((23, 31)) < p_mask).astype(np.uint8)
    seed_px = mask & (rng.random(mask.shape) < p_seed).astype(np.uint8)
    want = reconstruction(seed_px, mask, method="dilation", footprint=np.ones((3, 3)))
    assert np.array_equal(_joined(seed_px, mask), want.astype(np.uint8))


def test_near_ceiling_pixels_need_the_luma_near_the_ceiling_too():
    # CLIP_LUMA_MARGIN_REL: every channel within 4 % of the ceiling is not enough where the luma
    # falls more than 1 % below it (a sheen); a grey frame's luma is its value, the same bar
    from simtest.decisions import CLIP_LUMA_MARGIN_REL, CLIP_MARGIN_REL
    from simtest.reconstruct.detect_pixels import near_ceiling_mask

    low = int(np.ceil(255 * (1 - CLIP_MARGIN_REL)))       # every channel just within the margin
    edge = int(np.ceil(255 * (1 - CLIP_LUMA_MARGIN_REL)))  # the luma's bar
    img = np.array([[[255, 255, 255], [low, low, low], [edge, edge, edge], [255, 255, low]]], np.uint8)
    assert near_ceiling_mask(img, 255.0).tolist() == [[1, 0, 1, 1]]
    assert near_ceiling_mask(img, 255.0, grey=True, gray=img[..., 0].copy()).tolist() == [[1, 0, 1, 1]]


@pytest.mark.parametrize("method", ["local_peak", "full_scale"])
def test_a_top_the_codec_left_one_pixel_of_is_read_whole(method):
    # JPEG at q70 may keep a single pixel of a clipped top at 255 in every channel, anywhere on
    # it (an independent generator's frames: the BP 5.8 px off, one guide's highlight missed): the
    # top is the near-ceiling pixels joined to it, whatever the number of pieces at the ceiling
    yy, xx = np.mgrid[0:100, 0:120]
    g = 150.0 + 100.0 * np.exp(-((xx - 50.0) ** 2 + (yy - 40.0) ** 2) / (2 * 12.0 ** 2))
    top = (xx - 50.0) ** 2 + (yy - 40.0) ** 2 <= 8.0 ** 2
    g[top] = 253.0  # luma within CLIP_LUMA_MARGIN_REL, every channel within CLIP_MARGIN_REL
    img = np.repeat(np.rint(g).astype(np.uint8)[..., None], 3, axis=2)
    img[40, 57] = 255  # what stays at the ceiling, at the top's edge
    (cand,) = [c for c in detect_specularities(img, method=method).candidates if c.saturated]
    # the disc's centroid on the pixel grid (symmetric about (50, 40))
    assert np.hypot(cand.bp_uv[0] - 50.0, cand.bp_uv[1] - 40.0) < 0.5, cand.bp_uv


@given(seed=st.integers(0, 2**32 - 1), radius=st.integers(3, 9))
@settings(max_examples=30, deadline=None)
def test_a_near_clipped_top_gives_the_centroid_of_its_pixels_over_the_limit(seed, radius):
    """``_top_centroids``: whichever pixel of a top over the limit is its brightest (noise decides
    on a flat top), the BP is the centroid of the top's pixels connected to it; a top of one
    pixel keeps the BP given."""
    from simtest.reconstruct.candidates import _top_centroids

    rng = np.random.default_rng(seed)
    h = w = 2 * radius + 9
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = rng.uniform(radius + 3, h - radius - 4, 2)
    disc = (yy - cy) ** 2 + (xx - cx) ** 2 <= radius**2
    gray = np.where(disc, 253.0 + rng.uniform(0, 1, (h, w)), 200.0)
    gray[0, 0] = 254.5  # over the limit but not connected to the top: left out
    idx, k = np.arange(h * w), np.zeros(h * w, np.int64)  # one candidate: the whole box
    rows, level, given = np.array([0]), np.array([252.45]), np.array([-1.0])
    pix = np.array([int(np.argmax(np.where(disc, gray, -1)))])
    row, col = _top_centroids(gray, rows, idx, k, level, pix, given, given)
    rr, cc = np.nonzero(disc)
    assert (row[0], col[0]) == pytest.approx((rr.mean(), cc.mean()), abs=1e-12)
    one = np.full((h, w), 200.0)
    one[5, 5] = 254.0
    got = _top_centroids(one, rows, idx, k, level, np.array([5 * w + 5]), np.array([5.2]), np.array([4.9]))
    assert (got[0][0], got[1][0]) == (5.2, 4.9)


def test_clipped_tops_on_a_sheen_near_the_ceiling_are_candidates():
    # two small tops clipped at 255 on a broad sheen at 240: they stand 15 levels above the
    # background square's opening, under TOPHAT_MIN_REL (0.08 of 255: 20.4), so the contrast rule
    # alone drops them; given as clipped (the ceiling cut their height), they are the mask
    from simtest.reconstruct.detect_pixels import local_peak_mask

    g = np.full((120, 160), 120.0, np.float32)
    yy, xx = np.mgrid[0:120, 0:160]
    g[np.hypot(yy - 60, xx - 80) < 45] = 240.0
    tops = (np.hypot(yy - 60, xx - 65) < 4) | (np.hypot(yy - 60, xx - 95) < 4)
    g[tops] = 255.0
    plain, _ = local_peak_mask(g, 255.0, background_px=31)
    censored, _ = local_peak_mask(g, 255.0, background_px=31, censored=tops.astype(np.uint8))
    # (the sheen's rim is in both: the reduced opening, enlarged, smears its 120-level edge)
    assert not plain[tops].any()
    assert np.array_equal(censored.astype(bool), plain.astype(bool) | tops)


# --- broad lobes: the reduced look before a detection on a wider background square ---------------

_WIDE = dict(side=216, wider_than=72.0, core_min_px=36.0, isovalue=0.7)  # a 960 x 720 frame's squares


def _wide_boxes(img):
    return wide_lobe_boxes(img.astype(np.float32), 1.0, _WIDE["side"], _WIDE["wider_than"], _WIDE["core_min_px"],
                           _WIDE["isovalue"])


@pytest.mark.parametrize("sigma, found", [(50.0, True), (10.0, False)])
def test_a_lobe_wider_than_the_narrow_square_gets_a_box_around_its_peak(sigma, found):
    # a Gaussian lobe on a flat background: its 0.6 level spans 2 sigma sqrt(2 ln(1 / 0.6)) = 2.02
    # sigma (101 px for sigma 50, wider than 72; 20 px for sigma 10) and its 0.7 core 1.69 sigma
    centre = (430.0, 350.0)
    img = 0.2 + gaussian((720, 960), centre, sigma, 0.6)
    boxes = _wide_boxes(img)
    if not found:
        assert len(boxes) == 0
        return
    assert len(boxes) == 1
    r0, r1, c0, c1 = boxes[0]
    assert r0 <= centre[1] < r1 and c0 <= centre[0] < c1
    # the box holds the 0.6 level (2.02 sigma across), widened by one reduced pixel (72 // 16 = 4 px) and
    # rounded to the reduced grid (4 px more)
    assert 2.02 * sigma - 8 <= max(r1 - r0, c1 - c0) <= 2.02 * sigma + 16


def test_a_glint_on_a_wide_pale_plateau_has_too_small_a_core_for_a_box():
    # a flat-topped pale patch 160 px across at 0.62 of the glint's height, and a glint (sigma 3 px)
    # at its middle: the 0.6 level holds the whole patch (wide), the 0.7 core only the glint (small)
    v, u = np.mgrid[0:720, 0:960].astype(float)
    patch = 0.31 / (1.0 + np.exp((np.hypot(u - 480, v - 360) - 80.0) / 2.0))
    img = 0.2 + patch + gaussian((720, 960), (480.0, 360.0), 3.0, 0.19)
    assert len(_wide_boxes(img)) == 0
    # the same patch without the glint is a broad top of its own, and gets its box
    assert len(_wide_boxes(0.2 + patch)) == 1


@given(r0=st.integers(0, 500), c0=st.integers(0, 500), bh=st.integers(1, 300), bw=st.integers(1, 300),
       margin=st.integers(0, 200), grid=st.integers(1, 40), h=st.integers(1, 900), w=st.integers(1, 900))
@settings(max_examples=200, deadline=None)
def test_a_broad_lobes_region_holds_its_box_and_margin_on_the_reduced_grid(r0, c0, bh, bw, margin, grid, h, w):
    # the region detected again around a broad lobe: the box and its margin (within the frame), its
    # corners on the wider square's reduced grid unless at the frame's edge, so that the region's
    # reduction has the frame's block boundaries
    from simtest.reconstruct.broad_lobes import _aligned_crop

    box = np.array([r0, min(r0 + bh, h), c0, min(c0 + bw, w)])
    crop = _aligned_crop(box, margin, grid, (h, w))
    assert crop.row0 <= max(0, box[0] - margin) and crop.row1 >= min(h, box[1] + margin)
    assert crop.col0 <= max(0, box[2] - margin) and crop.col1 >= min(w, box[3] + margin)
    assert 0 <= crop.row0 and crop.row1 <= h and 0 <= crop.col0 and crop.col1 <= w
    assert crop.row0 % grid == 0 and crop.col0 % grid == 0
    assert crop.row1 in (h,) or crop.row1 % grid == 0
    assert crop.col1 in (w,) or crop.col1 % grid == 0
    # and no wider than a grid step past the margin
    assert crop.row0 > box[0] - margin - grid and crop.col0 > box[2] - margin - grid
