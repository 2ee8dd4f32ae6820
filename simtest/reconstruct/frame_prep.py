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
from simtest.reconstruct.detect import (
    colour_luma32, luma_cv2, default_full_scale, image_noise_sigma, luma, smooth_sigma_for_noise, validate_image,
)
from simtest.reconstruct.failures import OK
from simtest.reconstruct.settings import ReconSettings

#: A whole-frame call (:func:`~simtest.reconstruct.pipeline.reconstruct`) on an RGB image with at least
#: this many accepted highlights computes the luma of the frame once and slices each ROI's from it (the
#: same values, see ``_Frame.luma``): on the banner (666 highlights, ROIs grown to 11 times the frame in
#: all) that is a third of the time of one luma per ROI; for a few highlights the ROIs are cheaper.
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
        raise ValueError(
            f"dist_coeffs: need 4, 5, 8, 12 or 14 finite values (OpenCV order), got {d.tolist()}"
        )
    return d if np.any(d) else None


@dataclass(frozen=True)
class _Frame:
    """One image as the pipeline sees it, checked once: the image, its camera and the settings.

    ``full_scale`` and ``saturation_level`` are the settings' values resolved for this image's
    dtype (:func:`~simtest.reconstruct.detect.default_full_scale`; the integer dtype maximum).
    """

    img: np.ndarray
    camera: CameraModel
    settings: ReconSettings
    full_scale: float
    saturation_level: float | None
    smooth_sigma_px: float
    luma_frame: np.ndarray | None = None
    #: The whole frame's smoothed luma as detection computed it (float32, read-only; see
    #: ``with_detection_smoothing``): every ROI's values are slices of it.
    smoothed32: np.ndarray | None = None
    #: The luma's noise standard deviation (image units) measured to choose the smoothing
    #: (:func:`~simtest.reconstruct.detect.image_noise_sigma` of the region looked at); None
    #: when the settings fixed the smoothing.
    noise: float | None = None
    #: A colour (not gray) 8- or 16-bit RGB frame's luma in float32 (H, W), read-only, where
    #: ``reconstruct`` computed it (:func:`_colour_luma32`): the verifier's luma, and the one the
    #: frame's ROIs are smoothed from.
    luma32: np.ndarray | None = None
    #: Whether the image's R, G and B are equal (:func:`_is_gray`), where it was asked.
    grey: bool | None = None
    #: The frame's luma (H, W) each ROI of a frame with few highlights is smoothed from alone, in
    #: float32 (:func:`~simtest.reconstruct.isophotes._roi_values`), where ``reconstruct`` has it: a colour frame's ``luma32``, a
    #: gray 8-bit frame's channel (detection's gray), a single-channel integer frame itself.
    roi_luma: np.ndarray | None = None
    #: An unsmoothed frame's luma (H, W) in float32, read-only, where ``reconstruct`` made it for
    #: a frame with few highlights (detection's gray of a gray frame, a colour frame's ``luma32``):
    #: the contour walks (:func:`~simtest.reconstruct.isophotes._grown_drafts`) read their ROIs' values from it.
    luma_frame32: np.ndarray | None = None
    #: The luma that ``isophotes._first_rings`` read many ROIs' rings from (a grown ROI's too).
    ring_luma: np.ndarray | None = None
    #: The frame's tone curve (a camera file's ``"response"``, a SensorResponse) that the colour
    #: checks undo; None: a display-encoded (sRGB) frame.
    response: object | None = None

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
            sat = float(np.iinfo(img.dtype).max)
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
        """This frame with the luma of the whole image computed once (read-only), for calls that
        look at many ROIs (:data:`LUMA_FRAME_MIN_HIGHLIGHTS`): an ROI's luma is then a slice of
        it, the same bits (``luma``, ``_roi_values``)."""
        full = self.luma_frame
        if full is None and self.img.ndim == 3:
            full = luma(self.img)
            full.setflags(write=False)
        return replace(self, luma_frame=full)

    def with_detection_smoothing(self, smoothed: np.ndarray) -> _Frame:
        """This frame with its ROIs' values sliced from detection's smoothed luma (H, W) of the
        whole image (one smoothing per frame, :data:`simtest.reconstruct.detect.Detection.smoothed`)
        instead of each ROI smoothed alone with its borders reflected.

        The values differ from an ROI's own smoothing within the kernel's radius of the ROI's
        sides inside the image (there the frame's true neighbours replace the reflected ones:
        the frame's values are, if anything, the better ones), and by float32 rounding
        (``5e-8`` relative); :mod:`simtest.reconstruct.compare` holds the results to
        :data:`~simtest.reconstruct.compare.ACCURACY` (``tests/test_golden.py``)."""
        return replace(self, smoothed32=smoothed)

    @property
    def kernel(self) -> np.ndarray:
        """OpenCV's Gaussian kernel of ``_smooth`` at this frame's sigma, float64 (2 R + 1,)."""
        return _gaussian_kernel(self.smooth_sigma_px)

    def luma(self, roi: Roi) -> np.ndarray:
        """Luma of the image in ``roi`` (h, w), float64: sliced from the frame's luma when it
        was computed, else computed for the ROI.

        Both are the same bits: a pixel's luma is computed from that pixel alone
        (:func:`~simtest.reconstruct.detect.luma`), whatever the extent of the array
        (``tests/test_pipeline.py`` checks it over random ROIs).
        """
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


# ------------------------------------------------------------------------------------------------
# rays, luma and smoothing


# A hot-path form of simtest.geometry's bp_ray_normal for a K validated once per call (that one
# re-validates K each time); the tests check that they agree to rounding.


def _bp_ray(bp_uv: np.ndarray, camera) -> np.ndarray:
    """BP-ray normal: minus the unit viewing ray through the pixel ``bp_uv`` (3,).

    ``camera`` is a CameraModel or a pinhole K; NaN when the pixel has no ray in the model.
    For a pinhole without distortion, :func:`_bp_rays`' arithmetic in Python floats (a highlight's
    time is then not that of ten numpy calls on one row): the same operations in the same order,
    numpy's norm of a row of three summing ``(x^2 + y^2) + 1`` (``tests/test_pipeline.py``
    checks the bits against the batched form).
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


def _is_gray(img: np.ndarray) -> bool:
    """Whether R = G = B at every pixel of an (H, W, C >= 3) image (a NaN is no match): a few
    spread rows first (a colour frame differs there), then an 8- or 16-bit RGB frame against its
    R made RGB again by OpenCV (``cv2.norm`` of the difference), any other image by numpy, channel
    against channel."""
    rows = img[:: max(1, img.shape[0] // 16)]  # about 16 rows: speed only, the answer is the same
    if not (np.array_equal(rows[..., 0], rows[..., 1]) and np.array_equal(rows[..., 0], rows[..., 2])):
        return False
    if img.shape[2] == 3 and img.size and img.dtype.type in (np.uint8, np.uint16):
        img = np.ascontiguousarray(img)
        back = cv2.cvtColor(cv2.extractChannel(img, 0), cv2.COLOR_GRAY2RGB)
        return bool(cv2.norm(img, back, cv2.NORM_INF) == 0)
    return bool(np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 0], img[..., 2]))


def _colour_luma32(img: np.ndarray, grey: bool | None = None) -> np.ndarray | None:
    """The luma of a colour 8- or 16-bit RGB frame in float32 (H, W), read-only
    (:func:`~simtest.reconstruct.detect.luma_cv2`); None for any other frame (single-channel,
    gray (R = G = B), float, RGBA). ``grey``: whether R = G = B, where the caller knows (else
    tested here, for a frame :func:`~simtest.reconstruct.detect.colour_luma32` could take)."""
    if grey is None:
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype.type not in (np.uint8, np.uint16):
            return None
        grey = _is_gray(img)
    return colour_luma32(img, grey)


def _frame_luma_smoothing(img: np.ndarray, detection_smoothed: np.ndarray, sigma: float,
                          luma32: np.ndarray | None = None,
                          detection_luma32: np.ndarray | None = None) -> np.ndarray:
    """The whole frame's luma smoothed once (float32, read-only): detection's smoothing where
    detection smoothed the luma itself (a single-channel, gray (R = G = B) or float image, or a
    colour frame's unrounded luma, ``detection_luma32``: ``Detection.luma32``, which ``luma32``
    then is), else the unrounded luma (:func:`~simtest.reconstruct.detect.luma_cv2` in float32;
    ``luma32`` where the caller has it, :func:`_colour_luma32`) smoothed as detection smooths
    (an 8-bit frame's OpenCV gray is rounded to whole levels, which moves contours)."""
    if luma32 is not None and luma32 is detection_luma32:
        return detection_smoothed
    if luma32 is not None:
        src = luma32
    elif img.ndim == 2 or img.dtype.kind == "f" or _is_gray(img):
        return detection_smoothed
    else:
        src = luma_cv2(img, np.float32) if img.dtype.type in (np.uint8, np.uint16) else \
            luma(img).astype(np.float32)
    out = cv2.GaussianBlur(src, (0, 0), float(sigma), borderType=cv2.BORDER_REFLECT)
    out.setflags(write=False)
    return out


def _prepared(frame: _Frame, det, whole: bool) -> _Frame:
    """The frame made ready after detection ``det`` (of the whole image where ``whole``): its
    float32 luma where read, and its ROIs' values: for many highlights (:data:`LUMA_FRAME_MIN_HIGHLIGHTS`)
    one smoothing of the frame, for few each ROI smoothed alone, or the unsmoothed float32 luma."""
    img, settings = frame.img, frame.settings
    many = sum(c.status == OK for c in det.candidates) >= LUMA_FRAME_MIN_HIGHLIGHTS
    sliced = many and det.smoothed is not None and det.smoothed.shape == img.shape[:2]
    if sliced or (settings.verify and not many):
        # the colour frame's float32 luma, for the frame's smoothing and the verifier (which reads
        # for_many_highlights' float64 luma where computed) (detection's answer where it asked)
        grey = img.ndim == 3 and img.shape[2] >= 3 and (
            det.grey if det.grey is not None and whole else bool(_is_gray(img)))
        # (detection's own where it smoothed this frame's luma: the same values)
        frame = replace(frame, luma32=None if grey else det.luma32 if (det.luma32 is not None and whole)
                        else _colour_luma32(img, False), grey=grey)
    if not many and whole and frame.smooth_sigma_px > 0:
        # few ROIs, each smoothed alone: in float32 from the frame's luma where it is at hand (the
        # colour frame's float32 luma, a gray frame's channel, a single-channel 8- or 16-bit frame)
        if frame.luma32 is not None:
            frame = replace(frame, roi_luma=frame.luma32)
        elif frame.grey and det.gray is not None and det.gray.dtype == np.uint8 and det.gray.shape == img.shape[:2]:
            frame = replace(frame, roi_luma=det.gray)
        elif img.ndim == 2 and img.dtype.type in (np.uint8, np.uint16):
            frame = replace(frame, roi_luma=img)
    elif not many and whole and not frame.smooth_sigma_px > 0:
        # few ROIs of a frame not smoothed: contoured by the walks in its float32 luma
        # (isophotes._grown_drafts), at hand or one conversion of detection's gray away
        if frame.luma32 is not None:
            luma_frame32 = frame.luma32
        elif det.gray is not None and det.gray.shape == img.shape[:2] and (img.ndim == 2 or frame.grey):
            luma_frame32 = det.gray.astype(np.float32)
            luma_frame32.setflags(write=False)
        else:
            luma_frame32 = None
        frame = replace(frame, luma_frame32=luma_frame32)
    if many:
        # many ROIs: contoured in one smoothing of the frame's luma (detection's own where it is
        # the luma: a gray, single-channel or float frame), not each smoothed for itself
        if sliced:
            frame = frame.with_detection_smoothing(_frame_luma_smoothing(
                img, det.smoothed, frame.smooth_sigma_px, frame.luma32, det.luma32))
        else:
            frame = frame.for_many_highlights()
    return frame
