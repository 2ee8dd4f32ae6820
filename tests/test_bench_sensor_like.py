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
