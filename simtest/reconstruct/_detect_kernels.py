"""Compiled (numba) kernels of specularity detection (:mod:`simtest.reconstruct.detect`).

:func:`examine_candidates` does, for every candidate highlight of a frame in one compiled call,
what the per-candidate loop of ``detect_specularities`` does with a dozen numpy calls: the
brightest pixel, the sub-pixel brightest point (BP, the parabola of ``refine_peak_uv`` or the
centroid of the flat top of ``peak_uv``), the rejection status and the region of interest of
``Roi.around``, with the same floating-point operations in the same order, so the results are the
same bits (``tests/test_detect_kernels.py`` compares whole detections with the numpy form, which
stays in ``detect.py`` as the reference and the fallback). A frame has up to a thousand
candidates of a few pixels each: there the fixed cost of each numpy call was the time.

Kernels
-------
- :func:`paste_labels`: a band's component labels into the frame's label image.
- :func:`label_stats`: the boxes and areas of a label image's components.
- :func:`top_hat`, :func:`peak_mask`: the whole-frame arithmetic of ``local_peak_mask``, one pass
  each instead of one numpy call per operation.
- :func:`examine_candidates`: BP, peak, status and ROI of every candidate.
- :func:`mad_of_uint8_rows`: the median absolute deviation of the noise estimate, by counting.

Notes
-----
Compiled with ``cache=True`` (see :mod:`simtest.reconstruct._kernels`): one compilation per
intensity dtype (uint8, uint16, float32, float64) on the first call in a fresh environment. numba
does not contract ``a * b + c`` into a fused multiply-add without ``fastmath`` (not set here).
"""

from __future__ import annotations

import numba
import numpy as np

from simtest.reconstruct._kernels import _linear_sample, _rows_enlarged

#: :func:`examine_candidates` status codes (column ``STATUS`` of its integer result).
FALLBACK = -1  #: the numpy path examines this candidate (clipped pixels; a brightest pixel outside it)
OK = 0  #: accepted
TOO_SMALL = 1  #: ``too_small``
TOUCHES_BORDER = 2  #: ``touches_border``
BLACK_BORDER = 3  #: ``black_border``
NOT_ELLIPTICAL = 4  #: ``not_elliptical``, certainly (see :func:`examine_candidates`)
ELLIPTICITY_UNSURE = 5  #: the ellipticity is too close to a bound: numpy's value decides
MERGED = 6  #: ``merged``: several clipped plateaus of at least the plateau size

#: Columns of the integer result: status, ROI, whether the candidate is clipped (its BP the
#: centroid of its largest plateau) and its plateaus of at least the plateau size.
STATUS, ROI_ROW0, ROI_ROW1, ROI_COL0, ROI_COL1, SATURATED, N_PLATEAUS = range(7)
#: Columns of the float result: BP (u, v), peak, level, ellipticity and its relative tolerance.
BP_U, BP_V, PEAK, LEVEL, ELLIPTICITY, ELLIPTICITY_TOL = range(6)

_EPS = np.finfo(np.float64).eps


@numba.njit(cache=True, nogil=True)
def half_means_uint8(img, out):
    """The means of the 2 x 2 blocks of an 8-bit image (H, W) into ``out`` (H // 2, W // 2),
    float32: ``((a + b) + (c + d)) * 0.25``, exact (integers up to 1020), as OpenCV's
    ``cv2.resize(img.astype(np.float32), (W // 2, H // 2), interpolation=cv2.INTER_AREA)``
    gives them, without the frame's float32 copy (0.6 -> 0.2 ms on 1350 x 1080 px)."""
    h2, w2 = out.shape
    for i in range(h2):
        for j in range(w2):
            a = np.int32(img[2 * i, 2 * j]) + np.int32(img[2 * i, 2 * j + 1])
            b = np.int32(img[2 * i + 1, 2 * j]) + np.int32(img[2 * i + 1, 2 * j + 1])
            out[i, j] = np.float32(a + b) * np.float32(0.25)


@numba.njit(cache=True, nogil=True)
def block_means(img, f, out):
    """The means of the ``f`` x ``f`` blocks of an image (H, W) into ``out`` (H // f, W // f),
    float32: each block's f rows summed in float32 (in order), then its f columns, times
    ``1 / f^2``: ``cv2.resize(img, (W // f, H // f), interpolation=cv2.INTER_AREA)`` to float32
    rounding (OpenCV groups the sums otherwise). The rows that fill no block are not read. For
    an odd f (OpenCV's general area path) a half to two thirds of OpenCV's time: 0.49 -> 0.29 ms
    on the banner's 2240 x 840 px reduced by 5; by 2, OpenCV's vectorised path is faster."""
    ho, wo = out.shape
    n = wo * f
    inv = np.float32(1.0 / (f * f))
    acc = np.empty(n, np.float32)
    for i in range(ho):
        r = i * f
        for j in range(n):
            acc[j] = np.float32(img[r, j])
        for q in range(1, f):
            for j in range(n):
                acc[j] += np.float32(img[r + q, j])
        for j in range(wo):
            s = acc[j * f]
            for c in range(1, f):
                s += acc[j * f + c]
            out[i, j] = s * inv


@numba.njit(cache=True, nogil=True)
def packed_block_means_uint8(img, f, out):
    """The means of the ``f`` x ``f`` blocks of an 8-bit image (H, W, C), C-contiguous, whose
    sides are multiples of ``f`` (2 to 16), into ``out`` (H // f, W // f, C) float32, with the
    bits of ``verify._block_means``' numpy and OpenCV form: each block's ``f`` rows summed in
    uint16 (exact), times ``float32(1 / f)``; then OpenCV's integer area reduction along the row
    (``cv2.resize(..., (W // f, H // f), interpolation=cv2.INTER_AREA)`` of those (H // f, W, C)
    float32 rows): the ``f`` values of each block summed in float32 from 0, four at a time
    (``((a + b) + c) + d``, OpenCV's unrolled loop) then one at a time, times ``1.f / f``.
    One pass over the frame's bytes, without numpy's uint16 and float32 copies (the banner's
    2240 x 840 RGB reduced by 5: 1.33 -> 1.06 ms; ``tests/test_verify.py`` compares it with
    OpenCV for every f)."""
    H, W, C = img.shape
    n = W * C
    rows = img.reshape(H, n)
    ho, wo = H // f, W // f
    inv = np.float32(1.0 / f)
    scale = np.float32(np.float32(1.0) / np.float32(f))
    acc = np.empty(n, np.uint16)
    rowm = np.empty(n, np.float32)
    m = wo * C
    base = np.empty(m, np.int64)
    for d in range(wo):
        for ch in range(C):
            base[d * C + ch] = d * f * C + ch
    o = out.reshape(ho, m)
    for i in range(ho):
        r = i * f
        a0 = rows[r]
        for t in range(n):
            acc[t] = np.uint16(a0[t])
        for q in range(1, f):
            aq = rows[r + q]
            for t in range(n):
                acc[t] += np.uint16(aq[t])
        for t in range(n):
            rowm[t] = np.float32(acc[t]) * inv
        oi = o[i]
        for p in range(m):
            b = base[p]
            sm = np.float32(0.0)
            k = 0
            while k + 4 <= f:
                sm = sm + (((rowm[b + k * C] + rowm[b + (k + 1) * C]) + rowm[b + (k + 2) * C]) + rowm[b + (k + 3) * C])
                k += 4
            while k < f:
                sm = sm + rowm[b + k * C]
                k += 1
            oi[p] = sm * scale


@numba.njit(cache=True, nogil=True)
def paste_labels(dst, lab, offset):
    """Copy the component labels ``lab`` (0: background) into ``dst`` shifted by ``offset``.

    Parameters
    ----------
    dst : ndarray of shape (h, w), int32
        The frame's label image over the band (a view), written whole: its background pixels
        become 0 (the bands of a mask do not overlap, so the frame's image may start unwritten).
    lab : ndarray of shape (h, w), int32
        The band's labels.
    offset : int
        Components before this band.
    """
    h, w = lab.shape
    for r in range(h):
        for c in range(w):
            v = lab[r, c]
            dst[r, c] = v + offset if v != 0 else 0


@numba.njit(cache=True, nogil=True)
def label_stats(labels, n):
    """The bounding box and pixel count of each label of a label image: the ``stats`` of
    ``cv2.connectedComponentsWithStats``, from its labels alone.

    Parameters
    ----------
    labels : ndarray of shape (h, w), int32
        Labels 0 (background) to ``n - 1``.
    n : int
        Number of labels, the background's included.

    Returns
    -------
    ndarray of shape (n, 5), int32
        Per label ``x, y, width, height, area`` (columns ``x : x + width``, rows ``y : y +
        height``, px), OpenCV's ``CC_STAT_*`` order. A label without pixels (the background of a
        full mask) has area 0 and a width and height below 1 (OpenCV's row holds other
        placeholders).

    Notes
    -----
    One pass over the components' pixels; the background's box is read from the first and last
    rows and columns that hold a background pixel (a few rows and columns of a sparse mask).
    """
    h, w = labels.shape
    x0 = np.full(n, w, np.int64)
    y0 = np.full(n, h, np.int64)
    x1 = np.full(n, -1, np.int64)
    y1 = np.full(n, -1, np.int64)
    area = np.zeros(n, np.int64)
    for r in range(h):
        for c in range(w):
            k = labels[r, c]
            if k == 0:
                continue
            area[k] += 1
            if c < x0[k]:
                x0[k] = c
            if c > x1[k]:
                x1[k] = c
            if r < y0[k]:
                y0[k] = r
            y1[k] = r  # rows come in order: the last seen is the largest
    area[0] = h * w - area[1:].sum()
    if area[0] > 0:
        y0[0] = _first_line_with_zero(labels, 0, h, 1, True)
        y1[0] = _first_line_with_zero(labels, h - 1, -1, -1, True)
        x0[0] = _first_line_with_zero(labels, 0, w, 1, False)
        x1[0] = _first_line_with_zero(labels, w - 1, -1, -1, False)
    out = np.empty((n, 5), np.int32)
    for k in range(n):
        out[k, 0] = x0[k]
        out[k, 1] = y0[k]
        out[k, 2] = x1[k] - x0[k] + 1
        out[k, 3] = y1[k] - y0[k] + 1
        out[k, 4] = area[k]
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _first_line_with_zero(labels, start, stop, step, rows):
    """The first row (``rows``) or column from ``start`` toward ``stop`` that holds a 0."""
    h, w = labels.shape
    for i in range(start, stop, step):
        for j in range(w if rows else h):
            if (labels[i, j] if rows else labels[j, i]) == 0:
                return i
    return -1


@numba.njit(cache=True, nogil=True)
def _kth_counted(hist, k):
    """The ``k``-th smallest (0-based) of the integers counted by ``hist`` (``hist[i]`` values
    equal to ``i``): the first ``i`` whose running count exceeds ``k``, as ``np.searchsorted(
    np.cumsum(hist), k, side="right")``."""
    acc = 0
    for i in range(len(hist)):
        acc += hist[i]
        if acc > k:
            return i
    return len(hist)


@numba.njit(cache=True, nogil=True)
def mad_of_uint8_rows(rows):
    """``np.median(np.abs(d - np.median(d)))`` of the second differences ``d = x - (left +
    right) / 2`` along uint8 rows, by counting (one pass over the rows, two histograms).

    Parameters
    ----------
    rows : ndarray of shape (h, W), uint8
        ``h >= 1``, ``W >= 3``.

    Returns
    -------
    float
        The median absolute deviation, intensity units: a multiple of 1/4 (or 1/8), exact in
        float32.

    Notes
    -----
    ``2 d = 2 x - (left + right)`` is an integer in [-510, 510], and ``4 |d - median(d)| = |2 (2
    d) - 4 median(d)|`` one in [0, 4080]: both medians are order statistics of integers, the mean
    of the two middle ones for an even count as ``np.median`` takes it; numpy's float32
    arithmetic on these values is exact, so the value is numpy's (``tests/test_detect.py``
    compares the two on random rows, ties and even counts included).
    """
    h, w = rows.shape
    n = h * (w - 2)
    if n % 2:
        k0, k1, nk = n // 2, n // 2, 1
    else:
        k0, k1, nk = n // 2 - 1, n // 2, 2
    # four histograms filled in turn, summed after: consecutive values of a row fall in the same
    # few bins, and one histogram would make each count wait for the last
    parts = np.zeros((4, 1021), np.int64)
    for r in range(h):
        for c in range(1, w - 1):
            d2 = 2 * np.int64(rows[r, c]) - (np.int64(rows[r, c - 1]) + np.int64(rows[r, c + 1]))
            parts[c & 3, d2 + 510] += 1
    hist = parts[0] + parts[1] + parts[2] + parts[3]
    m2 = _kth_counted(hist, k0) - 510  # 2 median(d) or, for an even count, the lower middle
    if nk == 2:
        m2 += _kth_counted(hist, k1) - 510
    m4 = m2 * (2 // nk)  # 4 median(d)
    # the deviations' histogram from the first: every 2 d = v counts at |2 v - m4|
    dev = np.zeros(4081, np.int64)
    for v in range(-510, 511):
        dev[abs(2 * v - m4)] += hist[v + 510]
    t = _kth_counted(dev, k0)
    if nk == 2:
        t += _kth_counted(dev, k1)
    return t / (4 * nk)


@numba.njit(cache=True, nogil=True)
def top_hat(gray, background, top, thr, rows):
    """The top-hat of ``local_peak_mask`` in one pass: ``background = min(background, gray)``
    (in place: an opening never exceeds the image) and ``top = gray - background``, with the
    rows that hold a top-hat of at least ``thr``.

    Parameters
    ----------
    gray : ndarray of shape (H, W), float32
        The luma examined.
    background : ndarray of shape (H, W), float32
        The opening brought back to full size; overwritten with its minimum with ``gray``.
    top : ndarray of shape (H, W), float32
        Output, the top-hat (image units).
    thr : float32
        The smallest top-hat of a candidate (image units).
    rows : ndarray of shape (H,), uint8
        Output, 1 for the rows that hold a top-hat ``>= thr`` (NaN fails it), else 0: the rows
        :func:`peak_mask` cannot skip.

    Notes
    -----
    ``np.minimum`` and the float32 subtraction, element by element (NaN propagates as in
    ``np.minimum``): the same bits as the two numpy calls it replaces, one pass over the frame
    instead of two and no temporary (``tests/test_detect_kernels.py``). The rows are an integer
    OR over the row, which the compiler vectorises (a float maximum would not be: it took the
    pass from 0.75 to 1.95 ms on a 1350 x 1080 frame).
    """
    h, w = gray.shape
    for r in range(h):
        hit = 0
        for c in range(w):
            a = background[r, c]
            g = gray[r, c]
            m = a if (a <= g or a != a) else g
            background[r, c] = m
            t = g - m
            top[r, c] = t
            hit |= t >= thr
        rows[r] = hit


@numba.njit(cache=True, nogil=True)
def peak_mask(top, local_peak, peak_rel, thr, rows, mask):
    """The candidate mask of ``local_peak_mask`` in one pass: ``top >= peak_rel * max(local_peak,
    top)`` and ``top >= thr``.

    Parameters
    ----------
    top : ndarray of shape (H, W), float32
        The top-hat (:func:`top_hat`).
    local_peak : ndarray of shape (H, W), float32
        The dilated top-hat brought back to full size (read only).
    peak_rel, thr : float32
        The fraction of the local peak and the smallest top-hat (image units), as float32: numpy
        multiplies and compares a float32 array with a Python float in float32.
    rows : ndarray of shape (H,), uint8
        1 for the rows that hold a top-hat ``>= thr`` (:func:`top_hat`).
    mask : ndarray of shape (H, W), uint8
        Output, 1 for candidate pixels.

    Notes
    -----
    ``np.maximum``, the float32 product and the two comparisons, element by element: the same
    bits as the five numpy calls it replaces (``tests/test_detect_kernels.py``). A row with no
    top-hat ``>= thr`` holds no candidate: it is written 0 without reading ``top`` and
    ``local_peak`` (the rows of the highlights are 289 of the 1080 rows of the bench's noisy
    10-highlight frame; the pass takes 0.17 ms instead of 0.48 ms there).
    """
    h, w = top.shape
    for r in range(h):
        if rows[r] == 0:
            for c in range(w):
                mask[r, c] = 0
            continue
        for c in range(w):
            t = top[r, c]
            p = local_peak[r, c]
            q = p if (p >= t or p != p) else t
            q = q * peak_rel
            mask[r, c] = 1 if (t >= q and t >= thr) else 0


@numba.njit(cache=True, nogil=True)
def _ellipticity(labels, cid, x, y, bw, bh, n=0, sr=0, sc=0):
    """``ellipticity`` of component ``cid`` in its box, and a bound on its relative difference
    from numpy's value: ``(e, tol)``; ``tol`` is NaN where the determinant is not positive.
    ``n``, ``sr``, ``sc``: the component's pixel count and the sums of its rows and columns in
    the box, where the caller counted them (integers: the same sums), else 0 (counted here).

    The same operations as ``detect.ellipticity`` but for the sums of the covariance, which numpy
    leaves to BLAS (its summation order is not ours). Each of the two computed sums of squares
    or products of ``n`` centred coordinates is within ``(n + 2) eps`` (relative; ``(n + 2) eps
    sqrt(a c)`` for the cross term) of the exact one, so each determinant is within
    ``4 (n + 4) eps A C`` of the exact (``A``, ``C`` the diagonal with the pixel's 1/12), and
    ``e``, which goes as its inverse square root, within half that relative to ``det``; the two
    values differ by at most the sum. ``tol`` is four times that, and at least 1e-9.
    """
    if n == 0:
        for r in range(bh):
            for c in range(bw):
                if labels[y + r, x + c] == cid:
                    n += 1
                    sr += r
                    sc += c
    mr = sr / n
    mc = sc / n
    srr = 0.0
    scc = 0.0
    src = 0.0
    for r in range(bh):
        dr = r - mr
        l_row = labels[y + r, x : x + bw]
        for c in range(bw):
            if l_row[c] == cid:
                dc = c - mc
                srr += dr * dr
                scc += dc * dc
                src += dr * dc
    inv = 1.0 / n  # np.true_divide(1, n), as numpy scales the covariance
    a = srr * inv + 1 / 12
    cc = scc * inv + 1 / 12
    b = src * inv
    det = a * cc - b**2
    if not det > 0:
        return np.nan, np.nan
    e = n / (4 * np.pi * np.sqrt(det))
    tol = max(1e-9, 16.0 * (n + 4) * _EPS * (a * cc) / det)
    return e, tol


@numba.njit(cache=True, nogil=True, inline="always")
def _box_min(gray, x, y, bw, bh):
    """``gray[y : y + bh, x : x + bw].min()``: the first least value in raster order."""
    mn = gray[y, x]
    for r in range(bh):
        g_row = gray[y + r, x : x + bw]
        for c in range(bw):
            v = g_row[c]
            if v < mn:
                mn = v
    return mn


@numba.njit(cache=True, nogil=True, inline="always")
def _outside_cross(labels, cid, x, y, bw, bh, pr, pc):
    """Whether a neighbour that the parabolas through box pixel (pr, pc) read (above and below
    it where both are in the box, left and right likewise) is outside component ``cid``."""
    if 0 < pr < bh - 1 and (labels[y + pr - 1, x + pc] != cid or labels[y + pr + 1, x + pc] != cid):
        return True
    return 0 < pc < bw - 1 and (labels[y + pr, x + pc - 1] != cid or labels[y + pr, x + pc + 1] != cid)


@numba.njit(cache=True, nogil=True, inline="always")
def _value(gray, labels, cid, mn, r, c):
    """``np.where(comp, box, box.min())`` at pixel (r, c), as float64."""
    return np.float64(gray[r, c] if labels[r, c] == cid else mn)


@numba.njit(cache=True, nogil=True, inline="always")
def _parabola_offset(a, b, d):
    """``refine_peak_uv``'s offset along one axis through the values ``a, b, d`` (b the
    maximum): ``0.5 (a - d) / (a - 2 b + d)`` clipped to +-0.5 px, 0 without a strict maximum."""
    b = np.float64(b)
    den = a - 2 * b + d
    if not den < 0:
        return 0.0
    t = 0.5 * (a - d) / den
    if -0.5 > t:  # Python's max(t, -0.5), then min(., 0.5)
        t = -0.5
    if 0.5 < t:
        t = 0.5
    return t


@numba.njit(cache=True, nogil=True)
def close_binary(src, k, out):
    """OpenCV's ``cv2.morphologyEx(src, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))`` of a 0/1
    uint8 image (h, w) into ``out``: the dilation, then the erosion, by the k x k square (k odd,
    centred), each over the pixels of the image only (OpenCV's default border, which neither
    dilates nor erodes), separably (a square's extremes are those of its rows' extremes).

    Each pass counts the set pixels of its window (the window clipped to the image): a pixel of
    the dilation is set where the count is positive, one of the erosion where every pixel of the
    clipped window is set. Along the rows the count slides (one addition and one subtraction a
    pixel, whatever k); down the columns the rows' counts are kept per column and updated a row
    at a time (vectorised across the columns): the same image as the k OR-s or AND-s a pixel of
    the direct passes (the noisy bench frame's clipped highlight, a 90 x 88 px box closed by
    11 px: 137 -> 105 us of its examination; the banner's largest, 518 -> 129 us)."""
    h, w = src.shape
    r = k // 2
    tmp = np.empty((h, w), np.uint8)
    dil = np.empty((h, w), np.uint8)
    _rows_count_test(src, r, False, tmp)
    _columns_count_test(tmp, r, False, dil)
    _rows_count_test(dil, r, True, tmp)
    _columns_count_test(tmp, r, True, out)


@numba.njit(cache=True, nogil=True)
def _rows_count_test(src, r, every, out):
    """Along each row of a 0/1 uint8 image (h, w): ``out[i, j]`` = 1 where the window
    ``src[i, max(0, j - r) : min(w, j + r + 1)]`` holds a set pixel (``every`` False: the OR of
    a dilation) or only set pixels (``every`` True: the AND of an erosion), else 0; the window's
    count slides along the row."""
    h, w = src.shape
    for i in range(h):
        row = src[i]
        o = out[i]
        cnt = 0
        for c in range(min(w, r)):  # the window of column 0 but its last pixel
            cnt += row[c]
        for j in range(w):
            if j + r < w:
                cnt += row[j + r]
            if j - r - 1 >= 0:
                cnt -= row[j - r - 1]
            n = min(w, j + r + 1) - max(0, j - r)
            o[j] = 1 if (cnt == n if every else cnt > 0) else 0


@numba.njit(cache=True, nogil=True)
def _columns_count_test(src, r, every, out):
    """:func:`_rows_count_test` down the columns: the window ``src[max(0, i - r) : min(h, i + r +
    1), j]``, each column's count kept and updated a row at a time."""
    h, w = src.shape
    cnt = np.zeros(w, np.int64)
    for q in range(min(h, r)):
        for j in range(w):
            cnt[j] += src[q, j]
    for i in range(h):
        if i + r < h:
            add = src[i + r]
            for j in range(w):
                cnt[j] += add[j]
        if i - r - 1 >= 0:
            sub = src[i - r - 1]
            for j in range(w):
                cnt[j] -= sub[j]
        n = min(h, i + r + 1) - max(0, i - r)
        o = out[i]
        if every:
            for j in range(w):
                o[j] = 1 if cnt[j] == n else 0
        else:
            for j in range(w):
                o[j] = 1 if cnt[j] > 0 else 0


@numba.njit(cache=True, nogil=True)
def plateau_pieces(mask, min_area):
    """The 8-connected pieces of a 0/1 uint8 image (h, w) as ``connected_components_with_stats``
    (OpenCV's Grana labelling) orders and measures them: ``(n_big, cx, cy)``, the pieces of at
    least ``min_area`` px, and the centroid (column, row; float64, the integer sums over the area,
    as OpenCV's) of the first largest piece in OpenCV's label order. Grana's labels come in the
    order of each piece's first 2 x 2 block in raster order of the blocks (the pixels of a block
    are 8-neighbours: one piece each), so the pieces are followed from the blocks in that order.
    ``n_big`` is -1 for an image without a set pixel."""
    h, w = mask.shape
    seen = np.zeros((h, w), np.uint8)
    stack = np.empty(h * w, np.int64)
    n_big = 0
    best = -1
    cx = np.nan
    cy = np.nan
    for br in range(0, h, 2):
        for bc in range(0, w, 2):
            for r0 in range(br, min(h, br + 2)):
                for c0 in range(bc, min(w, bc + 2)):
                    if mask[r0, c0] == 0 or seen[r0, c0]:
                        continue
                    seen[r0, c0] = 1
                    stack[0] = r0 * w + c0
                    top = 1
                    area = 0
                    sr = 0
                    sc = 0
                    while top > 0:
                        top -= 1
                        p = stack[top]
                        r, c = p // w, p % w
                        area += 1
                        sr += r
                        sc += c
                        for rr in range(max(0, r - 1), min(h, r + 2)):
                            for cc in range(max(0, c - 1), min(w, c + 2)):
                                if mask[rr, cc] != 0 and not seen[rr, cc]:
                                    seen[rr, cc] = 1
                                    stack[top] = rr * w + cc
                                    top += 1
                    if area >= min_area:
                        n_big += 1
                    if area > best:  # np.argmax: the first of the largest
                        best = area
                        cx = np.float64(sc) / area
                        cy = np.float64(sr) / area
    if best < 0:
        return -1, cx, cy
    return n_big, cx, cy


@numba.njit(cache=True, nogil=True)
def _clipped_top(labels, clipped, cid, x, y, bw, bh, k_close, min_plateau_px, local_peak):
    """The clipped plateaus of a candidate, as ``detect._examine_numpy`` finds them with OpenCV:
    ``(n_big, cx, cy)`` of :func:`plateau_pieces` (box coordinates) of its clipped pixels, closed
    by 3 x 3 and cut by the component (``local_peak``; pieces from 3 px, or the plateau size if
    larger), or closed by ``k_close`` where that joins two or more such pieces into one; the
    clipped pixels themselves otherwise (pieces from ``min_plateau_px``)."""
    comp = np.empty((bh, bw), np.uint8)
    raw = np.empty((bh, bw), np.uint8)
    for r in range(bh):
        for c in range(bw):
            inside = labels[y + r, x + c] == cid
            comp[r, c] = 1 if inside else 0
            raw[r, c] = 1 if (inside and clipped[y + r, x + c] != 0) else 0
    if not local_peak:
        return plateau_pieces(raw, min_plateau_px)
    min_plateau = max(min_plateau_px, 3)
    sat8 = np.empty((bh, bw), np.uint8)
    close_binary(raw, 3, sat8)
    sat8 &= comp
    n_big, cx, cy = plateau_pieces(sat8, min_plateau)
    if k_close > 3 and n_big > 1:
        # pieces of one clipped top, broken by noise or speckle: one plateau
        close_binary(raw, k_close, sat8)
        sat8 &= comp
        n_wide, cxw, cyw = plateau_pieces(sat8, min_plateau)
        if n_wide == 1:
            return n_wide, cxw, cyw
    return n_big, cx, cy


@numba.njit(cache=True, nogil=True)
def examine_candidates(gray, labels, comps, clipped, scope, levels, min_area_px, ellipticity_min,
                       ellipticity_max, roi_scale, roi_margin_px, peak_rel, origin_x, origin_y,
                       k_close=0, min_plateau_px=2, local_peak=True):
    """Brightest pixel, BP, peak, status, ROI and level of every candidate highlight.

    Parameters
    ----------
    gray : ndarray of shape (H, W), uint8, uint16, float32 or float64
        The intensities the detector examines (the luma, smoothed if it smooths), C-contiguous.
    labels : ndarray of shape (H, W), int32
        Component labels (0: background).
    comps : ndarray of shape (M, 6), int64
        One candidate per row, in the order to examine: label, x, y, width, height (the bounding
        box, px) and area (px).
    clipped : ndarray of shape (H, W), uint8, or of size 0
        Clipped pixels (``detect.clipped_mask``); size 0 without a saturation level.
    scope : ndarray of shape (H, W), bool, or of size 0
        The endoscope's black border (``detect._scope_border``); size 0 for none.
    levels : ndarray of shape (H, W), float32, or of size 0
        The local background (``method="local_peak"``); size 0 for none.
    min_area_px, ellipticity_min, ellipticity_max : float
        Limits of ``too_small`` and ``not_elliptical`` (``ellipticity_max = 1 / ellipticity_min``
        as Python computes it).
    roi_scale, roi_margin_px, peak_rel : float
        As ``detect_specularities``' arguments.
    origin_x, origin_y : int
        The column and row of the arrays' first pixel in the frame (0, 0 for a whole frame; a
        window's corner): added to each box's corner for the BP (as numpy adds the box's corner
        in the frame: the same bits). The ROI is clipped to the arrays' sides, so it is the
        frame's only at origin 0 (a window's caller proposes its own).
    k_close, min_plateau_px, local_peak : int, int, bool
        The clipped plateaus' closing side (``_DetectFrame.k_close``), their size and whether
        the method is ``"local_peak"`` (its closings); ``k_close`` 0: a clipped candidate is a
        :data:`FALLBACK` (numpy examines it).

    Returns
    -------
    ints : ndarray of shape (M, 7), int64
        Columns :data:`STATUS` (a status code), the ROI (:data:`ROI_ROW0` .. :data:`ROI_COL1`,
        half-open array indices), :data:`SATURATED` (1: clipped) and :data:`N_PLATEAUS` (of a
        clipped one). A :data:`FALLBACK` row holds nothing else.
    floats : ndarray of shape (M, 6), float64
        Columns :data:`BP_U`, :data:`BP_V` (px, full image), :data:`PEAK` (image units),
        :data:`LEVEL` (NaN without ``levels``), :data:`ELLIPTICITY` and
        :data:`ELLIPTICITY_TOL` (its relative tolerance; NaN where not computed).

    Notes
    -----
    The numpy form is the loop of ``detect._candidates_numpy``; its steps here:

    - brightest pixel: ``np.argmax(np.where(comp, box, box.min()))`` (the first maximum in
      raster order). A maximum outside the component (every pixel of it at the box minimum) is a
      :data:`FALLBACK`. A candidate with clipped pixels has the centroid of its largest
      plateau as its BP (:func:`_clipped_top`: OpenCV's closings and labelling, written out) and
      is :data:`MERGED` where two or more plateaus reach the plateau size (then no ellipticity);
      without ``k_close`` it is a :data:`FALLBACK`.
    - BP: ``peak_uv``, i.e. the separable parabola of ``refine_peak_uv`` through the values
      ``np.where(comp, box, box.min())``, or, where another pixel of the 3 x 3 neighbourhood is
      in the component at the same value, the centroid of the 8-connected flat top (integer sums
      are exact, so the means are numpy's).
    - status: ``too_small``, ``touches_border``, ``black_border``, then from 12 px the
      ellipticity, whose covariance sums cannot be numpy's bits (BLAS): :data:`OK` or
      :data:`NOT_ELLIPTICAL` only where the value is on one side of both bounds by more than its
      tolerance, else :data:`ELLIPTICITY_UNSURE` (the caller asks numpy).
    - ROI: ``Roi.around(bp, roi_scale * max(w, h) / 2 + roi_margin_px, (H, W))``.
    """
    H, W = gray.shape
    m = comps.shape[0]
    ints = np.zeros((m, 7), dtype=np.int64)
    floats = np.full((m, 6), np.nan, dtype=np.float64)
    has_clipped = clipped.size > 0
    has_scope = scope.size > 0
    has_levels = levels.size > 0
    stack = np.empty(64, dtype=np.int64)
    for k in range(m):
        cid, x, y, bw, bh, area = comps[k, 0], comps[k, 1], comps[k, 2], comps[k, 3], comps[k, 4], comps[k, 5]
        # np.where(comp, box, box.min()) and its argmax: the first maximum of the component,
        # unless that maximum is the box minimum (every value the same: the argmax is the box's
        # first pixel); and whether the component has clipped pixels
        best = gray[y, x]
        # the least of the component's values and the box's first (at least the box minimum,
        # which is read only where it matters: below; the box's pass was a third of a real
        # frame's examination)
        low = best
        pr, pc = -1, -1
        sat = False
        # (and the component's pixel count and the sums of its rows and columns, which its
        # ellipticity reads: one pass over the box fewer)
        n_px = 0
        s_r = 0
        s_c = 0
        for r in range(bh):
            g_row = gray[y + r, x : x + bw]
            l_row = labels[y + r, x : x + bw]
            for c in range(bw):
                if l_row[c] == cid:
                    v = g_row[c]
                    n_px += 1
                    s_r += r
                    s_c += c
                    if pr < 0 or v > best:
                        best = v
                        pr, pc = r, c
                    if v < low:
                        low = v
                    if has_clipped and clipped[y + r, x + c]:
                        sat = True
        # the box minimum, where the maximum can be it (low == best: a flat component whose
        # value is the box's first); below, where a neighbour of the BP's parabola is outside
        # the component
        mn = best
        have_mn = False
        if low == best:
            mn = _box_min(gray, x, y, bw, bh)
            have_mn = True
            if best == mn:
                pr, pc = 0, 0
                best = gray[y, x]
        if labels[y + pr, x + pc] != cid or (sat and k_close == 0):
            ints[k, STATUS] = FALLBACK
            continue
        peak = np.float64(best)
        merged = False
        if sat:
            # the BP is the centroid of the largest clipped plateau: rc_to_uv([cy, cx]) + (col0, row0)
            n_big, cx, cy = _clipped_top(labels, clipped, cid, x, y, bw, bh, k_close, min_plateau_px, local_peak)
            merged = n_big > 1
            ints[k, SATURATED] = 1
            ints[k, N_PLATEAUS] = n_big
            bp_u = cx + (x + origin_x)
            bp_v = cy + (y + origin_y)
        # peak_uv: a flat top (another pixel of the component at the peak within the 3 x 3
        # neighbourhood) gives the centroid of its 8-connected piece, else the parabola
        n_top = 0
        for r in range(max(0, pr - 1), min(bh, pr + 2)):
            for c in range(max(0, pc - 1), min(bw, pc + 2)):
                if labels[y + r, x + c] == cid and gray[y + r, x + c] == best:
                    n_top += 1
        if sat:
            pass
        elif n_top <= 1:
            dr = 0.0
            dc = 0.0
            if not have_mn and _outside_cross(labels, cid, x, y, bw, bh, pr, pc):
                mn = _box_min(gray, x, y, bw, bh)
            if 0 < pr < bh - 1:
                dr = _parabola_offset(_value(gray, labels, cid, mn, y + pr - 1, x + pc), best,
                                      _value(gray, labels, cid, mn, y + pr + 1, x + pc))
            if 0 < pc < bw - 1:
                dc = _parabola_offset(_value(gray, labels, cid, mn, y + pr, x + pc - 1), best,
                                      _value(gray, labels, cid, mn, y + pr, x + pc + 1))
            # rc_to_uv([r + dr, c + dc]) + (col0, row0)
            bp_u = ((pc + dc) + 0.0) + (x + origin_x)
            bp_v = ((pr + dr) + 0.0) + (y + origin_y)
        else:
            seen = np.zeros((bh, bw), dtype=np.uint8)
            seen[pr, pc] = 1
            stack[0] = pr * bw + pc
            top = 1
            n = 0
            sr = 0
            sc = 0
            while top > 0:
                top -= 1
                p = stack[top]
                r, c = p // bw, p % bw
                n += 1
                sr += r
                sc += c
                if top + 8 > len(stack):
                    grown = np.empty(2 * len(stack), dtype=np.int64)
                    grown[:top] = stack[:top]
                    stack = grown
                for rr in range(max(0, r - 1), min(bh, r + 2)):
                    for cc in range(max(0, c - 1), min(bw, c + 2)):
                        if (not seen[rr, cc] and labels[y + rr, x + cc] == cid
                                and gray[y + rr, x + cc] == best):
                            seen[rr, cc] = 1
                            stack[top] = rr * bw + cc
                            top += 1
            # rc_to_uv([rr.mean(), cc.mean()]) + (col0, row0)
            bp_u = ((sc / n) + 0.0) + (x + origin_x)
            bp_v = ((sr / n) + 0.0) + (y + origin_y)
        status = MERGED if merged else OK
        if area < min_area_px:
            status = TOO_SMALL
        elif x == 0 or y == 0 or x + bw >= W or y + bh >= H:
            status = TOUCHES_BORDER
        else:
            black = False
            if has_scope:
                for r in range(y, y + bh):
                    for c in range(x, x + bw):
                        if scope[r, c]:
                            black = True
                            break
                    if black:
                        break
            if black:
                status = BLACK_BORDER
            elif status == OK and area >= 12:
                e, tol = _ellipticity(labels, cid, x, y, bw, bh, n_px, s_r, s_c)
                floats[k, ELLIPTICITY] = e
                floats[k, ELLIPTICITY_TOL] = tol
                if np.isnan(tol):
                    status = ELLIPTICITY_UNSURE
                else:
                    lo, hi = e * (1.0 - tol), e * (1.0 + tol)
                    if ellipticity_min <= lo and hi <= ellipticity_max:
                        status = OK
                    elif hi < ellipticity_min or lo > ellipticity_max:
                        status = NOT_ELLIPTICAL
                    else:
                        status = ELLIPTICITY_UNSURE
        # Roi.around(bp, half, (H, W))
        half = roi_scale * max(bw, bh) / 2.0 + roi_margin_px
        ints[k, ROI_ROW0] = max(0, int(np.floor(bp_v - half)))
        ints[k, ROI_ROW1] = min(H, int(np.ceil(bp_v + half)) + 1)
        ints[k, ROI_COL0] = max(0, int(np.floor(bp_u - half)))
        ints[k, ROI_COL1] = min(W, int(np.ceil(bp_u + half)) + 1)
        ints[k, STATUS] = status
        floats[k, BP_U] = bp_u
        floats[k, BP_V] = bp_v
        floats[k, PEAK] = peak
        if has_levels:
            lb = np.float64(levels[y + pr, x + pc])
            floats[k, LEVEL] = lb + peak_rel * (peak - lb)
    return ints, floats


@numba.njit(cache=True, nogil=True, inline="always")
def _reflected(p, n):
    """Index ``p`` of an axis of ``n`` samples with OpenCV's BORDER_REFLECT (``fedcba|abcdef``)."""
    while p < 0 or p >= n:
        if p < 0:
            p = -p - 1
        else:
            p = 2 * n - p - 1
    return p


@numba.njit(cache=True, nogil=True)
def _taps_row(kern, src, out):
    """``out[j] = sum_t kern[t] src[j + t]`` in float32 (the taps in order), for a contiguous row:
    one pass over the row per tap (vectorised)."""
    n = len(out)
    for j in range(n):
        out[j] = 0.0
    for t in range(len(kern)):
        kt = kern[t]
        for j in range(n):
            out[j] += kt * src[j + t]


@numba.njit(cache=True, nogil=True)
def window_component(native, r0, r1, c0, c1, kern, bg_small, peak_small, peak_rel, thr, gr, gc, g, bg, lab):
    """The candidate mask of ``local_peak_mask`` in a window of the full frame, from the frame's
    smoothing and the reduced frame's background and local peaks, and the 8-connected component
    of the window's mask that holds a candidate's BP pixel: what
    ``detect._component_at_full_resolution`` computed with a Gaussian blur of the window, two
    OpenCV enlargements, numpy's mask and ``cv2.connectedComponentsWithStats``, in one call.

    Parameters
    ----------
    native : ndarray of shape (H, W)
        The frame's unsmoothed luma (any real dtype).
    r0, r1, c0, c1 : int
        The window (rows r0:r1, columns c0:c1 of the frame).
    kern : ndarray of shape (2 K + 1,), float32
        The Gaussian's taps (``cv2.getGaussianKernel``): the window is smoothed as the whole frame
        is, with the frame's sides reflected (``BORDER_REFLECT``), in float32.
    bg_small, peak_small : ndarray, float32
        The reduced background and local peaks, enlarged to (H, W) bilinearly as
        ``cv2.resize(..., INTER_LINEAR)`` (its sample positions and clamping; float32).
    peak_rel, thr : float32
        As :func:`peak_mask`.
    gr, gc : int
        The reduced frame's BP in the window (row, column): the component's pixel is the largest
        smoothed value of the mask within 2 px of it (the first in row-major order).
    g, bg : ndarray of shape (r1 - r0, c1 - c0), float32
        Outputs: the window's smoothing and its background (``min(background, g)``).
    lab : ndarray of shape (r1 - r0, c1 - c0), int32
        Output: 1 on the component, 0 elsewhere.

    Returns
    -------
    (found, x, y, bw, bh, area) : (bool, int, int, int, int, int)
        Whether the mask holds a pixel near the BP, and the component's box (column, row,
        width, height in the window) and area.
    """
    H, W = native.shape
    nr, nc = r1 - r0, c1 - c0
    K = len(kern) // 2
    n_t = 2 * K + 1
    # horizontal pass over the rows the vertical one reads (the frame's sides reflected), each row
    # gathered once into a buffer (the taps' loop then runs over contiguous float32)
    cols = np.empty(nc + 2 * K, np.int64)
    for j in range(nc + 2 * K):
        cols[j] = _reflected(c0 - K + j, W)
    buf = np.empty(nc + 2 * K, np.float32)
    tmp = np.zeros((nr + 2 * K, nc), np.float32)
    acc = np.empty(nc, np.float32)
    inside = c0 - K >= 0 and c1 + K <= W  # no column reflected: each row read in order
    for i in range(nr + 2 * K):
        rr = _reflected(r0 - K + i, H)
        if inside:
            src_row = native[rr, c0 - K : c1 + K]
            for j in range(nc + 2 * K):
                buf[j] = np.float32(src_row[j])
        else:
            for j in range(nc + 2 * K):
                buf[j] = np.float32(native[rr, cols[j]])
        _taps_row(kern, buf, acc)
        tmp[i, :] = acc
    # the vertical pass row by row: each output row the taps' weighted sum of the rows below it,
    # in the taps' order (the same sums as along each column), over contiguous rows
    for i in range(nr):
        gi = g[i]
        for j in range(nc):
            gi[j] = 0.0
        for t in range(n_t):
            kt = kern[t]
            src = tmp[i + t]
            for j in range(nc):
                gi[j] += kt * src[j]
    # the mask: top-hat over the enlarged background, against the enlarged local peaks (each
    # column's sources computed once)
    sh, sw = bg_small.shape
    ph, pw = peak_small.shape
    one = np.float32(1.0)
    bx0 = np.empty(nc, np.int64)
    bx1 = np.empty(nc, np.int64)
    ax = np.empty(nc, np.float32)
    px0 = np.empty(nc, np.int64)
    px1 = np.empty(nc, np.int64)
    qx = np.empty(nc, np.float32)
    for j in range(nc):
        bx0[j], ax[j], bx1[j] = _linear_sample(c0 + j, sw, W)
        px0[j], qx[j], px1[j] = _linear_sample(c0 + j, pw, W)
    # each reduced row the window's rows read, enlarged along the row once (the rows of a
    # window read a few): the same products as per pixel, computed once per source row
    bs_lo, _, _ = _linear_sample(r0, sh, H)
    _, _, bs_hi = _linear_sample(r1 - 1, sh, H)
    ps_lo, _, _ = _linear_sample(r0, ph, H)
    _, _, ps_hi = _linear_sample(r1 - 1, ph, H)
    blines = _rows_enlarged(bg_small, bs_lo, bs_hi, bx0, bx1, ax)
    plines = _rows_enlarged(peak_small, ps_lo, ps_hi, px0, px1, qx)
    # the mask, padded by a row and a column of 0 on each side (the flood fill below needs no
    # bounds checks)
    W2 = nc + 2
    mp = np.zeros((nr + 2) * W2, np.uint8)
    for i in range(nr):
        by0, ay, by1 = _linear_sample(r0 + i, sh, H)
        py0, qy, py1 = _linear_sample(r0 + i, ph, H)
        btop, bbot = blines[by0 - bs_lo], blines[by1 - bs_lo]
        ptop, pbot = plines[py0 - ps_lo], plines[py1 - ps_lo]
        base = (i + 1) * W2 + 1
        for j in range(nc):
            b = btop[j] * (one - ay) + bbot[j] * ay
            v = g[i, j]
            m = b if (b <= v or b != b) else v
            bg[i, j] = m
            t = v - m
            p = ptop[j] * (one - qy) + pbot[j] * qy
            q = p if (p >= t or p != p) else t
            mp[base + j] = 1 if (t >= q * peak_rel and t >= thr) else 0
    # the BP's pixel: the largest smoothed value of the mask within 2 px of the reduced BP
    best = np.float32(-np.inf)
    pr, pc = -1, -1
    for i in range(max(0, gr - 2), min(nr, gr + 3)):
        for j in range(max(0, gc - 2), min(nc, gc + 3)):
            if mp[(i + 1) * W2 + j + 1] and g[i, j] > best:
                best = g[i, j]
                pr, pc = i, j
    for i in range(nr):
        for j in range(nc):
            lab[i, j] = 0
    if pr < 0:
        return False, 0, 0, 0, 0, 0
    # its 8-connected component: a span fill over the padded mask (each run of mask pixels along
    # a row filled at once and its mask cleared, the rows above and below scanned over the run
    # widened by a column on each side for the runs to fill next, one seed per run; the padding
    # needs no bounds checks). A pixel lies in the widened scans of at most two runs of each
    # neighbouring row: at most four pushes a pixel. The same component as the pixel-by-pixel
    # flood fill it replaced, in about half its time (0.16 -> 0.08 ms of the noisy bench frame's
    # ten windows)
    stack = np.empty(4 * nr * nc + 8, np.int64)
    stack[0] = (pr + 1) * W2 + pc + 1
    n_st = 1
    ya, yb, xa, xb = pr, pr, pc, pc
    area = 0
    while n_st > 0:
        n_st -= 1
        p = stack[n_st]
        if not mp[p]:  # filled by another run since it was pushed
            continue
        lo = p
        while mp[lo - 1]:
            lo -= 1
        hi = p
        while mp[hi + 1]:
            hi += 1
        i = p // W2 - 1
        j0 = lo - (i + 1) * W2 - 1
        for q in range(lo, hi + 1):
            mp[q] = 0
            lab[i, q - lo + j0] = 1
        area += hi - lo + 1
        ya, yb, xa, xb = min(ya, i), max(yb, i), min(xa, j0), max(xb, j0 + hi - lo)
        for q0 in (lo - 1 - W2, lo - 1 + W2):
            inrun = False
            for q in range(q0, q0 + hi - lo + 3):
                if mp[q]:
                    if not inrun:
                        stack[n_st] = q
                        n_st += 1
                        inrun = True
                else:
                    inrun = False
    return True, xa, ya, xb - xa + 1, yb - ya + 1, area


@numba.njit(cache=True, nogil=True)
def linear_rows(n_full, n_small):
    """OpenCV's INTER_LINEAR sources along one axis of an enlargement from ``n_small`` to
    ``n_full`` samples: per output index the lower source index, the upper one and the float32
    weight of the upper (``(i + 0.5) n_small / n_full - 0.5``, clamped at the sides)."""
    i0 = np.empty(n_full, np.int64)
    i1 = np.empty(n_full, np.int64)
    a = np.empty(n_full, np.float32)
    for i in range(n_full):
        k, w, k1 = _linear_sample(i, n_small, n_full)
        i0[i] = k
        i1[i] = k1
        a[i] = w
    return i0, i1, a


@numba.njit(cache=True, nogil=True)
def top_hat_rows(gray, wide, y0, y1, ay, background, top, thr, rows, hit_rows_only):
    """:func:`top_hat` with the background enlarged on the fly from ``wide`` (sh, W): the reduced
    opening enlarged along its rows only (``cv2.resize(bg_small, (W, sh), INTER_LINEAR)``),
    each frame row r weighing rows ``y0[r]`` and ``y1[r]`` of it by ``ay[r]``
    (:func:`linear_rows`): ``cv2.resize(bg_small, (W, H), INTER_LINEAR)`` to float32 rounding,
    without the full-size enlargement's pass (issue 41: a third of ``local_peak_mask``'s passes
    over the frame). ``background`` gets ``min(enlarged, gray)``; with ``hit_rows_only``, in the
    rows that hold a top-hat ``>= thr`` only (the rows of the candidates, whose levels are read
    there; the others unwritten: a third of the pass's memory traffic)."""
    h, w = gray.shape
    one = np.float32(1.0)
    for r in range(h):
        a = ay[r]
        b = one - a
        lo, hi = wide[y0[r]], wide[y1[r]]
        hit = 0
        for c in range(w):
            e = lo[c] * b + hi[c] * a
            g = gray[r, c]
            m = e if (e <= g or e != e) else g
            t = g - m
            top[r, c] = t
            hit |= t >= thr
        rows[r] = hit
        if hit or not hit_rows_only:
            for c in range(w):
                e = lo[c] * b + hi[c] * a
                g = gray[r, c]
                background[r, c] = e if (e <= g or e != e) else g


@numba.njit(cache=True, nogil=True)
def peak_mask_rows(top, wide, y0, y1, ay, peak_rel, thr, rows, mask):
    """:func:`peak_mask` with the local peaks enlarged on the fly from ``wide`` (the reduced local
    peaks enlarged along their rows, as :func:`top_hat_rows`), in the rows that hold a top-hat
    ``>= thr`` only."""
    h, w = top.shape
    one = np.float32(1.0)
    for r in range(h):
        if rows[r] == 0:
            for c in range(w):
                mask[r, c] = 0
            continue
        a = ay[r]
        b = one - a
        lo, hi = wide[y0[r]], wide[y1[r]]
        for c in range(w):
            t = top[r, c]
            p = lo[c] * b + hi[c] * a
            q = p if (p >= t or p != p) else t
            q = q * peak_rel
            mask[r, c] = 1 if (t >= q and t >= thr) else 0


@numba.njit(cache=True, nogil=True)
def components_at_full_resolution(native, boxes, bps, kern, bg_small, peak_small, peak_rel, thr, clipped, gray,
                                  levels, min_area_px, ellipticity_min, ellipticity_max, roi_scale, roi_margin_px,
                                  level_rel, k_close, min_plateau_px):
    """``detect._component_at_full_resolution`` and ``detect._examine_in_window`` of every
    candidate found on the reduced frame, in one call: each window around the candidate's box
    (grown until its component is not cut by a side inside the frame) by :func:`window_component`,
    then its component examined by :func:`examine_candidates` (``local_peak``, no scope border),
    the window's smoothing and background written into the frame's ``gray`` and ``levels``.

    Parameters
    ----------
    native, kern, bg_small, peak_small, peak_rel, thr
        As :func:`window_component`.
    boxes : ndarray of shape (n, 4), int64
        The reduced frame's boxes (row0, row1, col0, col1).
    bps : ndarray of shape (n, 2), float64
        The reduced frame's BPs (u, v).
    clipped : ndarray of shape (H, W), uint8, or of size 0
        The frame's clipped pixels.
    gray, levels : ndarray of shape (H, W), float32
        Outputs: the frame's smoothing and background, written in the windows.
    min_area_px .. roi_margin_px, k_close, min_plateau_px
        As :func:`examine_candidates`; ``level_rel`` is its ``peak_rel`` (float64, where
        ``peak_rel`` above is the mask's float32).

    Returns
    -------
    found : ndarray of shape (n,), bool
        Whether the BP's pixel is in the full frame's mask (where not, nothing else is set).
    ints, floats : as :func:`examine_candidates`, one row per candidate (BP in the frame; the
        ROI clipped to the window: the caller proposes the frame's)
    comp : ndarray of shape (n, 7), int64
        The component's box in the frame (column, row, width, height), its area, and the
        window's corner (row, column).
    """
    H, W = native.shape
    n = boxes.shape[0]
    found = np.zeros(n, np.bool_)
    ints = np.zeros((n, 7), np.int64)
    floats = np.full((n, 6), np.nan)
    comp = np.zeros((n, 7), np.int64)
    has_clipped = clipped.size > 0
    none_b = np.zeros((0, 0), np.bool_)
    none_u8 = np.zeros((0, 0), np.uint8)
    table = np.empty((1, 6), np.int64)
    for k in range(n):
        m = 4
        while True:
            r0, r1 = max(0, 2 * boxes[k, 0] - m), min(H, 2 * boxes[k, 1] + m)
            c0, c1 = max(0, 2 * boxes[k, 2] - m), min(W, 2 * boxes[k, 3] + m)
            # the BP's pixel: the largest smoothed value within 2 px of the reduced frame's BP
            gc = min(max(int(np.rint(2.0 * bps[k, 0] + 0.5)), c0), c1 - 1) - c0
            gr = min(max(int(np.rint(2.0 * bps[k, 1] + 0.5)), r0), r1 - 1) - r0
            g = np.empty((r1 - r0, c1 - c0), np.float32)
            bg = np.empty_like(g)
            lab = np.empty((r1 - r0, c1 - c0), np.int32)
            ok, x, y, bw, bh, area = window_component(native, r0, r1, c0, c1, kern, bg_small, peak_small,
                                                      peak_rel, thr, gr, gc, g, bg, lab)
            if not ok:
                break
            cut = ((x == 0 and c0 > 0) or (y == 0 and r0 > 0) or (x + bw == c1 - c0 and c1 < W)
                   or (y + bh == r1 - r0 and r1 < H))
            if not cut:
                break
            m *= 2
        if not ok:
            continue
        found[k] = True
        gray[r0:r1, c0:c1] = g
        levels[r0:r1, c0:c1] = bg
        table[0, 0], table[0, 1], table[0, 2], table[0, 3], table[0, 4], table[0, 5] = 1, x, y, bw, bh, area
        win_clipped = np.ascontiguousarray(clipped[r0:r1, c0:c1]) if has_clipped else none_u8
        i1, f1 = examine_candidates(g, lab, table, win_clipped, none_b, bg, min_area_px, ellipticity_min,
                                    ellipticity_max, roi_scale, roi_margin_px, level_rel, c0, r0, k_close,
                                    min_plateau_px, True)
        ints[k] = i1[0]
        floats[k] = f1[0]
        comp[k, 0], comp[k, 1], comp[k, 2], comp[k, 3], comp[k, 4] = x + c0, y + r0, bw, bh, area
        comp[k, 5], comp[k, 6] = r0, c0
    return found, ints, floats, comp


@numba.njit(cache=True, nogil=True)
def clipped_where_gray(img, gray, lo, out):
    """``detect.clipped_mask`` of an integer RGB image (H, W, C) from its gray (H, W): a pixel is
    clipped where every channel is >= ``lo``, tested only where the gray is >= ``lo`` (OpenCV's
    gray is a rounded weighted mean with positive weights summing to one: a clipped pixel's gray
    is >= ``lo``), so the frame's channels are read at those pixels only (``cv2.inRange`` over the
    rows that hold them read all three: 1.6 ms of the banner). ``out`` (H, W) uint8 gets 0/1;
    returns the count of ones."""
    H, W = gray.shape
    nch = img.shape[2]
    n = 0
    for r in range(H):
        grow = gray[r]
        orow = out[r]
        hit = False
        for c in range(W):
            orow[c] = 0
            hit |= grow[c] >= lo
        if not hit:
            continue
        for c in range(W):
            if grow[c] >= lo:
                ok = True
                for k in range(nch):
                    ok &= img[r, c, k] >= lo
                if ok:
                    orow[c] = 1
                    n += 1
    return n
