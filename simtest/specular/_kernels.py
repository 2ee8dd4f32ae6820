"""Compiled (numba) kernel of Phong's model on the plane: ``cos beta`` at many points in one pass.

:func:`plane_cos_beta` computes what ``phong._cos_beta_numpy`` computes with a dozen whole-array
numpy passes and their temporaries, for points on the plane z = 0 (the paper protocol's 406 x 406
texture, drawn anew for each realisation with a moving light), with the same float64 operations in
the same order, so its results are the same bits: ``tests/test_specular.py`` compares the two. The
numpy form stays in the code as the reference and serves points off the plane.

The order that makes the bits: numpy evaluates ``vx * rx + vy * ry + vz * rz`` left to right, the
z products (one value for every point on the plane) once; ``np.sqrt`` and the division round once,
as here. numba does not contract ``a * b + c`` into a fused multiply-add unless ``fastmath`` is set
(it is not); ``error_model="numpy"`` makes a zero length give inf or NaN as numpy does, not raise.
Compiled with ``cache=True`` (see :mod:`simtest.reconstruct._kernels`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["plane_cos_beta", "plane_cos_beta_from"]


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cos_beta_at(px, py, V, R, vzrz, vzvz, rzrz):
    """``cos beta`` at the plane point (px, py), the z terms given (one value on the plane)."""
    vx = V[0] - px
    vy = V[1] - py
    rx = px - R[0]
    ry = py - R[1]
    dot = vx * rx + vy * ry + vzrz
    norms = np.sqrt(vx * vx + vy * vy + vzvz) * np.sqrt(rx * rx + ry * ry + rzrz)
    return dot / norms


@numba.njit(cache=True, nogil=True, error_model="numpy")
def plane_cos_beta(pxy, V, R):
    """``cos beta`` of Phong's model (paper eq. 1) at points of the plane z = 0.

    Parameters
    ----------
    pxy : ndarray of shape (N, 2), float64
        Points ``(x, y)`` on the plane, scene-plane frame.
    V, R : ndarray of shape (3,), float64
        The viewer and the mirror image of the light ``(L_X, L_Y, -L_Z)``.

    Returns
    -------
    ndarray of shape (N,), float64
        ``(V - P) . (P - R) / (|V - P| |P - R|)`` (NaN or inf where a length is 0, as numpy).
    """
    vz = V[2] - 0.0
    rz = 0.0 - R[2]
    vzrz, vzvz, rzrz = vz * rz, vz * vz, rz * rz
    n = pxy.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = _cos_beta_at(pxy[i, 0], pxy[i, 1], V, R, vzrz, vzvz, rzrz)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def plane_cos_beta_from(pxy, origin, V, R):
    """:func:`plane_cos_beta` at the points ``pxy + origin``, each coordinate added as ``np.add``
    adds it (one float64 addition), without building those points (the paper protocol's texture
    is a fixed grid of offsets moved to each realisation's window centre).

    Parameters
    ----------
    pxy : ndarray of shape (N, 2), float64
        Offsets ``(x, y)`` on the plane.
    origin : ndarray of shape (2,), float64
        What is added to each offset, scene-plane frame.
    V, R : ndarray of shape (3,), float64
        As :func:`plane_cos_beta`.

    Returns
    -------
    ndarray of shape (N,), float64
    """
    vz = V[2] - 0.0
    rz = 0.0 - R[2]
    vzrz, vzvz, rzrz = vz * rz, vz * vz, rz * rz
    ox, oy = origin[0], origin[1]
    n = pxy.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = _cos_beta_at(pxy[i, 0] + ox, pxy[i, 1] + oy, V, R, vzrz, vzvz, rzrz)
    return out
