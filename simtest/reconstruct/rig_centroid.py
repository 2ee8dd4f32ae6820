"""A rig's lobes fused into one highlight: the normal bisecting the camera and the centroid light.

Where the lights' specular lobes lie closer than their width they add up to one lobe with one
maximum, and no fit tells the depth (the lobes' offsets, which carry it, are below the lobe's width).

Derivation. Lobes of one shape (one surface) at the lights' specular points p_j (image, px) with
amplitudes a_j (the irradiance each light gives there: intensity, profile, falloff), A = sum a_j,
peak at their amplitude-weighted mean m = sum a_j p_j / A plus the bias
``y = -sum_j a_j |e_j|^2 e_j / (2 A s^2)`` (e_j = p_j - m; a Gaussian lobe of sigma s): the first
order vanishes (sum a_j e_j = 0) and so does the second (the lobe is symmetric), so ``|y|`` is of
third order in the lobes' offsets over their width. And m is the specular point of the centroid
light C = sum a_j L_j / A to second order in the lights' offsets over the depth. So the normal at
the BP bisects the directions to the camera and to C
(:func:`~simtest.reconstruct.lightaware.bisector`): the BP ray where C is the camera centre (guides
either side of the lens), else a normal that depends on the depth.

Stated sigma (``normal_sigma_deg``): the largest angle between the normal at the depth used and at
the ends of its range (a fit's released depth +- its 1-sigma; a fit's ``depth_range_mm``; else the
nominal depth, over the working range :data:`~simtest.decisions.PAIR_DEPTH_MIN_MM` to
:data:`~simtest.decisions.PAIR_DEPTH_MAX_MM`), plus the fusion bias: the angle the BP's ray turns
through when the BP moves by ``y + m - c`` (c the centroid's specular point), which is the angle
the normal turns through (exactly under a co-located light).

One fused lobe: the lights' specular points predicted for the plane of this normal and depth
(:func:`~simtest.reconstruct.rig_lobes.guide_specular_points`) lie in the highlight's bright region
(:data:`~simtest.decisions.FUSED_LOBE_LEVEL`), at most
:data:`~simtest.decisions.FUSED_SEPARATION_MAX` lobe sigmas apart. The sigma s is read off the
region's width across its long axis (the lobes' offsets do not widen it): a Gaussian's region above
the level q of its peak is a disc of radius ``s sqrt(-2 ln q)``, whose coordinate variance is a
quarter of that radius squared.
"""

from __future__ import annotations

import math

import numpy as np

from simtest.decisions import FUSED_LOBE_LEVEL, FUSED_SEPARATION_MAX, PAIR_DEPTH_MAX_MM, PAIR_DEPTH_MIN_MM
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.detect_pixels import luma
from simtest.reconstruct.lightaware import LightAwareEstimate, bisector
from simtest.reconstruct.lightaware.model import _rays
from simtest.reconstruct.recommend import LIGHT_AWARE, _angle_deg, bp_error_depth_mm, bp_ray_error_deg
from simtest.reconstruct.rig_lobes import _bright_region, _inside, guide_specular_points

__all__ = ["rig_centroid"]


def _amplitudes(rig: LightRig, X: np.ndarray) -> np.ndarray:
    """The irradiance each light gives at the point ``X`` (mm, camera frame), relative."""
    out = []
    for lt in rig.lights:
        d = X - lt.position
        r = float(np.linalg.norm(d))
        a = lt.intensity * max(d[2] / r, 0.0) ** lt.profile_exponent
        out.append(a / (r * r) if lt.falloff == "inverse_square" else a)
    return np.asarray(out)


def _centroid_normal(bp, camera, rig: LightRig, ray: np.ndarray, depth_mm: float) -> np.ndarray:
    """The bisector at ``depth_mm`` along ``ray`` for the rig's centroid light there."""
    a = _amplitudes(rig, depth_mm * ray)
    c = a @ rig.positions / a.sum()
    return bisector(bp, camera, LightRig((Light(tuple(c.tolist())),)), depth_mm).normal


def _depth_span(fits: dict, nominal_depth_mm: float) -> tuple[float, float, float, float]:
    """``(depth, near, far, depth of the BP ray's error)``, mm: the first released depth of the
    recommendation's fits with its 1-sigma, else a fit's depth range, else the nominal depth over
    the working range (module docstring)."""
    for r in (fits.get(name) for name in LIGHT_AWARE):
        if r is not None and r.depth_mm is not None and r.depth_sigma_mm is not None:
            d, s = float(r.depth_mm), float(r.depth_sigma_mm)
            return d, max(d - s, 1e-3 * d), d + s, d
    for r in (fits.get(name) for name in LIGHT_AWARE):
        if r is not None and r.depth_range_mm is not None:
            near, far = (float(v) for v in r.depth_range_mm)
            return math.sqrt(near * far), near, far, bp_error_depth_mm(r, nominal_depth_mm)
    return nominal_depth_mm, PAIR_DEPTH_MIN_MM, PAIR_DEPTH_MAX_MM, nominal_depth_mm


def rig_centroid(image, est, camera, rig: LightRig, fits: dict, nominal_depth_mm: float = 20.0
                 ) -> LightAwareEstimate | None:
    """The normal of a highlight that is one fused lobe of the rig's lights (module docstring).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        The frame the highlight was detected in.
    est : SpecularityEstimate
        The highlight (its BP, ROI and BP intensity).
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K or a camera model.
    rig : LightRig
        The scope's lights, camera frame, mm.
    fits : dict
        The highlight's light-aware fits, released
        (:func:`~simtest.reconstruct.light_fits.light_aware_estimates`), read for a depth.
    nominal_depth_mm : float
        The depth used where no fit gives one, mm.

    Returns
    -------
    LightAwareEstimate or None
        ``"rig_centroid"``, status ``depth_not_observable`` (it estimates no depth): its normal,
        ``normal_sigma_deg`` (module docstring) and ``bp_ray_error_deg`` (the BP ray's error of a
        highlight that is not fused, :func:`~simtest.reconstruct.recommend.bp_ray_error_deg`);
        None where the rig has no two lights at different places, or the highlight is not one
        fused lobe of them.
    """
    if rig is None or not rig.has_separate_lights:
        return None
    depth, near, far, at = _depth_span(fits, nominal_depth_mm)
    bp = np.asarray(est.bp_px, dtype=np.float64)
    ray = _rays(camera, bp[None])[0]
    n = _centroid_normal(bp, camera, rig, ray, depth)
    pts = guide_specular_points(camera, rig, n, -float(n @ (depth * ray)))
    region = _bright_region(luma(np.asarray(image)), est)
    if region is None or not _inside(region, pts).all():
        return None
    rr, cc = np.nonzero(region[0])
    if len(rr) < 3:
        return None
    spread = float(np.linalg.eigvalsh(np.cov(np.vstack([cc, rr]).astype(np.float64)))[0])
    s = 2.0 * math.sqrt(max(spread, 1.0 / 12.0)) / math.sqrt(-2.0 * math.log(FUSED_LOBE_LEVEL))
    gaps = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    i, j = np.unravel_index(int(np.argmax(gaps)), gaps.shape)
    apart = float(gaps[i, j])
    t = (pts[j] - pts[i]) / apart if apart > 0 else np.zeros(2)
    off = float((np.array([cc.mean() + region[2], rr.mean() + region[1]]) - bp) @ t)
    if apart > FUSED_SEPARATION_MAX * s or abs(off) > apart / 4.0:
        return None  # two lobes, or the BP at one light's lobe (the region off it by half the gap)
    a = _amplitudes(rig, depth * ray)
    m = a @ pts / a.sum()
    e = pts - m
    y = -(a * (e * e).sum(axis=1)) @ e / (2.0 * a.sum() * s * s)
    bias = _angle_deg(ray, _rays(camera, (m + y)[None])[0])  # the BP moved by m - c + y, c = the BP
    spread_deg = max(_angle_deg(n, _centroid_normal(bp, camera, rig, ray, d)) for d in (near, far))
    return LightAwareEstimate(
        "rig_centroid", "depth_not_observable",
        f"one fused lobe: specular points {apart:.3g} px apart, lobe sigma {s:.3g} px, centred {off:.2g} px off the BP; depth {depth:.3g} mm "
        f"({near:.3g} to {far:.3g}: {spread_deg:.3g} deg), fusion bias {bias:.3g} deg",
        n, normal_sigma_deg=spread_deg + bias, bp_ray_error_deg=bp_ray_error_deg(ray, at, rig))
