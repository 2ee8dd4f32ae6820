"""The isophote cone fitted on viewing rays, for any camera model.

An isophote spans a cone of viewing rays ``r^T C' r = 0`` (C' = K^T C K for a pinhole, the
paper's step 3). With a wide-angle lens its pixels lie on no conic but its rays still lie on the
cone, so the contour points are mapped to unit rays by the camera model, projected centrally onto
one plane per highlight and fitted there by :func:`~simtest.reconstruct.fit.fit_ellipse`: exact
for exact rays, whatever the lens. The plane (:func:`fit_frame`) is:

- for a pinhole (with or without OpenCV distortion): its image plane in undistorted pixels,
  C' = K^T C K as in the paper;
- for any other model: the plane perpendicular to the BP ray, in virtual pixels of
  ``K_v = diag(f_v, f_v, 1)`` with f_v = ``det(J J^T)^(1/4)`` of the ray-to-pixel Jacobian J at
  the BP ray (residuals stay in about pixels); with R taking the BP ray to +z,
  ``C' = R^T K_v^T C K_v R``.

The estimators run in the fit frame and their normals are rotated back (:func:`to_camera`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.cameras import CameraModel, PinholeCamera
from simtest.reconstruct.failures import Failure
from simtest.reconstruct.fit import fit_stacked, point_sets

__all__ = ["ConeFit", "FitFrame", "fit_cones", "fit_frame", "fit_frames", "rotations_to_z", "to_camera", "to_fit_frame"]


@dataclass(frozen=True)
class FitFrame:
    """The plane a highlight's rays are fitted on.

    Attributes
    ----------
    camera : CameraModel
        The camera.
    R : ndarray of shape (3, 3)
        Rotation from the camera frame to the fit frame (``x_fit = R x_cam``); identity for a pinhole.
    K : ndarray of shape (3, 3)
        Intrinsics of the fit plane: the camera's K for a pinhole, ``diag(f_v, f_v, 1)`` otherwise.
    on_image_plane : bool
        True when the fit plane is the camera's (undistorted) image plane.
    """

    camera: CameraModel
    R: np.ndarray
    K: np.ndarray
    on_image_plane: bool


@dataclass(frozen=True)
class ConeFit:
    """A cone fitted on rays (truthy).

    Attributes
    ----------
    cone : ndarray of shape (3, 3)
        C' in the camera frame, ``r^T C' r = 0`` on the isophote's rays, symmetric, unit Frobenius
        norm (any sign).
    cone_fit_frame : ndarray of shape (3, 3)
        The same cone in the fit frame, ``R C' R^T`` (what the estimators use).
    conic : ndarray of shape (3, 3) or None
        The fitted point conic in undistorted image pixels on the image plane (pinhole); else None.
    ellipse : simtest.geometry.conics.Ellipse or None
        That conic's centre (u, v) px, semi-axes px and angle; None as ``conic``.
    residual_px : float
        RMS Sampson distance on the fit plane, px (image px for a pinhole, virtual px otherwise).
    n_points : int
        Points fitted.
    """

    cone: np.ndarray
    cone_fit_frame: np.ndarray
    conic: np.ndarray | None
    ellipse: object | None
    residual_px: float
    n_points: int

    def __bool__(self) -> bool:
        return True


def rotations_to_z(d: np.ndarray) -> np.ndarray:
    """Rotations R with ``R d = |d| e_z``, one per direction.

    Parameters
    ----------
    d : ndarray of shape (k, 3)
        Non-zero directions, camera frame.

    Returns
    -------
    ndarray of shape (k, 3, 3)
        Proper rotations (det +1), each from its own direction only; rows are the fit frame's
        axes in camera coordinates, the image x axis kept as close to the camera's x as possible
        (so plane pixels read like image pixels).
    """
    z = d / np.linalg.norm(d, axis=1, keepdims=True)
    ref = np.where(np.abs(z[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    x = ref - np.sum(ref * z, axis=1, keepdims=True) * z
    x = x / np.linalg.norm(x, axis=1, keepdims=True)
    y = np.stack([z[:, 1] * x[:, 2] - z[:, 2] * x[:, 1], z[:, 2] * x[:, 0] - z[:, 0] * x[:, 2],
                  z[:, 0] * x[:, 1] - z[:, 1] * x[:, 0]], axis=1)  # z x x
    return np.stack([x, y, z], axis=1)


#: The rotation of a pinhole's fit frame (the image plane), read-only: one array for every frame.
_IDENTITY = np.eye(3)
_IDENTITY.setflags(write=False)


def fit_frame(camera: CameraModel, bp_ray) -> FitFrame:
    """The fit plane of a highlight (module Notes).

    Parameters
    ----------
    camera : CameraModel
        The camera.
    bp_ray : array_like of shape (3,)
        Unit viewing ray of the brightest point, camera frame (z may be <= 0 for a wide lens).

    Returns
    -------
    FitFrame
    """
    return fit_frames(camera, np.asarray(bp_ray, dtype=np.float64).reshape(1, 3))[0]


def fit_frames(camera: CameraModel, bp_rays: np.ndarray) -> list[FitFrame]:
    """:func:`fit_frame` of several highlights of one camera at once.

    Parameters
    ----------
    camera : CameraModel
        The camera.
    bp_rays : ndarray of shape (k, 3)
        Unit viewing rays of the brightest points, camera frame.

    Returns
    -------
    list of FitFrame
        One per ray: the image plane for a pinhole; otherwise the plane normal to the ray with
        the focal length ``det(J J^T)^(1/4)`` of the model's ray-to-pixel Jacobian J there (1 where
        the model has none), in one call of the model for all rays.
    """
    d = np.asarray(bp_rays, dtype=np.float64).reshape(-1, 3)
    if isinstance(camera, PinholeCamera):
        return [FitFrame(camera, _IDENTITY, camera.K, True)] * len(d)
    if not len(d):
        return []
    R = rotations_to_z(d)
    J = camera.ray_to_pixel_jacobian(d)
    with np.errstate(invalid="ignore"):
        f = np.maximum(np.linalg.det(J @ np.swapaxes(J, 1, 2)), 0.0) ** 0.25
    f = np.where(np.isfinite(f) & (f > 0), f, 1.0)
    return [FitFrame(camera, R[i], np.diag([f[i], f[i], 1.0]), False) for i in range(len(d))]


def fit_cones(points_list, frames) -> list[ConeFit | Failure]:
    """Fit the isophote cone of each of several highlights' contours through their viewing rays.

    With plane pixels x = K (R r) / (R r)_z and the fitted conic C, ``C' = R^T K^T C K R``.

    Parameters
    ----------
    points_list : sequence of array_like of shape (N_i, 2)
        Contour points as found in the image (distorted pixels), px.
    frames : sequence of FitFrame
        Each contour's camera and fit plane (:func:`fit_frame`), as many as contours.

    Returns
    -------
    list of ConeFit or Failure
        One per contour, in order. Failures of :func:`~simtest.reconstruct.fit.fit_ellipse`;
        ``non_finite_points`` also when a point has no ray or lies more than 90 deg from the BP ray;
        ``pose_failed`` if the cone is zero or non-finite.

    Raises
    ------
    ValueError
        If a point set is not of shape (N, 2), or the two sequences differ in length.
    """
    pts_list = point_sets(points_list)
    frames = list(frames)
    if len(frames) != len(pts_list):
        raise ValueError(f"{len(pts_list)} contours but {len(frames)} fit frames")
    if not pts_list:
        return []
    counts = np.array([len(p) for p in pts_list], dtype=np.int64)
    pts = np.concatenate(pts_list, axis=0)
    # per distinct frame object: its camera where its points are mapped to rays, else None
    camera_of: dict = {}
    for f in frames:
        if id(f) not in camera_of:
            plain = isinstance(f.camera, PinholeCamera) and f.camera.dist_coeffs is None
            camera_of[id(f)] = None if plain else f.camera
    cams = [camera_of[id(f)] for f in frames]
    mapped = np.array([c is not None for c in cams], dtype=bool)
    if mapped.any():
        R = np.stack([f.R for f in frames])
        K = np.stack([f.K for f in frames])
        owner = np.repeat(np.arange(len(frames)), counts)
        cam_ids = np.array([id(c) for c in cams], dtype=np.int64)
        for cid in np.unique(cam_ids[mapped]).tolist():
            rows = np.repeat(mapped & (cam_ids == cid), counts)
            cam = cams[int(np.flatnonzero(mapped & (cam_ids == cid))[0])]
            pts[rows] = _to_planes(cam.pixel_to_ray(pts[rows]), R, K, owner[rows])
    fits = fit_stacked(pts, counts)
    out: list = list(fits)
    good = np.array([i for i, f in enumerate(fits) if f], dtype=np.intp)
    if not len(good):
        return out
    gframes = [frames[i] for i in good.tolist()]
    C = np.stack([fits[i].conic for i in good.tolist()])
    one_frame = len(camera_of) == 1
    if one_frame:
        # one frame object for all (a pinhole's image plane): its K once, broadcast (the same products)
        Kg = frames[0].K
        cf = Kg.T @ C @ Kg
    else:
        Kg = np.stack([f.K for f in gframes])
        cf = np.swapaxes(Kg, 1, 2) @ C @ Kg
    cf = 0.5 * (cf + np.swapaxes(cf, 1, 2))
    norm = np.sqrt(np.einsum("kij,kij->k", cf, cf))
    formed = np.isfinite(norm) & (norm > 0)
    c = cf / np.where(formed, norm, 1.0)[:, None, None]
    # the cone in the camera frame, R^T c R, where the fit plane is not the image plane
    on_image = np.full(len(gframes), bool(frames[0].on_image_plane)) if one_frame else \
        np.array([f.on_image_plane for f in gframes], dtype=bool)
    cone = c.copy()
    if not on_image.all():
        Rg = np.stack([f.R for f, img in zip(gframes, on_image.tolist()) if not img])
        rot = np.swapaxes(Rg, 1, 2) @ c[~on_image] @ Rg
        cone[~on_image] = 0.5 * (rot + np.swapaxes(rot, 1, 2))
    # (ConeFit's fields in order: cone, cone_fit_frame, conic, ellipse, residual_px, n_points)
    for j, i, is_formed, img in zip(range(len(good)), good.tolist(), formed.tolist(), on_image.tolist()):
        if not is_formed:
            out[i] = Failure("pose_failed", "C' = K^T C K is zero or not finite")
            continue
        fit = fits[i]
        out[i] = ConeFit(cone[j], c[j], fit.conic if img else None, fit.ellipse if img else None,
                         fit.residual_px, fit.n_points)
    return out


def _to_planes(rays: np.ndarray, R: np.ndarray, K: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Central projection of camera-frame rays (N, 3) onto their fit planes: ``K (R r) / (R r)_z`` (N, 2)
    with the g planes' R, K (g, 3, 3) and each ray's plane ``owner`` (N,); NaN at or behind a horizon.
    """
    Ro = R[owner]
    r = np.einsum("nij,nj->ni", Ro, rays)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(r[:, 2] > 0, r[:, 2], np.nan)
        x = r[:, 0] / z
        y = r[:, 1] / z
    Ko = K[owner]
    return np.stack([Ko[:, 0, 0] * x + Ko[:, 0, 1] * y + Ko[:, 0, 2], Ko[:, 1, 1] * y + Ko[:, 1, 2]], axis=1)


def to_camera(frame: FitFrame, v):
    """Rotate fit-frame vectors (..., 3) back to the camera frame (None stays None)."""
    if v is None or frame.on_image_plane:
        return v
    return np.asarray(v, dtype=np.float64) @ frame.R


def to_fit_frame(frame: FitFrame, v):
    """Rotate camera-frame vectors (..., 3) into the fit frame (None stays None)."""
    if v is None or frame.on_image_plane:
        return v
    return np.asarray(v, dtype=np.float64) @ frame.R.T
