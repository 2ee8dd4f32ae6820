"""The compiled kernels (simtest.reconstruct._kernels) give the bits of the numpy forms they replace.

The numpy forms stay in the code as the reference and the fallback; each test runs both on random
inputs that reach every branch (closed, open, declined) and compares them bit for bit.
"""

from __future__ import annotations

from unittest import mock

import cv2
import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.geometry.conics import Ellipse
from simtest.reconstruct import _kernels, pipeline, verify
from simtest.reconstruct.isophote import (Isophote, _cut_and_contour, _extract, _region, extract_isophote,
                                         isophote_cut_by_roi, polygon_contains)


def _extract_both(*args, **kwargs):
    """extract_isophote as it runs, and with the kernel declining every case (its numpy path)."""
    got = extract_isophote(*args, **kwargs)
    with mock.patch.object(_kernels, "component_contour",
                           lambda *a: (_kernels.FALLBACK, _kernels._EMPTY, False, (False,) * 4)):
        want = extract_isophote(*args, **kwargs)
    return got, want


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, Isophote):
        return ((a.closed, a.cut_by_roi, a.cut_by_image, a.level) == (b.closed, b.cut_by_roi, b.cut_by_image, b.level)
                and a.points_uv.shape == b.points_uv.shape
                and a.points_uv.tobytes() == b.points_uv.tobytes())
    return (a.reason, a.detail) == (b.reason, b.detail)


def _random_region(rng):
    """A region with one elliptic lobe, noise or quantisation (pixels exactly at a level), a hole
    (a ring) or none, a BP at the peak or anywhere, and a level from near 0 to the peak."""
    h, w = (int(v) for v in rng.integers(5, 60, 2))
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx, s = rng.uniform(0, h - 1), rng.uniform(0, w - 1), rng.uniform(1, 15)
    img = np.exp(-((yy - cy) ** 2 / (2 * s**2) + (xx - cx) ** 2 / (2 * (s * rng.uniform(0.5, 2)) ** 2)))
    img += rng.normal(0, rng.choice([0.0, 0.01, 0.05, 0.2]), img.shape)
    if rng.random() < 0.3:
        img = np.round(img * 20) / 20
    if rng.random() < 0.2:
        img -= 0.8 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * (s / 3) ** 2))
    r, c = np.unravel_index(np.argmax(img), img.shape)
    if rng.random() < 0.3:
        r, c = rng.integers(0, h), rng.integers(0, w)
    level = float(img[r, c] * rng.uniform(0.05, 1.0))
    if rng.random() < 0.1:
        level = float(np.round(img[r, c] * 10) / 20)
    off = (int(rng.integers(0, 50)), int(rng.integers(0, 50)))
    shape = (off[0] + h + int(rng.integers(0, 3)), off[1] + w + int(rng.integers(0, 3)))
    bp = np.array([c + rng.uniform(-0.5, 0.5) + off[1], r + rng.uniform(-0.5, 0.5) + off[0]])
    return img, level, bp, off, shape


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
# pixels within 1e-25 of a level 0 (a quantised lobe less a hole): interpolated points round onto
# pixel centres, where find_contours joins segments by their coordinates (an open contour lost a
# 12-point loop; a 5-point closed one appeared around a BP below the level)
@example(seed=5884)
@example(seed=19756)
def test_extract_isophote_gives_the_numpy_paths_bits(seed):
    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    try:
        got, want = _extract_both(img, level, bp, origin_rc=off, image_shape=shape,
                                  allow_open=True, min_points=0)
    except ValueError:  # a BP rounded outside the region: both raise before the kernel
        return
    assert _same(got, want)


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=100, deadline=None)
def test_a_region_read_in_place_from_a_wider_array_gives_the_same_isophote(seed):
    # the pipeline hands the kernels views of the frame's luma (row stride of the frame) uncopied
    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    wide = np.zeros((img.shape[0], img.shape[1] + 7))
    wide[:, 3 : 3 + img.shape[1]] = img
    view = wide[:, 3 : 3 + img.shape[1]]
    assert not view.flags.c_contiguous
    kw = dict(origin_rc=off, image_shape=shape, allow_open=True, min_points=0)
    try:
        a, b = extract_isophote(img, level, bp, **kw), extract_isophote(view, level, bp, **kw)
    except ValueError:
        return
    assert _same(a, b)
    assert isophote_cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape) == \
        isophote_cut_by_roi(view, level, bp, origin_rc=off, image_shape=shape)


def test_every_kernel_branch_is_reached_by_the_random_regions():
    # the property test above means something only if its inputs reach each branch
    rng = np.random.default_rng(0)
    codes = set()
    for _ in range(400):
        img, level, bp, off, _ = _random_region(rng)
        ri, ci = int(round(bp[1] - off[0])), int(round(bp[0] - off[1]))
        if 0 <= ri < img.shape[0] and 0 <= ci < img.shape[1]:
            codes.add(_kernels.component_contour(img, level, ri, ci, off[0], off[1], bp[0], bp[1])[0])
    assert codes == {_kernels.NOT_ABOVE, _kernels.CLOSED, _kernels.OPEN, _kernels.FALLBACK}


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_the_growth_question_has_the_extractions_answer(seed):
    # isophote_cut_by_roi answers what the pipeline asks before growing an ROI without tracing
    # the isophote: the extraction's cut_by_roi (False where it fails), or None where only the
    # extraction can tell
    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    try:
        iso = extract_isophote(img, level, bp, origin_rc=off, image_shape=shape, allow_open=True, min_points=0)
    except ValueError:
        return
    cut = isophote_cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape)
    if cut is not None:
        assert cut == (isinstance(iso, Isophote) and iso.cut_by_roi)


def test_the_growth_question_meets_each_answer():
    # the property test above means something only if the random regions give every answer
    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(400):
        img, level, bp, off, shape = _random_region(rng)
        try:
            seen.add(isophote_cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape))
        except ValueError:
            pass
    assert seen == {True, False, None}


def test_the_flood_fill_stops_at_a_side_asked_about():
    # a bar across the region: it reaches the left and right sides, not the top or bottom
    sub = np.zeros((9, 12))
    sub[4, :] = 1.0
    assert _kernels.component_reaches(sub, 0.5, 4, 6, False, False, True, False) == 1
    assert _kernels.component_reaches(sub, 0.5, 4, 6, True, True, False, False) == 0
    assert _kernels.component_reaches(sub, 0.5, 3, 6, True, True, True, True) == -1
    filled, x, y, w, h, stopped = _kernels._flood4(sub, 0.5, 4, 6, False, False, False, True)
    assert stopped and filled[4, 11] and not filled[4, 0]  # the fill went right first, and stopped
    filled, x, y, w, h, stopped = _kernels._flood4(sub, 0.5, 4, 6)
    assert not stopped and (x, y, w, h) == (0, 4, 12, 1) and filled.sum() == 12


def test_a_ring_a_neighbour_and_a_cut_highlight():
    # the exact cases the box construction is for: a hole raised, another component lowered, and
    # a component reaching two sides of the region (open contours in find_contours' order)
    img = np.zeros((30, 40))
    img[5:20, 5:20] = 1.0
    img[10:14, 10:14] = 0.0  # a hole
    img[5:9, 21:25] = 1.0  # touches the highlight at a corner only: another component
    got, want = _extract_both(img, 0.5, (12.0, 7.0), allow_open=True)
    assert got.closed and _same(got, want)
    img = np.zeros((30, 40))
    img[0:12, 25:40] = 1.0
    got, want = _extract_both(img, 0.5, (30.0, 5.0), allow_open=True)
    assert not got.closed and got.cut_by_image and _same(got, want)


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
       quantised=st.booleans(), layout=st.sampled_from(["C", "F", "view"]))
@settings(max_examples=200, deadline=None)
def test_border_median_is_numpys_median_of_the_ring(seed, h, w, quantised, layout):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(h, w))
    if quantised:  # repeated values: the even-count mean of two equal middles
        v = np.round(v * 3)
    if layout == "F":
        v = np.asfortranarray(v)
    elif layout == "view":
        v = np.pad(v, 2)[2:-2, 2:-2]
    ring = np.concatenate([v[0], v[-1], v[1:-1, 0], v[1:-1, -1]])
    # equal in value; a zero may come back as -0.0 where numpy's selection took +0.0 (or the
    # reverse): the levels offset + t * scale and i_bp - offset computed from it are the same bits
    assert float(_kernels.border_median(v)) == float(np.median(ring))


def test_border_median_of_a_nan_is_nan():
    v = np.ones((5, 6))
    v[0, 2] = np.nan
    assert np.isnan(_kernels.border_median(v))
    assert np.isnan(np.median(np.concatenate([v[0], v[-1], v[1:-1, 0], v[1:-1, -1]])))


@given(seed=st.integers(0, 2**32 - 1), dtype=st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]),
       strided=st.booleans())
@settings(max_examples=60, deadline=None)
def test_the_compiled_luma_is_the_blas_products_bits(seed, dtype, strided):
    # luma_rgb replaces numpy's image @ weights (OpenBLAS); detect.luma and every ROI's luma use it
    from simtest.reconstruct.detect import _LUMA, _LUMA_WEIGHTS, luma, packed_rows

    rng = np.random.default_rng(seed)
    # w >= 2: numpy's product of a one-column image, shape (h, 1, 3), is a stack of h 1 x 3
    # products, which numpy computes without fused multiply-adds, not OpenBLAS's matrix-vector
    # product (the last bit differs); the kernel gives a pixel the same bits whatever the width
    # (checked below), and no ROI is one pixel wide
    h, w = int(rng.integers(1, 80)), int(rng.integers(2, 80))
    if np.issubdtype(dtype, np.integer):
        img = rng.integers(0, np.iinfo(dtype).max, (h, w + 3, 3), dtype=dtype, endpoint=True)
    else:
        img = (rng.random((h, w + 3, 3)) * rng.choice([1.0, 255.0, 1e4])).astype(dtype)
    img = img[:, 2 : 2 + w] if strided else img[:, :w].copy()
    want = img.astype(np.float64) @ _LUMA
    got = _kernels.luma_rgb(img, *_LUMA_WEIGHTS)
    assert got.dtype == np.float64 and got.shape == (h, w)
    assert got.tobytes() == want.tobytes()
    assert luma(img).tobytes() == want.tobytes()
    assert _kernels.luma_rgb(img[:, 1:2], *_LUMA_WEIGHTS).tobytes() == got[:, 1:2].copy().tobytes()
    # luma_rows (the packed rows of a frame, or of a slice of one, as detect.luma and the
    # pipeline's float32 luma read them): the same bits, in float64 and float32
    rows = packed_rows(img)
    assert rows is not None and packed_rows(img[:, :, [0, 1, 2, 0]]) is None
    out = np.empty((h, w))
    _kernels.luma_rows(rows, *_LUMA_WEIGHTS, out)
    assert out.tobytes() == want.tobytes()
    assert pipeline._luma32(img).tobytes() == _kernels.luma_rgb32(img, *_LUMA_WEIGHTS).tobytes()


def _smooth_noise_region(rng):
    """A smoothed white-noise field (many components, holes, islands in holes), sometimes
    quantised (pixels exactly at the level), a pixel anywhere and a level below it."""
    from scipy.ndimage import gaussian_filter

    h, w = (int(v) for v in rng.integers(2, 70, 2))
    img = gaussian_filter(rng.normal(0, 1, (h, w)), rng.uniform(0.3, 4))
    steps = rng.choice([0, 30, 3 / img.std()]) if img.std() > 0 else 0  # quantisation steps per unit
    if steps:
        img = np.round(img * steps) / steps
    r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
    level = float(img[r, c] - abs(rng.normal(0, img.std() + 1e-9)))
    if steps and rng.random() < 0.5:  # a level some pixels are exactly at
        level = float(np.floor(level * steps) / steps)
    return img, level, r, c


def _kernel_args(seed):
    rng = np.random.default_rng(seed)
    if seed % 2:
        img, level, bp, off, _ = _random_region(rng)
        ri, ci = int(round(bp[1] - off[0])), int(round(bp[0] - off[1]))
        if not (0 <= ri < img.shape[0] and 0 <= ci < img.shape[1]):
            return None
        return img, level, ri, ci, off[0], off[1], float(bp[0]), float(bp[1])
    img, level, ri, ci = _smooth_noise_region(rng)
    return img, level, ri, ci, 3, 5, ci + 5 + rng.uniform(-0.5, 0.5), ri + 3 + rng.uniform(-0.5, 0.5)


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=500, deadline=None)
def test_the_boundary_walk_gives_the_flood_fills_bits(seed):
    # component_contour walks the component's boundary; component_contour_flood fills the
    # component and contours its box: the same code, points (bit for bit), inside test and sides
    args = _kernel_args(seed)
    if args is None:
        return
    a, b = _kernels.component_contour(*args), _kernels.component_contour_flood(*args)
    assert (a[0], a[2], tuple(a[3])) == (b[0], b[2], tuple(b[3]))
    assert a[1].shape == b[1].shape and a[1].tobytes() == b[1].tobytes()


def test_the_boundary_walk_itself_handles_closed_and_open_contours():
    # the property test above means something only if the walk, not its fallback, answers the
    # closed and open cases; on these regions it declines only where the flood fill also falls
    # back to find_contours or the region is under 3 x 3 px
    walked, declined = set(), set()
    for seed in range(600):
        args = _kernel_args(seed)
        if args is None:
            continue
        code = _kernels._contour_by_walk(*args)[0]
        if code == _kernels.DECLINED:
            declined.add(_kernels.component_contour_flood(*args)[0]
                         if min(args[0].shape) >= 3 else "small")
        else:
            walked.add(code)
    assert walked == {_kernels.NOT_ABOVE, _kernels.CLOSED, _kernels.OPEN}
    assert declined <= {_kernels.FALLBACK, "small"}


def test_a_pixel_at_the_level_anywhere_in_the_components_box_declines_the_walk():
    # find_contours' own handling of a pixel exactly at the level is left to it (FALLBACK); the
    # flood-fill kernel checks the component's box plus one pixel, so the walk checks the same box:
    # a pixel at the level on each of its four corners, one at a time
    for r, c in ((1, 2), (1, 5), (5, 2), (5, 5)):
        sub = np.zeros((8, 9))
        sub[2:5, 3:5] = 2.0  # the component: rows 2-4, columns 3-4
        sub[r, c] = 1.0
        got = _kernels.component_contour(sub, 1.0, 3, 3, 0, 0, 3.0, 3.0)
        assert got[0] == _kernels.component_contour_flood(sub, 1.0, 3, 3, 0, 0, 3.0, 3.0)[0] == _kernels.FALLBACK
    sub = np.zeros((8, 9))
    sub[2:5, 3:5] = 2.0
    sub[0, 0] = 1.0  # outside the box: the walk answers
    assert _kernels._contour_by_walk(sub, 1.0, 3, 3, 0, 0, 3.0, 3.0)[0] == _kernels.CLOSED


@given(seed=st.integers(0, 2**32 - 1), flags=st.tuples(st.booleans(), st.booleans(), st.booleans(), st.booleans()))
@settings(max_examples=400, deadline=None)
def test_one_walk_answers_the_growth_question_and_traces_the_contour(seed, flags):
    # the pipeline asks whether an ROI's lowest isophote is cut and then extracts it: one walk
    # gives component_reaches' answer, which is the flood fill's, and component_contour's result
    # (bit for bit) where it traced it; it says DECLINED where component_contour's flood fill must
    # decide, CUT where it stopped at an open contour reaching a side asked about
    args = _kernel_args(seed)
    if args is None:
        return
    sub, level, ri, ci = args[:4]
    got = _kernels.component_reaches_contour(*args, *flags)
    assert got[0] == _kernels.component_reaches(sub, level, ri, ci, *flags) == \
        _kernels.component_reaches_flood(sub, level, ri, ci, *flags)
    if got[1] == _kernels.CUT:  # stopped at an open contour reaching a side asked about
        assert got[0] == 1 and _kernels.component_contour(*args)[0] in (_kernels.OPEN, _kernels.FALLBACK)
        return
    if got[1] == _kernels.DECLINED:
        assert _kernels._contour_by_walk(*args)[0] == _kernels.DECLINED
        return
    want = _kernels.component_contour(*args)
    assert (got[1], got[3], tuple(got[4])) == (want[0], want[2], tuple(want[3]))
    assert got[2].shape == want[1].shape and got[2].tobytes() == want[1].tobytes()


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_the_extraction_from_the_growth_walk_is_the_extraction(seed):
    # isophote._extract given the contour the growth question traced (_cut_and_contour) returns
    # what it returns when it traces the contour itself
    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    try:
        region = _region(img, bp, off, shape)
    except ValueError:
        return
    cut, walked = _cut_and_contour(region, level)
    assert cut == isophote_cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape)
    assert _same(_extract(region, level, True, 0, walked), _extract(region, level, True, 0))


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


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), channels=st.sampled_from([1, 3]), sigma=st.sampled_from([0.8, 1.7, 2.5]),
       dtype=st.sampled_from([np.uint8, np.float64]), r0=st.integers(0, 20), c0=st.integers(0, 20),
       h=st.integers(1, 30), w=st.integers(1, 30))
def test_the_border_level_of_an_roi_smoothed_alone_from_its_ring(seed, channels, sigma, dtype, r0, c0, h, w):
    """smoothed_border_median (the pipeline's local background level when the frame is smoothed
    once) is the median of the ring of the ROI's luma smoothed alone by OpenCV, its sides
    reflected, to rounding; ROIs down to one pixel (reflected more than once)."""
    import cv2

    from simtest.reconstruct.detect import luma
    from simtest.reconstruct.pipeline import _LUMA_W, _gaussian_kernel

    rng = np.random.default_rng(seed)
    img = rng.uniform(0, 255, (50, 50, channels))
    img = img.astype(np.uint8) if dtype == np.uint8 else img
    roi = img[r0 : r0 + h, c0 : c0 + w]
    vals = luma(roi if channels == 3 else roi[:, :, 0])
    want = _kernels.border_median(cv2.GaussianBlur(vals, (0, 0), sigma, borderType=cv2.BORDER_REFLECT))
    got = _kernels.smoothed_border_median(img, *_LUMA_W, r0, r0 + roi.shape[0], c0, c0 + roi.shape[1],
                                          _gaussian_kernel(sigma))
    # the same sums in another order (OpenCV: the row pass first, over the ROI): float64 rounding
    assert abs(got - want) <= 1e-9 * max(1.0, abs(want))


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
    assert np.array_equal(_kernels.luma_rgb32(img, *w), _kernels.luma_rgb(img, *w).astype(np.float32))


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


def _other_peaks_loop(top, xs, ys, bps, ij, reach, height, noise, ellipses, todo):
    """verify's neighbour count as it was before the compiled call: a k-d tree's ball around each
    BP, then verify._other_peaks (OpenCV's labels) on each candidate that has peaks in it."""
    from scipy.spatial import cKDTree

    from simtest.reconstruct import verify

    out = np.zeros(len(todo), np.int64)
    tree = cKDTree(np.c_[xs, ys].astype(np.float64))
    for i, (k, idx) in enumerate(zip(todo, tree.query_ball_point(bps[todo], reach[todo]))):
        if idx:
            out[i] = verify._other_peaks(top, xs[idx], ys[idx], ij[k], reach[k], height[k], noise,
                                         None if ellipses is None else ellipses[k])
    return out


@given(seed=st.integers(0, 2**32 - 1), with_ellipses=st.booleans())
@settings(max_examples=150, deadline=None)
def test_other_peaks_counts_the_neighbours_verifys_loop_counted(seed, with_ellipses):
    """The compiled neighbour count (verify._other_peaks_compiled) against the loop of
    verify._other_peaks it replaced, on random top-hats of Gaussian lobes, plateaus and noise
    (valleys above and below the level, peaks on the BP's own lobe and on others, BPs at the
    frame's edges, below the level, and inside and outside their ellipses)."""
    from simtest.geometry.conics import Ellipse
    from simtest.reconstruct import verify

    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(20, 90)), int(rng.integers(20, 90))
    yy, xx = np.mgrid[0:h, 0:w]
    top = rng.normal(0, 0.5, (h, w))
    for _ in range(int(rng.integers(1, 12))):
        cy, cx, s, a = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.7, 6), rng.uniform(5, 60)
        top += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    top = np.maximum(np.round(top, int(rng.integers(0, 2))), 0.0).astype(np.float32)
    ys, xs = np.nonzero((top >= np.maximum.reduce([np.roll(np.roll(top, dy, 0), dx, 1)
                                                   for dy in (-1, 0, 1) for dx in (-1, 0, 1)])) & (top > 2))
    xs, ys = xs.astype(np.int64), ys.astype(np.int64)
    if not len(xs):
        return
    n = int(rng.integers(1, 15))
    pick = rng.integers(0, len(xs), n)
    bps = np.c_[xs[pick], ys[pick]] + rng.uniform(-0.6, 0.6, (n, 2))
    bps[rng.random(n) < 0.2] = rng.uniform(0, [w, h], (1, 2))  # some BPs not on a peak
    ij = np.clip(np.rint(bps).astype(np.int64), 0, [w - 1, h - 1])
    reach = rng.uniform(1, 40, n)
    reach[rng.random(n) < 0.2] = np.nan
    height = top[ij[:, 1], ij[:, 0]]
    ellipses = None
    if with_ellipses:
        ellipses = [None if rng.random() < 0.2 else
                    Ellipse(center=bps[k] + rng.normal(0, 1, 2), semi_axes=np.sort(rng.uniform(0.5, 12, 2))[::-1],
                            angle_rad=float(rng.uniform(-np.pi, np.pi))) for k in range(n)]
    todo = np.flatnonzero(np.isfinite(reach))
    if not len(todo):
        return
    noise = float(rng.uniform(0, 3))
    args = (top, xs, ys, bps, ij, reach, height, noise, ellipses, todo)
    np.testing.assert_array_equal(verify._other_peaks_compiled(*args), _other_peaks_loop(*args))


def test_other_peaks_meets_each_case():
    """A peak on the BP's own lobe, one beyond a valley, one too small, one on the background."""
    from simtest.reconstruct import verify

    top = np.zeros((30, 60), np.float32)
    top[10:20, 5:15] = 100.0  # the candidate's lobe, 100 px
    top[14, 12] = 101.0  # a peak on its own lobe: not a neighbour
    top[10:20, 30:40] = 90.0  # another lobe beyond a valley: a neighbour
    top[15, 50] = 95.0  # a one-pixel glint: under a tenth of the lobe's area
    xs, ys = np.array([12, 35, 50], np.int64), np.array([14, 15, 15], np.int64)
    bps = np.array([[12.0, 14.0]])
    ij = bps.astype(np.int64)
    args = (top, xs, ys, bps, ij, np.array([45.0]), np.array([100.0], np.float32), 1.0, None, np.array([0]))
    assert verify._other_peaks_compiled(*args)[0] == 1 == _other_peaks_loop(*args)[0]


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 30), w=st.integers(1, 30), plateau=st.booleans())
@settings(max_examples=200, deadline=None)
def test_top_hat_maxima_are_numpys_and_opencvs(seed, h, w, plateau):
    """verify's top-hat and its 3 x 3 maxima above the floor, compiled, against the numpy and
    OpenCV form they replace (np.maximum, cv2.dilate, np.flatnonzero), on quantised values
    (plateaus: ties with neighbours), negative differences, and a floor rounded to float32."""
    import cv2

    rng = np.random.default_rng(seed)
    g = rng.normal(10, 5, (h, w)).astype(np.float32)
    if plateau:
        g = np.round(g / 4) * 4
    bg = rng.normal(8, 3, (h, w)).astype(np.float32)
    floor = float(rng.uniform(0, 8)) + 1e-9  # not a float32: numpy rounds it to compare
    want_top = np.maximum(g - bg, 0.0)
    want = np.flatnonzero((want_top >= cv2.dilate(want_top, np.ones((3, 3), np.uint8))) & (want_top > floor))
    top, mask = np.empty_like(g), np.empty((h, w), bool)
    _kernels.top_hat_maxima(g, bg, np.float32(floor), top, mask)
    assert top.tobytes() == want_top.tobytes()
    np.testing.assert_array_equal(np.flatnonzero(mask), want)


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40))
@settings(max_examples=200, deadline=None)
def test_flat_pixels_are_numpys(seed, h, w):
    """The flat mask of verify._panels, compiled, against its numpy form, on the 5 x 5 means of
    a luma with flat, quantised and noisy parts (variances that round below zero included)."""
    import cv2

    rng = np.random.default_rng(seed)
    g = np.round(rng.normal(100, rng.uniform(0, 3), (h, w)), int(rng.integers(0, 3))).astype(np.float32)
    g[: h // 2] = np.float32(rng.uniform(0, 255))  # a flat part: m2 - m1^2 rounds about 0
    m1, m2 = cv2.blur(g, (5, 5)), cv2.blur(g * g, (5, 5))
    thr = float(rng.uniform(0, 1.5))
    want = (np.sqrt(np.maximum(m2 - m1 * m1, 0.0)) < thr).astype(np.uint8)
    out = np.empty((h, w), np.uint8)
    n = _kernels.flat_pixels(m1, m2, np.float32(thr), out)
    assert out.tobytes() == want.tobytes() and n == int(want.sum())


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40))
@settings(max_examples=100, deadline=None)
def test_label_areas_and_labels_in_are_numpys(seed, h, w):
    """The label areas and the big labels' pixels of verify._panels, compiled, against
    np.bincount and a table indexed by the labels."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 12))
    lab = rng.integers(0, n, (h, w)).astype(np.int32)
    areas = _kernels.label_areas(lab, n)
    np.testing.assert_array_equal(areas, np.bincount(lab.ravel(), minlength=n))
    keep = (rng.random(n) < 0.5).astype(np.uint8)
    out = np.empty((h, w), np.uint8)
    _kernels.labels_in(lab, keep, out)
    assert out.tobytes() == keep[lab].tobytes()


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 20), w=st.integers(1, 20),
       kind=st.sampled_from(["rgb8", "rgba8", "grey8", "rgb32nan", "grey64"]))
@settings(max_examples=100, deadline=None)
def test_rgb_gathers_are_numpys(seed, h, w, kind):
    """_kernels.rgb_at_points and rgb_max9 (frame_evidence's colours at the maxima and the 3 x 3
    maximum around each BP) against the numpy gathers they replaced: float32, a grey frame's
    channel repeated, the window clipped at the sides, NaN propagated."""
    rng = np.random.default_rng(seed)
    c = {"rgb8": 3, "rgba8": 4, "grey8": 0, "rgb32nan": 3, "grey64": 0}[kind]
    shape = (h, w, c) if c else (h, w)
    if kind.endswith("8"):
        img = rng.integers(0, 256, shape).astype(np.uint8)
    else:
        img = rng.normal(100.0, 30.0, shape).astype(np.float32 if "32" in kind else np.float64)
        if "nan" in kind:
            img[rng.random(shape) < 0.05] = np.nan
    src = img[..., :3] if img.ndim == 3 else img  # frame_evidence's view (RGBA: not contiguous)
    src3 = src if src.ndim == 3 else src[:, :, None]

    def numpy_at(r, c):
        v = src[r, c].astype(np.float32)
        return v if src.ndim == 3 else np.repeat(v[..., None], 3, -1)
    rows, cols = rng.integers(0, h, 25).astype(np.int64), rng.integers(0, w, 25).astype(np.int64)
    np.testing.assert_array_equal(_kernels.rgb_at_points(src3, rows, cols), numpy_at(rows, cols))
    dr, dc = np.repeat(np.arange(-1, 2), 3), np.tile(np.arange(-1, 2), 3)
    want = numpy_at(np.clip(rows[:, None] + dr, 0, h - 1), np.clip(cols[:, None] + dc, 0, w - 1)).max(axis=1)
    got = _kernels.rgb_max9(src3, rows, cols)
    assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True)


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 30), w=st.integers(1, 30), n=st.integers(0, 5))
@settings(max_examples=100, deadline=None)
def test_in_windows_is_the_windows_coverage(seed, h, w, n):
    """_kernels.in_windows (the maxima frame_evidence keeps on a frame measured whole) against
    numpy's coverage of the windows, empty ones and none included."""
    rng = np.random.default_rng(seed)
    wins = np.array([(*sorted(rng.integers(0, h + 1, 2)), *sorted(rng.integers(0, w + 1, 2))) for _ in range(n)],
                    np.int64).reshape(-1, 4)
    cover = np.zeros((h, w), bool)
    for r0, r1, c0, c1 in wins:
        cover[r0:r1, c0:c1] = True
    idx = rng.integers(0, h * w, 40).astype(np.int64)
    assert _kernels.in_windows(idx, h, w, wins).tolist() == cover.ravel()[idx].tolist()


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40), fill=st.floats(0.02, 0.8),
       min_area=st.integers(1, 40))
@settings(max_examples=150, deadline=None)
def test_big_component_counts_are_the_panel_maps_integral_sums(seed, h, w, fill, min_area):
    """The panel pixels of each region counted from the mask's runs (_kernels.big_component_counts)
    against what frame_evidence counted before: OpenCV's 8-connected labels, the components of
    at least min_area px, their map summed over the region (regions clipped to the mask, empty
    and reaching past its sides too)."""
    from simtest.reconstruct.detect import connected_components
    rng = np.random.default_rng(seed)
    mask = (rng.random((h, w)) < fill).astype(np.uint8)
    n, lab = connected_components(mask)
    big = np.bincount(lab.ravel(), minlength=n) >= min_area
    big[0] = False
    panel = big[lab]
    rr = np.sort(rng.integers(-3, max(h, w) + 3, (12, 4)), axis=1).astype(np.int64)
    want = [int(panel[max(0, a):max(0, b), max(0, c):max(0, d)].sum()) for a, b, c, d in rr]
    assert _kernels.big_component_counts(mask, float(min_area), rr).tolist() == want


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 60), w=st.integers(1, 60), k=st.integers(1, 70),
       quantised=st.booleans())
@settings(max_examples=200, deadline=None)
def test_the_compiled_opening_is_opencvs(seed, h, w, k, quantised):
    """van Herk and Gil-Werman's running extremes give OpenCV's grey opening by a square, edges
    replicated: the same values (minima and maxima are exact), squares wider than the array too."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 10.0, (h, w)).astype(np.float32)
    if quantised:  # ties
        x = np.round(x / 5.0).astype(np.float32)
    k |= 1
    want = cv2.morphologyEx(x, cv2.MORPH_OPEN, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    got = _kernels.rect_opening(x, k)
    # equal values (a tie of 0.0 and -0.0 may keep either sign, as OpenCV's SIMD min may)
    assert got.dtype == np.float32 and np.array_equal(got, want)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), dtype=st.sampled_from([np.uint8, np.float32, np.float64]))
@settings(max_examples=60, deadline=None)
def test_the_surround_of_several_candidates_in_one_call_is_verifys_loop(seed, n, dtype):
    """verify._surround_fractions (one compiled call) gives verify._surround_fraction's share of
    each candidate, windows cut by the frame's edges included."""
    rng = np.random.default_rng(seed)
    h, w = 90, 120
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = rng.uniform(0, 30, (h, w))
    ells, ij, reach = [], [], []
    for _ in range(n):
        cu, cv = rng.uniform(0, w - 1), rng.uniform(0, h - 1)
        s, q, ang = rng.uniform(1.5, 8.0), rng.uniform(0.4, 1.0), rng.uniform(0, np.pi)
        c, si = np.cos(ang), np.sin(ang)
        x, y = c * (xx - cu) + si * (yy - cv), -si * (xx - cu) + c * (yy - cv)
        img += rng.uniform(50, 200) * np.exp(-0.5 * ((x / s) ** 2 + (y / (q * s)) ** 2))
        r07 = np.sqrt(2 * np.log(1 / 0.7))
        ells.append(Ellipse(np.array([cu, cv]), np.array([r07 * s, r07 * q * s]), ang))
        ij.append([int(round(cu)), int(round(cv))])
        reach.append(verify.NEIGHBOUR_REACH * r07 * s + verify.OWN_RADIUS_PX)
    img = np.clip(img, 0, 255).astype(dtype)
    ij, reach = np.array(ij), np.array(reach)
    want = [verify._surround_fraction(img, e, b, r) for e, b, r in zip(ells, ij, reach)]
    assert verify._surround_fractions(img, ells, ij, reach).tolist() == want


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


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 20), st.integers(2, 20), st.integers(2, 8), st.sampled_from([1, 3]), st.integers(0, 2**31 - 1))
def test_linear_at_points_is_opencvs_enlargement_read_at_those_pixels(sh, sw, f, channels, seed):
    # the verifier reads the enlarged reduced opening at a few pixels only; the values are
    # OpenCV's INTER_LINEAR ones, up to float32 rounding of values below 256 (2^-15 relative)
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (sh, sw, channels)).astype(np.float32)
    h, w = sh * f, sw * f
    big = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR).reshape(h, w, channels)
    rows, cols = rng.integers(0, h, 40), rng.integers(0, w, 40)
    got = _kernels.linear_at_points(small, h, w, rows, cols)
    assert np.allclose(got, big[rows, cols], rtol=0, atol=255 * 2.0 ** -15)


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


def test_smoothed_border_medians_are_each_rois_own():
    """The first ROIs' rings of a frame in one call give each ROI's smoothed_border_median."""
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (60, 80, 3)).astype(np.uint8)
    kern = cv2.getGaussianKernel(9, 1.5, cv2.CV_64F).ravel()
    rois = np.array([[0, 60, 0, 80], [5, 20, 7, 40], [30, 31, 2, 3], [10, 59, 70, 80]], dtype=np.int64)
    got = _kernels.smoothed_border_medians(img, 0.299, 0.587, 0.114, rois, kern)
    want = [_kernels.smoothed_border_median(img, 0.299, 0.587, 0.114, *r, kern) for r in rois.tolist()]
    assert got.tolist() == want


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.integers(1, 12), st.sampled_from([np.uint8, np.uint16]),
       st.integers(-1, 2))
def test_is_gray_packed_is_is_gray(seed, h, w, dtype, channel):
    """The packed rows' test (pipeline._is_gray's) answers as the per-pixel one and as numpy, on
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
    from simtest.reconstruct.pipeline import _is_gray

    assert _is_gray(img) == want and _is_gray(img[:, ::-1]) == want  # packed, and not contiguous
    # detection's test and copy of a gray frame's channel in one pass: the same answer, and where
    # gray the R channel itself
    out = np.zeros((h, w), dtype)
    assert bool(_kernels.grey_channel_packed(img.reshape(h, -1), out)) == want
    if want:
        assert np.array_equal(out, img[..., 0])
