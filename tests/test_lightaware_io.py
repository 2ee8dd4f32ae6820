"""estimates.json schema 2 (recommended normal, depth, light-aware estimators) and the CLI's rig."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from simtest.cli import app
from simtest.geometry import angle_between_deg
from simtest.geometry.camera_file import save_camera
from simtest.geometry.cameras import PinholeCamera
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import read_estimates, write_estimates
from simtest.reconstruct.lightaware.solve import _residual_correlation
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.recommend import recommend
from simtest.reconstruct.light_fits import with_light_aware
from simtest.reconstruct.settings import ReconSettings
from exact_tolerances import EXACT
from test_lightaware import one_light, plane_case

runner = CliRunner()
SETTINGS = ReconSettings(isovalues=(0.3, 0.5, 0.7))


def _estimates(rig, h=25.0, tilt=25.0):
    img, K, N, depth, bp = plane_case(h, tilt, rig)
    ests = reconstruct(img, K, settings=SETTINGS)
    assert len(ests) == 1 and ests[0].ok, ests
    return img, K, N, depth, with_light_aware(img, ests, K, rig)


def test_recommended_normal_with_an_offset_rig():
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, ests = _estimates(rig)
    rec = recommend(ests[0])
    assert rec.normal_from == "photometric_fit"
    assert angle_between_deg(rec.normal, N) < EXACT.exact_image_normal_deg
    assert abs(rec.depth_mm / depth - 1) < EXACT.exact_image_depth_rel
    assert rec.normal_sigma_deg is not None and rec.normal_sigma_deg >= 0
    # the baselines are still there, and err by about half the angle the offset subtends
    assert angle_between_deg(ests[0].bp_ray, N) > 1.0


def test_a_plane_misfit_rules_out_both_plane_fits():
    # the photometric fit's residuals say the plane model does not fit: neither it nor the
    # isocurve fit (the same plane model, seen through the contours) is recommended, however ok
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, ests = _estimates(rig)
    la_ = dict(ests[0].light_aware)
    assert la_["isocurve_fit"].ok
    la_["photometric_fit"] = dataclasses.replace(la_["photometric_fit"], status="plane_misfit")
    rec = recommend(dataclasses.replace(ests[0], light_aware=la_))
    assert rec.normal_from == "bp_ray" and rec.depth_mm is None
    assert np.allclose(rec.normal, ests[0].bp_ray)


def test_residual_correlation_separates_noise_from_a_smooth_misfit():
    # independent pixel noise: neighbours uncorrelated (|rho| within a few 1/sqrt(pairs) = 0.02);
    # a smooth pattern (a ring) plus the same noise: neighbours agree
    rng = np.random.default_rng(0)
    H = W = 60
    sel = np.arange(H * W)
    noise = rng.normal(0.0, 1.0, H * W)
    rho, c = _residual_correlation(noise, sel, (H, W), 1)
    assert abs(rho) < 0.1 and abs(c) < 0.1
    vv, uu = np.mgrid[0:H, 0:W]
    ring = 3.0 * np.cos(np.hypot(uu - 30, vv - 30) / 4.0).ravel()
    rho, c = _residual_correlation(ring + noise, sel, (H, W), 1)
    assert rho > 0.5
    # on a sub-grid (every 2nd row and column) the neighbours are 2 px apart
    grid = ((vv % 2 == 0) & (uu % 2 == 0)).ravel()
    rho2, _ = _residual_correlation(noise[grid], sel[grid], (H, W), 2)
    assert abs(rho2) < 0.15


def test_without_rig_the_recommendation_is_the_joint_cone_axis_and_no_depth():
    img, K, N, depth, ests = _estimates(LightRig.colocated())
    assert ests[0].light_aware is None  # nothing run for a co-located rig
    rec = recommend(ests[0])
    assert rec.normal_from == "joint_cone_axis" and rec.depth_mm is None
    assert np.allclose(rec.normal, ests[0].joint_cone_axis)


def test_schema_2_round_trip_and_schema_1_still_read(tmp_path):
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, ests = _estimates(rig)
    path = write_estimates(tmp_path / "estimates.json", ests, K=K, isovalues=SETTINGS.isovalues,
                           lights=rig)
    doc = read_estimates(path)
    assert doc["schema"] == 2
    spec = doc["specularities"][0]
    assert spec["normal_from"] == "photometric_fit"
    assert np.allclose(spec["normal"], spec["normals"]["photometric_fit"])
    assert spec["normals"]["isocurve_fit"] is not None and spec["normals"]["bp_ray"] is not None
    assert spec["depth_mm"] == spec["light_aware"]["photometric_fit"]["depth_mm"]
    assert doc["lights"][0]["position_mm"] == [3.0, 0.0, 0.0]
    # a schema-1 file (no recommended normal) is still read
    old = json.loads(path.read_text())
    old["schema"] = 1
    for s in old["specularities"]:
        for key in ("normal", "normal_from", "depth_mm", "normal_sigma_deg", "light_aware"):
            s.pop(key)
    old.pop("lights")
    (tmp_path / "old.json").write_text(json.dumps(old))
    assert read_estimates(tmp_path / "old.json")["schema"] == 1


def test_cli_reads_the_rig_from_the_camera_file(tmp_path):
    rig = LightRig((Light((0.0, 3.0, 0.0), 1.0, "inverse_square"),))
    img, K, N, depth, bp = plane_case(20.0, 30.0, rig)
    np.save(tmp_path / "img.npy", img)
    save_camera(tmp_path / "camera.json", PinholeCamera(K, image_size=(240, 240)), lights=rig)
    res = runner.invoke(app, ["reconstruct", str(tmp_path / "img.npy"), "--intrinsics",
                              str(tmp_path / "camera.json"), "--out", str(tmp_path / "out"),
                              "-t", "0.3", "-t", "0.5", "-t", "0.7", "--no-overlay"])
    assert res.exit_code == 0, res.output
    spec = read_estimates(tmp_path / "out" / "estimates.json")["specularities"][0]
    assert spec["normal_from"] == "photometric_fit"
    assert angle_between_deg(spec["normal"], N) < EXACT.exact_image_normal_deg
    assert abs(spec["depth_mm"] / depth - 1) < EXACT.exact_image_depth_rel
    # depth_mm is a range along the BP's ray; point_mm is that point, whose z is the z-depth a
    # depth map (ground_truth.npz) holds: exactly on the estimated BP's ray, at the true point's z
    # within the depth's tolerance (off the axis the range and the z-depth differ by 1 / cos)
    P, ray = np.array(spec["point_mm"]), np.linalg.solve(K, [*spec["bp_px"], 1.0])
    assert np.linalg.norm(P) == pytest.approx(spec["depth_mm"], rel=1e-12)
    assert np.allclose(P / np.linalg.norm(P), ray / np.linalg.norm(ray), atol=1e-12)
    true_point = depth * np.linalg.solve(K, [*bp, 1.0]) / np.linalg.norm(np.linalg.solve(K, [*bp, 1.0]))
    assert abs(P[2] / true_point[2] - 1) < EXACT.exact_image_depth_rel
    assert true_point[2] < 0.99 * depth  # off the axis: a z-depth read as the range would fail above


def test_estimates_json_carries_the_per_light_normals_of_a_two_light_patch(tmp_path):
    # A two-light exact sphere (tests/test_lightaware.py): the recommended cubic patch's normal
    # and depth at each light's specular point are written, in the rig's order, and read back.
    # (the fits, cubic=None and fit_rejected: the two lobes merge, are those that
    # test_lightaware's whole-chain test checks; made once per process)
    from test_lightaware import SPHERE_K, TWO_LIGHTS_15, sphere_specular_point, two_light_sphere_cubic_fits

    lights = list(TWO_LIGHTS_15)
    img, rig, ests = two_light_sphere_cubic_fits()
    path = tmp_path / "estimates.json"
    write_estimates(path, ests, K=SPHERE_K, image_shape=img.shape, isovalues=(0.3, 0.5, 0.7),
                    lights=rig)
    back = read_estimates(path)
    for spec in back["specularities"]:
        assert spec["normal_from"] == "cubic_patch_fit"
        entry = spec["light_aware"]["cubic_patch_fit"]
        assert entry["light_normals"] == spec["light_normals"]
        # each light's normal carries its own sigma, and the recommendation states the largest
        sig = entry["light_normal_sigmas_deg"]
        assert len(sig) == len(lights) and all(v is not None and v > 0 for v in sig)
        assert spec["normal_sigma_deg"] >= max(sig)
        for j, L in enumerate(lights):
            X, n = sphere_specular_point(L)
            assert angle_between_deg(spec["light_normals"][j], n) < 0.1
            assert abs(spec["light_depths_mm"][j] / np.linalg.norm(X) - 1) < 1e-3
    assert back["specularities"][0]["light_aware"]["photometric_fit"]["light_normals"] is None
    # a grey image: one channel fitted, no projection
    assert back["specularities"][0]["light_aware"]["photometric_fit"]["projection"] is None
