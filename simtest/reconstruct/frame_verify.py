"""The verifier's stage of a frame (:mod:`simtest.reconstruct.verify`): its checks of the BPs before any
isophote (:func:`_early_checks`), and the confidences and verdicts of the fitted estimates (:func:`_verified`)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from simtest.decisions import DEFAULT_MIN_CONFIDENCE, MIN_CONFIDENCE_UNMODELLED
from simtest.reconstruct.assemble import SpecularityEstimate, _replaced
from simtest.reconstruct.detect import background_side_px, luma, noise_sigma
from simtest.reconstruct.failures import OK
from simtest.reconstruct.frame_prep import _Frame, _is_gray
from simtest.reconstruct.rig_pairs import box_wander_px, rig_twins
from simtest.reconstruct.verify import WEAK_TWIN, assess, bp_checks, confidence, seed_opening, verdict


def _early_checks(frame: _Frame, det, bps_arr: np.ndarray, fitted: np.ndarray,
                  whole: bool, verifier: tuple | None = None, lights=None) -> tuple[tuple | None, dict, np.ndarray]:
    """``(verifier, early, fitted)``: the verifier's inputs (None without ``verify``; given: an earlier
    pass's of the same frame), the BP checks' ``k -> detail`` of the ``fitted`` candidates that fail
    (``not_specular``, neither contoured nor fitted), and ``fitted`` without them (cleared in place).
    Under a rig of separate ``lights`` a weak lobe with a twin passes (:meth:`Evidence.with_twins`), each
    BP's wander taken from its detected region's box.
    """
    if not frame.settings.verify:
        return None, {}, fitted
    given = verifier is not None
    if not given:
        verifier = _verifier_inputs(frame, det.gray if whole else None, frame.noise if whole else None)
    gray_v, grey_v, noise_v = verifier
    if not given and whole and det.half is not None and gray_v is det.gray:
        # the verifier's reduced opening from detection's 2 x 2 means of the same gray
        seed_opening(gray_v, frame.background_px or background_side_px(gray_v.shape), det.half)
    fk = np.flatnonzero(fitted)
    sat = np.array([det.candidates[k].saturated for k in fk.tolist()], dtype=bool)
    twins = None
    if lights is not None and lights.has_separate_lights and len(fk) > 1:
        cands = [det.candidates[k] for k in fk.tolist()]
        wander = box_wander_px([c.bp_uv for c in cands], [tuple(c.bbox) for c in cands])  # (detection's coordinates)
        bps_f = bps_arr[fk]

        def twins(pool, which):
            return rig_twins(frame.camera, lights.positions, bps_f, pool, wander, which)
    early = {k: d for k, d in zip(fk.tolist(), bp_checks(frame.img, gray_v, bps_arr[fk], sat,
                                                         full_scale=frame.full_scale, noise=noise_v,
                                                         grey=grey_v, response=frame.response,
                                                         background_px=frame.background_px, twins=twins))
             if d is not None}
    fitted[list(early)] = False
    return verifier, early, fitted


def _verifier_inputs(frame: _Frame, native: np.ndarray | None = None,
                     noise: float | None = None) -> tuple[np.ndarray, bool, float]:
    """``(gray, grey, noise)``: the luma the verifier measures in, whether R = G = B, and its noise
    standard deviation (``native``: detection's gray; ``noise`` measured on it, or None).
    """
    # the frame's unsmoothed luma (glints beside a highlight survive no smoothing)
    gray, grey = _verifier_luma(frame, native)
    if gray is not native:
        # a colour frame: OpenCV's gray, rounded to whole levels, carries the rounding's noise
        noise = None
    return gray, grey, noise_sigma(gray) if noise is None else float(noise)


def _verified(frame: _Frame, ests: list[SpecularityEstimate], *, verifier: tuple | None = None,
              lights=None) -> list[SpecularityEstimate]:
    """The estimates with their confidence, and the fitted ones that fail a check of
    :mod:`simtest.reconstruct.verify` with its reason as status (the fit kept).
    """
    gray, grey, noise = _verifier_inputs(frame) if verifier is None else verifier
    # only the estimates with isophotes can have a confidence or a verdict; the others stay as they are
    fit = [e for e in ests if e.isophotes]
    if not fit:
        return list(ests)
    ev, res, inside = assess(frame.img, gray, fit, full_scale=frame.full_scale, noise=noise, grey=grey,
                             camera=frame.camera, lights=lights, response=frame.response,
                             background_px=frame.background_px)
    conf = confidence(ev, res).tolist()
    checks = verdict(ev, res, inside, only=[k for k, e in enumerate(fit) if e.ok])
    judged = {}
    floor = frame.settings.min_confidence
    floor = default_min_confidence(frame.img, lights, grey) if floor is None else floor
    for k, e in enumerate(fit):
        status, detail = (checks[k] if e.ok else (e.status, e.detail))
        fitted = math.isfinite(res[k])  # a confidence for the fitted candidates only
        if status in (OK, WEAK_TWIN) and fitted and conf[k] < floor:
            status, detail = "low_confidence", f"confidence {conf[k]:.3f} < min_confidence {floor:g}"
        judged[id(e)] = _replaced(e, status=status, detail=detail, confidence=conf[k] if fitted else None)
    return [judged.get(id(e), e) for e in ests]


def default_min_confidence(image: np.ndarray, lights=None, grey: bool | None = None) -> float:
    """The default ``--min-confidence`` of a frame: :data:`~simtest.decisions.DEFAULT_MIN_CONFIDENCE` on a
    colour frame without a rig of separate lights (the frames the model was fitted on), else
    :data:`~simtest.decisions.MIN_CONFIDENCE_UNMODELLED`. ``grey``: whether R = G = B (None: looked at).
    """
    img = np.asarray(image)
    colour = img.ndim == 3 and img.shape[2] >= 3 and not (_is_gray(img) if grey is None else grey)
    rig = lights is not None and lights.has_separate_lights
    return DEFAULT_MIN_CONFIDENCE if colour and not rig else MIN_CONFIDENCE_UNMODELLED


def _verifier_luma(frame: _Frame, native: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """The luma :func:`_verified` measures in (H, W) and whether R = G = B: ``native`` where it is the
    luma's values, the frame's luma where computed, else OpenCV's float32 luma.
    """
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
