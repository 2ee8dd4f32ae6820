"""The colour stage of the light-aware fits: the specular image of a linear RGB ROI, the tissue's
body colours measured on the ROI's border and projected out (:func:`specular_image`)."""

from __future__ import annotations

import functools

import numpy as np

from simtest._lazy import require
from simtest.reconstruct.detect_pixels import noise_sigma_of_differences, second_differences

from simtest.decisions import BODY_PROJECTION_MAX_GAIN, BODY_SECOND_SNR as _BODY_SECOND_SNR

#: Passes of :func:`specular_image`'s trimming of the border, and the share of the ROI's peak
#: above which a border pixel's projected value marks a lobe (left out).
_BODY_TRIM_PASSES = 3
_BODY_TRIM_SHARE = 0.02
#: Width of :func:`specular_image`'s border band, px: the ROI's smaller side over this, 1 to the max.
_BODY_BAND_DIVISOR = 64
_BODY_BAND_MAX = 8


def _border_band(shape) -> np.ndarray:
    """The band along an (H, W) ROI's edges on which :func:`specular_image` measures the body colours:
    its smaller side over :data:`_BODY_BAND_DIVISOR`, 1 to :data:`_BODY_BAND_MAX` px. (H, W) bool."""
    h, w = int(shape[0]), int(shape[1])
    b = int(np.clip(min(h, w) // _BODY_BAND_DIVISOR, 1, _BODY_BAND_MAX))
    ring = np.ones((h, w), bool)
    ring[b:-b, b:-b] = False
    return ring


def per_channel(level) -> np.ndarray:
    """One level, or each channel's, as the three channels' (3,) float64 (a view: read-only)."""
    return np.broadcast_to(np.asarray(level, dtype=np.float64).reshape(-1), (3,))


def specular_image(rgb, clip_level=None, *, ring=None, fluctuation: bool = True, border: bool = True,
                   two_channels: bool = True, censor_margin=None):
    """The specular reflection of a linear RGB ROI, the tissue's body colours projected out.

    Dichromatic reflection [6]_: ``I = S (1, 1, 1) + D a(x)``, the film's reflection S white and the
    body reflection coloured by the albedo ``a(x)``, whose texture moves within a plane B of RGB.
    Weights ``w`` orthogonal to B with ``w . (1, 1, 1) = 1`` give ``w . I = S`` whatever the texture.
    B is the plane of the border band's colours clear of the clip (each channel below its clip less
    ``censor_margin``, no 8-neighbour clipped: noise leaves a clipped channel below its clip now and
    then, a colour no tissue has), fitted in units of each channel's noise where the ROI shows noise
    (:func:`_body_weights`), pixels whose projected value
    exceeds :data:`_BODY_TRIM_SHARE` of the peak (another lobe) trimmed in passes; a
    second body colour counts only above :data:`_BODY_SECOND_SNR` times the third singular value, and
    so in units of each channel's noise (:func:`_channel_noise`: noise added after a tone curve, or
    shot noise, is larger in the brighter channels, and a noisier channel alone passes for a colour).
    Otherwise (or with a noise gain ``|w|`` above :data:`BODY_PROJECTION_MAX_GAIN`) the
    least-fluctuation weights stand in (:func:`_least_fluctuation_weights`), and failing those None.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3)
        Linear radiance, white balance undone (white is equal in the three channels).
    clip_level : float or array_like of 3 floats, optional
        Each channel's linear clip level (None: nothing clipped).
    ring : ndarray of shape (H, W), bool, optional
        The pixels B is measured on (default :func:`_border_band`).
    fluctuation : bool
        Fall back on the least-fluctuation weights (False: None there).
    border : bool
        Measure the body colours on the border (False: the least-fluctuation weights directly).
    two_channels : bool
        Value a pixel clipped in one channel with a negative weight from its two other channels
        (:func:`_from_two_channels`); False: leave it out (``missing``).
    censor_margin : float or array_like of 3 floats, optional
        A channel within this of its clip level counts as clipped, in the masks returned and where
        the body colours are measured (:data:`~simtest.decisions.CLIP_MARGIN`). None: 0.

    Returns
    -------
    tuple or None
        ``(values, lower, missing, w)``: ``values`` (H, W) ``w . I`` (two channels' value where one
        clipped channel has ``w_c < 0``); ``lower`` (H, W) bool where a value is a lower bound
        (censored); ``missing`` (H, W) bool where no bound exists (left out); ``w`` (3,). None where no
        projection within the gain's bound exists, or the border has fewer than 3 unclipped pixels.

    Raises
    ------
    ValueError
        ``rgb`` not (H, W, 3) and finite, or a clip level not 1 or 3 numbers.

    References
    ----------
    .. [6] S. A. Shafer, "Using color to separate reflection components", Color Research &
           Application 10(4), 210-218, 1985. https://doi.org/10.1002/col.5080100409
    """
    v = np.asarray(rgb, dtype=np.float64)
    if v.ndim != 3 or v.shape[2] != 3 or not np.isfinite(v).all():
        raise ValueError(f"rgb: need a finite (H, W, 3) array, got shape {v.shape}")
    if clip_level is not None and np.size(clip_level) not in (1, 3):
        raise ValueError(f"clip_level: need 1 or 3 numbers, got {clip_level!r}")
    clip = np.full(3, np.inf) if clip_level is None else per_channel(clip_level)
    level = clip if censor_margin is None else clip - per_channel(censor_margin)
    clipped = v >= level  # (H, W, 3)
    unclipped = ~clipped.any(axis=2)
    clear = ~require("scipy.ndimage").maximum_filter(~unclipped, size=3, mode="constant", cval=False)
    edge = v[(_border_band(v.shape[:2]) if ring is None else ring) & clear]
    if len(edge) < 3:
        return None
    free = v[unclipped]
    scale = functools.cache(lambda: _channel_noise(v, clear))  # (measured where a second colour is read)
    keep = np.ones(len(edge), bool)
    w = None
    for _ in range(_BODY_TRIM_PASSES if border else 0):
        w = _body_weights(edge[keep], scale)
        if w is None:
            break
        # border pixels above a share of the peak hold another lobe's white: measure again without them
        spec = edge @ w
        new = spec <= _BODY_TRIM_SHARE * max(float((free @ w).max()), 0.0)
        if np.array_equal(new, keep) or np.count_nonzero(new) < 3:
            break
        keep = new
    w = None if w is None else _body_weights(edge[keep], scale)
    if w is None and fluctuation:
        # the border's second body colour is lost in the noise
        w = _least_fluctuation_weights(v, ~unclipped)
    if w is None:
        return None
    # a channel censored below the clip holds at least its level: bound by the level, not the noisy value
    values = v @ w if censor_margin is None else np.minimum(v, level) @ w
    anyc = clipped.any(axis=2)
    neg = (clipped & (w < 0)).any(axis=2)
    if two_channels and neg.any():
        _from_two_channels(v, clipped, neg, anyc, values, edge[keep])
    return values, anyc & ~neg, neg, w


def _channel_noise(v, clear) -> np.ndarray | None:
    """Each channel's noise standard deviation over the ROI's pixels clear of the clip (3,), from the second
    differences along its rows; None where a channel shows none (a noise-free render) or too few pixels do."""
    ok = clear[:, :-2] & clear[:, 1:-1] & clear[:, 2:]
    if np.count_nonzero(ok) < _FLUCTUATION_MIN_PIXELS:
        return None
    sig = np.array([noise_sigma_of_differences(second_differences(v[..., c])[ok]) for c in range(3)])
    return sig if (sig > 0).all() else None


def _from_two_channels(v, clipped, neg, anyc, values, colours) -> None:
    """In place: the specular value of each pixel with one clipped channel of negative weight, from its
    two other channels (weights ``u`` with ``u . (1, 1) = 1`` and ``u`` orthogonal to the leading body
    colour of ``colours`` (M, 3)). ``neg`` and ``anyc`` lose the pixels given a value; a channel pair
    whose gain ``|u|`` exceeds :data:`BODY_PROJECTION_MAX_GAIN` is left as it was."""
    b1 = np.linalg.svd(colours, full_matrices=False)[2][0]
    one = neg & (np.count_nonzero(clipped, axis=2) == 1)
    for c in range(3):
        rows = one & clipped[..., c]
        if not rows.any():
            continue
        o0, o1 = [k for k in range(3) if k != c]
        den = float(b1[o0] - b1[o1])
        if not abs(den) > 1e-12:
            continue
        u = np.zeros(3)
        u[o0], u[o1] = -b1[o1] / den, b1[o0] / den
        if float(np.linalg.norm(u)) > BODY_PROJECTION_MAX_GAIN:
            continue
        # at most w . I as measured: with a negative weight on the clipped channel it bounds S from above
        values[rows] = np.minimum(v[rows] @ u, values[rows])
        neg[rows] = anyc[rows] = False


#: Side of the box (px) whose mean is the smooth part :func:`_least_fluctuation_weights` takes out.
_FLUCTUATION_BOX = 9
#: Passes of :func:`_least_fluctuation_weights`' trimming of the lobes (as ``_BODY_TRIM_PASSES``).
_FLUCTUATION_PASSES = 4
#: The fewest pixels :func:`_least_fluctuation_weights` measures the fluctuations on.
_FLUCTUATION_MIN_PIXELS = 100


def _least_fluctuation_weights(v, clipped) -> np.ndarray | None:
    """The weights ``w`` (3,) that let through the least of the ROI's fluctuations about its box mean
    (:data:`_FLUCTUATION_BOX`), with ``w . (1, 1, 1) = 1`` and ``w . a0 = 0`` (a0 the leading body
    colour): ``w = R^-1 C (C^T R^-1 C)^-1 (0, 1)``, ``C = [a0, (1, 1, 1)]`` [7]_. None with too few
    pixels, a singular system or a gain above :data:`BODY_PROJECTION_MAX_GAIN`.

    References
    ----------
    .. [7] O. L. Frost, "An algorithm for linearly constrained adaptive array processing",
           Proc. IEEE 60(8), 926-935, 1972. https://doi.org/10.1109/PROC.1972.8817
    """
    ndi = require("scipy.ndimage")  # when first needed: scipy slows the start
    k = _FLUCTUATION_BOX
    if min(v.shape[:2]) < 2 * k:
        return None
    inside = ndi.minimum_filter((v > 0).any(axis=2), size=k) & ~ndi.maximum_filter(clipped, size=k)
    # channels first, (3, H * W): the masked 3 x 3 sums below run over contiguous rows
    smooth = np.stack([ndi.uniform_filter(v[..., c], k, mode="nearest") for c in range(3)]).reshape(3, -1)
    fluct = np.moveaxis(v, -1, 0).reshape(3, -1) - smooth
    use = inside = inside.ravel()
    w = None
    for _ in range(_FLUCTUATION_PASSES):
        if (count := np.count_nonzero(use)) < _FLUCTUATION_MIN_PIXELS:
            return None
        # a0 (the smooth colours' leading right singular vector) and R: 3 x 3 sums over the mask, no copies
        a0 = np.linalg.eigh((smooth * use) @ smooth.T)[1][:, -1]
        R = (fluct * use) @ fluct.T / count
        R = R + 1e-12 * float(np.trace(R)) * np.eye(3)  # a texture-free, noise-free ROI: R ~ 0
        C = np.column_stack([a0, np.ones(3)])
        try:
            RiC = np.linalg.solve(R, C)
            w = RiC @ np.linalg.solve(C.T @ RiC, np.array([0.0, 1.0]))
        except np.linalg.LinAlgError:
            return None
        spec = w @ smooth
        peak = max(float(spec[inside].max()), 0.0)
        new = inside & (spec <= _BODY_TRIM_SHARE * peak)
        if np.array_equal(new, use):
            break
        use = new
    if w is None or not np.isfinite(w).all() or float(np.linalg.norm(w)) > BODY_PROJECTION_MAX_GAIN:
        return None
    return w


def _body_weights(colours, scale=None) -> np.ndarray | None:
    """Weights ``w`` (3,) orthogonal to the plane of the two leading body colours of ``colours`` (M, 3),
    ``w . (1, 1, 1) = 1``; None without a second body colour or with a gain above
    :data:`BODY_PROJECTION_MAX_GAIN`. ``scale`` (3,): each channel's noise standard deviation, or a
    function giving it or None (called only where the colours as given show a second colour); the plane
    is then fitted, and the second colour must stand out, in units of each channel's noise, where the
    noise is alike in every direction and the total least squares plane the maximum-likelihood one
    (Van Huffel and Vandewalle 1991, https://doi.org/10.1137/1.9781611971002); a plane fitted to the
    colours as given tilts towards the noisiest channel. None: as given."""
    sv = np.linalg.svd(colours, compute_uv=False)
    # a second body colour only where its singular value stands above the third's and round-off, and so in
    # units of each channel's noise, where a noisier channel alone no longer looks like a colour
    if not (sv[1] > _BODY_SECOND_SNR * sv[2] and sv[1] > 1e-9 * sv[0]):
        return None
    scale = scale() if callable(scale) else scale
    unit = np.ones(3) if scale is None else np.asarray(scale, dtype=np.float64)
    sw, Vt = np.linalg.svd(colours / unit, full_matrices=False)[1:]
    if scale is not None and not sw[1] > _BODY_SECOND_SNR * sw[2]:
        return None
    n = Vt[2] / unit  # the plane's normal in noise units, mapped back: n . b = 0 for the body colours b
    w = n / float(n.sum()) if n.sum() else None
    return w if w is not None and float(np.linalg.norm(w)) <= BODY_PROJECTION_MAX_GAIN else None
