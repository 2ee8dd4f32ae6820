"""Pinhole intrinsics K: validation, rays and projection.

OpenCV camera frame (x right, y down, z forward), pixel centres at integer coordinates, (u, v) =
(column, row), ``x = K X / Z``. A Mitsuba M x M film has ``cx = cy = M / 2 - 0.5`` here (Mitsuba puts
pixel centres at i + 0.5). Other camera models: :mod:`simtest.geometry.cameras`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["IntrinsicsError", "bp_ray_normal", "look_at", "pixel_to_ray", "project_points", "validate_intrinsics"]


class IntrinsicsError(ValueError):
    """An intrinsics matrix or file is unusable; the message names the file and key."""


def validate_intrinsics(K, where: str = "K") -> np.ndarray:
    """Check an intrinsics matrix and return it as float64.

    Parameters
    ----------
    K : array_like of shape (3, 3)
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0, in pixels.
    where : str
        What to call K in error messages (e.g. a file name and key).

    Returns
    -------
    ndarray of shape (3, 3), float64

    Raises
    ------
    IntrinsicsError
        Wrong shape, non-finite entries, a last row other than (0, 0, 1), a non-positive focal
        length, or a singular matrix.
    """
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise IntrinsicsError(f"{where}: not a numeric 3x3 matrix ({exc})") from None
    if K.shape != (3, 3):
        raise IntrinsicsError(f"{where}: must be 3x3, got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise IntrinsicsError(f"{where}: has non-finite entries {K.tolist()}")
    # np.allclose(K[2], (0, 0, 1)) written out (cheaper)
    k20, k21, k22 = (float(v) for v in K[2])
    if not (abs(k20) <= 1e-8 and abs(k21) <= 1e-8 and abs(k22 - 1.0) <= 1e-8 + 1e-5) or K[1, 0] != 0:
        raise IntrinsicsError(f"{where}: must be upper triangular with last row (0, 0, 1), got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise IntrinsicsError(f"{where}: focal lengths must be > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
    if abs(np.linalg.det(K)) < 1e-12:
        raise IntrinsicsError(f"{where}: is singular")
    return K


def pixel_to_ray(uv, K) -> np.ndarray:
    """Unit viewing rays through pixels, in the camera frame.

    Parameters
    ----------
    uv : array_like of shape (..., 2)
        Pixel coordinates (u, v), pixel centres at integers.
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (..., 3)
        Unit directions with z > 0.
    """
    K = validate_intrinsics(K)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"uv must have shape (..., 2), got {uv.shape}")
    x = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
    d = x @ np.linalg.inv(K).T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def project_points(X_cam, K) -> np.ndarray:
    """Project camera-frame points to pixels.

    Parameters
    ----------
    X_cam : array_like of shape (..., 3)
        Points in the camera frame, z > 0 (mm or any unit).
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (..., 2)
        Pixel coordinates (u, v).
    """
    K = validate_intrinsics(K)
    X = np.asarray(X_cam, dtype=np.float64)
    if X.shape[-1:] != (3,):
        raise ValueError(f"X_cam must have shape (..., 3), got {X.shape}")
    x = X @ K.T
    return x[..., :2] / x[..., 2:3]


def bp_ray_normal(bp_uv, K) -> np.ndarray:
    """The ``bp_ray`` estimator: minus the unit viewing ray through the brightest point.

    With an exactly co-located light the BP is where the surface normal is parallel to the viewing
    ray, whatever the curvature (Notes of :func:`simtest.geometry.curvature.curvature_ratio`), so this is the normal at the BP. It is biased when
    the BP is saturated or the light is offset.

    Parameters
    ----------
    bp_uv : array_like of shape (2,)
        Brightest point (u, v) in pixels.
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (3,)
        Unit normal facing the camera, camera frame.
    """
    return -pixel_to_ray(np.asarray(bp_uv, dtype=np.float64).reshape(2), K)


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """Camera-to-world pose of an OpenCV camera at ``eye`` looking at ``target``.

    Parameters
    ----------
    eye, target : array_like of shape (3,)
        World positions, mm.
    up : array_like of shape (3,)
        World direction that should appear as image "up" (-y in the OpenCV frame). The default
        (0, -1, 0) matches Mitsuba's ``look_at(origin, target, up=(0, -1, 0))`` used by simtest.

    Returns
    -------
    ndarray of shape (4, 4)
        ``T`` with ``X_world = T[:3, :3] @ X_cam + T[:3, 3]``; columns are the camera x (right),
        y (down) and z (forward) axes in world coordinates.

    Raises
    ------
    ValueError
        If eye equals target or ``up`` is parallel to the viewing direction.
    """
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    z = target - eye
    nz = np.linalg.norm(z)
    if nz == 0:
        raise ValueError("look_at: eye equals target")
    z /= nz
    down = -np.asarray(up, dtype=np.float64)
    x = np.cross(down, z)
    nx = np.linalg.norm(x)
    if nx < 1e-12:
        raise ValueError("look_at: up is parallel to the viewing direction")
    x /= nx
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T
