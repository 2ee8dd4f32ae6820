"""The held-out sensor-like benchmark (benchmarks/sensor_like.py): its truth is exact and its scoring
matches as it says. (The section itself, a minute of reconstructions, runs in `simtest bench`.)"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from benchmarks import sensor_like


@settings(max_examples=8, deadline=None)  # (a frame each: 0.2 s)
@given(st.integers(0, 2**31 - 1))
def test_each_true_highlight_is_its_guides_specular_point_on_the_plane(seed):
    # the truth pixel's viewing ray meets the plane where the normal bisects the directions to the
    # camera and to the guide (the specular point), and the plane faces the camera
    frame, cam, n, truth, meta = sensor_like.sensor_frame(np.random.default_rng(seed))
    W, H = cam["image_size"]
    assert frame.shape == (H, W, 3) and frame.dtype == np.uint8
    assert np.isclose(np.linalg.norm(n), 1.0) and n[2] < 0
    K = np.asarray(cam["K"])
    h = -meta["depth_mm"] * n[2]
    for uv, light in zip(truth, cam["lights"]):
        ray = np.linalg.solve(K, [uv[0], uv[1], 1.0])
        X = ray * (-h / (ray @ n))
        to_cam, to_light = -X / np.linalg.norm(X), np.asarray(light["position_mm"]) - X
        bis = to_cam + to_light / np.linalg.norm(to_light)
        # 1e-9: float64 round-off of a solve and a few norms at depths of tens of mm
        assert np.linalg.norm(np.cross(bis / np.linalg.norm(bis), -n)) < 1e-9


def test_a_sharp_clipped_lobes_brightest_pixels_sit_on_the_true_highlights():
    # the image agrees with the truth: with a sharp lobe the clipped plateau of each guide covers its
    # specular point's pixel (independent of the bisector algebra above)
    rng = np.random.default_rng(7)  # (its third frame is one)
    for _ in range(20):
        frame, cam, n, truth, meta = sensor_like.sensor_frame(rng)
        W, H = cam["image_size"]
        inside = np.all((truth >= 2) & (truth <= np.array([W, H]) - 3))
        if inside and meta["spec_gain"] > 3 and meta["lobe"] in ("phong", "blinn") and meta["exponent"] > 500:
            break
    else:
        pytest.skip("no sharp clipped frame drawn")
    for u, v in np.rint(truth).astype(int):
        assert frame[v - 1:v + 2, u - 1:u + 2].min() >= 250, frame[v - 1:v + 2, u - 1:u + 2, 1]


def test_scoring_takes_the_nearest_estimate_within_the_radius_and_only_light_aware_oks():
    n = np.array([0.0, 0.0, -1.0])
    truth = np.array([[100.0, 100.0], [140.0, 100.0]])
    specs = [
        {"bp_px": [101.0, 100.0], "status": "ok", "normal": [0.0, 0.0, -1.0], "normal_from": "photometric_fit"},
        {"bp_px": [139.0, 101.0], "status": "ok", "normal": [0.0, 0.0, -1.0], "normal_from": "bp_ray"},
    ]
    assert sensor_like.score(specs, truth, n) == [("ok", 0.0), ("ok", None)]
    # an estimate beyond half the guides' separation (20 px) is not the highlight's, even within MATCH_PX
    far = [{**specs[0], "bp_px": [121.0, 100.0]}]
    assert sensor_like.score(far, truth, n)[0] == ("not_detected", None)
    assert sensor_like.score([], truth, n) == [("not_detected", None)] * 2


def test_a_false_ok_is_a_light_aware_ok_normal_beyond_the_match_radius_of_every_true_highlight():
    truth = np.array([[100.0, 100.0], [140.0, 100.0]])  # 40 px apart: the radius is 20 px
    ok = {"status": "ok", "normal": [0.0, 0.0, -1.0], "normal_from": "rig_pair"}
    on_truth = {**ok, "bp_px": [139.0, 101.0]}
    between = {**ok, "bp_px": [120.5, 100.0]}  # 20.5 px from both: no true highlight's
    far = {**ok, "bp_px": [300.0, 50.0]}
    assert sensor_like.false_oks([on_truth], truth) == 0
    assert sensor_like.false_oks([on_truth, between, far], truth) == 2
    # the BP ray's or the isophotes' normal, or a rejected row, is no light-aware normal given to the user
    others = [{**far, "normal_from": "bp_ray"}, {**far, "normal_from": "isophote"}, {**far, "status": "cluster"},
              {**far, "normal": None}]
    assert sensor_like.false_oks(others, truth) == 0
    assert sensor_like.false_oks([], truth) == 0


def test_coded_noise_frames_are_the_sensor_order_frames_with_a_noisy_plateau():
    # the coded-noise section draws the same scene as the sensor order (same geometry, lobe, exposure,
    # truth) and differs only where the noise goes: after the clip a clipped plateau holds pixels below
    # 255 (about half its pixels draw a negative noise), before it the plateau stays at 255
    for seed in range(40):
        a = sensor_like.sensor_frame(np.random.default_rng(seed))
        b = sensor_like.sensor_frame(np.random.default_rng(seed), sensor_like.CODED_NOISE)
        if a[4]["spec_gain"] > 3 and (a[0] == 255).all(axis=2).sum() >= 50:
            break
    else:
        pytest.skip("no frame with a clipped plateau drawn")
    assert np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3]) and a[4] == b[4]
    plateau = (a[0] == 255).all(axis=2)
    # a clipped linear value gives the code 255; noise of 0.5 to 2 % of 255 (1.3 to 5 levels) drawn after
    # it leaves a code below 255 in one channel or more for 1 - 0.5^3 of the pixels, 0.6 at the least here
    below = (b[0][plateau] < 255).any(axis=1).mean()
    assert below > 0.6, below
    # elsewhere the two noises are alike: the frames' mean codes agree within a level
    assert abs(float(a[0].mean()) - float(b[0].mean())) < 1.0
