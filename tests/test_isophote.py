"""Isophote extraction by marching squares: coordinates, contour choice, cuts, failures."""

from __future__ import annotations

import ast
import inspect

import cv2
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

import simtest.reconstruct as rec_pkg
from simtest.reconstruct._pixels import Roi, rc_to_uv, uv_to_rc
from simtest.reconstruct.isophote import extract_isophote, polygon_area, polygon_contains


def paraboloid(shape, centre_uv, radius):
    """1 - (r / radius)^2, clipped at 0: its level L is the circle of radius radius*sqrt(1 - L)."""
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    r2 = (u - centre_uv[0]) ** 2 + (v - centre_uv[1]) ** 2
    return np.clip(1.0 - r2 / radius**2, 0.0, None)


def test_rc_to_uv_worked_number_and_inverse():
    assert rc_to_uv([10, 20]).tolist() == [20.0, 10.0]
    assert rc_to_uv([[10, 20]], row0=5, col0=7).tolist() == [[27.0, 15.0]]
    assert uv_to_rc(rc_to_uv([3.5, 4.25])).tolist() == [3.5, 4.25]


def test_the_swap_happens_in_one_function_only():
    # Every module of simtest.reconstruct goes through rc_to_uv / uv_to_rc: no other function
    # indexes a coordinate array as [..., 1] and [..., 0] in swapped order. A cheap static check:
    # only _pixels.py may stack columns [1] then [0].
    import pathlib

    pkg = pathlib.Path(inspect.getfile(rec_pkg)).parent
    offenders = []
    for path in pkg.glob("*.py"):
        if path.name == "_pixels.py":
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.List, ast.Tuple)) and len(node.elts) == 2:
                idx = []
                for el in node.elts:
                    if isinstance(el, ast.Subscript):
                        sl = el.slice
                        if isinstance(sl, ast.Tuple) and sl.elts:
                            sl = sl.elts[-1]
                        if isinstance(sl, ast.Constant) and isinstance(sl.value, int):
                            idx.append(sl.value)
                if idx == [1, 0]:
                    offenders.append(f"{path.name}:{node.lineno}")
    assert not offenders, offenders


@given(cu=st.floats(30, 90), cv=st.floats(25, 55), radius=st.floats(15, 24), level=st.floats(0.1, 0.9))
@settings(max_examples=50, deadline=None)
def test_contour_of_a_paraboloid_is_its_circle_in_uv(cu, cv, radius, level):
    # An off-centre, non-square image: a (row, col) swap would move the centre by (cv - cu).
    img = paraboloid((80, 120), (cu, cv), radius)
    iso = extract_isophote(img, level, (cu, cv))
    assert iso and iso.closed and not (iso.cut_by_roi or iso.cut_by_image)
    rho = radius * np.sqrt(1 - level)
    d = np.hypot(iso.points_uv[:, 0] - cu, iso.points_uv[:, 1] - cv)
    # Linear interpolation of r^2 along a pixel edge errs by at most h^2 / (8 rho) ~ 0.01 px for
    # rho >= 4.7 px (h = 1 px; second difference of r^2 is 2h^2): 0.03 px is a safe bound.
    assert np.abs(d - rho).max() < 0.03
    # a closed contour is returned without its repeated end point
    assert not np.array_equal(iso.points_uv[0], iso.points_uv[-1])


def test_picks_the_contour_around_the_bp():
    img = np.maximum(paraboloid((60, 140), (30, 30), 15), paraboloid((60, 140), (100, 30), 12))
    left = extract_isophote(img, 0.5, (30, 30))
    right = extract_isophote(img, 0.5, (100, 30))
    assert np.allclose(left.points_uv.mean(axis=0), (30, 30), atol=0.05)   # symmetric contour
    assert np.allclose(right.points_uv.mean(axis=0), (100, 30), atol=0.05)


def test_innermost_closed_contour_wins_over_a_bright_ring():
    v, u = np.mgrid[0:101, 0:101].astype(float)
    r = np.hypot(u - 50, v - 50)
    img = np.exp(-(r / 8) ** 2) + 0.8 * np.exp(-((r - 35) / 3) ** 2)  # highlight and a ring
    iso = extract_isophote(img, 0.5, (50, 50))
    # the level-0.5 circle of the central lobe: 8 sqrt(ln 2) = 6.66 px, not the ring at ~33-37
    d = np.hypot(iso.points_uv[:, 0] - 50, iso.points_uv[:, 1] - 50)
    assert d.max() < 8


def test_cut_by_image_border_is_reported_and_fitted_only_when_allowed():
    img = paraboloid((60, 60), (5, 30), 20)  # the level-0.5 circle (r = 14) leaves the left side
    refused = extract_isophote(img, 0.5, (5, 30))
    assert not refused and refused.reason == "contour_cut"
    iso = extract_isophote(img, 0.5, (5, 30), allow_open=True)
    assert iso and not iso.closed and iso.cut_by_image and not iso.cut_by_roi
    assert len(iso.points_uv) >= 6


def test_cut_by_roi_is_told_apart_from_the_image_border():
    img = paraboloid((100, 100), (50, 50), 30)
    roi = Roi(35, 65, 20, 80)  # the level-0.2 circle (r = 26.8) leaves this ROI at top and bottom
    iso = extract_isophote(img[roi.slices], 0.2, (50, 50), origin_rc=(35, 20), image_shape=img.shape,
                           allow_open=True)
    assert iso and iso.cut_by_roi and not iso.cut_by_image and not iso.closed
    # points are in full-image coordinates, on the circle
    assert iso.points_uv[:, 1].min() >= 35 and iso.points_uv[:, 1].max() <= 64
    d = np.hypot(iso.points_uv[:, 0] - 50, iso.points_uv[:, 1] - 50)
    assert np.abs(d - 30 * np.sqrt(0.8)).max() < 0.03  # as in the paraboloid test above
    # an ROI wholly inside the isophote: no contour at all, but reported as cut by the ROI
    inner = Roi(40, 60, 40, 60)
    f = extract_isophote(img[inner.slices], 0.2, (50, 50), origin_rc=(40, 40), image_shape=img.shape)
    assert not f and f.reason == "contour_cut"
    iso = extract_isophote(img[inner.slices], 0.2, (50, 50), origin_rc=(40, 40), image_shape=img.shape,
                           allow_open=True, min_points=0)
    assert iso.cut_by_roi and len(iso.points_uv) == 0


def test_failures():
    img = np.zeros((20, 20))
    img[10, 10] = 1.0  # one bright pixel: marching squares gives a 4-point diamond
    f = extract_isophote(img, 0.5, (10, 10))
    assert not f and f.reason == "too_few_points"
    f = extract_isophote(img, 2.0, (10, 10))
    assert not f and f.reason == "bp_below_isovalue"
    f = extract_isophote(np.zeros((20, 20)), 0.0, (10, 10))
    assert not f and f.reason == "bp_below_isovalue"
    with pytest.raises(ValueError, match="outside"):
        extract_isophote(img, 0.5, (30, 10))
    with pytest.raises(ValueError, match="2D"):
        extract_isophote(np.zeros((4, 4, 3)), 0.5, (1, 1))
    with pytest.raises(ValueError, match="image_shape"):
        extract_isophote(img, 0.5, (10, 10), origin_rc=(1, 1))


def test_polygon_helpers():
    square = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], dtype=float)
    assert polygon_area(square) == 16.0
    assert polygon_contains(square, (2, 2)) and not polygon_contains(square, (5, 2))
    assert polygon_contains(square, [[1, 1], [9, 9], [3, 0.5]]).tolist() == [True, False, True]


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_the_whole_regions_closed_hits_are_its_closed_contours_that_hold_the_bp(seed, on_vertex):
    # _whole_region_contours tests a contour's box before its polygon (the box taken in array
    # coordinates, then shifted): only a pre-filter, the same contours as the polygon test alone,
    # also with the BP on a contour's vertex (on its box's edge) and far from the image origin
    from skimage.measure import find_contours

    from simtest.reconstruct import isophote

    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(3, 40, 2))
    sub = cv2.GaussianBlur(rng.random((h, w)), (0, 0), float(rng.uniform(0.5, 2.0)))
    level = float(np.median(sub))
    r0, c0 = (int(v) for v in rng.integers(0, 5000, 2))
    roi = Roi(r0, r0 + h, c0, c0 + w)
    closed = [rc[:-1] for rc in find_contours(sub, level)
              if len(rc) >= 3 and rc[0, 0] == rc[-1, 0] and rc[0, 1] == rc[-1, 1]]
    bp = np.array([c0 + rng.uniform(0, w - 1), r0 + rng.uniform(0, h - 1)])
    if on_vertex and closed:
        row, col = closed[0][int(rng.integers(len(closed[0])))]
        bp = np.array([col + c0, row + r0])
    want = [uv for uv in (rc_to_uv(rc, r0, c0) for rc in closed) if polygon_contains(uv, bp)]
    got, _ = isophote._whole_region_contours(sub, level, roi, bp)
    assert len(got) == len(want) and all(np.array_equal(a, b) for a, b in zip(got, want))


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


def _same(a, b) -> bool:
    from simtest.reconstruct.isophote import Isophote

    if type(a) is not type(b):
        return False
    if isinstance(a, Isophote):
        return ((a.closed, a.cut_by_roi, a.cut_by_image, a.level) == (b.closed, b.cut_by_roi, b.cut_by_image, b.level)
                and a.points_uv.shape == b.points_uv.shape
                and a.points_uv.tobytes() == b.points_uv.tobytes())
    return (a.reason, a.detail) == (b.reason, b.detail)


def _cut_by_roi(values, level, bp_uv, *, origin_rc, image_shape):
    """The growth question in a region (isophote._cut_and_contour's answer)."""
    from simtest.reconstruct.isophote import _cut_and_contour, _region

    return _cut_and_contour(_region(values, bp_uv, origin_rc, image_shape), level)[0]


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=100, deadline=None)
def test_a_region_read_in_place_from_a_wider_array_gives_the_same_isophote(seed):
    # the pipeline hands the extraction views of the frame's luma (row stride of the frame) uncopied

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
    assert _cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape) == \
        _cut_by_roi(view, level, bp, origin_rc=off, image_shape=shape)


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_the_growth_question_has_the_extractions_answer(seed):
    # _cut_and_contour answers what the pipeline asks before growing an ROI without contouring:
    # the extraction's cut_by_roi (False where it fails), or None where only the extraction can tell
    from simtest.reconstruct.isophote import Isophote

    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    try:
        iso = extract_isophote(img, level, bp, origin_rc=off, image_shape=shape, allow_open=True, min_points=0)
    except ValueError:
        return
    cut = _cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape)
    if cut is not None:
        assert cut == (isinstance(iso, Isophote) and iso.cut_by_roi)


def test_the_growth_question_meets_each_answer():
    # the property test above means something only if the random regions give every answer

    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(400):
        img, level, bp, off, shape = _random_region(rng)
        try:
            seen.add(_cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape))
        except ValueError:
            pass
    assert seen == {True, False, None}


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_the_extraction_from_the_growth_questions_flood_fill_is_the_extraction(seed):
    # the BP's component box from the flood fill the growth question made (_cut_and_contour), as
    # the pipeline's contouring takes it, is the one it makes when it fills the component itself
    from simtest.reconstruct.isophote import _component_box, _cut_and_contour, _region

    img, level, bp, off, shape = _random_region(np.random.default_rng(seed))
    try:
        region = _region(img, bp, off, shape)
    except ValueError:
        return
    cut, flood = _cut_and_contour(region, level)
    assert cut == _cut_by_roi(img, level, bp, origin_rc=off, image_shape=shape)
    if flood is not None:
        (box, at, sides), (box2, at2, sides2) = (_component_box(region.sub, level, region.ri, region.ci, f)
                                                 for f in (flood, None))
        assert np.array_equal(box, box2) and at == at2 and sides == sides2


def test_a_ring_a_neighbour_and_a_cut_highlight():
    # the cases the component's box is for: another component lowered, a hole whose contour is
    # not the isophote even where it encloses the BP, and a component reaching two sides of the
    # region (open contours in find_contours' order)
    from skimage.measure import find_contours

    img = np.zeros((30, 40))
    img[5:20, 5:20] = 1.0
    img[10:14, 10:14] = 0.0  # a hole: its contour at 0.9 runs at row 13.9 below it
    img[5:9, 21:25] = 1.0  # touches the highlight at a corner only: another component
    for level, bp in ((0.5, (12.0, 7.0)), (0.9, (12.0, 13.6))):  # the second BP inside the hole's contour
        iso = extract_isophote(img, level, bp, allow_open=True)
        assert iso.closed and not iso.cut_by_roi
        # the outer boundary of the 15 x 15 px square: (14 + 2 (1 - level))^2 px^2
        assert polygon_area(iso.points_uv) == pytest.approx((14 + 2 * (1 - level)) ** 2 - 2 * (1 - level) ** 2)
    img = np.zeros((30, 40))
    img[0:12, 25:40] = 1.0
    iso = extract_isophote(img, 0.5, (30.0, 5.0), allow_open=True)
    assert not iso.closed and iso.cut_by_image
    assert np.array_equal(iso.points_uv, rc_to_uv(np.concatenate(find_contours(img, 0.5))))


def test_a_float32_region_is_compared_with_the_level_in_float64():
    # the pipeline's ROIs are float32 views of the frame's smoothing: a pixel equal to the level
    # rounded to float32, but above the level itself, belongs to the component (find_contours
    # reads the region in float64)
    img = np.zeros((9, 9), dtype=np.float32)
    img[3:6, 3:6] = np.float32(0.1)
    level = float(np.float32(0.1)) - 1e-12  # rounds to img's value in float32
    iso = extract_isophote(img, level, (4.0, 4.0))
    assert iso.closed and len(iso.points_uv) == 12


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 60), near=st.booleans())
def test_the_enclosure_test_is_the_even_odd_test(seed, n, near):
    # _encloses decides by OpenCV's point-in-polygon test on the contour in float32 away from it,
    # by polygon_contains in float64 near it: polygon_contains' answer on star-shaped polygons far
    # from the origin, for points anywhere, on a vertex and within 1e-9 px of an edge
    from simtest.reconstruct.isophote import _encloses

    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    centre = rng.uniform(0, 4000, 2)
    poly = centre + rng.uniform(1, 30, (n, 1)) * np.c_[np.cos(ang), np.sin(ang)]
    if near:
        k = int(rng.integers(n))
        p = poly[k] + rng.uniform(0, 1) * (poly[(k + 1) % n] - poly[k]) + rng.normal(0, 1e-9, 2)
    else:
        p = centre + rng.uniform(-35, 35, 2)
    assert _encloses(poly, p) == polygon_contains(poly, p)
    assert _encloses(poly, poly[0]) == polygon_contains(poly, poly[0])


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
       quantised=st.booleans(), layout=st.sampled_from(["C", "F", "view", "f32"]))
@settings(max_examples=200, deadline=None)
def test_border_median_is_numpys_median_of_the_ring(seed, h, w, quantised, layout):
    from simtest.reconstruct.isophotes import _border_median

    rng = np.random.default_rng(seed)
    v = rng.normal(size=(h, w))
    if quantised:  # repeated values: the even-count mean of two equal middles
        v = np.round(v * 3)
    if layout == "F":
        v = np.asfortranarray(v)
    elif layout == "view":
        v = np.pad(v, 2)[2:-2, 2:-2]
    elif layout == "f32":  # the frame's float32 smoothing: the median of its values in float64
        v = v.astype(np.float32)
    ring = np.concatenate([v[0], v[-1], v[1:-1, 0], v[1:-1, -1]]).astype(np.float64)
    assert _border_median(v) == float(np.median(ring))


def test_border_median_of_a_nan_is_nan():
    from simtest.reconstruct.isophotes import _border_median

    v = np.ones((5, 6))
    v[0, 2] = np.nan
    assert np.isnan(_border_median(v))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), channels=st.sampled_from([1, 3]), sigma=st.sampled_from([0.8, 1.7, 2.5]),
       dtype=st.sampled_from([np.uint8, np.float64]), r0=st.integers(0, 20), c0=st.integers(0, 20),
       h=st.integers(1, 30), w=st.integers(1, 30))
def test_the_border_level_of_an_roi_smoothed_alone_from_its_ring(seed, channels, sigma, dtype, r0, c0, h, w):
    """_smoothed_border_median (the pipeline's local background level when the frame is smoothed
    once) is the median of the ring of the ROI's luma smoothed alone by OpenCV, its sides
    reflected, to rounding; ROIs down to one pixel (reflected more than once)."""
    from simtest.reconstruct.detect import luma
    from simtest.reconstruct.frame_prep import _gaussian_kernel
    from simtest.reconstruct.isophotes import _border_median, _smoothed_border_median

    rng = np.random.default_rng(seed)
    img = rng.uniform(0, 255, (50, 50, channels))
    img = img.astype(np.uint8) if dtype == np.uint8 else img
    img = img if channels == 3 else img[:, :, 0]
    roi = Roi(r0, min(r0 + h, 50), c0, min(c0 + w, 50))
    want = _border_median(cv2.GaussianBlur(luma(img[roi.slices]), (0, 0), sigma, borderType=cv2.BORDER_REFLECT))
    got = _smoothed_border_median(img, _gaussian_kernel(sigma), roi)
    # the same sums in another order (OpenCV: the row pass first, over the ROI): float64 rounding
    assert abs(got - want) <= 1e-9 * max(1.0, abs(want))


def _component_jobs(rng, n):
    """``(region, level, component box)`` of the BP components of up to ``n`` random regions."""
    from simtest.reconstruct.isophote import _component_box, _region

    jobs = []
    for _ in range(n):
        img, level, bp, off, shape = _random_region(rng)
        try:
            g = _region(img, bp, off, shape)
        except ValueError:
            continue
        comp = _component_box(g.sub, level, g.ri, g.ci) if g.near_bp > level else None
        if comp is not None:
            jobs.append((g, level, comp))
    return jobs


def _batch_and_one_by_one(rng, n):
    """:func:`marching.batch_contours` of ``n`` random regions' BP components in one batch, and
    each one's by :func:`isophote._contours` alone (its closed contours, or its open pieces)."""
    from simtest.reconstruct.isophote import _contours
    from simtest.reconstruct.marching import batch_contours

    jobs = _component_jobs(rng, n)
    origins = np.array([(g.roi.col0 + c0, g.roi.row0 + r0) for g, _, (_, (r0, c0), _) in jobs], np.float64)
    got = batch_contours([box for _, _, (box, _, _) in jobs], np.array([lv for _, lv, _ in jobs]), origins,
                          np.array([g.bp_uv for g, _, _ in jobs]))
    want = []
    for g, lv, (_, (r0, c0), sides) in jobs:
        closed, pieces, _ = _contours(g.sub, lv, g.roi, g.ri, g.ci, g.bp_uv)
        want.append(pieces if any(sides) else closed)
    # an open contour's points in the region, as the pipeline shifts them
    got = [[rc + box_rc for rc in g] if isinstance(g, list) else g for g, (_, _, (_, box_rc, _)) in zip(got, jobs)]
    return got, want, [any(sides) for _, _, (_, _, sides) in jobs]


@given(seed=st.integers(0, 2**32 - 1))
@example(seed=10518)  # a component that fills its box, around a hole the batch once took for its outline
@settings(max_examples=100, deadline=None)
def test_a_frames_batch_of_contours_is_find_contours_one_by_one(seed):
    # the pipeline contours a frame's components in one batch of numpy calls: the points, their
    # order and bits are those find_contours gives each component alone (None: a degenerate
    # case the batch leaves to it)
    got, want, cut = _batch_and_one_by_one(np.random.default_rng(seed), 12)
    for g, w, open_ in zip(got, want, cut):
        if g is None:
            continue
        if open_:
            assert len(g) == len(w) and all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(g, w))
        else:
            assert len(w) <= 1
            assert np.array_equal(g, w[0] if w else np.empty((0, 2))) and g.shape == (w[0].shape if w else (0, 2))


@given(seed=st.integers(0, 2**32 - 1), batch_px=st.integers(1, 20000))
@settings(max_examples=40, deadline=None)
def test_a_batch_cut_into_batches_gives_the_same_bits(seed, batch_px):
    # a batch stacks at most BATCH_MAX_PX of boxes (a frame of overlapping boxes would stack
    # gigabytes): cut anywhere between boxes, the answers are the uncut batch's, bit for bit (a
    # box's answer reads its own squares only)
    from unittest import mock

    from simtest.reconstruct import marching

    jobs = [(box, level, (g.roi.col0 + c0, g.roi.row0 + r0), g.bp_uv)
            for g, level, (box, (r0, c0), _) in _component_jobs(np.random.default_rng(seed), 16)]
    assume(len(jobs) > 1)
    args = ([b for b, *_ in jobs], np.array([lv for _, lv, *_ in jobs]), np.array([o for *_, o, _ in jobs], np.float64),
            np.array([bp for *_, bp in jobs]))
    with mock.patch.object(marching, "BATCH_MAX_PX", 1 << 40):
        whole = marching.batch_contours(*args)
    with mock.patch.object(marching, "BATCH_MAX_PX", batch_px):
        cut = marching.batch_contours(*args)
    assert len(cut) == len(whole)
    for a, b in zip(cut, whole):
        if a is None or b is None:
            assert a is None and b is None
        elif isinstance(b, list):
            assert isinstance(a, list) and len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
        else:
            assert a.shape == b.shape and np.array_equal(a, b)


def test_the_batch_of_contours_meets_each_answer():
    # the property test above means something only if its random regions give every answer
    got, _, cut = _batch_and_one_by_one(np.random.default_rng(2), 400)
    assert {None if g is None else "open" if c else bool(len(g)) for g, c in zip(got, cut)} == \
        {None, True, False, "open"}
