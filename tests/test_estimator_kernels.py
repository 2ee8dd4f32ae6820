"""The compiled estimators (simtest.reconstruct._estimator_kernels) against the numpy forms.

The numpy forms (``estimate_from_conics(..., compiled=False)``, ``joint_cone_axes(...,
compiled=False)``) stay in the code as the reference and the fallback. These tests run both on
stacks of normalised conics of every kind the pipeline meets or must refuse: exact and noisy
circle poses at any scale and sign, near-right cones (a plane seen almost head-on, where which of
the pair is N+ turns on the last bit of the cone), and non-cones (hyperbola, imaginary, line pair,
parabola, zero, non-finite).

Failures must be identical, reason and detail (the kernels hand every failing conic, or group,
over to the numpy form), and the estimates the same bits: the kernels decompose the same matrices
with the same LAPACK routine and sum in the numpy forms' order.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from _cases import random_circle_pose
from simtest.geometry import bp_ray_normal, normalised_conic, project_circle, project_points
from simtest.reconstruct import _estimator_kernels
from simtest.reconstruct.estimators import estimate_from_conics, joint_cone_axes
from simtest.reconstruct.failures import Failure
from simtest.tolerances import TOL

K = np.array([[320.0, 0.0, 202.5], [0.0, 300.0, 190.5], [0.0, 0.0, 1.0]])

_NON_CONES = {
    "hyperbola": np.diag([1.0, -1.0, -1.0]),
    "imaginary": np.eye(3),
    "line_pair": np.diag([1.0, -1.0, 0.0]),
    "parabola": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -0.5], [0.0, -0.5, 0.0]]),
    "zero": np.zeros((3, 3)),
    "nan": np.full((3, 3), np.nan),
    "inf": np.diag([np.inf, 1.0, -1.0]),
}


def _cone(seed: int, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """A normalised conic of the kind and the BP-ray normal of its circle's centre."""
    centre, normal, radius, rng = random_circle_pose(seed, key=131)
    ray = bp_ray_normal(project_points(centre, K), K)
    if kind in _NON_CONES:
        return _NON_CONES[kind], ray
    if kind == "head_on":  # tilted 1e-9 to 1e-2 rad from the centre's viewing ray: near-right cone
        view = centre / np.linalg.norm(centre)
        perp = np.cross(view, rng.normal(size=3))
        tilt = 10.0 ** rng.uniform(-9.0, -2.0)
        normal = -np.cos(tilt) * view + np.sin(tilt) * perp / np.linalg.norm(perp)
    cn = normalised_conic(project_circle(centre, normal, radius, K), K)
    if kind == "noisy":
        cn = cn + 10.0 ** rng.uniform(-8.0, -2.0) * rng.standard_normal((3, 3))
    return cn * rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-6.0, 6.0), ray


KINDS = ["exact", "head_on", "noisy", *_NON_CONES]


@given(st.integers(0, 100_000), st.lists(st.sampled_from(KINDS), min_size=1, max_size=12))
@settings(max_examples=60, deadline=None)
def test_cone_estimates_are_the_numpy_forms_bits(seed, kinds):
    pairs = [_cone(seed + 7919 * i, kind) for i, kind in enumerate(kinds)]
    cns, refs = np.array([c for c, _ in pairs]), np.array([r for _, r in pairs])
    got = estimate_from_conics(cns, refs)
    want = estimate_from_conics(cns, refs, compiled=False)
    for kind, g, w in zip(kinds, got, want):
        assert bool(g) == bool(w), kind
        if not w:
            assert (g.reason, g.detail) == (w.reason, w.detail), kind
            continue
        assert np.array_equal(g.paper, w.paper) and np.array_equal(g.cone_axis, w.cone_axis), kind
        assert np.array_equal(g.paper_selected, w.paper_selected), kind
        assert g.paper_selected_index == w.paper_selected_index and g.eigenvalue_gap == w.eigenvalue_gap


def test_every_kernel_status_occurs_and_non_cones_are_handed_over():
    pairs = [_cone(i, kind) for i, kind in enumerate(KINDS)]
    cns, refs = np.array([c for c, _ in pairs]), np.array([r for _, r in pairs])
    status, *_ = _estimator_kernels.cone_estimates(
        cns, np.nan_to_num(cns), refs, TOL.conic_degenerate_rel)  # the unit cones are not read for these
    by_kind = dict(zip(KINDS, status.tolist()))
    assert by_kind["exact"] == by_kind["head_on"] == by_kind["noisy"] == _estimator_kernels.OK
    assert all(by_kind[k] == _estimator_kernels.HANDED_OVER for k in _NON_CONES)


def _group(seed: int, kind: str) -> tuple[list[np.ndarray], np.ndarray]:
    """A group of conics: nested isophotes of one plane (with noise), unrelated cones, or nested
    isophotes with one non-cone."""
    centre, normal, radius, rng = random_circle_pose(seed, key=137)
    ray = bp_ray_normal(project_points(centre, K), K)
    m = int(rng.integers(1, 5))
    if kind == "unrelated":
        return [_cone(seed * 11 + q, "exact")[0] for q in range(m)], ray
    cns = []
    for q in range(m):
        cn = normalised_conic(project_circle(centre, normal, radius * (q + 1) / m, K), K)
        cns.append((cn + 1e-6 * rng.standard_normal((3, 3))) * rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-5, 5))
    if kind == "with_non_cone":
        cns[int(rng.integers(0, m))] = _NON_CONES[str(rng.choice(list(_NON_CONES)))]
    return cns, ray


@given(st.integers(0, 100_000), st.lists(st.sampled_from(["nested", "unrelated", "with_non_cone", "empty"]),
                                         min_size=1, max_size=8))
@settings(max_examples=60, deadline=None)
def test_joint_axes_are_the_numpy_forms_bits(seed, kinds):
    cns, group, refs = [], [], []
    for g, kind in enumerate(kinds):
        members, ray = ([], _group(seed + g, "nested")[1]) if kind == "empty" else _group(seed + g, kind)
        cns += members
        group += [g] * len(members)
        refs.append(ray)
    cns = np.array(cns).reshape(-1, 3, 3)
    group, refs = np.array(group, dtype=int), np.array(refs)
    got = joint_cone_axes(cns, group, refs)
    want = joint_cone_axes(cns, group, refs, compiled=False)
    for kind, g, w in zip(kinds, got, want):
        if isinstance(w, Failure):
            assert isinstance(g, Failure) and (g.reason, g.detail) == (w.reason, w.detail), kind
        else:
            assert not isinstance(g, Failure), kind
            assert np.array_equal(g, w), (kind, g - w)
        if kind in ("empty", "with_non_cone"):
            assert isinstance(g, Failure), kind
