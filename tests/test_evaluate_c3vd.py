"""`simtest evaluate c3vd`: small sequences in C3VD's layout built here from analytic scenes (no C3VD
data: its licence is CC BY-NC-SA), scored against their exact ground truth."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import PinholeCamera, save_camera
from _quadrics import phong_sphere_image
from simtest.simulate.analytic import phong_plane_image

SIZE = 160
K = np.array([[180.0, 0, (SIZE - 1) / 2], [0, 180.0, (SIZE - 1) / 2], [0, 0, 1]])
SPHERE_C = np.array([3.0, -2.0, 60.0])
SPHERE_R = 20.0
runner = CliRunner()


def _rays():
    vv, uu = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    d = np.stack([uu, vv, np.ones_like(uu)], axis=-1) @ np.linalg.inv(K).T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def plane_truth(normal, dist):
    d = _rays()
    lam = -dist / (d @ normal)
    X = d * lam[..., None]
    return np.broadcast_to(normal, d.shape).copy(), X[..., 2]


def sphere_truth():
    d = _rays()
    b = d @ SPHERE_C
    disc = b * b - (SPHERE_C @ SPHERE_C - SPHERE_R**2)
    lam = b - np.sqrt(np.maximum(disc, 0))
    X = d * lam[..., None]
    n = (X - SPHERE_C) / SPHERE_R
    hit = disc > 0
    n[~hit] = 0.0
    z = np.where(hit, X[..., 2], 0.0)
    return n, z


def encode_normals(n):
    # C3VD: n = 2 v / 65535 - 1; background (no surface) is written as v = 32768 (n ~ 0)
    v = np.round((n + 1.0) / 2.0 * 65535)
    v[np.linalg.norm(n, axis=-1) == 0] = 32768
    return v.astype(np.uint16)


def encode_depth(z):
    return np.where(z > 0, np.round(z / 100.0 * 65535), 0).astype(np.uint16)


def write_frame(seq, idx, img, n, z, occlusion=True):
    cv2.imwrite(str(seq / f"{idx}_color.png"), cv2.cvtColor(np.round(img / img.max() * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    tifffile.imwrite(seq / f"{idx}_normals.tiff", encode_normals(n))
    if z is not None:
        tifffile.imwrite(seq / f"{idx}_depth.tiff", encode_depth(z))
    if occlusion:
        cv2.imwrite(str(seq / f"{idx}_occlusion.png"), np.zeros((SIZE, SIZE), np.uint8))


def write_c3vd(seq, index, color, normals, depth_mm):
    """One frame as C3VD's ground-truth renderer writes it (``simtest.evaluate.c3vd``'s module
    docstring): RGB uint8 ``color``; NaN normals and depths (no surface) written as 0."""
    seq.mkdir(parents=True, exist_ok=True)
    n, z = np.asarray(normals, np.float64), np.asarray(depth_mm, np.float64)
    nv = np.where(np.isfinite(n).all(axis=-1, keepdims=True), np.round(65535 * np.clip((n + 1) / 2, 0, 1)), 0)
    zv = np.where(np.isfinite(z), np.round(65535 * np.clip(np.nan_to_num(z) / 100.0, 0, 1)), 0)
    assert cv2.imwrite(str(seq / f"{index:04d}_color.png"), cv2.cvtColor(color, cv2.COLOR_RGB2BGR))
    tifffile.imwrite(seq / f"{index:04d}_normals.tiff", nv.astype(np.uint16))
    tifffile.imwrite(seq / f"{index:04d}_depth.tiff", zv.astype(np.uint16))


@pytest.fixture
def sequence(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    t = np.radians(15)
    normal = np.array([np.sin(t), 0.0, -np.cos(t)])
    write_frame(seq, "0000", phong_plane_image(K, (SIZE, SIZE), normal, 40.0, 80), *plane_truth(normal, 40.0))
    write_frame(seq, "0001", phong_sphere_image(K, (SIZE, SIZE), SPHERE_C, SPHERE_R, 80), *sphere_truth())
    (seq / "pose.txt").write_text("ignored\n")
    cam = save_camera(tmp_path / "cam.json", PinholeCamera(K, None, (SIZE, SIZE)))
    return seq, cam, normal


def run(seq, cam, out, *extra):
    return runner.invoke(app, ["evaluate", "c3vd", str(seq), "--intrinsics", str(cam), "--out", str(out),
                               "-t", "0.3", "-t", "0.6", "--normalise", "bp", *extra])


def test_scores_every_estimator_against_the_ground_truth(sequence, tmp_path):
    seq, cam, normal = sequence
    out = tmp_path / "out"
    res = run(seq, cam, out)
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "results.json").read_text())
    assert doc["n_frames"] == 2 and doc["n_scored"] == 2
    est = doc["estimators"]
    assert {"cone_axis", "joint_cone_axis", "paper_selected", "bp_ray"} <= set(est)
    assert list(est)[-1] == "bp_ray"  # the baseline is listed beside (after) the others
    for name in ("cone_axis", "joint_cone_axis", "bp_ray"):
        # co-located plane and sphere: the cone axis and the BP ray are the normal at the BP up to
        # 8-bit quantisation of the contour and the BP's sub-pixel position (~0.2 deg here)
        assert est[name]["n"] == 2 and est[name]["p95_deg"] < 1.0, (name, est[name])
    rows = {r["frame"]: r for r in doc["highlights"] if r["scored"]}
    # the plane's footprint mean is its normal; the sphere's curvature is 1/R from depth
    assert rows["0000"]["errors_footprint_deg"]["bp_ray"] < 1.0
    assert rows["0000"]["gt_curvature_per_mm"] < 0.05 / SPHERE_R
    assert abs(rows["0001"]["gt_curvature_per_mm"] * SPHERE_R - 1.0) < 0.1  # 16-bit depth (1.5 um) on a small window
    assert rows["0000"]["size_px"] > 3 and rows["0000"]["dist_pp_px"] >= 0
    page = (out / "report.html").read_text()
    assert len(re.findall(r"<img ", page)) == 4 and "bp_ray" in page
    # --views: the 3D view of a frame beside its ground-truth surface, written with the set
    res = run(seq, cam, out, "--views", "1")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["report.html", "results.json", "view_0000.png"]
    view = cv2.imread(str(out / "view_0000.png"))
    assert view is not None and view.shape[1] > view.shape[0]  # two panels


def test_refuses_missing_and_mismatched_files(sequence, tmp_path):
    seq, cam, _ = sequence
    out = tmp_path / "out"
    (seq / "0001_normals.tiff").unlink()
    res = run(seq, cam, out)
    assert res.exit_code == 2 and "0001_normals.tiff: missing" in res.output and not out.exists()
    tifffile.imwrite(seq / "0001_normals.tiff", np.zeros((SIZE, SIZE - 1, 3), np.uint16))
    res = run(seq, cam, out)
    assert res.exit_code == 2 and "0001_normals.tiff" in res.output and "159 x 160" in res.output
    tifffile.imwrite(seq / "0001_normals.tiff", np.zeros((SIZE, SIZE), np.uint16))
    res = run(seq, cam, out)
    assert res.exit_code == 2 and "16-bit with 3 channels" in res.output
    tifffile.imwrite(seq / "0001_normals.tiff", np.zeros((SIZE, SIZE, 3), np.uint16))
    (seq / "0000_depth.tiff").unlink()
    res = run(seq, cam, out)
    assert res.exit_code == 2 and "0000_depth.tiff: missing (1 of 2 frames have a depth file)" in res.output
    (seq / "0001_depth.tiff").unlink()
    (seq / "0002_color.png").write_bytes((seq / "0000_color.png").read_bytes())
    res = run(seq, cam, out)
    assert res.exit_code == 2 and "0002_normals.tiff: missing" in res.output
    (seq / "0002_color.png").unlink()
    other = save_camera(tmp_path / "other.json", PinholeCamera(K, None, (SIZE + 2, SIZE)))
    res = run(seq, other, out)
    assert res.exit_code == 2 and "0000_color.png: 160 x 160 px, but the camera file is for 162 x 160 px" in res.output
    res = run(tmp_path / "nowhere", cam, out)
    assert res.exit_code == 2 and "sequence folder not found" in res.output
    for r in (res,):
        assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1
    assert not out.exists()


def test_outputs_replaced_as_a_set(sequence, tmp_path, monkeypatch):
    seq, cam, _ = sequence
    out = tmp_path / "out"
    assert run(seq, cam, out).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # the report fails after results.json could have been written: neither file changes
    import simtest.evaluate.cli as report  # the module whose name the command calls

    monkeypatch.setattr(report, "render_html", lambda results: (_ for _ in ()).throw(OSError("disk full")))
    res = run(seq, cam, out, "--max-frames", "1")
    assert res.exit_code == 2 and "disk full" in res.output
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_miss_written_as_c3vd_writes_it_is_invalid(sequence, tmp_path):
    # C3VD's renderer writes a pixel whose ray misses the model as n = (-1, -1, -1), i.e. all
    # zeros in the file (simtest.evaluate.c3vd's notes), which decodes to a unit-length
    # direction: it must be invalid, as the near-zero normals (v ~ 32768) are
    from simtest.evaluate.c3vd import load_frame, scan_sequence
    from simtest.geometry import load_camera

    seq, cam, _ = sequence
    n, z = sphere_truth()
    v = encode_normals(n)
    v[np.linalg.norm(n, axis=-1) == 0] = 0
    tifffile.imwrite(seq / "0001_normals.tiff", v)
    frame = [f for f in scan_sequence(seq) if f.index == "0001"][0]
    _, truth = load_frame(frame, load_camera(cam).model)
    miss = np.linalg.norm(n, axis=-1) == 0
    assert miss.any() and (~miss).any()
    assert np.isnan(truth.normals[miss]).all() and np.isfinite(truth.normals[~miss]).all()


def test_depth_of_the_light_aware_fits_is_scored_with_a_rig_in_the_camera_file(tmp_path):
    """An exact Phong plane lit by a guide 4 mm off the lens: the photometric fit's depth of the
    specular point within 2 % of the truth (8-bit frame, 16-bit depth: about 0.5 % here); the same
    sequence with the bare intrinsics has no estimator with a depth."""
    from simtest.geometry.lights import Light, LightRig
    seq = tmp_path / "seq"
    light = (4.0, 0.0, 0.0)
    for i, (tilt, dist) in enumerate([(10, 30.0), (20, 40.0)]):
        t = np.radians(tilt)
        normal = np.array([np.sin(t), 0.0, -np.cos(t)])
        img = phong_plane_image(K, (SIZE, SIZE), normal, dist, 80, light_mm=light, falloff=True)
        n, z = plane_truth(normal, dist)
        grey = np.round(img / img.max() * 255).astype(np.uint8)
        write_c3vd(seq, i, np.repeat(grey[..., None], 3, axis=2), n, z)
    rig_cam = save_camera(tmp_path / "rig.json", PinholeCamera(K, None, (SIZE, SIZE)), lights=LightRig((Light(light),)))
    res = runner.invoke(app, ["evaluate", "c3vd", str(seq), "-k", str(rig_cam), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    d = doc["depth"]["photometric_fit"]
    assert d["n"] == 2 and d["p95_abs"] < 0.02, d
    assert "normal" in doc["depth"]  # the recommended depth is scored too
    assert "relative depth error" in res.output and "Depth of the specular point" in (
        tmp_path / "out" / "report.html").read_text()
    bare = save_camera(tmp_path / "bare.json", PinholeCamera(K, None, (SIZE, SIZE)))
    res = runner.invoke(app, ["evaluate", "c3vd", str(seq), "-k", str(bare), "-o", str(tmp_path / "out2")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "out2" / "results.json").read_text())["depth"] == {}


@pytest.mark.render
def test_a_rendered_sequence_in_c3vds_layout_is_scored_against_the_renders_own_truth(tmp_path):
    """The virtual endoscope's frame written as C3VD writes its files: the ground-truth depth the
    reader recovers along each BP's ray is the renderer's own ray distance (16-bit z-depth, 1.5 um
    steps, and the bilinear read between pixel centres: well within 1 %), and the normals the
    reader decodes are the renderer's."""
    from simtest.render.render import render_scene
    from simtest.scene import load_scene, with_overrides
    # full size: at half size the two guides' highlights, 8 px apart, are one cluster
    spec = with_overrides(load_scene("colonoscope_plane"), {"render.spp": 4})
    r = render_scene(spec)
    normals = np.where(r.mask[..., None], r.normals, np.nan)
    write_c3vd(tmp_path / "seq", 0, r.frame, normals, np.where(r.mask, r.depth, np.nan))
    cam = save_camera(tmp_path / "cam.json", r.camera, lights=r.lights)
    res = runner.invoke(app, ["evaluate", "c3vd", str(tmp_path / "seq"), "-k", str(cam), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    rows = [h for h in doc["highlights"] if h.get("depth_gt_mm") is not None]
    assert rows and doc["depth"] is not None
    for h in rows:
        u, v = (int(round(x)) for x in h["bp_px"])
        assert h["depth_gt_mm"] == pytest.approx(float(r.distance[v, u]), rel=0.01)
        # the decoded normal at the BP is the renderer's there: the BP ray's error against it, from
        # the camera model's ray, to the 16-bit normals' step (2 / 65535 a component: ~0.005 deg)
        ray = np.asarray(r.camera.pixel_to_ray(np.asarray(h["bp_px"], np.float64)[None])[0], np.float64)
        true = np.asarray(r.normals[v, u], np.float64)
        want = np.degrees(np.arccos(np.clip(abs(ray @ true) / np.linalg.norm(ray) / np.linalg.norm(true), -1, 1)))
        assert h["errors_bp_deg"]["bp_ray"] == pytest.approx(want, abs=0.01), (h["errors_bp_deg"], want)
