"""The light-aware model's per-ray terms (``lightaware.model._terms``, ``_ggx_lobe``) against geometry.

``_terms`` forms cos beta of one light on a plane along each ray from a few scalars per ray (its
Notes), and its derivatives in closed form; ``_ggx_lobe`` forms the film's GGX lobe from the same
pieces. Here they are checked against the vectors themselves: the plane point ``X = s d`` on the
plane (n, h), the unit directions to the light and to the camera, ``cos beta = 2 (n . l)(n . v) -
l . v``, the half-vector's GGX distribution, Smith's masking and Fresnel's factor, and the
derivatives against central differences.
"""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.reconstruct import lightaware as la

#: Relative agreement of the closed forms with the vector forms: both round at ~1e-16 per
#: operation on well-conditioned rays (the plane seen at more than 6 deg from edge-on, the light
#: more than 1e-3 of its range off the ray); 1e-9 leaves a wide margin.
REL = 1e-9


def _case(seed: int):
    rng = np.random.default_rng(np.random.SeedSequence([151, seed]))
    n0 = np.array([0.0, 0.0, -1.0]) + 0.3 * rng.standard_normal(3)
    n0 /= np.linalg.norm(n0)
    N = int(rng.integers(1, 200))
    d = rng.standard_normal((3, N)) * 0.3
    d[2] = 1.0
    dT = d / np.linalg.norm(d, axis=0)
    keep = (-n0) @ dT > 0.1  # the plane seen at more than ~6 deg from edge-on
    dT = np.ascontiguousarray(dT[:, keep] if keep.any() else -n0[:, None])
    h = float(np.exp(rng.uniform(0.0, 5.0)))  # 1 mm to 15 cm
    L = rng.standard_normal(3) * rng.choice([0.0, 1.0, 10.0])
    e1, e2 = rng.standard_normal(3), rng.standard_normal(3)
    return rng, dT, n0, h, L, e1, e2


def _vectors(dT, n, h, L):
    """The unit directions to the light and to the camera at the plane points along the rays."""
    s = h / ((-n) @ dT)
    X = s * dT
    to_l = L[:, None] - X
    l = to_l / np.linalg.norm(to_l, axis=0)
    v = -dT
    return l, v


@given(st.integers(0, 1_000_000))
@example(345)  # a ray that meets the plane behind the camera
@example(17095)  # a ray 2e-6 from edge-on
@settings(max_examples=100, deadline=None)
def test_cos_beta_and_its_derivatives_are_those_of_the_vectors(seed):
    rng, dT, n0, h, L, e1, e2 = _case(seed)
    p = rng.standard_normal(2) * 0.05
    n, dns = la.model._normal_derivs(p, n0, e1, e2)
    rl = la.model._ray_light(L, dT)
    cb, delta, s, sl, ir, c, dcb = la.model._terms(dT, n, h, L, rl, dns=dns)
    l, v = _vectors(dT, n, h, L)
    off = np.linalg.norm(np.cross(L, dT.T), axis=1) > 1e-3 * np.linalg.norm(L - (h / delta)[:, None] * dT.T, axis=1)
    want = 2.0 * (n @ l) * (n @ v) - np.einsum("in,in->n", l, v)
    scale = np.abs(want) + 1.0
    # a ray that meets the plane behind the camera or edge-on (1 in ~1000 of the seeds' rays)
    # sits at the model's floor of delta, 1e-9: it sees no point of the plane, so no cos beta
    front = (-n) @ dT > 1e-9
    seen = (off | ~np.any(L)) & front
    assert np.all(np.abs(cb - want)[seen] <= REL * scale[seen])
    assert np.allclose(delta[front], ((-n) @ dT)[front], rtol=1e-15) and np.all(delta[~front] == 1e-9)
    assert np.allclose(s * delta, h, rtol=1e-14)
    assert np.allclose(1.0 / ir, np.linalg.norm(L[:, None] - s * dT, axis=0), rtol=1e-12)
    # derivatives in (a, b, log h): central differences, step 1e-5 (truncation ~1e-10, rounding
    # ~1e-11 of a cos beta of order 1): agree to 1e-6, on rays whose delta stays far above the
    # step's change of it (|d delta / d(a, b)| <= 1, n being unit): a ray within 1e-3 of edge-on
    # is stepped through delta's floor, where the difference is no derivative (seed 17095)
    step = 1e-5
    smooth = delta > 100 * step
    for i in range(3):
        cbs = []
        for sign in (1.0, -1.0):
            q = p.copy()
            hh = h
            if i < 2:
                q[i] += sign * step
            else:
                hh = h * np.exp(sign * step)
            nq, _ = la.model._normal_derivs(q, n0, e1, e2)
            cbs.append(la.model._terms(dT, nq, hh, L, rl)[0])
        fd = (cbs[0] - cbs[1]) / (2 * step)
        assert np.allclose(dcb[i][smooth], fd[smooth], rtol=1e-6, atol=1e-6), i


def test_an_edge_on_plane_gives_a_zero_inverse_range_not_a_warning():
    # delta at its floor: s^2 overflows and 1 / r is 0, silently
    dT = np.array([[1.0], [0.0], [0.0]])
    n = np.array([0.0, 0.0, -1.0])
    L = np.zeros(3)
    rl = la.model._ray_light(L, dT)
    with np.errstate(all="raise"):
        got = la.model._terms(dT, n, 1e146, L, rl)  # s = 1e155 mm: s^2 overflows
    assert got[2][0] > 1e154 and got[4][0] == 0.0


@given(st.integers(0, 1_000_000), st.floats(1e-2, 1.0), st.floats(1.2, 2.0))
@settings(max_examples=100, deadline=None)
def test_the_ggx_lobe_is_walters_with_the_films_fresnel(seed, alpha, ior):
    # F(v . m) D(m) G1(v) G1(l) / (4 n . v) from the vectors (Walter et al. 2007, eqs. 25-34), 0
    # where the light is below the plane
    _, dT, n, h, L, _, _ = _case(seed)
    rl = la.model._ray_light(L, dT)
    _, delta, s, sl, ir, c, _ = la.model._terms(dT, n, h, L, rl)
    a2 = alpha * alpha
    got = la.model._ggx_lobe(delta, s, sl, ir, c, a2, ior)
    l, v = _vectors(dT, n, h, L)
    hv = l + v
    m = hv / np.linalg.norm(hv, axis=0)
    nm, nv, nl, vm = n @ m, n @ v, n @ l, np.einsum("in,in->n", v, m)
    D = a2 / (np.pi * (nm * nm * (a2 - 1.0) + 1.0) ** 2)

    def g1(x):
        return 2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - x * x) / (x * x)))

    cos_t = np.sqrt(np.maximum(1.0 - (1.0 - vm * vm) / (ior * ior), 0.0))
    rs = (vm - ior * cos_t) / (vm + ior * cos_t)
    rp = (ior * vm - cos_t) / (ior * vm + cos_t)
    F = 0.5 * (rs * rs + rp * rp)
    with np.errstate(invalid="ignore", divide="ignore"):
        want = np.where(nl > 0.0, F * D * g1(nv) * g1(np.maximum(nl, 1e-6)) / (4.0 * nv), 0.0)
    lit = nl > 1e-3  # away from the floors of the grazing light
    assert np.allclose(got[lit], want[lit], rtol=1e-8, atol=1e-12 * np.abs(want[lit]).max(initial=0.0))
    assert np.all(got[nl <= 0.0] == 0.0)
