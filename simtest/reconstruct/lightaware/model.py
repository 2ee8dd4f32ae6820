"""The forward model of a highlight lit by a rig (package docstring, "Model").

Viewing rays, the rig's arrays, cos beta of each light on a plane, the rig's Phong, Blinn and GGX images
and their gradients in (a, b, log h, log n), the diffuse shading, the specular point's depth and
the ROI's pixel grid the fits sample.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest.decisions import ALBEDO_LINE_PX, ALBEDO_LINE_STEPS, GGX_FILM_IOR
from simtest.geometry.angles import unit
from simtest.geometry.camera import validate_intrinsics
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.specular.fresnel import fresnel_dielectric


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
    """``(L . d, |L|^2 - (L . d)^2)`` per ray for lights L (3,) or (J, 3), unit rays ``dT`` (3, N)."""
    Ld = L @ dT
    LL = (L * L).sum(axis=-1)
    return Ld, np.maximum((LL if np.ndim(LL) == 0 else LL[:, None]) - Ld * Ld, 0.0)


def _terms(dT, n, h, L, rl, dns=None, ds=None):
    """cos beta of one light on the plane (n, h) along unit rays ``dT`` (3, N), and its derivatives.

    ``rl = (Ld, K2)`` of :func:`_ray_light`. Returns ``(cb, delta, s, sl, ir, c, dcb)``: ``delta = -d . n``,
    ``s = |X| = h / delta``, ``sl = s - Ld``, ``ir = 1 / |L - X|``, ``c = n . L + h``,
    ``cb = (2 c delta - sl) ir`` and, given the normal's derivatives ``dns``, ``dcb`` (3, N) in
    (a, b, log h) (else None); ``ds = (delta, s)`` may be passed if at hand.
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
    """Normal ``unit(n0 + a e1 + b e2)`` and its derivatives in a and b."""
    m = n0 + p[0] * e1 + p[1] * e2
    nm = np.sqrt(m @ m)
    n = m / nm
    return n, ((e1 - n * (n @ e1)) / nm, (e2 - n * (n @ e2)) / nm)


#: Below this cos beta a lobe is taken as 0, so its derivative never divides by a denormal.
_CB_FLOOR = 1e-200


#: Blinn's exponent per Phong exponent of the same lobe near its peak: the mirror angle is twice the
#: half-vector's, ``cos(2 theta)^n ~ exp(-2 n theta^2) ~ cos(theta)^(4 n)`` (Blinn 1977, SIGGRAPH 11(2)).
BLINN_PER_PHONG = 4.0


def _blinn_cos(delta, sl, ir, c):
    """``n . H`` of one light, ``H = unit(l + v)``: ``n . l = c / r``, ``n . v = delta``, ``l . v = sl / r``
    (:func:`_terms`' pieces); 0 where the light is behind the plane."""
    with np.errstate(invalid="ignore", divide="ignore"):
        nh = (c * ir + delta) / np.sqrt(np.maximum(2.0 * (1.0 + sl * ir), 1e-300))
    return np.where(c > 0, nh, 0.0)


def _rig_geometry(dT, rl, n, h, rig_arr, blinn: bool = False) -> list:
    """Per light, the roughness-free pieces of :func:`_rig_value`:
    ``(cb, cbp, lcb, pos, delta, s, sl, ir, c, cp, raw, f, p)`` (f falloff, p profile; None where absent).
    ``blinn``: ``cb`` is the half vector's ``n . H`` (:func:`_blinn_cos`), not the mirror direction's."""
    L, w, inv_sq, m = rig_arr
    geo = []
    for j in range(len(w)):
        cb, delta, s, sl, ir, c, _ = _terms(dT, n, h, L[j], (rl[0][j], rl[1][j]), ds=geo[0][4:6] if geo else None)
        if blinn:
            cb = _blinn_cos(delta, sl, ir, c)
        pos, hir = cb > _CB_FLOOR, h * ir
        cbp = np.where(pos, cb, 1.0)
        raw = (s * dT[2] - L[j, 2]) * ir if m[j] > 0 else None
        cp = None if raw is None else np.maximum(raw, 1e-12)
        geo.append((cb, cbp, np.log(cbp), pos, delta, s, sl, ir, c, cp, raw, hir * hir if inv_sq[j] else None,
                    None if cp is None else cp ** m[j]))
    return geo


def _rig_value(dT, rl, n, h, rig_arr, rough, geo=None, blinn: bool = False):
    """``S = sum_j w_j max(0, cb_j)^n f_j p_j`` (N,) and the per-light pieces :func:`_rig_grad` needs. ``dT`` (3, N)
    unit rays transposed, ``rl`` the rig's :func:`_ray_light`; ``geo``: :func:`_rig_geometry` if at hand;
    ``blinn``: Blinn's lobe ``(n . H)^n`` (:func:`_blinn_cos`), else Phong's."""
    w = rig_arr[1]
    S = np.zeros(dT.shape[1])
    parts = []
    for j, (cb, cbp, lcb, pos, delta, s, sl, ir, c, cp, raw, f, p) in enumerate(
            _rig_geometry(dT, rl, n, h, rig_arr, blinn) if geo is None else geo):
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


def _rig_grad(dT, parts, dns, h, rig_arr, rough, blinn: bool = False):
    """``dS`` (4, N) of :func:`_rig_value` in (a, b, log h, log n). Per light
    ``d log val = n d cb / cb + d log f + d log p``, with the derivatives of :func:`_terms`; ``blinn``: of
    :func:`_blinn_cos`, ``d log(n . H) = (dc / r + c d(1/r) + d delta) / (c / r + delta) - d(sl / r) / (2 (1 + sl / r))``
    (``d(1/r) = -(sl / r^3) ds``)."""
    L, w, inv_sq, m = rig_arr
    P = np.array(dns) @ dT
    dS = np.zeros((4, dT.shape[1]))
    for j, (cb, cbp, lcb, val, delta, s, sl, ir, c, cp, *_) in enumerate(parts):
        slr = sl * ir  # dr / ds
        if blinn:  # d log(lobe) in dc, d delta and ds (val is 0 where cb is)
            a_ = np.where(val > 0, c * ir + delta, 1.0)
            A, D = ((rough * ir) / a_) * val, (rough / a_) * val  # coefficients of dc and d delta, times val
            C = -rough * ir * ((c * ir * slr) / a_ + 0.5 * (1.0 - slr))  # coefficient of ds
        else:
            k = (rough * ir) / cbp  # n / (r cb): d log(lobe) = k (2 (dc delta + c d delta) - q ds)
            C = -k * (1.0 + cb * slr)  # coefficient of ds
            kv = k * val
            A, D = (2.0 * delta) * kv, (2.0 * c) * kv  # coefficients of dc and d delta, times val
        if inv_sq[j]:
            C -= (2.0 * slr) * ir
        if cp is not None:
            C += m[j] * ((dT[2] / cp - slr) * ir)
        Cvs = C * val * s
        Bv = Cvs / delta - D  # coefficient of P (d delta = -P), times val
        dS[0] += A * (dns[0] @ L[j]) + P[0] * Bv
        dS[1] += A * (dns[1] @ L[j]) + P[1] * Bv
        dS[2] += A * h + Cvs + (2.0 * val if inv_sq[j] else 0.0)
        dS[3] += (rough * val) * lcb
    return dS


def _rig_image(d, n, dns, h, rig_arr, rough, grad=True):
    """``S`` (N,) of the rig's Phong image along unit rays ``d`` (N, 3), and ``dS`` (N, 4) in (a, b, log h, log n)."""
    dT = np.ascontiguousarray(np.asarray(d, dtype=np.float64).T)
    rl = _ray_light(rig_arr[0], dT)
    S, parts = _rig_value(dT, rl, n, h, rig_arr, rough)
    return S, (_rig_grad(dT, parts, dns, h, rig_arr, rough).T if grad else None)


def plane_rig_intensity(rays: np.ndarray, normal, distance_mm: float, rig: LightRig, roughness: float) -> np.ndarray:
    """Specular image of a plane lit by a rig, along given rays (unit gain, no background).

    ``sum_j w_j max(0, cos beta_j)^n f_j p_j`` (package docstring).

    Parameters
    ----------
    rays : ndarray of shape (N, 3)
        Unit viewing rays, camera frame.
    normal, distance_mm
        As in :func:`specular_point_depth`.
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
    """Plane distance h at which the plane of normal n has its specular point on the BP ray. Least squares on the
    component of ``L' = L0 - 2 h n`` across the ray (``L0`` the mirror image of L in the plane through the camera
    centre). None if not > 0."""
    L0 = L - 2.0 * (n @ L) * n
    pn = n - (ray @ n) * ray  # P n
    den = 2.0 * (pn @ pn)
    if not den > 1e-18:
        return None
    h = float((L0 - (ray @ L0) * ray) @ pn / den)
    return h if h > 0 else None


def _log_depth_gradient(n, h, Lm, basis=None) -> np.ndarray:
    """d log(depth) / d(a, b, log h) about (n, h) in the tangent basis of :func:`plane_basis` (3,). From
    ``D = h sqrt(|L|^2 + 4 k h) / (k + h)``, ``k = n . L + h``; NaN with the light behind the plane."""
    e1, e2 = plane_basis(n) if basis is None else basis
    k = float(n @ Lm) + h
    if not k > 0:
        return np.full(3, np.nan)
    q = float(Lm @ Lm) + 4.0 * k * h
    ga = 2.0 * h / q - 1.0 / (k + h)
    return np.array([float(e1 @ Lm) * ga, float(e2 @ Lm) * ga, 1.0 + 2.0 * h * (h + k) / q - 2.0 * h / (k + h)])


def _roi_samples(vals, o, uu, vv, keep, max_pixels):
    """The ROI pixels a photometric fit uses: every kept pixel, or a regular sub-grid of them. Returns
    ``(sel, step, uv, y)``: flat indices, sub-grid step, (u, v) positions (N, 2), values (N,)."""
    sel = np.flatnonzero(keep)
    step = 1
    if max_pixels and len(sel) > max_pixels:  # a regular sub-grid of the ROI
        step = int(np.ceil(np.sqrt(len(sel) / max_pixels)))
        grid = np.zeros_like(keep)
        grid[::step, ::step] = True
        sel = np.flatnonzero(keep & grid)
    uv = np.column_stack([uu.ravel()[sel] + o[0], vv.ravel()[sel] + o[1]]).astype(np.float64)
    return sel, step, uv, vals.ravel()[sel]


def albedo_lines(luma_roi, step: float = 1.0, noise: float = 0.0) -> np.ndarray:
    """The pixels of the tissue albedo's thin dark lines (vessels) in an ROI of a frame's luma.

    The film's lobe is smooth with convex level sets, so it survives a closing; vessels are the
    pixels whose black top-hat (closing by a disc of :data:`ALBEDO_LINE_PX` px) is at least
    ``max(ALBEDO_LINE_STEPS * step, 3 * noise)``, grown by one pixel, none within the disc's radius
    of the ROI's border. Two lobes closer than the disc leave their saddle marked as a line.

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
    v = np.asarray(luma_roi, dtype=np.float32)
    lines = np.zeros(v.shape[:2], np.uint8)
    h = ALBEDO_LINE_PX // 2
    if v.ndim != 2 or min(v.shape) <= 2 * h:
        return lines.astype(bool)
    yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
    disc = (xx * xx + yy * yy <= h * h + 0.5).astype(np.uint8)
    top_hat = cv2.morphologyEx(v, cv2.MORPH_CLOSE, disc, borderType=cv2.BORDER_REPLICATE) - v
    lines[h:-h, h:-h] = top_hat[h:-h, h:-h] >= max(ALBEDO_LINE_STEPS * float(step), 3.0 * float(noise))
    return cv2.dilate(lines, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).astype(bool)


def _roi_grid(values, camera, origin_uv, clip_level):
    """The ROI of a photometric fit: ``(vals, camera, o, uu, vv, keep)``, ``o`` the top-left pixel, ``keep``
    ``vals < clip_level``. Raises ValueError for values that are not a finite 2-D array."""
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
    """The rig's Lambertian shading ``sum_j w_j max(0, n . l_j) f_j p_j`` of the plane (n, h), (N,). Unit albedo, the
    lobes' falloff and profile; ``terms``: each light's ``_terms[:6]`` if at hand; ``keep``: a list that receives each
    light's ``(term, cos theta)``."""
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
    """The derivatives (3, N) of :func:`_rig_diffuse` in (a, b, log h) about ``p``. ``at``: ``(n, dns, terms)`` or
    ``(n, dns, terms, keep)`` if at hand."""
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
    """The derivatives (3, N) of the rig's Phong image in the curvatures (k_xx, k_xy, k_yy) at zero, the
    plane (n, h) bent about ``apex`` as :func:`~simtest.reconstruct.lightaware.patch.quadric_fit`'s
    patch (each column up to a constant factor)."""
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


def _rig_value_ggx(dT, rl, n, h, rig_arr, alpha, ior: float = GGX_FILM_IOR, parts=None):
    """The rig's GGX lobes under a dielectric film on the plane (n, h) along unit rays ``dT`` (3, N):
    ``S = sum_j w_j F D G1(v) G1(l_j) / (4 n . v) f_j p_j``, the renderer's wet film
    (:func:`simtest.render.tissue.specular_lobe`); ``parts`` receives each light's pieces."""
    L, w, inv_sq, m = rig_arr
    # a product, not ``** 2``: a run-off trial alpha overflows to inf (rejected) where ``** 2`` raises
    a2 = float(alpha) * float(alpha)
    S = np.zeros(dT.shape[1])
    for j in range(len(w)):
        _, delta, s, sl, ir, c, _ = _terms(dT, n, h, L[j], (rl[0][j], rl[1][j]))
        F = _fresnel_of_vl(sl * ir, ior)
        val = _ggx_lobe(delta, s, sl, ir, c, a2, ior, F)
        scaled = val * ((h * ir) * (h * ir)) if inv_sq[j] else val  # falloff and profile
        if m[j] > 0:
            scaled = scaled * np.maximum((s * dT[2] - L[j, 2]) * ir, 1e-12) ** m[j]
        scaled = w[j] * scaled
        S += scaled
        if parts is not None:
            parts.append((delta, s, sl, ir, c, val, F, scaled))
    return S


def _ggx_lobe(delta, s, sl, ir, c, a2, ior, F=None):
    """One light's film lobe before falloff and profile: ``F D G1(v) G1(l) / (4 n . v)`` (Walter et al.
    2007, doi:10.2312/EGWR/EGSR07/195-206), 0 below the plane; ``F`` the Fresnel factor if at hand."""
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


def _fresnel_of_vl(vl, ior):
    """Fresnel's reflectance ``F(v . m)``, ``v . m = sqrt((1 + v . l) / 2)``, from ``vl = v . l``."""
    return fresnel_dielectric(np.sqrt(np.clip(0.5 * (1.0 + vl), 0.0, 1.0)), ior)


#: Step in ``v . l`` of :func:`_rig_grad_ggx`'s central difference of Fresnel's factor.
_FRESNEL_STEP = 1e-6


def _rig_grad_ggx(dT, rl, n, dns, h, rig_arr, alpha, ior: float = GGX_FILM_IOR, parts=None) -> np.ndarray:
    """``dS`` (4, N) of :func:`_rig_value_ggx` in (a, b, log h, log alpha); ``parts`` its pieces if at hand.
    ``d val = val * sum of the logarithmic derivatives of F, D, G1(v), G1(l), 1 / (4 n . v), f and p`` (Walter et al.
    2007, eqs. 33-34); Fresnel's by a central difference (:data:`_FRESNEL_STEP`). Where a floor or clip holds, the
    derivative is 0."""
    L, w, inv_sq, m = rig_arr
    a2 = float(alpha) * float(alpha)
    am1 = a2 - 1.0
    # dn . d per ray, term by term (no BLAS call: the same bits on any number of threads)
    P = [dn[0] * dT[0] + dn[1] * dT[1] + dn[2] * dT[2] for dn in dns]
    dS = np.zeros((4, dT.shape[1]))
    if parts is None:
        parts = []
        _rig_value_ggx(dT, rl, n, h, rig_arr, alpha, ior, parts)
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
        kD = np.where(free_h, -4.0 * am1 * cos_h / t, 0.0)  # d log D / d cos_h
        # d log G1(v) / d delta, and d log (1 / (4 n . v)) / d delta = -1 / delta
        kGi = np.where(delta > 1e-6, a2 / ((1.0 + ui) * ui * (ci * ci * ci)) - 1.0 / ci, 0.0)
        kGo = np.where(cos_o > 1e-6, a2 / ((1.0 + uo) * uo * (co * co * co)), 0.0)  # d log G1(l) / d cos_o
        irs, sz, f2 = -(ir * ir * ir) * sl, s * dT[2] - L[j, 2], 2.0 * (ir * ir) * sl  # (per ds, sz * ir: cos theta)
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
        # log alpha: through a2 in D and both G1 (written out: an alpha run off to 0 gives 0)
        gi = -(1.0 / (ci * ci) - 1.0) / (2.0 * ui * (1.0 + ui))
        go = -(1.0 / (co * co) - 1.0) / (2.0 * uo * (1.0 + uo))
        dS[3] += scaled * (2.0 - 4.0 * a2 * cos_h * cos_h / t + 2.0 * a2 * (gi + go))
    return dS


def ggx_alpha_of_phong(n: float) -> float:
    """The GGX alpha whose lobe's peak curvature matches Phong's exponent n: ``sqrt(2 / (n + 2))``
    (Walter et al. 2007, section 5.2)."""
    return float(np.sqrt(2.0 / (max(float(n), 0.0) + 2.0)))


def phong_of_ggx_alpha(alpha: float) -> float:
    """The inverse of :func:`ggx_alpha_of_phong`: ``2 / alpha^2 - 2`` (-2 where alpha^2 overflows)."""
    with np.errstate(over="ignore"):
        return float(2.0 / max(np.float64(alpha) ** 2, 1e-300) - 2.0)
