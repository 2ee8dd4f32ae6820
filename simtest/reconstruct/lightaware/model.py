"""The image model of a highlight lit by a rig: rays, the rig's lobes on a plane, their derivatives.

Everything here is the forward model (the package docstring's "Model"): the viewing rays of a camera,
the rig's arrays, cos beta of each light on a plane along each ray (:func:`_terms`), the rig's
specular image and its gradient in (a, b, log h, log n) (:func:`_rig_value`, :func:`_rig_grad`),
the specular point's depth and its gradient, and the ROI's pixel grid the fits sample.
"""

from __future__ import annotations

import numpy as np

from simtest._lazy import require
from simtest.decisions import ALBEDO_LINE_PX, ALBEDO_LINE_STEPS, GGX_FILM_IOR
from simtest.geometry.angles import unit
from simtest.geometry.camera import validate_intrinsics
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig


class _Kinv:
    """A validated K's inverse, so that rays are made without validating K each time."""

    def __init__(self, K):
        self.Kinv_T = np.linalg.inv(validate_intrinsics(K)).T


def _camera(camera):
    """``camera`` as given if it has ``pixel_to_ray``, else K (3, 3) validated once."""
    return camera if hasattr(camera, "pixel_to_ray") or isinstance(camera, _Kinv) else _Kinv(camera)


def _rays(camera, uv) -> np.ndarray:
    """Unit viewing rays (N, 3) of pixels (N, 2): ``camera`` is K (3, 3) or has ``pixel_to_ray``."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    camera = _camera(camera)
    if hasattr(camera, "pixel_to_ray"):
        return np.asarray(camera.pixel_to_ray(uv), dtype=np.float64)
    d = np.column_stack([uv, np.ones(len(uv))]) @ camera.Kinv_T
    return d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]


def _rig_arrays(rig: LightRig):
    L = np.array([lt.position_mm for lt in rig.lights], dtype=np.float64).reshape(-1, 3)
    w = np.array([lt.intensity for lt in rig.lights], dtype=np.float64)
    inv_sq = np.array([lt.falloff == "inverse_square" for lt in rig.lights])
    m = np.array([lt.profile_exponent for lt in rig.lights], dtype=np.float64)
    return L, w, inv_sq, m


def _mean_light(rig: LightRig) -> np.ndarray:
    L, w, _, _ = _rig_arrays(rig)
    return (w[:, None] * L).sum(axis=0) / w.sum()


def specular_point_depth(normal, distance_mm: float, light_mm) -> float:
    """Depth (distance from the camera centre) of the specular point of a plane for one light.

    Parameters
    ----------
    normal : array_like of shape (3,)
        Unit plane normal facing the camera, camera frame.
    distance_mm : float
        Plane distance h > 0, mm.
    light_mm : array_like of shape (3,)
        Light position, camera frame, mm.

    Returns
    -------
    float
        ``|X_s|`` with ``X_s = L' h / (-n . L')`` and ``L' = L - 2 (n . L + h) n`` (module
        docstring); NaN if the light is behind the plane.
    """
    n = np.asarray(normal, dtype=np.float64)
    L = np.asarray(light_mm, dtype=np.float64)
    hl = n @ L + distance_mm
    if not hl > 0:
        return float("nan")
    Lm = L - 2.0 * hl * n
    return float(np.linalg.norm(Lm) * distance_mm / (-(n @ Lm)))


def _ray_light(L, dT):
    """``(Ld, K2)``: ``L . d`` and ``|L|^2 - (L . d)^2`` (the light's squared distance from the
    ray's line) per ray, for lights L (3,) or (J, 3) and unit rays ``dT`` (3, N): (N,) or (J, N)."""
    Ld = L @ dT
    LL = (L * L).sum(axis=-1)
    return Ld, np.maximum((LL if np.ndim(LL) == 0 else LL[:, None]) - Ld * Ld, 0.0)


def _terms(dT, n, h, L, rl, P=None, dns=None, ds=None):
    """cos beta of one light on the plane (n, h) along unit rays, and its derivatives.

    The rays are given transposed, ``dT`` (3, N) (each operation then runs along N), with
    ``rl = (Ld, K2)`` of :func:`_ray_light` (they depend on the rays only). Returns
    ``cb (N,)``, the pieces ``delta = -d . n``, ``s = |X|``, ``sl = s - Ld``, ``ir = 1 / r`` with
    ``r = |L - X|`` (each (N,)), ``c = n . L + h``, and, when the normal's derivatives ``dns``
    (two (3,) vectors) are given, ``dcb (3, N)`` with respect to (a, b, log h) (``P = [dn_a,
    dn_b] @ dT`` (2, N) may be given too); else None. ``ds``: the plane's ``(delta, s)`` if at hand.

    Notes
    -----
    The plane point is ``X = s d`` with ``s = h / delta``. Then
    ``r^2 = |L|^2 - 2 s Ld + s^2 = (s - Ld)^2 + K2``, ``n . (L - X) = n . L + s delta = c`` and
    ``(L - X) . d = Ld - s``, so ``cos beta = 2 (n . l)(n . v) - l . v = (2 c delta + Ld - s) / r``
    (package docstring): a few operations per ray, no per-ray vectors. A change (dn, dh) gives
    ``d delta = -d . dn``, ``ds = (dh - s d delta) / delta``, ``dr = ds (s - Ld) / r``,
    ``dc = dn . L + dh`` and ``d cos beta = (2 (dc delta + c d delta) - ds - cb dr) / r``
    ``= (2 (dc delta + c d delta) - q ds) / r`` with ``q = 1 + cb (s - Ld) / r``. For a and b
    (dh = 0, d delta = -P): ``(2 delta dc - P (2 c + q s / delta)) / r``; for log h (dn = 0,
    dh = h, ds = s): ``(2 h delta - q s) / r``.
    """
    Ld, K2 = rl
    delta = np.maximum((-n) @ dT, 1e-9) if ds is None else ds[0]
    s = h / delta if ds is None else ds[1]
    sl = s - Ld
    with np.errstate(over="ignore"):  # a plane seen edge-on (delta at its floor): s^2 overflows, 1 / r = 0
        ir = 1.0 / np.sqrt(np.maximum(sl * sl + K2, 1e-300))
    c = n @ L + h
    cb = (2.0 * c * delta - sl) * ir
    if dns is None:
        return cb, delta, s, sl, ir, c, None
    if P is None:
        P = np.array(dns) @ dT
    qs = (1.0 + cb * sl * ir) * s
    t = 2.0 * delta * ir
    u = (2.0 * c + qs / delta) * ir
    dcb = np.empty((3, dT.shape[1]))
    dcb[0] = t * (dns[0] @ L) - P[0] * u
    dcb[1] = t * (dns[1] @ L) - P[1] * u
    dcb[2] = t * h - qs * ir
    return cb, delta, s, sl, ir, c, dcb


def _normal_derivs(p, n0, e1, e2):
    """Normal ``unit(n0 + a e1 + b e2)`` and its derivatives with respect to a and b."""
    m = n0 + p[0] * e1 + p[1] * e2
    nm = np.sqrt(m @ m)
    n = m / nm
    return n, ((e1 - n * (n @ e1)) / nm, (e2 - n * (n @ e2)) / nm)


#: Below this cos beta a lobe is taken as 0 (``cb^n`` < 1e-200 for n >= 1): its derivative
#: ``n cb^(n-1)`` is then formed without dividing by a denormal.
_CB_FLOOR = 1e-200


def _rig_geometry(dT, rl, n, h, rig_arr) -> list:
    """Per light, the pieces of :func:`_rig_value` that do not depend on the roughness (one
    plane at several roughnesses): ``(cb, cbp, lcb, pos, delta, s, sl, ir, c, cp, raw, f, p)``,
    ``raw`` the profile's cos theta before its floor, ``f`` the falloff ``(h / r)^2`` and ``p`` the
    profile ``cp^m`` (None where the light has none)."""
    L, w, inv_sq, m = rig_arr
    geo = []
    for j in range(len(w)):
        cb, delta, s, sl, ir, c, _ = _terms(dT, n, h, L[j], (rl[0][j], rl[1][j]), ds=geo[0][4:6] if geo else None)
        pos, hir = cb > _CB_FLOOR, h * ir
        cbp = np.where(pos, cb, 1.0)
        raw = (s * dT[2] - L[j, 2]) * ir if m[j] > 0 else None
        cp = None if raw is None else np.maximum(raw, 1e-12)
        geo.append((cb, cbp, np.log(cbp), pos, delta, s, sl, ir, c, cp, raw, hir * hir if inv_sq[j] else None,
                    None if cp is None else cp ** m[j]))
    return geo


def _rig_value(dT, rl, n, h, rig_arr, rough, geo=None):
    """``S = sum_j w_j max(0, cb_j)^n f_j p_j`` (N,) and the per-light pieces its gradient needs.

    ``dT`` (3, N) the unit rays transposed, ``rl`` the :func:`_ray_light` of the rig's lights
    (each (J, N)); ``geo``: :func:`_rig_geometry` if at hand. See :func:`_rig_grad` for the derivatives.
    """
    w = rig_arr[1]
    S = np.zeros(dT.shape[1])
    parts = []
    for j, (cb, cbp, lcb, pos, delta, s, sl, ir, c, cp, raw, f, p) in enumerate(
            _rig_geometry(dT, rl, n, h, rig_arr) if geo is None else geo):
        arg = rough * lcb  # 0 below exp(-708) = 3e-308: exp's slow path for a subnormal takes 4x
        val = np.zeros_like(arg)
        np.exp(arg, out=val, where=pos & (arg > -708.0))
        if f is not None:
            val *= f
        if p is not None:
            val *= p
        if w[j] != 1.0:
            val *= w[j]
        S += val
        parts.append((cb, cbp, lcb, val, delta, s, sl, ir, c, cp, raw, f))
    return S, parts


def _rig_grad(dT, parts, n, dns, h, rig_arr, rough):
    """``dS`` (4, N) of :func:`_rig_value` with respect to (a, b, log h, log n).

    Notes
    -----
    Per light, ``d log(val) = n d cb / cb + d log f + d log p`` with ``f = (h / r)^2``
    (``d log f = 2 dh / h - 2 dr / r``) and ``p = cp^m``, ``cp = (s d_z - L_z) / r``
    (``d log p = m (ds d_z / (r cp) - dr / r)``), and ``d val / d log n = val n log cb``. With
    the derivatives of :func:`_terms` (``dr = ds (s - Ld) / r``, ``ds = s P / delta`` and
    ``d delta = -P`` for a and b, ``ds = s`` for log h) each row is ``val`` times a sum of
    per-ray factors.
    """
    L, w, inv_sq, m = rig_arr
    P = np.array(dns) @ dT
    dS = np.zeros((4, dT.shape[1]))
    for j, (cb, cbp, lcb, val, delta, s, sl, ir, c, cp, *_) in enumerate(parts):
        slr = sl * ir  # dr / ds
        k = (rough * ir) / cbp  # n / (r cb): d log(lobe) = k (2 (dc delta + c d delta) - q ds)
        C = -k * (1.0 + cb * slr)  # coefficient of ds
        if inv_sq[j]:
            C -= (2.0 * slr) * ir
        if cp is not None:
            C += m[j] * ((dT[2] / cp - slr) * ir)
        kv = k * val
        A = (2.0 * delta) * kv  # coefficient of dc, times val
        Cvs = C * val * s
        Bv = Cvs / delta - (2.0 * c) * kv  # coefficient of P, times val
        dS[0] += A * (dns[0] @ L[j]) + P[0] * Bv
        dS[1] += A * (dns[1] @ L[j]) + P[1] * Bv
        dS[2] += A * h + Cvs + (2.0 * val if inv_sq[j] else 0.0)
        dS[3] += (rough * val) * lcb
    return dS


def _rig_image(d, n, dns, h, rig_arr, rough, grad=True):
    """``S = sum_j w_j max(0, cb_j)^n f_j p_j`` (N,) and ``dS`` (N, 4) w.r.t. (a, b, log h, log n).

    ``d`` (N, 3) unit rays.
    """
    dT = np.ascontiguousarray(np.asarray(d, dtype=np.float64).T)
    rl = _ray_light(rig_arr[0], dT)
    S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
    return S, (_rig_grad(dT, parts, n, dns, h, rig_arr, rough).T if grad else None)


def plane_rig_intensity(rays: np.ndarray, normal, distance_mm: float, rig: LightRig,
                        roughness: float) -> np.ndarray:
    """Specular image of a plane lit by a rig, along given rays (unit gain, no background).

    ``sum_j w_j max(0, cos beta_j)^n f_j p_j`` (package docstring), with
    ``f_j = (h / |L_j - X|)^2`` for inverse-square lights and ``p_j = max(0, cos theta_j)^m_j``.

    Parameters
    ----------
    rays : ndarray of shape (N, 3)
        Unit viewing rays, camera frame.
    normal : array_like of shape (3,)
        Unit plane normal facing the camera.
    distance_mm : float
        Plane distance h > 0, mm.
    rig : LightRig
        The lights.
    roughness : float
        Phong n > 0.

    Returns
    -------
    ndarray of shape (N,)
        Intensity; 0 for rays that miss the plane.
    """
    dT = np.ascontiguousarray(np.asarray(rays, dtype=np.float64).T)
    n, rig_arr = unit(np.asarray(normal, dtype=np.float64)), _rig_arrays(rig)
    S = _rig_value(dT, _ray_light(rig_arr[0], dT), n, float(distance_mm), rig_arr, float(roughness))[0]
    return np.where(-(n @ dT) > 1e-9, S, 0.0)


def _distance_for_bp(ray: np.ndarray, n: np.ndarray, L: np.ndarray) -> float | None:
    """Plane distance h for which a plane of normal n has its specular point on the BP ray.

    The specular point is ``X_s ∝ L' = L0 - 2 h n`` with ``L0 = L - 2 (n . L) n`` (the mirror image
    of L in the plane through the camera centre), so it lies on the ray b when L' is parallel to b:
    with ``P = I - b b^T``, ``h = (P L0) . (P n) / (2 |P n|^2)`` (least squares on the component
    of L' across the ray). None if the result is not > 0 (then no such plane faces the light).
    """
    L0 = L - 2.0 * (n @ L) * n
    pn = n - (ray @ n) * ray  # P n
    den = 2.0 * (pn @ pn)
    if not den > 1e-18:
        return None
    h = float((L0 - (ray @ L0) * ray) @ pn / den)
    return h if h > 0 else None


def _log_depth_gradient(n, h, Lm, basis=None) -> np.ndarray:
    """d log(depth) / d(a, b, log h) about (n, h), the tangent basis of :func:`plane_basis` (3,).

    ``basis``: that basis (e1, e2) when already at hand.

    Notes
    -----
    With ``k = n . L + h`` (> 0: the light in front of the plane), the mirror image is
    ``L' = L - 2 k n``, so ``-n . L' = k + h`` and ``|L'|^2 = |L|^2 + 4 k h``, and the depth of
    :func:`specular_point_depth` is ``D = h sqrt(|L|^2 + 4 k h) / (k + h)``. About n the normal
    moves by ``dn = e1 da + e2 db`` (n unit, e1 and e2 orthogonal to it), so
    ``d log D / da = (e1 . L) (2 h / (|L|^2 + 4 k h) - 1 / (k + h))`` (and e2 for b), and with
    ``dh = dk = h d log h``: ``d log D / d log h = 1 + 2 h (h + k) / (|L|^2 + 4 k h) - 2 h / (k + h)``.
    NaN with the light behind the plane.
    """
    e1, e2 = plane_basis(n) if basis is None else basis
    k = float(n @ Lm) + h
    if not k > 0:
        return np.full(3, np.nan)
    q = float(Lm @ Lm) + 4.0 * k * h
    ga = 2.0 * h / q - 1.0 / (k + h)
    return np.array([float(e1 @ Lm) * ga, float(e2 @ Lm) * ga,
                     1.0 + 2.0 * h * (h + k) / q - 2.0 * h / (k + h)])


def _roi_samples(vals, o, uu, vv, keep, max_pixels):
    """The ROI pixels a photometric fit uses: every kept pixel, or a regular sub-grid of them.

    Returns ``(sel, step, uv, y)``: flat indices of the used pixels, the sub-grid step (1: every
    pixel), their (u, v) image positions (N, 2) in pixels and their values (N,).
    """
    sel = np.flatnonzero(keep)
    step = 1
    if max_pixels and len(sel) > max_pixels:  # a regular sub-grid of the ROI
        step = int(np.ceil(np.sqrt(len(sel) / max_pixels)))
        grid = np.zeros_like(keep)
        grid[::step, ::step] = True
        sel = np.flatnonzero(keep & grid)
    uv = np.column_stack([uu.ravel()[sel] + o[0], vv.ravel()[sel] + o[1]]).astype(np.float64)
    y = vals.ravel()[sel]
    return sel, step, uv, y


def albedo_lines(luma_roi, step: float = 1.0, noise: float = 0.0) -> np.ndarray:
    """The pixels of the tissue albedo's thin dark lines (vessels) in an ROI of a frame's luma.

    The wet film reflects the light above the tissue, so its lobe is smooth, its level sets
    discs or ellipses, with no dark line of its own; the vessels darken the diffuse shading
    beneath it in lines a few pixels wide. Where a fit cannot project the tissue's body colours
    out (a JPEG frame's chroma, subsampled and quantised: the darkest channel's fit), those lines
    are left out of it: the pixels whose black top-hat (the closing by a disc of
    :data:`ALBEDO_LINE_PX` px, minus the image) is at least ``max(ALBEDO_LINE_STEPS * step, 3 *
    noise)``, grown by one pixel (the line's blurred edge), none within the disc's radius of the
    ROI's border (where the closing sees past the ROI). A lone lobe is its own closing (flat
    morphology commutes with thresholds, and a convex level set is closed under a disc), so it
    loses nothing (``test_a_lone_lobe_holds_no_albedo_line``: 8-bit elliptical Gaussians 2 to
    40 px wide); the saddle between two lobes nearer than the disc's width is taken for a line.

    Parameters
    ----------
    luma_roi : ndarray of shape (H, W)
        The ROI's luma in the frame's units (e.g. 0 to 255).
    step : float
        The frame's quantisation step in those units (1 for an integer frame).
    noise : float
        The frame's noise sigma in those units.

    Returns
    -------
    ndarray of shape (H, W), bool
        True on the lines.
    """
    ndi = require("scipy.ndimage")  # when first needed: scipy slows the start
    v = np.asarray(luma_roi, dtype=np.float32)
    lines = np.zeros(v.shape[:2], bool)
    h = ALBEDO_LINE_PX // 2
    if v.ndim != 2 or min(v.shape) <= 2 * h:
        return lines
    yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
    disc = xx * xx + yy * yy <= h * h + 0.5
    top_hat = ndi.grey_closing(v, footprint=disc, mode="nearest") - v
    lines[h:-h, h:-h] = top_hat[h:-h, h:-h] >= max(ALBEDO_LINE_STEPS * float(step), 3.0 * float(noise))
    return ndi.maximum_filter(lines, size=3, mode="nearest")


def _roi_grid(values, camera, origin_uv, clip_level):
    """The ROI of a photometric fit: checked values, camera model, origin, pixel grid, unclipped mask.

    Returns ``vals`` (H, W) float64, the camera model, ``o`` (2,) the ROI's top-left pixel (u, v),
    ``uu, vv`` (H, W) the column and row indices, and ``keep`` (H, W) bool (``vals < clip_level``,
    all True without a clip level).

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite.
    """
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim != 2 or not np.isfinite(vals).all():
        raise ValueError(f"values: need a finite (H, W) array, got shape {vals.shape}")
    camera = _camera(camera)
    H, W = vals.shape
    o = np.asarray(origin_uv, dtype=np.float64).reshape(2)
    vv, uu = np.mgrid[0:H, 0:W]
    keep = np.ones((H, W), bool) if clip_level is None else vals < clip_level
    return vals, camera, o, uu, vv, keep


def _rig_diffuse(dT, rl, n, h, rig_arr, terms=None, keep=None) -> np.ndarray:
    """The rig's Lambertian shading of the plane (n, h) along unit rays ``dT`` (3, N): (N,).

    ``D = sum_j w_j max(0, n . l_j) f_j p_j`` with ``l_j`` the unit direction from the plane point
    to light j, ``f_j = (h / r_j)^2`` for an inverse-square light (1 otherwise) and ``p_j`` its
    ``cos^m`` profile about +z, the same falloff and profile as the specular lobes of
    :func:`_rig_value` (unit albedo; the fit's linear part scales it). From the pieces of
    :func:`_terms`: ``n . (L - X) = c`` so ``n . l = c / r``; ``terms``: each light's ``_terms[:6]``
    if at hand (and :func:`_rig_geometry`'s ``raw, f``); ``keep``: a list given each light's term
    of D and ``cos theta`` (or None).
    """
    L, w, inv_sq, m = rig_arr
    terms = [_terms(dT, n, h, L_, (rl[0][j], rl[1][j]))[:6] for j, L_ in enumerate(L)] if terms is None else terms
    D = np.zeros(dT.shape[1])
    for j in range(len(w)):
        _, _, s, _, ir, c, *pre = terms[j]
        cp, f = pre or ((s * dT[2] - L[j, 2]) * ir if m[j] > 0 else None, (h * ir) * (h * ir) if inv_sq[j] else None)
        val = max(c, 0.0) * ir if f is None else max(c, 0.0) * ir * f
        val = w[j] * (val if cp is None else val * np.maximum(cp, 0.0) ** m[j])
        D += val
        if keep is not None:
            keep.append((val, cp))
    return D


def _rig_diffuse_grad(dT, rl, p, nb, e1, e2, rig_arr, at=None) -> np.ndarray:
    """The derivatives of :func:`_rig_diffuse` in (a, b, log h) about ``p`` (the plane
    ``unit(nb + a e1 + b e2)`` at ``h = exp(p[2])``): (3, N); ``at``: its ``(n, dns, terms)`` if at hand,
    or ``(n, dns, terms, keep)`` with the shading's ``keep`` list.

    Notes
    -----
    Per light, ``val = w c / r (h / r)^2 cp^m`` (the falloff's factor for an inverse-square light
    only) with ``c = n . L + h`` one number per plane, so
    ``d log val = dc / c - (1 + 2) dr / r + 2 dh / h + m (ds d_z / (r cp) - dr / r)``, and with the
    pieces of :func:`_terms`: ``dr / r = ds (s - Ld) / r^2``, ``ds = s P / delta`` for a and b
    (``P = dn . d``, ``dc = dn . L``) and ``ds = s`` for log h (``dc = dh = h``).
    """
    L, w, inv_sq, m = rig_arr
    h = float(np.exp(p[2]))
    if at is None:
        n, dns = _normal_derivs(np.asarray(p, dtype=np.float64), nb, e1, e2)
        at = (n, dns, [_terms(dT, n, h, L_, (rl[0][j], rl[1][j]))[:6] for j, L_ in enumerate(L)])
    n, dns, terms, keep = at if len(at) == 4 else (*at, [])
    if not keep:
        _rig_diffuse(dT, rl, n, h, rig_arr, terms, keep)
    P = np.array(dns) @ dT
    out = np.zeros((3, dT.shape[1]))
    for j in range(len(w)):
        _, delta, s, sl, ir, c, *_ = terms[j]
        if not c > 0:
            continue  # the light behind the plane: no shading, none to change (max(c, 0))
        val, cp = keep[j]  # (val: the light's term of the shading)
        k = (3.0 if inv_sq[j] else 1.0) + max(m[j], 0.0)  # dr / r's coefficient in d log val
        zc = m[j] * dT[2] * ir / np.where(cp > 0, cp, 1.0) if m[j] > 0 else 0.0  # d log p per ds, and -m dr / r
        per_ds = -k * (sl * ir * ir) + zc  # d log val per ds (sl / r^2: dr / r per ds)
        sd = s / delta
        for i in range(2):
            out[i] += val * (float(dns[i] @ L[j]) / c + per_ds * sd * P[i])
        out[2] += val * (h / c + per_ds * s + (2.0 if inv_sq[j] else 0.0))
    return out


def _curvature_columns(dT, rl, n, h, rig_arr, rough, apex) -> np.ndarray:
    """The derivatives (3, N) of the rig's Phong image of a curved patch in its three curvatures,
    at zero curvature: the patch the plane (n, h), bent about ``apex`` (a point of the plane, the
    tangent basis t1, t2 of :func:`plane_basis`) as the quadric patch of
    :func:`~simtest.reconstruct.lightaware.patch.quadric_fit` is
    (``z + (k_xx x^2 + 2 k_xy x y + k_yy y^2) / 2 = 0``), each up to a constant factor.

    Notes
    -----
    To first order in the curvatures a pixel's surface point moves along its ray by
    ``ds = q / (2 delta)`` (``q = k_xx x^2 + 2 k_xy x y + k_yy y^2``, (x, y) the plane point's
    coordinates about the apex, ``delta = -n . d``) and its normal tilts by
    ``dn = (k_xx x + k_xy y) t1 + (k_xy x + k_yy y) t2``. With the point held,
    ``d cos beta = 2 delta (dn . l) - 2 (n . l) (dn . d)`` (``cos beta = 2 (n . l)(n . v) - l . v``,
    v = -d); with the normal held, ``d cos beta / ds = (2 delta^2 - 1 - cos beta (s - Ld) / r) / r``
    (:func:`_terms`' pieces, ``n . (L - X)`` growing by ``delta ds``), and the falloff and
    profile change with ds as in :func:`_rig_grad`. Columns k_xx, k_xy, k_yy.
    """
    L, w, inv_sq, m = rig_arr
    t1, t2 = plane_basis(n)
    A1, A2 = t1 @ dT, t2 @ dT
    out = np.zeros((3, dT.shape[1]))
    S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
    for j, (cb, cbp, lcb, val, delta, s, sl, ir, c, cp, *_) in enumerate(parts):
        x = s * A1 - float(apex @ t1)
        y = s * A2 - float(apex @ t2)
        k = rough / cbp
        slr2 = sl * ir * ir
        g_ds = k * ir * (2.0 * delta * delta - 1.0 - cb * sl * ir)  # d log val per ds
        if inv_sq[j]:
            g_ds = g_ds - 2.0 * slr2
        if cp is not None:
            g_ds = g_ds + m[j] * (dT[2] * ir / cp - slr2)
        tL1, tL2 = float(t1 @ L[j]), float(t2 @ L[j])
        for i, (al, be, ds) in enumerate(((x, 0.0, 0.5 * x * x / delta),
                                          (y, x, x * y / delta),
                                          (0.0, y, 0.5 * y * y / delta))):
            dnd = al * A1 + be * A2
            dcb = 2.0 * delta * (al * tL1 + be * tL2 - s * dnd) * ir - 2.0 * c * ir * dnd
            out[i] += val * (k * dcb + g_ds * ds)
    return out


def _fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric interface (exact), ``cos_i`` in [0, 1]."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def _rig_value_ggx(dT, rl, n, h, rig_arr, alpha, ior: float = GGX_FILM_IOR, parts=None):
    """The rig's GGX lobes under a dielectric film on the plane (n, h) along unit rays ``dT`` (3, N).

    ``S = sum_j w_j F(v . m) D(m) G1(v) G1(l_j) / (4 n . v) f_j p_j``: the radiance of the
    renderer's wet film (:func:`simtest.render.tissue.specular_lobe`, ``lobe = "ggx"``: Walter et
    al. 2007, eqs. 25-34, with Smith's G) lit by each light, its BRDF times ``n . l`` times the
    light's falloff ``f_j = (h / r_j)^2`` and profile ``p_j`` (as :func:`_rig_value`'s), for the
    half-vector ``m = unit(v + l_j)``, v the direction to the camera. From the pieces of
    :func:`_terms`: ``n . v = delta``, ``n . l = c / r``, ``v . l = (s - Ld) / r``, so
    ``n . m = (delta + c / r) / sqrt(2 + 2 v . l)`` and ``v . m = sqrt((1 + v . l) / 2)``.
    ``parts``: a list given each light's pieces, for :func:`_rig_grad_ggx`.

    Returns
    -------
    ndarray of shape (N,)
        0 where the light or the camera is below the plane.
    """
    return _ggx_sum(dT, rl, n, h, rig_arr, alpha, ior, _ggx_lobe, parts)


def _ggx_lobe(delta, s, sl, ir, c, a2, ior, F=None):
    """One light's film lobe along the rays, before falloff and profile (Walter et al. 2007,
    eqs. 25-34, doi:10.2312/EGWR/EGSR07/195-206, with Smith's G1 and the exact dielectric Fresnel
    factor): ``F(v . m) D(m) G1(v) G1(l) / (4 n . v)``, 0 where the light or the camera is below
    the plane. ``delta, s, sl, ir`` (N,) and ``c`` are :func:`_terms`' pieces; ``F`` Fresnel's
    factor (:func:`_fresnel_of_vl`) if at hand."""
    cos_o = c * ir
    vl = sl * ir
    hv = np.sqrt(np.maximum(2.0 + 2.0 * vl, 1e-300))
    cos_h = np.clip((delta + cos_o) / hv, 1e-6, 1.0)
    c2 = cos_h * cos_h
    with np.errstate(over="ignore", invalid="ignore"):  # a trial alpha run off: D 0 or NaN, which the fit rejects
        D = a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)
    ci = np.maximum(delta, 1e-6)
    co = np.maximum(cos_o, 1e-6)
    g1i = 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - ci * ci) / (ci * ci)))
    g1o = 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - co * co) / (co * co)))
    F = _fresnel_of_vl(vl, ior) if F is None else F
    val = F * D * g1i * g1o / (4.0 * ci)
    val[(cos_o <= 0.0) | (delta <= 1e-9)] = 0.0
    return val


def _ggx_sum(dT, rl, n, h, rig_arr, alpha, ior, lobe, parts=None):
    """The sum over the rig's lights of ``lobe``'s values times each light's falloff and
    profile (:func:`_rig_value_ggx`; ``parts`` its list of each light's pieces)."""
    L, w, inv_sq, m = rig_arr
    # a product, not ``** 2``: a fit's trial roughness that runs off (a lobe broader than the
    # ROI) overflows to inf, which the fits reject as a non-finite model, where ``** 2`` raises
    a2 = float(alpha) * float(alpha)
    S = np.zeros(dT.shape[1])
    for j in range(len(w)):
        _, delta, s, sl, ir, c, _ = _terms(dT, n, h, L[j], (rl[0][j], rl[1][j]))
        cp = np.maximum((s * dT[2] - L[j, 2]) * ir, 1e-12) if m[j] > 0 else None
        F = _fresnel_of_vl(sl * ir, ior)
        val = lobe(delta, s, sl, ir, c, a2, ior, F)
        scaled = w[j] * _lobe_scale(val, h, ir, inv_sq[j], cp, m[j])
        S += scaled
        if parts is not None:
            parts.append((delta, s, sl, ir, c, val, F, scaled))
    return S


def _fresnel_of_vl(vl, ior):
    """Fresnel's reflectance at the half-vector, ``F(v . m)`` with ``v . m = sqrt((1 + v . l) / 2)``,
    as :func:`_ggx_lobe` forms it from ``vl = v . l``."""
    return _fresnel_dielectric(np.sqrt(np.clip(0.5 * (1.0 + vl), 0.0, 1.0)), ior)


#: Step in ``v . l`` of :func:`_rig_grad_ggx`'s central difference of Fresnel's factor (a smooth
#: function of one variable: its error is near 1e-14, far below the fit's resolution).
_FRESNEL_STEP = 1e-6


def _rig_grad_ggx(dT, rl, n, dns, h, rig_arr, alpha, ior: float = GGX_FILM_IOR, parts=None) -> np.ndarray:
    """``dS`` (4, N) of :func:`_rig_value_ggx` in (a, b, log h, log alpha); ``parts``: its ``parts`` if at hand.

    Notes
    -----
    Per light, ``log val = log F + log D + log G1(v) + log G1(l) - log(4 n . v) + log f + log p``
    (the film lobe of :func:`_rig_value_ggx`, falloff ``f = (h / r)^2``, profile ``p = cp^m``), so
    ``d val = val (sum of the terms' logarithmic derivatives)``. The pieces, from :func:`_terms`'
    (``d delta = -P``, ``ds = s P / delta`` for a and b; ``ds = s``, ``dc = h`` for log h;
    ``dc = dn . L`` for a and b): ``d r^-1 = -r^-3 (s - Ld) ds``, ``d cos_o = dc / r + c d r^-1``
    (``cos_o = n . l``), ``d vl = ds / r + (s - Ld) d r^-1`` (``vl = v . l``), the half-vector's
    ``cos_h = (delta + cos_o) / sqrt(2 + 2 vl)``; GGX's ``d log D / d cos_h = -4 (a2 - 1) cos_h / t``
    with ``t = cos_h^2 (a2 - 1) + 1`` and ``d log D / d a2 = 1 / a2 - 2 cos_h^2 / t``; Smith's
    ``G1(x) = 2 / (1 + u)``, ``u = sqrt(1 + a2 (1 / x^2 - 1))``: ``d log G1 / d x = a2 / ((1 + u)
    u x^3)`` and ``d log G1 / d a2 = -(1 / x^2 - 1) / (2 u (1 + u))`` (Walter et al. 2007, eqs.
    33-34, doi:10.2312/EGWR/EGSR07/195-206); ``d a2 / d log alpha = 2 a2``. Fresnel's factor, a
    function of ``vl`` alone, is differentiated by a central difference
    (:data:`_FRESNEL_STEP`). Where a floor or clip of the lobe's pieces holds (cos_h at 1e-6 or
    1, ``n . v`` or ``n . l`` at 1e-6, ``cp`` at 1e-12) its derivative is 0, as the value's.
    ``tests/test_lightaware_ggx.py`` holds it to central differences of the value.
    """
    L, w, inv_sq, m = rig_arr
    a2 = float(alpha) * float(alpha)
    am1 = a2 - 1.0
    # dn . d per ray, term by term (no BLAS call: the same bits on any number of threads)
    P = [dn[0] * dT[0] + dn[1] * dT[1] + dn[2] * dT[2] for dn in dns]
    dS = np.zeros((4, dT.shape[1]))
    if parts is None:
        parts = []
        _ggx_sum(dT, rl, n, h, rig_arr, alpha, ior, _ggx_lobe, parts)
    for j in range(len(w)):
        delta, s, sl, ir, c, val, F, scaled = parts[j]  # (scaled: this light's term of S)
        cos_o = c * ir
        vl = sl * ir
        hv2 = np.maximum(2.0 + 2.0 * vl, 1e-300)
        hv = np.sqrt(hv2)
        q = delta + cos_o
        raw = q / hv
        cos_h = np.clip(raw, 1e-6, 1.0)
        free_h = (raw > 1e-6) & (raw < 1.0)
        t = cos_h * cos_h * am1 + 1.0
        ci = np.maximum(delta, 1e-6)
        co = np.maximum(cos_o, 1e-6)
        ui = np.sqrt(1.0 + a2 * (1.0 - ci * ci) / (ci * ci))
        uo = np.sqrt(1.0 + a2 * (1.0 - co * co) / (co * co))
        dF = (_fresnel_of_vl(vl + _FRESNEL_STEP, ior) - _fresnel_of_vl(vl - _FRESNEL_STEP, ior)) \
            / (2.0 * _FRESNEL_STEP)
        with np.errstate(divide="ignore", invalid="ignore"):
            dlogF = np.where(F > 0.0, dF / F, 0.0)
        # logarithmic derivatives in the pieces
        kD = np.where(free_h, -4.0 * am1 * cos_h / t, 0.0)  # d log D / d cos_h
        # d log G1(v) / d delta, and d log (1 / (4 n . v)) / d delta = -1 / delta
        kGi = np.where(delta > 1e-6, a2 / ((1.0 + ui) * ui * ci ** 3) - 1.0 / ci, 0.0)
        kGo = np.where(cos_o > 1e-6, a2 / ((1.0 + uo) * uo * co ** 3), 0.0)  # d log G1(l) / d cos_o
        irs, sz, f2 = -(ir ** 3) * sl, s * dT[2] - L[j, 2], 2.0 * (ir * ir) * sl  # (per ds, sz * ir: cos theta)
        raw_cp = sz * ir
        cp, live = (np.maximum(raw_cp, 1e-12), raw_cp > 1e-12) if m[j] > 0 else (None, None)
        for k in range(3):
            if k < 2:
                dd, ds, dc = -P[k], s * P[k] / delta, float(dns[k] @ L[j])
            else:
                dd, ds, dc = 0.0, s, h
            dir_ = irs * ds
            dco = dc * ir + c * dir_
            dvl = ds * ir + sl * dir_
            dhv = dvl / hv
            dch = (dd + dco) / hv - q * dhv / hv2
            g = kD * dch + kGi * dd + kGo * dco + dlogF * dvl
            if inv_sq[j]:
                # d log f = 2 d log h + 2 d log r^-1, d log r^-1 = -r^-2 (s - Ld) ds
                g = g - f2 * ds + (2.0 if k == 2 else 0.0)
            if cp is not None:
                dcp = ds * dT[2] * ir + sz * dir_
                g = g + np.where(live, m[j] * dcp / cp, 0.0)
            dS[k] += scaled * g
        # log alpha: through a2 in D and both G1, times d a2 / d log alpha = 2 a2 (written out,
        # so that an alpha run off to 0 gives 0, not a division by it)
        gi = -(1.0 / (ci * ci) - 1.0) / (2.0 * ui * (1.0 + ui))
        go = -(1.0 / (co * co) - 1.0) / (2.0 * uo * (1.0 + uo))
        dS[3] += scaled * (2.0 - 4.0 * a2 * cos_h * cos_h / t + 2.0 * a2 * (gi + go))
    return dS


def _lobe_scale(val, h, ir, inv_sq, cp, m) -> np.ndarray:
    """One light's lobe ``val`` times its falloff ``(h / r)^2`` (``inv_sq``) and profile ``cp^m``
    (``cp`` None: none): the term :func:`_ggx_sum` adds, before the light's weight."""
    out = val
    if inv_sq:
        hir = h * ir
        out = out * (hir * hir)
    if cp is not None:
        out = out * cp ** m
    return out


def ggx_alpha_of_phong(n: float) -> float:
    """The GGX roughness alpha whose lobe's peak curvature matches a Phong lobe of exponent n:
    ``alpha = sqrt(2 / (n + 2))`` (Walter et al. 2007, section 5.2, Beckmann's)."""
    return float(np.sqrt(2.0 / (max(float(n), 0.0) + 2.0)))


def phong_of_ggx_alpha(alpha: float) -> float:
    """The Phong exponent of :func:`ggx_alpha_of_phong`'s correspondence, ``2 / alpha^2 - 2``
    (-2 for an alpha whose square overflows: a fit's iterate run off)."""
    with np.errstate(over="ignore"):
        return float(2.0 / max(np.float64(alpha) ** 2, 1e-300) - 2.0)
