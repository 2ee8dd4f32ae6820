"""Closed-form Phong images of planes seen by a camera model (no renderer).

OpenCV camera frame, camera at the origin, mm. The plane is ``{X : normal . X = -distance_mm}``,
``normal`` facing the camera; the light is a point at ``light_mm`` (the origin: co-located). The
intensity is paper eq. 1, ``c max(0, cos beta)^n``, optionally times the 1/d^2 falloff relative to
the plane's distance.
"""

from __future__ import annotations

import numpy as np

from simtest.geometry.camera import validate_intrinsics
from simtest.geometry.cameras import CameraModel

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

    Notes
    -----
    Phong's lobe peaks where the normal equals ``unit(unit(-X) + unit(L - X))``. With the light's
    mirror image ``L' = L - 2 (n . L + h) n`` in the plane ``n . X = -h``, the BP is where the segment
    from the camera to ``L'`` meets the plane, ``X = s L'``, ``s = -h / (n . L')``; for ``L = 0`` the
    foot ``-h n``. An offset turns the BP ray off the normal by about ``|L_perp| / (2 d)`` rad.
    """
    n = _plane(normal, distance_mm)
    L = np.asarray(light_mm, dtype=np.float64).reshape(3)
    h = n @ L + distance_mm  # signed height of the light above the plane
    if not h > 0:
        raise ValueError(f"the light {L.tolist()} is not on the camera's side of the plane")
    L_mirror = L - 2.0 * h * n
    s = -distance_mm / (n @ L_mirror)
    return s * L_mirror


def phong_plane_image(K, shape: tuple[int, int], normal, distance_mm: float, n: float, c: float = 1.0,
                      light_mm=(0.0, 0.0, 0.0), falloff: bool = False, supersample: int = 1) -> np.ndarray:
    """Closed-form Phong image of a plane (paper eq. 1), pixel centres at integer coordinates.

    Parameters
    ----------
    K : array_like of shape (3, 3) or CameraModel
        Pinhole intrinsics, or any camera model (pixels without a ray are 0).
    shape : (H, W)
        Image size in pixels.
    normal : array_like of shape (3,)
        Plane normal facing the camera, camera frame.
    distance_mm : float
        Camera-to-plane distance, mm.
    n, c : float
        Phong roughness (> 0) and peak intensity.
    light_mm : array_like of shape (3,)
        Point light position, camera frame (origin: co-located).
    falloff : bool
        Multiply by ``(distance_mm / |L - X|)^2``.
    supersample : int
        s x s samples per pixel, box-averaged.

    Returns
    -------
    ndarray of shape (H, W), float64
        Intensity; 0 where the pixel ray misses the plane.

    Raises
    ------
    ValueError
        Invalid K, shape, normal, distance, n, c or supersample.
    """
    N = _plane(normal, distance_mm)

    def intersect(d):
        denom = d @ N
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -distance_mm / denom
        return (denom < 0) & (lam > 0), lam, np.broadcast_to(N, d.shape)

    return _phong_image(K, shape, n, c, light_mm, supersample, intersect,
                        falloff_ref_mm=distance_mm if falloff else None)


def _phong_image(K, shape, n, c, light_mm, supersample, intersect, falloff_ref_mm=None):
    """Eq. 1 through each pixel, box-averaged over s x s sub-pixel rays.

    ``intersect(d)`` maps unit rays (H, W, 3) to (hit mask, ray length, unit normal); with
    ``falloff_ref_mm`` the intensity is multiplied by ``(falloff_ref_mm / |L - X|)^2``.
    """
    camera = K if isinstance(K, CameraModel) else None
    K = None if camera is not None else validate_intrinsics(K)
    H, W = (int(x) for x in shape)
    if H < 1 or W < 1:
        raise ValueError(f"shape must be positive, got {shape}")
    if int(supersample) < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    if not n > 0 or not c > 0:
        raise ValueError(f"n and c must be > 0, got n={n}, c={c}")
    L = np.asarray(light_mm, dtype=np.float64).reshape(3)
    s = int(supersample)
    offs = (np.arange(s) + 0.5) / s - 0.5
    Kinv = None if K is None else np.linalg.inv(K)
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    acc = np.zeros((H, W))
    for dv in offs:
        for du in offs:
            if camera is None:
                d = np.stack([uu + du, vv + dv, np.ones_like(uu)], axis=-1) @ Kinv.T
                d /= np.linalg.norm(d, axis=-1, keepdims=True)
            else:
                uv = np.stack([(uu + du).ravel(), (vv + dv).ravel()], axis=1)
                d = np.nan_to_num(camera.pixel_to_ray(uv), nan=0.0).reshape(H, W, 3)
            hit, lam, N = intersect(d)
            hit = hit & np.isfinite(lam)
            X = d * np.where(hit, lam, 0.0)[..., None]
            with np.errstate(invalid="ignore", divide="ignore"):
                N = np.where((np.sum(N * d, axis=-1) > 0)[..., None], -N, N)
                to_light = L - X
                dl = np.linalg.norm(to_light, axis=-1, keepdims=True)
                to_light = to_light / dl
                refl = 2.0 * np.sum(to_light * N, axis=-1)[..., None] * N - to_light
                val = c * np.maximum(np.sum(refl * -d, axis=-1), 0.0) ** n
                if falloff_ref_mm is not None:
                    val = val * (falloff_ref_mm / dl[..., 0]) ** 2
            acc += np.where(hit, np.nan_to_num(val), 0.0)
    return acc / (s * s)
