"""The compiled window kernels of issue 41 against the OpenCV and numpy passes they replace:
:func:`simtest.reconstruct._kernels.maxima_in_windows` (the verifier's enlarged background,
top-hat and 3 x 3 maxima in windows) and
:func:`simtest.reconstruct._detect_kernels.window_component` (the half-resolution detection's
mask and component at full resolution)."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.constants import gaussian_radius_px
from simtest.reconstruct import _detect_kernels as dk
from simtest.reconstruct import _kernels, verify


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), f=st.integers(2, 6), sh=st.integers(3, 9), sw=st.integers(3, 9),
       n=st.integers(0, 4), dtype=st.sampled_from([np.uint8, np.float32]))
def test_maxima_in_windows_is_the_upsampled_top_hat_maxima(seed, f, sh, sw, n, dtype):
    """The same maxima as ``verify._upsampled`` + ``verify._maxima_windows``, and the top-hat
    inside the windows to float32 rounding of the bilinear weights (OpenCV rounds its own: 1e-3
    grey levels is 2^-18 of the 255 levels' range, a few float32 ulps)."""
    rng = np.random.default_rng(seed)
    h, w = sh * f, sw * f
    gray = (rng.integers(0, 256, (h, w)) if dtype == np.uint8 else rng.random((h, w)) * 255).astype(dtype)
    bg_small = (rng.random((sh, sw)) * 128).astype(np.float32)
    r0 = rng.integers(0, h, n)
    c0 = rng.integers(0, w, n)
    win = np.c_[r0, np.minimum(h, r0 + rng.integers(1, h, n)), c0, np.minimum(w, c0 + rng.integers(1, w, n))]
    win = np.ascontiguousarray(win.astype(np.int64).reshape(-1, 4))
    floor = np.float32(10.0)
    wide = np.c_[np.maximum(win[:, 0] - 1, 0), np.minimum(win[:, 1] + 1, h),
                 np.maximum(win[:, 2] - 1, 0), np.minimum(win[:, 3] + 1, w)]
    bg = verify._upsampled(bg_small, f, (h, w), wide)
    top0, ys0, xs0 = verify._maxima_windows(gray, bg, floor, win)
    top = np.empty((h, w), np.float32)
    flat = _kernels.maxima_in_windows(gray, bg_small, win, floor, top)
    inside = np.zeros((h, w), bool)
    for a, b, c, d in win:
        inside[a:b, c:d] = True
    np.testing.assert_allclose(top[inside], top0[inside], atol=1e-3)
    # a maximum whose top-hat ties a neighbour's within the rounding may differ: none here
    # (random values tie with probability ~1e-6)
    assert np.array_equal(flat, ys0 * w + xs0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), sigma=st.floats(1.0, 3.0), r0=st.integers(0, 40), c0=st.integers(0, 40),
       nr=st.integers(5, 40), nc=st.integers(5, 40))
def test_window_component_is_the_frames_mask_and_component(seed, sigma, r0, c0, nr, nc):
    """The window's smoothing is the whole frame's (``cv2.GaussianBlur``, BORDER_REFLECT) to
    float32 rounding (1e-3 of 255 grey levels), and the component is OpenCV's 8-connected
    component of the frame's mask at the brightest mask pixel near the given one, where no mask
    pixel is within that rounding of its threshold."""
    rng = np.random.default_rng(seed)
    h, w = 80, 84
    native = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 2.0).astype(np.uint8)
    r1, c1 = min(h, r0 + nr), min(w, c0 + nc)
    bg_small = (rng.random((h // 4, w // 4)) * 100).astype(np.float32)
    peak_small = (rng.random((h // 4, w // 4)) * 60).astype(np.float32)
    kern = cv2.getGaussianKernel(2 * gaussian_radius_px(sigma) + 1, sigma).astype(np.float32).ravel()
    full = cv2.GaussianBlur(native.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    bgf = np.minimum(cv2.resize(bg_small, (w, h), interpolation=cv2.INTER_LINEAR), full)
    top = full - bgf
    lp = cv2.resize(peak_small, (w, h), interpolation=cv2.INTER_LINEAR)
    peak_rel, thr = np.float32(0.6), np.float32(5.0)
    mask = ((top >= peak_rel * np.maximum(lp, top)) & (top >= thr)).astype(np.uint8)[r0:r1, c0:c1]
    gr, gc = (r1 - r0) // 2, (c1 - c0) // 2
    g = np.empty((r1 - r0, c1 - c0), np.float32)
    bg = np.empty_like(g)
    lab = np.empty(g.shape, np.int32)
    found, x, y, bw, bh, area = dk.window_component(native, r0, r1, c0, c1, kern, bg_small, peak_small,
                                                     peak_rel, thr, gr, gc, g, bg, lab)
    np.testing.assert_allclose(g, full[r0:r1, c0:c1], atol=1e-3)
    np.testing.assert_allclose(bg, bgf[r0:r1, c0:c1], atol=1e-3)
    t = top[r0:r1, c0:c1]
    margin = np.minimum(np.abs(t - thr), np.abs(t - peak_rel * np.maximum(lp[r0:r1, c0:c1], t)))
    if (margin < 1e-2).any():
        return  # a pixel within the rounding of a threshold: the masks may differ there
    near = mask[max(0, gr - 2):gr + 3, max(0, gc - 2):gc + 3]
    assert found == bool(near.any())
    if not found:
        return
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    core = np.where(near.view(bool), g[max(0, gr - 2):gr + 3, max(0, gc - 2):gc + 3], -np.inf)
    pr, pc = divmod(int(np.argmax(core)), core.shape[1])
    k = labels[max(0, gr - 2) + pr, max(0, gc - 2) + pc]
    assert (x, y, bw, bh, area) == tuple(int(v) for v in stats[k])
    assert np.array_equal(lab == 1, labels == k)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), f=st.integers(2, 6), sh=st.integers(4, 20), sw=st.integers(4, 20))
def test_top_hat_and_peak_mask_rows_are_the_enlarged_frames(seed, f, sh, sw):
    """The compiled passes with the enlargement down the columns done inside them give OpenCV's
    full-size enlargement to float32 rounding (1e-3 of 255 grey levels): the background (in the
    rows with a candidate when asked for those only), the top-hat, and the mask wherever no
    pixel lies within that rounding of a threshold."""
    from simtest.reconstruct import detect

    rng = np.random.default_rng(seed)
    h, w = sh * f, sw * f
    g = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 1.0)
    side = 16 * f + rng.integers(0, 16)
    mask, background = detect.local_peak_mask(g, 255.0, background_px=int(side))
    mask_r, background_r = detect.local_peak_mask(g, 255.0, background_px=int(side), _hit_rows_only=True)
    # the reference: OpenCV's full-size enlargements (local_peak_mask before issue 41's passes)
    k = max(3, int(side) // f)
    k += 1 - k % 2
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg_small = cv2.morphologyEx(detect._area_reduced(g, f), cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)
    bg = np.minimum(cv2.resize(bg_small, (w, h), interpolation=cv2.INTER_LINEAR), g)
    top = g - bg
    peak = cv2.dilate(detect._area_reduced(top, f), kernel, borderType=cv2.BORDER_REPLICATE)
    lp = cv2.resize(peak, (w, h), interpolation=cv2.INTER_LINEAR)
    thr, rel = np.float32(0.08 * 255), np.float32(0.6)
    want = ((top >= rel * np.maximum(lp, top)) & (top >= thr)).astype(np.uint8)
    np.testing.assert_allclose(background, bg, atol=1e-3)
    hit = (top >= thr).any(axis=1)
    np.testing.assert_allclose(background_r[hit], bg[hit], atol=1e-3)
    near = (np.abs(top - thr) < 1e-2) | (np.abs(top - rel * np.maximum(lp, top)) < 1e-2)
    assert np.array_equal(mask[~near], want[~near]) and np.array_equal(mask_r, mask)
