"""The light-aware estimators run on detected highlights, and the normal recommended to a user.

:func:`with_light_aware` runs :func:`~simtest.reconstruct.lightaware.isocurve_fit` and
:func:`~simtest.reconstruct.lightaware.photometric_fit` on the highlights that
:func:`~simtest.reconstruct.reconstruct` found, given the scope's light rig, and attaches the results
to each :class:`~simtest.reconstruct.pipeline.SpecularityEstimate` (``light_aware``).
:func:`recommend` then picks one normal per highlight, the ``normal`` of ``estimates.json``.

Recommendation rule
-------------------
Chosen from the harness' measurements on Mitsuba renders (``simtest validate rendered`` and the
``lightaware``, ``lightaware-curved`` and ``endoscope`` suites), never from ground truth at run
time; the measurements behind each rule are in ``docs/decisions/light-aware-recommendation.md``.

1. With a rig whose lights are not all at the camera centre: ``photometric_fit`` when its status
   is ``ok``, else ``cubic_patch_fit`` when ``ok`` (run only with two or more lights at
   different places), else ``quadric_fit`` when ``ok``, else ``isocurve_fit`` when ``ok`` (and
   the plane does not misfit), else (rule 3) the fit whose depth is not observable but whose
   normal's sigma beats the BP ray's expected error, else ``bp_ray``. The BP ray and the cone
   estimators estimate the direction of the BP, not the normal, when the light is off the
   camera. A fit whose depth is not observable is not used by this rule: with the light off the
   camera the tilt and the distance trade off, so an undetermined distance leaves the normal
   undetermined too, unless its normal's sigma, which carries that trade, says otherwise (rule
   3). On a curved patch the plane model trades the curvature for roughness and distance, and
   its spatially correlated residuals make ``photometric_fit`` report ``plane_misfit`` (or run
   off, ``not_converged``); such a fit (:data:`CURVED_FIT_AFTER`) runs ``quadric_fit`` (a
   curved patch, exact on spheres), recommended when its status is ``ok``; then
   ``isocurve_fit``, unless the plane misfits (the isocurve fit is the same plane model, seen
   through the contours); else the BP ray. Under one light the quadric is never ``ok``: its
   depth is not observable (a single highlight does not tell the depth from the surface's
   third-order shape), so it is withdrawn, and its normal's sigma spans the bisectors at the
   depths within :data:`~simtest.reconstruct.lightaware.patch.ONE_LIGHT_DEPTH_FACTOR` of the
   fitted one (``depth_range_mm``); rule 3 then compares it with the BP ray's error at the
   farthest of those depths (:func:`bp_error_depth_mm`). The quadric is fitted on the
   highlight's ROI grown 1.5 times, not the plane's 2.5 (a larger ROI takes in more of the
   surface's third-order shape, which the fit's depth trades with). With two lights at
   different places (a colonoscope's guides either side of the lens) the lobes shift apart as
   the light offsets over the depth say while the surface's shape acts on both alike, so the
   third-order patch fitted to both (``cubic_patch_fit``) fixes the depth with the shape free;
   it comes before the quadric, whose depth, with the third-order shape left out, is the one at
   which the offsets stand in for it. With one light it is not run (nor recommended when run on
   request): its depth is then not observable, and a cubic patch whose depth is not observable
   is never used. Its normal is the apex's (the mean light's specular point); the normal at each
   light's specular point (``light_normals``) is given beside it.
2. Without a rig, or with every light at the camera centre: ``joint_cone_axis`` when at least two
   isophotes succeeded, else ``cone_axis``, else ``bp_ray``. Over the co-located rendered suite the
   joint cone axis has the lowest mean and median error (:func:`colocated_ranking` recomputes the
   ranking from a ``results.json``); the BP ray is better on the curved meshes (liver, colon), the
   cone axes on planes, spheres, cylinders and saddles and wherever the BP is clipped.

3. Where no light-aware fit is ``ok`` with a rig off the camera centre, a fit whose depth is not
   observable (``depth_not_observable``, the misfit tests passed, and the same exclusions as in
   1.; ``cubic_patch_fit`` only with its normal per light, i.e. two lights whose depth passed
   the noise floor's test and only the ceiling withdrew it: under one light its third-order
   shape trades with the depth) is still recommended, the one of least stated sigma
   (``normal_sigma_deg``, with a normal per light the largest of theirs: :func:`_stated_sigma`),
   when twice that sigma (:data:`SIGMA_MARGIN`: the fit's error at 95 %) is below the BP ray's
   expected error (:func:`bp_ray_error_deg`: half the angle the rig's mean light subtends at the
   specular point, at the nominal depth of 20 mm where the depth is unknown, or at the farthest
   depth the fit cannot exclude where it states one: :func:`bp_error_depth_mm`); ``depth_mm`` is
   then None. Reasons: the BP is where the normal bisects the directions to the camera and the
   light, so the BP ray errs by about that half angle whatever the surface, while the fit's
   sigma comes from its covariance with the distance free, so the tilt that trades with the
   undetermined distance is in it; a depth that is not observable leaves the normal determined
   to within that sigma. Twice the sigma, not once: a curved patch's fit can pass its misfit
   tests with a sigma that does not carry the patch's shape. The BP ray's error compared with is
   also at least half the angle between the BP ray and the fit's normal: where the two differ by
   more than 2 x ``SIGMA_MARGIN`` sigmas, the fit's own sigma says the BP ray is the worse. A
   ``plane_misfit`` fit is not a candidate, although its sigma is then the sandwich's
   (:func:`~simtest.reconstruct.lightaware.solve._hac_covariance`, which counts correlated
   residuals): a plane fit that ends in a wrong local minimum misfits with a sigma that does not
   cover its error. On a sensor frame (RGB, a response, no JPEG grid) the fit runs on the three
   linear channels with the tissue's body colours projected out (``colour.specular_image``), so
   that the albedo's texture under the rig's diffuse light is not left in the residual; where
   the lobe itself does not fit (micro-relief breaking it into sparkle, a film sharper than the
   sensor resolves) the fit misfits, and rule 4 decides. The endoscope suite's report gives the
   share of each.

4. Where rules 1 to 3 found nothing, a ``plane_misfit`` photometric fit whose normal the curved
   patch confirms: ``quadric_fit`` gives a normal with a stated sigma s_q, the plane's normal
   lies within s_q of it (angle g <= s_q), and twice the stated sigma ``g + s_q`` is below the BP
   ray's expected error (as in rule 3); ``depth_mm`` is then None (the misfit withdrew it). The
   plane's normal errs by at most g plus the quadric's error, so ``g + s_q`` states what the
   quadric's sigma covers. Why: micro-relief on flat mucosa (the shading normal leaving the
   plane's) leaves a residual that the curvature test reads as a curved patch, while the plane's
   normal, averaged over the lobe, stays near the macro normal; on a curved patch the plane
   trades curvature for distance and misses the normal, and the quadric then disagrees.
   A quadric whose sigma is not stated (180 deg: its depth not bounded along its valley) confirms
   nothing.

Depth ceiling
-------------
A depth is released (``depth_mm``, the status ``ok``) only when its relative 1-sigma,
``depth_sigma_mm / depth_mm`` (and the noise-floored ``depth_rel_sigma`` of the patch fits, the
larger), is at most :data:`DEPTH_REL_SIGMA_CEILING` = 0.2 (:func:`depth_within_ceiling`); above it
the fit's status becomes ``depth_not_observable`` and its depth, distance and per-light depths
are withdrawn, its normal kept (rule 3 may still recommend it). Why 0.2: the fits estimate
log h, and the delta method's symmetric sigma describes the depth's interval while the log is
near linear over +-2 sigma: at 0.2, exp(+-0.4) is -33 % / +49 %, already lopsided; at the
previous bound of 0.5 (``TOL.depth_rel_sigma_max``, the fits' own observability test at the
noise floor) a "1-sigma" of 50 % spans a factor of 2.7 at 2 sigma, which is no measurement of
scale. A depth within 20 % (1 sigma) still gives the metric scale of the view to within a
factor of 1.5 at 2 sigma.

Isophotes of the isocurve fit
-----------------------------
:func:`isocurve_fit` takes its own isophotes, at :data:`ISOCURVE_ISOVALUES` (0.3, 0.5, 0.7) of the
BP's height above the median of the grown ROI's border, extracted from that ROI (the
photometric fit's), not the command line's isovalues. The command line's defaults (0.7, 0.85)
draw two small contours near the peak, where the lobe is nearly its quadratic approximation and
says little about the distance (measured: ``docs/decisions/light-aware-recommendation.md``).
Lower levels reach into the tails, where the falloff the isocurve model leaves out and
the background weigh more.

``depth_mm`` and ``normal_sigma_deg`` are those of the estimator recommended (None for the cone
axes and the BP ray, which observe neither), and so are ``light_normals`` and
``light_depths_mm`` (``cubic_patch_fit`` only).
"""

from __future__ import annotations

import dataclasses
import math
from concurrent.futures import as_completed
from dataclasses import dataclass

import numpy as np

from simtest._threads import one_thread_each
from simtest._workers import worker_pool
from simtest.decisions import (
    ISOCURVE_ISOVALUES,
    SIGMA_MARGIN,
    DEPTH_RELEASE_REL_SIGMA as DEPTH_REL_SIGMA_CEILING,
)
from simtest.geometry.lights import LightRig
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.detect import luma, noise_sigma
from simtest.reconstruct import lightaware as _la
from simtest.reconstruct.isophote import extract_isophote
from simtest.reconstruct.jpeg import jpeg_grid
from simtest.reconstruct.registry import names
from simtest.reconstruct.lightaware import (
    LightAwareEstimate,
    cubic_patch_fit,
    isocurve_fit,
    photometric_fit,
    quadric_fit,
    refine_isophote_points,
)

__all__ = ["DEPTH_REL_SIGMA_CEILING", "ISOCURVE_ISOVALUES", "LIGHT_AWARE", "NOT_FITTED", "SIGMA_MARGIN",
           "Recommendation", "bp_error_depth_mm",
           "bp_ray_error_deg", "colocated_ranking", "depth_within_ceiling", "light_aware_estimates",
           "recommend", "with_light_aware"]

#: The light-aware estimators, in the order of preference of the recommendation rule.
LIGHT_AWARE = names("light_aware", ranked=True)
#: The photometric fit's statuses after which the curved-patch fits run by default (``quadric``,
#: ``cubic`` None in :func:`light_aware_estimates`): those that say the plane is not the ROI's
#: surface (its residual holds a curved patch's pattern, or the fit ran off). After the others
#: a patch fit cannot do better and takes seconds: ``depth_not_observable`` (the plane fits; a
#: patch has more parameters to trade with the depth), ``too_few_points`` (fewer pixels than a
#: patch's parameters too), ``light_behind_plane``.
CURVED_FIT_AFTER = ("plane_misfit", "not_converged")
#: Fallback order without a rig (or with a co-located one).
COLOCATED_ORDER = names("isophote", "baseline", ranked=True)
#: Candidate statuses that never get a light-aware fit, not even with ``fit_rejected`` of
#: :func:`with_light_aware`: too small to fit, or judged no specular highlight of the tissue (the
#: scope's black border, a burnt-in overlay, a peak that is not specular:
#: :mod:`simtest.reconstruct.verify`).
NOT_FITTED = ("too_small", "black_border", "overlay", "not_specular")


@dataclass(frozen=True)
class Recommendation:
    """The normal recommended for one highlight.

    Attributes
    ----------
    normal : ndarray of shape (3,)
        Unit normal, OpenCV camera frame, facing the camera.
    normal_from : str
        The estimator it comes from.
    depth_mm : float or None
        Depth of the specular point along its ray, mm (None: not observable or not estimated).
    normal_sigma_deg : float or None
        1-sigma angular uncertainty, degrees (None when the estimator gives none); with
        ``light_normals``, the largest of the normal's and theirs.
    light_normals : ndarray of shape (J, 3) or None
        The normal at the specular point of each of the rig's J lights, where the estimator
        gives them (:func:`~simtest.reconstruct.lightaware.cubic_patch_fit`), unit, camera frame.
    light_depths_mm : ndarray of shape (J,) or None
        The depth of each light's specular point along its ray, mm, likewise.
    """

    normal: np.ndarray
    normal_from: str
    depth_mm: float | None = None
    normal_sigma_deg: float | None = None
    light_normals: np.ndarray | None = None
    light_depths_mm: np.ndarray | None = None


def _offset_rig(rig) -> bool:
    return rig is not None and not rig.is_colocated


def _several_lights(rig) -> bool:
    """Whether the rig has at least two lights at different places (their lobes can differ)."""
    return rig is not None and rig.has_separate_lights


def light_aware_estimates(image, est, camera, rig: LightRig, *, nominal_depth_mm: float = 20.0,
                          saturation_level: float | None = None,
                          roi_scale: float = 2.5, quadric_roi_scale: float = 1.5,
                          supersample: int = 1,
                          quadric: bool | None = None,
                          cubic: bool | None = False, response=None,
                          diffuse: bool | None = None,
                          lobe: str | None = None, linear=None, colour: bool | None = None,
                          floor_refit: bool = False) -> dict[str, LightAwareEstimate]:
    """Run the light-aware estimators on one detected highlight.

    ``isocurve_fit`` takes its own isophotes, at :data:`ISOCURVE_ISOVALUES` of the BP's height above
    the grown ROI's border median (refined onto the cubic spline of the image,
    :func:`~simtest.reconstruct.lightaware.refine_isophote_points`; module docstring, "Isophotes
    of the isocurve fit"), whatever isovalues the highlight was detected with; ``photometric_fit`` takes the highlight's
    ROI grown ``roi_scale`` times about the BP (the lobe's tails carry the distance), clipped pixels
    left out, refined from two starts (the bisector at the nominal depth and the isocurve fit's
    normal when it has one) and the better kept, so that one fit's local minimum does not become
    the other's answer.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The image the highlight was detected in.
    est : SpecularityEstimate
        From :func:`~simtest.reconstruct.reconstruct` or ``reconstruct_roi``.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The scope's lights, camera frame, mm.
    nominal_depth_mm : float
        Depth assumed for the fits' start, mm.
    saturation_level : float, optional
        Clip level (default: the dtype's maximum for integer images; none for float images).
    roi_scale : float
        Growth of the highlight's ROI for the photometric fit.
    quadric_roi_scale : float
        Growth of the highlight's ROI for the curved-patch fit: smaller than the plane's, as a
        quadric holds over a smaller part of a curved surface than the lobe's faint tails span
        (module docstring, "Recommendation rule").
    supersample : int
        Sub-pixel samples per pixel side of the photometric model (its box filter).
    quadric : bool or None
        Run the curved-patch fit :func:`~simtest.reconstruct.lightaware.quadric_fit` (on the
        highlight's ROI grown ``quadric_roi_scale`` times about the BP): True always, None
        (default) when the photometric fit's status is in :data:`CURVED_FIT_AFTER` (a plane
        misfit, or a plane fit that ran off on a curved patch: the recommendation then needs
        it), False never (the harness' oracle inputs keep the plane fit only).
    cubic : bool or None
        Run the third-order patch fit
        :func:`~simtest.reconstruct.lightaware.cubic_patch_fit` on the same ROI as the quadric's:
        True always, False (default: it takes about 1 to 5 s per highlight, against a few ms
        for the others) never, None when the photometric fit's status is in
        :data:`CURVED_FIT_AFTER` and the rig has at least two lights at different places (with
        one light its depth, and with it the normal, is not observable: module docstring);
        ``simtest reconstruct --cubic-patch`` asks for None.
    response : SensorResponse, optional
        The sensor's response (:class:`~simtest.geometry.response.SensorResponse`, a camera
        file's ``"response"``): the fits then run on the linear intensities of the channel where
        the tissue is darkest (:meth:`~simtest.geometry.response.SensorResponse.linearize`), its
        clipped pixels censored (the radiance is at least the clip level), with the rig's diffuse
        shading in the photometric model; ``saturation_level`` is then the response's.
    diffuse : bool or None
        The rig's Lambertian shading as a column of the photometric model
        (:func:`~simtest.reconstruct.lightaware.photometric_fit`'s ``diffuse``); None (default):
        with a ``response`` (a sensor frame of tissue), not without.
    lobe : {"phong", "ggx", "auto"} or None
        The photometric fit's specular lobe (:func:`~simtest.reconstruct.lightaware.photometric_fit`;
        ``"auto"``: GGX where Phong misfits and GGX does not). None (default): "auto" where the
        fit runs on the three channels (the film's own lobes, whose GGX shape Phong's misfits
        once the texture no longer hides it), else Phong. Phong on one channel: on sensor frames
        ``"auto"`` has not been seen to change a recommendation and costs CPU (measured:
        ``docs/decisions/light-aware-recommendation.md``). Where the image is the film's own
        (the renderer's specular radiance) GGX fits it to the render's noise where Phong misfits.
    floor_refit : bool
        Refit the photometric fit without the pixels whose model lies within a few noise sigmas
        of an integer image's 0 (:func:`~simtest.reconstruct.lightaware.photometric_fit`'s
        ``floor_refit``: read noise clipped at 0 biases the fit there; off by default, as on the
        ``lightaware`` suite's renders it cost more accuracy than it removed bias). The floor
        itself is always passed: the fit's curvature test reads only the pixels above it.
    colour : bool, optional
        Fit the photometric model on the ROI's three linear channels, the tissue's body colours
        projected out (:func:`colour_fit_applies`; None: decided here, :func:`with_light_aware`
        decides once per frame).
    linear : tuple, optional
        ``response.linearize(image)`` when already at hand (:func:`with_light_aware` computes it
        once per frame: on a 1350 x 1080 RGB frame it takes 25 ms, which each highlight took
        again).

    Returns
    -------
    dict
        ``{"isocurve_fit": LightAwareEstimate, "photometric_fit": LightAwareEstimate}`` (the
        isocurve fit is absent when none of its isophotes closes in the grown ROI),
        ``"quadric_fit"`` and ``"cubic_patch_fit"`` as ``quadric`` and ``cubic`` say. Each has
        its depth within :data:`DEPTH_REL_SIGMA_CEILING` (:func:`depth_within_ceiling`) and its
        ``bp_ray_error_deg`` set (:func:`bp_ray_error_deg` at its depth, or at
        ``nominal_depth_mm``).
    """
    img = np.asarray(image)
    censor = False
    # an unsigned integer image's 0 is a floor its read noise is clipped at (0 in the linear
    # image too: every response curve maps 0 to 0), its quantisation step 1 (in the linear
    # image, the linear value of 1)
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
    if diffuse is None:
        diffuse = response is not None
    out: dict[str, LightAwareEstimate] = {}
    roi = Roi(*(int(v) for v in est.roi))
    half = roi_scale * max(roi.shape) / 2.0
    big = Roi.around(est.bp_px, half, img.shape)
    start_n = None
    pts, ts = _isocurve_isophotes(gray, big, est.bp_px)
    if pts:
        iso_est = _guarded("isocurve_fit", isocurve_fit, pts, ts, est.bp_px,
                           camera, rig, nominal_depth_mm=nominal_depth_mm)
        out["isocurve_fit"] = iso_est
        if iso_est.has_normal:
            start_n = iso_est.normal
    fit_values, fit_clip = gray[big.slices], saturation_level
    if colour is None:
        colour = colour_fit_applies(img, response)
    if lobe is None:
        lobe = "auto" if colour else "phong"
    if colour:
        # the ROI's three linear channels: the fit projects the tissue's body colours out
        # (photometric_fit's values (H, W, 3)), which takes the albedo's texture with them
        fs = response.full_scale(img)
        sub = img[big.slices]
        fit_values = np.stack([response.linear(sub[..., c], c, fs) for c in range(3)], axis=-1)
        fit_clip = [float(response.linear(fs, c, fs)) for c in range(3)]
    pkw = dict(clip_level=fit_clip, nominal_depth_mm=nominal_depth_mm,
               start_normal=start_n, supersample=supersample, diffuse=diffuse, censor=censor,
               lobe=lobe, floor_level=floor, floor_refit=floor_refit, floor_step=floor_step)
    if response is not None and not colour and img.ndim == 3:
        # one channel of a sensor frame whose colours cannot be projected out (a JPEG grid):
        # the albedo's dark lines (vessels) are left out of the fit (model.albedo_lines)
        y = luma(img[big.slices])
        pkw["exclude"] = _la.model.albedo_lines(y, 1.0 if img.dtype.kind in "ui" else 0.0,
                                                noise_sigma(y) if min(y.shape) >= 3 else 0.0)

    def fitted(projection: str) -> LightAwareEstimate:
        """The photometric fit on ``projection``, guarded, before the depth ceiling."""
        return _guarded("photometric_fit", photometric_fit, fit_values, (big.col0, big.row0), est.bp_px,
                        camera, rig, projection=projection, **pkw)

    first = fitted("auto")
    # its depth within the ceiling before the curved fits' turn is decided by its status
    out["photometric_fit"] = depth_within_ceiling(first)
    if colour and first.ok and not out["photometric_fit"].ok and first.projection == "body_colours":
        # the body colours' depth above the ceiling: the least-fluctuation weights' fit where it
        # is ok within it (as photometric_fit's "auto" projection does for a fit without depth)
        lf = depth_within_ceiling(fitted("least_fluctuation"))
        if lf.ok and lf.projection == "least_fluctuation":
            why = "the body colours' depth is above the ceiling"
            out["photometric_fit"] = dataclasses.replace(
                lf, detail=f"{lf.detail}; {why}" if lf.detail else why)
    pf = out["photometric_fit"]
    if colour and ((not pf.ok and pf.projection == "least_fluctuation")
                   or (pf.projection == "body_colours" and pf.curvature_shift_deg is None
                       and pf.status in ("depth_not_observable", "not_converged"))):
        # a fit on the least-fluctuation projection is kept only with its depth within the
        # ceiling (photometric_fit's ``projection``): on the endoscope suite's colon wall one
        # passed the fit's own tests with a relative depth sigma of 0.37, 16 deg off with a sigma
        # of 2.4, and was recommended over the BP ray (1.5 deg); the darkest channel's fit then
        # stands in, as before the projection. So does it for the body colours' fit without its
        # depth: their plane, measured on the border through the sensor's noise, leaves some
        # texture too (the colon wall without relief: two such fits 17.4 and 17.6 deg off with
        # sigmas of 3.6 deg were recommended over a BP ray 2.3 deg off); a misfit of theirs
        # stands (rule 4 may confirm its normal), and so does a fit kept with a curved patch's
        # pattern (curvature_shift_deg: a micro-relief's), whose depth that pattern took and
        # whose normal's sigma carries the shift (rule 3 weighs it)
        why = f"the {pf.projection.replace('_', ' ')} projection's fit: {pf.status}"
        chan = depth_within_ceiling(fitted("darkest_channel"))
        out["photometric_fit"] = dataclasses.replace(
            chan, detail=f"{chan.detail}; {why}" if chan.detail else why)
    near = Roi.around(est.bp_px, quadric_roi_scale * max(roi.shape) / 2.0, img.shape)
    curved = out["photometric_fit"].status in CURVED_FIT_AFTER
    # a curved patch that misfits serves the recommendation only through the quadric's sigma
    # where the plane misfits (rule 4): elsewhere its sigma, whose depth valley takes most of
    # the fit's time, is not read (on a real frame's glints the plane fit often runs off and
    # the quadric misfits: seconds a highlight)
    # There, only a sigma below what rule 4 could take is read: the valley only widens the
    # quadric's local sigma, and rule 4 takes a stated sigma s_q below 90 deg with
    # SIGMA_MARGIN (g + s_q) below the BP ray's error beside the plane (a real frame's glint: a
    # local sigma of 126 deg, its valley 5 s of one core, read for nothing)
    ray = _la.model._rays(camera, np.asarray(est.bp_px, dtype=np.float64)[None])[0]

    def released(r: LightAwareEstimate) -> LightAwareEstimate:
        """``r`` as returned: its depth within the ceiling, the BP ray's error beside it set."""
        r = depth_within_ceiling(_la.estimate.light_behind_surface(r, ray, rig.positions))
        return dataclasses.replace(
            r, bp_ray_error_deg=bp_ray_error_deg(ray, bp_error_depth_mm(r, nominal_depth_mm), rig))

    misfit_sigma: bool | float = bool(quadric)
    if out["photometric_fit"].status == "plane_misfit" and not quadric:
        # the plane as rule 4 reads it
        misfit_sigma = min(90.0, _bp_ray_error_beside(est, released(out["photometric_fit"])) / SIGMA_MARGIN)
    if quadric or (quadric is None and curved):
        out["quadric_fit"] = _guarded(
            "quadric_fit", quadric_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm, misfit_sigma=misfit_sigma)
    if cubic or (cubic is None and curved and _several_lights(rig)):
        out["cubic_patch_fit"] = _guarded(
            "cubic_patch_fit", cubic_patch_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm, misfit_sigma=bool(cubic))
    for name, r in out.items():
        out[name] = released(r)
    return out


def colour_fit_applies(image, response) -> bool:
    """Whether the photometric fit runs on a frame's three linear channels (the tissue's body
    colours projected out, :func:`~simtest.reconstruct.lightaware.colour.specular_image`): an RGB
    frame with a sensor response that shows no JPEG block grid
    (:func:`~simtest.reconstruct.jpeg.jpeg_grid`). A JPEG's chroma is subsampled (4:2:0) and
    blocky, and the projection is a colour difference: on the endoscope suite's colon wall at
    JPEG quality 50 to 75 the projected fits passed 6 to 17 deg off, where the darkest channel's
    misfit and the BP ray stood."""
    img = np.asarray(image)
    if response is None or img.ndim != 3:
        return False
    return img.dtype != np.uint8 or jpeg_grid(img) is None


def bp_error_depth_mm(r: LightAwareEstimate, nominal_depth_mm: float) -> float:
    """The depth at which :func:`bp_ray_error_deg` is read next to the fit ``r``, mm: its depth;
    without one, the farthest depth it cannot exclude (``depth_range_mm``, :func:`quadric_fit`
    under one light), where the BP ray's error is least; else ``nominal_depth_mm``.

    Why not the fit's own depth where it is not vouched for: under one light the quadric's depth
    is the one at which the light's offset stands in for the surface's third-order shape (57 %
    short on the ``lightaware-curved`` liver at epsilon/d 0.1), and the BP ray's error read there
    was 6.7 deg where it erred 2.9, which kept a quadric 3.8 deg off; nor the nominal 20 mm,
    which on that liver (63.6 mm away) says 8.9 deg.
    """
    if r.depth_mm is not None:
        return float(r.depth_mm)
    if r.depth_range_mm is not None:
        return float(r.depth_range_mm[1])
    return float(nominal_depth_mm)


def _isocurve_isophotes(gray, big: Roi, bp_uv) -> tuple[list[np.ndarray], list[float]]:
    """The isophotes :func:`isocurve_fit` is given (module docstring, "Isophotes of the isocurve
    fit"): at each of :data:`ISOCURVE_ISOVALUES` of the BP's height above the median of the
    ROI's border, the closed contour about the BP, its points refined onto the image's cubic
    spline; levels whose contour is cut or too short are left out.

    Returns
    -------
    (list of ndarray of shape (N_k, 2), list of float)
        The points (u, v), px, and their isovalues.
    """
    vals = np.asarray(gray[big.slices], dtype=np.float64)
    border = np.concatenate([vals[0], vals[-1], vals[:, 0], vals[:, -1]])
    base = float(np.median(border))
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
        pts.append(refine_isophote_points(vals, level, iso.points_uv, origin))
        ts.append(t)
    return pts, ts


def depth_within_ceiling(r: LightAwareEstimate) -> LightAwareEstimate:
    """``r`` with its depth withdrawn when its relative 1-sigma exceeds the ceiling.

    Parameters
    ----------
    r : LightAwareEstimate
        A fit's result.

    Returns
    -------
    LightAwareEstimate
        ``r`` itself when it gives no depth or the depth's relative 1-sigma (the larger of
        ``depth_sigma_mm / depth_mm`` and ``depth_rel_sigma``; a depth without sigma counts as
        unbounded) is at most :data:`DEPTH_REL_SIGMA_CEILING`; else a copy without depth,
        depth sigma, distance and per-light depths, an ``ok`` status turned
        ``depth_not_observable`` (module docstring, "Depth ceiling"). The normal is kept, and so
        are the per-light normals with their sigmas, which carry the depth's variance (rule 3
        may recommend them).
    """
    if r.depth_mm is None:
        return r
    rel = (r.depth_sigma_mm / r.depth_mm if r.depth_sigma_mm is not None and r.depth_mm > 0
           else math.inf)
    if r.depth_rel_sigma is not None:
        rel = max(rel, r.depth_rel_sigma)
    if rel <= DEPTH_REL_SIGMA_CEILING:
        return r
    detail = f"relative depth sigma {rel:.3g} > ceiling {DEPTH_REL_SIGMA_CEILING}"
    return r.without_depth("depth_not_observable" if r.ok else r.status,
                           f"{r.detail}; {detail}" if r.detail else detail)


def bp_ray_error_deg(ray, depth_mm: float, rig: LightRig) -> float:
    """The BP ray's expected error, degrees: half the angle each light subtends from the camera at
    the point ``depth_mm`` along ``ray``, averaged over the rig's lights by intensity.

    The BP is where the normal bisects the directions to the camera and to the light, so the BP
    ray (the direction to the camera) is off the normal by half the angle between them; exact
    for a plane and one light. For a rig of several lights each light's highlight has its own
    BP, and a merged highlight's BP lies between them: the half angles' mean, not the half angle
    of the mean light (which is 0 for guides either side of the lens, where the BP ray errs by
    2 to 2.5 deg on the endoscope suite's flat mucosa).

    Parameters
    ----------
    ray : array_like of shape (3,)
        Unit viewing ray of the BP, camera frame.
    depth_mm : float
        Distance of the specular point along the ray, mm, > 0.
    rig : LightRig
        The lights (their intensities weight the mean).

    Returns
    -------
    float
        Degrees, in [0, 90].
    """
    X = float(depth_mm) * np.asarray(ray, dtype=np.float64)
    to_cam = -X / np.linalg.norm(X)
    L, w, _, _ = _la.model._rig_arrays(rig)
    half = []
    for Lj in L:
        to_light = Lj - X
        nl = np.linalg.norm(to_light)
        if not nl > 0:
            return 90.0
        c = float(np.clip(to_cam @ (to_light / nl), -1.0, 1.0))
        half.append(0.5 * math.degrees(math.acos(c)))
    return float(np.average(half, weights=w))


def _stated_sigma(r: LightAwareEstimate) -> float | None:
    """The ``normal_sigma_deg`` a recommendation drawn from ``r`` states: the fit's own, or with
    a normal per light (``light_normals``) the largest of it and theirs
    (``light_normal_sigmas_deg``), so that it covers every normal the recommendation gives (a
    per-light truth is compared with that light's normal, whose sigma also carries the
    curvature's: on the two-light spheres and cylinders 20 to 40 times the apex's)."""
    sig = r.normal_sigma_deg
    ls = r.light_normal_sigmas_deg
    if sig is None or r.light_normals is None or ls is None:
        return sig
    ls = np.asarray(ls, dtype=np.float64)
    if not np.isfinite(ls).all():
        return None  # a light's normal without a sigma: none is stated
    return float(max(sig, float(ls.max())))


def _confirmed_plane(est, pho: LightAwareEstimate | None, quad: LightAwareEstimate | None) -> float | None:
    """Rule 4 (module docstring): the stated sigma ``g + s_q`` of a misfitting plane's normal that
    the quadric's normal confirms, or None where it does not (no misfitting plane normal, no
    quadric normal with a stated sigma below 90 deg, the two more than s_q apart, or twice
    ``g + s_q`` not below the BP ray's expected error)."""
    if pho is None or pho.status != "plane_misfit" or not pho.has_normal:
        return None
    if quad is None or not quad.has_normal:
        return None
    s_q = _stated_sigma(quad)
    if s_q is None or not s_q < 90.0:
        return None
    gap = _angle_deg(pho.normal, quad.normal)
    if gap > s_q:
        return None
    sigma = gap + s_q
    return sigma if SIGMA_MARGIN * sigma < _bp_ray_error_beside(est, pho) else None


def _bp_ray_error_beside(est, r: LightAwareEstimate) -> float:
    """The BP ray's error that rules 3 and 4 compare a fit's stated sigma with, degrees: its
    expected error next to the fit (``r.bp_ray_error_deg``; 0 where not set), and at least half
    the angle between the BP ray and the fit's normal (module docstring, rule 3)."""
    expected = r.bp_ray_error_deg if r.bp_ray_error_deg is not None else 0.0
    return max(expected, 0.5 * _angle_deg(est.bp_ray, r.normal))


def _angle_deg(a, b) -> float:
    """Angle between two directions, degrees (0 where either is missing)."""
    if a is None or b is None:
        return 0.0
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c = float(a @ b) / float(np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _guarded(name: str, fit, *args, **kwargs) -> LightAwareEstimate:
    """``fit(*args, **kwargs)``, or a ``not_converged`` estimate named ``name`` when the solver
    refuses the highlight (scipy raises ValueError for residuals that are not finite at the
    start; a singular or overflowing model raises LinAlgError or an ArithmeticError): one
    highlight's failure is a status, never the frame's."""
    try:
        return fit(*args, **kwargs)
    # ArithmeticError: FloatingPointError, OverflowError and a ZeroDivisionError of a fit run off
    except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
        return LightAwareEstimate(name, "not_converged", f"{type(exc).__name__}: {exc}")


def with_light_aware(image, estimates, camera, rig: LightRig | None, *, on_highlight=None,
                     fit_rejected: bool = False, workers: int = 1, **kwargs) -> list:
    """The estimates with their light-aware results attached (``light_aware``).

    Nothing is run, and the estimates are returned unchanged, without a rig or with every light at
    the camera centre (the cone axes and the BP ray are then the estimators of choice, module
    docstring). By default only the accepted highlights (status ``ok``) are fitted: a rejected
    candidate keeps its status whatever its fits give, so its normal is not one to use, and on a
    whole frame the rejected candidates' fits are most of its time and end in misfits
    (``docs/decisions/light-aware-recommendation.md``). With ``fit_rejected`` every candidate the
    paper's ellipse rejected is fitted too (the fits need no ellipse: a two-light rig's lobes that
    merge into one highlight, or the harness scoring the estimators on every rendered highlight it
    matched), but never those whose status says they are no specular highlight of the tissue
    (:data:`NOT_FITTED`).

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
        Called as ``on_highlight(done, total)`` after each highlight's fits (the command line's
        progress bar: the curved fits take up to seconds per highlight).
    fit_rejected : bool, optional
        Fit also the candidates rejected for a reason other than :data:`NOT_FITTED` (default: the
        accepted ones only).
    workers : int
        Worker processes the highlights' fits are shared among (1: in this process). Each
        highlight's fits read the image in its own ROI only, so the results are the same, bit for
        bit, whatever the number (``tests/test_lightaware_workers.py``); the image, camera, rig
        and arguments go to each worker once, the highlights one by one. This process and the
        workers run BLAS on one thread each (:func:`simtest._threads.one_thread_each`), with one
        worker too.
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
    def fitted(est) -> bool:
        return est.ok or (fit_rejected and est.status not in NOT_FITTED)

    if kwargs.get("response") is not None and "linear" not in kwargs:
        kwargs = dict(kwargs, linear=kwargs["response"].linearize(np.asarray(image)))
    if "colour" not in kwargs:
        kwargs = dict(kwargs, colour=colour_fit_applies(image, kwargs.get("response")))
    out = list(estimates)
    todo = [i for i, est in enumerate(out) if fitted(est)]
    # the others are marked with no fits ({}): under a rig off the camera centre the co-located
    # estimators' normals are not recommended (rule 1: the BP ray), as for a fitted highlight
    # whose fits all fail (a rejected candidate with a joint cone axis would otherwise get it)
    skipped = set(range(len(out))).difference(todo)
    for i in sorted(skipped):
        if out[i].light_aware is None:
            out[i] = dataclasses.replace(out[i], light_aware={})
    # one BLAS thread here as in the workers: a product summed over many pixels on several
    # threads differs in its last bits, which a fit's iterations carry to its results
    with one_thread_each():
        if workers > 1 and len(todo) > 1:
            with worker_pool(min(workers, len(todo)), initializer=_fit_context,
                             initargs=(image, camera, rig, kwargs)) as pool:
                futures = {pool.submit(_fits_in_context, out[i]): i for i in todo}
                for done, fut in enumerate(as_completed(futures), 1):
                    i = futures[fut]
                    out[i] = dataclasses.replace(out[i], light_aware=fut.result())
                    if on_highlight is not None:
                        on_highlight(done, len(todo))
            return out
        for done, i in enumerate(todo, 1):
            out[i] = dataclasses.replace(out[i], light_aware=light_aware_estimates(image, out[i], camera,
                                                                                  rig, **kwargs))
            if on_highlight is not None:
                on_highlight(done, len(todo))
    return out


#: A worker's image, camera, rig and arguments of :func:`with_light_aware` (:func:`_fit_context`).
_CONTEXT: dict = {}


def _fit_context(image, camera, rig, kwargs) -> None:
    """A worker's initializer: what every highlight's fits share, received once."""
    _CONTEXT.update(image=image, camera=camera, rig=rig, kwargs=kwargs)


def _fits_in_context(est) -> dict[str, LightAwareEstimate]:
    """:func:`light_aware_estimates` of one highlight in a worker (:func:`_fit_context`)."""
    c = _CONTEXT
    return light_aware_estimates(c["image"], est, c["camera"], c["rig"], **c["kwargs"])


def recommend(est) -> Recommendation:
    """The normal recommended for one highlight (module docstring, "Recommendation rule").

    Parameters
    ----------
    est : SpecularityEstimate
        With ``light_aware`` attached by :func:`with_light_aware` when a rig is known.

    Returns
    -------
    Recommendation
    """
    la = getattr(est, "light_aware", None)
    if la is not None:  # a rig off the camera centre is known ({}: no fit ran, the BP ray's)
        pho = la.get("photometric_fit")
        plane_fits = pho is None or pho.status != "plane_misfit"
        candidates = []
        for name in LIGHT_AWARE:
            r = la.get(name)
            if r is None or not r.has_normal:
                continue
            if name == "isocurve_fit" and not plane_fits:
                continue
            if name == "cubic_patch_fit" and (r.light_normals is None or len(r.light_normals) < 2):
                continue  # one light (run on request only) or its depth not observable: the
                # patch's third-order shape then trades with the depth, and so does its normal
            if r.status == "ok":
                return Recommendation(np.asarray(r.normal), name, r.depth_mm, _stated_sigma(r),
                                      r.light_normals, r.light_depths_mm)
            candidates.append((name, r))
        # rule 3: a normal whose depth is not observable, where its sigma beats the BP ray's error
        better = [(_stated_sigma(r), i, name, r) for i, (name, r) in enumerate(candidates)
                  if r.status == "depth_not_observable" and _stated_sigma(r) is not None
                  and r.bp_ray_error_deg is not None
                  and SIGMA_MARGIN * _stated_sigma(r) < _bp_ray_error_beside(est, r)]
        if better:
            sigma, _, name, r = min(better)
            return Recommendation(np.asarray(r.normal), name, None, sigma, r.light_normals, None)
        confirmed = _confirmed_plane(est, pho, la.get("quadric_fit"))
        if confirmed is not None:
            return Recommendation(np.asarray(pho.normal), "photometric_fit", None, confirmed)
        return Recommendation(np.asarray(est.bp_ray), "bp_ray")
    for name in COLOCATED_ORDER:
        n = getattr(est, name, None)
        if n is not None:
            return Recommendation(np.asarray(n), name)
    return Recommendation(np.asarray(est.bp_ray), "bp_ray")


def colocated_ranking(results: dict, exclude_sweeps=("light_offset",)) -> list[tuple[str, float, float]]:
    """Rank today's estimators by their errors over a rendered suite's co-located cases.

    Parameters
    ----------
    results : dict
        A harness ``results.json`` document.
    exclude_sweeps : sequence of str
        Sweeps left out (the light offset is not co-located).

    Returns
    -------
    list of (name, mean of case means, median of case means)
        Best first (by the mean), over the cases where every estimator has a mean.
    """
    ests = [e for e in results["suite"]["estimators"] if e in COLOCATED_ORDER]
    skip = {k for sw in results["sweeps"] if sw["name"] in exclude_sweeps for k in sw["cases"]}
    vals: dict[str, list[float]] = {e: [] for e in ests}
    for case in results["cases"]:
        if case["id"] in skip:
            continue
        m = case["metrics"]["estimators"]
        if all(m.get(e, {}).get("mean") is not None for e in ests):
            for e in ests:
                vals[e].append(float(m[e]["mean"]))
    rows = [(e, float(np.mean(v)), float(np.median(v))) for e, v in vals.items() if v]
    return sorted(rows, key=lambda r: r[1])
