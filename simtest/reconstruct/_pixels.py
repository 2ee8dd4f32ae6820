"""Pixel-coordinate conventions of the reconstruction package, in one place.

An array index ``(row, col)`` is the pixel ``(u, v) = (col, row)``, pixel centres at integer
coordinates (as :func:`skimage.measure.find_contours` and OpenCV): ``image[10, 20]`` is centred
at ``(u, v) = (20, 10)``. :func:`rc_to_uv` and its inverse :func:`uv_to_rc` are the only
functions of :mod:`simtest.reconstruct` that swap them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


def rc_to_uv(rc, row0: float = 0.0, col0: float = 0.0) -> np.ndarray:
    """Turn array coordinates (row, col) into pixel coordinates (u, v) = (col, row).

    Parameters
    ----------
    rc : array_like of shape (..., 2)
        Array coordinates (row, col), possibly sub-pixel, relative to a sub-array whose first
        element is ``image[row0, col0]``.
    row0, col0 : float, optional
        Offset of the sub-array in the full image (the ROI origin).

    Returns
    -------
    ndarray of shape (..., 2), float64
        Pixel coordinates (u, v) in the full image.

    Examples
    --------
    >>> rc_to_uv([10, 20]).tolist()
    [20.0, 10.0]
    """
    rc = np.asarray(rc, dtype=np.float64)
    # (col + col0, row + row0): swapped and shifted in one operation
    return rc[..., ::-1] + np.array([col0, row0], dtype=np.float64)


def image_size_wh(shape) -> tuple[int, int]:
    """Image size (W, H) in pixels, the order of intrinsics files, from an array shape (H, W, ...).

    Examples
    --------
    >>> image_size_wh((480, 640, 3))
    (640, 480)
    """
    return int(shape[1]), int(shape[0])


def uv_to_rc(uv) -> np.ndarray:
    """Inverse of :func:`rc_to_uv` (no offset): pixel (u, v) to array (row, col).

    Parameters
    ----------
    uv : array_like of shape (..., 2)
        Pixel coordinates (u, v) = (col, row), pixel centres at integer coordinates.

    Returns
    -------
    ndarray of shape (..., 2), float64
        Array coordinates (row, col).

    Examples
    --------
    >>> uv_to_rc([20, 10]).tolist()
    [10.0, 20.0]
    """
    return np.asarray(uv, dtype=np.float64)[..., ::-1].copy()


def border_ring(a) -> np.ndarray:
    """The edge pixels of an (H, W) array, float64 (2 W + 2 H,): its first and last rows, then its first
    and last columns (each corner twice)."""
    return np.concatenate([a[0], a[-1], a[:, 0], a[:, -1]], dtype=np.float64)


class Roi(NamedTuple):
    """A rectangular region of interest in array indices, half-open: ``image[row0:row1, col0:col1]``.

    Examples
    --------
    >>> roi = Roi(2, 5, 10, 20)
    >>> roi.shape
    (3, 10)
    """

    row0: int
    row1: int
    col0: int
    col1: int

    @property
    def slices(self) -> tuple[slice, slice]:
        """``(slice(row0, row1), slice(col0, col1))``, to index an image."""
        return slice(self.row0, self.row1), slice(self.col0, self.col1)

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the region."""
        return self.row1 - self.row0, self.col1 - self.col0

    def touches_image_border(self, image_shape: tuple[int, ...]) -> tuple[bool, bool, bool, bool]:
        """Which sides (top, bottom, left, right) lie on the border of an image of that shape."""
        h, w = image_shape[:2]
        return self.row0 <= 0, self.row1 >= h, self.col0 <= 0, self.col1 >= w

    @classmethod
    def around(cls, centre_uv, half_size: float, image_shape: tuple[int, ...]) -> Roi:
        """Square ROI of half-width ``half_size`` px around ``centre_uv``, clipped to the image.

        Parameters
        ----------
        centre_uv : array_like of shape (2,)
            Centre (u, v), px.
        half_size : float
            Half-width, px; the rows and columns within it (rounded outward) are included.
        image_shape : tuple of int
            ``(H, W, ...)`` of the image.

        Returns
        -------
        Roi
            Half-open, clipped to ``[0, H) x [0, W)``.
        """
        h, w = image_shape[:2]
        if len(centre_uv) == 2:  # (u, v): the values uv_to_rc gives, without its arrays
            c, r = float(centre_uv[0]), float(centre_uv[1])
        else:
            r, c = (float(x) for x in uv_to_rc(centre_uv))
        hs = float(half_size)
        return cls(max(0, math.floor(r - hs)), min(h, math.ceil(r + hs) + 1), max(0, math.floor(c - hs)),
                   min(w, math.ceil(c + hs) + 1))

    @classmethod
    def coerce(cls, roi, image_shape: tuple[int, ...], where: str = "roi") -> Roi:
        """Validate ``(row0, row1, col0, col1)`` against an image shape.

        Parameters
        ----------
        roi : sequence of 4 integers
            ``(row0, row1, col0, col1)``, half-open array indices.
        image_shape : tuple of int
            ``(H, W, ...)`` of the image.
        where : str
            Name used in the error message (e.g. the CLI option or JSON key).

        Returns
        -------
        Roi

        Raises
        ------
        ValueError
            If ``roi`` is not 4 integers, or is empty or outside the image; the message names
            ``where`` and the value.
        """
        try:
            vals = [int(x) for x in roi]
            if len(vals) != 4 or any(float(x) != int(x) for x in roi):
                raise ValueError
        except (TypeError, ValueError):
            raise ValueError(f"{where}: expected 4 integers (row0, row1, col0, col1), got {roi!r}") from None
        r0, r1, c0, c1 = vals
        h, w = image_shape[:2]
        if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w):
            raise ValueError(f"{where}: (row0, row1, col0, col1) = {tuple(vals)} is empty or outside the image of "
                             f"shape {(h, w)}")
        return cls(r0, r1, c0, c1)
