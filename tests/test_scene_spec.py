"""Scene specs, the pure spec -> Mitsuba dict translation and the sensor model (no rendering)."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.render.mitsuba_dict import (
    cam_to_world_matrix,
    intrinsics_matrix,
    light_position_cam,
    mitsuba_scene_dict,
)
from simtest.scene.kinds import plane_normal_cam
from simtest.render.sensor import apply_sensor
from simtest.scene import (
    SceneError,
    bundled_scene_names,
    bundled_scene_path,
    load_scene,
    scene_from_dict,
    scene_to_dict,
    with_overrides,
)
from simtest.scene.spec import SensorSpec

PLANE = {"geometry": {"type": "plane", "tilt_deg": 30.0, "distance_mm": 50.0}}


def _write(tmp_path, text: str):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


def test_bundled_scenes_load_and_round_trip():
    names = bundled_scene_names()
    for required in ("plane_58deg", "plane_fronto", "sphere", "cylinder"):
        assert required in names
    for name in names:
        spec = load_scene(name)
        assert spec == load_scene(bundled_scene_path(name))
        assert scene_from_dict(scene_to_dict(spec), base_dir=bundled_scene_path(name).parent) == spec


def test_plane_58deg_field_of_view_shows_the_t01_isophote():
    # n = 50, t = 0.1: the isophote is where cos(2 theta_i)^50 = 0.1 (co-located light), so the
    # view rays reach tilt + theta_i off axis; the half field of view must exceed that.
    spec = load_scene("plane_58deg")
    theta_i = 0.5 * math.degrees(math.acos(0.1 ** (1.0 / spec.material.n)))
    half_fov_y = math.degrees(math.atan(0.5 * spec.camera.height_px / spec.camera.focal))
    assert spec.geometry.tilt_deg == 58.0
    assert half_fov_y > spec.geometry.tilt_deg + theta_i


@pytest.mark.parametrize(
    ("text", "key", "reason"),
    [
        ("[camera]\nwidth_px = 100\nfocus = 3\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "camera.focus", "unknown key"),
        ("[camera]\nwidth_px = 'big'\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "camera.width_px", "expected an integer"),
        ("[material]\nn = -3.0\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "material.n", "out of range"),
        ("[geometry]\ntype='plane'\ntilt_deg = 95\ndistance_mm = 5\n", "geometry.tilt_deg", "out of range"),
        ("[geometry]\ntype='plane'\ntilt_deg = 5\n", "geometry.distance_mm", "missing"),
        ("[geometry]\ntype='plane'\ntilt_deg = 5\ndistance_mm = 5\nradius_mm = 3\n", "geometry.radius_mm",
         "not a key of geometry type 'plane'"),
        ("[geometry]\ntype='torus'\n", "geometry.type", "must be one of"),
        # a kind's class attributes (how it renders) are not keys of the file
        ("[geometry]\ntype='plane'\ntilt_deg = 5\ndistance_mm = 5\nframe = 'world'\n", "geometry.frame",
         "unknown key"),
        ("[geometry]\ntype='sphere'\ncenter_mm=[0,0]\nradius_mm=1\n", "geometry.center_mm", "list of 3"),
        ("[render]\nvariant='llvm_ad_mono'\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "render.variant", "must be one of"),
        ("[light]\nfalloff = true\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "light.falloff", "expected a string"),
        ("[camera]\nfov_deg = 90\nfocal_px = 100\n[geometry]\ntype='sphere'\ncenter_mm=[0,0,9]\nradius_mm=1\n",
         "camera.focal_px", "not both"),
        ("[geometry\ntype='sphere'\n", "not valid TOML", "line 1"),
    ],
)
def test_bad_scene_file_gives_one_readable_error(tmp_path, text, key, reason):
    path = _write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {key}: "), msg
    assert reason in msg


def test_an_image_given_for_a_scene_or_a_dataset_config_is_one_line(tmp_path):
    # a PNG's bytes are not UTF-8: every config loader names the file, and the command exits 2 without a traceback
    from typer.testing import CliRunner

    from simtest.cli import app
    from simtest.dataset.config import DatasetConfigError, load_config

    png = tmp_path / "frame.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    for load, error in ((load_scene, SceneError), (load_config, DatasetConfigError)):
        with pytest.raises(error, match=f"^{re.escape(str(png))}: not valid TOML: "):
            load(png)
    r = CliRunner().invoke(app, ["render", str(png), "--out", str(tmp_path / "out")])
    assert r.exit_code == 2 and (r.exception is None or isinstance(r.exception, SystemExit)), r.output
    assert "Traceback" not in r.output and f"{png}: not valid TOML" in " ".join(r.output.split())


def test_missing_mesh_file_names_the_path(tmp_path):
    path = _write(tmp_path, "[geometry]\ntype = 'mesh'\npath = 'nowhere/gut.ply'\n")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert "geometry.path" in msg and "nowhere/gut.ply" in msg and str(tmp_path) in msg


def test_unknown_bundled_name_lists_known_names():
    with pytest.raises(SceneError, match="plane_58deg"):
        load_scene("no_such_scene")


def test_with_overrides_validates_and_replaces():
    spec = scene_from_dict(PLANE)
    out = with_overrides(spec, {"material.n": 80, "geometry.tilt_deg": 10, "render.seed": 4})
    assert (out.material.n, out.geometry.tilt_deg, out.render.seed) == (80.0, 10.0, 4)
    assert out.camera == spec.camera
    with pytest.raises(SceneError, match="geometry.tilt_deg"):
        with_overrides(spec, {"geometry.tilt_deg": 90})
    with pytest.raises(SceneError, match="material.shininess"):
        with_overrides(spec, {"material.shininess": 3})
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.material.n = 3  # type: ignore[misc]


@settings(max_examples=40, deadline=None)
@given(
    tilt=st.floats(0.0, 89.0),
    az=st.floats(-360.0, 360.0),
    n=st.floats(1.0, 500.0),
    w=st.integers(8, 1024),
    fov=st.floats(5.0, 170.0),
    seed=st.integers(0, 2**31 - 1),
)
def test_round_trip_and_plane_geometry(tilt, az, n, w, fov, seed):
    spec = scene_from_dict({
        "camera": {"width_px": w, "height_px": w + 1, "fov_deg": fov},
        "material": {"n": n},
        "geometry": {"type": "plane", "tilt_deg": tilt, "azimuth_deg": az, "distance_mm": 40.0},
        "render": {"seed": seed},
    })
    assert scene_from_dict(scene_to_dict(spec)) == spec
    # The focal length reproduces the horizontal field of view (float round-off only).
    assert math.isclose(spec.camera.fov_x_deg, fov, rel_tol=1e-12)
    nrm = plane_normal_cam(spec.geometry)
    assert math.isclose(np.linalg.norm(nrm), 1.0, rel_tol=1e-12)
    # The tilt is the angle between the camera-facing normal and minus the optical axis.
    assert math.isclose(math.degrees(math.acos(-nrm[2])), tilt, abs_tol=1e-6)
    d = mitsuba_scene_dict(spec)
    m = d["surface"]["to_world"]
    # Mitsuba's rectangle normal (+z local) maps to the camera-facing normal; the plane passes at
    # distance_mm from the camera centre.
    z = m[:3, 2] / np.linalg.norm(m[:3, 2])
    assert np.allclose(z, nrm, atol=1e-12)
    assert math.isclose(-np.dot(nrm, m[:3, 3]), 40.0, rel_tol=1e-12)


def test_intrinsics_convention():
    spec = scene_from_dict({"camera": {"width_px": 200, "height_px": 100, "focal_px": 150.0,
                                       "principal_offset_px": [3.0, -2.0]}, **PLANE})
    K = intrinsics_matrix(spec.camera)
    # Mitsuba pixel centres at i + 0.5 -> OpenCV centres at integers: cx = W/2 - 0.5 + offset.
    assert np.array_equal(K, [[150.0, 0, 102.5], [0, 150.0, 47.5], [0, 0, 1]])
    assert np.array_equal(cam_to_world_matrix(spec.camera), np.eye(4))


def test_camera_pose_is_opencv():
    spec = scene_from_dict({"camera": {"position_mm": [1, 2, 3], "look_at_mm": [1, 2, 13],
                                       "up": [0, 5, 0]}, **PLANE})
    m = cam_to_world_matrix(spec.camera)
    # Looking along +z with the world's +y shown at the top: camera y (down) is world -y.
    assert np.allclose(m[:3, :3], np.diag([-1.0, -1.0, 1.0]))
    assert np.allclose(m[:3, 3], [1, 2, 3])


def test_light_offset_draw_is_seeded_and_parametrised():
    spec = scene_from_dict({"light": {"epsilon_mm": 5.0}, **PLANE})
    a, b = light_position_cam(spec.light, 7), light_position_cam(spec.light, 7)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, light_position_cam(spec.light, 8))
    # L - V = epsilon (cos a, sin a, b) with b in [-0.5, 0.5].
    assert math.isclose(math.hypot(a[0], a[1]), 5.0, rel_tol=1e-12)
    assert abs(a[2]) <= 2.5
    fixed = scene_from_dict({"light": {"epsilon_mm": 2.0, "alpha_deg": 90.0, "b": 0.25}, **PLANE})
    assert np.allclose(light_position_cam(fixed.light, 1), [0.0, 2.0, 0.5], atol=1e-12)
    assert np.array_equal(light_position_cam(scene_from_dict(PLANE).light, 3), np.zeros(3))


def test_sensor_model():
    lin = np.linspace(0.0, 2.0, 1001).reshape(7, 143)
    s8 = apply_sensor(lin, SensorSpec(), 0)
    assert s8.dtype == np.uint8
    # No noise, gamma 1: round(clip(x, 0, 1) * 255).
    assert np.array_equal(s8, np.rint(np.clip(lin, 0, 1) * 255).astype(np.uint8))
    s16 = apply_sensor(lin, SensorSpec(bit_depth=12, saturation=0.5, gamma=2.2), 0)
    assert s16.dtype == np.uint16 and s16.max() == round(0.5 ** (1 / 2.2) * 4095)
    noisy = SensorSpec(gaussian_sigma=0.02, full_well_e=1000.0)
    assert np.array_equal(apply_sensor(lin, noisy, 5), apply_sensor(lin, noisy, 5))
    assert not np.array_equal(apply_sensor(lin, noisy, 5), apply_sensor(lin, noisy, 6))


def test_each_geometry_type_is_its_own_class_with_only_its_keys():
    from simtest.scene.spec import GEOMETRY_KEYS, GEOMETRY_TYPES

    assert list(GEOMETRY_TYPES) == list(GEOMETRY_KEYS)
    for kind, cls in GEOMETRY_TYPES.items():
        required, optional = GEOMETRY_KEYS[kind]
        assert cls.type == kind
        assert {f.name for f in dataclasses.fields(cls)} == set(required) | set(optional)
    for name in bundled_scene_names():
        spec = load_scene(bundled_scene_path(name))
        geo = spec.geometry
        assert type(geo) is GEOMETRY_TYPES[geo.type]
        d = scene_to_dict(spec)
        assert next(iter(d["geometry"])) == "type"  # the layout of the files, type first
        assert scene_from_dict(d, source=spec.source) == spec


def test_switching_the_geometry_type_by_override_drops_the_old_keys():
    plane = scene_from_dict(PLANE)
    sphere = with_overrides(plane, {"geometry.type": "sphere", "geometry.center_mm": [0, 0, 90],
                                    "geometry.radius_mm": 20.0})
    assert sphere.geometry == scene_from_dict(
        {"geometry": {"type": "sphere", "center_mm": [0, 0, 90], "radius_mm": 20.0}}).geometry
    # the same type keeps its keys; a key of another type is refused, naming this type's keys
    assert with_overrides(plane, {"geometry.type": "plane"}).geometry == plane.geometry
    with pytest.raises(SceneError, match=r"geometry\.radius_mm: not a key of geometry type "
                                         r"'plane' \(keys: tilt_deg, distance_mm, azimuth_deg"):
        with_overrides(plane, {"geometry.radius_mm": 3.0})
    # the old style, unsetting the old keys first, still gives the same spec
    old = with_overrides(plane, {"geometry.tilt_deg": None, "geometry.distance_mm": None,
                                 "geometry.type": "sphere", "geometry.center_mm": [0, 0, 90],
                                 "geometry.radius_mm": 20.0})
    assert old == sphere


def test_each_kind_says_how_it_renders():
    from simtest.scene.spec import GEOMETRY_TYPES

    assert {k for k, c in GEOMETRY_TYPES.items() if c.triangulated} == {"mesh", "saddle"}
    assert {k for k, c in GEOMETRY_TYPES.items() if c.frame == "camera"} == {"plane", "saddle"}


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(["plane", "sphere", "cylinder"]), a=st.floats(-8.0, 8.0), b=st.floats(-8.0, 8.0),
       size=st.floats(3.0, 12.0), tilt=st.floats(0.0, 60.0), eps=st.floats(0.0, 3.0))
def test_an_analytic_kinds_highlight_lies_on_the_surface_it_gives_mitsuba(kind, a, b, size, tilt, eps):
    # exact geometry, camera frame: the closed-form BP lies on the surface whose Mitsuba transform the
    # kind writes (the rectangle's plane; the sphere; the cylinder's side), and its normal is the
    # surface's there; the tolerance is float64 round-off on mm-sized numbers
    geo = {"plane": {"type": "plane", "tilt_deg": tilt, "azimuth_deg": 30.0 * a, "distance_mm": 20.0 + size},
           "sphere": {"type": "sphere", "center_mm": [a, b, 40.0], "radius_mm": size},
           "cylinder": {"type": "cylinder", "center_mm": [a, b, 40.0], "radius_mm": size,
                        "axis": [1.0, 0.2 * b, 0.0], "length_mm": 200.0}}[kind]
    spec = scene_from_dict({"geometry": geo})
    g, K = spec.geometry, intrinsics_matrix(spec.camera)
    w2c = np.linalg.inv(cam_to_world_matrix(spec.camera))
    hl = g.highlight(w2c, np.array([eps, 0.0, 0.0]), K, (spec.camera.width_px, spec.camera.height_px))
    if hl is None:  # off the image: nothing to check
        return
    surface, X, n = g.surface(w2c, {}), np.asarray(hl.bp_mm), np.asarray(hl.normal)
    if kind == "plane":  # the rectangle's normal is its transform's z column; its centre lies on the plane
        m = surface["to_world"]
        z = m[:3, 2] / np.linalg.norm(m[:3, 2])
        assert abs(z @ (X - m[:3, 3])) < 1e-9 and abs(abs(z @ n) - 1.0) < 1e-12
    elif kind == "sphere":
        c = np.asarray(surface["center"])
        assert abs(np.linalg.norm(X - c) - surface["radius"]) < 1e-9
        assert np.linalg.norm(n - (X - c) / surface["radius"]) < 1e-9
    else:  # the side of Mitsuba's unit cylinder about z, mapped by to_world
        local = np.linalg.solve(surface["to_world"], np.append(X, 1.0))[:3]
        assert abs(math.hypot(local[0], local[1]) - 1.0) < 1e-9 and 0.0 <= local[2] <= 1.0
