"""Camera poses on the bundled meshes (simtest.scene.poses): the geometry each placement promises."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry.angles import angle_between_deg, unit
from simtest.scene.poses import (
    camera_up,
    colon_pose,
    liver_orbit_pose,
    liver_surface_pose,
    mesh_placement,
)

# Orthogonality and lengths are built from unit vectors of norm 1 to a few ulp; 1e-9 leaves room
# for the sums of a few such products at lengths of tens of millimetres.
EPS = 1e-9

_angle = st.floats(0.0, 360.0)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.15, 0.85), st.floats(0.0, 80.0), _angle, st.floats(0.0, 0.5), _angle)
def test_colon_pose_stands_off_the_centre_line_by_the_asked_fraction(station, view, az, offset, roll):
    pose = colon_pose(station, view, azimuth_deg=az, radial_offset=offset, roll_deg=roll)
    forward = pose.look_at - pose.position
    assert abs(np.linalg.norm(forward) - 1.0) < EPS
    assert abs(float(pose.up @ forward)) < EPS and abs(np.linalg.norm(pose.up) - 1.0) < EPS
    info = mesh_placement("colon")
    s = info.arc[0] + station * (info.arc[-1] - info.arc[0])
    r_min = float(np.interp(s, info.arc, info.radius_min))
    # the offset is across the tangent: the camera is offset x r_min from the centre line's point
    base = colon_pose(station, 0.0, azimuth_deg=az, radial_offset=0.0, roll_deg=roll)
    assert abs(np.linalg.norm(pose.position - base.position) - offset * r_min) < EPS * 100
    tangent = base.look_at - base.position
    assert abs(angle_between_deg(forward, tangent) - view) < 1e-6  # degrees, from acos near 0


def test_the_harness_colon_pose_is_the_dataset_one_at_azimuth_zero_without_roll():
    a = colon_pose(0.3, 80.0)
    b = colon_pose(0.3, 80.0, azimuth_deg=0.0, radial_offset=0.3, roll_deg=0.0)
    for x, y in ((a.position, b.position), (a.look_at, b.look_at), (a.up, b.up)):
        assert np.allclose(x, y, rtol=0, atol=EPS)


@settings(max_examples=20, deadline=None)
@given(_angle, st.floats(-60.0, 60.0), st.floats(5.0, 50.0))
def test_liver_orbit_pose_looks_at_the_box_centre_from_outside_the_bounding_sphere(az, el, d):
    info = mesh_placement("liver")
    pose = liver_orbit_pose(az, el, d)
    to_centre = info.centre - pose.position
    assert abs(np.linalg.norm(to_centre) - (info.bounding_radius + d)) < EPS * 1e3
    assert angle_between_deg(pose.look_at - pose.position, to_centre) < 1e-6


@settings(max_examples=20, deadline=None)
@given(_angle, st.floats(-45.0, 60.0), st.floats(15.0, 50.0), st.floats(0.0, 70.0), _angle)
def test_liver_surface_pose_sees_its_point_at_the_distance_and_tilt_asked(az, el, d, view, roll):
    info = mesh_placement("liver")
    pose = liver_surface_pose(az, el, d, view, roll)
    k = int(np.argmin(np.linalg.norm(np.asarray(info.mesh.vertices) - pose.look_at, axis=1)))
    normal = unit(np.asarray(info.mesh.vertex_normals[k], dtype=np.float64))
    back = pose.position - pose.look_at
    assert abs(np.linalg.norm(back) - d) < EPS * 1e3
    tilt = angle_between_deg(back, normal)
    assert abs(min(tilt, 180.0 - tilt) - view) < 1e-5  # the outward normal, either orientation
    assert abs(float(pose.up @ unit(back))) < EPS


def test_camera_up_rolls_about_the_viewing_direction():
    f = unit([0.2, -0.3, 0.9])
    u0, u90 = camera_up(f, 0.0), camera_up(f, 90.0)
    assert abs(float(u0 @ u90)) < EPS and abs(float(u0 @ f)) < EPS
    assert np.allclose(np.cross(u0, u90), f, rtol=0, atol=EPS)


#: Clearance the haustral colon's placement keeps from its wall over the dataset's ranges, mm:
#: the offset is a fraction (< 0.5) of the smallest wall distance within half a fold spacing, so
#: the camera keeps at least half of it (about 17 mm at a fold of 8 mm: 8.5 mm; measured over
#: 400 draws of the example config's ranges: 8.4 mm, a nearer vertex of a staggered crest). A
#: scope's tip is about 13 mm across: 5 mm leaves it in the lumen.
HAUSTRAL_CLEARANCE_MM = 5.0


@settings(max_examples=25, deadline=None)
@given(st.floats(0.15, 0.85), st.floats(0.0, 80.0), _angle, st.floats(0.0, 0.5), _angle)
def test_haustral_colon_pose_stays_in_the_lumen_and_looks_as_asked(station, view, az, offset, roll):
    from scipy.spatial import cKDTree

    from simtest.scene.meshes import haustral_pose

    info = mesh_placement("colon_haustral")
    pose = colon_pose(station, view, azimuth_deg=az, radial_offset=offset, roll_deg=roll,
                      mesh="colon_haustral")
    assert pose.path.endswith("colon_haustral.ply")
    assert cKDTree(info.mesh.vertices).query(pose.position)[0] > HAUSTRAL_CLEARANCE_MM
    forward = pose.look_at - pose.position
    assert abs(np.linalg.norm(forward) - 1.0) < EPS and abs(pose.up @ forward) < EPS
    # the view angle off the centre line's tangent at the station, as asked
    s = info.arc[0] + station * (info.arc[-1] - info.arc[0])
    v = float(np.interp(s, info.arc, info.mesh.metadata["centerline"]["v"]))
    line = haustral_pose(info.mesh, v, 0.0, radial_offset=0.0)
    tangent = np.subtract(line["look_at_mm"], line["position_mm"])
    assert abs(angle_between_deg(tangent, forward) - view) < 1e-6


def test_dataset_example_draws_the_haustral_colon():
    from pathlib import Path

    from simtest.dataset.config import load_config
    from simtest.dataset.card import make_card
    from simtest.dataset.sample import build_scene, draw_parameters

    cfg = load_config(Path(__file__).resolve().parents[1] / "scenes" / "datasets" / "example.toml")
    assert list(make_card(cfg, status="complete")["meshes"]) == ["meshes/colon_haustral.ply", "meshes/liver.ply"]
    i = next(i for i in range(100) if draw_parameters(cfg, i)["family"] == "colon")
    spec = build_scene(cfg, draw_parameters(cfg, i))
    assert Path(spec.geometry.path).name == "colon_haustral.ply"
