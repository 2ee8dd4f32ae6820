"""The batched ellipse fit's machinery (simtest.reconstruct.fit.fit_stacked) on random batches.

``tests/test_fit.py`` holds the fit's geometry (exact points give the ellipse, imaged circles the
true normal, noise the residual); here, what the stacked numpy pass adds: its closed-form 3 x 3
and 2 x 2 eigen-solves against LAPACK, the Cholesky shortcut that spares the eigenvalue checks
(it changes no verdict), and random batches of every kind the fit meets or refuses (ellipses of
any size, place and noise, near-circles, too few, non-finite, coincident, collinear, parallel
lines, hyperbola points): each refused for its reason, each set's fit its own.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct import fit
from simtest.reconstruct.cone_fit import FitFrame, _to_planes, rotations_to_z
from simtest.reconstruct.fit import _least_eigenvalue_above, ellipses_of, fit_stacked


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



#: The reasons each kind of random set may be refused for (a noisy arc or a tiny ellipse may be
#: refused as a non-ellipse by the guard; lines as collinear, or as unbounded ellipses once noise
#: or rounding lifts their scatter off singular).
_REASONS = {
    "few": {"too_few_points"}, "nan": {"non_finite_points"}, "coincident": {"degenerate_points"},
    "line": {"degenerate_points", "not_an_ellipse"}, "parallel": {"degenerate_points", "not_an_ellipse"},
    "hyperbola": {"degenerate_points", "not_an_ellipse"},
}


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 60))
@settings(max_examples=20, deadline=None)
def test_random_batches_fit_ellipses_and_refuse_the_rest_for_their_reason(seed, k):
    # exact or lightly noisy full ellipses are fitted with their centre; degenerate sets are
    # refused for their kind's reason; a set's result is that of fitting it alone (bit for bit)
    rng = np.random.default_rng(seed)
    sets, kinds = [], []
    for _ in range(k):
        kind, pts, truth = _labelled_set(rng)
        sets.append(pts)
        kinds.append((kind, truth))
    counts = np.array([len(s) for s in sets])
    got = fit_stacked(np.concatenate(sets) if sets else np.empty((0, 2)), counts)
    for (kind, truth), g, pts in zip(kinds, got, sets, strict=True):
        if kind in _REASONS:
            assert not g and g.reason in _REASONS[kind], (kind, g)
        elif truth is not None:  # a full ellipse, noise under 1e-3 of its minor axis
            assert g, (kind, g)
            centre, a, b = truth
            assert np.abs(g.ellipse.center - centre).max() <= 1e-2 * b
            assert np.allclose(g.ellipse.semi_axes, [a, b], rtol=1e-2)
        alone = fit_stacked(pts, np.array([len(pts)]))[0]
        assert bool(alone) == bool(g)
        if not g:
            assert (alone.reason, alone.detail) == (g.reason, g.detail)
        else:
            assert np.array_equal(alone.conic, g.conic) and alone.residual_px == g.residual_px
            assert np.array_equal(alone.ellipse.center, g.ellipse.center)


def _labelled_set(rng):
    """A point set of a random kind: (kind, points, (centre, a, b) for a full ellipse whose
    noise is under 1e-3 of its minor axis, else None)."""
    kind = str(rng.choice(["ellipse"] * 6 + ["circle", "few", "nan", "coincident", "line", "parallel", "hyperbola"]))
    n = int(rng.integers(6, 300))
    centre = rng.uniform(-2000.0, 2000.0, 2)
    if kind == "few":
        return kind, rng.uniform(0.0, 100.0, (int(rng.integers(0, 6)), 2)), None
    if kind == "coincident":
        return kind, np.tile(centre, (n, 1)), None
    if kind == "line":
        t = rng.uniform(-50.0, 50.0, n)
        d = rng.normal(size=2)
        return kind, centre + t[:, None] * d / np.linalg.norm(d), None
    if kind == "parallel":
        t = rng.uniform(-50.0, 50.0, n)
        return kind, centre + np.column_stack([t, rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 5.0)]), None
    if kind == "hyperbola":
        s = rng.uniform(-2.0, 2.0, n)
        a, b = rng.uniform(1.0, 40.0, 2)
        return kind, centre + np.column_stack([a * np.cosh(s) * rng.choice([-1.0, 1.0], n), b * np.sinh(s)]), None
    a = rng.uniform(2.0, 400.0)
    b = a * (rng.uniform(1.0 - 1e-6, 1.0) if kind == "circle" else rng.uniform(0.2, 1.0))
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, 2 * np.pi)
    th = rng.uniform(0.0, np.pi)
    rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    noise = b * rng.choice([0.0, 1e-5, 1e-4])
    pts = centre + np.column_stack([a * np.cos(t), b * np.sin(t)]) @ rot.T + rng.normal(0.0, 1.0, (n, 2)) * noise
    if kind == "nan":
        pts[rng.integers(0, n, int(rng.integers(1, 4)))] = rng.choice([np.nan, np.inf, -np.inf])
        return kind, pts, None
    return kind, pts, (centre, a, b)


@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 120))
@settings(max_examples=25, deadline=None)
def test_the_cholesky_shortcut_changes_no_verdict(seed, k):
    # the collinearity check and the guard against non-ellipses cleared by a Cholesky
    # factorisation where they certainly pass: the same verdicts (reason and detail) and the same
    # fits as asking LAPACK's eigenvalues of every set (the shortcut switched off)
    pts, counts = _batch(np.random.default_rng(seed), k)
    fast = fit_stacked(pts, counts)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fit, "_least_eigenvalue_above", lambda s, base: np.zeros(len(s), dtype=bool))
        full = fit_stacked(pts, counts)
    for a, b in zip(fast, full, strict=True):
        assert bool(a) == bool(b)
        if not a:
            assert (a.reason, a.detail) == (b.reason, b.detail)
        else:
            assert np.array_equal(a.conic, b.conic) and a.residual_px == b.residual_px


def test_random_batches_reach_every_refusal():
    # the tests above mean something only if their sets reach each of the fit's refusals
    pts, counts = _batch(np.random.default_rng(0), 1500)
    t = np.linspace(-30.0 / 5000.0, 30.0 / 5000.0, 40)  # 60 px of a 5000 px circle: unbounded
    arc = np.column_stack([300.0 + 5000.0 * np.sin(t), -200.0 + 5000.0 * (1.0 - np.cos(t))])
    got = fit_stacked(np.concatenate([pts, arc]), np.append(counts, len(arc)))
    assert not got[-1] and got[-1].detail.startswith("unbounded")
    details = {(g.reason, g.detail.split(" (")[0].split(":")[0]) for g in got if not g}
    assert {("too_few_points", "too_few_points"), ("degenerate_points", "all points coincide"),
            ("degenerate_points", "linear scatter is singular"), ("not_an_ellipse", "unbounded")} <= {
        (r, r if r == "too_few_points" else d) for r, d in details}
    assert any(r == "non_finite_points" for r, _ in details)
    assert any(d.startswith("the points fit a") for _, d in details)


@given(cu=st.floats(-2000, 2000), cv=st.floats(-2000, 2000), a=st.floats(0.5, 500), ratio=st.floats(0.05, 1.0),
       angle=st.floats(-np.pi / 2, np.pi / 2, exclude_min=True),
       scale=st.floats(-1e6, 1e6).filter(lambda x: abs(x) > 1e-6))
@settings(max_examples=200, deadline=None)
def test_ellipses_of_reads_the_ellipse_of_its_conic(cu, cv, a, ratio, angle, scale):
    # the conic of a known ellipse, at any scale and sign: its centre, semi-axes and angle back
    b = a * ratio
    ca, sa = np.cos(angle), np.sin(angle)
    rot = np.array([[ca, -sa], [sa, ca]])
    q = rot @ np.diag([1 / a**2, 1 / b**2]) @ rot.T
    ctr = np.array([cu, cv])
    conic = np.block([[q, (-q @ ctr)[:, None]], [(-q @ ctr)[None, :], np.array([[ctr @ q @ ctr - 1.0]])]])
    ok, centre, axes, got_angle = ellipses_of(conic[None] * scale)
    size = np.abs(ctr).max() + a
    cond = (a / b) ** 2  # the centre solves a system of condition (a / b)^2
    assert ok[0]
    assert np.allclose(centre[0], ctr, rtol=0, atol=1e-9 * size * cond)
    assert np.allclose(axes[0], [a, b], rtol=1e-7 * cond)
    if ratio < 0.999:  # a circle's angle is any
        d = abs(got_angle[0] - angle)
        assert min(d, np.pi - d) <= 1e-7 * cond / (1 - ratio)


def test_ellipses_of_refuses_what_is_not_a_real_ellipse():
    # an imaginary ellipse (x^2 + y^2 + 1 = 0), a hyperbola, a parabola, a line pair, zero
    parabola = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -0.5], [0.0, -0.5, 0.0]])
    ok, centre, axes, angle = ellipses_of(np.stack([
        np.diag([1.0, 1.0, 1.0]), np.diag([1.0, -1.0, -1.0]), parabola, np.diag([1.0, -1.0, 0.0]),
        np.zeros((3, 3)), np.diag([1.0 / 16, 1.0 / 4, -1.0])]))
    assert ok.tolist() == [False, False, False, False, False, True]
    assert np.allclose([*centre[5], *axes[5], angle[5]], [0.0, 0.0, 4.0, 2.0, 0.0])


def test_refused_sets_come_back_at_their_place():
    # refused sets between fitted ones keep their order
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
    cleared = bool(_least_eigenvalue_above(s[None], np.array([r / 3.96]))[0])
    if cleared:
        assert not r > 3.96 * max(w_np[0] - 1e-12 * w_np[5], 0.0)
        assert w_np[0] > 1e-10 * w_np[5]  # the collinearity check's form too (s3_rcond)
    if ratio < 3.96 / 1.01 and w_np[0] > 1e-8 * w_np[5]:
        assert cleared
