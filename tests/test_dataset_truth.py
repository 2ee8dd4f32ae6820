"""Every pose the dataset samplers draw has a defined brightest point, or is redrawn by a stated rule.

Analytic truth only (no rendering): the samplers' draws for scenes/datasets/example.toml, per
family, through :func:`simtest.dataset.sample.draw_parameters` (which applies the redraw rule), then
the BP of every light of the scene from :mod:`simtest.simulate.truth`, checked against the
condition that defines it (the normal bisects the directions to the camera and the light).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from simtest.dataset.config import config_from_dict, load_config
from simtest.dataset.sample import (
    MAX_REDRAWS,
    _draw_family,
    build_scene,
    draw_parameters,
    sample_rng,
    truth_problem,
)
from simtest.render.endoscope import light_rig
from simtest.render.mitsuba_dict import intrinsics_matrix
from simtest.scene.kinds import plane_normal_cam
from simtest.simulate import truth

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "scenes" / "datasets" / "example.toml"

#: Draws per family: thousands for the analytic families (their truth is what can fail), a few
#: hundred for the mesh families (their BPs are searched in the render; here only the pose).
DRAWS = {"planes": 1000, "spheres": 1000, "cylinders": 1000, "colon": 200, "liver": 200}


def _family_config(family: str):
    d = tomllib.loads(EXAMPLE.read_text())
    d["families"] = {family: 1.0}
    d["count"] = DRAWS[family]
    return config_from_dict(d, source=f"example.toml ({family} only)")


def _analytic_bps(spec, seed):
    """(BP, light position) of every light of an analytic scene: as the renderer computes them."""
    geo = spec.geometry
    K, size = intrinsics_matrix(spec.camera), (spec.camera.width_px, spec.camera.height_px)
    out = []
    for light in light_rig(spec, seed).lights:
        L = np.asarray(light.position_mm, dtype=np.float64)
        if geo.type == "plane":
            h = truth.plane_highlight(plane_normal_cam(geo), geo.distance_mm, L, K, size)
        elif geo.type == "sphere":
            h = truth.sphere_highlight(np.asarray(geo.center_mm), geo.radius_mm, L, K, size)
        else:
            h = truth.cylinder_highlight(np.asarray(geo.center_mm), np.asarray(geo.axis), geo.radius_mm,
                                         20.0 * geo.radius_mm, L, K, size)
        out.append((h, L))
    return out


@pytest.mark.parametrize("family", ["planes", "spheres", "cylinders"])
def test_every_drawn_analytic_pose_has_a_brightest_point_that_satisfies_its_definition(family):
    cfg = _family_config(family)
    found = redrawn = 0
    for i in range(cfg.count):
        p = draw_parameters(cfg, i)  # never raises: undefined poses are redrawn
        assert p["family"] == family
        redrawn += "redraw" in p
        spec = build_scene(cfg, p)
        for h, L in _analytic_bps(spec, p["render_seed"]):
            if h is None:  # defined, but no highlight (BP beyond the tube's length)
                continue
            found += 1
            # The normal bisects the directions to camera and light, to the solver's bound (the
            # sine of the angle, 1e-12: 100x float64 round-off), and faces the camera.
            assert truth._facing(h.bp_mm, h.normal, L)[0] <= truth.STATIONARY_RESIDUAL_TOL, (i, p)
            assert np.dot(h.normal, h.bp_mm) < 0, (i, p)
            if family == "spheres":
                assert math.isclose(np.linalg.norm(h.bp_mm - np.asarray(spec.geometry.center_mm)),
                                    spec.geometry.radius_mm, rel_tol=1e-9)
    assert found >= 0.9 * cfg.count  # nearly every pose has one (measured: all but a few cylinders)
    if family == "cylinders":
        # about 1 in 7 of the example's cylinder draws puts the camera inside the tube (measured
        # 27 of 197 over its 2000 samples); they are redrawn, the others are not
        assert 0.05 * cfg.count < redrawn < 0.3 * cfg.count
    else:
        assert redrawn == 0


@pytest.mark.parametrize("family", ["colon", "liver"])
def test_every_drawn_mesh_pose_is_a_camera_pose(family):
    cfg = _family_config(family)
    for i in range(cfg.count):
        p = draw_parameters(cfg, i)
        assert "redraw" not in p
        spec = build_scene(cfg, p)
        from simtest.render.mitsuba_dict import cam_to_world_matrix

        m = cam_to_world_matrix(spec.camera)
        assert np.all(np.isfinite(m))
        # a rotation (columns orthonormal, right-handed) and a translation
        np.testing.assert_allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-9)
        assert np.linalg.det(m[:3, :3]) > 0


def test_sample_41_of_the_example_is_redrawn_from_its_own_seed_sequence_child():
    cfg = load_config(EXAMPLE)
    # the first draw of sample 41: a cylinder with the camera inside (71.2 mm from the axis, R 77.6)
    rng = sample_rng(cfg.seed, 41)
    names = [f for f, _ in cfg.families]
    w = np.array([w for _, w in cfg.families])
    family = names[int(rng.choice(len(names), p=w / w.sum()))]
    first = _draw_family(cfg, family, rng)
    assert family == "cylinders" and math.isclose(first["radius_mm"], 77.63097395124659)
    assert "camera is inside the cylinder" in truth_problem(cfg, first)
    # the rule: child 0 of SeedSequence([seed, 41]) draws the family's parameters again
    p = draw_parameters(cfg, 41)
    child = np.random.default_rng(np.random.SeedSequence([cfg.seed, 41]).spawn(1)[0])
    assert p == {**_draw_family(cfg, "cylinders", child), "redraw": 1}
    assert truth_problem(cfg, p) is None
    assert draw_parameters(cfg, 41) == p  # a pure function of (config, index)
    # samples that needed no redraw are what they always were
    assert "redraw" not in draw_parameters(cfg, 40)


def test_a_family_that_never_has_a_truth_is_one_line_naming_it():
    cfg = config_from_dict({"count": 1, "seed": 1, "families": {"cylinders": 1.0},
                            "params": {"cylinders": {"view_angle_deg": 80.0, "radius_mm": 200.0,
                                                     "distance_mm": 20.0}}}, source="bad.toml")
    with pytest.raises(ValueError, match=rf"sample 0: {MAX_REDRAWS} draws in a row of family "
                                         r"'cylinders'.*narrow params.cylinders") as err:
        draw_parameters(cfg, 0)
    assert "\n" not in str(err.value)
