"""A broad lobe in the photometric fit: its GGX tails on one channel, and an ROI the lobe spans
(issue 63: the endoscope-flat suite's film roughness 0.2 and JPEG 25)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from simtest.decisions import LOBE_EDGE_REL, LOBE_ROI_MISMATCH
from simtest.reconstruct import lightaware as la
from simtest.reconstruct._pixels import Roi
from simtest.reconstruct.light_fits import _lobe_roi, light_aware_estimates
from simtest.reconstruct.lightaware import model as lam
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from test_lightaware import plane_case
from test_lightaware_sensor import RIG

SIZE = 160


@pytest.fixture(scope="module")
def plane():
    """K, the true normal and the BP of a plane 20 mm away, 20 deg tilted, under the two guides."""
    _, K, N, _, bp = plane_case(20.0, 20.0, RIG, size=SIZE)
    return K, N, np.ravel(bp)


def _fit(N, n):
    return LightAwareEstimate("photometric_fit", "ok", normal=N, distance_mm=20.0, roughness=float(n))


def _lobe_image(K, N, n):
    vv, uu = np.mgrid[0:SIZE, 0:SIZE]
    rays = lam._rays(K, np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    return la.plane_rig_intensity(rays, N, 20.0, RIG, n).reshape(SIZE, SIZE)


def test_a_cut_lobe_gets_the_roi_it_spans(plane):
    # The detection's region of a faint broad lobe (Phong n 48, GGX alpha 0.2) is its noisy top,
    # 8 px a side: the ROI is grown to every pixel where the fitted lobe is at least
    # LOBE_EDGE_REL of its peak (both guides' lobes), and that ROI is then left as it is.
    K, N, bp = plane
    roi = _lobe_roi(_fit(N, 48.0), bp, K, RIG, (SIZE, SIZE), Roi.around(bp, 4.0, (SIZE, SIZE)))
    assert roi is not None
    S = _lobe_image(K, N, 48.0)
    inside = np.zeros_like(S, dtype=bool)
    inside[roi.slices] = True
    assert not (S >= LOBE_EDGE_REL * S.max())[~inside].any()
    assert max(roi.shape) > 2 * LOBE_ROI_MISMATCH * 4.0
    assert _lobe_roi(_fit(N, 48.0), bp, K, RIG, (SIZE, SIZE), roi) is None


def test_a_roi_wider_than_the_lobe_is_left_as_it_is(plane):
    # A narrow lobe (n 2000) in a region spanning a 480 px frame: no refit (the border that gives
    # the body colours keeps its room), and none for a fit without a plane.
    K, N, bp = plane
    shape = (3 * SIZE, 3 * SIZE)
    whole = Roi(0, shape[0], 0, shape[1])
    assert _lobe_roi(_fit(N, 2000.0), bp, K, RIG, shape, whole) is None
    assert _lobe_roi(LightAwareEstimate("photometric_fit", "not_converged"), bp, K, RIG, shape,
                     Roi.around(bp, 2.0, shape)) is None


def test_a_broad_phong_fit_on_one_channel_is_refitted_with_ggx(plane):
    # An 8-bit image of the GGX film (alpha 0.2, Phong n of the same peak curvature 48) with 4
    # levels of noise: Phong passes its misfit test with n near 30 (measured 29 to 35), broader
    # than the lobe, as a Phong lobe's faster tails make it. Its n is below BROAD_LOBE_PHONG_N,
    # so the GGX fit runs and, with the lower residual, is kept, its roughness the film's
    # (measured 46 to 54 on three noise draws; bound 20 %).
    K, N, bp = plane
    vv, uu = np.mgrid[0:SIZE, 0:SIZE]
    dT = np.ascontiguousarray(lam._rays(K, np.column_stack([uu.ravel(), vv.ravel()]).astype(float)).T)
    arr = lam._rig_arrays(RIG)
    S = lam._rig_value_ggx(dT, lam._ray_light(arr[0], dT), N, 20.0, arr, 0.2).reshape(SIZE, SIZE)
    noisy = 200.0 * S / S.max() + 20.0 + np.random.default_rng(0).normal(0.0, 4.0, S.shape)
    img = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    ray = np.linalg.inv(K) @ np.array([bp[0], bp[1], 1.0])
    est = SimpleNamespace(roi=(int(bp[1]) - 8, int(bp[1]) + 9, int(bp[0]) - 8, int(bp[0]) + 9), bp_px=bp,
                          bp_ray=ray / np.linalg.norm(ray))
    pf = light_aware_estimates(img, est, K, RIG, quadric=False)["photometric_fit"]
    assert pf.ok and pf.lobe == "ggx", pf
    assert pf.roughness == pytest.approx(lam.phong_of_ggx_alpha(0.2), rel=0.2)
