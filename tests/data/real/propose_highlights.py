"""Proposals for the hand-labelled highlights of tests/data/real (see README.md there).

Bright compact blobs: local maxima (5 x 5) of the white top-hat (luma minus its grey opening by a
21 px disc) of at least 40 levels, away from near-black pixels (the scope border and its text),
each cut at half its height above the background; the labeller then accepted or refused each
one by eye. Independent of simtest's detector (another background, level and shape rule), so
that the labels do not inherit its choices. Usage: ``python propose_highlights.py IMAGE OUT.json``.
"""
import sys, json, cv2, numpy as np

def propose(img_bgr, min_contrast=40.0):
    g = cv2.cvtColor(img_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    bg = cv2.morphologyEx(g, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (21, 21)))
    th = g - bg
    # local maxima of the top-hat
    mx = cv2.dilate(th, np.ones((5, 5), np.uint8))
    peaks = np.argwhere((th >= mx) & (th >= min_contrast))
    dark = cv2.dilate((g < 25).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    out = []
    H, W = g.shape
    seen = np.zeros(g.shape, bool)
    for r, c in peaks:
        if seen[r, c] or dark[r, c]:
            continue
        half = bg[r, c] + 0.5 * th[r, c]
        m = (g > half).astype(np.uint8)
        _, _, _, (x, y, w, h) = cv2.floodFill(m, None, (int(c), int(r)), 2, 0, 0, 4)
        comp = m[y:y+h, x:x+w] == 2
        if seen[y:y+h, x:x+w][comp].any():
            continue
        seen[y:y+h, x:x+w] |= comp
        area = int(comp.sum())
        if area < 3 or area > 2000 or x == 0 or y == 0 or x + w >= W or y + h >= H:
            continue
        rr, cc = np.nonzero(comp)
        out.append({"u": float(cc.mean() + x), "v": float(rr.mean() + y), "area": area,
                    "w": int(w), "h": int(h), "contrast": float(th[r, c])})
    return out

if __name__ == "__main__":
    img = cv2.imread(sys.argv[1])
    p = propose(img)
    json.dump(p, open(sys.argv[2], "w"))
    print(len(p))
