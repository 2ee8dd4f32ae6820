"""A guide's weak lobe alone in the frame: the last step of a frame under a rig of separate guides.

A white peak of significant height that only the paleness or contrast bar refuses passes where another
guide's highlight lies where the rig puts it (a rig twin, :data:`~simtest.reconstruct.verify.WEAK_TWIN`).
On a tilted plane the other guide's specular point often falls outside the frame, and a weak lobe then has
no twin to show. Where a frame under the rig ends with no accepted highlight, its brightest such peaks (at
most one per light place: a smooth patch shows no more lobes) get a plane fit over the fits' window grown
once (:data:`~simtest.decisions.ROI_GROWTH_FACTOR`), as a weak lobe's isophote, cut by its ROI, grows it.
The fit confirms the lobe where it is ok with its distance, puts one guide's specular point on the peak
(:data:`~simtest.decisions.PAIR_TOL_PX` plus the BP's wander, or in its bright region) and every other
guide's outside the frame: the rig's geometry then explains both what the frame shows and what it does not.
One lobe alone hardly tells which guide lit it: the swapped hypothesis (another guide lit the BP, at any depth
of the depth of field) must be refuted by the image too, no lobe rising where it puts the fit's own guide's
(:func:`_swap_seen`). The row becomes ``ok`` with that fit. Where the frame could show none of the swapped
hypotheses' lobes (each off the frame or within the lobe's own tails), the fit must refute them: started from
another guide's bisector planes alone, it must not settle on an ok plane that confirms a lone lobe of that
guide (:func:`_guide_resolved`). Else each guide's plane fits the lobe, and the fit's sigma counts the guides'
spread (:func:`~simtest.reconstruct.recommend.with_guide_spread`): the BP ray is kept.

An ok row whose recommended plane fit reads its lobe as such a lone lobe (:func:`lone_fit_rows`) is told apart
the same way, and keeps the BP ray where its guide is not.

Where the frame's edge cuts a region split into two guides' fused lobes, the joint fit may have settled on a far
plane that puts both points in it while one guide's lobe alone, its twin beyond the edge, fits better
(:func:`lone_rival`; :func:`~simtest.reconstruct.rig_lobes.split_fused_lobes` then gives that guide's row), its
guide told apart as above.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.decisions import GUIDE_SEEN_REL, LIGHT_AWARE_ROI_SCALE, PAIR_TOL_PX, ROI_GROWTH_FACTOR
from simtest.geometry.angles import unit
from simtest.geometry.lights import LightRig
from simtest.reconstruct.detect import default_full_scale
from simtest.reconstruct.detect_pixels import luma, noise_sigma
from simtest.reconstruct.light_fits import (PLANE_ONLY, _fit_intensities, _reach, _rise,
                                            light_aware_estimates, nearest_guide)
from simtest.reconstruct.lightaware.model import plane_rig_intensity
from simtest.reconstruct.lightaware.plane import RETRY_START_DEPTHS, FitSettings
from simtest.reconstruct.lightaware.plane_solve import start_depths
from simtest.reconstruct.lightaware.solve import _bisector_plane
from simtest.reconstruct.recommend import with_guide_spread
from simtest.reconstruct.rig_lobes import _bright_region, _inside
from simtest.reconstruct.rig_pairs import (_dense_curve, _guide_pairs, _in_frame, estimate_wander_px,
                                           guide_specular_points)
from simtest.reconstruct.verify import weak_white_peaks

__all__ = ["lone_lobe_rows", "lone_fit_rows", "lone_rival"]


def lone_lobe_rows(image, estimates: list, camera, rig: LightRig | None, fit_kwargs: dict, *, gray=None,
                   refused=()) -> list:
    """The estimates with each weak lone lobe its plane fit confirms made ``ok`` (module docstring).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The frame.
    estimates : list of SpecularityEstimate
        After every other step of the rig (:func:`~simtest.reconstruct.rig_centroid.light_aware_with_rig`).
    camera : CameraModel
        The camera (``pixel_to_ray``, ``ray_to_pixel``).
    rig : LightRig or None
        The scope's lights, camera frame, mm (without separate guides: returned unchanged).
    fit_kwargs : dict
        The light-aware fits' arguments (:func:`~simtest.reconstruct.light_fits.fit_arguments`' result).
    gray : ndarray of shape (H, W), optional
        The frame's luma where at hand.
    refused : collection of int
        Rows not to try (weak twins whose fit did not confirm them).

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``; a confirmed row ``ok`` with its ``photometric_fit`` alone.
    """
    if rig is None or not rig.has_separate_lights or any(e.ok for e in estimates):
        return estimates
    rows = [k for k, e in enumerate(estimates) if e.status == "not_specular" and k not in refused
            and e.bp_px is not None and np.isfinite(e.bp_px).all()]
    if not rows:
        return estimates
    img = np.asarray(image)
    gray = luma(img) if gray is None else gray
    weak = weak_white_peaks(img, gray, np.array([estimates[k].bp_px for k in rows], np.float64),
                            np.array([estimates[k].saturated for k in rows], bool),
                            full_scale=default_full_scale(img), noise=noise_sigma(gray),
                            grey=img.ndim == 2, response=fit_kwargs.get("response"))
    tries = sorted((k for k, w in zip(rows, weak) if w), key=lambda k: -float(estimates[k].bp_intensity))
    out = list(estimates)
    values, clip = _fit_intensities(img, fit_kwargs.get("response"), fit_kwargs.get("linear"),
                                    fit_kwargs.get("saturation_level"))[:2]
    wide = {"roi_scale": ROI_GROWTH_FACTOR * fit_kwargs.get("roi_scale", LIGHT_AWARE_ROI_SCALE)}
    for k in tries[:rig.light_places]:
        fit = light_aware_estimates(image, out[k], camera, rig, **(fit_kwargs | PLANE_ONLY | wide))
        fit = fit.get("photometric_fit")
        if not _confirms(fit, out[k], camera, rig, gray):
            continue
        fit, why = _told_apart(image, out[k], fit, camera, rig, fit_kwargs | wide, gray, values, clip)
        if fit is None:
            continue
        out[k] = dataclasses.replace(
            out[k], status="ok", light_aware={"photometric_fit": fit},
            detail=f"{out[k].detail}; a lone lobe: its plane fit puts its guide's specular point on its BP and "
                   f"every other guide's outside the frame, and {why}")
    return out


def lone_fit_rows(image, estimates: list, camera, rig: LightRig | None, fit_kwargs: dict, *, gray=None) -> list:
    """The estimates with each ok row whose recommended normal is a plane fit of a lone lobe told apart.

    A row qualifies where its ``photometric_fit`` is recommended, holds its distance and confirms a lone lobe
    (:func:`_confirms`: one guide's specular point on the row's peak, every other guide's outside the frame).
    Where the image shows another guide lit it, or another guide's plane fits it too (:func:`_told_apart`), the
    fit counts the guides' spread in its sigma (:func:`~simtest.reconstruct.recommend.with_guide_spread`) and the
    recommendation keeps the BP ray. Where another guide's plane fits it too, every hypothesis reads the lobe as
    one guide's alone, so its ``rig_centroid`` (a fused lobe's normal) is dropped too. Arguments as
    :func:`lone_lobe_rows`'; returns a list in their order.
    """
    if rig is None or not rig.has_separate_lights:
        return estimates
    todo = [k for k, e in enumerate(estimates) if e.ok and e.recommended.normal_from == "photometric_fit"
            and e.light_aware["photometric_fit"].distance_mm is not None
            and e.light_aware["photometric_fit"].guide_spread_deg is None]
    if not todo:
        return estimates
    img = np.asarray(image)
    gray = luma(img) if gray is None else gray
    values, clip = _fit_intensities(img, fit_kwargs.get("response"), fit_kwargs.get("linear"),
                                    fit_kwargs.get("saturation_level"))[:2]
    out = list(estimates)
    for k in todo:
        fit = out[k].light_aware["photometric_fit"]
        if not _confirms(fit, out[k], camera, rig, gray):
            continue
        told, why = _told_apart(image, out[k], fit, camera, rig, fit_kwargs, gray, values, clip)
        if told is fit:
            continue
        told = _with_spread(fit, out[k], camera, rig) if told is None else told
        fits = dict(out[k].light_aware, photometric_fit=told)
        if why:  # each guide's plane reads the lobe as that guide's alone: no fused lobe for the centroid light
            fits.pop("rig_centroid", None)
        out[k] = dataclasses.replace(out[k], light_aware=fits, detail=f"{out[k].detail}; its lobe alone in the "
                                     f"frame: {why or 'the image shows another guide lit it'}")
    return out


def _told_apart(image, est, fit, camera, rig: LightRig, fit_kwargs: dict, gray, values=None, clip=None):
    """``(fit, why)``: a lone lobe's confirmed ``fit`` as released, and which image evidence tells its guide
    (module docstring); ``(None, "")`` where the image shows another guide lit it. ``values``, ``clip``: the
    values the fits read and their clip level (None: read from ``image`` and ``fit_kwargs``)."""
    if values is None:
        values, clip = _fit_intensities(np.asarray(image), fit_kwargs.get("response"), fit_kwargs.get("linear"),
                                        fit_kwargs.get("saturation_level"))[:2]
    seen = _swap_seen(fit, est, camera, rig, values, clip)
    if seen:
        return None, ""
    if seen is False:
        return fit, "no other guide lit it"
    if _guide_resolved(image, est, fit, camera, rig, fit_kwargs, gray):
        return fit, "no other guide's plane fits it"
    return _with_spread(fit, est, camera, rig), "another guide's plane fits it too"


def _with_spread(fit, est, camera, rig: LightRig):
    """``fit`` with the guides' spread at its distance along ``est``'s BP ray in its sigma, which guide lit the
    lobe unresolved (:func:`~simtest.reconstruct.recommend.with_guide_spread`)."""
    ray = unit(camera.pixel_to_ray(np.asarray(est.bp_px, np.float64)[None])[0])
    return with_guide_spread(fit, ray, fit.distance_mm, rig, unresolved=True)


def _guide_resolved(image, est, fit, camera, rig: LightRig, fit_kwargs: dict, gray) -> bool:
    """Whether no other guide's hypothesis fits ``est``'s lobe: the plane fit (on ``fit``'s lobe) started from
    each other guide's bisector planes along the BP's ray alone (the retry's depths) is not ok, or confirms no
    lone lobe of that guide (:func:`_confirms`)."""
    bp = np.asarray(est.bp_px, np.float64)
    own = nearest_guide(guide_specular_points(camera, rig, fit.normal, fit.distance_mm), bp)
    depths = start_depths(FitSettings.nominal_depth_mm, RETRY_START_DEPTHS)
    for i in range(len(rig.positions)):
        if i == own:
            continue
        starts = {"lobe": fit.lobe, "guide_starts": tuple((i, float(d)) for d in depths)}
        alt = light_aware_estimates(image, est, camera, rig, **(fit_kwargs | PLANE_ONLY | starts))
        alt = alt.get("photometric_fit")
        if _confirms(alt, est, camera, rig, gray) and nearest_guide(
                guide_specular_points(camera, rig, alt.normal, alt.distance_mm), bp) == i:
            return False
    return True


def lone_rival(image, est, fit, camera, rig: LightRig, fit_kwargs: dict, gray: np.ndarray):
    """A lone-lobe plane fit of ``est``'s region that fits it better than its joint fit ``fit``, or None.

    The region is refitted (plane only) from the plane fit's retry starts (:data:`~simtest.reconstruct.lightaware.
    plane.RETRY_START_DEPTHS` depths, 1/8 to 8 times the nominal); a refit counts where :func:`_confirms` reads a
    lone lobe in it and, on ``fit``'s lobe and projection, it leaves a lower residual RMS and holds the normal at
    least as surely (its sigma at most ``fit``'s): the same model's better minimum. A lower residual with a looser
    normal is the model bending to what it does not describe (a lobe as broad as the shading on a near plane).
    ``image``, ``camera``, ``rig``, ``fit_kwargs``, ``gray``: as :func:`lone_lobe_rows`' (``gray`` given). Returns
    the LightAwareEstimate of least residual RMS among those, its guide told apart as a lone lobe's (module
    docstring; None where the image shows another guide lit it).
    """
    if fit is None or not fit.ok or fit.residual_rms is None:
        return None
    best = None
    ray = unit(camera.pixel_to_ray(np.asarray(est.bp_px, np.float64)[None])[0])
    for depth in start_depths(FitSettings.nominal_depth_mm, RETRY_START_DEPTHS):
        if not _lone_start(ray, float(depth), camera, rig, gray.shape):
            continue
        alt = light_aware_estimates(image, est, camera, rig,
                                    **(fit_kwargs | PLANE_ONLY | {"nominal_depth_mm": float(depth), "lobe": fit.lobe}))
        alt = alt.get("photometric_fit")
        if (alt is not None and alt.projection == fit.projection and alt.residual_rms is not None
                and alt.residual_rms < (fit.residual_rms if best is None else best.residual_rms)
                and _as_sure(alt, fit) and _confirms(alt, est, camera, rig, gray)):
            best = alt
    return None if best is None else _told_apart(image, est, best, camera, rig, fit_kwargs, gray)[0]


def _lone_start(ray, depth_mm: float, camera, rig: LightRig, shape) -> bool:
    """Whether some guide's bisector plane at ``depth_mm`` along the BP's ``ray`` puts every other guide's
    specular point outside a frame of ``shape``: a start of the lone-lobe hypothesis."""
    for j, L in enumerate(np.asarray(rig.positions, np.float64)):
        pts = guide_specular_points(camera, rig, *_bisector_plane(ray, L, depth_mm))
        if not _in_frame(np.delete(pts, j, axis=0), shape).any():
            return True
    return False


def _as_sure(alt, fit) -> bool:
    """Whether ``alt``'s normal sigma is known and at most ``fit``'s."""
    return alt.normal_sigma_deg is not None and fit.normal_sigma_deg is not None and (
        alt.normal_sigma_deg <= fit.normal_sigma_deg)


def _confirms(fit, est, camera, rig: LightRig, gray: np.ndarray) -> bool:
    """Whether ``fit`` (ok, with its distance) puts one guide's specular point on ``est``'s peak (within
    PAIR_TOL_PX plus its wander of the BP, or in its bright region: :data:`~simtest.decisions.FUSED_LOBE_LEVEL`)
    and every other guide's outside the frame of ``gray``."""
    if fit is None or not fit.ok or fit.distance_mm is None:
        return False
    pts = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
    near = np.nan_to_num(np.linalg.norm(pts - np.asarray(est.bp_px, np.float64), axis=1), nan=np.inf)
    own = near <= PAIR_TOL_PX + estimate_wander_px(est)
    if (region := _bright_region(gray, est)) is not None:
        own |= _inside(region, pts)
    if own.sum() != 1:
        return False
    others = pts[~own]
    inside = (others >= 0).all(axis=1) & (others[:, 0] <= gray.shape[1] - 1) & (others[:, 1] <= gray.shape[0] - 1)
    return not inside.any()  # (NaN: the plane images no point of that guide; compares False, so outside)


def _swap_seen(fit, est, camera, rig: LightRig, values: np.ndarray, clip) -> bool | None:
    """Whether the image holds up the swapped hypothesis of a lone lobe's fit: another guide ``i`` lit the BP (the
    plane of ``i``'s bisector at a depth of the rig's curves, :mod:`~simtest.reconstruct.rig_pairs`), and the fit's
    own guide or another shows a lobe predicted at least GUIDE_SEEN_REL as high (the fit's roughness) beyond the own
    lobe's tails (LIGHT_AWARE_ROI_SCALE times its half-size, plus PAIR_TOL_PX): measured as ``light_fits._unseen_guide``
    measures a fit's own prediction, on the values the fits read (``values``, clip level ``clip``, None without).
    None where the frame could show no such lobe (nothing tested)."""
    bp = np.asarray(est.bp_px, np.float64)
    pts = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
    own = nearest_guide(pts, bp)
    ray = unit(camera.pixel_to_ray(bp[None])[0])
    L = np.asarray(rig.positions, np.float64)
    ring = _reach(est, 1.0)
    height = _rise(values, bp, ring)[0]
    tested = False
    for i, j in _guide_pairs(L):
        if i == own:
            continue
        depths, uv = _dense_curve(camera, L[i], L[j], ray, values.shape, PAIR_TOL_PX)  # (no lobe between samples)
        use = np.flatnonzero(_in_frame(uv, values.shape)
                             & (np.abs(uv - bp).max(axis=1) > LIGHT_AWARE_ROI_SCALE * ring + PAIR_TOL_PX))
        for d, p in zip(depths[use], uv[use]):
            spec = plane_rig_intensity(unit(camera.pixel_to_ray(np.stack([bp, p])), -1),
                                       *_bisector_plane(ray, L[i], d), rig, fit.roughness)
            if not spec[0] > 0 or spec[1] / spec[0] < GUIDE_SEEN_REL:
                continue
            tested = True
            rise, peak = _rise(values, p, ring)
            if rise >= GUIDE_SEEN_REL * spec[1] / spec[0] * height or (clip is not None and peak >= clip):
                return True
    return False if tested else None
