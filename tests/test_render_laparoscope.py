"""The laparoscope scene: the liver in its abdomen fills the field (no void), the exposure is
metered on tissue and clips under 2 % of the tissue pixels, the wall is its own tissue."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.resources import data_root
from simtest.scene.meshes import load_mesh
from simtest.scene.meshes.abdomen import wall_sphere
from simtest.scene.meshes.params import MeshError
from simtest.scene.spec import load_scene, with_overrides

MESH = data_root() / "meshes" / "liver_abdomen.ply"


def test_wall_sphere_holds_the_liver_with_its_gap():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(500, 3)) * (60.0, 40.0, 25.0)
    centre, R = wall_sphere(pts, (0.0, -1.0, -1.0), 300.0, 15.0)
    reach = np.linalg.norm(pts - centre, axis=1).max()
    assert reach == pytest.approx(R - 15.0, abs=1e-6)  # as near as the gap allows
    with pytest.raises(MeshError, match="too small"):
        wall_sphere(pts, (0.0, -1.0, -1.0), 50.0, 15.0)


def test_committed_abdomen_mesh():
    """The wall's vertices lie on its sphere with exact normals and curvatures; the liver is the
    committed liver, every point of it at least the gap inside the sphere."""
    gen = json.loads(MESH.with_suffix(".json").read_text())["generator"]
    mesh = load_mesh(MESH)
    liver = load_mesh(data_root() / "meshes" / "liver.ply")
    nl = len(liver.vertices)
    v = np.asarray(mesh.vertices)
    assert np.array_equal(v[:nl], np.asarray(liver.vertices))
    c, R = np.array(gen["wall_centre_mm"]), gen["wall_radius_mm"]
    d = np.linalg.norm(v - c, axis=1)
    # float32 vertices 400 mm out: 3e-5 mm of round-off
    assert np.allclose(d[nl:], R, atol=1e-4) and d[:nl].max() <= R - gen["gap_mm"] + 1e-4
    n = np.asarray(mesh.vertex_normals)[nl:]
    assert np.allclose(n, (c - v[nl:]) / R, atol=1e-5)  # toward the centre
    assert np.allclose(mesh.vertex_attributes["k1"][nl:], -1.0 / R, rtol=1e-6)


@pytest.mark.render
def test_laparoscope_fills_the_field_and_does_not_clip():
    from simtest.render.render import render_scene

    spec = load_scene("laparoscope_liver")
    res = render_scene(with_overrides(spec, {"camera.width_px": 320, "camera.height_px": 240, "render.spp": 4}))
    stop = res.field_stop
    assert res.mask[stop].all()  # tissue at every pixel of the field: no void
    f = res.frame
    clipped = (f >= 255).any(axis=-1) & stop
    assert clipped.sum() / stop.sum() < 0.02
    # both tissues in view, told apart by their albedo (the wall's is paler: more green)
    alb = res.albedo[stop]
    ratio = alb[:, 1] / alb[:, 0]
    assert (ratio < 0.25).mean() > 0.3 and (ratio > 0.45).mean() > 0.05
    # metering on tissue: the field's mean luma is the target (every field pixel is tissue)
    assert not np.isnan(res.depth[stop]).any()


def test_meshes_build_makes_the_committed_abdomen_mesh(tmp_path):
    # `simtest meshes build` builds liver_abdomen (it built colon and liver only), the same file
    from typer.testing import CliRunner

    from simtest.scene.meshes.abdomen import LAPAROSCOPE_WALL_AXIS
    from simtest.scene.meshes_cli import meshes_app

    result = CliRunner().invoke(meshes_app, ["build", "--out", str(tmp_path), "--only", "liver_abdomen"])
    assert result.exit_code == 0, result.output
    gen = json.loads(MESH.with_suffix(".json").read_text())["generator"]
    fresh_gen = json.loads((tmp_path / "liver_abdomen.json").read_text())["generator"]
    assert gen["wall_axis"] == pytest.approx(LAPAROSCOPE_WALL_AXIS, abs=1e-15)
    floats = ("wall_axis", "wall_centre_mm")  # an ulp apart from the normalisation's round-off
    assert {k: v for k, v in fresh_gen.items() if k not in floats} == {k: v for k, v in gen.items()
                                                                      if k not in floats}
    assert fresh_gen["wall_centre_mm"] == pytest.approx(gen["wall_centre_mm"], abs=1e-9)
    fresh, committed = load_mesh(tmp_path / "liver_abdomen.ply"), load_mesh(MESH)
    assert len(fresh.faces) == len(committed.faces)
    # float32 files, as tests/test_meshes.py: libm may differ by an ulp across platforms
    np.testing.assert_allclose(committed.vertices, fresh.vertices, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(committed.vertex_normals, fresh.vertex_normals, atol=1e-6)
    assert MESH.stat().st_size < 2_000_000
