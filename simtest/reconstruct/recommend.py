"""The light-aware estimators run on detected highlights, and the normal recommended to a user.

:func:`~simtest.reconstruct.light_fits.with_light_aware` attaches the light-aware fits to each
:class:`~simtest.reconstruct.assemble.SpecularityEstimate` (``light_aware``); :func:`recommend` then
picks one normal per highlight, the ``normal`` of ``estimates.json``.

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
   off, ``not_converged``); such a fit (:data:`~simtest.reconstruct.light_fits.CURVED_FIT_AFTER`)
   runs ``quadric_fit`` (a curved patch, exact on spheres), recommended when its status is ``ok``; then
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

Isophotes of the isocurve fit: :mod:`simtest.reconstruct.light_fits`.

``depth_mm`` and ``normal_sigma_deg`` are those of the estimator recommended (None for the cone
axes and the BP ray, which observe neither), and so are ``light_normals`` and
``light_depths_mm`` (``cubic_patch_fit`` only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simtest.decisions import DEPTH_RELEASE_REL_SIGMA as DEPTH_REL_SIGMA_CEILING, ISOCURVE_ISOVALUES, SIGMA_MARGIN
from simtest.geometry.lights import LightRig
from simtest.reconstruct import lightaware as _la
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.reconstruct.registry import names

__all__ = ["DEPTH_REL_SIGMA_CEILING", "ISOCURVE_ISOVALUES", "LIGHT_AWARE", "SIGMA_MARGIN", "Recommendation",
           "bp_error_depth_mm", "bp_ray_error_deg", "colocated_ranking", "depth_within_ceiling", "recommend"]

#: The light-aware estimators, in the order of preference of the recommendation rule.
LIGHT_AWARE = names("light_aware", ranked=True)
#: Fallback order without a rig (or with a co-located one).
COLOCATED_ORDER = names("isophote", "baseline", ranked=True)


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

def recommend(est) -> Recommendation:
    """The normal recommended for one highlight (module docstring, "Recommendation rule").

    Parameters
    ----------
    est : SpecularityEstimate
        With ``light_aware`` attached by :func:`~simtest.reconstruct.light_fits.with_light_aware` when a rig is known.

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
        fused = la.get("rig_centroid")  # rule 5
        if fused is not None and SIGMA_MARGIN * fused.normal_sigma_deg < fused.bp_ray_error_deg:
            return Recommendation(np.asarray(fused.normal), "rig_centroid", None, fused.normal_sigma_deg)
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
