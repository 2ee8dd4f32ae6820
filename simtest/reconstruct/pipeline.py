"""The reconstruction pipeline: image -> specular highlights -> isophote ellipses -> normals.

``reconstruct(image, K, isovalue)`` detects every highlight of an image and estimates one
:class:`SpecularityEstimate` per candidate; ``reconstruct_roi`` does one known highlight and
``reconstruct_rois`` many, their fits batched.

Per highlight (Makki and Bartoli [1]_, section 2.3): 1. normalise the intensities so that the BP is 1
(``normalise="bp"``, the paper's step 4), or relative to the ROI border's median b, contouring at
``b + t (I_bp - b)`` (``normalise="local"``, beyond the paper: the diffuse background of tissue is
often brighter than t I_bp); 2. extract the isophote at each isovalue t by marching squares [2]_,
growing the ROI while the lowest isophote is cut; 3. fit the isophote cone C' on the viewing rays
(:mod:`~simtest.reconstruct.cone_fit`, [3]_); 4. compute the estimators of
:mod:`~simtest.reconstruct.estimators` from C' [4]_ [5]_. Steps 3 and 4 run once per call for every
isophote, batched: a highlight gets the same bits as it would alone. The stages live in
:mod:`~simtest.reconstruct.frame_prep`, :mod:`~simtest.reconstruct.isophotes`,
:mod:`~simtest.reconstruct.assemble` and :mod:`~simtest.reconstruct.frame_verify`.

The *primary* isophote is the one at the first isovalue. Caller mistakes raise ValueError; a
highlight that cannot be reconstructed gets a status from :data:`simtest.reconstruct.failures.REASONS`
and None normals, never NaN. Pixel (u, v) = (column, row), centres at integers; ROIs are half-open
``(row0, row1, col0, col1)``; normals are unit vectors in the OpenCV camera frame facing the camera.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting".
.. [2] W. E. Lorensen, H. E. Cline, SIGGRAPH 1987. https://doi.org/10.1145/37402.37422
.. [3] A. Fitzgibbon, M. Pilu, R. B. Fisher, IEEE TPAMI 21(5), 1999. https://doi.org/10.1109/34.765658
.. [4] D. Forsyth et al., IEEE TPAMI 13(10), 1991, appendix A. https://doi.org/10.1109/34.99233
.. [5] dam410/LightModel, public MATLAB code, branch ``vanishing_line_paper_co`` (cone-axis estimator).
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import gc
from collections.abc import Sequence
from contextlib import contextmanager

import numpy as np

from simtest.geometry.cameras import CameraModel
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.assemble import SpecularityEstimate, _complete
from simtest.reconstruct.broad_lobes import with_broad_lobes
from simtest.reconstruct.detect import validate_image
from simtest.reconstruct.frame_pass import frame_pass
from simtest.reconstruct.frame_prep import _Frame, as_camera
from simtest.reconstruct.isophotes import RESOLVE_BATCH_ISOPHOTES, _Batches, _estimate_one, _find_bp
from simtest.reconstruct.result import Reconstruction
from simtest.reconstruct.settings import ReconSettings
from simtest.reconstruct.verify import shared_passes


@contextmanager
def _gc_paused():
    """Pause Python's cyclic garbage collector for a frame's work, then restore it as it was: a frame builds
    thousands of small objects in no reference cycle, and full collections over every object the process
    holds would only cost time."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


#: glibc's ``mallopt`` parameters (malloc.h): blocks up to MMAP_THRESHOLD_BYTES come from the heap (a 1350 x 1080
#: RGB frame's float64 copy, which its luma reads, is 33.4 MiB); up to TRIM_THRESHOLD_BYTES of free memory stays.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 64 << 20
TRIM_THRESHOLD_BYTES = 256 << 20


@functools.cache
def _keep_freed_memory() -> bool:
    """Have glibc keep freed arrays' memory for the next ones (once per process): a batch's or a frame's
    arrays are then not unmapped or trimmed and faulted in again. True if it took the settings; elsewhere
    (macOS, musl) nothing is changed.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) & bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def reconstruct_roi(image, K, isovalues: float | Sequence[float] | None = None, *, bp_uv=None, roi=None,
                    dist_coeffs=None, settings: ReconSettings | None = None, **options) -> SpecularityEstimate:
    """Reconstruct the normal of one known highlight.

    Parameters
    ----------
    image : ndarray of shape (H, W), (H, W, 3) or (H, W, 4)
        uint8, uint16 or float image, RGB.
    K : CameraModel or array_like of shape (3, 3)
        The camera model, or pinhole intrinsics K (pixel centres at integer coordinates).
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is the primary. Default those of ``settings``.
    bp_uv : array_like of shape (2,), optional
        Brightest point (u, v), px; default the ROI's brightest pixel (sub-pixel refined), or the
        centroid of its saturated plateau.
    roi : (row0, row1, col0, col1), optional
        Half-open array-index region searched; default the whole image. Not grown.
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients of a pinhole K (not with a camera model).
    settings : ReconSettings, optional
        The reconstruction settings (default ``ReconSettings()``).
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change.

    Returns
    -------
    SpecularityEstimate
        Unit normals in the OpenCV camera frame facing the camera, or a status from
        :data:`~simtest.reconstruct.failures.REASONS` and None normals.

    Raises
    ------
    ValueError
        Bad image, K, ROI, BP or dist_coeffs, or a bad or unknown setting.
    """
    settings = ReconSettings.make(settings, isovalues, **options)
    return _complete([_roi_draft(image, K, bp_uv, roi, dist_coeffs, settings)])[0]


def _roi_draft(image, K, bp_uv, roi, dist_coeffs, settings: ReconSettings, cameras: dict | None = None,
               defer: list | None = None):
    """Phase one of :func:`reconstruct_roi` (checks, BP, isophotes) for :func:`_complete`.

    ``cameras``: pinhole cameras already built, keyed by the bytes of their K.
    """
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
    return _estimate_one(frame, bp, roi, saturated=saturated, grow=False, defer=defer)


@_gc_paused()
def reconstruct_rois(items, isovalues: float | Sequence[float] | None = None, *,
                     settings: ReconSettings | None = None, **options) -> list[SpecularityEstimate]:
    """:func:`reconstruct_roi` of many known highlights, their fits batched.

    Parameters
    ----------
    items : iterable of tuple
        ``(image, K, bp_uv, roi)`` per highlight, as the arguments of :func:`reconstruct_roi`.
        Consumed one at a time: an image is released once its isophotes are contoured.
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is the primary. Default those of ``settings``.
    settings : ReconSettings, optional
        The settings of every item (default ``ReconSettings()``).
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change.

    Returns
    -------
    list of SpecularityEstimate
        One per item, in order, bit for bit what ``reconstruct_roi`` returns for each alone.

    Raises
    ------
    ValueError
        As :func:`reconstruct_roi`, for the first bad item.
    """
    _keep_freed_memory()
    settings = ReconSettings.make(settings, isovalues, **options)
    cameras: dict = {}
    batches = _Batches(RESOLVE_BATCH_ISOPHOTES)  # the contours of the items since the last batch
    for image, K, bp_uv, roi in items:
        batches.add(_roi_draft(image, K, bp_uv, roi, None, settings, cameras, batches.defer))
    batches.finish()
    return _complete(batches.made)


#: The first name of :class:`~simtest.reconstruct.result.Reconstruction`.
Estimates = Reconstruction


@_gc_paused()
@shared_passes()  # the verifier's frame-wide passes, once for the BP checks and the verdict
def reconstruct(image, K, isovalues: float | Sequence[float] | None = None, *, dist_coeffs=None, roi=None,
                settings: ReconSettings | None = None, lights=None, response=None, **options) -> Reconstruction:
    """Detect every specular highlight of an image and estimate its normal.

    Parameters
    ----------
    image : ndarray of shape (H, W), (H, W, 3) or (H, W, 4)
        uint8, uint16 or float image, RGB.
    K : CameraModel or array_like of shape (3, 3)
        The camera model, or pinhole intrinsics (pixel centres at integer coordinates).
    isovalues : float or sequence of float, optional
        Isovalue(s) t in (0, 1); the first is primary. Default those of ``settings``.
    dist_coeffs : array_like, optional
        OpenCV distortion coefficients of a pinhole K (not with a camera model).
    roi : (row0, row1, col0, col1), optional
        Restrict detection to this region (array indices, half-open).
    settings : ReconSettings, optional
        Default :meth:`ReconSettings.for_frames`; the paper's settings are ``ReconSettings()``.
    lights : LightRig, optional
        The scope's rig: another guide's highlight is expected, not a cluster (:mod:`~simtest.reconstruct.rig_pairs`).
    response : SensorResponse, optional
        The frame's tone curve, which the colour checks undo; None: a display-encoded (sRGB) frame.
    **options
        Fields of :class:`~simtest.reconstruct.settings.ReconSettings` to change (see also
        :func:`~simtest.reconstruct.detect.detect_specularities`).

    Returns
    -------
    Reconstruction
        One SpecularityEstimate per examined candidate, accepted or rejected (a rejected one carries
        the detection reason as status), brightest first; empty if there is no candidate.

    Raises
    ------
    ValueError
        Bad image, K, ROI or dist_coeffs, or a bad or unknown setting.
    """
    _keep_freed_memory()
    settings = ReconSettings.make(settings, isovalues, frames=True, **options)
    img = validate_image(image)
    r = Roi(0, img.shape[0], 0, img.shape[1]) if roi is None else Roi.coerce(roi, img.shape)
    frame = _Frame.make(img, K, dist_coeffs, settings, noise_roi=r)
    frame = frame if response is None else dataclasses.replace(frame, response=response)
    done, det, again = frame_pass(frame, img, r, lights)
    if again[1] is not None and settings.detection == "local_peak" and det.background_px:
        done, det = with_broad_lobes(frame, img, r, lights, done, det, again)
    return Reconstruction.of_frame(done, det, settings, frame.camera, img.shape)
