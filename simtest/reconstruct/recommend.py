"""The normal recommended to a user from the light-aware estimators run on detected highlights.

:func:`~simtest.reconstruct.light_fits.with_light_aware` attaches the light-aware fits to each
estimate (``light_aware``); :func:`recommend` picks one normal per highlight, the ``normal`` of
``estimates.json``.

Recommendation rule
-------------------
Chosen on the harness' tuning renders, never from ground truth at run time; the measurements
behind each rule are in ``docs/decisions/light-aware-recommendation.md``.

0. Two guides' clipped tops fused into one highlight (:mod:`~simtest.reconstruct.rig_lobes`):
   ``rig_pair``, the plane the two tops fix as a stereo pair
   (:func:`~simtest.reconstruct.rig_pairs.pair_plane`).
1. With a rig whose lights are not all at the camera centre, the first ``ok`` fit of
   ``photometric_fit``, ``cubic_patch_fit`` (two lights at different places), ``quadric_fit``,
   ``isocurve_fit`` (unless the plane misfits) whose stated sigma beats the BP ray
   (:func:`_beats_bp_ray`); else rules 3 to 5; else ``bp_ray`` (off the camera the BP ray and cone
   axes give the BP's direction, not the normal).
2. Without a rig or with every light at the camera centre: ``joint_cone_axis`` (two isophotes),
   else ``cone_axis``, else ``bp_ray``.
3. The fit of least stated sigma (:func:`_stated_sigma`) whose depth is not observable (misfit
   tests passed), where :data:`SIGMA_MARGIN` times it is below the BP ray's expected error
   (:func:`_bp_ray_error_beside`); ``depth_mm`` None. Under two or more guides such a fit cannot
   tell which guide lit the lobe unless the image shows the other guide's highlight where its normal
   puts it: its sigma then counts the spread of those hypotheses (:func:`with_guide_spread`), about
   twice the BP ray's own error, and the BP ray is kept.
4. A ``plane_misfit`` photometric fit whose normal the quadric confirms (angle g <= the quadric's
   sigma s_q < 90 deg), :data:`SIGMA_MARGIN` times ``g + s_q`` below the BP ray's expected error;
   ``depth_mm`` None (micro-relief reads as curvature while the plane's normal stays near the macro normal).
5. A fused lobe of the rig's lights (:mod:`~simtest.reconstruct.rig_centroid`): ``rig_centroid``,
   the bisector towards the lights' centroid, when :data:`SIGMA_MARGIN` times its sigma is below
   the BP ray's expected error; ``depth_mm`` None.

Depth ceiling
-------------
A depth is released (``depth_mm``, status ``ok``) only when its relative 1-sigma is at most
:data:`DEPTH_REL_SIGMA_CEILING` (:func:`depth_within_ceiling`), else withdrawn
(``depth_not_observable``), the normal kept.

``depth_mm``, ``normal_sigma_deg``, ``light_normals`` and ``light_depths_mm`` are those of the
estimator recommended (None where it gives none).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from simtest.decisions import DEPTH_RELEASE_REL_SIGMA as DEPTH_REL_SIGMA_CEILING, ISOCURVE_ISOVALUES, SIGMA_MARGIN
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.lights import LightRig
from simtest.reconstruct import lightaware as _la
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.reconstruct.lightaware.bisector import light_bisectors
from simtest.reconstruct.registry import names

__all__ = ["DEPTH_REL_SIGMA_CEILING", "ISOCURVE_ISOVALUES", "LIGHT_AWARE", "SIGMA_MARGIN", "Recommendation",
           "bp_error_depth_mm", "bp_ray_error_deg", "depth_within_ceiling", "guide_spread_deg", "recommend",
           "with_guide_spread", "without_guide_spread", "normals_from", "counts_text"]

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
        1-sigma angular uncertainty, degrees (None: not given); with ``light_normals`` the largest.
    light_normals : ndarray of shape (J, 3) or None
        The unit normal at each of the rig's J lights' specular points (``cubic_patch_fit``).
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
    """The depth, mm, at which :func:`bp_ray_error_deg` is read next to the fit ``r``: its depth, else
    the farthest depth it cannot exclude (``depth_range_mm``), else ``nominal_depth_mm``.
    """
    if r.depth_mm is not None:
        return float(r.depth_mm)
    if r.depth_range_mm is not None:
        return float(r.depth_range_mm[1])
    return float(nominal_depth_mm)

def depth_within_ceiling(r: LightAwareEstimate) -> LightAwareEstimate:
    """``r`` (a fit's result) with its depth withdrawn when its relative 1-sigma exceeds the ceiling.

    Returns
    -------
    LightAwareEstimate
        ``r`` where it gives no depth or the depth's relative 1-sigma (a depth without sigma:
        unbounded) is within the ceiling; else a copy without depth, depth sigma, distance and
        per-light depths, ``ok`` turned ``depth_not_observable`` (module docstring, "Depth
        ceiling"), its normals and their sigmas kept.
    """
    if r.depth_mm is None:
        return r
    rel = r.depth_sigma_mm / r.depth_mm if r.depth_sigma_mm is not None and r.depth_mm > 0 else math.inf
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

    The BP ray is off the normal by half the angle between camera and light (exact for a plane and
    one light); for a rig, the half angles' mean, as each light's lobe has its own BP.

    Parameters
    ----------
    ray : array_like of shape (3,)
        Unit viewing ray of the BP, camera frame.
    depth_mm : float
        Distance of the specular point along the ray, mm, > 0.
    rig : LightRig

    Returns
    -------
    float
        Degrees, in [0, 90].
    """
    X = float(depth_mm) * np.asarray(ray, dtype=np.float64)
    L, w, _, _ = _la.model._rig_arrays(rig)
    to_lights = L - X
    if not np.all(np.linalg.norm(to_lights, axis=1) > 0):
        return 90.0
    return float(np.average(0.5 * angle_between_deg(-X, to_lights), weights=w))


#: The detail :func:`with_guide_spread` adds (the spread, degrees).
_SPREAD_NOTE = "which guide lit the lobe not resolved: normals {:.2g} deg apart counted in the sigma"


def guide_spread_deg(ray, normal, depth_mm: float, rig: LightRig) -> float:
    """How far a normal may be off where one lobe could be any guide's: the largest angle, degrees,
    between ``normal`` and the bisector of the directions to the camera and to one light of the rig,
    at the point ``depth_mm`` along ``ray`` (the normal of a plane whose specular point for that light
    alone is the BP).

    A fit that cannot pin the depth under two or more guides cannot tell which guide lit its lobe, or
    whether both did (at a larger depth the guides' lobes fuse): those hypotheses' normals differ by
    about half the angle the guides subtend, twice the BP ray's own error (:func:`bp_ray_error_deg`).

    Parameters
    ----------
    ray, depth_mm, rig
        As in :func:`bp_ray_error_deg`.
    normal : array_like of shape (3,)
        Unit normal, camera frame, facing the camera.

    Returns
    -------
    float
        Degrees, in [0, 180].
    """
    halves = light_bisectors(float(depth_mm) * np.asarray(ray, dtype=np.float64), rig)
    return float(np.max(angle_between_deg(halves, normal)))


def with_guide_spread(r: LightAwareEstimate, ray, depth_mm: float, rig: LightRig, *,
                      unresolved: bool | None = None) -> LightAwareEstimate:
    """``r`` with :func:`guide_spread_deg` added in quadrature to its ``normal_sigma_deg`` (set as
    ``guide_spread_deg``) where it gives a normal and its sigma, which guide lit its lobe is
    ``unresolved`` (None: where its depth is not observable) and the rig has two or more lights at
    different places; else ``r``. Rules 1 and 3 (module docstring) then keep the BP ray.
    """
    unresolved = r.status == "depth_not_observable" if unresolved is None else unresolved
    if (not unresolved or not r.has_normal or r.normal_sigma_deg is None
            or not rig.has_separate_lights or r.guide_spread_deg is not None):
        return r
    spread = guide_spread_deg(ray, r.normal, depth_mm, rig)
    return dataclasses.replace(r, normal_sigma_deg=float(math.hypot(r.normal_sigma_deg, spread)),
                               guide_spread_deg=spread).noted(_SPREAD_NOTE.format(spread))


def without_guide_spread(r: LightAwareEstimate, how: str) -> LightAwareEstimate:
    """``r`` without the spread :func:`with_guide_spread` counted, where the image resolves the guides
    (``how``: where it does, for the detail)."""
    if r.guide_spread_deg is None:
        return r
    sigma = math.sqrt(max(0.0, r.normal_sigma_deg**2 - r.guide_spread_deg**2))
    detail = r.detail.replace(_SPREAD_NOTE.format(r.guide_spread_deg), how)
    return dataclasses.replace(r, normal_sigma_deg=sigma, guide_spread_deg=None, detail=detail)


def _stated_sigma(r: LightAwareEstimate) -> float | None:
    """The ``normal_sigma_deg`` a recommendation from ``r`` states (with per-light normals, the largest)."""
    sig, ls = r.normal_sigma_deg, r.light_normal_sigmas_deg
    if sig is None or r.light_normals is None or ls is None:
        return sig
    ls = np.asarray(ls, dtype=np.float64)
    if not np.isfinite(ls).all():
        return None  # a light's normal without a sigma: none is stated
    return float(max(sig, float(ls.max())))


def _confirmed_plane(est, pho: LightAwareEstimate | None, quad: LightAwareEstimate | None) -> float | None:
    """Rule 4 (module docstring): the stated sigma ``g + s_q`` of a misfitting plane's normal that
    the quadric's normal confirms, or None where it does not."""
    if pho is None or pho.status != "plane_misfit" or not pho.has_normal or quad is None or not quad.has_normal:
        return None
    s_q = _stated_sigma(quad)
    if s_q is None or not s_q < 90.0:
        return None
    gap = _angle_deg(pho.normal, quad.normal)
    sigma = gap + s_q
    return sigma if gap <= s_q and SIGMA_MARGIN * sigma < _bp_ray_error_beside(est, pho) else None


def _beats_bp_ray(est, r: LightAwareEstimate) -> bool:
    """Whether an ``ok`` fit's stated sigma is small enough to be recommended over the BP ray (rule 1): below
    :data:`SIGMA_MARGIN` times the BP ray's expected error where the fit states both (a fit whose normal misses the
    law of reflection at the BP by degrees states that miss in its sigma, :func:`~simtest.reconstruct.rig_centroid.
    light_aware_with_rig`); any ok fit where it states neither."""
    sigma = _stated_sigma(r)
    return sigma is None or r.bp_ray_error_deg is None or SIGMA_MARGIN * sigma < _bp_ray_error_beside(est, r)


def _bp_ray_error_beside(est, r: LightAwareEstimate) -> float:
    """The BP ray's error, degrees, that rules 3 and 4 compare with: ``r.bp_ray_error_deg`` (0 where not
    set), at least half the angle between the BP ray and the fit's normal.
    """
    expected = r.bp_ray_error_deg if r.bp_ray_error_deg is not None else 0.0
    return max(expected, 0.5 * _angle_deg(est.bp_ray, r.normal))


def _angle_deg(a, b) -> float:
    """Angle between two directions, degrees (0 where either is missing)."""
    return 0.0 if a is None or b is None else float(angle_between_deg(a, b))


def recommend(est) -> Recommendation:
    """The normal recommended for one highlight (module docstring, "Recommendation rule").

    Parameters
    ----------
    est : SpecularityEstimate
        With ``light_aware`` attached (:func:`~simtest.reconstruct.light_fits.with_light_aware`).

    Returns
    -------
    Recommendation
    """
    la = getattr(est, "light_aware", None)
    if la is not None:  # a rig off the camera centre is known ({}: no fit ran, the BP ray's)
        pair = la.get("rig_pair")  # rule 0
        if pair is not None and pair.has_normal:
            return Recommendation(np.asarray(pair.normal), "rig_pair", pair.depth_mm, pair.normal_sigma_deg)
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
                continue  # one light, or its depth not observable: its shape trades with the depth
            if r.status == "ok" and _beats_bp_ray(est, r):
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
        if fused is not None and None not in (fused.normal_sigma_deg, fused.bp_ray_error_deg) \
                and SIGMA_MARGIN * fused.normal_sigma_deg < fused.bp_ray_error_deg:
            return Recommendation(np.asarray(fused.normal), "rig_centroid", None, fused.normal_sigma_deg)
        return Recommendation(np.asarray(est.bp_ray), "bp_ray")
    for name in COLOCATED_ORDER:
        n = getattr(est, name, None)
        if n is not None:
            return Recommendation(np.asarray(n), name)
    return Recommendation(np.asarray(est.bp_ray), "bp_ray")


def normals_from(estimates) -> dict[str, int]:
    """How many of the ``ok`` estimates' recommended normals each estimator gives (:func:`recommend`'s
    ``normal_from``), in the order the estimators first appear: what ``simtest reconstruct`` reports."""
    return dict(Counter(e.recommended.normal_from for e in estimates if e.ok))


def counts_text(counts: dict[str, int]) -> str:
    """``"name count, ..."`` of ``counts``, most first (ties by name): how the command line's summary and
    the overlay's legend write counts."""
    return ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
