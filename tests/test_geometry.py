"""Exact geometric truths of conics, circle pose and the cone axis (Notes of simtest.geometry.conics.cone_axis)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from simtest.geometry import (
    IntrinsicsError,
    angle_between_deg,
    bp_ray_normal,
    circle_pose,
    conic_kind,
    conic_to_ellipse,
    cone_axis,
    load_camera,
    look_at,
    normalised_conic,
    pixel_to_ray,
    project_circle,
    project_points,
    save_intrinsics,
    validate_intrinsics,
)
from exact_tolerances import EXACT

from _cases import ellipse_to_conic, random_circle_pose, sample_ellipse, undistort_points

K = np.array([[320.0, 0.0, 202.5], [0.0, 300.0, 190.5], [0.0, 0.0, 1.0]])


@given(st.integers(0, 10_000))
@settings(max_examples=60, deadline=None)
@example(2365)  # a steep plane far off-axis: faces the camera with n_z > 0
def test_circle_pose_exact_conic_gives_true_normal(seed):
    centre, normal, radius, _ = random_circle_pose(seed)
    C = project_circle(centre, normal, radius, K)
    pose = circle_pose(normalised_conic(C, K))
    errors = angle_between_deg(pose.normals, normal)
    assert errors.min() < EXACT.exact_normal_deg
    # the matching solution also gives the direction of the circle centre
    best = int(np.argmin(errors))
    assert angle_between_deg(pose.centres[best], centre) < EXACT.exact_normal_deg
    # both normals face the camera
    assert np.all(pose.normals @ (centre / np.linalg.norm(centre)) < 0)


@given(st.integers(0, 10_000))
@settings(max_examples=40, deadline=None)
def test_co_located_circle_gives_right_cone_with_normal_axis(seed):
    # A circle centred on the foot of the perpendicular from the camera: the cone is right circular
    # and its axis is the plane normal (Notes of cone_axis).
    rng = np.random.default_rng(np.random.SeedSequence([99, seed]))
    tilt = np.radians(rng.uniform(0, 60))
    az = rng.uniform(0, 2 * np.pi)
    normal = np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)])
    d = rng.uniform(20, 200)
    C = project_circle(-d * normal, normal, rng.uniform(0.05, 0.8) * d, K)
    Cn = normalised_conic(C, K)
    ca = cone_axis(Cn)
    assert angle_between_deg(ca.axis, normal) < EXACT.exact_normal_deg
    assert ca.eigenvalue_gap < EXACT.right_cone_gap
    pose = circle_pose(Cn)
    # Both circle-pose normals coincide with the axis, up to the conditioning of circle pose near a
    # right cone: they tilt by asin(sqrt(gap)), so rounding of order 1e-16 in the eigenvalues shows
    # as ~1e-8 rad, and a gap at the right-cone threshold as sqrt(1e-9) rad = 1.8e-3 deg.
    bound_deg = np.degrees(np.arcsin(np.sqrt(EXACT.right_cone_gap)))
    assert np.all(angle_between_deg(pose.normals, normal) < bound_deg)


def test_eigenvalue_gap_is_sin2_of_circle_pose_tilt():
    centre, normal, radius = np.array([10.0, -20.0, 200.0]), np.array([0.3, 0.1, -1.0]), 15.0
    Cn = normalised_conic(project_circle(centre, normal, radius, K), K)
    ca = cone_axis(Cn)
    pose = circle_pose(Cn)
    tilt = angle_between_deg(pose.normals, ca.axis)
    assert ca.eigenvalue_gap > 1e-4  # an off-centre circle: not a right cone
    np.testing.assert_allclose(tilt, ca.circle_pose_tilt_deg, atol=1e-9)


@given(st.integers(0, 10_000))
@settings(max_examples=60, deadline=None)
def test_ellipse_conic_round_trip(seed):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-500, 500, 2)
    b = rng.uniform(0.5, 200)
    a = b * rng.uniform(1.0, 20)
    angle = rng.uniform(-np.pi / 2, np.pi / 2)
    C = ellipse_to_conic(centre, (a, b), angle)
    assert conic_kind(C) == "ellipse"
    e = conic_to_ellipse(C * rng.choice([-1, 1]) * rng.uniform(1e-3, 1e3))
    np.testing.assert_allclose(e.center, centre, rtol=0, atol=1e-7 * (1 + np.abs(centre).max()))
    np.testing.assert_allclose(e.semi_axes, (a, b), rtol=1e-8)
    if a / b > 1 + 1e-6:  # the orientation of a circle is undefined
        d = (e.angle_rad - angle + np.pi / 2) % np.pi - np.pi / 2
        assert abs(d) < 1e-6
    pts = sample_ellipse(e, 50)
    x = np.c_[pts, np.ones(len(pts))]
    Cu = C / np.linalg.norm(C)
    assert np.abs(np.einsum("ni,ij,nj->n", x, Cu, x)).max() < 1e-9


@pytest.mark.parametrize(
    ("C", "kind"),
    [
        (np.diag([1.0, -1.0, -1.0]), "hyperbola"),
        (np.array([[0.0, 0, -0.5], [0, 1, 0], [-0.5, 0, 0]]), "parabola"),  # v^2 - u = 0
        (np.diag([1.0, 1.0, 0.0]), "degenerate"),  # a point
        (np.array([[0.0, 0.5, 0], [0.5, 0, 0], [0, 0, 0]]), "degenerate"),  # u v = 0: two lines
        (np.diag([1.0, 1.0, 1.0]), "imaginary"),
        (np.diag([1.0, 4.0, -1.0]), "ellipse"),
    ],
)
def test_conic_kind(C, kind):
    assert conic_kind(C) == kind
    assert (conic_to_ellipse(C) is None) == (kind != "ellipse")


def test_non_cones_are_refused_by_circle_pose_and_cone_axis():
    for C in (np.diag([1.0, 1.0, 1.0]), np.diag([1.0, 1.0, 0.0]), np.zeros((3, 3)) + np.eye(3) * [1, 0, -1]):
        with pytest.raises(ValueError, match="not a real elliptic cone"):
            cone_axis(C)
        with pytest.raises(ValueError, match="not a real elliptic cone"):
            circle_pose(C)
    with pytest.raises(ValueError, match="non-finite"):
        cone_axis(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="3x3"):
        cone_axis(np.eye(2))


def test_angle_between_resolves_tiny_angles():
    a = np.array([0.0, 0.0, 1.0])
    eps = 1e-9  # rad; arccos(dot) returns 0 here (1 - eps^2/2 rounds to 1)
    b = np.array([np.sin(eps), 0.0, np.cos(eps)])
    assert np.isclose(angle_between_deg(a, b), np.degrees(eps), rtol=1e-6)
    assert angle_between_deg(a, -a) == 180.0
    assert np.isnan(angle_between_deg(a, np.zeros(3)))
    out = angle_between_deg(np.tile(a, (4, 1)), b)
    assert out.shape == (4,)


def test_projection_and_rays_are_inverse_with_integer_pixel_centres():
    # Convention worked number: K maps direction (0.1, 0.2, 1) to pixel (cx + 0.1 fx, cy + 0.2 fy).
    Kw = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    np.testing.assert_allclose(project_points([0.1, 0.2, 1.0], Kw), [60.0, 60.0])
    uv = np.array([[0.0, 0.0], [405.0, 405.0], [202.5, 190.5]])
    rays = pixel_to_ray(uv, K)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0)
    np.testing.assert_allclose(project_points(rays * 37.0, K), uv, atol=1e-10)
    np.testing.assert_allclose(bp_ray_normal([202.5, 190.5], K), [0, 0, -1], atol=1e-15)


@pytest.mark.parametrize(
    ("K_bad", "msg"),
    [
        (np.eye(2), "3x3"),
        (np.array([[np.nan, 0, 1], [0, 1, 1], [0, 0, 1]]), "non-finite"),
        (np.array([[-100.0, 0, 1], [0, 100, 1], [0, 0, 1]]), "focal"),
        (np.array([[100.0, 0, 1], [0, 100, 1], [0, 1, 1]]), "last row"),
        (np.array([[0.0, 0, 1], [0, 100, 1], [0, 0, 1]]), "focal"),
        ("abc", "numeric"),
    ],
)
def test_validate_intrinsics_rejects_bad_K(K_bad, msg):
    with pytest.raises(IntrinsicsError, match=msg):
        validate_intrinsics(K_bad, where="test K")


def test_intrinsics_json_and_opencv_yaml_round_trip(tmp_path):
    import cv2

    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.0])
    p = save_intrinsics(tmp_path / "k.json", K, dist_coeffs=dist, image_size=(406, 381))
    intr = load_camera(p).model
    np.testing.assert_array_equal(intr.K, K)
    np.testing.assert_array_equal(intr.dist_coeffs, dist)
    assert intr.image_size == (406, 381)
    y = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(y), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("dist_coeffs", dist.reshape(1, 5))
    fs.write("image_width", 406)
    fs.write("image_height", 381)
    fs.release()
    intr2 = load_camera(y).model
    np.testing.assert_allclose(intr2.K, K)
    np.testing.assert_allclose(intr2.dist_coeffs, dist)
    assert intr2.image_size == (406, 381)


def test_intrinsics_file_errors_name_file_and_key(tmp_path):
    with pytest.raises(IntrinsicsError, match="not found"):
        load_camera(tmp_path / "missing.json").model
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(IntrinsicsError, match="bad.json: not valid JSON"):
        load_camera(bad).model
    nok = tmp_path / "nok.json"
    nok.write_text(json.dumps({"k": 1}))
    with pytest.raises(IntrinsicsError, match="missing key 'K'"):
        load_camera(nok).model
    neg = tmp_path / "neg.json"
    neg.write_text(json.dumps({"K": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}))
    with pytest.raises(IntrinsicsError, match="neg.json: key 'K': focal"):
        load_camera(neg).model
    dist = tmp_path / "dist.json"
    dist.write_text(json.dumps({"K": K.tolist(), "dist_coeffs": [1, 2, 3]}))
    with pytest.raises(IntrinsicsError, match="dist_coeffs"):
        load_camera(dist).model


def test_undistort_inverts_opencv_distortion():
    import cv2

    dist = np.array([-0.25, 0.08, 0.0005, -0.0007, -0.01])
    rays = pixel_to_ray(np.array([[30.0, 40.0], [202.5, 190.5], [380.0, 20.0]]), K)
    pts, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    und = undistort_points(pts.reshape(-1, 2), K, dist)
    # iterated to 1e-12 in normalised coordinates: 1e-6 px leaves margin for the iteration's stop
    np.testing.assert_allclose(und, project_points(rays, K), atol=1e-6)
    np.testing.assert_array_equal(undistort_points(pts.reshape(-1, 2), K, None), pts.reshape(-1, 2))


def test_look_at_is_opencv_frame():
    T = look_at([0, 0, 0], [0, 0, 10], up=(0, -1, 0))
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-15)
    T = look_at([1, 2, 3], [1, 2, -7], up=(0, 1, 0))
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0, 0, -1], atol=1e-15)
    assert np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 0], [0, 1, 0], up=(0, 1, 0))


@pytest.mark.parametrize("centre", [(0.0, 0.0), (1300.0, 1000.0), (-5e4, 2e4)])
def test_conic_kind_does_not_depend_on_position(centre):
    # a small (2 x 0.5 px) ellipse is an ellipse wherever it lies in the image
    C = ellipse_to_conic(centre, (2.0, 0.5), 0.3)
    assert conic_kind(C) == "ellipse"
    e = conic_to_ellipse(C)
    np.testing.assert_allclose(e.semi_axes, (2.0, 0.5), rtol=1e-6)
    # and a point / crossing lines centred there are degenerate
    T = np.array([[1.0, 0, -centre[0]], [0, 1.0, -centre[1]], [0, 0, 1]])
    assert conic_kind(T.T @ np.diag([1.0, 4.0, 0.0]) @ T) == "degenerate"
    assert conic_kind(T.T @ np.diag([1.0, -4.0, 0.0]) @ T) == "degenerate"
    assert conic_kind(T.T @ np.diag([1.0, -4.0, -1.0]) @ T) == "hyperbola"


_finite = st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=False)


@given(a=st.lists(_finite, min_size=3, max_size=3), b=st.lists(_finite, min_size=3, max_size=3))
@settings(max_examples=200, deadline=None)
def test_cross3_is_np_cross_bit_for_bit(a, b):
    from simtest.geometry.angles import cross3

    want = np.cross(np.array(a), np.array(b))
    assert np.array_equal(cross3(a, b), want) and cross3(a, b).dtype == np.float64


@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from([(1,), (5,), (2, 4), (0,)]),
       broadcast=st.booleans(), scale=st.sampled_from([1e-300, 1.0, 1e150]))
@settings(max_examples=200, deadline=None)
def test_cross3_of_stacks_is_np_cross_bit_for_bit(seed, shape, broadcast, scale):
    # stacks (plane_basis' rows, angle_between_deg's): the same bits as np.cross's, each row its own;
    # the scales reach underflow and overflow, where the order of the operations shows
    from simtest.geometry.angles import cross3

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(*shape, 3)) * scale
    b = rng.normal(size=(3,) if broadcast else (*shape, 3))
    got, want = cross3(a, b), np.cross(a, b)
    assert got.shape == want.shape and got.dtype == np.float64
    assert np.array_equal(got, want, equal_nan=True)
