"""One pass of the reconstruction over a frame: detection, isophotes, estimators and checks, with the
background square the frame names (:mod:`~simtest.reconstruct.pipeline` runs it, and
:mod:`~simtest.reconstruct.broad_lobes` again on a wider square)."""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.assemble import SpecularityEstimate, _complete, _merge_guard, _replaced
from simtest.reconstruct.detect import detect_specularities
from simtest.reconstruct.failures import OK
from simtest.reconstruct.frame_prep import _Frame, _prepared
from simtest.reconstruct.frame_verify import _early_checks, _verified
from simtest.reconstruct.isophotes import _candidate_drafts
from simtest.reconstruct.rig_pairs import encloses_only_partners, estimate_wander_px

__all__ = ["detected", "frame_pass"]


def detected(frame: _Frame, sub: np.ndarray, background_px: int | None = None):
    """:func:`detect_specularities` of the frame's region ``sub`` with the frame's settings."""
    settings = frame.settings
    return detect_specularities(sub, brightness_rel=settings.brightness_rel, full_scale=frame.full_scale,
                                saturation_level=frame.saturation_level, min_area_px=settings.min_area_px,
                                smooth_sigma_px=frame.smooth_sigma_px, method=settings.detection,
                                peak_rel=settings.peak_rel, max_candidates=settings.max_candidates,
                                background_px=background_px)


def frame_pass(frame: _Frame, img: np.ndarray, r: Roi, lights, det=None, only: list[int] | None = None,
                again: tuple | None = None) -> tuple[list[SpecularityEstimate], object, tuple | None]:
    """``(estimates, detection, (prepared, verifier))``: detection, isophotes, estimators and checks of the
    frame's region ``r`` with the background square of ``frame.background_px``.

    ``det``: its detection, already made; ``only``: indices of the candidates to estimate (every
    candidate's BP guarding the isophotes against merges), the estimates being theirs; ``again``: an
    earlier pass's ``(prepared, verifier)`` of the same image, whose lumas and checks' inputs serve
    again. ``prepared`` is the frame made ready (:func:`~simtest.reconstruct.frame_prep._prepared`)
    and ``verifier`` the checks' ``(gray, grey, noise)`` (None without checks).
    """
    settings = frame.settings
    sub = img[r.slices]
    if det is None:
        det = detected(frame, sub, frame.background_px)
    whole = sub.shape == img.shape
    if again is None:
        frame, verifier = _prepared(frame, det, whole), None
    else:
        frame, verifier = dataclasses.replace(again[0], background_px=frame.background_px), again[1]
    # every candidate's BP in the image, in one addition (each estimate's BP is a row of it)
    bps_arr = np.array([c.bp_uv for c in det.candidates], dtype=np.float64).reshape(-1, 2) + \
        np.array([r.col0, r.row0], dtype=np.float64)
    others, keep, row_in_others = _merge_guard(det, bps_arr)
    if only is not None:
        det = dataclasses.replace(det, candidates=[det.candidates[i] for i in only])
        bps_arr, keep, row_in_others = bps_arr[only], keep[only], row_in_others[only]
    # every candidate's BP ray, and the fit frames of the accepted ones, in one call of the model
    rays = frame.bp_rays(bps_arr)
    has_ray = np.isfinite(rays).all(axis=1)
    fitted = has_ray & np.array([c.status == OK for c in det.candidates], dtype=bool)
    verifier, early, fitted = _early_checks(frame, det, bps_arr, fitted, whole, verifier, lights)
    done = _complete(_candidate_drafts(frame, det, r, bps_arr, rays, has_ray, fitted, early, others, keep,
                                       row_in_others))
    if lights is not None and lights.has_separate_lights:
        done = _rig_partners_not_merged(frame, done, lights, others.uv, [row_in_others[k] for k in early],
                                        row_in_others)
    if settings.verify and done:
        done = _verified(frame, done, verifier=verifier, lights=lights)
    return done, det, (frame, verifier)


def _rig_partners_not_merged(frame: _Frame, done: list, lights, others_uv: np.ndarray, refused_rows: list,
                             row_in_others: np.ndarray) -> list:
    """The estimates, each ``merged`` one whose isophote encloses only other guides' lobes where the rig puts
    them, or peaks the colour checks refused (rows of ``others_uv``), given back its isophote's status (ok).
    ``row_in_others``: each estimate's row of ``others_uv`` (-1: none); a BP with a closed isophote may lie
    its :func:`~simtest.reconstruct.rig_pairs.estimate_wander_px` further from the rig's curve."""
    if not any(e.status == "merged" for e in done):
        return done
    (refused := np.zeros(len(others_uv), bool))[[k for k in refused_rows if k >= 0]] = True
    wander = np.zeros(len(others_uv))
    for e, row in zip(done, row_in_others):
        if row >= 0:
            wander[row] = estimate_wander_px(e)
    return [_replaced(e, status=OK, detail="") if e.status == "merged" and e.primary is not None and e.primary.closed
            and encloses_only_partners(frame.camera, lights.positions, e.bp_px, e.primary.points_uv, others_uv,
                                       refused, wander)
            else e for e in done]
