"""Compiled (numba) kernels of the reconstruction's per-highlight hot path.

Each kernel computes, in one compiled call, what a chain of numpy and OpenCV calls computed
before, with the same floating-point operations in the same order, so its results are the same
bits (``tests/test_kernels.py`` compares them with the numpy forms, which stay in the code as the
reference and the fallback). A real frame has hundreds of highlights, each a few hundred pixels:
there the fixed cost of each numpy call, not the arithmetic, was the time.

Kernels
-------
- :func:`count_enclosed`: how many other highlights' BPs an isophote encloses (``merged``).
- :func:`luma_rgb`: the luma of an RGB image or ROI.

Notes
-----
Compiled with ``cache=True``: the first call in a fresh environment compiles (about a second
each) and writes the machine code beside this file, or in numba's user cache when the package
folder is read-only; later processes load it. numba does not contract ``a * b + c`` into a fused
multiply-add unless ``fastmath`` is set (it is not here but for :func:`luma_rgb`, which contracts
as the BLAS product it replaces does), so the arithmetic rounds as numpy's.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _inside(poly, px, py):
    """Even-odd test of the point (px, py) against the closed polygon ``poly`` (N, 2), as
    :func:`simtest.reconstruct.isophote.polygon_contains`."""
    n = len(poly)
    count = 0
    for i in range(n):
        x, y = poly[i, 0], poly[i, 1]
        j = i + 1 if i + 1 < n else 0
        x2, y2 = poly[j, 0], poly[j, 1]
        if (y > py) != (y2 > py):
            if px < x + (py - y) * (x2 - x) / (y2 - y):
                count += 1
    return count % 2 == 1


@numba.njit(cache=True, nogil=True)
def _bounds(poly):
    """The bounding box of a polygon (N, 2), N >= 1: (min u, min v, max u, max v)."""
    lo_u, lo_v = poly[0, 0], poly[0, 1]
    hi_u, hi_v = lo_u, lo_v
    for i in range(1, len(poly)):
        u, v = poly[i, 0], poly[i, 1]
        if u < lo_u:
            lo_u = u
        if u > hi_u:
            hi_u = u
        if v < lo_v:
            lo_v = v
        if v > hi_v:
            hi_v = v
    return lo_u, lo_v, hi_u, hi_v


@numba.njit(cache=True, nogil=True)
def count_enclosed(poly, points, skip):
    """How many of ``points`` (k, 2) but row ``skip`` (-1: none) lie in the closed polygon
    ``poly`` (N, 2), N >= 1: those in its bounding box (bounds included), tested even-odd by
    :func:`_inside`. As ``polygon_contains(poly, points[near]).sum()`` with ``near`` the rows
    within ``poly.min(axis=0)`` and ``poly.max(axis=0)``, without a Python call per highlight
    (the pipeline's ``merged`` test)."""
    lo_u, lo_v, hi_u, hi_v = _bounds(poly)
    n = 0
    for k in range(len(points)):
        if k == skip:
            continue
        u, v = points[k, 0], points[k, 1]
        if lo_u <= u <= hi_u and lo_v <= v <= hi_v and _inside(poly, u, v):
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def count_enclosed_sorted_many(polys, starts, counts, points, us, skips):
    """:func:`count_enclosed_sorted` of several polygons in one call: polygon j is
    ``polys[starts[j]:starts[j] + counts[j]]`` (counts >= 1) and skips row ``skips[j]`` of the
    points (sorted by u, ``us`` their u); int64 (len(starts),). A frame's ``merged`` tests in one
    compiled call instead of one a highlight."""
    out = np.zeros(len(starts), np.int64)
    for j in range(len(starts)):
        out[j] = count_enclosed_sorted(polys[starts[j]:starts[j] + counts[j]], points, us, skips[j])
    return out


@numba.njit(cache=True, nogil=True)
def is_gray(img):
    """Whether R = G = B at every pixel of an (H, W, C >= 3) image (stops at the first colour
    pixel)."""
    H, W = img.shape[0], img.shape[1]
    for r in range(H):
        for c in range(W):
            if img[r, c, 0] != img[r, c, 1] or img[r, c, 0] != img[r, c, 2]:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _pixel_pairs_mask(rows):
    """All ones where a pair of neighbouring values of a packed RGB row (H, 3 W) lies within one
    pixel, zero across a pixel's boundary: (3 W - 1,), the rows' dtype."""
    n = rows.shape[1]
    m = np.zeros(n - 1, rows.dtype)
    for i in range(n - 1):
        if i % 3 != 2:
            m[i] = ~m[i]
    return m


@numba.njit(cache=True, nogil=True)
def _row_is_gray(rows, r, m):
    """Whether row r of a packed RGB image has R = G = B at every pixel: its neighbouring values
    XOR-ed, masked by :func:`_pixel_pairs_mask` and OR-ed together (a loop of unit stride that
    the compiler vectorises)."""
    acc = rows[r, 0] ^ rows[r, 0]
    for i in range(m.shape[0]):
        acc |= (rows[r, i] ^ rows[r, i + 1]) & m[i]
    return acc == 0


@numba.njit(cache=True, nogil=True)
def _row_is_gray_pixels(row, W):
    """Whether a packed RGB row (3 W,) has R = G = B at every pixel, read pixel by pixel: each
    pixel's values XOR-ed pairwise and OR-ed together. For 8-bit rows the compiler turns the
    stride-3 reads into vector shuffles: 0.29 ms on a 1350 x 1080 gray frame where the masked
    pairs of :func:`_row_is_gray` take 0.70 (2-core Xeon VM); for 16-bit rows the pairs are
    quicker (0.57 against 0.64 ms)."""
    acc = row[0] ^ row[0]
    for j in range(W):
        b0, b1, b2 = row[3 * j], row[3 * j + 1], row[3 * j + 2]
        acc |= (b0 ^ b1) | (b1 ^ b2)
    return acc == 0


@numba.njit(cache=True, nogil=True)
def is_gray_packed(rows):
    """:func:`is_gray` of a C-contiguous integer RGB image (H, W, 3) given as its rows (H, 3 W):
    an 8-bit row pixel by pixel (:func:`_row_is_gray_pixels`), a wider one's neighbouring values
    XOR-ed, the pairs across a pixel's boundary masked out, and OR-ed together
    (:func:`_row_is_gray`; each a loop the compiler vectorises); stops at the first row with a
    colour pixel."""
    H, n = rows.shape
    if H == 0 or n == 0:
        return True
    if rows.itemsize == 1:  # 8-bit: pixel by pixel (_row_is_gray_pixels), 0.70 -> 0.29 ms
        W = n // 3
        for r in range(H):
            if not _row_is_gray_pixels(rows[r], W):
                return False
        return True
    m = _pixel_pairs_mask(rows)
    for r in range(H):
        if not _row_is_gray(rows, r, m):
            return False
    return True


@numba.njit(cache=True, nogil=True, fastmath={"contract"})
def luma_rgb32(img, w0, w1, w2):
    """:func:`luma_rgb` rounded to float32 (H, W): ``luma_rgb(...).astype(np.float32)`` without
    the float64 frame."""
    H, W = img.shape[0], img.shape[1]
    out = np.empty((H, W), dtype=np.float32)
    for r in range(H):
        for c in range(W):
            out[r, c] = float(img[r, c, 0]) * w0 + float(img[r, c, 1]) * w1 + float(img[r, c, 2]) * w2
    return out


@numba.njit(cache=True, nogil=True)
def count_enclosed_sorted(poly, points, us, skip):
    """:func:`count_enclosed` of points sorted by u (``us`` their u, ascending): only the rows
    whose u lies in the polygon's u range are tested (binary search), so a frame of thousands of
    highlights costs n log n, not n^2; the same count."""
    lo_u, lo_v, hi_u, hi_v = _bounds(poly)
    n = 0
    for k in range(np.searchsorted(us, lo_u, "left"), np.searchsorted(us, hi_u, "right")):
        if k == skip:
            continue
        u, v = points[k, 0], points[k, 1]
        if lo_u <= u <= hi_u and lo_v <= v <= hi_v and _inside(poly, u, v):
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def multiple_counts(hist, mult_idx, mult_start):
    """Per candidate step and frequency, the coefficients within 1 of a nonzero multiple of the
    step: ``sum(np.add.reduceat(hist[mult_idx + d], mult_start, axis=0) for d in (-1, 0, 1))``
    of :func:`simtest.reconstruct.jpeg._steps_of` (a histogram (bins, K) of rounded magnitudes;
    the multiples of each step concatenated, each step's run starting at ``mult_start``, none
    empty), int64 (len(mult_start), K), without the gathered copies; and, of the same windows,
    the first multiple's count and the largest count at a later multiple (0 where the step has
    one multiple), each int64 (len(mult_start), K)."""
    nq = len(mult_start)
    K = hist.shape[1]
    out = np.zeros((nq, K), np.int64)
    first = np.zeros((nq, K), np.int64)
    later = np.zeros((nq, K), np.int64)
    for i in range(nq):
        j0 = mult_start[i]
        j1 = mult_start[i + 1] if i + 1 < nq else len(mult_idx)
        for j in range(j0, j1):
            b = mult_idx[j]
            for k in range(K):
                n = hist[b - 1, k] + hist[b, k] + hist[b + 1, k]
                out[i, k] += n
                if j == j0:
                    first[i, k] = n
                elif n > later[i, k]:
                    later[i, k] = n
    return out, first, later
