"""One plane images every guide's highlight: a row left with the BP ray takes the plane of a row that places both.

:func:`~simtest.reconstruct.rig_lobes.shared_plane_rows` on hand-made rows: a plane under two guides, its specular
points from :func:`simtest.simulate.offset.specular_point` (the mirror image's construction, independent of the
rig module's), row A at guide 1's with an ok plane fit, row B at guide 2's whose own fits misfit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.decisions import PAIR_TOL_PX
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.assemble import IsophoteEstimate, SpecularityEstimate
from simtest.reconstruct.lightaware import LightAwareEstimate
from simtest.reconstruct.rig_lobes import _own_guide, shared_plane_rows
from simtest.simulate.offset import specular_point

F, SIZE = 300.0, 400
K = np.array([[F, 0.0, 199.5], [0.0, F, 199.5], [0.0, 0.0, 1.0]])
RIG = LightRig((Light((-4.0, 0.5, 0.0), 1.0, "inverse_square"), Light((3.5, -0.5, 0.0), 1.0, "inverse_square")))
#: The rows' depths against the specular points' own: both are the ray meeting the plane, computed two ways
#: (float rounding over a few operations on numbers near 50 mm).
DEPTH_REL = 1e-9


def _row(uv, fit: LightAwareEstimate) -> SpecularityEstimate:
    uv = np.asarray(uv, float)
    r, c = int(round(uv[1])), int(round(uv[0]))
    ray = np.linalg.solve(K, [uv[0], uv[1], 1.0])
    return SpecularityEstimate(uv, 200.0, False, Roi(r - 5, r + 6, c - 5, c + 6), "ok", "", -ray / np.linalg.norm(ray),
                               (), light_aware={"photometric_fit": fit})


def _plane(tilt_deg, az_deg, h):
    t, a = np.radians(tilt_deg), np.radians(az_deg)
    n = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])
    pts = [specular_point(n, h, L.position_mm) for L in RIG.lights]
    uv = [(K @ x)[:2] / x[2] for x, _ in pts]
    return n, uv, [d for _, d in pts]


def _rows(n, uv, depths, h, b_off=(0.0, 0.0)):
    a = _row(uv[0], LightAwareEstimate("photometric_fit", "ok", "", n, depth_mm=depths[0], normal_sigma_deg=0.05,
                                       depth_sigma_mm=0.01 * depths[0], distance_mm=h, bp_ray_error_deg=5.0))
    b = _row(np.asarray(uv[1]) + b_off, LightAwareEstimate("photometric_fit", "plane_misfit", "", np.array([0.0, 0.0, -1.0]),
                                                           normal_sigma_deg=0.05, bp_ray_error_deg=5.0))
    return [a, b]


@settings(max_examples=40, deadline=None)
@given(st.floats(5.0, 50.0), st.floats(0.0, 360.0), st.floats(8.0, 50.0))
def test_the_row_left_with_the_bp_ray_takes_the_plane_that_places_it(tilt, az, h):
    n, uv, depths = _plane(tilt, az, h)
    rows = _rows(n, uv, depths, h)
    assert [e.recommended.normal_from for e in rows] == ["photometric_fit", "bp_ray"]
    a, b = shared_plane_rows(rows, K, RIG)
    assert a is rows[0]
    rec = b.recommended
    assert rec.normal_from == "rig_pair" and np.array_equal(rec.normal, n)
    assert abs(b.light_aware["rig_pair"].depth_mm / depths[1] - 1.0) <= DEPTH_REL
    assert b.status == "ok" and b.light_aware["photometric_fit"] is rows[1].light_aware["photometric_fit"]


@settings(max_examples=20, deadline=None)
@given(st.floats(5.0, 50.0), st.floats(0.0, 360.0), st.floats(8.0, 50.0), st.floats(0.0, 2 * np.pi))
def test_a_row_the_plane_does_not_place_keeps_the_bp_ray(tilt, az, h, turn):
    n, uv, depths = _plane(tilt, az, h)
    off = (PAIR_TOL_PX + 0.5) * np.array([np.cos(turn), np.sin(turn)])  # (no closed isophote: no wander)
    rows = _rows(n, uv, depths, h, off)
    assert [e.recommended.normal_from for e in shared_plane_rows(rows, K, RIG)] == ["photometric_fit", "bp_ray"]


def test_a_plane_that_misplaces_its_own_highlight_lends_nothing():
    n, uv, depths = _plane(20.0, 30.0, 25.0)
    rows = _rows(n, uv, depths, 25.0)
    rows[0] = _row(np.asarray(uv[0]) + (PAIR_TOL_PX + 0.5, 0.0), rows[0].light_aware["photometric_fit"])
    assert [e.recommended.normal_from for e in shared_plane_rows(rows, K, RIG)] == ["photometric_fit", "bp_ray"]


def test_a_rig_at_the_camera_centre_changes_nothing():
    n, uv, depths = _plane(20.0, 30.0, 25.0)
    rows = _rows(n, uv, depths, 25.0)
    centre = LightRig((Light((0.0, 0.0, 0.0), 1.0, "inverse_square"),))
    assert shared_plane_rows(rows, K, centre) == rows


def test_of_two_planes_that_place_the_row_the_surer_one_lends():
    # two donors at guide 1's highlight, planes 0.02 deg apart (both place guide 2's within PAIR_TOL_PX):
    # the row takes the plane of the smaller sigma, whichever row comes first
    n, uv, depths = _plane(20.0, 30.0, 25.0)
    m, _, m_depths = _plane(20.02, 30.0, 25.0)

    def donor(normal, depth, sigma):
        return _row(uv[0], LightAwareEstimate("photometric_fit", "ok", "", normal, depth_mm=depth, normal_sigma_deg=sigma,
                                              depth_sigma_mm=0.01 * depth, distance_mm=25.0, bp_ray_error_deg=5.0))

    b = _rows(n, uv, depths, 25.0)[1]
    for first_sigma, second_sigma in ((0.5, 0.05), (0.05, 0.5)):
        rows = [donor(n, depths[0], first_sigma), b, donor(m, m_depths[0], second_sigma)]
        made = shared_plane_rows(rows, K, RIG)[1].recommended
        assert made.normal_from == "rig_pair"
        assert np.array_equal(made.normal, n if first_sigma < second_sigma else m)
        assert made.normal_sigma_deg == min(first_sigma, second_sigma)


def _circle(centre, radius, n=48):
    """A closed primary isophote: ``n`` points on a circle (u, v) px."""
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])


@settings(max_examples=30, deadline=None)
@given(st.floats(5.0, 50.0), st.floats(0.0, 360.0), st.floats(8.0, 50.0), st.floats(0.0, 2 * np.pi),
       st.booleans())
def test_a_donor_whose_bp_left_its_point_lends_where_its_isophote_holds_it(tilt, az, h, turn, holds):
    # the donor's BP PAIR_TOL_PX + 1 px from its guide's specular point, its closed isophote a circle about the BP (no
    # wander: the reach is PAIR_TOL_PX): the plane places its own highlight exactly where the isophote holds that point
    # (radius 1 px beyond it, or 1 px short of it)
    n, uv, depths = _plane(tilt, az, h)
    rows = _rows(n, uv, depths, h)
    d = PAIR_TOL_PX + 1.0
    bp = np.asarray(uv[0]) + d * np.array([np.cos(turn), np.sin(turn)])
    if np.linalg.norm(bp - uv[1]) < d + 2.0:
        return  # (the circle would hold guide 2's point too: the next test's case)
    ring = IsophoteEstimate(0.7, "ok", points_uv=_circle(bp, d + (1.0 if holds else -1.0)), closed=True)
    rows[0] = replace(_row(bp, rows[0].light_aware["photometric_fit"]), isophotes=(ring,))
    want = "rig_pair" if holds else "bp_ray"
    assert [e.recommended.normal_from for e in shared_plane_rows(rows, K, RIG)] == ["photometric_fit", want]


def test_an_isophote_holding_both_guides_points_places_neither():
    # _own_guide: beyond the reach, the guide whose point the row's isophote holds, where it holds one only
    pts = np.array([[100.0, 100.0], [130.0, 100.0]])
    ring = IsophoteEstimate(0.7, "ok", points_uv=_circle((115.0, 100.0), 20.0), closed=True)
    row = replace(_row((115.0, 100.0), None), isophotes=(ring,))
    assert _own_guide(pts, (115.0, 100.0), PAIR_TOL_PX, row) is None
    ring = IsophoteEstimate(0.7, "ok", points_uv=_circle((110.0, 100.0), 12.0), closed=True)
    row = replace(row, isophotes=(ring,))
    assert _own_guide(pts, (115.0, 100.0), PAIR_TOL_PX, row) == 0
    assert _own_guide(pts, (115.0, 100.0), PAIR_TOL_PX) is None  # (no row: the reach alone)
    open_ring = IsophoteEstimate(0.7, "ok", points_uv=_circle((110.0, 100.0), 12.0), closed=False)
    assert _own_guide(pts, (115.0, 100.0), PAIR_TOL_PX, replace(row, isophotes=(open_ring,))) is None
