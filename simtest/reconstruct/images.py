"""Reading an image file for the reconstruction, with one-line errors (:class:`InputError`).

OpenCV's decoders write their complaints to file descriptor 2; :func:`quiet_stderr` captures them
so that a bad file gives one line, ``error: ...``, with the library's words folded in. Refused
before any fit: a header claiming more than :data:`MAX_IMAGE_PIXELS`; a file the decoder
complained about while decoding (damaged pixels; libpng's warnings about ancillary chunks, PNG
spec 5.4, are let through); a negative pixel value. float16 is read as float32.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from simtest._lazy import require
from simtest.reconstruct.detect import validate_image

__all__ = ["C3VD_DEPTH_RANGE_MM", "InputError", "LibraryMessages", "MAX_IMAGE_PIXELS", "c3vd_depth_mm", "decoder_damage",
           "load_image", "quiet_stderr", "read_tiff"]

#: The most pixels (W x H) of an image the reconstruction reads: 2^26, eight times a 4K sensor; a
#: header claiming more is damaged or a decompression bomb.
MAX_IMAGE_PIXELS = 1 << 26

# FFmpeg's log level (read when OpenCV loads the backend): 8 = AV_LOG_FATAL, quiet in workers too
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "8")
os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


class InputError(ValueError):
    """A user-facing input problem, reported as one line."""


class LibraryMessages:
    """What C libraries wrote to standard error inside :func:`quiet_stderr` (filled on exit)."""

    def __init__(self) -> None:
        self.text = ""

    def brief(self, limit: int = 160) -> str:
        """The messages on one line, colour codes removed, cut to ``limit`` characters."""
        line = " ".join(_ANSI.sub("", self.text).split())
        return line if len(line) <= limit else line[: limit - 3] + "..."


@contextmanager
def quiet_stderr() -> Iterator[LibraryMessages]:
    """Capture what is written to file descriptor 2 (C libraries: libpng, FFmpeg, VTK) meanwhile.

    The descriptor is pointed at a temporary file and restored on exit, whatever happens; Python's
    ``sys.stderr`` is flushed first so that nothing of ours is captured. The whole process is
    affected meanwhile, so keep the block to the library call.

    Yields
    ------
    LibraryMessages
        Its ``text`` holds the captured bytes (decoded, errors replaced) once the block ends.
    """
    messages = LibraryMessages()
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError, OSError):
        pass
    try:
        saved = os.dup(2)
    except OSError:  # no descriptor 2 at all: nothing to silence
        yield messages
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield messages
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            messages.text = sink.read(64 * 1024).decode("utf-8", "replace")


#: libpng's warning about an ancillary chunk (lower-case first letter: PNG spec 5.4), e.g.
#: "libpng warning: iCCP: known incorrect sRGB profile": metadata, not pixels
_ANCILLARY_PNG_WARNING = re.compile(r"libpng warning: [a-z][A-Za-z]{3}:[^\n]*")
#: OpenCV's log prefix, "[ERROR:0@4.086] global grfmt_tiff.cpp:117 ", left out of the message
_CV_LOG_PREFIX = re.compile(r"\[\s*[A-Z]+:\d+@[\d.]+\]\s*(global\s+)?\S+:\d+\s*")


def decoder_damage(said: str) -> str:
    """What a decoder wrote while decoding, less libpng's ancillary-chunk warnings; empty when nothing else."""
    said = _CV_LOG_PREFIX.sub("", _ANCILLARY_PNG_WARNING.sub("", _ANSI.sub("", said)))
    return " ".join(said.split())


def _check_pixel_limit(h: int, w: int, path: Path, what: str) -> None:
    if h * w > MAX_IMAGE_PIXELS:
        raise InputError(f"{path}: {what} {w} x {h} px ({h * w / 1e6:.0f} Mpx), over the {MAX_IMAGE_PIXELS / 1e6:.0f} "
                         "Mpx an image may have (an endoscope's 4K frame is 8.3 Mpx)")


def _header_size(path: Path) -> None:
    """Refuse ``path`` when its header (read lazily by Pillow) claims more than :data:`MAX_IMAGE_PIXELS`;
    formats Pillow does not know are left to the decoder.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                w, h = im.size
    except Image.DecompressionBombError as exc:  # over Pillow's own 2 x 89 Mpx: over ours too
        n = re.search(r"\((\d+) pixels\)", str(exc))
        claims = f"{int(n.group(1)) / 1e6:.0f} Mpx" if n else "more pixels than Pillow opens"
        raise InputError(f"{path}: the header claims {claims}, over the {MAX_IMAGE_PIXELS / 1e6:.0f} Mpx "
                         f"an image may have (an endoscope's 4K frame is 8.3 Mpx)") from None
    except Exception:  # noqa: BLE001 - not Pillow's format or a damaged header: the decoder decides
        return
    _check_pixel_limit(int(h), int(w), path, "the header claims")


_EXPECTED = "expected an image: shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), dtype uint8, uint16 or float16/32/64"


def _check_layout(shape, dtype, path: Path) -> None:
    """:class:`InputError` naming ``path``, its shape and dtype, unless they are an image's."""
    dtype = np.dtype(dtype)
    ok_rank = len(shape) == 2 or (len(shape) == 3 and shape[2] in (1, 3, 4))
    ok_dtype = (dtype.kind == "f" and dtype.itemsize <= 8) or dtype in (np.uint8, np.uint16)
    if not (ok_rank and ok_dtype):
        shown = dtype.str if dtype.kind in "US" else dtype  # '<U1' says what numpy's name 'str32' hides
        raise InputError(f"{path}: holds an array of shape {tuple(shape)}, dtype {shown}; {_EXPECTED}")


def _npy_header(path: Path):
    """(shape, dtype) from a ``.npy`` header without loading it; None for a header version not parsed here.
    InputError if the file is not a ``.npy`` file or cannot be read.
    """
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            read = {(1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read is None:
                return None
            shape, _, dtype = read(fh, max_header_size=1 << 20)
            return shape, dtype
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc.strerror or exc}") from None
    except (ValueError, SyntaxError, EOFError, TypeError) as exc:
        raise InputError(f"{path}: not a NumPy .npy file ({' '.join(str(exc).split())[:120]})") from None


def _checked(img: np.ndarray, path: Path) -> np.ndarray:
    """``img`` unchanged if the reconstruction accepts it, else :class:`InputError` naming ``path``."""
    _check_layout(img.shape, img.dtype, path)
    _check_pixel_limit(int(img.shape[0]), int(img.shape[1]), path, "holds")
    if img.dtype == np.float16:  # exact in float32, which the pipeline takes
        img = img.astype(np.float32)
    try:
        validate_image(img, where=str(path))  # size and finiteness, in the pipeline's own words
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if img.dtype.kind == "f" and img.size and float(img.min()) < 0.0:
        neg = img < 0
        r, c = (int(v) for v in np.argwhere(neg)[0][:2])
        value = float(img[r, c].min()) if img.ndim == 3 else float(img[r, c])
        raise InputError(f"{path}: pixel (row {r}, col {c}) is {value:g}, below 0 ({int(neg.sum())} negative "
                         f"values): a pixel counts light, no sensor writes a negative value")
    return img


def load_image(path) -> "np.ndarray":  # noqa: F821
    """Read an image file for the reconstruction.

    Parameters
    ----------
    path : str or Path
        A ``.npy`` array, or any image format OpenCV decodes (PNG, JPEG, TIFF, ...).

    Returns
    -------
    ndarray of shape (H, W), (H, W, 3) or as stored in the ``.npy``
        Gray or RGB (alpha dropped); uint8, uint16 or float as stored (float16 as float32).

    Raises
    ------
    InputError
        If the path is a folder, is missing, or cannot be read or decoded, the decoder reported
        damage, the header claims too many pixels, or it holds an array the reconstruction does not
        take; the message names the file, its shape and dtype, or the pixel.
    """

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a folder, not an image file")
    if not path.is_file():
        raise InputError(f"image file not found: {path}")
    if path.suffix.lower() == ".npy":
        header = _npy_header(path)
        if header is not None:  # refused before loading: a 1-D, 0-D, string or object array
            _check_layout(*header, path)
            if len(header[0]) >= 2:
                _check_pixel_limit(int(header[0][0]), int(header[0][1]), path, "holds an array of")
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"cannot read image {path}: {exc}") from None
        return _checked(arr, path)

    _header_size(path)
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc}") from None
    cv_said = ""
    with quiet_stderr() as lib:
        try:
            img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        except cv2.error as exc:  # OpenCV's own size limit, an unsupported layout
            img, cv_said = None, " ".join(str(exc).split("error:")[-1].split())
    if img is None:
        said = lib.brief() or cv_said
        raise InputError(f"cannot decode image {path} (empty, corrupt or not an image format"
                         + (f"; the decoder said: {said})" if said else ")"))
    damage = decoder_damage(lib.text)
    if damage:
        raise InputError(f"{path}: damaged: the decoder reported "
                         f"{damage if len(damage) <= 160 else damage[:157] + '...'}")
    if img.ndim == 3 and img.shape[2] in (3, 4):  # OpenCV's BGR(A) to RGB, alpha dropped (any depth: cvtColor
        img = np.ascontiguousarray(img[..., 2::-1])  # takes 8U, 16U and 32F only, a TIFF holds more)
    return _checked(img, path)


#: C3VD's 16-bit depth maps hold ``v / 65535 * 100`` mm; 0 and 65535 hold no depth.
C3VD_DEPTH_RANGE_MM = 100.0


def read_tiff(path, what: str, error: type[Exception] = ValueError) -> np.ndarray:
    """A TIFF file's array as tifffile reads it (any bit depth and channel count).

    Parameters
    ----------
    path : str or Path
    what : str
        What the file holds ("depth", "normals"), for the message.
    error : type of Exception
        Raised, with one line naming the file, ``what`` and tifffile's reason, when it cannot be read.
    """
    try:
        return require("tifffile").imread(path)
    except Exception as exc:  # tifffile raises many types for a corrupt file
        raise error(f"{path}: cannot read the {what} TIFF ({type(exc).__name__}: {exc})") from None


def c3vd_depth_mm(raw: np.ndarray) -> np.ndarray:
    """A C3VD depth map (uint16, (H, W), ``v / 65535 * 100`` mm; Bobrow et al. 2023, Med. Image
    Anal. 90:102956) as depth along the optical axis, mm, float64; NaN where it holds 0 or 65535
    (no surface)."""
    full = np.iinfo(np.uint16).max
    return np.where((raw == 0) | (raw == full), np.nan, raw.astype(np.float64) / full * C3VD_DEPTH_RANGE_MM)
