"""Angles between directions and orientation of normals toward the camera."""

from __future__ import annotations

import numpy as np


def cross3(a, b) -> np.ndarray:
    """Cross product of 3-vectors, bit for bit ``np.cross(a, b)``, several times cheaper.

    The same products and differences (``a1 b2 - a2 b1``, ...), without ``np.cross``'s axis handling,
    which costs more than the arithmetic on a few vectors.

    Parameters
    ----------
    a, b : array_like of shape (3,) or (..., 3)
        Vectors (any units), broadcast against each other.

    Returns
    -------
    ndarray of shape (3,) or the broadcast shape (..., 3), float64
    """
    if np.shape(a) == np.shape(b) == (3,):
        a0, a1, a2 = (float(v) for v in a)
        b0, b1, b2 = (float(v) for v in b)
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def angle_between_deg(a, b) -> np.ndarray | float:
    """Angle between direction vectors, in degrees, as ``atan2(|a x b|, a . b)`` (accurate near 0 and 180).

    Parameters
    ----------
    a, b : array_like of shape (..., 3)
        Direction vectors (need not be unit), broadcast against each other.

    Returns
    -------
    float or ndarray of shape (...)
        Angle in [0, 180] degrees; NaN where either vector is zero or non-finite.

    Raises
    ------
    ValueError
        If the last axis of ``a`` or ``b`` is not of length 3.

    Examples
    --------
    >>> round(float(angle_between_deg([0, 0, 1], [0, 1, 1])), 12)
    45.0
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape[-1:] != (3,) or b.shape[-1:] != (3,):
        raise ValueError(f"angle_between_deg needs (..., 3) vectors, got {a.shape} and {b.shape}")
    axb = cross3(a, b)
    cross = np.linalg.norm(axb, axis=-1)
    dot = np.sum(a * b, axis=-1)
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    ang = np.degrees(np.arctan2(cross, dot))
    ang = np.where((na > 0) & (nb > 0) & np.isfinite(ang), ang, np.nan)
    return float(ang) if ang.ndim == 0 else ang


def unit(v, axis: int | None = None) -> np.ndarray:
    """``v`` scaled to unit length: ``v / |v|``; the one normalisation of directions in simtest.

    Parameters
    ----------
    v : array_like of shape (3,) or (..., 3)
        Non-zero direction(s) (any length).
    axis : int, optional
        None (default): ``v`` is one vector, divided by its norm (``np.linalg.norm(v)``).
        ``-1``: ``v`` is a stack of vectors along its last axis, each divided by its own norm.
        The two differ in the last bit (a dot product against a sum of squares), so a caller keeps
        the one it was written with.

    Returns
    -------
    ndarray, float64, the shape of ``v``
        The unit vector(s); NaN (with a numpy warning) where ``v`` is zero.
    """
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v) if axis is None else v / np.linalg.norm(v, axis=axis, keepdims=True)
