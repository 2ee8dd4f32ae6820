"""The photometric plane fit's pixel caps bound pixels times lights: a rig of more lights than the
colonoscope's two guides fits a coarser sub-grid (each model evaluation costs pixels x lights)."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.lightaware.plane import FitSettings
from simtest.reconstruct.lightaware.plane_model import CAP_LIGHTS, PlaneModel
from simtest.reconstruct.lightaware.plane_solve import REFINE_MAX_PIXELS


def _ring(count: int) -> LightRig:
    a = 2 * np.pi * np.arange(count) / count
    return LightRig(tuple(Light((4.0 * np.cos(t), 4.0 * np.sin(t), 0.0), 1.0, "inverse_square") for t in a))


@pytest.mark.parametrize("count", [1, 2, 3, 8])
def test_a_rigs_fit_holds_at_most_the_caps_pixels_times_two_lights(count):
    # a 400 x 400 ROI (160,000 unclipped pixels): over both caps' share under any rig
    roi = np.full((400, 400), 100.0)
    K = np.array([[300.0, 0, 199.5], [0, 300.0, 199.5], [0, 0, 1]])
    s = FitSettings()
    m = PlaneModel(roi, (0, 0), (199.5, 199.5), K, _ring(count), s, None, None, None, False)
    share = CAP_LIGHTS / max(count, CAP_LIGHTS)  # the share of each cap a rig of `count` lights fits
    assert len(m.y) <= share * s.max_pixels
    assert len(m.y) > share * s.max_pixels / 4  # the sub-grid's step is the least that meets it
    m.use(REFINE_MAX_PIXELS)
    assert len(m.y) <= share * REFINE_MAX_PIXELS
    assert len(m.y) > share * REFINE_MAX_PIXELS / 4
