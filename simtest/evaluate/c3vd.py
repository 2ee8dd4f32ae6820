"""Reading a sequence in the layout of the C3VD dataset (colonoscopy video with ground truth).

Layout
------
One folder per sequence, frames numbered ``NNNN`` (four or more digits):

- ``NNNN_color.png``: the 8-bit RGB frame (required);
- ``NNNN_normals.tiff``: 16-bit, 3 channels, the surface normal in the camera frame (OpenCV
  axes) encoded ``n = 2 v / 65535 - 1``, renormalised here (required);
- ``NNNN_depth.tiff``: 16-bit z-depth, ``mm = v / 65535 * 100``, 0 and 65535 invalid (optional,
  but then for every frame);
- ``NNNN_occlusion.png``: non-zero where the ground truth is occluded (optional, every frame);
- other files are ignored.

A missing required file, optional files for only some frames, a size mismatch or a file of the
wrong kind is refused with one line naming the file. Normals are oriented to face the camera.

From the dataset's renderer (``render/Render.cu`` of DurrLab/C3VD [1]_): normals are the flat
*face* normals of the registered mesh, a miss written as zeros (so a zero normal is invalid);
depth is the z-depth of the first hit; the occlusion mask marks a fold behind the surface seen,
which this reader treats as invalid (conservative). C3VD is CC BY-NC-SA 4.0; simtest ships none
of its data.

References
----------
.. [1] T. L. Bobrow, M. Golhar, R. Vijayan, V. S. Akshintala, J. R. Garcia, N. J. Durr,
   "Colonoscopy 3D video dataset with paired depth from 2D-3D registration", Medical Image
   Analysis 90, 2023, doi:10.1016/j.media.2023.102956.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest.geometry.cameras import CameraModel
from simtest.reconstruct.images import c3vd_depth_mm, quiet_stderr, read_tiff

__all__ = ["C3VDError", "C3VDFrame", "GroundTruth", "load_frame", "scan_sequence"]

_NAME = re.compile(r"^(\d{4,})_(color|normals|depth|occlusion)\.(png|tiff?)$")
_EXT = {"color": ("png",), "occlusion": ("png",), "normals": ("tiff", "tif"), "depth": ("tiff", "tif")}
#: Largest 16-bit value: C3VD's normals are ``2 v / 65535 - 1``.
U16 = 65535


class C3VDError(ValueError):
    """A sequence cannot be read; the one-line message names the file."""


@dataclass(frozen=True)
class C3VDFrame:
    """The files of one frame.

    Attributes
    ----------
    index : str
        The frame number as in the file names (``"0000"``).
    color, normals : Path
        Colour frame and ground-truth normals.
    depth, occlusion : Path or None
        Optional depth and occlusion mask.
    """

    index: str
    color: Path
    normals: Path
    depth: Path | None = None
    occlusion: Path | None = None


@dataclass(frozen=True)
class GroundTruth:
    """Ground truth of one frame.

    Attributes
    ----------
    normals : ndarray of shape (H, W, 3)
        Unit normals, camera frame, facing the camera; NaN where invalid (zero, occluded).
    depth_mm : ndarray of shape (H, W) or None
        z-depth, mm; NaN where invalid (0, 65535, occluded).
    """

    normals: np.ndarray
    depth_mm: np.ndarray | None


def scan_sequence(seq_dir) -> list[C3VDFrame]:
    """List and check the frames of a sequence folder (module docstring).

    Parameters
    ----------
    seq_dir : str or Path
        The sequence folder.

    Returns
    -------
    list of C3VDFrame
        Sorted by frame number.

    Raises
    ------
    C3VDError
        Missing folder, no frame, a frame missing its colour or normals file, depth or occlusion
        files for some frames only, or a file with a wrong extension for its kind.
    """
    seq = Path(seq_dir)
    if not seq.is_dir():
        raise C3VDError(f"{seq}: sequence folder not found")
    found: dict[str, dict[str, Path]] = {}
    for p in sorted(seq.iterdir()):
        m = _NAME.match(p.name)
        if not m or not p.is_file():
            continue
        idx, kind, ext = m.groups()
        if ext not in _EXT[kind]:
            raise C3VDError(f"{p}: a {kind} file must be .{_EXT[kind][0]}, not .{ext}")
        if kind in found.setdefault(idx, {}):
            raise C3VDError(f"{p}: frame {idx} has two {kind} files ({found[idx][kind].name})")
        found[idx][kind] = p
    if not found:
        raise C3VDError(f"{seq}: no frame files (NNNN_color.png, NNNN_normals.tiff) in this folder")
    for idx, kinds in sorted(found.items()):
        for need, ext in (("color", "png"), ("normals", "tiff")):
            if need not in kinds:
                raise C3VDError(f"{seq / f'{idx}_{need}.{ext}'}: missing (frame {idx} has {', '.join(sorted(kinds))})")
    for opt, ext in (("depth", "tiff"), ("occlusion", "png")):
        have = [i for i, k in found.items() if opt in k]
        if have and len(have) != len(found):
            miss = sorted(set(found) - set(have))[0]
            raise C3VDError(f"{seq / f'{miss}_{opt}.{ext}'}: missing ({len(have)} of {len(found)} frames have a {opt} file)")
    return [C3VDFrame(i, k["color"], k["normals"], k.get("depth"), k.get("occlusion")) for i, k in sorted(found.items())]


def read_color(path: Path) -> np.ndarray:
    """The 8-bit RGB frame (H, W, 3) uint8; one-line C3VDError when unreadable."""
    data = np.fromfile(path, dtype=np.uint8)
    with quiet_stderr():  # libpng's own line for a damaged file is not printed (ours names the file)
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise C3VDError(f"{path}: cannot decode the colour frame")
    channels = 1 if img.ndim == 2 else img.shape[2]
    return cv2.cvtColor(img, {1: cv2.COLOR_GRAY2RGB, 4: cv2.COLOR_BGRA2RGB}.get(channels, cv2.COLOR_BGR2RGB))


def load_frame(frame: C3VDFrame, camera: CameraModel) -> tuple[np.ndarray, GroundTruth]:
    """Read one frame and its ground truth, checked against each other and the camera.

    Parameters
    ----------
    frame : C3VDFrame
    camera : CameraModel
        The sequence's camera (its image size, when known, must match; its rays orient the normals).

    Returns
    -------
    image : ndarray of shape (H, W, 3), uint8
    truth : GroundTruth

    Raises
    ------
    C3VDError
        A file that cannot be read, of the wrong kind or of another size than the colour frame or
        the camera.
    """
    img = read_color(frame.color)
    H, W = img.shape[:2]
    if camera.image_size is not None and tuple(camera.image_size) != (W, H):
        cw, ch = camera.image_size
        raise C3VDError(f"{frame.color}: {W} x {H} px, but the camera file is for {cw} x {ch} px")
    raw = read_tiff(frame.normals, "normals", C3VDError)
    if raw.dtype != np.uint16 or raw.ndim != 3 or raw.shape[2] != 3:
        raise C3VDError(f"{frame.normals}: normals must be 16-bit with 3 channels, got {raw.dtype} of shape {raw.shape}")
    if raw.shape[:2] != (H, W):
        raise C3VDError(f"{frame.normals}: {raw.shape[1]} x {raw.shape[0]} px, but {frame.color.name} is {W} x {H} px")
    n = 2.0 * raw.astype(np.float64) / U16 - 1.0
    norm = np.linalg.norm(n, axis=2, keepdims=True)
    # a miss is all zeros in the file; a normal near zero is no direction either
    miss = (raw == 0).all(axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where((norm > 0.5) & ~miss, n / norm, np.nan)  # renormalise
    invalid = ~np.isfinite(n).all(axis=2)
    if frame.occlusion is not None:
        with quiet_stderr():
            occ = cv2.imread(str(frame.occlusion), cv2.IMREAD_GRAYSCALE)
        if occ is None:
            raise C3VDError(f"{frame.occlusion}: cannot decode the occlusion mask")
        if occ.shape != (H, W):
            raise C3VDError(f"{frame.occlusion}: {occ.shape[1]} x {occ.shape[0]} px, but {frame.color.name} is {W} x {H} px")
        invalid |= occ > 0
    depth = None
    if frame.depth is not None:
        d = read_tiff(frame.depth, "depth", C3VDError)
        if d.dtype != np.uint16 or d.ndim != 2:
            raise C3VDError(f"{frame.depth}: depth must be 16-bit single-channel, got {d.dtype} of shape {d.shape}")
        if d.shape != (H, W):
            raise C3VDError(f"{frame.depth}: {d.shape[1]} x {d.shape[0]} px, but {frame.color.name} is {W} x {H} px")
        depth = c3vd_depth_mm(d)
        if frame.occlusion is not None:
            depth[invalid & ~np.isnan(depth)] = np.nan
    # orient toward the camera along each pixel's ray
    vv, uu = np.mgrid[0:H, 0:W]
    rays = camera.pixel_to_ray(np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)).reshape(H, W, 3)
    flip = np.sum(n * rays, axis=2) > 0
    n[flip] = -n[flip]
    n[invalid] = np.nan
    return img, GroundTruth(n, depth)
