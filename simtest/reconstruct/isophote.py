"""Isophote extraction: the sub-pixel iso-intensity contour around a brightest point.

Step 1 of the method [1]_: the isophote at isovalue t is found by marching squares [2]_
(:func:`skimage.measure.find_contours`, linear interpolation between pixel centres). The one kept
is the innermost *closed* contour that encloses the brightest point (BP); a contour cut by the ROI
or image border is returned (flagged) only when the caller allows open contours. Points are
(u, v) = (col, row), pixel centres at integers (:mod:`simtest.reconstruct._pixels`).

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3, step 1.
.. [2] W. E. Lorensen, H. E. Cline, "Marching cubes: a high resolution 3D surface construction
       algorithm", SIGGRAPH 1987. https://doi.org/10.1145/37402.37422
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from skimage.measure import find_contours

from simtest.decisions import MIN_FIT_POINTS as MIN_CONTOUR_POINTS
from simtest.reconstruct._pixels import Roi, rc_to_uv, uv_to_rc
from simtest.reconstruct.failures import Failure


@dataclass(frozen=True)
class Isophote:
    """An isophote contour around a BP.

    Attributes
    ----------
    points_uv : ndarray of shape (N, 2)
        Sub-pixel contour points (u, v) in full-image pixels; closed contours without a repeated end point.
    level : float
        The contour level in the units of the image passed in.
    closed : bool
        True if marching squares closed the contour inside the ROI.
    cut_by_roi : bool
        True if the contour is open because it leaves the ROI at a side inside the image.
    cut_by_image : bool
        True if the contour is open because it reaches the image border.
    """

    points_uv: np.ndarray
    level: float
    closed: bool
    cut_by_roi: bool
    cut_by_image: bool


def polygon_contains(polygon_uv: np.ndarray, points_uv) -> np.ndarray | bool:
    """Even-odd test: which of ``points_uv`` lie inside the closed polygon ``polygon_uv`` (N, 2)?

    Parameters
    ----------
    polygon_uv : ndarray of shape (N, 2)
        Vertices, without a repeated end point.
    points_uv : array_like of shape (2,) or (M, 2)
        Query points.

    Returns
    -------
    bool or ndarray of shape (M,)
        One bool for a single point, else one per point.
    """
    pts = np.asarray(points_uv, dtype=np.float64)
    single = pts.ndim == 1
    pts = pts.reshape(-1, 2)
    x = polygon_uv[:, 0][:, None]
    y = polygon_uv[:, 1][:, None]
    x2 = np.concatenate([polygon_uv[1:, 0], polygon_uv[:1, 0]])[:, None]
    y2 = np.concatenate([polygon_uv[1:, 1], polygon_uv[:1, 1]])[:, None]
    px, py = pts[:, 0][None, :], pts[:, 1][None, :]
    straddle = (y > py) != (y2 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x + (py - y) * (x2 - x) / (y2 - y)
    inside = (np.count_nonzero(straddle & (px < x_cross), axis=0) % 2).astype(bool)
    return bool(inside[0]) if single else inside


def polygon_area(polygon_uv: np.ndarray) -> float:
    """Unsigned shoelace area of a closed polygon.

    Parameters
    ----------
    polygon_uv : ndarray of shape (N, 2)
        Vertices (u, v) in px, without a repeated end point (the closing edge is implied).

    Returns
    -------
    float
        Area in px^2 (>= 0; 0 for fewer than 3 distinct vertices).
    """
    x = polygon_uv[:, 0]
    y = polygon_uv[:, 1]
    return 0.5 * abs(float(np.dot(x[:-1], y[1:]) - np.dot(y[:-1], x[1:]) + x[-1] * y[0] - y[-1] * x[0]))


def extract_isophote(values: np.ndarray, level: float, bp_uv, *, origin_rc: tuple[int, int] = (0, 0),
                     image_shape: tuple[int, ...] | None = None, allow_open: bool = False,
                     min_points: int = MIN_CONTOUR_POINTS) -> Isophote | Failure:
    """Extract the isophote at ``level`` that encloses the brightest point.

    Marching squares joins the pixels above ``level`` 4-connectedly (``fully_connected="low"``), so
    highlights touching at a corner stay apart. The smallest closed contour enclosing the BP is kept
    (a bright ring would give an outer one); if none is closed, the open contours bordering the BP's
    component are taken.

    Parameters
    ----------
    values : ndarray of shape (h, w), float
        Single-channel intensities of the region searched (the ROI, or the whole image).
    level : float
        Contour level in the units of ``values`` (the pipeline passes ``t * I_BP``).
    bp_uv : array_like of shape (2,)
        Brightest point (u, v) in full-image pixels; must lie inside the region.
    origin_rc : (int, int), optional
        Position (row, col) of ``values[0, 0]`` in the full image (the ROI origin).
    image_shape : tuple, optional
        Shape of the full image, to tell a cut by the image border from one by the ROI; default
        ``values.shape`` (then ``origin_rc`` must be (0, 0)).
    allow_open : bool, optional
        If False (default), a cut contour gives ``Failure("contour_cut")``; if True it is returned
        with ``closed=False`` and the cut flags.
    min_points : int, optional
        Fewer contour points give ``Failure("too_few_points")`` (default 6: an ellipse has 5
        degrees of freedom, one more gives a residual).

    Returns
    -------
    Isophote or Failure
        Failure reasons: ``bp_below_isovalue``, ``no_contour``, ``contour_cut``, ``too_few_points``.

    Raises
    ------
    ValueError
        If ``values`` is not 2D or the BP lies outside the region.
    """
    return _extract(_region(values, bp_uv, origin_rc, image_shape), level, allow_open, min_points)


def _extract(region: _Region, level: float, allow_open: bool, min_points: int) -> Isophote | Failure:
    """:func:`extract_isophote` in a checked region (one per ROI, whatever the levels asked)."""
    sub, roi, image_shape, bp_uv, ri, ci, near_bp = region
    if not near_bp > level:
        return Failure("bp_below_isovalue", f"max near BP {near_bp:.6g} <= level {level:.6g}")
    return _isophote_of(*_contours(sub, level, roi, ri, ci, bp_uv), region, level, allow_open, min_points)


def _isophote_of(closed_hits: list, pieces: list, sides, region: _Region, level: float, allow_open: bool,
                 min_points: int) -> Isophote | Failure:
    """:func:`_extract`'s isophote from the contours at ``level`` (:func:`_contours`' three answers)."""
    roi, image_shape, bp_uv = region.roi, region.image_shape, region.bp_uv
    if closed_hits:
        uv = min(closed_hits, key=polygon_area) if len(closed_hits) > 1 else closed_hits[0]
        if len(uv) < min_points:
            return Failure("too_few_points", f"{len(uv)} contour points < {min_points}")
        return Isophote(uv, float(level), True, False, False)
    if not pieces and not any(sides):
        return Failure("no_contour", f"no contour at level {level:.6g} around BP {bp_uv.tolist()}")
    rc = np.concatenate(pieces, axis=0) if pieces else np.empty((0, 2))
    # which borders the component above the level reaches: ROI sides inside the image, or the image
    on_image = [s and b for s, b in zip(sides, roi.touches_image_border(image_shape))]
    on_roi = [s and not b for s, b in zip(sides, roi.touches_image_border(image_shape))]
    iso = Isophote(rc_to_uv(rc, roi.row0, roi.col0), float(level), False, any(on_roi), any(on_image))
    if not allow_open:
        where = "image border" if iso.cut_by_image else "ROI border"
        return Failure("contour_cut", f"isophote at level {level:.6g} is cut by the {where}")
    if len(iso.points_uv) < min_points:
        return Failure("too_few_points", f"{len(iso.points_uv)} contour points < {min_points}")
    return iso


class _Region(NamedTuple):
    """The checked arguments of :func:`extract_isophote`."""

    sub: np.ndarray
    roi: Roi
    image_shape: tuple
    bp_uv: np.ndarray
    ri: int
    ci: int
    near_bp: float


def _region(values, bp_uv, origin_rc, image_shape) -> _Region:
    """The :class:`_Region` of :func:`extract_isophote`'s arguments (float32 kept, anything else float64)."""
    sub = values if isinstance(values, np.ndarray) and values.dtype == np.float32 else \
        np.asarray(values, dtype=np.float64)
    sub = sub.view()
    sub.flags.writeable = False  # read-only as the frame's smoothing
    if sub.ndim != 2:
        raise ValueError(f"values must be a 2D array, got shape {sub.shape}")
    roi = Roi(origin_rc[0], origin_rc[0] + sub.shape[0], origin_rc[1], origin_rc[1] + sub.shape[1])
    if image_shape is None:
        if tuple(origin_rc) != (0, 0):
            raise ValueError("image_shape is required when origin_rc is not (0, 0)")
        image_shape = sub.shape
    bp_uv = np.asarray(bp_uv, dtype=np.float64)
    if bp_uv.shape == (2,):  # uv_to_rc(bp_uv) - (row0, col0) in Python floats, the same bits
        r_bp, c_bp = float(bp_uv[1]) - roi.row0, float(bp_uv[0]) - roi.col0
    else:
        r_bp, c_bp = uv_to_rc(bp_uv) - (roi.row0, roi.col0)
    ri, ci = int(round(r_bp)), int(round(c_bp))
    if not (0 <= ri < sub.shape[0] and 0 <= ci < sub.shape[1]):
        raise ValueError(f"bp_uv = {bp_uv.tolist()} lies outside the ROI {tuple(roi)}")
    near_bp = float(sub[max(0, ri - 1) : ri + 2, max(0, ci - 1) : ci + 2].max())
    return _Region(sub, roi, tuple(image_shape), bp_uv, ri, ci, near_bp)


def _cut_and_contour(region: _Region, level: float) -> tuple[bool | None, tuple | None]:
    """Whether :func:`_extract` (``allow_open``) gives an isophote cut by the ROI, by one flood fill of
    the BP's component (None where only the extraction can tell), and the flood fill or None.
    """
    sub, roi, image_shape, _, ri, ci, near_bp = region
    if not near_bp > level:
        return False, None
    flood = _flood(sub, level, ri, ci)
    if flood is None:  # the BP's pixel is not above the level: only the extraction can tell
        return None, None
    return any(s and not b for s, b in zip(flood[2], roi.touches_image_border(image_shape))), flood


def _contours(sub, level, roi, ri, ci, bp_uv):
    """The contours of :func:`extract_isophote`: the closed ones enclosing the BP as (u, v), the open
    pieces as (row, col) in ``sub``, and the sides of ``sub`` the BP's component reaches.
    """
    comp = _component_box(sub, level, ri, ci)
    if comp is not None:
        # only the BP's 4-connected component above the level is contoured, in its box
        box, (dr, dc), sides = comp
        return _box_answer(_box_contours(box, level, rc_to_uv((roi.row0 + dr, roi.col0 + dc)), bp_uv), dr, dc, sides)
    # the BP pixel itself is not above the level: every contour of the region
    closed_hits, open_contours = _whole_region_contours(sub, level, roi, bp_uv)
    pieces, sides = [], (False, False, False, False)
    if not closed_hits:
        pieces, sides = _open_pieces_around_bp(sub, level, ri, ci, open_contours)
    return closed_hits, pieces, sides


#: Where the BP lies farther than this (px) from a closed contour, OpenCV's point-in-polygon test
#: on the float32 contour decides; nearer, the even-odd test in float64 does.
ENCLOSE_FLOAT32_MARGIN_PX = 0.01


def _encloses(uv: np.ndarray, bp_uv: np.ndarray) -> bool:
    """:func:`polygon_contains` of one point in a closed, simple contour, by
    ``cv2.pointPolygonTest`` away from the contour (:data:`ENCLOSE_FLOAT32_MARGIN_PX`)."""
    d = cv2.pointPolygonTest(uv.astype(np.float32), (float(bp_uv[0]), float(bp_uv[1])), True)
    return d > 0 if abs(d) > ENCLOSE_FLOAT32_MARGIN_PX else bool(polygon_contains(uv, bp_uv))


def _box_contours(box, level, origin_uv, bp_uv):
    """:func:`~simtest.reconstruct.marching.batch_contours`' answer for one box by ``find_contours`` (degenerate cases too)."""
    closed, pieces = [], []
    for rc in find_contours(box, level):
        if len(rc) >= 3 and rc[0, 0] == rc[-1, 0] and rc[0, 1] == rc[-1, 1]:
            # the component's outer boundary has a positive signed area in (col, row) (the values above the
            # level on its left), each hole's a negative one; a hole's is never the isophote
            r, c = rc[:, 0], rc[:, 1]
            if np.dot(c[:-1], r[1:]) > np.dot(r[:-1], c[1:]):
                uv = rc_to_uv(rc[:-1]) + origin_uv
                if _encloses(uv, bp_uv):
                    closed.append(uv)
        else:
            pieces.append(rc)
    return pieces if pieces else min(closed, key=polygon_area) if closed else np.empty((0, 2))


def _box_answer(got, dr: int, dc: int, sides) -> tuple[list, list, tuple]:
    """:func:`_contours`' three answers from a box's contours."""
    if isinstance(got, list):
        return [], [rc + (dr, dc) for rc in got], sides
    return [got] if len(got) else [], [], sides


def _flood(sub, level, ri, ci):
    """The 4-connected component of ``sub > level`` holding pixel (ri, ci): the mask (2 on it, 1 on
    other pixels above the level), its box (x, y, w, h) and the sides of ``sub`` it reaches; None
    if that pixel is not above the level.
    """
    level = np.float64(level)  # a float32 region compares in float64, as find_contours reads it
    if not sub[ri, ci] > level:
        return None
    if sub.dtype == np.float32 and abs(level) < 3e38:  # float32's largest not above it: the same pixels, 2x faster
        level = np.float32(level) if np.float32(level) <= level else np.nextafter(np.float32(level), np.float32(-1e38))
    mask = (sub > level).view(np.uint8)  # a fresh array: filled in place
    # the cost is that of the component, not of the region
    _, _, _, (x, y, w, h) = cv2.floodFill(mask, None, (int(ci), int(ri)), 2, 0, 0, 4)
    return mask, (x, y, w, h), (y == 0, y + h == sub.shape[0], x == 0, x + w == sub.shape[1])


def _component_box(sub, level, ri, ci, flood=None):
    """The box (plus one pixel) of the BP's 4-connected component of ``sub > level``, other components
    lowered below the level, its origin (row, col) and the sides of ``sub`` it reaches; None if that
    pixel is not above the level. ``flood``: :func:`_flood`'s result where the caller has it.
    """
    if flood is None:
        flood = _flood(sub, level, ri, ci)
        if flood is None:
            return None
    mask, (x, y, w, h), sides = flood
    H, W = sub.shape
    r0, r1, c0, c1 = max(y - 1, 0), min(y + h + 1, H), max(x - 1, 0), min(x + w + 1, W)
    box = sub[r0:r1, c0:c1].astype(np.float64)  # find_contours' dtype (a copy)
    lab = mask[r0:r1, c0:c1]
    box[lab == 1] = level - 1.0  # pixels of other components (above the level, not joined)
    return box, (r0, c0), sides


def _whole_region_contours(sub, level, roi, bp_uv):
    """Closed contours of the whole region that enclose the BP (as (u, v)), and the open ones
    (as (row, col) in ``sub``)."""
    closed_hits, open_contours = [], []
    for rc in find_contours(sub, level):
        if len(rc) >= 3 and rc[0, 0] == rc[-1, 0] and rc[0, 1] == rc[-1, 1]:
            uv = rc_to_uv(rc[:-1], roi.row0, roi.col0)
            if polygon_contains(uv, bp_uv):
                closed_hits.append(uv)
        else:
            open_contours.append(rc)
    return closed_hits, open_contours


def _open_pieces_around_bp(sub, level, ri, ci, open_contours):
    """Open contours bounding the BP's 4-connected component of ``sub >= level``, and the sides it reaches."""
    mask = (sub >= np.float64(level)).view(np.uint8)
    _, labels = cv2.connectedComponents(mask, connectivity=4)
    target = labels[ri, ci]
    if target == 0:
        return [], (False, False, False, False)
    sides = (bool((labels[0] == target).any()), bool((labels[-1] == target).any()),
             bool((labels[:, 0] == target).any()), bool((labels[:, -1] == target).any()))
    h, w = sub.shape
    pieces = []
    for rc in open_contours:
        r0 = np.clip(np.floor(rc[:, 0]).astype(int), 0, h - 1)
        r1 = np.clip(np.ceil(rc[:, 0]).astype(int), 0, h - 1)
        c0 = np.clip(np.floor(rc[:, 1]).astype(int), 0, w - 1)
        c1 = np.clip(np.ceil(rc[:, 1]).astype(int), 0, w - 1)
        # each marching-squares point lies on an edge between a pixel >= level and one below it
        touches = (labels[r0, c0] == target) | (labels[r1, c1] == target)
        if touches.mean() > 0.5:
            pieces.append(rc)
    return pieces, sides
