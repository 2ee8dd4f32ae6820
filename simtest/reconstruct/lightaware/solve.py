"""The fitting machinery the light-aware fits share: start, Levenberg-Marquardt with a robust loss,
covariance and depth observability, plausibility and the misfit tests on the residuals."""

from __future__ import annotations

import math
import warnings

import numpy as np

from simtest._lazy import require
from simtest.decisions import (
    SMOOTHEST_FILM_ALPHA, ROUGHEST_FILM_ALPHA, DISTANCE_FACTOR_MAX as _H_FACTOR, SIGMA_CLUSTER_PX as CLUSTER_PX,
    SIGMA_MIN_CLUSTERS as MIN_CLUSTERS,
)
from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate, OK
from simtest.reconstruct.lightaware.model import (
    _distance_for_bp, _log_depth_gradient, _mean_light, _rays, _rig_arrays, phong_of_ggx_alpha, specular_point_depth,
)


def _start(bp_uv, camera, rig, nominal_depth_mm, start_normal):
    """Start normal n0 and distance h0 (package docstring, "Parametrisation, start")."""
    d_bp = _rays(camera, np.asarray(bp_uv, dtype=np.float64)[None])[0]
    Lm = _mean_light(rig)
    if start_normal is None:
        n0 = _bisector_plane(d_bp, Lm, nominal_depth_mm)[0]
    else:
        n0 = unit(np.asarray(start_normal, dtype=np.float64))
        if n0 @ d_bp > 0:
            n0 = -n0
    h0 = _distance_for_bp(d_bp, n0, Lm) if np.linalg.norm(Lm) > 0 else None
    if h0 is None or not np.isfinite(h0):
        h0 = float(-(n0 @ (nominal_depth_mm * d_bp)))
    return d_bp, n0, max(h0, 1e-3)


def _bisector_plane(d_bp, light_mm, depth_mm):
    """The plane (n, h) making the point at ``depth_mm`` along the unit BP ray ``d_bp`` the specular point of
    the light at ``light_mm``: n bisects the directions to the camera and the light."""
    X = depth_mm * np.asarray(d_bp, dtype=np.float64)
    n = unit(unit(-X) + unit(np.asarray(light_mm, dtype=np.float64) - X))
    return n, float(-(n @ X))


def _light_start(d_bp, light_mm, nominal_depth_mm):
    """:func:`_bisector_plane`, its distance at least 1e-3 mm."""
    n, h = _bisector_plane(d_bp, light_mm, nominal_depth_mm)
    return n, max(h, 1e-3)


def _covariance(jac: np.ndarray, resid_var: float) -> np.ndarray | None:
    """``resid_var (J^T J)^-1``, or None when J^T J is singular (a column below 1e-10 of the largest, or
    a condition number above 1e12 with unit-norm columns)."""
    jtj = jac.T @ jac
    scale = np.sqrt(np.diag(jtj))
    if not np.all(scale > 1e-10 * scale.max()):  # a column of rounding noise: a flat direction
        return None
    jn = jtj / np.outer(scale, scale)
    if np.linalg.cond(jn) > 1e12:
        return None
    return resid_var * np.linalg.inv(jn) / np.outer(scale, scale)


#: The guard column's value (a power of 2: its finite difference is exact), far below any real column's norm.
_GUARD = 2.0**-900


def lm_least_squares(fun, x0, *, x_scale=None, batched: bool = False, stop=None, **options):
    """``scipy.optimize.least_squares(fun, x0, method="lm", ...)`` with a guard: a last parameter z, residual
    ``_GUARD z`` (0: LM keeps z at 0), read by no other residual. SciPy's C MINPACK (1.16.3, 1.17.1) recomputes a
    column's norm one element too far (qrfac), past the last column into heap garbage, so a solve could end in two
    places; the guard is pivoted last and reads a zero there, every other number unchanged. ``batched``: ``fun``
    takes (K, n) points (the finite differences' as one batch). ``x``, ``fun``, ``jac`` without the guard; ``nfev``
    and ``max_nfev`` count LM's steps (SciPy >= 1.16's "lm" counts no finite difference). ``stop(x)`` (``batched``
    only) returns a reason to end the solve at an iterate LM accepted (its Jacobian's): status -1, that message."""
    n, last = len(x0), {"n": 0}  # last: the latest point's residuals (the guard's finite difference is at that point)
    def guarded(q):
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 1:  # (batched: a step, what SciPy's nfev counts)
            last.update(key=q[:n].tobytes(), x=q[:n].copy(), r=fun(q[:n]), n=last["n"] + 1)
            return np.append(last["r"], _GUARD * q[n])
        if stop is not None and (why := stop(last["x"])):
            raise _RanOff(last["x"], why)
        rows = [last["r"] if p.tobytes() == last.get("key") else None for p in q[:, :n]]  # each its point's alone
        todo = [k for k, v in enumerate(rows) if v is None]
        for k, v in zip(todo, fun(q[todo, :n]) if todo else ()):
            rows[k] = v
        return np.column_stack([np.array(rows), _GUARD * q[:, n]])

    kw = {"workers": lambda f, qs: list(guarded(np.array(list(qs))))} if batched else {}
    scale = None if x_scale is None else np.append(x_scale, 1.0)
    opt = require("scipy.optimize")
    try:
        r = opt.least_squares(guarded, np.append(np.asarray(x0, np.float64), 0.0), method="lm", x_scale=scale,
                              **kw, **options)
    except _RanOff as off:  # (the residuals are its point's, the last evaluated)
        return opt.OptimizeResult(x=off.args[0], fun=last["r"], cost=0.5 * float(last["r"] @ last["r"]), status=-1,
                                  message=off.args[1], nfev=last["n"])
    r.x, r.fun, r.jac = r.x[:n], r.fun[:-1], r.jac[:-1, :n]
    return r


def _leastsq(opt, fun, jac, q, w, **options):
    """``opt.leastsq(fun, q, args=(w,), Dfun=jac, ...)``'s ``(q, ier)`` with :func:`lm_least_squares`' guard column."""
    n = len(q)
    def jac_g(z, w):
        J = jac(z[:n], w)
        out = np.zeros((len(J) + 1, n + 1))  # [[J, 0], [0, _GUARD]]
        out[:-1, :n], out[-1, n] = J, _GUARD
        return out

    z, ier = opt.leastsq(lambda z, w: np.append(fun(z[:n], w), _GUARD * z[n]), np.append(q, 0.0), args=(w,),
                         Dfun=jac_g, **options)
    return z[:n], ier


#: Levenberg-Marquardt's tolerances (MINPACK's ftol, xtol, gtol) in the light-aware fits: a relative
#: cost change below 1e-8 leaves the solution within about ``1e-4 sqrt(m)`` standard deviations (m residuals).
_LM_TOL = 1e-8

#: The same for the first pass of a reweighted fit, which only sets the second's weights (a second-order effect).
_LM_TOL_FIRST_PASS = 1e-4
#: LM's tolerance before :func:`_newton`, the pass' evaluations after which it runs, its largest step (else LM)
_LM_TOL_NEWTON, _NEWTON_AFTER, _NEWTON_STEP = 1e-5, 10, 0.1


class _RanOff(Exception):
    """Raised in the model of :func:`_solve` or :func:`lm_least_squares` where ``stop`` says the iterate ran off."""


def _solve(resjac, p0, args, loss: str, f_scale: float, max_nfev: int, free=None,
           lazy_jac: bool = False, weighted: bool = False, newton: bool = False, stop=None):
    """Levenberg-Marquardt (MINPACK's lmder via :func:`scipy.optimize.leastsq`), robust loss by reweighting.

    ``loss="linear"``: one solve; ``soft_l1``, ``huber``, ``cauchy``: the solution reweighted once by
    ``sqrt(rho'(z))``, ``z = (r / f_scale)^2`` (scipy's robust losses), and solved again.
    ``resjac(p, *args, grad=...)`` returns residuals and (with ``grad``) the Jacobian. ``free`` (bool
    mask) holds the other parameters at ``p0``; ``lazy_jac``: trial points get the residuals alone;
    ``weighted``: the weights are passed to ``resjac`` as ``w=``; ``newton``: :func:`_newton` takes LM's
    linear tail; ``stop(p)`` returns a reason (non-empty string) to end the solve there, not converged.
    Returns ``(x, n_evaluations, converged, message, residuals at x)``.
    """
    opt = require("scipy.optimize")  # when first needed: scipy slows the start
    if loss not in ("linear", "soft_l1", "huber", "cauchy"):
        raise ValueError(f"loss: {loss!r} is not one of linear, soft_l1, huber, cauchy")
    p0 = np.asarray(p0, dtype=np.float64)
    free = np.ones(len(p0), bool) if free is None else np.asarray(free, bool)
    cache: dict = {}

    def full(q):
        p = p0.copy()
        p[free] = q
        return p

    def rj(q, grad=True):
        # MINPACK asks for J only at accepted points (those of its last f): lazy_jac computes it then
        grad = grad or not lazy_jac
        key = q.tobytes()
        if cache.get("key") != key or (grad and cache.get("J") is None):
            kw = {"w": model_w[0]} if weighted and model_w[0] is not None else {}
            r, J = resjac(full(q), *args, grad=grad, **kw)
            new = cache.get("key") != key
            cache.update(key=key, r=r, J=J if J is None or all_free else J[:, free])
            if new:
                count[0] += 1
                why = stop(full(q)) if stop is not None else ""
                if why:
                    raise _RanOff(q.copy(), why)
        return cache["r"], cache["J"]

    def fun(q, w):
        r = rj(q, grad=False)[0]
        return r if w is None else r * w

    def jac(q, w):
        J = rj(q)[1]
        return J if w is None else J * w[:, None]

    all_free = bool(free.all())
    model_w = [None]  # the weights resjac solves its linear part with (weighted only)
    count = [0]  # model evaluations (new points)
    q = p0[free]
    w = None  # unit weights
    ok, msg = True, ""
    try:
        for it in range(1 if loss == "linear" else 2):
            if it:
                z = (rj(q, grad=False)[0] / f_scale) ** 2
                if loss == "soft_l1":
                    w = (1.0 + z) ** -0.25
                elif loss == "huber":
                    w = np.where(z <= 1.0, 1.0, z ** -0.25)
                else:
                    w = (1.0 + z) ** -0.5
                if weighted:
                    model_w[0] = w
                    cache.clear()
            # without full_output leastsq skips a covariance and warns with its message when it stops short
            with np.errstate(all="ignore"), warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                # the first pass of a reweighted fit only sets the weights: looser tolerances
                tol = _LM_TOL if it or loss == "linear" else _LM_TOL_FIRST_PASS
                done, budget = False, max_nfev + count[0]
                if newton and (it or loss == "linear"):  # Newton's steps take LM's linear tail (_newton)
                    q, ier = _leastsq(opt, fun, jac, q, w, xtol=_LM_TOL_NEWTON, ftol=_LM_TOL_NEWTON, gtol=tol,
                                      maxfev=max_nfev)
                    late = count[0] + max_nfev - budget > _NEWTON_AFTER
                    q, done = _newton(fun, jac, q, w, tol) if late else (q, False)
                if not done:  # (the pass' evaluations within max_nfev)
                    q, ier = _leastsq(opt, fun, jac, q, w, xtol=tol, ftol=tol, gtol=tol,
                                      maxfev=max(budget - count[0], 1))
            ok = ier in (1, 2, 3, 4) and bool(np.isfinite(q).all())
            msg = "" if ier in (1, 2, 3, 4) else (str(caught[-1].message) if caught else f"MINPACK info {ier}")
    except _RanOff as off:  # (the residuals at its point are the cache's last)
        return full(off.args[0]), count[0], False, off.args[1], cache["r"]
    return full(q), count[0], ok, msg, rj(q, grad=False)[0]


def _newton(fun, jac, q, w, tol: float, steps: int = 6):
    """Newton's steps on ``|fun(q, w)|^2 / 2`` from ``q``, the Hessian once by forward differences of the
    gradient ``jac^T fun``. ``(q, converged)``: converged at a step below ``tol`` that did not raise the
    cost; else the last point that lowered it."""
    f0 = fun(q, w)
    g = jac(q, w).T @ f0
    eps = 1e-6 * np.maximum(np.abs(q), 1.0)
    H = np.empty((len(q), len(q)))
    for j in range(len(q)):
        d = q.copy()
        d[j] += eps[j]
        H[:, j] = (jac(d, w).T @ fun(d, w) - g) / eps[j]
    try:
        Hinv = np.linalg.inv(0.5 * (H + H.T))
    except np.linalg.LinAlgError:
        return q, False
    for _ in range(steps):
        step = -Hinv @ g
        if not (np.isfinite(step).all() and g @ step < 0 and np.abs(step).max() <= _NEWTON_STEP):
            return q, False  # not a descent (the Hessian is not positive definite there), or far
        f1 = fun(q + step, w)
        if not f1 @ f1 <= (f0 @ f0) * (1.0 + 1e-12):
            return q, False
        q, f0 = q + step, f1
        if np.all(np.abs(step) <= tol * (np.abs(q) + tol)):
            return q, True
        g = jac(q, w).T @ f0
    return q, False


#: Plausible roughness (simtest.decisions); outside, or a distance beyond DISTANCE_FACTOR_MAX, not converged.
_ROUGHNESS_RANGE = (1.0, phong_of_ggx_alpha(SMOOTHEST_FILM_ALPHA))
#: ... the range with the diffuse shading's column.
_ROUGHNESS_RANGE_SHADED = (phong_of_ggx_alpha(ROUGHEST_FILM_ALPHA), _ROUGHNESS_RANGE[1])


def _implausible(h_hat: float, h0: float, roughness: float | None, shaded: bool = False, widen: float = 1.0) -> str:
    """Why a fit's solution is implausible ("" when it is not); ``shaded``: the model holds the diffuse
    column; ``widen``: each range that much wider (:data:`~simtest.decisions.RUN_OFF_FACTOR`)."""
    f = _H_FACTOR * widen
    if not (np.isfinite(h_hat) and h0 / f <= h_hat <= h0 * f):
        return f"fitted distance {h_hat:.4g} mm is not within a factor {f:g} of the start's {h0:.4g} mm"
    lo, hi = _ROUGHNESS_RANGE_SHADED if shaded else _ROUGHNESS_RANGE
    lo, hi = lo / widen, hi * widen
    if roughness is not None and not (np.isfinite(roughness) and lo <= roughness <= hi):
        return (f"fitted roughness {roughness:.4g} outside ({lo:.4g}, {hi:.4g})"
                + (": a lobe as broad as the diffuse shading" if shaded and roughness < lo else ""))
    return ""


def _ran_off_near(h_hat: float, h0: float, roughness: float | None, shaded: bool = False) -> bool:
    """Whether an implausible fit ran off towards the camera: its distance below its start's range, or within it a
    lobe broader than the roughness range allows. A nearer plane images a wider lobe: nearer starts may reach it.
    One that ran off the other way (distance to infinity, every guide's lobe on one point, or a lobe sharper than
    any roughness) read one lobe where a plane at any depth shows each guide's: no start depth changes that."""
    lo = (_ROUGHNESS_RANGE_SHADED if shaded else _ROUGHNESS_RANGE)[0]
    return bool(np.isfinite(h_hat) and (h_hat < h0 / _H_FACTOR or (
        h_hat <= h0 * _H_FACTOR and roughness is not None and roughness < lo)))


def _finish(name, resjac_at, n_hat, h_hat, rig, extra_params, resid_floor, n_eval, converged,
            roughness=None, taus=None, detail="", post=None, n_linear=0):
    """Covariance about the solution, depth and its observability, and the estimate; ``post(estimate,
    residuals)`` returns the estimate to report, ``n_linear`` counts the projected-out parameters."""
    e1, e2 = plane_basis(n_hat)
    p_hat = np.concatenate([[0.0, 0.0, np.log(h_hat)], extra_params])
    r0, J = resjac_at(p_hat, n_hat, e1, e2)
    m, k = J.shape
    rr = float(r0 @ r0)
    resid_var = rr / max(m - k - n_linear, 1)
    unit_cov = _covariance(J, 1.0)  # (J^T J)^-1: scaled by the residual variance, or its floor
    cov = None if unit_cov is None else resid_var * unit_cov
    floor_var = max(resid_var, resid_floor**2)
    Lm = _mean_light(rig)
    sigma_deg = (None if cov is None else math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))))
    depth = specular_point_depth(n_hat, h_hat, Lm)
    g = _log_depth_gradient(n_hat, h_hat, Lm, (e1, e2))
    gcg = None if unit_cov is None else float(g @ unit_cov[:3, :3] @ g)  # g^T (J^T J)^-1 g
    rel_floor = None if gcg is None else math.sqrt(max(floor_var * gcg, 0.0))
    observable = rel_floor is not None and math.isfinite(depth) and rel_floor <= TOL.depth_rel_sigma_max
    if not converged:
        status = "not_converged"
    elif not observable:
        status = "depth_not_observable"
        detail = detail or ("J^T J singular in h" if rel_floor is None
                            else f"relative depth sigma {rel_floor:.3g} at the noise floor > {TOL.depth_rel_sigma_max}")
    else:
        status = OK
    depth_sigma = depth * math.sqrt(max(resid_var * gcg, 0.0)) if observable and cov is not None else None
    lights = _rig_arrays(rig)[0]
    light_depths = (np.array([specular_point_depth(n_hat, h_hat, L) for L in lights])
                    if observable and len(lights) > 1 else None)
    est = LightAwareEstimate(name, status, detail, n_hat, depth if observable else None, sigma_deg, depth_sigma,
                             h_hat if observable else None, roughness, taus, n_eval, math.sqrt(rr / m),
                             light_depths_mm=light_depths)
    return est if post is None else post(est, r0)


def _residual_correlation(r, sel, shape, step: int) -> tuple[float, float]:
    """``(rho, c)`` of the residuals ``r`` of neighbouring pixels ``sel`` (flat indices into ``shape``,
    sub-grid of spacing ``step``): ``rho = sum a b / sqrt(sum a^2 sum b^2)``, ``c = mean(a b)``."""
    R = np.full(int(np.prod(shape)), np.nan)
    R[sel] = r
    R = R.reshape(shape)
    a = np.concatenate([R[:, :-step].ravel(), R[:-step, :].ravel()])
    b = np.concatenate([R[:, step:].ravel(), R[step:, :].ravel()])
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    den = np.sqrt((a @ a) * (b @ b))
    if not (len(a) and den > 0):
        return 0.0, 0.0
    return float(a @ b / den), float(a @ b / len(a))


def _correlated(r, sel, shape, step: int) -> str | None:
    """The misfit detail when neighbouring residuals correlate (rho above ``TOL.plane_misfit_rho``,
    covariance above ``TOL.plane_misfit_rel^2``), else None."""
    rho, c = _residual_correlation(r, sel, shape, step)
    if rho > TOL.plane_misfit_rho and c > TOL.plane_misfit_rel**2:
        return (f"neighbouring residuals correlate (rho {rho:.3g} > {TOL.plane_misfit_rho}; "
                f"systematic RMS {np.sqrt(c):.3g})")
    return None


def _patch_verdict(rel_floor: float | None, r, sel, shape, step: int, ok_detail: str,
                   misfit_hint: str) -> tuple[str, str, bool, float]:
    """``(status, detail, observable, rms)`` of a curved-patch fit: ``depth_not_observable`` where
    ``rel_floor`` is None or above ``TOL.depth_rel_sigma_max``; ``patch_misfit`` where the residuals
    correlate or their RMS exceeds ``TOL.patch_misfit_rms_rel`` (detail ending in ``misfit_hint``)."""
    observable = rel_floor is not None and rel_floor <= TOL.depth_rel_sigma_max
    status, detail = OK, ok_detail
    if not observable:
        status = "depth_not_observable"
        detail = ("J^T J singular" if rel_floor is None else
                  f"relative depth sigma {rel_floor:.3g} at the noise floor > {TOL.depth_rel_sigma_max}")
    correlated = _correlated(r, sel, shape, step)
    rms = float(np.sqrt(np.mean(r * r)))
    if correlated:
        status, observable, detail = "patch_misfit", False, correlated
    elif rms > TOL.patch_misfit_rms_rel:
        status, observable = "patch_misfit", False
        detail = f"residual RMS {rms:.3g} of the ROI's maximum > {TOL.patch_misfit_rms_rel}: {misfit_hint}"
    return status, detail, observable, rms


#: False-alarm probability of :func:`_curvature_score`'s test on a plane with white noise (chi-square 3 dof: 21.1).
_CURVATURE_ALPHA = 1e-4


def _curvature_score(cols, span, r, grid=None) -> str | None:
    """The score (Lagrange multiplier) test [2]_ of the plane fit against a curved patch.

    ``T = |Qc^T r|^2 / s^2`` (Qc: ``cols`` (M, 3), the image's derivatives in the curvatures, made
    orthonormal and orthogonal to ``span``, the plane fit's Jacobian and linear columns) is chi-square
    with 3 dof on a plane with white noise; with ``grid = (sel, shape, step)`` it is divided by the
    correlation area (:func:`_correlation_area`) of the residual outside the pattern. Returns the
    misfit detail beyond :data:`_CURVATURE_ALPHA` with a curved RMS above ``TOL.plane_misfit_rel``,
    else None; False where no test can be made.

    References
    ----------
    .. [2] C. R. Rao, Proc. Cambridge Philos. Soc. 44(1), 1948 (the score test).
    """
    special = require("scipy.special")  # when first needed: scipy slows the start
    m, k = span.shape
    if m <= k + 3 or not np.isfinite(cols).all():
        return False
    Q = np.linalg.qr(span)[0]
    Cp = cols - Q @ (Q.T @ cols)
    U, sv, _ = np.linalg.svd(Cp, full_matrices=False)
    U = U[:, sv > 1e-9 * max(float(sv.max()), 1e-300)]
    if U.shape[1] == 0:
        return False
    z = U.T @ r
    zz = float(z @ z)
    s2 = max(float(r @ r) - zz, 0.0) / (m - k - U.shape[1])
    if not s2 > 0:
        return False
    T = zz / s2
    if grid is not None:
        T /= _correlation_area(r - U @ z, *grid)
    rms = math.sqrt(zz / m)
    if T > special.chdtri(U.shape[1], _CURVATURE_ALPHA) and rms > TOL.plane_misfit_rel:
        return (f"the residual holds a curved patch's pattern (score {T:.3g} > "
                f"{special.chdtri(U.shape[1], _CURVATURE_ALPHA):.3g}; RMS {rms:.3g})")
    return None


def _curvature_shift(cols, span, r) -> tuple[float, float] | None:
    """How far the curvature pattern in a plane fit's residual would move the plane: ``(normal shift
    deg, relative distance shift)`` of the Gauss-Newton step ``[span, cols] beta = -r``; None where
    degenerate."""
    A = np.column_stack([span, cols])
    if len(r) <= A.shape[1] or not np.isfinite(A).all():
        return None
    beta, _, rank, _ = np.linalg.lstsq(A, -np.asarray(r, dtype=np.float64), rcond=None)
    if rank < A.shape[1] or not np.isfinite(beta[:3]).all():
        return None
    return math.degrees(math.hypot(float(beta[0]), float(beta[1]))), abs(float(beta[2]))


def _misfit(est: LightAwareEstimate, r, sel, shape, step: int) -> LightAwareEstimate:
    """``est`` with status ``plane_misfit`` (depth withdrawn) when neighbouring residuals correlate
    (:func:`_correlated`)."""
    correlated = est.status in (OK, "depth_not_observable") and _correlated(r, sel, shape, step)
    return est.without_depth("plane_misfit", correlated) if correlated else est


#: Longest correlation length, in sub-grid steps, that :func:`_hac_covariance` spans.
_HAC_MAX_LAG = 24


def _hac_covariance(J, r, sel, shape, step: int) -> tuple[np.ndarray | None, int]:
    """The HAC (sandwich) covariance (k, k) of a fit whose residuals correlate between nearby pixels,
    and its bandwidth b; None (and 0) when J^T J is singular.

    ``C = (J^T J)^-1 M (J^T J)^-1``, ``M = sum_ij w(i - j) g_i g_j^T``, ``g_i = J_i r_i`` over the
    residuals ``r`` (M,) of the pixels ``sel`` (flat indices into ``shape``, sub-grid ``step``), J (M, k),
    with a separable Bartlett window [1]_ of ``b = ceil(-3 / log rho_1)`` sub-grid steps (at most
    :data:`_HAC_MAX_LAG`; 0, White's sandwich, for uncorrelated residuals).

    References
    ----------
    .. [1] W. K. Newey, K. D. West, "A simple, positive semi-definite, heteroskedasticity and
           autocorrelation consistent covariance matrix", Econometrica 55(3), 1987.
    """
    ndi = require("scipy.ndimage")  # when first needed: scipy slows the start
    unit_cov = _covariance(J, 1.0)
    if unit_cov is None:
        return None, 0
    rho, _ = _residual_correlation(r, sel, shape, step)
    b = 0 if not rho > 0 else min(_HAC_MAX_LAG, int(math.ceil(-3.0 / math.log(min(rho, 0.999)))))
    Hs, Ws = -(-shape[0] // step), -(-shape[1] // step)
    rows, cols = np.divmod(np.asarray(sel), shape[1])
    k = J.shape[1]
    G = np.zeros((k, Hs, Ws))
    G[:, rows // step, cols // step] = (J * r[:, None]).T
    if b > 0:
        w = 1.0 - np.abs(np.arange(-b, b + 1)) / (b + 1.0)
        KG = ndi.convolve1d(ndi.convolve1d(G, w, axis=1, mode="constant"), w, axis=2, mode="constant")
    else:
        KG = G
    meat = np.einsum("kij,lij->kl", G, KG)
    meat = 0.5 * (meat + meat.T)
    return unit_cov @ meat @ unit_cov, b


def cluster_blocks(shape, texture: bool = True) -> tuple[int, ...]:
    """The block sides of :data:`CLUSTER_PX` (the first two without ``texture``) whose grid over an ROI of
    ``shape`` holds at least :data:`MIN_CLUSTERS` blocks; the smallest side always."""
    h, w = int(shape[0]), int(shape[1])
    sides = CLUSTER_PX if texture else CLUSTER_PX[:2]
    ok = tuple(b for b in sides if (-(-h // b)) * (-(-w // b)) >= MIN_CLUSTERS)
    return ok or CLUSTER_PX[:1]


def _cluster_terms(J, r, sel, width: int) -> tuple:
    """What :func:`_cluster_covariance` reads for every block side: ``(unit_cov or None, rows, cols, X, J^T J)``,
    X the per-pixel products ``J^T r`` and the upper triangle of ``J^T J`` (k + k (k + 1) / 2 rows)."""
    unit_cov = _covariance(J, 1.0)
    rows, cols = np.divmod(np.asarray(sel), width)
    Jt = np.ascontiguousarray(J.T)
    iu, ju = np.triu_indices(J.shape[1])  # J_c^T J_c is symmetric: its upper triangle summed, then mirrored
    return unit_cov, rows, cols, np.concatenate([Jt * np.asarray(r, np.float64), Jt[iu] * Jt[ju]]), J.T @ J


def _cluster_covariance(J, r, sel, shape, block: int = CLUSTER_PX[0], terms=None) -> np.ndarray | None:
    """The cluster-robust covariance (k, k) over ``block`` x ``block`` px blocks: the delete-one-block
    jackknife (CR3 [8]_); None when J^T J is singular or fewer than two blocks hold pixels.

    Per block c, ``d_c = (J^T J - J_c^T J_c)^-1 J_c^T r_c`` and
    ``C = (G - 1) / G sum_c (d_c - mean d)(d_c - mean d)^T`` over the G blocks that hold pixels;
    ``J``, ``r``, ``sel``, ``shape`` as :func:`_hac_covariance`'s; ``terms``: their :func:`_cluster_terms`, if at
    hand (several block sides of one fit).

    References
    ----------
    .. [8] A. C. Cameron, D. L. Miller, "A practitioner's guide to cluster-robust inference",
           J. Human Resources 50(2), 317-372, 2015. https://doi.org/10.3368/jhr.50.2.317
    """
    unit_cov, rows, cols, X, A = _cluster_terms(J, r, sel, shape[1]) if terms is None else terms
    if unit_cov is None:
        return None
    cid = (rows // block) * -(-shape[1] // block) + cols // block  # raster order of the blocks
    held = np.flatnonzero(np.bincount(cid))  # the blocks that hold pixels
    if (G := len(held)) < 2:
        return None
    k = J.shape[1]
    iu, ju = np.triu_indices(k)
    sums = np.stack([np.bincount(cid, x)[held] for x in X], axis=1)  # per block: J_c^T r_c, J_c^T J_c
    S, rest = sums[:, :k], np.empty((G, k, k))
    rest[:, iu, ju] = rest[:, ju, iu] = A[iu, ju] - sums[:, k:]  # J^T J without each block's rows
    # a block whose removal leaves J^T J (near) singular is counted as the plain sandwich counts it
    ev = np.linalg.eigvalsh(rest)
    ok = ev[:, 0] > 1e-9 * np.maximum(ev[:, -1], 1e-300)
    D = S @ unit_cov.T
    if ok.any():
        D[ok] = np.linalg.solve(rest[ok], S[ok][..., None])[..., 0]
    D -= D.mean(axis=0)
    return (D.T @ D) * ((G - 1.0) / G)


def _correlation_area(r, sel, shape, step: int) -> float:
    """Fitted pixels per independent residual (>= 1): the residuals' 2-D autocorrelation summed within
    its radial mean's first zero crossing (A. D. Sokal's window, NATO ASI Series B 361, 1997). One real FFT
    of the residuals and the pixels (Hs x Ws), zero-padded by at least ``min(Hs, Ws) // 2``, the window's
    longest lag: none of the lags read wraps round onto one that holds pairs."""
    fft = require("scipy.fft")  # when first needed: scipy slows the start
    Hs, Ws = -(-shape[0] // step), -(-shape[1] // step)
    rows, cols = np.divmod(np.asarray(sel), shape[1])
    both = np.zeros((2, Hs, Ws))  # the pixels fitted (1) and their residuals about the mean
    both[:, rows // step, cols // step] = np.stack([np.ones(len(r)), r - float(np.mean(r))])
    nrad = int(min(Hs, Ws) // 2)
    size = (fft.next_fast_len(Hs + nrad, real=True), fft.next_fast_len(Ws + nrad, real=True))
    pairs, prods = fft.irfft2(np.abs(fft.rfft2(both, s=size)) ** 2, s=size)
    pairs = np.rint(pairs)  # counts of pixel pairs at each lag (the FFT's rounding taken off)
    var = float(prods[0, 0]) / max(float(pairs[0, 0]), 1.0)
    if not var > 0:
        return 1.0
    rad = np.rint(np.hypot(*np.meshgrid(*(np.fft.fftfreq(n, 1.0 / n) for n in size), indexing="ij"))).astype(int)
    use = (pairs > 0.5 * float(pairs[0, 0]) / 4.0) & (rad <= nrad)  # an eighth of the pairs, in reach
    acf = np.where(use, prods / np.maximum(pairs, 1.0), 0.0) / var
    counts = np.bincount(rad[use], minlength=nrad + 1)
    radial = np.bincount(rad[use], acf[use], minlength=nrad + 1) / np.maximum(counts, 1)
    zero = np.flatnonzero((radial[1:] <= 0) | (counts[1:] == 0))
    cut = int(zero[0]) + 1 if len(zero) else nrad + 1
    return max(float(acf[use & (rad < cut)].sum()), 1.0)
