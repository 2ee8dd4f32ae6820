"""A rendered frame read from its files gives the same estimates as the frame held in memory.

``simtest render`` writes ``image.png`` and ``camera.json``; ``simtest reconstruct IMAGE
--intrinsics camera.json`` must then give exactly the estimates that
:func:`simtest.reconstruct.reconstruct` and the rig's step (``light_aware_with_rig``) give on the
rendered array with the rendered camera model and rig, each with its defaults. Any difference (a
lossy write, a camera parameter rounded on its way through the file, defaults that differ between
the CLI and the functions) shows up as an inequality.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry.response import video_response
from simtest.reconstruct import reconstruct
from simtest.reconstruct.io import estimates_document
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.render import render_scene, write_render
from simtest.resources import bundled_scene_path
from simtest.scene import load_scene, scene_from_dict, with_overrides

pytestmark = pytest.mark.render


def _specularities(doc: dict) -> list[dict]:
    # Only what the estimates are: the file path and version fields legitimately differ.
    return json.loads(json.dumps(doc["specularities"]))


def _check_same(tmp_path, spec, min_candidates: int = 0) -> int:
    result = render_scene(spec, seed=0)
    paths = write_render(result, tmp_path / "render")
    # The file holds exactly the in-memory sensor image (lossless PNG).
    assert np.array_equal(np.asarray(Image.open(paths["image"])), result.sensor)

    camera = result.camera_model
    # the CLI reads the rig from camera.json and runs the light-aware estimators with it, on the
    # linear intensities of the video sensor's response that the file carries
    response = video_response(spec.sensor) if result.video is not None else None
    memory = light_aware_with_rig(result.sensor, reconstruct(result.sensor, camera, lights=result.light_rig,
                                                             response=response), camera, result.light_rig,
                                  response=response)
    expected = estimates_document(memory, K=getattr(camera, "K", None), image_shape=result.sensor.shape,
                                  camera=camera)

    out = tmp_path / "est"
    cli = CliRunner().invoke(app, ["reconstruct", str(paths["image"]), "--intrinsics",
                                   str(paths["camera"]), "--out", str(out)])
    assert cli.exit_code == 0, cli.output
    from_file = json.loads((out / "estimates.json").read_text())
    assert _specularities(from_file) == _specularities(expected)
    assert len(from_file["specularities"]) >= min_candidates  # something was compared
    return sum(s["status"] == "ok" for s in from_file["specularities"])


def test_plane_through_the_c3vd_camera(tmp_path):
    # A co-located plane seen through C3VD's omnidirectional model: the camera file carries the
    # model's polynomial, which must survive the trip through JSON bit for bit.
    spec = scene_from_dict({
        "camera": {"model": "c3vd", "width_px": 270, "height_px": 216},
        "light": {"falloff": "cancel"},
        "material": {"model": "phong", "n": 200.0},
        "geometry": {"type": "plane", "tilt_deg": 25.0, "distance_mm": 40.0},
        "sensor": {"bit_depth": 16},
        "render": {"spp": 8},
    })
    assert _check_same(tmp_path, spec) >= 1


def test_bundled_sphere(tmp_path):
    spec = with_overrides(load_scene(bundled_scene_path("sphere")),
                          {"camera.width_px": 203, "camera.height_px": 203, "render.spp": 8})
    assert _check_same(tmp_path, spec) >= 1


def test_colonoscope_video_frame(tmp_path):
    # The virtual endoscope: two light guides, tissue, an 8-bit video frame, C3VD optics (scaled).
    # (a fifth of the frame's width: every candidate runs the light-aware fits twice, in memory
    # and through the files, which took 75 s at 270 x 216 px)
    spec = with_overrides(load_scene(bundled_scene_path("colonoscope_tube")),
                          {"camera.width_px": 135, "camera.height_px": 108, "render.spp": 4})
    _check_same(tmp_path, spec, min_candidates=1)
