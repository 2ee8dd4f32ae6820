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
