"""The photometric plane fit's pixel caps bound pixels times lights: a rig of more lights than the
colonoscope's two guides fits a coarser sub-grid (each model evaluation costs pixels x lights); the
background bases the model keeps between evaluations are those its rows and weights give."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.lightaware.plane import FitSettings
from simtest.reconstruct.lightaware.plane_model import _BASES_KEPT, CAP_LIGHTS, PlaneModel, _qr_rows
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


def _fresh_basis(m: PlaneModel, active, w):
    """The background's basis computed anew (what the kept one must equal)."""
    om = None if w is None and active.all() else np.where(active, 1.0 if w is None else w, 0.0)
    B = m.design.T[-3:] if om is None else m.design.T[-3:] * om
    return _qr_rows(np.array(B), False) + (om,)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 2)), min_size=1, max_size=30))
def test_the_kept_background_bases_are_the_ones_computed_anew(visits):
    # a solve's evaluations go back and forth between active sets (the censored rows' first set and the
    # model's) and weights: whatever the order, each basis handed out is the one its rows and weights give,
    # a new weights array with the same rows is not served another's basis, and the memory stays bounded
    roi = np.full((30, 30), 100.0)
    K = np.array([[300.0, 0, 14.5], [0, 300.0, 14.5], [0, 0, 1]])
    m = PlaneModel(roi, (0, 0), (14.5, 14.5), K, _ring(2), FitSettings(), None, None, None, False)
    rng = np.random.default_rng(7)
    n = len(m.y)
    actives = [np.ones(n, bool)] + [rng.random(n) > 0.3 for _ in range(5)]
    weights = [None, rng.uniform(0.5, 1.5, n), rng.uniform(0.5, 1.5, n)]
    for a, k in visits:
        active, w = actives[a].copy(), weights[k]  # (a copy: the rows compared, not the array's identity)
        QT, R, om = m._background_basis(active, w)
        QT0, R0, om0 = _fresh_basis(m, active, w)
        assert np.array_equal(QT, QT0) and np.array_equal(R, R0)
        assert (om is None and om0 is None) or np.array_equal(om, om0)
        assert len(m.lin) <= _BASES_KEPT
