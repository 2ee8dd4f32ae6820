"""The light-aware model's compiled pass (simtest.reconstruct._lightaware_kernels) against numpy.

``lightaware.model._terms`` hands the element-by-element arithmetic of cos beta and its derivatives to
one compiled pass; its numpy form (``lightaware.model._terms_numpy``) stays as the reference. The pass
takes the same operations in the same order on the same BLAS products, so every output must be
the same bits, on rays of any direction (head-on, grazing, behind the plane), planes near and
far, lights on the camera centre and far off it, and non-finite light terms.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct import lightaware as la


def _case(seed: int):
    rng = np.random.default_rng(np.random.SeedSequence([151, seed]))
    N = int(rng.integers(0, 300))
    d = rng.standard_normal((3, N))
    d[2] = np.abs(d[2]) + rng.choice([0.0, 1e-12, 0.5])  # grazing rays among them
    dT = np.ascontiguousarray(d / np.linalg.norm(d, axis=0))
    n = rng.standard_normal(3)
    n = np.array([0.0, 0.0, -1.0]) if seed % 5 == 0 else n / np.linalg.norm(n)  # head-on or any
    h = float(np.exp(rng.uniform(-3.0, 8.0)))  # 0.05 mm to 3 m
    L = rng.standard_normal(3) * rng.choice([0.0, 1.0, 10.0, 1e3])
    rl = la.model._ray_light(L, dT)
    if seed % 7 == 0:
        rl = (rl[0] * np.nan, rl[1])
    nn, dns = la.model._normal_derivs(rng.standard_normal(2) * 0.1, n, rng.standard_normal(3), rng.standard_normal(3))
    return dT, nn, h, L, rl, dns


@given(st.integers(0, 1_000_000))
@settings(max_examples=200, deadline=None)
def test_the_compiled_pass_gives_the_numpy_forms_bits(seed):
    dT, n, h, L, rl, dns = _case(seed)
    P = np.array(dns) @ dT
    for args in ((dT, n, h, L, rl), (dT, n, h, L, rl, None, dns), (dT, n, h, L, rl, P, dns)):
        got = la.model._terms(*args)
        with np.errstate(invalid="ignore"):  # the numpy form warns on the non-finite cases
            want = la.model._terms_numpy(*args)
        assert len(got) == len(want) == 7
        for g, w in zip(got, want):
            if w is None:
                assert g is None
            else:
                g, w = np.asarray(g), np.asarray(w)
                assert g.shape == w.shape and np.array_equal(g, w, equal_nan=True)
                assert np.array_equal(np.signbit(g), np.signbit(w))


def test_an_edge_on_plane_gives_a_zero_inverse_range_not_a_warning():
    # delta at its floor: s^2 overflows and 1 / r is 0 in both forms, silently
    dT = np.array([[1.0], [0.0], [0.0]])
    n = np.array([0.0, 0.0, -1.0])
    L = np.zeros(3)
    rl = la.model._ray_light(L, dT)
    with np.errstate(all="raise"):
        got = la.model._terms(dT, n, 1e146, L, rl)  # s = 1e155 mm: s^2 overflows
        want = la.model._terms_numpy(dT, n, 1e146, L, rl)
    assert got[2][0] == want[2][0] > 1e154 and got[4][0] == want[4][0] == 0.0


@given(st.integers(0, 1_000_000), st.floats(1e-3, 1.0), st.floats(1.0, 2.0))
@settings(max_examples=200, deadline=None)
def test_the_compiled_ggx_lobe_gives_the_numpy_forms_bits(seed, alpha, ior):
    # the rig's GGX lobes under the film (lightaware.model._rig_value_ggx) against their numpy
    # form, on the rays, planes and lights of _case: two lights (one inverse square with a
    # profile, one neither), rays behind the plane and non-finite light terms among them
    dT, n, h, L, _, _ = _case(seed)
    Ls = np.array([L, -0.5 * L + 1.0])
    arr = (Ls, np.array([1.0, 0.7]), np.array([True, False]), np.array([1.5, 0.0]))
    rl = la.model._ray_light(Ls, dT)
    if seed % 7 == 0:
        rl = (rl[0] * np.nan, rl[1])
    with np.errstate(all="ignore"):  # the numpy form warns on the non-finite cases
        want = la.model._rig_value_ggx_numpy(dT, rl, n, h, arr, alpha, ior)
        got = la.model._rig_value_ggx(dT, rl, n, h, arr, alpha, ior)
    assert got.shape == want.shape and np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))
