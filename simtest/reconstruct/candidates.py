"""The examination of a frame's candidate highlights as one table (detection's second half).

:func:`examine` takes the components of a candidate mask as a table (label, box and area per
component) and returns, column by column, each one's brightest pixel and peak, sub-pixel BP,
status, ROI and detection level. The rules (statuses named in :mod:`simtest.reconstruct.detect`):

- brightest pixel: the first maximum of the component in raster order;
- BP: the centroid of the largest clipped plateau of a clipped candidate; else, where the peak
  lies within :data:`~simtest.decisions.CLIP_LUMA_MARGIN_REL` of an integer frame's ceiling, the
  centroid of its pixels over that limit 8-connected to the brightest pixel; else the centroid of
  a flat top through the brightest pixel; else the separable parabola through the 3 x 3
  neighbourhood (offsets clipped to +-0.5 px, 0 at the box's side or without a strict maximum);
- status: ``too_small``, ``touches_border``, ``black_border`` (the scope's border), ``merged``
  (two or more clipped plateaus), then from :data:`ELLIPTICITY_MIN_AREA_PX` px ``not_elliptical``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from simtest.decisions import CLIP_LUMA_MARGIN_REL, ELLIPTICITY_MIN_AREA_PX
from simtest.reconstruct._pixels import uv_to_rc
from simtest.reconstruct.detect_pixels import connected_components

#: Status codes of :func:`examine` (column ``code``) and their names.
OK, TOO_SMALL, TOUCHES_BORDER, BLACK_BORDER, NOT_ELLIPTICAL, MERGED = range(6)
STATUS_NAMES = ("ok", "too_small", "touches_border", "black_border", "not_elliptical", "merged")
#: Boxes up to this side have their minimum gathered at once; larger ones one by one.
_GATHER_SIDE = 8
#: Up to this many components are read box by box (:func:`_pixels`).
_FEW = 64


@dataclass(frozen=True)
class Rules:
    """The decision numbers of :func:`examine` (``detect_specularities``' arguments, resolved);
    ``k_close``: side of the closing that joins pieces of one clipped top (px).
    """

    min_area_px: int
    ellipticity_min: float
    min_plateau_px: int
    roi_scale: float
    roi_margin_px: float
    peak_rel: float
    k_close: int
    local_peak: bool
    #: An integer frame's ceiling (its saturation level), image units; None: no ceiling (floats).
    ceiling: float | None = None


@dataclass
class Examined:
    """The columns of :func:`examine`, one row per component of its table (same order)."""

    bp_uv: np.ndarray  #: (N, 2) float64, px in the frame
    peak: np.ndarray  #: (N,) float64, image units
    code: np.ndarray  #: (N,) int64 status codes
    saturated: np.ndarray  #: (N,) bool
    n_plateaus: np.ndarray  #: (N,) int64, clipped plateaus of the plateau size
    ellipticity: np.ndarray  #: (N,) float64, NaN where not computed
    roi: np.ndarray  #: (N, 4) int64 row0, row1, col0, col1 (frame)
    level: np.ndarray | None  #: (N,) float64 detection level, or None without levels


def roi_columns(bp_uv: np.ndarray, half: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """:meth:`simtest.reconstruct._pixels.Roi.around` of many centres: (N, 4), clipped to ``shape`` (H, W)."""
    h, w = shape
    r, c = uv_to_rc(bp_uv).T
    out = np.empty((len(bp_uv), 4), np.int64)
    out[:, 0] = np.maximum(0, np.floor(r - half))
    out[:, 1] = np.minimum(h, np.ceil(r + half) + 1)
    out[:, 2] = np.maximum(0, np.floor(c - half))
    out[:, 3] = np.minimum(w, np.ceil(c + half) + 1)
    return out


def _box_minima(gray: np.ndarray, x, y, bw, bh) -> np.ndarray:
    """The minimum of ``gray`` in each box (float64): small boxes gathered at once."""
    out = np.empty(len(x), np.float64)
    small = (bw <= _GATHER_SIDE) & (bh <= _GATHER_SIDE)
    s = np.flatnonzero(small)
    if len(s):
        k = np.arange(_GATHER_SIDE)
        rr = y[s, None, None] + k[None, :, None]
        cc = x[s, None, None] + k[None, None, :]
        inside = (k[None, :, None] < bh[s, None, None]) & (k[None, None, :] < bw[s, None, None])
        vals = gray[np.minimum(rr, gray.shape[0] - 1), np.minimum(cc, gray.shape[1] - 1)].astype(np.float64)
        out[s] = np.where(inside, vals, np.inf).min(axis=(1, 2))
    for i in np.flatnonzero(~small).tolist():
        out[i] = float(gray[y[i] : y[i] + bh[i], x[i] : x[i] + bw[i]].min())
    return out


def _pixels(labels: np.ndarray, table: np.ndarray):
    """The examined components' pixels, each in raster order: (flat index, row of ``table``)."""
    w = labels.shape[1]
    if len(table) <= _FEW:
        parts, rows = [], []
        for i, (cid, x, y, bw, bh, _) in enumerate(table.tolist()):
            rr, cc = np.nonzero(labels[y : y + bh, x : x + bw] == cid)
            parts.append((rr + y) * w + (cc + x))
            rows.append(np.full(len(rr), i, np.int64))
        return np.concatenate(parts).astype(np.int64), np.concatenate(rows)
    y0 = int(table[:, 2].min())
    y1 = int((table[:, 2] + table[:, 4]).max())
    band = labels[y0:y1]
    idx = np.flatnonzero(band)
    lab = band.ravel()[idx]
    idx += y0 * w
    row_of = np.full(max(int(table[:, 0].max()), int(lab.max(initial=0))) + 1, -1, np.int64)
    row_of[table[:, 0]] = np.arange(len(table))
    k = row_of[lab]
    if len(table) < len(row_of) - 1:  # components left out (max_candidates)
        keep = k >= 0
        idx, k = idx[keep], k[keep]
    return idx, k


def _top_centroids(gray, rows, idx, k, level, pix, row, col):
    """The centroid (row, col) of each candidate's top for the candidates ``rows``: its pixels at or
    above ``level`` 8-connected to the brightest pixel ``pix``.
    """
    is_top = np.zeros(len(level), bool)
    is_top[rows] = True
    sel = is_top[k]
    on = idx[sel][gray.ravel()[idx[sel]] >= level[k[sel]]]
    w = gray.shape[1]
    r0, r1 = int(on.min()) // w, int(on.max()) // w + 1
    on = on - r0 * w
    top = np.zeros((r1 - r0, w), np.uint8)
    top.ravel()[on] = 1
    n, plab = connected_components(top)
    pl = plab.ravel()[on]
    rr, cc = np.divmod(on, w)
    cnt = np.bincount(pl, minlength=n)
    sr = np.bincount(pl, weights=rr, minlength=n) + r0 * cnt
    sc = np.bincount(pl, weights=cc, minlength=n)
    at = plab.ravel()[pix[rows] - r0 * w]
    alone = cnt[at] < 2
    return (np.where(alone, row[rows], sr[at] / np.maximum(cnt[at], 1)),
            np.where(alone, col[rows], sc[at] / np.maximum(cnt[at], 1)))


def _plateaus(clipped: np.ndarray, labels: np.ndarray, cid: int, x: int, y: int, bw: int, bh: int,
              rules: Rules, near: np.ndarray | None = None) -> tuple[int, float, float]:
    """The clipped plateaus of one candidate: ``(n, row, col)``, the count of plateau-sized plateaus and
    the largest one's centroid (frame). With ``"local_peak"`` a codec's broken top (pieces, or pixels
    of ``near``) counts as one plateau.
    """
    comp = (labels[y : y + bh, x : x + bw] == cid).view(np.uint8)
    top = clipped[y : y + bh, x : x + bw] & comp
    if near is not None:
        top = _joined(top, near[y : y + bh, x : x + bw] & comp)
    n_big, row, col = _plateau_count(top, comp, rules)
    return n_big, row + y, col + x


def _joined(seed: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The pieces of ``mask`` (0/1, 8-connected) that hold a pixel of ``seed``."""
    _, lab = cv2.connectedComponents(mask | seed, connectivity=8)
    keep = np.zeros(int(lab.max()) + 1, bool)
    keep[lab[seed != 0]] = True
    keep[0] = False
    return keep[lab].view(np.uint8)


def _plateau_count(raw: np.ndarray, comp: np.ndarray, rules: Rules) -> tuple[int, float, float]:
    """:func:`_plateaus` of one mask in the candidate's box: ``(n, row, col)`` (box coordinates)."""
    sat = raw
    min_plateau = rules.min_plateau_px
    if rules.local_peak:
        sat = cv2.morphologyEx(raw, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) & comp
        min_plateau = max(min_plateau, 3)
    _, _, stats, cent = cv2.connectedComponentsWithStats(sat, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    n_big = int(np.sum(areas >= min_plateau))
    if rules.local_peak and rules.k_close > 3 and n_big > 1:
        wide = cv2.morphologyEx(raw, cv2.MORPH_CLOSE, np.ones((rules.k_close,) * 2, np.uint8)) & comp
        _, _, wstats, wcent = cv2.connectedComponentsWithStats(wide, connectivity=8)
        if int(np.sum(wstats[1:, cv2.CC_STAT_AREA] >= min_plateau)) == 1:
            stats, cent, n_big = wstats, wcent, 1
            areas = stats[1:, cv2.CC_STAT_AREA]
    cx, cy = cent[1 + int(np.argmax(areas))]
    return n_big, float(cy), float(cx)


def _parabola(a: np.ndarray, b: np.ndarray, d: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Offset of the parabola through (a, b, d), clipped to +-0.5; 0 where not ``ok`` or not concave."""
    den = a - 2 * b + d
    use = ok & (den < 0)
    off = np.zeros(len(a))
    off[use] = np.clip(0.5 * (a[use] - d[use]) / den[use], -0.5, 0.5)
    return off


def examine(gray: np.ndarray, labels: np.ndarray, table: np.ndarray, rules: Rules, *,
            clipped: np.ndarray | None = None, near: np.ndarray | None = None,
            scope: np.ndarray | None = None, levels: np.ndarray | None = None) -> Examined:
    """Brightest point, peak, status, ROI and level of every component of a table.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        The intensities examined (the luma, smoothed where detection smooths).
    labels : ndarray of shape (H, W), int32
        Component labels (0 background); read inside the table's boxes only.
    table : ndarray of shape (N, 6), int64
        Label, x, y, width, height, area of each component.
    rules : Rules
    clipped : ndarray of shape (H, W), uint8, optional
        Clipped pixels (0/1).
    near : ndarray of shape (H, W), uint8, optional
        Pixels near the ceiling (0/1, :func:`~simtest.reconstruct.detect_pixels.near_ceiling_mask`).
    scope : ndarray of shape (H, W), bool, optional
        The endoscope's black border.
    levels : ndarray of shape (H, W), float32, optional
        The local background (``"local_peak"``).

    Returns
    -------
    Examined
    """
    n = len(table)
    h, w = gray.shape
    cid, x, y, bw, bh, area = (table[:, j].astype(np.int64) for j in range(6))
    idx, k = _pixels(labels, table)
    flat = gray.ravel()
    vals = flat[idx].astype(np.float64)
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, k, vals)
    is_max = vals == peak[k]
    pix = np.full(n, flat.size, np.int64)
    np.minimum.at(pix, k[is_max], idx[is_max])  # the first maximum in raster order
    pr, pc = pix // w, pix % w

    # the 3 x 3 neighbours of the brightest pixel in the component: flat tops, and the parabola
    def neighbour(dr, dc):
        rr, cc = pr + dr, pc + dc
        inb = (rr >= y) & (rr < y + bh) & (cc >= x) & (cc < x + bw)
        rr, cc = np.minimum(np.maximum(rr, 0), h - 1), np.minimum(np.maximum(cc, 0), w - 1)
        inside = inb & (labels[rr, cc] == cid)
        return inb, inside, gray[rr, cc].astype(np.float64)

    n_top = np.ones(n, np.int64)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                _, inside, v = neighbour(dr, dc)
                n_top += inside & (v == peak)
    sides = [neighbour(dr, dc) for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))]
    need_min = np.zeros(n, bool)
    for inb, inside, _ in sides:
        need_min |= inb & ~inside
    box_min = np.zeros(n)
    nm = np.flatnonzero(need_min)
    if len(nm):
        box_min[nm] = _box_minima(gray, x[nm], y[nm], bw[nm], bh[nm])
    v4 = [np.where(inside, v, box_min) for _, inside, v in sides]
    dr = _parabola(v4[0], peak, v4[1], (pr > y) & (pr < y + bh - 1))
    dc = _parabola(v4[2], peak, v4[3], (pc > x) & (pc < x + bw - 1))
    row, col = pr + dr, pc + dc

    # clipped candidates: their plateaus, one by one
    saturated = np.zeros(n, bool)
    n_plateaus = np.zeros(n, np.int64)
    if clipped is not None:
        hits = np.bincount(k[clipped.ravel()[idx] != 0], minlength=n)
        saturated = hits > 0
        for i in np.flatnonzero(saturated).tolist():
            n_plateaus[i], row[i], col[i] = _plateaus(clipped, labels, int(cid[i]), int(x[i]), int(y[i]),
                                                      int(bw[i]), int(bh[i]), rules, near)
    # unclipped tops: a flat one, and one near the ceiling (centroid of their pixels)
    level = np.where((n_top > 1) & ~saturated, peak, np.inf)
    if rules.ceiling is not None:
        lim = rules.ceiling * (1.0 - CLIP_LUMA_MARGIN_REL)
        level[~saturated & (peak >= lim)] = lim
    top_rows = np.flatnonzero(np.isfinite(level))
    if len(top_rows):
        row[top_rows], col[top_rows] = _top_centroids(gray, top_rows, idx, k, level, pix, row, col)

    code = np.full(n, OK, np.int64)
    code[n_plateaus > 1] = MERGED
    # ellipticity of the ok ones from the threshold size: second moments of the pixels
    ell = np.full(n, np.nan)
    e_rows = (code == OK) & (area >= ELLIPTICITY_MIN_AREA_PX) & (area >= rules.min_area_px)
    if e_rows.any():
        sel = e_rows[k]
        kk = k[sel]
        # frame coordinates: the sums are exact integers in float64
        rr, cc = (v.astype(np.float64) for v in np.divmod(idx[sel], w))
        cnt = area.astype(np.float64)
        sums = [np.bincount(kk, weights=v, minlength=n) for v in (rr, cc, rr * rr, cc * cc, rr * cc)]
        with np.errstate(invalid="ignore", divide="ignore"):
            mr, mc = sums[0] / cnt, sums[1] / cnt
            srr = sums[2] / cnt - mr * mr + 1 / 12
            scc = sums[3] / cnt - mc * mc + 1 / 12
            src = sums[4] / cnt - mr * mc
            det = srr * scc - src * src
            e = np.where(det > 0, cnt / (4 * np.pi * np.sqrt(np.maximum(det, 0))), np.nan)
        ell[e_rows] = e[e_rows]
        bad = e_rows & ~((rules.ellipticity_min <= ell) & (ell <= 1.0 / rules.ellipticity_min))
        code[bad] = NOT_ELLIPTICAL
    if scope is not None:
        integral = cv2.integral(scope.view(np.uint8))  # each box's sum from it
        code[integral[y + bh, x + bw] - integral[y, x + bw] - integral[y + bh, x] + integral[y, x] > 0] = BLACK_BORDER
    code[(x == 0) | (y == 0) | (x + bw >= w) | (y + bh >= h)] = TOUCHES_BORDER
    code[area < rules.min_area_px] = TOO_SMALL

    bp = np.empty((n, 2))
    bp[:, 0] = col
    bp[:, 1] = row
    half = rules.roi_scale * np.maximum(bw, bh) / 2.0 + rules.roi_margin_px
    level = None
    if levels is not None:
        b = levels[pr, pc].astype(np.float64)
        level = b + rules.peak_rel * (peak - b)
    return Examined(bp, peak, code, saturated, n_plateaus, ell, roi_columns(bp, half, (h, w)), level)
