"""Curved-patch fits: the quadric patch (:func:`quadric_fit`) and the cubic patch under a rig of
several lights (:func:`cubic_patch_fit`, :func:`patch_depth_profile`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import (
    _mean_light,
    _rays,
    _rig_arrays,
    _roi_grid,
    _roi_samples,
)
from simtest.reconstruct.lightaware.solve import (
    _covariance,
    _hac_covariance,
    _implausible,
    _patch_verdict,
)



def _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N):
    """Where the rays ``t d`` (d (k, 3), camera frame) first meet the quadric patch
    ``z + (k_xx x^2 + 2 k_xy x y + k_yy y^2 + k_zz z^2) / 2 = 0`` in the frame (t1, t2, N) at P0,
    with ``k_zz = (k_xx + k_yy) / 2`` (exact for a sphere): A t^2 + B t + C = 0, the root near
    -C/B in the cancellation-free form.

    Returns
    -------
    ax, ay, az, bx, by, bz : ndarray
        The rays and -P0 in the patch frame.
    t : ndarray
        The ray parameter (inf where there is no root).
    ok : ndarray of bool
        A real, positive, finite root.
    """
    kzz = 0.5 * (kxx + kyy)
    ax, ay, az = d @ t1, d @ t2, d @ N
    bx, by, bz = -(P0 @ t1), -(P0 @ t2), -(P0 @ N)
    A = 0.5 * (kxx * ax * ax + 2 * kxy * ax * ay + kyy * ay * ay + kzz * az * az)
    B = az + (kxx * ax * bx + kxy * (ax * by + ay * bx) + kyy * ay * by + kzz * az * bz)
    C = bz + 0.5 * (kxx * bx * bx + 2 * kxy * bx * by + kyy * by * by + kzz * bz * bz)
    disc = B * B - 4 * A * C
    ok = disc >= 0
    den = B + np.where(B >= 0, 1.0, -1.0) * np.sqrt(np.where(ok, disc, 0.0))
    good_den = np.abs(den) > 1e-15
    t = np.where(good_den, -2 * C / np.where(good_den, den, 1.0), np.inf)
    ok &= (t > 0) & np.isfinite(t)
    return ax, ay, az, bx, by, bz, t, ok

def _patch_lobes(d, X, ns, ok, s, rough, rig_arr):
    """The rig's Phong lobes (N,) seen along rays d (N, 3) on a curved patch: surface points X
    (N, 3), unit normals ns (N, 3), ``ok`` (N,) where the ray meets it, apex depth s (mm, the
    inverse-square falloff's reference) and roughness n; 0 where the ray misses or the patch faces
    away (the image of :func:`_quadric_image` and :func:`_cubic_patch_image`)."""
    L, w, inv_sq, m = rig_arr
    nv = -np.einsum("ij,ij->i", ns, d)
    out = np.zeros(len(d))
    for j in range(len(w)):
        tl = L[j] - X
        r = np.sqrt(np.einsum("ij,ij->i", tl, tl))
        cb = (2.0 * np.einsum("ij,ij->i", ns, tl) * nv + np.einsum("ij,ij->i", tl, d)) / r
        pos = cb > 0
        val = np.where(pos, np.exp(rough * np.log(np.where(pos, cb, 1.0))), 0.0)
        if inv_sq[j]:
            val = val * (s / r) ** 2
        if m[j] > 0:
            val = val * np.maximum((X[:, 2] - L[j, 2]) / r, 0.0) ** m[j]
        out += w[j] * val
    return np.where(ok & (nv > 0), out, 0.0)


def _quadric_image(d, b_ray, p, rig_arr, Lm):
    """Specular image (N,) of the quadric patch ``p`` along rays d (see :func:`quadric_fit`).

    ``p = (a, b, log s, kappa_xx, kappa_xy, kappa_yy, log n)``: the apex is at depth s on the ray
    ``unit(b_ray + a e1 + b e2)``, its normal the bisector there for the light Lm, the shape
    operator ``kappa / s`` in the apex's tangent basis. Rays that miss the patch give 0.
    """
    e1, e2 = plane_basis(b_ray)
    ray0 = unit(b_ray + p[0] * e1 + p[1] * e2)
    s = np.exp(p[2])
    P0 = s * ray0
    N = unit(unit(-P0) + unit(Lm - P0))
    t1, t2 = plane_basis(N)
    kxx, kxy, kyy = p[3] / s, p[4] / s, p[5] / s
    rough = np.exp(p[6])
    # F = z + (k_xx x^2 + 2 k_xy x y + k_yy y^2) / 2 = 0 along the ray X = t d
    kzz = 0.5 * (kxx + kyy)  # the z^2 term: exact for a sphere
    ax, ay, az, bx, by, bz, t, ok = _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N)
    t = np.where(ok, t, s)
    X = d * t[:, None]
    x, y = ax * t + bx, ay * t + by
    z = az * t + bz
    ns = ((1.0 + kzz * z)[:, None] * N[None, :] + (kxx * x + kxy * y)[:, None] * t1
          + (kxy * x + kyy * y)[:, None] * t2)
    ns /= np.sqrt(np.einsum("ij,ij->i", ns, ns))[:, None]
    return _patch_lobes(d, X, ns, ok, s, rough, rig_arr), N


@dataclass
class _PatchProblem:
    """A ROI's samples and what a curved patch's variable-projection fit of them needs
    (:func:`quadric_fit`, :func:`cubic_patch_fit`): ``y`` (m,) the unclipped intensities over
    their largest magnitude, ``d`` (m, 3) their pixel rays, ``b_ray`` (3,) the BP's ray,
    ``rig_arr`` and ``Lm`` the rig's arrays and mean light, ``A`` (m, 4) the linear part's design
    (column 0 the patch image, then a constant and a plane in the offsets from the BP over the ROI
    size), ``sel``, ``step`` and ``shape`` the samples' place in the ROI grid, ``px_per_rad`` the
    image's scale at the BP."""

    y: np.ndarray
    d: np.ndarray
    b_ray: np.ndarray
    rig_arr: object
    Lm: np.ndarray
    A: np.ndarray
    sel: np.ndarray
    step: int
    shape: tuple
    px_per_rad: float

    def residual(self, image) -> np.ndarray:
        """The residual (m,) of the patch image (m,) (or a scalar) with the linear part fitted
        by its normal equations (least squares where they are singular): variable projection."""
        A, y = self.A, self.y
        A[:, 0] = image
        try:
            c = np.linalg.solve(A.T @ A, A.T @ y)
        except np.linalg.LinAlgError:
            c = np.linalg.lstsq(A, y, rcond=None)[0]
        return A @ c - y


def _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels, min_pixels):
    """The :class:`_PatchProblem` of a ROI, or None with fewer than ``min_pixels`` unclipped
    samples; and the number of samples: ``(problem or None, m)``."""
    vals, camera, o, uu, vv, keep = _roi_grid(values, camera, origin_uv, clip_level)
    H, W = vals.shape
    sel, step, uv, y = _roi_samples(vals, o, uu, vv, keep, max_pixels)
    if len(y) < min_pixels:
        return None, len(y)
    y = y / max(float(np.abs(y).max()), 1e-12)
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(2)
    b_ray = _rays(camera, bp[None])[0]
    du = (uv[:, 0] - bp[0]) / max(H, W)
    dv = (uv[:, 1] - bp[1]) / max(H, W)
    A = np.column_stack([np.zeros_like(du), np.ones_like(du), du, dv])
    px = 1.0 / float(np.linalg.norm(_rays(camera, bp[None] + [1.0, 0.0])[0] - b_ray))
    return _PatchProblem(y, _rays(camera, uv), b_ray, _rig_arrays(rig), _mean_light(rig), A, sel,
                         step, keep.shape, px), len(y)


def quadric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *,
                clip_level: float | None = None, nominal_depth_mm: float = 20.0,
                start_depths_mm=None, start_roughness: float | None = None,
                max_pixels: int | None = 800, max_nfev: int = 100,
                misfit_sigma: bool | float = True) -> LightAwareEstimate:
    """Fit the ROI with the image of a curved (quadric) patch lit by the rig.

    The patch is second-order about its apex: the apex X0 at depth s on a ray near the BP's
    (two angles (a, b) about it), its normal N the bisector of the directions from X0 to the
    camera and to the rig's mean light (so X0 is that light's specular point, the point whose depth
    and normal are reported), and a symmetric shape operator ``kappa / s`` (kappa_xx, kappa_xy,
    kappa_yy dimensionless) in the tangent basis (t1, t2) of N: in the apex's frame (z along N,
    toward the camera) the patch is
    ``F = z + (k_xx x^2 + 2 k_xy x y + k_yy y^2 + H z^2) / 2 = 0`` with ``H = (k_xx + k_yy) / 2``
    the mean curvature (positive curvatures bend away from the camera, as the outside of a
    sphere). Each pixel ray meets it at the root of a quadratic nearest the tangent plane; the
    surface normal there (the gradient of F), the rig's lobes (as in :func:`photometric_fit`), gain
    and linear background (solved linearly, variable projection) give the image. The seven
    nonlinear parameters (a, b, log s, kappa, log n) are fitted by Levenberg-Marquardt
    (:func:`scipy.optimize.least_squares`, finite-difference Jacobian, scaled) on a regular
    sub-grid of at most ``max_pixels`` unclipped pixels, from a flat patch at each start depth in
    turn until one ends at a plausible solution (distance and roughness in the ranges of
    :func:`photometric_fit`), kept; without one, the least cost. A fit whose neighbouring
    residuals correlate (the test of :func:`photometric_fit`), or whose residual RMS exceeds
    ``TOL.patch_misfit_rms_rel`` of the ROI's maximum, is reported as ``patch_misfit``.

    Notes
    -----
    Why tie N to the bisector: a surface point with its normal has five degrees of freedom, two of
    which slide the point along the surface; fixing the point to the one where the normal bisects
    camera and light removes that freedom without restricting the patch, and makes the normal a
    function of the depth and the apex ray only. Why the ``H z^2`` term: without it (a
    paraboloid) the patch departs from a sphere at fourth order in the distance from the apex,
    and on rendered spheres at epsilon/d = 0.3 that departure moved the fitted depth by 40 % along
    the valley where depth, curvature and roughness trade off (2 deg of normal); with it a
    sphere is exact and a cylinder's fourth-order error is halved. The plane model
    (:func:`photometric_fit`) meets a curved patch by trading the curvature's compression or
    spreading of the lobe for roughness and distance, and the distance sets the normal through
    the bisector; the quadric model fits the curvature instead. Uncertainty: the larger of
    ``C = s^2 (J^T J)^-1`` and the sandwich (:func:`_patch_covariances`), with J the Jacobian of
    the projected residual at the solution, and the depth's width along the parameters' valley
    beyond it (:func:`_depth_valley`), propagated to N by finite differences.

    Where it breaks: the depth, and through the bisector the normal, rests on the patch being a
    quadric over the ROI. With the apex tied to the BP ray, the normal is the bisector at depth
    s, off the true one by about ``(epsilon_perp / 2) |1/s - 1/d|`` (2.9 deg times ``|d/s - 1|``
    at epsilon/d = 0.1): the depth must be right within a factor of about 1.4 for 1 deg there.
    To first order in epsilon/d the light's offset changes the lobe as the curvature's gradient
    over the patch does (the third-order terms of the height function
    ``(c_xxx x^3 + 3 c_xxy x^2 y + 3 c_xyy x y^2 + c_yyy y^3) / 6``). Measured on the
    ``lightaware-curved`` liver renders: with those four terms added to the patch, the fit's cost
    changed by at most 1.3 % between half and twice the true depth, where the quadric's changed
    by 20 % to 120 %: a single highlight does not tell the depth from the surface's third-order
    shape, and the quadric's depth is the one at which the offset stands in for it (0.4 times
    the truth on the liver mesh at epsilon/d 0.1, a lobe 12 mm long over which the curvature
    varies). On spheres, cylinders and saddles the quadric holds and the depth follows. A
    larger ROI brings in more of the surface's third-order shape: the recommendation fits an ROI
    1.5 times the highlight's (:func:`~simtest.reconstruct.recommend.light_aware_estimates`).
    So under one light (every light of the rig at one place) the fit never gives a depth: its
    status is at best ``depth_not_observable``, ``depth_range_mm`` states the depths within
    :data:`ONE_LIGHT_DEPTH_FACTOR` of the fitted one, and ``normal_sigma_deg`` carries the
    normals' spread over them (:func:`_one_light_band`): on the liver its stated 1.2 deg did not
    cover its 3.8 deg error, the normal of a depth 57 % short.
    A second light beside the lens makes the depth observable with the third-order terms free
    (:func:`cubic_patch_fit`).

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, nominal_depth_mm
        As in :func:`photometric_fit`.
    start_depths_mm : sequence of float, optional
        Start depths of the apex along the BP ray, tried in turn (default: 1, 3 and 0.5 times
        ``nominal_depth_mm``).
    start_roughness : float, optional
        Start Phong n (default 50).
    max_pixels : int or None
        Beyond this many unclipped pixels, fit those of a regular sub-grid (None keeps all).
    max_nfev : int
        Evaluation budget per start, in Jacobian evaluations (scipy's ``max_nfev`` for ``lm`` with
        a finite-difference Jacobian counts each of its 8 residual evaluations).
    misfit_sigma : bool or float
        State a sigma for a fit that misfits (``patch_misfit``): read its depth valley as for the
        others. False: a misfit states none (``normal_sigma_deg`` None) and its valley, six
        refits with the depth fixed and most of the fit's time, is not read
        (:data:`MISFIT_SIGMA_NOTE`). A number, degrees: read only where the local sigma (the
        covariances' alone) is below it; the valley only widens a sigma, so a misfit whose local
        sigma already reaches the bound states none. The misfit verdict does not depend on it.

    Returns
    -------
    LightAwareEstimate
        ``estimator="quadric_fit"``, status ``ok`` (two or more lights at different places
        only), ``depth_not_observable``, ``patch_misfit`` or ``not_converged``; ``distance_mm``
        is the apex depth s; under one light ``depth_range_mm`` (near, far), mm.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.
    """
    name = "quadric_fit"
    P, n_px = _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels, 12)
    if P is None:
        return LightAwareEstimate(name, "too_few_points", f"{n_px} unclipped pixels")
    d, b_ray, rig_arr, Lm, sel, step = P.d, P.b_ray, P.rig_arr, P.Lm, P.sel, P.step

    def res(p):
        return P.residual(_quadric_image(d, b_ray, p, rig_arr, Lm)[0])

    starts = (np.array([1.0, 3.0, 0.5]) * nominal_depth_mm if start_depths_mm is None
              else np.asarray(start_depths_mm, dtype=np.float64).reshape(-1))
    n0 = 50.0 if start_roughness is None else float(start_roughness)
    px = P.px_per_rad
    x_scale = np.array([1.0 / px, 1.0 / px, 0.1, 0.1, 0.1, 0.1, 0.3])
    best = None
    nfev = 0
    for s0 in starts:
        p0 = np.array([0.0, 0.0, np.log(s0), 0.0, 0.0, 0.0, np.log(n0)])
        with np.errstate(all="ignore"):
            r = least_squares(res, p0, method="lm", max_nfev=max_nfev * 8, x_scale=x_scale,
                              ftol=1e-6, xtol=1e-6)
        nfev += r.nfev
        if np.isfinite(r.cost) and (best is None or r.cost < best.cost):
            best = r
        if (np.isfinite(r.cost) and r.status > 0
                and not _implausible(float(np.exp(r.x[2])), float(nominal_depth_mm),
                                     float(np.exp(r.x[6])))):
            best = r  # a plausible solution: the other starts are for a fit that ran off
            break
    if best is None:
        return LightAwareEstimate(name, "not_converged", "no finite solution", n_evaluations=nfev)
    x = best.x
    n_hat = _quadric_image(d[:1], b_ray, x, rig_arr, Lm)[1]
    s_hat = float(np.exp(x[2]))
    rough = float(np.exp(x[6]))
    bad = _implausible(s_hat, float(nominal_depth_mm), rough)
    if best.status <= 0 or bad:
        return LightAwareEstimate(name, "not_converged", bad or best.message, n_evaluations=nfev)
    r0 = best.fun
    J = best.jac
    m_, k_ = J.shape
    resid_var = float(r0 @ r0) / max(m_ - k_ - 4, 1)
    covs = _patch_covariances(J, r0, resid_var, sel, P.shape, step)
    cov_floor = _covariance(J, max(resid_var, TOL.photometric_noise_rel**2))
    G = np.empty((3, 7))  # dN / dp
    for i in range(7):
        dp = np.zeros(7)
        dp[i] = 1e-6 * x_scale[i]
        G[:, i] = (_quadric_image(d[:1], b_ray, x + dp, rig_arr, Lm)[1]
                   - _quadric_image(d[:1], b_ray, x - dp, rig_arr, Lm)[1]) / (2 * dp[i])
    rel_floor = None if cov_floor is None else float(np.sqrt(max(cov_floor[2, 2], 0.0)))
    status, detail, observable, rms = _patch_verdict(
        rel_floor, r0, sel, P.shape, step, "",
        "the ROI is not one patch's lobe (streaks along folds, several lobes)")
    sigma_deg, _, excess, detail = _patch_sigma(status, detail, misfit_sigma,
                                                {"res": res, "x_scale": x_scale}, x, float(r0 @ r0),
                                                resid_var, covs, max_nfev, G)
    depth_sigma = (float(s_hat * np.sqrt(max(max(c[2, 2] for c in covs), 0.0) + excess))
                   if observable and covs else None)
    depth_range = None
    if not rig.has_separate_lights:
        # one light: the third-order shape the quadric leaves out trades with the depth (Notes)
        sigma_deg, depth_range = _one_light_band(x, sigma_deg, d[:1], b_ray, rig_arr, Lm)
        if status == "ok":
            status = "depth_not_observable"
            detail = (f"{detail}; one light: the depth trades with the third-order shape, "
                      f"{depth_range[0]:.3g} to {depth_range[1]:.3g} mm not excluded")
        observable = False
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None, sigma_deg,
                              depth_sigma if observable else None, s_hat if observable else None,
                              rough, None, nfev, rms, depth_rel_sigma=rel_floor,
                              depth_range_mm=depth_range)


#: Under one light, the factor either way of the quadric's fitted depth within which the data
#: cannot exclude the true depth (:func:`_one_light_band`). Why 2.5: with the four third-order
#: terms free the one-light liver's cost changed by at most 1.3 % between half and twice the
#: true depth (issue 10), i.e. the data exclude no depth there, and the quadric's depth was 0.4
#: to 0.43 times the truth on the ``lightaware-curved`` liver at epsilon/d 0.1 (the truth 2.3 to
#: 2.5 times the fitted depth).
ONE_LIGHT_DEPTH_FACTOR = 2.5


def _one_light_band(x, sigma_deg, d0, b_ray, rig_arr, Lm):
    """The quadric's normal sigma under one light with the third-order shape's spread added,
    and the depths (near, far) the data cannot exclude.

    Under one light a single highlight does not tell the depth from the surface's third-order
    shape (:func:`quadric_fit`, Notes): to first order in epsilon/d the light's offset changes the
    lobe as the curvature's gradient does, so the quadric's depth is the one at which the offset
    stands in for the surface's third-order terms, and its normal (the bisector at that depth)
    follows. Every depth within :data:`ONE_LIGHT_DEPTH_FACTOR` of the fitted one is kept
    possible: the normals of the apex at those two depths (the apex ray and shape fixed) are
    taken as the band's ends at 2 sigma, so half the larger angle from the fitted normal is
    added in quadrature to ``sigma_deg``. A sphere has no third-order terms at its vertex and
    its quadric is right (0.3 deg where the BP ray errs 2.9), but the data cannot tell it from
    the liver, where the same fit erred 3.8 deg with a stated 1.2.

    Returns
    -------
    (float or None, (float, float))
        The widened sigma (None where ``sigma_deg`` is), degrees; the near and far depths, mm.
    """
    n0 = _quadric_image(d0, b_ray, x, rig_arr, Lm)[1]
    spread = 0.0
    for sgn in (1.0, -1.0):
        xe = x.copy()
        xe[2] += sgn * np.log(ONE_LIGHT_DEPTH_FACTOR)
        ne = _quadric_image(d0, b_ray, xe, rig_arr, Lm)[1]
        spread = max(spread, float(np.degrees(np.arccos(np.clip(n0 @ ne, -1.0, 1.0)))))
    s_hat = float(np.exp(x[2]))
    band = (s_hat / ONE_LIGHT_DEPTH_FACTOR, s_hat * ONE_LIGHT_DEPTH_FACTOR)
    if sigma_deg is None:
        return None, band
    return float(np.hypot(sigma_deg, 0.5 * spread)), band


#: Newton steps that take a pixel ray's intersection from the quadric's root to the cubic patch's:
#: the third-order terms move it by a small fraction of the ROI, and Newton converges
#: quadratically from there (on the liver renders a fifth step changes the image by < 1e-12).
_CUBIC_NEWTON_STEPS = 4


#: Parameters of the cubic patch: (a, b, log s, kappa_xx, kappa_xy, kappa_yy, log n) and the four
#: dimensionless third-order coefficients (c_xxx, c_xxy, c_xyy, c_yyy).
_CUBIC_PARAMS = 11


#: Depths of the profile's grid, as multiples of ``nominal_depth_mm``: 2^k for k = -2..3 (0.25 to
#: 8 times), a factor 2 apart, so that the profile's least cost lies within a factor 1.42 of a
#: minimum in that range, from where the free fit converges.
_PROFILE_FACTORS = 2.0 ** np.arange(-2, 4)


#: Evaluation budget (in Jacobian evaluations) and tolerances of each fit of the profile: a
#: start, not a result (the free fit that follows has the full budget and 1e-8).
_PROFILE_NFEV = 30


_PROFILE_TOL = 1e-5


#: Largest ratio between neighbouring depths of :func:`patch_depth_profile` (intermediate depths
#: are fitted where the ones asked for are farther apart): each fit starts from its neighbour's
#: solution, and on the two-light liver render at epsilon/d 0.3 a step of 2 from the true depth
#: started a fit that ended 1300 times above the cost that steps of 1.25 reached.
_PROFILE_STEP = 1.25


#: :func:`patch_depth_profile` also starts each depth from a flat patch whose Phong n is this
#: fraction of the start roughness (n 10 for the default 50): its wider lobes overlap the image's
#: lobes where the narrower ones do not, and a fit whose model lobes miss the image's finds no
#: gradient. On the two-light liver render at epsilon/d 0.3 the narrow start alone reached the
#: profile's minimum (cost 0.0014) at the true depth only by way of a neighbouring depth's lucky
#: fit: with that depth moved by 3e-8 (its value on the cuda_ad_rgb render of the same scene)
#: every depth ended at costs of 1.8 to 8.3, a missed lobe; with the wide start too, 0.0014 again.
_PROFILE_WIDE_START = 0.2


def _cubic_patch_geometry(d, b_ray, p, Lm):
    """Intersections and surface normals of the cubic patch ``p`` along rays d.

    Returns ``(X (N, 3), ns (N, 3), ok (N,), N (3,), s, frame)``: points and unit normals (camera
    frame), which rays meet the patch in front of the camera, the apex normal, the apex depth s
    and the apex frame ``(P0, t1, t2, N)``. See :func:`cubic_patch_fit` for the parameters.
    """
    e1, e2 = plane_basis(b_ray)
    s = np.exp(np.float64(p[2]))  # numpy scalars: a fit that runs off overflows to inf, no raise
    P0 = s * unit(b_ray + p[0] * e1 + p[1] * e2)
    N = unit(unit(-P0) + unit(Lm - P0))
    t1, t2 = plane_basis(N)
    kxx, kxy, kyy = p[3] / s, p[4] / s, p[5] / s
    kzz = 0.5 * (kxx + kyy)
    cxxx, cxxy, cxyy, cyyy = np.asarray(p[7:11], dtype=np.float64) * np.exp(-2.0 * np.float64(p[2]))
    # the quadric's root (as in _quadric_image), then Newton on the full F along the ray
    ax, ay, az, bx, by, bz, t, ok = _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N)
    t = np.where(ok, t, s)

    def grad(t):
        x, y, z = ax * t + bx, ay * t + by, az * t + bz
        fx = kxx * x + kxy * y + 0.5 * (cxxx * x * x + 2 * cxxy * x * y + cxyy * y * y)
        fy = kxy * x + kyy * y + 0.5 * (cxxy * x * x + 2 * cxyy * x * y + cyyy * y * y)
        return x, y, z, fx, fy, 1.0 + kzz * z

    for _ in range(_CUBIC_NEWTON_STEPS if any((cxxx, cxxy, cxyy, cyyy)) else 0):
        x, y, z, fx, fy, fz = grad(t)
        F = (z + 0.5 * (kxx * x * x + 2 * kxy * x * y + kyy * y * y + kzz * z * z)
             + (cxxx * x**3 + 3 * cxxy * x * x * y + 3 * cxyy * x * y * y + cyyy * y**3) / 6.0)
        dF = fx * ax + fy * ay + fz * az
        good = np.abs(dF) > 1e-12
        t = t - np.where(good, F / np.where(good, dF, 1.0), 0.0)
    ok &= (t > 0) & np.isfinite(t)
    t = np.where(ok, t, s)
    _, _, _, fx, fy, fz = grad(t)
    ns = fz[:, None] * N + fx[:, None] * t1 + fy[:, None] * t2
    ns /= np.sqrt(np.einsum("ij,ij->i", ns, ns))[:, None]
    return d * t[:, None], ns, ok, N, s, (P0, t1, t2, N)


def _cubic_patch_image(d, b_ray, p, rig_arr, Lm):
    """Specular image (N,) of the cubic patch ``p`` along rays d, and its apex normal (3,)."""
    X, ns, ok, N, s, _ = _cubic_patch_geometry(d, b_ray, p, Lm)
    rough = np.exp(p[6])
    return _patch_lobes(d, X, ns, ok, s, rough, rig_arr), N


def _patch_specular_points(b_ray, p, Lm, lights):
    """Each light's specular point on the cubic patch ``p``: unit normals (J, 3) and depths (J,).

    The point is searched along the rays ``unit(b + u e1 + v e2)`` ((e1, e2) the tangent basis of
    the BP ray b): the tangential part of ``ns - unit(unit(-X) + unit(L_j - X))`` vanishes there
    (two equations in (u, v), solved by Levenberg-Marquardt from the apex's ray). NaN rows where
    the search fails (the ray misses the patch).
    """
    e1, e2 = plane_basis(b_ray)
    ray0 = np.array([p[0], p[1]], dtype=np.float64)
    normals = np.full((len(lights), 3), np.nan)
    depths = np.full(len(lights), np.nan)
    for j, Lj in enumerate(lights):
        def f(q, Lj=Lj):
            X, ns, ok, _, _, _ = _cubic_patch_geometry(unit(b_ray + q[0] * e1 + q[1] * e2)[None],
                                                       b_ray, p, Lm)
            if not ok[0]:
                return np.array([1.0, 1.0])
            c = ns[0] - unit(unit(-X[0]) + unit(Lj - X[0]))
            return np.array([c @ e1, c @ e2])

        with np.errstate(all="ignore"):
            r = least_squares(f, ray0, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
        X, ns, ok, _, _, _ = _cubic_patch_geometry(unit(b_ray + r.x[0] * e1 + r.x[1] * e2)[None],
                                                   b_ray, p, Lm)
        if ok[0] and float(np.max(np.abs(r.fun))) < 1e-9:
            normals[j], depths[j] = ns[0], float(np.linalg.norm(X[0]))
    return normals, depths


def _patch_covariances(J, r, resid_var, sel, shape, step) -> list:
    """The covariances a curved patch's sigmas are the larger of: the plain ``s^2 (J^T J)^-1``
    and the sandwich (:func:`~simtest.reconstruct.lightaware.solve._hac_covariance`), those that
    are not singular.

    Why the sandwich: the plain estimate spreads the residual's variance evenly over the ROI,
    while a render's Monte Carlo noise, and the misfit of what the model leaves out, grow with
    the radiance: they sit on the lobes, where the Jacobian is, and the dark surround, where
    the 8-bit image is 0 and its residual nearly so, dilutes ``s^2``. On the ``lightaware-curved``
    two-light spheres and cylinders (3 seeds each at epsilon/d 0.1 and 0.3) the plain sigma of
    the normal at each light's specular point covered 10 of 24 errors at 2 sigma, the sandwich's
    (1.4 to 3 times larger, its bandwidth 0 or 1 there) 23 of 24.
    """
    return [c for c in (_covariance(J, resid_var), _hac_covariance(J, r, sel, shape, step)[0])
            if c is not None]


def _sigma_deg(G, covs) -> float | None:
    """The largest RMS angle, degrees, of a unit vector whose derivative in the parameters is
    G (3, k), over the covariances ``covs`` (None when there are none)."""
    if not covs:
        return None
    return float(np.degrees(np.sqrt(max(max(float(np.trace(G @ c @ G.T)), 0.0) for c in covs))))


#: The step in log depth of :func:`_depth_valley`'s nearest profile points (5 % of the depth):
#: on the noisy two-light spheres the profile's half width at Delta chi^2 = 1 was 3 to 10 %,
#: where the local covariance said 0.7 to 1.5 %.
_VALLEY_STEP = 0.05


#: The steps in log depth at which :func:`_depth_valley` reads the profile's width: a profile
#: that is flat-bottomed (the two-light liver at epsilon/d 0.1: within 6 % of its least cost
#: from the true depth to twice it) rises less at 40 % than a parabola through its 5 % points
#: says, and each step's width counts.
_VALLEY_STEPS = (_VALLEY_STEP, 0.15, 0.4)

#: The detail a patch fit's misfit ends with where it states no sigma (``misfit_sigma`` False:
#: the recommendation has no use for it, :func:`~simtest.reconstruct.recommend.light_aware_estimates`).
MISFIT_SIGMA_NOTE = "no sigma stated (a misfit's depth valley not read)"


def _patch_sigma(status, detail, misfit_sigma, S, x, cost0, resid_var, covs, max_nfev, G):
    """A patch fit's normal sigma from its depth valley (:func:`_depth_valley`,
    :func:`_valley_sigma_deg`; ``G`` (3, k) the normal's derivative), or none for a misfit when
    ``misfit_sigma`` is False (its valley not read), or a number of degrees that the local sigma
    (:func:`_sigma_deg` of ``covs``, which the valley only widens) is not below. Returns
    ``(sigma_deg, valley, excess, detail)``: the valley's direction (None where not read) and
    excess variance of log depth, and the detail, for an ``ok`` fit how its cost rises at the
    valley's nearest steps."""
    if status == "patch_misfit":
        if not misfit_sigma:
            return None, None, 0.0, f"{detail}; {MISFIT_SIGMA_NOTE}"
        if misfit_sigma is not True:
            local = _sigma_deg(G, covs)
            if local is None or not local < float(misfit_sigma):
                said = "none" if local is None else f"{local:.3g} deg"
                return None, None, 0.0, (f"{detail}; {MISFIT_SIGMA_NOTE}: its local sigma, {said}, is not "
                                         f"below {float(misfit_sigma):.3g} deg")
    valley, excess, rises = _depth_valley(S, x, cost0, resid_var, covs, max_nfev)
    if status == "ok":
        detail = (f"the fit's cost rises by {rises[0]:.3g} and {rises[1]:.3g} residual variances at "
                  f"+-{_VALLEY_STEP:.0%} of its depth")
    return _valley_sigma_deg(G, covs, G @ valley, excess), valley, excess, detail


def _depth_valley(S, x, cost0, resid_var, covs, max_nfev):
    """The cubic patch's cost along its depth, beyond the local covariance.

    The patch is refitted with its log depth fixed at ``x[2] +- step`` for each step of
    :data:`_VALLEY_STEPS` (every other parameter free, from ``x``): the widest of the profile's
    readings ``sigma_p^2 = max step^2 s^2 / Delta`` (``Delta`` the rise of the sum of squares at
    that point, ``s^2 = resid_var``; scaled by the sandwich's over the plain variance of log
    depth where the sandwich is the larger) is the depth's variance, and the two solutions at
    the nearest step the direction ``v = (p_+ - p_-) / (2 step)`` (11,) in which the other
    parameters follow the depth (``v[2] = 1``). Each side and each step, not a mean curvature:
    a profile bounded on one side only, or flat-bottomed (the two-light liver at epsilon/d 0.1,
    whose depths erred by +1 to +24 %, always long), has an interval wider than its curvature
    at the minimum says.

    Why: the patch's parameters trade along a curved valley (depth against curvature,
    third-order terms and roughness) that the Gauss-Newton covariance ``s^2 (J^T J)^-1``, a
    quadratic fitted at one point, sees as much narrower than it is: on a noisy 8-bit two-light
    sphere (60 px, epsilon/d 0.1) the local 1-sigma of the depth was 0.7 %, the profile's 9 %,
    and the fit's depth 13 % off (its normals 0.37 deg off with a stated 0.03).

    ``S`` holds the fit's residual ``res(p)`` and ``x_scale``; the same reading serves
    :func:`quadric_fit` (7 parameters, log depth third as here).

    Returns
    -------
    (ndarray of shape (k,), float, tuple)
        ``v`` (zeros where a profile fit failed), the variance of log depth in excess of the
        local covariance's largest (0 where the profile is narrower; inf where it does not
        rise: the depth is then not bounded), and the two rises over ``s^2`` (NaN where a fit
        failed).
    """
    k = len(x)
    free = [i for i in range(k) if i != 2]
    ends, rises, var = [], [], 0.0
    for step in _VALLEY_STEPS:
        for sgn in (1.0, -1.0):
            start = x.copy()
            start[2] += sgn * step
            c, p, _ = _fit_fixed_depth(S, start[2], free, [start], max_nfev)
            if not np.isfinite(c):
                continue  # a refit that failed reads no width
            rise = max(c - cost0, 0.0) / resid_var if resid_var > 0 else np.inf
            if step == _VALLEY_STEP:
                ends.append(p)
                rises.append(rise)
            var = max(var, step**2 / rise if rise > 0 else np.inf)
    if len(ends) < 2:
        return np.zeros(k), 0.0, (np.nan, np.nan)
    v = (ends[0] - ends[1]) / (2.0 * _VALLEY_STEP)
    local = max(float(cv[2, 2]) for cv in covs) if covs else 0.0
    plain = float(covs[0][2, 2]) if covs else 0.0
    scale = local / plain if plain > 0 else 1.0
    return v, max(scale * var - local, 0.0), tuple(rises)


def _valley_sigma_deg(G, covs, Gv, excess) -> float | None:
    """:func:`_sigma_deg` of a unit vector with derivative G (3, k), with the excess variance of
    log depth along the valley (:func:`_depth_valley`) added through ``Gv = G v`` (3,)."""
    sig = _sigma_deg(G, covs)
    if sig is None:
        return None
    if not np.isfinite(excess):
        return 180.0
    return float(np.degrees(np.sqrt(np.radians(sig) ** 2 + float(Gv @ Gv) * excess)))


def _light_normal_jacobian(b_ray, p, Lm, lights, x_scale) -> np.ndarray:
    """The derivative (J, 3, 11) of each light's specular-point normal on the cubic patch ``p``
    in its parameters, by central differences (steps of 1e-4 of ``x_scale``; NaN where a
    specular point is not found)."""
    k = len(p)
    G = np.zeros((len(lights), 3, k))
    for i in range(k):
        dp = np.zeros(k)
        dp[i] = 1e-4 * x_scale[i]
        up = _patch_specular_points(b_ray, p + dp, Lm, lights)[0]
        dn = _patch_specular_points(b_ray, p - dp, Lm, lights)[0]
        G[:, :, i] = (up - dn) / (2 * dp[i])
    return G


def _cubic_setup(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels):
    """The ROI's samples and the variable-projection residual of the cubic patch.

    Returns None with too few unclipped pixels, else a dict: ``res(p)`` (the residual of the
    11 parameters; a quadric when the last four are 0), ``b_ray``, ``Lm``, ``rig_arr``,
    ``x_scale`` (11,), ``sel``, ``step``, ``shape`` and ``m`` (pixels used).
    """
    P, n_px = _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels,
                             2 * _CUBIC_PARAMS)
    if P is None:
        return None
    d, b_ray, rig_arr, Lm = P.d, P.b_ray, P.rig_arr, P.Lm

    def res(p):
        with np.errstate(all="ignore"):
            image = _cubic_patch_image(d, b_ray, p, rig_arr, Lm)[0]
        if not np.all(np.isfinite(image)):  # a patch run off to an overflow: no image
            image = 0.0
        return P.residual(image)

    px = P.px_per_rad
    x_scale = np.array([1.0 / px, 1.0 / px, 0.1, 0.1, 0.1, 0.1, 0.3, 0.1, 0.1, 0.1, 0.1])
    return {"res": res, "b_ray": b_ray, "Lm": Lm, "rig_arr": rig_arr, "x_scale": x_scale,
            "sel": P.sel, "step": P.step, "shape": P.shape, "m": n_px}


def _fit_fixed_depth(S, log_s, free, starts, max_nfev, tol=1e-8):
    """Least squares over the parameters ``free`` (indices) with log s fixed; the best of the
    starts (full 11-vectors). Returns ``(sum of squares, p (11,), nfev)``."""
    free = np.asarray(free)
    best, nfev = None, 0
    for p0 in starts:
        base = np.array(p0, dtype=np.float64)
        base[2] = log_s

        def fun(q, base=base):
            pp = base.copy()
            pp[free] = q
            return S["res"](pp)

        with np.errstate(all="ignore"):
            r = least_squares(fun, base[free], method="lm", x_scale=S["x_scale"][free],
                              max_nfev=max_nfev * (len(free) + 1), ftol=tol, xtol=tol)
        nfev += r.nfev
        if np.isfinite(r.cost) and (best is None or r.cost < best[0]):
            pp = base.copy()
            pp[free] = r.x
            best = (2.0 * float(r.cost), pp)
    if best is None:
        return float("inf"), np.array(starts[0], dtype=np.float64), nfev
    return best[0], best[1], nfev


def _flat_start(roughness):
    p = np.zeros(_CUBIC_PARAMS)
    p[6] = np.log(roughness)
    return p


def patch_depth_profile(values, origin_uv, bp_uv, camera, rig: LightRig, depths_mm, *,
                        clip_level: float | None = None, cubic: bool = True,
                        start_roughness: float | None = None, max_pixels: int | None = 800,
                        max_nfev: int = 100) -> np.ndarray:
    """The least misfit of a curved patch to the ROI with its apex depth fixed, depth by depth.

    At each depth the other parameters of :func:`cubic_patch_fit` (the apex ray, the curvatures,
    the roughness, and with ``cubic`` the four third-order coefficients; gain and background
    linearly) are fitted from two flat patches (Phong n ``start_roughness`` and a fifth of it,
    whose wider lobes overlap image lobes that the narrower ones miss) and from the neighbouring
    depth's solution (depths ascending, then descending, with intermediate depths fitted where
    neighbours are more than a factor 1.25 apart), the least sum of squared residuals kept. A profile that rises
    away from its minimum says the ROI fixes the depth; a flat one says the other parameters
    stand in for it (the evidence behind :func:`cubic_patch_fit`'s Notes).

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels
        As in :func:`photometric_fit`.
    depths_mm : array_like of shape (P,)
        Apex depths along the apex ray, mm (> 0).
    cubic : bool
        Fit the third-order terms too (else a quadric patch, that of :func:`quadric_fit`).
    start_roughness : float, optional
        Phong n of the flat start (default 50); the wide start has a fifth of it.
    max_nfev : int
        Evaluation budget per fit, in Jacobian evaluations.

    Returns
    -------
    ndarray of shape (P,)
        The least sum of squared residuals at each depth, in the order given, in units of the
        ROI's maximum squared (inf where no fit was finite).

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite, a depth that is not positive, or fewer than
        22 unclipped pixels.
    """
    depths = np.asarray(depths_mm, dtype=np.float64).reshape(-1)
    if not (depths.size and np.all(np.isfinite(depths)) and np.all(depths > 0)):
        raise ValueError(f"depths_mm: need positive depths, got {depths_mm!r}")
    S = _cubic_setup(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels)
    if S is None:
        raise ValueError("values: fewer unclipped pixels than twice the patch's parameters")
    free = [0, 1, 3, 4, 5, 6] + ([7, 8, 9, 10] if cubic else [])
    n0 = 50.0 if start_roughness is None else float(start_roughness)
    flats = [_flat_start(n0), _flat_start(_PROFILE_WIDE_START * n0)]
    # the depths asked for, with steps of at most _PROFILE_STEP between them for the warm starts
    lo, hi = np.log(depths.min()), np.log(depths.max())
    grid = np.union1d(np.log(depths), np.linspace(lo, hi, int(np.ceil((hi - lo) / np.log(_PROFILE_STEP))) + 1))
    cost = np.full(grid.size, np.inf)
    sol: dict[int, np.ndarray] = {}
    for seq in (range(grid.size), range(grid.size - 1, -1, -1)):
        prev = None
        for i in seq:
            starts = flats + ([prev] if prev is not None else [])
            c, p, _ = _fit_fixed_depth(S, grid[i], free, starts, max_nfev)
            if c < cost[i]:
                cost[i], sol[i] = c, p
            prev = sol.get(i, p)
    return cost[np.searchsorted(grid, np.log(depths))]


def cubic_patch_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *,
                    clip_level: float | None = None, nominal_depth_mm: float = 20.0,
                    start_roughness: float | None = None, max_pixels: int | None = 800,
                    max_nfev: int = 100, misfit_sigma: bool = True) -> LightAwareEstimate:
    """Fit the ROI with the image of a third-order surface patch lit by the whole rig.

    The patch is :func:`quadric_fit`'s with the four third-order terms of the height function
    added: in the apex's frame (z along the apex normal N, toward the camera; (x, y) along the
    tangent basis (t1, t2) of N)
    ``F = z + (k_xx x^2 + 2 k_xy x y + k_yy y^2 + H z^2) / 2
    + (c_xxx x^3 + 3 c_xxy x^2 y + 3 c_xyy x y^2 + c_yyy y^3) / 6 = 0``, with the curvatures
    ``k = kappa / s`` (1/mm) and ``c = gamma / s^2`` (1/mm^2) for dimensionless kappa and gamma,
    s the apex depth. The apex sits at depth s on the ray ``unit(b + a e1 + b' e2)`` near the BP
    ray b, and N bisects the directions from it to the camera and to the rig's mean light (the
    apex is that light's specular point). Each pixel ray meets the patch at the quadric's root
    refined by Newton steps; the surface normal there, every light's Phong lobe (with falloff and
    profile, as in :func:`photometric_fit`), gain and a linear background (solved linearly,
    variable projection [3]_) give the image. Eleven nonlinear parameters (a, b', log s, kappa,
    log n, gamma).

    Fitting: a depth profile first (:func:`patch_depth_profile` with the quadric patch, on the
    grid ``nominal_depth_mm`` times 2^(k/2), k = -4..6), whose least-cost depth starts the free
    fit of all eleven parameters (Levenberg-Marquardt, finite-difference Jacobian, scaled):
    a global search in depth, along which the local fits of :func:`quadric_fit` from a flat
    patch ran off on two-light renders. Then the observability of the depth (the relative
    1-sigma of s from ``(J^T J)^-1`` with the residual variance floored at
    ``TOL.photometric_noise_rel``, against ``TOL.depth_rel_sigma_max``), the misfit tests of
    :func:`quadric_fit`, and, when the depth is observable, each light's specular point on the
    fitted patch (its normal and depth: ``light_normals``, ``light_depths_mm``).

    Uncertainty: each sigma is the largest over the plain ``s^2 (J^T J)^-1`` and the sandwich
    (:func:`_patch_covariances`), with the depth's variance along the parameters' curved valley
    beyond the local one added (:func:`_depth_valley`: two refits at the depth +-5 %, the
    other parameters free), propagated to the apex's normal, the depth
    (``depth_sigma_mm``) and each light's normal (``light_normal_sigmas_deg``, by central
    differences of the specular points). A light's normal is the bisector at its specular
    point, which the curvature and the depth move: its sigma was 20 to 40 times the apex's on
    the ``lightaware-curved`` two-light spheres and cylinders, where the apex's alone covered
    none of the per-light errors at 2 sigma and these 24 of 24 (3 seeds per case).

    Notes
    -----
    Why the third-order terms, and why the rig: with one light, to first order in epsilon/d the
    light's offset changes the lobe as the curvature's gradient over the patch does
    (:func:`quadric_fit`, Notes), so with those terms free the fit's cost hardly changes with the
    depth (on the ``lightaware-curved`` liver render at epsilon/d 0.1, seed 0: by less than
    1e-4 of itself between half and twice the true depth, measured with
    :func:`patch_depth_profile`), the status is ``depth_not_observable`` and the normal, the
    bisector at an undetermined depth, is not used. Two lights on opposite sides of the lens (a
    colonoscope's guides) shift their lobes in opposite directions while the surface's shape
    acts on both alike, so the pair's separation and shapes fix the depth with the shape free.
    On the suite's ``liver_two_lights`` renders (seed 0), guides 19.1 mm either side
    (epsilon/d 0.3 each): the profile's least cost is at the true depth and rises by 49 % at
    0.9 times it, 35 % at 1.1 times, and 26 and 13 times at half and twice it. The reported
    ``normal`` is the apex's (the mean light's specular point; for a rig symmetric about the
    lens, the camera-facing point, whose normal is its viewing ray); ``light_normals`` are the
    normals where each light's highlight is, the ones a single-light truth compares with.

    Where it breaks: at 6.4 mm (epsilon/d 0.1) the same liver profile rises 6.4 times at half
    the depth and 35 % at 0.8 times, but stays within 6 % from the truth to twice it (its least
    cost at 1.25 times): the depth is bounded from below only; over the suite's six
    realisations the fits' depth errs by 11 % on average and the normal by 0.3 deg (median). A ROI that is not one smooth patch's lobes (the colon's fold
    streaks, a lobe cut off) misfits (``patch_misfit``) or does not converge.

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, nominal_depth_mm, max_pixels
        As in :func:`photometric_fit`; ``nominal_depth_mm`` centres the profile's grid (0.25 to
        8 times it).
    start_roughness : float, optional
        Phong n of the flat start (default 50).
    max_nfev : int
        Evaluation budget per fit, in Jacobian evaluations.

    Returns
    -------
    LightAwareEstimate
        ``estimator="cubic_patch_fit"``, status ``ok``, ``depth_not_observable``,
        ``patch_misfit``, ``not_converged`` or ``too_few_points``; ``distance_mm`` is the apex
        depth s, ``depth_mm`` the same (the apex is the mean light's specular point),
        ``light_normals`` (J, 3) and ``light_depths_mm`` (J,) when the depth is observable, and
        ``depth_rel_sigma``.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.

    References
    ----------
    .. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic
           Setting", eqs. (1) and (2).
    .. [2] M. P. do Carmo, "Differential Geometry of Curves and Surfaces", Prentice-Hall, 1976,
           section 3-3 (the local height function and its Taylor terms).
    .. [3] G. H. Golub, V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least
           squares problems whose variables separate", SIAM J. Numer. Anal. 10(2), 1973.
    """
    name = "cubic_patch_fit"
    S = _cubic_setup(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels)
    if S is None:
        return LightAwareEstimate(name, "too_few_points",
                                  f"fewer than {2 * _CUBIC_PARAMS} unclipped pixels")
    n0 = 50.0 if start_roughness is None else float(start_roughness)
    flat = _flat_start(n0)
    depths = float(nominal_depth_mm) * _PROFILE_FACTORS
    quad = [0, 1, 3, 4, 5, 6]
    cost = np.full(depths.size, np.inf)
    sol: list = [None] * depths.size
    nfev = 0
    for seq in (range(depths.size), range(depths.size - 1, -1, -1)):
        prev = None
        for i in seq:
            starts = [flat] + ([prev] if prev is not None else [])
            c, p, k = _fit_fixed_depth(S, np.log(depths[i]), quad, starts,
                                       min(max_nfev, _PROFILE_NFEV), _PROFILE_TOL)
            nfev += k
            if c < cost[i]:
                cost[i], sol[i] = c, p
            prev = sol[i] if sol[i] is not None else p
    if not np.isfinite(cost).any():
        return LightAwareEstimate(name, "not_converged", "no finite profile", n_evaluations=nfev)
    i0 = int(np.argmin(cost))
    with np.errstate(all="ignore"):
        r = least_squares(S["res"], sol[i0], method="lm", x_scale=S["x_scale"],
                          max_nfev=max_nfev * (_CUBIC_PARAMS + 1), ftol=1e-8, xtol=1e-8)
    nfev += r.nfev
    x = r.x
    s_hat = float(np.exp(x[2]))
    rough = float(np.exp(x[6]))
    bad = _implausible(s_hat, float(nominal_depth_mm), rough)
    if not np.isfinite(r.cost) or r.status <= 0 or bad:
        return LightAwareEstimate(name, "not_converged", bad or r.message, n_evaluations=nfev)
    b_ray, Lm = S["b_ray"], S["Lm"]
    n_hat = _cubic_patch_geometry(b_ray[None], b_ray, x, Lm)[3]
    r0, J = r.fun, r.jac
    m_, k_ = J.shape
    resid_var = float(r0 @ r0) / max(m_ - k_ - 4, 1)
    covs = _patch_covariances(J, r0, resid_var, S["sel"], S["shape"], S["step"])
    cov_floor = _covariance(J, max(resid_var, TOL.photometric_noise_rel**2))
    G = np.empty((3, _CUBIC_PARAMS))  # dN / dp
    for i in range(_CUBIC_PARAMS):
        dp = np.zeros(_CUBIC_PARAMS)
        dp[i] = 1e-6 * S["x_scale"][i]
        G[:, i] = (_cubic_patch_geometry(b_ray[None], b_ray, x + dp, Lm)[3]
                   - _cubic_patch_geometry(b_ray[None], b_ray, x - dp, Lm)[3]) / (2 * dp[i])
    rel_floor = None if cov_floor is None else float(np.sqrt(max(cov_floor[2, 2], 0.0)))
    status, detail, observable, rms = _patch_verdict(
        rel_floor, r0, S["sel"], S["shape"], S["step"], "",
        "the ROI is not one patch's lobes (streaks along folds, a lobe cut off)")
    sigma_deg, valley, excess, detail = _patch_sigma(status, detail, misfit_sigma, S, x, float(r0 @ r0),
                                                     resid_var, covs, max_nfev, G)
    if status == "ok":
        detail = f"profile minimum at {depths[i0]:.4g} mm; {detail}"
    depth_sigma = (float(s_hat * np.sqrt(max(max(c[2, 2] for c in covs), 0.0) + excess))
                   if observable and covs else None)
    ln = ld = lsig = None
    if observable:
        ln, ld = _patch_specular_points(b_ray, x, Lm, S["rig_arr"][0])
        if covs:
            GL = _light_normal_jacobian(b_ray, x, Lm, S["rig_arr"][0], S["x_scale"])
            lsig = np.array([np.nan if not np.isfinite(g).all()
                             else _valley_sigma_deg(g, covs, g @ valley, excess) for g in GL])
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None,
                              sigma_deg, depth_sigma, s_hat if observable else None, rough, None,
                              nfev, rms, ln, ld, rel_floor, light_normal_sigmas_deg=lsig)
