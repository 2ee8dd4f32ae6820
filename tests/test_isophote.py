"""Isophote extraction by marching squares: coordinates, contour choice, cuts, failures."""

from __future__ import annotations

import ast
import inspect

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
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
    assert iso and iso.closed and not iso.cut
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


def _traced(img, level):
    """The compiled tracer as ``(points, closed)``, or None where it declines."""
    from simtest.reconstruct import _kernels

    code, pts = _kernels.trace_contours(np.ascontiguousarray(img, dtype=np.float64), float(level))
    return None if code == _kernels.FALLBACK else (pts, code == _kernels.CLOSED)


@given(seed=st.integers(0, 2**32 - 1), h=st.integers(4, 40), w=st.integers(4, 40),
       blur=st.floats(0.5, 3.0), q=st.floats(0.3, 0.97), edges=st.booleans())
@settings(max_examples=150, deadline=None)
def test_the_compiled_tracer_gives_find_contours_bit_for_bit(seed, h, w, blur, q, edges):
    # A random smooth field reduced to one 4-connected component without holes (what
    # extract_isophote contours), inside the box or (edges) free to reach its sides: the tracer
    # must give find_contours' closed contour, or its open contours concatenated, with the same
    # start, order and bits; anything else (a pixel at the level, several closed contours) it
    # declines with None and extract_isophote uses find_contours.
    import cv2
    from scipy import ndimage
    from skimage.measure import find_contours


    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w)), (0, 0), blur)
    level = float(np.quantile(img, q))
    if not edges:
        img[[0, -1]] = level - 1.0
        img[:, [0, -1]] = level - 1.0
    lab, n = ndimage.label(img > level)  # 4-connected
    if n:
        one = ndimage.binary_fill_holes(lab == 1)
        img[(img > level) & ~one] = level - 1.0
        img[one & ~(img > level)] = level + 1.0
    want = find_contours(img, level)
    got = _traced(img, level)
    is_closed = [len(c) >= 3 and c[0].tolist() == c[-1].tolist() for c in want]
    if got is None:
        assert (img == level).any() or not want or (any(is_closed) and len(want) > 1)
    elif got[1]:
        assert len(want) == 1 and is_closed[0] and np.array_equal(got[0], want[0][:-1])
    else:
        assert want and not any(is_closed) and np.array_equal(got[0], np.concatenate(want))


def test_the_tracer_gives_open_contours_in_order_and_declines_the_rest():
    from skimage.measure import find_contours


    img = np.zeros((10, 12))
    img[3:6, 0:5] = 1.0  # reaches the left edge: one open contour
    img[0:4, 8:12] = 1.0  # and the top right corner: a second one
    pts, closed = _traced(img, 0.5)
    want = find_contours(img, 0.5)
    assert not closed and len(want) == 2 and np.array_equal(pts, np.concatenate(want))
    img = np.zeros((10, 12))
    img[2:5, 2:5] = img[2:5, 7:10] = 1.0  # two closed contours
    assert _traced(img, 0.5) is None
    img[0:2, 0:2] = 1.0  # and an open one
    assert _traced(img, 0.5) is None
    img = np.zeros((10, 10))
    img[3:6, 3:6] = 1.0
    img[4, 4] = 0.5  # a pixel exactly at the level
    assert _traced(img, 0.5) is None


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


def _region_below_bp(rng):
    """A smooth random region (many closed contours at its median-ish level, or quantised so
    that pixels sit exactly at it), a level, a pixel not above the level and the BP within half a
    pixel of it, or on a vertex of a closed contour, far from the image origin."""
    from skimage.measure import find_contours

    h, w = (int(v) for v in rng.integers(2, 50, 2))
    sub = cv2.GaussianBlur(rng.random((h, w)), (0, 0), float(rng.uniform(0.5, 3.0)))
    if rng.random() < 0.2:
        sub = np.round(sub * 30) / 30
    level = float(np.quantile(sub, rng.uniform(0.05, 0.95)))
    r0, c0 = (int(v) for v in rng.integers(0, 5000, 2))
    below = np.argwhere(sub <= level)
    ri, ci = (int(v) for v in below[rng.integers(len(below))])
    bp = np.array([c0 + ci + rng.uniform(-0.5, 0.5), r0 + ri + rng.uniform(-0.5, 0.5)])
    closed = [rc for rc in find_contours(sub, level) if len(rc) >= 3 and (rc[0] == rc[-1]).all()]
    if closed and rng.random() < 0.2:
        row, col = closed[0][int(rng.integers(len(closed[0]) - 1))]
        if 0 <= round(row) < h and 0 <= round(col) < w and sub[round(row), round(col)] <= level:
            bp = np.array([col + c0, row + r0])
    return sub, level, Roi(r0, r0 + h, c0, c0 + w), bp


@settings(max_examples=400, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_whole_region_verdict_is_find_contours_closed_hits(seed):
    # region_encloses_bp decides, without find_contours, whether a closed contour of the region
    # encloses a BP whose pixel is not above the level: 1 exactly where _whole_region_contours
    # finds closed hits, 0 where it finds none; FALLBACK only with a pixel at the level
    from simtest.reconstruct import _kernels, isophote

    sub, level, roi, bp = _region_below_bp(np.random.default_rng(seed))
    got = _kernels.region_encloses_bp(sub, level, roi.row0, roi.col0, float(bp[0]), float(bp[1]))
    if got == _kernels.FALLBACK:
        assert (sub == level).any()
        return
    hits, _ = isophote._whole_region_contours(sub, level, roi, bp)
    assert got == (1 if hits else 0)


def test_the_whole_region_verdicts_meet_each_answer():
    # the property test above means something only if its regions give each answer
    from simtest.reconstruct import _kernels

    rng = np.random.default_rng(0)
    seen = set()
    for _ in range(300):
        sub, level, roi, bp = _region_below_bp(rng)
        seen.add(_kernels.region_encloses_bp(sub, level, roi.row0, roi.col0, float(bp[0]), float(bp[1])))
    assert seen == {0, 1, _kernels.FALLBACK}
