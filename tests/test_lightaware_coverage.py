"""``normal_sigma_deg`` against the errors it should cover (issue 39: at least 90 % within 2 sigma),
on noisy exact planes and spheres: the plane fit's curvature test and its floor."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.geometry import angle_between_deg, project_points
from simtest.geometry.angles import unit
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.light_fits import light_aware_estimates
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.settings import ReconSettings
from _quadrics import phong_sphere_image
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
    20 deg, epsilon/d 0.15): fitted as data the clipped noise biases the plane (its mean is above
    the model where the model is near 0; 8 of 12 errors within 2 sigma of 0.34 deg, measured);
    with ``floor_refit`` the pixels whose model is within 3 noise sigmas of the floor are left
    out and the sigma covers the errors (measured: 11 of 12 within 2 sigma, RMS error 0.80 deg,
    median sigma 0.66). Opt-in: on the lightaware suite's renders it cost accuracy."""
    img0, K, N, depth, rig = _plane8(20.0, 20.0, 3.0)
    est = _highlight(img0, K)
    errs, sig = [], []
    for seed in range(12):
        img, *_ = _plane8(20.0, 20.0, 3.0, noise=0.01, seed=seed)
        pho = light_aware_estimates(img, est, K, rig, quadric=False,
                                    floor_refit=True)["photometric_fit"]
        assert pho.status in ("ok", "depth_not_observable"), pho
        errs.append(angle_between_deg(pho.normal, N))
        sig.append(pho.normal_sigma_deg)
    covered = float(np.mean(np.array(errs) < 2.0 * np.array(sig)))
    assert covered >= COVERAGE, (errs, sig)


def test_curvature_columns_span_the_quadric_patchs_derivatives():
    """The analytic derivatives of the image in the three curvatures at zero curvature
    (``model._curvature_columns``) against central differences of the quadric patch's image
    (``patch._quadric_image``, step 1e-5): the same three directions (each column of the
    differences is within 1e-6 of its projection on the analytic span, relative; measured 0 to
    1e-8), for two lights with falloff, one with a profile. (A rig mixing falloffs differs: the
    quadric's falloff is relative to the apex depth, the plane's to its distance, so their
    images weigh such lights differently.)"""
    from simtest.reconstruct.lightaware import model as lam
    from simtest.reconstruct.lightaware.patch import _quadric_image
    from test_lightaware import tilted_normal

    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square", 1.5),
                    Light((-2.0, 1.0, 0.5), 0.6, "inverse_square")))
    arr = lam._rig_arrays(rig)
    n, h, rough = tilted_normal(20.0), 25.0, 40.0
    Lm = lam._mean_light(rig)
    c = float(n @ Lm) + h
    Lp = Lm - 2.0 * c * n
    Xs = Lp * (h / -float(n @ Lp))
    K = np.array([[300.0, 0, 0], [0, 300.0, 0], [0, 0, 1.0]])
    x0 = project_points(Xs, K)
    vv, uu = np.mgrid[-40:41, -40:41]
    uv = np.column_stack([uu.ravel() + x0[0], vv.ravel() + x0[1]]).astype(float)
    dT = np.ascontiguousarray(lam._rays(K, uv).T)
    A = lam._curvature_columns(dT, lam._ray_light(arr[0], dT), n, h, arr, rough, Xs).T
    p0 = np.array([0.0, 0.0, np.log(np.linalg.norm(Xs)), 0.0, 0.0, 0.0, np.log(rough)])
    Q = np.linalg.qr(A)[0]
    for k in range(3):
        dp = np.zeros(7)
        dp[3 + k] = 1e-5
        fd = (_quadric_image(dT.T, unit(Xs), p0 + dp, arr, Lm)[0]
              - _quadric_image(dT.T, unit(Xs), p0 - dp, arr, Lm)[0]) / 2e-5
        assert np.linalg.norm(fd - Q @ (Q.T @ fd)) < 1e-6 * np.linalg.norm(fd), k
    # and the zero-curvature quadric is the plane (its falloff's reference a constant factor)
    S = lam._rig_value(dT, lam._ray_light(arr[0], dT), n, h, arr, rough)[0]
    q = _quadric_image(dT.T, unit(Xs), p0, arr, Lm)[0]
    np.testing.assert_allclose(q * (h / np.linalg.norm(Xs)) ** 2, S, rtol=1e-9, atol=1e-12 * S.max())


def test_the_quadric_patchs_batched_images_are_each_patchs_alone_bit_for_bit():
    """``quadric_fit``'s finite differences image their points as one batch (``_quadric_image``
    of (K, 7) parameters, ``_PatchProblem.residual`` of (K, m) images): each row must be the
    point's own image and residual to the last bit, as MINPACK's steps from a Jacobian that
    differs in its last bits end elsewhere (on the colonoscope frame's highlights, 4 of 24
    quadric fits changed status and normals moved up to 2.6 deg)."""
    from simtest.reconstruct.lightaware import model as lam
    from simtest.reconstruct.lightaware.patch import _PatchProblem, _quadric_image

    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square", 1.5),
                    Light((-2.0, 1.0, 0.5), 0.6, "inverse_square")))
    arr, Lm = lam._rig_arrays(rig), lam._mean_light(rig)
    K = np.array([[300.0, 0, 0], [0, 300.0, 0], [0, 0, 1.0]])
    vv, uu = np.mgrid[-30:31, -30:31]
    uv = np.column_stack([uu.ravel() + 20.0, vv.ravel() - 10.0]).astype(float)
    d, b_ray = lam._rays(K, uv), unit(np.array([0.07, -0.03, 1.0]))
    rng = np.random.default_rng(3)
    ps = np.array([0.01, -0.02, np.log(25.0), 0.2, -0.05, -0.1, np.log(60.0)]) + rng.normal(0.0, 0.2, (7, 7))
    images, normals = _quadric_image(d, b_ray, ps, arr, Lm)
    y = images[0] + 0.01 * rng.normal(size=len(d))
    P = _PatchProblem(y, d, b_ray, arr, Lm, np.column_stack([np.zeros(len(d)), np.ones(len(d)), uv / 100.0]),
                      np.arange(len(d)), 1, (61, 61), 300.0)
    res = P.residual(images)
    for k, p in enumerate(ps):
        image, normal = _quadric_image(d, b_ray, p, arr, Lm)
        assert np.array_equal(images[k], image) and np.array_equal(normals[k], normal), k
        assert np.array_equal(res[k], P.residual(image)), k


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 12), quadric_rows=st.integers(0, 12))
def test_the_cubic_patchs_batched_images_are_each_patchs_alone_bit_for_bit(seed, k, quadric_rows):
    """``cubic_patch_fit`` and ``patch_depth_profile`` image their finite differences' points as one
    batch too (``_cubic_patch_image`` of (K, 11) parameters): each row must be the point's own image
    and apex normal to the last bit, whatever the mix of cubic rows and quadric rows (all third-order
    terms 0: no Newton steps), for the reason the quadric's test gives."""
    from simtest.reconstruct.lightaware import model as lam
    from simtest.reconstruct.lightaware.cubic import _cubic_patch_image

    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square", 1.5),
                    Light((-3.0, 0.0, 0.0), 1.0, "inverse_square")))
    arr, Lm = lam._rig_arrays(rig), lam._mean_light(rig)
    K = np.array([[300.0, 0, 0], [0, 300.0, 0], [0, 0, 1.0]])
    vv, uu = np.mgrid[-20:21, -20:21]
    d = lam._rays(K, np.column_stack([uu.ravel() + 20.0, vv.ravel() - 10.0]).astype(float))
    b_ray = unit(np.array([0.07, -0.03, 1.0]))
    rng = np.random.default_rng(seed)
    ps = np.array([0.01, -0.02, np.log(25.0), 0.2, -0.05, -0.1, np.log(60.0), 0.1, -0.2, 0.05, 0.3])
    ps = ps + rng.normal(0.0, 0.2, (k, 11))
    ps[: min(quadric_rows, k), 7:] = 0.0
    images, normals = _cubic_patch_image(d, b_ray, ps, arr, Lm)
    for j, p in enumerate(ps):
        image, normal = _cubic_patch_image(d, b_ray, p, arr, Lm)
        assert np.array_equal(images[j], image, equal_nan=True) and np.array_equal(normals[j], normal), j
