"""The curved patches' apex frames for K patches at once are each patch's own, bit for bit: the quadric and
cubic fits evaluate a batch of parameter vectors per step (their Jacobian's columns), and a batch must give
the same image as the patches one by one (simtest.reconstruct.lightaware.patch_geometry)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.reconstruct.lightaware.patch_geometry import _quadric_frame


def _one_by_one(e1, e2, b_ray, p, Lm):
    """The frame of one patch written with simtest's one normalisation (:func:`unit`) and plane basis."""
    s = np.exp(p[2])
    P0 = s * unit(b_ray + p[0] * e1 + p[1] * e2)
    N = unit(unit(-P0) + unit(Lm - P0))
    return (s, P0, N, *plane_basis(N))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 12), st.booleans())
def test_a_batch_of_patches_gives_each_patchs_frame_bit_for_bit(seed, k, near_x):
    rng = np.random.default_rng(seed)
    b_ray = unit(rng.normal(size=3) + (0.0, 0.0, 3.0))
    Lm = rng.normal(scale=5.0, size=3)
    if near_x:  # apex normals near the x axis: plane_basis takes its other helper
        b_ray, Lm = unit((-1.0, 0.05, 0.3)), np.array([0.5, 0.2, 0.1])
    e1, e2 = plane_basis(b_ray)
    tilt = 0.02 if near_x else 0.3  # (near_x: apexes about the ray, their normals about the x axis)
    P = np.column_stack([rng.normal(scale=tilt, size=(k, 2)), rng.uniform(0.5, 5.0, k), rng.normal(size=(k, 4))])
    batch = _quadric_frame(b_ray, P, Lm)
    assert batch[0].shape == (k,) and all(v.shape == (k, 3) for v in batch[1:])
    assert not near_x or (np.abs(batch[2][:, 0]) >= 0.9).all()
    for i in range(k):
        one = _one_by_one(e1, e2, b_ray, P[i], Lm)
        for got, want in zip((v[i] for v in batch), one):
            assert np.array_equal(got, want), (i, got, want)
        single = _quadric_frame(b_ray, P[i], Lm)  # one patch's parameters alone
        for got, want in zip(single, one):
            assert np.array_equal(got, want)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 9), st.sampled_from([(0, 1), (2, 0), (1, 2)]))
def test_plane_basis_of_a_stack_of_normals_is_each_normals_own_bit_for_bit(seed, k, axes):
    rng = np.random.default_rng(seed)
    normals = unit(rng.normal(size=(k, 3)), axis=-1)
    normals[0] = unit(np.eye(3)[axes[0]] + 0.1 * rng.normal(size=3))  # past 0.9 on the first axis: the other helper
    u, w = plane_basis(normals, axes)
    for i in range(k):
        ui, wi = plane_basis(normals[i], axes)
        assert np.array_equal(u[i], ui) and np.array_equal(w[i], wi), i
