"""Specularity detection on a whole image: candidate highlights, their BP, ROI, or a reason.

A candidate is an 8-connected component of bright pixels. Its brightest point (BP) is the
centroid of the saturated plateau when clipped, else the brightest pixel refined by a separable
parabola through its 3x3 neighbourhood (or the centroid of a flat top). It gets a square ROI
around the BP and a status, ``"ok"`` or a reason: ``too_small`` (fewer than ``min_area_px``
pixels), ``touches_border``, ``merged`` (several saturated plateaus), ``not_elliptical``
(``area / (4 pi sqrt(det Sigma))`` of its second moments outside [``ellipticity_min``,
1 / ``ellipticity_min``]).

Images: (H, W), (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA (alpha ignored); uint8, uint16 or
floating. Full scale is the dtype maximum for integers, ``max(1, max(image))`` for floats. The
intensity is the Rec. 601 luma; a pixel is saturated when every channel is at ``saturation_level``
(the red channel of tissue alone clips over broad diffuse areas in endoscopy).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from simtest.constants import gaussian_radius_px
from simtest.decisions import MULTIRES_SIDE_MIN_PX, MULTIRES_SIGMA_MIN_PX, SCOPE_BORDER_LEVEL_REL, TOPHAT_MIN_REL
from simtest.reconstruct._pixels import Roi, rc_to_uv
from simtest.reconstruct.candidates import MERGED, NOT_ELLIPTICAL, STATUS_NAMES, TOO_SMALL, Examined, Rules, examine
# the detection's pixel work, re-exported
from simtest.reconstruct.detect_pixels import (  # noqa: F401
    BACKGROUND_DIV, BACKGROUND_PLATEAU_FACTOR, _gray_and_grey, _scope_border, _threshold_mask,
    background_side_px, clipped_mask, colour_luma32, luma_cv2, connected_components, connected_components_with_stats,
    frame_ceiling, image_noise_sigma, linear_at, local_peak_mask, luma, mask_labels,
    near_ceiling_mask, noise_sigma, smooth_sigma_for_noise
)
from simtest.reconstruct.settings import DETECTION_METHODS

_SUPPORTED = (np.uint8, np.uint16, np.float16, np.float32, np.float64)


@dataclass(frozen=True)
class Candidate:
    """One candidate highlight.

    Attributes
    ----------
    bp_uv : ndarray of shape (2,)
        Brightest point (u, v), px (sub-pixel).
    peak : float
        Intensity at the BP, image units.
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
        Intensity level (image units) at which ``method="local_peak"`` cut the component out; None
        with ``method="full_scale"`` (the level is ``Detection.threshold``).
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
        The smallest components left out beyond ``max_candidates``.
    smoothed : ndarray of shape (H, W), float32, or None
        The smoothed gray detection examined (read-only), when it smoothed at full resolution.
    gray : ndarray of shape (H, W) or None
        The gray detection examined before any smoothing (not to be written).
    grey : bool or None
        Whether the image's R, G and B are equal, where detection found out.
    half : ndarray of shape (H // 2, W // 2), float32, or None
        The means of ``gray``'s 2 x 2 blocks, where detection reduced the frame (read-only).
    luma32 : ndarray of shape (H, W), float32, or None
        The unrounded luma of a colour 8- or 16-bit RGB frame, where detection smoothed it at full
        resolution (read-only).
    background_px : int or None
        Side of the background square of ``method="local_peak"``, px; None for ``"full_scale"``.
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
    background_px: int | None = None

    @property
    def n_components(self) -> int:
        """Bright components found: the examined candidates and those left out."""
        return len(self.candidates) + self.n_unexamined


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
        raise ValueError(f"{where}: dtype {arr.dtype} not supported (use uint8, uint16 or float16/32/64)")
    if arr.ndim == 3 and arr.shape[2] in (1, 3, 4):
        arr = arr[:, :, 0] if arr.shape[2] == 1 else arr[:, :, :3]
    elif arr.ndim != 2:
        raise ValueError(f"{where}: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got {arr.shape}")
    if arr.shape[0] < 3 or arr.shape[1] < 3:
        raise ValueError(f"{where}: image of shape {arr.shape} is empty or smaller than 3 x 3")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = ~np.isfinite(arr)
        r, c = np.argwhere(bad)[0][:2]
        raise ValueError(f"{where}: {int(bad.sum())} non-finite values (NaN or inf), first at row {r}, col {c}")
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


def refine_peak_uv(values: np.ndarray, r: int, c: int) -> np.ndarray:
    """Sub-pixel peak from the separable parabola through the 3x3 neighbourhood of (r, c).

    Per axis the offset is ``0.5 (a - d) / (a - 2 b + d)``, clipped to +-0.5 px; 0 without a strict
    maximum or on the border.

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
    off, b = [0.0, 0.0], float(values[r, c])
    for k, (sr, sc) in enumerate(((1, 0), (0, 1))):  # rows, then columns
        if 0 < (r, c)[k] < values.shape[k] - 1:
            a, d = float(values[r - sr, c - sc]), float(values[r + sr, c + sc])
            den = a - 2 * b + d
            if den < 0:
                off[k] = min(max(0.5 * (a - d) / den, -0.5), 0.5)
    return rc_to_uv([r + off[0], c + off[1]])


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
    cov = np.cov(np.array([rr, cc], dtype=np.float64), bias=True)
    # a pixel is a unit square: add its own second moment (1/12 per axis) to the centres' spread
    det = (cov[0, 0] + 1 / 12) * (cov[1, 1] + 1 / 12) - cov[0, 1] ** 2
    return float(n / (4 * np.pi * np.sqrt(det))) if det > 0 else float("nan")


def detect_specularities(image, *, brightness_rel: float = 0.7, full_scale: float | None = None,
                         saturation_level: float | None = None, min_area_px: int = 4, ellipticity_min: float = 0.75,
                         min_plateau_px: int = 2, roi_scale: float = 3.0, roi_margin_px: int = 4,
                         max_candidates: int | None = None, smooth_sigma_px: float | None = 0.0,
                         method: str = "full_scale", peak_rel: float = 0.6,
                         contrast_min_rel: float = TOPHAT_MIN_REL, background_px: int | None = None) -> Detection:
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
        A pixel is clipped when every channel is >= this; default :func:`frame_ceiling` (an integer
        frame's maximum, or the level a JPEG's clipped tops decode to), no clipping for float images.
    min_area_px : int, optional
        Smaller components are rejected as ``too_small``.
    ellipticity_min : float, optional
        See the module docstring (``not_elliptical``); checked for components of >= 12 px.
    min_plateau_px : int, optional
        Saturated plateaus smaller than this do not count toward ``merged``.
    roi_scale, roi_margin_px : float, int, optional
        The ROI is a square of half-width ``roi_scale * max(bbox) / 2 + roi_margin_px`` around the
        BP, clipped to the image.
    max_candidates : int, optional
        Only the largest ``max_candidates`` components are examined (default None, every one).
    smooth_sigma_px : float or None, optional
        Gaussian smoothing of the luma before thresholding and BP search (0: none; None: chosen
        from the noise by :func:`smooth_sigma_for_noise`).
    method : {"full_scale", "local_peak"}
        ``"full_scale"``: bright pixels are >= ``brightness_rel * full_scale``. ``"local_peak"``:
        bright pixels by :func:`local_peak_mask`; candidates on the endoscope's black border get
        ``black_border``; saturated plateaus are counted after a 3 x 3 closing, from 3 px.
    peak_rel, contrast_min_rel : float
        See :func:`local_peak_mask` (``method="local_peak"`` only).
    background_px : int, optional
        Side of the background square, px (``method="local_peak"`` only); default
        :func:`background_side_px` of the frame and its clipped plateaus.

    Returns
    -------
    Detection
        Every candidate with its status, sorted by decreasing peak intensity.

    Raises
    ------
    ValueError
        For a bad image (see :func:`validate_image`) or bad options.
    """

    img = validate_image(image)
    if not 0.0 < brightness_rel < 1.0:
        raise ValueError(f"brightness_rel must be in (0, 1), got {brightness_rel!r}")
    fs = default_full_scale(img) if full_scale is None else float(full_scale)
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"full_scale must be finite and positive, got {full_scale!r}")
    if saturation_level is None and img.dtype.kind == "u":
        saturation_level = frame_ceiling(img)

    if method not in DETECTION_METHODS:
        raise ValueError(f"method: {method!r} is not one of {DETECTION_METHODS}")
    gray, grey = _gray_and_grey(img)
    native = gray
    if smooth_sigma_px is None:
        smooth_sigma_px = smooth_sigma_for_noise(noise_sigma(gray), fs)
    if (method == "local_peak" and smooth_sigma_px >= MULTIRES_SIGMA_MIN_PX and min(gray.shape) >= MULTIRES_SIDE_MIN_PX
            and 0.0 < peak_rel < 1.0 and max_candidates != 0):
        det = _detect_half_resolution(
            img, native, fs, saturation_level, grey=grey is True, min_area_px=min_area_px, ellipticity_min=ellipticity_min,
            min_plateau_px=min_plateau_px, roi_scale=roi_scale, roi_margin_px=roi_margin_px,
            max_candidates=max_candidates, smooth_sigma_px=float(smooth_sigma_px), peak_rel=peak_rel,
            contrast_min_rel=contrast_min_rel, background_px=background_px)
        if det is not None:
            return replace(det, grey=grey)
    luma32 = None
    if smooth_sigma_px > 0:
        # a colour frame's unrounded luma, which the pipeline contours: smoothed once for both
        luma32 = colour_luma32(img, grey is not False)
        gray = cv2.GaussianBlur(gray.astype(np.float32) if luma32 is None else luma32, (0, 0),
                                float(smooth_sigma_px), borderType=cv2.BORDER_REFLECT)
    h, w = gray.shape
    levels = gray32 = half = side = None
    clipped = near = None  # whole-frame clipped and near-ceiling masks, when the method computes them
    if method == "local_peak":
        if not 0.0 < peak_rel < 1.0:
            raise ValueError(f"peak_rel must be in (0, 1), got {peak_rel!r}")
        clipped = clipped_mask(img, saturation_level, native, grey=grey is True)
        near = near_ceiling_mask(img, saturation_level, native, grey=grey is True)
        side = int(background_px) if background_px else background_side_px((h, w), clipped)
        # the float32 intensities of the mask and of the scope border, converted once
        gray32 = gray.astype(np.float32, copy=False)
        halves: list = []
        mask, background = local_peak_mask(gray32, fs, peak_rel=peak_rel, contrast_min_rel=contrast_min_rel,
                                           background_px=side, censored=clipped, _half=halves)
        half = halves[0] if halves else None
        thr = contrast_min_rel * fs
        levels = background
    else:
        thr = brightness_rel * fs
        mask = _threshold_mask(gray, thr)
    # Saturated plateaus are counted (``merged``) after a closing of 2 ceil(2 sigma) + 1 px on a
    # smoothed image: noise breaks one clipped top into pieces that far apart.
    k_close = max(3, 2 * int(np.ceil(2.0 * smooth_sigma_px)) + 1) if smooth_sigma_px > 0 else 3
    frame = _DetectFrame(img=img, gray=gray, gray32=gray32, method=method, full_scale=fs, clipped=clipped,
                         levels=levels, saturation_level=saturation_level, min_area_px=min_area_px,
                         ellipticity_min=ellipticity_min, min_plateau_px=min_plateau_px, roi_scale=roi_scale,
                         roi_margin_px=roi_margin_px, max_candidates=max_candidates, peak_rel=peak_rel, k_close=k_close,
                         half=half, near=near)
    out, n_comps = _candidates(frame, mask)  # by peak
    smoothed = None
    if smooth_sigma_px > 0:
        smoothed = gray
        smoothed.setflags(write=False)
        half = None  # the smoothed gray's means: not the native gray's, which the verifier reads
    elif half is not None:
        half.setflags(write=False)  # the native gray's 2 x 2 means: the verifier's too
    return Detection(out, fs, thr, max(0, n_comps - len(out)), smoothed, native, grey, half=half, luma32=luma32,
                     background_px=side)


#: Half-resolution detection takes frames with at most this many candidates (each examined in a
#: full-resolution window; more are detected at full resolution).
MULTIRES_CANDIDATES_MAX = 64


def _detect_half_resolution(img, native, fs, saturation_level, *, grey=False, min_area_px, ellipticity_min, min_plateau_px,
                            roi_scale, roi_margin_px, max_candidates, smooth_sigma_px, peak_rel,
                            contrast_min_rel, background_px=None) -> Detection:
    """:func:`detect_specularities` (``"local_peak"``) of a smoothed frame on the frame reduced by 2 x 2
    block means, its candidates placed at full resolution (BP refined on the full frame's smoothing).

    None (detect at full resolution) where the reduced block grid is not the full one's or with
    more than :data:`MULTIRES_CANDIDATES_MAX` candidates. ``grey``: R = G = B, ``native`` their value.
    """
    h, w = native.shape
    h2, w2 = h // 2, w // 2
    clipped = clipped_mask(img, saturation_level, native, grey=grey)
    near = near_ceiling_mask(img, saturation_level, native, grey=grey)
    side = int(background_px) if background_px else background_side_px((h, w), clipped)
    half = cv2.resize(native[: 2 * h2, : 2 * w2].astype(np.float32, copy=False), (w2, h2), interpolation=cv2.INTER_AREA)
    sigma2 = float(np.sqrt(max(smooth_sigma_px ** 2 - 0.25, 0.0)) / 2.0)
    gray2 = cv2.GaussianBlur(half, (0, 0), sigma2, borderType=cv2.BORDER_REFLECT)
    clipped2 = None
    if clipped is not None:  # a reduced pixel is clipped where 3 or 4 of its 4 are
        clipped2 = cv2.resize(clipped[: 2 * h2, : 2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    parts: list = []
    mask2, background2 = local_peak_mask(gray2, fs, peak_rel=peak_rel, contrast_min_rel=contrast_min_rel,
                                         background_px=max(3, side // 2), censored=clipped2, _parts=parts)
    bg_small, peak_small, f2 = parts
    if max(1, side // 16) != 2 * f2 or bg_small.shape != (h // (2 * f2), w // (2 * f2)):
        return None  # the reduced grids differ: the caller detects at full resolution
    k_close = max(3, 2 * int(np.ceil(2.0 * sigma2)) + 1)
    frame2 = _DetectFrame(
        img=gray2, gray=gray2, gray32=gray2, method="local_peak", full_scale=fs, clipped=clipped2,
        levels=background2, saturation_level=saturation_level, min_area_px=max(1, -(-min_area_px // 4)),
        ellipticity_min=ellipticity_min, min_plateau_px=max(1, -(-min_plateau_px // 4)), roi_scale=roi_scale,
        roi_margin_px=roi_margin_px, max_candidates=max_candidates, peak_rel=peak_rel, k_close=k_close)
    cands2, n_comps = _candidates(frame2, mask2, by_peak=False)
    if len(cands2) > MULTIRES_CANDIDATES_MAX:
        return None  # each costs a window at full resolution: the whole frame is cheaper
    # the full frame's smoothing, background and labels, written in the candidates' windows only
    gray = np.empty((h, w), np.float32)
    levels = np.empty((h, w), np.float32)
    labels = np.zeros((h, w), np.int32)
    full = replace(frame2, img=img, gray=gray, gray32=None, clipped=clipped, levels=levels, min_area_px=min_area_px,
                   min_plateau_px=min_plateau_px, k_close=max(3, 2 * int(np.ceil(2.0 * smooth_sigma_px)) + 1))
    window = _Window(native, bg_small, peak_small, float(smooth_sigma_px), np.float32(peak_rel),
                     np.float32(contrast_min_rel * fs))
    out = []
    rows, found = [], []
    for i, c in enumerate(cands2):
        got = _component_at_full_resolution(window, c)
        if got is None:  # its BP's pixel is not in the full frame's mask: the reduced frame's
            b = c.bbox
            bbox = Roi(2 * b.row0, min(h, 2 * b.row1), 2 * b.col0, min(w, 2 * b.col1))
            bp = 2.0 * np.asarray(c.bp_uv, np.float64) + 0.5
            roi = Roi.around(bp, roi_scale * max(bbox.shape) / 2.0 + roi_margin_px, img.shape)
            out.append(Candidate(bp, c.peak, c.saturated, 4 * c.area_px, bbox, roi, c.status, c.detail, c.level))
            continue
        (r0, r1, c0, c1), g, bg, comp, row = got
        gray[r0:r1, c0:c1] = g
        levels[r0:r1, c0:c1] = bg
        lab = labels[r0:r1, c0:c1]
        if lab[comp].any():  # the component of an earlier candidate: the same, once
            continue
        lab[comp] = len(rows) + 1
        rows.append([len(rows) + 1, *row])
        found.append(c)
    if rows:
        table = np.array(rows, np.int64)
        ex = examine(gray, labels, table, _rules(full), clipped=clipped, near=near, levels=levels)
        for c, got in zip(found, _built(full, ex, table)):
            if c.status == "black_border":  # the scope's border, found on the reduced frame
                got = Candidate(got.bp_uv, got.peak, got.saturated, got.area_px, got.bbox, got.roi, c.status,
                                _rejection_detail(c.status, got.bbox), got.level)
            out.append(got)
    out.sort(key=lambda c: -c.peak)
    half.setflags(write=False)
    return Detection(out, fs, contrast_min_rel * fs, max(0, n_comps - len(out)), None, native, half=half,
                     background_px=side)


@dataclass(frozen=True)
class _Window:
    """What the full-resolution windows of :func:`_detect_half_resolution` share: the frame's
    unsmoothed luma, the reduced frame's background and local peaks, the smoothing sigma (px),
    ``peak_rel`` and the contrast threshold (image units)."""

    native: np.ndarray
    bg_small: np.ndarray
    peak_small: np.ndarray
    sigma: float
    peak_rel: np.float32
    thr: np.float32

    def mask(self, r0: int, r1: int, c0: int, c1: int):
        """The smoothing (float32), background and :func:`local_peak_mask`'s mask of the frame's window
        ``[r0:r1, c0:c1]``, the reduced background and local peaks enlarged there.
        """
        h, w = self.native.shape
        k = gaussian_radius_px(self.sigma)
        q0, q1, p0, p1 = max(0, r0 - k), min(h, r1 + k), max(0, c0 - k), min(w, c1 + k)
        src = np.ascontiguousarray(self.native[q0:q1, p0:p1], dtype=np.float32)
        g = cv2.GaussianBlur(src, (2 * k + 1, 2 * k + 1), self.sigma, borderType=cv2.BORDER_REFLECT)
        g = np.ascontiguousarray(g[r0 - q0 : r1 - q0, c0 - p0 : c1 - p0])
        bg = np.minimum(linear_at(self.bg_small, (h, w), r0, r1, c0, c1), g)
        top = g - bg
        peak = np.maximum(linear_at(self.peak_small, (h, w), r0, r1, c0, c1), top)
        mask = ((top >= peak * self.peak_rel) & (top >= self.thr)).view(np.uint8)
        return g, bg, mask


def _component_at_full_resolution(window: _Window, c: Candidate):
    """The full frame's component of a candidate found on the reduced frame.

    ``((r0, r1, c0, c1), g, bg, comp, (x, y, width, height, area))``: the window, its smoothing and
    background, the component's mask and its box in the frame; None when the mask is empty there.
    """
    h, w = window.native.shape
    b = c.bbox
    m = 4
    while True:
        r0, r1 = max(0, 2 * b.row0 - m), min(h, 2 * b.row1 + m)
        c0, c1 = max(0, 2 * b.col0 - m), min(w, 2 * b.col1 + m)
        gc = min(max(int(round(2.0 * c.bp_uv[0] + 0.5)), c0), c1 - 1) - c0
        gr = min(max(int(round(2.0 * c.bp_uv[1] + 0.5)), r0), r1 - 1) - r0
        g, bg, mask = window.mask(r0, r1, c0, c1)
        i0, j0 = max(0, gr - 2), max(0, gc - 2)
        near = np.where(mask[i0 : gr + 3, j0 : gc + 3] != 0, g[i0 : gr + 3, j0 : gc + 3], -np.inf)
        if not np.isfinite(near.max()):
            return None
        pr, pc = np.unravel_index(int(np.argmax(near)), near.shape)
        _, lab, stats, _ = connected_components_with_stats(mask)
        k = int(lab[i0 + pr, j0 + pc])
        x, y, bw, bh, area = (int(v) for v in stats[k])
        cut = (x == 0 and c0 > 0) or (y == 0 and r0 > 0) or (x + bw == c1 - c0 and c1 < w) or (y + bh == r1 - r0 and r1 < h)
        if not cut:
            return (r0, r1, c0, c1), g, bg, lab == k, (x + c0, y + r0, bw, bh, area)
        m *= 2


@dataclass(frozen=True)
class _DetectFrame:
    """What the examination of a frame's candidates needs: the resolved arguments of
    :func:`detect_specularities` and the frame's arrays (``img``, ``gray``, ``clipped``, ``levels``,
    ``k_close``, ``gray32``).
    """

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
    #: Pixels near the ceiling (:func:`near_ceiling_mask`) where ``clipped`` is given, else None.
    near: np.ndarray | None = None

    def scope(self) -> np.ndarray | None:
        """The endoscope's black border (``"local_peak"`` only), see :func:`_scope_border`."""
        if self.method != "local_peak":
            return None
        return _scope_border(self.gray if self.gray32 is None else self.gray32, SCOPE_BORDER_LEVEL_REL * self.full_scale,
                             self.half if self.gray32 is not None else None)


def _outer_components(mask: np.ndarray) -> list[tuple[int, int, int, int, int, np.ndarray]]:
    """The components of ``method="full_scale"``: outer boundaries (``findContours``) each filled in its
    box and cut by the mask, as (area, x, y, width, height, comp), in ``findContours``' order.
    """
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    comps = []
    for cnt in contours:
        x, y, bw, bh = cv2.boundingRect(cnt)
        comp = np.zeros((bh, bw), np.uint8)
        cv2.drawContours(comp, [cnt], -1, 1, thickness=-1, offset=(-x, -y))
        comp &= mask[y : y + bh, x : x + bw]
        comps.append((int(np.count_nonzero(comp)), x, y, bw, bh, comp))
    return comps


def _rules(frame: _DetectFrame) -> Rules:
    return Rules(frame.min_area_px, frame.ellipticity_min, frame.min_plateau_px, frame.roi_scale, frame.roi_margin_px,
                 frame.peak_rel, frame.k_close, frame.method == "local_peak", frame.saturation_level)


def _candidates(frame: _DetectFrame, mask: np.ndarray, by_peak: bool = True) -> tuple[list[Candidate], int]:
    """The candidates of a frame's mask (largest first, at most ``max_candidates``, examined at once)
    and the number of its components. ``by_peak``: by decreasing peak, ties largest first.
    """
    if frame.method == "local_peak":
        n_comps, labels, stats = mask_labels(mask)
        table = np.empty((n_comps, 6), np.int64)
        table[:, 0] = np.arange(1, n_comps + 1)
        table[:, 1:] = stats
    else:
        comps = _outer_components(mask)
        n_comps = len(comps)
        labels = np.zeros(frame.gray.shape, np.int32)
        table = np.empty((n_comps, 6), np.int64)
        for k, (area, x, y, bw, bh, comp) in enumerate(comps):
            labels[y : y + bh, x : x + bw][comp.view(bool)] = k + 1
            table[k] = (k + 1, x, y, bw, bh, area)
    if n_comps == 0:
        return [], 0
    table = table[np.argsort(-table[:, 5], kind="stable")[: frame.max_candidates]]
    clipped, near = frame.clipped, frame.near
    if clipped is None and frame.saturation_level is not None:
        clipped = clipped_mask(frame.img, frame.saturation_level)
        near = near_ceiling_mask(frame.img, frame.saturation_level)
    ex = examine(frame.gray, labels, table, _rules(frame), clipped=clipped, near=near, scope=frame.scope(),
                 levels=frame.levels)
    if by_peak:
        order = np.argsort(-ex.peak, kind="stable")
        table = table[order]
        ex = Examined(*(None if v is None else v[order] for v in vars(ex).values()))
    return _built(frame, ex, table), n_comps


def _built(frame: _DetectFrame, ex: Examined, table: np.ndarray) -> list[Candidate]:
    """The :class:`Candidate` of each row of an examination (``table``'s boxes in the frame)."""
    _, xs, ys, bws, bhs, areas = table.T.tolist()
    codes = ex.code.tolist()
    details = [""] * len(codes)
    bounds = f"outside [{frame.ellipticity_min}, {1 / frame.ellipticity_min:.3f}]"
    for k in np.flatnonzero(ex.code != 0).tolist():
        code = codes[k]
        if code == MERGED:
            details[k] = f"{int(ex.n_plateaus[k])} saturated plateaus"
        elif code == NOT_ELLIPTICAL:
            details[k] = f"ellipticity {ex.ellipticity[k]:.3f} {bounds}"
        elif code == TOO_SMALL:
            details[k] = f"{areas[k]} px < {frame.min_area_px}"
        else:
            details[k] = _rejection_detail(STATUS_NAMES[code], Roi(ys[k], ys[k] + bhs[k], xs[k], xs[k] + bws[k]))
    new_roi = tuple.__new__  # Roi(...) without its generated __new__'s call (thousands a frame)
    bboxes = [new_roi(Roi, (y, y + bh, x, x + bw)) for x, y, bw, bh in zip(xs, ys, bws, bhs)]
    rois = [new_roi(Roi, r) for r in map(tuple, ex.roi.tolist())]
    levels = ex.level.tolist() if ex.level is not None else [None] * len(codes)
    return list(map(Candidate, list(ex.bp_uv), ex.peak.tolist(), ex.saturated.tolist(), areas, bboxes, rois,
                    [STATUS_NAMES[c] for c in codes], details, levels))


def _rejection_detail(status: str, bbox: Roi) -> str:
    """The numbers behind a ``touches_border`` or ``black_border`` rejection (the box); else empty."""
    if status == "touches_border":
        return f"bbox (row0, row1, col0, col1) = {tuple(bbox)}"
    if status == "black_border":
        return "on or within 5 px of the endoscope's black border"
    return ""


