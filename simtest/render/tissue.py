"""Procedural tissue: seeded RGB albedo with branching vessels, micro-relief and a wet specular film.

Every field is a closed-form function of the point, written once for numpy and Dr.Jit (the ``xp``
argument), so the renderer and the ground truth evaluate the same function. The fields live in the
*texture frame* (the mesh's own frame; world for spheres and cylinders; camera for planes and saddles);
:func:`in_camera` evaluates them on camera-frame points through ``q = A p + b``, so a surface point keeps
its albedo and relief from any pose (``A``, ``b``, amplitudes and roughness are opaque Dr.Jit values:
one compiled kernel serves every pose and sweep).

- **Albedo**: a base colour (:data:`TISSUE_ALBEDO`) times a smooth variation times the vessel networks'
  transmission (:mod:`simtest.render.vessels`) on the surface's (u, v) (:func:`surface_uv`: a plane's
  own axes, else triplanar weights ``|n_i|^4``, Geiss 2007, GPU Gems 3, ch. 1).
- **Micro-relief**: ``h(q) = sum_j a_j sin(k_j . q + phi_j)``, :data:`N_RELIEF_WAVES` random waves with
  log-uniform stratified wavelengths and self-affine amplitudes ``a_j ~ lambda_j^H`` (PSD
  ``q^-(2 + 2H)``, Persson et al. 2005, https://doi.org/10.1088/0953-8984/17/1/R01; Berry & Lewis 1980,
  https://doi.org/10.1098/rspa.1980.0044), scaled to RMS ``relief_mm``. :data:`RELIEF_HURST` is the
  value common to natural rough surfaces (0.7 to 0.9), not a measurement of mucosa. The shading
  normal is bump-mapped: ``n_s = unit(n - (grad h - (grad h . n) n))`` (Blinn 1978,
  https://doi.org/10.1145/965139.507101).
- **Film thickness**: a smooth field ``f`` sets the film's roughness (:func:`film_alpha`) and levels
  the relief: by the linearised thin-film equation a wave of wavenumber k on a film of thickness h keeps
  ``exp(-(k L)^4)``, ``L^4 = l_s h^3`` (:data:`LEVELLING_MM`; Orchard 1962, Appl. Sci. Res. A 11, 451;
  Salez et al. 2012, https://arxiv.org/abs/1210.5905), ``h = h_0 exp(-s f)``. Only the specular normal
  is levelled. Ranges: ``h_0`` 0 to 1 mm (human colon mucus 107-155 um, Pullan et al. 1994,
  https://doi.org/10.1136/gut.35.3.353; rat colon 0.83 mm, Atuma et al. 2001,
  https://doi.org/10.1152/ajpgi.2001.280.5.G922), ``s`` 0 to 1.5.
- **Specular film**: a dielectric (IOR 1.33 to 1.45) with Fresnel over a Beckmann or GGX microfacet
  lobe (Walter et al. 2007, https://doi.org/10.2312/EGWR/EGSR07/195-206), or the paper's Phong lobe
  ``c cos(beta)^n`` (eq. 1) scaled by Fresnel at normal incidence.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from simtest.render.vessels import TILE_MM, transmission_map
from simtest.specular.fresnel import fresnel_dielectric

__all__ = ["TISSUE_ALBEDO", "TISSUE_SEED_KEY", "N_WAVES", "N_RELIEF_WAVES", "RELIEF_HURST", "RELIEF_MIN_MM",
           "TissueParams", "tissue_params", "with_neighbours", "in_camera", "surface_uv", "vessel_transmission",
           "albedo", "relief_height", "relief_normal", "LEVELLING_MM", "film_alpha", "specular_lobe"]

#: Linear-RGB diffuse albedo of each tissue before variation. Mucosa: pink, sRGB about (225, 140, 125),
#: assumed. Liver: inside the published diffuse reflectance of liver over the camera's bands (Jacques
#: 2013, https://doi.org/10.1088/0031-9155/58/11/R37). Peritoneum over fat: sRGB about (215, 170, 140);
#: gallbladder (bile through its wall): about (140, 150, 105); both assumed.
TISSUE_ALBEDO = {"mucosa": (0.75, 0.26, 0.20), "liver": (0.35, 0.12, 0.09),
                 "peritoneum": (0.68, 0.40, 0.26), "gallbladder": (0.26, 0.30, 0.14)}

#: Relative margin of the organ's ellipsoid in :func:`albedo` (``sum(((q - c) / axes)^2) <= (1 + m)^2``):
#: covers the mesh vertices' float32 round-off, far below a pixel's footprint.
ORGAN_MARGIN = 1e-3

#: Stable key of the tissue texture stream in ``SeedSequence([seed, TISSUE_SEED_KEY])``.
TISSUE_SEED_KEY = 0x7155E

#: Plane waves of the albedo's colour variation (and of the film's thickness field).
N_WAVES = 12
#: Plane waves of the micro-relief spectrum.
N_RELIEF_WAVES = 40
#: Default Hurst exponent of the micro-relief's self-affine spectrum (see the module notes).
RELIEF_HURST = 0.8
#: Default shortest wavelength of the micro-relief, mm: the colonic crypt openings' spacing (0.05-0.1 mm)
RELIEF_MIN_MM = 0.05
#: Levelling length ``l_s = sigma t / (3 eta)``, mm: sigma 0.05 N/m, eta 1 Pa s (loose mucus; Lai et al. 2009,
#: https://doi.org/10.1016/j.addr.2008.09.012), t 1 s (the film's renewal). Only ``l_s h^3`` is seen.
LEVELLING_MM = 16.7


@dataclass(frozen=True)
class TissueParams:
    """Seeded parameters of one tissue texture: plane waves ``sin(k . p + phase)``, wave vectors in rad/mm."""

    base: tuple[float, float, float]
    colour_k: np.ndarray  # (N, 3) wave vectors, rad/mm
    colour_phase: np.ndarray  # (N,)
    #: (H, W, 3) vessel transmission over a mirrored tile TILE_MM wide; None: no vessels
    vessel_map: np.ndarray | None
    relief_k: np.ndarray  # (M, 3)
    relief_phase: np.ndarray  # (M,)
    relief_amp: np.ndarray  # (M,) mm; the RMS of the sum is the relief's RMS height
    #: (4, 4) rigid map from the points' frame (camera) to the texture frame; None: same frame
    frame: np.ndarray | None = None
    #: Base albedo of a wall's tissue at least ``wall_radius`` from ``wall_centre`` (mm); None: none
    wall_base: tuple[float, float, float] | None = None
    wall_centre: tuple[float, float, float] | None = None
    wall_radius: float = 0.0
    #: Base albedo of an organ inside the axis-aligned ellipsoid ``organ_centre``, ``organ_axes`` (mm);
    #: None: no organ. It takes precedence over the wall.
    organ_base: tuple[float, float, float] | None = None
    organ_centre: tuple[float, float, float] | None = None
    organ_axes: tuple[float, float, float] | None = None
    #: Waves of the film's thickness field (unit RMS) and the log-SD of its roughness (0: uniform)
    film_k: np.ndarray | None = None
    film_phase: np.ndarray | None = None
    film_variation: float = 0.0
    #: (2, 3) in-surface axes of a plane, ``(u, v) = (e1 . q, e2 . q)``; None: triplanar
    uv_axes: np.ndarray | None = None
    #: (M,) weight of each relief wave's slope in the diffuse normal; None: the shading normal
    relief_diffuse: np.ndarray | None = None
    #: The film's ``L^4 = l_s h_0^3``, mm^4 (0: no levelling) and the log-SD of its thickness.
    film_level4: float = 0.0
    film_thickness_spread: float = 0.0


def with_neighbours(t: TissueParams, wall=(None, None, None), organ=(None, None, None)) -> TissueParams:
    """``t`` with a wall's tissue and a neighbouring organ's (their default albedos).

    ``wall``: (tissue name, centre mm, radius mm), the second tissue at least that far from the centre;
    ``organ``: (tissue name, centre mm, semi-axes mm), the third tissue inside that ellipsoid. A name None
    leaves that part out.
    """
    if wall[0] is not None:
        t = dataclasses.replace(t, wall_base=TISSUE_ALBEDO[wall[0]], wall_centre=tuple(float(x) for x in wall[1]),
                                wall_radius=float(wall[2]))
    if organ[0] is not None:
        t = dataclasses.replace(t, organ_base=TISSUE_ALBEDO[organ[0]], organ_centre=tuple(float(x) for x in organ[1]),
                                organ_axes=tuple(float(x) for x in organ[2]))
    return t


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _waves(rng: np.random.Generator, wavelength_mm: float, n: int = N_WAVES):
    d = _directions(rng, n)
    lam = wavelength_mm * np.exp(rng.uniform(math.log(0.5), math.log(2.0), size=n))
    return d * (2.0 * math.pi / lam)[:, None], rng.uniform(0.0, 2.0 * math.pi, size=n)


def relief_spectrum(rng: np.random.Generator, relief_mm: float, min_mm: float, max_mm: float,
                    hurst: float, n: int = N_RELIEF_WAVES):
    """Wave vectors (n, 3), phases (n,) and amplitudes (n,) of the micro-relief (module notes).

    Wavelengths stratified log-uniform over [min_mm, max_mm]; amplitudes ``~ lambda^hurst`` scaled so the RMS
    height ``sqrt(sum a^2 / 2)`` is ``relief_mm``.
    """
    d = _directions(rng, n)
    u = (np.arange(n) + rng.uniform(0.0, 1.0, size=n)) / n
    lam = min_mm * (max_mm / min_mm) ** u
    phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
    w = lam ** float(hurst)
    amp = relief_mm * w / math.sqrt(float(np.sum(w * w)) / 2.0)
    return d * (2.0 * math.pi / lam)[:, None], phase, amp


def tissue_params(kind: str, seed: int, relief_mm: float, relief_scale_mm: float, vessel_scale_mm: float = 4.0, *,
                  relief_min_mm: float | None = None, relief_hurst: float = RELIEF_HURST,
                  base: tuple[float, float, float] | None = None, film_variation: float = 0.0,
                  film_scale_mm: float = 2.0, subsurface_mm: float = 0.0, film_thickness_mm: float = 0.0,
                  film_thickness_spread: float = 0.0) -> TissueParams:
    """Draw a tissue texture (texture frame) from ``SeedSequence([seed, TISSUE_SEED_KEY])``.

    Parameters
    ----------
    kind : {"mucosa", "liver"}
    seed : int
        Texture seed.
    relief_mm : float
        RMS height of the micro-relief, mm (0: smooth).
    relief_scale_mm : float
        Longest wavelength of the micro-relief, mm.
    vessel_scale_mm : float
        A third of the colour variation's typical wavelength, mm.
    relief_min_mm : float, optional
        Shortest wavelength, mm; default ``min(RELIEF_MIN_MM, relief_scale_mm)``.
    relief_hurst : float
        Hurst exponent H, amplitudes ``~ lambda^H``.
    base : (float, float, float), optional
        Linear-RGB base albedo; default ``TISSUE_ALBEDO[kind]`` (the seeded pattern does not depend on it).
    film_variation : float
        Standard deviation of the log of the film's roughness (0: uniform; :func:`film_alpha`).
    film_scale_mm : float
        Typical wavelength of the film's thickness field, mm.
    subsurface_mm : float
        Diffusion length ``l`` of the diffuse light, mm (0: it takes the shading normal): the diffuse
        normal keeps ``1 / (1 + (2 pi l / lambda)^2)`` of each wave's slope (Cuccia et al. 2009,
        https://doi.org/10.1117/1.3088140).
    film_thickness_mm, film_thickness_spread : float
        Median thickness ``h_0`` (mm, 0: none) and log-SD of the film that levels the relief.

    Raises
    ------
    ValueError
        If ``relief_min_mm`` exceeds ``relief_scale_mm`` or is not positive.
    """
    lo = min(RELIEF_MIN_MM, relief_scale_mm) if relief_min_mm is None else float(relief_min_mm)
    if not 0.0 < lo <= relief_scale_mm:
        raise ValueError(f"relief_min_mm {lo} must be in (0, relief_scale_mm = {relief_scale_mm}]")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), TISSUE_SEED_KEY]))
    ck, cp = _waves(rng, 3.0 * vessel_scale_mm)
    _waves(rng, vessel_scale_mm)  # the former vessel field's draw: keeps the relief's and film's streams
    rk, rp, amp = relief_spectrum(rng, relief_mm, lo, relief_scale_mm, relief_hurst)
    fk, fp = _waves(rng, film_scale_mm)  # drawn last: the other fields do not depend on it
    diffuse = 1.0 / (1.0 + (subsurface_mm * np.linalg.norm(rk, axis=1)) ** 2) if subsurface_mm > 0.0 else None
    colour = TISSUE_ALBEDO[kind] if base is None else tuple(float(x) for x in base)
    return TissueParams(colour, ck, cp, transmission_map(int(seed)), rk, rp, amp, film_k=fk, film_phase=fp,
                        film_variation=float(film_variation), relief_diffuse=diffuse,
                        film_level4=LEVELLING_MM * float(film_thickness_mm) ** 3,
                        film_thickness_spread=float(film_thickness_spread))


def in_camera(t: TissueParams, cam_to_texture: np.ndarray) -> TissueParams:
    """The texture ``t`` as a function of camera-frame points and normals.

    Parameters
    ----------
    t : TissueParams
    cam_to_texture : ndarray of shape (4, 4)
        Rigid map ``q = A p + b`` from camera-frame to texture-frame points, mm.

    Returns
    -------
    TissueParams
        ``t`` with :attr:`TissueParams.frame` set (unchanged, no frame, for the identity).
    """
    m = np.asarray(cam_to_texture, dtype=np.float64)
    if np.array_equal(m, np.eye(4)):
        return dataclasses.replace(t, frame=None)
    return dataclasses.replace(t, frame=m.copy())


def _const(xp, x: float):
    """``x`` as a Python float for numpy, an opaque Dr.Jit value where ``xp`` offers ``const``."""
    f = getattr(xp, "const", None)
    return float(x) if f is None else f(float(x))


def _to_texture(xp, p, t: TissueParams):
    """Points ``p`` (camera frame) in the texture frame, and the rotation ``A`` used (None: none)."""
    if t.frame is None:
        return p, None
    A = [[_const(xp, t.frame[i, j]) for j in range(3)] for i in range(3)]
    b = [_const(xp, t.frame[i, 3]) for i in range(3)]
    q = tuple(A[i][0] * p[0] + A[i][1] * p[1] + A[i][2] * p[2] + b[i] for i in range(3))
    return q, A


def _field(xp, p, k, phase):
    """sum_j sin(k_j . p + phase_j) / sqrt(N / 2) (unit RMS)."""
    s = 0.0
    for j in range(len(phase)):
        s = s + xp.sin(p[0] * float(k[j, 0]) + p[1] * float(k[j, 1]) + p[2] * float(k[j, 2]) + float(phase[j]))
    return s * math.sqrt(2.0 / len(phase))


def _np_texture(tex: np.ndarray, s, r):
    """Bilinear, mirrored lookup of ``tex`` (H, W, C) at ``(s, r)`` in float64, as Dr.Jit's ``Texture2f``."""
    h, w = tex.shape[:2]
    s, r = np.broadcast_arrays(np.asarray(s, dtype=np.float64), np.asarray(r, dtype=np.float64))
    coords = np.stack([r.ravel() * h - 0.5, s.ravel() * w - 0.5])
    return tuple(map_coordinates(tex[..., c].astype(np.float64), coords, order=1, mode="reflect").reshape(s.shape)
                 for c in range(tex.shape[2]))


#: Offsets (mm) of the triplanar projections' (u, v), so the three views show different parts of the tile
_TRIPLANAR_OFFSET_MM = ((0.0, 0.0), (TILE_MM / 3.0, 2.0 * TILE_MM / 3.0), (2.0 * TILE_MM / 3.0, TILE_MM / 3.0))


def surface_uv(xp, q, nq, t: TissueParams):
    """The surface's (u, v), mm, at texture-frame points ``q``, as a list of ``(weight, u, v)``.

    One term on a plane (:attr:`TissueParams.uv_axes`) or without normals; else the three triplanar
    projections weighted by ``|n_i|^4 / sum_j |n_j|^4``.
    """
    if t.uv_axes is not None:
        e = t.uv_axes
        return [(1.0, q[0] * float(e[0, 0]) + q[1] * float(e[0, 1]) + q[2] * float(e[0, 2]),
                 q[0] * float(e[1, 0]) + q[1] * float(e[1, 1]) + q[2] * float(e[1, 2]))]
    if nq is None:
        return [(1.0, q[0], q[1])]
    w = [nq[i] * nq[i] * nq[i] * nq[i] for i in range(3)]
    inv = 1.0 / xp.maximum(w[0] + w[1] + w[2], 1e-30)  # a zero normal (a ray's miss): no vessels, not NaN
    (ax, ay), (bx, by), (cx, cy) = _TRIPLANAR_OFFSET_MM
    return [(w[0] * inv, q[1] + ax, q[2] + ay), (w[1] * inv, q[2] + bx, q[0] + by), (w[2] * inv, q[0] + cx, q[1] + cy)]


def vessel_transmission(xp, q, nq, t: TissueParams):
    """Per-channel transmission (R, G, B) of the vessel networks at texture-frame points (1 without vessels)."""
    if t.vessel_map is None:
        return 1.0, 1.0, 1.0
    look = getattr(xp, "texture", None) or _np_texture
    out = None
    for w, u, v in surface_uv(xp, q, nq, t):
        # the tile centred on the origin of (u, v): its mirror lines sit TILE_MM / 2 away from it
        rgb = look(t.vessel_map, u * (1.0 / TILE_MM) + 0.5, v * (1.0 / TILE_MM) + 0.5)
        out = [w * x for x in rgb] if out is None else [o + w * x for o, x in zip(out, rgb)]
    return tuple(out)


def albedo(xp, p, t: TissueParams, n=None):
    """Diffuse RGB albedo, a tuple of three arrays in [0, 1], at surface points ``p`` = (x, y, z), mm.

    ``p`` (and the normals ``n`` the triplanar mapping weighs, or None) are in the camera frame after
    :func:`in_camera`, else the texture frame. The wall's and the organ's tissues apply where set.
    """
    q, A = _to_texture(xp, p, t)
    nq = n
    if n is not None and A is not None:
        nq = tuple(A[i][0] * n[0] + A[i][1] * n[1] + A[i][2] * n[2] for i in range(3))
    var = _field(xp, q, t.colour_k, t.colour_phase)  # smooth, unit RMS
    wall = None
    if t.wall_base is not None:
        d = [q[i] - float(t.wall_centre[i]) for i in range(3)]
        wall = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) >= float(t.wall_radius) ** 2
    organ = None
    if t.organ_base is not None:
        e = [(q[i] - float(t.organ_centre[i])) * (1.0 / float(t.organ_axes[i])) for i in range(3)]
        organ = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) <= (1.0 + ORGAN_MARGIN) ** 2
    trans = vessel_transmission(xp, q, nq, t)
    out = []
    for c in range(3):
        base = t.base[c] if wall is None else xp.where(wall, t.wall_base[c], t.base[c])
        if organ is not None:
            base = xp.where(organ, t.organ_base[c], base)
        a = base * (1.0 + 0.12 * var) * trans[c]
        out.append(xp.minimum(xp.maximum(a, 0.0), 1.0))
    return tuple(out)


def relief_height(xp, p, t: TissueParams, n=None):
    """Micro-relief height ``sum_j a_j sin(k_j . p + phi_j)``, mm; given unit normals ``n``, the levelled film's."""
    p, A = _to_texture(xp, p, t)
    kept = _kept(xp, p, n, A, t)
    h = 0.0
    for j in range(len(t.relief_phase)):
        k = t.relief_k[j]
        a = _const(xp, t.relief_amp[j]) if kept is None else _const(xp, t.relief_amp[j]) * kept[j]
        h = h + a * xp.sin(p[0] * float(k[0]) + p[1] * float(k[1]) + p[2] * float(k[2]) + float(t.relief_phase[j]))
    return h


def _bumped(xp, n, g, A):
    """``unit(n - (g - (g . n) n))`` for a texture-frame gradient ``g`` (turned back by ``A^T``)."""
    if A is not None:  # the gradient back in the camera frame: grad_p h = A^T grad_q h
        g = [A[0][i] * g[0] + A[1][i] * g[1] + A[2][i] * g[2] for i in range(3)]
    gn = g[0] * n[0] + g[1] * n[1] + g[2] * n[2]
    s = [n[i] - (g[i] - gn * n[i]) for i in range(3)]
    inv = 1.0 / xp.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    return s[0] * inv, s[1] * inv, s[2] * inv


def _kept(xp, q, n, A, t: TissueParams):
    """Each relief wave's share ``exp(-(k_t L)^4)`` in the film's surface (tangential k_t); None: no film."""
    if t.film_level4 <= 0.0 or n is None:
        return None
    nq = n if A is None else [A[i][0] * n[0] + A[i][1] * n[1] + A[i][2] * n[2] for i in range(3)]
    e = _const(xp, t.film_level4)
    if t.film_thickness_spread > 0.0:
        e = e * xp.exp(_const(xp, -3.0 * t.film_thickness_spread) * _field(xp, q, t.film_k, t.film_phase))
    kt2 = [float(k @ k) - (nq[0] * float(k[0]) + nq[1] * float(k[1]) + nq[2] * float(k[2])) ** 2 for k in t.relief_k]
    return [xp.exp(-(x * x) * e) for x in kt2]


def relief_normal(xp, p, n, t: TissueParams, *, diffuse: bool = False):
    """Shading normal with micro-relief, ``unit(n - (grad h - (grad h . n) n))``, as an (x, y, z) tuple.

    ``p`` and ``n`` (unit macro normal) are (x, y, z) tuples of arrays; the result is that of the film's
    surface, on the side of ``n``. With ``diffuse``: the pair (shading normal, the diffuse light's normal:
    the unlevelled relief with slopes weighted by :attr:`TissueParams.relief_diffuse`).
    """
    w = t.relief_diffuse if diffuse else None
    if not np.any(t.relief_amp):  # smooth: no waves to evaluate (the normal, normalised)
        ns = _bumped(xp, n, (0.0, 0.0, 0.0), None)
        return (ns, ns) if diffuse else ns
    p, A = _to_texture(xp, p, t)
    kept = _kept(xp, p, n, A, t)
    if diffuse and w is None and kept is not None:
        w = np.ones(len(t.relief_phase))  # the diffuse light: the tissue's relief, not the film's
    g, gd = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for j in range(len(t.relief_phase)):
        k = t.relief_k[j]
        cj = xp.cos(p[0] * float(k[0]) + p[1] * float(k[1]) + p[2] * float(k[2]) + float(t.relief_phase[j]))
        c = _const(xp, t.relief_amp[j]) * cj
        cf = c if kept is None else c * kept[j]
        g = [g[i] + cf * float(k[i]) for i in range(3)]
        if w is not None:
            cd = _const(xp, t.relief_amp[j] * w[j]) * cj
            gd = [gd[i] + cd * float(k[i]) for i in range(3)]
    ns = _bumped(xp, n, g, A)
    if not diffuse:
        return ns
    return ns, (ns if w is None else _bumped(xp, n, gd, A))


def film_alpha(xp, p, t: TissueParams, alpha: float):
    """The wet film's roughness ``alpha exp(v f(q))`` at points ``p``, clipped to [0.002, 1].

    ``f`` is the unit-RMS thickness field, ``v`` :attr:`TissueParams.film_variation` (``alpha`` itself when 0):
    a thick film is smooth (small, bright glints), a thin one rough (broad sheen).
    """
    if t.film_variation == 0.0 or t.film_k is None:
        return alpha
    q, _ = _to_texture(xp, p, t)
    f = _field(xp, q, t.film_k, t.film_phase)
    a = alpha * xp.exp(_const(xp, t.film_variation) * f)
    return xp.minimum(xp.maximum(a, 0.002), 1.0)


def specular_lobe(xp, n, wi, wo, lobe: str, alpha: float, phong_n: float, ior: float, c: float):
    """Specular BRDF of the wet film for unit (x, y, z) tuples n, wi (to the camera), wo (to the light).

    ``lobe``: "beckmann", "ggx" (Smith's G, Walter et al. 2007, eqs. 25-34) or "phong" (paper eq. 1 times
    the normal-incidence Fresnel). Scaled by ``c``; zero below the surface.
    """
    cos_i = n[0] * wi[0] + n[1] * wi[1] + n[2] * wi[2]
    cos_o = n[0] * wo[0] + n[1] * wo[1] + n[2] * wo[2]
    ok = (cos_i > 0.0) & (cos_o > 0.0)
    ci = xp.maximum(cos_i, 1e-6)
    co = xp.maximum(cos_o, 1e-6)
    if lobe == "phong":
        rx, ry, rz = (2.0 * cos_i * n[0] - wi[0], 2.0 * cos_i * n[1] - wi[1], 2.0 * cos_i * n[2] - wi[2])
        cb = xp.maximum(rx * wo[0] + ry * wo[1] + rz * wo[2], 0.0)
        f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
        val = c * f0 * xp.power(cb, phong_n) / co  # radiance c cos^n (no foreshortening, as eq. 1)
        return xp.where(ok, val, 0.0)
    hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
    inv = 1.0 / xp.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    cos_h = xp.maximum(hx * n[0] + hy * n[1] + hz * n[2], 1e-6)
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    tan2 = (1.0 - c2) / c2
    if lobe == "beckmann":
        D = xp.exp(-tan2 / a2) / (math.pi * a2 * c2 * c2)

        def g1(cos):
            a = cos / (alpha * xp.sqrt(xp.maximum(1.0 - cos * cos, 1e-12)))
            return xp.where(a < 1.6, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a), 1.0)
    else:
        D = a2 / (math.pi * c2 * c2 * (a2 + tan2) * (a2 + tan2))

        def g1(cos):
            t2 = (1.0 - cos * cos) / (cos * cos)
            return 2.0 / (1.0 + xp.sqrt(1.0 + a2 * t2))
    cos_ih = xp.maximum(wi[0] * hx + wi[1] * hy + wi[2] * hz, 0.0)
    F = fresnel_dielectric(cos_ih, ior, xp)
    val = c * F * D * g1(ci) * g1(co) / (4.0 * ci * co)
    return xp.where(ok, val, 0.0)
