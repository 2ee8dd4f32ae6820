"""Estimators: paper pair and its non-oracle choice, cone axis, joint axis, failures."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import (
    angle_between_deg,
    bp_ray_normal,
    normalised_conic,
    project_circle,
    project_points,
)
from simtest.reconstruct.estimators import (
    estimate_from_conic,
    estimate_from_conics,
    joint_cone_axes,
    joint_cone_axis,
    select_paper_normal,
)
from simtest.reconstruct.failures import Failure
from exact_tolerances import EXACT

from _cases import ellipse_to_conic, random_circle_pose

K = np.array([[320.0, 0.0, 202.5], [0.0, 300.0, 190.5], [0.0, 0.0, 1.0]])


def random_plane(seed, max_tilt_deg=70.0):
    """Foot of the perpendicular from the camera (the co-located BP) and the plane normal."""
    rng = np.random.default_rng(np.random.SeedSequence([99, seed]))
    foot_dir = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 1.0])
    foot = foot_dir / np.linalg.norm(foot_dir) * rng.uniform(50, 300)
    normal = -foot / np.linalg.norm(foot)
    return rng, foot, normal


@given(st.integers(0, 10_000))
@settings(max_examples=50, deadline=None)
def test_exact_circle_one_paper_normal_is_true(seed):
    centre, normal, radius, _ = random_circle_pose(seed, key=98)
    Cn = normalised_conic(project_circle(centre, normal, radius, K), K)
    bp_ray = bp_ray_normal(project_points(centre, K), K)
    est = estimate_from_conic(Cn, bp_ray)
    assert est
    assert angle_between_deg(est.paper, normal).min() < EXACT.exact_normal_deg
    # all normals unit and facing the camera along the BP ray
    for n in (*est.paper, est.cone_axis, est.paper_selected):
        assert abs(np.linalg.norm(n) - 1) < 1e-12
        assert n @ (-bp_ray) < 0
    # the pair is symmetric about the cone axis: the cone-axis rule cannot choose (a tie)
    a = angle_between_deg(est.paper, est.cone_axis)
    assert abs(a[0] - a[1]) < 1e-9
    # and the gap is sin^2 of that half-angle (circle_pose's geometry)
    assert abs(np.sin(np.radians(a[0])) ** 2 - est.eigenvalue_gap) < 1e-9


@given(st.integers(0, 10_000), st.floats(1.0, 40.0))
@settings(max_examples=40, deadline=None)
def test_co_located_circles_give_the_normal_by_every_estimator(seed, radius):
    _, foot, normal = random_plane(seed)
    Cn = normalised_conic(project_circle(foot, normal, radius, K), K)
    bp_ray = bp_ray_normal(project_points(foot, K), K)
    est = estimate_from_conic(Cn, bp_ray)
    assert angle_between_deg(est.cone_axis, normal) < EXACT.exact_normal_deg
    # N+ and N- sit at asin(sqrt(gap)) from the axis: near a right cone a rounding-level gap
    # (~1e-16) still tilts them by ~1e-8 rad (sqrt sensitivity of the paper's estimator), so they
    # are held to that bound instead of the closed-form tolerance.
    bound = np.degrees(np.arcsin(np.sqrt(est.eigenvalue_gap))) + EXACT.exact_normal_deg
    assert angle_between_deg(est.paper, normal).max() < bound
    assert bound < 1e-5
    assert angle_between_deg(bp_ray, normal) < EXACT.exact_normal_deg
    assert est.eigenvalue_gap < EXACT.right_cone_gap


@given(st.integers(0, 10_000), st.lists(st.floats(1.0, 60.0), min_size=2, max_size=5, unique=True))
@settings(max_examples=40, deadline=None)
def test_joint_axis_of_nested_co_located_circles_is_the_normal(seed, radii):
    _, foot, normal = random_plane(seed)
    bp_ray = bp_ray_normal(project_points(foot, K), K)
    cns = [normalised_conic(project_circle(foot, normal, r, K), K) for r in radii]
    # signs and scales of the conics must not matter
    cns = [(-1) ** i * (i + 1) * c for i, c in enumerate(cns)]
    axis = joint_cone_axis(cns, bp_ray)
    assert angle_between_deg(axis, normal) < EXACT.exact_normal_deg
    assert axis @ (-bp_ray) < 0


def test_joint_axis_averages_perturbed_axes():
    # Two right cones about axes tilted +-1 deg from the normal in one plane: the least-squares
    # common axis is the normal (by symmetry), to rounding.
    normal = np.array([0.0, 0.0, -1.0])
    cns = []
    for sgn in (1, -1):
        e = np.array([np.sin(np.radians(sgn)), 0.0, np.cos(np.radians(sgn))])
        cns.append(np.outer(e, e) - np.cos(np.radians(10)) ** 2 * np.eye(3))
    axis = joint_cone_axis(cns, normal)
    assert angle_between_deg(axis, normal) < 1e-9


def test_selection_rule_picks_the_one_closer_to_the_reference():
    pair = np.array([[0.1, 0.0, -1.0], [-0.3, 0.0, -1.0]])
    pair /= np.linalg.norm(pair, axis=1, keepdims=True)
    assert select_paper_normal(pair, np.array([0.0, 0.0, -1.0])) == 0
    assert select_paper_normal(pair, np.array([-0.5, 0.0, -1.0]) / np.hypot(0.5, 1)) == 1
    assert select_paper_normal(np.array([pair[0], pair[0]]), pair[0]) == 0  # tie -> N+


@pytest.mark.parametrize(
    "C",
    [
        np.diag([1.0, -1.0, -1.0]),  # hyperbola x^2 - y^2 = 1
        np.array([[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]]),  # line pair xy = 0
        np.diag([1.0, 1.0, 1.0]),  # imaginary ellipse
        np.zeros((3, 3)),
    ],
    ids=["hyperbola", "line_pair", "imaginary", "zero"],
)
def test_non_cones_fail_by_value(C):
    ray = np.array([0.0, 0.0, -1.0])
    est = estimate_from_conic(C, ray)
    assert not est and est.reason == "pose_failed"
    j = joint_cone_axis([C], ray)
    assert isinstance(j, Failure) and j.reason == "pose_failed"


def test_ellipse_conic_in_pixels_through_K():
    # A pixel-space ellipse centred on the principal point is a cone about the optical axis.
    C = ellipse_to_conic((202.5, 190.5), (30.0, 30.0 * 300 / 320), 0.0)
    est = estimate_from_conic(normalised_conic(C, K), np.array([0.0, 0.0, -1.0]))
    assert angle_between_deg(est.cone_axis, [0, 0, -1]) < EXACT.exact_normal_deg


@given(st.integers(0, 10_000))
@settings(max_examples=30, deadline=None)
def test_pipeline_hot_path_forms_agree_with_geometry(seed):
    # simtest.reconstruct.frame_prep computes the BP ray inline (K validated once per call); it
    # must equal simtest.geometry's function to rounding.
    from simtest.reconstruct.frame_prep import _bp_ray

    centre, normal, radius, _ = random_circle_pose(seed, key=98)
    uv = project_points(centre, K)
    assert angle_between_deg(_bp_ray(uv, K), bp_ray_normal(uv, K)) < 1e-9


@given(st.integers(0, 10_000), st.integers(1, 9))
@settings(max_examples=30, deadline=None)
def test_batched_estimators_are_bit_for_bit_those_of_each_cone_alone(seed, k):
    """estimate_from_conics and joint_cone_axes batch the eigen-decompositions and circle poses
    of a frame's isophotes; each cone's result must be the one it gets alone, to the last bit,
    with non-cones failing at their place and not touching the others."""
    cns, refs = [], []
    for i in range(k):
        centre, normal, radius, _ = random_circle_pose(seed + 7919 * i, key=97)
        cns.append(normalised_conic(project_circle(centre, normal, radius, K), K))
        refs.append(bp_ray_normal(project_points(centre, K), K))
    if k > 1:
        cns[1] = np.diag([1.0, -1.0, -1.0])  # a hyperbola: not a cone of a visible highlight
    cns, refs = np.array(cns), np.array(refs)
    batch = estimate_from_conics(cns, refs)
    for c, r, got in zip(cns, refs, batch):
        alone = estimate_from_conic(c, r)
        assert bool(got) == bool(alone)
        if not alone:
            assert (got.reason, got.detail) == (alone.reason, alone.detail)
            continue
        assert np.array_equal(got.paper, alone.paper) and np.array_equal(got.cone_axis, alone.cone_axis)
        assert got.paper_selected_index == alone.paper_selected_index
        assert got.eigenvalue_gap == alone.eigenvalue_gap
    # joint axes of consecutive pairs (groups of two conics)
    m = 2 * (k // 2)
    group = np.repeat(np.arange(m // 2), 2)
    joint = joint_cone_axes(cns[:m], group, refs[: m // 2])
    for g, got in enumerate(joint):
        alone = joint_cone_axis(cns[2 * g: 2 * g + 2], refs[g])
        if isinstance(alone, Failure):
            assert isinstance(got, Failure) and got.detail == alone.detail
        else:
            assert np.array_equal(got, alone)


# ---- moved from the deleted compiled kernels' tests: the exact truths of the numpy forms --------

@given(st.integers(0, 10_000), st.floats(-9.0, -2.0))
@settings(max_examples=60, deadline=None)
def test_a_near_right_cone_gives_its_circles_normal(seed, log_tilt):
    # a circle seen almost head-on (its normal 1e-9 to 1e-2 rad from its centre's viewing ray):
    # the same-sign eigenvalues nearly coincide, and one of N+ and N- is still the normal, the
    # cone axis within the tilt, at any scale and sign of C'
    centre, _, radius, rng = random_circle_pose(seed, key=131)
    view = centre / np.linalg.norm(centre)
    perp = np.cross(view, rng.normal(size=3))
    tilt = 10.0 ** log_tilt
    normal = -np.cos(tilt) * view + np.sin(tilt) * perp / np.linalg.norm(perp)
    cn = normalised_conic(project_circle(centre, normal, radius, K), K)
    cn = cn * rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-6.0, 6.0)
    est = estimate_from_conic(cn, bp_ray_normal(project_points(centre, K), K))
    assert est
    # 1e-5 deg: the rounding of the projected conic, amplified near a right cone
    assert min(angle_between_deg(est.paper[0], normal), angle_between_deg(est.paper[1], normal)) < 1e-5
    assert angle_between_deg(est.cone_axis, normal) < np.degrees(tilt) + 1e-5


def test_non_cones_fail_with_their_reason_in_a_batch_of_cones():
    good = normalised_conic(project_circle(np.array([5.0, -3.0, 80.0]), np.array([0.2, 0.1, -1.0]) / np.sqrt(1.05),
                                           6.0, K), K)
    bad = [np.diag([1.0, -1.0, -1.0]), np.eye(3), np.diag([1.0, -1.0, 0.0]), np.zeros((3, 3)),
           np.full((3, 3), np.nan), np.diag([np.inf, 1.0, -1.0])]
    cns = np.stack([good, *bad, good])
    refs = np.tile(np.array([0.0, 0.0, -1.0]), (len(cns), 1))
    out = estimate_from_conics(cns, refs)
    assert out[0] and out[-1] and np.array_equal(out[0].paper, out[-1].paper)
    assert all(isinstance(f, Failure) and f.reason == "pose_failed" for f in out[1:-1])
    axes = joint_cone_axes(cns, np.array([0, 1, 1, 2, 2, 2, 2, 3]), refs[:4])
    assert not isinstance(axes[0], Failure) and not isinstance(axes[3], Failure)
    assert isinstance(axes[1], Failure) and isinstance(axes[2], Failure)
    assert np.array_equal(axes[0], axes[3])
