"""Light-aware estimators: normal and depth of a highlight lit by a known rig off the camera centre.

With the light exactly at the camera centre the BP ray is the normal at the BP and the image of a
plane is invariant to the plane's distance. Real endoscopes carry their light guides a few
millimetres beside the lens, at 5 to 50 mm from the tissue: the offset over the distance,
epsilon/d, is 0.05 to 0.5, and the BP ray is then off the normal by about half the angle the
offset subtends (the BP is where the normal *bisects* the directions to camera and light). A known
(calibrated) offset also breaks the scale ambiguity: the image depends on L/d, so the distance
becomes observable. Three estimators use the rig:

- :func:`bisector`: the BP ray corrected by the rig for a *given* depth (a depth map, a stereo
  depth): exact for a plane when the depth is exact.
- :func:`isocurve_fit`: the general specular isocurve (paper eq. 2, any light and viewer) with the
  calibrated light position, fitted to the isophote points taken as rays: plane normal, distance h,
  and the cosine level tau of each isovalue (nested isovalues tie their taus through the
  roughness n).
- :func:`quadric_fit`: the photometric fit with a curved (quadric) patch, for curved surfaces
  where the plane model explains the curvature's compression of the lobe by roughness and depth
  (:func:`photometric_fit` then reports ``plane_misfit``).
- :func:`photometric_fit`: the ROI's intensities fitted with the image of a plane lit by the whole
  rig (sum of the lights' Phong lobes with their falloff and emission profile) plus a smooth linear
  background: normal, distance, roughness and gain; clipped pixels are left out.
- :func:`cubic_patch_fit`: the quadric patch with its four third-order terms, fitted to the lobes
  of every light of a rig of several lights (a depth profile, then the free fit): with one light
  the surface's third-order shape stands in for the light's offset and the depth is not
  observable; two lights apart shift their lobes apart while the shape acts on both alike, which
  fixes the depth (:func:`patch_depth_profile` measures it), and with it each light's specular
  point and normal.

Each returns a :class:`LightAwareEstimate`: the normal, the depth in mm of the specular point along
its ray (None when not observable), a 1-sigma angular uncertainty from the fit's Jacobian, and a
status with its cause (:data:`STATUSES`).

Model (paper eq. 1 with the mirror direction of eq. 2)
------------------------------------------------------
Camera frame (OpenCV), camera centre V = 0, mm. Plane ``n . X = -h`` (n unit, facing the camera,
h > 0). The pixel ray d (unit) meets the plane at ``X = d h / (-n . d)``. With ``l`` the unit
direction from X to a light L and ``v = -d`` the direction to the camera, the mirror direction
of the light is ``r = 2 (n . l) n - l`` and

``cos beta = r . v = 2 (n . l)(n . v) - l . v``,

the quantity whose level sets on the plane are the general specular isocurve (eq. 2:
``Q(p) = 0`` is ``cos^2 beta = tau^2``; the isophote is the branch ``cos beta = +tau``). The
photometric model is ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv`` with
``f_j = (h / |L_j - X|)^2`` for an inverse-square light (1 otherwise), ``p_j`` the emission profile
``cos^m`` about +z, gain g and a linear background (b0, b1, b2), solved linearly for each value of
the nonlinear parameters (variable projection).

Specular point and depth: on the plane (n, h) the specular point of a light L is where the
segment from the camera centre to the mirror image ``L' = L - 2 (n . L + h) n`` meets the plane,
``X_s = L' h / (-n . L')``; ``depth_mm = |X_s|``, its distance along its viewing ray. For a rig of
several lights the depth reported is that of the intensity-weighted mean light position.

Parametrisation, start and uncertainty
--------------------------------------
The normal is ``n = unit(n0 + a e1 + b e2)`` about the start normal n0 ((e1, e2) a basis of its
tangent plane), the distance enters as log h. The start is the bisector at the BP with a nominal
distance (``nominal_depth_mm``) whose h is then made consistent with the BP: for the start
normal, the depth along the BP ray at which the specular point projects to the BP. The
covariance of the parameters is ``s^2 (J^T J)^-1`` at the solution, J the Jacobian re-taken about
the solution, s^2 the residual variance ``sum r^2 / (m - p)``; ``normal_sigma_deg`` is
``sqrt(var a + var b)`` in degrees (the RMS angle of the normal's error) and the depth's
standard deviation follows by the delta method.

Depth observability: the depth's relative standard deviation is computed again with the residual
variance floored at the localisation noise of a contour point or a pixel
(``TOL.isophote_noise_px`` and ``TOL.photometric_noise_rel``); above ``TOL.depth_rel_sigma_max``
(or with a singular J^T J, as at epsilon = 0 where the image does not depend on h) the depth is
reported as None with status ``depth_not_observable``; the normal is still given (the fit's flat
direction in h leaves the normal determined).

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       eqs. (1) and (2).
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] G. H. Golub, V. Pereyra, "The differentiation of pseudo-inverses and nonlinear least squares
       problems whose variables separate", SIAM J. Numer. Anal. 10(2), 1973.
       https://doi.org/10.1137/0710036 (variable projection).
.. [4] J. Iranzo et al., "EndoMetric: near-light metric scale monocular SLAM", MICCAI 2025,
       arXiv 2410.15065 (the same near-light baseline, for scale from diffuse shading).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import map_coordinates, spline_filter
from scipy.optimize import least_squares, leastsq

from simtest.geometry.angles import unit
from simtest.geometry.camera import validate_intrinsics
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.reconstruct import _lightaware_kernels
from simtest.reconstruct._pixels import uv_to_rc
from simtest.tolerances import TOL

__all__ = [
    "STATUSES",
    "LightAwareEstimate",
    "CramerRaoBound",
    "bisector",
    "cubic_patch_fit",
    "isocurve_fit",
    "photometric_crb",
    "photometric_fit",
    "plane_rig_intensity",
    "quadric_fit",
    "refine_isophote_points",
    "specular_point_depth",
]

OK = "ok"

#: Status of a light-aware estimate, with its meaning.
STATUSES: dict[str, str] = {
    OK: "normal and depth estimated",
    "depth_not_observable": "normal estimated; the depth is not (epsilon/d too small: the image "
                            "hardly depends on the distance)",
    "not_converged": "the least-squares fit stopped without meeting its tolerances",
    "too_few_points": "fewer isophote points or unclipped pixels than parameters",
    "multi_light_rig": "the isocurve model (eq. 2) holds for one light; use photometric_fit",
    "light_behind_plane": "a light of the rig lies behind the fitted plane",
    "patch_misfit": "the quadric patch does not fit the ROI (spatially correlated residuals); "
                    "the normal is kept for the record, the depth withdrawn",
    "plane_misfit": "the plane model does not fit the ROI (its residuals are spatially correlated: "
                    "a curved patch); the normal is kept for the record, the depth withdrawn",
}


@dataclass(frozen=True)
class LightAwareEstimate:
    """Result of a light-aware estimator.

    Attributes
    ----------
    estimator : str
        ``"bisector"``, ``"isocurve_fit"``, ``"photometric_fit"``, ``"quadric_fit"`` or
        ``"cubic_patch_fit"``.
    status : str
        A key of :data:`STATUSES`.
    detail : str
        Numbers behind the status.
    normal : ndarray of shape (3,) or None
        Unit normal, OpenCV camera frame, facing the camera.
    depth_mm : float or None
        Distance from the camera centre to the specular point (along its ray), mm; None when not
        observable.
    normal_sigma_deg : float or None
        1-sigma angular uncertainty of the normal (RMS angle), degrees.
    depth_sigma_mm : float or None
        1-sigma uncertainty of the depth, mm (None when the depth is not observable).
    distance_mm : float or None
        Fitted camera-to-plane distance h, mm (None when not observable).
    roughness : float or None
        Fitted Phong roughness n (None when not fitted).
    taus : ndarray of shape (K,) or None
        Fitted cosine level tau per isovalue (isocurve_fit).
    n_evaluations : int
        Model evaluations of the fit (0 for the closed form).
    residual_rms : float or None
        RMS residual at the solution, in the fit's units (px for the isocurve fit; fraction of the
        ROI's maximum for the photometric fit); a plane model meeting a curved patch leaves a
        residual well above the sensor's noise.
    light_normals : ndarray of shape (J, 3) or None
        :func:`cubic_patch_fit` only: the fitted patch's unit normal at the specular point of
        each of the rig's J lights (where it bisects the directions to the camera and to that
        light), OpenCV camera frame, facing the camera; None when the depth is not observable.
    light_depths_mm : ndarray of shape (J,) or None
        :func:`cubic_patch_fit` only: the distance from the camera centre to each light's
        specular point on the fitted patch, mm; None when the depth is not observable.
    depth_rel_sigma : float or None
        :func:`quadric_fit` and :func:`cubic_patch_fit`: the relative 1-sigma of the fitted depth
        with the residual variance floored at ``TOL.photometric_noise_rel`` (the quantity the
        observability test compares with ``TOL.depth_rel_sigma_max``); None when J^T J is
        singular.
    bp_ray_error_deg : float or None
        The BP ray's expected error next to this fit, degrees: half the angle the rig's mean light
        subtends from the camera at the specular point (at this fit's depth, or at the nominal
        depth where the depth is not observable); set by
        :func:`simtest.reconstruct.recommend.light_aware_estimates`, whose recommendation keeps a
        normal whose ``normal_sigma_deg`` is below it. None when not set.
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

    @property
    def ok(self) -> bool:
        """True when the status is ``"ok"`` (normal and depth given)."""
        return self.status == OK

    @property
    def has_normal(self) -> bool:
        """True when a normal is given (status ``ok`` or ``depth_not_observable``)."""
        return self.normal is not None


# ------------------------------------------------------------------------------------------------
# geometry


class _Kinv:
    """A validated K's inverse, so that rays are made without validating K each time."""

    def __init__(self, K):
        self.Kinv_T = np.linalg.inv(validate_intrinsics(K)).T


def _camera(camera):
    """``camera`` as given if it has ``pixel_to_ray``, else K (3, 3) validated once."""
    return camera if hasattr(camera, "pixel_to_ray") or isinstance(camera, _Kinv) else _Kinv(camera)


def _rays(camera, uv) -> np.ndarray:
    """Unit viewing rays (N, 3) of pixels (N, 2): ``camera`` is K (3, 3) or has ``pixel_to_ray``."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    camera = _camera(camera)
    if hasattr(camera, "pixel_to_ray"):
        return np.asarray(camera.pixel_to_ray(uv), dtype=np.float64)
    d = np.column_stack([uv, np.ones(len(uv))]) @ camera.Kinv_T
    return d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]


def _rig_arrays(rig: LightRig):
    L = np.array([lt.position_mm for lt in rig.lights], dtype=np.float64).reshape(-1, 3)
    w = np.array([lt.intensity for lt in rig.lights], dtype=np.float64)
    inv_sq = np.array([lt.falloff == "inverse_square" for lt in rig.lights])
    m = np.array([lt.profile_exponent for lt in rig.lights], dtype=np.float64)
    return L, w, inv_sq, m


def _mean_light(rig: LightRig) -> np.ndarray:
    L, w, _, _ = _rig_arrays(rig)
    return (w[:, None] * L).sum(axis=0) / w.sum()


def specular_point_depth(normal, distance_mm: float, light_mm) -> float:
    """Depth (distance from the camera centre) of the specular point of a plane for one light.

    Parameters
    ----------
    normal : array_like of shape (3,)
        Unit plane normal facing the camera, camera frame.
    distance_mm : float
        Plane distance h > 0, mm.
    light_mm : array_like of shape (3,)
        Light position, camera frame, mm.

    Returns
    -------
    float
        ``|X_s|`` with ``X_s = L' h / (-n . L')`` and ``L' = L - 2 (n . L + h) n`` (module
        docstring); NaN if the light is behind the plane.
    """
    n = np.asarray(normal, dtype=np.float64)
    L = np.asarray(light_mm, dtype=np.float64)
    hl = n @ L + distance_mm
    if not hl > 0:
        return float("nan")
    Lm = L - 2.0 * hl * n
    return float(np.linalg.norm(Lm) * distance_mm / (-(n @ Lm)))


def _ray_light(L, dT):
    """``(Ld, K2)``: ``L . d`` and ``|L|^2 - (L . d)^2`` (the light's squared distance from the
    ray's line) per ray, for lights L (3,) or (J, 3) and unit rays ``dT`` (3, N): (N,) or (J, N)."""
    Ld = L @ dT
    LL = (L * L).sum(axis=-1)
    return Ld, np.maximum((LL if np.ndim(LL) == 0 else LL[:, None]) - Ld * Ld, 0.0)


def _terms(dT, n, h, L, rl, P=None, dns=None):
    """cos beta of one light on the plane (n, h) along unit rays, and its derivatives.

    The rays are given transposed, ``dT`` (3, N) (each operation then runs along N), with
    ``rl = (Ld, K2)`` of :func:`_ray_light` (they depend on the rays only). Returns
    ``cb (N,)``, the pieces ``delta = -d . n``, ``s = |X|``, ``sl = s - Ld``, ``ir = 1 / r`` with
    ``r = |L - X|`` (each (N,)), ``c = n . L + h``, and, when the normal's derivatives ``dns``
    (two (3,) vectors) are given, ``dcb (3, N)`` with respect to (a, b, log h)
    (``P = [dn_a, dn_b] @ dT`` (2, N) may be given too); else None.

    Notes
    -----
    The plane point is ``X = s d`` with ``s = h / delta``. Then
    ``r^2 = |L|^2 - 2 s Ld + s^2 = (s - Ld)^2 + K2``, ``n . (L - X) = n . L + s delta = c`` and
    ``(L - X) . d = Ld - s``, so ``cos beta = 2 (n . l)(n . v) - l . v = (2 c delta + Ld - s) / r``
    (module docstring): a few operations per ray, no per-ray vectors. A change (dn, dh) gives
    ``d delta = -d . dn``, ``ds = (dh - s d delta) / delta``, ``dr = ds (s - Ld) / r``,
    ``dc = dn . L + dh`` and ``d cos beta = (2 (dc delta + c d delta) - ds - cb dr) / r``
    ``= (2 (dc delta + c d delta) - q ds) / r`` with ``q = 1 + cb (s - Ld) / r``. For a and b
    (dh = 0, d delta = -P): ``(2 delta dc - P (2 c + q s / delta)) / r``; for log h (dn = 0,
    dh = h, ds = s): ``(2 h delta - q s) / r``.
    """
    Ld, K2 = rl
    nd = (-n) @ dT
    c = n @ L + h
    N = nd.shape[0]
    cb, delta, s, sl, ir = np.empty((5, N))  # one allocation, its rows the outputs
    if dns is None:
        _lightaware_kernels.cos_beta_terms(nd, h, c, Ld, K2, None, None, cb, delta, s, sl, ir, None)
        return cb, delta, s, sl, ir, c, None
    if P is None:
        P = np.array(dns) @ dT
    dcb = np.empty((3, N))
    _lightaware_kernels.cos_beta_terms(nd, h, c, Ld, K2, P, np.array([dns[0] @ L, dns[1] @ L]),
                                       cb, delta, s, sl, ir, dcb)
    return cb, delta, s, sl, ir, c, dcb


def _terms_numpy(dT, n, h, L, rl, P=None, dns=None):
    """The numpy form of :func:`_terms`: the reference of its compiled pass
    (:func:`simtest.reconstruct._lightaware_kernels.cos_beta_terms`, the same bits)."""
    Ld, K2 = rl
    delta = np.maximum((-n) @ dT, 1e-9)
    s = h / delta
    sl = s - Ld
    with np.errstate(over="ignore"):  # a plane seen edge-on (delta at its floor): s^2 overflows, 1 / r = 0
        ir = 1.0 / np.sqrt(np.maximum(sl * sl + K2, 1e-300))
    c = n @ L + h
    cb = (2.0 * c * delta - sl) * ir
    if dns is None:
        return cb, delta, s, sl, ir, c, None
    if P is None:
        P = np.array(dns) @ dT
    qs = (1.0 + cb * sl * ir) * s
    t = 2.0 * delta * ir
    u = (2.0 * c + qs / delta) * ir
    dcb = np.empty((3, dT.shape[1]))
    dcb[0] = t * (dns[0] @ L) - P[0] * u
    dcb[1] = t * (dns[1] @ L) - P[1] * u
    dcb[2] = t * h - qs * ir
    return cb, delta, s, sl, ir, c, dcb


def _normal_derivs(p, n0, e1, e2):
    """Normal ``unit(n0 + a e1 + b e2)`` and its derivatives with respect to a and b."""
    m = n0 + p[0] * e1 + p[1] * e2
    nm = np.sqrt(m @ m)
    n = m / nm
    return n, ((e1 - n * (n @ e1)) / nm, (e2 - n * (n @ e2)) / nm)


#: Below this cos beta a lobe is taken as 0 (``cb^n`` < 1e-200 for n >= 1): its derivative
#: ``n cb^(n-1)`` is then formed without dividing by a denormal.
_CB_FLOOR = 1e-200


def _rig_value(dT, rl, n, h, rig_arr, rough):
    """``S = sum_j w_j max(0, cb_j)^n f_j p_j`` (N,) and the per-light pieces its gradient needs.

    ``dT`` (3, N) the unit rays transposed, ``rl`` the :func:`_ray_light` of the rig's lights
    (each (J, N)). See :func:`_rig_grad` for the derivatives.
    """
    L, w, inv_sq, m = rig_arr
    S = np.zeros(dT.shape[1])
    parts = []
    for j in range(len(w)):
        cb, delta, s, sl, ir, c, _ = _terms(dT, n, h, L[j], (rl[0][j], rl[1][j]))
        pos = cb > _CB_FLOOR
        cbp = np.where(pos, cb, 1.0)
        lcb = np.log(cbp)
        val = np.exp(rough * lcb)
        val[~pos] = 0.0
        if inv_sq[j]:
            hir = h * ir
            val *= hir * hir
        cp = None
        if m[j] > 0:
            cp = np.maximum((s * dT[2] - L[j, 2]) * ir, 1e-12)
            val *= cp ** m[j]
        if w[j] != 1.0:
            val *= w[j]
        S += val
        parts.append((cb, cbp, lcb, val, delta, s, sl, ir, c, cp))
    return S, parts


def _rig_grad(dT, parts, n, dns, h, rig_arr, rough):
    """``dS`` (4, N) of :func:`_rig_value` with respect to (a, b, log h, log n).

    Notes
    -----
    Per light, ``d log(val) = n d cb / cb + d log f + d log p`` with ``f = (h / r)^2``
    (``d log f = 2 dh / h - 2 dr / r``) and ``p = cp^m``, ``cp = (s d_z - L_z) / r``
    (``d log p = m (ds d_z / (r cp) - dr / r)``), and ``d val / d log n = val n log cb``. With
    the derivatives of :func:`_terms` (``dr = ds (s - Ld) / r``, ``ds = s P / delta`` and
    ``d delta = -P`` for a and b, ``ds = s`` for log h) each row is ``val`` times a sum of
    per-ray factors.
    """
    L, w, inv_sq, m = rig_arr
    P = np.array(dns) @ dT
    dS = np.zeros((4, dT.shape[1]))
    for j, (cb, cbp, lcb, val, delta, s, sl, ir, c, cp) in enumerate(parts):
        slr = sl * ir  # dr / ds
        k = (rough * ir) / cbp  # n / (r cb): d log(lobe) = k (2 (dc delta + c d delta) - q ds)
        C = -k * (1.0 + cb * slr)  # coefficient of ds
        if inv_sq[j]:
            C -= (2.0 * slr) * ir
        if cp is not None:
            C += m[j] * ((dT[2] / cp - slr) * ir)
        kv = k * val
        A = (2.0 * delta) * kv  # coefficient of dc, times val
        Cvs = C * val * s
        Bv = Cvs / delta - (2.0 * c) * kv  # coefficient of P, times val
        dS[0] += A * (dns[0] @ L[j]) + P[0] * Bv
        dS[1] += A * (dns[1] @ L[j]) + P[1] * Bv
        dS[2] += A * h + Cvs + (2.0 * val if inv_sq[j] else 0.0)
        dS[3] += (rough * val) * lcb
    return dS


def _rig_image(d, n, dns, h, rig_arr, rough, grad=True):
    """``S = sum_j w_j max(0, cb_j)^n f_j p_j`` (N,) and ``dS`` (N, 4) w.r.t. (a, b, log h, log n).

    ``d`` (N, 3) unit rays.
    """
    dT = np.ascontiguousarray(np.asarray(d, dtype=np.float64).T)
    rl = _ray_light(rig_arr[0], dT)
    S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
    return S, (_rig_grad(dT, parts, n, dns, h, rig_arr, rough).T if grad else None)


def _intensity(d, n, h, rig_arr, rough):
    dT = np.ascontiguousarray(np.asarray(d, dtype=np.float64).T)
    hit = -(n @ dT) > 1e-9
    return np.where(hit, _rig_value(dT, _ray_light(rig_arr[0], dT), n, h, rig_arr, rough)[0], 0.0)


def plane_rig_intensity(rays: np.ndarray, normal, distance_mm: float, rig: LightRig,
                        roughness: float) -> np.ndarray:
    """Specular image of a plane lit by a rig, along given rays (unit gain, no background).

    ``sum_j w_j max(0, cos beta_j)^n f_j p_j`` (module docstring), with
    ``f_j = (h / |L_j - X|)^2`` for inverse-square lights and ``p_j = max(0, cos theta_j)^m_j``.

    Parameters
    ----------
    rays : ndarray of shape (N, 3)
        Unit viewing rays, camera frame.
    normal : array_like of shape (3,)
        Unit plane normal facing the camera.
    distance_mm : float
        Plane distance h > 0, mm.
    rig : LightRig
        The lights.
    roughness : float
        Phong n > 0.

    Returns
    -------
    ndarray of shape (N,)
        Intensity; 0 for rays that miss the plane.
    """
    return _intensity(np.asarray(rays, dtype=np.float64), unit(np.asarray(normal, dtype=np.float64)),
                      float(distance_mm), _rig_arrays(rig), float(roughness))


def _distance_for_bp(ray: np.ndarray, n: np.ndarray, L: np.ndarray) -> float | None:
    """Plane distance h for which a plane of normal n has its specular point on the BP ray.

    The specular point is ``X_s ∝ L' = L0 - 2 h n`` with ``L0 = L - 2 (n . L) n`` (the mirror image
    of L in the plane through the camera centre), so it lies on the ray b when L' is parallel to b:
    with ``P = I - b b^T``, ``h = (P L0) . (P n) / (2 |P n|^2)`` (least squares on the component
    of L' across the ray). None if the result is not > 0 (then no such plane faces the light).
    """
    L0 = L - 2.0 * (n @ L) * n
    pn = n - (ray @ n) * ray  # P n
    den = 2.0 * (pn @ pn)
    if not den > 1e-18:
        return None
    h = float((L0 - (ray @ L0) * ray) @ pn / den)
    return h if h > 0 else None


# ------------------------------------------------------------------------------------------------
# bisector


def bisector(bp_uv, camera, rig: LightRig, depth_mm) -> LightAwareEstimate:
    """The BP ray corrected by the rig for a given depth: the normal that makes the BP specular.

    At depth s along the BP's ray the surface point is ``X = s d``; the normal that reflects the
    light L into the camera there bisects the directions to camera and light,
    ``N = unit(unit(-X) + unit(L - X))``. For a plane, with the true depth of the BP, N is the
    plane normal exactly (the specular point is the BP of a Phong plane without falloff); with a
    co-located light it is the ``bp_ray`` normal whatever the depth. For a rig of several lights
    the intensity-weighted mean light position is used (an approximation: the brightest point of a
    merged pair is not one light's specular point).

    Parameters
    ----------
    bp_uv : array_like of shape (2,)
        Brightest point (u, v), undistorted px.
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The lights, camera frame, mm.
    depth_mm : float or ndarray of shape (H, W)
        Distance from the camera centre to the BP along its ray, mm; or a depth map (same
        meaning per pixel), sampled at the nearest pixel of the BP.

    Returns
    -------
    LightAwareEstimate
        ``normal`` (unit, facing the camera), ``depth_mm`` as given, ``normal_sigma_deg`` None.

    Raises
    ------
    ValueError
        A non-finite BP, a depth that is not > 0, or a BP outside the depth map.
    """
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(-1)
    if bp.shape != (2,) or not np.isfinite(bp).all():
        raise ValueError(f"bp_uv: need 2 finite numbers (u, v), got {bp_uv!r}")
    dm = np.asarray(depth_mm, dtype=np.float64)
    if dm.ndim == 2:
        r, c = (int(v) for v in np.rint(uv_to_rc(bp)))
        if not (0 <= r < dm.shape[0] and 0 <= c < dm.shape[1]):
            raise ValueError(f"bp_uv {bp.tolist()} lies outside the depth map of shape {dm.shape}")
        s = float(dm[r, c])
    elif dm.ndim == 0:
        s = float(dm)
    else:
        raise ValueError(f"depth_mm: a number or an (H, W) map, got shape {dm.shape}")
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"depth_mm: must be finite and > 0 at the BP, got {s}")
    d = _rays(camera, bp[None])[0]
    X = s * d
    n = unit(unit(-X) + unit(_mean_light(rig) - X))
    return LightAwareEstimate("bisector", OK, "", n, s)


# ------------------------------------------------------------------------------------------------
# shared fitting machinery


def _start(bp_uv, camera, rig, nominal_depth_mm, start_normal):
    """Start normal n0 and distance h0 (module docstring, "Parametrisation, start")."""
    d_bp = _rays(camera, np.asarray(bp_uv, dtype=np.float64)[None])[0]
    Lm = _mean_light(rig)
    if start_normal is None:
        n0 = unit(unit(-d_bp * nominal_depth_mm) + unit(Lm - d_bp * nominal_depth_mm))
    else:
        n0 = unit(np.asarray(start_normal, dtype=np.float64))
        if n0 @ d_bp > 0:
            n0 = -n0
    h0 = _distance_for_bp(d_bp, n0, Lm) if np.linalg.norm(Lm) > 0 else None
    if h0 is None or not np.isfinite(h0):
        h0 = float(-(n0 @ (nominal_depth_mm * d_bp)))
    return d_bp, n0, max(h0, 1e-3)


def _covariance(jac: np.ndarray, resid_var: float) -> np.ndarray | None:
    """``resid_var (J^T J)^-1``, or None when J^T J is singular.

    Singular: a column of J below 1e-10 of the largest (a parameter the model does not depend on,
    such as h with the light at the camera centre, whose column is rounding noise), or a condition
    number above 1e12 after scaling the columns to unit norm.
    """
    jtj = jac.T @ jac
    scale = np.sqrt(np.diag(jtj))
    if not np.all(scale > 1e-10 * scale.max()):  # a column of rounding noise: a flat direction
        return None
    jn = jtj / np.outer(scale, scale)
    if np.linalg.cond(jn) > 1e12:
        return None
    return resid_var * np.linalg.inv(jn) / np.outer(scale, scale)


#: Levenberg-Marquardt's tolerances (MINPACK's ftol, xtol, gtol) in the light-aware plane fits.
#: Near the minimum the cost is ``C* (1 + u^2 / (m - k))`` with u the distance to the minimum in
#: standard deviations (m residuals, k parameters): a relative cost change below 1e-8 leaves u
#: below about ``1e-4 sqrt(m)``, under 1 % of a standard deviation for the 4096 px of a 64 px
#: ROI and about 0.1 % for the 128 points of two isophotes. Exact images (C* = 0) converge
#: quadratically, to rounding, in one or two steps more. Tighter (1e-12, as before) took 25 to
#: 75 % more evaluations on the bench's highlight and changed its results in the ninth digit.
_LM_TOL = 1e-8
#: The same for the first pass of a reweighted (robust) fit, which only sets the weights of the
#: second: the weights move with the residuals, a change at 1e-4 of the cost moves the final
#: solution by a second-order amount (1e-9 of the depth on the bench's highlight).
_LM_TOL_FIRST_PASS = 1e-4


def _solve(resjac, p0, args, loss: str, f_scale: float, max_nfev: int, free=None,
           lazy_jac: bool = False, weighted: bool = False):
    """Levenberg-Marquardt (MINPACK, analytic Jacobian), robust loss by reweighting.

    ``loss="linear"``: one LM solve. Otherwise (``soft_l1``, ``huber``, ``cauchy``): the LM solution
    is reweighted once by iteratively reweighted least squares, each residual scaled by
    ``sqrt(rho'(z))`` with ``z = (r / f_scale)^2`` (the weights of scipy's robust losses), and
    re-solved from there. ``free`` (bool mask) holds the other parameters at ``p0``.
    ``resjac(p, *args, grad=...)`` returns the residuals and, with ``grad``, their Jacobian (else
    None). ``lazy_jac``: MINPACK's trial points get the residuals alone and the Jacobian is
    computed only where it is asked (worth it for a large Jacobian, the photometric fit's; for a
    few hundred contour points the second call costs more than the Jacobian). ``weighted``: the
    reweighting's weights are passed to ``resjac`` too (``w=``), for a model that solves part of
    itself with them (the photometric fit's linear parameters); it returns the unweighted
    residuals and Jacobian of that solution. MINPACK's lmder is called through
    :func:`scipy.optimize.leastsq`: ``least_squares(method="lm")`` is the same solver behind a
    wrapper that cost as much as the model on a few hundred isophote points. Returns (x,
    n_evaluations (the model evaluated at a new point), converged, message, residuals at x).
    """
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
        # MINPACK asks for f at each trial point and for J only at the accepted ones (at the
        # point of its last f): with lazy_jac the residual alone first, r and J together when J
        # is asked; else both at once
        grad = grad or not lazy_jac
        key = q.tobytes()
        if cache.get("key") != key or (grad and cache.get("J") is None):
            kw = {"w": model_w[0]} if weighted and model_w[0] is not None else {}
            r, J = resjac(full(q), *args, grad=grad, **kw)
            if cache.get("key") != key:
                count[0] += 1
            cache.update(key=key, r=r, J=J if J is None or all_free else J[:, free])
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
        # MINPACK's lmder through leastsq (least_squares' method="lm" is the same solver behind
        # a heavier wrapper); without full_output it skips a covariance we do not use and warns
        # with its message when it stops short
        with np.errstate(all="ignore"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            # the first pass of a reweighted fit only sets the weights: looser tolerances
            tol = _LM_TOL if it or loss == "linear" else _LM_TOL_FIRST_PASS
            q, ier = leastsq(fun, q, args=(w,), Dfun=jac, xtol=tol, ftol=tol, gtol=tol,
                             maxfev=max_nfev)
        ok = ier in (1, 2, 3, 4) and bool(np.isfinite(q).all())
        msg = "" if ier in (1, 2, 3, 4) else (str(caught[-1].message) if caught
                                               else f"MINPACK info {ier}")
    return full(q), count[0], ok, msg, rj(q, grad=False)[0]


#: Plausible fitted values: the distance within this factor of the start's, the roughness in
#: this range. Outside, the plane model is explaining something else (a curved patch whose lobe
#: the curvature compresses is fitted with n in the thousands and h -> 0): reported as not converged.
_H_FACTOR = 20.0
_ROUGHNESS_RANGE = (1.0, 2000.0)
#: Gauss-Newton steps on log n alone that refine the photometric fit's start roughness: on the
#: bench's exact highlight (n = 150) three steps from n = 50, 86 or 258 (the regression's starts
#: with cos beta with and without the falloff) end within 0.003 of log 150.
_ROUGHNESS_START_STEPS = 3


def _implausible(h_hat: float, h0: float, roughness: float | None) -> str:
    """Why a fit's solution is implausible ("" when it is not)."""
    if not (np.isfinite(h_hat) and h0 / _H_FACTOR <= h_hat <= h0 * _H_FACTOR):
        return f"fitted distance {h_hat:.4g} mm is not within a factor {_H_FACTOR:g} of the start's {h0:.4g} mm"
    if roughness is not None and not (np.isfinite(roughness)
                                      and _ROUGHNESS_RANGE[0] <= roughness <= _ROUGHNESS_RANGE[1]):
        return f"fitted roughness {roughness:.4g} outside {_ROUGHNESS_RANGE}"
    return ""


def _log_depth_gradient(n, h, Lm, basis=None) -> np.ndarray:
    """d log(depth) / d(a, b, log h) about (n, h), the tangent basis of :func:`plane_basis` (3,).

    ``basis``: that basis (e1, e2) when already at hand.

    Notes
    -----
    With ``k = n . L + h`` (> 0: the light in front of the plane), the mirror image is
    ``L' = L - 2 k n``, so ``-n . L' = k + h`` and ``|L'|^2 = |L|^2 + 4 k h``, and the depth of
    :func:`specular_point_depth` is ``D = h sqrt(|L|^2 + 4 k h) / (k + h)``. About n the normal
    moves by ``dn = e1 da + e2 db`` (n unit, e1 and e2 orthogonal to it), so
    ``d log D / da = (e1 . L) (2 h / (|L|^2 + 4 k h) - 1 / (k + h))`` (and e2 for b), and with
    ``dh = dk = h d log h``: ``d log D / d log h = 1 + 2 h (h + k) / (|L|^2 + 4 k h) - 2 h / (k + h)``.
    NaN with the light behind the plane.
    """
    e1, e2 = plane_basis(n) if basis is None else basis
    k = float(n @ Lm) + h
    if not k > 0:
        return np.full(3, np.nan)
    q = float(Lm @ Lm) + 4.0 * k * h
    ga = 2.0 * h / q - 1.0 / (k + h)
    return np.array([float(e1 @ Lm) * ga, float(e2 @ Lm) * ga,
                     1.0 + 2.0 * h * (h + k) / q - 2.0 * h / (k + h)])


def _finish(name, resjac_at, n_hat, h_hat, rig, extra_params, resid_floor, n_eval, converged,
            roughness=None, taus=None, detail="", post=None, n_linear=0):
    """Covariance about the solution, depth and its observability, and the estimate.

    ``post(estimate, residuals)``, when given, returns the estimate to report (the residuals at the
    solution are those the covariance used). ``n_linear``: parameters eliminated from the
    Jacobian by variable projection (they count in the residual variance's degrees of freedom).
    """
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
    sigma_deg = (None if cov is None
                 else math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))))
    depth = specular_point_depth(n_hat, h_hat, Lm)
    g = _log_depth_gradient(n_hat, h_hat, Lm, (e1, e2))
    gcg = None if unit_cov is None else float(g @ unit_cov[:3, :3] @ g)  # g^T (J^T J)^-1 g
    rel_floor = None if gcg is None else math.sqrt(max(floor_var * gcg, 0.0))
    observable = rel_floor is not None and math.isfinite(depth) and rel_floor <= TOL.depth_rel_sigma_max
    if not converged:
        status = "not_converged"
    elif not observable:
        status = "depth_not_observable"
        detail = detail or (
            "J^T J singular in h" if rel_floor is None
            else f"relative depth sigma {rel_floor:.3g} at the noise floor > {TOL.depth_rel_sigma_max}")
    else:
        status = OK
    depth_sigma = None
    if observable and cov is not None:
        depth_sigma = depth * math.sqrt(max(resid_var * gcg, 0.0))
    est = LightAwareEstimate(
        name, status, detail, n_hat,
        depth if observable else None, sigma_deg, depth_sigma,
        h_hat if observable else None, roughness, taus, n_eval, math.sqrt(rr / m),
    )
    return est if post is None else post(est, r0)


# ------------------------------------------------------------------------------------------------
# isocurve fit


def refine_isophote_points(values, level: float, points_uv, origin_uv=(0.0, 0.0),
                           iterations: int = 3) -> np.ndarray:
    """Move contour points onto the level set of the cubic-spline interpolant of an image.

    Marching squares interpolates linearly between pixel centres: on a smooth highlight its points
    sit off the true isophote by a few hundredths of a pixel, inward on the convex side, enough to
    bias the distance a light-aware fit reads from the isophote's shape. Each point takes Newton
    steps ``p <- p - (f(p) - level) grad f / |grad f|^2`` on the cubic B-spline interpolant f of the
    values (gradient by central differences of f, 0.25 px). Points whose step would exceed 1 px are
    left where they were.

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
    coef = spline_filter(np.asarray(values, dtype=np.float64), order=3, mode="mirror")
    o = np.asarray(origin_uv, dtype=np.float64)
    p = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2) - o
    p0 = p.copy()

    def f(q):
        return map_coordinates(coef, uv_to_rc(q).T, order=3, mode="mirror", prefilter=False)

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


def isocurve_fit(points_uv, isovalues, bp_uv, camera, rig: LightRig, *,
                 nominal_depth_mm: float = 20.0, start_normal=None,
                 loss: str = "soft_l1", f_scale_px: float = 0.5,
                 max_points_per_isophote: int | None = 64, n_start_depths: int = 0,
                 max_nfev: int = 200) -> LightAwareEstimate:
    """Fit the general specular isocurve (paper eq. 2) with a calibrated light to isophote points.

    Each contour point is a ray; the plane (n, h) puts it at ``X = d h / (-n . d)`` where its
    ``cos beta`` (module docstring) should equal its isovalue's level tau. Residuals are
    ``(cos beta_i - tau_k) / |grad cos beta_i|``, the distance in pixels to the model isophote at
    first order (gradient in px taken at the start). One isovalue: tau is free. Two or more
    (nested isophotes): ``log tau_k = (log t_k - log s) / n``, tying the levels through the
    roughness n and the peak-to-BP ratio s, both fitted. Levenberg-Marquardt (MINPACK through
    :func:`scipy.optimize.leastsq`, analytic Jacobian, cos beta in a few operations per point:
    ``_terms``) with a robust loss (``soft_l1``) by one reweighting (``_solve``).

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
        Exactly one light (eq. 2 is a one-light model; its falloff and profile are ignored: the
        model is exact for a light without falloff).
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. the cone axis) in place of the bisector.
    loss : str
        ``soft_l1``, ``huber``, ``cauchy`` (the weights of the
        :func:`scipy.optimize.least_squares` losses of those names) or ``linear``.
    f_scale_px : float
        Soft margin of the robust loss, px.
    max_points_per_isophote : int or None
        Keep every k-th point of a longer contour (speed; None keeps all).
    n_start_depths : int
        Starts tried along the BP's constraint (depths nominal/8 to nominal*8), besides the given
        start; the one of least cost is refined (0: only the given start).
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

    def taus_of(q):
        if n_tau == 1:
            return np.array([q[0]])
        return np.exp((log_t - q[1]) * q[0])  # q = (1/n, log s)

    # pixel-unit weights: 1 / |grad_px cos beta| at a start (central differences, 0.5 px)
    def weights(n, h):
        cu, cu2, cv, cv2 = _terms(dT_pm, n, h, L, rl_pm)[0].reshape(4, -1)
        grad = np.hypot(cu - cu2, cv - cv2)
        k = len(grad) // 2  # the median, by partition (np.median's own overhead is 5x that)
        part = np.partition(grad, [k - 1, k] if len(grad) % 2 == 0 else [k])
        med = 0.5 * (part[k - 1] + part[k]) if len(grad) % 2 == 0 else part[k]
        return 1.0 / np.maximum(grad, 1e-12 + 1e-6 * med)

    wts = weights(n0, h0)

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
        """Levels from the mean cos beta of each point set at (n, h), and the start's cost."""
        cb0 = _terms(dT, n, h, L, rl)[0]
        tau0 = np.clip(np.bincount(kidx, weights=cb0, minlength=len(ts)) / n_members, 1e-3,
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
        r = (cb0 - taus_of(q)[kidx]) * wts
        return q, float(r @ r)

    # start: the given one and planes along the BP's constraint (as in photometric_fit)
    cands = [(n0, h0)]
    if n_start_depths and np.linalg.norm(L) > 0:
        for sdep in nominal_depth_mm * np.geomspace(1 / 8, 8, n_start_depths):
            X = sdep * d_bp
            nc = unit(unit(-X) + unit(L - X))
            cands.append((nc, float(-(nc @ X))))
    q0, _, n0_c, h0_c = min((tau_start(n, h) + (n, h) for n, h in cands), key=lambda c: c[1])
    if n0_c is not n0:  # the weights and levels at the chosen start
        n0, h0 = n0_c, h0_c
        wts = weights(n0, h0)
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
                   taus=taus_of(q), detail="" if conv else msg)


# ------------------------------------------------------------------------------------------------
# photometric fit


def _roi_samples(vals, o, uu, vv, keep, max_pixels):
    """The ROI pixels a photometric fit uses: every kept pixel, or a regular sub-grid of them.

    Returns ``(sel, step, uv, y)``: flat indices of the used pixels, the sub-grid step (1: every
    pixel), their (u, v) image positions (N, 2) in pixels and their values (N,).
    """
    sel = np.flatnonzero(keep)
    step = 1
    if max_pixels and len(sel) > max_pixels:  # a regular sub-grid of the ROI
        step = int(np.ceil(np.sqrt(len(sel) / max_pixels)))
        grid = np.zeros_like(keep)
        grid[::step, ::step] = True
        sel = np.flatnonzero(keep & grid)
    uv = np.column_stack([uu.ravel()[sel] + o[0], vv.ravel()[sel] + o[1]]).astype(np.float64)
    y = vals.ravel()[sel]
    return sel, step, uv, y


def _roi_grid(values, camera, origin_uv, clip_level):
    """The ROI of a photometric fit: checked values, camera model, origin, pixel grid, unclipped mask.

    Returns ``vals`` (H, W) float64, the camera model, ``o`` (2,) the ROI's top-left pixel (u, v),
    ``uu, vv`` (H, W) the column and row indices, and ``keep`` (H, W) bool (``vals < clip_level``,
    all True without a clip level).

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.
    """
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim != 2 or not np.isfinite(vals).all():
        raise ValueError(f"values: need a finite (H, W) array, got shape {vals.shape}")
    camera = _camera(camera)
    H, W = vals.shape
    o = np.asarray(origin_uv, dtype=np.float64).reshape(2)
    vv, uu = np.mgrid[0:H, 0:W]
    keep = np.ones((H, W), bool) if clip_level is None else vals < clip_level
    return vals, camera, o, uu, vv, keep


def _residual_correlation(r, sel, shape, step: int) -> tuple[float, float]:
    """Correlation of the residuals of neighbouring fitted pixels, and their covariance.

    ``r`` (M,) are the residuals of the pixels ``sel`` (flat indices into an (H, W) grid, on a
    regular sub-grid of spacing ``step``); the pairs are the horizontal and vertical neighbours
    on that sub-grid. Returns ``(rho, c)``: ``rho = sum a b / sqrt(sum a^2 sum b^2)`` and
    ``c = mean(a b)`` (0, 0 without pairs).
    """
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
    """The misfit test of the plane and the curved patches: when neighbouring residuals
    correlate (rho above ``TOL.plane_misfit_rho``, covariance above ``TOL.plane_misfit_rel^2``;
    see :func:`_residual_correlation`), the detail saying so, else None."""
    rho, c = _residual_correlation(r, sel, shape, step)
    if rho > TOL.plane_misfit_rho and c > TOL.plane_misfit_rel**2:
        return (f"neighbouring residuals correlate (rho {rho:.3g} > {TOL.plane_misfit_rho}; "
                f"systematic RMS {np.sqrt(c):.3g})")
    return None


def _patch_verdict(rel_floor: float | None, r, sel, shape, step: int, ok_detail: str,
                   misfit_hint: str) -> tuple[str, str, bool, float]:
    """The status of a curved-patch fit (``quadric_fit``, ``cubic_patch_fit``) from its relative
    depth sigma at the noise floor ``rel_floor`` (None: J^T J singular) and its residuals ``r``
    of the pixels ``sel`` (see :func:`_residual_correlation`).

    Returns ``(status, detail, observable, rms)``: ``depth_not_observable`` when ``rel_floor``
    is None or above ``TOL.depth_rel_sigma_max``; ``patch_misfit`` (the depth withdrawn) when
    neighbouring residuals correlate as in :func:`_misfit`, or their RMS ``rms`` (relative to the
    ROI's maximum) is above ``TOL.patch_misfit_rms_rel``, the detail then ending in
    ``misfit_hint``; else ``ok`` with ``ok_detail``.
    """
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


def _misfit(est: LightAwareEstimate, r, sel, shape, step: int) -> LightAwareEstimate:
    """``est`` with status ``plane_misfit`` when the residuals are spatially correlated.

    Sensor and render noise are independent from pixel to pixel, so the residuals of a model that
    fits leave neighbouring pixels uncorrelated; a plane meeting a curved patch leaves a smooth
    residual pattern (rings, a ridge) whose neighbours agree. The test: the correlation rho of
    neighbouring residuals above ``TOL.plane_misfit_rho`` and their covariance above
    ``TOL.plane_misfit_rel^2`` (an exact image's residuals are rounding, correlated or not).
    The normal is kept (for the record); the depth is withdrawn.
    """
    if est.status not in (OK, "depth_not_observable"):
        return est
    correlated = _correlated(r, sel, shape, step)
    if correlated:
        return replace(est, status="plane_misfit", depth_mm=None, depth_sigma_mm=None,
                       distance_mm=None, detail=correlated)
    return est


def photometric_fit(values, origin_uv, bp_uv, camera, rig: LightRig, *,
                    clip_level: float | None = None, nominal_depth_mm: float = 20.0,
                    start_normal=None, start_roughness: float | None = None,
                    loss: str = "linear", f_scale: float = 0.02, supersample: int = 1,
                    n_start_depths: int = 0,
                    max_pixels: int | None = 16384, max_nfev: int = 200) -> LightAwareEstimate:
    """Fit the intensities of an ROI with the image of a plane lit by the whole rig.

    Model (module docstring): ``I = g sum_j w_j max(0, cos beta_j)^n f_j p_j + b0 + b1 du + b2 dv``
    per pixel centre; the linear parameters (g, b0, b1, b2) are solved for each value of the
    nonlinear ones (a, b, log h, log n) by linear least squares (variable projection, Notes), and
    those four are fitted by Levenberg-Marquardt (MINPACK through
    :func:`scipy.optimize.leastsq`, analytic Jacobian). Pixels at or above ``clip_level`` are left
    out (a saturated plateau carries no shape). A two-light rig's merged highlight is one model.
    The roughness starts from a log-log regression of the ROI's specular part on the start's
    cos beta (``log(I - b) - log(f p) = log g + n log cos beta``), refined by a few Gauss-Newton
    steps on log n alone with the start plane held, unless given.

    Parameters
    ----------
    values : ndarray of shape (H, W)
        ROI intensities (float, any unit).
    origin_uv : array_like of shape (2,)
        Pixel (u, v) of ``values[0, 0]`` in the image.
    bp_uv : array_like of shape (2,)
        Brightest point, undistorted px (for the start).
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    rig : LightRig
        The lights, camera frame, mm.
    clip_level : float, optional
        Pixels ``>= clip_level`` are left out (e.g. 255 for 8-bit); None keeps every pixel.
    nominal_depth_mm : float
        Depth of the BP assumed for the start's bisector, mm.
    start_normal : array_like of shape (3,), optional
        Start normal (e.g. from :func:`isocurve_fit`).
    start_roughness : float, optional
        Start Phong n.
    loss : str
        ``linear`` (Gaussian sensor noise), or ``soft_l1``, ``huber``, ``cauchy`` (reweighted).
    f_scale : float
        Soft margin of a robust loss, relative to the ROI's maximum.
    n_start_depths : int
        Further starts along the BP's constraint (depths nominal/8 to nominal*8), each refined;
        the solution of least cost is kept (0: the start, and the nominal bisector when a start is
        given).
    supersample : int
        s x s point samples per pixel, averaged (a renderer's or sensor's box filter; 1: the
        value at the pixel centre, as the exact images of :mod:`simtest.simulate.offset`).
    max_pixels : int or None
        Beyond this many unclipped pixels, fit those of a regular sub-grid (every k-th row and
        column; None keeps all). Every pixel of the lobe's tails matters: the tilt and the
        distance trade off along the BP's constraint, and what separates them is the lobe's shape
        down to its faint tails (a fit to the pixels above 2 % of the peak lost a factor of 3 to 5
        in accuracy against the Cramer-Rao bound).
    max_nfev : int
        Evaluation budget.

    Returns
    -------
    LightAwareEstimate
        ``estimator="photometric_fit"``, with ``roughness``. Status ``plane_misfit`` (normal kept,
        depth withdrawn) when the residuals of neighbouring pixels correlate: the plane model
        does not explain the ROI (a curved patch, whose lobe the plane model reproduces by
        trading the curvature for roughness and distance, and so misses the normal; see
        ``_misfit``).

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.

    Notes
    -----
    Variable projection [3]_. The background columns ``B = [1, du, dv]`` (M, 3) do not depend on
    the nonlinear parameters p: with Q an orthonormal basis of B and ``P = I - Q Q^T``, the values
    and the lobe image S(p) (M,) are projected once each, ``y~ = P y`` and ``a = P S``; the gain
    is then ``g = a . y~ / a . a`` and the residual ``r = g a - y~`` is exactly that of the full
    linear least squares in (g, b0, b1, b2) at p (pixel by pixel, so the residual tests of
    ``_misfit`` read it unchanged). Its exact Jacobian (Golub and Pereyra) with ``da = P dS``:
    ``dr = g (da - a (a . da) / (a . a)) - a (r . da) / (a . a)``; the first term alone
    (Kaufman's), which is ``P_[S, B] (g dS)``, gives the covariance, equal to the (a, b, log h,
    log n) block of the full eight-parameter ``s^2 (J^T J)^-1`` (a Schur complement), the
    residual variance counting all eight parameters. A robust loss reweights the rows: the
    linear part is then solved with the weights. Four parameters instead of eight, and the
    linear ones always at their optimum, take Levenberg-Marquardt fewer steps; with the start's
    roughness refined first it converges in about five evaluations on an exact image.
    """
    name = "photometric_fit"
    vals, camera, o, uu, vv, keep = _roi_grid(values, camera, origin_uv, clip_level)
    H, W = vals.shape
    border = np.concatenate([vals[0], vals[-1], vals[:, 0], vals[:, -1]])
    b_level = float(np.median(border))
    sel, step, uv, y = _roi_samples(vals, o, uu, vv, keep, max_pixels)
    if len(y) < 8 + 1:
        return LightAwareEstimate(name, "too_few_points", f"{len(y)} unclipped pixels")
    ss = int(supersample)
    if ss < 1:
        raise ValueError(f"supersample: must be >= 1, got {supersample!r}")
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    sub = np.array([(du_, dv_) for dv_ in offs for du_ in offs])  # (ss^2, 2)
    dT = np.ascontiguousarray(_rays(camera, (uv[:, None, :] + sub[None]).reshape(-1, 2)).T)
    rig_arr = _rig_arrays(rig)
    bp = np.asarray(bp_uv, dtype=np.float64).reshape(2)
    d_bp, n0, h0 = _start(bp, camera, rig, nominal_depth_mm, start_normal)
    du = (uv[:, 0] - bp[0]) / max(W, H)
    dv = (uv[:, 1] - bp[1]) / max(W, H)
    yscale = max(float(np.abs(y).max()), 1e-12)
    yn = y / yscale
    rl = _ray_light(rig_arr[0], dT)  # (J, N) each
    background = np.column_stack([np.ones_like(du), du, dv])
    proj = {}  # orthonormal basis of the (weighted) background columns, per weights

    def basis(w):
        """``QT`` (3, M), the background's orthonormal basis (rows), and the projected values."""
        key = None if w is None else w.tobytes()
        if proj.get("key") != key or "QT" not in proj:
            B = background if w is None else background * w[:, None]
            QT = np.ascontiguousarray(np.linalg.qr(B)[0].T)
            yw = yn if w is None else yn * w
            proj.update(key=key, QT=QT, yt=yw - (QT @ yw) @ QT)
        return proj["QT"], proj["yt"]

    def box(v):
        """The mean of each pixel's sub-pixel samples (the last axis)."""
        return v if ss == 1 else v.reshape(*v.shape[:-1], -1, ss * ss).mean(axis=-1)

    state = {}

    def resjac_at(p, nb, e1, e2, grad=True, w=None, kaufman=False):
        """Residuals of the variable projection (Notes) and their Jacobian in (a, b, log h, log n).

        ``w``: row weights (a robust loss' reweighting): the linear part is solved with them and
        the residual and Jacobian returned are the unweighted ones of that solution. ``kaufman``:
        the Jacobian without its second-order term, ``P (g dS)`` (for the covariance).
        """
        QT, yt = basis(w)
        key = (p.tobytes(), nb.tobytes(), None if w is None else w.tobytes())
        if state.get("key") != key:
            n, dns = _normal_derivs(p, nb, e1, e2)
            h, rough = float(np.exp(p[2])), float(np.exp(p[3]))
            S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
            S = box(S)
            Sw = S if w is None else S * w
            St = Sw - (QT @ Sw) @ QT
            aa = float(St @ St)
            g = float(St @ yt) / aa if aa > 0 else 0.0
            rw = g * St - yt
            state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, St=St, aa=aa, g=g,
                         rw=rw, r=rw if w is None else rw / w)
        if not grad:
            return state["r"], None
        return state["r"], jac_of(state["dns"], w, kaufman)

    def jac_of(dns, w, kaufman):
        """The Jacobian (M, 4) at the point of ``state``, the normal's derivatives ``dns``."""
        st = state
        QT = basis(w)[0]
        dS = box(_rig_grad(dT, st["parts"], st["n"], dns, st["h"], rig_arr, st["rough"]))
        if w is not None:
            dS = dS * w
        St, aa, g = st["St"], st["aa"], st["g"]
        if not aa > 0:
            return np.zeros((len(St), 4))
        M = np.empty((4, 4))  # JT = g dS - M @ [QT; St]: the projections in one product
        M[:, :3] = (g * dS) @ QT.T
        M[:, 3] = dS @ St * (g / aa)
        if not kaufman:
            M[:, 3] += dS @ st["rw"] / aa
        JT = g * dS - M @ np.vstack([QT, St])
        return (JT if w is None else JT / w).T

    def start_for(n, h):
        """Start roughness: a log-log regression of the specular part on cos beta, then Gauss-Newton.

        The regression's slope is sensitive to the start plane (log cos beta is small near the
        peak); a few Gauss-Newton steps on log n alone (the plane held, the linear part projected
        out as in the fit) bring it to the least-squares roughness of the start plane.
        """
        if start_roughness is not None:
            return float(start_roughness)
        # cos beta f p and f p (the lobe at n = 1 and n = 0): their ratio is cos beta (one light)
        S1, parts = _rig_value(dT, rl, n, h, rig_arr, 1.0)  # 0 where a ray misses (cb < 0)
        S0 = sum(pt[3] / pt[1] for pt in parts)  # val / cb
        S1, S0 = box(S1), box(S0)
        spec = y - b_level
        selr = (spec > 0.05 * spec.max()) & (S1 > 0)
        log_n = np.log(50.0)
        if np.count_nonzero(selr) >= 3:
            x = np.log(np.clip(S1[selr] / S0[selr], 1e-12, None))
            z = np.log(spec[selr] / S0[selr])
            xc = x - x.mean()
            den = float(xc @ xc)
            slope = float(xc @ (z - z.mean())) / den if den > 0 else np.nan  # least-squares line
            if np.isfinite(slope) and slope > 1:
                log_n = np.log(min(slope, _ROUGHNESS_RANGE[1]))
        QT, yt = basis(None)
        for _ in range(_ROUGHNESS_START_STEPS):
            rough = float(np.exp(log_n))
            S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
            S, dS = box(S), box(sum(pt[3] * pt[2] for pt in parts) * rough)  # dS / d log n
            St, da = S - (QT @ S) @ QT, dS - (QT @ dS) @ QT
            aa = float(St @ St)
            if not aa > 0:
                break
            g = float(St @ yt) / aa
            r = g * St - yt
            J = g * (da - St * (float(St @ da) / aa)) - St * (float(r @ da) / aa)
            jj = float(J @ J)
            step = -float(J @ r) / jj if jj > 0 else 0.0
            if not np.isfinite(step):
                break
            log_n = float(np.clip(log_n + np.clip(step, -1.0, 1.0), *np.log(_ROUGHNESS_RANGE)))
            if abs(step) < 1e-3:
                break
        return float(np.exp(log_n))

    # Starts: the given one (or the bisector at the nominal depth), the nominal bisector too when
    # a start was given, and n_start_depths planes along the BP's constraint (each the bisector
    # at a depth from nominal/8 to nominal*8, its distance such that the specular point is the
    # BP). Each is refined; the solution of least cost is kept. A near plane with a rough lobe can
    # mimic a far one with a smooth lobe (a local minimum), which one start may fall into.
    cands = [(n0, h0)]
    if np.abs(rig_arr[0]).max() > 0:
        Lm = _mean_light(rig)
        depths = (list(nominal_depth_mm * np.geomspace(1 / 8, 8, n_start_depths))
                  if n_start_depths else [])
        if start_normal is not None:
            depths.append(nominal_depth_mm)
        for sdep in depths:
            X = sdep * d_bp
            nc = unit(unit(-X) + unit(Lm - X))
            cands.append((nc, float(-(nc @ X))))
    best = None
    nfev_total = 0
    for nc, hc in cands:
        e1, e2 = plane_basis(nc)
        p0 = np.array([0.0, 0.0, np.log(hc), np.log(start_for(nc, hc))])
        free = np.ones(len(p0), bool)
        free[2] = np.abs(rig_arr[0]).max() > 1e-9 * hc  # all lights at V: no dependence on h
        x, nfev, conv, msg, r = _solve(resjac_at, p0, (nc, e1, e2), loss, f_scale, max_nfev, free,
                                       lazy_jac=True, weighted=True)
        nfev_total += nfev
        cost = float(r @ r) if np.isfinite(r).all() else np.inf
        if best is None or cost < best[0]:
            best = (cost, x, nc, hc, e1, e2, conv, msg)
    _, x, n0, h0, e1, e2, conv, msg = best
    nfev = nfev_total
    n_hat = _normal_derivs(x, n0, e1, e2)[0]
    h_hat = float(np.exp(x[2]))
    bad = _implausible(h_hat, h0, float(np.exp(x[3])))
    if bad:
        return LightAwareEstimate(name, "not_converged", bad, n_evaluations=nfev)
    if np.any(n_hat @ rig_arr[0].T + h_hat <= 0):
        return LightAwareEstimate(name, "light_behind_plane", f"h = {h_hat:.4g} mm", n_evaluations=nfev)

    def at_solution(p_hat, nb, e1_, e2_):
        """Residuals and covariance Jacobian about (nb, e1_, e2_) at the solution x.

        The plane and roughness are x's (``nb`` is x's normal): the model at x, most often the
        solver's last evaluation, is reused and only the derivatives are taken about ``nb``.
        """
        resjac_at(x, n0, e1, e2, grad=False)
        return state["r"], jac_of(_normal_derivs(p_hat, nb, e1_, e2_)[1], None, True)

    return _finish(name, at_solution, n_hat, h_hat, rig, x[3:],
                   TOL.photometric_noise_rel, nfev, conv, roughness=float(np.exp(x[3])),
                   detail="" if conv else msg, n_linear=4,
                   post=lambda est, r0: _misfit(est, r0, sel, keep.shape, step))


# ------------------------------------------------------------------------------------------------
# Cramer-Rao bound of the photometric model


@dataclass(frozen=True)
class CramerRaoBound:
    """Lower bounds on the standard deviations of an unbiased photometric estimate.

    Attributes
    ----------
    normal_deg : float
        RMS angle of the normal's error, degrees (``sqrt(C_aa + C_bb)``).
    depth_rel : float
        Relative standard deviation of the specular point's depth (inf when not observable).
    n_pixels : int
        Pixels that carry the information (unclipped pixels of the ROI).
    """

    normal_deg: float
    depth_rel: float
    n_pixels: int


def photometric_crb(camera, origin_uv, shape, normal, distance_mm: float, rig: LightRig,
                    roughness: float, gain: float, sigma: float, *,
                    background=(0.0, 0.0, 0.0), bp_uv=None,
                    clip_level: float | None = None) -> CramerRaoBound:
    """Cramer-Rao bound of the photometric model under per-pixel Gaussian noise.

    The image model is the one :func:`photometric_fit` fits (module docstring): nonlinear
    parameters (a, b, log h, log n) and linear ones (g, b0, b1, b2). With independent Gaussian
    noise of standard deviation sigma on each pixel, the Fisher information is
    ``F = J^T J / sigma^2``, J the Jacobian of the noise-free image (every unclipped pixel of the
    ROI) at the true parameters; ``C = F^-1`` bounds the covariance of any unbiased estimator
    (the nuisance parameters, roughness, gain and background, are accounted for, not assumed
    known). The normal's bound is ``sqrt(C_aa + C_bb)``; the depth's follows by the delta method
    through the specular point of the rig's mean light.

    Parameters
    ----------
    camera : array_like of shape (3, 3) or CameraModel
        Intrinsics K, or a camera model with ``pixel_to_ray``.
    origin_uv : array_like of shape (2,)
        Pixel (u, v) of the ROI's first element.
    shape : (H, W)
        ROI size, px.
    normal : array_like of shape (3,)
        True unit normal facing the camera.
    distance_mm : float
        True plane distance h, mm.
    rig : LightRig
        The lights.
    roughness : float
        True Phong n.
    gain : float
        Image units per unit of the model (the peak of a Phong lobe without falloff).
    sigma : float
        Noise standard deviation, image units.
    background : (b0, b1, b2)
        Linear background (``b0 + b1 du + b2 dv`` with du, dv the offsets from ``bp_uv`` over the
        ROI's larger side), image units.
    bp_uv : array_like of shape (2,), optional
        The reference pixel of the background (default the ROI centre).
    clip_level : float, optional
        Pixels whose noise-free value reaches it carry no information and are left out.

    Returns
    -------
    CramerRaoBound

    Raises
    ------
    ValueError
        If sigma is not > 0.
    """
    if not sigma > 0:
        raise ValueError(f"sigma: must be > 0, got {sigma}")
    camera = _camera(camera)
    H, W = (int(v) for v in shape)
    o = np.asarray(origin_uv, dtype=np.float64).reshape(2)
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.column_stack([uu.ravel() + o[0], vv.ravel() + o[1]]).astype(np.float64)
    ref = o + [(W - 1) / 2, (H - 1) / 2] if bp_uv is None else np.asarray(bp_uv, dtype=np.float64)
    du = (uv[:, 0] - ref[0]) / max(W, H)
    dv = (uv[:, 1] - ref[1]) / max(W, H)
    d = _rays(camera, uv)
    n = unit(np.asarray(normal, dtype=np.float64))
    e1, e2 = plane_basis(n)
    _, dns = _normal_derivs(np.zeros(2), n, e1, e2)
    S, dS = _rig_image(d, n, dns, float(distance_mm), _rig_arrays(rig), float(roughness))
    b0, b1, b2 = (float(v) for v in background)
    img = gain * S + b0 + b1 * du + b2 * dv
    keep = np.ones(len(img), bool) if clip_level is None else img < clip_level
    J = np.column_stack([gain * dS, S, np.ones_like(S), du, dv])[keep]
    cov = _covariance(J, sigma**2)
    if cov is None:  # h not observable: bound the normal with h held (its column removed)
        Jr = np.delete(J, 2, axis=1)
        covr = _covariance(Jr, sigma**2)
        nd = float("inf") if covr is None else float(np.degrees(np.sqrt(covr[0, 0] + covr[1, 1])))
        return CramerRaoBound(nd, float("inf"), int(keep.sum()))
    g = _log_depth_gradient(n, float(distance_mm), _mean_light(rig))
    return CramerRaoBound(float(np.degrees(np.sqrt(cov[0, 0] + cov[1, 1]))),
                          float(np.sqrt(max(g @ cov[:3, :3] @ g, 0.0))), int(keep.sum()))


# ------------------------------------------------------------------------------------------------
# quadric patch (curved surfaces)


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
    ax, ay, az = d @ t1, d @ t2, d @ N
    bx, by, bz = -(P0 @ t1), -(P0 @ t2), -(P0 @ N)
    # F = z + (k_xx x^2 + 2 k_xy x y + k_yy y^2) / 2 = 0 along the ray X = t d: A t^2 + B t + C = 0
    kzz = 0.5 * (kxx + kyy)  # the z^2 term: exact for a sphere
    A = 0.5 * (kxx * ax * ax + 2 * kxy * ax * ay + kyy * ay * ay + kzz * az * az)
    B = az + (kxx * ax * bx + kxy * (ax * by + ay * bx) + kyy * ay * by + kzz * az * bz)
    C = bz + 0.5 * (kxx * bx * bx + 2 * kxy * bx * by + kyy * by * by + kzz * bz * bz)
    disc = B * B - 4 * A * C
    ok = disc >= 0
    den = B + np.where(B >= 0, 1.0, -1.0) * np.sqrt(np.where(ok, disc, 0.0))
    good_den = np.abs(den) > 1e-15
    t = np.where(good_den, -2 * C / np.where(good_den, den, 1.0), np.inf)  # the root near -C/B
    ok &= (t > 0) & np.isfinite(t)
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
                max_pixels: int | None = 800, max_nfev: int = 100) -> LightAwareEstimate:
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
    the bisector; the quadric model fits the curvature instead. Uncertainty: ``C = s^2 (J^T J)^-1`` with J the Jacobian of the projected
    residual at the solution, propagated to N by finite differences.

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

    Returns
    -------
    LightAwareEstimate
        ``estimator="quadric_fit"``, status ``ok``, ``depth_not_observable``, ``patch_misfit``
        or ``not_converged``; ``distance_mm`` is the apex depth s.

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
    cov = _covariance(J, resid_var)
    cov_floor = _covariance(J, max(resid_var, TOL.photometric_noise_rel**2))
    G = np.empty((3, 7))  # dN / dp
    for i in range(7):
        dp = np.zeros(7)
        dp[i] = 1e-6 * x_scale[i]
        G[:, i] = (_quadric_image(d[:1], b_ray, x + dp, rig_arr, Lm)[1]
                   - _quadric_image(d[:1], b_ray, x - dp, rig_arr, Lm)[1]) / (2 * dp[i])
    sigma_deg = (None if cov is None
                 else float(np.degrees(np.sqrt(max(np.trace(G @ cov @ G.T), 0.0)))))
    rel_floor = None if cov_floor is None else float(np.sqrt(max(cov_floor[2, 2], 0.0)))
    status, detail, observable, rms = _patch_verdict(
        rel_floor, r0, sel, P.shape, step, "", "the ROI is not one patch's lobe (streaks along folds, several lobes)")
    depth_sigma = (float(s_hat * np.sqrt(max(cov[2, 2], 0.0)))
                   if observable and cov is not None else None)
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None, sigma_deg,
                              depth_sigma if observable else None, s_hat if observable else None,
                              rough, None, nfev, rms, depth_rel_sigma=rel_floor)


# ------------------------------------------------------------------------------------------------
# cubic patch (curved surfaces under a rig of several lights)

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
    ax, ay, az = d @ t1, d @ t2, d @ N
    bx, by, bz = -(P0 @ t1), -(P0 @ t2), -(P0 @ N)
    # the quadric's root (as in _quadric_image), then Newton on the full F along the ray
    A = 0.5 * (kxx * ax * ax + 2 * kxy * ax * ay + kyy * ay * ay + kzz * az * az)
    B = az + (kxx * ax * bx + kxy * (ax * by + ay * bx) + kyy * ay * by + kzz * az * bz)
    C = bz + 0.5 * (kxx * bx * bx + 2 * kxy * bx * by + kyy * by * by + kzz * bz * bz)
    disc = B * B - 4 * A * C
    ok = disc >= 0
    den = B + np.where(B >= 0, 1.0, -1.0) * np.sqrt(np.where(ok, disc, 0.0))
    good_den = np.abs(den) > 1e-15
    t = np.where(good_den, -2 * C / np.where(good_den, den, 1.0), np.inf)
    ok &= (t > 0) & np.isfinite(t)
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
                    max_nfev: int = 100) -> LightAwareEstimate:
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
    cov = _covariance(J, resid_var)
    cov_floor = _covariance(J, max(resid_var, TOL.photometric_noise_rel**2))
    G = np.empty((3, _CUBIC_PARAMS))  # dN / dp
    for i in range(_CUBIC_PARAMS):
        dp = np.zeros(_CUBIC_PARAMS)
        dp[i] = 1e-6 * S["x_scale"][i]
        G[:, i] = (_cubic_patch_geometry(b_ray[None], b_ray, x + dp, Lm)[3]
                   - _cubic_patch_geometry(b_ray[None], b_ray, x - dp, Lm)[3]) / (2 * dp[i])
    sigma_deg = (None if cov is None
                 else float(np.degrees(np.sqrt(max(np.trace(G @ cov @ G.T), 0.0)))))
    rel_floor = None if cov_floor is None else float(np.sqrt(max(cov_floor[2, 2], 0.0)))
    status, detail, observable, rms = _patch_verdict(
        rel_floor, r0, S["sel"], S["shape"], S["step"], f"profile minimum at {depths[i0]:.4g} mm",
        "the ROI is not one patch's lobes (streaks along folds, a lobe cut off)")
    depth_sigma = (float(s_hat * np.sqrt(max(cov[2, 2], 0.0)))
                   if observable and cov is not None else None)
    ln = ld = None
    if observable:
        ln, ld = _patch_specular_points(b_ray, x, Lm, S["rig_arr"][0])
    return LightAwareEstimate(name, status, detail, n_hat, s_hat if observable else None,
                              sigma_deg, depth_sigma, s_hat if observable else None, rough, None,
                              nfev, rms, ln, ld, rel_floor)
