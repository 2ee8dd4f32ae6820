"""`simtest render` on bad input and failed writes: one line and exit 2, outputs replaced as a set;
highlights only where the camera can see them (never behind it, never on an unlit surface)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _cases import assert_one_error_line
from typer.testing import CliRunner

from simtest.cli import app
from simtest.render import render as render_module
from simtest.render import render_scene, write_render
from simtest.scene import scene_from_dict

pytestmark = pytest.mark.render

_TINY = {"camera": {"width_px": 32, "height_px": 24, "focal_px": 32.0}, "render": {"spp": 2},
         "geometry": {"type": "plane", "tilt_deg": 10.0, "distance_mm": 20.0}}



def _one_line(res, *words, code=2):
    assert_one_error_line(res, code, *words)


def _bad_index_ply(path):
    """A binary PLY in the project's layout whose second face names vertex 7 of 4."""
    import trimesh

    from simtest.scene.meshes import save_mesh

    v = np.array([[0, 0, 10], [1, 0, 10], [0, 1, 10], [1, 1, 10]], dtype=np.float64)
    m = trimesh.Trimesh(vertices=v, faces=np.array([[0, 1, 2], [1, 3, 7]]), process=False,
                        validate=False)
    m.vertex_normals = np.tile([0.0, 0.0, -1.0], (4, 1))
    m.vertex_attributes["k1"] = np.zeros(4)
    m.vertex_attributes["k2"] = np.zeros(4)
    save_mesh(m, path)


def _mesh_scene(tmp_path, ply):
    scene = tmp_path / "mesh.toml"
    scene.write_text("[camera]\nwidth_px = 16\nheight_px = 16\n[render]\nspp = 1\n"
                     f"[geometry]\ntype = 'mesh'\npath = '{ply}'\n")
    return scene


def test_garbage_and_out_of_range_ply_give_one_line(tmp_path):
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(np.random.default_rng(0).bytes(3000))
    res = CliRunner().invoke(app, ["render", str(_mesh_scene(tmp_path, garbage)), "--out", str(tmp_path / "o")])
    _one_line(res, "geometry.path", "garbage.ply")
    bad = tmp_path / "bad_index.ply"
    _bad_index_ply(bad)
    res = CliRunner().invoke(app, ["render", str(_mesh_scene(tmp_path, bad)), "--out", str(tmp_path / "o")])
    _one_line(res, "geometry.path", "face 1", "7", "4 vertices")
    assert not (tmp_path / "o").exists()


def test_film_too_large_for_memory_is_refused(tmp_path, monkeypatch):
    # An 8 GiB machine (the limit under which a 16384^2 render used to segfault).
    monkeypatch.setattr(render_module, "available_memory_bytes", lambda: 8 * 2**30)
    scene = tmp_path / "big.toml"
    scene.write_text("[camera]\nwidth_px = 16384\nheight_px = 16384\n"
                     "[geometry]\ntype = 'plane'\ntilt_deg = 0.0\ndistance_mm = 20.0\n")
    res = CliRunner().invoke(app, ["render", str(scene), "--out", str(tmp_path / "o")])
    _one_line(res, "camera.width_px", "16384 x 16384", "GiB")
    # The estimate grows with the film: one pixel fewer than the limit renders.
    need = render_module.BASE_BYTES + render_module.BYTES_PER_PIXEL * 32 * 24
    monkeypatch.setattr(render_module, "available_memory_bytes", lambda: need)
    render_module.check_film_fits(scene_from_dict(_TINY))
    monkeypatch.setattr(render_module, "available_memory_bytes", lambda: need - 1)
    with pytest.raises(render_module.RenderInputError):
        render_module.check_film_fits(scene_from_dict(_TINY))


def test_failed_write_keeps_the_previous_set_or_none(tmp_path, monkeypatch):
    r1 = render_scene(scene_from_dict(_TINY), seed=1)
    r2 = render_scene(scene_from_dict(_TINY), seed=2)
    out = tmp_path / "out"
    write_render(r1, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", disk_full)
    for target in (out, tmp_path / "new"):
        with pytest.raises(OSError):
            write_render(r2, target)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary folder left
    monkeypatch.undo()
    write_render(r2, out)
    assert json.loads((out / "highlights.json").read_text())["seed"] == 2
    # A folder holding anything else is not replaced.
    (out / "notes.txt").write_text("mine")
    with pytest.raises(render_module.OutputFolderError, match="notes.txt"):
        write_render(r1, out)
    res = CliRunner().invoke(app, ["render", "plane_fronto", "--out", str(out)])
    _one_line(res, "--out", "notes.txt", code=4)  # the output folder cannot be replaced


def _highlights_after_cli(tmp_path, name, scene_text):
    scene = tmp_path / f"{name}.toml"
    scene.write_text(scene_text)
    res = CliRunner().invoke(app, ["render", str(scene), "--out", str(tmp_path / name)])
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / name / "highlights.json").read_text(), parse_constant=float)
    return meta["highlights"]


def test_no_highlight_behind_the_camera_or_from_a_light_inside(tmp_path):
    small = "[camera]\nwidth_px = 48\nheight_px = 48\n[render]\nspp = 2\n"
    sphere = "[geometry]\ntype = 'sphere'\ncenter_mm = [0, 0, 100]\nradius_mm = 20\n"
    away = _highlights_after_cli(tmp_path, "away", small.replace("[render]", "look_at_mm = [0, 0, -1]\n[render]") + sphere)
    assert away == []
    inside = _highlights_after_cli(
        tmp_path, "inside",
        small + "[light]\nepsilon_mm = 10.0\nalpha_deg = 0.0\nb = 10.0\n" + sphere)  # light (10, 0, 100)
    assert inside == []
    gt = np.load(tmp_path / "inside" / "ground_truth.npz")
    assert gt["mask"].any() and float(gt["specular"].max()) == 0.0  # the sphere is seen, unlit
    # The same sphere lit from outside: one finite highlight in front of the camera.
    lit = _highlights_after_cli(tmp_path, "lit", small + sphere)
    assert len(lit) == 1 and lit[0]["bp_mm"][2] > 0
    assert all(math.isfinite(x) for x in lit[0]["bp_mm"] + lit[0]["normal"])
