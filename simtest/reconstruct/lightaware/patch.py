"""Curved-patch fits: the quadric patch (:func:`quadric_fit`), and the sigmas and the fixed-depth
fits the quadric and the cubic patch (:mod:`~simtest.reconstruct.lightaware.cubic`) share."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from simtest.decisions import ONE_LIGHT_DEPTH_FACTOR, RUN_OFF_FACTOR
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.lights import LightRig
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import _mean_light, _rays, _rig_arrays, _roi_grid, _roi_samples
from simtest.reconstruct.lightaware.patch_geometry import (
    QUADRIC_PARAMS, _light_normal_jacobian, _patch_specular_points, _quadric_image,
)
from simtest.reconstruct.lightaware.solve import (
    _covariance, _hac_covariance, _implausible, _patch_verdict, lm_least_squares,
)


@dataclass
class _PatchProblem:
    """A ROI's samples for a curved patch's variable-projection fit: normalised intensities ``y``, rays
    ``d``, the BP's ray, the rig, the linear design ``A`` (patch image, constant, du, dv), the samples'
    place in the ROI grid and ``px_per_rad`` the image's scale at the BP."""

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
        """The residual (m,) of a patch image (or (K, m) of K images), the linear part fitted by its normal
        equations (least squares where singular)."""
        A, y = self.A, self.y
        if np.ndim(image) == 2:  # stacked: numpy's matmul and solve take each image's the same BLAS and LAPACK calls
            AA = np.repeat(A[None], len(image), axis=0)
            AA[:, :, 0] = image
            AT = AA.transpose(0, 2, 1)
            try:
                return (AA @ np.linalg.solve(AT @ AA, (AT @ y)[..., None]))[..., 0] - y
            except np.linalg.LinAlgError:  # (one singular: each its own, as below)
                return np.array([self.residual(im) for im in image])
        A[:, 0] = image
        try:
            c = np.linalg.solve(A.T @ A, A.T @ y)
        except np.linalg.LinAlgError:
            c = np.linalg.lstsq(A, y, rcond=None)[0]
        return A @ c - y


def _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels, min_pixels):
    """``(problem or None, m)``: the :class:`_PatchProblem` of a ROI, None below ``min_pixels`` samples."""
    vals, camera, o, uu, vv, keep = _roi_grid(values, camera, origin_uv, clip_level)
    sel, step, uv, y = _roi_samples(vals, o, uu, vv, keep, max_pixels)
    if len(y) < min_pixels:
        return None, len(y)
    y = y / max(float(np.abs(y).max()), 1e-12)
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(2)
    b_ray = _rays(camera, bp[None])[0]
    du, dv = ((uv - bp) / max(vals.shape)).T
    A = np.column_stack([np.zeros_like(du), np.ones_like(du), du, dv])
    px = 1.0 / float(np.linalg.norm(_rays(camera, bp[None] + [1.0, 0.0])[0] - b_ray))
    return _PatchProblem(y, _rays(camera, uv), b_ray, _rig_arrays(rig), _mean_light(rig), A, sel,
                         step, keep.shape, px), len(y)


def _quadric_residual(P: _PatchProblem):
    """The residual on ``P``'s samples of the quadric's parameters, (7,) or a batch (K, 7)."""
    return lambda p: P.residual(_quadric_image(P.d, P.b_ray, p, P.rig_arr, P.Lm)[0])


def _quadric_lm(res, p0, x_scale, max_nfev, nominal_mm):
    """Levenberg-Marquardt on the quadric's residual ``res`` from ``p0`` (scipy's result), each start's; stopped as a
    plane fit's where the apex depth (about ``nominal_mm``) or n ran off (:data:`~simtest.decisions.RUN_OFF_FACTOR`)."""
    with np.errstate(all="ignore"):  # (batched: the finite differences' points imaged at once, each bit for bit)
        return lm_least_squares(res, p0, max_nfev=max_nfev * (QUADRIC_PARAMS + 1), x_scale=x_scale, ftol=1e-6,
                                xtol=1e-6, batched=True, stop=lambda p: _implausible(
                                    np.exp(p[2]), nominal_mm, np.exp(p[6]), widen=RUN_OFF_FACTOR))


def _quadric_starts(res, x_scale, nominal_depth_mm, start_depths_mm, start_roughness, max_nfev):
    """:func:`quadric_fit`'s starts: a flat patch at each start depth in turn until one ends plausible.
    Returns the least-squares result kept (None: none finite) and the evaluations spent."""
    starts = (np.array([1.0, 3.0, 0.5]) * nominal_depth_mm if start_depths_mm is None
              else np.asarray(start_depths_mm, dtype=np.float64).reshape(-1))
    n0 = 50.0 if start_roughness is None else float(start_roughness)
    best, nfev = None, 0
    for s0 in starts:
        r = _quadric_lm(res, np.array([0.0, 0.0, np.log(s0), 0.0, 0.0, 0.0, np.log(n0)]), x_scale, max_nfev,
                        nominal_depth_mm)
        nfev += r.nfev
        if np.isfinite(r.cost) and (best is None or r.cost < best.cost):
            best = r
        if (np.isfinite(r.cost) and r.status > 0
                and not _implausible(float(np.exp(r.x[2])), float(nominal_depth_mm), float(np.exp(r.x[6])))):
            best = r  # a plausible solution: the other starts are for a fit that ran off
            break
    return best, nfev


#: Depths of the coarse profile, as multiples of ``nominal_depth_mm``: 0.25 to 8, a factor 2 apart.
_PROFILE_FACTORS = 2.0 ** np.arange(-2, 4)

#: Budget (times free parameters + 1 LM steps, as quadric_fit's) and tolerance of each fit of the coarse profile.
_PROFILE_NFEV = 30
_PROFILE_TOL = 1e-5

#: Samples (a sub-grid of the ROI's unclipped pixels) of the profile that starts :func:`quadric_fit` again: it only
#: picks the depth's basin, which a quarter of the fit's 800 samples shows at its factor-2 steps; the refit reads all.
#: Chosen on lightaware-curved's tuning seed (no case's quadric worse end to end; half the profile's cost).
_PROFILE_PIXELS = 200


def _flat_start(roughness, k):
    """A flat patch of ``k`` parameters (a quadric's or a cubic patch's) at the BP's ray, Phong n ``roughness``."""
    return np.concatenate([np.zeros(QUADRIC_PARAMS - 1), [np.log(roughness)], np.zeros(k - QUADRIC_PARAMS)])


def _coarse_profile(S, depths, start_roughness, max_nfev, k):
    """The coarse quadric profile over ``depths`` (mm) of a patch of ``k`` parameters (its third-order terms,
    if any, held at 0), swept up and down from a flat patch and the neighbour's solution: the start of
    :func:`~simtest.reconstruct.lightaware.cubic.cubic_patch_fit` and, under separate lights, of
    :func:`quadric_fit` where its flat starts end in a misfit. Returns ``(cost, sol, nfev)``."""
    n0 = 50.0 if start_roughness is None else float(start_roughness)
    return _sweep(S, np.log(depths), [0, 1, 3, 4, 5, 6], [_flat_start(n0, k)], min(max_nfev, _PROFILE_NFEV),
                  _PROFILE_TOL)


def _sweep(S, log_depths, free, flats, max_nfev, tol):
    """Fixed-depth fits (:func:`_fit_fixed_depth`) over ``log_depths`` swept up and then down, each depth
    from the ``flats`` going up and from the neighbour's solution (the first flat where it had no finite
    fit); the least cost kept. Returns ``(cost (P,), solutions (P,) or None, nfev)``."""
    cost, sol, nfev = np.full(len(log_depths), np.inf), [None] * len(log_depths), 0
    for down, seq in enumerate((range(len(log_depths)), range(len(log_depths) - 1, -1, -1))):
        prev = None
        for i in seq:  # the flat starts going up only: going down they would give the same fits again
            starts = ([] if down else list(flats)) + ([prev] if prev is not None else [])
            c, p, nf = _fit_fixed_depth(S, log_depths[i], free, starts, max_nfev, tol) if starts else (np.inf, None, 0)
            nfev += nf
            if c < cost[i]:
                cost[i], sol[i] = c, p
            prev = sol[i] if sol[i] is not None else flats[0]
    return cost, sol, nfev


def _apex_normal_gradient(d1, b_ray, x, x_scale, rig_arr, Lm) -> np.ndarray:
    """dN / dp (3, 7) of the quadric patch's apex normal, by central differences of ``1e-6 x_scale``."""
    dp = np.diag(1e-6 * x_scale)
    N = _quadric_image(d1, b_ray, np.vstack([x + dp, x - dp]), rig_arr, Lm)[1]
    return ((N[:7] - N[7:]) / (2 * np.diag(dp))[:, None]).T


def quadric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *, clip_level: float | None = None,
                nominal_depth_mm: float = 20.0, start_depths_mm=None, start_roughness: float | None = None,
                max_pixels: int | None = 800, max_nfev: int = 100,
                misfit_sigma: bool | float = True) -> LightAwareEstimate:
    """Fit the ROI with the image of a curved (quadric) patch lit by the rig.

    The apex lies at depth s on a ray near the BP's, its normal N bisecting the directions to the
    camera and the mean light; in the apex frame the patch is
    ``z + (k_xx x^2 + 2 k_xy x y + k_yy y^2 + H z^2) / 2 = 0``, ``k = kappa / s``, ``H = (k_xx + k_yy) / 2``
    (exact for a sphere). Its lobes, gain and linear background give the image; (a, b, log s, kappa,
    log n) are fitted by Levenberg-Marquardt from a flat patch at each start depth until one ends
    plausible; under separate lights, where that ends in a misfit or runs off, again from the best
    depth of the coarse quadric profile (:func:`_coarse_profile`, on :data:`_PROFILE_PIXELS`
    samples), the lower cost kept. Under one light the depth trades with the surface's third-order
    shape and is not reported (``depth_range_mm`` instead; :func:`cubic_patch_fit` uses two lights).

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, nominal_depth_mm
        As in :func:`photometric_fit`.
    start_depths_mm : sequence of float, optional
        Start depths of the apex along the BP ray (default: 1, 3 and 0.5 times ``nominal_depth_mm``).
    start_roughness : float, optional
        Start Phong n (default 50).
    max_pixels : int or None
        Beyond this many unclipped pixels, fit those of a regular sub-grid (None keeps all).
    max_nfev : int
        Budget per start: ``8 max_nfev`` Levenberg-Marquardt steps (their finite differences' points not counted).
    misfit_sigma : bool or float
        State a sigma for a ``patch_misfit`` fit (reading its depth valley). False: none
        (:data:`MISFIT_SIGMA_NOTE`); a number, degrees: only where the local sigma is below it.

    Returns
    -------
    LightAwareEstimate
        ``estimator="quadric_fit"``, status ``ok`` (separate lights only), ``depth_not_observable``,
        ``patch_misfit`` (correlated residuals, or RMS above ``TOL.patch_misfit_rms_rel``) or
        ``not_converged``; ``distance_mm`` is the apex depth s (the mean light's specular point);
        sigmas from the larger of the covariances (:func:`_patch_covariances`) and the depth valley
        (:func:`_depth_valley`). With an observable depth, each light's specular point on the patch
        (``light_normals`` (J, 3), ``light_depths_mm`` (J,), ``light_normal_sigmas_deg``): on a
        curved surface each guide's highlight has its own normal, which the apex's is not.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.
    """
    P, n_px = _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels, 12)
    if P is None:
        return LightAwareEstimate("quadric_fit", "too_few_points", f"{n_px} unclipped pixels")
    res = _quadric_residual(P)
    x_scale = np.array([1.0 / P.px_per_rad, 1.0 / P.px_per_rad, 0.1, 0.1, 0.1, 0.1, 0.3])
    best, nfev = _quadric_starts(res, x_scale, nominal_depth_mm, start_depths_mm, start_roughness, max_nfev)
    S = {"res": res, "x_scale": x_scale, "batched": True}
    # the verdict first: a misfit's sigma (its depth valley, the costliest step) only for the fit returned
    est = _quadric_estimate(best, nfev, P, S, rig, nominal_depth_mm, False, max_nfev)
    first = (lambda: est) if est.status != "patch_misfit" or misfit_sigma is False else (
        lambda: _quadric_estimate(best, nfev, P, S, rig, nominal_depth_mm, misfit_sigma, max_nfev))
    if rig.has_separate_lights and est.status in ("patch_misfit", "not_converged"):
        # the flat starts' basin missed the patch: the depth the coarse profile finds starts a second fit
        coarse = _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, _PROFILE_PIXELS, 12)[0] or P
        cost, sol, n_profile = _coarse_profile(dict(S, res=_quadric_residual(coarse)), float(nominal_depth_mm)
                                               * _PROFILE_FACTORS, start_roughness, max_nfev, QUADRIC_PARAMS)
        total = nfev + n_profile
        if np.isfinite(cost).any():
            again = _quadric_lm(res, sol[int(np.argmin(cost))], x_scale, max_nfev, float(nominal_depth_mm))
            total += again.nfev
            if np.isfinite(again.cost) and (best is None or again.cost < best.cost):
                return _quadric_estimate(again, total, P, S, rig, nominal_depth_mm, misfit_sigma, max_nfev)
        return dataclasses.replace(first(), n_evaluations=total)
    return first()


def _quadric_estimate(best, nfev, P, S, rig, nominal_depth_mm, misfit_sigma, max_nfev) -> LightAwareEstimate:
    """:func:`quadric_fit`'s estimate from its least-squares result ``best`` (None: none finite) on the
    :class:`_PatchProblem` ``P`` (``S``: its residual and scales), ``nfev`` evaluations spent."""
    name = "quadric_fit"
    if best is None:
        return LightAwareEstimate(name, "not_converged", "no finite solution", n_evaluations=nfev)
    d, b_ray, rig_arr, Lm, x_scale = P.d, P.b_ray, P.rig_arr, P.Lm, S["x_scale"]
    x = best.x
    n_hat = _quadric_image(d[:1], b_ray, x, rig_arr, Lm)[1]
    s_hat, rough = float(np.exp(x[2])), float(np.exp(x[6]))
    bad = _implausible(s_hat, float(nominal_depth_mm), rough)
    if best.status <= 0 or bad:
        return LightAwareEstimate(name, "not_converged", bad or best.message, n_evaluations=nfev)
    G = _apex_normal_gradient(d[:1], b_ray, x, x_scale, rig_arr, Lm)
    status, detail, observable, rms, sigma_deg, valley, excess, depth_sigma, rel_floor, covs = _patch_uncertainty(
        best, S, P.sel, P.shape, P.step, x, G, misfit_sigma, max_nfev,
        "the ROI is not one patch's lobe (streaks along folds, several lobes)")
    depth_range = None
    ln, ld, lsig = _light_normals(observable and rig.has_separate_lights, b_ray, x, Lm, rig_arr[0], x_scale, covs,
                                  valley, excess)
    if not rig.has_separate_lights:
        # one light: the third-order shape the quadric leaves out trades with the depth
        sigma_deg, depth_range = _one_light_band(x, sigma_deg, d[:1], b_ray, rig_arr, Lm)
        if status == "ok":
            status = "depth_not_observable"
            detail = (f"{detail}; one light: the depth trades with the third-order shape, "
                      f"{depth_range[0]:.3g} to {depth_range[1]:.3g} mm not excluded")
        observable = False
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None, sigma_deg,
                              depth_sigma if observable else None, s_hat if observable else None, rough, None,
                              nfev, rms, ln, ld, rel_floor, depth_range_mm=depth_range, light_normal_sigmas_deg=lsig)


def _light_normals(observable, b_ray, x, Lm, lights, x_scale, covs, valley, excess):
    """``(normals (J, 3), depths (J,), sigmas (J,))`` of each light's specular point on the fitted patch ``x``
    (:func:`~simtest.reconstruct.lightaware.patch_geometry._patch_specular_points`), the sigmas (deg) through
    the covariances and the depth valley as the apex normal's; all None where the depth is not ``observable``
    (the patch's place along the rays, and so where each light's specular point lies on it, is not known),
    the sigmas None without ``covs``."""
    if not observable:
        return None, None, None
    ln, ld = _patch_specular_points(b_ray, x, Lm, lights)
    if not covs:
        return ln, ld, None
    GL = _light_normal_jacobian(b_ray, x, Lm, lights, x_scale)
    return ln, ld, np.array([np.nan if not np.isfinite(g).all() else _valley_sigma_deg(g, covs, g @ valley, excess)
                             for g in GL])


def _one_light_band(x, sigma_deg, d0, b_ray, rig_arr, Lm):
    """``(sigma, (near, far))``: the quadric's normal sigma (deg; None where ``sigma_deg`` is) with
    half the apex normals' spread over the depths within :data:`ONE_LIGHT_DEPTH_FACTOR` added in
    quadrature, and those depths, mm."""
    xe = np.repeat(x[None], 3, axis=0)
    xe[1:, 2] += np.array([1.0, -1.0]) * np.log(ONE_LIGHT_DEPTH_FACTOR)
    n0, *ne = _quadric_image(d0, b_ray, xe, rig_arr, Lm)[1]
    spread = max([0.0] + [float(angle_between_deg(n0, n)) for n in ne])
    s_hat = float(np.exp(x[2]))
    band = (s_hat / ONE_LIGHT_DEPTH_FACTOR, s_hat * ONE_LIGHT_DEPTH_FACTOR)
    return (None if sigma_deg is None else float(np.hypot(sigma_deg, 0.5 * spread))), band


def _patch_uncertainty(r, S, sel, shape, step, x, G, misfit_sigma, max_nfev, misfit_hint):
    """The verdict and sigmas of a curved-patch fit from its least-squares result ``r`` (``fun``, ``jac``):
    ``(status, detail, observable, rms, sigma_deg, valley, excess, depth_sigma, rel_floor, covs)``."""
    r0, J = r.fun, r.jac
    resid_var = float(r0 @ r0) / max(J.shape[0] - J.shape[1] - 4, 1)
    covs = _patch_covariances(J, r0, resid_var, sel, shape, step)
    cov_floor = _covariance(J, max(resid_var, TOL.photometric_noise_rel**2))
    rel_floor = None if cov_floor is None else float(np.sqrt(max(cov_floor[2, 2], 0.0)))
    status, detail, observable, rms = _patch_verdict(rel_floor, r0, sel, shape, step, "", misfit_hint)
    sigma_deg, valley, excess, detail = _patch_sigma(status, detail, misfit_sigma, S, x, float(r0 @ r0), resid_var,
                                                     covs, max_nfev, G)
    s_hat = float(np.exp(x[2]))
    depth_sigma = float(s_hat * np.sqrt(max(max(c[2, 2] for c in covs), 0.0) + excess)) if observable and covs else None
    return status, detail, observable, rms, sigma_deg, valley, excess, depth_sigma, rel_floor, covs


def _patch_covariances(J, r, resid_var, sel, shape, step) -> list:
    """The non-singular covariances a curved patch's sigmas are the larger of: ``s^2 (J^T J)^-1`` and
    the sandwich (:func:`~simtest.reconstruct.lightaware.solve._hac_covariance`), which counts the
    noise sitting on the lobes rather than spread over the dark surround."""
    return [c for c in (_covariance(J, resid_var), _hac_covariance(J, r, sel, shape, step)[0]) if c is not None]


def _sigma_deg(G, covs) -> float | None:
    """The largest RMS angle, degrees, of a unit vector with derivative G (3, k) over ``covs`` (None: none)."""
    if not covs:
        return None
    return float(np.degrees(np.sqrt(max(max(float(np.trace(G @ c @ G.T)), 0.0) for c in covs))))


#: The step in log depth of :func:`_depth_valley`'s nearest profile points (5 % of the depth).
_VALLEY_STEP = 0.05

#: The steps in log depth at which :func:`_depth_valley` reads the profile's width (a flat-bottomed
#: profile rises less far out than a parabola through its nearest points says).
_VALLEY_STEPS = (_VALLEY_STEP, 0.15, 0.4)

#: The detail a patch fit's misfit ends with where it states no sigma (``misfit_sigma`` False:
#: the recommendation has no use for it, :func:`~simtest.reconstruct.light_fits.light_aware_estimates`).
MISFIT_SIGMA_NOTE = "no sigma stated (a misfit's depth valley not read)"


def _patch_sigma(status, detail, misfit_sigma, S, x, cost0, resid_var, covs, max_nfev, G):
    """A patch fit's normal sigma from its depth valley, or none for a misfit per ``misfit_sigma``. Returns
    ``(sigma_deg, valley, excess, detail)``; an ``ok`` fit's detail states how its cost rises at the valley's nearest
    steps."""
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
    """The patch's cost along its depth, beyond the local covariance: ``(v, excess, rises)``.

    Refits with log depth fixed at ``x[2] +- step`` (:data:`_VALLEY_STEPS`): the widest
    ``step^2 s^2 / Delta`` (``Delta`` the cost's rise) is the depth's variance; ``excess`` is what
    exceeds the local covariance's (inf where the cost does not rise), ``v = (p_+ - p_-) / (2 step)``
    the direction the other parameters follow (zeros where a refit failed), ``rises`` the nearest
    step's rises over ``s^2``. ``S`` holds ``res`` and ``x_scale``.
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
    """:func:`_sigma_deg` with the valley's excess variance of log depth added through ``Gv = G v``."""
    sig = _sigma_deg(G, covs)
    if sig is None:
        return None
    if not np.isfinite(excess):
        return 180.0
    return float(np.degrees(np.sqrt(np.radians(sig) ** 2 + float(Gv @ Gv) * excess)))


def _fit_fixed_depth(S, log_s, free, starts, max_nfev, tol=1e-8):
    """Least squares over ``free`` (indices) with log s fixed, ``max_nfev (len(free) + 1)`` LM steps a start; the
    best of the starts. Returns ``(sum of squares, p, nfev)``."""
    free = np.asarray(free)
    best, nfev = None, 0
    for p0 in starts:
        base = np.array(p0, dtype=np.float64)
        base[2] = log_s

        def fun(q, base=base):
            pp = np.repeat(base[None], len(np.atleast_2d(q)), axis=0)
            pp[:, free] = q
            return S["res"](pp if np.ndim(q) == 2 else pp[0])

        with np.errstate(all="ignore"):  # (as _quadric_starts': S's res takes a batch)
            r = lm_least_squares(fun, base[free], x_scale=S["x_scale"][free], max_nfev=max_nfev * (len(free) + 1),
                                 ftol=tol, xtol=tol, batched=bool(S.get("batched")))
        nfev += r.nfev
        if np.isfinite(r.cost) and (best is None or 2.0 * r.cost < best[0]):  # best[0]: a sum of squares
            pp = base.copy()
            pp[free] = r.x
            best = (2.0 * float(r.cost), pp)
    return (float("inf"), np.array(starts[0], dtype=np.float64), nfev) if best is None else (*best, nfev)
