"""A pair refit that places the other guide's highlight within its BP's wander confirms it (issue 63:
sensor-like flat mucosa near the scope, end to end through ``simtest reconstruct``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from simtest.geometry import angle_between_deg
from test_rig_pairs import _reconstruct

DATA = Path(__file__).resolve().parent / "data" / "sensor_like"


def test_weak_twins_near_the_scope_whose_pair_fit_places_both_get_light_aware_normals(tmp_path):
    # A plane 10.7 mm away (epsilon/d about 0.4), two weak narrow lobes 180 px apart, each 0.3 of the
    # sensor's room above the diffuse: passed for each other's rig twin only where a plane fit confirms
    # them. Each lobe's own ROI leaves the depth loose (relative sigma 0.34); the refit on the ROI
    # that holds both is 0.02 deg off at the right depth, yet puts the partner 2.1 to 2.8 px from its
    # BP, which noise and the shading's slope move 1.5 to 2.3 px from its specular point (the
    # isophote's centroid says so). Within PAIR_TOL_PX alone, one twin stayed not_specular (its BP
    # ray 9 to 14 deg off); within PAIR_TOL_PX plus that wander both are confirmed.
    shutil.copy(DATA / "probe780_028.png", tmp_path / "frame.png")
    shutil.copy(DATA / "probe780_028_camera.json", tmp_path / "camera.json")
    truth = json.loads((DATA / "probe780_028_truth.json").read_text())["highlights"]
    specs = _reconstruct(tmp_path)
    for h in truth:
        s = min(specs, key=lambda s: np.hypot(*(np.asarray(s["bp_px"]) - h["specular_px"])))
        assert np.hypot(*(np.asarray(s["bp_px"]) - h["specular_px"])) < 4.0
        assert s["status"] == "ok" and s["normal_from"] == "photometric_fit", s["detail"]
        # 0.2 deg: below each fit's stated 1-sigma (0.33 and 0.37 deg); the BP ray is 9 to 14 deg off
        assert angle_between_deg(s["normal"], h["normal"]) < 0.2
