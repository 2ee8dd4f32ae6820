"""Where a scope's other light guides put their highlights, seen from one highlight's BP.

A planar patch lit by several guides shows one highlight per guide; the ``cluster`` check
(:mod:`simtest.reconstruct.verify`) must not take them for a cluster.

Derivation (planar patch, camera frame, mm): if the BP's unit ray ``r`` is guide ``i``'s specular
point at depth ``d``, ``X = d r``, the normal is ``n = unit(unit(-X) + unit(L_i - X))``, the plane
``n . Y = -h`` with ``h = -n . X``, and guide ``j``'s specular point is ``X_j = L'_j h / (-n . L'_j)``
with the mirror image ``L'_j = L_j - 2 (n . L_j + h) n``. Sweeping ``d`` over :data:`DEPTH_MIN_MM`
to :data:`DEPTH_MAX_MM` draws, per ordered pair of guides, a curve in the image; a peak within
:data:`PAIR_TOL_PX` of it is another guide's highlight. :func:`other_lobe_centres` finds that lobe
on the curve so the verifier can leave it out of the surround. The merge rule and :func:`rig_twins` (a
pair vouching for a weak lobe's colour) add each BP's :func:`bp_wander_px` to the tolerance.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest._lazy import require
from simtest.decisions import PAIR_DEPTH_MAX_MM as DEPTH_MAX_MM
from simtest.decisions import PAIR_DEPTH_MIN_MM as DEPTH_MIN_MM
from simtest.decisions import PAIR_TOL_PX
from simtest.geometry.angles import angle_between_deg, unit
from simtest.geometry.cameras import PinholeCamera
from simtest.reconstruct._pixels import uv_to_rc
from simtest.reconstruct.evidence_pixels import ellipse_level
from simtest.reconstruct.isophote import polygon_contains

__all__ = ["DEPTH_MIN_MM", "DEPTH_MAX_MM", "DEPTH_SAMPLES", "PAIR_TOL_PX", "other_guide_curves", "pair_starts",
           "guide_specular_points", "patch_specular_points", "other_lobe_centres", "pair_plane", "pair_partners",
           "encloses_only_partners", "bp_wander_px", "box_wander_px", "estimate_wander_px", "rig_twins"]

#: Depths sampled, geometrically spaced (the curve's image step shrinks as 1 / d^2).
DEPTH_SAMPLES = 256
_DEPTHS = np.geomspace(DEPTH_MIN_MM, DEPTH_MAX_MM, DEPTH_SAMPLES)
#: The most pieces :func:`_dense_curve` cuts one depth step into (a step whose image runs off towards the
#: horizon is thousands of px long; a frame is at most a few thousand wide).
_MOST_CUTS = 4096


def _curve(ray, Li, Lj, depths) -> np.ndarray:
    """Guide j's specular points (D, 3) for the BP as guide i's at each depth (NaN: inadmissible); for rays
    (N, 3), (N, D, 3), each row the same bits as its ray's alone."""
    rays = np.asarray(ray, np.float64)
    X = (depths[None, :, None] * rays.reshape(-1, 1, 3)).reshape(-1, 3)
    n = unit(unit(-X, -1) + unit(Li - X, -1), -1)
    h = -np.einsum("ij,ij->i", n, X)  # > 0: the plane faces the camera (n . ray < 0)
    Lm = Lj - 2.0 * (n @ Lj + h)[:, None] * n
    den = -np.einsum("ij,ij->i", n, Lm)
    ok = (h > 0) & (n @ Li + h > 0) & (n @ Lj + h > 0) & (den > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok[:, None], Lm * (h / den)[:, None], np.nan).reshape(*rays.shape[:-1], len(depths), 3)


def _imaged_curves(camera, L: np.ndarray, ray, depths: np.ndarray):
    """Per ordered pair (i, j) of guides at different places: ``(i, j, uv)``, guide j's specular
    points (D, 2) imaged for the BP's unit ``ray`` as guide i's at ``depths`` (NaN: inadmissible); for
    rays (N, 3), uv (N, D, 2), one call of the camera model for all."""
    for i, j in _guide_pairs(L):
        yield i, j, _imaged_curve(camera, L[i], L[j], ray, depths)


def _guide_pairs(L: np.ndarray) -> list[tuple[int, int]]:
    """The ordered pairs (i, j) of guides at different places among the positions ``L`` (G, 3), i first."""
    return [(i, j) for i in range(len(L)) for j in range(len(L)) if np.linalg.norm(L[i] - L[j]) > 0]


def _imaged_curve(camera, Li, Lj, ray, depths: np.ndarray) -> np.ndarray:
    """Guide j's specular points imaged (D, 2) or (N, D, 2) for the BP as guide i's (:func:`_imaged_curves`)."""
    flat = (Xj := _curve(unit(ray, -1), Li, Lj, depths)).reshape(-1, 3)
    uv, good = np.full((len(flat), 2), np.nan), np.isfinite(flat).all(axis=1)
    uv[good] = camera.ray_to_pixel(flat[good]) if good.any() else uv[good]
    return uv.reshape(*Xj.shape[:-1], 2)


def _in_frame(pts: np.ndarray, shape) -> np.ndarray:
    """Which (u, v) px points of ``pts`` (J, 2) lie in an image of ``shape`` (J,) bool."""
    h, w = shape[:2]
    with np.errstate(invalid="ignore"):
        return np.isfinite(pts).all(axis=1) & (pts >= 0).all(axis=1) & (pts[:, 0] < w) & (pts[:, 1] < h)


def _dense_curve(camera, Li, Lj, ray, shape, step_px: float) -> tuple[np.ndarray, np.ndarray]:
    """``(depths (D,), uv (D, 2))``: :func:`_imaged_curve` on the depth grid with each step that has an end in a
    frame of ``shape`` (rows, columns) cut into geometric pieces by its image length, about one a ``step_px`` px:
    the grid's image step grows as 1 / d^2, tens of px on a near steep plane, where a lobe may lie between samples."""
    uv = _imaged_curve(camera, Li, Lj, ray, _DEPTHS)
    inside = _in_frame(uv, shape)
    gap = np.linalg.norm(np.diff(uv, axis=0), axis=1)
    cut = np.isfinite(gap) & (inside[:-1] | inside[1:])
    k = np.ones(len(gap), np.int64)
    k[cut] = np.clip(np.ceil(gap[cut] / step_px), 1, _MOST_CUTS)
    seg = np.repeat(np.arange(len(k)), k)
    t = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / np.repeat(k, k)
    depths = np.concatenate([_DEPTHS[seg] * (_DEPTHS[seg + 1] / _DEPTHS[seg]) ** t, _DEPTHS[-1:]])
    return depths, _imaged_curve(camera, Li, Lj, ray, depths)


def _resampled(uv: np.ndarray, step: float, centre: np.ndarray, radius: float) -> np.ndarray:
    """The polyline through the finite rows of ``uv`` every ``step`` px, within ``radius`` of
    ``centre`` (the vertices beyond dropped but for those of a segment crossing the circle)."""
    uv = uv[np.isfinite(uv).all(axis=1)]
    near = np.linalg.norm(uv - centre, axis=1) <= radius
    uv = uv[near | np.r_[near[1:], False] | np.r_[False, near[:-1]]]
    if len(uv) < 2:
        return uv
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv, axis=0), axis=1))])
    t = np.arange(0.0, s[-1] + step, step)
    pts = np.column_stack([np.interp(t, s, uv[:, 0]), np.interp(t, s, uv[:, 1])])
    return pts[np.linalg.norm(pts - centre, axis=1) <= radius]


def other_guide_curves(camera, positions_mm, bps_uv, radius_px, step_px: float = 0.5) -> list[np.ndarray]:
    """Where the other guides' specular points can lie, per candidate (module docstring).

    Parameters
    ----------
    camera : CameraModel
        The camera (``pixel_to_ray``, ``ray_to_pixel``).
    positions_mm : array_like of shape (G, 3)
        The guides' positions, camera frame, mm.
    bps_uv : array_like of shape (N, 2)
        The candidates' BPs (u, v), px.
    radius_px : array_like of shape (N,)
        Keep the points within this distance of each BP, px (negative or NaN: none).
    step_px : float
        Spacing of the points along each curve, px.

    Returns
    -------
    list of ndarray of shape (M_k, 2)
        Per candidate, the points (u, v) of every ordered pair of guides' curve.
    """
    L = np.asarray(positions_mm, np.float64).reshape(-1, 3)
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    radius = np.broadcast_to(np.asarray(radius_px, np.float64), (len(bps),))
    rays = camera.pixel_to_ray(bps) if len(bps) else np.zeros((0, 3))
    use = np.flatnonzero(np.isfinite(rays).all(axis=1) & (radius >= 0))  # (NaN radius: none)
    curves = [uv for _, _, uv in _imaged_curves(camera, L, rays[use], _DEPTHS)] if len(use) else []
    out = [np.zeros((0, 2)) for _ in bps]
    for k, i in enumerate(use):  # every pair's curve of the candidate, resampled within its radius
        out[i] = np.concatenate([np.zeros((0, 2))] + [_resampled(uv[k], step_px, bps[i], radius[i]) for uv in curves])
    return out


def encloses_only_partners(camera, positions_mm, bp_uv, polygon_uv, points_uv, excused, wander_px=None) -> bool:
    """Whether a closed isophote encloses, besides its own BP, only other guides' lobes where the rig puts
    them (within :data:`PAIR_TOL_PX` of the BP's curves) or points ``excused``: a highlight of another
    guide of the rig is expected, not a merge.

    Parameters
    ----------
    camera, positions_mm
        As in :func:`other_guide_curves`.
    bp_uv : array_like of shape (2,)
        The isophote's BP (u, v), px.
    polygon_uv : ndarray of shape (P, 2)
        The closed isophote (u, v), px, without a repeated end point.
    points_uv : ndarray of shape (K, 2)
        The frame's other candidates' BPs (the own one may be among them).
    excused : ndarray of bool, shape (K,)
        The points that are no highlight's BP (peaks the colour checks refused).
    wander_px : ndarray of shape (K,), optional
        Each point's :func:`bp_wander_px` (0 where it has no isophote), px; the tolerance of a point is
        :data:`PAIR_TOL_PX` plus its wander and the polygon's own across the line from the BP to the point
        (None: no wander). Along that line the polygon's centroid is pulled towards the very lobes it
        encloses, and a shift of the BP along a curve moves no point off it.

    Returns
    -------
    bool
    """
    bp = np.asarray(bp_uv, np.float64)
    pts = np.asarray(points_uv, np.float64).reshape(-1, 2)
    inside = np.asarray(polygon_contains(polygon_uv, pts), bool) & ~np.asarray(excused, bool)
    inside &= np.hypot(*(pts - bp).T) > 1e-9
    if not inside.any():
        return True
    wander = np.zeros(len(pts)) if wander_px is None else np.asarray(wander_px, np.float64).reshape(-1)
    off = pts[inside] - bp
    own = _centroid_offset(bp, polygon_uv) if wander_px is not None else np.zeros(2)
    tol = PAIR_TOL_PX + np.abs(off[:, 0] * own[1] - off[:, 1] * own[0]) / np.hypot(*off.T) + wander[inside]
    reach = float(np.hypot(*(np.asarray(polygon_uv) - bp).T).max()) + float(tol.max())
    (curve,) = other_guide_curves(camera, positions_mm, bp[None], [reach])
    return bool(len(curve)) and bool(_placed(curve, pts[inside], bp, tol).all())


def rig_twins(camera, positions_mm, bps_uv, pool, wander_px, which) -> np.ndarray:
    """Which BPs of ``which`` have a twin: another BP of ``pool`` where the rig puts another guide's
    highlight, within :data:`PAIR_TOL_PX` plus both BPs' wander of the BP's curves.

    A weak lobe on tissue could be a pale patch of texture; a second one where the rig's geometry puts
    another guide's highlight of the same patch is what texture does not repeat.

    Parameters
    ----------
    camera, positions_mm
        As in :func:`other_guide_curves`.
    bps_uv : array_like of shape (N, 2)
        The BPs (u, v), px.
    pool : ndarray of bool, shape (N,)
        The BPs that may be a twin (white peaks that pass the height check).
    wander_px : ndarray of shape (N,)
        Each BP's wander from its lobe's centre (:func:`bp_wander_px`, 0 where unknown), px.
    which : ndarray of bool, shape (N,)
        The BPs asked about (the others are False).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    pool = np.asarray(pool, bool).reshape(-1)
    wander = np.asarray(wander_px, np.float64).reshape(-1)
    out = np.zeros(len(bps), bool)
    ask = np.flatnonzero(np.asarray(which, bool).reshape(-1))
    if not len(ask) or not pool.any():
        return out
    cand, w_cand = bps[pool], wander[pool]
    reach = np.linalg.norm(bps[ask][:, None] - cand[None], axis=-1).max(axis=1) + PAIR_TOL_PX + w_cand.max() + \
        wander[ask]
    for k, curve in zip(ask, other_guide_curves(camera, positions_mm, bps[ask], reach)):
        others = np.linalg.norm(cand - bps[k], axis=1) > PAIR_TOL_PX
        if len(curve) and others.any():
            out[k] = bool(_placed(curve, cand[others], bps[k], PAIR_TOL_PX + wander[k] + w_cand[others]).any())
    return out


def _placed(curve_uv: np.ndarray, points_uv: np.ndarray, bp_uv, tol_px) -> np.ndarray:
    """Which points (K,) lie within ``tol_px`` of a BP's curve (M, 2) where that tells: the curve starts beside the
    BP, so a tolerance as large as a point's distance from the BP admits it from any direction and confirms nothing."""
    gaps = require("scipy.spatial").cKDTree(curve_uv).query(points_uv)[0]  # to the curve's nearest sample, px
    return (gaps <= tol_px) & (tol_px < np.hypot(*(points_uv - np.asarray(bp_uv)).T))


def estimate_wander_px(est) -> float:
    """:func:`bp_wander_px` of an estimate's BP from its closed primary isophote; 0 without one."""
    p = est.primary
    return bp_wander_px(est.bp_px, p.points_uv) if p is not None and p.closed and p.points_uv is not None else 0.0


def box_wander_px(bps_uv, boxes) -> np.ndarray:
    """(N,): each BP's distance (px) from the centre of its region's box ``(row0, row1, col0, col1)`` (N, 4), both
    in one frame's coordinates: the wander of a BP whose lobe has no closed isophote yet (:func:`rig_twins`)."""
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    return np.hypot(bps[:, 0] - (b[:, 2] + b[:, 3] - 1) / 2, bps[:, 1] - (b[:, 0] + b[:, 1] - 1) / 2)


def bp_wander_px(bp_uv, polygon_uv) -> float:
    """How far a BP may lie from its guide's specular point beyond :data:`PAIR_TOL_PX`: its distance
    from the area centroid of its closed isophote ``polygon_uv`` (P, 2) (u, v) px.

    A lobe's isophotes surround its centre; its brightest pixel wanders from it where the top is flat
    (noise picks the maximum among pixels within a few sigmas of the peak) and where the diffuse shading
    or another lobe's tail slopes under it (the maximum moves up the slope by the slope times the lobe's
    squared width over its height). The isophote, a level well below the top, moves much less, so the
    BP's distance from its centroid measures that wander on each lobe, whatever its width. 0 for a
    degenerate polygon.
    """
    return float(np.hypot(*_centroid_offset(bp_uv, polygon_uv)))


def _centroid_offset(bp_uv, polygon_uv) -> np.ndarray:
    """The area centroid of a closed polygon (P, 2) less the BP (u, v), px (2,); 0 for a degenerate polygon."""
    poly = np.asarray(polygon_uv, np.float32).reshape(-1, 1, 2)
    m = cv2.moments(poly) if len(poly) >= 3 else {"m00": 0.0}
    if not abs(m["m00"]) > 0:
        return np.zeros(2)
    return np.array([m["m10"] / m["m00"] - float(bp_uv[0]), m["m01"] / m["m00"] - float(bp_uv[1])])


def pair_starts(camera, positions_mm, bps_uv, partners_uv, wander_px=None,
                partner_wander_px=None) -> list[tuple[tuple[int, int, float], ...]]:
    """The guides and depths at which the BP as one guide's specular point puts another's on a partner.

    On a plane the pair's separation fixes the depth, as a stereo baseline would: a start of the
    photometric fit (``FitSettings``' ``pair_starts``).

    Parameters
    ----------
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a model with ``pixel_to_ray`` and ``ray_to_pixel``.
    positions_mm : array_like of shape (G, 3)
        The guides' positions, camera frame, mm.
    bps_uv : array_like of shape (N, 2)
        The candidates' BPs (u, v), px.
    partners_uv : array_like of shape (P, 2)
        The BPs of the highlights that may be another guide's, px.
    wander_px : array_like of shape (N,), optional
        Each candidate's BP wander from its lobe's centre (:func:`estimate_wander_px`), px; default 0.
    partner_wander_px : array_like of shape (P,), optional
        Each partner's, px; default 0.

    Returns
    -------
    list of tuple of (int, int, float)
        Per candidate, sorted (i, j, d): the BP as guide i's specular point at depth d (mm, within
        :data:`DEPTH_MIN_MM` to :data:`DEPTH_MAX_MM`) puts guide j's within :data:`PAIR_TOL_PX` plus both
        BPs' wander of a partner (as :func:`rig_twins` pairs them); empty where no partner, or more than one,
        lies on a curve.
    """
    camera = _model(camera)
    L = np.asarray(positions_mm, np.float64).reshape(-1, 3)
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    partners = np.asarray(partners_uv, np.float64).reshape(-1, 2)
    wander = np.zeros(len(bps)) if wander_px is None else np.asarray(wander_px, np.float64).reshape(-1)
    p_wander = np.zeros(len(partners)) if partner_wander_px is None else np.asarray(partner_wander_px,
                                                                                    np.float64).reshape(-1)
    out: list = []
    rays = camera.pixel_to_ray(bps) if len(bps) else np.zeros((0, 3))
    for ray, bp, w in zip(rays, bps, wander):
        keep = np.linalg.norm(partners - bp, axis=1) > PAIR_TOL_PX
        near, tol = partners[keep], PAIR_TOL_PX + w + p_wander[keep]
        found: dict[int, set[tuple[int, int, float]]] = {}  # partner -> (i, j, depth)
        for i, j, uv in _imaged_curves(camera, L, ray, _DEPTHS) if len(near) and np.isfinite(ray).all() else ():
            # each partner's nearest point on the polyline's segments (consecutive admissible
            # samples), its depth interpolated geometrically along the segment
            a, ab = uv[:-1], np.diff(uv, axis=0)
            seg = np.isfinite(ab).all(axis=1)
            a, ab, d0, d1 = a[seg], ab[seg], _DEPTHS[:-1][seg], _DEPTHS[1:][seg]
            if not len(a):
                continue
            # (a partner beyond the tolerance of the curve's bounding box is beyond it of the curve)
            ends = np.concatenate([a, a + ab])
            box = np.all(np.abs(near - (ends.min(0) + ends.max(0)) / 2) <= np.ptp(ends, 0) / 2 + tol[:, None], axis=1)
            if not box.any():
                continue
            ap = near[box][None] - a[:, None]  # (segments, partners in the box, 2)
            t = np.clip((ap @ ab[..., None])[..., 0] / np.maximum((ab * ab).sum(axis=1), 1e-12)[:, None], 0, 1)
            dist = np.linalg.norm(ap - t[..., None] * ab[:, None], axis=-1)
            best = dist.argmin(axis=0)
            cols = np.arange(int(np.count_nonzero(box)))
            hit = dist[best, cols] <= tol[box]
            tb = t[best, cols]
            for c, d in zip(np.flatnonzero(box)[hit], (d0[best] ** (1.0 - tb) * d1[best] ** tb)[hit]):
                found.setdefault(int(c), set()).add((i, j, float(d)))
        out.append(tuple(sorted(next(iter(found.values())))) if len(found) == 1 else ())
    return out


def _pair_depth(camera, ray, Li, Lj, d0: float, partner) -> float:
    """The depth (mm along ``ray``) near the sampled ``d0`` at which guide j's specular point images on ``partner``."""
    opt = require("scipy.optimize")
    half = np.log(DEPTH_MAX_MM / DEPTH_MIN_MM) / (DEPTH_SAMPLES - 1)

    def gap(logd):
        X = _curve(ray, Li, Lj, np.exp(np.atleast_1d(logd)))
        if not np.isfinite(X).all():
            return np.inf
        return float(np.linalg.norm(camera.ray_to_pixel(X)[0] - partner))

    got = opt.minimize_scalar(gap, bounds=(np.log(d0) - half, np.log(d0) + half), method="bounded",
                              options={"xatol": 1e-6})
    return float(np.exp(got.x)) if np.isfinite(got.fun) else d0


def pair_plane(camera, positions_mm, a_uv, b_uv, slack_px: float = 0.0):
    """The plane of two highlights that are two guides' specular points on it (a stereo pair whose
    baseline is the guides'), solved both ways and the normals averaged.

    Parameters
    ----------
    camera, positions_mm
        As in :func:`pair_starts`.
    a_uv, b_uv : array_like of shape (2,)
        The two highlights' specular points (u, v), px.
    slack_px : float, optional
        Added to :data:`PAIR_TOL_PX` where the pairing is sought (:func:`pair_starts`): the px by which a caller
        moved the points on purpose (a sigma's perturbation of a pair already found).

    Returns
    -------
    tuple of (ndarray of shape (3,), ndarray of shape (2,), tuple of int, float) or None
        The unit normal (camera frame, facing the camera), each point's depth along its ray (mm),
        the guides (i, j) of a and b, and the misclosure of the two ways (deg); None where no or
        several guide pairs fit, or the two ways name different guides.
    """
    cam = _model(camera)
    L = np.asarray(positions_mm, np.float64).reshape(-1, 3)
    a, b = np.asarray(a_uv, np.float64).reshape(2), np.asarray(b_uv, np.float64).reshape(2)
    (sa,), (sb,) = (pair_starts(cam, L, p[None], q[None], [slack_px], [0.0]) for p, q in ((a, b), (b, a)))
    if len(sa) != 1 or len(sb) != 1 or sa[0][:2] != sb[0][1::-1]:
        return None
    normals, depths = [], []
    for (i, j, d0), p, q in ((sa[0], a, b), (sb[0], b, a)):
        ray = unit(np.asarray(cam.pixel_to_ray(p[None]), np.float64)[0])
        d = _pair_depth(cam, ray, L[i], L[j], d0, q)
        X = d * ray
        normals.append(unit(unit(-X) + unit(L[i] - X)))
        depths.append(d)
    misclosure = float(angle_between_deg(normals[0], normals[1]))
    return unit(normals[0] + normals[1]), np.array(depths), (sa[0][0], sa[0][1]), misclosure


def pair_misfit_px(camera, rig, bp_uv, starts, normal, distance_mm: float | None, *, shape=None,
                   margin_px: float = 0.0) -> float:
    """The least image distance (px), over ``starts`` (:func:`pair_starts`' (i, j, d)), between guide j's
    specular point on the plane (``normal``, ``distance_mm``) and the partner; inf without starts or
    where guide j lies behind the plane. ``distance_mm`` None (a fit that holds the normal, not the
    depth): each start's plane of ``normal`` through the BP's ray at its depth d. With ``shape`` (rows,
    cols), a partner within ``margin_px`` of the frame's edge counts no distance out toward that edge:
    the frame may cut its lobe, whose BP then lies inside of its specular point.
    """
    cam = _model(camera)
    ray = unit(np.asarray(cam.pixel_to_ray(np.asarray(bp_uv, np.float64).reshape(1, 2)), np.float64)[0])
    n = np.asarray(normal, np.float64)
    best = np.inf
    for (_, j, d), partner in zip(starts, pair_partners(cam, rig, bp_uv, starts)):
        h = distance_mm if distance_mm is not None else -float(n @ ray) * d  # (n . X = -h at X = d ray)
        diff = guide_specular_points(cam, rig, n, h)[j] - partner
        if shape is not None:
            # inward from a left or top edge +1, from a right or bottom edge -1, elsewhere 0 (u, v)
            far = np.array(shape[1::-1], np.float64) - 1.0 - partner
            inward = np.where(partner <= margin_px, 1.0, 0.0) - np.where(far <= margin_px, 1.0, 0.0)
            diff = np.where(inward * diff < 0, 0.0, diff)  # (a point out toward the edge is a cut lobe's)
        best = min(best, float(np.linalg.norm(diff)))  # (NaN: guide j behind the plane, never the least)
    return best


def pair_partners(camera, rig, bp_uv, starts) -> np.ndarray:
    """Where each of ``starts`` (:func:`pair_starts`' (i, j, d)) puts guide j's specular point: the BP
    as guide i's at depth d on the plane whose normal bisects the BP's ray and guide i's direction.

    Parameters
    ----------
    camera
        As in :func:`pair_starts`.
    rig : LightRig
        The scope's lights, camera frame, mm.
    bp_uv : array_like of shape (2,)
        The BP (u, v), px.
    starts : sequence of (int, int, float)
        Guides i and j and the depth d, mm.

    Returns
    -------
    ndarray of shape (len(starts), 2)
        (u, v) px of each partner; NaN where guide j's point is inadmissible (behind the plane).
    """
    cam = _model(camera)
    ray = unit(np.asarray(cam.pixel_to_ray(np.asarray(bp_uv, np.float64).reshape(1, 2)), np.float64)[0])
    L = np.asarray(rig.positions, np.float64).reshape(-1, 3)
    return np.array([cam.ray_to_pixel(_curve(ray, L[i], L[j], np.array([d])))[0] for i, j, d in starts],
                    np.float64).reshape(-1, 2)


def guide_specular_points(camera, rig, normal, distance_mm: float) -> np.ndarray:
    """Image points of each guide's specular point on a plane (module docstring).

    Parameters
    ----------
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a model with ``ray_to_pixel``.
    rig : LightRig
        The scope's lights, camera frame, mm.
    normal : array_like of shape (3,)
        Unit plane normal facing the camera (``n . X = -h`` on the plane), camera frame.
    distance_mm : float
        The plane's distance ``h`` from the camera centre, mm.

    Returns
    -------
    ndarray of shape (J, 2)
        (u, v) px per light, in the rig's order; NaN for a light behind the plane.
    """
    return _specular_points(camera, rig, normal, np.array([float(distance_mm)]))[0]


def patch_specular_points(camera, rig, light_normals, light_depths_mm) -> np.ndarray:
    """Image points of each guide's specular point on a curved patch, from the patch's normal there and
    the point's depth (a quadric fit's ``light_normals`` and ``light_depths_mm``).

    The plane tangent to the patch at guide j's specular point has that point as its own specular point
    for guide j (the mirror condition reads only the point and its normal): its distance h is where the
    plane's point (module docstring) lies at the depth d, ``h^2 (|L|^2 + 4 h (n . L + h)) = d^2 (n . L +
    2 h)^2``, solved by Brent's method between the light's plane and ``2 (d + |L|)`` (the depth exceeds h
    by ``O(|L|^2 / h)``), for a point farther from the camera than the light (nearer, two planes may put
    it at that depth).

    Parameters
    ----------
    camera, rig
        As in :func:`guide_specular_points`.
    light_normals : array_like of shape (J, 3)
        Unit normals at each guide's specular point, facing the camera, camera frame.
    light_depths_mm : array_like of shape (J,)
        Those points' distances from the camera centre, mm.

    Returns
    -------
    ndarray of shape (J, 2)
        (u, v) px per guide, in the rig's order; NaN where a normal or depth is not finite, the depth is not
        beyond the light's distance, or no plane facing the light puts its point there.
    """
    brentq = require("scipy.optimize").brentq
    L = np.asarray(rig.positions, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(L), 2), np.nan)
    for j, (n, d) in enumerate(zip(np.asarray(light_normals, np.float64).reshape(-1, 3),
                                   np.asarray(light_depths_mm, np.float64).reshape(-1))):
        a = float(n @ L[j])
        gap = lambda h, a=a, j=j, d=d: h * np.sqrt(L[j] @ L[j] + 4.0 * h * (a + h)) - d * (a + 2.0 * h)  # noqa: E731
        lo, hi = max(-a, 0.0) + 1e-9 * d, 2.0 * (d + np.linalg.norm(L[j]))  # (h > 0 and n . L + h > 0)
        if np.isfinite(n).all() and d > np.linalg.norm(L[j]) and gap(lo) < 0.0 < gap(hi):
            out[j] = _specular_points(camera, rig, n, np.array([brentq(gap, lo, hi, xtol=1e-12)]))[0, j]
    return out


def _specular_points(camera, rig, normal, h: np.ndarray) -> np.ndarray:
    """:func:`guide_specular_points` at each distance of ``h`` (M,): (M, J, 2)."""
    n = np.asarray(normal, dtype=np.float64)
    L = np.asarray(rig.positions, dtype=np.float64).reshape(-1, 3)
    h = np.asarray(h, dtype=np.float64)[:, None]
    c = L @ n + h  # (M, J)
    Lm = L - 2.0 * c[..., None] * n
    with np.errstate(divide="ignore", invalid="ignore"):
        X = Lm * (h / -(Lm @ n))[..., None]
    X[~(c > 0)] = np.nan
    rays = (X / np.linalg.norm(X, axis=-1, keepdims=True)).reshape(-1, 3)
    return np.asarray(_model(camera).ray_to_pixel(rays), dtype=np.float64).reshape(len(h), -1, 2)


def _model(camera):
    """``camera`` as a camera model: itself, or the pinhole of intrinsics K (3, 3)."""
    return camera if hasattr(camera, "pixel_to_ray") else PinholeCamera(np.asarray(camera, np.float64))


def other_lobe_centres(gray: np.ndarray, expected, ellipses, own_level, lit_level) -> list[list[tuple[float, float]]]:
    """Per candidate, the other guide's lobe centre (u, v) px on its curve ``expected[k]``, or none:
    around the brightest pixel of ``gray`` there outside the own lobe (``ellipses[k]`` scaled by
    ``own_level[k]``), kept where at least ``lit_level[k]``, the middle of the curve's pixels above
    half the way from that level to it.
    """
    h, w = gray.shape
    out: list = []
    for k, pts in enumerate(expected):
        ell, q = ellipses[k], np.unique(np.rint(pts).astype(np.int64), axis=0) if len(pts) else None
        if ell is None or q is None:
            out.append([])
            continue
        q = q[(q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)]
        q = q[ellipse_level(ell, q[:, 0], q[:, 1]) > own_level[k]]
        vals = gray[tuple(uv_to_rc(q).astype(np.int64).T)].astype(np.float64)
        b = int(np.argmax(vals)) if len(q) else -1
        if b < 0 or not vals[b] >= lit_level[k]:
            out.append([])
            continue
        near = np.linalg.norm(q - q[b], axis=1) <= np.sqrt(own_level[k]) * ell.semi_axes[0]
        top = q[near & (vals >= 0.5 * (vals[b] + lit_level[k]))]
        out.append([(float(top[:, 0].mean()), float(top[:, 1].mean()))])
    return out
