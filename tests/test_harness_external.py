"""A researcher's own method on the suites (simtest.harness.external), through the command line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simtest.geometry.cameras import PinholeCamera
from simtest.harness.external import (ExternalError, external_estimators, load_external, score_external,
                                      with_external)
from simtest.harness.suite import load_suite

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE / "data" / "external"
README = HERE.parent / "README.md"


def test_the_readme_shows_the_example_as_it_is_tested():
    code = (EXAMPLE / "my_method.py").read_text(encoding="utf-8")
    body = code.split('"""', 2)[2].strip()  # the module without its docstring
    assert body in README.read_text(encoding="utf-8")
    assert len(code.splitlines()) <= 20


def _flat_truth(n=(0.0, 0.0, -1.0)):
    cam = PinholeCamera(np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]]), image_size=(101, 101))
    return cam, np.asarray(n) / np.linalg.norm(n)


def test_score_external_matches_within_the_radius_and_scores_the_angle(monkeypatch):
    cam, n = _flat_truth()
    mod = type(sys)("_ext_probe")
    # the answer: a BP 2 px off the truth with a normal 10 deg off, and a far one
    tilt = np.deg2rad(10.0)
    mod.f = lambda frame, camera, rig, response: {
        "bp_px": [[52.0, 50.0], [90.0, 90.0]],
        "normal": [[0.0, np.sin(tilt), -np.cos(tilt)], [0, 0, -1]]}
    monkeypatch.setitem(sys.modules, "_ext_probe", mod)
    got = score_external("_ext_probe:f", np.zeros((101, 101)), cam, None, None,
                         [((50.0, 50.0), n), ((10.0, 10.0), n)], match_px=3.0)
    assert got[0][1] is None and abs(got[0][0] - 10.0) < 1e-9
    assert np.isnan(got[1][0]) and got[1][1] == "not_detected"


def test_a_malformed_answer_is_named(monkeypatch):
    cam, n = _flat_truth()
    mod = type(sys)("_ext_bad")
    mod.f = lambda *a: {"bp_px": [[1.0, 2.0]], "normal": [[0, 0, -1], [0, 0, -1]]}
    monkeypatch.setitem(sys.modules, "_ext_bad", mod)
    with pytest.raises(ExternalError, match="1 rows and 'normal' 2"):
        score_external("_ext_bad:f", np.zeros((5, 5)), cam, None, None, [((1, 2), n)], 3.0)


@pytest.mark.parametrize("spec, why", [("nonsense", "expected package.module:function or path/to/file.py"),
                                       ("no_such_module_xyz:f", "cannot import"),
                                       ("json:no_such_function", "has no function"),
                                       ("bp_ray=os.path:join", "is taken"),
                                       # the protocol's four arguments: refused before any render, not per realisation
                                       ("json:dumps", r"dumps\(obj, \*, .*\) cannot be called as f\(frame, camera"),
                                       ("math:hypot", None), ("os.path:join", None)])
def test_a_bad_spec_is_refused_in_one_line(spec, why):
    if why is None:  # four positional arguments fit (hypot(*coordinates), join(a, *p))
        assert load_external(spec).__name__ == spec.split(":")[1]
        return
    with pytest.raises(ExternalError, match=why):
        external_estimators([spec], taken=("bp_ray",))


def test_the_suite_keeps_its_external_estimators_through_overrides(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.setitem(sys.modules, "my_method", None)  # imported here, then forgotten (README's copy: its own)
    del sys.modules["my_method"]
    s = with_external(load_suite("quick"), ["mine=my_method:bp_ray_cv"])
    t = s.with_overrides(seed=3, realisations=2)
    assert t.estimators[-1] == "mine" and t.external == (("mine", "my_method:bp_ray_cv"),)


#: The README's line that runs the example (tests/test_readme_examples.py runs it and checks its
#: run with :func:`check_external_run`: the suite runs once for both).
README_LINE = "simtest validate quick --estimator tests/data/external/my_method.py:bp_ray_cv -o out/reports"


def check_external_run(folder: Path) -> None:
    """The run folder of ``simtest validate quick --estimator .../my_method.py:bp_ray_cv``, as the README
    shows it: the external column is reported beside the built-in ones, and an OpenCV BP ray errs
    as the built-in BP ray does on the paper protocol's planes."""
    res = json.loads((folder / "results.json").read_text())
    assert res["suite"]["estimators"][-1] == "bp_ray_cv"
    assert "bp_ray_cv" in (folder / "report.md").read_text()
    for case in res["cases"]:
        m = case["metrics"]["estimators"]
        assert m["bp_ray_cv"]["n_ok"] > 0, case["id"]
        if case["id"].startswith("paper_"):
            # its BP is the brightest pixel of the smoothed image, the built-in's a sub-pixel
            # peak: at f of hundreds of px, a pixel moves the ray by a fraction of a degree; 1 deg
            # is several pixels
            assert abs(m["bp_ray_cv"]["median"] - m["bp_ray"]["median"]) < 1.0, case["id"]


def test_the_readme_runs_the_example_and_its_test_checks_the_run():
    """The command line's run of the example is the README's own line (one run of the quick suite
    in worker processes, each importing ``my_method``); the README examples' test runs it and
    checks its folder with :func:`check_external_run`."""
    assert README_LINE in README.read_text(encoding="utf-8").splitlines()
    examples = (HERE / "test_readme_examples.py").read_text(encoding="utf-8")
    assert "check_external_run(" in examples


@pytest.mark.parametrize("name, text, why", [("absent_method_xyz.py", None, "no such file"),
                                             ("my-method.py", "def f(a, b, c, d): pass\n", "is no module name"),
                                             # a file whose name an installed module takes: that one would run
                                             ("json.py", "def f(a, b, c, d): pass\n", "imports .*json.* first")])
def test_a_file_that_cannot_be_its_module_is_refused_in_one_line(tmp_path, monkeypatch, name, text, why):
    monkeypatch.setattr(sys, "path", list(sys.path))  # (the file's folder joins it)
    if text is not None:
        (tmp_path / name).write_text(text)
    with pytest.raises(ExternalError, match=why):
        external_estimators([f"{tmp_path / name}:f"], taken=())


def test_a_file_imports_by_its_name_from_its_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "path", list(sys.path))
    (tmp_path / "ext_file_probe_95.py").write_text("def f(frame, camera, rig, response):\n    return 1\n")
    try:
        got = external_estimators([f"mine={tmp_path / 'ext_file_probe_95.py'}:f"], taken=())
        # the workers import the module by its name: the folder ends sys.path, after what is installed
        assert got == (("mine", "ext_file_probe_95:f"),) and sys.path[-1] == str(tmp_path)
        assert load_external("ext_file_probe_95:f")(None, None, None, None) == 1
    finally:
        sys.modules.pop("ext_file_probe_95", None)


def test_a_method_beside_the_user_runs_without_pythonpath(tmp_path):
    """As the console script runs (``-P``: neither the current folder nor the file's on ``sys.path``), a
    module in the current folder and a file elsewhere are scored, in the suite's worker processes."""
    here, elsewhere = tmp_path / "here", tmp_path / "methods"
    for folder, name in ((here, "my_method.py"), (elsewhere, "their_method.py")):
        folder.mkdir()
        shutil.copy2(EXAMPLE / "my_method.py", folder / name)
    r = subprocess.run([sys.executable, "-P", "-m", "simtest.cli", "validate", "quick", "--no-progress", "-o", "out",
                        "--run-id", "r", "--estimator", "my_method:bp_ray_cv",
                        "--estimator", f"theirs={elsewhere / 'their_method.py'}:bp_ray_cv"],
                       cwd=here, env=dict(os.environ, PYTHONPATH=str(HERE.parent)), capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads((here / "out" / "quick" / "r" / "results.json").read_text())
    assert res["suite"]["estimators"][-2:] == ["bp_ray_cv", "theirs"]
    for case in res["cases"]:
        for name in ("bp_ray_cv", "theirs"):
            assert case["metrics"]["estimators"][name]["n_ok"] > 0, (case["id"], name)


#: A method that checks what the protocol hands it on a rendered endoscope frame (the scene's camera model of the
#: frame's size, the two-guide rig in mm, the video sensor's response) and answers the BP ray of the brightest pixel.
_CHECKING_METHOD = '''
import cv2
import numpy as np
from simtest.geometry.cameras import CameraModel
from simtest.geometry.lights import LightRig


def checked(frame, camera, rig, response):
    assert isinstance(camera, CameraModel) and tuple(camera.image_size) == frame.shape[1::-1]
    assert isinstance(rig, LightRig) and len(rig.positions) == 2 and 0 < abs(rig.positions[0][0]) < 10
    assert response is not None and frame.dtype == np.uint8
    white = cv2.GaussianBlur(frame.min(axis=-1).astype(np.float32), (5, 5), 1.0)  # specular light is white
    n, labels = cv2.connectedComponents((white >= 0.9 * white.max()).astype(np.uint8))
    vu = [np.unravel_index(np.argmax(np.where(labels == i, white, -np.inf)), white.shape) for i in range(1, n)]
    bp = np.asarray(vu, dtype=float).reshape(-1, 2)[:, ::-1]
    return {"bp_px": bp, "normal": -camera.pixel_to_ray(bp)}
'''


@pytest.mark.render
@pytest.mark.slow
def test_a_method_runs_on_the_endoscope_protocol_with_its_camera_rig_and_response(tmp_path):
    """The endoscope suite's protocol hands the method its rendered video frame with the camera model, the light
    rig and the sensor response (one case of the suite, guides 4 mm off the lens, one realisation; its light-aware
    estimators make the frame the video's), and scores it beside the built-in estimators."""
    (tmp_path / "checking_method.py").write_text(_CHECKING_METHOD)
    suite = tmp_path / "endoscope_one.toml"
    suite.write_text('[suite]\nname = "endoscope_one"\nprotocol = "rendered"\nscene = "colonoscope_plane"\n'
                     'realisations = 1\nestimators = ["recommended", "photometric_fit", "bp_ray"]\n\n[[sweep]]\nname = "guide_offset"\n'
                     'parameter = "light.guide_offset_mm"\nvalues = [4.0]\n')
    r = subprocess.run([sys.executable, "-P", "-m", "simtest.cli", "validate", str(suite), "--no-progress", "-o", "out",
                        "--run-id", "r", "-j", "1", "--estimator", "checking_method.py:checked"],
                       cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(HERE.parent)), capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    (case,) = json.loads((tmp_path / "out" / "endoscope_one" / "r" / "results.json").read_text())["cases"]
    ours, builtin = case["metrics"]["estimators"]["checked"], case["metrics"]["estimators"]["bp_ray"]
    assert ours["n"] == 2 and ours["n_ok"] == 2, ours  # both guides' highlights (an assertion above: an exception)
    # each white blob's brightest pixel's ray errs as the built-in BP ray (a sub-pixel peak of the smoothed frame):
    # within 1 deg, a few px at this focal length
    assert abs(ours["median"] - builtin["median"]) < 1.0, (ours["median"], builtin["median"])
