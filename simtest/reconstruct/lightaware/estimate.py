"""The result of every light-aware estimator (:class:`LightAwareEstimate`) and its statuses."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from simtest.decisions import ON_PLANE_MM


OK = "ok"

#: Status of a light-aware estimate, with its meaning.
STATUSES: dict[str, str] = {
    OK: "normal and depth estimated",
    "depth_not_observable": "normal estimated; the depth is not (epsilon/d too small: the image "
                            "hardly depends on the distance; or a curved patch under one light, "
                            "whose depth trades with its third-order shape)",
    "not_converged": "the least-squares fit stopped without meeting its tolerances",
    "too_few_points": "fewer isophote points or unclipped pixels than parameters",
    "multi_light_rig": "the isocurve model (eq. 2) holds for one light; use photometric_fit",
    "light_behind_plane": "a light of the rig lies behind the fitted surface (the fitted plane, or the "
                          "fitted patch's tangent plane at its specular point): no light there lights "
                          "the side the camera sees; the normal is kept for the record, the depth "
                          "withdrawn",
    "patch_misfit": "the quadric patch does not fit the ROI (spatially correlated residuals); "
                    "the normal is kept for the record, the depth withdrawn",
    "guide_misfit": "the fitted plane puts another guide's specular point where the image shows no "
                    "highlight of it (away from the highlight the rig pairs with this one, or in the "
                    "frame where none rises): one guide's lobe alone hardly tells which guide lit it, "
                    "and the fit took the other guide's plane; the normal is kept for the record, the "
                    "depth withdrawn",
    "glint_field": "the fit's ROI holds more specular peaks than the rig has light places (a smooth patch shows "
                   "one lobe per place): a glint field of micro-relief or folds, which no plane or quadric images; "
                   "not fitted",
    "plane_misfit": "the plane model does not fit the ROI (its residuals are spatially correlated, "
                    "or hold a curved patch's pattern); the normal is kept for the record, the "
                    "depth withdrawn",
}


@dataclass(frozen=True)
class LightAwareEstimate:
    """Result of a light-aware estimator.

    Attributes
    ----------
    estimator : str
        ``"bisector"``, ``"isocurve_fit"``, ``"photometric_fit"``, ``"quadric_fit"`` or ``"cubic_patch_fit"``.
    status : str
        A key of :data:`STATUSES`.
    detail : str
        Numbers behind the status.
    normal : ndarray of shape (3,) or None
        Unit normal, OpenCV camera frame, facing the camera.
    depth_mm : float or None
        Distance from the camera centre to the specular point along its ray, mm; None when not observable.
    normal_sigma_deg : float or None
        1-sigma angular uncertainty of the normal (RMS angle), degrees.
    depth_sigma_mm : float or None
        1-sigma uncertainty of the depth, mm (None when the depth is not observable).
    distance_mm : float or None
        Fitted camera-to-plane distance h, mm (None when not observable).
    roughness : float or None
        Fitted Phong roughness n; for a GGX lobe the Phong n of the same peak curvature.
    taus : ndarray of shape (K,) or None
        Fitted cosine level tau per isovalue (isocurve_fit).
    n_evaluations : int
        Levenberg-Marquardt steps of the fit's solves (finite differences not counted; 0 for the closed form).
    residual_rms : float or None
        RMS residual at the solution (px for the isocurve fit; fraction of the ROI's maximum otherwise).
    light_normals : ndarray of shape (J, 3) or None
        :func:`cubic_patch_fit`: the patch's unit normal at each light's specular point, camera frame.
    light_depths_mm : ndarray of shape (J,) or None
        Depth of each light's specular point, mm, under several lights (``depth_mm`` is the mean light's).
    depth_rel_sigma : float or None
        Curved patches: the depth's relative 1-sigma with the residual variance floored at
        ``TOL.photometric_noise_rel``; None when J^T J is singular.
    bp_ray_error_deg : float or None
        The BP ray's expected error next to this fit, degrees (half the angle the mean light subtends
        at the specular point); set by :func:`simtest.reconstruct.light_fits.light_aware_estimates`.
    lobe : str or None
        :func:`photometric_fit`: the lobe of the model kept, ``"phong"``, ``"ggx"`` or ``"blinn"``.
    n_residuals : int
        :func:`photometric_fit`: the number of pixels fitted; 0 elsewhere.
    light_normal_sigmas_deg : ndarray of shape (J,) or None
        :func:`cubic_patch_fit`: the 1-sigma of each of ``light_normals``, degrees.
    depth_range_mm : tuple of float or None
        :func:`quadric_fit` under one light: the depths (near, far), mm, the data cannot exclude
        (:data:`~simtest.decisions.ONE_LIGHT_DEPTH_FACTOR`); the depth itself is then None.
    projection : str or None
        :func:`photometric_fit` on RGB: ``"body_colours"``, ``"least_fluctuation"`` or ``"darkest_channel"``.
    curvature_shift_deg : float or None
        :func:`photometric_fit`: the normal's shift by a curved pattern within its sigma, degrees,
        already added to ``normal_sigma_deg``.
    fitted_distance_mm : float or None
        :func:`photometric_fit`: the plane distance h at the solution, mm, kept where the status withdraws
        ``distance_mm`` (another lobe's fit starts from that plane); None where the fit did not solve.
    guide_spread_deg : float or None
        A fit without its depth under two or more guides that the image does not tell apart: the largest
        angle between its normal and the normal of a lobe lit by one guide alone at the BP, degrees,
        already added to ``normal_sigma_deg`` in quadrature
        (:func:`~simtest.reconstruct.recommend.guide_spread_deg`).
    run_off_near : bool
        A ``not_converged`` :func:`photometric_fit` that ran off towards the camera, which one channel's fit tries
        again from further starts (:func:`~simtest.reconstruct.lightaware.solve._ran_off_near`).
    """

    estimator: str
    status: str
    detail: str = ""
    normal: np.ndarray | None = None
    depth_mm: float | None = None
    normal_sigma_deg: float | None = None
    depth_sigma_mm: float | None = None
    distance_mm: float | None = None
    roughness: float | None = None
    taus: np.ndarray | None = None
    n_evaluations: int = 0
    residual_rms: float | None = None
    light_normals: np.ndarray | None = None
    light_depths_mm: np.ndarray | None = None
    depth_rel_sigma: float | None = None
    bp_ray_error_deg: float | None = None
    lobe: str | None = None
    n_residuals: int = 0
    light_normal_sigmas_deg: np.ndarray | None = None
    depth_range_mm: tuple[float, float] | None = None
    projection: str | None = None
    curvature_shift_deg: float | None = None
    guide_spread_deg: float | None = None
    fitted_distance_mm: float | None = None
    run_off_near: bool = False

    @property
    def ok(self) -> bool:
        """True when the status is ``"ok"`` (normal and depth given)."""
        return self.status == OK

    def without_depth(self, status: str, detail: str) -> "LightAwareEstimate":
        """This estimate with ``depth_mm``, ``depth_sigma_mm``, ``distance_mm`` and ``light_depths_mm`` None.

        Parameters
        ----------
        status : str
            The new status, a key of :data:`STATUSES`.
        detail : str
            Why the depth is withdrawn.
        """
        return replace(self, status=status, detail=detail, depth_mm=None, depth_sigma_mm=None,
                       distance_mm=None, light_depths_mm=None)

    def noted(self, why: str) -> "LightAwareEstimate":
        """This estimate with ``why`` appended to its detail."""
        return replace(self, detail=f"{self.detail}; {why}" if self.detail else why)

    @property
    def has_normal(self) -> bool:
        """True when a normal is given (status ``ok`` or ``depth_not_observable``)."""
        return self.normal is not None


def light_behind_surface(est: LightAwareEstimate, ray, lights_mm) -> LightAwareEstimate:
    """``est``, or ``est`` with status ``light_behind_plane`` where its fitted surface hides a light.

    A light L is behind the surface at ``P = depth_mm * ray`` where ``(L - P) . n`` and the camera's
    ``(0 - P) . n`` have opposite signs by more than :data:`ON_PLANE_MM`: it lights the far side.

    Parameters
    ----------
    est : LightAwareEstimate
        A fit; only one with a normal and a depth is checked.
    ray : array_like of shape (3,)
        Unit viewing ray of the highlight's BP, camera frame.
    lights_mm : array_like of shape (J, 3)
        The rig's light positions, mm, camera frame.

    Returns
    -------
    LightAwareEstimate
        ``est`` unchanged, or with the depth withdrawn and the light named in ``detail``.
    """
    if est.normal is None or est.depth_mm is None:
        return est
    n = np.asarray(est.normal, dtype=np.float64)
    P = float(est.depth_mm) * np.asarray(ray, dtype=np.float64)
    cam = float(-P @ n)
    for j, L in enumerate(np.asarray(lights_mm, dtype=np.float64).reshape(-1, 3)):
        side = float((L - P) @ n)
        if side * np.sign(cam) < -ON_PLANE_MM:
            why = (f"light {j} at ({L[0]:.3g}, {L[1]:.3g}, {L[2]:.3g}) mm lies {abs(side):.3g} mm behind the "
                   f"fitted surface at depth {est.depth_mm:.4g} mm (the camera {abs(cam):.3g} mm in front)")
            return est.without_depth("light_behind_plane", f"{est.detail}; {why}" if est.detail else why)
    return est
