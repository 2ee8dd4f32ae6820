"""Closed-form Phong images of a plane agree with the scene-plane model and the conic geometry."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from simtest.geometry import angle_between_deg, cone_axis, normalised_conic, project_circle, project_points
from simtest.simulate.analytic import phong_plane_image, plane_bp
from simtest.specular import isophote_radius, phong_intensity


def tilted_normal(tilt_deg: float, az_deg: float = 90.0) -> np.ndarray:
    t, a = np.radians(tilt_deg), np.radians(az_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])


@pytest.mark.parametrize("tilt", [0.0, 30.0, 58.0])
def test_camera_frame_image_equals_scene_plane_model(tilt):
    K = np.array([[120.0, 0, 101.5], [0, 120.0, 101.5], [0, 0, 1]])
    N = tilted_normal(tilt)
    d = 50.0
    img = phong_plane_image(K, (204, 204), N, d, n=40)
    # pick pixels, intersect with the plane, express in a plane frame, compare with eq. 1
    rng = np.random.default_rng(3)
    uv = rng.uniform(0, 203, size=(50, 2)).round()
    rays = np.c_[uv, np.ones(50)] @ np.linalg.inv(K).T
    X = rays * (-d / (rays @ N))[:, None]
    u = np.cross(N, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    w = np.cross(N, u)
    foot = -d * N
    P = np.c_[(X - foot) @ u, (X - foot) @ w]
    expected = phong_intensity(P, [0, 0, d], [0, 0, d], 40)
    got = img[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-14)


def test_bp_is_foot_of_perpendicular_and_image_peak():
    K = np.array([[120.0, 0, 101.5], [0, 120.0, 101.5], [0, 0, 1]])
    N = tilted_normal(40.0, 20.0)
    bp = plane_bp(N, 50.0)
    np.testing.assert_allclose(bp, -50.0 * N)
    img = phong_plane_image(K, (204, 204), N, 50.0, n=60)
    peak = np.unravel_index(np.argmax(img), img.shape)[::-1]
    assert np.all(np.abs(np.array(peak) - project_points(bp, K)) <= 0.5)


def test_offset_light_bp_bisects_directions():
    N = tilted_normal(25.0)
    L = np.array([8.0, -3.0, 2.0])
    bp = plane_bp(N, 60.0, L)
    assert np.isclose(bp @ N, -60.0)
    to_cam = -bp / np.linalg.norm(bp)
    to_light = (L - bp) / np.linalg.norm(L - bp)
    assert angle_between_deg(to_cam + to_light, N) < 1e-9
    with pytest.raises(ValueError, match="side"):
        plane_bp(N, 60.0, -100 * N)


def test_isophote_of_analytic_image_is_the_projected_circle():
    # The t-isophote of the closed-form image lies on the projected circle of radius r- (Prop. 2),
    # and its cone axis is the normal (Notes of simtest.geometry.conics.cone_axis).
    K = np.array([[150.0, 0, 150.5], [0, 150.0, 150.5], [0, 0, 1]])
    N = tilted_normal(35.0)
    d, n, t = 40.0, 50.0, 0.1
    r = isophote_radius(t, n, d)
    C = project_circle(-d * N, N, r, K)
    ang = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    u = np.cross(N, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    w = np.cross(N, u)
    X = -d * N + r * (np.outer(np.cos(ang), u) + np.outer(np.sin(ang), w))
    uv = project_points(X, K)
    x = np.c_[uv, np.ones(len(uv))]
    assert np.abs(np.einsum("ni,ij,nj->n", x, C, x)).max() < 1e-9
    # intensity sampled exactly on those points equals t (pixel-free evaluation through a 1x1 K)
    for p in uv[:8]:
        Kp = K.copy()
        Kp[0, 2] -= p[0]
        Kp[1, 2] -= p[1]
        assert phong_plane_image(Kp, (1, 1), N, d, n)[0, 0] == pytest.approx(t, rel=1e-9)
    assert angle_between_deg(cone_axis(normalised_conic(C, K)).axis, N) < 1e-6


def test_supersampling_and_falloff():
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]])
    a = phong_plane_image(K, (64, 64), [0, 0, -1], 30.0, 20)
    b = phong_plane_image(K, (64, 64), [0, 0, -1], 30.0, 20, supersample=3)
    assert np.abs(a - b).max() < 0.05 and not np.array_equal(a, b)
    f = phong_plane_image(K, (64, 64), [0, 0, -1], 30.0, 20, falloff=True)
    assert f[32, 32] <= a[32, 32] and np.all(f <= a + 1e-15)
    with pytest.raises(ValueError):
        phong_plane_image(K, (0, 4), [0, 0, -1], 30.0, 20)


def test_sphere_and_cylinder_peak_at_their_bp():
    from _quadrics import cylinder_bp, phong_cylinder_image, phong_sphere_image, sphere_bp

    K = np.array([[150.0, 0, 150.5], [0, 150.0, 150.5], [0, 0, 1]])

    def at(uv, render):
        # evaluate the closed form exactly at sub-pixel uv: a 1x1 image whose pixel centre is uv
        Kp = K.copy()
        Kp[:2, 2] -= uv
        return render(Kp, (1, 1))[0, 0]

    S = np.array([10.0, 20.0, 80.0])
    bp, nrm = sphere_bp(S, 20.0)
    np.testing.assert_allclose(nrm, (bp - S) / 20.0)
    sph = lambda Kp, shape: phong_sphere_image(Kp, shape, S, 20.0, 50)  # noqa: E731
    uv = project_points(bp, K)
    assert at(uv, sph) == pytest.approx(1.0, abs=1e-12)
    assert sph(K, (302, 302)).max() <= 1.0
    P0, axis = np.array([5.0, 0.0, 60.0]), np.array([1.0, 1.0, 0.3])
    bp, nrm = cylinder_bp(P0, axis, 15.0)
    assert abs(nrm @ axis) < 1e-12 and angle_between_deg(nrm, -bp) < 1e-9
    cyl = lambda Kp, shape: phong_cylinder_image(Kp, shape, P0, axis, 15.0, 50)  # noqa: E731
    uv = project_points(bp, K)
    assert at(uv, cyl) == pytest.approx(1.0, abs=1e-12)
    # a step of one pixel away from the BP in any direction darkens the image
    for step in ([1, 0], [0, 1], [-1, 0], [0, -1]):
        assert at(uv + step, cyl) < 1.0 and at(uv + step, sph) < 1.0


def test_large_sphere_tends_to_its_tangent_plane():
    from _quadrics import phong_sphere_image, sphere_bp

    K = np.array([[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]])
    S = np.array([0.0, 0.0, 50.0 + 1e6])
    sph = phong_sphere_image(K, (64, 64), S, 1e6, 30)
    bp, nrm = sphere_bp(S, 1e6)
    pl = phong_plane_image(K, (64, 64), nrm, -(bp @ nrm), 30)
    # curvature 1e-6 /mm over a ~30 mm footprint changes the image by O(1e-5)
    assert np.abs(sph - pl).max() < 1e-4


# ------------------------------------------------------------------------------------------------
# brightest points of spheres and cylinders for any pose (simtest.simulate.truth)

import math  # noqa: E402

from hypothesis import example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from simtest.simulate import truth  # noqa: E402

_K = np.array([[100.0, 0, 127.5], [0, 100.0, 127.5], [0, 0, 1]])
#: The BP test: the sine of the angle between the normal and the bisector, as accepted by the
#: solver (STATIONARY_RESIDUAL_TOL, 1e-12: 100x float64 round-off of a unit vector).
_RES = truth.STATIONARY_RESIDUAL_TOL


def _residual(h, L):
    return truth._facing(h.bp_mm, h.normal, np.asarray(L, dtype=np.float64))[0]


@settings(max_examples=100, deadline=None)
@given(ax=st.floats(-50, 50), ay=st.floats(-50, 50), bx=st.floats(-50, 50), by=st.floats(-50, 50),
       r=st.floats(0.5, 20))
@example(ax=3.0, ay=1.1360032247523812e-07, bx=4.0, by=0.0, r=3.0)  # a on the circle, to rounding
def test_circle_reflection_is_the_mirror_point_and_the_shortest_path(ax, ay, bx, by, r):
    a, b = np.array([ax, ay]), np.array([bx, by])
    if not (np.hypot(*a) > r and np.hypot(*b) > r):
        with pytest.raises(ValueError):
            truth.circle_reflection(a, b, r)
        return
    w = truth.circle_reflection(a, b, r)
    ab = b - a
    t = 0.0 if not ab @ ab else min(1.0, max(0.0, -(a @ ab) / (ab @ ab)))
    near = np.hypot(*(a + t * ab))  # distance from the centre to the segment a-b
    assert (w is None) == (near <= r)  # None exactly when the segment meets the disk
    if w is None:
        return
    P = r * w
    g = (a - P) / np.linalg.norm(a - P) + (b - P) / np.linalg.norm(b - P)
    # the outward normal w bisects the directions to a and b: g is along +w. Tolerance: 1e-9 of
    # |g|, plus the rounding of the unit directions to a and b, which grows as a or b nears the
    # circle (a - P cancels: its direction carries eps * |a| / |a - P| of error)
    cond = np.linalg.norm(a) / np.linalg.norm(a - P) + np.linalg.norm(b) / np.linalg.norm(b - P)
    tol = 1e-9 * np.linalg.norm(g) + 8 * np.finfo(float).eps * cond
    assert abs(w[0] * g[1] - w[1] * g[0]) <= tol and w @ g > 0
    th = np.linspace(0, 2 * np.pi, 1024, endpoint=False)
    Q = r * np.stack([np.cos(th), np.sin(th)], -1)
    path = np.linalg.norm(Q - a, axis=1) + np.linalg.norm(Q - b, axis=1)
    assert np.linalg.norm(P - a) + np.linalg.norm(P - b) <= path.min() + 1e-9 * (1 + path.min())


def _first_solve_fails(monkeypatch):
    """Make the root solve from the co-located BP fail once per call, as hybr can (status 5)."""
    real = truth._solve_stationary
    state = {"n": 0}

    def flaky(*args, **kwargs):
        state["n"] += 1
        if state["n"] % 2 == 1:
            raise truth.HighlightTruthError("root solve stalled (status 5)")
        return real(*args, **kwargs)

    monkeypatch.setattr(truth, "_solve_stationary", flaky)
    return state


def _pose(kind, d, r, view, az, eps, al, b):
    v, a = math.radians(view), math.radians(az)
    L = eps * np.array([math.cos(math.radians(al)), math.sin(math.radians(al)), b])
    if kind == "sphere":
        c = (d + r) * np.array([math.sin(v) * math.cos(a), math.sin(v) * math.sin(a), math.cos(v)])
        return (lambda: truth.sphere_highlight(c, r, L, _K, (256, 256))), L
    c = np.array([0.0, 0.0, d + r])
    axis = np.array([math.cos(v) * math.cos(a), math.cos(v) * math.sin(a), math.sin(v)])
    return (lambda: truth.cylinder_highlight(c, axis, r, 20.0 * r, L, _K, (256, 256))), L


_POSES = dict(kind=st.sampled_from(["sphere", "cylinder"]), d=st.floats(0.2, 100.0),
              r=st.floats(1.0, 500.0), view=st.floats(0.0, 89.9), az=st.floats(0.0, 360.0),
              eps=st.floats(0.01, 20.0), al=st.floats(0.0, 360.0), b=st.floats(-0.5, 0.5))


@settings(max_examples=200, deadline=None)
@given(**_POSES)
# sample 41 of scenes/datasets/example.toml (first draw): the camera inside the tube
@example(kind="cylinder", d=20.028051617065902, r=77.63097395124659, view=43.22984035316789,
         az=215.66564796410472, eps=2.5, al=256.11167127703175, b=0.0)
# a light 1 mm beyond the tube's end, 0.75 mm from its axis (R 1 mm): no point of the outside is
# lit (found by hypothesis on a fresh clone's local run)
@example(kind="cylinder", d=1.0, r=1.0, view=0.0, az=0.0, eps=11.0, al=0.0, b=0.25)
# a camera 0.56 mm from a 210 mm sphere: the minimiser needs its polish
@example(kind="sphere", d=0.5610746778597463, r=210.58871159307196, view=2.98, az=21.0, eps=0.5,
         al=310.0, b=-0.14)
# the camera 0.2 mm from a 179 mm sphere: converged solves at residuals of 1e-12 to 8e-11
# (found by hypothesis on a local run outside CI's derandomised profile)
@example(kind="sphere", d=0.2, r=179.0, view=30.0, az=339.4453125, eps=0.62890625, al=30.0, b=0.0)
@example(kind="sphere", d=0.2, r=179.0, view=30.0, az=339.0, eps=0.62890625, al=30.0, b=0.0)
# a light 11 mm off a cylinder 3 mm away: the root solve's normal turned 90 deg from its start, where the
# tangential part of the bisector lay along the start's normal and read 0 in its basis (a point facing away
# from the camera, residual 0.34, was accepted); and a camera on the surface to rounding
# (found by hypothesis on local runs)
@example(kind="cylinder", d=3.0, r=1.0, view=40.0, az=0.0, eps=11.0, al=193.0, b=0.0)
@example(kind="cylinder", d=3.0, r=1.0, view=39.0, az=0.0, eps=10.0, al=192.0, b=0.0)
@example(kind="cylinder", d=1.0, r=1.0, view=60.0, az=46.0, eps=1.0, al=0.0, b=0.0)
@example(kind="cylinder", d=1.0, r=1.0, view=60.0, az=0.0, eps=1.0, al=0.0, b=0.0)
def test_the_path_minimiser_gives_the_root_solves_bp_for_any_pose(kind, d, r, view, az, eps, al, b):
    # Both routes, for the same pose: the root solve from the co-located BP, and the light-path
    # minimiser used where that solve fails. Same outcome (BP, None, or an error for a camera
    # inside the surface), the same point to 1e-9 mm, and the BP condition to the solver's bound.
    solve, L = _pose(kind, d, r, view, az, eps, al, b)
    outcomes = []
    for forced in (False, True):
        with pytest.MonkeyPatch.context() as m:
            if forced:
                _first_solve_fails(m)
            try:
                outcomes.append(solve())
            except truth.HighlightTruthError as exc:
                outcomes.append(str(exc))
    a, bb = outcomes
    if isinstance(a, str) or isinstance(bb, str):
        assert isinstance(a, str) and isinstance(bb, str), (a, bb)
        assert "camera is inside" in a and "camera is inside" in bb
        # (on the surface to rounding counts as inside: the camera's distance from the axis is computed
        # another way there)
        inside = (kind == "cylinder" and (d + r) * math.cos(math.radians(view)) <= r * (1 + 8 * np.finfo(float).eps))
        assert inside, a
        return
    assert (a is None) == (bb is None)
    if a is None:
        return
    assert np.linalg.norm(a.bp_mm - bb.bp_mm) <= 1e-9 * (1 + np.linalg.norm(a.bp_mm))
    for h in (a, bb):
        assert _residual(h, L) <= _RES
        assert np.dot(h.normal, h.bp_mm) < 0  # faces the camera


def test_sample_41_the_camera_inside_the_cylinder_is_named_not_a_solver_status():
    # The pose that stopped `dataset generate scenes/datasets/example.toml` at sample 41: the
    # axis passes 71.2 mm from the camera, inside R = 77.6 mm; the render is black (one-sided
    # surface seen from inside), so there is no BP, and the error says why.
    c = np.array([0.0, 0.0, 97.65902556831249])
    axis = np.array([-0.5919486191415929, -0.4248203036755105, 0.6849266689810001])
    L = np.array([-0.6001, -2.4269, 0.0])
    with pytest.raises(truth.HighlightTruthError, match=r"camera is inside the cylinder \(71.16 mm"):
        truth.cylinder_highlight(c, axis, 77.63097395124659, 1552.6, L, _K, (256, 256))
    # 10 mm thinner, the camera is outside: a BP that satisfies the condition
    h = truth.cylinder_highlight(c, axis, 67.63, 1352.6, L, _K, (256, 256))
    assert h is not None and _residual(h, L) <= _RES


def test_a_failed_solve_is_an_error_not_a_wrong_point(monkeypatch):
    """Both routes failing raises HighlightTruthError naming both, never returns a non-BP."""
    c, L = np.array([5.0, -3.0, 80.0]), np.array([8.0, 3.0, 1.0])

    def stalled(*args, **kwargs):
        raise truth.HighlightTruthError("root solve stalled (status 5)")

    monkeypatch.setattr(truth, "_solve_stationary", stalled)
    monkeypatch.setattr(truth, "circle_reflection", lambda a, b, r: np.array([0.6, 0.8]))
    with pytest.raises(truth.HighlightTruthError, match=r"status 5.*minimiser gives residual"):
        truth.sphere_highlight(c, 20.0, L, _K, (128, 128))
    with pytest.raises(truth.HighlightTruthError, match=r"status 5.*minimiser gives residual"):
        truth.cylinder_highlight(c, [1.0, 0.3, 0.2], 15.0, 1000.0, L, _K, (128, 128))


def test_no_point_faces_both_when_the_light_is_behind_the_body():
    # The segment from the camera to the light crosses the sphere: None (no highlight), not an error,
    # and no numpy warning on the way (the root search's bisector there is NaN, as documented)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert truth.sphere_highlight(np.array([0.0, 0.0, 50.0]), 10.0, np.array([0.0, 0.0, 100.0]),
                                      _K, (256, 256)) is None
