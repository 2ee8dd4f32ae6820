"""The light-aware fits run on detected highlights, given the scope's light rig (:func:`with_light_aware`),
attached to each estimate (``light_aware``) for :func:`~simtest.reconstruct.recommend.recommend`.

:func:`isocurve_fit` takes its own isophotes, at :data:`ISOCURVE_ISOVALUES` of the BP's height above
the median of the grown ROI's border, not the command line's isovalues (whose contours near the
peak say little about the distance).
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import as_completed

import numpy as np

from simtest._lazy import require
from simtest._threads import one_thread_each
from simtest._workers import worker_pool
from simtest.decisions import (BROAD_LOBE_PHONG_N, CLIP_MARGIN, CLIP_NOISE_FROM_REL, GUIDE_SEEN_REL, ISOCURVE_ISOVALUES,
                               LIGHT_AWARE_ROI_SCALE, LOBE_EDGE_REL, LOBE_ROI_MISMATCH, PAIR_TOL_PX, SIGMA_MARGIN,
                               SIGNIFICANCE_MIN)
from simtest.geometry.lights import LightRig
from simtest.reconstruct import lightaware as _la
from simtest.reconstruct._pixels import Roi, border_ring
from simtest.reconstruct.detect import default_full_scale, luma, noise_sigma
from simtest.reconstruct.detect_pixels import frame_ceiling, noise_sigma_of_differences, second_differences
from simtest.reconstruct.isophote import extract_isophote
from simtest.reconstruct.jpeg import jpeg_grid
from simtest.reconstruct.lightaware import (LightAwareEstimate, cubic_patch_fit, isocurve_fit, photometric_fit,
                                            quadric_fit, refine_isophote_points)
from simtest.reconstruct.verify import specular_colour_at
from simtest.reconstruct.recommend import (_bp_ray_error_beside, bp_error_depth_mm, bp_ray_error_deg,
                                           depth_within_ceiling, with_guide_spread)
from simtest.reconstruct.rig_pairs import (_in_frame, estimate_wander_px, guide_specular_points, pair_misfit_px,
                                           pair_partners, pair_starts)

#: The photometric fit's statuses after which the curved-patch fits run by default (the plane is
#: not the ROI's surface; docs/decisions/light-aware-recommendation.md).
CURVED_FIT_AFTER, QUADRIC_AFTER = ("plane_misfit", "not_converged"), ("plane_misfit",)
#: Candidate statuses never fitted, not even with ``fit_rejected``: too small to fit, or no
#: specular highlight of the tissue (:mod:`simtest.reconstruct.verify`).
NOT_FITTED = ("too_small", "black_border", "overlay", "not_specular")
#: The light-aware arguments of a rejected candidate fitted for its fused lobes: the plane's fit
#: only (:mod:`simtest.reconstruct.rig_lobes` reads its normal and distance; a patch's take seconds).
PLANE_ONLY = {"quadric": False, "cubic": False}


def _offset_rig(rig) -> bool:
    return rig is not None and not rig.is_colocated


def light_aware_estimates(image, est, camera, rig: LightRig, *, nominal_depth_mm: float = 20.0,
                          saturation_level: float | None = None, roi_scale: float = LIGHT_AWARE_ROI_SCALE,
                          quadric_roi_scale: float = 1.5, supersample: int = 1, quadric: bool | None = None,
                          cubic: bool | None = False, response=None, diffuse: bool | None = None,
                          lobe: str | None = None, linear=None, colour: bool | None = None,
                          floor_refit: bool = False, pair_starts=(), lobe_partners=(),
                          guide_starts=()) -> dict[str, LightAwareEstimate]:
    """Run the light-aware estimators on one detected highlight.

    ``isocurve_fit`` takes its own isophotes (module docstring); ``photometric_fit`` the ROI grown
    ``roi_scale`` times about the BP, clipped pixels left out, started from the bisector at the
    nominal depth and from the isocurve fit's normal, the better kept, and refitted on the ROI its
    lobe spans where the grown ROI cuts it (:func:`_lobe_roi`).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The image the highlight was detected in.
    est : SpecularityEstimate
    camera : array_like of shape (3, 3) or CameraModel
    rig : LightRig
    nominal_depth_mm : float
        Depth assumed for the fits' start, mm.
    saturation_level : float, optional
        Clip level (default: an integer dtype's maximum, none for floats; with_light_aware: frame_ceiling's).
    roi_scale, quadric_roi_scale : float
        Growth of the highlight's ROI for the photometric fit, and for the curved-patch fits.
    supersample : int
        Sub-pixel samples per pixel side of the photometric model.
    quadric : bool or None
        Run :func:`~simtest.reconstruct.lightaware.quadric_fit`: True always, False never, None when
        the photometric fit's status is in :data:`QUADRIC_AFTER`.
    cubic : bool or None
        Run :func:`~simtest.reconstruct.lightaware.cubic_patch_fit` on the quadric's ROI: True always,
        False (default) never, None as the quadric where the rig has two lights at different places.
    response : SensorResponse, optional
        The sensor response: the fits run on the linear intensities of the channel where the tissue
        is darkest, clipped pixels censored, with the rig's diffuse shading.
    diffuse : bool or None
        The rig's Lambertian shading in the photometric model (None: with a ``response``).
    lobe : {"phong", "ggx", "blinn", "auto"} or None
        The photometric fit's lobe (``"auto"``: GGX where Phong's fit leaves a curved pattern or, on three channels,
        fails; Blinn where GGX's leaves one too); None: "auto", on one channel with GGX beside a broad Phong lobe.
    floor_refit : bool
        Refit without the pixels whose model lies within a few noise sigmas of an integer image's 0.
    pair_starts : tuple of (int, int, float)
        Guides and depth at which the rig puts another guide's highlight on another highlight
        (:func:`~simtest.reconstruct.rig_pairs.pair_starts`): a fit with a normal (ok, or without the depth,
        which the pair may give) that misplaces it, or one that ran off (``_RAN_OFF``: on its ROI alone), is
        refitted from there too, then on the ROI that holds both highlights (:func:`_pair_roi`), a refit kept
        where it is ok and places it (none where the ROI holds as many ``lobe_partners`` as the rig has light
        places: a glint field); a fit (a depth-less one at the pair's depth) still off the partner by more
        than the lobe's size becomes ``guide_misfit`` (one guide's lobe alone hardly tells which guide lit
        it), as does any plane fit that puts another guide's lobe in the frame where the image shows none
        (:func:`_unseen_guide`).
    guide_starts : sequence of (int, float)
        Where given, the plane fit's only starts: guide i's bisector plane at depth d mm along the BP's
        ray, for each (i, d) (one guide's hypothesis of a lone lobe: :mod:`~simtest.reconstruct.lone_lobes`).
    lobe_partners : sequence of (float, float)
        BPs (u, v), px, of the other candidates whose ROI meets the grown one (:func:`with_light_aware`).
        Under separate lights they may be the other guides' lobes of one curved patch: a quadric fit that
        fails on its own ROI is fitted again on the ROI that holds them too.
    colour : bool, optional
        Fit on the ROI's three linear channels, the body colours projected out (None:
        :func:`colour_fit_applies`).
    linear : tuple, optional
        ``response.linearize(image)`` when at hand.

    Returns
    -------
    dict
        ``"photometric_fit"``; ``"isocurve_fit"`` where an isophote closes in the grown ROI;
        ``"quadric_fit"``, ``"cubic_patch_fit"`` as ``quadric`` and ``cubic`` say; each with its
        depth within the ceiling and ``bp_ray_error_deg`` set.
    """
    img = np.asarray(image)
    gray, saturation_level, censor, floor, floor_step = _fit_intensities(img, response, linear, saturation_level)
    diffuse = response is not None if diffuse is None else diffuse
    out: dict[str, LightAwareEstimate] = {}
    big = Roi.around(est.bp_px, _reach(est, roi_scale), img.shape)
    start_n = None
    pts, ts = _isocurve_isophotes(gray, big, est.bp_px, refine=len(rig.lights) == 1)  # (isocurve_fit: one light)
    if pts:
        out["isocurve_fit"] = iso = _guarded("isocurve_fit", isocurve_fit, pts, ts, est.bp_px, camera, rig,
                                             nominal_depth_mm=nominal_depth_mm)
        start_n = iso.normal if iso.has_normal else None
    colour = colour_fit_applies(img, response) if colour is None else colour
    lobe = "auto" if lobe is None else lobe
    pkw = dict(nominal_depth_mm=nominal_depth_mm, start_normal=start_n, supersample=supersample, diffuse=diffuse,
               censor=censor, lobe=lobe, floor_level=floor, floor_refit=floor_refit, floor_step=floor_step,
               guide_starts=tuple((int(i), float(d)) for i, d in guide_starts))
    pf = _photometric(img, gray, big, est, camera, rig, response, colour, saturation_level, pkw)
    lobe_roi = _lobe_roi(pf, est.bp_px, camera, rig, img.shape, big)
    if lobe_roi is not None:
        # the ROI the fitted lobe spans, where the detection's region cut it or drowned it
        refit = _photometric(img, gray, lobe_roi, est, camera, rig, response, colour, saturation_level, pkw)
        if refit.ok:
            pf = refit.noted(f"refitted on the lobe's ROI ({lobe_roi.shape[1]} x {lobe_roi.shape[0]} px)")
    # the other guide's highlight seen where the fit's plane puts it: the image tells the guides apart
    wander = estimate_wander_px(est) if pair_starts else 0.0
    paired = bool(pair_starts) and _fits_the_pair(pf, est.bp_px, camera, rig, pair_starts, wander)
    ran_off = pf.status in _RAN_OFF
    if pair_starts and (pf.ok or pf.status == "depth_not_observable" or ran_off) and not paired:
        # the other guide's highlight, which the ROI's fit did not see: refitted from the pair's depth too,
        # but not in a glint field (a plane shows a lobe per place of the rig's lights: no plane's image)
        if not (rig.has_separate_lights and _peaks_in(lobe_partners, big) >= rig.light_places):
            alt = _photometric(img, gray, big, est, camera, rig, response, colour, saturation_level,
                               dict(pkw, pair_starts=tuple(pair_starts)))
            if alt.ok and _fits_the_pair(alt, est.bp_px, camera, rig, pair_starts, wander):
                pf = alt.noted("refitted from the depth its pair with another guide's highlight gives")
            elif not ran_off and (span := _pair_roi(big, est.bp_px, camera, rig, pair_starts, img.shape)) is not None:
                # one guide's lobe alone leaves which guide lit it to the fit: the swapped guide at another
                # depth images nearly the same lobe. The other guide's highlight, in the ROI, tells them apart
                joint = _photometric(img, gray, span, est, camera, rig, response, colour, saturation_level,
                                     dict(pkw, pair_starts=tuple(pair_starts)))
                if joint.ok and _fits_the_pair(joint, est.bp_px, camera, rig, pair_starts, wander):
                    pf = joint.noted(f"refitted on the ROI that holds its pair with another guide's "
                                     f"highlight ({span.shape[1]} x {span.shape[0]} px)")
        # the plane (a depth-less fit's normal: at the pair's depth) off the partner's lobe, farther than a
        # BP's wander off its specular point: the lobe's size, its isophote's (both guides' lobes on one
        # plane image alike) or the detection's where none closed
        lobe = lobe_size_px(est)
        gap = (pair_misfit_px(camera, rig, est.bp_px, pair_starts, pf.normal, pf.distance_mm, shape=img.shape,
                              margin_px=lobe) if pf.has_normal else 0)
        paired = pf.has_normal and gap <= lobe
        if gap > lobe and not ran_off:
            pf = pf.without_depth("guide_misfit", f"its plane puts the paired guide's specular point {gap:.3g} px "
                                                  f"from the highlight the rig pairs with this one; {pf.detail}")
    unseen = _unseen_guide(pf, est, gray, saturation_level, camera, rig) if pf.ok and pf.distance_mm else ""
    if unseen:
        pf = pf.without_depth("guide_misfit", f"{unseen}; {pf.detail}")
    out["photometric_fit"] = pf
    _curved_fits(out, gray, img.shape, est, camera, rig, saturation_level=saturation_level, cubic=cubic,
                 nominal_depth_mm=nominal_depth_mm, quadric_roi_scale=quadric_roi_scale, quadric=quadric,
                 paired=paired, partners=lobe_partners if rig.has_separate_lights else ())
    return out


#: Statuses of a plane fit that ran off (its distance or roughness out of bounds) or ended on a plane
#: with a light behind it: the pair's depth is the start such a fit lacked. Refitted from it on its own
#: ROI only: on the ROI that holds both, a glint field's spurious partner gave an ok 13.8 deg off.
_RAN_OFF = ("not_converged", "light_behind_plane")


def _pair_roi(big: Roi, bp_uv, camera, rig, starts, shape) -> Roi | None:
    """The smallest ROI that holds ``big`` and a square of its size about each partner that ``starts`` place
    (:func:`~simtest.reconstruct.rig_pairs.pair_partners`); None where no partner lies in the image."""
    half = max(big.shape) / 2.0
    partners = pair_partners(camera, rig, bp_uv, starts)
    boxes = [Roi.around(uv, half, shape) for uv in partners[_in_frame(partners, shape)]]
    return _roi_union(big, *boxes) if boxes else None


def _reach(est, scale: float) -> float:
    """``scale`` times half the larger side of ``est``'s ROI, px: the half-size of a ROI grown about its BP."""
    return scale * max(Roi(*(int(v) for v in est.roi)).shape) / 2.0


def lobe_size_px(est) -> float:
    """A highlight's size, px: its primary ellipse's semi-major axis, else half the larger side of its ROI."""
    ell = getattr(est, "ellipse", None)
    return float(max(ell.semi_axes)) if ell is not None else _reach(est, 1.0)


def _peaks_in(bps, roi: Roi) -> int:
    """How many of the points ``bps`` ((k, 2) (u, v), px) lie in ``roi``."""
    bps = np.asarray(bps, dtype=np.float64).reshape(-1, 2)
    return int(np.count_nonzero(np.all((bps >= (roi.col0, roi.row0)) & (bps < (roi.col1, roi.row1)), axis=1)))


def _roi_union(*rois: Roi) -> Roi:
    """The smallest ROI that holds every one of ``rois``."""
    return Roi(min(b.row0 for b in rois), max(b.row1 for b in rois), min(b.col0 for b in rois),
               max(b.col1 for b in rois))


def _unseen_guide(fit: LightAwareEstimate, est, gray: np.ndarray, clip, camera, rig) -> str:
    """Why the image refutes a plane fit (:data:`~simtest.decisions.GUIDE_SEEN_REL`): another guide's lobe
    predicted in the frame at least that share as high as the fit's own (at their specular points), or less high
    where that share of its predicted rise stands :data:`~simtest.decisions.SIGNIFICANCE_MIN` noise sigmas above
    the noise about its point, where the image rises less than that share of its predicted rise (the own lobe's
    measured height times the prediction's ratio) and reaches no clipped pixel (``clip``: the values' clip level,
    None without); "" where none. A lobe's rise is measured alike at either point (:func:`_rise`, the tail at the
    detected highlight's half-size; a clipped top's a lower bound); the own lobe is the guide whose point lies
    nearest the BP."""
    if len(rig.positions) < 2:
        return ""
    pts = guide_specular_points(camera, rig, fit.normal, fit.distance_mm)
    inside = _in_frame(pts, gray.shape)
    bp = np.asarray(est.bp_px, np.float64)
    own = nearest_guide(pts, bp)
    if not inside[own]:
        return ""
    others = np.flatnonzero(inside & (np.arange(len(pts)) != own))
    if not others.size:
        return ""
    rays = _la.model._rays(camera, pts[np.r_[own, others]])
    spec = _la.model.plane_rig_intensity(rays, fit.normal, fit.distance_mm, rig, fit.roughness)
    if not spec[0] > 0:
        return ""
    ring = _reach(est, 1.0)
    height = _rise(gray, pts[own], ring)[0]  # (a clipped top: a lower bound)
    for j, s in zip(others, spec[1:]):
        rel = float(s / spec[0])
        if rel < GUIDE_SEEN_REL and not (GUIDE_SEEN_REL * rel * height >= SIGNIFICANCE_MIN * noise_sigma(
                gray[Roi.around(pts[j], ring, gray.shape).slices])):
            continue
        rise, peak = _rise(gray, pts[j], ring)
        if rise < GUIDE_SEEN_REL * rel * height and not (clip is not None and peak >= clip):
            return (f"its plane puts guide {j + 1}'s specular point at ({pts[j, 0]:.0f}, {pts[j, 1]:.0f}) px, its "
                    f"lobe {rel:.2g} times as high as this one's, where the image rises {rise:.3g} of {height:.3g}")
    return ""


def nearest_guide(pts: np.ndarray, bp_uv) -> int:
    """The guide whose specular point of ``pts`` (J, 2) (u, v) px, NaN where its plane images none, lies nearest
    the BP ``bp_uv``: the guide that lit the highlight, as a plane fit reads it."""
    gaps = np.linalg.norm(np.where(np.isfinite(pts), pts, np.inf) - np.asarray(bp_uv, np.float64), axis=1)
    return int(np.nanargmin(gaps))


def _rise(gray: np.ndarray, uv, ring: float) -> tuple[float, float]:
    """A lobe's height at its predicted specular point ``uv`` (u, v) px: the peak within ``PAIR_TOL_PX`` of it
    (where a right plane puts the lobe's top) above the median of the border of a square of half-side ``ring``
    px about it (the lobe's tail: on a smooth shading gradient without a lobe, the two differ by the gradient
    over ``PAIR_TOL_PX``), and the peak itself."""
    peak = float(gray[Roi.around(uv, PAIR_TOL_PX, gray.shape).slices].max())
    return peak - float(np.median(border_ring(gray[Roi.around(uv, ring, gray.shape).slices]))), peak


def _fits_the_pair(fit: LightAwareEstimate, bp_uv, camera, rig, starts, wander_px: float = 0.0) -> bool:
    """Whether a fit with a depth puts the pair's other highlight within ``PAIR_TOL_PX`` plus ``wander_px`` of it
    (:func:`~simtest.reconstruct.rig_pairs.pair_misfit_px`): the BP's wander, the partner's alike (one plane's lobes)."""
    return (fit.has_normal and fit.distance_mm is not None
            and pair_misfit_px(camera, rig, bp_uv, starts, fit.normal, fit.distance_mm) <= PAIR_TOL_PX + wander_px)


def _fit_intensities(img: np.ndarray, response, linear, saturation_level):
    """``(gray, saturation_level, censor, floor, floor_step)``: the values the fits read (a sensor
    frame's linear channel, else the luma), their clip level, censoring, an integer image's floor and step."""
    censor = False
    # an unsigned integer image's 0 is a floor its read noise is clipped at; its step is 1 (linear: its value)
    floor = 0.0 if img.dtype.kind == "u" else None
    floor_step = 1.0
    if response is not None:
        gray, saturation_level, ch = response.linearize(img) if linear is None else linear
        censor = True
        if floor is not None:
            floor_step = float(np.ravel(response.linear(np.ones(1), ch, response.full_scale(img)))[0])
    else:
        if saturation_level is None and img.dtype.kind == "u":
            saturation_level = float(np.iinfo(img.dtype).max)
        gray = luma(img)
    return gray, saturation_level, censor, floor, floor_step


def _photometric(img, gray, big: Roi, est, camera, rig, response, colour: bool, saturation_level,
                 pkw: dict) -> LightAwareEstimate:
    """The photometric fit of :func:`light_aware_estimates` on the ROI ``big``, its depth within
    the ceiling: on the three linear channels where ``colour``, else on ``gray``."""
    fit_values, fit_clip = gray[big.slices], saturation_level
    if colour:
        # the ROI's three linear channels: the fit projects the body colours (and texture) out
        fs = response.full_scale(img)
        sub = img[big.slices]
        fit_values = np.stack([response.linear(sub[..., c], c, fs) for c in range(3)], axis=-1)
        fit_clip = [float(response.linear(fs, c, fs)) for c in range(3)]
    margin = _clip_margin(fit_values, fit_clip)
    # (the projections measure the body colours on what the clip left)
    pkw = (dict(pkw, clip_level=fit_clip, clip_margin=margin) if colour or margin is None
           else dict(pkw, clip_level=fit_clip - margin))
    if response is not None and not colour and img.ndim == 3:
        # one channel of a sensor frame (a JPEG grid): the albedo's dark lines are left out
        y = luma(img[big.slices])
        pkw["exclude"] = _la.model.albedo_lines(y, 1.0 if img.dtype.kind in "ui" else 0.0,
                                                noise_sigma(y) if min(y.shape) >= 3 else 0.0)

    def fitted(projection: str, **extra) -> LightAwareEstimate:
        """The photometric fit on ``projection``, guarded, before the depth ceiling."""
        return _guarded("photometric_fit", photometric_fit, fit_values, (big.col0, big.row0), est.bp_px,
                        camera, rig, projection=projection, **dict(pkw, **extra))

    first = fitted("auto")
    if (pkw.get("lobe") == "phong" or (pkw.get("lobe") == "auto" and not colour)) and _broad_phong(first):
        # a broad lobe's tails tell Phong from GGX: the GGX fit from Phong's plane, the better kept
        first = _la.plane._choose_lobe(first, fitted("auto", lobe="ggx", start_normal=first.normal,
                                                     start_roughness=first.roughness))
    # its depth within the ceiling before the curved fits' turn is decided by its status
    pf = depth_within_ceiling(first)
    if colour and first.ok and not pf.ok and first.projection == "body_colours":
        # the body colours' depth above the ceiling: the least-fluctuation weights' fit if ok
        lf = depth_within_ceiling(fitted("least_fluctuation"))
        if lf.ok and lf.projection == "least_fluctuation":
            pf = lf.noted("the body colours' depth is above the ceiling")
    if colour and ((not pf.ok and pf.projection == "least_fluctuation")
                   or (pf.projection == "body_colours" and pf.curvature_shift_deg is None
                       and pf.status in ("depth_not_observable", "not_converged"))):
        # the darkest channel's fit stands in for a projection's fit without its depth
        # (docs/decisions/light-aware-recommendation.md)
        why = f"the {pf.projection.replace('_', ' ')} projection's fit: {pf.status}"
        pf = depth_within_ceiling(fitted("darkest_channel")).noted(why)
    return pf


def _clip_margin(values: np.ndarray, clip):
    """How far below ``clip`` (one level, or per channel of ``values`` (H, W, 3); None: none) the fits
    censor: ``CLIP_MARGIN`` times the noise of the ROI's unclipped pixels, or of those above
    ``CLIP_NOISE_FROM_REL`` of the clip where larger; 0 without noise.
    """
    if clip is None:
        return None
    chans = [values[..., c] for c in range(values.shape[-1])] if np.ndim(clip) else [values]
    out = []
    for v, cl in zip(chans, np.ravel(clip)):
        v = np.asarray(v, np.float64)
        below = (v[:, :-2] < cl) & (v[:, 1:-1] < cl) & (v[:, 2:] < cl)
        d = second_differences(v)
        top = below & (np.minimum(v[:, :-2], v[:, 2:]) >= CLIP_NOISE_FROM_REL * cl)
        sig = [noise_sigma_of_differences(d[m]) for m in (below, top) if np.count_nonzero(m) >= 3]
        out.append(CLIP_MARGIN * max(sig, default=0.0))
    return out if np.ndim(clip) else out[0]


def _broad_phong(fit: LightAwareEstimate) -> bool:
    """Whether a Phong fit passed (no curved patch's pattern) with n at most ``BROAD_LOBE_PHONG_N``."""
    return (fit.has_normal and fit.lobe == "phong" and fit.roughness is not None and fit.roughness <= BROAD_LOBE_PHONG_N
            and fit.curvature_shift_deg is None and (fit.ok or fit.status == "depth_not_observable"))


def _lobe_roi(fit: LightAwareEstimate, bp_uv, camera, rig, shape, roi: Roi) -> Roi | None:
    """The square ROI about the BP where the fit's Phong image of the rig exceeds ``LOBE_EDGE_REL`` of
    its peak (radius r), where ``roi`` cuts it (half-width below r / ``LOBE_ROI_MISMATCH``); else None."""
    if not fit.has_normal or fit.distance_mm is None or fit.roughness is None or not fit.roughness > 0:
        return None
    (h, w), grid = shape[:2], 129  # grid points a side: the lobe's edge found to one step, added below
    u, v = np.meshgrid(np.linspace(0.0, w - 1.0, grid), np.linspace(0.0, h - 1.0, grid))
    uv = np.column_stack([u.ravel(), v.ravel()])
    s = _la.model.plane_rig_intensity(_la.model._rays(camera, uv), fit.normal, fit.distance_mm, rig, fit.roughness)
    if not np.isfinite(s).all() or not s.max() > 0:
        return None
    r = float(np.max(np.hypot(*(uv[s >= LOBE_EDGE_REL * s.max()] - np.asarray(bp_uv, float)).T)))
    r += max(w, h) / (grid - 1)
    return Roi.around(bp_uv, r, shape) if max(roi.shape) / 2.0 < r / LOBE_ROI_MISMATCH else None


def _curved_fits(out: dict, gray, shape, est, camera, rig, *, saturation_level, nominal_depth_mm,
                 quadric_roi_scale, quadric, cubic, paired: bool = False, partners=()) -> None:
    """The curved-patch fits added to ``out`` (the photometric fit's) as ``quadric`` and ``cubic``
    say, and every fit released: its depth within the ceiling, the BP ray's error beside it set, a
    depth-less one's sigma with the guides' spread (:func:`~simtest.reconstruct.recommend.with_guide_spread`)
    unless it is the photometric fit and ``paired`` (its plane puts another guide's specular point on
    the highlight the rig pairs with this one).

    ``partners`` (BPs of other candidates, under separate lights) may be the other guides' lobes of one curved
    patch: a quadric that fails on the highlight's ROI is fitted again on the ROI that holds a square of the same
    size about each too, and kept where that fit is ok. A smooth patch shows at most one lobe per place of the
    rig's lights: the default quadric does not run on a ROI holding as many partners as that, nor the refit where
    the highlight and its partners outnumber them. Under separate lights it also runs where the plane ran off
    beside fewer (none: the guides' lobes fused into the one candidate; one: another guide's lobe)."""
    half = _reach(est, quadric_roi_scale)
    near = Roi.around(est.bp_px, half, shape)
    status = out["photometric_fit"].status  # the plane's: which curved fits run by default
    ray = _la.model._rays(camera, np.asarray(est.bp_px, dtype=np.float64)[None])[0]
    # a misfitting patch's sigma only where the plane misfits, below what rule 4 could take
    misfit_sigma: bool | float = bool(quadric)
    if status == "plane_misfit" and not quadric:
        # the plane as rule 4 reads it
        plane = _released(out["photometric_fit"], ray, rig, nominal_depth_mm)
        misfit_sigma = min(90.0, _bp_ray_error_beside(est, plane) / SIGMA_MARGIN)
    # a smooth patch shows a lobe per place of the rig's lights: a ROI with more peaks (glints) is no quadric's
    lobes, bps = rig.light_places, np.asarray(partners, dtype=np.float64).reshape(-1, 2)
    inside = _peaks_in(bps, near)
    ran_off = status == "not_converged" and rig.has_separate_lights and len(bps) < lobes  # (docstring)
    fits = {}
    if quadric or (quadric is None and (status in QUADRIC_AFTER or ran_off) and inside < lobes):
        fits["quadric_fit"] = (quadric_fit, misfit_sigma)
    if cubic or (cubic is None and status in CURVED_FIT_AFTER and rig.has_separate_lights):  # two lobes apart
        fits["cubic_patch_fit"] = (cubic_patch_fit, bool(cubic))
    for name, (fit, sigma) in fits.items():
        out[name] = _curved_fit(name, fit, gray, near, est, camera, rig, saturation_level, nominal_depth_mm, sigma)
        if name == "quadric_fit" and not out[name].ok and 0 < len(bps) < lobes:
            # the other guides' lobes of a curved patch, which the highlight's ROI cuts: fitted together
            wide = _roi_union(near, *(Roi.around(uv, half, shape) for uv in partners))
            again = _curved_fit(name, fit, gray, wide, est, camera, rig, saturation_level, nominal_depth_mm, sigma)
            if again.ok:
                out[name] = again.noted(f"fitted on the ROI that holds the {len(partners)} other "
                                        f"candidate(s) beside it ({wide.shape[1]} x {wide.shape[0]} px)")
    for name, r in out.items():
        out[name] = _released(r, ray, rig, nominal_depth_mm, paired and name == "photometric_fit")


def _released(r: LightAwareEstimate, ray, rig, nominal_depth_mm, resolved: bool = False) -> LightAwareEstimate:
    """``r`` as returned: its depth within the ceiling, the error beside it of the BP's ray ``ray`` set, the
    guides' spread counted in a depth-less sigma unless ``resolved``."""
    r = depth_within_ceiling(_la.estimate.light_behind_surface(r, ray, rig.positions))
    at = bp_error_depth_mm(r, nominal_depth_mm)
    r = r if resolved else with_guide_spread(r, ray, at, rig)
    return dataclasses.replace(r, bp_ray_error_deg=bp_ray_error_deg(ray, at, rig))


def patch_fit(name: str, image, est, camera, rig: LightRig, at: Roi, *, nominal_depth_mm: float = 20.0,
              saturation_level: float | None = None, response=None, linear=None, **_ignored) -> LightAwareEstimate:
    """One curved-patch fit of a highlight on the ROI ``at``, which may hold other guides' lobes of the patch
    (:mod:`simtest.reconstruct.curved_lobes`).

    Parameters
    ----------
    name : {"quadric_fit", "cubic_patch_fit"}
        The fit (:func:`~simtest.reconstruct.lightaware.quadric_fit` or
        :func:`~simtest.reconstruct.lightaware.cubic_patch_fit`).
    image, est, camera, rig, nominal_depth_mm, saturation_level, response, linear
        As for :func:`light_aware_estimates` (its other arguments ignored).
    at : Roi
        The pixels fitted.

    Returns
    -------
    LightAwareEstimate
        As :func:`light_aware_estimates` returns it: its depth within the ceiling, ``bp_ray_error_deg`` set.

    Raises
    ------
    KeyError
        An unknown ``name``.
    """
    fit = {"quadric_fit": quadric_fit, "cubic_patch_fit": cubic_patch_fit}[name]
    img = np.asarray(image)
    gray, saturation_level = _fit_intensities(img, response, linear, saturation_level)[:2]
    r = _curved_fit(name, fit, gray, at, est, camera, rig, saturation_level, nominal_depth_mm, True)
    ray = _la.model._rays(camera, np.asarray(est.bp_px, dtype=np.float64)[None])[0]
    return _released(r, ray, rig, nominal_depth_mm)


def _curved_fit(name, fit, gray, at: Roi, est, camera, rig, saturation_level, nominal_depth_mm, misfit_sigma):
    """One curved-patch fit of ``est`` on the ROI ``at``, guarded; its clip the plane fit's, less the noise's
    margin (values within it are clipped pixels read low)."""
    margin = _clip_margin(gray[at.slices], saturation_level)
    clip = saturation_level if margin is None else saturation_level - margin
    return _guarded(name, fit, gray[at.slices], (at.col0, at.row0), est.bp_px, camera, rig, clip_level=clip,
                    nominal_depth_mm=nominal_depth_mm, misfit_sigma=misfit_sigma)


def colour_fit_applies(image, response) -> bool:
    """Whether the photometric fit runs on a frame's three linear channels: an RGB frame with a sensor
    response and no JPEG block grid (a JPEG's chroma is subsampled and blocky).
    """
    img = np.asarray(image)
    if response is None or img.ndim != 3:
        return False
    return img.dtype != np.uint8 or jpeg_grid(img) is None

def fit_arguments(image, kwargs: dict) -> dict:
    """``kwargs`` with, once a frame, the clip a codec left the tops at (:func:`frame_ceiling`), the
    frame's linear image (that clip made linear) and :func:`colour_fit_applies`' decision."""
    img, response = np.asarray(image), kwargs.get("response")
    if response is not None and "linear" not in kwargs:
        gray, clip, ch = response.linearize(img)
        fs, top = response.full_scale(img), frame_ceiling(img) if img.dtype.kind == "u" else np.inf
        if top < fs:
            clip = float(np.ravel(response.linear(np.full(1, top), ch, fs))[0])
        kwargs = dict(kwargs, linear=(gray, clip, ch))
    elif response is None and kwargs.get("saturation_level") is None and img.dtype.kind == "u":
        kwargs = dict(kwargs, saturation_level=frame_ceiling(img))
    return kwargs if "colour" in kwargs else dict(kwargs, colour=colour_fit_applies(image, kwargs.get("response")))


def _isocurve_isophotes(gray, big: Roi, bp_uv, refine: bool = True) -> tuple[list[np.ndarray], list[float]]:
    """The isophotes given to :func:`isocurve_fit`, ``(points, isovalues)``: at each of :data:`ISOCURVE_ISOVALUES`,
    the closed contour's points (N_k, 2) (u, v) px about the BP (refined as ``refine`` says); cut or short levels
    are left out."""
    vals = np.asarray(gray[big.slices], dtype=np.float64)
    base = float(np.median(border_ring(vals)))
    c, r = int(round(bp_uv[0])) - big.col0, int(round(bp_uv[1])) - big.row0
    peak = float(vals[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].max())
    if not peak > base:
        return [], []
    origin = (big.col0, big.row0)
    pts, ts = [], []
    for t in ISOCURVE_ISOVALUES:
        level = base + t * (peak - base)
        iso = extract_isophote(vals, level, bp_uv, origin_rc=(big.row0, big.col0), image_shape=gray.shape)
        if not iso or iso.points_uv is None or len(iso.points_uv) < 6:
            continue
        pts.append(refine_isophote_points(vals, level, iso.points_uv, origin) if refine else iso.points_uv)
        ts.append(t)
    return pts, ts

def _guarded(name: str, fit, *args, **kwargs) -> LightAwareEstimate:
    """``fit(*args, **kwargs)``, or a ``not_converged`` estimate named ``name`` when the solver
    refuses the highlight (ValueError, LinAlgError, ArithmeticError): a status, not the frame's."""
    try:
        return fit(*args, **kwargs)
    # ArithmeticError: FloatingPointError, OverflowError and a ZeroDivisionError of a fit run off
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
        return LightAwareEstimate(name, "not_converged", f"{type(exc).__name__}: {exc}")


def with_light_aware(image, estimates, camera, rig: LightRig | None, *, on_highlight=None,
                     fit_rejected: bool = False, workers: int = 1, plane_only=(), deferred=None, weak=(),
                     **kwargs) -> list:
    """The estimates with their light-aware results attached (``light_aware``).

    Nothing runs without a rig or with every light at the camera centre. Only accepted highlights
    are fitted, unless ``fit_rejected`` (not those rejected for :data:`NOT_FITTED`).

    Parameters
    ----------
    image : ndarray
        The image.
    estimates : sequence of SpecularityEstimate
        From :func:`~simtest.reconstruct.reconstruct`.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K or a camera model.
    rig : LightRig or None
        The scope's lights.
    on_highlight : callable, optional
        Called as ``on_highlight(done, total)`` after each highlight's fits (``total`` grows where a deferred
        piece is fitted after all).
    fit_rejected : bool, optional
        Fit the rejected candidates too.
    workers : int
        Worker processes (1: in this process); the same results bit for bit whatever the number.
    plane_only : collection of int
        Indexes of rejected candidates fitted too, with :data:`PLANE_ONLY`
        (:func:`~simtest.reconstruct.rig_lobes.fused_lobe_candidates`).
    deferred : dict of int to int, optional
        Of the ``plane_only`` indexes, those fitted only where the fit of another (the value) is no ok plane
        with its distance: pieces of one fused top (:func:`~simtest.reconstruct.rig_centroid.fused_top_groups`).
        The others get no fits (``light_aware`` ``{}``).
    weak : collection of int
        Indexes of the estimates ok only as weak twins. A highlight in a glint field (:func:`glint_fields`)
        gets ``photometric_fit`` alone, ``glint_field`` (unless ``quadric`` or ``cubic`` is True).
    **kwargs
        Passed to :func:`light_aware_estimates`.

    Returns
    -------
    list of SpecularityEstimate
        In the order of ``estimates``.

    Raises
    ------
    ValueError
        If ``workers`` is below 1.
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if not _offset_rig(rig):
        return list(estimates)
    kwargs = fit_arguments(image, kwargs)
    out = list(estimates)
    todo = [i for i, est in enumerate(out) if est.ok or (fit_rejected and est.status not in NOT_FITTED)]
    jobs = {i: {} for i in todo} | {i: PLANE_ONLY for i in plane_only if i not in todo}
    todo = sorted(jobs)
    partners = np.array([out[i].bp_px for i in todo], np.float64).reshape(-1, 2)  # of the pair starts, fields or not
    wander = dict(zip(todo, [estimate_wander_px(out[i]) for i in todo]))  # (and the BPs' wander, px)
    if rig.has_separate_lights:
        roi_scale = kwargs.get("roi_scale", LIGHT_AWARE_ROI_SCALE)
        _add_lobe_partners(out, todo, jobs, roi_scale)
        fields = {} if kwargs.get("quadric") or kwargs.get("cubic") else glint_fields(  # (True: every highlight)
            out, [i for i in todo if jobs[i].get("quadric") is not False], rig, roi_scale, np.shape(image),
            set(weak) | _tissue_clusters(image, out, kwargs.get("response")))
        for i, why in fields.items():
            out[i] = dataclasses.replace(out[i], light_aware={"photometric_fit": LightAwareEstimate(
                "photometric_fit", "glint_field", why, None)})
            todo.remove(i)
    # further starts: where the rig puts another guide's highlight on another fitted highlight
    for i, starts in zip(todo, pair_starts(camera, rig.positions, [out[i].bp_px for i in todo], partners,
                                           [wander[i] for i in todo], list(wander.values()))):
        if starts:
            jobs[i] = dict(jobs[i], pair_starts=starts)
    # the others get no fits ({}): under a rig off the camera centre rule 1 recommends the BP ray
    skipped = set(range(len(out))).difference(todo)
    for i in sorted(skipped):
        if out[i].light_aware is None:
            out[i] = dataclasses.replace(out[i], light_aware={})
    deferred = deferred or {}
    later = {i: j for i, j in deferred.items() if i in todo and j in todo and j not in deferred}
    first = [i for i in todo if i not in later]
    # one BLAS thread here as in the workers: several threads' sums differ in their last bits
    with one_thread_each():
        _run_fits(image, out, camera, rig, kwargs, jobs, first, workers, on_highlight, len(first))
        again = [i for i in sorted(later) if not _plane((out[later[i]].light_aware or {}).get("photometric_fit"))]
        _run_fits(image, out, camera, rig, kwargs, jobs, again, workers, on_highlight, len(first) + len(again),
                  len(first))
    for i in set(later).difference(again):
        out[i] = dataclasses.replace(out[i], light_aware={})
    return out


def _plane(fit) -> bool:
    """Whether a light-aware fit is ok with its plane's distance."""
    return fit is not None and fit.ok and fit.distance_mm is not None


def _run_fits(image, out: list, camera, rig, kwargs: dict, jobs: dict, rows: list, workers: int, on_highlight,
              total: int, done: int = 0) -> None:
    """The light-aware fits of ``out``'s ``rows`` with their ``jobs``' arguments over ``kwargs``, in ``workers``
    processes (1: here), into ``out`` in place; ``on_highlight(done, total)`` after each, counting on from ``done``."""
    if workers > 1 and len(rows) > 1:
        for name in ("scipy.optimize", "scipy.ndimage"):  # imported once here, not in each worker
            require(name)
        with worker_pool(min(workers, len(rows)), initializer=_fit_context,
                         initargs=(image, camera, rig, kwargs)) as pool:
            futures = {pool.submit(_fits_in_context, out[i], jobs[i]): i for i in rows}
            for done, fut in enumerate(as_completed(futures), done + 1):
                i = futures[fut]
                out[i] = dataclasses.replace(out[i], light_aware=fut.result())
                if on_highlight is not None:
                    on_highlight(done, total)
        return
    for done, i in enumerate(rows, done + 1):
        out[i] = dataclasses.replace(out[i], light_aware=light_aware_estimates(image, out[i], camera,
                                                                              rig, **(kwargs | jobs[i])))
        if on_highlight is not None:
            on_highlight(done, total)


def glint_fields(out: list, rows: list, rig: LightRig, roi_scale: float, shape, weak=()) -> dict[int, str]:
    """Why each of the ``rows`` of ``out`` whose photometric fit's ROI (``roi_scale`` times its ROI's half-size
    about the BP, within ``shape``) holds as many other glints as the rig has light places: more peaks with its own
    than a smooth patch under the rig shows (a lobe per place). A glint: a candidate ok or only a ``cluster``'s,
    not one of ``weak`` (a weak twin, unconfirmed; a cluster of the tissue's colour, :func:`_tissue_clusters`) nor
    one rejected otherwise (texture's spots, a skirt, a sheen's pieces)."""
    glint = [k for k, e in enumerate(out) if getattr(e, "bp_px", None) is not None
             and e.status in ("ok", "cluster") and k not in weak]
    bps, fields = np.array([out[k].bp_px for k in glint], np.float64).reshape(-1, 2), {}
    for i in rows if len(glint) > rig.light_places else ():
        big = Roi.around(out[i].bp_px, _reach(out[i], roi_scale), shape)
        if (k := _peaks_in(bps, big) - (i in glint)) >= rig.light_places:
            fields[i] = (f"{k + 1} specular peaks in the fit's {big.shape[1]} x {big.shape[0]} px ROI, where a smooth "
                         f"patch under the rig's {rig.light_places} light places shows at most {rig.light_places}")
    return fields


def _tissue_clusters(image, out: list, response) -> set[int]:
    """The ``cluster`` candidates of ``out`` whose BP, unclipped, shows the tissue's colour and not the
    illuminant's (:func:`~simtest.reconstruct.verify.specular_colour_at`): no glint, whatever their peak. Tissue
    ringed by darker vessels reads as a peak over a background the vessels pull down; its excess is the
    tissue's colour, where a glint's is the light's. Empty on a grey frame."""
    img = np.asarray(image)
    rows = [k for k, e in enumerate(out) if e.status == "cluster" and not e.saturated
            and getattr(e, "bp_px", None) is not None]
    if not rows or img.ndim != 3:
        return set()
    white = specular_colour_at(img, [out[k].bp_px for k in rows], full_scale=default_full_scale(img),
                               response=response)
    return {k for k, w in zip(rows, white) if not w}


def _add_lobe_partners(out: list, todo: list, jobs: dict, roi_scale: float) -> None:
    """Each curve-fitted job of ``todo`` given ``lobe_partners``: the BPs of the other candidates (but those
    :data:`NOT_FITTED`) whose ROI meets its grown ROI (``roi_scale`` times its ROI's half-size about its BP)."""
    use = [k for k, e in enumerate(out) if getattr(e, "bp_px", None) is not None and e.status not in NOT_FITTED]
    if len(use) < 2:
        return
    bps = np.array([out[k].bp_px for k in use], np.float64).reshape(-1, 2)
    rois = np.array([[int(v) for v in out[k].roi] for k in use], np.float64).reshape(-1, 4)  # row0, row1, col0, col1
    for i in todo:
        if jobs[i].get("quadric") is False or i not in use:  # (PLANE_ONLY's, with or without pair starts)
            continue
        (u, v), reach = out[i].bp_px, _reach(out[i], roi_scale)
        meets = ((rois[:, 0] < v + reach) & (rois[:, 1] > v - reach) & (rois[:, 2] < u + reach)
                 & (rois[:, 3] > u - reach) & (np.array(use) != i))
        if meets.any():
            jobs[i] = dict(jobs[i], lobe_partners=tuple(map(tuple, bps[meets])))


#: A worker's image, camera, rig and arguments of :func:`with_light_aware` (:func:`_fit_context`).
_CONTEXT: dict = {}


def _fit_context(image, camera, rig, kwargs) -> None:
    """A worker's initializer: what every highlight's fits share, received once."""
    _CONTEXT.update(image=image, camera=camera, rig=rig, kwargs=kwargs)


def _fits_in_context(est, extra: dict) -> dict[str, LightAwareEstimate]:
    """:func:`light_aware_estimates` of one highlight in a worker (:func:`_fit_context`), with
    ``extra`` arguments over the shared ones."""
    c = _CONTEXT
    return light_aware_estimates(c["image"], est, c["camera"], c["rig"], **(c["kwargs"] | extra))
