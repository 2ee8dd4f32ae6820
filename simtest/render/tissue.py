"""Procedural tissue: seeded RGB albedo with branching vessels, micro-relief and a wet specular film.

Everything here is a closed-form function of the surface point, written once for numpy and Dr.Jit
alike (the ``xp`` argument: ``numpy`` or ``drjit``), so the renderer shades with it in Mitsuba's
wavefront and the ground truth evaluates the very same function per pixel:

- **Attached to the tissue.** The fields are solid textures of the point ``q`` in the *texture
  frame*: the mesh's own frame (the mesh file's axes, in mm, moved with the mesh's rotation and
  translation), the world frame for spheres and cylinders, the camera frame for planes and
  saddles, which are defined in it. A render evaluates them on camera-frame points ``p`` and
  normals ``n`` through the rigid map ``q = A p + b`` of :attr:`TissueParams.frame`
  (:func:`in_camera`): the fields are evaluated at ``q`` with the normal ``A n`` and the shading
  normal is turned back by ``A^T``, so a surface point keeps its albedo and relief from any pose.
  Dr.Jit takes ``A`` and ``b`` as opaque values (``xp.const``), so a new pose reuses the compiled
  kernels; so are the relief's amplitudes (its height and Hurst exponent) and the film's
  roughness, so that a fit or a sweep over them compiles once.
- **Albedo** (diffuse RGB): a base colour per tissue (:data:`TISSUE_ALBEDO`) times a smooth
  colour variation, times the transmission of seeded vessel networks (:mod:`simtest.render.vessels`:
  branching, tapering trees grown by space colonisation at two depths, blurred and greyer with
  depth), a texture of the surface's own 2D coordinates ``(u, v)``, mm (:func:`surface_uv`): the
  plane's own axes on a plane (:attr:`TissueParams.uv_axes`), elsewhere a triplanar projection of
  the texture-frame point blended by its normal (Geiss 2007, "Generating complex procedural
  terrains using the GPU", GPU Gems 3, ch. 1: weights ``|n_i|^4``).
- **Micro-relief**: a height field ``h(q) = sum_j a_j sin(k_j . q + phi_j)``, a random-wave
  (Longuet-Higgins) sum of :data:`N_RELIEF_WAVES` plane waves with isotropic seeded directions,
  uniform phases and wavelengths drawn stratified log-uniformly between ``relief_min_mm`` and
  ``relief_scale_mm``, with amplitudes of a self-affine (fractal) surface: power spectral density
  ``C(q) ~ q^-(2 + 2H)`` (Persson et al. 2005, https://doi.org/10.1088/0953-8984/17/1/R01, eq. 5;
  the Weierstrass-Mandelbrot construction of Berry & Lewis 1980,
  https://doi.org/10.1098/rspa.1980.0044), so a wave standing for an equal share of log-wavenumber
  carries ``a_j ~ lambda_j^H``. The Hurst exponent ``H`` (:data:`RELIEF_HURST` = 0.8 by default) is
  the value common to natural rough surfaces (0.7 to 0.9 in Persson's survey), not a measurement
  of mucosa: ``simtest simreal`` compares the result with real frames. The amplitudes are scaled so
  the RMS height is ``relief_mm``. With ``H < 1`` the slopes grow toward the short wavelengths, so
  the relief breaks a specular lobe into many small glints rather than a regular cross-hatch. The
  height tilts the shading normal: ``n_s = unit(n - (grad h - (grad h . n) n))`` (the bump mapping
  of Blinn 1978, https://doi.org/10.1145/965139.507101, on the tangent plane of the macro normal
  ``n``).
- **Film thickness**: a smooth seeded field ``f`` over the surface sets the film's roughness
  (:func:`film_alpha`, ``material.film_variation``; thick and smooth, thin and rough) and, with
  ``material.film_thickness_mm``, levels the relief: surface tension levels the wet film's free
  surface. Linearised, the thin-film equation makes a wave of in-surface wavenumber ``k`` on a film
  of thickness ``h`` decay as ``exp(-sigma h^3 k^4 t / (3 eta))`` (Orchard 1962, "On surface
  levelling in viscous liquids and gels", Appl. Sci. Res. A 11, 451; Salez et al. 2012,
  https://arxiv.org/abs/1210.5905), so the film keeps ``exp(-(k L)^4)`` of each relief wave, ``L^4 =
  l_s h^3`` (:data:`LEVELLING_MM`), ``h = h_0 exp(-s f)`` (``s`` = ``film_thickness_spread``). Only
  the specular normal is levelled. Ranges: ``h_0`` 0 to 1 mm (the human colon's adherent mucus 107
  to 155 um on average, SD 48 to 68 um, Pullan et al. 1994, https://doi.org/10.1136/gut.35.3.353;
  the rat colon's whole mucus about 0.83 mm, Atuma et al. 2001,
  https://doi.org/10.1152/ajpgi.2001.280.5.G922), ``s`` 0 to 1.5 (Pullan's SD over mean 0.35 to
  0.5).
- **Specular film**: a dielectric interface (IOR 1.33 to 1.45, water to mucus) with Fresnel's
  reflectance over a rough microfacet lobe, Beckmann or GGX (Walter et al. 2007,
  https://doi.org/10.2312/EGWR/EGSR07/195-206), ``f_s = F(wi . m) D(m) G(wi, wo) / (4 cos_i
  cos_o)`` about the half-vector m of the shading normal; or the paper's exact Phong lobe
  ``c cos(beta)^n`` (eq. 1) scaled by Fresnel at normal incidence.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from simtest.render.vessels import TILE_MM, transmission_map

__all__ = ["TISSUE_ALBEDO", "TISSUE_SEED_KEY", "N_WAVES", "N_RELIEF_WAVES", "RELIEF_HURST", "RELIEF_MIN_MM",
           "TissueParams", "tissue_params", "with_neighbours", "in_camera", "surface_uv", "vessel_transmission", "albedo",
           "relief_height", "relief_normal", "LEVELLING_MM",
           "film_alpha", "specular_lobe"]

#: Linear-RGB diffuse albedo of each tissue before variation. Mucosa: pink (sRGB about (225, 140,
#: 125), the colour of a bowel wall under white light), assumed to match the colour of endoscopic
#: frames. Liver: dark red-brown, (0.35, 0.12, 0.09), inside the range of published diffuse
#: reflectance of liver averaged over the camera's bands (about 0.3 to 0.4 in red, 0.1 to 0.15 in
#: green, 0.08 to 0.12 in blue): liver is rich in blood, whose haemoglobin absorbs green and blue
#: strongly and red weakly, while its scattering is broadband (Jacques 2013, "Optical properties of
#: biological tissues: a review", https://doi.org/10.1088/0031-9155/58/11/R37). Its median frame
#: R/G in laparoscope_liver, 1.67, is near the real liver's.
TISSUE_ALBEDO = {"mucosa": (0.75, 0.26, 0.20), "liver": (0.35, 0.12, 0.09),
                 # peritoneum over fat (abdominal wall, omentum): pale yellow-pink, sRGB about
                 # (215, 170, 140); assumed like the others
                 "peritoneum": (0.68, 0.40, 0.26),
                 # gallbladder: the green-grey of bile seen through its thin wall, sRGB about
                 # (140, 150, 105); assumed like the others
                 "gallbladder": (0.26, 0.30, 0.14)}

#: Relative margin of the organ's ellipsoid in :func:`albedo`: a point belongs to the organ where
#: ``sum(((q - centre) / axes)^2) <= (1 + ORGAN_MARGIN)^2``. The organ's vertices lie on the
#: ellipsoid to float32 round-off (1e-5 mm at 100 mm) and its flat faces inside it (chords of a
#: convex surface); 1e-3 of a 16 mm semi-axis is 0.016 mm, far below a pixel's footprint.
ORGAN_MARGIN = 1e-3

#: Stable key of the tissue texture stream in ``SeedSequence([seed, TISSUE_SEED_KEY])``.
TISSUE_SEED_KEY = 0x7155E

#: Plane waves of the albedo's colour variation (and of the film's thickness field).
N_WAVES = 12
#: Plane waves of the micro-relief spectrum.
N_RELIEF_WAVES = 40
#: Default Hurst exponent of the micro-relief's self-affine spectrum (see the module notes).
RELIEF_HURST = 0.8
#: Default shortest wavelength of the micro-relief, mm: the scale of the colonic crypt openings
#: (about 0.05 to 0.1 mm apart); shorter waves are below a pixel's footprint at working distances.
RELIEF_MIN_MM = 0.05
#: Levelling length ``l_s = sigma t / (3 eta)``, mm: sigma 0.05 N/m (mucus or saline against gas,
#: 0.03 to 0.07), eta 1 Pa s (loose mucus; human mucus spans 0.01 to 1000 Pa s over its shear
#: rates, Lai et al. 2009, https://doi.org/10.1016/j.addr.2008.09.012), t 1 s (the film renewed
#: by peristalsis, insufflation, the scope). Only ``l_s h^3`` is seen: an ``eta / t`` 100 times
#: larger is the same film 4.6 times thinner.
LEVELLING_MM = 16.7


@dataclass(frozen=True)
class TissueParams:
    """Seeded parameters of one tissue texture: plane waves ``sin(k . p + phase)`` of the frame
    the points are given in (the texture frame from :func:`tissue_params`, the camera frame after
    :func:`in_camera`), wave vectors in rad/mm."""

    base: tuple[float, float, float]
    colour_k: np.ndarray  # (N, 3) wave vectors, rad/mm
    colour_phase: np.ndarray  # (N,)
    #: (H, W, 3) per-channel vessel transmission over a tile TILE_MM wide, repeated mirrored
    #: (:func:`simtest.render.vessels.transmission_map`); None: no vessels.
    vessel_map: np.ndarray | None
    relief_k: np.ndarray  # (M, 3)
    relief_phase: np.ndarray  # (M,)
    relief_amp: np.ndarray  # (M,) mm; the RMS of the sum is the relief's RMS height
    #: (4, 4) rigid map from the frame of the points given to the functions below (the camera
    #: frame) to the texture frame; None: they are given in the texture frame.
    frame: np.ndarray | None = None
    #: Base albedo of a second tissue (a wall around the first), used at texture-frame points at
    #: least ``wall_radius`` from ``wall_centre`` (mm); None: one tissue everywhere.
    wall_base: tuple[float, float, float] | None = None
    wall_centre: tuple[float, float, float] | None = None
    wall_radius: float = 0.0
    #: Base albedo of a third tissue (a neighbouring organ), used at texture-frame points inside
    #: the ellipsoid of centre ``organ_centre`` and semi-axes ``organ_axes`` along the texture
    #: frame's axes (mm, :data:`ORGAN_MARGIN`); None: no organ. It takes precedence over the wall.
    organ_base: tuple[float, float, float] | None = None
    organ_centre: tuple[float, float, float] | None = None
    organ_axes: tuple[float, float, float] | None = None
    #: Waves of the wet film's thickness field (unit RMS) and the standard deviation of the log of
    #: the film's roughness over it (0: a uniform film).
    film_k: np.ndarray | None = None
    film_phase: np.ndarray | None = None
    film_variation: float = 0.0
    #: (2, 3) orthonormal in-surface axes (texture frame) of a plane: ``(u, v) = (e1 . q, e2 . q)``;
    #: None: the triplanar projection (:func:`surface_uv`).
    uv_axes: np.ndarray | None = None
    #: (M,) weight of each relief wave's slope in the diffuse light's normal (:func:`tissue_params`'s
    #: ``subsurface_mm``); None: the diffuse light takes the shading normal (every weight 1).
    relief_diffuse: np.ndarray | None = None
    #: The film's ``L^4 = l_s h_0^3``, mm^4 (0: no levelling) and the log-SD of its thickness.
    film_level4: float = 0.0
    film_thickness_spread: float = 0.0


def with_neighbours(t: TissueParams, wall=(None, None, None), organ=(None, None, None)) -> TissueParams:
    """``t`` with a wall's tissue and a neighbouring organ's (their default albedos).

    ``wall``: (tissue name, centre mm, radius mm), the second tissue at the points at least that
    far from the centre; ``organ``: (tissue name, centre mm, semi-axes mm), the third tissue inside
    that ellipsoid (:attr:`TissueParams.organ_base`). A name None leaves that part out.
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

    Wavelengths are stratified log-uniform over [min_mm, max_mm] (one per equal share of
    log-wavenumber, jittered within it), amplitudes ``~ lambda^hurst`` scaled so that the RMS
    height of the sum, ``sqrt(sum a^2 / 2)``, is ``relief_mm``.
    """
    d = _directions(rng, n)
    u = (np.arange(n) + rng.uniform(0.0, 1.0, size=n)) / n
    lam = min_mm * (max_mm / min_mm) ** u
    phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
    w = lam ** float(hurst)
    amp = relief_mm * w / math.sqrt(float(np.sum(w * w)) / 2.0)
    return d * (2.0 * math.pi / lam)[:, None], phase, amp


def tissue_params(kind: str, seed: int, relief_mm: float, relief_scale_mm: float,
                  vessel_scale_mm: float = 4.0, *, relief_min_mm: float | None = None,
                  relief_hurst: float = RELIEF_HURST,
                  base: tuple[float, float, float] | None = None,
                  film_variation: float = 0.0, film_scale_mm: float = 2.0,
                  subsurface_mm: float = 0.0, film_thickness_mm: float = 0.0, film_thickness_spread: float = 0.0,
                  ) -> TissueParams:
    """Draw a tissue texture (texture frame) from ``SeedSequence([seed, TISSUE_SEED_KEY])``.

    Parameters
    ----------
    kind : {"mucosa", "liver"}
    seed : int
        Texture seed.
    relief_mm : float
        RMS height of the micro-relief, mm (0: smooth).
    relief_scale_mm : float
        Longest wavelength of the micro-relief spectrum, mm.
    vessel_scale_mm : float
        A third of the colour variation's typical wavelength, mm. (The vessels are
        :data:`simtest.render.vessels.VESSEL_LAYERS`, grown from ``seed``.)
    relief_min_mm : float, optional
        Shortest wavelength of the micro-relief, mm; default ``min(RELIEF_MIN_MM, relief_scale_mm)``.
    relief_hurst : float
        Hurst exponent H of the relief spectrum, amplitudes ``~ lambda^H``.
    base : (float, float, float), optional
        Linear-RGB base albedo; default ``TISSUE_ALBEDO[kind]``. The seeded pattern does not
        depend on it.
    film_variation : float
        Standard deviation of the log of the wet film's roughness over the surface (0: uniform;
        :func:`film_alpha`).
    film_scale_mm : float
        Typical wavelength of the film's thickness field, mm.
    subsurface_mm : float
        Diffusion length ``l`` of the diffuse light, mm (0: it takes the shading normal). It leaves
        the tissue after a lateral walk of about ``l``, which averages the irradiance a relief wave
        of wavelength ``lambda`` modulates: the diffuse normal keeps ``1 / (1 + (2 pi l /
        lambda)^2)`` of its slope (a Lorentzian point spread, the diffusion approximation's
        low-pass; Cuccia et al. 2009, https://doi.org/10.1117/1.3088140).
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
        Waves of the texture frame.
    cam_to_texture : ndarray of shape (4, 4)
        Rigid map ``q = A p + b`` from camera-frame points ``p`` to texture-frame points ``q``, mm
        (``A`` a rotation).

    Returns
    -------
    TissueParams
        ``t`` with :attr:`TissueParams.frame` set: :func:`albedo`, :func:`relief_height` and
        :func:`relief_normal` then take camera-frame points (and normals, returned in the camera
        frame) and evaluate the texture at ``q``: the albedo and relief of a surface point do not
        depend on the camera pose. The identity returns ``t`` unchanged (no frame).
    """
    m = np.asarray(cam_to_texture, dtype=np.float64)
    if np.array_equal(m, np.eye(4)):
        return dataclasses.replace(t, frame=None)
    return dataclasses.replace(t, frame=m.copy())


def _const(xp, x: float):
    """``x`` as the kernel's value: a Python float for numpy, an opaque Dr.Jit value (not baked
    into the compiled kernel) where ``xp`` offers ``const``."""
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
        s = s + xp.sin(p[0] * float(k[j, 0]) + p[1] * float(k[j, 1]) + p[2] * float(k[j, 2])
                       + float(phase[j]))
    return s * math.sqrt(2.0 / len(phase))


def _np_texture(tex: np.ndarray, s, r):
    """Bilinear lookup of ``tex`` (H, W, C) at texture coordinates ``(s, r)`` (the tile is [0, 1]^2,
    texel centres at ``(j + 0.5) / W``), repeated mirrored: Dr.Jit's ``Texture2f`` with linear
    filtering and ``WrapMode.Mirror``, in float64."""
    h, w = tex.shape[:2]
    s, r = np.broadcast_arrays(np.asarray(s, dtype=np.float64), np.asarray(r, dtype=np.float64))
    coords = np.stack([r.ravel() * h - 0.5, s.ravel() * w - 0.5])
    return tuple(map_coordinates(tex[..., c].astype(np.float64), coords, order=1, mode="reflect").reshape(s.shape)
                 for c in range(tex.shape[2]))


#: Offsets (mm) of the triplanar projections' (u, v) in the tile, so the three views of a point
#: show different parts of the network.
_TRIPLANAR_OFFSET_MM = ((0.0, 0.0), (TILE_MM / 3.0, 2.0 * TILE_MM / 3.0), (2.0 * TILE_MM / 3.0, TILE_MM / 3.0))


def surface_uv(xp, q, nq, t: TissueParams):
    """The surface's 2D coordinates (u, v), mm, at texture-frame points ``q``, and their weights.

    Returns a list of ``(weight, u, v)``: one term with weight 1 on a plane
    (:attr:`TissueParams.uv_axes`) or where no normal is given (the texture frame's (x, y)); else
    three, the projections along the texture frame's axes weighted by ``|n_i|^4 / sum_j |n_j|^4``
    of the texture-frame normal ``nq`` (triplanar mapping, module notes).
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
    return [(w[0] * inv, q[1] + ax, q[2] + ay), (w[1] * inv, q[2] + bx, q[0] + by),
            (w[2] * inv, q[0] + cx, q[1] + cy)]


def vessel_transmission(xp, q, nq, t: TissueParams):
    """Per-channel transmission (R, G, B) of the vessel networks at texture-frame points ``q``
    (normals ``nq`` or None; :func:`surface_uv`); 1 where :attr:`TissueParams.vessel_map` is None."""
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
    """Diffuse RGB albedo at surface points ``p`` = (x, y, z) arrays, mm (the camera frame with
    :func:`in_camera`, else the texture frame); the wall's tissue (:attr:`TissueParams.wall_base`)
    where the point is at least ``wall_radius`` from ``wall_centre``; the organ's
    (:attr:`TissueParams.organ_base`) inside its ellipsoid.

    ``n``: the surface normals at ``p`` (same frame), which the vessels' triplanar mapping weighs
    (:func:`surface_uv`); None: the texture frame's (x, y) projection (a plane's own axes where
    :attr:`TissueParams.uv_axes` is set, which need no normal).

    Returns a tuple of three arrays (R, G, B) in [0, 1].
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
    """Micro-relief height ``h(p) = sum_j a_j sin(k_j . p + phi_j)``, mm, at points ``p`` = (x, y, z)
    (the camera frame with :func:`in_camera`); given the unit normals ``n``, the wet film's surface:
    each wave levelled (:attr:`TissueParams.film_level4`, module notes)."""
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
    """Each relief wave's share ``exp(-(k_t L)^4)`` in the film's surface at texture-frame points
    ``q`` (module notes), ``k_t`` its wavenumber in the tangent plane of ``n``; None: no film."""
    if t.film_level4 <= 0.0 or n is None:
        return None
    nq = n if A is None else [A[i][0] * n[0] + A[i][1] * n[1] + A[i][2] * n[2] for i in range(3)]
    e = _const(xp, t.film_level4)
    if t.film_thickness_spread > 0.0:
        e = e * xp.exp(_const(xp, -3.0 * t.film_thickness_spread) * _field(xp, q, t.film_k, t.film_phase))
    kt2 = [float(k @ k) - (nq[0] * float(k[0]) + nq[1] * float(k[1]) + nq[2] * float(k[2])) ** 2 for k in t.relief_k]
    return [xp.exp(-(x * x) * e) for x in kt2]


def relief_normal(xp, p, n, t: TissueParams, *, diffuse: bool = False):
    """Shading normal with micro-relief: ``unit(n - (grad h - (grad h . n) n))``.

    ``p`` and ``n`` are (x, y, z) tuples of arrays (the camera frame with :func:`in_camera`, else
    the texture frame; ``n`` the unit macro normal); returns the unit shading normal in the same
    frame as a tuple, facing the same side as ``n``: that of the wet film's surface
    (:func:`relief_height` given ``n``). With ``diffuse``: the pair (shading
    normal, the diffuse light's normal: the tissue's own relief, unlevelled, with each wave's
    slope weighted by :attr:`TissueParams.relief_diffuse`; the shading normal itself where there
    is neither a weight nor a film).
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
    """The wet film's roughness at surface points ``p`` (the camera frame with :func:`in_camera`):
    ``alpha exp(v f(q))`` with ``f`` the film's thickness field (a unit-RMS sum of seeded plane
    waves of the texture frame, wavelengths about ``film_scale_mm``) and ``v`` =
    :attr:`TissueParams.film_variation`; ``alpha`` itself where ``v`` is 0.

    A thick film smooths the tissue's relief into a smoother mirror (small ``alpha``: glints
    small and bright), a thin one leaves it rough (broad, dim sheen): with ``v > 0`` a frame shows
    highlights of every size between the two, as real mucosa does, instead of one broad sheen
    beside point glints. Clipped to [0.002, 1].
    """
    if t.film_variation == 0.0 or t.film_k is None:
        return alpha
    q, _ = _to_texture(xp, p, t)
    f = _field(xp, q, t.film_k, t.film_phase)
    a = alpha * xp.exp(_const(xp, t.film_variation) * f)
    return xp.minimum(xp.maximum(a, 0.002), 1.0)


def _fresnel_dielectric(xp, cos_i, eta):
    """Unpolarised Fresnel reflectance of a dielectric (exact), ``cos_i`` in [0, 1], ``eta`` = n2/n1."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = xp.sqrt(xp.maximum(1.0 - sin2_t, 0.0))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def specular_lobe(xp, n, wi, wo, lobe: str, alpha: float, phong_n: float, ior: float, c: float):
    """Specular BRDF value of the wet film for unit vectors n (shading normal), wi (to the
    camera), wo (to the light), as (x, y, z) tuples of arrays; zero below the surface.

    ``lobe``: "beckmann", "ggx" (microfacet with Smith's G, Walter et al. 2007, eqs. 25-34) or
    "phong" (paper eq. 1 times the normal-incidence Fresnel). Scaled by ``c``.
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
    F = _fresnel_dielectric(xp, cos_ih, ior)
    val = c * F * D * g1(ci) * g1(co) / (4.0 * ci * co)
    return xp.where(ok, val, 0.0)
