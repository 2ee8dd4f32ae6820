"""Specularity detection on a whole image: candidate highlights, their BP, ROI, or a reason.

A candidate highlight is an 8-connected component of bright pixels (``gray >= brightness_rel *
full_scale``; outer boundaries by OpenCV ``findContours``, each filled in its bounding box: faster
than ``connectedComponentsWithStats`` on a sparse frame; a component inside the hole of another is
counted with it). For each candidate the detector finds the
brightest point (BP): the centroid of the saturated plateau when the highlight is clipped, else
the brightest pixel refined to sub-pixel by a separable parabola through its 3x3 neighbourhood
(or the centroid of its flat top when quantisation makes several pixels equal to the maximum).
It gives a square region of interest around the BP, large enough to hold the low isophotes, and a
status: ``"ok"`` or the reason the candidate is rejected:
- ``too_small``: fewer than ``min_area_px`` pixels (noise, glints of a few pixels).
- ``touches_border``: the component reaches the image border, so its isophotes are cut.
- ``merged``: several separate saturated plateaus (two highlights run together).
- ``not_elliptical``: the filled area is far from that of the ellipse with the same second
  moments (``area / (4 pi sqrt(det Sigma))`` outside [``ellipticity_min``, 1 /
  ``ellipticity_min``]; it is 1 for a filled ellipse, 0.83 for an equilateral triangle and lower
  for rings, crescents and L shapes).

Image types: (H, W) gray, (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA (alpha ignored); dtype uint8,
uint16 or floating. Full scale is the dtype maximum for integers and ``max(1, max(image))`` for
floats unless given. The intensity used everywhere is the Rec. 601 luma
``0.299 R + 0.587 G + 0.114 B``; a pixel is saturated (clipped white, as a specular highlight is)
when every channel is at ``saturation_level`` (default: the integer dtype maximum; none for float
images). A single clipped channel does not count: the red channel of tissue clips over broad
diffuse areas in endoscopy.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import repeat
from operator import add

import cv2
import numpy as np

from simtest._records import fast_init
from simtest.constants import LUMA_BT601, gaussian_radius_px
from simtest.reconstruct import _detect_kernels as _dk
from simtest.reconstruct import _kernels
from simtest.reconstruct._pixels import Roi, rc_to_uv

_LUMA = np.array(LUMA_BT601)
_LUMA_WEIGHTS = tuple(float(w) for w in LUMA_BT601)
#: Image dtypes whose float64 luma :func:`luma` computes by one compiled pass
#: (:func:`simtest.reconstruct._kernels.luma_rgb`, the bits of ``image @ _LUMA``).
_LUMA_COMPILED = (np.uint8, np.uint16, np.float32, np.float64)


def connected_components(mask: np.ndarray) -> tuple[int, np.ndarray]:
    """8-connected components of a uint8 mask (count with the background, int32 labels), by
    Grana's block-based algorithm: the default of the installed OpenCV (Spaghetti) took 57 ms on a
    1350 x 1080 mask where this takes 3 ms; the components are the same."""
    return cv2.connectedComponentsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)


def connected_components_with_stats(mask: np.ndarray):
    """As :func:`connected_components`, with the stats and centroids of
    ``cv2.connectedComponentsWithStats``."""
    return cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)


def connected_components_boxes(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """:func:`connected_components_with_stats` without the centroids: ``(n, labels, stats)``, the
    same labels and the same stats rows of the components (1 to ``n - 1``), the labels by OpenCV
    and the stats by one compiled pass over them (:func:`simtest.reconstruct._detect_kernels.label_stats`).
    OpenCV's statistics made its labelling four times slower (0.59 against 0.16 ms on a band of
    the noisy bench frame); ``tests/test_detect_kernels.py`` checks that both agree."""
    n, labels = connected_components(mask)
    return n, labels, _dk.label_stats(labels, n)


def _bands(mask: np.ndarray) -> list[tuple[int, int]]:
    """The runs of rows of ``mask`` that hold mask pixels, as half-open (row0, row1), row0 widened
    to an even index (Grana's algorithm labels by 2 x 2 blocks: a band keeps the whole mask's
    blocks, so its components come in the whole mask's order)."""
    nz = np.flatnonzero(mask.max(axis=1))
    if nz.size == 0:
        return []
    gaps = np.flatnonzero(np.diff(nz) > 1)
    starts = np.concatenate([nz[:1], nz[gaps + 1]])
    ends = np.concatenate([nz[gaps], nz[-1:]]) + 1
    return [(r0 - r0 % 2, r1) for r0, r1 in zip(starts.tolist(), ends.tolist())]


def _label_band(mask: np.ndarray, r0: int, r1: int):
    """:func:`connected_components_boxes` of the band ``mask[r0:r1]`` cropped to the columns
    that hold mask pixels, the first widened to an even index: ``(c0, n, labels, stats)``, the
    labels and stats relative to (r0, c0)."""
    band = mask[r0:r1]
    cols = np.flatnonzero(band.max(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    c0 -= c0 % 2
    n, lab, stats = connected_components_boxes(np.ascontiguousarray(band[:, c0:c1]))
    return c0, n, lab, stats


def mask_components(mask: np.ndarray) -> list[tuple[int, int, int, int, int, np.ndarray]]:
    """The 8-connected components of a uint8 0/1 mask, each with its area and bounding box.

    Parameters
    ----------
    mask : ndarray of shape (H, W), uint8

    Returns
    -------
    list of (area, x, y, width, height, comp)
        In the label order of :func:`connected_components_with_stats`; ``comp`` is the component's uint8 0/1 mask in its box (rows
        ``y : y + height``, columns ``x : x + width`` of ``mask``).

    Notes
    -----
    The mask is labelled band by band: a band is a run of rows that hold mask pixels, cropped to
    the columns that do, both widened to start at an even index. No 8-connected component crosses
    an empty row, so the components are those of one pass over the whole mask; Grana's algorithm
    numbers them in the order of their first 2 x 2 block, and a band aligned to even rows and
    columns has the whole mask's blocks, so the order is the same too. A sparse mask (a few
    highlights in a 1350 x 1080 frame) costs a third of one pass.
    """
    out = []
    for r0, r1 in _bands(mask):
        c0, n, lab, stats = _label_band(mask, r0, r1)
        for k in range(1, n):
            x, y, bw, bh, area = (int(v) for v in stats[k])
            out.append((area, x + c0, y + r0, bw, bh, (lab[y : y + bh, x : x + bw] == k).view(np.uint8)))
    return out


def mask_labels(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The 8-connected components of a uint8 0/1 mask as a label image, band by band.

    Parameters
    ----------
    mask : ndarray of shape (H, W), uint8

    Returns
    -------
    n : int
        Number of components (background not counted).
    labels : ndarray of shape (H, W), int32
        0 for the background, ``k`` for the pixels of component ``k`` (1 to ``n``).
    stats : ndarray of shape (n, 5), int32
        Per component ``x, y, width, height, area``: the bounding box (columns ``x : x +
        width``, rows ``y : y + height``) and the pixel count.

    Notes
    -----
    The labels, boxes and order of :func:`connected_components_with_stats` over the whole mask
    (and of :func:`mask_components`), from its bands (see there): a mask whose bright pixels fill
    a few runs of rows is labelled in those alone, the label image outside them is never written
    (1.3 ms against 3 ms for one pass over a 1350 x 1080 frame with ten highlights). Where the
    bands hold more than half the rows, one pass over the whole mask is cheaper (3.9 ms against
    5.3 ms on the bench's colonoscope frame) and is taken.
    """
    return _mask_labels(mask, np.zeros)


def _mask_labels(mask: np.ndarray, alloc) -> tuple[int, np.ndarray, np.ndarray]:
    """:func:`mask_labels`, the label image of several bands made by ``alloc(shape, dtype)``:
    ``np.zeros`` gives the documented image; ``np.empty`` leaves the pixels outside the bands'
    boxes (rows of a band, columns from its first to its last mask pixel, each box written whole
    by ``paste_labels``) unwritten, for a caller that reads the labels inside the components'
    bounding boxes only, which lie in those boxes (zeroing a 1350 x 1080 int32 image takes 0.3 ms,
    a fiftieth of the noisy bench frame)."""
    h, w = mask.shape
    bands = _bands(mask)
    if not bands:
        return 0, np.zeros((h, w), np.int32), np.zeros((0, 5), np.int32)
    if 2 * sum(r1 - r0 for r0, r1 in bands) > h:
        # bands over most rows: one pass costs less than theirs and the copies
        n, labels, stats = connected_components_boxes(mask)
        return n - 1, labels, stats[1:]
    labels = None
    parts = []
    n = 0
    for r0, r1 in bands:
        c0, nb, lab, stats = _label_band(mask, r0, r1)
        if lab.shape == (h, w):
            labels = lab  # one band: the whole mask
        else:
            if labels is None:
                labels = alloc((h, w), np.int32)
            _dk.paste_labels(labels[r0:r1, c0 : c0 + lab.shape[1]], lab, n)
        stats = stats[1:]
        stats[:, cv2.CC_STAT_LEFT] += c0
        stats[:, cv2.CC_STAT_TOP] += r0
        parts.append(stats)
        n += nb - 1
    return n, labels, np.concatenate(parts)


_SUPPORTED = (np.uint8, np.uint16, np.float16, np.float32, np.float64)


@fast_init
@dataclass(frozen=True)
class Candidate:
    """One candidate highlight.

    Attributes
    ----------
    bp_uv : ndarray of shape (2,)
        Brightest point (u, v), px (sub-pixel).
    peak : float
        Intensity at the BP (max of the luma in the component), image units.
    saturated : bool
        True if the BP is the centroid of a clipped plateau.
    area_px : int
        Pixels in the component.
    bbox : Roi
        Bounding box of the component.
    roi : Roi
        Region of interest proposed for the isophotes.
    status : str
        ``"ok"`` or a reason (see module docstring).
    detail : str
        Numbers behind a rejection.
    level : float or None
        Intensity level (image units) at which the component was cut out with
        ``method="local_peak"`` (its local background plus ``peak_rel`` of its height); None with
        ``method="full_scale"`` (the level is ``Detection.threshold``).
    """

    bp_uv: np.ndarray
    peak: float
    saturated: bool
    area_px: int
    bbox: Roi
    roi: Roi
    status: str = "ok"
    detail: str = ""
    level: float | None = None


@dataclass(frozen=True)
class Detection:
    """All candidates found in an image, accepted (``status == "ok"``) or not.

    Attributes
    ----------
    candidates : list of Candidate
        Every examined candidate.
    full_scale : float
        Full scale of the image (image units) the relative thresholds refer to.
    threshold : float
        Brightness level of the candidate masks, image units (``brightness_rel * full_scale``).
    n_unexamined : int
        The smallest components left out beyond ``max_candidates`` (not examined, not in
        ``candidates``).
    smoothed : ndarray of shape (H, W), float32, or None
        The smoothed gray detection examined (read-only), when it smoothed (``smooth_sigma_px``
        > 0) at full resolution: for a colour 8-bit or 16-bit RGB frame its unrounded float32
        luma (``luma32``), for a gray frame (R = G = B), a single-channel or a float image the
        luma itself; the pipeline contours every ROI of the frame in it (one smoothing per frame).
    gray : ndarray of shape (H, W) or None
        The gray detection examined before any smoothing (not to be written): OpenCV's gray of an RGB
        frame (rounded to whole levels for 8-bit and 16-bit frames; the channel itself where
        R = G = B), the image itself when single-channel.
    grey : bool or None
        Whether the image's R, G and B are equal, where detection found out (an 8-bit RGB frame:
        its gray is then the R channel, :func:`_gray_and_grey`); None where it did not ask.
    half : ndarray of shape (H // 2, W // 2), float32, or None
        The means of ``gray``'s 2 x 2 blocks, where detection reduced the frame (at half
        resolution, or in :func:`local_peak_mask` of the unsmoothed gray; read-only; the
        verifier reduces its opening's blocks from them).
    luma32 : ndarray of shape (H, W), float32, or None
        The unrounded luma of a colour 8-bit or 16-bit RGB frame
        (:func:`compiled_luma` in float32, read-only), where detection smoothed it at full
        resolution (``smoothed`` is its smoothing): the pipeline's own float32 luma, which it
        then neither computes nor smooths again.
    """

    candidates: list[Candidate] = field(default_factory=list)
    full_scale: float = 1.0
    threshold: float = 0.0
    n_unexamined: int = 0
    smoothed: np.ndarray | None = None
    gray: np.ndarray | None = None
    grey: bool | None = None
    half: np.ndarray | None = None
    luma32: np.ndarray | None = None

    @property
    def n_components(self) -> int:
        """Bright components found: the examined candidates and those left out."""
        return len(self.candidates) + self.n_unexamined

    @property
    def accepted(self) -> list[Candidate]:
        """Candidates with status ``"ok"``."""
        return [c for c in self.candidates if c.status == "ok"]

    @property
    def rejected(self) -> list[Candidate]:
        """Candidates with a rejection reason."""
        return [c for c in self.candidates if c.status != "ok"]


def validate_image(image, where: str = "image") -> np.ndarray:
    """Check an image and return it as (H, W) or (H, W, 3) without copying when possible.

    Parameters
    ----------
    image : array_like of shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4)
        Gray, RGB or RGBA (alpha dropped); uint8, uint16 or float16/32/64; H, W >= 3.
    where : str
        Name used in error messages (a file name or argument name).

    Returns
    -------
    ndarray of shape (H, W) or (H, W, 3)
        Same dtype; a view of ``image`` where possible.

    Raises
    ------
    ValueError
        Naming ``where``: not an array, rank not 2 or 3, channels not 1, 3 or 4, empty, dtype not
        uint8/uint16/float, or non-finite pixels.
    """
    if isinstance(image, (str, bytes)) or image is None:
        raise ValueError(f"{where}: expected an image array, got {type(image).__name__}")
    arr = np.asarray(image)
    if arr.dtype.type not in _SUPPORTED:
        raise ValueError(
            f"{where}: dtype {arr.dtype} not supported (use uint8, uint16 or float16/32/64)"
        )
    if arr.ndim == 3 and arr.shape[2] in (1, 3, 4):
        arr = arr[:, :, 0] if arr.shape[2] == 1 else arr[:, :, :3]
    elif arr.ndim != 2:
        raise ValueError(
            f"{where}: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {arr.shape}"
        )
    if arr.shape[0] < 3 or arr.shape[1] < 3:
        raise ValueError(f"{where}: image of shape {arr.shape} is empty or smaller than 3 x 3")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = ~np.isfinite(arr)
        r, c = np.argwhere(bad)[0][:2]
        raise ValueError(
            f"{where}: {int(bad.sum())} non-finite values (NaN or inf), first at row {r}, col {c}"
        )
    return arr


def default_full_scale(image: np.ndarray) -> float:
    """Full scale of an image: the level relative thresholds refer to.

    Parameters
    ----------
    image : ndarray
        A validated image (:func:`validate_image`).

    Returns
    -------
    float
        Dtype maximum for unsigned integer images (255, 65535), ``max(1, image.max())`` for floats.
    """
    if image.dtype.kind == "u":
        return float(np.iinfo(image.dtype).max)
    return max(1.0, float(image.max()))


def luma(image: np.ndarray, *, dtype=np.float64) -> np.ndarray:
    """Rec. 601 luma ``0.299 R + 0.587 G + 0.114 B`` of an RGB image.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        A validated image; a gray image is returned as is (cast).
    dtype : numpy dtype
        Output dtype (float64 by default).

    Returns
    -------
    ndarray of shape (H, W)
        Intensity in image units (no rescaling).

    Notes
    -----
    A float64 luma of a uint8, uint16, float32 or float64 image is one compiled pass
    (:func:`simtest.reconstruct._kernels.luma_rgb`), the bits of numpy's ``image @ weights``
    without its float64 copy of the image; each pixel's value depends on that pixel only, so
    an ROI's luma is the same bits as the frame's luma sliced.
    """
    if image.ndim == 2:
        return image.astype(dtype, copy=False)
    if np.dtype(dtype) == np.float64 and image.dtype.type in _LUMA_COMPILED:
        return compiled_luma(image, np.float64)
    return (image.astype(dtype, copy=False) @ _LUMA.astype(dtype)).astype(dtype, copy=False)


def colour_luma32(image: np.ndarray, grey: bool) -> np.ndarray | None:
    """The unrounded luma of a colour 8- or 16-bit RGB frame in float32 (H, W), read-only
    (:func:`compiled_luma`); None for any other frame (single-channel, gray (R = G = B), float,
    RGBA). ``grey``: whether R = G = B (the caller's answer: detection's, or the pipeline's
    test). Detection smooths it and the pipeline contours in it, so both take it from here."""
    if grey or image.ndim != 3 or image.shape[2] != 3 or image.dtype.type not in (np.uint8, np.uint16):
        return None
    out = compiled_luma(image, np.float32)
    out.setflags(write=False)
    return out


def compiled_luma(image: np.ndarray, dtype) -> np.ndarray:
    """The Rec. 601 luma (H, W) of an (H, W, 3) image in float64 or float32, by the compiled
    kernels: :func:`~simtest.reconstruct._kernels.luma_rows` where its pixels are packed along
    its rows (:func:`packed_rows`; vectorised, a quarter of the time), else
    :func:`~simtest.reconstruct._kernels.luma_rgb` (float64) or
    :func:`~simtest.reconstruct._kernels.luma_rgb32` (float32); the same bits either way."""
    rows = packed_rows(image)
    if rows is None:
        kernel = _kernels.luma_rgb if np.dtype(dtype) == np.float64 else _kernels.luma_rgb32
        return kernel(image, *_LUMA_WEIGHTS)
    out = np.empty(image.shape[:2], dtype)
    _kernels.luma_rows(rows, *_LUMA_WEIGHTS, out)
    return out


def packed_rows(img: np.ndarray) -> np.ndarray | None:
    """The rows (H, 3 W) of an (H, W, 3) image whose pixels are packed along its rows (channel and
    pixel strides of one and three items: a C-contiguous frame or a slice of its rows and columns),
    as a view for :func:`~simtest.reconstruct._kernels.luma_rows`; None for any other layout."""
    if img.ndim != 3 or img.shape[2] != 3:
        return None
    it = img.itemsize
    if img.strides[2] != it or img.strides[1] != 3 * it or img.strides[0] < 3 * it * img.shape[1]:
        return None
    return np.lib.stride_tricks.as_strided(img, shape=(img.shape[0], 3 * img.shape[1]), strides=(img.strides[0], it),
                                           writeable=False)


def _gray_native(image: np.ndarray) -> np.ndarray:
    """Fast luma for thresholding: OpenCV for uint8/uint16/float32 RGB, numpy otherwise."""
    if image.ndim == 2:
        return image
    if image.dtype in (np.uint8, np.uint16, np.float32):
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return luma(image)


def _gray_and_grey(image: np.ndarray) -> tuple[np.ndarray, bool | None]:
    """:func:`_gray_native` of an image and whether its R, G and B are equal (None: not asked).
    A C-contiguous 8-bit RGB frame is tested and, where gray, its R channel taken as its gray in
    one compiled pass (:func:`~simtest.reconstruct._kernels.grey_channel_packed`: OpenCV's gray
    of R = G = B is R, ``tests/test_detect.py`` checks it); a colour one stops at its first
    colour row and is converted by OpenCV."""
    if image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8 and image.flags.c_contiguous:
        out = np.empty(image.shape[:2], np.uint8)
        if _kernels.grey_channel_packed(image.reshape(image.shape[0], -1), out):
            return out, True
        return _gray_native(image), False
    return _gray_native(image), None


def _threshold_mask(gray: np.ndarray, thr: float) -> np.ndarray:
    """uint8 mask (0/1) of ``gray >= thr``, by cv2.threshold where the dtype allows."""
    if gray.dtype == np.uint8 or gray.dtype == np.uint16:
        t = float(np.ceil(thr)) - 1.0  # integer x >= thr  <=>  x > ceil(thr) - 1
        if t < 0:
            return np.ones(gray.shape, np.uint8)
        m = cv2.threshold(gray, t, 1, cv2.THRESH_BINARY)[1]
        return m if m.dtype == np.uint8 else m.astype(np.uint8)
    if gray.dtype == np.float32 or gray.dtype == np.float64:
        t = float(np.nextafter(gray.dtype.type(thr), gray.dtype.type(-np.inf)))
        return cv2.threshold(gray, t, 1, cv2.THRESH_BINARY)[1].astype(np.uint8)
    return (gray >= thr).view(np.uint8)


def refine_peak_uv(values: np.ndarray, r: int, c: int) -> np.ndarray:
    """Sub-pixel peak from the separable parabola through the 3x3 neighbourhood of (r, c).

    Along each axis a parabola through the three values gives the offset
    ``0.5 (a - d) / (a - 2 b + d)``, clipped to +-0.5 px; an axis with no strict maximum
    (non-negative curvature) or on the border keeps offset 0.

    Parameters
    ----------
    values : ndarray of shape (H, W)
        Intensities.
    r, c : int
        Array index (row, col) of the integer maximum.

    Returns
    -------
    ndarray of shape (2,)
        Peak (u, v), px, pixel centres at integer coordinates.
    """
    h, w = values.shape
    dr = dc = 0.0
    if 0 < r < h - 1:
        a, b, d = float(values[r - 1, c]), float(values[r, c]), float(values[r + 1, c])
        den = a - 2 * b + d
        if den < 0:
            dr = min(max(0.5 * (a - d) / den, -0.5), 0.5)
    if 0 < c < w - 1:
        a, b, d = float(values[r, c - 1]), float(values[r, c]), float(values[r, c + 1])
        den = a - 2 * b + d
        if den < 0:
            dc = min(max(0.5 * (a - d) / den, -0.5), 0.5)
    return rc_to_uv([r + dr, c + dc])


def peak_uv(values: np.ndarray, r: int, c: int, mask: np.ndarray | None = None) -> np.ndarray:
    """Sub-pixel BP (u, v) at the maximum ``values[r, c]`` of an unclipped highlight.

    A unique maximum is refined by :func:`refine_peak_uv`. A flat top (several 8-connected pixels
    equal to the maximum, as 8-bit quantisation makes of a broad lobe) gives the centroid of that
    plateau instead: a parabola through equal values would sit half a pixel off.

    Parameters
    ----------
    values : ndarray of shape (H, W)
        Intensities.
    r, c : int
        Array index (row, col) of a maximum.
    mask : ndarray of shape (H, W), bool, optional
        Restricts the plateau to these pixels (the candidate's component).

    Returns
    -------
    ndarray of shape (2,)
        BP (u, v), px, pixel centres at integer coordinates.
    """
    top = values == values[r, c]
    if mask is not None:
        top &= mask
    r0, r1, c0, c1 = max(0, r - 1), r + 2, max(0, c - 1), c + 2
    if np.count_nonzero(top[r0:r1, c0:c1]) <= 1:
        return refine_peak_uv(values, r, c)
    _, lab = connected_components(top.view(np.uint8) if top.dtype == bool else top.astype(np.uint8))
    rr, cc = np.nonzero(lab == lab[r, c])
    return rc_to_uv([rr.mean(), cc.mean()])


def ellipticity(mask: np.ndarray) -> float:
    """Ellipticity ``area / (4 pi sqrt(det Sigma))`` of a binary mask.

    ``Sigma`` is the second-moment matrix of the pixels, each a unit square (its own 1/12 per
    axis added to the spread of the centres).

    Parameters
    ----------
    mask : ndarray of shape (H, W), bool
        The component.

    Returns
    -------
    float
        1 for a filled ellipse, about 0.83 for an equilateral triangle, lower for rings and
        crescents; NaN for fewer than 3 pixels or a singular ``Sigma``.
    """
    rr, cc = np.nonzero(mask)
    n = rr.size
    if n < 3:
        return float("nan")
    # np.cov(np.stack([rr, cc]).astype(float), bias=True) step by step, without its argument
    # handling (most of its time on a small component): the same operations, the same bits
    x = np.array([rr, cc], dtype=np.float64)
    x -= x.mean(axis=1)[:, None]
    cov = np.dot(x, x.T.conj())
    cov *= np.true_divide(1, n)
    # a pixel is a unit square: add its own second moment (1/12 per axis) to the centres' spread
    det = (cov[0, 0] + 1 / 12) * (cov[1, 1] + 1 / 12) - cov[0, 1] ** 2
    return float(n / (4 * np.pi * np.sqrt(det))) if det > 0 else float("nan")


#: Detection methods: ``"local_peak"`` (the default: relative to each highlight's own height
#: above its local background) and ``"full_scale"`` (a fixed fraction of full scale, the former
#: default).
DETECT_METHODS = ("local_peak", "full_scale")


def noise_sigma(gray: np.ndarray) -> float:
    """Robust standard deviation of the pixel noise of an image, image units.

    The median absolute deviation of the difference between each pixel and the mean of its two
    horizontal neighbours, ``d = x - (left + right) / 2`` (a smooth image has ``d ~ 0``; for white
    noise of variance s^2, ``var d = 1.5 s^2``), scaled to a standard deviation:
    ``s = 1.4826 MAD(d) / sqrt(1.5)``.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        Intensities (W >= 3).

    Returns
    -------
    float
        Estimated noise standard deviation (0 for a noise-free smooth or quantised-flat image).
    """
    return _noise_sigma_of_rows(_noise_rows(gray))


def _noise_rows(image: np.ndarray) -> np.ndarray:
    """The rows :func:`noise_sigma` reads: ~50 rows (tens of thousands of pixels) are plenty for
    a median."""
    return image[:: max(1, image.shape[0] // 48)]


def _noise_sigma_of_rows(rows: np.ndarray) -> float:
    """:func:`noise_sigma` of the rows it reads (h, W)."""
    if rows.dtype == np.uint8 and rows.shape[1] >= 3 and rows.shape[0] >= 1:
        mad = _mad_of_uint8_rows(rows)
    else:
        g = rows.astype(np.float32)
        d = (g[:, 1:-1] - 0.5 * (g[:, :-2] + g[:, 2:])).ravel()
        mad = _median(np.abs(d - _median(d)))  # float32, as its float32 data
    return float(1.4826 * mad / np.sqrt(1.5))


def _median(a: np.ndarray):
    """``np.median`` of a 1-D float array, the same value, by one partition at the upper middle
    index (the lower middle value is the largest below it): numpy's median partitions at both
    middle indices at once, twice the time (2.6 -> 1.4 ms for the two medians of the banner's
    noise estimate, 107 000 float32 values; ``tests/test_detect.py`` compares them)."""
    n = a.size
    if n == 0 or np.isnan(a).any():
        return np.median(a)
    k = n // 2
    # middle order statistics at 0, where most values tie there (the differences of a JPEG or
    # clean frame's flat rows): counted, not selected (a partition among that many ties took 2 of
    # the 2.7 ms of the bench video frame's noise estimate); 0 (a -0.0 among them reads as 0.0)
    below = np.count_nonzero(a < 0)
    if below <= k - 1 + n % 2 and k < below + np.count_nonzero(a == 0):
        return a.dtype.type(0)
    p = np.partition(a, k)
    if n % 2:
        return p[k]
    return (p[:k].max() + p[k]) / a.dtype.type(2)


def _mad_of_uint8_rows(rows: np.ndarray) -> np.float32:
    """``np.median(np.abs(d - np.median(d)))`` of :func:`_noise_sigma_of_rows` for uint8 rows,
    by counting: the same float32 value.

    For 8-bit intensities ``2 d = 2 x - (left + right)`` is an integer in [-510, 510] and numpy's
    float32 arithmetic on ``d`` is exact (multiples of 1/2, of 1/4 after the median is taken off,
    far within float32's 24 bits), so both medians are order statistics read off histograms of
    integers, the mean of the two middle ones for an even count as ``np.median`` takes it (one
    compiled call, :func:`simtest.reconstruct._detect_kernels.mad_of_uint8_rows`). On the bench's
    noisy 1350 x 1080 frame (50 rows, 67 400 values) this takes about 0.05 ms; numpy's histograms took
    0.31 ms and its two partitions 1.6 ms (``tests/test_detect.py`` compares with ``np.median``).
    """
    return np.float32(_dk.mad_of_uint8_rows(np.ascontiguousarray(rows)))


def auto_smooth_sigma_px(gray: np.ndarray, full_scale: float) -> float:
    """Gaussian smoothing for detection and contouring chosen from the image's noise.

    0 (none) when the noise is below 0.5 % of full scale (renders, clean frames: 8-bit JPEG
    ringing included), else ``min(2.5, 1 + noise / (1 % of full scale))`` px: 2 px for 1 %,
    2.5 px from 1.5 % (a Gaussian of sigma s divides white noise by ``2 s sqrt(pi)``: 2 px cut it
    sevenfold, enough to keep one highlight in one component; more blurs small highlights away).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
    full_scale : float

    Returns
    -------
    float
        Sigma in px, >= 0.
    """
    return _sigma_for_noise(noise_sigma(gray) / full_scale)


def image_smooth_sigma_px(image: np.ndarray, full_scale: float) -> float:
    """:func:`auto_smooth_sigma_px` of a validated image's luma, computed on the rows the noise
    estimate reads only (the luma is per pixel, so these are the same values as those rows of
    the whole image's luma; a 1350 x 1080 RGB frame needs 49 rows of it, not 1080).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        A validated image (:func:`validate_image`).
    full_scale : float

    Returns
    -------
    float
        Sigma in px, >= 0.
    """
    return _sigma_for_noise(image_noise_sigma(image) / full_scale)


def image_noise_sigma(image: np.ndarray) -> float:
    """:func:`noise_sigma` of a validated image's luma (OpenCV's gray of an RGB image), read on
    the rows the estimate reads only (what :func:`image_smooth_sigma_px` measures).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, 3)
        A validated image (:func:`validate_image`).

    Returns
    -------
    float
        Image units, >= 0.
    """
    return _noise_sigma_of_rows(_gray_native(_noise_rows(image)))


def smooth_sigma_for_noise(noise: float, full_scale: float) -> float:
    """:func:`auto_smooth_sigma_px`'s choice for a measured ``noise`` (image units), px."""
    return _sigma_for_noise(noise / full_scale)


def _sigma_for_noise(s: float) -> float:
    return 0.0 if s < 0.005 else float(min(2.5, 1.0 + s / 0.01))


def _area_reduced(img: np.ndarray, f: int, halves: list | None = None) -> np.ndarray:
    """The means of the ``f`` x ``f`` blocks of a float32 image whose sides are multiples of f:
    ``cv2.resize(img, (W // f, H // f), interpolation=cv2.INTER_AREA)``, as a chain of 2 x 2
    reductions (OpenCV's vectorised path, a third of the general integer one's time on a 1350 x
    1080 frame) and one by the odd rest (:func:`~simtest.reconstruct._detect_kernels.block_means`);
    the same means to float32 rounding (the sums grouped otherwise). ``halves``: the first 2 x 2 reduction is appended to it (for f even)."""
    h, w = img.shape[:2]
    while f % 2 == 0 and f > 1:
        h, w, f = h // 2, w // 2, f // 2
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        if halves is not None and not halves:
            halves.append(img)
    if f > 1:  # the odd rest in one compiled pass (OpenCV's general area path: twice its time)
        out = np.empty((h // f, w // f), np.float32)
        _dk.block_means(img, f, out)
        img = out
    return img


def _scope_border(gray: np.ndarray, level: float, half: np.ndarray | None = None) -> np.ndarray | None:
    """The endoscope's black border: pixels below ``level`` joined to at least two image corners,
    when they cover 1 % to 60 % of the image (a dark scene, such as a render on black, is not a
    scope border); closed (the text drawn on it) and dilated by about 5 px (the edge of the field
    of view). Found on the image reduced 4 times (the mean of each 4 x 4 block; the last rows and
    columns that fill no block are left out of the reduction, and the border mask is brought back
    over the whole image): the border is large and its edge needs no finer place. None if there
    is none. ``half``: the means of ``gray``'s 2 x 2 blocks (float32, (H // 2, W // 2)) where the
    caller has them (:func:`local_peak_mask`'s): the reduction's first step, not made again
    (0.4 ms of a 1350 x 1080 frame; the same blocks' means)."""
    h, w = gray.shape
    f = 4 if min(h, w) >= 64 else 1
    if f > 1:
        # the reduced image's corners (the corner blocks' means, as the reduction gives them):
        # fewer than two dark, no border, without reducing the whole frame (0.5 ms of a clean
        # 1350 x 1080 frame without a scope border)
        hf, wf = h // f * f, w // f * f
        dark = 0
        for r, c in ((0, 0), (0, wf - f), (hf - f, 0), (hf - f, wf - f)):
            block = np.ascontiguousarray(gray[r : r + f, c : c + f], dtype=np.float32)
            dark += bool(cv2.resize(block, (1, 1), interpolation=cv2.INTER_AREA)[0, 0] < level)
        if dark < 2:
            return None
    # whole f x f blocks (the last h mod f rows and w mod f columns left out): OpenCV's integer
    # area reduction, a third of the time of the fractional one over the whole image
    if f == 4 and half is not None and half.shape == (h // 2, w // 2):
        small = _area_reduced(np.ascontiguousarray(half[: h // f * 2, : w // f * 2]), 2)
    else:
        small = _area_reduced(gray[: h // f * f, : w // f * f].astype(np.float32, copy=False), f) if f > 1 else gray
    border = _dark_corner_components((small < level).astype(np.uint8))
    if border is None:
        return None
    # the text drawn on the border: bright holes of the dark region (filled by closing)
    close, grow = (15 // f) | 1, (11 // f) | 1
    border = cv2.morphologyEx(border, cv2.MORPH_CLOSE, np.ones((close, close), np.uint8))
    border = cv2.dilate(border, np.ones((grow, grow), np.uint8))
    if f > 1:
        border = cv2.resize(border, (w, h), interpolation=cv2.INTER_NEAREST)
    return border.view(bool)


def _dark_corner_components(dark: np.ndarray) -> np.ndarray | None:
    """The dark 8-connected components that hold the corners of a uint8 0/1 mask (1 dark), as a
    uint8 0/1 mask, when at least two corners are dark and those components cover 1 % to 60 % of
    it; None otherwise. ``dark`` is written (the components become 2).

    A scope's field of view is round or octagonal: its black border holds the image corners. The
    components are flood-filled from the corners, each once: those of a labelling of the whole
    mask and their areas, in about half its time (0.15 to 0.22 against 0.41 to 0.44 ms on the
    noisy bench frame's reduced image, one dark region to its corners, minima of 200;
    ``tests/test_detect.py`` compares the two on random masks).
    """
    hs, ws = dark.shape
    corners = [(0, 0), (ws - 1, 0), (0, hs - 1), (ws - 1, hs - 1)]  # (x, y)
    if sum(int(dark[y, x]) for x, y in corners) < 2:
        return None
    area = 0
    for x, y in corners:
        if dark[y, x] == 1:
            area += cv2.floodFill(dark, None, (x, y), 2, 0, 0, 8)[0]
    if not 0.01 <= area / dark.size <= 0.6:
        return None
    return (dark == 2).view(np.uint8)


#: The background square of :func:`local_peak_mask` is ``min(H, W) / BACKGROUND_DIV`` px (>= 31).
BACKGROUND_DIV = 10
#: ... and at least this many times the extent of the widest clipped plateau (see
#: :func:`background_side_px`).
BACKGROUND_PLATEAU_FACTOR = 2


def clipped_mask(image: np.ndarray, saturation_level: float | None,
                 gray: np.ndarray | None = None, grey: bool = False) -> np.ndarray | None:
    """Pixels clipped white (every channel >= ``saturation_level``), uint8 0/1; None without a
    saturation level (float images).

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C)
        A validated image (:func:`validate_image`).
    saturation_level : float or None
        Image units.
    gray : ndarray of shape (H, W), optional
        The image's luma as :func:`_gray_native` gives it (OpenCV's integer Rec. 601 weights, of
        the same dtype as ``image``). Only pixels where it reaches the level are examined
        (:func:`~simtest.reconstruct._detect_kernels.clipped_where_gray`): OpenCV's luma is a
        rounded weighted mean with positive weights summing to one, so a pixel whose channels are
        all >= an integer level has a luma >= that level. The mask is the same
        (``tests/test_detect.py`` checks it against the definition); the banner's channels are
        read at a few pixels instead of over the rows of its clipped highlights (1 -> 0.2 ms).
    grey : bool, optional
        The caller knows that the image's R, G and B are equal and ``gray`` is their value (an
        8-bit gray frame: :func:`_gray_and_grey`'s channel). The mask is then the gray's, every
        channel reaching the level where it does: one ``cv2.threshold`` pass over the gray, the
        channels not read (0.17 -> 0.09 ms on the noisy bench frame). Ignored for other dtypes.

    Returns
    -------
    ndarray of shape (H, W), uint8, or None

    Notes
    -----
    For uint8 and uint16 images this is one ``cv2.inRange`` pass (an integer pixel is >= the
    level exactly when it is >= its ceiling): a twentieth of the time of numpy's comparison and
    reduction over the channels on a 1350 x 1080 RGB frame; the mask is the same.
    """
    if saturation_level is None:
        return None
    if image.dtype in (np.uint8, np.uint16) and image.ndim in (2, 3):
        top = int(np.iinfo(image.dtype).max)
        lo = float(np.ceil(saturation_level))
        if lo > top:
            return np.zeros(image.shape[:2], np.uint8)
        lo = int(max(lo, 0.0))
        nch = 1 if image.ndim == 2 else image.shape[2]
        if grey and gray is not None and image.ndim == 3 and image.dtype == np.uint8 and gray.dtype == np.uint8 \
                and gray.shape == image.shape[:2]:
            # (an integer x >= lo exactly when x > lo - 1; one pass, the 0/1 mask itself)
            return cv2.threshold(np.ascontiguousarray(gray), lo - 1, 1, cv2.THRESH_BINARY)[1]
        if gray is not None and image.ndim == 3 and lo > 0 and gray.dtype == image.dtype:
            # the channels read only where the gray reaches the level, in one compiled pass
            out = np.empty(image.shape[:2], np.uint8)
            _dk.clipped_where_gray(image, gray, lo, out)
            return out
        if gray is not None and image.ndim == 3 and lo > 0:
            rows = np.flatnonzero(gray.max(axis=1) >= lo)
            out = np.zeros(image.shape[:2], np.uint8)
            if len(rows):
                r0, r1 = int(rows[0]), int(rows[-1]) + 1
                m = cv2.inRange(np.ascontiguousarray(image[r0:r1]), (lo,) * nch, (top,) * nch)
                np.right_shift(m, 7, out=out[r0:r1])  # 255 -> 1
            return out
        m = cv2.inRange(np.ascontiguousarray(image), (lo,) * nch, (top,) * nch)
        return np.right_shift(m, 7, out=m)  # 255 -> 1
    sat = image >= saturation_level
    if sat.ndim == 3:
        sat = sat.all(axis=2)
    return sat.view(np.uint8)


def background_side_px(shape: tuple[int, int], clipped: np.ndarray | None = None) -> int:
    """Side of the background square of :func:`local_peak_mask`, px.

    ``max(31, min(H, W) // BACKGROUND_DIV)``, widened to ``BACKGROUND_PLATEAU_FACTOR`` times the
    largest bounding-box side of the clipped plateaus (8-connected) plus one.

    Parameters
    ----------
    shape : (H, W)
    clipped : ndarray of shape (H, W), uint8, optional
        Clipped pixels (:func:`clipped_mask`).

    Returns
    -------
    int

    Notes
    -----
    The grey opening by the square is the diffuse background only where the highlight is
    narrower than the square: a highlight wider than it (a lobe close to the scope that the
    auto-exposure clips together with the bright tissue around it, 70 px in a 406 px frame of
    ``colonoscope_plane``, 90 px in ``laparoscope_liver``) is taken for background, its top-hat
    is near 0 in its middle and the detector cuts its rim into pieces. A clipped plateau is part
    of a highlight, so its extent bounds the highlight's size from below; twice it leaves room
    for the unclipped flanks. The frames whose clipped plateaus are narrower than half the
    default square (every real image of tests/data, the bench frames) keep the default.
    """
    h, w = shape
    side = max(31, min(h, w) // BACKGROUND_DIV)
    rows = np.flatnonzero(clipped.max(axis=1)) if clipped is not None else ()
    if len(rows):
        # The outer boundaries of the 8-connected plateaus bound them: their bounding boxes are
        # the components' (a plateau in the hole of another lies within the other's box, so the
        # largest side is the same); a tenth of the time of labelling the frame. Only the rows
        # that hold clipped pixels are contoured (the same boxes; 0.33 against 0.14 ms on the
        # noisy bench frame, whose plateaus span 50 of its 1080 rows).
        band = clipped[rows[0] : rows[-1] + 1]
        contours, _ = cv2.findContours(band, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        ext = max(max(cv2.boundingRect(c)[2:]) for c in contours)
        side = max(side, BACKGROUND_PLATEAU_FACTOR * ext + 1)
    return side


def local_peak_mask(gray: np.ndarray, full_scale: float, *, peak_rel: float = 0.6,
                    contrast_min_rel: float = 0.08, background_px: int | None = None, _parts: list | None = None,
                    _hit_rows_only: bool = False, _half: list | None = None, _gray8: np.ndarray | None = None):
    """Bright-candidate mask relative to local peaks (``method="local_peak"``).

    The diffuse background is the grey opening of the luma by a square of side ``background_px``
    (it removes every bright structure narrower than that), computed on the image reduced by area
    averaging so that the square is about 16 px, then brought back by bilinear interpolation (the
    background is smooth at that scale; the opening at full size costs ten times more); the
    top-hat ``T = gray - background`` is the specular part. A pixel is a candidate when ``T >= peak_rel * max(T over the same
    square around it)`` (relative to its own local peak, not to full scale) and ``T >=
    contrast_min_rel * full_scale`` (it stands out of the background).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        Luma (smoothed if the caller smooths).
    full_scale : float
        Intensity of white, image units.
    peak_rel : float
        Fraction of the local top-hat peak (0.5: the half-height core of each highlight).
    contrast_min_rel : float
        Smallest top-hat, fraction of full scale.
    background_px : int, optional
        Side of the square, px; default :func:`background_side_px` without clipped pixels
        (``max(31, min(H, W) // BACKGROUND_DIV)``): wider than the highlights of endoscopic
        frames (up to about 30 px in a 1350 x 1080 frame); a broader lobe keeps a smaller core
        and its ROI grows in the pipeline.

    Returns
    -------
    mask : ndarray of shape (H, W), uint8
        1 for candidate pixels.
    background : ndarray of shape (H, W), float32
        The opening (image units).
    """
    g = gray.astype(np.float32, copy=False)
    h, w = g.shape
    side = int(background_px) if background_px else background_side_px((h, w))
    # The background is smooth at the scale of the square: open (and take the local peaks) on the
    # image reduced so that the square is ~16 px (area averaging), then back to full size.
    f = max(1, side // 16)
    whole = f > 1 and h % f == 0 and w % f == 0  # whole blocks: the reductions by 2 x 2 steps
    src8 = gray if gray.dtype == np.uint8 else _gray8
    if whole and src8 is not None and f % 2 == 0:
        # an 8-bit frame's first 2 x 2 means by one compiled pass over its bytes (OpenCV's
        # values: integer sums times 0.25 are exact in float32), not OpenCV's pass over the
        # float32 copy (0.35 ms on 1350 x 1080 px), then the rest of the chain
        first = np.empty((h // 2, w // 2), np.float32)
        _dk.half_means_uint8(src8, first)
        if _half is not None and not _half:
            _half.append(first)
        small = _area_reduced(first, f // 2)
    elif whole:
        # (``_half``: the means of g's 2 x 2 blocks, the chain's first step, for the scope border
        # and the verifier)
        small = _area_reduced(g, f, _half)
    else:
        small = cv2.resize(g, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA) if f > 1 else g
    k = max(3, side // f)
    k += 1 - k % 2
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg_small = cv2.morphologyEx(small, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)
    # whole-frame arrays are updated in place where they can be (a new 1350 x 1080 float array
    # costs as much as the arithmetic on it)
    top = np.empty_like(g)
    rows = np.empty(h, np.uint8)
    thr = np.float32(contrast_min_rel * full_scale)
    if f > 1:
        # the enlargement along the rows by OpenCV (the reduced rows), down the columns inside the
        # compiled pass: background = min(enlarged, g) (an opening never exceeds the image) and
        # top = g - background, one pass over the frame (to float32 rounding OpenCV's enlargement)
        sh = bg_small.shape[0]
        y0, y1, ay = _dk.linear_rows(h, sh)
        background = np.empty_like(g)
        _dk.top_hat_rows(np.ascontiguousarray(g), cv2.resize(bg_small, (w, sh), interpolation=cv2.INTER_LINEAR),
                         y0, y1, ay, background, top, thr, rows, _hit_rows_only)
    else:
        background = bg_small
        # background = min(background, g), top = g - background: one compiled pass
        _dk.top_hat(g, background, top, thr, rows)
    if whole:
        top_small = _area_reduced(top, f)
    else:
        top_small = cv2.resize(top, small.shape[::-1], interpolation=cv2.INTER_AREA) if f > 1 else top
    peak_small = cv2.dilate(top_small, kernel, borderType=cv2.BORDER_REPLICATE)
    # top >= peak_rel * max(local_peak, top) (the local peak is at least the pixel itself) and
    # top >= contrast_min_rel * full_scale, in float32 as numpy computes them: one compiled pass
    # (the local peaks enlarged as the background, in the rows that hold candidates only)
    mask = np.empty((h, w), np.uint8)
    if f > 1:
        _dk.peak_mask_rows(top, cv2.resize(peak_small, (w, peak_small.shape[0]), interpolation=cv2.INTER_LINEAR),
                           y0, y1, ay, np.float32(peak_rel), thr, rows, mask)
    else:
        _dk.peak_mask(top, peak_small, np.float32(peak_rel), thr, rows, mask)
    # (``_hit_rows_only``: detect_specularities reads the background at its candidates' pixels
    # only, which lie in the rows that hold a top-hat >= the threshold: the other rows' background
    # is left unwritten where the reduction is whole)
    if _parts is not None:  # the reduced background and local peaks (_detect_half_resolution)
        _parts.extend((bg_small, peak_small, f))
    return mask, background


def detect_specularities(
    image,
    *,
    brightness_rel: float = 0.7,
    full_scale: float | None = None,
    saturation_level: float | None = None,
    min_area_px: int = 4,
    ellipticity_min: float = 0.75,
    min_plateau_px: int = 2,
    roi_scale: float = 3.0,
    roi_margin_px: int = 4,
    max_candidates: int | None = None,
    smooth_sigma_px: float | None = 0.0,
    method: str = "full_scale",
    peak_rel: float = 0.6,
    contrast_min_rel: float = 0.08,
) -> Detection:
    """Find candidate specular highlights in a whole image.

    Parameters
    ----------
    image : ndarray of shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4)
        uint8, uint16 or float image (RGB channel order).
    brightness_rel : float, optional
        A pixel is bright when its luma is >= ``brightness_rel * full_scale``.
    full_scale : float, optional
        Intensity of a white pixel; default :func:`default_full_scale`.
    saturation_level : float, optional
        A pixel is clipped when every channel is >= this; default the integer dtype maximum, and
        no clipping for float images.
    min_area_px : int, optional
        Smaller components are rejected as ``too_small``.
    ellipticity_min : float, optional
        See the module docstring (``not_elliptical``); checked for components of >= 12 px.
    min_plateau_px : int, optional
        Saturated plateaus smaller than this do not count toward ``merged``.
    roi_scale, roi_margin_px : float, int, optional
        The ROI is a square of half-width ``roi_scale * max(bbox) / 2 + roi_margin_px`` around
        the BP, clipped to the image (the t = 0.1 isophote of a Phong lobe is about 2.8 times
        wider than its 0.7 level). The pipeline grows it when an isophote is cut.
    max_candidates : int, optional
        Only the largest ``max_candidates`` components are examined (a safety valve for noise;
        default None, every one);
        how many were left out is ``Detection.n_unexamined``.
    smooth_sigma_px : float or None, optional
        Gaussian smoothing of the luma before thresholding and BP search (0: none; None: chosen
        from the image's noise by :func:`auto_smooth_sigma_px`). On a noisy image it keeps one
        highlight from breaking into several components.
    method : {"full_scale", "local_peak"}
        ``"full_scale"``: bright pixels are >= ``brightness_rel * full_scale``, components found
        by their outer boundaries. ``"local_peak"``: bright pixels by :func:`local_peak_mask`
        (``peak_rel``, ``contrast_min_rel``), components by :func:`mask_components` (those
        of one ``cv2.connectedComponentsWithStats`` pass); candidates on the endoscope's black border
        (burnt-in text) get ``black_border``; saturated plateaus are counted after a 3 x 3
        closing, from 3 px, so that noise does not split one clipped top into several.
    peak_rel, contrast_min_rel : float
        See :func:`local_peak_mask` (``method="local_peak"`` only).

    Returns
    -------
    Detection
        Every candidate with its status, sorted by decreasing peak intensity.

    Raises
    ------
    ValueError
        For a bad image (see :func:`validate_image`) or bad options.

    Notes
    -----
    The candidates are examined by one compiled call over the frame's label image
    (:func:`simtest.reconstruct._detect_kernels.examine_candidates`, on uint8, uint16, float32
    and float64 intensities), with the same bits as the numpy form (``_candidates_numpy``, kept
    as the reference and the fallback, tested against it): clipped candidates, whose BP needs
    OpenCV's morphology, go through the numpy form one by one.
    """

    img = validate_image(image)
    if not 0.0 < brightness_rel < 1.0:
        raise ValueError(f"brightness_rel must be in (0, 1), got {brightness_rel!r}")
    fs = default_full_scale(img) if full_scale is None else float(full_scale)
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"full_scale must be finite and positive, got {full_scale!r}")
    if saturation_level is None and img.dtype.kind == "u":
        saturation_level = float(np.iinfo(img.dtype).max)

    if method not in DETECT_METHODS:
        raise ValueError(f"method: {method!r} is not one of {DETECT_METHODS}")
    gray, grey = _gray_and_grey(img)
    native = gray
    if smooth_sigma_px is None:
        smooth_sigma_px = auto_smooth_sigma_px(gray, fs)
    if (method == "local_peak" and smooth_sigma_px >= MULTIRES_SIGMA_MIN_PX and min(gray.shape) >= MULTIRES_SIDE_MIN_PX
            and 0.0 < peak_rel < 1.0 and max_candidates != 0):
        det = _detect_half_resolution(
            img, native, fs, saturation_level, grey=grey is True, min_area_px=min_area_px, ellipticity_min=ellipticity_min,
            min_plateau_px=min_plateau_px, roi_scale=roi_scale, roi_margin_px=roi_margin_px,
            max_candidates=max_candidates, smooth_sigma_px=float(smooth_sigma_px), peak_rel=peak_rel,
            contrast_min_rel=contrast_min_rel)
        if det is not None:
            return replace(det, grey=grey)
    luma32 = None
    if smooth_sigma_px > 0:
        # a colour frame's unrounded luma, which the pipeline contours: smoothed once for both
        # (OpenCV's gray, rounded to whole levels, was a second full-frame blur: 2.8 ms of the
        # banner's); a frame detection did not ask about is left to the pipeline
        luma32 = colour_luma32(img, grey is not False)
        gray = cv2.GaussianBlur(gray.astype(np.float32) if luma32 is None else luma32, (0, 0),
                                float(smooth_sigma_px), borderType=cv2.BORDER_REFLECT)
    h, w = gray.shape
    levels = gray32 = half = None
    clipped = None  # whole-frame clipped mask, when the method computes it
    if method == "local_peak":
        if not 0.0 < peak_rel < 1.0:
            raise ValueError(f"peak_rel must be in (0, 1), got {peak_rel!r}")
        clipped = clipped_mask(img, saturation_level, native, grey=grey is True)
        side = background_side_px((h, w), clipped)
        # the float32 intensities of the mask and of the scope border, converted once (an 8-bit
        # gray frame not smoothed: the same values as each converting its own copy)
        gray32 = gray.astype(np.float32, copy=False)
        halves: list = []
        # (``_gray8``: the 8-bit frame gray32 is the exact copy of, for its compiled 2 x 2 means)
        mask, background = local_peak_mask(gray32, fs, peak_rel=peak_rel,
                                           contrast_min_rel=contrast_min_rel, background_px=side,
                                           _hit_rows_only=True, _half=halves,
                                           _gray8=gray if gray.dtype == np.uint8 else None)
        half = halves[0] if halves else None
        thr = contrast_min_rel * fs
        levels = background
    else:
        thr = brightness_rel * fs
        mask = _threshold_mask(gray, thr)
    # Saturated plateaus are counted (``merged``) after a 3 x 3 closing; on an image smoothed
    # with sigma (noise), pieces that a closing of 2 ceil(2 sigma) + 1 px joins into one are one
    # plateau (noise and the speckle of micro-relief break one clipped top into pieces that far
    # apart), its centroid the BP.
    k_close = max(3, 2 * int(np.ceil(2.0 * smooth_sigma_px)) + 1) if smooth_sigma_px > 0 else 3
    frame = _DetectFrame(
        img=img, gray=gray, gray32=gray32, method=method, full_scale=fs, clipped=clipped, levels=levels,
        saturation_level=saturation_level, min_area_px=min_area_px,
        ellipticity_min=ellipticity_min, min_plateau_px=min_plateau_px, roi_scale=roi_scale,
        roi_margin_px=roi_margin_px, max_candidates=max_candidates, peak_rel=peak_rel,
        k_close=k_close, half=half,
    )
    found = _candidates_compiled(frame, mask, True)  # by peak
    if found is None:
        found = _candidates_numpy(frame, mask)
        found[0].sort(key=lambda c: -c.peak)
    out, n_comps = found
    smoothed = None
    if smooth_sigma_px > 0:
        smoothed = gray
        smoothed.setflags(write=False)
        half = None  # the smoothed gray's means: not the native gray's, which the verifier reads
    elif half is not None:
        half.setflags(write=False)  # the native gray's 2 x 2 means: the verifier's too
    return Detection(out, fs, thr, max(0, n_comps - len(out)), smoothed, native, grey, half=half, luma32=luma32)


#: Detection relative to local peaks on a frame smoothed by at least this sigma, px, looks for
#: its candidates on the frame reduced twice (:func:`_detect_half_resolution`): the Gaussian of
#: 2 px leaves 0.6 % of the amplitude at the reduced frame's Nyquist frequency (a quarter cycle a
#: pixel), so the reduced smoothed frame holds what the full one does.
MULTIRES_SIGMA_MIN_PX = 2.0
#: ... on frames whose sides are at least this many px (a small frame costs little), and with at
#: most this many candidates (each is examined in a window at full resolution, about 0.3 ms; a
#: frame with more is detected at full resolution).
MULTIRES_SIDE_MIN_PX = 256
MULTIRES_CANDIDATES_MAX = 64


def _detect_half_resolution(img, native, fs, saturation_level, *, grey=False, min_area_px, ellipticity_min, min_plateau_px,
                            roi_scale, roi_margin_px, max_candidates, smooth_sigma_px, peak_rel,
                            contrast_min_rel) -> Detection:
    """:func:`detect_specularities` (``method="local_peak"``) of a smoothed frame, its candidates
    found on the frame reduced twice and placed at full resolution.

    The gray is reduced by the mean of each 2 x 2 block (float32) and smoothed there by the sigma
    that, with the block's own variance (1/4 px^2), makes the full frame's ``smooth_sigma_px``;
    the background, the mask, the components, their statuses and the scope's border are those of
    the reduced frame (the background square and the areas scaled to it). Each candidate's box
    and area are scaled back; its BP is the maximum of the full frame's smoothing within 2 px of
    the reduced one's, refined by :func:`refine_peak_uv` as at full resolution (that smoothing
    computed in a window around it only), a clipped plateau's centroid scaled back; its ROI is
    proposed at full resolution. On the bench's noisy 1350 x 1080 frame: 9 -> 5.5 ms, the same
    BPs and ROIs, areas within 3 px (:mod:`simtest.reconstruct.compare` holds the results to its
    tolerance). None (the caller detects at full resolution) where the reduced frame's block grid
    is not the full one's, or with more than :data:`MULTIRES_CANDIDATES_MAX` candidates.
    ``grey``: the frame's R, G and B are equal and ``native`` is their value (as
    :func:`clipped_mask` takes it).
    """
    h, w = native.shape
    h2, w2 = h // 2, w // 2
    clipped = clipped_mask(img, saturation_level, native, grey=grey)
    side = background_side_px((h, w), clipped)
    if native.dtype == np.uint8:  # OpenCV's values, without the frame's float32 copy
        half = np.empty((h2, w2), np.float32)
        _dk.half_means_uint8(native, half)
    else:
        half = cv2.resize(native[: 2 * h2, : 2 * w2].astype(np.float32, copy=False), (w2, h2),
                          interpolation=cv2.INTER_AREA)
    sigma2 = float(np.sqrt(max(smooth_sigma_px ** 2 - 0.25, 0.0)) / 2.0)
    gray2 = cv2.GaussianBlur(half, (0, 0), sigma2, borderType=cv2.BORDER_REFLECT)
    clipped2 = None
    if clipped is not None:  # a reduced pixel is clipped where 3 or 4 of its 4 are
        clipped2 = cv2.resize(clipped[: 2 * h2, : 2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    parts: list = []
    mask2, background2 = local_peak_mask(gray2, fs, peak_rel=peak_rel, contrast_min_rel=contrast_min_rel,
                                         background_px=max(3, side // 2), _parts=parts, _hit_rows_only=True)
    bg_small, peak_small, f2 = parts
    if max(1, side // 16) != 2 * f2 or bg_small.shape != (h // (2 * f2), w // (2 * f2)):
        return None  # the reduced grids differ: the caller detects at full resolution
    k_close = max(3, 2 * int(np.ceil(2.0 * sigma2)) + 1)
    frame2 = _DetectFrame(
        img=gray2, gray=gray2, gray32=gray2, method="local_peak", full_scale=fs, clipped=clipped2,
        levels=background2, saturation_level=saturation_level, min_area_px=max(1, -(-min_area_px // 4)),
        ellipticity_min=ellipticity_min, min_plateau_px=max(1, -(-min_plateau_px // 4)), roi_scale=roi_scale,
        roi_margin_px=roi_margin_px, max_candidates=max_candidates, peak_rel=peak_rel, k_close=k_close)
    found = _candidates_compiled(frame2, mask2)
    if found is None:
        found = _candidates_numpy(frame2, mask2)
    cands2, n_comps = found
    if len(cands2) > MULTIRES_CANDIDATES_MAX:
        return None  # each costs a window at full resolution: the whole frame is cheaper
    # the full frame's smoothing, background and local peaks, written in the candidates' windows
    # only (np.empty: the rest is never read)
    gray = np.empty((h, w), np.float32)
    levels = np.empty((h, w), np.float32)
    k_close_full = max(3, 2 * int(np.ceil(2.0 * smooth_sigma_px)) + 1)
    full = _DetectFrame(
        img=img, gray=gray, gray32=None, method="local_peak", full_scale=fs, clipped=clipped, levels=levels,
        saturation_level=saturation_level, min_area_px=min_area_px, ellipticity_min=ellipticity_min,
        min_plateau_px=min_plateau_px, roi_scale=roi_scale, roi_margin_px=roi_margin_px,
        max_candidates=max_candidates, peak_rel=peak_rel, k_close=k_close_full)
    # the full frame's Gaussian (OpenCV's taps for a float image), applied in each window by
    # _dk.window_component with the frame's sides reflected: the frame's smoothing there
    kern = cv2.getGaussianKernel(2 * gaussian_radius_px(smooth_sigma_px) + 1, smooth_sigma_px).astype(np.float32).ravel()
    thr = np.float32(contrast_min_rel * fs)
    out = []
    # every candidate's window, component and examination in one compiled call (the loop of
    # _component_at_full_resolution's calls cost 40 us a candidate of glue); a candidate the
    # kernel leaves to numpy is measured again by that function
    ell_min = ellipticity_min
    boxes = np.array([tuple(c.bbox) for c in cands2], np.int64).reshape(-1, 4)
    bps2 = np.array([c.bp_uv for c in cands2], np.float64).reshape(-1, 2)
    found_k, ints, floats, comps = _dk.components_at_full_resolution(
        native, boxes, bps2, kern, bg_small, peak_small, np.float32(peak_rel), thr,
        np.zeros((0, 0), np.uint8) if clipped is None else clipped, gray, levels, float(min_area_px),
        float(ell_min), float(1.0 / ell_min), float(roi_scale), float(roi_margin_px), float(peak_rel),
        int(k_close_full), int(min_plateau_px))
    for c, ok, row, fl, cp in zip(cands2, found_k.tolist(), ints.tolist(), floats.tolist(), comps.tolist()):
        got = _from_window(full, row, fl, cp) if ok else None
        if ok and got is None:  # left to numpy: measured again
            got = _component_at_full_resolution(full, native, c, bg_small, peak_small, kern, np.float32(peak_rel), thr)
        if got is None:  # its BP's pixel is not in the full frame's mask: the reduced frame's
            b = c.bbox
            bbox = Roi(2 * b.row0, min(h, 2 * b.row1), 2 * b.col0, min(w, 2 * b.col1))
            bp = 2.0 * np.asarray(c.bp_uv, np.float64) + 0.5
            roi = Roi.around(bp, roi_scale * max(bbox.shape) / 2.0 + roi_margin_px, img.shape)
            out.append(Candidate(bp, c.peak, c.saturated, 4 * c.area_px, bbox, roi, c.status, c.detail, c.level))
            continue
        if c.status == "black_border":  # the scope's border, found on the reduced frame
            got = Candidate(got.bp_uv, got.peak, got.saturated, got.area_px, got.bbox, got.roi, c.status,
                            _rejection_detail(c.status, full, got.area_px, got.bbox), got.level)
        out.append(got)
    out.sort(key=lambda c: -c.peak)
    half.setflags(write=False)
    return Detection(out, fs, contrast_min_rel * fs, max(0, n_comps - len(out)), None, native, half=half)


def _linear_at(small: np.ndarray, shape: tuple[int, int], r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """``cv2.resize(small, shape[::-1], interpolation=cv2.INTER_LINEAR)[r0:r1, c0:c1]`` computed in
    that window only (OpenCV's sample positions and clamping at the sides; float32, to its
    rounding)."""
    sh, sw = small.shape
    h, w = shape
    if h % sh == 0 and w % sw == 0 and h // sh == w // sw and h // sh > 1:
        # an integer factor f: the enlargement of the blocks under the window and one more on
        # each side is the frame's there (as verify._upsampled)
        f = h // sh
        q0, q1 = max(0, r0 // f - 1), min(sh, (r1 - 1) // f + 2)
        p0, p1 = max(0, c0 // f - 1), min(sw, (c1 - 1) // f + 2)
        up = cv2.resize(np.ascontiguousarray(small[q0:q1, p0:p1]), ((p1 - p0) * f, (q1 - q0) * f),
                        interpolation=cv2.INTER_LINEAR)
        return up[r0 - q0 * f : r1 - q0 * f, c0 - p0 * f : c1 - p0 * f]

    def axis(n0, n1, src, dst):
        x = (np.arange(n0, n1, dtype=np.float64) + 0.5) * (src / dst) - 0.5
        i0 = np.floor(x).astype(np.int64)
        a = (x - i0).astype(np.float32)
        a[i0 < 0] = 0.0
        i0 = np.maximum(i0, 0)
        a[i0 >= src - 1] = 0.0
        i0 = np.minimum(i0, src - 1)
        return i0, np.minimum(i0 + 1, src - 1), a

    y0, y1, ay = axis(r0, r1, sh, h)
    x0, x1, ax = axis(c0, c1, sw, w)
    one = np.float32(1.0)
    top = small[y0][:, x0] * (one - ax) + small[y0][:, x1] * ax
    bot = small[y1][:, x0] * (one - ax) + small[y1][:, x1] * ax
    return top * (one - ay)[:, None] + bot * ay[:, None]


def _component_at_full_resolution(full: _DetectFrame, native, c: Candidate, bg_small, peak_small, kern: np.ndarray,
                                  peak_rel: np.float32, thr: np.float32) -> Candidate | None:
    """The full frame's component of a candidate found on the reduced frame, examined as at full
    resolution (:func:`_examine_numpy`): the window around its box (grown until the component
    lies inside it) smoothed, its background and local peaks enlarged from the reduced frame's
    (the same blocks of the full frame: their means to float32 rounding), the mask of
    :func:`local_peak_mask` there, and the 8-connected component of the BP's pixel. None when that
    pixel is not in the mask."""
    h, w = native.shape
    b = c.bbox
    m = 4
    while True:
        r0, r1 = max(0, 2 * b.row0 - m), min(h, 2 * b.row1 + m)
        c0, c1 = max(0, 2 * b.col0 - m), min(w, 2 * b.col1 + m)
        # the BP's pixel: the largest smoothed value within 2 px of the reduced frame's BP
        gc = min(max(int(round(2.0 * c.bp_uv[0] + 0.5)), c0), c1 - 1) - c0
        gr = min(max(int(round(2.0 * c.bp_uv[1] + 0.5)), r0), r1 - 1) - r0
        g = np.empty((r1 - r0, c1 - c0), np.float32)
        bg = np.empty_like(g)
        lab = np.empty(g.shape, np.int32)
        found, x, y, bw, bh, area = _dk.window_component(native, r0, r1, c0, c1, kern, bg_small, peak_small,
                                                          peak_rel, thr, gr, gc, g, bg, lab)
        if not found:
            return None
        cut = (x == 0 and c0 > 0) or (y == 0 and r0 > 0) or (x + bw == c1 - c0 and c1 < w) or (y + bh == r1 - r0 and r1 < h)
        if not cut:
            break
        m *= 2
    k = 1
    full.gray[r0:r1, c0:c1] = g
    full.levels[r0:r1, c0:c1] = bg
    got = _examine_in_window(full, g, lab, bg, k, x, y, bw, bh, area, r0, c0)
    if got is not None:
        return got
    comp = (lab[y : y + bh, x : x + bw] == k).view(np.uint8)
    return _examine_numpy(full, None, area, x + c0, y + r0, bw, bh, comp)


def _examine_in_window(full: _DetectFrame, g: np.ndarray, lab: np.ndarray, bg: np.ndarray, k: int, x: int,
                       y: int, bw: int, bh: int, area: int, r0: int, c0: int) -> Candidate | None:
    """:func:`_examine_numpy` of the component ``k`` of a window's labels ``lab`` (box at column
    ``x``, row ``y`` of the window, whose corner is the frame's row ``r0``, column ``c0``), by the
    compiled examination (:func:`simtest.reconstruct._detect_kernels.examine_candidates`) of the
    window's smoothing ``g`` and background ``bg``, without the scope's border (as
    :func:`_component_at_full_resolution` examines it): its brightest pixel, BP, status and
    level, the same bits (a clipped one's plateaus too); None where the kernel leaves the candidate to numpy.
    The window holds the whole component and touches the frame's sides only where it does (the
    caller grows it until the component is not cut), so its ``touches_border`` is the frame's;
    the ROI is proposed in the frame. 0.1 ms a candidate less than numpy's (a sixth of the
    noisy bench frame's detection)."""
    clipped = full.clipped
    win_clipped = (np.zeros((0, 0), np.uint8) if clipped is None
                   else np.ascontiguousarray(clipped[r0 : r0 + g.shape[0], c0 : c0 + g.shape[1]]))
    ell_min = full.ellipticity_min
    ints, floats = _dk.examine_candidates(
        g, lab, np.array([[k, x, y, bw, bh, area]], np.int64), win_clipped, np.zeros((0, 0), np.bool_), bg,
        float(full.min_area_px), float(ell_min), float(1.0 / ell_min), float(full.roi_scale),
        float(full.roi_margin_px), float(full.peak_rel), c0, r0, int(full.k_close), int(full.min_plateau_px),
        full.method == "local_peak")
    code = int(ints[0, _dk.STATUS])
    if code == _dk.FALLBACK:
        return None
    u, v, peak, level, e, tol = floats[0].tolist()
    bbox = Roi(y + r0, y + r0 + bh, x + c0, x + c0 + bw)
    if code == _dk.NOT_ELLIPTICAL or code == _dk.ELLIPTICITY_UNSURE:
        # as _candidates_compiled: the kernel's value decides where every value within its
        # tolerance formats the same, numpy's otherwise
        text = f"{e * (1.0 - tol):.3f}" if code == _dk.NOT_ELLIPTICAL else None
        if text is None or text != f"{e * (1.0 + tol):.3f}":
            e = ellipticity(lab[y : y + bh, x : x + bw] == k)
            text = f"{e:.3f}"
            code = _dk.OK if ell_min <= e <= 1.0 / ell_min else _dk.NOT_ELLIPTICAL
    else:
        text = ""
    status = _STATUS[code]
    bp = np.array([u, v])  # in the frame (the kernel adds the window's corner as numpy adds the box's)
    roi = Roi.around(bp, full.roi_scale * max(bw, bh) / 2.0 + full.roi_margin_px, full.img.shape)
    return Candidate(bp, peak, bool(ints[0, _dk.SATURATED]), area, bbox, roi, status,
                     _kernel_detail(code, status, full, area, bbox, text, int(ints[0, _dk.N_PLATEAUS])), level)


def _from_window(full: _DetectFrame, row: list, fl: list, cp: list) -> Candidate | None:
    """The candidate of one row of :func:`~simtest.reconstruct._detect_kernels.components_at_full_resolution`
    (``row`` its ints, ``fl`` its floats, ``cp`` its component's box, area and window corner), as
    :func:`_examine_in_window` makes it; None where the kernel leaves it to numpy (a
    :data:`~simtest.reconstruct._detect_kernels.FALLBACK`, or an ellipticity whose detail numpy's
    value decides)."""
    code = row[_dk.STATUS]
    if code in (_dk.FALLBACK, _dk.ELLIPTICITY_UNSURE):
        return None
    u, v, peak, level, e, tol = fl
    x, y, bw, bh, area = cp[:5]
    bbox = Roi(y, y + bh, x, x + bw)
    text = ""
    if code == _dk.NOT_ELLIPTICAL:
        text = f"{e * (1.0 - tol):.3f}"
        if text != f"{e * (1.0 + tol):.3f}":
            return None
    status = _STATUS[code]
    bp = np.array([u, v])
    roi = Roi.around(bp, full.roi_scale * max(bw, bh) / 2.0 + full.roi_margin_px, full.img.shape)
    return Candidate(bp, peak, bool(row[_dk.SATURATED]), area, bbox, roi, status,
                     _kernel_detail(code, status, full, area, bbox, text, row[_dk.N_PLATEAUS]), level)


@dataclass(frozen=True)
class _DetectFrame:
    """What the examination of a frame's candidates needs (the arguments of
    :func:`detect_specularities`, resolved, and the frame's arrays): ``img`` the validated image,
    ``gray`` the intensities examined (H, W), ``clipped`` the whole-frame clipped mask where the
    method computes it, ``levels`` the local background (``"local_peak"``), ``k_close`` the side
    of the wide closing of clipped pieces, ``gray32`` the gray as float32 where the method made it
    (the scope border's input; None: converted from ``gray``)."""

    img: np.ndarray
    gray: np.ndarray
    method: str
    full_scale: float
    clipped: np.ndarray | None
    levels: np.ndarray | None
    saturation_level: float | None
    min_area_px: int
    ellipticity_min: float
    min_plateau_px: int
    roi_scale: float
    roi_margin_px: int
    max_candidates: int
    peak_rel: float
    k_close: int
    gray32: np.ndarray | None = None
    #: The means of ``gray32``'s 2 x 2 blocks where :func:`local_peak_mask` computed them (the
    #: scope border's reduction starts from them), else None.
    half: np.ndarray | None = None

    def scope(self) -> np.ndarray | None:
        """The endoscope's black border (``"local_peak"`` only), see :func:`_scope_border`."""
        if self.method != "local_peak":
            return None
        return _scope_border(self.gray if self.gray32 is None else self.gray32, 0.08 * self.full_scale,
                             self.half if self.gray32 is not None else None)


def _outer_components(mask: np.ndarray) -> list[tuple[int, int, int, int, int, np.ndarray]]:
    """The components of ``method="full_scale"``: the outer boundaries of the 8-connected
    components of a uint8 0/1 mask (OpenCV ``findContours``, a raster scan: much faster than
    ``connectedComponentsWithStats`` on a sparse 1.5 Mpx mask), each filled in its bounding box
    and cut by the mask, so that a component in the hole of another is counted with it; as
    (area, x, y, width, height, comp) like :func:`mask_components`, in ``findContours``' order."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    comps = []
    for cnt in contours:
        x, y, bw, bh = cv2.boundingRect(cnt)
        comp = np.zeros((bh, bw), np.uint8)
        cv2.drawContours(comp, [cnt], -1, 1, thickness=-1, offset=(-x, -y))
        comp &= mask[y : y + bh, x : x + bw]
        comps.append((int(np.count_nonzero(comp)), x, y, bw, bh, comp))
    return comps


#: Intensity dtypes :func:`_candidates_compiled` takes (one compilation each).
_COMPILED_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)
_STATUS = {_dk.OK: "ok", _dk.TOO_SMALL: "too_small", _dk.TOUCHES_BORDER: "touches_border",
           _dk.BLACK_BORDER: "black_border", _dk.NOT_ELLIPTICAL: "not_elliptical", _dk.MERGED: "merged"}


def _kernel_detail(code: int, status: str, frame: _DetectFrame, area: int, bbox: Roi, text: str,
                   n_plateaus: int) -> str:
    """The detail of a candidate the kernel examined: ``_examine_numpy``'s words for its status."""
    if code == _dk.OK:
        return ""
    if code == _dk.MERGED:
        return f"{n_plateaus} saturated plateaus"
    return _rejection_detail(status, frame, area, bbox, text)


def _candidates_compiled(frame: _DetectFrame, mask: np.ndarray,
                         by_peak: bool = False) -> tuple[list[Candidate], int] | None:
    """The candidates of a frame's mask, as :func:`_candidates_numpy` (the same bits), examined
    by one compiled call (:func:`simtest.reconstruct._detect_kernels.examine_candidates`) on the
    frame's label image; the candidates with clipped pixels, and those the kernel declines, by
    :func:`_examine_numpy`. None (the caller takes the numpy path) for a float16 image, or
    ``method="full_scale"`` components that share pixels. With ``by_peak`` the candidates come
    in ``detect_specularities``' order (by decreasing peak, ties largest first) instead of
    :func:`_candidates_numpy`'s (largest first).
    """
    gray = frame.gray
    if gray.dtype.type not in _COMPILED_DTYPES:
        return None
    if frame.method == "local_peak":
        # the components of one labelling of the whole mask: those of mask_components, in the
        # same order; the labels are read inside the components' boxes only (the kernel,
        # _examine_numpy, ellipticity), so the image outside the bands is left unwritten
        n_comps, labels, stats = _mask_labels(mask, np.empty)
        if n_comps == 0:
            return [], 0
        table = np.empty((n_comps, 6), np.int64)
        table[:, 0] = np.arange(1, n_comps + 1)
        table[:, 1:] = stats
    else:
        comps = _outer_components(mask)
        if not comps:
            return [], 0
        n_comps = len(comps)
        labels = np.zeros(gray.shape, np.int32)
        table = np.empty((n_comps, 6), np.int64)
        for k, (area, x, y, bw, bh, comp) in enumerate(comps):
            labels[y : y + bh, x : x + bw][comp.view(bool)] = k + 1
            table[k] = (k + 1, x, y, bw, bh, area)
        if np.count_nonzero(labels) != int(table[:, 5].sum()):
            return None  # filled outer boundaries that overlap: the numpy path's masks
    scope = frame.scope()
    # largest first, ties in label order (list.sort is stable)
    table = table[np.argsort(-table[:, 5], kind="stable")[: frame.max_candidates]]
    clipped = frame.clipped
    if clipped is None and frame.saturation_level is not None:
        clipped = clipped_mask(frame.img, frame.saturation_level)
    ell_min = frame.ellipticity_min
    ell_max = 1.0 / ell_min
    ints, floats = _dk.examine_candidates(
        np.ascontiguousarray(gray), labels, table,
        np.zeros((0, 0), np.uint8) if clipped is None else clipped,
        np.zeros((0, 0), np.bool_) if scope is None else scope,
        np.zeros((0, 0), np.float32) if frame.levels is None else frame.levels,
        float(frame.min_area_px), float(ell_min), float(ell_max), float(frame.roi_scale),
        float(frame.roi_margin_px), float(frame.peak_rel), 0, 0, int(frame.k_close), int(frame.min_plateau_px),
        frame.method == "local_peak")
    n = len(table)
    codes = ints[:, _dk.STATUS]  # (a view: the ellipticities numpy decides are written back)
    # the candidates the kernel leaves to numpy, examined first: their peaks join the sort below
    declined = np.flatnonzero(codes == _dk.FALLBACK)
    redone = {k: _examine_numpy(frame, scope, area, x, y, bw, bh,
                                (labels[y : y + bh, x : x + bw] == cid).view(np.uint8))
              for k, (cid, x, y, bw, bh, area) in zip(declined.tolist(), table[declined].tolist())}
    if by_peak:
        # by decreasing peak, ties in the order above: the bits of a stable list.sort(key=-peak)
        # on the built list (the peaks are finite), without its thousands of key calls; the
        # columns are put in that order before anything is built from them
        peaks = floats[:, _dk.PEAK].copy()
        for k, c in redone.items():
            peaks[k] = c.peak
        order = np.argsort(-peaks, kind="stable")
        table, ints, floats = table[order], ints[order], floats[order]
        codes = ints[:, _dk.STATUS]
        at = np.empty(n, np.int64)
        at[order] = np.arange(n)
        redone = {int(at[k]): c for k, c in redone.items()}
    cids, xs, ys, bws, bhs, areas = table.T.tolist()
    # the rejections other than too_small (a few hundred of a real frame's thousands): their
    # words, and the ellipticities numpy decides, one by one
    words = {}
    bounds = _ellipticity_bounds_words(frame)
    rest = np.flatnonzero(codes > _dk.TOO_SMALL)
    for k, code, e, tol, n_plateaus in zip(rest.tolist(), codes[rest].tolist(),
                                           floats[rest, _dk.ELLIPTICITY].tolist(),
                                           floats[rest, _dk.ELLIPTICITY_TOL].tolist(),
                                           ints[rest, _dk.N_PLATEAUS].tolist()):
        if code == _dk.NOT_ELLIPTICAL or code == _dk.ELLIPTICITY_UNSURE:
            # numpy's value is within tol (relative) of the kernel's: the kernel's decides
            # where every value that close formats the same
            text = f"{e * (1.0 - tol):.3f}" if code == _dk.NOT_ELLIPTICAL else None
            if text is None or text != f"{e * (1.0 + tol):.3f}":
                x, y = xs[k], ys[k]
                e = ellipticity((labels[y : y + bhs[k], x : x + bws[k]] == cids[k]))
                text = f"{e:.3f}"
                code = _dk.OK if ell_min <= e <= ell_max else _dk.NOT_ELLIPTICAL
                codes[k] = code
            if code == _dk.NOT_ELLIPTICAL:
                words[k] = f"ellipticity {text} {bounds}"  # _rejection_detail's words
        else:
            words[k] = _kernel_detail(code, _STATUS[code], frame, areas[k],
                                      Roi(ys[k], ys[k] + bhs[k], xs[k], xs[k] + bws[k]), "", n_plateaus)
    codes = codes.tolist()
    # every candidate built from the columns at once (map: no Python loop), the accepted and the
    # too small (most of a real frame's thousands) with their words; a too small one's words
    # name its area, below min_area_px: a few strings, made once
    bps = list(floats[:, :2].copy())  # each candidate's BP a row of one array (views, made at once)
    new_roi = tuple.__new__  # Roi(...) without its generated __new__'s call (thousands a frame)
    bboxes = map(new_roi, repeat(Roi), zip(ys, map(add, ys, bhs), xs, map(add, xs, bws)))
    rois = map(new_roi, repeat(Roi), zip(*ints[:, _dk.ROI_ROW0:_dk.ROI_COL1 + 1].T.tolist()))
    min_area = frame.min_area_px
    small = np.where(ints[:, _dk.STATUS] == _dk.TOO_SMALL, table[:, 5], -1)
    small_words = {a: f"{a} px < {min_area}" for a in np.unique(small).tolist()}
    small_words[-1] = ""
    details = list(map(small_words.__getitem__, small.tolist()))
    for k, w in words.items():
        details[k] = w
    out = list(map(Candidate, bps, floats[:, _dk.PEAK].tolist(), (ints[:, _dk.SATURATED] != 0).tolist(), areas,
                   bboxes, rois, map(_STATUS.get, codes), details,
                   floats[:, _dk.LEVEL].tolist() if frame.levels is not None else repeat(None, n)))
    for k, c in redone.items():
        out[k] = c
    return out, n_comps


def _rejection_detail(status: str, frame: _DetectFrame, area: int, bbox: Roi,
                      ellipticity_text: str = "") -> str:
    """The numbers behind a candidate's rejection ``status`` (empty for ``"ok"``): its area, its
    box, or its ellipticity as ``ellipticity_text`` (formatted by the caller, which knows it)."""
    if status == "too_small":
        return f"{area} px < {frame.min_area_px}"
    if status == "touches_border":
        return f"bbox (row0, row1, col0, col1) = {tuple(bbox)}"
    if status == "black_border":
        return "on or within 5 px of the endoscope's black border"
    if status == "not_elliptical":
        return f"ellipticity {ellipticity_text} {_ellipticity_bounds_words(frame)}"
    return ""


def _ellipticity_bounds_words(frame: _DetectFrame) -> str:
    """The bounds in a ``not_elliptical`` candidate's detail (:func:`_rejection_detail`)."""
    return f"outside [{frame.ellipticity_min}, {1 / frame.ellipticity_min:.3f}]"


def _candidates_numpy(frame: _DetectFrame, mask: np.ndarray) -> tuple[list[Candidate], int]:
    """The candidates of a frame's mask, examined one by one with numpy and OpenCV: the reference
    form of :func:`_candidates_compiled`, and its fallback.

    Returns
    -------
    candidates : list of Candidate
        The examined candidates, largest component first (unsorted by peak).
    n_components : int
        Components found (examined or not).
    """
    comps = mask_components(mask) if frame.method == "local_peak" else _outer_components(mask)
    if not comps:
        return [], 0
    scope = frame.scope()
    comps.sort(key=lambda c: -c[0])
    return [_examine_numpy(frame, scope, *c) for c in comps[: frame.max_candidates]], len(comps)


def _examine_numpy(frame: _DetectFrame, scope: np.ndarray | None, area: int, x: int, y: int,
                   bw: int, bh: int, comp: np.ndarray) -> Candidate:
    """One candidate (a component of ``area`` px, its box at column ``x``, row ``y``, ``bw`` x
    ``bh`` px, ``comp`` its uint8 0/1 mask in the box) examined with numpy and OpenCV: its
    brightest pixel, BP, status and ROI."""
    img, gray, clipped, levels = frame.img, frame.gray, frame.clipped, frame.levels
    saturation_level, method = frame.saturation_level, frame.method
    ellipticity_min, peak_rel = frame.ellipticity_min, frame.peak_rel
    h, w = gray.shape
    close3 = np.ones((3, 3), np.uint8)
    close_wide = np.ones((frame.k_close, frame.k_close), np.uint8)
    bbox = Roi(y, y + bh, x, x + bw)
    sub_lab = comp.view(bool)
    sub_val = gray[bbox.slices]
    vals = np.where(sub_lab, sub_val, sub_val.min())
    flat = int(np.argmax(vals))
    pr, pc = divmod(flat, bw)
    peak = float(vals[pr, pc])
    status, detail, saturated = "ok", "", False
    bp_uv = None
    if saturation_level is not None:
        sat = (clipped_mask(img[bbox.slices], saturation_level) if clipped is None
               else clipped[bbox.slices]).view(bool) & sub_lab
        if sat.any():
            saturated = True
            sat8 = sat.view(np.uint8)
            min_plateau = frame.min_plateau_px
            if method == "local_peak":
                raw8 = sat8
                sat8 = cv2.morphologyEx(raw8, cv2.MORPH_CLOSE, close3) & comp
                min_plateau = max(frame.min_plateau_px, 3)
            _, _, pstats, pcent = connected_components_with_stats(sat8)
            areas = pstats[1:, cv2.CC_STAT_AREA]
            if method == "local_peak" and frame.k_close > 3 and int(np.sum(areas >= min_plateau)) > 1:
                # pieces of one clipped top, broken by noise or speckle: one plateau
                wide = cv2.morphologyEx(raw8, cv2.MORPH_CLOSE, close_wide) & comp
                _, _, wstats, wcent = connected_components_with_stats(wide)
                if int(np.sum(wstats[1:, cv2.CC_STAT_AREA] >= min_plateau)) == 1:
                    pstats, pcent = wstats, wcent
                    areas = pstats[1:, cv2.CC_STAT_AREA]
            big = int(np.argmax(areas))
            if int(np.sum(areas >= min_plateau)) > 1:
                status, detail = "merged", f"{int(np.sum(areas >= min_plateau))} saturated plateaus"
            # centroid (x, y) = (col, row) of the plateau in the bbox
            cx, cy = pcent[1 + big]
            bp_uv = rc_to_uv([cy, cx], bbox.row0, bbox.col0)
    if bp_uv is None:
        bp_uv = peak_uv(vals, pr, pc, sub_lab) + (bbox.col0, bbox.row0)
    if area < frame.min_area_px:
        status = "too_small"
    elif x == 0 or y == 0 or x + bw >= w or y + bh >= h:
        status = "touches_border"
    elif scope is not None and scope[bbox.slices].any():
        status = "black_border"
    elif status == "ok" and area >= 12:
        e = ellipticity(sub_lab)
        if not (ellipticity_min <= e <= 1.0 / ellipticity_min):
            status = "not_elliptical"
            detail = _rejection_detail(status, frame, area, bbox, f"{e:.3f}")
    if status in ("too_small", "touches_border", "black_border"):
        detail = _rejection_detail(status, frame, area, bbox)
    half = frame.roi_scale * max(bw, bh) / 2.0 + frame.roi_margin_px
    roi = Roi.around(bp_uv, half, img.shape)
    level = None
    if levels is not None:  # the detection level of this component: half its local height
        b = float(levels[y + pr, x + pc])
        level = b + peak_rel * (peak - b)
    return Candidate(bp_uv, peak, saturated, area, bbox, roi, status, detail, level)

