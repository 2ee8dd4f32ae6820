"""Highlights of several light guides fused into one: one row per guide, from their joint fit.

Where the patch is near and shiny, the guides' lobes (:mod:`simtest.reconstruct.rig_pairs`) touch and the detector sees
one bright region (``ok`` at neither specular point, ``merged``, ``bad_fit``, ``not_elliptical``, ``contour_cut``,
``touches_border``; ``not_specular`` where the lobes are pale or weak, as for a rig twin). The light-aware photometric
fit models every lobe on one plane: it needs no ellipse, nor the part of the region the frame cuts.

Rule. A candidate's plane fit (``n . X = -h``) predicts each guide's specular point ``X_s = L' h / (-n . L')`` with
``L' = L - 2 (n . L + h) n`` (without a distance, the h that centres them on the clipped tops, :func:`_on_the_tops`,
where the tops narrow between them, :func:`_waisted`: one lobe's top holds any two points at some h). When two or more
guides' points lie in the candidate's bright region (above :data:`FUSED_LOBE_LEVEL` of the BP's height, holding the BP),
at least :data:`~simtest.decisions.PAIR_TOL_PX` apart and, if clipped, one within ``PAIR_TOL_PX`` of its top (a weaker
lobe may not clip), it gives one row per guide whose point is no light-aware ok candidate's BP (that highlight has its
own row): BP at its specular point, status ``ok``, the joint fit's normal (a depth-less one's sigma without the guides'
spread: the points apart tell which guide lit which). A rejected candidate is fitted for this only where the rig's curve
runs in its region. Under two guides a ``merged`` or ``cluster`` one whose tops do not stretch along that curve gives
rows only where the luma dips between its fit's two points (:func:`_dips_between`; one elongated blob peaks between
them), or, clipped, lies on the clip there (lobes fused above the clip, whose sum peaks between them). A
``not_specular`` one is fitted under two guides only, where it is white (the colour check's white share; its
paleness is waived, as for a rig twin: two tops at the rig's baseline are what texture does not repeat), its peak is
significant and its tops stretch along the curve, and it gives rows only where the luma dips between its fit's points,
as does a weak peak the height check passed for its rig twin (a twin elsewhere and both lobes here cannot both hold). A
lobe the frame's edge cuts (its region, ``touches_border``, or its isophote, ``contour_cut``) gives its guide's row
where its fit, ok with its distance, puts that point alone (if clipped, within ``PAIR_TOL_PX`` of its top). Rejected
candidates on a split's points or inside its closed isophote (noise maxima on the lobes' tops) give no rows; of the
clipped pieces of one top, one is fitted, the others only where its fit fails
(:func:`~simtest.reconstruct.rig_centroid.fused_top_groups`).

Partner. An ok row whose plane fit (ok, with its distance) puts its own guide's point on its BP and another guide's on a
rejected candidate's (each within ``PAIR_TOL_PX`` plus the BP's wander, the placing row's point also inside its closed
isophote: :func:`isophote_holds`) makes that candidate the other guide's row where the candidate's own plane fit puts
both points back: a weak lobe whose isophote the other's tail deforms. A candidate
with no closed isophote to measure its BP's wander (a lobe the frame cuts; a pale one, ``not_specular``; a weak one
whose core is ``too_small``) is the other guide's where its bright region holds that point, its fit's too. An ok row
whose recommended quadric (one curved patch fitted to every guide's lobe) puts its own guide's specular point on its BP
makes the rejected candidate whose BP lies at another guide's point that guide's row, from the same fit. Where no ok
row's lobe holds another guide's point that such a plane fit puts in the frame (detection found no candidate of that
lobe: a weak one on bright shading), a plane fit of its own on a ROI of the placing row's size about the point makes
it that guide's row (status ``ok``, BP at its specular point) where it puts both guides' points where the first does.

Shared plane. An ok row left with the BP ray (its own fits misfit: another guide's lobe on its ROI, a lobe the model
does not hold) is a guide's highlight on the plane of an ok row whose recommended plane fit (ok, with its distance)
puts its own guide's point on its BP and another guide's on this row's (each within ``PAIR_TOL_PX`` plus the BP's
wander, or inside the row's closed isophote): the row gets that plane as ``rig_pair`` (of two such, the smaller
sigma's), its depth where its ray meets the plane, the plane's sigma. One plane images every guide's highlight; two
highlights at the points it predicts are its evidence.

Pair. A clipped candidate whose joint fit gives no rows at its two largest clipped tops (each holding a
:data:`~simtest.decisions.TOP_CORE_PX` square) where the rig pairs them gives one row per top at its centroid, with
the plane the two fix as a stereo pair (``rig_pair``, :func:`~simtest.reconstruct.rig_pairs.pair_plane`).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from simtest._lazy import require
from simtest._threads import one_thread_each
from simtest.decisions import (CLIP_LUMA_MARGIN_REL, DEPTH_RELEASE_REL_SIGMA, FUSED_LOBE_LEVEL, FUSED_TOPS_STRETCH,
                               FUSED_TOPS_WAIST_PX, PAIR_DEPTH_MAX_MM, PAIR_TOL_PX, PEAK_SMOOTH_GAP_SHARE,
                               PEAK_SMOOTH_SIGMA_PX, PEAK_TOP_SHARE, SIGNIFICANCE_MIN, TOP_CORE_PX,
                               TOP_CORE_SHARE, TOPS_PLACE_SIGMA_PX)
from simtest.geometry.angles import angle_between_deg
from simtest.reconstruct._pixels import Roi, uv_to_rc
from simtest.reconstruct.assemble import SpecularityEstimate
from simtest.reconstruct.detect_pixels import interior_top, luma, noise_sigma
from simtest.reconstruct.isophote import polygon_contains
from simtest.reconstruct.light_fits import (NOT_FITTED, PLANE_ONLY, _offset_rig, _plane, _reach,
                                           light_aware_estimates, lobe_size_px)
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.reconstruct.recommend import without_guide_spread
from simtest.reconstruct.rig_pairs import (_in_frame, _model, _specular_points, estimate_wander_px,
                                           guide_specular_points, other_guide_curves, pair_plane, patch_specular_points)

__all__ = ["FUSED_LOBE_LEVEL", "fused_lobe_candidates", "guide_specular_points", "isophote_holds", "partner_rows",
           "shared_plane_rows", "split_fused_lobes", "splittable"]

#: Candidates whose statuses the rule may turn into rows of fused lobes (module docstring, :func:`splittable`).
SPLIT_STATUSES = ("ok", "merged", "bad_fit", "not_elliptical", "cluster", "contour_cut", "touches_border",
                  "not_specular")


def splittable(est, gray: np.ndarray | None = None, origin=(0, 0)) -> bool:
    """Whether the rule may split a candidate: its status in :data:`SPLIT_STATUSES`, touching the border only
    with a clipped top in the frame or, unclipped, where its BP is the top of a lobe the edge cuts and not the
    shoulder of one outside (:func:`~simtest.reconstruct.detect_pixels.interior_top` on the luma ``gray`` of the
    region detected, its [0, 0] at the image's (row, col) ``origin``; without it, not), ``not_specular`` only under
    two guides (:func:`fused_lobe_candidates`)."""
    if est.status not in SPLIT_STATUSES or est.saturated or est.status != "touches_border":
        return est.status in SPLIT_STATUSES
    r0, c0 = origin
    return gray is not None and interior_top(gray, np.subtract(est.bp_px, (c0, r0)),
                                             np.subtract(tuple(est.roi), (r0, r0, c0, c0)))


def _roi_base(gray: np.ndarray, est) -> tuple[np.ndarray, float, int, int]:
    """``(sub, base, row0, col0)``: the candidate's ROI of ``gray`` and the lobe's zero, the median of the ROI's
    border (the isophotes' zero: the diffuse shading under the lobe)."""
    r0, r1, c0, c1 = (int(v) for v in (est.roi.row0, est.roi.row1, est.roi.col0, est.roi.col1))
    sub = gray[r0:r1, c0:c1]
    return sub, float(np.median(np.concatenate([sub[0], sub[-1], sub[1:-1, 0], sub[1:-1, -1]]))), r0, c0


def _significant(gray: np.ndarray, est) -> bool:
    """Whether the candidate's BP stands :data:`~simtest.decisions.SIGNIFICANCE_MIN` noise sigmas of its ROI
    (:func:`~simtest.reconstruct.detect_pixels.noise_sigma`) above the ROI's border median: a peak, not noise."""
    sub, base, _, _ = _roi_base(gray, est)
    return float(est.bp_intensity) - base >= SIGNIFICANCE_MIN * noise_sigma(sub)


def _bright_region(gray: np.ndarray, est) -> tuple[np.ndarray, int, int] | None:
    """The connected pixels of the candidate's ROI above :data:`FUSED_LOBE_LEVEL` of its BP's height
    that hold the BP: ``(mask, row0, col0)``, or None when the BP's pixel is not above the level.
    """
    sub, base, r0, c0 = _roi_base(gray, est)
    above = (sub >= base + FUSED_LOBE_LEVEL * (float(est.bp_intensity) - base)).astype(np.uint8)
    r, c = (int(v) for v in np.rint(uv_to_rc(np.asarray(est.bp_px, dtype=np.float64))))
    r, c = r - r0, c - c0
    if not (0 <= r < sub.shape[0] and 0 <= c < sub.shape[1]) or not above[r, c]:
        return None
    _, labels = cv2.connectedComponents(above, connectivity=8)
    return labels == labels[r, c], r0, c0


def _roi_index(uv, shape, origin) -> tuple[np.ndarray, np.ndarray]:
    """Per point (k, 2) (u, v): its pixel's (row, col) (k, 2) int in an array of ``shape`` whose [0, 0]
    is the image's (row, col) ``origin``, and (k,) bool whether the point is finite and on the array."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    ok = np.isfinite(uv).all(axis=1)
    rc = np.rint(uv_to_rc(np.where(ok[:, None], uv, -1.0))).astype(np.int64) - np.asarray(origin, np.int64)
    return rc, ok & ((rc >= 0) & (rc < shape)).all(axis=1)


def _inside(mask_at, pts: np.ndarray) -> np.ndarray:
    """Per point (u, v): whether it lies in the region (:func:`_bright_region`)."""
    rc, inside = _roi_index(pts, mask_at[0].shape, mask_at[1:])
    inside[inside] = mask_at[0][rc[inside, 0], rc[inside, 1]]
    return inside


def _along_the_rig(gray: np.ndarray, est, camera, rig, stretched: bool = True) -> bool:
    """Whether a candidate's region reaches along the rig's curve beyond :data:`PAIR_TOL_PX` from its
    BP, and with ``stretched`` its tops are at least :data:`~simtest.decisions.FUSED_TOPS_STRETCH`
    times as long along the curve as across.
    """
    region = _bright_region(gray, est)
    if region is None:
        return False
    mask, r0, c0 = region
    rr, cc = np.nonzero(mask)
    d = np.column_stack([cc + c0, rr + r0]).astype(np.float64) - np.asarray(est.bp_px, np.float64)
    reach = float(np.sqrt((d * d).sum(axis=1).max())) + 1.0
    (curve,) = other_guide_curves(_model(camera), rig.positions, np.asarray(est.bp_px, np.float64)[None], [reach])
    curve = curve[_inside(region, curve)] - np.asarray(est.bp_px, np.float64)
    far = curve[np.argmax((curve * curve).sum(axis=1))] if len(curve) else np.zeros(2)  # none: no reach
    along = float(np.hypot(*far))
    if not stretched or not along > PAIR_TOL_PX:
        return along > PAIR_TOL_PX
    t = far / along
    # a merged candidate's stretch is its tops' (near its peak in luma), not its region's
    d = d[_tops(gray, region)[rr, cc]]
    return float(np.ptp(d @ t)) >= FUSED_TOPS_STRETCH * float(np.ptp(d @ np.array([-t[1], t[0]])))


#: The plane distances h (mm) :func:`_on_the_tops` tries: 1 mm to the farthest depth a pair may lie at
#: (``PAIR_DEPTH_MAX_MM``; h is at most the depth), 1 % apart.
_TOPS_H_GRID = np.geomspace(1.0, PAIR_DEPTH_MAX_MM, int(round(np.log(PAIR_DEPTH_MAX_MM) / np.log(1.01))) + 1)


def _tops(gray: np.ndarray, region, margin_rel: float = CLIP_LUMA_MARGIN_REL) -> np.ndarray:
    """The region's tops (bool, ROI indices): pixels within ``margin_rel`` of its peak (default
    :data:`~simtest.decisions.CLIP_LUMA_MARGIN_REL`; 0: at the peak)."""
    mask, r0, c0 = region
    sub = gray[r0:r0 + mask.shape[0], c0:c0 + mask.shape[1]]
    return mask & (sub >= (1.0 - margin_rel) * float(sub[mask].max()))


def _tops_depth(gray: np.ndarray, region) -> np.ndarray:
    """Each pixel's distance (px) to the edge of the region's tops (:func:`_tops`), their holes filled (noise
    below the margin inside a clipped top: a lobe's clipped set has none), 0 off them."""
    tops = require("scipy.ndimage").binary_fill_holes(_tops(gray, region))  # (scipy: when first needed)
    return cv2.distanceTransform(np.pad(tops.astype(np.uint8), 1), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]


def _on_the_tops(depth: np.ndarray, region, camera, rig, normal) -> np.ndarray | None:
    """The guides' specular points (J, 2) on the plane of ``normal`` at the distance h that puts them
    deepest in the region's clipped tops (``depth``: :func:`_tops_depth`), all inside them; None
    where the tops hold no two.
    """
    _, r0, c0 = region
    pts = _specular_points(camera, rig, normal, _TOPS_H_GRID)  # (M, J, 2)
    rc, inside = _roi_index(pts, depth.shape, (r0, c0))
    d = np.zeros(len(rc))
    d[inside] = depth[rc[inside, 0], rc[inside, 1]]
    d = d.reshape(pts.shape[:2])
    score = np.where((d > 0).all(axis=1), d.sum(axis=1), -1.0)
    if not score.max() > 0:
        return None
    best = np.flatnonzero(score == score.max())
    return pts[int(best[len(best) // 2])]


def _segment(img: np.ndarray, origin, a, b, border: int) -> tuple[np.ndarray, np.ndarray]:
    """``(t, values)``: float32 ``img`` (its [0, 0] at the image's (row, col) ``origin``) bilinear a pixel apart from
    ``a`` to ``b`` (u, v) px, ``t`` in [0, 1] from ``a``; ``border``: OpenCV's mode off the array (constant 0)."""
    t = np.linspace(0.0, 1.0, int(np.ceil(np.linalg.norm(np.subtract(b, a)))) + 2)
    uv = (a + t[:, None] * np.subtract(b, a) - origin[::-1]).astype(np.float32)  # (u, v) in the array
    return t, cv2.remap(img, uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR, borderMode=border, borderValue=0.0)[:, 0]


def _waisted(depth: np.ndarray, region, pts: np.ndarray) -> bool:
    """Whether the clipped tops (``depth``: :func:`_tops_depth`) narrow between every two of ``pts`` (k, 2) (u, v) px:
    each segment's middle half dips :data:`~simtest.decisions.FUSED_TOPS_WAIST_PX` below its shallower end."""
    for a, b in zip(*np.triu_indices(len(pts), 1)):
        t, prof = _segment(depth, region[1:], pts[a], pts[b], cv2.BORDER_CONSTANT)  # (0 off the ROI)
        middle = prof[(t >= 0.25) & (t <= 0.75)]
        if not (middle.size and middle.min() <= min(prof[0], prof[-1]) - FUSED_TOPS_WAIST_PX):
            return False
    return True


def _significant_dip(dip: float, sub: np.ndarray, s: float) -> bool:
    """Whether a dip in ``sub`` smoothed over ``s`` px passes :data:`~simtest.decisions.SIGNIFICANCE_MIN` sigmas of its
    noise: two white-noise pixels through the Gaussian, sqrt(2 / (4 pi)) / s of a pixel's (``noise_sigma(sub)``)."""
    return dip > SIGNIFICANCE_MIN * noise_sigma(sub) / (np.sqrt(2 * np.pi) * s)


def _on_the_peaks(gray: np.ndarray, region, camera, rig, normal) -> np.ndarray | None:
    """:func:`_on_the_tops` for two guides' unclipped lobes: their tops are the region's two brightest
    peaks (luma smoothed by :data:`~simtest.decisions.PEAK_SMOOTH_SIGMA_PX`; local maxima farther apart
    than :data:`~simtest.decisions.PAIR_TOL_PX`) above :data:`~simtest.decisions.PEAK_TOP_SHARE` of the
    valley between them, where it is deeper than :data:`~simtest.decisions.SIGNIFICANCE_MIN` sigmas of
    its noise (two lobes, not one lobe's noise). The points (2, 2) at the distance h that puts one within
    ``PAIR_TOL_PX`` of each top's centroid (which noise moves less than the maximum), nearest them in
    sum; None where none does."""
    mask, r0, c0 = region
    sub = gray[r0:r0 + mask.shape[0], c0:c0 + mask.shape[1]].astype(np.float32)
    sm = cv2.GaussianBlur(sub, (0, 0), PEAK_SMOOTH_SIGMA_PX)
    k = 2 * int(np.ceil(PAIR_TOL_PX)) + 1
    rc = np.argwhere(mask & (sm >= cv2.dilate(sm, np.ones((k, k), np.uint8))))
    rc = rc[np.argsort(-sm[rc[:, 0], rc[:, 1]], kind="stable")]
    far = np.flatnonzero(np.linalg.norm(rc - rc[:1], axis=1) > PAIR_TOL_PX) if len(rc) else []
    if not len(far) or min(sub.shape) < 3:
        return None
    two = rc[[0, far[0]]]
    line = np.rint(np.linspace(two[0], two[1], int(np.ceil(np.linalg.norm(two[1] - two[0]))) + 1)).astype(int)
    valley = float(sm[line[:, 0], line[:, 1]].min())
    dip = float(sm[two[1, 0], two[1, 1]]) - valley
    if not _significant_dip(dip, sub, PEAK_SMOOTH_SIGMA_PX):
        return None
    _, labels, _, centroids = cv2.connectedComponentsWithStats((mask & (sm >= valley + PEAK_TOP_SHARE * dip)).astype(
        np.uint8), connectivity=8)
    tops = labels[two[:, 0], two[:, 1]]
    if tops[0] == tops[1]:
        return None
    uv = centroids[tops] + (c0, r0)  # the tops' centroids (u, v)
    pts = _specular_points(camera, rig, normal, _TOPS_H_GRID)  # (M, 2, 2)
    d = np.linalg.norm(pts[:, :, None] - uv[None, None], axis=-1)  # (M, guide, top)
    cost = np.minimum(d[:, 0, 0] + d[:, 1, 1], d[:, 0, 1] + d[:, 1, 0])  # one guide on each top
    on = np.minimum(np.maximum(d[:, 0, 0], d[:, 1, 1]), np.maximum(d[:, 0, 1], d[:, 1, 0])) <= PAIR_TOL_PX
    return pts[np.flatnonzero(on)[np.argmin(cost[on])]] if on.any() else None


def _dips_between(gray: np.ndarray, region, pts: np.ndarray, clipped: bool = False) -> bool:
    """Whether the region's luma dips between two guides' specular points ``pts`` (2, 2) (u, v) px: smoothed by a
    Gaussian of :data:`~simtest.decisions.PEAK_SMOOTH_GAP_SHARE` of their gap, the lower of the brightest within
    :data:`~simtest.decisions.PAIR_TOL_PX` of each point stands above the darkest of the segment's middle half by
    :data:`~simtest.decisions.SIGNIFICANCE_MIN` sigmas of the dip's noise (two lobes, not one elongated blob); or,
    ``clipped`` (a saturated region), whether that middle half lies on the clipped top, within
    :data:`~simtest.decisions.CLIP_LUMA_MARGIN_REL` of the profile's peak: two lobes fused above the clip, whose sum
    peaks between their points, where no dip can show."""
    mask, r0, c0 = region
    sub = gray[r0:r0 + mask.shape[0], c0:c0 + mask.shape[1]].astype(np.float32)
    gap = float(np.linalg.norm(pts[1] - pts[0]))
    s = max(PEAK_SMOOTH_SIGMA_PX, PEAK_SMOOTH_GAP_SHARE * gap)
    sm = cv2.GaussianBlur(sub, (0, 0), s)
    t, prof = _segment(sm, (r0, c0), pts[0], pts[1], cv2.BORDER_REPLICATE)
    middle = float(prof[(t >= 0.25) & (t <= 0.75)].min())
    tops = min(float(prof[t * gap <= PAIR_TOL_PX].max()), float(prof[(1.0 - t) * gap <= PAIR_TOL_PX].max()))
    return _significant_dip(tops - middle, sub, s) or (clipped and middle >= (1.0 - CLIP_LUMA_MARGIN_REL) * prof.max())


def _dip_needed(gray: np.ndarray, est, camera, rig, weak: bool = False) -> bool:
    """Whether a fused candidate's rows need its luma to dip between its fit's points (:func:`_dips_between`): a
    ``not_specular`` one (pale or weak), a ``weak`` twin, and under two guides a ``merged`` or ``cluster`` one whose
    tops do not stretch along the rig's curve (:func:`_along_the_rig`: a dimmer lobe's top under the other's margin)."""
    return weak or est.status == "not_specular" or (est.status in ("merged", "cluster") and len(rig.positions) == 2
                                                    and not _along_the_rig(gray, est, camera, rig, True))


#: The statuses of a candidate whose region or isophote the frame's edge cuts.
_CUT = ("touches_border", "contour_cut")


def _rows(est, camera, rig, gray, region, pair, others: np.ndarray, weak: bool = False) -> list | None:
    """The rows of one fitted candidate's fused lobes (module docstring), or None; ``weak``: a weak twin's."""
    fit = (est.light_aware or {}).get("photometric_fit")
    if fit is None or not fit.has_normal or region is None:
        return None
    if fit.distance_mm is not None:
        pts = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
    elif fit.status == "depth_not_observable" and len(rig.positions) > 1:
        # the fit holds the normal but not the distance: the h that centres the points on the tops (peaks),
        # where the tops narrow between them (one lobe's top holds any two points at some h)
        depth = _tops_depth(gray, region) if est.saturated else None
        pts = (_on_the_tops(depth, region, camera, rig, fit.normal) if est.saturated
               else _on_the_peaks(gray, region, camera, rig, fit.normal) if len(rig.positions) == 2 else None)
        if pts is None or (est.saturated and not _waisted(depth, region, pts)):
            return None
    else:
        return None
    if _dip_needed(gray, est, camera, rig, weak) and not (len(pts) == 2 and _dips_between(gray, region, pts,
                                                                                          est.saturated)):
        return None  # two guides' lobes only where the luma dips between their points, or is clipped there
    k = np.flatnonzero(_inside(region, pts))
    cut = est.status in _CUT and _plane(fit)
    if len(k) < (1 if cut else 2):
        return None
    p = pts[k]
    gaps = np.linalg.norm(p[:, None] - p[None], axis=-1)[np.triu_indices(len(p), 1)]
    if len(p) > 1 and gaps.min() < PAIR_TOL_PX:
        return None  # lobes the image does not tell apart: one highlight, the candidate's row
    # a guide's highlight that is an ok candidate of its own already has its row: the rows of the others
    free = (np.linalg.norm(np.reshape(others, (-1, 2))[:, None] - p[None], axis=-1) >= PAIR_TOL_PX).all(axis=0)
    if not free.any():
        return None
    if est.saturated:
        # no point within PAIR_TOL_PX of the tops: it fitted something else (a weaker lobe may not clip)
        off = cv2.distanceTransform(np.pad((~_tops(gray, region)).astype(np.uint8), 1, constant_values=1),
                                    cv2.DIST_L2, 5)[1:-1, 1:-1]
        rc = _roi_index(p, off.shape, region[1:])[0]  # (p: points inside the region)
        if (off[rc[:, 0], rc[:, 1]] > PAIR_TOL_PX).all():
            return None
        if pair is not None and not all(_on_a_top(p, pair[1], [t], region[1:]) for t in pair[2]):
            return None  # two tops the rig pairs, the plane's points not one on each: it misplaced them
    fused = len(k) > 1
    # the fused lobes' points apart in the image: it tells which guide lit which
    la = dict(est.light_aware, photometric_fit=without_guide_spread(fit, "the guides' points resolved in the "
                                                                         "region")) if fused else est.light_aware
    return [_row(est, camera, uv, f"guide {j + 1}'s lobe of {len(k)} fused into one highlight" if fused
                 else f"guide {j + 1}'s lobe, cut by the frame's edge",
                 f"BP at its specular point, normal from {'their joint' if fused else 'its'} photometric fit",
                 light_aware=la)
            for j, uv in zip(k[free].tolist(), p[free])]


def _row(est, camera, uv: np.ndarray, what: str, how: str, **fields):
    """``est`` as one guide's ok row: BP ``uv`` and its ray, detail ``what (status: detail); how``, ``fields``."""
    was = f"{est.status}{': ' + est.detail if est.detail else ''}"
    return dataclasses.replace(est, bp_px=uv.copy(), status="ok", detail=f"{what} ({was}); {how}",
                               bp_ray=-np.asarray(_model(camera).pixel_to_ray(uv[None]), np.float64)[0], **fields)


def _tops_pair(gray: np.ndarray, region, camera, rig, at_clip: bool = False):
    """The region's two largest clipped tops (each holding a :data:`~simtest.decisions.TOP_CORE_PX` square: pixels
    a noise lifts over the level on a lobe's flank are no specular point) where the rig pairs them:
    ``(centroids (2, 2), labels, the two labels, pair_plane's result)``, or None. The tops within
    :data:`~simtest.decisions.CLIP_LUMA_MARGIN_REL` of the peak (JPEG's broken tops); ``at_clip``, those at the peak
    where the margin's top narrows between them (:func:`_waisted`): two lobes near the scope whose tails sum to within
    the margin between their plateaus are one top at the margin, two at the clip (a top JPEG broke is not waisted)."""
    pair = _paired_tops(_tops(gray, region, 0.0 if at_clip else CLIP_LUMA_MARGIN_REL), region, camera, rig)
    return pair if not at_clip or pair is None or _waisted(_tops_depth(gray, region), region, pair[0]) else None


def _paired_tops(tops_mask: np.ndarray, region, camera, rig):
    """:func:`_tops_pair` of the tops ``tops_mask`` (bool, ROI indices)."""
    mask, r0, c0 = region
    _, labels, stats, centroids = cv2.connectedComponentsWithStats(top8 := tops_mask.astype(np.uint8), connectivity=8)
    # the components that hold a TOP_CORE_PX square (a pixel whose square lies in the tops)
    core = cv2.erode(top8, np.ones((TOP_CORE_PX, TOP_CORE_PX), np.uint8)) > 0
    tops = np.setdiff1d(labels[core], [0])
    if len(tops) < 2:
        return None
    two = tops[np.argsort(-stats[tops, cv2.CC_STAT_AREA], kind="stable")[:2]]
    x, y, w, h = (stats[two, k] for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    if (x == 0).any() or (y == 0).any() or (x + w == mask.shape[1]).any() or (y + h == mask.shape[0]).any():
        return None  # a top the ROI cuts: its centroid is not its guide's specular point
    pts = centroids[two] + (c0, r0)
    plane = pair_plane(camera, rig.positions, pts[0], pts[1])
    return None if plane is None else (pts, labels, two.tolist(), plane)


def _on_a_top(uv: np.ndarray, labels: np.ndarray, two, origin) -> bool:
    """Whether any of the points (k, 2) lies on either of the two tops ``two`` of ``labels``."""
    rc, ok = _roi_index(uv, labels.shape, origin)
    return bool(np.isin(labels[rc[ok, 0], rc[ok, 1]], two).any())


def _places_the_pair(uv: np.ndarray, pair, origin) -> bool:
    """Whether a split's points (k, 2) place a pair of clipped tops (:func:`_tops_pair`): one within
    :data:`~simtest.decisions.PAIR_TOL_PX` of each top's centroid, or one on each top at least
    :data:`~simtest.decisions.TOP_CORE_SHARE` of its largest distance from its edge (a large top's
    centroid is off its specular point)."""
    centres, labels, two, _ = pair
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if not len(uv):
        return False
    if (np.linalg.norm(centres[:, None] - uv[None], axis=-1).min(axis=1) <= PAIR_TOL_PX).all():
        return True
    rc, ok = _roi_index(uv, labels.shape, origin)
    rc = rc[ok]
    for t in two:  # the depth below the top's edge (0 off it)
        depth = cv2.distanceTransform(np.pad((labels == t).astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
        if not (depth[rc[:, 0], rc[:, 1]] >= TOP_CORE_SHARE * depth.max()).any():
            return False
    return True


def _pair_estimates(camera, rig, pts: np.ndarray, plane) -> list:
    """The ``rig_pair`` estimate of each of the two tops: the pair's normal, its sigma from the
    centroids moved by :data:`~simtest.decisions.TOPS_PLACE_SIGMA_PX` plus half the misclosure,
    each top's depth where within the depth ceiling.
    """
    normal, depths, guides, misclosure = plane
    turns, rel = [], []
    for k, axis in np.ndindex(2, 2):
        moved = pts.copy()
        moved[k, axis] += TOPS_PLACE_SIGMA_PX
        got = pair_plane(camera, rig.positions, moved[0], moved[1], slack_px=TOPS_PLACE_SIGMA_PX)
        if got is None:  # the moved pair off the curves: no sigma to state
            return []
        turns.append(angle_between_deg(got[0], normal))
        rel.append(np.abs(np.log(got[1] / depths)))
    sigma = float(np.sqrt(np.sum(np.square(turns)))) + 0.5 * misclosure
    rel_sigma = np.sqrt(np.sum(np.square(rel), axis=0))  # per top
    out = []
    for k in range(2):
        released = bool(rel_sigma[k] <= DEPTH_RELEASE_REL_SIGMA)
        detail = (f"guides {guides[0] + 1} and {guides[1] + 1}'s clipped tops {np.linalg.norm(pts[0] - pts[1]):.3g} "
                  f"px apart: depths {depths[0]:.4g} and {depths[1]:.4g} mm (relative sigma {rel_sigma[k]:.2g}), "
                  f"misclosure {misclosure:.2g} deg")
        out.append(LightAwareEstimate("rig_pair", "ok" if released else "depth_not_observable", detail, normal.copy(),
                                      depth_mm=float(depths[k]) if released else None, normal_sigma_deg=sigma,
                                      depth_sigma_mm=float(rel_sigma[k] * depths[k]) if released else None))
    return out


def _pair_rows(est, camera, rig, region, pair, others: np.ndarray, split: list | None) -> list | None:
    """The ``rig_pair`` rows of a clipped candidate's paired tops where ``split`` does not place them
    (:func:`_places_the_pair`), or None."""
    if pair is None:
        return None
    pts, labels, two, plane = pair
    if _on_a_top(others, labels, two, region[1:]):
        return None  # a top that holds an ok candidate's BP already has its row
    if split is not None and _places_the_pair(np.array([r.bp_px for r in split]), pair, region[1:]):
        return None  # the candidate's fit places the pair: its split stands
    ests, guides = _pair_estimates(camera, rig, pts, plane), plane[2]
    return [_row(est, camera, pts[k], f"guide {guides[k] + 1}'s clipped top of 2 fused into one highlight",
                 "BP at its centroid, normal from the pair's geometry (rig_pair)",
                 light_aware=dict(est.light_aware or {}, rig_pair=ests[k]))
            for k in np.argsort(guides)] if ests else None


def fused_lobe_candidates(gray, estimates, camera, rig, among=None) -> list[int]:
    """The indexes of the rejected candidates in :data:`SPLIT_STATUSES` (of ``among``, default all) whose region
    reaches along the rig's curve (``gray``: the frame's luma), to be fitted with the plane only and split (none
    without a rig off the camera centre); each one's peak significant (:func:`_significant`: the detector's rejects
    were never height-checked), a ``not_specular`` one only under two guides, its tops stretched along the curve."""
    if not _offset_rig(rig):
        return []
    two = len(rig.positions) == 2  # three or more guides' tops make a polygon, not a line
    return [i for i, e in enumerate(estimates) if (among is None or i in among) and splittable(e, gray) and not e.ok
            and (two or e.status != "not_specular") and _significant(gray, e)
            and _along_the_rig(gray, e, camera, rig, two and e.status == "not_specular")]


def _one_split_per_pair(parts: list, splits: list) -> None:
    """Of two candidates split for the same guides' lobes, the split of smaller normal sigma keeps its
    rows, the other its own row (``parts`` edited in place).
    """
    for a in range(len(splits)):
        for b in range(a + 1, len(splits)):
            (ka, pa, sa, ea), (kb, pb, sb, eb) = splits[a], splits[b]
            if len(pa) != len(pb) or len(parts[ka]) == 1 or len(parts[kb]) == 1:
                continue
            spacing = min(float(np.linalg.norm(pa[0] - pa[-1])), float(np.linalg.norm(pb[0] - pb[-1])))
            if np.all(np.linalg.norm(pa - pb, axis=1) < spacing / 2.0):
                k, est = (kb, eb) if sa <= sb else (ka, ea)
                parts[k] = [est]


def split_fused_lobes(image, estimates, camera, rig, *, prefitted=(), gray=None, weak=(), rival=None) -> list:
    """The estimates with each candidate of fused guide lobes replaced by one row per guide.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The frame the estimates were made on.
    estimates : sequence of SpecularityEstimate
        With their light-aware fits.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K or a camera model.
    rig : LightRig or None
        The scope's lights (None, or every light at the camera centre: returned unchanged).
    prefitted : collection of int
        The rejected candidates fitted with the plane only (:func:`fused_lobe_candidates`).
    gray : ndarray of shape (H, W), optional
        The frame's luma when at hand.
    weak : collection of int
        The candidates the height check passed for their rig twin alone (module docstring, "Rule").
    rival : callable, optional
        ``rival(est, fit)``: a lone-lobe fit of a region the frame cuts that fits it better than its joint fit
        ``fit`` (:func:`~simtest.reconstruct.lone_lobes.lone_rival`), or None; such a region is that guide's lobe,
        its row from the rival (the cut lobe's rule), not a split.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``, a split candidate's rows in the rig's order in its place.
    """
    if not _offset_rig(rig):
        return list(estimates)
    # the frame's luma, made for the first candidate that a split may concern if not given
    bps = np.array([e.bp_px for e in estimates], dtype=np.float64).reshape(-1, 2)
    # an ok candidate whose recommendation is the BP ray has no light-aware row a split would repeat
    aware = np.array([e.ok and e.recommended.normal_from != "bp_ray" for e in estimates], bool)
    parts: list = []  # each candidate's rows
    splits: list = []  # (part index, its rows' BPs, the joint fit's normal sigma, the unsplit row)
    tops: dict = {}  # part index -> a clipped unsplit row's bright region
    for i, est in enumerate(estimates):
        rows = None
        if est.ok or i in prefitted:
            gray = luma(np.asarray(image)) if gray is None else gray
            # the light-aware ok candidates' BPs and the guide lobes split so far have their rows
            others = np.concatenate([bps[aware & (np.arange(len(bps)) != i)], *(pts for _, pts, _, _ in splits)])
            # the fit's split if it places the paired tops (_places_the_pair), else the pair's rows, else the split
            region = _bright_region(gray, est)
            # the clipped tops' pair, once for both (the rig's pair of one guide is none)
            pair = _tops_pair(gray, region, camera, rig) if est.saturated and region is not None else None
            rows = _rows(est, camera, rig, gray, region, pair, others, i in weak)
            if rival is not None and rows is not None and len(rows) > 1 and est.status in _CUT and (
                    lone := rival(est, est.light_aware["photometric_fit"])) is not None:
                est = dataclasses.replace(est, light_aware=dict(est.light_aware, photometric_fit=lone))
                rows = _rows(est, camera, rig, gray, region, pair, others, i in weak)
            if pair is None and rows is None and est.saturated and region is not None:
                pair = _tops_pair(gray, region, camera, rig, at_clip=True)  # (no split: the tops at the clip)
            rows = _pair_rows(est, camera, rig, region, pair, others, rows) or rows
            est = est if est.ok else dataclasses.replace(est, light_aware={})  # a rejected row: no fits
        if rows is not None:
            la = rows[0].light_aware
            sigma = (la.get("rig_pair") or la["photometric_fit"]).normal_sigma_deg
            splits.append((len(parts), np.array([r.bp_px for r in rows]), np.inf if sigma is None else sigma, est))
            if est.saturated and region is not None:
                tops[len(parts)] = region
        parts.append(rows if rows is not None else [est])
    if not splits:
        return [e for part in parts for e in part]
    _one_split_per_pair(parts, splits)
    out = [e for part in parts for e in part]
    # a rejected candidate, or an ok one with only the BP ray, on a split's specular point, inside the split
    # candidate's closed isophote or, clipped, in its bright region (a maximum the noise made on the lobes' tops: one
    # peak, not many) is that row
    done = [k for k, _, _, _ in splits if len(parts[k]) > 1]
    sp = np.asarray([p for k, pts, _, _ in splits if k in done for p in pts], np.float64).reshape(-1, 2)
    split_rows = {id(r) for k in done for r in parts[k]}
    out_bps = np.array([e.bp_px for e in out], np.float64).reshape(-1, 2)
    near = (np.linalg.norm(out_bps[:, None] - sp[None], axis=-1) < PAIR_TOL_PX).any(axis=1) | np.any(
        [isophote_holds(unsplit, out_bps) for k, _, _, unsplit in splits if k in done], axis=0) | np.any(
        [_inside(tops[k], out_bps) for k in done if k in tops], axis=0)
    return [e for e, at in zip(out, near)
            if not at or id(e) in split_rows or (e.ok and e.recommended.normal_from != "bp_ray")]


def _partner(out: list, bps: np.ndarray, wander: np.ndarray, uv, gray: np.ndarray):
    """``(c, region)``: the rejected candidate (not ok, fitted when rejected ones are) whose BP lies within
    ``PAIR_TOL_PX`` plus its wander of ``uv``, the nearest (region None); else one with no closed isophote to
    measure its wander (or rejected as ``not_specular`` or ``too_small``) whose bright region (:func:`_bright_region`)
    holds ``uv``, with that region. None where an ok row's BP lies within ``PAIR_TOL_PX`` of ``uv``, or none is."""
    uv = np.asarray(uv, np.float64)
    gaps = np.nan_to_num(np.linalg.norm(bps - uv, axis=1), nan=np.inf)
    ok = np.array([e.ok for e in out], bool)
    fitted = np.array([e.status not in NOT_FITTED for e in out], bool)
    free = ~ok & fitted & (gaps <= PAIR_TOL_PX + wander)
    if _ok_row_at(out, bps, uv):
        return None
    if free.any():
        return int(np.flatnonzero(free)[np.argmin(gaps[free])]), None
    # no wander to measure (no closed isophote; a not_specular or too_small lobe has none either), its ROI holding uv
    rois = np.array([tuple(e.roi) for e in out], np.float64).reshape(-1, 4)  # (row0, row1, col0, col1)
    bare = (~ok & ~(wander > 0) & (fitted | np.array([e.status in ("not_specular", "too_small") for e in out], bool))
            & (rois[:, 2] <= uv[0]) & (uv[0] < rois[:, 3]) & (rois[:, 0] <= uv[1]) & (uv[1] < rois[:, 1]))
    for c in np.flatnonzero(bare)[np.argsort(gaps[bare], kind="stable")]:
        region = _bright_region(gray, out[c])
        if region is not None and _inside(region, uv[None])[0]:
            return int(c), region
    return None


def _ok_row_at(out: list, bps: np.ndarray, uv, but: int | None = None) -> bool:
    """Whether an ok row of ``out`` (other than row ``but``) has its BP within ``PAIR_TOL_PX`` of ``uv``: that
    guide's highlight has its row already, which a partner's row there would give twice."""
    gaps = np.nan_to_num(np.linalg.norm(bps - np.asarray(uv, np.float64), axis=1), nan=np.inf)
    return bool(((gaps < PAIR_TOL_PX) & np.array([e.ok for e in out], bool) & (np.arange(len(out)) != but)).any())


def _placing_plane(est, bp, reach: float, camera, rig):
    """``(fit, pts, i)`` of an ok row whose recommended plane fit (ok, with its distance) puts its own guide i's
    specular point within ``reach`` px of its BP ``bp``, ``pts`` (J, 2) every guide's; None for any other row."""
    fit = (est.light_aware or {}).get("photometric_fit")
    if not (est.ok and est.recommended.normal_from == "photometric_fit" and _plane(fit)):
        return None
    pts = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
    return None if (i := _own_guide(pts, bp, reach, est)) is None else (fit, pts, i)


def isophote_holds(est, points) -> np.ndarray:
    """Which of ``points`` (N, 2) px lie inside ``est``'s closed primary isophote (all False without one): a broad
    lobe's BP climbs the diffuse slope away from its specular point by more than its isophote does."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    p = est.primary
    if p is None or not p.closed or p.points_uv is None or len(p.points_uv) < 3:
        return np.zeros(len(points), bool)
    return np.asarray(polygon_contains(np.asarray(p.points_uv, np.float64), points), bool)


def _own_guide(pts: np.ndarray, bp, reach: float, est=None) -> int | None:
    """The guide whose point of ``pts`` (J, 2) lies nearest ``bp``, where within ``reach`` px; else, given the row
    ``est``, the one guide whose point its closed isophote holds (:func:`isophote_holds`); else None."""
    own = np.nan_to_num(np.linalg.norm(pts - np.asarray(bp, np.float64), axis=1), nan=np.inf)
    if own.min() <= reach:
        return int(np.argmin(own))
    held = () if est is None else np.flatnonzero(isophote_holds(est, np.nan_to_num(pts, nan=-1e9)))
    return int(held[0]) if len(held) == 1 else None


def _quadric_partners(out: list, a: int, bps: np.ndarray, wander: np.ndarray, camera, rig, gray) -> None:
    """Each rejected candidate at another guide's specular point of row ``a``'s quadric fit (one patch holding
    every guide's lobe) made that guide's row with the same fit, where the fit puts its own guide's point on
    row ``a``'s BP (:func:`partner_rows`; ``out`` and ``bps`` updated)."""
    q = out[a].light_aware["quadric_fit"]
    if q.light_normals is None or q.light_depths_mm is None:
        return
    pts = patch_specular_points(camera, rig, q.light_normals, q.light_depths_mm)
    i = _own_guide(pts, bps[a], PAIR_TOL_PX + wander[a])
    if i is None:
        return  # its fit does not place its own highlight
    for j in range(len(pts)):
        found = None if j == i or not np.isfinite(pts[j]).all() else _partner(out, bps, wander, pts[j], gray)
        if found is not None and found[1] is None:  # (a candidate whose BP lies there, not a bare region)
            c = found[0]
            out[c] = _row(out[c], camera, pts[j], f"guide {j + 1}'s highlight where guide {i + 1}'s quadric puts it",
                          "BP at its specular point, normals from that quadric fit (one patch, both lobes)",
                          light_aware=out[a].light_aware)
            bps[c] = pts[j]


def partner_rows(image, estimates, camera, rig, fit_kwargs: dict, *, gray=None) -> list:
    """The estimates with each rejected candidate where an ok row's plane fit puts another guide's highlight
    made that guide's row, where its own plane fit puts the row's highlight back (module docstring).

    Parameters
    ----------
    image, estimates, camera, rig, gray
        As in :func:`split_fused_lobes` (the estimates after it).
    fit_kwargs : dict
        The frame's arguments of :func:`~simtest.reconstruct.light_fits.light_aware_estimates`.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``; a partner's row in its candidate's place.
    """
    out = list(estimates)
    if not _offset_rig(rig):
        return out
    bps = np.array([e.bp_px for e in out], np.float64).reshape(-1, 2)
    wander = np.array([estimate_wander_px(e) for e in out])
    for a, est in enumerate(estimates):
        if est.ok and est.recommended.normal_from == "quadric_fit":
            gray = luma(np.asarray(image)) if gray is None else gray
            _quadric_partners(out, a, bps, wander, camera, rig, gray)
        if (placed := _placing_plane(est, bps[a], PAIR_TOL_PX + wander[a], camera, rig)) is None:
            continue
        _, pts, i = placed
        for j in range(len(pts)):
            gray = luma(np.asarray(image)) if gray is None and j != i else gray
            found = None if j == i else _partner(out, bps, wander, pts[j], gray)
            if found is None:
                continue
            c, region = found
            with one_thread_each():  # as with_light_aware's fits: the same bits on any number of workers
                fits = light_aware_estimates(image, out[c], camera, rig, **(fit_kwargs | PLANE_ONLY))
            pf = fits.get("photometric_fit")
            q = guide_specular_points(camera, rig, pf.normal, pf.distance_mm) if _plane(pf) else None
            if q is None or _ok_row_at(out, bps, q[j], but=c) or not (
                    (np.linalg.norm(q[j] - bps[c]) <= PAIR_TOL_PX + wander[c]
                     if region is None else _inside(region, q[j][None])[0])
                    and _own_guide(q, bps[a], PAIR_TOL_PX + wander[a], est) == i):
                continue  # (an ok row at its specular point holds that guide's highlight already)
            out[c] = _row(out[c], camera, q[j], f"guide {j + 1}'s highlight where guide {i + 1}'s fit puts it",
                          f"BP at its specular point, normal from its photometric fit, which puts guide {i + 1}'s back",
                          light_aware=fits)
            bps[c] = q[j]
    return _with_unseen_partners(image, out, bps, wander, camera, rig, fit_kwargs, gray)


def _with_unseen_partners(image, out: list, bps: np.ndarray, wander: np.ndarray, camera, rig, fit_kwargs: dict,
                          gray) -> list:
    """``out`` with a row for each guide's highlight that an ok row's plane fit places in the frame where no ok
    row's lobe holds it (detection found no candidate of it: a weak lobe on bright shading), where a plane fit of its own on a ROI
    of the placing row's size about that point puts both guides' specular points where the first fit does (its own
    within :data:`~simtest.decisions.PAIR_TOL_PX` of that point, the placing row's guide within ``PAIR_TOL_PX`` plus
    that BP's wander). Rows in ``out``'s order, the new ones by their BP's luma among them (brightest first)."""
    new, ok = [], np.array([e.ok for e in out], bool)
    size = np.array([lobe_size_px(e) for e in out])
    for a, est in enumerate(list(out)):
        if (placed := _placing_plane(est, bps[a], PAIR_TOL_PX + wander[a], camera, rig)) is None:
            continue
        _, pts, i = placed
        for j in np.flatnonzero(_in_frame(pts, np.shape(image)) & (np.arange(len(pts)) != i)):
            gaps = np.nan_to_num(np.linalg.norm(bps - pts[j], axis=1), nan=np.inf)
            if ((gaps <= size) & ok).any() or any(np.linalg.norm(e.bp_px - pts[j]) <= PAIR_TOL_PX for e in new):
                continue  # an ok row holds that lobe already (its BP within the lobe: a broad one's climbs the shading)
            gray = luma(np.asarray(image)) if gray is None else gray
            row = _unseen_partner(image, gray, est, pts[j], (i, j), bps[a], PAIR_TOL_PX + wander[a], camera, rig,
                                  fit_kwargs)
            if row is not None:
                new.append(row)
    for row in new:  # (stable: after the rows as bright)
        at = next((k for k, e in enumerate(out) if e.bp_intensity < row.bp_intensity), len(out))
        out.insert(at, row)
    return out


def _unseen_partner(image, gray, donor, uv, guides, donor_bp, reach: float, camera, rig, fit_kwargs: dict):
    """Guide ``j``'s row at ``uv`` (u, v) px, where ``donor``'s plane fit puts it (``guides = (i, j)``, ``i`` the
    donor's guide, its BP ``donor_bp`` within ``reach``), where a plane fit on a ROI of the donor's size about
    ``uv`` agrees (:func:`_with_unseen_partners`); None where it does not."""
    i, j = guides
    r, c = (int(v) for v in np.rint(uv_to_rc(np.asarray(uv, np.float64))))
    roi = Roi.around(uv, _reach(donor, 1.0), np.shape(gray))
    ray = np.asarray(_model(camera).pixel_to_ray(np.asarray(uv, np.float64)[None]), np.float64)[0]
    cand = SpecularityEstimate(np.asarray(uv, np.float64).copy(), float(gray[r, c]), False, roi, "not_detected",
                               "no candidate of the lobe's size", -ray, ())
    with one_thread_each():  # as with_light_aware's fits: the same bits on any number of workers
        fits = light_aware_estimates(image, cand, camera, rig, **(fit_kwargs | PLANE_ONLY))
    pf = fits.get("photometric_fit")
    if not _plane(pf):
        return None
    q = guide_specular_points(camera, rig, pf.normal, pf.distance_mm)
    if not (np.linalg.norm(q[j] - uv) <= PAIR_TOL_PX and _own_guide(q, donor_bp, reach, donor) == i):
        return None
    return _row(cand, camera, q[j], f"guide {j + 1}'s highlight where guide {i + 1}'s fit puts it",
                f"BP at its specular point, normal from its photometric fit, which puts guide {i + 1}'s back",
                light_aware=fits)


def shared_plane_rows(estimates, camera, rig) -> list:
    """The estimates with each ok row left with the BP ray given the plane of an ok row that places both
    (``rig_pair``, its depth released as the plane fit's; module docstring).

    Parameters
    ----------
    estimates : sequence of SpecularityEstimate
        After the light-aware fits and the rig's rows (:func:`partner_rows`), their sigmas final.
    camera, rig
        As in :func:`split_fused_lobes`.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``.
    """
    out = list(estimates)
    left = [b for b, e in enumerate(out) if e.ok and e.light_aware is not None and e.recommended.normal_from == "bp_ray"]
    if not (left and _offset_rig(rig)):
        return out
    bps = np.array([e.bp_px for e in out], np.float64).reshape(-1, 2)
    reach = PAIR_TOL_PX + np.array([estimate_wander_px(e) for e in out])
    donors = [(a, p) for a, e in enumerate(estimates) if (p := _placing_plane(e, bps[a], reach[a], camera, rig))]
    # the rows given (a row made here is no plane fit's), the surest plane first where two place one row
    for a, (fit, pts, i) in sorted(donors, key=lambda d: np.inf if (g := d[1][0].normal_sigma_deg) is None else g):
        for b in [b for b in left if "rig_pair" not in out[b].light_aware]:
            if (j := _own_guide(pts, bps[b], reach[b], out[b])) is None or j == i:
                continue
            ray = np.asarray(_model(camera).pixel_to_ray(bps[b][None]), np.float64)[0]
            depth = fit.distance_mm / -float(np.asarray(fit.normal) @ ray)  # the plane n . X = -h along the ray
            rel = fit.depth_sigma_mm / fit.depth_mm if fit.depth_mm and fit.depth_sigma_mm is not None else None
            detail = (f"guide {j + 1}'s highlight where row {a}'s plane fit puts it ({np.linalg.norm(pts[j] - bps[b]):.2g}"
                      f" px), with guide {i + 1}'s on that row's BP ({np.linalg.norm(pts[i] - bps[a]):.2g} px)")
            pair = LightAwareEstimate("rig_pair", fit.status, detail, np.array(fit.normal, np.float64),
                                      depth_mm=depth if fit.depth_mm is not None else None,
                                      normal_sigma_deg=fit.normal_sigma_deg, depth_sigma_mm=rel and rel * depth,
                                      distance_mm=fit.distance_mm, bp_ray_error_deg=fit.bp_ray_error_deg)
            out[b] = dataclasses.replace(out[b], light_aware={**out[b].light_aware, "rig_pair": pair})
    return out
