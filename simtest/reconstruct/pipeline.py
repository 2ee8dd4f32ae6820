"""The reconstruction pipeline: image -> specular highlights -> isophote ellipses -> normals.

``reconstruct(image, K, isovalue)`` detects every highlight of a whole image and estimates one
:class:`SpecularityEstimate` per candidate; ``reconstruct_roi(image, K, isovalue, bp_uv=..., roi=...)``
does one known highlight (the harness uses it on simulated images whose BP and ROI are known).

Per highlight (Makki and Bartoli, "Normal reconstruction"):

1. the intensities are normalised so that the BP has intensity 1 (``normalise="bp"``, the paper's
   step 4; optional Gaussian smoothing first, ``smooth_sigma_px``). On real tissue the specular
   lobe sits on a diffuse background that is often brighter than t times the BP, so that no
   isophote of the specular lobe exists at ``t I_bp``; ``normalise="local"`` takes the median of
   the ROI's border pixels as the local diffuse level b and contours at ``b + t (I_bp - b)``, i.e.
   t is relative to the specular part (exact when the diffuse term is constant over the ROI;
   beyond the paper);
2. the isophote at each isovalue t is extracted by marching squares
   (:func:`~simtest.reconstruct.isophote.extract_isophote`); the ROI grows (x2, up to 4 times) while
   the lowest isophote is cut by the ROI border;
3. the contour points are mapped to unit viewing rays by the camera model and the isophote cone
   C' (``r^T C' r = 0``) is fitted on the rays (:mod:`~simtest.reconstruct.cone_fit`; for a
   pinhole this is the ellipse fit in undistorted pixels and C' = K^T C K, for a wide-angle model
   it is exact where no pixel conic exists);
4. the estimators of :mod:`~simtest.reconstruct.estimators` give the paper pair N+ and N- and the
   non-oracle choice between them, the cone axis with its eigenvalue gap, the BP-ray normal and,
   with several isovalues, the joint cone axis of the nested isophotes, all computed from the
   cone C'.

Steps 1 and 2 run highlight by highlight (the ROI grows on what the isophote shows); steps 3
and 4 run once per call for every isophote of every highlight, batched
(:func:`~simtest.reconstruct.cone_fit.fit_cones`,
:func:`~simtest.reconstruct.estimators.estimate_from_conics`,
:func:`~simtest.reconstruct.estimators.joint_cone_axes`, each one compiled call over the batch
with numpy around it): a highlight gets the same bits as it would alone, and a frame of hundreds
of highlights pays the fixed cost of the calls once.
:func:`reconstruct_rois` does the same for many known highlights.

The *primary* isophote is the one at the first isovalue given: the estimate's ``conic``,
``ellipse``, ``normals_paper``, ``cone_axis``, ``eigenvalue_gap``, ``fit_residual_px`` and
``status`` are those of the primary isophote; every isovalue's own result is in ``isophotes``.

Errors: caller mistakes raise ValueError (bad image, K, isovalue, ROI, options); a highlight
that cannot be reconstructed gets a status from
:data:`simtest.reconstruct.failures.REASONS` and ``None`` in place of its normals, never NaN.

Conventions: pixel (u, v) = (column, row) with pixel centres at integer coordinates; ROIs are
half-open array-index ranges ``(row0, row1, col0, col1)``; every normal is a unit vector in the
OpenCV camera frame (x right, y down, z forward) facing the camera (``n . ray < 0``).

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 2.3 (the four steps) and section 3.1, step 4 (smoothing and normalisation).
.. [2] W. E. Lorensen, H. E. Cline, "Marching cubes: a high resolution 3D surface construction
       algorithm", SIGGRAPH 1987. https://doi.org/10.1145/37402.37422 (marching squares, step 2).
.. [3] A. Fitzgibbon, M. Pilu, R. B. Fisher, "Direct least square fitting of ellipses", IEEE
       TPAMI 21(5), 1999. https://doi.org/10.1109/34.765658; in the form of R. Halir,
       J. Flusser, "Numerically stable direct least squares fitting of ellipses", WSCG 1998.
.. [4] D. Forsyth et al., "Invariant descriptors for 3-D object recognition and pose", IEEE
       TPAMI 13(10), 1991, appendix A. https://doi.org/10.1109/34.99233 (circle pose, step 4).
.. [5] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co`` (prior art of
       the cone-axis estimator).
"""

from __future__ import annotations

import ctypes
import functools
import gc
import math
from contextlib import contextmanager
from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from simtest._records import fast_init
from simtest.constants import LUMA_BT601, gaussian_radius_px, smooth_block_px
from simtest.geometry.cameras import CameraModel, PinholeCamera
from simtest.decisions import ROI_GROWTH_FACTOR, ROI_MAX_GROWTHS
from simtest.reconstruct import _kernels
from simtest.reconstruct._pixels import Roi, image_size_wh, rc_to_uv
from simtest.reconstruct.cone_fit import FitFrame, fit_cones, fit_frame, fit_frames, to_camera, to_fit_frame
from simtest.reconstruct.detect import (
    background_side_px,
    colour_luma32,
    compiled_luma,
    connected_components,
    default_full_scale,
    detect_specularities,
    image_noise_sigma,
    luma,
    noise_sigma,
    peak_uv,
    smooth_sigma_for_noise,
    validate_image,
)
from simtest.reconstruct.estimators import estimate_from_conics, joint_cone_axes
from simtest.reconstruct.failures import OK, Failure
from simtest.reconstruct.isophote import MIN_CONTOUR_POINTS, Isophote, _cut_and_contour, _extract, _Region, _region
from simtest.reconstruct.recommend import recommend
from simtest.reconstruct.result import Reconstruction
from simtest.reconstruct.settings import AUTO_LOCAL_BACKGROUND_REL, Normalisation, ReconSettings
from simtest.reconstruct.verify import assess, bp_checks, confidence, seed_opening, shared_passes, verdict

#: A whole-frame call (:func:`reconstruct`) on an RGB image with at least this many accepted
#: highlights computes the luma of the frame once and slices each ROI's from it (the same values,
#: see ``_Frame.luma``): on the banner (666 highlights, ROIs grown to 11 times the frame in all)
#: that is a third of the time of one luma per ROI; for a few highlights the ROIs are cheaper.
LUMA_FRAME_MIN_HIGHLIGHTS = 32

_TINY = float(np.finfo(float).tiny)

#: A frame prepared for many highlights (``_Frame.for_many_highlights``) smooths its luma once and
#: takes an ROI of at least this many pixels from it (``_patched_from_frame``); a smaller ROI is
#: smoothed for itself, which is cheaper there (the same bits either way). On the Hyper-Kvasir
#: banner (sigma 1.7 px) the two took the same time at about 160 x 160 px (medians of six ROIs:
#: 186 against 182 us; at 128 px 114 against 142 us, at 224 px 355 against 249 us).
SMOOTH_FRAME_MIN_ROI_PX = 160 * 160
#: Columns the strip re-smoothed at an ROI's right side starts on a multiple of, and more than
#: it covers (:data:`simtest.constants.SMOOTH_BLOCK_BYTES` of float64): each column of the strip is
#: computed in the same kind of block (SIMD, or a row's scalar last columns) as in the ROI, and the
#: strip reaches past the frame's own scalar columns when the ROI ends on the image's right border.
#: The strips cost in proportion to their width: 16 instead of 64 halved the re-smoothed pixels of
#: the Hyper-Kvasir banner (8.6 to 3.9 Mpx).
SMOOTH_STRIP_ALIGN = smooth_block_px(np.dtype(np.float64).itemsize)



@fast_init
@dataclass(frozen=True)
class IsophoteEstimate:
    """The result at one isovalue.

    Attributes
    ----------
    isovalue : float
        t in (0, 1), relative to the normalisation (the BP intensity by default).
    status : str
        ``"ok"`` or a reason from :data:`~simtest.reconstruct.failures.REASONS`.
    detail : str
        Numbers behind a failure.
    points_uv : ndarray of shape (N, 2) or None
        Contour points as found in the image (distorted pixel coordinates), px.
    closed : bool
        False if the contour is cut (then fitted only with ``allow_open=True``).
    conic : ndarray of shape (3, 3) or None
        Fitted point conic in undistorted pixel coordinates (unit Frobenius norm), for a pinhole
        camera; None for a fisheye or omnidirectional camera, whose isophotes are no conics in
        pixels (the fit is the cone ``normalised_conic``).
    ellipse : simtest.geometry.conics.Ellipse or None
        Its centre (u, v) px, semi-axes (a >= b) px and angle (rad); None as ``conic``.
    fit_residual_px : float or None
        RMS Sampson distance of the points to the conic on the fit plane, px
        (:mod:`~simtest.reconstruct.cone_fit`).
    normals_paper : ndarray of shape (2, 3) or None
        N+ and N-.
    paper_selected : ndarray of shape (3,) or None
        The non-oracle choice among N+ and N- (closer to the BP ray).
    paper_selected_index : int or None
        0 if that is N+, 1 if N-.
    cone_axis : ndarray of shape (3,) or None
        Cone-axis normal.
    eigenvalue_gap : float or None
        0 for a right circular cone.
    normalised_conic : ndarray of shape (3, 3) or None
        The isophote cone C' in the camera frame (``r^T C' r = 0`` on its unit rays; K^T C K for
        a pinhole), unit Frobenius norm.
    """

    isovalue: float
    status: str
    detail: str = ""
    points_uv: np.ndarray | None = None
    closed: bool = False
    conic: np.ndarray | None = None
    ellipse: object | None = None
    fit_residual_px: float | None = None
    normals_paper: np.ndarray | None = None
    paper_selected: np.ndarray | None = None
    paper_selected_index: int | None = None
    cone_axis: np.ndarray | None = None
    eigenvalue_gap: float | None = None
    normalised_conic: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True if the status is ``"ok"``."""
        return self.status == OK


@fast_init
@dataclass(frozen=True)
class SpecularityEstimate:
    """Everything estimated for one highlight.

    Attributes
    ----------
    bp_px : ndarray of shape (2,)
        Brightest point (u, v) as detected in the image, px.
    bp_intensity : float
        Intensity used for normalisation (image units).
    saturated : bool
        True if the BP is the centroid of a clipped plateau.
    roi : Roi
        Final region of interest (array indices, half-open).
    status : str
        ``"ok"`` or a reason: a detection rejection, the primary isophote's failure, or
        ``merged`` (the primary isophote encloses another highlight's BP).
    detail : str
        Numbers behind the status.
    bp_ray : ndarray of shape (3,) or None
        BP-ray normal (minus the unit viewing ray of the BP through the camera model); None only
        when the BP has no ray in the model (status ``non_finite_points``).
    isophotes : tuple of IsophoteEstimate
        One per isovalue, in the order given.
    joint_cone_axis : ndarray of shape (3,) or None
        Common axis of the nested isophotes, when at least two succeeded.
    light_aware : dict or None
        The light-aware estimates by name (:mod:`simtest.reconstruct.recommend`), when a light rig
        off the camera centre is known; an empty dict where that rig is known but no fit ran (a
        rejected candidate: its recommended normal is the BP ray's). None: no such rig.
    confidence : float or None
        In [0, 1]: how likely the candidate is an isolated specular highlight the isophote method
        can use (:func:`simtest.reconstruct.verify.confidence`, calibrated on labelled real
        frames); None where the frame was not verified (``ReconSettings.verify`` off).
    """

    bp_px: np.ndarray
    bp_intensity: float
    saturated: bool
    roi: Roi
    status: str
    detail: str
    bp_ray: np.ndarray
    isophotes: tuple[IsophoteEstimate, ...]
    joint_cone_axis: np.ndarray | None = None
    light_aware: dict | None = None
    confidence: float | None = None

    @property
    def ok(self) -> bool:
        """True if the status is ``"ok"``."""
        return self.status == OK

    @property
    def recommended(self):
        """The recommended normal, its estimator, depth and uncertainty
        (:func:`simtest.reconstruct.recommend.recommend`)."""
        return recommend(self)

    @property
    def primary(self) -> IsophoteEstimate | None:
        """The isophote at the first isovalue (None for a rejected detection)."""
        return self.isophotes[0] if self.isophotes else None

    def _p(self, name):
        p = self.primary
        return None if p is None else getattr(p, name)

    @property
    def points_uv(self):
        """Primary isophote points (N, 2) px, or None."""
        return self._p("points_uv")

    @property
    def conic(self):
        """Primary fitted conic (3, 3), or None."""
        return self._p("conic")

    @property
    def ellipse(self):
        """Primary ellipse parameters, or None."""
        return self._p("ellipse")

    @property
    def normals_paper(self):
        """Primary N+ and N- (2, 3), or None."""
        return self._p("normals_paper")

    @property
    def paper_selected(self):
        """Primary non-oracle paper normal (3,), or None."""
        return self._p("paper_selected")

    @property
    def cone_axis(self):
        """Primary cone-axis normal (3,), or None."""
        return self._p("cone_axis")

    @property
    def eigenvalue_gap(self):
        """Primary eigenvalue gap, or None."""
        return self._p("eigenvalue_gap")

    @property
    def fit_residual_px(self):
        """Primary RMS Sampson residual, px, or None."""
        return self._p("fit_residual_px")


# ------------------------------------------------------------------------------------------------
# argument checks


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
    #: The frame's smoothed luma (``for_many_highlights``), into which a large ROI's bands are
    #: written for the time of its extraction (``_patched_from_frame``), then put back.
    smooth_frame_rw: np.ndarray | None = None
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
    #: Whether the image's R, G and B are equal (``_kernels.is_gray``), where it was asked.
    grey: bool | None = None
    #: The frame's luma (H, W) each ROI of a frame with few highlights is smoothed from alone, in
    #: float32 (:func:`_roi_values`), where ``reconstruct`` has it: a colour frame's ``luma32``, a
    #: gray 8-bit frame's channel (detection's gray), a single-channel integer frame itself.
    roi_luma: np.ndarray | None = None
    #: An unsmoothed frame's luma (H, W) in float32, read-only, where ``reconstruct`` made it for
    #: a frame with few highlights (detection's gray of a gray frame, a colour frame's ``luma32``):
    #: the compiled contour walks (:func:`_grown_drafts`) read their ROIs' values from it.
    luma_frame32: np.ndarray | None = None

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

    @property
    def smooth_frame(self) -> np.ndarray | None:
        """The frame's smoothed luma (H, W), float64, as a read-only view of
        ``smooth_frame_rw``; None when it was not computed."""
        if self.smooth_frame_rw is None:
            return None
        view = self.smooth_frame_rw.view()
        view.setflags(write=False)
        return view

    def for_many_highlights(self) -> _Frame:
        """This frame with the luma of the whole image computed once (read-only), and smoothed
        once when the frame is smoothed (a large ROI's bands are written into it for the time of
        the ROI's extraction, then put back), for calls that look at many ROIs
        (:data:`LUMA_FRAME_MIN_HIGHLIGHTS`): an ROI's values are then slices of them, the same bits
        (``luma``, ``_roi_values``)."""
        full = self.luma_frame
        if full is None and self.img.ndim == 3:
            full = luma(self.img)
            full.setflags(write=False)
        smooth = self.smooth_frame_rw
        if smooth is None and self.smooth_sigma_px > 0:
            smooth = _smooth(luma(self.img) if full is None else full, self.smooth_sigma_px)
        return replace(self, luma_frame=full, smooth_frame_rw=smooth)

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
    def img3(self) -> np.ndarray:
        """The image as (H, W, C) (a view)."""
        return self.img if self.img.ndim == 3 else self.img[:, :, None]

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


@contextmanager
def _gc_paused():
    """Python's cyclic garbage collector paused for a frame's work, then restored as it was
    (a context manager, and a decorator of :func:`reconstruct` and :func:`reconstruct_rois`).

    A frame with hundreds of highlights builds thousands of small result objects, none of them
    in a reference cycle; each allocation burst triggers collections, and every few of them is a
    full one over every object the process holds (about 170 000 after importing simtest: numba,
    OpenCV, scikit-image). On the Hyper-Kvasir banner these passes were about a tenth of the
    time. Nothing the pipeline allocates waits for the collector (no cycles), and a caller that
    had paused it keeps it paused.
    """
    _keep_freed_memory()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


#: glibc's ``mallopt`` parameters (malloc.h) and the values :func:`_keep_freed_memory` sets.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: Blocks up to this size come from the heap, not from their own mapping (glibc's largest
#: threshold, 32 MiB: a 1350 x 1080 RGB frame in float32 is 17 MiB) ...
MMAP_THRESHOLD_BYTES = 32 << 20
#: ... and up to this much free memory stays at the top of the heap.
TRIM_THRESHOLD_BYTES = 256 << 20


@functools.cache
def _keep_freed_memory() -> bool:
    """Have the C library keep the memory of freed whole-frame arrays for the next ones (once
    per process, at the first frame; glibc only: True if it took the settings).

    A frame's reconstruction allocates dozens of whole-frame arrays (the luma, its smoothing, the
    opening, the top-hat, the verifier's masks), each a few MiB. glibc gives every block above
    its mmap threshold (128 KiB, raised as blocks are freed) its own mapping and returns it to
    the kernel when freed, so that the next frame's arrays fault every page in afresh: on the
    2-core VM that was 12 ms of the noisy 10-highlight frame's 42 (the verifier's arrays,
    measured with the C library keeping them: 30 ms). With blocks up to
    :data:`MMAP_THRESHOLD_BYTES` taken from the heap and up to :data:`TRIM_THRESHOLD_BYTES` of
    free memory kept there, the pages stay mapped between frames; the process's resident memory
    stays at its peak (a few hundred MiB for 1350 x 1080 frames) instead of falling between them.
    Elsewhere (macOS, musl) nothing is changed.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) & bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


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
# one highlight


# Hot-path forms of simtest.geometry's normalised_conic and bp_ray_normal for a K validated once
# per call (those re-validate K each time, ~30 us, 10 % of a highlight's budget); the tests check
# that they agree with the geometry functions to rounding.


def _normalised_conic(C: np.ndarray, K: np.ndarray) -> np.ndarray | None:
    """C' = K^T C K (paper step 3), symmetrised, unit Frobenius norm; None if zero or non-finite."""
    cn = K.T @ C @ K
    cn = 0.5 * (cn + cn.T)
    norm = float(np.linalg.norm(cn))
    if not (np.isfinite(norm) and norm > 0):
        return None
    return cn / norm


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


_LUMA_W = tuple(float(w) for w in LUMA_BT601)


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


def _roi_values(frame: _Frame, roi: Roi, smooth_sigma_px: float) -> tuple[np.ndarray, list | None]:
    """An ROI's intensities (h, w), float64 (read-only where they are a view): its luma, smoothed
    with the ROI's borders reflected when ``smooth_sigma_px`` > 0 (for a large ROI of a frame
    smoothed once, the frame's values with the ROI's bands written in: ``_patched_from_frame``,
    the same bits), and what :func:`_put_back` needs to restore the frame afterwards (None when
    nothing was written)."""
    if frame.smoothed32 is not None and smooth_sigma_px > 0:
        return frame.smoothed32[roi.slices], None  # float32, read-only: the kernels read it as it is
    if frame.roi_luma is not None and smooth_sigma_px > 0:
        # the ROI's luma smoothed alone in float32 (OpenCV's float32 blur, its borders reflected):
        # the float64 luma and its float64 blur of the same ROI to float32 rounding (5e-8
        # relative, as the frame's smoothing is; 0.65 -> 0.3 ms for the ten ROIs of the noisy
        # bench frame)
        return _smooth(frame.roi_luma[roi.slices].astype(np.float32), smooth_sigma_px), None
    vals = frame.luma(roi)
    if smooth_sigma_px <= 0:
        return vals, None
    if frame.smooth_frame_rw is not None and vals.size >= SMOOTH_FRAME_MIN_ROI_PX:
        got = _patched_from_frame(frame.smooth_frame_rw, vals, roi, smooth_sigma_px)
        if got is not None:
            return got
    return _smooth(vals, smooth_sigma_px), None


def _patched_from_frame(smooth_frame: np.ndarray, vals: np.ndarray, roi: Roi,
                        sigma: float) -> tuple[np.ndarray, list] | None:
    """``_smooth(vals, sigma)`` of an ROI, as a view of the smoothed frame with the ROI's bands
    written in, and the frame's values that were there (for :func:`_put_back`).

    A pixel farther than the kernel's radius from the ROI's sides has the same neighbourhood in
    the frame and in the ROI (a side on the image border reflects as the frame's does), and
    OpenCV computes it with the same operations, but for the last columns of a row, which it
    computes in scalar code where the rest is in SIMD blocks (:data:`SMOOTH_STRIP_ALIGN`). So the
    bands along the ROI's top, bottom and left sides inside the image are smoothed again from
    strips twice the radius wide (a strip's own far side does not reach the band), and the
    ROI's last columns from a strip that starts on a multiple of the alignment (its blocks are
    the ROI's) and is wider than the frame's scalar columns. Writing the bands into the frame
    for the time of the ROI's extraction, instead of copying the ROI out of it, moves a fifth of
    the bytes (the banner's large ROIs are 19 Mpx, ten times the frame).

    Returns None (smooth the ROI itself) for an ROI too narrow for the strips. The bits equal
    those of smoothing the ROI, and the frame is itself again after :func:`_put_back`:
    ``tests/test_pipeline.py`` checks random ROIs.
    """
    r = gaussian_radius_px(sigma) + 1  # one more than OpenCV's kernel radius
    h, w = vals.shape
    H = smooth_frame.shape[0]
    c = (w - SMOOTH_STRIP_ALIGN - 2 * r) // SMOOTH_STRIP_ALIGN * SMOOTH_STRIP_ALIGN
    if h < 2 * r or c <= 2 * r:
        return None
    # The bands as (rows, columns) of the ROI and their values, in this order (a later band
    # overwrites the corners of an earlier one). Two strips on opposite sides are smoothed in one
    # OpenCV call, stacked or side by side (a call's fixed cost, and a narrow strip's cost per
    # row, are most of a strip's time): a band reads its own strip only, within the kernel's
    # radius, and each column (row) is computed as in a call of its own (the left strip's width,
    # a multiple of the alignment, keeps the right one's SIMD blocks).
    bands = []
    top, bottom = vals[: 2 * r], vals[h - 2 * r :]
    if roi.row0 > 0 and roi.row1 < H:
        both = _smooth(np.concatenate([top, bottom]), sigma)
        bands += [(slice(0, r), slice(0, w), both[:r]), (slice(h - r, h), slice(0, w), both[3 * r :])]
    elif roi.row0 > 0:
        bands.append((slice(0, r), slice(0, w), _smooth(top, sigma)[:r]))
    elif roi.row1 < H:
        bands.append((slice(h - r, h), slice(0, w), _smooth(bottom, sigma)[r:]))
    right = slice(0, h), slice(c + r, w)
    if roi.col0 > 0:
        wl = -(-max(2 * r, SMOOTH_STRIP_ALIGN) // SMOOTH_STRIP_ALIGN) * SMOOTH_STRIP_ALIGN
        both = _smooth(np.concatenate([vals[:, :wl], vals[:, c:]], axis=1), sigma)
        bands += [(slice(0, h), slice(0, r), both[:, :r]), (*right, both[:, wl + r :])]
    else:
        bands.append((*right, _smooth(vals[:, c:], sigma)[:, r:]))
    view = smooth_frame[roi.slices]
    # each band's place in the frame and the frame's values there, all saved before any write
    places = [view[rows, cols] for rows, cols, _ in bands]
    saved = [(place, place.copy()) for place in places]
    for place, (_, _, v) in zip(places, bands):
        place[...] = v
    out = view.view()
    out.setflags(write=False)
    return out, saved


def _put_back(saved: list | None) -> None:
    """Restore the smoothed frame's values that :func:`_patched_from_frame` overwrote (each
    saved before any band was written, so the order does not matter)."""
    for place, v in saved or ():
        place[...] = v


def _find_bp(img: np.ndarray, roi: Roi, saturation_level) -> tuple[np.ndarray, bool]:
    """BP inside ROI: saturated plateau centroid when clipped, else the refined brightest pixel."""
    vals = luma(img[roi.slices])
    flat = int(np.argmax(vals))
    r, c = divmod(flat, vals.shape[1])
    if saturation_level is not None:
        sub = img[roi.slices]
        sat = sub >= saturation_level
        if sat.ndim == 3:
            sat = sat.all(axis=2)
        if sat[r, c]:
            _, lab = connected_components(sat.view(np.uint8))
            rr, cc = np.nonzero(lab == lab[r, c])
            return rc_to_uv([rr.mean(), cc.mean()], roi.row0, roi.col0), True
    return peak_uv(vals, r, c) + (roi.col0, roi.row0), False


def _border_median(vals: np.ndarray) -> float:
    """Median of the pixels on the border of an ROI: the local diffuse level of ``normalise="local"``."""
    return float(_kernels.border_median(vals))  # np.median of the ring's pixels (tested)


@fast_init
@dataclass(frozen=True)
class _Levels:
    """Contour level of isovalue t in one ROI: ``offset + t * scale`` (image units)."""

    scale: float
    offset: float = 0.0

    @classmethod
    def of(cls, frame: _Frame, vals: np.ndarray, i_bp: float, roi: Roi | None = None,
           ring: float | None = None) -> _Levels:
        """``ring``: the ROI's smoothed border median where the caller computed it
        (:func:`_first_rings`)."""
        mode = frame.settings.normalise
        if ring is None and roi is not None and frame.smoothed32 is not None and \
                mode in (Normalisation.AUTO, Normalisation.LOCAL):
            # the ROI's values are the frame's smoothing; its background level is that of the ROI
            # smoothed alone (_kernels.smoothed_border_median), as without the frame's
            ring = float(_kernels.smoothed_border_median(frame.img3, *_LUMA_W, roi.row0, roi.row1,
                                                         roi.col0, roi.col1, frame.kernel))
        if mode == Normalisation.AUTO:
            if ring is None:
                ring = _border_median(vals)
            local = ring >= AUTO_LOCAL_BACKGROUND_REL * i_bp
            mode = Normalisation.LOCAL if local else Normalisation.BP
        if mode == Normalisation.BP:
            return cls(i_bp)
        if mode == Normalisation.LOCAL:
            offset = min(_border_median(vals) if ring is None else ring, i_bp)
            return cls(i_bp - offset, offset)
        return cls(frame.full_scale)

    def level(self, t: float) -> float:
        return self.offset + t * self.scale


@fast_init
@dataclass(frozen=True)
class _Pending:
    """An isophote extracted and waiting for its cone fit (done for a whole frame at once)."""

    isovalue: float
    iso: object  # simtest.reconstruct.isophote.Isophote


def _one_isophote(frame: _Frame, region, levels: _Levels, t, walked=None):
    """Extract the isophote at ``t`` in an ROI's checked region (``isophote._region``):
    ``(IsophoteEstimate of a failure, or _Pending, Isophote or None)``. ``walked``: the contour
    the growth question traced at that level (``isophote._cut_and_contour``), or None."""
    iso = _extract(region, levels.level(t), True, 0, walked)
    if not iso:
        return IsophoteEstimate(t, iso.reason, iso.detail), None
    if iso.cut and not frame.settings.allow_open:
        where = "image border" if iso.cut_by_image else "ROI border"
        return IsophoteEstimate(t, "contour_cut", f"cut by the {where}", iso.points_uv, False), iso
    if len(iso.points_uv) < MIN_CONTOUR_POINTS:
        return IsophoteEstimate(t, "too_few_points", f"{len(iso.points_uv)} contour points < "
                                f"{MIN_CONTOUR_POINTS}", iso.points_uv, iso.closed), iso
    return _Pending(t, iso), iso


@dataclass
class _Draft:
    """One highlight after its isophotes were extracted, before the frame's batched fits."""

    bp_uv: np.ndarray
    i_bp: float
    saturated: bool
    roi: Roi
    bp_ray: np.ndarray
    fitf: FitFrame
    results: list
    other_bps: object = ()
    own_bp: int = -1  # this highlight's own row in other_bps (skipped), -1 if not there


def _estimate_one(frame: _Frame, bp_uv, roi: Roi, *, saturated: bool, grow: bool,
                  other_bps=(), own_bp: int = -1, bp_ray=None, fitf: FitFrame | None = None,
                  ring: float | None = None) -> _Draft | SpecularityEstimate:
    """Extract one highlight's isophotes (growing the ROI): a draft for :func:`_complete`, or the
    finished estimate of a BP without a viewing ray. ``other_bps`` (k, 2) are the BPs its isophote
    must not enclose (``merged``), one frame's array shared by its highlights, whose own row
    ``own_bp`` is skipped. ``bp_ray`` and ``fitf`` are the BP's ray and fit frame when the caller
    computed them (for many highlights at once); ``ring`` the first ROI's smoothed border
    median (:func:`_first_rings`), or None."""
    isovalues = frame.settings.isovalues
    sigma = frame.smooth_sigma_px
    bp_uv = np.asarray(bp_uv, dtype=np.float64)
    if bp_ray is None:
        bp_ray = frame.bp_ray(bp_uv)
    if not all(map(math.isfinite, bp_ray.tolist())):
        i_bp = _region(frame.luma(roi), bp_uv, (roi.row0, roi.col0), frame.img.shape).near_bp
        return SpecularityEstimate(bp_uv, i_bp, saturated, roi, "non_finite_points",
                                   "the BP has no viewing ray in the camera model", None, ())
    if fitf is None:
        fitf = fit_frame(frame.camera, -bp_ray)
    # Lowest isovalue first: the widest contour decides the ROI size.
    order = sorted(range(len(isovalues)), key=lambda i: isovalues[i])
    results: list = [None] * len(isovalues)
    growths = 0
    saved = None  # the frame's values under the current ROI's bands (_roi_values), put back after
    # With the frame smoothed once (smoothed32), an ROI's values are the frame's: within the
    # kernel's reach of an ROI side inside the image they are not the ROI's own smoothing (its
    # sides reflected) but the frame's true neighbours' (issue 41: no longer looked at again
    # smoothed alone; the contours that come that near a side move within the accuracy
    # tolerance, and the banner takes 243 -> 185 ms). Its background level stays that of the ROI
    # smoothed alone (_Levels.of).
    fast = frame.smoothed32 is not None and sigma > 0
    try:
        while True:
            _put_back(saved)
            vals, saved = _roi_values(frame, roi, sigma)
            region = _region(vals, bp_uv, (roi.row0, roi.col0), frame.img.shape)
            i_bp = region.near_bp  # the largest of the BP's 3 x 3 pixels
            levels = _Levels.of(frame, vals, i_bp, roi if fast else None, ring if fast and not growths else None)
            i0 = order[0]
            res = walked = None
            cut = False
            if grow and growths < ROI_MAX_GROWTHS:
                new = Roi.around(bp_uv, ROI_GROWTH_FACTOR * max(roi.shape) / 2.0, frame.img.shape)
                # an isophote cut by the ROI is discarded for the grown ROI's: ask only whether it
                # is (the walk that answers traces the isophote: kept for the extraction when it
                # is not)
                if new != roi:
                    cut, walked = _cut_and_contour(region, levels.level(isovalues[i0]))
                if cut is None:  # only the extraction can tell
                    res, iso = _one_isophote(frame, region, levels, isovalues[i0], walked)
                    cut = iso is not None and iso.cut_by_roi
                if cut:
                    roi, growths = new, growths + 1
                    continue
            if not cut:
                results[i0] = _one_isophote(frame, region, levels, isovalues[i0], walked)[0] if res is None else res
                for i in order[1:]:
                    results[i], _ = _one_isophote(frame, region, levels, isovalues[i])
            break
    finally:
        _put_back(saved)
    return _Draft(bp_uv, i_bp, saturated, roi, bp_ray, fitf, results, other_bps, own_bp)


def _complete(drafts: list) -> list[SpecularityEstimate]:
    """Fit the cones of every pending isophote of ``drafts`` in one batch, run the estimators in
    one batch, and finish each highlight (``merged`` test, joint cone axis)."""
    # the drafts among the estimates (a real frame's thousands of rejections are finished already)
    dr = [d for d in drafts if type(d) is _Draft]
    pend = [(d, i) for d in dr for i, r in enumerate(d.results) if type(r) is _Pending]
    fits = fit_cones([d.results[i].iso.points_uv for d, i in pend], [d.fitf for d, _ in pend])
    fitted = [k for k, f in enumerate(fits) if f]
    ests = [] if not fitted else estimate_from_conics(
        np.array([fits[k].cone_fit_frame for k in fitted]).reshape(-1, 3, 3),
        np.array([to_fit_frame(pend[k][0].fitf, pend[k][0].bp_ray) for k in fitted]).reshape(-1, 3))
    est_of = dict(zip(fitted, ests))
    for k, ((d, i), fit) in enumerate(zip(pend, fits)):
        p = d.results[i]
        t, iso = p.isovalue, p.iso
        if not fit:
            d.results[i] = IsophoteEstimate(t, fit.reason, fit.detail, iso.points_uv, iso.closed)
            continue
        est = est_of[k]
        # (IsophoteEstimate's fields given in order: no keyword dicts, 1500 isophotes a real frame)
        if not est:
            d.results[i] = IsophoteEstimate(t, est.reason, est.detail, iso.points_uv, iso.closed, fit.conic,
                                            fit.ellipse, fit.residual_px, None, None, None, None, None, fit.cone)
            continue
        f = d.fitf  # the estimators ran in the fit frame (identity for a pinhole): rotate back
        if f.on_image_plane:
            paper, selected, axis = est.paper, est.paper_selected, est.cone_axis
        else:
            paper, selected, axis = to_camera(f, est.paper), to_camera(f, est.paper_selected), to_camera(f, est.cone_axis)
        d.results[i] = IsophoteEstimate(
            t, OK, "" if iso.closed else "open contour fitted (allow_open=True)", iso.points_uv, iso.closed,
            fit.conic, fit.ellipse, fit.residual_px, paper, selected, est.paper_selected_index, axis,
            est.eigenvalue_gap, fit.cone)
    # joint cone axes of the highlights with two or more good isophotes, in one batch
    multi = [d for d in dr if sum(r.status == OK for r in d.results) >= 2]
    if not multi:
        enclosed = _enclosed_counts(dr)
        return [_finish(d, None, enclosed.get(id(d))) if type(d) is _Draft else d for d in drafts]
    cones, group = [], []
    for g, d in enumerate(multi):
        for r in d.results:
            if r.ok:
                c = r.normalised_conic
                cones.append(c if d.fitf.on_image_plane else d.fitf.R @ c @ d.fitf.R.T)
                group.append(g)
    axes = joint_cone_axes(np.array(cones).reshape(-1, 3, 3), np.array(group, dtype=int),
                           np.array([to_fit_frame(d.fitf, d.bp_ray) for d in multi]).reshape(-1, 3))
    joint_of = {id(d): (to_camera(d.fitf, j) if not isinstance(j, Failure) else None)
                for d, j in zip(multi, axes)}
    enclosed = _enclosed_counts(dr)
    return [_finish(d, joint_of.get(id(d)), enclosed.get(id(d))) if type(d) is _Draft else d for d in drafts]


#: ``_Levels.of``'s normalisations as :func:`simtest.reconstruct._kernels.grown_isophotes` takes them.
_NORM_CODES = {Normalisation.AUTO: _kernels.NORM_AUTO, Normalisation.LOCAL: _kernels.NORM_LOCAL,
               Normalisation.BP: _kernels.NORM_BP, Normalisation.FULL_SCALE: _kernels.NORM_FULL_SCALE}


_NO_TAPS = np.ones(1)


def _grown_drafts(frame: _Frame, ks: list, bps: list, rois_of: dict, rings_of: dict, rays: np.ndarray,
                  frames_of: dict, saturated: list, others, own_rows: list) -> dict:
    """``k -> _Draft``: :func:`_estimate_one` (``grow=True``) of the candidates ``ks`` (their BPs
    ``bps[k]``, first ROIs, rings, rays and fit frames by ``k``; ``saturated`` and ``own_rows``
    in the order of ``ks``) of a frame smoothed once (``smoothed32``), by one compiled call for
    their ROIs' growth, levels and contour walks
    (:func:`simtest.reconstruct._kernels.grown_isophotes`, the same calls and arithmetic) and
    the Python objects from its results: the same drafts, without the Python loop's 40 us a
    candidate (a third of the banner's 448 fitted candidates' extraction). The ROIs' values are
    slices of the frame's smoothing (``smoothed32``) or, where the frame is not smoothed, of its
    float64 luma (``luma_frame``); on any other frame the result is empty, as it is for a
    candidate the call leaves (a BP outside its ROI, a cut that only the extraction can tell)."""
    if not ks:
        return {}
    if frame.smoothed32 is not None and frame.smooth_sigma_px > 0:
        # the frame's smoothing; the first rings given, a grown ROI's computed
        # (the rings only where the normalisation reads them: "auto" and "local")
        sm, own_ring = frame.smoothed32, False
        rings = [np.nan if rings_of[k] is None else rings_of[k] for k in ks]
        if frame.settings.normalise in (Normalisation.AUTO, Normalisation.LOCAL) and any(
                rings_of[k] is None for k in ks):
            return {}
    elif frame.luma_frame is not None and not frame.smooth_sigma_px > 0 and frame.luma_frame.dtype == np.float64:
        # a frame not smoothed: its luma; every ring the region's own border median
        sm, own_ring, rings = frame.luma_frame, True, [np.nan] * len(ks)  # (and no kernel read)
    elif frame.luma_frame32 is not None and not frame.smooth_sigma_px > 0:
        # a frame with few highlights, not smoothed: its float32 luma (the float64 luma of each ROI
        # to float32 rounding, 6e-8 relative; the clean bench frame's ten _estimate_one calls
        # cost 1.2 ms)
        sm, own_ring, rings = frame.luma_frame32, True, [np.nan] * len(ks)
    else:
        return {}
    isovalues = frame.settings.isovalues
    order = sorted(range(len(isovalues)), key=lambda i: isovalues[i])
    done, rr, near, scale, offset, code, inside, sides, start, count, pts = _kernels.grown_isophotes(
        sm, frame.img3, *_LUMA_W, _NO_TAPS if own_ring else frame.kernel,
        np.array([tuple(rois_of[k]) for k in ks], np.int64).reshape(-1, 4),
        np.array([bps[k] for k in ks], np.float64).reshape(-1, 2), np.array(rings, np.float64), own_ring,
        np.array([isovalues[i] for i in order], np.float64), _NORM_CODES[frame.settings.normalise],
        float(AUTO_LOCAL_BACKGROUND_REL), float(frame.full_scale), ROI_MAX_GROWTHS, float(ROI_GROWTH_FACTOR))
    shape = frame.img.shape
    out = {}
    rows = zip(ks, done.tolist(), rr.tolist(), near.tolist(), scale.tolist(), offset.tolist(), code.tolist(),
               inside.tolist(), sides.tolist(), start.tolist(), count.tolist(), saturated, own_rows)
    for k, ok, box, i_bp, sc, off, codes, ins, sds, st, cn, sat, own in rows:
        if not ok:
            continue
        roi = Roi(*box)
        bp_uv = bps[k]
        levels = _Levels(sc, off)
        region = None
        results: list = [None] * len(isovalues)
        for q, i in enumerate(order):
            t = isovalues[i]
            level = levels.level(t)
            if codes[q] == _kernels.CLOSED and ins[q] and i_bp > level:
                # a closed walk around the BP, above its level: the isophote _one_isophote makes
                # of it (_extract's first case), without the region's checks (most of a real
                # frame's 1500 isophotes)
                uv = pts[st[q]:st[q] + cn[q]]
                results[i] = _Pending(t, Isophote(uv, float(level), True, False, False)) \
                    if len(uv) >= MIN_CONTOUR_POINTS else IsophoteEstimate(
                        t, "too_few_points", f"{len(uv)} contour points < {MIN_CONTOUR_POINTS}", uv, True)
                continue
            if region is None:
                region = _Region(sm[roi.row0:roi.row1, roi.col0:roi.col1], roi, shape, bp_uv,
                                 int(round(float(bp_uv[1]) - roi.row0)), int(round(float(bp_uv[0]) - roi.col0)),
                                 i_bp)
            walked = None if codes[q] == _kernels.NOT_WALKED else \
                (codes[q], pts[st[q]:st[q] + cn[q]], ins[q], tuple(sds[q]))
            results[i] = _one_isophote(frame, region, levels, t, walked)[0]
        out[k] = _Draft(bp_uv, i_bp, sat, roi, rays[k], frames_of[k], results, others, own)
    return out


def _enclosed_counts(drafts: list) -> dict:
    """``id(draft) -> n``: how many other BPs the closed ok primary isophote of each draft whose
    other BPs are a frame's sorted array (``_SortedBps``) encloses, in one compiled call
    (:func:`simtest.reconstruct._kernels.count_enclosed_sorted_many`: the counts of
    ``count_enclosed_sorted`` one draft at a time). The drafts not counted here are counted by
    :func:`_finish` itself."""
    todo = [d for d in drafts if isinstance(d.other_bps, _SortedBps) and d.results[0].status == OK
            and d.results[0].closed and len(d.other_bps) > (d.own_bp >= 0)]
    if not todo:
        return {}
    others = todo[0].other_bps
    if any(d.other_bps is not others for d in todo):
        return {}
    polys = [d.results[0].points_uv for d in todo]
    counts = np.array([len(p) for p in polys], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_in = _kernels.count_enclosed_sorted_many(
        np.ascontiguousarray(np.concatenate(polys, axis=0), dtype=np.float64), starts, counts, others.uv,
        others.u, np.array([d.own_bp for d in todo], dtype=np.int64))
    return dict(zip(map(id, todo), n_in.tolist()))


def _is_gray(img: np.ndarray) -> bool:
    """:func:`simtest.reconstruct._kernels.is_gray` of an (H, W, C >= 3) image, by
    :func:`~simtest.reconstruct._kernels.is_gray_packed` where the image is a C-contiguous 8- or
    16-bit RGB one (its rows packed, half the time)."""
    if img.shape[2] == 3 and img.dtype.type in (np.uint8, np.uint16) and img.flags.c_contiguous:
        return bool(_kernels.is_gray_packed(img.reshape(img.shape[0], -1)))
    return bool(_kernels.is_gray(img))


def _colour_luma32(img: np.ndarray, grey: bool | None = None) -> np.ndarray | None:
    """The luma of a colour 8- or 16-bit RGB frame in float32 (H, W), read-only
    (:func:`simtest.reconstruct._kernels.luma_rgb32`); None for any other frame (single-channel,
    gray (R = G = B), float, RGBA). ``grey``: whether R = G = B, where the caller knows (else
    tested here, for a frame :func:`~simtest.reconstruct.detect.colour_luma32` could take)."""
    if grey is None:
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype.type not in (np.uint8, np.uint16):
            return None
        grey = _is_gray(img)
    return colour_luma32(img, grey)


def _luma32(img: np.ndarray) -> np.ndarray:
    """:func:`simtest.reconstruct._kernels.luma_rgb32` of an (H, W, 3) image
    (:func:`~simtest.reconstruct.detect.compiled_luma` in float32)."""
    return compiled_luma(img, np.float32)


def _frame_luma_smoothing(img: np.ndarray, detection_smoothed: np.ndarray, sigma: float,
                          luma32: np.ndarray | None = None,
                          detection_luma32: np.ndarray | None = None) -> np.ndarray:
    """The whole frame's luma smoothed once (float32, read-only): detection's smoothing where
    detection smoothed the luma itself (a single-channel, gray (R = G = B) or float image, or a
    colour frame's unrounded luma, ``detection_luma32``: ``Detection.luma32``, which ``luma32``
    then is), else the unrounded luma (:func:`simtest.reconstruct._kernels.luma_rgb32`;
    ``luma32`` where the caller has it, :func:`_colour_luma32`) smoothed as detection smooths
    (an 8-bit frame's OpenCV gray is rounded to whole levels, which moves contours)."""
    if luma32 is not None and luma32 is detection_luma32:
        return detection_smoothed
    if luma32 is not None:
        src = luma32
    elif img.ndim == 2 or img.dtype.kind == "f" or _is_gray(img):
        return detection_smoothed
    else:
        src = _luma32(img) if img.dtype.type in (np.uint8, np.uint16) else \
            luma(img).astype(np.float32)
    out = cv2.GaussianBlur(src, (0, 0), float(sigma), borderType=cv2.BORDER_REFLECT)
    out.setflags(write=False)
    return out


class _SortedBps:
    """A frame's BPs (k, 2) sorted by u, and their u (k,) contiguous, for the ``merged`` test."""

    __slots__ = ("uv", "u")

    def __init__(self, uv: np.ndarray):
        self.uv = uv
        self.u = np.ascontiguousarray(uv[:, 0])

    def __len__(self) -> int:
        return len(self.uv)


def _finish(d: _Draft, joint, enclosed: int | None = None) -> SpecularityEstimate:
    """The estimate of a completed draft: the primary isophote's status, ``merged`` when that
    closed isophote encloses another candidate's BP (``enclosed``: how many, where
    :func:`_enclosed_counts` counted them)."""
    primary = d.results[0]
    status, detail = primary.status, primary.detail
    if status == OK and primary.closed and len(d.other_bps) > (d.own_bp >= 0):
        # the other BPs in the isophote's bounding box, tested even-odd (polygon_contains)
        if enclosed is not None:
            n_in = enclosed
        elif isinstance(d.other_bps, _SortedBps):
            n_in = int(_kernels.count_enclosed_sorted(primary.points_uv, d.other_bps.uv, d.other_bps.u,
                                                      d.own_bp))
        else:
            others = np.asarray(d.other_bps, dtype=np.float64).reshape(-1, 2)
            n_in = int(_kernels.count_enclosed(primary.points_uv, others, d.own_bp))
        if n_in:
            status, detail = "merged", f"the isophote at t = {primary.isovalue} encloses {n_in} other BP(s)"
    return SpecularityEstimate(d.bp_uv, d.i_bp, d.saturated, d.roi, status, detail, d.bp_ray,
                               tuple(d.results), joint)


def _initial_roi(cand, bp_uv, threshold, frame: _Frame) -> Roi:
    """ROI expected to hold the lowest isophote, from the size of the bright component.

    Model: a Gaussian-like lobe I = P exp(-r^2 / (2 s^2)) has radius ``s sqrt(2 ln(P / L))`` at
    level L, so the isophote at level ``t P`` is ``sqrt(ln(1/t) / ln(P / threshold))`` times the
    component (clamped to [1, 8]; a clipped highlight makes this an over-estimate). Too small an
    ROI is grown by the pipeline; this only saves the retries.
    """
    t_min = min(frame.settings.isovalues)
    if cand.level is not None:
        threshold = cand.level  # this component's own detection level (detection="local_peak")
    peak = max(cand.peak, threshold * (1 + 1e-6), _TINY)
    full = frame.settings.normalise == Normalisation.FULL_SCALE
    level = t_min * (frame.full_scale if full else peak)
    num = np.log(peak / level) if level > 0 else 1.0
    den = np.log(peak / threshold) if threshold > 0 else 1.0
    ratio = min(max(float(np.sqrt(max(num, 0.0) / max(den, 1e-6))), 1.0), 8.0)
    radius = max(cand.bbox.shape) / 2.0
    return Roi.around(bp_uv, 1.2 * ratio * radius + 4.0, frame.img.shape)


def _first_rings(frame: _Frame, rois: list[Roi]) -> list:
    """Each ROI's smoothed border median (``_Levels.of``'s ring) in one compiled call
    (:func:`simtest.reconstruct._kernels.smoothed_border_medians`: each ROI's
    ``smoothed_border_median``), where the frame's ROIs read them (smoothed once, normalised
    ``auto`` or ``local``); else None for each."""
    if not rois or frame.smoothed32 is None or not frame.smooth_sigma_px > 0 or \
            frame.settings.normalise not in (Normalisation.AUTO, Normalisation.LOCAL):
        return [None] * len(rois)
    rr = np.array(rois, dtype=np.int64).reshape(-1, 4)
    return _kernels.smoothed_border_medians(frame.img3, *_LUMA_W, rr, frame.kernel).tolist()


def _initial_rois(cands: list, bps_uv: np.ndarray, threshold, frame: _Frame) -> list[Roi]:
    """:func:`_initial_roi` of many candidates (BPs ``bps_uv`` (k, 2)) in one batch of numpy
    calls (the same formulas elementwise; a real frame has hundreds)."""
    if not cands:
        return []
    t_min = min(frame.settings.isovalues)
    thr = np.array([threshold if c.level is None else c.level for c in cands], dtype=np.float64)
    peak = np.maximum(np.maximum(np.array([c.peak for c in cands], dtype=np.float64), thr * (1 + 1e-6)), _TINY)
    full = frame.settings.normalise == Normalisation.FULL_SCALE
    level = t_min * (frame.full_scale if full else peak)
    with np.errstate(divide="ignore", invalid="ignore"):
        num = np.where(level > 0, np.log(peak / np.where(level > 0, level, 1.0)), 1.0)
        den = np.where(thr > 0, np.log(peak / np.where(thr > 0, thr, 1.0)), 1.0)
    ratio = np.minimum(np.maximum(np.sqrt(np.maximum(num, 0.0) / np.maximum(den, 1e-6)), 1.0), 8.0)
    radius = np.array([max(c.bbox.row1 - c.bbox.row0, c.bbox.col1 - c.bbox.col0) for c in cands],
                      dtype=np.float64) / 2.0
    hs = 1.2 * ratio * radius + 4.0
    h, w = frame.img.shape[:2]
    u, v = bps_uv[:, 0], bps_uv[:, 1]  # Roi.around, elementwise
    rows = np.stack([np.maximum(0, np.floor(v - hs)), np.minimum(h, np.ceil(v + hs) + 1),
                     np.maximum(0, np.floor(u - hs)), np.minimum(w, np.ceil(u + hs) + 1)], axis=1).astype(np.int64)
    return [Roi(*r) for r in rows.tolist()]


# ------------------------------------------------------------------------------------------------
# public API


def reconstruct_roi(
    image,
    K,
    isovalues: float | Sequence[float] | None = None,
    *,
    bp_uv=None,
    roi=None,
    dist_coeffs=None,
    settings: ReconSettings | None = None,
    **options,
) -> SpecularityEstimate:
    """Reconstruct the normal of one known highlight.

    Parameters
    ----------
    image : ndarray of shape (H, W), (H, W, 3) or (H, W, 4)
        uint8, uint16 or float image, RGB.
    K : CameraModel or array_like of shape (3, 3)
        The camera: any :class:`~simtest.geometry.cameras.CameraModel` (pinhole, fisheye,
        omnidirectional), or pinhole intrinsics K (pixel centres at integer coordinates).
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is the primary. Default those of ``settings``
        (``ReconSettings().isovalues = (0.1,)``).
    bp_uv : array_like of shape (2,), optional
        Brightest point (u, v) px; default the brightest pixel of the ROI (sub-pixel refined), or
        the centroid of its saturated plateau.
    roi : (row0, row1, col0, col1), optional
        Half-open array-index region searched; default the whole image. Not grown.
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients of a pinhole K (not with a camera model, which holds its
        own); contour points and BP are mapped to rays through them.
    settings : ReconSettings, optional
        The reconstruction settings (default ``ReconSettings()``).
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change (``normalise``,
        ``allow_open``, ``smooth_sigma_px``, ``full_scale``, ``saturation_level``; the detection
        limits are not used here).

    Returns
    -------
    SpecularityEstimate
        Normals are unit vectors in the OpenCV camera frame facing the camera; a highlight that
        cannot be reconstructed has a status from :data:`~simtest.reconstruct.failures.REASONS`
        and None normals.

    Raises
    ------
    ValueError
        Bad image, K, ROI, BP or dist_coeffs, or a bad or unknown setting.
    """
    settings = ReconSettings.make(settings, isovalues, **options)
    return _complete([_roi_draft(image, K, bp_uv, roi, dist_coeffs, settings)])[0]


def _roi_draft(image, K, bp_uv, roi, dist_coeffs, settings: ReconSettings, cameras: dict | None = None):
    """Phase one of :func:`reconstruct_roi` (checks, BP, isophotes) for :func:`_complete`.

    ``cameras``: pinhole cameras already built, by the bytes of their K (a batch whose items share
    one K builds and validates it once; the same camera, the same results)."""
    if cameras is not None and dist_coeffs is None and not isinstance(K, CameraModel):
        k = np.asarray(K)
        if k.shape == (3, 3) and k.dtype.kind in "fiu":
            key = k.astype(np.float64).tobytes()
            if key not in cameras:
                cameras[key] = as_camera(K)
            K = cameras[key]
    frame = _Frame.make(image, K, dist_coeffs, settings)
    img = frame.img
    roi = Roi(0, img.shape[0], 0, img.shape[1]) if roi is None else Roi.coerce(roi, img.shape)
    if bp_uv is None:
        bp, saturated = _find_bp(img, roi, frame.saturation_level)
    else:
        bp = np.asarray(bp_uv, dtype=np.float64).reshape(-1)
        if bp.shape != (2,) or not np.isfinite(bp).all():
            raise ValueError(f"bp_uv must be 2 finite numbers (u, v), got {bp_uv!r}")
        r, c = round(float(bp[1])), round(float(bp[0]))  # np.rint(uv_to_rc(bp)): half to even
        if not (roi.row0 <= r < roi.row1 and roi.col0 <= c < roi.col1):
            raise ValueError(f"bp_uv = {bp.tolist()} lies outside the ROI {tuple(roi)}")
        saturated = False
    return _estimate_one(frame, bp, roi, saturated=saturated, grow=False)


@_gc_paused()  # thousands of small objects, no cycles (see _gc_paused)
def reconstruct_rois(items, isovalues: float | Sequence[float] | None = None, *,
                     settings: ReconSettings | None = None, **options) -> list[SpecularityEstimate]:
    """:func:`reconstruct_roi` of many known highlights, their fits batched.

    Parameters
    ----------
    items : iterable of tuple
        ``(image, K, bp_uv, roi)`` per highlight, each as the arguments of :func:`reconstruct_roi`
        of those names (``bp_uv`` and ``roi`` may be None). Consumed one at a time: an image is
        released once its isophotes are extracted, so a generator of simulated images keeps
        memory flat.
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is the primary. Default those of ``settings``.
    settings : ReconSettings, optional
        The settings of every item (default ``ReconSettings()``).
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change.

    Returns
    -------
    list of SpecularityEstimate
        One per item, in order: bit for bit what ``reconstruct_roi`` returns for each alone (the
        batched fits and estimators compute each highlight from its own numbers only;
        ``tests/test_pipeline.py`` checks it).

    Raises
    ------
    ValueError
        As :func:`reconstruct_roi`, for the first bad item.

    Notes
    -----
    The isophotes of every item are extracted first; then all their ellipse fits
    (:func:`~simtest.reconstruct.fit.fit_ellipses`), estimators
    (:func:`~simtest.reconstruct.estimators.estimate_from_conics`) and joint axes run in one batch
    of numpy calls, whose fixed cost is shared by the items (the harness' paper protocol runs its
    realisations through here).
    """
    settings = ReconSettings.make(settings, isovalues, **options)
    cameras: dict = {}
    return _complete([_roi_draft(image, K, bp_uv, roi, None, settings, cameras) for image, K, bp_uv, roi in items])


#: The name this module gave :class:`~simtest.reconstruct.result.Reconstruction` first.
Estimates = Reconstruction


@_gc_paused()  # thousands of small objects, no cycles (see _gc_paused)
@shared_passes()  # the verifier's frame-wide passes, once for the BP checks and the verdict
def reconstruct(
    image,
    K,
    isovalues: float | Sequence[float] | None = None,
    *,
    dist_coeffs=None,
    roi=None,
    settings: ReconSettings | None = None,
    lights=None,
    **options,
) -> Reconstruction:
    """Detect every specular highlight of an image and estimate its normal.

    Parameters
    ----------
    image : ndarray of shape (H, W), (H, W, 3) or (H, W, 4)
        uint8, uint16 or float image, RGB.
    K : CameraModel or array_like of shape (3, 3)
        The camera model, or pinhole intrinsics (pixel centres at integer coordinates).
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is primary. Default those of ``settings``
        (``ReconSettings.for_frames()``: 0.7 and 0.85 of the highlight's height above its local
        background).
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients of a pinhole K (not with a camera model).
    roi : (row0, row1, col0, col1), optional
        Restrict detection to this region (array indices, half-open).
    settings : ReconSettings, optional
        The reconstruction settings; default :meth:`ReconSettings.for_frames` (the defaults for
        whole frames: detection relative to local peaks, smoothing chosen from the noise,
        ``normalise="auto"``). The paper's settings are ``ReconSettings()``.
    lights : LightRig, optional
        The scope's rig: another guide's highlight is expected, not a cluster (:mod:`~simtest.reconstruct.rig_pairs`).
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change: ``normalise``,
        ``allow_open``, ``smooth_sigma_px`` (applies to detection too; None: from the noise),
        ``detection``, ``peak_rel`` and the detection limits ``brightness_rel``, ``full_scale``,
        ``saturation_level``, ``min_area_px`` (see
        :func:`~simtest.reconstruct.detect.detect_specularities`).

    Returns
    -------
    Reconstruction
        A list of SpecularityEstimate, one per examined candidate highlight, accepted or rejected
        (with ``n_components`` and ``n_unexamined``: the components detection found and those
        ``max_candidates`` left out; rejected ones carry the detection
        reason as status and no isophotes), brightest first. Empty if there is no candidate.
        Tables: ``.bp_px``, ``.statuses``, ``.normals()``, ``.to_arrow()``, ``.to_json()``.

    Raises
    ------
    ValueError
        Bad image, K, ROI or dist_coeffs, or a bad or unknown setting.

    Examples
    --------
    Each estimate holds the BP (u, v) in px and normals in the OpenCV camera frame::

        ests = reconstruct(image, K, [0.1, 0.3])
        for e in ests:
            if e.ok:
                print(e.bp_px, e.cone_axis, e.normals_paper)
    """
    settings = ReconSettings.make(settings, isovalues, frames=True, **options)
    img = validate_image(image)
    r = Roi(0, img.shape[0], 0, img.shape[1]) if roi is None else Roi.coerce(roi, img.shape)
    frame = _Frame.make(img, K, dist_coeffs, settings, noise_roi=r)
    sub = img[r.slices]
    det = detect_specularities(
        sub, brightness_rel=settings.brightness_rel, full_scale=frame.full_scale,
        saturation_level=settings.saturation_level, min_area_px=settings.min_area_px,
        smooth_sigma_px=frame.smooth_sigma_px, method=settings.detection,
        peak_rel=settings.peak_rel, max_candidates=settings.max_candidates,
    )
    many = sum(c.status == OK for c in det.candidates) >= LUMA_FRAME_MIN_HIGHLIGHTS
    sliced = many and det.smoothed is not None and det.smoothed.shape == img.shape[:2]
    if sliced or (settings.verify and not many):
        # the colour frame's float32 luma, for the frame's smoothing and the verifier (which reads
        # for_many_highlights' float64 luma where computed) (detection's answer where it asked)
        grey = img.ndim == 3 and img.shape[2] >= 3 and (
            det.grey if det.grey is not None and sub.shape == img.shape else bool(_is_gray(img)))
        # (detection's own where it smoothed this frame's luma: the same values)
        frame = replace(frame, luma32=None if grey else det.luma32 if (det.luma32 is not None and sub.shape == img.shape)
                        else _colour_luma32(img, False), grey=grey)
    if not many and sub.shape == img.shape and frame.smooth_sigma_px > 0:
        # few ROIs, each smoothed alone: in float32 from the frame's luma where it is at hand (the
        # colour frame's float32 luma, a gray frame's channel, a single-channel 8- or 16-bit frame)
        if frame.luma32 is not None:
            frame = replace(frame, roi_luma=frame.luma32)
        elif frame.grey and det.gray is not None and det.gray.dtype == np.uint8 and det.gray.shape == img.shape[:2]:
            frame = replace(frame, roi_luma=det.gray)
        elif img.ndim == 2 and img.dtype.type in (np.uint8, np.uint16):
            frame = replace(frame, roi_luma=img)
    elif not many and sub.shape == img.shape and not frame.smooth_sigma_px > 0:
        # few ROIs of a frame not smoothed: contoured by the compiled walks in its float32 luma
        # (_grown_drafts), at hand or one conversion of detection's gray away
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
    shift = np.array([r.col0, r.row0], dtype=np.float64)
    # every candidate's BP in the image, in one addition (each estimate's BP is a row of it)
    bps_arr = np.array([c.bp_uv for c in det.candidates], dtype=np.float64).reshape(-1, 2) + shift
    bps = list(bps_arr)
    # BPs another highlight's isophote must not enclose (``merged``): all but the too small (noise)
    keep = np.array([c.status != "too_small" for c in det.candidates], dtype=bool)
    # sorted by u, so that each isophote tests only the BPs in its u range (count_enclosed_sorted)
    kept = np.flatnonzero(keep)
    order = np.argsort(bps_arr[kept, 0], kind="stable")
    others = _SortedBps(np.ascontiguousarray(bps_arr[kept][order]))
    row_in_others = np.full(len(keep), -1, dtype=np.int64)
    row_in_others[kept[order]] = np.arange(len(kept))
    # every candidate's BP ray, and the fit frames of the accepted ones, in one call of the model
    rays = frame.bp_rays(bps_arr)
    has_ray = np.isfinite(rays).all(axis=1)
    fitted = has_ray & np.array([c.status == OK for c in det.candidates], dtype=bool)
    whole = sub.shape == img.shape
    verifier = None
    if settings.verify:
        # the verifier's luma and noise, and its checks that read only the BP (colour, height)
        # before any isophote: a candidate that fails them is not_specular whatever its fit, and
        # is neither contoured nor fitted (issue 41; a third of a real frame's candidates)
        verifier = _verifier_inputs(frame, det.gray if whole else None, frame.noise if whole else None)
        gray_v, grey_v, noise_v = verifier
        if whole and det.half is not None and gray_v is det.gray:
            # the verifier's reduced opening from detection's 2 x 2 means of the same gray
            seed_opening(gray_v, background_side_px(gray_v.shape), det.half)
        fk = np.flatnonzero(fitted)
        sat = np.array([det.candidates[k].saturated for k in fk.tolist()], dtype=bool)
        early = {k: d for k, d in zip(fk.tolist(), bp_checks(frame.img, gray_v, bps_arr[fk], sat,
                                                             full_scale=frame.full_scale, noise=noise_v,
                                                             grey=grey_v)) if d is not None}
        fitted[list(early)] = False
    else:
        early = {}
    fk = np.flatnonzero(fitted)
    frames_of = dict(zip(fk.tolist(), fit_frames(frame.camera, -rays[fitted])))
    # the fitted candidates' first ROIs, in one batch of numpy calls
    rois_of = dict(zip(fk.tolist(), _initial_rois([det.candidates[k] for k in fk.tolist()], bps_arr[fk],
                                                  det.threshold, frame)))
    rings_of = dict(zip(fk.tolist(), _first_rings(frame, [rois_of[k] for k in fk.tolist()])))
    # a frame smoothed once: every fitted candidate's ROI growth, levels and contour walks in one
    # compiled call (_grown_drafts); those it leaves go through _estimate_one
    drafts = _grown_drafts(frame, fk.tolist(), bps, rois_of, rings_of, rays, frames_of,
                           [det.candidates[k].saturated for k in fk.tolist()], others,
                           [int(row_in_others[k]) if keep[k] else -1 for k in fk.tolist()])
    out = []
    # each candidate's ray a row of the rays (views made at once, as rays[k]), and whether it
    # has one, as Python objects: the loop below reads them for a real frame's thousands
    ray_rows, ray_ok = list(rays), has_ray.tolist()
    for k, cand in enumerate(det.candidates):
        bp = bps[k]
        if k in drafts:
            out.append(drafts[k])
            continue
        if cand.status != OK or k in early:
            roi_k = cand.roi if not (r.row0 or r.col0) else Roi(
                cand.roi.row0 + r.row0, cand.roi.row1 + r.row0, cand.roi.col0 + r.col0, cand.roi.col1 + r.col0)
            status, detail = ("not_specular", early[k]) if k in early else (cand.status, cand.detail)
            out.append(SpecularityEstimate(bp, cand.peak, cand.saturated, roi_k, status,
                                           detail, ray_rows[k] if ray_ok[k] else None, ()))
            continue
        roi_k = rois_of[k] if k in rois_of else _initial_roi(cand, bp, det.threshold, frame)
        out.append(_estimate_one(frame, bp, roi_k, saturated=cand.saturated, grow=True, other_bps=others,
                                 own_bp=int(row_in_others[k]) if keep[k] else -1, bp_ray=rays[k],
                                 fitf=frames_of.get(k), ring=rings_of.get(k)))
    done = _complete(out)
    if settings.verify and done:
        done = _verified(frame, done, verifier=verifier, lights=lights)
    return Reconstruction.of_frame(done, det, settings, frame.camera, img.shape)


def _verifier_inputs(frame: _Frame, native: np.ndarray | None = None,
                     noise: float | None = None) -> tuple[np.ndarray, bool, float]:
    """``(gray, grey, noise)``: the luma the verifier measures in (:func:`_verifier_luma`), whether
    it is the value of R, G and B alike, and its noise standard deviation.

    ``native`` is detection's unsmoothed gray of the whole frame (``Detection.gray``) and
    ``noise`` the noise measured on it (``_Frame.noise``), or None: measured again (also where
    the verifier measures in another luma than ``native``)."""
    # the frame's luma as the camera gave it (small glints beside a highlight survive no smoothing;
    # the checks weigh heights against its noise): detection's gray where it is the luma itself
    # (a single-channel frame, or R = G = B, where OpenCV's gray is the channel), else the float32
    # luma (the checks measure in float32)
    gray, grey = _verifier_luma(frame, native)
    if gray is not native:
        # a colour frame: OpenCV's gray, rounded to whole levels, carries the rounding's noise
        # (0.6 against 0.29 levels on a small colonoscope_plane render): measured on the luma
        noise = None
    return gray, grey, noise_sigma(gray) if noise is None else float(noise)


def _verified(frame: _Frame, ests: list[SpecularityEstimate], native: np.ndarray | None = None,
              noise: float | None = None, *, verifier: tuple | None = None, lights=None) -> list[SpecularityEstimate]:
    """The estimates with their confidence, and the fitted ones that fail a specularity check
    of :mod:`simtest.reconstruct.verify` with its reason as status (the fit is kept).

    ``native`` and ``noise`` as for :func:`_verifier_inputs`, or ``verifier``: its result,
    where the caller has it; ``lights`` the scope's rig (:func:`~simtest.reconstruct.verify.assess`)."""
    gray, grey, noise = _verifier_inputs(frame, native, noise) if verifier is None else verifier
    # only the estimates with isophotes can have a fit (a confidence) or be ok (a verdict); the
    # others (detection's rejections, the BP checks', most of a real frame's thousands) are
    # returned as they are: each estimate's evidence is measured from its own BP and region only
    fit = [e for e in ests if e.isophotes]
    if not fit:
        return list(ests)
    ev, res, inside = assess(frame.img, gray, fit, full_scale=frame.full_scale, noise=noise, grey=grey, camera=frame.camera, lights=lights)
    conf = confidence(ev, res).tolist()
    checks = verdict(ev, res, inside, only=[k for k, e in enumerate(fit) if e.ok])
    judged = {}
    floor = frame.settings.min_confidence
    for k, e in enumerate(fit):
        status, detail = (checks[k] if e.ok else (e.status, e.detail))
        fitted = math.isfinite(res[k])  # a confidence for the fitted candidates only
        if status == OK and fitted and conf[k] < floor:
            status, detail = "low_confidence", f"confidence {conf[k]:.3f} < min_confidence {floor:g}"
        judged[id(e)] = _replaced(e, status=status, detail=detail, confidence=conf[k] if fitted else None)
    return [judged.get(id(e), e) for e in ests]


def _verifier_luma(frame: _Frame, native: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The luma :func:`_verified` measures in (H, W), and whether it is the value of R, G and B
    alike: ``native`` (detection's gray) where it is the luma's values (a single-channel image,
    or an RGB one with R = G = B), the frame's luma where it was computed (float64, or a colour
    frame's float32 ``luma32``), else OpenCV's float32 luma of the frame (the verifier's arithmetic is float32: within a float32 rounding of the
    float64 luma, a third of its time)."""
    img = frame.img
    if native is not None and native.shape == img.shape[:2] and frame.luma32 is None:
        if img.ndim == 2:
            return native, False
        if img.shape[2] >= 3 and (frame.grey if frame.grey is not None else _is_gray(img)):
            return native, True
    if frame.luma_frame is not None:
        return frame.luma_frame, False
    if frame.luma32 is not None:  # a colour frame's (not gray: is_gray was asked)
        return frame.luma32, False
    if img.ndim == 3 and img.shape[2] == 3 and img.dtype.type in (np.uint8, np.uint16, np.float32):
        return cv2.cvtColor(img.astype(np.float32), cv2.COLOR_RGB2GRAY), False
    return luma(img), False


def _replaced(est: SpecularityEstimate, **changes) -> SpecularityEstimate:
    """``dataclasses.replace(est, **changes)`` for the fields of a :class:`SpecularityEstimate`
    (which has no ``__post_init__``), by copying its ``__dict__``: a fifth of the time, for the
    thousands of candidates of a real frame."""
    new = object.__new__(SpecularityEstimate)
    new.__dict__.update(est.__dict__)
    new.__dict__.update(changes)
    return new
