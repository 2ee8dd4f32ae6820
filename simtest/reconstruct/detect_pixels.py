"""The pixel work of specularity detection on whole frames (OpenCV and numpy): luma, noise, clipped
pixels, the scope's border, the local-peak mask and the components of a mask.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest.constants import LUMA_BT601
from simtest.decisions import (BACKGROUND_DIV, BACKGROUND_PLATEAU_FACTOR, CLIP_LUMA_MARGIN_REL, CLIP_MARGIN_REL,
                               CODEC_CEILING_SPIKE, NOISE_LEVEL_BINS, NOISE_LEVEL_MIN_SAMPLES, SIGNIFICANCE_MIN,
                               SMOOTH_NOISE_MIN_REL,
                               SMOOTH_NOISE_PER_PX_REL, SMOOTH_SIGMA_MAX_PX, TOPHAT_MIN_REL)
from simtest.reconstruct.jpeg import MCU_PX, jpeg_grid

_LUMA = np.array(LUMA_BT601)
#: The luma weights as OpenCV's ``cv2.transform`` matrix (one output channel from R, G, B).
_LUMA_ROW = np.array([LUMA_BT601], np.float64)


def connected_components(mask: np.ndarray) -> tuple[int, np.ndarray]:
    """8-connected components of a uint8 mask (count with the background, int32 labels), Grana's algorithm."""
    return cv2.connectedComponentsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)


def connected_components_with_stats(mask: np.ndarray):
    """As :func:`connected_components`, with the stats and centroids of ``cv2.connectedComponentsWithStats``."""
    return cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_GRANA)


def mask_labels(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The 8-connected components of a mask, labelled band by band (runs of rows holding mask pixels).

    Equal to :func:`connected_components_with_stats` over the whole mask, labels included.

    Parameters
    ----------
    mask : ndarray of shape (H, W), uint8
        0 or 1.

    Returns
    -------
    n : int
        Number of components, the background not counted.
    labels : ndarray of shape (H, W), int32
        0 the background, 1 to n the components.
    stats : ndarray of shape (n, 5), int32
        Per component ``x, y, width, height, area`` (px).
    """
    h, w = mask.shape
    nz = np.flatnonzero(mask.max(axis=1))
    gaps = np.flatnonzero(np.diff(nz) > 1)
    bands = [(r0 - r0 % 2, r1) for r0, r1 in zip(np.append(nz[:1], nz[gaps + 1]).tolist(),
                                                  (np.append(nz[gaps], nz[-1:]) + 1).tolist())]
    if not bands or 2 * sum(r1 - r0 for r0, r1 in bands) > h:
        n, labels, stats = connected_components_with_stats(mask)[:3]
        return n - 1, labels, stats[1:]
    labels, parts, n = np.zeros((h, w), np.int32), [], 0
    for r0, r1 in bands:
        cols = np.flatnonzero(mask[r0:r1].max(axis=0))
        c0, c1 = int(cols[0]) - int(cols[0]) % 2, int(cols[-1]) + 1
        nb, lab, stats = connected_components_with_stats(np.ascontiguousarray(mask[r0:r1, c0:c1]))[:3]
        np.copyto(labels[r0:r1, c0:c1], lab + n, where=lab > 0)
        parts.append(stats[1:] + (c0, r0, 0, 0, 0))
        n += nb - 1
    return n, labels, np.concatenate(parts).astype(np.int32)


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
        Intensity in image units; per pixel, so an ROI's luma is the frame's luma sliced.
    """
    if image.ndim == 2:
        return image.astype(dtype, copy=False)
    if np.dtype(dtype) in (np.float32, np.float64):
        return luma_cv2(image, dtype)
    return (image.astype(dtype, copy=False) @ _LUMA.astype(dtype)).astype(dtype, copy=False)


def colour_luma32(image: np.ndarray, grey: bool) -> np.ndarray | None:
    """The unrounded float32 luma (H, W), read-only, of a colour 8- or 16-bit RGB frame; None for any
    other frame. ``grey``: whether R = G = B (the caller's answer).
    """
    if grey or image.ndim != 3 or image.shape[2] != 3 or image.dtype.type not in (np.uint8, np.uint16):
        return None
    out = luma_cv2(image, np.float32)
    out.setflags(write=False)
    return out


def luma_cv2(image: np.ndarray, dtype) -> np.ndarray:
    """The Rec. 601 luma (H, W) of an (H, W, 3) image in float64 or float32, by ``cv2.transform``."""
    dt = np.dtype(dtype)
    src = image if image.dtype == dt else image.astype(dt)
    return cv2.transform(np.ascontiguousarray(src), _LUMA_ROW)


def _gray_native(image: np.ndarray) -> np.ndarray:
    """Fast luma for thresholding: OpenCV for uint8/uint16/float32 RGB, numpy otherwise."""
    if image.ndim == 2:
        return image
    if image.dtype in (np.uint8, np.uint16, np.float32):
        return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return luma(image)


def _gray_and_grey(image: np.ndarray) -> tuple[np.ndarray, bool | None]:
    """:func:`_gray_native` of an image and whether its R, G and B are equal (None: not asked, not 8-bit RGB)."""
    asked = image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8
    return _gray_native(image), _is_gray(image) if asked else None


def _is_gray(img: np.ndarray) -> bool:
    """Whether R = G = B at every pixel of an (H, W, C >= 3) image (a NaN is no match)."""
    rows = img[:: max(1, img.shape[0] // 16)]  # about 16 rows: speed only, the answer is the same
    if not (np.array_equal(rows[..., 0], rows[..., 1]) and np.array_equal(rows[..., 0], rows[..., 2])):
        return False
    if img.shape[2] == 3 and img.size and img.dtype.type in (np.uint8, np.uint16):
        img = np.ascontiguousarray(img)
        back = cv2.cvtColor(cv2.extractChannel(img, 0), cv2.COLOR_GRAY2RGB)
        return bool(cv2.norm(img, back, cv2.NORM_INF) == 0)
    return bool(np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 0], img[..., 2]))


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


def noise_sigma(gray: np.ndarray) -> float:
    """Robust standard deviation of the pixel noise of an image, image units.

    ``s = 1.4826 MAD(d) / sqrt(1.5)`` of ``d = x - (left + right) / 2`` (for white noise of variance
    s^2, ``var d = 1.5 s^2``), on about 50 rows.

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


def interior_top(gray: np.ndarray, bp_uv, box) -> bool:
    """Whether a region that the frame's edge cuts holds its lobe's top: the luma at its BP ``bp_uv`` (u, v) px
    stands :data:`~simtest.decisions.SIGNIFICANCE_MIN` noise sigmas (:func:`noise_sigma` of the box) above the
    highest luma where its box ``(row0, row1, col0, col1)`` meets the edge of ``gray`` (H, W). A lobe's top inside
    the frame falls off toward the edge; the shoulder of a lobe outside it rises to the edge, whose pixels then
    hold the region's highest values. False where the box meets no edge of ``gray``."""
    r0, r1, c0, c1 = (int(v) for v in box)
    h, w = gray.shape
    edge = [seg for on, seg in ((r0 <= 0, gray[0, c0:c1]), (r1 >= h, gray[h - 1, c0:c1]), (c0 <= 0, gray[r0:r1, 0]),
                                (c1 >= w, gray[r0:r1, w - 1])) if on and seg.size]
    if not edge:
        return False
    col, row = (min(max(int(round(float(x))), 0), n - 1) for x, n in zip(bp_uv, (w, h)))
    rise = float(gray[row, col]) - max(float(seg.max()) for seg in edge)
    return rise > 0.0 and rise >= SIGNIFICANCE_MIN * noise_sigma(gray[max(r0, 0):r1, max(c0, 0):c1])


def _noise_rows(image: np.ndarray) -> np.ndarray:
    """The rows :func:`noise_sigma` reads (about 50)."""
    return image[:: max(1, image.shape[0] // 48)]


def _noise_sigma_of_rows(rows: np.ndarray) -> float:
    """:func:`noise_sigma` of the rows it reads (h, W)."""
    return noise_sigma_of_differences(second_differences(rows.astype(np.float32)).ravel())  # (float32, as its data)


def second_differences(x: np.ndarray) -> np.ndarray:
    """``x - (left + right) / 2`` along the rows of ``x`` (H, W, ...): (H, W - 2, ...), :func:`noise_sigma`'s."""
    return x[:, 1:-1] - 0.5 * (x[:, :-2] + x[:, 2:])


def noise_sigma_of_differences(d: np.ndarray) -> float:
    """:func:`noise_sigma` from any selection of its differences ``d`` (1-D)."""
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(1.5))  # white noise's sd from its MAD


def noise_level_table(gray: np.ndarray, full_scale: float, fallback: float) -> np.ndarray:
    """The noise's standard deviation per intensity bin (the noise level function), image units.

    :func:`noise_sigma` over the pixels whose three-pixel mean is in the bin; a sparse or noise-free
    bin takes its nearest measured bin's value (``fallback`` where none), then the largest of its and
    its neighbours' (:data:`~simtest.decisions.NOISE_LEVEL_BINS` bins).
    """
    g = gray[:: max(1, gray.shape[0] // 192)].astype(np.float32)  # ~200 rows: a few bins' share each
    d = second_differences(g).ravel()
    k = _level_bin((g[:, 1:-1] + g[:, :-2] + g[:, 2:]).ravel() / 3.0, full_scale).astype(np.uint8)
    out, ends = np.full(NOISE_LEVEL_BINS, np.nan), np.cumsum(np.bincount(k, minlength=NOISE_LEVEL_BINS))
    for b, db in enumerate(np.split(d[np.argsort(k, kind="stable")], ends[:-1])):  # one radix sort: bins in order
        if len(db) >= NOISE_LEVEL_MIN_SAMPLES:
            out[b] = 1.4826 * float(np.median(np.abs(db - np.median(db)))) / np.sqrt(1.5)
    full = np.flatnonzero(out > 0)  # 0: most of the bin has no noise (clipped, drawn, rendered)
    if not len(full) or not fallback > 0:  # a frame whose noise reads 0 (JPEG's flat blocks): none
        return np.full(NOISE_LEVEL_BINS, float(fallback))
    t = np.pad(out[full[np.abs(np.arange(NOISE_LEVEL_BINS)[:, None] - full[None, :]).argmin(1)]], 1, mode="edge")
    return np.maximum(np.maximum(t[:-2], t[1:-1]), t[2:])  # a flat panel's own bins do not lower it


def _level_bin(levels, full_scale: float) -> np.ndarray:
    """The bin of :func:`noise_level_table` that each intensity falls in (int64; NaN in the first)."""
    x = np.multiply(levels, NOISE_LEVEL_BINS / full_scale, dtype=np.float64)
    return np.fmin(np.fmax(x, 0.0, out=x), NOISE_LEVEL_BINS - 1, out=x).astype(np.int64)


def image_noise_sigma(image: np.ndarray) -> float:
    """:func:`noise_sigma` of a validated image's luma (OpenCV's gray of an RGB image), read on
    the rows the estimate reads only (a 1350 x 1080 RGB frame's 49 rows, not 1080: the luma is per pixel).

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
    """Gaussian smoothing for detection and contouring chosen from the image's noise (:func:`noise_sigma`).

    0 when the noise is below :data:`~simtest.decisions.SMOOTH_NOISE_MIN_REL` of full scale (0.5 %), else
    1 px plus 1 px per :data:`~simtest.decisions.SMOOTH_NOISE_PER_PX_REL` (1 %), at most
    :data:`~simtest.decisions.SMOOTH_SIGMA_MAX_PX` (2.5 px); the reasons are theirs.

    Parameters
    ----------
    noise : float
        The noise's standard deviation, image units.
    full_scale : float

    Returns
    -------
    float
        Sigma in px, >= 0.
    """
    s = noise / full_scale
    return 0.0 if s < SMOOTH_NOISE_MIN_REL else float(min(SMOOTH_SIGMA_MAX_PX, 1.0 + s / SMOOTH_NOISE_PER_PX_REL))


def _area_reduced(img: np.ndarray, f: int, halves: list | None = None) -> np.ndarray:
    """The means of the ``f`` x ``f`` blocks of a float32 image whose sides are multiples of f, as a
    chain of 2 x 2 ``INTER_AREA`` reductions. ``halves``: receives the first 2 x 2 reduction.
    """
    h, w = img.shape[:2]
    while f % 2 == 0 and f > 1:
        h, w, f = h // 2, w // 2, f // 2
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        if halves is not None and not halves:
            halves.append(img)
    if f > 1:  # the odd rest
        img = cv2.resize(img, (w // f, h // f), interpolation=cv2.INTER_AREA)
    return img


def _scope_border(gray: np.ndarray, level: float, half: np.ndarray | None = None) -> np.ndarray | None:
    """The endoscope's black border: pixels below ``level`` joined to at least two image corners,
    covering 1 % to 60 % of the image, closed (text drawn on it) and dilated by about 5 px; found
    on the image reduced 4 times. None if there is none. ``half``: ``gray``'s 2 x 2 block means.
    """
    h, w = gray.shape
    f = 4 if min(h, w) >= 64 else 1
    if f > 1:
        # the reduced corners: fewer than two dark, no border
        hf, wf = h // f * f, w // f * f
        dark = 0
        for r, c in ((0, 0), (0, wf - f), (hf - f, 0), (hf - f, wf - f)):
            block = np.ascontiguousarray(gray[r : r + f, c : c + f], dtype=np.float32)
            dark += bool(cv2.resize(block, (1, 1), interpolation=cv2.INTER_AREA)[0, 0] < level)
        if dark < 2:
            return None
    # whole f x f blocks (the last h mod f rows and w mod f columns left out)
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
    """The dark components (flood-filled from the corners) of a uint8 0/1 mask, as a 0/1 mask, when at
    least two corners are dark and they cover 1 % to 60 % of it; None otherwise. ``dark`` is written.
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


def frame_ceiling(image: np.ndarray) -> float:
    """The level an integer frame's clipped tops read: its dtype's maximum, or where the frame carries
    a JPEG grid, the lowest level the tops' flat blocks decode to when it lies below: the lowest level
    within :data:`~simtest.decisions.CLIP_MARGIN_REL` of the maximum whose count of pixels (darkest
    channel) is a spike (:data:`~simtest.decisions.CODEC_CEILING_SPIKE`) of at least
    :data:`~simtest.reconstruct.jpeg.MCU_PX`.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C), unsigned integer

    Returns
    -------
    float
        The ceiling, image units.

    References
    ----------
    ISO/IEC 10918-1 (JPEG), F.2.1: a block's DC coefficient is quantised to a multiple of its step.
    """
    top = int(np.iinfo(image.dtype).max)
    if image.dtype != np.uint8 or image.ndim == 3 and image.shape[2] != 3:  # (JPEG: 8-bit grey or RGB)
        return float(top)
    darkest = image if image.ndim == 2 else cv2.min(cv2.min(image[..., 0], image[..., 1]), image[..., 2])
    lo = top - int(CLIP_MARGIN_REL * top)
    counts = cv2.calcHist([darkest], [0], None, [top - lo + 1], [lo, top + 1]).ravel()
    spikes = np.flatnonzero((counts >= CODEC_CEILING_SPIKE * float(np.median(counts))) & (counts >= MCU_PX))
    if not len(spikes) or lo + spikes[0] == top or jpeg_grid(image) is None:
        return float(top)
    return float(lo + spikes[0])


def near_ceiling_mask(image: np.ndarray, saturation_level: float | None,
                      gray: np.ndarray | None = None, grey: bool = False) -> np.ndarray | None:
    """Pixels of an integer frame near its ceiling, where a lossy codec leaves a clipped top.

    Every channel within :data:`~simtest.decisions.CLIP_MARGIN_REL` of full scale below
    ``saturation_level`` and the luma within :data:`~simtest.decisions.CLIP_LUMA_MARGIN_REL` of it.

    Parameters
    ----------
    image, saturation_level, gray, grey
        As for :func:`clipped_mask`; without ``gray`` the luma is OpenCV's of ``image``.

    Returns
    -------
    ndarray of shape (H, W), uint8 (0/1), or None
        None for a float image or without a saturation level.
    """
    if saturation_level is None or image.dtype not in (np.uint8, np.uint16):
        return None
    top = float(np.iinfo(image.dtype).max)
    near = clipped_mask(image, saturation_level - CLIP_MARGIN_REL * top, gray, grey)
    if gray is None:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 and image.shape[2] == 3 else image
    if gray.ndim == 2:  # (a grey frame's luma is its value: the luma's margin, the narrower, decides)
        near &= (gray >= float(np.ceil(saturation_level - CLIP_LUMA_MARGIN_REL * top))).view(np.uint8)
    return near


def clipped_mask(image: np.ndarray, saturation_level: float | None,
                 gray: np.ndarray | None = None, grey: bool = False) -> np.ndarray | None:
    """Pixels clipped white (every channel >= ``saturation_level``), uint8 0/1.

    Parameters
    ----------
    image : ndarray of shape (H, W) or (H, W, C)
        A validated image (:func:`validate_image`).
    saturation_level : float or None
        Image units.
    gray : ndarray of shape (H, W), optional
        The image's luma as :func:`_gray_native` gives it: only the rows where it reaches the level
        are examined (the same mask).
    grey : bool, optional
        R, G and B are equal and ``gray`` is their value (8-bit): the mask is the gray's.

    Returns
    -------
    ndarray of shape (H, W), uint8, or None
        None without a saturation level (float images).
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


_CLOSE_3 = np.ones((3, 3), np.uint8)


def background_side_px(shape: tuple[int, int], clipped: np.ndarray | None = None) -> int:
    """Side of the background square of :func:`local_peak_mask`, px.

    ``max(31, min(H, W) // BACKGROUND_DIV)``, widened to ``BACKGROUND_PLATEAU_FACTOR`` times the
    largest bounding-box side of the clipped plateaus (8-connected after a 3 x 3 closing) plus one:
    a highlight wider than the square would be taken for background.

    Parameters
    ----------
    shape : (H, W)
    clipped : ndarray of shape (H, W), uint8, optional
        Clipped pixels (:func:`clipped_mask`).

    Returns
    -------
    int
    """
    h, w = shape
    side = max(31, min(h, w) // BACKGROUND_DIV)
    rows = np.flatnonzero(clipped.max(axis=1)) if clipped is not None else ()
    if len(rows):
        # the plateaus' outer contours bound them; pieces one pixel apart are one plateau (3 x 3 closing)
        band = cv2.morphologyEx(clipped[max(rows[0] - 2, 0) : rows[-1] + 3], cv2.MORPH_CLOSE, _CLOSE_3)
        contours, _ = cv2.findContours(band, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        ext = max(max(cv2.boundingRect(c)[2:]) for c in contours)
        side = max(side, BACKGROUND_PLATEAU_FACTOR * ext + 1)
    return side


def local_peak_mask(gray: np.ndarray, full_scale: float, *, peak_rel: float = 0.6,
                    contrast_min_rel: float = TOPHAT_MIN_REL, background_px: int | None = None,
                    censored: np.ndarray | None = None, reduce: bool = True, _parts: list | None = None,
                    _half: list | None = None):
    """Bright-candidate mask relative to local peaks (``method="local_peak"``).

    The background is the grey opening of the luma by a square of side ``background_px`` (on the
    image area-reduced so that the square is about 16 px, enlarged bilinearly); the top-hat
    ``T = gray - background`` is the specular part. A pixel is a candidate when
    ``T >= peak_rel * max(T over the same square)`` and ``T >= contrast_min_rel * full_scale``.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        Luma (smoothed if the caller smooths).
    full_scale : float
        Intensity of white, image units.
    peak_rel : float
        Fraction of the local top-hat peak.
    contrast_min_rel : float
        Smallest top-hat, fraction of full scale.
    background_px : int, optional
        Side of the square, px; default :func:`background_side_px` without clipped pixels.
    censored : ndarray of shape (H, W), uint8, optional
        Pixels clipped white: candidates wherever they meet the local-peak rule and stand above
        the background at all (the ceiling cuts their top-hat).
    reduce : bool
        Open on the area-reduced image (the default); False: on ``gray`` itself.

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
    # open (and take the local peaks) on the image reduced so that the square is ~16 px
    f = max(1, side // 16) if reduce else 1
    whole = f > 1 and h % f == 0 and w % f == 0  # whole blocks: the reductions by 2 x 2 steps
    if whole:
        small = _area_reduced(g, f, _half)
    else:
        small = cv2.resize(g, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA) if f > 1 else g
    k = max(3, side // f)
    k += 1 - k % 2
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg_small = cv2.morphologyEx(small, cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_REPLICATE)
    # background = min(enlarged opening, g) (an opening never exceeds the image), top = g - background
    background = cv2.resize(bg_small, (w, h), interpolation=cv2.INTER_LINEAR) if f > 1 else bg_small
    background = cv2.min(background, g)
    top = cv2.subtract(g, background)
    if whole:
        top_small = _area_reduced(top, f)
    else:
        top_small = cv2.resize(top, small.shape[::-1], interpolation=cv2.INTER_AREA) if f > 1 else top
    peak_small = cv2.dilate(top_small, kernel, borderType=cv2.BORDER_REPLICATE)
    # top >= peak_rel * local peak (top and peak >= 0, peak_rel < 1), scaled on the reduced peaks
    scaled = peak_small * np.float32(peak_rel)
    near_level = cv2.resize(scaled, (w, h), interpolation=cv2.INTER_LINEAR) if f > 1 else scaled
    thr = np.float32(contrast_min_rel * full_scale)
    # top >= near_level and top >= thr: one comparison with their maximum
    mask = cv2.compare(top, cv2.max(near_level, float(thr)), cv2.CMP_GE)
    if censored is not None:  # clipped tops: the local-peak rule and any height above the background
        core = cv2.bitwise_and(cv2.compare(top, near_level, cv2.CMP_GE), cv2.compare(top, 0.0, cv2.CMP_GT))
        cv2.max(mask, cv2.bitwise_and(core, core, mask=censored), dst=mask)  # 0 or 255: an or
    np.right_shift(mask, 7, out=mask)  # 255 -> 1
    if _parts is not None:  # the reduced background and local peaks (_detect_half_resolution)
        _parts.extend((bg_small, peak_small, f))
    return mask, background


def wide_lobe_boxes(gray: np.ndarray, full_scale: float, side: int, wider_than: float, core_min_px: float,
                    isovalue: float, *, peak_rel: float = 0.6, contrast_min_rel: float = TOPHAT_MIN_REL) -> np.ndarray:
    """Boxes of the broad lobes that :func:`local_peak_mask` on a square of ``side`` px may find: its
    components wider than ``wider_than`` px whose core, the pixels at least ``isovalue`` of the component's
    top-hat peak, is at least ``core_min_px`` across (the diameter of a disc of its area). Found on the
    frame reduced by ``wider_than // 16``: a cheap look before a full detection, on pixels a sixteenth of
    the narrower square, so that lobes the full mask tells apart stay apart.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
        Luma, image units.
    full_scale : float
        Intensity of white, image units.
    side : int
        Side of the background square, px.
    wider_than : float
        Smallest box side kept (exclusive), px.
    core_min_px : float
        Smallest core diameter kept, px.
    isovalue : float
        The core's level, a fraction of the component's top-hat peak.
    peak_rel, contrast_min_rel : float
        As for :func:`local_peak_mask`.

    Returns
    -------
    ndarray of shape (N, 4), int64
        ``(row0, row1, col0, col1)``, half-open, in full-resolution px, widened by one reduced pixel.
    """
    h, w = gray.shape
    f = max(1, int(wider_than) // 16)
    small = cv2.resize(gray.astype(np.float32, copy=False), (max(1, w // f), max(1, h // f)),
                       interpolation=cv2.INTER_AREA) if f > 1 else gray.astype(np.float32)
    mask, background = local_peak_mask(small, full_scale, peak_rel=peak_rel, contrast_min_rel=contrast_min_rel,
                                       background_px=max(1, side // f), reduce=False)
    top = cv2.subtract(small, background)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    x, y, bw, bh = (stats[1:, :4].astype(np.int64) * f).T
    wide = np.flatnonzero(np.maximum(bw, bh) > wider_than)
    if not len(wide):
        return np.zeros((0, 4), np.int64)
    # each wide component's core: its pixels at least isovalue of its top-hat peak (in its box)
    area = np.zeros(len(wide))
    for j, (cx, cy, cw, ch) in enumerate(stats[wide + 1, :4].tolist()):
        t = top[cy : cy + ch, cx : cx + cw][labels[cy : cy + ch, cx : cx + cw] == wide[j] + 1]
        area[j] = np.count_nonzero(t >= np.float32(isovalue) * t.max()) * float(f * f)
    wide = wide[2.0 * np.sqrt(area / np.pi) >= core_min_px]
    return np.stack([np.maximum(y - f, 0), np.minimum(y + bh + f, h), np.maximum(x - f, 0), np.minimum(x + bw + f, w)],
                    axis=1)[wide].reshape(-1, 4)


def linear_taps(i, src: int, dst: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's ``INTER_LINEAR`` taps for output indices ``i`` of an axis enlarged from ``src`` to ``dst``
    samples: the two source indices and the float32 weight of the second.
    """
    x = (np.asarray(i, np.float64) + 0.5) * (src / dst) - 0.5
    i0 = np.floor(x).astype(np.int64)
    a = (x - i0).astype(np.float32)
    a[i0 < 0] = 0.0
    i0 = np.maximum(i0, 0)
    a[i0 >= src - 1] = 0.0
    i0 = np.minimum(i0, src - 1)
    return i0, np.minimum(i0 + 1, src - 1), a


def linear_at(small: np.ndarray, shape: tuple[int, int], r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """``cv2.resize(small, shape[::-1], interpolation=cv2.INTER_LINEAR)[r0:r1, c0:c1]``, computed in that window only.
    """
    sh, sw = small.shape
    h, w = shape
    if h % sh == 0 and w % sw == 0 and h // sh == w // sw and h // sh > 1:
        # an integer factor f: enlarge the blocks under the window and one more on each side
        f = h // sh
        q0, q1 = max(0, r0 // f - 1), min(sh, (r1 - 1) // f + 2)
        p0, p1 = max(0, c0 // f - 1), min(sw, (c1 - 1) // f + 2)
        up = cv2.resize(np.ascontiguousarray(small[q0:q1, p0:p1]), ((p1 - p0) * f, (q1 - q0) * f),
                        interpolation=cv2.INTER_LINEAR)
        return up[r0 - q0 * f : r1 - q0 * f, c0 - p0 * f : c1 - p0 * f]

    y0, y1, ay = linear_taps(np.arange(r0, r1), sh, h)
    x0, x1, ax = linear_taps(np.arange(c0, c1), sw, w)
    one = np.float32(1.0)
    top = small[y0][:, x0] * (one - ax) + small[y0][:, x1] * ax
    bot = small[y1][:, x0] * (one - ax) + small[y1][:, x1] * ax
    return top * (one - ay)[:, None] + bot * ay[:, None]
