"""Closed-form Phong images of a plane seen by a pinhole camera (no renderer).

Frame: OpenCV camera frame, camera centre at the origin, lengths in mm. The plane is
``{X : normal . X = -distance_mm}`` with ``normal`` facing the camera, so the foot of the
perpendicular from the camera is ``-distance_mm * normal``. The light is a point at ``light_mm``
(the origin for the endoscopic, co-located setup).

The intensity at the surface point X seen through a pixel is paper eq. 1,
``c max(0, cos beta)^n``, with beta between the direction to the camera and the mirror direction
of the light about the normal; optionally divided by the squared distance to the light relative to
the distance of the plane (``falloff=True``, the 1/d^2 of a real point source).
"""

from __future__ import annotations

import numpy as np

from simtest.geometry.camera import validate_intrinsics

__all__ = ["phong_plane_image", "plane_bp"]


def _plane(normal, distance_mm: float) -> np.ndarray:
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    nn = np.linalg.norm(n)
    if not nn > 0:
        raise ValueError(f"plane normal must be non-zero, got {normal}")
    if not distance_mm > 0:
        raise ValueError(f"distance_mm must be > 0, got {distance_mm}")
    return n / nn


def plane_bp(normal, distance_mm: float, light_mm=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Brightest point of a Phong plane: where the normal bisects the directions to camera and light.

    It is where the ray from the camera toward the mirror image of the light crosses the plane; for
    a co-located light, the foot of the perpendicular ``-distance_mm * normal``.

    Parameters
    ----------
    normal : array_like of shape (3,)
        Plane normal facing the camera (camera frame).
    distance_mm : float
        Distance from the camera centre to the plane, > 0.
    light_mm : array_like of shape (3,)
        Light position, camera frame, on the camera's side of the plane.

    Returns
    -------
    ndarray of shape (3,)
        The BP in the camera frame, mm.

    Raises
    ------
    ValueError
        If the light is not on the camera's side of the plane.
    """
    n = _plane(normal, distance_mm)
    L = np.asarray(light_mm, dtype=np.float64).reshape(3)
    h = n @ L + distance_mm  # signed height of the light above the plane
    if not h > 0:
        raise ValueError(f"the light {L.tolist()} is not on the camera's side of the plane")
    L_mirror = L - 2.0 * h * n
    s = -distance_mm / (n @ L_mirror)
    return s * L_mirror


def phong_plane_image(
    K,
    shape: tuple[int, int],
    normal,
    distance_mm: float,
    n: float,
    c: float = 1.0,
    light_mm=(0.0, 0.0, 0.0),
    falloff: bool = False,
    supersample: int = 1,
) -> np.ndarray:
    """Closed-form Phong image of a plane (paper eq. 1), pixel centres at integer coordinates.

    Parameters
    ----------
    K : array_like of shape (3, 3)
        Intrinsics.
    shape : (H, W)
        Image size in pixels.
    normal : array_like of shape (3,)
        Plane normal facing the camera, camera frame.
    distance_mm : float
        Camera-to-plane distance, mm.
    n : float
        Phong roughness, > 0.
    c : float
        Peak intensity.
    light_mm : array_like of shape (3,)
        Point light position, camera frame (origin: co-located).
    falloff : bool
        Multiply by ``(distance_mm / |L - X|)^2`` (1/d^2 of a point source, 1 at the foot point for a
        co-located light).
    supersample : int
        s x s samples per pixel, box-averaged (what a renderer with a box filter integrates).

    Returns
    -------
    ndarray of shape (H, W), float64
        Intensity; 0 where the pixel ray misses the plane.

    Raises
    ------
    ValueError
        Invalid K, shape, normal, distance, n, c or supersample.
    """
    K = validate_intrinsics(K)
    H, W = (int(x) for x in shape)
    if H < 1 or W < 1:
        raise ValueError(f"shape must be positive, got {shape}")
    if int(supersample) < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    if not n > 0 or not c > 0:
        raise ValueError(f"n and c must be > 0, got n={n}, c={c}")
    N = _plane(normal, distance_mm)
    L = np.asarray(light_mm, dtype=np.float64).reshape(3)
    s = int(supersample)
    offs = (np.arange(s) + 0.5) / s - 0.5
    Kinv = np.linalg.inv(K)
    acc = np.zeros((H, W))
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    for dv in offs:
        for du in offs:
            x = np.stack([uu + du, vv + dv, np.ones_like(uu)], axis=-1)
            d = x @ Kinv.T
            denom = d @ N
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = -distance_mm / denom
            hit = (denom < 0) & (lam > 0)
            X = d * np.where(hit, lam, 0.0)[..., None]
            to_cam = -X
            to_light = L - X
            with np.errstate(invalid="ignore", divide="ignore"):
                to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
                dl = np.linalg.norm(to_light, axis=-1, keepdims=True)
                to_light = to_light / dl
                refl = 2.0 * (to_light @ N)[..., None] * N - to_light
                cos_b = np.sum(refl * to_cam, axis=-1)
                val = c * np.maximum(cos_b, 0.0) ** n
                if falloff:
                    val = val * (distance_mm / dl[..., 0]) ** 2
            acc += np.where(hit, np.nan_to_num(val), 0.0)
    return acc / (s * s)
