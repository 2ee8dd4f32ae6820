"""The camera file: every model and the light rig round-trip; bad files are one line naming file and key."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from simtest.geometry import (
    CameraFileError,
    FisheyeCamera,
    Light,
    LightRig,
    LightRigError,
    PinholeCamera,
    c3vd_camera,
    load_camera,
    save_camera,
)

from _cases import frame_pixels

K = np.array([[400.0, 0.0, 202.5], [0.0, 410.0, 190.5], [0.0, 0.0, 1.0]])


def models():
    return [
        PinholeCamera(K, None, (406, 381)),
        PinholeCamera(K, [-0.2, 0.05, 0.001, -0.002, 0.0], (406, 381)),
        FisheyeCamera(K, [0.05, -0.01, 0.002, -0.0003], (406, 381)),
        c3vd_camera(),
    ]


@pytest.mark.parametrize("model", models(), ids=lambda m: m.model)
def test_every_model_round_trips_through_the_file(tmp_path, model):
    rig = LightRig((Light((2.0, 0.0, 0.0)), Light((-2.0, 0.5, 0.0), 0.5, "none", 2.0)))
    p = save_camera(tmp_path / "cam.json", model, rig)
    cf = load_camera(p)
    assert cf.model == model and cf.lights == rig
    uv = frame_pixels(model, 50.0)
    np.testing.assert_array_equal(cf.model.pixel_to_ray(uv), model.pixel_to_ray(uv))
    assert load_camera(save_camera(tmp_path / "nolights.json", model)).lights == LightRig.colocated()


def test_c3vd_file_in_the_published_form(tmp_path):
    doc = {"model": "omnidirectional", "cx": 678.544839263292, "cy": 542.975887548343,
           "a0": 769.243600037458, "a1": 0, "a2": -0.000812770624150226, "a3": 6.25674244578925e-07,
           "a4": -1.1966218214428e-09, "c": 0.99998688224999, "d": 0.00288273829525059,
           "e": -0.00296316513429569, "image_size": [1350, 1080]}
    p = tmp_path / "c3vd.json"
    p.write_text(json.dumps(doc))
    assert load_camera(p).model == c3vd_camera()


def test_legacy_intrinsics_file_reads_as_pinhole(tmp_path):
    p = tmp_path / "intrinsics.json"
    p.write_text(json.dumps({"K": K.tolist(), "dist_coeffs": None, "image_size": [406, 381]}))
    cf = load_camera(p)
    assert isinstance(cf.model, PinholeCamera) and cf.model.dist_coeffs is None
    assert cf.lights.is_colocated
    np.testing.assert_array_equal(load_camera(p).model.K, K)


def write(tmp_path, name, obj):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return p


BAD_JSON = [
    # today's silent failures
    ({"K": K.tolist(), "dist_coeff": [0.1, 0, 0, 0]}, "unknown key 'dist_coeff'"),
    ({"K": [[True, 0, 1], [0, 1, 1], [0, 0, 1]]}, "key 'K' must hold numbers, got a boolean"),
    ({"K": K.tolist(), "image_size": [True, 3]}, "key 'image_size' must hold numbers"),
    ({"model": "omnidirectional", "cx": 1, "cy": 1, "a0": True, "a1": 0, "a2": 0, "a3": 0, "a4": 0,
      "c": 1, "d": 0, "e": 0}, "key 'a0' must hold numbers"),
    # keys and values
    ({"model": "fisheye", "K": K.tolist()}, "missing key 'D' for model 'fisheye'"),
    ({"model": "pinhole", "K": K.tolist(), "D": [0, 0, 0, 0]}, "unknown key 'D' for model 'pinhole'"),
    ({"model": "orthographic", "K": K.tolist()}, "key 'model' must be one of"),
    ({"K": K.tolist(), "dist_coeffs": [1, 2, 3]}, "key 'dist_coeffs': OpenCV needs"),
    ({"K": K.tolist(), "image_size": [406]}, "key 'image_size' must be \\[W, H\\]"),
    ({"model": "omnidirectional", "cx": 1, "cy": 1, "a0": -5, "a1": 0, "a2": 0, "a3": 0, "a4": 0,
      "c": 1, "d": 0, "e": 0}, "key 'a0': must be > 0"),
    ([1, 2], "must be a JSON object"),
    ("{not json", "not valid JSON"),
    # lights
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, 0], "intensity": 0}]}, "lights\\[0\\].intensity: must be > 0"),
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, 0], "falloff": "linear"}]}, "lights\\[0\\].falloff"),
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, 0], "profile_exponent": -1}]}, "profile_exponent: must be >= 0"),
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, "x"]}]}, "lights\\[0\\].position_mm\\[2\\]: must be a number"),
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, True]}]}, "position_mm\\[2\\]: must be a number"),
    ({"K": K.tolist(), "lights": [{"position_mm": [0, 0, 0], "colour": "red"}]}, "lights\\[0\\]: unknown key 'colour'"),
    ({"K": K.tolist(), "lights": [{"intensity": 1}]}, "lights\\[0\\]: missing key 'position_mm'"),
    ({"K": K.tolist(), "lights": []}, "need 1 to 8 lights, got 0"),
    ({"K": K.tolist(), "lights": [{"position_mm": [i, 0, 0]} for i in range(9)]}, "need 1 to 8 lights, got 9"),
]


@pytest.mark.parametrize(("doc", "msg"), BAD_JSON)
def test_bad_json_is_one_line_naming_file_and_key(tmp_path, doc, msg):
    p = write(tmp_path, "cam.json", doc)
    with pytest.raises(CameraFileError, match=msg) as info:
        load_camera(p)
    text = str(info.value)
    assert text.startswith(str(p)) and "\n" not in text


YAML_HEAD = "%YAML:1.0\n---\n"
MAT = "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {} ]\n"
BAD_YAML = [
    (MAT.format("500., 0., 320., 0., 500., 240., 0., 0."), "camera_matrix"),  # 8 of 9 entries
    ("camera_matrix: [1, 2\n", "not a readable OpenCV YAML/XML file"),  # unparseable
    ("camera_matrix: hello\n", "camera_matrix' must be an OpenCV matrix"),
    (MAT.format("500., 0., 320., 0., 500., 240., 0., 0., 1.") + "image_width: foo\nimage_height: 480\n", "image_width"),
    (MAT.format("500., 0., 320., 0., 500., 240., 0., 0., 1.") + "dist_coeffs: [1, 2, 3]\n", "dist_coeffs"),
    ("just text: : :\n\t- x", "not a readable OpenCV YAML/XML file"),
    ("other: 1\n", "missing key 'camera_matrix'"),
]


@pytest.mark.parametrize(("body", "msg"), BAD_YAML)
def test_malformed_opencv_yaml_is_one_line(tmp_path, body, msg):
    p = write(tmp_path, "calib.yml", YAML_HEAD + body)
    with pytest.raises(CameraFileError, match=msg) as info:
        load_camera(p)
    text = str(info.value)
    assert text.startswith(str(p)) and "\n" not in text


def test_opencv_yaml_reads_as_pinhole(tmp_path):
    y = tmp_path / "calib.yml"
    dist = np.array([-0.2, 0.05, 0.001, -0.002, 0.01])
    fs = cv2.FileStorage(str(y), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("dist_coeffs", dist.reshape(1, 5))
    fs.write("image_width", 406)
    fs.write("image_height", 381)
    fs.write("avg_reprojection_error", 0.3)  # calibration metadata is allowed in OpenCV files
    fs.release()
    cf = load_camera(y)
    assert cf.model == PinholeCamera(K, dist, (406, 381))


def test_light_rig_validation():
    assert LightRig.colocated().is_colocated and len(LightRig.colocated()) == 1
    with pytest.raises(LightRigError, match="position_mm\\[0\\]: must be finite"):
        Light((np.inf, 0, 0))
    with pytest.raises(LightRigError, match="not a Light"):
        LightRig(("x",))
    rig = LightRig((Light([1, 2, 3]),))
    np.testing.assert_array_equal(rig.positions, [[1.0, 2.0, 3.0]])
    assert not rig.is_colocated
    # separate lights: two places, not two lights (a doubled light at one place is one light's lobe)
    assert not rig.has_separate_lights and not LightRig((Light([1, 2, 3]), Light([1, 2, 3]))).has_separate_lights
    assert LightRig((Light([-4, 0, 0]), Light([4, 0, 0]))).has_separate_lights


@pytest.mark.parametrize(
    ("doc", "msg"),
    [({"K": K.tolist(), "dist_coeff": [0.1, 0, 0, 0]}, "unknown key 'dist_coeff'"),
     ({"K": [[400, 0, 202.5], [0, True, 190.5], [0, 0, 1]]}, "got a boolean")],
)
def test_reconstruct_cli_refuses_a_bad_camera_file_in_one_line(tmp_path, doc, msg):
    from typer.testing import CliRunner

    from simtest.cli import app

    img = tmp_path / "img.png"
    cv2.imwrite(str(img), np.zeros((381, 406), np.uint8))
    cam = write(tmp_path, "cam.json", doc)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["reconstruct", str(img), "--intrinsics", str(cam), "--out", str(out)])
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and msg in lines[0] and "cam.json" in lines[0]
    assert not out.exists()


BAD_RIGS = [
    # a light behind the tissue: 40 mm ahead of the lens (issue 39: depth +910 %, sigma 0.21 deg)
    ([{"position_mm": [3, 0, 40]}], "lights[0].position_mm: z = 40 mm"),
    ([{"position_mm": [3, 0, 0]}, {"position_mm": [0, 0, 20]}], "lights[1].position_mm: z = 20 mm"),
    ([{"position_mm": [3000, 0, 0]}], "on no scope"),  # metres taken for mm
    ([{"position_mm": [0, 0, -250]}], "on no scope"),  # far behind the camera
    (None, "key 'lights' is null"),  # not silently the co-located light
    ([{"position_mm": [3, 0, 0], "intensity": 1e300}], "lights[0].intensity: must be within"),
    ([{"position_mm": [3, 0, 0], "intensity": 1e-300}], "lights[0].intensity: must be within"),
]


@pytest.mark.parametrize(("lights", "msg"), BAD_RIGS)
def test_a_rig_without_physical_sense_is_one_line(tmp_path, lights, msg):
    p = write(tmp_path, "cam.json", {"K": K.tolist(), "lights": lights})
    with pytest.raises(CameraFileError) as info:
        load_camera(p)
    text = str(info.value)
    assert text.startswith(str(p)) and msg in text and "\n" not in text


def test_a_scope_rig_within_the_bounds_loads(tmp_path):
    # the colonoscope's guides 4 mm either side, a guide 2 mm behind the lens plane, the bounds'
    # edges: z just under 20 mm ahead, 200 mm from the lens, intensities 1e-9 and 1e9
    lights = [{"position_mm": [-4, 0, 0]}, {"position_mm": [4, 0, -2], "intensity": 1e9},
              {"position_mm": [0, 0, 19.9], "intensity": 1e-9}, {"position_mm": [0, 200, 0]}]
    rig = load_camera(write(tmp_path, "cam.json", {"K": K.tolist(), "lights": lights})).lights
    assert len(rig) == 4 and rig.lights[1].intensity == 1e9
    # no "lights" key at all still means one light at the camera centre
    assert load_camera(write(tmp_path, "bare.json", {"K": K.tolist()})).lights.is_colocated


@pytest.mark.parametrize("sequence", [False, True])
def test_reconstruct_refuses_an_absurd_rig_without_warnings(tmp_path, sequence):
    # exit 2 and one line, for an image and for a folder, with RuntimeWarnings made errors: an
    # intensity of 1e300 leaked overflow warnings from the fits before it was refused
    import os
    import subprocess
    import sys

    frames = tmp_path / "frames"
    frames.mkdir()
    img = frames / "f0.png"
    yy, xx = np.mgrid[0:381, 0:406]
    cv2.imwrite(str(img), np.clip(240 * np.exp(-((xx - 200) ** 2 + (yy - 190) ** 2) / 50.0), 0, 255)
                .astype(np.uint8))
    cam = write(tmp_path, "cam.json", {"K": K.tolist(),
                                       "lights": [{"position_mm": [3, 0, 0], "intensity": 1e300}]})
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    res = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "simtest.cli",
                          "reconstruct", str(frames if sequence else img), "-k", str(cam), "-o",
                          str(tmp_path / "out")], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 2, res.stderr
    lines = [x for x in res.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "intensity" in lines[0], res.stderr
    assert "Warning" not in res.stdout + res.stderr and not (tmp_path / "out").exists()
