"""What the principal curvatures at a co-located BP predict for the isophote cone.

Sign convention (the one of :mod:`simtest.simulate.truth` and :mod:`simtest.scene.meshes`): the
principal curvatures ``k1 >= k2`` (1/mm) are signed, positive where the surface bends away from
its camera-facing normal, i.e. a patch that bulges toward the camera like the outside of a sphere
(sphere of radius R seen from outside: ``k1 = k2 = +1/R``; cylinder seen from outside:
``k1 = +1/R, k2 = 0``), negative where it is hollow toward the camera (the inside of a tube, as
the colon's lumen: ``k1 = 0, k2 = -1/R``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["curvature_ratio", "predicted_eigenvalue_gap", "predicted_pose_error_deg"]


def curvature_ratio(k1, k2, distance_mm):
    """The ratio rho = |1 + k2 d| / |1 + k1 d| that governs the co-located isophote cone.

    Parameters
    ----------
    k1, k2 : float or array_like
        Signed principal curvatures at the BP, 1/mm, ``k1 >= k2`` (module sign convention).
    distance_mm : float or array_like
        Distance d from the camera centre to the BP along its viewing ray, mm (> 0).

    Returns
    -------
    float or ndarray
        rho >= 0 (1 for an isotropic patch: sphere or plane); NaN where ``1 + k1 d = 0``
        (the camera at a focal point of the patch) or an input is not finite.

    Notes
    -----
    With a co-located light the BP is where the normal N is parallel to the viewing ray
    (``X0 = -d N``). Near it the surface is ``X0 + x e1 + y e2 + (k1 x^2 + k2 y^2) / 2 (-N)`` to
    second order, with e1, e2 the principal directions. The Phong intensity depends on the angle
    between the mirror of the light direction and the view direction; to first order in (x, y)
    that angle along e_i is ``|1 + k_i d| |x_i| / d`` (the surface normal turns by ``k_i x_i``
    and the viewing direction by ``x_i / d``, in the same sense for a convex patch). An isophote
    is therefore an ellipse with semi-axes proportional to ``1 / |1 + k_i d|``, and the cone from
    the camera through it has half-apertures whose tangents are in the ratio
    ``|1 + k2 d| / |1 + k1 d|`` = rho. For such a cone, normalised so that ``l1 >= l2 > 0 > l3``,
    the eigenvalues are ``l_i = 1 / tan^2(a_i)`` up to scale for a narrow cone, so
    ``(l1 - l2) / (l1 - l3) -> 1 - rho^2`` (:func:`predicted_eigenvalue_gap`). The axis of that
    cone is still N (the patch is symmetric about N to second order), which is why the cone axis
    stays unbiased while the circle-pose normals N+ and N- leave it (:func:`predicted_pose_error_deg`).
    A plane (k1 = k2 = 0) and a sphere (k1 = k2) give rho = 1: a right circular cone.
    """
    k1 = np.asarray(k1, dtype=np.float64)
    k2 = np.asarray(k2, dtype=np.float64)
    d = np.asarray(distance_mm, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        den = np.abs(1.0 + k1 * d)
        rho = np.where(den > 0, np.abs(1.0 + k2 * d) / np.where(den > 0, den, 1.0), np.nan)
    return float(rho) if rho.ndim == 0 else rho


def predicted_eigenvalue_gap(rho):
    """Eigenvalue gap ``(l1 - l2) / (l1 - l3)`` of C' predicted from rho: ``1 - min(rho, 1/rho)^2``.

    Parameters
    ----------
    rho : float or array_like
        :func:`curvature_ratio` (>= 0).

    Returns
    -------
    float or ndarray
        In [0, 1]; 0 for a right circular cone (rho = 1), 1 for rho = 0 (the camera at a focal
        point of one principal direction); NaN where rho is NaN.

    Notes
    -----
    For ``k1 >= k2`` and both ``1 + k_i d > 0`` (a patch in front of its focal points) rho <= 1
    and the gap is ``1 - rho^2`` (see :func:`curvature_ratio`). Beyond a focal point of the
    concave direction ``|1 + k2 d|`` can exceed ``|1 + k1 d|``: the wider half-aperture then
    belongs to the other principal direction, and the gap is ``1 - 1/rho^2``.
    """
    r = np.asarray(rho, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        m = np.where(r > 1.0, 1.0 / r, r)
        g = np.where(r >= 0, 1.0 - m * m, np.nan)
    return float(g) if g.ndim == 0 else g


def predicted_pose_error_deg(rho):
    """Angle between each circle-pose normal N+- and the cone axis predicted from rho, degrees.

    Parameters
    ----------
    rho : float or array_like
        :func:`curvature_ratio`.

    Returns
    -------
    float or ndarray
        ``asin(sqrt(gap))`` with gap from :func:`predicted_eigenvalue_gap`, in [0, 90] deg.

    Notes
    -----
    :func:`simtest.geometry.conics.circle_pose` builds ``N+- = +-sin(phi) e1 + cos(phi) e3`` with
    ``sin^2 phi = (l1 - l2) / (l1 - l3)``, the eigenvalue gap; e3 is the cone axis. Since the axis
    is the true normal (see :func:`curvature_ratio`), both N+ and N- err by ``phi =
    asin(sqrt(gap))``: the paper's circle-pose normals, oracle or not, inherit this error on any
    anisotropic patch however small the isophote (Forsyth et al. 1991 circle pose, applied to a
    cone that is not a circle's: https://doi.org/10.1109/34.99233).
    """
    g = np.asarray(predicted_eigenvalue_gap(rho), dtype=np.float64)
    a = np.degrees(np.arcsin(np.sqrt(np.clip(g, 0.0, 1.0))))
    a = np.where(np.isfinite(g), a, np.nan)
    return float(a) if a.ndim == 0 else a
