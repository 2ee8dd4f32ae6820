"""The compiled ellipse fit (simtest.reconstruct._fit_kernels) agrees with the numpy form.

The numpy form (``fit._fit_stack``) stays in the code as the reference and the fallback; these
tests run both (``fit_stacked(..., compiled=True / False)``) on random point sets that reach every
branch of the kernel: ellipses of any size, place and noise, near-circles, and the degenerate sets
the fit refuses (too few, non-finite, coincident, collinear, parallel lines, hyperbola points).

Statuses, failure reasons and detail strings must be identical (the kernel's refusals are refitted
by the numpy form, so this also checks that the kernel accepts no set the numpy form refuses); the
fitted floats agree to rounding, not bit for bit: the two forms sum in another order (numpy's
pairwise sums against a running sum) and call the same LAPACK routines of two OpenBLAS builds.
"""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.reconstruct import _fit_kernels
from simtest.reconstruct.cone_fit import FitFrame, _to_planes, rotations_to_z
from simtest.reconstruct.fit import MAX_AXIS_TO_SPREAD, _S3_RCOND, fit_stacked
from simtest.tolerances import TOL

#: Relative agreement of the fitted floats. The forms differ by rounding in the sums (~1e-16
#: relative each) carried through the 3 x 3 eigenproblem of a conditioned set: the recorded
#: inputs of the test images (5379 isophotes) differ by at most 2e-12 in the unit conic and 8e-12
#: of the centre's distance from the origin; 1e-9 leaves a margin of ~100 for the random sets.
REL = 1e-9
#: The RMS Sampson residual divides by the conic's gradient, which vanishes at the centre: on a
#: 10-point, 1.6 px ellipse whose points lie near its centre (the banner's smallest isophotes) the
#: residual differed by 2e-9 of itself. 1e-7 relative leaves a margin. Exact points have a residual
#: that is rounding: a unit-norm conic evaluated at 2000 px, divided by the small gradient of a
#: 0.5 px-wide ellipse, leaves ~3e-9 px that differs between the forms, hence 1e-8 px absolute
#: (both far below a pixel's rounding).
RESIDUAL_REL = 1e-7
RESIDUAL_ABS_PX = 1e-8

_REASON = {
    _fit_kernels.NON_FINITE: {"non_finite_points"},
    _fit_kernels.COINCIDENT: {"degenerate_points"},
    _fit_kernels.SINGULAR_SCATTER: {"degenerate_points"},
    _fit_kernels.NO_ELLIPSE: {"not_an_ellipse"},
    _fit_kernels.NON_FINITE_CONIC: {"degenerate_points"},
    _fit_kernels.NOT_REAL_ELLIPSE: {"not_an_ellipse"},
    _fit_kernels.UNBOUNDED: {"not_an_ellipse"},
}


def _random_set(rng) -> np.ndarray:
    """A point set: mostly noisy ellipse arcs, else one of the degenerate kinds."""
    kind = rng.choice(["ellipse"] * 6 + ["circle", "few", "nan", "coincident", "line", "parallel",
                                         "hyperbola", "arc", "tiny"])
    n = int(rng.integers(6, 300))
    centre = rng.uniform(-2000.0, 2000.0, 2)
    if kind == "few":
        return rng.uniform(0.0, 100.0, (int(rng.integers(0, 6)), 2))
    if kind == "coincident":
        return np.tile(centre, (n, 1))
    if kind == "line":
        t = rng.uniform(-50.0, 50.0, n)
        d = rng.normal(size=2)
        return centre + t[:, None] * d / np.linalg.norm(d)
    if kind == "parallel":
        t = rng.uniform(-50.0, 50.0, n)
        side = rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 5.0)
        return centre + np.column_stack([t, side])
    if kind == "hyperbola":
        s = rng.uniform(-2.0, 2.0, n)
        a, b = rng.uniform(1.0, 40.0, 2)
        pts = np.column_stack([a * np.cosh(s) * rng.choice([-1.0, 1.0], n), b * np.sinh(s)])
        return centre + pts + rng.normal(0.0, rng.choice([0.0, 0.01]), pts.shape)
    a = rng.uniform(0.5, 400.0)
    b = a * (rng.uniform(1.0 - 1e-6, 1.0) if kind == "circle" else rng.uniform(0.05, 1.0))
    span = rng.uniform(0.3, 1.0) * np.pi if kind == "arc" else 2 * np.pi
    if kind == "tiny":
        a, b = rng.uniform(0.5, 3.0), rng.uniform(0.3, 0.5)
    t = rng.uniform(0.0, span, n) + rng.uniform(0, 2 * np.pi)
    th = rng.uniform(0.0, np.pi)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    pts = centre + np.column_stack([a * np.cos(t), b * np.sin(t)]) @ rot.T
    pts = pts + rng.normal(0.0, rng.choice([0.0, 0.0, 1e-3, 0.05, 0.5, 3.0]), pts.shape)
    if kind == "nan":
        pts[rng.integers(0, n, int(rng.integers(1, 4)))] = rng.choice([np.nan, np.inf, -np.inf])
    return pts


def _batch(rng, k):
    sets = [_random_set(rng) for _ in range(k)]
    return np.concatenate(sets, axis=0) if sets else np.empty((0, 2)), np.array([len(s) for s in sets])


def _assert_agree(got, want):
    assert bool(got) == bool(want), (got, want)
    if not want:
        assert (got.reason, got.detail) == (want.reason, want.detail)
        return
    assert got.n_points == want.n_points
    assert np.abs(got.conic - want.conic).max() <= REL  # unit Frobenius norm
    size = np.abs(want.ellipse.center).max() + want.ellipse.semi_axes[0]
    a, b = want.ellipse.semi_axes
    # the centre solves A2 c = -b2 with the conic's quadratic part A2, whose condition number is
    # (a / b)^2: a thin ellipse's centre and axes move that much more than its conic (seed 112827:
    # 16 noisy points of a 323 x 16 px ellipse 1800 px from the origin, the conics 1e-10 apart,
    # the centres 6e-6 px)
    cond = (a / b) ** 2
    assert np.abs(got.ellipse.center - want.ellipse.center).max() <= REL * size * cond
    assert np.abs(got.ellipse.semi_axes - want.ellipse.semi_axes).max() <= REL * size * cond
    # the angle is defined by the eccentricity: a near-circle's turns freely with rounding
    d = abs(got.ellipse.angle_rad - want.ellipse.angle_rad)
    d = min(d, np.pi - d)
    assert d * (a - b) <= REL * size * cond
    # the residual of points on a thin ellipse is read through the same ill-conditioned centre and
    # axes: its rounding floor grows by cond too (seed 121, k 162: a 0.55 x 0.029 px ellipse, exact
    # points, residuals 6.0e-8 and 4.9e-8 px)
    assert abs(got.residual_px - want.residual_px) <= RESIDUAL_REL * want.residual_px + RESIDUAL_ABS_PX * cond


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 200))
@settings(max_examples=60, deadline=None)
@example(seed=121, k=162)
def test_compiled_fit_agrees_with_the_numpy_form(seed, k):
    pts, counts = _batch(np.random.default_rng(seed), k)
    got = fit_stacked(pts, counts, compiled=True)
    want = fit_stacked(pts, counts, compiled=False)
    for g, w in zip(got, want, strict=True):
        _assert_agree(g, w)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 200))
@settings(max_examples=30, deadline=None)
def test_the_kernels_refusals_name_the_numpy_forms_reason(seed, k):
    # fit_stacked refits refused sets with the numpy form; the kernel's own verdict must still
    # be the numpy form's (an OK where numpy refuses would be a wrong fit reported)
    pts, counts = _batch(np.random.default_rng(seed), k)
    keep = counts >= 6
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[keep]
    status = _fit_kernels.fit_conics(pts, starts, counts[keep], _S3_RCOND, MAX_AXIS_TO_SPREAD,
                                     TOL.conic_degenerate_rel)[0]
    want = [w for w, kp in zip(fit_stacked(pts, counts, compiled=False), keep) if kp]
    for s, w in zip(status.tolist(), want, strict=True):
        if s == _fit_kernels.OK:
            assert w
        elif s in _REASON:
            assert not w and w.reason in _REASON[s]


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 200))
@settings(max_examples=30, deadline=None)
def test_a_sets_fit_does_not_depend_on_the_rest_of_the_batch(seed, k):
    # the kernel fits each set from its own rows in its own loop iteration: bit for bit
    rng = np.random.default_rng(seed)
    pts, counts = _batch(rng, k)
    batch = fit_stacked(pts, counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for j in rng.choice(k, size=min(k, 5), replace=False).tolist():
        alone = fit_stacked(pts[starts[j]:starts[j] + counts[j]], counts[j:j + 1])[0]
        got = batch[j]
        assert bool(got) == bool(alone)
        if not alone:
            assert (got.reason, got.detail) == (alone.reason, alone.detail)
            continue
        assert np.array_equal(got.conic, alone.conic) and got.residual_px == alone.residual_px
        assert np.array_equal(got.ellipse.center, alone.ellipse.center)
        assert np.array_equal(got.ellipse.semi_axes, alone.ellipse.semi_axes)
        assert got.ellipse.angle_rad == alone.ellipse.angle_rad


def test_every_kernel_status_is_reached_by_the_random_sets():
    # the tests above mean something only if their inputs reach each branch (but a non-finite
    # conic from finite normalised points, which needs an overflow); DECLINED is LAPACK's refusal
    # (complex eigenvalues of the reduced problem of line pairs and hyperbola points)
    rng = np.random.default_rng(0)
    pts, counts = _batch(rng, 3000)
    # UNBOUNDED for certain: 40 exact points on 60 px of a circle of radius 5000 px (its semi-major
    # axis about 167 times the points' spread, their largest distance from their mean, 30 px: far
    # past the limit of MAX_AXIS_TO_SPREAD = 10 whatever the rounding). The random sets are
    # unbounded only as near-lines (semi-major axes about 1e5 px), whose reduced problem is so near
    # singular that the kernel hands them to numpy (SUSPECT, DECLINED) or decides them itself by
    # the last bits of LAPACK's eigenvalues: on an AMD EPYC none of the 33 reached UNBOUNDED, and
    # this test failed without the arc.
    t = np.linspace(-30.0 / 5000.0, 30.0 / 5000.0, 40)
    arc = np.column_stack([300.0 + 5000.0 * np.sin(t), -200.0 + 5000.0 * (1.0 - np.cos(t))])
    pts, counts = np.concatenate([pts, arc]), np.append(counts, len(arc))
    keep = counts >= 6
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[keep]
    status = _fit_kernels.fit_conics(pts, starts, counts[keep], _S3_RCOND, MAX_AXIS_TO_SPREAD,
                                     TOL.conic_degenerate_rel)[0]
    assert status[-1] == _fit_kernels.UNBOUNDED
    # NO_ELLIPSE and NOT_REAL_ELLIPSE: the random sets reached them (2 each of 3000) only as
    # near-degenerate problems decided by LAPACK's last bits; the closed-form eigen-solve declines
    # those (DECLINED: numpy's form decides them, as the tests above check). Their branches are
    # reached by test_closed_form_refusals below.
    assert set(status.tolist()) >= set(range(10)) - {_fit_kernels.NON_FINITE_CONIC, _fit_kernels.NO_ELLIPSE,
                                                     _fit_kernels.NOT_REAL_ELLIPSE}


@given(seed=st.integers(0, 2**32 - 1))
@settings(max_examples=200, deadline=None)
@example(seed=462008)
def test_closed_form_solves_agree_with_lapack(seed):
    # the written-out 3 x 3 solve, 3 x 3 real eigenproblem and 2 x 2 symmetric one of the fit
    # against numpy's LAPACK (the routines they replace), on random well-conditioned matrices:
    # to rounding (1e-9 relative leaves a margin of ~1e4 over a condition number of ~1e3)
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3)) + 3.0 * np.eye(3) * rng.choice([-1.0, 1.0])
    b = rng.normal(size=(3, 3))
    ok, x = _fit_kernels._solve3(a, b)
    assert ok and np.allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=1e-9)
    # a real spectrum with distinct eigenvalues: V diag(lam) V^-1
    lam = np.sort(rng.uniform(-10.0, 10.0, 3))
    if np.min(np.diff(lam)) < 0.1:
        lam = np.array([-5.0, 0.5, 4.0])
    v = rng.normal(size=(3, 3)) + 2.0 * np.eye(3)
    m = v @ np.diag(lam) @ np.linalg.inv(v)
    ok, got_lam, got_vec = _fit_kernels._eig3_real(m)
    assert ok
    # backward error: each pair an eigenpair of a matrix within 1e-11 of m (relative; 4e-13 the
    # largest over 20000 seeds: the characteristic cubic's rounding)
    for i in range(3):
        assert np.linalg.norm(m @ got_vec[:, i] - got_lam[i] * got_vec[:, i]) <= 1e-11 * np.linalg.norm(m)
    want_lam, want_vec = np.linalg.eig(m)
    # forward error: the same as LAPACK's to 1e-9 where the eigenproblem is well conditioned (the
    # eigenvalues' condition number times |m| over their gap at most 1e3: 1e-12 over 20000 seeds);
    # beyond, both solvers' eigenvalues move by that condition times their rounding (seed 462008:
    # two eigenvalues 0.18 apart, the cubic's 8e-8 from LAPACK's, LAPACK's own 2e-10 from the
    # construction's)
    kappa = max(np.linalg.norm(want_vec[:, i]) * np.linalg.norm(np.linalg.inv(want_vec)[i]) for i in range(3))
    if kappa * np.linalg.norm(m) / np.min(np.diff(np.sort(want_lam.real))) <= 1e3:
        order_got, order_want = np.argsort(got_lam), np.argsort(want_lam.real)
        assert np.allclose(got_lam[order_got], want_lam.real[order_want], rtol=1e-9, atol=1e-9)
        for i, j in zip(order_got, order_want):  # unit vectors, the same up to sign
            g, w = got_vec[:, i], want_vec[:, j].real
            assert abs(abs(g @ w) - 1.0) < 1e-9
    s = rng.normal(size=(2, 2))
    s = s + s.T
    lo, hi, vx, vy = _fit_kernels._eigh2(s[0, 0], s[0, 1], s[1, 1])
    w, vec = np.linalg.eigh(s)
    assert np.allclose([lo, hi], w, rtol=1e-12, atol=1e-12)
    assert abs(abs(vx * vec[0, 0] + vy * vec[1, 0]) - 1.0) < 1e-9


def test_closed_form_refusals():
    # a singular system and complex or repeated eigenvalues are refused (LAPACK raised or returned
    # complex values: the set is DECLINED), and ellipse_of tells an imaginary ellipse
    # (x^2 + y^2 + 1 = 0: NOT_REAL_ELLIPSE) and a hyperbola from a real ellipse
    assert not _fit_kernels._solve3(np.array([[1.0, 2, 3], [2, 4, 6], [0, 1, 1]]), np.eye(3))[0]
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 2]])  # eigenvalues +-i and 2
    assert not _fit_kernels._eig3_real(rot)[0]
    assert not _fit_kernels._eig3_real(np.eye(3))[0]
    eps = TOL.conic_degenerate_rel
    assert not _fit_kernels.ellipse_of(np.diag([1.0, 1.0, 1.0]), eps)[0]
    assert not _fit_kernels.ellipse_of(np.diag([1.0, -1.0, -1.0]), eps)[0]
    ok, cu, cv, a, b, angle = _fit_kernels.ellipse_of(np.diag([1.0 / 16, 1.0 / 4, -1.0]), eps)
    assert ok and np.allclose([cu, cv, a, b, angle], [0.0, 0.0, 4.0, 2.0, 0.0])


def test_fallback_sets_come_back_at_their_place():
    # refused sets (refitted by the numpy form) between fitted ones keep their order
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    circle = np.column_stack([100 + 7 * np.cos(t), 50 + 7 * np.sin(t)])
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])
    hyperbola = np.column_stack([np.cosh(np.linspace(-2, 2, 30)), np.sinh(np.linspace(-2, 2, 30))])
    sets = [circle, line, circle + 5, np.vstack([circle, [[np.nan, 0.0]]]), hyperbola, circle[:5], circle * 2]
    got = fit_stacked(np.concatenate(sets), np.array([len(s) for s in sets]))
    assert [g.reason if not g else "ok" for g in got] == [
        "ok", "degenerate_points", "ok", "non_finite_points", "not_an_ellipse", "too_few_points", "ok"]
    assert np.allclose(got[2].ellipse.center, [105, 55], atol=1e-9)
    assert np.allclose(got[6].ellipse.semi_axes, [14, 14], atol=1e-9)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 20))
@settings(max_examples=30, deadline=None)
def test_batched_plane_projection_is_each_frames_own(seed, k):
    # fit_cones projects the rays of all highlights in one call; each highlight's plane points
    # must be those of its own FitFrame.to_plane, bit for bit, rays past the horizon NaN
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(k, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.1
    R = rotations_to_z(d)
    f = rng.uniform(100.0, 900.0, k)
    K = np.stack([np.diag([fi, fi, 1.0]) for fi in f])
    counts = rng.integers(0, 50, k)
    rays = rng.normal(size=(int(counts.sum()), 3))
    owner = np.repeat(np.arange(k), counts)
    got = _to_planes(rays, R, K, owner)
    assert np.isnan(got[np.einsum("nj,nj->n", R[owner, 2], rays) <= 0]).all()
    for i in range(k):
        frame = FitFrame(None, R[i], K[i], False)
        want = frame.to_plane(rays[owner == i])
        assert np.array_equal(got[owner == i], want, equal_nan=True)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 120))
@settings(max_examples=40, deadline=None)
def test_the_guards_shortcut_changes_no_bit(seed, k):
    # the collinearity check and the guard against non-ellipses cleared by a Cholesky
    # factorisation where they certainly pass (_least_eigenvalue_above) give every output of the
    # eigenvalue checks, to the bit, collinear, hyperbola and line-pair sets (refused) included
    pts, counts = _batch(np.random.default_rng(seed), k)
    keep = counts >= 6
    pts = np.concatenate([s for s, n in zip(np.split(pts, np.cumsum(counts)[:-1]), keep) if n] or [np.empty((0, 2))])
    counts = counts[keep]
    if not len(counts):
        return
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    args = (np.ascontiguousarray(pts, dtype=np.float64), starts, counts.astype(np.int64),
            _S3_RCOND, MAX_AXIS_TO_SPREAD, TOL.conic_degenerate_rel)
    fast = _fit_kernels.fit_conics(*args)
    full = _fit_kernels.fit_conics(*args, True)
    for a, b in zip(fast, full, strict=True):
        assert a.tobytes() == b.tobytes()


@given(seed=st.integers(0, 2**32 - 1), ratio=st.floats(0.5, 8.0), spread=st.floats(-12.0, 0.0))
@settings(max_examples=200, deadline=None)
def test_a_cleared_guard_is_one_the_eigenvalues_pass(seed, ratio, spread):
    # on positive semi-definite 6 x 6 matrices whose eigenvalues span up to 12 decades, with the
    # residual at `ratio` times the least eigenvalue: cleared only where numpy's eigenvalues pass
    # the guard, and cleared well inside it (ratio < 3.96 / 1.01 and a least eigenvalue not lost
    # in the rounding of the largest)
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    w = np.sort(10.0 ** rng.uniform(spread, 0.0, 6)) * float(rng.uniform(1.0, 1e4))
    s = (q * w) @ q.T
    s = 0.5 * (s + s.T)
    w_np = np.linalg.eigvalsh(s)
    r = ratio * max(w_np[0], 1e-300)
    cleared = _fit_kernels._least_eigenvalue_above(s, r / 3.96)
    if cleared:
        assert not r > 3.96 * max(w_np[0] - 1e-12 * w_np[5], 0.0)
        assert w_np[0] > 1e-10 * w_np[5]  # the collinearity check's form too (s3_rcond)
    if ratio < 3.96 / 1.01 and w_np[0] > 1e-8 * w_np[5]:
        assert cleared
