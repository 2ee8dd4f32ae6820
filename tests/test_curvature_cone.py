"""rho = |1 + k2 d| / |1 + k1 d| against the exact isophote cone of a quadric patch (no image, no fit)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from simtest.geometry.conics import circle_pose, cone_axis
from simtest.geometry.curvature import (
    curvature_ratio,
    predicted_eigenvalue_gap,
    predicted_pose_error_deg,
)
from exact_tolerances import EXACT

GAMMA0_DEG = 0.1  # cone half-angle of the isophote; EXACT.small_isophote_gap_abs says why


def isophote_cone(k1, k2, d, gamma0_deg=GAMMA0_DEG, n=48):
    """C' of the exact isophote 'angle(ray, normal) = gamma0' on z = d + (k1 x^2 + k2 y^2) / 2."""
    g0 = np.radians(gamma0_deg)
    uv = []
    for th in np.linspace(0.0, 2 * np.pi, n, endpoint=False):
        c, s = np.cos(th), np.sin(th)

        def point(r):
            x, y = r * c, r * s
            return np.array([x, y, d + (k1 * x * x + k2 * y * y) / 2])

        def excess(r):
            P = point(r)
            N = np.array([-k1 * P[0], -k2 * P[1], 1.0])
            return np.arccos(abs(P @ N) / np.linalg.norm(P) / np.linalg.norm(N)) - g0

        P = point(brentq(excess, 1e-9, d))
        uv.append(P[:2] / P[2])
    u, v = np.array(uv).T
    A = np.c_[u * u, u * v, v * v, u, v, np.ones_like(u)]
    a, b, c, dd, e, f = np.linalg.svd(A)[2][-1]  # exact points: the null vector is the conic
    return np.array([[a, b / 2, dd / 2], [b / 2, c, e / 2], [dd / 2, e / 2, f]])


curv = st.floats(-0.05, 0.2)


@settings(max_examples=15, deadline=None)
@given(curv, curv, st.floats(10.0, 50.0))
def test_gap_is_one_minus_rho_squared_and_the_axis_is_the_normal(ka, kb, d):
    k1, k2 = max(ka, kb), min(ka, kb)
    assume(min(abs(1 + k1 * d), abs(1 + k2 * d)) >= 0.25)  # see EXACT.small_isophote_gap_abs
    rho = curvature_ratio(k1, k2, d)
    Cn = isophote_cone(k1, k2, d)
    ca = cone_axis(Cn)
    assert abs(ca.eigenvalue_gap - predicted_eigenvalue_gap(rho)) < EXACT.small_isophote_gap_abs
    # the cone axis is the normal at the BP, which is minus the optical axis here
    assert np.degrees(np.arccos(min(1.0, -ca.axis[2]))) < EXACT.fitted_normal_deg
    # N+ and N- leave it by asin(sqrt(gap)): compared as sin^2 of the angle, where the gap's
    # tolerance applies as it is (the angle itself is ill-conditioned near gap 0)
    err = np.arccos(np.clip(-circle_pose(Cn).normals[:, 2], -1, 1))
    predicted = np.radians(predicted_pose_error_deg(rho))
    assert np.all(np.abs(np.sin(err) ** 2 - np.sin(predicted) ** 2) < EXACT.small_isophote_gap_abs)
