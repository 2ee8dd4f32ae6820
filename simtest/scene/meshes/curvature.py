"""Principal curvatures of closed-form surfaces (finite differences and exact derivatives).

The sign convention and the accuracy of the finite differences are in :mod:`simtest.scene.meshes`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from simtest.scene.meshes.params import MeshError


#: Finite-difference step of the closed-form ground truth, mm (angles use this over a radius).
FD_STEP_MM = 1e-2


# Fourth-order central stencils: offsets (in steps) and weights.
_D1 = ((-2, 1.0 / 12.0), (-1, -8.0 / 12.0), (1, 8.0 / 12.0), (2, -1.0 / 12.0))
_D2 = ((-2, -1.0 / 12.0), (-1, 16.0 / 12.0), (0, -30.0 / 12.0), (1, 16.0 / 12.0), (2, -1.0 / 12.0))


def _principal_from_h_k(h: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """k1, k2 = H +- sqrt(max(H^2 - K, 0)) (k1 >= k2)."""
    disc = np.sqrt(np.maximum(h * h - k, 0.0))
    return h + disc, h - disc


def parametric_curvature(surface: Callable[[np.ndarray, np.ndarray], np.ndarray], u: np.ndarray, v: np.ndarray,
                         h_u: float, h_v: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, unit normal and principal curvatures of a parametrised surface X(u, v).

    Parameters
    ----------
    surface : callable
        ``surface(u, v) -> ndarray of shape (..., 3)``, vectorised, broadcasting ``u`` and ``v``.
    u, v : ndarray
        Parameters (broadcastable to one shape S).
    h_u, h_v : float
        Finite-difference steps in ``u`` and ``v`` (in parameter units).

    Returns
    -------
    position : ndarray of shape S + (3,)
    normal : ndarray of shape S + (3,)
        ``X_u x X_v / |X_u x X_v|`` (the orientation follows the parametrisation).
    k1, k2 : ndarray of shape S
        Principal curvatures (k1 >= k2), positive where the surface bends away from ``normal``,
        1 / (unit of X): fourth-order central differences, then :func:`curvature_from_derivatives`.
    """
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    x0 = surface(u, v)
    xu = sum(w * surface(u + i * h_u, v) for i, w in _D1) / h_u
    xv = sum(w * surface(u, v + j * h_v) for j, w in _D1) / h_v
    xuu = sum(w * (x0 if i == 0 else surface(u + i * h_u, v)) for i, w in _D2) / h_u**2
    xvv = sum(w * (x0 if j == 0 else surface(u, v + j * h_v)) for j, w in _D2) / h_v**2
    xuv = sum(wi * wj * surface(u + i * h_u, v + j * h_v) for i, wi in _D1 for j, wj in _D1) / (h_u * h_v)
    n, k1, k2 = curvature_from_derivatives(xu, xv, xuu, xuv, xvv)
    return x0, n, k1, k2


def curvature_from_derivatives(xu: np.ndarray, xv: np.ndarray, xuu: np.ndarray, xuv: np.ndarray,
                               xvv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normal and principal curvatures from a parametrisation's first and second derivatives.

    Parameters
    ----------
    xu, xv, xuu, xuv, xvv : ndarray of shape S + (3,)
        ``X_u, X_v, X_uu, X_uv, X_vv`` of a surface X(u, v).

    Returns
    -------
    normal : ndarray of shape S + (3,)
        ``X_u x X_v / |X_u x X_v|``.
    k1, k2 : ndarray of shape S
        Principal curvatures (k1 >= k2), positive where the surface bends away from ``normal``:
        ``E, F, G = X_u.X_u, X_u.X_v, X_v.X_v``; ``L, M, N = -X_uu.n, -X_uv.n, -X_vv.n``;
        ``K = (LN - M^2) / (EG - F^2)``, ``H = (EN - 2FM + GL) / (2 (EG - F^2))`` (do Carmo,
        Differential Geometry of Curves and Surfaces, 1976, sec. 3-3).
    """
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    e = np.einsum("...i,...i", xu, xu)
    f = np.einsum("...i,...i", xu, xv)
    g = np.einsum("...i,...i", xv, xv)
    ll = -np.einsum("...i,...i", xuu, n)
    mm = -np.einsum("...i,...i", xuv, n)
    nn = -np.einsum("...i,...i", xvv, n)
    det = e * g - f * f
    gauss = (ll * nn - mm * mm) / det
    mean = (e * nn - 2.0 * f * mm + g * ll) / (2.0 * det)
    k1, k2 = _principal_from_h_k(mean, gauss)
    return n, k1, k2


def implicit_curvature(func: Callable[[np.ndarray], np.ndarray], points: np.ndarray,
                       h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normal and principal curvatures of the level set of ``func`` through each point.

    Parameters
    ----------
    func : callable
        ``func(x) -> ndarray of shape (...)`` for ``x`` of shape ``(..., 3)``; smooth near the points.
    points : ndarray of shape (N, 3)
        Points on the level set.
    h : float
        Finite-difference step (units of the points).

    Returns
    -------
    normal : ndarray of shape (N, 3)
        ``grad F / |grad F|`` (toward increasing F).
    k1, k2 : ndarray of shape (N,)
        Principal curvatures (k1 >= k2), positive where the surface bends away from ``normal``:
        the eigenvalues of ``P Hess(F) P / |grad F|`` on the tangent plane, P = I - n n^T
        (Goldman, "Curvature formulas for implicit curves and surfaces", CAGD 22, 2005,
        doi:10.1016/j.cagd.2005.06.005); gradient and Hessian by fourth-order central differences.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise MeshError(f"implicit_curvature: points must have shape (N, 3), got {p.shape}")
    eye = np.eye(3)
    f0 = func(p)
    grad = np.empty_like(p)
    hess = np.empty(p.shape[:1] + (3, 3))
    for a in range(3):
        grad[:, a] = sum(w * func(p + i * h * eye[a]) for i, w in _D1) / h
        hess[:, a, a] = sum(w * (f0 if i == 0 else func(p + i * h * eye[a])) for i, w in _D2) / h**2
        for b in range(a + 1, 3):
            hess[:, a, b] = hess[:, b, a] = sum(wi * wj * func(p + (i * eye[a] + j * eye[b]) * h)
                                                for i, wi in _D1 for j, wj in _D1) / (h * h)
    gnorm = np.linalg.norm(grad, axis=1)
    n = grad / gnorm[:, None]
    # Orthonormal tangent basis (t1, t2) at each point.
    ref = np.where(np.abs(n[:, :1]) < 0.9, eye[0], eye[1])
    t1 = np.cross(n, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    a11 = np.einsum("ni,nij,nj->n", t1, hess, t1) / gnorm
    a12 = np.einsum("ni,nij,nj->n", t1, hess, t2) / gnorm
    a22 = np.einsum("ni,nij,nj->n", t2, hess, t2) / gnorm
    mean = 0.5 * (a11 + a22)
    disc = np.sqrt((0.5 * (a11 - a22)) ** 2 + a12 * a12)
    return n, mean + disc, mean - disc
