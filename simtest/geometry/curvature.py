"""What the principal curvatures at a co-located BP predict for the isophote cone.

Signs (as :mod:`simtest.simulate.truth`): ``k1 >= k2``, 1/mm, positive where the patch bulges toward the
camera (a sphere seen from outside: ``k1 = k2 = +1/R``), negative where it is hollow (a tube's inside,
the colon's lumen: ``k1 = 0, k2 = -1/R``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["curvature_ratio", "predicted_eigenvalue_gap", "predicted_pose_error_deg"]


def curvature_ratio(k1, k2, distance_mm):
    """The ratio rho = |1 + k2 d| / |1 + k1 d| that governs the co-located isophote cone.

    With a co-located light the isophote near the BP is an ellipse with semi-axes proportional to
    ``1 / |1 + k_i d|``, so the cone's half-aperture tangents are in the ratio rho; its axis stays the normal.

    Parameters
    ----------
    k1, k2 : float or array_like
        Signed principal curvatures at the BP, 1/mm, ``k1 >= k2``.
    distance_mm : float or array_like
        Distance d from the camera centre to the BP along its viewing ray, mm (> 0).

    Returns
    -------
    float or ndarray
        rho >= 0 (1 for a sphere or plane); NaN where ``1 + k1 d = 0`` or an input is not finite.
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
        In [0, 1]; 0 for a right circular cone (rho = 1); NaN where rho is NaN.
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
