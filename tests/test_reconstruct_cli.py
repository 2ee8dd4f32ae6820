"""`simtest reconstruct`: outputs, intrinsics formats, and one-line errors on bad files."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import angle_between_deg, save_intrinsics
from simtest.reconstruct import read_estimates
from simtest.simulate.analytic import phong_plane_image

REAL = Path(__file__).parent / "data" / "real"
runner = CliRunner()


def intrinsics(f, size):
    return np.array([[f, 0, size / 2 - 0.5], [0, f, size / 2 - 0.5], [0, 0, 1.0]])


@pytest.fixture
def scene(tmp_path):
    """A 16-bit PNG of an analytic Phong plane (tilt 12 deg) and its intrinsics JSON."""
    K = intrinsics(300, 240)
    t = np.radians(12)
    normal = np.array([np.sin(t), 0.0, -np.cos(t)])
    img = phong_plane_image(K, (240, 240), normal, 500.0, 60)
    png = tmp_path / "plane.png"
    cv2.imwrite(str(png), np.round(img * 60000).astype(np.uint16))
    kjson = tmp_path / "K.json"
    save_intrinsics(kjson, K)
    return png, kjson, K, normal


def test_writes_estimates_and_overlay(scene, tmp_path):
    png, kjson, K, normal = scene
    out = tmp_path / "out"
    res = runner.invoke(app, ["reconstruct", str(png), "--intrinsics", str(kjson), "--out", str(out),
                              "--isovalue", "0.2", "--isovalue", "0.4"])
    assert res.exit_code == 0, res.output
    doc = read_estimates(out / "estimates.json")
    assert doc["isovalues"] == [0.2, 0.4] and np.allclose(doc["K"], K)
    (s,) = doc["specularities"]
    assert s["status"] == "ok"
    # 16-bit quantisation of the analytic image: a ~1e-5 relative contour shift, far under 0.1 deg
    assert angle_between_deg(s["normals"]["cone_axis"], normal) < 0.1
    assert angle_between_deg(s["normals"]["joint_cone_axis"], normal) < 0.1
    overlay = cv2.imread(str(out / "overlay.png"))
    assert overlay is not None and overlay.shape[0] >= 240


def test_opencv_yaml_intrinsics_with_distortion(scene, tmp_path):
    png, _, K, _ = scene
    yml = tmp_path / "K.yml"
    fs = cv2.FileStorage(str(yml), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("dist_coeffs", np.array([[0.01, -0.001, 0.0, 0.0, 0.0]]))
    fs.release()
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(yml), "-o", str(tmp_path / "o"),
                              "--no-overlay"])
    assert res.exit_code == 0, res.output
    doc = read_estimates(tmp_path / "o" / "estimates.json")
    assert doc["dist_coeffs"] == [0.01, -0.001, 0.0, 0.0, 0.0]
    assert not (tmp_path / "o" / "overlay.png").exists()


def test_real_tile_runs(tmp_path):
    kjson = tmp_path / "K.json"
    save_intrinsics(kjson, intrinsics(140, 280))  # stand-in pinhole (tests/data/real/README.md)
    tile = REAL / "hyperkvasir_tile_r1c7_mucosa.png"
    out = tmp_path / "o"
    res = runner.invoke(app, ["reconstruct", str(tile), "-k", str(kjson), "-o", str(out), "-t", "0.8"])
    assert res.exit_code == 0, res.output
    doc = read_estimates(out / "estimates.json")
    assert any(s["status"] == "ok" for s in doc["specularities"])
    assert (out / "overlay.png").stat().st_size > 0


def _one_line_error(res, *words, code=2):
    assert res.exit_code == code, res.output
    err = res.output  # stdout and stderr together (Click 8.1 and 8.2 alike): nothing but the error
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]


def test_bad_files_give_one_readable_line(scene, tmp_path):
    png, kjson, _, _ = scene
    garbage = tmp_path / "garbage.png"
    garbage.write_bytes(b"\x89PNG not really" * 10)
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    bad_json = tmp_path / "bad.json"
    bad_json.write_text("{ not json")
    singular = tmp_path / "singular.json"
    singular.write_text(json.dumps({"K": [[0, 0, 0], [0, 0, 0], [0, 0, 1]]}))
    other_size = tmp_path / "other_size.json"
    save_intrinsics(other_size, intrinsics(300, 240), image_size=(640, 480))
    cases = [
        ([str(tmp_path / "missing.png"), "-k", str(kjson)], ["missing.png", "not found"]),
        ([str(garbage), "-k", str(kjson)], ["garbage.png"]),
        ([str(empty), "-k", str(kjson)], ["empty.png"]),
        ([str(png), "-k", str(tmp_path / "nope.json")], ["nope.json"]),
        ([str(png), "-k", str(bad_json)], ["bad.json"]),
        ([str(png), "-k", str(singular)], ["singular.json"]),
        ([str(png), "-k", str(kjson), "-t", "1.5"], ["isovalue"]),
        ([str(tmp_path), "-k", str(kjson)], ["cannot decode", "empty.png"]),  # a folder of frames
        ([str(png), "-k", str(other_size)], ["other_size.json", "640 x 480", "240 x 240"]),
    ]
    for args, words in cases:
        res = runner.invoke(app, ["reconstruct", *args, "-o", str(tmp_path / "o")])
        _one_line_error(res, *words)
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    res = runner.invoke(app, ["reconstruct", str(png), "-k", str(kjson), "-o", str(a_file)])
    _one_line_error(res, "--out", "a_file", "is a file, not a folder", code=4)
