"""``normal_sigma_deg`` against the errors it should cover (issue 39: at least 90 % within 2 sigma),
on noisy exact planes and spheres: the plane fit's curvature test and its floor."""

from __future__ import annotations

import numpy as np

from simtest.geometry import angle_between_deg, project_points
from simtest.geometry.angles import unit
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.recommend import light_aware_estimates
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.settings import ReconSettings
from simtest.simulate.analytic import phong_sphere_image
from test_recommend_rules import _highlight, _plane8

#: The issue's coverage: the fraction of errors below twice the stated sigma. An honest sigma of a
#: 2-D Gaussian error covers 95 % (one dominant axis) to 98 % (isotropic) at 2 sigma.
COVERAGE = 0.9


def _sphere(seed, noise):
    """An exact Phong sphere (radius 10 to 30 mm, 30 to 60 mm away, one light at epsilon/d 0.1 to
    0.3) over a background of 0.1 with white noise (fraction of the peak), its true normal at
    the light's specular point, and the rig."""
    rng = np.random.default_rng(seed)
    R, dist = rng.uniform(10, 30), rng.uniform(30, 60)
    C = np.array([rng.uniform(-4, 4), rng.uniform(-4, 4), dist + R])
    ang = rng.uniform(0, 2 * np.pi)
    L = rng.uniform(0.1, 0.3) * dist * np.array([np.cos(ang), np.sin(ang), 0.0])
    n = unit(-C)
    for _ in range(300):  # the bisector condition, by fixed-point iteration
        X = C + R * n
        n = unit(unit(-X) + unit(L - X))
    K = np.array([[250.0, 0, 0], [0, 250.0, 0], [0, 0, 1.0]])
    x = project_points(C + R * n, K)
    K[0, 2], K[1, 2] = 79.5 - x[0], 79.5 - x[1]
    img = phong_sphere_image(K, (160, 160), C, R, 40.0, light_mm=L)
    img = img / img.max() * 0.8 + 0.1 + rng.normal(0.0, noise * 0.8, img.shape)
    return img, K, n, LightRig((Light(tuple(float(v) for v in L), 1.0, "none"),)), dist


def test_a_noisy_sphere_is_no_plane():
    """1 % noise: the plane fit's residuals no longer correlate enough for the neighbour test, and
    its normal (3.6 to 6.6 deg off on such spheres, sigma 1.1 to 2.3) passed as ok and was
    recommended; the curvature's score test sees the curved patch (plane_misfit), and a plane fit
    that passes it has an error its sigma covers."""
    misfits = 0
    for seed in (0, 1, 4, 5):
        img, K, n, rig, dist = _sphere(seed, 0.01)
        ests = [e for e in reconstruct(img, K, settings=ReconSettings(isovalues=(0.3, 0.5, 0.7)))
                if e.ok]
        assert len(ests) == 1
        pho = light_aware_estimates(img, ests[0], K, rig, nominal_depth_mm=dist,
                                    quadric=False)["photometric_fit"]
        misfits += pho.status == "plane_misfit"
        if pho.status in ("ok", "depth_not_observable"):
            assert angle_between_deg(pho.normal, n) < 2.0 * pho.normal_sigma_deg, (seed, pho)
        else:
            assert pho.depth_mm is None
    assert misfits >= 3  # measured: seeds 0, 4, 5 misfit; seed 1 is depth_not_observable, 3.0 deg
    # off with sigma 3.3


def test_noisy_planes_pass_the_curvature_test():
    """The score test's false alarms on planes (2 % noise, white): its tail probability is 1e-4
    per fit, so none of these 16 fits may misfit."""
    from test_lightaware import one_light, plane_case, roi_around

    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(20.0, 25.0, rig, f=200.0, size=120)
    roi0, origin = roi_around(img + 0.1, bp, 40)
    rng = np.random.default_rng(5)
    for _ in range(16):
        roi = roi0 + rng.normal(0.0, 0.02 * roi0.max(), roi0.shape)
        est = la.photometric_fit(roi, origin, bp, K, rig)
        assert est.status in ("ok", "depth_not_observable"), est


def test_sigma_covers_the_errors_on_8_bit_planes_with_read_noise_clipped_at_0():
    """An exact 8-bit plane on a black background with 1 % read noise, clipped at 0 (20 mm, tilt
    20 deg, epsilon/d 0.15): fitted as data the clipped noise biased the plane (its mean is above
    the model where the model is near 0) and the fit misfit; the pixels whose model is within 3
    noise sigmas of the floor are left out (``floor_level``) and the sigma covers the errors
    (measured: 11 of 12 within 2 sigma, RMS error 0.80 deg, median sigma 0.66; the same 12 as float
    images without the floor: all plane_misfit, 8 of 12 within 2 sigma of 0.34)."""
    img0, K, N, depth, rig = _plane8(20.0, 20.0, 3.0)
    est = _highlight(img0, K)
    errs, sig = [], []
    for seed in range(12):
        img, *_ = _plane8(20.0, 20.0, 3.0, noise=0.01, seed=seed)
        pho = light_aware_estimates(img, est, K, rig, quadric=False)["photometric_fit"]
        assert pho.status in ("ok", "depth_not_observable"), pho
        errs.append(angle_between_deg(pho.normal, N))
        sig.append(pho.normal_sigma_deg)
    covered = float(np.mean(np.array(errs) < 2.0 * np.array(sig)))
    assert covered >= COVERAGE, (errs, sig)
