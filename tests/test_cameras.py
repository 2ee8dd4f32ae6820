"""Camera models: round trips over the whole frame, agreement with OpenCV and with the published
formula, and Jacobians against finite differences."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg
from simtest.geometry.camera import IntrinsicsError
from simtest.geometry.cameras import (
    CameraModel,
    FisheyeCamera,
    OmnidirectionalCamera,
    PinholeCamera,
    c3vd_camera,
)
from exact_tolerances import EXACT

from _cases import frame_pixels

C3VD = dict(
    cx=678.544839263292, cy=542.975887548343,
    a=(769.243600037458, 0.0, -0.000812770624150226, 6.25674244578925e-07, -1.1966218214428e-09),
    c=0.99998688224999, d=0.00288273829525059, e=-0.00296316513429569,
)


def round_trip_error(cam: CameraModel, step: float) -> float:
    uv = frame_pixels(cam, step)
    rays = cam.pixel_to_ray(uv)
    assert np.all(np.isfinite(rays)), "a pixel of the frame has no ray"
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    back = cam.ray_to_pixel(rays * 3.7)  # any positive scale
    return float(np.abs(back - uv).max())


# ---------------------------------------------------------------- round trips (must hold: 1e-6 px)


def test_c3vd_round_trip_every_pixel():
    cam = c3vd_camera()
    assert round_trip_error(cam, 1.0) < EXACT.camera_round_trip_px
    # sub-pixel positions too
    rng = np.random.default_rng(1)
    W, H = cam.image_size
    uv = np.stack([rng.uniform(0, W - 1, 20000), rng.uniform(0, H - 1, 20000)], axis=1)
    assert np.abs(cam.ray_to_pixel(cam.pixel_to_ray(uv)) - uv).max() < EXACT.camera_round_trip_px


size = st.tuples(st.integers(16, 900), st.integers(16, 900))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    size=size,
    f_rel=st.floats(0.6, 2.0),
    aspect=st.floats(0.9, 1.1),
    skew=st.floats(-0.01, 0.01),
    c_off=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)),
    k=st.tuples(st.floats(-0.2, 0.2), st.floats(-0.05, 0.05), st.floats(-0.01, 0.01)),
    p=st.tuples(st.floats(-0.002, 0.002), st.floats(-0.002, 0.002)),
    rational=st.booleans(),
)
def test_pinhole_round_trip_whole_frame(size, f_rel, aspect, skew, c_off, k, p, rational):
    W, H = size
    f = f_rel * max(W, H)
    K = np.array([[f, skew * f, (W - 1) / 2 + c_off[0] * W], [0, f * aspect, (H - 1) / 2 + c_off[1] * H], [0, 0, 1]])
    dist = [k[0], k[1], p[0], p[1], k[2]] + ([0.3 * k[0], 0.0, 0.0] if rational else [])
    # the radial map must stay monotone out to the corner for an inverse to exist
    r = np.linspace(0, 1.2 * np.hypot(W, H) / f, 400)
    rd = r * (1 + k[0] * r**2 + k[1] * r**4 + k[2] * r**6) / (1 + (0.3 * k[0] if rational else 0) * r**2)
    assume(np.all(np.diff(rd) > 1e-3 * (r[1] - r[0])))
    cam = PinholeCamera(K, dist, (W, H))
    assert round_trip_error(cam, max(1.0, max(W, H) / 60)) < EXACT.camera_round_trip_px


@settings(max_examples=25, deadline=None)
@given(
    size=size,
    f_rel=st.floats(0.25, 1.0),
    D=st.tuples(st.floats(-0.05, 0.05), st.floats(-0.02, 0.02), st.floats(-0.005, 0.005), st.floats(-0.001, 0.001)),
)
def test_fisheye_round_trip_whole_frame(size, f_rel, D):
    W, H = size
    f = f_rel * max(W, H)
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    try:
        cam = FisheyeCamera(K, D, (W, H))
    except IntrinsicsError:
        assume(False)
    assert round_trip_error(cam, max(1.0, max(W, H) / 60)) < EXACT.camera_round_trip_px


@settings(max_examples=25, deadline=None)
@given(
    scale=st.floats(0.2, 1.5),
    poly=st.tuples(st.floats(0.8, 1.2), st.floats(0.8, 1.2), st.floats(0.8, 1.2)),
    a1=st.floats(-0.01, 0.01),
    cde=st.tuples(st.floats(0.97, 1.03), st.floats(-0.01, 0.01), st.floats(-0.01, 0.01)),
    shift=st.tuples(st.floats(-20, 20), st.floats(-20, 20)),
)
def test_omnidirectional_round_trip_whole_frame(scale, poly, a1, cde, shift):
    # C3VD-like calibrations scaled to other sensor sizes: r -> r / scale keeps the angles
    a0, _, a2, a3, a4 = C3VD["a"]
    a = (a0 * scale, a1, a2 * poly[0] / scale, a3 * poly[1] / scale**2, a4 * poly[2] / scale**3)
    W, H = max(16, int(1350 * scale)), max(16, int(1080 * scale))
    try:
        cam = OmnidirectionalCamera((W - 1) / 2 + shift[0] * scale, (H - 1) / 2 + shift[1] * scale, a, *cde, (W, H))
    except IntrinsicsError:
        assume(False)
    assert round_trip_error(cam, max(1.0, max(W, H) / 60)) < EXACT.camera_round_trip_px


# ------------------------------------------------------------------------ against other sources


def test_pinhole_forward_is_opencv_projectpoints():
    K = np.array([[500.0, 0, 320], [0, 480, 240], [0, 0, 1]])
    d = np.array([-0.3, 0.1, 0.001, -0.002, -0.02, 0.01, 0.002, 0.0005, 0.001, 0.0002, -0.001, 0.0003])
    cam = PinholeCamera(K, d, (640, 480))
    rays = cam.pixel_to_ray(frame_pixels(cam, 16.0))
    cvp, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, d)
    # both closed form in float64: agreement to rounding of a 10^3 px number
    np.testing.assert_allclose(cam.ray_to_pixel(rays), cvp.reshape(-1, 2), atol=1e-9)


def test_fisheye_forward_is_opencv_fisheye():
    K = np.array([[300.0, 0, 320], [0, 310, 240], [0, 0, 1]])
    cam = FisheyeCamera(K, [0.05, -0.01, 0.002, -0.0003], (640, 480))
    rays = cam.pixel_to_ray(frame_pixels(cam, 16.0))
    assert rays[:, 2].min() > 0  # OpenCV's fisheye works through X / Z: compare in front only
    cvp, _ = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, cam.D)
    np.testing.assert_allclose(cam.ray_to_pixel(rays), cvp.reshape(-1, 2), atol=1e-9)


def test_omnidirectional_is_the_published_formula():
    cam = c3vd_camera()
    rng = np.random.default_rng(2)
    uv = np.stack([rng.uniform(0, 1349, 500), rng.uniform(0, 1079, 500)], axis=1)
    A = np.array([[C3VD["c"], C3VD["d"]], [C3VD["e"], 1.0]])
    xy = np.linalg.solve(A, (uv - [C3VD["cx"], C3VD["cy"]]).T).T
    r = np.hypot(xy[:, 0], xy[:, 1])
    z = sum(ai * r**i for i, ai in enumerate(C3VD["a"]))
    p = np.column_stack([xy, z])
    np.testing.assert_allclose(cam.pixel_to_ray(uv), p / np.linalg.norm(p, axis=1, keepdims=True), atol=1e-14)
    np.testing.assert_allclose(cam.principal_point, [C3VD["cx"], C3VD["cy"]])
    np.testing.assert_allclose(cam.ray_to_pixel(np.array([[0.0, 0.0, 2.0]]))[0], cam.principal_point, atol=1e-12)


def test_c3vd_field_of_view_exceeds_pinhole():
    # the frame's corners see past 90 deg off the axis: no pinhole can describe them
    cam = c3vd_camera()
    W, H = cam.image_size
    corners = cam.pixel_to_ray(np.array([[0.0, 0.0], [W - 1, H - 1]]))
    assert np.all(angle_between_deg(corners, [0, 0, 1]) > 90)
    stand_in = cam.pinhole_stand_in()
    np.testing.assert_allclose(stand_in.K[0, 0], C3VD["a"][0])


def test_outside_domain_is_nan_not_an_exception():
    K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])
    cam = PinholeCamera(K, None, (101, 101))
    assert np.all(np.isnan(cam.ray_to_pixel(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]))))
    omni = c3vd_camera()
    assert np.all(np.isnan(omni.ray_to_pixel(np.array([[0.0, 0.0, -1.0]]))))  # 180 deg: past its 121 deg


# ---------------------------------------------------------------------------------- Jacobians


def cameras():
    K = np.array([[500.0, 1.5, 320], [0, 480, 240], [0, 0, 1]])
    return [
        c3vd_camera(),
        PinholeCamera(K, None, (640, 480)),
        PinholeCamera(K, [-0.3, 0.1, 0.001, -0.002, -0.02, 0.01, 0.002, 0.0005, 0.001, 0.0002, -0.001, 0.0003], (640, 480)),
        FisheyeCamera(np.array([[200.0, 0, 320], [0, 210, 240], [0, 0, 1]]), [0.05, -0.01, 0.002, -0.0003], (640, 480)),
    ]


@pytest.mark.parametrize("cam", cameras(), ids=lambda c: f"{c.model}{'' if getattr(c, 'dist_coeffs', None) is None else '+dist'}")
def test_jacobians_match_finite_differences(cam):
    rng = np.random.default_rng(3)
    W, H = cam.image_size
    uv = np.stack([rng.uniform(0, W - 1, 200), rng.uniform(0, H - 1, 200)], axis=1)
    uv = np.vstack([uv, cam.principal_point])  # the axis is a special case of every model
    J = cam.pixel_to_ray_jacobian(uv)
    assert J.shape == (len(uv), 3, 2)
    h = 1e-3  # px
    fd = np.stack([(cam.pixel_to_ray(uv + e * h) - cam.pixel_to_ray(uv - e * h)) / (2 * h) for e in np.eye(2)], axis=2)
    scale = np.abs(J).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(J - fd) <= EXACT.camera_jacobian_rel * scale)
    rays = cam.pixel_to_ray(uv)
    np.testing.assert_allclose(np.einsum("ni,nij->nj", rays, J), 0.0, atol=1e-12)  # unit rays
    s = rng.uniform(0.5, 3.0, (len(uv), 1))
    JP = cam.ray_to_pixel_jacobian(rays * s)
    assert JP.shape == (len(uv), 2, 3)
    h = 1e-5
    fd = np.stack([(cam.ray_to_pixel(rays * s + e * h) - cam.ray_to_pixel(rays * s - e * h)) / (2 * h) for e in np.eye(3)], axis=2)
    scale = np.abs(JP).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(JP - fd) <= EXACT.camera_jacobian_rel * scale)
    assert np.all(np.abs(np.einsum("nij,nj->ni", JP, rays * s)) <= 1e-9 * scale[:, :, 0])
    # the two are inverse on the tangent plane
    np.testing.assert_allclose(JP @ J * s[:, :, None], np.broadcast_to(np.eye(2), (len(uv), 2, 2)), atol=1e-9)


# ---------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("build", "msg"),
    [
        (lambda: PinholeCamera(np.eye(3) * [100, 100, 1], [0.1, 0.2, 0.3]), "4, 5, 8, 12 or 14"),
        (lambda: PinholeCamera(np.eye(3), [0.0] * 12 + [0.1, 0.0]), "tilted"),
        (lambda: PinholeCamera(np.eye(3), None, (0, 10)), "image_size"),
        (lambda: FisheyeCamera(np.eye(3), [0.1, 0.2]), "4 finite"),
        (lambda: FisheyeCamera(np.eye(3) * [100, 100, 1] + [[0, 0, 50], [0, 0, 50], [0, 0, 0]], [-0.5, 0, 0, 0], (101, 101)), "not invertible"),
        (lambda: OmnidirectionalCamera(0, 0, (1, 0, 0, 0), 1, 0, 0), "5 coefficients"),
        (lambda: OmnidirectionalCamera(0, 0, (-1, 0, 0, 0, 0), 1, 0, 0), "a0"),
        (lambda: OmnidirectionalCamera(0, 0, (1, 0, 0, 0, 0), 0, 0, 0), "singular"),
        (lambda: OmnidirectionalCamera(True, 0, (1, 0, 0, 0, 0), 1, 0, 0), "cx: must be a number"),
        (lambda: OmnidirectionalCamera(0, 0, (1, 0, float("nan"), 0, 0), 1, 0, 0), "a2: must be finite"),
        # z = 100 + 0.01 r^2: the angle atan(r / z) peaks at r = 100 px, atan(0.5) = 26.57 deg
        (lambda: OmnidirectionalCamera(200, 200, (100, 0, 0.01, 0, 0), 1, 0, 0, (400, 400)),
         r"angle off the axis stops growing at 26\.6 deg, 100 px"),
    ],
)
def test_bad_parameters_are_one_line_errors(build, msg):
    with pytest.raises(IntrinsicsError, match=msg) as info:
        build()
    assert "\n" not in str(info.value)


def test_a_camera_model_leaves_the_callers_arrays_writable_and_keeps_its_own():
    # A model froze the very float64 arrays it was given, so a user's K became read-only after a
    # reconstruction call; the model now keeps read-only copies.
    K = np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]])
    dist = np.array([0.1, -0.05, 0.001, 0.002, 0.0])
    D = np.array([0.01, -0.002, 0.0003, 0.0])
    ray = np.array([[0.1, 0.2, 1.0]])
    for cam, given in ((PinholeCamera(K, dist), (K, dist)), (FisheyeCamera(K, D), (K, D))):
        before = cam.ray_to_pixel(ray)
        for a in given:
            assert a.flags.writeable
            a += 1.0  # the caller changes its arrays: the model does not move
            a -= 1.0
        assert not cam.K.flags.writeable
        K[0, 2] = 999.0
        np.testing.assert_array_equal(cam.ray_to_pixel(ray), before)
        K[0, 2] = 50.0
    from simtest.reconstruct import reconstruct_roi

    img = np.zeros((81, 101))
    img[40, 50] = 1.0
    reconstruct_roi(img, K, 0.5, bp_uv=(50.0, 40.0))
    assert K.flags.writeable
