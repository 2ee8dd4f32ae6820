"""Light guides as discs: the disc's irradiance in closed form, a zero diameter is the point light
bit for bit, the CF-H190 preset and its ground truth (the discs' centres)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.render.endoscope import CF_H190_GUIDE_DIAMETER_MM, CF_H190_GUIDE_OFFSET_MM, cf_h190_rig
from simtest.scene.spec import SceneError, scene_from_dict

D_MM, R_MM = 15.0, 5.0
BASE = {
    "camera": {"width_px": 33, "height_px": 33, "fov_deg": 60.0},
    # both guides 1 um from the lens: on the axis, the two discs are one disc of twice the power
    "light": {"rig": "colonoscope", "falloff": "keep", "intensity": 100.0, "guide_offset_mm": 0.001},
    "material": {"model": "microfacet", "base": "plastic", "distribution": "ggx", "alpha": 0.5,
                 "diffuse_albedo": 0.5, "c": 0.0},
    "geometry": {"type": "plane", "tilt_deg": 0.0, "distance_mm": D_MM},
    "render": {"spp": 64},
}


def _with_light(**light):
    return scene_from_dict({**BASE, "light": {**BASE["light"], **light}})


def test_preset_geometry_and_keys():
    assert cf_h190_rig().positions.tolist() == [[-CF_H190_GUIDE_OFFSET_MM, 0.0, 0.0],
                                                [CF_H190_GUIDE_OFFSET_MM, 0.0, 0.0]]
    with pytest.raises(SceneError, match="light.guide_diameter_mm"):
        scene_from_dict({**BASE, "light": {"intensity": 1.0, "guide_diameter_mm": 1.0}})


@pytest.mark.render
def test_disc_irradiance_in_closed_form():
    """On the axis of a disc of radius R whose points emit I cos(theta) / s^2 (m = 1), a
    fronto-parallel plane at distance d receives ``I / (d^2 + R^2)`` (the integral of
    ``cos^2 theta / s^2`` over the disc, divided by its area), against ``I / d^2`` from its
    centre alone."""
    from simtest.render.render import render_scene

    point = render_scene(_with_light())
    disc = render_scene(_with_light(guide_diameter_mm=2 * R_MM))
    ratio = disc.linear[16, 16] / point.linear[16, 16]
    # 64 samples of the Vogel spiral integrate the smooth integrand to 0.1 % (measured 0.1 %)
    assert ratio == pytest.approx(D_MM**2 / (D_MM**2 + R_MM**2), rel=3e-3)
    assert np.array_equal(render_scene(_with_light(guide_diameter_mm=0.0)).linear, point.linear)
    # the ground truth is the discs' centres': a glossy tilted plane has the same highlights
    glossy = {**BASE, "material": {**BASE["material"], "c": 1.0, "alpha": 0.2},
              "geometry": {"type": "plane", "tilt_deg": 10.0, "distance_mm": D_MM}, "render": {"spp": 4}}
    hp = render_scene(scene_from_dict(glossy)).highlights
    hd = render_scene(scene_from_dict({**glossy, "light": {**BASE["light"], "guide_diameter_mm": 2.0}})).highlights
    assert hp and [h.bp_px.tolist() for h in hd] == [h.bp_px.tolist() for h in hp]


@pytest.mark.render
def test_cf_h190_render_records_its_discs(tmp_path):
    from simtest.render.render import render_scene, write_render

    spec = scene_from_dict({**BASE, "light": {"rig": "cf_h190", "falloff": "keep", "intensity": 100.0},
                            "render": {"spp": 4}})
    res = render_scene(spec)
    assert res.light_rig.positions[:, 0].tolist() == [-CF_H190_GUIDE_OFFSET_MM, CF_H190_GUIDE_OFFSET_MM]
    write_render(res, tmp_path / "r")
    meta = json.loads((tmp_path / "r" / "highlights.json").read_text())
    assert [x["diameter_mm"] for x in meta["lights"]] == [CF_H190_GUIDE_DIAMETER_MM] * 2
