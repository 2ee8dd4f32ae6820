"""Compiled (numba) kernel of the ground truth's highlight search: the bisector image.

:func:`bisector_cos` computes, in one pass over the frame, what
:func:`simtest.render.truth.bisector_cos_image_numpy` computes in about twenty whole-frame numpy
passes and their temporaries (on a 1350 x 1080 frame 122 to 184 ms per light on the 2-core VM,
against 18 ms here), with the same float32 operations in the same order, so its results are the same bits:
``tests/test_render.py`` compares the two on random frames, zeros and signed zeros included. The
numpy form stays in the code as the reference.

The order that makes the bits: each ``np.einsum("ijk,ijk->ij", a, b)`` of numpy sums the three
products from a zero, left to right, in float32 (``((0 + a0 b0) + a1 b1) + a2 b2``; the zero start
turns a sum of negative zeros into a positive zero); ``np.sqrt`` and the divisions round once, as
here. numba does not contract ``a * b + c`` into a fused multiply-add unless ``fastmath`` is set
(it is not), so the arithmetic rounds as numpy's; ``error_model="numpy"`` makes a division by a
zero length give inf or NaN as numpy does, not raise. Compiled with ``cache=True`` (see
:mod:`simtest.reconstruct._kernels`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["bisector_cos"]


@numba.njit(inline="always", error_model="numpy")
def _dot3(a0, a1, a2, b0, b1, b2):
    s = np.float32(0.0)
    s += a0 * b0
    s += a1 * b1
    s += a2 * b2
    return s


@numba.njit(cache=True, nogil=True, error_model="numpy")
def bisector_cos(normals, position, mask, light, colocated, out):
    """``n . h`` per pixel into ``out`` (float32), -1 outside ``mask``.

    Parameters
    ----------
    normals, position : ndarray of shape (H, W, 3), float32 or float64
        Unit normals and surface points, camera frame (mm); read where ``mask`` only, each value
        rounded to float32 first (as the numpy form's ``astype``).
    mask : ndarray of shape (H, W), bool
    light : ndarray of shape (3,), float32
        Point-light position, camera frame, mm.
    colocated : bool
        The light at the camera centre: h is the unit vector toward the camera (the general
        formula's bits, :func:`simtest.render.truth.bisector_cos_image_numpy`).
    out : ndarray of shape (H, W), float32
        Written.
    """
    H, W = mask.shape
    for i in range(H):
        for j in range(W):
            if not mask[i, j]:
                out[i, j] = np.float32(-1.0)
                continue
            p0 = np.float32(position[i, j, 0])
            p1 = np.float32(position[i, j, 1])
            p2 = np.float32(position[i, j, 2])
            r = np.sqrt(_dot3(p0, p1, p2, p0, p1, p2))
            c0 = -p0 / r
            c1 = -p1 / r
            c2 = -p2 / r
            if colocated:
                rc = np.sqrt(_dot3(c0, c1, c2, c0, c1, c2))
                h0 = c0 / rc
                h1 = c1 / rc
                h2 = c2 / rc
            else:
                t0 = light[0] - p0
                t1 = light[1] - p1
                t2 = light[2] - p2
                rt = np.sqrt(_dot3(t0, t1, t2, t0, t1, t2))
                t0 /= rt
                t1 /= rt
                t2 /= rt
                h0 = c0 + t0
                h1 = c1 + t1
                h2 = c2 + t2
                rh = np.sqrt(_dot3(h0, h1, h2, h0, h1, h2))
                h0 /= rh
                h1 /= rh
                h2 /= rh
            out[i, j] = _dot3(np.float32(normals[i, j, 0]), np.float32(normals[i, j, 1]),
                              np.float32(normals[i, j, 2]), h0, h1, h2)
