"""The isocurve fit: the general specular isocurve (paper eq. 2) fitted to isophote points."""

from __future__ import annotations

import numpy as np

from simtest._lazy import require
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.reconstruct._pixels import uv_to_rc
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import _camera, _normal_derivs, _ray_light, _rays, _terms
from simtest.reconstruct.lightaware.plane_solve import start_depths
from simtest.reconstruct.lightaware.solve import _bisector_plane, _finish, _implausible, _solve, _start


def refine_isophote_points(values, level: float, points_uv, origin_uv=(0.0, 0.0), iterations: int = 3) -> np.ndarray:
    """Move contour points onto the level set of the cubic-spline interpolant of an image.

    Marching squares' linear interpolation leaves points a few hundredths of a pixel inside a convex
    isophote, which biases the distance a light-aware fit reads from its shape. Newton steps on the
    cubic B-spline interpolant (gradient by central differences, 0.25 px); points whose step would
    exceed 1 px stay where they were.

    Parameters
    ----------
    values : ndarray of shape (H, W)
        Intensities (the ROI).
    level : float
        The isophote's level, in the units of ``values``.
    points_uv : ndarray of shape (N, 2)
        Contour points (u, v) in image px.
    origin_uv : array_like of shape (2,)
        Pixel (u, v) of ``values[0, 0]``.
    iterations : int
        Newton steps.

    Returns
    -------
    ndarray of shape (N, 2)
        Refined points (u, v), px.
    """
    ndi = require("scipy.ndimage")  # when first needed: scipy slows the start
    coef = ndi.spline_filter(np.asarray(values, dtype=np.float64), order=3, mode="mirror")
    o = np.asarray(origin_uv, dtype=np.float64)
    p = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2) - o
    p0 = p.copy()

    def f(q):
        return ndi.map_coordinates(coef, uv_to_rc(q).T, order=3, mode="mirror", prefilter=False)

    e = 0.25
    for _ in range(iterations):
        gu = (f(p + [e, 0]) - f(p - [e, 0])) / (2 * e)
        gv = (f(p + [0, e]) - f(p - [0, e])) / (2 * e)
        g2 = gu * gu + gv * gv
        step = np.where(g2 > 0, (f(p) - level) / np.where(g2 > 0, g2, 1.0), 0.0)
        p = p - step[:, None] * np.column_stack([gu, gv])
    bad = ~np.isfinite(p).all(axis=1) | (np.linalg.norm(p - p0, axis=1) > 1.0)
    p[bad] = p0[bad]
    return p + o


def _taus_of(q, n_tau, log_t) -> np.ndarray:
    """The levels tau_k of ``q``: tau (one isophote), or ``exp((log t_k - log s) / n)``, ``q = (1/n, log s)``."""
    if n_tau == 1:
        return np.array([q[0]])
    return np.exp((log_t - q[1]) * q[0])  # q = (1/n, log s)


def _pixel_weights(dT_pm, rl_pm, L, n, h) -> np.ndarray:
    """Pixel-unit weights 1 / |grad_px cos beta| at a start, from the rays ``dT_pm`` 0.5 px either side."""
    cu, cu2, cv, cv2 = _terms(dT_pm, n, h, L, rl_pm)[0].reshape(4, -1)
    grad = np.hypot(cu - cu2, cv - cv2)
    return 1.0 / np.maximum(grad, 1e-12 + 1e-6 * np.median(grad))


def _tau_start(cb0, kidx, n_members, log_t, n_tau, wts):
    """Levels from the mean cos beta ``cb0`` of each point set at a start plane, and the start's cost."""
    tau0 = np.clip(np.bincount(kidx, weights=cb0, minlength=len(log_t)) / n_members, 1e-3,
                   1 - 1e-9)  # the mean cos beta of each point set
    if n_tau == 1:
        q = tau0
    else:  # fit log tau_k = (log t_k - log s) / n to the start levels (a least-squares line)
        xc = log_t - log_t.mean()
        lt = np.log(tau0)
        inv_n = float(xc @ (lt - lt.mean())) / float(xc @ xc)
        c = inv_n * log_t.mean() - lt.mean()
        inv_n = inv_n if inv_n > 0 else 1.0 / 50.0
        q = np.array([inv_n, c / inv_n])
    r = (cb0 - _taus_of(q, n_tau, log_t)[kidx]) * wts
    return q, float(r @ r)


def isocurve_fit(points_uv, isovalues, bp_uv, camera, rig: LightRig, *, nominal_depth_mm: float = 20.0,
                 start_normal=None, loss: str = "soft_l1", f_scale_px: float = 0.5,
                 max_points_per_isophote: int | None = 64, n_start_depths: int = 0,
                 max_nfev: int = 200) -> LightAwareEstimate:
    """Fit the general specular isocurve (paper eq. 2) with a calibrated light to isophote points.

    Each contour point is a ray meeting the plane (n, h); its residual is
    ``(cos beta_i - tau_k) / |grad cos beta_i|``, the distance in px to the model isophote at first
    order. One isovalue: tau is free; several: ``log tau_k = (log t_k - log s) / n`` ties them through
    the roughness n. Levenberg-Marquardt with a robust loss by one reweighting.

    Parameters
    ----------
    points_uv : sequence of ndarray of shape (N_k, 2)
        Isophote points per isovalue, undistorted px (pixel centres at integer coordinates).
    isovalues : sequence of float
        t_k in (0, 1), relative to the BP intensity, one per point set.
    bp_uv : array_like of shape (2,)
        Brightest point, undistorted px (for the start).
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        Exactly one light (its falloff and profile are ignored).
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. the cone axis) in place of the bisector.
    loss : str
        ``soft_l1``, ``huber``, ``cauchy`` or ``linear``.
    f_scale_px : float
        Soft margin of the robust loss, px.
    max_points_per_isophote : int or None
        Keep every k-th point of a longer contour (None keeps all).
    n_start_depths : int
        Further starts along the BP's constraint (nominal/8 to nominal*8); the cheapest is refined.
    max_nfev : int
        Evaluation budget.

    Returns
    -------
    LightAwareEstimate
        ``estimator="isocurve_fit"``; ``taus`` per isovalue; ``roughness`` with >= 2 isovalues.

    Raises
    ------
    ValueError
        Mismatched points and isovalues, an isovalue outside (0, 1), a non-finite BP.
    """
    sets = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points_uv]
    ts = np.asarray(isovalues, dtype=np.float64).reshape(-1)
    if len(sets) != len(ts) or not len(ts):
        raise ValueError(f"points_uv and isovalues: need one point set per isovalue, got {len(sets)} and {len(ts)}")
    if np.any(~((ts > 0) & (ts < 1))):
        raise ValueError(f"isovalues: each in (0, 1), got {ts.tolist()}")
    name = "isocurve_fit"
    camera = _camera(camera)
    if len(rig.lights) != 1:
        return LightAwareEstimate(name, "multi_light_rig", f"{len(rig.lights)} lights")
    L = np.asarray(rig.lights[0].position_mm, dtype=np.float64)
    n_tau = 1 if len(ts) == 1 else 2
    n_all = sum(len(ps) for ps in sets)
    if n_all < 3 + n_tau + 1:
        return LightAwareEstimate(name, "too_few_points", f"{n_all} points")
    if max_points_per_isophote:  # every k-th point of a longer contour
        sets = [ps[::max(1, -(-len(ps) // max_points_per_isophote))] for ps in sets]
    uv = np.concatenate(sets)
    kidx = np.repeat(np.arange(len(sets)), [len(ps) for ps in sets])
    # the contour points' rays and, for the pixel-unit weights, those 0.5 px either side in u, v
    m_pts = len(uv)
    offs = np.array([[0.0, 0.0], [0.5, 0], [-0.5, 0], [0, 0.5], [0, -0.5]])
    dT_all = np.ascontiguousarray(_rays(camera, (uv[None] + offs[:, None]).reshape(-1, 2)).T)
    Ld_all, K2_all = _ray_light(L, dT_all)
    dT, rl = dT_all[:, :m_pts], (Ld_all[:m_pts], K2_all[:m_pts])
    dT_pm, rl_pm = dT_all[:, m_pts:], (Ld_all[m_pts:], K2_all[m_pts:])
    d_bp, n0, h0 = _start(bp_uv, camera, rig, nominal_depth_mm, start_normal)
    log_t = np.log(ts)
    n_members = np.bincount(kidx, minlength=len(ts))
    wts = _pixel_weights(dT_pm, rl_pm, L, n0, h0)
    log_tk = log_t[kidx]  # per point

    def resjac_at(p, nb, e1, e2, grad=True):
        n, dns = _normal_derivs(p, nb, e1, e2)
        cb, *_, dcb = _terms(dT, n, np.exp(p[2]), L, rl, dns=dns if grad else None)
        if n_tau == 1:
            tkw = p[3] * wts
        else:
            ltk = log_tk - p[4]
            tkw = np.exp(ltk * p[3]) * wts  # tau_k per point, weighted
        r = cb * wts - tkw
        if not grad:
            return r, None
        JT = np.empty((3 + n_tau, len(r)))
        JT[:3] = dcb * wts
        if n_tau == 1:
            JT[3] = -wts
        else:
            JT[3] = -tkw * ltk
            JT[4] = tkw * p[3]
        return r, JT.T

    def tau_start(n, h):
        """Levels and start cost at (n, h)."""
        return _tau_start(_terms(dT, n, h, L, rl)[0], kidx, n_members, log_t, n_tau, wts)

    # start: the given one and planes along the BP's constraint (as in photometric_fit)
    cands = [(n0, h0)]
    if n_start_depths and np.linalg.norm(L) > 0:
        cands += [_bisector_plane(d_bp, L, sdep) for sdep in start_depths(nominal_depth_mm, n_start_depths)]
    q0, _, n0_c, h0_c = min((tau_start(n, h) + (n, h) for n, h in cands), key=lambda c: c[1])
    if n0_c is not n0:  # the weights and levels at the chosen start
        n0, h0 = n0_c, h0_c
        wts = _pixel_weights(dT_pm, rl_pm, L, n0, h0)
        q0 = tau_start(n0, h0)[0]
    e1, e2 = plane_basis(n0)
    p0 = np.concatenate([[0.0, 0.0, np.log(h0)], q0])
    free = np.ones(len(p0), bool)
    free[2] = np.linalg.norm(L) > 1e-9 * h0  # L = V: the image does not depend on h
    x, nfev, conv, msg, _ = _solve(resjac_at, p0, (n0, e1, e2), loss, f_scale_px, max_nfev, free)
    n_hat = _normal_derivs(x, n0, e1, e2)[0]
    h_hat = float(np.exp(x[2]))
    q = x[3:]
    bad = _implausible(h_hat, h0, None if n_tau == 1 else 1.0 / q[0])
    if bad:
        return LightAwareEstimate(name, "not_converged", bad, n_evaluations=nfev)
    if n_hat @ L + h_hat <= 0:
        return LightAwareEstimate(name, "light_behind_plane", f"h = {h_hat:.4g} mm", n_evaluations=nfev)
    return _finish(name, resjac_at, n_hat, h_hat, rig, q, TOL.isophote_noise_px, nfev, conv,
                   roughness=None if n_tau == 1 else float(1.0 / q[0]),
                   taus=_taus_of(q, n_tau, log_t), detail="" if conv else msg)
