"""Procedural tissue: seeded RGB albedo with vessel-like patterns, micro-relief and a wet specular film.

Everything here is a closed-form function of the surface point ``p`` (camera frame, mm), written
once for numpy and Dr.Jit alike (the ``xp`` argument: ``numpy`` or ``drjit``), so the renderer
shades with it in Mitsuba's wavefront and the ground truth evaluates the very same function per
pixel in float64:

- **Albedo** (diffuse RGB): a base colour per tissue (:data:`TISSUE_ALBEDO`) times a smooth
  colour variation, darkened along vessel-like lines: the zero set of a smooth random field
  ``g(p)`` (a sum of seeded plane waves), drawn as ``exp(-(g / w)^2)`` with a thin ``w``, which
  gives branching, meandering curves like the submucosal vessels seen through mucosa.
- **Micro-relief**: a height field ``h(p) = A sum_k a_k sin(k_k . p + phi_k)`` (seeded directions,
  wavelengths between half and twice ``relief_scale_mm``, 0.05 to 1 mm) that tilts the shading
  normal: ``n_s = unit(n - (grad h - (grad h . n) n))`` (the bump mapping of Blinn 1978,
  https://doi.org/10.1145/965139.507101, on the tangent plane of the macro normal ``n``).
- **Specular film**: a dielectric interface (IOR 1.33 to 1.45, water to mucus) with Fresnel's
  reflectance over a rough microfacet lobe, Beckmann or GGX (Walter et al. 2007,
  https://doi.org/10.2312/EGWR/EGSR07/195-206), ``f_s = F(wi . m) D(m) G(wi, wo) / (4 cos_i
  cos_o)`` about the half-vector m of the shading normal; or the paper's exact Phong lobe
  ``c cos(beta)^n`` (eq. 1) scaled by Fresnel at normal incidence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TISSUE_ALBEDO", "TISSUE_SEED_KEY", "TissueParams", "tissue_params", "albedo", "relief_height",
           "relief_normal", "specular_lobe"]

#: Linear-RGB diffuse albedo of each tissue before variation. Mucosa: pink (sRGB about (225, 140,
#: 125), the colour of a bowel wall under white light); liver: red-brown (sRGB about (150, 60, 45)).
#: Assumed values chosen to match the colour of endoscopic frames, not measured reflectances.
TISSUE_ALBEDO = {"mucosa": (0.75, 0.26, 0.20), "liver": (0.30, 0.045, 0.026)}

#: Stable key of the tissue texture stream in ``SeedSequence([seed, TISSUE_SEED_KEY])``.
TISSUE_SEED_KEY = 0x7155E

#: Plane waves in each procedural field.
N_WAVES = 12


@dataclass(frozen=True)
class TissueParams:
    """Seeded parameters of one tissue texture (arrays of plane waves, camera-frame mm)."""

    base: tuple[float, float, float]
    colour_k: np.ndarray  # (N, 3) wave vectors, rad/mm
    colour_phase: np.ndarray  # (N,)
    vessel_k: np.ndarray
    vessel_phase: np.ndarray
    vessel_width: float
    relief_k: np.ndarray
    relief_phase: np.ndarray
    relief_amp: np.ndarray  # (N,) mm, sums to the relief amplitude over sqrt(N)


def _waves(rng: np.random.Generator, wavelength_mm: float, n: int = N_WAVES):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lam = wavelength_mm * np.exp(rng.uniform(math.log(0.5), math.log(2.0), size=n))
    return d * (2.0 * math.pi / lam)[:, None], rng.uniform(0.0, 2.0 * math.pi, size=n)


def tissue_params(kind: str, seed: int, relief_mm: float, relief_scale_mm: float,
                  vessel_scale_mm: float = 4.0) -> TissueParams:
    """Draw a tissue texture from ``SeedSequence([seed, TISSUE_SEED_KEY])``.

    Parameters
    ----------
    kind : {"mucosa", "liver"}
    seed : int
        Texture seed.
    relief_mm : float
        RMS height of the micro-relief, mm (0: smooth).
    relief_scale_mm : float
        Typical wavelength of the micro-relief, mm.
    vessel_scale_mm : float
        Typical spacing of the vessel pattern, mm.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), TISSUE_SEED_KEY]))
    ck, cp = _waves(rng, 3.0 * vessel_scale_mm)
    vk, vp = _waves(rng, vessel_scale_mm)
    rk, rp = _waves(rng, relief_scale_mm)
    amp = np.full(N_WAVES, relief_mm * math.sqrt(2.0 / N_WAVES))  # RMS of the sum = relief_mm
    width = 0.06 if kind == "mucosa" else 0.03
    return TissueParams(TISSUE_ALBEDO[kind], ck, cp, vk, vp, width, rk, rp, amp)


def _field(xp, p, k, phase):
    """sum_j sin(k_j . p + phase_j) / sqrt(N / 2) (unit RMS) and, for ``grad``, its gradient."""
    s = 0.0
    for j in range(len(phase)):
        s = s + xp.sin(p[0] * float(k[j, 0]) + p[1] * float(k[j, 1]) + p[2] * float(k[j, 2])
                       + float(phase[j]))
    return s * math.sqrt(2.0 / len(phase))


def albedo(xp, p, t: TissueParams):
    """Diffuse RGB albedo at surface points ``p`` = (x, y, z) arrays (camera frame, mm).

    Returns a tuple of three arrays (R, G, B) in [0, 1].
    """
    var = _field(xp, p, t.colour_k, t.colour_phase)  # smooth, unit RMS
    g = _field(xp, p, t.vessel_k, t.vessel_phase)
    vessel = xp.exp(-(g * g) / (t.vessel_width * t.vessel_width))
    # Vessels absorb green and blue more than red (haemoglobin): darker and redder lines.
    absorb = (0.25, 0.55, 0.45)
    out = []
    for c in range(3):
        a = t.base[c] * (1.0 + 0.12 * var) * (1.0 - absorb[c] * vessel)
        out.append(xp.minimum(xp.maximum(a, 0.0), 1.0))
    return tuple(out)


def relief_height(xp, p, t: TissueParams):
    """Micro-relief height ``h(p) = sum_k a_k sin(k_k . p + phi_k)``, mm, at points ``p`` = (x, y, z)."""
    h = 0.0
    for j in range(len(t.relief_phase)):
        k = t.relief_k[j]
        h = h + float(t.relief_amp[j]) * xp.sin(p[0] * float(k[0]) + p[1] * float(k[1]) + p[2] * float(k[2])
                                                + float(t.relief_phase[j]))
    return h


def relief_normal(xp, p, n, t: TissueParams):
    """Shading normal with micro-relief: ``unit(n - (grad h - (grad h . n) n))``.

    ``p`` and ``n`` are (x, y, z) tuples of arrays (camera frame; ``n`` the unit macro normal);
    returns the unit shading normal as a tuple, facing the same side as ``n``.
    """
    gx = gy = gz = 0.0
    for j in range(len(t.relief_phase)):
        k = t.relief_k[j]
        c = float(t.relief_amp[j]) * xp.cos(p[0] * float(k[0]) + p[1] * float(k[1]) + p[2] * float(k[2])
                                            + float(t.relief_phase[j]))
        gx, gy, gz = gx + c * float(k[0]), gy + c * float(k[1]), gz + c * float(k[2])
    gn = gx * n[0] + gy * n[1] + gz * n[2]
    sx, sy, sz = n[0] - (gx - gn * n[0]), n[1] - (gy - gn * n[1]), n[2] - (gz - gn * n[2])
    inv = 1.0 / xp.sqrt(sx * sx + sy * sy + sz * sz)
    return sx * inv, sy * inv, sz * inv


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
