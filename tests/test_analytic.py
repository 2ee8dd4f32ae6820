"""Closed-form Phong images of a plane agree with the scene-plane model and the conic geometry."""

from __future__ import annotations

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
    from simtest.simulate.analytic import cylinder_bp, phong_cylinder_image, phong_sphere_image, sphere_bp

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
    from simtest.simulate.analytic import phong_sphere_image, sphere_bp

    K = np.array([[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]])
    S = np.array([0.0, 0.0, 50.0 + 1e6])
    sph = phong_sphere_image(K, (64, 64), S, 1e6, 30)
    bp, nrm = sphere_bp(S, 1e6)
    pl = phong_plane_image(K, (64, 64), nrm, -(bp @ nrm), 30)
    # curvature 1e-6 /mm over a ~30 mm footprint changes the image by O(1e-5)
    assert np.abs(sph - pl).max() < 1e-4
