"""The sensor response reaches the light-aware fits from every input: a folder's or a video's frames,
and the camera file that ``simtest render`` writes beside its video frame (issue 39)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry.camera_file import load_camera, save_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import SensorResponse, video_response
from simtest.reconstruct.frames import open_frames, reconstruct_frames
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.table import read_frames
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.reconstruct.settings import ReconSettings
from test_lightaware import ROUGHNESS, plane_case


def _gamma_frame():
    """An exact plane lit 3 mm off the lens (Phong n = ROUGHNESS), through a gamma-2.2 8-bit
    sensor, as an RGB frame; its camera, rig and response."""
    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
    img, K, _, _, _ = plane_case(20.0, 30.0, rig)
    pix = np.rint(255.0 * (0.9 * img / img.max()) ** (1 / 2.2)).astype(np.uint8)
    return (np.repeat(pix[..., None], 3, axis=2), PinholeCamera(K, image_size=(240, 240)), rig,
            SensorResponse("gamma", 2.2, (1.0, 1.0, 1.0), 1.0, 255.0))


@pytest.mark.slow
def test_a_folders_frames_are_fitted_on_the_camera_files_response(tmp_path):
    # A folder's frames dropped the response (the fits ran on the gamma-encoded values: a Phong
    # lobe s^(1/2.2) fitted as n = 27 instead of 60). With it passed on, every frame's record is
    # the single image's (light_aware_with_rig with the response, as `simtest reconstruct` runs
    # it), bit for bit, and the lobe's roughness is the scene's (0.2 %: 8-bit quantisation of the
    # encoded values; measured 59.89).
    rgb, cam, rig, resp = _gamma_frame()
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        cv2.imwrite(str(frames / f"f{i}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    settings = ReconSettings.for_frames()
    single = light_aware_with_rig(rgb, reconstruct(rgb, cam, settings=settings), cam, rig, response=resp)
    expect = [estimate_to_dict(e, False) for e in single]
    fitted = [e for e in single if e.status == "ok"]
    assert fitted and fitted[0].light_aware["photometric_fit"].roughness == pytest.approx(ROUGHNESS, rel=2e-3)
    recs = list(reconstruct_frames(open_frames(frames), cam, settings, rig=rig, response=resp))
    assert len(recs) == 2
    for rec in recs:
        assert json.loads(json.dumps(rec["specularities"])) == json.loads(json.dumps(expect))
    # without the response the same frames give the encoded lobe's roughness
    plain = list(reconstruct_frames(open_frames(frames), cam, settings, rig=rig))[0]
    rough = [s["light_aware"]["photometric_fit"]["roughness"] for s in plain["specularities"]
             if s["status"] == "ok"]
    assert rough and rough[0] < 0.6 * ROUGHNESS
    # and through the command line: the camera file's response reaches a folder's frames
    cam_file = save_camera(tmp_path / "cam.json", cam, lights=rig, response=resp)
    res = CliRunner().invoke(app, ["reconstruct", str(frames), "--intrinsics", str(cam_file), "-o",
                                   str(tmp_path / "out"), "-j", "1"])
    assert res.exit_code == 0, res.output
    line = read_frames(tmp_path / "out" / "estimates.parquet")[0]
    rough = [s["light_aware"]["photometric_fit"]["roughness"] for s in line["specularities"]
             if s["status"] == "ok"]
    assert rough and rough[0] == pytest.approx(ROUGHNESS, rel=2e-3)


@pytest.mark.render
def test_render_writes_its_video_frames_response_and_reconstruct_fits_on_it(tmp_path):
    # simtest render wrote camera.json without "response": reconstruct on frame.png then fitted
    # the gamma-encoded lobe (plane_misfit, n 23.8 for the scene's 50, the BP ray recommended).
    # With the response written, the frame is fitted on its linear values: ok, n within 1 % of
    # the scene's (measured 49.95: spp 4 sampling noise and 8-bit quantisation), the fit's
    # normal recommended.
    from simtest.render import render_scene, write_render
    from simtest.scene import scene_from_dict

    d = {"camera": {"width_px": 160, "height_px": 160, "fov_deg": 70.0},
         "light": {"rig": "colonoscope", "falloff": "keep", "intensity": 400.0},
         "material": {"model": "phong", "c": 1.0, "n": 50.0, "diffuse_albedo": 0.0},
         "geometry": {"type": "plane", "tilt_deg": 15.0, "distance_mm": 20.0},
         "sensor": {"output": "video", "tone": "gamma", "gamma": 2.2, "exposure_mode": "fixed",
                    "exposure": 1.0, "gaussian_sigma": 0.0, "full_well_e": 0},
         "render": {"spp": 4}}
    spec = scene_from_dict(d)
    paths = write_render(render_scene(spec, seed=1), tmp_path / "r")
    cam = load_camera(paths["camera"])
    assert cam.response == video_response(spec.sensor)
    assert cam.response == SensorResponse("gamma", 2.2, (1.0, 1.0, 1.0), 1.0, 255.0)
    res = CliRunner().invoke(app, ["reconstruct", str(paths["frame"]), "-k", str(paths["camera"]),
                                   "-o", str(tmp_path / "rec"), "--no-overlay"])
    assert res.exit_code == 0, res.output
    specs = json.loads((tmp_path / "rec" / "estimates.json").read_text())["specularities"]
    ok = [s for s in specs if s["status"] == "ok"]
    # the two guides' broad lobes (n 50) make one region: a row per guide, one joint fit
    # (simtest.reconstruct.rig_lobes)
    assert len(ok) == 2 and all("fused into one highlight" in s["detail"] for s in ok)
    fit = ok[0]["light_aware"]["photometric_fit"]
    assert fit == ok[1]["light_aware"]["photometric_fit"]
    assert fit["status"] == "ok" and fit["roughness"] == pytest.approx(50.0, rel=0.01)
    assert all(s["normal_from"] == "photometric_fit" for s in ok)
    # a grey sensor image has no video frame's response: none is written
    grey = write_render(render_scene(scene_from_dict({**d, "sensor": {"output": "grey"}}), seed=1),
                        tmp_path / "g")
    assert load_camera(grey["camera"]).response is None
    # (a camera file without the response fits the encoded values: the failure this fixes)
    save_camera(tmp_path / "bare.json", cam.model, cam.lights)
    res = CliRunner().invoke(app, ["reconstruct", str(paths["frame"]), "-k", str(tmp_path / "bare.json"),
                                   "-o", str(tmp_path / "bare"), "--no-overlay"])
    assert res.exit_code == 0, res.output
    bare = json.loads((tmp_path / "bare" / "estimates.json").read_text())["specularities"]
    assert [s["normal_from"] for s in bare if s["status"] == "ok"] == ["bp_ray"]
