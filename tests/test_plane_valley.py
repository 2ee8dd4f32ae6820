"""The plane fit's coordinates along the BP's valley: an exact inverse, and planes that hold the ray's
point whose normal is the light's bisector there, so that point is the light's specular point."""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.reconstruct.lightaware.model import _normal_derivs
from simtest.reconstruct.lightaware.plane_solve import ValleyCoords
from simtest.simulate.offset import specular_point

# a few dozen float operations on values of order 1 (normals) and log depths: rounding stays below 1e-12
ROUNDING = 1e-9

_small = st.floats(-0.3, 0.3)


@st.composite
def valley_cases(draw):
    """A BP ray, a light off the camera centre, a start normal facing the camera, and a point q."""
    r = unit(np.array([draw(st.floats(-0.6, 0.6)), draw(st.floats(-0.6, 0.6)), 1.0]))
    light = np.array([draw(st.floats(-8.0, 8.0)), draw(st.floats(-8.0, 8.0)), draw(st.floats(-2.0, 2.0))])
    assume(np.linalg.norm(light) > 0.5)
    n0 = unit(-r + np.array([draw(_small), draw(_small), 0.0]))
    q = np.array([draw(st.floats(-0.2, 0.2)), draw(st.floats(-0.2, 0.2)), np.log(draw(st.floats(3.0, 100.0))),
                  np.log(draw(st.floats(2.0, 5000.0)))])
    return ValleyCoords(r, light, n0, *plane_basis(n0)), q


@settings(max_examples=200, deadline=None)
@given(valley_cases())
def test_valley_coordinates_invert_exactly_and_hold_the_rays_point(case):
    c, q = case
    p = c.to_p(q)
    n = _normal_derivs(p, *c.B)[0]
    assume(n @ c.r < -0.05)  # the plane faces the BP's ray
    assert np.allclose(c.to_q(p), q, rtol=0.0, atol=ROUNDING)
    # whatever alpha and beta, the plane holds the ray's point at depth d
    X = np.exp(q[2]) * c.r
    assert abs(n @ X + np.exp(p[2])) <= ROUNDING * np.exp(q[2])
    assert p[3] == q[3]  # the roughness is left as it is


@settings(max_examples=200, deadline=None)
@given(valley_cases())
def test_on_the_valley_the_rays_point_is_the_lights_specular_point(case):
    c, q = case
    q[:2] = 0.0
    p = c.to_p(q)
    n, h = _normal_derivs(p, *c.B)[0], float(np.exp(p[2]))
    assume(n @ c.r < -0.05 and n @ c.L + h > 0.1)  # the plane faces the ray, the light on the camera's side
    X, _ = specular_point(n, h, c.L)
    assert np.allclose(X, np.exp(q[2]) * c.r, rtol=ROUNDING, atol=ROUNDING * np.exp(q[2]))


def test_a_plane_turned_away_from_the_ray_has_no_valley_coordinates():
    r = np.array([0.0, 0.0, 1.0])
    n0 = unit(np.array([0.1, 0.0, 1.0]))  # faces along the ray: the camera sees its back
    c = ValleyCoords(r, np.array([4.0, 0.0, 0.0]), n0, *plane_basis(n0))
    assert c.to_q(np.array([0.0, 0.0, np.log(10.0), 0.0])) is None


def test_a_fit_run_off_to_an_infinite_distance_is_not_converged_without_a_warning(monkeypatch):
    # LM's iterate can end with log h past exp's range (h = inf): the estimate says not_converged and
    # no RuntimeWarning reaches the user's terminal (the run of lightaware-curved at seed 0 printed one)
    import warnings

    from benchmarks.inputs import synthetic_offset_highlight
    from simtest.reconstruct.lightaware import plane, photometric_fit

    roi, K, bp, rig, _, _ = synthetic_offset_highlight()
    solve = plane.solve_plane

    def run_off(m, cands, s, floor_level):
        x, n0, h0, e1, e2, conv, msg, nfev = solve(m, cands, s, floor_level)
        return np.array([x[0], x[1], 1000.0, x[3]]), n0, h0, e1, e2, conv, msg, nfev

    monkeypatch.setattr(plane, "solve_plane", run_off)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = photometric_fit(roi, (0, 0), bp, K, rig)
    assert est.status == "not_converged" and "inf" in est.detail, (est.status, est.detail)
