"""Frame preparation: the image as the pipeline sees it (:class:`_Frame`), its rays and luma, and its
smoothing chosen after detection for its number of highlights (:func:`_prepared`)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from simtest.constants import gaussian_radius_px
from simtest.geometry.cameras import CameraModel, PinholeCamera
from simtest.reconstruct._pixels import Roi, image_size_wh
from simtest.reconstruct.detect import (colour_luma32, luma_cv2, default_full_scale, frame_ceiling, image_noise_sigma,
                                        luma, smooth_sigma_for_noise, validate_image)
from simtest.reconstruct.detect_pixels import _is_gray
from simtest.reconstruct.failures import OK
from simtest.reconstruct.settings import ReconSettings

#: A whole-frame call with at least this many accepted highlights computes the luma of the frame once
#: and slices each ROI's from it (the same values); for fewer the ROIs are cheaper.
LUMA_FRAME_MIN_HIGHLIGHTS = 32


def validate_dist_coeffs(dist_coeffs) -> np.ndarray | None:
    """Check OpenCV distortion coefficients.

    Parameters
    ----------
    dist_coeffs : array_like or None
        ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]])`` in OpenCV order.

    Returns
    -------
    ndarray of shape (4,), (5,), (8,), (12,) or (14,), or None
        The coefficients as float64; None if ``dist_coeffs`` is None or all zero (no distortion).

    Raises
    ------
    ValueError
        If the count is not 4, 5, 8, 12 or 14 or a value is not finite.
    """
    if dist_coeffs is None:
        return None
    d = np.asarray(dist_coeffs, dtype=np.float64).ravel()
    if d.size not in (4, 5, 8, 12, 14) or not np.isfinite(d).all():
        raise ValueError(f"dist_coeffs: need 4, 5, 8, 12 or 14 finite values (OpenCV order), got {d.tolist()}")
    return d if np.any(d) else None


@dataclass(frozen=True)
class _Frame:
    """One image as the pipeline sees it, checked once: the image, its camera and the settings
    (``full_scale`` and ``saturation_level`` resolved for its dtype).
    """

    img: np.ndarray
    camera: CameraModel
    settings: ReconSettings
    full_scale: float
    saturation_level: float | None
    smooth_sigma_px: float
    luma_frame: np.ndarray | None = None
    #: The whole frame's smoothed luma as detection computed it (float32, read-only).
    smoothed32: np.ndarray | None = None
    #: The luma's noise standard deviation (image units) measured to choose the smoothing; None if fixed.
    noise: float | None = None
    #: A colour 8- or 16-bit RGB frame's float32 luma (H, W), read-only, where ``reconstruct`` computed it.
    luma32: np.ndarray | None = None
    #: Whether the image's R, G and B are equal (:func:`_is_gray`), where it was asked.
    grey: bool | None = None
    #: The frame's float32 luma (H, W) each ROI of a frame with few highlights is smoothed from alone.
    roi_luma: np.ndarray | None = None
    #: An unsmoothed frame's float32 luma (H, W), read-only, the contour walks read their ROIs from.
    luma_frame32: np.ndarray | None = None
    #: The luma that ``isophotes._first_rings`` read many ROIs' rings from (a grown ROI's too).
    ring_luma: np.ndarray | None = None
    #: The frame's tone curve that the colour checks undo; None: a display-encoded (sRGB) frame.
    response: object | None = None
    #: Side of the background square of detection and the checks, px; None: the frame's default.
    background_px: int | None = None

    @classmethod
    def make(cls, image, K, dist_coeffs, settings: ReconSettings, noise_roi: Roi | None = None) -> _Frame:
        img = validate_image(image)
        camera = as_camera(K, dist_coeffs)
        if camera.image_size is not None and tuple(camera.image_size) != image_size_wh(img.shape):
            (W, H), (w, h) = camera.image_size, image_size_wh(img.shape)
            raise ValueError(f"camera: image_size is {W} x {H} px but the image is {w} x {h} px")
        fs = default_full_scale(img) if settings.full_scale is None else settings.full_scale
        sat = settings.saturation_level
        if sat is None and img.dtype.kind == "u":
            sat = frame_ceiling(img)
        sigma, noise = settings.smooth_sigma_px, None
        if sigma is None:  # chosen from the noise of the region looked at
            region = img if noise_roi is None else img[noise_roi.slices]
            noise = image_noise_sigma(region)
            sigma = smooth_sigma_for_noise(noise, fs)
        return cls(img, camera, settings, fs, sat, float(sigma), noise=noise)

    def bp_ray(self, bp_uv: np.ndarray) -> np.ndarray:
        """BP-ray normal of a pixel (3,), NaN when the pixel has no ray in the camera model."""
        return _bp_ray(bp_uv, self.camera)

    def bp_rays(self, bp_uv: np.ndarray) -> np.ndarray:
        """BP-ray normals of pixels (k, 2): (k, 3), the same bits as one by one."""
        return _bp_rays(np.asarray(bp_uv, dtype=np.float64).reshape(-1, 2), self.camera)

    def for_many_highlights(self) -> _Frame:
        """This frame with the whole image's luma computed once (read-only): an ROI's luma is a slice of it."""
        full = self.luma_frame
        if full is None and self.img.ndim == 3:
            full = luma(self.img)
            full.setflags(write=False)
        return replace(self, luma_frame=full)

    def with_detection_smoothing(self, smoothed: np.ndarray) -> _Frame:
        """This frame with its ROIs' values sliced from detection's smoothed luma of the whole image instead
        of each ROI smoothed alone (within the kernel's radius of a side the frame's true neighbours
        replace reflected ones; :mod:`simtest.reconstruct.compare` holds the results).
        """
        return replace(self, smoothed32=smoothed)

    @property
    def kernel(self) -> np.ndarray:
        """OpenCV's Gaussian kernel of ``_smooth`` at this frame's sigma, float64 (2 R + 1,)."""
        return _gaussian_kernel(self.smooth_sigma_px)

    def luma(self, roi: Roi) -> np.ndarray:
        """Luma of the image in ``roi`` (h, w), float64: sliced from the frame's luma when computed (the same bits)."""
        if self.luma_frame is not None:
            return self.luma_frame[roi.slices]
        return luma(self.img[roi.slices])


def as_camera(K, dist_coeffs=None) -> CameraModel:
    """The camera model of a ``reconstruct`` call: a model as given, or a pinhole from K.

    Parameters
    ----------
    K : CameraModel or array_like of shape (3, 3)
        A camera model, or pinhole intrinsics.
    dist_coeffs : array_like or None
        OpenCV distortion of a pinhole K; must be None with a camera model (which holds its own).

    Returns
    -------
    CameraModel

    Raises
    ------
    ValueError
        Invalid K or coefficients, or coefficients beside a camera model.
    """
    if isinstance(K, CameraModel):
        if dist_coeffs is not None:
            raise ValueError("dist_coeffs: a camera model holds its own distortion; give one or the other")
        return K
    return PinholeCamera(K, validate_dist_coeffs(dist_coeffs))  # which validates K, as "K"


def _bp_ray(bp_uv: np.ndarray, camera) -> np.ndarray:
    """BP-ray normal: minus the unit viewing ray through the pixel ``bp_uv`` (3,) (NaN without a ray);
    ``camera`` a CameraModel or a pinhole K, done in Python floats with :func:`_bp_rays`' bits (a hot-path
    form of simtest.geometry's bp_ray_normal for a K validated once per call).
    """
    if isinstance(camera, np.ndarray) or (type(camera) is PinholeCamera and camera.dist_coeffs is None):
        K = camera if isinstance(camera, np.ndarray) else camera.K
        u, v = float(bp_uv[0]), float(bp_uv[1])
        y = (v - float(K[1, 2])) / float(K[1, 1])
        x = (u - float(K[0, 2]) - float(K[0, 1]) * y) / float(K[0, 0])
        n = math.sqrt((x * x + y * y) + 1.0)
        return np.array([-x / n, -y / n, -1.0 / n])
    return _bp_rays(np.asarray(bp_uv, dtype=np.float64).reshape(1, 2), camera)[0]


def _bp_rays(bp_uv: np.ndarray, camera) -> np.ndarray:
    """:func:`_bp_ray` of several pixels (k, 2): (k, 3), each from its own pixel only."""
    if isinstance(camera, CameraModel) and not (isinstance(camera, PinholeCamera) and camera.dist_coeffs is None):
        return -camera.pixel_to_ray(bp_uv)
    K = camera.K if isinstance(camera, PinholeCamera) else camera
    # K^-1 (u, v, 1) of an upper-triangular K, element by element
    y = (bp_uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (bp_uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    ray = np.stack([x, y, np.ones_like(x)], axis=1)
    return -ray / np.linalg.norm(ray, axis=1, keepdims=True)


@functools.lru_cache(maxsize=16)
def _gaussian_kernel(sigma: float) -> np.ndarray:
    """The taps :func:`_smooth` uses on float64 values (``ksize=(0, 0)``): OpenCV's kernel of
    ``2 gaussian_radius_px(sigma) + 1`` taps."""
    k = cv2.getGaussianKernel(2 * gaussian_radius_px(sigma) + 1, sigma, cv2.CV_64F).ravel()
    k.setflags(write=False)
    return k


def _smooth(vals: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing of an ROI's intensities (step 1), its borders reflected."""
    return cv2.GaussianBlur(vals, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def _frame_luma_smoothing(img: np.ndarray, detection_smoothed: np.ndarray, sigma: float,
                          luma32: np.ndarray | None = None, detection_luma32: np.ndarray | None = None) -> np.ndarray:
    """The whole frame's luma smoothed once (float32, read-only): detection's smoothing where it smoothed
    the luma itself, else the unrounded luma (``luma32`` where at hand) smoothed as detection smooths.
    """
    if luma32 is not None and luma32 is detection_luma32:
        return detection_smoothed
    if luma32 is not None:
        src = luma32
    elif img.ndim == 2 or img.dtype.kind == "f" or _is_gray(img):
        return detection_smoothed
    else:
        src = luma_cv2(img, np.float32) if img.dtype.type in (np.uint8, np.uint16) else luma(img).astype(np.float32)
    out = cv2.GaussianBlur(src, (0, 0), float(sigma), borderType=cv2.BORDER_REFLECT)
    out.setflags(write=False)
    return out


def _prepared(frame: _Frame, det, whole: bool) -> _Frame:
    """The frame made ready after detection ``det``: one smoothing of the frame for many highlights
    (:data:`LUMA_FRAME_MIN_HIGHLIGHTS`), else each ROI smoothed alone or the unsmoothed float32 luma.
    """
    img, settings = frame.img, frame.settings
    many = sum(c.status == OK for c in det.candidates) >= LUMA_FRAME_MIN_HIGHLIGHTS
    sliced = many and det.smoothed is not None and det.smoothed.shape == img.shape[:2]
    if sliced or (settings.verify and not many):
        # the colour frame's float32 luma, for the frame's smoothing and the verifier
        grey = img.ndim == 3 and img.shape[2] >= 3 and (
            det.grey if det.grey is not None and whole else bool(_is_gray(img)))
        # (detection's own where it smoothed this frame's luma: the same values)
        frame = replace(frame, luma32=None if grey else det.luma32 if (det.luma32 is not None and whole)
                        else colour_luma32(img, False), grey=grey)
    if not many and whole and frame.smooth_sigma_px > 0:
        # few ROIs, each smoothed alone: in float32 from the frame's luma where it is at hand
        if frame.luma32 is not None:
            frame = replace(frame, roi_luma=frame.luma32)
        elif frame.grey and det.gray is not None and det.gray.dtype == np.uint8 and det.gray.shape == img.shape[:2]:
            frame = replace(frame, roi_luma=det.gray)
        elif img.ndim == 2 and img.dtype.type in (np.uint8, np.uint16):
            frame = replace(frame, roi_luma=img)
    elif not many and whole and not frame.smooth_sigma_px > 0:
        # few ROIs of a frame not smoothed: contoured by the walks in its float32 luma
        if frame.luma32 is not None:
            luma_frame32 = frame.luma32
        elif det.gray is not None and det.gray.shape == img.shape[:2] and (img.ndim == 2 or frame.grey):
            luma_frame32 = det.gray.astype(np.float32)
            luma_frame32.setflags(write=False)
        else:
            luma_frame32 = None
        frame = replace(frame, luma_frame32=luma_frame32)
    if many:
        # many ROIs: contoured in one smoothing of the frame's luma
        if sliced:
            frame = frame.with_detection_smoothing(_frame_luma_smoothing(
                img, det.smoothed, frame.smooth_sigma_px, frame.luma32, det.luma32))
        else:
            frame = frame.for_many_highlights()
    return frame
