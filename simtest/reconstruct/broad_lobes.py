"""Broad lobes: highlights wider than the local background's square, searched again on a wider one.

Rough tissue seen close gives specular lobes wider than the square over which local-peak detection
opens the frame (:data:`~simtest.decisions.BACKGROUND_DIV`): the opening then holds part of the lobe,
so its top-hat is cut and its colour read against its own shoulders. :func:`with_broad_lobes` looks
for such lobes on the reduced frame and measures them on a square
:data:`~simtest.decisions.BROAD_LOBE_SCALE` times wider.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simtest.decisions import BROAD_ISOPHOTE_REL, BROAD_LOBE_SCALE
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.detect import noise_sigma
from simtest.reconstruct.detect_pixels import background_side_px, interior_top, wide_lobe_boxes
from simtest.reconstruct.failures import OK
from simtest.reconstruct.frame_pass import detected, frame_pass
from simtest.reconstruct.frame_prep import _Frame
from simtest.reconstruct.light_fits import _offset_rig
from simtest.reconstruct.rig_lobes import splittable
from simtest.reconstruct.rig_pairs import box_wander_px, rig_twins
from simtest.reconstruct.verify import WEAK_TWIN, bp_checks

__all__ = ["with_broad_lobes"]


def _in_boxes(uv: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """bool (N, M): whether point (u, v) n lies in box m ``(row0, row1, col0, col1)`` (half-open)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    return ((uv[:, None, 0] >= boxes[:, 2]) & (uv[:, None, 0] < boxes[:, 3])
            & (uv[:, None, 1] >= boxes[:, 0]) & (uv[:, None, 1] < boxes[:, 1]))


def with_broad_lobes(frame: _Frame, img: np.ndarray, r: Roi, lights, done: list, det, again: tuple):
    """The estimates and detection of a frame with its broad lobes measured on a wider background.

    A lobe wider than the background square is taken in part for background: its top-hat is cut
    and its colour read against its own shoulders. The second look, in three steps:

    1. on the reduced frame (:func:`~simtest.reconstruct.detect_pixels.wide_lobe_boxes`), the
       components of the local-peak mask on a square :data:`~simtest.decisions.BROAD_LOBE_SCALE`
       times wider that are wider than the first square, whose core at the primary isovalue is at
       least :data:`~simtest.decisions.BROAD_ISOPHOTE_REL` of the first square across and whose box
       holds no candidate the first pass fitted (one whose colour and height passed: the first
       square measured it, and its verdict stands);
    2. of those, the ones whose brightest pixel passes the colour and height checks on the wider
       square (:func:`~simtest.reconstruct.verify.bp_checks`), under a rig of separate lights a weak white
       one for its rig twin as in the first pass; twins are looked at together, in one box;
    3. the region around each detected again on the wider square, and its accepted candidates wider than
       the first square (the narrower are the first pass's) in the box through every check. One that comes
       out ``ok`` (or, under a rig of separate lights, ``weak_twin`` or a status the rig's step splits,
       :func:`~simtest.reconstruct.rig_lobes.splittable`: the guides' lobes fused, or cut by the frame) with
       a primary isophote at least ``BROAD_ISOPHOTE_REL`` of the first
       square across (with no ellipse, a region narrower across than ``BROAD_LOBE_SCALE`` of the frame's
       own squares: wider is shading) replaces the estimates in its box.

    The verdicts decide, so a frame reconstructed without the checks keeps its first pass.

    Parameters
    ----------
    frame : _Frame
        The frame as :func:`~simtest.reconstruct.pipeline.reconstruct` made it (before detection).
    img : ndarray of shape (H, W[, C])
        The image.
    r : Roi
        The region detected, image px.
    lights : LightRig or None
        The scope's light rig.
    done : list of SpecularityEstimate
        The first pass's estimates (BPs in image px).
    det : Detection
        The first pass's detection of ``img[r]`` (``background_px``: its square, px).
    again : tuple
        The first pass's ``(prepared, verifier)`` (:func:`~simtest.reconstruct.frame_pass.frame_pass`).

    Returns
    -------
    (list of SpecularityEstimate, Detection)
        The estimates, brightest first, and the detection with the same candidates; ``done`` and
        ``det`` themselves where no broad lobe replaced any.
    """
    narrow = det.background_px
    side = int(BROAD_LOBE_SCALE * narrow)
    widest = BROAD_LOBE_SCALE * background_side_px(img.shape[:2])  # (without its clipped plateaus' widening)
    sub = img[r.slices]
    # the first pass's fitted candidates (their colour and height passed): a box holding one is left as it is
    held = np.array([e.bp_px for e in done if e.isophotes], np.float64).reshape(-1, 2) - [r.col0, r.row0]
    # a look on the reduced frame first: most frames have no broad lobe without a fitted candidate
    boxes = wide_lobe_boxes(det.gray, frame.full_scale, side, narrow, BROAD_ISOPHOTE_REL * narrow,
                            frame.settings.isovalues[0], peak_rel=frame.settings.peak_rel)
    boxes = boxes[~_in_boxes(held, boxes).any(axis=0)]
    if len(boxes):
        boxes = _twins_together(boxes, *_specular_tops(frame, sub, det.gray, boxes, side, again[1], lights,
                                                        (r.col0, r.row0)))
    wide_frame = dataclasses.replace(frame, background_px=side)
    # under a rig of separate lights a merged second look is kept too: two guides' broad lobes fused into one
    # region, which the rig's step splits where their luma dips between its fit's points (rig_lobes)
    rig = _offset_rig(lights)
    ests, cands, at = [], [], []
    for box in boxes:
        # the box and half a square around it, on the grid of the wider square's reduced frame
        crop = _aligned_crop(box, side // 2, 2 * max(1, side // 16), sub.shape[:2])
        wide = detected(frame, sub[crop.slices], side)
        # the crop's candidates no wider than the first square are the first pass's, its verdicts on them stand:
        # not estimated again, nor guarding the broad lobes' isophotes (a broad top's noise maxima are no BPs)
        wide = dataclasses.replace(wide, candidates=[c for c in wide.candidates if max(c.bbox.shape) > narrow])
        off = np.array([crop.row0, crop.row0, crop.col0, crop.col0])
        bx = np.array([[c.bbox.row0, c.bbox.row1, c.bbox.col0, c.bbox.col1] for c in wide.candidates],
                      np.int64).reshape(-1, 4) + off
        bp = np.array([c.bp_uv for c in wide.candidates], np.float64).reshape(-1, 2) + [crop.col0, crop.row0]
        # under a rig of separate lights, a region the frame's edge cuts where it holds its lobe's top (the guides'
        # lobes, fused or not, whose joint plane fit reads the pixels the frame holds: rig_lobes)
        cut = np.array([rig and c.status == "touches_border" and interior_top(det.gray, bp[k], bx[k])
                        for k, c in enumerate(wide.candidates)], dtype=bool)
        pick = np.flatnonzero((np.array([c.status == OK for c in wide.candidates], dtype=bool) | cut)
                              & _in_boxes(bp, box[None]).any(axis=1) & ~_in_boxes(held, bx).any(axis=0)).tolist()
        if not pick:
            continue
        region = Roi(r.row0 + crop.row0, r.row0 + crop.row1, r.col0 + crop.col0, r.col0 + crop.col1)
        got, _, _ = frame_pass(wide_frame, img, region, lights, det=wide, only=pick, again=again)
        for i, e in zip(pick, got):
            seen = any(np.array_equal(e.bp_px, x.bp_px) for x in ests)  # boxes that overlap find it twice
            # no ellipse: the region's narrower side, one lobe across the rig's baseline where two guides' lobes fuse
            ell = None if e.primary is None else e.primary.ellipse
            broad = (2.0 * max(ell.semi_axes) >= BROAD_ISOPHOTE_REL * narrow if ell is not None
                     else not e.ok and min(bx[i, 1] - bx[i, 0], bx[i, 3] - bx[i, 2]) < widest)
            # (det.gray: the region r's; a weak twin, ok where the rig's step confirms it)
            kept = e.ok or e.status == WEAK_TWIN or (rig and splittable(e, det.gray, (r.row0, r.col0)))
            if kept and not seen and (e.primary is not None or cut[i]) and broad:
                ests.append(e)
                cands.append(wide.candidates[i])
                at.append(bx[i] + [r.row0, r.row0, r.col0, r.col0])
    if not ests:
        return done, det
    kept = ~_in_boxes(np.array([e.bp_px for e in done], np.float64), np.array(at)).any(axis=1)
    ests = [e for e, k in zip(done, kept) if k] + ests
    cands = [c for c, k in zip(det.candidates, kept) if k] + cands
    order = sorted(range(len(ests)), key=lambda i: -ests[i].bp_intensity)
    return [ests[i] for i in order], dataclasses.replace(det, candidates=[cands[i] for i in order])


def _twins_together(boxes: np.ndarray, passed: np.ndarray, twins: np.ndarray) -> np.ndarray:
    """The ``boxes`` (N, 4) whose tops ``passed``, each group that ``twins`` (N, N) links as one box that holds
    them all: a weak top passes the crop's checks for its twin only where the crop holds both."""
    group = np.arange(len(boxes))
    for k, j in zip(*np.nonzero(twins)):
        group[group == group[j]] = group[k]
    out = []
    for g in np.unique(group[passed]).tolist():
        b = boxes[group == g]
        out.append([b[:, 0].min(), b[:, 1].max(), b[:, 2].min(), b[:, 3].max()])
    return np.array(out, boxes.dtype).reshape(-1, 4)


def _aligned_crop(box: np.ndarray, margin: int, grid: int, shape: tuple[int, int]) -> Roi:
    """The box ``(row0, row1, col0, col1)`` widened by ``margin`` px, its corners moved out to multiples
    of ``grid`` px and clipped to ``shape`` (H, W)."""
    r0, r1, c0, c1 = (int(v) for v in box)
    h, w = shape
    return Roi(max(0, (r0 - margin) // grid * grid), min(h, -(-(r1 + margin) // grid) * grid),
               max(0, (c0 - margin) // grid * grid), min(w, -(-(c1 + margin) // grid) * grid))


def _specular_tops(frame: _Frame, sub: np.ndarray, gray: np.ndarray, boxes: np.ndarray, side: int,
                   verifier: tuple, lights=None, origin=(0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """``(passed, twins)``: bool (N,), whether the brightest pixel of ``gray`` in each box ``(row0, row1, col0,
    col1)`` of ``sub`` passes the colour and height checks (:func:`~simtest.reconstruct.verify.bp_checks`) on a
    background square of ``side`` px; bool (N, N), ``twins[k, j]`` where box k's top, too weak alone, passes for
    box j's: a white top where the rig of separate ``lights`` puts another guide's highlight
    (:func:`~simtest.reconstruct.rig_pairs.rig_twins`; ``origin``: ``sub``'s (u, v) in the image).
    ``verifier``: the checks' ``(gray, grey, noise)`` of the frame."""
    bps = np.empty((len(boxes), 2), np.float64)
    for k, (r0, r1, c0, c1) in enumerate(boxes.tolist()):
        row, col = np.unravel_index(int(np.argmax(gray[r0:r1, c0:c1])), (r1 - r0, c1 - c0))
        bps[k] = c0 + col, r0 + row
    gray_v, grey_v, noise_v = verifier
    if gray_v.shape != sub.shape[:2]:  # a region of the frame: its own luma and noise
        gray_v, noise_v = gray, noise_sigma(gray)
    n, twins, links = len(bps), None, np.zeros((len(bps), len(bps)), bool)
    if lights is not None and lights.has_separate_lights and n > 1:
        wander = box_wander_px(bps, boxes)  # (as the first pass takes it from its region's box)
        at = bps + np.asarray(origin, np.float64)

        def twins(pool, which):
            for k in np.flatnonzero(which).tolist():
                for j in np.flatnonzero(pool).tolist():
                    links[k, j] = j != k and bool(rig_twins(frame.camera, lights.positions, at[[k, j]],
                                                            [False, True], wander[[k, j]], [True, False])[0])
            return links.any(axis=1)
    fails = bp_checks(sub, gray_v, bps, np.zeros(n, bool), full_scale=frame.full_scale, noise=noise_v,
                      grey=grey_v, response=frame.response, background_px=side, twins=twins)
    return np.array([f is None for f in fails], dtype=bool), links
