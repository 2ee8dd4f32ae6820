"""Contact sheets for labelling the proposals of propose_structures.py by eye (see README.md here).

For each proposal a 48 x 48 px crop of its tile centred on its peak pixel, enlarged 3 x (nearest
neighbour), with a small cyan cross around the peak (a gap of 1 px around it, so the peak itself is
not covered: arms from 3 to 6 px away) and yellow corner ticks just outside the structure's
bounding box when it is over 6 px wide or tall; outside the tile is dark blue-grey. A dark crop
(99.5th percentile of luma below 200) is multiplied by a gain (at most 3, shown as "x1.8" in the
caption) so that its 99.5th percentile is 200. Sheets hold COLS x ROWS crops of one tile, captioned with the proposal number n
(id "r{r}c{c}-{n:03d}"). Context views: per tile the whole tile enlarged 2 x with every proposal's
number at its peak, and the four quadrants enlarged 4 x with the numbers (for dense tiles).

Usage: ``python make_label_sheets.py BANNER.jpg PROPOSALS.json OUTDIR``
"""
import json
import os
import sys

import cv2
import numpy as np

TILE = 280
CROP = 48
ZOOM = 3
COLS, ROWS = 8, 5
CAP = 16  # caption height (px)
PAD_BGR = (70, 50, 40)


def crop(tile, s):
    h = CROP // 2
    u, v = s["u_peak"], s["v_peak"]
    out = np.empty((CROP, CROP, 3), np.uint8)
    out[:] = PAD_BGR
    x0, y0 = u - h, v - h
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + CROP, TILE), min(y0 + CROP, TILE)
    out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = tile[sy0:sy1, sx0:sx1]
    # dark crops are brightened by a gain (multiplicative, so relative contrast is kept)
    inside = out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0]
    p = float(np.percentile(cv2.cvtColor(inside, cv2.COLOR_BGR2GRAY), 99.5))
    gain = 1.0
    if p < 200:
        gain = min(200.0 / max(p, 1.0), 3.0)
        inside[:] = np.clip(inside.astype(np.float32) * gain, 0, 255).astype(np.uint8)
    big = cv2.resize(out, (CROP * ZOOM, CROP * ZOOM), interpolation=cv2.INTER_NEAREST)
    # cross around the peak pixel, its arms from 3 to 6 px away from it (the peak and its
    # neighbours are not covered)
    cx, cy = h * ZOOM + ZOOM // 2, h * ZOOM + ZOOM // 2
    cyan = (255, 255, 0)
    for d0, d1 in ((-18, -9), (9, 18)):
        cv2.line(big, (cx + d0, cy), (cx + d1, cy), cyan, 1)
        cv2.line(big, (cx, cy + d0), (cx, cy + d1), cyan, 1)
    # bounding-box corner ticks (just outside the box) when the box is wider or taller than 6 px
    bx, by, bw, bh = s["bbox"]
    if max(bw, bh) > 6:
        X0 = (bx - x0) * ZOOM - 2
        Y0 = (by - y0) * ZOOM - 2
        X1 = (bx + bw - x0) * ZOOM + 1
        Y1 = (by + bh - y0) * ZOOM + 1
        yel = (0, 230, 255)
        t = 5
        for X, Y, dx, dy in ((X0, Y0, 1, 1), (X1, Y0, -1, 1), (X0, Y1, 1, -1), (X1, Y1, -1, -1)):
            cv2.line(big, (X, Y), (X + dx * t, Y), yel, 1)
            cv2.line(big, (X, Y), (X, Y + dy * t), yel, 1)
    return big, gain


def sheet(tile_id, tile, props, page):
    W = COLS * (CROP * ZOOM + 4) + 4
    H = ROWS * (CROP * ZOOM + CAP + 4) + 4 + 22
    img = np.full((H, W, 3), 255, np.uint8)
    first, last = props[0]["n"], props[-1]["n"]
    cv2.putText(img, f"tile {tile_id}  sheet {page}  proposals {first}-{last}", (6, 16),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for k, s in enumerate(props):
        r, c = divmod(k, COLS)
        x = 4 + c * (CROP * ZOOM + 4)
        y = 26 + r * (CROP * ZOOM + CAP + 4)
        big, gain = crop(tile, s)
        cap = f"{s['n']}" + (f"   x{gain:.1f}" if gain > 1.0 else "")
        cv2.putText(img, cap, (x + 2, y + 12), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (0, 0, 200), 1, cv2.LINE_AA)
        img[y + CAP:y + CAP + CROP * ZOOM, x:x + CROP * ZOOM] = big
    return img


def context(tile, props, zoom, x0=0, y0=0, size=TILE):
    sub = tile[y0:y0 + size, x0:x0 + size]
    big = cv2.resize(sub, (size * zoom, size * zoom), interpolation=cv2.INTER_NEAREST)
    for s in props:
        u, v = s["u_peak"] - x0, s["v_peak"] - y0
        if not (0 <= u < size and 0 <= v < size):
            continue
        X, Y = int(u * zoom + zoom // 2), int(v * zoom + zoom // 2)
        cv2.circle(big, (X, Y), 1, (255, 255, 0), -1)
        txt = str(s["n"])
        for col, th in (((0, 0, 0), 3), ((255, 255, 255), 1)):
            cv2.putText(big, txt, (X + 3, Y - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.33, col, th,
                        cv2.LINE_AA)
    return big


def main(banner, proposals, outdir):
    img = cv2.imread(banner, cv2.IMREAD_COLOR)
    tiles = json.load(open(proposals))["tiles"]
    os.makedirs(os.path.join(outdir, "context"), exist_ok=True)
    index = []
    per = COLS * ROWS
    for tid, props in tiles.items():
        r, c = int(tid[1]), int(tid[3])
        tile = img[r * TILE:(r + 1) * TILE, c * TILE:(c + 1) * TILE]
        for page in range(0, len(props), per):
            name = f"{tid}_s{page // per:02d}.png"
            cv2.imwrite(os.path.join(outdir, name), sheet(tid, tile, props[page:page + per],
                                                          page // per))
            index.append({"sheet": name, "tile": tid, "n_first": props[page]["n"],
                          "n_last": props[min(page + per, len(props)) - 1]["n"]})
        cv2.imwrite(os.path.join(outdir, "context", f"{tid}_x2.png"), context(tile, props, 2))
        h = TILE // 2
        for q, (x0, y0) in enumerate(((0, 0), (h, 0), (0, h), (h, h))):
            cv2.imwrite(os.path.join(outdir, "context", f"{tid}_q{q}_x4.png"),
                        context(tile, props, 4, x0, y0, h))
    json.dump(index, open(os.path.join(outdir, "index.json"), "w"), indent=1)
    print(len(index), "sheets")


if __name__ == "__main__":
    main(*sys.argv[1:4])
