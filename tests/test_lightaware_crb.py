"""The photometric fit against its Cramer-Rao bound on noisy analytic planes (seeded noise)."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.geometry import angle_between_deg
from simtest.reconstruct import lightaware as la
from test_lightaware import one_light, plane_case, roi_around

ROUGHNESS = 60.0
BACKGROUND = 0.1
#: Realisations per case: the RMS of 24 draws is within about 15 % (1 sigma) of the true RMS.
N_REAL = 24
#: The estimator must be within this factor of the bound (the issue's "within 2x").
BOUND_FACTOR = 2.0


def _noisy_fits(h, tilt, x_mm, sigma, seed):
    rig = one_light(x_mm, "inverse_square")
    img, K, N, depth, bp = plane_case(h, tilt, rig, f=200.0, size=160)
    roi0, origin = roi_around(img + BACKGROUND, bp, 32)
    crb = la.photometric_crb(K, origin, roi0.shape, N, h, rig, ROUGHNESS, 1.0, sigma,
                             background=(BACKGROUND, 0.0, 0.0), bp_uv=bp)
    rng = np.random.default_rng(np.random.SeedSequence([seed, int(h), int(tilt)]))
    errs, derrs, sig = [], [], []
    for _ in range(N_REAL):
        roi = roi0 + rng.normal(0.0, sigma, roi0.shape)
        bp_noisy = np.array(np.unravel_index(np.argmax(roi), roi.shape)[::-1], float) + origin
        est = la.photometric_fit(roi, origin, bp_noisy, K, rig)
        assert est.has_normal, est
        errs.append(angle_between_deg(est.normal, N))
        derrs.append(np.nan if est.depth_mm is None else est.depth_mm / depth - 1.0)
        sig.append(est.normal_sigma_deg)
    return crb, np.array(errs), np.array(derrs), np.array(sig)


@pytest.mark.parametrize("h,tilt,sigma", [(20.0, 25.0, 0.003), (12.0, 40.0, 0.002)])
def test_photometric_fit_within_twice_the_bound(h, tilt, sigma):
    crb, errs, derrs, sig = _noisy_fits(h, tilt, 3.0, sigma, seed=11)
    assert np.isfinite(crb.normal_deg) and np.isfinite(crb.depth_rel)
    rms = float(np.sqrt(np.mean(errs**2)))
    assert rms <= BOUND_FACTOR * crb.normal_deg, (rms, crb)
    assert np.all(np.isfinite(derrs))
    assert float(np.sqrt(np.mean(derrs**2))) <= BOUND_FACTOR * crb.depth_rel, (derrs, crb)
    # the fit's own 1-sigma (Jacobian and residual variance) tells the size of its error
    assert 0.5 * crb.normal_deg <= float(np.median(sig)) <= BOUND_FACTOR * crb.normal_deg


def test_bound_scales_with_noise_and_depth_bound_is_infinite_colocated():
    from simtest.geometry.lights import Light, LightRig

    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(20.0, 25.0, rig, f=200.0, size=160)
    a = la.photometric_crb(K, (40, 40), (80, 80), N, 20.0, rig, ROUGHNESS, 1.0, 0.01)
    b = la.photometric_crb(K, (40, 40), (80, 80), N, 20.0, rig, ROUGHNESS, 1.0, 0.02)
    # C = sigma^2 (J^T J)^-1: every standard deviation doubles with the noise
    assert np.isclose(b.normal_deg, 2 * a.normal_deg, rtol=1e-9)
    assert np.isclose(b.depth_rel, 2 * a.depth_rel, rtol=1e-9)
    co = LightRig((Light(),))
    c = la.photometric_crb(K, (40, 40), (80, 80), N, 20.0, co, ROUGHNESS, 1.0, 0.01)
    assert c.depth_rel == float("inf") and np.isfinite(c.normal_deg)
    with pytest.raises(ValueError, match="sigma"):
        la.photometric_crb(K, (40, 40), (80, 80), N, 20.0, rig, ROUGHNESS, 1.0, 0.0)


def test_crb_study_and_figure(tmp_path):
    from simtest.harness.crb import crb_study, plot_crb

    rows = crb_study(eps_over_d=(0.2,), sigmas=(0.005,), realisations=3, seed=1)
    assert len(rows) == 1 and rows[0]["n"] == 3
    r = rows[0]
    assert np.isfinite(r["crb_normal_deg"]) and np.isfinite(r["crb_depth_pct"])
    assert r["rms_normal_deg"] is not None
    png = plot_crb(rows, tmp_path / "crb.png")
    assert png.stat().st_size > 1000 and [p.name for p in tmp_path.iterdir()] == ["crb.png"]


#: Read noise of the must-hold (issue 39): 2 % of the lobe's peak, white, per pixel.
READ_NOISE = 0.02
#: Spread over the Cramer-Rao bound the photometric fit must stay within at 2 % read noise, on
#: ROIs of every size (issue 39). What the test could see otherwise: ROIs over ``max_pixels``
#: (16384) fitted on every second row and column only gave 1.4 to 3.2 times the bound (2.0 on
#: these cases: a quarter of the pixels, twice the standard deviation).
SPREAD_FACTOR = 1.3
#: Realisations per ROI (3 ROIs, pooled): the RMS of the 3 x 14 errors, each over its case's
#: bound, is within about 9 % (1 sigma: a 2-D error, about 80 degrees of freedom) of its
#: expectation, which 100 realisations per ROI put at 0.96 to 1.12 (every pixel used): so 1.3 is
#: two standard errors above the worst of them, and 2.0 (the sub-grid) some eight below.
N_SPREAD = 14


def _spread_over_bound(half, h, tilt, seed, **kw):
    """Normal errors (deg) over the bound, and the depth's, of ``N_SPREAD`` noisy fits of a plane
    whose ROI is ``2 half + 1`` px square."""
    rig = one_light(3.0, "inverse_square")
    img, K, N, depth, bp = plane_case(h, tilt, rig, f=200.0, size=2 * half + 40)
    roi0, origin = roi_around(img + BACKGROUND, bp, half)
    sigma = READ_NOISE * (roi0.max() - BACKGROUND)
    crb = la.photometric_crb(K, origin, roi0.shape, N, h, rig, ROUGHNESS, 1.0, sigma,
                             background=(BACKGROUND, 0.0, 0.0), bp_uv=bp)
    rng = np.random.default_rng(np.random.SeedSequence([seed, half]))
    errs, derrs = [], []
    for _ in range(N_SPREAD):
        roi = roi0 + rng.normal(0.0, sigma, roi0.shape)
        bp_noisy = np.array(np.unravel_index(np.argmax(roi), roi.shape)[::-1], float) + origin
        est = la.photometric_fit(roi, origin, bp_noisy, K, rig, **kw)
        assert est.has_normal, est
        errs.append(angle_between_deg(est.normal, N) / crb.normal_deg)
        if est.depth_mm is not None:
            derrs.append((est.depth_mm / depth - 1.0) / crb.depth_rel)
    return np.array(errs), np.array(derrs)


def test_photometric_fit_spread_within_the_bound_on_rois_of_every_size():
    """2 % read noise: the spread is within 1.3 times the bound on a 65 px ROI (4225 px) and on
    ROIs over ``max_pixels`` (129 px: 16641, 201 px: 40401), where the sub-grid's solution is
    refined on every pixel (``refine_all``)."""
    cases = [(32, 20.0, 25.0), (64, 20.0, 25.0), (100, 12.0, 40.0)]
    errs = [_spread_over_bound(half, h, tilt, seed=7) for half, h, tilt in cases]
    e = np.concatenate([a for a, _ in errs])
    assert float(np.sqrt(np.mean(e**2))) <= SPREAD_FACTOR, [np.sqrt(np.mean(a**2)) for a, _ in errs]
    # the depth, where observable (every large-ROI fit; the 65 px ROI's at 2 % noise in about
    # 2 of 3): its relative error over its bound likewise
    d = np.concatenate([b for _, b in errs])
    assert len(d) >= 2 * N_SPREAD
    assert float(np.sqrt(np.mean(d**2))) <= SPREAD_FACTOR, [np.sqrt(np.mean(b**2)) for _, b in errs]


def test_photometric_fit_on_a_sub_grid_only_is_what_the_refinement_fixes():
    """Without the refinement on every pixel a 201 px ROI's fit keeps the sub-grid's spread:
    about twice the bound (the must-hold's test above would fail)."""
    e, _ = _spread_over_bound(100, 12.0, 40.0, seed=7, refine_all=False)
    assert float(np.sqrt(np.mean(e**2))) > 1.5
