"""A rig's lobes fused into one highlight: the normal bisecting the camera and the centroid light.

Lobes of one shape at the lights' specular points p_j with amplitudes a_j (A = sum a_j) fuse
into one lobe peaking at m = sum a_j p_j / A plus ``y = -sum_j a_j |e_j|^2 e_j / (2 A s^2)``
(e_j = p_j - m; Gaussian lobes of sigma s). m is the specular point of the centroid light
C = sum a_j L_j / A to second order, so the normal at the BP bisects the directions to the camera
and to C.

Its sigma: the largest angle between the normal at the depth used and at the ends of its range
(a fit's depth +- its 1-sigma, its ``depth_range_mm``, else :data:`~simtest.decisions.PAIR_DEPTH_MIN_MM`
to ``PAIR_DEPTH_MAX_MM``), plus the angle the BP's ray turns through when moved by the fusion bias
``m - c + y`` and the BP's own error (:data:`~simtest.decisions.BP_PLACE_SIGMA_PX` per axis).

One fused lobe: the predicted specular points lie in the highlight's bright region
(:data:`~simtest.decisions.FUSED_LOBE_LEVEL`), at most :data:`~simtest.decisions.FUSED_SEPARATION_MAX`
lobe sigmas apart (s from the region's width), and the centroid of the light above the region's
edge lies within a quarter of their separation of the BP (half for a BP at one light's lobe).
A region that holds another accepted highlight's BP is two lobes, not one.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from simtest._threads import one_thread_each
from simtest.decisions import (BP_PLACE_SIGMA_PX, FUSED_LOBE_LEVEL, FUSED_SEPARATION_MAX, LIGHT_AWARE_ROI_SCALE,
                               PAIR_DEPTH_MAX_MM, PAIR_DEPTH_MIN_MM, PAIR_TOL_PX)
from simtest.geometry.lights import Light, LightRig
from simtest.tolerances import TOL
from simtest.reconstruct.curved_lobes import curved_lobe_rows
from simtest.reconstruct.detect import default_full_scale
from simtest.reconstruct.detect_pixels import luma
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.light_fits import _offset_rig, _reach, fit_arguments, with_light_aware
from simtest.reconstruct.lightaware import LightAwareEstimate, bisector, reflection_offset_deg
from simtest.reconstruct.lightaware.model import _rays, _rig_arrays
from simtest.reconstruct.lone_lobes import lone_fit_rows, lone_lobe_rows, lone_rival
from simtest.reconstruct.verify import WEAK_TWIN, specular_colour_at
from simtest.reconstruct.recommend import LIGHT_AWARE, _angle_deg, bp_error_depth_mm, bp_ray_error_deg
from simtest.reconstruct.rig_pairs import estimate_wander_px
from simtest.reconstruct.rig_lobes import (SPLIT_STATUSES, _bright_region, _inside, fused_lobe_candidates,
                                           guide_specular_points, isophote_holds, partner_rows, shared_plane_rows,
                                           split_fused_lobes, splittable)

__all__ = ["centroid_normal", "fused_top_groups", "light_aware_with_rig", "rig_centroid"]


def centroid_normal(bp_uv, camera, rig: LightRig, depth_mm: float) -> np.ndarray:
    """The normal bisecting the directions to the camera and to the rig's centroid light (the
    lights weighted by the irradiance each gives there) at ``depth_mm`` along the BP's ray.

    Parameters
    ----------
    bp_uv : array_like of shape (2,)
        The BP (u, v), px.
    camera : array_like of shape (3, 3) or CameraModel
    rig : LightRig
    depth_mm : float
        Depth of the specular point along the BP's ray, mm (> 0).

    Returns
    -------
    ndarray of shape (3,)
        Unit normal facing the camera, camera frame.
    """
    X = depth_mm * _rays(camera, np.asarray(bp_uv, np.float64)[None])[0]
    a = _amplitudes(rig, X)
    c = a @ rig.positions / a.sum()
    return bisector(bp_uv, camera, LightRig((Light(tuple(c.tolist())),)), depth_mm).normal


def _amplitudes(rig: LightRig, X: np.ndarray) -> np.ndarray:
    """The irradiance each light gives at the point ``X`` (mm, camera frame), relative."""
    L, w, inv_sq, m = _rig_arrays(rig)
    r = np.linalg.norm(X - L, axis=1)
    return w * np.clip((X[2] - L[:, 2]) / r, 0.0, None) ** m / np.where(inv_sq, r * r, 1.0)


def _depth_span(fits: dict, nominal_depth_mm: float) -> tuple[float, float, float, float]:
    """``(depth, near, far, depth of the BP ray's error)``, mm (module docstring)."""
    for r in (fits.get(name) for name in LIGHT_AWARE):
        if r is not None and r.depth_mm is not None and r.depth_sigma_mm is not None:
            d, s = float(r.depth_mm), float(r.depth_sigma_mm)
            return d, max(d - s, 1e-3 * d), d + s, d
    for r in (fits.get(name) for name in LIGHT_AWARE):
        if r is not None and r.depth_range_mm is not None:
            near, far = (float(v) for v in r.depth_range_mm)
            return math.sqrt(near * far), near, far, bp_error_depth_mm(r, nominal_depth_mm)
    return nominal_depth_mm, PAIR_DEPTH_MIN_MM, PAIR_DEPTH_MAX_MM, nominal_depth_mm


def rig_centroid(image, estimates, camera, rig: LightRig | None, nominal_depth_mm: float = 20.0, *, gray=None) -> list:
    """The estimates with ``"rig_centroid"`` among the light-aware results of each fitted highlight that
    is one fused lobe of the rig's lights (module docstring).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
    estimates : sequence of SpecularityEstimate
        With their light-aware fits.
    camera : array_like of shape (3, 3) or CameraModel
    rig : LightRig or None
        The scope's lights (without two at different places: returned unchanged).
    nominal_depth_mm : float
    gray : ndarray of shape (H, W), optional
        The frame's luma when at hand.

    Returns
    -------
    list of SpecularityEstimate
        ``"rig_centroid"``: status ``depth_not_observable``, its normal (:func:`centroid_normal`),
        ``normal_sigma_deg`` and ``bp_ray_error_deg``.
    """
    if rig is None or not rig.has_separate_lights:
        return list(estimates)
    peaks = np.array([e.bp_px for e in estimates if e.ok], np.float64).reshape(-1, 2)  # the accepted BPs
    out = []  # the frame's luma, made for the first highlight with fits if not given (most frames have none)
    for est in estimates:
        gray = luma(np.asarray(image)) if gray is None and est.light_aware else gray
        r = _fused_lobe(gray, est, camera, rig, est.light_aware, nominal_depth_mm, peaks) if est.light_aware else None
        out.append(est if r is None else dataclasses.replace(est, light_aware={**est.light_aware, "rig_centroid": r}))
    return out


def _fused_lobe(gray, est, camera, rig: LightRig, fits: dict, nominal_depth_mm: float, peaks) -> LightAwareEstimate | None:
    """:func:`rig_centroid`'s estimate of one highlight, or None where not one fused lobe (``peaks``: accepted BPs)."""
    depth, near, far, at = _depth_span(fits, nominal_depth_mm)
    bp = np.asarray(est.bp_px, dtype=np.float64)
    ray = _rays(camera, bp[None])[0]
    n = centroid_normal(bp, camera, rig, depth)
    pts = guide_specular_points(camera, rig, n, -float(n @ (depth * ray)))
    region = _bright_region(gray, est)
    others = peaks[(peaks != bp).any(axis=1)]  # another accepted BP in the region: two lobes (module docstring)
    if region is None or not _inside(region, pts).all() or region[0].sum() < 3 or _inside(region, others).any():
        return None
    rr, cc = np.nonzero(region[0])  # the lobe's sigma from the region's width across (docstring)
    across = float(np.linalg.eigvalsh(np.cov(np.vstack([cc, rr]).astype(np.float64)))[0])
    s = 2.0 * math.sqrt(max(across, 1.0 / 12.0)) / math.sqrt(-2.0 * math.log(FUSED_LOBE_LEVEL))
    gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    i, j = np.unravel_index(int(np.argmax(gaps)), gaps.shape)
    apart = float(gaps[i, j])
    t = (pts[j] - pts[i]) / apart if apart > 0 else np.zeros(2)
    w = gray[rr + region[1], cc + region[2]].astype(np.float64)
    w -= w.min()  # the light above the region's edge (module docstring)
    centre = np.array([w @ cc, w @ rr]) / max(w.sum(), 1e-300) + (region[2], region[1])
    off = float((centre - bp) @ t)
    if apart > FUSED_SEPARATION_MAX * s or abs(off) > apart / 4.0:
        return None  # two lobes, or the BP at one light's lobe (the region off it by half the gap)
    a = _amplitudes(rig, depth * ray)
    e = pts - (m := a @ pts / a.sum())
    y = -(a * (e * e).sum(axis=1)) @ e / (2.0 * a.sum() * s * s)
    bias = _angle_deg(ray, _rays(camera, (m + y)[None])[0])  # the BP moved by m - c + y, c = the BP
    spread_deg = max(_angle_deg(n, centroid_normal(bp, camera, rig, d)) for d in (near, far))
    place = math.hypot(*(_angle_deg(ray, _rays(camera, (bp + step)[None])[0])
                         for step in np.eye(2) * BP_PLACE_SIGMA_PX))
    return LightAwareEstimate(
        "rig_centroid", "depth_not_observable",
        f"one fused lobe: specular points {apart:.3g} px apart, lobe sigma {s:.3g} px, centred {off:.2g} px "
        f"off the BP; depth {depth:.3g} mm ({near:.3g} to {far:.3g}: {spread_deg:.3g} deg), fusion bias "
        f"{bias:.3g} deg, BP {place:.3g} deg", n, normal_sigma_deg=spread_deg + bias + place,
        bp_ray_error_deg=bp_ray_error_deg(ray, at, rig))


def _obeys_reflection(est, camera, rig: LightRig):
    """``est`` with its ok plane fits' sigma raised by their normal's miss of the law of reflection at
    the BP (:func:`~simtest.reconstruct.lightaware.bisector.reflection_offset_deg`): a plane's error on
    a curved patch that its covariance does not see. A guide's row, its BP at its plane's specular
    point, misses by nothing."""
    if rig is None or not est.light_aware:
        return est
    fits, new = est.light_aware, {}
    for name in ("photometric_fit", "isocurve_fit"):
        r = fits.get(name)
        if r is None or r.status != "ok" or not r.distance_mm or r.normal_sigma_deg is None:
            continue
        off = reflection_offset_deg(est.bp_px, camera, rig, r.normal, r.distance_mm)
        if off > TOL.reflection_rounding_deg:  # (NaN: its plane does not meet the BP's ray; not ok then)
            new[name] = dataclasses.replace(r, normal_sigma_deg=r.normal_sigma_deg + off).noted(
                f"its normal {off:.2g} deg off the law of reflection at the BP")
    return dataclasses.replace(est, light_aware={**fits, **new}) if new else est


@one_thread_each()  # every step's BLAS on one thread, as in the fits' workers: the same bits on any machine
def light_aware_with_rig(image, estimates, camera, rig: LightRig | None, *, workers: int = 1, on_highlight=None,
                         **kwargs) -> list:
    """The light-aware step of one image or frame as ``simtest reconstruct`` runs it:
    :func:`~simtest.reconstruct.light_fits.with_light_aware`, then the rig's fused lobes split or
    given their centroid light's normal, then a curved patch's guide lobes fitted as one
    (:func:`~simtest.reconstruct.curved_lobes.curved_lobe_rows`), the ok plane fits' sigmas raised by
    their miss of the law of reflection at the BP (:func:`_obeys_reflection`), then an ok row left with the BP ray
    given the plane of a row that places both (:func:`~simtest.reconstruct.rig_lobes.shared_plane_rows`), an ok
    row's plane fit of a lone lobe told apart (:func:`~simtest.reconstruct.lone_lobes.lone_fit_rows`), then,
    where no row is ok, a weak lone lobe its plane fit confirms
    (:func:`~simtest.reconstruct.lone_lobes.lone_lobe_rows`); a list of SpecularityEstimate.
    """
    kwargs = fit_arguments(image, kwargs) if _offset_rig(rig) else kwargs  # made once for both steps
    # a weak twin is ok to the fits and the rig's rules, and stays so where its plane fit confirms the twin (its
    # row found again by its BP, which the steps below keep; a split, only where the luma dips between its
    # points, gives its rows their own BPs)
    weak_rows = {i for i, e in enumerate(estimates) if e.status == WEAK_TWIN}
    weak_bps = {tuple(estimates[i].bp_px) for i in weak_rows}
    estimates = [dataclasses.replace(e, status="ok") if e.status == WEAK_TWIN else e for e in estimates]
    # the frame's luma once for the three steps, where a highlight or a split may read it
    gray = luma(np.asarray(image)) if _offset_rig(rig) and any(e.status in SPLIT_STATUSES for e in estimates) else None
    split = []  # the rejected candidates of fused lobes, fitted in the workers
    if gray is not None:
        # two guides' lobes are the illuminant's light: a candidate of the tissue's colour is no pair (a top
        # clipped in every channel is white whatever the colour at its BP; a pale not_specular one needs only the
        # white share, its tops along the rig's curve standing for a twin). The colour first, the cheaper check
        maybe = [i for i, e in enumerate(estimates) if splittable(e, gray) and not e.ok]
        white = specular_colour_at(np.asarray(image), [estimates[i].bp_px for i in maybe],
                                   full_scale=default_full_scale(np.asarray(image)), response=kwargs.get("response"),
                                   white_only=[estimates[i].status == "not_specular" for i in maybe])
        split = fused_lobe_candidates(gray, estimates, camera, rig,
                                      among={i for i, w in zip(maybe, white) if w or estimates[i].saturated})
    deferred = fused_top_groups(gray, estimates, split, kwargs.get("roi_scale", LIGHT_AWARE_ROI_SCALE)) if split else {}
    fitted = with_light_aware(image, estimates, camera, rig, workers=workers, on_highlight=on_highlight,
                              plane_only=split, deferred=deferred, weak=weak_rows, **kwargs)
    prefitted = {i for i in split if fitted[i].light_aware}  # (a deferred piece its top's fit spared has none)
    split_rows = split_fused_lobes(image, fitted, camera, rig, prefitted=prefitted, gray=gray, weak=weak_rows,
                                   rival=lambda est, fit: lone_rival(image, est, fit, camera, rig, kwargs, gray))
    out = rig_centroid(image, partner_rows(image, split_rows, camera, rig, kwargs, gray=gray), camera, rig, gray=gray)
    out = curved_lobe_rows(image, out, camera, rig, kwargs, gray=gray)
    out = shared_plane_rows([_obeys_reflection(e, camera, rig) for e in out], camera, rig)
    weak = [k for k, e in enumerate(out) if e.ok and tuple(e.bp_px) in weak_bps]
    if weak:
        bps = np.array([e.bp_px for e in out], np.float64)
        reach = PAIR_TOL_PX + np.array([estimate_wander_px(e) for e in out])
        for k in weak:
            yes = _twin_confirmed(out, k, bps, reach, camera, rig)
            why = ("which its plane fit confirms" if yes == "photometric_fit" else
                   "which the plane that places both confirms (rig_pair)" if yes else
                   "which its plane fit does not confirm (no plane with its depth puts a guide's highlight on its BP "
                   "and another's on another highlight)")
            out[k] = dataclasses.replace(out[k], status="ok" if yes else "not_specular",
                                         detail=f"{out[k].detail}, {why}")
    out = lone_fit_rows(image, out, camera, rig, kwargs, gray=gray)
    return lone_lobe_rows(image, out, camera, rig, kwargs, gray=gray,
                          refused={k for k, e in enumerate(out) if e.bp_px is not None and tuple(e.bp_px) in weak_bps})


def fused_top_groups(gray, estimates: list, rows, roi_scale: float = LIGHT_AWARE_ROI_SCALE) -> dict[int, int]:
    """Of the clipped ``rows`` of ``estimates`` (rejected candidates to be split, :func:`fused_lobe_candidates`), each
    one another covers, mapped to that one: fitted only where that one's fit fails (``deferred`` of
    :func:`~simtest.reconstruct.light_fits.with_light_aware`). A clipped top holds no image of its own, so the maxima
    noise leaves on it are one peak, not many, and a joint plane fit of one piece models the lobes any other's would.
    A piece covers another whose BP lies in its bright region (:func:`~simtest.reconstruct.rig_lobes._bright_region`)
    and whose fit's window (``roi_scale`` times its ROI's half-size about its BP) lies in its own: its fit sees every
    pixel the other's would. The pieces covering the most others come first (ties: the detector's order); a piece no
    first one covers is fitted too.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        The frame's luma.
    estimates : list of SpecularityEstimate
        The frame's candidates.
    rows : sequence of int
        The indexes of the candidates to be split.
    roi_scale : float
        The fits' ROI growth (:data:`~simtest.decisions.LIGHT_AWARE_ROI_SCALE`).

    Returns
    -------
    dict of int to int
        Each deferred piece's index, mapped to its top's first piece.
    """
    clipped = [i for i in rows if estimates[i].saturated and estimates[i].bp_px is not None]
    bps = np.array([estimates[i].bp_px for i in clipped], np.float64).reshape(-1, 2)
    rois = np.array([tuple(Roi.around(estimates[i].bp_px, _reach(estimates[i], roi_scale), gray.shape))
                     for i in clipped], np.int64).reshape(-1, 4)  # the fits' windows: row0, row1, col0, col1
    holds = {}
    for k, i in enumerate(clipped):
        region = _bright_region(gray, estimates[i])
        within = (rois[:, [0, 2]] >= rois[k, [0, 2]]).all(axis=1) & (rois[:, [1, 3]] <= rois[k, [1, 3]]).all(axis=1)
        holds[i] = set() if region is None else {j for j, yes in zip(clipped, _inside(region, bps) & within)
                                                 if yes and j != i}
    deferred: dict[int, int] = {}
    firsts: set[int] = set()  # the pieces others wait on
    for i in sorted(clipped, key=lambda i: (-len(holds[i]), i)):
        if i in deferred:
            continue
        for j in sorted(holds[i] - firsts - deferred.keys()):
            deferred[j] = i
            firsts.add(i)
    return deferred


def _twin_confirmed(rows: list, k: int, bps: np.ndarray, reach: np.ndarray, camera, rig) -> str:
    """The name of the fit that confirms a weak twin, "" where none does: a plane fit of ``rows[k]`` (its BP row
    ``k`` of ``bps``), ok with its distance, that puts one guide's specular point on its own row and another guide's
    on another row: within ``reach`` of the row's BP or inside its closed primary isophote (``reach``:
    :data:`~simtest.decisions.PAIR_TOL_PX` plus each BP's wander). The twin that let a weak peak pass is a claim on
    the rig's geometry, which only such a fit checks (a bump on a lobe's broad shoulder, or a pale spot of texture,
    can have a twin too). Inside the isophote counts, the row's own too (:func:`~simtest.reconstruct.rig_lobes.
    isophote_holds`). The plane may be the row's own fit's or its ``rig_pair``'s, another row's fit that places both
    (:func:`~simtest.reconstruct.rig_lobes.shared_plane_rows`): one plane, whichever lobe it was fitted on."""
    fits = [f for name in ("photometric_fit", "rig_pair") if (f := (rows[k].light_aware or {}).get(name)) is not None
            and f.ok and f.distance_mm is not None]
    for fit in fits:
        points = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
        near = np.linalg.norm(points[:, None] - bps[None], axis=-1) <= reach[None]  # (guides, rows)
        for r, e in enumerate(rows):
            near[:, r] |= isophote_holds(e, points)
        own, other = near[:, k], np.delete(near, k, axis=1).any(axis=1)
        if (own[:, None] & other[None, :] & ~np.eye(len(own), dtype=bool)).any():
            return fit.estimator
    return ""
