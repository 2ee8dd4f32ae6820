"""The isophotes of each highlight: its ROI's values and levels, the isophote at each isovalue, the ROI
grown while the lowest is cut (:func:`_estimate_one`, :func:`_grown_drafts`), and a frame's drafts
(:func:`_candidate_drafts`) for :func:`simtest.reconstruct.assemble._complete`."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from simtest.decisions import AUTO_LOCAL_BACKGROUND_REL, ROI_GROWTH_FACTOR, ROI_MAX_GROWTHS
from simtest.reconstruct._pixels import Roi, rc_to_uv
from simtest.reconstruct.assemble import IsophoteEstimate, SpecularityEstimate, _Draft, _Pending
from simtest.reconstruct.cone_fit import FitFrame, fit_frame, fit_frames
from simtest.reconstruct.detect import connected_components, luma, peak_uv
from simtest.reconstruct.failures import OK
from simtest.reconstruct.frame_prep import LUMA_FRAME_MIN_HIGHLIGHTS, _Frame, _smooth
from simtest.reconstruct.isophote import (MIN_CONTOUR_POINTS, _box_answer, _box_contours,
                                          _component_box, _cut_and_contour, _extract, _isophote_of, _region, _Region)
from simtest.reconstruct.marching import batch_contours
from simtest.reconstruct.settings import Normalisation

_TINY, _ONE_TAP = float(np.finfo(float).tiny), np.ones(1)

#: Isophotes ``reconstruct_rois`` contours in one batch (:class:`_Batches`): its items' images wait with them.
RESOLVE_BATCH_ISOPHOTES = 256
#: Fewer isophotes than this, in boxes of fewer px than the next, are contoured one by one.
RESOLVE_BATCH_MIN = 32
RESOLVE_BATCH_MIN_PX = 50_000
#: The most bytes of component boxes a frame's deferred isophotes hold before they are contoured (:class:`_Batches`):
#: at t = 0.1 of the BP (``--normalise bp``) a box can span much of the frame (731 boxes of 1.5 GB in all on the
#: 2240 x 840 banner). A box's contour is the same in any batch (``batch_contours``): this bounds memory only.
RESOLVE_PENDING_MAX_BYTES = 1 << 28


def _roi_values(frame: _Frame, roi: Roi, smooth_sigma_px: float) -> np.ndarray:
    """An ROI's intensities (h, w), float64 or float32 (read-only where a view): its luma,
    smoothed with its borders reflected."""
    if frame.smoothed32 is not None and smooth_sigma_px > 0:
        return frame.smoothed32[roi.slices]  # float32, read-only: read as it is
    if frame.roi_luma is not None and smooth_sigma_px > 0:
        # the ROI's luma smoothed alone in float32 (the float64 result to float32 rounding)
        return _smooth(frame.roi_luma[roi.slices].astype(np.float32), smooth_sigma_px)
    vals = frame.luma(roi)
    return vals if smooth_sigma_px <= 0 else _smooth(vals, smooth_sigma_px)


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
    """Median of the pixels on the border of an ROI: the local diffuse level of ``normalise="local"``
    (float64; NaN if any is NaN; a single row or column counts twice)."""
    return float(np.median(np.concatenate([vals[0], vals[-1], vals[1:-1, 0], vals[1:-1, -1]], dtype=np.float64)))


@functools.lru_cache(maxsize=256)
def _folded_taps(kern: tuple, n: int) -> np.ndarray:
    """The taps ``kern`` (2 R + 1,) folded by ``BORDER_REFLECT`` onto the first ``min(n, R + 1)`` pixels
    from a side of a line of ``n``.
    """
    R = len(kern) // 2
    m = np.mod(np.arange(-R, R + 1), 2 * n)
    return np.bincount(np.where(m < n, m, 2 * n - 1 - m), weights=np.array(kern))


def _smoothed_border_median(img: np.ndarray, kern: np.ndarray, roi: Roi, full: np.ndarray | None = None) -> float:
    """:func:`_border_median` of the luma of ``img[roi]`` smoothed alone with the Gaussian taps ``kern``
    (its sides reflected), computed for its border pixels only; equal to the ring's median of the
    smoothed ROI to rounding. ``full``: the frame's luma where the caller has it.
    """
    h, w = roi.shape
    taps = tuple(kern.tolist())
    kr, kc = _folded_taps(taps, h), _folded_taps(taps, w)
    r0, r1, c0, c1 = roi
    lum = (lambda sl: luma(img[sl])) if full is None else full.__getitem__
    sq = np.empty((4, w)) if h == w else None  # a square ROI's four lines, smoothed in one call (each alone)
    rows, cols = (sq[:2], sq[2:]) if h == w else (np.empty((2, w)), np.empty((2, h)))
    np.matmul(kr, lum(np.s_[r0:r0 + len(kr), c0:c1]), out=rows[0])
    np.matmul(kr, lum(np.s_[r1 - len(kr):r1, c0:c1])[::-1], out=rows[1])
    np.matmul(lum(np.s_[r0:r1, c0:c0 + len(kc)]), kc, out=cols[0])
    np.matmul(lum(np.s_[r0:r1, c1 - len(kc):c1])[:, ::-1], kc, out=cols[1])
    smooth = lambda a: cv2.sepFilter2D(a, cv2.CV_64F, kern, _ONE_TAP, borderType=cv2.BORDER_REFLECT)
    rows, cols = smooth(sq).reshape(2, 2, w) if h == w else (smooth(rows), smooth(cols))
    return float(np.median(np.concatenate([rows.ravel(), cols[:, 1:-1].ravel()])))


@dataclass(frozen=True)
class _Levels:
    """Contour level of isovalue t in one ROI: ``offset + t * scale`` (image units)."""

    scale: float
    offset: float = 0.0

    @classmethod
    def of(cls, frame: _Frame, vals: np.ndarray, i_bp: float, roi: Roi | None = None,
           ring: float | None = None) -> _Levels:
        """``ring``: the ROI's smoothed border median where the caller computed it."""
        mode = frame.settings.normalise
        if ring is None and roi is not None and frame.smoothed32 is not None and \
                mode in (Normalisation.AUTO, Normalisation.LOCAL):
            # the ROI's values are the frame's smoothing; its background level is that of the ROI
            # smoothed alone (_smoothed_border_median), as without the frame's
            ring = _smoothed_border_median(frame.img, frame.kernel, roi, frame.ring_luma)
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


def _one_isophote(frame: _Frame, region, levels: _Levels, t, flood=None, defer=None, comp=None):
    """Extract the isophote at ``t`` in an ROI's checked region: ``(IsophoteEstimate of a failure, or
    _Pending, Isophote or None)``; with ``defer``, ``(its index there, None)`` until :func:`_resolve`.
    ``flood``: the flood fill made at that level, or None; ``comp``: its :func:`_component_box`, or None.
    """
    level = levels.level(t)
    if defer is not None and region.near_bp > level:
        comp = comp or _component_box(region.sub, level, region.ri, region.ci, flood)
        if comp is not None:
            defer.append((comp, level, region, levels, t, frame))
            return len(defer) - 1, None
    return _isophote_result(frame, t, _extract(region, level, True, 0))


def _isophote_result(frame: _Frame, t, iso):
    """:func:`_one_isophote`'s answer for the extraction's ``iso`` (an Isophote or a Failure)."""
    if not iso:
        return IsophoteEstimate(t, iso.reason, iso.detail), None
    if not iso.closed and not frame.settings.allow_open:
        where = "image border" if iso.cut_by_image else "ROI border"
        return IsophoteEstimate(t, "contour_cut", f"cut by the {where}", iso.points_uv, False), iso
    if len(iso.points_uv) < MIN_CONTOUR_POINTS:
        return IsophoteEstimate(t, "too_few_points", f"{len(iso.points_uv)} contour points < "
                                f"{MIN_CONTOUR_POINTS}", iso.points_uv, iso.closed), iso
    return _Pending(t, iso), iso


def _estimate_one(frame: _Frame, bp_uv, roi: Roi, *, saturated: bool, grow: bool, other_bps=(), own_bp: int = -1,
                  bp_ray=None, fitf: FitFrame | None = None, ring: float | None = None, sm: np.ndarray | None = None,
                  defer: list | None = None) -> _Draft | SpecularityEstimate | None:
    """Extract one highlight's isophotes (growing the ROI): a draft for
    :func:`~simtest.reconstruct.assemble._complete`, or the finished estimate of a BP without a ray.

    ``other_bps`` (k, 2): the BPs its isophote must not enclose (own row ``own_bp`` skipped);
    ``bp_ray``, ``fitf``, ``ring``: precomputed where the caller has them. ``sm``: the frame-wide array
    the ROI values are sliced from; with it, None where only the extraction can tell (the caller
    asks again without ``sm``). ``defer``: as :func:`_one_isophote`'s.
    """
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
    # With the frame smoothed once, an ROI's values near a side are the frame's neighbours', not
    # its own reflected smoothing; its background level stays that of the ROI smoothed alone.
    fast = frame.smoothed32 is not None and sigma > 0
    while True:
        vals = sm[roi.slices] if sm is not None else _roi_values(frame, roi, sigma)
        try:
            region = _region(vals, bp_uv, (roi.row0, roi.col0), frame.img.shape)
        except ValueError:  # the BP outside its ROI
            if sm is None:
                raise
            return None
        i_bp = region.near_bp  # the largest of the BP's 3 x 3 pixels
        levels = _Levels.of(frame, vals, i_bp, roi if fast else None, ring if fast and not growths else None)
        i0 = order[0]
        res = flood = None
        cut = False
        if grow and growths < ROI_MAX_GROWTHS:
            new = Roi.around(bp_uv, ROI_GROWTH_FACTOR * max(roi.shape) / 2.0, frame.img.shape)
            # an isophote cut by the ROI is discarded for the grown ROI's: ask only whether it is
            if new != roi:
                cut, flood = _cut_and_contour(region, levels.level(isovalues[i0]))
            if cut is None and sm is not None:
                return None
            if cut is None:  # only the extraction can tell
                res, iso = _one_isophote(frame, region, levels, isovalues[i0], flood)
                cut = iso is not None and iso.cut_by_roi
            if cut:
                roi, growths = new, growths + 1
                continue
        results[i0] = _one_isophote(frame, region, levels, isovalues[i0], flood, defer)[0] if res is None else res
        for i in order[1:]:
            results[i], _ = _one_isophote(frame, region, levels, isovalues[i], None, defer)
        break
    return _Draft(bp_uv, i_bp, saturated, roi, bp_ray, fitf, results, other_bps, own_bp)


def _grown_drafts(frame: _Frame, ks: list, bps: list, rois_of: dict, rings_of: dict, rays: np.ndarray,
                  frames_of: dict, saturated: list, others, own_rows: list, batches: _Batches) -> dict:
    """``k -> _Draft``: :func:`_estimate_one` (``grow=True``) of the candidates ``ks`` whose ROI values
    are slices of one frame-wide array (``smoothed32``, ``luma_frame`` or ``luma_frame32``); a
    candidate left out is asked again without it; each draft added to ``batches`` (its ``defer``: as
    :func:`_one_isophote`'s).
    """
    defer = batches.defer
    if not ks:
        return {}
    if frame.smoothed32 is not None and frame.smooth_sigma_px > 0:
        # the frame's smoothing; the first rings given, a grown ROI's computed
        # (the rings only where the normalisation reads them: "auto" and "local")
        sm = frame.smoothed32
        if frame.settings.normalise in (Normalisation.AUTO, Normalisation.LOCAL) and any(
                rings_of[k] is None for k in ks):
            return {}
    elif frame.luma_frame is not None and not frame.smooth_sigma_px > 0 and frame.luma_frame.dtype == np.float64:
        # a frame not smoothed: its luma; every ring the region's own border median
        sm = frame.luma_frame  # (every ring the region's own border median: _Levels.of)
    elif frame.luma_frame32 is not None and not frame.smooth_sigma_px > 0:
        # a frame with few highlights, not smoothed: its float32 luma
        sm = frame.luma_frame32
    else:
        return {}
    out = {}
    isovalues = frame.settings.isovalues
    first = _first_components(frame, ks, bps, rois_of, rings_of, sm)
    for k, sat, own in zip(ks, saturated, own_rows):
        if k in first:  # _estimate_one's draft of an ROI that does not grow, from the batch's components
            region, levels, comps = first[k]
            results = [None] * len(isovalues)
            for i in sorted(range(len(isovalues)), key=lambda i: isovalues[i]):
                results[i] = _one_isophote(frame, region, levels, isovalues[i], None, defer, comps[i])[0]
            out[k] = batches.add(_Draft(region.bp_uv, region.near_bp, sat, region.roi, rays[k], frames_of[k], results,
                                        others, own))
            continue
        draft = batches.add(_estimate_one(frame, bps[k], rois_of[k], saturated=sat, grow=True, other_bps=others,
                                          own_bp=own, bp_ray=rays[k], fitf=frames_of[k], ring=rings_of[k], sm=sm,
                                          defer=defer))
        if draft is not None:
            out[k] = draft
    return out


#: :func:`_first_components` batches the ROIs of at most this side (px).
FIRST_BATCH_SIDE_PX = 32


def _first_components(frame: _Frame, ks: list, bps: list, rois_of: dict, rings_of: dict, sm: np.ndarray) -> dict:
    """``k -> (region, levels, comps)`` of the candidates whose small first ROI does not grow, as
    :func:`_estimate_one` finds them, in whole-table calls (the ROIs on one canvas, apart by -inf).
    Any other candidate is left to :func:`_estimate_one` (the same bits).
    """
    if frame.settings.normalise != Normalisation.AUTO or not ks:
        return {}
    rr = np.array([rois_of[k] for k in ks], np.int64).reshape(-1, 4)
    h, w = rr[:, 1] - rr[:, 0], rr[:, 3] - rr[:, 2]
    bp = np.array([bps[k] for k in ks], np.float64).reshape(-1, 2)
    ri, ci = np.rint(bp[:, 1] - rr[:, 0]).astype(np.int64), np.rint(bp[:, 0] - rr[:, 2]).astype(np.int64)
    sel = np.flatnonzero((np.maximum(h, w) <= FIRST_BATCH_SIDE_PX) & (np.minimum(h, w) >= 3) & (ri >= 0) & (ri < h)
                         & (ci >= 0) & (ci < w))
    if not len(sel):
        return {}
    rr, h, w, ri, ci, n = rr[sel], h[sel], w[sel], ri[sel], ci[sel], len(sel)
    x0, y0 = np.cumsum(w + 1) - w, np.ones(n, np.int64)  # the ROIs in a row, -inf between and around
    canvas = np.full((int(h.max()) + 2, int(x0[-1] + w[-1]) + 1), -np.inf)
    owner = np.full(canvas.shape[1], n, np.int64)  # each column's ROI (n: none)
    for j, (r0, r1, c0, c1), x in zip(range(n), rr.tolist(), x0.tolist()):
        canvas[1:1 + r1 - r0, x:x + c1 - c0] = sm[r0:r1, c0:c1]
        owner[x:x + c1 - c0] = j
    by, bx = y0 + ri, x0 + ci  # the BPs' pixels on the canvas
    near = canvas[by[:, None] + np.repeat([-1, 0, 1], 3), bx[:, None] + np.tile([-1, 0, 1], 3)].max(axis=1)
    if frame.smoothed32 is not None and frame.smooth_sigma_px > 0:
        ring = np.array([rings_of[k] for k in np.asarray(ks)[sel].tolist()], np.float64)
    else:  # _border_median: each ring (top, bottom, left, right) padded by as many -inf as +inf
        p, hh, ww, top = np.arange(int(2 * (h + w).max() - 4))[None, :], h[:, None], w[:, None], 2 * (h + w)[:, None] - 4
        r = np.where(p < ww, 0, np.where(p < 2 * ww, hh - 1, np.where(p < 2 * ww + hh - 2, p - 2 * ww + 1, p - 2 * ww - hh + 3)))
        c = np.where(p < ww, p, np.where(p < 2 * ww, p - ww, np.where(p < 2 * ww + hh - 2, 0, ww - 1)))
        vals = np.where(p < top, canvas[np.minimum(y0[:, None] + r, canvas.shape[0] - 1), np.minimum(
            x0[:, None] + c, canvas.shape[1] - 1)], np.where(p < (top + p.shape[1]) // 2, -np.inf, np.inf))
        part = np.partition(vals, ((m := p.shape[1] // 2) - 1, m, p.shape[1] - 1), axis=1)
        ring = np.where(np.isnan(part[:, -1]), np.nan, (part[:, m - 1] + part[:, m]) / 2)
    local = ring >= AUTO_LOCAL_BACKGROUND_REL * near  # _Levels.of
    offset = np.where(local, np.where(near < ring, near, ring), 0.0)
    scale, keep = np.where(local, near - offset, near), np.isfinite(ring) & np.isfinite(near)
    isovalues = frame.settings.isovalues
    order, comps = sorted(range(len(isovalues)), key=lambda i: isovalues[i]), []
    for i in order:
        lvc = np.append(offset + isovalues[i] * scale, np.inf)[owner]  # each column's level
        lab = cv2.connectedComponentsWithAlgorithm((canvas > lvc).view(np.uint8), 4, cv2.CV_32S, cv2.CCL_WU)[1]
        own = np.where(up := canvas[by, bx] > lvc[bx], lab[by, bx], -1)
        yy, xx = np.divmod(q := np.flatnonzero(lab), canvas.shape[1])
        mine = lab.ravel()[q] == own[jq := owner[xx]]
        (low := canvas.copy()).ravel()[q[~mine]] = lvc[xx[~mine]] - 1.0  # _component_box's values
        x, y, x1, y1 = np.full(n, canvas.shape[1]), np.full(n, canvas.shape[0]), np.zeros(n, np.int64), np.zeros(n, np.int64)
        for a, v, fn in ((x, xx, np.minimum), (y, yy, np.minimum), (x1, xx + 1, np.maximum), (y1, yy + 1, np.maximum)):
            fn.at(a, jq[mine], v[mine])  # the bounding box of each BP's component
        x, y, x1, y1 = x - x0, y - y0, x1 - x0, y1 - y0
        sides = np.stack([y == 0, y1 == h, x == 0, x1 == w], 1)
        if i == order[0]:  # the lowest isophote cut by an ROI side inside the frame: the ROI grows
            keep &= up & ~(sides & ~np.stack([rr[:, 0] <= 0, rr[:, 1] >= sm.shape[0], rr[:, 2] <= 0,
                                               rr[:, 3] >= sm.shape[1]], 1)).any(axis=1)
        box = np.stack([np.maximum(y - 1, 0), np.minimum(y1 + 1, h), np.maximum(x - 1, 0), np.minimum(x1 + 1, w)], 1)
        comps.append((up.tolist(), low, (box + np.stack([y0, y0, x0, x0], 1)).tolist(), box.tolist(), sides.tolist()))
    out, shape = {}, tuple(frame.img.shape)
    for j in np.flatnonzero(keep).tolist():
        k = ks[sel[j]]
        (sub := sm[rois_of[k].slices]).flags.writeable = False
        got = [None] * len(isovalues)
        for i, (up, low, at, box, sides) in zip(order, comps):
            if up[j]:
                got[i] = (low[at[j][0]:at[j][1], at[j][2]:at[j][3]], (box[j][0], box[j][2]), tuple(sides[j]))
        out[k] = (_Region(sub, rois_of[k], shape, bps[k], int(ri[j]), int(ci[j]), float(near[j])),
                  _Levels(float(scale[j]), float(offset[j])), got)
    return out


class _Batches:
    """Drafts in the order made (:meth:`add` each), their deferred isophotes (``defer``) contoured
    (:func:`_resolve`) whenever the boxes pending hold more than :data:`RESOLVE_PENDING_MAX_BYTES` or, with
    ``max_isophotes``, that many isophotes wait; :meth:`finish` contours the rest."""

    def __init__(self, max_isophotes: int | None = None):
        self.defer, self.made, self.start, self.seen, self.nbytes = [], [], 0, 0, 0
        self.max_isophotes = max_isophotes

    def add(self, draft):
        self.made.append(draft)
        self.nbytes, self.seen = self.nbytes + sum(d[0][0].nbytes for d in self.defer[self.seen:]), len(self.defer)
        many = self.max_isophotes is not None and len(self.defer) >= self.max_isophotes
        if many or self.nbytes > RESOLVE_PENDING_MAX_BYTES:
            self.finish()
        return draft

    def finish(self):
        _resolve(self.made[self.start:], self.defer)
        self.start, self.seen, self.nbytes = len(self.made), 0, 0


def _resolve(drafts, defer: list) -> None:
    """Replace each index of ``defer`` in ``drafts`` by its isophote, all contoured in one batch
    (:func:`~simtest.reconstruct.marching.batch_contours`), and empty ``defer``.
    """
    if not defer:
        return
    origins = rc_to_uv([(g.roi.row0 + rc[0], g.roi.col0 + rc[1]) for (_, rc, _), _, g, *_ in defer])
    few = len(defer) < RESOLVE_BATCH_MIN and sum(d[0][0].size for d in defer) < RESOLVE_BATCH_MIN_PX
    found = [None] * len(defer) if few else batch_contours(
        [box for (box, _, _), *_ in defer], np.array([d[1] for d in defer]), origins, np.array([d[2].bp_uv for d in defer]))
    got = []
    for ((box, (dr, dc), sides), level, g, _, t, frame), uv, origin in zip(defer, found, origins):
        if uv is None:  # one by one, or a degenerate case: find_contours
            uv = _box_contours(box, level, origin, g.bp_uv)
        got.append(_isophote_result(frame, t, _isophote_of(*_box_answer(uv, dr, dc, sides), g, level, True, 0))[0])
    defer.clear()
    for draft in drafts:
        res = draft.results if isinstance(draft, _Draft) else ()
        for i, r in enumerate(res):
            if type(r) is int:
                res[i] = got[r]


def _first_rings(frame: _Frame, rois: list[Roi]) -> tuple[list, np.ndarray | None]:
    """Each ROI's smoothed border median where the normalisation reads it (``auto``, ``local``), else
    None each; and the frame's luma they were read from (or None).
    """
    if not rois or frame.smoothed32 is None or not frame.smooth_sigma_px > 0 or \
            frame.settings.normalise not in (Normalisation.AUTO, Normalisation.LOCAL):
        return [None] * len(rois), None
    full = frame.luma_frame if frame.luma_frame is not None or len(rois) < LUMA_FRAME_MIN_HIGHLIGHTS else \
        frame.luma32 if frame.luma32 is not None else luma(frame.img)
    return [_smoothed_border_median(frame.img, frame.kernel, roi, full) for roi in rois], full


def _initial_rois(cands: list, bps_uv: np.ndarray, threshold, frame: _Frame) -> list[Roi]:
    """The ROIs expected to hold the lowest isophotes of candidates (BPs ``bps_uv`` (k, 2)), batched.

    A Gaussian-like lobe has radius ``s sqrt(2 ln(P / L))`` at level L, so the isophote at ``t P`` is
    ``sqrt(ln(1/t) / ln(P / threshold))`` times the component (clamped to [1, 8]); the pipeline grows
    an ROI too small.
    """
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


def _candidate_drafts(frame: _Frame, det, r: Roi, bps_arr: np.ndarray, rays: np.ndarray, has_ray: np.ndarray,
                      fitted: np.ndarray, early: dict, others, keep: np.ndarray, row_in_others: np.ndarray) -> list:
    """One draft per candidate of ``det`` (region ``r``), in order: a ``_Draft`` of each ``fitted`` one,
    else the finished estimate (detection's reason, the ``early`` checks' detail, or no ray).
    """
    bps = list(bps_arr)
    fk = np.flatnonzero(fitted)
    frames_of = dict(zip(fk.tolist(), fit_frames(frame.camera, -rays[fitted])))
    # the fitted candidates' first ROIs, in one batch of numpy calls
    rois_of = dict(zip(fk.tolist(), _initial_rois([det.candidates[k] for k in fk.tolist()], bps_arr[fk],
                                                  det.threshold, frame)))
    rings, full = _first_rings(frame, [rois_of[k] for k in fk.tolist()])
    frame = frame if full is None else replace(frame, ring_luma=full)  # a grown ROI's ring read from it too
    rings_of = dict(zip(fk.tolist(), rings))
    # a frame smoothed once: every fitted candidate's ROI growth, levels and contour walks
    # (_grown_drafts); those it leaves go through _estimate_one
    batches = _Batches()  # the drafts' contours in batches, the last at the end
    defer = batches.defer
    drafts = _grown_drafts(frame, fk.tolist(), bps, rois_of, rings_of, rays, frames_of,
                           [det.candidates[k].saturated for k in fk.tolist()], others,
                           [int(row_in_others[k]) if keep[k] else -1 for k in fk.tolist()], batches)
    out = []
    # each candidate's ray a row of the rays, and whether it has one, as Python objects
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
        roi_k = rois_of[k] if k in rois_of else _initial_rois([cand], bp[None], det.threshold, frame)[0]
        out.append(batches.add(_estimate_one(frame, bp, roi_k, saturated=cand.saturated, grow=True, other_bps=others,
                                             own_bp=int(row_in_others[k]) if keep[k] else -1, bp_ray=rays[k],
                                             fitf=frames_of.get(k), ring=rings_of.get(k), defer=defer)))
    batches.finish()
    return out
