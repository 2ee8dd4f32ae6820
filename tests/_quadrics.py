"""Closed-form Phong images of spheres and cylinders (ray-quadric intersection, no renderer) and
their brightest points under a co-located light: exact inputs for the tests of the estimators.

Frames and units as :mod:`simtest.simulate.analytic` (whose per-pixel Phong shading they use).
"""

from __future__ import annotations

import numpy as np

from simtest.simulate.analytic import _phong_image


def _quadric_image(K, shape, A, b, c0, n, c, light_mm, supersample):
    """Phong image of the quadric ``X^T A X + 2 b.X + c0 = 0`` (camera frame), first hit per ray."""

    def intersect(d):
        # (lam d)^T A (lam d) + 2 lam b.d + c0 = 0
        qa = np.einsum("...i,ij,...j->...", d, A, d)
        qb = 2.0 * (d @ b)
        disc = qb * qb - 4.0 * qa * c0
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(np.maximum(disc, 0.0))
            r1 = (-qb - sq) / (2.0 * qa)
            r2 = (-qb + sq) / (2.0 * qa)
            lo, hi = np.minimum(r1, r2), np.maximum(r1, r2)
            lam = np.where(lo > 0, lo, hi)
            X = d * lam[..., None]
            N = X @ A.T + b
            N = N / np.linalg.norm(N, axis=-1, keepdims=True)
        return (disc >= 0) & (lam > 0), lam, N

    return _phong_image(K, shape, n, c, light_mm, supersample, intersect)


def phong_sphere_image(K, shape, centre_mm, radius_mm: float, n: float, c: float = 1.0,
                       light_mm=(0.0, 0.0, 0.0), supersample: int = 1) -> np.ndarray:
    """Closed-form Phong image of a sphere seen from outside (ray-quadric intersection).

    Parameters
    ----------
    K : array_like of shape (3, 3)
        Intrinsics.
    shape : (H, W)
        Image size, pixels.
    centre_mm : array_like of shape (3,)
        Sphere centre, camera frame, mm; the camera must be outside the sphere.
    radius_mm : float
        Radius R, mm; principal curvatures k1 = k2 = 1/R.
    n, c, light_mm, supersample
        As in :func:`phong_plane_image` (no falloff).

    Returns
    -------
    ndarray of shape (H, W)

    Raises
    ------
    ValueError
        If the camera is inside the sphere or parameters are invalid.
    """
    S = np.asarray(centre_mm, dtype=np.float64).reshape(3)
    if not radius_mm > 0 or np.linalg.norm(S) <= radius_mm:
        raise ValueError(f"need radius_mm > 0 and the camera outside the sphere, got R={radius_mm}, |S|={np.linalg.norm(S)}")
    return _quadric_image(K, shape, np.eye(3), -S, S @ S - radius_mm**2, n, c, light_mm, supersample)


def phong_cylinder_image(K, shape, point_mm, axis, radius_mm: float, n: float, c: float = 1.0,
                         light_mm=(0.0, 0.0, 0.0), supersample: int = 1) -> np.ndarray:
    """Closed-form Phong image of an infinite circular cylinder seen from outside.

    Parameters
    ----------
    point_mm : array_like of shape (3,)
        A point on the axis, camera frame, mm.
    axis : array_like of shape (3,)
        Axis direction (any length).
    radius_mm : float
        Radius R; principal curvatures k1 = 1/R (around the axis) and k2 = 0 (along it).
    K, shape, n, c, light_mm, supersample
        As in :func:`phong_sphere_image`.

    Returns
    -------
    ndarray of shape (H, W)
    """
    P0 = np.asarray(point_mm, dtype=np.float64).reshape(3)
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    a = a / np.linalg.norm(a)
    Pm = np.eye(3) - np.outer(a, a)  # projector orthogonal to the axis
    q = Pm @ P0
    if not radius_mm > 0 or np.linalg.norm(q) <= radius_mm:
        raise ValueError("need radius_mm > 0 and the camera outside the cylinder")
    # |Pm (X - P0)|^2 = R^2  ->  X^T Pm X - 2 (Pm P0).X + P0^T Pm P0 - R^2 = 0
    return _quadric_image(K, shape, Pm, -q, P0 @ Pm @ P0 - radius_mm**2, n, c, light_mm, supersample)


def sphere_bp(centre_mm, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """BP and normal of a sphere under a co-located light: the point nearest the camera.

    There the normal is parallel to the viewing ray: with the light at the camera, the BP of any
    surface is where the normal is parallel to the viewing ray (``gamma = 0`` in the Notes of
    :func:`simtest.geometry.conics.cone_axis`, where ``cos beta = cos 2 gamma`` is largest).

    Returns
    -------
    bp_mm : ndarray of shape (3,)
        Camera frame, mm.
    normal : ndarray of shape (3,)
        Unit normal facing the camera, ``-S / |S|``.
    """
    S = np.asarray(centre_mm, dtype=np.float64).reshape(3)
    u = S / np.linalg.norm(S)
    return S - radius_mm * u, -u


def cylinder_bp(point_mm, axis, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """BP and normal of a cylinder under a co-located light: the point nearest the camera.

    Returns
    -------
    bp_mm : ndarray of shape (3,)
    normal : ndarray of shape (3,)
        Unit normal facing the camera, perpendicular to the axis.
    """
    P0 = np.asarray(point_mm, dtype=np.float64).reshape(3)
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    a = a / np.linalg.norm(a)
    Q = P0 - (P0 @ a) * a  # foot of the perpendicular from the camera to the axis
    u = Q / np.linalg.norm(Q)
    return Q - radius_mm * u, -u
