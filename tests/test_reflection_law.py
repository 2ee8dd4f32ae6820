"""The law of reflection at the BP: a plane fit's normal against the bisector there.

Exact truths: a plane's own specular point (of any light of the rig) misses the law by nothing; under
a light at the camera centre the bisector is the BP's ray reversed, so the miss is the angle between
the normal and it. Then the command line's step: an ok plane fit's sigma grows by its miss, a row at
its plane's specular point keeps its sigma.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry.angles import angle_between_deg
from simtest.geometry.camera import project_points
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.assemble import SpecularityEstimate
from simtest.reconstruct.lightaware import LightAwareEstimate, reflection_offset_deg
from simtest.reconstruct.rig_centroid import _obeys_reflection
from simtest.simulate.offset import specular_point

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
#: two guides either side of the lens, as the endoscope suite's colonoscope's
RIG = LightRig((Light((-1.5, 0.0, 0.0)), Light((1.5, 0.2, 0.0))))


def _normal(tilt_deg, az_deg):
    t, a = np.radians(tilt_deg), np.radians(az_deg)
    return np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])


@settings(max_examples=60, deadline=None)
@given(tilt=st.floats(0.0, 50.0), az=st.floats(0.0, 360.0), h=st.floats(5.0, 80.0), j=st.integers(0, 1))
def test_a_planes_own_specular_point_obeys_the_law(tilt, az, h, j):
    N = _normal(tilt, az)
    X, _ = specular_point(N, h, RIG.lights[j].position)
    off = reflection_offset_deg(project_points(X, K), K, RIG, N, h)
    assert off < 1e-6  # the projection's round trip; a miss of the law is a tenth of a degree or more


@settings(max_examples=60, deadline=None)
@given(tilt=st.floats(0.0, 60.0), az=st.floats(0.0, 360.0), h=st.floats(5.0, 80.0),
       u=st.floats(50.0, 590.0), v=st.floats(50.0, 430.0))
def test_under_a_colocated_light_the_miss_is_the_normals_angle_to_the_ray(tilt, az, h, u, v):
    N = _normal(tilt, az)
    ray = np.linalg.solve(K, [u, v, 1.0])
    ray /= np.linalg.norm(ray)
    if not -(N @ ray) > 0.05:  # the ray grazes or misses the plane
        return
    off = reflection_offset_deg((u, v), K, LightRig.colocated(), N, h)
    assert off == pytest.approx(angle_between_deg(N, -ray), abs=1e-9)


def test_a_plane_behind_the_ray_gives_nan():
    assert np.isnan(reflection_offset_deg((320.0, 240.0), K, RIG, np.array([0.0, 0.0, 1.0]), 20.0))


def _highlight(bp, fit):
    r, c = int(round(bp[1])), int(round(bp[0]))
    ray = np.linalg.solve(K, [bp[0], bp[1], 1.0])
    return SpecularityEstimate(np.asarray(bp, float), 1.0, False, Roi(r - 10, r + 11, c - 10, c + 11), "ok", "",
                               -ray / np.linalg.norm(ray), (), light_aware={"photometric_fit": fit})


def test_an_ok_plane_fits_sigma_grows_by_its_miss_and_a_row_keeps_its_own():
    N, h = _normal(20.0, 30.0), 20.0
    X, _ = specular_point(N, h, RIG.lights[0].position)
    bp = project_points(X, K)
    fit = LightAwareEstimate("photometric_fit", "ok", "", N, 21.0, normal_sigma_deg=0.3, distance_mm=h)
    # the row: its BP at its plane's specular point
    row = _obeys_reflection(_highlight(bp, fit), K, RIG).light_aware["photometric_fit"]
    assert row.normal_sigma_deg == pytest.approx(0.3, abs=1e-6)
    # the same plane read off a BP 25 px away (a curved patch's lobe): the sigma counts the miss
    moved = bp + np.array([25.0, 0.0])
    miss = reflection_offset_deg(moved, K, RIG, N, h)
    assert miss > 1.0
    got = _obeys_reflection(_highlight(moved, fit), K, RIG).light_aware["photometric_fit"]
    assert got.normal_sigma_deg == pytest.approx(0.3 + miss, abs=1e-12)
    assert "law of reflection" in got.detail and got.status == "ok"
    assert np.array_equal(got.normal, N) and got.depth_mm == 21.0  # the normal and depth stay the fit's
    # a fit not ok, or without a depth, is left alone
    for other in (LightAwareEstimate("photometric_fit", "depth_not_observable", "", N, None, normal_sigma_deg=0.3),
                  LightAwareEstimate("photometric_fit", "plane_misfit", "", N, 21.0, 0.3, distance_mm=h)):
        est = _highlight(moved, other)
        assert _obeys_reflection(est, K, RIG) is est
