"""The light-aware estimators run on detected highlights, and the normal recommended to a user.

:func:`with_light_aware` runs :func:`~simtest.reconstruct.lightaware.isocurve_fit` and
:func:`~simtest.reconstruct.lightaware.photometric_fit` on the highlights that
:func:`~simtest.reconstruct.reconstruct` found, given the scope's light rig, and attaches the results
to each :class:`~simtest.reconstruct.pipeline.SpecularityEstimate` (``light_aware``).
:func:`recommend` then picks one normal per highlight, the ``normal`` of ``estimates.json``.

Recommendation rule
-------------------
Chosen from the harness' measurements on Mitsuba renders (``simtest validate rendered`` and the
``lightaware`` suite), never from ground truth at run time:

1. With a rig whose lights are not all at the camera centre: ``photometric_fit`` when its status
   is ``ok``, else ``cubic_patch_fit`` when ``ok`` (run only with two or more lights at
   different places), else ``quadric_fit`` when ``ok``, else ``isocurve_fit`` when ``ok`` (and
   the plane does not misfit), else ``bp_ray``. On renders of
   planes lit off the camera (the ``lightaware`` suite) the BP ray and every cone estimator err by
   about 24 deg per unit epsilon/d (they estimate the direction of the BP, not the normal); the
   photometric fit uses every unclipped pixel, the lobe's shape and its position, and errs by
   about a tenth of a degree; the isocurve fit, which sees only the contour points, by several
   times more. A fit whose depth is not observable is not used: with the light off the camera the
   tilt and the distance trade off, so an undetermined distance leaves the normal undetermined
   too (on the curved scenes such fits missed by up to 12 deg). On curved patches the plane
   model trades the curvature for roughness and distance and misses the normal, by more than the
   BP ray on the sphere, while its residual stays near the sensor's noise; its residuals are then
   spatially correlated, which ``photometric_fit`` reports as ``plane_misfit`` (or its fit runs
   off, ``not_converged``). A photometric fit that is not ``ok`` runs ``quadric_fit`` (a curved
   patch, exact on spheres), recommended when its status is ``ok``; then ``isocurve_fit``, unless
   the plane misfits (the isocurve fit is the same plane model, seen through the contours); else
   the BP ray. The quadric is fitted on the highlight's ROI grown 1.5 times, not the plane's
   2.5: on the ``lightaware-curved`` renders the larger ROI took in more of the surface's
   third-order shape, which the fit's depth trades with (``quadric_fit``, Notes), and its
   misfit test passed more wrong patches (on the liver
   mesh at epsilon/d 0.1 the quadric was recommended in 4 of 6 realisations, 3 of them worse
   than the BP ray; with 1.5, in 1 of 6). There the quadric patch beats the BP ray on the
   sphere, cylinder and saddle at epsilon/d 0.1 and 0.3 (medians below 1 deg); on the liver
   mesh it mostly misfits or runs off (BP ray), and where it does not its depth is the one at
   which the light's offset stands in for the surface's third-order shape; on the colon's fold
   streaks it misfits or runs off (BP ray). With two lights at different places (a
   colonoscope's guides either side of the lens) the lobes shift apart as the light offsets
   over the depth say while the surface's shape acts on both alike, so the third-order patch
   fitted to both (``cubic_patch_fit``) fixes the depth with the shape free; on the suite's
   two-light liver renders (``liver_two_lights``, six realisations) its status was ``ok`` on
   every highlight and its median error 0.30 deg at epsilon/d 0.1 per light and 0.09 at 0.3,
   against 2.2 and 8.4 for the BP ray, where the quadric misfits and the plane fit does not
   converge; it
   comes before the quadric, whose depth, with the third-order shape left out, is the one at
   which the offsets stand in for it. With one light it is not run (nor recommended when run
   on request): its depth is then not observable (on the exact sphere and the liver render the
   depth profile is flat within 0.06 of the noise floor's variance; on the suite's one-light
   curved renders its relative depth sigma was 1.8 to 31, against 0.008 to 0.07 on the
   two-light liver), and a fit whose depth is not observable is not used.
   On the colon's fold streaks it misfits or does not converge, and the BP ray is kept. Its
   normal is the apex's (the mean light's specular point); the normal at each light's specular
   point (``light_normals``) is given beside it.
2. Without a rig, or with every light at the camera centre: ``joint_cone_axis`` when at least two
   isophotes succeeded, else ``cone_axis``, else ``bp_ray``. Over the co-located rendered suite the
   joint cone axis has the lowest mean and median error (:func:`colocated_ranking` recomputes the
   ranking from a ``results.json``); the BP ray is better on the curved meshes (liver, colon), the
   cone axes on planes, spheres, cylinders and saddles and wherever the BP is clipped.

``depth_mm`` and ``normal_sigma_deg`` are those of the estimator recommended (None for the cone
axes and the BP ray, which observe neither), and so are ``light_normals`` and
``light_depths_mm`` (``cubic_patch_fit`` only).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from simtest.geometry.lights import LightRig
from simtest.reconstruct._pixels import Roi, uv_to_rc
from simtest.reconstruct.detect import luma
from simtest.reconstruct.lightaware import (
    LightAwareEstimate,
    cubic_patch_fit,
    isocurve_fit,
    photometric_fit,
    quadric_fit,
    refine_isophote_points,
)

__all__ = ["LIGHT_AWARE", "Recommendation", "colocated_ranking", "light_aware_estimates",
           "recommend", "with_light_aware"]

#: The light-aware estimators, in the order of preference of the recommendation rule.
LIGHT_AWARE = ("photometric_fit", "cubic_patch_fit", "quadric_fit", "isocurve_fit")
#: Fallback order without a rig (or with a co-located one).
COLOCATED_ORDER = ("joint_cone_axis", "cone_axis", "bp_ray")


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
        1-sigma angular uncertainty, degrees (None when the estimator gives none).
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
    return rig is not None and not all(lt.position_mm == (0.0, 0.0, 0.0) for lt in rig.lights)


def _several_lights(rig) -> bool:
    """Whether the rig has at least two lights at different places (their lobes can differ)."""
    return rig is not None and len({tuple(lt.position_mm) for lt in rig.lights}) >= 2


def light_aware_estimates(image, est, camera, rig: LightRig, *, nominal_depth_mm: float = 20.0,
                          saturation_level: float | None = None,
                          roi_scale: float = 2.5, quadric_roi_scale: float = 1.5,
                          supersample: int = 1,
                          quadric: bool | None = None,
                          cubic: bool | None = False) -> dict[str, LightAwareEstimate]:
    """Run the light-aware estimators on one detected highlight.

    ``isocurve_fit`` takes the points of every isophote that succeeded (refined onto the cubic
    spline of the image, :func:`~simtest.reconstruct.lightaware.refine_isophote_points`, at the
    level the points sit on) when the rig has one light; ``photometric_fit`` takes the highlight's
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
        (default) when the photometric fit's status is not ``ok`` (a plane misfit, or a plane
        fit that ran off on a curved patch: the recommendation then needs it), False never (the
        harness' oracle inputs keep the plane fit only).
    cubic : bool or None
        Run the third-order patch fit
        :func:`~simtest.reconstruct.lightaware.cubic_patch_fit` on the same ROI as the quadric's:
        True always, False (default: it takes about 1 to 5 s per highlight, against a few ms
        for the others) never, None when the photometric fit's status is not ``ok`` and the rig
        has at least two lights at different places (with one light its depth, and with it the
        normal, is not observable: module docstring); ``simtest reconstruct --cubic-patch``
        asks for None.

    Returns
    -------
    dict
        ``{"isocurve_fit": LightAwareEstimate, "photometric_fit": LightAwareEstimate}`` (the
        isocurve fit is absent when no isophote succeeded), ``"quadric_fit"`` and
        ``"cubic_patch_fit"`` as ``quadric`` and ``cubic`` say.
    """
    img = np.asarray(image)
    if saturation_level is None and img.dtype.kind == "u":
        saturation_level = float(np.iinfo(img.dtype).max)
    gray = luma(img)
    out: dict[str, LightAwareEstimate] = {}
    roi = Roi(*(int(v) for v in est.roi))
    vals = gray[roi.slices]
    origin = np.array([roi.col0, roi.row0], dtype=np.float64)
    isos = [i for i in est.isophotes if i.ok and i.points_uv is not None and len(i.points_uv) >= 6]
    start_n = None
    if isos:
        pts = []
        for iso in isos:
            raw = np.asarray(iso.points_uv, dtype=np.float64)
            level = float(np.median(_spline_values(vals, raw - origin)))
            pts.append(refine_isophote_points(vals, level, raw, origin))
        iso_est = _guarded("isocurve_fit", isocurve_fit, pts, [i.isovalue for i in isos], est.bp_px,
                           camera, rig, nominal_depth_mm=nominal_depth_mm)
        out["isocurve_fit"] = iso_est
        if iso_est.has_normal:
            start_n = iso_est.normal
    half = roi_scale * max(roi.shape) / 2.0
    big = Roi.around(est.bp_px, half, img.shape)
    out["photometric_fit"] = _guarded(
        "photometric_fit", photometric_fit, gray[big.slices], (big.col0, big.row0), est.bp_px, camera, rig,
        clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm,
        start_normal=start_n, supersample=supersample)
    near = Roi.around(est.bp_px, quadric_roi_scale * max(roi.shape) / 2.0, img.shape)
    if quadric or (quadric is None and not out["photometric_fit"].ok):
        out["quadric_fit"] = _guarded(
            "quadric_fit", quadric_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm)
    if cubic or (cubic is None and not out["photometric_fit"].ok and _several_lights(rig)):
        out["cubic_patch_fit"] = _guarded(
            "cubic_patch_fit", cubic_patch_fit, gray[near.slices], (near.col0, near.row0), est.bp_px, camera, rig,
            clip_level=saturation_level, nominal_depth_mm=nominal_depth_mm)
    return out


def _guarded(name: str, fit, *args, **kwargs) -> LightAwareEstimate:
    """``fit(*args, **kwargs)``, or a ``not_converged`` estimate named ``name`` when the solver
    refuses the highlight (scipy raises ValueError for residuals that are not finite at the
    start; a singular or overflowing model raises LinAlgError or FloatingPointError): one
    highlight's failure is a status, never the frame's."""
    try:
        return fit(*args, **kwargs)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError, OverflowError) as exc:
        return LightAwareEstimate(name, "not_converged", f"{type(exc).__name__}: {exc}")


def _spline_values(vals, uv_local):
    return map_coordinates(np.asarray(vals, dtype=np.float64), uv_to_rc(uv_local).T, order=3,
                           mode="mirror")


def with_light_aware(image, estimates, camera, rig: LightRig | None, *, on_highlight=None,
                     **kwargs) -> list:
    """The estimates with their light-aware results attached (``light_aware``).

    Nothing is run, and the estimates are returned unchanged, without a rig or with every light at
    the camera centre (the cone axes and the BP ray are then the estimators of choice, module
    docstring); nor for highlights rejected at detection as ``too_small``.

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
    **kwargs
        Passed to :func:`light_aware_estimates`.

    Returns
    -------
    list of SpecularityEstimate
    """
    if not _offset_rig(rig):
        return list(estimates)
    out = []
    todo = sum(est.status != "too_small" for est in estimates)
    done = 0
    for est in estimates:
        if est.status == "too_small":
            out.append(est)
            continue
        out.append(dataclasses.replace(est, light_aware=light_aware_estimates(image, est, camera, rig,
                                                                             **kwargs)))
        done += 1
        if on_highlight is not None:
            on_highlight(done, todo)
    return out


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
    la = getattr(est, "light_aware", None) or {}
    if la:
        pho = la.get("photometric_fit")
        plane_fits = pho is None or pho.status != "plane_misfit"
        for name in LIGHT_AWARE:
            r = la.get(name)
            if name == "isocurve_fit" and not plane_fits:
                continue
            if name == "cubic_patch_fit" and (r is None or r.light_normals is None
                                              or len(r.light_normals) < 2):
                continue  # one light: run on request only, its depth is then not observable
            if r is not None and r.has_normal and r.status == "ok":
                return Recommendation(np.asarray(r.normal), name, r.depth_mm, r.normal_sigma_deg,
                                      r.light_normals, r.light_depths_mm)
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
