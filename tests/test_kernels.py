"""The compiled kernels (simtest.reconstruct._kernels) give the bits of the numpy forms they replace.

The numpy forms stay in the code as the reference and the fallback; each test runs both on random
inputs that reach every branch (closed, open, declined) and compares them bit for bit.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct import _kernels
from simtest.reconstruct.isophote import polygon_contains


def _enclosed_numpy(poly, points, skip):
    """The ``merged`` count as the pipeline computed it in numpy: the other points in the
    polygon's bounding box, tested by polygon_contains."""
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    near = np.all((points >= lo) & (points <= hi), axis=1)
    if skip >= 0:
        near[skip] = False
    return int(np.count_nonzero(polygon_contains(poly, points[near]))) if near.any() else 0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(3, 80), st.integers(0, 60))
def test_count_enclosed_is_the_bounding_box_and_even_odd_count(seed, n_vertices, n_points):
    rng = np.random.default_rng(seed)
    # a star-shaped (possibly self-touching) polygon, and points inside, outside, on its vertices
    # and on its bounding box's sides, where '<=' and the even-odd rule decide
    ang = np.sort(rng.uniform(0, 2 * np.pi, n_vertices))
    rad = rng.uniform(1.0, 20.0, n_vertices)
    poly = np.column_stack([50 + rad * np.cos(ang), 40 + rad * np.sin(ang)])
    pts = rng.uniform(25, 75, (n_points, 2))
    if n_points >= 4:
        pts[0] = poly[0]
        pts[1] = poly.min(axis=0)
        pts[2] = [poly[:, 0].max(), pts[2, 1]]
        pts[3] = np.round(pts[3])
    skip = int(rng.integers(-1, n_points)) if n_points else -1
    assert _kernels.count_enclosed(poly, pts.reshape(-1, 2), skip) == _enclosed_numpy(poly, pts.reshape(-1, 2), skip)


def test_the_float32_luma_and_the_gray_test():
    rng = np.random.default_rng(1)
    gray = rng.integers(0, 256, (20, 30), dtype=np.uint8)
    img = np.repeat(gray[:, :, None], 3, axis=2)
    w = (0.299, 0.587, 0.114)
    assert _kernels.is_gray(img)
    # the luma of (x, x, x) is x in float32: a gray frame's OpenCV gray is its luma
    assert np.array_equal(_kernels.luma_rgb32(img, *w), gray.astype(np.float32))
    img[3, 4, 1] += 1
    assert not _kernels.is_gray(img)
    assert np.array_equal(_kernels.luma_rgb32(img, *w), (img.astype(np.float64) @ np.array(w)).astype(np.float32))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n_points=st.integers(0, 60))
def test_count_enclosed_on_points_sorted_by_u_is_the_same_count(seed, n_points):
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 12))
    poly = np.stack([20 + rng.uniform(3, 9, 12) * np.cos(ang), 20 + rng.uniform(3, 9, 12) * np.sin(ang)], axis=1)
    pts = np.round(rng.uniform(5, 35, (n_points, 2)) * 2) / 2  # ties in u
    order = np.argsort(pts[:, 0], kind="stable")
    srt = np.ascontiguousarray(pts[order])
    for skip in (-1, *range(min(n_points, 3))):
        want = _kernels.count_enclosed(poly, pts, int(order[skip]) if skip >= 0 else -1)
        assert _kernels.count_enclosed_sorted(poly, srt, np.ascontiguousarray(srt[:, 0]), skip) == want


@given(seed=st.integers(0, 2**32 - 1), coarse=st.booleans())
@settings(max_examples=40, deadline=None)
def test_the_counts_near_each_steps_multiples_are_numpys_reduceat(seed, coarse):
    """jpeg._steps_of's counts of coefficients within 1 of each candidate step's multiples, one
    compiled pass (_kernels.multiple_counts), are numpy's three reduceat over gathered rows; its
    first multiple's count and the largest later one's are those rows' first and largest."""
    from simtest.reconstruct import jpeg

    nbin, qs, mult_idx, mult_start, _ = jpeg._COARSE if coarse else jpeg._FULL
    rng = np.random.default_rng(seed)
    hist = rng.integers(0, 50, (nbin, int(rng.integers(1, 65)))).astype(np.int32)
    windows = sum(hist[mult_idx + d].astype(np.int64) for d in (-1, 0, 1))  # (rows, K)
    want = np.add.reduceat(windows, mult_start, axis=0)
    at, first, later = _kernels.multiple_counts(hist, mult_idx, mult_start)
    assert np.array_equal(at, want)
    assert np.array_equal(first, windows[mult_start])
    ends = np.append(mult_start[1:], len(mult_idx))
    want_later = np.array([windows[a + 1:b].max(axis=0) if b > a + 1 else np.zeros(hist.shape[1], np.int64)
                           for a, b in zip(mult_start, ends)])
    assert np.array_equal(later, want_later)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(0, 40), st.integers(0, 2**31 - 1))
def test_count_enclosed_sorted_many_is_each_polygons_count(n_polys, n_points, seed):
    """The frame's ``merged`` tests in one call give each polygon's count_enclosed_sorted."""
    rng = np.random.default_rng(seed)
    polys = []
    for _ in range(n_polys):
        m = int(rng.integers(1, 30))
        ang = np.sort(rng.uniform(0, 2 * np.pi, m))
        c, r = rng.uniform(0, 50, 2), rng.uniform(1, 20)
        polys.append(np.c_[c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)])
    pts = rng.uniform(-5, 55, (n_points, 2))
    pts = pts[np.argsort(pts[:, 0], kind="stable")]
    us = np.ascontiguousarray(pts[:, 0])
    skips = rng.integers(-1, max(n_points, 1), n_polys)
    counts = np.array([len(p) for p in polys], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    got = _kernels.count_enclosed_sorted_many(np.concatenate(polys), starts, counts, pts, us, skips)
    want = [_kernels.count_enclosed_sorted(p, pts, us, int(s)) for p, s in zip(polys, skips)]
    assert got.tolist() == want


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.integers(1, 12), st.sampled_from([np.uint8, np.uint16]),
       st.integers(-1, 2))
def test_is_gray_packed_is_is_gray(seed, h, w, dtype, channel):
    """The packed rows' test (frame_prep._is_gray's) answers as the per-pixel one and as numpy, on
    gray frames and on gray frames with one pixel's channel changed (anywhere: the row ends, the
    last pixel)."""
    rng = np.random.default_rng(seed)
    g = rng.integers(0, np.iinfo(dtype).max, (h, w), endpoint=True).astype(dtype)
    img = np.repeat(g[:, :, None], 3, axis=2)
    if channel >= 0:
        r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
        img[r, c, channel] ^= dtype(1 + int(rng.integers(0, 100)))
    want = bool((img[..., 0] == img[..., 1]).all() and (img[..., 0] == img[..., 2]).all())
    assert bool(_kernels.is_gray_packed(img.reshape(h, -1))) == want
    assert bool(_kernels.is_gray(img)) == want
    from simtest.reconstruct.frame_prep import _is_gray

    assert _is_gray(img) == want and _is_gray(img[:, ::-1]) == want  # packed, and not contiguous
