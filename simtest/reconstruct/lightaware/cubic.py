"""The cubic patch fit: a third-order patch fitted to the lobes of every light of a rig
(:func:`cubic_patch_fit`), and its cost along the depth (:func:`patch_depth_profile`)."""

from __future__ import annotations

import numpy as np

from simtest.geometry.lights import LightRig
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.patch import (
    _PROFILE_FACTORS, _coarse_profile, _flat_start, _light_normals, _patch_problem, _patch_uncertainty, _sweep,
)
from simtest.reconstruct.lightaware.patch_geometry import PATCH_PARAMS as _CUBIC_PARAMS
from simtest.reconstruct.lightaware.patch_geometry import _cubic_patch_geometry, _cubic_patch_image
from simtest.reconstruct.lightaware.solve import _implausible, lm_least_squares

#: Largest ratio between neighbouring depths of :func:`patch_depth_profile`, whose fits start
#: from their neighbour's solution.
_PROFILE_STEP = 1.25

#: :func:`patch_depth_profile` also starts each depth from a flat patch whose Phong n is this
#: fraction of the start roughness: its wider lobes overlap image lobes that narrower ones miss.
_PROFILE_WIDE_START = 0.2


def _cubic_setup(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels):
    """The ROI's samples and the variable-projection residual of the cubic patch: None with too few
    unclipped pixels, else a dict of ``res(p)`` (11 parameters), ``b_ray``, ``Lm``, ``rig_arr``,
    ``x_scale``, ``sel``, ``step``, ``shape`` and ``m`` (pixels used)."""
    P, n_px = _patch_problem(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels, 2 * _CUBIC_PARAMS)
    if P is None:
        return None
    d, b_ray, rig_arr, Lm = P.d, P.b_ray, P.rig_arr, P.Lm

    def res(p):  # p (11,) or a batch (K, 11) (the finite differences' points)
        with np.errstate(all="ignore"):
            image = _cubic_patch_image(d, b_ray, p, rig_arr, Lm)[0]
        image = np.where(np.isfinite(image).all(axis=-1, keepdims=True), image, 0.0)  # overflow: no image
        return P.residual(image)

    px = P.px_per_rad
    x_scale = np.array([1.0 / px, 1.0 / px, 0.1, 0.1, 0.1, 0.1, 0.3, 0.1, 0.1, 0.1, 0.1])
    return {"res": res, "b_ray": b_ray, "Lm": Lm, "rig_arr": rig_arr, "x_scale": x_scale,
            "sel": P.sel, "step": P.step, "shape": P.shape, "m": n_px, "batched": True}


def patch_depth_profile(values, origin_uv, bp_uv, camera, rig: LightRig, depths_mm, *, clip_level: float | None = None,
                        cubic: bool = True, start_roughness: float | None = None, max_pixels: int | None = 800,
                        max_nfev: int = 100) -> np.ndarray:
    """The least misfit of a curved patch to the ROI with its apex depth fixed, depth by depth.

    The other parameters of :func:`cubic_patch_fit` are fitted at each depth from two flat patches
    (Phong n ``start_roughness`` and :data:`_PROFILE_WIDE_START` of it) and the neighbouring depth's
    solution (swept up and down, at most :data:`_PROFILE_STEP` apart). A profile that rises away from
    its minimum says the ROI fixes the depth.

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels
        As in :func:`photometric_fit`.
    depths_mm : array_like of shape (P,)
        Apex depths along the apex ray, mm (> 0).
    cubic : bool
        Fit the third-order terms too (else the quadric patch of :func:`quadric_fit`).
    start_roughness : float, optional
        Phong n of the flat start (default 50).
    max_nfev : int
        Budget per fit: ``max_nfev (k + 1)`` LM steps for k free parameters (finite differences not counted).

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
    flats = [_flat_start(n0, _CUBIC_PARAMS), _flat_start(_PROFILE_WIDE_START * n0, _CUBIC_PARAMS)]
    # the depths asked for, with steps of at most _PROFILE_STEP between them for the warm starts
    lo, hi = np.log(depths.min()), np.log(depths.max())
    grid = np.union1d(np.log(depths), np.linspace(lo, hi, int(np.ceil((hi - lo) / np.log(_PROFILE_STEP))) + 1))
    cost = _sweep(S, grid, free, flats, max_nfev, 1e-8)[0]
    return cost[np.searchsorted(grid, np.log(depths))]


def _apex_normal_gradient(b_ray, x, x_scale, Lm) -> np.ndarray:
    """dN / dp (3, 11) of the cubic patch's apex normal, by central differences of ``1e-6 x_scale``."""
    h = 1e-6 * np.asarray(x_scale, dtype=np.float64)
    N = _cubic_patch_geometry(b_ray[None], b_ray, np.concatenate([x + np.diag(h), x - np.diag(h)]), Lm)[3]
    return ((N[:_CUBIC_PARAMS] - N[_CUBIC_PARAMS:]) / (2 * h)[:, None]).T  # (the 22 patches as one batch)


def cubic_patch_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *, clip_level: float | None = None,
                    nominal_depth_mm: float = 20.0, start_roughness: float | None = None, max_pixels: int | None = 800,
                    max_nfev: int = 100, misfit_sigma: bool = True) -> LightAwareEstimate:
    """Fit the ROI with the image of a third-order surface patch lit by the whole rig.

    :func:`quadric_fit`'s patch plus the height function's third-order terms [2]_
    ``(c_xxx x^3 + 3 c_xxy x^2 y + 3 c_xyy x y^2 + c_yyy y^3) / 6``, ``c = gamma / s^2``: eleven
    parameters (a, b', log s, kappa, log n, gamma), the linear part by variable projection [3]_. A
    coarse quadric depth profile (:data:`_PROFILE_FACTORS`) starts the free fit. Two lights on
    opposite sides of the lens shift their lobes apart while the shape acts on both alike, which
    fixes the depth; under one light it is not observable.

    Parameters
    ----------
    values, origin_uv, bp_uv, camera, rig, clip_level, nominal_depth_mm, max_pixels
        As in :func:`photometric_fit`; ``nominal_depth_mm`` centres the profile's grid.
    start_roughness, max_nfev
        As in :func:`patch_depth_profile`.
    misfit_sigma : bool
        As :func:`quadric_fit`'s.

    Returns
    -------
    LightAwareEstimate
        ``estimator="cubic_patch_fit"``, status ``ok``, ``depth_not_observable``, ``patch_misfit``,
        ``not_converged`` or ``too_few_points``; ``distance_mm`` and ``depth_mm`` the apex depth s (the
        mean light's specular point); with an observable depth, each light's specular point
        (``light_normals`` (J, 3), ``light_depths_mm`` (J,), ``light_normal_sigmas_deg``);
        ``depth_rel_sigma``.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.

    References
    ----------
    .. [2] M. P. do Carmo, "Differential Geometry of Curves and Surfaces", Prentice-Hall, 1976,
           section 3-3 (the local height function and its Taylor terms).
    .. [3] G. H. Golub, V. Pereyra, SIAM J. Numer. Anal. 10(2), 1973. https://doi.org/10.1137/0710036
    """
    name = "cubic_patch_fit"
    S = _cubic_setup(values, origin_uv, bp_uv, camera, rig, clip_level, max_pixels)
    if S is None:
        return LightAwareEstimate(name, "too_few_points", f"fewer than {2 * _CUBIC_PARAMS} unclipped pixels")
    depths = float(nominal_depth_mm) * _PROFILE_FACTORS
    cost, sol, nfev = _coarse_profile(S, depths, start_roughness, max_nfev, _CUBIC_PARAMS)
    if not np.isfinite(cost).any():
        return LightAwareEstimate(name, "not_converged", "no finite profile", n_evaluations=nfev)
    i0 = int(np.argmin(cost))
    with np.errstate(all="ignore"):  # (batched: the finite differences' points as one batch)
        r = lm_least_squares(S["res"], sol[i0], x_scale=S["x_scale"], max_nfev=max_nfev * (_CUBIC_PARAMS + 1),
                             ftol=1e-8, xtol=1e-8, batched=True)
    nfev += r.nfev
    x = r.x
    s_hat, rough = float(np.exp(x[2])), float(np.exp(x[6]))
    bad = _implausible(s_hat, float(nominal_depth_mm), rough)
    if not np.isfinite(r.cost) or r.status <= 0 or bad:
        return LightAwareEstimate(name, "not_converged", bad or r.message, n_evaluations=nfev)
    b_ray, Lm = S["b_ray"], S["Lm"]
    n_hat = _cubic_patch_geometry(b_ray[None], b_ray, x, Lm)[3]
    G = _apex_normal_gradient(b_ray, x, S["x_scale"], Lm)
    status, detail, observable, rms, sigma_deg, valley, excess, depth_sigma, rel_floor, covs = _patch_uncertainty(
        r, S, S["sel"], S["shape"], S["step"], x, G, misfit_sigma, max_nfev,
        "the ROI is not one patch's lobes (streaks along folds, a lobe cut off)")
    if status == "ok":
        detail = f"profile minimum at {depths[i0]:.4g} mm; {detail}"
    ln, ld, lsig = _light_normals(observable, b_ray, x, Lm, S["rig_arr"][0], S["x_scale"], covs, valley, excess)
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None,
                              sigma_deg, depth_sigma, s_hat if observable else None, rough, None,
                              nfev, rms, ln, ld, rel_floor, light_normal_sigmas_deg=lsig)
