"""Direct least-squares ellipse fit (Halir-Flusser form): exactness, conditioning, failures."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import (
    Ellipse,
    angle_between_deg,
    circle_pose,
    conic_to_ellipse,
    normalised_conic,
    project_circle,
)
from simtest.reconstruct.fit import fit_ellipse, fit_ellipses
from exact_tolerances import EXACT

from _cases import ellipse_to_conic, random_circle_pose, sample_ellipse

K = np.array([[320.0, 0.0, 202.5], [0.0, 300.0, 190.5], [0.0, 0.0, 1.0]])


def ellipse_points(center, a, b, angle, n):
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(angle), np.sin(angle)
    x, y = a * np.cos(t), b * np.sin(t)
    return np.column_stack([center[0] + c * x - s * y, center[1] + s * x + c * y])


def angle_diff_mod_pi(a, b):
    d = (a - b) % np.pi
    return min(d, np.pi - d)


@given(
    cu=st.floats(-2000, 2000), cv=st.floats(-2000, 2000), a=st.floats(3, 800),
    ratio=st.floats(0.05, 0.95), angle=st.floats(0, np.pi), n=st.integers(6, 400),
)
@settings(max_examples=80, deadline=None)
def test_exact_points_give_the_ellipse(cu, cv, a, ratio, angle, n):
    b = a * ratio
    pts = ellipse_points((cu, cv), a, b, angle, n)
    fit = fit_ellipse(pts)
    assert fit, fit
    e = fit.ellipse
    # Exact points: the only error is float64 rounding through a conditioned 3x3 eigenproblem;
    # 1e-7 of the size (1e-4 px on an 800 px ellipse 2000 px from the origin) leaves a wide margin.
    assert np.allclose(e.center, (cu, cv), atol=1e-7 * (a + abs(cu) + abs(cv)))
    assert np.allclose(e.semi_axes, (a, b), rtol=1e-7)
    # the angle is defined only for an eccentric ellipse; ratio <= 0.95 keeps it well defined
    assert angle_diff_mod_pi(e.angle_rad, angle) < 1e-6
    # the conic is the exact one up to scale and sign
    C = ellipse_to_conic((cu, cv), (a, b), angle)
    C /= np.linalg.norm(C)
    assert min(np.linalg.norm(fit.conic - C), np.linalg.norm(fit.conic + C)) < 1e-7
    # every point lies on the fitted conic (Sampson residual in px, rounding only)
    assert fit.residual_px < 1e-6 * a
    assert fit.n_points == n


@given(st.integers(0, 10_000))
@settings(max_examples=40, deadline=None)
def test_fitted_points_of_an_imaged_circle_give_the_true_normal(seed):
    # Fit-level half of the exact-circle truth (the conic-level half is in test_geometry.py):
    # points sampled exactly on the image of a circle under a random pose, fitted, then
    # circle pose: one of N+ and N- is the true normal to EXACT.fitted_normal_deg.
    centre, normal, radius, rng = random_circle_pose(seed, key=42)
    C = project_circle(centre, normal, radius, K)
    ellipse = conic_to_ellipse(C)
    pts = sample_ellipse(ellipse, int(rng.integers(20, 400)))
    fit = fit_ellipse(pts)
    assert fit
    pose = circle_pose(normalised_conic(fit.conic, K))
    assert angle_between_deg(pose.normals, normal).min() < EXACT.fitted_normal_deg


def test_fit_is_translation_equivariant_far_from_the_origin():
    # Centring and scaling the points is what makes this hold: without it the scatter matrix of
    # points 1e5 px from the origin is singular in float64.
    pts = ellipse_points((10.0, 20.0), 30.0, 12.0, 0.4, 60)
    near = fit_ellipse(pts)
    far = fit_ellipse(pts + 1e5)
    assert far
    assert np.allclose(far.ellipse.center - 1e5, near.ellipse.center, atol=1e-6)  # 1e-11 relative
    assert np.allclose(far.ellipse.semi_axes, near.ellipse.semi_axes, rtol=1e-9)


def test_residual_measures_the_noise_in_pixels():
    rng = np.random.default_rng(np.random.SeedSequence([7, 0]))
    sigma = 0.1
    e = Ellipse(np.array([300.0, 200.0]), np.array([60.0, 35.0]), 0.3)
    pts = sample_ellipse(e, 2000, rng=rng, noise_px=sigma)
    fit = fit_ellipse(pts)
    # Isotropic noise of std sigma: the distance to the curve has RMS sigma (normal component);
    # 2000 points give the RMS to +-2 % (1 sigma of a chi estimate), so 10 % is a 5-sigma margin.
    assert abs(fit.residual_px - sigma) < 0.1 * sigma


def test_opencv_near_circle_behaviour_is_recorded_and_ours_is_exact():
    # 2000 points on a near-circle (b/a = 0.999): the case where cv2.fitEllipse has switched to a
    # different solver or a circle fallback in some versions, and where OpenCV only takes float32
    # points. Our fit must be exact to rounding; OpenCV's figures are printed for the record
    # (pytest -s) and must not be better than ours.
    a, b, angle, c = 100.0, 99.9, np.radians(30.0), np.array([500.3, 400.7])
    pts = ellipse_points(c, a, b, angle, 2000)
    ours = fit_ellipse(pts)
    err_ours = (
        np.abs(ours.ellipse.center - c).max(),
        np.abs(ours.ellipse.semi_axes - (a, b)).max(),
        np.degrees(angle_diff_mod_pi(ours.ellipse.angle_rad, angle)),
    )
    # rounding only: 1e-9 px and 1e-6 deg (the angle of a b/a = 0.999 ellipse is sensitive by
    # 1 / (a - b) = 10 per px of axis error)
    assert err_ours[0] < 1e-9 and err_ours[1] < 1e-9 and err_ours[2] < 1e-6
    for fn in (cv2.fitEllipse, cv2.fitEllipseDirect, cv2.fitEllipseAMS):
        (cu, cv_), (w, h), ang_deg = fn(pts.astype(np.float32))
        semi = sorted([w / 2, h / 2], reverse=True)
        major_deg = ang_deg if w >= h else ang_deg + 90.0
        err_cv = (
            max(abs(cu - c[0]), abs(cv_ - c[1])),
            max(abs(semi[0] - a), abs(semi[1] - b)),
            np.degrees(angle_diff_mod_pi(np.radians(major_deg), angle)),
        )
        print(f"OpenCV {cv2.__version__} {fn.__name__}: centre {err_cv[0]:.2e} px, "
              f"axes {err_cv[1]:.2e} px, angle {err_cv[2]:.2e} deg; ours {err_ours}")
        assert all(o <= max(e, 1e-9) for o, e in zip(err_ours, err_cv))


@pytest.mark.parametrize(
    "points, reason",
    [
        (ellipse_points((0, 0), 5, 3, 0, 5), "too_few_points"),
        (np.column_stack([np.arange(20.0), 2 * np.arange(20.0) + 1]), "degenerate_points"),
        (np.ones((10, 2)), "degenerate_points"),
        (np.vstack([ellipse_points((0, 0), 5, 3, 0, 10), [[np.nan, 1.0]]]), "non_finite_points"),
        # points on the hyperbola x^2 - y^2 = 25: the direct fit finds no ellipse
        (np.column_stack([5 * np.cosh(np.linspace(-2, 2, 40)), 5 * np.sinh(np.linspace(-2, 2, 40))]),
         "not_an_ellipse"),
        # two crossing lines: a degenerate conic
        (np.vstack([np.column_stack([np.linspace(-5, 5, 20)] * 2),
                    np.column_stack([np.linspace(-5, 5, 20), -np.linspace(-5, 5, 20)])]),
         "not_an_ellipse"),
        # two parallel lines: exactly fitted by ever longer ellipses, refused as unbounded
        (np.vstack([np.column_stack([np.arange(20.0), np.zeros(20)]),
                    np.column_stack([np.arange(20.0), np.full(20, 5.0)])]), "not_an_ellipse"),
    ],
    ids=["five_points", "collinear", "coincident", "nan", "hyperbola", "line_pair", "parallel"],
)
def test_failures_are_falsy_and_named(points, reason):
    fit = fit_ellipse(points)
    assert not fit
    assert fit.reason == reason, str(fit)


@pytest.mark.parametrize("bad", [np.zeros((10, 3)), np.zeros(12), np.zeros((2, 10, 2))])
def test_wrong_shape_raises(bad):
    with pytest.raises(ValueError, match="shape"):
        fit_ellipse(bad)


@given(seed=st.integers(0, 10_000), a=st.floats(5, 200), ratio=st.floats(0.2, 1.0))
@settings(max_examples=60, deadline=None)
def test_noisy_ellipses_are_never_refused(seed, a, ratio):
    # The hyperbola / line-pair guard must not fire on real isophotes: 0.3 px noise (worse than
    # marching squares on a clean image) on ellipses from 5 px to 200 px, near-circles included.
    rng = np.random.default_rng(np.random.SeedSequence([11, seed]))
    e = Ellipse(rng.uniform(0, 1000, 2), np.array([a, a * ratio]), rng.uniform(0, np.pi))
    n = max(12, int(2 * np.pi * a))  # about one point per pixel of perimeter, as marching squares
    fit = fit_ellipse(sample_ellipse(e, n, rng=rng, noise_px=0.3))
    assert fit, str(fit)
    # the centre is found to a fraction of the noise times the size-to-count ratio; 1 px is loose
    assert np.linalg.norm(fit.ellipse.center - e.center) < 1.0


def _noisy_ellipse(rng, n):
    t = rng.uniform(0.0, 2 * np.pi, n)
    a, b = rng.uniform(1.0, 60.0, 2)
    th = rng.uniform(0.0, np.pi)
    rot = np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])
    pts = np.column_stack([a * np.cos(t), b * np.sin(t)]) @ rot + rng.uniform(0.0, 1500.0, 2)
    return pts + rng.normal(0.0, rng.choice([0.0, 0.01, 0.5, 5.0]), pts.shape)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12))
def test_a_batched_fit_is_bit_for_bit_the_fit_of_each_set_alone(seed, k):
    """fit_ellipses sums each set's monomials over its own rows and runs LAPACK per matrix, so a
    set's fit must not depend, even in the last bit, on the other sets of its batch (the
    pipeline fits a whole frame in one batch; reconstruct_roi fits one highlight)."""
    rng = np.random.default_rng(seed)
    sets = [_noisy_ellipse(rng, int(rng.integers(3, 200))) for _ in range(k)]
    if k > 2:  # a failure in the batch must not touch the others
        sets[1] = np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])  # collinear
    batch = fit_ellipses(sets)
    for s, got in zip(sets, batch):
        alone = fit_ellipse(s)
        assert bool(got) == bool(alone)
        if not alone:
            assert (got.reason, got.detail) == (alone.reason, alone.detail)
            continue
        assert np.array_equal(got.conic, alone.conic)
        assert np.array_equal(got.ellipse.center, alone.ellipse.center)
        assert np.array_equal(got.ellipse.semi_axes, alone.ellipse.semi_axes)
        assert got.ellipse.angle_rad == alone.ellipse.angle_rad and got.residual_px == alone.residual_px


def test_batched_fit_refuses_as_the_single_fit_does():
    """Every failure reason comes out of the batch at its place, with the others fitted."""
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    circle = np.column_stack([100 + 7 * np.cos(t), 50 + 7 * np.sin(t)])
    sets = [circle[:4], np.vstack([circle, [[np.nan, 1.0]]]), np.full((10, 2), 3.0),
            np.column_stack([np.arange(10.0), 2 * np.arange(10.0)]), circle]
    got = fit_ellipses(sets)
    assert [g.reason if not g else "ok" for g in got] == [
        "too_few_points", "non_finite_points", "degenerate_points", "degenerate_points", "ok"]
    # the circle: centre and radius exact to rounding of its 40 samples
    assert np.allclose(got[-1].ellipse.center, [100, 50], atol=1e-9)
    assert np.allclose(got[-1].ellipse.semi_axes, [7, 7], atol=1e-9)


# ---- the closed forms over the stack (fit.py's private helpers) against LAPACK --------------------
# (moved from the deleted compiled kernels' tests: the same truths, now of the numpy forms)

from simtest.reconstruct.fit import _cubic_roots, _eigh2, _ellipse_params, _null_vectors, _positive_definite


@pytest.mark.parametrize("seed", range(5))
def test_closed_form_eigenvectors_are_lapacks(seed):
    # real matrices with three real, distinct eigenvalues (V diag(w) V^-1): each closed-form
    # root is one of LAPACK's, its null vector LAPACK's eigenvector up to sign (to ~1e-12: a
    # well separated spectrum, as the reduced scatter of an ellipse fit has)
    rng = np.random.default_rng(seed)
    w = np.sort(rng.uniform(-3, 3, (50, 3)), axis=1) + np.array([0.0, 0.5, 1.0])
    V = rng.normal(size=(50, 3, 3))
    m = V @ (w[:, :, None] * np.linalg.inv(V))
    lam, ok = _cubic_roots(m)
    vec, defined = _null_vectors(m[:, None] - lam[:, :, None, None] * np.eye(3))
    assert ok.all() and defined.all()
    assert np.allclose(np.sort(lam, axis=1), w, atol=1e-9)
    Vn = V / np.linalg.norm(V, axis=1, keepdims=True)
    for j in range(50):
        for q in range(3):
            col = Vn[j][:, np.argmin(np.abs(w[j] - lam[j, q]))]
            assert abs(abs(vec[j, q] @ col) - 1.0) < 1e-9


def test_closed_form_refusals():
    # complex roots (a rotation), a repeated root (the identity) and NaN: declined, LAPACK decides
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 2.0]])
    with np.errstate(all="ignore"):
        _, ok = _cubic_roots(np.stack([rot, np.eye(3), np.full((3, 3), np.nan)]))
        _, defined = _null_vectors(np.zeros((1, 3, 3)))
    assert not ok.any()
    assert not defined.any()


@pytest.mark.parametrize("seed", range(5))
def test_closed_form_2x2_and_cholesky_checks_are_lapacks(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(200, 2, 2)) * 10.0 ** rng.uniform(-6, 6, (200, 1, 1))
    s = a @ np.swapaxes(a, 1, 2)
    lo, hi, x, y = _eigh2(s[:, 0, 0], s[:, 0, 1], s[:, 1, 1])
    w, v = np.linalg.eigh(s)
    scale = np.abs(w).max(axis=1)
    assert np.allclose(lo / scale, w[:, 0] / scale, atol=1e-14) and np.allclose(hi / scale, w[:, 1] / scale, atol=1e-14)
    assert np.allclose(np.abs(x * v[:, 0, 0] + y * v[:, 1, 0]), 1.0, atol=1e-8)
    # s - tau I factorises exactly where LAPACK's least eigenvalue is above tau (beyond rounding)
    b = rng.normal(size=(300, 6, 6))
    s6 = b @ np.swapaxes(b, 1, 2)
    ev = np.linalg.eigvalsh(s6)
    tau = ev[:, 0] * rng.uniform(0.5, 1.5, 300)
    got = _positive_definite(s6, tau, np.ones(300, dtype=bool))
    clear = np.abs(ev[:, 0] - tau) > 1e-9 * ev[:, -1]
    assert np.array_equal(got[clear], (ev[:, 0] > tau)[clear])
    assert not _positive_definite(s6, tau, np.zeros(300, dtype=bool)).any()


@given(st.floats(-2, 2), st.floats(-2, 2), st.floats(0.5, 3), st.floats(0.05, 1.0), st.floats(-np.pi, np.pi))
@settings(max_examples=100, deadline=None)
def test_ellipse_parameters_of_a_known_conic(cu, cv, a, ratio, angle):
    # a known ellipse's conic, of the size the fit hands in (the conic of points centred and
    # scaled to unit RMS radius), gives back its centre, semi-axes and angle (mod pi); a
    # hyperbola, an imaginary conic and a line pair are no real ellipses
    C = ellipse_to_conic((cu, cv), (a, a * ratio), angle)
    with np.errstate(all="ignore"):
        centre, axes, ang, ok = _ellipse_params(np.stack([C, -3.0 * C, np.diag([1.0, -1.0, -1.0]), np.eye(3),
                                                          np.diag([1.0, -1.0, 0.0])]))
    assert ok.tolist() == [True, True, False, False, False]
    for j in (0, 1):
        assert np.allclose(centre[j], (cu, cv), atol=1e-9 * (1 + abs(cu) + abs(cv)) + 1e-9 * a)
        assert np.allclose(axes[j], (a, a * ratio), rtol=1e-9)
        if ratio < 0.99:
            assert angle_diff_mod_pi(ang[j], angle) < 1e-7
