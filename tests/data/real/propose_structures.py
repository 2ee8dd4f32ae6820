"""Proposals for the labelled bright structures of the Hyper-Kvasir banner (see README.md here).

Every bright structure a highlight detector could pick, on each of the banner's 24 tiles (280 x 280,
tile (row r, col c) at x = c*280, y = r*280, id "r{r}c{c}"), independent of simtest's detector:

1. tissue top-hat peaks: the white top-hat of the luma (luma minus its grey opening by a 21 px
   disc, the opening taken with the dark field, luma < 25, set to white so that the tissue beside
   the field stop or the lumen is not measured against black); its local maxima (5 x 5) of at
   least 25 grey levels that also stand at least 25 levels above the local median (21 x 21: on
   granular mucosa every bump stands 25 above the local minimum). Strongest first, each peak's
   region is the 4-connected set of pixels within +-16 px of it whose top-hat is at least half
   the peak's (cut at half height above the local background). A peak inside an earlier region
   belongs to it; a region that overlaps earlier structures merges with those whose peak is at
   most 2 x its own, and leaves the pixels of stronger ones to them (a glint is not swallowed by
   the texture or the weaker glint beside it);
2. near-saturated components: 8-connected components of pixels with luma >= 240, or with a
   channel = 255 and a top-hat of at least 25 (a red channel clipped in flat red mucosa is no
   structure); each merges with every structure it overlaps;
3. plain top-hat peaks (no dark-field fill, same thresholds) on pixels not yet claimed: things
   bright only against the dark field; their regions take unclaimed pixels and merge with each
   other;
4. structures of fewer than 2 px are dropped.

Nothing is excluded (overlays, the scope border, instruments and texture are proposed too: the
labels say what each one is). Coordinates are tile pixels, u = column, v = row, pixel centres at
integer coordinates; (u, v) is the structure's centroid, (u_peak, v_peak) its brightest top-hat
pixel (or brightest pixel if it has no top-hat peak). Deterministic (no randomness, fixed order).

Usage: ``python propose_structures.py BANNER.jpg OUT.json [LABELMAP.png]`` (the label map: uint16
PNG of the banner, 0 = no structure, k = the structure whose "index" is k).
"""
import json
import sys

import cv2
import numpy as np

TILE = 280
ROWS, COLS = 3, 8
DISC = 21            # px, diameter of the opening's disc
MIN_TOPHAT = 25.0    # grey levels, peak top-hat
MIN_ABOVE_MEDIAN = 25.0  # grey levels, peak above the local median (21 x 21)
SAT_LUMA = 240       # near-saturated luma
MIN_AREA = 2         # px
DARK = 25            # luma below this is dark field (not background for the top-hat)
WIN = 16             # px, a top-hat region stays within +-WIN of its peak
MERGE_RATIO = 2.0    # a region merges with overlapped structures whose peak is <= this x its own


def _peaks(th, above_median):
    """local maxima (5 x 5) of th of at least MIN_TOPHAT that stand at least MIN_ABOVE_MEDIAN
    above the local median, strongest first, ties in raster order"""
    mx = cv2.dilate(th, np.ones((5, 5), np.uint8))
    pk = np.argwhere((th >= mx) & (th >= MIN_TOPHAT) & (above_median >= MIN_ABOVE_MEDIAN))
    return pk[np.lexsort((pk[:, 1], pk[:, 0], -th[pk[:, 0], pk[:, 1]]))]


def propose_tile(tile_bgr):
    g8 = cv2.cvtColor(tile_bgr, cv2.COLOR_BGR2GRAY)
    g = g8.astype(np.float32)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (DISC, DISC))
    dark = g8 < DARK
    # th_t: top-hat against the tissue (the dark field is not background: a glint beside the
    # field stop is measured against the tissue around it); th_p: the plain top-hat (text, status
    # squares and the tissue rim are bright only against the dark field)
    gf = g.copy()
    gf[dark] = 255.0
    th_t = np.maximum(g - cv2.morphologyEx(gf, cv2.MORPH_OPEN, disc), 0.0)
    th_t[dark] = 0.0
    th_p = g - cv2.morphologyEx(g, cv2.MORPH_OPEN, disc)
    # the opening is the local minimum level: on granular texture every bump stands 25 levels
    # above it; a peak must also stand MIN_ABOVE_MEDIAN above the local median (21 px)
    above_median = g - cv2.medianBlur(g8, DISC).astype(np.float32)

    H, W = g.shape
    lab = np.zeros((H, W), np.int32)      # structure label per pixel
    src = {}                               # label -> set of sources
    peak_of = {}                           # label -> (top-hat, r, c) of its strongest peak
    nxt = [1]

    def region(th, r, c, free):
        """half-height region of the peak (r, c): 4-connected, th >= th[r, c] / 2, inside free,
        within +-WIN px of the peak"""
        y0, y1 = max(r - WIN, 0), min(r + WIN + 1, H)
        x0, x1 = max(c - WIN, 0), min(c + WIN + 1, W)
        m = np.ascontiguousarray(((th[y0:y1, x0:x1] >= 0.5 * th[r, c])
                                  & free[y0:y1, x0:x1]).astype(np.uint8))
        cv2.floodFill(m, None, (int(c - x0), int(r - y0)), 2, 0, 0, 4)
        mask = np.zeros((H, W), bool)
        mask[y0:y1, x0:x1] = m == 2
        return mask

    def merge(mask, source, peak, labels):
        """a new structure of mask, merged with the structures in labels"""
        new = nxt[0]
        nxt[0] += 1
        srcs, best = {source}, peak
        for o in labels:
            srcs |= src.pop(o)
            p = peak_of.pop(o)
            if best is None or (p is not None and p[0] > best[0]):
                best = p
            lab[lab == o] = new
        lab[mask] = new
        src[new] = srcs
        peak_of[new] = best

    def overlapped(mask):
        return [int(o) for o in np.unique(lab[mask]) if o > 0]

    # 1. tissue top-hat peaks, strongest first. A peak inside an earlier structure belongs to it.
    #    Its half-height region merges with the structures it overlaps whose peak is at most
    #    MERGE_RATIO times its own (the same blob at a lower level, glints of a cluster, a patch of
    #    texture); stronger ones keep their pixels (a glint is not swallowed by the texture or
    #    the weaker glint beside it).
    for r, c in _peaks(th_t, above_median):
        if lab[r, c]:
            continue
        t = float(th_t[r, c])
        strong = {L for L, p in peak_of.items() if p is not None and p[0] > MERGE_RATIO * t}
        free = ~np.isin(lab, list(strong)) if strong else np.ones((H, W), bool)
        mask = region(th_t, r, c, free)
        merge(mask, "tophat", (t, int(r), int(c)), overlapped(mask))

    # 2. near-saturated components, each merged with the structures it overlaps
    # (a channel clipped in flat red or orange mucosa is no structure: a clipped pixel counts when
    # its luma is near-saturated or it stands MIN_TOPHAT above the opening)
    sat = (g8 >= SAT_LUMA) | ((tile_bgr == 255).any(axis=2) & (th_t >= MIN_TOPHAT))
    n, cc = cv2.connectedComponents(sat.astype(np.uint8), connectivity=8)
    for k in range(1, n):
        mask = cc == k
        merge(mask, "saturated", None, overlapped(mask))

    # 3. plain top-hat peaks not yet claimed (bright against the dark field only: burnt-in text,
    #    status squares, the tissue rim at the field stop); their regions take unclaimed pixels
    #    and merge with each other
    nb = nxt[0]
    for r, c in _peaks(th_p, above_median):
        if lab[r, c]:
            continue
        mask = region(th_p, r, c, (lab == 0) | (lab >= nb))
        merge(mask, "tophat_dark_ground", (float(th_p[r, c]), int(r), int(c)),
              [o for o in overlapped(mask) if o >= nb])

    out = []
    for L in sorted(src):
        mask = lab == L
        area = int(mask.sum())
        if area < MIN_AREA:
            continue
        rr, cc_ = np.nonzero(mask)
        p = peak_of[L]
        if p is None:
            i = int(np.argmax(g[rr, cc_]))
            pr, pc, pth = int(rr[i]), int(cc_[i]), float(th_t[rr[i], cc_[i]])
        else:
            pth, pr, pc = p
        px = tile_bgr[rr, cc_]
        out.append({
            "u": round(float(cc_.mean()), 2), "v": round(float(rr.mean()), 2),
            "u_peak": pc, "v_peak": pr,
            "area_px": area,
            "bbox": [int(cc_.min()), int(rr.min()), int(cc_.max() - cc_.min() + 1),
                     int(rr.max() - rr.min() + 1)],
            "tophat_peak": round(pth, 1),
            "luma_max": int(g8[rr, cc_].max()),
            "saturated_px": int(sat[rr, cc_].sum()),
            "label": int(L),
            "mean_rgb": [round(float(px[:, 2].mean()), 1), round(float(px[:, 1].mean()), 1),
                         round(float(px[:, 0].mean()), 1)],
            "touches_tile_edge": bool(rr.min() == 0 or cc_.min() == 0 or rr.max() == H - 1
                                      or cc_.max() == W - 1),
            "sources": sorted(src[L]),
        })
    # number in raster order of the centroid (row bands of 10 px, then column) for the context views
    out.sort(key=lambda s: (int(s["v"] // 10), s["u"], s["v"]))
    return out, lab


def propose_banner(img_bgr):
    """{tile id: [structure, ...]} and a label map of the banner (uint16: 0 none, i + 1 for the
    i-th structure in the order tiles r0c0, r0c1, ..., r2c7 and their lists)"""
    tiles = {}
    labelmap = np.zeros(img_bgr.shape[:2], np.uint16)
    i = 0
    for r in range(ROWS):
        for c in range(COLS):
            t = img_bgr[r * TILE:(r + 1) * TILE, c * TILE:(c + 1) * TILE]
            props, lab = propose_tile(np.ascontiguousarray(t))
            tid = f"r{r}c{c}"
            sub = labelmap[r * TILE:(r + 1) * TILE, c * TILE:(c + 1) * TILE]
            for k, s in enumerate(props):
                s["id"] = f"{tid}-{k:03d}"
                s["n"] = k
                i += 1
                s["index"] = i
                sub[lab == s.pop("label")] = i
            tiles[tid] = props
    return tiles, labelmap


if __name__ == "__main__":
    img = cv2.imread(sys.argv[1], cv2.IMREAD_COLOR)
    tiles, labelmap = propose_banner(img)
    if len(sys.argv) > 3:
        cv2.imwrite(sys.argv[3], labelmap)
    total = sum(len(v) for v in tiles.values())
    json.dump({"source": "tests/data/real/hyperkvasir_banner.jpg",
               "method": __doc__.strip().split("\n\n")[1],
               "params": {"disc_px": DISC, "min_tophat": MIN_TOPHAT, "sat_luma": SAT_LUMA,
                          "min_area_px": MIN_AREA},
               "total": total, "tiles": tiles}, open(sys.argv[2], "w"), indent=1)
    print(total, {k: len(v) for k, v in tiles.items()})
