"""Endoscope renders: light rigs and camera models, against closed forms and exact projections.

Films are small (48 to 96 px, a few spp) to keep the suite fast on a 2-core CPU.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simtest.geometry.camera_file import load_camera, save_camera
from simtest.geometry.cameras import FisheyeCamera, PinholeCamera, c3vd_camera
from simtest.render import render_scene, write_render
from simtest.render.endoscope import (
    COLONOSCOPE_GUIDE_OFFSET_MM,
    camera_model,
    colonoscope_rig,
    laparoscope_rig,
    scaled_omnidirectional,
    uses_endoscope,
)
from simtest.simulate.truth import bisector, plane_highlight
from simtest.scene import SceneError, load_scene, scene_from_dict, with_overrides

pytestmark = pytest.mark.render

#: Largest pixel error of a ground-truth position projected back with the camera model (the must-hold
#: bound): the positions are float32 (~1e-7 relative), a few 1e-5 px at these focal lengths.
PROJECTION_TOL_PX = 0.01


def _plane(**over):
    d = {"camera": {"width_px": 64, "height_px": 64, "fov_deg": 100.0},
         "light": {"rig": "colonoscope", "falloff": "keep", "intensity": 400.0},
         "material": {"model": "phong", "c": 1.0, "n": 50.0, "diffuse_albedo": 0.2},
         "geometry": {"type": "plane", "tilt_deg": 15.0, "distance_mm": 20.0},
         "render": {"spp": 4}}
    for k, v in over.items():
        sec, key = k.split(".")
        d.setdefault(sec, {})[key] = v
    return scene_from_dict(d)


def test_presets_geometry():
    rig = colonoscope_rig()
    assert rig.positions.tolist() == [[-COLONOSCOPE_GUIDE_OFFSET_MM, 0, 0], [COLONOSCOPE_GUIDE_OFFSET_MM, 0, 0]]
    ring = laparoscope_rig(radius_mm=4.0, count=6)
    assert len(ring) == 6
    assert np.allclose(np.linalg.norm(ring.positions, axis=1), 4.0) and np.allclose(ring.positions[:, 2], 0)
    assert np.allclose(ring.positions.sum(axis=0), 0.0, atol=1e-12)  # evenly spaced
    with pytest.raises(ValueError, match="6 to 8"):
        laparoscope_rig(count=5)


def test_default_scenes_keep_the_perspective_path():
    for name in ("plane_58deg", "colon", "sphere"):
        assert not uses_endoscope(load_scene(name))
    assert uses_endoscope(_plane())


@pytest.mark.parametrize(("over", "key"), [
    ({"light.falloff": "cancel"}, "light.falloff"),
    ({"light.epsilon_mm": 2.0}, "light.epsilon_mm"),
    ({"light.guide_count": 6}, "light.guide_count"),
])
def test_rig_keys_are_validated(over, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        _plane(**over)


def test_rig_radiance_matches_the_closed_form():
    """Lambertian plane, fronto, two lights with a cos^m profile and 1/s^2 falloff."""
    m, inten, albedo = 2.0, 300.0, 0.5
    spec = _plane(**{"material.c": 0.0, "material.diffuse_albedo": albedo, "geometry.tilt_deg": 0.0,
                     "light.profile_exponent": m, "light.intensity": inten, "render.spp": 64})
    r = render_scene(spec, seed=3)
    p = r.position.reshape(-1, 3).astype(np.float64)
    expect = np.zeros(len(p))
    for L in colonoscope_rig().positions:
        to_l = L - p
        s = np.linalg.norm(to_l, axis=1)
        wo = to_l / s[:, None]
        cos_o = -wo[:, 2]  # the normal is (0, 0, -1)
        expect += albedo / math.pi * cos_o * inten * np.maximum(-wo[:, 2], 0) ** m / s**2
    got = r.linear.reshape(-1)
    # Each pixel is a 64-sample jittered mean over its footprint, where the radiance changes by up
    # to 5 % from pixel to pixel: sampling noise up to 1.7e-3 relative (measured), so 4e-3 per
    # pixel; over the image the noise averages out and what is left is the second-order footprint
    # bias (measured 6e-5), bounded by 5e-4.
    assert np.allclose(got, expect, rtol=4e-3, atol=0)
    assert abs(np.mean(got - expect)) < 5e-4 * np.mean(expect)


def test_rig_highlights_match_each_lights_closed_form(tmp_path):
    spec = _plane(**{"render.spp": 2, "material.diffuse_albedo": 0.0})
    r = render_scene(spec, seed=1)
    assert sorted(h.light for h in r.highlights) == [0, 1]
    n = np.array([0.0, math.sin(math.radians(15.0)), -math.cos(math.radians(15.0))])
    for h in r.highlights:
        L = r.light_rig.lights[h.light].position
        ref = plane_highlight(n, 20.0, L, r.K, (64, 64))
        assert np.allclose(h.bp_mm, ref.bp_mm, atol=1e-9) and np.allclose(h.bp_px, ref.bp_px, atol=1e-6)
        assert np.degrees(np.arccos(min(1.0, float(h.normal @ bisector(h.bp_mm, L))))) < 1e-6
    paths = write_render(r, tmp_path / "o")
    cam = load_camera(paths["camera"])
    assert cam.lights == r.light_rig and np.allclose(cam.model.K, r.K)
    meta = json.loads(paths["highlights"].read_text())
    assert sorted(h["light"] for h in meta["highlights"]) == [0, 1]
    assert all(h["depth_mm"] == h["bp_mm"][2] for h in meta["highlights"])


def test_single_light_on_the_ray_path_matches_the_perspective_render():
    """The same scene through the camera model's rays and through Mitsuba's sensor."""
    base = {"camera": {"width_px": 48, "height_px": 48, "fov_deg": 90.0},
            "light": {"falloff": "keep", "intensity": 300.0},
            "material": {"model": "phong", "c": 1.0, "n": 20.0, "diffuse_albedo": 0.3},
            "geometry": {"type": "sphere", "center_mm": [2.0, -1.0, 40.0], "radius_mm": 12.0},
            "render": {"spp": 64}}
    a = render_scene(scene_from_dict(base), seed=1)
    base["camera"]["dist_coeffs"] = [0.0, 0.0, 0.0, 0.0]  # a pinhole through the ray path
    b = render_scene(scene_from_dict(base), seed=1)
    assert b.camera is not None and a.camera is None
    # Fully covered pixels (perspective mask) have their centre on the sphere (ray-path mask), whose
    # pixels are at least partly covered.
    assert np.all(b.mask[a.mask]) and np.all(a.coverage[b.mask] > 0)
    both = a.mask
    # Independent 64-sample estimates of the same pixel means: the difference is sampling noise
    # (Monte Carlo over the pixel footprint, ~1 % of the signal), not a bias.
    rel = np.abs(a.linear[both] - b.linear[both]) / a.linear[both].max()
    assert np.median(rel) < 0.01 and abs(np.mean(a.linear[both] - b.linear[both])) < 1e-3 * a.linear.max()
    assert len(a.highlights) == len(b.highlights) == 1
    assert np.allclose(a.highlights[0].bp_px, b.highlights[0].bp_px, atol=1e-9)


def _models(tmp_path):
    K = np.array([[40.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]])
    omni = scaled_omnidirectional(c3vd_camera(), 135)
    save_camera(tmp_path / "omni.json", omni, colonoscope_rig(profile_exponent=0.0))
    return {
        "pinhole_distorted": {"model": "pinhole", "width_px": 64, "height_px": 48, "focal_px": 40.0,
                              "dist_coeffs": [-0.3, 0.08, 0.001, -0.002, 0.0]},
        "fisheye": {"model": "fisheye", "width_px": 64, "height_px": 48, "focal_px": 25.0,
                    "fisheye_d": [0.05, -0.01, 0.002, 0.0]},
        "c3vd": {"model": "c3vd", "width_px": 135, "height_px": 108},
        "file": {"model": "file", "file": str(tmp_path / "omni.json"), "width_px": 135, "height_px": 108},
    }, K


@pytest.mark.parametrize("which", ["pinhole_distorted", "fisheye", "c3vd", "file"])
def test_ground_truth_projects_onto_its_pixel(tmp_path, which):
    """Must hold: every pixel's GT position projects onto that pixel; GT normals unit, facing the camera."""
    cams, _ = _models(tmp_path)
    spec = with_overrides(load_scene("colon"), {
        **{f"camera.{k}": v for k, v in cams[which].items()}, "camera.fov_deg": None,
        "light.rig": "file" if which == "file" else "colonoscope", "render.spp": 1})
    r = render_scene(spec, seed=0)
    model = camera_model(spec)
    assert r.camera == model and r.mask.mean() > 0.5
    v, u = np.nonzero(r.mask)
    uv = model.ray_to_pixel(r.position[r.mask].astype(np.float64))
    err = np.abs(uv - np.stack([u, v], axis=-1))
    assert np.nanmax(err) < PROJECTION_TOL_PX and np.all(np.isfinite(uv))
    n = r.normals[r.mask].astype(np.float64)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert np.all(np.sum(n * r.position[r.mask], axis=1) < 0)
    for h in r.highlights:  # each highlight in view lands on its own pixel too
        assert np.allclose(model.ray_to_pixel(h.bp_mm[None])[0], h.bp_px, atol=1e-6)
        assert h.bp_mm[2] > 0 and 0 <= h.light < len(r.light_rig)


def test_c3vd_scaling_keeps_the_rays():
    full, small = c3vd_camera(), scaled_omnidirectional(c3vd_camera(), 270)
    s = 270 / 1350
    uv = np.array([[0.0, 0.0], [100.5, 40.25], [269.0, 215.0]])
    assert small.image_size == (270, 216)
    assert np.allclose(small.pixel_to_ray(uv), full.pixel_to_ray((uv + 0.5) / s - 0.5), atol=1e-12)


def test_sample_rays_in_drjit_follow_the_camera_model():
    """The image's sample rays (float32, Dr.Jit) are the model's rays (float64, numpy)."""
    from simtest.render.render import choose_variant

    choose_variant()
    from simtest.render import wavefront

    uv = np.random.default_rng(0).uniform([0, 0], [1349, 1079], size=(2000, 2))
    K = np.array([[500.0, 0, 600], [0, 510, 500], [0, 0, 1]])
    for m in (c3vd_camera(), PinholeCamera(K), PinholeCamera(K, dist_coeffs=[-0.2, 0.05, 0, 0, 0]),
              FisheyeCamera(K, [0.01, 0.0, 0.0, 0.0])):
        d = np.array(wavefront.model_rays(m, uv), dtype=np.float64).T
        # float32 rays: ~6e-8 per component round-off, times a few operations.
        assert np.abs(d - m.pixel_to_ray(uv)).max() < 2e-6


@pytest.mark.parametrize("spp", [4, 6])
def test_an_endoscope_image_does_not_depend_on_the_wavefront_size(monkeypatch, spp):
    """Each sample draws its sub-pixel position from its own stream and each pixel's samples are
    summed in order, so cutting the frame into other runs of pixels gives the same bits (a square
    spp: jittered grid; another spp: Latin hypercube)."""
    from simtest.render import rig_render as render_mod

    spec = _plane(**{"render.spp": spp, "material.model": "tissue", "geometry.tilt_deg": 25.0})
    whole = render_scene(spec, seed=3)
    monkeypatch.setattr(render_mod, "BLOCK_PIXELS", 1000)  # 64 x 64 px in 5 runs, one partial
    cut = render_scene(spec, seed=3)
    for name in ("linear", "specular", "coverage", "sensor", "rgb", "shading_normals"):
        assert np.array_equal(getattr(whole, name), getattr(cut, name), equal_nan=True), name
    assert not np.array_equal(whole.linear, render_scene(spec, seed=4).linear)  # the seed matters


def test_no_light_reaches_the_pixels_outside_the_field_stop():
    """Outside the scope's field stop the renderer shades nothing: radiance 0 there, every pixel
    inside with the bits of a render without a field stop, coverage everywhere, and no ground truth
    outside it (issue 40, item 5: mask False, NaN normals, positions, depths)."""
    from simtest.render.sensor import field_stop_mask

    over = {"render.spp": 6, "material.model": "tissue", "sensor.output": "video"}
    open_ = render_scene(_plane(**over, **{"sensor.field_stop": "none"}), seed=2)
    stopped = render_scene(_plane(**over, **{"sensor.field_stop": "circle", "sensor.field_stop_radius": 0.8}),
                           seed=2)
    inside = field_stop_mask((64, 64), "circle", 0.8)
    assert 0 < inside.sum() < inside.size
    for name in ("linear", "specular", "rgb"):
        a, b = getattr(open_, name), getattr(stopped, name)
        assert np.array_equal(a[inside], b[inside]), name
        assert np.all(b[~inside] == 0) and np.any(a[~inside] > 0), name
    assert np.array_equal(open_.coverage, stopped.coverage)
    assert open_.field_stop is None and np.array_equal(stopped.field_stop, inside)
    assert np.array_equal(stopped.mask, open_.mask & inside) and not stopped.mask[~inside].any()
    for name in ("normals", "position", "depth", "distance", "shading_normals", "albedo"):
        a, b = getattr(open_, name), getattr(stopped, name)
        assert np.array_equal(a[inside], b[inside], equal_nan=True), name
        assert np.all(np.isnan(b[~inside])) and np.all(np.isfinite(a[~inside])), name


def test_sample_positions_of_a_pixel_list_are_those_of_a_run():
    """A run given as a list of pixels draws for each pixel the samples of a contiguous run."""
    from simtest.render.endoscope import sample_positions
    from simtest.render.render import choose_variant

    choose_variant()
    W, first, n = 9, 4, 20
    pick = np.array([21, 5, 17, 6, 22])  # unordered, with gaps
    for spp in (16, 6):
        run = [np.array(x).reshape(n, spp) for x in sample_positions(spp, W, first, n, 5)]
        listed = [np.array(x).reshape(len(pick), spp) for x in sample_positions(spp, W, 0, 0, 5, pixels=pick)]
        for a, b in zip(run, listed):
            assert np.array_equal(a[pick - first], b)


def test_coherent_tracing_gives_the_same_hits():
    """The renderer traces its camera and shadow rays in Embree's coherent mode (faster); the hits
    must be those of the default (incoherent) mode to the bit."""
    from simtest._lazy import require
    from simtest.render import wavefront
    from simtest.render.render import choose_variant
    from simtest.resources import bundled_mesh_path

    choose_variant()
    mi = require("mitsuba")
    scene = mi.load_dict({"type": "scene", "m": {"type": "ply", "filename": str(bundled_mesh_path("colon"))}})
    origin = load_scene("colonoscope_tube").camera.position_mm  # inside colon.ply
    d = np.random.default_rng(0).normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*origin), mi.Vector3f(*(np.ascontiguousarray(d[:, i], dtype=np.float32) for i in range(3))))
    plain, fast = scene.ray_intersect(ray), wavefront._intersect(scene, ray)
    valid = plain.is_valid()
    assert 1000 < int(np.array(valid).sum()) and np.array_equal(np.array(valid), np.array(fast.is_valid()))
    for a, b in ((plain.t, fast.t), (plain.p, fast.p), (plain.sh_frame.n, fast.sh_frame.n),
                 (plain.prim_index, fast.prim_index)):
        assert np.array_equal(np.array(a), np.array(b), equal_nan=True)
    shadow = plain.spawn_ray_to(mi.Point3f(*(float(x) for x in np.asarray(origin) + [4.0, 0.0, 0.0])))
    blocked = np.array(scene.ray_test(shadow, valid))
    assert 0 < blocked.sum() < np.array(valid).sum()  # some shadow rays blocked, some not
    assert np.array_equal(blocked, np.array(wavefront._occluded(scene, shadow, valid)))


def test_sample_positions_stratify_each_pixel():
    """The spp samples of a pixel fall one per stratum: a sqrt(spp) grid, or spp strata on each axis."""
    from simtest.render.endoscope import sample_positions
    from simtest.render.render import choose_variant

    choose_variant()
    W, first, n = 7, 5, 9
    for spp in (16, 6):
        u, v = (np.array(x, dtype=np.float64).reshape(n, spp) for x in sample_positions(spp, W, first, n, 11))
        q = np.arange(first, first + n)
        du, dv = u - (q % W)[:, None], v - (q // W)[:, None]
        assert np.all((du >= -0.5) & (du < 0.5) & (dv >= -0.5) & (dv < 0.5))
        k = math.isqrt(spp)
        if k * k == spp:
            cells = np.floor((du + 0.5) * k) + k * np.floor((dv + 0.5) * k)
            assert all(sorted(c) == list(range(spp)) for c in cells)
        else:
            for d in (du, dv):
                assert all(sorted(c) == list(range(spp)) for c in np.floor((d + 0.5) * spp))
