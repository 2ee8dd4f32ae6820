"""Reading an image file for the reconstruction, with one-line errors (:class:`InputError`)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


class InputError(ValueError):
    """A user-facing input problem, reported as one line."""


def load_image(path) -> "np.ndarray":  # noqa: F821
    """Read an image file for the reconstruction.

    Parameters
    ----------
    path : str or Path
        A ``.npy`` array, or any image format OpenCV decodes (PNG, JPEG, TIFF, ...).

    Returns
    -------
    ndarray of shape (H, W), (H, W, 3) or as stored in the ``.npy``
        Gray or RGB (OpenCV's BGR/BGRA converted to RGB, alpha dropped); uint8, uint16 or float
        as stored.

    Raises
    ------
    InputError
        If the path is a folder, is missing, or cannot be read or decoded; the message names it.
    """

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not an image file")
    if not path.is_file():
        raise InputError(f"image file not found: {path}")
    if path.suffix.lower() == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read image {path}: {exc}") from None

    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc}") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError(f"cannot decode image {path} (empty, corrupt or not an image format)")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return img
