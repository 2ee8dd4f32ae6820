"""The colour stage of the light-aware fits: the specular image of a linear RGB ROI, the tissue's
body colours measured on the ROI's border and projected out (:func:`specular_image`), or the
least-fluctuation weights where the border tells no second body colour."""

from __future__ import annotations

import numpy as np

from simtest._lazy import require

from simtest.decisions import BODY_PROJECTION_MAX_GAIN, BODY_SECOND_SNR as _BODY_SECOND_SNR

#: Passes of :func:`specular_image`'s trimming of the border: a border pixel whose projected
#: (specular) value is above ``_BODY_TRIM_SHARE`` of the ROI's peak is left out and the body
#: colours measured again. White lies near mucosa's body plane (12 deg off it: the projection's
#: gain of 2.8), so that a colour's distance from the plane does not tell a lobe's white from the
#: body's variation; its projected value does, to the share it leaks.
_BODY_TRIM_PASSES = 3
_BODY_TRIM_SHARE = 0.02
#: Width of :func:`specular_image`'s border band, px: the ROI's smaller side over this, between
#: 1 and :data:`_BODY_BAND_MAX` (a 406 px ROI: 6 px, 9600 pixels; a 40 px one: 1 px).
_BODY_BAND_DIVISOR = 64
_BODY_BAND_MAX = 8


def _border_band(shape) -> np.ndarray:
    """The pixels of an (H, W) ROI that :func:`specular_image` measures the body colours on: the
    band of :data:`_BODY_BAND_DIVISOR`-th of its smaller side (1 to :data:`_BODY_BAND_MAX` px) along
    its edges, where the lobes' tails are faintest. (H, W) bool."""
    h, w = int(shape[0]), int(shape[1])
    b = int(np.clip(min(h, w) // _BODY_BAND_DIVISOR, 1, _BODY_BAND_MAX))
    ring = np.zeros((h, w), bool)
    ring[:b] = ring[-b:] = True
    ring[:, :b] = ring[:, -b:] = True
    return ring


def per_channel(level) -> np.ndarray:
    """One level, or each channel's, as the three channels' (3,) float64 (a view: read-only)."""
    return np.broadcast_to(np.asarray(level, dtype=np.float64).reshape(-1), (3,))


def specular_image(rgb, clip_level=None, *, ring=None, fluctuation: bool = True, border: bool = True,
                   two_channels: bool = True, censor_margin=None):
    """The specular reflection of a linear RGB ROI, the tissue's body colours projected out.

    Dichromatic reflection [6]_: a pixel's linear radiance is ``I = S (1, 1, 1) + D a(x)``, the
    wet film's specular reflection S white (Fresnel's reflectance of the film is flat over the
    visible band; the white balance undone, each channel's radiance in the units in which white is
    (1, 1, 1)) and the body reflection ``D a(x)`` coloured by the tissue's albedo ``a(x)``, whose
    texture (colour variation, vessels) moves ``a`` within a plane of RGB spanned by a few
    chromophores' colours. Where the albedo's colours span a plane B (two body colours), the
    weights ``w`` orthogonal to B with ``w . (1, 1, 1) = 1`` give ``w . I = S`` exactly at every
    pixel, whatever the texture: the photometric fit then sees the film's lobes (and what of the
    shading the projection leaves, which its diffuse column still takes) instead of the lobes
    under a textured shading, whose texture the plane model cannot hold (measured:
    ``docs/decisions/light-aware-recommendation.md``).

    B is measured on a band along the ROI's edges (:func:`_border_band`: the lobe's faint tails,
    where the body reflection dominates): the two leading right singular vectors of its unclipped pixels' colours (about 0:
    colours are proportional to the shading), the colours off their plane (where the border
    crosses another lobe) left out in a few passes where their projected value is above a share
    of the peak (:data:`_BODY_TRIM_SHARE`). A share e of white left in a body colour leaks
    e times its shading into the values: the diffuse column takes the shading's smooth part, e
    times its texture stays. A second body colour is used only where the border's second singular
    value stands above its third (:data:`_BODY_SECOND_SNR`); where the border holds one body
    colour, or the projection's noise gain ``|w|`` exceeds :data:`BODY_PROJECTION_MAX_GAIN`,
    the least-fluctuation weights of the whole ROI stand in (``fluctuation``,
    :func:`_least_fluctuation_weights`: the leading body colour removed, and of the rest, what
    lets through the least of the ROI's texture and noise together), and where they too are
    beyond the bound or not measurable, None is returned and the caller fits one channel. Not
    the leading colour alone, orthogonally: that leaves the texture's second colour in the values
    (the vessels; measured: ``docs/decisions/light-aware-recommendation.md``). Why the border's
    colours are lost in read noise: the sensor's noise is added to the linear channels and
    clipped at 0, and on the endoscope's mucosa the blue channel's body reflection is 1 to 3
    noise sigmas at 0.5 to 2 % read noise, where the border's second singular value (1.5 % of
    the first, noise-free) is within the noise's.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3)
        Linear radiance, white balance undone (white is equal in the three channels).
    clip_level : float or array_like of 3 floats, optional
        Each channel's linear clip level: a channel at or above it is clipped (its radiance at
        least that). None: nothing clipped.
    ring : ndarray of shape (H, W), bool, optional
        The pixels B is measured on (default: the band along the ROI's edges,
        :func:`_border_band`).
    fluctuation : bool
        Where the border tells no second body colour, the least-fluctuation weights
        (:func:`_least_fluctuation_weights`; False: None there).
    border : bool
        Measure the body colours on the border (default); False: the least-fluctuation weights
        whatever the border tells (with ``fluctuation``).
    two_channels : bool
        Value a pixel clipped in one channel whose weight is negative from its two other channels
        (:func:`_from_two_channels`; default); False: leave it out (``missing``).
    censor_margin : float or array_like of 3 floats, optional
        A channel within this of its clip level counts as clipped in the masks returned (the
        noise clips it often: :data:`~simtest.decisions.CLIP_MARGIN`); the body colours are
        measured on the pixels the clip itself left. None: 0.

    Returns
    -------
    tuple or None
        ``(values, lower, missing, w)``: ``values`` (H, W) ``w . I``, and where one channel is
        clipped and its ``w_c < 0`` the value of the two others (:func:`_from_two_channels`);
        ``lower`` (H, W) bool where a pixel's value is a lower bound (clipped channels, each with
        ``w_c >= 0``: censored data); ``missing`` (H, W) bool where several channels are clipped
        and one of them has ``w_c < 0`` (no bound: left out); ``w`` (3,). None where neither the
        border's two body colours nor (with ``fluctuation``) the least-fluctuation weights give a
        projection within the gain's bound, or the border has fewer than 3 unclipped pixels.

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
    if clip_level is None:
        clip = np.full(3, np.inf)
    else:
        clip = per_channel(clip_level).copy() if np.size(clip_level) in (1, 3) else None
        if clip is None:
            raise ValueError(f"clip_level: need 1 or 3 numbers, got {clip_level!r}")
    clipped = v >= clip  # (H, W, 3)
    if ring is None:
        ring = _border_band(v.shape[:2])
    edge = v[ring & ~clipped.any(axis=2)]
    if len(edge) < 3:
        return None
    free = v[~clipped.any(axis=2)]
    keep = np.ones(len(edge), bool)
    w = None
    for _ in range(_BODY_TRIM_PASSES if border else 0):
        w = _body_weights(edge[keep])
        if w is None:
            break
        # border pixels whose specular value is above a share of the ROI's peak hold a lobe's
        # white (where the border crosses another light's lobe or a neighbouring highlight):
        # they are left out and the body colours measured again
        spec = edge @ w
        new = spec <= _BODY_TRIM_SHARE * max(float((free @ w).max()), 0.0)
        if np.array_equal(new, keep) or np.count_nonzero(new) < 3:
            break
        keep = new
    w = None if w is None else _body_weights(edge[keep])
    if w is None and fluctuation:
        # the border's second body colour is lost in the noise (on the endoscope's mucosa at
        # 0.5 % read noise and above, where the darkest channel is at 1 to 3 noise sigmas): the
        # projection that lets through the least of the ROI's fluctuations instead
        w = _least_fluctuation_weights(v, clipped.any(axis=2))
    if w is None:
        return None
    values = v @ w
    if censor_margin is not None:
        # a channel censored at its level below the clip holds at least that level: the bound
        # its projection gives is that of the level, not of its noisy value
        level = clip - per_channel(censor_margin)
        clipped = v >= level
        values = np.minimum(v, level) @ w
    anyc = clipped.any(axis=2)
    neg = (clipped & (w < 0)).any(axis=2)
    if two_channels and neg.any():
        _from_two_channels(v, clipped, neg, anyc, values, edge[keep])
    return values, anyc & ~neg, neg, w


def _from_two_channels(v, clipped, neg, anyc, values, colours) -> None:
    """The specular value of each pixel with one clipped channel whose projection weight is
    negative (no bound from ``w``), from its two unclipped channels, in place.

    Dichromatic reflection in two channels (o0, o1): ``I_o = S + D a_o``; with the albedo ``a``
    along the leading body colour b1 (the first right singular vector of the ROI's border
    ``colours`` (M, 3)), the weights ``u`` on (o0, o1) with ``u . (1, 1) = 1`` and
    ``u . (b1_o0, b1_o1) = 0`` give S, the second body colour's texture left in (the three
    channels remove both). Why: a red tissue lit near the guides clips its red channel by its
    body reflection alone, where the specular lobe's flanks lie; left out (``missing``), the fit
    lost the flanks nearest the lobe's core (measured: ``docs/decisions/light-aware-recommendation.md``).
    ``neg`` and ``anyc`` lose the pixels given a value. A channel pair whose weights' noise gain
    ``|u|`` exceeds :data:`BODY_PROJECTION_MAX_GAIN` (white too near b1 in it) leaves its pixels
    as they were."""
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
        # at most w . I as measured: the clipped channel's true value is above its clip level
        # and its weight negative, so the three channels' projection bounds S from above
        values[rows] = np.minimum(v[rows] @ u, values[rows])
        neg[rows] = False
        anyc[rows] = False


#: Side of the box (px) whose mean is the smooth part of the image that
#: :func:`_least_fluctuation_weights` takes from each pixel: the shading and the lobes vary over
#: tens of pixels, the albedo's texture (vessels) and the sensor's noise over one to a few.
_FLUCTUATION_BOX = 9
#: Passes of :func:`_least_fluctuation_weights`' trimming of the lobes (as ``_BODY_TRIM_PASSES``).
_FLUCTUATION_PASSES = 4
#: The fewest pixels :func:`_least_fluctuation_weights` measures the fluctuations on.
_FLUCTUATION_MIN_PIXELS = 100


def _least_fluctuation_weights(v, clipped) -> np.ndarray | None:
    """The projection's weights ``w`` (3,) that let through the least of the ROI's fluctuations
    about its smooth part, white kept (``w . (1, 1, 1) = 1``) and the tissue's leading body colour
    removed (``w . a0 = 0``): the linearly constrained minimum-variance weights [7]_
    ``w = R^-1 C (C^T R^-1 C)^-1 (0, 1)``, ``C = [a0, (1, 1, 1)]``.

    R is the 3 x 3 covariance of each pixel's colour minus its :data:`_FLUCTUATION_BOX` box mean:
    the albedo's texture (whose second colour the border's singular values no longer tell from
    the noise) and the sensor's noise together, each as much as it is there. Where the texture
    dominates, w is orthogonal to both body colours (the exact projection of
    :func:`specular_image`); where the noise does (a dark channel at 1 to 3 noise sigmas: the
    endoscope's mucosa at 0.5 % read noise and above), w trades the texture left in against the
    noise gain, which no fixed projection does (measured: ``docs/decisions/light-aware-recommendation.md``).
    ``a0``: the leading
    right singular vector of the box means. Measured on the pixels off the field stop's black
    (a channel above 0 in the whole box) and away from clipped pixels (none in the box), the
    lobes trimmed in passes as :func:`specular_image` trims the border (box means whose
    projected value is above ``_BODY_TRIM_SHARE`` of the peak). None where fewer than
    :data:`_FLUCTUATION_MIN_PIXELS` pixels remain, R or the constraints are singular, or the
    noise gain ``|w|`` is above :data:`BODY_PROJECTION_MAX_GAIN`.

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
    smooth = np.stack([ndi.uniform_filter(v[..., c], k, mode="nearest") for c in range(3)], axis=-1)
    fluct = v - smooth
    use = inside
    one = np.ones(3)
    w = None
    for _ in range(_FLUCTUATION_PASSES):
        if np.count_nonzero(use) < _FLUCTUATION_MIN_PIXELS:
            return None
        a0 = np.linalg.svd(smooth[use], full_matrices=False)[2][0]
        X = fluct[use]
        R = X.T @ X / len(X)
        R = R + 1e-12 * float(np.trace(R)) * np.eye(3)  # a texture-free, noise-free ROI: R ~ 0
        C = np.column_stack([a0, one])
        try:
            RiC = np.linalg.solve(R, C)
            w = RiC @ np.linalg.solve(C.T @ RiC, np.array([0.0, 1.0]))
        except np.linalg.LinAlgError:
            return None
        spec = smooth @ w
        peak = max(float(spec[inside].max()), 0.0)
        new = inside & (spec <= _BODY_TRIM_SHARE * peak)
        if np.array_equal(new, use):
            break
        use = new
    if w is None or not np.isfinite(w).all() or float(np.linalg.norm(w)) > BODY_PROJECTION_MAX_GAIN:
        return None
    return w


def _body_weights(colours) -> np.ndarray | None:
    """The projection's weights ``w`` (3,) from body colours (M, 3) (:func:`specular_image`):
    orthogonal to their two leading right singular vectors, ``w . (1, 1, 1) = 1``, the noise gain
    ``|w|`` within :data:`BODY_PROJECTION_MAX_GAIN`; None where the colours hold no second one
    or the gain is above it."""
    sv, Vt = np.linalg.svd(colours, full_matrices=False)[1:]
    one = np.ones(3)
    # a second body colour only where the colours hold one: its singular value well above the
    # third's (the noise's and what white remains) and above round-off
    if not (sv[1] > _BODY_SECOND_SNR * sv[2] and sv[1] > 1e-9 * sv[0]):
        return None
    B = Vt[:2].T
    P = np.eye(3) - B @ B.T  # the rows of Vt are orthonormal
    den = float(one @ P @ one)
    if not den > 0:
        return None
    w = (P @ one) / den
    return w if float(np.linalg.norm(w)) <= BODY_PROJECTION_MAX_GAIN else None
