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
:func:`~simtest.reconstruct.estimators.joint_cone_axes`): a highlight gets the same bits as it
would alone, and a frame of hundreds of highlights pays the fixed cost of the calls once.
:func:`reconstruct_rois` does the same for many known highlights.
This module calls the stages in order: :mod:`~simtest.reconstruct.frame_prep`,
:mod:`~simtest.reconstruct.isophotes`, :mod:`~simtest.reconstruct.assemble`, :mod:`~simtest.reconstruct.frame_verify`.

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

import dataclasses

import ctypes
import functools
import gc
from contextlib import contextmanager
from collections.abc import Sequence

import numpy as np

from simtest.geometry.cameras import CameraModel
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.assemble import SpecularityEstimate, _complete, _merge_guard
from simtest.reconstruct.detect import detect_specularities, validate_image
from simtest.reconstruct.failures import OK
from simtest.reconstruct.frame_prep import _Frame, _prepared, as_camera
from simtest.reconstruct.frame_verify import _early_checks, _verified
from simtest.reconstruct.isophotes import RESOLVE_BATCH_ISOPHOTES, _candidate_drafts, _estimate_one, _find_bp, _resolve
from simtest.reconstruct.result import Reconstruction
from simtest.reconstruct.settings import ReconSettings
from simtest.reconstruct.verify import shared_passes


@contextmanager
def _gc_paused():
    """Python's cyclic garbage collector paused for a frame's work, then restored as it was
    (a context manager, and a decorator of :func:`reconstruct` and :func:`reconstruct_rois`).

    A frame with hundreds of highlights builds thousands of small result objects, none of them
    in a reference cycle; each allocation burst triggers collections, and every few of them is a
    full one over every object the process holds (about 170 000 after importing simtest: OpenCV,
    scikit-image, scipy). Nothing the pipeline allocates waits for the collector (no cycles),
    and a caller that had paused it keeps it paused.
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
    the kernel when freed, so that the next frame's arrays fault every page in afresh. With
    blocks up to :data:`MMAP_THRESHOLD_BYTES` taken from the heap and up to
    :data:`TRIM_THRESHOLD_BYTES` of free memory kept there, the pages stay mapped between frames;
    the process's resident memory stays at its peak (a few hundred MiB for 1350 x 1080 frames)
    instead of falling between them.
    Elsewhere (macOS, musl) nothing is changed.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) & bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


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


def _roi_draft(image, K, bp_uv, roi, dist_coeffs, settings: ReconSettings, cameras: dict | None = None,
               defer: list | None = None):
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
    return _estimate_one(frame, bp, roi, saturated=saturated, grow=False, defer=defer)


@_gc_paused()  # thousands of small objects, no cycles (see _gc_paused)
def reconstruct_rois(items, isovalues: float | Sequence[float] | None = None, *,
                     settings: ReconSettings | None = None, **options) -> list[SpecularityEstimate]:
    """:func:`reconstruct_roi` of many known highlights, their fits batched.

    Parameters
    ----------
    items : iterable of tuple
        ``(image, K, bp_uv, roi)`` per highlight, each as the arguments of :func:`reconstruct_roi`
        of those names (``bp_uv`` and ``roi`` may be None). Consumed one at a time: an image is
        released once its isophotes are contoured (in batches of
        :data:`~simtest.reconstruct.isophotes.RESOLVE_BATCH_ISOPHOTES`), so a generator of
        simulated images keeps memory flat.
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
    drafts, defer, done = [], [], 0
    for image, K, bp_uv, roi in items:
        drafts.append(_roi_draft(image, K, bp_uv, roi, None, settings, cameras, defer))
        if len(defer) >= RESOLVE_BATCH_ISOPHOTES:  # the contours of the items since the last batch
            _resolve(drafts[done:], defer)
            done = len(drafts)
    _resolve(drafts[done:], defer)
    return _complete(drafts)


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
    response=None,
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
    response : SensorResponse, optional
        The frame's tone curve (a camera file's ``"response"``), which the colour checks undo
        (:func:`~simtest.reconstruct.verify.frame_evidence`); None: a display-encoded (sRGB) frame.
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
    frame = frame if response is None else dataclasses.replace(frame, response=response)
    sub = img[r.slices]
    det = detect_specularities(
        sub, brightness_rel=settings.brightness_rel, full_scale=frame.full_scale,
        saturation_level=settings.saturation_level, min_area_px=settings.min_area_px,
        smooth_sigma_px=frame.smooth_sigma_px, method=settings.detection,
        peak_rel=settings.peak_rel, max_candidates=settings.max_candidates,
    )
    whole = sub.shape == img.shape
    frame = _prepared(frame, det, whole)
    # every candidate's BP in the image, in one addition (each estimate's BP is a row of it)
    bps_arr = np.array([c.bp_uv for c in det.candidates], dtype=np.float64).reshape(-1, 2) + \
        np.array([r.col0, r.row0], dtype=np.float64)
    others, keep, row_in_others = _merge_guard(det, bps_arr)
    # every candidate's BP ray, and the fit frames of the accepted ones, in one call of the model
    rays = frame.bp_rays(bps_arr)
    has_ray = np.isfinite(rays).all(axis=1)
    fitted = has_ray & np.array([c.status == OK for c in det.candidates], dtype=bool)
    verifier, early, fitted = _early_checks(frame, det, bps_arr, fitted, whole)
    done = _complete(_candidate_drafts(frame, det, r, bps_arr, rays, has_ray, fitted, early, others, keep,
                                       row_in_others))
    if settings.verify and done:
        done = _verified(frame, done, verifier=verifier, lights=lights)
    return Reconstruction.of_frame(done, det, settings, frame.camera, img.shape)
