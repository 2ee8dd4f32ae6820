"""Compiled (numba) kernel of the light-aware plane model (:mod:`simtest.reconstruct.lightaware`).

:func:`cos_beta_terms` does, in one compiled pass over the rays, the element-by-element arithmetic
of ``lightaware.model._terms``: cos beta of one light on a plane along each ray, the pieces the rig's
lobes are built from, and its derivatives with respect to the plane's parameters. The numpy form
took some thirty array operations per evaluation on a few hundred isophote points, each costing
more in its call than in its arithmetic; :func:`~simtest.reconstruct.lightaware.isocurve_fit`
evaluates the model about ten times per highlight.

The products that sum over the three coordinates (``n . d`` per ray, the normal's derivatives
along the rays, ``n . L``) stay numpy's (BLAS; ``lightaware.model._terms`` computes them and hands
them over), and the kernel takes the same element-by-element operations in the same order as
the numpy form: multiplications, divisions and square roots are correctly rounded whatever the
vector width, and no ``a * b + c`` is contracted into a fused multiply-add (no ``fastmath``), so
the results are the same bits (``tests/test_lightaware_kernels.py`` checks them against the numpy
form, which stays in ``lightaware/model.py`` as the reference). Compiled with ``cache=True``, as
:mod:`simtest.reconstruct._kernels`.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _maximum(a, b):
    """``np.maximum(a, b)`` of two floats: NaN in ``a`` propagates (``b`` is a finite floor)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, nogil=True)
def cos_beta_terms(nd, h, c, Ld, K2, P, dnL, cb, delta, s, sl, ir, dcb):
    """cos beta of one light on the plane (n, h) along unit rays, and its derivatives.

    Parameters
    ----------
    nd : ndarray of shape (N,), float64
        ``(-n) @ dT``: minus the cosine of each unit ray with the plane normal n (camera frame).
    h : float
        The plane's distance from the camera centre, mm.
    c : float
        ``n . L + h`` for the light L (mm).
    Ld, K2 : ndarray of shape (N,), float64
        ``L . d`` and ``|L|^2 - (L . d)^2`` per ray (``lightaware.model._ray_light``), mm and mm^2.
    P : ndarray of shape (2, N), float64, or None
        ``[dn_a, dn_b] @ dT``: the normal's derivatives along the rays; None: no derivatives.
    dnL : ndarray of shape (2,), float64
        ``dn_a . L`` and ``dn_b . L`` (read only with ``P``).
    cb, delta, s, sl, ir : ndarray of shape (N,), float64
        Outputs: cos beta, ``delta = max(-n . d, 1e-9)``, the plane point's range ``s = h /
        delta`` (mm), ``s - Ld`` (mm) and ``1 / r`` with ``r = |L - s d|`` (1/mm).
    dcb : ndarray of shape (3, N), float64
        Output with ``P``: the derivatives of cos beta with respect to (a, b, log h).

    Notes
    -----
    The formulas and their derivation: ``lightaware.model._terms``. ``1 / r`` is 0 where ``(s - Ld)^2``
    overflows (a plane seen edge-on), as in the numpy form.
    """
    for i in range(nd.shape[0]):
        de = _maximum(nd[i], 1e-9)
        si = h / de
        sli = si - Ld[i]
        iri = 1.0 / math.sqrt(_maximum(sli * sli + K2[i], 1e-300))
        cbi = (2.0 * c * de - sli) * iri
        cb[i], delta[i], s[i], sl[i], ir[i] = cbi, de, si, sli, iri
        if P is not None:  # pruned at compile time for P = None
            qs = (1.0 + cbi * sli * iri) * si
            t = 2.0 * de * iri
            u = (2.0 * c + qs / de) * iri
            dcb[0, i] = t * dnL[0] - P[0, i] * u
            dcb[1, i] = t * dnL[1] - P[1, i] * u
            dcb[2, i] = t * h - qs * iri


@numba.njit(cache=True, nogil=True)
def _clip(x, lo, hi):
    """``np.clip(x, lo, hi)`` of a float: NaN propagates."""
    if x != x:
        return x
    return hi if x > hi else (lo if x < lo else x)


@numba.njit(cache=True, nogil=True)
def ggx_film_lobe(delta, s, sl, ir, c, a2, eta, out):
    """One light's GGX lobe under a dielectric film along each ray, before falloff and profile.

    The element-by-element arithmetic of ``lightaware.model._rig_value_ggx_numpy`` for one light
    (Walter et al. 2007, eqs. 25-34, doi:10.2312/EGWR/EGSR07/195-206, with Smith's G1 and the
    exact dielectric Fresnel factor): ``F(v . m) D(m) G1(v) G1(l) / (4 n . v)``, 0 where the light
    or the camera is below the plane.

    Parameters
    ----------
    delta, s, sl, ir : ndarray of shape (N,), float64
        ``cos_beta_terms``' outputs: ``-d . n`` (floored at 1e-9), the plane point's range (mm),
        ``s - L . d`` (mm) and ``1 / r`` (1/mm).
    c : float
        ``n . L + h`` for the light L (mm).
    a2 : float
        The GGX roughness squared, alpha^2.
    eta : float
        The film's refractive index.
    out : ndarray of shape (N,), float64
        Output.

    Notes
    -----
    The same operations in the same order as the numpy form, no fused multiply-add (no
    ``fastmath``): the same bits (``tests/test_lightaware_kernels.py``).
    """
    am1 = a2 - 1.0
    ee = eta * eta
    for i in range(delta.shape[0]):
        de = delta[i]
        cos_o = c * ir[i]
        vl = sl[i] * ir[i]
        hv = math.sqrt(_maximum(2.0 + 2.0 * vl, 1e-300))
        cos_h = _clip((de + cos_o) / hv, 1e-6, 1.0)
        c2 = cos_h * cos_h
        t = c2 * am1 + 1.0
        D = a2 / (math.pi * (t * t))
        ci = _maximum(de, 1e-6)
        co = _maximum(cos_o, 1e-6)
        g1i = 2.0 / (1.0 + math.sqrt(1.0 + a2 * (1.0 - ci * ci) / (ci * ci)))
        g1o = 2.0 / (1.0 + math.sqrt(1.0 + a2 * (1.0 - co * co) / (co * co)))
        cos_i = math.sqrt(_clip(0.5 * (1.0 + vl), 0.0, 1.0))
        sin2_t = (1.0 - cos_i * cos_i) / ee
        cos_t = math.sqrt(_maximum(1.0 - sin2_t, 0.0))
        rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        F = 0.5 * (rs * rs + rp * rp)
        v = F * D * g1i * g1o / (4.0 * ci)
        if cos_o <= 0.0 or de <= 1e-9:
            v = 0.0
        out[i] = v
