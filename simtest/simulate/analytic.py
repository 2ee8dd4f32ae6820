"""Closed-form Phong images of planes and quadrics seen by a camera model (no renderer).

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
from simtest.geometry.cameras import CameraModel

__all__ = ["cylinder_bp", "phong_cylinder_image", "phong_plane_image", "phong_sphere_image", "plane_bp",
           "sphere_bp"]


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

    Notes
    -----
    *Light-offset geometry.* Phong's lobe (paper eq. 1) peaks where the mirror direction of the
    light points at the camera, i.e. where the normal bisects the unit directions to the camera and
    to the light: ``N = unit(unit(-X) + unit(L - X))``. On the plane ``n . X = -h`` the mirror
    image of the light is ``L' = L - 2 (n . L + h) n``; a ray from ``L'`` through X reflects at X
    into the ray from X to L, so the BP is where the segment from the camera centre to ``L'`` meets
    the plane: ``X = s L'`` with ``s = -h / (n . L')``. With ``L = 0`` this is the foot of the
    perpendicular ``-h n`` and the BP ray is the normal. With an offset the BP ray leaves the normal
    by about half the angle the offset subtends at the BP, ``~ |L_perp| / (2 d)`` rad for an offset
    ``L_perp`` across the ray at distance ``d``; the cone axis follows the BP ray. Since the image
    then depends on ``L / d``, a known offset makes the distance observable (paper eq. 2 is the
    isocurve for any light and viewer).
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
    K : array_like of shape (3, 3) or CameraModel
        Pinhole intrinsics, or any camera model (fisheye, omnidirectional: each pixel's ray is
        the model's; pixels without a ray are 0).
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
    N = _plane(normal, distance_mm)

    def intersect(d):
        denom = d @ N
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -distance_mm / denom
        return (denom < 0) & (lam > 0), lam, np.broadcast_to(N, d.shape)

    return _phong_image(K, shape, n, c, light_mm, supersample, intersect,
                        falloff_ref_mm=distance_mm if falloff else None)


# --- curved surfaces: quadrics ---------------------------------------------------------------------


def _phong_image(K, shape, n, c, light_mm, supersample, intersect, falloff_ref_mm=None):
    """Eq. 1 through each pixel, box-averaged over s x s sub-pixel rays.

    ``intersect(d)`` takes unit rays (H, W, 3) and returns (hit mask, ray length, unit normal at
    the hit); normals are turned to face the camera here. With ``falloff_ref_mm`` the intensity is
    multiplied by ``(falloff_ref_mm / |L - X|)^2``.
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
