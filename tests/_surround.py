"""The verifier's surround share of other light, one candidate at a time: the plain reference of
:func:`simtest.reconstruct.evidence_pixels.surround_fractions` (which batches it)."""

from __future__ import annotations

import cv2
import numpy as np

from simtest.reconstruct.evidence_pixels import ellipse_level


def surround_fraction(gray: np.ndarray, ell, bp_ij: np.ndarray, reach: float, own_level: float,
                      rel: float) -> float:
    """Share of the surround's pixels (within ``reach`` of the BP pixel ``bp_ij`` (column, row),
    where :func:`ellipse_level` of the primary isophote ``ell`` exceeds ``own_level``) whose local
    top-hat (the luma less its grey opening by a square about as wide as the reach) is at least
    ``rel`` of the peak's (its maximum over the 3 x 3 px around the BP). 0 without a surround
    or a peak."""
    h, w = gray.shape
    R = int(np.ceil(reach))
    bi, bj = int(bp_ij[1]), int(bp_ij[0])
    r0, r1 = max(0, bi - R), min(h, bi + R + 1)
    c0, c1 = max(0, bj - R), min(w, bj + R + 1)
    yy = np.arange(r0, r1, dtype=np.float64)[:, None]
    xx = np.arange(c0, c1, dtype=np.float64)[None, :]
    ring = ((xx - bp_ij[0]) ** 2 + (yy - bp_ij[1]) ** 2 <= reach * reach) & (ellipse_level(ell, xx, yy) > own_level)
    if not ring.any():
        return 0.0
    win = np.ascontiguousarray(gray[r0:r1, c0:c1], dtype=np.float32)
    k = max(3, R | 1)  # odd, about the reach
    top = win - cv2.morphologyEx(win, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)),
                                 borderType=cv2.BORDER_REPLICATE)
    peak = float(top[max(0, bi - 1 - r0):bi + 2 - r0, max(0, bj - 1 - c0):bj + 2 - c0].max())
    if not peak > 0:
        return 0.0
    return float(np.count_nonzero((top >= rel * peak) & ring) / np.count_nonzero(ring))
