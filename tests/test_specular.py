"""The specular model: paper eqs. 1-3 and Propositions 1-2, checked numerically."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from simtest.specular import (
    endoscopic_isocurve,
    general_isocurve,
    isocurve_radii,
    isophote_radius,
    kappa_from_isovalue,
    phong_intensity,
    tau_from_isovalue,
)


@given(
    kappa=st.floats(0.01, 0.99),
    vz=st.floats(1.0, 2000.0),
    vx=st.floats(-100, 100),
    vy=st.floats(-100, 100),
    seed=st.integers(0, 1000),
)
@settings(max_examples=80, deadline=None)
def test_endoscopic_quartic_factorises_into_two_circles(kappa, vz, vx, vy, seed):
    # Prop. 1: E = kappa q+ q- with q+- = s - r+-^2 (the paper's E = q+ q-, up to kappa).
    rng = np.random.default_rng(seed)
    V = np.array([vx, vy, vz])
    p = rng.uniform(-3 * vz, 3 * vz, size=(20, 2)) + V[:2]
    r_p, r_m = isocurve_radii(kappa, vz)
    s = np.sum((p - V[:2]) ** 2, axis=1)
    E = endoscopic_isocurve(p, V, kappa)
    scale = kappa * (s + r_p**2) * (s + r_m**2)  # magnitude of the terms, for a relative check
    np.testing.assert_allclose(E / scale, kappa * (s - r_p**2) * (s - r_m**2) / scale, atol=1e-12)
    # and the endoscopic quartic is the general quartic with L = V (eq. 2 -> eq. 3)
    tau = np.sqrt(1 - kappa)
    G = general_isocurve(p, V, V, tau)
    np.testing.assert_allclose(G / scale, E / scale, atol=1e-12)


@given(kappa=st.floats(1e-4, 0.9999), vz=st.floats(0.1, 5000.0))
@settings(max_examples=80, deadline=None)
def test_radii_bracket_the_outer_ring(kappa, vz):
    r_p, r_m = isocurve_radii(kappa, vz)
    assert r_m < vz < r_p  # Prop. 2's proof: r- < |V_Z| < r+
    np.testing.assert_allclose(r_p * r_m, vz**2, rtol=1e-12)


@pytest.mark.parametrize("n", [5.0, 30.0, 50.0, 120.0])
@pytest.mark.parametrize("t", [0.02, 0.1, 0.5, 0.8])
def test_isophote_radius_matches_brute_force_search_of_intensity(n, t):
    # Prop. 2: the isophote I = t is the circle of radius r-. Find it by root search of eq. 1 along
    # a ray from the foot point (the intensity decreases monotonically inside the outer ring).
    vz = 1000.0
    V = np.array([0.0, 0.0, vz])
    theta = 0.7  # any direction: the isophote is a circle
    f = lambda r: phong_intensity([r * np.cos(theta), r * np.sin(theta)], V, V, n) - t  # noqa: E731
    r_search = brentq(f, 0.0, vz, xtol=1e-12, rtol=1e-14)
    np.testing.assert_allclose(isophote_radius(t, n, vz), r_search, rtol=1e-9)


def test_phong_intensity_peaks_at_the_foot_and_is_radial():
    V = np.array([5.0, -3.0, 100.0])
    assert phong_intensity(V[:2], V, V, 50) == pytest.approx(1.0)
    ang = np.linspace(0, 2 * np.pi, 12)
    ring = V[:2] + 20 * np.c_[np.cos(ang), np.sin(ang)]
    vals = phong_intensity(ring, V, V, 50, c=2.0)
    np.testing.assert_allclose(vals, vals[0], rtol=1e-12)
    assert 0 < vals[0] < 2.0


def test_phong_intensity_general_light_peaks_at_mirror_point():
    V = np.array([0.0, 0.0, 100.0])
    L = np.array([60.0, 0.0, 100.0])
    # mirror point between V and L at equal heights: the midpoint's foot (30, 0)
    xs = np.linspace(0, 60, 6001)
    vals = phong_intensity(np.c_[xs, np.zeros_like(xs)], V, L, 80)
    assert xs[np.argmax(vals)] == pytest.approx(30.0, abs=0.02)


@pytest.mark.parametrize(("t", "n", "c"), [(0.0, 50, 1), (1.5, 50, 1), (-0.1, 50, 1), (0.1, 0, 1), (0.1, 50, -1)])
def test_bad_parameters_are_refused(t, n, c):
    with pytest.raises(ValueError):
        tau_from_isovalue(t, n, c)


def test_kappa_limits():
    assert kappa_from_isovalue(1.0, 50) == 0.0
    with pytest.raises(ValueError, match="kappa"):
        isophote_radius(1.0, 50, 100)  # t = c: the isophote is the BP itself, kappa = 0
    with pytest.raises(ValueError):
        phong_intensity([0, 0], [0, 0, 1], [0, 0, 1], n=-2)


@given(seed=st.integers(0, 2**32 - 1), n=st.floats(1.0, 500.0), flat=st.booleans())
@settings(max_examples=30, deadline=None)
def test_phong_intensity_is_the_vector_formula_bit_for_bit(seed, n, flat):
    # phong_intensity works per coordinate plane for speed; it must give exactly the bits of
    # the (..., 3)-array formula c max(0, (V - P).(P - R) / (|V - P| |P - R|))^n.
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(20, 30, 3)) * rng.uniform(1.0, 500.0)
    if flat:
        P[..., 2] = 0.0
    V = rng.normal(size=3) * 100.0
    L = rng.normal(size=3) * 100.0
    V[2], L[2] = abs(V[2]) + 1.0, abs(L[2]) + 1.0
    R = np.array([L[0], L[1], -L[2]])
    to_v, refl = V - P, P - R
    cos_b = np.sum(to_v * refl, axis=-1) / (np.linalg.norm(to_v, axis=-1) * np.linalg.norm(refl, axis=-1))
    assert np.array_equal(phong_intensity(P, V, L, n, 0.7), 0.7 * np.maximum(cos_b, 0.0) ** n)
    if flat:  # points given as (x, y) on the plane z = 0: the same bits
        assert np.array_equal(phong_intensity(P[..., :2], V, L, n, 0.7), 0.7 * np.maximum(cos_b, 0.0) ** n)


@given(seed=st.integers(0, 2**32 - 1), on_plane=st.booleans())
@settings(max_examples=60, deadline=None)
def test_cos_beta_of_plane_points_is_that_of_their_3d_form(seed, on_plane):
    # points on an integer grid, the viewer's and the light's feet among them: zero products and
    # sums (signed zeros); (x, y) and (x, y, 0) give the same bits, and a viewer on the plane gives
    # a zero length at its foot (NaN)
    from simtest.specular.phong import _cos_beta, _mirror

    rng = np.random.default_rng(seed)
    P = rng.integers(-6, 7, size=(40, 2)).astype(np.float64)
    V = rng.integers(-6, 7, size=3).astype(np.float64)
    L = rng.integers(-6, 7, size=3).astype(np.float64)
    V[2] = 0.0 if on_plane else abs(V[2]) + 1.0
    L[2] = abs(L[2]) + 1.0
    P[:2] = [V[:2], L[:2]]
    R = _mirror(L)
    with np.errstate(all="ignore"):
        want = _cos_beta(np.column_stack([P, np.zeros(len(P))]), V, R)
        got = _cos_beta(P, V, R)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))
    assert np.isnan(got[0]) == on_plane


@given(seed=st.integers(0, 2**32 - 1), n=st.floats(1.0, 500.0), c=st.sampled_from([1.0, 0.7]),
       integer=st.booleans())
@settings(max_examples=60, deadline=None)
def test_the_intensity_at_offsets_from_an_origin_is_that_at_the_points(seed, n, c, integer):
    # the paper protocol passes its fixed grid of offsets and the window centre instead of the
    # points: the same bits as the points offsets + origin built by numpy, signed zeros and the
    # NaN of a viewer on the plane included (integer grids hit the viewer's and light's feet)
    rng = np.random.default_rng(seed)
    if integer:
        off = rng.integers(-6, 7, size=(7, 9, 2)).astype(np.float64)
        origin = rng.integers(-3, 4, size=2).astype(np.float64)
        V = rng.integers(-6, 7, size=3).astype(np.float64)
        L = rng.integers(-6, 7, size=3).astype(np.float64)
        V[2], L[2] = float(rng.integers(0, 3)), abs(L[2]) + 1.0
    else:
        off = rng.normal(size=(7, 9, 2)) * rng.uniform(1.0, 300.0)
        origin = rng.normal(size=2) * 50.0
        V, L = rng.normal(size=3) * 100.0, rng.normal(size=3) * 100.0
        V[2], L[2] = abs(V[2]) + 1.0, abs(L[2]) + 1.0
    with np.errstate(all="ignore"):
        want = phong_intensity(off + origin, V, L, n, c)
        got = phong_intensity(off, V, L, n, c, origin=origin)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))


def test_one_point_gives_a_scalar_and_offsets_need_two_coordinates():
    assert np.ndim(phong_intensity([1.0, 2.0], [0, 0, 5], [0, 0, 5], 10)) == 0
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        phong_intensity(np.zeros((3, 3)), [0, 0, 5], [0, 0, 5], 10, origin=(0.0, 0.0))
