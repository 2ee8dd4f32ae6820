"""Exact images of a Phong plane lit by a light rig off the camera centre (no renderer, no noise).

OpenCV camera frame, mm; the plane is ``{X : normal . X = -distance_mm}``, ``normal`` facing the
camera. Each light j of the rig (:class:`simtest.geometry.lights.Light`) adds its own lobe (paper
eqs. 1 and 2, viewer at the camera centre):

``I(X) = c sum_j w_j cos(beta_j(X))^n [ (distance_mm / |L_j - X|)^2 ] [ cos(theta_j)^m_j ]``

with ``theta_j`` the angle between +z and ``X - L_j``. Evaluated with
:func:`simtest.specular.phong.phong_intensity` in the scene-plane frame, independently of
:mod:`simtest.reconstruct.lightaware`, so its tests compare two derivations.
"""

from __future__ import annotations

import numpy as np

from simtest.geometry.angles import unit
from simtest.geometry.camera import validate_intrinsics
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.simulate.analytic import plane_bp
from simtest.specular.phong import phong_intensity

__all__ = ["rig_plane_image", "specular_point"]


def specular_point(normal, distance_mm: float, light_mm) -> tuple[np.ndarray, float]:
    """The specular point of a plane for one light, and its depth along its ray.

    Where the normal bisects the directions to the camera and to the light: the segment from the
    camera centre to the mirror image ``L' = L - 2 (n.L + h) n`` meets the plane there
    (:func:`simtest.simulate.analytic.plane_bp`).

    Parameters
    ----------
    normal : array_like of shape (3,)
        Plane normal facing the camera, camera frame.
    distance_mm : float
        Camera-to-plane distance h, > 0.
    light_mm : array_like of shape (3,)
        Light position, camera frame, on the camera's side of the plane.

    Returns
    -------
    point_mm : ndarray of shape (3,)
        The specular point, camera frame, mm.
    depth_mm : float
        Its distance from the camera centre (the depth along its viewing ray, as Mitsuba's depth).

    Raises
    ------
    ValueError
        If the light is not on the camera's side of the plane.
    """
    X = plane_bp(normal, distance_mm, light_mm)
    return X, float(np.linalg.norm(X))


def rig_plane_image(K, shape: tuple[int, int], normal, distance_mm: float, rig: LightRig,
                    n: float, c: float = 1.0, supersample: int = 1) -> np.ndarray:
    """Exact float image of a Phong plane lit by a rig, through a pinhole (module docstring).

    Parameters
    ----------
    K : array_like of shape (3, 3)
        Intrinsics, pixel centres at integer coordinates.
    shape : (H, W)
        Image size, px.
    normal : array_like of shape (3,)
        Plane normal facing the camera (camera frame).
    distance_mm : float
        Camera-to-plane distance, mm, > 0.
    rig : LightRig
        The lights (camera frame, mm), each on the camera's side of the plane.
    n : float
        Phong roughness, > 0.
    c : float
        Scale, > 0.
    supersample : int
        s x s point samples per pixel, box-averaged (1: the value at the pixel centre).

    Returns
    -------
    ndarray of shape (H, W), float64
        Intensity; 0 where the pixel ray misses the plane.

    Raises
    ------
    ValueError
        Invalid K, shape, normal, distance, n, c, supersample, or a light behind the plane.
    """
    K = validate_intrinsics(K)
    N = unit(np.asarray(normal, dtype=np.float64).reshape(3))
    h = float(distance_mm)
    if not h > 0:
        raise ValueError(f"distance_mm must be > 0, got {distance_mm}")
    H, W = (int(x) for x in shape)
    s = int(supersample)
    if H < 1 or W < 1 or s < 1:
        raise ValueError(f"shape and supersample must be positive, got {shape}, {supersample}")
    for j, light in enumerate(rig.lights):
        if not N @ np.asarray(light.position_mm) + h > 0:
            raise ValueError(f"rig.lights[{j}] at {light.position_mm} is not on the camera's side of the plane")
    # scene-plane frame: origin at the foot of the perpendicular, axes (e1, e2, N)
    e1, e2 = plane_basis(N)
    R = np.stack([e1, e2, N])  # rows: camera frame -> plane frame
    foot = -h * N
    V = R @ (np.zeros(3) - foot)
    Kinv = np.linalg.inv(K)
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    offs = (np.arange(s) + 0.5) / s - 0.5
    acc = np.zeros((H, W))
    for dv in offs:
        for du in offs:
            d = np.stack([uu + du, vv + dv, np.ones_like(uu)], axis=-1) @ Kinv.T
            denom = d @ N
            hit = denom < 0
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = np.where(hit, -h / denom, 0.0)
            X = d * lam[..., None]
            P = (X - foot) @ R.T
            P[..., 2] = 0.0
            img = np.zeros((H, W))
            for light in rig.lights:
                Lc = np.asarray(light.position_mm, dtype=np.float64)
                val = phong_intensity(P, V, R @ (Lc - foot), n, c) * light.intensity
                r = np.linalg.norm(X - Lc, axis=-1)
                if light.falloff == "inverse_square":
                    val = val * (h / r) ** 2
                if light.profile_exponent > 0:
                    val = val * np.maximum((X[..., 2] - Lc[2]) / r, 0.0) ** light.profile_exponent
                img += val
            acc += np.where(hit, img, 0.0)
    return acc / (s * s)
