"""Phong's specular model on a plane and its isocurves (Makki and Bartoli, section 2).

Scene-plane frame: the plane is z = 0, points ``P = (x, y, 0)``; viewer ``V`` and light ``L`` are
3D points (mm in simtest), ``R = (L_X, L_Y, -L_Z)`` the light's mirror image; endoscopic: ``L = V``.
Roughness ``n > 0``, scale ``c > 0``, isovalue ``t`` in (0, c], ``tau = (t / c)^(1/n)``,
``kappa = 1 - tau^2``.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       eqs. (1)-(3), Propositions 1 and 2.
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] A. Bartoli et al., "A highlight model for specular isophotes", 2019 (the general quartic).
"""

from __future__ import annotations

import numpy as np

__all__ = ["endoscopic_isocurve", "general_isocurve", "isocurve_radii", "isophote_radius", "kappa_from_isovalue",
           "phong_intensity", "tau_from_isovalue"]


def _points(P) -> np.ndarray:
    P = np.asarray(P, dtype=np.float64)
    if P.shape[-1] == 2:
        P = np.concatenate([P, np.zeros(P.shape[:-1] + (1,))], axis=-1)
    if P.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 2) or (..., 3), got {P.shape}")
    return P


def _mirror(L) -> np.ndarray:
    L = np.asarray(L, dtype=np.float64).reshape(3)
    return np.array([L[0], L[1], -L[2]])


def phong_intensity(P, V, L, n: float, c: float = 1.0, origin=None) -> np.ndarray:
    """Phong specular intensity on the plane z = 0 (paper eq. 1).

    ``I(p) = c max(0, cos beta)^n`` with beta the angle between the direction to the viewer
    ``mu(V - P)`` and the mirror direction of the light ``-mu(R - P)``.

    Parameters
    ----------
    P : array_like of shape (..., 2) or (..., 3)
        Points on the plane (z = 0 is assumed or must be given), scene-plane frame, mm.
    V, L : array_like of shape (3,)
        Viewer and light positions, mm, on the same side of the plane (z > 0).
    n, c : float
        Phong roughness exponent and scale factor, > 0.
    origin : array_like of shape (2,), optional
        When given, ``P`` (..., 2) are offsets from this point of the plane: the intensity at
        ``P + origin``.

    Returns
    -------
    ndarray of shape (...)
        Intensity in [0, c] (a numpy scalar for one point).

    Raises
    ------
    ValueError
        If n or c is not positive, or ``origin`` is given with points that are not (..., 2).
    """
    if not n > 0 or not c > 0:
        raise ValueError(f"roughness n and scale c must be > 0, got n={n}, c={c}")
    P = np.asarray(P, dtype=np.float64)
    V = np.asarray(V, dtype=np.float64).reshape(3)
    R = _mirror(L)
    if origin is not None:
        if P.shape[-1] != 2:
            raise ValueError(f"offsets from an origin must have shape (..., 2), got {P.shape}")
        P = P + np.asarray(origin, dtype=np.float64).reshape(2)
    elif P.shape[-1] != 2:
        P = _points(P)
    cos_b = np.asarray(_cos_beta(P, V, R), dtype=np.float64)
    # c max(0, cos beta)^n in place (the same bits as the expression)
    out = np.maximum(cos_b, 0.0, out=cos_b)
    out **= n
    out *= c
    return out[()] if out.ndim == 0 else out


def _cos_beta(P: np.ndarray, V: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``cos beta = (V - P) . (P - R) / (|V - P| |P - R|)`` of :func:`phong_intensity`, per coordinate.

    The same bits as ``np.sum`` and ``np.linalg.norm`` over the last axis, without (..., 3) arrays.
    """
    px, py = P[..., 0], P[..., 1]
    pz = P[..., 2] if P.shape[-1] == 3 else 0.0
    if not np.any(pz):
        pz = 0.0  # on the plane z = 0 (the usual case): the z terms are the same for every point
    vx, vy, vz = V[0] - px, V[1] - py, V[2] - pz  # to the viewer
    rx, ry, rz = px - R[0], py - R[1], pz - R[2]  # = -(R - P)
    dot = vx * rx + vy * ry + vz * rz
    norms = np.sqrt(vx * vx + vy * vy + vz * vz) * np.sqrt(rx * rx + ry * ry + rz * rz)
    return dot / norms


def tau_from_isovalue(t, n: float, c: float = 1.0):
    """``tau = (t / c)^(1/n)``, the cosine of beta on the isophote of isovalue t (paper sec. 2.1).

    Raises
    ------
    ValueError
        If t is not in (0, c] or n, c are not positive.
    """
    t = np.asarray(t, dtype=np.float64)
    if not n > 0 or not c > 0:
        raise ValueError(f"roughness n and scale c must be > 0, got n={n}, c={c}")
    if np.any(~((t > 0) & (t <= c))):
        raise ValueError(f"isovalue t must be in (0, c] = (0, {c}], got {t}")
    return (t / c) ** (1.0 / n)


def kappa_from_isovalue(t, n: float, c: float = 1.0):
    """``kappa = 1 - tau^2`` (paper sec. 2.2); in [0, 1) for t in (0, c]."""
    return 1.0 - tau_from_isovalue(t, n, c) ** 2


def general_isocurve(P, V, L, tau: float) -> np.ndarray:
    """The general specular isocurve Q(p) (paper eq. 2), a quartic in (x, y).

    ``Q(p) = ((R - P)^T (V - P))^2 - tau^2 ||R - P||^2 ||V - P||^2``; the isophote I = t is a subset
    of Q = 0 (both cos beta = +tau and -tau satisfy it).

    Parameters
    ----------
    P : array_like of shape (..., 2) or (..., 3)
        Points on the plane z = 0.
    V, L : array_like of shape (3,)
        Viewer and light positions.
    tau : float
        Cosine level, in (0, 1].

    Returns
    -------
    ndarray of shape (...)
    """
    P = _points(P)
    V = np.asarray(V, dtype=np.float64).reshape(3)
    R = _mirror(L)
    a, b = R - P, V - P
    return np.sum(a * b, axis=-1) ** 2 - tau**2 * np.sum(a * a, axis=-1) * np.sum(b * b, axis=-1)


def endoscopic_isocurve(P, V, kappa: float) -> np.ndarray:
    """The endoscopic specular isocurve E(p) (paper eq. 3), Q with L = V.

    ``E(p) = kappa s^2 + 2 V_Z^2 (kappa - 2) s + kappa V_Z^4`` with
    ``s = (x - V_X)^2 + (y - V_Y)^2``. It factorises as ``E = kappa q+ q-`` with
    ``q+- = s - r+-^2`` (Prop. 1; the paper writes E = q+ q-, up to the factor kappa).

    Parameters
    ----------
    P : array_like of shape (..., 2) or (..., 3)
        Points on the plane z = 0.
    V : array_like of shape (3,)
        Viewer (and light) position.
    kappa : float
        ``1 - tau^2``.

    Returns
    -------
    ndarray of shape (...)
    """
    P = _points(P)
    V = np.asarray(V, dtype=np.float64).reshape(3)
    s = (P[..., 0] - V[0]) ** 2 + (P[..., 1] - V[1]) ** 2
    return kappa * s**2 + 2.0 * V[2] ** 2 * (kappa - 2.0) * s + kappa * V[2] ** 4


def isocurve_radii(kappa, V_Z):
    """Radii (r+, r-) of the two concentric circles of E(p) = 0 (paper Prop. 1).

    ``r+- = |V_Z| sqrt(k +- sqrt(k^2 - 1))`` with ``k = (2 - kappa) / kappa``; for kappa in (0, 1),
    ``r+ > |V_Z| > r- > 0`` and ``r+ r- = V_Z^2``.

    Parameters
    ----------
    kappa : float or ndarray
        In (0, 1].
    V_Z : float
        Distance from the viewer to the plane (mm).

    Returns
    -------
    tuple of float or ndarray
        (r_plus, r_minus), in the unit of V_Z.

    Raises
    ------
    ValueError
        If kappa is outside (0, 1].
    """
    kappa = np.asarray(kappa, dtype=np.float64)
    if np.any(~((kappa > 0) & (kappa <= 1))):
        raise ValueError(f"kappa must be in (0, 1], got {kappa}")
    k = (2.0 - kappa) / kappa
    root = np.sqrt(k * k - 1.0)
    # k - root = 1 / (k + root): the stable form of the small root.
    return abs(V_Z) * np.sqrt(k + root), abs(V_Z) / np.sqrt(k + root)


def isophote_radius(t, n: float, V_Z, c: float = 1.0):
    """Radius of the endoscopic specular isophote of isovalue t: r- of Prop. 1 (paper Prop. 2).

    Parameters
    ----------
    t : float or ndarray
        Isovalue in (0, c).
    n : float
        Phong roughness.
    V_Z : float
        Camera-to-plane distance, mm.
    c : float
        Scale (peak intensity).

    Returns
    -------
    float or ndarray
        Radius in mm of the isophote circle centred on the foot of the perpendicular from the camera.
    """
    return isocurve_radii(kappa_from_isovalue(t, n, c), V_Z)[1]
