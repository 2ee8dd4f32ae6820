"""Marching squares over a frame's isophote components in one pass: the project's one accelerated
module. ``skimage.measure.find_contours`` contours one array per call; :func:`batch_contours` runs its
case table, interpolation and linking over many components' boxes at once with numpy, and returns
what ``find_contours`` returns for each, bit for bit (tested against it)."""

from __future__ import annotations

import numpy as np

from simtest._lazy import require

__all__ = ["batch_contours"]

#: ``find_contours``' segments (``fully_connected="low"``) by square case (bits: upper left, upper right, lower left,
#: lower right above the level) as (from, to) edges (0 top, 1 bottom, 2 left, 3 right; -1 none), in its order.
_SQUARE_SEGMENTS = np.full((16, 2, 2), -1, np.int64)
for _case, _pairs in {1: [(0, 2)], 2: [(3, 0)], 3: [(3, 2)], 4: [(2, 1)], 5: [(0, 1)], 6: [(3, 0), (2, 1)],
                      7: [(3, 1)], 8: [(1, 3)], 9: [(0, 2), (1, 3)], 10: [(1, 0)], 11: [(1, 2)],
                      12: [(2, 3)], 13: [(0, 3)], 14: [(2, 0)]}.items():
    _SQUARE_SEGMENTS[_case, : len(_pairs)] = _pairs
#: The pixels (0 upper left, 1 upper right, 2 lower left, 3 lower right) each edge's crossing is interpolated from, to.
_EDGE_ENDS = np.array([[0, 2, 0, 1], [1, 3, 2, 3]])
#: The most pixels of boxes one batch stacks: overlapping boxes (146 M px of them on the 1.9 M px banner at t
#: relative to each BP) would stack gigabytes, paid in page faults; whole boxes in batches keep each array under
#: glibc's 32 MiB mmap threshold, reused. A box's answer reads its own squares only: the same bits in any batch.
BATCH_MAX_PX = 1 << 21


def batch_contours(boxes: list, levels: np.ndarray, origins: np.ndarray, bps: np.ndarray) -> list:
    """The contours of many isophote components at once, bit for bit as
    ``find_contours(box, level, fully_connected="low")`` gives them one by one.

    Parameters
    ----------
    boxes : list of N ndarray of shape (h_i, w_i), float
        Each component's bounding box of luma, with a border below its level where the component
        is off the region's sides.
    levels : ndarray of shape (N,)
        Each box's isovalue, in its luma's units.
    origins : ndarray of shape (N, 2)
        Each box's first pixel, image (u, v), px.
    bps : ndarray of shape (N, 2)
        Each component's brightest point (BP), image (u, v), px.

    Returns
    -------
    list of N items
        For a component off its region's sides: its outer boundary (P, 2) image (u, v) if it
        encloses its BP, else a (0, 2) array. For one reaching a side: its open contours, (row, col)
        in the box. None where a crossing falls on a pixel.
    """
    if len(boxes) > 1 and (px := np.cumsum([b.size for b in boxes]))[-1] > BATCH_MAX_PX:
        cut = int(max(1, np.searchsorted(px, BATCH_MAX_PX, side="right")))  # whole boxes, answers in order
        return (batch_contours(boxes[:cut], levels[:cut], origins[:cut], bps[:cut])
                + batch_contours(boxes[cut:], levels[cut:], origins[cut:], bps[cut:]))
    n, (h, w) = len(boxes), np.array([b.shape for b in boxes], np.int64).T
    # boxes of one width stacked in a column (border rows below the level keep them apart)
    by_w = np.argsort(w, kind="stable")
    widths, first = np.unique(w[by_w], return_index=True)
    row0 = np.zeros(n, np.int64)  # each box's first row in its column
    base, parts = 0, []
    for wd, ks in zip(widths.tolist(), np.split(by_w, first[1:])):
        col = np.concatenate([boxes[k] for k in ks.tolist()]) if len(ks) > 1 else boxes[ks[0]]
        rows = np.concatenate([[0], np.cumsum(h[ks])])
        row0[ks] = rows[:-1]
        up = col > np.repeat(levels[ks], h[ks])[:, None]
        case = up[:-1, :-1] + 2 * up[:-1, 1:].view(np.uint8) + 4 * up[1:, :-1].view(np.uint8) + \
            8 * up[1:, 1:].view(np.uint8)
        gr, gc = np.divmod(q := np.flatnonzero((case != 0) & (case != 15)), wd - 1)
        b = ks[np.searchsorted(rows, gr, side="right") - 1]
        keep = gr - row0[b] < h[b] - 1  # not a square across two boxes
        q, gr, gc, b = q[keep], gr[keep], gc[keep], b[keep]
        fi, cf = gr * wd + gc, col.ravel()  # each square's upper left pixel, flat
        parts.append((base + fi, b, gr - row0[b], gc, case.ravel()[q], cf[fi], cf[fi + 1], cf[fi + wd], cf[fi + wd + 1],
                      np.full(len(gr), wd)))
        base += col.size
    sq, b, r, c, case, ul, ur, ll, lr, wb = (np.concatenate(x) for x in zip(*parts))
    o = np.argsort(b.astype(np.uint16) if n <= 1 << 16 else b, kind="stable")  # each box's squares in scan order
    sq, b, r, c, case, wb = sq[o], b[o], r[o].astype(float), c[o].astype(float), case[o], wb[o]
    corners = np.stack([ul[o], ur[o], ll[o], lr[o]], 1).ravel()
    segs = _SQUARE_SEGMENTS[case]
    si, sj = np.nonzero(segs[:, :, 0] >= 0)  # the segments in scan order
    fe, te, sb, r, c = segs[si, sj, 0], segs[si, sj, 1], b[si], r[si], c[si]
    lv = levels[sb]

    def point(e):  # each segment's crossing on its square's edge e: (row, col), and off the edge's ends
        a, z = corners[4 * si + _EDGE_ENDS[0, e]], corners[4 * si + _EDGE_ENDS[1, e]]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = (lv - a) / (z - a)
        side = e >= 2
        pr, pc = np.where(side, r + f, r + (e == 1)), np.where(side, c + (e == 3), c + f)
        return pr, pc, np.where(side, (r < pr) & (pr < r + 1), (c < pc) & (pc < c + 1))

    fr, fc, fok = point(fe)
    tr, tc, tok = point(te)
    fkey, tkey = (2 * (sq[si] + np.where(e == 1, wb[si], e == 3)) + (e >= 2) for e in (fe, te))
    bad = np.bincount(sb, ~(fok & tok), n) > 0  # a crossing on a pixel: find_contours decides
    k = len(fkey)
    if not k:  # no crossing anywhere
        return [np.empty((0, 2)) for _ in boxes]
    order = np.argsort(fkey)
    succ = order[np.minimum(np.searchsorted(fkey, tkey, sorter=order), k - 1)]
    linked = fkey[succ] == tkey
    csr = require("scipy.sparse").csr_matrix  # imported here: 0.2 to 0.5 s of a command's start
    edges = csr((np.ones(int(linked.sum())), succ[linked], np.concatenate([[0], np.cumsum(linked)])), (k, k))
    ncomp, comp = require("scipy.sparse.csgraph").connected_components(edges, directed=True, connection="weak")
    is_open = np.bincount(comp, ~linked, ncomp) > 0
    open_box = np.bincount(sb, is_open[comp], n) > 0
    # of a closed box, its cycle of largest signed area (find_contours' orientation): the outer boundary,
    # if positive (a component that fills its box has only holes, and a hole is never the isophote)
    area = np.bincount(comp, fc * tr - fr * tc, ncomp)
    (comp_box := np.zeros(ncomp, np.int64))[comp] = sb
    o = np.lexsort((area, comp_box))
    top = o[np.append(comp_box[o][1:] != comp_box[o][:-1], True)]  # the last of each box's
    top = top[area[top] > 0]
    (outer := np.full(n, -1))[comp_box[top]] = top
    sel = np.flatnonzero(np.where(open_box[sb], is_open[comp], outer[sb] == comp))
    bs = sb[sel]
    u0, v0 = origins[bs].T
    x, y, x2, y2 = fc[sel] + u0, fr[sel] + v0, tc[sel] + u0, tr[sel] + v0
    px, py = bps[bs].T
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = ((y > py) != (y2 > py)) & (px < x + (py - y) * (x2 - x) / (y2 - y))
    inside = np.bincount(bs, cross, n) % 2 == 1
    # each contour cut after its last segment (a cycle's last scanned), walked from its start by one depth-first
    # search from a root (node k) whose edges lead to the starts in the order of their contours' first segments
    ptr = np.where(linked, succ, -1)
    last, first = np.zeros(ncomp, np.int64), np.full(ncomp, k)
    np.maximum.at(last, comp[sel], sel)
    np.minimum.at(first, comp[sel], sel)
    ptr[last[comp[sel]][~is_open[comp[sel]]]] = -1
    (pred := np.zeros(k, bool))[ptr[src := sel[ptr[sel] >= 0]]] = True
    starts = sel[~pred[sel]][np.argsort(first[comp[sel[~pred[sel]]]])]
    walk = csr((np.ones(len(src) + len(starts)), np.concatenate([ptr[src], starts]), np.concatenate(
        [[0], np.cumsum(np.bincount(src, minlength=k)), [len(src) + len(starts)]])), (k + 1, k + 1))
    seg = require("scipy.sparse.csgraph").depth_first_order(walk, k, return_predecessors=False)[1:]
    start = np.concatenate([[0], np.cumsum(np.bincount(bs, minlength=n))])
    (at := np.zeros(k, np.int64))[sel] = np.arange(len(sel))  # a segment's place in sel
    pts = np.stack([x, y], 1)[at[seg]]
    rc = np.stack([fr[seg], fc[seg]], 1)
    ends = np.flatnonzero(np.diff(np.append(comp[seg], -1)))  # each contour's last segment
    tail = np.stack([tr[seg[ends]], tc[seg[ends]]], 1)  # its end point (an open contour's last)
    out = []
    for i in range(n):
        if bad[i]:
            out.append(None)
        elif not open_box[i]:
            out.append(pts[start[i]:start[i + 1]] if inside[i] else pts[:0])
        else:  # each open contour, its end point appended
            cut = ends[(ends >= start[i]) & (ends < start[i + 1])]
            out.append([np.concatenate([rc[a:e + 1], tail[j : j + 1]]) for j, a, e in
                        zip(np.searchsorted(ends, cut), np.append(start[i], cut[:-1] + 1), cut)])
    return out
