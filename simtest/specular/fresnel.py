"""Fresnel's reflectance of the wet film: what the renderer's GGX lobe and the light-aware fits' share."""

from __future__ import annotations

import numpy as np

__all__ = ["fresnel_dielectric"]


def fresnel_dielectric(cos_i, eta, xp=np):
    """Unpolarised Fresnel reflectance of a dielectric interface, exact: ``(rs^2 + rp^2) / 2`` (the Fresnel
    formulae: M. Born, E. Wolf, "Principles of Optics", 7th ed., section 1.5.2).

    Parameters
    ----------
    cos_i : array_like
        Cosine of the angle of incidence (to the interface's or microfacet's normal), in [0, 1].
    eta : float
        Relative index of refraction n2 / n1 (the film's, from air).
    xp : module
        The array module of ``cos_i`` (numpy, or Dr.Jit's in the renderer); its ``sqrt`` and ``maximum``.

    Returns
    -------
    array_like
        The reflectance in [0, 1], the shape of ``cos_i``; total internal reflection gives 1.
    """
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = xp.sqrt(xp.maximum(1.0 - sin2_t, 0.0))
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)
