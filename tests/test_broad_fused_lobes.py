"""Broad lobes of two guides fused into one region that the frame's edge cuts: the second look on a
wider background square (broad_lobes.py) hands the cut region to the rig's step, which gives each
guide its row (issue 63: sensor-like flat mucosa, end to end through ``simtest reconstruct``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from simtest.geometry import angle_between_deg
from simtest.reconstruct.detect_pixels import background_side_px
from test_rig_pairs import _reconstruct, _write, sensor_plane

DATA = Path(__file__).resolve().parent / "data" / "sensor_like"


def test_fused_broad_lobes_the_frames_edge_cuts_get_both_guides_rows(tmp_path):
    # Blinn exponent 60 at 16 mm, tilted 28 deg along the guides' baseline: the two lobes fuse into
    # one region about 120 x 50 px, four times the frame's 31 px background square and unclipped
    # (red alone reaches the ceiling), so the first look finds nothing; the wider look finds the
    # region, whose isophote the frame's left edge cuts (contour_cut), and the rig's step splits it.
    img, K, n, truth = sensor_plane(28.0, 16.0, 3, spec=0.5, size=320, rows=256, f=160.0, shininess=60.0,
                                    azimuth_deg=0.0)
    assert not (img == 255).all(axis=-1).any()  # no clipped plateau widens the first square
    assert background_side_px(img.shape[:2]) == 31
    _write(tmp_path, img, K)
    specs = _reconstruct(tmp_path)
    for t in truth:
        near = [s for s in specs if np.hypot(*(np.asarray(s["bp_px"]) - t)) <= 2.0]
        assert len(near) == 1, [(s["bp_px"], s["status"]) for s in specs]
        s = near[0]
        assert s["status"] == "ok" and s["normal_from"] == "photometric_fit", s["detail"]
        # 0.5 deg: issue 63's bar for the median on flat mucosa; the fit's own error here is ~0.04
        assert angle_between_deg(s["normal"], n) < 0.5


def test_a_diffuse_hump_wider_than_three_squares_stays_out_of_the_rig_step(tmp_path):
    # A sensor-like frame (tests/data/sensor_like: a plane tilted 49 deg, the guides' narrow clipped lobes
    # at its left edge, the diffuse maximum a hump about 255 px across in the middle). Its clipped tops
    # widen the first square to 95 px, so the hump fits the wider look's 285 px square and comes out
    # contour_cut, its isophote cut by its ROI. Wider across than three of the frame's own 51 px squares,
    # it is shading and stays out: kept, its ROI (the whole frame) made it every fit's lobe partner and
    # moved guide 1's plane fit from 0.03 to 0.91 deg.
    shutil.copy(DATA / "probe779_021.png", tmp_path / "frame.png")
    shutil.copy(DATA / "probe779_021_camera.json", tmp_path / "camera.json")
    truth = json.loads((DATA / "probe779_021_truth.json").read_text())["highlights"]
    specs = _reconstruct(tmp_path)
    assert not [s["roi"] for s in specs if s["status"] == "contour_cut"]
    g0 = truth[0]
    s = min(specs, key=lambda s: np.hypot(*(np.asarray(s["bp_px"]) - g0["specular_px"])))
    assert s["status"] == "ok" and s["normal_from"] == "photometric_fit"
    # 0.2 deg: its stated 1-sigma is 0.25 deg; the hump's partnership moved it to 0.91
    assert angle_between_deg(s["normal"], g0["normal"]) < 0.2
