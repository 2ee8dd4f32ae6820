"""Is a fitted candidate a specular highlight the isophote method can use? Checks and a confidence.

A candidate earns ``ok`` when it passes, in order (numbers and their reasons: :mod:`simtest.decisions`):

- **not a burnt-in overlay** (``overlay``): at most :data:`PANEL_FRACTION_MAX` of its region is
  flat panel (5 x 5 px luma std under :data:`PANEL_STD_REL` of the noise at its level);
- **specular colour** (``not_specular``): a dielectric reflects the illuminant's colour (dichromatic
  model, Shafer 1985, doi:10.1002/col.5080100409): the peak's chroma ``1 - min(RGB) / max(RGB)`` is
  at most :data:`PALENESS_MAX` of the tissue's or below :data:`WHITE_CHROMA`, and at least
  :data:`WHITE_SHARE_MIN` of its linear-light excess over the background is white;
- **a peak above the diffuse level** (``not_specular``): top-hat height at least :data:`SIGNIFICANCE_MIN`
  noise sigmas and :data:`CONTRAST_MIN` of the room the sensor leaves, unless clipped in every channel;
- under a rig of separate guides, a white peak of at least :data:`SIGNIFICANCE_MIN` sigmas with a **rig twin**
  (another such peak where the rig puts another guide's highlight, :func:`~simtest.reconstruct.rig_pairs.rig_twins`)
  is exempt from the paleness and contrast bars (:meth:`Evidence.with_twins`); one below the contrast bar is
  ``weak_twin`` until its plane fit confirms the twin (:data:`WEAK_TWIN`);
- **isolated** (``cluster``): no other peak of :data:`NEIGHBOUR_REL` of its height beyond :data:`OWN_RADIUS_PX` of the
  BP (another guide's excepted, :mod:`simtest.reconstruct.rig_pairs`) and a valley below :data:`VALLEY_REL` of it,
  within its isophotes' reach (one light place: :data:`GLINT_FIELD_DEG` of view, :data:`GLINT_FIELD_VALLEY_REL`:
  a glint field); and at most :data:`SURROUND_FRACTION_MAX` of its surround lit by other light;
- **nested ellipses** (``bad_fit``): primary isophote RMS residual at most :data:`RESIDUAL_MAX_REL` of
  its semi-minor axis, BP inside it, semi-minor axis at least :data:`MINOR_AXIS_MIN_PX`.

``confidence`` is a logistic function of the same quantities, fitted on the hand-labelled real
frames (``tests/data/real/structures_labelled.json``): a ranking calibrated there, not a
probability on other scopes. The colour and height checks read only the BP: the pipeline runs
them first (:func:`bp_checks`) and neither contours nor fits a candidate that fails them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, replace
from types import SimpleNamespace

import cv2
import numpy as np

from simtest.decisions import (PALENESS_MAX, WHITE_CHROMA, WHITE_SHARE_MIN, SIGNIFICANCE_MIN, CONTRAST_MIN,
                               PANEL_STD_REL, PANEL_MIN_AREA, PANEL_FRACTION_MAX, NEIGHBOUR_REL, NEIGHBOUR_AREA_REL,
                               VALLEY_REL, VALLEY_NOISE, NEIGHBOUR_REACH, OWN_RADIUS_PX, GLINT_FIELD_DEG, OWN_REL,
                               GLINT_FIELD_VALLEY_REL, SURROUND_REL, SURROUND_FRACTION_MAX, RESIDUAL_MAX_REL,
                               MINOR_AXIS_MIN_PX, QUANTISATION_SIGMA_LSB, CONFIDENCE_COEFFICIENTS as COEFFICIENTS)
from simtest.geometry.response import srgb_inverse
from simtest.reconstruct import evidence_pixels as px
from simtest.reconstruct._pixels import uv_to_rc
from simtest.reconstruct.detect import background_side_px, noise_sigma
from simtest.reconstruct.detect_pixels import _level_bin, noise_level_table
from simtest.reconstruct.fit import fit_ellipses
from simtest.reconstruct.jpeg import quantisation_sigma
from simtest.reconstruct.rig_pairs import (PAIR_TOL_PX, estimate_wander_px, other_guide_curves, other_lobe_centres,
                                          rig_twins)

__all__ = ["bp_checks", "shared_passes", "PALENESS_MAX", "WHITE_CHROMA", "SIGNIFICANCE_MIN", "CONTRAST_MIN",
           "PANEL_STD_REL", "PANEL_FRACTION_MAX", "NEIGHBOUR_REL", "OWN_RADIUS_PX", "SURROUND_REL", "OWN_REL",
           "SURROUND_FRACTION_MAX", "RESIDUAL_MAX_REL", "MINOR_AXIS_MIN_PX", "COEFFICIENTS", "Evidence",
           "frame_evidence", "assess", "confidence", "confidence_features", "verdict", "weak_white_peaks"]

@dataclass(frozen=True)
class Evidence:
    """Per-candidate measurements of a frame (arrays of shape (N,), one row per candidate).

    Attributes
    ----------
    chroma_peak, chroma_tissue : ndarray
        Chroma ``1 - min/max`` of the RGB maximum over the 3 x 3 px around the BP, and of the
        background (grey opening per channel) there; 0 for a grey image.
    height, background : ndarray
        Luma top-hat and luma background at the BP, image units.
    noise : float
        Noise standard deviation, image units: the sensor's and JPEG's quantisation error in
        quadrature, at least :data:`QUANTISATION_SIGMA_LSB` for an integer image.
    panel_fraction : ndarray
        Share of flat-panel pixels in the candidate's region of interest.
    neighbours : ndarray of int
        Specular peaks in the region of interest other than the candidate's own.
    clipped : ndarray of bool, optional
        The BP is on a clipped plateau (its height is only a lower bound).
    full_scale : float
        Intensity of white, image units.
    minor_px : ndarray, optional
        Semi-minor axis of each primary isophote, px (NaN without a fit).
    surround : ndarray, optional
        Fraction of the surround lit by other light, for the candidates that pass the checks before
        it; 1 for the other fitted ones, NaN for the rest.
    paired : list of list of (float, float), optional
        Per candidate, the centres (u, v) px of the other light guides' lobes left out of the
        surround; None without a rig.
    noise_bg : ndarray, optional
        Noise at the background's level, image units.
    white_share : ndarray, optional
        The peak's white share (:func:`~simtest.reconstruct.evidence_pixels.white_share`).
    surround_white : ndarray, optional
        As ``surround``, white light only (None on a grey frame).
    twin : ndarray of bool, optional
        A white peak of significant height lies where the rig puts another guide's highlight
        (:func:`~simtest.reconstruct.rig_pairs.rig_twins`): the paleness and contrast bars are waived.
    """

    chroma_peak: np.ndarray
    chroma_tissue: np.ndarray
    height: np.ndarray
    background: np.ndarray
    noise: float
    panel_fraction: np.ndarray
    neighbours: np.ndarray
    clipped: np.ndarray | None = None
    full_scale: float = 255.0
    minor_px: np.ndarray | None = None
    surround: np.ndarray | None = None
    paired: list | None = None
    noise_bg: np.ndarray | None = None
    white_share: np.ndarray | None = None
    surround_white: np.ndarray | None = None
    twin: np.ndarray | None = None

    @property
    def paleness(self) -> np.ndarray:
        """Chroma of the peak over the tissue's (0: white peak; 1: the tissue's own colour)."""
        return self.chroma_peak / np.maximum(self.chroma_tissue, 1e-3)

    @property
    def specular_colour(self) -> np.ndarray:
        """The colour check (:func:`_specular_colour`) at each BP; a twin needs only the white share."""
        colour = _specular_colour(self.chroma_peak, self.chroma_tissue, self.white_share)
        return colour if self.twin is None else colour | (self.twin & self.white)

    @property
    def white(self) -> np.ndarray:
        """At least :data:`WHITE_SHARE_MIN` of the peak's light above the tissue is white (all on a grey frame)."""
        return np.ones(len(self.height), bool) if self.white_share is None else self.white_share >= WHITE_SHARE_MIN

    @property
    def significant(self) -> np.ndarray:
        """Clipped, or a height of at least :data:`SIGNIFICANCE_MIN` noise sigmas."""
        clipped = np.zeros(len(self.height), bool) if self.clipped is None else np.asarray(self.clipped, bool)
        return clipped | (self.significance >= SIGNIFICANCE_MIN)

    @property
    def tall(self) -> np.ndarray:
        """The height check: clipped, or :data:`SIGNIFICANCE_MIN` and :data:`CONTRAST_MIN`; a twin needs only the
        first."""
        clipped = np.zeros(len(self.height), bool) if self.clipped is None else np.asarray(self.clipped, bool)
        tall = self.significant & (clipped | (self.contrast >= CONTRAST_MIN))  # clipped | (significant & contrast)
        return tall if self.twin is None else tall | (self.twin & self.significant)

    @property
    def weak_twin(self) -> np.ndarray:
        """A twin that passes the height check below :data:`CONTRAST_MIN`: its light-aware fit must confirm it
        (:data:`WEAK_TWIN`)."""
        return np.zeros(len(self.height), bool) if self.twin is None else self.tall & ~replace(self, twin=None).tall

    @property
    def weak_white(self) -> np.ndarray:
        """White peaks of significant height that the paleness or contrast bar alone refuses: those a rig twin
        lets pass (:meth:`with_twins`)."""
        return self.white & self.significant & ~(
            _specular_colour(self.chroma_peak, self.chroma_tissue, self.white_share) & self.tall)

    def with_twins(self, twins) -> Evidence:
        """This evidence with ``twin`` set where ``twins(pool, which)`` (bool (N,)) finds one for the peaks refused
        for paleness or contrast alone (``which``: :attr:`weak_white`), among the white peaks of significant
        height (``pool``)."""
        pool, which = self.white & self.significant, self.weak_white
        return replace(self, twin=twins(pool, which) if which.any() else np.zeros(len(pool), bool))

    @property
    def significance(self) -> np.ndarray:
        """Height over the noise at the background's level (``noise_bg``; else ``noise``)."""
        return self.height / np.maximum(self.noise if self.noise_bg is None else self.noise_bg, 1e-9)

    @property
    def contrast(self) -> np.ndarray:
        """Height over the background, or the headroom above it where smaller."""
        room = np.minimum(self.background, self.full_scale - self.background)
        return self.height / np.maximum(room, 1e-9)


#: The status of a peak the height check passed for its rig twin alone (:attr:`Evidence.weak_twin`): ``ok`` only
#: where its plane fit confirms the twin (:func:`~simtest.reconstruct.rig_centroid.light_aware_with_rig`).
WEAK_TWIN = "weak_twin"


#: The frame-wide passes :func:`shared_passes` keeps: ``key -> (the array, the result)``, or None outside.
_SHARED: ContextVar[dict | None] = ContextVar("simtest_verify_shared", default=None)


@contextmanager
def shared_passes() -> Iterator[None]:
    """Compute the frame-wide passes of :func:`frame_evidence` once per array and argument inside the block.

    A context manager and decorator. The arrays must not change inside the block (keyed by memory,
    shape, strides and dtype); per context, a nested block starts empty.
    """
    token = _SHARED.set({})
    try:
        yield
    finally:
        _SHARED.reset(token)


def _shared(fn, img: np.ndarray, *args):
    """``fn(img, *args)``, computed once per array and arguments inside :func:`shared_passes` (array
    arguments keyed as ``img`` is, and kept alive with it)."""
    memo = _SHARED.get()
    if memo is None:
        return fn(img, *args)
    key = (fn.__name__, *_array_key(img), tuple(_array_key(a) if isinstance(a, np.ndarray) else a for a in args))
    hit = memo.get(key)
    if hit is None:
        hit = memo[key] = (img, args, fn(img, *args))
    return hit[2]


def _float32(img: np.ndarray) -> np.ndarray:
    """The image as float32 (itself when it is)."""
    return img.astype(np.float32, copy=False)


def _opening_small(img: np.ndarray, side: int):
    """:func:`simtest.reconstruct.evidence_pixels.opening_small` (shared in a block); a square wider than
    the frame's (:func:`background_side_px`, a broad lobe's) reduced at any frame size."""
    return px.opening_small(img, side, exact=side <= background_side_px(img.shape[:2]))


def seed_opening(gray: np.ndarray, side: int, half: np.ndarray) -> bool:
    """Seed :func:`_opening_small` of ``gray`` (H, W) from the means of its 2 x 2 blocks ``half``.

    Inside :func:`shared_passes` and for an even block side only; returns whether it was seeded.
    """
    memo = _SHARED.get()
    h, w = gray.shape
    f = max(1, side // 16)
    if memo is None or f % 2 or h % f or w % f or half.shape != (h // 2, w // 2):
        return False
    key = (_opening_small.__name__, *_array_key(gray), (side,))
    memo[key] = (gray, (side,), px.opening_small(gray, side, half))  # as _shared stores it
    return True


def _opening_at(img: np.ndarray, side: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The grey opening of ``img`` (H, W[, C]) at the pixels (``rows``, ``cols``) only."""
    h, w = img.shape[:2]
    bg, f = _shared(_opening_small, img, side)
    if f == 1:
        return bg[rows, cols]
    return px.linear_at_points(bg, (h, w), rows, cols)


def _as_srgb(values: np.ndarray, full_scale: float, response) -> np.ndarray:
    """RGB samples as an sRGB sensor would have written the same light (``response``: the frame's curve).

    The colour checks' numbers are stated on sRGB frames; without a response or with an sRGB one the
    samples are returned as they are.
    """
    if response is None or response.curve == "srgb":
        return values
    return response.as_srgb(values, float(full_scale))


def _bp_colour(src3, rows, cols, tissue_rgb, full_scale, response) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(chroma_peak, chroma_tissue, white_share)`` at BP pixels of channels ``src3`` (H, W, C), the white share
    of the peaks over their backgrounds ``tissue_rgb`` (P, 3) in linear light."""
    peak = _as_srgb(px.rgb_max9(src3, rows, cols), full_scale, response)
    fs = np.float32(full_scale)
    lin_peak, lin_tissue = (srgb_inverse(np.clip(v / fs, 0, 1)) for v in (peak, tissue_rgb))
    return px.chroma(peak), px.chroma(tissue_rgb), px.white_share(lin_peak - lin_tissue, lin_tissue)


def _specular_colour(chroma: np.ndarray, chroma_tissue: np.ndarray, share: np.ndarray | None = None) -> np.ndarray:
    """The colour check: chroma at most :data:`PALENESS_MAX` of the tissue's or :data:`WHITE_CHROMA`,
    and white share at least :data:`WHITE_SHARE_MIN` where ``share`` is given.
    """
    pale = (chroma <= PALENESS_MAX * chroma_tissue) | (chroma <= WHITE_CHROMA)
    return pale if share is None else pale & (share >= WHITE_SHARE_MIN)


def _panel_pixels_in(gray: np.ndarray, noise: np.ndarray, rr: np.ndarray, image: np.ndarray | None = None,
                     full_scale: float | None = None) -> np.ndarray:
    """How many flat-panel pixels each region ``rr`` (row0, row1, col0, col1) holds.

    ``noise`` is a :func:`~simtest.reconstruct.detect_pixels.noise_level_table`; next to a clipped
    channel a pixel must be flat in every channel.
    """
    if not np.max(noise) > 0:
        return np.zeros(len(rr), np.int64)
    rgb = image[..., :3] if image is not None and image.ndim == 3 and image.dtype.kind == "u" else None
    ceiling = float(np.iinfo(rgb.dtype).max) if rgb is not None else None
    # the panels of a frame once inside shared_passes (a second pass on a wider background reads them again)
    return px.pixels_in(_shared(_frame_panels, gray, noise, rgb, ceiling, full_scale), rr)


def _frame_panels(gray: np.ndarray, noise: np.ndarray, rgb, ceiling, full_scale) -> np.ndarray:
    """:func:`simtest.reconstruct.evidence_pixels.panels` of a frame, with the verifier's panel bars."""
    return px.panels(gray, PANEL_STD_REL * noise, PANEL_MIN_AREA * gray.size, rgb, ceiling, full_scale)


def _array_key(a: np.ndarray) -> tuple:
    """An array's memory, shape, strides and dtype: its key in :func:`shared_passes`' memo."""
    return a.__array_interface__["data"][0], a.shape, a.strides, a.dtype.str


#: :func:`frame_evidence` measures only around the candidates while its windows cover at most this
#: fraction of the frame.
WINDOWED_AREA_MAX = 0.25
#: Margin around a region of interest in which :func:`_surely_no_panels` follows a possibly flat component, px.
_PANEL_MARGIN_PX = 16
#: Relative slack of :func:`_surely_no_panels`' flatness test: 30 times the float32 rounding of the
#: panels' variance (about 6 x 2^-24 of the mean square).
_FLAT_SLACK = 1e-5


def _surely_no_panels(gray: np.ndarray, noise, rr: np.ndarray, full_scale: float | None = None) -> bool:
    """Whether no pixel of any region ``rr`` can be a panel pixel, proven without the frame."""
    thr2 = (PANEL_STD_REL * np.asarray(noise, np.float64)) ** 2 * (1.0 + _FLAT_SLACK)
    return px.surely_no_panels(gray, rr, _PANEL_MARGIN_PX, thr2, _FLAT_SLACK, PANEL_MIN_AREA * gray.size, full_scale)


def frame_evidence(image: np.ndarray, gray: np.ndarray, bps_uv: np.ndarray, rois, *, full_scale: float, noise: float,
                   background_px: int, reach_px: np.ndarray | None = None, ellipses=None, windowed: bool | None = None,
                   grey: bool = False, panels: bool = True, expected=None, response=None,
                   valley_rel: float = VALLEY_REL) -> Evidence:
    """Measure every candidate of a frame.

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) or (H, W)
        The frame as given (RGB).
    gray : ndarray of shape (H, W)
        Its luma, image units.
    bps_uv : ndarray of shape (N, 2)
        The candidates' BPs (u, v), px.
    rois : sequence of Roi, or ndarray of shape (N, 4), int
        Their regions of interest (row0, row1, col0, col1).
    full_scale : float
        Intensity of white, image units.
    noise : float
        Noise standard deviation of the luma, image units.
    background_px : int
        Side of the background opening's square, px (detection's).
    reach_px : ndarray of shape (N,), optional
        Radius around each BP in which other specular peaks are counted, px; NaN (or None): not counted.
    ellipses : sequence of Ellipse or None, optional
        Each candidate's primary isophote: peaks inside it are its own, not neighbours.
    windowed : bool, optional
        Measure only where the checks read (True) or over the frame (False): the same evidence to
        the bit; default: windows while they cover at most :data:`WINDOWED_AREA_MAX` of the frame.
    grey : bool
        R, G and B are equal and ``gray`` is their value.
    panels : bool or ndarray of bool, shape (N,)
        Measure the flat panels' share for all, none or the candidates marked (the others 0).
    expected : list of ndarray of shape (M, 2), optional
        Per candidate, where another light guide's highlight can lie (u, v) px
        (:func:`simtest.reconstruct.rig_pairs.other_guide_curves`). None: no rig.
    response : SensorResponse, optional
        The frame's tone curve; None: a display-encoded (sRGB) frame.
    valley_rel : float
        A peak joined to the candidate above this fraction of its height (less the noise's dip) is its own.

    Returns
    -------
    Evidence
    """
    h, w = gray.shape
    n = len(bps_uv)
    ij = np.clip(np.rint(np.asarray(bps_uv, np.float64).reshape(-1, 2)).astype(np.int64), 0, [w - 1, h - 1])
    cols, rows = ij.T  # the BPs' pixels (u is the column)
    reach = np.asarray(reach_px, np.float64).reshape(-1) if reach_px is not None else np.full(n, np.nan)
    todo = np.flatnonzero(np.isfinite(reach))
    rr = (np.asarray(rois, np.int64) if isinstance(rois, np.ndarray)
          else np.array([[r.row0, r.row1, r.col0, r.col1] for r in rois], np.int64)).reshape(-1, 4)
    # the windows the neighbour count reads (rows r0:r1, columns c0:c1 of the top-hat)
    win = np.stack([np.maximum(0, (rows[todo] - reach[todo]).astype(np.int64)),
                    np.minimum(h, (rows[todo] + reach[todo]).astype(np.int64) + 1),
                    np.maximum(0, (cols[todo] - reach[todo]).astype(np.int64)),
                    np.minimum(w, (cols[todo] + reach[todo]).astype(np.int64) + 1)], axis=1).reshape(-1, 4)
    measured = np.broadcast_to(np.asarray(panels, bool), (n,))  # the regions whose panel share is read
    rp = rr[measured]
    if windowed is None:
        spans = np.maximum(np.concatenate([win[:, 1] - win[:, 0] + 2, rp[:, 1] - rp[:, 0] + 2 * _PANEL_MARGIN_PX]), 0)
        widths = np.maximum(np.concatenate([win[:, 3] - win[:, 2] + 2, rp[:, 3] - rp[:, 2] + 2 * _PANEL_MARGIN_PX]), 0)
        windowed = float(np.sum(spans * widths)) <= WINDOWED_AREA_MAX * h * w
    floor = np.float32(max(SIGNIFICANCE_MIN * noise, 1e-9))  # numpy rounds the floor to float32 to compare
    bg_small, f = _shared(_opening_small, gray, background_px)
    # the luma's opening at the BPs: the reduced opening enlarged at those pixels only
    bg_bp = px.linear_at_points(bg_small, (h, w), rows, cols) if f > 1 else bg_small[rows, cols]
    g = _shared(_float32, gray) if not windowed else gray
    d = g[rows, cols].astype(np.float32, copy=False) - bg_bp  # the top-hat max(g - bg, 0) (float32, NaN kept)
    height = np.where((d >= 0) | np.isnan(d), d, np.float32(0.0)).astype(np.float32, copy=False)
    # only the maxima some neighbour count can select (top-hat >= NEIGHBOUR_REL of its height) are read
    if len(todo):
        s = np.float32(np.fmin.reduce(NEIGHBOUR_REL * height[todo]))  # NaN: none
        floor_max = np.float32(np.nan) if np.isnan(s) else max(floor, np.nextafter(s, np.float32(-np.inf)))
    else:
        floor_max = np.float32(np.inf)
    if windowed:  # the top-hat and its maxima in the reach windows only
        top, ys, xs = px.maxima_in_windows(gray, bg_small, f, win, floor_max)
    else:  # over the frame, the maxima in some candidate's reach window kept
        bg = cv2.resize(bg_small, (w, h), interpolation=cv2.INTER_LINEAR) if f > 1 else bg_small
        top, is_max = px.top_hat_maxima(g, bg, floor_max)
        ys, xs = np.divmod(np.flatnonzero(is_max), w)
        keep = px.in_windows(ys, xs, (h, w), win)
        ys, xs = ys[keep], xs[keep]
    # the colour: the RGB and its opening at the BPs and the maxima only
    src = image[..., :3] if image.ndim == 3 and not grey else gray
    at = _opening_at(src, background_px, np.concatenate([rows, ys]), np.concatenate([cols, xs]))
    if src.ndim != 3:  # a grey frame: its three channels alike
        at = np.repeat(at[:, None], 3, 1)
    at = _as_srgb(at, full_scale, response)  # the colour as an sRGB frame holds it
    bg_rgb_bp, bg_rgb_pk = at[:n], at[n:]
    # the RGB maximum over the 3 x 3 px around each BP (the window clipped to the frame)
    src3 = src if src.ndim == 3 else src[:, :, None]
    chroma_peak, chroma_tissue, share = _bp_colour(src3, rows, cols, bg_rgb_bp, full_scale, response)
    background = bg_bp
    # flat panels: share in each ROI (none where none can be: see _surely_no_panels)
    table = _shared(noise_level_table, gray, float(full_scale), float(noise))  # the noise at each level
    panel_fraction = np.zeros(n)
    if measured.any() and not (windowed and (not noise > 0 or _surely_no_panels(gray, table, rp, float(full_scale)))):
        inside = _panel_pixels_in(_shared(_float32, gray), table, rp, None if grey else image, float(full_scale))
        panel_fraction[measured] = inside / np.maximum((rp[:, 1] - rp[:, 0]) * (rp[:, 3] - rp[:, 2]), 1)
    # specular peaks of the frame: the top-hat's local maxima that pass the colour check
    colour = _specular_colour(px.chroma(_as_srgb(px.rgb_at(src3, ys, xs), full_scale, response)), px.chroma(bg_rgb_pk))
    ys, xs = ys[colour].astype(np.int64), xs[colour].astype(np.int64)
    neighbours = np.zeros(n, np.int64)
    if len(xs) and len(todo):
        # the same roundings as before: float32 thresholds from the float32 height
        ht = height[todo]
        ells = None if ellipses is None else [ellipses[k] for k in todo]
        exp_t = None if expected is None else [expected[k] for k in todo]
        neighbours[todo] = px.other_peaks(top, xs, ys, np.asarray(bps_uv, np.float64).reshape(-1, 2)[todo], ij[todo],
                                          reach[todo], NEIGHBOUR_REL * ht, valley_rel * ht - VALLEY_NOISE * noise,
                                          ells, NEIGHBOUR_AREA_REL, exp_t, PAIR_TOL_PX)
    # the significance's noise: the sensor's at the background's level, and JPEG's quantisation
    # error where the frame carries a block grid; an integer image's at least the rounding's
    q_sig = _shared(quantisation_sigma, gray if grey and gray.dtype == image.dtype else image) * float(full_scale) / 255.0
    lsb = QUANTISATION_SIGMA_LSB if np.issubdtype(image.dtype, np.integer) else 0.0
    noise_sig = max(float(np.hypot(noise, q_sig)), lsb)
    noise_bg = np.maximum(np.hypot(table[_level_bin(background, float(full_scale))], q_sig), lsb)
    return Evidence(chroma_peak, chroma_tissue, height, background, noise_sig, panel_fraction,
                    neighbours, full_scale=float(full_scale), noise_bg=noise_bg, white_share=share)


def specular_colour_at(image: np.ndarray, bps_uv: np.ndarray, *, full_scale: float,
                       response=None, background_px: int | None = None, white_only=None) -> np.ndarray:
    """The colour check of ``not_specular`` alone at the BPs ``bps_uv`` (N, 2) (u, v) px of ``image``
    (``background_px``: as for :func:`bp_checks`); where ``white_only`` (bool (N,)) is set, the white share
    alone (:data:`WHITE_SHARE_MIN`; the paleness waived, as for a rig twin).

    Returns bool (N,); all True for a grey frame.
    """
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    if image.ndim != 3 or not len(bps):
        return np.ones(len(bps), bool)
    shape = image.shape[:2]
    ij = np.clip(np.rint(bps).astype(np.int64), 0, [shape[1] - 1, shape[0] - 1])
    src = image[..., :3]
    side = background_px or background_side_px(shape)
    bg = _as_srgb(_opening_at(src, side, ij[:, 1], ij[:, 0]), full_scale, response)
    chroma, chroma_tissue, share = _bp_colour(src, ij[:, 1], ij[:, 0], bg, full_scale, response)
    out = _specular_colour(chroma, chroma_tissue, share)
    return out if white_only is None else out | (np.asarray(white_only, bool) & (share >= WHITE_SHARE_MIN))


def bp_checks(image: np.ndarray, gray: np.ndarray, bps_uv: np.ndarray, clipped: np.ndarray, *,
              full_scale: float, noise: float, grey: bool = False, response=None,
              background_px: int | None = None, twins=None) -> list[str | None]:
    """The checks of :func:`verdict` that read only a candidate's BP (colour and height), before any fit.

    Parameters
    ----------
    image, gray, full_scale, noise, grey, response
        As for :func:`frame_evidence`.
    bps_uv : ndarray of shape (N, 2)
        The candidates' BPs (u, v), px.
    clipped : ndarray of bool, shape (N,)
        The BP is on a clipped plateau (the height check is skipped).
    background_px : int, optional
        Side of the background opening's square, px; default :func:`background_side_px` of ``gray``.
    twins : callable, optional
        ``twins(pool, which)`` as for :meth:`Evidence.with_twins` (under a rig of separate lights).

    Returns
    -------
    list of str or None
        Per candidate: None where it passes, else its ``not_specular`` detail as :func:`verdict` gives it.
    """
    n = len(bps_uv)
    if not n:
        return []
    ev = _bp_evidence(image, gray, bps_uv, clipped, full_scale=full_scale, noise=noise, grey=grey, response=response,
                      background_px=background_px)
    if twins is not None:
        ev = ev.with_twins(twins)
    checks = verdict(ev, np.full(n, np.nan), np.zeros(n, bool))
    return [detail if status == "not_specular" else None for status, detail in checks]


def weak_white_peaks(image: np.ndarray, gray: np.ndarray, bps_uv: np.ndarray, clipped: np.ndarray, *,
                     full_scale: float, noise: float, grey: bool = False, response=None,
                     background_px: int | None = None) -> np.ndarray:
    """Which BPs are white peaks of significant height that the paleness or contrast bar alone refuses: the
    peaks a rig twin would let pass (:attr:`Evidence.weak_white`). Arguments as for :func:`bp_checks`;
    returns bool (N,)."""
    if not len(bps_uv):
        return np.zeros(0, bool)
    return _bp_evidence(image, gray, bps_uv, clipped, full_scale=full_scale, noise=noise, grey=grey,
                        response=response, background_px=background_px).weak_white


def _bp_evidence(image, gray, bps_uv, clipped, *, full_scale, noise, grey, response, background_px) -> Evidence:
    """:func:`frame_evidence` at the BPs alone (a pixel's ROI each), with ``clipped`` set."""
    bps = np.asarray(bps_uv, np.float64).reshape(-1, 2)
    ij = np.clip(np.rint(bps).astype(np.int64), 0, [gray.shape[1] - 1, gray.shape[0] - 1])
    rc = uv_to_rc(ij).astype(np.int64)  # (u, v) to (row, col): the one place that swaps them
    rows, cols = rc[:, 0], rc[:, 1]
    rois = np.stack([rows, rows + 1, cols, cols + 1], axis=1)
    ev = frame_evidence(image, gray, bps, rois, full_scale=full_scale, noise=noise,
                        background_px=background_px or background_side_px(gray.shape), windowed=True, grey=grey,
                        panels=False, response=response)
    return replace(ev, clipped=np.asarray(clipped, bool).reshape(-1))


#: The isovalue at which :data:`NEIGHBOUR_REACH` is stated (the default primary); not a level any check reads.
_REACH_T = 0.7


def _own_level(t) -> np.ndarray:
    """Squared ratio of the own lobe's radius at :data:`OWN_REL` to its radius at isovalue ``t``
    (a Gaussian lobe reaches level t at r = s sqrt(2 ln(1 / t))).
    """
    return np.log(1.0 / OWN_REL) / np.log(1.0 / np.asarray(t, np.float64))


def _reach_axes(t) -> np.ndarray:
    """:data:`NEIGHBOUR_REACH` for a primary isophote at ``t``, in its semi-major axes."""
    return NEIGHBOUR_REACH * np.sqrt(np.log(1.0 / _REACH_T) / np.log(1.0 / np.asarray(t, np.float64)))


def glint_field_px(camera) -> float:
    """:data:`~simtest.decisions.GLINT_FIELD_DEG` in px at the principal point of ``camera``.

    Parameters
    ----------
    camera : CameraModel or ndarray of shape (3, 3)
        A camera model (:mod:`simtest.geometry.cameras`) or pinhole intrinsics K.

    Returns
    -------
    float
        The angle (rad) times the lesser of the two image axes' px per radian at the principal point: exact
        for an equidistant lens, the least over a pinhole's field.
    """
    if isinstance(camera, np.ndarray):
        return float(min(camera[0, 0], camera[1, 1])) * math.radians(GLINT_FIELD_DEG)
    rad_per_px = np.linalg.norm(camera.pixel_to_ray_jacobian(camera.principal_point[None])[0], axis=0)
    return math.radians(GLINT_FIELD_DEG) / float(rad_per_px.max())


def assess(image: np.ndarray, gray: np.ndarray, ests, *, full_scale: float, windowed: bool | None = None,
           noise: float | None = None, grey: bool = False, camera=None, lights=None, response=None,
           background_px: int | None = None):
    """The evidence on a frame's estimates, with their fits' residual ratios and BP placement.

    Parameters
    ----------
    image, gray, full_scale, windowed, grey, response
        As for :func:`frame_evidence`.
    ests : sequence of SpecularityEstimate
        The frame's estimates (N), as the pipeline completed them.
    noise : float, optional
        The luma's noise standard deviation, image units; default
        :func:`~simtest.reconstruct.detect.noise_sigma` of ``gray``.
    camera : CameraModel, optional
        The camera, with ``lights``.
    lights : LightRig, optional
        The scope's light rig: a peak where another guide's highlight can lie is neither a
        neighbour nor the surround's light. None (or one light): no pairing.
    background_px : int, optional
        Side of the background opening's square, px; default :func:`background_side_px` of ``gray``.

    Returns
    -------
    (Evidence, ndarray of shape (N,), ndarray of bool, shape (N,))
        The evidence, the primary isophote's RMS residual over its semi-minor axis (NaN without a
        fit; 0 for a camera model without image conics), and whether the BP lies inside that ellipse.
    """
    n = len(ests)
    res = np.full(n, np.nan)
    reach = np.full(n, np.nan)
    minor = np.full(n, np.nan)
    inside = np.zeros(n, dtype=bool)
    bps = np.array([e.bp_px for e in ests], dtype=np.float64).reshape(-1, 2)
    # each estimate's primary isophote read once (its ellipse and residual are the primary's)
    prims = [e.primary for e in ests]
    ells = [None if p is None else p.ellipse for p in prims]
    resid = [None if p is None else p.fit_residual_px for p in prims]
    ok = np.array([e.ok for e in ests], dtype=bool)
    major = np.full(n, np.nan)
    # each primary isophote's isovalue (the user's): the reach and the own lobe scale with it
    t = np.array([_REACH_T if p is None else p.isovalue for p in prims], np.float64)
    # a camera model without image conics: its image outline still gives the checks its size, reach and
    # own lobe (its residual is the lens's, taken as 0)
    refit = [k for k in np.flatnonzero(ok) if ells[k] is None and ests[k].points_uv is not None]
    for k, fit in zip(refit, fit_ellipses([ests[k].points_uv for k in refit]) if refit else ()):
        if fit:
            ells[k], resid[k] = fit.ellipse, 0.0
    fitted = np.array([ell is not None and r is not None for ell, r in zip(ells, resid)], dtype=bool)
    if fitted.any():  # every fitted estimate's numbers at once (arrays in the ellipse's place)
        f = np.flatnonzero(fitted)
        cu, cv, a, b, ang, r = np.array([(ells[k].center[0], ells[k].center[1], ells[k].semi_axes[0],
                                          ells[k].semi_axes[1], ells[k].angle_rad, resid[k]) for k in f],
                                        dtype=np.float64).T
        minor[f], major[f] = b, a
        res[f] = r / np.maximum(b, 1e-9)
        inside[f] = px.ellipse_level(SimpleNamespace(center=(cu, cv), semi_axes=(a, b), angle_rad=ang),
                                   bps[f, 0], bps[f, 1]) <= 1.0
        reach[f] = np.where(ok[f], _reach_axes(t[f]) * a + OWN_RADIUS_PX, np.nan)
    separate = lights is not None and lights.has_separate_lights
    glints = camera is not None and not separate  # one light place: glint fields (NaN kept)
    near = np.maximum(reach, glint_field_px(camera)) if glints else reach
    expected = None
    if separate and camera is not None:
        # out to the reach plus the own lobe's radius at OWN_REL
        expected = other_guide_curves(camera, lights.positions, bps,
                                      np.nan_to_num(reach + np.sqrt(_own_level(t)) * major, nan=-1.0))
    # no image outline at all: judged on the rest
    res[ok & ~fitted], inside[ok & ~fitted] = 0.0, True
    ev = frame_evidence(image, gray, bps, [e.roi for e in ests], full_scale=full_scale,
                        noise=noise_sigma(gray) if noise is None else float(noise),
                        background_px=background_px or background_side_px(gray.shape),
                        reach_px=near, ellipses=ells, windowed=windowed, grey=grey, expected=expected,
                        panels=ok, response=response, valley_rel=GLINT_FIELD_VALLEY_REL if glints else VALLEY_REL)
    clipped = np.array([bool(e.saturated) for e in ests], dtype=bool)
    # the surround, for the candidates that pass every check before it; the others' share counts as 1
    surround = np.where(np.isfinite(reach), 1.0, np.nan)
    white = None
    ev = replace(ev, clipped=clipped)
    if expected is not None:  # a weak lobe whose twin lies where the rig puts another guide's
        wander = np.array([estimate_wander_px(e) for e in ests])
        ev = ev.with_twins(lambda pool, which: rig_twins(camera, lights.positions, bps, pool, wander, which))
    passed = (np.isfinite(reach) & (ev.panel_fraction <= PANEL_FRACTION_MAX) & ev.specular_colour & ev.tall
              & (ev.neighbours == 0))
    if expected is not None:  # the other guides' lobes, where the rig puts them
        lit = ev.background + SURROUND_REL * ev.height
        ev = replace(ev, paired=other_lobe_centres(gray, expected, ells, _own_level(t), lit))
    if passed.any():
        g = np.asarray(gray)  # surround_fractions converts its windows to float32 (the same values)
        ij = np.clip(np.rint(bps).astype(np.int64), 0, [gray.shape[1] - 1, gray.shape[0] - 1])
        sel = np.flatnonzero(passed)
        args = (g, [ells[k] for k in sel], ij[sel], reach[sel], _own_level(t[sel]), SURROUND_REL,
                None if ev.paired is None else [ev.paired[k] for k in sel])
        if not grey and image.ndim == 3:  # and the cluster check's: white light only
            white = surround.copy()
            surround[passed], white[passed] = px.surround_fractions(*args, rgb=image[..., :3],
                                                                    full_scale=float(full_scale), response=response)
        else:
            surround[passed] = px.surround_fractions(*args)
    return replace(ev, minor_px=minor, surround=surround, surround_white=white), res, inside


def confidence_features(ev: Evidence, residual_rel: np.ndarray) -> np.ndarray:
    """The features :func:`confidence` weighs, one row per candidate.

    Parameters
    ----------
    ev : Evidence
        The frame's evidence (N candidates).
    residual_rel : ndarray of shape (N,)
        As for :func:`confidence`, finite.

    Returns
    -------
    ndarray of shape (N, 5)
        Log white share (clipped to 0.1..10; 1 where not measured), log significance (clipped),
        minus log of the surround's share of other light plus 1 % (white light only on a colour
        frame), minus log residual ratio (clipped), minus the panel share.
    """
    sur = ev.surround if ev.surround_white is None else ev.surround_white
    surround = np.ones(len(ev.height)) if sur is None else np.nan_to_num(sur, nan=1.0)
    share = np.ones(len(ev.height)) if ev.white_share is None else np.nan_to_num(ev.white_share, nan=1.0)
    return np.stack([
        np.log(np.clip(share, 0.1, 10.0)),
        np.log(np.clip(ev.significance, 1.0, 1e4)),
        -np.log(surround + 0.01),
        -np.log(np.clip(residual_rel, 0.01, 10.0)),
        -np.asarray(ev.panel_fraction, np.float64),
    ], axis=1)


def confidence(ev: Evidence, residual_rel: np.ndarray, coefficients: np.ndarray | None = None) -> np.ndarray:
    """Confidence in [0, 1] that each candidate is an isolated specular highlight (logistic in the features).

    Parameters
    ----------
    ev : Evidence
        The frame's evidence (N candidates).
    residual_rel : ndarray of shape (N,)
        Primary isophote's RMS residual over its semi-minor axis (NaN: taken at :data:`RESIDUAL_MAX_REL`).
    coefficients : ndarray of shape (6,), optional
        Intercept and weights; default :data:`COEFFICIENTS`.

    Returns
    -------
    ndarray of shape (N,)
    """
    c = COEFFICIENTS if coefficients is None else np.asarray(coefficients, np.float64)
    r = np.where(np.isfinite(residual_rel), residual_rel, RESIDUAL_MAX_REL)
    z = c[0] + confidence_features(ev, r) @ c[1:]
    return 1.0 / (1.0 + np.exp(-z))


def verdict(ev: Evidence, residual_rel: np.ndarray, bp_inside: np.ndarray, only=None) -> list[tuple[str, str] | None]:
    """The status each fitted candidate earns: ``("ok", "")`` or a rejection and its numbers.

    Parameters
    ----------
    ev : Evidence
    residual_rel : ndarray of shape (N,)
        As for :func:`confidence`.
    bp_inside : ndarray of bool, shape (N,)
        Whether the BP lies inside the primary isophote's ellipse.
    only : array_like of int, optional
        Judge only these candidates (the others get None).

    Returns
    -------
    list of (str, str) or None
        Status and detail per candidate, the first failing check in the order overlay,
        not_specular, cluster, bad_fit; ``weak_twin`` where only its rig twin passed its height (:data:`WEAK_TWIN`).
    """
    n = len(ev.height)
    out: list = [None] * n
    # Python floats (their formatting is several times numpy scalars'), read once per array
    pal, sig, con = ev.paleness.tolist(), ev.significance.tolist(), ev.contrast.tolist()
    colour, tall, weak = ev.specular_colour.tolist(), ev.tall.tolist(), ev.weak_twin.tolist()
    minor = [math.nan] * n if ev.minor_px is None else np.asarray(ev.minor_px, np.float64).tolist()
    sur = ev.surround if ev.surround_white is None else ev.surround_white
    surround = [math.nan] * n if sur is None else np.asarray(sur, np.float64).tolist()
    panel = np.asarray(ev.panel_fraction, np.float64).tolist()
    neighbours = np.asarray(ev.neighbours).tolist()
    height, cpeak, ctissue = ev.height.tolist(), ev.chroma_peak.tolist(), ev.chroma_tissue.tolist()
    share = [1.0] * n if ev.white_share is None else np.asarray(ev.white_share, np.float64).tolist()
    res = np.asarray(residual_rel, np.float64).tolist()
    inside = np.asarray(bp_inside, bool).tolist()
    for k in (range(n) if only is None else np.asarray(only, np.int64).tolist()):
        if panel[k] > PANEL_FRACTION_MAX:
            out[k] = ("overlay", f"{panel[k]:.0%} of its region is a flat panel (> {PANEL_FRACTION_MAX:.0%})")
        elif not colour[k] and not share[k] >= WHITE_SHARE_MIN:
            out[k] = ("not_specular", f"white is {share[k]:.2f} of the peak's light above the tissue "
                                      f"(< {WHITE_SHARE_MIN})")
        elif not colour[k]:
            out[k] = ("not_specular", f"peak chroma {cpeak[k]:.2f} is {pal[k]:.2f} of the tissue's {ctissue[k]:.2f} "
                                      f"(> {PALENESS_MAX})")
        elif not tall[k]:
            out[k] = ("not_specular", f"height {height[k]:.3g} is {sig[k]:.1f} noise sigma and {con[k]:.2f} of the "
                                      f"background (need {SIGNIFICANCE_MIN:g} and {CONTRAST_MIN:g})")
        elif neighbours[k] > 0:
            out[k] = ("cluster", f"{neighbours[k]} other specular peak(s) in its region")
        elif surround[k] > SURROUND_FRACTION_MAX:
            out[k] = ("cluster", f"{surround[k]:.0%} of its surround is other light at {SURROUND_REL:g} of its height "
                                 f"(> {SURROUND_FRACTION_MAX:.0%})")
        elif not (res[k] <= RESIDUAL_MAX_REL) or not inside[k]:
            why = "the BP lies outside its isophote" if not inside[k] else (
                f"isophote residual {res[k]:.2f} of its semi-minor axis (> {RESIDUAL_MAX_REL})")
            out[k] = ("bad_fit", why)
        elif minor[k] < MINOR_AXIS_MIN_PX:
            out[k] = ("bad_fit", f"isophote semi-minor axis {minor[k]:.2f} px (< {MINOR_AXIS_MIN_PX} px: "
                                 "narrower than the pixel grid resolves)")
        elif weak[k]:
            out[k] = (WEAK_TWIN, f"height {con[k]:.2f} of the room, below {CONTRAST_MIN:g}, passed for its rig twin")
        else:
            out[k] = ("ok", "")
    return out
