"""The pixel work of the verifier (:mod:`simtest.reconstruct.verify`) by OpenCV and numpy calls:
openings, top-hat maxima, colour at points, flat panels, neighbouring peaks and the lit surround.
The decision numbers come in as arguments.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from simtest.decisions import WHITE_CHROMA, WHITE_SHARE_MIN
from simtest.geometry.response import srgb_inverse
from simtest.reconstruct.detect_pixels import (connected_components, connected_components_with_stats, linear_at,
                                              linear_taps, mask_labels)

#: A 3 x 3 square: the neighbourhood of a local maximum.
_SQUARE3 = np.ones((3, 3), np.uint8)


def block_means(img: np.ndarray, f: int) -> np.ndarray:
    """Means (H / f, W / f[, C]) float32 of the f x f blocks of an image whose sides are multiples of f,
    as ``cv2.resize``'s INTER_AREA reduction.
    """
    h, w = img.shape[:2]
    if img.dtype != np.uint8 or f > 16 or f == 1:
        x = img.astype(np.float32, copy=False)
        return cv2.resize(x, (w // f, h // f), interpolation=cv2.INTER_AREA) if f > 1 else x
    c = img.shape[2] if img.ndim == 3 else 1
    rows = np.ascontiguousarray(img).reshape(h // f, f, w * c).sum(axis=1, dtype=np.uint16).astype(np.float32)
    rows *= np.float32(1.0 / f)
    return cv2.resize(rows.reshape(h // f, w, c) if c > 1 else rows, (w // f, h // f), interpolation=cv2.INTER_AREA)


def _open(small: np.ndarray, side: int, f: int) -> np.ndarray:
    k = max(3, side // f)
    k += 1 - k % 2
    return cv2.morphologyEx(small, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)),
                            borderType=cv2.BORDER_REPLICATE)


def opening(img: np.ndarray, side: int) -> np.ndarray:
    """Grey opening by a square of ``side`` px on the image reduced so that the square is ~16 px
    (as :func:`~simtest.reconstruct.detect.local_peak_mask`), back to full size; float32."""
    h, w = img.shape[:2]
    f = max(1, side // 16)
    if f > 1 and h % f == 0 and w % f == 0:
        small = block_means(img, f)
    else:
        x = img.astype(np.float32, copy=False)
        small = cv2.resize(x, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA) if f > 1 else x
    bg = _open(small, side, f)
    return cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR) if f > 1 else bg


def opening_small(img: np.ndarray, side: int, half: np.ndarray | None = None, *, exact: bool = True):
    """:func:`opening` before its last step: ``(bg_small, f)``, the opening on the image reduced by
    ``f > 1`` where the sides are multiples of f, else ``(the full-size opening, 1)``, or with ``exact``
    False the opening on the image reduced to ``(H // f, W // f)`` by INTER_AREA at any size (as
    :func:`~simtest.reconstruct.detect.local_peak_mask`; enlarged by the same taps within 2e-5 of
    :func:`opening`'s). ``half``: the image's 2 x 2 block means where the caller has them.
    """
    h, w = img.shape[:2]
    f = max(1, side // 16)
    if f > 1 and (h % f or w % f) and not exact:
        small = cv2.resize(img.astype(np.float32, copy=False), (max(1, w // f), max(1, h // f)),
                           interpolation=cv2.INTER_AREA)
        return _open(small, side, f), f
    if f == 1 or h % f or w % f:
        return opening(img, side), 1
    if half is not None and f % 2 == 0 and half.shape == (h // 2, w // 2):
        small = half if f == 2 else cv2.resize(np.ascontiguousarray(half), (w // f, h // f),
                                               interpolation=cv2.INTER_AREA)
    else:
        small = block_means(img, f)
    return _open(small, side, f), f


def linear_at_points(small: np.ndarray, shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``cv2.resize(small, shape[::-1], interpolation=cv2.INTER_LINEAR)[rows, cols]`` at those pixels only."""
    sh, sw = small.shape[:2]
    h, w = shape

    y0, y1, ay = linear_taps(rows, sh, h)
    x0, x1, ax = linear_taps(cols, sw, w)
    if small.ndim == 3:
        ax, ay = ax[:, None], ay[:, None]
    one = np.float32(1.0)
    top = small[y0, x0] * (one - ax) + small[y0, x1] * ax
    bot = small[y1, x0] * (one - ax) + small[y1, x1] * ax
    return top * (one - ay) + bot * ay


def top_hat_maxima(g: np.ndarray, bg: np.ndarray, floor: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """The top-hat ``max(g - bg, 0)`` (float32) and a bool mask of its 3 x 3 local maxima above ``floor``."""
    top = np.subtract(g, bg, dtype=np.float32)
    np.maximum(top, np.float32(0.0), out=top)
    peak = cv2.dilate(top, _SQUARE3, borderType=cv2.BORDER_REPLICATE)
    return top, (top >= peak) & (top > floor)


def maxima_in_windows(g: np.ndarray, bg_small: np.ndarray, f: int, windows: np.ndarray,
                      floor: np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`top_hat_maxima` in the ``windows`` (row0, row1, col0, col1) only: a frame-sized top-hat
    exact inside them and the maxima inside them (rows, columns), the whole frame's there.
    """
    h, w = g.shape
    top = np.empty((h, w), np.float32)
    idx = []
    for r0, r1, c0, c1 in np.asarray(windows, np.int64).reshape(-1, 4).tolist():
        if r1 <= r0 or c1 <= c0:
            continue
        e0, e1, f0, f1 = max(0, r0 - 1), min(h, r1 + 1), max(0, c0 - 1), min(w, c1 + 1)
        bg = linear_at(bg_small, (h, w), e0, e1, f0, f1) if f > 1 else bg_small[e0:e1, f0:f1]
        t, mk = top_hat_maxima(g[e0:e1, f0:f1], bg, floor)
        top[r0:r1, c0:c1] = t[r0 - e0 : r1 - e0, c0 - f0 : c1 - f0]
        yy, xx = np.nonzero(mk[r0 - e0 : r1 - e0, c0 - f0 : c1 - f0])
        idx.append((yy + r0).astype(np.int64) * w + (xx + c0))
    flat = np.unique(np.concatenate(idx)) if idx else np.zeros(0, np.int64)
    ys, xs = np.divmod(flat, w)
    return top, ys, xs


def in_windows(ys: np.ndarray, xs: np.ndarray, shape: tuple[int, int], windows: np.ndarray) -> np.ndarray:
    """Whether each pixel (``ys``, ``xs``) lies in one of the ``windows`` (row0, row1, col0, col1); bool."""
    marks = np.zeros(shape, np.uint8)
    for r0, r1, c0, c1 in np.asarray(windows, np.int64).reshape(-1, 4).tolist():
        marks[r0:r1, c0:c1] = 1
    return marks[ys, xs] != 0


def rgb_at(src3: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The (P, 3) float64 colour at pixels of an (H, W, C) image (C = 1: the channel as three)."""
    v = src3[rows, cols].astype(np.float64)
    return np.repeat(v, 3, axis=1) if v.shape[1] == 1 else v[:, :3]


def rgb_max9(src3: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The channel-wise maximum over the 3 x 3 px around each pixel, (P, 3) float64."""
    h, w = src3.shape[:2]
    out = None
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            v = rgb_at(src3, np.clip(rows + dr, 0, h - 1), np.clip(cols + dc, 0, w - 1))
            out = v if out is None else np.maximum(out, v)
    return out


def chroma(rgb: np.ndarray) -> np.ndarray:
    """``1 - min / max`` over the last axis (3 channels), the max floored at 1e-9."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mx = np.maximum(np.maximum(r, g), b)
    return 1.0 - np.minimum(np.minimum(r, g), b) / np.maximum(mx, 1e-9)


@functools.lru_cache(maxsize=64)
def _variance_below(std_max: float) -> np.float32:
    """The least float32 variance v >= 0 whose float32 square root is not below ``std_max``."""
    s = np.float32(std_max)
    lo, hi = 0, int(np.array(np.inf, np.float32).view(np.uint32))  # sqrt(+inf) = +inf >= s
    while lo < hi:
        mid = (lo + hi) // 2
        if np.sqrt(np.array(mid, np.uint32).view(np.float32)) >= s:
            hi = mid
        else:
            lo = mid + 1
    return np.array(lo, np.uint32).view(np.float32)[()]


def flat_mask(gray: np.ndarray, std_max, full_scale: float | None = None) -> np.ndarray:
    """Pixels whose 5 x 5 luma standard deviation is below ``std_max`` (a number, or with
    ``full_scale`` a table over the noise level bins), uint8 0/1.
    """
    g = gray.astype(np.float32, copy=False)
    m1 = cv2.blur(g, (5, 5))
    var = cv2.blur(g * g, (5, 5))
    # the variance against the square of std_max's bound (none below one not positive): no root
    bound = np.float32([_variance_below(float(v)) if np.float32(v) > 0 else -np.inf for v in np.atleast_1d(std_max)])
    if full_scale is not None:  # each pixel's bin (the floor of its scaled mean, the last past it), its bound
        lut = np.concatenate([bound, np.full(256 - len(bound), bound[-1], np.float32)])  # cv2.LUT: 4x numpy's take
        bound = cv2.LUT((m1 * np.float32(len(bound) / full_scale)).astype(np.uint8), lut)
    # in place: each frame-sized temporary costs its page faults
    np.subtract(var, np.multiply(m1, m1, out=m1), out=var)
    return np.less(var, bound if full_scale is not None else bound[0]).view(np.uint8)


#: Clipped-and-flat pixels within this many px share one window of :func:`drop_clipped` (speed only).
_HIT_JOIN_PX = 8


def drop_clipped(flat: np.ndarray, rgb: np.ndarray, std_max, ceiling: float, full_scale: float | None = None) -> np.ndarray:
    """The flat pixels ``flat`` less those at ``ceiling`` in every channel of ``rgb`` (the sensor's clip, not a
    drawing) and those whose 5 x 5 window holds a channel there unless every channel is flat (a clip has no noise)."""
    chans = cv2.split(np.ascontiguousarray(rgb))
    top = functools.reduce(cv2.max, chans)  # the channel maximum: numpy's any over the last axis is 20x slower
    clip = np.greater_equal(top, ceiling).view(np.uint8)
    if not clip.any():
        return flat
    flat = cv2.bitwise_and(flat, np.less(functools.reduce(cv2.min, chans), ceiling).view(np.uint8))
    near = cv2.dilate(clip, np.ones((5, 5), np.uint8))
    hit = flat & near
    if not hit.any():
        return flat
    # the channels' flatness only around the pixels it decides, cluster by cluster (2 px of context)
    h, w = flat.shape
    out = flat.copy()
    join = np.ones((2 * _HIT_JOIN_PX + 1,) * 2, np.uint8)
    for x, y, bw, bh in mask_labels(cv2.dilate(hit, join))[2][:, :4].tolist():
        r0, r1, c0, c1 = y, y + bh, x, x + bw
        R0, R1, C0, C1 = max(0, r0 - 2), min(h, r1 + 2), max(0, c0 - 2), min(w, c1 + 2)
        every = flat[r0:r1, c0:c1].copy()
        for c in chans:
            every &= flat_mask(c[R0:R1, C0:C1], std_max, full_scale)[r0 - R0:r1 - R0, c0 - C0:c1 - C0]
        np.copyto(out[r0:r1, c0:c1], every, where=hit[r0:r1, c0:c1] != 0)
    return out


def panels(gray: np.ndarray, std_max, min_area: float, rgb: np.ndarray | None = None,
           ceiling: float | None = None, full_scale: float | None = None) -> np.ndarray:
    """Flat panels: the 8-connected components of :func:`flat_mask` of at least ``min_area`` px, uint8
    0/1 (next to a clipped channel, flat in every channel: :func:`drop_clipped`).
    """
    flat = flat_mask(gray, std_max, full_scale)
    if rgb is not None and ceiling is not None and np.count_nonzero(flat) >= min_area:
        flat = drop_clipped(flat, rgb, std_max, ceiling, full_scale)
    if np.count_nonzero(flat) < min_area:
        return np.zeros_like(flat)
    # labels alone and their areas by counting (OpenCV's statistics cost more than its labels)
    n, lab = connected_components(flat)
    big = (np.bincount(lab.ravel(), minlength=n) >= min_area).astype(np.uint8)
    big[0] = 0
    if not big.any():
        return np.zeros_like(flat)
    return np.take(big, lab)


def pixels_in(p: np.ndarray, rr: np.ndarray) -> np.ndarray:
    """How many set pixels of the 0/1 mask ``p`` (H, W) each region ``rr`` (row0, row1, col0, col1) holds,
    int64 (n,)."""
    rr = np.asarray(rr, np.int64).reshape(-1, 4)
    if not p.any():
        return np.zeros(len(rr), np.int64)
    s = cv2.integral(p, sdepth=cv2.CV_32S)
    r0, r1, c0, c1 = rr.T
    # the corners read first, then widened (no int64 copy of the frame's sums)
    return (s[r1, c1].astype(np.int64) - s[r0, c1] - s[r1, c0]) + s[r0, c0]


def surely_no_panels(gray: np.ndarray, rr: np.ndarray, margin: int, thr2, slack: float,
                     min_area: float, full_scale: float | None = None) -> bool:
    """Whether no pixel of any region ``rr`` can be a panel pixel, True only when proven without the
    frame: every component of a superset of the flat pixels (5 x 5 float64 variance below
    ``thr2 + slack * m2``) reaching into a region within ``margin`` px is under ``min_area`` and not
    cut by the window's edge inside the frame.
    """
    h, w = gray.shape
    # each level bin's bound and its neighbours' largest (a 3-wide maximum, the ends repeated)
    t2 = cv2.dilate(np.atleast_1d(np.asarray(thr2, np.float64)).reshape(1, -1), np.ones((1, 3), np.uint8),
                    borderType=cv2.BORDER_REPLICATE).ravel()
    for row0, row1, col0, col1 in np.asarray(rr, np.int64).reshape(-1, 4).tolist():
        wr0, wr1, wc0, wc1 = max(0, row0 - margin), min(h, row1 + margin), max(0, col0 - margin), min(w, col1 + margin)
        cr0, cr1, cc0, cc1 = max(0, wr0 - 2), min(h, wr1 + 2), max(0, wc0 - 2), min(w, wc1 + 2)
        x = gray[cr0:cr1, cc0:cc1].astype(np.float32).astype(np.float64)
        if not np.isfinite(x).all():
            return False
        m1 = cv2.blur(x, (5, 5))[wr0 - cr0 : wr1 - cr0, wc0 - cc0 : wc1 - cc0]
        m2 = cv2.blur(x * x, (5, 5))[wr0 - cr0 : wr1 - cr0, wc0 - cc0 : wc1 - cc0]
        bound = t2[0] if full_scale is None else t2[np.clip((m1 * (len(t2) / full_scale)).astype(np.int64), 0, len(t2) - 1)]
        maybe = ((m2 - m1 * m1) < bound + slack * m2).view(np.uint8)
        roi = maybe[row0 - wr0 : row1 - wr0, col0 - wc0 : col1 - wc0]
        if not roi.any():
            continue
        n, lab, stats, _ = connected_components_with_stats(np.ascontiguousarray(maybe))
        ids = np.flatnonzero(np.bincount(lab[row0 - wr0 : row1 - wr0, col0 - wc0 : col1 - wc0].ravel(), minlength=n))
        st = stats[ids[ids > 0]]
        x0, y0 = st[:, cv2.CC_STAT_LEFT], st[:, cv2.CC_STAT_TOP]
        x1, y1 = x0 + st[:, cv2.CC_STAT_WIDTH], y0 + st[:, cv2.CC_STAT_HEIGHT]
        cut = (((x0 == 0) & (wc0 > 0)) | ((y0 == 0) & (wr0 > 0)) | ((x1 == wc1 - wc0) & (wc1 < w))
               | ((y1 == wr1 - wr0) & (wr1 < h)))
        if cut.any() or (st[:, cv2.CC_STAT_AREA] >= min_area).any():
            return False
    return True


def ellipse_level(ell, u, v):
    """``(x / a)^2 + (y / b)^2`` of points (u, v) px in the ellipse's own axes: at most 1 inside it."""
    c, s = np.cos(ell.angle_rad), np.sin(ell.angle_rad)
    du, dv = u - ell.center[0], v - ell.center[1]
    a, b = ell.semi_axes
    return ((c * du + s * dv) / a) ** 2 + ((-s * du + c * dv) / b) ** 2


def other_peaks(top: np.ndarray, xs: np.ndarray, ys: np.ndarray, bps: np.ndarray, ij: np.ndarray,
                reach: np.ndarray, min_top: np.ndarray, level: np.ndarray, ellipses, area_rel: float,
                expected=None, tol_px: float = 0.0) -> np.ndarray:
    """Per candidate, how many specular peaks (int64 (n,)) lie within ``reach`` of its BP.

    A peak counts with a top-hat of at least ``min_top``, outside the candidate's isophote
    ``ellipses[k]``, not joined to it above ``level``, with a region above ``level`` of at least
    ``area_rel`` of the candidate's (the maxima of one region count once), and not within ``tol_px``
    of another guide's ``expected`` points.
    """
    h, w = top.shape
    n = len(bps)
    out = np.zeros(n, np.int64)
    if not n or not len(xs):
        return out
    r0 = np.maximum(0, np.trunc(ij[:, 1] - reach).astype(np.int64))
    r1 = np.minimum(h, np.trunc(ij[:, 1] + reach).astype(np.int64) + 1)
    c0 = np.maximum(0, np.trunc(ij[:, 0] - reach).astype(np.int64))
    c1 = np.minimum(w, np.trunc(ij[:, 0] + reach).astype(np.int64) + 1)
    lo, hi = np.searchsorted(ys, r0), np.searchsorted(ys, r1)
    cnt = np.maximum(hi - lo, 0)
    cand = np.repeat(np.arange(n), cnt)
    start = np.cumsum(cnt) - cnt
    p = lo[cand] + np.arange(len(cand)) - start[cand]
    px, py = xs[p], ys[p]
    sel = (px >= c0[cand]) & (px < c1[cand]) & (top[py, px] >= min_top[cand])
    sel &= (px - bps[cand, 0]) ** 2 + (py - bps[cand, 1]) ** 2 <= reach[cand] ** 2
    has = np.array([e is not None for e in ellipses], bool) if ellipses is not None else np.zeros(n, bool)
    if has.any():
        e = [ellipses[k] if has[k] else None for k in range(n)]
        prm = np.array([(q.center[0], q.center[1], q.semi_axes[0], q.semi_axes[1], q.angle_rad) if q is not None
                        else (0.0, 0.0, 1.0, 1.0, 0.0) for q in e], np.float64)
        # each candidate's cosine and sine once, then read per pair (the same values: elementwise)
        c, s = np.cos(prm[:, 4])[cand], np.sin(prm[:, 4])[cand]
        du, dv = px - prm[cand, 0], py - prm[cand, 1]
        lev = ((c * du + s * dv) / prm[cand, 2]) ** 2 + ((-s * du + c * dv) / prm[cand, 3]) ** 2
        sel &= ~has[cand] | (lev > 1.0)
    cand, px, py = cand[sel], px[sel], py[sel]
    ks = np.unique(cand)
    if not len(ks):
        return out
    # every labelled window's valley mask in one mosaic (a zero row and column between them), labelled once
    hh, ww = (r1 - r0)[ks], (c1 - c0)[ks]
    order = np.argsort(-hh, kind="stable")
    width = max(2048, int(ww.max()) + 1)
    oy, ox = np.zeros(len(ks), np.int64), np.zeros(len(ks), np.int64)
    y = x = shelf = 0
    for i in order.tolist():
        if x + ww[i] + 1 > width:
            y, x, shelf = y + shelf, 0, 0
        oy[i], ox[i] = y, x
        x += int(ww[i]) + 1
        shelf = max(shelf, int(hh[i]) + 1)
    mosaic = np.zeros((y + shelf, width), np.uint8)
    fg = np.zeros(len(ks), np.int64)
    for i, k in enumerate(ks.tolist()):
        a0, a1, b0, b1 = int(r0[k]), int(r1[k]), int(c0[k]), int(c1[k])
        m = mosaic[oy[i]:oy[i] + a1 - a0, ox[i]:ox[i] + b1 - b0]
        np.greater_equal(top[a0:a1, b0:b1], level[k], out=m.view(bool))
        fg[i] = np.count_nonzero(m)
    lab = connected_components(mosaic)[1]
    area = np.bincount(lab.ravel())
    pos = np.searchsorted(ks, cand)  # each pair's window
    own = lab[ij[ks, 1] - r0[ks] + oy, ij[ks, 0] - c0[ks] + ox]
    other = lab[py - r0[cand] + oy[pos], px - c0[cand] + ox[pos]]
    # a label's area; the background's (label 0) is its window's
    a_other = np.where(other > 0, area[other], hh[pos] * ww[pos] - fg[pos])
    a_own = np.where(own > 0, area[own], hh * ww - fg)
    big = (a_other >= area_rel * a_own[pos]) | (own[pos] == 0)
    counted = ((other != own[pos]) | (own[pos] == 0)) & big
    if expected is not None:
        hit = _labels_near(lab, expected, ks, r0, r1, c0, c1, oy, ox, tol_px)
        counted &= ~np.array([o in hit[q] for q, o in zip(pos.tolist(), other.tolist())], bool)
    # one count per region (pos, label): the maxima of a noisy plateau are one peak
    # (a maximum below the level, label 0, is a peak of its own)
    region = counted & (other > 0)
    key = np.unique(pos[region] * (int(lab.max()) + 1) + other[region])
    out[ks] = (np.bincount(key // (int(lab.max()) + 1), minlength=len(ks))
               + np.bincount(pos[counted & (other == 0)], minlength=len(ks))).astype(np.int64)
    return out


def _labels_near(lab: np.ndarray, expected, ks: np.ndarray, r0, r1, c0, c1, oy, ox, tol: float) -> list[set]:
    """Per labelled window ``i``, the labels of ``lab`` within ``tol`` px of candidate ``ks[i]``'s expected points."""
    R = int(np.floor(tol))
    dy, dx = np.mgrid[-R:R + 1, -R:R + 1]
    disk = np.column_stack([dx.ravel(), dy.ravel()])[(dx.ravel() ** 2 + dy.ravel() ** 2) <= tol * tol]
    out = []
    for i, k in enumerate(ks.tolist()):
        pts = expected[k]
        if pts is None or not len(pts):
            out.append(set())
            continue
        q = (np.rint(np.asarray(pts, np.float64)).astype(np.int64)[:, None, :] + disk[None]).reshape(-1, 2)
        inw = (q[:, 1] >= r0[k]) & (q[:, 1] < r1[k]) & (q[:, 0] >= c0[k]) & (q[:, 0] < c1[k])
        q = q[inw]
        out.append(set(lab[q[:, 1] - r0[k] + oy[i], q[:, 0] - c0[k] + ox[i]].tolist()) - {0})
    return out


def white_share(excess: np.ndarray, tissue: np.ndarray) -> np.ndarray:
    """The share of light above the background that is the illuminant's, shape ``excess[..., 0]``.

    Dichromatic model (Shafer 1985, doi:10.1002/col.5080100409): a linear excess is ``a t + s (1, 1, 1)``
    with ``t`` the tissue's colour (``tissue``, (..., 3) or (3,)); solved on t's brightest and darkest
    channels, the share is s over the excess in the brightest (1 white, 0 the tissue's own colour).
    1 where t is too pale to tell (chroma below :data:`~simtest.decisions.WHITE_CHROMA`).
    """
    if np.ndim(tissue) == 1:  # one tissue colour: its channels picked once, not per pixel
        ex, t = np.asarray(excess), np.asarray(tissue)
        hi, lo = int(np.argmax(t)), int(np.argmin(t))
        if not t[hi] > 0 or 1.0 - t[lo] / t[hi] < WHITE_CHROMA:
            return np.ones(ex.shape[:-1], ex.dtype)
        s = (ex[..., lo] * t[hi] - ex[..., hi] * t[lo]) / (t[hi] - t[lo])
        return s / np.maximum(ex[..., hi], ex.dtype.type(1e-6))
    ex = np.asarray(excess, np.float64)
    t = np.broadcast_to(np.asarray(tissue, np.float64), ex.shape)
    hi, lo = np.argmax(t, axis=-1)[..., None], np.argmin(t, axis=-1)[..., None]
    t_hi, t_lo = np.take_along_axis(t, hi, -1)[..., 0], np.take_along_axis(t, lo, -1)[..., 0]
    e_hi, e_lo = np.take_along_axis(ex, hi, -1)[..., 0], np.take_along_axis(ex, lo, -1)[..., 0]
    pale = ~(t_hi > 0) | (1.0 - t_lo / np.where(t_hi > 0, t_hi, 1.0) < WHITE_CHROMA)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (e_lo * t_hi - e_hi * t_lo) / (t_hi - t_lo)
        share = s / np.maximum(e_hi, 1e-6)
    return np.where(pale, 1.0, share)


#: The inverse sRGB curve at each 8-bit code (float32).
_SRGB_8BIT = srgb_inverse(np.arange(256) / 255.0).astype(np.float32)


def white_share_in(win_rgb: np.ndarray, se: np.ndarray, bp_rc: tuple[int, int], full_scale: float,
                   response=None) -> np.ndarray:
    """:func:`white_share` of each pixel of a display-encoded window (rows, cols, 3) over its channels'
    grey openings by ``se``, linearised by ``response`` (None: sRGB), the tissue read at ``bp_rc``.
    """
    if response is not None and response.curve != "srgb":
        lin = response.decode(np.asarray(win_rgb, np.float64) / float(full_scale)).astype(np.float32)
    else:
        lin = (_SRGB_8BIT[win_rgb] if win_rgb.dtype == np.uint8 and full_scale == 255.0 else
               srgb_inverse(np.clip(np.asarray(win_rgb, np.float32) / np.float32(full_scale), 0, 1)).astype(np.float32))
    base = cv2.morphologyEx(lin, cv2.MORPH_OPEN, se, borderType=cv2.BORDER_REPLICATE)
    return white_share(lin - base, base[bp_rc])


def surround_fractions(gray: np.ndarray, ells, bps_ij: np.ndarray, reaches: np.ndarray, own_level, rel: float,
                       paired=None, rgb: np.ndarray | None = None, full_scale: float = 255.0, response=None):
    """Per candidate, the share of its surround lit by other light, float64 (n,).

    The surround is within ``reaches`` of the BP pixel ``bps_ij`` (column, row), outside the primary
    isophote at ``own_level``; a pixel is lit when its local top-hat is at least ``rel`` of the
    peak's; 0 without a surround or peak (``tests/_surround.py``). ``paired``: other guides' lobes
    (the own lobe moved there) left out too. With ``rgb`` (display-encoded, ``full_scale`` white), a
    pair of arrays, the second counting only white light (:func:`white_share_in` at least
    :data:`~simtest.decisions.WHITE_SHARE_MIN`).
    """
    h, w = gray.shape
    bps_ij = np.asarray(bps_ij, np.int64).reshape(-1, 2)
    reaches = np.asarray(reaches, np.float64).reshape(-1)
    n = len(reaches)
    out, white = np.zeros(n), np.zeros(n)
    if not n:
        return out if rgb is None else (out, white)
    R_all = np.ceil(reaches).astype(np.int64)
    own = np.broadcast_to(np.asarray(own_level, np.float64), (n,))
    # each ellipse's numbers; its cosine and sine taken one by one (numpy's scalar path)
    prm = np.array([(e.center[0], e.center[1], e.semi_axes[0], e.semi_axes[1]) for e in ells], np.float64)
    cs = np.array([(np.cos(e.angle_rad), np.sin(e.angle_rad)) for e in ells], np.float64)
    for R in np.unique(R_all).tolist():
        idx = np.flatnonzero(R_all == R)
        bj, bi = bps_ij[idx, 0], bps_ij[idx, 1]
        off = np.arange(-R, R + 1, dtype=np.int64)
        ry, rx = bi[:, None] + off, bj[:, None] + off  # (m, S) rows and columns
        yy = ry.astype(np.float64)[:, :, None]
        xx = rx.astype(np.float64)[:, None, :]
        col = lambda a: a[:, None, None]  # noqa: E731
        reach = reaches[idx]
        c, s = col(cs[idx, 0]), col(cs[idx, 1])
        du, dv = xx - col(prm[idx, 0]), yy - col(prm[idx, 1])
        # ellipse_level's terms in place (the same operations in the same order: the same bits)
        lev = np.add(c * du, s * dv)
        lev /= col(prm[idx, 2])
        np.multiply(lev, lev, out=lev)
        t = np.add(-s * du, c * dv)
        t /= col(prm[idx, 3])
        np.multiply(t, t, out=t)
        lev += t
        ring = np.greater(lev, col(own[idx]))
        # within the reach (whole numbers: exact in any order) and inside the frame
        ring &= ((ry - bi[:, None]) ** 2)[:, :, None] + ((rx - bj[:, None]) ** 2)[:, None, :] <= col(reach * reach)
        for m, q in enumerate(idx.tolist()):
            for pu, pv in (paired[q] if paired is not None else ()):
                du, dv = xx[m] - (prm[q, 0] + pu - bj[m]), yy[m] - (prm[q, 1] + pv - bi[m])
                lv = ((cs[q, 0] * du + cs[q, 1] * dv) / prm[q, 2]) ** 2 + ((-cs[q, 1] * du + cs[q, 0] * dv) / prm[q, 3]) ** 2
                ring[m] &= lv > own[q]
        ring &= ((ry >= 0) & (ry < h))[:, :, None] & ((rx >= 0) & (rx < w))[:, None, :]
        n_ring = np.count_nonzero(ring, axis=(1, 2))
        k = max(3, R | 1)  # odd, about the reach
        se = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
        for m, q in enumerate(idx.tolist()):
            if not n_ring[m]:
                continue
            i, j = int(bi[m]), int(bj[m])
            r0, r1, c0, c1 = max(0, i - R), min(h, i + R + 1), max(0, j - R), min(w, j + R + 1)
            win = np.ascontiguousarray(gray[r0:r1, c0:c1], dtype=np.float32)
            top = win - cv2.morphologyEx(win, cv2.MORPH_OPEN, se, borderType=cv2.BORDER_REPLICATE)
            peak = float(top[max(0, i - 1 - r0):i + 2 - r0, max(0, j - 1 - c0):j + 2 - c0].max())
            if peak > 0:
                lit = (top >= rel * peak) & ring[m, r0 - i + R:r1 - i + R, c0 - j + R:c1 - j + R]
                out[q] = float(np.count_nonzero(lit) / int(n_ring[m]))
                if rgb is not None and out[q] > 0:
                    lit &= white_share_in(rgb[r0:r1, c0:c1], se, (i - r0, j - c0), full_scale,
                                          response) >= WHITE_SHARE_MIN
                    white[q] = float(np.count_nonzero(lit) / int(n_ring[m]))
    return out if rgb is None else (out, white)
